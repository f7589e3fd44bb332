// RTSP end to end: an in-process gst-rtsp-server on loopback serves three overlapping crops of
// a real clip (H.264 over RTP), and a live pipeline stitches them through rtspsrc with its
// latency set. The panorama must be the clip's strip (the crops are pure shifts of it), come
// at the clip's rate, and no camera may drop out.
#include <gst/app/app.h>
#include <gst/gst.h>
#include <gst/rtsp-server/rtsp-server.h>
#include <gst/video/video.h>
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>
#include <string>
#include <thread>
#include <vector>

#include "gst_helpers.hpp"
#include "test_data.hpp"

namespace {

constexpr int kCropW = 320, kCropH = 240, kShift = 200, kTop = 80;
constexpr int kPanoW = 2 * kShift + kCropW;

bool have(const char* factory) {
  GstElementFactory* f = gst_element_factory_find(factory);
  if (f) gst_object_unref(f);
  return f != nullptr;
}

std::string clip() { return testdata::repo_path("data/limlight_2cam_apartment/left.mp4"); }

// Serves /cam0../cam2: crops kShift apart of the clip, re-encoded, from a loopback port.
class Server {
 public:
  Server() {
    context_ = g_main_context_new();
    loop_ = g_main_loop_new(context_, FALSE);
    server_ = gst_rtsp_server_new();
    gst_rtsp_server_set_address(server_, "127.0.0.1");
    gst_rtsp_server_set_service(server_, "0");  // any free port
    GstRTSPMountPoints* mounts = gst_rtsp_server_get_mount_points(server_);
    for (int i = 0; i < 3; ++i) {
      const int left = kShift * i;
      const std::string launch =
          "( filesrc location=" + clip() + " ! qtdemux ! h264parse ! avdec_h264 ! videocrop left=" +
          std::to_string(left) + " right=" + std::to_string(720 - left - kCropW) + " top=" + std::to_string(kTop) +
          " bottom=" + std::to_string(404 - kTop - kCropH) +
          " ! videoconvert ! x264enc tune=zerolatency speed-preset=ultrafast key-int-max=10 bitrate=3000 "
          "! rtph264pay name=pay0 pt=96 config-interval=1 )";
      GstRTSPMediaFactory* factory = gst_rtsp_media_factory_new();
      gst_rtsp_media_factory_set_launch(factory, launch.c_str());
      gst_rtsp_media_factory_set_shared(factory, FALSE);
      gst_rtsp_mount_points_add_factory(mounts, ("/cam" + std::to_string(i)).c_str(), factory);
    }
    g_object_unref(mounts);
    source_ = gst_rtsp_server_attach(server_, context_);
    port_ = gst_rtsp_server_get_bound_port(server_);
    thread_ = std::thread([this]() { g_main_loop_run(loop_); });
  }
  ~Server() {
    g_main_loop_quit(loop_);
    thread_.join();
    if (GSource* s = g_main_context_find_source_by_id(context_, source_)) g_source_destroy(s);
    g_object_unref(server_);
    g_main_loop_unref(loop_);
    g_main_context_unref(context_);
  }
  int port() const { return port_; }
  std::string url(int i) const { return "rtsp://127.0.0.1:" + std::to_string(port_) + "/cam" + std::to_string(i); }

 private:
  GMainContext* context_;
  GMainLoop* loop_;
  GstRTSPServer* server_;
  guint source_ = 0;
  int port_ = 0;
  std::thread thread_;
};

// The clip's first `count` frames, cropped to the strip the panorama shows.
std::vector<cv::Mat> clip_strips(int count) {
  gsttest::RunResult r;
  std::vector<cv::Mat> out;
  GstElement* p = gst_parse_launch(("filesrc location=" + clip() +
                                    " ! qtdemux ! h264parse ! avdec_h264 ! videoconvert ! video/x-raw,format=RGBA ! "
                                    "appsink name=out sync=false")
                                       .c_str(),
                                   nullptr);
  GstElement* sink = gst_bin_get_by_name(GST_BIN(p), "out");
  gst_element_set_state(p, GST_STATE_PLAYING);
  while (int(out.size()) < count) {
    GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 5 * GST_SECOND);
    if (!s) break;
    GstVideoInfo info;
    gst_video_info_from_caps(&info, gst_sample_get_caps(s));
    GstVideoFrame vf;
    if (gst_video_frame_map(&vf, &info, gst_sample_get_buffer(s), GST_MAP_READ)) {
      cv::Mat m(info.height, info.width, CV_8UC4, GST_VIDEO_FRAME_PLANE_DATA(&vf, 0), GST_VIDEO_FRAME_PLANE_STRIDE(&vf, 0));
      out.push_back(m(cv::Rect(0, kTop, kPanoW, kCropH)).clone());
      gst_video_frame_unmap(&vf);
    }
    gst_sample_unref(s);
  }
  gst_element_set_state(p, GST_STATE_NULL);
  gst_object_unref(sink);
  gst_object_unref(p);
  return out;
}

}  // namespace

