// A final photometric refinement of a rotating lens rig (issue 15, radtan rigs calibrated from
// rough rigs). The dense matches (dense_matches.hpp) place each patch to a few hundredths of a
// pixel, but every located point carries a texture-dependent bias of a few thousandths (sub-pixel
// peak locking and its kin) that is coherent over an overlap and leans on the rig's weakest
// direction: one focal scale for all cameras, with the side cameras' angles following it.
// Here no point is located: the rig's parameters (rotations, focal lengths, k1 / k2 where
// estimated) and a gain / offset per camera pair are fitted directly to the overlaps' brightness
// (Gauss-Newton on the grey-level differences of the two views of fixed scene rays, sampled all
// over each overlap; image gradients through the lens Jacobians; Cauchy weights), so the texture's
// evidence is pooled before any position is decided.
#pragma once

#include <opencv2/core.hpp>
#include <utility>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace stitch {

struct PhotometricRefineOptions {
  double blur_sigma = 1.0;     // smoothing of both views (bilinear interpolation bias, aliasing)
  int step_px = 2;             // sample spacing on each camera's pixel grid
  int iterations = 10;         // Gauss-Newton / Levenberg-Marquardt steps
  double robust_scale = 2.0;   // Cauchy scale, in the residuals' robust sigma
  double min_gradient = 2.0;   // grey levels per pixel: flat samples carry no geometry
};

struct PhotometricRefineResult {
  bool ok = false;
  int samples = 0;
  double rms_before = 0, rms_after = 0;  // grey levels (robust)
};

// Refines `rig` in place. `gray[set][camera]`: 8-bit grey frames. `links`: camera pairs that
// overlap. `refine_lens[i]`: camera i's k1 / k2 are free (else held). The reference camera's
// rotation is held (the gauge). Returns ok = false (rig untouched) when there is too little
// texture or the fit does not lower the cost.
PhotometricRefineResult photometric_refine(Rig& rig, const std::vector<std::pair<int, int>>& links,
                                           const std::vector<std::vector<cv::Mat>>& gray,
                                           const std::vector<bool>& refine_lens,
                                           const PhotometricRefineOptions& o = {});

}  // namespace stitch
