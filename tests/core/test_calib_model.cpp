// Camera model selection (issue 14): the rotation model by default on rotating rigs (planar
// canvas included), a free homography per camera on a planar scene seen by translating cameras,
// calibration from the images alone for every projection (focal lengths, rotations, ring
// closure, projection choice), and bad input that keeps the rough rig with a warning.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cstdio>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <filesystem>

#include "ring_rig.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "synthetic_rig.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

constexpr double kPi = 3.14159265358979323846;

cv::Mat photo() {
  static cv::Mat p = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  return p;
}

// Camera c sees the photo (a plane) through camera pixel -> photo pixel homography H[c].
std::vector<cv::Mat> render_views(const cv::Mat& scene, const std::vector<Eigen::Matrix3d>& H, int w, int h) {
  std::vector<cv::Mat> out;
  for (const auto& e : H) {
    cv::Mat m(3, 3, CV_64F);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) m.at<double>(r, c) = e(r, c);
    cv::Mat v;
    cv::warpPerspective(scene, v, m, cv::Size(w, h), cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_REFLECT);
    out.push_back(v);
  }
  return out;
}

std::vector<ImageView> views_of(std::vector<cv::Mat>& frames) {
  std::vector<ImageView> v;
  for (auto& f : frames) v.push_back(as_view(f));
  return v;
}

// A rotating rig looking at the photo from its centre: the example (3 x 640x480, 40
// degrees apart, 60-degree lenses, pitch and roll of a degree).
struct RotatingScene {
  Rig truth;
  std::vector<cv::Mat> frames;
};

RotatingScene rotating_scene(int n, double step_deg, int w = 640, int h = 480, double hfov = 60) {
  RotatingScene s;
  s.truth.reference = n / 2;
  const double f = w / 2.0 / std::tan(hfov * kPi / 360);
  for (int i = 0; i < n; ++i) {
    Camera c = testdata::pinhole(w, h, f);
    c.yaw_deg = (i - (n - 1) / 2.0) * step_deg;
    c.pitch_deg = 0.8 * std::sin(2.1 * i + 0.4);
    c.roll_deg = 0.8 * std::cos(1.3 * i);
    s.truth.cameras.push_back(c);
  }
  const cv::Mat p = photo();
  const double span = std::tan(((n - 1) * step_deg / 2 + hfov / 2) * kPi / 180);
  const double fp = 0.48 * p.cols / span;
  Eigen::Matrix3d Kp;
  Kp << fp, 0, (p.cols - 1) * 0.5, 0, fp, (p.rows - 1) * 0.5, 0, 0, 1;
  std::vector<Eigen::Matrix3d> H;
  for (const auto& c : s.truth.cameras) H.push_back(Kp * c.R() * c.K().inverse());
  s.frames = render_views(p, H, w, h);
  return s;
}

// The rough rig of the issue: focal +-5%, yaw +-3 degrees, pitch/roll +-1.5 degrees.
Rig rough_of(const Rig& truth) {
  Rig r = truth;
  for (std::size_t i = 0; i < r.cameras.size(); ++i) {
    Camera& c = r.cameras[i];
    c.fx = c.fy = c.fx * (1 + 0.05 * std::cos(1.7 * i + 0.2));
    c.yaw_deg += 3.0 * std::sin(2.3 * i + 1.1);
    c.pitch_deg += 1.5 * std::cos(0.7 * i + 0.5);
    c.roll_deg += 1.5 * std::sin(1.9 * i);
    c.homography.reset();
  }
  return r;
}

