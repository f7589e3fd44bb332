// Frames in CUDA memory between the stitch elements.
// Everywhere: every bundle pad lists video/x-raw(memory:CUDAMemory) first and system memory
// second (in a build with gst-cuda), and a chain negotiates CUDA memory between our elements
// exactly when a device opens (so here, without one, system memory as before).
// With a GPU (skipped, with a message, without one): fed with CUDA memory (cudaupload) the
// chain gives the system-memory chain's panorama (PSNR >= 45 dB), every link between our
// elements is memory:CUDAMemory, NV12 from the GPU matches videoconvert's, and
// nvh264dec ! stitchsync ... stitchblend ! cudadownload runs in one CUDA context, and the
// stream-ordered hand-off (CUDA events, no host synchronisation between our elements) gives the
// panoramas of STITCH_CUDA_HOST_SYNC=1 with a queue between every element.
// Like test_cuda it links no imgcodecs (the photo is read as PPM), so it fits the GPU bundle.
#include <gst/gst.h>
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <map>
#include <mutex>
#include <random>
#include <opencv2/imgproc.hpp>
#include <unistd.h>

#include "../../gst/gststitchbundle.h"  // the bundle meta's layout only
#include "gst_helpers.hpp"
#include "cuda_test.hpp"
#include "image_compare.hpp"
#include "ppm.hpp"
#include "stitch/backend.hpp"
#include "stitch/rig/rig.hpp"
#include "synthetic_rig.hpp"

#ifdef STITCH_HAVE_GST_CUDA
#include <cuda_runtime_api.h>
#include <gst/cuda/gstcudacontext.h>
#include <gst/cuda/gstcudaloader.h>
#endif

