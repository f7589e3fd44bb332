#include <stdexcept>

#include "stitch/cuda/cuda_util.hpp"
#include "stitch/cuda/stages_cuda.hpp"
#include "stitch/cuda/view_geometry.hpp"

namespace stitch {
namespace {

// The weights are evaluated per pixel from the homography (a few flops) rather than read
// from precomputed maps (bytes): the kernel stays memory-bound on the images alone.
class BlenderCuda final : public Blender {
 public:
  void prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height) override {
    if (views.size() > std::size_t(stitch_cuda::kMaxViews)) throw std::invalid_argument("at most 16 views on the GPU");
    views_.clear();
    for (const auto& v : views) views_.push_back(to_device_geometry(v));
    out_w_ = out_width;
    out_h_ = out_height;
  }
  void fuse(const std::vector<ImageView>& warped, const ImageView& out) override {
    if (warped.size() != views_.size()) throw std::invalid_argument("view count differs from prepare()");
    if (out.width != out_w_ || out.height != out_h_) throw std::invalid_argument("output size differs from prepare()");
    if (!out.on_device) throw std::invalid_argument("CUDA blender needs device memory");
    std::vector<stitch_cuda::DeviceImage> images(warped.size());
    for (std::size_t i = 0; i < warped.size(); ++i) {
      if (warped[i].empty()) continue;
      if (!warped[i].on_device) throw std::invalid_argument("CUDA blender needs device memory");
      images[i] = to_device_image(warped[i]);
    }
    stitch_cuda::launch_fuse(int(views_.size()), views_.data(), images.data(), to_device_image(out), stream_.get());
    stream_.sync();
  }
  Backend backend() const override { return Backend::Cuda; }

 private:
  std::vector<stitch_cuda::ViewGeometry> views_;
  int out_w_ = 0, out_h_ = 0;
  CudaStream stream_;
};

}  // namespace

std::unique_ptr<Blender> make_blender_cuda() { return std::make_unique<BlenderCuda>(); }

}  // namespace stitch
