// Per-camera lens evidence that needs no other camera (issue 15, mixed rigs): the plumb-line
// principle. Straight scene edges (studs, window frames, a horizon) must be straight in an ideal
// pinhole picture; the lens that straightens a camera's long edge chains is its lens. A rig that
// mixes lenses (a 0.5x ultra-wide beside a 1x camera, an action camera beside a phone) gets each
// camera's own model, distortion and, for fisheyes, focal length from here, where a fit of the
// pair's matches alone cannot tell one camera's lens from the other's (one shared overlap).
#pragma once

#include <string>
#include <vector>

#include "stitch/image.hpp"
#include "stitch/rig/rig.hpp"

namespace stitch {

struct PlumbLineLens {
  // Enough long edge chains to judge (kPlumbMinWindows straight windows at the best lens).
  bool found = false;
  // The camera at the frame's size, principal point at the centre. Pinhole: no distortion seen.
  // Radtan: k1, k2 at fx (a nominal 70-degree focal length: straightness fixes only k1 / fx^2 and
  // k2 / fx^4, the distortion in pixels; rescale them with the focal a calibration finds,
  // plumb_line_rescaled). Fisheye (equidistant, Kannala-Brandt with zero coefficients): fx is the
  // lens's own focal length (the curvature of its straight lines sets its field of view).
  Camera camera;
  // The lens's largest relative move of a radius out to the middle of the frame's side edge
  // (raw over pinhole radius, minus 1): 0 for a rectilinear lens, -0.14 for a 0.5x phone lens,
  // -0.7 for an action camera; comparable between models.
  double edge_bend = 0;
  // The lens straightens clearly more windows than none: at least kPlumbDistortedGain times as
  // many and kPlumbMinWindows more. A mild lens (k1 -0.10 at 75 degrees: 348 vs 340 windows) or a
  // small noisy frame (26 vs 22) keeps its reading as a start but does not make a rig mixed.
  bool distorted = false;
  int windows = 0;             // straight edge windows at the estimate
  int pinhole_windows = 0;     // the same taken as they are (no lens)
  double residual_px = 0;      // their rms distance to their lines at the estimate (raw-scale px)
  double pinhole_residual_px = 0;  // the same windows' taken as they are
  std::string describe() const;
};

// The plumb-line lens of one camera from one or more of its frames (RGBA, one size).
PlumbLineLens plumb_line_lens(const std::vector<ImageView>& frames);

// A fisheye camera's focal length from its frames at each of the Kannala-Brandt k1 given
// (`fisheye`: the plumb-line lens): straightness pins the field of view well once k1 is fixed,
// the two together poorly (they trade off: 456-551 px over six frames of one 495 px lens).
// Returns `fisheye` with each k1 and its focal length (the focal unchanged when the frames show
// too few edges); the frames' edges are found once.
std::vector<Camera> plumb_line_fisheye_at(const std::vector<ImageView>& frames, const Camera& fisheye,
                                          const std::vector<double>& k1s);

// The same lens at another focal length in pixels (a calibration's of the ideal pictures): the
// radtan coefficients rescaled so that the distortion in pixels stays; a fisheye or pinhole takes
// the focal length as it is.
Camera plumb_line_rescaled(const Camera& plumb, double fx);

// Whether the cameras' plumb-line lenses say the rig mixes lenses: every camera judged, at least
// one clearly distorted (PlumbLineLens::distorted) by more than kPlumbMixedBend, and two whose
// edge bends differ by more than that (a camera not clearly distorted counts as bend 0).
bool plumb_lenses_mixed(const std::vector<PlumbLineLens>& lenses);
extern const double kPlumbMixedBend, kPlumbDistortedGain;
extern const int kPlumbMinWindows;

}  // namespace stitch
