// OpenCV calibration YAML (cv::FileStorage) -> Rig (issue 15).
//
// One camera: top-level `camera_matrix` (3x3) and `dist_coeffs` or `distortion_coefficients`,
// the size from `resolution` [w, h] or `image_width`/`image_height`. Several cameras: top-level
// maps `cam0`, `cam1`, ... each holding the same keys, or Kalibr's camchain keys (`intrinsics`
// [fu, fv, pu, pv], `distortion_coeffs`, `distortion_model` radtan|equidistant, `resolution`,
// `T_cn_cnm1` chaining the rotations). The model: `distortion_model` / `model` when given
// (plumb_bob/radtan/pinhole, equidistant/fisheye); otherwise 4 coefficients are OpenCV fisheye
// (k1..k4, as cv::fisheye::calibrate writes them) and 5 are radtan (k1 k2 p1 p2 k3). Optional
// per camera `yaw_deg`, `pitch_deg`, `roll_deg`; optional top-level `projection`.
// The rig is laid out (calibrated) when its cameras overlap; a single camera is left rough.
#pragma once
#include <string>

#include "stitch/rig/rig.hpp"

namespace stitch {

Rig rig_load_opencv_yaml(const std::string& path);  // throws RigError naming the file and camera

}  // namespace stitch
