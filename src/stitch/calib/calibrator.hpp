// Calibration: from rough camera parameters (paper eq. 8-12) refined by feature matching
// in the widened overlaps (eq. 13-14, or a full homography), or from the images alone.
// Runs rarely (start-up, on request), on the CPU with OpenCV's features2d.
#pragma once

#include <string>
#include <vector>

#include "stitch/image.hpp"
#include "stitch/rig/rig.hpp"

namespace stitch {

enum class Refinement {
  None,        // rough homographies only
  SkewScale,   // the paper's H' = M H N: per-axis scale and translation
  Homography,  // a full projective correction in the overlap (falls back to SkewScale)
};

enum class FeatureType { Sift, Orb, Akaze };

struct CalibrationOptions {
  Refinement refinement = Refinement::Homography;
  FeatureType features = FeatureType::Sift;
  double overlap_margin = 0.15;    // widen overlaps by this fraction of the view width
  int min_inliers = 20;            // fewer: keep the previous homography for that view
  double ransac_threshold_px = 3.0;
  int max_features = 4000;         // per image and overlap
  double feature_megapixels = 1.0; // larger frames are downscaled for detection
  // Refine every camera's rotation and focal length jointly on all pairwise matches (bundle
  // adjustment) instead of chaining pairwise corrections; always on for non-planar rigs.
  bool bundle_adjust = false;
  bool wave_correct = true;        // non-planar rigs: level the horizon after the adjustment
};

struct PairReport {
  int camera = -1, neighbour = -1;
  int matches = 0, inliers = 0;
  double rms_px = 0;      // residual of the inliers after the fit, canvas pixels
  bool accepted = false;
  std::string note;
};

struct CalibrationResult {
  Rig rig;                         // calibrated: homographies (planar) or K, R + canvas
  std::vector<PairReport> pairs;
  std::vector<std::string> warnings;
  int refined_cameras = 0;         // cameras whose homography the features corrected
  double ba_rms_before_px = -1, ba_rms_after_px = -1;  // bundle adjustment, when it ran
};

// `rough` needs camera parameters (a cylindrical or spherical rig: K and R, refined by bundle
// adjustment; so is a planar one with options.bundle_adjust); homographies already in it are used as the starting
// point instead. frames[i] is camera i (RGBA). Throws RigError on degenerate geometry;
// a refinement that fails keeps the rough homography and adds a warning.
CalibrationResult calibrate_from_rig(const Rig& rough, const std::vector<ImageView>& frames,
                                     const CalibrationOptions& options);

// The same, pooling the matches of several instants (sets[t][camera]) of a static rig: moving
// people and noise average out, and textureless moments are bridged.
CalibrationResult calibrate_from_rig(const Rig& rough, const std::vector<std::vector<ImageView>>& sets,
                                     const CalibrationOptions& options);

// No rig: pairwise homographies from features, chained to `reference` (-1: middle camera)
// along the strongest matches. Throws RigError when a camera matches no other.
CalibrationResult calibrate_from_images(const std::vector<ImageView>& frames, int reference,
                                        const CalibrationOptions& options);

// The same, pooling the matches of several instants.
CalibrationResult calibrate_from_images(const std::vector<std::vector<ImageView>>& sets, int reference,
                                        const CalibrationOptions& options);

struct AlignmentReport {
  double median_px = -1;   // over all pairs' matches; -1 when nothing could be matched
  int matches = 0;
  std::vector<double> pair_median_px;  // per overlapping pair (i, i+k) in discovery order
};

// Independent check of a calibration: SIFT matches between overlapping views (outliers
// rejected by a fundamental-matrix RANSAC, which assumes no planarity), mapped through the
// calibration to the canvas; the distance between the two ends of each match.
AlignmentReport measure_alignment(const Rig& rig, const std::vector<ImageView>& frames);

const char* refinement_name(Refinement r);
const char* feature_name(FeatureType f);

}  // namespace stitch
