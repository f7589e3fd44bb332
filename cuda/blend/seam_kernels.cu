#include <algorithm>
#include <cuda_pipeline.h>
#include <map>
#include <mutex>
#include "../launch_check.hpp"
#include "seam_kernels.hpp"

namespace stitch_cuda {

namespace sm = stitch::seam;

namespace {

__device__ __forceinline__ int luma_at(const uint8_t* l, const int* roi, int x, int y) {
  x = min(max(x, roi[0]), roi[0] + roi[2] - 1);
  y = min(max(y, roi[1]), roi[1] + roi[3] - 1);
  return l[size_t(y - roi[1]) * roi[2] + (x - roi[0])];
}

__global__ void luma_kernel(DeviceImage view, uint8_t* luma) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= view.width || y >= view.height) return;
  luma[size_t(y) * view.width + x] = sm::luma(view.data + size_t(y) * view.pitch + size_t(x) * 4);
}

__global__ void cost_kernel(SeamPairGeometry p, DeviceImage va, DeviceImage vb, const uint8_t* la, const uint8_t* lb,
                            const uint8_t* pa, const uint8_t* pb, const float* centre_map, sm::Weights w, float* cost,
                            int* diff, int* counts) {
  const int bx = blockIdx.x * blockDim.x + threadIdx.x, by = blockIdx.y * blockDim.y + threadIdx.y;
  const bool in_box = bx < p.box_w && by < p.box_h;
  const float centre = in_box ? centre_map[size_t(by) * p.box_w + bx] : -1.f;
  const int x = p.box_x + bx, y = p.box_y + by;
  const bool inside = centre >= 0.f;
  const int a = inside ? luma_at(la, p.roi_a, x, y) : 255, b = inside ? luma_at(lb, p.roi_b, x, y) : 255;
  if (counts) {  // the overlap's pixels and the dark ones of each view, a warp's worth per atomic
    const unsigned n_in = __ballot_sync(0xffffffffu, inside), n_a = __ballot_sync(0xffffffffu, a <= sm::kDark),
                   n_b = __ballot_sync(0xffffffffu, b <= sm::kDark);
    if ((threadIdx.x & 31) == 0 && n_in) {
      atomicAdd(counts, __popc(n_in));
      if (n_a) atomicAdd(counts + 1, __popc(n_a));
      if (n_b) atomicAdd(counts + 2, __popc(n_b));
    }
  }
  if (!in_box) return;
  const int row = p.vertical ? by : bx, col = p.vertical ? bx : by, cols = p.vertical ? p.box_w : p.box_h;
  float& out = cost[size_t(row) * cols + col];
  if (!inside) {
    out = sm::kOutside;
    if (diff) diff[size_t(row) * cols + col] = 0;
    return;
  }
  const int gradients = abs(luma_at(la, p.roi_a, x + 1, y) - luma_at(la, p.roi_a, x - 1, y)) +
                        abs(luma_at(la, p.roi_a, x, y + 1) - luma_at(la, p.roi_a, x, y - 1)) +
                        abs(luma_at(lb, p.roi_b, x + 1, y) - luma_at(lb, p.roi_b, x - 1, y)) +
                        abs(luma_at(lb, p.roi_b, x, y + 1) - luma_at(lb, p.roi_b, x, y - 1));
  const int motion = abs(a - luma_at(pa, p.roi_a, x, y)) + abs(b - luma_at(pb, p.roi_b, x, y));
  const float difference =
      sm::color_difference(va.data + size_t(y - p.roi_a[1]) * va.pitch + size_t(x - p.roi_a[0]) * 4,
                           vb.data + size_t(y - p.roi_b[1]) * vb.pitch + size_t(x - p.roi_b[0]) * 4);
  out = sm::pixel_cost(w, difference, gradients, motion, centre);
  if (diff)
    diff[size_t(row) * cols + col] =
        sm::color_difference_sum(va.data + size_t(y - p.roi_a[1]) * va.pitch + size_t(x - p.roi_a[0]) * 4,
                                 vb.data + size_t(y - p.roi_b[1]) * vb.pitch + size_t(x - p.roi_b[0]) * 4);
}

