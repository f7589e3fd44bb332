// End to end at real scale (issue 17): camera streams encoded as H.264/H.265 files, decoded by
// the GPU (nvh264dec / nvh265dec) straight into stitchsync and the whole chain, against the
// decode-only ceiling of the same files in the same run; several rigs in one process; latency
// from live 30 fps sources. Makes its own clips: each camera's view of a real photo (a planar
// rig, or a 360-degree ring for the equirectangular case) with sensor noise and a moving disc,
// encoded by x264enc / x265enc on the host's cores.
// usage: stitch-bench-e2e [--photo PPM] [--frames N] [--dir DIR] [--decoder nvh264dec|avdec_h264]
//                         [--cases all|small] [--only NAME,...] [--bin] [--blend PROPS] [--flowwarp PROPS] [--rigs 1,2,4,8] [--skip-latency] [--json FILE]
//                         [--handoff event|host|both]
// --handoff: the rigs-per-process runs with the stream-ordered hand-off (event, the default),
// with every element synchronising as before (host: STITCH_CUDA_HOST_SYNC=1), or both.
#include <gst/app/gstappsrc.h>
#include <gst/gst.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <thread>
#include <vector>

#include "bench_common.hpp"
#include "live_latency.hpp"
#include "ppm.hpp"
#include "ring_rig.hpp"
#include "stitch/rig/rig.hpp"

namespace {

using Clock = std::chrono::steady_clock;

struct E2eCase {
  std::string name;
  int cameras, width, height;
  bool ring360 = false;              // a 6-camera 360-degree ring to an equirectangular panorama
  int out_width = 0, out_height = 0; // 0: 0.85 x the cameras' total width (planar)
  std::string codec = "h264";
};

// "<case>_cylindrical": <case>'s cameras and clips on a cylindrical canvas (what stitchcalib
// picks for a rig wider than 110 degrees) instead of the plane.
const std::string kCylindrical = "_cylindrical";
bool cylindrical(const E2eCase& c) {
  return c.name.size() > kCylindrical.size() && c.name.compare(c.name.size() - kCylindrical.size(), std::string::npos, kCylindrical) == 0;
}

std::string g_blend_props, g_flow_props;  // --blend PROPS, --flowwarp PROPS: added to stitchblend / stitchflowwarp
bool g_bin = false;  // --bin: stitchbin with its defaults (its queue after stitchcalib) instead of the chain

// Counts buffers at a pad; the rate is taken after `warmup` buffers. With `live`, the latency
// of every panorama is measured by livelat::Meter (tests/common/live_latency.hpp): from the
// capture time of the newest camera frame it holds to the sink. (The panorama's own running time
// is stitchsync's output grid, not a capture time: "now - running time" was off by up to a frame
// either way, and gave a negative median on the H100.)
// Without a stitchsync (the sources straight to a sink) the buffers are the cameras' own frames
// and their running time is their capture time: `direct` keeps "now - running time".
struct Probe {
  int seen = 0, warmup = 0;
  Clock::time_point start, end;
  GstElement* direct = nullptr;  // the pipeline, when there is no stitchsync
  std::vector<double> direct_ms;
};

GstPadProbeReturn on_buffer(GstPad* pad, GstPadProbeInfo* info, gpointer data) {
  Probe* p = static_cast<Probe*>(data);
  if (++p->seen == p->warmup) p->start = Clock::now();
  p->end = Clock::now();
  if (p->direct && p->seen > p->warmup) {
    GstBuffer* buf = GST_PAD_PROBE_INFO_BUFFER(info);
    GstEvent* seg_event = gst_pad_get_sticky_event(pad, GST_EVENT_SEGMENT, 0);
    GstClock* clock = gst_element_get_clock(p->direct);
    if (seg_event && clock && GST_BUFFER_PTS_IS_VALID(buf)) {
      const GstSegment* seg = nullptr;
      gst_event_parse_segment(seg_event, &seg);
      const guint64 running = gst_segment_to_running_time(seg, GST_FORMAT_TIME, GST_BUFFER_PTS(buf));
      const GstClockTime now = gst_clock_get_time(clock) - gst_element_get_base_time(p->direct);
      if (running != GST_CLOCK_TIME_NONE) p->direct_ms.push_back((double(now) - double(running)) / 1e6);
    }
    if (clock) gst_object_unref(clock);
    if (seg_event) gst_event_unref(seg_event);
  }
  return GST_PAD_PROBE_OK;
}

struct Run {
  double fps = 0;
  int frames = 0, counted = 0;      // counted: after the warm-up
  Clock::time_point start, end;     // of the counted frames
  double latency_median_ms = -1, latency_p99_ms = -1;  // newest capture -> sink
  livelat::Summary latency;
  std::string error;
};

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return -1;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(q * (v.size() - 1) + 0.5))];
}

