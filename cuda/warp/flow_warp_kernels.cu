#include <stdexcept>
#include <string>

#include "../launch_check.hpp"
#include "../common.cuh"
#include "flow_warp_kernels.hpp"
#include "stitch/warp/flow_gate_math.hpp"

namespace stitch_cuda {

namespace {

struct ViewsParam {
  int n;
  ViewGeometry views[kMaxViews];
  DeviceImage frames[kMaxViews];
};

ViewsParam views_param(const ViewGeometry* views, const DeviceImage* frames, int n) {
  if (n < 0 || n > kMaxViews) throw std::invalid_argument("at most 16 views on the GPU");
  ViewsParam p{};
  p.n = n;
  for (int i = 0; i < n; ++i) {
    p.views[i] = views[i];
    p.frames[i] = frames[i];
  }
  return p;
}

// cv::cvtColor(RGBA2GRAY) on 8-bit values: fixed-point BT.601 luma.
__device__ __forceinline__ uint8_t luma(float4 c) {
  const int r = to_u8(c.x), g = to_u8(c.y), b = to_u8(c.z);
  return uint8_t((r * 4899 + g * 9617 + b * 1868 + (1 << 13)) >> 14);
}

// Bilinear read of an interleaved (u, v) field, coordinates clamped to the image (replicate).
__device__ __forceinline__ float2 sample_flow(const float* f, int w, int h, float x, float y) {
  x = fminf(fmaxf(x, 0.f), float(w - 1));
  y = fminf(fmaxf(y, 0.f), float(h - 1));
  const int x0 = int(x), y0 = int(y);
  const int x1 = min(x0 + 1, w - 1), y1 = min(y0 + 1, h - 1);
  const float ax = x - x0, ay = y - y0;
  const float2* p = reinterpret_cast<const float2*>(f);
  const float2 a = p[y0 * w + x0], b = p[y0 * w + x1], c = p[y1 * w + x0], d = p[y1 * w + x1];
  return make_float2((1 - ay) * ((1 - ax) * a.x + ax * b.x) + ay * ((1 - ax) * c.x + ax * d.x),
                     (1 - ay) * ((1 - ax) * a.y + ax * b.y) + ay * ((1 - ax) * c.y + ax * d.y));
}

// Bilinear read of a packed 8-bit gray image, coordinates clamped (as the CPU warper's sample()).
__device__ __forceinline__ float sample_gray(const uint8_t* g, int w, int h, float x, float y) {
  x = fminf(fmaxf(x, 0.f), float(w - 1));
  y = fminf(fmaxf(y, 0.f), float(h - 1));
  const int x0 = int(x), y0 = int(y);
  const int x1 = min(x0 + 1, w - 1), y1 = min(y0 + 1, h - 1);
  const float ax = x - x0, ay = y - y0;
  const float a = g[y0 * w + x0], b = g[y0 * w + x1], c = g[y1 * w + x0], d = g[y1 * w + x1];
  return (1.f - ay) * ((1.f - ax) * a + ax * b) + ay * ((1.f - ax) * c + ax * d);
}

// Value and central-difference gradient of a gray image at (x, y) (flow_gate::match_error).
__device__ __forceinline__ void gray_with_gradient(const uint8_t* g, int w, int h, float x, float y, float& v,
                                                   float& gx, float& gy) {
  v = sample_gray(g, w, h, x, y);
  gx = 0.5f * (sample_gray(g, w, h, x + 1.f, y) - sample_gray(g, w, h, x - 1.f, y));
  gy = 0.5f * (sample_gray(g, w, h, x, y + 1.f) - sample_gray(g, w, h, x, y - 1.f));
}

template <bool kCurved>
__global__ void overlap_gray_kernel(const FlowPairDevice* pairs, FlowPairMask active, const ViewsParam vp) {
  const int z = blockIdx.z;
  if (!active.test(z)) return;
  const FlowPairDevice& P = pairs[z];
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= P.work_w || y >= P.work_h) return;
  // The output pixel this flow pixel stands for, as cv::resize(INTER_LINEAR) of the full-size
  // maps would pick it (clamped to the rectangle).
  const float ox = P.rect_x + fminf(fmaxf((x + 0.5f) * P.rect_w / P.work_w - 0.5f, 0.f), float(P.rect_w - 1));
  const float oy = P.rect_y + fminf(fmaxf((y + 0.5f) * P.rect_h / P.work_h - 0.5f, 0.f), float(P.rect_h - 1));
  uint8_t g[2];
  bool valid[2];
#pragma unroll
  for (int k = 0; k < 2; ++k) {
    const int v = k == 0 ? P.a : P.b;
    const ViewGeometry& vg = vp.views[v];
    const DeviceImage& f = vp.frames[v];
    float u = 0.f, w = 0.f;
    const bool in_front = view_to_camera<kCurved>(vg, ox, oy, u, w);
    valid[k] = in_front && u >= 0.f && w >= 0.f && u <= vg.camera_w - 1 && w <= vg.camera_h - 1;
    g[k] = in_front ? luma(sample_bilinear(f.data, f.pitch, f.width, f.height, u, w)) : 0;
  }
  // Where one view has no pixels, show it the other's: zero flow there, and no false edges.
  if (!valid[0]) g[0] = g[1];
  if (!valid[1]) g[1] = g[0];
  const int i = y * P.work_w + x;
  P.gray[0][i] = g[0];
  P.gray[1][i] = g[1];
  P.valid[i] = uint8_t((valid[0] ? 1 : 0) | (valid[1] ? 2 : 0));
}

__global__ void confidence_kernel(const FlowPairDevice* pairs, FlowPairMask active, float inv_tau2) {
  const int pair = blockIdx.z >> 1, d = blockIdx.z & 1;
  if (!active.test(pair)) return;
  const FlowPairDevice& P = pairs[pair];
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= P.work_w || y >= P.work_h) return;
  const int i = y * P.work_w + x;
  const float2 f = reinterpret_cast<const float2*>(P.flow[d])[i];
  const float2 b = sample_flow(P.flow[1 - d], P.work_w, P.work_h, x + f.x, y + f.y);
  const float ex = f.x + b.x, ey = f.y + b.y;
  const float c = __expf(-(ex * ex + ey * ey) * inv_tau2);
  P.confidence[d][i] = c;
  // How much the flow improves the match over the homography (blurred, then gated).
  const float a = P.gray[d][i], o = P.gray[1 - d][i];
  const float warped = sample_gray(P.gray[1 - d], P.work_w, P.work_h, x + f.x, y + f.y);
  P.gate[d][i] = fabsf(a - o) - fabsf(a - warped);
}

