/**
 * SECTION:element-stitchcolor
 * @title: stitchcolor
 *
 * Spatio-temporal color correction of a calibrated stitch bundle, in place (paper §2). Each
 * view is corrected toward the reference camera, chaining adjacent overlaps outward from it,
 * and the correction is applied to the whole view so no edge appears where the overlap ends.
 *
 * - `method=3dm`: the paper's 3D-M color transfer: a 3x3 matrix fitted by least squares over
 *   the overlaps of the current and the previous `window - 1` frames (eq. 2-4);
 * - `method=2dm`: Tian's 2D-M, the same over the current frame only (the baseline);
 * - `method=gain`: Brown-Lowe per-channel gains solved jointly over all overlaps, smoothed
 *   over `window` frames;
 * - `pairing=histogram` fits against view i's overlap histogram-specified to the reference's
 *   (paper Step 3, robust to misalignment); `pairing=pixels` against the co-located pixels;
 * - `balance=true` adds the online piecewise balancing (eq. 5-7) with thresholds at `lambda`;
 * - `smoothing` (beyond the paper) moves each correction only part of the way to the new
 *   estimate per frame, so estimation noise does not flicker; `smoothing=0` is the paper.
 *
 * Robust and still (issue 16, defaults on): `static-mask` fits only overlap samples that
 * have not moved for a while (a per-sample difference against the previous frame, held for
 * ten frames) and whose two views' luma gradients agree; the colour stage runs before
 * stitchflowwarp, so it computes this cheap mask itself at its sample positions.
 * `stabilize` holds each applied correction until the estimate stays more than `hold` grey
 * levels away for `keyframe-interval` frames, then moves it to the new keyframe at `max-rate`
 * levels per frame; a step that every view shows at once (`step-threshold`, or a cut) is
 * followed on the same frame. Above `highlight-knee` the correction fades out, so clipped
 * highlights stay white and still.
 *
 * The default, `method=3dm smoothing=0.8`, was chosen by measurement on two real clip sets
 * (BENCHMARKS.md): best or tied overlap PSNR on both, the lowest flicker on the 3-camera set;
 * `gain` costs half as much and is within 0.25 dB.
 *
 * Saturated and black pixels are left out of every fit; ill-conditioned fits are regularised
 * toward the identity; a sudden change moves the correction by a bounded step per frame;
 * overlaps with too few valid pixels keep the last correction. History resets on flush, seek
 * and caps change.
 *
 * Bundles in CUDA memory (stitchsync with a GPU) are corrected in place on the GPU (sample
 * gather and 3x3 + LUT kernels in the shared CUDA context; `backend=cpu` keeps the chain in
 * system memory).
 *
 * ## Example launch lines
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib ! stitchcolor method=3dm ! stitchblend ! \
 *   videoconvert ! autovideosink \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * |[
 * gst-launch-1.0 -e stitchsync name=s ! stitchcalib ! stitchcolor method=gain balance=true ! \
 *   stitchblend ! videoconvert ! x264enc ! mp4mux ! filesink location=pano.mp4 \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * With a GPU (the bundles stay in CUDA memory):
 * |[
 * gst-launch-1.0 -e stitchsync name=s ! stitchcalib ! stitchcolor ! stitchblend ! cudadownload ! \
 *   videoconvert ! x264enc ! mp4mux ! filesink location=pano.mp4 \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_1
 * ]|
 */
#include "gststitchcolor.h"

#include <gst/video/video.h>

#include <mutex>

#include "gststitchbundle.h"
#include "gststitchcuda.h"
#include "stitch/color/color.hpp"

GST_DEBUG_CATEGORY_STATIC(gst_stitch_color_debug);
#define GST_CAT_DEFAULT gst_stitch_color_debug

enum {
  PROP_0,
  PROP_METHOD,
  PROP_PAIRING,
  PROP_WINDOW,
  PROP_BALANCE,
  PROP_LAMBDA,
  PROP_SMOOTHING,
  PROP_BACKEND,
  PROP_STATIC_MASK,
  PROP_MOTION_THRESHOLD,
  PROP_STABILIZE,
  PROP_HOLD,
  PROP_KEYFRAME_INTERVAL,
  PROP_MAX_RATE,
  PROP_STEP_THRESHOLD,
  PROP_HIGHLIGHT_KNEE,
};

#define DEFAULT_METHOD stitch::ColorMethod::Matrix3D
#define DEFAULT_PAIRING stitch::ColorPairing::Histogram
#define DEFAULT_WINDOW 3
#define DEFAULT_BALANCE FALSE
#define DEFAULT_LAMBDA 0.05
#define DEFAULT_SMOOTHING 0.8

