/**
 * SECTION:element-stitchcalib
 * @title: stitchcalib
 *
 * Attaches the rig geometry (camera -> canvas homographies and the canvas size) to every
 * bundle from stitchsync. The geometry comes from, in order of precedence:
 *
 * - `load-file`: a saved calibration, used as is (no estimation);
 * - `rig-file`: rough camera parameters (stitch-rig JSON), turned into homographies
 *   (paper eq. 8-12) and refined by feature matching in the widened overlaps
 *   (`refine=skew-scale` is the paper's eq. 13-14, `refine=homography` a full correction);
 * - neither: calibration from the images alone (features; focal lengths and rotations from
 *   the pairwise homographies along the match graph, whatever the pad order; one bundle
 *   adjustment over every pair, which closes a 360-degree ring).
 *
 * `camera-model` (default `auto`): cameras that turn about one centre (most rigs) are modelled
 * by rotation + intrinsics, refined jointly by bundle adjustment; a free homography per camera
 * fits a really planar scene seen by translating cameras (a document, a wall, a top-down view).
 * `auto` picks the model whose error on held-out matches is lower, and the result message says
 * which (`model`).
 *
 * `projection` picks the canvas: `plane` (the reference camera's image plane, homographies),
 * `cylindrical` or `spherical` (equirectangular; each camera's K and R map the canvas, and a
 * ring that looks all around gets a 360-degree canvas whose seam closes at the wrap). Unset, the
 * rig-file's `projection` holds; with neither, it is chosen from the estimated field of view:
 * plane while the views fit, cylindrical for wide rigs, spherical for rigs that also look up
 * or down. Features of every overlapping pair feed one bundle adjustment of all rotations and
 * focal lengths, then `wave-correct` levels the horizon. `bundle-adjust=true` is the older
 * switch for `camera-model=rotation`.
 *
 * The policy (src/stitch/calib/calib_session.hpp) over a whole stream:
 *
 * - Frames are picked by quality: a bundle with a dark, torn (a broken keyframe: two pictures
 *   in one), blurred or featureless view is not calibrated on (a rig-file's rough geometry
 *   needs no features, only no dark or torn view). A "tear" that stays at one row for 3 s is
 *   the picture's own (a newspaper's rules, a still image), not a broken keyframe.
 * - The first usable bundle is calibrated at once (the stream waits for it: nothing can be
 *   output before). Then `calibration-frames` good bundles, the best of each stretch of
 *   `calibration-window` seconds, are pooled into a new calibration, judged against the first
 *   on held-out bundles of the same window by independent matches: it replaces the first only
 *   when it aligns them clearly better in camera pixels (a canvas fitted into the same panorama
 *   size shrinks canvas-pixel residuals with it), so the geometry never flips between equals,
 *   and only when it keeps every overlap the first aligns and the picture (no camera shrinks to
 *   less than 2/3 of its share of the canvas, the covered share falls by 5 points at most,
 *   unless the residual halves); `reason` in a `stitchcalib-rejected` message says why not. It keeps the
 *   camera model and projection the first calibration chose when `camera-model` and
 *   `projection` are left to auto (so do recalibrations): the panorama's layout does not change
 *   mid-stream. `model` in the message says which model is installed.
 * - `recalibrate` (action signal), `recalibrate-interval` (running time) and the optional drift
 *   watch (`drift-threshold`: a check every 5 s, two bad checks in a row recalibrate) open such a
 *   window again; the result must beat the current calibration on held-out frames, or it is
 *   reported in a `stitchcalib-rejected` message and kept out. A recalibration keeps the
 *   panorama size: its canvas is fitted into the current one.
 * - Until a calibration exists, a `stitchcalib-pending` message (`reason`, naming the cameras
 *   that hold it up, and `waited-s`) is posted at most once a second; while the stream waits for
 *   a first calibration in flight (files: it may include the lens fit, a minute or more), it comes
 *   once a second of wall time with what the worker is doing: `stage` (e.g. "lens fit"),
 *   `attempt` and `calibrating-s` (wall seconds of that attempt). With live inputs the
 *   bundles are dropped meanwhile, QoS messages rate-limited (the first drop, at most one a
 *   second, and the total before the first bundle passes), and a failed attempt is tried again
 *   0.5 s later. With non-live inputs (files) no frame is lost: the complete bundles that come
 *   before the first calibration are held (copies, 512 MiB at most: beyond, the oldest are
 *   dropped and a warning says so) and go out with it, in order, so that every frame set gets a
 *   panorama; a failed attempt is tried again on the next bundle, then 2, 4, 8, ... bundles
 *   later (0.5 s of running time at most), on the newest `calibration-frames` frame sets tried
 *   pooled, and once more on the last bundle when the stream ends before one succeeds (a
 *   6-camera ring at 8% overlap whose first frame set left a camera a few matches short gave 20
 *   panoramas of 20 instead of 5). After `calibration-timeout` seconds of running
 *   time it stops with an error; a stream that ends before any calibration is an error. With
 *   non-live inputs, a bundle that lacks a camera which has not started yet is held before it is
 *   dropped (200 ms, doubling to 1 s; 10 s of wall time in all), so the cameras that started do
 *   not run ahead and end before a late one joins.
 * - A camera that has delivered no frame, or only dark ones, for `leave-out-after` seconds of
 *   running time (4 s) before the first calibration is left out of it: the others (two at least)
 *   are calibrated and stitched, its view is marked missing, a warning and the message's
 *   `left-out` (camera indices) name it, and save-file is not written. When it shows a picture
 *   it joins, with a calibration from scratch: live cameras get it in the background, the
 *   panorama going on without the camera until it is ready (a failed one is tried again a
 *   little later); with non-live inputs (files) the stream waits for it, so the camera is back
 *   from about the frame it came back on, whatever the machine's load.
 * - The same source given to two pads (identical pictures) is said in a warning.
 *   A camera that starts at a size other than its placeholder's is
 *   calibrated in from scratch at once.
 * - A `load-file` is checked against the images once: a warning names the cameras it does not
 *   fit.
 * - Lenses from evidence: the first calibration from the images is pinhole (fast). Afterwards,
 *   in the background, a radtan k1/k2 lens is fitted to every camera from the installed rig on
 *   the pooled window's frames, judged like a pooled calibration on the held-out frames, and
 *   installed (`source` lens) only when it also wins by the evidence rule of stitch-calibrate
 *   (below 70% of the pinhole residual and 0.2 camera px less); else it is reported in a
 *   `stitchcalib-rejected` message. Barrel-distorted phones and action cameras get their lens;
 *   undistorted cameras stay pinhole. Not run with a rig-file or load-file (the file states the
 *   lenses: absent is pinhole), `camera-model=homography`, cameras that already have lenses
 *   (fisheyes), a camera left out, or when the pinhole residual is already within 0.2 camera
 *   px. With live cameras it never delays the stream: it gives way to a recalibration and is
 *   cancelled at the end of the stream. With cameras that are not live (files) the same fit runs
 *   inside the first calibration, which the stream waits for: a short file gets its lens from the
 *   first panorama on (a pinhole fit more than 5 camera px off skips the cheap test; a lens that
 *   still leaves over 1 camera px is said in a warning). A cheap test runs first (about a second of a core: a k1 adjustment of sparse
 *   matches against a pinhole one, held out); without a sign of distortion the fit is not run
 *   (every real clip measured). Once a lens is installed, later calibrations from the images
 *   (recalibrations, the pooled window after a resize of the same aspect or a camera that came
 *   back) keep the cameras' lenses, judged as before in camera pixels.
 *
 * Every installed calibration is posted as an element message named `stitchcalib`: `version`,
 * `source` (file, rig, images, pooled, recalibration, lens), `canvas-width`/`-height`, `rms-px` (root
 * mean square of the overlapping pairs' median misalignment, canvas pixels, by independent
 * matches on `residual-source` frames), `alignment-px` (their mean), `camera-px` (per camera),
 * `previous-px` (the calibration it replaced, same frames), `alignment-camera-px` and
 * `previous-camera-px` (the same in camera pixels, what the judge compares; over 5 camera px
 * a warning names the worst pair: the seams will show), `unverified-pairs` (camera pairs, flattened:
 * overlaps that nothing could measure, no feature matching there and too plain to align by area;
 * the figures leave them out, and a warning names them: the seam there may be off), `coverage` and
 * `previous-coverage` (the share of the canvas the cameras cover; pooled calibrations and
 * recalibrations), `lens` (the cameras' lens models: `pinhole`, `radtan`, `fisheye`, ...) with
 * `lens-k1` and `lens-k2` (per camera) when they have lenses, `fit-rms-px`, `inliers`, ... It is
 * written to `save-file` when set, with the time offsets stitchsync applies (time-alignment,
 * its load-file, pad offsets) as each camera's `time_offset_ns` when there are any. The canvas is always the panorama size (as
 * stitchblend outputs it: even unless downstream fixes an odd size; fitted into the current
 * panorama on recalibration).
 *
 * Before a calibration from scratch, stitchcalib asks downstream (a custom query that queues,
 * stitchcolor and stitchflowwarp pass on) what panorama stitchblend will output: its
 * output-width/-height, or the size a capsfilter after it fixes. When that shows the canvas
 * smaller, the canvas is made at that size, so that the stages between (colour, the flow warp,
 * seams, multiband) work at the size that is output (a 6 x 4K ring shown at 7680x3840 is
 * warped at 7680 columns, not at the cameras' 14400). It is never enlarged.
 *
 * Calibration runs in a worker thread that holds no lock of the element: results are picked up
 * by the streaming thread, messages are posted outside every lock, properties never wait for a
 * calibration, and a state change to READY (or a flush) releases the streaming thread and
 * cancels the worker between its stages.
 *
 * An input that changes resolution mid-stream is calibrated again
 * from scratch (the rig-file or the images, never the old geometry), with a warning naming the
 * camera and both sizes (`on-resize=recalibrate`), or stops the stream with an error
 * (`on-resize=error`). A camera that leaves (its stitchsync pad released) takes its view with
 * it: the cameras that stay keep their geometry on the same canvas (message `source=kept`, a
 * warning naming the camera and its input), so the panorama goes on at once even where the
 * camera that left was the only link between the others; `on-resize=error` stops instead.
 * A camera added while playing is always calibrated in, with a warning that the number of
 * cameras changed. Such a calibration from scratch, and the one a left-out
 * camera joins with, is fitted into the panorama size the stream already has (encoders and
 * muxers cannot take a size change). Flushes (seeks) keep the calibration: the rig has not moved.
 *
 * Bundles in CUDA memory pass through untouched: only the frames the calibration policy reads
 * (quality checks and calibrations) are mapped through host memory.
 *
 * ## Example launch lines
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib save-file=/tmp/calib.json ! stitchblend ! \
 *   videoconvert ! autovideosink \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * |[
 * # a 360-degree ring of 6 cameras: build/tests/stitch-render-rig --photo data/photos/boat1_1600.jpg \
 * #   --ring spherical --cameras 6 --hfov 80 --frames 10 --out /tmp/ring
 * gst-launch-1.0 stitchsync name=s ! stitchcalib rig-file=/tmp/ring/rig_rough.json projection=cylindrical \
 *   save-file=/tmp/ring/calib.json ! stitchblend ! videoconvert ! autovideosink \
 *   filesrc location=/tmp/ring/cam0.avi ! decodebin ! s.sink_0 filesrc location=/tmp/ring/cam1.avi ! decodebin ! s.sink_1 \
 *   filesrc location=/tmp/ring/cam2.avi ! decodebin ! s.sink_2 filesrc location=/tmp/ring/cam3.avi ! decodebin ! s.sink_3 \
 *   filesrc location=/tmp/ring/cam4.avi ! decodebin ! s.sink_4 filesrc location=/tmp/ring/cam5.avi ! decodebin ! s.sink_5
 * ]|
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib load-file=/tmp/calib.json ! stitchblend ! \
 *   videoconvert ! x264enc ! mp4mux ! filesink location=pano.mp4 \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 */