__global__ void gate_kernel(const FlowPairDevice* pairs, FlowPairMask active, bool use_gate) {
  const int pair = blockIdx.z >> 1, d = blockIdx.z & 1;
  if (!active.test(pair)) return;
  const FlowPairDevice& P = pairs[pair];
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= P.work_w || y >= P.work_h) return;
  const int i = y * P.work_w + x;
  const float2 f = reinterpret_cast<const float2*>(P.flow[d])[i];
  const float c = P.confidence[d][i] * (use_gate ? stitch::flow_gate::gate(P.gate[d][i]) : 1.f);
  reinterpret_cast<float2*>(P.work[d])[i] = make_float2(f.x * c, f.y * c);
}

struct Taps {
  float w[25];
  int radius;
};

__device__ __forceinline__ int reflect101(int i, int n) {
  if (n == 1) return 0;
  while (i < 0 || i >= n) i = i < 0 ? -i : 2 * n - 2 - i;
  return i;
}

// One pass of the separable Gaussian over C-channel float images; kVertical picks the axis.
// The radius is a template parameter so the tap loop unrolls; only pixels within a radius of
// the border pay for the reflection.
template <int C, bool kVertical, int kRadius>
__global__ void blur_kernel(const FlowPairDevice* pairs, FlowPairMask active, int target, const Taps taps) {
  const int pair = blockIdx.z >> 1, k = blockIdx.z & 1;
  if (!active.test(pair)) return;
  const FlowPairDevice& P = pairs[pair];
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= P.work_w || y >= P.work_h) return;
  const float* src = target == 0   ? (kVertical ? P.work2[k] : P.work[k])
                     : target == 1 ? (kVertical ? P.change2[k] : P.change[k])
                                   : (kVertical ? P.gate2[k] : P.gate[k]);
  float* dst = target == 0   ? (kVertical ? P.work[k] : P.work2[k])
               : target == 1 ? (kVertical ? P.change[k] : P.change2[k])
                             : (kVertical ? P.gate[k] : P.gate2[k]);
  const int n = kVertical ? P.work_h : P.work_w, i = kVertical ? y : x;
  const int step = kVertical ? P.work_w * C : C;
  const float* base = src + (y * P.work_w + x) * C - i * step;  // start of this row / column
  const bool interior = i >= kRadius && i + kRadius < n;
  float acc[C];