TEST(Rtsp, ThreeLiveCamerasStitchEndToEnd) {
  gsttest::init();
  for (const char* f : {"rtspsrc", "rtph264depay", "rtph264pay", "x264enc", "avdec_h264", "videocrop", "qtdemux"})
    if (!have(f)) GTEST_SKIP() << "GStreamer element " << f << " missing (scripts/setup.sh installs it)";
  Server server;
  ASSERT_GT(server.port(), 0) << "the RTSP server did not bind a loopback port";
  const std::string calib = testdata::temp_dir() + "/rtsp_exact.json";
  stitch::rig_save(testdata::shifted_rig(3, kCropW, kCropH, kShift), calib);

  std::string desc = "stitchsync name=s latency=300000000 ! stitchcalib load-file=" + calib +
                     " ! stitchblend ! appsink name=out sync=false max-buffers=8";
  for (int i = 0; i < 3; ++i)
    desc += " rtspsrc location=" + server.url(i) +
            " latency=200 protocols=tcp ! rtph264depay ! h264parse ! avdec_h264 ! s.sink_" + std::to_string(i);
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(desc.c_str(), &err);
  ASSERT_NE(pipe, nullptr) << (err ? err->message : "");
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  GstBus* bus = gst_element_get_bus(pipe);
  gst_element_set_state(pipe, GST_STATE_PLAYING);

  std::vector<cv::Mat> panoramas;
  std::vector<GstClockTime> pts;
  std::vector<std::string> errors, warnings;
  gboolean live = FALSE;
  const gint64 deadline = g_get_monotonic_time() + 30 * G_TIME_SPAN_SECOND;
  while (panoramas.size() < 45 && errors.empty() && g_get_monotonic_time() < deadline) {
    if (GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 20 * GST_MSECOND)) {
      GstVideoInfo info;
      gst_video_info_from_caps(&info, gst_sample_get_caps(s));
      GstVideoFrame vf;
      if (gst_video_frame_map(&vf, &info, gst_sample_get_buffer(s), GST_MAP_READ)) {
        panoramas.push_back(cv::Mat(info.height, info.width, CV_8UC4, GST_VIDEO_FRAME_PLANE_DATA(&vf, 0),
                                    GST_VIDEO_FRAME_PLANE_STRIDE(&vf, 0))
                                .clone());
        pts.push_back(GST_BUFFER_PTS(gst_sample_get_buffer(s)));
        gst_video_frame_unmap(&vf);
      }
      gst_sample_unref(s);
    }
    while (GstMessage* m = gst_bus_pop(bus)) {
      GError* e = nullptr;
      if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) {
        gst_message_parse_error(m, &e, nullptr);
        errors.push_back(e->message);
      } else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_WARNING) {
        gst_message_parse_warning(m, &e, nullptr);
        warnings.push_back(e->message);
      }
      if (e) g_error_free(e);
      gst_message_unref(m);
    }
  }
  // stitchsync aggregates in live mode (on its latency timeout) when its inputs are live
  GstElement* sync = gst_bin_get_by_name(GST_BIN(pipe), "s");
  GstQuery* latency = gst_query_new_latency();
  if (gst_element_query(sync, latency)) gst_query_parse_latency(latency, &live, nullptr, nullptr);
  gst_query_unref(latency);
  gst_object_unref(sync);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(bus);
  gst_object_unref(sink);
  gst_object_unref(pipe);

  ASSERT_TRUE(errors.empty()) << errors[0];
  ASSERT_EQ(panoramas.size(), 45u) << "too few panoramas within 30 s";
  EXPECT_TRUE(live) << "the pipeline did not run in live mode";
  for (const auto& w : warnings) EXPECT_EQ(w.find("dropped out"), std::string::npos) << w;
  // ~30 fps with steady timestamps
  const double fps = 44.0 * GST_SECOND / double(pts.back() - pts.front());
  EXPECT_NEAR(fps, 30.0, 2.0);
  // each panorama is one of the clip's strips (the clip plays in real time, so which one is
  // not known exactly): the best match must be close, limited by the H.264 round trip
  const std::vector<cv::Mat> strips = clip_strips(120);
  ASSERT_FALSE(strips.empty());
  for (std::size_t k : {std::size_t(10), std::size_t(44)}) {
    ASSERT_EQ(panoramas[k].size(), cv::Size(kPanoW, kCropH));
    double best = 0;
    for (const cv::Mat& s : strips) best = std::max(best, testdata::psnr_rgb(panoramas[k], s));
    EXPECT_GT(best, 28.0) << "panorama " << k << " is not the clip's strip";
  }
}
