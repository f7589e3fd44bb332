// Calibration policy over a whole stream, as a state machine with no GStreamer and no threads:
// which frames to calibrate from (quality), when to calibrate (first usable frame, a pooling
// window over the first seconds, recalibration on request, at an interval or on drift), whether a
// new calibration replaces the current one (it must beat it on held-out frames), how long to keep
// trying, and what to say about it (events). The element feeds bundles and runs the jobs the
// session hands out (run_calib_job, in a worker thread); the session never blocks.
#pragma once

#include <algorithm>
#include <array>
#include <atomic>
#include <cstdint>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "stitch/calib/calibrator.hpp"
#include "stitch/image.hpp"
#include "stitch/rig/rig.hpp"
#include "stitch/warp/geometry.hpp"

namespace stitch {

// ---- frame quality ---------------------------------------------------------------------------

enum class FrameVerdict { Good, Dark, Featureless, Blurred, Corrupt };
const char* frame_verdict_name(FrameVerdict v);

struct FrameQuality {
  FrameVerdict verdict = FrameVerdict::Good;
  double mean_luma = 0;   // 0..255
  double contrast = 0;    // luma standard deviation
  double sharpness = 0;   // variance of the Laplacian (downscaled to ~320 px wide)
  int corners = 0;        // FAST corners on the same image
  double tear = 0;        // strongest row discontinuity against its neighbourhood (corrupt frames)
  double tear_row = 0;    // where it is, as a fraction of the height
  std::uint64_t picture = 0;  // fingerprint of the grey copy: equal for the same picture again (a still)
  double score() const;   // larger is better (for picking among good frames)
  std::string describe() const;  // "dark (mean luma 3)", ...
};

// RGBA view -> verdict. Cheap (a few ms): works on a ~320 px wide grey copy.
FrameQuality assess_frame(const ImageView& view);

// ---- canvas helpers --------------------------------------------------------------------------

// Moves the canvas of a calibrated rig by canvas' = s * canvas + (tx, ty) (pixel-centre
// convention), for every projection, and sets the canvas size.
void transform_canvas(Rig& rig, double s, double tx, double ty, int width, int height);
// Pads the canvas to even sizes (encoders take 4:2:0 only at even sizes; stitchblend rounds the
// same way): the saved canvas is the panorama size. A 360-degree canvas is scaled instead so that
// it keeps closing. Returns true when something changed.
bool make_canvas_even(Rig& rig);
// Fits the whole canvas into width x height (uniform scale, centred): a recalibration keeps the
// panorama size (stitchblend keeps it too), so the saved canvas stays the video's size.
void fit_canvas(Rig& rig, int width, int height);
// The panorama downstream (stitchblend's output-width/-height or the size a capsfilter fixes,
// and its crop): when it shows the canvas smaller, the canvas itself is scaled down to it, so
// that the stages between (colour, flow warp, seams, multiband) work at the size that is
// output rather than at the cameras' full resolution, and the saved canvas is the output's
// size. Returns the scale applied (1: unchanged; never enlarged). A 360-degree canvas keeps
// closing exactly at the wrap.
double shrink_canvas_to_output(Rig& rig, int output_width, int output_height, CropMode crop);

// ---- jobs (run by a worker) ------------------------------------------------------------------

struct SessionConfig {
  std::string rig_file, load_file, save_file;
  CalibrationOptions options;
  std::optional<Projection> projection;  // unset: the rig-file's
  int reference = -1;
  int calibration_frames = 5;          // pooled frame sets (1: the first usable frame only)
  double calibration_window_s = 2.0;   // pooled sets are spread over this much running time
  double calibration_timeout_s = 30;   // uncalibrated this long: an error (0: keep trying)
  double recalibrate_interval_s = 0;   // 0: only on request
  double drift_threshold_px = 0;       // 0: no drift watch
  double drift_check_interval_s = 5;
  double retry_interval_s = 0.5;       // between failed first attempts (live; files: see FirstAttempts)
  // Files (non-live): the bundles that arrive before the first calibration are held (at most
  // this many bytes) and go out with it (EarlyBundles).
  std::size_t hold_before_first_bytes = std::size_t(512) << 20;
  double pending_interval_s = 1;       // pending messages at most this often
  double qos_interval_s = 1;           // QoS messages for dropped bundles at most this often
  double load_misfit_px = 4;           // a loaded calibration worse than this warns
  bool resize_is_error = false;        // on-resize=error
  // The panorama stitchblend makes (0: the canvas's size): a first calibration's canvas is
  // shrunk to it (shrink_canvas_to_output).
  int output_width = 0, output_height = 0;
  CropMode output_crop = CropMode::None;
  // A camera that has not delivered a frame, or shows a dark picture, this long (running time)
  // before the first calibration is left out of it: the others are calibrated and stitched, and
  // it joins with a calibration from scratch once it delivers. 0: wait for every camera.
  double leave_out_after_s = 4.0;
};

// Lens: the background lens-from-evidence fit (see CalibSession: "lens from evidence").
enum class JobKind { First, Pooled, Recalibration, DriftCheck, LoadCheck, Lens };
const char* job_kind_name(JobKind k);

// At the end of the stream, whether the job in flight is cancelled rather than waited for: what
// it would make applies to frames that will never come. The lens fit always; the automatic pooled
// recalibration and a returning camera's calibration (`calibrated`: one is installed) unless
// `saving` (a save-file records it). A first calibration and a requested recalibration (its
// message is awaited) are finished.
bool cancel_at_end_of_stream(JobKind kind, bool calibrated, bool saving);

// Whether the stream waits for the job in flight before the bundle goes on: a calibration with
// nothing installed always (there is no panorama yet); a returning camera's calibration (kind
// First while one is `calibrated`) when the cameras are not `live`: files then show the camera
// from about the bundle it came back on, whatever the machine's speed, as a late file camera's
// first calibration does. Live cameras go on without it meanwhile: the panorama must not stop.
bool stream_waits_for_job(JobKind kind, bool calibrated, bool live);

// Pairs (i, j), i < j, of views of one size that show the same picture (mean absolute difference
// under 1 grey level at 64 px across): the same source given to two pads. Views in `skip` and
// empty ones are not compared.
std::vector<std::pair<int, int>> identical_views(const std::vector<ImageView>& views, std::uint64_t skip = 0);

// Owned copies of one bundle's views (RGBA).
struct FrameSet {
  std::vector<cv::Mat> images;
  std::vector<ImageView> views() const;
  static FrameSet copy_of(const std::vector<ImageView>& views);
};

// What a running job is doing, for a stream that waits for it (stitchcalib-pending while a file
// waits for its first calibration): written by the worker, read by the element's streaming thread.
enum class JobStage { Estimating, Measuring, LensTest, LensFit, LensJudging };
const char* job_stage_name(JobStage s);  // "estimating the cameras", "lens fit", ...
struct JobProgress {
  std::atomic<JobStage> stage{JobStage::Estimating};
};

struct CalibJob {
  JobKind kind = JobKind::First;
  std::uint64_t serial = 0;
  // First: which attempt this is (1: the first; files retry a failed one on the next bundles).
  int attempt = 1;
  std::shared_ptr<JobProgress> progress = std::make_shared<JobProgress>();
  SessionConfig config;
  std::optional<Rig> rough;                 // from the rig-file (sizes adapted)
  std::shared_ptr<const Rig> current;       // the calibration to beat (or to check)
  std::vector<FrameSet> calib_sets, holdout_sets;
  int fit_width = 0, fit_height = 0;        // > 0: fit the new canvas into this panorama size
  // Cameras calibrated without (their frames are not in calib_sets, nor in `rough`): the result
  // holds a left-out placeholder for each (Camera::left_out), sized from `sizes` (every camera's).
  std::uint64_t left_out = 0;
  // First, from the images, cameras not live: the lens-from-evidence fit (as JobKind::Lens) runs
  // inside this job, and its lens, when it wins, is the first calibration's. A file waits for it,
  // so a short clip (20-30 frames, over before the background fit) is stitched with the lens
  // from its first panorama on; a live stream gets the fit in the background (it must not stall).
  bool lens_before_output = false;
  std::vector<std::array<int, 2>> sizes;
  // The cameras' known lenses (intrinsics and lens, per camera; empty: none known): a calibration
  // from the images (First, Pooled, Recalibration) keeps them (calibrate_from_images_with_lenses)
  // instead of calibrating pinhole cameras; see CalibSession, "lens from evidence".
  std::vector<Camera> lenses;
};

struct PairResidual {
  int a = -1, b = -1;
  double median_px = -1;  // canvas pixels, over the held-out frames' independent matches
  double median_camera_px = -1;  // the same in camera pixels (AlignmentReport::median_camera_px)
  int matches = 0;
};

// Residuals of a rig on frame sets: independent matches of every overlapping pair (see
// measure_alignment), per pair, per camera and overall. Checks `cancel` between pairs.
struct RigResiduals {
  std::vector<PairResidual> pairs;
  std::vector<double> camera_px;  // match-weighted mean of its pairs' medians; -1: no pair measured
  double median_px = -1;          // match-weighted mean of the pair medians; -1: nothing measured
  double rms_px = -1;             // root mean square of the pair medians (match-weighted)
  // The match-weighted mean of the pair medians in camera pixels: free of the canvas's scale,
  // which is what a new calibration is judged by (a canvas fitted into the same panorama size
  // shrinks every canvas-pixel residual with it).
  double median_camera_px = -1;
  int matches = 0;
  // Pairs whose views overlap (pinhole cameras, kMinVerifiableOverlap of a frame or more) but
  // that nothing measured: no feature matched there and the overlap is too plain to align by
  // area (a duct, a sky). The figures above leave them out, so a seam there may be far off while
  // they read well (a 5-camera ring at 8% overlap: 10.7 px off the truth at 0.25 camera px).
  std::vector<std::pair<int, int>> unverified;
};
constexpr double kMinVerifiableOverlap = 0.03;
RigResiduals measure_residuals(const Rig& rig, const std::vector<FrameSet>& sets, const std::atomic<bool>* cancel);
// An installed calibration whose overlaps stay this far apart (camera px, independent matches)
// is said in a warning: real clips with parallax measure 0.5-1.8, a strong barrel lens left
// pinhole 17.5 (probe-lens).
constexpr double kPoorAlignmentCameraPx = 5.0;
// The warning for residuals over `limit_camera_px` (their match-weighted median, camera px),
// naming the worst pair; empty within it or when nothing was measured.
std::string poor_alignment_text(const RigResiduals& residuals, double limit_camera_px);
// The warning for RigResiduals::unverified (empty when none).
std::string unverified_overlap_text(const RigResiduals& residuals);

// How much of the canvas each camera covers (its share of the canvas area; 0 when left out or
// off the canvas) and all of them together, on a grid of ~160 cells across.
struct RigCoverage {
  std::vector<double> camera_share;
  double share = 0;
};
RigCoverage rig_coverage(const Rig& rig);

// Whether a new calibration (pooled, recalibration) replaces the current one, both measured on
// the same held-out frames. It must be better by 10% and 0.05 px in camera pixels (canvas pixels
// favour the rig whose canvas is scaled down), and must keep what the current one has:
//  - every overlap: a pair of cameras the current calibration aligns on held-out matches (16 or
//    more, median under 10 camera px) keeps at least half of those matches (a candidate that
//    pulls two cameras apart leaves nothing there to be judged by);
//  - the picture: no camera's share of the canvas falls below 2/3 of what it is now, and the
//    canvas covered by any camera does not fall by more than 5 points, unless the candidate
//    halves the residual (the current calibration is badly off).
struct Judgement {
  bool install = false;
  std::string reason;  // why not (empty when installed)
};
Judgement judge_candidate(const RigResiduals& candidate, const RigResiduals& current, const RigCoverage& candidate_cover,
                          const RigCoverage& current_cover);
// A lens fit's candidate (JobKind::Lens, or the one a non-live first calibration runs): judged
// as any candidate, and it must win by the evidence rule of calibrate_from_images
// (lens_evidence_wins: a lens only where the images show distortion), in camera pixels on the
// same frames.
Judgement judge_lens_candidate(const RigResiduals& candidate, const RigResiduals& current,
                               const RigCoverage& candidate_cover, const RigCoverage& current_cover);

struct CalibOutcome {
  JobKind kind = JobKind::First;
  std::uint64_t serial = 0;
  bool cancelled = false;
  bool fatal = false;           // the geometry cannot be repaired by other frames
  std::string error;            // empty: success
  std::optional<CalibrationResult> result;  // the new calibration (First, Pooled, Recalibration)
  RigResiduals candidate, current;          // on the held-out frames (or the calibration's own)
  RigCoverage candidate_cover, current_cover;  // Pooled, Recalibration
  std::string residual_source;              // "held-out" or "calibration frames"
  // A job given known lenses: whether the result keeps them (false: the refit with them failed,
  // `lens_error` says why, and the result is the pinhole calibration of the raw frames).
  bool kept_lenses = false;
  std::string lens_error;
  std::optional<LensPrecheck> lens_precheck;  // Lens: the cheap test before the fit (lens_precheck)
  // First with CalibJob::lens_before_output: whether the lens fit ran (installed or not, it is
  // not run again in the background), and why it was not kept (empty when it was).
  bool lens_tried = false;
  std::string lens_not_kept;
};

// The work of one job; pure, may run in any thread. Catches nothing: the caller does.
CalibOutcome run_calib_job(const CalibJob& job, const std::atomic<bool>& cancel);

// ---- the session -----------------------------------------------------------------------------

struct CalibReport {        // one installed (or rejected) calibration, for the bus
  std::uint64_t version = 0;
  std::string source;        // file, rig, images, pooled, recalibration, kept (a camera left)
  std::shared_ptr<const Rig> rig;
  int refined_cameras = 0, inliers = 0, warnings = 0;
  double fit_rms_px = -1;    // the calibrator's own residual over accepted pairs (-1: not given)
  double ba_rms_px = -1;
  RigResiduals residuals;    // independent, see residual_source
  std::string residual_source;
  double previous_px = -1;   // the calibration it replaced (or kept), same frames
  double previous_camera_px = -1;  // the same in camera pixels (RigResiduals::median_camera_px)
  std::string rejected_because;    // a rejected candidate: why (judge_candidate)
  double coverage = -1, previous_coverage = -1;  // RigCoverage::share (pooled, recalibration)
  std::string model;         // "rotation" or "homography" (planar canvases); empty: a loaded file
};

// What lenses a rig's cameras have, for messages: "pinhole" when none has one, else the models
// (e.g. "radtan", "fisheye", "radtan, pinhole").
std::string rig_lens_summary(const Rig& rig);

struct SessionEvent {
  enum class Type { Installed, Rejected, Pending, Qos, Warning, Error } type = Type::Warning;
  std::string text;          // Pending: why; Warning, Error: the message
  CalibReport report;        // Installed, Rejected
  double waited_s = 0;       // Pending
  std::uint64_t processed = 0, dropped = 0;  // Qos (totals)
};

// A first calibration from the images needs every camera. In a non-live pipeline the cameras
// that have started decode as fast as they can while stitchsync stands in for a late one, and
// every bundle without it is dropped: a file camera that started 2 s late in wall time cost ~11 s
// of the others' video. Holding each such bundle a while (back-pressure on stitchsync) keeps the
// others at one frame per slice until it comes; the wall-time budget bounds what a camera that
// never comes costs. The slices grow (200 ms, doubling, 1 s at most): a camera a moment late
// joins within 200 ms, one 8 s late costs the others 11 frames instead of 40 (each held bundle
// is a frame of theirs that is never stitched). Live cameras run at their own pace: never held.
class LateCameraHold {
 public:
  static constexpr std::int64_t kSliceUs = 200000, kMaxSliceUs = 1000000, kBudgetUs = 10000000;
  // Microseconds to hold this bundle (0: none), counted against the budget.
  std::int64_t wait_us(bool waits_for_a_camera, bool live) {
    if (!waits_for_a_camera || live || spent_us_ >= kBudgetUs) return 0;
    const std::int64_t w = std::min(slice_us_, kBudgetUs - spent_us_);
    spent_us_ += w;
    slice_us_ = std::min(kMaxSliceUs, 2 * slice_us_);
    return w;
  }
  void reset() { spent_us_ = 0, slice_us_ = kSliceUs; }

