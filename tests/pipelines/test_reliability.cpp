// Reliability: cameras that drop out and come back (ended, stalled, timestamp jumps, live
// stalls), frames from the past (QoS), inputs that change resolution, flushing seeks, and bad
// frames (black, saturated, 1x1) and 16 inputs through the whole chain.
#include <gst/app/app.h>
#include <gst/gst.h>
#include <gst/video/video.h>
#include <gtest/gtest.h>

#include <cstdio>
#include <functional>
#include <opencv2/imgproc.hpp>
#include <string>
#include <thread>
#include <vector>

// Only the struct layout of the bundle meta is used from here (the plugin is not linked).
#include "../../gst/gststitchbundle.h"
#include "gst_helpers.hpp"
#include "synthetic_rig.hpp"
#include "test_data.hpp"

namespace {

constexpr int kFps = 30;

GstClockTime frame_time(int f) { return gst_util_uint64_scale(guint64(f), GST_SECOND, kFps); }

// One frame to push: its image (RGBA) and frame number (timestamp f/30 s).
struct Push {
  int frame;
  cv::Mat image;
  int pause_ms = 0;  // wall-clock wait before pushing it (a camera that stalls)
};

// Uniform RGBA image whose red channel codes (input, frame): decoded back from the bundles.
cv::Mat coded(int input, int frame, int w = 32, int h = 24) {
  return cv::Mat(h, w, CV_8UC4, cv::Scalar(1 + frame, 200, 40 + 50 * input, 255));
}

struct Output {
  GstClockTime pts;
  guint64 missing;
  std::vector<cv::Vec4b> view_pixel;  // centre pixel of each view (bundles)
  cv::Mat panorama;                   // stitchblend output
};

struct Collected {
  std::vector<Output> outputs;
  std::vector<std::string> errors, warnings;
  std::vector<GstStructure*> dropouts;  // stitchsync-dropout messages, in order (owned)
  std::vector<std::pair<guint64, guint64>> qos;  // (processed, dropped) of QoS messages
  std::vector<GstStructure*> calibrations;       // stitchcalib messages (owned)
  ~Collected() {
    for (auto* s : dropouts) gst_structure_free(s);
    for (auto* s : calibrations) gst_structure_free(s);
  }
  bool warned(const std::string& a, const std::string& b = "") const {
    for (const auto& w : warnings)
      if (w.find(a) != std::string::npos && w.find(b) != std::string::npos) return true;
    return false;
  }
  bool failed(const std::string& a, const std::string& b = "") const {
    for (const auto& w : errors)
      if (w.find(a) != std::string::npos && w.find(b) != std::string::npos) return true;
    return false;
  }
};

const GstStitchBundleMeta* bundle_meta(GstBuffer* buf) {
  gpointer state = nullptr;
  while (GstMeta* m = gst_buffer_iterate_meta(buf, &state))
    if (g_strcmp0(g_type_name(m->info->api), "GstStitchBundleMetaAPI") == 0)
      return reinterpret_cast<const GstStitchBundleMeta*>(m);
  return nullptr;
}

void read_sample(GstSample* s, Collected& run) {
  GstBuffer* b = gst_sample_get_buffer(s);
  Output o;
  o.pts = GST_BUFFER_PTS(b);
  const GstStitchBundleMeta* bm = bundle_meta(b);
  o.missing = bm ? bm->missing_mask : 0;
  if (bm) {
    for (guint i = 0; i < bm->n_views; ++i) {
      GstVideoMeta* vm = gst_buffer_get_video_meta_id(b, gint(i));
      GstMapInfo map;
      gpointer data = nullptr;
      gint stride = 0;
      cv::Vec4b px(0, 0, 0, 0);
      if (vm && gst_video_meta_map(vm, 0, &map, &data, &stride, GST_MAP_READ)) {
        const auto* p = static_cast<const guint8*>(data) + gsize(vm->height / 2) * stride + (vm->width / 2) * 4;
        px = cv::Vec4b(p[0], p[1], p[2], p[3]);
        gst_video_meta_unmap(vm, 0, &map);
      }
      o.view_pixel.push_back(px);
    }
  } else {
    GstVideoInfo info;
    gst_video_info_from_caps(&info, gst_sample_get_caps(s));
    GstVideoFrame vf;
    if (gst_video_frame_map(&vf, &info, b, GST_MAP_READ)) {
      o.panorama = cv::Mat(info.height, info.width, CV_8UC4, GST_VIDEO_FRAME_PLANE_DATA(&vf, 0),
                           GST_VIDEO_FRAME_PLANE_STRIDE(&vf, 0))
                       .clone();
      gst_video_frame_unmap(&vf);
    }
  }
  run.outputs.push_back(o);
}

void read_message(GstMessage* m, Collected& run) {
  switch (GST_MESSAGE_TYPE(m)) {
    case GST_MESSAGE_ERROR:
    case GST_MESSAGE_WARNING: {
      GError* e = nullptr;
      if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) gst_message_parse_error(m, &e, nullptr);
      else gst_message_parse_warning(m, &e, nullptr);
      (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR ? run.errors : run.warnings).push_back(e->message);
      g_error_free(e);
      break;
    }
    case GST_MESSAGE_QOS: {
      GstFormat fmt;
      guint64 processed = 0, dropped = 0;
      gst_message_parse_qos_stats(m, &fmt, &processed, &dropped);
      run.qos.emplace_back(processed, dropped);
      break;
    }
    case GST_MESSAGE_ELEMENT: {
      const GstStructure* s = gst_message_get_structure(m);
      if (s && gst_structure_has_name(s, "stitchsync-dropout")) run.dropouts.push_back(gst_structure_copy(s));
      if (s && gst_structure_has_name(s, "stitchcalib")) run.calibrations.push_back(gst_structure_copy(s));
      break;
    }
    default: break;
  }
}

