#include <algorithm>
#include <cstring>
#include <stdexcept>
#include <vector>

#include "../../../cuda/color/color_kernels.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/cuda/stages_cuda.hpp"

namespace stitch {
namespace {

// Page-locked host memory that only grows: the per-frame uploads and the download of the
// results are then true asynchronous copies. Rewritten only after the stream synchronised.
class PinnedBuffer {
 public:
  PinnedBuffer() = default;
  PinnedBuffer(const PinnedBuffer&) = delete;
  PinnedBuffer& operator=(const PinnedBuffer&) = delete;
  ~PinnedBuffer() {
    if (ptr_) cudaFreeHost(ptr_);
  }
  void resize(std::size_t bytes) {
    if (bytes <= bytes_) return;
    if (ptr_) cudaFreeHost(ptr_);
    ptr_ = nullptr;
    bytes_ = 0;
    STITCH_CUDA(cudaMallocHost(&ptr_, bytes));
    bytes_ = bytes;
  }
  uint8_t* data() const { return static_cast<uint8_t*>(ptr_); }

 private:
  void* ptr_ = nullptr;
  std::size_t bytes_ = 0;
};

template <typename T>
void upload(DeviceBuffer& dst, const std::vector<T>& src, cudaStream_t stream) {
  dst.resize(src.size() * sizeof(T));
  if (!src.empty())
    STITCH_CUDA(cudaMemcpyAsync(dst.data(), src.data(), src.size() * sizeof(T), cudaMemcpyHostToDevice, stream));
}

bool is_identity(const std::array<std::array<uint8_t, 256>, 3>& lut) {
  for (int c = 0; c < 3; ++c)
    for (int v = 0; v < 256; ++v)
      if (lut[c][v] != v) return false;
  return true;
}

// The color stage's per-frame work on views in device memory: the sample positions stay on
// the device (uploaded per geometry), the reductions run as a few small kernels whose
// results (a few KB) come back with one stream synchronisation, and every view is corrected
// by one launch. Views still in system memory (a chain that negotiated no CUDA memory) go to
// the CPU implementation: a round trip to the GPU for a 3x3 per pixel would cost more than
// it saves.
class ColorOpsCuda final : public ColorOps {
 public:
  ColorOpsCuda() : cpu_(ColorOps::create(Backend::Cpu)) {}

  void set_sampling(const ColorSampling& sampling) override {
    cpu_->set_sampling(sampling);
    std::vector<stitch_cuda::ColorSamplePair> pairs;
    std::vector<int4> pair_samples;
    max_pair_samples_ = 0;
    for (const ColorSampling::Pair& g : sampling.pairs) {
      pairs.push_back({g.a, g.b, int32_t(pair_samples.size()), g.count()});
      for (int k = 0; k < g.count(); ++k)
        pair_samples.push_back(int4{g.xy_a[2 * k], g.xy_a[2 * k + 1], g.xy_b[2 * k], g.xy_b[2 * k + 1]});
      max_pair_samples_ = std::max(max_pair_samples_, g.count());
    }
    std::vector<stitch_cuda::ColorSampleGrid> grids;
    std::vector<int2> grid_samples;
    max_grid_samples_ = 0;
    for (const std::vector<int32_t>& xy : sampling.balance_xy) {
      const int count = int(xy.size() / 2);
      grids.push_back({int32_t(grid_samples.size()), count});
      for (int k = 0; k < count; ++k) grid_samples.push_back(int2{xy[2 * k], xy[2 * k + 1]});
      max_grid_samples_ = std::max(max_grid_samples_, count);
    }
    // Pageable sources: each copy returns once the data is staged, so the vectors may go.
    upload(pairs_, pairs, stream_.get());
    upload(pair_samples_, pair_samples, stream_.get());
    upload(grids_, grids, stream_.get());
    upload(grid_samples_, grid_samples, stream_.get());
    pair_count_ = int(pairs.size());
    view_count_ = int(grids.size());
    // The mask's per-sample state, zeroed; the next frame starts it.
    const std::size_t samples = pair_samples.size();
    prev_a_.resize(std::max<std::size_t>(1, samples) * 4);
    prev_b_.resize(std::max<std::size_t>(1, samples) * 4);
    age_.resize(std::max<std::size_t>(1, samples));
    moved_.resize(std::max<std::size_t>(1, samples));
    use_.resize(std::max<std::size_t>(1, samples));
    if (samples) {
      STITCH_CUDA(cudaMemsetAsync(prev_a_.data(), 0, samples * 4, stream_.get()));
      STITCH_CUDA(cudaMemsetAsync(prev_b_.data(), 0, samples * 4, stream_.get()));
      STITCH_CUDA(cudaMemsetAsync(age_.data(), 0, samples, stream_.get()));
    }
    fresh_ = true;
  }

