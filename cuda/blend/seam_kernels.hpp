// Launchers of the seam finder's kernels (definitions in seam_kernels.cu); the per-pixel
// arithmetic is stitch/blend/seam_math.hpp, shared with the CPU seam finder.
#pragma once
#include <cuda_runtime_api.h>
#include <stdint.h>

#include "blend_kernels.hpp"
#include "stitch/blend/seam_math.hpp"

namespace stitch_cuda {

struct SeamPairGeometry {
  int a, b;      // views; a lies before the seam
  int vertical;  // 1: one path point per row of the box
  int box_x, box_y, box_w, box_h;
  int roi_a[4], roi_b[4];  // the views' rectangles (x, y, width, height)
};

// luma (width x height, packed) = (r + 2g + b + 2) / 4 of an RGBA view.
void launch_seam_luma(const DeviceImage& view, uint8_t* luma, cudaStream_t stream);
// cost (rows x cols in the seam's frame) of every box pixel; centre (box-sized) < 0 outside
// the overlap. previous lumas may equal the current ones (no motion). diff and across (rows x
// cols ints, scratch) hold the clearance term's sums; nullptr or a radius of 0: no clearance.
// counts (3 ints, zeroed by the caller before; may be nullptr): += the overlap's pixels and those
// at or below stitch::seam::kDark in view a and in view b (stitch::seam::view_blank).
void launch_seam_cost(const SeamPairGeometry& pair, const DeviceImage& view_a, const DeviceImage& view_b,
                      const uint8_t* luma_a, const uint8_t* luma_b, const uint8_t* previous_a,
                      const uint8_t* previous_b, const float* centre, const stitch::seam::Weights& weights,
                      float* cost, int* diff, int* across, int* counts, cudaStream_t stream);
// The consensus blend's mix levels of one pair (stitch::seam::mix_level over the (2 mix_radius
// + 1)^2 window of diff, the sums launch_seam_cost left when weights.mix_radius > 0; across:
// scratch), written as the max with what `mix` (label_width wide, zeroed per frame) holds; 255
// over the whole overlap when a view is blank (counts). The pair's own level then turns its cost
// into stitch::seam::crossing_cost: run it between launch_seam_cost and launch_seam_dp. With
// weights.label_hold > 0, levels (rows x cols bytes, scratch) and previous_labels (last frame's
// label map, label_width wide; nullptr: none yet), the cost then gains stitch::seam::view_switch_cost.
void launch_seam_mix(const SeamPairGeometry& pair, const int* diff, int* across, const float* centre,
                     const stitch::seam::Weights& weights, const int* counts, float* cost, uint8_t* mix,
                     int label_width, uint8_t* levels, const uint8_t* previous_labels, cudaStream_t stream);
// One pair's dynamic programming: the least-energy path through cost (rows x cols);
// previous == nullptr: no pull; steps: rows x cols scratch; path: rows.
struct SeamDpJob {
  const float* cost;
  int rows, cols;
  const int* previous;
  int8_t* steps;
  int* path;
  float* edge;  // 2 cols + 2 floats of scratch: where the two sweeps meet (seam_kernels.cu)
};
// All pairs at once, one block each (a block sweeps its rows one after the other); jobs is in
// device memory; max_cols sizes the shared rows.
// A pair whose previous path still costs within hold per row of the best keeps it
// (stitch::seam::keep_previous).
void launch_seam_dp(const SeamDpJob* jobs, int n_jobs, int max_cols, float stability, float hold, cudaStream_t stream);
// Overlap pixels labelled a or b: a before the path, b from it on; all the other view's when one
// is blank (counts, as launch_seam_cost left them; nullptr: never).
void launch_seam_labels(uint8_t* labels, int label_width, const SeamPairGeometry& pair, const float* centre,
                        const int* path, const int* counts, cudaStream_t stream);

}  // namespace stitch_cuda
