// Panoramas per second through the whole GStreamer pipeline, sources pre-filled so that they
// cost nothing:
//   appsrc x N ! stitchsync ! stitchcalib ! stitchcolor ! stitchflowwarp ! stitchblend ! fakesink
// Each appsrc holds every buffer before the pipeline starts; the buffers share one frame's
// memory (system memory, or CUDA memory with --cuda-input). Output: the panorama stays where
// stitchblend puts it (CUDA memory when a device opens), or, with --system-output, is
// downloaded to system memory.
// --handoff event|host|both: the elements hand the bundles on by CUDA event (the default) or
// synchronise their streams before pushing (STITCH_CUDA_HOST_SYNC=1, as before issue 17); both:
// each case twice, for the A/B.
// usage: stitch-bench-pipeline [--photo PPM] [--frames N] [--rigs N] [--cuda-input] [--input-format RGBA|I420] [--system-output]
//                              [--chain "stitchcolor ! stitchflowwarp ! stitchblend"] [--handoff MODE]
//                              [--json FILE]
#include <gst/app/gstappsrc.h>
#include <gst/gst.h>
#include <gst/video/video.h>

#include <opencv2/imgproc.hpp>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "ppm.hpp"
#include "stitch/backend.hpp"
#include "stitch/rig/rig.hpp"

#ifdef STITCH_HAVE_GST_CUDA
#include <cuda_runtime_api.h>
#include <gst/cuda/gstcudacontext.h>
#include <gst/cuda/gstcudaloader.h>
#include <gst/cuda/gstcudamemory.h>
#include <gst/cuda/gstcudautils.h>
#endif

