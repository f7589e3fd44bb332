/**
 * SECTION:element-stitchflowwarp
 * @title: stitchflowwarp
 *
 * Coarse-to-fine frame warping (paper §3.2). Every view of a calibrated bundle is pre-warped
 * onto the canvas by its homography; then, in each overlap, bidirectional dense optical flow
 * (DIS) moves each view toward its neighbour by the other view's blend weight, so both meet
 * in between and stitchblend fuses them without the ghosting that parallax and near objects
 * cause. The displacement fades to zero where an overlap ends.
 *
 * Beyond the paper: each frame's flow starts from the previous frame's and is blended with it
 * where neither view changed (`temporal-smoothing`), so static scenes do not shimmer while
 * moving objects are followed at once; where the two flow directions disagree (occlusion, no
 * texture) the flow is scaled toward zero, i.e. back to the homography. History resets on
 * flush, seek and caps change.
 *
 * Never worse than the homography: per pixel the flow is used only where it makes the views
 * match better than the homography alone (so a background the homography aligns keeps it,
 * and no copy of a distant object appears beside a near one); per overlap the stage measures
 * the views' matching error (photometric + structural) with and without the flow every frame
 * and switches the flow off where it does not cut the error, on again where it does, with
 * hysteresis and a gain that ramps over a few frames. The decision travels with every buffer
 * (GstStitchFlowMeta, drawn by stitchblend's debug view) and, when it changes, as an element
 * message "stitch-flow-decision" (view-a, view-b, flow-on, gain, error-homography,
 * error-flow).
 *
 * The output is a bundle of the same caps whose views are the warped rectangles of the canvas
 * (a GstStitchWarpMeta says where each lies); stitchblend detects it and only fuses.
 * `flow=false` (the default) keeps the homography alone: the bundle passes through unwarped,
 * stitchblend composes the frames onto the canvas (one full-canvas pass fewer than pre-warping)
 * and its consensus blend (seam=dp) handles the parallax; flow=true turns the local warp on.
 *
 * Bundles in CUDA memory (stitchsync with a GPU) are warped on the GPU and the warped views
 * go out in CUDA memory, from a pool of bundles allocated once per canvas layout.
 *
 * ## Example launch lines
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib ! stitchcolor ! stitchflowwarp ! \
 *   stitchblend crop=auto ! videoconvert ! autovideosink \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * |[
 * gst-launch-1.0 -e stitchsync name=s ! stitchcalib ! stitchflowwarp quality=fine margin=32 \
 *   temporal-smoothing=0.7 ! stitchblend ! videoconvert ! x264enc ! mp4mux ! \
 *   filesink location=pano.mp4 \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * With a GPU, the whole chain in CUDA memory:
 * |[
 * gst-launch-1.0 -e stitchsync name=s ! stitchcalib ! stitchcolor ! stitchflowwarp ! \
 *   stitchblend crop=auto ! cudadownload ! videoconvert ! x264enc ! mp4mux ! filesink location=pano.mp4 \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_1
 * ]|
 */
#include "gststitchflowwarp.h"

#include <gst/video/video.h>

#include <array>
#include <mutex>
#include <vector>

#include "gststitchbundle.h"
#include "gststitchcuda.h"
#include "stitch/warp/flow_warper.hpp"

GST_DEBUG_CATEGORY_STATIC(gst_stitch_flow_warp_debug);
#define GST_CAT_DEFAULT gst_stitch_flow_warp_debug

enum {
  PROP_0,
  PROP_FLOW,
  PROP_QUALITY,
  PROP_ALGORITHM,
  PROP_MARGIN,
  PROP_TEMPORAL_SMOOTHING,
  PROP_BACKEND,
  PROP_FALLBACK
};

/* Off by default (issue 16, BENCHMARKS.md "Parallax: the consensus blend"): on the rendered
 * parallax rigs the flow spreads a near object's displacement into the background around it
 * (2-3 dB below the homography there) and ghosts more than stitchblend's consensus blend. */
#define DEFAULT_FLOW FALSE
#define DEFAULT_QUALITY stitch::FlowQuality::Medium
#define DEFAULT_ALGORITHM stitch::FlowAlgorithm::Dis
#define DEFAULT_MARGIN 16
#define DEFAULT_TEMPORAL_SMOOTHING 0.95
#define DEFAULT_FALLBACK TRUE

