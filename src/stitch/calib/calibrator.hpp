// Calibration: from rough camera parameters (paper eq. 8-12) refined by feature matching
// in the widened overlaps (eq. 13-14, or a full homography), or from the images alone.
// Runs rarely (start-up, on request), on the CPU with OpenCV's features2d.
#pragma once

#include <atomic>
#include <chrono>
#include <optional>
#include <stdexcept>
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

// How the cameras relate. Rotation: every camera turns about one centre (K and R per camera,
// refined jointly by bundle adjustment; exact for any rig whose cameras share a centre, and
// it extrapolates correctly beyond the overlaps). Homography: a free 8-parameter homography
// per camera, chained from the reference (a planar scene seen by translating cameras: a
// document, a wall, a top-down view). Auto: both are fitted and the one that explains held-out
// matches better wins (rotation unless the homography is clearly better); non-planar
// projections always use the rotation model.
enum class CameraModel { Auto, Rotation, Homography };

struct CalibrationOptions {
  Refinement refinement = Refinement::Homography;
  FeatureType features = FeatureType::Sift;
  double overlap_margin = 0.15;    // widen overlaps by this fraction of the view width
  int min_inliers = 20;            // fewer: keep the previous homography for that view
  double ransac_threshold_px = 3.0;
  // calibrate_from_images (no rig, so no lens): also fit a radtan k1/k2 lens to every camera and
  // keep it only when the held-out error clearly drops (issue 15: "when evidence shows
  // distortion"); undistorted cameras stay pinhole.
  bool lens_from_evidence = true;
  // calibrate_from_images: frames that all show a lit image circle on black (circular fisheyes:
  // a 360 camera) are calibrated as fisheyes on a spherical canvas, two back to back or N in a
  // ring (fisheye_guess.hpp), instead of as pinhole cameras that cannot see them.
  bool circular_fisheyes = true;
  // calibrate_from_images: frames without an image circle that the pinhole path cannot calibrate,
  // or calibrates poorly (action cameras: a rectangle cut from a fisheye image, 120-170 degrees
  // across), are tried as full-frame fisheyes: rotations read from matched rays through a guessed
  // equidistant lens, then lenses and focal lengths estimated (calibrate_full_frame_fisheyes).
  bool full_frame_fisheyes = true;
  // calibrate_from_images: each camera's lens read from its own frames first (the plumb-line
  // principle, plumb_line.hpp: straight scene edges must come out straight). When the cameras'
  // lenses clearly differ (a 0.5x ultra-wide beside a 1x camera, an action camera beside a
  // phone), each camera is calibrated with its own lens model and focal length
  // (undistorted pictures calibrated as pinhole cameras, then refined on the raw frames), kept
  // when it explains the held-out matches better than the pinhole fit. Rigs of alike cameras pay
  // only the reading (~0.1 s a camera).
  bool per_camera_lenses = true;
  // Lenses being estimated (issue 15): once the adjustment is close, fit again on
  // correspondences located photometrically all over each overlap (dense_matches.hpp) rather
  // than on the SIFT keypoints alone, whose ~0.25 px noise extrapolated to 1-2 px at the frame
  // corners. Wide-lens (ray-matched) pairs too, through their lenses (branch lens-dual): a
  // back-to-back ring's keypoints carry a bias that reads as k1.
  bool dense_lens_matches = true;
  // After the dense refit of a radtan (not ray-matched) rig: fit rotations, focal lengths and
  // k1 / k2 directly to the overlaps' brightness (photometric_refine.hpp). Measured and left OFF
  // (BENCHMARKS.md, "Ring order ... direct photometric refit"): its optimum moves with the
  // smoothing and the texture as much as the dense matches' does (worst PSNR gap -1.63 dB vs -1.16).
  bool photometric_refit = false;
  double photometric_blur_sigma = 1.0;
  int max_features = 4000;         // per image and overlap
  double feature_megapixels = 1.0; // larger frames are downscaled for detection
  // Planar canvases: which camera model (see CameraModel). Non-planar rigs: always rotation.
  CameraModel model = CameraModel::Auto;
  // Older switch, kept for compatibility: true forces CameraModel::Rotation.
  bool bundle_adjust = false;
  bool wave_correct = true;        // rotation model: level the horizon after the adjustment
  // The canvas projection. calibrate_from_rig: unset keeps the rough rig's; set, it replaces
  // it (homographies and canvas of the rough rig are then dropped). calibrate_from_images:
  // unset chooses from the estimated field of view (plane while the views fit, cylindrical
  // for wide rigs and 360-degree rings, spherical for rigs that also look up or down).
  std::optional<Projection> projection;
  // A held-out match is kept out of both fits and judges them (every holdout_every-th).
  int holdout_every = 5;
  // Set (by another thread): the calibration stops at its next stage (a detection, a pair's
  // match, an adjustment, a guess) with CalibrationCancelled. A live session's background job
  // is useless once the stream ended, and the process waits for its thread.
  const std::atomic<bool>* cancel = nullptr;
  // Set: the same once the steady clock passes it (a background job's budget: the lens fit on a
  // real clip that shows no distortion tried every start for 143 s of a core).
  std::optional<std::chrono::steady_clock::time_point> deadline;
};