#pragma unroll
  for (int c = 0; c < C; ++c) acc[c] = 0.f;
#pragma unroll
  for (int t = -kRadius; t <= kRadius; ++t) {
    const int j = interior ? i + t : reflect101(i + t, n);
    const float wt = taps.w[t + kRadius];
#pragma unroll
    for (int c = 0; c < C; ++c) acc[c] += wt * base[j * step + c];
  }
#pragma unroll
  for (int c = 0; c < C; ++c) dst[(y * P.work_w + x) * C + c] = acc[c];
}

__global__ void gray_change_kernel(const FlowPairDevice* pairs, FlowPairMask history) {
  const int pair = blockIdx.z >> 1, k = blockIdx.z & 1;
  if (!history.test(pair)) return;
  const FlowPairDevice& P = pairs[pair];
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= P.work_w || y >= P.work_h) return;
  const int i = y * P.work_w + x;
  P.change[k][i] = float(P.gray[k][i]) - float(P.prev_gray[k][i]);
}

__device__ __forceinline__ float warp_sum(float v) {
#pragma unroll
  for (int o = 16; o > 0; o >>= 1) v += __shfl_down_sync(0xffffffffu, v, o);
  return v;
}

__global__ void temporal_kernel(const FlowPairDevice* pairs, FlowPairMask active, FlowPairMask history,
                                float smoothing, float* stats) {
  const int pair = blockIdx.z >> 1, d = blockIdx.z & 1;
  if (!active.test(pair)) return;  // uniform per block: no lane of a warp is left behind
  const FlowPairDevice& P = pairs[pair];
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  const bool inside = x < P.work_w && y < P.work_h;
  float mag = 0.f, both = 0.f, confident = 0.f, err_h = 0.f, err_f = 0.f;
  if (inside) {
    const int i = y * P.work_w + x;
    float keep = 0.f;
    if (history.test(pair) && smoothing > 0.f) {
      // 1 where neither view changed since the last frame, falling to 0 over a few grey
      // levels of (locally averaged) change: static scene, static flow.
      const float c = fmaxf(fabsf(P.change[0][i]), fabsf(P.change[1][i]));
      const float s = fmaxf(0.f, c - 1.f) * 0.5f;
      keep = smoothing * __expf(-s * s);
    }
    const float2 now = reinterpret_cast<const float2*>(P.work[d])[i];
    float2 out = now;
    if (keep > 0.f) {
      const float2 prev = reinterpret_cast<const float2*>(P.prev_flow[d])[i];
      out = make_float2(keep * prev.x + (1.f - keep) * now.x, keep * prev.y + (1.f - keep) * now.y);
    }
    reinterpret_cast<float2*>(P.flow[d])[i] = out;
    if (d == 0 && P.valid[i] == 3) {
      both = 1.f;
      mag = sqrtf(out.x * out.x + out.y * out.y);
      confident = P.confidence[0][i] > 0.5f ? 1.f : 0.f;
      // The views' matching error without and with the flow (flow_gate_math.hpp).
      float av, agx, agy, bv, bgx, bgy, wv, wgx, wgy;
      gray_with_gradient(P.gray[0], P.work_w, P.work_h, float(x), float(y), av, agx, agy);
      gray_with_gradient(P.gray[1], P.work_w, P.work_h, float(x), float(y), bv, bgx, bgy);
      gray_with_gradient(P.gray[1], P.work_w, P.work_h, x + out.x, y + out.y, wv, wgx, wgy);
      err_h = stitch::flow_gate::match_error(av, bv, agx, agy, bgx, bgy);
      err_f = stitch::flow_gate::match_error(av, wv, agx, agy, wgx, wgy);
    }
  }
  if (d != 0) return;  // uniform per block
  // Warp sums, then one atomic per block: per-warp atomics on three addresses serialise.
  __shared__ float partial[kFlowStats][8];
  float values[kFlowStats] = {mag, both, confident, err_h, err_f};
  const int lane = threadIdx.x & 31, warp = (threadIdx.y * blockDim.x + threadIdx.x) >> 5;
#pragma unroll
  for (int q = 0; q < kFlowStats; ++q) {
    values[q] = warp_sum(values[q]);
    if (lane == 0) partial[q][warp] = values[q];
  }
  __syncthreads();
  if (threadIdx.x == 0 && threadIdx.y == 0) {
    float sum[kFlowStats] = {};
    for (int w = 0; w < (blockDim.x * blockDim.y) >> 5; ++w)
      for (int q = 0; q < kFlowStats; ++q) sum[q] += partial[q][w];
    if (sum[1] > 0.f)
      for (int q = 0; q < kFlowStats; ++q) atomicAdd(stats + kFlowStats * pair + q, sum[q]);
  }
}

