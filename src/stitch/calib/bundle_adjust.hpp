// Global refinement of a rotating rig: every camera's rotation and focal length fitted jointly
// to the feature matches of all overlapping pairs (Levenberg-Marquardt, Eigen), so that errors
// do not add up along a chain of pairwise fits; and wave correction, which levels the horizon.
#pragma once

#include <Eigen/Core>
#include <atomic>
#include <chrono>
#include <optional>
#include <string>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace stitch {

struct PairMatches {
  int a = -1, b = -1;
  std::vector<Eigen::Vector2d> pa, pb;  // the same scene point in camera a and camera b (pixels)
  std::vector<double> weight;           // per match (1 / its localisation uncertainty); empty: all 1
  // Raw pixels of the same matches (issue 15), when the cameras have lenses: pa/pb are then the
  // ideal (undistorted) pixels under the start rig's lenses, and the adjustment works on these
  // through lens_unproject / lens_project (the focal changes the undistortion too). Empty: pinhole.
  std::vector<Eigen::Vector2d> ra, rb;
};

struct BundleAdjustOptions {
  bool refine_focal = true;
  // One focal scale for every camera (a rig of identical cameras): the ratios of the start
  // focal lengths stay. Fewer unknowns; per-camera focals can drift along a chain of overlaps.
  bool shared_focal = false;
  int max_iterations = 100;      // LM iterations per round
  double outlier_px = 3.0;       // after the first round, matches off by more are dropped
  // Cameras whose lens.estimate is set also get k1 (and k2 when `estimate_k2`) refined, through
  // the raw matches (issue 15). Off: every lens is kept as given.
  bool estimate_lens = true;
  bool estimate_k2 = true;
  // Cameras of the same lens model and frame size that all estimate share one k1 (k2): fewer
  // unknowns for a rig of identical cameras. Off by default (per-camera lenses measured as well).
  bool shared_lens = false;
  // Lenses estimated from zero coefficients start from a 1-D sweep of the distortion (the focal
  // and rotations fitted for each candidate) instead of k = 0.
  bool sweep_lens = true;
  // > 0: after the rounds above, a few reweighted rounds with Cauchy's loss of scale
  // robust_scale x the matches' robust sigma (1.4826 x their median error): precise, dense matches
  // (dense_matches.hpp) whose few poorly placed ones would otherwise lean on the focal length.
  double robust_scale = 0;
  // Set (by another thread): every minimisation stops at its next iteration, and the report is
  // of an unfinished fit; the caller checks the flag and gives up (calibrator.hpp's cancel).
  const std::atomic<bool>* cancel = nullptr;
  std::optional<std::chrono::steady_clock::time_point> deadline;  // the same once the clock passes it
};

struct BundleAdjustReport {
  double rms_before_px = -1, rms_after_px = -1;  // symmetric transfer error over the kept matches
  int matches = 0, dropped = 0;
  bool ok = false;
  bool lens = false;                 // the residuals went through the cameras' lenses (raw pixels)
  std::vector<int> lens_estimated;   // cameras whose k1 (k2) the adjustment estimated
  double lens_sweep_d = 0;            // the sweep's pick: k1 (r/f)^2 at the half diagonal (0: no sweep)
  std::string lens_warning;          // an estimate that folded the image and was dropped
  // Per camera: the standard error of its estimated k1 (from the fit's Jacobian and residual
  // scale: how well the matches pin it down); 0 where k1 was not estimated.
  std::vector<double> lens_k1_sigma;
};

// Refines R and f (fx, fy together; principal points stay) of every camera (and k1, k2 of
// cameras whose lens asks for an estimate); the reference
// camera's rotation is held (it fixes the rig frame). Cameras without matches stay as they are.
BundleAdjustReport bundle_adjust(Rig& rig, const std::vector<PairMatches>& matches,
                                 const BundleAdjustOptions& options = {});

// Transfer error of one match through the rotation model (pixels, a->b and b->a summed in
// quadrature); the BA's residual.
double transfer_error_px(const Rig& rig, int a, int b, const Eigen::Vector2d& pa, const Eigen::Vector2d& pb);

// Horizontal wave correction: rotates the whole rig so that the cameras' x axes lie in the
// horizontal plane as far as possible (the normal of the plane that they span becomes "up"),
// keeping the reference camera's heading. Returns the rotation applied (rig frame).
Eigen::Matrix3d wave_correct(Rig& rig);

}  // namespace stitch
