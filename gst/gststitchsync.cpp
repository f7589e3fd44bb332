/**
 * SECTION:element-stitchsync
 * @title: stitchsync
 *
 * Synchronises 2 to 16 camera streams by running time and outputs one bundle per output
 * frame: a buffer with one RGBA view per input (caps `multiview-mode=separated, views=N`),
 * which stitchcalib, stitchcolor, stitchflowwarp and stitchblend consume. Views are ordered
 * by pad number (sink_0 first). For every output timestamp each view is the input frame that
 * covers that running time (GstVideoAggregator semantics), so inputs may run at different or
 * variable rates and may be live (latency, timeouts). Inputs of any raw format are converted
 * to RGBA; interlaced inputs are refused with an error that names the pad.
 *
 * With a GPU (and `backend` not `cpu`) the bundle goes out in CUDA memory
 * (`video/x-raw(memory:CUDAMemory)`, gst-cuda) when downstream takes it, and the frames then
 * stay on the GPU until stitchblend: each input is uploaded once, or copied on the device when
 * it already is CUDA memory (`nvh264dec`, `cudaupload`), and NV12, I420 and 4-byte RGB are
 * converted to RGBA by CUDA kernels (by the input's own colorimetry, as videoconvert does).
 * Other formats are converted on the CPU before the upload. Without a GPU everything stays in
 * system memory and is converted by GStreamer's video converter.
 *
 * Cameras fail. One that ends (EOS) or stalls (its newest frame ended more than
 * `dropout-timeout` before the output time) drops out without stopping the panorama: a warning
 * names it, an element message `stitchsync-dropout` (pad, view, dropped, reason) is posted, and
 * `dropout=freeze` keeps its region on its last frame while `dropout=fill` marks the view
 * missing so that stitchblend fills the region from its neighbours. With its next fresh frame
 * (a stalled camera that resumes, a new segment after a reconnect) it rejoins, with an info
 * message and a `stitchsync-dropout` message with dropped=false. Live inputs are aggregated on
 * the `latency` timeout, so a stalled live camera is seen; file inputs that may stall need
 * `force-live=true`. A frame that ends before one its input already delivered comes from the
 * past and is dropped with a QoS message.
 *
 * ## Example launch lines
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib rig-file=examples/limlight_rig.json refine=none ! \
 *   stitchblend ! videoconvert ! autovideosink \
 *   videotestsrc pattern=ball ! video/x-raw,width=720,height=404 ! s.sink_0 \
 *   videotestsrc pattern=ball ! video/x-raw,width=720,height=404 ! s.sink_1
 * ]|
 * |[
 * gst-launch-1.0 stitchsync name=s framerate=30/1 input-eos=end-stream ! fakesink \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * Live cameras, one of which may fail: its region is filled by its neighbours meanwhile.
 * |[
 * gst-launch-1.0 stitchsync name=s latency=100000000 dropout=fill dropout-timeout=300000000 ! \
 *   stitchcalib rig-file=examples/limlight_rig.json refine=none ! stitchblend ! videoconvert ! autovideosink \
 *   videotestsrc is-live=true pattern=ball ! video/x-raw,width=720,height=404 ! s.sink_0 \
 *   videotestsrc is-live=true pattern=ball ! video/x-raw,width=720,height=404 ! s.sink_1
 * ]|
 * GPU decoding to a GPU panorama (the frames never return to the host in between):
 * |[
 * gst-launch-1.0 -e stitchsync name=s ! stitchcalib ! stitchcolor ! stitchblend ! cudadownload ! \
 *   videoconvert ! x264enc ! mp4mux ! filesink location=pano.mp4 \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_1
 * ]|
 */
#include "gststitchsync.h"

#include <algorithm>
#include <atomic>
#include <cstring>
#include <map>
#include <mutex>
#include <vector>

#include "gststitchbundle.h"
#include "gststitchcuda.h"
#include "stitch/convert/convert.hpp"

GST_DEBUG_CATEGORY_STATIC(gst_stitch_sync_debug);
#define GST_CAT_DEFAULT gst_stitch_sync_debug

enum { PROP_0, PROP_FRAMERATE, PROP_INPUT_EOS, PROP_BACKEND, PROP_DROPOUT, PROP_DROPOUT_TIMEOUT };

#define DEFAULT_FRAMERATE_N 0
#define DEFAULT_FRAMERATE_D 1
#define DEFAULT_INPUT_EOS GST_STITCH_SYNC_INPUT_EOS_REPEAT_LAST
#define DEFAULT_BACKEND stitch::Backend::Auto
#define DEFAULT_DROPOUT GST_STITCH_SYNC_DROPOUT_FREEZE
#define DEFAULT_DROPOUT_TIMEOUT (500 * GST_MSECOND)

struct StitchSyncState {
  /* Last real frame of each pad, reused while a live camera is late. */
  struct Last {
    /* system-memory bundles: the view's memory, held alive */
    GstBuffer* buffer = nullptr;
    gint width = 0, height = 0, stride = 0;
    gsize offset = 0;
    /* CUDA-memory bundles: the input frame, converted again when repeated */
    GstBuffer* frame = nullptr;
    GstVideoInfo frame_info;
    /* dropout bookkeeping: announced once when the camera goes, once when it is back */
    bool dropped = false;
    /* end (running time) of the newest frame taken in, to drop frames from the past (QoS) */
    GstClockTime newest_end = GST_CLOCK_TIME_NONE;
    guint64 processed = 0, late = 0;
  };
  std::mutex lock;  // guards `last` against pad release from the application thread
  std::map<GstPad*, Last> last;
  /* CUDA-memory bundles (aggregate thread; the pads read out_cuda) */
  std::atomic<bool> out_cuda{false};
  StitchCudaContext cuda;
  StitchCudaOwned<stitch::FrameConverter> converter;
  GstBufferPool* pool = nullptr;
  std::vector<std::array<int, 2>> pool_sizes;
  /* QoS messages for frames dropped in clip, posted from aggregate_frames (clip runs under the
   * element's object lock, which posting takes) */
  std::vector<GstMessage*> pending_qos;

  static void release(Last& l) {
    gst_clear_buffer(&l.buffer);
    gst_clear_buffer(&l.frame);
  }
  void clear_last() {
    for (auto& kv : last) release(kv.second);
    last.clear();
  }
  void clear() {
    clear_last();
    for (GstMessage* m : pending_qos) gst_message_unref(m);
    pending_qos.clear();
    converter.reset();
    stitch_bundle_pool_clear(&pool);
    pool_sizes.clear();
  }
};

struct _GstStitchSync {
  GstVideoAggregator parent;
  /* settings */
  gint fps_n, fps_d;
  GstStitchSyncInputEos input_eos;
  stitch::Backend backend;
  GstStitchSyncDropout dropout;
  GstClockTime dropout_timeout;
  /* state */
  StitchSyncState* state;
};

