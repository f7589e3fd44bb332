#include <stdexcept>
#include <string>

#include "../launch_check.hpp"
#include "flow_kernels.hpp"
#include "flow_math.cuh"

namespace stitch_cuda {

namespace {

void check_pairs(int n_pairs) {
  if (n_pairs < 0 || n_pairs > kMaxFlowTasks) throw std::invalid_argument("at most 32 flow pairs per batch");
}

constexpr int kPyrBlockW = 32, kPyrBlockH = 8, kPyrThreads = kPyrBlockW * kPyrBlockH;

struct PyramidParams {
  FlowPyramidImage images[2 * kMaxFlowTasks];
  uint32_t* stats;
  int stats_blocks;
};

// Sum over the block, valid in thread 0.
__device__ __forceinline__ uint32_t block_sum(uint32_t v, uint32_t* scratch) {
  for (int o = 16; o > 0; o >>= 1) v += __shfl_down_sync(0xffffffffu, v, o);
  const int tid = threadIdx.y * blockDim.x + threadIdx.x;
  if ((tid & 31) == 0) scratch[tid >> 5] = v;
  __syncthreads();
  uint32_t s = 0;
  if (tid == 0)
    for (int w = 0; w < kPyrThreads / 32; ++w) s += scratch[w];
  return s;
}

template <typename Pixel, bool kStats>
__global__ void __launch_bounds__(kPyrThreads) pyramid_kernel(const __grid_constant__ PyramidParams p) {
  const FlowPyramidImage& im = p.images[blockIdx.z];
  const int x = blockIdx.x * kPyrBlockW + threadIdx.x, y = blockIdx.y * kPyrBlockH + threadIdx.y;
  if (!kStats && (im.dst == nullptr || int(blockIdx.x) * kPyrBlockW >= im.dst_w ||
                  int(blockIdx.y) * kPyrBlockH >= im.dst_h))
    return;  // whole block: no barrier below in this variant
  const Pixel* src = static_cast<const Pixel*>(im.src);
  const bool inside = x < im.dst_w && y < im.dst_h;
  if (inside && im.dst)
    im.dst[size_t(y) * size_t(im.dst_pitch) + size_t(x)] =
        flow::pyr_down_at(src, size_t(im.src_pitch), im.src_w, im.src_h, x, y);
  if (kStats) {
    // Every source pixel belongs to exactly one destination pixel's 2x2 cell: integer sums
    // of the level-0 grey values and their squares (exact; <= 1024 pixels per block).
    uint32_t sum = 0, sq = 0;
    if (inside)
      for (int j = 0; j < 2; ++j)
        for (int i = 0; i < 2; ++i) {
          const int sx = 2 * x + i, sy = 2 * y + j;
          if (sx >= im.src_w || sy >= im.src_h) continue;
          const uint32_t g = uint32_t(flow::load_pixel(src, size_t(im.src_pitch), sx, sy));
          sum += g;
          sq += g * g;
        }
    __shared__ uint32_t scratch[kPyrThreads / 32];
    sum = block_sum(sum, scratch);
    __syncthreads();  // scratch is reused
    sq = block_sum(sq, scratch);
    if (threadIdx.x == 0 && threadIdx.y == 0) {
      const size_t slot = size_t(blockIdx.z) * size_t(p.stats_blocks) + blockIdx.y * gridDim.x + blockIdx.x;
      p.stats[2 * slot] = sum;
      p.stats[2 * slot + 1] = sq;
    }
  }
}

struct FlatnessParams {
  const uint32_t* stats;
  int stats_blocks;
  int pixels[kMaxFlowTasks];
  int* flat;
};

// One block per pair: adds up the partial sums of both images and compares the variance.
__global__ void __launch_bounds__(256) flatness_kernel(const __grid_constant__ FlatnessParams p) {
  const int t = blockIdx.x;
  __shared__ unsigned long long partial[4][256];
  unsigned long long acc[4] = {0, 0, 0, 0};  // from sum, from squares, to sum, to squares
  for (int k = 0; k < 2; ++k) {
    const uint32_t* s = p.stats + 2 * size_t(2 * t + k) * size_t(p.stats_blocks);
    for (int b = threadIdx.x; b < p.stats_blocks; b += blockDim.x) {
      acc[2 * k] += s[2 * b];
      acc[2 * k + 1] += s[2 * b + 1];
    }
  }
  for (int c = 0; c < 4; ++c) partial[c][threadIdx.x] = acc[c];
  __syncthreads();
  for (int half = 128; half > 0; half >>= 1) {
    if (int(threadIdx.x) < half)
      for (int c = 0; c < 4; ++c) partial[c][threadIdx.x] += partial[c][threadIdx.x + half];
    __syncthreads();
  }
  if (threadIdx.x == 0) {
    const double n = double(p.pixels[t] > 0 ? p.pixels[t] : 1);
    bool flat = false;
    for (int k = 0; k < 2; ++k) {
      const double mean = double(partial[2 * k][0]) / n;
      const double var = double(partial[2 * k + 1][0]) / n - mean * mean;
      flat = flat || var < 1.0;
    }
    p.flat[t] = flat ? 1 : 0;
  }
}

// The iteration kernel: a block computes a 32 x 16 tile of the new flow. Its Gaussian window
// needs the eight per-pixel terms on the tile plus a kWindowRadius halo; they are computed once
// into shared memory, blurred along rows (held in registers, then written back over the same
// shared array: 39 KB instead of 68), then along columns at the tile's pixels.
constexpr int kR = flow::kWindowRadius;
constexpr int kTileW = 32, kTileH = 16;
constexpr int kIterBlockW = 32, kIterBlockH = 8, kIterThreads = kIterBlockW * kIterBlockH;
constexpr int kRegionW = kTileW + 2 * kR, kRegionH = kTileH + 2 * kR;
constexpr int kTerms = 8;
constexpr int kRowSums = kTileW * kRegionH;  // horizontally blurred values per term
constexpr int kRowSumsPerThread = (kRowSums + kIterThreads - 1) / kIterThreads;

struct IterationParams {
  FlowLevelTask tasks[kMaxFlowTasks];
  float window[flow::kWindowTaps];
  float lambda, max_step;
  int final_pass;
  const int* flat;
};
static_assert(sizeof(IterationParams) <= 4096, "kernel parameters must fit the classic 4 KiB");
static_assert(sizeof(PyramidParams) <= 4096, "kernel parameters must fit the classic 4 KiB");

// The flow this pass starts from at pixel (x, y) of the level.
__device__ __forceinline__ void starting_flow(const FlowLevelTask& t, int x, int y, float& u, float& v) {
  switch (t.source) {
    case kFlowCurrent: {
      const float* q = t.src + 2 * (size_t(y) * size_t(t.src_pitch) + size_t(x));
      u = __ldg(q);
      v = __ldg(q + 1);
      return;
    }
    case kFlowUpsample: flow::upsample_flow_at(t.src, size_t(t.src_pitch), t.src_w, t.src_h, x, y, u, v); return;
    case kFlowSeed:
      flow::seed_flow_at(t.src, size_t(t.src_pitch), t.src_w, t.src_h, t.seed_step, x, y, u, v);
      return;
    default: u = v = 0.f; return;
  }
}

struct SeedParams {
  FlowLevelTask tasks[kMaxFlowTasks];
};
static_assert(sizeof(SeedParams) <= 4096, "kernel parameters must fit the classic 4 KiB");

__global__ void seed_kernel(const __grid_constant__ SeedParams p) {
  const FlowLevelTask& t = p.tasks[blockIdx.z];
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (t.source != kFlowSeed || x >= t.width || y >= t.height) return;
  float u, v;
  flow::seed_flow_at(t.src, size_t(t.src_pitch), t.src_w, t.src_h, t.seed_step, x, y, u, v);
  float* q = t.dst + 2 * (size_t(y) * size_t(t.dst_pitch) + size_t(x));
  q[0] = u;
  q[1] = v;
}

template <typename Pixel>
__global__ void __launch_bounds__(kIterThreads) lk_iteration_kernel(const __grid_constant__ IterationParams p) {
  const FlowLevelTask& t = p.tasks[blockIdx.z];
  const int x0 = blockIdx.x * kTileW, y0 = blockIdx.y * kTileH;
  if (t.source == kFlowSkip || x0 >= t.width || y0 >= t.height) return;  // whole block, before any barrier
  const int w = t.width, h = t.height;
  const size_t pitch = size_t(t.image_pitch);
  const Pixel* from = static_cast<const Pixel*>(t.from);
  const Pixel* to = static_cast<const Pixel*>(t.to);

  // terms[c][ly][lx] over the region (kRegionW wide), later row sums[c][ly][lx] (kTileW wide).
  __shared__ float terms[kTerms * kRegionH * kRegionW];
  const int tid = threadIdx.y * kIterBlockW + threadIdx.x;

  // Terms of every tile + halo pixel; outside the image the edge pixel repeats (as the host
  // prototype's blur with a replicated border).
  for (int i = tid; i < kRegionW * kRegionH; i += kIterThreads) {
    const int ly = i / kRegionW, lx = i - ly * kRegionW;
    const int gx = flow::clamp_int(x0 - kR + lx, 0, w - 1), gy = flow::clamp_int(y0 - kR + ly, 0, h - 1);
    float u, v, ix, iy;
    starting_flow(t, gx, gy, u, v);
    flow::gradient_at(from, pitch, w, h, gx, gy, ix, iy);
    const float it = flow::sample_clamped(to, pitch, w, h, float(gx) + u, float(gy) + v) -
                     flow::load_pixel(from, pitch, gx, gy);
    const flow::LkTerms e = flow::lk_terms(ix, iy, it, u, v);
    const float values[kTerms] = {e.xx, e.xy, e.yy, e.x, e.y, e.xd, e.yd, e.d};
#pragma unroll
    for (int c = 0; c < kTerms; ++c) terms[(c * kRegionH + ly) * kRegionW + lx] = values[c];
  }
  __syncthreads();

  float row_sum[kRowSumsPerThread][kTerms];
#pragma unroll
  for (int r = 0; r < kRowSumsPerThread; ++r) {
    const int i = tid + r * kIterThreads;
#pragma unroll
    for (int c = 0; c < kTerms; ++c) row_sum[r][c] = 0.f;
    if (i >= kRowSums) continue;
    const int ly = i / kTileW, lx = i - ly * kTileW;
#pragma unroll
    for (int k = 0; k < flow::kWindowTaps; ++k) {
      const float wk = p.window[k];
#pragma unroll
      for (int c = 0; c < kTerms; ++c) row_sum[r][c] += wk * terms[(c * kRegionH + ly) * kRegionW + lx + k];
    }
  }
  __syncthreads();  // every row sum is read before the array is overwritten
#pragma unroll
  for (int r = 0; r < kRowSumsPerThread; ++r) {
    const int i = tid + r * kIterThreads;
    if (i >= kRowSums) continue;
#pragma unroll
    for (int c = 0; c < kTerms; ++c) terms[c * kRowSums + i] = row_sum[r][c];  // [c][ly][lx], kTileW wide
  }
  __syncthreads();

#pragma unroll
  for (int r = 0; r < kTileH / kIterBlockH; ++r) {
    const int lx = threadIdx.x, ly = threadIdx.y + r * kIterBlockH;
    const int x = x0 + lx, y = y0 + ly;
    if (x >= w || y >= h) continue;
    float s[kTerms] = {0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f, 0.f};
#pragma unroll
    for (int k = 0; k < flow::kWindowTaps; ++k) {
      const float wk = p.window[k];
#pragma unroll
      for (int c = 0; c < kTerms; ++c) s[c] += wk * terms[c * kRowSums + (ly + k) * kTileW + lx];
    }
    const flow::LkTerms sums{s[0], s[1], s[2], s[3], s[4], s[5], s[6], s[7]};
    float u, v;
    starting_flow(t, x, y, u, v);
    flow::lk_solve(sums, p.lambda, p.max_step, u, v);
    flow::keep_inside(x, y, w, h, u, v);
    if (p.final_pass && p.flat[blockIdx.z]) u = v = 0.f;
    // Scalar stores: the caller's flow needs only float alignment.
    float* q = t.dst + 2 * (size_t(y) * size_t(t.dst_pitch) + size_t(x));
    q[0] = u;
    q[1] = v;
  }
}

dim3 pyramid_grid(int n_pairs, const FlowPyramidImage* images) {
  int max_w = 1, max_h = 1;
  for (int i = 0; i < 2 * n_pairs; ++i) {
    max_w = images[i].dst_w > max_w ? images[i].dst_w : max_w;
    max_h = images[i].dst_h > max_h ? images[i].dst_h : max_h;
  }
  return dim3((max_w + kPyrBlockW - 1) / kPyrBlockW, (max_h + kPyrBlockH - 1) / kPyrBlockH, 2 * n_pairs);
}

PyramidParams pyramid_params(int n_pairs, const FlowPyramidImage* images) {
  PyramidParams p{};
  for (int i = 0; i < 2 * n_pairs; ++i) p.images[i] = images[i];
  return p;
}

}  // namespace

int flow_stats_blocks_per_image(int max_dst_w, int max_dst_h) {
  const int bx = (max_dst_w + kPyrBlockW - 1) / kPyrBlockW, by = (max_dst_h + kPyrBlockH - 1) / kPyrBlockH;
  return (bx > 1 ? bx : 1) * (by > 1 ? by : 1);
}

void launch_flow_pyramid_first(int n_pairs, const FlowPyramidImage* images, uint32_t* stats, int stats_blocks,
                               cudaStream_t stream) {
  check_pairs(n_pairs);
  if (n_pairs == 0) return;
  const dim3 grid = pyramid_grid(n_pairs, images);
  if (int(grid.x * grid.y) != stats_blocks)
    throw std::invalid_argument("flow pyramid: statistics buffer sized for another grid");
  PyramidParams p = pyramid_params(n_pairs, images);
  p.stats = stats;
  p.stats_blocks = stats_blocks;
  pyramid_kernel<uint8_t, true><<<grid, dim3(kPyrBlockW, kPyrBlockH), 0, stream>>>(p);
  check_launch("flow pyramid (first level) kernel");
}

void launch_flow_flatness(int n_pairs, const uint32_t* stats, int stats_blocks, const int* pixels, int* flat,
                          cudaStream_t stream) {
  check_pairs(n_pairs);
  if (n_pairs == 0) return;
  FlatnessParams p{};
  p.stats = stats;
  p.stats_blocks = stats_blocks;
  for (int t = 0; t < n_pairs; ++t) p.pixels[t] = pixels[t];
  p.flat = flat;
  flatness_kernel<<<n_pairs, 256, 0, stream>>>(p);
  check_launch("flow flatness kernel");
}

void launch_flow_pyramid(int n_pairs, const FlowPyramidImage* images, cudaStream_t stream) {
  check_pairs(n_pairs);
  if (n_pairs == 0) return;
  const PyramidParams p = pyramid_params(n_pairs, images);
  pyramid_kernel<float, false><<<pyramid_grid(n_pairs, images), dim3(kPyrBlockW, kPyrBlockH), 0, stream>>>(p);
  check_launch("flow pyramid kernel");
}

void launch_flow_seed(int n_pairs, const FlowLevelTask* tasks, int max_w, int max_h, cudaStream_t stream) {
  if (n_pairs <= 0 || max_w <= 0 || max_h <= 0) return;
  if (n_pairs > kMaxFlowTasks) throw std::invalid_argument("too many flow tasks");
  SeedParams p{};
  for (int i = 0; i < n_pairs; ++i) p.tasks[i] = tasks[i];
  const dim3 block(32, 8), grid((max_w + 31) / 32, (max_h + 7) / 8, n_pairs);
  seed_kernel<<<grid, block, 0, stream>>>(p);
  check_launch("flow seed kernel");
}

void launch_flow_iteration(int n_pairs, const FlowLevelTask* tasks, const FlowIterationSettings& settings,
                           cudaStream_t stream) {
  check_pairs(n_pairs);
  if (n_pairs == 0) return;
  if (settings.final_pass && !settings.flat) throw std::invalid_argument("flow iteration: final pass without flags");
  IterationParams p{};
  int max_w = 1, max_h = 1;
  for (int t = 0; t < n_pairs; ++t) {
    p.tasks[t] = tasks[t];
    if (tasks[t].source == kFlowSkip) continue;
    max_w = tasks[t].width > max_w ? tasks[t].width : max_w;
    max_h = tasks[t].height > max_h ? tasks[t].height : max_h;
  }
  flow::window_weights(p.window);
  p.lambda = settings.lambda;
  p.max_step = settings.max_step;
  p.final_pass = settings.final_pass;
  p.flat = settings.flat;
  const dim3 grid((max_w + kTileW - 1) / kTileW, (max_h + kTileH - 1) / kTileH, n_pairs);
  const dim3 block(kIterBlockW, kIterBlockH);
  if (settings.level0)
    lk_iteration_kernel<uint8_t><<<grid, block, 0, stream>>>(p);
  else
    lk_iteration_kernel<float><<<grid, block, 0, stream>>>(p);
  check_launch("flow iteration kernel");
}

}  // namespace stitch_cuda