struct ColorElementState {
  std::mutex lock;  // guards settings
  stitch::ColorOptions options;
  stitch::Backend backend = stitch::Backend::Auto;
  bool reset_requested = false;
  /* streaming thread only */
  StitchCudaOwned<stitch::ColorCorrector> corrector;
  stitch::Backend corrector_backend = stitch::Backend::Auto;
  bool cuda_memory = false;  /* negotiated bundles in CUDA memory */
  StitchCudaContext cuda;
};

struct _GstStitchColor {
  GstBaseTransform parent;
  ColorElementState* state;
};

G_DEFINE_TYPE(GstStitchColor, gst_stitch_color, GST_TYPE_BASE_TRANSFORM);
GST_ELEMENT_REGISTER_DEFINE(stitchcolor, "stitchcolor", GST_RANK_NONE, GST_TYPE_STITCH_COLOR);

static GType method_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::ColorMethod::None), "No color transfer", "none"},
      {int(stitch::ColorMethod::Matrix2D), "2D-M (Tian): 3x3 matrix on the current frame", "2dm"},
      {int(stitch::ColorMethod::Matrix3D), "3D-M: 3x3 matrix over a window of frames", "3dm"},
      {int(stitch::ColorMethod::Gain), "Brown-Lowe per-channel gains over all overlaps", "gain"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchColorMethod", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GType pairing_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::ColorPairing::Histogram), "Histogram-specified overlap (paper Step 3)", "histogram"},
      {int(stitch::ColorPairing::Pixels), "Co-located overlap pixels", "pixels"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchColorPairing", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GstStaticPadTemplate sink_template = GST_STATIC_PAD_TEMPLATE(
    "sink", GST_PAD_SINK, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));
static GstStaticPadTemplate src_template = GST_STATIC_PAD_TEMPLATE(
    "src", GST_PAD_SRC, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));

static void request_reset(GstStitchColor* self) {
  std::lock_guard<std::mutex> guard(self->state->lock);
  self->state->reset_requested = true;
}

static GstFlowReturn gst_stitch_color_transform_ip(GstBaseTransform* trans, GstBuffer* buf) {
  GstStitchColor* self = GST_STITCH_COLOR(trans);
  ColorElementState* st = self->state;
  GstStitchRigMeta* meta = stitch_bundle_require_rig(GST_ELEMENT(self), buf);
  if (!meta || !stitch_bundle_require_camera_views(GST_ELEMENT(self), buf)) return GST_FLOW_ERROR;
  stitch::ColorOptions options;
  stitch::Backend backend;
  bool reset;
  {
    std::lock_guard<std::mutex> guard(st->lock);
    options = st->options;
    backend = st->backend;
    reset = st->reset_requested;
    st->reset_requested = false;
  }
  const stitch::Rig& rig = **meta->rig;
  /* CUDA-memory views are corrected where they lie, by the CUDA ColorOps. */
  const stitch::Backend effective = backend != stitch::Backend::Cpu && st->cuda_memory ? stitch::Backend::Cuda : backend;
  StitchCudaHandoff handoff(st->cuda);  /* stream-ordered: no host synchronisation before the push */
  StitchBundleMapping mapping;
  std::string error;
  if (!mapping.map(buf, guint(rig.cameras.size()), GstMapFlags(GST_MAP_READ | GST_MAP_WRITE), error,
                   effective == stitch::Backend::Cuda ? &st->cuda : nullptr)) {
    GST_ELEMENT_ERROR(self, STREAM, FORMAT, ("Bad bundle: %s", error.c_str()), (NULL));
    return GST_FLOW_ERROR;
  }
  const gboolean ok = stitch_guard(GST_ELEMENT(self), "stitchcolor", [&]() {
    if (!st->corrector.made_with(st->cuda) || st->corrector_backend != effective) {
      st->corrector.make(st->cuda, [&]() { return std::make_unique<stitch::ColorCorrector>(effective); });
      st->corrector_backend = effective;
    }
    st->corrector.run([&](stitch::ColorCorrector& c) {
      c.set_options(options);
      if (reset) c.reset();
      c.process(rig, meta->version, mapping.views());
    });
  });
  if (!ok || !handoff.finish(GST_ELEMENT(self), buf, GST_BASE_TRANSFORM_SRC_PAD(trans))) return GST_FLOW_ERROR;
  return GST_FLOW_OK;
}

