// Lenses (issue 15): a camera's raw pixel <-> its ray / ideal pinhole pixel, on the host.
// The forward direction (ray -> raw pixel) is stitch_projection::lens_project
// (projection_math.hpp, shared with the kernels); the inverse here is iterative, as
// cv::undistortPoints and cv::fisheye::undistortPoints.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "stitch/rig/projection_math.hpp"
#include "stitch/rig/rig.hpp"

namespace stitch {

// The kernels' parameters of the camera's lens (limit computed: where the radius folds back).
stitch_projection::LensParams<double> lens_params(const Camera& c);
stitch_projection::LensParams<float> lens_params_f(const Camera& c);

// Raw pixel of the camera-frame ray; false where the lens does not see it.
bool lens_project(const Camera& c, const Eigen::Vector3d& ray, Eigen::Vector2d& raw);

// Unit camera-frame ray of raw pixel `raw` (the inverse of lens_project); false where the
// iteration finds none (beyond the fold of the distortion, or the fisheye's limit).
bool lens_unproject(const Camera& c, const Eigen::Vector2d& raw, Eigen::Vector3d& ray);

// Raw pixel -> ideal pinhole pixel (fx, fy, cx, cy) and back. undistort fails for rays at 90
// degrees or more from the axis (a fisheye's outer ring: no ideal pixel there).
bool undistort_point(const Camera& c, const Eigen::Vector2d& raw, Eigen::Vector2d& ideal);
bool distort_point(const Camera& c, const Eigen::Vector2d& ideal, Eigen::Vector2d& raw);

// cv::undistortPoints(..., P = K) for any of our lenses: raw pixels -> ideal pixels. Points with
// no ideal pixel come back as NaN. The calibrator undistorts keypoints through this before it
// fits homographies (the planar contract: homographies map ideal pixels).
std::vector<cv::Point2f> undistort_points(const Camera& c, const std::vector<cv::Point2f>& raw);

// Whether raw pixel (u, v) shows the scene: inside the image and its image circle.
bool lens_sees(const Camera& c, double u, double v);

// The normalised raw radius ((u - cx) / fx, (v - cy) / fy) of the farthest frame corner, or of
// the image circle's rim when that is nearer: how far off the axis the frame reaches.
double lens_far_radius(const Camera& c);

// Empty when the lens is usable; else what is wrong (coefficients that fold the radius inside
// the image, an image circle outside the frame, a negative radius).
std::string lens_problem(const Camera& c);

// A calibration's polynomial holds only where the calibration saw its target: OpenCV fisheye and
// radtan fits of wide lenses often fold back in the frame's (black or unused) corners. When the
// lens has no image circle and folds inside the frame, but only beyond `min_share` of the shorter
// half side, give it an image circle centred on the principal point that ends just before the
// fold (pixels beyond carry no weight) and return true; false (camera unchanged) otherwise.
bool lens_cap_at_fold(Camera& c, double min_share = 0.8);

// Empty when nothing looks odd; else a warning (not an error: the lens is usable): a fisheye
// whose frame sees less than `kFisheyeMinDiagonalFovDeg` across its diagonal is most likely a
// rectilinear image given the fisheye model (its focal length in pixels is that of a normal lens:
// a rectilinear lens of up to ~100 degrees reads as under 140 through the equidistant model, while
// fisheyes see 150-220 degrees).
constexpr double kFisheyeMinDiagonalFovDeg = 140.0;
std::string lens_warning(const Camera& c);

// Lens cameras on a plane canvas (issue 15): the plane is the reference camera's image plane and
// shows only rays less than 90 degrees off its axis, stretched without bound towards 90 (4x at
// 60, 15x at 75). A rotating rig whose lens views reach kPlaneCanvasMaxOffDeg or more off that
// axis (a fisheye of 150 degrees or more, or a wide lens turned away) needs a curved canvas.
// `problems`: one line per such camera, naming it; `projection`: the canvas its views need
// ("spherical" when a view comes within 30 degrees of a pole, else "cylindrical"), empty when the
// plane is fine. Rigs of pinholes only, and rigs given by homographies (a ground plane, a
// calibration), are not checked.
constexpr double kPlaneCanvasMaxOffDeg = 75.0;
struct PlaneCanvasCheck {
  std::string projection;
  std::vector<std::string> problems;
  double worst_off_deg = 0;  // the farthest view ray from the reference axis, degrees
};
PlaneCanvasCheck check_plane_canvas(const Rig& rig);

}  // namespace stitch