 private:
  std::int64_t spent_us_ = 0, slice_us_ = kSliceUs;
};

// Files (non-live inputs) are stitched to the frame: a panorama for every frame set, however long
// the first calibration takes or however many attempts fail before one succeeds (a 6-camera ring
// at 8% overlap failed its first attempt on frame 1 and gave its first panorama at frame 16 of
// 20). The bundles that come before the first calibration are held, oldest first, and go out
// with it, in order. Bounded: `max_bytes` of held bundles (the oldest are dropped beyond, said
// once: bound_reached), and the calibration timeout (the stream then stops with an error). Only
// complete bundles of one layout are held (a bundle that lacks a camera is not stitched with a
// calibration made of every camera; a size change drops the older ones). Live inputs hold
// nothing: their panorama must not stall behind a backlog. `T` is the element's bundle handle
// (GstBuffer*): what comes out of keep() and take() is the caller's to release.
template <class T>
class EarlyBundles {
 public:
  explicit EarlyBundles(std::size_t max_bytes = std::size_t(512) << 20) : max_bytes_(max_bytes) {}
  void set_max_bytes(std::size_t max_bytes) { max_bytes_ = max_bytes; }
  // Whether a bundle that no calibration covers yet is held rather than dropped.
  static bool holds(bool live, bool session_failed, std::uint64_t missing_mask) {
    return !live && !session_failed && missing_mask == 0;
  }
  // Holds `item` (`bytes` of pixels, views of `sizes`); returns what no longer fits, oldest first
  // (held bundles of other sizes, then the oldest beyond max_bytes), for the caller to drop.
  std::vector<T> keep(T item, std::size_t bytes, const std::vector<std::array<int, 2>>& sizes) {
    std::vector<T> out;
    if (!held_.empty() && sizes != sizes_) out = take();
    sizes_ = sizes;
    held_.push_back({item, bytes});
    bytes_ += bytes;
    while (bytes_ > max_bytes_ && held_.size() > 1) {
      out.push_back(held_.front().item);
      bytes_ -= held_.front().bytes;
      held_.erase(held_.begin());
      if (!bound_said_) bound_reached_ = bound_said_ = true;
    }
    return out;
  }
  // Everything held, oldest first (the first calibration is installed, or a flush, a stop).
  std::vector<T> take() {
    std::vector<T> out;
    for (const auto& h : held_) out.push_back(h.item);
    held_.clear();
    bytes_ = 0;
    return out;
  }
  // The newest held bundle (the stream ended on it: the caller calibrates on it, see
  // CalibSession::accept_torn_pictures); nullopt when none.
  const T& newest() const { return held_.back().item; }
  std::optional<T> take_newest() {
    if (held_.empty()) return std::nullopt;
    T item = held_.back().item;
    bytes_ -= held_.back().bytes;
    held_.pop_back();
    return item;
  }
  // True once, after keep() first dropped a bundle for the bound (to be said on the bus).
  bool bound_reached() { return std::exchange(bound_reached_, false); }
  std::size_t count() const { return held_.size(); }
  std::size_t bytes() const { return bytes_; }
  std::size_t max_bytes() const { return max_bytes_; }
  bool empty() const { return held_.empty(); }

