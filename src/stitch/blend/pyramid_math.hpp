// The multiband blender's pyramid arithmetic, one definition for the CPU and the CUDA code so
// that both compute the same numbers: OpenCV's 5-tap binomial kernel [1 4 6 4 1]/16, mirrored
// borders (BORDER_REFLECT_101), sizes that halve exactly (the canvas is padded to 2^bands).
#pragma once

#include "stitch/host_device.hpp"

namespace stitch {
namespace pyramid {

STITCH_HD int reflect101(int i, int n) {
  if (n == 1) return 0;
  while (i < 0 || i >= n) i = i < 0 ? -i : 2 * n - 2 - i;
  return i;
}

// Mirror without repeating the edge (BORDER_REFLECT): pads a view's rectangle outwards.
STITCH_HD int reflect(int i, int n) {
  while (i < 0 || i >= n) i = i < 0 ? -i - 1 : 2 * n - 1 - i;
  return i;
}

STITCH_HD float binomial_tap(int i) {  // i in -2..2
  return i == 0 ? 6.f / 16.f : (i == 1 || i == -1) ? 4.f / 16.f : 1.f / 16.f;
}

// Downsampling n -> n/2: dst[x] = sum_i tap(i) · src[reflect101(2x + i, n)], i = -2..2.
STITCH_HD int down_source(int x, int i, int n_src) { return reflect101(2 * x + i, n_src); }

// Upsampling n -> 2n (zero insertion, then the kernel times 2 per axis): the source index and
// weight of tap i (-2..2) at dst x, or -1 where the tap falls on an inserted zero.
STITCH_HD int up_source(int x, int i, int n_dst, float& weight) {
  const int X = reflect101(x + i, n_dst);
  weight = 2.f * binomial_tap(i);
  return (X & 1) ? -1 : X >> 1;
}

}  // namespace pyramid
}  // namespace stitch
