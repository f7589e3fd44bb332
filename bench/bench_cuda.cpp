// CUDA per-frame path, timed with CUDA events, against the measured device-to-device copy
// bandwidth and the CPU path in the same run.
// usage: stitch-bench-cuda [--json FILE] [--photo PPM] [--cpu-frames N]
// For each rig size: the fused compose kernel (warp + blend, with and without the per-view
// color matrix) on frames already in device memory; the separate warp, fuse and color-apply
// kernels; the Compositor from system memory (upload + compose + download); the CPU Compositor.
#include <cuda_runtime_api.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "../cuda/color/color_kernels.hpp"
#include "bench_common.hpp"
#include "ppm.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/cuda/view_geometry.hpp"
#include "stitch/cv_interop.hpp"

using namespace stitch;

namespace {

// Median over `repeats` batches of the time per call of `body` (CUDA events, one stream).
template <typename F>
double time_ms(cudaStream_t stream, F&& body, int batch = 50, int repeats = 7) {
  cudaEvent_t a, b;
  STITCH_CUDA(cudaEventCreate(&a));
  STITCH_CUDA(cudaEventCreate(&b));
  for (int k = 0; k < 5; ++k) body();  // warm-up
  std::vector<float> per_call;
  for (int r = 0; r < repeats; ++r) {
    STITCH_CUDA(cudaEventRecord(a, stream));
    for (int k = 0; k < batch; ++k) body();
    STITCH_CUDA(cudaEventRecord(b, stream));
    STITCH_CUDA(cudaEventSynchronize(b));
    float ms = 0;
    STITCH_CUDA(cudaEventElapsedTime(&ms, a, b));
    per_call.push_back(ms / batch);
  }
  cudaEventDestroy(a);
  cudaEventDestroy(b);
  std::sort(per_call.begin(), per_call.end());
  return per_call[per_call.size() / 2];
}

stitch_cuda::DeviceImage device_image(uint8_t* data, int width, int height) {
  stitch_cuda::DeviceImage d;
  d.data = data;
  d.pitch = std::size_t(width) * 4;
  d.width = width;
  d.height = height;
  return d;
}

}  // namespace