// Runs `description` (appsrc a0..a{n-1}, appsink out): input i gets pushes[i] (each frame
// timestamped f/30 s, lasting 1/30 s; a frame of another size changes the caps first), then
// EOS. Collects every output and message until EOS, an error or `timeout_s`.
void run_pipeline(const std::string& description, const std::vector<std::vector<Push>>& pushes, Collected& run,
                  double timeout_s = 30) {
  gsttest::init();
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(description.c_str(), &err);
  ASSERT_NE(pipe, nullptr) << (err ? err->message : "parse failed");
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  g_object_set(sink, "sync", FALSE, "max-buffers", 4u, NULL);
  std::vector<GstElement*> srcs;
  for (std::size_t i = 0; i < pushes.size(); ++i) {
    GstElement* a = gst_bin_get_by_name(GST_BIN(pipe), ("a" + std::to_string(i)).c_str());
    g_object_set(a, "format", GST_FORMAT_TIME, "block", TRUE, "max-bytes", guint64(8 << 20), NULL);
    srcs.push_back(a);
  }
  GstBus* bus = gst_element_get_bus(pipe);
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  std::vector<std::thread> pushers;
  for (std::size_t i = 0; i < pushes.size(); ++i) {
    pushers.emplace_back([a = srcs[i], &list = pushes[i]]() {
      cv::Size size;
      for (const Push& p : list) {
        if (p.image.size() != size) {
          size = p.image.size();
          GstCaps* caps = gst_caps_new_simple("video/x-raw", "format", G_TYPE_STRING, "RGBA", "width", G_TYPE_INT,
                                              size.width, "height", G_TYPE_INT, size.height, "framerate",
                                              GST_TYPE_FRACTION, kFps, 1, NULL);
          g_object_set(a, "caps", caps, NULL);
          gst_caps_unref(caps);
        }
        if (p.pause_ms > 0) g_usleep(gulong(p.pause_ms) * 1000);
        GstBuffer* b = gst_buffer_new_allocate(nullptr, p.image.total() * 4, nullptr);
        gst_buffer_fill(b, 0, p.image.data, p.image.total() * 4);
        GST_BUFFER_PTS(b) = frame_time(p.frame);
        GST_BUFFER_DURATION(b) = frame_time(p.frame + 1) - frame_time(p.frame);
        if (gst_app_src_push_buffer(GST_APP_SRC(a), b) != GST_FLOW_OK) return;
      }
      gst_app_src_end_of_stream(GST_APP_SRC(a));
    });
  }
  bool eos = false;
  const gint64 deadline = g_get_monotonic_time() + gint64(timeout_s * G_TIME_SPAN_SECOND);
  while (!eos && run.errors.empty() && g_get_monotonic_time() < deadline) {
    if (GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 20 * GST_MSECOND)) {
      read_sample(s, run);
      gst_sample_unref(s);
    } else if (gst_app_sink_is_eos(GST_APP_SINK(sink))) {
      eos = true;
    }
    while (GstMessage* m = gst_bus_pop(bus)) {
      read_message(m, run);
      gst_message_unref(m);
    }
  }
  EXPECT_TRUE(eos || !run.errors.empty()) << "neither EOS nor an error within " << timeout_s << " s";
  // An error ends the loop above at once, but outputs made before it may still wait in the
  // appsink (the error is posted by a later bundle): collect them before NULL flushes them.
  while (GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 0)) {
    read_sample(s, run);
    gst_sample_unref(s);
  }
  gst_element_set_state(pipe, GST_STATE_NULL);
  for (auto& t : pushers) t.join();
  while (GstMessage* m = gst_bus_pop(bus)) {
    read_message(m, run);
    gst_message_unref(m);
  }
  gst_object_unref(bus);
  for (auto* a : srcs) gst_object_unref(a);
  gst_object_unref(sink);
  gst_object_unref(pipe);
}

std::vector<Push> coded_frames(int input, int first, int last) {
  std::vector<Push> v;
  for (int f = first; f <= last; ++f) v.push_back({f, coded(input, f)});
  return v;
}

// Frame number a view's centre pixel codes for `input`; -1 for anything else (black).
int frame_of(const cv::Vec4b& px, int input) {
  if (px[1] != 200 || px[2] != 40 + 50 * input) return -1;
  return int(px[0]) - 1;
}

std::string bundles(const std::string& sync_props, int n) {
  return "stitchsync name=s " + sync_props + " ! appsink name=out" + gsttest::appsrc_inputs(n);
}

}  // namespace

// A file camera whose timestamps jump 1 s ahead (a hole in the file, variable frame rate): its
// later frames are already queued, so it never "dropped out": no warning, no message, its last
// frame shows through the hole and it goes on with the frames after it.
TEST(FileGaps, TimestampHoleIsNotADropout) {
  std::vector<std::vector<Push>> in = {coded_frames(0, 0, 59), coded_frames(1, 0, 9)};
  for (const Push& p : coded_frames(1, 40, 59)) in[1].push_back(p);
  Collected run;
  run_pipeline(bundles("dropout=fill dropout-timeout=250000000", 2), in, run);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_EQ(run.outputs.size(), 60u);
  for (int k = 0; k < 60; ++k) {
    SCOPED_TRACE("output " + std::to_string(k));
    const Output& o = run.outputs[std::size_t(k)];
    EXPECT_EQ(o.pts, frame_time(k));
    EXPECT_EQ(frame_of(o.view_pixel[0], 0), k);
    EXPECT_FALSE(o.missing & 2);
    EXPECT_EQ(frame_of(o.view_pixel[1], 1), k < 40 ? std::min(k, 9) : k);
  }
  EXPECT_TRUE(run.dropouts.empty());
  EXPECT_FALSE(run.warned("dropped out"));
}

// Variable frame rate files (frame durations from 10 to 200 ms): never dropped out.
TEST(FileGaps, VariableFrameRateIsNotADropout) {
  std::vector<std::vector<Push>> in = {coded_frames(0, 0, 59), {}};
  for (int f = 0; f < 58; f += 1 + (f * 7) % 6) in[1].push_back({f, coded(1, f)});
  in[1].push_back({59, coded(1, 59)});
  Collected run;
  run_pipeline(bundles("dropout-timeout=100000000", 2), in, run);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  EXPECT_EQ(run.outputs.size(), 60u);
  EXPECT_TRUE(run.dropouts.empty());
  EXPECT_FALSE(run.warned("dropped out"));
}

class Dropout : public ::testing::TestWithParam<bool> {};

// File inputs that may stall: force-live aggregates on the clock, the stalled camera drops out
// and rejoins, and the stream still ends when every input has ended.
TEST(ForceLive, StallingFileInputDropsOutAndTheStreamEnds) {
  std::vector<std::vector<Push>> in = {coded_frames(0, 0, 59), coded_frames(1, 0, 9)};
  for (const Push& p : coded_frames(1, 40, 59)) in[1].push_back(p);
  in[1][10].pause_ms = 1000;  // the camera stalls: nothing arrives for a second
  Collected run;
  run_pipeline(bundles("force-live=true latency=50000000 dropout=fill dropout-timeout=250000000", 2), in, run, 10);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  EXPECT_GE(run.outputs.size(), 55u);
  EXPECT_LE(run.outputs.size(), 61u);
  EXPECT_TRUE(run.warned("sink_1", "dropped out"));
  ASSERT_EQ(run.dropouts.size(), 2u) << "one dropout and one rejoin, nothing at the end";
  EXPECT_FALSE(run.outputs.back().missing & 2);
}

