// Lens-aware calibration (issue 15): three barrel-distorted cameras rendered from the
// repository photo (taken as an equirectangular panorama), calibrated from a rough rig whose
// focal lengths are 5 % off and yaws 3 degrees off. With the lens coefficients known the fits
// run on undistorted keypoints; with `"lens": {"model": "radtan"}` and no coefficients the
// bundle adjustment estimates k1 (and k2).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "lens_rig.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/calib/dense_matches.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/lens.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

constexpr double kK1 = -0.23, kK2 = 0.055;

Rig true_rig(double k1 = kK1, double k2 = kK2) {
  return testdata::radtan_trio(320, 240, 260, 35.0, k1, k2, true, "plane");
}

// Focal 5 % off (alternating), yaw 3 degrees off, pitch dropped.
Rig rough_of(const Rig& truth) {
  Rig r = truth;
  for (std::size_t i = 0; i < r.cameras.size(); ++i) {
    Camera& c = r.cameras[i];
    const double s = i % 2 ? 1.05 : 0.95;
    c.fx *= s;
    c.fy *= s;
    c.yaw_deg += i % 2 ? -3.0 : 3.0;
    c.pitch_deg = 0;
  }
  return r;
}


struct Scene {
  Rig truth;
  std::vector<cv::Mat> frames;
  std::vector<ImageView> views;
};

const Scene& scene() {
  static Scene s = [] {
    Scene sc;
    sc.truth = true_rig();
    const cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
    for (const auto& c : sc.truth.cameras) sc.frames.push_back(testdata::render_camera_from_equirect(photo, c));
    for (auto& f : sc.frames) sc.views.push_back(as_view(f));
    return sc;
  }();
  return s;
}

// Renders `truth`'s cameras from the photo (into frames/views) and calibrates them from their
// rough rig with radtan lenses of unknown coefficients.
CalibrationResult calibrate_radtan_unknown(const Rig& truth, const cv::Mat& photo, std::vector<cv::Mat>& frames,
                                           std::vector<ImageView>& views) {
  for (const auto& c : truth.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
  for (auto& f : frames) views.push_back(as_view(f));
  Rig rough = rough_of(truth);
  for (auto& c : rough.cameras) {
    c.lens = Lens{};
    c.lens.model = Lens::Model::Radtan;
    c.lens.estimate = true;
  }
  return calibrate_from_rig(rough, views, CalibrationOptions{});
}

}  // namespace

TEST(CalibLens, KnownRadtanCoefficients) {
  const Scene& s = scene();
  const Rig rough = rough_of(s.truth);
  const double rough_err = testdata::lens_corner_error(rough, s.truth);
  const CalibrationResult r = calibrate_from_rig(rough, s.views, CalibrationOptions{});
  const double err = testdata::lens_corner_error(r.rig, s.truth);
  const AlignmentReport al = measure_alignment(r.rig, s.views);
  // The same calibration with the lens ignored (a pinhole rough rig).
  Rig pin = rough;
  for (auto& c : pin.cameras) c.lens = Lens{};
  const CalibrationResult rp = calibrate_from_rig(pin, s.views, CalibrationOptions{});
  const double err_pin = testdata::lens_corner_error(rp.rig, s.truth);
  const AlignmentReport al_pin = measure_alignment(rp.rig, s.views);
  // What the calibrator did before it knew lenses: the pinhole fit on raw keypoints, the rough
  // rig's lens kept in the result.
  Rig before = rp.rig;
  for (std::size_t i = 0; i < before.cameras.size(); ++i) before.cameras[i].lens = rough.cameras[i].lens;
  const double err_before = testdata::lens_corner_error(before, s.truth);
  for (std::size_t i = 0; i < rp.rig.cameras.size(); ++i)
    std::printf("  lens ignored: camera %zu f %.1f (true %.0f), yaw %.2f (true %.2f)\n", i, rp.rig.cameras[i].fx,
                s.truth.cameras[i].fx, rp.rig.cameras[i].yaw_deg - rp.rig.cameras[rp.rig.reference].yaw_deg,
                s.truth.cameras[i].yaw_deg - s.truth.cameras[s.truth.reference].yaw_deg);
  const AlignmentReport al_before = measure_alignment(before, s.views);
  std::printf("  pinhole fit, lens kept (the calibrator before issue 15): corner error %.3f px, overlap matches "
              "median %.3f px (p90 %.3f, %d)\n",
              err_before, al_before.median_px, al_before.p90_px, al_before.matches);
  std::printf("radtan k1 %.2f k2 %.3f, 3x 320x240, rough corner error %.2f px\n"
              "  lens known:   model %s, corner error %.3f px, overlap matches median %.3f px (p90 %.3f, %d)\n"
              "  lens ignored: model %s, corner error %.3f px, overlap matches median %.3f px (p90 %.3f, %d)\n",
              kK1, kK2, rough_err, camera_model_name(r.model), err, al.median_px, al.p90_px, al.matches,
              camera_model_name(rp.model), err_pin, al_pin.median_px, al_pin.p90_px, al_pin.matches);
  for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
  RecordProperty("corner_error_px", std::to_string(err));
  RecordProperty("corner_error_lens_ignored_px", std::to_string(err_pin));
  EXPECT_GT(rough_err, 5.0);
  EXPECT_LE(err, 0.5);
  ASSERT_GT(al.matches, 50);
  EXPECT_LE(al.median_px, 0.3);
  EXPECT_GT(err_pin, 3 * err);
  // The coefficients were given: they stay.
  for (const auto& c : r.rig.cameras) {
    EXPECT_DOUBLE_EQ(c.lens.k1, kK1);
    EXPECT_DOUBLE_EQ(c.lens.k2, kK2);
  }
}