// The clearance term's window sums (seam frame, rows x cols), as SeamFinder::cut: across the
// seam first, then along it, in integers.
__global__ void clearance_across_kernel(const int* diff, int rows, int cols, int radius, int* across) {
  const int c = blockIdx.x * blockDim.x + threadIdx.x, r = blockIdx.y * blockDim.y + threadIdx.y;
  if (c >= cols || r >= rows) return;
  int sum = 0;
  for (int k = max(0, c - radius); k <= min(cols - 1, c + radius); ++k) sum += diff[size_t(r) * cols + k];
  across[size_t(r) * cols + c] = sum;
}

__global__ void clearance_along_kernel(const int* across, int rows, int cols, sm::Weights w, float* cost) {
  const int c = blockIdx.x * blockDim.x + threadIdx.x, r = blockIdx.y * blockDim.y + threadIdx.y;
  if (c >= cols || r >= rows) return;
  float& v = cost[size_t(r) * cols + c];
  if (v == sm::kOutside) return;
  int sum = 0;
  for (int k = max(0, r - w.clearance_radius); k <= min(rows - 1, r + w.clearance_radius); ++k)
    sum += across[size_t(k) * cols + c];
  v = sm::add(v, sm::clearance_cost(w, sum));
}

__device__ __forceinline__ bool blank(const int* counts, int view) {  // view 0: a, 1: b
  return counts && sm::view_blank(counts[1 + view], counts[2 - view], counts[0]);
}

// The pair's mix levels (max into the mix map) and, from them, the crossing cost (as SeamFinder::cut).
__global__ void mix_along_kernel(SeamPairGeometry p, const int* across, const float* centre, sm::Weights w,
                                 const int* counts, float* cost, uint8_t* mix, int label_width, uint8_t* levels) {
  const int bx = blockIdx.x * blockDim.x + threadIdx.x, by = blockIdx.y * blockDim.y + threadIdx.y;
  if (bx >= p.box_w || by >= p.box_h) return;
  const float ce = centre[size_t(by) * p.box_w + bx];
  const int row = p.vertical ? by : bx, col = p.vertical ? bx : by;
  const int rows = p.vertical ? p.box_h : p.box_w, cols = p.vertical ? p.box_w : p.box_h;
  if (ce < 0.f) {
    if (levels) levels[size_t(row) * cols + col] = 0;
    return;
  }
  int sum = 0;
  for (int k = max(0, row - w.mix_radius); k <= min(rows - 1, row + w.mix_radius); ++k)
    sum += across[size_t(k) * cols + col];
  const int level = blank(counts, 0) || blank(counts, 1) ? 255 : sm::mix_level(w, sum);
  uint8_t& m = mix[size_t(p.box_y + by) * label_width + p.box_x + bx];
  m = uint8_t(max(int(m), level));  // pairs run one after another: no race
  if (levels) levels[size_t(row) * cols + col] = uint8_t(level);
  if (w.crossing > 0.f) {
    float& v = cost[size_t(row) * cols + col];
    v = sm::crossing_cost(w, v, ce, level);
  }
}

