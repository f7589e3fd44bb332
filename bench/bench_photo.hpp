// Small helpers of the lens benchmarks: a photo as RGBA, comma-separated arguments.
#pragma once

#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

namespace stitch_bench {

// The photo at `path` as RGBA, at most `max_width` px wide when > 0 (aspect kept); empty, with
// a message on stderr, when it cannot be read.
inline cv::Mat read_photo_rgba(const std::string& path, int max_width = 0) {
  const cv::Mat bgr = cv::imread(path, cv::IMREAD_COLOR);
  cv::Mat photo;
  if (bgr.empty()) {
    std::fprintf(stderr, "cannot read %s\n", path.c_str());
    return photo;
  }
  cv::cvtColor(bgr, photo, cv::COLOR_BGR2RGBA);
  if (max_width > 0 && photo.cols > max_width)
    cv::resize(photo, photo, cv::Size(max_width, max_width * photo.rows / photo.cols), 0, 0, cv::INTER_AREA);
  return photo;
}

// "a,b,c" -> {"a", "b", "c"}.
inline std::vector<std::string> comma_list(const std::string& s) {
  std::vector<std::string> v;
  std::stringstream ss(s);
  std::string x;
  while (std::getline(ss, x, ',')) v.push_back(x);
  return v;
}

// "0.1,-0.2" -> {0.1, -0.2}.
inline std::vector<double> comma_numbers(const std::string& s) {
  std::vector<double> v;
  for (const std::string& x : comma_list(s)) v.push_back(std::stod(x));
  return v;
}

}  // namespace stitch_bench