namespace {

constexpr const char* kCudaFeature = "memory:CUDAMemory";

bool cuda_memory_possible() {
#ifdef STITCH_HAVE_GST_CUDA
  gsttest::init();
  return gst_cuda_load_library() && stitch::cuda_device_available();
#else
  return false;
#endif
}

#define REQUIRE_CUDA_MEMORY()                                                                   \
  do {                                                                                          \
    if (!cuda_memory_possible())                                                                \
      GTEST_SKIP() << "no CUDA device here (or a build without gst-cuda): the CUDA-memory "    \
                      "chain is not checked";                                                   \
  } while (0)

bool has_cuda_feature(const GstCaps* caps, guint i) {
  const GstCapsFeatures* f = gst_caps_get_features(caps, i);
  return f && !gst_caps_features_is_any(f) && gst_caps_features_contains(f, kCudaFeature);
}

std::string to_string(const GstCaps* caps) {
  gchar* s = gst_caps_to_string(caps);
  std::string r = s ? s : "";
  g_free(s);
  return r;
}

// Two crops of a real photo, 400 px apart, and their exact calibration.
struct Scene {
  cv::Mat photo;
  std::vector<cv::Mat> views;
  std::string calib;
};

Scene scene() {
  Scene s;
  const char* ppm = std::getenv("STITCH_TEST_PPM");
  s.photo = testdata::read_ppm_rgba(ppm ? ppm : "");
  if (s.photo.empty()) throw std::runtime_error(std::string("cannot read STITCH_TEST_PPM=") + (ppm ? ppm : ""));
  for (int i = 0; i < 2; ++i) s.views.push_back(s.photo(cv::Rect(400 * i, 200, 640, 480)).clone());
  const auto dir = std::filesystem::temp_directory_path() / ("stitch-cuda-memory-" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  s.calib = (dir / "calib.json").string();
  stitch::rig_save(testdata::shifted_rig(2, 640, 480, 400), s.calib);
  return s;
}

// Caps of every stitch element's src pad as they are negotiated (element name -> caps).
struct CapsLog {
  std::mutex lock;
  std::map<std::string, std::string> caps;
};
CapsLog g_caps;

GstPadProbeReturn record_caps(GstPad*, GstPadProbeInfo* info, gpointer name) {
  GstEvent* event = GST_PAD_PROBE_INFO_EVENT(info);
  if (GST_EVENT_TYPE(event) == GST_EVENT_CAPS) {
    GstCaps* caps = nullptr;
    gst_event_parse_caps(event, &caps);
    std::lock_guard<std::mutex> guard(g_caps.lock);
    g_caps.caps[static_cast<const char*>(name)] = to_string(caps);
  }
  return GST_PAD_PROBE_OK;
}

// Elements named s (stitchsync), c (calib), col (color), fw (flow warp), b (blend), d0/d1
// (decoders): a caps probe on each src pad.
void watch_caps(GstElement* pipe) {
  {
    std::lock_guard<std::mutex> guard(g_caps.lock);
    g_caps.caps.clear();
  }
  for (const char* name : {"s", "c", "col", "fw", "b", "d0", "d1"}) {
    GstElement* e = gst_bin_get_by_name(GST_BIN(pipe), name);
    if (!e) continue;
    GstPad* pad = gst_element_get_static_pad(e, "src");
    gst_pad_add_probe(pad, GST_PAD_PROBE_TYPE_EVENT_DOWNSTREAM, record_caps, g_strdup(name), g_free);
    gst_object_unref(pad);
    gst_object_unref(e);
  }
}

// gsttest::run_pipeline calls this before the first buffer is pushed.
void watch_caps_on_first_frame(GstElement* pipe, int frame) {
  if (frame == 0) watch_caps(pipe);
}

std::map<std::string, std::string> caps_seen() {
  std::lock_guard<std::mutex> guard(g_caps.lock);
  return g_caps.caps;
}

// Links between our elements in `chain` order, each with its caps; ends at stitchblend.
void expect_memory(const std::vector<std::string>& elements, bool cuda) {
  const auto seen = caps_seen();
  for (const std::string& e : elements) {
    auto it = seen.find(e);
    ASSERT_NE(it, seen.end()) << "no caps seen on " << e << "'s src pad";
    if (e == "b") continue;  // the panorama's memory is downstream's choice
    EXPECT_EQ(it->second.find(kCudaFeature) != std::string::npos, cuda)
        << e << ".src: " << it->second << (cuda ? " (expected CUDA memory)" : " (expected system memory)");
  }
}

const char* kMiddles[] = {"", "stitchcolor name=col ! ", "stitchflowwarp name=fw flow=false ! "};

std::string appsrc_cuda_inputs(int n, const std::string& convert = "") {
  std::string s;
  for (int i = 0; i < n; ++i)
    s += " appsrc name=a" + std::to_string(i) + " ! queue ! " + convert + "cudaupload ! s.sink_" + std::to_string(i);
  return s;
}

bool elements_exist(std::initializer_list<const char*> names, std::string& missing) {
  gsttest::init();
  for (const char* n : names) {
    GstElementFactory* f = gst_element_factory_find(n);
    if (!f) missing += std::string(missing.empty() ? "" : ", ") + n;
    else gst_object_unref(f);
  }
  return missing.empty();
}

}  // namespace

// Every bundle pad offers CUDA memory first and system memory second; stitchsync's inputs take
// decoders' CUDA NV12 and any raw video in system memory.
TEST(CudaMemoryCaps, PadTemplatesOfferBothMemories) {
  gsttest::init();
  const std::vector<std::pair<const char*, std::vector<const char*>>> bundle_pads = {
      {"stitchsync", {"src"}},
      {"stitchcalib", {"sink", "src"}},
      {"stitchcolor", {"sink", "src"}},
      {"stitchflowwarp", {"sink", "src"}},
      {"stitchblend", {"sink"}}};
  for (const auto& [element, pads] : bundle_pads) {
    GstElementFactory* f = gst_element_factory_find(element);
    ASSERT_NE(f, nullptr) << element << " not found";
    for (const char* pad : pads) {
      GstCaps* caps = nullptr;
      for (const GList* l = gst_element_factory_get_static_pad_templates(f); l; l = l->next) {
        auto* t = static_cast<GstStaticPadTemplate*>(l->data);
        if (g_strcmp0(t->name_template, pad) == 0) caps = gst_static_pad_template_get_caps(t);
      }
      ASSERT_NE(caps, nullptr) << element << " has no pad " << pad;
      SCOPED_TRACE(std::string(element) + "." + pad + ": " + to_string(caps));
#ifdef STITCH_HAVE_GST_CUDA
      ASSERT_EQ(gst_caps_get_size(caps), 2u);
      EXPECT_TRUE(has_cuda_feature(caps, 0));
      EXPECT_FALSE(has_cuda_feature(caps, 1));
#else
      ASSERT_EQ(gst_caps_get_size(caps), 1u);
      EXPECT_FALSE(has_cuda_feature(caps, 0));
#endif
      for (guint i = 0; i < gst_caps_get_size(caps); ++i)
        EXPECT_STREQ(gst_structure_get_string(gst_caps_get_structure(caps, i), "multiview-mode"), "separated");
      gst_caps_unref(caps);
    }
    gst_object_unref(f);
  }
  GstElementFactory* sync = gst_element_factory_find("stitchsync");
  ASSERT_NE(sync, nullptr);
  for (const GList* l = gst_element_factory_get_static_pad_templates(sync); l; l = l->next) {
    auto* t = static_cast<GstStaticPadTemplate*>(l->data);
    if (t->direction != GST_PAD_SINK) continue;
    GstCaps* caps = gst_static_pad_template_get_caps(t);
    SCOPED_TRACE(to_string(caps));
    const guint last = gst_caps_get_size(caps) - 1;
    EXPECT_FALSE(has_cuda_feature(caps, last));  // system memory: any raw format, as before
    GstCaps* i420 = gst_caps_from_string("video/x-raw,format=I420,width=64,height=48,framerate=30/1");
    EXPECT_TRUE(gst_caps_can_intersect(caps, i420));
    gst_caps_unref(i420);
#ifdef STITCH_HAVE_GST_CUDA
    EXPECT_TRUE(has_cuda_feature(caps, 0));
    for (const char* format : {"NV12", "I420", "RGBA", "BGRA", "BGRx"}) {
      GstCaps* cuda = gst_caps_from_string(
          (std::string("video/x-raw(memory:CUDAMemory),format=") + format + ",width=64,height=48,framerate=30/1").c_str());
      EXPECT_TRUE(gst_caps_can_intersect(caps, cuda)) << format;
      gst_caps_unref(cuda);
    }
#endif
    gst_caps_unref(caps);
  }
  gst_object_unref(sync);
}

// The whole chain negotiates CUDA memory between our elements exactly when a device opens:
// here without one, system memory on every link, as before; on a GPU, memory:CUDAMemory.
TEST(CudaMemoryCaps, ChainNegotiatesCudaMemoryExactlyWhenADeviceOpens) {
  Scene s = scene();
  const bool cuda = cuda_memory_possible();
  gsttest::RunResult r;
  gsttest::run_pipeline("stitchsync name=s ! stitchcalib name=c load-file=" + s.calib +
                            " ! stitchcolor name=col ! stitchflowwarp name=fw ! stitchblend name=b ! "
                            "video/x-raw,format=RGBA ! appsink name=out sync=false" +
                            gsttest::appsrc_inputs(2),
                        s.views, 2, r, nullptr, watch_caps_on_first_frame);
  ASSERT_TRUE(r.errors.empty()) << r.errors[0];
  ASSERT_EQ(r.frames.size(), 2u);
  std::printf("device memory possible here: %s\n", cuda ? "yes" : "no");
  for (const auto& [element, caps] : caps_seen()) std::printf("  %s.src: %s\n", element.c_str(), caps.c_str());
  expect_memory({"s", "c", "col", "fw", "b"}, cuda);
  // The panorama went out in system memory (appsink asked for it) and is the scene.
  EXPECT_GT(testdata::psnr_rgb(r.frames[1](cv::Rect(0, 0, 1040, 480)), s.photo(cv::Rect(0, 200, 1040, 480))), 40.0);
}

// GPU: fed with CUDA memory, with and without stitchcolor / stitchflowwarp, the chain gives the
// panorama of the system-memory chain, and every link between our elements is CUDA memory.
TEST(CudaMemoryChain, CudauploadFedChainMatchesSystemMemoryChain) {
  REQUIRE_CUDA_MEMORY();
  std::string missing;
  if (!elements_exist({"cudaupload", "cudadownload"}, missing)) GTEST_SKIP() << "missing elements: " << missing;
  Scene s = scene();
  for (const char* middle : kMiddles) {
    SCOPED_TRACE(std::string("middle: ") + middle);
    gsttest::RunResult gpu, cpu;
    gsttest::run_pipeline("stitchsync name=s ! stitchcalib name=c load-file=" + s.calib + " ! " + middle +
                              "stitchblend name=b ! cudadownload ! video/x-raw,format=RGBA ! appsink name=out sync=false" +
                              appsrc_cuda_inputs(2),
                          s.views, 3, gpu, nullptr, watch_caps_on_first_frame);
    ASSERT_TRUE(gpu.errors.empty()) << gpu.errors[0];
    for (const auto& [element, caps] : caps_seen()) std::printf("  %s.src: %s\n", element.c_str(), caps.c_str());
    std::vector<std::string> links = {"s", "c", "b"};
    if (std::string(middle).find("col") != std::string::npos) links.push_back("col");
    if (std::string(middle).find("fw") != std::string::npos) links.push_back("fw");
    expect_memory(links, true);
    EXPECT_NE(caps_seen()["b"].find(kCudaFeature), std::string::npos) << "stitchblend ! cudadownload: " << caps_seen()["b"];
    gsttest::run_pipeline("stitchsync name=s backend=cpu ! stitchcalib load-file=" + s.calib + " ! " + middle +
                              "stitchblend ! video/x-raw,format=RGBA ! appsink name=out sync=false" +
                              gsttest::appsrc_inputs(2),
                          s.views, 3, cpu);
    ASSERT_TRUE(cpu.errors.empty()) << cpu.errors[0];
    ASSERT_EQ(gpu.frames.size(), cpu.frames.size());
    ASSERT_FALSE(gpu.frames.empty());
    for (std::size_t k = 0; k < gpu.frames.size(); ++k) {
      const double psnr = testdata::psnr_rgb(gpu.frames[k], cpu.frames[k]);
      std::printf("chain [%s] frame %zu: CUDA memory vs system memory PSNR %.2f dB\n", middle, k, psnr);
      EXPECT_GE(psnr, 45.0);
    }
  }
}

// GPU: with optical flow on, the CUDA-memory chain runs and stays close to the system-memory one
// (the CUDA flow is its own implementation, so the bound is looser).
TEST(CudaMemoryChain, FlowWarpInCudaMemoryRuns) {
  REQUIRE_CUDA_MEMORY();
  std::string missing;
  if (!elements_exist({"cudaupload", "cudadownload"}, missing)) GTEST_SKIP() << "missing elements: " << missing;
  Scene s = scene();
  s.views[1] = testdata::with_parallax(s.views[1], 4.0);
  gsttest::RunResult gpu, cpu;
  gsttest::run_pipeline("stitchsync name=s ! stitchcalib name=c load-file=" + s.calib +
                            " ! stitchcolor name=col ! stitchflowwarp name=fw ! stitchblend name=b ! cudadownload ! "
                            "video/x-raw,format=RGBA ! appsink name=out sync=false" +
                            appsrc_cuda_inputs(2),
                        s.views, 3, gpu, nullptr, watch_caps_on_first_frame);
  ASSERT_TRUE(gpu.errors.empty()) << gpu.errors[0];
  expect_memory({"s", "c", "col", "fw", "b"}, true);
  gsttest::run_pipeline("stitchsync backend=cpu name=s ! stitchcalib load-file=" + s.calib +
                            " ! stitchcolor ! stitchflowwarp ! stitchblend ! video/x-raw,format=RGBA ! "
                            "appsink name=out sync=false" +
                            gsttest::appsrc_inputs(2),
                        s.views, 3, cpu);
  ASSERT_TRUE(cpu.errors.empty()) << cpu.errors[0];
  ASSERT_EQ(gpu.frames.size(), cpu.frames.size());
  for (std::size_t k = 0; k < gpu.frames.size(); ++k) {
    const double psnr = testdata::psnr_rgb(gpu.frames[k], cpu.frames[k]);
    std::printf("flow chain frame %zu: CUDA memory vs system memory PSNR %.2f dB\n", k, psnr);
    EXPECT_GE(psnr, 30.0);
  }
}

// GPU: the stream-ordered hand-off (issue 17). With a queue (a thread) between every element
// and frames that alternate between bright and dark, reading a bundle before its producer's
// kernels finished, or rewriting a pooled bundle before its reader finished, shows as a frame
// of the wrong brightness. The panoramas equal those of STITCH_CUDA_HOST_SYNC=1 (every element
// synchronises its stream, as before), and the fence meta travels between our elements.
TEST(CudaMemoryChain, StreamOrderedHandoffMatchesHostSync) {
  REQUIRE_CUDA_MEMORY();
  std::string missing;
  if (!elements_exist({"cudaupload", "cudadownload"}, missing)) GTEST_SKIP() << "missing elements: " << missing;
  Scene s = scene();
  s.views[1] = testdata::with_parallax(s.views[1], 4.0);
  auto frames = [&](int k) {
    std::vector<cv::Mat> v;
    for (const cv::Mat& m : s.views) {
      cv::Mat d;
      cv::multiply(m, cv::Scalar(k % 2 ? 0.4 : 1.0, k % 2 ? 0.4 : 1.0, k % 2 ? 0.4 : 1.0, 1.0), d);  // alpha kept
      v.push_back(d);
    }
    return v;
  };
  const std::string q = " ! queue max-size-buffers=2 ! ";
  const std::string desc = "stitchsync name=s" + q + "stitchcalib name=c load-file=" + s.calib + q +
                           "stitchcolor name=col" + q + "stitchflowwarp name=fw" + q + "stitchblend name=b" + q +
                           "cudadownload ! video/x-raw,format=RGBA ! appsink name=out sync=false" +
                           appsrc_cuda_inputs(2);
  static std::atomic<int> fenced{0};
  fenced = 0;
  auto count_fences = [](GstElement* pipe, int frame) {
    if (frame != 0) return;
    GstElement* fw = gst_bin_get_by_name(GST_BIN(pipe), "fw");
    GstPad* pad = gst_element_get_static_pad(fw, "sink");
    gst_pad_add_probe(pad, GST_PAD_PROBE_TYPE_BUFFER,
                      [](GstPad*, GstPadProbeInfo* info, gpointer) {
                        const GType api = g_type_from_name("GstStitchCudaFenceMetaAPI");
                        if (api && gst_buffer_get_meta(GST_PAD_PROBE_INFO_BUFFER(info), api)) ++fenced;
                        return GST_PAD_PROBE_OK;
                      },
                      nullptr, nullptr);
    gst_object_unref(pad);
    gst_object_unref(fw);
  };
  gsttest::RunResult host, event;
  setenv("STITCH_CUDA_HOST_SYNC", "1", 1);
  gsttest::run_pipeline_frames(desc, frames, 16, host);
  setenv("STITCH_CUDA_HOST_SYNC", "0", 1);
  gsttest::run_pipeline_frames(desc, frames, 16, event, nullptr, count_fences);
  unsetenv("STITCH_CUDA_HOST_SYNC");
  ASSERT_TRUE(host.errors.empty()) << host.errors[0];
  ASSERT_TRUE(event.errors.empty()) << event.errors[0];
  ASSERT_EQ(host.frames.size(), event.frames.size());
  ASSERT_GE(event.frames.size(), 12u);
  EXPECT_GT(fenced.load(), 0) << "no bundle reached stitchflowwarp with a CUDA event";
  for (std::size_t k = 0; k < event.frames.size(); ++k) {
    const double psnr = testdata::psnr_rgb(event.frames[k], host.frames[k]);
    std::printf("hand-off frame %zu: event vs host sync PSNR %.2f dB\n", k, psnr);
    EXPECT_GE(psnr, 40.0) << "frame " << k;
  }
}

// GPU: decoder formats are converted by our kernels, NV12 in CUDA memory (what nvh264dec hands
// over) and I420 in system memory (uploaded once); the panorama matches the system-memory path,
// where videoconvert converts (within two converters' differences: dithering, chroma taps).
TEST(CudaMemoryChain, DecoderFormatsMatchVideoconvert) {
  REQUIRE_CUDA_MEMORY();
  std::string missing;
  if (!elements_exist({"cudaupload", "cudadownload", "videoconvert"}, missing))
    GTEST_SKIP() << "missing elements: " << missing;
  Scene s = scene();
  const std::pair<const char*, const char*> inputs[] = {
      {"videoconvert ! video/x-raw,format=NV12,colorimetry=bt709 ! ", "cudaupload ! "},
      {"videoconvert ! video/x-raw,format=I420,colorimetry=bt601 ! ", ""}};
  for (const auto& [convert, upload] : inputs) {
    SCOPED_TRACE(std::string(convert) + upload);
    std::string gpu_inputs, cpu_inputs;
    for (int i = 0; i < 2; ++i) {
      const std::string head = " appsrc name=a" + std::to_string(i) + " ! queue ! " + convert;
      gpu_inputs += head + upload + "s.sink_" + std::to_string(i);
      cpu_inputs += head + "s.sink_" + std::to_string(i);
    }
    gsttest::RunResult gpu, cpu;
    gsttest::run_pipeline("stitchsync name=s ! stitchcalib name=c load-file=" + s.calib +
                              " ! stitchblend name=b ! cudadownload ! video/x-raw,format=RGBA ! appsink name=out sync=false" +
                              gpu_inputs,
                          s.views, 3, gpu, nullptr, watch_caps_on_first_frame);
    ASSERT_TRUE(gpu.errors.empty()) << gpu.errors[0];
    expect_memory({"s", "c", "b"}, true);
    gsttest::run_pipeline("stitchsync name=s backend=cpu ! stitchcalib load-file=" + s.calib +
                              " ! stitchblend ! video/x-raw,format=RGBA ! appsink name=out sync=false" + cpu_inputs,
                          s.views, 3, cpu);
    ASSERT_TRUE(cpu.errors.empty()) << cpu.errors[0];
    ASSERT_EQ(gpu.frames.size(), cpu.frames.size());
    ASSERT_FALSE(gpu.frames.empty());
    for (std::size_t k = 0; k < gpu.frames.size(); ++k) {
      const double psnr = testdata::psnr_rgb(gpu.frames[k], cpu.frames[k]);
      std::printf("%s%sframe %zu: CUDA kernels vs videoconvert PSNR %.2f dB\n", convert, upload, k, psnr);
      EXPECT_GE(psnr, 35.0);
    }
  }
}

namespace {

// One input frame: uniform RGBA that encodes (input, frame number).
cv::Vec4b code_colour(int input, int frame) {
  const int code = 1 + input * 100 + frame;
  return {uchar(code), uchar(255 - code), uchar(17 * input + 3), 255};
}

struct Bundle {
  guint64 missing = 0;
  std::vector<cv::Mat> views;
  bool cuda = false;
};

// stitchsync (with `props`) ! appsink, fed by appsrc a0, a1 with frames at 30 fps: input i gets
// frame numbers frames[i] (timestamped by number, so gaps and late starts are real), then EOS.
// `shared` (optional): each input pushes copies of one buffer (the same memory every frame, as a
// pool's buffers come back), coloured as its frame 0; those buffers are returned there, and
// `before_stop` sees the pipeline once the bundles are in.
std::vector<Bundle> run_sync(const std::string& props, const std::vector<std::vector<int>>& frames, int w, int h,
                             std::vector<GstBuffer*>* shared = nullptr,
                             const std::function<void(GstElement*)>& before_stop = {}) {
  gsttest::init();
  std::string desc = "stitchsync name=s " + props + " ! appsink name=out sync=false";
  for (std::size_t i = 0; i < frames.size(); ++i)
    desc += " appsrc name=a" + std::to_string(i) + " ! s.sink_" + std::to_string(i);
  GstElement* pipe = gst_parse_launch(desc.c_str(), nullptr);
  EXPECT_NE(pipe, nullptr);
  std::vector<Bundle> out;
  if (!pipe) return out;
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  std::vector<GstElement*> srcs;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    GstElement* a = gst_bin_get_by_name(GST_BIN(pipe), ("a" + std::to_string(i)).c_str());
    GstCaps* caps = gst_caps_new_simple("video/x-raw", "format", G_TYPE_STRING, "RGBA", "width", G_TYPE_INT, w, "height",
                                        G_TYPE_INT, h, "framerate", GST_TYPE_FRACTION, 30, 1, NULL);
    g_object_set(a, "caps", caps, "format", GST_FORMAT_TIME, "block", FALSE, "max-bytes", guint64(64 << 20), NULL);
    gst_caps_unref(caps);
    srcs.push_back(a);
  }
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  for (std::size_t i = 0; i < frames.size(); ++i) {
    if (shared) {
      cv::Mat m(h, w, CV_8UC4, code_colour(int(i), 0));
      shared->push_back(gst_buffer_new_allocate(nullptr, m.total() * 4, nullptr));
      gst_buffer_fill(shared->back(), 0, m.data, m.total() * 4);
    }
    for (int f : frames[i]) {
      cv::Mat m(h, w, CV_8UC4, code_colour(int(i), f));
      GstBuffer* b = shared ? gst_buffer_copy((*shared)[i]) : gst_buffer_new_allocate(nullptr, m.total() * 4, nullptr);
      if (!shared) gst_buffer_fill(b, 0, m.data, m.total() * 4);
      GST_BUFFER_PTS(b) = gst_util_uint64_scale(guint64(f), GST_SECOND, 30);
      GST_BUFFER_DURATION(b) = gst_util_uint64_scale(guint64(f + 1), GST_SECOND, 30) - GST_BUFFER_PTS(b);
      gst_app_src_push_buffer(GST_APP_SRC(srcs[i]), b);
    }
    gst_app_src_end_of_stream(GST_APP_SRC(srcs[i]));
  }
  const gint64 deadline = g_get_monotonic_time() + 30 * G_TIME_SPAN_SECOND;
  while (g_get_monotonic_time() < deadline && !gst_app_sink_is_eos(GST_APP_SINK(sink))) {
    GstSample* smp = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 50 * GST_MSECOND);
    if (!smp) continue;
    GstBuffer* buf = gst_sample_get_buffer(smp);
    Bundle bundle;
    const GstCapsFeatures* f = gst_caps_get_features(gst_sample_get_caps(smp), 0);
    bundle.cuda = f && gst_caps_features_contains(f, kCudaFeature);
    gpointer state = nullptr;
    while (GstMeta* m = gst_buffer_iterate_meta(buf, &state))
      if (g_strcmp0(g_type_name(m->info->api), "GstStitchBundleMetaAPI") == 0)
        bundle.missing = reinterpret_cast<GstStitchBundleMeta*>(m)->missing_mask;
    for (gint id = 0; id < gint(frames.size()); ++id) {
      GstVideoMeta* vm = gst_buffer_get_video_meta_id(buf, id);
      GstMapInfo map;
      gpointer data = nullptr;
      gint stride = 0;
      if (!vm || !gst_video_meta_map(vm, 0, &map, &data, &stride, GST_MAP_READ)) {
        bundle.views.emplace_back();
        continue;
      }
      bundle.views.push_back(cv::Mat(int(vm->height), int(vm->width), CV_8UC4, data, std::size_t(stride)).clone());
      gst_video_meta_unmap(vm, 0, &map);
    }
    out.push_back(std::move(bundle));
    gst_sample_unref(smp);
  }
  if (before_stop) before_stop(pipe);
  gst_element_set_state(pipe, GST_STATE_NULL);
  for (GstElement* a : srcs) gst_object_unref(a);
  gst_object_unref(sink);
  gst_object_unref(pipe);
  return out;
}

