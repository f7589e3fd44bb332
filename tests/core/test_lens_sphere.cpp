// Dual fisheye to the full sphere (issue 15), calibrated: two back-to-back fisheyes (190-220
// degrees) rendered from the real 360-degree photo of ../shared/data/images/equirect_jobsite (the
// repository photo taken as a panorama when ../shared is absent), calibrated from a rough rig
// (focal 3 % off, yaw / pitch / roll up to 2 degrees off, the lens coefficients given), stitched
// to a 2:1 sphere: seam error against the ground truth <= 1 px, every pixel covered, poles
// included. Worst case over several fields of view and seeds.
//
// Was disabled (branch lens-out): the calibrator fitted homographies on ideal pinhole pixels,
// which rays >= 90 degrees off the axis do not have (all of a back-to-back pair's overlap).
// Branch fisheye-match matches such pairs on rays (calibrator.cpp, match_pair_rays). The
// coverage is checked from the geometry (the photo's nadir is black itself). Branch lens-fisheye:
// a shared k1 from the back-to-back ring (estimated or declined), and the ground truth's edges
// kept on a rendered radtan rig (tests/common/lens_quality.hpp).
#include <chrono>
#include <gtest/gtest.h>

#include <cstdio>
#include <random>

#include "lens_quality.hpp"
#include "lens_rig.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/calib/fisheye_guess.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "stitch/rig/lens.hpp"
#include "stitch/warp/geometry.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

// The worst canvas distance, in the estimated rig, between where it puts the two views of one
// scene ray, over the rays both true cameras see (their image circles): the seam error.
double worst_seam_px(const Rig& est, const Rig& truth, int a, int b, int* samples) {
  const CameraCanvasMap ma = camera_canvas_map(est, a), mb = camera_canvas_map(est, b);
  const Camera &A = truth.cameras[a], &B = truth.cameras[b];
  double worst = 0;
  int n = 0;
  for (double y = 2; y < A.height - 2; y += 4)
    for (double x = 2; x < A.width - 2; x += 4) {
      if (!lens_sees(A, x, y)) continue;
      Eigen::Vector3d ray;
      Eigen::Vector2d qb;
      if (!lens_unproject(A, {x, y}, ray)) continue;
      if (!lens_project(B, B.R().transpose() * (A.R() * ray), qb) || !lens_sees(B, qb.x(), qb.y())) continue;
      Eigen::Vector2d ca, cb;
      if (!ma.to_canvas({x, y}, ca) || !mb.to_canvas(qb, cb)) continue;
      double dx = ca.x() - cb.x();
      if (est.canvas_wrap) dx -= std::round(dx / est.canvas_width) * est.canvas_width;
      // Near the poles a canvas row is one point: measure on the sphere, in canvas pixels.
      const double lat = (0.5 * (ca.y() + cb.y()) - est.canvas_origin_y) / est.canvas_scale;
      worst = std::max(worst, std::hypot(dx * std::cos(lat), ca.y() - cb.y()));
      ++n;
    }
  if (samples) *samples = n;
  return worst;
}

cv::Mat equirect_photo(std::string& name) {
  const std::string jobsite = testdata::shared_path("images/equirect_jobsite/jobsite1.jpg");
  cv::Mat p = jobsite.empty() ? cv::Mat() : testdata::load_rgba(jobsite);
  name = "equirect_jobsite";
  if (p.empty()) {
    p = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
    name = "boat1_1600 (no ../shared)";
  } else {
    cv::resize(p, p, cv::Size(2688, 1344), 0, 0, cv::INTER_AREA);  // still finer than the cameras
  }
  return p;
}

// Each camera of `truth` rendered from the equirectangular photo.
void render_views(const cv::Mat& photo, const Rig& truth, std::vector<cv::Mat>& frames, std::vector<ImageView>& views) {
  for (const auto& c : truth.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
  for (auto& f : frames) views.push_back(as_view(f));
}

}  // namespace

