#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <vector>

#include "../launch_check.hpp"
#include "../common.cuh"
#include "blend_kernels.hpp"
#include "stitch/blend/seam_math.hpp"

namespace stitch_cuda {

namespace {

struct ComposeParams {
  int n;
  ViewGeometry views[kMaxViews];
  DeviceImage src[kMaxViews];
  float color[kMaxViews][9];
  int has_color;
  DeviceImage out;
  // The consensus blend in the same pass (fuse only; nullptr: none): out.width-wide labels and
  // mix levels: where a level m > 0, the rounded mean becomes stitch::seam::mix_value(mean, labelled view, m)
  // (the CPU: seam.hpp apply_seam_mix).
  const uint8_t* labels;
  const uint8_t* mix;
  const uint8_t* tiles;  // nullptr: none; launch_fuse_tiles' classes, one per block
  int vector_rows;       // out's rows start on 16 bytes
};

// Every view's warp in one launch (blockIdx.z: the view), kWarpPixels consecutive pixels of a row
// per thread: the per-thread index arithmetic and the stores are shared (one 8-byte store where
// the rows allow it). With a texture the hardware does the bilinear taps (8-bit weights: within
// 2 grey levels of the gathers, 60 dB; the CPU's fixed-point remap is 1/32 px); without, gathers.
constexpr int kWarpPixels = 2;  // 2 beat 4 at four of the five sizes measured (BENCHMARKS)
struct WarpBatch {
  ViewGeometry views[kMaxViews];
  DeviceImage src[kMaxViews], dst[kMaxViews];
  uint8_t* luma[kMaxViews];
  unsigned long long tex[kMaxViews];  // 0: gathers
  unsigned vector_rows;               // bit i: view i's rows (and luma rows) take vector stores
};

template <bool kCurved, bool kTexture>
__global__ void warp_views_kernel(const __grid_constant__ WarpBatch b) {
  const int i = blockIdx.z;
  const DeviceImage& dst = b.dst[i];
  const int x0 = (blockIdx.x * blockDim.x + threadIdx.x) * kWarpPixels, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x0 >= dst.width || y >= dst.height) return;
  const ViewGeometry& vg = b.views[i];
  const DeviceImage& src = b.src[i];
  uchar4 o[kWarpPixels];
#pragma unroll
  for (int k = 0; k < kWarpPixels; ++k) {
    float u, v;
    float4 c = make_float4(0.f, 0.f, 0.f, 0.f);
    if (view_to_camera<kCurved>(vg, float(vg.roi_x + x0 + k), float(vg.roi_y + y), u, v) && u > -1.f && v > -1.f &&
        u < src.width && v < src.height) {
      if (kTexture) {
        // Texel centres sit at +0.5 in texture coordinates; normalised reads return [0, 1].
        c = tex2D<float4>(cudaTextureObject_t(b.tex[i]), u + 0.5f, v + 0.5f);
        c = make_float4(c.x * 255.f, c.y * 255.f, c.z * 255.f, c.w * 255.f);
      } else {
        c = sample_bilinear(src.data, src.pitch, src.width, src.height, u, v);
      }
    }
    o[k] = make_uchar4(to_u8(c.x), to_u8(c.y), to_u8(c.z), to_u8(c.w));
  }
  uint8_t* row = dst.data + size_t(y) * dst.pitch + size_t(x0) * 4;
  uint8_t* luma = b.luma[i] ? b.luma[i] + size_t(y) * dst.width + x0 : nullptr;
  if ((b.vector_rows >> i & 1u) && x0 + kWarpPixels <= dst.width) {
    static_assert(kWarpPixels == 2, "one uint2 of pixels, one uchar2 of luma");
    *reinterpret_cast<uint2*>(row) = make_uint2(*reinterpret_cast<const unsigned*>(&o[0]), *reinterpret_cast<const unsigned*>(&o[1]));
    if (luma)
      *reinterpret_cast<uchar2*>(luma) =
          make_uchar2(stitch::seam::luma(reinterpret_cast<const uint8_t*>(&o[0])), stitch::seam::luma(reinterpret_cast<const uint8_t*>(&o[1])));
    return;
  }
#pragma unroll
  for (int k = 0; k < kWarpPixels; ++k) {
    if (x0 + k >= dst.width) break;
    reinterpret_cast<uchar4*>(row)[k] = o[k];
    if (luma) luma[k] = stitch::seam::luma(reinterpret_cast<const uint8_t*>(&o[k]));
  }
}

// out_c = sum_k in_k M[k][c], clamped to [0, 255].
__device__ __forceinline__ void apply_color(float4& c, const float* M) {
  const float cr = c.x * M[0] + c.y * M[3] + c.z * M[6];
  const float cg = c.x * M[1] + c.y * M[4] + c.z * M[7];
  const float cb = c.x * M[2] + c.y * M[5] + c.z * M[8];
  c.x = fminf(fmaxf(cr, 0.f), 255.f);
  c.y = fminf(fmaxf(cg, 0.f), 255.f);
  c.z = fminf(fmaxf(cb, 0.f), 255.f);
}

// The weighted mean as an opaque pixel; black where no view covers it.
__device__ __forceinline__ uchar4 mean_pixel(float r, float g, float b, float wsum) {
  if (!(wsum > 0.f)) return make_uchar4(0, 0, 0, 255);
  const float inv = 1.f / wsum;
  return make_uchar4(to_u8(r * inv), to_u8(g * inv), to_u8(b * inv), 255);
}

// The weighted mean as mean_pixel rounds it (o), then the consensus blend's mix towards the
// labelled view (seam.hpp apply_seam_mix on the CPU, the same arithmetic), in the fuse's own pass.
__device__ __forceinline__ uchar4 mixed_pixel(const ComposeParams& p, int x, int y, uchar4 o) {
  const size_t at = size_t(y) * p.out.width + x;
  const int m = p.mix[at], l = p.labels[at];
  if (m && l < p.n && p.src[l].data) {
    const ViewGeometry& v = p.views[l];
    if (x >= v.roi_x && y >= v.roi_y && x < v.roi_x + v.roi_w && y < v.roi_y + v.roi_h) {
      const uchar4 q =
          *reinterpret_cast<const uchar4*>(p.src[l].data + size_t(y - v.roi_y) * p.src[l].pitch + size_t(x - v.roi_x) * 4);
      o.x = stitch::seam::mix_value(o.x, q.x, m);
      o.y = stitch::seam::mix_value(o.y, q.y, m);
      o.z = stitch::seam::mix_value(o.z, q.z, m);
    }
  }
  return o;
}

// Output pixel (x, y). mode 0: views are warped rois (fuse); mode 1: views are camera frames
// (compose). `alone` (fuse with tiles): the tile's view when one view covers it alone, or
// kFuseTileEmpty; -1: map the pixel into every view.
template <int kMode, bool kCurved>
__device__ __forceinline__ uchar4 blend_pixel(const ComposeParams& p, int x, int y, int alone) {
  if (kMode == 0 && alone >= 0) {
    // The weighted mean of one view, w c / w, rounds back to c exactly (c <= 255, a few ulps
    // off before the rounding), so the pixel is the view's.
    uchar4 o = make_uchar4(0, 0, 0, 255);
    if (alone != kFuseTileEmpty) {
      const ViewGeometry& vg = p.views[alone];
      const uchar4 q =
          *reinterpret_cast<const uchar4*>(p.src[alone].data + size_t(y - vg.roi_y) * p.src[alone].pitch + size_t(x - vg.roi_x) * 4);
      o = make_uchar4(q.x, q.y, q.z, 255);
    }
    return p.mix ? mixed_pixel(p, x, y, o) : o;
  }
  if (kMode == 1 && alone >= 0) {
    // One view alone (its position weight > 0 on the whole tile): its sample, w c / w without
    // the weight (a tie may round the other way: one level, rarely).
    if (alone == kFuseTileEmpty) return make_uchar4(0, 0, 0, 255);
    float u, v;
    view_to_camera<kCurved>(p.views[alone], float(x), float(y), u, v);
    const DeviceImage& s = p.src[alone];
    float4 c = sample_bilinear(s.data, s.pitch, s.width, s.height, u, v);
    if (p.has_color) apply_color(c, p.color[alone]);
    return mean_pixel(c.x, c.y, c.z, 1.f);
  }
  float r = 0.f, g = 0.f, b = 0.f, wsum = 0.f;
  for (int i = 0; i < p.n; ++i) {
    const ViewGeometry& vg = p.views[i];
    const DeviceImage& s = p.src[i];
    float u, v;
    const float w = s.data ? view_weight<kCurved>(vg, x, y, u, v) : 0.f;
    if (w <= 0.f) continue;
    float4 c;
    if (kMode == 0) {
      const uchar4 q = *reinterpret_cast<const uchar4*>(s.data + size_t(y - vg.roi_y) * s.pitch + size_t(x - vg.roi_x) * 4);
      c = make_float4(q.x, q.y, q.z, q.w);
    } else {
      c = sample_bilinear(s.data, s.pitch, s.width, s.height, u, v);
      if (p.has_color) apply_color(c, p.color[i]);
    }
    r += w * c.x;
    g += w * c.y;
    b += w * c.z;
    wsum += w;
  }
  const uchar4 o = mean_pixel(r, g, b, wsum);
  return kMode == 0 && p.mix ? mixed_pixel(p, x, y, o) : o;
}

// kPixels consecutive pixels of a row to a thread (one vector store where the output rows
// allow); a block of kFuseTileW / kPixels x kFuseTileH threads is one fuse tile. Both take 2
// (measured against 1 and 4: fastest from 2 x 1080p up; the compose, on its tiles, 17-24 % faster
// than 1 there, 0.6 us slower at 3 x 640x480, where a copy of the same bytes is slower still).
constexpr int kFusePixels = 2, kComposePixels = 2;
template <int kPixels>
__device__ __forceinline__ void store_pixels(const DeviceImage& out, bool vector_rows, int x0, int y, const uchar4* o) {
  uint8_t* row = out.data + size_t(y) * out.pitch + size_t(x0) * 4;
  if (kPixels > 1 && vector_rows && x0 + kPixels <= out.width) {
    const unsigned* u = reinterpret_cast<const unsigned*>(o);
    if (kPixels == 4) *reinterpret_cast<uint4*>(row) = make_uint4(u[0], u[1], u[2], u[3]);
    else *reinterpret_cast<uint2*>(row) = make_uint2(u[0], u[1]);
    return;
  }
#pragma unroll
  for (int k = 0; k < kPixels; ++k)
    if (x0 + k < out.width) reinterpret_cast<uchar4*>(row)[k] = o[k];
}
template <int kPixels>
dim3 tile_block() {
  static_assert(kFuseTileW % kPixels == 0 && (kPixels == 1 || kPixels == 2 || kPixels == 4), "a block is one fuse tile");
  return dim3(kFuseTileW / kPixels, kFuseTileH);
}
inline dim3 tile_grid(int width, int height) {
  return dim3((width + kFuseTileW - 1) / kFuseTileW, (height + kFuseTileH - 1) / kFuseTileH);
}

// This block's tile (the block is the tile; tiles: launch_fuse_tiles', nullptr: none): the view
// that covers it alone when `present(view)`, or kFuseTileEmpty; -1: map every view.
template <class Present>
__device__ __forceinline__ int alone_in_tile(const uint8_t* tiles, int n, const Present& present) {
  if (!tiles) return -1;
  const int tile = tiles[blockIdx.y * gridDim.x + blockIdx.x];
  return (tile < n && present(tile)) || tile == kFuseTileEmpty ? tile : -1;
}

template <int kMode, bool kCurved, int kPixels>
__global__ void blend_kernel(const ComposeParams p) {
  const int x0 = (blockIdx.x * blockDim.x + threadIdx.x) * kPixels, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x0 >= p.out.width || y >= p.out.height) return;
  const int alone = alone_in_tile(p.tiles, p.n, [&](int view) { return p.src[view].data != nullptr; });
  uchar4 o[kPixels];
#pragma unroll
  for (int k = 0; k < kPixels; ++k)
    o[k] = x0 + k < p.out.width ? blend_pixel<kMode, kCurved>(p, x0 + k, y, alone) : make_uchar4(0, 0, 0, 0);
  store_pixels<kPixels>(p.out, p.vector_rows, x0, y, o);
}