bool uniform(const cv::Mat& m, const cv::Vec4b& colour) {
  return !m.empty() && cv::norm(m, cv::Mat(m.size(), CV_8UC4, colour), cv::NORM_INF) == 0;
}

}  // namespace

// GPU: stitchsync's device path keeps the synchronisation rules of the system-memory one: a
// camera that starts late is black and marked missing, one that ends early repeats its last
// frame; the bundles equal the system-memory ones byte for byte.
TEST(CudaMemorySync, LateAndEndedInputsOnTheDevice) {
  REQUIRE_CUDA_MEMORY();
  const std::vector<std::vector<int>> frames = {{0, 1, 2, 3, 4, 5, 6, 7}, {3, 4, 5}};
  const std::vector<Bundle> gpu = run_sync("", frames, 64, 48), cpu = run_sync("backend=cpu", frames, 64, 48);
  ASSERT_EQ(gpu.size(), 8u);
  ASSERT_EQ(cpu.size(), gpu.size());
  for (std::size_t k = 0; k < gpu.size(); ++k) {
    SCOPED_TRACE("bundle " + std::to_string(k));
    EXPECT_TRUE(gpu[k].cuda);
    EXPECT_FALSE(cpu[k].cuda);
    ASSERT_EQ(gpu[k].views.size(), 2u);
    EXPECT_TRUE(uniform(gpu[k].views[0], code_colour(0, int(k))));
    if (k < 3) {
      EXPECT_EQ(gpu[k].missing, 0x2u);
      EXPECT_TRUE(uniform(gpu[k].views[1], cv::Vec4b(0, 0, 0, 0))) << "a missing view is transparent black";
    } else {
      EXPECT_EQ(gpu[k].missing, 0u);
      EXPECT_TRUE(uniform(gpu[k].views[1], code_colour(1, std::min(int(k), 5)))) << "frame 5 repeated after EOS";
    }
    EXPECT_EQ(gpu[k].missing, cpu[k].missing);
    for (int v = 0; v < 2; ++v) EXPECT_EQ(cv::norm(gpu[k].views[v], cpu[k].views[v], cv::NORM_INF), 0.0) << "view " << v;
  }
}

