#include "../launch_check.hpp"
#include "stitch/sync/thumbnail_math.hpp"
#include "thumbnail_kernels.hpp"

namespace stitch_cuda {

namespace {

__global__ void thumbnail_kernel(const uint8_t* data, int width, int height, size_t pitch, int bpp, int channel,
                                 float* out) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= stitch::sync::kThumbnailW * stitch::sync::kThumbnailH) return;
  const int tx = i % stitch::sync::kThumbnailW, ty = i / stitch::sync::kThumbnailW;
  out[i] = stitch::sync::thumbnail_cell(data, width, height, pitch, bpp, channel, tx, ty);
}

}  // namespace

void launch_thumbnail(const uint8_t* data, int width, int height, size_t pitch, int bytes_per_pixel, int channel,
                      float* out, cudaStream_t stream) {
  const int cells = stitch::sync::kThumbnailW * stitch::sync::kThumbnailH;
  thumbnail_kernel<<<(cells + 127) / 128, 128, 0, stream>>>(data, width, height, pitch, bytes_per_pixel, channel, out);
  check_launch("thumbnail kernel");
}

}  // namespace stitch_cuda
