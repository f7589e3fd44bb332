#include <stdexcept>
#include <string>

#include "../launch_check.hpp"
#include "color_kernels.hpp"

namespace stitch_cuda {

namespace {

// ---- Apply ----

__global__ void apply_batch_kernel(const __grid_constant__ ColorApplyBatch batch, const uint8_t* lut) {
  const ColorApplyView& view = batch.views[blockIdx.z];
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= view.width || y >= view.height) return;
  uchar4* p = reinterpret_cast<uchar4*>(view.data + size_t(y) * view.pitch) + x;
  uchar4 c = *p;
  if (view.has_matrix) {
    const uchar4 in = c;
    const float* M = view.M;
    const float r = c.x, g = c.y, b = c.z;
    c.x = uint8_t(fminf(fmaxf(r * M[0] + g * M[3] + b * M[6] + 0.5f, 0.f), 255.f));
    c.y = uint8_t(fminf(fmaxf(r * M[1] + g * M[4] + b * M[7] + 0.5f, 0.f), 255.f));
    c.z = uint8_t(fminf(fmaxf(r * M[2] + g * M[5] + b * M[8] + 0.5f, 0.f), 255.f));
    // stitch::highlight_blend: clipped highlights keep their input.
    const int k = batch.highlight_knee, m = max(max(int(in.x), int(in.y)), int(in.z));
    if (k < 255 && m > k) {
      const float w = __fdiv_rn(float(m - k), float(255 - k));
      c.x = uint8_t(__fadd_rn(__fadd_rn(float(c.x), __fmul_rn(w, float(int(in.x) - int(c.x)))), 0.5f));
      c.y = uint8_t(__fadd_rn(__fadd_rn(float(c.y), __fmul_rn(w, float(int(in.y) - int(c.y)))), 0.5f));
      c.z = uint8_t(__fadd_rn(__fadd_rn(float(c.z), __fmul_rn(w, float(int(in.z) - int(c.z)))), 0.5f));
    }
  }
  if (lut) {
    c.x = lut[c.x];
    c.y = lut[256 + c.y];
    c.z = lut[512 + c.z];
  }
  *p = c;
}

__global__ void gather_kernel(const uint8_t* data, size_t pitch, const int32_t* xy, int count, uint8_t* out) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= count) return;
  const uint8_t* p = data + size_t(xy[2 * k + 1]) * pitch + size_t(xy[2 * k]) * 4;
  out[3 * k] = p[0];
  out[3 * k + 1] = p[1];
  out[3 * k + 2] = p[2];
}

// ---- Reductions ----
//
// Every sum is of 8-bit integers or their products, accumulated in 64-bit integers: exact in
// any order, so the atomics give the CPU's values bit for bit. Histograms are counted in
// shared memory per block and added to global memory once per bin.

constexpr int kThreads = 256;  // every reduction kernel runs blocks of exactly this size
constexpr int kWarps = kThreads / 32;
constexpr int kSamplesPerBlock = 4 * kThreads;

struct Rgb {
  unsigned int c[3];
};

// The pixel at (x, y) of a view; false outside it.
__device__ __forceinline__ bool load_rgb(const ColorFrameView& view, int x, int y, Rgb& out) {
  if (x < 0 || y < 0 || x >= view.width || y >= view.height) return false;
  const uint8_t* p = view.data + size_t(y) * view.pitch + size_t(x) * 4;
  out.c[0] = p[0];
  out.c[1] = p[1];
  out.c[2] = p[2];
  return true;
}

// stitch::ColorOpsCpu's test: not every channel dark, no channel saturated.
__device__ __forceinline__ bool usable(const Rgb& p, int dark, int bright) {
  const bool is_dark = p.c[0] <= unsigned(dark) && p.c[1] <= unsigned(dark) && p.c[2] <= unsigned(dark);
  const bool is_bright = p.c[0] >= unsigned(bright) || p.c[1] >= unsigned(bright) || p.c[2] >= unsigned(bright);
  return !is_dark && !is_bright;
}

