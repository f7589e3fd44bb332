// The rig: camera models, camera->canvas homographies, canvas size; JSON I/O.
//
// Conventions (the "stitch-rig" JSON contract):
//  * pixel coordinates use the pixel-centre convention: pixel (0,0) is centred on (0,0);
//  * camera orientation R = Ry(yaw) * Rx(pitch) * Rz(roll) maps camera rays into the rig frame
//    (x right, y down, z forward); +yaw looks right, +pitch looks up, +roll turns the image
//    clockwise as seen by the viewer;
//  * "homography" maps camera pixels to canvas pixels (row-major, 9 numbers), planar rigs only;
//  * non-planar rigs ("cylindrical", "spherical") map canvas pixels to cameras through K and R:
//    canvas (X, Y) -> angles a = (X - origin_x) / scale, b = (Y - origin_y) / scale -> rig ray
//    (projection_math.hpp) -> camera ray R^T ray -> pixel K (R^T ray) (when in front, z > 0);
//  * "cubemap" (issue 15) the same with cube-face angles: 3 x 2 faces of 2 scale pixels a side.
#pragma once

#include <Eigen/Core>
#include <array>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace stitch {

struct RigError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// --- lens (issue 15) -------------------------------------------------------------------------
// Distortion between the raw pixel and the ideal pinhole pixel (fx, fy, cx, cy), as OpenCV:
//   radtan (cv::projectPoints): x' = x r(1 + k1 r^2 + k2 r^4 + k3 r^6) + tangential(p1, p2);
//   fisheye (cv::fisheye, Kannala-Brandt): theta_d = theta (1 + k1 theta^2 + .. + k4 theta^8),
//     theta = the ray's angle from the optical axis (may exceed 90 degrees on curved canvases).
// "circle": the image circle (raw pixels); pixels outside it carry no weight.
struct LensCircle {
  double cx = 0, cy = 0, radius = 0;
};
struct Lens {
  enum class Model { Pinhole, Radtan, Fisheye };
  Model model = Model::Pinhole;
  double k1 = 0, k2 = 0, k3 = 0, k4 = 0, p1 = 0, p2 = 0;
  std::optional<LensCircle> circle;
  bool estimate = false;  // a rough rig's model without coefficients: "estimate them"
  bool pinhole() const { return model == Model::Pinhole; }
  bool operator==(const Lens& o) const;
};
const char* lens_model_name(Lens::Model m);
// --- end lens ----------------------------------------------------------------------------------

struct Camera {
  int width = 0, height = 0;
  double fx = 0, fy = 0, cx = 0, cy = 0;
  double yaw_deg = 0, pitch_deg = 0, roll_deg = 0;
  std::optional<Eigen::Vector3d> t;          // metres, optional
  std::optional<Eigen::Matrix3d> homography; // camera pixel -> canvas pixel
  // Time alignment (stitchsync): ns added to this camera's running time so that its frames
  // line up with camera 0's (GstPad offset semantics); absent when never measured.
  std::optional<int64_t> time_offset_ns;
  Lens lens;                                 // pinhole unless the rig says otherwise (issue 15)
  // Not calibrated: it had no usable frame (never delivered, dark) when the rig was made, so it
  // is on no canvas (no outline, no view) until a calibration with it. Never saved.
  bool left_out = false;

  Eigen::Matrix3d K() const;
  Eigen::Matrix3d R() const;  // camera -> rig rotation
  void set_R(const Eigen::Matrix3d& R);  // stores R as yaw/pitch/roll (R = Ry Rx Rz)
};

// Cubemap (issue 15, optional contract addition): 3 x 2 cube faces, Spherical Video V2 `cbmp`
// layout 0 (projection_math.hpp); canvas_scale is half a face's side, the origin (-0.5, -0.5).
enum class Projection { Plane, Cylindrical, Spherical, Cubemap };
const char* projection_name(Projection p);
Projection projection_from_name(const std::string& name);  // throws RigError naming the choices

