#include "../launch_check.hpp"
#include "../common.cuh"
#include "multiband_kernels.hpp"
#include "stitch/blend/pyramid_math.hpp"

// Each pyramid step is one kernel that evaluates its separable 5-tap filter in registers (rows
// of taps summed first, then the rows: the order of the CPU's and the former two-pass kernels),
// and the steps that only feed one consumer are fused into it: the premultiplied view into its
// first pull level, the finest fill level into the view's level 0, the upsampled coarser level
// into the accumulation and the collapse, the collapse's finest level into the store. Nothing
// the size of the canvas is written but the accumulators and the output.

namespace stitch_cuda {

namespace pm = stitch::pyramid;

namespace {

__device__ __forceinline__ float4& at(const FloatImage& im, int x, int y) {
  return im.data[size_t(y) * im.pitch + x];
}
__device__ __forceinline__ void madd(float4& a, const float4& b, float w) {
  a.x += b.x * w, a.y += b.y * w, a.z += b.z * w, a.w += b.w * w;
}

// A level's pixels read from memory.
struct Stored {
  FloatImage im;
  __device__ float4 operator()(int x, int y) const { return at(im, x, y); }
};

// The view's colours premultiplied by its coverage, 0 outside the view (the pull's level 0).
__device__ __forceinline__ float4 premultiplied(const DeviceImage& view, int x, int y) {
  if (x >= view.width || y >= view.height) return make_float4(0.f, 0.f, 0.f, 0.f);
  const uchar4 p = *reinterpret_cast<const uchar4*>(view.data + size_t(y) * view.pitch + size_t(x) * 4);
  const float a = p.w * (1.f / 255.f);
  return make_float4(__fmul_rn(p.x, a), __fmul_rn(p.y, a), __fmul_rn(p.z, a), a);
}
struct Premultiplied {
  DeviceImage view;
  __device__ float4 operator()(int x, int y) const { return premultiplied(view, x, y); }
};

// pyrDown at (x, y) of a source n_w x n_h.
template <class Source>
__device__ __forceinline__ float4 down_at(const Source& src, int x, int y, int n_w, int n_h) {
  int sx[5];
#pragma unroll
  for (int i = -2; i <= 2; ++i) sx[i + 2] = pm::down_source(x, i, n_w);
  float4 a = make_float4(0.f, 0.f, 0.f, 0.f);
#pragma unroll
  for (int j = -2; j <= 2; ++j) {
    const int sy = pm::down_source(y, j, n_h);
    float4 row = make_float4(0.f, 0.f, 0.f, 0.f);
#pragma unroll
    for (int i = -2; i <= 2; ++i) madd(row, src(sx[i + 2], sy), pm::binomial_tap(i));
    madd(a, row, pm::binomial_tap(j));
  }
  return a;
}

// pyrUp's taps along one axis at x of the finer level (n wide): the kernel's taps i = -2..2 land
// on the coarse level only where x + i is even (reflection keeps the parity), so an even x takes
// three (1/8, 3/4, 1/8) and an odd x two (1/2, 1/2; the third weight 0). The same taps, weights
// and order as pyramid::up_source, without evaluating the two that fall on inserted zeros.
struct UpTaps {
  int s[3];
  float w[3];
};
__device__ __forceinline__ UpTaps up_taps(int x, int n) {
  UpTaps t;
  if (x & 1) {
    t.s[0] = pm::reflect101(x - 1, n) >> 1, t.s[1] = t.s[2] = pm::reflect101(x + 1, n) >> 1;
    t.w[0] = t.w[1] = 2.f * pm::binomial_tap(1), t.w[2] = 0.f;
  } else {
    t.s[0] = pm::reflect101(x - 2, n) >> 1, t.s[1] = x >> 1, t.s[2] = pm::reflect101(x + 2, n) >> 1;
    t.w[0] = t.w[2] = 2.f * pm::binomial_tap(2), t.w[1] = 2.f * pm::binomial_tap(0);
  }
  return t;
}

// pyrUp of `src` at (x, y) of the finer level, n_w x n_h: rows of taps first, then the rows.
// A warp shares y, so its row count (three or two) does not diverge.
__device__ __forceinline__ float4 up_at(const FloatImage& src, int x, int y, int n_w, int n_h) {
  const UpTaps tx = up_taps(x, n_w), ty = up_taps(y, n_h);
  float4 a = make_float4(0.f, 0.f, 0.f, 0.f);
  const int rows = (y & 1) ? 2 : 3;
#pragma unroll
  for (int j = 0; j < 3; ++j) {
    if (j >= rows) break;
    float4 row = make_float4(0.f, 0.f, 0.f, 0.f);
#pragma unroll
    for (int i = 0; i < 3; ++i) madd(row, at(src, tx.s[i], ty.s[j]), tx.w[i]);
    madd(a, row, ty.w[j]);
  }
  return a;
}

// fill.rgb = pull.rgb + (1 - pull.a) · up(coarser).rgb, or pull.rgb / pull.a at the coarsest level.
__device__ __forceinline__ float4 pushed(const float4& p, const FloatImage& coarser, int x, int y, int n_w, int n_h) {
  if (coarser.data) {
    const float4 u = up_at(coarser, x, y, n_w, n_h);
    const float r = 1.f - p.w;
    return make_float4(p.x + r * u.x, p.y + r * u.y, p.z + r * u.z, p.w);
  }
  const float inv = 1.f / (p.w + 1e-5f);
  return make_float4(p.x * inv, p.y * inv, p.z * inv, p.w);
}

__global__ void premultiply_down_kernel(DeviceImage view, int fill_w, int fill_h, FloatImage pull1) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= pull1.width || y >= pull1.height) return;
  at(pull1, x, y) = down_at(Premultiplied{view}, x, y, fill_w, fill_h);
}

