// stitchcalib in real pipelines fed with crops of a real photo: rig-file refinement, load/save,
// messages, recalibration, and every bad-input path named in the issue.
#include <gst/app/gstappsink.h>
#include <gst/app/gstappsrc.h>
#include <gtest/gtest.h>

#include <atomic>

#include <Eigen/Dense>
#include <fstream>
#include <thread>
#include <opencv2/imgproc.hpp>

#include "gst_helpers.hpp"
#include "image_compare.hpp"
#include "lens_rig.hpp"
#include "stitch/rig/rig.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

// Three 640x480 crops of one photo, 400 px apart: the true geometry is a pure shift.
std::vector<cv::Mat> crops(int n = 3) {
  cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  std::vector<cv::Mat> v;
  for (int i = 0; i < n; ++i) v.push_back(photo(cv::Rect(400 * i, 200, 640, 480)).clone());
  return v;
}

std::string write_file(const std::string& name, const std::string& text) {
  const std::string path = testdata::temp_dir() + "/" + name;
  std::ofstream(path) << text;
  return path;
}

// Rough rig for the crops: parallel cameras 400 px apart on a plane 10 m away, with the
// baseline 4% too long and a degree of yaw error (rough parameters, as a user measures them).
std::string rough_rig(int n, double yaw_step = 1.0, double fx = 600) {
  std::string cams;
  for (int i = 0; i < n; ++i) {
    if (i) cams += ",";
    const double tx = (i - n / 2) * 400.0 / 600.0 * 10.0 * 1.04;
    cams += R"({"width":640,"height":480,"fx":)" + std::to_string(fx) + R"(,"fy":)" + std::to_string(fx) +
            R"(,"cx":319.5,"cy":239.5,"yaw_deg":)" + std::to_string((i - n / 2) * yaw_step) +
            R"(,"t":[)" + std::to_string(tx) + ",0,0]}";
  }
  return R"({"format":"stitch-rig","version":1,"projection":"plane","plane_distance_m":10,"reference":)" +
         std::to_string(n / 2) + R"(,"cameras":[)" + cams + "]}";
}

std::string chain(const std::string& calib_props, int n) {
  return "stitchsync name=s ! stitchcalib name=c " + calib_props + " ! stitchblend ! appsink name=out sync=false" +
         gsttest::appsrc_inputs(n);
}

const GstStructure* calib_message(const gsttest::RunResult& r, int index = 0) {
  int k = 0;
  for (auto* s : r.element_messages)
    if (gst_structure_has_name(s, "stitchcalib") && k++ == index) return s;
  return nullptr;
}

double corner_error_vs_shift(const Rig& rig, int cam, double shift) {
  const Eigen::Matrix3d rel = rig.cameras[0].homography->inverse() * *rig.cameras[cam].homography;
  double e = 0;
  for (Eigen::Vector2d c : {Eigen::Vector2d(0, 0), Eigen::Vector2d(639, 0), Eigen::Vector2d(639, 479),
                            Eigen::Vector2d(0, 479)})
    e += (apply_homography(rel, c) - (c + Eigen::Vector2d(shift, 0))).norm();
  return e / 4;
}

}  // namespace

TEST(StitchCalib, RigFileIsRefinedSavedAndAnnounced) {
  const std::string rig = write_file("rough3.json", rough_rig(3));
  const std::string saved = testdata::temp_dir() + "/saved3.json";
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig + " save-file=" + saved, 3), crops(), 5, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.frames.size(), 5u);
  const GstStructure* m = calib_message(r);
  ASSERT_NE(m, nullptr);
  int refined = 0, canvas_w = 0;
  gst_structure_get_int(m, "refined-cameras", &refined);
  gst_structure_get_int(m, "canvas-width", &canvas_w);
  EXPECT_EQ(refined, 2);
  EXPECT_STREQ(gst_structure_get_string(m, "source"), "rig");
  // Which camera model was installed (later calibrations keep it when left to auto).
  const char* model = gst_structure_get_string(m, "model");
  ASSERT_NE(model, nullptr) << "no model on the bus";
  EXPECT_TRUE(g_str_equal(model, "rotation") || g_str_equal(model, "homography")) << model;
  Rig out = rig_load(saved);
  ASSERT_TRUE(out.calibrated());
  EXPECT_EQ(out.canvas_width, canvas_w);
  // The rough rig is tens of pixels off at the corners; features bring it to sub-pixel.
  EXPECT_LT(corner_error_vs_shift(out, 1, 400), 1.0);
  EXPECT_LT(corner_error_vs_shift(out, 2, 800), 1.0);
  EXPECT_NEAR(r.frames[0].cols, 1440, 4);
}

// stitchblend shows the panorama at half the canvas's size: stitchcalib, asking it through the
// stages between (a queue, stitchcolor, stitchflowwarp), makes the canvas that size, so the flow
// warp and the blend work at the output's size; the saved canvas is the panorama's; and the
// panorama is the one the direct warp (flow off) makes at that size.
TEST(StitchCalib, CanvasMadeAtTheSizeStitchblendOutputs) {
  const std::string rig = write_file("rough3s.json", rough_rig(3));
  const std::string saved = testdata::temp_dir() + "/saved3s.json";
  const std::string inputs = gsttest::appsrc_inputs(3);
  gsttest::RunResult full, by_property, by_caps, direct;
  const std::string head = "stitchsync name=s ! stitchcalib name=c rig-file=" + rig;
  gsttest::run_pipeline(head + " ! stitchblend ! appsink name=out sync=false" + inputs, crops(), 2, full);
  ASSERT_TRUE(full.errors.empty()) << full.errors[0];
  int full_w = 0;
  gst_structure_get_int(calib_message(full), "canvas-width", &full_w);
  ASSERT_GT(full_w, 1000);
  const int half = full_w / 4 * 2;
  gsttest::run_pipeline(head + " save-file=" + saved + " ! queue ! stitchcolor ! stitchflowwarp flow=true ! stitchblend output-width=" +
                            std::to_string(half) + " ! appsink name=out sync=false" + inputs,
                        crops(), 3, by_property);
  ASSERT_TRUE(by_property.errors.empty()) << by_property.errors[0];
  const GstStructure* m = calib_message(by_property);
  ASSERT_NE(m, nullptr);
  int w = 0, h = 0;
  gst_structure_get_int(m, "canvas-width", &w);
  gst_structure_get_int(m, "canvas-height", &h);
  EXPECT_NEAR(w, half, 2);
  ASSERT_EQ(by_property.frames.size(), 3u);
  EXPECT_EQ(by_property.frames[0].cols, half);
  EXPECT_EQ(by_property.frames[0].rows, h);
  EXPECT_EQ(rig_load(saved).canvas_width, w);
  // A capsfilter that fixes the size does the same.
  gsttest::run_pipeline(head + " ! stitchflowwarp flow=true ! stitchblend ! video/x-raw,width=" + std::to_string(half) +
                            ",height=" + std::to_string(h) + " ! appsink name=out sync=false" + inputs,
                        crops(), 2, by_caps);
  ASSERT_TRUE(by_caps.errors.empty()) << by_caps.errors[0];
  int cw = 0;
  gst_structure_get_int(calib_message(by_caps), "canvas-width", &cw);
  EXPECT_EQ(cw, w);
  ASSERT_EQ(by_caps.frames.size(), 2u);
  // Flow off, the blend warps the cameras straight to the output: the same picture.
  gsttest::run_pipeline(head + " ! stitchblend output-width=" + std::to_string(half) + " ! appsink name=out sync=false" + inputs,
                        crops(), 2, direct);
  ASSERT_EQ(direct.frames.size(), 2u);
  ASSERT_EQ(direct.frames[1].size(), by_caps.frames[1].size());
  EXPECT_GT(testdata::psnr_rgb(direct.frames[1], by_caps.frames[1]), 35.0);
}