// Mean distance, in camera pixels, between where the true and the estimated calibrations send
// each non-reference camera's corners (through the reference camera and back).
double corner_error_camera_px(const Rig& est, const Rig& truth) {
  const int ref = truth.reference;
  double sum = 0;
  int count = 0;
  for (std::size_t i = 0; i < truth.cameras.size(); ++i) {
    if (int(i) == ref) continue;
    const Camera &c = truth.cameras[i], &r = truth.cameras[ref];
    const Eigen::Matrix3d T = r.K() * r.R().transpose() * c.R() * c.K().inverse();
    Eigen::Matrix3d E;
    if (est.planar()) {
      E = est.cameras[est.reference].homography->inverse() * *est.cameras[i].homography;
    } else {
      const Camera &ec = est.cameras[i], &er = est.cameras[est.reference];
      E = er.K() * er.R().transpose() * ec.R() * ec.K().inverse();
    }
    // Estimated reference != truth reference is fine: compare through the truth's.
    if (est.reference != ref) {
      const Camera &er = est.cameras[est.reference], &tr = truth.cameras[est.reference];
      const Eigen::Matrix3d Tref = r.K() * r.R().transpose() * tr.R() * tr.K().inverse();
      E = Tref * E;  // est camera -> est reference (~ truth) -> truth reference
      (void)er;
    }
    const Eigen::Matrix3d back = T.inverse() * E;
    for (Eigen::Vector2d p : {Eigen::Vector2d(0, 0), Eigen::Vector2d(c.width - 1, 0),
                              Eigen::Vector2d(c.width - 1, c.height - 1), Eigen::Vector2d(0, c.height - 1)}) {
      sum += (apply_homography(back, p) - p).norm();
      ++count;
    }
  }
  return sum / count;
}

}  // namespace

TEST(CameraModel, RotatingRigOnAPlanarCanvasUsesTheRotationModelByDefault) {
  // 480x360 views of the 1600-pixel photo (640x480 magnifies it ~2x: blurrier features; the
  // 640x480 figure is in BENCHMARKS.md).
  RotatingScene s = rotating_scene(3, 40, 480, 360);
  const Rig rough = rough_of(s.truth);
  Rig rough_laid = rough;
  rig_compute_rough_homographies(rough_laid);
  auto views = views_of(s.frames);
  const CalibrationResult r = calibrate_from_rig(rough, views, CalibrationOptions{});
  CalibrationOptions forced;
  forced.model = CameraModel::Homography;
  const CalibrationResult h = calibrate_from_rig(rough, views, forced);
  const double e = corner_error_camera_px(r.rig, s.truth), eh = corner_error_camera_px(h.rig, s.truth);
  std::printf("FIGURE: 3 x 480x360, 40 deg apart, rough rig (%.1f px): default %s %.3f px, forced homography %.3f px; "
              "held-out rms rotation %.3f px, homography %.3f px (%d held out)\n",
              corner_error_camera_px(rough_laid, s.truth), camera_model_name(r.model), e, eh, r.rotation_heldout_px,
              r.homography_heldout_px, r.heldout_matches);
  for (std::size_t i = 0; i < 3; ++i)
    std::printf("  camera %zu: focal %.4f of the truth, yaw error %.3f deg\n", i, r.rig.cameras[i].fx / s.truth.cameras[i].fx,
                r.rig.cameras[i].yaw_deg - s.truth.cameras[i].yaw_deg);
  EXPECT_EQ(r.model, CameraModel::Rotation);
  EXPECT_TRUE(r.rig.planar());
  EXPECT_LE(e, 0.5);
  EXPECT_GT(r.heldout_matches, 50);
  EXPECT_GT(r.homography_heldout_px, 0);
  // The reports carry camera-pixel residuals: every pair, every camera.
  ASSERT_EQ(r.cameras.size(), 3u);
  for (const auto& c : r.cameras) {
    EXPECT_GT(c.matches, 0);
    EXPECT_GT(c.rms_px, 0);
    EXPECT_LT(c.rms_px, 1.0);
  }
  for (const auto& p : r.pairs)
    if (p.accepted) EXPECT_GT(p.rms_px, 0);
  // Forcing the homography model gives the old behaviour.
  EXPECT_EQ(h.model, CameraModel::Homography);
}

