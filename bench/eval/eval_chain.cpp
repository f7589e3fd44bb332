// stitch-eval-chain: runs our GStreamer chain on N clips for the evaluation suite and writes
// every panorama (PNG), the calibration and the timing.
//   appsrc x N ! stitchsync ! stitchcalib [rig-file=...] save-file=DIR/calib.json ! CHAIN !
//   stitchblend BLEND ! video/x-raw,format=RGBA ! appsink
// The clips are decoded before the pipeline starts (as in stitch-bench-pipeline), so the time
// per panorama is the chain's alone, comparable with stitch-eval-opencv's.
// usage: stitch-eval-chain --out DIR --clips A,B[,C...] [--frames 40] [--rig ROUGH.json]
//          [--chain "stitchcolor ! stitchflowwarp"] [--blend "mode=..."] [--backend cpu|cuda|auto]
//          [--calib SAVED.json]   (stitchcalib load-file: a known calibration, no estimation)
#include <gst/app/gstappsink.h>
#include <gst/app/gstappsrc.h>
#include <gst/gst.h>
#include <gst/video/video.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <sstream>
#include <string>
#include <vector>

namespace {

using Clock = std::chrono::steady_clock;

struct Options {
  std::string out, rig, calib, chain, blend, backend = "cpu";
  std::vector<std::string> clips;
  int frames = 40;
};

[[noreturn]] void die(int code, const std::string& msg) {
  std::fprintf(stderr, "stitch-eval-chain: %s\n", msg.c_str());
  std::exit(code);
}

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> parts;
  std::stringstream ss(s);
  for (std::string p; std::getline(ss, p, sep);)
    if (!p.empty()) parts.push_back(p);
  return parts;
}

Options parse_args(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    if (i + 1 >= argc) die(2, "option " + key + " needs a value");
    const std::string v = argv[++i];
    if (key == "--out") o.out = v;
    else if (key == "--clips") o.clips = split(v, ',');
    else if (key == "--frames") o.frames = std::atoi(v.c_str());
    else if (key == "--rig") o.rig = v;
    else if (key == "--calib") o.calib = v;
    else if (key == "--chain") o.chain = v;
    else if (key == "--blend") o.blend = v;
    else if (key == "--backend") o.backend = v;
    else die(2, "unknown option " + key);
  }
  if (o.out.empty() || o.clips.size() < 2) die(2, "--out and at least two --clips are required");
  if (o.frames < 2) die(2, "--frames must be at least 2");
  return o;
}

// Every clip's first `frames` frames as RGBA (fewer when a clip is shorter: all are cut to the
// shortest).
std::vector<std::vector<cv::Mat>> decode(const Options& o) {
  std::vector<std::vector<cv::Mat>> clips;
  std::size_t shortest = std::size_t(o.frames);
  for (const auto& path : o.clips) {
    cv::VideoCapture cap(path);
    if (!cap.isOpened()) die(1, "cannot open the clip \"" + path + "\"");
    std::vector<cv::Mat> frames;
    cv::Mat f;
    while (int(frames.size()) < o.frames && cap.read(f)) {
      cv::Mat rgba;
      cv::cvtColor(f, rgba, cv::COLOR_BGR2RGBA);
      frames.push_back(rgba);
    }
    if (frames.size() < 2) die(1, "the clip \"" + path + "\" has fewer than 2 frames");
    if (frames.front().size() != frames.back().size()) die(1, "the clip \"" + path + "\" changes size");
    shortest = std::min(shortest, frames.size());
    clips.push_back(std::move(frames));
  }
  for (auto& c : clips) c.resize(shortest);
  return clips;
}

GstBuffer* to_buffer(const cv::Mat& rgba, const GstVideoInfo& info) {
  GstBuffer* buf = gst_buffer_new_allocate(nullptr, GST_VIDEO_INFO_SIZE(&info), nullptr);
  GstVideoFrame f;
  gst_video_frame_map(&f, &info, buf, GST_MAP_WRITE);
  for (int y = 0; y < rgba.rows; ++y)
    std::memcpy(static_cast<uint8_t*>(GST_VIDEO_FRAME_PLANE_DATA(&f, 0)) + std::size_t(y) * GST_VIDEO_FRAME_PLANE_STRIDE(&f, 0),
                rgba.ptr(y), std::size_t(rgba.cols) * 4);
  gst_video_frame_unmap(&f);
  return buf;
}

void set_backend(GstElement* pipe, const std::string& backend) {
  GstIterator* it = gst_bin_iterate_recurse(GST_BIN(pipe));
  GValue item = G_VALUE_INIT;
  while (gst_iterator_next(it, &item) == GST_ITERATOR_OK) {
    GstElement* e = GST_ELEMENT(g_value_get_object(&item));
    if (g_object_class_find_property(G_OBJECT_GET_CLASS(e), "backend"))
      gst_util_set_object_arg(G_OBJECT(e), "backend", backend.c_str());
    g_value_reset(&item);
  }
  g_value_unset(&item);
  gst_iterator_free(it);
}

}  // namespace

