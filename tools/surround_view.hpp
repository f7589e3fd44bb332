// Automotive surround view (issue 15): the 4-fisheye set of neozhaoliang/surround-view-system-
// introduction (MIT; ../shared/data/images/surround_view_4fisheye: front/back/left/right .png +
// .yaml) as a planar rig: each camera an OpenCV fisheye lens (camera_matrix, dist_coeffs) and a
// homography from its ideal pixel onto the ground plane, the bird's-eye canvas.
//
// The set's yaml chain, per camera (the repository's fisheye_camera.py / param_settings.py):
// raw pixel -> cv::fisheye undistortion to K_new (K with fx, fy scaled by scale_xy and cx, cy
// shifted by shift_xy) -> project_matrix (a homography onto that camera's strip of the ground,
// project_shapes) -> the strip turned into the 1200x1600 bird's-eye image (front as is, back
// 180 degrees, left / right transposed and flipped). Our rig's homography is the product
// placement * project_matrix * K_new * K^-1 (ideal pixel -> canvas); the lens does the rest.
// Header-only: the tool and its test share it.
#pragma once

#include <Eigen/Dense>
#include <array>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "stitch/cv_interop.hpp"
#include "stitch/rig/lens.hpp"
#include "stitch/warp/geometry.hpp"
#include "stitch/warp/warper.hpp"
#include "stitch/rig/rig.hpp"