// A camera that ends: with fill its view is left out from then on (a warning says it ended).
TEST_P(Dropout, EndedCameraIsLeftOutOrFrozen) {
  const bool fill = GetParam();
  Collected run;
  run_pipeline(bundles(std::string("dropout=") + (fill ? "fill" : "freeze"), 2),
               {coded_frames(0, 0, 29), coded_frames(1, 0, 9)}, run);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_EQ(run.outputs.size(), 30u);
  for (int k = 12; k < 30; ++k) {
    EXPECT_EQ(bool(run.outputs[std::size_t(k)].missing & 2), fill) << k;
    if (!fill) {
      EXPECT_EQ(frame_of(run.outputs[std::size_t(k)].view_pixel[1], 1), 9) << k;
    }
  }
  EXPECT_TRUE(run.warned("sink_1", "it ended"));
  ASSERT_EQ(run.dropouts.size(), 1u);
}

INSTANTIATE_TEST_SUITE_P(Modes, Dropout, ::testing::Values(true, false),
                         [](const auto& info) { return info.param ? "Fill" : "Freeze"; });

// A frame that ends before one its input already delivered is dropped with a QoS message; the
// frames around it are stitched as usual.
TEST(LateFrames, FrameFromThePastDroppedWithQos) {
  std::vector<std::vector<Push>> in = {coded_frames(0, 0, 19), coded_frames(1, 0, 7)};
  in[1].push_back({3, coded(1, 3)});  // from the past
  for (const Push& p : coded_frames(1, 8, 19)) in[1].push_back(p);
  Collected run;
  run_pipeline(bundles("", 2), in, run);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_EQ(run.outputs.size(), 20u);
  for (int k = 0; k < 20; ++k) EXPECT_EQ(frame_of(run.outputs[std::size_t(k)].view_pixel[1], 1), k) << k;
  ASSERT_EQ(run.qos.size(), 1u) << "the dropped frame was not announced";
  EXPECT_EQ(run.qos[0].second, 1u);
  EXPECT_EQ(run.qos[0].first, 8u);
  EXPECT_TRUE(run.dropouts.empty());
}

// A camera whose clock jumps back sends a run of frames from the past: each is dropped, but the
// QoS messages are rate-limited (one per input per second, carrying the running totals).
TEST(LateFrames, QosMessagesAreRateLimited) {
  std::vector<std::vector<Push>> in = {coded_frames(0, 0, 59), coded_frames(1, 0, 29)};
  for (int f = 0; f < 29; ++f) in[1].push_back({f, coded(1, f)});  // 29 frames from the past
  for (const Push& p : coded_frames(1, 30, 59)) in[1].push_back(p);
  Collected run;
  run_pipeline(bundles("", 2), in, run);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  EXPECT_EQ(run.outputs.size(), 60u);
  ASSERT_GE(run.qos.size(), 1u);
  EXPECT_LE(run.qos.size(), 3u) << "one QoS message per dropped frame";
}

// A camera that starts late, with a complete calibration file: the file needs no pixels, so
// stitchcalib stitches from the first bundle on, the late camera missing (its region filled by
// the other) until it starts; nothing is dropped. (Calibrating from the images still waits for
// every camera.)
TEST(LateFrames, CompleteLoadFileStitchesBeforeALateCameraStarts) {
  const std::string calib = testdata::temp_dir() + "/late_start.json";
  stitch::rig_save(testdata::shifted_rig(2, 32, 24, 16), calib);
  Collected run;
  run_pipeline("stitchsync name=s ! stitchcalib load-file=" + calib + " ! stitchblend ! appsink name=out" +
                   gsttest::appsrc_inputs(2),
               {coded_frames(0, 0, 11), coded_frames(1, 3, 11)}, run);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  EXPECT_EQ(run.outputs.size(), 12u);
  EXPECT_TRUE(run.qos.empty()) << "bundles dropped while the file was there";
  EXPECT_EQ(run.outputs.front().pts, frame_time(0));
}

namespace {

// Pulls samples and messages for `ms` of wall-clock time; `on_tick(t_ms)` runs each round.
void collect_for(GstElement* pipe, GstElement* sink, int ms, Collected& run,
                 const std::function<void(gint64)>& on_tick = nullptr) {
  GstBus* bus = gst_element_get_bus(pipe);
  const gint64 start = g_get_monotonic_time();
  while (g_get_monotonic_time() - start < gint64(ms) * 1000 && run.errors.empty()) {
    if (on_tick) on_tick((g_get_monotonic_time() - start) / 1000);
    if (GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 10 * GST_MSECOND)) {
      read_sample(s, run);
      gst_sample_unref(s);
    }
    while (GstMessage* m = gst_bus_pop(bus)) {
      read_message(m, run);
      gst_message_unref(m);
    }
  }
  gst_object_unref(bus);
}

}  // namespace

// Live cameras: one stalls for 0.6 s (a valve drops its frames). The aggregator's latency
// timeout keeps the panorama going; the camera is left out meanwhile and rejoins.
TEST(LiveDropout, StalledLiveCameraIsLeftOutAndRejoins) {
  gsttest::init();
  const std::string desc =
      "stitchsync name=s latency=40000000 dropout=fill dropout-timeout=150000000 ! appsink name=out sync=false "
      "videotestsrc is-live=true pattern=red ! video/x-raw,format=RGBA,width=32,height=24,framerate=30/1 ! s.sink_0 "
      "videotestsrc is-live=true pattern=green ! video/x-raw,format=RGBA,width=32,height=24,framerate=30/1 ! "
      "valve name=v ! s.sink_1";
  GstElement* pipe = gst_parse_launch(desc.c_str(), nullptr);
  ASSERT_NE(pipe, nullptr);
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  GstElement* valve = gst_bin_get_by_name(GST_BIN(pipe), "v");
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  Collected run;
  collect_for(pipe, sink, 2200, run, [&](gint64 t) { g_object_set(valve, "drop", t > 600 && t <= 1200, NULL); });
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(valve);
  gst_object_unref(sink);
  gst_object_unref(pipe);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_GT(run.outputs.size(), 40u);
  // the output never stopped: consecutive timestamps one frame apart
  int left_out = 0, back_after = 0;
  for (std::size_t k = 1; k < run.outputs.size(); ++k) {
    EXPECT_NEAR(double(run.outputs[k].pts - run.outputs[k - 1].pts), double(frame_time(1)), 1.0) << k;
    if (run.outputs[k].missing & 2) ++left_out;
    else if (left_out > 0) ++back_after;
  }
  EXPECT_GT(left_out, 5) << "the stalled camera was never left out";
  EXPECT_GT(back_after, 5) << "the camera did not rejoin";
  EXPECT_TRUE(run.warned("sink_1", "dropped out"));
  ASSERT_GE(run.dropouts.size(), 2u);
  gboolean dropped = TRUE;
  gst_structure_get_boolean(run.dropouts.back(), "dropped", &dropped);
  EXPECT_FALSE(dropped);
}