TEST(StitchCalib, LoadFileIsUsedAsIs) {
  const Rig rig = testdata::shifted_rig(2, 640, 480, 400);
  const std::string path = testdata::temp_dir() + "/exact2.json";
  rig_save(rig, path);
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("load-file=" + path, 2), crops(2), 3, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  const GstStructure* m = calib_message(r);
  ASSERT_NE(m, nullptr);
  EXPECT_FALSE(gst_structure_has_field(m, "model")) << "a loaded file was not estimated with a model";
  EXPECT_STREQ(gst_structure_get_string(m, "source"), "file");
  ASSERT_FALSE(r.frames.empty());
  EXPECT_EQ(r.frames[0].cols, 1040);
}

TEST(StitchCalib, CalibratesFromImagesAlone) {
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("", 3), crops(), 3, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  const GstStructure* m = calib_message(r);
  ASSERT_NE(m, nullptr);
  EXPECT_STREQ(gst_structure_get_string(m, "source"), "images");
  // What lenses the cameras have (issue 15): crops of one photo have none; the first calibration
  // is pinhole (a non-live first calibration tries the lens fit and finds no evidence).
  EXPECT_STREQ(gst_structure_get_string(m, "lens"), "pinhole");
  EXPECT_FALSE(gst_structure_has_field(m, "lens-k1"));
  ASSERT_FALSE(r.frames.empty());
  EXPECT_NEAR(r.frames[0].cols, 1440, 4);
}

// Crops of the photo with camera i at x = shift * i (a rig whose cameras are `shift` px apart).
std::vector<cv::Mat> crops_apart(int n, int shift) {
  cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  std::vector<cv::Mat> v;
  for (int i = 0; i < n; ++i) v.push_back(photo(cv::Rect(shift * i, 200, 640, 480)).clone());
  return v;
}

GstElement* calib_of(GstElement* pipe) { return gst_bin_get_by_name(GST_BIN(pipe), "c"); }

void emit_recalibrate(GstElement* pipe) {
  GstElement* c = calib_of(pipe);
  g_signal_emit_by_name(c, "recalibrate");
  gst_object_unref(c);
}

int count_messages(const gsttest::RunResult& r, const char* name) {
  int n = 0;
  for (auto* s : r.element_messages) n += gst_structure_has_name(s, name);
  return n;
}

// Whether a stitchcalib-pending message gave a reason containing `text`.
bool pending_said(const gsttest::RunResult& r, const char* text) {
  for (auto* m : r.element_messages)
    if (gst_structure_has_name(m, "stitchcalib-pending")) {
      const char* why = gst_structure_get_string(m, "reason");
      if (why && std::string(why).find(text) != std::string::npos) return true;
    }
  return false;
}

// The rig moved (camera 1 now 360 px from camera 0 instead of 400): `recalibrate` collects a
// window of frames, the new calibration beats the old one on held-out frames and is installed,
// in the same panorama size, and the saved file describes the video exactly.
TEST(StitchCalib, RecalibrationAfterTheRigMovedIsInstalled) {
  const std::string saved = testdata::temp_dir() + "/moved.json";
  static const auto before = crops_apart(2, 400), after = crops_apart(2, 360);
  gsttest::RunResult r;
  gsttest::run_pipeline_frames(
      chain("calibration-frames=1 calibration-window=0.2 save-file=" + saved, 2),
      [](int f) { return f < 5 ? before : after; }, 40, r, nullptr, [](GstElement* pipe, int f) {
        if (f == 1) g_usleep(3000000);  // the first calibration is done: no backlog in the queues
        if (f == 10) emit_recalibrate(pipe);
        if (f >= 5) g_usleep(40000);  // live-camera pace: the worker finishes while frames flow
      });
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  const GstStructure* second = calib_message(r, 1);
  ASSERT_NE(second, nullptr) << "no second calibration";
  guint64 version = 0;
  gst_structure_get_uint64(second, "version", &version);
  EXPECT_EQ(version, 2u);
  EXPECT_STREQ(gst_structure_get_string(second, "source"), "recalibration");
  double previous = 0, now = 0;
  gst_structure_get_double(second, "previous-px", &previous);
  gst_structure_get_double(second, "alignment-px", &now);
  EXPECT_GT(previous, 10);
  EXPECT_LT(now, 1.5);
  EXPECT_EQ(r.frames.size(), 40u);
  // The canvas is the panorama: after the recalibration too.
  const Rig out = rig_load(saved);
  ASSERT_FALSE(r.frames.empty());
  EXPECT_EQ(out.canvas_width, r.frames.back().cols);
  EXPECT_EQ(out.canvas_height, r.frames.back().rows);
  EXPECT_LT(corner_error_vs_shift(out, 1, 360), 1.5);
}

