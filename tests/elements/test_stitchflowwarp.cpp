// stitchflowwarp: with flow off the chain gives exactly stitchblend's own warp; with flow on,
// parallax in the overlap is aligned in the panorama; without calibration it is a clear error;
// the properties round-trip.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "gst_helpers.hpp"
#include "stitch/rig/rig.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

struct Scene {
  cv::Mat photo;
  std::vector<cv::Mat> views;
  std::string calib;
};

// Two crops 400 px apart and their exact calibration; view 1 optionally with local parallax.
Scene scene(double parallax) {
  Scene s;
  s.photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  for (int i = 0; i < 2; ++i) s.views.push_back(s.photo(cv::Rect(400 * i, 200, 640, 480)).clone());
  if (parallax > 0) {
    cv::Mat mx(480, 640, CV_32F), my(480, 640, CV_32F);
    for (int y = 0; y < 480; ++y)
      for (int x = 0; x < 640; ++x) {
        mx.at<float>(y, x) = float(x - parallax * std::sin(CV_PI * y / 480.0));
        my.at<float>(y, x) = float(y);
      }
    cv::remap(s.views[1].clone(), s.views[1], mx, my, cv::INTER_CUBIC, cv::BORDER_REFLECT);
  }
  const Rig rig = testdata::shifted_rig(2, 640, 480, 400);
  s.calib = testdata::temp_dir() + "/flowwarp_exact.json";
  rig_save(rig, s.calib);
  return s;
}

std::string chain(const Scene& s, const std::string& middle, const std::string& blend = "stitchblend") {
  return "stitchsync name=s ! stitchcalib load-file=" + s.calib + " ! " + middle + blend +
         " ! appsink name=out sync=false" + gsttest::appsrc_inputs(2);
}

}  // namespace

TEST(StitchFlowWarp, FlowOffEqualsTheHomographyOnlyChain) {
  for (const char* blend : {"stitchblend", "stitchblend crop=auto", "stitchblend output-width=520"}) {
    Scene s = scene(0);
    gsttest::RunResult plain, warped;
    gsttest::run_pipeline(chain(s, "", blend), s.views, 2, plain);
    gsttest::run_pipeline(chain(s, "stitchflowwarp flow=false ! ", blend), s.views, 2, warped);
    ASSERT_TRUE(plain.errors.empty()) << plain.errors[0];
    ASSERT_TRUE(warped.errors.empty()) << warped.errors[0];
    ASSERT_EQ(plain.frames.size(), 2u);
    ASSERT_EQ(warped.frames.size(), 2u);
    ASSERT_EQ(plain.frames[0].size(), warped.frames[0].size()) << blend;
    // Same maps, same weights: identical, up to the resampling of a scaled output.
    EXPECT_LE(cv::norm(plain.frames[1], warped.frames[1], cv::NORM_INF),
              std::string(blend).find("width") != std::string::npos ? 12.0 : 0.0)
        << blend;
  }
}

TEST(StitchFlowWarp, IdenticalViewsGiveTheHomographyOnlyPanorama) {
  Scene s = scene(0);
  gsttest::RunResult plain, flow;
  gsttest::run_pipeline(chain(s, ""), s.views, 3, plain);
  gsttest::run_pipeline(chain(s, "stitchflowwarp flow=true ! "), s.views, 3, flow);
  ASSERT_TRUE(flow.errors.empty()) << flow.errors[0];
  ASSERT_EQ(flow.frames.size(), 3u);
  for (int k = 0; k < 3; ++k) EXPECT_EQ(cv::norm(plain.frames[k], flow.frames[k], cv::NORM_INF), 0.0);
}

TEST(StitchFlowWarp, ParallaxMovesTheOverlapOnly) {
  Scene s = scene(8.0);
  gsttest::RunResult plain, flow;
  gsttest::run_pipeline(chain(s, "stitchflowwarp flow=false ! "), s.views, 2, plain);
  gsttest::run_pipeline(chain(s, "stitchflowwarp flow=true quality=medium ! "), s.views, 2, flow);
  ASSERT_TRUE(flow.errors.empty()) << flow.errors[0];
  ASSERT_EQ(flow.frames.size(), 2u);
  // The overlap is x in [400, 640) of the panorama: the flow changes it (the core tests
  // measure how well it aligns), and nothing outside it.
  const cv::Rect overlap(400, 0, 240, 480), left(0, 0, 360, 480), right(680, 0, 360, 480);
  if (std::getenv("STITCH_DUMP")) {
    cv::Mat both;
    cv::hconcat(plain.frames[1](overlap), flow.frames[1](overlap), both);
    cv::cvtColor(both, both, cv::COLOR_RGBA2BGR);
    cv::imwrite(std::string(std::getenv("STITCH_DUMP")) + "/flowwarp_overlap.png", both);
  }
  cv::Mat d;
  cv::absdiff(plain.frames[1](overlap), flow.frames[1](overlap), d);
  EXPECT_GT(cv::mean(d)[0], 1.0);
  EXPECT_EQ(cv::norm(plain.frames[1](left), flow.frames[1](left), cv::NORM_INF), 0.0);
  EXPECT_EQ(cv::norm(plain.frames[1](right), flow.frames[1](right), cv::NORM_INF), 0.0);
}