// ---------------------------------------------------------------------------------------------
// Resolution changes: crops of a real photo; the cameras switch to half size after 4 frames.

namespace {

struct Scene {
  cv::Mat photo;
  std::string calib;  // exact calibration of two 640x480 crops 400 px apart
  std::vector<cv::Mat> views(double scale) const {
    std::vector<cv::Mat> v;
    for (int i = 0; i < 2; ++i) {
      cv::Mat m = photo(cv::Rect(400 * i, 200, 640, 480)).clone();
      if (scale != 1.0) cv::resize(m, m, cv::Size(), scale, scale, cv::INTER_AREA);
      v.push_back(m);
    }
    return v;
  }
};

const Scene& scene() {
  static Scene s = []() {
    Scene sc;
    sc.photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
    sc.calib = testdata::temp_dir() + "/reliability_exact.json";
    stitch::rig_save(testdata::shifted_rig(2, 640, 480, 400), sc.calib);
    return sc;
  }();
  return s;
}

std::vector<std::vector<Push>> resizing_inputs() {
  std::vector<std::vector<Push>> in(2);
  const auto full = scene().views(1.0), half = scene().views(0.5);
  for (int f = 0; f < 8; ++f)
    for (int i = 0; i < 2; ++i) in[std::size_t(i)].push_back({f, f < 4 ? full[std::size_t(i)] : half[std::size_t(i)]});
  return in;
}

}  // namespace

TEST(Resize, RecalibratesForTheNewSize) {
  Collected run;
  run_pipeline("stitchsync name=s ! stitchcalib load-file=" + scene().calib +
                   " on-resize=recalibrate ! stitchblend ! appsink name=out" + gsttest::appsrc_inputs(2),
               resizing_inputs(), run);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_EQ(run.outputs.size(), 8u);
  EXPECT_TRUE(run.warned("resolution changed", "camera 0 640x480 -> 320x240"));
  ASSERT_EQ(run.calibrations.size(), 2u) << "no second calibration";
  guint64 version = 0;
  gst_structure_get_uint64(run.calibrations[1], "version", &version);
  EXPECT_EQ(version, 2u);
  // The saved calibration is scaled to the new size: the canvas (and the output) stay, and the
  // half-size frames still land where the scene is (the old geometry would cover a quarter).
  const cv::Mat want = scene().photo(cv::Rect(0, 200, 1040, 480));
  ASSERT_EQ(run.outputs[7].panorama.size(), want.size());
  EXPECT_GT(testdata::psnr_rgb(run.outputs[0].panorama, want), 40.0);
  EXPECT_GT(testdata::psnr_rgb(run.outputs[7].panorama, want), 24.0);
}

// Calibrated from the images: the cameras' change of resolution recalibrates from scratch (never
// from the geometry made for the old sizes), as good as a fresh start on the new frames, fitted
// into the panorama the stream has (an encoder and a muxer cannot take a size change; the saved
// canvas is the video's size).
TEST(Resize, RecalibrationFromTheImagesMatchesAFreshOne) {
  const std::string desc = "stitchsync name=s ! stitchcalib calibration-frames=1 ! stitchblend ! appsink name=out" +
                           gsttest::appsrc_inputs(2);
  Collected run, fresh;
  run_pipeline(desc, resizing_inputs(), run);
  std::vector<std::vector<Push>> half(2);
  const auto small = scene().views(0.5);
  for (int f = 0; f < 4; ++f)
    for (int i = 0; i < 2; ++i) half[std::size_t(i)].push_back({f, small[std::size_t(i)]});
  run_pipeline(desc, half, fresh);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_TRUE(fresh.errors.empty()) << fresh.errors[0];
  ASSERT_EQ(run.outputs.size(), 8u);
  ASSERT_EQ(run.calibrations.size(), 2u);
  ASSERT_EQ(fresh.calibrations.size(), 1u);
  int w = 0, h = 0, w0 = 0, h0 = 0, fw = 0;
  gst_structure_get_int(run.calibrations[1], "canvas-width", &w);
  gst_structure_get_int(run.calibrations[1], "canvas-height", &h);
  gst_structure_get_int(run.calibrations[0], "canvas-width", &w0);
  gst_structure_get_int(run.calibrations[0], "canvas-height", &h0);
  gst_structure_get_int(fresh.calibrations[0], "canvas-width", &fw);
  EXPECT_EQ(w, w0);
  EXPECT_EQ(h, h0);
  EXPECT_LT(fw, w0 * 2 / 3) << "a fresh start on the half-size frames makes a smaller canvas";
  // As well aligned as the fresh start, in camera pixels (the canvas pixels differ by the fit).
  double px = -1, fresh_px = -1;
  gst_structure_get_double(run.calibrations[1], "alignment-camera-px", &px);
  gst_structure_get_double(fresh.calibrations[0], "alignment-camera-px", &fresh_px);
  EXPECT_LT(px, fresh_px + 0.5);
  EXPECT_EQ(run.outputs[7].panorama.cols, w0);
  EXPECT_EQ(run.outputs[7].panorama.rows, h0);
  // The half-size frames fill the same panorama: the scene where it was.
  const cv::Mat want = scene().photo(cv::Rect(0, 200, 1040, 480));
  const cv::Mat got = run.outputs[7].panorama(cv::Rect(0, 0, std::min(1040, w0), std::min(480, h0)));
  EXPECT_GT(testdata::psnr_rgb(got, want(cv::Rect(0, 0, got.cols, got.rows))), 24.0);
}

TEST(Resize, ErrorWhenAskedTo) {
  Collected run;
  run_pipeline("stitchsync name=s ! stitchcalib load-file=" + scene().calib +
                   " on-resize=error ! stitchblend ! appsink name=out" + gsttest::appsrc_inputs(2),
               resizing_inputs(), run);
  EXPECT_TRUE(run.failed("resolution changed", "camera 1 640x480 -> 320x240"))
      << (run.errors.empty() ? "no error" : run.errors[0]);
  EXPECT_EQ(run.outputs.size(), 4u);
}

