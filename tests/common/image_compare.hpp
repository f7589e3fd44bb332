// Image comparison shared by the tests (header-only: test_cuda links no imgcodecs).
#pragma once
#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

namespace testdata {

// PSNR over the RGB channels of two RGBA images.
inline double psnr_rgb(const cv::Mat& a, const cv::Mat& b) {
  cv::Mat a3, b3;
  cv::cvtColor(a, a3, cv::COLOR_RGBA2RGB);
  cv::cvtColor(b, b3, cv::COLOR_RGBA2RGB);
  return cv::PSNR(a3, b3);
}

// PSNR over the RGB channels of two RGBA images, counting only the pixels where `mask` is set.
inline double masked_psnr_rgb(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  cv::Mat a3, b3;
  cv::cvtColor(a, a3, cv::COLOR_RGBA2RGB);
  cv::cvtColor(b, b3, cv::COLOR_RGBA2RGB);
  a3.convertTo(a3, CV_32F);
  b3.convertTo(b3, CV_32F);
  cv::Mat d = a3 - b3;
  d = d.mul(d);
  d.setTo(cv::Scalar::all(0), mask == 0);
  const cv::Scalar s = cv::sum(d);
  const double mse = (s[0] + s[1] + s[2]) / std::max(1.0, 3.0 * cv::countNonZero(mask));
  return 10 * std::log10(255.0 * 255.0 / std::max(mse, 1e-10));
}

}  // namespace testdata
