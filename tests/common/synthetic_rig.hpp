// Hand-made rigs for tests (header-only: the CUDA tests link no test_data.cpp).
#pragma once
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace testdata {

// A centred pinhole camera of width x height with focal length f (no homography).
inline stitch::Camera pinhole(int width, int height, double f) {
  stitch::Camera c;
  c.width = width;
  c.height = height;
  c.fx = c.fy = f;
  c.cx = (width - 1) * 0.5;
  c.cy = (height - 1) * 0.5;
  return c;
}

// n cameras side by side, `shift` pixels apart on the canvas (pure translations), laid out.
inline stitch::Rig shifted_rig(int n, int width, int height, double shift) {
  stitch::Rig rig;
  for (int i = 0; i < n; ++i) {
    stitch::Camera c = pinhole(width, height, width);
    Eigen::Matrix3d H = Eigen::Matrix3d::Identity();
    H(0, 2) = shift * i;
    c.homography = H;
    rig.cameras.push_back(c);
  }
  stitch::rig_layout_canvas(rig);
  return rig;
}

// Shifts the content of `img` by a smooth field (up to `amplitude` px): local parallax.
inline cv::Mat with_parallax(const cv::Mat& img, double amplitude) {
  cv::Mat mx(img.size(), CV_32F), my(img.size(), CV_32F);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      mx.at<float>(y, x) = float(x - amplitude * std::sin(CV_PI * y / img.rows) * std::cos(0.01 * x));
      my.at<float>(y, x) = float(y - 0.5 * amplitude * std::cos(CV_PI * x / img.cols));
    }
  cv::Mat out;
  cv::remap(img, out, mx, my, cv::INTER_CUBIC, cv::BORDER_REFLECT);
  return out;
}

}  // namespace testdata

namespace testdata {

// Three 480x360 cameras of `photo` on a rotating rig (yaw -30/0/30 deg, a little roll; rough
// homographies), camera i's exposure scaled by gains[i].
struct RotatingRig {
  stitch::Rig rig;
  std::vector<cv::Mat> frames;  // RGBA
};

inline RotatingRig rotating_rig(const cv::Mat& photo_rgba, const double gains[3]) {
  RotatingRig s;
  const int w = 480, h = 360;
  s.rig.reference = 1;
  for (int i = 0; i < 3; ++i) {
    stitch::Camera c = pinhole(w, h, 420.0);
    c.yaw_deg = (i - 1) * 30.0;
    c.roll_deg = (i - 1) * 2.0;
    s.rig.cameras.push_back(c);
    cv::Mat f;
    cv::resize(photo_rgba(cv::Rect(i * 450, 100, 700, 525)), f, cv::Size(w, h), 0, 0, cv::INTER_AREA);
    f.convertTo(f, -1, gains[i]);
    cv::Mat alpha(f.size(), CV_8U, cv::Scalar(255));
    cv::insertChannel(alpha, f, 3);  // gains touch colour, not alpha
    s.frames.push_back(f);
  }
  stitch::rig_compute_rough_homographies(s.rig);
  return s;
}

}  // namespace testdata
