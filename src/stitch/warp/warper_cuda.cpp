#include <stdexcept>

#include "stitch/cuda/cuda_util.hpp"
#include "stitch/cuda/stages_cuda.hpp"
#include "stitch/cuda/view_geometry.hpp"

namespace stitch {
namespace {

// Samples the homography per pixel instead of reading precomputed maps: on the GPU the
// projective divide is cheaper than the 8 bytes per pixel a map would cost.
class WarperCuda final : public Warper {
 public:
  void prepare(const std::vector<ViewPlacement>& views) override {
    views_.clear();
    for (const auto& v : views) views_.push_back(to_device_geometry(v));
  }
  void warp(int index, const ImageView& src, const ImageView& dst) override {
    if (!src.on_device || !dst.on_device) throw std::invalid_argument("CUDA warper needs device memory");
    const stitch_cuda::ViewGeometry& g = views_.at(std::size_t(index));
    if (g.roi_w == 0) return;
    if (dst.width != g.roi_w || dst.height != g.roi_h)
      throw std::invalid_argument("warp destination does not match the view's rectangle");
    stitch_cuda::launch_warp(to_device_image(src), g, to_device_image(dst), stream_.get());
    stream_.sync();
  }
  Backend backend() const override { return Backend::Cuda; }

 private:
  std::vector<stitch_cuda::ViewGeometry> views_;
  CudaStream stream_;
};

}  // namespace

std::unique_ptr<Warper> make_warper_cuda() { return std::make_unique<WarperCuda>(); }

}  // namespace stitch