TEST(DualFisheye, CalibratedFromARoughRigSeamsWithinAPixel) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  struct Case {
    double fov, k1;
    unsigned seed;
  };
  const Case cases[] = {{190, 0.0, 1}, {200, -0.02, 2}, {210, 0.0, 3}, {220, 0.01, 4}};
  double worst_all = 0, worst_rough = 1e9;
  for (const Case& cs : cases) {
    const Rig truth = testdata::dual_fisheye_rig(480, cs.fov, 0, cs.k1);
    std::vector<cv::Mat> frames;
    std::vector<ImageView> views;
    render_views(photo, truth, frames, views);
    Rig rough = testdata::rough_sphere(truth, cs.seed);
    Rig rough_laid = rough;
    rig_layout_canvas(rough_laid);
    int n_rough = 0;
    const double rough_err = worst_seam_px(rough_laid, truth, 0, 1, &n_rough);
    const CalibrationResult r = calibrate_from_rig(rough, views, CalibrationOptions{});
    int n = 0;
    const double err = worst_seam_px(r.rig, truth, 0, 1, &n);
    // The full sphere: 2:1, wraps, and every pixel covered (both poles included).
    const cv::Mat pano = testdata::compose_cpu(r.rig, frames);
    cv::Mat gray;
    cv::cvtColor(pano(cv::Rect(0, 0, r.rig.canvas_width, r.rig.canvas_height)), gray, cv::COLOR_RGBA2GRAY);
    const int black = int(gray.total()) - cv::countNonZero(gray > 2);
    const double top = cv::mean(gray.row(0))[0], bottom = cv::mean(gray.row(gray.rows - 1))[0];
    // Coverage from the geometry, not the pixels (the photo's nadir is black itself): every canvas
    // pixel is inside some camera's image circle; pole rows counted apart.
    int uncovered = 0, pole_uncovered = 0;
    {
      std::vector<CameraCanvasMap> maps;
      for (int i = 0; i < int(r.rig.cameras.size()); ++i) maps.push_back(camera_canvas_map(r.rig, i));
      for (int y = 0; y < r.rig.canvas_height; ++y)
        for (int x = 0; x < r.rig.canvas_width; ++x) {
          bool seen = false;
          for (int i = 0; i < int(maps.size()) && !seen; ++i) {
            Eigen::Vector2d px;
            seen = maps[i].to_camera({double(x), double(y)}, px) && lens_sees(r.rig.cameras[i], px.x(), px.y());
          }
          if (!seen) ++uncovered, pole_uncovered += (y == 0 || y == r.rig.canvas_height - 1);
        }
    }
    std::printf("%s: dual fisheye %.0f deg k1 %+.2f seed %u, 2x 480x480 -> %dx%d: seam error rough %.2f px -> "
                "calibrated %.3f px (%d rays), BA rms %.3f px, black px %d, pole rows mean %.0f / %.0f, uncovered px %d (pole rows %d)\n",
                name.c_str(), cs.fov, cs.k1, cs.seed, r.rig.canvas_width, r.rig.canvas_height, rough_err, err, n,
                r.ba_rms_after_px, black, top, bottom, uncovered, pole_uncovered);
    for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
    EXPECT_EQ(r.rig.projection, "spherical");
    EXPECT_TRUE(r.rig.canvas_wrap);
    EXPECT_EQ(r.rig.canvas_width, 2 * r.rig.canvas_height);
    EXPECT_GT(n, 100);
    EXPECT_LE(err, 1.0) << cs.fov;
    EXPECT_EQ(uncovered, 0);
    EXPECT_EQ(pole_uncovered, 0);
    // Black output only where the photo itself is dark (its nadir): most of the canvas has content.
    EXPECT_LT(black, int(gray.total() / 100));
    EXPECT_GT(top, 5.0);
    worst_all = std::max(worst_all, err);
    worst_rough = std::min(worst_rough, rough_err);
  }
  std::printf("dual fisheye, worst calibrated seam error %.3f px (the rough rigs: >= %.2f px)\n", worst_all, worst_rough);
  RecordProperty("worst_seam_px", std::to_string(worst_all));
}

// The stitch with the true rig on the real photo: 2:1, every pixel covered (both poles), PSNR
// against the photo's own ground truth, for 190 and 220 degrees.
TEST(DualFisheye, TrueRigCoversTheWholeSphereOfTheRealPhoto) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  for (double fov : {190.0, 220.0}) {
    const Rig rig = testdata::dual_fisheye_rig(480, fov);
    std::vector<cv::Mat> frames;
    for (const auto& c : rig.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
    const cv::Mat pano = testdata::compose_cpu(rig, frames);
    const cv::Rect canvas(0, 0, rig.canvas_width, rig.canvas_height);
    cv::Mat gray, gt_gray;
    cv::cvtColor(pano(canvas), gray, cv::COLOR_RGBA2GRAY);
    const cv::Mat gt = testdata::equirect_ground_truth(photo, rig);
    cv::cvtColor(gt, gt_gray, cv::COLOR_RGBA2GRAY);
    const int black = cv::countNonZero((gray <= 2) & (gt_gray > 10));  // black where the photo is not
    cv::Mat all(gt.size(), CV_8U, cv::Scalar(255));
    const double psnr = testdata::masked_psnr_rgb(pano(canvas).clone(), gt, all);
    std::printf("%s: dual fisheye %.0f deg, 2x 480x480 -> %dx%d sphere: PSNR vs ground truth %.2f dB, black px %d\n",
                name.c_str(), fov, rig.canvas_width, rig.canvas_height, psnr, black);
    EXPECT_EQ(rig.canvas_width, 2 * rig.canvas_height);
    EXPECT_EQ(black, 0);
    EXPECT_GT(psnr, 24.0);
  }
}