#include "gststitchcalib.h"

#include <gst/video/video.h>

#include <atomic>
#include <condition_variable>
#include <mutex>
#include <thread>

#include "gststitchbundle.h"
#include "gststitchcuda.h"
#include "stitch/calib/calib_session.hpp"

GST_DEBUG_CATEGORY_STATIC(gst_stitch_calib_debug);
#define GST_CAT_DEFAULT gst_stitch_calib_debug

enum {
  PROP_0,
  PROP_RIG_FILE,
  PROP_LOAD_FILE,
  PROP_SAVE_FILE,
  PROP_REFINE,
  PROP_FEATURES,
  PROP_RECALIBRATE_INTERVAL,
  PROP_MIN_INLIERS,
  PROP_OVERLAP_MARGIN,
  PROP_REFERENCE,
  PROP_CALIBRATION_FRAMES,
  PROP_BACKEND,
  PROP_ON_RESIZE,
  PROP_PROJECTION,
  PROP_BUNDLE_ADJUST,
  PROP_CAMERA_MODEL,
  PROP_WAVE_CORRECT,
  PROP_CALIBRATION_WINDOW,
  PROP_CALIBRATION_TIMEOUT,
  PROP_DRIFT_THRESHOLD,
  PROP_LEAVE_OUT_AFTER,
};

typedef enum { ON_RESIZE_RECALIBRATE = 0, ON_RESIZE_ERROR = 1 } OnResize;
enum { SIGNAL_RECALIBRATE, LAST_SIGNAL };
static guint signals[LAST_SIGNAL];

#define DEFAULT_REFINE stitch::Refinement::Homography
#define DEFAULT_FEATURES stitch::FeatureType::Sift
#define DEFAULT_INTERVAL 0.0
#define DEFAULT_MIN_INLIERS 20
#define DEFAULT_OVERLAP_MARGIN 0.15
#define DEFAULT_REFERENCE -1
#define DEFAULT_CALIBRATION_FRAMES 5
#define DEFAULT_CALIBRATION_WINDOW 2.0
#define DEFAULT_CALIBRATION_TIMEOUT 30.0
#define DEFAULT_DRIFT_THRESHOLD 0.0
#define DEFAULT_LEAVE_OUT_AFTER 4.0
#define PROJECTION_UNSET -1

/* One calibration job in a worker thread. The worker owns its inputs and this channel (shared):
 * it never touches the element, which may be gone before it finishes. */
struct WorkerChannel {
  stitch::JobKind kind = stitch::JobKind::First;
  std::atomic<bool> cancel{false};
  std::atomic<bool> done{false};
  std::mutex m;  // only for the condition variable: never held while computing
  std::condition_variable cv;
  stitch::CalibOutcome outcome;  // written before `done`
  /* for the pending messages of a stream that waits for it */
  std::shared_ptr<const stitch::JobProgress> progress;
  int attempt = 1, frame_sets = 1, cameras = 0;
  gint64 started_us = 0;
};

/* Live workers: the plugin's static teardown (process exit) waits a little for them. */
static std::mutex workers_lock;
static std::condition_variable workers_cv;
static int workers_alive = 0;
static struct WorkersAtExit {
  ~WorkersAtExit() {
    std::unique_lock<std::mutex> g(workers_lock);
    workers_cv.wait_for(g, std::chrono::seconds(10), [] { return workers_alive == 0; });
  }
} workers_at_exit;

/* stitchsync's offsets as the bundle meta carries them. */
struct TimeOffsets {
  bool present = false;  // some offset non-zero, or estimated by time-alignment
  guint64 estimated_mask = 0;
  std::vector<gint64> ns;
  bool operator==(const TimeOffsets& o) const {
    return present == o.present && estimated_mask == o.estimated_mask && ns == o.ns;
  }
  bool operator!=(const TimeOffsets& o) const { return !(*this == o); }
};

struct CalibSettings {
  stitch::SessionConfig config;
  stitch::Backend backend = stitch::Backend::Auto;
  OnResize on_resize = ON_RESIZE_RECALIBRATE;
};

struct CalibState {
  /* Guards `settings` only, for copies: never held while calibrating, waiting or posting. */
  std::mutex settings_lock;
  CalibSettings settings;
  std::atomic<bool> recalibrate_requested{false};
  /* Flushing or stopping: a streaming thread waiting for the first calibration returns. */
  std::atomic<bool> unblock{false};
  /* Streaming thread only (start/stop run when it does not). */
  stitch::CalibSession session;
  std::shared_ptr<WorkerChannel> worker;
  gint64 started_us = 0;
  bool passed_any = false;  /* a bundle has gone downstream since start */
  GstClockTime drop_running = GST_CLOCK_TIME_NONE, drop_stream = GST_CLOCK_TIME_NONE, drop_pts = GST_CLOCK_TIME_NONE,
               drop_duration = GST_CLOCK_TIME_NONE;
  /* shared with the neighbours; calibration itself reads views through host memory */
  StitchCudaContext cuda;
  /* save-file is written here, not by the session, so that stitchsync's time offsets (the
   * bundle meta's) go in as the cameras' "time_offset_ns" (streaming thread only) */
  std::string save_path;
  TimeOffsets offsets, saved_offsets;
  std::shared_ptr<const stitch::Rig> saved_rig;
  double saved_at_s = -1, now_s = 0;  // running time (s) of the last write, of the last bundle
  /* the panorama stitchblend will output (STITCH_OUTPUT_SIZE_QUERY), asked before a first calibration */
  gint output_width = 0, output_height = 0, output_crop = 0;
  /* bundles held while a first calibration waits for a late camera (streaming thread only) */
  stitch::LateCameraHold late_hold;
  int upstream_live = -1;  /* -1: not asked yet */
  /* Non-live inputs: the bundles before the first calibration, deep copies (they would hold the
   * upstream pools' buffers), pushed with it (streaming thread only) */
  stitch::EarlyBundles<GstBuffer*> early;
  void drop_early() {
    for (GstBuffer* b : early.take()) gst_buffer_unref(b);
  }