 private:
  struct Held {
    T item;
    std::size_t bytes;
  };
  std::size_t max_bytes_;
  std::vector<Held> held_;
  std::size_t bytes_ = 0;
  std::vector<std::array<int, 2>> sizes_;
  bool bound_reached_ = false, bound_said_ = false;
};

class CalibSession {
 public:
  struct Frame {
    double time_s = 0;  // running time (seconds); may jump back (seeks): only forward steps count
    std::vector<std::array<int, 2>> sizes;
    std::uint64_t missing_mask = 0;  // views the bundle lacks
    // Which input each view comes from (stitchsync's pad numbers; empty: unknown). When a camera
    // leaves, the others keep their geometry instead of a calibration from scratch.
    std::vector<unsigned> camera_ids;
    bool live = true;  // the cameras are live (a returning camera is then calibrated without stopping the stream)
  };

  void set_config(const SessionConfig& config);
  const SessionConfig& config() const { return config_; }

  // A bundle arrives: whether its pixels are needed (quality, pooling, a job).
  bool wants_pixels(const Frame& frame);
  // The bundle's pixels (empty when not wanted). Returns a job to run, if any (one at a time).
  std::shared_ptr<CalibJob> on_frame(const Frame& frame, const std::vector<ImageView>& views);
  // A job's outcome (stale serials are ignored).
  void on_outcome(const CalibOutcome& outcome);
  // After on_frame/on_outcome: this bundle passes (counted) or is dropped (QoS events, rate-limited).
  void bundle_passed();
  void bundle_dropped();
  // The stream ended: an error when no calibration was ever made.
  void on_eos();
  // The job in flight was cancelled by the caller: its outcome, if it comes, is ignored, and
  // the next job may start (a seek after the end of the stream).
  void abandon_job();
  void request_recalibration() { recalibrate_requested_ = true; }
  // Lens from evidence (issue 15). The first calibration from the images is pinhole (fast: the
  // stream waits for it). Afterwards a background job (JobKind::Lens) fits a radtan k1/k2 lens
  // to every camera from the installed rig (lens_fit_starts) on the frames of the pooling window,
  // and installs it only when judge_candidate accepts it and it wins by the evidence rule
  // (lens_evidence_wins) in camera pixels on the held-out frames. Skipped with a rig-file or a
  // load-file (the file states the lenses: absent is pinhole), camera-model=homography,
  // options.lens_from_evidence off, a camera left out, cameras that already have a lens (a
  // fisheye ring, estimated), and when the installed calibration's held-out residual is already
  // within kLensEvidenceMinPx (no lens could win). It is a background job: it gives way.
  // Once a lens is installed, the session knows the cameras' lenses (known_lenses_, by input when
  // stitchsync numbers them): later calibrations from the images (a recalibration, the pooled
  // window after a calibration from scratch, a resize of the same aspect, a camera that comes
  // back) keep them (CalibJob::lenses), judged as before in camera pixels against what is
  // installed. A calibration from the images installed without lenses (the refit with them failed
  // and the pinhole one won) forgets them, and the lens fit may find them again.
  // Whether the job in flight is one that gives way (the lens fit) to work that waits now (a
  // recalibration window that has collected its frames) or to the end of the stream (`at_eos`):
  // when it does, the session forgets it (its outcome is ignored) and the caller cancels the
  // worker instead of waiting for it.
  bool give_way(bool at_eos);
  // Whether the last bundle was kept from the first calibration by torn pictures alone (every
  // camera delivered; each refused one was "corrupt"). At the end of a stream such a picture is
  // the camera's last (two photos given as one-frame streams): accept_torn_pictures() then takes
  // tears as the pictures' own for the next bundle.
  bool last_bundle_torn_only() const { return torn_only_; }
  void accept_torn_pictures() { accept_torn_ = true; }
  // Files that end before the first calibration, after a failed attempt and bundles that were not
  // tried (the back-off skipped them): whether the last bundle is worth one more attempt; when it
  // is, the next on_frame makes it at once (the element gives it the last held bundle again).
  bool retry_at_end();
  // Stop: forgets everything (and any job in flight).
  void reset();

