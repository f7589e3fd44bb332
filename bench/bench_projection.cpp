// Cost of the projections: the per-frame compose (warp + blend) of one rig on a planar,
// cylindrical and spherical canvas of the same output size, and of a 360-degree ring of 6
// cameras (one view crosses the wrap and is evaluated over the full width); CPU, and the CUDA
// Compositor on device-memory frames when a device opens; plus the calibration of a ring
// (features + bundle adjustment + wave correction). Baseline in the same run: the planar canvas,
// and copying every input and output byte once.
// usage: stitch-bench-projection [--photo PPM] [--frames N] [--json FILE]
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "ppm.hpp"
#include "ring_rig.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/cv_interop.hpp"

#ifdef STITCH_HAVE_CUDA
#include <cuda_runtime_api.h>
#endif

using namespace stitch;

namespace {

double now_ms() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

struct Timing {
  int width = 0, height = 0;
  long evaluated = 0;  // output pixels the views' rectangles cover, summed over the views
  double cpu_ms = 0, cuda_ms = -1, copy_ms = 0;
};

Timing time_compose(const Rig& rig, std::vector<cv::Mat>& frames, const CompositorSettings& s, int reps) {
  Timing t;
  std::vector<ImageView> host;
  for (auto& f : frames) host.push_back(as_view(f));
  Compositor cpu(Backend::Cpu);
  cpu.prepare(rig, s);
  t.width = cpu.geometry().width;
  t.height = cpu.geometry().height;
  for (const auto& v : place_views(rig, cpu.geometry())) t.evaluated += long(v.roi.width) * v.roi.height;
  cv::Mat out(t.height, t.width, CV_8UC4), copy(out.size(), out.type());
  cpu.compose(host, as_view(out));
  double t0 = now_ms();
  for (int k = 0; k < reps; ++k) cpu.compose(host, as_view(out));
  t.cpu_ms = (now_ms() - t0) / reps;
  std::vector<cv::Mat> copies(frames.size());
  t0 = now_ms();
  for (int k = 0; k < reps; ++k) {
    for (std::size_t i = 0; i < frames.size(); ++i) frames[i].copyTo(copies[i]);
    out.copyTo(copy);
  }
  t.copy_ms = (now_ms() - t0) / reps;
#ifdef STITCH_HAVE_CUDA
  if (cuda_device_available()) {
    std::vector<void*> dev;
    std::vector<ImageView> dv;
    for (auto& f : frames) {
      void* p = nullptr;
      cudaMalloc(&p, f.total() * 4);
      cudaMemcpy(p, f.data, f.total() * 4, cudaMemcpyHostToDevice);
      dev.push_back(p);
      ImageView v = as_view(f);
      v.data = static_cast<uint8_t*>(p);
      v.pitch = std::size_t(f.cols) * 4;
      v.on_device = true;
      dv.push_back(v);
    }
    void* o = nullptr;
    cudaMalloc(&o, out.total() * 4);
    ImageView ov = as_view(out);
    ov.data = static_cast<uint8_t*>(o);
    ov.pitch = std::size_t(out.cols) * 4;
    ov.on_device = true;
    Compositor gpu(Backend::Cuda);
    gpu.prepare(rig, s);
    for (int k = 0; k < 5; ++k) gpu.compose(dv, ov);
    cudaDeviceSynchronize();
    const int gpu_reps = reps * 20;
    t0 = now_ms();
    for (int k = 0; k < gpu_reps; ++k) gpu.compose(dv, ov);
    cudaDeviceSynchronize();
    t.cuda_ms = (now_ms() - t0) / gpu_reps;
    for (void* p : dev) cudaFree(p);
    cudaFree(o);
  }
#endif
  return t;
}

}  // namespace

