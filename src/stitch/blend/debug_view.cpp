#include "stitch/blend/debug_view.hpp"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>

#include "stitch/blend/blender_cpu.hpp"
#include "stitch/blend/multiband.hpp"

namespace stitch {

void debug_view_color(int i, uint8_t rgb[3]) {
  // Hues a golden angle apart, full saturation: neighbours never look alike.
  cv::Mat hsv(1, 1, CV_8UC3, cv::Scalar(int(i * 137.508) % 180, 255, 255)), out;
  cv::cvtColor(hsv, out, cv::COLOR_HSV2RGB);
  const cv::Vec3b c = out.at<cv::Vec3b>(0, 0);
  rgb[0] = c[0], rgb[1] = c[1], rgb[2] = c[2];
}

namespace {

cv::Scalar view_color(int i) {
  uint8_t c[3];
  debug_view_color(i, c);
  return cv::Scalar(c[0], c[1], c[2], 255);
}

// Each view's coverage in output pixels (CV_8U, output-sized, 255 where its weight is > 0).
std::vector<cv::Mat> coverage(const std::vector<ViewPlacement>& views, cv::Size size) {
  std::vector<cv::Mat> out;
  for (const ViewPlacement& v : views) {
    cv::Mat m(size, CV_8U, cv::Scalar(0));
    if (!v.roi.empty()) {
      const cv::Mat w = position_weight_map(v);
      cv::Mat roi = m(cv::Rect(v.roi.x, v.roi.y, v.roi.width, v.roi.height) & cv::Rect(0, 0, size.width, size.height));
      cv::Mat mask = w(cv::Rect(0, 0, roi.cols, roi.rows)) > 0;
      mask.copyTo(roi);
    }
    out.push_back(m);
  }
  return out;
}

// The label each output pixel shows (nearest label-grid pixel).
cv::Mat labels_in_output(const DebugScene& s, cv::Size size) {
  cv::Mat out(size, CV_8U, cv::Scalar(kNoView));
  if (!s.labels) return out;
  const Eigen::Matrix3d back = s.label_to_output.inverse();
  for (int y = 0; y < size.height; ++y) {
    uint8_t* o = out.ptr<uint8_t>(y);
    for (int x = 0; x < size.width; ++x) {
      const Eigen::Vector3d p = back * Eigen::Vector3d(x, y, 1);
      const int lx = int(std::lround(p.x() / p.z())), ly = int(std::lround(p.y() / p.z()));
      if (lx >= 0 && ly >= 0 && lx < s.label_width && ly < s.label_height)
        o[x] = s.labels[std::size_t(ly) * s.label_width + lx];
    }
  }
  return out;
}

}  // namespace

void draw_debug_view(const ImageView& out, unsigned flags, const DebugScene& scene) {
  if (out.on_device) throw std::invalid_argument("the debug view draws in host memory");
  if (!flags || out.empty()) return;
  cv::Mat img(out.height, out.width, CV_8UC4, out.data, out.pitch);
  const cv::Size size(out.width, out.height);
  std::vector<cv::Mat> cover;
  if (flags & (kDebugOverlaps | kDebugOutlines)) cover = coverage(scene.views, size);
  if (flags & kDebugOverlaps) {
    cv::Mat count(size, CV_8U, cv::Scalar(0));
    for (const cv::Mat& c : cover) count += c / 255;
    cv::Mat tint(size, CV_8UC4, cv::Scalar(255, 230, 0, 255)), mixed;
    cv::addWeighted(img, 0.7, tint, 0.3, 0, mixed);
    mixed.copyTo(img, count >= 2);
  }
  if (flags & kDebugSeams) {
    // A seam pixel shows a different view than its right or lower neighbour (both covered).
    const cv::Mat lab = labels_in_output(scene, size);
    for (int y = 0; y + 1 < lab.rows; ++y)
      for (int x = 0; x + 1 < lab.cols; ++x) {
        const uint8_t l = lab.at<uint8_t>(y, x), r = lab.at<uint8_t>(y, x + 1), d = lab.at<uint8_t>(y + 1, x);
        if (l == kNoView) continue;
        if ((r != kNoView && r != l) || (d != kNoView && d != l))
          cv::rectangle(img, cv::Rect(x, y, 2, 2), cv::Scalar(255, 255, 255, 255), cv::FILLED);
      }
  }
  if (flags & kDebugOutlines) {
    for (std::size_t i = 0; i < cover.size(); ++i) {
      std::vector<std::vector<cv::Point>> contours;
      cv::findContours(cover[i], contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
      cv::drawContours(img, contours, -1, view_color(int(i)), 2, cv::LINE_AA);
      if (!scene.views[i].roi.empty()) {
        const Rect& r = scene.views[i].roi;
        cv::putText(img, "view " + std::to_string(i), cv::Point(r.x + 8, r.y + 24), cv::FONT_HERSHEY_SIMPLEX, 0.7,
                    view_color(int(i)), 2, cv::LINE_AA);
      }
    }
  }
  if (flags & kDebugFlow) {
    for (const FlowPairStats& f : scene.flow) {
      const Eigen::Matrix3d& A = scene.canvas_to_output;
      const Eigen::Vector3d p0 = A * Eigen::Vector3d(f.rect.x, f.rect.y, 1);
      const Eigen::Vector3d p1 = A * Eigen::Vector3d(f.rect.x + f.rect.width, f.rect.y + f.rect.height, 1);
      const cv::Rect box(cv::Point(int(p0.x() / p0.z()), int(p0.y() / p0.z())),
                         cv::Point(int(p1.x() / p1.z()), int(p1.y() / p1.z())));
      // Heat: green at rest, red from 8 px of mean flow on.
      const double t = std::min(1.0, f.mean_magnitude / 8.0);
      const cv::Scalar heat(255 * t, 255 * (1 - t), 0, 255);
      cv::rectangle(img, box, heat, 2);
      char text[96];
      std::snprintf(text, sizeof text, "flow %d-%d: %.1f px, %.0f%% sure", f.view_a, f.view_b, f.mean_magnitude,
                    100 * f.confident_fraction);
      cv::putText(img, text, cv::Point(box.x + 6, box.y + box.height - 10), cv::FONT_HERSHEY_SIMPLEX, 0.5, heat, 1,
                  cv::LINE_AA);
      // The overlap's decision (stitchflowwarp's fallback): on/off, gain, error without/with.
      std::snprintf(text, sizeof text, "%s x%.2f, err %.1f -> %.1f", f.flow_on ? "flow on" : "homography", f.gain,
                    f.error_homography, f.error_flow);
      cv::putText(img, text, cv::Point(box.x + 6, box.y + box.height - 28), cv::FONT_HERSHEY_SIMPLEX, 0.5, heat, 1,
                  cv::LINE_AA);
    }
  }
}

}  // namespace stitch
