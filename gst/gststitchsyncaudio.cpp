/**
 * SECTION:element-stitchsyncaudio
 * @title: stitchsyncaudio
 *
 * Takes the cameras' audio for stitchsync's `time-alignment=auto`: audio request pad `audio_N`
 * pairs with stitchsync's video pad `sink_N` (the same camera, its sound on the same clock as its
 * frames). stitchsync then lines the cameras up by their sound where it is distinct (GCC-PHAT
 * cross-correlation at 8 kHz, sub-sample peak, confidence from the peak-to-sidelobe ratio) and
 * by the motion in the frames otherwise; the `stitchsync-time-offsets` message says which
 * (`source-N`: audio, vision or none).
 *
 * The audio is consumed here, not output: the panorama carries no sound. An application that
 * wants the sound too splits it with a `tee` before this element. Caps: interleaved F32 or S16,
 * any rate and channel count (downmixed to mono).
 *
 * stitchsync is not a bin and its base class (GstVideoAggregator) takes only video pads, so the
 * audio comes in through this element: it feeds the stitchsync named by `sync`, or the only
 * stitchsync in the nearest enclosing bin that holds one (stitchbin's `audio_%u` pads use it
 * that way). It is not a sink in the bin's sense: it neither prerolls nor posts EOS, so it never
 * holds a pipeline.
 *
 * ## Example launch lines
 * |[
 * gst-launch-1.0 stitchsync name=s time-alignment=auto ! fakesink stitchsyncaudio name=a \
 *   videotestsrc num-buffers=90 ! video/x-raw,width=320,height=240 ! s.sink_0 \
 *   videotestsrc num-buffers=90 ! video/x-raw,width=320,height=240 ! s.sink_1 \
 *   audiotestsrc wave=white-noise num-buffers=100 ! a.audio_0 \
 *   audiotestsrc wave=white-noise num-buffers=100 ! a.audio_1
 * ]|
 */
#include "gststitchsyncaudio.h"

#include <gst/audio/audio.h>

#include "gststitchsyncpriv.h"

GST_DEBUG_CATEGORY_STATIC(gst_stitch_sync_audio_debug);
#define GST_CAT_DEFAULT gst_stitch_sync_audio_debug

struct _GstStitchSyncAudio {
  GstElement parent;
  gchar* sync_name;      /* object lock */
  GstStitchSync* target; /* object lock; resolved at the first buffer, dropped at READY */
  gboolean warned;
};

/* One camera's audio: its caps, segment and where its last block ended. */
typedef struct {
  GstPad parent;
  guint view;
  GstAudioInfo info;
  gboolean have_info;
  GstSegment segment;
  GstClockTime next_rt;
} GstStitchSyncAudioPad;
typedef struct {
  GstPadClass parent_class;
} GstStitchSyncAudioPadClass;

G_DEFINE_TYPE(GstStitchSyncAudioPad, gst_stitch_sync_audio_pad, GST_TYPE_PAD);
static void gst_stitch_sync_audio_pad_class_init(GstStitchSyncAudioPadClass*) {}
static void gst_stitch_sync_audio_pad_init(GstStitchSyncAudioPad* pad) {
  gst_segment_init(&pad->segment, GST_FORMAT_TIME);
  pad->next_rt = GST_CLOCK_TIME_NONE;
}

enum { PROP_0, PROP_SYNC };

G_DEFINE_TYPE(GstStitchSyncAudio, gst_stitch_sync_audio, GST_TYPE_ELEMENT);
GST_ELEMENT_REGISTER_DEFINE(stitchsyncaudio, "stitchsyncaudio", GST_RANK_NONE, GST_TYPE_STITCH_SYNC_AUDIO);

static GstStaticPadTemplate audio_template =
    GST_STATIC_PAD_TEMPLATE("audio_%u", GST_PAD_SINK, GST_PAD_REQUEST,
                            GST_STATIC_CAPS("audio/x-raw, format=(string){ " GST_AUDIO_NE(F32) ", " GST_AUDIO_NE(S16)
                                            " }, layout=(string)interleaved, rate=(int)[ 1, MAX ], "
                                            "channels=(int)[ 1, MAX ]"));

