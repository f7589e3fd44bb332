// What each blend mode costs per panorama, on the CPU and on the GPU: stitchblend's work on
// views stitchflowwarp pre-warped onto the canvas (fuse, then crop and scale into the output),
// for the weighted mean (the baseline, measured in the same run), multiband, multiband with
// DP seams, and the consensus blend (the weighted mean with DP seams and the mix map). GPU: views and panorama in device memory; wall-clock medians, stream synchronised.
// usage: stitch-bench-blend [--json FILE] [--photo PPM] [--frames N] [--cpu-frames N] [--bands N] [--case NxWxH]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "ppm.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/warp/warper.hpp"

#ifdef STITCH_HAVE_CUDA
#include "stitch/cuda/cuda_util.hpp"
#endif

using namespace stitch;

namespace {

using Clock = std::chrono::steady_clock;

struct Mode {
  const char* name;
  BlendMode blend;
  SeamMode seam;
};
const Mode kModes[] = {{"weighted", BlendMode::Weighted, SeamMode::None},
                       {"multiband", BlendMode::Multiband, SeamMode::None},
                       {"multiband+dp", BlendMode::Multiband, SeamMode::DynamicProgramming},
                       // the consensus blend (stitchblend's default since issue 16)
                       {"consensus", BlendMode::Weighted, SeamMode::DynamicProgramming}};
constexpr int kNumModes = int(sizeof kModes / sizeof kModes[0]);

// Median ms of `frames` compose() calls after one warm-up.
double time_compose(Compositor& c, const std::vector<ImageView>& views, const ImageView& out, int frames) {
  c.compose(views, out);
  std::vector<double> t;
  for (int k = 0; k < frames; ++k) {
    const auto t0 = Clock::now();
    c.compose(views, out);
    t.push_back(std::chrono::duration<double, std::milli>(Clock::now() - t0).count());
  }
  std::sort(t.begin(), t.end());
  return t[t.size() / 2];
}

}  // namespace