// Runs `descs.size()` pipelines at once (one per rig) in this process, each with a sink named
// "sink", until every one ends. One Run per pipeline.
std::vector<Run> run_pipelines(const std::vector<std::string>& descs, int warmup, bool live, int timeout_s) {
  std::vector<Run> runs(descs.size());
  std::vector<GstElement*> pipes(descs.size(), nullptr);
  std::vector<Probe> probes(descs.size());
  std::vector<std::unique_ptr<livelat::Meter>> meters(descs.size());
  for (size_t i = 0; i < descs.size(); ++i) {
    GError* err = nullptr;
    pipes[i] = gst_parse_launch(descs[i].c_str(), &err);
    if (!pipes[i] || err) {
      runs[i].error = err ? err->message : "parse error";
      g_clear_error(&err);
      if (pipes[i]) gst_object_unref(pipes[i]);
      pipes[i] = nullptr;
      continue;
    }
    probes[i].warmup = warmup;
    GstElement* sink = gst_bin_get_by_name(GST_BIN(pipes[i]), "sink");
    GstPad* pad = gst_element_get_static_pad(sink, "sink");
    gst_pad_add_probe(pad, GST_PAD_PROBE_TYPE_BUFFER, on_buffer, &probes[i], nullptr);
    if (live) {
      if (GstElement* sync = livelat::find_stitchsync(pipes[i])) {
        meters[i].reset(new livelat::Meter);
        if (!meters[i]->attach(pipes[i], sync, pad)) meters[i].reset();
        gst_object_unref(sync);
      } else {
        probes[i].direct = pipes[i];
      }
    }
    gst_object_unref(pad);
    gst_object_unref(sink);
  }
  for (GstElement* p : pipes)
    if (p) gst_element_set_state(p, GST_STATE_PLAYING);
  std::thread configure;  // reads each meter's configured latency once its first panorama is out
  if (live)
    configure = std::thread([&] {
      std::vector<bool> done(meters.size(), false);
      for (int k = 0; k < 400; ++k) {
        bool all = true;
        for (size_t i = 0; i < meters.size(); ++i) {
          if (!meters[i] || done[i]) continue;
          if (!meters[i]->samples().empty()) {
            meters[i]->read_configuration();
            done[i] = true;
          } else {
            all = false;
          }
        }
        if (all) break;
        g_usleep(50000);
      }
    });
  std::vector<std::thread> waiters;
  for (size_t i = 0; i < pipes.size(); ++i) {
    if (!pipes[i]) continue;
    waiters.emplace_back([&, i] {
      GstBus* bus = gst_element_get_bus(pipes[i]);
      GstMessage* msg = gst_bus_timed_pop_filtered(bus, GstClockTime(timeout_s) * GST_SECOND,
                                                   GstMessageType(GST_MESSAGE_EOS | GST_MESSAGE_ERROR));
      if (!msg) {
        runs[i].error = "timed out";
      } else if (GST_MESSAGE_TYPE(msg) == GST_MESSAGE_ERROR) {
        GError* e = nullptr;
        gst_message_parse_error(msg, &e, nullptr);
        runs[i].error = e ? e->message : "error";
        g_clear_error(&e);
      }
      if (msg) gst_message_unref(msg);
      gst_object_unref(bus);
    });
  }
  for (auto& t : waiters) t.join();
  if (configure.joinable()) configure.join();
  for (size_t i = 0; i < pipes.size(); ++i) {
    if (!pipes[i]) continue;
    gst_element_set_state(pipes[i], GST_STATE_NULL);
    gst_object_unref(pipes[i]);
    const Probe& p = probes[i];
    runs[i].frames = p.seen;
    runs[i].counted = std::max(0, p.seen - p.warmup);
    runs[i].start = p.start;
    runs[i].end = p.end;
    const double s = std::chrono::duration<double>(p.end - p.start).count();
    if (p.seen > p.warmup && s > 0) runs[i].fps = (p.seen - p.warmup) / s;
    if (meters[i]) {
      runs[i].latency = meters[i]->summarize(size_t(warmup));
      runs[i].latency_median_ms = runs[i].latency.newest_median_ms;
      runs[i].latency_p99_ms = runs[i].latency.newest_p99_ms;
      meters[i].reset();
    } else if (p.direct) {
      runs[i].latency_median_ms = percentile(p.direct_ms, 0.5);
      runs[i].latency_p99_ms = percentile(p.direct_ms, 0.99);
    }
  }
  return runs;
}

