/**
 * SECTION:element-stitch360sink
 * @title: stitch360sink
 *
 * Writes an MP4 file that players and video sites show as a 360-degree video: `mp4mux !
 * filesink` inside, and at EOS the file gains Google's Spherical Video metadata (V2 `st3d` +
 * `sv3d` { `svhd`, `proj` { `prhd`, `equi` } } in the video sample entry, and the V1 XML `uuid`
 * box in the video track), equirectangular and monoscopic. Feed it an encoded equirectangular
 * panorama (2:1, e.g. stitchblend's output of a full-sphere `projection=spherical` rig). The
 * muxer is the child `mux` (`stitch360sink mux::faststart=true` works: the chunk offsets are
 * fixed). Without EOS (gst-launch-1.0 without -e, interrupted) the MP4 is unfinished and gets no
 * metadata.
 *
 * ## Example launch lines
 * |[
 * gst-launch-1.0 -e videotestsrc num-buffers=30 ! video/x-raw,width=512,height=256,format=I420 ! \
 *   x264enc ! stitch360sink location=out360.mp4
 * ]|
 *
 * A full-sphere rig (e.g. back-to-back fisheyes, `"projection": "spherical"`) to a 360 file:
 * `stitchsync name=s ! stitchcalib load-file=dual_fisheye.json ! stitchblend ! videoconvert !
 * video/x-raw,format=I420 ! x264enc ! stitch360sink location=sphere.mp4` with the two cameras
 * linked to `s.sink_0` and `s.sink_1`.
 *
 * `projection=cubemap` marks a `"projection": "cubemap"` rig's 3x2 output (V2 `cbmp` layout 0;
 * V1 has no cubemap, so `metadata=both` writes V2 alone).
 */
#include "gststitch360sink.h"

#include <string>

#include "stitch/io/spherical_mp4.hpp"

GST_DEBUG_CATEGORY_STATIC(gst_stitch_360_sink_debug);
#define GST_CAT_DEFAULT gst_stitch_360_sink_debug

enum { PROP_0, PROP_LOCATION, PROP_METADATA, PROP_PROJECTION };

enum Stitch360Metadata { METADATA_BOTH = 0, METADATA_V2 = 1, METADATA_V1 = 2 };
#define DEFAULT_METADATA METADATA_BOTH

struct _GstStitch360Sink {
  GstBin parent;
  GstElement* mux;
  GstElement* sink;
  GstPad* ghost;
  gchar* location;  // settings
  int metadata;
  int projection;  // stitch::SphericalMetadata::Projection
};

G_DEFINE_TYPE(GstStitch360Sink, gst_stitch_360_sink, GST_TYPE_BIN);
GST_ELEMENT_REGISTER_DEFINE(stitch360sink, "stitch360sink", GST_RANK_NONE, GST_TYPE_STITCH_360_SINK);

static GType stitch_360_projection_get_type() {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::SphericalMetadata::Projection::Equirectangular), "Equirectangular (2:1 sphere, V2 equi + V1)",
       "equirectangular"},
      {int(stitch::SphericalMetadata::Projection::Cubemap),
       "Cubemap, 3x2 faces right left up / down front back (a \"cubemap\" rig; V2 cbmp layout 0, no V1)", "cubemap"},
      {0, nullptr, nullptr}};
  if (g_once_init_enter(&type)) g_once_init_leave(&type, g_enum_register_static("GstStitch360Projection", values));
  return type;
}

static GType stitch_360_metadata_get_type() {
  static GType type = 0;
  static const GEnumValue values[] = {
      {METADATA_BOTH, "Spherical Video V2 boxes and the V1 XML box", "both"},
      {METADATA_V2, "Spherical Video V2 boxes only (sv3d, st3d)", "v2"},
      {METADATA_V1, "Spherical Video V1 XML uuid box only", "v1"},
      {0, nullptr, nullptr}};
  if (g_once_init_enter(&type)) g_once_init_leave(&type, g_enum_register_static("GstStitch360Metadata", values));
  return type;
}

static GstStaticPadTemplate sink_template = GST_STATIC_PAD_TEMPLATE(
    "sink", GST_PAD_SINK, GST_PAD_ALWAYS,
    GST_STATIC_CAPS("video/x-h264, stream-format=(string){ avc, avc3 }, alignment=(string)au; "
                    "video/x-h265, stream-format=(string){ hvc1, hev1 }, alignment=(string)au; "
                    "video/x-vp9; video/x-av1; video/mpeg, mpegversion=(int)4, systemstream=(boolean)false"));