G_DEFINE_TYPE(GstStitchSync, gst_stitch_sync, GST_TYPE_VIDEO_AGGREGATOR);
GST_ELEMENT_REGISTER_DEFINE(stitchsync, "stitchsync", GST_RANK_NONE, GST_TYPE_STITCH_SYNC);

/* Input pads: GstVideoAggregator's converting pad, except for CUDA-memory bundles, which our
 * kernels convert: the frame is then handed over as it is, mapped where it lies (GST_MAP_CUDA
 * for CUDA memory of our context). Formats the kernels do not take still go through the CPU
 * converter and are uploaded as RGBA. */
typedef struct {
  GstVideoAggregatorConvertPad parent;
} GstStitchSyncPad;
typedef struct {
  GstVideoAggregatorConvertPadClass parent_class;
} GstStitchSyncPadClass;

G_DEFINE_TYPE(GstStitchSyncPad, gst_stitch_sync_pad, GST_TYPE_VIDEO_AGGREGATOR_CONVERT_PAD);

static gboolean converts_on_device(GstVideoFormat format) {
  switch (format) {
    case GST_VIDEO_FORMAT_RGBA:
    case GST_VIDEO_FORMAT_RGBx:
    case GST_VIDEO_FORMAT_BGRA:
    case GST_VIDEO_FORMAT_BGRx:
    case GST_VIDEO_FORMAT_NV12:
    case GST_VIDEO_FORMAT_I420: return TRUE;
    default: return FALSE;
  }
}

/* Maps `buffer` as a frame of `info`: device pointers when it is CUDA memory of our context. */
static gboolean map_input_frame(StitchSyncState* st, const GstVideoInfo* info, GstBuffer* buffer,
                                GstVideoFrame* frame) {
  GstMapFlags flags = GST_MAP_READ;
  if (st->cuda.owns(gst_buffer_peek_memory(buffer, 0))) flags = GstMapFlags(flags | STITCH_MAP_CUDA);
  return gst_video_frame_map(frame, info, buffer, flags);
}

static gboolean gst_stitch_sync_pad_prepare_frame(GstVideoAggregatorPad* pad, GstVideoAggregator* vagg,
                                                  GstBuffer* buffer, GstVideoFrame* prepared) {
  StitchSyncState* st = GST_STITCH_SYNC(vagg)->state;
  if (!st->out_cuda || !converts_on_device(GST_VIDEO_INFO_FORMAT(&pad->info)))
    return GST_VIDEO_AGGREGATOR_PAD_CLASS(gst_stitch_sync_pad_parent_class)->prepare_frame(pad, vagg, buffer, prepared);
  if (!map_input_frame(st, &pad->info, buffer, prepared)) {
    GST_WARNING_OBJECT(pad, "cannot map the input frame");
    return FALSE;
  }
  return TRUE;
}

static void gst_stitch_sync_pad_class_init(GstStitchSyncPadClass* klass) {
  GST_VIDEO_AGGREGATOR_PAD_CLASS(klass)->prepare_frame = GST_DEBUG_FUNCPTR(gst_stitch_sync_pad_prepare_frame);
}

static void gst_stitch_sync_pad_init(GstStitchSyncPad*) {}

