#include "stitch/sync/thumbnail.hpp"

#include <stdexcept>

namespace stitch::sync {

void frame_thumbnail_cpu(const uint8_t* data, int width, int height, std::size_t pitch, int bytes_per_pixel,
                         int channel, float* out) {
  for (int ty = 0; ty < kThumbnailH; ++ty)
    for (int tx = 0; tx < kThumbnailW; ++tx)
      out[ty * kThumbnailW + tx] = thumbnail_cell(data, width, height, pitch, bytes_per_pixel, channel, tx, ty);
}

#ifndef STITCH_HAVE_CUDA
struct FrameThumbnailerCuda::Impl {};
FrameThumbnailerCuda::FrameThumbnailerCuda() = default;
FrameThumbnailerCuda::~FrameThumbnailerCuda() = default;
void FrameThumbnailerCuda::thumbnail(const uint8_t*, int, int, std::size_t, int, int, float*) {
  throw std::runtime_error("built without CUDA");
}
void FrameThumbnailerCuda::submit(int, const uint8_t*, int, int, std::size_t, int, int) {
  throw std::runtime_error("built without CUDA");
}
bool FrameThumbnailerCuda::pending(int) const { return false; }
bool FrameThumbnailerCuda::ready(int) const { return false; }
bool FrameThumbnailerCuda::take(int, float*) { return false; }
#endif

}  // namespace stitch::sync
