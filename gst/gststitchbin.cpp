/**
 * SECTION:element-stitchbin
 * @title: stitchbin
 *
 * The whole stitching chain in one element: `stitchsync ! stitchcalib ! stitchcolor !
 * stitchflowwarp ! stitchblend`. Its request pads `sink_%u` take the cameras (they are
 * stitchsync's pads, ghosted); its source pad gives the panorama. The children's main
 * properties are the bin's own, under the same names (`backend` is set on every child); the
 * `recalibrate` action signal is stitchcalib's. The children are named sync, calib, color,
 * flowwarp and blend: gst_bin_get_by_name() finds them, and the properties not proxied here are
 * set through them (GstChildProxy), e.g. `stitchbin calib::features=orb color::window=5`.
 *
 * ## Example launch lines
 * |[
 * gst-launch-1.0 stitchbin name=s rig-file=examples/limlight_rig.json ! videoconvert ! autovideosink \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * |[
 * gst-launch-1.0 -e stitchbin name=s mode=multiband seam=dp crop=auto ! videoconvert ! x264enc ! \
 *   mp4mux ! filesink location=pano.mp4 \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 */
#include "gststitchbin.h"

#include <string>
#include <vector>

GST_DEBUG_CATEGORY_STATIC(gst_stitch_bin_debug);
#define GST_CAT_DEFAULT gst_stitch_bin_debug

namespace {

// The chain, in order: (child name, factory).
constexpr const char* kChildren[][2] = {{"sync", "stitchsync"},
                                        {"calib", "stitchcalib"},
                                        {"color", "stitchcolor"},
                                        {"flowwarp", "stitchflowwarp"},
                                        {"blend", "stitchblend"}};
constexpr int kSync = 0, kCalib = 1, kBlend = 4;
constexpr int kAllChildren = -1;

// Proxied properties: the bin's property of this name is child `child`'s (or every child's).
struct Proxy {
  const char* name;
  int child;
};
constexpr Proxy kProxies[] = {
    {"framerate", kSync},          {"input-eos", kSync},
    {"latency", kSync},            {"rig-file", kCalib},
    {"load-file", kCalib},         {"save-file", kCalib},
    {"refine", kCalib},            {"recalibrate-interval", kCalib},
    {"method", 2},                 {"smoothing", 2},
    {"flow", 3},                   {"quality", 3},
    {"output-width", kBlend},      {"output-height", kBlend},
    {"crop", kBlend},              {"mode", kBlend},
    {"bands", kBlend},             {"seam", kBlend},
    {"debug", kBlend},
    {"backend", kAllChildren},
};

// A copy of a child's property spec under the same name, for the bin.
GParamSpec* clone_pspec(GParamSpec* p) {
  const GParamFlags flags = GParamFlags((p->flags & (G_PARAM_READWRITE)) | G_PARAM_STATIC_STRINGS);
  const char *name = g_param_spec_get_name(p), *nick = g_param_spec_get_nick(p), *blurb = g_param_spec_get_blurb(p);
  const GType t = G_PARAM_SPEC_TYPE(p);
  if (t == G_TYPE_PARAM_ENUM) {
    GParamSpecEnum* e = G_PARAM_SPEC_ENUM(p);
    return g_param_spec_enum(name, nick, blurb, G_TYPE_FROM_CLASS(e->enum_class), e->default_value, flags);
  }
  if (t == G_TYPE_PARAM_FLAGS) {
    GParamSpecFlags* f = G_PARAM_SPEC_FLAGS(p);
    return g_param_spec_flags(name, nick, blurb, G_TYPE_FROM_CLASS(f->flags_class), f->default_value, flags);
  }
  if (t == G_TYPE_PARAM_BOOLEAN)
    return g_param_spec_boolean(name, nick, blurb, G_PARAM_SPEC_BOOLEAN(p)->default_value, flags);
  if (t == G_TYPE_PARAM_STRING)
    return g_param_spec_string(name, nick, blurb, G_PARAM_SPEC_STRING(p)->default_value, flags);
  if (t == G_TYPE_PARAM_INT) {
    GParamSpecInt* i = G_PARAM_SPEC_INT(p);
    return g_param_spec_int(name, nick, blurb, i->minimum, i->maximum, i->default_value, flags);
  }
  if (t == G_TYPE_PARAM_UINT64) {
    GParamSpecUInt64* i = G_PARAM_SPEC_UINT64(p);
    return g_param_spec_uint64(name, nick, blurb, i->minimum, i->maximum, i->default_value, flags);
  }
  if (t == G_TYPE_PARAM_INT64) {
    GParamSpecInt64* i = G_PARAM_SPEC_INT64(p);
    return g_param_spec_int64(name, nick, blurb, i->minimum, i->maximum, i->default_value, flags);
  }
  if (t == G_TYPE_PARAM_DOUBLE) {
    GParamSpecDouble* d = G_PARAM_SPEC_DOUBLE(p);
    return g_param_spec_double(name, nick, blurb, d->minimum, d->maximum, d->default_value, flags);
  }
  if (t == GST_TYPE_PARAM_FRACTION) {
    GstParamSpecFraction* f = GST_PARAM_SPEC_FRACTION(p);
    return gst_param_spec_fraction(name, nick, blurb, f->min_num, f->min_den, f->max_num, f->max_den, f->def_num,
                                   f->def_den, flags);
  }
  return nullptr;
}

}  // namespace