// One camera's clip: its view with sensor noise (a few precomputed fields, cycled) and a disc
// moving across it, `frames` frames at 30 fps, encoded on the host's cores.
std::string encode_clip(const cv::Mat& view_rgba, int frames, const std::string& codec, const std::string& path,
                        int camera) {
  const int w = view_rgba.cols, h = view_rgba.rows;
  // Camera-like bitrates: 8 Mbit/s at 1080p, scaled by area.
  const int kbps = std::max(500, int(8000.0 * w * h / (1920.0 * 1080.0)));
  const std::string enc = codec == "h265"
                              ? "x265enc speed-preset=ultrafast key-int-max=30 bitrate=" + std::to_string(kbps) +
                                    " ! h265parse"
                              : "x264enc speed-preset=ultrafast key-int-max=30 bframes=0 bitrate=" +
                                    std::to_string(kbps) + " ! video/x-h264,profile=high ! h264parse";
  const std::string desc = "appsrc name=src format=time ! videoconvert ! video/x-raw,format=I420 ! " + enc +
                           " ! mp4mux ! filesink location=\"" + path + "\"";
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(desc.c_str(), &err);
  if (!pipe || err) {
    std::string e = err ? err->message : "parse error";
    g_clear_error(&err);
    return e;
  }
  GstElement* src = gst_bin_get_by_name(GST_BIN(pipe), "src");
  GstCaps* caps = gst_caps_new_simple("video/x-raw", "format", G_TYPE_STRING, "RGBA", "width", G_TYPE_INT, w,
                                      "height", G_TYPE_INT, h, "framerate", GST_TYPE_FRACTION, 30, 1, nullptr);
  gst_app_src_set_caps(GST_APP_SRC(src), caps);
  gst_caps_unref(caps);
  g_object_set(src, "max-bytes", guint64(4) * w * h * 4, "block", TRUE, nullptr);
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  cv::RNG rng(1234 + camera);
  std::vector<cv::Mat> noise(4);
  for (auto& n : noise) {
    n.create(h, w, CV_16SC4);
    rng.fill(n, cv::RNG::NORMAL, 0, 3);
  }
  cv::Mat frame, shifted;
  for (int k = 0; k < frames; ++k) {
    view_rgba.convertTo(shifted, CV_16SC4);
    shifted += noise[size_t(k) % noise.size()];
    shifted.convertTo(frame, CV_8UC4);
    const int r = std::max(8, h / 10);
    cv::circle(frame, {int((k * 7L) % std::max(1, w)), h / 2}, r, cv::Scalar(200, 60, 40, 255), cv::FILLED);
    GstBuffer* buf = gst_buffer_new_allocate(nullptr, size_t(w) * h * 4, nullptr);
    gst_buffer_fill(buf, 0, frame.data, size_t(w) * h * 4);
    GST_BUFFER_PTS(buf) = GstClockTime(k) * GST_SECOND / 30;
    GST_BUFFER_DURATION(buf) = GST_SECOND / 30;
    gst_app_src_push_buffer(GST_APP_SRC(src), buf);
  }
  gst_app_src_end_of_stream(GST_APP_SRC(src));
  gst_object_unref(src);
  GstBus* bus = gst_element_get_bus(pipe);
  GstMessage* msg = gst_bus_timed_pop_filtered(bus, 600 * GST_SECOND, GstMessageType(GST_MESSAGE_EOS | GST_MESSAGE_ERROR));
  std::string error;
  if (!msg) error = "encoding timed out";
  else if (GST_MESSAGE_TYPE(msg) == GST_MESSAGE_ERROR) error = "encoding failed";
  if (msg) gst_message_unref(msg);
  gst_object_unref(bus);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(pipe);
  return error;
}