// Fisheye coefficient estimation on the ray matches: the rough rig gives the fisheye model
// without coefficients ("estimate them"), the truth has k1 != 0 (or 0); focal / angles off as
// above. A back-to-back pair's matches lie in a ring near 90 degrees off both axes, where each
// camera's focal length and k1 trade off (per-camera lenses: k1 -0.03 came out +0.04 / -0.09).
// Two identical lenses share one bend (k1 times (half diagonal / f)^2; no k2), which the ring's shape pins down in some cases; the
// calibrator keeps it only when its standard error is small and otherwise declines (warning, k1
// kept). Either way: seams within a pixel when estimated, a sane rig when declined.
TEST(DualFisheye, EstimatesASharedK1FromTheOverlapRingOrDeclines) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  struct Case {
    double fov, k1;
    unsigned seed;
  };
  const Case cases[] = {{200, -0.03, 5}, {210, 0.02, 6}, {220, 0.01, 11}, {200, -0.02, 11}, {190, 0.0, 11}};
  int estimated = 0;
  double worst_est_seam = 0, worst_k1 = 0;
  for (const Case& cs : cases) {
    const Rig truth = testdata::dual_fisheye_rig(480, cs.fov, 0, cs.k1);
    std::vector<cv::Mat> frames;
    std::vector<ImageView> views;
    render_views(photo, truth, frames, views);
    Rig rough = testdata::rough_sphere(truth, cs.seed);
    for (auto& c : rough.cameras) {
      c.lens.k1 = c.lens.k2 = 0;
      c.lens.estimate = true;
    }
    Rig rough_laid = rough;
    rig_layout_canvas(rough_laid);
    const double rough_err = worst_seam_px(rough_laid, truth, 0, 1, nullptr);
    const CalibrationResult r = calibrate_from_rig(rough, views, CalibrationOptions{});
    int n = 0;
    const double err = worst_seam_px(r.rig, truth, 0, 1, &n);
    std::printf("%s: dual fisheye %.0f deg true k1 %+.3f f %.2f, seed %u: seam error rough (k1 0) %.2f px -> %.3f px "
                "(%d rays), estimated k1 %+.4f / %+.4f, k2 %+.4f / %+.4f, f %.2f / %.2f\n",
                name.c_str(), cs.fov, cs.k1, truth.cameras[0].fx, cs.seed, rough_err, err, n, r.rig.cameras[0].lens.k1,
                r.rig.cameras[1].lens.k1, r.rig.cameras[0].lens.k2, r.rig.cameras[1].lens.k2, r.rig.cameras[0].fx,
                r.rig.cameras[1].fx);
    bool told = false;
    for (const auto& w : r.warnings) {
      std::printf("  warning: %s\n", w.c_str());
      told |= w.find("too narrow to estimate the lens") != std::string::npos;
    }
    EXPECT_GT(n, 100);
    EXPECT_LT(err, 0.25 * rough_err) << cs.fov;
    for (int i = 0; i < 2; ++i) EXPECT_NEAR(r.rig.cameras[i].fx / truth.cameras[i].fx, 1.0, 0.15) << i;
    if (told) {
      // Declined: k1 kept, the unmodelled lens costs seam error (1.3-1.6 px measured).
      EXPECT_LE(err, 3.0) << cs.fov;
      for (int i = 0; i < 2; ++i) EXPECT_EQ(r.rig.cameras[i].lens.k1, 0.0) << i;
    } else {
      // Estimated (pinned, or loose with a warning): one k1 for both, close to the truth (within
      // 0.004, the check's floor, or 30 %), seams within a pixel.
      ++estimated;
      // (The shared unknown is the bend at the half diagonal, so k1 differs by the focal ratio.)
      EXPECT_NEAR(r.rig.cameras[0].lens.k1, r.rig.cameras[1].lens.k1, 0.03 * std::abs(r.rig.cameras[0].lens.k1) + 1e-4);
      EXPECT_LE(err, 1.0) << cs.fov;
      // Branch lens-dual: photometric matches through the lens map (unbiased, the whole ring) pin
      // it within 10 % (measured 0.3-3.5 % on both photos; keypoints alone: 11-22 %).
      const double dk = std::abs(r.rig.cameras[0].lens.k1 - cs.k1);
      EXPECT_LE(dk, std::max(0.001, 0.1 * std::abs(cs.k1))) << cs.fov;
      worst_est_seam = std::max(worst_est_seam, err);
      if (cs.k1 != 0) worst_k1 = std::max(worst_k1, dk / std::abs(cs.k1));
    }
  }
  std::printf("shared k1 estimated in %d of %zu cases: worst seam %.3f px, worst k1 error %.0f %%\n", estimated,
              std::size(cases), worst_est_seam, 100 * worst_k1);
  // The cases where the ring pins k1 down (measured: 4 of 5; 190 deg with k1 0 declines, at no
  // cost) must not regress to declining; their seams (0.01-0.06 px measured; 0.23 px from
  // keypoints alone) stay well under a pixel.
  EXPECT_GE(estimated, 4);
  EXPECT_LE(worst_est_seam, 0.15);
}

// Two back-to-back fisheyes of different frames (no identical lens to share one k1 with): the
// calibrator declines to estimate from the ring and says why.
TEST(DualFisheye, DeclinesWithoutAnIdenticalLens) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  Rig truth = testdata::dual_fisheye_rig(480, 200, 0, -0.02);
  Camera other = testdata::fisheye_camera(464, 200, -0.02);
  other.yaw_deg = 180;
  truth.cameras[1] = other;
  rig_layout_canvas(truth);
  std::vector<cv::Mat> frames;
  std::vector<ImageView> views;
  render_views(photo, truth, frames, views);
  Rig rough = testdata::rough_sphere(truth, 5);
  for (auto& c : rough.cameras) c.lens.k1 = c.lens.k2 = 0, c.lens.estimate = true;
  const CalibrationResult r = calibrate_from_rig(rough, views, CalibrationOptions{});
  bool told = false;
  for (const auto& w : r.warnings) told |= w.find("no identical lens") != std::string::npos;
  EXPECT_TRUE(told);
  for (int i = 0; i < 2; ++i) EXPECT_EQ(r.rig.cameras[i].lens.k1, 0.0) << i;
  EXPECT_LE(worst_seam_px(r.rig, truth, 0, 1, nullptr), 3.0);
}

// A ring of fisheyes (not back-to-back: the ray path's other use) calibrated from a rough rig:
// worst seam error over the neighbouring pairs.
TEST(FisheyeRing, CalibratedFromARoughRigSeamsWithinAPixel) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  for (const auto& [cams, fov] : {std::pair<int, double>{3, 180}, {4, 160}}) {
    const Rig truth = testdata::fisheye_ring(cams, 320, fov);
    std::vector<cv::Mat> frames;
    std::vector<ImageView> views;
    render_views(photo, truth, frames, views);
    Rig rough = testdata::rough_sphere(truth, 7 + cams);
    Rig rough_laid = rough;
    rig_layout_canvas(rough_laid);
    const CalibrationResult r = calibrate_from_rig(rough, views, CalibrationOptions{});
    double worst = 0, worst_rough = 0;
    int n_min = 1 << 30;
    for (int i = 0; i < cams; ++i) {
      int n = 0;
      worst = std::max(worst, worst_seam_px(r.rig, truth, i, (i + 1) % cams, &n));
      worst_rough = std::max(worst_rough, worst_seam_px(rough_laid, truth, i, (i + 1) % cams, nullptr));
      n_min = std::min(n_min, n);
    }
    std::printf("%s: fisheye ring %d x %.0f deg 320x320: worst neighbour seam error rough %.2f px -> %.3f px "
                "(>= %d rays a pair), BA rms %.3f px\n",
                name.c_str(), cams, fov, worst_rough, worst, n_min, r.ba_rms_after_px);
    for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
    EXPECT_GT(n_min, 100);
    EXPECT_LE(worst, 1.0) << cams;
  }
}

