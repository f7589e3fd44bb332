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
 * `seam=dp` (the default) moves the cut, frame by frame, along the path of least color
 * difference, edges and motion through each overlap (dynamic programming), held until something
 * crosses it. With the weighted mean, `seam=dp` is the consensus blend: where the two views
 * agree (the background of a calibrated rig) the output is their weighted mean, where they
 * disagree (a near object in one view, its parallax copy or the background in the other) it is
 * the view on the seam's side, so a near object comes whole from one view instead of as two
 * half-transparent ghosts; `seam=none` gives the paper's weighted mean everywhere. Both run on
 * the GPU where the blend does.
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

#include <algorithm>
#include <cmath>

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

enum {
  PROP_0,
  PROP_OUTPUT_WIDTH,
  PROP_OUTPUT_HEIGHT,
  PROP_CROP,
  PROP_BACKEND,
  PROP_MODE,
  PROP_BANDS,
  PROP_SEAM,
  PROP_DEBUG,
  PROP_MEMORY_LIMIT
};

#define DEFAULT_CROP stitch::CropMode::None
/* The consensus blend (issue 16, BENCHMARKS.md "Parallax: the consensus blend"): with the
 * weighted mean, seams give each near object to one view; with multiband, they cut its masks. */
#define DEFAULT_SEAM stitch::SeamMode::DynamicProgramming