TEST(CalibLens, EstimatesRadtanCoefficients) {
  const Scene& s = scene();
  Rig rough = rough_of(s.truth);
  for (auto& c : rough.cameras) {
    c.lens = Lens{};
    c.lens.model = Lens::Model::Radtan;  // "lens": {"model": "radtan"}: estimate them
    c.lens.estimate = true;
  }
  const CalibrationResult r = calibrate_from_rig(rough, s.views, CalibrationOptions{});
  const double err = testdata::lens_corner_error(r.rig, s.truth);
  const AlignmentReport al = measure_alignment(r.rig, s.views);
  std::printf("radtan estimated: model %s, corner error %.3f px, overlap matches median %.3f px (p90 %.3f, %d)\n",
              camera_model_name(r.model), err, al.median_px, al.p90_px, al.matches);
  for (std::size_t i = 0; i < r.rig.cameras.size(); ++i)
    std::printf("  camera %zu: k1 %+.4f (true %+.3f) k2 %+.4f (true %+.3f) f %.2f (true %.0f)\n", i,
                r.rig.cameras[i].lens.k1, kK1, r.rig.cameras[i].lens.k2, kK2, r.rig.cameras[i].fx, s.truth.cameras[i].fx);
  for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
  RecordProperty("corner_error_px", std::to_string(err));
  EXPECT_EQ(r.model, CameraModel::Rotation);
  EXPECT_LE(err, 0.5);
  EXPECT_LE(al.median_px, 0.3);
  for (const auto& c : r.rig.cameras) {
    EXPECT_NEAR(c.lens.k1, kK1, 0.1 * std::abs(kK1));
    EXPECT_TRUE(lens_problem(c).empty());
    EXPECT_FALSE(c.lens.estimate) << "estimated: the written rig carries the coefficients";
  }
  // The calibrated rig file carries the estimates and loads back to the same lenses.
  const Rig back = rig_from_json_string(rig_to_json_string(r.rig));
  for (std::size_t i = 0; i < back.cameras.size(); ++i) {
    EXPECT_FALSE(back.cameras[i].lens.estimate);
    EXPECT_NEAR(back.cameras[i].lens.k1, r.rig.cameras[i].lens.k1, 1e-9);
    EXPECT_NEAR(back.cameras[i].lens.k2, r.rig.cameras[i].lens.k2, 1e-9);
  }
}

