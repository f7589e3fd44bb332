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
  };
  const std::vector<Pair>& pairs() const { return pairs_; }
  const SeamSettings& settings() const { return settings_; }
  const std::vector<uint8_t>& labels() const { return labels_; }  // the last find()'s

 private:
  void cut(Pair& p, const std::vector<ImageView>& warped);
  seam::Weights weights() const {
    return {settings_.difference_weight, settings_.edge_weight, settings_.motion_weight, settings_.stability,
            settings_.hold, settings_.clearance_weight, settings_.clearance_radius};
  }

  SeamSettings settings_;
  std::vector<ViewPlacement> views_;
  int width_ = 0, height_ = 0;
  std::vector<Pair> pairs_;
  std::vector<std::vector<uint8_t>> luma_, previous_luma_;  // per view, roi-sized
  std::vector<uint8_t> labels_;
  uint64_t nearest_mask_ = ~uint64_t(0);
  std::vector<uint8_t> nearest_;
};

}  // namespace stitch
