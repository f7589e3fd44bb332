// Launchers of the dense-flow kernels (pyramidal dense Lucas-Kanade, see flow_math.cuh);
// plain C++ declarations, definitions in flow_kernels.cu. Every launch covers a whole batch of
// image pairs (gridDim.z = image or pair index), is enqueued on the given stream and is
// checked; errors throw std::runtime_error.
#pragma once
#include <cuda_runtime_api.h>
#include <stddef.h>
#include <stdint.h>

namespace stitch_cuda {

constexpr int kMaxFlowTasks = 32;

// One image of one pyramid step: dst (dst_w x dst_h) = pyrDown(src). Pitches in elements.
// dst == nullptr: no image is written (the first step still counts the statistics of src).
struct FlowPyramidImage {
  const void* src = nullptr;  // uint8 for the first step, float above
  float* dst = nullptr;
  int src_pitch = 0, dst_pitch = 0;
  int src_w = 0, src_h = 0, dst_w = 0, dst_h = 0;
};

// Number of per-block partial sums the first pyramid step writes per image (the statistics
// buffer holds 2 * n_pairs * this many uint32 pairs).
int flow_stats_blocks_per_image(int max_dst_w, int max_dst_h);

// Level 0 (uint8) -> level 1 (float) of 2 * n_pairs images (image 2t = from, 2t + 1 = to of
// pair t), and per-block sums of the level-0 pixels and their squares into `stats`.
void launch_flow_pyramid_first(int n_pairs, const FlowPyramidImage* images, uint32_t* stats, int stats_blocks,
                               cudaStream_t stream);

// flat[t] = 1 when the from or the to image of pair t has a standard deviation below one grey
// level (as the CPU flows decide), else 0. pixels[t] = width * height of pair t.
void launch_flow_flatness(int n_pairs, const uint32_t* stats, int stats_blocks, const int* pixels, int* flat,
                          cudaStream_t stream);

// One float -> float pyramid step of 2 * n_pairs images (dst == nullptr: skipped).
void launch_flow_pyramid(int n_pairs, const FlowPyramidImage* images, cudaStream_t stream);

// Where a pass reads the flow it refines.
enum FlowSource : int {
  kFlowSkip = 0,      // the pair has no work at this level
  kFlowZero = 1,      // start from zero (coarsest level)
  kFlowSeed = 2,      // start from a full-resolution field (src), averaged down by seed_step
  kFlowUpsample = 3,  // start from the coarser level's result (src), doubled
  kFlowCurrent = 4,   // refine this level's previous pass (src)
};

// One pair at one pyramid level for one Lucas-Kanade pass. Flows are interleaved (u, v)
// floats; pitches in elements (float2 for flows).
struct FlowLevelTask {
  const void* from = nullptr;  // level image: uint8 at level 0, float above
  const void* to = nullptr;
  const float* src = nullptr;
  float* dst = nullptr;
  int image_pitch = 0;
  int src_pitch = 0, dst_pitch = 0;
  int width = 0, height = 0;
  int src_w = 0, src_h = 0;  // of src (a coarser level or the full-resolution seed)
  int source = kFlowSkip;
  int seed_step = 1;         // 2^level for kFlowSeed
};

struct FlowIterationSettings {
  float lambda = 1.f;    // Tikhonov weight (grey^2 per px^2): flat windows keep their flow
  float max_step = 1.f;  // largest change of one pass, px at this level
  int level0 = 0;        // images are the uint8 level 0 (else float pyramid levels)
  int final_pass = 0;    // dst is the caller's flow: pairs marked flat get exactly zero
  const int* flat = nullptr;
};

// The starting flow of the tasks whose source is kFlowSeed (the caller's full-resolution field
// averaged down by seed_step, flow::seed_flow_at) written once to their dst at the level's size;
// other tasks are skipped. The pass that follows reads it as kFlowCurrent: the same values, but
// computed once per level pixel instead of for every pixel of every iteration block's window
// and halo (a (step + 1)^2 window each: ~100 us of a 1 ms chain at level 5 on an H100).
void launch_flow_seed(int n_pairs, const FlowLevelTask* tasks, int max_w, int max_h, cudaStream_t stream);

// One dense Lucas-Kanade pass of n_pairs pairs at one level: every pixel's flow becomes the
// solution of its Gaussian window's linearised constraints (flow_math.cuh), kept inside the
// image.
void launch_flow_iteration(int n_pairs, const FlowLevelTask* tasks, const FlowIterationSettings& settings,
                           cudaStream_t stream);

}  // namespace stitch_cuda
