// Panorama PSNR and straight lines of lens rigs calibrated from rough rigs (issue 15: "panorama
// PSNR against ground truth within 1 dB of the same rig with pinhole cameras", "straight lines
// straight"). Every rig is rendered (2x supersampled) from a photo taken as an equirectangular
// panorama; its rough rig has the lens model without coefficients ("estimate them") and the
// focal / angles off (seeded); the calibrated rig is turned as a whole onto the truth (the gauge)
// and composed on the truth's spherical canvas; PSNR against the photo resampled onto that canvas,
// over what the true rig covers. Lines: rectilinear views of the ground truth and of the stitched
// panorama at the seams and centres; the ground truth's long edges (LSD) located again in the
// stitched view: shift (90th percentile a line) and extra bend (sagitta), median and worst.
// Radtan trios (k1 -0.35..+0.1) are compared with the same trio of pinhole cameras (same
// calibration from the same kind of rough rig); fisheye rigs (180-220 degrees, no pinhole can see
// that) with the same rig composed with its true lenses.
//
//   stitch-bench-lens-psnr --photo a.jpg [--photo b.jpg] [--seeds 2] [--cases radtan,fisheye]
//                          [--supersample 2] [--dense 0]
// --supersample N: render each camera N x N supersampled (default 2; 4 aliases less).
// --dense 0: the calibrator's photometric refit off (the baseline before it).
// --frames N: calibrate on N frame sets (a stream): the whole rig panned by 5 degrees of yaw and
// 1.5 of pitch per frame over the photo (the first set is the one composed and scored).
// --photometric 1 [--photometric-blur 1.0]: the direct photometric refit after it (off by default;
// CalibrationOptions::photometric_refit).
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <opencv2/imgcodecs.hpp>
#include <string>
#include <vector>

#include "bench_photo.hpp"
#include "image_compare.hpp"
#include "lens_quality.hpp"
#include "lens_rig.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/lens.hpp"

using namespace stitch;

