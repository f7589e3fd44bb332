// stitchsync element tests: GstHarness pushes frames whose pixels encode (input, frame number)
// into the aggregator and the tests check which input frame every view of every output bundle
// holds, the bundle timing, the missing-view mask, the input-eos modes, the framerate property,
// format conversion, the interlaced refusal and the pad limit.
#include <gst/check/gstharness.h>
#include <gst/gst.h>
#include <gst/video/video.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <random>
#include <string>
#include <thread>
#include <vector>

// Only the struct layout and the STITCH_* constants are used from here; the functions live
// in the plugin, which the test does not link.
#include "../../gst/gststitchbundle.h"
#include "stitch/backend.hpp"
#include "stitch/convert/convert.hpp"

namespace {

class GstEnvironment : public ::testing::Environment {
 public:
  void SetUp() override { gst_init(nullptr, nullptr); }
};
::testing::Environment* const gst_env = ::testing::AddGlobalTestEnvironment(new GstEnvironment);

constexpr int kWidth = 64;
constexpr int kHeight = 48;

// ---------------------------------------------------------------------------------------------
// Inputs: each frame carries a code in its pixels. For RGBA inputs the code identifies
// (input, frame): R = code, G = 255 - code, B = 17 * input + 3, A = 255, on every pixel.

int frame_code(int input, int frame) { return 1 + input * 100 + frame; }  // frame < 99
std::array<guint8, 4> code_pixel(int input, int code) {
  return {guint8(code), guint8(255 - code), guint8(17 * input + 3), 255};
}

struct Frame {
  GstClockTime pts = 0;
  GstClockTime duration = 0;
  int number = 0;  // frame number within its input
};

struct Input {
  std::string caps;                      // full caps string
  std::vector<Frame> frames;
  bool send_eos = true;
  // Raw per-plane fill values for non-RGBA inputs (e.g. Y, U, V); empty = RGBA code pixels.
  std::vector<guint8> plane_values;
  // A whole frame's bytes in the caps' default layout, used for every frame when not empty.
  std::vector<guint8> frame_bytes;
};

std::string rgba_caps(int fps_n, int fps_d = 1) {
  return "video/x-raw,format=RGBA,width=" + std::to_string(kWidth) +
         ",height=" + std::to_string(kHeight) + ",framerate=" + std::to_string(fps_n) + "/" +
         std::to_string(fps_d);
}

Input rgba_input(std::string caps, std::vector<Frame> frames) {
  Input in;
  in.caps = std::move(caps);
  in.frames = std::move(frames);
  return in;
}

// Frames at `fps`, frame numbers [0, count), shifted by `offset`; numbers in `skip` are left
// out (a gap). Each frame lasts until the next slot of the nominal rate. Timestamps truncate
// like videotestsrc's and GstVideoAggregator's output timestamps.
std::vector<Frame> frames_at(int fps, int count, GstClockTime offset = 0,
                             const std::vector<int>& skip = {}) {
  std::vector<Frame> out;
  for (int f = 0; f < count; ++f) {
    bool skipped = false;
    for (int s : skip) skipped = skipped || s == f;
    if (skipped) continue;
    const GstClockTime a = gst_util_uint64_scale(guint64(f), GST_SECOND, guint64(fps));
    const GstClockTime b = gst_util_uint64_scale(guint64(f + 1), GST_SECOND, guint64(fps));
    out.push_back({offset + a, b - a, f});
  }
  return out;
}

GstClockTime end_of(const Input& in) {
  if (in.frames.empty()) return 0;
  return in.frames.back().pts + in.frames.back().duration;
}

// The frame the aggregator shows at output running time t: the most recent one that started
// at or before t; -1 when none started yet.
int frame_at(const Input& in, GstClockTime t) {
  int best = -1;
  for (const Frame& f : in.frames)
    if (f.pts <= t) best = f.number;
  return best;
}

GstBuffer* make_buffer(const Input& in, int input_index, const Frame& fr) {
  GstCaps* caps = gst_caps_from_string(in.caps.c_str());
  GstVideoInfo info;
  const gboolean ok = gst_video_info_from_caps(&info, caps);
  gst_caps_unref(caps);
  if (!ok) return nullptr;
  GstBuffer* buf = gst_buffer_new_allocate(nullptr, GST_VIDEO_INFO_SIZE(&info), nullptr);
  if (!in.frame_bytes.empty()) {
    gst_buffer_fill(buf, 0, in.frame_bytes.data(), std::min(in.frame_bytes.size(), gsize(GST_VIDEO_INFO_SIZE(&info))));
    GST_BUFFER_PTS(buf) = fr.pts;
    GST_BUFFER_DURATION(buf) = fr.duration;
    return buf;
  }
  GstVideoFrame vf;
  if (!gst_video_frame_map(&vf, &info, buf, GST_MAP_WRITE)) {
    gst_buffer_unref(buf);
    return nullptr;
  }
  if (in.plane_values.empty()) {
    const auto px = code_pixel(input_index, frame_code(input_index, fr.number));
    auto* data = static_cast<guint8*>(GST_VIDEO_FRAME_PLANE_DATA(&vf, 0));
    const int stride = GST_VIDEO_FRAME_PLANE_STRIDE(&vf, 0);
    for (int y = 0; y < GST_VIDEO_FRAME_HEIGHT(&vf); ++y)
      for (int x = 0; x < GST_VIDEO_FRAME_WIDTH(&vf); ++x)
        for (int c = 0; c < 4; ++c) data[y * stride + x * 4 + c] = px[c];
  } else {
    for (guint p = 0; p < GST_VIDEO_FRAME_N_PLANES(&vf) && p < in.plane_values.size(); ++p) {
      auto* data = static_cast<guint8*>(GST_VIDEO_FRAME_PLANE_DATA(&vf, p));
      const int stride = GST_VIDEO_FRAME_PLANE_STRIDE(&vf, p);
      const int rows = GST_VIDEO_FRAME_COMP_HEIGHT(&vf, p);
      for (int y = 0; y < rows; ++y) memset(data + y * stride, in.plane_values[p], gsize(stride));
    }
  }
  gst_video_frame_unmap(&vf);
  GST_BUFFER_PTS(buf) = fr.pts;
  GST_BUFFER_DURATION(buf) = fr.duration;
  return buf;
}

// ---------------------------------------------------------------------------------------------
// Reading bundles.

const GstStitchBundleMeta* bundle_meta(GstBuffer* buf) {
  gpointer state = nullptr;
  while (GstMeta* m = gst_buffer_iterate_meta(buf, &state)) {
    if (g_strcmp0(g_type_name(m->info->api), "GstStitchBundleMetaAPI") == 0)
      return reinterpret_cast<const GstStitchBundleMeta*>(m);
  }
  return nullptr;
}

struct View {
  bool present = false;  // a GstVideoMeta with this id exists and maps
  GstVideoFormat format = GST_VIDEO_FORMAT_UNKNOWN;
  int width = 0, height = 0, stride = 0;
  std::array<guint8, 4> first{}, last{}, middle{};
  bool uniform = false;  // first, middle and last pixel agree
};

View read_view(GstBuffer* buf, int id) {
  View v;
  GstVideoMeta* vm = gst_buffer_get_video_meta_id(buf, id);
  if (!vm) return v;
  v.format = vm->format;
  v.width = int(vm->width);
  v.height = int(vm->height);
  GstMapInfo map;
  gpointer data = nullptr;
  gint stride = 0;
  if (!gst_video_meta_map(vm, 0, &map, &data, &stride, GST_MAP_READ)) return v;
  v.present = true;
  v.stride = stride;
  const auto* p = static_cast<const guint8*>(data);
  auto px = [&](int x, int y) {
    std::array<guint8, 4> a;
    for (int c = 0; c < 4; ++c) a[c] = p[gsize(y) * gsize(stride) + gsize(x) * 4 + gsize(c)];
    return a;
  };
  v.first = px(0, 0);
  v.middle = px(v.width / 2, v.height / 2);
  v.last = px(v.width - 1, v.height - 1);
  v.uniform = v.first == v.last && v.first == v.middle;
  gst_video_meta_unmap(vm, 0, &map);
  return v;
}

// Frame number that a view's pixels encode for `input`; -1 when they encode no frame of it.
int decode_frame(const View& v, int input) {
  if (!v.present || !v.uniform) return -1;
  const int code = v.first[0];
  if (v.first != code_pixel(input, code)) return -1;
  const int frame = code - frame_code(input, 0);
  return frame >= 0 && frame < 99 ? frame : -1;
}

bool is_black(const View& v) {
  return v.present && v.uniform && v.first == std::array<guint8, 4>{0, 0, 0, 0};
}

std::string caps_string(const GstCaps* caps) {
  gchar* s = gst_caps_to_string(caps);
  std::string r = s ? s : "";
  g_free(s);
  return r;
}

// ---------------------------------------------------------------------------------------------
// Fixture: one stitchsync with N harnessed inputs; outputs come out of inputs[0]'s harness.

class StitchSyncTest : public ::testing::Test {
 protected:
  GstElement* element = nullptr;
  GstBus* bus = nullptr;
  std::vector<GstHarness*> harnesses;
  std::vector<GstBuffer*> outputs;
  GstCaps* out_caps = nullptr;
  bool got_eos = false;