/* The stitchsync in `bin` (recursively) named `name`, or its only one when name is NULL. */
static GstStitchSync* find_sync(GstBin* bin, const gchar* name, guint& count) {
  count = 0;
  if (name) {
    GstElement* e = gst_bin_get_by_name(bin, name);
    if (e && GST_IS_STITCH_SYNC(e)) {
      count = 1;
      return GST_STITCH_SYNC(e);
    }
    if (e) gst_object_unref(e);
    return NULL;
  }
  GstStitchSync* found = NULL;
  GstIterator* it = gst_bin_iterate_recurse(bin);
  GValue item = G_VALUE_INIT;
  bool done = false;
  while (!done) {
    switch (gst_iterator_next(it, &item)) {
      case GST_ITERATOR_OK: {
        GstElement* e = GST_ELEMENT(g_value_get_object(&item));
        if (GST_IS_STITCH_SYNC(e)) {
          ++count;
          if (!found) found = GST_STITCH_SYNC(gst_object_ref(e));
        }
        g_value_reset(&item);
        break;
      }
      case GST_ITERATOR_RESYNC:
        gst_iterator_resync(it);
        count = 0;
        gst_clear_object(&found);
        break;
      default: done = true; break;
    }
  }
  g_value_unset(&item);
  gst_iterator_free(it);
  if (count != 1) gst_clear_object(&found);
  return found;
}

/* The stitchsync to feed: from the nearest enclosing bin outwards (ref'd; NULL after an error). */
static GstStitchSync* target(GstStitchSyncAudio* self) {
  GST_OBJECT_LOCK(self);
  if (self->target) {
    GstStitchSync* t = GST_STITCH_SYNC(gst_object_ref(self->target));
    GST_OBJECT_UNLOCK(self);
    return t;
  }
  gchar* name = g_strdup(self->sync_name);
  GST_OBJECT_UNLOCK(self);
  GstStitchSync* found = NULL;
  guint count = 0;
  for (GstObject* bin = gst_object_get_parent(GST_OBJECT(self)); bin && !found;) {
    if (GST_IS_BIN(bin)) found = find_sync(GST_BIN(bin), name, count);
    if (count > 1) {
      gst_object_unref(bin);
      break;
    }
    GstObject* up = gst_object_get_parent(bin);
    gst_object_unref(bin);
    bin = up;
  }
  if (!found) {
    if (count > 1)
      GST_ELEMENT_ERROR(self, CORE, FAILED, ("%u stitchsync elements in the bin: set sync=NAME", count), (NULL));
    else
      GST_ELEMENT_ERROR(self, CORE, FAILED, ("no stitchsync %s%s%sto feed the audio to", name ? "named '" : "",
                                             name ? name : "", name ? "' " : ""),
                        ("put stitchsyncaudio in the same pipeline as the stitchsync it serves"));
    g_free(name);
    return NULL;
  }
  g_free(name);
  GST_OBJECT_LOCK(self);
  if (!self->target) self->target = GST_STITCH_SYNC(gst_object_ref(found));
  GST_OBJECT_UNLOCK(self);
  return found;
}

static GstFlowReturn gst_stitch_sync_audio_chain(GstPad* pad, GstObject* parent, GstBuffer* buf) {
  GstStitchSyncAudio* self = GST_STITCH_SYNC_AUDIO(parent);
  GstStitchSyncAudioPad* ap = reinterpret_cast<GstStitchSyncAudioPad*>(pad);
  if (!ap->have_info) {
    gst_buffer_unref(buf);
    GST_ELEMENT_ERROR(self, CORE, NEGOTIATION, ("%s got audio before its caps", GST_PAD_NAME(pad)), (NULL));
    return GST_FLOW_NOT_NEGOTIATED;
  }
  GstStitchSync* sync = target(self);
  if (!sync) {
    gst_buffer_unref(buf);
    return GST_FLOW_ERROR;
  }
  GstClockTime rt = GST_CLOCK_TIME_NONE;
  if (GST_BUFFER_PTS_IS_VALID(buf)) rt = gst_segment_to_running_time(&ap->segment, GST_FORMAT_TIME, GST_BUFFER_PTS(buf));
  if (!GST_CLOCK_TIME_IS_VALID(rt)) rt = ap->next_rt;  // untimestamped: right after the last block
  GstMapInfo map;
  if (GST_CLOCK_TIME_IS_VALID(rt) && gst_buffer_map(buf, &map, GST_MAP_READ)) {
    const gsize frames = map.size / gsize(MAX(GST_AUDIO_INFO_BPF(&ap->info), 1));
    stitch_sync_add_audio(sync, ap->view, rt, &ap->info, map.data, frames);
    ap->next_rt = rt + gst_util_uint64_scale(frames, GST_SECOND, guint64(MAX(GST_AUDIO_INFO_RATE(&ap->info), 1)));
    gst_buffer_unmap(buf, &map);
  } else if (!self->warned) {
    self->warned = TRUE;
    GST_ELEMENT_WARNING(self, STREAM, DECODE, ("%s: audio without timestamps, or unreadable; it is not used",
                                               GST_PAD_NAME(pad)), (NULL));
  }
  gst_object_unref(sync);
  gst_buffer_unref(buf);
  return GST_FLOW_OK;
}

