// Image comparison shared by the tests (header-only: test_cuda links no imgcodecs).
#pragma once
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

}  // namespace testdata
