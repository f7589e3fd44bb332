// Device helpers shared by the kernels: bilinear RGBA sampling with transparent black outside
// the image (OpenCV's remap with BORDER_CONSTANT 0), and the blend's position weight.
#pragma once
#include <cuda_runtime.h>
#include <stdint.h>

#include "blend/blend_kernels.hpp"
#include "stitch/rig/projection_math.hpp"

namespace stitch_cuda {

struct Homography {
  float m[9];  // row-major, output pixel -> camera pixel
};

__device__ __forceinline__ float4 load_rgba(const uint8_t* base, size_t pitch, int w, int h, int x, int y) {
  if (x < 0 || y < 0 || x >= w || y >= h) return make_float4(0.f, 0.f, 0.f, 0.f);
  const uchar4 p = *reinterpret_cast<const uchar4*>(base + size_t(y) * pitch + size_t(x) * 4);
  return make_float4(p.x, p.y, p.z, p.w);
}

__device__ __forceinline__ float4 sample_bilinear(const uint8_t* base, size_t pitch, int w, int h, float u, float v) {
  const float fx0 = floorf(u), fy0 = floorf(v);
  const int x0 = int(fx0), y0 = int(fy0);
  const float ax = u - fx0, ay = v - fy0;
  float4 a, b, c, d;
  if (unsigned(x0) < unsigned(w - 1) && unsigned(y0) < unsigned(h - 1)) {
    // The whole 2x2 footprint inside (nearly every sample): one bounds test instead of four.
    const uint8_t* p = base + size_t(y0) * pitch + size_t(x0) * 4;
    const uchar4 pa = *reinterpret_cast<const uchar4*>(p), pb = *reinterpret_cast<const uchar4*>(p + 4);
    const uchar4 pc = *reinterpret_cast<const uchar4*>(p + pitch), pd = *reinterpret_cast<const uchar4*>(p + pitch + 4);
    a = make_float4(pa.x, pa.y, pa.z, pa.w);
    b = make_float4(pb.x, pb.y, pb.z, pb.w);
    c = make_float4(pc.x, pc.y, pc.z, pc.w);
    d = make_float4(pd.x, pd.y, pd.z, pd.w);
  } else {
    a = load_rgba(base, pitch, w, h, x0, y0), b = load_rgba(base, pitch, w, h, x0 + 1, y0);
    c = load_rgba(base, pitch, w, h, x0, y0 + 1), d = load_rgba(base, pitch, w, h, x0 + 1, y0 + 1);
  }
  const float w00 = (1 - ax) * (1 - ay), w10 = ax * (1 - ay), w01 = (1 - ax) * ay, w11 = ax * ay;
  return make_float4(a.x * w00 + b.x * w10 + c.x * w01 + d.x * w11, a.y * w00 + b.y * w10 + c.y * w01 + d.y * w11,
                     a.z * w00 + b.z * w10 + c.z * w01 + d.z * w11, a.w * w00 + b.w * w10 + c.w * w01 + d.w * w11);
}

// Camera coordinates of output pixel (x, y); false behind the camera.
__device__ __forceinline__ bool to_camera(const Homography& H, float x, float y, float& u, float& v) {
  const float Z = H.m[6] * x + H.m[7] * y + H.m[8];
  if (!(Z > 1e-12f)) return false;
  const float inv = 1.f / Z;
  u = (H.m[0] * x + H.m[1] * y + H.m[2]) * inv;
  v = (H.m[3] * x + H.m[4] * y + H.m[5]) * inv;
  return true;
}

// Camera coordinates of output pixel (x, y) of view `vg` (stitch::view_to_camera); false behind
// the camera. kCurved = false compiles the planar mapping alone: kernels are instantiated both
// ways and launched planar-only when every view is planar, so the trigonometry of the curved
// projections costs planar rigs nothing (registers, occupancy).
// Lenses (issue 15) take the kCurved instantiation too: planar pinhole rigs pay nothing for them.
template <bool kCurved>
__device__ __forceinline__ bool view_to_camera(const ViewGeometry& vg, float x, float y, float& u, float& v) {
  if (kCurved && vg.has_lens)
    return stitch_projection::canvas_to_lens_camera(vg.projection, vg.output_to_angles, vg.output_to_camera, vg.lens, x,
                                                    y, u, v);
  if (!kCurved || vg.projection == stitch_projection::kPlane) {
    Homography H;
#pragma unroll
    for (int k = 0; k < 9; ++k) H.m[k] = vg.output_to_camera[k];
    return to_camera(H, x, y, u, v);
  }
  return stitch_projection::canvas_to_camera(vg.projection, vg.output_to_angles, vg.output_to_camera, x, y, u, v);
}

// stitch::position_weight: a tent, 1 at the centre and 0 half a pixel outside the border.
__device__ __forceinline__ float position_weight(float u, float v, int w, int h) {
  const float wx = fminf(u + 0.5f, w - 0.5f - u) / (w * 0.5f);
  const float wy = fminf(v + 0.5f, h - 0.5f - v) / (h * 0.5f);
  if (wx <= 0.f || wy <= 0.f) return 0.f;
  return fminf(wx, 1.f) * fminf(wy, 1.f);
}

// Across the wrap a view's roi is the whole width: whether column x is one it cannot reach.
__device__ __forceinline__ bool outside_wrap_span(const ViewGeometry& vg, int x) {
  if (vg.wrap_w <= 0) return false;
  const float xu = float(x) < vg.span_x0 ? float(x + vg.wrap_w) : float(x);
  return xu > vg.span_x1;
}

// Position weight of view `vg` at output pixel (x, y), with its camera coordinates; 0 where the
// view does not cover the pixel.
template <bool kCurved>
__device__ __forceinline__ float view_weight(const ViewGeometry& vg, int x, int y, float& u, float& v) {
  if (x < vg.roi_x || y < vg.roi_y || x >= vg.roi_x + vg.roi_w || y >= vg.roi_y + vg.roi_h) return 0.f;
  if (kCurved && outside_wrap_span(vg, x)) return 0.f;
  if (!view_to_camera<kCurved>(vg, float(x), float(y), u, v)) return 0.f;
  if (kCurved && vg.has_lens) return stitch_projection::lens_position_weight(vg.lens, u, v, vg.camera_w, vg.camera_h);
  return position_weight(u, v, vg.camera_w, vg.camera_h);
}

// Whether any of the n views needs the curved (or lens) mapping (host side: picks the instantiation).
inline bool any_curved(const ViewGeometry* views, int n) {
  for (int i = 0; i < n; ++i)
    if (views[i].projection != stitch_projection::kPlane || views[i].has_lens) return true;
  return false;
}

__device__ __forceinline__ uint8_t to_u8(float v) { return uint8_t(fminf(fmaxf(v + 0.5f, 0.f), 255.f)); }

}  // namespace stitch_cuda
