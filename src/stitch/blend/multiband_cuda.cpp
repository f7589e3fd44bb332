// The multiband blender on the device: the same pyramids as the CPU one (pyramid_math.hpp),
// float4 levels allocated once per geometry, every view processed on one stream.
#include <stdexcept>

#include "../../../cuda/blend/multiband_kernels.hpp"
#include "stitch/blend/multiband.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/cuda/stages_cuda.hpp"
#include "stitch/cuda/view_geometry.hpp"

namespace stitch {
namespace {

using stitch_cuda::FloatImage;

class MultibandBlenderCuda final : public MultibandBlender {
 public:
  explicit MultibandBlenderCuda(int bands) : bands_(bands) {}

  void prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height) override {
    if (views.size() >= kNoView) throw std::invalid_argument("too many views");
    views_ = views;
    layout_ = plan_multiband(views, out_width, out_height, bands_);
    nearest_mask_ = nearest_for_ = ~uint64_t(0);
    custom_.clear();
    device_labels_ = nullptr;
    const int L = layout_.bands;
    const int max_w = layout_.max_rect_width, max_h = layout_.max_rect_height;
    // One allocation each for the canvas pyramid, the view pyramid, the hole filling's levels
    // 1..L and the collapse's two scratch levels (level 1 at most: the finest level of the fill
    // and of the collapse is never stored, the kernels fuse it into their consumers).
    const int fill_w = layout_.fill_width, fill_h = layout_.fill_height;  // the hole filling's level 0
    acc_.assign(L + 1, {});
    gauss_.assign(L + 1, {});
    pull_.assign(L + 1, {});
    fill_.assign(L + 1, {});
    std::size_t acc_px = 0, view_px = 0, fill_px = 0;
    for (int k = 0; k <= L; ++k) {
      acc_[k] = {nullptr, layout_.padded_width >> k, layout_.padded_width >> k, layout_.padded_height >> k};
      acc_px += std::size_t(acc_[k].pitch) * acc_[k].height;
      gauss_[k] = {nullptr, max_w >> k, max_w >> k, max_h >> k};
      view_px += std::size_t(gauss_[k].pitch) * gauss_[k].height;
      pull_[k] = fill_[k] = {nullptr, fill_w >> k, fill_w >> k, fill_h >> k};
      if (k > 0) fill_px += std::size_t(pull_[k].pitch) * pull_[k].height;
    }
    const std::size_t scratch_px = L > 0 ? std::size_t(acc_[1].width) * acc_[1].height : 1;
    acc_mem_.resize(acc_px * sizeof(float4));
    gauss_mem_.resize(view_px * sizeof(float4));
    pull_mem_.resize(std::max<std::size_t>(fill_px, 1) * sizeof(float4));
    fill_mem_.resize(std::max<std::size_t>(fill_px, 1) * sizeof(float4));
    up_mem_.resize(scratch_px * sizeof(float4));
    img_mem_.resize(scratch_px * sizeof(float4));
    float4* a = reinterpret_cast<float4*>(acc_mem_.data());
    float4* g = reinterpret_cast<float4*>(gauss_mem_.data());
    float4* pl = reinterpret_cast<float4*>(pull_mem_.data());
    float4* fl = reinterpret_cast<float4*>(fill_mem_.data());
    for (int k = 0; k <= L; ++k) {
      acc_[k].data = a;
      a += std::size_t(acc_[k].pitch) * acc_[k].height;
      gauss_[k].data = g;
      g += std::size_t(gauss_[k].pitch) * gauss_[k].height;
      if (k == 0) continue;
      pull_[k].data = pl;
      fill_[k].data = fl;
      pl += std::size_t(pull_[k].pitch) * pull_[k].height;
      fl += std::size_t(fill_[k].pitch) * fill_[k].height;
    }
    labels_dev_.resize(std::size_t(out_width) * out_height);
  }

  void set_labels(const uint8_t* labels, bool on_device) override {
    device_labels_ = on_device ? labels : nullptr;
    if (labels && !on_device) custom_.assign(labels, labels + std::size_t(layout_.width) * layout_.height);
    else custom_.clear();
    nearest_mask_ = ~uint64_t(0);  // the device copy must be refreshed
  }
  const MultibandLayout& layout() const override { return layout_; }
  Backend backend() const override { return Backend::Cuda; }

