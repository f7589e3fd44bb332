// stitchflowwarp on the GPU: the same method as flow_warper_cpu.cpp (read that first), with
// every overlapping pair handled in the same launches and the final pre-warp + flow
// displacement fused into one pass per view.
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "../../../cuda/warp/flow_warp_kernels.hpp"
#include "stitch/blend/blender_cpu.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/cuda/stages_cuda.hpp"
#include "stitch/cuda/view_geometry.hpp"
#include "stitch/flow/flow_cuda.hpp"
#include "stitch/warp/flow_gate_math.hpp"
#include "stitch/warp/flow_pairs.hpp"
#include "stitch/warp/flow_warper.hpp"

namespace stitch {
namespace {

using stitch_cuda::FlowPairDevice;
using stitch_cuda::FlowPairMask;

std::vector<float> gaussian_taps(double sigma) {
  // OpenCV's GaussianBlur(sigma) on float images: ksize = round(8 sigma + 1) | 1.
  const int ksize = int(std::lround(sigma * 8 + 1)) | 1;
  const cv::Mat k = cv::getGaussianKernel(ksize, sigma, CV_32F);
  return std::vector<float>(k.begin<float>(), k.end<float>());
}

class FlowWarperCuda final : public FlowWarper {
 public:
  // The canvas size is not needed: every view's rectangle and homography says where it lands.
  void prepare(const std::vector<ViewPlacement>& views, int, int) override {
    if (views.size() > std::size_t(stitch_cuda::kMaxViews)) throw std::invalid_argument("at most 16 views on the GPU");
    views_ = views;
    prefilter_sparse_views(views_);
    geometry_.clear();
    for (const auto& v : views_) geometry_.push_back(to_device_geometry(v));
    inputs_.resize(views_.size());
    outputs_.resize(views_.size());
    build();
  }

  void set_settings(const FlowWarpSettings& s) override {
    const bool rebuild = flow_layout_changed(settings_, s);
    settings_ = sanitized(s);
    if (rebuild && !views_.empty()) build();
  }

  void reset() override {
    std::fill(history_.begin(), history_.end(), false);
    std::fill(decisions_.begin(), decisions_.end(), flow_gate::Decision{});
  }