  void SetUp() override {
    element = gst_element_factory_make("stitchsync", nullptr);
    ASSERT_NE(element, nullptr) << "stitchsync not found (GST_PLUGIN_PATH=" <<
        (g_getenv("GST_PLUGIN_PATH") ? g_getenv("GST_PLUGIN_PATH") : "") << ")";
    gst_object_ref_sink(element);
    bus = gst_bus_new();
    gst_element_set_bus(element, bus);
  }

  void TearDown() override {
    for (GstBuffer* b : outputs) gst_buffer_unref(b);
    outputs.clear();
    if (out_caps) gst_caps_unref(out_caps);
    for (auto it = harnesses.rbegin(); it != harnesses.rend(); ++it) gst_harness_teardown(*it);
    harnesses.clear();
    if (element) {
      gst_element_set_state(element, GST_STATE_NULL);
      gst_element_set_bus(element, nullptr);
      gst_object_unref(element);
    }
    if (bus) gst_object_unref(bus);
  }

  // Requests sink pads in `pad_numbers` order; harness 0 also takes the src pad.
  void attach(const std::vector<int>& pad_numbers) {
    for (std::size_t i = 0; i < pad_numbers.size(); ++i) {
      const std::string name = "sink_" + std::to_string(pad_numbers[i]);
      harnesses.push_back(
          gst_harness_new_with_element(element, name.c_str(), i == 0 ? "src" : nullptr));
    }
  }
  void attach(int n) {
    std::vector<int> nums;
    for (int i = 0; i < n; ++i) nums.push_back(i);
    attach(nums);
  }

  // Sets caps on every harness, pushes every input from its own thread (the aggregator holds
  // one buffer per pad, so pushes block), collects outputs until EOS or `timeout_s`.
  // inputs[i] goes to harnesses[i]; `pixel_index[i]` is the input number coded into its pixels.
  void run(const std::vector<Input>& inputs, const std::vector<int>& pixel_index = {},
           double timeout_s = 10.0) {
    ASSERT_EQ(inputs.size(), harnesses.size());
    for (std::size_t i = 0; i < inputs.size(); ++i)
      gst_harness_set_src_caps_str(harnesses[i], inputs[i].caps.c_str());
    std::vector<std::thread> pushers;
    for (std::size_t i = 0; i < inputs.size(); ++i) {
      const int idx = pixel_index.empty() ? int(i) : pixel_index[i];
      pushers.emplace_back([h = harnesses[i], &in = inputs[i], idx]() {
        for (const Frame& f : in.frames) {
          GstBuffer* b = make_buffer(in, idx, f);
          if (!b || gst_harness_push(h, b) != GST_FLOW_OK) break;
        }
        if (in.send_eos) gst_harness_push_event(h, gst_event_new_eos());
      });
    }
    GstHarness* h0 = harnesses[0];
    const gint64 deadline = g_get_monotonic_time() + gint64(timeout_s * G_TIME_SPAN_SECOND);
    while (!got_eos && g_get_monotonic_time() < deadline) {
      while (GstBuffer* b = gst_harness_try_pull(h0)) outputs.push_back(b);
      while (GstEvent* e = gst_harness_try_pull_event(h0)) {
        if (GST_EVENT_TYPE(e) == GST_EVENT_EOS) got_eos = true;
        gst_event_unref(e);
      }
      if (!got_eos) g_usleep(1000);
    }
    // EOS comes after the last buffer: whatever was queued before it is here now.
    while (GstBuffer* b = gst_harness_try_pull(h0)) outputs.push_back(b);
    out_caps = gst_pad_get_current_caps(h0->sinkpad);
    // Unblock pushers that wait on a pad the aggregator no longer drains.
    gst_element_set_state(element, GST_STATE_NULL);
    for (auto& t : pushers) t.join();
  }

  // Message and debug text of the next ERROR on the element's bus; empty when none comes.
  std::pair<std::string, std::string> pop_error(double timeout_s) {
    GstMessage* m = gst_bus_timed_pop_filtered(bus, GstClockTime(timeout_s * GST_SECOND),
                                               GST_MESSAGE_ERROR);
    if (!m) return {};
    GError* err = nullptr;
    gchar* dbg = nullptr;
    gst_message_parse_error(m, &err, &dbg);
    std::pair<std::string, std::string> text{err ? err->message : "", dbg ? dbg : ""};
    g_clear_error(&err);
    g_free(dbg);
    gst_message_unref(m);
    return text;
  }

  // Output timing at `fps_n/fps_d`: PTS of output k (GstVideoAggregator truncates).
  static GstClockTime out_pts(int k, int fps_n, int fps_d) {
    return gst_util_uint64_scale(guint64(k), GST_SECOND * guint64(fps_d), guint64(fps_n));
  }

  // Number of outputs a stream at the given rate has before `end`.
  static int outputs_before(GstClockTime end, int fps_n, int fps_d) {
    int k = 0;
    while (out_pts(k, fps_n, fps_d) < end) ++k;
    return k;
  }

