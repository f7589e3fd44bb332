// Quality of a calibrated lens rig against the ground truth (issue 15): the calibrated rig put in
// the truth's frame (the calibration's gauge: one rotation of the whole rig is free), its panorama
// on the truth's canvas, PSNR against the photo; rectilinear views of a spherical canvas; and the
// long edges of the ground truth found again in the stitched panorama (how far they moved and
// how much they bend). Header-only: stitch-bench-lens-psnr and the tests share it.
#pragma once
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "stitch/rig/projection_math.hpp"
#include "stitch/rig/rig.hpp"

namespace testdata {

// `est` turned as a whole onto `truth` (the rotation G minimising sum |G R_est,i - R_true,i|^2),
// on the truth's canvas (projection, size, scale, origin, wrap). Non-planar canvases.
inline stitch::Rig aligned_to_truth(const stitch::Rig& est, const stitch::Rig& truth) {
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < truth.cameras.size(); ++i) M += truth.cameras[i].R() * est.cameras[i].R().transpose();
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1 : 1;
  const Eigen::Matrix3d G = svd.matrixU() * D * svd.matrixV().transpose();
  stitch::Rig out = est;
  for (auto& c : out.cameras) {
    c.set_R(G * c.R());
    c.homography.reset();
  }
  out.projection = truth.projection;
  out.reference = truth.reference;
  out.canvas_width = truth.canvas_width, out.canvas_height = truth.canvas_height;
  out.canvas_scale = truth.canvas_scale;
  out.canvas_origin_x = truth.canvas_origin_x, out.canvas_origin_y = truth.canvas_origin_y;
  out.canvas_wrap = truth.canvas_wrap;
  return out;
}

// A rectilinear view (pinhole, hfov_deg across w) looking at (yaw, pitch) of an image on the
// spherical canvas of `rig` (its first canvas_width x canvas_height pixels).
inline cv::Mat rectilinear_view(const cv::Mat& canvas, const stitch::Rig& rig, double yaw_deg, double pitch_deg,
                                double hfov_deg, int w, int h) {
  stitch::Camera v;
  v.yaw_deg = yaw_deg, v.pitch_deg = pitch_deg;
  const Eigen::Matrix3d R = v.R();
  const double f = 0.5 * w / std::tan(0.5 * hfov_deg * CV_PI / 180);
  cv::Mat mx(h, w, CV_32F), my(h, w, CV_32F);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const Eigen::Vector3d r = R * Eigen::Vector3d((x - 0.5 * (w - 1)) / f, (y - 0.5 * (h - 1)) / f, 1.0);
      double a, b;
      stitch_projection::ray_to_angles(stitch_projection::kSpherical, r.x(), r.y(), r.z(), a, b);
      double X = rig.canvas_origin_x + rig.canvas_scale * a;
      if (rig.canvas_wrap) X -= std::floor((X + 0.5) / rig.canvas_width) * rig.canvas_width;
      mx.at<float>(y, x) = float(X);
      my.at<float>(y, x) = float(rig.canvas_origin_y + rig.canvas_scale * b);
    }
  cv::Mat out;
  cv::remap(canvas(cv::Rect(0, 0, rig.canvas_width, rig.canvas_height)), out, mx, my, cv::INTER_LINEAR,
            rig.canvas_wrap ? cv::BORDER_WRAP : cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return out;
}

struct LineComparison {
  int lines = 0;              // ground-truth segments found along most of their length in both
  double median_shift_px = 0, worst_shift_px = 0;  // per line: 90th percentile of |stitched - truth| across it
  double median_bend_px = 0, worst_bend_px = 0;    // per line: |sagitta of stitched - of truth| (parabola fits)
};

