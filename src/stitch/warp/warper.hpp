// Homography warp of each view into its rectangle of the output (bilinear, precomputed maps).
#pragma once

#include <memory>
#include <vector>

#include "stitch/backend.hpp"
#include "stitch/image.hpp"
#include "stitch/warp/geometry.hpp"

namespace stitch {

class Warper {
 public:
  virtual ~Warper() = default;
  // Rebuilds the per-view maps; call when the geometry changes, not per frame.
  virtual void prepare(const std::vector<ViewPlacement>& views) = 0;
  // Warps camera frame `src` of view `index` into `dst`, an image of exactly roi size.
  // Pixels outside the camera image become transparent black.
  virtual void warp(int index, const ImageView& src, const ImageView& dst) = 0;
  virtual Backend backend() const = 0;

  static std::unique_ptr<Warper> create(Backend backend);
};

}  // namespace stitch
