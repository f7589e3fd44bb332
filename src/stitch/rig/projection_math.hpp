// The canvas <-> ray mappings of the non-planar projections, for the host (double) and the
// device (float) alike: one definition, so the CPU and CUDA paths cannot drift apart.
//
// Canvas angles (a, b) in radians, rig frame (x right, y down, z forward):
//   cylindrical: a = longitude (atan2(x, z)), b = height on the unit cylinder (y / hypot(x, z));
//   spherical (equirectangular): a = longitude, b = latitude (atan2(y, hypot(x, z))), +b is down;
//   cubemap: a in [0, 6), b in [0, 4) lay out 3 x 2 cube faces of side 2 (Spherical Video V2
//     `cbmp` layout 0; cube_face_ray below): face (col, row) = (floor(a / 2), floor(b / 2)), its
//     point (s, t) = (a - 2 col - 1, b - 2 row - 1) in [-1, 1]^2 (s right, t down on the face).
//     scale = pixels per unit of a face's tangent plane (half a face side): a face's focal length.
// A canvas pixel (X, Y) has angles a = (X - origin_x) / scale, b = (Y - origin_y) / scale.
#pragma once

#include <math.h>

#include "stitch/host_device.hpp"

namespace stitch_projection {

enum Kind : int { kPlane = 0, kCylindrical = 1, kSpherical = 2, kCubemap = 3 };

// On the device the hardware sine and cosine: canvas angles lie within about ±2π, where their
// error (~1e-6) is a thousandth of a pixel at a focal length of 2000 px, far below the 1/256 px
// of the texture units' bilinear weights; the accurate ones cost ~30 instructions each at every
// output pixel of every curved view.
#ifdef __CUDA_ARCH__
__device__ __forceinline__ float p_sin(float x) { return __sinf(x); }
__device__ __forceinline__ float p_cos(float x) { return __cosf(x); }
#else
inline float p_sin(float x) { return sinf(x); }
inline float p_cos(float x) { return cosf(x); }
#endif
STITCH_HD double p_sin(double x) { return sin(x); }
STITCH_HD double p_cos(double x) { return cos(x); }
STITCH_HD float p_atan2(float y, float x) { return atan2f(y, x); }
STITCH_HD double p_atan2(double y, double x) { return atan2(y, x); }
STITCH_HD float p_sqrt(float x) { return sqrtf(x); }
STITCH_HD double p_sqrt(double x) { return sqrt(x); }
STITCH_HD float p_abs(float x) { return fabsf(x); }
STITCH_HD double p_abs(double x) { return fabs(x); }
STITCH_HD float p_floor(float x) { return floorf(x); }
STITCH_HD double p_floor(double x) { return floor(x); }

// --- cubemap (issue 15) ------------------------------------------------------------------------
// Faces in the 3 x 2 grid (index col + 3 row), Spherical Video V2 `cbmp` layout 0:
//   right | left  | up
//   down  | front | back
// Each face is what a viewer at the centre sees looking at it; front, left, right and back
// upright, the up face with its top towards the front, the down face with its top towards the back.
enum CubeFace : int { kFaceRight = 0, kFaceLeft = 1, kFaceUp = 2, kFaceDown = 3, kFaceFront = 4, kFaceBack = 5 };

// Ray (not normalised; rig frame x right, y down, z forward) of point (s, t) of a face.
template <typename T>
STITCH_HD void cube_face_ray(int face, T s, T t, T& x, T& y, T& z) {
  switch (face) {
    case kFaceRight: x = T(1), y = t, z = -s; break;
    case kFaceLeft: x = T(-1), y = t, z = s; break;
    case kFaceUp: x = -s, y = T(-1), z = -t; break;
    case kFaceDown: x = -s, y = T(1), z = t; break;
    case kFaceFront: x = s, y = t, z = T(1); break;
    default: x = -s, y = t, z = T(-1); break;  // back
  }
}

// Cubemap angles (a, b) of the ray (x, y, z): the face its largest component points at.
template <typename T>
STITCH_HD bool cube_ray_to_angles(T x, T y, T z, T& a, T& b) {
  const T ax = p_abs(x), ay = p_abs(y), az = p_abs(z);
  int face;
  T s, t;
  if (ax >= ay && ax >= az) {
    if (!(ax > T(0))) return false;
    face = x > T(0) ? kFaceRight : kFaceLeft;
    s = (x > T(0) ? -z : z) / ax;
    t = y / ax;
  } else if (ay >= az) {
    face = y > T(0) ? kFaceDown : kFaceUp;
    s = -x / ay;
    t = y > T(0) ? z / ay : -z / ay;
  } else {
    face = z > T(0) ? kFaceFront : kFaceBack;
    s = z > T(0) ? x / az : -x / az;
    t = y / az;
  }
  a = T(2 * (face % 3) + 1) + s;
  b = T(2 * (face / 3) + 1) + t;
  return true;
}

// The ray of cubemap angles (a, b); the zero ray outside the 3 x 2 layout (no ray there).
template <typename T>
STITCH_HD void cube_angles_to_ray(T a, T b, T& x, T& y, T& z) {
  const T col = p_floor(a * T(0.5)), row = p_floor(b * T(0.5));
  if (!(col >= T(0) && col <= T(2) && row >= T(0) && row <= T(1))) {
    x = y = z = T(0);
    return;
  }
  cube_face_ray(int(col) + 3 * int(row), a - T(2) * col - T(1), b - T(2) * row - T(1), x, y, z);
}
// --- end cubemap -------------------------------------------------------------------------------

// Direction (not normalised) of the ray with canvas angles (a, b).
template <typename T>
STITCH_HD void angles_to_ray(int kind, T a, T b, T& x, T& y, T& z) {
  if (kind == kCubemap) {
    cube_angles_to_ray(a, b, x, y, z);
    return;
  }
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
  if (kind == kCubemap) return cube_ray_to_angles(x, y, z, a, b);
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

// --- lens (issue 15) -------------------------------------------------------------------------
// A camera's lens between its camera-frame ray and its raw pixel, exactly as OpenCV's
// projectPoints (radtan) and fisheye::projectPoints (fisheye): closed form, no iteration, so the
// gather warps (canvas -> raw pixel) stay one pass. The inverse (raw pixel -> ray) is iterative
// and host-only (stitch/rig/lens.hpp).
enum LensModel : int { kLensPinhole = 0, kLensRadtan = 1, kLensFisheye = 2 };

template <typename T>
struct LensParams {
  int model;        // LensModel
  T fx, fy, cx, cy;
  T k1, k2, k3, k4;  // radtan: k1 k2 k3 (k4 unused); fisheye: k1..k4
  T p1, p2;          // radtan tangential
  // radtan: the largest r^2 (ideal, normalised) before the radius folds back; fisheye: the
  // largest angle from the axis (radians) the lens sees (monotonic, <= the circle, <= pi).
  T limit;
  T circle_cx, circle_cy, circle_r;  // circle_r <= 0: no image circle
};

// Raw pixel (u, v) of the camera-frame ray (x, y, z); false where the lens does not see it
// (behind a radtan camera, beyond the fold of its distortion or the fisheye's limit).
template <typename T>
STITCH_HD bool lens_project(const LensParams<T>& L, T x, T y, T z, T& u, T& v) {
  T xd, yd;
  if (L.model == kLensFisheye) {
    const T r = p_sqrt(x * x + y * y);
    const T theta = p_atan2(r, z);
    if (!(theta <= L.limit)) return false;
    const T t2 = theta * theta;
    const T td = theta * (T(1) + t2 * (L.k1 + t2 * (L.k2 + t2 * (L.k3 + t2 * L.k4))));
    // On the axis theta / r -> 1 / z.
    const T s = r > T(1e-12) * p_abs(z) ? td / r : T(1) / z;
    xd = x * s;
    yd = y * s;
  } else {
    if (!(z > T(1e-9))) return false;
    const T xn = x / z, yn = y / z;
    if (L.model == kLensRadtan) {
      const T r2 = xn * xn + yn * yn;
      if (!(r2 <= L.limit)) return false;
      const T radial = T(1) + r2 * (L.k1 + r2 * (L.k2 + r2 * L.k3));
      xd = xn * radial + T(2) * L.p1 * xn * yn + L.p2 * (r2 + T(2) * xn * xn);
      yd = yn * radial + L.p1 * (r2 + T(2) * yn * yn) + T(2) * L.p2 * xn * yn;
    } else {
      xd = xn;
      yd = yn;
    }
  }
  u = L.fx * xd + L.cx;
  v = L.fy * yd + L.cy;
  return true;
}

// Output pixel (x, y) -> raw camera pixel (u, v) of a view with a lens. `m` maps to the
// camera-frame ray: planar canvases (kind kPlane) the homogeneous ray of (x, y, 1), non-planar
// the rig ray of the output's angles. A planar canvas holds only rays in front (z > 0).
template <typename T>
STITCH_HD bool canvas_to_lens_camera(int kind, const T* angle, const T* m, const LensParams<T>& L, T x, T y, T& u,
                                     T& v) {
  T rx = x, ry = y, rz = T(1);
  if (kind != kPlane) {
    angles_to_ray(kind, angle[0] * x + angle[1], angle[2] * y + angle[3], rx, ry, rz);
    if (kind == kCubemap && rx == T(0) && ry == T(0) && rz == T(0)) return false;  // off the cube's layout
  }
  const T X = m[0] * rx + m[1] * ry + m[2] * rz;
  const T Y = m[3] * rx + m[4] * ry + m[5] * rz;
  const T Z = m[6] * rx + m[7] * ry + m[8] * rz;
  if (kind == kPlane && !(Z > T(1e-12))) return false;
  return lens_project(L, X, Y, Z, u, v);
}

// 1 inside the image circle's centre falling linearly to 0 at its rim (1 when there is none).
template <typename T>
STITCH_HD T circle_weight(const LensParams<T>& L, T u, T v) {
  if (!(L.circle_r > T(0))) return T(1);
  const T du = u - L.circle_cx, dv = v - L.circle_cy;
  const T w = T(1) - p_sqrt(du * du + dv * dv) / L.circle_r;
  return w > T(0) ? w : T(0);
}
// The blend weight of raw pixel (u, v) of a w x h view with a lens: the position tent
// (stitch::position_weight); with an image circle, the circle's tent (1 at its centre, 0 at its
// rim) bounded by the tent of each image axis (a circle cropped by the frame).
template <typename T>
STITCH_HD T lens_position_weight(const LensParams<T>& L, T u, T v, int w, int h) {
  const T ax = u + T(0.5), bx = T(w) - T(0.5) - u, ay = v + T(0.5), by = T(h) - T(0.5) - v;
  const T wx = (ax < bx ? ax : bx) / (T(w) * T(0.5)), wy = (ay < by ? ay : by) / (T(h) * T(0.5));
  if (!(wx > T(0)) || !(wy > T(0))) return T(0);
  if (L.circle_r > T(0)) {
    const T c = circle_weight(L, u, v), m = wx < wy ? wx : wy;
    return c < m ? c : m;
  }
  return (wx < T(1) ? wx : T(1)) * (wy < T(1) ? wy : T(1));
}

// Whether a view needs the lens path (a distortion model or an image circle).
template <typename T>
STITCH_HD bool has_lens(const LensParams<T>& L) {
  return L.model != kLensPinhole || L.circle_r > T(0);
}
// --- end lens ----------------------------------------------------------------------------------

}  // namespace stitch_projection