namespace {

Rig lenses_dropped(Rig r) {
  for (auto& c : r.cameras) c.lens = Lens{};
  return r;
}

struct Views {
  double hfov;
  std::vector<std::pair<double, double>> dirs;  // yaw, pitch
};

struct Quality {
  double psnr = 0;
  testdata::LineComparison lines;
};

cv::Mat padded(const cv::Mat& gt, cv::Size size) {
  cv::Mat out(size, gt.type(), cv::Scalar::all(0));
  gt.copyTo(out(cv::Rect(0, 0, gt.cols, gt.rows)));
  return out;
}

// PSNR of `rig`'s panorama (on the truth's canvas) over `mask`, and its lines in `views` against
// the ground truth's.
Quality quality_of(const Rig& rig, std::vector<cv::Mat>& frames, const cv::Mat& gt, const cv::Mat& mask, const Views& views) {
  Quality q;
  const cv::Mat pano = testdata::compose_cpu(rig, frames);
  q.psnr = testdata::masked_psnr_rgb(pano, padded(gt, pano.size()), mask);
  std::vector<double> shift, bend;
  const int w = int(std::lround(2 * rig.canvas_scale * std::tan(0.5 * views.hfov * CV_PI / 180)));
  int lines = 0;
  for (const auto& [yaw, pitch] : views.dirs) {
    const cv::Mat tv = testdata::rectilinear_view(gt, rig, yaw, pitch, views.hfov, w, w * 3 / 4);
    const cv::Mat sv = testdata::rectilinear_view(pano, rig, yaw, pitch, views.hfov, w, w * 3 / 4);
    const testdata::LineComparison c = testdata::compare_lines(tv, sv, 40);
    if (c.lines == 0) continue;
    lines += c.lines;
    shift.push_back(c.median_shift_px), shift.push_back(c.worst_shift_px);
    bend.push_back(c.median_bend_px), bend.push_back(c.worst_bend_px);
    q.lines.worst_shift_px = std::max(q.lines.worst_shift_px, c.worst_shift_px);
    q.lines.worst_bend_px = std::max(q.lines.worst_bend_px, c.worst_bend_px);
    q.lines.median_shift_px = std::max(q.lines.median_shift_px, c.median_shift_px);  // worst view's median
    q.lines.median_bend_px = std::max(q.lines.median_bend_px, c.median_bend_px);
  }
  q.lines.lines = lines;
  return q;
}

struct Case {
  std::string name;
  Rig truth;
  bool fisheye;
  Views views;
};

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> photos;
  int seeds = 1;
  std::string which = "radtan,fisheye";
  int supersample = 2;
  bool dense = true, photometric = false;
  int stream_frames = 1;
  double photometric_blur = 1.0;
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--photo") photos.push_back(v);
    else if (k == "--seeds") seeds = std::stoi(v);
    else if (k == "--cases") which = v;
    else if (k == "--supersample") supersample = std::stoi(v);
    else if (k == "--photometric") photometric = v != "0";
    else if (k == "--frames") stream_frames = std::max(1, std::stoi(v));
    else if (k == "--photometric-blur") photometric_blur = std::stod(v);
    else if (k == "--dense") dense = v != "0";  // 0: the calibrator's photometric refit off (the baseline before it)
    else {
      std::fprintf(stderr, "unknown option %s\n", k.c_str());
      return 2;
    }
  }
  if (photos.empty()) {
    std::fprintf(stderr, "usage: %s --photo a.jpg [--photo b.jpg] [--seeds 2] [--cases radtan,fisheye] [--supersample 2] [--dense 0] [--photometric 1] [--photometric-blur 1]\n", argv[0]);
    return 2;
  }
  std::vector<Case> cases;
  const Views trio_views{60, {{-35, 0}, {-17.5, 0}, {0, 0}, {17.5, 0}, {35, 0}}};
  if (which.find("radtan") != std::string::npos) {
    cases.push_back({"pinhole trio", testdata::radtan_trio(320, 240, 260, 35, 0, 0, false, "spherical"), false, trio_views});
    for (double k1 : {-0.35, -0.2, 0.1}) {
      char name[64];
      const double k2 = k1 < 0 ? k1 * k1 : 0.0;  // as stitch-bench-calib-lens: the barrel lens does not fold
      std::snprintf(name, sizeof name, "radtan k1 %+.2f k2 %.3f", k1, k2);
      cases.push_back({name, testdata::radtan_trio(320, 240, 260, 35, k1, k2, true, "spherical"), false, trio_views});
    }
  }
  if (which.find("fisheye") != std::string::npos) {
    const Views sphere_views{80, {{0, 0}, {90, 0}, {180, 0}, {-90, 0}, {45, 40}, {-135, 40}, {135, -40}, {-45, -40}}};
    cases.push_back({"dual fisheye 190 k1 0", testdata::dual_fisheye_rig(480, 190, 0, 0.0), true, sphere_views});
    cases.push_back({"dual fisheye 200 k1 -0.02", testdata::dual_fisheye_rig(480, 200, 0, -0.02), true, sphere_views});
    cases.push_back({"dual fisheye 210 k1 +0.02", testdata::dual_fisheye_rig(480, 210, 0, 0.02), true, sphere_views});
    cases.push_back({"dual fisheye 220 k1 +0.01", testdata::dual_fisheye_rig(480, 220, 0, 0.01), true, sphere_views});
    cases.push_back({"fisheye ring 3x180 k1 -0.02", testdata::fisheye_ring(3, 320, 180), true, sphere_views});
    cases.push_back({"fisheye ring 4x160 k1 -0.02", testdata::fisheye_ring(4, 320, 160), true, sphere_views});
  }
  std::printf("| photo | rig | seed | PSNR true lenses | PSNR calibrated | vs pinhole trio (calibrated) | lines | shift median / worst (px) | bend median / worst (px) | lenses ignored: PSNR, shift, bend | k1 est (true) | f est (true) | s | warnings |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  double worst_gap = -1e9, worst_shift = 0, worst_bend = 0;
  std::string worst_gap_at;
  for (const auto& path : photos) {
    const cv::Mat photo = stitch_bench::read_photo_rgba(path, 2688);
    if (photo.empty()) return 1;
    const std::string name = path.substr(path.find_last_of('/') + 1);
    for (int seed = 0; seed < seeds; ++seed) {
      double pinhole_psnr = 0;
      for (const Case& cs : cases) {
        Rig truth = cs.truth;
        rig_layout_canvas(truth);
        std::vector<cv::Mat> frames;
        std::vector<ImageView> views;
        for (const auto& c : truth.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c, supersample));
        for (auto& m : frames) views.push_back(as_view(m));
        const cv::Mat gt = testdata::equirect_ground_truth(photo, truth);
        // What the true rig covers (its panorama's non-black pixels, eroded): the PSNR's mask.
        cv::Mat mask, gray;
        const cv::Mat true_pano = testdata::compose_cpu(truth, frames);
        cv::cvtColor(true_pano, gray, cv::COLOR_RGBA2GRAY);
        mask = gray > 0;
        cv::erode(mask, mask, cv::Mat::ones(9, 9, CV_8U));
        const Quality qt = quality_of(truth, frames, gt, mask, cs.views);
        const Rig rough = testdata::without_coefficients(cs.fisheye ? testdata::rough_sphere(truth, 11 + seed) : testdata::rough_trio(truth, seed));
        std::string warn;
        Quality qc;
        double k1_est = 0, f_est = 0, secs = 0;
        try {
          const auto t0 = std::chrono::steady_clock::now();
          CalibrationOptions co;
          co.dense_lens_matches = dense;
          co.photometric_refit = photometric;
          co.photometric_blur_sigma = photometric_blur;
          std::vector<std::vector<cv::Mat>> more;
          std::vector<std::vector<ImageView>> sets{views};
          for (int f = 1; f < stream_frames; ++f) {
            const Eigen::Matrix3d turn = (Eigen::AngleAxisd(5.0 * f * CV_PI / 180, Eigen::Vector3d::UnitY()) *
                                          Eigen::AngleAxisd(1.5 * f * CV_PI / 180, Eigen::Vector3d::UnitX()))
                                             .toRotationMatrix();
            more.emplace_back();
            sets.emplace_back();
            for (const auto& c : truth.cameras) {
              Camera t = c;
              t.set_R(turn * c.R());
              more.back().push_back(testdata::render_camera_from_equirect(photo, t, supersample));
            }
            for (auto& m : more.back()) sets.back().push_back(as_view(m));
          }
          const CalibrationResult r = calibrate_from_rig(rough, sets, co);
          secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
          const Rig est = testdata::aligned_to_truth(r.rig, truth);
          qc = quality_of(est, frames, gt, mask, cs.views);
          if (std::getenv("LENS_PSNR_HYBRID")) {
            // Where the loss comes from: the estimated rotations with the true intrinsics and lenses,
            // and the true rotations with the estimated ones.
            Rig rot_only = truth, intr_only = truth;
            for (std::size_t i = 0; i < truth.cameras.size(); ++i) {
              rot_only.cameras[i].set_R(est.cameras[i].R());
              Camera c = est.cameras[i];
              c.set_R(truth.cameras[i].R());
              intr_only.cameras[i] = c;
              const Eigen::AngleAxisd e(truth.cameras[i].R().transpose() * est.cameras[i].R());
              std::fprintf(stderr, "  camera %zu: rotation off %.4f deg, f %.3f (%.3f), k1 %+.5f (%+.5f), k2 %+.5f (%+.5f)\n", i,
                           e.angle() * 180 / CV_PI, est.cameras[i].fx, truth.cameras[i].fx, est.cameras[i].lens.k1,
                           truth.cameras[i].lens.k1, est.cameras[i].lens.k2, truth.cameras[i].lens.k2);
            }
            std::fprintf(stderr, "  %s: PSNR estimated rotations + true intrinsics %.2f dB, true rotations + estimated intrinsics %.2f dB\n",
                         cs.name.c_str(), quality_of(rot_only, frames, gt, mask, cs.views).psnr,
                         quality_of(intr_only, frames, gt, mask, cs.views).psnr);
          }
          double worst_rel = -1;
          for (std::size_t i = 0; i < est.cameras.size(); ++i) {
            const double rel = std::abs(est.cameras[i].lens.k1 - truth.cameras[i].lens.k1);
            if (rel > worst_rel) worst_rel = rel, k1_est = est.cameras[i].lens.k1, f_est = est.cameras[i].fx;
          }
          for (const auto& s : r.warnings) warn += s + "; ";
        } catch (const std::exception& e) {
          warn = std::string("calibration failed: ") + e.what();
        }
        std::string ignored = "-";
        if (!cs.fisheye && !truth.cameras[0].lens.pinhole()) {
          const Quality qi = quality_of(lenses_dropped(truth), frames, gt, mask, cs.views);
          char b[96];
          std::snprintf(b, sizeof b, "%.2f dB, %.2f / %.2f, %.2f / %.2f", qi.psnr, qi.lines.median_shift_px,
                        qi.lines.worst_shift_px, qi.lines.median_bend_px, qi.lines.worst_bend_px);
          ignored = b;
        }
        if (!cs.fisheye && truth.cameras[0].lens.pinhole()) pinhole_psnr = qc.psnr;
        std::string vs = "-";
        if (!cs.fisheye && !truth.cameras[0].lens.pinhole() && pinhole_psnr > 0) {
          char b[32];
          std::snprintf(b, sizeof b, "%+.2f dB", qc.psnr - pinhole_psnr);
          vs = b;
          if (pinhole_psnr - qc.psnr > worst_gap) worst_gap = pinhole_psnr - qc.psnr, worst_gap_at = name + " " + cs.name;
        } else if (cs.fisheye) {
          char b[48];
          std::snprintf(b, sizeof b, "(true lenses: %+.2f dB)", qc.psnr - qt.psnr);
          vs = b;
          if (qt.psnr - qc.psnr > worst_gap) worst_gap = qt.psnr - qc.psnr, worst_gap_at = name + " " + cs.name + " (vs true lenses)";
        }
        worst_shift = std::max(worst_shift, qc.lines.worst_shift_px);
        worst_bend = std::max(worst_bend, qc.lines.worst_bend_px);
        std::printf("| %s | %s | %d | %.2f dB | %.2f dB | %s | %d | %.2f / %.2f | %.2f / %.2f | %s | %+.4f (%+.4f) | %.1f (%.1f) | %.0f | %s |\n",
                    name.c_str(), cs.name.c_str(), seed, qt.psnr, qc.psnr, vs.c_str(), qc.lines.lines,
                    qc.lines.median_shift_px, qc.lines.worst_shift_px, qc.lines.median_bend_px, qc.lines.worst_bend_px,
                    ignored.c_str(), k1_est, truth.cameras[0].lens.k1, f_est, truth.cameras[0].fx, secs,
                    warn.empty() ? "-" : warn.c_str());
        std::fflush(stdout);
      }
    }
  }
  std::printf("worst: %.2f dB below the baseline (%s); lines: worst shift %.2f px, worst extra bend %.2f px\n", worst_gap,
              worst_gap_at.c_str(), worst_shift, worst_bend);
  return 0;
}