// One block per fuse tile: which views' position weights are positive at each pixel, the
// tile's class from them (launch_fuse_tiles).
template <bool kCurved>
__global__ void fuse_tiles_kernel(const ComposeParams p, int width, int height, uint8_t* tiles) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  unsigned covering = 0;
  const bool inside = x < width && y < height;
  if (inside)
    for (int i = 0; i < p.n; ++i) {
      float u, v;
      if (view_weight<kCurved>(p.views[i], x, y, u, v) > 0.f) covering |= 1u << i;
    }
  __shared__ unsigned first, differs;
  if (threadIdx.x == 0 && threadIdx.y == 0) {
    first = covering;  // the tile's first pixel is always inside the output
    differs = 0;
  }
  __syncthreads();
  if (inside && covering != first) atomicOr(&differs, 1u);
  __syncthreads();
  if (threadIdx.x != 0 || threadIdx.y != 0) return;
  uint8_t cls = kFuseTileMixed;
  if (!differs) {
    if (first == 0) cls = kFuseTileEmpty;
    else if ((first & (first - 1)) == 0) cls = uint8_t(__ffs(first) - 1);
  }
  tiles[blockIdx.y * gridDim.x + blockIdx.x] = cls;
}

struct TexComposeParams {
  int n;
  ViewGeometry views[kMaxViews];
  cudaTextureObject_t tex[kMaxViews];
  float color[kMaxViews][9];
  int has_color;
  DeviceImage out;
  const uint8_t* tiles;  // nullptr: none (launch_compose_tex)
  int vector_rows;       // out's rows start on 16 bytes
};

