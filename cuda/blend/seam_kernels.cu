#include <algorithm>
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
                                 const int* counts, float* cost, uint8_t* mix, int label_width) {
  const int bx = blockIdx.x * blockDim.x + threadIdx.x, by = blockIdx.y * blockDim.y + threadIdx.y;
  if (bx >= p.box_w || by >= p.box_h) return;
  const float ce = centre[size_t(by) * p.box_w + bx];
  if (ce < 0.f) return;
  const int row = p.vertical ? by : bx, col = p.vertical ? bx : by;
  const int rows = p.vertical ? p.box_h : p.box_w, cols = p.vertical ? p.box_w : p.box_h;
  int sum = 0;
  for (int k = max(0, row - w.mix_radius); k <= min(rows - 1, row + w.mix_radius); ++k)
    sum += across[size_t(k) * cols + col];
  const int level = blank(counts, 0) || blank(counts, 1) ? 255 : sm::mix_level(w, sum);
  uint8_t& m = mix[size_t(p.box_y + by) * label_width + p.box_x + bx];
  m = uint8_t(max(int(m), level));  // pairs run one after another: no race
  if (w.crossing > 0.f) {
    float& v = cost[size_t(row) * cols + col];
    v = sm::crossing_cost(w, v, ce, level);
  }
}

__global__ void mix_apply_kernel(DeviceImage out, MixViews v, const uint8_t* labels, const uint8_t* mix) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= out.width || y >= out.height) return;
  const size_t at = size_t(y) * out.width + x;
  const int m = mix[at], l = labels[at];
  if (!m || l >= v.n || !v.view[l].data) return;
  const int* r = v.roi[l];
  if (x < r[0] || y < r[1] || x >= r[0] + r[2] || y >= r[1] + r[3]) return;
  const uint8_t* src = v.view[l].data + size_t(y - r[1]) * v.view[l].pitch + size_t(x - r[0]) * 4;
  uint8_t* o = out.data + size_t(y) * out.pitch + size_t(x) * 4;
  for (int k = 0; k < 3; ++k) o[k] = sm::mix_value(o[k], src[k], m);
}

// One block per pair: the rows one after the other (each depends on the one before), the columns
// of a row across the threads; two rows of energy in shared memory. Thread 0 sums the previous
// seam's cost on the way (row order, as the CPU). The walk back is serial, so the steps come to
// shared memory a band of `walk_rows` rows at a time (every thread loading) and thread 0 follows
// them there: a global load per row made it latency-bound (~1 us a row on tall overlaps).
__global__ void dp_kernel(const SeamDpJob* jobs, float stability, float hold, int walk_rows) {
  extern __shared__ float energy[];  // 2 x max_cols, then walk_rows x max_cols steps
  __shared__ int best_col, keep;
  const SeamDpJob job = jobs[blockIdx.x];
  const int rows = job.rows, cols = job.cols;
  float* above = energy;
  float* here = energy + cols;
  int8_t* band = reinterpret_cast<int8_t*>(energy + 2 * cols);
  float previous_cost = 0.f;
  for (int r = 0; r < rows; ++r) {
    const int prev = job.previous ? job.previous[r] : -1;
    for (int c = threadIdx.x; c < cols; c += blockDim.x)
      job.steps[size_t(r) * cols + c] =
          int8_t(sm::dp_cell(above, c, cols, r == 0, job.cost[size_t(r) * cols + c], stability, prev, here[c]));
    if (threadIdx.x == 0 && job.previous) previous_cost = sm::add(previous_cost, job.cost[size_t(r) * cols + prev]);
    __syncthreads();
    float* t = above;
    above = here;
    here = t;
  }
  if (threadIdx.x == 0) {
    int c = 0;  // the first minimum, as std::min_element
    for (int k = 1; k < cols; ++k)
      if (above[k] < above[c]) c = k;
    best_col = c;
    // the seam holds still until something crosses it
    keep = job.previous && sm::keep_previous(previous_cost, above[c], rows, hold) ? 1 : 0;
  }
  __syncthreads();
  if (keep) {
    for (int r = threadIdx.x; r < rows; r += blockDim.x) job.path[r] = job.previous[r];
    return;
  }
  int c = best_col;
  for (int top = rows; top > 0; top -= walk_rows) {
    const int r0 = top > walk_rows ? top - walk_rows : 0;
    const int n = (top - r0) * cols;
    for (int i = threadIdx.x; i < n; i += blockDim.x) band[i] = job.steps[size_t(r0) * cols + i];
    __syncthreads();
    if (threadIdx.x == 0)
      for (int r = top - 1; r >= r0; --r) {
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
                     int label_width, cudaStream_t stream) {
  if (weights.mix_radius <= 0) return;
  const int rows = pair.vertical ? pair.box_h : pair.box_w, cols = pair.vertical ? pair.box_w : pair.box_h;
  clearance_across_kernel<<<grid_for(cols, rows), kBlock, 0, stream>>>(diff, rows, cols, weights.mix_radius, across);
  check_launch("seam mix across kernel");
  mix_along_kernel<<<grid_for(pair.box_w, pair.box_h), kBlock, 0, stream>>>(pair, across, centre, weights, counts,
                                                                            cost, mix, label_width);
  check_launch("seam mix_along_kernel");
}

void launch_seam_mix_apply(const DeviceImage& out, const MixViews& views, const uint8_t* labels, const uint8_t* mix,
                           cudaStream_t stream) {
  if (out.width <= 0 || out.height <= 0) return;
  mix_apply_kernel<<<grid_for(out.width, out.height), kBlock, 0, stream>>>(out, views, labels, mix);
  check_launch("seam mix_apply_kernel");
}

void launch_seam_dp(const SeamDpJob* jobs, int n_jobs, int max_cols, float stability, float hold, cudaStream_t stream) {
  if (n_jobs <= 0) return;
  const int walk_rows = std::max(1, std::min(64, 16384 / std::max(1, max_cols)));  // <= 16 KB of steps
  const size_t shared = size_t(2) * max_cols * sizeof(float) + size_t(walk_rows) * max_cols + sizeof(float);
  if (shared > 48 * 1024) {
    const cudaError_t e = cudaFuncSetAttribute(dp_kernel, cudaFuncAttributeMaxDynamicSharedMemorySize, int(shared));
    if (e != cudaSuccess) throw std::runtime_error(std::string("seam dp_kernel: overlap too wide: ") + cudaGetErrorString(e));
  }
  dp_kernel<<<n_jobs, 1024, shared, stream>>>(jobs, stability, hold, walk_rows);
  check_launch("seam dp_kernel");
}

void launch_seam_labels(uint8_t* labels, int label_width, const SeamPairGeometry& pair, const float* centre,
                        const int* path, const int* counts, cudaStream_t stream) {
  labels_kernel<<<grid_for(pair.box_w, pair.box_h), kBlock, 0, stream>>>(labels, label_width, pair, centre, path,
                                                                         counts);
  check_launch("seam labels_kernel");
}

}  // namespace stitch_cuda