// A static rig: the recalibration cannot clearly beat the current calibration, so it is
// reported (stitchcalib-rejected) and kept out: the geometry never flips between equals.
TEST(StitchCalib, RecalibrationThatDoesNotBeatTheCurrentIsKeptOut) {
  const std::string rig = write_file("rough2.json", rough_rig(2));
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig + " calibration-frames=1 calibration-window=0.2", 2), crops(2), 40, r,
                        nullptr, [](GstElement* pipe, int f) {
                          if (f == 5) emit_recalibrate(pipe);
                          if (f >= 5) g_usleep(40000);
                        });
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_EQ(count_messages(r, "stitchcalib"), 1);
  EXPECT_EQ(count_messages(r, "stitchcalib-rejected"), 1);
  EXPECT_EQ(r.frames.size(), 40u);
  // The message says why, in the units the judge compares (camera pixels).
  const GstStructure* rejected = nullptr;
  for (auto* m : r.element_messages)
    if (gst_structure_has_name(m, "stitchcalib-rejected")) rejected = m;
  ASSERT_NE(rejected, nullptr);
  const char* reason = gst_structure_get_string(rejected, "reason");
  ASSERT_NE(reason, nullptr) << "stitchcalib-rejected without a reason";
  EXPECT_NE(std::string(reason).find("not better"), std::string::npos) << reason;
  double cam = -2, prev = -2;
  EXPECT_TRUE(gst_structure_get_double(rejected, "alignment-camera-px", &cam));
  EXPECT_TRUE(gst_structure_get_double(rejected, "previous-camera-px", &prev));
  EXPECT_GE(cam, 0);
  EXPECT_GE(prev, 0);
}

// `recalibrate` at every frame of the pooling window: requests merge into one window, nothing
// blocks, the stream flows to the end.
TEST(StitchCalib, RecalibrateAtEveryFrameOfThePoolingWindow) {
  const std::string rig = write_file("rough2e.json", rough_rig(2));
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig + " calibration-frames=3 calibration-window=0.5", 2), crops(2), 60, r,
                        nullptr, [](GstElement* pipe, int) {
                          emit_recalibrate(pipe);
                          g_usleep(10000);
                        });
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_TRUE(r.eos);
  EXPECT_EQ(r.frames.size(), 60u);
}

// An application whose bus sync handler reads and sets stitchcalib properties on every
// stitchcalib message (posted from the streaming thread): no deadlock.
TEST(StitchCalib, BusSyncHandlerReadsAndSetsProperties) {
  static int handled;
  handled = 0;
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("calibration-frames=2 calibration-window=0.2", 2), crops(2), 20, r, nullptr,
                        [](GstElement* pipe, int f) {
                          if (f != 0) return;
                          GstBus* bus = gst_element_get_bus(pipe);
                          gst_bus_set_sync_handler(
                              bus,
                              [](GstBus*, GstMessage* m, gpointer) -> GstBusSyncReply {
                                const GstStructure* s = gst_message_get_structure(m);
                                if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ELEMENT && s &&
                                    g_str_has_prefix(gst_structure_get_name(s), "stitchcalib")) {
                                  GstElement* c = GST_ELEMENT(GST_MESSAGE_SRC(m));
                                  gint frames = 0;
                                  gchar* rig = nullptr;
                                  g_object_get(c, "calibration-frames", &frames, "rig-file", &rig, NULL);
                                  g_free(rig);
                                  g_object_set(c, "recalibrate-interval", 0.0, "min-inliers", 20, NULL);
                                  ++handled;
                                }
                                return GST_BUS_PASS;
                              },
                              nullptr, nullptr);
                          gst_object_unref(bus);
                        });
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_GE(handled, 1);
  EXPECT_EQ(r.frames.size(), 20u);
}

// set_state(NULL) while the first calibration runs (large views, seconds of work) returns
// promptly: the waiting streaming thread is released and the worker cancelled; stop() waits only
// for the calibrator's current stage to end (an application exiting while the worker ran OpenCV
// crashed in its thread pool's teardown), 0.1-0.5 s on the loaded 2-core VM, not for the
// calibration.
TEST(StitchCalib, NullDuringACalibrationReturnsPromptly) {
  gsttest::init();
  cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  cv::Mat big;
  cv::resize(photo, big, cv::Size(3200, 2132));
  std::vector<cv::Mat> views;
  for (int i = 0; i < 3; ++i) views.push_back(big(cv::Rect(700 * i, 0, 1800, 2132)).clone());
  GstElement* pipe = gst_parse_launch(chain("", 3).c_str(), nullptr);
  ASSERT_NE(pipe, nullptr);
  std::vector<GstElement*> srcs;
  for (int i = 0; i < 3; ++i) {
    GstElement* a = gst_bin_get_by_name(GST_BIN(pipe), ("a" + std::to_string(i)).c_str());
    GstCaps* caps = gst_caps_new_simple("video/x-raw", "format", G_TYPE_STRING, "RGBA", "width", G_TYPE_INT, 1800,
                                        "height", G_TYPE_INT, 2132, "framerate", GST_TYPE_FRACTION, 30, 1, NULL);
    g_object_set(a, "caps", caps, "format", GST_FORMAT_TIME, NULL);
    gst_caps_unref(caps);
    srcs.push_back(a);
  }
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  for (int i = 0; i < 3; ++i) {
    GstBuffer* b = gst_buffer_new_allocate(nullptr, views[std::size_t(i)].total() * 4, nullptr);
    gst_buffer_fill(b, 0, views[std::size_t(i)].data, views[std::size_t(i)].total() * 4);
    GST_BUFFER_PTS(b) = 0;
    GST_BUFFER_DURATION(b) = GST_SECOND / 30;
    gst_app_src_push_buffer(GST_APP_SRC(srcs[std::size_t(i)]), b);
    gst_object_unref(srcs[std::size_t(i)]);
  }
  g_usleep(400000);  // the calibration is under way
  GstBus* bus = gst_element_get_bus(pipe);
  bool calibrated = false;
  while (GstMessage* m = gst_bus_pop_filtered(bus, GST_MESSAGE_ELEMENT)) {
    calibrated |= gst_structure_has_name(gst_message_get_structure(m), "stitchcalib");
    gst_message_unref(m);
  }
  gst_object_unref(bus);
  const gint64 t0 = g_get_monotonic_time();
  gst_element_set_state(pipe, GST_STATE_NULL);
  const double took = double(g_get_monotonic_time() - t0) / G_USEC_PER_SEC;
  gst_object_unref(pipe);
  EXPECT_FALSE(calibrated) << "the calibration finished before NULL: the test proves nothing";
  EXPECT_LT(took, 1.5);
}