// The per-overlap decision goes on the bus: a "stitch-flow-decision" element message whenever
// it changes (the first frame's included). Aligned views: the flow cannot cut the matching
// error, so it is switched off; parallax: it stays on.
TEST(StitchFlowWarp, PostsThePerOverlapDecision) {
  for (double parallax : {0.0, 8.0}) {
    Scene s = scene(parallax);
    gsttest::RunResult run;
    gsttest::run_pipeline(chain(s, "stitchflowwarp flow=true ! "), s.views, 3, run);
    ASSERT_TRUE(run.errors.empty()) << run.errors[0];
    std::vector<bool> decisions;
    for (GstStructure* m : run.element_messages) {
      if (!gst_structure_has_name(m, "stitch-flow-decision")) continue;
      int a = -1, b = -1;
      gboolean on = FALSE;
      double gain = -1, err_h = -1, err_f = -1;
      ASSERT_TRUE(gst_structure_get_int(m, "view-a", &a) && gst_structure_get_int(m, "view-b", &b));
      ASSERT_TRUE(gst_structure_get_boolean(m, "flow-on", &on) && gst_structure_get_double(m, "gain", &gain));
      ASSERT_TRUE(gst_structure_get_double(m, "error-homography", &err_h) &&
                  gst_structure_get_double(m, "error-flow", &err_f));
      EXPECT_EQ(a, 0);
      EXPECT_EQ(b, 1);
      EXPECT_GE(gain, 0.0);
      EXPECT_LE(gain, 1.0);
      decisions.push_back(on);
    }
    ASSERT_FALSE(decisions.empty()) << "parallax " << parallax;
    EXPECT_EQ(decisions.back(), parallax > 0) << "parallax " << parallax;
  }
}

TEST(StitchFlowWarp, WithoutCalibrationIsAnError) {
  Scene s = scene(0);
  gsttest::RunResult r;
  gsttest::run_pipeline("stitchsync name=s ! stitchflowwarp ! stitchblend ! appsink name=out sync=false" +
                            gsttest::appsrc_inputs(2),
                        s.views, 2, r);
  EXPECT_TRUE(r.error_contains("put stitchcalib before stitchflowwarp")) << (r.errors.empty() ? "no error" : r.errors[0]);
}

TEST(StitchFlowWarp, PropertiesRoundTrip) {
  gsttest::init();
  GstElement* e = gst_element_factory_make("stitchflowwarp", nullptr);
  ASSERT_NE(e, nullptr);
  gboolean flow = TRUE;
  gint margin = 0;
  gdouble smoothing = 0;
  g_object_get(e, "flow", &flow, "margin", &margin, "temporal-smoothing", &smoothing, NULL);
  EXPECT_FALSE(flow);  // off by default (issue 16): stitchblend's consensus blend handles parallax
  EXPECT_EQ(margin, 16);
  EXPECT_DOUBLE_EQ(smoothing, 0.95);
  gst_util_set_object_arg(G_OBJECT(e), "quality", "fine");
  gst_util_set_object_arg(G_OBJECT(e), "algorithm", "farneback");
  g_object_set(e, "flow", TRUE, "margin", 40, "temporal-smoothing", 0.3, NULL);
  gint quality = 0, algorithm = 0;
  g_object_get(e, "flow", &flow, "margin", &margin, "temporal-smoothing", &smoothing, "quality", &quality,
               "algorithm", &algorithm, NULL);
  EXPECT_TRUE(flow);
  EXPECT_EQ(margin, 40);
  EXPECT_DOUBLE_EQ(smoothing, 0.3);
  EXPECT_EQ(quality, 2);
  EXPECT_EQ(algorithm, 1);
  gst_object_unref(e);
}

// Guard rails (issue 18): stages after a warping stitchflowwarp that need camera frames refuse,
// naming the fix. With the flow off (the default) the bundle passes through unwarped, and the
// order does not matter: the same panorama.
TEST(StitchFlowWarp, StagesThatNeedCameraFramesRefuseToComeAfterIt) {
  Scene s = scene(0);
  gsttest::RunResult color_after;
  gsttest::run_pipeline(chain(s, "stitchflowwarp flow=true ! stitchcolor ! "), s.views, 2, color_after);
  EXPECT_TRUE(color_after.error_contains("put stitchcolor before stitchflowwarp"))
      << (color_after.errors.empty() ? "no error" : color_after.errors[0]);
  EXPECT_TRUE(color_after.frames.empty());
  gsttest::RunResult twice;
  gsttest::run_pipeline(chain(s, "stitchflowwarp flow=true ! stitchflowwarp flow=true ! "), s.views, 2, twice);
  EXPECT_TRUE(twice.error_contains("keep one stitchflowwarp")) << (twice.errors.empty() ? "no error" : twice.errors[0]);
  // the right order runs
  gsttest::RunResult right;
  gsttest::run_pipeline(chain(s, "stitchcolor ! stitchflowwarp ! "), s.views, 2, right);
  EXPECT_TRUE(right.errors.empty()) << right.errors[0];
  // flow off: either order, the same panorama
  gsttest::RunResult off_after;
  gsttest::run_pipeline(chain(s, "stitchflowwarp ! stitchcolor ! "), s.views, 2, off_after);
  ASSERT_TRUE(off_after.errors.empty()) << off_after.errors[0];
  ASSERT_EQ(off_after.frames.size(), right.frames.size());
  for (std::size_t k = 0; k < right.frames.size(); ++k)
    EXPECT_EQ(cv::norm(off_after.frames[k], right.frames[k], cv::NORM_INF), 0.0);
  EXPECT_EQ(right.frames.size(), 2u);
}