static void gst_stitch_360_sink_init(GstStitch360Sink* self) {
  self->metadata = DEFAULT_METADATA;
  self->projection = int(stitch::SphericalMetadata::Projection::Equirectangular);
  self->location = nullptr;
  self->mux = gst_element_factory_make("mp4mux", "mux");
  self->sink = gst_element_factory_make("filesink", "sink");
  if (!self->mux || !self->sink) {
    // Reported at the state change (missing plugins: isomp4 from gst-plugins-good, coreelements).
    if (self->mux) gst_object_unref(gst_object_ref_sink(self->mux));
    if (self->sink) gst_object_unref(gst_object_ref_sink(self->sink));
    self->mux = self->sink = nullptr;
    self->ghost = gst_ghost_pad_new_no_target_from_template("sink", gst_static_pad_template_get(&sink_template));
    gst_element_add_pad(GST_ELEMENT(self), self->ghost);
    return;
  }
  gst_bin_add_many(GST_BIN(self), self->mux, self->sink, nullptr);
  gst_element_link(self->mux, self->sink);
  GstPad* target = gst_element_request_pad_simple(self->mux, "video_%u");
  self->ghost = gst_ghost_pad_new_from_template("sink", target, gst_static_pad_template_get(&sink_template));
  gst_object_unref(target);
  gst_element_add_pad(GST_ELEMENT(self), self->ghost);
}

static void gst_stitch_360_sink_finalize(GObject* object) {
  GstStitch360Sink* self = GST_STITCH_360_SINK(object);
  g_free(self->location);
  G_OBJECT_CLASS(gst_stitch_360_sink_parent_class)->finalize(object);
}

static void gst_stitch_360_sink_set_property(GObject* object, guint id, const GValue* value, GParamSpec* pspec) {
  GstStitch360Sink* self = GST_STITCH_360_SINK(object);
  switch (id) {
    case PROP_LOCATION:
      GST_OBJECT_LOCK(self);
      g_free(self->location);
      self->location = g_value_dup_string(value);
      GST_OBJECT_UNLOCK(self);
      if (self->sink) g_object_set(self->sink, "location", g_value_get_string(value), nullptr);
      break;
    case PROP_METADATA:
      GST_OBJECT_LOCK(self);
      self->metadata = g_value_get_enum(value);
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_PROJECTION:
      GST_OBJECT_LOCK(self);
      self->projection = g_value_get_enum(value);
      GST_OBJECT_UNLOCK(self);
      break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, id, pspec);
  }
}

static void gst_stitch_360_sink_get_property(GObject* object, guint id, GValue* value, GParamSpec* pspec) {
  GstStitch360Sink* self = GST_STITCH_360_SINK(object);
  GST_OBJECT_LOCK(self);
  switch (id) {
    case PROP_LOCATION: g_value_set_string(value, self->location); break;
    case PROP_METADATA: g_value_set_enum(value, self->metadata); break;
    case PROP_PROJECTION: g_value_set_enum(value, self->projection); break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, id, pspec);
  }
  GST_OBJECT_UNLOCK(self);
}

// The panorama size from the negotiated caps (for the V1 FullPano* fields); 0 when unknown.
static void negotiated_size(GstStitch360Sink* self, int& w, int& h) {
  w = h = 0;
  GstCaps* caps = gst_pad_get_current_caps(self->ghost);
  if (!caps) return;
  const GstStructure* s = gst_caps_get_structure(caps, 0);
  gst_structure_get_int(s, "width", &w);
  gst_structure_get_int(s, "height", &h);
  gst_caps_unref(caps);
}