TEST(StitchCalib, MessageCarriesPerCameraResiduals) {
  const std::string rig = write_file("rough3r.json", rough_rig(3));
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig, 3), crops(), 2, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  const GstStructure* m = calib_message(r);
  ASSERT_NE(m, nullptr);
  double rms = 0;
  gst_structure_get_double(m, "rms-px", &rms);
  EXPECT_GT(rms, 0.0);
  EXPECT_LT(rms, 1.5);
  const GValue* cams = gst_structure_get_value(m, "camera-px");
  ASSERT_NE(cams, nullptr);
  ASSERT_EQ(gst_value_array_get_size(cams), 3u);
  for (guint i = 0; i < 3; ++i) {
    const double px = g_value_get_double(gst_value_array_get_value(cams, i));
    EXPECT_GE(px, 0.0) << i;
    EXPECT_LT(px, 1.5) << i;
  }
}

// A loaded calibration with an odd canvas: stitchblend rounds the panorama to even sizes, so
// stitchcalib pads the canvas the same way: the message and the saved file equal the video.
TEST(StitchCalib, OddLoadedCanvasEqualsTheEvenPanorama) {
  const Rig rig = testdata::shifted_rig(2, 640, 480, 401);
  ASSERT_EQ(rig.canvas_width, 1041);
  const std::string path = testdata::temp_dir() + "/odd.json", saved = testdata::temp_dir() + "/odd_saved.json";
  rig_save(rig, path);
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("load-file=" + path + " save-file=" + saved, 2), crops_apart(2, 401), 2, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_FALSE(r.frames.empty());
  const Rig out = rig_load(saved);
  EXPECT_EQ(out.canvas_width, r.frames[0].cols);
  EXPECT_EQ(out.canvas_height, r.frames[0].rows);
  EXPECT_EQ(out.canvas_width, 1042);
}

TEST(StitchCalib, ShortStillInputsThatNeverCalibrateAreAnError) {
  std::vector<cv::Mat> views = crops(3);
  views[1] = cv::Mat(480, 640, CV_8UC4, cv::Scalar(0, 0, 0, 255));
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("", 3), views, 5, r);
  ASSERT_FALSE(r.errors.empty()) << "no error: an empty output with exit 0";
  EXPECT_TRUE(r.error_contains("Could not calibrate before the stream ended")) << r.errors[0];
  EXPECT_TRUE(r.error_contains("camera 1 is dark")) << r.errors[0];  // the right camera
  EXPECT_TRUE(r.frames.empty());
}

// Two photos as one-frame streams (probe2: bridge01/02.jpg through decodebin): a photo whose
// strong horizontal edge reads as a torn picture has no second frame to show it is a still, so
// the stream ended with "Could not calibrate ... camera 1 is corrupt (a torn picture ...)" and no
// panorama. At the end of the stream the last bundle's tears are the pictures' own.
TEST(StitchCalib, AStreamThatEndsOnTornPicturesIsCalibratedOnThem) {
  cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  std::vector<cv::Mat> views;  // 200 px apart, the second glued at row 320 (a tear of 6.6x)
  for (int i = 0; i < 2; ++i) views.push_back(photo(cv::Rect(200 * i, 200, 640, 480)).clone());
  photo(cv::Rect(900, 700, 640, 160)).copyTo(views[1](cv::Rect(0, 320, 640, 160)));
  // Three frames (files): the ones held before the last come out once each, with it.
  for (const int frames : {1, 3}) {
    gsttest::RunResult r;
    gsttest::run_pipeline(chain("", 2), views, frames, r);
    ASSERT_TRUE(r.errors.empty()) << r.errors[0];
    EXPECT_EQ(r.frames.size(), std::size_t(frames));
    EXPECT_EQ(count_messages(r, "stitchcalib"), 1);
    EXPECT_TRUE(pending_said(r, "camera 1 is corrupt")) << "the test frame is not read as torn: it tests nothing";
  }
}

// Files (non-live): a first calibration attempt that fails loses no frame. Camera 2's first
// picture is mirrored (sharp and textured, but it matches no other camera: "camera 2 shares too
// few features"), as the first frame set of a 6-camera ring at 8% overlap failed; the attempt
// on the next bundle succeeds, and the first bundle, held meanwhile, goes out with it. Before,
// the retry came 0.5 s later and the 15 bundles between had no panorama (5 of 20 came out).
TEST(StitchCalib, FilesGetAPanoramaForEveryFrameWhenTheFirstAttemptFails) {
  const std::vector<cv::Mat> good = crops();
  std::vector<cv::Mat> first = good;
  first[2] = cv::Mat();
  cv::flip(good[2], first[2], 1);  // into a picture of its own
  constexpr int kFrames = 20;
  gsttest::RunResult r;
  gsttest::run_pipeline_frames(chain("", 3), [&](int f) { return f == 0 ? first : good; }, kFrames, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_TRUE(pending_said(r, "attempt failed")) << "the mirrored frame calibrated: the test tests nothing";
  EXPECT_EQ(count_messages(r, "stitchcalib"), 1);
  ASSERT_EQ(r.frames.size(), std::size_t(kFrames));
  for (const auto& f : r.frames) EXPECT_EQ(f.size(), r.frames.back().size());
  EXPECT_FALSE(r.warning_contains("are held until the first calibration"));
}

// Files wait for their first calibration (with the lens fit it took 25-192 s on the 2-core VM):
// meanwhile stitchcalib says once a second what it is doing, in stitchcalib-pending messages
// (reason, stage, attempt, calibrating-s) before the first stitchcalib message. Before, nothing
// came until the calibration: a frozen pipeline. The wait is not timed out (calibration-timeout
// counts running time, which stands still while the stream waits). Skipped when the machine
// calibrates within 1.5 s (no message is due then). Camera 2's first picture is mirrored, so that
// the first attempt fails and the second, on two pooled frame sets, makes the wait longer.
TEST(StitchCalib, FileWaitingForItsFirstCalibrationSaysSoEverySecond) {
  static std::atomic<gint64> started_us, first_calibration_us;
  started_us = first_calibration_us = 0;
  const std::vector<cv::Mat> good = crops();
  std::vector<cv::Mat> first = good;
  first[2] = cv::Mat();
  cv::flip(good[2], first[2], 1);
  gsttest::RunResult r;
  const auto frames = [&](int f) { return f == 0 ? first : good; };
  gsttest::run_pipeline_frames(chain("calibration-timeout=1", 3), frames, 5, r, nullptr, [](GstElement* pipe, int f) {
    if (f != 0) return;
    started_us = g_get_monotonic_time();
    GstBus* bus = gst_element_get_bus(pipe);
    gst_bus_set_sync_handler(
        bus,
        [](GstBus*, GstMessage* m, gpointer) -> GstBusSyncReply {
          const GstStructure* s = gst_message_get_structure(m);
          if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ELEMENT && s && gst_structure_has_name(s, "stitchcalib") &&
              first_calibration_us == 0)
            first_calibration_us = g_get_monotonic_time();
          return GST_BUS_PASS;
        },
        nullptr, nullptr);
    gst_object_unref(bus);
  });
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_NE(first_calibration_us.load(), 0) << "no calibration";
  const double waited_s = double(first_calibration_us - started_us) / G_USEC_PER_SEC;
  int said = 0;
  for (auto* m : r.element_messages) {
    if (gst_structure_has_name(m, "stitchcalib")) break;
    if (!gst_structure_has_name(m, "stitchcalib-pending")) continue;
    const char* why = gst_structure_get_string(m, "reason");
    const char* stage = gst_structure_get_string(m, "stage");
    if (!stage) continue;  // the session's own (the first attempt failed)
    int attempt = 0;
    double calibrating_s = -1, waited = -1;
    ASSERT_TRUE(why);
    EXPECT_TRUE(gst_structure_get_int(m, "attempt", &attempt));
    EXPECT_TRUE(gst_structure_get_double(m, "calibrating-s", &calibrating_s));
    EXPECT_TRUE(gst_structure_get_double(m, "waited-s", &waited));  // the field every pending message has
    EXPECT_NE(std::string(why).find("calibrating the first frames"), std::string::npos) << why;
    EXPECT_NE(std::string(why).find(stage), std::string::npos) << why;
    EXPECT_TRUE(attempt == 1 || attempt == 2) << attempt;
    EXPECT_GE(calibrating_s, 0.9);
    ++said;
  }
  std::printf("first calibration after %.2f s: %d pending messages before it\n", waited_s, said);
  if (waited_s < 1.5 && said == 0) GTEST_SKIP() << "calibrated in " << waited_s << " s: no message was due";
  EXPECT_GE(said, 1) << "the stream waited " << waited_s << " s for its first calibration in silence";
  EXPECT_LE(said, int(waited_s) + 1) << "more than one a second";
  EXPECT_TRUE(pending_said(r, "attempt failed")) << "the mirrored frame calibrated";
  EXPECT_EQ(r.frames.size(), 5u);
}