struct Prepared {
  std::vector<std::string> clips;
  std::string rig_path;
  std::string error;
};

Prepared prepare(const E2eCase& c, const cv::Mat& photo, int frames, const std::string& dir) {
  Prepared p;
  stitch::Rig rig;
  std::vector<cv::Mat> views;
  if (c.ring360) {
    // 6 cameras with 80-degree lenses around one centre, the photo taken as a 360-degree panorama.
    const double f = 0.5 * c.width / std::tan(40.0 * CV_PI / 180);
    testdata::RingScene ring = testdata::render_ring(photo, c.cameras, c.width, c.height, f,
                                                     stitch::Projection::Spherical, 0.0, 60.0);
    rig = ring.truth;
    views = ring.frames;
  } else {
    rig = stitch_bench::ring({c.cameras, c.width, c.height});
    views = stitch_bench::ring_views(photo, {c.cameras, c.width, c.height});
    if (cylindrical(c)) {
      rig.projection = stitch::projection_name(stitch::Projection::Cylindrical);
      rig.canvas_scale = 0;  // the median focal length
      stitch::rig_layout_canvas(rig);
    }
  }
  const std::string clip_name = cylindrical(c) ? c.name.substr(0, c.name.size() - kCylindrical.size()) : c.name;
  p.rig_path = dir + "/" + c.name + "_rig.json";
  stitch::rig_save(rig, p.rig_path);
  // Encode the cameras in parallel: each x264/x265 instance also uses several threads.
  std::vector<std::thread> encoders;
  std::mutex m;
  for (int i = 0; i < c.cameras; ++i) {
    const std::string path = dir + "/" + clip_name + "_cam" + std::to_string(i) + "." + c.codec + ".mp4";
    p.clips.push_back(path);
    if (std::ifstream(path).good()) continue;  // made by an earlier run
    encoders.emplace_back([&, i, path] {
      const std::string e = encode_clip(views[size_t(i)], frames, c.codec, path, i);
      std::lock_guard<std::mutex> lock(m);
      if (!e.empty()) p.error = "camera " + std::to_string(i) + ": " + e;
    });
  }
  for (auto& t : encoders) t.join();
  return p;
}

std::string decoder_for(const std::string& codec, const std::string& decoder) {
  if (decoder == "avdec") return codec == "h265" ? "h265parse ! avdec_h265" : "h264parse ! avdec_h264";
  return codec == "h265" ? "h265parse ! nvh265dec" : "h264parse ! nvh264dec";
}

