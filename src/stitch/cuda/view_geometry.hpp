// ViewPlacement -> the kernels' plain ViewGeometry.
#pragma once
#include <vector>

#include "../../../cuda/blend/blend_kernels.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/image.hpp"
#include "stitch/warp/geometry.hpp"

namespace stitch {

inline stitch_cuda::ViewGeometry to_device_geometry(const ViewPlacement& v) {
  stitch_cuda::ViewGeometry g{};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) g.output_to_camera[3 * r + c] = float(v.output_to_camera(r, c));
  g.roi_x = v.roi.x;
  g.roi_y = v.roi.y;
  g.roi_w = v.roi.empty() ? 0 : v.roi.width;
  g.roi_h = v.roi.empty() ? 0 : v.roi.height;
  g.camera_w = v.camera_width;
  g.camera_h = v.camera_height;
  g.projection = static_cast<int>(v.projection);
  for (int k = 0; k < 4; ++k) g.output_to_angles[k] = float(v.output_to_angles[k]);
  g.wrap_w = v.wrap_width;
  g.span_x0 = float(v.span_x0);
  g.span_x1 = float(v.span_x1);
  g.has_lens = v.has_lens() ? 1 : 0;
  const auto& l = v.lens;
  g.lens = {l.model, float(l.fx), float(l.fy), float(l.cx), float(l.cy), float(l.k1), float(l.k2), float(l.k3),
            float(l.k4), float(l.p1), float(l.p2), float(l.limit < 1e30 ? l.limit : 1e30), float(l.circle_cx),
            float(l.circle_cy), float(l.circle_r)};
  return g;
}

inline stitch_cuda::DeviceImage to_device_image(const ImageView& v) {
  stitch_cuda::DeviceImage d;
  d.data = v.data;
  d.pitch = v.pitch;
  d.width = v.width;
  d.height = v.height;
  return d;
}

// Rows of a device copy start on 256 bytes: a texture object binds any width then (the
// compositor's warp and compose sample through the texture units; rows of width * 4 bytes bind
// only when that is a multiple of the device's texture pitch alignment, 32 or 64 bytes).
inline std::size_t device_row_pitch(int width) { return (std::size_t(width) * 4 + 255) / 256 * 256; }

// The device image of `v`: `v` itself when it is in device memory, else a copy uploaded into
// `staging` (grown once, reused every frame) on `stream`.
inline stitch_cuda::DeviceImage device_image_of(const ImageView& v, DeviceBuffer& staging, cudaStream_t stream) {
  if (v.on_device) return to_device_image(v);
  const std::size_t pitch = device_row_pitch(v.width);
  staging.resize(pitch * v.height);
  STITCH_CUDA(cudaMemcpy2DAsync(staging.data(), pitch, v.data, v.pitch, std::size_t(v.width) * 4, v.height,
                                cudaMemcpyHostToDevice, stream));
  stitch_cuda::DeviceImage d;
  d.data = staging.data();
  d.pitch = pitch;
  d.width = v.width;
  d.height = v.height;
  return d;
}

// `d` halved `level` times on `stream` (stitch_cuda::launch_halve, halve_frame's bytes) into
// `scratch` (one buffer per level, grown once); `d` itself at level 0.
inline stitch_cuda::DeviceImage reduce_on_device(stitch_cuda::DeviceImage d, int level, std::vector<DeviceBuffer>& scratch,
                                                 cudaStream_t stream) {
  if (level > 0 && scratch.size() < std::size_t(level)) scratch.resize(std::size_t(level));
  for (int l = 0; l < level; ++l) {
    stitch_cuda::DeviceImage h;
    h.width = (d.width + 1) / 2;
    h.height = (d.height + 1) / 2;
    h.pitch = device_row_pitch(h.width);
    scratch[std::size_t(l)].resize(h.pitch * std::size_t(h.height));
    h.data = scratch[std::size_t(l)].data();
    stitch_cuda::launch_halve(d, h, stream);
    d = h;
  }
  return d;
}

}  // namespace stitch