// A short file whose first frames all fail (camera 2 shows another picture: it matches no other
// camera) and whose last frame would calibrate: the back-off skipped that frame (attempts on
// frames 0 and 1), so at the end of the stream it is tried once more, pooled, and every frame
// gets a panorama. Before: none, and "Could not calibrate before the stream ended".
TEST(StitchCalib, ShortFileWhoseLastFrameCalibratesGetsEveryPanorama) {
  const std::vector<cv::Mat> good = crops();
  std::vector<cv::Mat> foreign = good;
  cv::Mat aero = testdata::load_rgba(testdata::repo_path("data/photos/aero1.jpg"));
  foreign[2] = cv::Mat();  // a picture of its own
  cv::resize(aero, foreign[2], cv::Size(640, 480), 0, 0, cv::INTER_AREA);
  constexpr int kFrames = 3;
  gsttest::RunResult r;  // pools of two frame sets: failed attempts are slow (seconds each)
  gsttest::run_pipeline_frames(chain("calibration-frames=2", 3), [&](int f) { return f == kFrames - 1 ? good : foreign; },
                               kFrames, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_EQ(count_messages(r, "stitchcalib"), 1);
  EXPECT_EQ(r.frames.size(), std::size_t(kFrames));
}

TEST(StitchCalib, PropertiesReadPerFrameAreMutableWhilePlaying) {
  gsttest::init();
  GstElement* c = gst_element_factory_make("stitchcalib", nullptr);
  ASSERT_NE(c, nullptr);
  for (const char* name : {"recalibrate-interval", "calibration-timeout", "drift-threshold", "save-file", "on-resize"}) {
    GParamSpec* p = g_object_class_find_property(G_OBJECT_GET_CLASS(c), name);
    ASSERT_NE(p, nullptr) << name;
    EXPECT_TRUE(p->flags & GST_PARAM_MUTABLE_PLAYING) << name;
  }
  // Unset projection reads back as unset, not "plane".
  gint projection = 0;
  g_object_get(c, "projection", &projection, NULL);
  GEnumValue* v = g_enum_get_value(G_ENUM_CLASS(g_type_class_peek(
                                       G_PARAM_SPEC_VALUE_TYPE(g_object_class_find_property(G_OBJECT_GET_CLASS(c), "projection")))),
                                   projection);
  ASSERT_NE(v, nullptr);
  EXPECT_STREQ(v->value_nick, "unset");
  const char* blurb = g_param_spec_get_blurb(g_object_class_find_property(G_OBJECT_GET_CLASS(c), "backend"));
  EXPECT_EQ(std::string(blurb).find("no effect"), std::string::npos);
  gst_object_unref(c);
}

// A camera leaves (its stitchsync pad is released): the two that stay are calibrated from
// scratch, as well as a fresh start with two cameras, and fitted into the panorama the stream
// has (an encoder and a muxer downstream cannot take a size change).
TEST(StitchCalib, RecalibrationAfterAPadReleaseMatchesAFreshOne) {
  const std::string saved = testdata::temp_dir() + "/released.json";
  gsttest::RunResult released, fresh;
  gsttest::run_pipeline_frames(
      chain("calibration-frames=1 save-file=" + saved, 3), [](int) { return crops(3); }, 30, released, nullptr,
      [](GstElement* pipe, int f) {
        if (f == 1) g_usleep(2000000);  // calibrated on three cameras, no backlog
        if (f != 8) return;
        g_usleep(300000);
        GstElement* sync = gst_bin_get_by_name(GST_BIN(pipe), "s");
        GstElement* a2 = gst_bin_get_by_name(GST_BIN(pipe), "a2");
        GstPad* sink2 = gst_element_get_static_pad(sync, "sink_2");
        GstPad* peer = gst_pad_get_peer(sink2);
        GstElement* queue = gst_pad_get_parent_element(peer);
        // Release first (it flushes the pad: a push blocked in it returns), then stop the branch.
        gst_element_release_request_pad(sync, sink2);
        gst_element_set_locked_state(a2, TRUE);
        gst_element_set_locked_state(queue, TRUE);
        EXPECT_EQ(gst_element_set_state(a2, GST_STATE_NULL), GST_STATE_CHANGE_SUCCESS);
        EXPECT_EQ(gst_element_set_state(queue, GST_STATE_NULL), GST_STATE_CHANGE_SUCCESS);
        gst_bin_remove_many(GST_BIN(pipe), a2, queue, NULL);
        gst_object_unref(peer);
        gst_object_unref(queue);
        gst_object_unref(sink2);
        gst_object_unref(a2);
        gst_object_unref(sync);
      });
  gsttest::run_pipeline(chain("calibration-frames=1", 2), crops(2), 4, fresh);
  ASSERT_TRUE(released.errors.empty()) << released.errors[0];
  ASSERT_TRUE(fresh.errors.empty()) << fresh.errors[0];
  const GstStructure* after = calib_message(released, 1);
  ASSERT_NE(after, nullptr) << "no recalibration after the release";
  const GstStructure* ref = calib_message(fresh, 0);
  ASSERT_NE(ref, nullptr);
  int cameras = 0, w = 0, h = 0, fw = 0, fh = 0;
  gst_structure_get_int(after, "cameras", &cameras);
  gst_structure_get_int(after, "canvas-width", &w);
  gst_structure_get_int(after, "canvas-height", &h);
  gst_structure_get_int(ref, "canvas-width", &fw);
  gst_structure_get_int(ref, "canvas-height", &fh);
  int w0 = 0, h0 = 0;
  gst_structure_get_int(calib_message(released, 0), "canvas-width", &w0);
  gst_structure_get_int(calib_message(released, 0), "canvas-height", &h0);
  EXPECT_EQ(cameras, 2);
  EXPECT_EQ(w, w0);  // the three cameras' panorama size, kept
  EXPECT_EQ(h, h0);
  EXPECT_LT(fw, w0);  // which is wider than two cameras need
  double px = -1, fresh_px = -1;
  gst_structure_get_double(after, "alignment-px", &px);
  gst_structure_get_double(ref, "alignment-px", &fresh_px);
  EXPECT_LT(px, fresh_px + 0.5);
  ASSERT_FALSE(released.frames.empty());
  EXPECT_EQ(released.frames.back().cols, w);
  EXPECT_EQ(released.frames.back().rows, h);
  const Rig out = rig_load(saved);
  EXPECT_EQ(out.cameras.size(), 2u);
  EXPECT_LT(corner_error_vs_shift(out, 1, 400), 1.5);
}

TEST(StitchCalibBadInput, MissingRigFile) {
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=/nonexistent/rig.json", 2), crops(2), 2, r);
  EXPECT_TRUE(r.error_contains("cannot open rig file")) << (r.errors.empty() ? "no error" : r.errors[0]);
}

TEST(StitchCalib, CurvedProjectionAndRotationModelFromImagesAlone) {
  // No rig-file: focal lengths and rotations are estimated from the images (it used to be an
  // error asking for one).
  for (const char* props : {"projection=cylindrical", "camera-model=rotation", "bundle-adjust=true"}) {
    gsttest::RunResult r;
    gsttest::run_pipeline(chain(props, 2), crops(2), 2, r);
    for (const auto& e : r.errors) EXPECT_EQ(e.find("rig-file"), std::string::npos) << props << ": " << e;
    EXPECT_FALSE(r.frames.empty()) << props << ": " << (r.errors.empty() ? "no panorama" : r.errors[0]);
  }
}

TEST(StitchCalibBadInput, MalformedRigFile) {
  const std::string rig = write_file("bad.json", "{\"cameras\": [ {\"width\": 640, ");
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig, 2), crops(2), 2, r);
  EXPECT_TRUE(r.error_contains("malformed JSON")) << (r.errors.empty() ? "no error" : r.errors[0]);
}