std::string sources(const E2eCase& c, const Prepared& p, const std::string& decoder, const std::string& into) {
  std::string s;
  for (size_t i = 0; i < p.clips.size(); ++i)
    s += " filesrc location=\"" + p.clips[i] + "\" ! qtdemux ! " + decoder_for(c.codec, decoder) + " ! " + into +
         std::to_string(i);
  return s;
}

std::string stitch_head(const E2eCase& c, const Prepared& p) {
  const int ow = c.out_width ? c.out_width : int(0.85 * c.cameras * c.width) / 2 * 2;
  const int oh = c.out_height ? c.out_height : c.height;
  if (g_bin)
    return "stitchbin name=s rig-file=\"" + p.rig_path + "\" refine=none " + g_blend_props + " " + g_flow_props +
           (c.ring360 ? std::string(" crop=none") : std::string(" crop=auto")) + " output-width=" + std::to_string(ow) +
           " output-height=" + std::to_string(oh);
  return "stitchsync name=s ! stitchcalib rig-file=\"" + p.rig_path +
         "\" refine=none ! stitchcolor ! stitchflowwarp " + g_flow_props + " ! stitchblend " + g_blend_props +
         (c.ring360 ? std::string(" crop=none") : std::string(" crop=auto")) +
         " output-width=" + std::to_string(ow) + " output-height=" + std::to_string(oh);
}

std::string json_run(const std::string& what, const Run& r) {
  char buf[1024];
  const livelat::Summary& m = r.latency;
  std::snprintf(buf, sizeof buf,
                "{\"what\":\"%s\",\"fps\":%.1f,\"frames\":%d,\"latency_median_ms\":%.2f,\"latency_p99_ms\":%.2f,"
                "\"oldest_median_ms\":%.2f,\"sync_median_ms\":%.2f,\"stages_median_ms\":%.2f,\"configured_ms\":%.2f,"
                "\"query_min_ms\":%.2f,\"added_median_frames\":%.3f,\"added_p99_frames\":%.3f,\"old_probe_median_ms\":%.2f,"
                "\"error\":\"%s\"}",
                what.c_str(), r.fps, r.frames, r.latency_median_ms, r.latency_p99_ms, m.oldest_median_ms, m.sync_median_ms,
                m.stages_median_ms, m.configured_ms, m.query_min_ms, m.added_median_frames, m.added_p99_frames,
                m.grid_median_ms, r.error.c_str());
  return buf;
}

}  // namespace