  void forget_saved() {
    offsets = saved_offsets = TimeOffsets();
    saved_rig.reset();
    saved_at_s = -1;
    now_s = 0;
  }

  /* Before the first calibration: the last bundle, when torn pictures alone kept it from being
   * calibrated on (streaming thread). The stream may end on it (two photos as one-frame streams). */
  GstBuffer* last_torn = nullptr;
  void forget_torn() { gst_clear_buffer(&last_torn); }
  void cancel_worker() {
    if (worker) worker->cancel = true;
    worker.reset();
  }
};

struct _GstStitchCalib {
  GstBaseTransform parent;
  CalibState* state;
};

G_DEFINE_TYPE(GstStitchCalib, gst_stitch_calib, GST_TYPE_BASE_TRANSFORM);
GST_ELEMENT_REGISTER_DEFINE(stitchcalib, "stitchcalib", GST_RANK_NONE, GST_TYPE_STITCH_CALIB);

static GType refine_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::Refinement::None), "Rough homographies only", "none"},
      {int(stitch::Refinement::SkewScale), "Paper eq. 13-14: scale and translation", "skew-scale"},
      {int(stitch::Refinement::Homography), "Full homography correction (skew-scale fallback)",
       "homography"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchCalibRefine", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GType on_resize_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {ON_RESIZE_RECALIBRATE, "Calibrate again for the new sizes", "recalibrate"},
      {ON_RESIZE_ERROR, "Stop with an error", "error"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchCalibOnResize", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GType features_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {{int(stitch::FeatureType::Sift), "SIFT", "sift"},
                                      {int(stitch::FeatureType::Orb), "ORB", "orb"},
                                      {int(stitch::FeatureType::Akaze), "AKAZE", "akaze"},
                                      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchCalibFeatures", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GType projection_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {PROJECTION_UNSET, "Unset: the rig-file's \"projection\"; without one, chosen from the field of view", "unset"},
      {int(stitch::Projection::Plane), "The reference camera's image plane (homographies)", "plane"},
      {int(stitch::Projection::Cylindrical), "Cylinder about the rig's vertical axis", "cylindrical"},
      {int(stitch::Projection::Spherical), "Sphere, equirectangular", "spherical"},
      {int(stitch::Projection::Cubemap), "Cube, 3x2 faces (Spherical Video V2 cbmp layout 0)", "cubemap"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchCalibProjection", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GType camera_model_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::CameraModel::Auto), "The model with the lower error on held-out matches", "auto"},
      {int(stitch::CameraModel::Rotation), "Rotation + intrinsics about one centre, bundle-adjusted", "rotation"},
      {int(stitch::CameraModel::Homography), "A free homography per camera (planar scenes)", "homography"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchCalibCameraModel", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GstStaticPadTemplate sink_template = GST_STATIC_PAD_TEMPLATE(
    "sink", GST_PAD_SINK, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));
static GstStaticPadTemplate src_template = GST_STATIC_PAD_TEMPLATE(
    "src", GST_PAD_SRC, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));

static void set_item(GValue* item, double v) {
  g_value_init(item, G_TYPE_DOUBLE);
  g_value_set_double(item, v);
}
static void set_item(GValue* item, int v) {
  g_value_init(item, G_TYPE_INT);
  g_value_set_int(item, v);
}

template <class T>
static GValue value_array(const std::vector<T>& values) {
  GValue array = G_VALUE_INIT;
  gst_value_array_init(&array, guint(values.size()));
  for (const T v : values) {
    GValue item = G_VALUE_INIT;
    set_item(&item, v);
    gst_value_array_append_and_take_value(&array, &item);
  }
  return array;
}

static GstStructure* report_structure(const char* name, const stitch::CalibReport& r) {
  const stitch::Rig& rig = *r.rig;
  const double rms = r.residuals.rms_px >= 0 ? r.residuals.rms_px : r.fit_rms_px;
  GstStructure* s = gst_structure_new(
      name, "version", G_TYPE_UINT64, guint64(r.version), "source", G_TYPE_STRING, r.source.c_str(), "cameras",
      G_TYPE_INT, int(rig.cameras.size()), "refined-cameras", G_TYPE_INT, r.refined_cameras, "inliers", G_TYPE_INT,
      r.inliers, "rms-px", G_TYPE_DOUBLE, rms, "alignment-px", G_TYPE_DOUBLE, r.residuals.median_px, "fit-rms-px",
      G_TYPE_DOUBLE, r.fit_rms_px, "residual-matches", G_TYPE_INT, r.residuals.matches, "residual-source",
      G_TYPE_STRING, r.residual_source.c_str(), "previous-px", G_TYPE_DOUBLE, r.previous_px, "canvas-width",
      G_TYPE_INT, rig.canvas_width, "canvas-height", G_TYPE_INT, rig.canvas_height, "warnings", G_TYPE_INT,
      r.warnings, "projection", G_TYPE_STRING, rig.projection.c_str(), "canvas-wrap", G_TYPE_BOOLEAN,
      gboolean(rig.canvas_wrap), "ba-rms-px", G_TYPE_DOUBLE, r.ba_rms_px, "alignment-camera-px", G_TYPE_DOUBLE,
      r.residuals.median_camera_px, "previous-camera-px", G_TYPE_DOUBLE, r.previous_camera_px, NULL);
  if (!r.rejected_because.empty()) gst_structure_set(s, "reason", G_TYPE_STRING, r.rejected_because.c_str(), NULL);
  if (r.coverage >= 0)
    gst_structure_set(s, "coverage", G_TYPE_DOUBLE, r.coverage, "previous-coverage", G_TYPE_DOUBLE, r.previous_coverage, NULL);
  if (!r.model.empty()) gst_structure_set(s, "model", G_TYPE_STRING, r.model.c_str(), NULL);
  /* the cameras' lenses (issue 15): "pinhole", or the models and, per camera, k1 and k2 */
  const std::string lens = stitch::rig_lens_summary(rig);
  gst_structure_set(s, "lens", G_TYPE_STRING, lens.c_str(), NULL);
  if (lens != "pinhole") {
    std::vector<double> k1, k2;
    for (const auto& c : rig.cameras) k1.push_back(c.lens.k1), k2.push_back(c.lens.k2);
    GValue a1 = value_array(k1), a2 = value_array(k2);
    gst_structure_take_value(s, "lens-k1", &a1);
    gst_structure_take_value(s, "lens-k2", &a2);
  }
  GValue cams = value_array(r.residuals.camera_px);
  gst_structure_take_value(s, "camera-px", &cams);
  if (!r.residuals.unverified.empty()) {
    /* overlaps no figure above covers (nothing could measure them): camera pairs, flattened */
    std::vector<int> pairs;
    for (const auto& p : r.residuals.unverified) pairs.push_back(p.first), pairs.push_back(p.second);
    GValue unverified = value_array(pairs);
    gst_structure_take_value(s, "unverified-pairs", &unverified);
  }
  std::vector<int> left_out;  // the cameras calibrated without (no frame, or a dark one)
  for (std::size_t i = 0; i < rig.cameras.size(); ++i)
    if (rig.cameras[i].left_out) left_out.push_back(int(i));
  if (!left_out.empty()) {
    GValue cameras = value_array(left_out);
    gst_structure_take_value(s, "left-out", &cameras);
  }
  return s;
}

/* Writes `rig` to save-file, with stitchsync's time offsets as the cameras' "time_offset_ns"
 * when the bundles carry some (a camera whose offset is 0 and not estimated has none); without
 * offsets the rig is written as it is. A failure is a warning, as in the session. */
static void save_rig(GstStitchCalib* self, const std::shared_ptr<const stitch::Rig>& rig, double now_s) {
  CalibState* st = self->state;
  if (st->save_path.empty() || !rig) return;
  if (stitch::any_left_out(*rig)) return;  /* the session said so when it installed it */
  try {
    if (st->offsets.present) {
      stitch::Rig out = *rig;
      for (std::size_t v = 0; v < out.cameras.size() && v < st->offsets.ns.size(); ++v) {
        const gint64 ns = st->offsets.ns[v];
        if (ns != 0 || (st->offsets.estimated_mask >> v & 1)) out.cameras[v].time_offset_ns = ns;
        else out.cameras[v].time_offset_ns.reset();
      }
      stitch::rig_save(out, st->save_path);
    } else {
      stitch::rig_save(*rig, st->save_path);
    }
    st->saved_rig = rig;
    st->saved_offsets = st->offsets;
    st->saved_at_s = now_s;
  } catch (const std::exception& e) {
    GST_ELEMENT_WARNING(self, RESOURCE, WRITE, ("save-file: %s", e.what()), (NULL));
  }
}

/* The offsets moved since the file was written (time-alignment refines them, drift makes them
 * move every frame): written again at most once a second of running time, and at the end. */
static void save_moved_offsets(GstStitchCalib* self, double now_s, bool at_end) {
  CalibState* st = self->state;
  std::shared_ptr<const stitch::Rig> rig = st->session.current();
  if (st->save_path.empty() || !rig || rig != st->saved_rig || st->offsets == st->saved_offsets) return;
  if (!at_end && st->saved_at_s >= 0 && now_s - st->saved_at_s < 1.0) return;
  save_rig(self, rig, now_s);
}

/* Posts what the session says; the caller holds no lock. FALSE when it reported an error. */
static gboolean post_events(GstStitchCalib* self) {
  CalibState* st = self->state;
  gboolean ok = TRUE;
  for (const stitch::SessionEvent& e : st->session.take_events()) {
    switch (e.type) {
      case stitch::SessionEvent::Type::Installed:
        save_rig(self, e.report.rig, st->now_s);
        GST_INFO_OBJECT(self, "calibration %" G_GUINT64_FORMAT " from %s: canvas %dx%d, alignment %.2f px",
                        guint64(e.report.version), e.report.source.c_str(), e.report.rig->canvas_width,
                        e.report.rig->canvas_height, e.report.residuals.median_px);
        gst_element_post_message(GST_ELEMENT(self), gst_message_new_element(GST_OBJECT(self),
                                                                           report_structure("stitchcalib", e.report)));
        break;
      case stitch::SessionEvent::Type::Rejected: {
        GST_INFO_OBJECT(self, "%s kept out: %s", e.report.source.c_str(), e.report.rejected_because.c_str());
        gst_element_post_message(GST_ELEMENT(self),
                                 gst_message_new_element(GST_OBJECT(self), report_structure("stitchcalib-rejected", e.report)));
        break;
      }
      case stitch::SessionEvent::Type::Pending:
        gst_element_post_message(
            GST_ELEMENT(self),
            gst_message_new_element(GST_OBJECT(self), gst_structure_new("stitchcalib-pending", "reason", G_TYPE_STRING,
                                                                        e.text.c_str(), "waited-s", G_TYPE_DOUBLE,
                                                                        e.waited_s, NULL)));
        break;
      case stitch::SessionEvent::Type::Qos: {
        GstMessage* qos = gst_message_new_qos(GST_OBJECT(self), FALSE, st->drop_running, st->drop_stream, st->drop_pts,
                                              st->drop_duration);
        gst_message_set_qos_stats(qos, GST_FORMAT_BUFFERS, e.processed, e.dropped);
        gst_element_post_message(GST_ELEMENT(self), qos);
        break;
      }
      case stitch::SessionEvent::Type::Warning:
        GST_ELEMENT_WARNING(self, STREAM, FAILED, ("%s", e.text.c_str()), (NULL));
        break;
      case stitch::SessionEvent::Type::Error:
        GST_ELEMENT_ERROR(self, STREAM, FAILED, ("%s", e.text.c_str()), (NULL));
        ok = FALSE;
        break;
    }
  }
  return ok;
}

static void start_worker(CalibState* st, std::shared_ptr<stitch::CalibJob> job) {
  st->cancel_worker();  /* one the session forgot (a resize, a lens fit that gave way): stop it */
  auto ch = std::make_shared<WorkerChannel>();
  ch->kind = job->kind;
  ch->progress = job->progress;
  ch->attempt = job->attempt;
  ch->frame_sets = int(job->calib_sets.size());
  ch->cameras = job->calib_sets.empty() ? 0 : int(job->calib_sets.front().images.size());
  ch->started_us = g_get_monotonic_time();
  {
    std::lock_guard<std::mutex> g(workers_lock);
    ++workers_alive;
  }
  try {
    std::thread([ch, job]() {
      stitch::CalibOutcome o;
      try {
        o = stitch::run_calib_job(*job, ch->cancel);
      } catch (const std::exception& e) {
        o = stitch::CalibOutcome();
        o.error = e.what();
      } catch (...) {
        o = stitch::CalibOutcome();
        o.error = "unknown exception in the calibration";
      }
      o.kind = job->kind;
      o.serial = job->serial;
      {
        std::lock_guard<std::mutex> g(ch->m);
        ch->outcome = std::move(o);
        ch->done = true;
      }
      ch->cv.notify_all();
      std::lock_guard<std::mutex> g(workers_lock);
      --workers_alive;
      workers_cv.notify_all();
    }).detach();
  } catch (...) {
    std::lock_guard<std::mutex> g(workers_lock);
    --workers_alive;
    throw;
  }
  st->worker = ch;
}

/* Hands a finished job's outcome to the session, without waiting. */
static void collect_outcome(CalibState* st) {
  if (!st->worker || !st->worker->done.load()) return;
  std::shared_ptr<WorkerChannel> ch = std::move(st->worker);
  st->worker.reset();
  GST_INFO("%s job (attempt %d, %d frame sets) done in %.2f s: %s", stitch::job_kind_name(ch->kind), ch->attempt,
           ch->frame_sets, double(g_get_monotonic_time() - ch->started_us) / G_USEC_PER_SEC,
           ch->outcome.cancelled ? "cancelled" : ch->outcome.error.empty() ? "ok" : ch->outcome.error.c_str());
  st->session.on_outcome(ch->outcome);
}

/* While the stream waits for its first calibration (files: the lens fit may take a minute), a
 * stitchcalib-pending message about once a second of wall time says what the worker is doing:
 * the stream is not frozen. Running time stands still meanwhile, so calibration-timeout does not
 * run out during it. */
static void post_calibrating(GstStitchCalib* self, const WorkerChannel& ch) {
  const double job_s = double(g_get_monotonic_time() - ch.started_us) / G_USEC_PER_SEC;
  const char* stage = stitch::job_stage_name(ch.progress ? ch.progress->stage.load() : stitch::JobStage::Estimating);
  /* live cameras' bundles are dropped meanwhile; files' are held (EarlyBundles) */
  const char* meanwhile = self->state->upstream_live == 1 ? "no panorama until then" : "the stream waits for it and no frame is lost";
  gchar* reason = g_strdup_printf("calibrating the first frames (attempt %d, %d frame set%s of %d cameras): %s, %.0f s so far; %s",
                                  ch.attempt, ch.frame_sets, ch.frame_sets == 1 ? "" : "s", ch.cameras, stage, job_s,
                                  meanwhile);
  GST_DEBUG_OBJECT(self, "%s", reason);
  gst_element_post_message(
      GST_ELEMENT(self),
      gst_message_new_element(GST_OBJECT(self),
                              gst_structure_new("stitchcalib-pending", "reason", G_TYPE_STRING, reason, "waited-s",
                                                G_TYPE_DOUBLE, self->state->session.waited_s(), "stage", G_TYPE_STRING,
                                                stage, "attempt", G_TYPE_INT, ch.attempt, "calibrating-s",
                                                G_TYPE_DOUBLE, job_s, NULL)));
  g_free(reason);
}

/* The first calibration: nothing can be output before it, so the streaming thread waits for the
 * worker (holding no lock), and gives up as soon as the element flushes or stops. Until a
 * calibration exists it says so once a second (post_calibrating). */
static gboolean wait_for_worker(GstStitchCalib* self) {
  CalibState* st = self->state;
  std::shared_ptr<WorkerChannel> ch = st->worker;
  const bool say = !st->session.current() && ch->kind == stitch::JobKind::First && !ch->cancel.load();
  gint64 next_say_us = g_get_monotonic_time() + G_USEC_PER_SEC;
  std::unique_lock<std::mutex> g(ch->m);
  while (!ch->done.load()) {
    if (st->unblock.load()) return FALSE;
    ch->cv.wait_for(g, std::chrono::milliseconds(20));
    if (say && !ch->done.load() && g_get_monotonic_time() >= next_say_us) {
      g.unlock();  /* posted outside every lock: a bus handler may do anything */
      post_calibrating(self, *ch);
      g.lock();
      next_say_us = g_get_monotonic_time() + G_USEC_PER_SEC;
    }
  }
  return TRUE;
}

/* Whether the cameras upstream are live (a latency query, asked once per start). */
static bool upstream_is_live(GstStitchCalib* self) {
  CalibState* st = self->state;
  if (st->upstream_live < 0) {
    GstQuery* q = gst_query_new_latency();
    gboolean live = FALSE;
    if (gst_pad_peer_query(GST_BASE_TRANSFORM_SINK_PAD(self), q)) gst_query_parse_latency(q, &live, nullptr, nullptr);
    gst_query_unref(q);
    st->upstream_live = live ? 1 : 0;
  }
  return st->upstream_live == 1;
}

/* Holds a bundle that a first calibration cannot use for lack of a camera (LateCameraHold),
 * so that non-live cameras do not run ahead of it. FALSE: flushing or stopping. */
static gboolean hold_for_late_camera(GstStitchCalib* self, const stitch::CalibSession::Frame& frame) {
  CalibState* st = self->state;
  const gint64 hold_us = st->late_hold.wait_us(st->session.waits_for_a_camera(frame), upstream_is_live(self));
  if (hold_us <= 0) return TRUE;
  GST_DEBUG_OBJECT(self, "holding a bundle without every camera for %" G_GINT64_FORMAT " ms (non-live inputs)", hold_us / 1000);
  const gint64 until = g_get_monotonic_time() + hold_us;
  while (g_get_monotonic_time() < until) {
    if (st->unblock.load()) return FALSE;
    g_usleep(10000);
  }
  return TRUE;
}

static double running_time_s(GstStitchCalib* self, GstBuffer* buf) {
  GstBaseTransform* trans = GST_BASE_TRANSFORM(self);
  const GstClockTime pts = GST_BUFFER_PTS(buf);
  if (trans->segment.format == GST_FORMAT_TIME && GST_CLOCK_TIME_IS_VALID(pts)) {
    const GstClockTime rt = gst_segment_to_running_time(&trans->segment, GST_FORMAT_TIME, pts);
    if (GST_CLOCK_TIME_IS_VALID(rt)) return double(rt) / GST_SECOND;
  }
  /* no timestamps: wall time since start */
  return double(g_get_monotonic_time() - self->state->started_us) / G_USEC_PER_SEC;
}

static void note_drop(GstStitchCalib* self, GstBuffer* buf) {
  GstBaseTransform* trans = GST_BASE_TRANSFORM(self);
  CalibState* st = self->state;
  st->drop_pts = GST_BUFFER_PTS(buf);
  st->drop_duration = GST_BUFFER_DURATION(buf);
  st->drop_running = st->drop_stream = GST_CLOCK_TIME_NONE;
  if (trans->segment.format == GST_FORMAT_TIME && GST_CLOCK_TIME_IS_VALID(st->drop_pts)) {
    st->drop_running = gst_segment_to_running_time(&trans->segment, GST_FORMAT_TIME, st->drop_pts);
    st->drop_stream = gst_segment_to_stream_time(&trans->segment, GST_FORMAT_TIME, st->drop_pts);
  }
}

/* Before a calibration from scratch: what panorama stitchblend downstream will output, so
 * that the canvas is made at that size (none answering: the canvas's own size). */
static void ask_output_size(GstStitchCalib* self) {
  CalibState* st = self->state;
  GstQuery* q = stitch_output_size_query_new();
  gint w = 0, h = 0, crop = 0;
  if (gst_pad_peer_query(GST_BASE_TRANSFORM_SRC_PAD(self), q) && stitch_output_size_query_parse(q, &w, &h, &crop)) {
    if (w != st->output_width || h != st->output_height)
      GST_INFO_OBJECT(self, "stitchblend outputs %dx%d (0: the canvas's): the canvas is made no larger", w, h);
    st->output_width = w;
    st->output_height = h;
    st->output_crop = crop;
  }
  gst_query_unref(q);
}

static void snapshot_settings(CalibState* st) {
  stitch::SessionConfig config;
  {
    std::lock_guard<std::mutex> g(st->settings_lock);
    config = st->settings.config;
    config.resize_is_error = st->settings.on_resize == ON_RESIZE_ERROR;
  }
  st->save_path = config.save_file;
  config.save_file.clear();  // saved by save_rig, with the time offsets
  config.output_width = st->output_width;
  config.output_height = st->output_height;
  config.output_crop = st->output_crop == 1 ? stitch::CropMode::Auto : stitch::CropMode::None;
  st->session.set_config(config);
}

/* The calibration on a bundle; a camera calibrated without (never delivered, or dark) is a
 * missing view downstream. */
static void attach_rig(GstStitchCalib* self, GstBuffer* buf, const std::shared_ptr<const stitch::Rig>& rig) {
  gst_buffer_add_stitch_rig_meta(buf, rig, self->state->session.version());
  if (!stitch::any_left_out(*rig)) return;
  GstStitchBundleMeta* writable = gst_buffer_get_stitch_bundle_meta(buf);
  for (std::size_t i = 0; writable && i < rig->cameras.size() && i < 64; ++i)
    if (rig->cameras[i].left_out) writable->missing_mask |= guint64(1) << i;
}

/* Non-live inputs, no calibration yet: keeps a copy of the bundle to go out with the first
 * calibration (EarlyBundles). FALSE when it cannot be held (the caller drops it). */
static gboolean hold_early_bundle(GstStitchCalib* self, GstBuffer* buf, const stitch::CalibSession::Frame& frame) {
  CalibState* st = self->state;
  st->early.set_max_bytes(st->session.config().hold_before_first_bytes);
  GstBuffer* copy = gst_buffer_copy_deep(buf);
  if (!copy) {
    GST_DEBUG_OBJECT(self, "cannot copy a bundle before the first calibration: dropped");
    return FALSE;
  }
  for (GstBuffer* old : st->early.keep(copy, gst_buffer_get_size(copy), frame.sizes)) {
    note_drop(self, old);
    gst_buffer_unref(old);
    st->session.bundle_dropped();
  }
  if (st->early.bound_reached())
    GST_ELEMENT_WARNING(self, STREAM, FAILED,
                        ("%u bundles (%.0f MiB) are held until the first calibration, the most it keeps: the oldest "
                         "are dropped, and the panorama starts later than the inputs",
                         guint(st->early.count()), double(st->early.bytes()) / (1 << 20)),
                        ("non-live inputs: the bundles before the first calibration go out with it, up to %.0f MiB",
                         double(st->early.max_bytes()) / (1 << 20)));
  GST_LOG_OBJECT(self, "holding %u bundles (%.1f MiB) until the first calibration", guint(st->early.count()),
                 double(st->early.bytes()) / (1 << 20));
  return TRUE;
}

/* The first calibration is installed: the bundles held before it go out with it, in order. */
static GstFlowReturn push_early_bundles(GstStitchCalib* self, const std::shared_ptr<const stitch::Rig>& rig) {
  CalibState* st = self->state;
  const std::vector<GstBuffer*> held = st->early.take();
  if (!held.empty())
    GST_INFO_OBJECT(self, "the %u bundles held until the first calibration go out with it", guint(held.size()));
  GstFlowReturn ret = GST_FLOW_OK;
  for (GstBuffer* b : held) {
    if (ret != GST_FLOW_OK) {
      gst_buffer_unref(b);
      continue;
    }
    attach_rig(self, b, rig);
    st->passed_any = true;
    st->session.bundle_passed();
    ret = gst_pad_push(GST_BASE_TRANSFORM_SRC_PAD(self), b);
  }
  return ret;
}

static GstFlowReturn gst_stitch_calib_transform_ip(GstBaseTransform* trans, GstBuffer* buf) {
  GstStitchCalib* self = GST_STITCH_CALIB(trans);
  CalibState* st = self->state;
  GstCaps* caps = gst_pad_get_current_caps(GST_BASE_TRANSFORM_SINK_PAD(trans));
  const guint n_views = stitch_bundle_caps_views(caps);
  if (caps) gst_caps_unref(caps);

  stitch::CalibSession::Frame frame;
  std::string error;
  if (!stitch_bundle_view_sizes(buf, n_views, frame.sizes, error)) {
    GST_ELEMENT_ERROR(self, STREAM, FORMAT, ("Bad bundle: %s", error.c_str()), (NULL));
    return GST_FLOW_ERROR;
  }
  const GstStitchBundleMeta* bundle = gst_buffer_get_stitch_bundle_meta(buf);
  frame.missing_mask = bundle ? bundle->missing_mask : 0;
  if (bundle && bundle->has_pad_numbers && bundle->n_views == frame.sizes.size())
    frame.camera_ids.assign(bundle->pad_numbers, bundle->pad_numbers + MIN(bundle->n_views, guint(STITCH_MAX_VIEWS)));
  frame.time_s = running_time_s(self, buf);
  frame.live = upstream_is_live(self);
  st->now_s = frame.time_s;
  if (bundle) {
    st->offsets.present = bundle->has_time_offsets;
    st->offsets.estimated_mask = bundle->estimated_mask;
    st->offsets.ns.assign(bundle->time_offsets_ns, bundle->time_offsets_ns + MIN(bundle->n_views, guint(STITCH_MAX_VIEWS)));
  }
  if (!st->session.current()) ask_output_size(self);
  snapshot_settings(st);
  if (st->recalibrate_requested.exchange(false)) st->session.request_recalibration();

  bool flushing = false;
  const gboolean guarded = stitch_guard(GST_ELEMENT(self), "stitchcalib", [&]() {
    /* the background lens fit gives way to a recalibration whose frames are collected */
    if (st->worker && !st->worker->done.load() && st->session.give_way(false)) st->cancel_worker();
    collect_outcome(st);
    /* Pixels are read only on the bundles the session wants (quality checks and calibrations):
     * CUDA-memory views then come to the host through gst-cuda; every other bundle passes untouched. */
    StitchBundleMapping mapping;
    std::vector<stitch::ImageView> views;
    if (st->session.wants_pixels(frame)) {
      if (!mapping.map(buf, n_views, GST_MAP_READ, error)) throw std::runtime_error("bad bundle: " + error);
      views = mapping.views();
    }
    std::shared_ptr<stitch::CalibJob> job = st->session.on_frame(frame, views);
    if (job) start_worker(st, job);
    if (st->worker && !st->session.failed() &&
        stitch::stream_waits_for_job(st->worker->kind, st->session.current() != nullptr, frame.live)) {
      if (!wait_for_worker(self)) {
        flushing = true;
        return;
      }
      collect_outcome(st);
    }
  });
  if (!guarded) return GST_FLOW_ERROR;
  if (!post_events(self)) return GST_FLOW_ERROR;
  if (flushing) return GST_FLOW_FLUSHING;
  std::shared_ptr<const stitch::Rig> rig = st->session.current();
  /* at start-up a live stitchsync may bundle before any camera's first frame is due: every
   * view missing is nothing to show, so no black panorama goes out first */
  const bool all_missing = n_views > 0 && n_views < 64 && (frame.missing_mask & ((guint64(1) << n_views) - 1)) ==
                                                              (guint64(1) << n_views) - 1;
  if (!rig || (all_missing && !st->passed_any)) {
    if (!rig && !hold_for_late_camera(self, frame)) return GST_FLOW_FLUSHING;
    if (!rig && st->session.last_bundle_torn_only()) gst_buffer_replace(&st->last_torn, buf);
    else st->forget_torn();
    if (!rig && stitch::EarlyBundles<GstBuffer*>::holds(frame.live, st->session.failed(), frame.missing_mask) &&
        hold_early_bundle(self, buf, frame)) {
      post_events(self);
      return GST_BASE_TRANSFORM_FLOW_DROPPED;
    }
    note_drop(self, buf);
    st->session.bundle_dropped();
    post_events(self);
    return GST_BASE_TRANSFORM_FLOW_DROPPED;
  }
  st->forget_torn();
  if (!st->early.empty()) {
    const GstFlowReturn pushed = push_early_bundles(self, rig);
    if (pushed != GST_FLOW_OK) return pushed;
  }
  attach_rig(self, buf, rig);
  st->passed_any = true;
  st->session.bundle_passed();
  post_events(self);
  save_moved_offsets(self, frame.time_s, false);
  return GST_FLOW_OK;
}

static gboolean gst_stitch_calib_sink_event(GstBaseTransform* trans, GstEvent* event) {
  GstStitchCalib* self = GST_STITCH_CALIB(trans);
  CalibState* st = self->state;
  switch (GST_EVENT_TYPE(event)) {
    case GST_EVENT_FLUSH_START: st->unblock = true; break;
    case GST_EVENT_FLUSH_STOP:
      st->unblock = false;
      st->forget_torn();
      st->drop_early();
      break;
    case GST_EVENT_EOS:
      /* Serialized: the streaming thread owns the session here. A calibration in flight is
       * finished first (a flush or a stop still releases the wait), so that its result is
       * announced and saved. */
      snapshot_settings(st);
      if (st->worker && !st->worker->done.load() &&
          stitch::cancel_at_end_of_stream(st->worker->kind, st->session.current() != nullptr, !st->save_path.empty())) {
        /* Not waited for (the EOS came 6-15 s late on the real clips with the pooled one). */
        GST_DEBUG_OBJECT(self, "end of stream: the %s job in flight is cancelled", stitch::job_kind_name(st->worker->kind));
        std::shared_ptr<WorkerChannel> ch = st->worker;
        ch->cancel = true;
        /* It stops at the calibrator's next stage (a detection, a pair: well under a second).
         * Waited for all the same: a process that exits while it runs OpenCV crashes in the
         * thread pool's teardown. */
        wait_for_worker(self);
        st->worker.reset();
        st->session.abandon_job();
      }
      if (st->worker && wait_for_worker(self)) collect_outcome(st);
      if (!st->session.current() && !st->session.failed() && st->last_torn) {
        /* the held copy of the last bundle: it is calibrated on and output below */
        if (!st->early.empty() && GST_BUFFER_PTS(st->early.newest()) == GST_BUFFER_PTS(st->last_torn))
          gst_buffer_unref(*st->early.take_newest());
        /* The stream ended on torn pictures alone: no later frame can replace them (a photo, a
         * camera's last frame), so they are taken as the pictures' own and the last bundle is
         * calibrated on and output (two photos of a bridge as one-frame streams made no
         * panorama: "camera 0 is corrupt (a torn picture ...)"). */
        GstBuffer* last = gst_buffer_make_writable(st->last_torn);
        st->last_torn = nullptr;
        st->session.accept_torn_pictures();
        GST_INFO_OBJECT(self, "the stream ended on torn pictures: taken as the cameras' own");
        if (gst_stitch_calib_transform_ip(trans, last) == GST_FLOW_OK)
          gst_pad_push(GST_BASE_TRANSFORM_SRC_PAD(trans), last);
        else
          gst_buffer_unref(last);
      }
      if (!st->session.current() && !st->session.failed() && !st->early.empty() && st->session.retry_at_end()) {
        /* Files that end uncalibrated after a failed attempt and bundles the back-off skipped: the
         * last one is tried once more, pooled with those tried (a short clip gets its panoramas). */
        GstBuffer* last = *st->early.take_newest();
        GST_INFO_OBJECT(self, "the stream ended uncalibrated: one more attempt on its last bundle");
        if (gst_stitch_calib_transform_ip(trans, last) == GST_FLOW_OK)
          gst_pad_push(GST_BASE_TRANSFORM_SRC_PAD(trans), last);
        else
          gst_buffer_unref(last);
      }
      st->forget_torn();
      /* the first calibration came with the last bundle's job: what it held goes out before the end */
      if (std::shared_ptr<const stitch::Rig> rig = st->session.current()) push_early_bundles(self, rig);
      st->drop_early();
      st->session.on_eos();
      post_events(self);
      save_moved_offsets(self, st->now_s, true);
      break;
    default: break;
  }
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_calib_parent_class)->sink_event(trans, event);
}

