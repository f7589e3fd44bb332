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

std::optional<Rig> circular_fisheye_rig(const std::vector<ImageView>& frames, double fov_deg,
                                        const std::vector<int>& slots) {
  if (frames.size() < 2 || !(fov_deg > 90 && fov_deg < 360)) return std::nullopt;
  if (!slots.empty() && slots.size() != frames.size()) return std::nullopt;
  Rig rig;
  rig.projection = "spherical";
  rig.reference = 0;
  const int n = int(frames.size());
  for (int i = 0; i < n; ++i) {
    const std::optional<LensCircle> circle = find_image_circle(frames[i]);
    if (!circle) return std::nullopt;
    Camera c;
    c.width = frames[i].width;
    c.height = frames[i].height;
    c.fx = c.fy = circle->radius / (0.5 * fov_deg * CV_PI / 180.0);
    c.cx = circle->cx;
    c.cy = circle->cy;
    c.lens.model = Lens::Model::Fisheye;
    c.lens.circle = circle;
    c.lens.estimate = true;
    c.yaw_deg = 360.0 * (slots.empty() ? i : slots[i]) / n;  // two: back to back; more: evenly around
    if (c.yaw_deg > 180.0) c.yaw_deg -= 360.0;
    rig.cameras.push_back(c);
  }
  return rig;
}

}  // namespace stitch
