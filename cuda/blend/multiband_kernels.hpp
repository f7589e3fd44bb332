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

// Hole filling (pull-push), as the CPU's fill_holes. The pull's level 0 (the view padded to
// fill_w x fill_h) is the view's colours premultiplied by its coverage (alpha), 0 outside the
// view; it is never stored: pull1 = pyrDown of it.
void launch_mb_premultiply_down(const DeviceImage& view, int fill_w, int fill_h, const FloatImage& pull1,
                                cudaStream_t stream);
// dst = pyrDown(src), one pass.
void launch_mb_down(const FloatImage& src, const FloatImage& dst, cudaStream_t stream);
// fill.rgb = pull.rgb + (1 - pull.a) · pyrUp(coarser).rgb, or pull.rgb / pull.a at the coarsest
// level (coarser.data == nullptr); fill.w = pull.a.
void launch_mb_push(const FloatImage& pull, const FloatImage& coarser, const FloatImage& fill, cudaStream_t stream);
// dst (the view's padded rectangle at (rect_x, rect_y) of the canvas) = the view's hole-filled
// level 0 (the push of its premultiplied pixels over pyrUp(fill1), fill_w x fill_h; fill1.data ==
// nullptr: no coarser level), mirrored outside its roi (roi_w x roi_h; roi_x, roi_y: where the roi
// starts inside the rectangle), and w = 1 where labels (label_w x label_h, row-major) give the
// pixel to view `index`.
void launch_mb_load_view(const DeviceImage& view, const FloatImage& fill1, int fill_w, int fill_h, int roi_w, int roi_h,
                         int roi_x, int roi_y, int rect_x, int rect_y, const uint8_t* labels, int label_w, int label_h,
                         int index, const FloatImage& dst, cudaStream_t stream);
// acc(at x0, y0).rgb += (g - pyrUp(coarser)).rgb · g.w, acc.w += g.w (coarser.data == nullptr:
// coarsest level).
void launch_mb_accumulate(const FloatImage& g, const FloatImage& coarser, const FloatImage& acc, int x0, int y0,
                          cudaStream_t stream);
// img = pyrUp(coarser) + acc.rgb / (acc.w + eps) (coarser.data == nullptr: the quotient alone).
void launch_mb_collapse(const FloatImage& acc, const FloatImage& coarser, const FloatImage& img, cudaStream_t stream);
// out (uchar4, opaque) = the collapse's finest level (as launch_mb_collapse on acc0) rounded,
// black where labels say kNoView (255).
void launch_mb_store(const FloatImage& acc0, const FloatImage& coarser, const uint8_t* labels, const DeviceImage& out,
                     cudaStream_t stream);

}  // namespace stitch_cuda
