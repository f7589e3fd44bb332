// The per-pixel arithmetic of frame conversion, shared by the CPU implementation and the CUDA
// kernels so that both give the same bytes: Y'CbCr -> R'G'B' in fixed point (exact integers
// on both sides), 4:2:0 chroma interpolated bilinearly at its siting.
#pragma once
#include <stddef.h>
#include <stdint.h>

#include "stitch/host_device.hpp"

namespace stitch {

// Coefficients for 16 x the chroma step and for luma, so that sums land in Q20
// (1 << 20 = one output level). Bounds: |sum| < 2^30 for every matrix and range.
struct YuvToRgbQ16 {
  int32_t y_offset = 16;  // 16 (limited range) or 0 (full)
  int32_t y_gain = 0;     // Q16: 255/219 or 1
  int32_t r_v = 0, g_u = 0, g_v = 0, b_u = 0;  // Q16 per chroma step
};

// R' = Y' + 2(1-kr) Cr, B' = Y' + 2(1-kb) Cb, G' = Y' - (2kb(1-kb) Cb + 2kr(1-kr) Cr) / kg,
// with Y' and Cb, Cr normalised by the range (219/224 levels limited, 255 full).
inline YuvToRgbQ16 yuv_to_rgb_q16(double kr, double kb, bool full_range) {
  const double kg = 1.0 - kr - kb;
  const double y_scale = full_range ? 1.0 : 255.0 / 219.0;
  const double c_scale = full_range ? 1.0 : 255.0 / 224.0;
  auto q16 = [](double v) { return int32_t(v * 65536.0 + (v < 0 ? -0.5 : 0.5)); };
  YuvToRgbQ16 k;
  k.y_offset = full_range ? 0 : 16;
  k.y_gain = q16(y_scale);
  k.r_v = q16(2.0 * (1.0 - kr) * c_scale);
  k.g_u = q16(-2.0 * kb * (1.0 - kb) / kg * c_scale);
  k.g_v = q16(-2.0 * kr * (1.0 - kr) / kg * c_scale);
  k.b_u = q16(2.0 * (1.0 - kb) * c_scale);
  return k;
}

STITCH_HD uint8_t q20_to_u8(int32_t v) {
  v = (v + (1 << 19)) >> 20;
  return uint8_t(v < 0 ? 0 : v > 255 ? 255 : v);
}

// Two chroma samples and the weight of the first, in quarters, for luma coordinate x of a
// plane `n` samples wide. Co-sited: sample j sits on luma 2j; else between luma 2j and 2j+1.
struct ChromaTaps {
  int i0, i1, w0;
};

STITCH_HD ChromaTaps chroma_taps(int x, bool cosited, int n) {
  const int j = x >> 1;
  ChromaTaps t;
  if (cosited) {
    t.i0 = j;
    t.i1 = (x & 1) ? j + 1 : j;
    t.w0 = (x & 1) ? 2 : 4;
  } else if (x & 1) {
    t.i0 = j;
    t.i1 = j + 1;
    t.w0 = 3;
  } else {
    t.i0 = j - 1;
    t.i1 = j;
    t.w0 = 1;
  }
  t.i0 = t.i0 < 0 ? 0 : t.i0 > n - 1 ? n - 1 : t.i0;
  t.i1 = t.i1 < 0 ? 0 : t.i1 > n - 1 ? n - 1 : t.i1;
  return t;
}

// 16 x (interpolated chroma - 128); `step` is 1 for a planar plane, 2 for NV12's CbCr pairs.
STITCH_HD int32_t chroma16(const uint8_t* plane, size_t pitch, int step, ChromaTaps tx, ChromaTaps ty) {
  const uint8_t* r0 = plane + size_t(ty.i0) * pitch;
  const uint8_t* r1 = plane + size_t(ty.i1) * pitch;
  const int32_t a = tx.w0 * r0[tx.i0 * step] + (4 - tx.w0) * r0[tx.i1 * step];
  const int32_t b = tx.w0 * r1[tx.i0 * step] + (4 - tx.w0) * r1[tx.i1 * step];
  return ty.w0 * a + (4 - ty.w0) * b - 16 * 128;
}

// One RGBA pixel from luma `y` and 16 x centred chroma.
STITCH_HD void yuv_to_rgba(const YuvToRgbQ16& k, int32_t y, int32_t cb16, int32_t cr16, uint8_t* px) {
  const int32_t l = (y - k.y_offset) * k.y_gain * 16;
  px[0] = q20_to_u8(l + cr16 * k.r_v);
  px[1] = q20_to_u8(l + cb16 * k.g_u + cr16 * k.g_v);
  px[2] = q20_to_u8(l + cb16 * k.b_u);
  px[3] = 255;
}

// A 4:2:0 frame: luma plane, Cb and Cr planes (NV12: cr = cb + 1, step 2).
struct Yuv420Planes {
  const uint8_t* y;
  const uint8_t* cb;
  const uint8_t* cr;
  size_t y_pitch, cb_pitch, cr_pitch;
  int step;  // bytes between chroma samples of one plane
  int width, height;
  bool cosited_x, cosited_y;
};

STITCH_HD void yuv420_pixel(const Yuv420Planes& p, const YuvToRgbQ16& k, int x, int y, uint8_t* px) {
  const ChromaTaps tx = chroma_taps(x, p.cosited_x, (p.width + 1) >> 1);
  const ChromaTaps ty = chroma_taps(y, p.cosited_y, (p.height + 1) >> 1);
  yuv_to_rgba(k, p.y[size_t(y) * p.y_pitch + x], chroma16(p.cb, p.cb_pitch, p.step, tx, ty),
              chroma16(p.cr, p.cr_pitch, p.step, tx, ty), px);
}

// A 4-byte RGB pixel to RGBA: `swap_rb` for B,G,R order, `opaque` when the 4th byte is padding.
STITCH_HD void rgb4_pixel(const uint8_t* in, bool swap_rb, bool opaque, uint8_t* px) {
  const uint8_t r = in[swap_rb ? 2 : 0], b = in[swap_rb ? 0 : 2];
  px[0] = r;
  px[1] = in[1];
  px[2] = b;
  px[3] = opaque ? 255 : in[3];
}

}  // namespace stitch