  // Checks the caps, timing, layout and view contents of every output against `inputs`
  // (view i = inputs[i], unless `pixel_index` says which input's code view i carries).
  void check_bundles(const std::vector<Input>& inputs, int fps_n, int fps_d, int expected_count,
                     bool allow_missing = false) {
    const int n = int(inputs.size());
    ASSERT_NE(out_caps, nullptr);
    const GstStructure* s = gst_caps_get_structure(out_caps, 0);
    EXPECT_STREQ(gst_structure_get_string(s, "format"), "RGBA") << caps_string(out_caps);
    EXPECT_STREQ(gst_structure_get_string(s, "multiview-mode"), "separated");
    gint views = 0, w = 0, h = 0, cn = 0, cd = 0;
    EXPECT_TRUE(gst_structure_get_int(s, "views", &views));
    EXPECT_EQ(views, n);
    EXPECT_TRUE(gst_structure_get_int(s, "width", &w));
    EXPECT_TRUE(gst_structure_get_int(s, "height", &h));
    EXPECT_EQ(w, kWidth);
    EXPECT_EQ(h, kHeight);
    EXPECT_TRUE(gst_structure_get_fraction(s, "framerate", &cn, &cd));
    EXPECT_EQ(gint64(cn) * fps_d, gint64(fps_n) * cd) << "output framerate " << cn << "/" << cd;

    ASSERT_EQ(int(outputs.size()), expected_count);
    for (int k = 0; k < expected_count; ++k) {
      SCOPED_TRACE("output " + std::to_string(k));
      GstBuffer* b = outputs[std::size_t(k)];
      const GstClockTime t = out_pts(k, fps_n, fps_d);
      EXPECT_EQ(GST_BUFFER_PTS(b), t);
      EXPECT_EQ(GST_BUFFER_DURATION(b), out_pts(k + 1, fps_n, fps_d) - t);
      EXPECT_EQ(int(gst_buffer_n_memory(b)), n);
      const GstStitchBundleMeta* bm = bundle_meta(b);
      ASSERT_NE(bm, nullptr) << "no GstStitchBundleMeta";
      EXPECT_EQ(int(bm->n_views), n);
      for (int i = 0; i < n; ++i) {
        SCOPED_TRACE("view " + std::to_string(i));
        const View v = read_view(b, i);
        ASSERT_TRUE(v.present) << "no mappable GstVideoMeta with id " << i;
        EXPECT_EQ(v.format, GST_VIDEO_FORMAT_RGBA);
        EXPECT_EQ(v.width, kWidth);
        EXPECT_EQ(v.height, kHeight);
        const int want = frame_at(inputs[std::size_t(i)], t);
        const bool missing = (bm->missing_mask >> i) & 1;
        if (want < 0) {
          EXPECT_TRUE(allow_missing) << "test setup: input " << i << " has no frame yet";
          EXPECT_TRUE(missing) << "view without any frame yet is not marked missing";
          EXPECT_TRUE(is_black(v)) << "missing view is not black";
        } else {
          EXPECT_FALSE(missing) << "view wrongly marked missing";
          EXPECT_EQ(decode_frame(v, i), want)
              << "pixel " << int(v.first[0]) << "," << int(v.first[1]) << "," << int(v.first[2])
              << "," << int(v.first[3]);
        }
      }
    }
  }
};

// 1. Two rates: the output runs at the fastest (30 fps) and the 15 fps view holds the frame
//    covering each output time.
TEST_F(StitchSyncTest, DifferentRatesFollowFastestInput) {
  attach(2);
  std::vector<Input> in(2);
  in[0] = rgba_input(rgba_caps(30), frames_at(30, 30));
  in[1] = rgba_input(rgba_caps(15), frames_at(15, 15));
  run(in);
  EXPECT_TRUE(got_eos);
  const int count = outputs_before(std::max(end_of(in[0]), end_of(in[1])), 30, 1);
  EXPECT_EQ(count, 30);
  check_bundles(in, 30, 1, count);
  // The slow view really changes every second output (guards against a constant view).
  if (outputs.size() == 30) {
    EXPECT_EQ(decode_frame(read_view(outputs[2], 1), 1), 1);
    EXPECT_EQ(decode_frame(read_view(outputs[3], 1), 1), 1);
    EXPECT_EQ(decode_frame(read_view(outputs[29], 1), 1), 14);
  }
}

// Views follow pad numbers, not the order the pads were requested in.
TEST_F(StitchSyncTest, ViewsOrderedByPadNumber) {
  attach(std::vector<int>{2, 0, 1});  // harness j feeds sink_{2,0,1}[j]
  std::vector<Input> in(3);
  for (auto& i : in) i = rgba_input(rgba_caps(30), frames_at(30, 6));
  // Harness j pushes pixels coded as input number = its pad number.
  run(in, {2, 0, 1});
  EXPECT_TRUE(got_eos);
  ASSERT_EQ(outputs.size(), 6u);
  for (std::size_t k = 0; k < outputs.size(); ++k) {
    for (int v = 0; v < 3; ++v)
      EXPECT_EQ(decode_frame(read_view(outputs[k], v), v), int(k)) << "output " << k << " view " << v;
    const GstStitchBundleMeta* bm = bundle_meta(outputs[k]);
    ASSERT_NE(bm, nullptr);
    ASSERT_TRUE(bm->has_pad_numbers);
    for (int v = 0; v < 3; ++v) EXPECT_EQ(bm->pad_numbers[v], guint(v));
  }
}

// 2. An input that starts 100 ms late is black and marked missing until its first frame.
TEST_F(StitchSyncTest, LateInputMarkedMissingUntilFirstFrame) {
  attach(2);
  const GstClockTime offset = 100 * GST_MSECOND;
  std::vector<Input> in(2);
  in[0] = rgba_input(rgba_caps(30), frames_at(30, 30));
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 27, offset));
  run(in);
  EXPECT_TRUE(got_eos);
  const int count = outputs_before(std::max(end_of(in[0]), end_of(in[1])), 30, 1);
  check_bundles(in, 30, 1, count, /*allow_missing=*/true);
  // Outputs before the late input's first frame (3 at 30 fps) had it missing, later ones not.
  const int n_missing = outputs_before(offset, 30, 1);
  ASSERT_EQ(n_missing, 3);
  for (int k = 0; k < int(outputs.size()); ++k) {
    const GstStitchBundleMeta* bm = bundle_meta(outputs[std::size_t(k)]);
    ASSERT_NE(bm, nullptr);
    EXPECT_EQ(bm->missing_mask, k < n_missing ? 0x2u : 0x0u) << "output " << k;
  }
}

// 3. A gap (frames 3..8 never sent): the view keeps the most recent frame that started at or
//    before the output time, then picks up again.
TEST_F(StitchSyncTest, GapRepeatsMostRecentFrame) {
  attach(2);
  std::vector<Input> in(2);
  in[0] = rgba_input(rgba_caps(30), frames_at(30, 30));
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 30, 0, {3, 4, 5, 6, 7, 8}));
  run(in);
  EXPECT_TRUE(got_eos);
  check_bundles(in, 30, 1, 30);
  if (outputs.size() == 30) {
    for (int k = 3; k <= 8; ++k)
      EXPECT_EQ(decode_frame(read_view(outputs[std::size_t(k)], 1), 1), 2) << "output " << k;
    EXPECT_EQ(decode_frame(read_view(outputs[9], 1), 1), 9);
  }
}

// 4. input-eos=repeat-last: the ended input's last frame is repeated until the other ends.
TEST_F(StitchSyncTest, RepeatLastAfterInputEos) {
  gst_util_set_object_arg(G_OBJECT(element), "input-eos", "repeat-last");
  attach(2);
  std::vector<Input> in(2);
  in[0] = rgba_input(rgba_caps(30), frames_at(30, 30));
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 15));
  run(in);
  EXPECT_TRUE(got_eos) << "no EOS after every input ended";
  const int count = outputs_before(end_of(in[0]), 30, 1);
  EXPECT_EQ(count, 30);
  check_bundles(in, 30, 1, count);
  if (outputs.size() == 30) {
    for (int k = 15; k < 30; ++k) {
      EXPECT_EQ(decode_frame(read_view(outputs[std::size_t(k)], 1), 1), 14) << "output " << k;
      EXPECT_EQ(decode_frame(read_view(outputs[std::size_t(k)], 0), 0), k) << "output " << k;
    }
  }
}

// 5. input-eos=end-stream: the output ends right after the shorter input's last frame.
TEST_F(StitchSyncTest, EndStreamWhenAnyInputEnds) {
  gst_util_set_object_arg(G_OBJECT(element), "input-eos", "end-stream");
  attach(2);
  std::vector<Input> in(2);
  in[0] = rgba_input(rgba_caps(30), frames_at(30, 30));
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 15));
  run(in);
  EXPECT_TRUE(got_eos) << "no EOS after the first input ended";
  const int count = outputs_before(std::min(end_of(in[0]), end_of(in[1])), 30, 1);
  EXPECT_EQ(count, 15);
  check_bundles(in, 30, 1, count);
}

// The same holds when the *first* pad is the one that ends.
TEST_F(StitchSyncTest, EndStreamWhenFirstPadEnds) {
  gst_util_set_object_arg(G_OBJECT(element), "input-eos", "end-stream");
  attach(2);
  std::vector<Input> in(2);
  in[0] = rgba_input(rgba_caps(30), frames_at(30, 10));
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 30));
  run(in);
  EXPECT_TRUE(got_eos);
  check_bundles(in, 30, 1, 10);
}