TEST(StitchCalibBadInput, CameraCountDiffersFromRig) {
  const std::string rig = write_file("rough2b.json", rough_rig(2));
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig, 3), crops(3), 2, r);
  EXPECT_TRUE(r.error_contains("describes 2 cameras but 3 streams")) << (r.errors.empty() ? "no error" : r.errors[0]);
}

TEST(StitchCalibBadInput, LoadFileWithoutCalibration) {
  const std::string rig = write_file("rough2c.json", rough_rig(2));
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("load-file=" + rig, 2), crops(2), 2, r);
  EXPECT_TRUE(r.error_contains("holds no calibration")) << (r.errors.empty() ? "no error" : r.errors[0]);
}

TEST(StitchCalibBadInput, DegenerateHomographyInLoadFile) {
  const std::string text =
      R"({"format":"stitch-rig","version":1,"reference":0,"canvas":{"width":1000,"height":480},"cameras":[)"
      R"({"width":640,"height":480,"fx":600,"homography":[1,0,0,0,1,0,0,0,1]},)"
      R"({"width":640,"height":480,"fx":600,"homography":[-1,0,1000,0,1,0,0,0,1]}]})";
  const std::string path = write_file("mirrored.json", text);
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("load-file=" + path, 2), crops(2), 2, r);
  EXPECT_TRUE(r.error_contains("camera 1: degenerate homography")) << (r.errors.empty() ? "no error" : r.errors[0]);
}

TEST(StitchCalibBadInput, TexturelessViewsKeepRoughGeometryAndWarn) {
  const std::string rig = write_file("rough2d.json", rough_rig(2));
  std::vector<cv::Mat> flat = {cv::Mat(480, 640, CV_8UC4, cv::Scalar(80, 80, 80, 255)),
                               cv::Mat(480, 640, CV_8UC4, cv::Scalar(90, 90, 90, 255))};
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig, 2), flat, 3, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_TRUE(r.warning_contains("keeping the rough homography"));
  EXPECT_EQ(r.frames.size(), 3u);  // the stream goes on with the rough calibration
}

TEST(StitchCalibBadInput, CamerasWithNoOverlapWarn) {
  // Narrow lenses (fx 1200, 30 degrees) yawed 35 degrees apart leave a gap between the views.
  const std::string rig = write_file("apart.json", rough_rig(2, 35.0, 1200));
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig, 2), crops(2), 2, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_TRUE(r.warning_contains("overlaps no other camera"));
}

TEST(StitchCalibBadInput, GrazingRigIsAClearError) {
  const std::string rig = write_file("grazing.json", rough_rig(2, 100.0));
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig, 2), crops(2), 2, r);
  EXPECT_TRUE(r.error_contains("degenerate")) << (r.errors.empty() ? "no error" : r.errors[0]);
}

