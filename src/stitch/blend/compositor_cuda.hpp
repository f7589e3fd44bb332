// The Compositor's CUDA path: one fused warp + blend kernel per panorama. Frames and output may
// be in device memory (used in place) or in system memory (uploaded / downloaded through
// buffers allocated once, not per frame).
#pragma once
#include <functional>
#include <memory>
#include <vector>

#include "stitch/blend/multiband.hpp"
#include "stitch/blend/seam.hpp"
#include "stitch/image.hpp"
#include "stitch/warp/geometry.hpp"

namespace stitch {

class CudaComposer {
 public:
  CudaComposer();
  ~CudaComposer();
  // Weighted: the fused kernels; Multiband: views warped into device rectangles, then the
  // CUDA multiband blender, its masks cut by a seam finder when `seams` is given. Takes effect
  // at the next prepare().
  void set_blend_mode(BlendMode mode, int bands, const SeamSettings* seams = nullptr);
  void prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height);
  // frames: camera frames; color: 9 floats per view (row-major, out_c = sum_k in_k M[k][c]) or null.
  void compose(const std::vector<ImageView>& frames, const ImageView& out, const float* color = nullptr);
  // views: already warped into their rois (stitchflowwarp's output).
  void fuse(const std::vector<ImageView>& views, const ImageView& out);
  // The same, fused on the device into the prepared size, then cropped/scaled into `out` (any
  // size) by output = canvas_to_output · canvas (bilinear).
  void fuse_resampled(const std::vector<ImageView>& views, const ImageView& out, const double canvas_to_output[6]);

  // The labels of the last multiband blend with seams (host copy), empty without seams.
  std::vector<uint8_t> seam_labels() const;
  // Runs `draw` on a host copy of `out` (device memory: downloaded, then uploaded back).
  void draw_on_host(const ImageView& out, const std::function<void(const ImageView&)>& draw);

 private:
  struct State;
  std::unique_ptr<State> s_;
};

}  // namespace stitch
