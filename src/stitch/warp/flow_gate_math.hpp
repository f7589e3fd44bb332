// When stitchflowwarp trusts its flow, one definition for the CPU and the CUDA warper.
//
// Per pixel (the matching-cost gate): the flow a->b is used only where it makes the two views
// match better than the homography alone, by more than sensor noise:
//   gain(p) = blur(|A(p) - B(p)| - |A(p) - B(p + f(p))|)        (grey levels, Gaussian sigma 2)
//   gate(p) = clamp((gain(p) - kGateOffset) / kGateRange, 0, 1)
// and the flow is scaled by gate(p) times the forward-backward confidence. On a background
// that the homography already aligns (at infinity, or the calibrated plane), the flow cannot
// improve the match, so it is zero there: no copy of a distant object is made beside a near
// one, and still scenes do not shimmer.
//
// Per overlap and over time (the decision): the mean matching error of the views, photometric
// |A - B| plus structural |grad A - grad B| / 2, with the flow (B sampled at p + f(p)) and
// without it (the homography). The flow is switched on when it cuts that error by
// kDecisionOn, off when it cuts less than kDecisionOff (hysteresis: no toggling), and its gain
// moves toward 1 (on) or 0 (off) by at most kGainStep per frame, so the fallback is smooth.
// The decision of frame t applies to frame t + 1 (the GPU needs no mid-frame round trip).
#pragma once

#include <math.h>

#include "stitch/host_device.hpp"

namespace stitch {
namespace flow_gate {

constexpr float kGateOffset = 0.5f;   // grey levels of improvement that count as noise
constexpr float kGateRange = 1.0f;    // grey levels from no trust to full trust
constexpr double kGateSigma = 2.0;    // blur of the per-pixel improvement (flow pixels)
constexpr double kDecisionOn = 0.10;  // relative error cut that switches the flow on
constexpr double kDecisionOff = 0.03; // ... below which it is switched off
constexpr double kGainStep = 0.25;    // largest gain change per frame

STITCH_HD float gate(float improvement) {
  const float g = (improvement - kGateOffset) * (1.f / kGateRange);
  return g < 0.f ? 0.f : (g > 1.f ? 1.f : g);
}

// The matching error of one pixel: photometric + half the structural (gradient) difference.
STITCH_HD float match_error(float a, float b, float agx, float agy, float bgx, float bgy) {
  const float dx = agx - bgx, dy = agy - bgy;
  return fabsf(a - b) + 0.5f * (fabsf(dx) + fabsf(dy));
}

// One overlap's decision state.
struct Decision {
  bool on = true;     // a new overlap starts trusting the flow (the gate guards it per pixel)
  double gain = 1.0;  // applied to the flow of the next frame
};

// The relative error cut of the flow; 0 when the homography has no error to cut.
inline double relative_cut(double error_homography, double error_flow) {
  return error_homography > 0.5 ? (error_homography - error_flow) / error_homography : 0.0;
}

inline Decision update(Decision d, double error_homography, double error_flow) {
  const double cut = relative_cut(error_homography, error_flow);
  if (d.on && cut < kDecisionOff) d.on = false;
  else if (!d.on && cut > kDecisionOn) d.on = true;
  const double target = d.on ? 1.0 : 0.0;
  const double step = target - d.gain;
  d.gain += step > kGainStep ? kGainStep : (step < -kGainStep ? -kGainStep : step);
  return d;
}

}  // namespace flow_gate
}  // namespace stitch