// Both pixels of sample k of a pair, when the mask kernel let it into the fit.
__device__ __forceinline__ bool load_pair_sample(const ColorReduceArgs& args, const ColorSamplePair& pair, int k,
                                                 Rgb& a, Rgb& b) {
  if (!args.use[pair.first + k]) return false;
  const int4 s = args.pair_samples[pair.first + k];
  return load_rgb(args.views[pair.a], s.x, s.y, a) && load_rgb(args.views[pair.b], s.z, s.w, b);
}

// stitch::mask_luma / mask_moved / luma_gradient / mask_aligned, the same integers.
__device__ __forceinline__ int luma_at(const ColorFrameView& v, int x, int y) {
  const uint8_t* p = v.data + size_t(y) * v.pitch + size_t(x) * 4;
  return (77 * int(p[0]) + 150 * int(p[1]) + 29 * int(p[2]) + 128) >> 8;
}
__device__ __forceinline__ int luma_gradient(const ColorFrameView& v, int x, int y) {
  const int x0 = max(0, x - 1), x1 = min(v.width - 1, x + 1), y0 = max(0, y - 1), y1 = min(v.height - 1, y + 1);
  return abs(luma_at(v, x1, y) - luma_at(v, x0, y)) + abs(luma_at(v, x, y1) - luma_at(v, x, y0));
}
__device__ __forceinline__ bool moved_since(const Rgb& p, uchar4 q, int threshold) {
  return abs(int(p.c[0]) - int(q.x)) > threshold || abs(int(p.c[1]) - int(q.y)) > threshold ||
         abs(int(p.c[2]) - int(q.z)) > threshold;
}

// Sums v[i] over the block into totals[i] (shared), visible to every thread on return. Every
// thread of the block must call it.
template <int N>
__device__ void block_sum(unsigned long long (&v)[N], unsigned long long* totals) {
  __shared__ unsigned long long per_warp[kWarps][N];
  const int lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
#pragma unroll
  for (int i = 0; i < N; ++i) {
    unsigned long long x = v[i];
#pragma unroll
    for (int offset = 16; offset > 0; offset >>= 1) x += __shfl_down_sync(0xffffffffu, x, offset);
    if (lane == 0) per_warp[warp][i] = x;
  }
  __syncthreads();
  for (int i = threadIdx.x; i < N; i += blockDim.x) {
    unsigned long long t = 0;
    for (int w = 0; w < kWarps; ++w) t += per_warp[w][i];
    totals[i] = t;
  }
  __syncthreads();
}

__device__ __forceinline__ void add_histogram(const unsigned int* block_hist, unsigned int* global_hist, int bins) {
  for (int i = threadIdx.x; i < bins; i += blockDim.x)
    if (block_hist[i]) atomicAdd(global_hist + i, block_hist[i]);
}

