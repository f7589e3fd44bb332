// Where each view lands in the output panorama: the output frame is the canvas, cropped
// and scaled; each view covers a rectangle (ROI) of it.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace stitch {

struct Rect {
  int x = 0, y = 0, width = 0, height = 0;
  bool empty() const { return width <= 0 || height <= 0; }
};

enum class CropMode { None, Auto };

struct OutputGeometry {
  int width = 0, height = 0;
  Eigen::Matrix3d canvas_to_output = Eigen::Matrix3d::Identity();
};

struct ViewPlacement {
  Rect roi;                     // in output pixels; empty when the view is not visible
  Eigen::Matrix3d output_to_camera;  // output pixel -> camera pixel
  int camera_width = 0, camera_height = 0;
};

// Output size and canvas->output transform. requested_w/h = 0 keep the canvas (or crop) size;
// one of them set keeps the aspect ratio; both set fit the canvas inside, centred.
// Sizes are rounded to even numbers so that 4:2:0 encoders accept them.
OutputGeometry plan_output(const Rig& rig, int requested_w, int requested_h, CropMode crop);

// The canvas itself, 1:1 (padded to even sizes): where stitchflowwarp pre-warps the views.
inline OutputGeometry canvas_geometry(const Rig& rig) { return plan_output(rig, 0, 0, CropMode::None); }

// Largest axis-aligned rectangle of the canvas that every pixel of is covered by a view.
Rect largest_covered_rect(const Rig& rig);

std::vector<ViewPlacement> place_views(const Rig& rig, const OutputGeometry& out);

}  // namespace stitch