// The range of radtan lenses (k1 -0.35 ... +0.1), estimated from rough rigs without
// coefficients. The bundle adjustment starts from a sweep of the distortion (from k = 0 the
// k1 -0.35 lens ran the focal lengths off x60), then refits on dense photometric matches
// (dense_matches.hpp): the corner error (extrapolated to corners no match reaches) was 0.7-0.8 px
// on SIFT keypoints alone, the 0.5 px is asserted (BENCHMARKS.md, "Radtan corner error").
TEST(CalibLens, EstimatesAcrossTheRange) {
  const cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  for (double k1 : {-0.35, 0.1}) {
    // Barrel lenses get k2 = k1^2: with k1^2/4 the k1 -0.35 lens itself folds inside the frame
    // (its corners unseen), a lens lens_problem refuses.
    const double k2 = k1 < 0 ? k1 * k1 : 0.0;
    // Spherical: on a plane, the k1 -0.35 rig's wide views (corners 45 degrees off axis, yaws
    // +-35) need a canvas 16x the input (refused as degenerate).
    Rig truth = true_rig(k1, k2);
    truth.projection = "spherical";
    std::vector<cv::Mat> frames;
    std::vector<ImageView> views;
    const CalibrationResult r = calibrate_radtan_unknown(truth, photo, frames, views);
    const double err = testdata::lens_corner_error(r.rig, truth);
    const AlignmentReport al = measure_alignment(r.rig, views);
    double worst_k1 = 0;
    for (const auto& c : r.rig.cameras) worst_k1 = std::max(worst_k1, std::abs(c.lens.k1 - k1));
    std::printf("radtan k1 %+.2f k2 %.3f estimated: model %s, corner error %.3f px, overlap matches median %.3f px, "
                "worst k1 error %.4f\n",
                k1, k2, camera_model_name(r.model), err, al.median_px, worst_k1);
    for (const auto& w : r.warnings) std::printf("  warning: %s\n", w.c_str());
    for (std::size_t i = 0; i < r.rig.cameras.size(); ++i)
      std::printf("  camera %zu: k1 %+.4f k2 %+.4f f %.2f (true 260)\n", i, r.rig.cameras[i].lens.k1,
                  r.rig.cameras[i].lens.k2, r.rig.cameras[i].fx);
    // 0.236 / 0.088 px measured (0.305 / 0.099 before the phase-bias correction and Cauchy 1): the issue's
    // 0.5 px with a margin that still catches a regression of the dense refit.
    EXPECT_LE(err, 0.4) << k1;
    EXPECT_LE(al.median_px, 0.3) << k1;
    EXPECT_LE(worst_k1, 0.1 * std::abs(k1)) << k1;
    for (const auto& c : r.rig.cameras) EXPECT_TRUE(lens_problem(c).empty()) << k1;
  }
}

// Alike cameras (same model and frame) with different lenses (issue 15): the dense refit's lens
// sharing is decided on held-out matches, so a trio whose k1 differ (-0.35, -0.2, -0.3) keeps
// one lens per camera, each within 10 %.
TEST(CalibLens, DifferentLensesOnAlikeCamerasStaySeparate) {
  const cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  Rig truth = true_rig(-0.35, 0.1225);
  truth.projection = "spherical";
  const double k1s[3] = {-0.35, -0.2, -0.3};
  for (int i = 0; i < 3; ++i) truth.cameras[i].lens.k1 = k1s[i], truth.cameras[i].lens.k2 = k1s[i] * k1s[i];
  std::vector<cv::Mat> frames;
  std::vector<ImageView> views;
  const CalibrationResult r = calibrate_radtan_unknown(truth, photo, frames, views);
  const double err = testdata::lens_corner_error(r.rig, truth);
  std::printf("k1 -0.35 / -0.2 / -0.3: corner error %.3f px\n", err);
  for (std::size_t i = 0; i < r.rig.cameras.size(); ++i) {
    std::printf("  camera %zu: k1 %+.4f (%+.2f) k2 %+.4f f %.2f\n", i, r.rig.cameras[i].lens.k1, k1s[i],
                r.rig.cameras[i].lens.k2, r.rig.cameras[i].fx);
    EXPECT_NEAR(r.rig.cameras[i].lens.k1, k1s[i], 0.1 * std::abs(k1s[i])) << i;
  }
  EXPECT_LE(err, 0.5);
}

// The true rig a little off, as the calibrator's fit is when it locates dense matches: camera 0
// turned by `yaw_deg`, camera 2's focal length times `focal`.
static Rig off_truth(Rig rig, double yaw_deg, double focal) {
  rig.cameras[0].yaw_deg += yaw_deg;
  rig.cameras[2].fx *= focal;
  rig.cameras[2].fy *= focal;
  return rig;
}

static std::vector<DenseImage> dense_images(const std::vector<cv::Mat>& frames) {
  std::vector<DenseImage> imgs;
  for (const auto& f : frames) {
    cv::Mat g;
    cv::cvtColor(f, g, cv::COLOR_RGBA2GRAY);
    imgs.push_back(prepare_dense_image(g));
  }
  return imgs;
}

