#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <string>

#include "../launch_check.hpp"
#include "color_kernels.hpp"

namespace stitch_cuda {

namespace {

// ---- Apply ----

// One pixel through a view's 3x3 (with the highlight knee) and the LUT.
__device__ __forceinline__ uchar4 apply_pixel(uchar4 c, const ColorApplyView& view, int knee, const uint8_t* lut) {
  if (view.has_matrix) {
    const uchar4 in = c;
    const float* M = view.M;
    const float r = c.x, g = c.y, b = c.z;
    c.x = uint8_t(fminf(fmaxf(r * M[0] + g * M[3] + b * M[6] + 0.5f, 0.f), 255.f));
    c.y = uint8_t(fminf(fmaxf(r * M[1] + g * M[4] + b * M[7] + 0.5f, 0.f), 255.f));
    c.z = uint8_t(fminf(fmaxf(r * M[2] + g * M[5] + b * M[8] + 0.5f, 0.f), 255.f));
    // stitch::highlight_blend: clipped highlights keep their input.
    const int k = knee, m = max(max(int(in.x), int(in.y)), int(in.z));
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
  return c;
}

// kPixels consecutive pixels per thread; 4: one 16-byte load and store (rows 16-byte aligned).
template <int kPixels>
__global__ void apply_batch_kernel(const __grid_constant__ ColorApplyBatch batch, const uint8_t* lut) {
  const ColorApplyView& view = batch.views[blockIdx.z];
  const int x = (blockIdx.x * blockDim.x + threadIdx.x) * kPixels, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= view.width || y >= view.height) return;
  uchar4* p = reinterpret_cast<uchar4*>(view.data + size_t(y) * view.pitch) + x;
  if (kPixels == 4 && x + 4 <= view.width) {
    uint4 q = *reinterpret_cast<uint4*>(p);
    uchar4* c = reinterpret_cast<uchar4*>(&q);
#pragma unroll
    for (int k = 0; k < 4; ++k) c[k] = apply_pixel(c[k], view, batch.highlight_knee, lut);
    *reinterpret_cast<uint4*>(p) = q;
    return;
  }
  for (int k = 0; k < kPixels && x + k < view.width; ++k) p[k] = apply_pixel(p[k], view, batch.highlight_knee, lut);
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
// thread of the block must call it. A thread's sums are of at most kMaxSamplesPerThread
// products of two 8-bit values, so a warp's sum fits 32 bits (32 x 16 x 255^2 < 2^32): the
// shuffles move 32-bit words, the block's total is formed in 64 bits.
constexpr int kMaxSamplesPerThread = 16;
template <int N>
__device__ void block_sum(unsigned int (&v)[N], unsigned long long* totals) {
  __shared__ unsigned int per_warp[kWarps][N];
  const int lane = threadIdx.x & 31, warp = threadIdx.x >> 5;
#pragma unroll
  for (int i = 0; i < N; ++i) {
    unsigned int x = v[i];
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

// The samples one block of a pair or view covers, [begin, end): empty when past its count.
struct SampleRange {
  int begin, end;
};
__device__ __forceinline__ SampleRange block_range(int per_block, int count) {
  const int begin = blockIdx.x * per_block;
  return {begin, min(begin + per_block, count)};
}

// Pass 1 of the mask, one block of pair p: in-view samples, which moved since the last frame
// (against the stored pixels, then replaced), raw RGB sums.
__device__ void motion_block(const ColorReduceArgs& args, int p) {
  const ColorSamplePair pair = args.pairs[p];
  const SampleRange r = block_range(args.motion_per_block, pair.count);
  if (r.begin >= r.end || !args.views[pair.a].data || !args.views[pair.b].data) return;  // whole block
  // [0] in view, [1] moved now, [2, 5) sum a, [5, 8) sum b.
  unsigned int sums[8] = {};
  for (int k = r.begin + threadIdx.x; k < r.end; k += blockDim.x) {
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
  ColorPairResult& out = args.pair_results[p];
  if (threadIdx.x == 0) {
    if (totals[0]) atomicAdd(&out.inview, totals[0]);
    if (totals[1]) atomicAdd(&out.moved_now, totals[1]);
  }
  if (threadIdx.x < 3) {
    atomicAdd(&out.sum_a[threadIdx.x], totals[2 + threadIdx.x]);
    atomicAdd(&out.sum_b[threadIdx.x], totals[5 + threadIdx.x]);
  }
}

// stitch::corrected_level: clamp(round(sum_k p_k M(k, c))) in the CPU's order, no FMA.
__device__ __forceinline__ int corrected_level(const Rgb& p, const double* M, int c) {
  const double v = __dadd_rn(__dadd_rn(__dmul_rn(double(p.c[0]), M[c]), __dmul_rn(double(p.c[1]), M[3 + c])),
                             __dmul_rn(double(p.c[2]), M[6 + c]));
  const long long level = llround(v);
  return int(level < 0 ? 0 : level > 255 ? 255 : level);
}

// One block of view i's balance grid: per-channel histograms under the view's matrix.
__device__ void balance_block(const ColorReduceArgs& args, int i) {
  const ColorFrameView& view = args.views[i];
  const ColorSampleGrid grid = args.grids[i];
  const SampleRange r = block_range(args.balance_per_block, grid.count);
  if (r.begin >= r.end || !view.data) return;  // whole block
  __shared__ unsigned int hist[3 * 256];
  __shared__ double M[9];
  for (int k = threadIdx.x; k < 3 * 256; k += blockDim.x) hist[k] = 0;
  if (threadIdx.x < 9) M[threadIdx.x] = view.balance_matrix[threadIdx.x];
  __syncthreads();
  for (int k = r.begin + threadIdx.x; k < r.end; k += blockDim.x) {
    const int2 s = args.grid_samples[grid.first + k];
    Rgb p;
    if (!load_rgb(view, s.x, s.y, p)) continue;
#pragma unroll
    for (int ch = 0; ch < 3; ++ch) atomicAdd(&hist[256 * ch + corrected_level(p, M, ch)], 1u);
  }
  __syncthreads();
  add_histogram(hist, args.balance_results + 3 * 256 * i, 3 * 256);
}

// Launch 1, grid (sample blocks, motion rows + balance rows): the mask's first pass for every
// pair and the balance histograms, which depend on nothing else, side by side.
__global__ void motion_balance_kernel(const __grid_constant__ ColorReduceArgs args) {
  const int row = blockIdx.y;
  if (row < args.motion_rows) motion_block(args, row);
  else balance_block(args, row - args.motion_rows);
}

// Inclusive prefix sums of three rows of 256 values in shared memory, thread i doing column i
// of every row (Hillis-Steele): the three channels' scans share their barriers.
__device__ void inclusive_scan_3x256(unsigned long long (*v)[256]) {
  const int i = threadIdx.x;
  for (int offset = 1; offset < 256; offset <<= 1) {
    unsigned long long add[3];
#pragma unroll
    for (int c = 0; c < 3; ++c) add[c] = i >= offset ? v[c][i - offset] : 0;
    __syncthreads();
#pragma unroll
    for (int c = 0; c < 3; ++c) v[c][i] += add[c];
    __syncthreads();
  }
}

// Pair p's histogram-specification LUTs (stitch::histogram_specification of the matched
// side's histogram onto the other side's), by one block of 256 threads, one per level and
// all three channels at once, after every block of the pair added its histograms. Thread v
// computes lut[v] directly: the CPU walks u upward as v grows, which ends at the first u < 255
// whose reference CDF reaches v's target (255 if none); the CDF is monotonic, so a binary
// search finds the same u. The doubles are formed exactly as on the CPU (sums of integers,
// then one division), without fused multiply-adds, so the comparisons and the LUT are identical.
__device__ void build_match_luts(const ColorReduceArgs& args, int p, int match) {
  const ColorPairResult& r = args.pair_results[p];
  const int v = threadIdx.x;
  const unsigned int* src = match == kColorMatchAOntoB ? r.hist_a : r.hist_b;
  const unsigned int* ref = match == kColorMatchAOntoB ? r.hist_b : r.hist_a;
  __shared__ unsigned long long src_cum[3][256], ref_cum[3][256];
  __shared__ double cdf_ref[3][256];
  unsigned int src_v[3];
#pragma unroll
  for (int c = 0; c < 3; ++c) {
    src_v[c] = __ldcg(src + 256 * c + v);  // other blocks' atomics: read from L2
    src_cum[c][v] = src_v[c];
    ref_cum[c][v] = __ldcg(ref + 256 * c + v);
  }
  __syncthreads();
  inclusive_scan_3x256(src_cum);
  inclusive_scan_3x256(ref_cum);
#pragma unroll
  for (int c = 0; c < 3; ++c) {
    const unsigned long long nr = ref_cum[c][255];
    cdf_ref[c][v] = nr ? __ddiv_rn(double(ref_cum[c][v]), double(nr)) : 0.0;
  }
  __syncthreads();
  for (int c = 0; c < 3; ++c) {
    const unsigned long long ns = src_cum[c][255], nr = ref_cum[c][255];
    uint8_t* lut = args.match_luts + 3 * 256 * p + 256 * c;
    if (ns == 0 || nr == 0) {
      lut[v] = uint8_t(v);
      continue;
    }
    const double below = double(src_cum[c][v] - src_v[c]);  // the CPU's running sum before level v
    const double target = __ddiv_rn(__dadd_rn(below, __dmul_rn(0.5, double(src_v[c]))), double(ns));
    int lo = 0, hi = 255;
    while (lo < hi) {
      const int mid = (lo + hi) >> 1;
      if (cdf_ref[c][mid] >= target) hi = mid;
      else lo = mid + 1;
    }
    lut[v] = uint8_t(lo);
  }
}

// Launch 2, grid (sample blocks, pairs): pass 2 of the mask (ages, restarted when most of the
// overlap moved at once; the alignment test; which samples go into the fit) and, for the
// samples it lets in, the fit's sums: usable count, both sides' histograms, sum a a^T, b b^T,
// a b^T. The block of a pair that finishes last builds the pair's matching LUTs.
__global__ void mask_moments_kernel(const __grid_constant__ ColorReduceArgs args) {
  const int p = blockIdx.y;
  const ColorSamplePair pair = args.pairs[p];
  const SampleRange r = block_range(args.mask_per_block, pair.count);
  if (r.begin >= r.end) return;  // whole block
  const ColorFrameView &va = args.views[pair.a], &vb = args.views[pair.b];
  if (!va.data || !vb.data) {
    for (int k = r.begin + threadIdx.x; k < r.end; k += blockDim.x) args.use[pair.first + k] = 0;
    return;  // whole block; the pair has no sums to match
  }
  ColorPairResult& out = args.pair_results[p];
  const unsigned long long inview = out.inview, moved_now = out.moved_now;
  const bool restart = args.fresh || moved_now * 2 > inview;
  if (blockIdx.x == 0 && threadIdx.x == 0) out.global_change = (!args.fresh && restart && inview > 0) ? 1 : 0;
  __shared__ unsigned int hist_a[3 * 256], hist_b[3 * 256];
  for (int i = threadIdx.x; i < 3 * 256; i += blockDim.x) hist_a[i] = hist_b[i] = 0;
  __syncthreads();
  // [0]: not yet static, [1]: misaligned, [2]: count, [3, 12): a a^T, [12, 21): b b^T, [21, 30): a b^T.
  unsigned int sums[30] = {};
  for (int k = r.begin + threadIdx.x; k < r.end; k += blockDim.x) {
    const int idx = pair.first + k;
    args.use[idx] = 0;
    const int4 s = args.pair_samples[idx];
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
    sums[2] += 1;
#pragma unroll
    for (int i = 0; i < 3; ++i)
#pragma unroll
      for (int c = 0; c < 3; ++c) {
        sums[3 + 3 * i + c] += a.c[i] * a.c[c];
        sums[12 + 3 * i + c] += b.c[i] * b.c[c];
        sums[21 + 3 * i + c] += a.c[i] * b.c[c];
      }
#pragma unroll
    for (int ch = 0; ch < 3; ++ch) {
      atomicAdd(&hist_a[256 * ch + a.c[ch]], 1u);
      atomicAdd(&hist_b[256 * ch + b.c[ch]], 1u);
    }
  }
  __shared__ unsigned long long totals[30];
  block_sum<30>(sums, totals);  // also orders the shared histograms before they are read
  add_histogram(hist_a, out.hist_a, 3 * 256);
  add_histogram(hist_b, out.hist_b, 3 * 256);
  if (threadIdx.x == 0) {
    if (totals[0]) atomicAdd(&out.moving, totals[0]);
    if (totals[1]) atomicAdd(&out.misaligned, totals[1]);
    if (totals[2]) atomicAdd(&out.count, totals[2]);
  }
  if (threadIdx.x < 9) {
    atomicAdd(&out.aa[threadIdx.x], totals[3 + threadIdx.x]);
    atomicAdd(&out.bb[threadIdx.x], totals[12 + threadIdx.x]);
    atomicAdd(&out.ab[threadIdx.x], totals[21 + threadIdx.x]);
  }
  const int match = args.want_match ? args.pair_match[p] : kColorMatchNone;
  if (match == kColorMatchNone) return;  // whole block
  // The last of the pair's blocks to finish sees every histogram complete.
  __shared__ bool last;
  __threadfence();
  __syncthreads();
  if (threadIdx.x == 0) {
    const unsigned int blocks = unsigned((pair.count + args.mask_per_block - 1) / args.mask_per_block);
    last = atomicAdd(&out.blocks_done, 1u) == blocks - 1;
  }
  __syncthreads();
  if (!last) return;  // whole block
  __threadfence();
  build_match_luts(args, p, match);
}

// Launch 3, grid (sample blocks, pairs): sum s lut(s)^T over the usable samples, s the matched side.
__global__ void matched_moments_kernel(const __grid_constant__ ColorReduceArgs args) {
  const int match = args.pair_match[blockIdx.y];
  const ColorSamplePair pair = args.pairs[blockIdx.y];
  const SampleRange r = block_range(args.matched_per_block, pair.count);
  if (match == kColorMatchNone || r.begin >= r.end || !args.views[pair.a].data || !args.views[pair.b].data)
    return;  // whole block
  __shared__ uint8_t lut[3 * 256];
  for (int i = threadIdx.x; i < 3 * 256; i += blockDim.x) lut[i] = args.match_luts[3 * 256 * blockIdx.y + i];
  __syncthreads();
  unsigned int sums[9] = {};
  for (int k = r.begin + threadIdx.x; k < r.end; k += blockDim.x) {
    Rgb a, b;
    if (!load_pair_sample(args, pair, k, a, b)) continue;
    const Rgb s = match == kColorMatchAOntoB ? a : b;
#pragma unroll
    for (int i = 0; i < 3; ++i)
#pragma unroll
      for (int c = 0; c < 3; ++c) sums[3 * i + c] += s.c[i] * unsigned(lut[256 * c + s.c[c]]);
  }
  __shared__ unsigned long long totals[9];
  block_sum<9>(sums, totals);
  if (threadIdx.x < 9) atomicAdd(&args.pair_results[blockIdx.y].matched[threadIdx.x], totals[threadIdx.x]);
}

int blocks_for(int samples, int per_block) { return (samples + per_block - 1) / per_block; }

// Samples per thread of each kernel. One spreads the latency-bound gathers over every SM; the
// mask-and-moments kernel takes two, which halves its blocks' histogram flushes (nsys on an
// H100, 3 x 1080p: 1, 2 and 4 all within 1.4 us; BENCHMARKS.md).
constexpr int kMotionPerThread = 1, kBalancePerThread = 1, kMaskPerThread = 2, kMatchedPerThread = 1;
static_assert(kMotionPerThread <= kMaxSamplesPerThread && kMaskPerThread <= kMaxSamplesPerThread &&
                  kMatchedPerThread <= kMaxSamplesPerThread,
              "block_sum's 32-bit warp sums");

}  // namespace

void launch_color_apply_batch(const ColorApplyBatch& batch, const uint8_t* lut, cudaStream_t stream) {
  int width = 0, height = 0;
  for (int i = 0; i < batch.count; ++i) {
    width = batch.views[i].width > width ? batch.views[i].width : width;
    height = batch.views[i].height > height ? batch.views[i].height : height;
  }
  if (batch.count <= 0 || batch.count > kColorApplyMaxViews || width <= 0 || height <= 0) return;
  // Four pixels a thread where every row starts on 16 bytes: fewer, wider memory operations
  // and the index arithmetic once per four pixels.
  bool aligned = true;
  for (int i = 0; i < batch.count; ++i)
    aligned = aligned && reinterpret_cast<uintptr_t>(batch.views[i].data) % 16 == 0 && batch.views[i].pitch % 16 == 0;
  if (aligned) {
    const dim3 block(32, 8), grid((width + 127) / 128, (height + 7) / 8, batch.count);
    apply_batch_kernel<4><<<grid, block, 0, stream>>>(batch, lut);
  } else {
    const dim3 block(32, 8), grid((width + 31) / 32, (height + 7) / 8, batch.count);
    apply_batch_kernel<1><<<grid, block, 0, stream>>>(batch, lut);
  }
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

void launch_color_reduce(const ColorReduceArgs& args_in, cudaStream_t stream) {
  ColorReduceArgs args = args_in;
  args.motion_per_block = kMotionPerThread * kThreads;
  args.balance_per_block = kBalancePerThread * kThreads;
  args.mask_per_block = kMaskPerThread * kThreads;
  args.matched_per_block = kMatchedPerThread * kThreads;
  const bool pairs = args.want_pairs && args.pair_count > 0 && args.max_pair_samples > 0;
  const bool balance = args.want_balance && args.view_count > 0 && args.max_grid_samples > 0;
  args.motion_rows = pairs ? args.pair_count : 0;
  if (pairs || balance) {
    const int columns = std::max(pairs ? blocks_for(args.max_pair_samples, args.motion_per_block) : 0,
                                 balance ? blocks_for(args.max_grid_samples, args.balance_per_block) : 0);
    motion_balance_kernel<<<dim3(columns, args.motion_rows + (balance ? args.view_count : 0)), kThreads, 0, stream>>>(args);
    check_launch("color motion and balance kernel");
  }
  if (!pairs) return;
  mask_moments_kernel<<<dim3(blocks_for(args.max_pair_samples, args.mask_per_block), args.pair_count), kThreads, 0,
                        stream>>>(args);
  check_launch("color mask and moments kernel");
  if (args.want_match) {
    matched_moments_kernel<<<dim3(blocks_for(args.max_pair_samples, args.matched_per_block), args.pair_count),
                             kThreads, 0, stream>>>(args);
    check_launch("color matched moments kernel");
  }
}

}  // namespace stitch_cuda