__global__ void down_kernel(FloatImage src, FloatImage dst) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= dst.width || y >= dst.height) return;
  at(dst, x, y) = down_at(Stored{src}, x, y, src.width, src.height);
}

__global__ void push_kernel(FloatImage pull, FloatImage coarser, FloatImage fill) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= fill.width || y >= fill.height) return;
  at(fill, x, y) = pushed(at(pull, x, y), coarser, x, y, fill.width, fill.height);
}

__global__ void load_view_kernel(DeviceImage view, FloatImage fill1, int fill_w, int fill_h, int roi_w, int roi_h,
                                 int roi_x, int roi_y, int rect_x, int rect_y, const uint8_t* labels, int label_w,
                                 int label_h, int index, FloatImage dst) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= dst.width || y >= dst.height) return;
  const int px = pm::reflect(x - roi_x, roi_w), py = pm::reflect(y - roi_y, roi_h);
  const float4 p = pushed(premultiplied(view, px, py), fill1, px, py, fill_w, fill_h);
  const int cx = rect_x + x, cy = rect_y + y;
  const bool mine = cx < label_w && cy < label_h && labels[size_t(cy) * label_w + cx] == index;
  at(dst, x, y) = make_float4(p.x, p.y, p.z, mine ? 1.f : 0.f);
}

__global__ void accumulate_kernel(FloatImage g, FloatImage coarser, FloatImage acc, int x0, int y0) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= g.width || y >= g.height) return;
  const float4 p = at(g, x, y);
  if (p.w == 0.f) return;  // adds nothing: most of a view's rectangle at the finer levels
  const float4 u = coarser.data ? up_at(coarser, x, y, g.width, g.height) : make_float4(0.f, 0.f, 0.f, 0.f);
  float4& a = at(acc, x0 + x, y0 + y);
  a.x += (p.x - u.x) * p.w;
  a.y += (p.y - u.y) * p.w;
  a.z += (p.z - u.z) * p.w;
  a.w += p.w;
}