// Straight lines straight on a rendered radtan rig (issue 15): the ground truth's long edges
// (rectilinear views at the seams and centres) found again in the panorama composed through the
// true lenses, and in the one composed with the lenses ignored. The measure must tell them
// apart: with the lenses the edges stay where the truth has them and bend no more than it;
// ignoring them (an undistortion that broke) shifts and bends them.
TEST(LensLines, RadtanRigKeepsTheGroundTruthsEdges) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  Rig truth = testdata::radtan_trio(320, 240, 260, 35, -0.35, 0.1225, true, "spherical");
  rig_layout_canvas(truth);
  Rig ignored = truth;
  for (auto& c : ignored.cameras) c.lens = Lens{};
  std::vector<cv::Mat> frames;
  std::vector<ImageView> views;
  render_views(photo, truth, frames, views);
  const cv::Mat gt = testdata::equirect_ground_truth(photo, truth);
  auto lines_of = [&](const Rig& rig, double& shift, double& bend, int& lines) {
    const cv::Mat pano = testdata::compose_cpu(rig, frames);
    shift = bend = 0, lines = 0;
    const int w = int(std::lround(2 * rig.canvas_scale * std::tan(30.0 * CV_PI / 180)));
    for (double yaw : {-35.0, -17.5, 0.0, 17.5, 35.0}) {
      const testdata::LineComparison c = testdata::compare_lines(testdata::rectilinear_view(gt, rig, yaw, 0, 60, w, w * 3 / 4),
                                                                 testdata::rectilinear_view(pano, rig, yaw, 0, 60, w, w * 3 / 4), 40);
      if (c.lines == 0) continue;
      lines += c.lines;
      shift = std::max(shift, c.median_shift_px), bend = std::max(bend, c.median_bend_px);
    }
  };
  double s_on, b_on, s_off, b_off;
  int n_on, n_off;
  lines_of(truth, s_on, b_on, n_on);
  lines_of(ignored, s_off, b_off, n_off);
  std::printf("%s: radtan k1 -0.35 trio, ground-truth edges (worst view's median): with the lenses shift %.2f px, extra "
              "bend %.2f px (%d lines); lenses ignored shift %.2f px, bend %.2f px (%d lines)\n",
              name.c_str(), s_on, b_on, n_on, s_off, b_off, n_off);
  ASSERT_GE(n_on, 10);
  EXPECT_LT(s_on, 0.5);
  EXPECT_LT(b_on, 0.5);
  EXPECT_GT(s_off, 3 * s_on);
  EXPECT_GT(b_off, 2 * b_on);
}

// A ring calibrated from the images: every camera a fisheye, and the worst seam against the truth
// between ring neighbours (px).
static double ring_worst_seam(const Rig& calibrated, const Rig& truth, const std::string& what) {
  const int cams = int(truth.cameras.size());
  double err = 0;
  for (int i = 0; i < cams; ++i) {
    EXPECT_EQ(calibrated.cameras[i].lens.model, Lens::Model::Fisheye) << what << " camera " << i;
    err = std::max(err, worst_seam_px(calibrated, truth, i, (i + 1) % cams, nullptr));
  }
  return err;
}

// No rig file at all (issue 15: 360 without a hand-written rig): frames that show an image circle
// on black are taken as circular fisheyes, two back to back or N in a ring, and calibrated from
// that guess over a few fields of view. The circle is found within 3 % of the lens's, the seams
// within a pixel, on a 2:1 sphere; a rectilinear frame or a dark one shows no circle.
TEST(CircularFisheyes, FoundAndCalibratedFromTheImagesAlone) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  struct Case {
    int cams;
    double fov;
  };
  double worst = 0;
  for (const Case cs : {Case{2, 190}, Case{2, 220}, Case{4, 190}}) {
    const Rig truth = cs.cams == 2 ? testdata::dual_fisheye_rig(480, cs.fov) : testdata::fisheye_ring(cs.cams, 320, cs.fov);
    std::vector<cv::Mat> frames;
    std::vector<ImageView> views;
    render_views(photo, truth, frames, views);
    for (int i = 0; i < cs.cams; ++i) {
      const std::optional<LensCircle> circle = find_image_circle(views[i]);
      ASSERT_TRUE(circle) << "camera " << i;
      const Camera& c = truth.cameras[i];
      const double radius = c.lens.circle ? c.lens.circle->radius : 0.5 * std::min(c.width, c.height);
      EXPECT_NEAR(circle->radius, radius, 0.03 * radius);
      EXPECT_NEAR(circle->cx, c.cx, 0.01 * radius);
      EXPECT_NEAR(circle->cy, c.cy, 0.01 * radius);
    }
    const CalibrationResult r = calibrate_from_images(views, 0, CalibrationOptions{});
    ASSERT_EQ(r.rig.cameras.size(), std::size_t(cs.cams));
    EXPECT_EQ(r.rig.projection, "spherical");
    EXPECT_EQ(r.rig.canvas_width, 2 * r.rig.canvas_height);
    bool said = false;
    bool reordered = false;
    for (const auto& w : r.warnings) {
      said |= w.find("image circle") != std::string::npos;
      reordered |= w.find("not in ring order") != std::string::npos;
    }
    EXPECT_TRUE(said);
    EXPECT_FALSE(reordered) << "pads in ring order are kept in it";
    const double err = ring_worst_seam(r.rig, truth, std::to_string(cs.cams) + " x " + std::to_string(cs.fov));
    std::printf("%s: %d circular fisheyes of %.0f deg, no rig file: worst seam error %.3f px\n", name.c_str(), cs.cams,
                cs.fov, err);
    for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
    EXPECT_LE(err, 1.0) << cs.cams << " x " << cs.fov;
    worst = std::max(worst, err);
  }
  RecordProperty("worst_seam_px", std::to_string(worst));
  // A rectilinear frame (the photo itself) and a black one show no image circle.
  cv::Mat flat = photo(cv::Rect(0, photo.rows / 4, photo.rows / 2, photo.rows / 2)).clone();
  EXPECT_FALSE(find_image_circle(as_view(flat)));
  cv::Mat black(480, 480, CV_8UC4, cv::Scalar(0, 0, 0, 255));
  EXPECT_FALSE(find_image_circle(as_view(black)));
}

