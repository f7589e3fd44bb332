// Dense optical flow between two grayscale images (the overlap of two pre-warped views),
// the building block of stitchflowwarp's local warping (paper §3.2, eq. 17).
#pragma once

#include <memory>
#include <opencv2/core.hpp>

#include "stitch/backend.hpp"

namespace stitch {

enum class FlowAlgorithm { Dis, Farneback };
enum class FlowQuality { Fast, Medium, Fine };

class DenseFlow {
 public:
  virtual ~DenseFlow() = default;
  // flow(y, x) = displacement that takes pixel (x, y) of `from` to its match in `to`
  // (CV_32FC2). When `flow` holds a previous estimate of the right size and `use_initial` is
  // set, it is the starting point (temporal coherence). Uniform or black inputs give zero flow.
  virtual void compute(const cv::Mat& from, const cv::Mat& to, cv::Mat& flow, bool use_initial) = 0;
  virtual Backend backend() const = 0;

  static std::unique_ptr<DenseFlow> create(Backend backend, FlowAlgorithm algorithm, FlowQuality quality);
};

// Median endpoint error between two flow fields over the pixels where `mask` is set (or all).
double median_endpoint_error(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask = cv::Mat());

}  // namespace stitch