struct _GstStitchBin {
  GstBin parent;
  GstElement* children[G_N_ELEMENTS(kChildren)];
  GstPad* srcpad;
};

G_DEFINE_TYPE(GstStitchBin, gst_stitch_bin, GST_TYPE_BIN);
GST_ELEMENT_REGISTER_DEFINE(stitchbin, "stitchbin", GST_RANK_NONE, GST_TYPE_STITCH_BIN);

enum { SIGNAL_RECALIBRATE, N_SIGNALS };

static GstStaticPadTemplate sink_template =
    GST_STATIC_PAD_TEMPLATE("sink_%u", GST_PAD_SINK, GST_PAD_REQUEST, GST_STATIC_CAPS("video/x-raw(ANY)"));
static GstStaticPadTemplate src_template =
    GST_STATIC_PAD_TEMPLATE("src", GST_PAD_SRC, GST_PAD_ALWAYS, GST_STATIC_CAPS("video/x-raw(ANY)"));

static GstPad* gst_stitch_bin_request_new_pad(GstElement* element, GstPadTemplate*, const gchar* name,
                                              const GstCaps* caps) {
  GstStitchBin* self = GST_STITCH_BIN(element);
  GstElement* sync = self->children[kSync];
  GstPad* target = gst_element_request_pad_simple(sync, name ? name : "sink_%u");
  if (!target) {
    GST_ELEMENT_WARNING(self, CORE, PAD, ("stitchsync refused a camera pad named %s", name ? name : "sink_%u"),
                        (NULL));
    return NULL;
  }
  gchar* pad_name = gst_pad_get_name(target);
  GstPad* ghost = gst_ghost_pad_new_from_template(pad_name, target, gst_element_get_pad_template(element, "sink_%u"));
  g_free(pad_name);
  gst_object_unref(target);
  gst_pad_set_active(ghost, TRUE);
  gst_element_add_pad(element, ghost);
  return ghost;
}

static void gst_stitch_bin_release_pad(GstElement* element, GstPad* pad) {
  GstStitchBin* self = GST_STITCH_BIN(element);
  GstPad* target = gst_ghost_pad_get_target(GST_GHOST_PAD(pad));
  gst_element_remove_pad(element, pad);
  if (target) {
    gst_element_release_request_pad(self->children[kSync], target);
    gst_object_unref(target);
  }
}

static void gst_stitch_bin_recalibrate(GstStitchBin* self) {
  g_signal_emit_by_name(self->children[kCalib], "recalibrate");
}

static void gst_stitch_bin_set_property(GObject* object, guint prop_id, const GValue* value, GParamSpec* pspec) {
  GstStitchBin* self = GST_STITCH_BIN(object);
  if (prop_id == 0 || prop_id > G_N_ELEMENTS(kProxies)) {
    G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
    return;
  }
  const Proxy& p = kProxies[prop_id - 1];
  for (guint c = 0; c < G_N_ELEMENTS(kChildren); ++c)
    if (p.child == kAllChildren || p.child == int(c)) g_object_set_property(G_OBJECT(self->children[c]), p.name, value);
}