// ---------------------------------------------------------------------------------------------
// Bad frames and many inputs through the whole chain with an exact calibration: a graceful
// panorama, never a crash, a hang or an error.

namespace {

std::string whole_chain(const std::string& calib, int n) {
  return "stitchsync name=s ! stitchcalib load-file=" + calib +
         " ! stitchcolor ! stitchflowwarp ! stitchblend ! appsink name=out" + gsttest::appsrc_inputs(n);
}

std::vector<std::vector<Push>> still(const std::vector<cv::Mat>& views, int frames) {
  std::vector<std::vector<Push>> in(views.size());
  for (std::size_t i = 0; i < views.size(); ++i)
    for (int f = 0; f < frames; ++f) in[i].push_back({f, views[i]});
  return in;
}

}  // namespace

class FlatFrames : public ::testing::TestWithParam<int> {};

TEST_P(FlatFrames, PassThroughTheWholeChain) {
  const int value = GetParam();
  const std::string calib = testdata::temp_dir() + "/flat.json";
  stitch::rig_save(testdata::shifted_rig(3, 160, 120, 100), calib);
  const cv::Mat flat(120, 160, CV_8UC4, cv::Scalar(value, value, value, 255));
  Collected run;
  run_pipeline(whole_chain(calib, 3), still({flat, flat, flat}, 4), run);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_EQ(run.outputs.size(), 4u);
  const cv::Mat& pano = run.outputs[3].panorama;
  ASSERT_EQ(pano.size(), cv::Size(360, 120));
  cv::Scalar mean = cv::mean(pano);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean[c], value, 1.0);
}

INSTANTIATE_TEST_SUITE_P(BlackAndSaturated, FlatFrames, ::testing::Values(0, 255));

// 1x1 cameras cannot be described by a rig (every homography of a point is degenerate): a
// calibration for larger frames, scaled down to them, is refused with a clear error.
TEST(TinyFrames, OnePixelViewsWithASavedCalibrationAreAClearError) {
  const std::string calib = testdata::temp_dir() + "/tiny.json";
  stitch::rig_save(testdata::shifted_rig(2, 64, 48, 40), calib);
  const cv::Mat a(1, 1, CV_8UC4, cv::Scalar(200, 10, 10, 255)), b(1, 1, CV_8UC4, cv::Scalar(10, 200, 10, 255));
  Collected run;
  run_pipeline(whole_chain(calib, 2), still({a, b}, 3), run);
  EXPECT_TRUE(run.failed("camera 0", "degenerate homography")) << (run.errors.empty() ? "no error" : run.errors[0]);
  EXPECT_TRUE(run.outputs.empty());
}

TEST(TinyFrames, OnePixelViewsWithoutCalibrationAreAClearError) {
  const cv::Mat a(1, 1, CV_8UC4, cv::Scalar(200, 10, 10, 255));
  Collected run;
  run_pipeline("stitchsync name=s ! stitchcalib ! stitchblend ! appsink name=out" + gsttest::appsrc_inputs(2),
               still({a, a}, 200), run);
  ASSERT_FALSE(run.errors.empty()) << "1x1 views calibrated from images";
  EXPECT_TRUE(run.failed("calibrate")) << run.errors[0];
}

TEST(ManyInputs, SixteenCamerasStitch) {
  const cv::Mat photo = scene().photo;
  std::vector<cv::Mat> views;
  for (int i = 0; i < 16; ++i) views.push_back(photo(cv::Rect(80 * i, 300, 160, 120)).clone());
  const std::string calib = testdata::temp_dir() + "/sixteen.json";
  stitch::rig_save(testdata::shifted_rig(16, 160, 120, 80), calib);
  Collected run;
  run_pipeline("stitchsync name=s ! stitchcalib load-file=" + calib +
                   " ! stitchcolor ! stitchblend ! appsink name=out" + gsttest::appsrc_inputs(16),
               still(views, 3), run);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_EQ(run.outputs.size(), 3u);
  const cv::Mat& pano = run.outputs[2].panorama;
  ASSERT_EQ(pano.size(), cv::Size(80 * 15 + 160, 120));
  EXPECT_GT(testdata::psnr_rgb(pano, photo(cv::Rect(0, 300, pano.cols, 120))), 35.0);
}

// ---------------------------------------------------------------------------------------------
// A flushing seek on file inputs resets every element's temporal state (stitchsync's last
// frames, stitchcolor's history, stitchflowwarp's flow history): after a seek back to the start
// the panoramas are those of a fresh start.

namespace {

std::vector<Output> pull(GstElement* sink, int count, Collected& run, GstBus* bus) {
  std::vector<Output> out;
  const gint64 deadline = g_get_monotonic_time() + 60 * G_TIME_SPAN_SECOND;
  while (int(out.size()) < count && run.errors.empty() && g_get_monotonic_time() < deadline) {
    if (GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 20 * GST_MSECOND)) {
      Collected one;
      read_sample(s, one);
      out.push_back(one.outputs[0]);
      gst_sample_unref(s);
    }
    while (GstMessage* m = gst_bus_pop(bus)) {
      read_message(m, run);
      gst_message_unref(m);
    }
  }
  return out;
}

}  // namespace