#define GST_TYPE_STITCH_SYNC_INPUT_EOS (gst_stitch_sync_input_eos_get_type())
static GType gst_stitch_sync_input_eos_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {GST_STITCH_SYNC_INPUT_EOS_REPEAT_LAST, "Repeat the ended input's last frame", "repeat-last"},
      {GST_STITCH_SYNC_INPUT_EOS_END_STREAM, "End the output when any input ends", "end-stream"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchSyncInputEos", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

#define GST_TYPE_STITCH_SYNC_DROPOUT (gst_stitch_sync_dropout_get_type())
static GType gst_stitch_sync_dropout_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {GST_STITCH_SYNC_DROPOUT_FREEZE, "Show the camera's last frame until it is back", "freeze"},
      {GST_STITCH_SYNC_DROPOUT_FILL, "Leave the camera out (marked missing): its neighbours fill in", "fill"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchSyncDropout", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

/* Decoders' CUDA memory (nvh264dec: NV12) in the formats our kernels convert, first; then any
 * raw video in system memory. */
#ifdef STITCH_HAVE_GST_CUDA
#define SINK_CAPS                                                                 \
  GST_VIDEO_CAPS_MAKE_WITH_FEATURES(STITCH_CAPS_FEATURE_CUDA_MEMORY,              \
                                    "{ NV12, I420, RGBA, RGBx, BGRA, BGRx }") ";" \
  GST_VIDEO_CAPS_MAKE(GST_VIDEO_FORMATS_ALL)
#else
#define SINK_CAPS GST_VIDEO_CAPS_MAKE(GST_VIDEO_FORMATS_ALL)
#endif

static GstStaticPadTemplate sink_template =
    GST_STATIC_PAD_TEMPLATE("sink_%u", GST_PAD_SINK, GST_PAD_REQUEST, GST_STATIC_CAPS(SINK_CAPS));

static GstStaticPadTemplate src_template = GST_STATIC_PAD_TEMPLATE(
    "src", GST_PAD_SRC, GST_PAD_ALWAYS, GST_STATIC_CAPS(STITCH_BUNDLE_TEMPLATE_CAPS));

/* CUDA memory in and out where a device opens, unless backend=cpu. */
static bool offer_cuda(GstStitchSync* self) {
  GST_OBJECT_LOCK(self);
  const stitch::Backend backend = self->backend;
  GST_OBJECT_UNLOCK(self);
  return stitch_cuda_memory_offered(backend);
}

/* Sink pads sorted by the number in their name: view i is the i-th. */
static std::vector<GstVideoAggregatorPad*> sorted_pads(GstStitchSync* self) {
  std::vector<std::pair<guint, GstVideoAggregatorPad*>> pads;
  GST_OBJECT_LOCK(self);
  for (GList* l = GST_ELEMENT(self)->sinkpads; l; l = l->next) {
    const gchar* name = GST_PAD_NAME(l->data);
    guint idx = 0;
    if (name && g_str_has_prefix(name, "sink_")) idx = guint(g_ascii_strtoull(name + 5, NULL, 10));
    pads.emplace_back(idx, GST_VIDEO_AGGREGATOR_PAD(l->data));
  }
  GST_OBJECT_UNLOCK(self);
  std::sort(pads.begin(), pads.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<GstVideoAggregatorPad*> out;
  for (auto& p : pads) out.push_back(p.second);
  return out;
}

static gint count_negotiated(const std::vector<GstVideoAggregatorPad*>& pads) {
  gint n = 0;
  for (GstVideoAggregatorPad* p : pads)
    if (p->info.finfo && GST_VIDEO_INFO_FORMAT(&p->info) != GST_VIDEO_FORMAT_UNKNOWN) ++n;
  return n;
}

/* Inputs are still being linked (decodebin pads appear late) until at least two are negotiated
 * and the bundle's view count matches the pads. */
static bool bundle_ready(GstVideoAggregator* vagg, const std::vector<GstVideoAggregatorPad*>& pads) {
  return count_negotiated(pads) >= 2 && GST_VIDEO_INFO_VIEWS(&vagg->info) == gint(pads.size());
}

/* A pad's view size: its frames', or the bundle's while it has no caps. */
static std::array<int, 2> view_size(GstVideoAggregator* vagg, GstVideoAggregatorPad* pad) {
  gint w = pad->info.finfo ? GST_VIDEO_INFO_WIDTH(&pad->info) : 0;
  gint h = pad->info.finfo ? GST_VIDEO_INFO_HEIGHT(&pad->info) : 0;
  if (w <= 0 || h <= 0) {
    w = GST_VIDEO_INFO_WIDTH(&vagg->info);
    h = GST_VIDEO_INFO_HEIGHT(&vagg->info);
  }
  return {w, h};
}

static GstPad* gst_stitch_sync_request_new_pad(GstElement* element, GstPadTemplate* templ,
                                               const gchar* name, const GstCaps* caps) {
  GstStitchSync* self = GST_STITCH_SYNC(element);
  if (element->numsinkpads >= STITCH_MAX_VIEWS) {
    /* A warning, not an error: one camera too many must not stop the others. */
    GST_ELEMENT_WARNING(self, CORE, PAD, ("stitchsync takes at most %d inputs", STITCH_MAX_VIEWS),
                        ("refused request for pad %s", name ? name : "(any)"));
    return NULL;
  }
  /* Repeating an ended input is done here, not with the pads' repeat-after-eos, which
   * would keep the output running forever once every input has ended. */
  return GST_ELEMENT_CLASS(gst_stitch_sync_parent_class)->request_new_pad(element, templ, name, caps);
}

static void gst_stitch_sync_release_pad(GstElement* element, GstPad* pad) {
  GstStitchSync* self = GST_STITCH_SYNC(element);
  {
    std::lock_guard<std::mutex> guard(self->state->lock);
    auto it = self->state->last.find(pad);
    if (it != self->state->last.end()) {
      StitchSyncState::release(it->second);
      self->state->last.erase(it);
    }
  }
  GST_ELEMENT_CLASS(gst_stitch_sync_parent_class)->release_pad(element, pad);
}

/* A frame that ends before the newest one this pad already took in comes from the past: the
 * base class would drop it silently, so it is dropped here, with a QoS message. */
static GstBuffer* gst_stitch_sync_clip(GstAggregator* agg, GstAggregatorPad* pad, GstBuffer* buf) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  if (!GST_BUFFER_PTS_IS_VALID(buf)) return buf;
  GstClockTime pts = GST_BUFFER_PTS(buf), end = pts;
  if (GST_BUFFER_DURATION_IS_VALID(buf)) end += GST_BUFFER_DURATION(buf);
  GST_OBJECT_LOCK(pad);
  const GstClockTime end_rt = gst_segment_to_running_time(&pad->segment, GST_FORMAT_TIME, end);
  const GstClockTime start_rt = gst_segment_to_running_time(&pad->segment, GST_FORMAT_TIME, pts);
  const GstClockTime stream_time = gst_segment_to_stream_time(&pad->segment, GST_FORMAT_TIME, pts);
  GST_OBJECT_UNLOCK(pad);
  if (!GST_CLOCK_TIME_IS_VALID(end_rt)) return buf;
  std::lock_guard<std::mutex> guard(self->state->lock);
  StitchSyncState::Last& last = self->state->last[GST_PAD(pad)];
  if (!GST_CLOCK_TIME_IS_VALID(last.newest_end) || end_rt >= last.newest_end) {
    last.newest_end = end_rt;
    last.processed++;
    return buf;
  }
  GST_DEBUG_OBJECT(pad, "frame ending at %" GST_TIME_FORMAT " is from the past; dropped", GST_TIME_ARGS(end_rt));
  GstMessage* qos = gst_message_new_qos(GST_OBJECT(pad), FALSE, start_rt, stream_time, pts,
                                        GST_BUFFER_DURATION(buf));
  gst_message_set_qos_stats(qos, GST_FORMAT_BUFFERS, last.processed, ++last.late);
  self->state->pending_qos.push_back(qos);
  gst_buffer_unref(buf);
  return NULL;
}

static gboolean gst_stitch_sync_sink_event(GstAggregator* agg, GstAggregatorPad* pad,
                                           GstEvent* event) {
  if (GST_EVENT_TYPE(event) == GST_EVENT_SEGMENT || GST_EVENT_TYPE(event) == GST_EVENT_STREAM_START) {
    /* a new segment or a restarted camera: its running times start afresh */
    std::lock_guard<std::mutex> guard(GST_STITCH_SYNC(agg)->state->lock);
    auto it = GST_STITCH_SYNC(agg)->state->last.find(GST_PAD(pad));
    if (it != GST_STITCH_SYNC(agg)->state->last.end()) it->second.newest_end = GST_CLOCK_TIME_NONE;
  }
  if (GST_EVENT_TYPE(event) == GST_EVENT_CAPS) {
    GstCaps* caps = NULL;
    gst_event_parse_caps(event, &caps);
    GstVideoInfo info;
    if (!gst_video_info_from_caps(&info, caps)) {
      GST_ELEMENT_ERROR(agg, STREAM, FORMAT,
                        ("Input %s: caps are not raw video stitchsync can read", GST_PAD_NAME(pad)),
                        ("caps: %" GST_PTR_FORMAT, caps));
      gst_event_unref(event);
      return FALSE;
    }
    if (GST_VIDEO_INFO_IS_INTERLACED(&info)) {
      GST_ELEMENT_ERROR(agg, STREAM, FORMAT,
                        ("Input %s is interlaced; add a deinterlace element before stitchsync",
                         GST_PAD_NAME(pad)),
                        ("caps: %" GST_PTR_FORMAT, caps));
      gst_event_unref(event);
      return FALSE;
    }
    if (GST_VIDEO_INFO_MULTIVIEW_MODE(&info) != GST_VIDEO_MULTIVIEW_MODE_NONE &&
        GST_VIDEO_INFO_MULTIVIEW_MODE(&info) != GST_VIDEO_MULTIVIEW_MODE_MONO) {
      GST_ELEMENT_ERROR(agg, STREAM, FORMAT,
                        ("Input %s carries multiview (stereo) video; stitchsync takes one camera "
                         "per input",
                         GST_PAD_NAME(pad)),
                        ("caps: %" GST_PTR_FORMAT, caps));
      gst_event_unref(event);
      return FALSE;
    }
  }
  return GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->sink_event(agg, pad, event);
}

/* Inputs are independent cameras: any raw video is accepted whatever the bundle downstream
 * looks like (the base class would intersect with the downstream multiview caps); CUDA memory
 * only where the bundle can be in CUDA memory too. */
static GstCaps* input_caps(GstStitchSync* self, GstPad* pad) {
  return stitch_caps_prefer_cuda(gst_pad_get_pad_template_caps(pad), offer_cuda(self));
}

static gboolean gst_stitch_sync_sink_query(GstAggregator* agg, GstAggregatorPad* pad, GstQuery* query) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  switch (GST_QUERY_TYPE(query)) {
    case GST_QUERY_CAPS: {
      GstCaps* filter = NULL;
      gst_query_parse_caps(query, &filter);
      GstCaps* caps = input_caps(self, GST_PAD(pad));
      if (filter) {
        GstCaps* tmp = gst_caps_intersect_full(filter, caps, GST_CAPS_INTERSECT_FIRST);
        gst_caps_unref(caps);
        caps = tmp;
      }
      gst_query_set_caps_result(query, caps);
      gst_caps_unref(caps);
      return TRUE;
    }
    case GST_QUERY_ACCEPT_CAPS: {
      GstCaps* caps = NULL;
      gst_query_parse_accept_caps(query, &caps);
      GstCaps* accepted = input_caps(self, GST_PAD(pad));
      gst_query_set_accept_caps_result(query, gst_caps_can_intersect(caps, accepted));
      gst_caps_unref(accepted);
      return TRUE;
    }
    case GST_QUERY_CONTEXT:
      if (self->state->cuda.handle_query(GST_ELEMENT(agg), query)) return TRUE;
      return GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->sink_query(agg, pad, query);
    default:
      return GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->sink_query(agg, pad, query);
  }
}

static gboolean gst_stitch_sync_src_query(GstAggregator* agg, GstQuery* query) {
  if (GST_STITCH_SYNC(agg)->state->cuda.handle_query(GST_ELEMENT(agg), query)) return TRUE;
  return GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->src_query(agg, query);
}

static void gst_stitch_sync_set_context(GstElement* element, GstContext* context) {
  GST_STITCH_SYNC(element)->state->cuda.set_context(element, context);
  GST_ELEMENT_CLASS(gst_stitch_sync_parent_class)->set_context(element, context);
}

/* Bundles in CUDA memory first when a device opens and downstream takes them. backend=cuda
 * insists on it: anything else is a negotiation error that says why. */
static GstCaps* gst_stitch_sync_update_caps(GstVideoAggregator* vagg, GstCaps* caps) {
  GstStitchSync* self = GST_STITCH_SYNC(vagg);
  GstCaps* tmpl = gst_static_pad_template_get_caps(&src_template);
  GstCaps* out = stitch_caps_prefer_cuda(gst_caps_intersect(caps, tmpl), offer_cuda(self));
  gst_caps_unref(tmpl);
  GST_OBJECT_LOCK(self);
  const bool want_cuda = self->backend == stitch::Backend::Cuda;
  GST_OBJECT_UNLOCK(self);
  if (want_cuda && !stitch_caps_are_cuda_memory(out)) {
    GST_ELEMENT_ERROR(self, CORE, NEGOTIATION,
                      ("backend=cuda: %s", stitch_cuda_memory_possible()
                                               ? "downstream does not take video/x-raw(memory:CUDAMemory) bundles"
                                               : "no CUDA device opens (or this build has no gst-cuda)"),
                      ("downstream caps %" GST_PTR_FORMAT, caps));
    gst_caps_unref(out);
    return gst_caps_new_empty();
  }
  return out;
}

static GstCaps* gst_stitch_sync_fixate_src_caps(GstAggregator* agg, GstCaps* caps) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  auto pads = sorted_pads(self);
  gint width = 0, height = 0, n = 0;
  gdouble best_fps = -1;
  gint best_n = 0, best_d = 1;
  for (GstVideoAggregatorPad* p : pads) {
    if (!p->info.finfo || GST_VIDEO_INFO_FORMAT(&p->info) == GST_VIDEO_FORMAT_UNKNOWN) continue;
    if (n == 0) {
      width = GST_VIDEO_INFO_WIDTH(&p->info);
      height = GST_VIDEO_INFO_HEIGHT(&p->info);
    }
    ++n;
    const gint fn = GST_VIDEO_INFO_FPS_N(&p->info), fd = GST_VIDEO_INFO_FPS_D(&p->info);
    gdouble fps = 0;
    if (fn > 0 && fd > 0) gst_util_fraction_to_double(fn, fd, &fps);
    if (fps > best_fps) {
      best_fps = fps;
      best_n = fn;
      best_d = fd;
    }
  }
  if (n == 0) return gst_caps_fixate(caps);
  GST_OBJECT_LOCK(self);
  if (self->fps_n > 0) {
    best_n = self->fps_n;
    best_d = self->fps_d;
  }
  GST_OBJECT_UNLOCK(self);
  if (best_n <= 0) {
    /* only variable-rate inputs: without a rate nothing can be synchronised */
    best_n = 30;
    best_d = 1;
    GST_ELEMENT_WARNING(self, CORE, NEGOTIATION,
                        ("No input announces a framerate; outputting 30/1 (set the framerate "
                         "property)"),
                        (NULL));
  }
  caps = gst_caps_make_writable(caps);
  caps = gst_caps_truncate(caps);
  GstStructure* s = gst_caps_get_structure(caps, 0);
  gst_structure_fixate_field_nearest_int(s, "width", width);
  gst_structure_fixate_field_nearest_int(s, "height", height);
  gst_structure_fixate_field_nearest_fraction(s, "framerate", best_n, best_d);
  gst_structure_set(s, "views", G_TYPE_INT, MAX(gint(pads.size()), 2), "pixel-aspect-ratio", GST_TYPE_FRACTION, 1,
                    1, NULL);
  return gst_caps_fixate(caps);
}