  void fuse(const std::vector<ImageView>& warped, const ImageView& out) override {
    if (warped.size() != views_.size()) throw std::invalid_argument("view count differs from prepare()");
    if (out.width != layout_.width || out.height != layout_.height)
      throw std::invalid_argument("output size differs from prepare()");
    if (!out.on_device) throw std::invalid_argument("CUDA blender needs device memory");
    uint64_t mask = 0;
    for (std::size_t i = 0; i < warped.size(); ++i) {
      if (warped[i].empty() || views_[i].roi.empty()) continue;
      if (!warped[i].on_device) throw std::invalid_argument("CUDA blender needs device memory");
      mask |= uint64_t(1) << i;
    }
    const uint8_t* labels = device_labels_;
    if (!labels) {
      upload_labels(mask);
      labels = labels_dev_.data();
    }
    const cudaStream_t s = stream_.get();
    const int L = layout_.bands;
    STITCH_CUDA(cudaMemsetAsync(acc_mem_.data(), 0, acc_mem_.size(), s));
    for (const MultibandPiece& piece : layout_.pieces) {
      const int i = piece.view;
      if (!(mask >> i & 1)) continue;
      const Rect& pr = piece.rect;
      const Rect& roi = piece.part;
      std::vector<FloatImage> g(L + 1);
      for (int k = 0; k <= L; ++k) g[k] = sized(gauss_[k], pr.width >> k, pr.height >> k);
      // Holes filled from the view's own content (pull-push), as the CPU's fill_holes; level 0 of
      // the pull and of the fill exist only inside the kernels that read them.
      const int fw = padded_to_bands(roi.width, L), fh = padded_to_bands(roi.height, L);
      std::vector<FloatImage> pull(L + 1), fill(L + 1);
      for (int k = 1; k <= L; ++k) {
        pull[k] = sized(pull_[k], fw >> k, fh >> k);
        fill[k] = sized(fill_[k], fw >> k, fh >> k);
      }
      const stitch_cuda::DeviceImage view = to_device_image(piece_pixels(warped[i], views_[i].roi, piece));
      if (L > 0) {
        stitch_cuda::launch_mb_premultiply_down(view, fw, fh, pull[1], s);
        for (int k = 2; k <= L; ++k) stitch_cuda::launch_mb_down(pull[k - 1], pull[k], s);
        stitch_cuda::launch_mb_push(pull[L], FloatImage{}, fill[L], s);
        for (int k = L - 1; k >= 1; --k) stitch_cuda::launch_mb_push(pull[k], fill[k + 1], fill[k], s);
      }
      stitch_cuda::launch_mb_load_view(view, L > 0 ? fill[1] : FloatImage{}, fw, fh, roi.width, roi.height, roi.x - pr.x,
                                       roi.y - pr.y, pr.x, pr.y, labels, layout_.width, layout_.height, i, g[0], s);
      for (int k = 1; k <= L; ++k) stitch_cuda::launch_mb_down(g[k - 1], g[k], s);
      for (int k = 0; k <= L; ++k)
        stitch_cuda::launch_mb_accumulate(g[k], k < L ? g[k + 1] : FloatImage{}, acc_[k], pr.x >> k, pr.y >> k, s);
    }
    // Collapse: img_L = acc_L normalised; img_k = up(img_k+1) + acc_k normalised, the levels
    // alternating between two scratch images; level 0 goes straight to the output.
    FloatImage img{};
    for (int k = L; k >= 1; --k) {
      DeviceBuffer& target = (img.data == reinterpret_cast<float4*>(img_mem_.data())) ? up_mem_ : img_mem_;
      const FloatImage next = scratch(target, acc_[k].width, acc_[k].height);
      stitch_cuda::launch_mb_collapse(acc_[k], img, next, s);
      img = next;
    }
    stitch_cuda::launch_mb_store(acc_[0], img, labels, to_device_image(out), s);
    stream_.sync();
  }

 private:
  static FloatImage sized(FloatImage im, int w, int h) {
    im.width = w;
    im.height = h;
    im.pitch = w;
    return im;
  }
  static FloatImage scratch(const DeviceBuffer& mem, int w, int h) {
    return {reinterpret_cast<float4*>(mem.data()), w, w, h};
  }

  // Labels on the device for this set of present views: the nearest-view labels, or the
  // custom ones with missing views' pixels given to the nearest present view.
  void upload_labels(uint64_t mask) {
    if (mask == nearest_mask_) return;
    if (mask != nearest_for_) {
      nearest_ = nearest_view_labels(views_, layout_.width, layout_.height, mask);
      nearest_for_ = mask;
    }
    std::vector<uint8_t> labels = nearest_;
    if (!custom_.empty())
      for (std::size_t p = 0; p < labels.size(); ++p)
        if (custom_[p] != kNoView && (mask >> custom_[p] & 1)) labels[p] = custom_[p];
    STITCH_CUDA(cudaMemcpyAsync(labels_dev_.data(), labels.data(), labels.size(), cudaMemcpyHostToDevice, stream_.get()));
    stream_.sync();
    nearest_mask_ = mask;
  }

  int bands_;
  std::vector<ViewPlacement> views_;
  MultibandLayout layout_;
  std::vector<FloatImage> acc_, gauss_, pull_, fill_;  // pull_, fill_: the hole filling
  DeviceBuffer acc_mem_, gauss_mem_, pull_mem_, fill_mem_, up_mem_, img_mem_, labels_dev_;
  uint64_t nearest_mask_ = ~uint64_t(0);  // the present views the device labels are for
  uint64_t nearest_for_ = ~uint64_t(0);   // the present views nearest_ is for
  std::vector<uint8_t> custom_, nearest_;
  const uint8_t* device_labels_ = nullptr;  // given by set_labels(..., true)
  CudaStream stream_;
};

}  // namespace

std::unique_ptr<MultibandBlender> make_multiband_blender_cuda(int bands) {
  return std::make_unique<MultibandBlenderCuda>(bands);
}

}  // namespace stitch