int main(int argc, char** argv) {
  std::string photo_path = "build/tests/boat1_1600.ppm", json_path;
  int reps = 10;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--photo") && i + 1 < argc) photo_path = argv[++i];
    else if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) reps = std::max(1, std::atoi(argv[++i]));
    else if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else {
      std::fprintf(stderr, "usage: %s [--photo PPM] [--frames N] [--json FILE]\n", argv[0]);
      return 2;
    }
  }
  const cv::Mat photo = testdata::read_photo_or_exit(photo_path);
  std::printf("%-34s %-11s %9s %10s %10s %10s %10s\n", "case", "output", "eval/out", "CPU ms", "CUDA ms", "memcpy ms",
              "CPU/CUDA");
  std::string json = "{\"cases\":[";
  auto report = [&](const std::string& name, const Timing& t) {
    std::printf("%-34s %5dx%-5d %9.2f %10.2f %10.3f %10.2f %10.1f\n", name.c_str(), t.width, t.height,
                double(t.evaluated) / (double(t.width) * t.height), t.cpu_ms, t.cuda_ms, t.copy_ms,
                t.cuda_ms > 0 ? t.cpu_ms / t.cuda_ms : 0.0);
    json += std::string(json.back() == '[' ? "" : ",") + "{\"case\":\"" + name + "\",\"width\":" +
            std::to_string(t.width) + ",\"height\":" + std::to_string(t.height) + ",\"cpu_ms\":" +
            std::to_string(t.cpu_ms) + ",\"cuda_ms\":" + std::to_string(t.cuda_ms) + ",\"memcpy_ms\":" +
            std::to_string(t.copy_ms) + "}";
  };
  // One rotating rig (3 x 1080p, ~100 degrees) on each canvas, the same output size.
  const stitch_bench::Case c{3, 1920, 1080};
  std::vector<cv::Mat> views = stitch_bench::ring_views(photo, c);
  CompositorSettings s;
  s.crop = CropMode::Auto;
  s.output_width = int(0.85 * c.cameras * c.width) / 2 * 2;
  s.output_height = c.height;
  for (Projection p : {Projection::Plane, Projection::Cylindrical, Projection::Spherical}) {
    Rig rig = stitch_bench::ring(c);
    if (p != Projection::Plane) {
      rig.projection = projection_name(p);
      for (auto& cam : rig.cameras) cam.homography.reset();
      rig_layout_canvas(rig);
    }
    report(std::string("3x1920x1080 ") + projection_name(p), time_compose(rig, views, s, reps));
  }
  // A 360-degree ring of 6 x 1080p (80-degree lenses) at full canvas resolution.
  for (Projection p : {Projection::Cylindrical, Projection::Spherical}) {
    const double f = 960 / std::tan(40 * CV_PI / 180);
    testdata::RingScene ring = testdata::render_ring(photo, 6, 1920, 1080, f, p, 0.0, 60.0);
    rig_layout_canvas(ring.truth);
    report(std::string("ring 6x1920x1080 360deg ") + projection_name(p), time_compose(ring.truth, ring.frames, {}, reps));
  }
  // Calibration of a ring of 6 x 640x480 from rough parameters (a few degrees and % off).
  for (Projection p : {Projection::Cylindrical, Projection::Spherical}) {
    testdata::RingScene ring = testdata::render_ring(photo, 6, 640, 480, 400.0, p, 0.0, 60.0);
    Rig rough = ring.truth;
    for (int i = 0; i < 6; ++i) {
      rough.cameras[i].yaw_deg += 2.5 * std::sin(1.7 * i + 0.3);
      rough.cameras[i].pitch_deg += 1.5 * std::cos(2.3 * i);
      rough.cameras[i].fx = rough.cameras[i].fy = 400 * (1 + 0.03 * std::cos(1.1 * i));
    }
    std::vector<ImageView> fv;
    for (auto& f : ring.frames) fv.push_back(as_view(f));
    const double t0 = now_ms();
    const CalibrationResult r = calibrate_from_rig(rough, fv, CalibrationOptions{});
    const double ms = now_ms() - t0;
    const AlignmentReport a = measure_alignment(r.rig, fv);
    std::printf("calibration, ring 6x640x480 %s: %.0f ms (SIFT + matching + bundle adjustment + wave correction), "
                "BA rms %.2f -> %.3f px, alignment median %.3f px over %d matches\n",
                projection_name(p), ms, r.ba_rms_before_px, r.ba_rms_after_px, a.median_px, a.matches);
    json += std::string(",{\"case\":\"calibration ring 6x640x480 ") + projection_name(p) + "\",\"ms\":" +
            std::to_string(ms) + ",\"ba_rms_after_px\":" + std::to_string(r.ba_rms_after_px) +
            ",\"alignment_median_px\":" + std::to_string(a.median_px) + "}";
  }
  json += "]}\n";
  if (!json_path.empty()) std::ofstream(json_path) << json;
  return 0;
}
