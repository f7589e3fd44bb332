/**
 * SECTION:element-stitchbin
 * @title: stitchbin
 *
 * The whole stitching chain in one element: `stitchsync ! stitchcalib ! stitchcolor !
 * stitchflowwarp ! stitchblend`. Its request pads `sink_%u` take the cameras (they are
 * stitchsync's pads, ghosted); its source pad gives the panorama. Every property of the
 * children is the bin's own, under the same name, with the same range, default, description
 * and mutability (a property that several children have, `backend`, is set on all of them;
 * construct-only ones such as `force-live` are passed to the child as it is made); the
 * `recalibrate` action signal is stitchcalib's. Request pads `audio_%u` take the cameras' audio for
 * `time-alignment=auto` (`audio_N` for the camera on `sink_N`; consumed by a stitchsyncaudio child
 * named audio, made with the first such pad). The children are named sync, calib, color,
 * flowwarp and blend (with a two-bundle queue named queue between calib and color, so that
 * stitchsync's uploads overlap the stages' work, and a videoconvert named convert after blend:
 * it passes the RGBA panorama through, in system or CUDA memory, wherever downstream takes it,
 * and converts it for a downstream that takes other formats, so that `stitchbin ! x264enc` or
 * `stitchbin ! jpegenc` links): gst_bin_get_by_name() finds them, and their properties can also be set
 * through them (GstChildProxy), e.g. `stitchbin calib::features=orb color::window=5`. Control
 * bindings (GstController) go on the children (`gst_child_proxy_lookup`), which sync them per
 * frame: the bin does not.
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
constexpr guint kNumChildren = G_N_ELEMENTS(kChildren);
constexpr int kSync = 0, kCalib = 1, kBlend = 4;

// Properties of the children's base classes that users of the chain set too (GstAggregator's);
// the others (name, qos, start-time, ...) stay on the children.
constexpr const char* kBaseClassProperties[] = {"latency", "force-live"};

// Shared properties whose description says what the bin does with them.
constexpr const char* kBlurbs[][2] = {
    {"backend",
     "Where every stage runs (set on all five): auto: on the GPU when a CUDA device opens, the frames then "
     "staying in CUDA memory from stitchsync to stitchblend, otherwise on the CPU; cpu: every stage on the CPU, "
     "in system memory; cuda: on the GPU, or an error when no device opens"},
    {"load-file",
     "A saved calibration (set on stitchsync and stitchcalib): stitchcalib uses its geometry as is, and "
     "stitchsync applies its cameras' time_offset_ns to the inputs"},
};

// One property of the bin: the children that have it (a bit per child) and its spec.
struct Proxy {
  std::string name;
  guint children = 0;
  GType value_type = G_TYPE_INVALID;
  bool construct_only = false;
};
std::vector<Proxy>* proxies = nullptr;  // made once, in class_init

// How late a property may change: 0 (no flag: NULL only), READY, PAUSED, PLAYING.
int mutability(GParamFlags f) {
  if (f & GST_PARAM_MUTABLE_PLAYING) return 3;
  if (f & GST_PARAM_MUTABLE_PAUSED) return 2;
  if (f & GST_PARAM_MUTABLE_READY) return 1;
  return 0;
}

GParamFlags mutability_flag(int m) {
  static const GParamFlags flags[] = {GParamFlags(0), GParamFlags(GST_PARAM_MUTABLE_READY),
                                      GParamFlags(GST_PARAM_MUTABLE_PAUSED), GParamFlags(GST_PARAM_MUTABLE_PLAYING)};
  return flags[m];
}

// A copy of a child's property spec under the same name, for the bin, with `flags`.
GParamSpec* clone_pspec(GParamSpec* p, const char* blurb, GParamFlags flags) {
  const char *name = g_param_spec_get_name(p), *nick = g_param_spec_get_nick(p);
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
  if (t == G_TYPE_PARAM_UINT) {
    GParamSpecUInt* i = G_PARAM_SPEC_UINT(p);
    return g_param_spec_uint(name, nick, blurb, i->minimum, i->maximum, i->default_value, flags);
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
  if (t == G_TYPE_PARAM_FLOAT) {
    GParamSpecFloat* d = G_PARAM_SPEC_FLOAT(p);
    return g_param_spec_float(name, nick, blurb, d->minimum, d->maximum, d->default_value, flags);
  }
  if (t == GST_TYPE_PARAM_FRACTION) {
    GstParamSpecFraction* f = GST_PARAM_SPEC_FRACTION(p);
    return gst_param_spec_fraction(name, nick, blurb, f->min_num, f->min_den, f->max_num, f->max_den, f->def_num,
                                   f->def_den, flags);
  }
  return nullptr;
}

GType child_type(guint c) {
  GstElementFactory* factory = gst_element_factory_find(kChildren[c][1]);
  if (!factory) return G_TYPE_INVALID;
  GstPluginFeature* loaded = gst_plugin_feature_load(GST_PLUGIN_FEATURE(factory));
  gst_object_unref(factory);
  if (!loaded) return G_TYPE_INVALID;
  const GType type = gst_element_factory_get_element_type(GST_ELEMENT_FACTORY(loaded));
  gst_object_unref(loaded);
  return type;
}

}  // namespace

struct _GstStitchBin {
  GstBin parent;
  GstElement* children[kNumChildren];
  GstPad* srcpad;
  // Values set before the children exist (construction): applied as they are made.
  std::vector<std::pair<guint, GValue>>* pending;
};

G_DEFINE_TYPE(GstStitchBin, gst_stitch_bin, GST_TYPE_BIN);
GST_ELEMENT_REGISTER_DEFINE(stitchbin, "stitchbin", GST_RANK_NONE, GST_TYPE_STITCH_BIN);

static GstStaticPadTemplate sink_template =
    GST_STATIC_PAD_TEMPLATE("sink_%u", GST_PAD_SINK, GST_PAD_REQUEST, GST_STATIC_CAPS("video/x-raw(ANY)"));
static GstStaticPadTemplate src_template =
    GST_STATIC_PAD_TEMPLATE("src", GST_PAD_SRC, GST_PAD_ALWAYS, GST_STATIC_CAPS("video/x-raw(ANY)"));

static GstStaticPadTemplate audio_template =
    GST_STATIC_PAD_TEMPLATE("audio_%u", GST_PAD_SINK, GST_PAD_REQUEST, GST_STATIC_CAPS("audio/x-raw"));

/* A camera's audio: a pad of the stitchsyncaudio child (made with the first one), ghosted. */
static GstPad* request_audio_pad(GstStitchBin* self, const gchar* name) {
  GstElement* audio = gst_bin_get_by_name(GST_BIN(self), "audio");
  if (!audio) {
    audio = gst_element_factory_make("stitchsyncaudio", "audio");
    if (!audio || !gst_bin_add(GST_BIN(self), GST_ELEMENT(gst_object_ref(audio)))) {
      gst_clear_object(&audio);
      return NULL;
    }
    gst_element_sync_state_with_parent(audio);
  }
  GstPad* target = gst_element_request_pad_simple(audio, name ? name : "audio_%u");
  gst_object_unref(audio);
  if (!target) return NULL;
  gchar* pad_name = gst_pad_get_name(target);
  GstPad* ghost = gst_ghost_pad_new_from_template(pad_name, target, gst_element_get_pad_template(GST_ELEMENT(self), "audio_%u"));
  g_free(pad_name);
  gst_object_unref(target);
  gst_pad_set_active(ghost, TRUE);
  gst_element_add_pad(GST_ELEMENT(self), ghost);
  return ghost;
}