// up(coarser) + acc.rgb / (acc.w + eps) at (x, y) of acc's level.
__device__ __forceinline__ float4 collapsed(const FloatImage& acc, const FloatImage& coarser, int x, int y) {
  const float4 a = at(acc, x, y);
  const float inv = 1.f / (a.w + 1e-5f);
  if (!coarser.data) return make_float4(a.x * inv, a.y * inv, a.z * inv, 0.f);
  const float4 o = up_at(coarser, x, y, acc.width, acc.height);
  return make_float4(o.x + a.x * inv, o.y + a.y * inv, o.z + a.z * inv, 0.f);
}

__global__ void collapse_kernel(FloatImage acc, FloatImage coarser, FloatImage img) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= img.width || y >= img.height) return;
  at(img, x, y) = collapsed(acc, coarser, x, y);
}

__global__ void store_kernel(FloatImage acc0, FloatImage coarser, const uint8_t* labels, DeviceImage out) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= out.width || y >= out.height) return;
  uchar4 o = make_uchar4(0, 0, 0, 255);
  if (labels[size_t(y) * out.width + x] != 255) {
    const float4 p = collapsed(acc0, coarser, x, y);
    o = make_uchar4(to_u8(p.x), to_u8(p.y), to_u8(p.z), 255);
  }
  *reinterpret_cast<uchar4*>(out.data + size_t(y) * out.pitch + size_t(x) * 4) = o;
}

dim3 grid_for(int w, int h, dim3 block) { return dim3((w + block.x - 1) / block.x, (h + block.y - 1) / block.y); }
const dim3 kBlock(32, 8);

}  // namespace

void launch_mb_premultiply_down(const DeviceImage& view, int fill_w, int fill_h, const FloatImage& pull1,
                                cudaStream_t stream) {
  premultiply_down_kernel<<<grid_for(pull1.width, pull1.height, kBlock), kBlock, 0, stream>>>(view, fill_w, fill_h,
                                                                                              pull1);
  check_launch("multiband premultiply_down_kernel");
}

void launch_mb_down(const FloatImage& src, const FloatImage& dst, cudaStream_t stream) {
  down_kernel<<<grid_for(dst.width, dst.height, kBlock), kBlock, 0, stream>>>(src, dst);
  check_launch("multiband down_kernel");
}

void launch_mb_push(const FloatImage& pull, const FloatImage& coarser, const FloatImage& fill, cudaStream_t stream) {
  push_kernel<<<grid_for(fill.width, fill.height, kBlock), kBlock, 0, stream>>>(pull, coarser, fill);
  check_launch("multiband push_kernel");
}

void launch_mb_load_view(const DeviceImage& view, const FloatImage& fill1, int fill_w, int fill_h, int roi_w, int roi_h,
                         int roi_x, int roi_y, int rect_x, int rect_y, const uint8_t* labels, int label_w, int label_h,
                         int index, const FloatImage& dst, cudaStream_t stream) {
  load_view_kernel<<<grid_for(dst.width, dst.height, kBlock), kBlock, 0, stream>>>(
      view, fill1, fill_w, fill_h, roi_w, roi_h, roi_x, roi_y, rect_x, rect_y, labels, label_w, label_h, index, dst);
  check_launch("multiband load_view_kernel");
}

void launch_mb_accumulate(const FloatImage& g, const FloatImage& coarser, const FloatImage& acc, int x0, int y0,
                          cudaStream_t stream) {
  accumulate_kernel<<<grid_for(g.width, g.height, kBlock), kBlock, 0, stream>>>(g, coarser, acc, x0, y0);
  check_launch("multiband accumulate_kernel");
}

void launch_mb_collapse(const FloatImage& acc, const FloatImage& coarser, const FloatImage& img, cudaStream_t stream) {
  collapse_kernel<<<grid_for(img.width, img.height, kBlock), kBlock, 0, stream>>>(acc, coarser, img);
  check_launch("multiband collapse_kernel");
}

void launch_mb_store(const FloatImage& acc0, const FloatImage& coarser, const uint8_t* labels, const DeviceImage& out,
                     cudaStream_t stream) {
  store_kernel<<<grid_for(out.width, out.height, kBlock), kBlock, 0, stream>>>(acc0, coarser, labels, out);
  check_launch("multiband store_kernel");
}

}  // namespace stitch_cuda