// Texture units' sample of view i at camera pixel (u, v), 0..255, with its colour matrix.
__device__ __forceinline__ float4 tex_sample(const TexComposeParams& p, int i, float u, float v) {
  // Texel centres sit at +0.5 in texture coordinates; normalised reads return [0, 1].
  float4 c = tex2D<float4>(p.tex[i], u + 0.5f, v + 0.5f);
  c.x *= 255.f;
  c.y *= 255.f;
  c.z *= 255.f;
  if (p.has_color) apply_color(c, p.color[i]);
  return c;
}

template <bool kCurved>
__device__ __forceinline__ uchar4 compose_tex_pixel(const TexComposeParams& p, int x, int y, int alone) {
  if (alone >= 0) {  // as blend_pixel's one-view tiles
    if (alone == kFuseTileEmpty) return make_uchar4(0, 0, 0, 255);
    float u, v;
    view_to_camera<kCurved>(p.views[alone], float(x), float(y), u, v);
    const float4 c = tex_sample(p, alone, u, v);
    return mean_pixel(c.x, c.y, c.z, 1.f);
  }
  float r = 0.f, g = 0.f, b = 0.f, wsum = 0.f;
  for (int i = 0; i < p.n; ++i) {
    float u, v;
    const float w = p.tex[i] ? view_weight<kCurved>(p.views[i], x, y, u, v) : 0.f;
    if (w <= 0.f) continue;
    const float4 c = tex_sample(p, i, u, v);
    r += w * c.x;
    g += w * c.y;
    b += w * c.z;
    wsum += w;
  }
  return mean_pixel(r, g, b, wsum);
}