struct FlowWarpElementState {
  std::mutex lock;  // guards the settings
  stitch::FlowWarpSettings settings;
  stitch::Backend backend = stitch::Backend::Auto;
  bool reset_requested = false;
  /* streaming thread only */
  StitchCudaOwned<stitch::FlowWarper> warper;
  stitch::Backend warper_backend = stitch::Backend::Auto;  /* as asked for */
  guint64 rig_version = G_MAXUINT64;
  GstStitchWarpMeta layout{};  /* where each view lands; also the meta we attach */
  GstBufferPool* pool = nullptr;
  bool cuda_memory = false;  /* negotiated bundles in CUDA memory (both sides) */
  StitchCudaContext cuda;
  std::vector<std::array<int, 3>> decisions;  /* (view a, view b, flow on) last posted */
  void clear() {
    warper.reset();
    rig_version = G_MAXUINT64;
    stitch_bundle_pool_clear(&pool);
    decisions.clear();
  }
};

struct _GstStitchFlowWarp {
  GstBaseTransform parent;
  FlowWarpElementState* state;
};

G_DEFINE_TYPE(GstStitchFlowWarp, gst_stitch_flow_warp, GST_TYPE_BASE_TRANSFORM);
GST_ELEMENT_REGISTER_DEFINE(stitchflowwarp, "stitchflowwarp", GST_RANK_NONE, GST_TYPE_STITCH_FLOW_WARP);

static GType quality_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::FlowQuality::Fast), "Half-resolution flow, fewest iterations", "fast"},
      {int(stitch::FlowQuality::Medium), "Half-resolution flow", "medium"},
      {int(stitch::FlowQuality::Fine), "Full-resolution flow, most iterations", "fine"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchFlowQuality", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GType algorithm_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::FlowAlgorithm::Dis), "Dense inverse search (Kroeger et al.)", "dis"},
      {int(stitch::FlowAlgorithm::Farneback), "Farneback polynomial expansion", "farneback"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchFlowAlgorithm", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GstStaticPadTemplate sink_template = GST_STATIC_PAD_TEMPLATE(
    "sink", GST_PAD_SINK, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));
static GstStaticPadTemplate src_template = GST_STATIC_PAD_TEMPLATE(
    "src", GST_PAD_SRC, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));

static void post_decisions(GstStitchFlowWarp* self, const std::vector<stitch::FlowPairStats>& stats);

static void request_reset(GstStitchFlowWarp* self) {
  std::lock_guard<std::mutex> guard(self->state->lock);
  self->state->reset_requested = true;
}

/* The flow warper for `backend`. Bundles in CUDA memory ask for the CUDA one under
 * backend=auto; a build without it warps on the CPU (the views then go through host memory). */
static std::unique_ptr<stitch::FlowWarper> make_warper(GstStitchFlowWarp* self, stitch::Backend backend,
                                                       bool cuda_memory) {
  if (!cuda_memory || backend != stitch::Backend::Auto) return stitch::FlowWarper::create(backend);
  try {
    return stitch::FlowWarper::create(stitch::Backend::Cuda);
  } catch (const std::exception& e) {
    GST_WARNING_OBJECT(self, "no CUDA flow warper (%s): warping on the CPU through host memory", e.what());
    return stitch::FlowWarper::create(stitch::Backend::Cpu);
  }
}