  void warp(const std::vector<ImageView>& frames, const std::vector<ImageView>& warped) override {
    if (frames.size() != views_.size() || warped.size() != views_.size())
      throw std::invalid_argument("flow warp: view count differs from prepare()");
    const std::size_t n = views_.size();
    std::vector<stitch_cuda::DeviceImage> src(n), dst(n);
    check_frame_sizes(views_, frames);
    stream_.enter();  // the frames and the pooled outputs may still be in use by other stages
    reduced_.resize(n);
    for (std::size_t i = 0; i < n; ++i) {
      if (frames[i].empty() || views_[i].roi.empty()) continue;
      if (warped[i].width != views_[i].roi.width || warped[i].height != views_[i].roi.height)
        throw std::invalid_argument("flow warp: destination " + std::to_string(i) + " is not roi-sized");
      src[i] = reduce_on_device(device_image_of(frames[i], inputs_[i], stream_.get()), views_[i].level, reduced_[i],
                                stream_.get());
      dst[i] = device_output(warped[i], i);
    }

    FlowPairMask active{}, history{};
    bool any_active = false, any_history = false;
    for (std::size_t p = 0; p < plans_.size(); ++p) {
      const bool present = src[std::size_t(plans_[p].a)].data && src[std::size_t(plans_[p].b)].data;
      if (!settings_.flow || !present) {
        history_[p] = false;
        continue;
      }
      active.bits[p >> 6] |= 1ull << (p & 63);
      any_active = true;
      if (history_[p]) {
        history.bits[p >> 6] |= 1ull << (p & 63);
        any_history = true;
      }
    }
    const cudaStream_t s = stream_.get();
    const int np = int(plans_.size());
    if (any_active) {
      stitch_cuda::launch_overlap_gray(pairs_dev_.get(), np, max_w_, max_h_, active, geometry_.data(), src.data(),
                                       int(n), s);
      std::vector<DeviceFlowTask>& tasks = tasks_;
      tasks.clear();
      for (int p = 0; p < np; ++p) {
        if (!active.test(p)) continue;
        const FlowPairDevice& d = pairs_[std::size_t(p)];
        const std::size_t field = std::size_t(d.work_w) * d.work_h * 2 * sizeof(float);
        for (int k = 0; k < 2; ++k) {
          // Last frame's refined flow both seeds this frame's estimate and is blended back in.
          if (history_[std::size_t(p)])
            STITCH_CUDA(cudaMemcpyAsync(d.prev_flow[k], d.flow[k], field, cudaMemcpyDeviceToDevice, s));
          DeviceFlowTask t;
          t.from = d.gray[k];
          t.to = d.gray[1 - k];
          t.gray_pitch = std::size_t(d.work_w);
          t.width = d.work_w;
          t.height = d.work_h;
          t.flow = d.flow[k];
          t.flow_pitch = std::size_t(d.work_w) * 2 * sizeof(float);
          t.use_initial = history_[std::size_t(p)];
          tasks.push_back(t);
        }
      }
      flow_->compute(tasks, s);
      const double scale = flow_scale(settings_.quality);
      const float tau = std::max(float(settings_.consistency_px * scale), 0.25f);
      stitch_cuda::launch_flow_confidence(pairs_dev_.get(), np, max_w_, max_h_, active, tau, s);
      stitch_cuda::launch_pair_blur(pairs_dev_.get(), np, max_w_, max_h_, active, 2, change_taps_.data(),
                                    int(change_taps_.size() / 2), s);
      stitch_cuda::launch_flow_gate(pairs_dev_.get(), np, max_w_, max_h_, active, settings_.fallback, s);
      stitch_cuda::launch_pair_blur(pairs_dev_.get(), np, max_w_, max_h_, active, 0, flow_taps_.data(),
                                    int(flow_taps_.size() / 2), s);
      if (any_history) {
        stitch_cuda::launch_gray_change(pairs_dev_.get(), np, max_w_, max_h_, history, s);
        stitch_cuda::launch_pair_blur(pairs_dev_.get(), np, max_w_, max_h_, history, 1, change_taps_.data(),
                                      int(change_taps_.size() / 2), s);
      }
      STITCH_CUDA(cudaMemsetAsync(stats_dev_.data(), 0, stats_dev_.size(), s));
      stitch_cuda::launch_flow_temporal(pairs_dev_.get(), np, max_w_, max_h_, active, history,
                                        float(settings_.temporal_smoothing),
                                        reinterpret_cast<float*>(stats_dev_.data()), s);
      for (int p = 0; p < np; ++p) {
        if (!active.test(p)) continue;
        const FlowPairDevice& d = pairs_[std::size_t(p)];
        for (int k = 0; k < 2; ++k)
          STITCH_CUDA(cudaMemcpyAsync(d.prev_gray[k], d.gray[k], std::size_t(d.work_w) * d.work_h,
                                      cudaMemcpyDeviceToDevice, s));
        history_[std::size_t(p)] = true;
      }
    }
    // The statistics come back before the final warp is queued (the D2H copy into pageable
    // memory returns when done), so the host waits for the flow only and the warp pass is
    // handed on to the next stage without a host synchronisation.
    std::vector<float>& sums = sums_;
    sums.assign(plans_.size() * stitch_cuda::kFlowStats, 0.f);
    if (any_active)
      STITCH_CUDA(cudaMemcpyAsync(sums.data(), stats_dev_.data(), sums.size() * sizeof(float), cudaMemcpyDeviceToHost, s));
    // This frame is warped with the gains decided last frame (flow_gate_math.hpp): no round trip.
    gains_.assign(plans_.size(), 1.f);
    if (settings_.fallback)
      for (std::size_t p = 0; p < plans_.size(); ++p) gains_[p] = float(decisions_[p].gain);
    stitch_cuda::launch_flow_warp_views(geometry_.data(), src.data(), dst.data(), int(n), pairs_dev_.get(), np, active,
                                        float(1.0 / flow_scale(settings_.quality)), gains_.data(), s);
    for (std::size_t i = 0; i < n; ++i)
      if (dst[i].data && !warped[i].on_device)
        STITCH_CUDA(cudaMemcpy2DAsync(warped[i].data, warped[i].pitch, dst[i].data, dst[i].pitch,
                                      std::size_t(warped[i].width) * 4, warped[i].height, cudaMemcpyDeviceToHost, s));
    bool host_out = false;
    for (std::size_t i = 0; i < n; ++i) host_out = host_out || (dst[i].data && !warped[i].on_device);
    if (host_out)
      stream_.sync();
    else
      stream_.leave();
    stats_.clear();
    const double scale = flow_scale(settings_.quality);
    for (int p = 0; p < np; ++p) {
      if (!active.test(p)) continue;
      FlowPairStats st;
      st.view_a = plans_[std::size_t(p)].a;
      st.view_b = plans_[std::size_t(p)].b;
      st.rect = plans_[std::size_t(p)].rect;
      const float* sum = sums.data() + stitch_cuda::kFlowStats * std::size_t(p);
      const float count = sum[1];
      st.mean_magnitude = count > 0 ? sum[0] / count / scale : 0.0;
      st.confident_fraction = count > 0 ? sum[2] / count : 0.0;
      st.error_homography = count > 0 ? sum[3] / count : 0.0;
      st.error_flow = count > 0 ? sum[4] / count : 0.0;
      flow_gate::Decision& d = decisions_[std::size_t(p)];
      d = flow_gate::update(d, st.error_homography, st.error_flow);
      st.flow_on = d.on;
      st.gain = d.gain;
      stats_.push_back(st);
    }
  }

