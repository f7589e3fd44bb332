// The debug view: what stitchblend did, drawn onto the panorama so a user can see why a seam
// looks the way it does: each view's outline (its own color), the overlaps (tinted), the seams
// (where the blend's labels change view) and what the flow did in each overlap (rectangle,
// heat color by mean magnitude, and the figures).
#pragma once
#include <Eigen/Core>
#include <Eigen/LU>
#include <cstdint>
#include <vector>

#include "stitch/image.hpp"
#include "stitch/warp/flow_warper.hpp"
#include "stitch/warp/geometry.hpp"

namespace stitch {

enum DebugFlags : unsigned {
  kDebugOutlines = 1u << 0,
  kDebugOverlaps = 1u << 1,
  kDebugSeams = 1u << 2,
  kDebugFlow = 1u << 3,
};

struct DebugScene {
  std::vector<ViewPlacement> views;  // in output pixels
  // Per pixel of the label grid (label_width x label_height): the view it shows (kNoView: none);
  // label_to_output maps label-grid pixels to output pixels (identity, or the crop/scale).
  const uint8_t* labels = nullptr;
  int label_width = 0, label_height = 0;
  Eigen::Matrix3d label_to_output = Eigen::Matrix3d::Identity();
  // Flow pairs in canvas pixels (stitchflowwarp's last frame), and canvas -> output.
  std::vector<FlowPairStats> flow;
  Eigen::Matrix3d canvas_to_output = Eigen::Matrix3d::Identity();
};

// Draws the `flags` layers onto `out` (RGBA, host memory).
void draw_debug_view(const ImageView& out, unsigned flags, const DebugScene& scene);

// A distinct, saturated color for view i (RGB).
void debug_view_color(int i, uint8_t rgb[3]);

}  // namespace stitch