static gboolean gst_stitch_sync_negotiated_src_caps(GstAggregator* agg, GstCaps* caps) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  StitchSyncState* st = self->state;
  const bool cuda = stitch_caps_are_cuda_memory(caps);
  if (cuda && !st->cuda.ensure(GST_ELEMENT(agg))) return FALSE;
  if (cuda != st->out_cuda) {
    /* the last frames, the converter and the pool belong to one kind of memory */
    std::lock_guard<std::mutex> guard(st->lock);
    st->clear();
    st->out_cuda = cuda;
  }
  GST_INFO_OBJECT(self, "bundles in %s memory", cuda ? "CUDA" : "system");
  return GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->negotiated_src_caps(agg, caps);
}

/* System-memory bundles are assembled from the inputs' memory (aggregate_frames); CUDA-memory
 * ones come whole from a pool, one per layout of the inputs. */
static GstFlowReturn gst_stitch_sync_create_output_buffer(GstVideoAggregator* vagg, GstBuffer** outbuf) {
  GstStitchSync* self = GST_STITCH_SYNC(vagg);
  StitchSyncState* st = self->state;
  const auto pads = sorted_pads(self);
  if (!st->out_cuda || !bundle_ready(vagg, pads)) {
    *outbuf = gst_buffer_new();
    return GST_FLOW_OK;
  }
  std::vector<std::array<int, 2>> sizes;
  for (GstVideoAggregatorPad* pad : pads) sizes.push_back(view_size(vagg, pad));
  if (!st->pool || sizes != st->pool_sizes) {
    stitch_bundle_pool_clear(&st->pool);
    GstCaps* caps = gst_pad_get_current_caps(GST_AGGREGATOR_SRC_PAD(vagg));
    std::string error;
    st->pool = stitch_bundle_pool_new(st->cuda, TRUE, sizes, caps, error);
    if (caps) gst_caps_unref(caps);
    if (!st->pool) {
      GST_ELEMENT_ERROR(self, RESOURCE, NO_SPACE_LEFT, ("Cannot allocate CUDA-memory bundles: %s", error.c_str()),
                        (NULL));
      return GST_FLOW_ERROR;
    }
    st->pool_sizes = sizes;
  }
  return stitch_bundle_pool_acquire(GST_ELEMENT(self), st->pool, outbuf);
}

