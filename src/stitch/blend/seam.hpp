// Seam placement for the multiband blender: in every overlap of two views, a path of least
// cost by dynamic programming, where the cost is what a seam through the pixel would show
// (the views' color difference, strong edges, and motion since the last frame), plus a pull
// towards the previous frame's path so that the seam does not jump from frame to frame.
// The result is a label map (each output pixel to one view) for MultibandBlender::set_labels.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "stitch/blend/seam_math.hpp"
#include "stitch/image.hpp"
#include "stitch/warp/geometry.hpp"

namespace stitch {

enum class SeamMode { None, DynamicProgramming };

struct SeamSettings {
  float difference_weight = 1.f;  // per level of |view a - view b| (mean over r, g, b)
  float edge_weight = 0.5f;       // per luma level of the views' gradients (a seam along an edge shows)
  float motion_weight = 2.f;      // per luma level of change since the last frame, either view
  float centre_weight = 8.f;      // at the overlap's border; 0 at its middle (keeps the seam off the borders)
  float stability = 2.f;          // per pixel the path moves away from the last frame's path, per row
  float hold = 1.f;               // per row: the new path must be this much cheaper than last frame's
                                  // path is now, or that one is kept (seam_math.hpp keep_previous)
  float clearance_weight = 0.f;   // per level of the views' mean difference within clearance_radius (0: off;
                                  // 4 measured in BENCHMARKS.md "Parallax seams": not a clear win)
  int clearance_radius = 16;      // px: about the reach of multiband's coarse bands (seam_math.hpp
                                  // clearance_cost); 0 turns the term off
  // The consensus blend (mode=weighted with a seam; seam_math.hpp mix_level): per pixel of an
  // overlap, how much the seam's view replaces the weighted mean, from the views' mean
  // |dr|+|dg|+|db| over the (2 mix_radius + 1)^2 window: none at or below agree_level, all at or
  // above disagree_level. mix_radius 0: no mix map (multiband ignores it).
  int mix_radius = 4;
  int agree_level = 12;
  int disagree_level = 30;
  // Where the views disagree, a seam point costs crossing_weight at the overlap's border and twice
  // that in its middle instead of its per-pixel cost (seam_math.hpp crossing_cost): a seam that
  // must cross a near object and its parallax copy crosses at the border, where the least of the
  // object shows twice. 0: off (the default: on the rendered parallax rigs 64 cut the ghost ratio
  // a little and raised flicker by up to 18 points, BENCHMARKS.md). Needs mix_radius > 0.
  float crossing_weight = 0.f;
  // The temporal hold of the view choice (seam_math.hpp view_switch_cost): a cut that gives a pixel
  // of full disagreement the other view than last frame costs label_hold more (per row of the seam,
  // so a whole object's row switched costs ~its width x label_hold). 0: off (the default). At 4 it
  // cut the static-pixel flicker on the rendered parallax rigs (worst +17% -> +10%) but holds the
  // cut through an object that moves onto the seam (Seam.HoldsStillUntilSomethingCrossesIt fails)
  // and moved the ghost ratio -0.05..+0.04; holding only last frame's disagreement keeps that test
  // but loses the flicker gain (BENCHMARKS.md "Parallax: the view choice held over time").
  float label_hold = 0.f;
  // Not an option: giving each connected blob of disagreement (a near object and its parallax
  // copy) one view whole, held from frame to frame, was measured and lost (BENCHMARKS.md
  // "Parallax: a per-object view choice"). On a ring the left view shows a near object further
  // right than the right view does, so this cut (a before it, b after) drops a strip of the
  // object and shows none of it twice: the object drawn stays inside its true silhouette, while
  // one whole view's copy lies half the disparity off it (more flicker, equal ghost ratio).
};

class SeamFinder {
 public:
  explicit SeamFinder(const SeamSettings& settings = {}) : settings_(settings) {}
  // Finds the overlapping pairs and forgets the previous frame's seams.
  void prepare(const std::vector<ViewPlacement>& views, int width, int height);
  // Labels (width*height, kNoView where no view covers) for this frame's warped views (host
  // memory, roi-sized; empty = missing): the nearest-view labels, with every overlap of two
  // present views cut along its seam.
  const std::vector<uint8_t>& find(const std::vector<ImageView>& warped);
  // The seam of each pair (a's side is left of / above it), -1 where the line has no overlap.
  struct Pair {
    int a = 0, b = 0;      // views; a lies left of (vertical seam) or above b
    bool vertical = true;  // the seam runs top to bottom (one x per row)
    Rect box;              // bounding box of the overlap, in output pixels
    std::vector<float> centre_cost;  // box-sized: centre_weight · (how far from the overlap's middle); < 0: outside
    std::vector<int> path, previous_path;
    // find()'s per-frame work, kept between frames (no allocation, no page faults per frame):
    // costs in the seam's frame, the views' colour differences and their window sums across the
    // seam, the DP's steps, the dark-pixel counts per row, and whether a view is blank here.
    std::vector<float> costs;
    std::vector<int> diff, across, row_cells, row_dark_a, row_dark_b;
    std::vector<uint8_t> levels;  // the mix levels, for the view-switch cost (label_hold > 0)
    std::vector<int8_t> step;
    bool blank_a = false, blank_b = false;
  };
  const std::vector<Pair>& pairs() const { return pairs_; }
  const SeamSettings& settings() const { return settings_; }
  const std::vector<uint8_t>& labels() const { return labels_; }  // the last find()'s
  // The last find()'s mix map (width*height, 0..255; empty when mix_radius is 0): how much of
  // each pixel is its label's view rather than the weighted mean (apply_seam_mix).
  const std::vector<uint8_t>& mix() const { return mix_; }

