#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#include <stdexcept>
#include <vector>

#include "stitch/flow/flow.hpp"

#ifdef STITCH_HAVE_CUDA
#include "stitch/flow/flow_cuda.hpp"
#endif

namespace stitch {
namespace {

// Pixels of too little texture give no reliable flow: a flat input is zero flow, not noise.
bool is_flat(const cv::Mat& img) {
  cv::Scalar mean, stddev;
  cv::meanStdDev(img, mean, stddev);
  return stddev[0] < 1.0;
}

void sanitize(cv::Mat& flow, int width, int height) {
  // No NaN/Inf, and no displacement that lands outside the image.
  // By rows on OpenCV's threads (serially when the flow itself runs inside a parallel_for_).
  cv::parallel_for_(cv::Range(0, flow.rows), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) {
      cv::Vec2f* p = flow.ptr<cv::Vec2f>(y);
      for (int x = 0; x < flow.cols; ++x) {
        float& u = p[x][0];
        float& v = p[x][1];
        if (!std::isfinite(u) || !std::isfinite(v)) u = v = 0.f;
        u = std::clamp(u, float(-x), float(width - 1 - x));
        v = std::clamp(v, float(-y), float(height - 1 - y));
      }
    }
  });
}

class DisFlowCpu final : public DenseFlow {
 public:
  explicit DisFlowCpu(FlowQuality q) {
    const int preset = q == FlowQuality::Fast ? cv::DISOpticalFlow::PRESET_ULTRAFAST
                       : q == FlowQuality::Medium ? cv::DISOpticalFlow::PRESET_FAST
                                                  : cv::DISOpticalFlow::PRESET_MEDIUM;
    dis_ = cv::DISOpticalFlow::create(preset);
  }
  void compute(const cv::Mat& from, const cv::Mat& to, cv::Mat& flow, bool use_initial) override {
    check(from, to);
    if (is_flat(from) || is_flat(to)) {
      flow = cv::Mat::zeros(from.size(), CV_32FC2);
      return;
    }
    const bool init = use_initial && flow.size() == from.size() && flow.type() == CV_32FC2;
    dis_->setUseSpatialPropagation(true);
    if (!init) flow = cv::Mat::zeros(from.size(), CV_32FC2);
    // DIS refines the given field when it is passed in (its "initial flow").
    dis_->calc(from, to, flow);
    sanitize(flow, from.cols, from.rows);
  }
  Backend backend() const override { return Backend::Cpu; }

 private:
  static void check(const cv::Mat& a, const cv::Mat& b) {
    if (a.type() != CV_8UC1 || b.type() != CV_8UC1 || a.size() != b.size())
      throw std::invalid_argument("dense flow needs two 8-bit grayscale images of the same size");
  }
  cv::Ptr<cv::DISOpticalFlow> dis_;
};

class FarnebackFlowCpu final : public DenseFlow {
 public:
  explicit FarnebackFlowCpu(FlowQuality q) : quality_(q) {}
  void compute(const cv::Mat& from, const cv::Mat& to, cv::Mat& flow, bool use_initial) override {
    if (from.type() != CV_8UC1 || to.type() != CV_8UC1 || from.size() != to.size())
      throw std::invalid_argument("dense flow needs two 8-bit grayscale images of the same size");
    if (is_flat(from) || is_flat(to)) {
      flow = cv::Mat::zeros(from.size(), CV_32FC2);
      return;
    }
    const bool init = use_initial && flow.size() == from.size() && flow.type() == CV_32FC2;
    if (!init) flow = cv::Mat::zeros(from.size(), CV_32FC2);
    const int levels = quality_ == FlowQuality::Fast ? 3 : 5;
    const int iterations = quality_ == FlowQuality::Fine ? 5 : 3;
    const int win = quality_ == FlowQuality::Fast ? 13 : 15;
    cv::calcOpticalFlowFarneback(from, to, flow, 0.5, levels, win, iterations, 5, 1.1,
                                 init ? cv::OPTFLOW_USE_INITIAL_FLOW : 0);
    sanitize(flow, from.cols, from.rows);
  }
  Backend backend() const override { return Backend::Cpu; }

 private:
  FlowQuality quality_;
};

}  // namespace

std::unique_ptr<DenseFlow> DenseFlow::create(Backend backend, FlowAlgorithm algorithm, FlowQuality quality) {
#ifdef STITCH_HAVE_CUDA
  constexpr bool kHaveCudaFlow = true;
#else
  constexpr bool kHaveCudaFlow = false;
#endif
  switch (resolve_backend(backend, /*stage_has_cuda=*/kHaveCudaFlow)) {
#ifdef STITCH_HAVE_CUDA
    // The GPU has one flow, pyramidal dense Lucas-Kanade (flow_cuda.cpp), for both algorithm
    // names: `algorithm` picks between the CPU implementations only.
    case Backend::Cuda: return make_dense_flow_cuda(quality);
#endif
    case Backend::Cpu:
      if (algorithm == FlowAlgorithm::Dis) return std::make_unique<DisFlowCpu>(quality);
      return std::make_unique<FarnebackFlowCpu>(quality);
    default: break;
  }
  throw std::runtime_error("no dense flow for this backend");
}

double median_endpoint_error(const cv::Mat& a, const cv::Mat& b, const cv::Mat& mask) {
  std::vector<float> e;
  e.reserve(a.total());
  for (int y = 0; y < a.rows; ++y) {
    const cv::Vec2f* pa = a.ptr<cv::Vec2f>(y);
    const cv::Vec2f* pb = b.ptr<cv::Vec2f>(y);
    const uint8_t* pm = mask.empty() ? nullptr : mask.ptr<uint8_t>(y);
    for (int x = 0; x < a.cols; ++x)
      if (!pm || pm[x]) e.push_back(std::hypot(pa[x][0] - pb[x][0], pa[x][1] - pb[x][1]));
  }
  if (e.empty()) return 0;
  std::nth_element(e.begin(), e.begin() + e.size() / 2, e.end());
  return e[e.size() / 2];
}

}  // namespace stitch
