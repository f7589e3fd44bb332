// Automotive surround view (issue 15): the 4-fisheye set of ../shared/data/images/
// surround_view_4fisheye (MIT) as a planar rig (fisheye lens + ground homography per camera,
// tools/surround_view.hpp): undistorted with its yaml, the calibration mat's long edges measure
// straight (and curved without the lens); the bird's-eye view is composed by the CPU compositor,
// its checker edges straight, the views meeting at the corners. Exits 77 without ../shared.
#include <gtest/gtest.h>

#include <cstdio>
#include <opencv2/imgcodecs.hpp>

#include "../../tools/surround_view.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "test_data.hpp"

namespace {
std::string data_dir() { return testdata::shared_path("images/surround_view_4fisheye"); }
}  // namespace

TEST(SurroundView, UndistortedLinesAreStraightAndTheBirdsEyeStitches) {
  const std::string dir = data_dir();
  const stitch::Rig rig = surround::load_rig(dir);
  ASSERT_EQ(rig.cameras.size(), 4u);
  ASSERT_TRUE(rig.calibrated());
  // The rig file carries it all (lens + homography), and loads back the same.
  const stitch::Rig back = stitch::rig_from_json_string(stitch::rig_to_json_string(rig));
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_TRUE(back.cameras[i].lens == rig.cameras[i].lens);
    EXPECT_LT((*back.cameras[i].homography - *rig.cameras[i].homography).norm(), 1e-6 * rig.cameras[i].homography->norm());
  }
  std::vector<cv::Mat> frames;
  double worst_fixed = 0, best_raw = 1e9;
  for (std::size_t i = 0; i < 4; ++i) {
    const cv::Mat bgr = cv::imread(dir + "/" + surround::kNames[i] + ".png", cv::IMREAD_COLOR);
    ASSERT_FALSE(bgr.empty());
    cv::Mat rgba;
    cv::cvtColor(bgr, rgba, cv::COLOR_BGR2RGBA);
    frames.push_back(rgba);
    const stitch::Camera& c = rig.cameras[i];
    const surround::Straightness raw = surround::measure_straightness(bgr);
    const surround::Straightness fixed = surround::measure_straightness(surround::undistort(c, bgr, 0.5 * (c.fx + c.fy)));
    std::printf("%s: long edges' worst deviation from straight: raw %.2f px (median %.2f, %d lines), undistorted "
                "%.2f px (median %.2f, %d lines)\n",
                surround::kNames[i], raw.worst_px, raw.median_px, raw.lines, fixed.worst_px, fixed.median_px,
                fixed.lines);
    EXPECT_GE(fixed.lines, 5) << surround::kNames[i];
    worst_fixed = std::max(worst_fixed, fixed.median_px);
    best_raw = std::min(best_raw, raw.median_px);
  }
  std::printf("undistorted: worst per-camera median line deviation %.2f px; raw: best %.2f px\n", worst_fixed, best_raw);
  EXPECT_LE(worst_fixed, 1.0);
  EXPECT_GT(best_raw, 2.0 * worst_fixed);

  stitch::Compositor comp(stitch::Backend::Cpu);
  comp.prepare(rig, stitch::CompositorSettings{});
  ASSERT_EQ(comp.geometry().width, surround::kTotalW);
  ASSERT_EQ(comp.geometry().height, surround::kTotalH);
  cv::Mat pano(comp.geometry().height, comp.geometry().width, CV_8UC4);
  std::vector<stitch::ImageView> views;
  for (auto& f : frames) views.push_back(stitch::as_view(f));
  comp.compose(views, stitch::as_view(pano));
  // Covered all round the car (the car's own rectangle is seen by no camera).
  cv::Mat gray;
  cv::cvtColor(pano, gray, cv::COLOR_RGBA2GRAY);
  cv::Mat ring = gray.clone();
  ring(cv::Rect(surround::kXl, surround::kYt, surround::kTotalW - 2 * surround::kXl, surround::kTotalH - 2 * surround::kYt))
      .setTo(255);
  const double covered = double(cv::countNonZero(ring > 2)) / double(ring.total());
  const surround::Straightness bird = surround::measure_straightness(pano);
  std::printf("bird's eye %dx%d: %.1f %% covered around the car; long edges' worst deviation %.2f px (median %.2f, %d "
              "lines)\n",
              pano.cols, pano.rows, 100 * covered, bird.worst_px, bird.median_px, bird.lines);
  EXPECT_GT(covered, 0.97);
  EXPECT_GE(bird.lines, 8);
  EXPECT_LE(bird.median_px, 1.5);
  // Neighbouring cameras share the corners of the mat.
  for (int a = 0; a < 4; ++a)
    for (int b : {2, 3})
      if (a < 2) {
        const stitch::CameraCanvasMap ma = stitch::camera_canvas_map(rig, a), mb = stitch::camera_canvas_map(rig, b);
        const Eigen::Vector2d corner(b == 2 ? 250 : surround::kTotalW - 250, a == 0 ? 250 : surround::kTotalH - 250);
        Eigen::Vector2d pa, pb;
        EXPECT_TRUE(ma.to_camera(corner, pa) && pa.x() >= 0 && pa.y() >= 0 && pa.x() < 960 && pa.y() < 640)
            << surround::kNames[a] << " at the " << surround::kNames[b] << " corner";
        EXPECT_TRUE(mb.to_camera(corner, pb) && pb.x() >= 0 && pb.y() >= 0 && pb.x() < 960 && pb.y() < 640)
            << surround::kNames[b] << " at the " << surround::kNames[a] << " corner";
      }
}

int main(int argc, char** argv) {
  if (data_dir().empty()) {
    std::printf("../shared/data/images/surround_view_4fisheye is not here: skipped\n");
    return 77;
  }
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