template <bool kCurved>
__global__ void compose_tex_kernel(const TexComposeParams p) {
  constexpr int kPixels = kComposePixels;
  const int x0 = (blockIdx.x * blockDim.x + threadIdx.x) * kPixels, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x0 >= p.out.width || y >= p.out.height) return;
  const int alone = alone_in_tile(p.tiles, p.n, [&](int view) { return p.tex[view] != 0; });
  uchar4 o[kPixels];
#pragma unroll
  for (int k = 0; k < kPixels; ++k)
    o[k] = x0 + k < p.out.width ? compose_tex_pixel<kCurved>(p, x0 + k, y, alone) : make_uchar4(0, 0, 0, 0);
  store_pixels<kPixels>(p.out, p.vector_rows, x0, y, o);
}

struct Affine {
  float m[6];
};

__global__ void resample_kernel(DeviceImage src, Affine A, DeviceImage dst) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= dst.width || y >= dst.height) return;
  const float u = A.m[0] * x + A.m[1] * y + A.m[2], v = A.m[3] * x + A.m[4] * y + A.m[5];
  uchar4 o = make_uchar4(0, 0, 0, 255);
  if (u > -1.f && v > -1.f && u < src.width && v < src.height) {
    const float4 c = sample_bilinear(src.data, src.pitch, src.width, src.height, u, v);
    o = make_uchar4(to_u8(c.x), to_u8(c.y), to_u8(c.z), 255);
  }
  *reinterpret_cast<uchar4*>(dst.data + size_t(y) * dst.pitch + size_t(x) * 4) = o;
}