TEST(Seek, FlushingSeekGivesTheFreshStartOutput) {
  gsttest::init();
  const std::string clips = testdata::repo_path("data/limlight_2cam_apartment/");
  const std::string desc =
      "stitchsync name=s ! stitchcalib rig-file=" + testdata::repo_path("examples/limlight_rig.json") +
      " refine=none calibration-frames=1 ! stitchcolor ! stitchflowwarp ! stitchblend output-width=480 ! "
      "appsink name=out sync=false max-buffers=2 "
      "filesrc location=" + clips + "left.mp4 ! qtdemux ! h264parse ! avdec_h264 ! s.sink_0 "
      "filesrc location=" + clips + "right.mp4 ! qtdemux ! h264parse ! avdec_h264 ! s.sink_1";
  auto play = [&](int before_seek, int after, Collected& run) {
    GstElement* pipe = gst_parse_launch(desc.c_str(), nullptr);
    EXPECT_NE(pipe, nullptr);
    GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
    GstBus* bus = gst_element_get_bus(pipe);
    gst_element_set_state(pipe, GST_STATE_PAUSED);
    gst_element_get_state(pipe, nullptr, nullptr, 30 * GST_SECOND);
    gst_element_set_state(pipe, GST_STATE_PLAYING);
    std::vector<Output> out;
    if (before_seek > 0) {
      const auto early = pull(sink, before_seek, run, bus);
      EXPECT_EQ(int(early.size()), before_seek);
      EXPECT_TRUE(gst_element_seek_simple(pipe, GST_FORMAT_TIME, GstSeekFlags(GST_SEEK_FLAG_FLUSH | GST_SEEK_FLAG_ACCURATE), 0));
    }
    out = pull(sink, after, run, bus);
    gst_element_set_state(pipe, GST_STATE_NULL);
    gst_object_unref(bus);
    gst_object_unref(sink);
    gst_object_unref(pipe);
    return out;
  };
  Collected fresh_run, seek_run;
  const auto fresh = play(0, 6, fresh_run);
  const auto seeked = play(12, 6, seek_run);
  ASSERT_TRUE(fresh_run.errors.empty()) << fresh_run.errors[0];
  ASSERT_TRUE(seek_run.errors.empty()) << seek_run.errors[0];
  ASSERT_EQ(fresh.size(), 6u);
  ASSERT_EQ(seeked.size(), 6u);
  for (std::size_t k = 0; k < 6; ++k) {
    SCOPED_TRACE("frame " + std::to_string(k));
    EXPECT_EQ(seeked[k].pts, fresh[k].pts);
    ASSERT_EQ(seeked[k].panorama.size(), fresh[k].panorama.size());
    cv::Mat diff;
    cv::absdiff(seeked[k].panorama, fresh[k].panorama, diff);
    double max_diff = 0;
    cv::minMaxLoc(diff.reshape(1), nullptr, &max_diff);
    EXPECT_LE(max_diff, 1.0) << "the seek kept history from before it";
  }
}

// A camera that ends (EOS) and reconnects (a flush, a new stream and segment on its pad, as a
// source that restarts sends them) rejoins without a restart of the pipeline.
TEST(Reconnect, EndedCameraRejoinsAfterANewStream) {
  gsttest::init();
  GstElement* pipe = gst_parse_launch(
      "stitchsync name=s dropout=fill ! appsink name=out sync=false appsrc name=a0 format=time block=true ! s.sink_0",
      nullptr);
  ASSERT_NE(pipe, nullptr);
  GstElement* sync = gst_bin_get_by_name(GST_BIN(pipe), "s");
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  GstElement* a0 = gst_bin_get_by_name(GST_BIN(pipe), "a0");
  GstPad* sink1 = gst_element_request_pad_simple(sync, "sink_%u");
  GstPad* cam1 = gst_pad_new("cam1", GST_PAD_SRC);
  gst_pad_set_active(cam1, TRUE);
  ASSERT_EQ(gst_pad_link(cam1, sink1), GST_PAD_LINK_OK);
  GstCaps* caps = gst_caps_from_string("video/x-raw,format=RGBA,width=32,height=24,framerate=30/1");
  g_object_set(a0, "caps", caps, NULL);
  GstBus* bus = gst_element_get_bus(pipe);
  gst_element_set_state(pipe, GST_STATE_PLAYING);

  auto buffer = [](int input, int f) {
    const cv::Mat m = coded(input, f);
    GstBuffer* b = gst_buffer_new_allocate(nullptr, m.total() * 4, nullptr);
    gst_buffer_fill(b, 0, m.data, m.total() * 4);
    GST_BUFFER_PTS(b) = frame_time(f);
    GST_BUFFER_DURATION(b) = frame_time(f + 1) - frame_time(f);
    return b;
  };
  auto start_stream = [&](const char* id) {
    gst_pad_push_event(cam1, gst_event_new_stream_start(id));
    gst_pad_push_event(cam1, gst_event_new_caps(caps));
    GstSegment seg;
    gst_segment_init(&seg, GST_FORMAT_TIME);
    gst_pad_push_event(cam1, gst_event_new_segment(&seg));
  };
  std::thread camera0([&]() {
    for (int f = 0; f < 20; ++f) gst_app_src_push_buffer(GST_APP_SRC(a0), buffer(0, f));
  });
  std::thread camera1([&]() {
    start_stream("cam1-first");
    for (int f = 0; f < 10; ++f) gst_pad_push(cam1, buffer(1, f));
    gst_pad_push_event(cam1, gst_event_new_eos());
  });
  camera0.join();
  camera1.join();
  // the end is seen (camera 1 dropped out) before the camera comes back: otherwise its new
  // stream, queued behind the end, would only be a gap in its timestamps
  Collected run;
  for (gint64 until = g_get_monotonic_time() + 5 * G_TIME_SPAN_SECOND;
       run.dropouts.empty() && g_get_monotonic_time() < until;) {
    if (GstMessage* m = gst_bus_timed_pop(bus, 20 * GST_MSECOND)) {
      read_message(m, run);
      gst_message_unref(m);
    }
  }
  // the camera comes back: flush its pad, a new stream from frame 20 on
  gst_pad_push_event(cam1, gst_event_new_flush_start());
  gst_pad_push_event(cam1, gst_event_new_flush_stop(TRUE));
  start_stream("cam1-second");
  std::thread camera0b([&]() {
    for (int f = 20; f < 30; ++f) gst_app_src_push_buffer(GST_APP_SRC(a0), buffer(0, f));
    gst_app_src_end_of_stream(GST_APP_SRC(a0));
  });
  for (int f = 20; f < 30; ++f) gst_pad_push(cam1, buffer(1, f));
  gst_pad_push_event(cam1, gst_event_new_eos());
  camera0b.join();

  const gint64 deadline = g_get_monotonic_time() + 20 * G_TIME_SPAN_SECOND;
  while (g_get_monotonic_time() < deadline) {
    if (GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 20 * GST_MSECOND)) {
      read_sample(s, run);
      gst_sample_unref(s);
    } else if (gst_app_sink_is_eos(GST_APP_SINK(sink))) {
      break;
    }
  }
  while (GstMessage* m = gst_bus_pop(bus)) {
    read_message(m, run);
    gst_message_unref(m);
  }
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_caps_unref(caps);
  gst_object_unref(cam1);
  gst_element_release_request_pad(sync, sink1);
  gst_object_unref(sink1);
  for (GstElement* e : {sync, sink, a0}) gst_object_unref(e);
  gst_object_unref(bus);
  gst_object_unref(pipe);

  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_FALSE(run.outputs.empty());
  const Output& last = run.outputs.back();
  EXPECT_EQ(frame_of(last.view_pixel[0], 0), 29);
  EXPECT_EQ(frame_of(last.view_pixel[1], 1), 29) << "camera 1 did not rejoin";
  EXPECT_FALSE(last.missing & 2);
  bool left_out_between = false;
  for (const Output& o : run.outputs)
    if (o.pts >= frame_time(11) && o.pts < frame_time(19)) left_out_between = left_out_between || (o.missing & 2);
  EXPECT_TRUE(left_out_between) << "the ended camera was not left out";
  // "it ended", or "it stopped sending frames" when the flush came first
  EXPECT_TRUE(run.warned("sink_1", "dropped out"));
  ASSERT_GE(run.dropouts.size(), 2u);
  gboolean dropped = TRUE;
  gst_structure_get_boolean(run.dropouts.back(), "dropped", &dropped);
  EXPECT_FALSE(dropped);
}