// A real clip (../shared, when present): two phones side by side in an office, near desks.
// With vid2 as camera 0 the free homographies explained the held-out matches better (0.89 vs
// 1.40 px on 10-40 matches; frames 1, 3 and 8 with vid1 first too) and gave a stretched plane
// that scales one camera 3.9x the other, 40% black; with vid1 first the rotation model won.
// Rotation now wins in both orders (the homography model may not scale a camera 2x another),
// and the panoramas are alike (the pads' order does not matter).
TEST(CameraModel, RealTwoPhoneClipGetsTheSamePanoramaInEitherPadOrder) {
  const char* shared = std::getenv("STITCH_SHARED_DATA");
  const std::string dir = std::string(shared ? shared : "") + "/video/karthik_2cam_office";
  if (!shared || !std::filesystem::exists(dir + "/vid1.mp4")) GTEST_SKIP() << "no shared data";
  std::vector<cv::Mat> frames;
  for (const char* name : {"vid1.mp4", "vid2.mp4"}) {
    cv::VideoCapture cap(dir + "/" + name);
    cv::Mat bgr, rgba;
    if (!cap.read(bgr)) GTEST_SKIP() << "cannot decode " << name;
    cv::cvtColor(bgr, rgba, cv::COLOR_BGR2RGBA);
    frames.push_back(rgba);
  }
  std::vector<std::pair<CameraModel, double>> got;
  for (int order = 0; order < 2; ++order) {
    std::vector<ImageView> views = {as_view(frames[std::size_t(order)]), as_view(frames[std::size_t(1 - order)])};
    const CalibrationResult r = calibrate_from_images(views, -1, CalibrationOptions{});
    std::printf("vid%d first: %s model, %s canvas %dx%d; held-out rotation %.3f px, homography %.3f px\n", order + 1,
                camera_model_name(r.model), r.rig.projection.c_str(), r.rig.canvas_width, r.rig.canvas_height,
                r.rotation_heldout_px, r.homography_heldout_px);
    EXPECT_EQ(r.model, CameraModel::Rotation) << "vid" << order + 1 << " first";
    got.push_back({r.model, double(r.rig.canvas_width) * r.rig.canvas_height});
  }
  EXPECT_NEAR(got[1].second / got[0].second, 1.0, 0.3) << "the panorama's size depends on the pad order";
}

TEST(CameraModel, PlanarSceneSeenByTranslatingCamerasUsesHomographies) {
  // A flat photo (a document, a wall) seen by three cameras that move along it, each slightly
  // turned: plane-induced homographies that no common centre explains.
  const cv::Mat p = photo();
  const int w = 480, h = 360;
  const double f = 420, d = 1.0;
  Eigen::Matrix3d Kp;
  const double fp = 0.9 * f;
  Kp << fp, 0, 360, 0, fp, (p.rows - 1) * 0.5, 0, 0, 1;
  std::vector<Eigen::Matrix3d> H;
  Rig truth;
  truth.reference = 1;
  for (int i = 0; i < 3; ++i) {
    Camera c = testdata::pinhole(w, h, f);
    c.yaw_deg = 4.0 * (i - 1);
    c.pitch_deg = 3.0 * std::sin(i + 0.5);
    c.roll_deg = 2.0 * std::cos(2.0 * i);
    const Eigen::Vector3d C(0.55 * d * i, 0.05 * d * i, 0.1 * d * std::sin(i));
    Eigen::Matrix3d M = (d - C.z()) * Eigen::Matrix3d::Identity();
    M.col(2) += C;
    H.push_back(Kp * M * c.R() * c.K().inverse());
    truth.cameras.push_back(c);
  }
  std::vector<cv::Mat> frames = render_views(p, H, w, h);
  auto views = views_of(frames);
  const CalibrationResult r = calibrate_from_images(views, -1, CalibrationOptions{});
  std::printf("FIGURE: translating cameras over a plane: %s; held-out rms rotation %.3f px, homography %.3f px\n",
              camera_model_name(r.model), r.rotation_heldout_px, r.homography_heldout_px);
  EXPECT_EQ(r.model, CameraModel::Homography);
  EXPECT_TRUE(r.rig.planar());
  // The chosen model explains the held-out matches to within a pixel.
  EXPECT_LT(r.homography_heldout_px, 1.0);
  // The truth: camera i -> camera j is H_j^-1 H_i.
  for (int i = 0; i < 3; ++i) {
    if (i == r.rig.reference) continue;
    const Eigen::Matrix3d want = H[r.rig.reference].inverse() * H[i];
    const Eigen::Matrix3d got = r.rig.cameras[r.rig.reference].homography->inverse() * *r.rig.cameras[i].homography;
    double e = 0;
    for (Eigen::Vector2d q : {Eigen::Vector2d(0, 0), Eigen::Vector2d(w - 1, 0), Eigen::Vector2d(w - 1, h - 1),
                              Eigen::Vector2d(0, h - 1)})
      e += (apply_homography(got, q) - apply_homography(want, q)).norm() / 4;
    EXPECT_LT(e, 2.0) << "camera " << i;
  }
}

