// stitchblend: output caps follow the calibration, the panorama reproduces the scene, and a
// bundle without calibration is a clear error.
#include <gtest/gtest.h>

#include <sys/resource.h>

#include <chrono>
#include <cstdlib>
#include <opencv2/imgproc.hpp>

#include "gst_helpers.hpp"
#include "stitch/rig/rig.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

using Scene = testdata::BoatCrops;

// Two crops 400 px apart and their exact calibration.
Scene scene() { return testdata::boat_crops("blend_exact.json"); }

// The calibrated chain: stitchsync ! stitchcalib (the exact calibration) ! `stages` ! appsink.
std::string chain(const Scene& s, const std::string& stages, const std::string& sync = "stitchsync name=s") {
  return sync + " ! stitchcalib name=calib load-file=" + s.calib + " ! " + stages + " ! appsink name=out sync=false" +
         gsttest::appsrc_inputs(2);
}

// The panorama fitted into a taller frame (letterboxed): black bars above and below, the scene
// resampled to `scene_rows` rows in between, centred.
void expect_letterboxed(const Scene& s, const cv::Mat& pano, int scene_rows) {
  cv::Mat gray;
  cv::cvtColor(pano, gray, cv::COLOR_RGBA2GRAY);
  EXPECT_EQ(cv::countNonZero(gray.row(3)), 0);
  EXPECT_EQ(cv::countNonZero(gray.row(pano.rows - 4)), 0);
  EXPECT_GT(cv::countNonZero(gray.row(pano.rows / 2)), 600) << "the scene is missing";
  cv::Mat expected;
  cv::resize(s.photo(cv::Rect(0, 200, 1040, 480)), expected, cv::Size(pano.cols, scene_rows), 0, 0, cv::INTER_AREA);
  const int top = (pano.rows - scene_rows) / 2;
  EXPECT_GT(testdata::psnr_rgb(pano(cv::Rect(0, top + 4, pano.cols, 280)), expected(cv::Rect(0, 4, pano.cols, 280))),
            22.0);
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

// Issue 18: output-height=32766 asks for a panorama ~66 000 px wide (beyond caps' 32767): it used
// to allocate its maps until the OOM killer came (24 GB). Now it is refused before anything is
// allocated, with the size and the limit named. Run in a child process with 6 GiB of address
// space: 0 when the refusal came, fast, with the process still small.
static int refuse_oversized_output() {
  rlimit limit{};
  limit.rlim_cur = limit.rlim_max = rlim_t(6) << 30;
  setrlimit(RLIMIT_AS, &limit);
  Scene s = scene();
  gsttest::RunResult r;
  const auto t0 = std::chrono::steady_clock::now();
  gsttest::run_pipeline(chain(s, "stitchblend backend=cpu output-height=32766", "stitchsync name=s backend=cpu"),
                        s.views, 2, r);
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  rusage use{};
  getrusage(RUSAGE_SELF, &use);
  const bool ok = r.error_contains("beyond the 32767-pixel limit") && r.error_contains("output-height=") &&
                  r.frames.empty() && seconds < 20 && use.ru_maxrss < 2 * 1024 * 1024;  // KiB
  fprintf(stderr, "%s; %.1f s, peak %ld KiB\n", r.errors.empty() ? "no error" : r.errors[0].c_str(), seconds,
          long(use.ru_maxrss));
  return ok ? 0 : 1;
}

TEST(StitchBlendDeathTest, OversizedOutputIsRefusedUpFront) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  EXPECT_EXIT(std::exit(refuse_oversized_output()), ::testing::ExitedWithCode(0), "");
}

// A panorama within caps but beyond memory-limit is refused too, naming the budget.
TEST(StitchBlend, BeyondTheMemoryLimitIsRefused) {
  Scene s = scene();
  gsttest::RunResult r;
  gsttest::run_pipeline(chain(s, "stitchblend memory-limit=8"),
                        s.views, 2, r);
  EXPECT_TRUE(r.error_contains("beyond the budget of 8 MiB")) << (r.errors.empty() ? "no error" : r.errors[0]);
  EXPECT_TRUE(r.frames.empty());
}