ComposeParams params_of(int n, const ViewGeometry* views, const DeviceImage* images, const DeviceImage& out) {
  if (n < 0 || n > kMaxViews) throw std::invalid_argument("at most 16 views on the GPU");
  ComposeParams p{};
  p.n = n;
  for (int i = 0; i < n; ++i) {
    p.views[i] = views[i];
    p.src[i] = images[i];
  }
  p.out = out;
  p.vector_rows = reinterpret_cast<uintptr_t>(out.data) % 16 == 0 && out.pitch % 16 == 0;
  return p;
}

// One mipmap step: the rounded mean of each 2x2 block (the last row/column repeated at odd
// sizes), as stitch::halve_frame computes it.
__global__ void halve_kernel(DeviceImage src, DeviceImage dst) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= dst.width || y >= dst.height) return;
  const uchar4* r0 = reinterpret_cast<const uchar4*>(src.data + size_t(min(2 * y, src.height - 1)) * src.pitch);
  const uchar4* r1 = reinterpret_cast<const uchar4*>(src.data + size_t(min(2 * y + 1, src.height - 1)) * src.pitch);
  const int a = 2 * x, b = min(2 * x + 1, src.width - 1);
  const uchar4 p = r0[a], q = r0[b], r = r1[a], t = r1[b];
  uchar4 o;
  o.x = (unsigned(p.x) + q.x + r.x + t.x + 2) >> 2;
  o.y = (unsigned(p.y) + q.y + r.y + t.y + 2) >> 2;
  o.z = (unsigned(p.z) + q.z + r.z + t.z + 2) >> 2;
  o.w = (unsigned(p.w) + q.w + r.w + t.w + 2) >> 2;
  reinterpret_cast<uchar4*>(dst.data + size_t(y) * dst.pitch)[x] = o;
}

}  // namespace

void launch_halve(const DeviceImage& src, const DeviceImage& dst, cudaStream_t stream) {
  if (dst.width <= 0 || dst.height <= 0) return;
  const dim3 block(32, 8), grid((dst.width + 31) / 32, (dst.height + 7) / 8);
  halve_kernel<<<grid, block, 0, stream>>>(src, dst);
  check_launch("halve kernel");
}

