// Reading clip sets for the benchmarks (kept apart from bench_common.cpp so that benchmarks
// that read no video do not link OpenCV's videoio and its codec libraries).
#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "bench_common.hpp"

namespace stitch_bench {

namespace {
bool is_image(const std::string& p) {
  auto ends = [&](const char* s) {
    const std::string e(s);
    return p.size() >= e.size() && std::equal(e.rbegin(), e.rend(), p.rbegin(),
                                              [](char a, char b) { return a == std::tolower(b); });
  };
  return ends(".jpg") || ends(".jpeg") || ends(".png");
}
}  // namespace

std::vector<std::vector<cv::Mat>> read_sets(const std::vector<std::string>& paths, int frames, int step) {
  std::vector<std::vector<cv::Mat>> seq;
  if (!paths.empty() && is_image(paths[0])) {
    std::vector<cv::Mat> set;
    for (const auto& p : paths) {
      cv::Mat f = cv::imread(p, cv::IMREAD_COLOR);
      if (f.empty()) {
        std::fprintf(stderr, "cannot read %s\n", p.c_str());
        return {};
      }
      cv::cvtColor(f, f, cv::COLOR_BGR2RGBA);
      set.push_back(f);
    }
    seq.push_back(set);
    return seq;
  }
  std::vector<cv::VideoCapture> caps;
  for (const auto& c : paths) {
    caps.emplace_back(c);
    if (!caps.back().isOpened()) {
      std::fprintf(stderr, "cannot open %s\n", c.c_str());
      return {};
    }
  }
  for (int t = 0; t < frames * step; ++t) {
    std::vector<cv::Mat> set;
    for (auto& cap : caps) {
      cv::Mat f;
      if (!cap.read(f)) return seq;
      cv::cvtColor(f, f, cv::COLOR_BGR2RGBA);
      set.push_back(f);
    }
    if (t % step == 0) seq.push_back(set);
  }
  return seq;
}

}  // namespace stitch_bench