/* Appends one view: shares the frame's memory when it is a single block of system memory,
 * copies otherwise (CUDA memory is read through host memory: this bundle is in system memory). */
static void append_view(GstBuffer* bundle, guint id, GstBuffer* src, gsize src_offset, gint width,
                        gint height, gint stride) {
  const gsize bundle_offset = gst_buffer_get_size(bundle);
  gsize offset[GST_VIDEO_MAX_PLANES] = {0};
  gint strides[GST_VIDEO_MAX_PLANES] = {0};
  if (gst_buffer_n_memory(src) == 1 && !stitch_memory_is_cuda(gst_buffer_peek_memory(src, 0))) {
    gst_buffer_append_memory(bundle, gst_buffer_get_memory(src, 0));
    offset[0] = bundle_offset + src_offset;
    strides[0] = stride;
  } else {
    const gsize row = gsize(width) * 4;
    GstMemory* mem = gst_allocator_alloc(NULL, row * height, NULL);
    GstMapInfo dst, in;
    gst_memory_map(mem, &dst, GST_MAP_WRITE);
    gst_buffer_map(src, &in, GST_MAP_READ);
    for (gint y = 0; y < height; ++y)
      memcpy(dst.data + y * row, in.data + src_offset + gsize(y) * stride, row);
    gst_buffer_unmap(src, &in);
    gst_memory_unmap(mem, &dst);
    gst_buffer_append_memory(bundle, mem);
    offset[0] = bundle_offset;
    strides[0] = gint(row);
  }
  GstVideoMeta* vm = gst_buffer_add_video_meta_full(bundle, GST_VIDEO_FRAME_FLAG_NONE,
                                                    GST_VIDEO_FORMAT_RGBA, width, height, 1,
                                                    offset, strides);
  vm->id = gint(id);
}

static void append_black_view(GstBuffer* bundle, guint id, gint width, gint height) {
  const gsize size = gsize(width) * 4 * height;
  GstMemory* mem = gst_allocator_alloc(NULL, size, NULL);
  GstMapInfo map;
  gst_memory_map(mem, &map, GST_MAP_WRITE);
  memset(map.data, 0, size);
  gst_memory_unmap(mem, &map);
  GstBuffer* tmp = gst_buffer_new();
  gst_buffer_append_memory(tmp, mem);
  append_view(bundle, id, tmp, 0, width, height, width * 4);
  gst_buffer_unref(tmp);
}

/* The core's description of a mapped input frame (a format converts_on_device takes). */
static stitch::FrameView frame_view(const GstVideoFrame* frame) {
  stitch::FrameView v;
  switch (GST_VIDEO_FRAME_FORMAT(frame)) {
    case GST_VIDEO_FORMAT_RGBx: v.format = stitch::FrameFormat::RGBx; break;
    case GST_VIDEO_FORMAT_BGRA: v.format = stitch::FrameFormat::BGRA; break;
    case GST_VIDEO_FORMAT_BGRx: v.format = stitch::FrameFormat::BGRx; break;
    case GST_VIDEO_FORMAT_NV12: v.format = stitch::FrameFormat::NV12; break;
    case GST_VIDEO_FORMAT_I420: v.format = stitch::FrameFormat::I420; break;
    default: v.format = stitch::FrameFormat::RGBA; break;
  }
  v.width = GST_VIDEO_FRAME_WIDTH(frame);
  v.height = GST_VIDEO_FRAME_HEIGHT(frame);
  for (guint p = 0; p < GST_VIDEO_FRAME_N_PLANES(frame) && p < 3; ++p) {
    v.planes[p] = static_cast<const uint8_t*>(GST_VIDEO_FRAME_PLANE_DATA(frame, p));
    v.pitches[p] = std::size_t(GST_VIDEO_FRAME_PLANE_STRIDE(frame, p));
  }
  v.on_device = STITCH_MAP_CUDA != 0 && (frame->map[0].flags & STITCH_MAP_CUDA) != 0;
  /* Y'CbCr as GstVideoConverter reads it: the caps' matrix and range, else SD/HD defaults */
  const GstVideoColorimetry& c = frame->info.colorimetry;
  gdouble kr = 0, kb = 0;
  if (!gst_video_color_matrix_get_Kr_Kb(c.matrix, &kr, &kb))
    gst_video_color_matrix_get_Kr_Kb(v.height >= 720 ? GST_VIDEO_COLOR_MATRIX_BT709 : GST_VIDEO_COLOR_MATRIX_BT601,
                                     &kr, &kb);
  v.colorimetry.kr = kr;
  v.colorimetry.kb = kb;
  v.colorimetry.full_range = c.range == GST_VIDEO_COLOR_RANGE_0_255;
  v.colorimetry.chroma_cosited_x = (frame->info.chroma_site & GST_VIDEO_CHROMA_SITE_H_COSITED) != 0;
  v.colorimetry.chroma_cosited_y = (frame->info.chroma_site & GST_VIDEO_CHROMA_SITE_V_COSITED) != 0;
  return v;
}