static bool offer_cuda(GstStitchColor* self) {
  std::lock_guard<std::mutex> guard(self->state->lock);
  return stitch_cuda_memory_offered(self->state->backend);
}

static GstCaps* gst_stitch_color_transform_caps(GstBaseTransform* trans, GstPadDirection, GstCaps* caps, GstCaps* filter) {
  /* in place: both sides in the same memory */
  return stitch_caps_same_memory(caps, filter, offer_cuda(GST_STITCH_COLOR(trans)));
}

static void gst_stitch_color_set_context(GstElement* element, GstContext* context) {
  GST_STITCH_COLOR(element)->state->cuda.set_context(element, context);
  GST_ELEMENT_CLASS(gst_stitch_color_parent_class)->set_context(element, context);
}

static gboolean gst_stitch_color_query(GstBaseTransform* trans, GstPadDirection direction, GstQuery* query) {
  if (GST_STITCH_COLOR(trans)->state->cuda.handle_query(GST_ELEMENT(trans), query)) return TRUE;
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_color_parent_class)->query(trans, direction, query);
}

static gboolean gst_stitch_color_sink_event(GstBaseTransform* trans, GstEvent* event) {
  GstStitchColor* self = GST_STITCH_COLOR(trans);
  switch (GST_EVENT_TYPE(event)) {
    case GST_EVENT_FLUSH_STOP:
    case GST_EVENT_SEGMENT:  /* a seek or a new stream: the history no longer applies */
      request_reset(self);
      break;
    default: break;
  }
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_color_parent_class)->sink_event(trans, event);
}

static gboolean gst_stitch_color_set_caps(GstBaseTransform* trans, GstCaps* incaps, GstCaps*) {
  GstStitchColor* self = GST_STITCH_COLOR(trans);
  ColorElementState* st = self->state;
  if (!stitch_bundle_accept_caps(GST_ELEMENT(self), incaps)) return FALSE;
  st->cuda_memory = stitch_caps_are_cuda_memory(incaps);
  if (st->cuda_memory && !st->cuda.ensure(GST_ELEMENT(self))) return FALSE;
  request_reset(self);
  return TRUE;
}

static gboolean gst_stitch_color_stop(GstBaseTransform* trans) {
  GST_STITCH_COLOR(trans)->state->corrector.reset();
  return TRUE;
}