// 6. framerate=10/1 overrides the inputs' 30 fps.
TEST_F(StitchSyncTest, FrameratePropertyOverridesOutputRate) {
  GValue v = G_VALUE_INIT;
  g_value_init(&v, GST_TYPE_FRACTION);
  gst_value_set_fraction(&v, 10, 1);
  g_object_set_property(G_OBJECT(element), "framerate", &v);
  g_value_unset(&v);
  attach(2);
  std::vector<Input> in(2);
  in[0] = rgba_input(rgba_caps(30), frames_at(30, 30));
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 30));
  run(in);
  EXPECT_TRUE(got_eos);
  const int count = outputs_before(end_of(in[0]), 10, 1);
  EXPECT_EQ(count, 10);
  ASSERT_NE(out_caps, nullptr);
  gint n = 0, d = 0;
  EXPECT_TRUE(gst_structure_get_fraction(gst_caps_get_structure(out_caps, 0), "framerate", &n, &d));
  EXPECT_EQ(n, 10);
  EXPECT_EQ(d, 1);
  ASSERT_EQ(int(outputs.size()), count);
  int prev[2] = {-1, -1};
  for (int k = 0; k < count; ++k) {
    GstBuffer* b = outputs[std::size_t(k)];
    const GstClockTime t = out_pts(k, 10, 1), t_end = out_pts(k + 1, 10, 1);
    EXPECT_EQ(GST_BUFFER_PTS(b), t) << "output " << k;
    EXPECT_EQ(GST_BUFFER_DURATION(b), t_end - t) << "output " << k;
    // Downsampling: each view shows one input frame of the output's interval [t, t_end) and
    // time only moves forward. Which frame of the interval is not fixed: GstVideoAggregator
    // takes any queued frame that overlaps the interval, depending on thread timing
    // (documented in docs/ARCHITECTURE.md; put videorate before the inputs for exact decimation).
    for (int i = 0; i < 2; ++i) {
      const int f = decode_frame(read_view(b, i), i);
      ASSERT_GE(f, 0) << "output " << k << " view " << i;
      EXPECT_GT(f, prev[i]) << "output " << k << " view " << i << " went back in time";
      prev[i] = f;
      const Frame& fr = in[std::size_t(i)].frames[std::size_t(f)];
      EXPECT_LT(fr.pts, t_end) << "output " << k << " view " << i << " frame " << f;
      EXPECT_GT(fr.pts + fr.duration, t) << "output " << k << " view " << i << " frame " << f;
    }
  }
}

// RGBA that GStreamer's own converter makes of `in`'s first frame (first pixel).
std::array<guint8, 4> reference_rgba(const Input& in) {
  std::array<guint8, 4> px{};
  GstCaps* caps = gst_caps_from_string(in.caps.c_str());
  GstVideoInfo src_info, dst_info;
  const gboolean ok = gst_video_info_from_caps(&src_info, caps);
  gst_caps_unref(caps);
  if (!ok) return px;
  gst_video_info_set_format(&dst_info, GST_VIDEO_FORMAT_RGBA, guint(src_info.width),
                            guint(src_info.height));
  GST_VIDEO_INFO_FPS_N(&dst_info) = GST_VIDEO_INFO_FPS_N(&src_info);
  GST_VIDEO_INFO_FPS_D(&dst_info) = GST_VIDEO_INFO_FPS_D(&src_info);
  GstBuffer* sb = make_buffer(in, 0, in.frames.at(0));
  GstBuffer* db = gst_buffer_new_allocate(nullptr, GST_VIDEO_INFO_SIZE(&dst_info), nullptr);
  GstVideoFrame sf, df;
  if (sb && gst_video_frame_map(&sf, &src_info, sb, GST_MAP_READ)) {
    if (gst_video_frame_map(&df, &dst_info, db, GST_MAP_WRITE)) {
      if (GstVideoConverter* conv = gst_video_converter_new(&src_info, &dst_info, nullptr)) {
        gst_video_converter_frame(conv, &sf, &df);
        gst_video_converter_free(conv);
        memcpy(px.data(), GST_VIDEO_FRAME_PLANE_DATA(&df, 0), 4);
      }
      gst_video_frame_unmap(&df);
    }
    gst_video_frame_unmap(&sf);
  }
  if (sb) gst_buffer_unref(sb);
  gst_buffer_unref(db);
  return px;
}

// 7. A non-RGBA input is converted: an I420 frame of known Y/U/V comes out as RGBA close to
//    the BT.601 limited-range matrix (loosely: GStreamer's 8-bit fast path is off by up to 4)
//    and to what GstVideoConverter makes of the same frame (tightly).
TEST_F(StitchSyncTest, I420InputConvertedToRgba) {
  // The system-memory path, which is GStreamer's converter (on a GPU the harness would get CUDA
  // memory, converted by the exact matrix: StitchSyncFormats checks that one).
  gst_util_set_object_arg(G_OBJECT(element), "backend", "cpu");
  attach(2);
  const guint8 Y = 128, U = 100, V = 160;
  std::vector<Input> in(2);
  in[0].caps = "video/x-raw,format=I420,width=" + std::to_string(kWidth) +
               ",height=" + std::to_string(kHeight) + ",framerate=30/1,colorimetry=bt601";
  in[0].frames = frames_at(30, 3);
  in[0].plane_values = {Y, U, V};
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 3));
  run(in);
  EXPECT_TRUE(got_eos);
  ASSERT_EQ(outputs.size(), 3u);
  gdouble Kr = 0, Kb = 0;
  ASSERT_TRUE(gst_video_color_matrix_get_Kr_Kb(GST_VIDEO_COLOR_MATRIX_BT601, &Kr, &Kb));
  const double Kg = 1.0 - Kr - Kb;
  const double yn = (Y - 16) / 219.0, un = (U - 128) / 224.0, vn = (V - 128) / 224.0;
  const double rgb[3] = {255 * (yn + 2 * (1 - Kr) * vn),
                         255 * (yn - 2 * Kb * (1 - Kb) / Kg * un - 2 * Kr * (1 - Kr) / Kg * vn),
                         255 * (yn + 2 * (1 - Kb) * un)};
  const std::array<guint8, 4> ref = reference_rgba(in[0]);
  ASSERT_EQ(ref[3], 255) << "reference conversion failed";
  for (std::size_t k = 0; k < outputs.size(); ++k) {
    const View v0 = read_view(outputs[k], 0);
    ASSERT_TRUE(v0.present);
    EXPECT_EQ(v0.format, GST_VIDEO_FORMAT_RGBA);
    EXPECT_EQ(v0.width, kWidth);
    EXPECT_EQ(v0.height, kHeight);
    EXPECT_GE(v0.stride, kWidth * 4);
    EXPECT_TRUE(v0.uniform);
    for (int c = 0; c < 3; ++c) {
      EXPECT_NEAR(double(v0.first[c]), rgb[c], 6.0) << "output " << k << " channel " << c;
      EXPECT_NEAR(double(v0.first[c]), double(ref[c]), 2.0) << "output " << k << " channel " << c;
    }
    EXPECT_EQ(v0.first[3], 255);
    const GstStitchBundleMeta* bm = bundle_meta(outputs[k]);
    ASSERT_NE(bm, nullptr);
    EXPECT_EQ(bm->missing_mask, 0u);
    // The RGBA input next to it is untouched.
    EXPECT_EQ(decode_frame(read_view(outputs[k], 1), 1), int(k));
  }
}

// probe3: a camera with non-square pixels (pixel-aspect-ratio 4/3: anamorphic, DV/HDV) is
// resampled to square pixels (widened, nothing lost): its view has the picture's shape. Taken as
// square, a 540x404 4/3 camera beside a 720x404 one was stitched squeezed (rms 18 px, no warning).
TEST_F(StitchSyncTest, NonSquarePixelsBecomeSquareViews) {
  gst_util_set_object_arg(G_OBJECT(element), "backend", "cpu");
  attach(2);
  std::vector<Input> in(2);
  in[0].caps = "video/x-raw,format=I420,width=" + std::to_string(kWidth) + ",height=" + std::to_string(kHeight) +
               ",framerate=30/1,colorimetry=bt601,pixel-aspect-ratio=4/3";
  in[0].frames = frames_at(30, 3);
  in[0].plane_values = {128, 100, 160};
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 3));
  run(in);
  EXPECT_TRUE(got_eos);
  ASSERT_EQ(outputs.size(), 3u);
  for (std::size_t k = 0; k < outputs.size(); ++k) {
    const View v0 = read_view(outputs[k], 0);
    ASSERT_TRUE(v0.present);
    EXPECT_EQ(v0.width, (kWidth * 4 + 1) / 3) << "output " << k;
    EXPECT_EQ(v0.height, kHeight) << "output " << k;
    EXPECT_TRUE(v0.uniform);
    const View v1 = read_view(outputs[k], 1);
    EXPECT_EQ(v1.width, kWidth);
    EXPECT_EQ(decode_frame(v1, 1), int(k));
    // each view says which pad it comes from (stitchcalib keeps the others when one leaves)
    const GstStitchBundleMeta* bm = bundle_meta(outputs[k]);
    ASSERT_NE(bm, nullptr);
    EXPECT_TRUE(bm->has_pad_numbers);
    EXPECT_EQ(bm->pad_numbers[0], 0u);
    EXPECT_EQ(bm->pad_numbers[1], 1u);
  }
}