 private:
  // The phases of find() over every cut pair at once (rows of all pairs in one parallel loop).
  void cut_all(const std::vector<int>& cut, const std::vector<ImageView>& warped);
  seam::Weights weights() const {
    return {settings_.difference_weight, settings_.edge_weight, settings_.motion_weight, settings_.stability,
            settings_.hold, settings_.clearance_weight, settings_.clearance_radius,
            settings_.mix_radius, settings_.agree_level, settings_.disagree_level, settings_.crossing_weight,
            settings_.centre_weight, settings_.label_hold};
  }

  SeamSettings settings_;
  std::vector<ViewPlacement> views_;
  int width_ = 0, height_ = 0;
  std::vector<Pair> pairs_;
  std::vector<std::vector<uint8_t>> luma_, previous_luma_;  // per view, roi-sized
  std::vector<uint8_t> labels_, mix_, previous_labels_;  // previous_labels_: last find()'s labels
  uint64_t nearest_mask_ = ~uint64_t(0);
  std::vector<uint8_t> nearest_;
  // Per view, disjoint rectangles (roi coordinates) holding every pixel whose luma a cut reads
  // (each pair's box grown by 1, clipped to the roi): the luma is computed there only.
  std::vector<std::vector<Rect>> luma_rects_;
  bool boxes_disjoint_ = true;  // no two pairs' boxes share a pixel: their writes may run together
  bool labels_fresh_ = false;   // labels_/mix_ hold nearest_/0 outside the pairs' boxes
};

// The least-energy path through costs (rows x cols; one column per row, moving at most one column
// a row; seam_math.hpp dp_cell with the pull towards `previous`, nullptr: none), found from both
// ends (seam_math.hpp dp_meeting_row) in the order the CUDA sweeps take; or `previous` itself
// while it holds (keep_previous).
void seam_path(const std::vector<float>& costs, int rows, int cols, const int* previous, const seam::Weights& w,
               std::vector<int>& path);

// The consensus blend on the CPU: `out` holds the weighted mean of `warped` (placed at views'
// rois); every pixel whose mix level m > 0 becomes mix_value(mean, view[label], m).
void apply_seam_mix(const std::vector<ViewPlacement>& views, const std::vector<ImageView>& warped,
                    const std::vector<uint8_t>& labels, const std::vector<uint8_t>& mix, const ImageView& out);

}  // namespace stitch
