// Hugin / PTGui project (.pto) -> Rig (issue 15).
//
// `p` line: f (0 rectilinear -> plane, 1 cylindrical, 2 equirectangular -> spherical), w, v
// (the panorama's horizontal field of view: its scale). `i` lines, one camera each: w, h, f (lens
// type: 0 rectilinear, 2 circular fisheye, 3 full-frame fisheye; both fisheyes equidistant), v
// (hfov, degrees), y/p/r (yaw right, pitch up, roll: our yaw_deg/pitch_deg/roll_deg), a, b, c
// (panotools radial: r_src = a r^4 + b r^3 + c r^2 + (1 - a - b - c) r, r in units of half the
// smaller side, from the ideal to the raw image), d, e (lens centre shift, pixels). `v=0`-style
// back-references take image 0's value. A circular fisheye's image circle is the crop `S`
// (left,right,top,bottom) when given, else the inscribed circle.
//
// The panotools polynomial is converted to our models by linear least squares over the radius
// (rectilinear -> radtan k1 k2 k3; fisheye -> fisheye k1..k4); the worst residual, in raw
// pixels, is reported.
#pragma once
#include <string>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace stitch {

struct PtoReport {
  std::vector<double> fit_residual_px;  // per camera: worst |r_ours - r_panotools| over the image
};

Rig rig_from_pto_string(const std::string& text, PtoReport* report = nullptr);  // throws RigError
Rig rig_load_pto(const std::string& path, PtoReport* report = nullptr);

// Panotools a, b, c (ideal image of focal f px) -> our focal `focal` and radtan k1..k3
// (rectilinear) or fisheye k1..k4, fitted over raw radii up to max_radius_px (the focal is free:
// panotools' linear term d = 1 - a - b - c scales the image). Returns the worst residual in raw
// pixels. `half_short` = min(w, h) / 2.
double fit_panotools_radial(double a, double b, double c, double f, double half_short, double max_radius_px,
                            bool fisheye, Lens& lens, double& focal);

}  // namespace stitch