  void reset_motion() override {
    cpu_->reset_motion();
    fresh_ = true;
  }

  void reduce(const std::vector<ImageView>& views, const ColorReductionRequest& request,
              ColorStats& out) override {
    if (int(views.size()) != view_count_) throw std::invalid_argument("color: views do not match the sampling");
    bool any_device = false, any_host = false;
    for (const ImageView& v : views)
      if (!v.empty()) (v.on_device ? any_device : any_host) = true;
    if (!any_device) return cpu_->reduce(views, request, out);
    if (any_host) throw std::runtime_error("color: views in both system and device memory");
    if (request.balance && request.balance_matrices.size() < views.size())
      throw std::invalid_argument("color: a balance matrix per view is needed");

    // This frame's inputs (where the views are, the balance matrices, which pairs are
    // matched): one upload.
    const std::size_t views_bytes = std::size_t(view_count_) * sizeof(stitch_cuda::ColorFrameView);
    const std::size_t input_bytes = views_bytes + std::size_t(pair_count_) * sizeof(int32_t);
    inputs_host_.resize(input_bytes);
    inputs_.resize(input_bytes);
    auto* frame_views = reinterpret_cast<stitch_cuda::ColorFrameView*>(inputs_host_.data());
    auto* match = reinterpret_cast<int32_t*>(inputs_host_.data() + views_bytes);
    for (int i = 0; i < view_count_; ++i) {
      const ImageView& v = views[std::size_t(i)];
      stitch_cuda::ColorFrameView& f = frame_views[i];
      f.data = v.empty() ? nullptr : v.data;
      f.pitch = v.pitch;
      f.width = v.width;
      f.height = v.height;
      const Eigen::Matrix3d M = request.balance ? request.balance_matrices[std::size_t(i)] : Eigen::Matrix3d::Identity();
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) f.balance_matrix[3 * r + c] = M(r, c);
    }
    bool any_match = false;
    for (int k = 0; k < pair_count_; ++k) {
      const HistogramMatch m = std::size_t(k) < request.match.size() ? request.match[std::size_t(k)] : HistogramMatch::None;
      match[k] = m == HistogramMatch::AOntoB   ? stitch_cuda::kColorMatchAOntoB
                 : m == HistogramMatch::BOntoA ? stitch_cuda::kColorMatchBOntoA
                                               : stitch_cuda::kColorMatchNone;
      any_match = any_match || m != HistogramMatch::None;
    }
    stream_.enter();  // the views may still be written by the previous stage
    if (input_bytes)
      STITCH_CUDA(cudaMemcpyAsync(inputs_.data(), inputs_host_.data(), input_bytes, cudaMemcpyHostToDevice, stream_.get()));

    const std::size_t pair_bytes = std::size_t(pair_count_) * sizeof(stitch_cuda::ColorPairResult);
    const std::size_t result_bytes = pair_bytes + std::size_t(view_count_) * 3 * 256 * sizeof(unsigned int);
    results_.resize(result_bytes);
    results_host_.resize(result_bytes);
    match_luts_.resize(std::size_t(pair_count_) * 3 * 256);
    if (result_bytes) STITCH_CUDA(cudaMemsetAsync(results_.data(), 0, result_bytes, stream_.get()));

