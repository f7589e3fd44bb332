// Coarse-to-fine frame warping (paper §3.2): every view is pre-warped onto the output by its
// homography, then, in each overlap, moved by dense optical flow toward its neighbour so that
// the two meet in between (eq. 17) and the blender fuses them without ghosting (eq. 18).
//
// In the overlap of views i and j, with blend weights θ (the normalised position weights the
// blender uses), output pixel p samples
//   view i at p + θ_j(p) · flow_{j→i}(p)   and   view j at p + θ_i(p) · flow_{i→j}(p),
// flow_{a→b}(p) being where the content of a at p lies in b. The two samples then show the
// same scene point, and each view's displacement fades to zero where the other's weight does,
// so nothing jumps at the edge of an overlap. (Eq. 17 as printed scales each view by its own
// weight; that puts the full displacement at the overlap's edge, a visible step.)
#pragma once

#include <memory>
#include <vector>

#include "stitch/backend.hpp"
#include "stitch/flow/flow.hpp"
#include "stitch/image.hpp"
#include "stitch/warp/geometry.hpp"

namespace stitch {

struct FlowWarpSettings {
  bool flow = true;                      // false: homography only
  FlowAlgorithm algorithm = FlowAlgorithm::Dis;
  FlowQuality quality = FlowQuality::Medium;
  int margin = 16;                       // output pixels the overlap is widened by for the flow
  double temporal_smoothing = 0.95;      // weight of last frame's flow where the scene is still
  double consistency_px = 4.0;           // forward-backward error (px) at which confidence is 1/e
  bool fallback = true;                  // never worse than the homography: the per-pixel matching-cost
                                         // gate and the per-overlap decision (flow_gate_math.hpp)
};

// True when going from `a` to `b` changes the flow images (size, implementation): the warper
// rebuilds its pairs and drops their history.
inline bool flow_layout_changed(const FlowWarpSettings& a, const FlowWarpSettings& b) {
  return a.margin != b.margin || a.quality != b.quality || a.algorithm != b.algorithm;
}

// `s` with temporal_smoothing kept below 1, so the flow always follows a changing scene.
inline FlowWarpSettings sanitized(FlowWarpSettings s) {
  s.temporal_smoothing = s.temporal_smoothing < 0.0 ? 0.0 : s.temporal_smoothing > 0.99 ? 0.99 : s.temporal_smoothing;
  return s;
}

// One overlapping pair and what the last frame's flow did there.
struct FlowPairStats {
  int view_a = 0, view_b = 0;
  Rect rect;                     // output pixels, the widened overlap
  double mean_magnitude = 0;     // px, of the applied flow a→b where both views are valid
  double confident_fraction = 0; // of the valid pixels, those passing the forward-backward check
  // What the flow does for the overlap (flow_gate_math.hpp): the views' mean matching error
  // (grey levels, photometric + structural) without and with the flow, and the decision:
  // whether the flow is on and the gain it is applied with next frame (0 = homography only).
  double error_homography = 0, error_flow = 0;
  bool flow_on = true;
  double gain = 1;
};

class FlowWarper {
 public:
  virtual ~FlowWarper() = default;
  // Finds the overlapping pairs and builds the maps; call when the geometry changes.
  virtual void prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height) = 0;
  // Takes effect on the next frame; a change of algorithm or quality drops the history.
  virtual void set_settings(const FlowWarpSettings& settings) = 0;
  // Forgets the previous frames' flow (seek, flush, new stream).
  virtual void reset() = 0;
  // frames[i] is camera i's frame (empty: missing); warped[i] is roi-sized and receives view i
  // pre-warped and flow-warped (left untouched when frames[i] is empty or the roi is).
  virtual void warp(const std::vector<ImageView>& frames, const std::vector<ImageView>& warped) = 0;
  virtual const std::vector<FlowPairStats>& stats() const = 0;
  virtual Backend backend() const = 0;

  static std::unique_ptr<FlowWarper> create(Backend backend);
};

}  // namespace stitch
