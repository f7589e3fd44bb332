#include "../launch_check.hpp"
#include "../common.cuh"
#include "multiband_kernels.hpp"
#include "stitch/blend/pyramid_math.hpp"

namespace stitch_cuda {

namespace pm = stitch::pyramid;

namespace {

__device__ __forceinline__ float4& at(const FloatImage& im, int x, int y) {
  return im.data[size_t(y) * im.pitch + x];
}
__device__ __forceinline__ void madd(float4& a, const float4& b, float w) {
  a.x += b.x * w, a.y += b.y * w, a.z += b.z * w, a.w += b.w * w;
}

__global__ void premultiply_kernel(DeviceImage view, FloatImage pull) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= pull.width || y >= pull.height) return;
  float4 o = make_float4(0.f, 0.f, 0.f, 0.f);
  if (x < view.width && y < view.height) {
    const uchar4 p = *reinterpret_cast<const uchar4*>(view.data + size_t(y) * view.pitch + size_t(x) * 4);
    const float a = p.w * (1.f / 255.f);
    o = make_float4(__fmul_rn(p.x, a), __fmul_rn(p.y, a), __fmul_rn(p.z, a), a);
  }
  at(pull, x, y) = o;
}

__global__ void push_kernel(FloatImage pull, FloatImage upper, FloatImage fill) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= fill.width || y >= fill.height) return;
  const float4 p = at(pull, x, y);
  float4 f;
  if (upper.data) {
    const float4 u = at(upper, x, y);
    const float r = 1.f - p.w;
    f = make_float4(p.x + r * u.x, p.y + r * u.y, p.z + r * u.z, p.w);
  } else {
    const float inv = 1.f / (p.w + 1e-5f);
    f = make_float4(p.x * inv, p.y * inv, p.z * inv, p.w);
  }
  at(fill, x, y) = f;
}

__global__ void load_view_kernel(FloatImage filled, int roi_w, int roi_h, int roi_x, int roi_y, int rect_x, int rect_y,
                                 const uint8_t* labels, int label_w, int label_h, int index, FloatImage dst) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= dst.width || y >= dst.height) return;
  const float4 p = at(filled, pm::reflect(x - roi_x, roi_w), pm::reflect(y - roi_y, roi_h));
  const int cx = rect_x + x, cy = rect_y + y;
  const bool mine = cx < label_w && cy < label_h && labels[size_t(cy) * label_w + cx] == index;
  at(dst, x, y) = make_float4(p.x, p.y, p.z, mine ? 1.f : 0.f);
}

template <bool kAlongX>
__global__ void down_kernel(FloatImage src, FloatImage dst) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= dst.width || y >= dst.height) return;
  float4 a = make_float4(0.f, 0.f, 0.f, 0.f);
#pragma unroll
  for (int i = -2; i <= 2; ++i) {
    const float4 s = kAlongX ? at(src, pm::down_source(x, i, src.width), y) : at(src, x, pm::down_source(y, i, src.height));
    madd(a, s, pm::binomial_tap(i));
  }
  at(dst, x, y) = a;
}

template <bool kAlongX>
__global__ void up_kernel(FloatImage src, FloatImage dst) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= dst.width || y >= dst.height) return;
  float4 a = make_float4(0.f, 0.f, 0.f, 0.f);
#pragma unroll
  for (int i = -2; i <= 2; ++i) {
    float w;
    const int k = pm::up_source(kAlongX ? x : y, i, kAlongX ? dst.width : dst.height, w);
    if (k >= 0) madd(a, kAlongX ? at(src, k, y) : at(src, x, k), w);
  }
  at(dst, x, y) = a;
}

__global__ void accumulate_kernel(FloatImage g, FloatImage upper, FloatImage acc, int x0, int y0) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= g.width || y >= g.height) return;
  const float4 p = at(g, x, y);
  const float4 u = upper.data ? at(upper, x, y) : make_float4(0.f, 0.f, 0.f, 0.f);
  float4& a = at(acc, x0 + x, y0 + y);
  a.x += (p.x - u.x) * p.w;
  a.y += (p.y - u.y) * p.w;
  a.z += (p.z - u.z) * p.w;
  a.w += p.w;
}