static GstStateChangeReturn gst_stitch_calib_change_state(GstElement* element, GstStateChange transition) {
  GstStitchCalib* self = GST_STITCH_CALIB(element);
  /* Before the pads deactivate (they wait for the streaming thread): release a streaming thread
   * that waits for a calibration. stop() then cancels the worker. */
  if (transition == GST_STATE_CHANGE_PAUSED_TO_READY) self->state->unblock = true;
  if (transition == GST_STATE_CHANGE_READY_TO_PAUSED) self->state->unblock = false;
  return GST_ELEMENT_CLASS(gst_stitch_calib_parent_class)->change_state(element, transition);
}

static gboolean gst_stitch_calib_start(GstBaseTransform* trans) {
  CalibState* st = GST_STITCH_CALIB(trans)->state;
  st->cancel_worker();
  st->session.reset();
  st->forget_saved();
  st->started_us = g_get_monotonic_time();
  st->passed_any = false;
  st->unblock = false;
  st->late_hold.reset();
  st->upstream_live = -1;
  st->drop_early();
  return TRUE;
}

static gboolean gst_stitch_calib_stop(GstBaseTransform* trans) {
  /* The streaming thread has stopped: cancel the worker and forget everything. The worker stops
   * at the calibrator's next stage (CalibrationOptions::cancel: well under a second), and that
   * moment is waited for, 3 s at most: an application that sets the pipeline to NULL and exits
   * while it runs OpenCV crashed in the thread pool's teardown (examples/recalibrate.py with the
   * background lens fit in flight). */
  CalibState* st = GST_STITCH_CALIB(trans)->state;
  if (std::shared_ptr<WorkerChannel> ch = st->worker) {
    ch->cancel = true;
    std::unique_lock<std::mutex> g(ch->m);
    ch->cv.wait_for(g, std::chrono::seconds(3), [&] { return ch->done.load(); });
  }
  st->cancel_worker();
  st->session.reset();
  st->forget_torn();
  st->drop_early();
  return TRUE;
}

