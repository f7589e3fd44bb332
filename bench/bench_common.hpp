// Helpers the benchmarks share: reading clip sets, photometric comparison, running statistics.
#pragma once

#include <cmath>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace stitch_bench {

// seq[t][camera] (RGBA): `frames` instants every `step` frames of synchronised clips, or one
// instant from still images (any path ending in .jpg/.jpeg/.png). Empty with a message on error.
std::vector<std::vector<cv::Mat>> read_sets(const std::vector<std::string>& paths, int frames, int step);

struct Comparison {
  double psnr = 0, ssim = 0, mad = 0;  // mad: mean absolute difference, levels, RGB mean
  // MAD of the detail (each image minus its Gaussian local mean, sigma 8 px): what ghosting
  // and misalignment change, without the smooth exposure and vignetting differences between
  // two cameras that no warp can remove.
  double mad_detail = 0;
  int pixels = 0;
};

// a, b: RGB images of the same size; mask: CV_8U. SSIM (Wang et al.) on luma, Gaussian 11x11.
Comparison compare(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask);

struct Series {
  std::vector<double> v;
  double mean() const {
    double s = 0;
    for (double x : v) s += x;
    return v.empty() ? 0 : s / v.size();
  }
  double sigma() const {
    const double m = mean();
    double s = 0;
    for (double x : v) s += (x - m) * (x - m);
    return v.size() > 1 ? std::sqrt(s / (v.size() - 1)) : 0;
  }
};

struct Case {
  int cameras, width, height;
};
// "NxWxH" (e.g. 3x1920x1080) into c; false (with a message on stderr) when it is not one.
bool parse_case(const char* text, Case& c);

// A rotating rig of c.cameras cameras spanning at most 100 degrees (planar canvas), adjacent
// views overlapping ~30%, rough homographies computed.
stitch::Rig ring(const Case& c);

// Views of a real photo for the ring: camera i sees a shifted part of it, resized to W x H (RGBA).
std::vector<cv::Mat> ring_views(const cv::Mat& photo_rgba, const Case& c);

}  // namespace stitch_bench