// The new properties and their defaults (names are contracts: README and DESIGN use them).
TEST(Properties, DropoutAndResizeDefaults) {
  gsttest::init();
  GstElement* sync = gst_element_factory_make("stitchsync", nullptr);
  GstElement* calib = gst_element_factory_make("stitchcalib", nullptr);
  ASSERT_NE(sync, nullptr);
  ASSERT_NE(calib, nullptr);
  auto nick = [](GstElement* e, const char* prop) {
    GValue v = G_VALUE_INIT;
    g_value_init(&v, g_object_class_find_property(G_OBJECT_GET_CLASS(e), prop)->value_type);
    g_object_get_property(G_OBJECT(e), prop, &v);
    GEnumClass* klass = G_ENUM_CLASS(g_type_class_ref(G_VALUE_TYPE(&v)));
    const std::string n = g_enum_get_value(klass, g_value_get_enum(&v))->value_nick;
    g_type_class_unref(klass);
    g_value_unset(&v);
    return n;
  };
  EXPECT_EQ(nick(sync, "dropout"), "freeze");
  EXPECT_EQ(nick(calib, "on-resize"), "recalibrate");
  guint64 timeout = 0;
  g_object_get(sync, "dropout-timeout", &timeout, NULL);
  EXPECT_EQ(timeout, 500 * GST_MSECOND);
  gst_util_set_object_arg(G_OBJECT(sync), "dropout", "fill");
  gst_util_set_object_arg(G_OBJECT(calib), "on-resize", "error");
  EXPECT_EQ(nick(sync, "dropout"), "fill");
  EXPECT_EQ(nick(calib, "on-resize"), "error");
  gst_object_unref(sync);
  gst_object_unref(calib);
}

// ---------------------------------------------------------------------------------------------
// Start-up (issue 18): a camera dead from the start, late-linking decodebin pads, one input,
// live inputs without a framerate.

namespace {


const char* kLiveCam = "video/x-raw,format=RGBA,width=32,height=24,framerate=30/1";

}  // namespace

// Two live cameras run, the third never delivers anything (a valve drops all it would send):
// the panorama starts within dropout-timeout, the warning names the dead pad, its view is left
// out; when it starts it joins.
TEST(StartUp, DeadCameraAtStartIsLeftOutNamedAndJoinsLater) {
  gsttest::init();
  const std::string desc = std::string("stitchsync name=s latency=40000000 dropout=fill dropout-timeout=300000000 ! "
                                       "appsink name=out sync=false "
                                       "videotestsrc is-live=true pattern=red ! ") + kLiveCam + " ! s.sink_0 "
                           "videotestsrc is-live=true pattern=green ! " + kLiveCam + " ! s.sink_1 "
                           "videotestsrc is-live=true pattern=blue ! " + kLiveCam + " ! valve name=dead drop=true ! s.sink_2";
  GstElement* pipe = gst_parse_launch(desc.c_str(), nullptr);
  ASSERT_NE(pipe, nullptr);
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  GstElement* dead = gst_bin_get_by_name(GST_BIN(pipe), "dead");
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  Collected run;
  gint64 first_output_ms = -1;
  collect_for(pipe, sink, 2500, run, [&](gint64 t) {
    if (first_output_ms < 0 && !run.outputs.empty()) first_output_ms = t;
    if (t > 1500) g_object_set(dead, "drop", FALSE, NULL);  // the camera comes alive after 1.5 s
  });
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(dead);
  gst_object_unref(sink);
  gst_object_unref(pipe);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_GT(run.outputs.size(), 30u);
  EXPECT_GE(first_output_ms, 0);
  EXPECT_LT(first_output_ms, 300 + 400) << "the panorama waited for the dead camera";
  EXPECT_TRUE(run.warned("sink_2", "dropped out")) << (run.warnings.empty() ? "no warning" : run.warnings[0]);
  ASSERT_GE(run.dropouts.size(), 1u);
  EXPECT_STREQ(gst_structure_get_string(run.dropouts[0], "pad"), "sink_2");
  EXPECT_EQ(run.outputs[run.outputs.size() / 3].view_pixel.size(), 3u) << "the camera count changed";
  EXPECT_TRUE(run.outputs[run.outputs.size() / 3].missing & 4);
  gboolean dropped = TRUE;
  gst_structure_get_boolean(run.dropouts.back(), "dropped", &dropped);
  EXPECT_FALSE(dropped) << "the camera did not join when it started";
  EXPECT_FALSE(run.outputs.back().missing & 4);
}

// gst_parse_launch links `decodebin ! s.sink_N` when decodebin exposes its pad, one decoder at a
// time: the first bundle must still hold every camera (it waited for the pads to be linked).
TEST(StartUp, LateLinkingDecodebinsNeverChangeTheCameraCount) {
  gsttest::init();
  const std::string clips = testdata::repo_path("data/limlight_2cam_apartment/");
  const std::string desc = "stitchsync name=s ! appsink name=out sync=false max-buffers=1 "
                           "filesrc location=" + clips + "left.mp4 ! decodebin ! s.sink_0 "
                           "filesrc location=" + clips + "right.mp4 ! decodebin ! s.sink_1 "
                           "filesrc location=" + clips + "left.mp4 ! decodebin ! queue ! s.sink_2";
  for (int run_no = 0; run_no < 50; ++run_no) {
    SCOPED_TRACE("run " + std::to_string(run_no));
    GstElement* pipe = gst_parse_launch(desc.c_str(), nullptr);
    ASSERT_NE(pipe, nullptr);
    GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
    gst_element_set_state(pipe, GST_STATE_PLAYING);
    GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 20 * GST_SECOND);
    ASSERT_NE(s, nullptr) << "no bundle";
    gint views = 0;
    gst_structure_get_int(gst_caps_get_structure(gst_sample_get_caps(s), 0), "views", &views);
    const GstStitchBundleMeta* bm = bundle_meta(gst_sample_get_buffer(s));
    EXPECT_EQ(views, 3);
    ASSERT_NE(bm, nullptr);
    EXPECT_EQ(bm->n_views, 3u);
    EXPECT_EQ(bm->missing_mask, 0u);
    gst_sample_unref(s);
    gst_element_set_state(pipe, GST_STATE_NULL);
    gst_object_unref(sink);
    gst_object_unref(pipe);
    if (HasFailure()) break;
  }
}