// At the file sink's EOS (the MP4 is complete and flushed): add the metadata, then let the bin
// post EOS. Failures become an element error; no exception leaves here.
static void gst_stitch_360_sink_handle_message(GstBin* bin, GstMessage* message) {
  GstStitch360Sink* self = GST_STITCH_360_SINK(bin);
  if (GST_MESSAGE_TYPE(message) == GST_MESSAGE_EOS && GST_MESSAGE_SRC(message) == GST_OBJECT(self->sink)) {
    GST_OBJECT_LOCK(self);
    const std::string location = self->location ? self->location : "";
    const int which = self->metadata;
    const int projection = self->projection;
    GST_OBJECT_UNLOCK(self);
    stitch::SphericalMetadata meta;
    meta.projection = stitch::SphericalMetadata::Projection(projection);
    if (which == METADATA_V1 && meta.projection == stitch::SphericalMetadata::Projection::Cubemap)
      GST_ELEMENT_WARNING(self, STREAM, FORMAT, ("metadata=v1 cannot describe a cubemap: the file gets no metadata"),
                          ("use metadata=v2 or both (V2 cbmp)"));
    meta.v1 = which != METADATA_V2;
    meta.v2 = which != METADATA_V1;
    negotiated_size(self, meta.source_width, meta.source_height);
    // The metadata says "this covers the sphere": a panorama of another shape is stretched over
    // it by every player (a 640x480 picture, a plane rig's panorama). Written anyway, said.
    const int w = meta.source_width, h = meta.source_height;
    const bool cubemap = meta.projection == stitch::SphericalMetadata::Projection::Cubemap;
    if (w > 0 && h > 0 && (cubemap ? 2 * w != 3 * h : w != 2 * h))
      GST_ELEMENT_WARNING(self, STREAM, FORMAT,
                          ("the panorama is %dx%d, not %s: 360 players will stretch it over the whole sphere", w, h,
                           cubemap ? "3:2 (a 3x2 cubemap)" : "2:1 (equirectangular)"),
                          ("stitch a full-sphere rig (projection spherical, covered pole to pole), or videoscale "
                           "to %s", cubemap ? "3:2" : "2:1"));
    std::string error;
    try {
      error = stitch::add_spherical_metadata(location, meta);
    } catch (const std::exception& e) {
      error = e.what();
    }
    if (!error.empty())
      GST_ELEMENT_ERROR(self, RESOURCE, WRITE, ("cannot add the spherical metadata to \"%s\": %s", location.c_str(),
                                                error.c_str()), (NULL));
    else
      GST_INFO_OBJECT(self, "spherical metadata written to %s", location.c_str());
  }
  GST_BIN_CLASS(gst_stitch_360_sink_parent_class)->handle_message(bin, message);
}

static GstStateChangeReturn gst_stitch_360_sink_change_state(GstElement* element, GstStateChange transition) {
  GstStitch360Sink* self = GST_STITCH_360_SINK(element);
  if (transition == GST_STATE_CHANGE_NULL_TO_READY) {
    if (!self->mux) {
      GST_ELEMENT_ERROR(self, CORE, MISSING_PLUGIN, ("stitch360sink needs mp4mux (gst-plugins-good) and filesink"),
                        (NULL));
      return GST_STATE_CHANGE_FAILURE;
    }
    if (!self->location || !*self->location) {
      GST_ELEMENT_ERROR(self, RESOURCE, NOT_FOUND, ("stitch360sink: set location"), (NULL));
      return GST_STATE_CHANGE_FAILURE;
    }
  }
  return GST_ELEMENT_CLASS(gst_stitch_360_sink_parent_class)->change_state(element, transition);
}

static void gst_stitch_360_sink_class_init(GstStitch360SinkClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  GstBinClass* bin_class = GST_BIN_CLASS(klass);
  gobject_class->set_property = gst_stitch_360_sink_set_property;
  gobject_class->get_property = gst_stitch_360_sink_get_property;
  gobject_class->finalize = gst_stitch_360_sink_finalize;
  g_object_class_install_property(
      gobject_class, PROP_LOCATION,
      g_param_spec_string("location", "Location", "The MP4 file to write", nullptr,
                          GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS | GST_PARAM_MUTABLE_READY)));
  g_object_class_install_property(
      gobject_class, PROP_METADATA,
      g_param_spec_enum("metadata", "Metadata", "Which Spherical Video metadata to write", stitch_360_metadata_get_type(),
                        DEFAULT_METADATA,
                        GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS | GST_PARAM_MUTABLE_READY)));
  g_object_class_install_property(
      gobject_class, PROP_PROJECTION,
      g_param_spec_enum("projection", "Projection",
                        "The panorama's projection: equirectangular (a spherical rig) or cubemap (a cubemap rig)",
                        stitch_360_projection_get_type(), int(stitch::SphericalMetadata::Projection::Equirectangular),
                        GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS | GST_PARAM_MUTABLE_READY)));
  element_class->change_state = gst_stitch_360_sink_change_state;
  bin_class->handle_message = gst_stitch_360_sink_handle_message;
  gst_element_class_add_static_pad_template(element_class, &sink_template);
  gst_element_class_set_static_metadata(element_class, "Stitch 360 MP4 sink", "Sink/File/Video",
                                        "Writes an MP4 with Spherical Video (V1 and V2) metadata: an equirectangular "
                                        "360-degree video that players recognise",
                                        "gst-stitch");
  gst_type_mark_as_plugin_api(stitch_360_metadata_get_type(), GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(stitch_360_projection_get_type(), GstPluginAPIFlags(0));
  GST_DEBUG_CATEGORY_INIT(gst_stitch_360_sink_debug, "stitch360sink", 0, "360-degree MP4 sink");
}
