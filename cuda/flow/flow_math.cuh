// Per-pixel math of the GPU dense flow (pyramidal dense Lucas-Kanade), shared by the kernels
// and usable from plain C++ (the functions are __host__ __device__ under nvcc, inline
// otherwise), so the algorithm can be checked on a machine without a GPU.
#pragma once
#include <math.h>
#include <stddef.h>
#include <stdint.h>

#ifdef __CUDACC__
#define FLOW_HD __host__ __device__ __forceinline__
#else
#define FLOW_HD inline
#endif

namespace stitch_cuda {
namespace flow {

// Gaussian window of the structure tensor and of the constraint sums: sigma 2.5 px, cut at
// 2.4 sigma. Tuned on the host prototype: sigma 1.5 doubled the error, 3.5 gained 0.01 px.
constexpr int kWindowRadius = 6;
constexpr int kWindowTaps = 2 * kWindowRadius + 1;
constexpr float kWindowSigma = 2.5f;

// The separable window's taps, summing to one (so G is a mean and lambda is in grey^2/px^2).
FLOW_HD void window_weights(float* w) {
  float sum = 0.f;
  for (int i = -kWindowRadius; i <= kWindowRadius; ++i) {
    w[i + kWindowRadius] = expf(-float(i * i) / (2.f * kWindowSigma * kWindowSigma));
    sum += w[i + kWindowRadius];
  }
  for (int i = 0; i < kWindowTaps; ++i) w[i] /= sum;
}

FLOW_HD int clamp_int(int v, int lo, int hi) { return v < lo ? lo : (v > hi ? hi : v); }
FLOW_HD float clamp_float(float v, float lo, float hi) { return fminf(fmaxf(v, lo), hi); }

// Reads through the read-only cache on the device.
template <typename T>
FLOW_HD float load_pixel(const T* base, size_t pitch, int x, int y) {
#ifdef __CUDA_ARCH__
  return float(__ldg(base + size_t(y) * pitch + size_t(x)));
#else
  return float(base[size_t(y) * pitch + size_t(x)]);
#endif
}

// pyrDown's border: mirror without repeating the edge pixel (BORDER_REFLECT_101).
FLOW_HD int reflect101(int i, int n) {
  if (n == 1) return 0;
  if (i < 0) i = -i;
  if (i >= n) i = 2 * n - 2 - i;
  return clamp_int(i, 0, n - 1);
}

// One pixel of the next pyramid level: 5x5 binomial blur of `src` at (2x, 2y), as cv::pyrDown.
// Pitches are in elements.
template <typename T>
FLOW_HD float pyr_down_at(const T* src, size_t pitch, int w, int h, int x, int y) {
  const float k[5] = {1.f / 16, 4.f / 16, 6.f / 16, 4.f / 16, 1.f / 16};
  float sum = 0.f;
  for (int j = 0; j < 5; ++j) {
    const int sy = reflect101(2 * y + j - 2, h);
    float row = 0.f;
    for (int i = 0; i < 5; ++i) row += k[i] * load_pixel(src, pitch, reflect101(2 * x + i - 2, w), sy);
    sum += k[j] * row;
  }
  return sum;
}

// Bilinear sample with the position clamped into the image (the edge repeats outward).
template <typename T>
FLOW_HD float sample_clamped(const T* img, size_t pitch, int w, int h, float x, float y) {
  x = clamp_float(x, 0.f, float(w - 1));
  y = clamp_float(y, 0.f, float(h - 1));
  const int x0 = int(x), y0 = int(y);  // x, y >= 0: truncation is floor
  const int x1 = x0 + 1 < w ? x0 + 1 : x0, y1 = y0 + 1 < h ? y0 + 1 : y0;
  const float ax = x - float(x0), ay = y - float(y0);
  const float top = (1.f - ax) * load_pixel(img, pitch, x0, y0) + ax * load_pixel(img, pitch, x1, y0);
  const float bottom = (1.f - ax) * load_pixel(img, pitch, x0, y1) + ax * load_pixel(img, pitch, x1, y1);
  return (1.f - ay) * top + ay * bottom;
}

// Scharr gradient (normalised to intensity per pixel), edge pixels repeated.
template <typename T>
FLOW_HD void gradient_at(const T* img, size_t pitch, int w, int h, int x, int y, float& gx, float& gy) {
  const int xm = x > 0 ? x - 1 : 0, xp = x + 1 < w ? x + 1 : x;
  const int ym = y > 0 ? y - 1 : 0, yp = y + 1 < h ? y + 1 : y;
  const float a00 = load_pixel(img, pitch, xm, ym), a10 = load_pixel(img, pitch, x, ym), a20 = load_pixel(img, pitch, xp, ym);
  const float a01 = load_pixel(img, pitch, xm, y), a21 = load_pixel(img, pitch, xp, y);
  const float a02 = load_pixel(img, pitch, xm, yp), a12 = load_pixel(img, pitch, x, yp), a22 = load_pixel(img, pitch, xp, yp);
  gx = (3.f * (a20 - a00) + 10.f * (a21 - a01) + 3.f * (a22 - a02)) * (1.f / 32.f);
  gy = (3.f * (a02 - a00) + 10.f * (a12 - a10) + 3.f * (a22 - a20)) * (1.f / 32.f);
}

// Interleaved (u, v) flow, pitch in float2 elements: bilinear, position clamped.
FLOW_HD void sample_flow(const float* flow, size_t pitch, int w, int h, float x, float y, float& u, float& v) {
  x = clamp_float(x, 0.f, float(w - 1));
  y = clamp_float(y, 0.f, float(h - 1));
  const int x0 = int(x), y0 = int(y);
  const int x1 = x0 + 1 < w ? x0 + 1 : x0, y1 = y0 + 1 < h ? y0 + 1 : y0;
  const float ax = x - float(x0), ay = y - float(y0);
  const float w00 = (1.f - ax) * (1.f - ay), w10 = ax * (1.f - ay), w01 = (1.f - ax) * ay, w11 = ax * ay;
  const float* p00 = flow + 2 * (size_t(y0) * pitch + size_t(x0));
  const float* p10 = flow + 2 * (size_t(y0) * pitch + size_t(x1));
  const float* p01 = flow + 2 * (size_t(y1) * pitch + size_t(x0));
  const float* p11 = flow + 2 * (size_t(y1) * pitch + size_t(x1));
  u = w00 * p00[0] + w10 * p10[0] + w01 * p01[0] + w11 * p11[0];
  v = w00 * p00[1] + w10 * p10[1] + w01 * p01[1] + w11 * p11[1];
}

// Flow of pixel (x, y) of a level from the next coarser level (half size, pyrDown
// coordinates: coarse pixel c sits on fine pixel 2c), displacements doubled.
FLOW_HD void upsample_flow_at(const float* coarse, size_t pitch, int cw, int ch, int x, int y, float& u, float& v) {
  sample_flow(coarse, pitch, cw, ch, 0.5f * float(x), 0.5f * float(y), u, v);
  u *= 2.f;
  v *= 2.f;
}

// Flow of pixel (x, y) at pyramid level `level` from a full-resolution field (`step` = 2^level):
// the mean of the finite full-resolution vectors within step/2 of (step x, step y), scaled
// down.
FLOW_HD void seed_flow_at(const float* full, size_t pitch, int w, int h, int step, int x, int y, float& u, float& v) {
  const int half = step / 2;
  const int cx = step * x, cy = step * y;
  float su = 0.f, sv = 0.f;
  int n = 0;
  for (int j = cy - half; j <= cy + half; ++j) {
    if (j < 0 || j >= h) continue;
    for (int i = cx - half; i <= cx + half; ++i) {
      if (i < 0 || i >= w) continue;
      const float* p = full + 2 * (size_t(j) * pitch + size_t(i));
      const float pu = p[0], pv = p[1];
      if (isfinite(pu) && isfinite(pv)) {
        su += pu;
        sv += pv;
        ++n;
      }
    }
  }
  const float inv = n > 0 ? 1.f / (float(n) * float(step)) : 0.f;
  u = su * inv;
  v = sv * inv;
}

// The windowed terms of one dense Lucas-Kanade step. Every pixel y of a window gives the
// linearised constraint grad(y) . u - c = d(y), d(y) = grad(y) . u(y) - It(y), with grad the
// gradient of `from`, It = to(y + u(y)) - from(y) the mismatch at y's own flow and c the
// window's brightness offset between the images (unknown, like u). The window's weighted sums
// of the constraint products give its flow by least squares: for a constant flow this is the
// classic Lucas-Kanade step; with neighbours of differing flow it averages their measurements
// instead of their mismatches, so estimation noise does not pile up over iterations.
// The offset unknown makes the flow blind to a brightness difference between the cameras,
// as DIS's mean-normalised patches are: without it, an offset of 10 grey levels moved flat
// regions by pixels (host prototype: median error 7.7 px instead of 0.10 px).
struct LkTerms {
  float xx, xy, yy;  // gradient products
  float x, y;        // gradient (for the offset unknown)
  float xd, yd, d;   // gradient times the constraint's right side, and the right side
};

FLOW_HD LkTerms lk_terms(float gx, float gy, float it, float u, float v) {
  LkTerms t;
  t.xx = gx * gx;
  t.xy = gx * gy;
  t.yy = gy * gy;
  t.x = gx;
  t.y = gy;
  t.d = gx * u + gy * v - it;
  t.xd = gx * t.d;
  t.yd = gy * t.d;
  return t;
}

// The new flow at a pixel from its window sums (weights summing to one). Eliminating the
// offset leaves the covariance system (G - g g^T + lambda I) u_new = m - g d + lambda u. The
// Tikhonov term keeps the current flow where the window has no texture (never a division by
// zero); the step limit keeps one ill-conditioned window from jumping.
FLOW_HD void lk_solve(const LkTerms& s, float lambda, float max_step, float& u, float& v) {
  const float gxx = fmaxf(s.xx - s.x * s.x, 0.f), gyy = fmaxf(s.yy - s.y * s.y, 0.f), gxy = s.xy - s.x * s.y;
  const float a = gxx + lambda, c = gyy + lambda, b = gxy;
  const float det = a * c - b * b;
  if (!(det > 1e-12f)) return;
  const float rx = s.xd - s.x * s.d + lambda * u, ry = s.yd - s.y * s.d + lambda * v;
  const float inv = 1.f / det;
  const float nu = (c * rx - b * ry) * inv, nv = (a * ry - b * rx) * inv;
  if (!isfinite(nu) || !isfinite(nv)) return;
  u += clamp_float(nu - u, -max_step, max_step);
  v += clamp_float(nv - v, -max_step, max_step);
}

// No NaN/Inf, and x + u, y + v inside the image (stitch::sanitize of the CPU flows).
FLOW_HD void keep_inside(int x, int y, int w, int h, float& u, float& v) {
  if (!isfinite(u) || !isfinite(v)) u = v = 0.f;
  u = clamp_float(u, float(-x), float(w - 1 - x));
  v = clamp_float(v, float(-y), float(h - 1 - y));
}

}  // namespace flow
}  // namespace stitch_cuda