// One input: a clear error on the bus, never a pipeline stuck in PREROLLING.
TEST(StartUp, SingleInputIsAClearError) {
  Collected run;
  run_pipeline(bundles("dropout-timeout=200000000", 1), {coded_frames(0, 0, 29)}, run, 10);
  EXPECT_TRUE(run.failed("needs at least two cameras", "sink_0")) << (run.errors.empty() ? "no error" : run.errors[0]);
  EXPECT_TRUE(run.outputs.empty());
}

// Live inputs without a framerate and force-live: no GStreamer-CRITICAL (denominator 0, latency).
TEST(StartUp, LiveInputsWithoutFramerateNoCriticals) {
  gsttest::init();
  static int criticals = 0;
  criticals = 0;
  const guint handler = g_log_set_handler(
      "GStreamer", GLogLevelFlags(G_LOG_LEVEL_CRITICAL | G_LOG_LEVEL_WARNING),
      [](const gchar*, GLogLevelFlags, const gchar* message, gpointer) {
        ++criticals;
        std::fprintf(stderr, "%s\n", message);
      },
      nullptr);
  const std::string caps = "video/x-raw,format=RGBA,width=32,height=24,framerate=0/1";
  const std::string desc = "stitchsync name=s force-live=true latency=40000000 ! appsink name=out sync=false "
                           "appsrc name=a0 is-live=true format=time do-timestamp=true caps=\"" + caps + "\" ! s.sink_0 "
                           "appsrc name=a1 is-live=true format=time do-timestamp=true caps=\"" + caps + "\" ! s.sink_1";
  GstElement* pipe = gst_parse_launch(desc.c_str(), nullptr);
  ASSERT_NE(pipe, nullptr);
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  GstElement* a[2] = {gst_bin_get_by_name(GST_BIN(pipe), "a0"), gst_bin_get_by_name(GST_BIN(pipe), "a1")};
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  Collected run;
  int pushed = 0;
  collect_for(pipe, sink, 1200, run, [&](gint64 t) {
    while (pushed < t / 40) {
      for (int i = 0; i < 2; ++i) {
        const cv::Mat m = coded(i, pushed % 90);
        GstBuffer* b = gst_buffer_new_allocate(nullptr, m.total() * 4, nullptr);
        gst_buffer_fill(b, 0, m.data, m.total() * 4);
        gst_app_src_push_buffer(GST_APP_SRC(a[i]), b);
      }
      ++pushed;
    }
  });
  gst_element_set_state(pipe, GST_STATE_NULL);
  for (GstElement* e : a) gst_object_unref(e);
  gst_object_unref(sink);
  gst_object_unref(pipe);
  g_log_remove_handler("GStreamer", handler);
  EXPECT_EQ(criticals, 0);
  EXPECT_TRUE(run.errors.empty()) << run.errors[0];
  EXPECT_GT(run.outputs.size(), 5u);
}

// Pads requested while playing (a camera reconnecting) never stall the output, not even while
// they have no caps; releasing pads down to one does not stall either.
TEST(PadsWhilePlaying, RequestAndReleaseNeverStall) {
  gsttest::init();
  const std::string desc = std::string("stitchsync name=s latency=40000000 ! appsink name=out sync=false "
                                       "videotestsrc is-live=true pattern=red ! ") + kLiveCam + " ! s.sink_0 "
                           "videotestsrc name=cam1 is-live=true pattern=green ! " + kLiveCam + " ! s.sink_1";
  GstElement* pipe = gst_parse_launch(desc.c_str(), nullptr);
  ASSERT_NE(pipe, nullptr);
  GstElement* sync = gst_bin_get_by_name(GST_BIN(pipe), "s");
  GstElement* cam1 = gst_bin_get_by_name(GST_BIN(pipe), "cam1");
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  Collected run;
  GstPad* extra = nullptr;
  std::size_t at_request = 0, at_release = 0, at_single = 0;
  collect_for(pipe, sink, 2400, run, [&](gint64 t) {
    if (t > 600 && !extra && !at_request) {  // a third camera that never negotiates
      extra = gst_element_request_pad_simple(sync, "sink_%u");
      at_request = run.outputs.size() + 1;
    } else if (t > 1200 && extra) {
      gst_element_release_request_pad(sync, extra);
      gst_object_unref(extra);
      extra = nullptr;
      at_release = run.outputs.size() + 1;
    } else if (t > 1800 && !at_single) {  // down to one camera: its source stops, its pad goes
      gst_element_set_locked_state(cam1, TRUE);
      gst_element_set_state(cam1, GST_STATE_NULL);
      GstPad* p1 = gst_element_get_static_pad(sync, "sink_1");
      GstPad* peer = gst_pad_get_peer(p1);
      gst_pad_unlink(peer, p1);
      gst_element_release_request_pad(sync, p1);
      gst_object_unref(p1);
      gst_object_unref(peer);
      at_single = run.outputs.size() + 1;
    }
  });
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(cam1);
  gst_object_unref(sync);
  gst_object_unref(sink);
  gst_object_unref(pipe);
  ASSERT_TRUE(run.errors.empty()) << run.errors[0];
  ASSERT_GT(at_single, 0u);
  // output kept coming after each change, each bundle one frame after the last
  EXPECT_GT(run.outputs.size(), at_single + 10) << "stalled after going down to one camera";
  EXPECT_GT(at_release, at_request + 10) << "stalled while the new pad had no caps";
  for (std::size_t k = 1; k < run.outputs.size(); ++k)
    EXPECT_NEAR(double(run.outputs[k].pts - run.outputs[k - 1].pts), double(frame_time(1)), 1.0) << k;
  EXPECT_EQ(run.outputs[(at_request + at_release) / 2].view_pixel.size(), 3u);
  EXPECT_TRUE(run.outputs[(at_request + at_release) / 2].missing & 4);
  EXPECT_EQ(run.outputs.back().view_pixel.size(), 2u);
  EXPECT_TRUE(run.outputs.back().missing & 2);
}