// The view-switch cost (seam_math.hpp view_switch_cost, as SeamFinder::cut): a warp per row of the
// seam's frame; for every seam point c, the sum of the pair's levels over the cells before c that
// showed view b last frame and the cells from c on that showed view a. Integer warp scans: the
// same sums as the CPU's running totals.
__global__ void view_switch_kernel(SeamPairGeometry p, const uint8_t* levels, const uint8_t* previous_labels,
                                   int label_width, sm::Weights w, float* cost) {
  const int rows = p.vertical ? p.box_h : p.box_w, cols = p.vertical ? p.box_w : p.box_h;
  const int r = blockIdx.x * (blockDim.x >> 5) + (threadIdx.x >> 5), lane = threadIdx.x & 31;
  if (r >= rows) return;  // whole warps leave together
  auto split = [&](int c, int& to_a, int& to_b) {  // the cell's level, by the view it showed last frame
    to_a = to_b = 0;
    if (c >= cols) return;
    const int bx = p.vertical ? c : r, by = p.vertical ? r : c;
    const int level = levels[size_t(r) * cols + c];
    const uint8_t l = previous_labels[size_t(p.box_y + by) * label_width + p.box_x + bx];
    if (l == p.a) to_a = level;
    if (l == p.b) to_b = level;
  };
  int total_a = 0;
  for (int base = 0; base < cols; base += 32) {
    int to_a, to_b;
    split(base + lane, to_a, to_b);
    total_a += to_a;
  }
  for (int o = 16; o > 0; o >>= 1) total_a += __shfl_xor_sync(0xffffffffu, total_a, o);
  int carry_a = 0, carry_b = 0;  // sums over the columns before this chunk
  for (int base = 0; base < cols; base += 32) {
    int to_a, to_b;
    split(base + lane, to_a, to_b);
    int scan_a = to_a, scan_b = to_b;  // inclusive scans across the chunk
    for (int o = 1; o < 32; o <<= 1) {
      const int ua = __shfl_up_sync(0xffffffffu, scan_a, o), ub = __shfl_up_sync(0xffffffffu, scan_b, o);
      if (lane >= o) scan_a += ua, scan_b += ub;
    }
    const int c = base + lane;
    if (c < cols) {
      const int before_b = carry_b + scan_b - to_b, after_a = total_a - (carry_a + scan_a - to_a);
      float& v = cost[size_t(r) * cols + c];
      v = sm::view_switch_cost(w, v, before_b + after_a);
    }
    carry_a += __shfl_sync(0xffffffffu, scan_a, 31);
    carry_b += __shfl_sync(0xffffffffu, scan_b, 31);
  }
}

// The sweeps (seam_math.hpp dp_meeting_row): two blocks per pair, one down through rows
// [0, m), one up through rows [m, rows), the rows one after the other (each depends on the one
// before), the columns of a row across the threads; two rows of energy in shared memory. The
// costs (and last frame's path) come to shared memory a band of rows at a time, the next band
// copied asynchronously while this one is swept: a global load per row made every row wait
// ~1 us (latency, not bytes). Thread 0 sums last frame's path's cost in its sweep's row order.
// Each block leaves its last energy row and that sum in job.edge (up: edge + cols, sums at 2 cols).
__global__ void dp_sweep_kernel(const SeamDpJob* jobs, float stability, int band_rows) {
  extern __shared__ float shared[];  // 2 x (cols + 2) energy, 2 x band_rows x cols costs, 2 x band_rows path
  const SeamDpJob job = jobs[blockIdx.x >> 1];
  const bool up = blockIdx.x & 1;
  const int rows = job.rows, cols = job.cols, m = sm::dp_meeting_row(rows);
  const int n = up ? rows - m : m;  // rows this sweep takes; the k-th is row(k)
  auto row = [&](int k) { return up ? rows - 1 - k : k; };
  // Energy rows padded for sm::dp_cell_padded: a +inf cell on either side, all 0 before the first row.
  float* above = shared + 1;
  float* here = shared + cols + 3;
  for (int c = threadIdx.x - 1; c <= cols; c += blockDim.x) {
    const bool border = c < 0 || c == cols;
    above[c] = border ? INFINITY : 0.f;
    here[c] = border ? INFINITY : 0.f;
  }
  float* bands = shared + 2 * (cols + 2);
  int* path_bands = reinterpret_cast<int*>(bands + size_t(2) * band_rows * cols);
  const int n_bands = (n + band_rows - 1) / band_rows;
  // Band b holds sweep rows [b B, b B + count); in memory they are rows [lowest, lowest + count).
  auto lowest = [&](int b) { return up ? row(min(n, (b + 1) * band_rows) - 1) : b * band_rows; };
  auto load = [&](int b) {
    const int count = min(band_rows, n - b * band_rows), r0 = lowest(b);
    float* dst = bands + (b & 1) * band_rows * cols;
    const float* src = job.cost + size_t(r0) * cols;
    for (int i = threadIdx.x; i < count * cols; i += blockDim.x)
      __pipeline_memcpy_async(dst + i, src + i, sizeof(float));
    if (job.previous) {
      int* pdst = path_bands + (b & 1) * band_rows;
      for (int i = threadIdx.x; i < count; i += blockDim.x)
        __pipeline_memcpy_async(pdst + i, job.previous + r0 + i, sizeof(int));
    }
    __pipeline_commit();
  };
  if (n_bands > 0) load(0);
  const bool pulled = job.previous != nullptr;
  int8_t* steps = job.steps + size_t(row(0)) * cols;  // this row's steps; the next is `stride` on
  const int stride = up ? -cols : cols;
  float previous_cost = 0.f;
  for (int b = 0; b < n_bands; ++b) {
    if (b + 1 < n_bands)
      load(b + 1);  // its buffer was last read by band b - 1, which every thread has finished
    else
      __pipeline_commit();  // an empty group: wait_prior(1) below then waits for band b
    __pipeline_wait_prior(1);
    __syncthreads();
    const int count = min(band_rows, n - b * band_rows), r0 = lowest(b);
    const float* cost = bands + (b & 1) * band_rows * cols;
    const int* previous = path_bands + (b & 1) * band_rows;
    for (int k = b * band_rows; k < b * band_rows + count; ++k) {
      const int at = row(k) - r0;
      const float* cost_row = cost + at * cols;
      const int prev = pulled ? previous[at] : -1;
      for (int c = threadIdx.x; c < cols; c += blockDim.x)
        steps[c] = int8_t(sm::dp_cell_padded(above, c, cost_row[c], stability, prev, here[c]));
      if (threadIdx.x == 0 && pulled) previous_cost = sm::add(previous_cost, cost_row[prev]);
      steps += stride;
      __syncthreads();
      float* t = above;
      above = here;
      here = t;
    }
  }
  __pipeline_wait_prior(0);
  float* edge = job.edge + (up ? cols : 0);
  for (int c = threadIdx.x; c < cols; c += blockDim.x) edge[c] = above[c];  // all 0 when n == 0
  if (threadIdx.x == 0) job.edge[2 * cols + (up ? 1 : 0)] = previous_cost;
}