// Grid (sample blocks, pairs), pass 1 of the mask: in-view samples, which moved since the last
// frame (against the stored pixels, then replaced), raw RGB sums.
__global__ void motion_kernel(const __grid_constant__ ColorReduceArgs args) {
  const ColorSamplePair pair = args.pairs[blockIdx.y];
  const int begin = blockIdx.x * kSamplesPerBlock, end = min(begin + kSamplesPerBlock, pair.count);
  if (begin >= end || !args.views[pair.a].data || !args.views[pair.b].data) return;  // whole block
  // [0] in view, [1] moved now, [2, 5) sum a, [5, 8) sum b.
  unsigned long long sums[8] = {};
  for (int k = begin + threadIdx.x; k < end; k += blockDim.x) {
    const int idx = pair.first + k;
    const int4 s = args.pair_samples[idx];
    Rgb a, b;
    args.moved[idx] = 0;
    if (!load_rgb(args.views[pair.a], s.x, s.y, a) || !load_rgb(args.views[pair.b], s.z, s.w, b)) continue;
    sums[0] += 1;
    if (!args.fresh && (moved_since(a, args.prev_a[idx], args.motion_threshold) ||
                        moved_since(b, args.prev_b[idx], args.motion_threshold))) {
      args.moved[idx] = 1;
      sums[1] += 1;
    }
    args.prev_a[idx] = make_uchar4(uint8_t(a.c[0]), uint8_t(a.c[1]), uint8_t(a.c[2]), 0);
    args.prev_b[idx] = make_uchar4(uint8_t(b.c[0]), uint8_t(b.c[1]), uint8_t(b.c[2]), 0);
#pragma unroll
    for (int c = 0; c < 3; ++c) {
      sums[2 + c] += a.c[c];
      sums[5 + c] += b.c[c];
    }
  }
  __shared__ unsigned long long totals[8];
  block_sum<8>(sums, totals);
  ColorPairResult& out = args.pair_results[blockIdx.y];
  if (threadIdx.x == 0) {
    if (totals[0]) atomicAdd(&out.inview, totals[0]);
    if (totals[1]) atomicAdd(&out.moved_now, totals[1]);
  }
  if (threadIdx.x < 3) {
    atomicAdd(&out.sum_a[threadIdx.x], totals[2 + threadIdx.x]);
    atomicAdd(&out.sum_b[threadIdx.x], totals[5 + threadIdx.x]);
  }
}

// Grid (sample blocks, pairs), pass 2: ages (restarted when most of the overlap moved at
// once), the alignment test, and which samples go into the fit.
__global__ void mask_kernel(const __grid_constant__ ColorReduceArgs args) {
  const ColorSamplePair pair = args.pairs[blockIdx.y];
  const int begin = blockIdx.x * kSamplesPerBlock, end = min(begin + kSamplesPerBlock, pair.count);
  if (begin >= end || !args.views[pair.a].data || !args.views[pair.b].data) {
    for (int k = begin + threadIdx.x; k < end; k += blockDim.x) args.use[pair.first + k] = 0;
    return;  // whole block
  }
  ColorPairResult& out = args.pair_results[blockIdx.y];
  const unsigned long long inview = out.inview, moved_now = out.moved_now;
  const bool restart = args.fresh || moved_now * 2 > inview;
  if (blockIdx.x == 0 && threadIdx.x == 0) out.global_change = (!args.fresh && restart && inview > 0) ? 1 : 0;
  unsigned long long sums[2] = {};  // not static, misaligned
  for (int k = begin + threadIdx.x; k < end; k += blockDim.x) {
    const int idx = pair.first + k;
    args.use[idx] = 0;
    const int4 s = args.pair_samples[idx];
    const ColorFrameView &va = args.views[pair.a], &vb = args.views[pair.b];
    Rgb a, b;
    if (!load_rgb(va, s.x, s.y, a) || !load_rgb(vb, s.z, s.w, b)) continue;
    const int age = restart ? args.static_frames : args.moved[idx] ? 0 : min(255, int(args.age[idx]) + 1);
    args.age[idx] = uint8_t(age);
    const bool still = age >= args.static_frames;
    const int ga = luma_gradient(va, s.x, s.y), gb = luma_gradient(vb, s.z, s.w);
    const bool aligned = abs(ga - gb) <= args.align_tolerance + max(ga, gb) / 3;
    sums[0] += !still;
    sums[1] += !aligned;
    if (!usable(a, args.dark_level, args.bright_level) || !usable(b, args.dark_level, args.bright_level)) continue;
    if (args.static_mask && (!still || !aligned)) continue;
    args.use[idx] = 1;
  }
  __shared__ unsigned long long totals[2];
  block_sum<2>(sums, totals);
  if (threadIdx.x == 0) {
    if (totals[0]) atomicAdd(&out.moving, totals[0]);
    if (totals[1]) atomicAdd(&out.misaligned, totals[1]);
  }
}