static GstPad* gst_stitch_bin_request_new_pad(GstElement* element, GstPadTemplate* templ, const gchar* name,
                                              const GstCaps* caps) {
  GstStitchBin* self = GST_STITCH_BIN(element);
  if (templ && g_strcmp0(GST_PAD_TEMPLATE_NAME_TEMPLATE(templ), "audio_%u") == 0) return request_audio_pad(self, name);
  GstElement* sync = self->children[kSync];
  if (!sync) return NULL;
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
  GstPad* target = gst_ghost_pad_get_target(GST_GHOST_PAD(pad));
  gst_element_remove_pad(element, pad);
  if (target) {
    GstElement* owner = gst_pad_get_parent_element(target);
    if (owner) {
      gst_element_release_request_pad(owner, target);
      gst_object_unref(owner);
    }
    gst_object_unref(target);
  }
}

static void gst_stitch_bin_recalibrate(GstStitchBin* self) {
  if (self->children[kCalib]) g_signal_emit_by_name(self->children[kCalib], "recalibrate");
}

static void gst_stitch_bin_set_property(GObject* object, guint prop_id, const GValue* value, GParamSpec* pspec) {
  GstStitchBin* self = GST_STITCH_BIN(object);
  if (prop_id == 0 || prop_id > proxies->size()) {
    G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
    return;
  }
  if (!self->children[kSync]) {  // constructing: the children are made in constructed()
    GValue copy = G_VALUE_INIT;
    g_value_init(&copy, G_VALUE_TYPE(value));
    g_value_copy(value, &copy);
    self->pending->emplace_back(prop_id, copy);
    return;
  }
  const Proxy& p = (*proxies)[prop_id - 1];
  for (guint c = 0; c < kNumChildren; ++c)
    if (p.children >> c & 1) g_object_set_property(G_OBJECT(self->children[c]), p.name.c_str(), value);
}

