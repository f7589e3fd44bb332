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

stitch::Camera pinhole(int width, int height, double f) {
  stitch::Camera c;
  c.width = width;
  c.height = height;
  c.fx = c.fy = f;
  c.cx = (width - 1) * 0.5;
  c.cy = (height - 1) * 0.5;
  return c;
}

stitch::Rig shifted_rig(int n, int width, int height, double shift) {
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

}  // namespace testdata
