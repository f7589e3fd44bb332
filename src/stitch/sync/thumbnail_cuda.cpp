#include <cuda_runtime_api.h>

#include "../../../cuda/sync/thumbnail_kernels.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/sync/thumbnail.hpp"

namespace stitch::sync {

struct FrameThumbnailerCuda::Impl {
  CudaStream stream;
  DeviceBuffer cells{sizeof(float) * kThumbnailW * kThumbnailH};
};

FrameThumbnailerCuda::FrameThumbnailerCuda() : impl_(std::make_unique<Impl>()) {}
FrameThumbnailerCuda::~FrameThumbnailerCuda() = default;

void FrameThumbnailerCuda::thumbnail(const uint8_t* device_data, int width, int height, std::size_t pitch,
                                     int bytes_per_pixel, int channel, float* out) {
  impl_->stream.enter();  // after the frame's writers (stream-ordered hand-off)
  stitch_cuda::launch_thumbnail(device_data, width, height, pitch, bytes_per_pixel, channel,
                                reinterpret_cast<float*>(impl_->cells.data()), impl_->stream.get());
  STITCH_CUDA(cudaMemcpyAsync(out, impl_->cells.data(), sizeof(float) * kThumbnailW * kThumbnailH,
                              cudaMemcpyDeviceToHost, impl_->stream.get()));
  impl_->stream.sync();  // 9 KB the host reads now
}

}  // namespace stitch::sync
