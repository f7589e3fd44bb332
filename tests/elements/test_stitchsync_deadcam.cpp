// A non-live camera that delivers nothing (an appsrc that never pushes) must not hold the others:
// GstAggregator waits for data on every non-live pad, so stitchsync stands in for it with gaps
// after dropout-timeout. Panoramas flow within dropout-timeout plus a margin, a warning names the
// pad, and the camera joins when it starts.
#include <gst/app/gstappsrc.h>
#include <gst/gst.h>
#include <gtest/gtest.h>

#include <atomic>
#include <string>
#include <vector>

#include "stitch/rig/rig.hpp"
#include "synthetic_rig.hpp"
#include "test_data.hpp"

namespace {

class GstEnvironment : public ::testing::Environment {
 public:
  void SetUp() override { gst_init(nullptr, nullptr); }
};
::testing::Environment* const gst_env = ::testing::AddGlobalTestEnvironment(new GstEnvironment);

// The bundle meta's missing mask (GstStitchBundleMeta: meta, n_views, missing_mask).
struct BundleMetaView {
  GstMeta meta;
  guint n_views;
  guint64 missing_mask;
};
bool view_missing(GstBuffer* buf, guint view, bool& found) {
  gpointer state = nullptr;
  while (GstMeta* m = gst_buffer_iterate_meta(buf, &state))
    if (g_strcmp0(g_type_name(m->info->api), "GstStitchBundleMetaAPI") == 0) {
      found = true;
      return (reinterpret_cast<BundleMetaView*>(m)->missing_mask >> view) & 1;
    }
  found = false;
  return false;
}

struct Counts {
  std::atomic<int> bundles{0}, with_view2{0};
  std::atomic<gint64> first_us{-1};
};

GstPadProbeReturn on_bundle(GstPad*, GstPadProbeInfo* info, gpointer data) {
  Counts* c = static_cast<Counts*>(data);
  gint64 none = -1;
  c->first_us.compare_exchange_strong(none, g_get_monotonic_time());
  ++c->bundles;
  bool found = false;
  if (!view_missing(GST_PAD_PROBE_INFO_BUFFER(info), 2, found) && found) ++c->with_view2;
  return GST_PAD_PROBE_OK;
}

struct DeadCamRun {
  GstElement* pipe = nullptr;
  GstElement* dead = nullptr;
  GstBus* bus = nullptr;
  Counts counts;
  gint64 started_us = 0;
  std::vector<std::string> warnings;
  std::vector<std::string> errors;
  bool eos = false;
  // two paced cameras (identity sleep-time: about 100 frames a second) and a third, appsrc, that
  // sends nothing unless told to
  explicit DeadCamRun(int frames, const std::string& after = "") {
    const std::string cam = "videotestsrc pattern=ball num-buffers=" + std::to_string(frames) +
                            " ! video/x-raw,format=RGBA,width=96,height=64,framerate=30/1 ! identity sleep-time=10000 ! ";
    const std::string desc = "stitchsync name=s dropout-timeout=300000000 ! " + after + "fakesink name=out sync=false " + cam +
                             "s.sink_0 " + cam + "s.sink_1 appsrc name=dead format=time is-live=false ! s.sink_2";
    GError* err = nullptr;
    pipe = gst_parse_launch(desc.c_str(), &err);
    if (!pipe) return;
    dead = gst_bin_get_by_name(GST_BIN(pipe), "dead");
    GstElement* out = gst_bin_get_by_name(GST_BIN(pipe), "out");
    GstPad* pad = gst_element_get_static_pad(out, "sink");
    gst_pad_add_probe(pad, GST_PAD_PROBE_TYPE_BUFFER, on_bundle, &counts, nullptr);
    gst_object_unref(pad);
    gst_object_unref(out);
    bus = gst_element_get_bus(pipe);
  }
  ~DeadCamRun() {
    if (pipe) gst_element_set_state(pipe, GST_STATE_NULL);
    if (dead) gst_object_unref(dead);
    if (bus) gst_object_unref(bus);
    if (pipe) gst_object_unref(pipe);
  }
  void start() {
    started_us = g_get_monotonic_time();
    gst_element_set_state(pipe, GST_STATE_PLAYING);
  }
  // bus messages until `until_us` (monotonic) or the end
  void pump(gint64 until_us) {
    while (!eos && g_get_monotonic_time() < until_us) {
      GstMessage* m = gst_bus_timed_pop(bus, 20 * GST_MSECOND);
      if (!m) continue;
      GError* e = nullptr;
      if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_WARNING) {
        gst_message_parse_warning(m, &e, nullptr);
        warnings.push_back(e->message);
      } else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) {
        gst_message_parse_error(m, &e, nullptr);
        errors.push_back(e->message);
        eos = true;
      } else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_EOS) {
        eos = true;
      }
      if (e) g_error_free(e);
      gst_message_unref(m);
    }
  }
};

}  // namespace