// The dense matches themselves (issue 15): through a rig a little off the truth (yaw 0.3 degrees,
// focal 0.5 %), the photometric alignment places hundreds of correspondences a pair to a few
// hundredths of a pixel of where the true rig puts them (SIFT keypoints: ~0.25 px), over the
// whole overlap, corners included.
TEST(CalibLens, DenseMatchesAreHundredthsOfAPixel) {
  const Scene& s = scene();
  const Rig guide = off_truth(s.truth, 0.3, 1.005);
  const std::vector<DenseImage> imgs = dense_images(s.frames);
  for (int a : {0, 1}) {
    const PairMatches m = dense_pair_matches(guide, a, a + 1, imgs[a], imgs[a + 1]);
    std::vector<double> e;
    double reach = 0;
    const Camera& A = s.truth.cameras[a];
    for (std::size_t k = 0; k < m.ra.size(); ++k) {
      Eigen::Vector3d ray;
      Eigen::Vector2d q;
      ASSERT_TRUE(lens_unproject(A, m.ra[k], ray));
      const Camera& B = s.truth.cameras[a + 1];
      ASSERT_TRUE(lens_project(B, B.R().transpose() * (A.R() * ray), q));
      e.push_back((q - m.rb[k]).norm());
      reach = std::max(reach, std::hypot(m.ra[k].x() - A.cx, m.ra[k].y() - A.cy) / std::hypot(A.cx, A.cy));
    }
    ASSERT_GE(e.size(), 300u) << a;
    std::sort(e.begin(), e.end());
    const double med = e[e.size() / 2], p90 = e[e.size() * 9 / 10];
    std::printf("dense %d-%d: %zu matches, error vs the true rig median %.3f px, p90 %.3f px, max %.3f px; reach %.0f %% "
                "of the half diagonal\n",
                a, a + 1, e.size(), med, p90, e.back(), 100 * reach);
    EXPECT_LE(med, 0.05) << a;
    EXPECT_LE(p90, 0.12) << a;
    EXPECT_GE(reach, 0.85) << a;
  }
}

// Sub-pixel "peak locking" of the dense matches (correct_phase_bias): under the true rig the
// located points' residuals follow their sub-pixel phase (a few thousandths of a pixel, coherent
// over the overlap). Estimated through a rig a little off (as the calibrator does, through its
// own fit), the periodic part is taken off: the phase-dependent residual against the truth drops.
TEST(CalibLens, DensePhaseBiasIsTakenOff) {
  const Scene& s = scene();
  const Rig guide = off_truth(s.truth, 0.02, 1.001);
  const std::vector<DenseImage> imgs = dense_images(s.frames);
  std::vector<PairMatches> m;
  for (int a : {0, 1}) m.push_back(dense_pair_matches(guide, a, a + 1, imgs[a], imgs[a + 1]));
  // Amplitude of the first harmonic of the residual (truth minus located) over the phase, both axes.
  auto amplitude = [&](const std::vector<PairMatches>& ms) {
    double sum[2][2] = {{0, 0}, {0, 0}};
    int n = 0;
    for (const auto& p : ms)
      for (std::size_t k = 0; k < p.ra.size(); ++k) {
        const bool wa = p.ra[k] == p.ra[k].array().round().matrix();
        const Eigen::Vector2d& loc = wa ? p.rb[k] : p.ra[k];
        const Camera &S = s.truth.cameras[wa ? p.a : p.b], &T = s.truth.cameras[wa ? p.b : p.a];
        Eigen::Vector3d ray;
        Eigen::Vector2d q;
        if (!lens_unproject(S, wa ? p.ra[k] : p.rb[k], ray) || !lens_project(T, T.R().transpose() * (S.R() * ray), q)) continue;
        const Eigen::Vector2d e = q - loc;
        if (e.norm() > 0.5) continue;
        for (int ax = 0; ax < 2; ++ax) {
          const double t = 2 * M_PI * (loc[ax] - std::floor(loc[ax]));
          sum[ax][0] += e[ax] * std::sin(t), sum[ax][1] += e[ax] * std::cos(t);
        }
        ++n;
      }
    double amp = 0;
    for (int ax = 0; ax < 2; ++ax) amp = std::max(amp, 2 * std::hypot(sum[ax][0], sum[ax][1]) / std::max(n, 1));
    return amp;
  };
  const double before = amplitude(m);
  const int used = correct_phase_bias(guide, m);
  const double after = amplitude(m);
  std::printf("dense phase bias (first harmonic, worse axis): %.4f px before, %.4f px after the correction (%d matches)\n",
              before, after, used);
  EXPECT_GE(used, 300);
  EXPECT_GT(before, 0.003);
  EXPECT_LT(after, 0.5 * before);
}