// A non-live camera that starts late in wall time (a file on a slow disk, a decoder that takes
// a while): stitchsync stands in for it after dropout-timeout, and the two others would run
// ahead as fast as they decode while the first calibration, which needs every camera, drops
// their bundles (~5 s of their video here, ~11 s on the office clip). stitchcalib holds those
// bundles instead (back-pressure), so the panorama starts near the beginning of the others'.
TEST(StitchCalib, NonLiveCameraStartingLateCostsTheOthersLittleVideo) {
  gsttest::init();
  const std::string rig = write_file("rough3late.json", rough_rig(3));
  const std::vector<cv::Mat> views = crops();
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(("stitchsync name=s ! stitchcalib rig-file=" + rig +
                                       " ! stitchblend ! appsink name=out sync=false" + gsttest::appsrc_inputs(3)).c_str(),
                                      &err);
  ASSERT_NE(pipe, nullptr) << (err ? err->message : "");
  constexpr int kFrames = 300;
  std::vector<std::thread> cameras;
  const std::vector<GstElement*> srcs = gsttest::rgba_appsrcs(pipe, views);
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  for (int i = 0; i < 3; ++i)
    cameras.emplace_back([&, i]() {
      if (i == 2) g_usleep(2 * G_USEC_PER_SEC);  // camera 2 starts 2 s late, from its first frame
      for (int f = 0; f < kFrames; ++f) {
        if (!gsttest::push_frame(srcs[i], views[i], f)) return;
        g_usleep(10000);  // decoding at about 100 frames a second
      }
      gst_app_src_end_of_stream(GST_APP_SRC(srcs[i]));
    });
  GstClockTime first_pts = GST_CLOCK_TIME_NONE;
  int panoramas = 0;
  const gint64 deadline = g_get_monotonic_time() + 90 * G_TIME_SPAN_SECOND;
  while (g_get_monotonic_time() < deadline) {
    GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 50 * GST_MSECOND);
    if (s) {
      if (!panoramas++) first_pts = GST_BUFFER_PTS(gst_sample_get_buffer(s));
      gst_sample_unref(s);
    } else if (gst_app_sink_is_eos(GST_APP_SINK(sink))) {
      break;
    }
  }
  gst_element_set_state(pipe, GST_STATE_NULL);
  for (auto& t : cameras) t.join();
  for (auto* a : srcs) gst_object_unref(a);
  gst_object_unref(sink);
  gst_object_unref(pipe);
  ASSERT_GT(panoramas, 0);
  std::printf("camera 2 started 2 s late: first panorama at %.2f s of the others' video, %d panoramas of %d\n",
              double(first_pts) / GST_SECOND, panoramas, kFrames);
  EXPECT_LT(double(first_pts) / GST_SECOND, 1.5);
  EXPECT_GT(panoramas, kFrames - 60);
}

// A camera that shows only black (a lens cap, a dead sensor) is left out after 4 s: the others are
// calibrated and stitched, with a warning naming it; once it shows a picture it joins, with a
// calibration from scratch and a second warning. Before, no panorama came out at all.
TEST(StitchCalib, DarkCameraIsLeftOutThenJoins) {
  const std::vector<cv::Mat> good = crops();
  const cv::Mat black(good[2].size(), CV_8UC4, cv::Scalar(0, 0, 0, 255));
  constexpr int kFrames = 300, kDarkUntil = 180;
  gsttest::RunResult r;
  // The whole default chain: colour and the flow warp must take a camera that is on no canvas.
  gsttest::run_pipeline_frames("stitchsync name=s ! stitchcalib name=c ! stitchcolor ! stitchflowwarp ! stitchblend ! "
                               "appsink name=out sync=false" + gsttest::appsrc_inputs(3),
                               [&](int f) {
                                 std::vector<cv::Mat> v = good;
                                 if (f < kDarkUntil) v[2] = black;
                                 return v;
                               },
                               kFrames, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_TRUE(r.warning_contains("camera 2 delivered no picture"));
  // Non-live cameras: the stream waits for the calibration with it (stream_waits_for_job), so the
  // last calibration has every camera whatever the machine's load.
  EXPECT_TRUE(r.warning_contains("camera 2 delivers a picture now: calibrating again with it (the stream waits"));
  ASSERT_FALSE(r.frames.empty());
  // Stitched from 4 s on (120 frames), the dark camera's 2 s included.
  EXPECT_GT(int(r.frames.size()), kFrames - 120 - 30);
  // The first calibration leaves camera 2 out (and says so), the last one has all three.
  const GstStructure* first = calib_message(r);
  ASSERT_NE(first, nullptr);
  const GValue* left_out = gst_structure_get_value(first, "left-out");
  ASSERT_NE(left_out, nullptr);
  ASSERT_EQ(gst_value_array_get_size(left_out), 1u);
  EXPECT_EQ(g_value_get_int(gst_value_array_get_value(left_out, 0)), 2);
  const GstStructure* last_calib = nullptr;
  for (int k = 0; calib_message(r, k); ++k) last_calib = calib_message(r, k);
  EXPECT_NE(last_calib, first);
  EXPECT_FALSE(gst_structure_has_field(last_calib, "left-out"));
  const cv::Mat& last = r.frames.back();
  std::printf("dark camera 2 for %d frames: %zu panoramas of %d, first %dx%d, last %dx%d\n", kDarkUntil,
              r.frames.size(), kFrames, r.frames.front().cols, r.frames.front().rows, last.cols, last.rows);
}

// A file camera that never delivers a frame (a dead input that never ends): after the late-camera
// hold, the others are stitched without it from 4 s of their running time, with a warning naming it.
// Before, no panorama came out at all.
TEST(StitchCalib, CameraThatNeverDeliversIsLeftOut) {
  gsttest::init();
  const std::vector<cv::Mat> views = crops();
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(
      ("stitchsync name=s ! stitchcalib ! stitchblend ! appsink name=out sync=false" + gsttest::appsrc_inputs(3)).c_str(),
      &err);
  ASSERT_NE(pipe, nullptr) << (err ? err->message : "");
  constexpr int kFrames = 240;
  const std::vector<GstElement*> srcs = gsttest::rgba_appsrcs(pipe, views);
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  GstBus* bus = gst_element_get_bus(pipe);
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  std::atomic<int> finished{0};
  std::vector<std::thread> cameras;
  for (int i = 0; i < 2; ++i)
    cameras.emplace_back([&, i]() {
      for (int f = 0; f < kFrames; ++f) {
        if (!gsttest::push_frame(srcs[i], views[i], f)) break;
      }
      gst_app_src_end_of_stream(GST_APP_SRC(srcs[i]));
      ++finished;
    });
  int panoramas = 0;
  bool named = false, ended_camera2 = false;
  std::string error;
  const gint64 deadline = g_get_monotonic_time() + 90 * G_TIME_SPAN_SECOND;
  while (g_get_monotonic_time() < deadline && error.empty()) {
    if (GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 50 * GST_MSECOND)) {
      ++panoramas;
      gst_sample_unref(s);
    } else if (gst_app_sink_is_eos(GST_APP_SINK(sink))) {
      break;
    }
    if (finished == 2 && !ended_camera2) {  // the dead camera's source ends last
      gst_app_src_end_of_stream(GST_APP_SRC(srcs[2]));
      ended_camera2 = true;
    }
    while (GstMessage* m = gst_bus_pop(bus)) {
      GError* e = nullptr;
      if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_WARNING) {
        gst_message_parse_warning(m, &e, nullptr);
        named = named || std::string(e->message).find("camera 2 delivered no picture") != std::string::npos;
      } else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) {
        gst_message_parse_error(m, &e, nullptr);
        error = e->message;
      }
      if (e) g_error_free(e);
      gst_message_unref(m);
    }
  }
  gst_element_set_state(pipe, GST_STATE_NULL);
  for (auto& t : cameras) t.join();
  for (auto* a : srcs) gst_object_unref(a);
  gst_object_unref(sink);
  gst_object_unref(bus);
  gst_object_unref(pipe);
  std::printf("camera 2 never delivered: %d panoramas of %d\n", panoramas, kFrames);
  EXPECT_TRUE(error.empty()) << error;
  EXPECT_TRUE(named);
  EXPECT_GT(panoramas, kFrames - 120 - 30);
}

