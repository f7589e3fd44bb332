// Where each view lands in the output panorama: the output frame is the canvas, cropped
// and scaled; each view covers a rectangle (ROI) of it.
#pragma once

#include <Eigen/Core>
#include <vector>

#include "stitch/rig/projection_math.hpp"
#include "stitch/image.hpp"
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
  // Planar: output pixel -> camera pixel (homography). Non-planar: rig ray -> camera pixel
  // (K R^T), applied to the ray of the output pixel's canvas angles (output_to_angles).
  Eigen::Matrix3d output_to_camera;
  int camera_width = 0, camera_height = 0;
  Projection projection = Projection::Plane;
  // Non-planar: a = [0] x + [1], b = [2] y + [3] (output pixel -> canvas angles, radians).
  Eigen::Vector4d output_to_angles = Eigen::Vector4d::Zero();
  // A view across the 360-degree wrap (its roi spans the whole width): the output width, and
  // the columns it can reach with a margin, unwrapped: span_x0 in [0, wrap_width), span_x1
  // beyond wrap_width; column x < span_x0 stands for x + wrap_width.
  // Lets the kernels skip the columns it cannot see. wrap_width = 0 for every other view.
  int wrap_width = 0;
  double span_x0 = 0, span_x1 = 0;
  // The camera's lens (issue 15). A view with one (stitch_projection::has_lens) maps through
  // canvas_to_lens_camera: output_to_camera then yields the camera-frame ray (planar:
  // K^-1 (output -> ideal pixel); non-planar: R^T), and the lens gives the raw pixel.
  stitch_projection::LensParams<double> lens{};
  bool has_lens() const { return stitch_projection::has_lens(lens); }
  // An output smaller than the camera shows it sampled sparsely: the frame is then read from a
  // copy averaged over 2x2 pixels `level` times (halve_frame), as a mipmap is, so that fine
  // detail does not alias. camera_width/height and the mapping are the reduced frame's;
  // frame_width/height the camera's own (what the frames arrive at).
  int level = 0;
  int frame_width = 0, frame_height = 0;
};

// Camera pixel (u, v) of output pixel (x, y); false behind the camera (or the canvas plane).
inline bool view_to_camera(const ViewPlacement& v, double x, double y, double& u, double& w) {
  const Eigen::Matrix3d& M = v.output_to_camera;
  if (v.has_lens()) {
    const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> m = M;
    return stitch_projection::canvas_to_lens_camera(static_cast<int>(v.projection), v.output_to_angles.data(), m.data(),
                                                    v.lens, x, y, u, w);
  }
  if (v.projection == Projection::Plane) {
    const double Z = M(2, 0) * x + M(2, 1) * y + M(2, 2);
    if (!(Z > 1e-12)) return false;
    u = (M(0, 0) * x + M(0, 1) * y + M(0, 2)) / Z;
    w = (M(1, 0) * x + M(1, 1) * y + M(1, 2)) / Z;
    return true;
  }
  const Eigen::Vector4d& A = v.output_to_angles;
  Eigen::Vector3d ray;
  stitch_projection::angles_to_ray(static_cast<int>(v.projection), A[0] * x + A[1], A[2] * y + A[3], ray.x(),
                                   ray.y(), ray.z());
  const Eigen::Vector3d c = M * ray;
  if (!(c.z() > 1e-9)) return false;
  u = c.x() / c.z();
  w = c.y() / c.z();
  return true;
}

// The blend weight of camera pixel (u, v) of the view: the position tent, or with a lens
// lens_position_weight (the image circle). 0 outside the image.
float view_position_weight(const ViewPlacement& v, double u, double w);

// Output size and canvas->output transform. requested_w/h = 0 keep the canvas (or crop) size;
// one of them set keeps the aspect ratio; both set fit the canvas inside, centred.
// Sizes are rounded to even numbers so that 4:2:0 encoders accept them, except with exact_size
// and both sides requested: a size downstream fixed (a capsfilter's 1001x333) is made as it is.
OutputGeometry plan_output(const Rig& rig, int requested_w, int requested_h, CropMode crop, bool exact_size = false);

// The canvas itself, 1:1 (padded to even sizes): where stitchflowwarp pre-warps the views.
inline OutputGeometry canvas_geometry(const Rig& rig) { return plan_output(rig, 0, 0, CropMode::None); }

// Largest axis-aligned rectangle of the canvas that every pixel of is covered by a view.
Rect largest_covered_rect(const Rig& rig);

std::vector<ViewPlacement> place_views(const Rig& rig, const OutputGeometry& out);

// Sets each view's level (ViewPlacement::level) from how far apart the output reads the camera
// (the median spacing over the view: level L from 1.32 * 2^L camera pixels) and maps the view
// onto the reduced frame. Views read up to ~2.6 px apart keep level 0.
void prefilter_sparse_views(std::vector<ViewPlacement>& views);

// One level down: dst ((w + 1) / 2 x (h + 1) / 2) = the rounded mean of each 2x2 block of src
// (the last row/column repeated at odd sizes). The CUDA kernel computes the same bytes.
void halve_frame(const ImageView& src, const ImageView& dst);

// The frames the views read: each frame halved `level` times (halve_frame) where its view has
// a level, the frame itself elsewhere. Owns the reduced copies, reused every frame.
class FrameReducer {
 public:
  const std::vector<ImageView>& reduce(const std::vector<ViewPlacement>& views, const std::vector<ImageView>& frames);

 private:
  std::vector<std::vector<std::vector<uint8_t>>> levels_;  // per view, per level
  std::vector<ImageView> out_;
};

// An exception naming frame i when its size is not the camera's (frame_width x frame_height).
void check_frame_sizes(const std::vector<ViewPlacement>& views, const std::vector<ImageView>& frames);

}  // namespace stitch