  std::shared_ptr<const Rig> current() const { return current_; }
  // The first calibration, from the images, waits for a camera this bundle lacks (some views
  // present, none loaded from a file): see LateCameraHold.
  bool waits_for_a_camera(const Frame& frame) const;
  std::uint64_t version() const { return version_; }
  bool job_in_flight() const { return job_in_flight_; }
  bool failed() const { return failed_; }  // a fatal error was reported
  // Running time since the first bundle, while nothing is calibrated (pending messages' waited-s).
  double waited_s() const { return first_frame_at_ < 0 ? 0 : now_ - first_frame_at_; }
  std::vector<SessionEvent> take_events();

 private:
  struct Bin {
    bool holdout = false;
    std::optional<FrameSet> best;
    double score = -1;
  };
  void note_time(double t);
  void warn(const std::string& s);
  void fail(const std::string& s);
  void pending(const std::string& why);
  bool handle_sizes(const Frame& frame);
  // `missing`: views without a frame yet; they take the file's sizes (a complete calibration
  // needs no pixels, so it is used at once, and the late cameras join it)
  bool load_file(uint64_t missing = 0);
  bool load_rough();
  void warn_unknown_fields(const std::string& property, const std::string& path, const Rig& rig);
  void install(CalibReport report, CalibrationResult* result);
  // A candidate kept out: announced (stitchcalib-rejected) with its report, nothing installed.
  void reject(CalibReport report, const CalibrationResult& result);
  void start_window(JobKind kind);
  // Lens from evidence: why the background lens fit is not run on the installed calibration
  // (empty: it is); `residual_camera_px`: its held-out residual (-1: not known).
  std::string lens_skip_reason(double residual_camera_px) const;
  // After a windowed job's outcome: the lens fit becomes due (on that window's frames).
  void maybe_lens_due(double residual_camera_px);
  std::shared_ptr<CalibJob> make_job(JobKind kind);
  // `skip`: views not judged (left out).
  std::string bundle_problem(const std::vector<ImageView>& views, bool features_needed, double* score,
                             std::uint64_t skip = 0);
  // Forgets the calibration: the next bundles calibrate from scratch (resize, a camera back).
  void forget_calibration();
  // Left-out cameras `back` deliver a picture: said, and calibrated again with every camera.
  void rejoin(std::uint64_t back, std::size_t cameras);
  // A left-out camera that shows a picture again: a calibration from scratch with it, run in the
  // background while the current one (without it) keeps the panorama going.
  std::shared_ptr<CalibJob> rejoin_in_background(std::uint64_t back, const Frame& frame,
                                                 const std::vector<ImageView>& views);
  bool rejoin_announced_ = false, rejoin_failed_ = false;
  // Before the first calibration: camera absent (missing or dark) for leave_out_after_s.
  bool absent_long_enough(std::size_t camera) const;
  // Before the first calibration: the cameras absent (missing, or dark when pixels are given)
  // for leave_out_after_s; 0 when none may be left out yet (or fewer than two would remain).
  std::uint64_t cameras_to_leave_out(const Frame& frame, const std::vector<ImageView>& views);

