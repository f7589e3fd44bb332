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
// frame's writers through the CUDA hand-off on this thread, if any).
//
// thumbnail() waits for its result. The element uses submit()/take() instead, so that the 9 KB
// readback never blocks a bundle: submit() queues the kernel and a copy into page-locked host
// memory of a slot (one per view) and records an event; take(), a bundle later, finds it done
// (it waits only if not). The frame's device memory must stay valid until take() returned.
// Both give the CPU's thumbnail bit for bit (thumbnail_math.hpp).
class FrameThumbnailerCuda {
 public:
  FrameThumbnailerCuda();
  ~FrameThumbnailerCuda();  // waits for the work in flight
  FrameThumbnailerCuda(const FrameThumbnailerCuda&) = delete;
  FrameThumbnailerCuda& operator=(const FrameThumbnailerCuda&) = delete;
  // Throws std::runtime_error on a CUDA error, or when built without CUDA.
  void thumbnail(const uint8_t* device_data, int width, int height, std::size_t pitch, int bytes_per_pixel,
                 int channel, float* out);
  // Queues a thumbnail into `slot` (0..; slots are made as needed). A result still pending there
  // is dropped (waited for first).
  void submit(int slot, const uint8_t* device_data, int width, int height, std::size_t pitch, int bytes_per_pixel,
              int channel);
  bool pending(int slot) const;
  // The pending result is there: take() will not wait.
  bool ready(int slot) const;
  // Copies slot's result (kThumbnailW x kThumbnailH floats) into `out`, waiting for it if it is
  // not done yet; false (nothing written) when nothing is pending.
  bool take(int slot, float* out);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace stitch::sync
