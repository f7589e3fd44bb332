/**
 * SECTION:element-stitchblend
 * @title: stitchblend
 *
 * Turns a calibrated bundle into one panorama frame: it warps each view onto the canvas by
 * its homography (or takes the views stitchflowwarp already warped) and fuses the views with the paper's position-weighted mean (eq. 15-16):
 * each view's weight falls linearly to zero at its own border, so seams fade across the
 * whole overlap. The output is `video/x-raw, format=RGBA` in system memory, or in CUDA memory
 * (`video/x-raw(memory:CUDAMemory)`, gst-cuda) wherever downstream takes it (cudadownload,
 * nvh264enc); bundles are read in either memory, so with a GPU the frames stay on it from
 * stitchsync to the panorama.
 * The output size follows the calibration's canvas; `output-width`/`output-height` scale it
 * and `crop=auto` keeps only the largest rectangle that every camera pixel covers (no black
 * corners). A view that stitchsync marks missing is left out and its neighbours fill in.
 * The panorama size is fixed by the first calibration (or the properties): later
 * recalibrations are fitted into the same frame, so encoders and muxers see no caps change.
 *
 * `mode=multiband` blends band by band instead (Burt-Adelson Laplacian pyramids, `bands`
 * levels): each output pixel belongs to one view, and each view's mask is blurred per level, so
 * exposure differences fade over a wide band while detail is cut sharply (no ghosted double
 * edges where the views disagree). By default the masks meet in the middle of every overlap;
 * `seam=dp` moves the cut, frame by frame, along the path of least color difference, edges and
 * motion through each overlap (dynamic programming), pulled towards the previous frame's path so
 * that it does not jump. Both run on the GPU where the blend does.
 * `debug` draws each view's outline, the overlaps, the seams and what stitchflowwarp's flow did
 * onto the panorama.
 *
 * ## Example launch lines
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib ! stitchblend crop=auto ! videoconvert ! \
 *   x264enc ! mp4mux ! filesink location=pano.mp4 \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib ! stitchblend output-width=1280 ! \
 *   videoconvert ! autovideosink \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * Multiband blending with seams placed around moving objects, and the debug view:
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib ! stitchcolor ! stitchflowwarp ! \
 *   stitchblend mode=multiband seam=dp ! videoconvert ! autovideosink \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib ! stitchflowwarp ! \
 *   stitchblend mode=multiband seam=dp debug=all ! videoconvert ! autovideosink \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * With a GPU, from the decoders to the panorama in CUDA memory:
 * |[
 * gst-launch-1.0 -e stitchsync name=s ! stitchcalib ! stitchblend crop=auto ! cudadownload ! \
 *   videoconvert ! x264enc ! mp4mux ! filesink location=pano.mp4 \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_1
 * ]|
 */
#include "gststitchblend.h"

#include <gst/video/video.h>

#include "gststitchbundle.h"
#include "gststitchcuda.h"
#include "stitch/blend/compositor.hpp"

#ifdef STITCH_HAVE_GST_CUDA
#define SRC_CAPS                                                                    \
  GST_VIDEO_CAPS_MAKE_WITH_FEATURES(STITCH_CAPS_FEATURE_CUDA_MEMORY, "RGBA") ";" \
  GST_VIDEO_CAPS_MAKE("RGBA")
#else
#define SRC_CAPS GST_VIDEO_CAPS_MAKE("RGBA")
#endif

GST_DEBUG_CATEGORY_STATIC(gst_stitch_blend_debug);
#define GST_CAT_DEFAULT gst_stitch_blend_debug

enum { PROP_0, PROP_OUTPUT_WIDTH, PROP_OUTPUT_HEIGHT, PROP_CROP, PROP_BACKEND, PROP_MODE, PROP_BANDS, PROP_SEAM, PROP_DEBUG };

#define DEFAULT_CROP stitch::CropMode::None