// Grid (sample blocks, pairs): usable count, both sides' histograms, sum a a^T, b b^T, a b^T.
__global__ void pair_moments_kernel(const __grid_constant__ ColorReduceArgs args) {
  const ColorSamplePair pair = args.pairs[blockIdx.y];
  const int begin = blockIdx.x * kSamplesPerBlock, end = min(begin + kSamplesPerBlock, pair.count);
  if (begin >= end || !args.views[pair.a].data || !args.views[pair.b].data) return;  // whole block
  __shared__ unsigned int hist_a[3 * 256], hist_b[3 * 256];
  for (int i = threadIdx.x; i < 3 * 256; i += blockDim.x) hist_a[i] = hist_b[i] = 0;
  __syncthreads();
  // [0]: count, [1, 10): a a^T, [10, 19): b b^T, [19, 28): a b^T.
  unsigned long long sums[28] = {};
  for (int k = begin + threadIdx.x; k < end; k += blockDim.x) {
    Rgb a, b;
    if (!load_pair_sample(args, pair, k, a, b)) continue;
    sums[0] += 1;
#pragma unroll
    for (int r = 0; r < 3; ++r)
#pragma unroll
      for (int c = 0; c < 3; ++c) {
        sums[1 + 3 * r + c] += a.c[r] * a.c[c];
        sums[10 + 3 * r + c] += b.c[r] * b.c[c];
        sums[19 + 3 * r + c] += a.c[r] * b.c[c];
      }
#pragma unroll
    for (int ch = 0; ch < 3; ++ch) {
      atomicAdd(&hist_a[256 * ch + a.c[ch]], 1u);
      atomicAdd(&hist_b[256 * ch + b.c[ch]], 1u);
    }
  }
  __shared__ unsigned long long totals[28];
  block_sum<28>(sums, totals);  // also orders the shared histograms before they are read
  ColorPairResult& out = args.pair_results[blockIdx.y];
  add_histogram(hist_a, out.hist_a, 3 * 256);
  add_histogram(hist_b, out.hist_b, 3 * 256);
  if (threadIdx.x == 0 && totals[0]) atomicAdd(&out.count, totals[0]);
  if (threadIdx.x < 9) {
    atomicAdd(&out.aa[threadIdx.x], totals[1 + threadIdx.x]);
    atomicAdd(&out.bb[threadIdx.x], totals[10 + threadIdx.x]);
    atomicAdd(&out.ab[threadIdx.x], totals[19 + threadIdx.x]);
  }
}

// Inclusive prefix sum of 256 values in shared memory, one per thread (Hillis-Steele).
__device__ void inclusive_scan_256(unsigned long long* v) {
  const int i = threadIdx.x;
  for (int offset = 1; offset < 256; offset <<= 1) {
    const unsigned long long add = i >= offset ? v[i - offset] : 0;
    __syncthreads();
    v[i] += add;
    __syncthreads();
  }
}