// 8. Interlaced caps are refused with an error that names the pad.
TEST_F(StitchSyncTest, InterlacedInputErrorNamesPad) {
  attach(2);
  gst_harness_set_src_caps_str(harnesses[0], rgba_caps(30).c_str());
  // Pushed directly: gst_harness_set_src_caps asserts that the event is accepted.
  GstCaps* caps = gst_caps_from_string((rgba_caps(30) + ",interlace-mode=interleaved").c_str());
  gst_pad_push_event(harnesses[1]->srcpad, gst_event_new_caps(caps));
  gst_caps_unref(caps);
  const auto [message, debug] = pop_error(5.0);
  ASSERT_FALSE(message.empty()) << "no error message for interlaced input";
  EXPECT_NE(message.find("sink_1"), std::string::npos) << message << " | " << debug;
  EXPECT_EQ(message.find("sink_0"), std::string::npos) << message;
  EXPECT_NE(message.find("interlaced"), std::string::npos) << message;
  // Nothing was bundled from the refused input.
  GstBuffer* out = gst_harness_try_pull(harnesses[0]);
  EXPECT_EQ(out, nullptr);
  if (out) gst_buffer_unref(out);
}

// 9. At most 16 inputs: the 17th request fails; a released pad frees a slot.
TEST_F(StitchSyncTest, SeventeenthPadRefused) {
  std::vector<GstPad*> pads;
  for (int i = 0; i < STITCH_MAX_VIEWS; ++i) {
    GstPad* p = gst_element_request_pad_simple(element, "sink_%u");
    ASSERT_NE(p, nullptr) << "request " << i;
    pads.push_back(p);
  }
  EXPECT_EQ(int(element->numsinkpads), 16);
  GstPad* extra = gst_element_request_pad_simple(element, "sink_%u");
  EXPECT_EQ(extra, nullptr);
  if (extra) pads.push_back(extra);
  EXPECT_EQ(int(element->numsinkpads), 16);
  // the reason is on the bus, not only in the debug log
  GstMessage* m = gst_bus_timed_pop_filtered(bus, GST_SECOND, GST_MESSAGE_WARNING);
  ASSERT_NE(m, nullptr) << "no warning on the bus for the refused pad";
  GError* err = nullptr;
  gst_message_parse_warning(m, &err, nullptr);
  EXPECT_NE(std::string(err->message).find("at most 16 inputs"), std::string::npos) << err->message;
  g_error_free(err);
  gst_message_unref(m);
  // Freeing one slot lets a new request through.
  gst_element_release_request_pad(element, pads.back());
  gst_object_unref(pads.back());
  pads.pop_back();
  GstPad* again = gst_element_request_pad_simple(element, "sink_%u");
  EXPECT_NE(again, nullptr);
  if (again) pads.push_back(again);
  for (GstPad* p : pads) {
    gst_element_release_request_pad(element, p);
    gst_object_unref(p);
  }
}

// Property defaults and enum nicks the other tests rely on.
TEST_F(StitchSyncTest, PropertyDefaults) {
  GValue v = G_VALUE_INIT;
  g_value_init(&v, GST_TYPE_FRACTION);
  g_object_get_property(G_OBJECT(element), "framerate", &v);
  EXPECT_EQ(gst_value_get_fraction_numerator(&v), 0);
  EXPECT_EQ(gst_value_get_fraction_denominator(&v), 1);
  g_value_unset(&v);
  GParamSpec* ps = g_object_class_find_property(G_OBJECT_GET_CLASS(element), "input-eos");
  ASSERT_NE(ps, nullptr);
  gint eos_mode = -1;
  g_object_get(element, "input-eos", &eos_mode, NULL);
  GEnumValue* ev = g_enum_get_value(G_PARAM_SPEC_ENUM(ps)->enum_class, eos_mode);
  ASSERT_NE(ev, nullptr);
  EXPECT_STREQ(ev->value_nick, "repeat-last");
  EXPECT_NE(g_enum_get_value_by_nick(G_PARAM_SPEC_ENUM(ps)->enum_class, "end-stream"), nullptr);
}

// ---------------------------------------------------------------------------------------------
// Decoder formats and memory.

// A smooth RGBA card: gentle ramps in every channel, so that 4:2:0 chroma interpolated one way or
// another moves a pixel by about a level.
std::vector<guint8> rgba_card(int w, int h) {
  std::vector<guint8> px(gsize(w) * gsize(h) * 4);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      guint8* p = &px[(gsize(y) * gsize(w) + gsize(x)) * 4];
      p[0] = guint8(40 + x);
      p[1] = guint8(60 + 2 * y);
      p[2] = guint8(200 - x / 2 - y / 2);
      p[3] = 255;
    }
  return px;
}

// `src` (a frame of `from`) converted by GStreamer's video converter to a frame of `to`, both in
// their default layouts.
std::vector<guint8> video_convert(const std::vector<guint8>& src, const GstVideoInfo& from, const GstVideoInfo& to) {
  std::vector<guint8> out(GST_VIDEO_INFO_SIZE(&to));
  GstBuffer* sb = gst_buffer_new_allocate(nullptr, GST_VIDEO_INFO_SIZE(&from), nullptr);
  gst_buffer_fill(sb, 0, src.data(), std::min(src.size(), gsize(GST_VIDEO_INFO_SIZE(&from))));
  GstBuffer* db = gst_buffer_new_allocate(nullptr, GST_VIDEO_INFO_SIZE(&to), nullptr);
  GstVideoFrame sf, df;
  if (gst_video_frame_map(&sf, &from, sb, GST_MAP_READ)) {
    if (gst_video_frame_map(&df, &to, db, GST_MAP_WRITE)) {
      if (GstVideoConverter* conv = gst_video_converter_new(&from, &to, nullptr)) {
        gst_video_converter_frame(conv, &sf, &df);
        gst_video_converter_free(conv);
      }
      gst_video_frame_unmap(&df);
    }
    gst_video_frame_unmap(&sf);
  }
  gst_buffer_extract(db, 0, out.data(), out.size());
  gst_buffer_unref(sb);
  gst_buffer_unref(db);
  return out;
}

GstVideoInfo info_from(const std::string& caps_str) {
  GstVideoInfo info;
  gst_video_info_init(&info);
  GstCaps* caps = gst_caps_from_string(caps_str.c_str());
  EXPECT_TRUE(gst_video_info_from_caps(&info, caps)) << caps_str;
  gst_caps_unref(caps);
  return info;
}

// A view's pixels, rows packed.
std::vector<guint8> view_pixels(GstBuffer* buf, int id) {
  std::vector<guint8> px;
  GstVideoMeta* vm = gst_buffer_get_video_meta_id(buf, id);
  if (!vm) return px;
  GstMapInfo map;
  gpointer data = nullptr;
  gint stride = 0;
  if (!gst_video_meta_map(vm, 0, &map, &data, &stride, GST_MAP_READ)) return px;
  const gsize row = gsize(vm->width) * 4;
  px.resize(row * vm->height);
  for (guint y = 0; y < vm->height; ++y)
    memcpy(&px[y * row], static_cast<const guint8*>(data) + gsize(y) * gsize(stride), row);
  gst_video_meta_unmap(vm, 0, &map);
  return px;
}

bool caps_in_cuda_memory(const GstCaps* caps) {
  if (!caps || gst_caps_is_empty(caps) || gst_caps_is_any(caps)) return false;
  const GstCapsFeatures* f = gst_caps_get_features(caps, 0);
  return f && gst_caps_features_contains(f, "memory:CUDAMemory");
}

// Largest and mean absolute difference of two RGBA images, alpha left out.
std::pair<int, double> difference(const std::vector<guint8>& a, const std::vector<guint8>& b) {
  int worst = 0;
  double sum = 0;
  for (std::size_t i = 0; i < a.size() && i < b.size(); ++i) {
    if (i % 4 == 3) continue;
    const int d = std::abs(int(a[i]) - int(b[i]));
    worst = std::max(worst, d);
    sum += d;
  }
  return {worst, sum / (double(a.size()) * 0.75)};
}