/* Rebuilds the warper and the output pool when the rig, the backend or the memory changed. */
static void update_layout(GstStitchFlowWarp* self, GstStitchRigMeta* meta, stitch::Backend backend) {
  FlowWarpElementState* st = self->state;
  const bool new_warper = !st->warper.made_with(st->cuda) || st->warper_backend != backend;
  if (!new_warper && meta->version == st->rig_version && st->pool) return;
  const stitch::Rig& rig = **meta->rig;
  if (rig.cameras.size() > STITCH_MAX_VIEWS) throw std::invalid_argument("too many cameras");
  const stitch::OutputGeometry canvas = stitch::canvas_geometry(rig);
  const std::vector<stitch::ViewPlacement> views = stitch::place_views(rig, canvas);
  /* refused before anything is allocated; per canvas pixel of a view: 2 pooled bundles of warped
   * views (8 bytes), the warper's maps and flow buffers (conservatively 40 more) */
  guint64 pixels = 0;
  for (const auto& v : views) pixels += guint64(std::max(v.roi.width, 0)) * guint64(std::max(v.roi.height, 0));
  std::string too_big;
  if (!stitch_check_frame_size("the canvas", canvas.width, canvas.height, pixels * 48, stitch_memory_budget(0), too_big))
    throw std::runtime_error(too_big + ": leave stitchflowwarp out (stitchblend output-width/output-height then warps "
                             "straight into a smaller panorama) or calibrate a smaller canvas");
  if (new_warper) {
    st->warper.make(st->cuda, [&]() { return make_warper(self, backend, st->cuda_memory); });
    st->warper_backend = backend;
  }
  st->warper.run([&](stitch::FlowWarper& w) { w.prepare(views, canvas.width, canvas.height); });
  st->rig_version = meta->version;

  GstStitchWarpMeta& layout = st->layout;
  layout.rig_version = meta->version;
  layout.canvas_width = canvas.width;
  layout.canvas_height = canvas.height;
  layout.n_views = guint(views.size());
  std::vector<std::array<int, 2>> sizes;
  for (std::size_t i = 0; i < views.size(); ++i) {
    const stitch::Rect& r = views[i].roi;
    layout.rois[i][0] = r.x;
    layout.rois[i][1] = r.y;
    layout.rois[i][2] = r.width;
    layout.rois[i][3] = r.height;
    /* an invisible view still gets a 1x1 placeholder, marked missing */
    sizes.push_back({std::max(r.width, 1), std::max(r.height, 1)});
  }
  stitch_bundle_pool_clear(&st->pool);
  GstCaps* caps = gst_pad_get_current_caps(GST_BASE_TRANSFORM_SRC_PAD(self));
  std::string error;
  st->pool = stitch_bundle_pool_new(st->cuda, st->cuda_memory, sizes, caps, error);
  if (caps) gst_caps_unref(caps);
  if (!st->pool) throw std::runtime_error("cannot allocate the warped views: " + error);
  GST_INFO_OBJECT(self, "canvas %dx%d, %u views in %s memory, %s warper", canvas.width, canvas.height,
                  layout.n_views, st->cuda_memory ? "CUDA" : "system", stitch::backend_name(st->warper->backend()));
}

static GstFlowReturn gst_stitch_flow_warp_prepare_output_buffer(GstBaseTransform* trans,
                                                                GstBuffer* input, GstBuffer** outbuf) {
  GstStitchFlowWarp* self = GST_STITCH_FLOW_WARP(trans);
  FlowWarpElementState* st = self->state;
  GstStitchRigMeta* meta = stitch_bundle_require_rig(GST_ELEMENT(self), input);
  if (!meta || !stitch_bundle_require_camera_views(GST_ELEMENT(self), input)) return GST_FLOW_ERROR;
  if (gst_base_transform_is_passthrough(trans)) {  /* flow=false: the bundle as it came */
    *outbuf = input;
    return GST_FLOW_OK;
  }
  stitch::Backend backend;
  {
    std::lock_guard<std::mutex> guard(st->lock);
    backend = st->backend;
  }
  if (!stitch_guard(GST_ELEMENT(self), "stitchflowwarp: cannot build the canvas layout",
                    [&]() { update_layout(self, meta, backend); }))
    return GST_FLOW_ERROR;
  GstFlowReturn ret = stitch_bundle_pool_acquire(GST_ELEMENT(self), st->pool, outbuf);
  if (ret != GST_FLOW_OK) return ret;
  /* flags, timestamps and the metas that transform_meta keeps */
  GST_BASE_TRANSFORM_CLASS(gst_stitch_flow_warp_parent_class)->copy_metadata(trans, input, *outbuf);

  /* the views' GstVideoMetas come with the pooled bundle */
  GstStitchBundleMeta* in_bundle = gst_buffer_get_stitch_bundle_meta(input);
  guint64 missing = in_bundle ? in_bundle->missing_mask : 0;
  for (guint i = 0; i < st->layout.n_views; ++i)
    if (st->layout.rois[i][2] <= 0 || st->layout.rois[i][3] <= 0) missing |= guint64(1) << i;
  gst_buffer_add_stitch_bundle_meta(*outbuf, st->layout.n_views, missing);
  gst_buffer_add_stitch_rig_meta(*outbuf, *meta->rig, meta->version);
  gst_buffer_add_stitch_warp_meta(*outbuf, &st->layout);
  return GST_FLOW_OK;
}