/* System memory: views reference the inputs' memory (zero-copy for single-block frames). */
static guint64 bundle_in_system_memory(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads,
                                       GstBuffer* outbuf, guint64 left_out) {
  GstVideoAggregator* vagg = GST_VIDEO_AGGREGATOR(self);
  guint64 missing = 0;
  guint id = 0;
  for (GstVideoAggregatorPad* pad : pads) {
    GstVideoFrame* frame = gst_video_aggregator_pad_get_prepared_frame(pad);
    StitchSyncState::Last& last = self->state->last[GST_PAD(pad)];
    if (left_out >> id & 1) {
      /* dropped out with dropout=fill: black, marked missing, the last frame kept */
      const auto size = view_size(vagg, pad);
      append_black_view(outbuf, id, size[0], size[1]);
      missing |= guint64(1) << id;
    } else if (frame) {
      append_view(outbuf, id, frame->buffer, GST_VIDEO_FRAME_PLANE_OFFSET(frame, 0),
                  GST_VIDEO_FRAME_WIDTH(frame), GST_VIDEO_FRAME_HEIGHT(frame),
                  GST_VIDEO_FRAME_PLANE_STRIDE(frame, 0));
      /* Keep only what the bundle already references: the view's memory. */
      GstBuffer* keep = gst_buffer_new();
      gst_buffer_append_memory(keep, gst_buffer_get_memory(outbuf, id));
      gst_clear_buffer(&last.buffer);
      last.buffer = keep;
      GstVideoMeta* vm = gst_buffer_get_video_meta_id(outbuf, gint(id));
      last.width = gint(vm->width);
      last.height = gint(vm->height);
      last.stride = vm->stride[0];
      last.offset = vm->offset[0] - (gst_buffer_get_size(outbuf) - gst_buffer_get_size(keep));
    } else if (last.buffer) {
      /* a live camera that is late or gone: freeze its last frame */
      append_view(outbuf, id, last.buffer, last.offset, last.width, last.height, last.stride);
    } else {
      /* never had a frame: black, and marked missing so stitchblend leaves it out */
      const auto size = view_size(vagg, pad);
      append_black_view(outbuf, id, size[0], size[1]);
      missing |= guint64(1) << id;
    }
    ++id;
  }
  return missing;
}

/* CUDA memory: every view of the pooled bundle is written on the device from its input frame
 * (uploaded once when it is in system memory). FALSE after an element error. */
static gboolean bundle_in_cuda_memory(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads,
                                      GstBuffer* outbuf, guint64 left_out, guint64& missing) {
  StitchSyncState* st = self->state;
  const guint n = guint(pads.size());
  StitchBundleMapping out;
  std::string error;
  if (!out.map(outbuf, n, GST_MAP_WRITE, error, &st->cuda)) {
    GST_ELEMENT_ERROR(self, RESOURCE, FAILED, ("Cannot map the CUDA-memory bundle: %s", error.c_str()), (NULL));
    return FALSE;
  }
  GstVideoFrame repeated[STITCH_MAX_VIEWS];  /* last frames, mapped until the device is done */
  guint n_repeated = 0;
  const gboolean ok = stitch_guard(GST_ELEMENT(self), "stitchsync", [&]() {
    if (!st->converter.made_with(st->cuda))
      st->converter.make(st->cuda, []() { return stitch::FrameConverter::create(stitch::Backend::Cuda); });
    st->converter.run([&](stitch::FrameConverter& converter) {
      for (guint id = 0; id < n; ++id) {
        GstVideoAggregatorPad* pad = pads[id];
        const stitch::ImageView& view = out.views()[id];
        GstVideoFrame* frame = gst_video_aggregator_pad_get_prepared_frame(pad);
        StitchSyncState::Last& last = st->last[GST_PAD(pad)];
        if (left_out >> id & 1) {
          converter.clear(view);
          missing |= guint64(1) << id;
        } else if (frame) {
          converter.convert(frame_view(frame), view);
          gst_buffer_replace(&last.frame, frame->buffer);
          last.frame_info = frame->info;
        } else if (last.frame) {
          /* a live camera that is late or gone: its last frame again */
          GstVideoFrame* f = &repeated[n_repeated];
          if (!map_input_frame(st, &last.frame_info, last.frame, f))
            throw std::runtime_error("cannot map the last frame of " + std::string(GST_PAD_NAME(pad)));
          ++n_repeated;
          converter.convert(frame_view(f), view);
        } else {
          converter.clear(view);
          missing |= guint64(1) << id;
        }
      }
      converter.finish();
    });
  });
  if (!ok && st->converter) {
    /* nothing the device still reads may be unmapped under it */
    try {
      st->converter.run([](stitch::FrameConverter& converter) { converter.finish(); });
    } catch (...) {
    }
  }
  for (guint i = 0; i < n_repeated; ++i) gst_video_frame_unmap(&repeated[i]);
  return ok;
}

/* Dropouts. A camera has dropped out when it ended (EOS) or when its newest frame ended more
 * than dropout-timeout before the output time: a stalled camera (live inputs: the aggregator's
 * latency timeout brings the output here without it; a timestamp jump looks the same until the
 * frames catch up). It rejoins with its next fresh frame. */
struct DropoutChange {
  std::string pad;
  guint view;
  bool dropped;        // false: rejoined
  std::string reason;  // why it dropped out
  GstStitchSyncDropout mode;
};

/* Running time at which the pad's current input frame ends (its start without a duration). */
static GstClockTime current_frame_end(GstVideoAggregatorPad* pad) {
  GstBuffer* buf = gst_video_aggregator_pad_get_current_buffer(pad);
  if (!buf || !GST_BUFFER_PTS_IS_VALID(buf)) return GST_CLOCK_TIME_NONE;
  GstClockTime end = GST_BUFFER_PTS(buf);
  if (GST_BUFFER_DURATION_IS_VALID(buf)) end += GST_BUFFER_DURATION(buf);
  GST_OBJECT_LOCK(pad);
  GstSegment* seg = &GST_AGGREGATOR_PAD(pad)->segment;
  if (seg->format == GST_FORMAT_TIME && GST_CLOCK_TIME_IS_VALID(seg->stop)) end = MIN(end, GstClockTime(seg->stop));
  const GstClockTime rt = gst_segment_to_running_time(seg, GST_FORMAT_TIME, end);
  GST_OBJECT_UNLOCK(pad);
  return rt;
}