#ifdef STITCH_HAVE_GST_CUDA
namespace {

// The CUDA context an element's src pad answers a context query with (NULL: none).
GstCudaContext* context_of(GstElement* pipe, const char* name) {
  GstElement* e = gst_bin_get_by_name(GST_BIN(pipe), name);
  if (!e) return nullptr;
  GstPad* pad = gst_element_get_static_pad(e, "src");
  GstQuery* q = gst_query_new_context(GST_CUDA_CONTEXT_TYPE);
  GstCudaContext* ctx = nullptr;
  if (gst_pad_query(pad, q)) {
    GstContext* c = nullptr;
    gst_query_parse_context(q, &c);
    if (c) gst_structure_get(gst_context_get_structure(c), GST_CUDA_CONTEXT_TYPE, GST_TYPE_CUDA_CONTEXT, &ctx, NULL);
  }
  gst_query_unref(q);
  gst_object_unref(pad);
  gst_object_unref(e);
  return ctx;
}

}  // namespace
#endif

#ifdef STITCH_HAVE_GST_CUDA
// GPU: system-memory input whose memory comes back frame after frame (here: the same buffer
// again) is page-locked in stitchsync's context and uploaded straight from it (issue 17): the
// memory is registered with the driver by the end, and the bundles hold the right pixels.
TEST(CudaMemorySync, ReusedInputMemoryIsPageLockedAndUploadedRight) {
  REQUIRE_CUDA_MEMORY();
  const std::vector<std::vector<int>> frames = {{0, 1, 2, 3, 4, 5}, {0, 1, 2, 3, 4, 5}};
  std::vector<GstBuffer*> shared;
  std::vector<int> registered;
  const std::vector<Bundle> gpu = run_sync("", frames, 64, 48, &shared, [&](GstElement* pipe) {
    GstCudaContext* ctx = context_of(pipe, "s");
    ASSERT_NE(ctx, nullptr);
    gst_cuda_context_push(ctx);
    for (GstBuffer* b : shared) {
      GstMapInfo map;
      ASSERT_TRUE(gst_buffer_map(b, &map, GST_MAP_READ));
      cudaPointerAttributes a{};
      const bool ok = cudaPointerGetAttributes(&a, map.data) == cudaSuccess;
      cudaGetLastError();
      registered.push_back(ok && a.type == cudaMemoryTypeHost ? 1 : 0);
      gst_buffer_unmap(b, &map);
    }
    gst_cuda_context_pop(nullptr);
    gst_object_unref(ctx);
  });
  ASSERT_EQ(gpu.size(), 6u);
  for (std::size_t k = 0; k < gpu.size(); ++k) {
    EXPECT_TRUE(gpu[k].cuda);
    for (int v = 0; v < 2; ++v) EXPECT_TRUE(uniform(gpu[k].views[std::size_t(v)], code_colour(v, 0))) << k << " " << v;
  }
  EXPECT_EQ(registered, std::vector<int>({1, 1})) << "the reused input memory was not page-locked";
  for (GstBuffer* b : shared) gst_buffer_unref(b);
}
#endif

