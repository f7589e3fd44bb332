// A non-live camera that delivers nothing (an appsrc that never pushes) must not hold the others:
// GstAggregator waits for data on every non-live pad, so stitchsync stands in for it with gaps
// after dropout-timeout. Panoramas flow within dropout-timeout plus a margin, a warning names the
// pad, and the camera joins when it starts.
#include <gst/app/gstappsrc.h>
#include <gst/gst.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cstring>
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
  // pts of the newest bundle and of the first one with view 2
  std::atomic<gint64> last_pts{-1}, view2_pts{-1};
};

GstPadProbeReturn on_bundle(GstPad*, GstPadProbeInfo* info, gpointer data) {
  Counts* c = static_cast<Counts*>(data);
  gint64 none = -1;
  c->first_us.compare_exchange_strong(none, g_get_monotonic_time());
  ++c->bundles;
  bool found = false;
  GstBuffer* buf = GST_PAD_PROBE_INFO_BUFFER(info);
  if (!view_missing(buf, 2, found) && found) {
    ++c->with_view2;
    gint64 unset = -1;
    c->view2_pts.compare_exchange_strong(unset, gint64(GST_BUFFER_PTS(buf)));
  }
  c->last_pts = gint64(GST_BUFFER_PTS(buf));
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
  explicit DeadCamRun(int frames, const std::string& after = "", const std::string& before_sink2 = "") {
    const std::string cam = "videotestsrc pattern=ball num-buffers=" + std::to_string(frames) +
                            " ! video/x-raw,format=RGBA,width=96,height=64,framerate=30/1 ! identity sleep-time=10000 ! ";
    const std::string desc = "stitchsync name=s dropout-timeout=300000000 ! " + after + "fakesink name=out sync=false " + cam +
                             "s.sink_0 " + cam + "s.sink_1 appsrc name=dead format=time is-live=false ! " + before_sink2 + "s.sink_2";
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
  // The first panorama comes after dropout-timeout (300 ms); up to 5 s on a loaded machine.
  for (const gint64 end = r.started_us + 5 * G_TIME_SPAN_SECOND;
       r.counts.bundles.load() == 0 && !r.eos && g_get_monotonic_time() < end;)
    r.pump(g_get_monotonic_time() + 50 * G_TIME_SPAN_MILLISECOND);
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

namespace {

std::atomic<int> g_misordered{0};
void count_misordering(const gchar* domain, GLogLevelFlags level, const gchar* message, gpointer) {
  if (message && std::strstr(message, "misordering")) ++g_misordered;
  g_log_default_handler(domain, level, message, nullptr);
}

// Pushes 30 fps frames on `src` from `from` to `to` (ns), then EOS.
void push_frames(GstElement* src, GstClockTime from, GstClockTime to) {
  for (GstClockTime t = from; t < to; t += GST_SECOND / 30) {
    GstBuffer* b = gst_buffer_new_allocate(nullptr, 96 * 64 * 4, nullptr);
    gst_buffer_memset(b, 0, 128, 96 * 64 * 4);
    GST_BUFFER_PTS(b) = t;
    GST_BUFFER_DURATION(b) = GST_SECOND / 30;
    gst_app_src_push_buffer(GST_APP_SRC(src), b);
  }
  gst_app_src_end_of_stream(GST_APP_SRC(src));
}

}  // namespace

// The stand-in's stream-start and segment are sticky events on the pad; the camera that joins
// later sends stream-start, caps, segment. Before the fix every late camera printed
// "GStreamer-WARNING: ... Sticky event misordering, got 'segment' before 'caps'" on stderr (our
// segment was stored before its caps). A camera 1.5 s late, from pts 0 as a file would be:
// either its branch is held back (a queue blocked, as a slow decoder or network would), or it is
// an appsrc that has sent its stream-start but no caps yet. It must also be in the bundles from
// where the output was when it came (within a stand-in gap): before, it stayed out for about as
// long again as it had been late (3.1-4.3 s of pts here), its old frames dropped one per bundle
// while the others' video went on without it.
namespace {

GstPadProbeReturn hold(GstPad*, GstPadProbeInfo*, gpointer) { return GST_PAD_PROBE_OK; }

// the output's pts when the late camera's first frame reached stitchsync
struct Arrival {
  Counts* counts;
  std::atomic<gint64> out_pts{-2};
};
GstPadProbeReturn on_arrival(GstPad*, GstPadProbeInfo* info, gpointer data) {
  GstBuffer* b = GST_PAD_PROBE_INFO_BUFFER(info);
  if (GST_BUFFER_FLAG_IS_SET(b, GST_BUFFER_FLAG_GAP) && gst_buffer_get_size(b) == 0) return GST_PAD_PROBE_OK;
  Arrival* a = static_cast<Arrival*>(data);
  gint64 none = -2;
  a->out_pts.compare_exchange_strong(none, a->counts->last_pts.load());
  return GST_PAD_PROBE_OK;
}

void late_camera_joins(bool blocked_branch) {
  g_misordered = 0;
  const guint handler = g_log_set_handler("GStreamer", G_LOG_LEVEL_WARNING, count_misordering, nullptr);
  {
    DeadCamRun r(300, "", blocked_branch ? "queue name=q max-size-buffers=0 max-size-bytes=0 max-size-time=0 ! " : "");
    ASSERT_NE(r.pipe, nullptr);
    GstCaps* caps = gst_caps_from_string("video/x-raw,format=RGBA,width=96,height=64,framerate=30/1");
    GstPad* qsrc = nullptr;
    gulong block = 0;
    if (blocked_branch) {
      GstElement* q = gst_bin_get_by_name(GST_BIN(r.pipe), "q");
      qsrc = gst_element_get_static_pad(q, "src");
      block = gst_pad_add_probe(qsrc, GST_PAD_PROBE_TYPE_BLOCK_DOWNSTREAM, hold, nullptr, nullptr);
      gst_object_unref(q);
      gst_app_src_set_caps(GST_APP_SRC(r.dead), caps);
      push_frames(r.dead, 0, 10 * GST_SECOND);
    }
    Arrival arrival{&r.counts};
    {
      GstElement* s = gst_bin_get_by_name(GST_BIN(r.pipe), "s");
      GstPad* pad = gst_element_get_static_pad(s, "sink_2");
      gst_pad_add_probe(pad, GST_PAD_PROBE_TYPE_BUFFER, on_arrival, &arrival, nullptr);
      gst_object_unref(pad);
      gst_object_unref(s);
    }
    r.start();
    r.pump(r.started_us + 1500 * G_TIME_SPAN_MILLISECOND);
    ASSERT_GT(r.counts.bundles.load(), 0) << "no panorama while the camera was late";
    ASSERT_FALSE(r.eos);
    if (blocked_branch) {
      gst_pad_remove_probe(qsrc, block);
      gst_object_unref(qsrc);
    } else {
      gst_app_src_set_caps(GST_APP_SRC(r.dead), caps);
      push_frames(r.dead, 0, 10 * GST_SECOND);
    }
    gst_caps_unref(caps);
    r.pump(r.started_us + 30 * G_TIME_SPAN_SECOND);
    ASSERT_TRUE(r.errors.empty()) << r.errors[0];
    EXPECT_TRUE(r.eos);
    EXPECT_GT(r.counts.with_view2.load(), 30) << "the camera never joined";
    // it is in the bundles from (about) where the output was when it came: before, the gaps queued
    // ahead of it and its frames from before them (dropped one per output frame) kept it out for
    // as long as it had been late, while the others' video went on without it
    ASSERT_GE(arrival.out_pts.load(), -1) << "its first frame never reached stitchsync";
    ASSERT_GE(r.counts.view2_pts.load(), 0);
    EXPECT_LT(double(r.counts.view2_pts - std::max<gint64>(arrival.out_pts, 0)) / GST_SECOND, 0.25)
        << "joined at pts " << r.counts.view2_pts / 1e9 << " s, came when the output was at " << arrival.out_pts / 1e9
        << " s";
    // the pad ends with the camera's own sticky events, in order
    GstElement* s = gst_bin_get_by_name(GST_BIN(r.pipe), "s");
    GstPad* pad = gst_element_get_static_pad(s, "sink_2");
    ASSERT_NE(pad, nullptr);
    GstEvent* ss = gst_pad_get_sticky_event(pad, GST_EVENT_STREAM_START, 0);
    ASSERT_NE(ss, nullptr);
    const gchar* id = nullptr;
    gst_event_parse_stream_start(ss, &id);
    EXPECT_EQ(std::string(id).find("stitchsync-standin"), std::string::npos) << id;
    GstEvent* caps_ev = gst_pad_get_sticky_event(pad, GST_EVENT_CAPS, 0);
    EXPECT_NE(caps_ev, nullptr);
    if (caps_ev) gst_event_unref(caps_ev);
    gst_event_unref(ss);
    gst_object_unref(pad);
    gst_object_unref(s);
  }
  g_log_remove_handler("GStreamer", handler);
  EXPECT_EQ(g_misordered.load(), 0) << "GStreamer warned of sticky event misordering on the late camera's pad";
}

}  // namespace

TEST(StitchSyncDeadCamera, LateBranchJoinsWithoutStickyEventMisordering) { late_camera_joins(true); }
TEST(StitchSyncDeadCamera, LateAppsrcJoinsWithoutStickyEventMisordering) { late_camera_joins(false); }

// A live camera whose pad is requested and linked while the others have been running for 1.5 s:
// "no frame since the start" was posted at once (counted from the stream's start); the clock
// starts when the pad appears, so it drops out only after dropout-timeout (300 ms) without a frame.
TEST(StitchSyncDeadCamera, LivePadAddedLaterIsCountedFromWhenItWasAdded) {
  const std::string cam =
      "videotestsrc is-live=true pattern=ball ! video/x-raw,format=RGBA,width=96,height=64,framerate=30/1 ! ";
  const std::string desc =
      "stitchsync name=s dropout-timeout=300000000 ! fakesink name=out sync=false " + cam + "s.sink_0 " + cam + "s.sink_1";
  GstElement* pipe = gst_parse_launch(desc.c_str(), nullptr);
  ASSERT_NE(pipe, nullptr);
  GstBus* bus = gst_element_get_bus(pipe);
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  std::vector<std::string> warnings, errors;
  gint64 added_us = -1, dropped_us = -1;
  std::string dropped;
  auto pump = [&](gint64 until_us) {
    while (g_get_monotonic_time() < until_us && errors.empty()) {
      GstMessage* m = gst_bus_timed_pop(bus, 10 * GST_MSECOND);
      if (!m) continue;
      GError* e = nullptr;
      if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_WARNING) {
        gst_message_parse_warning(m, &e, nullptr);
        warnings.push_back(e->message);
        if (dropped_us < 0 && std::strstr(e->message, "sink_2") && std::strstr(e->message, "dropped out")) {
          dropped_us = g_get_monotonic_time();
          dropped = e->message;
        }
      } else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) {
        gst_message_parse_error(m, &e, nullptr);
        errors.push_back(e->message);
      }
      if (e) g_error_free(e);
      gst_message_unref(m);
    }
  };
  const gint64 t0 = g_get_monotonic_time();
  pump(t0 + 1500 * G_TIME_SPAN_MILLISECOND);
  ASSERT_TRUE(errors.empty()) << errors[0];
  // the third camera: a live appsrc with caps that sends nothing yet
  GstElement* s = gst_bin_get_by_name(GST_BIN(pipe), "s");
  GstElement* late = gst_element_factory_make("appsrc", "late");
  GstCaps* caps = gst_caps_from_string("video/x-raw,format=RGBA,width=96,height=64,framerate=30/1");
  g_object_set(late, "is-live", TRUE, "format", GST_FORMAT_TIME, "caps", caps, NULL);
  gst_caps_unref(caps);
  gst_bin_add(GST_BIN(pipe), late);
  GstPad* sink2 = gst_element_request_pad_simple(s, "sink_%u");
  GstPad* src = gst_element_get_static_pad(late, "src");
  ASSERT_EQ(gst_pad_link(src, sink2), GST_PAD_LINK_OK);
  added_us = g_get_monotonic_time();
  gst_element_sync_state_with_parent(late);
  pump(added_us + 3 * G_TIME_SPAN_SECOND);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(src);
  gst_object_unref(sink2);
  gst_object_unref(s);
  gst_object_unref(bus);
  gst_object_unref(pipe);
  ASSERT_TRUE(errors.empty()) << errors[0];
  ASSERT_GE(dropped_us, 0) << "the silent camera never dropped out";
  // 300 ms of running time after it was added, minus a little for the output's own latency
  EXPECT_GT(double(dropped_us - added_us) / 1e3, 200.0) << dropped;
  EXPECT_TRUE(dropped.find("since it was added") != std::string::npos || dropped.find("no caps after") != std::string::npos)
      << dropped;
  const std::size_t at = dropped.find(" ms)");
  ASSERT_NE(at, std::string::npos) << dropped;
  const std::size_t open = dropped.rfind('(', at);
  const int ms = std::atoi(dropped.substr(open + 1, at - open - 1).c_str());
  EXPECT_GE(ms, 300) << dropped;
  EXPECT_LT(ms, 1200) << dropped << ": counted from the stream's start, not from when the pad was added";
}

