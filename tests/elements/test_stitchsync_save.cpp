// Issue 18, item 1: the time offsets stitchsync applies (a pad's own offset, load-file's
// time_offset_ns, time-alignment's estimates) travel in the bundle meta, and stitchcalib's
// save-file writes them as the cameras' "time_offset_ns"; the saved file, loaded by stitchsync,
// applies the same offsets. Files without offsets stay as they were.
#include <gtest/gtest.h>

#include <fstream>
#include <functional>
#include <mutex>
#include <opencv2/core.hpp>
#include <sstream>

// Only the struct layout and the STITCH_* constants are used from here; the functions live
// in the plugin, which the test does not link.
#include "../../gst/gststitchbundle.h"
#include "gst_helpers.hpp"
#include "stitch/rig/rig.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

constexpr gint64 kFileOffset = 66666667;  // camera 1: two frames at 30 fps, from the load-file
constexpr gint64 kPadOffset = 33333334;   // camera 2: one frame, set by hand on its pad

// Three 640x480 crops of one photo, 400 px apart; the top-left 8x8 block of every view carries
// the frame number (R = 20 + 7 f), so that the bundle says which frame each view holds.
std::vector<cv::Mat> coded_crops(int f) {
  static const cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  std::vector<cv::Mat> v;
  for (int i = 0; i < 3; ++i) {
    cv::Mat c = photo(cv::Rect(400 * i, 200, 640, 480)).clone();
    c(cv::Rect(0, 0, 8, 8)).setTo(cv::Scalar(20 + 7 * f, 0, 0, 255));
    v.push_back(c);
  }
  return v;
}

std::string read_text(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

const GstStitchBundleMeta* bundle_meta(GstBuffer* buf) {
  gpointer state = nullptr;
  while (GstMeta* m = gst_buffer_iterate_meta(buf, &state))
    if (g_strcmp0(g_type_name(m->info->api), "GstStitchBundleMetaAPI") == 0)
      return reinterpret_cast<const GstStitchBundleMeta*>(m);
  return nullptr;
}

// What a probe on stitchsync's src pad saw: per bundle, the frame number of each view (-1:
// missing) and the meta's offsets.
struct Seen {
  std::mutex lock;
  std::vector<std::vector<int>> frames;
  std::vector<std::vector<gint64>> offsets;
  std::vector<bool> present;
};

GstPadProbeReturn on_bundle(GstPad*, GstPadProbeInfo* info, gpointer data) {
  auto* seen = static_cast<Seen*>(data);
  GstBuffer* buf = GST_PAD_PROBE_INFO_BUFFER(info);
  const GstStitchBundleMeta* bm = bundle_meta(buf);
  if (!bm) return GST_PAD_PROBE_OK;
  std::vector<int> frames;
  for (guint v = 0; v < bm->n_views; ++v) {
    GstVideoMeta* vm = gst_buffer_get_video_meta_id(buf, gint(v));
    GstMapInfo map;
    gpointer px = nullptr;
    gint stride = 0;
    if ((bm->missing_mask >> v & 1) || !vm || !gst_video_meta_map(vm, 0, &map, &px, &stride, GST_MAP_READ)) {
      frames.push_back(-1);
      continue;
    }
    frames.push_back((static_cast<const guint8*>(px)[0] - 20) / 7);
    gst_video_meta_unmap(vm, 0, &map);
  }
  std::lock_guard<std::mutex> g(seen->lock);
  seen->frames.push_back(frames);
  seen->offsets.emplace_back(bm->time_offsets_ns, bm->time_offsets_ns + bm->n_views);
  seen->present.push_back(bm->has_time_offsets);
  return GST_PAD_PROBE_OK;
}

std::string inputs() { return gsttest::appsrc_inputs(3); }

// run_pipeline_frames' per-frame hook: on the first frame, records stitchsync's (named s) bundles in `seen`.
std::function<void(GstElement*, int)> record_bundles(Seen& seen) {
  return [&seen](GstElement* pipe, int f) {
    if (f != 0) return;
    GstElement* s = gst_bin_get_by_name(GST_BIN(pipe), "s");
    GstPad* src = gst_element_get_static_pad(s, "src");
    gst_pad_add_probe(src, GST_PAD_PROBE_TYPE_BUFFER, on_bundle, &seen, nullptr);
    gst_object_unref(src);
    gst_object_unref(s);
  };
}

}  // namespace