// With a rig-file, a dark camera in the middle (the reference) is left out too: the rough rig
// places the two outer cameras, which do not overlap, on the canvas without it.
TEST(StitchCalib, DarkReferenceCameraIsLeftOutOfARigFileCalibration) {
  const std::string rig = write_file("rough3dark.json", rough_rig(3));
  std::vector<cv::Mat> views = crops();
  views[1] = cv::Mat(views[1].size(), CV_8UC4, cv::Scalar(0, 0, 0, 255));
  gsttest::RunResult r;
  gsttest::run_pipeline(chain("rig-file=" + rig, 3), views, 200, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_TRUE(r.warning_contains("camera 1 delivered no picture"));
  EXPECT_GT(int(r.frames.size()), 200 - 120 - 10);
  const GstStructure* m = calib_message(r);
  ASSERT_NE(m, nullptr);
  const GValue* left_out = gst_structure_get_value(m, "left-out");
  ASSERT_NE(left_out, nullptr);
  EXPECT_EQ(g_value_get_int(gst_value_array_get_value(left_out, 0)), 1);
  // Both outer crops show: the panorama's left and right quarters are not black.
  ASSERT_FALSE(r.frames.empty());
  const cv::Mat& pano = r.frames.back();
  for (const int x0 : {0, pano.cols * 3 / 4}) {
    const cv::Scalar mean = cv::mean(pano(cv::Rect(x0, pano.rows / 4, pano.cols / 4, pano.rows / 2)));
    EXPECT_GT(mean[0] + mean[1] + mean[2], 60) << x0 << " of " << pano.cols;
  }
}

// Issue 15, "defaults are the product": three barrel-distorted cameras (k1 -0.23, k2 0.055)
// rendered from the photo, stitchcalib with default properties and no rig-file. The first
// calibration is pinhole; the background lens fit then installs radtan lenses (a second
// `stitchcalib` message, source lens, with lens-k1 per camera near the truth) and the seams
// close. The frames flow at a live pace until it is in (at most ~40 s). Live cameras: non-live
// ones get the lens in the first calibration (branch lens-short, CalibSessionLensShortFile).
TEST(StitchCalib, DistortedCamerasGetALensInTheBackground) {
  static std::atomic<bool> lens_in;
  lens_in = false;
  const Rig truth = testdata::radtan_trio(320, 240, 260, 35.0, -0.23, 0.055, true, "spherical", 0.0);
  const cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  ASSERT_FALSE(photo.empty());
  static std::vector<cv::Mat> frames;
  frames.clear();
  for (const auto& c : truth.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
  gsttest::RunResult r;
  std::string live_chain = chain("", 3);
  for (std::size_t at = 0; (at = live_chain.find(" ! queue", at)) != std::string::npos; at += 20)
    live_chain.insert(at, " is-live=true");
  gsttest::run_pipeline(live_chain, frames, 330, r, nullptr, [](GstElement* pipe, int f) {
    if (f == 0) {
      GstBus* bus = gst_element_get_bus(pipe);
      gst_bus_set_sync_handler(
          bus,
          [](GstBus*, GstMessage* m, gpointer) -> GstBusSyncReply {
            const GstStructure* s = gst_message_get_structure(m);
            if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ELEMENT && s && g_str_has_prefix(gst_structure_get_name(s), "stitchcalib") &&
                g_strcmp0(gst_structure_get_string(s, "source"), "lens") == 0)
              lens_in = true;
            return GST_BUS_PASS;
          },
          nullptr, nullptr);
      gst_object_unref(bus);
    }
    if (f >= 60 && !lens_in) g_usleep(150000);
  });
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  const GstStructure *first = nullptr, *lens = nullptr;
  for (auto* m : r.element_messages) {
    const char* src = gst_structure_get_string(m, "source");
    if (!g_str_has_prefix(gst_structure_get_name(m), "stitchcalib") || !src) continue;
    if (!first && gst_structure_has_name(m, "stitchcalib")) first = m;
    if (g_str_equal(src, "lens")) lens = m;
  }
  ASSERT_NE(first, nullptr);
  EXPECT_STREQ(gst_structure_get_string(first, "lens"), "pinhole");
  ASSERT_NE(lens, nullptr) << "no lens fit in the background";
  ASSERT_TRUE(gst_structure_has_name(lens, "stitchcalib")) << gst_structure_get_string(lens, "reason");
  EXPECT_STREQ(gst_structure_get_string(lens, "lens"), "radtan");
  const GValue* k1 = gst_structure_get_value(lens, "lens-k1");
  ASSERT_NE(k1, nullptr);
  ASSERT_EQ(gst_value_array_get_size(k1), 3u);
  for (guint i = 0; i < 3; ++i) EXPECT_NEAR(g_value_get_double(gst_value_array_get_value(k1, i)), -0.23, 0.25 * 0.23);
  double now = -1, before = -1;
  gst_structure_get_double(lens, "alignment-camera-px", &now);
  gst_structure_get_double(lens, "previous-camera-px", &before);
  std::printf("lens installed: %.3f camera px (pinhole %.3f)\n", now, before);
  EXPECT_LT(now, 0.7 * before);
  // Live: the aggregator also puts out a panorama when the held-back inputs are late.
  EXPECT_GE(r.frames.size(), 330u);
}
