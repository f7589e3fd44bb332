// Multiband (Laplacian pyramid) blending, Burt & Adelson: every view's Laplacian pyramid is
// blended with the Gaussian pyramid of its mask, so low frequencies mix over a wide band and
// fine detail over a narrow one: no ghosting of detail, no visible step in exposure.
// The masks are a label map: each output pixel belongs to one view (by default the view whose
// position weight is highest there, i.e. the middle of every overlap; a seam finder may move
// it per frame).
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "stitch/blend/blender.hpp"

namespace stitch {

enum class BlendMode { Weighted, Multiband };

constexpr uint8_t kNoView = 255;  // label of a pixel no view covers

// One pyramid of a view: `part` of its roi (output pixels) and `rect`, that part widened and
// aligned. A view across the 360-degree wrap (roi the whole width) has two, one at each edge
// over the columns it reaches, instead of one pyramid as wide as the panorama.
struct MultibandPiece {
  int view = 0;
  Rect part;
  Rect rect;
};

// Where each view's pyramids lie on the padded canvas: all sizes are multiples of 2^bands,
// so level k of a piece is exactly the canvas' level k over (rect >> k).
struct MultibandLayout {
  int bands = 0;
  int width = 0, height = 0;                // the blended output
  int padded_width = 0, padded_height = 0;  // multiples of 2^bands
  std::vector<MultibandPiece> pieces;       // the visible views' pyramids, in view order
  int fill_width = 0, fill_height = 0;      // the largest part padded to 2^bands (the hole filling's level 0)
  int max_rect_width = 1, max_rect_height = 1;
};

// The pixels of `warped` (the view's roi) that `piece` covers.
inline ImageView piece_pixels(const ImageView& warped, const Rect& roi, const MultibandPiece& piece) {
  ImageView v = warped;
  v.data += std::size_t(piece.part.x - roi.x) * 4 + std::size_t(piece.part.y - roi.y) * warped.pitch;
  v.width = piece.part.width;
  v.height = piece.part.height;
  return v;
}

// n rounded up to a multiple of 2^bands: the size a view's hole filling works on.
inline int padded_to_bands(int n, int bands) { return (n + (1 << bands) - 1) >> bands << bands; }

// bands is clamped so that the smallest level keeps at least 2 pixels per side.
MultibandLayout plan_multiband(const std::vector<ViewPlacement>& views, int width, int height, int bands);

// Each pixel of the output to the present view (bit i of present_mask) whose position weight
// is highest there; kNoView where none covers it. width*height bytes, row-major.
std::vector<uint8_t> nearest_view_labels(const std::vector<ViewPlacement>& views, int width, int height,
                                         uint64_t present_mask);

class MultibandBlender : public Blender {
 public:
  static constexpr int kDefaultBands = 5;
  // Labels (width*height) to blend the next fuse() calls with, instead of the nearest-view
  // labels; nullptr returns to those. Host labels: pixels labelled with a missing view are
  // given to the nearest present one. Device labels (CUDA blender only; the CUDA seam finder's)
  // are used as they are and must stay valid until the next set_labels().
  virtual void set_labels(const uint8_t* labels, bool on_device = false) = 0;
  virtual const MultibandLayout& layout() const = 0;

  static std::unique_ptr<MultibandBlender> create(Backend backend, int bands = kDefaultBands);
};

// The blender that `mode` names (the weighted mean, or multiband with `bands` levels).
std::unique_ptr<Blender> make_blender(Backend backend, BlendMode mode, int bands = MultibandBlender::kDefaultBands);

}  // namespace stitch
