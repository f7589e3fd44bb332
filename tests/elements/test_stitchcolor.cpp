// stitchcolor in real pipelines with 2, 3 and 6 views: the seams' color differences shrink,
// the reference view is untouched, and a bundle without calibration is a clear error.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "gst_helpers.hpp"
#include "stitch/rig/rig.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

struct ColorScene {
  cv::Mat photo;
  std::vector<cv::Mat> views;
  std::string calib;
  int shift, width;
};

// n crops of a real photo, each but the reference with its own exposure / white balance.
ColorScene setup(int n) {
  cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  ColorScene s;
  s.photo = photo;
  s.width = n <= 3 ? 640 : 400;
  s.shift = n <= 3 ? 400 : 240;
  const int h = n <= 3 ? 480 : 300;
  const cv::Scalar casts[] = {{0.8, 0.85, 0.9, 1}, {1, 1, 1, 1}, {1.15, 1.05, 0.9, 1},
                              {0.9, 1.1, 1.0, 1},  {0.75, 0.8, 0.85, 1}, {1.1, 0.95, 1.05, 1}};
  for (int i = 0; i < n; ++i) {
    cv::Mat v = photo(cv::Rect(s.shift * i, 200, s.width, h)).clone();
    if (i != n / 2) cv::multiply(v, casts[i % 6], v);
    s.views.push_back(v);
  }
  Rig rig = testdata::shifted_rig(n, s.width, h, s.shift);
  rig.reference = n / 2;
  s.calib = testdata::temp_dir() + "/color" + std::to_string(n) + ".json";
  rig_save(rig, s.calib);
  return s;
}

// Mean absolute difference of the panorama from the undistorted photo it was cut from.
double error_vs_photo(const cv::Mat& pano, const ColorScene& s) {
  cv::Mat truth = s.photo(cv::Rect(0, 200, pano.cols, pano.rows));
  cv::Mat d;
  cv::absdiff(pano, truth, d);
  const cv::Scalar m = cv::mean(d);
  return (m[0] + m[1] + m[2]) / 3;
}

// Runs stitchsync ! stitchcalib ! [color] stitchblend on the views and returns the panoramas.
std::vector<cv::Mat> run(const ColorScene& s, int n, const std::string& color, gsttest::RunResult& r) {
  gsttest::run_pipeline("stitchsync name=s ! stitchcalib load-file=" + s.calib + " ! " + color +
                            " stitchblend ! appsink name=out sync=false" + gsttest::appsrc_inputs(n),
                        s.views, 4, r);
  return r.frames;
}

}  // namespace

class StitchColorViews : public ::testing::TestWithParam<int> {};

TEST_P(StitchColorViews, ReducesColorStepsAcrossSeams) {
  const int n = GetParam();
  ColorScene s = setup(n);
  gsttest::RunResult plain, corrected;
  run(s, n, "", plain);
  run(s, n, "stitchcolor method=3dm smoothing=0 !", corrected);
  ASSERT_TRUE(plain.errors.empty()) << plain.errors[0];
  ASSERT_TRUE(corrected.errors.empty()) << corrected.errors[0];
  ASSERT_EQ(corrected.frames.size(), 4u);
  const double before = error_vs_photo(plain.frames.back(), s);
  const double after = error_vs_photo(corrected.frames.back(), s);
  std::printf("%d views: panorama differs from the photo by %.2f -> %.2f levels\n", n, before, after);
  EXPECT_LT(after, before * 0.5);
  // The reference view's exclusive part is untouched.
  const int ref = n / 2;
  const int x = s.shift * ref + (s.width - s.shift) + 2;
  const int w = std::max(2, 2 * s.shift - s.width - 4);
  cv::Mat a = plain.frames.back()(cv::Rect(x, 0, w, 50)), b = corrected.frames.back()(cv::Rect(x, 0, w, 50));
  EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0.0);
}

INSTANTIATE_TEST_SUITE_P(Views, StitchColorViews, ::testing::Values(2, 3, 6));

TEST(StitchColor, EveryMethodAndBalanceRun) {
  ColorScene s = setup(3);
  for (const char* props : {"method=none", "method=2dm", "method=3dm window=5", "method=gain",
                            "method=3dm pairing=pixels", "method=gain balance=true lambda=0.1"}) {
    gsttest::RunResult r;
    run(s, 3, std::string("stitchcolor ") + props + " !", r);
    EXPECT_TRUE(r.errors.empty()) << props << ": " << (r.errors.empty() ? "" : r.errors[0]);
    EXPECT_EQ(r.frames.size(), 4u) << props;
  }
}

TEST(StitchColor, WithoutCalibrationIsAnError) {
  ColorScene s = setup(2);
  gsttest::RunResult r;
  gsttest::run_pipeline("stitchsync name=s ! stitchcolor ! fakesink" + gsttest::appsrc_inputs(2), s.views, 2, r);
  EXPECT_TRUE(r.error_contains("put stitchcalib before stitchcolor")) << (r.errors.empty() ? "no error" : r.errors[0]);
}

TEST(StitchColor, BlackFramesPassThrough) {
  ColorScene s = setup(2);
  for (auto& v : s.views) v.setTo(cv::Scalar(0, 0, 0, 255));
  gsttest::RunResult r;
  run(s, 2, "stitchcolor balance=true !", r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.frames.size(), 4u);
  double hi;
  cv::Mat g;
  cv::cvtColor(r.frames.back(), g, cv::COLOR_RGBA2GRAY);
  cv::minMaxLoc(g, nullptr, &hi);
  EXPECT_EQ(hi, 0.0);
}