// "Within a few levels" of videoconvert: it dithers its 16-bit intermediate (about 2 levels of
// noise) and takes 4:2:0 chroma differently; on the smooth card that stays below these bounds.
constexpr int kMaxLevels = 8;
constexpr double kMeanLevels = 3.0;

class StitchSyncFormats : public StitchSyncTest {
 protected:
  // Input 0 is the card in `format` (system memory); the view must be what videoconvert makes
  // of it within a few levels (the system-memory path is GStreamer's converter itself; on a GPU
  // the bundle is converted by our kernels, which use the exact matrix and bilinear chroma).
  void check_matches_videoconvert(const char* format, const char* colorimetry) {
    attach(2);
    const std::string caps = std::string("video/x-raw,format=") + format + ",width=" + std::to_string(kWidth) +
                             ",height=" + std::to_string(kHeight) + ",framerate=30/1,colorimetry=" + colorimetry;
    const GstVideoInfo yuv = info_from(caps), rgba = info_from(rgba_caps(30));
    std::vector<Input> in(2);
    in[0].caps = caps;
    in[0].frames = frames_at(30, 3);
    in[0].frame_bytes = video_convert(rgba_card(kWidth, kHeight), rgba, yuv);
    in[1] = rgba_input(rgba_caps(30), frames_at(30, 3));
    run(in);
    EXPECT_TRUE(got_eos);
    ASSERT_EQ(outputs.size(), 3u);
    const std::vector<guint8> want = video_convert(in[0].frame_bytes, yuv, rgba);
    for (std::size_t k = 0; k < outputs.size(); ++k) {
      const std::vector<guint8> got = view_pixels(outputs[k], 0);
      ASSERT_EQ(got.size(), want.size()) << "output " << k;
      const auto [worst, mean] = difference(got, want);
      EXPECT_LE(worst, kMaxLevels) << format << " " << colorimetry << " output " << k;
      EXPECT_LE(mean, kMeanLevels) << format << " " << colorimetry << " output " << k;
      for (std::size_t i = 3; i < got.size(); i += 4) ASSERT_EQ(got[i], 255) << "alpha at byte " << i;
      EXPECT_EQ(decode_frame(read_view(outputs[k], 1), 1), int(k));
    }
  }
};

// What decoders deliver: NV12 (BT.709, H.264's chroma siting) and I420 (BT.601), system memory.
TEST_F(StitchSyncFormats, Nv12MatchesVideoconvert) { check_matches_videoconvert("NV12", "bt709"); }
TEST_F(StitchSyncFormats, I420MatchesVideoconvert) { check_matches_videoconvert("I420", "bt601"); }

// The conversion our CUDA kernels run (stitch/convert; its CPU implementation computes the same
// bytes, tests/core/test_cuda_convert.cpp) against videoconvert, for every matrix, range and
// layout decoders deliver: checked here, where no GPU is needed.
TEST(StitchSyncConversion, CoreConverterMatchesVideoconvert) {
  for (const char* format : {"NV12", "I420"})
    for (const char* colorimetry : {"bt601", "bt709", "1:4:0:0"}) {  // the last: BT.601 full range
      SCOPED_TRACE(std::string(format) + " " + colorimetry);
      const GstVideoInfo yuv = info_from(std::string("video/x-raw,format=") + format + ",width=" + std::to_string(kWidth) +
                                         ",height=" + std::to_string(kHeight) + ",framerate=30/1,colorimetry=" + colorimetry);
      const GstVideoInfo rgba = info_from(rgba_caps(30));
      const std::vector<guint8> card = rgba_card(kWidth, kHeight);
      const std::vector<guint8> frame = video_convert(card, rgba, yuv);
      stitch::FrameView v;
      v.format = GST_VIDEO_INFO_FORMAT(&yuv) == GST_VIDEO_FORMAT_NV12 ? stitch::FrameFormat::NV12 : stitch::FrameFormat::I420;
      v.width = kWidth;
      v.height = kHeight;
      for (guint p = 0; p < GST_VIDEO_INFO_N_PLANES(&yuv); ++p) {
        v.planes[p] = frame.data() + GST_VIDEO_INFO_PLANE_OFFSET(&yuv, p);
        v.pitches[p] = std::size_t(GST_VIDEO_INFO_PLANE_STRIDE(&yuv, p));
      }
      gdouble kr = 0, kb = 0;
      ASSERT_TRUE(gst_video_color_matrix_get_Kr_Kb(yuv.colorimetry.matrix, &kr, &kb));
      v.colorimetry.kr = kr;
      v.colorimetry.kb = kb;
      v.colorimetry.full_range = yuv.colorimetry.range == GST_VIDEO_COLOR_RANGE_0_255;
      v.colorimetry.chroma_cosited_x = (yuv.chroma_site & GST_VIDEO_CHROMA_SITE_H_COSITED) != 0;
      v.colorimetry.chroma_cosited_y = (yuv.chroma_site & GST_VIDEO_CHROMA_SITE_V_COSITED) != 0;
      std::vector<guint8> ours(gsize(kWidth) * kHeight * 4);
      stitch::ImageView out;
      out.data = ours.data();
      out.pitch = gsize(kWidth) * 4;
      out.width = kWidth;
      out.height = kHeight;
      auto converter = stitch::FrameConverter::create(stitch::Backend::Cpu);
      converter->convert(v, out);
      converter->finish();
      const auto [worst, mean] = difference(ours, video_convert(frame, yuv, rgba));
      EXPECT_LE(worst, kMaxLevels);
      EXPECT_LE(mean, kMeanLevels);
      // and it is at least as faithful to the card the frame was made from
      const auto [worst_card, mean_card] = difference(ours, card);
      EXPECT_LE(mean_card, difference(video_convert(frame, yuv, rgba), card).second + 0.25);
      (void)worst_card;
    }
}

// backend=auto|cpu|cuda, auto by default.
TEST_F(StitchSyncTest, BackendProperty) {
  GParamSpec* ps = g_object_class_find_property(G_OBJECT_GET_CLASS(element), "backend");
  ASSERT_NE(ps, nullptr) << "stitchsync has no backend property";
  ASSERT_TRUE(G_IS_PARAM_SPEC_ENUM(ps));
  gint value = -1;
  g_object_get(element, "backend", &value, NULL);
  GEnumValue* ev = g_enum_get_value(G_PARAM_SPEC_ENUM(ps)->enum_class, value);
  ASSERT_NE(ev, nullptr);
  EXPECT_STREQ(ev->value_nick, "auto");
  for (const char* nick : {"cpu", "cuda"})
    EXPECT_NE(g_enum_get_value_by_nick(G_PARAM_SPEC_ENUM(ps)->enum_class, nick), nullptr) << nick;
}

// backend=cpu: bundles in system memory whatever the machine has (the harness takes anything).
TEST_F(StitchSyncTest, BackendCpuKeepsSystemMemory) {
  gst_util_set_object_arg(G_OBJECT(element), "backend", "cpu");
  attach(2);
  std::vector<Input> in(2);
  for (auto& i : in) i = rgba_input(rgba_caps(30), frames_at(30, 3));
  run(in);
  EXPECT_TRUE(got_eos);
  check_bundles(in, 30, 1, 3);
  EXPECT_FALSE(caps_in_cuda_memory(out_caps)) << caps_string(out_caps);
}

// backend=cuda where no device opens is a negotiation error that says why.
TEST_F(StitchSyncTest, BackendCudaWithoutDeviceIsAClearError) {
  if (stitch::cuda_device_available())
    GTEST_SKIP() << "a CUDA device opens here: backend=cuda is checked by test_cuda_memory";
  gst_util_set_object_arg(G_OBJECT(element), "backend", "cuda");
  attach(2);
  std::vector<Input> in(2);
  for (auto& i : in) i = rgba_input(rgba_caps(30), frames_at(30, 3));
  run(in, {}, 3.0);
  EXPECT_TRUE(outputs.empty());
  const auto [message, debug] = pop_error(5.0);
  EXPECT_NE(message.find("backend=cuda"), std::string::npos) << message << " | " << debug;
}

// ---------------------------------------------------------------------------------------------
// Time alignment (issue 18).