// Grid (pairs, 3 channels), 256 threads (one per level): stitch::histogram_specification of
// the matched side's histogram onto the other side's. Thread v computes lut[v] directly: the
// CPU walks u upward as v grows, which ends at the first u < 255 whose reference CDF reaches
// v's target (255 if none); the CDF is monotonic, so a binary search finds the same u. The
// doubles are formed exactly as on the CPU (sums of integers, then one division), without
// fused multiply-adds, so the comparisons and the LUT are identical.
__global__ void match_lut_kernel(const __grid_constant__ ColorReduceArgs args) {
  const int pair = blockIdx.x, ch = blockIdx.y, v = threadIdx.x;
  const int match = args.pair_match[pair];
  if (match == kColorMatchNone) return;  // whole block
  const ColorPairResult& r = args.pair_results[pair];
  const unsigned int* src = (match == kColorMatchAOntoB ? r.hist_a : r.hist_b) + 256 * ch;
  const unsigned int* ref = (match == kColorMatchAOntoB ? r.hist_b : r.hist_a) + 256 * ch;
  __shared__ unsigned long long src_cum[256], ref_cum[256];
  __shared__ double cdf_ref[256];
  const unsigned int src_v = src[v];
  src_cum[v] = src_v;
  ref_cum[v] = ref[v];
  __syncthreads();
  inclusive_scan_256(src_cum);
  inclusive_scan_256(ref_cum);
  const unsigned long long ns = src_cum[255], nr = ref_cum[255];
  uint8_t* lut = args.match_luts + 3 * 256 * pair + 256 * ch;
  if (ns == 0 || nr == 0) {  // whole block
    lut[v] = uint8_t(v);
    return;
  }
  cdf_ref[v] = __ddiv_rn(double(ref_cum[v]), double(nr));
  __syncthreads();
  const double below = double(src_cum[v] - src_v);  // the CPU's running sum before level v
  const double target = __ddiv_rn(__dadd_rn(below, __dmul_rn(0.5, double(src_v))), double(ns));
  int lo = 0, hi = 255;
  while (lo < hi) {
    const int mid = (lo + hi) >> 1;
    if (cdf_ref[mid] >= target) hi = mid;
    else lo = mid + 1;
  }
  lut[v] = uint8_t(lo);
}

// Grid (sample blocks, pairs): sum s lut(s)^T over the usable samples, s the matched side.
__global__ void matched_moments_kernel(const __grid_constant__ ColorReduceArgs args) {
  const int match = args.pair_match[blockIdx.y];
  const ColorSamplePair pair = args.pairs[blockIdx.y];
  const int begin = blockIdx.x * kSamplesPerBlock, end = min(begin + kSamplesPerBlock, pair.count);
  if (match == kColorMatchNone || begin >= end || !args.views[pair.a].data || !args.views[pair.b].data)
    return;  // whole block
  __shared__ uint8_t lut[3 * 256];
  for (int i = threadIdx.x; i < 3 * 256; i += blockDim.x) lut[i] = args.match_luts[3 * 256 * blockIdx.y + i];
  __syncthreads();
  unsigned long long sums[9] = {};
  for (int k = begin + threadIdx.x; k < end; k += blockDim.x) {
    Rgb a, b;
    if (!load_pair_sample(args, pair, k, a, b)) continue;
    const Rgb s = match == kColorMatchAOntoB ? a : b;
#pragma unroll
    for (int r = 0; r < 3; ++r)
#pragma unroll
      for (int c = 0; c < 3; ++c) sums[3 * r + c] += s.c[r] * unsigned(lut[256 * c + s.c[c]]);
  }
  __shared__ unsigned long long totals[9];
  block_sum<9>(sums, totals);
  if (threadIdx.x < 9) atomicAdd(&args.pair_results[blockIdx.y].matched[threadIdx.x], totals[threadIdx.x]);
}

// stitch::corrected_level: clamp(round(sum_k p_k M(k, c))) in the CPU's order, no FMA.
__device__ __forceinline__ int corrected_level(const Rgb& p, const double* M, int c) {
  const double v = __dadd_rn(__dadd_rn(__dmul_rn(double(p.c[0]), M[c]), __dmul_rn(double(p.c[1]), M[3 + c])),
                             __dmul_rn(double(p.c[2]), M[6 + c]));
  const long long level = llround(v);
  return int(level < 0 ? 0 : level > 255 ? 255 : level);
}