void launch_warps(int n, const DeviceImage* srcs, const ViewGeometry* views, const DeviceImage* dsts, uint8_t* const* lumas,
                  const unsigned long long* textures, cudaStream_t stream) {
  if (n < 0 || n > kMaxViews) throw std::invalid_argument("at most 16 views on the GPU");
  WarpBatch b{};
  int width = 0, height = 0;
  bool texture = textures != nullptr;
  for (int i = 0; i < n; ++i) {
    b.views[i] = views[i];
    b.src[i] = srcs[i];
    b.dst[i] = dsts[i];
    if (!srcs[i].data || !dsts[i].data) b.dst[i].width = b.dst[i].height = 0;  // nothing to warp
    b.luma[i] = lumas ? lumas[i] : nullptr;
    if (textures) b.tex[i] = textures[i];
    texture = texture && (textures[i] || !b.dst[i].width);
    constexpr size_t kRowBytes = 4 * kWarpPixels;  // one vector store of pixels, kWarpPixels bytes of luma
    const auto aligned = [](const void* p, size_t step, size_t to) { return reinterpret_cast<uintptr_t>(p) % to == 0 && step % to == 0; };
    if (aligned(b.dst[i].data, b.dst[i].pitch, kRowBytes) &&
        (!b.luma[i] || aligned(b.luma[i], size_t(b.dst[i].width), kWarpPixels)))
      b.vector_rows |= 1u << i;
    width = std::max(width, b.dst[i].width);
    height = std::max(height, b.dst[i].height);
  }
  if (width <= 0 || height <= 0) return;
  const dim3 block(32, 8), grid((width + 32 * kWarpPixels - 1) / (32 * kWarpPixels), (height + 7) / 8, n);
  const bool curved = any_curved(views, n);
  if (texture) {
    if (curved) warp_views_kernel<true, true><<<grid, block, 0, stream>>>(b);
    else warp_views_kernel<false, true><<<grid, block, 0, stream>>>(b);
  } else {
    if (curved) warp_views_kernel<true, false><<<grid, block, 0, stream>>>(b);
    else warp_views_kernel<false, false><<<grid, block, 0, stream>>>(b);
  }
  check_launch("warp kernel");
}

void launch_warp(const DeviceImage& src, const ViewGeometry& view, const DeviceImage& dst, cudaStream_t stream,
                 uint8_t* luma) {
  launch_warps(1, &src, &view, &dst, &luma, nullptr, stream);
}

void launch_resample_affine(const DeviceImage& src, const float* inverse_affine, const DeviceImage& dst,
                            cudaStream_t stream) {
  if (dst.width <= 0 || dst.height <= 0) return;
  Affine A;
  for (int k = 0; k < 6; ++k) A.m[k] = inverse_affine[k];
  const dim3 block(32, 8), grid((dst.width + 31) / 32, (dst.height + 7) / 8);
  resample_kernel<<<grid, block, 0, stream>>>(src, A, dst);
  check_launch("resample kernel");
}

void launch_fuse(int n, const ViewGeometry* views, const DeviceImage* warped, const DeviceImage& out,
                 cudaStream_t stream, const uint8_t* labels, const uint8_t* mix, const uint8_t* tiles) {
  ComposeParams p = params_of(n, views, warped, out);
  if (labels && mix) p.labels = labels, p.mix = mix;
  p.tiles = tiles;
  const dim3 block = tile_block<kFusePixels>(), grid = tile_grid(out.width, out.height);
  if (any_curved(views, n)) blend_kernel<0, true, kFusePixels><<<grid, block, 0, stream>>>(p);
  else blend_kernel<0, false, kFusePixels><<<grid, block, 0, stream>>>(p);
  check_launch("fuse kernel");
}

void launch_fuse_tiles(int n, const ViewGeometry* views, int width, int height, uint8_t* tiles, cudaStream_t stream) {
  if (width <= 0 || height <= 0) return;
  DeviceImage none{};
  none.width = width;
  none.height = height;
  const ComposeParams p = params_of(n, views, std::vector<DeviceImage>(size_t(n)).data(), none);
  const dim3 block(kFuseTileW, kFuseTileH), grid((width + kFuseTileW - 1) / kFuseTileW, (height + kFuseTileH - 1) / kFuseTileH);
  if (any_curved(views, n)) fuse_tiles_kernel<true><<<grid, block, 0, stream>>>(p, width, height, tiles);
  else fuse_tiles_kernel<false><<<grid, block, 0, stream>>>(p, width, height, tiles);
  check_launch("fuse tiles kernel");
}

