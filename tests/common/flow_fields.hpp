// Known displacement fields for the dense-flow tests (header-only: used by binaries that go
// to the GPU host and link no test_data.cpp).
#pragma once
#include <cmath>
#include <opencv2/imgproc.hpp>

namespace testdata {

// A smooth field (a few pixels, varying over the image) like parallax in an overlap.
inline cv::Mat smooth_field(cv::Size size, double amplitude) {
  cv::Mat f(size, CV_32FC2);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      const double u = amplitude * std::sin(2 * CV_PI * x / size.width) * std::cos(CV_PI * y / size.height);
      const double v = 0.5 * amplitude * std::cos(2 * CV_PI * y / size.height + x * 0.004);
      f.at<cv::Vec2f>(y, x) = {float(u), float(v)};
    }
  return f;
}

// `to` = `from` displaced by `field`: to(x + f(x)) = from(x), built by backward mapping
// with the field sampled at the target (smooth, so the difference is second order).
inline cv::Mat displace(const cv::Mat& from, const cv::Mat& field) {
  cv::Mat mx(from.size(), CV_32F), my(from.size(), CV_32F);
  for (int y = 0; y < from.rows; ++y)
    for (int x = 0; x < from.cols; ++x) {
      const cv::Vec2f d = field.at<cv::Vec2f>(y, x);
      mx.at<float>(y, x) = float(x - d[0]);
      my.at<float>(y, x) = float(y - d[1]);
    }
  cv::Mat to;
  cv::remap(from, to, mx, my, cv::INTER_CUBIC, cv::BORDER_REFLECT);
  return to;
}

}  // namespace testdata