// `stitchblend ! video/x-raw,width=640,height=360`: the panorama (1040x480) is fitted inside,
// centred, at its own aspect (640x296 between black bars), as output-width + output-height do.
TEST(StitchBlend, DownstreamFixedSizeGetsThePanoramaFitted) {
  Scene s = scene();
  gsttest::RunResult r;
  gsttest::run_pipeline(chain(s, "stitchblend ! video/x-raw,width=640,height=360"),
                        s.views, 2, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.frames.size(), 2u);
  const cv::Mat& pano = r.frames[0];
  ASSERT_EQ(pano.cols, 640);
  ASSERT_EQ(pano.rows, 360);
  expect_letterboxed(s, pano, 295);
  // the same as asking for the size
  gsttest::RunResult asked;
  gsttest::run_pipeline(chain(s, "stitchblend output-width=640 output-height=360"),
                        s.views, 1, asked);
  ASSERT_EQ(asked.frames.size(), 1u);
  EXPECT_EQ(cv::norm(asked.frames[0], pano, cv::NORM_INF), 0.0);
}

// `stitchblend ! videoscale ! video/x-raw,width=640,height=360` (probe2: a new user scaling the
// panorama down): videoscale prefers the size it is asked for but takes any. stitchblend fitted
// the canvas to it (640x296) and then, renegotiating, let videoscale's preferred 640x360 replace
// the panorama's caps: a GStreamer-CRITICAL (info->height <= meta->height) and "Cannot map the
// output frame", no panorama at all. The panorama goes out whole and videoscale scales it.
TEST(StitchBlend, VideoscaleAfterTheBlendGetsThePanorama) {
  Scene s = scene();
  gsttest::RunResult r;
  gsttest::run_pipeline(chain(s, "stitchblend ! videoscale ! video/x-raw,width=640,height=360"), s.views, 3, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.frames.size(), 3u);
  const cv::Mat& pano = r.frames[2];
  ASSERT_EQ(pano.cols, 640);
  ASSERT_EQ(pano.rows, 360);
  cv::Mat expected;
  cv::resize(s.photo(cv::Rect(0, 200, 1040, 480)), expected, cv::Size(640, 360), 0, 0, cv::INTER_AREA);
  cv::Mat gray;
  cv::cvtColor(pano, gray, cv::COLOR_RGBA2GRAY);
  EXPECT_GT(cv::countNonZero(gray.row(180)), 600) << "the scene is missing";
  EXPECT_GT(testdata::psnr_rgb(pano(cv::Rect(8, 8, 624, 344)), expected(cv::Rect(8, 8, 624, 344))), 20.0);
  // A tee whose second branch scales and decimates (videorate ! 10/1 ! videoscale ! 640x360)
  // lists those as its preferences too: the first branch used to get a 640x296 panorama at
  // 10 fps. It gets the whole panorama at the cameras' rate.
  gsttest::RunResult t;
  gsttest::run_pipeline("stitchsync name=s ! stitchcalib load-file=" + s.calib +
                            " ! stitchblend ! tee name=t ! queue ! appsink name=out sync=false t. ! queue ! videorate ! "
                            "video/x-raw,framerate=10/1 ! videoscale ! video/x-raw,width=640,height=360 ! fakesink" +
                            gsttest::appsrc_inputs(2),
                        s.views, 6, t);
  ASSERT_TRUE(t.errors.empty()) << t.errors[0];
  ASSERT_EQ(t.frames.size(), 6u) << "not the cameras' 30 fps";
  EXPECT_EQ(t.frames[5].cols, 1040);
  EXPECT_EQ(t.frames[5].rows, 480);
}