void launch_compose(int n, const ViewGeometry* views, const DeviceImage* frames, const float* color,
                    const DeviceImage& out, cudaStream_t stream, const uint8_t* tiles) {
  ComposeParams p = params_of(n, views, frames, out);
  p.tiles = tiles;
  if (color) {
    p.has_color = 1;
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < 9; ++k) p.color[i][k] = color[9 * i + k];
  }
  const dim3 block = tile_block<kComposePixels>(), grid = tile_grid(out.width, out.height);
  if (any_curved(views, n)) blend_kernel<1, true, kComposePixels><<<grid, block, 0, stream>>>(p);
  else blend_kernel<1, false, kComposePixels><<<grid, block, 0, stream>>>(p);
  check_launch("compose kernel");
}

void launch_compose_tex(int n, const ViewGeometry* views, const unsigned long long* textures, const float* color,
                        const DeviceImage& out, cudaStream_t stream, const uint8_t* tiles) {
  if (n < 0 || n > kMaxViews) throw std::invalid_argument("at most 16 views on the GPU");
  TexComposeParams p{};
  p.n = n;
  for (int i = 0; i < n; ++i) {
    p.views[i] = views[i];
    p.tex[i] = cudaTextureObject_t(textures[i]);
    if (color)
      for (int k = 0; k < 9; ++k) p.color[i][k] = color[9 * i + k];
  }
  p.has_color = color != nullptr;
  p.out = out;
  p.tiles = tiles;
  p.vector_rows = reinterpret_cast<uintptr_t>(out.data) % 16 == 0 && out.pitch % 16 == 0;
  const dim3 block = tile_block<kComposePixels>(), grid = tile_grid(out.width, out.height);
  if (any_curved(views, n)) compose_tex_kernel<true><<<grid, block, 0, stream>>>(p);
  else compose_tex_kernel<false><<<grid, block, 0, stream>>>(p);
  check_launch("compose (texture) kernel");
}

unsigned long long create_rgba_texture(const DeviceImage& image) {
  // Attributes, not cudaGetDeviceProperties: that one is slow and this runs when a buffer changes.
  int device = 0, pitch_alignment = 0;
  if (cudaGetDevice(&device) != cudaSuccess ||
      cudaDeviceGetAttribute(&pitch_alignment, cudaDevAttrTexturePitchAlignment, device) != cudaSuccess ||
      pitch_alignment <= 0) {
    cudaGetLastError();
    return 0;
  }
  constexpr uintptr_t kBaseAlignment = 512;  // cudaDeviceProp::textureAlignment on every current GPU
  if (reinterpret_cast<uintptr_t>(image.data) % kBaseAlignment != 0 || image.pitch % size_t(pitch_alignment) != 0)
    return 0;
  cudaResourceDesc res{};
  res.resType = cudaResourceTypePitch2D;
  res.res.pitch2D.devPtr = image.data;
  res.res.pitch2D.desc = cudaCreateChannelDesc<uchar4>();
  res.res.pitch2D.width = size_t(image.width);
  res.res.pitch2D.height = size_t(image.height);
  res.res.pitch2D.pitchInBytes = image.pitch;
  cudaTextureDesc td{};
  td.addressMode[0] = td.addressMode[1] = cudaAddressModeBorder;  // zero outside: transparent
  td.filterMode = cudaFilterModeLinear;
  td.readMode = cudaReadModeNormalizedFloat;
  td.normalizedCoords = 0;
  cudaTextureObject_t t = 0;
  const cudaError_t e = cudaCreateTextureObject(&t, &res, &td, nullptr);
  if (e != cudaSuccess) {
    cudaGetLastError();
    return 0;
  }
  return t;
}

void destroy_texture(unsigned long long texture) {
  if (texture) cudaDestroyTextureObject(cudaTextureObject_t(texture));
}

}  // namespace stitch_cuda