TEST(CameraModel, ImagesAloneOnARotatingRigMatchTheTruth) {
  // No rig at all, pads in a scrambled order: the rig's centre becomes the reference.
  RotatingScene s = rotating_scene(3, 40, 480, 360);
  std::vector<cv::Mat> frames = {s.frames[2], s.frames[0], s.frames[1]};
  Rig truth = s.truth;
  truth.cameras = {s.truth.cameras[2], s.truth.cameras[0], s.truth.cameras[1]};
  truth.reference = 2;
  auto views = views_of(frames);
  const CalibrationResult r = calibrate_from_images(views, -1, CalibrationOptions{});
  const double e = corner_error_camera_px(r.rig, truth);
  std::printf("FIGURE: images alone, 3 x 480x360 40 deg apart: %s on %s, reference %d, corner error %.3f px, "
              "fov %.0f x %.0f deg\n",
              camera_model_name(r.model), r.rig.projection.c_str(), r.rig.reference, e, r.hfov_deg, r.vfov_deg);
  EXPECT_EQ(r.model, CameraModel::Rotation);
  EXPECT_EQ(r.rig.reference, 2);  // the middle camera, whatever its pad
  EXPECT_LE(e, 0.5);
  for (std::size_t i = 0; i < 3; ++i)
    EXPECT_NEAR(r.rig.cameras[i].fx / truth.cameras[i].fx, 1.0, 0.01) << "camera " << i;
}

namespace {


}  // namespace

TEST(ImagesAlone, RingClosesAndPicksACylinder) {
  // Six cameras around a full circle, no rig, the pads shuffled: focal lengths, rotations,
  // closure and the projection come from the images.
  testdata::RingScene s =
      testdata::render_ring(photo(), 6, 400, 300, 220.0, Projection::Cylindrical, 0.0, 60.0);
  const std::vector<int> order = {3, 0, 5, 1, 4, 2};
  std::vector<cv::Mat> frames;
  Rig truth = s.truth;
  truth.cameras.clear();
  for (int i : order) {
    frames.push_back(s.frames[i]);
    truth.cameras.push_back(s.truth.cameras[i]);
  }
  auto views = views_of(frames);
  const CalibrationResult r = calibrate_from_images(views, -1, CalibrationOptions{});
  std::printf("FIGURE: images-alone ring: %s, canvas %dx%d wrap %d, fov %.0f x %.0f, BA %.3f -> %.3f px\n",
              r.rig.projection.c_str(), r.rig.canvas_width, r.rig.canvas_height, int(r.rig.canvas_wrap), r.hfov_deg,
              r.vfov_deg, r.ba_rms_before_px, r.ba_rms_after_px);
  EXPECT_EQ(r.rig.projection, "cylindrical");
  EXPECT_TRUE(r.projection_chosen);
  ASSERT_TRUE(r.rig.canvas_wrap);
  // Every seam, the one that closes the ring included (ring neighbours by true yaw).
  for (int k = 0; k < 6; ++k) {
    const int a = int(std::find(order.begin(), order.end(), k) - order.begin());
    const int b = int(std::find(order.begin(), order.end(), (k + 1) % 6) - order.begin());
    const double e = testdata::worst_seam_px(r.rig, truth, a, b);
    std::printf("  seam %d-%d: worst %.3f px\n", k, (k + 1) % 6, e);
    EXPECT_LT(e, 1.0) << "seam " << k;
  }
  for (const auto& c : r.rig.cameras) EXPECT_NEAR(c.pitch_deg, 0, 0.3);
}

