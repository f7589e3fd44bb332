// Plain description of a frame the core works on: no GStreamer, no ownership.
#pragma once
#include <cstddef>
#include <cstdint>

namespace stitch {

enum class PixelFormat { RGBA8 };

struct ImageView {
  uint8_t* data = nullptr;
  std::size_t pitch = 0;  // bytes per row
  int width = 0;
  int height = 0;
  PixelFormat format = PixelFormat::RGBA8;
  bool on_device = false;  // true: data is a CUDA device pointer

  uint8_t* row(int y) const { return data + static_cast<std::size_t>(y) * pitch; }
  bool empty() const { return data == nullptr || width <= 0 || height <= 0; }
};

}  // namespace stitch
