// The grey thumbnail that time alignment's vision signal is measured on (FrameSignal): one
// cell's box average, sampled on a sparse lattice (at most about 4x4 samples per cell). Shared
// by the CPU and the CUDA kernel so that both give the same thumbnail bit for bit.
#pragma once
#include <stddef.h>
#include <stdint.h>

#include "stitch/host_device.hpp"

namespace stitch::sync {

constexpr int kThumbnailW = 64, kThumbnailH = 36;

// Cell (tx, ty) of a `width` x `height` 8-bit plane (`bytes_per_pixel` apart, reading byte
// `channel` of each pixel).
STITCH_HD float thumbnail_cell(const uint8_t* data, int width, int height, size_t pitch, int bytes_per_pixel,
                               int channel, int tx, int ty) {
  const int y0 = ty * height / kThumbnailH;
  const int y1 = (ty + 1) * height / kThumbnailH > y0 + 1 ? (ty + 1) * height / kThumbnailH : y0 + 1;
  const int sy = (y1 - y0) / 4 > 1 ? (y1 - y0) / 4 : 1;
  const int x0 = tx * width / kThumbnailW;
  const int x1 = (tx + 1) * width / kThumbnailW > x0 + 1 ? (tx + 1) * width / kThumbnailW : x0 + 1;
  const int sx = (x1 - x0) / 4 > 1 ? (x1 - x0) / 4 : 1;
  double sum = 0;
  int n = 0;
  for (int y = y0; y < y1 && y < height; y += sy) {
    const uint8_t* row = data + size_t(y) * pitch + channel;
    for (int x = x0; x < x1 && x < width; x += sx) {
      sum += row[size_t(x) * size_t(bytes_per_pixel)];
      ++n;
    }
  }
  return n ? float(sum / n) : 0.f;
}

}  // namespace stitch::sync
