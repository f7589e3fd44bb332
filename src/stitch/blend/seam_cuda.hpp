// The seam finder on the device (built with CUDA only): the same pairs, costs and dynamic
// programming as SeamFinder (seam_math.hpp), on views in device memory; the labels stay on
// the device for the CUDA multiband blender.
#pragma once
#include <memory>
#include <vector>

#include <cuda_runtime_api.h>

#include "stitch/blend/seam.hpp"

namespace stitch {

class SeamFinderCuda {
 public:
  explicit SeamFinderCuda(const SeamSettings& settings = {});
  ~SeamFinderCuda();
  void prepare(const std::vector<ViewPlacement>& views, int width, int height);
  // Device labels (width*height) for this frame's views (device memory, roi-sized; empty =
  // missing); valid until the next call. Without a stream the finder works on its own and has
  // finished on return; with one (where the views were written) it is only queued there, and
  // the labels and mix map are ready in that stream's order (no host synchronisation).
  const uint8_t* find(const std::vector<ImageView>& warped, cudaStream_t stream = nullptr);
  // View i's luma buffer (roi-sized, stitch::seam::luma per pixel) for the next find(), for a
  // producer that computes it while it writes the view (the compositor's warp), in the stream
  // find() is then given: find() does not read the view again for it.
  uint8_t* luma_for_next_find(std::size_t i);
  // The last paths, downloaded (for tests): one per pair of pairs(), empty when not cut.
  std::vector<std::vector<int>> paths() const;
  std::vector<uint8_t> labels() const;  // the last find()'s, downloaded
  // The last find()'s consensus-blend mix levels (SeamFinder::mix): device (nullptr when
  // mix_radius is 0; valid until the next find()), and downloaded.
  const uint8_t* mix_map() const;
  std::vector<uint8_t> mix() const;
  const std::vector<SeamFinder::Pair>& pairs() const;

 private:
  struct State;
  std::unique_ptr<State> s_;
};

}  // namespace stitch