// probe6: a size downstream fixes is made as it is, odd or not (RGBA has no 4:2:0 constraint).
// `stitchblend ! video/x-raw,width=641,height=361` was an error ("panoramas have even sizes"),
// and so was `video/x-raw,width=1001` alone (the height that keeps the aspect is odd).
TEST(StitchBlend, DownstreamOddSizeIsMadeExactly) {
  Scene s = scene();
  gsttest::RunResult r;
  gsttest::run_pipeline(chain(s, "stitchblend ! video/x-raw,width=641,height=361"), s.views, 2, r);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.frames.size(), 2u);
  const cv::Mat& pano = r.frames[1];
  ASSERT_EQ(pano.cols, 641);
  ASSERT_EQ(pano.rows, 361);
  expect_letterboxed(s, pano, 296);  // like the even size, at the panorama's aspect

  gsttest::RunResult w;
  gsttest::run_pipeline(chain(s, "stitchblend ! video/x-raw,width=1001"), s.views, 2, w);
  ASSERT_TRUE(w.errors.empty()) << w.errors[0];
  ASSERT_EQ(w.frames.size(), 2u);
  EXPECT_EQ(w.frames[1].cols, 1001);
  EXPECT_EQ(w.frames[1].rows, 462);  // 480 * 1001 / 1040, nearest
}

// probe6: a downstream that takes no square pixels (`video/x-raw,pixel-aspect-ratio=4/3`) failed
// as "Internal data stream error ... not-negotiated" from the sources, naming no element of
// ours. stitchblend says what is wrong and what to do.
TEST(StitchBlend, NonSquarePixelsDownstreamIsAClearError) {
  Scene s = scene();
  gsttest::RunResult r;
  gsttest::run_pipeline(chain(s, "stitchblend ! video/x-raw,pixel-aspect-ratio=4/3"), s.views, 2, r);
  EXPECT_TRUE(r.frames.empty());
  EXPECT_TRUE(r.error_contains("Downstream takes no square pixels")) << (r.errors.empty() ? "no error" : r.errors[0]);
  // a pixel aspect ratio downstream merely allows besides square ones is no error
  gsttest::RunResult any;
  gsttest::run_pipeline(chain(s, "stitchblend ! video/x-raw,pixel-aspect-ratio=[1/2,2/1]"), s.views, 2, any);
  ASSERT_TRUE(any.errors.empty()) << any.errors[0];
  EXPECT_EQ(any.frames.size(), 2u);
}

