// Wrapping core ImageViews as OpenCV matrices and back (no copies).
#pragma once
#include <opencv2/core.hpp>
#include <stdexcept>

#include "stitch/image.hpp"

namespace stitch {

inline cv::Mat as_mat(const ImageView& v) {
  if (v.on_device) throw std::invalid_argument("device image cannot be wrapped as cv::Mat");
  return cv::Mat(v.height, v.width, CV_8UC4, v.data, v.pitch);
}

inline ImageView as_view(cv::Mat& m) {
  if (m.type() != CV_8UC4) throw std::invalid_argument("expected an RGBA (CV_8UC4) matrix");
  ImageView v;
  v.data = m.data;
  v.pitch = m.step;
  v.width = m.cols;
  v.height = m.rows;
  return v;
}

}  // namespace stitch
