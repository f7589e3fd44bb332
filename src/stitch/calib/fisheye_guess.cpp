#include "stitch/calib/fisheye_guess.hpp"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "stitch/cv_interop.hpp"

namespace stitch {

namespace {
constexpr int kDarkLuma = 24;           // black outside the circle, after compression
constexpr double kMinRadiusShare = 0.3;  // of the shorter side
constexpr double kMaxCentreOffset = 0.15;  // of the shorter side
// The circle through most of `contour`'s points (within 1 px), near the enclosing circle
// (centre, radius); nullopt when no arc of at least half the points agrees.
std::optional<cv::Vec3d> fit_rim(const std::vector<cv::Point>& contour, cv::Point2f centre, float radius) {
  std::vector<cv::Point2d> pts;
  const std::size_t step = std::max<std::size_t>(1, contour.size() / 720);
  for (std::size_t k = 0; k < contour.size(); k += step) pts.emplace_back(contour[k].x, contour[k].y);
  if (pts.size() < 24) return std::nullopt;
  auto circle3 = [](const cv::Point2d& a, const cv::Point2d& b, const cv::Point2d& c, cv::Vec3d& out) {
    const double d = 2 * (a.x * (b.y - c.y) + b.x * (c.y - a.y) + c.x * (a.y - b.y));
    if (std::abs(d) < 1e-9) return false;
    const double a2 = a.dot(a), b2 = b.dot(b), c2 = c.dot(c);
    const double ux = (a2 * (b.y - c.y) + b2 * (c.y - a.y) + c2 * (a.y - b.y)) / d;
    const double uy = (a2 * (c.x - b.x) + b2 * (a.x - c.x) + c2 * (b.x - a.x)) / d;
    out = cv::Vec3d(ux, uy, std::hypot(a.x - ux, a.y - uy));
    return true;
  };
  constexpr double kBand = 1.0;
  auto inliers_of = [&](const cv::Vec3d& c, std::vector<int>* in) {
    int n = 0;
    for (int k = 0; k < int(pts.size()); ++k)
      if (std::abs(std::hypot(pts[k].x - c[0], pts[k].y - c[1]) - c[2]) <= kBand) {
        ++n;
        if (in) in->push_back(k);
      }
    return n;
  };
  cv::Vec3d best(centre.x, centre.y, radius);
  int best_n = inliers_of(best, nullptr);
  cv::RNG rng(12345);
  const int m = int(pts.size());
  for (int it = 0; it < 400; ++it) {
    // Three points spread around the contour (a third apart, jittered): a well-conditioned circle.
    const int i0 = rng.uniform(0, m), i1 = (i0 + m / 3 + rng.uniform(-m / 12, m / 12 + 1) + m) % m,
              i2 = (i0 + 2 * m / 3 + rng.uniform(-m / 12, m / 12 + 1) + m) % m;
    cv::Vec3d c;
    if (!circle3(pts[i0], pts[i1], pts[i2], c)) continue;
    if (std::hypot(c[0] - centre.x, c[1] - centre.y) > 0.1 * radius || std::abs(c[2] - radius) > 0.1 * radius) continue;
    const int n = inliers_of(c, nullptr);
    if (n > best_n) best_n = n, best = c;
  }
  if (best_n < int(pts.size()) / 2) return std::nullopt;
  // Least squares (algebraic, Kasa) on the inliers, twice.
  for (int pass = 0; pass < 2; ++pass) {
    std::vector<int> in;
    inliers_of(best, &in);
    if (in.size() < 12) break;
    cv::Mat A(int(in.size()), 3, CV_64F), b(int(in.size()), 1, CV_64F), x;
    for (int r = 0; r < int(in.size()); ++r) {
      const cv::Point2d& q = pts[in[r]];
      A.at<double>(r, 0) = q.x, A.at<double>(r, 1) = q.y, A.at<double>(r, 2) = 1;
      b.at<double>(r) = q.x * q.x + q.y * q.y;
    }
    if (!cv::solve(A, b, x, cv::DECOMP_SVD)) break;
    const double cx = 0.5 * x.at<double>(0), cy = 0.5 * x.at<double>(1);
    const double r2 = x.at<double>(2) + cx * cx + cy * cy;
    if (!(r2 > 0)) break;
    best = cv::Vec3d(cx, cy, std::sqrt(r2));
  }
  return best;
}

}  // namespace

std::optional<LensCircle> find_image_circle(const ImageView& frame) {
  if (frame.empty() || frame.on_device || frame.width < 32 || frame.height < 32) return std::nullopt;
  cv::Mat gray;
  cv::cvtColor(as_mat(frame), gray, cv::COLOR_RGBA2GRAY);
  // Work at up to 512 px: the circle's shape, not its texture.
  const double scale = std::min(1.0, 512.0 / std::max(frame.width, frame.height));
  if (scale < 1.0) cv::resize(gray, gray, cv::Size(), scale, scale, cv::INTER_AREA);
  const int side = std::min(gray.cols, gray.rows), patch = std::max(2, side / 16);
  // The four corners must be black: a circular fisheye sees nothing there.
  for (const cv::Point corner : {cv::Point(0, 0), cv::Point(gray.cols - patch, 0), cv::Point(0, gray.rows - patch),
                                 cv::Point(gray.cols - patch, gray.rows - patch)})
    if (cv::mean(gray(cv::Rect(corner, cv::Size(patch, patch))))[0] > kDarkLuma / 2) return std::nullopt;
  cv::Mat lit = gray > kDarkLuma;
  // Dark scene content inside the disc must not cut it up: close small holes first.
  cv::morphologyEx(lit, lit, cv::MORPH_CLOSE, cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(9, 9)));
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(lit, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);
  if (contours.empty()) return std::nullopt;
  const auto& disc = *std::max_element(contours.begin(), contours.end(), [](const auto& a, const auto& b) {
    return cv::contourArea(a) < cv::contourArea(b);
  });
  cv::Point2f centre;
  float radius = 0;
  cv::minEnclosingCircle(disc, centre, radius);
  const double area = cv::contourArea(disc), circle_area = CV_PI * radius * radius;
  // Dark scene content at the rim (a 360 photo's black nadir, a shadow) cuts into the lit disc,
  // and the enclosing circle follows the cut: 1.25 px off centre on a 200-degree fisheye of
  // 640 px, the principal point with it (branch probe360: ~1 px seams). The rim is the largest
  // arc of contour points on one circle: a RANSAC over 3-point circles, refined by least squares.
  if (const std::optional<cv::Vec3d> rim = fit_rim(disc, centre, radius)) {
    centre = cv::Point2f(float((*rim)[0]), float((*rim)[1]));
    radius = float((*rim)[2]);
  }
  // One disc: it fills its enclosing circle (a rectangle or a blob does not), it is large and
  // near the centre. A circle the frame cuts off is not taken (its enclosing circle is not the lens's).
  if (radius < kMinRadiusShare * side || area < 0.85 * circle_area) return std::nullopt;
  if (std::hypot(centre.x - 0.5 * (gray.cols - 1), centre.y - 0.5 * (gray.rows - 1)) > kMaxCentreOffset * side)
    return std::nullopt;
  // Back to full resolution, 2% inside the lit edge: the rim is dimmed and soft (vignetting,
  // compression), and pixels within the circle take part in seams and blends at full weight.
  LensCircle c;
  c.cx = (centre.x + 0.5) / scale - 0.5;
  c.cy = (centre.y + 0.5) / scale - 0.5;
  c.radius = std::max(1.0, 0.98 * (radius + 0.5) / scale - 1.0);
  return c;
}

