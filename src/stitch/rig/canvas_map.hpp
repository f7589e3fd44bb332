// Camera pixel <-> canvas pixel for every projection (planar homography, or cylindrical /
// spherical through K and R), and the canvas footprint of a camera. Host side; the device
// side evaluates the same projection_math.hpp.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace stitch {

struct CameraCanvasMap {
  Projection kind = Projection::Plane;
  Eigen::Matrix3d H = Eigen::Matrix3d::Identity(), H_inv = Eigen::Matrix3d::Identity();  // plane
  Eigen::Matrix3d KRt = Eigen::Matrix3d::Identity();   // non-planar: rig ray -> camera pixel (homogeneous)
  Eigen::Matrix3d RKinv = Eigen::Matrix3d::Identity(); // non-planar: camera pixel -> rig ray
  double scale = 1, origin_x = 0, origin_y = 0;
  double period = 0;  // canvas pixels per 360 degrees (non-planar)
  // The camera's lens (issue 15): pixels are raw camera pixels; with a lens to_canvas undistorts
  // (iteratively) and to_camera distorts. Pinhole cameras keep the plain mappings above.
  Camera camera;
  bool lens = false;

  // False where the mapping has no answer (behind the camera or the canvas plane).
  bool to_canvas(const Eigen::Vector2d& pixel, Eigen::Vector2d& canvas) const;
  bool to_camera(const Eigen::Vector2d& canvas, Eigen::Vector2d& pixel) const;
};

// The map of camera `cam` of a calibrated rig (planar: needs the homography). Pixels are raw
// camera pixels (the lens applied).
CameraCanvasMap camera_canvas_map(const Rig& rig, int cam);

// Canvas polygon around the camera's image (planar: its four corners; non-planar: its border
// sampled, x unwrapped so the polygon is continuous, possibly reaching outside [0, width) on
// a wrapping canvas). Throws RigError when a cylindrical camera sees a pole.
std::vector<Eigen::Vector2d> camera_canvas_outline(const Rig& rig, int cam);

// Cubemap canvases (issue 15): which cells of a grid over the 3 x 2 face layout (cells_per_face
// a face side) camera `cam` sees. A view's footprint there can fall apart over several faces, so
// its outline is the bounding box of its cells (a margin of one cell), and overlaps count cells.
struct CubeCoverage {
  int cols = 0, rows = 0;  // 3 and 2 times cells_per_face
  double cell = 0;         // a cell's side, canvas pixels
  double x0 = 0, y0 = 0;   // canvas position of the grid's top-left corner
  std::vector<uint8_t> seen;
  bool at(int i, int j) const { return seen[std::size_t(j) * cols + i] != 0; }
};
CubeCoverage cube_coverage(const Rig& rig, int cam, int cells_per_face = 32);
// The canvas rectangle (4 corners, clockwise) of the cells set in `seen` (cols x rows of the
// coverage grid), a cell wider all round and clipped to the layout; empty when none is set.
std::vector<Eigen::Vector2d> cube_cells_box(const CubeCoverage& grid, const std::vector<uint8_t>& seen);

// rig_layout_canvas() of a non-planar rig (see rig.hpp).
void layout_projected_canvas(Rig& rig);

}  // namespace stitch