// GPU: nvh264dec ! stitchsync ... stitchblend ! cudadownload on the repository's clips: NV12
// stays in CUDA memory into stitchsync, every link is CUDA memory, and every element holds the
// decoders' CUDA context.
TEST(CudaMemoryChain, Nvh264decToCudadownloadInOneContext) {
  REQUIRE_CUDA_MEMORY();
#ifdef STITCH_HAVE_GST_CUDA
  std::string missing;
  if (!elements_exist({"nvh264dec", "cudadownload", "qtdemux", "h264parse"}, missing))
    GTEST_SKIP() << "missing elements: " << missing;
  const char* src = std::getenv("STITCH_SOURCE_DIR");
  const std::string dir = std::string(src ? src : ".") + "/data/limlight_2cam_apartment/";
  const std::string desc =
      "stitchsync name=s ! stitchcalib name=c ! stitchcolor name=col ! stitchblend name=b ! cudadownload ! "
      "video/x-raw,format=RGBA ! appsink name=out sync=false "
      "filesrc location=" + dir + "left.mp4 ! qtdemux ! h264parse ! nvh264dec name=d0 ! queue ! s.sink_0 "
      "filesrc location=" + dir + "right.mp4 ! qtdemux ! h264parse ! nvh264dec name=d1 ! queue ! s.sink_1";
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(desc.c_str(), &err);
  ASSERT_NE(pipe, nullptr) << (err ? err->message : "parse failed");
  watch_caps(pipe);
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "out");
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  int frames = 0;
  std::map<std::string, GstCudaContext*> contexts;
  std::string error;
  const gint64 deadline = g_get_monotonic_time() + 120 * G_TIME_SPAN_SECOND;
  GstBus* bus = gst_element_get_bus(pipe);
  while (g_get_monotonic_time() < deadline && !gst_app_sink_is_eos(GST_APP_SINK(sink)) && error.empty()) {
    if (GstSample* smp = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 50 * GST_MSECOND)) {
      if (frames++ == 0)  // every element is negotiated and running now
        for (const char* name : {"d0", "d1", "s", "c", "col", "b"}) contexts[name] = context_of(pipe, name);
      gst_sample_unref(smp);
    }
    if (GstMessage* m = gst_bus_pop_filtered(bus, GST_MESSAGE_ERROR)) {
      GError* e = nullptr;
      gst_message_parse_error(m, &e, nullptr);
      error = e ? e->message : "error";
      g_clear_error(&e);
      gst_message_unref(m);
    }
  }
  gst_object_unref(bus);
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(sink);
  gst_object_unref(pipe);
  EXPECT_TRUE(error.empty()) << error;
  EXPECT_GT(frames, 10);
  for (const auto& [element, caps] : caps_seen()) std::printf("  %s.src: %s\n", element.c_str(), caps.c_str());
  const auto seen = caps_seen();
  for (const char* d : {"d0", "d1"}) {
    ASSERT_TRUE(seen.count(d)) << d;
    EXPECT_NE(seen.at(d).find(kCudaFeature), std::string::npos) << d << ": " << seen.at(d);
  }
  expect_memory({"s", "c", "col", "b"}, true);
  ASSERT_NE(contexts["s"], nullptr) << "stitchsync answers no CUDA context query";
  for (const auto& [element, ctx] : contexts) {
    EXPECT_EQ(ctx, contexts["s"]) << element << " holds another CUDA context than stitchsync";
    if (ctx) gst_object_unref(ctx);
  }