__global__ void add_normalised_kernel(FloatImage acc, FloatImage img, bool add) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= img.width || y >= img.height) return;
  const float4 a = at(acc, x, y);
  const float inv = 1.f / (a.w + 1e-5f);
  float4& o = at(img, x, y);
  if (add) o = make_float4(o.x + a.x * inv, o.y + a.y * inv, o.z + a.z * inv, 0.f);
  else o = make_float4(a.x * inv, a.y * inv, a.z * inv, 0.f);
}

__global__ void store_kernel(FloatImage img, const uint8_t* labels, DeviceImage out) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= out.width || y >= out.height) return;
  uchar4 o = make_uchar4(0, 0, 0, 255);
  if (labels[size_t(y) * out.width + x] != 255) {
    const float4 p = at(img, x, y);
    o = make_uchar4(to_u8(p.x), to_u8(p.y), to_u8(p.z), 255);
  }
  *reinterpret_cast<uchar4*>(out.data + size_t(y) * out.pitch + size_t(x) * 4) = o;
}

dim3 grid_for(int w, int h, dim3 block) { return dim3((w + block.x - 1) / block.x, (h + block.y - 1) / block.y); }
const dim3 kBlock(32, 8);

}  // namespace

void launch_mb_premultiply(const DeviceImage& view, const FloatImage& pull, cudaStream_t stream) {
  premultiply_kernel<<<grid_for(pull.width, pull.height, kBlock), kBlock, 0, stream>>>(view, pull);
  check_launch("multiband premultiply_kernel");
}

void launch_mb_push(const FloatImage& pull, const FloatImage& upper, const FloatImage& fill, cudaStream_t stream) {
  push_kernel<<<grid_for(fill.width, fill.height, kBlock), kBlock, 0, stream>>>(pull, upper, fill);
  check_launch("multiband push_kernel");
}

void launch_mb_load_view(const FloatImage& filled, int roi_w, int roi_h, int roi_x, int roi_y, int rect_x, int rect_y,
                         const uint8_t* labels, int label_w, int label_h, int index, const FloatImage& dst,
                         cudaStream_t stream) {
  load_view_kernel<<<grid_for(dst.width, dst.height, kBlock), kBlock, 0, stream>>>(
      filled, roi_w, roi_h, roi_x, roi_y, rect_x, rect_y, labels, label_w, label_h, index, dst);
  check_launch("multiband load_view_kernel");
}

void launch_mb_down(const FloatImage& src, const FloatImage& tmp, const FloatImage& dst, cudaStream_t stream) {
  down_kernel<true><<<grid_for(tmp.width, tmp.height, kBlock), kBlock, 0, stream>>>(src, tmp);
  check_launch("multiband down_kernel (x)");
  down_kernel<false><<<grid_for(dst.width, dst.height, kBlock), kBlock, 0, stream>>>(tmp, dst);
  check_launch("multiband down_kernel (y)");
}

void launch_mb_up(const FloatImage& src, const FloatImage& tmp, const FloatImage& dst, cudaStream_t stream) {
  up_kernel<true><<<grid_for(tmp.width, tmp.height, kBlock), kBlock, 0, stream>>>(src, tmp);
  check_launch("multiband up_kernel (x)");
  up_kernel<false><<<grid_for(dst.width, dst.height, kBlock), kBlock, 0, stream>>>(tmp, dst);
  check_launch("multiband up_kernel (y)");
}

void launch_mb_accumulate(const FloatImage& g, const FloatImage& upper, const FloatImage& acc, int x0, int y0,
                          cudaStream_t stream) {
  accumulate_kernel<<<grid_for(g.width, g.height, kBlock), kBlock, 0, stream>>>(g, upper, acc, x0, y0);
  check_launch("multiband accumulate_kernel");
}

void launch_mb_add_normalised(const FloatImage& acc, const FloatImage& img, bool add, cudaStream_t stream) {
  add_normalised_kernel<<<grid_for(img.width, img.height, kBlock), kBlock, 0, stream>>>(acc, img, add);
  check_launch("multiband add_normalised_kernel");
}

void launch_mb_store(const FloatImage& img, const uint8_t* labels, const DeviceImage& out, cudaStream_t stream) {
  store_kernel<<<grid_for(out.width, out.height, kBlock), kBlock, 0, stream>>>(img, labels, out);
  check_launch("multiband store_kernel");
}

}  // namespace stitch_cuda
