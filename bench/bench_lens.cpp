// stitch-bench-lens (issue 15): what the lens model buys and costs.
//
//   stitch-bench-lens --photo PANO [--size 320]   quality: rigs rendered from PANO (taken as an
//       equirectangular 360-degree photo) through their lenses, stitched on the CPU with the TRUE
//       calibration, lens on vs the same rig with the lens ignored: PSNR against the ground
//       truth, and straightness (the worst deviation from its chord, canvas pixels, of scene
//       lines seen through each camera and mapped to the plane canvas).
//   stitch-bench-lens --timing [--backend cuda|cpu] [--iterations 50]   compose time per
//       panorama: 3 x 1920x1080 radtan on a plane (vs the same rig pinhole), and 2 x 3840x3840
//       200-degree fisheyes to a 7680x3840 sphere.
#include <chrono>
#include <cstdio>
#include <cstring>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "image_compare.hpp"
#include "lens_rig.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "stitch/warp/geometry.hpp"

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

double time_compose(const Rig& rig, Backend b, int iterations) {
  std::vector<cv::Mat> frames;
  for (const auto& c : rig.cameras) {
    cv::Mat f(c.height, c.width, CV_8UC4);
    cv::randu(f, cv::Scalar::all(0), cv::Scalar::all(255));
    frames.push_back(f);
  }
  Compositor comp(b);
  comp.prepare(rig, CompositorSettings{});
  cv::Mat pano(comp.geometry().height, comp.geometry().width, CV_8UC4);
  std::vector<ImageView> views;
  for (auto& f : frames) views.push_back(as_view(f));
  comp.compose(views, as_view(pano));  // warm up
  const auto t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < iterations; ++i) comp.compose(views, as_view(pano));
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / iterations;
}

int timing(Backend b, int iterations) {
  const Rig radtan = radtan_rig(1920, 1080, -0.25, 70);
  const Rig sphere = testdata::dual_fisheye_rig(3840, 200, 7680 / (2 * CV_PI));
  std::printf("backend %s, %d iterations, host frames (upload included on CUDA)\n", b == Backend::Cuda ? "cuda" : "cpu",
              iterations);
  std::printf("3x1920x1080 radtan plane (%dx%d): %.3f ms; same rig pinhole: %.3f ms\n", radtan.canvas_width,
              radtan.canvas_height, time_compose(radtan, b, iterations), time_compose(ignoring_lenses(radtan), b, iterations));
  std::printf("2x3840x3840 fisheye 200 -> %dx%d sphere: %.3f ms\n", sphere.canvas_width, sphere.canvas_height,
              time_compose(sphere, b, iterations));
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
    else if (i + 1 < argc && k == "--size") size = std::atoi(argv[++i]);
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
    if (photo.empty()) photo = "data/photos/boat1_1600.jpg";
    return quality(photo, std::max(64, size));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch-bench-lens: %s\n", e.what());
    return 1;
  }
}
