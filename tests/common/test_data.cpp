#include "test_data.hpp"

#include <Eigen/Dense>

#include <cstdlib>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <unistd.h>

namespace testdata {

std::string source_dir() {
  const char* s = std::getenv("STITCH_SOURCE_DIR");
  return s ? s : ".";
}

std::string repo_path(const std::string& rel) { return source_dir() + "/" + rel; }

std::string shared_path(const std::string& rel) {
  const char* s = std::getenv("STITCH_SHARED_DATA");
  std::string base = s ? s : source_dir() + "/../shared/data";
  std::string p = base + "/" + rel;
  return std::filesystem::exists(p) ? p : std::string();
}

std::string temp_dir() {
  static std::string dir;
  if (dir.empty()) {
    auto p = std::filesystem::temp_directory_path() / ("stitch-test-" + std::to_string(getpid()));
    std::filesystem::create_directories(p);
    dir = p.string();
  }
  return dir;
}

cv::Mat load_rgba(const std::string& path) {
  cv::Mat bgr = cv::imread(path, cv::IMREAD_COLOR);
  if (bgr.empty()) throw std::runtime_error("cannot read test image " + path);
  cv::Mat rgba;
  cv::cvtColor(bgr, rgba, cv::COLOR_BGR2RGBA);
  return rgba;
}

}  // namespace testdata