namespace {

using Clock = std::chrono::steady_clock;

struct Counter {
  int seen = 0, warmup = 0;
  Clock::time_point start, end;
};

GstPadProbeReturn count_buffers(GstPad*, GstPadProbeInfo*, gpointer data) {
  Counter* c = static_cast<Counter*>(data);
  if (++c->seen == c->warmup) c->start = Clock::now();
  c->end = Clock::now();
  return GST_PAD_PROBE_OK;
}

// One camera's frame as a GstBuffer in system memory or, with `cuda`, in CUDA memory.
GstBuffer* make_frame(const cv::Mat& rgba, GstCaps* caps, void* cuda_ctx) {
  GstVideoInfo info;
  gst_video_info_from_caps(&info, caps);
#ifdef STITCH_HAVE_GST_CUDA
  if (cuda_ctx) {
    // Debian's 1.22 gst-cuda wants the registered allocator, not NULL.
    gst_cuda_memory_init_once();
    GstAllocator* allocator = gst_allocator_find(GST_CUDA_MEMORY_TYPE_NAME);
    GstMemory* mem = gst_cuda_allocator_alloc(GST_CUDA_ALLOCATOR(allocator), GST_CUDA_CONTEXT(cuda_ctx), &info);
    gst_object_unref(allocator);
    if (!mem) return nullptr;
    GstVideoInfo layout = GST_CUDA_MEMORY_CAST(mem)->info;
    GstBuffer* buf = gst_buffer_new();
    gst_buffer_append_memory(buf, mem);
    gst_buffer_add_video_meta_full(buf, GST_VIDEO_FRAME_FLAG_NONE, GST_VIDEO_FORMAT_RGBA, guint(rgba.cols),
                                   guint(rgba.rows), 1, layout.offset, layout.stride);
    GstMapInfo map;
    gst_cuda_context_push(GST_CUDA_CONTEXT(cuda_ctx));
    gst_buffer_map(buf, &map, GstMapFlags(GST_MAP_WRITE | GST_MAP_CUDA));
    cudaMemcpy2D(map.data, size_t(layout.stride[0]), rgba.data, rgba.step, size_t(rgba.cols) * 4, size_t(rgba.rows),
                 cudaMemcpyHostToDevice);
    gst_buffer_unmap(buf, &map);
    gst_cuda_context_pop(nullptr);
    return buf;
  }
#else
  (void)cuda_ctx;
#endif
  GstBuffer* buf = gst_buffer_new_allocate(nullptr, GST_VIDEO_INFO_SIZE(&info), nullptr);
  GstVideoFrame f;
  gst_video_frame_map(&f, &info, buf, GST_MAP_WRITE);
  if (GST_VIDEO_INFO_FORMAT(&info) == GST_VIDEO_FORMAT_I420) {
    // a decoder's output: Y, U and V planes (cv's I420 packs them one after another)
    cv::Mat yuv;
    cv::cvtColor(rgba, yuv, cv::COLOR_RGBA2YUV_I420);
    const uint8_t* src = yuv.data;
    for (int p = 0; p < 3; ++p) {
      const int w = p ? rgba.cols / 2 : rgba.cols, h = p ? rgba.rows / 2 : rgba.rows;
      for (int y = 0; y < h; ++y, src += w)
        std::memcpy(static_cast<uint8_t*>(GST_VIDEO_FRAME_PLANE_DATA(&f, p)) + size_t(y) * GST_VIDEO_FRAME_PLANE_STRIDE(&f, p),
                    src, size_t(w));
    }
    gst_video_frame_unmap(&f);
    return buf;
  }
  for (int y = 0; y < rgba.rows; ++y)
    std::memcpy(static_cast<uint8_t*>(GST_VIDEO_FRAME_PLANE_DATA(&f, 0)) + size_t(y) * GST_VIDEO_FRAME_PLANE_STRIDE(&f, 0),
                rgba.ptr(y), size_t(rgba.cols) * 4);
  gst_video_frame_unmap(&f);
  return buf;
}

struct Result {
  double fps = 0;
  int frames = 0;
  std::string error;
};

std::string g_sync_props;  // --sync PROPS: stitchsync's properties (e.g. time-alignment=auto)
std::string g_input_format = "RGBA";  // --input-format I420: a decoder's planar output (system memory)

// One rig's pipeline, its buffers queued in its appsrcs; nullptr (and `error`) when it cannot be made.
GstElement* make_rig(const stitch_bench::Case& c, const cv::Mat& photo, int frames, bool cuda_input, bool system_output,
                     const std::string& chain, void* cuda_ctx, int rig_index, Counter& counter, std::string& error) {
  const stitch::Rig rig = stitch_bench::ring(c);
  const std::string rig_path =
      std::string(g_get_tmp_dir()) + "/stitch-bench-pipeline-rig" + std::to_string(rig_index) + ".json";
  stitch::rig_save(rig, rig_path);
  const std::vector<cv::Mat> views = stitch_bench::ring_views(photo, c);
  const int out_w = int(0.85 * c.cameras * c.width) / 2 * 2;
  const std::string size = " crop=auto output-width=" + std::to_string(out_w) + " output-height=" + std::to_string(c.height);
  // --chain "stitchbin [PROPS]": the bin (its own queue after stitchcalib) with its defaults or PROPS
  const bool bin = chain.rfind("stitchbin", 0) == 0;
  std::string desc = bin
                         ? "stitchbin name=s " + g_sync_props + " " + chain.substr(9) + " rig-file=\"" + rig_path +
                               "\" refine=none" + size
                         : "stitchsync name=s " + g_sync_props + " ! stitchcalib rig-file=\"" + rig_path +
                               "\" refine=none ! " + chain + size;
  desc += std::string(system_output ? " ! video/x-raw" : "") + " ! fakesink name=sink sync=false";
  for (int i = 0; i < c.cameras; ++i)
    desc += " appsrc name=src" + std::to_string(i) + " format=time max-bytes=0 ! s.sink_" + std::to_string(i);
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(desc.c_str(), &err);
  if (!pipe) {
    error = err ? err->message : "parse error";
    g_clear_error(&err);
    return nullptr;
  }
#ifdef STITCH_HAVE_GST_CUDA
  if (cuda_ctx) {
    GstContext* context = gst_context_new_cuda_context(GST_CUDA_CONTEXT(cuda_ctx));
    gst_element_set_context(pipe, context);
    gst_context_unref(context);
  }
#endif
  const std::string caps_str = std::string(cuda_input ? "video/x-raw(memory:CUDAMemory)" : "video/x-raw") +
                               ",format=" + g_input_format + ",width=" + std::to_string(c.width) + ",height=" +
                               std::to_string(c.height) + ",framerate=30/1";
  GstCaps* caps = gst_caps_from_string(caps_str.c_str());
  const GstClockTime duration = GST_SECOND / 30;
  for (int i = 0; i < c.cameras && error.empty(); ++i) {
    GstElement* src = gst_bin_get_by_name(GST_BIN(pipe), ("src" + std::to_string(i)).c_str());
    gst_app_src_set_caps(GST_APP_SRC(src), caps);
    GstBuffer* frame = make_frame(views[size_t(i)], caps, cuda_input ? cuda_ctx : nullptr);
    if (!frame) {
      error = "cannot allocate the source frames";
      gst_object_unref(src);
      break;
    }
    for (int k = 0; k < frames; ++k) {
      GstBuffer* b = gst_buffer_copy(frame);  // shares the memory: the source costs nothing
      GST_BUFFER_PTS(b) = GstClockTime(k) * duration;
      GST_BUFFER_DURATION(b) = duration;
      gst_app_src_push_buffer(GST_APP_SRC(src), b);
    }
    gst_app_src_end_of_stream(GST_APP_SRC(src));
    gst_buffer_unref(frame);
    gst_object_unref(src);
  }
  gst_caps_unref(caps);
  if (!error.empty()) {
    gst_object_unref(pipe);
    return nullptr;
  }
  counter.warmup = std::min(30, frames / 4);
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "sink");
  GstPad* pad = gst_element_get_static_pad(sink, "sink");
  gst_pad_add_probe(pad, GST_PAD_PROBE_TYPE_BUFFER, count_buffers, &counter, nullptr);
  gst_object_unref(pad);
  gst_object_unref(sink);
  return pipe;
}