  SessionConfig config_;
  std::vector<SessionEvent> events_;
  // time
  double now_ = 0, last_t_ = 0;
  bool have_t_ = false;
  double first_frame_at_ = -1;
  // geometry
  std::shared_ptr<const Rig> current_;
  // Cameras left out of the installed calibration (Camera::left_out), and, before the first
  // calibration, since when each camera has been absent (missing or dark; -1: present).
  std::uint64_t left_out_ = 0;
  std::vector<double> absent_since_;
  std::string leave_out_blocked_;  // why an absent camera is not left out (said while pending)
  double last_rejoin_check_ = -1e9;
  // How the installed calibration was estimated (unset: loaded from a file). Later calibrations
  // of the same cameras keep it when the user left the choice to auto: the panorama's model and
  // projection never flip mid-stream on a marginal held-out verdict.
  std::optional<CameraModel> installed_model_;
  // Per camera: the row of the last "torn" verdict, and since when the checks find it there.
  struct Tear {
    double row = 0;
    double since_s = -1;  // running time; -1: the last check found no tear
    std::uint64_t picture = 0;  // FrameQuality::picture of the last torn frame
  };
  std::vector<Tear> tears_;
  bool torn_only_ = false;    // last_bundle_torn_only()
  bool accept_torn_ = false;  // accept_torn_pictures()
  static constexpr double kTearIsContentAfterS = 3.0;
  bool poor_alignment_said_ = false;  // said again only after a calibration within the limit
  void say_poor_alignment(const CalibReport& rep);
  std::string unverified_said_;  // the last unverified-overlap warning (not repeated)
  std::optional<Rig> rough_;
  std::string rough_from_;
  std::vector<std::array<int, 2>> rough_sizes_;  // the view sizes rough_ was adapted to
  std::vector<std::array<int, 2>> sizes_;
  std::vector<unsigned> camera_ids_;  // the inputs of sizes_ (Frame::camera_ids), when known
  bool keep_remaining_cameras(const Frame& frame);
  bool shows_nothing(const ImageView& view) const;  // a camera to leave out (dark, or featureless)
  bool identical_warned_ = false;  // "the same picture" said once a session
  int panorama_w_ = 0, panorama_h_ = 0;  // kept over recalibrations
  // The panorama size a calibration from scratch mid-stream (a resize, a camera added or back)
  // is fitted into: stitchblend's output, which encoders and muxers cannot see change.
  int refit_w_ = 0, refit_h_ = 0;
  std::uint64_t version_ = 0;
  bool ever_installed_ = false, failed_ = false;
  // first calibration
  double next_attempt_at_ = 0;
  // Files (non-live): after a failed first attempt the next comes on the next usable bundles
  // (the next bundle, then 2, 4, 8, ... bundles later, retry_interval_s at most), pooled with the frame sets tried
  // before (the newest calibration_frames): nothing is lost meanwhile (EarlyBundles), and a
  // pooled attempt succeeds where one noisy frame set leaves a camera a few matches short.
  int failed_first_attempts_ = 0, bundles_to_next_attempt_ = 0, untried_bundles_ = 0;
  std::vector<FrameSet> tried_sets_;
  std::uint64_t tried_leave_ = 0;
  std::string last_problem_;
  double last_pending_at_ = -1e9;
  // windows
  JobKind window_kind_ = JobKind::Pooled;
  bool window_open_ = false;
  double window_start_ = 0;
  std::vector<Bin> bins_;
  double last_calibration_at_ = 0;
  bool recalibrate_requested_ = false;
  // load-file check
  bool load_check_due_ = false;
  // drift watch
  double next_drift_check_at_ = 0, drift_backoff_s_ = 0;
  int drift_strikes_ = 0;
  double baseline_px_ = -1;
  // jobs
  std::uint64_t serial_ = 0;
  bool job_in_flight_ = false;
  JobKind in_flight_kind_ = JobKind::First;
  // lens from evidence: wanted after the next windowed job (once per calibration from scratch),
  // due now (with the frames of the last window), the frames of the last window
  bool lens_wanted_ = false, lens_due_ = false;
  // The lenses installed calibrations found (intrinsics and lens at the size found), by input
  // (Frame::camera_ids; the view index when unknown). Kept over calibrations from scratch.
  std::vector<Camera> known_lenses_;
  std::vector<long> known_lens_keys_;
  void note_installed_lenses(const std::string& source);
  // The known lenses of the cameras now connected (sizes_, camera_ids_), empty unless every
  // camera has one.
  std::vector<Camera> known_lenses_now() const;
  std::vector<FrameSet> last_calib_sets_, last_holdout_sets_;
  // QoS
  std::uint64_t passed_ = 0, dropped_ = 0, dropped_reported_ = 0;
  double last_qos_at_ = -1e9;
};

}  // namespace stitch
