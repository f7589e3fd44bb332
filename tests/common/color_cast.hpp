// A known color distortion for the color tests (header-only: the CUDA tests link no
// test_data.cpp).
#pragma once
#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace testdata {

// out = in * M per pixel (row vector convention of eq. 4), rounded and clamped.
inline void distort(cv::Mat& img, const Eigen::Matrix3d& M) {
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      cv::Vec4b& p = img.at<cv::Vec4b>(y, x);
      const Eigen::RowVector3d v = Eigen::RowVector3d(p[0], p[1], p[2]) * M;
      for (int c = 0; c < 3; ++c) p[c] = cv::saturate_cast<uint8_t>(v[c]);
    }
}

}  // namespace testdata