// Where the sweeps meet, and the walk from there: two blocks per pair again, both finding the
// same meeting column (the first least of seam_math.hpp meet_cell), then one walking up through
// the down sweep's steps, the other down through the up sweep's. Last frame's path is kept while
// it holds (keep_previous on the two sums). The walks are serial, so the steps come to shared
// memory a band of walk_rows rows at a time (every thread loading) and thread 0 follows them.
__global__ void dp_walk_kernel(const SeamDpJob* jobs, float hold, int walk_rows) {
  extern __shared__ float walk_shared[];  // cols total, cols meet steps, walk_rows x cols steps
  __shared__ int best_col, keep;
  const SeamDpJob job = jobs[blockIdx.x >> 1];
  const bool up = blockIdx.x & 1;
  const int rows = job.rows, cols = job.cols, m = sm::dp_meeting_row(rows);
  float* total = walk_shared;
  int8_t* meet = reinterpret_cast<int8_t*>(total + cols);
  int8_t* band = meet + ((cols + 15) / 16) * 16;
  for (int c = threadIdx.x; c < cols; c += blockDim.x)
    meet[c] = int8_t(sm::meet_cell(job.edge, job.edge + cols, c, cols, m == 0, total[c]));
  __syncthreads();
  if (threadIdx.x == 0) {
    int c = 0;  // the first minimum, as std::min_element
    for (int k = 1; k < cols; ++k)
      if (total[k] < total[c]) c = k;
    best_col = c;
    keep = job.previous &&
                   sm::keep_previous(sm::add(job.edge[2 * cols], job.edge[2 * cols + 1]), total[c], rows, hold)
               ? 1
               : 0;
  }
  __syncthreads();
  const int first = up ? m : 0, last = up ? rows : m;  // this block's rows [first, last)
  if (keep) {
    for (int r = first + int(threadIdx.x); r < last; r += blockDim.x) job.path[r] = job.previous[r];
    return;
  }
  // Down block: rows m - 1 .. 0 through the down sweep's steps; up block: rows m .. rows - 1
  // through the up sweep's. Either way path[r] = c, then c moves by the step stored at row r.
  const int dir = up ? 1 : -1, count = last - first;
  int c = up ? best_col : best_col + meet[best_col];
  for (int done = 0; done < count; done += walk_rows) {
    const int n = min(walk_rows, count - done);
    const int r0 = up ? first + done : last - done - n;  // the band holds rows [r0, r0 + n)
    for (int i = threadIdx.x; i < n * cols; i += blockDim.x) band[i] = job.steps[size_t(r0) * cols + i];
    __syncthreads();
    if (threadIdx.x == 0)
      for (int k = 0, r = up ? r0 : r0 + n - 1; k < n; ++k, r += dir) {
        job.path[r] = c;
        c += band[(r - r0) * cols + c];
      }
    __syncthreads();  // the band is read before the next one overwrites it
  }
}

