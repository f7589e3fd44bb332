// Launchers of the warp and blend kernels (plain C++ declarations; definitions in *.cu).
// Every launch is on the given stream and is checked; errors throw std::runtime_error.
#pragma once
#include <cuda_runtime_api.h>
#include <stddef.h>
#include <stdint.h>

#include "stitch/rig/projection_math.hpp"

namespace stitch_cuda {

constexpr int kMaxViews = 16;

struct DeviceImage {
  uint8_t* data = nullptr;  // RGBA8, device memory
  size_t pitch = 0;
  int width = 0, height = 0;
};

struct ViewGeometry {
  float output_to_camera[9];  // planar: output pixel -> camera pixel; else rig ray -> camera pixel
  int roi_x, roi_y, roi_w, roi_h;  // in output pixels; roi_w = 0: not visible
  int camera_w, camera_h;
  int projection;              // stitch_projection::Kind
  float output_to_angles[4];   // non-planar: a = [0] x + [1], b = [2] y + [3]
  int wrap_w;                  // > 0: the view crosses the 360-degree wrap and reaches only
  float span_x0, span_x1;      // the columns [span_x0, span_x1] (unwrapped, modulo wrap_w)
  int has_lens;                // lens (issue 15): output_to_camera yields the camera-frame ray and
  stitch_projection::LensParams<float> lens;  // the lens the raw pixel (canvas_to_lens_camera)
};

// dst (roi-sized) = camera frame `src` sampled where output pixel roi + (x, y) maps to.
// dst ((w + 1) / 2 x (h + 1) / 2): src averaged over 2x2 blocks (stitch::halve_frame's bytes).
// Rows of uchar4: both pitches multiples of 4.
void launch_halve(const DeviceImage& src, const DeviceImage& dst, cudaStream_t stream);
// luma (optional, dst.width * dst.height bytes): stitch::seam::luma of every written pixel, for
// the seam finder, in the same pass (it would read the warped view again).
void launch_warp(const DeviceImage& src, const ViewGeometry& view, const DeviceImage& dst, cudaStream_t stream,
                 uint8_t* luma = nullptr);
// The same for n views in one launch: srcs[i] into dsts[i] (view i's roi; data == nullptr: left
// out), lumas (optional; lumas[i] may be nullptr). textures (optional, create_rgba_texture of
// srcs[i]; 0 for a left-out view): the hardware's bilinear taps, used only when every warped view has one.
void launch_warps(int n, const DeviceImage* srcs, const ViewGeometry* views, const DeviceImage* dsts, uint8_t* const* lumas,
                  const unsigned long long* textures, cudaStream_t stream);

// Position-weighted mean of views already warped into their rois; warped[i].data == nullptr
// leaves view i out. Uncovered pixels are opaque black. With labels and mix (out.width wide, the
// seam finder's): the consensus blend in the same pass (seam.hpp apply_seam_mix on the CPU).
// tiles (optional, from launch_fuse_tiles for this geometry and output size): where a tile is
// one view's alone, its pixels are that view's, without the per-view weights (the same bytes).
void launch_fuse(int n, const ViewGeometry* views, const DeviceImage* warped, const DeviceImage& out,
                 cudaStream_t stream, const uint8_t* labels = nullptr, const uint8_t* mix = nullptr,
                 const uint8_t* tiles = nullptr);

// The fuse's tiles (kFuseTileW x kFuseTileH output pixels, row-major, fuse_tile_count bytes):
// the view whose position weight is the only positive one on every pixel of the tile, or
// kFuseTileEmpty where no view covers any pixel of it, or kFuseTileMixed. Geometry only: made
// once per prepare(). Most of a panorama is one camera's alone, and there the weighted mean is
// that camera's pixel, so the fuse need not map the pixel into every view.
constexpr int kFuseTileW = 32, kFuseTileH = 8;
constexpr uint8_t kFuseTileMixed = 255, kFuseTileEmpty = 254;
inline size_t fuse_tile_count(int width, int height) {
  return size_t((width + kFuseTileW - 1) / kFuseTileW) * size_t((height + kFuseTileH - 1) / kFuseTileH);
}
void launch_fuse_tiles(int n, const ViewGeometry* views, int width, int height, uint8_t* tiles, cudaStream_t stream);

// Warp + optional 3x3 color matrix per view + blend in one pass: every input pixel is read
// about once and the output written once. frames[i].data == nullptr leaves camera i out;
// color == nullptr: no color matrix (out_c = sum_k in_k M[k][c], row-major 3x3 per view).
// tiles (optional, launch_fuse_tiles of this geometry and output size): where one view covers
// a tile alone, its pixels are that view's sample, without the per-view weights (w c / w).
void launch_compose(int n, const ViewGeometry* views, const DeviceImage* frames, const float* color,
                    const DeviceImage& out, cudaStream_t stream, const uint8_t* tiles = nullptr);

// dst(p) = src sampled (bilinear) at inverse_affine · p (row-major 2x3, dst pixel -> src
// pixel); opaque black outside src. Crops and scales a fused canvas into the output.
void launch_resample_affine(const DeviceImage& src, const float* inverse_affine, const DeviceImage& dst,
                            cudaStream_t stream);

// The same as launch_compose, sampling through texture objects (hardware bilinear filtering,
// transparent border): one fetch per sample instead of four gathers. textures[i] == 0 leaves
// camera i out.
void launch_compose_tex(int n, const ViewGeometry* views, const unsigned long long* textures, const float* color,
                        const DeviceImage& out, cudaStream_t stream, const uint8_t* tiles = nullptr);

// A texture object over an RGBA pitched image (linear filtering, zero border, unnormalised
// coordinates); 0 when the image's address or pitch does not meet the texture alignment.
unsigned long long create_rgba_texture(const DeviceImage& image);
void destroy_texture(unsigned long long texture);

}  // namespace stitch_cuda