// Grid (sample blocks, views): per-channel histograms of the balance grid under each view's matrix.
__global__ void balance_histogram_kernel(const __grid_constant__ ColorReduceArgs args) {
  const ColorFrameView& view = args.views[blockIdx.y];
  const ColorSampleGrid grid = args.grids[blockIdx.y];
  const int begin = blockIdx.x * kSamplesPerBlock, end = min(begin + kSamplesPerBlock, grid.count);
  if (begin >= end || !view.data) return;  // whole block
  __shared__ unsigned int hist[3 * 256];
  __shared__ double M[9];
  for (int i = threadIdx.x; i < 3 * 256; i += blockDim.x) hist[i] = 0;
  if (threadIdx.x < 9) M[threadIdx.x] = view.balance_matrix[threadIdx.x];
  __syncthreads();
  for (int k = begin + threadIdx.x; k < end; k += blockDim.x) {
    const int2 s = args.grid_samples[grid.first + k];
    Rgb p;
    if (!load_rgb(view, s.x, s.y, p)) continue;
#pragma unroll
    for (int ch = 0; ch < 3; ++ch) atomicAdd(&hist[256 * ch + corrected_level(p, M, ch)], 1u);
  }
  __syncthreads();
  add_histogram(hist, args.balance_results + 3 * 256 * blockIdx.y, 3 * 256);
}

int blocks_for(int samples) { return (samples + kSamplesPerBlock - 1) / kSamplesPerBlock; }

}  // namespace

void launch_color_apply_batch(const ColorApplyBatch& batch, const uint8_t* lut, cudaStream_t stream) {
  int width = 0, height = 0;
  for (int i = 0; i < batch.count; ++i) {
    width = batch.views[i].width > width ? batch.views[i].width : width;
    height = batch.views[i].height > height ? batch.views[i].height : height;
  }
  if (batch.count <= 0 || batch.count > kColorApplyMaxViews || width <= 0 || height <= 0) return;
  const dim3 block(32, 8), grid((width + 31) / 32, (height + 7) / 8, batch.count);
  apply_batch_kernel<<<grid, block, 0, stream>>>(batch, lut);
  check_launch("color apply kernel");
}

void launch_color_apply(uint8_t* data, size_t pitch, int width, int height, const float* M, const uint8_t* lut,
                        cudaStream_t stream) {
  if (width <= 0 || height <= 0 || (!M && !lut)) return;
  ColorApplyBatch batch{};
  batch.count = 1;
  batch.highlight_knee = 255;
  ColorApplyView& v = batch.views[0];
  v.data = data;
  v.pitch = pitch;
  v.width = width;
  v.height = height;
  v.has_matrix = M != nullptr;
  for (int k = 0; k < 9; ++k) v.M[k] = M ? M[k] : (k % 4 == 0 ? 1.f : 0.f);
  launch_color_apply_batch(batch, lut, stream);
}

void launch_gather(const uint8_t* data, size_t pitch, const int32_t* xy, int count, uint8_t* out,
                   cudaStream_t stream) {
  if (count <= 0) return;
  gather_kernel<<<(count + 255) / 256, 256, 0, stream>>>(data, pitch, xy, count, out);
  check_launch("gather kernel");
}

void launch_color_reduce(const ColorReduceArgs& args, cudaStream_t stream) {
  const bool pairs = args.want_pairs && args.pair_count > 0 && args.max_pair_samples > 0;
  if (pairs) {
    const dim3 grid(blocks_for(args.max_pair_samples), args.pair_count);
    motion_kernel<<<grid, kThreads, 0, stream>>>(args);
    check_launch("color motion kernel");
    mask_kernel<<<grid, kThreads, 0, stream>>>(args);
    check_launch("color mask kernel");
    pair_moments_kernel<<<grid, kThreads, 0, stream>>>(args);
    check_launch("color pair moments kernel");
    if (args.want_match) {
      match_lut_kernel<<<dim3(args.pair_count, 3), 256, 0, stream>>>(args);
      check_launch("color histogram specification kernel");
      matched_moments_kernel<<<grid, kThreads, 0, stream>>>(args);
      check_launch("color matched moments kernel");
    }
  }
  if (args.want_balance && args.view_count > 0 && args.max_grid_samples > 0) {
    balance_histogram_kernel<<<dim3(blocks_for(args.max_grid_samples), args.view_count), kThreads, 0, stream>>>(args);
    check_launch("color balance histogram kernel");
  }
}

}  // namespace stitch_cuda
