// Lens estimation across the radtan range (issue 15): 3 cameras rendered through a radtan
// lens from a photo taken as an equirectangular panorama, calibrated from rough rigs whose lenses
// carry the model only ("estimate them"), over photos x k1 x yaw spacings x seeds (the rough
// rig's perturbation). Prints one row a run and the worst case; the same rig with pinhole
// cameras (calibrated from the same kind of rough rig) is the baseline.
//
//   stitch-bench-calib-lens --photo a.jpg [--photo b.jpg] [--k1 -0.35,-0.2,0.1] [--spacing 35,30]
//                           [--seeds 2] [--size 320] [--dense 0]
// --dense 0: the lenses fitted on SIFT keypoints alone (before branch lens-radtan).
// --supersample N: render each camera N x N supersampled (default 2; 4 aliases less).
#include <cmath>
#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "bench_photo.hpp"
#include "lens_rig.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/lens.hpp"

using namespace stitch;

int main(int argc, char** argv) {
  std::vector<std::string> photos;
  std::vector<double> k1s = {-0.35, -0.2, 0.1}, spacings = {35};
  int seeds = 1, size = 320;
  CalibrationOptions opts;
  int supersample = 2;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--photo") photos.push_back(v);
    else if (k == "--k1") k1s = stitch_bench::comma_numbers(v);
    else if (k == "--spacing") spacings = stitch_bench::comma_numbers(v);
    else if (k == "--seeds") seeds = std::stoi(v);
    else if (k == "--size") size = std::stoi(v);
    else if (k == "--dense") opts.dense_lens_matches = std::stoi(v) != 0;
    else if (k == "--supersample") supersample = std::stoi(v);
    else {
      std::fprintf(stderr, "unknown option %s\n", k.c_str());
      return 2;
    }
  }
  if (photos.empty()) {
    std::fprintf(stderr, "usage: %s --photo a.jpg [--photo b.jpg] [--k1 l,i,s,t] [--spacing 35,30] [--seeds 2] [--size 320]\n", argv[0]);
    return 2;
  }
  const int w = size, h = size * 3 / 4;
  const double f = 260.0 * size / 320;
  double worst_corner = 0, worst_median = 0, worst_k1_rel = 0;
  std::printf("| photo | spacing | seed | k1 true | k2 true | k1 est (worst cam) | f est (true %.0f) | corner err | match median | pinhole rig: corner err | match median | warnings |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n", f);
  for (const auto& path : photos) {
    const cv::Mat photo = stitch_bench::read_photo_rgba(path);
    if (photo.empty()) return 1;
    const std::string name = path.substr(path.find_last_of('/') + 1);
    for (double spacing : spacings)
      for (int seed = 0; seed < seeds; ++seed) {
        // The pinhole rig of the same geometry: the baseline.
        const Rig pin_truth = testdata::radtan_trio(w, h, f, spacing, 0, 0, false, "spherical");
        std::vector<cv::Mat> pf;
        std::vector<ImageView> pv;
        for (const auto& c : pin_truth.cameras) pf.push_back(testdata::render_camera_from_equirect(photo, c, supersample));
        for (auto& m : pf) pv.push_back(as_view(m));
        double pin_corner = -1, pin_median = -1;
        try {
          const CalibrationResult rp = calibrate_from_rig(testdata::rough_trio(pin_truth, seed), pv, opts);
          pin_corner = testdata::lens_corner_error(rp.rig, pin_truth);
          pin_median = measure_alignment(rp.rig, pv).median_px;
        } catch (const std::exception& e) {
          std::fprintf(stderr, "pinhole: %s\n", e.what());
        }
        for (double k1 : k1s) {
          const double k2 = k1 < 0 ? k1 * k1 : 0.0;  // barrel: k2 = k1^2 keeps the lens unfolded in the frame
          const Rig truth = testdata::radtan_trio(w, h, f, spacing, k1, k2, true, "spherical");
          std::vector<cv::Mat> frames;
          std::vector<ImageView> views;
          for (const auto& c : truth.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c, supersample));
          for (auto& m : frames) views.push_back(as_view(m));
          double corner = 1e9, median = 1e9, k1_est = 0, f_est = 0, k1_rel = 1e9;
          std::string warn;
          try {
            const CalibrationResult r =
                calibrate_from_rig(testdata::without_coefficients(testdata::rough_trio(truth, seed)), views, opts);
            corner = testdata::lens_corner_error(r.rig, truth);
            median = measure_alignment(r.rig, views).median_px;
            k1_rel = 0;
            for (const auto& c : r.rig.cameras) {
              const double rel = std::abs(c.lens.k1 - k1) / std::abs(k1);
              if (rel >= k1_rel) k1_rel = rel, k1_est = c.lens.k1, f_est = c.fx;
            }
            for (const auto& s : r.warnings) warn += s + "; ";
          } catch (const std::exception& e) {
            warn = e.what();
          }
          worst_corner = std::max(worst_corner, corner);
          worst_median = std::max(worst_median, median);
          worst_k1_rel = std::max(worst_k1_rel, k1_rel);
          std::printf("| %s | %.0f | %d | %+.2f | %.4f | %+.4f (%.1f %%) | %.2f | %.3f | %.3f | %.3f | %.3f | %s |\n", name.c_str(),
                      spacing, seed, k1, k2, k1_est, 100 * k1_rel, f_est, corner, median, pin_corner, pin_median,
                      warn.empty() ? "-" : warn.c_str());
          std::fflush(stdout);
        }
      }
  }
  std::printf("worst: corner error %.3f px, match median %.3f px, k1 off by %.1f %%\n", worst_corner, worst_median,
              100 * worst_k1_rel);
  return 0;
}