TEST(StitchSyncDeadCamera, NonLiveSilentInputDoesNotHoldTheOthers) {
  DeadCamRun r(150);
  ASSERT_NE(r.pipe, nullptr);
  r.start();
  r.pump(r.started_us + 20 * G_TIME_SPAN_SECOND);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_TRUE(r.eos) << "the stream did not end: held by the silent camera";
  EXPECT_GE(r.counts.bundles.load(), 140);
  ASSERT_GE(r.counts.first_us.load(), 0) << "no panorama";
  // dropout-timeout (300 ms) plus a margin for a loaded machine
  EXPECT_LT(double(r.counts.first_us - r.started_us) / 1e6, 0.3 + 1.5);
  bool named = false;
  for (const auto& w : r.warnings) named = named || w.find("sink_2") != std::string::npos;
  EXPECT_TRUE(named) << (r.warnings.empty() ? "no warning" : r.warnings[0]);
  EXPECT_EQ(r.counts.with_view2.load(), 0);
}

// The silent camera starts a while later: its frames (timestamped from where the others are) make
// it a real view from then on.
TEST(StitchSyncDeadCamera, JoinsWhenItStarts) {
  DeadCamRun r(300);
  ASSERT_NE(r.pipe, nullptr);
  GstCaps* caps = gst_caps_from_string("video/x-raw,format=RGBA,width=96,height=64,framerate=30/1");
  gst_app_src_set_caps(GST_APP_SRC(r.dead), caps);
  gst_caps_unref(caps);
  r.start();
  r.pump(r.started_us + G_TIME_SPAN_SECOND);
  ASSERT_GT(r.counts.bundles.load(), 0) << "no panorama while the camera was silent";
  ASSERT_FALSE(r.eos);
  gint64 pos = 0;
  ASSERT_TRUE(gst_element_query_position(r.pipe, GST_FORMAT_TIME, &pos));
  // from a little ahead of the others to the end of the stream
  const GstClockTime from = GstClockTime(pos) + GST_SECOND;
  for (GstClockTime t = from; t < 10 * GST_SECOND; t += GST_SECOND / 30) {
    GstBuffer* b = gst_buffer_new_allocate(nullptr, 96 * 64 * 4, nullptr);
    gst_buffer_memset(b, 0, 128, 96 * 64 * 4);
    GST_BUFFER_PTS(b) = t;
    GST_BUFFER_DURATION(b) = GST_SECOND / 30;
    gst_app_src_push_buffer(GST_APP_SRC(r.dead), b);
  }
  gst_app_src_end_of_stream(GST_APP_SRC(r.dead));
  r.pump(r.started_us + 30 * G_TIME_SPAN_SECOND);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_TRUE(r.eos);
  EXPECT_GT(r.counts.with_view2.load(), 30) << "the camera never joined";
}

// stitchcalib with a complete calibration file does not wait for the silent camera either: the
// panoramas go through with the view marked missing.
TEST(StitchSyncDeadCamera, CompleteLoadFileDoesNotWaitEither) {
  const std::string path = testdata::temp_dir() + "/deadcam_rig.json";
  stitch::rig_save(testdata::shifted_rig(3, 96, 64, 60), path);
  DeadCamRun r(150, "stitchcalib load-file=" + path + " ! ");
  ASSERT_NE(r.pipe, nullptr);
  r.start();
  r.pump(r.started_us + 20 * G_TIME_SPAN_SECOND);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_TRUE(r.eos);
  EXPECT_GE(r.counts.bundles.load(), 140) << "stitchcalib held the bundles";
  ASSERT_GE(r.counts.first_us.load(), 0);
  EXPECT_LT(double(r.counts.first_us - r.started_us) / 1e6, 0.3 + 1.5);
}