__global__ void labels_kernel(uint8_t* labels, int label_width, SeamPairGeometry p, const float* centre, const int* path,
                              const int* counts) {
  const int bx = blockIdx.x * blockDim.x + threadIdx.x, by = blockIdx.y * blockDim.y + threadIdx.y;
  if (bx >= p.box_w || by >= p.box_h || centre[size_t(by) * p.box_w + bx] < 0.f) return;
  const int row = p.vertical ? by : bx, col = p.vertical ? bx : by;
  uint8_t& l = labels[size_t(p.box_y + by) * label_width + p.box_x + bx];
  if (l == p.a || l == p.b) l = uint8_t(blank(counts, 0) ? p.b : blank(counts, 1) ? p.a : col < path[row] ? p.a : p.b);
}

const dim3 kBlock(32, 8);
dim3 grid_for(int w, int h) { return dim3((w + kBlock.x - 1) / kBlock.x, (h + kBlock.y - 1) / kBlock.y); }

}  // namespace

void launch_seam_luma(const DeviceImage& view, uint8_t* luma, cudaStream_t stream) {
  luma_kernel<<<grid_for(view.width, view.height), kBlock, 0, stream>>>(view, luma);
  check_launch("seam luma_kernel");
}

void launch_seam_cost(const SeamPairGeometry& pair, const DeviceImage& view_a, const DeviceImage& view_b,
                      const uint8_t* luma_a, const uint8_t* luma_b, const uint8_t* previous_a,
                      const uint8_t* previous_b, const float* centre, const stitch::seam::Weights& weights,
                      float* cost, int* diff, int* across, int* counts, cudaStream_t stream) {
  const bool clearance = weights.clearance_radius > 0 && weights.clearance > 0.f && diff && across;
  const bool mixing = weights.mix_radius > 0 && diff;
  cost_kernel<<<grid_for(pair.box_w, pair.box_h), kBlock, 0, stream>>>(pair, view_a, view_b, luma_a, luma_b, previous_a,
                                                                      previous_b, centre, weights, cost,
                                                                      clearance || mixing ? diff : nullptr, counts);
  check_launch("seam cost_kernel");
  if (!clearance) return;
  const int rows = pair.vertical ? pair.box_h : pair.box_w, cols = pair.vertical ? pair.box_w : pair.box_h;
  clearance_across_kernel<<<grid_for(cols, rows), kBlock, 0, stream>>>(diff, rows, cols, weights.clearance_radius, across);
  check_launch("seam clearance_across_kernel");
  clearance_along_kernel<<<grid_for(cols, rows), kBlock, 0, stream>>>(across, rows, cols, weights, cost);
  check_launch("seam clearance_along_kernel");
}