/* Updates every pad's dropout state (state lock held); returns the views to leave out. */
static guint64 track_dropouts(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads,
                              GstBuffer* outbuf, GstStitchSyncDropout mode, GstClockTime timeout,
                              std::vector<DropoutChange>& changes) {
  GstAggregator* agg = GST_AGGREGATOR(self);
  GST_OBJECT_LOCK(agg->srcpad);
  const GstClockTime now =
      gst_segment_to_running_time(&GST_AGGREGATOR_PAD(agg->srcpad)->segment, GST_FORMAT_TIME, GST_BUFFER_PTS(outbuf));
  GST_OBJECT_UNLOCK(agg->srcpad);
  guint64 left_out = 0;
  for (guint id = 0; id < pads.size(); ++id) {
    GstVideoAggregatorPad* pad = pads[id];
    StitchSyncState::Last& last = self->state->last[GST_PAD(pad)];
    const bool had_frame = last.buffer || last.frame || last.dropped;
    std::string reason;
    if (!gst_video_aggregator_pad_get_prepared_frame(pad)) {
      if (had_frame) reason = gst_aggregator_pad_is_eos(GST_AGGREGATOR_PAD(pad)) ? "it ended" : "it stopped sending frames";
    } else if (GST_CLOCK_TIME_IS_VALID(now)) {
      const GstClockTime end = current_frame_end(pad);
      if (GST_CLOCK_TIME_IS_VALID(end) && now > end && now - end > timeout)
        reason = "no frame for " + std::to_string((now - end) / GST_MSECOND) + " ms";
    }
    const bool out = !reason.empty();
    if (out != last.dropped) {
      last.dropped = out;
      changes.push_back({GST_PAD_NAME(pad), id, out, reason, mode});
    }
    if (out && mode == GST_STITCH_SYNC_DROPOUT_FILL) left_out |= guint64(1) << id;
  }
  return left_out;
}

static void post_dropout_change(GstStitchSync* self, const DropoutChange& c) {
  if (c.dropped) {
    GST_ELEMENT_WARNING(self, STREAM, FAILED,
                        ("Camera %s (view %u) dropped out (%s); its region is %s until it is back", c.pad.c_str(),
                         c.view, c.reason.c_str(),
                         c.mode == GST_STITCH_SYNC_DROPOUT_FILL ? "filled by its neighbours" : "frozen"),
                        (NULL));
  } else {
    GST_ELEMENT_INFO(self, STREAM, FAILED, ("Camera %s (view %u) is back", c.pad.c_str(), c.view), (NULL));
  }
  GstStructure* s = gst_structure_new("stitchsync-dropout", "pad", G_TYPE_STRING, c.pad.c_str(), "view", G_TYPE_UINT,
                                      c.view, "dropped", G_TYPE_BOOLEAN, c.dropped, "reason", G_TYPE_STRING,
                                      c.reason.c_str(), NULL);
  gst_element_post_message(GST_ELEMENT(self), gst_message_new_element(GST_OBJECT(self), s));
}

static GstFlowReturn gst_stitch_sync_aggregate_frames(GstVideoAggregator* vagg, GstBuffer* outbuf) {
  GstStitchSync* self = GST_STITCH_SYNC(vagg);
  auto pads = sorted_pads(self);
  /* Wait for the inputs instead of sending bundles with a view count about to change. An input
   * can get its caps between create_output_buffer and here: a CUDA bundle made for fewer views
   * is not used either. */
  if (!bundle_ready(vagg, pads) || (self->state->out_cuda && gst_buffer_n_memory(outbuf) != pads.size())) {
    g_usleep(2000);
    return GST_AGGREGATOR_FLOW_NEED_DATA;
  }
  for (GstVideoAggregatorPad* pad : pads) {
    if (!gst_video_aggregator_pad_get_prepared_frame(pad) && gst_aggregator_pad_is_eos(GST_AGGREGATOR_PAD(pad)) &&
        self->input_eos == GST_STITCH_SYNC_INPUT_EOS_END_STREAM) {
      GST_INFO_OBJECT(self, "%s ended; ending the stream (input-eos=end-stream)", GST_PAD_NAME(pad));
      return GST_FLOW_EOS;
    }
  }
  /* Every input ended: the base class ends the stream itself only when it does not aggregate on
   * a timeout (live inputs, force-live), where it would repeat the end forever. */
  bool all_ended = true;
  for (GstVideoAggregatorPad* pad : pads)
    all_ended = all_ended && !gst_video_aggregator_pad_get_prepared_frame(pad) &&
                gst_aggregator_pad_is_eos(GST_AGGREGATOR_PAD(pad));
  if (all_ended) {
    GST_INFO_OBJECT(self, "every input ended; ending the stream");
    return GST_FLOW_EOS;
  }
  std::vector<DropoutChange> changes;
  std::vector<GstMessage*> qos;
  guint64 missing = 0;
  GST_OBJECT_LOCK(self);
  const GstStitchSyncDropout mode = self->dropout;
  const GstClockTime timeout = self->dropout_timeout;
  GST_OBJECT_UNLOCK(self);
  {
    std::lock_guard<std::mutex> guard(self->state->lock);
    qos.swap(self->state->pending_qos);
    const guint64 left_out = track_dropouts(self, pads, outbuf, mode, timeout, changes);
    if (self->state->out_cuda) {
      if (!bundle_in_cuda_memory(self, pads, outbuf, left_out, missing)) {
        for (GstMessage* m : qos) gst_message_unref(m);
        return GST_FLOW_ERROR;
      }
    } else {
      missing = bundle_in_system_memory(self, pads, outbuf, left_out);
    }
  }
  /* posted without the state lock: bus sync handlers may call back into the element */
  for (GstMessage* m : qos) gst_element_post_message(GST_ELEMENT(self), m);
  for (const DropoutChange& c : changes) post_dropout_change(self, c);
  gst_buffer_add_stitch_bundle_meta(outbuf, guint(pads.size()), missing);
  return GST_FLOW_OK;
}

static gboolean gst_stitch_sync_stop(GstAggregator* agg) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  {
    std::lock_guard<std::mutex> guard(self->state->lock);
    self->state->clear();
  }
  return GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->stop(agg);
}

static GstFlowReturn gst_stitch_sync_flush(GstAggregator* agg) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  {
    std::lock_guard<std::mutex> guard(self->state->lock);
    self->state->clear_last();
  }
  return GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->flush(agg);
}