namespace detail {
inline float bilinear(const cv::Mat& m, double x, double y) {
  const int x0 = int(std::floor(x)), y0 = int(std::floor(y));
  if (x0 < 0 || y0 < 0 || x0 + 1 >= m.cols || y0 + 1 >= m.rows) return 0.f;
  const double fx = x - x0, fy = y - y0;
  return float((1 - fy) * ((1 - fx) * m.at<float>(y0, x0) + fx * m.at<float>(y0, x0 + 1)) +
               fy * ((1 - fx) * m.at<float>(y0 + 1, x0) + fx * m.at<float>(y0 + 1, x0 + 1)));
}
// Sub-pixel offset (along n, within +-band) of the strongest gradient across the line at p;
// false when there is no clear edge (weak, or the peak at the band's end).
inline bool edge_offset(const cv::Mat& gx, const cv::Mat& gy, const Eigen::Vector2d& p, const Eigen::Vector2d& n,
                        int band, double min_grad, double& off) {
  std::vector<double> g(2 * band + 1);
  int bk = 0;
  double best = -1;
  for (int k = -band; k <= band; ++k) {
    const Eigen::Vector2d q = p + 0.5 * k * n;  // half-pixel steps
    g[k + band] = std::abs(bilinear(gx, q.x(), q.y()) * n.x() + bilinear(gy, q.x(), q.y()) * n.y());
    if (g[k + band] > best) best = g[k + band], bk = k;
  }
  if (best < min_grad || bk == -band || bk == band) return false;
  const double a = g[bk + band - 1], b = g[bk + band], c = g[bk + band + 1];
  const double den = a - 2 * b + c;
  off = 0.5 * (bk + (den < 0 ? 0.5 * (a - c) / den : 0.0));
  return true;
}
// Sagitta (px) over length `len` of the parabola fitted to offsets o(t).
inline double sagitta(const std::vector<double>& t, const std::vector<double>& o, double len) {
  Eigen::MatrixXd A(t.size(), 3);
  Eigen::VectorXd b(t.size());
  for (std::size_t i = 0; i < t.size(); ++i) {
    const double s = t[i] / len - 0.5;
    A(i, 0) = 1, A(i, 1) = s, A(i, 2) = s * s;
    b(i) = o[i];
  }
  const Eigen::Vector3d c = A.colPivHouseholderQr().solve(b);
  return c(2) * 0.25;  // s in [-1/2, 1/2]: the curve's rise at the middle over the chord
}
inline void median_worst(std::vector<double> v, double& med, double& worst) {
  if (v.empty()) return;
  std::sort(v.begin(), v.end());
  med = v[v.size() / 2];
  worst = v.back();
}
}  // namespace detail

// The long straight edges of `truth` (cv::LineSegmentDetector, >= min_len px) located again,
// every half pixel along them, in `truth` and in `stitched` (the sub-pixel gradient peak across
// the line, within +-band/2 px); per line, how far the stitched edge lies from the truth's (90th
// percentile) and how much more it bends (sagitta of the parabola through the offsets).
inline LineComparison compare_lines(const cv::Mat& truth, const cv::Mat& stitched, double min_len = 60, int band = 8) {
  auto prep = [](const cv::Mat& img, cv::Mat& gray, cv::Mat& gx, cv::Mat& gy) {
    if (img.channels() == 4) cv::cvtColor(img, gray, cv::COLOR_RGBA2GRAY);
    else if (img.channels() == 3) cv::cvtColor(img, gray, cv::COLOR_RGB2GRAY);
    else gray = img.clone();
    cv::Mat blur;
    cv::GaussianBlur(gray, blur, cv::Size(5, 5), 1.0);
    cv::Sobel(blur, gx, CV_32F, 1, 0);
    cv::Sobel(blur, gy, CV_32F, 0, 1);
  };
  cv::Mat tg, tx, ty, sg, sx, sy;
  prep(truth, tg, tx, ty);
  prep(stitched, sg, sx, sy);
  std::vector<cv::Vec4f> segs;
  cv::createLineSegmentDetector(cv::LSD_REFINE_STD)->detect(tg, segs);
  std::vector<double> shifts, bends;
  for (const auto& s : segs) {
    const Eigen::Vector2d p0(s[0], s[1]), p1(s[2], s[3]);
    const double len = (p1 - p0).norm();
    if (len < min_len) continue;
    const Eigen::Vector2d d = (p1 - p0) / len, n(-d.y(), d.x());
    std::vector<double> ts, ot, os, dev;
    int tried = 0;
    for (double t = 2; t <= len - 2; t += 0.5) {
      ++tried;
      const Eigen::Vector2d p = p0 + t * d;
      // Both images must have content around the point (the stitched one may be uncovered).
      if (sg.at<uchar>(std::clamp(int(p.y()), 0, sg.rows - 1), std::clamp(int(p.x()), 0, sg.cols - 1)) == 0) continue;
      double a, b;
      if (!detail::edge_offset(tx, ty, p, n, band, 60.0, a) || !detail::edge_offset(sx, sy, p, n, band, 30.0, b)) continue;
      ts.push_back(t), ot.push_back(a), os.push_back(b), dev.push_back(std::abs(b - a));
    }
    if (ts.size() < 0.7 * tried) continue;
    std::nth_element(dev.begin(), dev.begin() + dev.size() * 9 / 10, dev.end());
    shifts.push_back(dev[dev.size() * 9 / 10]);
    bends.push_back(std::abs(detail::sagitta(ts, os, len) - detail::sagitta(ts, ot, len)));
  }
  LineComparison r;
  r.lines = int(shifts.size());
  detail::median_worst(shifts, r.median_shift_px, r.worst_shift_px);
  detail::median_worst(bends, r.median_bend_px, r.worst_bend_px);
  return r;
}

}  // namespace testdata
