// Launchers of the color kernels (definitions in color_kernels.cu). Checked; throw on error.
#pragma once
#include <cuda_runtime_api.h>
#include <stddef.h>
#include <stdint.h>

namespace stitch_cuda {

// In place on an RGBA device image: c' = lut[c](round(sum_k in_k M[k][c])), alpha untouched.
// M: row-major 3x3 (nullptr: identity); lut: device pointer to 3 x 256 bytes (nullptr: none).
void launch_color_apply(uint8_t* data, size_t pitch, int width, int height, const float* M,
                        const uint8_t* lut, cudaStream_t stream);

// Several views in one launch (gridDim.z = view), each with its own matrix, one LUT for all.
constexpr int kColorApplyMaxViews = 16;
struct ColorApplyView {
  uint8_t* data;
  size_t pitch;
  int width, height;
  int has_matrix;  // 0: identity
  float M[9];      // row-major: out_c = sum_k in_k M[3k + c]
};
struct ColorApplyBatch {
  ColorApplyView views[kColorApplyMaxViews];
  int count;
  int highlight_knee;  // < 255: stitch::highlight_blend above it (255: off)
};
void launch_color_apply_batch(const ColorApplyBatch& batch, const uint8_t* lut, cudaStream_t stream);

// out[k] = RGB of the pixel at (xy[2k], xy[2k+1]); xy and out are device pointers.
void launch_gather(const uint8_t* data, size_t pitch, const int32_t* xy, int count, uint8_t* out,
                   cudaStream_t stream);

// ---- The per-frame reductions of the color stage (stitch::ColorOps::reduce) ----

// Per geometry, on the device: pair k's samples are pair_samples[first, first + count), each
// (ax, ay, bx, by); view i's balance grid is grid_samples[first, first + count), each (x, y).
struct ColorSamplePair {
  int32_t a, b, first, count;
};
struct ColorSampleGrid {
  int32_t first, count;
};

// Per frame, on the device: where each view is (data nullptr: missing view), and the matrix
// its balance-grid pixels go through before binning.
struct ColorFrameView {
  const uint8_t* data;
  uint64_t pitch;
  int32_t width, height;
  double balance_matrix[9];  // row-major: level_c = round(sum_k p_k M[3k + c])
};

// pair_match values: which side of the pair is histogram-specified onto the other.
enum : int32_t { kColorMatchNone = 0, kColorMatchAOntoB = 1, kColorMatchBOntoA = 2 };

// One pair's results (the layout the host downloads). Sums over usable samples, in 8-bit
// units: count, sum a a^T, sum b b^T, sum a b^T, sum s lut(s)^T for the matched side s
// (row-major), then the per-channel histograms of both sides (channel-major, 256 bins each).
struct ColorPairResult {
  unsigned long long count;
  unsigned long long aa[9], bb[9], ab[9], matched[9];
  // The static/aligned mask (stitch::PairStats): in-view samples, those that moved this
  // frame, those not yet static, the misaligned ones, the restart flag, raw RGB sums.
  unsigned long long inview, moved_now, moving, misaligned, global_change;
  unsigned long long sum_a[3], sum_b[3];
  unsigned int hist_a[3 * 256], hist_b[3 * 256];
  unsigned int blocks_done, unused;  // the mask-and-moments blocks of the pair that finished
};

struct ColorReduceArgs {
  const ColorFrameView* views;  // view_count entries
  int view_count;
  const ColorSamplePair* pairs;  // pair_count entries
  const int4* pair_samples;
  int pair_count, max_pair_samples;
  const int32_t* pair_match;  // pair_count entries, kColorMatch*
  const ColorSampleGrid* grids;  // view_count entries
  const int2* grid_samples;
  int max_grid_samples;
  int dark_level, bright_level;  // usable: not every channel <= dark, no channel >= bright
  int want_pairs, want_match, want_balance;
  // The mask: per pair sample (indexed like pair_samples) the pixels of the last frame, the
  // frames since it last moved, whether it moved now, and whether it goes into the fit.
  uchar4* prev_a;
  uchar4* prev_b;
  uint8_t* age;
  uint8_t* moved;
  uint8_t* use;
  int fresh;  // no motion history: every in-view sample counts as static
  int static_mask, motion_threshold, static_frames, align_tolerance;
  ColorPairResult* pair_results;  // pair_count entries, zeroed before the launch
  unsigned int* balance_results;  // view_count x 3 x 256, zeroed before the launch
  uint8_t* match_luts;            // scratch: pair_count x 3 x 256
  // Set by launch_color_reduce.
  int motion_rows, motion_per_block, balance_per_block, mask_per_block, matched_per_block;
};

// Three launches, in stream order: the mask's motion pass with the balance histograms beside
// it; the rest of the mask with the pair moments and histograms, the last block of each pair
// building its histogram-specification LUTs on the device (256 entries per channel, where
// building them on the host would cost a second round trip); the matched moments. The
// reductions are latency-bound gathers of a few thousand samples, so fewer launches and more
// blocks, not bandwidth, is what makes them fast. The results are complete once the stream reaches the next operation, so
// the caller downloads them (a few KB) and synchronises once.
void launch_color_reduce(const ColorReduceArgs& args, cudaStream_t stream);

}  // namespace stitch_cuda
