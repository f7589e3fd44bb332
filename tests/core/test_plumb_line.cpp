// Per-camera plumb-line lenses (issue 15, mixed rigs): plumb_line.hpp.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>

#include "stitch/calib/calibrator.hpp"
#include "stitch/calib/plumb_line.hpp"
#include "stitch/rig/lens.hpp"
#include "stitch/cv_interop.hpp"
#include "test_data.hpp"

using namespace stitch;

// PLUMB_FRAMES="a.png b.png ...": print each frame's plumb-line lens (a measuring aid).
TEST(PlumbLine, Probe) {
  const char* env = std::getenv("PLUMB_FRAMES");
  if (!env) GTEST_SKIP() << "PLUMB_FRAMES not set";
  std::istringstream in(env);
  std::string path;
  while (in >> path) {
    cv::Mat m = testdata::load_rgba(path);
    ASSERT_FALSE(m.empty()) << path;
    const auto t0 = cv::getTickCount();
    const PlumbLineLens l = plumb_line_lens({as_view(m)});
    std::printf("%s: %s%s (%.2f s)\n", path.c_str(), l.found ? "" : "NOT FOUND ", l.describe().c_str(),
                double(cv::getTickCount() - t0) / cv::getTickFrequency());
  }
}

namespace {

constexpr double kPi = 3.14159265358979323846;

Camera camera_of(int w, int h, double hfov_deg, double yaw_deg, Lens lens) {
  Camera c;
  c.width = w;
  c.height = h;
  c.fx = c.fy = 0.5 * w / std::tan(0.5 * hfov_deg * kPi / 180.0);
  c.cx = 0.5 * (w - 1);
  c.cy = 0.5 * (h - 1);
  c.yaw_deg = yaw_deg;
  c.lens = lens;
  return c;
}

Lens radtan(double k1, double k2) {
  Lens l;
  l.model = Lens::Model::Radtan;
  l.k1 = k1;
  l.k2 = k2;
  return l;
}

// Median distance (camera b px) between where the truth and the estimate carry a grid of camera
// a's pixels into camera b, over the pixels both true cameras see.
double median_transfer_px(const Rig& truth, const Rig& est, int a, int b) {
  const Camera &A = truth.cameras[a], &B = truth.cameras[b], &EA = est.cameras[a], &EB = est.cameras[b];
  std::vector<double> d;
  for (double y = 4; y < A.height - 4; y += 6)
    for (double x = 4; x < A.width - 4; x += 6) {
      Eigen::Vector3d ray, eray;
      Eigen::Vector2d q, eq;
      if (!lens_unproject(A, {x, y}, ray) || !lens_project(B, B.R().transpose() * (A.R() * ray), q)) continue;
      if (q.x() < 0 || q.y() < 0 || q.x() > B.width - 1 || q.y() > B.height - 1) continue;
      if (!lens_unproject(EA, {x, y}, eray) || !lens_project(EB, EB.R().transpose() * (EA.R() * eray), eq)) {
        d.push_back(1e3);
        continue;
      }
      d.push_back((q - eq).norm());
    }
  if (d.empty()) return 1e9;
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  return d[d.size() / 2];
}

// Camera c's view of `photo` laid flat on the plane z = 1 of the rig frame (`scale` px a unit,
// centred on the rig's axis): every straight line of the photo is straight in an ideal pinhole
// view (a photo taken as a 360-degree panorama bends its rows). Rendered at twice the size and
// area-averaged.
cv::Mat render_on_plane(const cv::Mat& photo, const Camera& c, double scale) {
  Camera big = c;
  big.width *= 2, big.height *= 2, big.fx *= 2, big.fy *= 2;
  big.cx = 2 * c.cx + 0.5, big.cy = 2 * c.cy + 0.5;
  cv::Mat mx(big.height, big.width, CV_32F), my(big.height, big.width, CV_32F);
  const Eigen::Matrix3d R = big.R();
  for (int y = 0; y < big.height; ++y)
    for (int x = 0; x < big.width; ++x) {
      Eigen::Vector3d ray;
      float u = -1, v = -1;
      if (lens_unproject(big, {double(x), double(y)}, ray)) {
        const Eigen::Vector3d r = R * ray;
        if (r.z() > 0.05) u = float(0.5 * photo.cols + scale * r.x() / r.z()), v = float(0.5 * photo.rows + scale * r.y() / r.z());
      }
      mx.at<float>(y, x) = u;
      my.at<float>(y, x) = v;
    }
  cv::Mat out, small;
  cv::remap(photo, out, mx, my, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0, 255));
  cv::resize(out, small, cv::Size(c.width, c.height), 0, 0, cv::INTER_AREA);
  return small;
}

}  // namespace