static void gst_stitch_bin_get_property(GObject* object, guint prop_id, GValue* value, GParamSpec* pspec) {
  GstStitchBin* self = GST_STITCH_BIN(object);
  if (prop_id == 0 || prop_id > proxies->size()) {
    G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
    return;
  }
  const Proxy& p = (*proxies)[prop_id - 1];
  for (guint c = 0; c < kNumChildren; ++c)
    if (p.children >> c & 1 && self->children[c]) {
      g_object_get_property(G_OBJECT(self->children[c]), p.name.c_str(), value);
      return;
    }
}

/* A queue of two bundles named "queue" after `upstream` (the element the chain continues
 * from; NULL when it cannot be made): stitchsync's thread then uploads and converts the next
 * bundle while the stages after it work on this one. On an H100, 3 x 1080p from system memory
 * goes from 475 to 909 panoramas/s (BENCHMARKS.md); a live chain that keeps up leaves it empty,
 * so it adds no latency. */
static GstElement* add_thread_boundary(GstStitchBin* self, GstElement* upstream) {
  GstElement* queue = gst_element_factory_make("queue", "queue");
  if (!queue) return nullptr;
  g_object_set(queue, "max-size-buffers", 2u, "max-size-bytes", 0u, "max-size-time", guint64(0), NULL);
  gst_bin_add(GST_BIN(self), queue);
  if (!gst_element_link(upstream, queue)) return nullptr;
  return queue;
}

/* The children, made once the bin's construct-only properties are known. */
static void gst_stitch_bin_constructed(GObject* object) {
  G_OBJECT_CLASS(gst_stitch_bin_parent_class)->constructed(object);
  GstStitchBin* self = GST_STITCH_BIN(object);
  GstElement* previous = nullptr;
  bool ok = true;
  for (guint c = 0; c < kNumChildren && ok; ++c) {
    // the name, and this child's construct-only properties
    std::vector<const gchar*> names{"name"};
    std::vector<GValue> values(1, G_VALUE_INIT);
    g_value_init(&values[0], G_TYPE_STRING);
    g_value_set_string(&values[0], kChildren[c][0]);
    for (const auto& [id, v] : *self->pending) {
      const Proxy& p = (*proxies)[id - 1];
      if (p.construct_only && p.children >> c & 1) {
        names.push_back(p.name.c_str());
        values.push_back(v);
      }
    }
    self->children[c] =
        gst_element_factory_make_with_properties(kChildren[c][1], guint(names.size()), names.data(), values.data());
    g_value_unset(&values[0]);
    if (!self->children[c]) {
      ok = false;
      break;
    }
    gst_bin_add(GST_BIN(self), self->children[c]);
    if (c == kCalib + 1 && !(previous = add_thread_boundary(self, previous))) ok = false;
    if (previous && !gst_element_link(previous, self->children[c])) ok = false;
    previous = self->children[c];
  }
  if (ok) {
    // every other value set at construction
    for (const auto& [id, v] : *self->pending) {
      const Proxy& p = (*proxies)[id - 1];
      if (p.construct_only) continue;
      for (guint c = 0; c < kNumChildren; ++c)
        if (p.children >> c & 1) g_object_set_property(G_OBJECT(self->children[c]), p.name.c_str(), &v);
    }
  }
  for (auto& [id, v] : *self->pending) g_value_unset(&v);
  self->pending->clear();
  if (!ok) {
    // Only if the plugin's own elements are missing (a broken install): say so, make no pad.
    g_critical("stitchbin: cannot build the stitchsync ! ... ! stitchblend chain");
    for (auto& child : self->children) child = nullptr;
    self->srcpad = nullptr;
    return;
  }
  /* The bin's source pad advertises any raw video: a converter after stitchblend keeps that
   * promise (probe6: `stitchbin ! x264enc`, `stitchbin ! jpegenc` and `stitchbin !
   * video/x-raw,format=I420` did not link). Where downstream takes RGBA it is in passthrough. */
  GstElement* last = self->children[kBlend];
  if (GstElement* convert = gst_element_factory_make("videoconvert", "convert")) {
    gst_bin_add(GST_BIN(self), convert);
    if (gst_element_link(last, convert)) last = convert;
    else gst_bin_remove(GST_BIN(self), convert);
  }
  GstPad* target = gst_element_get_static_pad(last, "src");
  self->srcpad = gst_ghost_pad_new_from_template(
      "src", target, gst_element_class_get_pad_template(GST_ELEMENT_GET_CLASS(self), "src"));
  gst_object_unref(target);
  gst_element_add_pad(GST_ELEMENT(self), self->srcpad);
}

static void gst_stitch_bin_finalize(GObject* object) {
  GstStitchBin* self = GST_STITCH_BIN(object);
  for (auto& [id, v] : *self->pending) g_value_unset(&v);
  delete self->pending;
  G_OBJECT_CLASS(gst_stitch_bin_parent_class)->finalize(object);
}

