// stitchsyncaudio: the cameras' audio into stitchsync's time-alignment=auto. Generated data only
// (still video, so vision has nothing; a sound scene recorded by each camera's microphone, the
// cameras started at different times), through a real pipeline.
#include <gst/app/gstappsrc.h>
#include <gst/gst.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <thread>
#include <vector>

#include "synthetic_audio.hpp"
#include "test_data.hpp"

namespace {

class GstEnvironment : public ::testing::Environment {
 public:
  void SetUp() override { gst_init(nullptr, nullptr); }
};
::testing::Environment* const gst_env = ::testing::AddGlobalTestEnvironment(new GstEnvironment);

struct Result {
  std::vector<GstStructure*> offsets;
  std::vector<std::string> errors;
  int bundles = 0;
  ~Result() {
    for (GstStructure* s : offsets) gst_structure_free(s);
  }
};

GstPadProbeReturn count_buffer(GstPad*, GstPadProbeInfo*, gpointer data) {
  ++*static_cast<int*>(data);
  return GST_PAD_PROBE_OK;
}

// The video is paced (about 100 frames a second): the audio estimate runs on the audio's own
// threads, and unpaced still video would be through before the first estimate is made.
// `starts[i]`: scene time (s) at which camera i started; `seconds` of still video at 30 fps and of
// audio (48 kHz stereo F32 on even cameras, 44.1 kHz mono S16 on odd ones) per camera.
// `bin`: through stitchbin (its audio_%u pads) instead of stitchsync + stitchsyncaudio.
// `speeds[i]`: how fast camera i's clock runs (1.005: 0.5 % fast; default 1).
void run(const std::string& extra, const std::vector<double>& starts, double seconds, bool with_audio, Result& r,
         bool bin = false, const std::vector<double>& speeds = {}) {
  const testdata::SoundScene scene(seconds + 1);
  std::string desc = (bin ? "stitchbin rig-file=" + testdata::repo_path("examples/testsrc_rig.json") + " refine=none"
                          : std::string("stitchsync")) +
                     " name=s time-alignment=auto " + extra + " ! fakesink name=out sync=false ";
  if (with_audio && !bin) desc += "stitchsyncaudio name=a ";
  const std::string size = bin ? "width=320,height=240" : "width=96,height=64";
  const int frames = int(seconds * 30);
  for (std::size_t i = 0; i < starts.size(); ++i) {
    desc += "videotestsrc pattern=smpte num-buffers=" + std::to_string(frames) +
            " ! video/x-raw,format=RGBA," + size + ",framerate=30/1 ! identity sleep-time=10000 ! s.sink_" +
            std::to_string(i) + " ";
    if (with_audio)
      desc += "appsrc name=mic" + std::to_string(i) + " format=time ! " + (bin ? "s" : "a") + ".audio_" +
              std::to_string(i) + " ";
  }
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(desc.c_str(), &err);
  ASSERT_NE(pipe, nullptr) << (err ? err->message : "");
  GstElement* out = gst_bin_get_by_name(GST_BIN(pipe), "out");
  GstPad* sinkpad = gst_element_get_static_pad(out, "sink");
  gst_pad_add_probe(sinkpad, GST_PAD_PROBE_TYPE_BUFFER, count_buffer, &r.bundles, nullptr);
  gst_object_unref(sinkpad);
  gst_object_unref(out);
  std::vector<std::thread> mics;
  if (with_audio) {
    for (std::size_t i = 0; i < starts.size(); ++i) {
      GstElement* src = gst_bin_get_by_name(GST_BIN(pipe), ("mic" + std::to_string(i)).c_str());
      const bool f32 = i % 2 == 0;
      const int rate = f32 ? 48000 : 44100, channels = f32 ? 2 : 1;
      GstCaps* caps = gst_caps_new_simple("audio/x-raw", "format", G_TYPE_STRING, f32 ? "F32LE" : "S16LE", "layout",
                                          G_TYPE_STRING, "interleaved", "rate", G_TYPE_INT, rate, "channels", G_TYPE_INT,
                                          channels, NULL);
      gst_app_src_set_caps(GST_APP_SRC(src), caps);
      gst_caps_unref(caps);
      const std::size_t n = std::size_t(seconds * rate);
      // camera i's own microphone: gain and noise of its own
      std::vector<float> x = scene.record(starts[i], n, rate, channels, 0.7f + 0.2f * float(i), 0.03f, unsigned(i + 1),
                                          i < speeds.size() ? speeds[i] : 1.0);
      // 20 ms buffers, timestamped from 0 on the camera's own clock
      const std::size_t block = std::size_t(rate / 50);
      for (std::size_t f = 0; f < n; f += block) {
        const std::size_t k = std::min(block, n - f);
        GstBuffer* b;
        if (f32) {
          b = gst_buffer_new_memdup(x.data() + f * channels, k * channels * sizeof(float));
        } else {
          std::vector<gint16> s(k);
          for (std::size_t j = 0; j < k; ++j) s[j] = gint16(std::clamp(x[f + j] * 32767.f, -32768.f, 32767.f));
          b = gst_buffer_new_memdup(s.data(), k * sizeof(gint16));
        }
        GST_BUFFER_PTS(b) = gst_util_uint64_scale(f, GST_SECOND, rate);
        GST_BUFFER_DURATION(b) = gst_util_uint64_scale(k, GST_SECOND, rate);
        gst_app_src_push_buffer(GST_APP_SRC(src), b);
      }
      gst_app_src_end_of_stream(GST_APP_SRC(src));
      gst_object_unref(src);
    }
  }
  GstBus* bus = gst_element_get_bus(pipe);
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  for (bool done = false; !done;) {
    GstMessage* m = gst_bus_timed_pop(bus, 60 * GST_SECOND);
    if (!m) break;
    switch (GST_MESSAGE_TYPE(m)) {
      case GST_MESSAGE_EOS: done = true; break;
      case GST_MESSAGE_ERROR: {
        GError* e = nullptr;
        gst_message_parse_error(m, &e, nullptr);
        r.errors.push_back(e->message);
        g_error_free(e);
        done = true;
        break;
      }
      case GST_MESSAGE_ELEMENT: {
        const GstStructure* st = gst_message_get_structure(m);
        if (st && gst_structure_has_name(st, "stitchsync-time-offsets")) r.offsets.push_back(gst_structure_copy(st));
        break;
      }
      default: break;
    }
    gst_message_unref(m);
  }
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(bus);
  gst_object_unref(pipe);
}

double frames_of(const GstStructure* s, int view) {
  gint64 off = 0;
  gst_structure_get_int64(s, ("offset-" + std::to_string(view)).c_str(), &off);
  return double(off) / 1e9 * 30;
}

}  // namespace