int main(int argc, char** argv) {
  std::string json_path, photo_path = "build/tests/boat1_1600.ppm";
  int frames = 100, cpu_frames = 5, bands = MultibandBlender::kDefaultBands;
  std::vector<stitch_bench::Case> cases = {{3, 640, 480}, {2, 1920, 1080}, {3, 1920, 1080}, {6, 1920, 1080}};
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else if (!std::strcmp(argv[i], "--photo") && i + 1 < argc) photo_path = argv[++i];
    else if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--cpu-frames") && i + 1 < argc) cpu_frames = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--bands") && i + 1 < argc) bands = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--case") && i + 1 < argc) {  // NxWxH: one size
      stitch_bench::Case c{};
      if (!stitch_bench::parse_case(argv[++i], c)) return 2;
      cases = {c};
    } else {
      std::fprintf(stderr, "usage: %s [--json FILE] [--photo PPM] [--frames N] [--cpu-frames N] [--bands N] [--case NxWxH]\n", argv[0]);
      return 2;
    }
  }
  const cv::Mat photo = testdata::read_photo_or_exit(photo_path);
  const bool gpu = cuda_device_available();
  if (!gpu) std::printf("no CUDA device: CPU only\n");
  try {
    std::printf("blend stage, ms per panorama (median); %d bands\n", bands);
    std::printf("%-12s %-11s %-5s %10s %10s %13s %10s %10s %13s %11s\n", "cameras", "panorama", "path", "weighted",
                "multiband", "multiband+dp", "consensus", "+multiband", "+multiband+dp", "+consensus");
    std::string json = "{\"bands\":" + std::to_string(bands) + ",\"cases\":[";
    for (const stitch_bench::Case& c : cases) {
      const Rig rig = stitch_bench::ring(c);
      std::vector<cv::Mat> frames_in = stitch_bench::ring_views(photo, c);
      CompositorSettings settings;
      settings.crop = CropMode::Auto;
      settings.output_width = int(0.85 * c.cameras * c.width) / 2 * 2;  // as stitch-bench-chain
      settings.output_height = c.height;
      settings.bands = bands;
      // The views pre-warped onto the canvas once (stitchflowwarp's output).
      Compositor planner(Backend::Cpu);
      planner.prepare(rig, settings, CompositorInput::Prewarped);
      const std::vector<ViewPlacement>& placements = planner.prewarped_placements();
      auto warper = Warper::create(Backend::Cpu);
      warper->prepare(placements);
      std::vector<cv::Mat> rois;
      std::vector<ImageView> host;
      for (std::size_t i = 0; i < placements.size(); ++i) {
        rois.emplace_back(std::max(1, placements[i].roi.height), std::max(1, placements[i].roi.width), CV_8UC4,
                          cv::Scalar::all(0));
        if (!placements[i].roi.empty()) warper->warp(int(i), as_view(frames_in[i]), as_view(rois.back()));
        host.push_back(placements[i].roi.empty() ? ImageView() : as_view(rois.back()));
      }
      const OutputGeometry& g = planner.geometry();
      char name[64], pano[64];
      std::snprintf(name, sizeof name, "%dx%dx%d", c.cameras, c.width, c.height);
      std::snprintf(pano, sizeof pano, "%dx%d", g.width, g.height);
      json += std::string(json.back() == '[' ? "" : ",") + "{\"case\":\"" + name + "\",\"panorama\":\"" + pano + "\"";
      auto report = [&](const char* path, const double ms[3]) {
        std::printf("%-12s %-11s %-5s %10.3f %10.3f %13.3f %10.3f %10.3f %13.3f %11.3f\n", name, pano, path, ms[0],
                    ms[1], ms[2], ms[3], ms[1] - ms[0], ms[2] - ms[0], ms[3] - ms[0]);
        char buf[320];
        std::snprintf(buf, sizeof buf,
                      ",\"%s\":{\"weighted_ms\":%.4f,\"multiband_ms\":%.4f,\"multiband_dp_ms\":%.4f,\"consensus_ms\":%.4f}",
                      path, ms[0], ms[1], ms[2], ms[3]);
        json += buf;
      };
      // Every mode on one backend, from the same views into the same output.
      auto time_modes = [&](Backend backend, const std::vector<ImageView>& views, const ImageView& out, int n,
                            const char* path) {
        double ms[kNumModes];
        for (int m = 0; m < kNumModes; ++m) {
          CompositorSettings s = settings;
          s.blend = kModes[m].blend;
          s.seam = kModes[m].seam;
          Compositor comp(backend);
          comp.prepare(rig, s, CompositorInput::Prewarped);
          ms[m] = time_compose(comp, views, out, n);
        }
        report(path, ms);
      };
      if (cpu_frames > 0) {
        cv::Mat out(g.height, g.width, CV_8UC4);
        time_modes(Backend::Cpu, host, as_view(out), cpu_frames, "CPU");
      }
#ifdef STITCH_HAVE_CUDA
      if (gpu) {
        std::vector<DeviceBuffer> dev(host.size());
        std::vector<ImageView> dv(host.size());
        for (std::size_t i = 0; i < host.size(); ++i) {
          if (host[i].empty()) continue;
          dev[i].resize(host[i].pitch * host[i].height);
          STITCH_CUDA(cudaMemcpy(dev[i].data(), host[i].data, host[i].pitch * host[i].height, cudaMemcpyHostToDevice));
          dv[i] = host[i];
          dv[i].data = dev[i].data();
          dv[i].on_device = true;
        }
        DeviceBuffer out_buf(std::size_t(g.width) * g.height * 4);
        const ImageView out{out_buf.data(), std::size_t(g.width) * 4, g.width, g.height, PixelFormat::RGBA8, true};
        time_modes(Backend::Cuda, dv, out, frames, "GPU");
      }
#endif
      json += "}";
    }
    json += "]}";
    if (!json_path.empty()) std::ofstream(json_path) << json << "\n";
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 0;
}