std::optional<std::vector<LensCircle>> find_image_circles(const std::vector<ImageView>& frames) {
  std::vector<LensCircle> circles;
  for (const ImageView& f : frames) {
    const std::optional<LensCircle> circle = find_image_circle(f);
    if (!circle) return std::nullopt;
    circles.push_back(*circle);
  }
  return circles;
}

std::optional<Rig> circular_fisheye_rig(const std::vector<ImageView>& frames, const std::vector<LensCircle>& circles,
                                        double fov_deg, const std::vector<int>& slots) {
  if (frames.size() < 2 || circles.size() != frames.size() || !(fov_deg > 90 && fov_deg < 360)) return std::nullopt;
  if (!slots.empty() && slots.size() != frames.size()) return std::nullopt;
  Rig rig;
  rig.projection = "spherical";
  rig.reference = 0;
  const int n = int(frames.size());
  for (int i = 0; i < n; ++i) {
    const LensCircle& circle = circles[std::size_t(i)];
    Camera c;
    c.width = frames[i].width;
    c.height = frames[i].height;
    c.fx = c.fy = circle.radius / (0.5 * fov_deg * CV_PI / 180.0);
    c.cx = circle.cx;
    c.cy = circle.cy;
    c.lens.model = Lens::Model::Fisheye;
    c.lens.circle = circle;
    c.lens.estimate = true;
    c.yaw_deg = 360.0 * (slots.empty() ? i : slots[i]) / n;  // two: back to back; more: evenly around
    if (c.yaw_deg > 180.0) c.yaw_deg -= 360.0;
    rig.cameras.push_back(c);
  }
  return rig;
}

std::optional<Rig> circular_fisheye_rig(const std::vector<ImageView>& frames, double fov_deg,
                                        const std::vector<int>& slots) {
  if (frames.size() < 2 || !(fov_deg > 90 && fov_deg < 360)) return std::nullopt;
  const std::optional<std::vector<LensCircle>> circles = find_image_circles(frames);
  if (!circles) return std::nullopt;
  return circular_fisheye_rig(frames, *circles, fov_deg, slots);
}

}  // namespace stitch
