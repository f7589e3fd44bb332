// Launchers of the multiband blender's kernels (definitions in multiband_kernels.cu). The
// pyramid arithmetic is stitch/blend/pyramid_math.hpp, shared with the CPU blender.
#pragma once
#include <cuda_runtime_api.h>
#include <stdint.h>

#include "blend_kernels.hpp"

namespace stitch_cuda {

struct FloatImage {  // float4 per pixel: rgb, and a mask weight in w
  float4* data = nullptr;
  int pitch = 0;  // in pixels
  int width = 0, height = 0;
};

// Hole filling (pull-push), as the CPU's fill_holes: pull (level 0, the view padded) = the
// view's colours premultiplied by its coverage (alpha), 0 outside the view.
void launch_mb_premultiply(const DeviceImage& view, const FloatImage& pull, cudaStream_t stream);
// fill.rgb = pull.rgb + (1 - pull.a) · upper.rgb, or pull.rgb / pull.a at the coarsest level
// (upper.data == nullptr); fill.w = pull.a.
void launch_mb_push(const FloatImage& pull, const FloatImage& upper, const FloatImage& fill, cudaStream_t stream);
// dst (the view's padded rectangle at (rect_x, rect_y) of the canvas) = the view's hole-filled
// pixels (`filled`, roi_w x roi_h at its top left), mirrored outside its roi (roi_x, roi_y: where
// the roi starts inside the rectangle), and w = 1 where labels (label_w x label_h, row-major)
// give the pixel to view `index`.
void launch_mb_load_view(const FloatImage& filled, int roi_w, int roi_h, int roi_x, int roi_y, int rect_x, int rect_y,
                         const uint8_t* labels, int label_w, int label_h, int index, const FloatImage& dst,
                         cudaStream_t stream);
// dst = pyrDown(src) through tmp (src.height x dst.width).
void launch_mb_down(const FloatImage& src, const FloatImage& tmp, const FloatImage& dst, cudaStream_t stream);
// dst = pyrUp(src) through tmp (src.height x dst.width).
void launch_mb_up(const FloatImage& src, const FloatImage& tmp, const FloatImage& dst, cudaStream_t stream);
// acc(at x0, y0).rgb += (g - upper).rgb · g.w, acc.w += g.w (upper.data == nullptr: coarsest level).
void launch_mb_accumulate(const FloatImage& g, const FloatImage& upper, const FloatImage& acc, int x0, int y0,
                          cudaStream_t stream);
// img.rgb += acc.rgb / (acc.w + eps); with add == false img = that quotient.
void launch_mb_add_normalised(const FloatImage& acc, const FloatImage& img, bool add, cudaStream_t stream);
// out (uchar4, opaque) = img rounded, black where labels say kNoView (255).
void launch_mb_store(const FloatImage& img, const uint8_t* labels, const DeviceImage& out, cudaStream_t stream);

}  // namespace stitch_cuda