// `rigs` pipelines of the case in one process, run at once. fps: every rig's panoramas after
// its warm-up over the span from the first rig's warm-up end to the last rig's end.
Result run_case(const stitch_bench::Case& c, const cv::Mat& photo, int frames, bool cuda_input, bool system_output,
                const std::string& chain, void* cuda_ctx, int rigs = 1) {
  Result r;
  std::vector<Counter> counters(size_t(std::max(1, rigs)));
  std::vector<GstElement*> pipes;
  for (size_t k = 0; k < counters.size() && r.error.empty(); ++k) {
    GstElement* pipe = make_rig(c, photo, frames, cuda_input, system_output, chain, cuda_ctx, int(k), counters[k], r.error);
    if (pipe) pipes.push_back(pipe);
  }
  if (r.error.empty())
    for (GstElement* pipe : pipes) gst_element_set_state(pipe, GST_STATE_PLAYING);
  const auto deadline = Clock::now() + std::chrono::seconds(300);
  for (GstElement* pipe : pipes) {
    if (!r.error.empty()) break;
    GstBus* bus = gst_element_get_bus(pipe);
    const auto left = std::chrono::duration_cast<std::chrono::nanoseconds>(deadline - Clock::now()).count();
    GstMessage* msg = gst_bus_timed_pop_filtered(bus, GstClockTime(std::max<long long>(left, 0)),
                                                 GstMessageType(GST_MESSAGE_EOS | GST_MESSAGE_ERROR));
    if (!msg) {
      r.error = "timed out";
    } else if (GST_MESSAGE_TYPE(msg) == GST_MESSAGE_ERROR) {
      GError* e = nullptr;
      gst_message_parse_error(msg, &e, nullptr);
      r.error = e ? e->message : "error";
      g_clear_error(&e);
    }
    if (msg) gst_message_unref(msg);
    gst_object_unref(bus);
  }
  for (GstElement* pipe : pipes) {
    gst_element_set_state(pipe, GST_STATE_NULL);
    gst_object_unref(pipe);
  }
  int counted = 0;
  Clock::time_point first = Clock::time_point::max(), last = Clock::time_point::min();
  r.frames = frames;
  for (const Counter& counter : counters) {
    r.frames = std::min(r.frames, counter.seen);
    if (counter.seen <= counter.warmup) continue;
    counted += counter.seen - counter.warmup;
    first = std::min(first, counter.start);
    last = std::max(last, counter.end);
  }
  const double span = counted > 0 ? std::chrono::duration<double>(last - first).count() : 0;
  if (span > 0) r.fps = counted / span;
  if (r.error.empty() && r.frames < frames) r.error = "only " + std::to_string(r.frames) + " panoramas";
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  gst_init(&argc, &argv);
  std::string photo_path = "build/tests/boat1_1600.ppm", json_path, chain = "stitchcolor ! stitchflowwarp ! stitchblend";
  int frames = 600;
  bool cuda_input = false, system_output = false;
  int rigs = 1;  // --rigs N: N pipelines of each case in this process, run at once (aggregate rate)
  std::vector<std::string> handoffs = {"event"};
  std::vector<stitch_bench::Case> cases = {{2, 1920, 1080}, {3, 1920, 1080}, {3, 3840, 2160}, {6, 1920, 1080}};
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--photo") && i + 1 < argc) photo_path = argv[++i];
    else if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::max(8, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--chain") && i + 1 < argc) chain = argv[++i];
    else if (!std::strcmp(argv[i], "--sync") && i + 1 < argc) g_sync_props = argv[++i];
    else if (!std::strcmp(argv[i], "--input-format") && i + 1 < argc) g_input_format = argv[++i];
    else if (!std::strcmp(argv[i], "--rigs") && i + 1 < argc) rigs = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--cuda-input")) cuda_input = true;
    else if (!std::strcmp(argv[i], "--system-output")) system_output = true;
    else if (!std::strcmp(argv[i], "--small")) cases = {{3, 640, 480}};
    else if (!std::strcmp(argv[i], "--case") && i + 1 < argc) {  // NxWxH: one size
      stitch_bench::Case c{};
      if (!stitch_bench::parse_case(argv[++i], c)) return 2;
      cases = {c};
    }
    else if (!std::strcmp(argv[i], "--handoff") && i + 1 < argc) {
      const std::string m = argv[++i];
      handoffs = m == "both" ? std::vector<std::string>{"host", "event"} : std::vector<std::string>{m};
    } else {
      std::fprintf(stderr, "usage: %s [--photo PPM] [--frames N] [--cuda-input] [--system-output] [--small] "
                           "[--case NxWxH] [--rigs N] [--chain DESC] [--sync PROPS] [--input-format RGBA|I420] [--handoff event|host|both] [--json FILE]\n", argv[0]);
      return 2;
    }
  }
  const cv::Mat photo = testdata::read_photo_or_exit(photo_path);
  void* cuda_ctx = nullptr;
  if (cuda_input) {
#ifdef STITCH_HAVE_GST_CUDA
    if (!gst_cuda_load_library() || !stitch::cuda_device_available()) {
      std::fprintf(stderr, "--cuda-input: no CUDA device\n");
      return 77;
    }
    cuda_ctx = gst_cuda_context_new(0);
#else
    std::fprintf(stderr, "--cuda-input: built without gst-cuda\n");
    return 77;
#endif
  }
  if (g_input_format != "RGBA" && (g_input_format != "I420" || cuda_input)) {
    std::fprintf(stderr, "--input-format: RGBA, or I420 in system memory\n");
    return 2;
  }
  const std::string input = std::string(cuda_input ? "CUDA memory" : "system memory") + " " + g_input_format;
  const char* output = system_output ? "system memory" : "stitchblend's choice";
  if (rigs > 1) std::printf("%d rigs in one process, at once; the rate is theirs in all\n", rigs);
  std::printf("input %s, output %s, %d frames; chain: %s\n", input.c_str(), output, frames, chain.c_str());
  std::string json = "{\"input\":\"" + input + "\",\"output\":\"" + output + "\",\"frames\":" +
                     std::to_string(frames) + ",\"cases\":[";
  int failures = 0;
  std::size_t row = 0;
  for (std::size_t i = 0; i < cases.size(); ++i)
   for (const std::string& handoff : handoffs) {
    const auto& c = cases[i];
    // read by the plugin at every frame (its own copy of the core library)
    setenv("STITCH_CUDA_HOST_SYNC", handoff == "host" ? "1" : "0", 1);
    const Result r = run_case(c, photo, frames, cuda_input, system_output, chain, cuda_ctx, rigs);
    char name[80];
    if (handoffs.size() > 1)
      std::snprintf(name, sizeof name, "%dx%dx%d/%s", c.cameras, c.width, c.height, handoff.c_str());
    else
      std::snprintf(name, sizeof name, "%dx%dx%d", c.cameras, c.width, c.height);
    if (!r.error.empty()) {
      ++failures;
      std::printf("%-18s error: %s\n", name, r.error.c_str());
    } else {
      std::printf("%-18s %8.1f panoramas/s (%d panoramas)\n", name, r.fps, r.frames);
    }
    json += std::string(row++ ? "," : "") + "{\"case\":\"" + name + "\",\"panoramas_per_s\":" + std::to_string(r.fps) +
            ",\"error\":\"" + r.error + "\"}";
  }
  json += "]}\n";
  if (!json_path.empty()) std::ofstream(json_path) << json;
#ifdef STITCH_HAVE_GST_CUDA
  if (cuda_ctx) gst_object_unref(cuda_ctx);
#endif
  return failures ? 1 : 0;
}