// Uniform RGBA frames whose brightness follows a scene of random flashes; camera `input` shows
// scene frame f + start[input] as its frame f.
std::vector<guint8> flash_frame(int scene_frame) {
  static const std::vector<guint32> scene = []() {
    std::mt19937 rng(42);
    std::vector<guint32> v(4000);
    for (auto& x : v) x = rng();
    return v;
  }();
  const guint32 h = scene[std::size_t(scene_frame) % scene.size()];
  const bool flash = h % 9 == 0;
  const guint8 v = guint8(flash ? 200 : 60 + (h >> 8) % 8);
  std::vector<guint8> px(gsize(kWidth) * kHeight * 4, v);
  for (gsize i = 3; i < px.size(); i += 4) px[i] = 255;
  return px;
}

class StitchSyncAlign : public StitchSyncTest {
 protected:
  // Pushes `frames` frames of each camera (camera i starts `start[i]` scene frames late), the
  // frame's pixels from `pixels(scene frame)`; collects every output and the offsets messages.
  std::vector<GstStructure*> offsets;
  std::vector<std::string> warnings;
  void TearDown() override {
    for (GstStructure* s : offsets) gst_structure_free(s);
    StitchSyncTest::TearDown();
  }
  void play(const std::vector<int>& start, int frames, std::vector<guint8> (*pixels)(int)) {
    attach(int(start.size()));
    std::vector<Input> in(start.size());
    for (std::size_t i = 0; i < start.size(); ++i) {
      in[i] = rgba_input(rgba_caps(30), {});
      in[i].frames = frames_at(30, frames);
    }
    // frame_bytes is per input, not per frame: push by hand instead of run()
    for (std::size_t i = 0; i < in.size(); ++i) gst_harness_set_src_caps_str(harnesses[i], in[i].caps.c_str());
    std::vector<std::thread> pushers;
    for (std::size_t i = 0; i < in.size(); ++i)
      pushers.emplace_back([h = harnesses[i], &input = in[i], s = start[i], pixels]() {
        for (const Frame& f : input.frames) {
          const std::vector<guint8> px = pixels(f.number + s);
          GstBuffer* b = gst_buffer_new_allocate(nullptr, px.size(), nullptr);
          gst_buffer_fill(b, 0, px.data(), px.size());
          GST_BUFFER_PTS(b) = f.pts;
          GST_BUFFER_DURATION(b) = f.duration;
          if (gst_harness_push(h, b) != GST_FLOW_OK) break;
        }
        gst_harness_push_event(h, gst_event_new_eos());
      });
    const gint64 deadline = g_get_monotonic_time() + 60 * G_TIME_SPAN_SECOND;
    while (!got_eos && g_get_monotonic_time() < deadline) {
      while (GstBuffer* b = gst_harness_try_pull(harnesses[0])) outputs.push_back(b);
      while (GstEvent* e = gst_harness_try_pull_event(harnesses[0])) {
        if (GST_EVENT_TYPE(e) == GST_EVENT_EOS) got_eos = true;
        gst_event_unref(e);
      }
      while (GstMessage* m = gst_bus_pop(bus)) {
        const GstStructure* st = gst_message_get_structure(m);
        if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ELEMENT && st && gst_structure_has_name(st, "stitchsync-time-offsets"))
          offsets.push_back(gst_structure_copy(st));
        if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_WARNING) {
          GError* e = nullptr;
          gst_message_parse_warning(m, &e, nullptr);
          warnings.push_back(e->message);
          g_error_free(e);
        }
        gst_message_unref(m);
      }
      if (!got_eos) g_usleep(1000);
    }
    while (GstBuffer* b = gst_harness_try_pull(harnesses[0])) outputs.push_back(b);
    gst_element_set_state(element, GST_STATE_NULL);
    for (auto& t : pushers) t.join();
  }
};

// Camera 1 started 7 frames after camera 0: time-alignment=auto finds +7 frames, says so on the
// bus with its confidence and rate, and the bundles then pair the same instants.
TEST_F(StitchSyncAlign, AutoFindsAndAppliesALateStart) {
  gst_util_set_object_arg(G_OBJECT(element), "time-alignment", "auto");
  play({0, 7}, 360, flash_frame);
  ASSERT_TRUE(got_eos);
  ASSERT_FALSE(offsets.empty()) << "no stitchsync-time-offsets message";
  const GstStructure* last = offsets.back();
  gint64 off0 = -1, off1 = 0;
  gdouble conf1 = 0, rate1 = 0;
  ASSERT_TRUE(gst_structure_get_int64(last, "offset-0", &off0));
  ASSERT_TRUE(gst_structure_get_int64(last, "offset-1", &off1));
  ASSERT_TRUE(gst_structure_get_double(last, "confidence-1", &conf1));
  ASSERT_TRUE(gst_structure_get_double(last, "rate-1", &rate1));
  EXPECT_EQ(off0, 0);
  EXPECT_NEAR(double(off1) / 1e9 * 30, 7.0, 0.5);
  EXPECT_GT(conf1, 0.5);
  EXPECT_NEAR(rate1, 1.0, 1e-3);
  // applied: in the last seconds both views show the same scene frame (the same brightness)
  ASSERT_GT(outputs.size(), 300u);
  int same = 0, compared = 0;
  for (std::size_t k = outputs.size() - 90; k < outputs.size() - 10; ++k) {
    const View a = read_view(outputs[k], 0), b = read_view(outputs[k], 1);
    ++compared;
    same += a.first[0] == b.first[0] ? 1 : 0;
  }
  EXPECT_GE(same, compared - 2) << "the views still show different instants";
}

// A static scene: nothing to align on. Confidence says so, the offset stays 0, and a warning
// names the pad.
std::vector<guint8> still_frame(int) {
  std::vector<guint8> px(gsize(kWidth) * kHeight * 4, 90);
  return px;
}

TEST_F(StitchSyncAlign, StaticSceneKeepsZeroWithAWarning) {
  gst_util_set_object_arg(G_OBJECT(element), "time-alignment", "auto");
  play({0, 5}, 660, still_frame);
  ASSERT_TRUE(got_eos);
  ASSERT_FALSE(offsets.empty());
  gint64 off1 = -1;
  gdouble conf1 = 1;
  gst_structure_get_int64(offsets.back(), "offset-1", &off1);
  gst_structure_get_double(offsets.back(), "confidence-1", &conf1);
  EXPECT_EQ(off1, 0);
  EXPECT_LT(conf1, 0.3);
  bool warned = false;
  for (const auto& w : warnings) warned = warned || (w.find("sink_1") != std::string::npos && w.find("no motion") != std::string::npos);
  EXPECT_TRUE(warned) << (warnings.empty() ? "no warning" : warnings[0]);
}