/* Every property of the children, in chain order, found by name from their specs: a property
 * that a child gains appears here with no code. */
static void install_proxies(GObjectClass* gobject_class) {
  proxies = new std::vector<Proxy>();
  std::vector<GParamSpec*> first;  // the spec each proxy copies (the first child's)
  std::vector<int> least_mutable;
  for (guint c = 0; c < kNumChildren; ++c) {
    const GType type = child_type(c);
    if (!type) {
      g_critical("stitchbin: %s is not registered", kChildren[c][1]);
      continue;
    }
    GObjectClass* child_class = G_OBJECT_CLASS(g_type_class_ref(type));
    guint n = 0;
    GParamSpec** specs = g_object_class_list_properties(child_class, &n);
    for (guint i = 0; i < n; ++i) {
      GParamSpec* spec = specs[i];
      const char* name = g_param_spec_get_name(spec);
      bool wanted = spec->owner_type == type && (spec->flags & G_PARAM_WRITABLE);
      for (const char* base : kBaseClassProperties) wanted = wanted || g_strcmp0(name, base) == 0;
      if (!wanted) continue;
      std::size_t k = 0;
      while (k < proxies->size() && (*proxies)[k].name != name) ++k;
      if (k == proxies->size()) {
        proxies->push_back({name, 0u, spec->value_type, (spec->flags & G_PARAM_CONSTRUCT_ONLY) != 0});
        first.push_back(spec);
        least_mutable.push_back(mutability(spec->flags));
      } else if ((*proxies)[k].value_type != spec->value_type) {
        g_critical("stitchbin: %s::%s differs from the earlier stage's", kChildren[c][1], name);
        continue;
      }
      (*proxies)[k].children |= 1u << c;
      least_mutable[k] = std::min(least_mutable[k], mutability(spec->flags));
    }
    g_free(specs);
    g_type_class_unref(child_class);
  }
  for (std::size_t k = 0; k < proxies->size(); ++k) {
    Proxy& p = (*proxies)[k];
    const char* blurb = g_param_spec_get_blurb(first[k]);
    for (const auto& b : kBlurbs)
      if (p.name == b[0]) blurb = b[1];
    // Readable, writable, construct-only and mutability as the child's (the strictest child's);
    // not controllable: control bindings go on the children, which sync them per frame.
    const GParamFlags flags =
        GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS | (first[k]->flags & G_PARAM_CONSTRUCT_ONLY) |
                    (first[k]->flags & G_PARAM_DEPRECATED) | mutability_flag(least_mutable[k]));
    GParamSpec* copy = clone_pspec(first[k], blurb, flags);
    if (copy) g_object_class_install_property(gobject_class, guint(k + 1), copy);
    else g_critical("stitchbin: cannot proxy %s (type %s)", p.name.c_str(), G_PARAM_SPEC_TYPE_NAME(first[k]));
  }
}

static void gst_stitch_bin_class_init(GstStitchBinClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  gobject_class->set_property = gst_stitch_bin_set_property;
  gobject_class->get_property = gst_stitch_bin_get_property;
  gobject_class->constructed = gst_stitch_bin_constructed;
  gobject_class->finalize = gst_stitch_bin_finalize;
  install_proxies(gobject_class);

  g_signal_new_class_handler("recalibrate", G_TYPE_FROM_CLASS(klass),
                             GSignalFlags(G_SIGNAL_RUN_LAST | G_SIGNAL_ACTION), G_CALLBACK(gst_stitch_bin_recalibrate),
                             NULL, NULL, NULL, G_TYPE_NONE, 0);

  gst_element_class_add_static_pad_template(element_class, &sink_template);
  gst_element_class_add_static_pad_template(element_class, &audio_template);
  gst_element_class_add_static_pad_template(element_class, &src_template);
  gst_element_class_set_static_metadata(element_class, "Stitch bin", "Video/Combiner",
      "Stitches the cameras on its sink_%u pads into one panorama: stitchsync, stitchcalib, "
      "stitchcolor, stitchflowwarp and stitchblend in one bin",
      "gst-stitch developers");
  element_class->request_new_pad = GST_DEBUG_FUNCPTR(gst_stitch_bin_request_new_pad);
  element_class->release_pad = GST_DEBUG_FUNCPTR(gst_stitch_bin_release_pad);
  GST_DEBUG_CATEGORY_INIT(gst_stitch_bin_debug, "stitchbin", 0, "stitch bin");
}

static void gst_stitch_bin_init(GstStitchBin* self) {
  for (auto& child : self->children) child = nullptr;
  self->srcpad = nullptr;
  self->pending = new std::vector<std::pair<guint, GValue>>();
}