static gboolean gst_stitch_sync_audio_event(GstPad* pad, GstObject* parent, GstEvent* event) {
  GstStitchSyncAudio* self = GST_STITCH_SYNC_AUDIO(parent);
  GstStitchSyncAudioPad* ap = reinterpret_cast<GstStitchSyncAudioPad*>(pad);
  gboolean ret = TRUE;
  switch (GST_EVENT_TYPE(event)) {
    case GST_EVENT_CAPS: {
      GstCaps* caps;
      gst_event_parse_caps(event, &caps);
      ap->have_info = gst_audio_info_from_caps(&ap->info, caps);
      if (!ap->have_info)
        GST_ELEMENT_WARNING(self, STREAM, FORMAT, ("%s: caps are not interleaved audio it reads", GST_PAD_NAME(pad)), (NULL));
      ret = ap->have_info;
      break;
    }
    case GST_EVENT_SEGMENT: {
      const GstSegment* seg;
      gst_event_parse_segment(event, &seg);
      if (seg->format == GST_FORMAT_TIME) gst_segment_copy_into(seg, &ap->segment);
      else gst_segment_init(&ap->segment, GST_FORMAT_TIME);
      ap->next_rt = GST_CLOCK_TIME_NONE;
      break;
    }
    case GST_EVENT_FLUSH_STOP: {
      gst_segment_init(&ap->segment, GST_FORMAT_TIME);
      ap->next_rt = GST_CLOCK_TIME_NONE;
      GstStitchSync* sync = NULL;
      GST_OBJECT_LOCK(self);
      if (self->target) sync = GST_STITCH_SYNC(gst_object_ref(self->target));
      GST_OBJECT_UNLOCK(self);
      if (sync) {
        stitch_sync_reset_audio(sync, ap->view);
        gst_object_unref(sync);
      }
      break;
    }
    default: break;  // consumed: nothing goes downstream of here
  }
  gst_event_unref(event);
  return ret;
}

static GstPad* gst_stitch_sync_audio_request_new_pad(GstElement* element, GstPadTemplate* templ, const gchar* name,
                                                     const GstCaps*) {
  guint view = 0;
  if (name && sscanf(name, "audio_%u", &view) == 1) {
    if (view >= STITCH_MAX_VIEWS) {
      GST_ELEMENT_WARNING(element, CORE, PAD, ("%s refused: cameras are audio_0 to audio_%d", name, STITCH_MAX_VIEWS - 1),
                          (NULL));
      return NULL;
    }
    GST_OBJECT_LOCK(element);
    bool taken = false;
    for (GList* l = element->sinkpads; l; l = l->next) taken = taken || g_strcmp0(GST_PAD_NAME(l->data), name) == 0;
    GST_OBJECT_UNLOCK(element);
    if (taken) return NULL;
  } else {
    /* the first free number */
    GST_OBJECT_LOCK(element);
    guint64 used = 0;
    for (GList* l = element->sinkpads; l; l = l->next) used |= guint64(1) << reinterpret_cast<GstStitchSyncAudioPad*>(l->data)->view;
    GST_OBJECT_UNLOCK(element);
    while (view < STITCH_MAX_VIEWS && (used >> view) & 1) ++view;
    if (view >= STITCH_MAX_VIEWS) return NULL;
  }
  gchar* pad_name = g_strdup_printf("audio_%u", view);
  GstPad* pad = GST_PAD(g_object_new(gst_stitch_sync_audio_pad_get_type(), "name", pad_name, "direction", GST_PAD_SINK,
                                     "template", templ, NULL));
  g_free(pad_name);
  reinterpret_cast<GstStitchSyncAudioPad*>(pad)->view = view;
  gst_pad_set_chain_function(pad, GST_DEBUG_FUNCPTR(gst_stitch_sync_audio_chain));
  gst_pad_set_event_function(pad, GST_DEBUG_FUNCPTR(gst_stitch_sync_audio_event));
  gst_pad_set_active(pad, TRUE);
  gst_element_add_pad(element, pad);
  return pad;
}