struct Destinations {
  DeviceImage dst[kMaxViews];
};

struct Gains {
  float g[kMaxFlowPairs];
};

template <bool kCurved>
__global__ void flow_warp_views_kernel(const ViewsParam vp, const Destinations out, const FlowPairDevice* pairs,
                                       int n_pairs, FlowPairMask active, float inv_scale, const Gains gains) {
  const int v = blockIdx.z;
  const DeviceImage& frame = vp.frames[v];
  const DeviceImage& dst = out.dst[v];
  if (!frame.data || !dst.data) return;
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= dst.width || y >= dst.height) return;
  const ViewGeometry& me = vp.views[v];
  const int px = me.roi_x + x, py = me.roi_y + y;
  if (kCurved && outside_wrap_span(me, px)) {  // the whole width across the wrap: most columns unseen
    *reinterpret_cast<uchar4*>(dst.data + size_t(y) * dst.pitch + size_t(x) * 4) = make_uchar4(0, 0, 0, 0);
    return;
  }
  float dx = 0.f, dy = 0.f;
  float wsum = -1.f;  // computed once, when a pair covers the pixel
  for (int i = 0; i < n_pairs; ++i) {
    if (!active.test(i)) continue;
    const FlowPairDevice& P = pairs[i];
    if (P.a != v && P.b != v) continue;
    if (px < P.rect_x || py < P.rect_y || px >= P.rect_x + P.rect_w || py >= P.rect_y + P.rect_h) continue;
    if (wsum < 0.f) {
      wsum = 0.f;
      for (int k = 0; k < vp.n; ++k) {
        float u, w;
        wsum += view_weight<kCurved>(vp.views[k], px, py, u, w);
      }
    }
    const float gain = gains.g[i];
    if (gain <= 0.f) continue;  // this overlap falls back to the homography
    const int other = P.a == v ? P.b : P.a;
    float u, w;
    const float theta = view_weight<kCurved>(vp.views[other], px, py, u, w) / fmaxf(wsum, 1e-12f);
    if (theta <= 0.f) continue;
    // View a samples at p + theta_b flow_{b->a}; view b at p + theta_a flow_{a->b}.
    const float* field = P.a == v ? P.flow[1] : P.flow[0];
    const float fx = (px - P.rect_x + 0.5f) * P.work_w / P.rect_w - 0.5f;
    const float fy = (py - P.rect_y + 0.5f) * P.work_h / P.rect_h - 0.5f;
    const float2 f = sample_flow(field, P.work_w, P.work_h, fx, fy);
    dx += gain * theta * f.x * inv_scale;
    dy += gain * theta * f.y * inv_scale;
  }
  float u, w;
  float4 c = make_float4(0.f, 0.f, 0.f, 0.f);
  if (view_to_camera<kCurved>(me, px + dx, py + dy, u, w) && u > -1.f && w > -1.f && u < frame.width &&
      w < frame.height)
    c = sample_bilinear(frame.data, frame.pitch, frame.width, frame.height, u, w);
  *reinterpret_cast<uchar4*>(dst.data + size_t(y) * dst.pitch + size_t(x) * 4) =
      make_uchar4(to_u8(c.x), to_u8(c.y), to_u8(c.z), to_u8(c.w));
}

dim3 grid_for(int w, int h, int z) { return dim3((w + 31) / 32, (h + 7) / 8, z); }

}  // namespace

void launch_overlap_gray(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& active,
                         const ViewGeometry* views, const DeviceImage* frames, int n_views, cudaStream_t stream) {
  if (n_pairs <= 0) return;
  const ViewsParam vp = views_param(views, frames, n_views);
  if (any_curved(views, n_views))
    overlap_gray_kernel<true><<<grid_for(max_w, max_h, n_pairs), dim3(32, 8), 0, stream>>>(pairs, active, vp);
  else
    overlap_gray_kernel<false><<<grid_for(max_w, max_h, n_pairs), dim3(32, 8), 0, stream>>>(pairs, active, vp);
  check_launch("overlap gray kernel");
}

