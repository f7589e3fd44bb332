// stitchblend: output caps follow the calibration, the panorama reproduces the scene, and a
// bundle without calibration is a clear error.
#include <gtest/gtest.h>

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

// Two crops 400 px apart and their exact calibration.
Scene scene() {
  Scene s;
  s.photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  for (int i = 0; i < 2; ++i) s.views.push_back(s.photo(cv::Rect(400 * i, 200, 640, 480)).clone());
  const Rig rig = testdata::shifted_rig(2, 640, 480, 400);
  s.calib = testdata::temp_dir() + "/blend_exact.json";
  rig_save(rig, s.calib);
  return s;
}

}  // namespace

TEST(StitchBlend, PanoramaReproducesTheScene) {
  Scene s = scene();
  gsttest::RunResult r;
  gsttest::run_pipeline("stitchsync name=s ! stitchcalib load-file=" + s.calib +
                            " ! stitchblend ! appsink name=out sync=false" + gsttest::appsrc_inputs(2),
                        s.views, 3, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.frames.size(), 3u);
  const cv::Mat& pano = r.frames[0];
  EXPECT_EQ(pano.cols, 1040);  // wider than any input
  EXPECT_EQ(pano.rows, 480);
  EXPECT_GT(testdata::psnr_rgb(pano(cv::Rect(0, 0, 1040, 480)), s.photo(cv::Rect(0, 200, 1040, 480))), 45.0);
}

TEST(StitchBlend, OutputWidthScales) {
  Scene s = scene();
  gsttest::RunResult r;
  gsttest::run_pipeline("stitchsync name=s ! stitchcalib load-file=" + s.calib +
                            " ! stitchblend output-width=520 ! appsink name=out sync=false" +
                            gsttest::appsrc_inputs(2),
                        s.views, 2, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_FALSE(r.frames.empty());
  EXPECT_EQ(r.frames[0].cols, 520);
  EXPECT_EQ(r.frames[0].rows, 240);
}

TEST(StitchBlend, WithoutCalibrationIsAnError) {
  Scene s = scene();
  gsttest::RunResult r;
  gsttest::run_pipeline("stitchsync name=s ! stitchblend ! appsink name=out sync=false" + gsttest::appsrc_inputs(2),
                        s.views, 2, r);
  EXPECT_TRUE(r.error_contains("put stitchcalib before stitchblend")) << (r.errors.empty() ? "no error" : r.errors[0]);
}

TEST(StitchBlend, AcceptsOnlyBundles) {
  gsttest::init();
  GError* err = nullptr;
  GstElement* p = gst_parse_launch("videotestsrc num-buffers=1 ! stitchblend ! fakesink", &err);
  ASSERT_NE(p, nullptr);
  gst_element_set_state(p, GST_STATE_PLAYING);
  GstBus* bus = gst_element_get_bus(p);
  GstMessage* m = gst_bus_timed_pop_filtered(bus, 10 * GST_SECOND,
                                             GstMessageType(GST_MESSAGE_ERROR | GST_MESSAGE_EOS));
  ASSERT_NE(m, nullptr);
  EXPECT_EQ(GST_MESSAGE_TYPE(m), GST_MESSAGE_ERROR);  // plain video cannot link: not-negotiated
  gst_message_unref(m);
  gst_object_unref(bus);
  gst_element_set_state(p, GST_STATE_NULL);
  gst_object_unref(p);
}