// time-alignment=none (the default) with a calibration file whose camera 1 carries
// time_offset_ns: the offset is applied (camera 1 two frames later), and an offset set by hand
// on a pad adds to it.
TEST_F(StitchSyncTest, LoadFileTimeOffsetAndPadOffset) {
  GValue v = G_VALUE_INIT;
  g_value_init(&v, G_TYPE_STRING);
  GParamSpec* ps = g_object_class_find_property(G_OBJECT_GET_CLASS(element), "time-alignment");
  ASSERT_NE(ps, nullptr);
  gint mode = -1;
  g_object_get(element, "time-alignment", &mode, NULL);
  EXPECT_STREQ(g_enum_get_value(G_PARAM_SPEC_ENUM(ps)->enum_class, mode)->value_nick, "none");
  g_value_unset(&v);
  const std::string path = std::string(g_get_tmp_dir()) + "/stitchsync_offsets.json";
  {
    FILE* f = std::fopen(path.c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs("{\"format\": \"stitch-rig\", \"version\": 1, \"cameras\": ["
               "{\"width\": 64, \"height\": 48, \"fx\": 60},"
               "{\"width\": 64, \"height\": 48, \"fx\": 60, \"time_offset_ns\": 66666667},"
               "{\"width\": 64, \"height\": 48, \"fx\": 60}]}", f);
    std::fclose(f);
  }
  g_object_set(element, "load-file", path.c_str(), NULL);
  attach(3);
  // camera 2: one frame by hand (GstPad offset on its sink pad)
  GstPad* p2 = gst_element_get_static_pad(element, "sink_2");
  gst_pad_set_offset(p2, 33333334);
  gst_object_unref(p2);
  std::vector<Input> in(3);
  for (auto& i : in) i = rgba_input(rgba_caps(30), frames_at(30, 20));
  run(in);
  ASSERT_TRUE(got_eos);
  ASSERT_GE(outputs.size(), 10u);
  for (std::size_t k = 4; k < 10; ++k) {
    EXPECT_EQ(decode_frame(read_view(outputs[k], 0), 0), int(k)) << k;
    EXPECT_EQ(decode_frame(read_view(outputs[k], 1), 1), int(k) - 2) << k;
    EXPECT_EQ(decode_frame(read_view(outputs[k], 2), 2), int(k) - 1) << k;
  }
}

// An application's camera, as it first writes it: a bytes segment (appsrc's default format) or
// frames without timestamps. Each gives an error that names the input (GstVideoAggregator
// aborted the process on the bytes segment, and stopped with a bare flow error on the frames).
class StitchSyncBadTiming : public StitchSyncTest {
 protected:
  // Pushes `frames` frames into both inputs from their own threads; input 1's go through
  // `change` first. Returns the first error's message.
  std::string push_and_error(const std::function<void(GstBuffer*)>& change, int frames = 3) {
    const Input in = rgba_input(rgba_caps(30), frames_at(30, frames));
    std::vector<std::thread> pushers;
    for (int i = 0; i < 2; ++i)
      pushers.emplace_back([this, &in, &change, i]() {
        for (const Frame& f : in.frames) {
          GstBuffer* b = make_buffer(in, i, f);
          if (i == 1) change(b);
          if (gst_harness_push(harnesses[std::size_t(i)], b) != GST_FLOW_OK) break;
        }
      });
    const auto [message, debug] = pop_error(5.0);
    gst_element_set_state(element, GST_STATE_NULL);  // unblocks the pushers
    for (auto& t : pushers) t.join();
    return message + " | " + debug;
  }
};

TEST_F(StitchSyncBadTiming, ABytesSegmentIsAnErrorNamingTheInput) {
  attach(2);
  for (GstHarness* h : harnesses) gst_harness_set_src_caps_str(h, rgba_caps(30).c_str());
  GstSegment bytes;
  gst_segment_init(&bytes, GST_FORMAT_BYTES);
  gst_pad_push_event(harnesses[1]->srcpad, gst_event_new_segment(&bytes));
  const std::string error = push_and_error([](GstBuffer*) {});
  EXPECT_NE(error.find("sink_1"), std::string::npos) << error;
  EXPECT_NE(error.find("bytes segment"), std::string::npos) << error;
  EXPECT_NE(error.find("format=time"), std::string::npos) << error;
}

TEST_F(StitchSyncBadTiming, FramesWithoutTimestampsAreAnErrorNamingTheInput) {
  attach(2);
  for (GstHarness* h : harnesses) gst_harness_set_src_caps_str(h, rgba_caps(30).c_str());
  const std::string error = push_and_error([](GstBuffer* b) {
    GST_BUFFER_PTS(b) = GST_CLOCK_TIME_NONE;
    GST_BUFFER_DURATION(b) = GST_CLOCK_TIME_NONE;
  });
  EXPECT_NE(error.find("sink_1"), std::string::npos) << error;
  EXPECT_NE(error.find("without a timestamp"), std::string::npos) << error;
}

// The same when the timestamps stop mid-stream (after bundles were made).
TEST_F(StitchSyncBadTiming, FramesLosingTheirTimestampsMidStreamAreAnErrorNamingTheInput) {
  attach(2);
  for (GstHarness* h : harnesses) gst_harness_set_src_caps_str(h, rgba_caps(30).c_str());
  int seen = 0;
  const std::string error = push_and_error(
      [&seen](GstBuffer* b) {
        if (++seen > 5) GST_BUFFER_PTS(b) = GST_CLOCK_TIME_NONE;
      },
      10);
  EXPECT_NE(error.find("sink_1"), std::string::npos) << error;
  EXPECT_NE(error.find("without a timestamp"), std::string::npos) << error;
}

// Non-live cameras whose timestamps all start at 100 s (an application's capture clock): the
// output starts at their first frame. It started at zero: 100 s of bundles without any frame,
// every camera "dropped out", and stitchcalib's calibration-timeout spent on them in a moment.
TEST_F(StitchSyncTest, NonLiveInputsStartingLateStartTheOutputAtTheirFirstFrame) {
  attach(2);
  for (GstHarness* h : harnesses) gst_harness_set_live(h, FALSE);  // (a harness says live by default)
  std::vector<Input> in(2);
  in[0] = rgba_input(rgba_caps(30), frames_at(30, 10, 100 * GST_SECOND));
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 10, 100 * GST_SECOND + 5 * GST_MSECOND));
  run(in);
  EXPECT_TRUE(got_eos);
  ASSERT_EQ(outputs.size(), 11u);  // input 1 ends 5 ms after input 0: one more output covers it
  EXPECT_EQ(GST_BUFFER_PTS(outputs[0]), 100 * GST_SECOND);
  const GstStitchBundleMeta* bm = bundle_meta(outputs[1]);
  ASSERT_NE(bm, nullptr);
  EXPECT_EQ(bm->missing_mask, 0u);
  EXPECT_EQ(decode_frame(read_view(outputs[1], 0), 0), 1);
  const int other = decode_frame(read_view(outputs[1], 1), 1);  // its frame 0 or 1 (5 ms later)
  EXPECT_TRUE(other == 0 || other == 1) << other;
}

// One non-live camera stamped by another clock (its frames start 100 s after the other's): a
// warning names it and says how to shift it (before, only "no frame since the start").
TEST_F(StitchSyncTest, AnInputStartingFarAfterTheOthersIsNamedInAWarning) {
  attach(2);
  for (GstHarness* h : harnesses) gst_harness_set_live(h, FALSE);
  std::vector<Input> in(2);
  in[0] = rgba_input(rgba_caps(30), frames_at(30, 3));
  in[1] = rgba_input(rgba_caps(30), frames_at(30, 3, 100 * GST_SECOND));
  run(in, {}, 2.0);
  std::string warnings;
  while (GstMessage* m = gst_bus_pop_filtered(bus, GST_MESSAGE_WARNING)) {
    GError* err = nullptr;
    gst_message_parse_warning(m, &err, nullptr);
    warnings += std::string(err ? err->message : "") + "\n";
    g_clear_error(&err);
    gst_message_unref(m);
  }
  EXPECT_NE(warnings.find("Input sink_1's first frame is at running time 100.000 s"), std::string::npos) << warnings;
  EXPECT_NE(warnings.find("another clock"), std::string::npos) << warnings;
}

// A player asks whether it may seek: seekable when every input is (GstAggregator says "no" for
// any aggregator, and players grey out their seek bar although seeks work), not when one is not.
bool pipeline_seekable(const std::string& description) {
  GstElement* pipe = gst_parse_launch(description.c_str(), nullptr);
  if (!pipe) return false;
  gst_element_set_state(pipe, GST_STATE_PAUSED);
  gst_element_get_state(pipe, nullptr, nullptr, 5 * GST_SECOND);
  GstQuery* q = gst_query_new_seeking(GST_FORMAT_TIME);
  gboolean seekable = FALSE;
  if (gst_element_query(pipe, q)) gst_query_parse_seeking(q, nullptr, &seekable, nullptr, nullptr);
  gst_query_unref(q);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(pipe);
  return seekable;
}

TEST(StitchSyncQueries, SeekableWhenEveryInputIs) {
  const std::string caps = " ! video/x-raw,width=64,height=48 ! ";
  EXPECT_TRUE(pipeline_seekable("stitchsync name=s ! fakesink videotestsrc num-buffers=30" + caps +
                                "s.sink_0 videotestsrc num-buffers=30 pattern=ball" + caps + "s.sink_1"));
  EXPECT_FALSE(pipeline_seekable("stitchsync name=s ! fakesink videotestsrc num-buffers=30" + caps +
                                 "s.sink_0 appsrc caps=video/x-raw,format=RGBA,width=64,height=48,framerate=30/1 "
                                 "format=time ! s.sink_1"));
}

}  // namespace