int main(int argc, char** argv) {
  std::string json_path, photo_path = "build/tests/boat1_1600.ppm";
  int cpu_frames = 10;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else if (!std::strcmp(argv[i], "--photo") && i + 1 < argc) photo_path = argv[++i];
    else if (!std::strcmp(argv[i], "--cpu-frames") && i + 1 < argc) cpu_frames = std::atoi(argv[++i]);
    else {
      std::fprintf(stderr, "usage: %s [--json FILE] [--photo PPM] [--cpu-frames N]\n", argv[0]);
      return 2;
    }
  }
  if (!cuda_device_available()) {
    std::fprintf(stderr, "no CUDA device: nothing to measure\n");
    return 77;
  }
  // A real photo as binary PPM (the build decodes data/photos/boat1_1600.jpg to it): this
  // binary links no imgcodecs, so that it fits the bundle carried to the GPU host.
  const cv::Mat photo = testdata::read_photo_or_exit(photo_path);
  try {
    cudaDeviceProp prop{};
    STITCH_CUDA(cudaGetDeviceProperties(&prop, 0));
    CudaStream stream;
    // The ceiling: a large device-to-device copy, bytes read + written.
    const std::size_t copy_bytes = std::size_t(1) << 30;
    DeviceBuffer ca(copy_bytes), cb(copy_bytes);
    STITCH_CUDA(cudaMemsetAsync(ca.data(), 1, copy_bytes, stream.get()));
    const double copy_ms = time_ms(stream.get(), [&] {
      STITCH_CUDA(cudaMemcpyAsync(cb.data(), ca.data(), copy_bytes, cudaMemcpyDeviceToDevice, stream.get()));
    }, 5, 5);
    const double copy_gbs = 2.0 * copy_bytes / (copy_ms * 1e-3) / 1e9;
    std::printf("device: %s, %d SMs; device-to-device copy %.0f GB/s (read + write)\n", prop.name,
                prop.multiProcessorCount, copy_gbs);

    const std::vector<stitch_bench::Case> cases = {
        {3, 640, 480}, {2, 1920, 1080}, {3, 1920, 1080}, {3, 3840, 2160}, {6, 1920, 1080}};
    std::printf("%-12s %-11s %9s %9s %7s %9s %7s %9s %9s %9s %10s %10s %9s\n", "cameras", "panorama", "compose",
                "+color", "%copy", "tex", "%copy", "warp", "fuse", "colorapp", "sysmem ms", "CPU ms", "CPU/GPU");
    std::string json = "{\"device\":\"" + std::string(prop.name) + "\",\"copy_gbs\":" + std::to_string(copy_gbs) +
                       ",\"cases\":[";
    for (std::size_t ci = 0; ci < cases.size(); ++ci) {
      const stitch_bench::Case& c = cases[ci];
      const Rig rig = stitch_bench::ring(c);
      std::vector<cv::Mat> views = stitch_bench::ring_views(photo, c);
      CompositorSettings settings;
      settings.crop = CropMode::Auto;
      settings.output_width = int(0.85 * c.cameras * c.width) / 2 * 2;  // the paper's 3x1080p -> 4880x1080
      settings.output_height = c.height;
      const OutputGeometry g = plan_output(rig, settings.output_width, settings.output_height, settings.crop);
      const std::vector<ViewPlacement> places = place_views(rig, g);

      std::vector<DeviceBuffer> in;
      std::vector<stitch_cuda::DeviceImage> frames;
      std::vector<stitch_cuda::ViewGeometry> geo;
      std::size_t in_bytes = 0;
      for (int i = 0; i < c.cameras; ++i) {
        in.emplace_back(std::size_t(c.width) * c.height * 4);
        STITCH_CUDA(cudaMemcpy(in.back().data(), views[i].data, std::size_t(c.width) * c.height * 4,
                               cudaMemcpyHostToDevice));
        frames.push_back(device_image(in.back().data(), c.width, c.height));
        geo.push_back(to_device_geometry(places[i]));
        in_bytes += std::size_t(c.width) * c.height * 4;
      }
      DeviceBuffer out_buf(std::size_t(g.width) * g.height * 4);
      const stitch_cuda::DeviceImage out = device_image(out_buf.data(), g.width, g.height);
      const std::size_t out_bytes = std::size_t(g.width) * g.height * 4;
      std::vector<float> color(9 * c.cameras, 0.f);
      for (int i = 0; i < c.cameras; ++i) {
        color[9 * i + 0] = 1.05f;
        color[9 * i + 4] = 0.97f;
        color[9 * i + 8] = 1.02f;
        color[9 * i + 1] = 0.01f;
      }
      // The compose as the compositor runs it: with the fuse's tiles (made once per geometry);
      // and without, for comparison.
      DeviceBuffer tiles(stitch_cuda::fuse_tile_count(out.width, out.height));
      stitch_cuda::launch_fuse_tiles(c.cameras, geo.data(), out.width, out.height, tiles.data(), stream.get());
      const double compose_ms = time_ms(stream.get(), [&] {
        stitch_cuda::launch_compose(c.cameras, geo.data(), frames.data(), nullptr, out, stream.get(), tiles.data());
      });
      const double compose_untiled_ms = time_ms(stream.get(), [&] {
        stitch_cuda::launch_compose(c.cameras, geo.data(), frames.data(), nullptr, out, stream.get());
      });
      std::vector<unsigned long long> tex;
      for (auto& f : frames) tex.push_back(stitch_cuda::create_rgba_texture(f));
      const double tex_ms = time_ms(stream.get(), [&] {
        stitch_cuda::launch_compose_tex(c.cameras, geo.data(), tex.data(), nullptr, out, stream.get(), tiles.data());
      });
      const double tex_untiled_ms = time_ms(stream.get(), [&] {
        stitch_cuda::launch_compose_tex(c.cameras, geo.data(), tex.data(), nullptr, out, stream.get());
      });
      std::printf("  compose without tiles: %.4f ms (gathers), %.4f ms (texture)\n", compose_untiled_ms, tex_untiled_ms);
      const double color_compose_ms = time_ms(stream.get(), [&] {
        stitch_cuda::launch_compose(c.cameras, geo.data(), frames.data(), color.data(), out, stream.get(), tiles.data());
      });
      // The unfused stages, for comparison: warp each view into its roi, then fuse.
      std::vector<DeviceBuffer> rois;
      std::vector<stitch_cuda::DeviceImage> warped;
      std::size_t roi_bytes = 0;
      for (int i = 0; i < c.cameras; ++i) {
        const Rect& r = places[i].roi;
        rois.emplace_back(std::size_t(std::max(1, r.width)) * std::max(1, r.height) * 4);
        warped.push_back(device_image(rois.back().data(), r.width, r.height));
        roi_bytes += std::size_t(r.width) * r.height * 4;
      }
      // The warp as the compositor runs it: every view in one launch, the texture units' bilinear
      // taps; and one launch per view with gathers, for comparison.
      const double warp_ms = time_ms(stream.get(), [&] {
        stitch_cuda::launch_warps(c.cameras, frames.data(), geo.data(), warped.data(), nullptr, tex.data(), stream.get());
      });
      const double warp_gathers_ms = time_ms(stream.get(), [&] {
        for (int i = 0; i < c.cameras; ++i) stitch_cuda::launch_warp(frames[i], geo[i], warped[i], stream.get());
      });
      std::printf("  warp with gathers, a launch per view: %.4f ms\n", warp_gathers_ms);
      for (auto t : tex) stitch_cuda::destroy_texture(t);
      // The fuse as the compositor runs it: with its tiles, and without.
      const double fuse_ms = time_ms(stream.get(), [&] {
        stitch_cuda::launch_fuse(c.cameras, geo.data(), warped.data(), out, stream.get(), nullptr, nullptr, tiles.data());
      });
      const double fuse_untiled_ms = time_ms(stream.get(), [&] {
        stitch_cuda::launch_fuse(c.cameras, geo.data(), warped.data(), out, stream.get());
      });
      std::printf("  fuse without tiles: %.4f ms\n", fuse_untiled_ms);
      const double apply_ms = time_ms(stream.get(), [&] {
        for (int i = 0; i < c.cameras; ++i)
          stitch_cuda::launch_color_apply(frames[i].data, frames[i].pitch, c.width, c.height, color.data() + 9 * i,
                                          nullptr, stream.get());
      });
      // From system memory through the Compositor (pageable upload, compose, download).
      Compositor gpu(Backend::Cuda), cpu(Backend::Cpu);
      gpu.prepare(rig, settings);
      cpu.prepare(rig, settings);
      std::vector<ImageView> host;
      for (auto& v : views) host.push_back(as_view(v));
      cv::Mat pano(g.height, g.width, CV_8UC4);
      for (int k = 0; k < 3; ++k) gpu.compose(host, as_view(pano));
      const int sys_frames = 30;
      auto t0 = std::chrono::steady_clock::now();
      for (int k = 0; k < sys_frames; ++k) gpu.compose(host, as_view(pano));
      const double sys_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / sys_frames;
      cpu.compose(host, as_view(pano));
      t0 = std::chrono::steady_clock::now();
      for (int k = 0; k < cpu_frames; ++k) cpu.compose(host, as_view(pano));
      const double cpu_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / cpu_frames;

      // A copy moving the same bytes as each kernel (read + write): the ceiling at this size,
      // launch and tail included (a 3 x 640x480 kernel lasts a few microseconds, where the 1 GiB
      // copy's rate is out of reach of any launch).
      const auto same_bytes_copy_ms = [&](std::size_t traffic) {
        const std::size_t n = std::min(copy_bytes, traffic / 2);
        return time_ms(stream.get(), [&] {
          STITCH_CUDA(cudaMemcpyAsync(cb.data(), ca.data(), n, cudaMemcpyDeviceToDevice, stream.get()));
        });
      };
      const double warp_copy_ms = same_bytes_copy_ms(in_bytes + roi_bytes);
      const double fuse_copy_ms = same_bytes_copy_ms(roi_bytes + out_bytes);
      const double compose_copy_ms = same_bytes_copy_ms(in_bytes + out_bytes);
      std::vector<uint8_t> classes(tiles.size());
      STITCH_CUDA(cudaMemcpy(classes.data(), tiles.data(), classes.size(), cudaMemcpyDeviceToHost));
      const double mixed_share =
          double(std::count(classes.begin(), classes.end(), stitch_cuda::kFuseTileMixed)) / double(classes.size());
      std::printf("  a copy of the same bytes: warp %.4f ms (kernel at %.0f%%), fuse %.4f ms (%.0f%%), compose %.4f ms "
                  "(%.0f%% gathers, %.0f%% texture); tiles where views overlap: %.1f%%\n",
                  warp_copy_ms, 100 * warp_copy_ms / warp_ms, fuse_copy_ms, 100 * fuse_copy_ms / fuse_ms, compose_copy_ms,
                  100 * compose_copy_ms / compose_ms, 100 * compose_copy_ms / tex_ms, 100 * mixed_share);
      const double compose_frac = (in_bytes + out_bytes) / (compose_ms * 1e-3) / 1e9 / copy_gbs;
      const double warp_frac = (in_bytes + roi_bytes) / (warp_ms * 1e-3) / 1e9 / copy_gbs;
      const double fuse_frac = (roi_bytes + out_bytes) / (fuse_ms * 1e-3) / 1e9 / copy_gbs;
      const double apply_frac = (2.0 * in_bytes) / (apply_ms * 1e-3) / 1e9 / copy_gbs;
      char name[64], pano_name[64];
      std::snprintf(name, sizeof name, "%dx%dx%d", c.cameras, c.width, c.height);
      std::snprintf(pano_name, sizeof pano_name, "%dx%d", g.width, g.height);
      const double tex_frac = (in_bytes + out_bytes) / (tex_ms * 1e-3) / 1e9 / copy_gbs;
      std::printf("%-12s %-11s %9.4f %9.4f %6.0f%% %9.4f %6.0f%% %9.4f %9.4f %9.4f %10.3f %10.2f %8.0fx\n", name,
                  pano_name, compose_ms, color_compose_ms, 100 * compose_frac, tex_ms, 100 * tex_frac, warp_ms, fuse_ms,
                  apply_ms, sys_ms, cpu_ms, cpu_ms / std::min(compose_ms, tex_ms));
      char buf[1400];
      std::snprintf(buf, sizeof buf,
                    "%s{\"case\":\"%s\",\"panorama\":\"%s\",\"compose_ms\":%.5f,\"compose_color_ms\":%.5f,"
                    "\"compose_bytes\":%zu,\"compose_copy_fraction\":%.3f,\"warp_ms\":%.5f,\"warp_bytes\":%zu,"
                    "\"warp_copy_fraction\":%.3f,\"fuse_ms\":%.5f,\"fuse_bytes\":%zu,\"fuse_copy_fraction\":%.3f,"
                    "\"color_apply_ms\":%.5f,\"color_apply_bytes\":%zu,\"color_apply_copy_fraction\":%.3f,"
                    "\"compose_texture_ms\":%.5f,\"compose_texture_copy_fraction\":%.3f,"
                    "\"system_memory_compose_ms\":%.4f,\"cpu_compose_ms\":%.3f,\"warp_same_bytes_copy_ms\":%.5f,"
                    "\"fuse_same_bytes_copy_ms\":%.5f,\"compose_same_bytes_copy_ms\":%.5f,\"mixed_tile_share\":%.4f}",
                    ci ? "," : "", name, pano_name, compose_ms, color_compose_ms, in_bytes + out_bytes, compose_frac,
                    warp_ms, in_bytes + roi_bytes, warp_frac, fuse_ms, roi_bytes + out_bytes, fuse_frac, apply_ms,
                    2 * in_bytes, apply_frac, tex_ms, tex_frac, sys_ms, cpu_ms, warp_copy_ms, fuse_copy_ms,
                    compose_copy_ms, mixed_share);
      json += buf;
    }
    json += "]}\n";
    std::printf("compose/warp/fuse/colorapp: ms per panorama on device-resident frames (CUDA events, median);\n"
                "%%copy: (input + output bytes) / time as a fraction of the device-to-device copy rate;\n"
                "sysmem: Compositor from system memory (upload + compose + download), wall clock.\n");
    if (!json_path.empty()) std::ofstream(json_path) << json;
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