static void gst_stitch_color_set_property(GObject* object, guint prop_id, const GValue* value,
                                          GParamSpec* pspec) {
  GstStitchColor* self = GST_STITCH_COLOR(object);
  std::lock_guard<std::mutex> guard(self->state->lock);
  stitch::ColorOptions& o = self->state->options;
  switch (prop_id) {
    case PROP_METHOD: o.method = stitch::ColorMethod(g_value_get_enum(value)); break;
    case PROP_PAIRING: o.pairing = stitch::ColorPairing(g_value_get_enum(value)); break;
    case PROP_WINDOW: o.window = g_value_get_int(value); break;
    case PROP_BALANCE: o.balance = g_value_get_boolean(value); break;
    case PROP_LAMBDA: o.lambda = g_value_get_double(value); break;
    case PROP_SMOOTHING: o.follow = 1.0 - g_value_get_double(value); break;
    case PROP_BACKEND: self->state->backend = stitch::Backend(g_value_get_enum(value)); break;
    case PROP_STATIC_MASK: o.static_mask = g_value_get_boolean(value); break;
    case PROP_MOTION_THRESHOLD: o.motion_threshold = g_value_get_int(value); break;
    case PROP_STABILIZE: o.stabilize = g_value_get_boolean(value); break;
    case PROP_HOLD: o.hold = g_value_get_double(value); break;
    case PROP_KEYFRAME_INTERVAL: o.keyframe = g_value_get_int(value); break;
    case PROP_MAX_RATE: o.max_rate = g_value_get_double(value); break;
    case PROP_STEP_THRESHOLD: o.step_threshold = g_value_get_double(value); break;
    case PROP_HIGHLIGHT_KNEE: o.highlight_knee = g_value_get_int(value); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_color_get_property(GObject* object, guint prop_id, GValue* value,
                                          GParamSpec* pspec) {
  GstStitchColor* self = GST_STITCH_COLOR(object);
  std::lock_guard<std::mutex> guard(self->state->lock);
  const stitch::ColorOptions& o = self->state->options;
  switch (prop_id) {
    case PROP_METHOD: g_value_set_enum(value, int(o.method)); break;
    case PROP_PAIRING: g_value_set_enum(value, int(o.pairing)); break;
    case PROP_WINDOW: g_value_set_int(value, o.window); break;
    case PROP_BALANCE: g_value_set_boolean(value, o.balance); break;
    case PROP_LAMBDA: g_value_set_double(value, o.lambda); break;
    case PROP_SMOOTHING: g_value_set_double(value, 1.0 - o.follow); break;
    case PROP_BACKEND: g_value_set_enum(value, int(self->state->backend)); break;
    case PROP_STATIC_MASK: g_value_set_boolean(value, o.static_mask); break;
    case PROP_MOTION_THRESHOLD: g_value_set_int(value, o.motion_threshold); break;
    case PROP_STABILIZE: g_value_set_boolean(value, o.stabilize); break;
    case PROP_HOLD: g_value_set_double(value, o.hold); break;
    case PROP_KEYFRAME_INTERVAL: g_value_set_int(value, o.keyframe); break;
    case PROP_MAX_RATE: g_value_set_double(value, o.max_rate); break;
    case PROP_STEP_THRESHOLD: g_value_set_double(value, o.step_threshold); break;
    case PROP_HIGHLIGHT_KNEE: g_value_set_int(value, o.highlight_knee); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_color_finalize(GObject* object) {
  delete GST_STITCH_COLOR(object)->state;
  G_OBJECT_CLASS(gst_stitch_color_parent_class)->finalize(object);
}

static void gst_stitch_color_class_init(GstStitchColorClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  GstBaseTransformClass* trans_class = GST_BASE_TRANSFORM_CLASS(klass);
  const GParamFlags rw = GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS);
  /* read on every bundle: may change while playing; the numbers may follow a GstControlSource */
  const GParamFlags per_frame = GParamFlags(rw | GST_PARAM_MUTABLE_PLAYING);
  const GParamFlags controllable = GParamFlags(per_frame | GST_PARAM_CONTROLLABLE);

  gobject_class->set_property = gst_stitch_color_set_property;
  gobject_class->get_property = gst_stitch_color_get_property;
  gobject_class->finalize = gst_stitch_color_finalize;

  g_object_class_install_property(gobject_class, PROP_METHOD,
      g_param_spec_enum("method", "Method", "Color transfer between the views", method_get_type(),
                        int(DEFAULT_METHOD), per_frame));
  g_object_class_install_property(gobject_class, PROP_PAIRING,
      g_param_spec_enum("pairing", "Pairing", "What the 2dm/3dm transfer is fitted against",
                        pairing_get_type(), int(DEFAULT_PAIRING), per_frame));
  g_object_class_install_property(gobject_class, PROP_WINDOW,
      g_param_spec_int("window", "Window", "Frames in the 3D-M fit and in the gain smoothing", 1, 30,
                       DEFAULT_WINDOW, controllable));
  g_object_class_install_property(gobject_class, PROP_BALANCE,
      g_param_spec_boolean("balance", "Balance", "Online piecewise color balancing (paper eq. 5-7)",
                           DEFAULT_BALANCE, per_frame));
  g_object_class_install_property(gobject_class, PROP_LAMBDA,
      g_param_spec_double("lambda", "Lambda", "Balance thresholds at lambda and 1 - lambda of the histogram",
                          0.0, 0.45, DEFAULT_LAMBDA, controllable));
  g_object_class_install_property(gobject_class, PROP_SMOOTHING,
      g_param_spec_double("smoothing", "Smoothing",
                          "Temporal smoothing of the corrections: each frame moves (1 - smoothing) of "
                          "the way to the new estimate (0 = the paper)", 0.0, 0.98, DEFAULT_SMOOTHING, controllable));
  g_object_class_install_property(gobject_class, PROP_BACKEND,
      g_param_spec_enum("backend", "Backend",
                        "Where the per-frame color work runs: auto: on the GPU when a CUDA device opens, else on "
                        "the CPU; cpu: on the CPU (CUDA-memory bundles are mapped through host "
                        "memory); cuda: on the GPU, or an error when no device opens",
                        GST_TYPE_STITCH_BACKEND, int(stitch::Backend::Auto), GParamFlags(rw | GST_PARAM_MUTABLE_READY)));
  /* Issue 16: statistics from static, well-aligned pixels, and a correction held over time. */
  const stitch::ColorOptions defaults;
  g_object_class_install_property(gobject_class, PROP_STATIC_MASK,
      g_param_spec_boolean("static-mask", "Static mask",
                           "Fit only overlap samples that have not moved for a while and whose two views' "
                           "gradients agree (people crossing an overlap and parallax leave the statistics)",
                           defaults.static_mask, per_frame));
  g_object_class_install_property(gobject_class, PROP_MOTION_THRESHOLD,
      g_param_spec_int("motion-threshold", "Motion threshold",
                       "A sample whose colour changed by more than this (levels, any channel) since the last "
                       "frame is moving (static-mask)", 1, 255, defaults.motion_threshold, controllable));
  g_object_class_install_property(gobject_class, PROP_STABILIZE,
      g_param_spec_boolean("stabilize", "Stabilize",
                           "Hold each applied correction still; move it (to a keyframe, at max-rate) only when the "
                           "estimate stays beyond hold for keyframe-interval frames; jump on a global "
                           "illumination step or cut; follow at once when one camera's exposure steps",
                           defaults.stabilize, per_frame));
  g_object_class_install_property(gobject_class, PROP_HOLD,
      g_param_spec_double("hold", "Hold", "Grey levels the estimate may differ from the applied correction "
                          "before it counts as a change (stabilize)", 0.0, 64.0, defaults.hold, controllable));
  g_object_class_install_property(gobject_class, PROP_KEYFRAME_INTERVAL,
      g_param_spec_int("keyframe-interval", "Keyframe interval",
                       "Frames a change beyond hold must last before a new keyframe (stabilize)", 1, 300,
                       defaults.keyframe, controllable));
  g_object_class_install_property(gobject_class, PROP_MAX_RATE,
      g_param_spec_double("max-rate", "Max rate", "Grey levels per frame the applied correction moves toward a "
                          "new keyframe (stabilize)", 0.01, 255.0, defaults.max_rate, controllable));
  g_object_class_install_property(gobject_class, PROP_STEP_THRESHOLD,
      g_param_spec_double("step-threshold", "Step threshold",
                          "Relative brightness change between two frames that every view must show for a global "
                          "illumination step (the corrections are re-estimated from that frame at once)",
                          0.01, 10.0, defaults.step_threshold, controllable));
  g_object_class_install_property(gobject_class, PROP_HIGHLIGHT_KNEE,
      g_param_spec_int("highlight-knee", "Highlight knee",
                       "Pixels whose brightest channel is above this level keep a growing share of their input "
                       "(all of it at 255): clipped highlights stay white and do not follow the correction "
                       "(255: off)", 0, 255, defaults.highlight_knee, controllable));

  gst_element_class_add_static_pad_template(element_class, &sink_template);
  gst_element_class_add_static_pad_template(element_class, &src_template);
  gst_element_class_set_static_metadata(element_class, "Stitch color correction", "Filter/Effect/Video",
      "Spatio-temporal color correction of stitch bundles: 3D-M / 2D-M color transfer or gain "
      "compensation on the overlaps, and online piecewise balancing",
      "gst-stitch developers");

  trans_class->transform_ip = GST_DEBUG_FUNCPTR(gst_stitch_color_transform_ip);
  trans_class->sink_event = GST_DEBUG_FUNCPTR(gst_stitch_color_sink_event);
  trans_class->set_caps = GST_DEBUG_FUNCPTR(gst_stitch_color_set_caps);
  trans_class->stop = GST_DEBUG_FUNCPTR(gst_stitch_color_stop);
  trans_class->transform_caps = GST_DEBUG_FUNCPTR(gst_stitch_color_transform_caps);
  trans_class->query = GST_DEBUG_FUNCPTR(gst_stitch_color_query);
  element_class->set_context = GST_DEBUG_FUNCPTR(gst_stitch_color_set_context);
  trans_class->passthrough_on_same_caps = FALSE;

  gst_type_mark_as_plugin_api(method_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(pairing_get_type(), GstPluginAPIFlags(0));
  GST_DEBUG_CATEGORY_INIT(gst_stitch_color_debug, "stitchcolor", 0, "stitch color correction");
}

static void gst_stitch_color_init(GstStitchColor* self) {
  self->state = new ColorElementState();
  self->state->options.method = DEFAULT_METHOD;
  self->state->options.pairing = DEFAULT_PAIRING;
  self->state->options.window = DEFAULT_WINDOW;
  self->state->options.balance = DEFAULT_BALANCE;
  self->state->options.lambda = DEFAULT_LAMBDA;
  self->state->options.follow = 1.0 - DEFAULT_SMOOTHING;
  gst_base_transform_set_in_place(GST_BASE_TRANSFORM(self), TRUE);
}
