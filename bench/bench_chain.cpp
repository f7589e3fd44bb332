// The whole per-frame core chain, as the elements run it, on the GPU and on the CPU:
//   bundle copy (stitchsync) -> color (stitchcolor: 3D-M on the overlaps + piecewise balance)
//   -> flow warp (stitchflowwarp: pre-warp + bidirectional dense flow + local warp)
//   -> blend (stitchblend: fuse on the canvas, crop and scale into the panorama).
// Two chains: "default" is stitchbin's defaults (stitchflowwarp flow=false passes the bundle
// through, stitchblend warps the frames itself and runs the consensus blend, seam=dp); "flow" has
// the flow warp on (stitchblend fuses the pre-warped views on the canvas, then crops/scales).
// usage: stitch-bench-chain [--json FILE] [--photo PPM] [--frames N] [--cpu-frames N] [--threads N] [--cpu-only]
//        [--chain default|flow|both] [--seam dp|none]
// --chain: which chain(s) to run (default both; rows "CPU"/"CUDA" are the default chain,
// "CPU+flow"/"CUDA+flow" the flow chain). --seam: stitchblend's seam (dp, its default; none: the
// plain weighted mean, as this bench measured before the consensus blend became the default).
// --threads N: the CPU chain on N threads (cv::setNumThreads; default: OpenCV's, every core).
// --hash: the cameras move (a shift of one pixel per frame) and each CPU frame's panorama is
// hashed (FNV-1a), to check that a change keeps the output bit for bit.
// GPU: frames already in device memory. Each stage ends with its stream synchronised (as in
// the elements), so stage and chain times are wall-clock medians over --frames frames.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "ppm.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/color/color.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/warp/flow_warper.hpp"

#include <opencv2/core/utility.hpp>

#ifdef STITCH_HAVE_CUDA
#include "stitch/cuda/cuda_util.hpp"
#endif

using namespace stitch;

