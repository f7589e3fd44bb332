// Camera frames to the bundle's RGBA (stitchsync): NV12 and I420 as decoders deliver them,
// converted by the frame's own Y'CbCr matrix and range as GStreamer's videoconvert does, and
// 4-byte RGB formats copied or swizzled. One interface, a CPU and a CUDA implementation that
// give the same bytes (both follow yuv_math.hpp).
#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>

#include "stitch/backend.hpp"
#include "stitch/image.hpp"

namespace stitch {

enum class FrameFormat { RGBA, RGBx, BGRA, BGRx, NV12, I420 };

// How Y'CbCr maps to R'G'B' and where 4:2:0 chroma sits on the luma grid.
struct YuvColorimetry {
  double kr = 0.2126, kb = 0.0722;  // the matrix: BT.709 here, BT.601 is 0.299 / 0.114
  bool full_range = false;          // false: Y' 16-235, Cb/Cr 16-240
  bool chroma_cosited_x = false;    // chroma on the even luma columns (MPEG-2, H.264) ...
  bool chroma_cosited_y = false;    // ... and rows; otherwise half-way between two
};

// A camera frame: NV12 planes are Y and interleaved CbCr, I420's Y, Cb, Cr; RGB formats use
// plane 0 only.
struct FrameView {
  FrameFormat format = FrameFormat::RGBA;
  int width = 0, height = 0;
  const uint8_t* planes[3] = {nullptr, nullptr, nullptr};
  std::size_t pitches[3] = {0, 0, 0};
  bool on_device = false;  // true: the planes are CUDA device pointers
  YuvColorimetry colorimetry;
};

bool is_yuv420(FrameFormat format);

class FrameConverter {
 public:
  virtual ~FrameConverter() = default;
  // out (RGBA, the frame's size) = in converted; alpha 255 where the input has none. Either
  // side may be in system or device memory (the CPU implementation takes system memory only).
  // The CUDA implementation queues the work on its stream: call finish() before `in` is
  // released or `out` is read.
  virtual void convert(const FrameView& in, const ImageView& out) = 0;
  // Fills `out` with transparent black (a camera that has not delivered a frame yet).
  virtual void clear(const ImageView& out) = 0;
  // Waits until the queued work is done.
  virtual void finish() = 0;
  virtual Backend backend() const = 0;
  static std::unique_ptr<FrameConverter> create(Backend backend);
};

}  // namespace stitch