  const std::vector<FlowPairStats>& stats() const override { return stats_; }
  Backend backend() const override { return Backend::Cuda; }

 private:
  // A device-pointer array uploaded once per geometry.
  struct DevicePairs {
    DeviceBuffer buffer;
    const FlowPairDevice* get() const { return reinterpret_cast<const FlowPairDevice*>(buffer.data()); }
  };

  stitch_cuda::DeviceImage device_output(const ImageView& v, std::size_t slot) {
    if (v.on_device) return to_device_image(v);
    const std::size_t pitch = std::size_t(v.width) * 4;
    outputs_[slot].resize(pitch * v.height);
    return {outputs_[slot].data(), pitch, v.width, v.height};
  }

  void build() {
    // The previous flow of a pair whose flow image keeps its size stays a good start after a
    // recalibration (as on the CPU): carried over below, device to device.
    const std::vector<FlowPairPlan> old_plans = plans_;
    const std::vector<FlowPairDevice> old_pairs = pairs_;
    const std::vector<bool> old_history = history_;
    const std::vector<flow_gate::Decision> old_decisions = decisions_;
    DeviceBuffer old_arena = std::move(arena_);

    std::vector<cv::Mat> weight(views_.size());
    for (std::size_t i = 0; i < views_.size(); ++i) weight[i] = position_weight_map(views_[i]);
    plans_ = plan_flow_pairs(views_, weight, settings_.margin, settings_.quality);
    if (plans_.size() > std::size_t(stitch_cuda::kMaxFlowPairs)) plans_.resize(stitch_cuda::kMaxFlowPairs);
    flow_ = CudaDenseFlow::create(settings_.quality);
    flow_taps_ = gaussian_taps(1.5);
    change_taps_ = gaussian_taps(2.0);

    // One arena for every pair's images; each image 256-byte aligned.
    auto aligned = [](std::size_t b) { return (b + 255) / 256 * 256; };
    std::size_t total = 0;
    for (const auto& p : plans_) {
      const std::size_t px = std::size_t(p.work_width) * p.work_height;
      total += 5 * aligned(px) + 8 * aligned(px * 8) + 10 * aligned(px * 4);
    }
    arena_ = DeviceBuffer();
    if (total) arena_.resize(total);
    pairs_.assign(plans_.size(), FlowPairDevice{});
    history_.assign(plans_.size(), false);
    decisions_.assign(plans_.size(), flow_gate::Decision{});
    max_w_ = max_h_ = 0;
    std::size_t offset = 0;
    auto take = [&](std::size_t bytes) {
      uint8_t* p = arena_.data() + offset;
      offset += aligned(bytes);
      return p;
    };
    for (std::size_t i = 0; i < plans_.size(); ++i) {
      const FlowPairPlan& p = plans_[i];
      FlowPairDevice& d = pairs_[i];
      d.a = p.a;
      d.b = p.b;
      d.rect_x = p.rect.x;
      d.rect_y = p.rect.y;
      d.rect_w = p.rect.width;
      d.rect_h = p.rect.height;
      d.work_w = p.work_width;
      d.work_h = p.work_height;
      max_w_ = std::max(max_w_, d.work_w);
      max_h_ = std::max(max_h_, d.work_h);
      const std::size_t px = std::size_t(d.work_w) * d.work_h;
      for (int k = 0; k < 2; ++k) {
        d.gray[k] = take(px);
        d.prev_gray[k] = take(px);
        d.flow[k] = reinterpret_cast<float*>(take(px * 8));
        d.prev_flow[k] = reinterpret_cast<float*>(take(px * 8));
        d.work[k] = reinterpret_cast<float*>(take(px * 8));
        d.work2[k] = reinterpret_cast<float*>(take(px * 8));
        d.confidence[k] = reinterpret_cast<float*>(take(px * 4));
        d.change[k] = reinterpret_cast<float*>(take(px * 4));
        d.change2[k] = reinterpret_cast<float*>(take(px * 4));
        d.gate[k] = reinterpret_cast<float*>(take(px * 4));
        d.gate2[k] = reinterpret_cast<float*>(take(px * 4));
      }
      d.valid = take(px);
      for (std::size_t o = 0; o < old_plans.size(); ++o) {
        const FlowPairDevice& od = old_pairs[o];
        if (od.a != d.a || od.b != d.b || !old_history[o] || od.work_w != d.work_w || od.work_h != d.work_h) continue;
        for (int k = 0; k < 2; ++k) {
          STITCH_CUDA(cudaMemcpyAsync(d.flow[k], od.flow[k], px * 8, cudaMemcpyDeviceToDevice, stream_.get()));
          STITCH_CUDA(cudaMemcpyAsync(d.prev_gray[k], od.prev_gray[k], px, cudaMemcpyDeviceToDevice, stream_.get()));
        }
        history_[i] = true;
        decisions_[i] = old_decisions[o];
      }
    }
    pairs_dev_.buffer.resize(std::max<std::size_t>(1, pairs_.size()) * sizeof(FlowPairDevice));
    if (!pairs_.empty())
      STITCH_CUDA(cudaMemcpyAsync(pairs_dev_.buffer.data(), pairs_.data(), pairs_.size() * sizeof(FlowPairDevice),
                                  cudaMemcpyHostToDevice, stream_.get()));
    stats_dev_.resize(std::max<std::size_t>(1, plans_.size()) * stitch_cuda::kFlowStats * sizeof(float));
    stream_.sync();  // the old arena is freed after the carry-over copies
  }