namespace {

using Clock = std::chrono::steady_clock;

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

struct StageTimes {
  std::vector<double> copy, color, flow, blend, total;
  double cpu[5] = {0, 0, 0, 0, 0};  // process CPU time (all threads), summed over the frames
};

// CPU time of the whole process (every thread), ms: the work a stage did, whatever the load of
// the machine and the thread count (wall clock on a loaded machine measures the load).
double process_cpu_ms() {
  timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return ts.tv_sec * 1e3 + ts.tv_nsec * 1e-6;
}

// The chain's state for one backend: what the elements hold between frames.
struct Chain {
  Backend backend;
  Rig rig;
  ColorCorrector color;
  std::unique_ptr<FlowWarper> flow;
  Compositor compositor;
  bool flow_on;
  Chain(Backend b, const Rig& r, const CompositorSettings& settings, FlowQuality quality, bool with_flow)
      : backend(b), rig(r), color(b), flow(FlowWarper::create(b)), compositor(b), flow_on(with_flow) {
    ColorOptions co;
    co.method = ColorMethod::Matrix3D;
    co.balance = true;
    color.set_options(co);
    compositor.prepare(rig, settings, flow_on ? CompositorInput::Prewarped : CompositorInput::CameraFrames);
    if (!flow_on) return;
    const OutputGeometry canvas = canvas_geometry(rig);
    FlowWarpSettings fs;
    fs.quality = quality;
    flow->set_settings(fs);
    flow->prepare(compositor.prewarped_placements(), canvas.width, canvas.height);
  }
  // One frame: bundle <- pristine (copy), color in place, flow warp into rois (flow chain), blend.
  void run(const std::function<void()>& copy, const std::vector<ImageView>& bundle, const std::vector<ImageView>& rois,
           const ImageView& out, StageTimes& t) {
    const bool host = backend == Backend::Cpu;
    double c[5] = {0, 0, 0, 0, 0};
    const auto t0 = Clock::now();
    if (host) c[0] = process_cpu_ms();
    copy();
    const auto t1 = Clock::now();
    if (host) c[1] = process_cpu_ms();
    color.process(rig, 1, bundle);
    const auto t2 = Clock::now();
    if (host) c[2] = process_cpu_ms();
    if (flow_on) flow->warp(bundle, rois);
    const auto t3 = Clock::now();
    if (host) c[3] = process_cpu_ms();
    compositor.compose(flow_on ? rois : bundle, out);
    const auto t4 = Clock::now();
    if (host) {
      c[4] = process_cpu_ms();
      for (int k = 0; k < 4; ++k) t.cpu[k] += c[k + 1] - c[k];
      t.cpu[4] += c[4] - c[0];
    }
    auto ms = [](Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
    t.copy.push_back(ms(t0, t1));
    t.color.push_back(ms(t1, t2));
    t.flow.push_back(ms(t2, t3));
    t.blend.push_back(ms(t3, t4));
    t.total.push_back(ms(t0, t4));
  }
};

void print_row(const char* name, const char* pano, const char* backend, const StageTimes& t) {
  const double total = median(t.total);
  std::printf("%-12s %-11s %-9s %8.3f %8.3f %8.3f %8.3f %9.3f %9.0f\n", name, pano, backend, median(t.copy),
              median(t.color), median(t.flow), median(t.blend), total, 1000.0 / total);
}

std::string json_row(const StageTimes& t) {
  char buf[256];
  std::snprintf(buf, sizeof buf, "{\"copy_ms\":%.4f,\"color_ms\":%.4f,\"flowwarp_ms\":%.4f,\"blend_ms\":%.4f,"
                "\"chain_ms\":%.4f,\"panoramas_per_s\":%.1f}", median(t.copy), median(t.color), median(t.flow),
                median(t.blend), median(t.total), 1000.0 / median(t.total));
  return buf;
}

}  // namespace

int main(int argc, char** argv) {
  std::string json_path, photo_path = "build/tests/boat1_1600.ppm";
  int frames = 200, cpu_frames = 10;
  std::string only_case;
  int threads = 0;
  bool cpu_only = false, hash = false;
  std::string chains = "both";
  SeamMode seam = SeamMode::DynamicProgramming;
  FlowQuality quality = FlowQuality::Medium;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else if (!std::strcmp(argv[i], "--photo") && i + 1 < argc) photo_path = argv[++i];
    else if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--cpu-frames") && i + 1 < argc) cpu_frames = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--case") && i + 1 < argc) only_case = argv[++i];
    else if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) threads = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--cpu-only")) cpu_only = true;
    else if (!std::strcmp(argv[i], "--hash")) hash = true;
    else if (!std::strcmp(argv[i], "--chain") && i + 1 < argc) chains = argv[++i];
    else if (!std::strcmp(argv[i], "--seam") && i + 1 < argc)
      seam = std::strcmp(argv[++i], "none") ? SeamMode::DynamicProgramming : SeamMode::None;
    else if (!std::strcmp(argv[i], "--quality") && i + 1 < argc) {
      const std::string q = argv[++i];
      quality = q == "fast" ? FlowQuality::Fast : q == "fine" ? FlowQuality::Fine : FlowQuality::Medium;
    } else {
      std::fprintf(stderr, "usage: %s [--json FILE] [--photo PPM] [--frames N] [--cpu-frames N] [--case CxWxH] "
                           "[--quality fast|medium|fine] [--threads N] [--cpu-only] [--hash] [--chain default|flow|both] "
                           "[--seam dp|none]\n", argv[0]);
      return 2;
    }
  }
  const cv::Mat photo = testdata::read_photo_or_exit(photo_path);
  if (threads > 0) cv::setNumThreads(threads);
  std::printf("CPU threads: %d\n", cv::getNumThreads());
  const bool gpu = !cpu_only && cuda_device_available();
  if (!gpu) std::printf("no CUDA device: CPU chain only\n");
  try {
    const std::vector<stitch_bench::Case> cases = {
        {3, 640, 480}, {2, 1920, 1080}, {3, 1920, 1080}, {3, 3840, 2160}, {6, 1920, 1080}};
    std::printf("%-12s %-11s %-9s %8s %8s %8s %8s %9s %9s\n", "cameras", "panorama", "path", "copy", "color",
                "flowwarp", "blend", "chain ms", "pano/s");
    const char* qname = quality == FlowQuality::Fast ? "fast" : quality == FlowQuality::Fine ? "fine" : "medium";
    std::printf("flow quality %s\n", qname);
    std::string json = std::string("{\"flow_quality\":\"") + qname + "\",\"cases\":[";
    for (std::size_t ci = 0; ci < cases.size(); ++ci) {
      const stitch_bench::Case& c = cases[ci];
      const Rig rig = stitch_bench::ring(c);
      std::vector<cv::Mat> pristine = stitch_bench::ring_views(photo, c);
      CompositorSettings settings;
      settings.crop = CropMode::Auto;
      settings.output_width = int(0.85 * c.cameras * c.width) / 2 * 2;  // the paper's 3x1080p -> 4880x1080
      settings.output_height = c.height;
      settings.seam = seam;
      char name[64], pano[64];
      std::snprintf(name, sizeof name, "%dx%dx%d", c.cameras, c.width, c.height);
      if (!only_case.empty() && only_case != name) continue;
      json += std::string(json.back() == '[' ? "" : ",") + "{\"case\":\"" + name + "\"";
      for (const bool with_flow : {false, true}) {
      if (chains != "both" && (chains == "flow") != with_flow) continue;
      const char* cpu_label = with_flow ? "CPU+flow" : "CPU";
      const char* cuda_label = with_flow ? "CUDA+flow" : "CUDA";
      const std::string key = with_flow ? "_flow" : "";
        // Output and pre-warped views (host for the CPU chain; device for the GPU chain).
        std::vector<cv::Mat> bundle(pristine.size());
        std::vector<ImageView> host_bundle, host_rois;
        for (std::size_t i = 0; i < pristine.size(); ++i) {
          bundle[i] = pristine[i].clone();
          host_bundle.push_back(as_view(bundle[i]));
        }
        {
          Chain cpu(Backend::Cpu, rig, settings, quality, with_flow);
          const OutputGeometry& g = cpu.compositor.geometry();
          std::snprintf(pano, sizeof pano, "%dx%d", g.width, g.height);
          std::vector<cv::Mat> rois;
          for (const auto& p : cpu.compositor.prewarped_placements())
            rois.emplace_back(std::max(1, p.roi.height), std::max(1, p.roi.width), CV_8UC4, cv::Scalar::all(0));
          for (auto& r : rois) host_rois.push_back(as_view(r));
          cv::Mat out(g.height, g.width, CV_8UC4);
          int shift = 0;
          auto copy = [&] {
            for (std::size_t i = 0; i < pristine.size(); ++i) {
              if (!hash) {  // by row strips on every thread, as stitchsync's staging copy runs on several cores
                cv::parallel_for_(cv::Range(0, bundle[i].rows), [&](const cv::Range& r) {
                  pristine[i].rowRange(r.start, r.end).copyTo(bundle[i].rowRange(r.start, r.end));
                });
                continue;
              }
              const cv::Matx23d m(1, 0, double(shift), 0, 1, 0.5 * shift);
              cv::warpAffine(pristine[i], bundle[i], m, bundle[i].size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
            }
          };
          auto print_hash = [&] {
            uint64_t h = 1469598103934665603ull;
            for (int y = 0; y < out.rows; ++y)
              for (int x = 0; x < out.cols * 4; ++x) h = (h ^ out.ptr<uint8_t>(y)[x]) * 1099511628211ull;
            std::printf("frame %d hash %016llx\n", shift, (unsigned long long)h);
            ++shift;
          };
          StageTimes t, warm;
          cpu.run(copy, host_bundle, host_rois, as_view(out), warm);
          if (hash) print_hash();
          for (int k = 0; k < cpu_frames; ++k) {
            cpu.run(copy, host_bundle, host_rois, as_view(out), t);
            if (hash) print_hash();
          }
          if (cpu_frames > 0) {
            print_row(name, pano, cpu_label, t);
            const double n = double(cpu_frames);
            std::printf("  CPU time ms per panorama, all threads (the work): copy %.1f color %.1f flowwarp %.1f blend "
                        "%.1f chain %.1f\n", t.cpu[0] / n, t.cpu[1] / n, t.cpu[2] / n, t.cpu[3] / n, t.cpu[4] / n);
            if (!with_flow || chains == "flow") json += ",\"panorama\":\"" + std::string(pano) + "\"";
            json += ",\"cpu" + key + "\":" + json_row(t);
          }
        }
#ifdef STITCH_HAVE_CUDA
        if (gpu) {
          Chain cuda(Backend::Cuda, rig, settings, quality, with_flow);
          const OutputGeometry& g = cuda.compositor.geometry();
          std::vector<DeviceBuffer> src, dst, rois;
          std::vector<ImageView> dev_bundle, dev_rois;
          auto device_view = [](DeviceBuffer& b, int w, int h) {
            b.resize(std::size_t(std::max(1, w)) * std::max(1, h) * 4);
            ImageView v;
            v.data = b.data();
            v.pitch = std::size_t(w) * 4;
            v.width = w;
            v.height = h;
            v.on_device = true;
            return v;
          };
          src.resize(pristine.size());
          dst.resize(pristine.size());
          for (std::size_t i = 0; i < pristine.size(); ++i) {
            const ImageView s = device_view(src[i], c.width, c.height);
            STITCH_CUDA(cudaMemcpy(s.data, pristine[i].data, pristine[i].total() * 4, cudaMemcpyHostToDevice));
            dev_bundle.push_back(device_view(dst[i], c.width, c.height));
          }
          rois.resize(pristine.size());
          for (std::size_t i = 0; i < pristine.size(); ++i) {
            const Rect& r = cuda.compositor.prewarped_placements()[i].roi;
            dev_rois.push_back(device_view(rois[i], r.width, r.height));
          }
          DeviceBuffer out_buf;
          const ImageView out = device_view(out_buf, g.width, g.height);
          CudaStream stream;
          auto copy = [&] {  // stitchsync's device-to-device copy of each camera into the bundle
            for (std::size_t i = 0; i < pristine.size(); ++i)
              STITCH_CUDA(cudaMemcpy2DAsync(dev_bundle[i].data, dev_bundle[i].pitch, src[i].data(), std::size_t(c.width) * 4,
                                            std::size_t(c.width) * 4, c.height, cudaMemcpyDeviceToDevice, stream.get()));
            stream.sync();
          };
          StageTimes t, warm;
          for (int k = 0; k < 10; ++k) cuda.run(copy, dev_bundle, dev_rois, out, warm);
          for (int k = 0; k < frames; ++k) cuda.run(copy, dev_bundle, dev_rois, out, t);
          print_row(name, pano, cuda_label, t);
          json += ",\"cuda" + key + "\":" + json_row(t);
        }
#endif
      }
      json += "}";
    }
    json += "]}\n";
    std::printf("ms per panorama (median wall clock; every stage synchronised as in the elements). copy: the\n"
                "bundle copy stitchsync does; color: 3D-M + balance; flowwarp: medium quality (+flow rows; none in\n"
                "the default chain); blend: warp + fuse (+ seams) on the output, or fuse on the canvas + crop/scale.\n");
    if (!json_path.empty()) std::ofstream(json_path) << json;
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