// The full sphere is exactly 2:1 on the output too (branch probe360): the canvas width was even,
// its half (the height) odd for about half of all lenses (a dual 210-degree fisheye of 640 px:
// 1094x547), and the panorama, always even-sized, came out 1094x548: no longer 2:1, the bottom
// row padding. Over fields of view and frame sizes: canvas and default output both 2:1, even.
TEST(DualFisheye, FullSphereCanvasAndOutputAreExactly2To1) {
  int cases = 0;
  for (int size : {480, 500, 640, 641, 700, 960})
    for (double fov = 185; fov <= 225; fov += 2.5) {
      const Rig rig = testdata::dual_fisheye_rig(size, fov);
      ASSERT_TRUE(rig.canvas_wrap) << size << " " << fov;
      EXPECT_EQ(rig.canvas_width, 2 * rig.canvas_height) << size << " px, " << fov << " deg";
      EXPECT_EQ(rig.canvas_height % 2, 0) << size << " px, " << fov << " deg";
      const OutputGeometry g = plan_output(rig, 0, 0, CropMode::None);
      EXPECT_EQ(g.width, 2 * g.height) << size << " px, " << fov << " deg: " << g.width << "x" << g.height;
      EXPECT_EQ(g.width, rig.canvas_width) << size << " px, " << fov << " deg";
      ++cases;
    }
  std::printf("%d dual-fisheye rigs (6 sizes x 17 fields of view): canvas and output 2:1, even\n", cases);
}

// The independent check (measure_alignment: what stitchcalib's load-file check and its
// recalibration judge use) on a dual fisheye (branch probe360): its epipolar RANSAC ran on ideal
// pinhole pixels, which a back-to-back overlap (80-100 degrees off both axes) does not have, so
// the exact rig read 400-800 px misaligned and load-file warned "does not fit the images". Wide
// lenses on a curved canvas now take the matches one rotation of their rays explains: the exact
// rig reads within a pixel, a rig 2 degrees off reads clearly worse.
TEST(DualFisheye, IndependentCheckReadsTheExactRigAligned) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  for (const double fov : {190.0, 200.0, 220.0}) {
    const Rig truth = testdata::dual_fisheye_rig(480, fov);
    std::vector<cv::Mat> frames;
    std::vector<ImageView> views;
    render_views(photo, truth, frames, views);
    const AlignmentReport exact = measure_alignment(truth, views);
    Rig off = truth;
    off.cameras[1].yaw_deg += 2.0;
    off.cameras[1].pitch_deg += 1.0;
    const AlignmentReport moved = measure_alignment(off, views);
    std::printf("%s: dual fisheye %.0f deg: exact rig %.3f px (%d matches), 2 deg off %.3f px (%d matches)\n",
                name.c_str(), fov, exact.median_px, exact.matches, moved.median_px, moved.matches);
    EXPECT_GE(exact.matches, 10) << fov;
    EXPECT_GE(exact.median_px, 0) << fov;
    EXPECT_LT(exact.median_px, 1.0) << fov;
    EXPECT_GT(moved.median_px, 3.0) << fov;
  }
}

// The image circle where the scene is dark at the rim (branch probe360): a 360 photo's black
// nadir cuts the bottom of a horizontal fisheye's lit disc, and the enclosing circle of what is
// lit moved up with the cut: 1.25 px on a 200-degree fisheye of 640 px, the principal point with
// it (circular_fisheye_rig), ~1 px seams (PSNR 23.4 dB against 29.2 with the true rig). The
// rim's arc is fitted instead: the centre within 0.3 px, with and without the dark cut.
TEST(CircularFisheyes, ImageCircleCentreHoldsWhenTheRimIsDark) {
  std::string name;
  cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  double worst = 0;
  for (const bool dark : {false, true}) {
    cv::Mat p = photo.clone();
    if (dark) p(cv::Rect(0, p.rows * 82 / 100, p.cols, p.rows - p.rows * 82 / 100)).setTo(cv::Scalar(0, 0, 0, 255));
    for (const double fov : {190.0, 200.0, 220.0})
      for (const int size : {480, 640}) {
        const Rig truth = testdata::dual_fisheye_rig(size, fov);
        for (const auto& c : truth.cameras) {
          cv::Mat frame = testdata::render_camera_from_equirect(p, c);
          const std::optional<LensCircle> circle = find_image_circle(as_view(frame));
          ASSERT_TRUE(circle) << fov << " " << size << (dark ? " dark" : "");
          const double off = std::hypot(circle->cx - c.lens.circle->cx, circle->cy - c.lens.circle->cy);
          worst = std::max(worst, off);
          EXPECT_LT(off, 0.3) << fov << " deg, " << size << " px" << (dark ? ", dark rim" : "") << ": centre ("
                              << circle->cx << ", " << circle->cy << ") vs (" << c.lens.circle->cx << ", "
                              << c.lens.circle->cy << ")";
          EXPECT_NEAR(circle->radius, 0.98 * c.lens.circle->radius, 0.015 * c.lens.circle->radius);
        }
      }
  }
  std::printf("%s: image circle centre worst %.3f px off (dual fisheyes 190-220 deg, 480/640 px, dark rim or not)\n",
              name.c_str(), worst);
}