// Thrown by the calibration functions when options.cancel is set. Not a RigError: nothing is
// wrong with the rig, and no caller reports it as a calibration failure.
struct CalibrationCancelled : std::runtime_error {
  CalibrationCancelled() : std::runtime_error("calibration cancelled") {}
};
void throw_if_cancelled(const CalibrationOptions& options);

const char* camera_model_name(CameraModel m);

struct PairReport {
  int camera = -1, neighbour = -1;
  int matches = 0, inliers = 0;
  double rms_px = 0;      // residual of the chosen model, camera pixels (held-out matches when
                          // there are enough, else the fitted ones); 0 when not measured. With
                          // the homography model forced: the chain's fit residual, canvas pixels
  bool accepted = false;
  std::string note;
  // The pair's views overlap and feature matches alone did not tie them (or a looser pass did):
  // how far off the calibration is there, measured by area alignment of the overlap (camera b
  // pixels, median over the agreeing patches); -1 when not measured.
  double overlap_px = -1;
};

struct CameraReport {
  int camera = -1;
  int neighbours = 0;     // cameras it has accepted matches with
  int matches = 0;        // accepted matches with them (fitted + held out)
  double rms_px = -1;     // the chosen model's residual over its pairs, camera pixels; -1: none
};

struct CalibrationResult {
  Rig rig;                         // calibrated: homographies (planar) or K, R + canvas
  std::vector<PairReport> pairs;
  std::vector<CameraReport> cameras;  // one per camera
  std::vector<std::string> warnings;
  int refined_cameras = 0;         // cameras whose mapping the features corrected (a planar
                                   // canvas's reference camera never counts: it is the plane)
  double ba_rms_before_px = -1, ba_rms_after_px = -1;  // bundle adjustment, when it ran
  // The model used and the evidence: the one-way rms transfer error (camera pixels) of each
  // model on the held-out matches; -1 when that model was not fitted or nothing was held out.
  CameraModel model = CameraModel::Homography;
  double rotation_heldout_px = -1, homography_heldout_px = -1;
  int heldout_matches = 0;
  bool projection_chosen = false;  // the projection was chosen from the field of view
  bool lens_ran_off = false;       // estimating a lens ran a focal length off: the rough rig was kept
  double hfov_deg = 0, vfov_deg = 0;  // rotation model: field of view the rig covers
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

// No rig: features matched between every pair of cameras (the pad order does not matter),
// focal lengths from the pairwise homographies, rotations along the maximum spanning tree of
// the match graph, bundle adjustment over every pair (a 360-degree ring closes on itself),
// wave correction; the homography chain is fitted too and the held-out matches choose (see
// CameraModel). `reference` -1: the rig's centre (the camera of median heading; the
// match-graph centre for the homography model). Throws RigError when a camera matches no other.
CalibrationResult calibrate_from_images(const std::vector<ImageView>& frames, int reference,
                                        const CalibrationOptions& options);

// The same, pooling the matches of several instants.
CalibrationResult calibrate_from_images(const std::vector<std::vector<ImageView>>& sets, int reference,
                                        const CalibrationOptions& options);

// Lens from evidence (issue 15; calibrate_from_images with lens_from_evidence, and the
// elements' background lens fit, calib_session.hpp): the rough rigs a radtan k1/k2 fit of pinhole
// cameras starts from, every lens radtan with its coefficients to estimate. `model` Rotation: the
// pinhole rig itself; Homography (a planar rig with every camera's homography): rotations read
// from the homographies through a few guessed focal lengths (strong distortion bends the
// rotation model more than a free homography). Empty when there is nothing to start from.
std::vector<Rig> lens_fit_starts(const Rig& pinhole, CameraModel model);
// Rough rigs of a lens fit read from a pinhole fit whose focal lengths cannot be trusted: for a
// few guessed fields of view (60, 45, 80 degrees across the reference's width), every camera's
// rotation read from the pinhole fit's own pixel maps to the reference (its homographies, or
// K R of a rotation rig) through the guessed focal lengths; radtan lenses to estimate; the
// projection chosen from the start's field of view.
std::vector<Rig> lens_fit_guessed_starts(const Rig& pinhole);
// A lens fit (calibrate_from_rig of a start, rotation model) that can be compared: rotation
// model, a held-out error, every lens estimated and sane.
bool lens_fit_usable(const CalibrationResult& lens);
// The evidence rule: a lens is kept only when its error falls below kLensEvidenceRatio (0.7) of
// the pinhole one and by more than kLensEvidenceMinPx (0.2 px), both measured alike.
bool lens_evidence_wins(double pinhole_px, double lens_px);
extern const double kLensEvidenceRatio, kLensEvidenceMinPx;

// The cheap test before a lens fit (the elements' background lens job, calib_session.hpp): whether
// the images show any sign of lens distortion at all. A whole lens fit (lens_fit_starts through
// calibrate_from_rig, dense matches) costs 3-90 s of a core; on cameras without distortion (every
// real clip measured) it finds nothing. This one matches SIFT features once in the overlaps the
// pinhole rig predicts (loosely, as a lens fit's first pass), then adjusts the same matches twice
// from the same starts: pinhole (rotations and focal lengths) and with one radial coefficient k1
// shared by alike cameras (the adjustment's distortion sweep included), and compares the two on
// the held-out matches (every holdout_every-th), raw pixel to raw pixel, each error capped at
// 3 px. Distortion is plausible when k1 explains them clearly and consistently better: rms below
// kLensPrecheckRatio (0.85) of the pinhole one and kLensPrecheckMinPx (0.05 px) less, the paired
// drop of the squared errors more than kLensPrecheckSignificance (3.5) standard errors, and a k1
// that bends the frame's corners by at most kLensPrecheckMaxBend (0.5) of their radius. Looser
// than the evidence rule: the full fit and the judge decide. About a second of a core on a few
// VGA frames. `pinhole`: a calibrated rig (rotation model; a planar rig with homographies also
// gets a start read from them through a guessed focal length, as lens_fit_starts does).
struct LensPrecheck {
  bool plausible = false;
  double pinhole_px = -1, lens_px = -1;  // held-out rms, raw camera pixels (each match capped)
  double k1 = 0;                          // the lens fit's (the reference camera's)
  double bend = 0;                        // k1 (r / f)^2 at its half diagonal r
  int heldout = 0;                        // held-out matches compared
  double significance = 0;                // the paired drop of their squared errors, in standard errors
  double seconds = 0;
  std::string describe() const;           // "k1 -0.093 (corner bend -0.034): 0.555 -> 0.243 px held out ..."
};
LensPrecheck lens_precheck(const Rig& pinhole, const std::vector<std::vector<ImageView>>& sets,
                           const CalibrationOptions& options);
extern const double kLensPrecheckRatio, kLensPrecheckMinPx, kLensPrecheckSignificance, kLensPrecheckMaxBend;

// A calibration from the images alone of cameras whose lenses are known (the elements' lens fit
// found them: a recalibration, a calibration from scratch after a resize or a camera that came
// back; calib_session.hpp). calibrate_from_images calibrates pinhole cameras, and a pinhole fit of
// distorted cameras is what the lens replaced. Here each frame is undistorted through its known
// lens first (ideal pinhole pictures with the known intrinsics, same size), those are calibrated
// as pinhole cameras (rotation model: rotations and focal lengths free to follow a rig that
// moved), and the result, given the known intrinsics and lenses (coefficients held), is refined
// on the raw frames by calibrate_from_rig. `lenses[i]`: camera i's intrinsics and lens; scaled
// when its frames are another size of the same aspect. Throws RigError as the calibrators do
// (and when a camera's known lens does not fit its frames).
CalibrationResult calibrate_from_images_with_lenses(const std::vector<std::vector<ImageView>>& sets, int reference,
                                                    const std::vector<Camera>& lenses,
                                                    const CalibrationOptions& options);

struct AlignmentReport {
  double median_px = -1;   // over all pairs' matches; -1 when nothing could be matched
  double p90_px = -1;      // 90th percentile of the same distances
  int matches = 0;
  std::vector<double> pair_median_px;  // per overlapping pair (i, i+k) in discovery order
  // The same distances divided by the canvas's local magnification at the match (canvas pixels
  // per camera pixel, the geometric mean of the two cameras'): camera pixels, so that rigs whose
  // canvases are scaled differently (a canvas fitted into the same panorama size) compare
  // like for like. -1 when nothing could be matched.
  double median_camera_px = -1;
  std::vector<double> pair_median_camera_px;
};

// Independent check of a calibration: SIFT matches between overlapping views (outliers
// rejected by a fundamental-matrix RANSAC, which assumes no planarity), mapped through the
// calibration to the canvas; the distance between the two ends of each match.
AlignmentReport measure_alignment(const Rig& rig, const std::vector<ImageView>& frames);

const char* refinement_name(Refinement r);
const char* feature_name(FeatureType f);

}  // namespace stitch