static gboolean gst_stitch_calib_set_caps(GstBaseTransform* trans, GstCaps* incaps, GstCaps*) {
  GstStitchCalib* self = GST_STITCH_CALIB(trans);
  if (!stitch_bundle_accept_caps(GST_ELEMENT(self), incaps)) return FALSE;
  return !stitch_caps_are_cuda_memory(incaps) || self->state->cuda.ensure(GST_ELEMENT(self));
}

static GstCaps* gst_stitch_calib_transform_caps(GstBaseTransform* trans, GstPadDirection, GstCaps* caps, GstCaps* filter) {
  /* In place, both sides in the same memory. CUDA memory unless backend=cpu: the bundles pass
   * untouched and feature matching runs on the CPU in every mode. */
  CalibState* st = GST_STITCH_CALIB(trans)->state;
  stitch::Backend backend;
  {
    std::lock_guard<std::mutex> g(st->settings_lock);
    backend = st->settings.backend;
  }
  return stitch_caps_same_memory(caps, filter, stitch_cuda_memory_offered(backend));
}

static void gst_stitch_calib_set_context(GstElement* element, GstContext* context) {
  GST_STITCH_CALIB(element)->state->cuda.set_context(element, context);
  GST_ELEMENT_CLASS(gst_stitch_calib_parent_class)->set_context(element, context);
}