// Rings of narrower circular fisheyes (branch probe360): 4 x 150 and 6 x 130 degrees cover the
// circle, but the field-of-view guesses were 185-225 degrees only, which put the focal lengths
// 25-45 % off; every fisheye fit failed and the calibration silently fell back to pinhole cameras
// (a panorama of undistorted discs, 43 px misaligned, 34 % holes, no warning). Now: found as
// fisheyes, seams within a pixel; and a ring whose circles no fisheye rig fits is said so.
TEST(CircularFisheyes, NarrowLensRingsFoundFromTheImagesAlone) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  struct Case {
    int cams;
    double fov;
  };
  double worst = 0;
  for (const Case cs : {Case{4, 150}, Case{6, 130}, Case{6, 120}}) {
    const Rig truth = testdata::fisheye_ring(cs.cams, 320, cs.fov);
    std::vector<cv::Mat> frames;
    std::vector<ImageView> views;
    render_views(photo, truth, frames, views);
    CalibrationResult r;
    ASSERT_NO_THROW(r = calibrate_from_images(views, 0, CalibrationOptions{})) << cs.cams << " x " << cs.fov;
    ASSERT_EQ(r.rig.cameras.size(), std::size_t(cs.cams));
    bool said = false;
    for (const auto& w : r.warnings) said |= w.find("image circle") != std::string::npos;
    EXPECT_TRUE(said) << cs.cams << " x " << cs.fov;
    EXPECT_EQ(r.rig.projection, "spherical") << cs.cams << " x " << cs.fov;
    EXPECT_TRUE(r.rig.canvas_wrap) << cs.cams << " x " << cs.fov;
    const double err = ring_worst_seam(r.rig, truth, std::to_string(cs.cams) + " x " + std::to_string(cs.fov));
    std::printf("%s: ring of %d circular fisheyes of %.0f deg, no rig file: worst seam error %.3f px\n", name.c_str(),
                cs.cams, cs.fov, err);
    for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
    EXPECT_LE(err, 1.0) << cs.cams << " x " << cs.fov;
    worst = std::max(worst, err);
  }
  RecordProperty("worst_seam_px", std::to_string(worst));
}

// A ring whose circles no fisheye rig fits (3 x 125 degrees: below the guesses, 5 degrees of
// overlap a pair) is never handed back silently as pinhole cameras: either an error or a warning
// names the image circles (branch probe360: the pinhole fallback said nothing).
TEST(CircularFisheyes, RingNoFisheyeRigFitsIsSaid) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  const Rig truth = testdata::fisheye_ring(3, 320, 125);
  std::vector<cv::Mat> frames;
  std::vector<ImageView> views;
  render_views(photo, truth, frames, views);
  try {
    const CalibrationResult r = calibrate_from_images(views, 0, CalibrationOptions{});
    bool fisheye = true, said = false;
    for (const auto& c : r.rig.cameras) fisheye &= c.lens.model == Lens::Model::Fisheye;
    for (const auto& w : r.warnings) said |= w.find("image circle") != std::string::npos;
    std::printf("%s: 3 x 125 deg: calibrated (%s), %s\n", name.c_str(), fisheye ? "fisheyes" : "pinhole",
                said ? "said" : "SILENT");
    for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
    EXPECT_TRUE(said);
  } catch (const RigError& e) {
    std::printf("%s: 3 x 125 deg: error: %s\n", name.c_str(), e.what());
    EXPECT_NE(std::string(e.what()).find("image circles"), std::string::npos) << e.what();
  }
}