struct Rig {
  std::string projection = "plane";
  // The rig file gave no "projection" (plane by default): a calibration may pick a curved canvas
  // when the views need one (lens rigs on a plane, issue 15). False when set in code or a file.
  bool projection_default = false;
  int reference = 0;
  int canvas_width = 0, canvas_height = 0;  // 0 when not calibrated
  double plane_distance_m = 0;              // >0: plane-induced homographies use "t"
  std::vector<Camera> cameras;
  // Non-planar canvases: pixels per radian, canvas pixel of angles (0, 0), and whether the
  // canvas spans 360 degrees horizontally (then width == 2 pi scale and columns wrap).
  double canvas_scale = 0;
  double canvas_origin_x = 0, canvas_origin_y = 0;
  bool canvas_wrap = false;
  // Fields of the file this loader does not know, each as `camera 1: "yaw" (did you mean
  // "yaw_deg"?)`: ignored, but a typo must not pass silently (callers warn with these).
  std::vector<std::string> unknown_fields;

  Projection projection_kind() const { return projection_from_name(projection); }
  bool planar() const { return projection == "plane"; }
  // Planar: every camera has a homography and the canvas is set; non-planar: the canvas and
  // its scale are set.
  bool calibrated() const;
};

bool any_left_out(const Rig& rig);  // a camera with Camera::left_out

// JSON I/O. Throws RigError with a message that names the problem (and the camera index).
Rig rig_from_json_string(const std::string& text);
// By extension: .yaml/.yml (OpenCV calibration, stitch/rig/opencv_yaml.hpp), .pto (Hugin/PTGui,
// stitch/rig/pto.hpp), anything else the JSON contract.
Rig rig_load(const std::string& path);
std::string rig_to_json_string(const Rig& rig);
void rig_save(const Rig& rig, const std::string& path);  // atomic: write temp + rename

// Homography from camera `src` pixels to camera `dst` pixels from the rough parameters
// (paper eq. 8-12): K_dst R_dst^T R_src K_src^-1 for a rotating rig, plane-induced when
// plane_distance_m > 0 and the cameras carry "t".
Eigen::Matrix3d rough_pairwise_homography(const Rig& rig, int src, int dst);

// Fills every camera's homography from the rough parameters (planar canvas = the reference
// camera's image plane) and lays out the canvas. Throws RigError on degenerate geometry.
void rig_compute_rough_homographies(Rig& rig);

// Planar rigs: shifts all homographies so the union of the warped views starts at (0,0), and sets the
// canvas size to cover it. Throws RigError when a view does not project (behind the plane)
// or the canvas would be absurdly large.
// Non-planar rigs: canvas scale (kept when set, else the median focal length), origin and size
// from where the cameras look; a canvas that the views cover all around wraps (360 degrees).
void rig_layout_canvas(Rig& rig);

// Adapts a rig written for other view sizes to the streams' sizes (scales intrinsics and
// homographies). Returns true when something changed.
bool rig_adapt_to_sizes(Rig& rig, const std::vector<std::array<int, 2>>& sizes);

// Empty string when H maps a width x height image to a sane, non-mirrored, finite quad.
std::string homography_problem(const Eigen::Matrix3d& H, int width, int height);
// The same for a camera's homography; with a lens (issue 15) H maps ideal pixels and may see past
// the plane's horizon (a fisheye over the ground), so only a finite, regular H that keeps some of
// the image (its centre, a corner or an edge's middle) in front is asked for.
std::string camera_homography_problem(const Camera& c);

Eigen::Vector2d apply_homography(const Eigen::Matrix3d& H, const Eigen::Vector2d& p);

// Canvas-space quad of a camera (its four corner pixels mapped by its homography).
std::array<Eigen::Vector2d, 4> camera_canvas_corners(const Camera& cam);

}  // namespace stitch