TEST(ImagesAlone, CylindricalOnRequestWithoutARig) {
  RotatingScene s = rotating_scene(3, 45, 480, 360, 65);
  auto views = views_of(s.frames);
  CalibrationOptions o;
  o.projection = Projection::Cylindrical;
  const CalibrationResult r = calibrate_from_images(views, -1, o);
  EXPECT_EQ(r.rig.projection, "cylindrical");
  EXPECT_EQ(r.model, CameraModel::Rotation);
  EXPECT_TRUE(r.rig.calibrated());
  for (int i = 0; i < 2; ++i) {
    const double e = testdata::worst_seam_px(r.rig, s.truth, i, i + 1);
    std::printf("cylindrical from images: seam %d-%d worst %.3f px\n", i, i + 1, e);
    EXPECT_LT(e, 1.0);
  }
}

TEST(ImagesAlone, WideRigLeavesThePlane) {
  // Five cameras 50 degrees apart span ~260 degrees: no plane holds them.
  RotatingScene s = rotating_scene(5, 50, 320, 240, 70);
  auto views = views_of(s.frames);
  const CalibrationResult r = calibrate_from_images(views, -1, CalibrationOptions{});
  std::printf("wide rig: %s, fov %.0f x %.0f\n", r.rig.projection.c_str(), r.hfov_deg, r.vfov_deg);
  EXPECT_EQ(r.rig.projection, "cylindrical");
  EXPECT_EQ(r.rig.reference, 2);
}

TEST(CalibBadInput, CameraThatOverlapsNobodyKeepsItsRoughPoseWithAWarning) {
  RotatingScene s = rotating_scene(3, 40, 480, 360);
  // Camera 2 shows something else (a flat grey wall): no matches.
  s.frames[2] = cv::Mat(360, 480, CV_8UC4, cv::Scalar(100, 100, 100, 255));
  const Rig rough = rough_of(s.truth);
  auto views = views_of(s.frames);
  const CalibrationResult r = calibrate_from_rig(rough, views, CalibrationOptions{});
  bool named = false;
  for (const auto& w : r.warnings) named |= w.find("camera 2") != std::string::npos;
  EXPECT_TRUE(named);
  EXPECT_NEAR(r.rig.cameras[2].yaw_deg - r.rig.cameras[1].yaw_deg, rough.cameras[2].yaw_deg - rough.cameras[1].yaw_deg,
              1e-6);
  EXPECT_NEAR(r.rig.cameras[2].fx, rough.cameras[2].fx, 1e-9);
  EXPECT_TRUE(r.rig.calibrated());
}

TEST(CalibBadInput, CamerasInAnotherOrderThanTheRigKeepTheRoughRigAndSaySo) {
  RotatingScene s = rotating_scene(3, 40, 480, 360);
  std::swap(s.frames[0], s.frames[1]);  // pads 0 and 1 swapped against the rig file
  const Rig rough = rough_of(s.truth);
  auto views = views_of(s.frames);
  const CalibrationResult r = calibrate_from_rig(rough, views, CalibrationOptions{});
  bool order = false;
  for (const auto& w : r.warnings) {
    std::printf("warning: %s\n", w.c_str());
    order |= w.find("order") != std::string::npos && w.find("camera ") != std::string::npos;
  }
  EXPECT_TRUE(order);
  EXPECT_TRUE(r.rig.calibrated());
}