int main(int argc, char** argv) {
  gst_init(&argc, &argv);
  std::string photo_path = "build/tests/boat1_1600.ppm", json_path, dir = "/tmp/stitch-e2e", decoder = "nv",
              cases_arg = "all", rigs_arg = "1,2,4,8", only;
  std::vector<std::string> handoffs = {"event"};
  int frames = 300;
  bool latency = true;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--photo") && i + 1 < argc) photo_path = argv[++i];
    else if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else if (!std::strcmp(argv[i], "--dir") && i + 1 < argc) dir = argv[++i];
    else if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::max(40, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--decoder") && i + 1 < argc) decoder = argv[++i];
    else if (!std::strcmp(argv[i], "--cases") && i + 1 < argc) cases_arg = argv[++i];
    else if (!std::strcmp(argv[i], "--only") && i + 1 < argc) only = std::string(",") + argv[++i] + ",";
    else if (!std::strcmp(argv[i], "--bin")) g_bin = true;
    else if (!std::strcmp(argv[i], "--blend") && i + 1 < argc) g_blend_props = argv[++i];
    else if (!std::strcmp(argv[i], "--flowwarp") && i + 1 < argc) g_flow_props = argv[++i];
    else if (!std::strcmp(argv[i], "--rigs") && i + 1 < argc) rigs_arg = argv[++i];
    else if (!std::strcmp(argv[i], "--skip-latency")) latency = false;
    else if (!std::strcmp(argv[i], "--handoff") && i + 1 < argc) {
      const std::string m = argv[++i];
      handoffs = m == "both" ? std::vector<std::string>{"host", "event"} : std::vector<std::string>{m};
    }
    else {
      std::fprintf(stderr, "usage: %s [--photo PPM] [--frames N] [--dir DIR] [--decoder nv|avdec] "
                           "[--cases all|small] [--only NAME,...] [--bin] [--blend PROPS] [--flowwarp PROPS] [--rigs 1,2,4,8] [--skip-latency] [--json FILE]\n", argv[0]);
      return 2;
    }
  }
  const cv::Mat photo = testdata::read_photo_or_exit(photo_path);
  g_mkdir_with_parents(dir.c_str(), 0755);
  std::vector<E2eCase> cases;
  if (cases_arg == "small") {
    cases = {{"3x320x240", 3, 320, 240}};
  } else {
    cases = {{"2x1080p", 2, 1920, 1080}, {"3x1080p", 3, 1920, 1080}, {"6x1080p", 6, 1920, 1080},
             {"3x1080p_h265", 3, 1920, 1080, false, 0, 0, "h265"}, {"3x4k", 3, 3840, 2160},
             {"6x4k_360_equirect", 6, 3840, 2160, true, 7680, 3840}};
    cases.insert(cases.begin() + 3, E2eCase{"6x1080p" + kCylindrical, 6, 1920, 1080});
  }
  if (!only.empty())  // --only a,b: those cases (the 3 x 1080p clips are still made for rigs/latency)
    cases.erase(std::remove_if(cases.begin(), cases.end(),
                               [&](const E2eCase& c) { return only.find("," + c.name + ",") == std::string::npos; }),
                cases.end());
  const std::string to_cuda = decoder == "avdec" ? "" : " ! video/x-raw(memory:CUDAMemory)";
  std::string json = "{\"frames\":" + std::to_string(frames) + ",\"decoder\":\"" + decoder + "\",\"cases\":[";
  const int warmup = 30;
  Prepared three;  // the 3 x 1080p clips, reused for several rigs and latency
  E2eCase three_case;
  for (const E2eCase& c : cases) {
    const auto t0 = Clock::now();
    Prepared p = prepare(c, photo, frames, dir);
    const double encode_s = std::chrono::duration<double>(Clock::now() - t0).count();
    if (!p.error.empty()) {
      std::printf("%-20s clips: %s\n", c.name.c_str(), p.error.c_str());
      continue;
    }
    if (c.name == "3x1080p" || cases_arg == "small") {
      three = p;
      three_case = c;
    }
    std::string decode_only;
    for (size_t i = 0; i < p.clips.size(); ++i)
      decode_only += " filesrc location=\"" + p.clips[i] + "\" ! qtdemux ! " + decoder_for(c.codec, decoder) +
                     " ! fakesink sync=false" + (i == 0 ? " name=sink" : "");
    const std::string head = stitch_head(c, p);
    const std::string srcs = sources(c, p, decoder, "s.sink_");
    const Run dec = run_pipelines({decode_only}, warmup, false, 300)[0];
    const Run gpu = run_pipelines({head + to_cuda + " ! fakesink name=sink sync=false" + srcs}, warmup, false, 300)[0];
    const Run down = run_pipelines(
        {head + (decoder == "avdec" ? "" : " ! cudadownload") + " ! video/x-raw ! fakesink name=sink sync=false" + srcs},
        warmup, false, 300)[0];
    std::printf("%-20s decode-only %7.1f/s | stitched (CUDA memory) %7.1f/s = %5.1f%% | downloaded %7.1f/s = %5.1f%%"
                "  (clips made in %.0f s)%s%s%s\n",
                c.name.c_str(), dec.fps, gpu.fps, dec.fps > 0 ? 100 * gpu.fps / dec.fps : 0, down.fps,
                dec.fps > 0 ? 100 * down.fps / dec.fps : 0, encode_s, dec.error.empty() ? "" : (" decode: " + dec.error).c_str(),
                gpu.error.empty() ? "" : (" stitched: " + gpu.error).c_str(),
                down.error.empty() ? "" : (" downloaded: " + down.error).c_str());
    std::fflush(stdout);
    json += std::string(json.back() == '[' ? "" : ",") + "{\"case\":\"" + c.name + "\",\"runs\":[" +
            json_run("decode-only", dec) + "," + json_run("stitched", gpu) + "," + json_run("downloaded", down) + "]}";
  }
  json += "],\"rigs\":[";
  if (!three.clips.empty()) {
    // Several rigs in one process: the same 3-camera rig's files, one pipeline per rig.
    std::vector<int> counts;
    for (const char* s = rigs_arg.c_str(); *s;) {
      counts.push_back(std::atoi(s));
      const char* comma = std::strchr(s, ',');
      if (!comma) break;
      s = comma + 1;
    }
    for (int n : counts)
     for (const std::string& handoff : handoffs) {
      if (n < 1) continue;
      setenv("STITCH_CUDA_HOST_SYNC", handoff == "host" ? "1" : "0", 1);  // read by the plugin per frame
      // Throughput: file inputs as fast as they decode. Aggregate = every rig's panoramas over
      // the span from the first rig's warm-up end to the last rig's end (rigs that finish early
      // do not inflate it).
      const std::string desc = stitch_head(three_case, three) + to_cuda + " ! fakesink name=sink sync=false" +
                               sources(three_case, three, decoder, "s.sink_");
      std::vector<Run> runs = run_pipelines(std::vector<std::string>(size_t(n), desc), warmup, false, 300);
      int counted = 0;
      double slowest = 1e30;
      Clock::time_point first = Clock::time_point::max(), last = Clock::time_point::min();
      std::string errors;
      for (const Run& r : runs) {
        counted += r.counted;
        slowest = std::min(slowest, r.fps);
        if (r.counted > 0) {
          first = std::min(first, r.start);
          last = std::max(last, r.end);
        }
        if (!r.error.empty()) errors += " " + r.error;
      }
      const double span = std::chrono::duration<double>(last - first).count();
      const double total = span > 0 ? counted / span : 0;
      // Latency: the same number of rigs, each fed by live 30 fps cameras.
      std::string live_desc = "stitchsync name=s ! stitchcalib rig-file=\"" + three.rig_path +
                              "\" refine=none ! stitchcolor ! stitchflowwarp ! stitchblend crop=auto ! "
                              "fakesink name=sink sync=false";
      for (int i = 0; i < three_case.cameras; ++i)
        live_desc += " videotestsrc is-live=true pattern=ball num-buffers=150 ! video/x-raw,format=RGBA,width=" +
                     std::to_string(three_case.width) + ",height=" + std::to_string(three_case.height) +
                     ",framerate=30/1" + (decoder == "avdec" ? "" : " ! cudaupload") + " ! s.sink_" + std::to_string(i);
      std::vector<Run> live = run_pipelines(std::vector<std::string>(size_t(n), live_desc), 10, true, 60);
      double worst_median = -1, worst_p99 = -1;  // -1: not measured (a max from 0 hid negative medians before)
      for (const Run& r : live) {
        worst_median = std::max(worst_median, r.latency_median_ms);
        worst_p99 = std::max(worst_p99, r.latency_p99_ms);
        if (!r.error.empty()) errors += " live: " + r.error;
      }
      std::printf("%d rig(s) of %s in one process [%s hand-off]: %7.1f panoramas/s in all, slowest rig %7.1f/s; "
                  "live 30 fps: latency median %.1f ms, p99 %.1f ms (worst rig)%s\n",
                  n, three_case.name.c_str(), handoff.c_str(), total, slowest, worst_median, worst_p99, errors.c_str());
      std::fflush(stdout);
      json += std::string(json.back() == '[' ? "" : ",") + "{\"rigs\":" + std::to_string(n) + ",\"handoff\":\"" + handoff + "\"" +
              ",\"total_fps\":" + std::to_string(total) + ",\"slowest_fps\":" + std::to_string(slowest) +
              ",\"live_latency_median_ms\":" + std::to_string(worst_median) +
              ",\"live_latency_p99_ms\":" + std::to_string(worst_p99) + "}";
    }
  }
  json += "],\"latency\":[";
  if (latency) {
    // Live 30 fps cameras (videotestsrc is-live, a moving pattern), 10 s: from each frame's
    // capture time to its panorama at the sink. The same sources straight to a sink give the
    // sources' own share. CPU chain and, with a device, the CUDA chain.
    const E2eCase& c = three_case.cameras ? three_case : cases.front();
    const int live_frames = 300;
    auto live_sources = [&](const std::string& into, bool upload) {
      std::string s;
      for (int i = 0; i < c.cameras; ++i)
        s += " videotestsrc is-live=true pattern=ball num-buffers=" + std::to_string(live_frames) +
             " ! video/x-raw,format=RGBA,width=" + std::to_string(c.width) + ",height=" + std::to_string(c.height) +
             ",framerate=30/1" + (upload ? " ! cudaupload" : "") + " ! " + into + std::to_string(i);
      return s;
    };
    std::string direct;
    for (int i = 0; i < c.cameras; ++i)
      direct += " videotestsrc is-live=true pattern=ball num-buffers=" + std::to_string(live_frames) +
                " ! video/x-raw,format=RGBA,width=" + std::to_string(c.width) + ",height=" +
                std::to_string(c.height) + ",framerate=30/1 ! fakesink sync=false" + (i == 0 ? " name=sink" : "");
    const std::string head = "stitchsync name=s ! stitchcalib rig-file=\"" + three.rig_path +
                             "\" refine=none ! stitchcolor BACKEND ! stitchflowwarp BACKEND ! stitchblend BACKEND";
    auto with_backend = [](std::string s, const std::string& b) {
      for (size_t at; (at = s.find("BACKEND")) != std::string::npos;) s.replace(at, 7, b);
      return s;
    };
    struct LiveCase {
      std::string name, desc;
    };
    std::vector<LiveCase> live = {
        {"sources only", direct},
        {"CPU chain", with_backend(head, "backend=cpu") + " ! fakesink name=sink sync=false" +
                          live_sources("s.sink_", false)}};
    if (decoder != "avdec")
      live.push_back({"CUDA chain", with_backend(head, "backend=cuda") + " ! fakesink name=sink sync=false" +
                                        live_sources("s.sink_", true)});
    for (const LiveCase& l : live) {
      const Run r = run_pipelines({l.desc}, 10, true, 60)[0];
      const livelat::Summary& m = r.latency;
      std::printf("latency, live %s %dx%dx%d at 30 fps: newest capture -> sink median %.1f ms, p99 %.1f ms (%d frames)%s\n",
                  l.name.c_str(), c.cameras, c.width, c.height, r.latency_median_ms, r.latency_p99_ms, r.frames,
                  r.error.empty() ? "" : (" " + r.error).c_str());
      if (m.samples > 0)
        std::printf("  oldest capture -> sink median %.1f ms; stitchsync %.1f ms, stages %.1f ms (medians); stitchsync "
                    "latency property %.1f ms, LATENCY query min %.1f ms; added latency %.2f frames (median), %.2f (p99); "
                    "old probe (sink - panorama running time) median %.1f ms, min %.1f ms\n",
                    m.oldest_median_ms, m.sync_median_ms, m.stages_median_ms, m.configured_ms, m.query_min_ms,
                    m.added_median_frames, m.added_p99_frames, m.grid_median_ms, m.grid_min_ms);
      std::fflush(stdout);
      json += std::string(json.back() == '[' ? "" : ",") + json_run("live " + l.name, r);
    }
  }
  json += "]}";
  if (!json_path.empty()) std::ofstream(json_path) << json << "\n";
  return 0;
}