namespace {

// An application's meta with no tags: it describes the frame as a whole, so it must survive.
struct AppMeta {
  GstMeta meta;
  gint value;
};

GType app_meta_api_get_type() {
  static GType type = 0;
  static const gchar* tags[] = {NULL};
  if (g_once_init_enter(&type)) g_once_init_leave(&type, gst_meta_api_type_register("TestAppMetaAPI", tags));
  return type;
}

const GstMetaInfo* app_meta_info();

gboolean app_meta_transform(GstBuffer* dest, GstMeta* meta, GstBuffer*, GQuark type, gpointer) {
  if (!GST_META_TRANSFORM_IS_COPY(type)) return FALSE;
  auto* m = reinterpret_cast<AppMeta*>(gst_buffer_add_meta(dest, app_meta_info(), NULL));
  m->value = reinterpret_cast<AppMeta*>(meta)->value;
  return TRUE;
}

const GstMetaInfo* app_meta_info() {
  static const GstMetaInfo* info = NULL;
  if (g_once_init_enter(&info))
    g_once_init_leave(&info, gst_meta_register(app_meta_api_get_type(), "TestAppMeta", sizeof(AppMeta),
                                               [](GstMeta*, gpointer, GstBuffer*) -> gboolean { return TRUE; }, NULL,
                                               app_meta_transform));
  return info;
}

struct MetaCounts {
  int buffers = 0, with_reference = 0, with_app = 0, video_metas = 0;
};


// Adds both metas to every bundle leaving stitchcalib.
GstPadProbeReturn add_metas(GstPad*, GstPadProbeInfo* info, gpointer) {
  GstBuffer* b = gst_buffer_make_writable(GST_PAD_PROBE_INFO_BUFFER(info));
  GstCaps* ref = gst_caps_new_empty_simple("timestamp/x-test");
  gst_buffer_add_reference_timestamp_meta(b, ref, GST_BUFFER_PTS(b) + 42, GST_CLOCK_TIME_NONE);
  gst_caps_unref(ref);
  reinterpret_cast<AppMeta*>(gst_buffer_add_meta(b, app_meta_info(), NULL))->value = 7;
  GST_PAD_PROBE_INFO_DATA(info) = b;
  return GST_PAD_PROBE_OK;
}

GstPadProbeReturn count_metas(GstPad*, GstPadProbeInfo* info, gpointer data) {
  auto* c = static_cast<MetaCounts*>(data);
  GstBuffer* b = GST_PAD_PROBE_INFO_BUFFER(info);
  c->buffers++;
  GstReferenceTimestampMeta* ref = gst_buffer_get_reference_timestamp_meta(b, NULL);
  if (ref && ref->timestamp == GST_BUFFER_PTS(b) + 42) c->with_reference++;
  auto* app = reinterpret_cast<AppMeta*>(gst_buffer_get_meta(b, app_meta_api_get_type()));
  if (app && app->value == 7) c->with_app++;
  gpointer state = NULL;
  while (GstMeta* m = gst_buffer_iterate_meta_filtered(b, &state, GST_VIDEO_META_API_TYPE)) {
    const GstVideoMeta* vm = reinterpret_cast<GstVideoMeta*>(m);
    if (vm->width != 1040 || vm->height != 480) c->video_metas++;  // a view's, not the panorama's
  }
  return GST_PAD_PROBE_OK;
}

}  // namespace

MetaCounts meta_counts;  // of the run in progress

// Metas that describe the frame (reference timestamps, an application's) pass through
// stitchflowwarp and stitchblend; those describing the views (one GstVideoMeta per view) do not.
TEST(StitchBlend, FrameMetasPassThroughFlowWarpAndBlend) {
  Scene s = scene();
  for (const std::string middle : {"", "stitchcolor ! stitchflowwarp ! "}) {
    meta_counts = MetaCounts();
    gsttest::RunResult r;
    gsttest::run_pipeline(
        chain(s, middle + "stitchblend"),
        s.views, 3, r, nullptr, [](GstElement* pipe, int frame) {
          if (frame != 0) return;
          GstElement* calib = gst_bin_get_by_name(GST_BIN(pipe), "calib");
          GstElement* out = gst_bin_get_by_name(GST_BIN(pipe), "out");
          GstPad* src = gst_element_get_static_pad(calib, "src");
          GstPad* sink = gst_element_get_static_pad(out, "sink");
          gst_pad_add_probe(src, GST_PAD_PROBE_TYPE_BUFFER, add_metas, NULL, NULL);
          gst_pad_add_probe(sink, GST_PAD_PROBE_TYPE_BUFFER, count_metas, &meta_counts, NULL);
          for (GstObject* o : {GST_OBJECT(src), GST_OBJECT(sink), GST_OBJECT(calib), GST_OBJECT(out)})
            gst_object_unref(o);
        });
    ASSERT_TRUE(r.errors.empty()) << r.errors[0];
    ASSERT_EQ(r.frames.size(), 3u) << middle;
    EXPECT_EQ(meta_counts.buffers, 3) << middle;
    EXPECT_EQ(meta_counts.with_reference, 3) << middle;
    EXPECT_EQ(meta_counts.with_app, 3) << middle;
    EXPECT_EQ(meta_counts.video_metas, 0) << middle;
  }
}