    stitch_cuda::ColorReduceArgs args{};
    args.views = reinterpret_cast<const stitch_cuda::ColorFrameView*>(inputs_.data());
    args.view_count = view_count_;
    args.pairs = reinterpret_cast<const stitch_cuda::ColorSamplePair*>(pairs_.data());
    args.pair_samples = reinterpret_cast<const int4*>(pair_samples_.data());
    args.pair_count = pair_count_;
    args.max_pair_samples = max_pair_samples_;
    args.pair_match = reinterpret_cast<const int32_t*>(inputs_.data() + views_bytes);
    args.grids = reinterpret_cast<const stitch_cuda::ColorSampleGrid*>(grids_.data());
    args.grid_samples = reinterpret_cast<const int2*>(grid_samples_.data());
    args.max_grid_samples = max_grid_samples_;
    args.dark_level = request.dark_level;
    args.bright_level = request.bright_level;
    args.want_pairs = request.pairs;
    args.want_match = request.pairs && any_match;
    args.want_balance = request.balance;
    args.prev_a = reinterpret_cast<uchar4*>(prev_a_.data());
    args.prev_b = reinterpret_cast<uchar4*>(prev_b_.data());
    args.age = age_.data();
    args.moved = moved_.data();
    args.use = use_.data();
    args.fresh = fresh_ ? 1 : 0;
    args.static_mask = request.static_mask ? 1 : 0;
    args.motion_threshold = request.motion_threshold;
    args.static_frames = request.static_frames;
    args.align_tolerance = request.align_tolerance;
    if (request.pairs) fresh_ = false;
    args.pair_results = reinterpret_cast<stitch_cuda::ColorPairResult*>(results_.data());
    args.balance_results = reinterpret_cast<unsigned int*>(results_.data() + pair_bytes);
    args.match_luts = match_luts_.data();
    stitch_cuda::launch_color_reduce(args, stream_.get());
    if (result_bytes)
      STITCH_CUDA(cudaMemcpyAsync(results_host_.data(), results_.data(), result_bytes, cudaMemcpyDeviceToHost, stream_.get()));
    stream_.sync();  // the frame's one synchronisation of the reductions

    const auto* pair_results = reinterpret_cast<const stitch_cuda::ColorPairResult*>(results_host_.data());
    out.pairs.resize(std::size_t(pair_count_));
    for (int k = 0; k < pair_count_; ++k) {
      const stitch_cuda::ColorPairResult& r = pair_results[k];
      PairStats& s = out.pairs[std::size_t(k)];
      s.count = r.count;
      std::copy(r.aa, r.aa + 9, s.aa.begin());
      std::copy(r.bb, r.bb + 9, s.bb.begin());
      std::copy(r.ab, r.ab + 9, s.ab.begin());
      std::copy(r.matched, r.matched + 9, s.matched.begin());
      s.inview = r.inview;
      s.moving = r.moving;
      s.misaligned = r.misaligned;
      s.global_change = r.global_change;
      std::copy(r.sum_a, r.sum_a + 3, s.sum_a.begin());
      std::copy(r.sum_b, r.sum_b + 3, s.sum_b.begin());
      for (int ch = 0; ch < 3; ++ch) {
        std::copy(r.hist_a + 256 * ch, r.hist_a + 256 * (ch + 1), s.hist_a[ch].begin());
        std::copy(r.hist_b + 256 * ch, r.hist_b + 256 * (ch + 1), s.hist_b[ch].begin());
      }
    }
    const auto* balance = reinterpret_cast<const unsigned int*>(results_host_.data() + pair_bytes);
    out.balance.resize(std::size_t(view_count_));
    for (int i = 0; i < view_count_; ++i)
      for (int ch = 0; ch < 3; ++ch)
        std::copy(balance + 256 * (3 * i + ch), balance + 256 * (3 * i + ch + 1), out.balance[std::size_t(i)][ch].begin());
  }

