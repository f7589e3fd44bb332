// Time alignment's frame thumbnail (thumbnail_math.hpp) on the CPU and on the device: a CUDA-
// memory frame is reduced where it lies and only its 64x36 cells come back to the host.
#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>

#include "stitch/sync/thumbnail_math.hpp"

namespace stitch::sync {

// kThumbnailW x kThumbnailH cells into `out` from an 8-bit plane in host memory.
void frame_thumbnail_cpu(const uint8_t* data, int width, int height, std::size_t pitch, int bytes_per_pixel,
                         int channel, float* out);

// The same for a plane in device memory, on the thumbnailer's own stream (it waits for the
// frame's writers through the CUDA hand-off on this thread, if any, and for its own result).
class FrameThumbnailerCuda {
 public:
  FrameThumbnailerCuda();
  ~FrameThumbnailerCuda();
  FrameThumbnailerCuda(const FrameThumbnailerCuda&) = delete;
  FrameThumbnailerCuda& operator=(const FrameThumbnailerCuda&) = delete;
  // Throws std::runtime_error on a CUDA error, or when built without CUDA.
  void thumbnail(const uint8_t* device_data, int width, int height, std::size_t pitch, int bytes_per_pixel,
                 int channel, float* out);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stitch::sync
