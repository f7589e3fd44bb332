#include "bench_common.hpp"

#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

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

Comparison compare(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  Comparison s;
  s.pixels = cv::countNonZero(mask);
  if (s.pixels < 100) return s;
  cv::Mat d;
  cv::absdiff(a, b, d);
  const cv::Scalar mad = cv::mean(d, mask);
  s.mad = (mad[0] + mad[1] + mad[2]) / 3.0;
  {
    cv::Mat fa, fb, la, lb;
    a.convertTo(fa, CV_32F);
    b.convertTo(fb, CV_32F);
    cv::GaussianBlur(fa, la, cv::Size(0, 0), 8.0);
    cv::GaussianBlur(fb, lb, cv::Size(0, 0), 8.0);
    cv::Mat dd;
    cv::absdiff(fa - la, fb - lb, dd);
    const cv::Scalar m = cv::mean(dd, mask);
    s.mad_detail = (m[0] + m[1] + m[2]) / 3.0;
  }
  d.convertTo(d, CV_64F);
  d = d.mul(d);
  const cv::Scalar msum = cv::mean(d, mask);
  const double mse = (msum[0] + msum[1] + msum[2]) / 3.0;
  s.psnr = mse > 0 ? 10 * std::log10(255.0 * 255.0 / mse) : 99.0;
  cv::Mat ga, gb;
  cv::cvtColor(a, ga, cv::COLOR_RGB2GRAY);
  cv::cvtColor(b, gb, cv::COLOR_RGB2GRAY);
  ga.convertTo(ga, CV_64F);
  gb.convertTo(gb, CV_64F);
  const double C1 = 6.5025, C2 = 58.5225;
  cv::Mat mu1, mu2, s11, s22, s12;
  cv::GaussianBlur(ga, mu1, cv::Size(11, 11), 1.5);
  cv::GaussianBlur(gb, mu2, cv::Size(11, 11), 1.5);
  cv::GaussianBlur(ga.mul(ga), s11, cv::Size(11, 11), 1.5);
  cv::GaussianBlur(gb.mul(gb), s22, cv::Size(11, 11), 1.5);
  cv::GaussianBlur(ga.mul(gb), s12, cv::Size(11, 11), 1.5);
  cv::Mat mu11 = mu1.mul(mu1), mu22 = mu2.mul(mu2), mu12 = mu1.mul(mu2);
  s11 -= mu11;
  s22 -= mu22;
  s12 -= mu12;
  cv::Mat num = (2 * mu12 + C1).mul(2 * s12 + C2), den = (mu11 + mu22 + C1).mul(s11 + s22 + C2);
  cv::Mat ssim_map;
  cv::divide(num, den, ssim_map);
  cv::Mat inner;
  cv::erode(mask, inner, cv::Mat::ones(11, 11, CV_8U));
  s.ssim = cv::mean(ssim_map, cv::countNonZero(inner) == 0 ? mask : inner)[0];
  return s;
}

}  // namespace stitch_bench
