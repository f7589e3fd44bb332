// The seam finder's per-pixel arithmetic, one definition for the CPU and the CUDA code. Products
// and sums are rounded one by one (no fused multiply-add on the device) so that both backends
// compute the same energies and so cut along the same paths.
#pragma once
#include <stdint.h>

#include "stitch/host_device.hpp"

namespace stitch {
namespace seam {

struct Weights {  // SeamSettings, for the kernels
  float difference, edge, motion, stability;
  float hold;  // per row: how much cheaper the new path must be to replace last frame's
  float clearance;     // per level of the views' mean difference within clearance_radius
  int clearance_radius;  // px; 0: no clearance term
  int mix_radius;        // px: the consensus blend's window; 0: no mix map
  int agree, disagree;   // window means of |dr|+|dg|+|db|: mix 0 at or below agree, 255 at or above disagree
  float crossing;        // cost of a seam point where the views disagree (mix 255) at the overlap's border;
                         // twice that at its middle (crossing_cost); 0: the per-pixel cost only
  float centre_max;      // the centre cost at the overlap's border (SeamSettings::centre_weight)
  float label_hold = 0.f;  // per pixel of full disagreement whose view the cut would change from last
                           // frame's (view_switch_cost); 0: off
};


constexpr float kOutside = 1e5f;  // a seam point outside the overlap: allowed, but never cheap

STITCH_HD float mul(float a, float b) {
#ifdef __CUDA_ARCH__
  return __fmul_rn(a, b);
#else
  return a * b;
#endif
}
STITCH_HD float add(float a, float b) {
#ifdef __CUDA_ARCH__
  return __fadd_rn(a, b);
#else
  return a + b;
#endif
}
STITCH_HD int absi(int v) { return v < 0 ? -v : v; }
STITCH_HD float div(float a, float b) {
#ifdef __CUDA_ARCH__
  return __fdiv_rn(a, b);
#else
  return a / b;
#endif
}

STITCH_HD uint8_t luma(const uint8_t* rgba) {
  return uint8_t((rgba[0] + 2 * rgba[1] + rgba[2] + 2) >> 2);
}

// Mean |a - b| over r, g, b: color, not luma (a magenta object on grey of the same luma shows).
STITCH_HD float color_difference(const uint8_t* a, const uint8_t* b) {
  return float(absi(a[0] - b[0]) + absi(a[1] - b[1]) + absi(a[2] - b[2])) / 3.f;
}

// What a seam through a pixel costs: the views' color difference there, their gradients (sum
// of |dx| + |dy| of each view's luma), the change since the last frame, and the centre cost.
STITCH_HD float pixel_cost(const Weights& w, float difference, int gradients, int motion, float centre) {
  return add(add(add(mul(w.difference, difference), mul(mul(w.edge, 0.25f), float(gradients))),
                 mul(w.motion, float(motion))),
             centre);
}

// |dr| + |dg| + |db| of two RGBA pixels: the integer the clearance term sums (exact on both
// backends, whatever the summation order).
STITCH_HD int color_difference_sum(const uint8_t* a, const uint8_t* b) {
  return absi(a[0] - b[0]) + absi(a[1] - b[1]) + absi(a[2] - b[2]);
}

// The clearance term: multiband's coarse bands mix the two views up to ~2^bands px from the
// cut, so a cut beside a near object (where the views disagree: the object in one, its
// parallax copy or the background in the other) leaks the object's colour into the background
// around it as a halo, and shows half of its copy. Adding the views' mean difference over the
// (2r+1)^2 window around each pixel keeps the cut that far from any disagreement: it goes
// around a near object, which then comes whole from one view. `sum` is the window's sum of
// color_difference_sum (pixels outside the overlap count 0).
STITCH_HD float clearance_cost(const Weights& w, int sum) {
  const int side = 2 * w.clearance_radius + 1;
  return mul(w.clearance, div(float(sum), float(3 * side * side)));
}

// The consensus blend (seam=dp with mode=weighted): where the two views agree, the weighted
// mean of both (sensor noise averages out, as the homography-only chain does); where they
// disagree (a near object in one, its parallax copy or the background in the other), the view
// the seam gives the pixel, so a near object comes whole from one view. `sum` is the window sum
// of color_difference_sum over (2 mix_radius + 1)^2 pixels (outside the overlap: 0). Integers
// only: the CPU and the device give the same level.
STITCH_HD int mix_level(const Weights& w, int sum) {
  const int side = 2 * w.mix_radius + 1, count = side * side;
  const int lo = w.agree * count, hi = w.disagree * count;
  if (sum <= lo) return 0;
  if (sum >= hi || hi <= lo) return 255;
  return int((long long)(sum - lo) * 255 / (hi - lo));
}

// Where the views disagree, crossing the disagreement is unavoidable only when a near object and
// its parallax copy fill the overlap from border to border; a cut through the middle of the pair
// then shows a d px strip of the object twice (d: the disparity), a cut at the overlap's border
// only what of the object lies beyond that border. The per-pixel difference says the opposite
// (it is lowest where the object overlaps its own copy, in the middle), so a cell of full
// disagreement (mix level m = 255) costs at least `crossing` at the border, rising to twice that
// at the middle; a cell of partial disagreement the blend of that and its per-pixel cost by m;
// never less than its per-pixel cost (what only one view shows stays dear). A seam that can go
// around the disagreement (agreement costs far less) still does: the object comes whole.
STITCH_HD float crossing_cost(const Weights& w, float cost, float centre, int m) {
  if (m <= 0 || w.crossing <= 0.f) return cost;
  const float border = w.centre_max > 0.f ? add(2.f, -div(centre, w.centre_max)) : 1.f;  // 1 at the border, 2 in the middle
  const float blob = mul(w.crossing, border);
  if (blob <= cost) return cost;  // never cheaper than the per-pixel cost: what only one view shows stays dear
  if (m >= 255) return blob;
  return add(mul(cost, div(float(255 - m), 255.f)), mul(blob, div(float(m), 255.f)));
}

// The temporal hold of the consensus blend's view choice: a seam point at column p of a row gives
// the row's cells c < p to view a and the others to b; each cell where the views disagree (level
// m > 0) that showed the other view last frame counts m / 255. `switched` = that row's sum of m
// over the cells before p labelled b last frame and the cells from p on labelled a (integers:
// exact on both backends, whatever the order). A disagreement blob (a near object and its
// parallax copy) keeps the view it had while it persists, instead of the cut moving through it.
STITCH_HD float view_switch_cost(const Weights& w, float cost, int switched) {
  if (w.label_hold <= 0.f || switched <= 0 || cost == kOutside) return cost;
  return add(cost, mul(w.label_hold, div(float(switched), 255.f)));
}

// A view that shows nothing in an overlap (an all-black or missing-signal camera: luma at or
// below kDark on nearly every pixel, while the other view is mostly not dark) counts as missing
// there: the other view wins the whole overlap. `dark_*`: the pair's overlap pixels at or below
// kDark in each view, `cells`: the overlap's pixels. Integers: the same decision on both backends.
constexpr int kDark = 16;
STITCH_HD bool view_blank(int dark_self, int dark_other, int cells) {
  return cells > 0 && 50LL * dark_self >= 49LL * cells && 2LL * dark_other < cells;
}

// One channel of the consensus blend: the weighted mean and the labelled view's value, mixed by
// level m (0..255), rounded.
STITCH_HD uint8_t mix_value(int weighted, int labelled, int m) {
  return uint8_t((weighted * (255 - m) + labelled * m + 127) / 255);
}

// One DP cell: the cheapest of the three cells above (ties: straight, then left), plus this
// cell's cost and the pull towards last frame's path (previous < 0: none). Returns the step.
STITCH_HD int dp_cell(const float* above, int c, int cols, bool first_row, float cost, float stability, int previous,
                      float& energy) {
  float best = 0.f;
  int step = 0;
  if (!first_row) {
    best = above[c];
    if (c > 0 && above[c - 1] < best) best = above[c - 1], step = -1;
    if (c + 1 < cols && above[c + 1] < best) best = above[c + 1], step = 1;
  }
  energy = add(best, cost);
  if (previous >= 0) energy = add(energy, mul(stability, float(absi(c - previous))));
  return step;
}

// dp_cell on an energy row that has a +inf cell on either side (above[-1], above[cols]) and is
// all zeros before a sweep's first row: no border or first-row tests (a +inf neighbour is never
// taken; three equal zeros go straight), the same energies and steps as dp_cell. The sweeps use
// it on both backends: on the device a row costs its instructions (the sweep is issue-bound).
STITCH_HD int dp_cell_padded(const float* above, int c, float cost, float stability, int previous, float& energy) {
  float best = above[c];
  int step = 0;
  const float left = above[c - 1], right = above[c + 1];
  if (left < best) best = left, step = -1;
  if (right < best) best = right, step = 1;
  energy = add(best, cost);
  if (previous >= 0) energy = add(energy, mul(stability, float(absi(c - previous))));
  return step;
}

// The path is found from both ends at once (bidirectional DP): rows [0, m) are swept down from
// the first row, rows [m, rows) up from the last, and the two sweeps meet between rows m - 1 and
// m. The least-energy path through the whole overlap is the least of `meet_cell` (the down
// sweep's energies above, the up sweep's at m, whose cost the up sweep already holds), so each
// sweep is half as long: the rows one after another are what a sweep's time is.
STITCH_HD int dp_meeting_row(int rows) { return rows / 2; }
STITCH_HD int meet_cell(const float* down, const float* up, int c, int cols, bool no_down, float& energy) {
  return dp_cell(down, c, cols, no_down, up[c], 0.f, -1, energy);
}

// Last frame's path is kept while its cost now is within `hold` per row of the best path's
// energy: the seam holds still until something crosses it (its cost then rises: motion,
// difference), instead of drifting with noise.
STITCH_HD bool keep_previous(float previous_cost, float best_energy, int rows, float hold) {
  return previous_cost <= add(best_energy, mul(hold, float(rows)));
}

}  // namespace seam
}  // namespace stitch