// Users connect a 360 ring's pads in any order (branch lens-radtan): the ring order comes from
// the images (which pairs share features, on which side), not from the pad order. Rings of 3-10
// circular fisheyes rendered from the real photo, their pads shuffled (mirror orders, camera 0
// moved, neighbours swapped), calibrated with no rig file: every pair of views meets within a
// pixel on the canvas, and the warning says the pads were reordered. Before, a shuffled ring
// either failed to calibrate or kept the rough yaw of cameras that matched no neighbour.
TEST(CircularFisheyes, RingOrderFoundFromTheImagesWhenPadsAreShuffled) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  struct Case {
    int cams;
    double fov;
    std::vector<int> pads;  // pad i shows the true ring's camera pads[i]
  };
  const Case cases[] = {{4, 190, {0, 2, 1, 3}}, {4, 190, {0, 3, 2, 1}}, {3, 200, {0, 2, 1}},
                        {5, 185, {3, 0, 4, 1, 2}}, {6, 190, {0, 3, 1, 5, 2, 4}},
                        {10, 185, {0, 7, 3, 9, 1, 5, 8, 2, 6, 4}}};
  double worst = 0;
  for (const Case& cs : cases) {
    const Rig ring = testdata::fisheye_ring(cs.cams, 320, cs.fov);
    Rig truth = ring;
    for (int i = 0; i < cs.cams; ++i) truth.cameras[i] = ring.cameras[cs.pads[i]];
    std::vector<cv::Mat> frames;
    std::vector<ImageView> views;
    render_views(photo, truth, frames, views);
    CalibrationResult r;
    const auto t0 = std::chrono::steady_clock::now();
    ASSERT_NO_THROW(r = calibrate_from_images(views, 0, CalibrationOptions{})) << cs.cams << " x " << cs.fov;
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    ASSERT_EQ(r.rig.cameras.size(), std::size_t(cs.cams));
    EXPECT_EQ(r.rig.projection, "spherical");
    bool said = false;
    for (const auto& w : r.warnings) said |= w.find("not in ring order") != std::string::npos;
    EXPECT_TRUE(said) << cs.cams << " x " << cs.fov;
    double err = 0;
    int pairs = 0;
    for (int a = 0; a < cs.cams; ++a)
      for (int b = a + 1; b < cs.cams; ++b) {
        int samples = 0;
        const double e = worst_seam_px(r.rig, truth, a, b, &samples);
        if (samples < 20) continue;
        err = std::max(err, e);
        ++pairs;
      }
    std::printf("%s: ring of %d x %.0f deg, pads shuffled, no rig file: %d overlapping pairs, worst seam error %.3f px "
                "(calibrated in %.1f s)\n",
                name.c_str(), cs.cams, cs.fov, pairs, err, seconds);
    for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
    EXPECT_GE(pairs, cs.cams);
    EXPECT_LE(err, 1.0) << cs.cams << " x " << cs.fov;
    worst = std::max(worst, err);
  }
  RecordProperty("worst_seam_px", std::to_string(worst));
}

// Lens rigs on a plane canvas (branch lens-dual): a plane shows only rays less than 90 degrees off
// the reference camera's axis. A fisheye rig whose file names no projection gets the canvas its
// views need, with a warning naming each camera; one that asks for the plane keeps it, warned.
namespace {
std::string without_projection(const Rig& rig) {
  std::string json = rig_to_json_string(rig);
  const std::size_t at = json.find("\"projection\"");
  const std::size_t end = json.find(',', at);
  json.erase(at, end + 1 - at);
  return json;
}
bool names(const std::vector<std::string>& warnings, const std::string& what, const std::string& also) {
  for (const auto& w : warnings)
    if (w.find(what) != std::string::npos && w.find(also) != std::string::npos) return true;
  return false;
}
}  // namespace

TEST(PlaneCanvas, FisheyeViewsBeyondThePlaneAreNamedAndGetACurvedCanvas) {
  Rig dual = testdata::dual_fisheye_rig(480, 200, 0, -0.02);
  dual.projection = "plane";
  dual.canvas_width = dual.canvas_height = 0, dual.canvas_scale = 0, dual.canvas_wrap = false;
  const Rig loaded = rig_from_json_string(without_projection(dual));
  EXPECT_TRUE(loaded.projection_default);
  EXPECT_EQ(loaded.projection, "plane");
  EXPECT_FALSE(rig_from_json_string(rig_to_json_string(dual)).projection_default);
  const PlaneCanvasCheck pc = check_plane_canvas(loaded);
  EXPECT_EQ(pc.projection, "spherical");
  ASSERT_EQ(pc.problems.size(), 2u);
  EXPECT_NE(pc.problems[0].find("camera 0 (fisheye, 200 degrees across)"), std::string::npos) << pc.problems[0];
  EXPECT_NE(pc.problems[1].find("camera 1"), std::string::npos);
  EXPECT_NE(pc.problems[1].find("cannot show"), std::string::npos);
  EXPECT_NEAR(pc.worst_off_deg, 180, 1e-9);  // the back camera holds the point opposite the front axis
  EXPECT_NE(pc.problems[0].find("100 degrees off"), std::string::npos) << pc.problems[0];
  // A fisheye of 160 degrees alone (80 off its axis, the reference's): stretched 41x, named.
  Rig one = dual;
  one.cameras.resize(1);
  one.cameras[0] = testdata::fisheye_camera(480, 160);
  const PlaneCanvasCheck p1 = check_plane_canvas(one);
  ASSERT_EQ(p1.problems.size(), 1u);
  EXPECT_NE(p1.problems[0].find("stretches them"), std::string::npos) << p1.problems[0];
  // A wide radtan trio spanning 2 x 88 degrees on the horizon: cylindrical.
  Rig wide = testdata::radtan_trio(320, 240, 260, 50, -0.1, 0.01, true, "plane", 0.0);
  const PlaneCanvasCheck pw = check_plane_canvas(wide);
  EXPECT_EQ(pw.projection, "cylindrical");
  EXPECT_EQ(pw.problems.size(), 2u);  // the side cameras, not the reference
  // What a plane shows well: nothing to say. A narrow radtan trio, a pinhole rig however wide,
  // and a rig given by homographies (the surround view's ground plane) are left alone.
  EXPECT_TRUE(check_plane_canvas(testdata::radtan_trio(320, 240, 260, 35, -0.2, 0.04, true, "plane")).problems.empty());
  EXPECT_TRUE(check_plane_canvas(testdata::radtan_trio(320, 240, 260, 50, 0, 0, false, "plane")).problems.empty());
  Rig given = wide;
  for (auto& c : given.cameras) c.homography = Eigen::Matrix3d::Identity();
  EXPECT_TRUE(check_plane_canvas(given).problems.empty());
  EXPECT_TRUE(check_plane_canvas(testdata::dual_fisheye_rig(480, 200)).problems.empty());  // spherical already
}