static GstFlowReturn gst_stitch_flow_warp_transform(GstBaseTransform* trans, GstBuffer* inbuf,
                                                    GstBuffer* outbuf) {
  GstStitchFlowWarp* self = GST_STITCH_FLOW_WARP(trans);
  FlowWarpElementState* st = self->state;
  stitch::FlowWarpSettings settings;
  bool reset;
  {
    std::lock_guard<std::mutex> guard(st->lock);
    settings = st->settings;
    reset = st->reset_requested;
    st->reset_requested = false;
  }
  const guint n_views = st->layout.n_views;
  /* a CUDA warper reads and writes CUDA-memory views where they lie; a CPU one through host memory */
  const StitchCudaContext* device =
      st->cuda_memory && st->warper->backend() == stitch::Backend::Cuda ? &st->cuda : nullptr;
  StitchCudaHandoff handoff(st->cuda);  /* stream-ordered: no host synchronisation before the push */
  StitchBundleMapping in, out;
  std::string error;
  if (!in.map(inbuf, n_views, GST_MAP_READ, error, device)) {
    GST_ELEMENT_ERROR(self, STREAM, FORMAT, ("Bad bundle: %s", error.c_str()), (NULL));
    return GST_FLOW_ERROR;
  }
  if (!out.map(outbuf, n_views, GST_MAP_WRITE, error, device)) {
    GST_ELEMENT_ERROR(self, STREAM, FAILED, ("Cannot map the warped views: %s", error.c_str()), (NULL));
    return GST_FLOW_ERROR;
  }
  std::vector<stitch::ImageView> frames = in.views();
  for (guint i = 0; i < n_views; ++i)
    if (out.views()[i].empty()) frames[i] = stitch::ImageView();  /* not visible: not warped */
  const gboolean ok = stitch_guard(GST_ELEMENT(self), "stitchflowwarp", [&]() {
    st->warper.run([&](stitch::FlowWarper& w) {
      w.set_settings(settings);
      if (reset) w.reset();
      w.warp(frames, out.views());
    });
  });
  if (ok) {
    /* what the flow did, for stitchblend's debug view and for the log */
    GstStitchFlowMeta flow{};
    for (const auto& s : st->warper->stats()) {
      GST_LOG_OBJECT(self, "views %d-%d: mean flow %.2f px, %.0f%% consistent", s.view_a, s.view_b,
                     s.mean_magnitude, 100.0 * s.confident_fraction);
      if (flow.n_pairs == STITCH_MAX_FLOW_PAIRS) continue;
      GstStitchFlowPair& p = flow.pairs[flow.n_pairs++];
      p.view_a = s.view_a;
      p.view_b = s.view_b;
      p.rect[0] = s.rect.x, p.rect[1] = s.rect.y, p.rect[2] = s.rect.width, p.rect[3] = s.rect.height;
      p.mean_magnitude = s.mean_magnitude;
      p.confident_fraction = s.confident_fraction;
      p.error_homography = s.error_homography;
      p.error_flow = s.error_flow;
      p.gain = s.gain;
      p.flow_on = s.flow_on;
    }
    gst_buffer_add_stitch_flow_meta(outbuf, &flow);
    post_decisions(self, st->warper->stats());
  }
  if (!ok || !handoff.finish(GST_ELEMENT(self), outbuf, GST_BASE_TRANSFORM_SRC_PAD(trans))) return GST_FLOW_ERROR;
  return GST_FLOW_OK;
}

