// Fuses views already warped into their output rectangles into one panorama with the
// paper's position-weighted mean (eq. 15-16), generalised to N views: each view's weight
// falls linearly to zero at its own image border, and the weights are normalised per pixel.
#pragma once

#include <algorithm>
#include <cstdint>
#include <memory>
#include <vector>

#include "stitch/backend.hpp"
#include "stitch/image.hpp"
#include "stitch/warp/geometry.hpp"

namespace stitch {

class Blender {
 public:
  virtual ~Blender() = default;
  // Rebuilds the weights; call when the geometry changes, not per frame.
  virtual void prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height) = 0;
  // warped[i] is view i warped into its roi (roi-sized); an empty view is left out (a missing
  // camera): the others' weights are renormalised so that no hole is blended in as black.
  virtual void fuse(const std::vector<ImageView>& warped, const ImageView& out) = 0;
  virtual Backend backend() const = 0;

  static std::unique_ptr<Blender> create(Backend backend);
};

// The unnormalised weight of camera pixel (u, v) in a width x height image: a tent that is 1
// at the centre and 0 half a pixel outside the border (eq. 16's position weight, in 2-D).
inline float position_weight(double u, double v, int width, int height) {
  const double hx = width * 0.5, hy = height * 0.5;
  double wx = std::min(u + 0.5, width - 0.5 - u) / hx;
  double wy = std::min(v + 0.5, height - 0.5 - v) / hy;
  if (wx <= 0 || wy <= 0) return 0.f;
  return static_cast<float>(std::min(wx, 1.0) * std::min(wy, 1.0));
}

}  // namespace stitch
