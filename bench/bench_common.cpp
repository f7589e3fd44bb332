#include "bench_common.hpp"

#include <cstdio>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

namespace stitch_bench {

stitch::Rig ring(const Case& c) {
  stitch::Rig rig;
  rig.reference = c.cameras / 2;
  const double spacing = std::min(35.0, 100.0 / std::max(1, c.cameras - 1));
  const double hfov = spacing * 1.4;
  const double f = c.width / (2 * std::tan(hfov / 2 * 3.14159265358979 / 180));
  for (int i = 0; i < c.cameras; ++i) {
    stitch::Camera cam;
    cam.width = c.width;
    cam.height = c.height;
    cam.fx = cam.fy = f;
    cam.cx = (c.width - 1) * 0.5;
    cam.cy = (c.height - 1) * 0.5;
    cam.yaw_deg = (i - (c.cameras - 1) * 0.5) * spacing;
    rig.cameras.push_back(cam);
  }
  stitch::rig_compute_rough_homographies(rig);
  return rig;
}

std::vector<cv::Mat> ring_views(const cv::Mat& photo, const Case& c) {
  std::vector<cv::Mat> views;
  for (int i = 0; i < c.cameras; ++i) {
    cv::Mat v;
    cv::resize(photo(cv::Rect(i * (photo.cols - photo.cols / 2) / std::max(1, c.cameras - 1), 0, photo.cols / 2, photo.rows)),
               v, cv::Size(c.width, c.height));
    views.push_back(v);
  }
  return views;
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

bool parse_case(const char* text, Case& c) {
  if (std::sscanf(text, "%dx%dx%d", &c.cameras, &c.width, &c.height) != 3 || c.cameras < 2 || c.width < 64 ||
      c.height < 64) {
    std::fprintf(stderr, "--case: cameras x width x height, e.g. 3x1920x1080\n");
    return false;
  }
  return true;
}

}  // namespace stitch_bench