// A load-file's time_offset_ns (camera 1) and a pad offset set by hand (camera 2) reach the
// file stitchcalib saves; camera 0, with no offset, gets no field. stitchcalib's own load-file
// has no offsets: they can only come from stitchsync's bundles.
class SyncSave : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = testdata::temp_dir();
    exact_ = dir_ + "/exact3.json";
    rig_save(testdata::shifted_rig(3, 640, 480, 400), exact_);
    Rig with = testdata::shifted_rig(3, 640, 480, 400);
    with.cameras[1].time_offset_ns = kFileOffset;
    offsets_ = dir_ + "/offsets3.json";
    rig_save(with, offsets_);
  }
  static std::string dir_, exact_, offsets_;
};
std::string SyncSave::dir_, SyncSave::exact_, SyncSave::offsets_;

TEST_F(SyncSave, LoadFileAndPadOffsetsAreSavedAndLoadedBack) {
  const std::string saved = dir_ + "/saved3.json";
  gsttest::RunResult r;
  gsttest::run_pipeline_frames(
      "stitchsync name=s load-file=" + offsets_ + " ! stitchcalib load-file=" + exact_ + " save-file=" + saved +
          " ! fakesink sync=false" + inputs(),
      coded_crops, 12, r, nullptr, [](GstElement* pipe, int f) {
        if (f != 0) return;
        GstElement* s = gst_bin_get_by_name(GST_BIN(pipe), "s");
        GstPad* p = gst_element_get_static_pad(s, "sink_2");
        gst_pad_set_offset(p, kPadOffset);
        gst_object_unref(p);
        gst_object_unref(s);
      });
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_TRUE(r.eos);
  const Rig out = rig_load(saved);
  ASSERT_EQ(out.cameras.size(), 3u);
  EXPECT_FALSE(out.cameras[0].time_offset_ns.has_value());
  ASSERT_TRUE(out.cameras[1].time_offset_ns.has_value());
  EXPECT_EQ(*out.cameras[1].time_offset_ns, kFileOffset);
  ASSERT_TRUE(out.cameras[2].time_offset_ns.has_value());
  EXPECT_EQ(*out.cameras[2].time_offset_ns, kPadOffset);
  // the geometry is the loaded one
  EXPECT_EQ(out.canvas_width, rig_load(exact_).canvas_width);
  EXPECT_TRUE(out.calibrated());

  // Round trip: the saved file given to stitchsync (no pad offset now) applies the same
  // offsets: camera 1 shows the frame two before camera 0's, camera 2 the one before; the
  // bundles carry them, and stitchcalib saves them again unchanged.
  Seen seen;
  const std::string again = dir_ + "/saved3_again.json";
  gsttest::RunResult r2;
  gsttest::run_pipeline_frames(
      "stitchsync name=s load-file=" + saved + " ! stitchcalib load-file=" + saved + " save-file=" + again +
          " ! fakesink sync=false" + inputs(),
      coded_crops, 12, r2, nullptr, record_bundles(seen));
  ASSERT_TRUE(r2.errors.empty()) << r2.errors[0];
  ASSERT_TRUE(r2.eos);
  std::lock_guard<std::mutex> g(seen.lock);
  ASSERT_GE(seen.frames.size(), 8u);
  int checked = 0;
  for (std::size_t k = 0; k < seen.frames.size(); ++k) {
    ASSERT_EQ(seen.offsets[k].size(), 3u);
    EXPECT_TRUE(seen.present[k]) << k;
    EXPECT_EQ(seen.offsets[k][0], 0) << k;
    EXPECT_EQ(seen.offsets[k][1], kFileOffset) << k;
    EXPECT_EQ(seen.offsets[k][2], kPadOffset) << k;
    const auto& fr = seen.frames[k];
    if (fr[0] < 3 || fr[0] > 9 || fr[1] < 0 || fr[2] < 0) continue;
    EXPECT_EQ(fr[1], fr[0] - 2) << "bundle " << k;
    EXPECT_EQ(fr[2], fr[0] - 1) << "bundle " << k;
    ++checked;
  }
  EXPECT_GE(checked, 5);
  const Rig back = rig_load(again);
  EXPECT_FALSE(back.cameras[0].time_offset_ns.has_value());
  EXPECT_EQ(back.cameras[1].time_offset_ns.value_or(0), kFileOffset);
  EXPECT_EQ(back.cameras[2].time_offset_ns.value_or(0), kPadOffset);
}