// Camera 1 started 7 frames after camera 0, camera 2 5 frames before it: the still video has
// nothing to align on, the audio has; the offsets come from the audio, within half a frame.
TEST(StitchSyncAudio, OffsetsFromTheCamerasAudio) {
  Result r;
  run("", {0.0, 7 / 30.0, -5 / 30.0}, 8, true, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  EXPECT_GT(r.bundles, 200);
  ASSERT_FALSE(r.offsets.empty()) << "no stitchsync-time-offsets message";
  const GstStructure* last = r.offsets.back();
  EXPECT_NEAR(frames_of(last, 1), 7.0, 0.5);
  EXPECT_NEAR(frames_of(last, 2), -5.0, 0.5);
  EXPECT_STREQ(gst_structure_get_string(last, "source-1"), "audio");
  EXPECT_STREQ(gst_structure_get_string(last, "source-2"), "audio");
  gdouble conf = 0;
  gst_structure_get_double(last, "confidence-1", &conf);
  EXPECT_GT(conf, 0.5);
}

// Camera 1's clock runs 0.5 % fast and it started 10 frames late: its sound drifts 5 ms a second
// against camera 0's. Over 40 s the audio's drift line gives the clock rate, which stitchsync
// posts as rate-1 (seconds of view 0 per second of view 1) and applies.
TEST(StitchSyncAudio, ClockRateFromTheAudio) {
  Result r;
  run("", {0.0, 10 / 30.0}, 40, true, r, false, {1.0, 1.005});
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_FALSE(r.offsets.empty()) << "no stitchsync-time-offsets message";
  const GstStructure* last = r.offsets.back();
  gdouble rate = 0;
  ASSERT_TRUE(gst_structure_get_double(last, "rate-1", &rate));
  EXPECT_NEAR(rate, 1.0 / 1.005, 0.0005);
  EXPECT_STREQ(gst_structure_get_string(last, "source-1"), "audio");
  // drift included: after t s of camera 1's clock the offset is 1/3 s + (rate - 1) t, well below
  // the start offset of 10 frames by the end (about 4 frames at 40 s)
  EXPECT_LT(frames_of(last, 1), 9.0);
  EXPECT_GT(frames_of(last, 1), 3.0);
}

// The same through stitchbin's audio_%u pads.
TEST(StitchSyncAudio, ThroughStitchbin) {
  Result r;
  run("", {0.0, 4 / 30.0}, 6, true, r, true);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_FALSE(r.offsets.empty()) << "no stitchsync-time-offsets message";
  EXPECT_NEAR(frames_of(r.offsets.back(), 1), 4.0, 0.5);
  EXPECT_STREQ(gst_structure_get_string(r.offsets.back(), "source-1"), "audio");
}

// The same cameras without their audio: nothing to align on, the offsets stay 0.
TEST(StitchSyncAudio, WithoutAudioStillVideoGivesNothing) {
  Result r;
  run("", {0.0, 7 / 30.0}, 6, false, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  for (const GstStructure* s : r.offsets) {
    EXPECT_EQ(frames_of(s, 1), 0.0);
    EXPECT_STRNE(gst_structure_get_string(s, "source-1"), "audio");
  }
}

// Audio with no stitchsync to feed: a clear error, not a silent no-op.
TEST(StitchSyncAudio, NoStitchsyncIsAnError) {
  GstElement* pipe = gst_parse_launch("stitchsyncaudio name=a audiotestsrc num-buffers=10 ! a.audio_0", nullptr);
  ASSERT_NE(pipe, nullptr);
  GstBus* bus = gst_element_get_bus(pipe);
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  GstMessage* m = gst_bus_timed_pop_filtered(bus, 10 * GST_SECOND, GstMessageType(GST_MESSAGE_ERROR | GST_MESSAGE_EOS));
  ASSERT_NE(m, nullptr);
  ASSERT_EQ(GST_MESSAGE_TYPE(m), GST_MESSAGE_ERROR);
  GError* e = nullptr;
  gst_message_parse_error(m, &e, nullptr);
  EXPECT_NE(std::string(e->message).find("no stitchsync"), std::string::npos) << e->message;
  g_error_free(e);
  gst_message_unref(m);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(bus);
  gst_object_unref(pipe);
}