/* An element message for every overlap whose decision (flow on or off) changed. */
static void post_decisions(GstStitchFlowWarp* self, const std::vector<stitch::FlowPairStats>& stats) {
  FlowWarpElementState* st = self->state;
  for (const auto& s : stats) {
    bool known = false, changed = true;
    for (auto& d : st->decisions)
      if (d[0] == s.view_a && d[1] == s.view_b) {
        known = true;
        changed = d[2] != int(s.flow_on);
        d[2] = int(s.flow_on);
      }
    if (!known) st->decisions.push_back({s.view_a, s.view_b, int(s.flow_on)});
    if (!changed) continue;
    GST_INFO_OBJECT(self, "views %d-%d: flow %s (error %.2f with, %.2f without)", s.view_a, s.view_b,
                    s.flow_on ? "on" : "off", s.error_flow, s.error_homography);
    GstStructure* structure = gst_structure_new("stitch-flow-decision", "view-a", G_TYPE_INT, s.view_a, "view-b",
                                                G_TYPE_INT, s.view_b, "flow-on", G_TYPE_BOOLEAN, gboolean(s.flow_on),
                                                "gain", G_TYPE_DOUBLE, s.gain, "error-homography", G_TYPE_DOUBLE,
                                                s.error_homography, "error-flow", G_TYPE_DOUBLE, s.error_flow, NULL);
    gst_element_post_message(GST_ELEMENT(self), gst_message_new_element(GST_OBJECT(self), structure));
  }
}

static gboolean gst_stitch_flow_warp_transform_meta(GstBaseTransform*, GstBuffer*, GstMeta* meta, GstBuffer*) {
  /* The views' metas describe the camera frames; prepare_output_buffer adds the new ones. */
  return stitch_meta_survives_new_views(meta);
}

static gboolean gst_stitch_flow_warp_sink_event(GstBaseTransform* trans, GstEvent* event) {
  switch (GST_EVENT_TYPE(event)) {
    case GST_EVENT_FLUSH_STOP:
    case GST_EVENT_SEGMENT:  /* a seek or a new stream: the previous flow no longer applies */
      request_reset(GST_STITCH_FLOW_WARP(trans));
      break;
    default: break;
  }
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_flow_warp_parent_class)->sink_event(trans, event);
}

static gboolean gst_stitch_flow_warp_set_caps(GstBaseTransform* trans, GstCaps* incaps, GstCaps*) {
  GstStitchFlowWarp* self = GST_STITCH_FLOW_WARP(trans);
  FlowWarpElementState* st = self->state;
  if (!stitch_bundle_accept_caps(GST_ELEMENT(self), incaps)) return FALSE;
  const bool cuda_memory = stitch_caps_are_cuda_memory(incaps);
  if (cuda_memory != st->cuda_memory) {
    st->clear();  /* the warper and the pool belong to one kind of memory */
    st->cuda_memory = cuda_memory;
  }
  if (cuda_memory && !st->cuda.ensure(GST_ELEMENT(self))) return FALSE;
  request_reset(self);
  return TRUE;
}

static bool offer_cuda(GstStitchFlowWarp* self) {
  std::lock_guard<std::mutex> guard(self->state->lock);
  return stitch_cuda_memory_offered(self->state->backend);
}

static GstCaps* gst_stitch_flow_warp_transform_caps(GstBaseTransform* trans, GstPadDirection, GstCaps* caps, GstCaps* filter) {
  /* the warped views go out in the memory the camera frames came in */
  return stitch_caps_same_memory(caps, filter, offer_cuda(GST_STITCH_FLOW_WARP(trans)));
}

static void gst_stitch_flow_warp_set_context(GstElement* element, GstContext* context) {
  GST_STITCH_FLOW_WARP(element)->state->cuda.set_context(element, context);
  GST_ELEMENT_CLASS(gst_stitch_flow_warp_parent_class)->set_context(element, context);
}

static gboolean gst_stitch_flow_warp_query(GstBaseTransform* trans, GstPadDirection direction, GstQuery* query) {
  if (GST_STITCH_FLOW_WARP(trans)->state->cuda.handle_query(GST_ELEMENT(trans), query)) return TRUE;
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_flow_warp_parent_class)->query(trans, direction, query);
}