void launch_flow_confidence(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h,
                            const FlowPairMask& active, float tau, cudaStream_t stream) {
  if (n_pairs <= 0) return;
  confidence_kernel<<<grid_for(max_w, max_h, 2 * n_pairs), dim3(32, 8), 0, stream>>>(pairs, active,
                                                                                     1.f / (tau * tau));
  check_launch("flow confidence kernel");
}

void launch_flow_gate(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& active,
                      bool use_gate, cudaStream_t stream) {
  if (n_pairs <= 0) return;
  gate_kernel<<<grid_for(max_w, max_h, 2 * n_pairs), dim3(32, 8), 0, stream>>>(pairs, active, use_gate);
  check_launch("flow gate kernel");
}

void launch_pair_blur(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& active,
                      int target, const float* taps, int radius, cudaStream_t stream) {
  if (n_pairs <= 0) return;
  if (radius < 0 || radius > 12) throw std::invalid_argument("blur radius must be 0..12");
  Taps t{};
  t.radius = radius;
  for (int k = 0; k < 2 * radius + 1; ++k) t.w[k] = taps[k];
  const dim3 grid = grid_for(max_w, max_h, 2 * n_pairs), block(32, 8);
  // The two blurs the flow warper uses: sigma 1.5 (radius 6) on the flow, 2 (radius 8) on the change.
  if (target == 0 && radius == 6) {
    blur_kernel<2, false, 6><<<grid, block, 0, stream>>>(pairs, active, target, t);
    blur_kernel<2, true, 6><<<grid, block, 0, stream>>>(pairs, active, target, t);
  } else if ((target == 1 || target == 2) && radius == 8) {
    blur_kernel<1, false, 8><<<grid, block, 0, stream>>>(pairs, active, target, t);
    blur_kernel<1, true, 8><<<grid, block, 0, stream>>>(pairs, active, target, t);
  } else {
    throw std::invalid_argument("pair blur: radius 6 on the flow or 8 on the change and the gate");
  }
  check_launch("pair blur kernel");
}

void launch_gray_change(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& history,
                        cudaStream_t stream) {
  if (n_pairs <= 0) return;
  gray_change_kernel<<<grid_for(max_w, max_h, 2 * n_pairs), dim3(32, 8), 0, stream>>>(pairs, history);
  check_launch("gray change kernel");
}

void launch_flow_temporal(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& active,
                          const FlowPairMask& history, float smoothing, float* stats, cudaStream_t stream) {
  if (n_pairs <= 0) return;
  temporal_kernel<<<grid_for(max_w, max_h, 2 * n_pairs), dim3(32, 8), 0, stream>>>(pairs, active, history,
                                                                                   smoothing, stats);
  check_launch("flow temporal kernel");
}

void launch_flow_warp_views(const ViewGeometry* views, const DeviceImage* frames, const DeviceImage* dst, int n_views,
                            const FlowPairDevice* pairs, int n_pairs, const FlowPairMask& active, float inv_scale,
                            const float* gains, cudaStream_t stream) {
  Destinations out{};
  int max_w = 0, max_h = 0;
  for (int v = 0; v < n_views && v < kMaxViews; ++v) {
    out.dst[v] = dst[v];
    if (frames[v].data && dst[v].data) {
      max_w = max_w > dst[v].width ? max_w : dst[v].width;
      max_h = max_h > dst[v].height ? max_h : dst[v].height;
    }
  }
  if (max_w == 0 || max_h == 0) return;
  if (n_pairs > kMaxFlowPairs) throw std::invalid_argument("too many overlapping pairs");
  const ViewsParam vp = views_param(views, frames, n_views);
  Gains g{};
  for (int i = 0; i < n_pairs; ++i) g.g[i] = gains ? gains[i] : 1.f;
  const dim3 grid = grid_for(max_w, max_h, n_views), block(32, 8);
  if (any_curved(views, n_views))
    flow_warp_views_kernel<true><<<grid, block, 0, stream>>>(vp, out, pairs, n_pairs, active, inv_scale, g);
  else
    flow_warp_views_kernel<false><<<grid, block, 0, stream>>>(vp, out, pairs, n_pairs, active, inv_scale, g);
  check_launch("flow warp kernel");
}

}  // namespace stitch_cuda