#endif
}

// time-alignment=auto on CUDA-memory inputs (issue 18): each frame's thumbnail is made on the
// device and read back asynchronously (a page-locked slot per view, taken with the view's next
// frame). Camera 1 started 7 frames after camera 0 (uniform frames whose brightness follows a
// scene of random flashes): the CUDA-memory run must find +7 frames like the system-memory run
// of the same frames, to a fraction of a frame. The system-memory reference runs everywhere;
// the CUDA part needs a device.
namespace {

std::vector<cv::Mat> flash_views(int f, int start1) {
  static const std::vector<unsigned> scene = []() {
    std::mt19937 rng(42);
    std::vector<unsigned> v(4000);
    for (auto& x : v) x = rng();
    return v;
  }();
  std::vector<cv::Mat> views;
  for (int start : {0, start1}) {
    const unsigned h = scene[std::size_t(f + start) % scene.size()];
    const int v = h % 9 == 0 ? 200 : 60 + int((h >> 8) % 8);
    views.emplace_back(120, 160, CV_8UC4, cv::Scalar(v, v, v, 255));
  }
  return views;
}

// The last stitchsync-time-offsets message's offset-1 (frames) and confidence-1; -1000 without.
std::pair<double, double> late_start_offset(const std::string& inputs) {
  gsttest::RunResult r;
  gsttest::run_pipeline_frames("stitchsync name=s time-alignment=auto ! fakesink sync=false " + inputs,
                               [](int f) { return flash_views(f, 7); }, 360, r);
  EXPECT_TRUE(r.errors.empty()) << (r.errors.empty() ? "" : r.errors[0]);
  std::pair<double, double> got{-1000, 0};
  for (const GstStructure* s : r.element_messages) {
    if (!gst_structure_has_name(s, "stitchsync-time-offsets")) continue;
    gint64 off = 0;
    gdouble conf = 0;
    if (gst_structure_get_int64(s, "offset-1", &off) && gst_structure_get_double(s, "confidence-1", &conf))
      got = {double(off) / 1e9 * 30, conf};
  }
  return got;
}

}  // namespace

TEST(CudaMemorySync, TimeAlignmentOnDeviceThumbnailsMatchesSystemMemory) {
  const auto sys = late_start_offset(gsttest::appsrc_inputs(2));
  EXPECT_NEAR(sys.first, 7.0, 0.5) << "system memory";
  EXPECT_GT(sys.second, 0.5) << "system memory";
  REQUIRE_CUDA_MEMORY();
  std::string missing;
  if (!elements_exist({"cudaupload"}, missing)) GTEST_SKIP() << "missing elements: " << missing;
  const auto dev = late_start_offset(appsrc_cuda_inputs(2));
  EXPECT_NEAR(dev.first, 7.0, 0.5) << "CUDA memory";
  EXPECT_GT(dev.second, 0.5) << "CUDA memory";
  // the same thumbnails (bit for bit), one frame later: the same estimate within a quarter frame
  EXPECT_NEAR(dev.first, sys.first, 0.25);
}