// No offset anywhere: the bundles say so, and the saved file has no time_offset_ns.
TEST_F(SyncSave, WithoutOffsetsTheFileIsUnchanged) {
  const std::string saved = dir_ + "/plain3.json";
  Seen seen;
  gsttest::RunResult r;
  gsttest::run_pipeline_frames(
      "stitchsync name=s ! stitchcalib load-file=" + exact_ + " save-file=" + saved + " ! fakesink sync=false" +
          inputs(),
      coded_crops, 6, r, nullptr, record_bundles(seen));
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_TRUE(r.eos);
  {
    std::lock_guard<std::mutex> g(seen.lock);
    ASSERT_FALSE(seen.present.empty());
    for (std::size_t k = 0; k < seen.present.size(); ++k) EXPECT_FALSE(seen.present[k]) << k;
  }
  const std::string text = read_text(saved);
  EXPECT_EQ(text.find("time_offset_ns"), std::string::npos) << text;
  EXPECT_TRUE(rig_load(saved).calibrated());
}

// time-alignment=auto: camera 1 started 7 frames after camera 0 (its frame f shows the scene's
// f + 7, the scene flashing at random). The estimate stitchsync applies reaches the saved file.
namespace {
cv::Mat flash_view(const cv::Mat& base, int scene_frame) {
  static const std::vector<guint32> scene = []() {
    std::vector<guint32> v(4000);
    guint32 x = 42;
    for (auto& s : v) s = x = x * 1664525u + 1013904223u;
    return v;
  }();
  const guint32 h = scene[std::size_t(scene_frame) % scene.size()] >> 8;
  const double gain = h % 9 == 0 ? 1.6 : 0.6 + 0.02 * double((h >> 8) % 8);
  cv::Mat out;
  base.convertTo(out, -1, gain);
  out.forEach<cv::Vec4b>([](cv::Vec4b& p, const int*) { p[3] = 255; });
  return out;
}
}  // namespace

TEST_F(SyncSave, AutoAlignmentEstimateIsSaved) {
  static const cv::Mat photo = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  static const std::vector<cv::Mat> base = {photo(cv::Rect(400, 300, 320, 240)).clone(),
                                            photo(cv::Rect(600, 300, 320, 240)).clone()};
  const std::string exact = dir_ + "/exact2.json", saved = dir_ + "/auto2.json";
  rig_save(testdata::shifted_rig(2, 320, 240, 200), exact);
  gsttest::RunResult r;
  gsttest::run_pipeline_frames(
      "stitchsync name=s time-alignment=auto ! stitchcalib load-file=" + exact + " save-file=" + saved +
          " ! fakesink sync=false" + gsttest::appsrc_inputs(2),
      [](int f) { return std::vector<cv::Mat>{flash_view(base[0], f), flash_view(base[1], f + 7)}; }, 360, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_TRUE(r.eos);
  gint64 announced = 0;
  for (auto* s : r.element_messages)
    if (gst_structure_has_name(s, "stitchsync-time-offsets")) gst_structure_get_int64(s, "offset-1", &announced);
  ASSERT_NE(announced, 0) << "time-alignment found no offset";
  const Rig out = rig_load(saved);
  ASSERT_EQ(out.cameras.size(), 2u);
  EXPECT_EQ(out.cameras[0].time_offset_ns.value_or(0), 0);
  ASSERT_TRUE(out.cameras[1].time_offset_ns.has_value());
  EXPECT_NEAR(double(*out.cameras[1].time_offset_ns) / 1e9 * 30, 7.0, 0.5);
}