void launch_seam_mix(const SeamPairGeometry& pair, const int* diff, int* across, const float* centre,
                     const stitch::seam::Weights& weights, const int* counts, float* cost, uint8_t* mix,
                     int label_width, uint8_t* levels, const uint8_t* previous_labels, cudaStream_t stream) {
  if (weights.mix_radius <= 0) return;
  const int rows = pair.vertical ? pair.box_h : pair.box_w, cols = pair.vertical ? pair.box_w : pair.box_h;
  const bool holding = weights.label_hold > 0.f && levels && previous_labels;
  clearance_across_kernel<<<grid_for(cols, rows), kBlock, 0, stream>>>(diff, rows, cols, weights.mix_radius, across);
  check_launch("seam mix across kernel");
  mix_along_kernel<<<grid_for(pair.box_w, pair.box_h), kBlock, 0, stream>>>(pair, across, centre, weights, counts,
                                                                            cost, mix, label_width,
                                                                            holding ? levels : nullptr);
  check_launch("seam mix_along_kernel");
  if (!holding) return;
  constexpr int kWarps = 8;  // rows per block
  view_switch_kernel<<<(rows + kWarps - 1) / kWarps, 32 * kWarps, 0, stream>>>(pair, levels, previous_labels,
                                                                             label_width, weights, cost);
  check_launch("seam view_switch_kernel");
}

// Kernels asking for more than 48 KB of dynamic shared memory must say so once per device; the
// largest size allowed so far is remembered, so the hot path makes no driver call per frame.
static void allow_dynamic_shared(const void* kernel, size_t bytes) {
  if (bytes <= 48 * 1024) return;
  static std::mutex lock;
  static std::map<std::pair<const void*, int>, size_t> allowed;
  int device = 0;
  cudaGetDevice(&device);
  std::lock_guard<std::mutex> guard(lock);
  size_t& done = allowed[{kernel, device}];
  if (bytes <= done) return;
  const cudaError_t e = cudaFuncSetAttribute(kernel, cudaFuncAttributeMaxDynamicSharedMemorySize, int(bytes));
  if (e != cudaSuccess) throw std::runtime_error(std::string("seam dp: overlap too wide: ") + cudaGetErrorString(e));
  done = bytes;
}

void launch_seam_dp(const SeamDpJob* jobs, int n_jobs, int max_cols, float stability, float hold, cudaStream_t stream) {
  if (n_jobs <= 0) return;
  // Sweeps: cost bands of up to 32 rows, double-buffered, within ~96 KB of shared memory.
  const size_t row_bytes = size_t(max_cols) * sizeof(float);
  const size_t budget = 96 * 1024, energy = 2 * (row_bytes + 2 * sizeof(float));
  const int band_rows =
      int(std::max<size_t>(1, std::min<size_t>(32, budget > energy ? (budget - energy) / (2 * row_bytes + 8) : 1)));
  const size_t shared = energy + size_t(band_rows) * (2 * row_bytes + 2 * sizeof(int));
  // Walks: the meeting row's energies and steps, then bands of up to 64 rows of steps.
  const size_t walk_fixed = 5 * size_t(max_cols) + 16, walk_budget = 48 * 1024;
  const int walk_rows =
      walk_fixed + max_cols <= walk_budget ? int(std::min<size_t>(64, (walk_budget - walk_fixed) / max_cols)) : 1;
  const size_t walk_shared = row_bytes + size_t((max_cols + 15) / 16 * 16) + size_t(walk_rows) * max_cols;
  allow_dynamic_shared(reinterpret_cast<const void*>(dp_sweep_kernel), shared);
  allow_dynamic_shared(reinterpret_cast<const void*>(dp_walk_kernel), walk_shared);
  // A thread per column up to 1024: fewer warps make each row's barrier cheaper.
  const int threads = std::min(1024, std::max(32, (max_cols + 31) / 32 * 32));
  dp_sweep_kernel<<<2 * n_jobs, threads, shared, stream>>>(jobs, stability, band_rows);
  check_launch("seam dp_sweep_kernel");
  dp_walk_kernel<<<2 * n_jobs, threads, walk_shared, stream>>>(jobs, hold, walk_rows);
  check_launch("seam dp_walk_kernel");
}

void launch_seam_labels(uint8_t* labels, int label_width, const SeamPairGeometry& pair, const float* centre,
                        const int* path, const int* counts, cudaStream_t stream) {
  labels_kernel<<<grid_for(pair.box_w, pair.box_h), kBlock, 0, stream>>>(labels, label_width, pair, centre, path,
                                                                         counts);
  check_launch("seam labels_kernel");
}

}  // namespace stitch_cuda