  CudaStream stream_;
  std::unique_ptr<CudaDenseFlow> flow_;
  FlowWarpSettings settings_;
  std::vector<ViewPlacement> views_;
  std::vector<std::vector<DeviceBuffer>> reduced_;  // per view, its frame halved per level
  std::vector<stitch_cuda::ViewGeometry> geometry_;
  std::vector<FlowPairPlan> plans_;
  std::vector<FlowPairDevice> pairs_;  // host copy of the descriptors
  std::vector<bool> history_;
  std::vector<flow_gate::Decision> decisions_;  // per pair: whether its flow helps, and its gain
  std::vector<float> gains_;                    // this frame's, from decisions_
  DevicePairs pairs_dev_;
  DeviceBuffer arena_, stats_dev_;
  int max_w_ = 0, max_h_ = 0;
  std::vector<float> flow_taps_, change_taps_;
  std::vector<DeviceBuffer> inputs_, outputs_;  // staging for views in system memory
  std::vector<FlowPairStats> stats_;
  std::vector<DeviceFlowTask> tasks_;  // reused every frame
  std::vector<float> sums_;            // per pair: kFlowStats sums (flow_warp_kernels.hpp)
};

}  // namespace

std::unique_ptr<FlowWarper> make_flow_warper_cuda() { return std::make_unique<FlowWarperCuda>(); }

}  // namespace stitch