struct BlendState {
  /* settings (object lock) */
  stitch::CompositorSettings settings;
  bool settings_changed = true;
  guint debug = 0; /* stitch::DebugFlags */
  guint memory_limit_mib = 0; /* 0: half the physical memory */
  /* state (streaming thread) */
  StitchCudaOwned<stitch::Compositor> compositor;
  guint64 rig_version = G_MAXUINT64;
  std::vector<std::array<int, 2>> camera_sizes; /* of the rig the compositor was made for */
  GstVideoInfo out_info;
  GstBufferPool* pool = nullptr;
  /* set_caps took a panorama size other than the compositor's (downstream renegotiated): the
   * next bundle fits the panorama into it, so that the pool, the caps and the frame agree */
  bool refit = false;
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
      /* the pixel aspect ratio too: fixate_caps sets square pixels, or says why it cannot */
      gst_structure_remove_fields(s, "multiview-mode", "views", "multiview-flags", "pixel-aspect-ratio", NULL);
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

/* Whether some structure of `caps` takes square pixels (no pixel-aspect-ratio, or one that may be 1/1). */
static bool takes_square_pixels(GstCaps* caps) {
  for (guint i = 0; i < gst_caps_get_size(caps); ++i) {
    GstStructure* s = gst_structure_copy(gst_caps_get_structure(caps, i));
    gint n = 1, d = 1;
    if (gst_structure_has_field(s, "pixel-aspect-ratio")) {
      gst_structure_fixate_field_nearest_fraction(s, "pixel-aspect-ratio", 1, 1);
      gst_structure_get_fraction(s, "pixel-aspect-ratio", &n, &d);
    }
    gst_structure_free(s);
    if (n == d) return true;
  }
  return false;
}

static GstCaps* gst_stitch_blend_fixate_caps(GstBaseTransform* trans, GstPadDirection direction,
                                             GstCaps* caps, GstCaps* othercaps) {
  GstStitchBlend* self = GST_STITCH_BLEND(trans);
  if (direction == GST_PAD_SINK && !gst_caps_is_empty(othercaps) && !takes_square_pixels(othercaps)) {
    /* probe6: `stitchblend ! video/x-raw,pixel-aspect-ratio=4/3` failed as "not-negotiated" in the
     * demuxers upstream, naming no element of ours */
    gchar* theirs = gst_caps_to_string(othercaps);
    GST_ELEMENT_ERROR(self, CORE, NEGOTIATION,
                      ("Downstream takes no square pixels (pixel-aspect-ratio 1/1), and the panorama has them: put "
                       "videoscale after stitchblend"),
                      ("downstream caps: %s", theirs));
    g_free(theirs);
  }
  /* Prefer CUDA memory wherever downstream takes it, whatever order it lists it in. */
  othercaps = stitch_caps_prefer_cuda(othercaps, TRUE);
  if (direction != GST_PAD_SINK) return gst_caps_fixate(gst_caps_truncate(othercaps));
  {
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
    /* Downstream may list a size it prefers before the range it takes (videoscale asked for
     * 640x360): truncating first replaced the panorama's size with videoscale's preference on
     * renegotiation, and the frames no longer matched the caps. */
    GstStructure* ours = gst_structure_new("video/x-raw", "width", G_TYPE_INT, MAX(w, 2), "height", G_TYPE_INT,
                                           MAX(h, 2), NULL);
    othercaps = stitch_caps_first_holding(othercaps, ours);
    gst_structure_free(ours);
    GstStructure* out = gst_caps_get_structure(othercaps, 0);
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
  if (!gst_video_info_from_caps(&st->out_info, outcaps)) return FALSE;
  /* A panorama size other than the one made (downstream renegotiated to a size it fixes): the
   * next bundle fits the panorama into it; frames of the old size must never go out with these caps. */
  if (st->compositor && st->compositor->prepared() &&
      (st->compositor->geometry().width != GST_VIDEO_INFO_WIDTH(&st->out_info) ||
       st->compositor->geometry().height != GST_VIDEO_INFO_HEIGHT(&st->out_info))) {
    GST_INFO_OBJECT(self, "downstream renegotiated the panorama to %dx%d (it was %dx%d): fitting it in",
                    GST_VIDEO_INFO_WIDTH(&st->out_info), GST_VIDEO_INFO_HEIGHT(&st->out_info),
                    st->compositor->geometry().width, st->compositor->geometry().height);
    st->refit = true;
  }
  return TRUE;
}

static void gst_stitch_blend_set_context(GstElement* element, GstContext* context) {
  GST_STITCH_BLEND(element)->state->cuda.set_context(element, context);
  GST_ELEMENT_CLASS(gst_stitch_blend_parent_class)->set_context(element, context);
}

/* stitchcalib asks what panorama will come out, to shrink the canvas to it: output-width/-height,
 * else the size downstream fixes (a capsfilter), else 0 (the canvas's). */
static gboolean answer_output_size(GstStitchBlend* self, GstQuery* query) {
  GST_OBJECT_LOCK(self);
  gint w = self->state->settings.output_width, h = self->state->settings.output_height;
  const gint crop = int(self->state->settings.crop);
  GST_OBJECT_UNLOCK(self);
  if (w <= 0 && h <= 0) {
    /* a size downstream fixes: every structure it takes has that one size. A size it merely
     * lists first (videoscale asked for 640x360 takes any size; a tee with such a branch) is a
     * preference: the panorama is made whole and scaled there. */
    GstCaps* peer = gst_pad_peer_query_caps(GST_BASE_TRANSFORM_SRC_PAD(self), NULL);
    gint fw = 0, fh = 0;
    bool fixed = peer && !gst_caps_is_any(peer) && !gst_caps_is_empty(peer);
    for (guint i = 0; fixed && i < gst_caps_get_size(peer); ++i) {
      const GstStructure* st = gst_caps_get_structure(peer, i);
      gint cw = 0, ch = 0;
      fixed = gst_structure_get_int(st, "width", &cw) && gst_structure_get_int(st, "height", &ch) &&
              (i == 0 || (cw == fw && ch == fh));
      fw = cw;
      fh = ch;
    }
    if (fixed) {
      w = fw;
      h = fh;
    }
    if (peer) gst_caps_unref(peer);
  }
  return stitch_output_size_query_answer(query, MAX(w, 0), MAX(h, 0), crop);
}

static gboolean gst_stitch_blend_query(GstBaseTransform* trans, GstPadDirection direction, GstQuery* query) {
  if (GST_STITCH_BLEND(trans)->state->cuda.handle_query(GST_ELEMENT(trans), query)) return TRUE;
  if (direction == GST_PAD_SINK && GST_QUERY_TYPE(query) == GST_QUERY_CUSTOM &&
      answer_output_size(GST_STITCH_BLEND(trans), query))
    return TRUE;
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_blend_parent_class)->query(trans, direction, query);
}

/* Caps of a width x height panorama in the negotiated memory. */
static GstCaps* panorama_caps(const BlendState* st, gint width, gint height) {
  GstVideoInfo info = st->out_info;
  gst_video_info_set_format(&info, GST_VIDEO_FORMAT_RGBA, width, height);
  info.fps_n = st->out_info.fps_n;
  info.fps_d = st->out_info.fps_d;
  info.par_n = info.par_d = 1;
  GstCaps* caps = gst_video_info_to_caps(&info);
  if (st->out_cuda) gst_caps_set_features(caps, 0, gst_caps_features_new(STITCH_CAPS_FEATURE_CUDA_MEMORY, NULL));
  return caps;
}

/* Whether downstream takes `caps`: accept-caps alone is answered from a transform's template (a
 * videoconvert between, as in stitchbin, takes any size), so downstream of it is asked too. */
static gboolean downstream_takes(GstPad* src, GstCaps* caps) {
  if (!gst_pad_peer_query_accept_caps(src, caps)) return FALSE;
  GstCaps* peer = gst_pad_peer_query_caps(src, caps);
  const gboolean takes = peer && !gst_caps_is_empty(peer);
  if (peer) gst_caps_unref(peer);
  return takes;
}

/* The panorama downstream takes: `g` when it accepts that size; otherwise the size it fixes
 * (a capsfilter, a sink of one size), or the one nearest `g` in its range, with the panorama
 * fitted inside, centred, at its own aspect (letterboxed, as output-width and output-height set
 * together do). FALSE after an element error when downstream takes no panorama we can make. */
static gboolean fit_downstream(GstStitchBlend* self, const stitch::Rig& rig, stitch::CompositorSettings& settings,
                               stitch::OutputGeometry& g) {
  BlendState* st = self->state;
  if (g.width == GST_VIDEO_INFO_WIDTH(&st->out_info) && g.height == GST_VIDEO_INFO_HEIGHT(&st->out_info)) return TRUE;
  GstPad* src = GST_BASE_TRANSFORM_SRC_PAD(self);
  GstCaps* natural = panorama_caps(st, g.width, g.height);
  const gboolean accepted = !gst_pad_is_linked(src) || downstream_takes(src, natural);
  if (accepted) {
    gst_caps_unref(natural);
    return TRUE;
  }
  GstCaps* any_size = gst_caps_copy(natural);
  gst_structure_remove_fields(gst_caps_get_structure(any_size, 0), "width", "height", NULL);
  GstCaps* peer = gst_pad_peer_query_caps(src, any_size);
  gst_caps_unref(any_size);
  gint w = 0, h = 0;
  if (!gst_caps_is_empty(peer) && !gst_caps_is_any(peer)) {
    peer = gst_caps_truncate(peer);
    GstStructure* s = gst_caps_get_structure(peer, 0);
    /* a side downstream leaves open may be absent altogether (`video/x-raw,width=1001`) */
    if (!gst_structure_has_field(s, "width")) gst_structure_set(s, "width", G_TYPE_INT, g.width, NULL);
    gst_structure_fixate_field_nearest_int(s, "width", g.width);
    gst_structure_get_int(s, "width", &w);
    const int aspect_height = w > 0 ? int(double(g.height) * w / g.width + 0.5) : 0;
    if (w > 0 && !gst_structure_has_field(s, "height")) gst_structure_set(s, "height", G_TYPE_INT, aspect_height, NULL);
    if (w > 0) gst_structure_fixate_field_nearest_int(s, "height", aspect_height);
    gst_structure_get_int(s, "height", &h);
  }
  stitch::OutputGeometry fitted;
  GstCaps* fitted_caps = nullptr;
  if (w > 0 && h > 0) {
    /* exactly the size downstream takes, odd or not (RGBA has no 4:2:0 constraint; probe6: a
     * capsfilter's 1001x333 was refused because our own sizes are rounded to even ones) */
    fitted = stitch::plan_output(rig, w, h, settings.crop, /*exact_size=*/true);
    fitted_caps = panorama_caps(st, fitted.width, fitted.height);
  }
  const gboolean ok = fitted_caps && fitted.width == w && fitted.height == h &&
                      downstream_takes(src, fitted_caps);
  if (ok) {
    GST_INFO_OBJECT(self, "downstream takes no %dx%d panorama: fitted into its %dx%d", g.width, g.height, w, h);
    settings.output_width = w;
    settings.output_height = h;
    settings.exact_output_size = true;
    g = fitted;
  } else {
    gchar* theirs = gst_caps_to_string(peer);
    GST_ELEMENT_ERROR(self, CORE, NEGOTIATION,
                      ("Downstream takes neither the %dx%d panorama nor a size stitchblend can fit it into: put "
                       "videoconvert ! videoscale after stitchblend, or set output-width/output-height",
                       g.width, g.height),
                      ("downstream caps: %s", theirs));
    g_free(theirs);
  }
  gst_caps_unref(peer);
  gst_caps_unref(natural);
  if (fitted_caps) gst_caps_unref(fitted_caps);
  return ok;
}

/* Working memory of a panorama, estimated before anything is allocated: the pooled output
 * frames, and per pixel of each view's rectangle its warp maps, warped copy and weight;
 * multiband adds its float pyramids and seam finding its costs; pre-warped views are fused on
 * the canvas, then resampled. Bytes per pixel measured on the CPU path (BENCHMARKS.md). */
static guint64 estimate_memory(const stitch::Rig& rig, const stitch::OutputGeometry& g,
                               const stitch::CompositorSettings& s, bool prewarped) {
  const stitch::OutputGeometry blend_geometry = prewarped ? stitch::canvas_geometry(rig) : g;
  guint64 view_pixels = 0;
  for (const auto& v : stitch::place_views(rig, blend_geometry))
    view_pixels += guint64(std::max(v.roi.width, 0)) * guint64(std::max(v.roi.height, 0));
  const guint64 blend_pixels = guint64(blend_geometry.width) * guint64(blend_geometry.height);
  guint64 per_view = 16, per_blend = 8;
  if (s.blend == stitch::BlendMode::Multiband) {
    per_view += 48;
    per_blend += 48;
    if (s.seam != stitch::SeamMode::None) per_view += 12;
  }
  return guint64(g.width) * guint64(g.height) * 4 * 3 + view_pixels * per_view + blend_pixels * per_blend;
}

/* Rebuilds the compositor when the rig or the settings changed; renegotiates the output. */
static gboolean update_geometry(GstStitchBlend* self, GstStitchRigMeta* meta, GstStitchWarpMeta* warped) {
  BlendState* st = self->state;
  const stitch::CompositorInput input =
      warped ? stitch::CompositorInput::Prewarped : stitch::CompositorInput::CameraFrames;
  GST_OBJECT_LOCK(self);
  const bool settings_changed = st->settings_changed;
  const stitch::CompositorSettings settings = st->settings;
  const guint memory_limit_mib = st->memory_limit_mib;
  st->settings_changed = false;
  GST_OBJECT_UNLOCK(self);
  const bool refit = st->refit;
  st->refit = false;
  if (st->compositor && meta->version == st->rig_version && !settings_changed && !refit &&
      st->compositor->input() == input)
    return TRUE;

  stitch::CompositorSettings effective = settings;
  std::vector<std::array<int, 2>> camera_sizes;
  for (const auto& c : (*meta->rig)->cameras) camera_sizes.push_back({c.width, c.height});
  if (st->compositor && !settings_changed && camera_sizes == st->camera_sizes) {
    /* A recalibration keeps the panorama size: encoders and muxers downstream rarely accept
     * a new resolution mid-stream. The new canvas is fitted into the same frame (stitchcalib
     * already fits it, so that its canvas stays the panorama size). Other cameras (one left,
     * or changed resolution) were calibrated from scratch: their canvas is the panorama. */
    effective.output_width = st->compositor->geometry().width;
    effective.output_height = st->compositor->geometry().height;
    effective.exact_output_size = true;  /* it may be a size downstream fixed, odd */
  }
  if (refit) {
    /* the size downstream renegotiated to: the panorama is fitted into it (letterboxed) */
    effective.output_width = GST_VIDEO_INFO_WIDTH(&st->out_info);
    effective.output_height = GST_VIDEO_INFO_HEIGHT(&st->out_info);
    effective.exact_output_size = true;
  }
  const bool device_memory = st->in_cuda || st->out_cuda;
  if (device_memory && settings.backend == stitch::Backend::Cpu)
    throw std::runtime_error("backend=cpu cannot read or write CUDA memory: put cudadownload around stitchblend, or use backend=auto");
  const stitch::Rig& rig = **meta->rig;
  if (!rig.calibrated()) throw stitch::RigError("the rig carries no calibration (homographies and canvas)");
  /* The size first, then the memory: nothing is allocated for a panorama that cannot be. */
  stitch::OutputGeometry planned = stitch::plan_output(rig, effective.output_width, effective.output_height, effective.crop,
                                                       effective.exact_output_size);
  if (!fit_downstream(self, rig, effective, planned)) return FALSE;
  const guint64 bytes = estimate_memory(rig, planned, effective, warped != nullptr);
  std::string too_big;
  if (!stitch_check_frame_size("the panorama", planned.width, planned.height, bytes,
                               stitch_memory_budget(memory_limit_mib), too_big)) {
    /* the largest size of this aspect that fits */
    double scale = std::min(1.0, std::min(double(STITCH_MAX_FRAME_SIDE - 1) / planned.width,
                                          double(STITCH_MAX_FRAME_SIDE - 1) / planned.height));
    const guint64 budget = stitch_memory_budget(memory_limit_mib);
    if (bytes > budget) scale = std::min(scale, 0.95 * std::sqrt(double(budget) / double(bytes)));
    const int w = std::max(2, int(planned.width * scale) / 2 * 2), h = std::max(2, int(planned.height * scale) / 2 * 2);
    GST_ELEMENT_ERROR(self, STREAM, FAILED,
                      ("stitchblend: %s: set a smaller output-width/output-height (e.g. output-width=%d "
                       "output-height=%d)%s",
                       too_big.c_str(), w, h, bytes > budget ? " or raise memory-limit" : ""),
                      ("canvas %dx%d, output-width=%d output-height=%d", rig.canvas_width, rig.canvas_height,
                       effective.output_width, effective.output_height));
    return FALSE;
  }
  GST_INFO_OBJECT(self, "panorama %dx%d: estimated working memory %" G_GUINT64_FORMAT " MiB", planned.width,
                  planned.height, bytes >> 20);
  st->compositor.make(st->cuda, [&]() {
    auto c = std::make_unique<stitch::Compositor>(device_memory ? stitch::Backend::Cuda : settings.backend);
    c->prepare(rig, effective, input);
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
  st->camera_sizes = camera_sizes;
  if (g.width != GST_VIDEO_INFO_WIDTH(&st->out_info) || g.height != GST_VIDEO_INFO_HEIGHT(&st->out_info)) {
    GstCaps* caps = panorama_caps(st, g.width, g.height);
    GST_INFO_OBJECT(self, "panorama is %dx%d%s", g.width, g.height, st->out_cuda ? " in CUDA memory" : "");
    const gboolean ok = gst_base_transform_update_src_caps(GST_BASE_TRANSFORM(self), caps);
    if (!ok || !gst_video_info_from_caps(&st->out_info, caps)) {
      gst_caps_unref(caps);
      GST_ELEMENT_ERROR(self, CORE, NEGOTIATION,
                        ("Downstream refused the %dx%d panorama (add videoscale/videoconvert, or "
                         "set output-width/output-height)", g.width, g.height),
                        (NULL));
      return FALSE;
    }
    gst_caps_unref(caps);
  }
  stitch_bundle_pool_clear(&st->pool);
  GstCaps* caps = panorama_caps(st, GST_VIDEO_INFO_WIDTH(&st->out_info), GST_VIDEO_INFO_HEIGHT(&st->out_info));
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

/* The panorama's geometry (and size) is settled before GstBaseTransform renegotiates for the
 * bundle: a new size set with update_src_caps is then negotiated, allocation query included,
 * before the first panorama of that size goes out. Settled later (in prepare_output_buffer), the
 * allocation query came with the second panorama, while a sink behind a tee and a queue had
 * prerolled on the first and another branch (videorate) was still waiting for its second: the
 * query could never be answered and the pipeline hung in PAUSED. */
static GstFlowReturn gst_stitch_blend_submit_input_buffer(GstBaseTransform* trans, gboolean is_discont,
                                                          GstBuffer* input) {
  GstStitchBlend* self = GST_STITCH_BLEND(trans);
  GstStitchRigMeta* meta = gst_buffer_get_stitch_rig_meta(input);
  if (meta && meta->rig && *meta->rig && gst_pad_has_current_caps(GST_BASE_TRANSFORM_SINK_PAD(trans))) {
    gboolean ok = FALSE;
    if (!stitch_guard(GST_ELEMENT(self), "stitchblend: cannot build the panorama geometry",
                      [&]() { ok = update_geometry(self, meta, gst_buffer_get_stitch_warp_meta(input)); }) ||
        !ok) {
      gst_buffer_unref(input);
      return GST_FLOW_ERROR;
    }
  }
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_blend_parent_class)->submit_input_buffer(trans, is_discont, input);
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
  /* flags, timestamps and the metas that transform_meta keeps */
  GST_BASE_TRANSFORM_CLASS(gst_stitch_blend_parent_class)->copy_metadata(trans, input, *outbuf);
  return GST_FLOW_OK;
}

static GstFlowReturn gst_stitch_blend_transform(GstBaseTransform* trans, GstBuffer* inbuf,
                                                GstBuffer* outbuf) {
  GstStitchBlend* self = GST_STITCH_BLEND(trans);
  BlendState* st = self->state;
  GstStitchRigMeta* meta = gst_buffer_get_stitch_rig_meta(inbuf);
  const guint n_views = guint((*meta->rig)->cameras.size());
  StitchCudaHandoff handoff(st->cuda);  /* waits on the bundle's events; the panorama is synchronised */
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
  /* the panorama leaves our elements: the host waits for it here (srcpad NULL) */
  const gboolean handed = ok && handoff.finish(GST_ELEMENT(self), outbuf, NULL);
  gst_video_frame_unmap(&out);
  return handed ? GST_FLOW_OK : GST_FLOW_ERROR;
}

static gboolean gst_stitch_blend_transform_meta(GstBaseTransform*, GstBuffer*, GstMeta* meta,
                                                GstBuffer*) {
  /* Views, rig and bundle metas describe the input bundle, not the panorama. */
  return stitch_meta_survives_new_views(meta);
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
    case PROP_MEMORY_LIMIT:
      self->state->memory_limit_mib = g_value_get_uint(value);
      GST_OBJECT_UNLOCK(self);
      return; /* checked at the next rebuild */
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
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
    case PROP_MEMORY_LIMIT: g_value_set_uint(value, self->state->memory_limit_mib); break;
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

static gboolean gst_stitch_blend_sink_event(GstBaseTransform* trans, GstEvent* event) {
  switch (GST_EVENT_TYPE(event)) {
    case GST_EVENT_FLUSH_STOP:
    case GST_EVENT_SEGMENT: { /* a seek or a new stream: the seams' history (last path, last
                               * frame's luma) no longer applies; the compositor is rebuilt */
      GstStitchBlend* self = GST_STITCH_BLEND(trans);
      GST_OBJECT_LOCK(self);
      self->state->settings_changed = true;
      GST_OBJECT_UNLOCK(self);
      break;
    }
    default: break;
  }
  return GST_BASE_TRANSFORM_CLASS(gst_stitch_blend_parent_class)->sink_event(trans, event);
}

static void gst_stitch_blend_class_init(GstStitchBlendClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  GstBaseTransformClass* trans_class = GST_BASE_TRANSFORM_CLASS(klass);
  const GParamFlags rw = GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS);
  /* a change while playing rebuilds the compositor at the next bundle (a new size renegotiates) */
  const GParamFlags playing = GParamFlags(rw | GST_PARAM_MUTABLE_PLAYING);

  gobject_class->set_property = gst_stitch_blend_set_property;
  gobject_class->get_property = gst_stitch_blend_get_property;
  gobject_class->finalize = gst_stitch_blend_finalize;

  g_object_class_install_property(gobject_class, PROP_OUTPUT_WIDTH,
      g_param_spec_int("output-width", "Output width",
                       "Panorama width in pixels (0: from the canvas; height alone keeps the aspect; both "
                       "fit the panorama inside, centred). A downstream that fixes the size (a capsfilter) "
                       "gets the panorama fitted the same way",
                       0, 32766, 0, playing));
  g_object_class_install_property(gobject_class, PROP_OUTPUT_HEIGHT,
      g_param_spec_int("output-height", "Output height",
                       "Panorama height in pixels (0: from the canvas; width alone keeps the aspect). A size "
                       "whose other side would exceed 32767 pixels, or the memory-limit, is refused before "
                       "anything is allocated",
                       0, 32766, 0, playing));
  g_object_class_install_property(gobject_class, PROP_CROP,
      g_param_spec_enum("crop", "Crop", "Which part of the canvas is output", crop_get_type(),
                        int(DEFAULT_CROP), playing));
  g_object_class_install_property(gobject_class, PROP_BACKEND,
      g_param_spec_enum("backend", "Backend",
                        "Where warp and blend run: auto: on the GPU when a CUDA device opens, else on the CPU; "
                        "cpu: on the CPU, in system memory; cuda: on the GPU, or an error when no device opens",
                        GST_TYPE_STITCH_BACKEND, int(stitch::Backend::Auto), GParamFlags(rw | GST_PARAM_MUTABLE_READY)));
  g_object_class_install_property(gobject_class, PROP_MODE,
      g_param_spec_enum("mode", "Mode",
                        "How overlapping views are fused: the position-weighted mean, or multiband (Laplacian "
                        "pyramid) blending, which mixes coarse structure over a wide band and detail over a "
                        "narrow one",
                        mode_get_type(), int(stitch::BlendMode::Weighted), playing));
  g_object_class_install_property(gobject_class, PROP_BANDS,
      g_param_spec_int("bands", "Bands",
                       "Pyramid levels of mode=multiband (fewer on small outputs: the coarsest level keeps "
                       "2 pixels); the widest band spreads over about 2^bands pixels",
                       1, 10, stitch::MultibandBlender::kDefaultBands, playing));
  g_object_class_install_property(gobject_class, PROP_SEAM,
      g_param_spec_enum("seam", "Seam",
                        "Where each overlap is cut between two views: none: its middle (multiband), or no cut "
                        "(the weighted mean everywhere); dp: the path that crosses the least color difference, "
                        "edges and motion, held until something crosses it. With mode=weighted, dp is the "
                        "consensus blend: the weighted mean where the views agree, the view on the seam's "
                        "side where they disagree (a near object comes whole from one view instead of as two "
                        "ghosts); it expects color-matched views (stitchcolor)",
                        seam_get_type(), int(DEFAULT_SEAM), playing));
  g_object_class_install_property(gobject_class, PROP_DEBUG,
      g_param_spec_flags("debug", "Debug view",
                         "Draws onto the panorama why it looks the way it does: each view's outline, the "
                         "overlaps, the seams, and what stitchflowwarp's flow did in each overlap (e.g. "
                         "debug=outlines+seams, debug=all). With CUDA memory the frame is drawn on the host.",
                         debug_get_type(), 0, GParamFlags(playing | GST_PARAM_CONTROLLABLE)));
  g_object_class_install_property(gobject_class, PROP_MEMORY_LIMIT,
      g_param_spec_uint("memory-limit", "Memory limit",
                        "MiB of working memory a panorama may take (output frames, warp maps, weights, "
                        "pyramids; estimated from the calibration before anything is allocated): a larger one "
                        "is refused with an error naming its size (0: half the physical memory)",
                        0, G_MAXUINT, 0, playing));

  gst_element_class_add_static_pad_template(element_class, &sink_template);
  gst_element_class_add_static_pad_template(element_class, &src_template);
  gst_element_class_set_static_metadata(element_class, "Stitch blend", "Filter/Converter/Video",
      "Warps the views of a calibrated stitch bundle onto the canvas and fuses them into one "
      "panorama (position-weighted mean, or multiband with optional seam finding)",
      "gst-stitch developers");

  trans_class->transform_caps = GST_DEBUG_FUNCPTR(gst_stitch_blend_transform_caps);
  trans_class->fixate_caps = GST_DEBUG_FUNCPTR(gst_stitch_blend_fixate_caps);
  trans_class->set_caps = GST_DEBUG_FUNCPTR(gst_stitch_blend_set_caps);
  trans_class->submit_input_buffer = GST_DEBUG_FUNCPTR(gst_stitch_blend_submit_input_buffer);
  trans_class->prepare_output_buffer = GST_DEBUG_FUNCPTR(gst_stitch_blend_prepare_output_buffer);
  trans_class->transform = GST_DEBUG_FUNCPTR(gst_stitch_blend_transform);
  trans_class->sink_event = GST_DEBUG_FUNCPTR(gst_stitch_blend_sink_event);
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
  self->state->settings.seam = DEFAULT_SEAM;
  gst_video_info_init(&self->state->out_info);
}
