#include <stdexcept>

#include "../../../cuda/color/color_kernels.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/cuda/stages_cuda.hpp"

namespace stitch {
namespace {

// Per-pixel color work on views in device memory. Views still in system memory (a chain that
// negotiated no CUDA memory) go to the CPU implementation: a round trip to the GPU for a
// 3x3 per pixel would cost more than it saves.
class ColorOpsCuda final : public ColorOps {
 public:
  ColorOpsCuda() : cpu_(ColorOps::create(Backend::Cpu)) {}

  void gather(const ImageView& view, const std::vector<int32_t>& xy,
              std::vector<std::array<uint8_t, 3>>& out) override {
    if (!view.on_device) return cpu_->gather(view, xy, out);
    const int count = int(xy.size() / 2);
    out.resize(std::size_t(count));
    if (count == 0) return;
    xy_.resize(xy.size() * sizeof(int32_t));
    samples_.resize(std::size_t(count) * 3);
    STITCH_CUDA(cudaMemcpyAsync(xy_.data(), xy.data(), xy.size() * sizeof(int32_t), cudaMemcpyHostToDevice, stream_.get()));
    stitch_cuda::launch_gather(view.data, view.pitch, reinterpret_cast<const int32_t*>(xy_.data()), count,
                               samples_.data(), stream_.get());
    STITCH_CUDA(cudaMemcpyAsync(out.data(), samples_.data(), std::size_t(count) * 3, cudaMemcpyDeviceToHost, stream_.get()));
    stream_.sync();
  }

  void apply(const ImageView& view, const Eigen::Matrix3d& M,
             const std::array<std::array<uint8_t, 256>, 3>& lut) override {
    if (!view.on_device) return cpu_->apply(view, M, lut);
    float m[9];
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) m[3 * r + c] = float(M(r, c));
    bool identity_lut = true;
    for (int c = 0; c < 3 && identity_lut; ++c)
      for (int v = 0; v < 256 && identity_lut; ++v) identity_lut = lut[c][v] == v;
    const uint8_t* dlut = nullptr;
    if (!identity_lut) {
      lut_.resize(768);
      STITCH_CUDA(cudaMemcpyAsync(lut_.data(), lut.data(), 768, cudaMemcpyHostToDevice, stream_.get()));
      dlut = lut_.data();
    }
    stitch_cuda::launch_color_apply(view.data, view.pitch, view.width, view.height,
                                    M.isIdentity(1e-9) ? nullptr : m, dlut, stream_.get());
    stream_.sync();
  }

  Backend backend() const override { return Backend::Cuda; }

 private:
  std::unique_ptr<ColorOps> cpu_;
  CudaStream stream_;
  DeviceBuffer xy_, samples_, lut_;
};

}  // namespace

std::unique_ptr<ColorOps> make_color_ops_cuda() { return std::make_unique<ColorOpsCuda>(); }

}  // namespace stitch