static void gst_stitch_bin_get_property(GObject* object, guint prop_id, GValue* value, GParamSpec* pspec) {
  GstStitchBin* self = GST_STITCH_BIN(object);
  if (prop_id == 0 || prop_id > G_N_ELEMENTS(kProxies)) {
    G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
    return;
  }
  const Proxy& p = kProxies[prop_id - 1];
  g_object_get_property(G_OBJECT(self->children[p.child == kAllChildren ? kBlend : p.child]), p.name, value);
}

static void gst_stitch_bin_class_init(GstStitchBinClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  gobject_class->set_property = gst_stitch_bin_set_property;
  gobject_class->get_property = gst_stitch_bin_get_property;

  // Each proxied property copies its child's spec (name, range, default, description).
  for (guint i = 0; i < G_N_ELEMENTS(kProxies); ++i) {
    const Proxy& p = kProxies[i];
    GstElementFactory* factory = gst_element_factory_find(kChildren[p.child == kAllChildren ? kBlend : p.child][1]);
    GType type = factory ? gst_element_factory_get_element_type(factory) : G_TYPE_INVALID;
    if (factory) gst_object_unref(factory);
    if (!type) {
      g_critical("stitchbin: %s is not registered", kChildren[p.child == kAllChildren ? kBlend : p.child][1]);
      continue;
    }
    GObjectClass* child_class = G_OBJECT_CLASS(g_type_class_ref(type));
    GParamSpec* spec = g_object_class_find_property(child_class, p.name);
    GParamSpec* copy = spec ? clone_pspec(spec) : nullptr;
    if (copy) g_object_class_install_property(gobject_class, i + 1, copy);
    else g_critical("stitchbin: cannot proxy %s::%s", kChildren[p.child == kAllChildren ? kBlend : p.child][1], p.name);
    g_type_class_unref(child_class);
  }

  g_signal_new_class_handler("recalibrate", G_TYPE_FROM_CLASS(klass),
                             GSignalFlags(G_SIGNAL_RUN_LAST | G_SIGNAL_ACTION), G_CALLBACK(gst_stitch_bin_recalibrate),
                             NULL, NULL, NULL, G_TYPE_NONE, 0);

  gst_element_class_add_static_pad_template(element_class, &sink_template);
  gst_element_class_add_static_pad_template(element_class, &src_template);
  gst_element_class_set_static_metadata(element_class, "Stitch bin", "Filter/Editor/Video/Bin",
      "Stitches the cameras on its sink_%u pads into one panorama: stitchsync, stitchcalib, "
      "stitchcolor, stitchflowwarp and stitchblend in one bin",
      "gst-stitch developers");
  element_class->request_new_pad = GST_DEBUG_FUNCPTR(gst_stitch_bin_request_new_pad);
  element_class->release_pad = GST_DEBUG_FUNCPTR(gst_stitch_bin_release_pad);
  GST_DEBUG_CATEGORY_INIT(gst_stitch_bin_debug, "stitchbin", 0, "stitch bin");
}

static void gst_stitch_bin_init(GstStitchBin* self) {
  GstElement* previous = nullptr;
  bool ok = true;
  for (guint c = 0; c < G_N_ELEMENTS(kChildren); ++c) {
    self->children[c] = gst_element_factory_make(kChildren[c][1], kChildren[c][0]);
    if (!self->children[c]) {
      ok = false;
      break;
    }
    gst_bin_add(GST_BIN(self), self->children[c]);
    if (previous && !gst_element_link(previous, self->children[c])) ok = false;
    previous = self->children[c];
  }
  if (!ok) {
    // Only if the plugin's own elements are missing (a broken install): say so, make no pad.
    g_critical("stitchbin: cannot build the stitchsync ! ... ! stitchblend chain");
    self->srcpad = nullptr;
    return;
  }
  GstPad* target = gst_element_get_static_pad(self->children[kBlend], "src");
  self->srcpad = gst_ghost_pad_new_from_template(
      "src", target, gst_element_class_get_pad_template(GST_ELEMENT_GET_CLASS(self), "src"));
  gst_object_unref(target);
  gst_element_add_pad(GST_ELEMENT(self), self->srcpad);
}