static gboolean gst_stitch_calib_query(GstBaseTransform* trans, GstPadDirection direction, GstQuery* query) {
  if (GST_STITCH_CALIB(trans)->state->cuda.handle_query(GST_ELEMENT(trans), query)) return TRUE;
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_calib_parent_class)->query(trans, direction, query);
}

static void gst_stitch_calib_recalibrate(GstStitchCalib* self) {
  self->state->recalibrate_requested = true;
}

static void set_string(std::string& dst, const GValue* value) {
  const gchar* s = g_value_get_string(value);
  dst = s ? s : "";
}

static void gst_stitch_calib_set_property(GObject* object, guint prop_id, const GValue* value,
                                          GParamSpec* pspec) {
  GstStitchCalib* self = GST_STITCH_CALIB(object);
  std::lock_guard<std::mutex> guard(self->state->settings_lock);
  CalibSettings& s = self->state->settings;
  stitch::SessionConfig& c = s.config;
  switch (prop_id) {
    case PROP_RIG_FILE: set_string(c.rig_file, value); break;
    case PROP_LOAD_FILE: set_string(c.load_file, value); break;
    case PROP_SAVE_FILE: set_string(c.save_file, value); break;
    case PROP_REFINE: c.options.refinement = stitch::Refinement(g_value_get_enum(value)); break;
    case PROP_FEATURES: c.options.features = stitch::FeatureType(g_value_get_enum(value)); break;
    case PROP_RECALIBRATE_INTERVAL: c.recalibrate_interval_s = g_value_get_double(value); break;
    case PROP_MIN_INLIERS: c.options.min_inliers = g_value_get_int(value); break;
    case PROP_OVERLAP_MARGIN: c.options.overlap_margin = g_value_get_double(value); break;
    case PROP_REFERENCE: c.reference = g_value_get_int(value); break;
    case PROP_CALIBRATION_FRAMES: c.calibration_frames = g_value_get_int(value); break;
    case PROP_BACKEND: s.backend = stitch::Backend(g_value_get_enum(value)); break;
    case PROP_ON_RESIZE: s.on_resize = OnResize(g_value_get_enum(value)); break;
    case PROP_PROJECTION: {
      const int p = g_value_get_enum(value);
      if (p == PROJECTION_UNSET) c.projection.reset();
      else c.projection = stitch::Projection(p);
      break;
    }
    case PROP_BUNDLE_ADJUST: c.options.bundle_adjust = g_value_get_boolean(value); break;
    case PROP_CAMERA_MODEL: c.options.model = stitch::CameraModel(g_value_get_enum(value)); break;
    case PROP_WAVE_CORRECT: c.options.wave_correct = g_value_get_boolean(value); break;
    case PROP_CALIBRATION_WINDOW: c.calibration_window_s = g_value_get_double(value); break;
    case PROP_CALIBRATION_TIMEOUT: c.calibration_timeout_s = g_value_get_double(value); break;
    case PROP_DRIFT_THRESHOLD: c.drift_threshold_px = g_value_get_double(value); break;
    case PROP_LEAVE_OUT_AFTER: c.leave_out_after_s = g_value_get_double(value); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_calib_get_property(GObject* object, guint prop_id, GValue* value,
                                          GParamSpec* pspec) {
  GstStitchCalib* self = GST_STITCH_CALIB(object);
  std::lock_guard<std::mutex> guard(self->state->settings_lock);
  const CalibSettings& s = self->state->settings;
  const stitch::SessionConfig& c = s.config;
  switch (prop_id) {
    case PROP_RIG_FILE: g_value_set_string(value, c.rig_file.empty() ? NULL : c.rig_file.c_str()); break;
    case PROP_LOAD_FILE: g_value_set_string(value, c.load_file.empty() ? NULL : c.load_file.c_str()); break;
    case PROP_SAVE_FILE: g_value_set_string(value, c.save_file.empty() ? NULL : c.save_file.c_str()); break;
    case PROP_REFINE: g_value_set_enum(value, int(c.options.refinement)); break;
    case PROP_FEATURES: g_value_set_enum(value, int(c.options.features)); break;
    case PROP_RECALIBRATE_INTERVAL: g_value_set_double(value, c.recalibrate_interval_s); break;
    case PROP_MIN_INLIERS: g_value_set_int(value, c.options.min_inliers); break;
    case PROP_OVERLAP_MARGIN: g_value_set_double(value, c.options.overlap_margin); break;
    case PROP_REFERENCE: g_value_set_int(value, c.reference); break;
    case PROP_CALIBRATION_FRAMES: g_value_set_int(value, c.calibration_frames); break;
    case PROP_BACKEND: g_value_set_enum(value, int(s.backend)); break;
    case PROP_ON_RESIZE: g_value_set_enum(value, int(s.on_resize)); break;
    case PROP_PROJECTION: g_value_set_enum(value, c.projection ? int(*c.projection) : PROJECTION_UNSET); break;
    case PROP_BUNDLE_ADJUST: g_value_set_boolean(value, c.options.bundle_adjust); break;
    case PROP_CAMERA_MODEL: g_value_set_enum(value, int(c.options.model)); break;
    case PROP_WAVE_CORRECT: g_value_set_boolean(value, c.options.wave_correct); break;
    case PROP_CALIBRATION_WINDOW: g_value_set_double(value, c.calibration_window_s); break;
    case PROP_CALIBRATION_TIMEOUT: g_value_set_double(value, c.calibration_timeout_s); break;
    case PROP_DRIFT_THRESHOLD: g_value_set_double(value, c.drift_threshold_px); break;
    case PROP_LEAVE_OUT_AFTER: g_value_set_double(value, c.leave_out_after_s); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_calib_finalize(GObject* object) {
  GstStitchCalib* self = GST_STITCH_CALIB(object);
  self->state->cancel_worker();  // the worker owns what it reads: nothing to wait for
  self->state->forget_torn();
  self->state->drop_early();
  delete self->state;
  G_OBJECT_CLASS(gst_stitch_calib_parent_class)->finalize(object);
}

static void gst_stitch_calib_class_init(GstStitchCalibClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  GstBaseTransformClass* trans_class = GST_BASE_TRANSFORM_CLASS(klass);
  const GParamFlags rw = GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS);
  /* read at every bundle (or at the next calibration): they may change while playing */
  const GParamFlags live = GParamFlags(rw | GST_PARAM_MUTABLE_PLAYING);

  gobject_class->set_property = gst_stitch_calib_set_property;
  gobject_class->get_property = gst_stitch_calib_get_property;
  gobject_class->finalize = gst_stitch_calib_finalize;

  g_object_class_install_property(gobject_class, PROP_RIG_FILE,
      g_param_spec_string("rig-file", "Rig file",
                          "Rough camera parameters (stitch-rig JSON); read again at the next calibration when changed",
                          NULL, live));
  g_object_class_install_property(gobject_class, PROP_LOAD_FILE,
      g_param_spec_string("load-file", "Load file",
                          "Saved calibration to use as is (no estimation); it is checked against the images "
                          "and a warning names the cameras it does not fit", NULL, GParamFlags(rw | GST_PARAM_MUTABLE_READY)));
  g_object_class_install_property(gobject_class, PROP_SAVE_FILE,
      g_param_spec_string("save-file", "Save file",
                          "Write the calibration here whenever it changes (its canvas is the panorama size)", NULL, live));
  g_object_class_install_property(gobject_class, PROP_REFINE,
      g_param_spec_enum("refine", "Refine", "How features refine the rough homographies",
                        refine_get_type(), int(DEFAULT_REFINE), live));
  g_object_class_install_property(gobject_class, PROP_FEATURES,
      g_param_spec_enum("features", "Features", "Feature detector for matching",
                        features_get_type(), int(DEFAULT_FEATURES), live));
  g_object_class_install_property(gobject_class, PROP_RECALIBRATE_INTERVAL,
      g_param_spec_double("recalibrate-interval", "Recalibrate interval",
                          "Recalibrate every this many seconds of running time (0 = only at start "
                          "and on request); the result replaces the current calibration only when it "
                          "aligns held-out frames better", 0, G_MAXDOUBLE, DEFAULT_INTERVAL, live));
  g_object_class_install_property(gobject_class, PROP_MIN_INLIERS,
      g_param_spec_int("min-inliers", "Minimum inliers",
                       "Fewer RANSAC inliers keep the previous homography of that camera", 4,
                       100000, DEFAULT_MIN_INLIERS, live));
  g_object_class_install_property(gobject_class, PROP_OVERLAP_MARGIN,
      g_param_spec_double("overlap-margin", "Overlap margin",
                          "Widen each overlap by this fraction of the view width before matching",
                          0, 2, DEFAULT_OVERLAP_MARGIN, live));
  g_object_class_install_property(gobject_class, PROP_REFERENCE,
      g_param_spec_int("reference", "Reference camera",
                       "Camera whose image plane is the canvas (-1: the rig's, or the middle one)",
                       -1, STITCH_MAX_VIEWS - 1, DEFAULT_REFERENCE, live));
  g_object_class_install_property(gobject_class, PROP_CALIBRATION_FRAMES,
      g_param_spec_int("calibration-frames", "Calibration frames",
                       "Pool the matches of this many good frames, spread over calibration-window, into a "
                       "calibration that replaces the first-frame one when it aligns held-out frames better "
                       "(1 = first frame only); recalibrations pool as many",
                       1, 100, DEFAULT_CALIBRATION_FRAMES, live));
  g_object_class_install_property(gobject_class, PROP_CALIBRATION_WINDOW,
      g_param_spec_double("calibration-window", "Calibration window",
                          "Seconds of running time over which the pooled and held-out frames of a "
                          "calibration are picked (the best of each stretch: sharp, textured, not dark or torn)",
                          0, 600, DEFAULT_CALIBRATION_WINDOW, live));
  g_object_class_install_property(gobject_class, PROP_CALIBRATION_TIMEOUT,
      g_param_spec_double("calibration-timeout", "Calibration timeout",
                          "Keep trying to calibrate for this many seconds of running time, posting "
                          "stitchcalib-pending messages, then stop with an error (0 = keep trying); a stream "
                          "that ends uncalibrated is an error", 0, G_MAXDOUBLE, DEFAULT_CALIBRATION_TIMEOUT, live));
  g_object_class_install_property(gobject_class, PROP_LEAVE_OUT_AFTER,
      g_param_spec_double("leave-out-after", "Leave out after",
                          "Before the first calibration, a camera that has delivered no frame, or only dark "
                          "ones, for this many seconds of running time is left out: the others are calibrated "
                          "and stitched, a warning and the message's left-out name it, and it joins with a new "
                          "calibration once it shows a picture (0 = wait for every camera)",
                          0, 3600, DEFAULT_LEAVE_OUT_AFTER, live));
  g_object_class_install_property(gobject_class, PROP_DRIFT_THRESHOLD,
      g_param_spec_double("drift-threshold", "Drift threshold",
                          "Drift watch: every 5 s, measure the alignment on a fresh frame; two checks in a row "
                          "above this many pixels (and above twice the calibration's own) recalibrate "
                          "(0 = off)", 0, 1000, DEFAULT_DRIFT_THRESHOLD, live));
  g_object_class_install_property(gobject_class, PROP_BACKEND,
      g_param_spec_enum("backend", "Backend",
                        "Which memory the bundles may travel in: cpu takes system memory only; auto and cuda "
                        "also take CUDA memory, passed through untouched (only the frames a calibration "
                        "reads are copied to the host). Feature matching always runs on the CPU",
                        GST_TYPE_STITCH_BACKEND, int(stitch::Backend::Auto), GParamFlags(rw | GST_PARAM_MUTABLE_READY)));
  g_object_class_install_property(gobject_class, PROP_ON_RESIZE,
      g_param_spec_enum("on-resize", "On resize",
                        "An input that changes resolution mid-stream (or a camera that leaves): calibrate "
                        "again from scratch for the new sizes (with a warning), or stop with an error",
                        on_resize_get_type(), ON_RESIZE_RECALIBRATE, live));
  g_object_class_install_property(gobject_class, PROP_PROJECTION,
      g_param_spec_enum("projection", "Projection",
                        "Canvas projection (unset: the rig-file's \"projection\", or without a rig-file chosen "
                        "from the estimated field of view); cylindrical and spherical may wrap around 360 degrees",
                        projection_get_type(), PROJECTION_UNSET, live));
  g_object_class_install_property(gobject_class, PROP_BUNDLE_ADJUST,
      g_param_spec_boolean("bundle-adjust", "Bundle adjust",
                           "Older switch: true forces camera-model=rotation (all rotations and focal lengths "
                           "refined jointly on every pair's matches)", FALSE, live));
  g_object_class_install_property(gobject_class, PROP_CAMERA_MODEL,
      g_param_spec_enum("camera-model", "Camera model",
                        "Planar canvases: rotation + intrinsics (cameras turning about one centre), a "
                        "homography per camera (a planar scene, translating cameras), or auto: the one "
                        "with the lower error on held-out matches (non-planar canvases: always rotation)",
                        camera_model_get_type(), int(stitch::CameraModel::Auto), live));
  g_object_class_install_property(gobject_class, PROP_WAVE_CORRECT,
      g_param_spec_boolean("wave-correct", "Wave correct",
                           "Non-planar rigs: level the horizon after the bundle adjustment", TRUE, live));

  signals[SIGNAL_RECALIBRATE] = g_signal_new_class_handler(
      "recalibrate", G_TYPE_FROM_CLASS(klass), GSignalFlags(G_SIGNAL_RUN_LAST | G_SIGNAL_ACTION),
      G_CALLBACK(gst_stitch_calib_recalibrate), NULL, NULL, NULL, G_TYPE_NONE, 0);

  gst_element_class_add_static_pad_template(element_class, &sink_template);
  gst_element_class_add_static_pad_template(element_class, &src_template);
  gst_element_class_set_static_metadata(element_class, "Stitch calibration", "Filter/Analyzer/Video",
      "Attaches camera->canvas homographies to stitch bundles: from rough rig parameters refined "
      "by features, from a saved calibration, or from the images alone",
      "gst-stitch developers");

  trans_class->transform_ip = GST_DEBUG_FUNCPTR(gst_stitch_calib_transform_ip);
  trans_class->start = GST_DEBUG_FUNCPTR(gst_stitch_calib_start);
  trans_class->stop = GST_DEBUG_FUNCPTR(gst_stitch_calib_stop);
  trans_class->set_caps = GST_DEBUG_FUNCPTR(gst_stitch_calib_set_caps);
  trans_class->transform_caps = GST_DEBUG_FUNCPTR(gst_stitch_calib_transform_caps);
  trans_class->query = GST_DEBUG_FUNCPTR(gst_stitch_calib_query);
  trans_class->sink_event = GST_DEBUG_FUNCPTR(gst_stitch_calib_sink_event);
  element_class->set_context = GST_DEBUG_FUNCPTR(gst_stitch_calib_set_context);
  element_class->change_state = GST_DEBUG_FUNCPTR(gst_stitch_calib_change_state);
  trans_class->passthrough_on_same_caps = FALSE;

  gst_type_mark_as_plugin_api(refine_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(features_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(on_resize_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(projection_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(camera_model_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(GST_TYPE_STITCH_BACKEND, GstPluginAPIFlags(0));
  GST_DEBUG_CATEGORY_INIT(gst_stitch_calib_debug, "stitchcalib", 0, "stitch calibration");
}

static void gst_stitch_calib_init(GstStitchCalib* self) {
  self->state = new CalibState();
  stitch::SessionConfig& c = self->state->settings.config;
  c.options.refinement = DEFAULT_REFINE;
  c.options.features = DEFAULT_FEATURES;
  c.options.min_inliers = DEFAULT_MIN_INLIERS;
  c.options.overlap_margin = DEFAULT_OVERLAP_MARGIN;
  c.calibration_frames = DEFAULT_CALIBRATION_FRAMES;
  c.calibration_window_s = DEFAULT_CALIBRATION_WINDOW;
  c.calibration_timeout_s = DEFAULT_CALIBRATION_TIMEOUT;
  c.drift_threshold_px = DEFAULT_DRIFT_THRESHOLD;
  gst_base_transform_set_in_place(GST_BASE_TRANSFORM(self), TRUE);
}
