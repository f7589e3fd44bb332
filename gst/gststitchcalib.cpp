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
 * - neither: calibration from the images alone (features, pairwise homographies chained to
 *   the reference camera).
 *
 * `projection` picks the canvas: `plane` (the reference camera's image plane, homographies),
 * `cylindrical` or `spherical` (equirectangular; each camera's K and R map the canvas, and a
 * ring that looks all around gets a 360-degree canvas whose seam closes at the wrap). Unset, the
 * rig-file's `projection` holds. Non-planar calibration needs a rig-file (rough focal lengths
 * and rotations): features of every overlapping pair feed one bundle adjustment of all
 * rotations and focal lengths, then `wave-correct` levels the horizon. `bundle-adjust=true`
 * does the same for a planar rig (a rotating one) instead of chaining pairwise corrections.
 *
 * It calibrates on the first bundle, then pools the matches of the first `calibration-frames`
 * frames (every 5th) into a refined calibration that replaces it (moving people and noise
 * average out on a static rig). It recalibrates when the `recalibrate` action signal is emitted,
 * and every `recalibrate-interval` seconds if set; later calibrations run in a worker thread
 * while the stream goes on with the previous geometry. Every result is posted as an element
 * message named `stitchcalib` and written to `save-file` when set. When matching fails the
 * last good calibration (or the rough one) is kept and a warning is posted.
 *
 * Bundles that come before the first calibration (a camera not delivering yet, calibration
 * attempts that failed) are dropped, each with a QoS message.
 *
 * An input that changes resolution mid-stream is calibrated again from that frame on, with a
 * warning naming the camera and both sizes (`on-resize=recalibrate`), or stops the stream with
 * an error (`on-resize=error`). Flushes (seeks) keep the calibration: the rig has not moved.
 *
 * Bundles in CUDA memory pass through untouched: only the frames a calibration reads (the
 * first ones, the pooled ones, a recalibration's) are mapped through host memory.
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
#include <mutex>
#include <opencv2/core.hpp>
#include <optional>
#include <thread>

#include "gststitchbundle.h"
#include "gststitchcuda.h"
#include "stitch/calib/calibrator.hpp"

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
  PROP_WAVE_CORRECT,
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
#define POOL_SPACING_FRAMES 5
#define MAX_FIRST_ATTEMPTS 10
#define FRAMES_BETWEEN_ATTEMPTS 15

/* Deep copies of one bundle's views, for calibrations that outlive the buffer. */
struct FrameSet {
  std::vector<cv::Mat> storage;
  std::vector<stitch::ImageView> views;
};

struct CalibSettings {
  std::string rig_file, load_file, save_file;
  stitch::CalibrationOptions options;
  double interval_s = DEFAULT_INTERVAL;
  int reference = DEFAULT_REFERENCE;
  int calibration_frames = DEFAULT_CALIBRATION_FRAMES;
  stitch::Backend backend = stitch::Backend::Auto;
  OnResize on_resize = ON_RESIZE_RECALIBRATE;
  std::optional<stitch::Projection> projection;  // unset: the rig-file's
};

struct CalibState {
  std::mutex lock;  // guards everything below and the settings
  CalibSettings settings;
  std::shared_ptr<const stitch::Rig> current;
  std::optional<stitch::Rig> rough;  // from rig-file, loaded once per start
  std::vector<std::array<int, 2>> sizes;  // the view sizes `current` was made for
  /* bundles passed and dropped (no calibration yet), for the QoS messages */
  std::atomic<guint64> passed{0}, dropped{0};
  guint64 version = 0;
  int failed_attempts = 0;
  guint64 frames_since_attempt = 0;
  GstClockTime last_calibration_pts = GST_CLOCK_TIME_NONE;
  std::atomic<bool> recalibrate_requested{false};
  /* pooling the first frames of a static rig */
  std::vector<FrameSet> pool;
  guint64 frames_seen = 0;
  bool pooling = false;
  /* worker */
  std::thread worker;
  std::atomic<bool> worker_busy{false};
  std::optional<stitch::CalibrationResult> finished;
  std::string finished_label;  // what the running worker computes: "pooled" or "recalibration"
  std::string worker_error;
  /* shared with the neighbours; calibration itself reads views through host memory */
  StitchCudaContext cuda;

  void join() {
    if (worker.joinable()) worker.join();
    worker_busy = false;
  }
  void reset() {
    join();
    current.reset();
    rough.reset();
    finished.reset();
    worker_error.clear();
    failed_attempts = 0;
    frames_since_attempt = 0;
    pool.clear();
    frames_seen = 0;
    pooling = false;
    last_calibration_pts = GST_CLOCK_TIME_NONE;
    sizes.clear();
    passed = 0;
    dropped = 0;
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

/* A camera whose frames changed size since the calibration: recalibrate (dropping every
 * calibration in flight) or stop, by on-resize. FALSE after the error. */
static gboolean handle_resize(GstStitchCalib* self, const std::vector<std::array<int, 2>>& sizes) {
  CalibState* st = self->state;
  std::unique_lock<std::mutex> guard(st->lock);
  if (!st->current || st->sizes.empty() || st->sizes == sizes) return TRUE;
  std::string what;
  for (std::size_t i = 0; i < sizes.size() && i < st->sizes.size(); ++i)
    if (sizes[i] != st->sizes[i])
      what += (what.empty() ? "" : ", ") + std::string("camera ") + std::to_string(i) + " " +
              std::to_string(st->sizes[i][0]) + "x" + std::to_string(st->sizes[i][1]) + " -> " +
              std::to_string(sizes[i][0]) + "x" + std::to_string(sizes[i][1]);
  if (sizes.size() != st->sizes.size())
    what = std::to_string(st->sizes.size()) + " -> " + std::to_string(sizes.size()) + " cameras";
  if (st->settings.on_resize == ON_RESIZE_ERROR) {
    GST_ELEMENT_ERROR(self, STREAM, FORMAT,
                      ("Input resolution changed mid-stream (%s) and on-resize=error", what.c_str()), (NULL));
    return FALSE;
  }
  GST_ELEMENT_WARNING(self, STREAM, FORMAT, ("Input resolution changed mid-stream (%s); recalibrating", what.c_str()),
                      (NULL));
  /* the worker takes the lock when it finishes: join it without */
  guard.unlock();
  st->join();
  guard.lock();
  const guint64 version = st->version, passed = st->passed, dropped = st->dropped;
  st->reset();
  st->version = version;
  st->passed = passed;
  st->dropped = dropped;
  return TRUE;
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
      {int(stitch::Projection::Plane), "The reference camera's image plane (homographies)", "plane"},
      {int(stitch::Projection::Cylindrical), "Cylinder about the rig's vertical axis", "cylindrical"},
      {int(stitch::Projection::Spherical), "Sphere, equirectangular", "spherical"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchCalibProjection", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GstStaticPadTemplate sink_template = GST_STATIC_PAD_TEMPLATE(
    "sink", GST_PAD_SINK, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));
static GstStaticPadTemplate src_template = GST_STATIC_PAD_TEMPLATE(
    "src", GST_PAD_SRC, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));

static void post_result(GstStitchCalib* self, const stitch::CalibrationResult& r, guint64 version,
                        const char* source) {
  double rms = 0;
  int inliers = 0, accepted = 0;
  for (const auto& p : r.pairs) {
    inliers += p.inliers;
    if (p.accepted) {
      rms += p.rms_px;
      ++accepted;
    }
  }
  GstStructure* s = gst_structure_new(
      "stitchcalib", "version", G_TYPE_UINT64, version, "source", G_TYPE_STRING, source,
      "cameras", G_TYPE_INT, int(r.rig.cameras.size()), "refined-cameras", G_TYPE_INT,
      r.refined_cameras, "inliers", G_TYPE_INT, inliers, "rms-px", G_TYPE_DOUBLE,
      accepted ? rms / accepted : 0.0, "canvas-width", G_TYPE_INT, r.rig.canvas_width,
      "canvas-height", G_TYPE_INT, r.rig.canvas_height, "warnings", G_TYPE_INT,
      int(r.warnings.size()), "projection", G_TYPE_STRING, r.rig.projection.c_str(), "canvas-wrap",
      G_TYPE_BOOLEAN, gboolean(r.rig.canvas_wrap), "ba-rms-px", G_TYPE_DOUBLE, r.ba_rms_after_px, NULL);
  gst_element_post_message(GST_ELEMENT(self), gst_message_new_element(GST_OBJECT(self), s));
}

static FrameSet clone_views(const std::vector<stitch::ImageView>& views) {
  FrameSet set;
  for (const auto& v : views) {
    cv::Mat m = cv::Mat(v.height, v.width, CV_8UC4, v.data, v.pitch).clone();
    set.storage.push_back(m);
    stitch::ImageView c;
    c.data = m.data;
    c.pitch = m.step;
    c.width = m.cols;
    c.height = m.rows;
    set.views.push_back(c);
  }
  return set;
}

/* The estimation itself: pure core calls, may run in the worker thread. */
static stitch::CalibrationResult run_calibration(
    const CalibSettings& s, const std::optional<stitch::Rig>& rough,
    const std::shared_ptr<const stitch::Rig>& previous,
    const std::vector<std::vector<stitch::ImageView>>& frames) {
  if (rough) {
    stitch::Rig start = *rough;
    if (s.reference >= 0) start.reference = s.reference;
    if (s.projection && start.projection != stitch::projection_name(*s.projection)) {
      /* Another canvas: what the file computed for its own one does not apply. */
      start.projection = stitch::projection_name(*s.projection);
      for (auto& c : start.cameras) c.homography.reset();
      start.canvas_width = start.canvas_height = 0;
      start.canvas_scale = 0;
    }
    return stitch::calibrate_from_rig(start, frames, s.options);
  }
  if (s.projection && *s.projection != stitch::Projection::Plane)
    throw stitch::RigError(std::string("projection=") + stitch::projection_name(*s.projection) +
                           " needs rough focal lengths and rotations: give a rig-file");
  if (previous) {
    /* re-calibration without a rig: refine the previous geometry with features */
    return stitch::calibrate_from_rig(*previous, frames, s.options);
  }
  return stitch::calibrate_from_images(frames, s.reference, s.options);
}

/* Installs a new calibration (streaming thread, state lock held). */
static void install(GstStitchCalib* self, stitch::CalibrationResult& r, const char* source) {
  CalibState* st = self->state;
  for (const auto& w : r.warnings)
    GST_ELEMENT_WARNING(self, STREAM, FAILED, ("Calibration: %s", w.c_str()), (NULL));
  st->current = std::make_shared<const stitch::Rig>(r.rig);
  st->version++;
  if (!st->settings.save_file.empty()) {
    try {
      stitch::rig_save(*st->current, st->settings.save_file);
    } catch (const std::exception& e) {
      GST_ELEMENT_WARNING(self, RESOURCE, WRITE, ("%s", e.what()), (NULL));
    }
  }
  GST_INFO_OBJECT(self, "calibration %" G_GUINT64_FORMAT " from %s: canvas %dx%d, %d refined",
                  st->version, source, r.rig.canvas_width, r.rig.canvas_height, r.refined_cameras);
  post_result(self, r, st->version, source);
}

/* First calibration (or retry): synchronous so the first output is already calibrated. */
static gboolean calibrate_now(GstStitchCalib* self, const std::vector<stitch::ImageView>& views,
                              const std::vector<std::array<int, 2>>& sizes) {
  CalibState* st = self->state;
  const CalibSettings& s = st->settings;
  if (!s.load_file.empty()) {
    stitch::Rig rig;
    try {
      rig = stitch::rig_load(s.load_file);
    } catch (const std::exception& e) {
      GST_ELEMENT_ERROR(self, RESOURCE, READ, ("%s", e.what()), (NULL));
      return FALSE;
    }
    if (s.projection && rig.projection != stitch::projection_name(*s.projection))
      GST_ELEMENT_WARNING(self, RESOURCE, READ,
                          ("load-file \"%s\" holds a %s calibration; projection=%s applies to "
                           "estimation only, the file is used as is",
                           s.load_file.c_str(), rig.projection.c_str(), stitch::projection_name(*s.projection)),
                          (NULL));
    if (!rig.calibrated()) {
      GST_ELEMENT_ERROR(self, RESOURCE, READ,
                        ("load-file \"%s\" holds no calibration (a planar rig needs a "
                         "\"homography\" per camera and a \"canvas\", a non-planar one a \"canvas\" "
                         "with \"scale\"); use rig-file for rough "
                         "parameters",
                         s.load_file.c_str()),
                        (NULL));
      return FALSE;
    }
    if (rig.cameras.size() != sizes.size()) {
      GST_ELEMENT_ERROR(self, STREAM, WRONG_TYPE,
                        ("load-file \"%s\" describes %d cameras but %d streams are connected",
                         s.load_file.c_str(), int(rig.cameras.size()), int(sizes.size())),
                        (NULL));
      return FALSE;
    }
    if (stitch::rig_adapt_to_sizes(rig, sizes))
      GST_ELEMENT_WARNING(self, STREAM, FORMAT,
                          ("The calibration was made for other frame sizes; it was scaled to the "
                           "streams"),
                          (NULL));
    try {
      stitch::rig_layout_canvas(rig);
    } catch (const std::exception& e) {
      GST_ELEMENT_ERROR(self, STREAM, FAILED, ("load-file: %s", e.what()), (NULL));
      return FALSE;
    }
    stitch::CalibrationResult r;
    r.rig = rig;
    install(self, r, "file");
    return TRUE;
  }
  if (s.rig_file.empty() && !st->current &&
      ((s.projection && *s.projection != stitch::Projection::Plane) || s.options.bundle_adjust)) {
    GST_ELEMENT_ERROR(self, RESOURCE, NOT_FOUND,
                      ("%s needs rough focal lengths and rotations: set rig-file",
                       s.options.bundle_adjust ? "bundle-adjust=true" : "a cylindrical or spherical projection"),
                      (NULL));
    return FALSE;
  }
  if (!s.rig_file.empty() && !st->rough) {
    try {
      st->rough = stitch::rig_load(s.rig_file);
    } catch (const std::exception& e) {
      GST_ELEMENT_ERROR(self, RESOURCE, READ, ("%s", e.what()), (NULL));
      return FALSE;
    }
    if (st->rough->cameras.size() != sizes.size()) {
      GST_ELEMENT_ERROR(self, STREAM, WRONG_TYPE,
                        ("rig-file \"%s\" describes %d cameras but %d streams are connected",
                         s.rig_file.c_str(), int(st->rough->cameras.size()), int(sizes.size())),
                        (NULL));
      return FALSE;
    }
    if (stitch::rig_adapt_to_sizes(*st->rough, sizes))
      GST_ELEMENT_WARNING(self, STREAM, FORMAT,
                          ("rig-file camera sizes differ from the streams; intrinsics were scaled"),
                          (NULL));
  }
  try {
    stitch::CalibrationResult r = run_calibration(s, st->rough, st->current, {views});
    install(self, r, st->rough ? "rig" : "images");
    return TRUE;
  } catch (const stitch::RigError& e) {
    if (st->rough) {
      /* Degenerate rough geometry cannot be repaired by features. */
      GST_ELEMENT_ERROR(self, STREAM, FAILED, ("Calibration failed: %s", e.what()), (NULL));
      return FALSE;
    }
    st->failed_attempts++;
    if (st->failed_attempts >= MAX_FIRST_ATTEMPTS) {
      GST_ELEMENT_ERROR(self, STREAM, FAILED,
                        ("Could not calibrate from the images after %d attempts: %s",
                         st->failed_attempts, e.what()),
                        (NULL));
      return FALSE;
    }
    GST_ELEMENT_WARNING(self, STREAM, FAILED,
                        ("Calibration attempt %d failed (%s); dropping frames and retrying",
                         st->failed_attempts, e.what()),
                        (NULL));
    return TRUE;
  }
}

static void start_worker(GstStitchCalib* self, std::shared_ptr<std::vector<FrameSet>> sets) {
  CalibState* st = self->state;
  st->join();
  std::vector<std::vector<stitch::ImageView>> frames;
  for (const auto& set : *sets) frames.push_back(set.views);
  CalibSettings settings = st->settings;
  std::optional<stitch::Rig> rough = st->rough;
  std::shared_ptr<const stitch::Rig> previous = st->current;
  /* The first pooled refinement starts again from the rough rig or from the images. */
  if (st->pooling) previous.reset();
  st->finished_label = st->pooling ? "pooled" : "recalibration";
  st->worker_busy = true;
  st->worker = std::thread([st, sets, frames, settings, rough, previous]() {
    std::optional<stitch::CalibrationResult> result;
    std::string error;
    try {
      result = run_calibration(settings, rough, previous, frames);
    } catch (const std::exception& e) {
      error = e.what();
    }
    std::lock_guard<std::mutex> guard(st->lock);
    st->finished = std::move(result);
    st->worker_error = error;
    st->worker_busy = false;
  });
}

/* A bundle dropped because there is no calibration yet: announced with a QoS message. */
static GstFlowReturn drop_with_qos(GstStitchCalib* self, GstBuffer* buf) {
  GstBaseTransform* trans = GST_BASE_TRANSFORM(self);
  const GstClockTime pts = GST_BUFFER_PTS(buf);
  GstClockTime running_time = GST_CLOCK_TIME_NONE, stream_time = GST_CLOCK_TIME_NONE;
  if (trans->segment.format == GST_FORMAT_TIME && GST_CLOCK_TIME_IS_VALID(pts)) {
    running_time = gst_segment_to_running_time(&trans->segment, GST_FORMAT_TIME, pts);
    stream_time = gst_segment_to_stream_time(&trans->segment, GST_FORMAT_TIME, pts);
  }
  GstMessage* qos = gst_message_new_qos(GST_OBJECT(self), FALSE, running_time, stream_time, pts,
                                        GST_BUFFER_DURATION(buf));
  gst_message_set_qos_stats(qos, GST_FORMAT_BUFFERS, self->state->passed, ++self->state->dropped);
  gst_element_post_message(GST_ELEMENT(self), qos);
  return GST_BASE_TRANSFORM_FLOW_DROPPED;
}

static GstFlowReturn gst_stitch_calib_transform_ip(GstBaseTransform* trans, GstBuffer* buf) {
  GstStitchCalib* self = GST_STITCH_CALIB(trans);
  CalibState* st = self->state;
  GstCaps* caps = gst_pad_get_current_caps(GST_BASE_TRANSFORM_SINK_PAD(trans));
  const guint n_views = stitch_bundle_caps_views(caps);
  if (caps) gst_caps_unref(caps);

  std::vector<std::array<int, 2>> sizes;
  std::string error;
  if (!stitch_bundle_view_sizes(buf, n_views, sizes, error)) {
    GST_ELEMENT_ERROR(self, STREAM, FORMAT, ("Bad bundle: %s", error.c_str()), (NULL));
    return GST_FLOW_ERROR;
  }
  if (!handle_resize(self, sizes)) return GST_FLOW_ERROR;
  const GstStitchBundleMeta* bundle = gst_buffer_get_stitch_bundle_meta(buf);
  const guint64 missing = bundle ? bundle->missing_mask : 0;
  for (guint i = 0; i < n_views; ++i) {
    if ((missing >> i & 1) && !st->current) {
      /* a camera has not delivered yet: wait, calibrating on black would fail */
      GST_DEBUG_OBJECT(self, "view %u missing; waiting before calibrating", i);
      return drop_with_qos(self, buf);
    }
  }
  /* Pixels are read only on the frames that calibrate (rarely): CUDA-memory views then come
   * to the host through gst-cuda for that frame only; every other bundle passes untouched. */
  StitchBundleMapping mapping;
  bool mapped = false;
  auto frames = [&]() -> const std::vector<stitch::ImageView>& {
    if (!mapped && !mapping.map(buf, n_views, GST_MAP_READ, error)) throw std::runtime_error("bad bundle: " + error);
    mapped = true;
    return mapping.views();
  };

  std::unique_lock<std::mutex> guard(st->lock);
  gboolean ok = TRUE;
  const gboolean guarded = stitch_guard(GST_ELEMENT(self), "stitchcalib", [&]() {
    if (!st->current) {
      if (st->failed_attempts > 0 && ++st->frames_since_attempt < FRAMES_BETWEEN_ATTEMPTS) return;
      st->frames_since_attempt = 0;
      static const std::vector<stitch::ImageView> no_frames;  // a saved calibration needs no pixels
      ok = calibrate_now(self, st->settings.load_file.empty() ? frames() : no_frames, sizes);
      st->last_calibration_pts = GST_BUFFER_PTS(buf);
      if (ok && st->current) st->sizes = sizes;
      if (ok && st->current && st->settings.load_file.empty() && st->settings.calibration_frames > 1) {
        st->pooling = true;
        st->frames_seen = 0;
        st->pool.push_back(clone_views(frames()));
      }
      return;
    }
    if (st->pooling && !st->worker_busy) {
      if (++st->frames_seen % POOL_SPACING_FRAMES == 0)
        st->pool.push_back(clone_views(frames()));
      if (int(st->pool.size()) >= st->settings.calibration_frames) {
        auto sets = std::make_shared<std::vector<FrameSet>>(std::move(st->pool));
        st->pool.clear();
        start_worker(self, sets);
        st->pooling = false;
        return;
      }
    }
    if (st->finished || !st->worker_error.empty()) {
      st->join();
      if (st->finished) {
        install(self, *st->finished, st->finished_label.c_str());
      } else {
        GST_ELEMENT_WARNING(self, STREAM, FAILED,
                            ("Recalibration failed (%s); keeping the last good calibration",
                             st->worker_error.c_str()),
                            (NULL));
      }
      st->finished.reset();
      st->worker_error.clear();
    }
    bool due = st->recalibrate_requested.exchange(false);
    const GstClockTime pts = GST_BUFFER_PTS(buf);
    if (st->settings.interval_s > 0 && GST_CLOCK_TIME_IS_VALID(pts) &&
        GST_CLOCK_TIME_IS_VALID(st->last_calibration_pts) &&
        pts >= st->last_calibration_pts + GstClockTime(st->settings.interval_s * GST_SECOND))
      due = true;
    if (due && !st->worker_busy && st->settings.load_file.empty()) {
      st->last_calibration_pts = pts;
      auto sets = std::make_shared<std::vector<FrameSet>>();
      sets->push_back(clone_views(frames()));
      start_worker(self, sets);
    }
  });
  if (!guarded || !ok) return GST_FLOW_ERROR;
  if (!st->current) {
    guard.unlock();  // posting may call back into the element
    return drop_with_qos(self, buf);
  }
  gst_buffer_add_stitch_rig_meta(buf, st->current, st->version);
  st->passed++;
  return GST_FLOW_OK;
}

static gboolean gst_stitch_calib_start(GstBaseTransform* trans) {
  GstStitchCalib* self = GST_STITCH_CALIB(trans);
  std::lock_guard<std::mutex> guard(self->state->lock);
  self->state->reset();
  return TRUE;
}

static gboolean gst_stitch_calib_stop(GstBaseTransform* trans) {
  GstStitchCalib* self = GST_STITCH_CALIB(trans);
  self->state->join();
  std::lock_guard<std::mutex> guard(self->state->lock);
  self->state->reset();
  return TRUE;
}

static gboolean gst_stitch_calib_set_caps(GstBaseTransform* trans, GstCaps* incaps, GstCaps*) {
  GstStitchCalib* self = GST_STITCH_CALIB(trans);
  if (!stitch_bundle_accept_caps(GST_ELEMENT(self), incaps)) return FALSE;
  return !stitch_caps_are_cuda_memory(incaps) || self->state->cuda.ensure(GST_ELEMENT(self));
}

static GstCaps* gst_stitch_calib_transform_caps(GstBaseTransform*, GstPadDirection, GstCaps* caps, GstCaps* filter) {
  /* In place, both sides in the same memory. CUDA memory whatever the backend: the bundles
   * pass untouched and feature matching runs on the CPU in every mode. */
  return stitch_caps_same_memory(caps, filter, stitch_cuda_memory_possible());
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
  std::lock_guard<std::mutex> guard(self->state->lock);
  CalibSettings& s = self->state->settings;
  switch (prop_id) {
    case PROP_RIG_FILE: set_string(s.rig_file, value); self->state->rough.reset(); break;
    case PROP_LOAD_FILE: set_string(s.load_file, value); break;
    case PROP_SAVE_FILE: set_string(s.save_file, value); break;
    case PROP_REFINE: s.options.refinement = stitch::Refinement(g_value_get_enum(value)); break;
    case PROP_FEATURES: s.options.features = stitch::FeatureType(g_value_get_enum(value)); break;
    case PROP_RECALIBRATE_INTERVAL: s.interval_s = g_value_get_double(value); break;
    case PROP_MIN_INLIERS: s.options.min_inliers = g_value_get_int(value); break;
    case PROP_OVERLAP_MARGIN: s.options.overlap_margin = g_value_get_double(value); break;
    case PROP_REFERENCE: s.reference = g_value_get_int(value); break;
    case PROP_CALIBRATION_FRAMES: s.calibration_frames = g_value_get_int(value); break;
    case PROP_BACKEND: s.backend = stitch::Backend(g_value_get_enum(value)); break;
    case PROP_ON_RESIZE: s.on_resize = OnResize(g_value_get_enum(value)); break;
    case PROP_PROJECTION: s.projection = stitch::Projection(g_value_get_enum(value)); break;
    case PROP_BUNDLE_ADJUST: s.options.bundle_adjust = g_value_get_boolean(value); break;
    case PROP_WAVE_CORRECT: s.options.wave_correct = g_value_get_boolean(value); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_calib_get_property(GObject* object, guint prop_id, GValue* value,
                                          GParamSpec* pspec) {
  GstStitchCalib* self = GST_STITCH_CALIB(object);
  std::lock_guard<std::mutex> guard(self->state->lock);
  const CalibSettings& s = self->state->settings;
  switch (prop_id) {
    case PROP_RIG_FILE: g_value_set_string(value, s.rig_file.empty() ? NULL : s.rig_file.c_str()); break;
    case PROP_LOAD_FILE: g_value_set_string(value, s.load_file.empty() ? NULL : s.load_file.c_str()); break;
    case PROP_SAVE_FILE: g_value_set_string(value, s.save_file.empty() ? NULL : s.save_file.c_str()); break;
    case PROP_REFINE: g_value_set_enum(value, int(s.options.refinement)); break;
    case PROP_FEATURES: g_value_set_enum(value, int(s.options.features)); break;
    case PROP_RECALIBRATE_INTERVAL: g_value_set_double(value, s.interval_s); break;
    case PROP_MIN_INLIERS: g_value_set_int(value, s.options.min_inliers); break;
    case PROP_OVERLAP_MARGIN: g_value_set_double(value, s.options.overlap_margin); break;
    case PROP_REFERENCE: g_value_set_int(value, s.reference); break;
    case PROP_CALIBRATION_FRAMES: g_value_set_int(value, s.calibration_frames); break;
    case PROP_BACKEND: g_value_set_enum(value, int(s.backend)); break;
    case PROP_ON_RESIZE: g_value_set_enum(value, int(s.on_resize)); break;
    case PROP_PROJECTION: g_value_set_enum(value, int(s.projection.value_or(stitch::Projection::Plane))); break;
    case PROP_BUNDLE_ADJUST: g_value_set_boolean(value, s.options.bundle_adjust); break;
    case PROP_WAVE_CORRECT: g_value_set_boolean(value, s.options.wave_correct); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_calib_finalize(GObject* object) {
  GstStitchCalib* self = GST_STITCH_CALIB(object);
  self->state->join();
  delete self->state;
  G_OBJECT_CLASS(gst_stitch_calib_parent_class)->finalize(object);
}

static void gst_stitch_calib_class_init(GstStitchCalibClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  GstBaseTransformClass* trans_class = GST_BASE_TRANSFORM_CLASS(klass);
  const GParamFlags rw = GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS);

  gobject_class->set_property = gst_stitch_calib_set_property;
  gobject_class->get_property = gst_stitch_calib_get_property;
  gobject_class->finalize = gst_stitch_calib_finalize;

  g_object_class_install_property(gobject_class, PROP_RIG_FILE,
      g_param_spec_string("rig-file", "Rig file", "Rough camera parameters (stitch-rig JSON)", NULL, rw));
  g_object_class_install_property(gobject_class, PROP_LOAD_FILE,
      g_param_spec_string("load-file", "Load file", "Saved calibration to use as is (no estimation)", NULL, rw));
  g_object_class_install_property(gobject_class, PROP_SAVE_FILE,
      g_param_spec_string("save-file", "Save file", "Write the calibration here whenever it changes", NULL, rw));
  g_object_class_install_property(gobject_class, PROP_REFINE,
      g_param_spec_enum("refine", "Refine", "How features refine the rough homographies",
                        refine_get_type(), int(DEFAULT_REFINE), rw));
  g_object_class_install_property(gobject_class, PROP_FEATURES,
      g_param_spec_enum("features", "Features", "Feature detector for matching",
                        features_get_type(), int(DEFAULT_FEATURES), rw));
  g_object_class_install_property(gobject_class, PROP_RECALIBRATE_INTERVAL,
      g_param_spec_double("recalibrate-interval", "Recalibrate interval",
                          "Recalibrate every this many seconds of stream time (0 = only at start "
                          "and on request)", 0, G_MAXDOUBLE, DEFAULT_INTERVAL, rw));
  g_object_class_install_property(gobject_class, PROP_MIN_INLIERS,
      g_param_spec_int("min-inliers", "Minimum inliers",
                       "Fewer RANSAC inliers keep the previous homography of that camera", 4,
                       100000, DEFAULT_MIN_INLIERS, rw));
  g_object_class_install_property(gobject_class, PROP_OVERLAP_MARGIN,
      g_param_spec_double("overlap-margin", "Overlap margin",
                          "Widen each overlap by this fraction of the view width before matching",
                          0, 2, DEFAULT_OVERLAP_MARGIN, rw));
  g_object_class_install_property(gobject_class, PROP_REFERENCE,
      g_param_spec_int("reference", "Reference camera",
                       "Camera whose image plane is the canvas (-1: the rig's, or the middle one)",
                       -1, STITCH_MAX_VIEWS - 1, DEFAULT_REFERENCE, rw));
  g_object_class_install_property(gobject_class, PROP_CALIBRATION_FRAMES,
      g_param_spec_int("calibration-frames", "Calibration frames",
                       "Pool the matches of this many of the first frames (every 5th) into a "
                       "refined calibration that replaces the first-frame one (1 = first frame only)",
                       1, 100, DEFAULT_CALIBRATION_FRAMES, rw));
  g_object_class_install_property(gobject_class, PROP_BACKEND,
      g_param_spec_enum("backend", "Backend",
                        "Feature matching runs on the CPU in every mode (it runs rarely)",
                        GST_TYPE_STITCH_BACKEND, int(stitch::Backend::Auto), rw));
  g_object_class_install_property(gobject_class, PROP_ON_RESIZE,
      g_param_spec_enum("on-resize", "On resize",
                        "An input that changes resolution mid-stream: calibrate again for the new "
                        "sizes (with a warning), or stop with an error",
                        on_resize_get_type(), ON_RESIZE_RECALIBRATE, rw));
  g_object_class_install_property(gobject_class, PROP_PROJECTION,
      g_param_spec_enum("projection", "Projection",
                        "Canvas projection (unset: the rig-file's \"projection\"); cylindrical and "
                        "spherical need a rig-file and may wrap around 360 degrees",
                        projection_get_type(), int(stitch::Projection::Plane), rw));
  g_object_class_install_property(gobject_class, PROP_BUNDLE_ADJUST,
      g_param_spec_boolean("bundle-adjust", "Bundle adjust",
                           "Planar rigs: refine all rotations and focal lengths jointly on every "
                           "pair's matches instead of chaining pairwise corrections (needs a "
                           "rig-file; non-planar rigs always do)", FALSE, rw));
  g_object_class_install_property(gobject_class, PROP_WAVE_CORRECT,
      g_param_spec_boolean("wave-correct", "Wave correct",
                           "Non-planar rigs: level the horizon after the bundle adjustment", TRUE, rw));

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
  element_class->set_context = GST_DEBUG_FUNCPTR(gst_stitch_calib_set_context);
  trans_class->passthrough_on_same_caps = FALSE;

  gst_type_mark_as_plugin_api(refine_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(features_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(on_resize_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(projection_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(GST_TYPE_STITCH_BACKEND, GstPluginAPIFlags(0));
  GST_DEBUG_CATEGORY_INIT(gst_stitch_calib_debug, "stitchcalib", 0, "stitch calibration");
}

static void gst_stitch_calib_init(GstStitchCalib* self) {
  self->state = new CalibState();
  self->state->settings.options.refinement = DEFAULT_REFINE;
  self->state->settings.options.features = DEFAULT_FEATURES;
  self->state->settings.options.min_inliers = DEFAULT_MIN_INLIERS;
  self->state->settings.options.overlap_margin = DEFAULT_OVERLAP_MARGIN;
  gst_base_transform_set_in_place(GST_BASE_TRANSFORM(self), TRUE);
}