namespace surround {

// The bird's-eye layout of the set (param_settings.py): 1200x1600, the car in [xl, xr] x [yt, yb].
constexpr int kTotalW = 600 + 2 * 300, kTotalH = 1000 + 2 * 300;
constexpr int kXl = 300 + 180 + 20, kYt = 300 + 200 + 50;
inline const std::array<const char*, 4> kNames = {"front", "back", "left", "right"};

inline cv::Mat read_mat(const cv::FileStorage& fs, const std::string& key, const std::string& where) {
  cv::Mat m;
  fs[key] >> m;
  if (m.empty()) throw stitch::RigError(where + ": no \"" + key + "\"");
  m.convertTo(m, CV_64F);
  return m;
}

// Strip pixel (x, y) of camera `name` (its project_shape image) -> bird's-eye pixel.
inline Eigen::Matrix3d placement(const std::string& name) {
  Eigen::Matrix3d T;
  if (name == "front") T.setIdentity();
  else if (name == "back") T << -1, 0, kTotalW - 1, 0, -1, kTotalH - 1, 0, 0, 1;  // [::-1, ::-1], at the bottom
  else if (name == "left") T << 0, 1, 0, -1, 0, kTotalH - 1, 0, 0, 1;             // transpose, [::-1]
  else if (name == "right") T << 0, -1, kTotalW - 1, 1, 0, 0, 0, 0, 1;            // transpose, flip(1), at the right
  else throw stitch::RigError("unknown surround-view camera \"" + name + "\"");
  return T;
}

// Camera `name` of the set in `dir` with its lens and its ideal-pixel -> bird's-eye homography.
inline stitch::Camera load_camera(const std::string& dir, const std::string& name) {
  const std::string path = dir + "/" + name + ".yaml";
  cv::FileStorage fs(path, cv::FileStorage::READ);
  if (!fs.isOpened()) throw stitch::RigError("cannot read " + path);
  const cv::Mat K = read_mat(fs, "camera_matrix", path), D = read_mat(fs, "dist_coeffs", path);
  const cv::Mat res = read_mat(fs, "resolution", path), P = read_mat(fs, "project_matrix", path);
  const cv::Mat scale = read_mat(fs, "scale_xy", path), shift = read_mat(fs, "shift_xy", path);
  if (K.total() != 9 || D.total() != 4 || res.total() != 2 || P.total() != 9 || scale.total() != 2 || shift.total() != 2)
    throw stitch::RigError(path + ": unexpected matrix sizes (camera_matrix 3x3, dist_coeffs 4, project_matrix 3x3)");
  stitch::Camera c;
  c.width = int(res.at<double>(0));
  c.height = int(res.at<double>(1));
  c.fx = K.at<double>(0, 0), c.fy = K.at<double>(1, 1), c.cx = K.at<double>(0, 2), c.cy = K.at<double>(1, 2);
  c.lens.model = stitch::Lens::Model::Fisheye;
  c.lens.k1 = D.at<double>(0), c.lens.k2 = D.at<double>(1), c.lens.k3 = D.at<double>(2), c.lens.k4 = D.at<double>(3);
  Eigen::Matrix3d Kn = c.K();
  Kn(0, 0) *= scale.at<double>(0);
  Kn(1, 1) *= scale.at<double>(1);
  Kn(0, 2) += shift.at<double>(0);
  Kn(1, 2) += shift.at<double>(1);
  Eigen::Matrix3d Pe;
  cv::cv2eigen(P.reshape(1, 3), Pe);
  Eigen::Matrix3d H = placement(name) * Pe * Kn * c.K().inverse();
  H /= std::abs(H(2, 2));
  // The set's matrices carry no sign (cv::warpPerspective ignores it); ours must map the ground
  // in front of the camera to positive w: the image's bottom middle looks down at the ground.
  Eigen::Vector3d ray;
  if (stitch::lens_unproject(c, {c.cx, c.height - 1.0}, ray) && ray.z() > 0 &&
      (H * c.K() * (ray / ray.z())).z() < 0)
    H = -H;
  c.homography = H;
  // These lenses' polynomials fold back (theta_d peaks near 109 degrees for `back`) inside the
  // frame's black corners: the image circle ends just before the fold.
  double td_max = 0;
  for (double th = 0; th < 3.14159; th += 0.001) {
    const double t2 = th * th, td = th * (1 + t2 * (c.lens.k1 + t2 * (c.lens.k2 + t2 * (c.lens.k3 + t2 * c.lens.k4))));
    if (td < td_max) break;
    td_max = td;
  }
  c.lens.circle = stitch::LensCircle{c.cx, c.cy, 0.99 * std::min(c.fx, c.fy) * td_max};
  const std::string problem = stitch::lens_problem(c);
  if (!problem.empty()) throw stitch::RigError(path + ": " + problem);
  return c;
}

// The planar rig of the set (front, back, left, right), the canvas the bird's-eye image.
inline stitch::Rig load_rig(const std::string& dir) {
  stitch::Rig rig;
  rig.projection = "plane";
  rig.reference = 0;
  for (const char* n : kNames) rig.cameras.push_back(load_camera(dir, n));
  rig.canvas_width = kTotalW;
  rig.canvas_height = kTotalH;
  return rig;
}

// Each view warped onto the canvas by our CPU warper (lens + homography), 1:1.
inline std::vector<cv::Mat> warp_views(const stitch::Rig& rig, std::vector<cv::Mat>& rgba) {
  const std::vector<stitch::ViewPlacement> views = stitch::place_views(rig, stitch::canvas_geometry(rig));
  auto warper = stitch::Warper::create(stitch::Backend::Cpu);
  warper->prepare(views);
  std::vector<cv::Mat> out;
  for (std::size_t i = 0; i < views.size(); ++i) {
    cv::Mat full(rig.canvas_height, rig.canvas_width, CV_8UC4, cv::Scalar::all(0));
    const stitch::Rect& r = views[i].roi;
    if (!r.empty()) {
      cv::Mat roi = full(cv::Rect(r.x, r.y, r.width, r.height));
      warper->warp(int(i), stitch::as_view(rgba[i]), stitch::as_view(roi));
    }
    out.push_back(full);
  }
  return out;
}

// The bird's-eye image the set's way: every camera sees the whole ground plane (the car's body
// is not in the model), so each is kept to its side (front: y < yt, back: y >= yb, left: x < xl,
// right: x >= xr) and the four corners, where two sides meet, blend them by distance to the
// sides' inner edges (the set's own corner blend is by masks drawn for this car). The default
// compositor picks by lens position weight, which on this rig favours far-field views.
inline cv::Mat compose_birdseye(const std::vector<cv::Mat>& warped) {
  cv::Mat out(kTotalH, kTotalW, CV_8UC4, cv::Scalar::all(0));
  const int xr = kTotalW - kXl, yb = kTotalH - kYt;
  for (int y = 0; y < kTotalH; ++y)
    for (int x = 0; x < kTotalW; ++x) {
      // front 0, back 1, left 2, right 3: how far inside each side's strip.
      const double in[4] = {double(kYt - y), double(y - yb + 1), double(kXl - x), double(x - xr + 1)};
      double wsum = 0, acc[4] = {0, 0, 0, 0};
      for (int c = 0; c < 4; ++c) {
        if (in[c] <= 0) continue;
        const cv::Vec4b v = warped[c].at<cv::Vec4b>(y, x);
        if (v[0] == 0 && v[1] == 0 && v[2] == 0) continue;  // that view has nothing here
        for (int k = 0; k < 4; ++k) acc[k] += in[c] * v[k];
        wsum += in[c];
      }
      if (wsum > 0)
        for (int k = 0; k < 4; ++k) out.at<cv::Vec4b>(y, x)[k] = cv::saturate_cast<uchar>(acc[k] / wsum);
    }
  return out;
}

// Undistorted views for measuring straightness use a pinhole of this times the lens's focal length:
// wide enough to keep the calibration mat's outer edges, where the fisheyes bend lines most.
constexpr double kUndistortFocalScale = 0.7;

// The camera's image undistorted to a pinhole of focal `f` (same size, same centre) with our lens
// model (stitch::lens_project), for measuring straightness.
inline cv::Mat undistort(const stitch::Camera& c, const cv::Mat& raw, double f) {
  cv::Mat mx(c.height, c.width, CV_32F), my(c.height, c.width, CV_32F);
  for (int y = 0; y < c.height; ++y)
    for (int x = 0; x < c.width; ++x) {
      Eigen::Vector2d q;
      const Eigen::Vector3d ray((x - c.cx) / f, (y - c.cy) / f, 1.0);
      const bool ok = stitch::lens_project(c, ray, q);
      mx.at<float>(y, x) = ok ? float(q.x()) : -1e6f;
      my.at<float>(y, x) = ok ? float(q.y()) : -1e6f;
    }
  cv::Mat out;
  cv::remap(raw, out, mx, my, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return out;
}

struct Straightness {
  int lines = 0;            // long edge segments measured
  double median_px = 0;     // median over the lines of the worst deviation from the fitted line
  double worst_px = 0;      // the worst
  // Bend: the sagitta of the parabola through each line's points over its chord, in percent of
  // the chord (scale-free, so raw and undistorted compare; the fit averages the edge noise that
  // the 90th-percentile deviation above keeps). Median and worst over the lines.
  double median_bend_pct = 0, worst_bend_pct = 0;
  std::vector<double> bends_pct;                 // per line
  std::vector<std::vector<cv::Point2f>> points;  // each line's edge points
};

// How much `pts` (edge points along one line) bend: a line fitted, each point's offset across
// it against its position along it, a parabola through those (least squares, points off by more
// than 3 robust sigmas dropped once); its sagitta over the chord, in percent of the chord.
inline double line_bend_pct(const std::vector<cv::Point2f>& pts) {
  cv::Vec4f l;
  cv::fitLine(pts, l, cv::DIST_L2, 0, 0.01, 0.01);
  const double dx = l[0], dy = l[1];
  std::vector<double> t, o;
  for (const auto& p : pts) {
    t.push_back((p.x - l[2]) * dx + (p.y - l[3]) * dy);
    o.push_back(-(p.x - l[2]) * dy + (p.y - l[3]) * dx);
  }
  const auto [lo, hi] = std::minmax_element(t.begin(), t.end());
  const double t0 = *lo, len = std::max(1e-6, *hi - *lo);
  std::vector<char> use(pts.size(), 1);
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (int pass = 0; pass < 2; ++pass) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (std::size_t k = 0; k < t.size(); ++k) {
      if (!use[k]) continue;
      const double s = (t[k] - t0) / len - 0.5;
      const Eigen::Vector3d row(1, s, s * s);
      A += row * row.transpose();
      b += row * o[k];
    }
    c = A.ldlt().solve(b);
    std::vector<double> res;
    for (std::size_t k = 0; k < t.size(); ++k) {
      const double s = (t[k] - t0) / len - 0.5;
      res.push_back(std::abs(o[k] - (c(0) + c(1) * s + c(2) * s * s)));
    }
    std::vector<double> sorted = res;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double cut = std::max(0.3, 3 * 1.4826 * sorted[sorted.size() / 2]);
    for (std::size_t k = 0; k < t.size(); ++k) use[k] = res[k] <= cut;
  }
  return 100.0 * std::abs(c(2)) / 4 / len;  // s in [-1/2, 1/2]: the rise at the ends over the middle
}

// How far `pts` stray from their line (a robust fit): the 90th percentile of the distances, so
// that a stray gradient peak (a checker corner, texture) does not count as a bend.
inline double line_deviation(const std::vector<cv::Point2f>& pts) {
  cv::Vec4f l;
  cv::fitLine(pts, l, cv::DIST_HUBER, 0, 0.01, 0.01);
  std::vector<double> d;
  for (const auto& p : pts) d.push_back(std::abs((p.x - l[2]) * -l[1] + (p.y - l[3]) * l[0]));
  std::nth_element(d.begin(), d.begin() + d.size() * 9 / 10, d.end());
  return d[d.size() * 9 / 10];
}

inline void summarise(Straightness& r, std::vector<double> worst) {
  r.lines = int(worst.size());
  if (worst.empty()) return;
  std::sort(worst.begin(), worst.end());
  r.median_px = worst[worst.size() / 2];
  r.worst_px = worst.back();
  r.bends_pct.clear();
  for (const auto& pts : r.points) r.bends_pct.push_back(line_bend_pct(pts));
  std::vector<double> b = r.bends_pct;
  std::sort(b.begin(), b.end());
  r.median_bend_pct = b[b.size() / 2];
  r.worst_bend_pct = b.back();
}

// The same edge points with the lens ignored: the undistorted image's lines (pinhole of focal f)
// taken back to the raw image, where they bend.
inline Straightness raw_straightness(const stitch::Camera& c, double f, const Straightness& undistorted) {
  Straightness r;
  std::vector<double> worst;
  for (const auto& line : undistorted.points) {
    std::vector<cv::Point2f> raw;
    for (const auto& p : line) {
      Eigen::Vector2d q;
      if (stitch::lens_project(c, Eigen::Vector3d((p.x - c.cx) / f, (p.y - c.cy) / f, 1.0), q))
        raw.emplace_back(float(q.x()), float(q.y()));
    }
    if (raw.size() < 10) continue;
    worst.push_back(line_deviation(raw));
    r.points.push_back(raw);
  }
  summarise(r, worst);
  return r;
}

// Straightness of the long edges of `img` (a calibration mat's checker edges): line segments
// (cv::HoughLinesP on Canny edges, >= min_len px); along each, the sub-pixel position of the edge
// (the gradient peak across the line, +-band px) at every pixel; a least-squares line through
// those; each line's worst deviation from it. A curved edge (a lens left in) deviates by its
// sagitta, up to the band.
inline Straightness measure_straightness(const cv::Mat& img, double min_len = 100, int band = 6) {
  cv::Mat gray, blur, edges, gx, gy;
  if (img.channels() == 4) cv::cvtColor(img, gray, cv::COLOR_BGRA2GRAY);
  else if (img.channels() == 3) cv::cvtColor(img, gray, cv::COLOR_BGR2GRAY);
  else gray = img;
  cv::GaussianBlur(gray, blur, cv::Size(5, 5), 1.2);
  cv::Canny(blur, edges, 60, 150);
  cv::Sobel(blur, gx, CV_32F, 1, 0);
  cv::Sobel(blur, gy, CV_32F, 0, 1);
  std::vector<cv::Vec4i> segs;
  cv::HoughLinesP(edges, segs, 1, CV_PI / 360, 80, min_len, 3);
  // Keep one segment per line: drop those close and parallel to a longer one.
  std::sort(segs.begin(), segs.end(), [](const cv::Vec4i& a, const cv::Vec4i& b) {
    return std::hypot(a[2] - a[0], a[3] - a[1]) > std::hypot(b[2] - b[0], b[3] - b[1]);
  });
  std::vector<cv::Vec4i> kept;
  for (const auto& s : segs) {
    const Eigen::Vector2d p0(s[0], s[1]), p1(s[2], s[3]), d = (p1 - p0).normalized(), m = 0.5 * (p0 + p1);
    bool dup = false;
    for (const auto& k : kept) {
      const Eigen::Vector2d q0(k[0], k[1]), q1(k[2], k[3]), e = (q1 - q0).normalized();
      const Eigen::Vector2d n(-e.y(), e.x());
      if (std::abs(d.dot(e)) > 0.98 && std::abs((m - q0).dot(n)) < 2.0 * band &&
          std::abs((m - 0.5 * (q0 + q1)).dot(e)) < 0.5 * (q1 - q0).norm() + 0.5 * (p1 - p0).norm())
        dup = true;
    }
    if (!dup) kept.push_back(s);
  }
  std::vector<double> worst;
  std::vector<std::vector<cv::Point2f>> lines;
  for (const auto& s : kept) {
    const Eigen::Vector2d p0(s[0], s[1]), p1(s[2], s[3]);
    const double len = (p1 - p0).norm();
    const Eigen::Vector2d d = (p1 - p0) / len, n(-d.y(), d.x());
    std::vector<cv::Point2f> pts;
    for (double t = 4; t < len - 4; t += 1.0) {
      // The gradient magnitude across the line; its peak, refined by a parabola.
      double best = -1;
      int bk = 0;
      std::vector<double> g(2 * band + 1, 0);
      for (int k = -band; k <= band; ++k) {
        // Sampled exactly on the normal (bilinear): rounding to the pixel grid would add a
        // staircase of up to half a pixel to the points of a slanted line.
        const Eigen::Vector2d q = p0 + t * d + double(k) * n;
        const int x = int(std::floor(q.x())), y = int(std::floor(q.y()));
        if (x < 1 || y < 1 || x >= gray.cols - 2 || y >= gray.rows - 2) continue;
        const double fx = q.x() - x, fy = q.y() - y;
        auto at = [&](const cv::Mat& m) {
          return (1 - fy) * ((1 - fx) * m.at<float>(y, x) + fx * m.at<float>(y, x + 1)) +
                 fy * ((1 - fx) * m.at<float>(y + 1, x) + fx * m.at<float>(y + 1, x + 1));
        };
        const double v = std::abs(at(gx) * n.x() + at(gy) * n.y());
        g[k + band] = v;
        if (v > best) best = v, bk = k;
      }
      if (best < 40 || bk == -band || bk == band) continue;  // no clear edge here
      const double a = g[bk + band - 1], b = g[bk + band], c = g[bk + band + 1];
      const double off = (a - 2 * b + c) < 0 ? 0.5 * (a - c) / (a - 2 * b + c) : 0.0;
      const Eigen::Vector2d q = p0 + t * d + (bk + off) * n;
      pts.emplace_back(float(q.x()), float(q.y()));
    }
    if (pts.size() < 0.6 * len) continue;  // the edge is not there along most of the segment
    worst.push_back(line_deviation(pts));
    lines.push_back(pts);
  }
  Straightness r;
  r.points = lines;
  summarise(r, worst);
  return r;
}

}  // namespace surround