  void apply_all(const std::vector<ImageView>& views, const std::vector<Eigen::Matrix3d>& matrices,
                 const std::array<std::array<uint8_t, 256>, 3>& lut, int highlight_knee) override {
    if (matrices.size() < views.size()) throw std::invalid_argument("color: a matrix per view is needed");
    bool any_device = false, any_host = false;
    for (const ImageView& v : views)
      if (!v.empty()) (v.on_device ? any_device : any_host) = true;
    if (any_host) {
      std::vector<ImageView> host_views(views.size());
      for (std::size_t i = 0; i < views.size(); ++i)
        if (!views[i].on_device) host_views[i] = views[i];
      cpu_->apply_all(host_views, matrices, lut, highlight_knee);
    }
    if (!any_device) return;
    stream_.enter();
    const uint8_t* device_lut = nullptr;
    if (!is_identity(lut)) {
      if (!lut_uploaded_ || lut != uploaded_lut_) {
        stream_.sync();  // the last upload from lut_host_ may still be queued (no per-frame sync now)
        lut_host_.resize(768);
        lut_.resize(768);
        for (int c = 0; c < 3; ++c) std::memcpy(lut_host_.data() + 256 * c, lut[c].data(), 256);
        STITCH_CUDA(cudaMemcpyAsync(lut_.data(), lut_host_.data(), 768, cudaMemcpyHostToDevice, stream_.get()));
        uploaded_lut_ = lut;
        lut_uploaded_ = true;
      }
      device_lut = lut_.data();
    }
    stitch_cuda::ColorApplyBatch batch{};
    batch.highlight_knee = std::clamp(highlight_knee, 0, 255);
    bool launched = false;
    auto flush = [&] {
      if (batch.count == 0) return;
      stitch_cuda::launch_color_apply_batch(batch, device_lut, stream_.get());
      launched = true;
      batch.count = 0;
    };
    for (std::size_t i = 0; i < views.size(); ++i) {
      const ImageView& v = views[i];
      const bool has_matrix = !matrices[i].isIdentity(1e-9);
      if (v.empty() || !v.on_device || (!has_matrix && !device_lut)) continue;
      stitch_cuda::ColorApplyView& a = batch.views[batch.count++];
      a.data = v.data;
      a.pitch = v.pitch;
      a.width = v.width;
      a.height = v.height;
      a.has_matrix = has_matrix;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) a.M[3 * r + c] = float(matrices[i](r, c));
      if (batch.count == stitch_cuda::kColorApplyMaxViews) flush();  // more views than a chain carries
    }
    flush();
    if (launched) stream_.leave();  // the next stage reads finished pixels (after the hand-off's event)
  }

  void gather(const ImageView& view, const std::vector<int32_t>& xy,
              std::vector<std::array<uint8_t, 3>>& out) override {
    if (!view.on_device) return cpu_->gather(view, xy, out);
    const int count = int(xy.size() / 2);
    out.resize(std::size_t(count));
    if (count == 0) return;
    stream_.enter();
    gather_xy_.resize(xy.size() * sizeof(int32_t));
    gather_out_.resize(std::size_t(count) * 3);
    STITCH_CUDA(cudaMemcpyAsync(gather_xy_.data(), xy.data(), xy.size() * sizeof(int32_t), cudaMemcpyHostToDevice,
                                stream_.get()));
    stitch_cuda::launch_gather(view.data, view.pitch, reinterpret_cast<const int32_t*>(gather_xy_.data()), count,
                               gather_out_.data(), stream_.get());
    STITCH_CUDA(cudaMemcpyAsync(out.data(), gather_out_.data(), std::size_t(count) * 3, cudaMemcpyDeviceToHost,
                                stream_.get()));
    stream_.sync();
  }

  Backend backend() const override { return Backend::Cuda; }

 private:
  std::unique_ptr<ColorOps> cpu_;
  CudaStream stream_;
  // Per geometry.
  DeviceBuffer pairs_, pair_samples_, grids_, grid_samples_;
  int pair_count_ = 0, view_count_ = 0, max_pair_samples_ = 0, max_grid_samples_ = 0;
  // The mask's state, per pair sample.
  DeviceBuffer prev_a_, prev_b_, age_, moved_, use_;
  bool fresh_ = true;
  // Per frame, reused.
  PinnedBuffer inputs_host_, results_host_, lut_host_;
  DeviceBuffer inputs_, results_, match_luts_, lut_;
  std::array<std::array<uint8_t, 256>, 3> uploaded_lut_{};
  bool lut_uploaded_ = false;
  DeviceBuffer gather_xy_, gather_out_;
};

}  // namespace

std::unique_ptr<ColorOps> make_color_ops_cuda() { return std::make_unique<ColorOpsCuda>(); }

}  // namespace stitch