// A 0.5x ultra-wide phone camera (radtan 110 degrees, k1 -0.30 k2 0.09) beside a 1x pinhole (70
// degrees), 45 degrees apart, rendered small from the repository photo: each camera's own
// straight edges tell its lens, and the calibration from the images alone (the elements'
// defaults) gives each camera its own model and focal length. Without per_camera_lenses (the
// rig-wide choices before): pinhole 335 / 802 px for a true 224 / 457, 22 px off.
TEST(PlumbLine, MixedPairEachCameraItsOwnLens) {
  cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  ASSERT_FALSE(photo.empty());
  // Seen through a window: the photo alone has too few long straight edges at this size (a
  // horizon, two masts) for the plumb line; a real room or street has frames, studs, kerbs.
  for (int x = 60; x < photo.cols; x += 230) cv::rectangle(photo, {x, 0}, {x + 14, photo.rows}, cv::Scalar(40, 40, 40, 255), -1);
  for (int y = 90; y < photo.rows; y += 260) cv::rectangle(photo, {0, y}, {photo.cols, y + 14}, cv::Scalar(235, 235, 225, 255), -1);
  Rig truth;
  truth.projection = "cylindrical";
  truth.cameras.push_back(camera_of(640, 360, 110, -15, radtan(-0.30, 0.09)));
  truth.cameras.push_back(camera_of(640, 360, 70, 30, Lens{}));
  std::vector<cv::Mat> frames;
  std::vector<ImageView> views;
  for (const auto& c : truth.cameras) frames.push_back(render_on_plane(photo, c, photo.cols / 4.0));
  for (auto& f : frames) views.push_back(as_view(f));
  if (const char* dir = std::getenv("PLUMB_SAVE"))
    for (std::size_t i = 0; i < frames.size(); ++i) {
      cv::Mat bgr;
      cv::cvtColor(frames[i], bgr, cv::COLOR_RGBA2BGR);
      cv::imwrite(std::string(dir) + "/mixed" + std::to_string(i) + ".png", bgr);
    }
  const PlumbLineLens wide = plumb_line_lens({views[0]}), normal = plumb_line_lens({views[1]});
  std::printf("plumb: camera 0 %s\nplumb: camera 1 %s\n", wide.describe().c_str(), normal.describe().c_str());
  ASSERT_TRUE(wide.found && normal.found);
  EXPECT_EQ(wide.camera.lens.model, Lens::Model::Radtan);
  EXPECT_GT(std::abs(wide.edge_bend), 0.08);
  EXPECT_LT(std::abs(normal.edge_bend), 0.05);
  EXPECT_TRUE(plumb_lenses_mixed({wide, normal}));

  CalibrationOptions o;
  o.lens_from_evidence = false;  // as the elements' sessions calibrate (calib_session.cpp)
  const auto t0 = cv::getTickCount();
  const CalibrationResult r = calibrate_from_images(std::vector<std::vector<ImageView>>{views}, -1, o);
  const double seconds = double(cv::getTickCount() - t0) / cv::getTickFrequency();
  const double err = median_transfer_px(truth, r.rig, 0, 1);
  std::printf("calibrated in %.1f s: camera 0 %s fx %.1f (true %.1f) k1 %.3f; camera 1 %s fx %.1f (true %.1f); median %.3f px\n",
              seconds, lens_model_name(r.rig.cameras[0].lens.model), r.rig.cameras[0].fx, truth.cameras[0].fx,
              r.rig.cameras[0].lens.k1, lens_model_name(r.rig.cameras[1].lens.model), r.rig.cameras[1].fx,
              truth.cameras[1].fx, err);
  EXPECT_EQ(r.rig.cameras[0].lens.model, Lens::Model::Radtan);
  // The 1x camera: no lens, or one that moves its frame's corner by under half a pixel.
  const Camera& normal_fit = r.rig.cameras[1];
  Eigen::Vector2d corner;
  ASSERT_TRUE(distort_point(normal_fit, {0.0, 0.0}, corner));
  EXPECT_LT(corner.norm(), 0.5) << lens_model_name(normal_fit.lens.model) << " k1 " << normal_fit.lens.k1;
  EXPECT_NEAR(r.rig.cameras[0].fx, truth.cameras[0].fx, 0.03 * truth.cameras[0].fx);
  EXPECT_NEAR(r.rig.cameras[1].fx, truth.cameras[1].fx, 0.03 * truth.cameras[1].fx);
  EXPECT_LT(err, 0.5);
}