static void gst_stitch_sync_set_property(GObject* object, guint prop_id, const GValue* value,
                                         GParamSpec* pspec) {
  GstStitchSync* self = GST_STITCH_SYNC(object);
  switch (prop_id) {
    case PROP_FRAMERATE:
      GST_OBJECT_LOCK(self);
      self->fps_n = gst_value_get_fraction_numerator(value);
      self->fps_d = gst_value_get_fraction_denominator(value);
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_INPUT_EOS: self->input_eos = GstStitchSyncInputEos(g_value_get_enum(value)); break;
    case PROP_DROPOUT:
      GST_OBJECT_LOCK(self);
      self->dropout = GstStitchSyncDropout(g_value_get_enum(value));
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_DROPOUT_TIMEOUT:
      GST_OBJECT_LOCK(self);
      self->dropout_timeout = g_value_get_uint64(value);
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_BACKEND:
      GST_OBJECT_LOCK(self);
      self->backend = stitch::Backend(g_value_get_enum(value));
      GST_OBJECT_UNLOCK(self);
      gst_pad_mark_reconfigure(GST_AGGREGATOR_SRC_PAD(self));
      break;
    default:
      G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_sync_get_property(GObject* object, guint prop_id, GValue* value,
                                         GParamSpec* pspec) {
  GstStitchSync* self = GST_STITCH_SYNC(object);
  switch (prop_id) {
    case PROP_FRAMERATE:
      GST_OBJECT_LOCK(self);
      gst_value_set_fraction(value, self->fps_n, self->fps_d);
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_INPUT_EOS: g_value_set_enum(value, self->input_eos); break;
    case PROP_DROPOUT:
      GST_OBJECT_LOCK(self);
      g_value_set_enum(value, self->dropout);
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_DROPOUT_TIMEOUT:
      GST_OBJECT_LOCK(self);
      g_value_set_uint64(value, self->dropout_timeout);
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_BACKEND:
      GST_OBJECT_LOCK(self);
      g_value_set_enum(value, int(self->backend));
      GST_OBJECT_UNLOCK(self);
      break;
    default: G_OBJECT_WARN_INVALID_PROPERTY_ID(object, prop_id, pspec);
  }
}

static void gst_stitch_sync_finalize(GObject* object) {
  GstStitchSync* self = GST_STITCH_SYNC(object);
  self->state->clear();
  delete self->state;
  G_OBJECT_CLASS(gst_stitch_sync_parent_class)->finalize(object);
}

static void gst_stitch_sync_class_init(GstStitchSyncClass* klass) {
  GObjectClass* gobject_class = G_OBJECT_CLASS(klass);
  GstElementClass* element_class = GST_ELEMENT_CLASS(klass);
  GstAggregatorClass* agg_class = GST_AGGREGATOR_CLASS(klass);
  GstVideoAggregatorClass* vagg_class = GST_VIDEO_AGGREGATOR_CLASS(klass);

  gobject_class->set_property = gst_stitch_sync_set_property;
  gobject_class->get_property = gst_stitch_sync_get_property;
  gobject_class->finalize = gst_stitch_sync_finalize;

  g_object_class_install_property(
      gobject_class, PROP_FRAMERATE,
      gst_param_spec_fraction("framerate", "Framerate",
                              "Output framerate; 0/1 takes the fastest input's rate", 0, 1,
                              G_MAXINT, 1, DEFAULT_FRAMERATE_N, DEFAULT_FRAMERATE_D,
                              GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS |
                                          GST_PARAM_MUTABLE_READY)));
  g_object_class_install_property(
      gobject_class, PROP_INPUT_EOS,
      g_param_spec_enum("input-eos", "Input EOS",
                        "What happens when one input ends before the others",
                        GST_TYPE_STITCH_SYNC_INPUT_EOS, DEFAULT_INPUT_EOS,
                        GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS)));
  g_object_class_install_property(
      gobject_class, PROP_DROPOUT,
      g_param_spec_enum("dropout", "Dropout",
                        "A camera that ended or stalled: freeze its region on its last frame, or "
                        "fill it from its neighbours (the view is marked missing)",
                        GST_TYPE_STITCH_SYNC_DROPOUT, DEFAULT_DROPOUT,
                        GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS)));
  g_object_class_install_property(
      gobject_class, PROP_DROPOUT_TIMEOUT,
      g_param_spec_uint64("dropout-timeout", "Dropout timeout",
                          "A camera whose newest frame ended this long (ns) before the output "
                          "time has dropped out (a warning is posted; it rejoins with its next frame)",
                          0, G_MAXUINT64, DEFAULT_DROPOUT_TIMEOUT,
                          GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS)));
  g_object_class_install_property(
      gobject_class, PROP_BACKEND,
      g_param_spec_enum("backend", "Backend",
                        "auto: bundles in CUDA memory (converted on the GPU) when a device opens and "
                        "downstream takes them; cpu: system memory; cuda: CUDA memory or an error",
                        GST_TYPE_STITCH_BACKEND, int(DEFAULT_BACKEND),
                        GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS)));

  gst_element_class_add_static_pad_template_with_gtype(element_class, &sink_template,
                                                       gst_stitch_sync_pad_get_type());
  gst_element_class_add_static_pad_template_with_gtype(element_class, &src_template,
                                                       GST_TYPE_AGGREGATOR_PAD);
  gst_element_class_set_static_metadata(
      element_class, "Stitch synchronizer", "Filter/Editor/Video/Compositor",
      "Synchronises N camera streams by running time into one multiview bundle per output frame",
      "gst-stitch developers");

  element_class->request_new_pad = GST_DEBUG_FUNCPTR(gst_stitch_sync_request_new_pad);
  element_class->release_pad = GST_DEBUG_FUNCPTR(gst_stitch_sync_release_pad);
  element_class->set_context = GST_DEBUG_FUNCPTR(gst_stitch_sync_set_context);
  agg_class->sink_event = GST_DEBUG_FUNCPTR(gst_stitch_sync_sink_event);
  agg_class->clip = GST_DEBUG_FUNCPTR(gst_stitch_sync_clip);
  agg_class->sink_query = GST_DEBUG_FUNCPTR(gst_stitch_sync_sink_query);
  agg_class->src_query = GST_DEBUG_FUNCPTR(gst_stitch_sync_src_query);
  agg_class->fixate_src_caps = GST_DEBUG_FUNCPTR(gst_stitch_sync_fixate_src_caps);
  agg_class->negotiated_src_caps = GST_DEBUG_FUNCPTR(gst_stitch_sync_negotiated_src_caps);
  agg_class->stop = GST_DEBUG_FUNCPTR(gst_stitch_sync_stop);
  agg_class->flush = GST_DEBUG_FUNCPTR(gst_stitch_sync_flush);
  vagg_class->update_caps = GST_DEBUG_FUNCPTR(gst_stitch_sync_update_caps);
  vagg_class->create_output_buffer = GST_DEBUG_FUNCPTR(gst_stitch_sync_create_output_buffer);
  vagg_class->aggregate_frames = GST_DEBUG_FUNCPTR(gst_stitch_sync_aggregate_frames);

  gst_type_mark_as_plugin_api(GST_TYPE_STITCH_SYNC_INPUT_EOS, GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(GST_TYPE_STITCH_SYNC_DROPOUT, GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(gst_stitch_sync_pad_get_type(), GstPluginAPIFlags(0));
  GST_DEBUG_CATEGORY_INIT(gst_stitch_sync_debug, "stitchsync", 0, "stitch synchronizer");
}

static void gst_stitch_sync_init(GstStitchSync* self) {
  self->fps_n = DEFAULT_FRAMERATE_N;
  self->fps_d = DEFAULT_FRAMERATE_D;
  self->input_eos = DEFAULT_INPUT_EOS;
  self->backend = DEFAULT_BACKEND;
  self->dropout = DEFAULT_DROPOUT;
  self->dropout_timeout = DEFAULT_DROPOUT_TIMEOUT;
  self->state = new StitchSyncState();
}