namespace {
GstPadProbeReturn count_views(GstPad*, GstPadProbeInfo* info, gpointer data) {
  auto* c = static_cast<std::vector<guint64>*>(data);
  gpointer state = nullptr;
  while (GstMeta* m = gst_buffer_iterate_meta(GST_PAD_PROBE_INFO_BUFFER(info), &state))
    if (g_strcmp0(g_type_name(m->info->api), "GstStitchBundleMetaAPI") == 0)
      c->push_back(reinterpret_cast<BundleMetaView*>(m)->missing_mask);
  return GST_PAD_PROBE_OK;
}
void push_one(GstElement* src) {
  GstBuffer* b = gst_buffer_new_allocate(nullptr, 64 * 48 * 4, nullptr);
  gst_buffer_memset(b, 0, 120, 64 * 48 * 4);
  GST_BUFFER_PTS(b) = 0;
  gst_app_src_push_buffer(GST_APP_SRC(src), b);
  gst_app_src_end_of_stream(GST_APP_SRC(src));
}
}  // namespace

// Two photos as cameras (probe2: `filesrc location=a.jpg ! decodebin ! s.sink_0 filesrc
// location=b.jpg ! decodebin ! s.sink_1`): each is one frame, then EOS, and gst_parse_launch links
// the second decodebin only when it has decoded. When the first had ended before that, the run
// ended with no bundle at all (every pad there was had ended), or with the first photo missing
// ("camera 0 has not delivered a frame yet"). The first bundle holds both photos.
TEST(StitchSyncDeadCamera, APhotoThatEndsBeforeTheOtherIsLinkedIsInTheBundle) {
  const std::string caps = "caps=video/x-raw,format=RGBA,width=64,height=48,framerate=0/1";
  const std::string desc = "stitchsync name=s ! fakesink name=out sync=false appsrc name=a0 format=time " + caps +
                           " ! s.sink_0 appsrc name=a1 format=time " + caps + " ! decodebin ! s.sink_1";
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(desc.c_str(), &err);
  ASSERT_NE(pipe, nullptr) << (err ? err->message : "");
  GstElement* a0 = gst_bin_get_by_name(GST_BIN(pipe), "a0");
  GstElement* a1 = gst_bin_get_by_name(GST_BIN(pipe), "a1");
  GstElement* out = gst_bin_get_by_name(GST_BIN(pipe), "out");
  std::vector<guint64> bundles;
  GstPad* pad = gst_element_get_static_pad(out, "sink");
  gst_pad_add_probe(pad, GST_PAD_PROBE_TYPE_BUFFER, count_views, &bundles, nullptr);
  gst_object_unref(pad);
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  push_one(a0);
  g_usleep(200000);  // the first photo has ended; the second is not decoded (nor linked) yet
  push_one(a1);
  GstBus* bus = gst_element_get_bus(pipe);
  GstMessage* m = gst_bus_timed_pop_filtered(bus, 20 * GST_SECOND, GstMessageType(GST_MESSAGE_EOS | GST_MESSAGE_ERROR));
  ASSERT_NE(m, nullptr) << "no end";
  std::string error;
  if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) {
    GError* e = nullptr;
    gst_message_parse_error(m, &e, nullptr);
    error = e->message;
    g_error_free(e);
  }
  gst_message_unref(m);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(bus);
  gst_object_unref(out);
  gst_object_unref(a0);
  gst_object_unref(a1);
  gst_object_unref(pipe);
  EXPECT_TRUE(error.empty()) << error;
  ASSERT_FALSE(bundles.empty()) << "the stream ended before the second photo came";
  EXPECT_EQ(bundles[0], 0u) << "a photo is missing from the first bundle";
}