struct BlendState {
  /* settings (object lock) */
  stitch::CompositorSettings settings;
  bool settings_changed = true;
  guint debug = 0; /* stitch::DebugFlags */
  /* state (streaming thread) */
  StitchCudaOwned<stitch::Compositor> compositor;
  guint64 rig_version = G_MAXUINT64;
  GstVideoInfo out_info;
  GstBufferPool* pool = nullptr;
  bool in_cuda = false;   /* negotiated bundles in CUDA memory */
  bool out_cuda = false;  /* negotiated a panorama in CUDA memory */
  StitchCudaContext cuda;
  void clear() {
    compositor.reset();
    rig_version = G_MAXUINT64;
    stitch_bundle_pool_clear(&pool);
  }
};

/* CUDA memory is offered on both sides when a device opens, and not with backend=cpu. */
struct _GstStitchBlend {
  GstBaseTransform parent;
  BlendState* state;
};

G_DEFINE_TYPE(GstStitchBlend, gst_stitch_blend, GST_TYPE_BASE_TRANSFORM);
GST_ELEMENT_REGISTER_DEFINE(stitchblend, "stitchblend", GST_RANK_NONE, GST_TYPE_STITCH_BLEND);

static GType crop_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::CropMode::None), "Whole canvas (uncovered corners are black)", "none"},
      {int(stitch::CropMode::Auto), "Largest rectangle covered by the cameras", "auto"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchBlendCrop", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GType mode_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::BlendMode::Weighted), "Position-weighted mean (the paper's eq. 15-16)", "weighted"},
      {int(stitch::BlendMode::Multiband), "Multiband: Laplacian pyramids blended band by band", "multiband"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchBlendMode", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GType seam_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::SeamMode::None), "Middle of every overlap (where the views' position weights meet)", "none"},
      {int(stitch::SeamMode::DynamicProgramming),
       "Least visible path by dynamic programming, kept near the last frame's", "dp"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchBlendSeam", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GType debug_get_type(void) {
  static GType type = 0;
  static const GFlagsValue values[] = {
      {stitch::kDebugOutlines, "Each view's outline, in its own color", "outlines"},
      {stitch::kDebugOverlaps, "The overlaps, tinted", "overlaps"},
      {stitch::kDebugSeams, "The seams: where the blend changes view", "seams"},
      {stitch::kDebugFlow, "What stitchflowwarp's flow did in each overlap (mean magnitude, confidence)", "flow"},
      {stitch::kDebugOutlines | stitch::kDebugOverlaps | stitch::kDebugSeams | stitch::kDebugFlow, "Everything",
       "all"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_flags_register_static("GstStitchBlendDebug", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

static GstStaticPadTemplate sink_template = GST_STATIC_PAD_TEMPLATE(
    "sink", GST_PAD_SINK, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));
static GstStaticPadTemplate src_template =
    GST_STATIC_PAD_TEMPLATE("src", GST_PAD_SRC, GST_PAD_ALWAYS, GST_STATIC_CAPS(SRC_CAPS));

static bool offer_cuda(GstStitchBlend* self) {
  GST_OBJECT_LOCK(self);
  const stitch::Backend backend = self->state->settings.backend;
  GST_OBJECT_UNLOCK(self);
  return stitch_cuda_memory_offered(backend);
}

static GstCaps* gst_stitch_blend_transform_caps(GstBaseTransform* trans, GstPadDirection direction,
                                                GstCaps* caps, GstCaps* filter) {
  GstStitchBlend* self = GST_STITCH_BLEND(trans);
  GstCaps* out = gst_caps_new_empty();
  for (guint i = 0; i < gst_caps_get_size(caps); ++i) {
    GstStructure* s = gst_structure_copy(gst_caps_get_structure(caps, i));
    gst_structure_set(s, "width", GST_TYPE_INT_RANGE, 1, 32767, "height", GST_TYPE_INT_RANGE, 1,
                      32767, NULL);
    if (direction == GST_PAD_SINK) {
      gst_structure_remove_fields(s, "multiview-mode", "views", "multiview-flags", NULL);
    } else {
      gst_structure_set(s, "multiview-mode", G_TYPE_STRING, "separated", "views",
                        GST_TYPE_INT_RANGE, 2, STITCH_MAX_VIEWS, NULL);
      gst_structure_remove_fields(s, "pixel-aspect-ratio", NULL);
    }
    out = gst_caps_merge_structure(out, s);
  }
  /* The CUDA compositor reads and writes either memory, so each side is offered both
   * (CUDA first: the panorama stays on the GPU). */
  out = stitch_caps_in_both_memories(out, offer_cuda(self));
  if (filter) {
    GstCaps* tmp = gst_caps_intersect_full(filter, out, GST_CAPS_INTERSECT_FIRST);
    gst_caps_unref(out);
    out = tmp;
  }
  return out;
}

static GstCaps* gst_stitch_blend_fixate_caps(GstBaseTransform* trans, GstPadDirection direction,
                                             GstCaps* caps, GstCaps* othercaps) {
  GstStitchBlend* self = GST_STITCH_BLEND(trans);
  /* Prefer CUDA memory wherever downstream takes it, whatever order it lists it in. */
  othercaps = gst_caps_truncate(stitch_caps_prefer_cuda(othercaps, TRUE));
  if (direction == GST_PAD_SINK) {
    GstStructure* out = gst_caps_get_structure(othercaps, 0);
    gint w = 0, h = 0;
    if (self->state->compositor && self->state->compositor->prepared()) {
      /* renegotiation: keep the geometry we already output */
      w = self->state->compositor->geometry().width;
      h = self->state->compositor->geometry().height;
    } else {
      /* provisional until the first calibrated bundle arrives */
      const GstStructure* in = gst_caps_get_structure(caps, 0);
      gint vw = 0, vh = 0, views = 2;
      gst_structure_get_int(in, "width", &vw);
      gst_structure_get_int(in, "height", &vh);
      gst_structure_get_int(in, "views", &views);
      GST_OBJECT_LOCK(self);
      w = self->state->settings.output_width > 0 ? self->state->settings.output_width : vw * views;
      h = self->state->settings.output_height > 0 ? self->state->settings.output_height : vh;
      GST_OBJECT_UNLOCK(self);
    }
    gst_structure_fixate_field_nearest_int(out, "width", MAX(w, 2));
    gst_structure_fixate_field_nearest_int(out, "height", MAX(h, 2));
    gst_structure_set(out, "pixel-aspect-ratio", GST_TYPE_FRACTION, 1, 1, NULL);
  }
  return gst_caps_fixate(othercaps);
}

static gboolean gst_stitch_blend_set_caps(GstBaseTransform* trans, GstCaps* incaps, GstCaps* outcaps) {
  GstStitchBlend* self = GST_STITCH_BLEND(trans);
  BlendState* st = self->state;
  if (!stitch_bundle_accept_caps(GST_ELEMENT(self), incaps)) return FALSE;
  const bool in_cuda = stitch_caps_are_cuda_memory(incaps), out_cuda = stitch_caps_are_cuda_memory(outcaps);
  if (in_cuda != st->in_cuda || out_cuda != st->out_cuda) {
    st->clear();  /* the compositor and the pool belong to one kind of memory */
    st->in_cuda = in_cuda;
    st->out_cuda = out_cuda;
  }
  if ((in_cuda || out_cuda) && !st->cuda.ensure(GST_ELEMENT(self))) return FALSE;
  return gst_video_info_from_caps(&st->out_info, outcaps);
}

static void gst_stitch_blend_set_context(GstElement* element, GstContext* context) {
  GST_STITCH_BLEND(element)->state->cuda.set_context(element, context);
  GST_ELEMENT_CLASS(gst_stitch_blend_parent_class)->set_context(element, context);
}

static gboolean gst_stitch_blend_query(GstBaseTransform* trans, GstPadDirection direction, GstQuery* query) {
  if (GST_STITCH_BLEND(trans)->state->cuda.handle_query(GST_ELEMENT(trans), query)) return TRUE;
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_blend_parent_class)->query(trans, direction, query);
}

/* Rebuilds the compositor when the rig or the settings changed; renegotiates the output. */
static gboolean update_geometry(GstStitchBlend* self, GstStitchRigMeta* meta, GstStitchWarpMeta* warped) {
  BlendState* st = self->state;
  const stitch::CompositorInput input =
      warped ? stitch::CompositorInput::Prewarped : stitch::CompositorInput::CameraFrames;
  GST_OBJECT_LOCK(self);
  const bool settings_changed = st->settings_changed;
  const stitch::CompositorSettings settings = st->settings;
  st->settings_changed = false;
  GST_OBJECT_UNLOCK(self);
  if (st->compositor && meta->version == st->rig_version && !settings_changed &&
      st->compositor->input() == input)
    return TRUE;

  stitch::CompositorSettings effective = settings;
  if (st->compositor && !settings_changed) {
    /* A recalibration keeps the panorama size: encoders and muxers downstream rarely accept
     * a new resolution mid-stream. The new canvas is fitted into the same frame. */
    effective.output_width = st->compositor->geometry().width;
    effective.output_height = st->compositor->geometry().height;
  }
  const bool device_memory = st->in_cuda || st->out_cuda;
  if (device_memory && settings.backend == stitch::Backend::Cpu)
    throw std::runtime_error("backend=cpu cannot read or write CUDA memory: put cudadownload around stitchblend, or use backend=auto");
  st->compositor.make(st->cuda, [&]() {
    auto c = std::make_unique<stitch::Compositor>(device_memory ? stitch::Backend::Cuda : settings.backend);
    c->prepare(**meta->rig, effective, input);
    return c;
  });
  const stitch::Compositor& compositor = *st->compositor;
  if (warped) {
    /* stitchflowwarp lays the views out on the canvas; we must read them where it put them */
    const auto& views = compositor.prewarped_placements();
    bool same = warped->rig_version == meta->version && warped->n_views == views.size();
    for (std::size_t i = 0; same && i < views.size(); ++i) {
      const stitch::Rect& r = views[i].roi;
      same = r.empty() ? warped->rois[i][2] <= 0 || warped->rois[i][3] <= 0
                       : warped->rois[i][0] == r.x && warped->rois[i][1] == r.y &&
                             warped->rois[i][2] == r.width && warped->rois[i][3] == r.height;
    }
    if (!same) throw std::runtime_error("the pre-warped views do not match the calibration's canvas");
  }
  const stitch::OutputGeometry& g = compositor.geometry();
  st->rig_version = meta->version;
  if (g.width != GST_VIDEO_INFO_WIDTH(&st->out_info) || g.height != GST_VIDEO_INFO_HEIGHT(&st->out_info)) {
    GstVideoInfo info = st->out_info;
    gst_video_info_set_format(&info, GST_VIDEO_FORMAT_RGBA, g.width, g.height);
    info.fps_n = st->out_info.fps_n;
    info.fps_d = st->out_info.fps_d;
    GstCaps* caps = gst_video_info_to_caps(&info);
    if (st->out_cuda) gst_caps_set_features(caps, 0, gst_caps_features_new(STITCH_CAPS_FEATURE_CUDA_MEMORY, NULL));
    GST_INFO_OBJECT(self, "panorama is %dx%d%s", g.width, g.height, st->out_cuda ? " in CUDA memory" : "");
    const gboolean ok = gst_base_transform_update_src_caps(GST_BASE_TRANSFORM(self), caps);
    gst_caps_unref(caps);
    if (!ok) {
      GST_ELEMENT_ERROR(self, CORE, NEGOTIATION,
                        ("Downstream refused the %dx%d panorama (add videoscale/videoconvert, or "
                         "set output-width/output-height)", g.width, g.height),
                        (NULL));
      return FALSE;
    }
    st->out_info = info;
  }
  stitch_bundle_pool_clear(&st->pool);
  GstCaps* caps = gst_video_info_to_caps(&st->out_info);
  if (st->out_cuda) gst_caps_set_features(caps, 0, gst_caps_features_new(STITCH_CAPS_FEATURE_CUDA_MEMORY, NULL));
  std::string error;
  st->pool = stitch_bundle_pool_new(st->cuda, st->out_cuda,
                                    {{GST_VIDEO_INFO_WIDTH(&st->out_info), GST_VIDEO_INFO_HEIGHT(&st->out_info)}}, caps,
                                    error);
  gst_caps_unref(caps);
  if (!st->pool) {
    GST_ELEMENT_ERROR(self, RESOURCE, NO_SPACE_LEFT, ("Cannot allocate panorama buffers: %s", error.c_str()), (NULL));
    return FALSE;
  }
  return TRUE;
}

static GstFlowReturn gst_stitch_blend_prepare_output_buffer(GstBaseTransform* trans,
                                                            GstBuffer* input, GstBuffer** outbuf) {
  GstStitchBlend* self = GST_STITCH_BLEND(trans);
  GstStitchRigMeta* meta = stitch_bundle_require_rig(GST_ELEMENT(self), input);
  if (!meta) return GST_FLOW_ERROR;
  gboolean ok = FALSE;
  if (!stitch_guard(GST_ELEMENT(self), "stitchblend: cannot build the panorama geometry",
                    [&]() { ok = update_geometry(self, meta, gst_buffer_get_stitch_warp_meta(input)); }) ||
      !ok)
    return GST_FLOW_ERROR;
  GstFlowReturn ret = stitch_bundle_pool_acquire(GST_ELEMENT(self), self->state->pool, outbuf);
  if (ret != GST_FLOW_OK) return ret;
  gst_buffer_copy_into(*outbuf, input, GstBufferCopyFlags(GST_BUFFER_COPY_FLAGS | GST_BUFFER_COPY_TIMESTAMPS), 0, -1);
  return GST_FLOW_OK;
}

static GstFlowReturn gst_stitch_blend_transform(GstBaseTransform* trans, GstBuffer* inbuf,
                                                GstBuffer* outbuf) {
  GstStitchBlend* self = GST_STITCH_BLEND(trans);
  BlendState* st = self->state;
  GstStitchRigMeta* meta = gst_buffer_get_stitch_rig_meta(inbuf);
  const guint n_views = guint((*meta->rig)->cameras.size());
  StitchBundleMapping mapping;
  std::string error;
  if (!mapping.map(inbuf, n_views, GST_MAP_READ, error, st->in_cuda ? &st->cuda : nullptr)) {
    GST_ELEMENT_ERROR(self, STREAM, FORMAT, ("Bad bundle: %s", error.c_str()), (NULL));
    return GST_FLOW_ERROR;
  }
  GstVideoFrame out;
  const GstMapFlags out_flags = st->out_cuda ? GstMapFlags(GST_MAP_WRITE | STITCH_MAP_CUDA) : GST_MAP_WRITE;
  if (!gst_video_frame_map(&out, &st->out_info, outbuf, out_flags)) {
    GST_ELEMENT_ERROR(self, STREAM, FAILED, ("Cannot map the output frame"), (NULL));
    return GST_FLOW_ERROR;
  }
  stitch::ImageView view;
  view.data = static_cast<uint8_t*>(GST_VIDEO_FRAME_PLANE_DATA(&out, 0));
  view.pitch = std::size_t(GST_VIDEO_FRAME_PLANE_STRIDE(&out, 0));
  view.width = GST_VIDEO_FRAME_WIDTH(&out);
  view.height = GST_VIDEO_FRAME_HEIGHT(&out);
  view.on_device = st->out_cuda;
  GST_OBJECT_LOCK(self);
  const guint debug = st->debug;
  GST_OBJECT_UNLOCK(self);
  std::vector<stitch::FlowPairStats> flow;
  if (GstStitchFlowMeta* fm = (debug & stitch::kDebugFlow) ? gst_buffer_get_stitch_flow_meta(inbuf) : nullptr)
    for (guint i = 0; i < fm->n_pairs; ++i) {
      const GstStitchFlowPair& p = fm->pairs[i];
      stitch::FlowPairStats f;
      f.view_a = p.view_a;
      f.view_b = p.view_b;
      f.rect = {p.rect[0], p.rect[1], p.rect[2], p.rect[3]};
      f.mean_magnitude = p.mean_magnitude;
      f.confident_fraction = p.confident_fraction;
      f.error_homography = p.error_homography;
      f.error_flow = p.error_flow;
      f.gain = p.gain;
      f.flow_on = p.flow_on;
      flow.push_back(f);
    }
  const gboolean ok = stitch_guard(GST_ELEMENT(self), "stitchblend", [&]() {
    st->compositor.run([&](stitch::Compositor& c) {
      c.set_debug(debug);
      c.set_flow_stats(std::move(flow));
      c.compose(mapping.views(), view);
    });
  });
  gst_video_frame_unmap(&out);
  return ok ? GST_FLOW_OK : GST_FLOW_ERROR;
}

static gboolean gst_stitch_blend_transform_meta(GstBaseTransform*, GstBuffer*, GstMeta* meta,
                                                GstBuffer*) {
  /* Views, rig and bundle metas describe the input bundle, not the panorama. */
  const GstMetaInfo* info = meta->info;
  return !gst_meta_api_type_has_tag(info->api, g_quark_from_static_string("stitch")) &&
         !gst_meta_api_type_has_tag(info->api, g_quark_from_static_string(GST_META_TAG_VIDEO_STR));
}

static gboolean gst_stitch_blend_stop(GstBaseTransform* trans) {
  GST_STITCH_BLEND(trans)->state->clear();
  return TRUE;
}

static void gst_stitch_blend_set_property(GObject* object, guint prop_id, const GValue* value,
                                          GParamSpec* pspec) {
  GstStitchBlend* self = GST_STITCH_BLEND(object);
  GST_OBJECT_LOCK(self);
  stitch::CompositorSettings& s = self->state->settings;
  switch (prop_id) {
    case PROP_OUTPUT_WIDTH: s.output_width = g_value_get_int(value); break;
    case PROP_OUTPUT_HEIGHT: s.output_height = g_value_get_int(value); break;
    case PROP_CROP: s.crop = stitch::CropMode(g_value_get_enum(value)); break;
    case PROP_BACKEND: s.backend = stitch::Backend(g_value_get_enum(value)); break;
    case PROP_MODE: s.blend = stitch::BlendMode(g_value_get_enum(value)); break;
    case PROP_BANDS: s.bands = g_value_get_int(value); break;
    case PROP_SEAM: s.seam = stitch::SeamMode(g_value_get_enum(value)); break;
    case PROP_DEBUG:
      self->state->debug = g_value_get_flags(value);
      GST_OBJECT_UNLOCK(self);
      return; /* drawn per frame: no rebuild */
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
  if ((prop_id == PROP_SEAM || prop_id == PROP_MODE) && s.seam != stitch::SeamMode::None &&
      s.blend != stitch::BlendMode::Multiband)
    GST_WARNING_OBJECT(self, "seam=%s has no effect with mode=weighted: set mode=multiband",
                       s.seam == stitch::SeamMode::DynamicProgramming ? "dp" : "?");
  self->state->settings_changed = true;
  GST_OBJECT_UNLOCK(self);
}

static void gst_stitch_blend_get_property(GObject* object, guint prop_id, GValue* value,
                                          GParamSpec* pspec) {
  GstStitchBlend* self = GST_STITCH_BLEND(object);
  GST_OBJECT_LOCK(self);
  const stitch::CompositorSettings& s = self->state->settings;
  switch (prop_id) {
    case PROP_OUTPUT_WIDTH: g_value_set_int(value, s.output_width); break;
    case PROP_OUTPUT_HEIGHT: g_value_set_int(value, s.output_height); break;
    case PROP_CROP: g_value_set_enum(value, int(s.crop)); break;
    case PROP_BACKEND: g_value_set_enum(value, int(s.backend)); break;
    case PROP_MODE: g_value_set_enum(value, int(s.blend)); break;
    case PROP_BANDS: g_value_set_int(value, s.bands); break;
    case PROP_SEAM: g_value_set_enum(value, int(s.seam)); break;
    case PROP_DEBUG: g_value_set_flags(value, self->state->debug); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
  GST_OBJECT_UNLOCK(self);
}

static void gst_stitch_blend_finalize(GObject* object) {
  GstStitchBlend* self = GST_STITCH_BLEND(object);
  self->state->clear();
  delete self->state;
  G_OBJECT_CLASS(gst_stitch_blend_parent_class)->finalize(object);
}

static void gst_stitch_blend_class_init(GstStitchBlendClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  GstBaseTransformClass* trans_class = GST_BASE_TRANSFORM_CLASS(klass);
  const GParamFlags rw = GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS);

  gobject_class->set_property = gst_stitch_blend_set_property;
  gobject_class->get_property = gst_stitch_blend_get_property;
  gobject_class->finalize = gst_stitch_blend_finalize;

  g_object_class_install_property(gobject_class, PROP_OUTPUT_WIDTH,
      g_param_spec_int("output-width", "Output width",
                       "Panorama width in pixels (0: from the canvas; height alone keeps the aspect)",
                       0, 32766, 0, rw));
  g_object_class_install_property(gobject_class, PROP_OUTPUT_HEIGHT,
      g_param_spec_int("output-height", "Output height",
                       "Panorama height in pixels (0: from the canvas; width alone keeps the aspect)",
                       0, 32766, 0, rw));
  g_object_class_install_property(gobject_class, PROP_CROP,
      g_param_spec_enum("crop", "Crop", "Which part of the canvas is output", crop_get_type(),
                        int(DEFAULT_CROP), rw));
  g_object_class_install_property(gobject_class, PROP_BACKEND,
      g_param_spec_enum("backend", "Backend", "Implementation of warp and blend",
                        GST_TYPE_STITCH_BACKEND, int(stitch::Backend::Auto), rw));
  g_object_class_install_property(gobject_class, PROP_MODE,
      g_param_spec_enum("mode", "Mode",
                        "How overlapping views are fused: the position-weighted mean, or multiband (Laplacian "
                        "pyramid) blending, which mixes coarse structure over a wide band and detail over a "
                        "narrow one",
                        mode_get_type(), int(stitch::BlendMode::Weighted), rw));
  g_object_class_install_property(gobject_class, PROP_BANDS,
      g_param_spec_int("bands", "Bands",
                       "Pyramid levels of mode=multiband (fewer on small outputs: the coarsest level keeps "
                       "2 pixels); the widest band spreads over about 2^bands pixels",
                       1, 10, stitch::MultibandBlender::kDefaultBands, rw));
  g_object_class_install_property(gobject_class, PROP_SEAM,
      g_param_spec_enum("seam", "Seam",
                        "Where mode=multiband cuts each overlap between two views: its middle, or the path "
                        "that crosses the least color difference, edges and motion, kept near the last "
                        "frame's path so that it does not jump",
                        seam_get_type(), int(stitch::SeamMode::None), rw));
  g_object_class_install_property(gobject_class, PROP_DEBUG,
      g_param_spec_flags("debug", "Debug view",
                         "Draws onto the panorama why it looks the way it does: each view's outline, the "
                         "overlaps, the seams, and what stitchflowwarp's flow did in each overlap (e.g. "
                         "debug=outlines+seams, debug=all). With CUDA memory the frame is drawn on the host.",
                         debug_get_type(), 0, GParamFlags(rw | GST_PARAM_MUTABLE_PLAYING)));

  gst_element_class_add_static_pad_template(element_class, &sink_template);
  gst_element_class_add_static_pad_template(element_class, &src_template);
  gst_element_class_set_static_metadata(element_class, "Stitch blend", "Filter/Editor/Video",
      "Warps the views of a calibrated stitch bundle onto the canvas and fuses them into one "
      "panorama (position-weighted mean, or multiband with optional seam finding)",
      "gst-stitch developers");

  trans_class->transform_caps = GST_DEBUG_FUNCPTR(gst_stitch_blend_transform_caps);
  trans_class->fixate_caps = GST_DEBUG_FUNCPTR(gst_stitch_blend_fixate_caps);
  trans_class->set_caps = GST_DEBUG_FUNCPTR(gst_stitch_blend_set_caps);
  trans_class->prepare_output_buffer = GST_DEBUG_FUNCPTR(gst_stitch_blend_prepare_output_buffer);
  trans_class->transform = GST_DEBUG_FUNCPTR(gst_stitch_blend_transform);
  trans_class->transform_meta = GST_DEBUG_FUNCPTR(gst_stitch_blend_transform_meta);
  trans_class->stop = GST_DEBUG_FUNCPTR(gst_stitch_blend_stop);
  element_class->set_context = GST_DEBUG_FUNCPTR(gst_stitch_blend_set_context);
  trans_class->query = GST_DEBUG_FUNCPTR(gst_stitch_blend_query);
  trans_class->passthrough_on_same_caps = FALSE;

  gst_type_mark_as_plugin_api(crop_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(mode_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(seam_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(debug_get_type(), GstPluginAPIFlags(0));
  GST_DEBUG_CATEGORY_INIT(gst_stitch_blend_debug, "stitchblend", 0, "stitch blend");
}

static void gst_stitch_blend_init(GstStitchBlend* self) {
  self->state = new BlendState();
  gst_video_info_init(&self->state->out_info);
}