static void gst_stitch_sync_audio_release_pad(GstElement* element, GstPad* pad) {
  gst_pad_set_active(pad, FALSE);
  gst_element_remove_pad(element, pad);
}

static GstStateChangeReturn gst_stitch_sync_audio_change_state(GstElement* element, GstStateChange transition) {
  GstStitchSyncAudio* self = GST_STITCH_SYNC_AUDIO(element);
  const GstStateChangeReturn ret = GST_ELEMENT_CLASS(gst_stitch_sync_audio_parent_class)->change_state(element, transition);
  if (transition == GST_STATE_CHANGE_PAUSED_TO_READY) {
    GST_OBJECT_LOCK(self);
    gst_clear_object(&self->target);
    self->warned = FALSE;
    GST_OBJECT_UNLOCK(self);
  }
  return ret;
}

static void gst_stitch_sync_audio_set_property(GObject* object, guint prop_id, const GValue* value, GParamSpec* pspec) {
  GstStitchSyncAudio* self = GST_STITCH_SYNC_AUDIO(object);
  switch (prop_id) {
    case PROP_SYNC:
      GST_OBJECT_LOCK(self);
      g_free(self->sync_name);
      self->sync_name = g_value_dup_string(value);
      gst_clear_object(&self->target);
      GST_OBJECT_UNLOCK(self);
      break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec); break;
  }
}

static void gst_stitch_sync_audio_get_property(GObject* object, guint prop_id, GValue* value, GParamSpec* pspec) {
  GstStitchSyncAudio* self = GST_STITCH_SYNC_AUDIO(object);
  switch (prop_id) {
    case PROP_SYNC:
      GST_OBJECT_LOCK(self);
      g_value_set_string(value, self->sync_name);
      GST_OBJECT_UNLOCK(self);
      break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec); break;
  }
}

static void gst_stitch_sync_audio_finalize(GObject* object) {
  GstStitchSyncAudio* self = GST_STITCH_SYNC_AUDIO(object);
  g_free(self->sync_name);
  gst_clear_object(&self->target);
  G_OBJECT_CLASS(gst_stitch_sync_audio_parent_class)->finalize(object);
}

static void gst_stitch_sync_audio_class_init(GstStitchSyncAudioClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  gobject_class->set_property = gst_stitch_sync_audio_set_property;
  gobject_class->get_property = gst_stitch_sync_audio_get_property;
  gobject_class->finalize = gst_stitch_sync_audio_finalize;
  g_object_class_install_property(
      gobject_class, PROP_SYNC,
      g_param_spec_string("sync", "stitchsync",
                          "Name of the stitchsync element whose cameras this audio belongs to (audio_N pairs with its "
                          "sink_N); empty: the only stitchsync in the nearest enclosing bin that has one",
                          NULL, GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS | GST_PARAM_MUTABLE_READY)));
  gst_element_class_add_static_pad_template_with_gtype(element_class, &audio_template,
                                                       gst_stitch_sync_audio_pad_get_type());
  gst_element_class_set_static_metadata(
      element_class, "Stitch sync audio", "Sink/Audio",
      "Takes each camera's audio (audio_N pairs with stitchsync's sink_N) for stitchsync's time-alignment=auto; the "
      "audio is consumed, not output",
      "gst-stitch");
  element_class->request_new_pad = GST_DEBUG_FUNCPTR(gst_stitch_sync_audio_request_new_pad);
  element_class->release_pad = GST_DEBUG_FUNCPTR(gst_stitch_sync_audio_release_pad);
  element_class->change_state = GST_DEBUG_FUNCPTR(gst_stitch_sync_audio_change_state);
  GST_DEBUG_CATEGORY_INIT(gst_stitch_sync_audio_debug, "stitchsyncaudio", 0, "stitchsync's audio input");
}

static void gst_stitch_sync_audio_init(GstStitchSyncAudio* self) {
  self->sync_name = NULL;
  self->target = NULL;
  self->warned = FALSE;
}
