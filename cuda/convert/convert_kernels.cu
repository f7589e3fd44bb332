#include <stdexcept>
#include <string>

#include "../launch_check.hpp"
#include "convert_kernels.hpp"

namespace stitch_cuda {

namespace {

// Two horizontally adjacent output pixels per thread (they share their chroma samples; one
// 8-byte store where aligned); the chroma taps are shared with the CPU (yuv_math.hpp).
__global__ void yuv420_kernel(stitch::Yuv420Planes in, stitch::YuvToRgbQ16 k, uint8_t* out, size_t out_pitch) {
  const int x = 2 * (blockIdx.x * blockDim.x + threadIdx.x), y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= in.width || y >= in.height) return;
  uint8_t a[4], b[4];
  stitch::yuv420_pixel(in, k, x, y, a);
  uint8_t* o = out + size_t(y) * out_pitch + size_t(x) * 4;
  if (x + 1 >= in.width) {
    *reinterpret_cast<uchar4*>(o) = make_uchar4(a[0], a[1], a[2], a[3]);
    return;
  }
  stitch::yuv420_pixel(in, k, x + 1, y, b);
  const uint32_t pa = a[0] | a[1] << 8 | a[2] << 16 | uint32_t(a[3]) << 24;
  const uint32_t pb = b[0] | b[1] << 8 | b[2] << 16 | uint32_t(b[3]) << 24;
  if ((reinterpret_cast<uintptr_t>(o) & 7) == 0) {
    *reinterpret_cast<uint2*>(o) = make_uint2(pa, pb);
  } else {
    reinterpret_cast<uint32_t*>(o)[0] = pa;
    reinterpret_cast<uint32_t*>(o)[1] = pb;
  }
}

__global__ void rgb4_kernel(const uint8_t* in, size_t in_pitch, int width, int height, bool swap_rb, bool opaque,
                            uint8_t* out, size_t out_pitch) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= width || y >= height) return;
  const uchar4 s = *reinterpret_cast<const uchar4*>(in + size_t(y) * in_pitch + size_t(x) * 4);
  const uint8_t src[4] = {s.x, s.y, s.z, s.w};
  uint8_t px[4];
  stitch::rgb4_pixel(src, swap_rb, opaque, px);
  *reinterpret_cast<uchar4*>(out + size_t(y) * out_pitch + size_t(x) * 4) = make_uchar4(px[0], px[1], px[2], px[3]);
}

}  // namespace

void launch_yuv420_to_rgba(const stitch::Yuv420Planes& in, const stitch::YuvToRgbQ16& k, uint8_t* out,
                           size_t out_pitch, cudaStream_t stream) {
  if (in.width <= 0 || in.height <= 0) return;
  const dim3 block(32, 8), grid((in.width + 63) / 64, (in.height + 7) / 8);
  yuv420_kernel<<<grid, block, 0, stream>>>(in, k, out, out_pitch);
  check_launch("4:2:0 to RGBA kernel");
}

void launch_rgb4_to_rgba(const uint8_t* in, size_t in_pitch, int width, int height, bool swap_rb, bool opaque,
                         uint8_t* out, size_t out_pitch, cudaStream_t stream) {
  if (width <= 0 || height <= 0) return;
  const dim3 block(32, 8), grid((width + 31) / 32, (height + 7) / 8);
  rgb4_kernel<<<grid, block, 0, stream>>>(in, in_pitch, width, height, swap_rb, opaque, out, out_pitch);
  check_launch("RGB to RGBA kernel");
}

}  // namespace stitch_cuda
