// stitch-bench-lens (issue 15): what the lens model buys and costs.
//
//   stitch-bench-lens --photo PANO [--size 320]   quality: rigs rendered from PANO (taken as an
//       equirectangular 360-degree photo) through their lenses, stitched on the CPU with the TRUE
//       calibration, lens on vs the same rig with the lens ignored: PSNR against the ground
//       truth, and straightness (the worst deviation from its chord, canvas pixels, of scene
//       lines seen through each camera and mapped to the plane canvas).
//   stitch-bench-lens --timing [--backend cuda|cpu] [--iterations 50]   what the lens costs per
//       panorama in compose and in the flow warp (frames already in the backend's memory):
//       3 x 1920x1080 radtan on a plane vs the same rig pinhole, and 2 x 3840x3840 200-degree
//       fisheyes to a 7680x3840 sphere.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#ifndef STITCH_LENS_TIMING_ONLY
#include <opencv2/imgcodecs.hpp>
#endif
#include <string>

#include "image_compare.hpp"
#include "lens_rig.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "stitch/warp/flow_warper.hpp"
#include "stitch/warp/geometry.hpp"
#ifdef STITCH_HAVE_CUDA
#include "stitch/cuda/cuda_util.hpp"
#endif

using namespace stitch;

namespace {

Rig radtan_rig(int w, int h, double k1, double hfov_deg) {
  Rig rig;
  const double f = 0.5 * w / std::tan(0.5 * hfov_deg * CV_PI / 180);
  for (int i = 0; i < 3; ++i) {
    Camera c;
    c.width = w, c.height = h, c.fx = c.fy = f, c.cx = 0.5 * (w - 1), c.cy = 0.5 * (h - 1);
    c.lens.model = Lens::Model::Radtan;
    c.lens.k1 = k1;
    c.lens.k2 = k1 < 0 ? 0.25 * k1 * k1 : 0.0;
    c.yaw_deg = 0.6 * hfov_deg * (i - 1);
    rig.cameras.push_back(c);
  }
  rig.reference = 1;
  rig_compute_rough_homographies(rig);
  return rig;
}

Rig ignoring_lenses(Rig rig) {
  for (auto& c : rig.cameras) c.lens = Lens{};
  return rig;
}

#ifndef STITCH_LENS_TIMING_ONLY
// Scene lines through each camera (rows and columns of rays across its view), seen in raw pixels
// through the TRUE lens, mapped to the plane canvas by `rig`: the worst distance of a point from
// its line's chord (0 = straight).
double straightness(const Rig& truth, const Rig& rig) {
  double worst = 0;
  for (int i = 0; i < int(truth.cameras.size()); ++i) {
    const Camera& c = truth.cameras[i];
    const CameraCanvasMap m = camera_canvas_map(rig, i);
    for (int line = 0; line < 8; ++line) {
      // A scene line: 3-D points (t, y0, 1) (horizontal) or (x0, t, 1) (vertical) in camera i.
      const double off = -0.3 + 0.6 * (line % 4) / 3.0;
      std::vector<Eigen::Vector2d> pts;
      for (double t = -1.5; t <= 1.5; t += 0.02) {
        const Eigen::Vector3d X = line < 4 ? Eigen::Vector3d(t, off, 1) : Eigen::Vector3d(off, t, 1);
        Eigen::Vector2d raw, q;
        if (!lens_project(c, X, raw) || !lens_sees(c, raw.x(), raw.y())) continue;
        if (m.to_canvas(raw, q)) pts.push_back(q);
      }
      if (pts.size() < 3) continue;
      const Eigen::Vector2d a = pts.front(), b = pts.back(), n = Eigen::Vector2d(b.y() - a.y(), a.x() - b.x()).normalized();
      for (const auto& p : pts) worst = std::max(worst, std::abs((p - a).dot(n)));
    }
  }
  return worst;
}

int quality(const std::string& path, int size) {
  cv::Mat bgr = cv::imread(path, cv::IMREAD_COLOR), pano;
  if (bgr.empty()) {
    std::fprintf(stderr, "cannot read %s\n", path.c_str());
    return 2;
  }
  cv::cvtColor(bgr, pano, cv::COLOR_BGR2RGBA);
  std::printf("| rig | cameras | canvas | PSNR lens on | PSNR lens ignored | straightness on / ignored (px) |\n");
  std::printf("|---|---|---|---|---|---|\n");
  for (double k1 : {-0.35, -0.25, -0.1, 0.0, 0.1}) {
    const Rig rig = radtan_rig(size * 4 / 3, size, k1, 60);
    std::vector<cv::Mat> frames;
    for (const auto& c : rig.cameras) frames.push_back(testdata::render_camera_from_equirect(pano, c));
    const Rig ign = ignoring_lenses(rig);
    const cv::Mat on = testdata::compose_cpu(rig, frames), off = testdata::compose_cpu(ign, frames), gt = testdata::plane_ground_truth(pano, rig);
    cv::Mat gray, mask;
    cv::cvtColor(on, gray, cv::COLOR_RGBA2GRAY);
    mask = gray > 0;
    cv::erode(mask, mask, cv::Mat::ones(9, 9, CV_8U));
    cv::Mat gt_padded(on.size(), gt.type(), cv::Scalar::all(0));
    gt.copyTo(gt_padded(cv::Rect(0, 0, gt.cols, gt.rows)));
    std::printf("| radtan k1 %+.2f k2 %.3f, plane | 3x %dx%d, hfov 60 | %dx%d | %.2f dB | %.2f dB | %.3f / %.1f |\n", k1,
                rig.cameras[0].lens.k2, rig.cameras[0].width, size, on.cols, on.rows, testdata::masked_psnr_rgb(on, gt_padded, mask),
                testdata::masked_psnr_rgb(off, gt_padded, mask), straightness(rig, rig), straightness(rig, ign));
    std::fflush(stdout);
  }
  struct Sphere {
    const char* name;
    Rig rig;
  };
  std::vector<Sphere> spheres = {{"dual fisheye 190", testdata::dual_fisheye_rig(size * 2, 190)},
                                 {"dual fisheye 200", testdata::dual_fisheye_rig(size * 2, 200)},
                                 {"dual fisheye 220, k1 -0.02", testdata::dual_fisheye_rig(size * 2, 220, 0, -0.02, 0.001)},
                                 {"fisheye ring of 3, 180", testdata::fisheye_ring(3, size * 2, 180)},
                                 {"fisheye ring of 4, 190", testdata::fisheye_ring(4, size * 2, 190)},
                                 {"fisheye ring of 8, 180", testdata::fisheye_ring(8, size, 180)}};
  for (auto& s : spheres) {
    std::vector<cv::Mat> frames;
    for (const auto& c : s.rig.cameras) frames.push_back(testdata::render_camera_from_equirect(pano, c));
    const cv::Mat on = testdata::compose_cpu(s.rig, frames);
    cv::Mat gt = testdata::equirect_ground_truth(pano, s.rig), gt_padded(on.size(), gt.type(), cv::Scalar::all(0));
    gt.copyTo(gt_padded(cv::Rect(0, 0, gt.cols, gt.rows)));
    cv::Mat mask(on.size(), CV_8U, cv::Scalar(0));
    mask(cv::Rect(0, 0, s.rig.canvas_width, s.rig.canvas_height)).setTo(255);
    cv::Mat gray;
    cv::cvtColor(on, gray, cv::COLOR_RGBA2GRAY);
    const int black = cv::countNonZero((gray == 0) & mask);
    std::printf("| %s, sphere | %dx %dx%d | %dx%d (2:1: %s) | %.2f dB | (a pinhole cannot see 180 deg) | black px: %d |\n",
                s.name, int(s.rig.cameras.size()), s.rig.cameras[0].width, s.rig.cameras[0].height, s.rig.canvas_width,
                s.rig.canvas_height, s.rig.canvas_width == 2 * s.rig.canvas_height ? "yes" : "no",
                testdata::masked_psnr_rgb(on, gt_padded, mask), black);
    std::fflush(stdout);
  }
  return 0;
}
#endif

// Frames (random pixels) in the backend's memory, as the elements hand them on: device memory on
// CUDA (no upload in the times), host memory on the CPU.
struct Frames {
  std::vector<cv::Mat> host;
#ifdef STITCH_HAVE_CUDA
  std::vector<DeviceBuffer> device;
#endif
  std::vector<ImageView> views;
  ImageView make(Backend b, int w, int h) {
    host.emplace_back(std::max(1, h), std::max(1, w), CV_8UC4);
    cv::randu(host.back(), cv::Scalar::all(0), cv::Scalar::all(255));
    ImageView v = as_view(host.back());
#ifdef STITCH_HAVE_CUDA
    if (b == Backend::Cuda) {
      device.emplace_back(host.back().total() * 4);
      STITCH_CUDA(cudaMemcpy(device.back().data(), host.back().data, host.back().total() * 4, cudaMemcpyHostToDevice));
      v.data = device.back().data();
      v.on_device = true;
    }
#endif
    views.push_back(v);
    return v;
  }
};

template <typename F>
double median_ms(int iterations, F&& f) {
  f();  // warm up
  std::vector<double> ms;
  for (int i = 0; i < iterations; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    f();
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
  }
  std::sort(ms.begin(), ms.end());
  return ms[ms.size() / 2];
}

// The two per-view mappings the lens enters on every frame: compose (weighted mean straight from
// the frames) and the flow warp (pre-warp + flow in the overlaps + local warp), each synchronised.
struct LensCost {
  double compose_ms, flowwarp_ms;
};
LensCost time_rig(const Rig& rig, Backend b, int iterations) {
  Frames in, rois;
  for (const auto& c : rig.cameras) in.make(b, c.width, c.height);
  Compositor direct(b);
  direct.prepare(rig, CompositorSettings{});
  const OutputGeometry& g = direct.geometry();
  Frames out;
  const ImageView pano = out.make(b, g.width, g.height);
  LensCost cost{};
  cost.compose_ms = median_ms(iterations, [&] { direct.compose(in.views, pano); });
  Compositor planner(b);
  planner.prepare(rig, CompositorSettings{}, CompositorInput::Prewarped);
  for (const auto& p : planner.prewarped_placements()) rois.make(b, p.roi.width, p.roi.height);
  auto flow = FlowWarper::create(b);
  flow->set_settings(FlowWarpSettings{});  // flow on, medium quality
  const OutputGeometry canvas = canvas_geometry(rig);
  flow->prepare(planner.prewarped_placements(), canvas.width, canvas.height);
  cost.flowwarp_ms = median_ms(iterations, [&] { flow->warp(in.views, rois.views); });
  return cost;
}

int timing(Backend b, int iterations) {
  const Rig radtan = radtan_rig(1920, 1080, -0.25, 60);
  const Rig sphere = testdata::dual_fisheye_rig(3840, 200, 7680 / (2 * CV_PI));
  std::printf("backend %s, median of %d iterations, frames already in %s memory\n", b == Backend::Cuda ? "cuda" : "cpu",
              iterations, b == Backend::Cuda ? "device" : "host");
  std::printf("| rig | canvas | compose ms | flow warp ms |\n|---|---|---|---|\n");
  auto row = [&](const char* name, const Rig& rig) {
    const LensCost c = time_rig(rig, b, iterations);
    std::printf("| %s | %dx%d | %.3f | %.3f |\n", name, rig.canvas_width, rig.canvas_height, c.compose_ms, c.flowwarp_ms);
    std::fflush(stdout);
  };
  row("3x1920x1080 radtan k1 -0.25, plane", radtan);
  row("3x1920x1080 same rig, pinhole", ignoring_lenses(radtan));
  row("2x3840x3840 fisheye 200, sphere", sphere);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::string photo, backend = "cuda";
  int size = 320, iterations = 50;
  bool do_timing = false;
  for (int i = 1; i < argc; ++i) {
    const std::string k = argv[i];
    if (k == "--timing") do_timing = true;
    else if (i + 1 < argc && k == "--photo") photo = argv[++i];
    else if (i + 1 < argc && k == "--size") size = std::atoi(argv[++i]);  // quality only
    else if (i + 1 < argc && k == "--backend") backend = argv[++i];
    else if (i + 1 < argc && k == "--iterations") iterations = std::atoi(argv[++i]);
    else {
      std::fprintf(stderr, "usage: stitch-bench-lens --photo PANO [--size 320] | --timing [--backend cuda|cpu] [--iterations 50]\n");
      return 2;
    }
  }
  try {
    if (do_timing) {
      if (backend == "cuda" && !cuda_device_available()) {
        std::fprintf(stderr, "no CUDA device\n");
        return 77;
      }
      return timing(backend == "cuda" ? Backend::Cuda : Backend::Cpu, iterations);
    }
#ifdef STITCH_LENS_TIMING_ONLY
    std::fprintf(stderr, "this build times only: --timing (photo %s, size %d ignored)\n", photo.c_str(), size);
    return 2;
#else
    if (photo.empty()) photo = "data/photos/boat1_1600.jpg";
    return quality(photo, std::max(64, size));
#endif
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch-bench-lens: %s\n", e.what());
    return 1;
  }
}
