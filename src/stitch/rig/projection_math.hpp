// The canvas <-> ray mappings of the non-planar projections, for the host (double) and the
// device (float) alike: one definition, so the CPU and CUDA paths cannot drift apart.
//
// Canvas angles (a, b) in radians, rig frame (x right, y down, z forward):
//   cylindrical: a = longitude (atan2(x, z)), b = height on the unit cylinder (y / hypot(x, z));
//   spherical (equirectangular): a = longitude, b = latitude (atan2(y, hypot(x, z))), +b is down.
// A canvas pixel (X, Y) has angles a = (X - origin_x) / scale, b = (Y - origin_y) / scale.
#pragma once

#include <math.h>

#include "stitch/host_device.hpp"

namespace stitch_projection {

enum Kind : int { kPlane = 0, kCylindrical = 1, kSpherical = 2 };

STITCH_HD float p_sin(float x) { return sinf(x); }
STITCH_HD double p_sin(double x) { return sin(x); }
STITCH_HD float p_cos(float x) { return cosf(x); }
STITCH_HD double p_cos(double x) { return cos(x); }
STITCH_HD float p_atan2(float y, float x) { return atan2f(y, x); }
STITCH_HD double p_atan2(double y, double x) { return atan2(y, x); }
STITCH_HD float p_sqrt(float x) { return sqrtf(x); }
STITCH_HD double p_sqrt(double x) { return sqrt(x); }

// Direction (not normalised) of the ray with canvas angles (a, b).
template <typename T>
STITCH_HD void angles_to_ray(int kind, T a, T b, T& x, T& y, T& z) {
  const T sa = p_sin(a), ca = p_cos(a);
  if (kind == kCylindrical) {
    x = sa;
    y = b;
    z = ca;
  } else {
    const T cb = p_cos(b);
    x = sa * cb;
    y = p_sin(b);
    z = ca * cb;
  }
}

// Canvas angles of the ray (x, y, z); false on the cylinder's axis (no longitude there).
template <typename T>
STITCH_HD bool ray_to_angles(int kind, T x, T y, T z, T& a, T& b) {
  const T r = p_sqrt(x * x + z * z);
  if (kind == kCylindrical && !(r > T(1e-12))) return false;
  a = p_atan2(x, z);
  b = kind == kCylindrical ? y / r : p_atan2(y, r);
  return true;
}

// Output pixel (x, y) -> camera pixel (u, v) of a non-planar view: angles by the affine
// `angle` (a = angle[0] x + angle[1], b = angle[2] y + angle[3]), then the camera's K R^T
// (`m`, row-major). False behind the camera.
template <typename T>
STITCH_HD bool canvas_to_camera(int kind, const T* angle, const T* m, T x, T y, T& u, T& v) {
  T rx, ry, rz;
  angles_to_ray(kind, angle[0] * x + angle[1], angle[2] * y + angle[3], rx, ry, rz);
  const T Z = m[6] * rx + m[7] * ry + m[8] * rz;
  if (!(Z > T(1e-9))) return false;
  u = (m[0] * rx + m[1] * ry + m[2] * rz) / Z;
  v = (m[3] * rx + m[4] * ry + m[5] * rz) / Z;
  return true;
}

}  // namespace stitch_projection