TEST(PlaneCanvas, DualFisheyeWithoutAProjectionIsCalibratedOnASphere) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  const Rig truth = testdata::dual_fisheye_rig(480, 200, 0, -0.02);
  std::vector<cv::Mat> frames;
  std::vector<ImageView> views;
  render_views(photo, truth, frames, views);
  Rig rough = testdata::rough_sphere(truth, 11);
  rough.projection = "plane";
  for (auto& c : rough.cameras) c.homography.reset();
  // The default (no "projection" in the file): a spherical canvas, said so, calibrated as one.
  const Rig from_file = rig_from_json_string(without_projection(rough));
  const CalibrationResult r = calibrate_from_rig(from_file, views, CalibrationOptions{});
  for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
  EXPECT_EQ(r.rig.projection, "spherical");
  EXPECT_TRUE(r.projection_chosen);
  EXPECT_TRUE(names(r.warnings, "camera 1 (fisheye", "using a spherical canvas"));
  EXPECT_LE(worst_seam_px(r.rig, truth, 0, 1, nullptr), 1.0);
  // Asked for explicitly (the file, or the element's projection): the plane stays, with the warning.
  const CalibrationResult p = calibrate_from_rig(rough, views, CalibrationOptions{});
  EXPECT_EQ(p.rig.projection, "plane");
  EXPECT_TRUE(names(p.warnings, "camera 1 (fisheye", "use projection spherical"));
  CalibrationOptions plane;
  plane.projection = Projection::Plane;
  const CalibrationResult q = calibrate_from_rig(from_file, views, plane);
  EXPECT_EQ(q.rig.projection, "plane");
  EXPECT_TRUE(names(q.warnings, "camera 0 (fisheye", "cannot show them"));
}


// Full-frame fisheyes (action cameras; branch probe-lens): no image circle, 140-150 degrees
// across a 16:9 frame. The pinhole path folded ("degenerate homography": no panorama) or bent
// them (a row of 3 x 140 degrees: 40-130 px seams, pinhole, no word). Now rotations are read
// from matched rays through a guessed equidistant lens and the lenses estimated: a ring of 4 and
// a row of 3 (pads out of order) within a pixel, said in a warning.
namespace {
Rig full_frame_fisheye_ring(int n, int width, int height, double hfov_deg) {
  Rig rig;
  rig.projection = "spherical";
  for (int i = 0; i < n; ++i) {
    Camera c;
    c.width = width;
    c.height = height;
    c.cx = 0.5 * (width - 1);
    c.cy = 0.5 * (height - 1);
    c.fx = c.fy = 0.5 * width / (0.5 * hfov_deg * CV_PI / 180.0);
    c.lens.model = Lens::Model::Fisheye;
    c.lens.k1 = -0.02;
    c.lens.k2 = 0.001;
    c.yaw_deg = 360.0 * i / n;
    if (c.yaw_deg > 180) c.yaw_deg -= 360;
    rig.cameras.push_back(c);
  }
  rig.reference = 0;
  return rig;
}
}  // namespace

TEST(FullFrameFisheyes, ActionCameraRingAndRowFromTheImagesAlone) {
  std::string name;
  const cv::Mat photo = equirect_photo(name);
  ASSERT_FALSE(photo.empty());
  struct Case {
    int ring;                // cameras around the full circle
    double hfov;             // degrees across the frame's width
    std::vector<int> pads;   // the ring's cameras fed, in this pad order
    bool wraps;
  };
  const Case cases[] = {{4, 148, {0, 1, 2, 3}, true}, {5, 140, {1, 0, 2}, false}};
  double worst = 0;
  for (const Case& cs : cases) {
    const Rig ring = full_frame_fisheye_ring(cs.ring, 384, 216, cs.hfov);
    Rig truth = ring;
    truth.cameras.clear();
    for (const int k : cs.pads) truth.cameras.push_back(ring.cameras[std::size_t(k)]);
    std::vector<cv::Mat> frames;
    std::vector<ImageView> views;
    render_views(photo, truth, frames, views);
    const std::string what = std::to_string(cs.pads.size()) + " x " + std::to_string(int(cs.hfov)) + " deg";
    CalibrationResult r;
    ASSERT_NO_THROW(r = calibrate_from_images(views, 0, CalibrationOptions{})) << what;
    ASSERT_EQ(r.rig.cameras.size(), truth.cameras.size());
    bool said = false;
    for (const auto& w : r.warnings) said |= w.find("full-frame fisheye") != std::string::npos;
    EXPECT_TRUE(said) << what;
    EXPECT_EQ(r.rig.canvas_wrap, cs.wraps) << what;
    double err = 0;
    const int n = int(truth.cameras.size());
    for (int a = 0; a < n; ++a) {
      EXPECT_EQ(r.rig.cameras[std::size_t(a)].lens.model, Lens::Model::Fisheye) << what << " camera " << a;
      for (int b = a + 1; b < n; ++b) {
        int samples = 0;
        const double e = worst_seam_px(r.rig, truth, a, b, &samples);
        if (samples > 50) err = std::max(err, e);  // pairs that truly overlap
      }
    }
    std::printf("%s: %s full-frame fisheyes, no rig file: worst seam error %.3f px\n", name.c_str(), what.c_str(), err);
    for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
    std::printf("  projection %s, model %d, held out rotation %.3f / homography %.3f px, fx %.1f (true %.1f), lens %d\n",
                r.rig.projection.c_str(), int(r.model), r.rotation_heldout_px, r.homography_heldout_px,
                r.rig.cameras[0].fx, truth.cameras[0].fx, int(r.rig.cameras[0].lens.model));
    EXPECT_LE(err, 1.0) << what;
    worst = std::max(worst, err);
  }
  RecordProperty("worst_seam_px", std::to_string(worst));
}