int main(int argc, char** argv) {
  gst_init(&argc, &argv);
  const Options o = parse_args(argc, argv);
  std::filesystem::create_directories(o.out);
  const auto clips = decode(o);
  const int n = int(clips.size()), frames = int(clips[0].size());
  const std::string calib = (std::filesystem::path(o.out) / "calib.json").string();

  std::string desc = "stitchsync name=s ! stitchcalib save-file=\"" + calib + "\"";
  if (!o.rig.empty()) desc += " rig-file=\"" + o.rig + "\"";
  if (!o.calib.empty()) desc += " load-file=\"" + o.calib + "\"";
  desc += " ! " + (o.chain.empty() ? std::string() : o.chain + " ! ") + "stitchblend " + o.blend +
          " ! video/x-raw,format=RGBA ! appsink name=sink sync=false max-buffers=0";
  for (int i = 0; i < n; ++i)
    desc += " appsrc name=src" + std::to_string(i) + " format=time max-bytes=0 ! s.sink_" + std::to_string(i);
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(desc.c_str(), &err);
  if (!pipe) die(1, std::string("cannot build the pipeline: ") + (err ? err->message : "?"));
  set_backend(pipe, o.backend);

  const GstClockTime duration = GST_SECOND / 30;
  for (int i = 0; i < n; ++i) {
    const cv::Mat& first = clips[std::size_t(i)][0];
    GstVideoInfo info;
    gst_video_info_set_format(&info, GST_VIDEO_FORMAT_RGBA, guint(first.cols), guint(first.rows));
    GST_VIDEO_INFO_FPS_N(&info) = 30;
    GST_VIDEO_INFO_FPS_D(&info) = 1;
    GstCaps* caps = gst_video_info_to_caps(&info);
    GstElement* src = gst_bin_get_by_name(GST_BIN(pipe), ("src" + std::to_string(i)).c_str());
    gst_app_src_set_caps(GST_APP_SRC(src), caps);
    for (int k = 0; k < frames; ++k) {
      GstBuffer* b = to_buffer(clips[std::size_t(i)][std::size_t(k)], info);
      GST_BUFFER_PTS(b) = GstClockTime(k) * duration;
      GST_BUFFER_DURATION(b) = duration;
      gst_app_src_push_buffer(GST_APP_SRC(src), b);
    }
    gst_app_src_end_of_stream(GST_APP_SRC(src));
    gst_caps_unref(caps);
    gst_object_unref(src);
  }

  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "sink");
  std::vector<cv::Mat> panoramas;
  std::vector<double> arrival_s;
  const Clock::time_point start = Clock::now();
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  std::string error;
  for (;;) {
    GstSample* sample = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 600 * GST_SECOND);
    if (!sample) break;  // EOS, error or timeout: the bus says which
    arrival_s.push_back(std::chrono::duration<double>(Clock::now() - start).count());
    GstVideoInfo info;
    gst_video_info_from_caps(&info, gst_sample_get_caps(sample));
    GstVideoFrame f;
    if (gst_video_frame_map(&f, &info, gst_sample_get_buffer(sample), GST_MAP_READ)) {
      cv::Mat view(GST_VIDEO_INFO_HEIGHT(&info), GST_VIDEO_INFO_WIDTH(&info), CV_8UC4,
                   GST_VIDEO_FRAME_PLANE_DATA(&f, 0), std::size_t(GST_VIDEO_FRAME_PLANE_STRIDE(&f, 0)));
      panoramas.push_back(view.clone());
      gst_video_frame_unmap(&f);
    }
    gst_sample_unref(sample);
  }
  GstBus* bus = gst_element_get_bus(pipe);
  GstMessage* msg = gst_bus_pop_filtered(bus, GST_MESSAGE_ERROR);
  if (msg) {
    GError* e = nullptr;
    gst_message_parse_error(msg, &e, nullptr);
    error = e ? e->message : "error";
    g_clear_error(&e);
    gst_message_unref(msg);
  }
  gst_object_unref(bus);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(sink);
  gst_object_unref(pipe);
  if (!error.empty()) die(1, "the pipeline failed: " + error);
  if (panoramas.size() < 2) die(1, "the chain produced " + std::to_string(panoramas.size()) + " panoramas");

  // Steady time per panorama: from the output after calibration settles (stitchcalib averages
  // its first frames) to the last one.
  const std::size_t settle = std::min<std::size_t>(5, panoramas.size() - 2);
  const double per_frame_ms =
      1e3 * (arrival_s.back() - arrival_s[settle]) / double(arrival_s.size() - 1 - settle);
  std::vector<int> png = {cv::IMWRITE_PNG_COMPRESSION, 1};
  for (std::size_t k = 0; k < panoramas.size(); ++k) {
    cv::Mat bgra;
    cv::cvtColor(panoramas[k], bgra, cv::COLOR_RGBA2BGRA);
    char name[32];
    std::snprintf(name, sizeof name, "pano_%04zu.png", k);
    if (!cv::imwrite((std::filesystem::path(o.out) / name).string(), bgra, png)) die(1, "cannot write " + std::string(name));
  }
  std::ofstream(std::filesystem::path(o.out) / "run.json")
      << "{\"stitcher\":\"gst-stitch\",\"chain\":\"" << o.chain << "\",\"blend\":\"" << o.blend
      << "\",\"backend\":\"" << o.backend << "\",\"cameras\":" << n << ",\"frames\":" << panoramas.size()
      << ",\"first_output_s\":" << arrival_s.front() << ",\"ms_per_frame\":" << per_frame_ms
      << ",\"failures\":0,\"width\":" << panoramas[0].cols << ",\"height\":" << panoramas[0].rows << "}\n";
  std::printf("stitch-eval-chain: %zu panoramas %dx%d, %.2f ms each (first after %.2f s) -> %s\n", panoramas.size(),
              panoramas[0].cols, panoramas[0].rows, per_frame_ms, arrival_s.front(), o.out.c_str());
  return 0;
}
