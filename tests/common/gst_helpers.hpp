// Runs small stitch pipelines fed by appsrc with real image crops; collects messages and output.
#pragma once
#include <gst/app/app.h>
#include <gst/gst.h>
#include <gst/video/video.h>

#include <functional>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace gsttest {

struct RunResult {
  std::vector<std::string> errors, warnings;
  std::vector<GstStructure*> element_messages;  // owned
  std::vector<cv::Mat> frames;                  // RGBA panoramas from appsink "out"
  bool eos = false;
  ~RunResult() {
    for (auto* s : element_messages) gst_structure_free(s);
  }
  bool error_contains(const std::string& needle) const {
    for (const auto& e : errors)
      if (e.find(needle) != std::string::npos) return true;
    return false;
  }
  bool warning_contains(const std::string& needle) const {
    for (const auto& e : warnings)
      if (e.find(needle) != std::string::npos) return true;
    return false;
  }
};

inline void init() {
  static bool done = false;
  if (!done) {
    gst_init(nullptr, nullptr);
    done = true;
  }
}

// Appsrc a0..a{n-1} of `pipe` (references the caller unrefs) set up for RGBA `views` at 30 fps,
// blocking once `max_bytes` are queued (0: two frames, so the pushing threads are paced as decoders are).
inline std::vector<GstElement*> rgba_appsrcs(GstElement* pipe, const std::vector<cv::Mat>& views, guint64 max_bytes = 0) {
  std::vector<GstElement*> srcs;
  for (std::size_t i = 0; i < views.size(); ++i) {
    GstElement* a = gst_bin_get_by_name(GST_BIN(pipe), ("a" + std::to_string(i)).c_str());
    GstCaps* caps = gst_caps_new_simple("video/x-raw", "format", G_TYPE_STRING, "RGBA", "width", G_TYPE_INT,
                                        views[i].cols, "height", G_TYPE_INT, views[i].rows, "framerate",
                                        GST_TYPE_FRACTION, 30, 1, NULL);
    g_object_set(a, "caps", caps, "format", GST_FORMAT_TIME, "block", TRUE, "max-bytes",
                 max_bytes ? max_bytes : guint64(2 * views[i].total() * 4), NULL);
    gst_caps_unref(caps);
    srcs.push_back(a);
  }
  return srcs;
}

// Frame f (30 fps timestamps) of `view` into appsrc `src`; false once the pipeline refuses it.
inline bool push_frame(GstElement* src, const cv::Mat& view, int f) {
  GstBuffer* b = gst_buffer_new_allocate(nullptr, view.total() * 4, nullptr);
  gst_buffer_fill(b, 0, view.data, view.total() * 4);
  GST_BUFFER_PTS(b) = gst_util_uint64_scale(f, GST_SECOND, 30);
  GST_BUFFER_DURATION(b) = gst_util_uint64_scale(1, GST_SECOND, 30);
  return gst_app_src_push_buffer(GST_APP_SRC(src), b) == GST_FLOW_OK;
}

// `description` must name appsrc elements a0..a{n-1} and may end in "appsink name=out".
// Appsrc i gets frames(f)[i] (RGBA) for f = 0..count-1 at 30 fps, then EOS; `on_frame` runs
// before each frame is pushed (signals, pacing, a bus sync handler).
inline void run_pipeline_frames(const std::string& description, const std::function<std::vector<cv::Mat>(int)>& frames,
                                int count, RunResult& res, GstElement** keep = nullptr,
                                const std::function<void(GstElement*, int)>& on_frame = {}) {
  init();
  const std::vector<cv::Mat> views = frames(0);
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(description.c_str(), &err);
  if (!pipe) {
    res.errors.push_back(err ? err->message : "parse failed");
    g_clear_error(&err);
    return;
  }
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  std::vector<GstElement*> srcs = rgba_appsrcs(pipe, views, guint64(64 << 20));
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  GstBus* bus = gst_element_get_bus(pipe);
  auto drain_bus = [&](GstClockTime wait) {
    while (GstMessage* m = gst_bus_timed_pop(bus, wait)) {
      wait = 0;
      switch (GST_MESSAGE_TYPE(m)) {
        case GST_MESSAGE_ERROR: {
          GError* e = nullptr;
          gst_message_parse_error(m, &e, nullptr);
          res.errors.push_back(e->message);
          g_error_free(e);
          break;
        }
        case GST_MESSAGE_WARNING: {
          GError* e = nullptr;
          gst_message_parse_warning(m, &e, nullptr);
          res.warnings.push_back(e->message);
          g_error_free(e);
          break;
        }
        case GST_MESSAGE_ELEMENT:
          if (gst_message_get_structure(m))
            res.element_messages.push_back(gst_structure_copy(gst_message_get_structure(m)));
          break;
        case GST_MESSAGE_EOS: res.eos = true; break;
        default: break;
      }
      gst_message_unref(m);
    }
  };
  for (int f = 0; f < count && res.errors.empty(); ++f) {
    if (on_frame) on_frame(pipe, f);
    const std::vector<cv::Mat> now = f == 0 ? views : frames(f);
    for (std::size_t i = 0; i < srcs.size(); ++i) {
      push_frame(srcs[i], now[i], f);
    }
    drain_bus(0);
  }
  for (auto* a : srcs) gst_app_src_end_of_stream(GST_APP_SRC(a));
  // Pull every panorama until EOS or an error.
  const gint64 deadline = g_get_monotonic_time() + 120 * G_TIME_SPAN_SECOND;
  while (res.errors.empty() && !res.eos && g_get_monotonic_time() < deadline) {
    if (sink) {
      GstSample* s = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 50 * GST_MSECOND);
      if (s) {
        GstVideoInfo info;
        gst_video_info_from_caps(&info, gst_sample_get_caps(s));
        GstVideoFrame vf;
        if (gst_video_frame_map(&vf, &info, gst_sample_get_buffer(s), GST_MAP_READ)) {
          cv::Mat m(info.height, info.width, CV_8UC4, GST_VIDEO_FRAME_PLANE_DATA(&vf, 0),
                    GST_VIDEO_FRAME_PLANE_STRIDE(&vf, 0));
          res.frames.push_back(m.clone());
          gst_video_frame_unmap(&vf);
        }
        gst_sample_unref(s);
      } else if (gst_app_sink_is_eos(GST_APP_SINK(sink))) {
        res.eos = true;
      }
    }
    drain_bus(sink ? 0 : 50 * GST_MSECOND);
  }
  drain_bus(0);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(bus);
  for (auto* a : srcs) gst_object_unref(a);
  if (sink) gst_object_unref(sink);
  if (keep) *keep = pipe;
  else gst_object_unref(pipe);
}

// Every appsrc gets `views[i]` (RGBA) pushed `count` times at 30 fps, then EOS.
inline void run_pipeline(const std::string& description, const std::vector<cv::Mat>& views, int count,
                         RunResult& res, GstElement** keep = nullptr,
                         void (*on_frame)(GstElement*, int) = nullptr) {
  std::function<void(GstElement*, int)> cb;
  if (on_frame) cb = on_frame;
  run_pipeline_frames(description, [&](int) { return views; }, count, res, keep, cb);
}

inline std::string appsrc_inputs(int n) {
  std::string s;
  for (int i = 0; i < n; ++i)
    s += " appsrc name=a" + std::to_string(i) + " ! queue ! s.sink_" + std::to_string(i);
  return s;
}

}  // namespace gsttest
