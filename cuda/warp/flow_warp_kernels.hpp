// Launchers of the flow-warp kernels (stitchflowwarp on the GPU). Every overlapping pair of
// views is one entry of a FlowPairDevice array in device memory; the kernels run over all
// pairs (and both flow directions) in one launch, gridDim.z indexing them. Checked; throw.
#pragma once
#include <cuda_runtime_api.h>
#include <stddef.h>
#include <stdint.h>

#include "../blend/blend_kernels.hpp"

namespace stitch_cuda {

constexpr int kMaxFlowPairs = 128;  // every pair of 16 views

// One overlapping pair's geometry and its working images, all work_w x work_h, densely
// packed (pitch = width x element size). Index 0 is view a, 1 is view b; flow[0] is a->b.
struct FlowPairDevice {
  int a, b;
  int rect_x, rect_y, rect_w, rect_h;  // output pixels
  int work_w, work_h;                  // flow resolution
  uint8_t* gray[2];       // this frame's overlap of each view (gaps filled from the other)
  uint8_t* prev_gray[2];  // last frame's
  uint8_t* valid;         // bit k: view k covers the pixel
  float* flow[2];         // (u, v) pairs: refined flow, kept as next frame's history
  float* prev_flow[2];    // last frame's refined flow
  float* work[2];         // (u, v) pairs: scratch
  float* work2[2];        // (u, v) pairs: scratch
  float* confidence[2];   // forward-backward confidence
  float* change[2];       // change of each view's gray since last frame (then blurred)
  float* change2[2];      // scratch
  float* gate[2];         // matching-cost improvement of the flow (flow_gate_math.hpp), blurred
  float* gate2[2];        // scratch
};

// Bits per pair: this frame's state. Pairs are indexed 0..n_pairs-1 (< kMaxFlowPairs).
struct FlowPairMask {
  unsigned long long bits[kMaxFlowPairs / 64];
  __host__ __device__ bool test(int i) const { return (bits[i >> 6] >> (i & 63)) & 1ull; }
};

// Gray overlap images of both views of every pair in `active`, sampled from the camera
// frames at flow resolution; where one view has no pixels it gets the other's.
void launch_overlap_gray(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& active,
                         const ViewGeometry* views, const DeviceImage* frames, int n_views, cudaStream_t stream);

// confidence[d] = exp(-|flow[d](p) + flow[1-d](p + flow[d](p))|^2 / tau^2), and gate[d] = the
// flow's matching improvement |A - B| - |A - B(p + flow[d](p))| (A = gray[d], B = gray[1-d]).
void launch_flow_confidence(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h,
                            const FlowPairMask& active, float tau, cudaStream_t stream);

// Separable Gaussian (reflect-101 borders, as OpenCV's GaussianBlur) of both work fields
// (target 0, 2 channels, through work2), both change images (target 1, 1 channel, through
// change2) or both gate images (target 2, 1 channel, through gate2). taps: 2 * radius + 1
// weights (radius <= 12).
void launch_pair_blur(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& active,
                      int target, const float* taps, int radius, cudaStream_t stream);

// work[d] = flow[d] * confidence[d] * flow_gate::gate(gate[d]) (the blurred improvement);
// without `use_gate`, flow[d] * confidence[d].
void launch_flow_gate(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& active,
                      bool use_gate, cudaStream_t stream);

// change[k] = gray[k] - prev_gray[k] (float), for the pairs in `history`.
void launch_gray_change(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& history,
                        cudaStream_t stream);

// flow[d] = keep * prev_flow[d] + (1 - keep) * work[d], keep = smoothing * stillness (0 for
// pairs without history). Accumulates per pair into stats[kFlowStats * pair]: sum of
// |flow[0]|, the count of pixels both views cover, of those whose confidence[0] > 0.5, and
// the sums of the matching error without and with flow[0] (flow_gate::match_error).
constexpr int kFlowStats = 5;
void launch_flow_temporal(const FlowPairDevice* pairs, int n_pairs, int max_w, int max_h, const FlowPairMask& active,
                          const FlowPairMask& history, float smoothing, float* stats, cudaStream_t stream);

// Every present view warped into its rectangle: output pixel p samples camera v at
// H_v(p + d(p)), d = sum over v's active pairs of gains[pair] * theta_other(p) * flow_{other->v}(p) / scale
// (bilinear from the flow resolution). frames[v].data == nullptr leaves dst[v] untouched.
void launch_flow_warp_views(const ViewGeometry* views, const DeviceImage* frames, const DeviceImage* dst, int n_views,
                            const FlowPairDevice* pairs, int n_pairs,
                            const FlowPairMask& active, float inv_scale, const float* gains, cudaStream_t stream);

}  // namespace stitch_cuda