static gboolean gst_stitch_flow_warp_stop(GstBaseTransform* trans) {
  GST_STITCH_FLOW_WARP(trans)->state->clear();
  return TRUE;
}

static void gst_stitch_flow_warp_set_property(GObject* object, guint prop_id, const GValue* value,
                                              GParamSpec* pspec) {
  GstStitchFlowWarp* self = GST_STITCH_FLOW_WARP(object);
  if (prop_id == PROP_FLOW) {
    const bool flow = g_value_get_boolean(value);
    {
      std::lock_guard<std::mutex> guard(self->state->lock);
      self->state->settings.flow = flow;
      /* turned back on: no flow history from before it was off */
      self->state->reset_requested = true;
    }
    /* Flow off: the bundle goes through unwarped and stitchblend composes the frames straight
     * onto the canvas, the same panorama (same maps and weights) without writing and reading
     * every view's warped rectangle (BENCHMARKS.md, "flow=false passes through"). */
    gst_base_transform_set_passthrough(GST_BASE_TRANSFORM(self), !flow);
    return;
  }
  std::lock_guard<std::mutex> guard(self->state->lock);
  stitch::FlowWarpSettings& s = self->state->settings;
  switch (prop_id) {
    case PROP_QUALITY: s.quality = stitch::FlowQuality(g_value_get_enum(value)); break;
    case PROP_ALGORITHM: s.algorithm = stitch::FlowAlgorithm(g_value_get_enum(value)); break;
    case PROP_MARGIN: s.margin = g_value_get_int(value); break;
    case PROP_TEMPORAL_SMOOTHING: s.temporal_smoothing = g_value_get_double(value); break;
    case PROP_BACKEND: self->state->backend = stitch::Backend(g_value_get_enum(value)); break;
    case PROP_FALLBACK: s.fallback = g_value_get_boolean(value); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_flow_warp_get_property(GObject* object, guint prop_id, GValue* value,
                                              GParamSpec* pspec) {
  GstStitchFlowWarp* self = GST_STITCH_FLOW_WARP(object);
  std::lock_guard<std::mutex> guard(self->state->lock);
  const stitch::FlowWarpSettings& s = self->state->settings;
  switch (prop_id) {
    case PROP_FLOW: g_value_set_boolean(value, s.flow); break;
    case PROP_QUALITY: g_value_set_enum(value, int(s.quality)); break;
    case PROP_ALGORITHM: g_value_set_enum(value, int(s.algorithm)); break;
    case PROP_MARGIN: g_value_set_int(value, s.margin); break;
    case PROP_TEMPORAL_SMOOTHING: g_value_set_double(value, s.temporal_smoothing); break;
    case PROP_BACKEND: g_value_set_enum(value, int(self->state->backend)); break;
    case PROP_FALLBACK: g_value_set_boolean(value, s.fallback); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_flow_warp_finalize(GObject* object) {
  GstStitchFlowWarp* self = GST_STITCH_FLOW_WARP(object);
  self->state->clear();
  delete self->state;
  G_OBJECT_CLASS(gst_stitch_flow_warp_parent_class)->finalize(object);
}

static void gst_stitch_flow_warp_class_init(GstStitchFlowWarpClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  GstBaseTransformClass* trans_class = GST_BASE_TRANSFORM_CLASS(klass);
  const GParamFlags rw = GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS);
  /* read on every bundle: may change while playing; the numbers may follow a GstControlSource */
  const GParamFlags per_frame = GParamFlags(rw | GST_PARAM_MUTABLE_PLAYING);
  const GParamFlags controllable = GParamFlags(per_frame | GST_PARAM_CONTROLLABLE);

  gobject_class->set_property = gst_stitch_flow_warp_set_property;
  gobject_class->get_property = gst_stitch_flow_warp_get_property;
  gobject_class->finalize = gst_stitch_flow_warp_finalize;

  g_object_class_install_property(gobject_class, PROP_FLOW,
      g_param_spec_boolean("flow", "Flow", "Local warping by optical flow in the overlaps "
                           "(false: homography only)", DEFAULT_FLOW, per_frame));
  g_object_class_install_property(gobject_class, PROP_QUALITY,
      g_param_spec_enum("quality", "Quality", "Flow quality preset (resolution and iterations)",
                        quality_get_type(), int(DEFAULT_QUALITY), per_frame));
  g_object_class_install_property(gobject_class, PROP_ALGORITHM,
      g_param_spec_enum("algorithm", "Algorithm", "Dense optical flow method",
                        algorithm_get_type(), int(DEFAULT_ALGORITHM), per_frame));
  g_object_class_install_property(gobject_class, PROP_MARGIN,
      g_param_spec_int("margin", "Margin", "Pixels the overlap is widened by for the flow", 0, 512,
                       DEFAULT_MARGIN, controllable));
  g_object_class_install_property(gobject_class, PROP_TEMPORAL_SMOOTHING,
      g_param_spec_double("temporal-smoothing", "Temporal smoothing",
                          "Weight of the previous frame's flow where neither view changed (static "
                          "scene); where the content moves the new flow is taken at once (0: every "
                          "frame alone)", 0.0, 0.99, DEFAULT_TEMPORAL_SMOOTHING, controllable));
  g_object_class_install_property(gobject_class, PROP_FALLBACK,
      g_param_spec_boolean("fallback", "Fallback",
                           "Never worse than the homography: use the flow only where it makes the views "
                           "match better, and per overlap only while it cuts the matching error "
                           "(false: the flow wherever it is forward-backward consistent)",
                           DEFAULT_FALLBACK, per_frame));
  g_object_class_install_property(gobject_class, PROP_BACKEND,
      g_param_spec_enum("backend", "Backend", "Implementation of the warp and the flow",
                        GST_TYPE_STITCH_BACKEND, int(stitch::Backend::Auto), GParamFlags(rw | GST_PARAM_MUTABLE_READY)));

  gst_element_class_add_static_pad_template(element_class, &sink_template);
  gst_element_class_add_static_pad_template(element_class, &src_template);
  gst_element_class_set_static_metadata(element_class, "Stitch flow warp", "Filter/Converter/Video",
      "Pre-warps the views of a calibrated stitch bundle onto the canvas and aligns their "
      "overlaps with bidirectional dense optical flow",
      "gst-stitch developers");

  trans_class->prepare_output_buffer = GST_DEBUG_FUNCPTR(gst_stitch_flow_warp_prepare_output_buffer);
  trans_class->transform = GST_DEBUG_FUNCPTR(gst_stitch_flow_warp_transform);
  trans_class->transform_meta = GST_DEBUG_FUNCPTR(gst_stitch_flow_warp_transform_meta);
  trans_class->sink_event = GST_DEBUG_FUNCPTR(gst_stitch_flow_warp_sink_event);
  trans_class->set_caps = GST_DEBUG_FUNCPTR(gst_stitch_flow_warp_set_caps);
  trans_class->stop = GST_DEBUG_FUNCPTR(gst_stitch_flow_warp_stop);
  trans_class->transform_caps = GST_DEBUG_FUNCPTR(gst_stitch_flow_warp_transform_caps);
  trans_class->query = GST_DEBUG_FUNCPTR(gst_stitch_flow_warp_query);
  element_class->set_context = GST_DEBUG_FUNCPTR(gst_stitch_flow_warp_set_context);
  trans_class->passthrough_on_same_caps = FALSE;

  gst_type_mark_as_plugin_api(quality_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(algorithm_get_type(), GstPluginAPIFlags(0));
  GST_DEBUG_CATEGORY_INIT(gst_stitch_flow_warp_debug, "stitchflowwarp", 0, "stitch flow warp");
}

static void gst_stitch_flow_warp_init(GstStitchFlowWarp* self) {
  self->state = new FlowWarpElementState();
  stitch::FlowWarpSettings& s = self->state->settings;
  s.flow = DEFAULT_FLOW;
  s.quality = DEFAULT_QUALITY;
  s.algorithm = DEFAULT_ALGORITHM;
  s.margin = DEFAULT_MARGIN;
  s.temporal_smoothing = DEFAULT_TEMPORAL_SMOOTHING;
  s.fallback = DEFAULT_FALLBACK;
  gst_base_transform_set_passthrough(GST_BASE_TRANSFORM(self), !DEFAULT_FLOW);
}
