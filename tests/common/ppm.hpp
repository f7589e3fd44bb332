// Binary PPM (P6) reading, for binaries that must not link OpenCV's imgcodecs (its GDAL and
// codec dependencies would not fit the bundle carried to the GPU host).
#pragma once
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>
#include <string>

namespace testdata {

// RGBA image from a P6 PPM with maxval 255; empty on any error.
inline cv::Mat read_ppm_rgba(const std::string& path) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) return cv::Mat();
  int w = 0, h = 0, maxval = 0;
  char magic[3] = {0};
  cv::Mat rgb;
  if (std::fscanf(f, "%2s %d %d %d", magic, &w, &h, &maxval) == 4 && std::string(magic) == "P6" && maxval == 255 &&
      w > 0 && h > 0 && w < 65536 && h < 65536 && std::fgetc(f) != EOF) {
    rgb.create(h, w, CV_8UC3);
    if (std::fread(rgb.data, 1, rgb.total() * 3, f) != rgb.total() * 3) rgb.release();
  }
  std::fclose(f);
  if (rgb.empty()) return rgb;
  cv::Mat rgba;
  cv::cvtColor(rgb, rgba, cv::COLOR_RGB2RGBA);
  return rgba;
}

// The repository photo (data/photos/boat1_1600.jpg), decoded to PPM at build time and named by
// STITCH_TEST_PPM; throws when it cannot be read.
inline cv::Mat test_photo() {
  const char* path = std::getenv("STITCH_TEST_PPM");
  cv::Mat p = read_ppm_rgba(path ? path : "");
  if (p.empty()) throw std::runtime_error(std::string("cannot read the test photo STITCH_TEST_PPM=") + (path ? path : ""));
  return p;
}


// The benchmarks' photo: read, or say how to get one and exit with status 2.
inline cv::Mat read_photo_or_exit(const std::string& path) {
  cv::Mat photo = read_ppm_rgba(path);
  if (photo.empty()) {
    std::fprintf(stderr, "cannot read %s (a P6 PPM; run from the repository root or pass --photo)\n", path.c_str());
    std::exit(2);
  }
  return photo;
}

}  // namespace testdata
