// stitchblend mode=multiband / seam=dp in a pipeline: the default is the consensus blend, and
// multiband, with and without seams, reproduces consistent views.
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

// Two crops 400 px apart of a photo and their exact calibration; view 1 darker by `dim`.
Scene scene(double dim = 1.0) {
  Scene s;
  s.photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  for (int i = 0; i < 2; ++i) s.views.push_back(s.photo(cv::Rect(400 * i, 200, 640, 480)).clone());
  std::vector<cv::Mat> ch;
  cv::split(s.views[1], ch);
  for (int c = 0; c < 3; ++c) ch[c].convertTo(ch[c], -1, dim);
  cv::merge(ch, s.views[1]);
  s.calib = testdata::temp_dir() + "/modes_exact.json";
  rig_save(testdata::shifted_rig(2, 640, 480, 400), s.calib);
  return s;
}

cv::Mat run_blend(const Scene& s, const std::string& blend_props) {
  gsttest::RunResult r;
  gsttest::run_pipeline("stitchsync name=s ! stitchcalib load-file=" + s.calib + " ! stitchblend " + blend_props +
                            " ! appsink name=out sync=false" + gsttest::appsrc_inputs(2),
                        s.views, 2, r);
  EXPECT_TRUE(r.errors.empty()) << (r.errors.empty() ? "" : r.errors[0]);
  return r.frames.empty() ? cv::Mat() : r.frames.back().clone();
}

}  // namespace

// The default is the consensus blend (the weighted mean with seam=dp): on consistent views it is
// the paper's weighted mean pixel for pixel; it differs from multiband on an exposure step.
TEST(StitchBlendModes, DefaultIsTheConsensusBlend) {
  Scene s = scene(0.7);
  const cv::Mat def = run_blend(s, ""), consensus = run_blend(s, "mode=weighted seam=dp"),
                multiband = run_blend(s, "mode=multiband");
  ASSERT_FALSE(def.empty() || consensus.empty() || multiband.empty());
  EXPECT_EQ(cv::norm(def, consensus, cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(def, multiband, cv::NORM_INF), 10.0);  // the modes do differ on an exposure step
  Scene same = scene(1.0);
  const cv::Mat agree = run_blend(same, ""), mean = run_blend(same, "seam=none");
  ASSERT_FALSE(agree.empty() || mean.empty());
  EXPECT_EQ(cv::norm(agree, mean, cv::NORM_INF), 0.0);
}

TEST(StitchBlendModes, MultibandAndSeamsReproduceConsistentViews) {
  Scene s = scene();
  for (const char* props : {"mode=multiband", "mode=multiband seam=dp bands=3"}) {
    const cv::Mat pano = run_blend(s, props);
    ASSERT_EQ(pano.cols, 1040) << props;
    EXPECT_GT(testdata::psnr_rgb(pano, s.photo(cv::Rect(0, 200, 1040, 480))), 45.0) << props;
  }
}

TEST(StitchBlendDebug, DrawsSeamsOutlinesAndFlowWithoutTouchingTheRest) {
  Scene s = scene();
  auto run = [&](const std::string& chain) {
    gsttest::RunResult r;
    gsttest::run_pipeline("stitchsync name=s ! stitchcalib load-file=" + s.calib + " ! " + chain +
                              " ! appsink name=out sync=false" + gsttest::appsrc_inputs(2),
                          s.views, 2, r);
    EXPECT_TRUE(r.errors.empty()) << (r.errors.empty() ? "" : r.errors[0]);
    return r.frames.empty() ? cv::Mat() : r.frames.back().clone();
  };
  const cv::Mat plain = run("stitchflowwarp flow=true ! stitchblend seam=none"), seams = run("stitchflowwarp flow=true ! stitchblend seam=none debug=seams"),
                all = run("stitchflowwarp flow=true ! stitchblend seam=none debug=all");
  ASSERT_FALSE(plain.empty() || seams.empty() || all.empty());
  // Overlap x = 400..639: the seam (nearest-view labels) runs down its middle, x ~ 520, in white
  // (where the photo is not white itself: at least 9 rows in 10 carry a drawn seam pixel).
  int seam_rows = 0;
  for (int y = 0; y < seams.rows; ++y) {
    bool drawn = false;
    for (int x = 510; x < 530; ++x) {
      const cv::Vec4b p = seams.at<cv::Vec4b>(y, x), q = plain.at<cv::Vec4b>(y, x);
      drawn |= p[0] == 255 && p[1] == 255 && p[2] == 255 && p != q;
    }
    seam_rows += drawn;
  }
  EXPECT_GT(seam_rows, seams.rows * 9 / 10);
  // debug=seams leaves everything away from the seam as it was.
  EXPECT_EQ(cv::norm(seams(cv::Rect(0, 0, 500, 480)), plain(cv::Rect(0, 0, 500, 480)), cv::NORM_INF), 0.0);
  // debug=all also tints the overlap and draws outlines and the flow pair's rectangle.
  cv::Mat diff;
  cv::absdiff(all, plain, diff);
  const double overlap_changed = cv::countNonZero(cv::Mat(diff(cv::Rect(420, 100, 80, 280))).reshape(1) > 0);
  EXPECT_GT(overlap_changed, 0.5 * 80 * 280);                                  // tinted
  EXPECT_GT(cv::norm(all(cv::Rect(0, 0, 1040, 3)), plain(cv::Rect(0, 0, 1040, 3)), cv::NORM_INF), 50.0);  // outlines
  EXPECT_EQ(cv::norm(all(cv::Rect(100, 100, 200, 200)), plain(cv::Rect(100, 100, 200, 200)), cv::NORM_INF), 0.0);
}
