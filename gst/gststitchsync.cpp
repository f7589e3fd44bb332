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
 * to RGBA; interlaced inputs are refused with an error that names the pad. Inputs with
 * non-square pixels (pixel-aspect-ratio other than 1/1) are resampled to square-pixel views
 * (widened, or heightened for ratios below 1). Each bundle's meta names the pad of every view,
 * so that stitchcalib knows which camera left when a pad is released.
 *
 * With a GPU (and `backend` not `cpu`) the bundle goes out in CUDA memory
 * (`video/x-raw(memory:CUDAMemory)`, gst-cuda) when downstream takes it, and the frames then
 * stay on the GPU until stitchblend: each input is uploaded once, or copied on the device when
 * it already is CUDA memory (`nvh264dec`, `cudaupload`), and NV12, I420 and 4-byte RGB are
 * converted to RGBA by CUDA kernels (by the input's own colorimetry, as videoconvert does).
 * Other formats are converted on the CPU before the upload. Without a GPU everything stays in
 * system memory and is converted by GStreamer's video converter.
 *
 * Cameras fail. One that ends (EOS), stalls (its newest frame ended more than
 * `dropout-timeout` before the output time with nothing queued after it), or never delivers
 * anything (for `dropout-timeout` after the others started, or after its pad was added when it
 * was added while playing) drops out without stopping the
 * panorama: a warning names it, an element message `stitchsync-dropout` (pad, view, dropped,
 * reason) is posted, and `dropout=freeze` keeps its region on its last frame while
 * `dropout=fill` marks the view missing so that stitchblend fills the region from its
 * neighbours. With its next fresh frame (a stalled camera that resumes, a new segment after a
 * reconnect, a dead camera that starts) it rejoins, with an info message and a
 * `stitchsync-dropout` message with dropped=false. A later frame already waiting is a gap in the
 * timestamps (variable frame rate, a file with holes), never a dropout. Live inputs are
 * aggregated on the `latency` timeout, so a stalled or dead live camera is seen. A non-live input
 * that delivers nothing at all (an appsrc or file branch that never starts) is stood in for with
 * GAP events once `dropout-timeout` has passed since the first frame came in, so the others go on
 * and it joins with its first frame, where the output is when it comes (its older frames are
 * dropped at once, and no bundle is made while it catches up); non-live inputs that stall after
 * delivering need
 * `force-live=true` (GstAggregator waits for every non-live input that has started). A frame
 * that ends before one its input already delivered comes from the past and is dropped with a
 * QoS message (at most one per input per second, carrying the totals).
 *
 * Start-up: the first bundle waits until every requested sink pad has caps (and the pads that
 * `gst-launch`/`gst_parse_launch` link late, `decodebin ! s.sink_2`, exist), or
 * `dropout-timeout`: the camera count never changes because a decoder was slow. A single input is
 * an error ("needs at least two cameras"), never a pipeline stuck in PREROLLING; at most 16
 * inputs, a 17th request is refused with a warning on the bus. Pads may be requested and released
 * while playing: the bundle's view count follows the pads (a new pad is a missing view until it
 * negotiates; one input left gives two views, the second missing).
 *
 * Time alignment: cameras not started together (phones, action cameras, separate recorders)
 * are lined up by `time-alignment=auto`: each input's offset to sink_0 is estimated from the
 * motion the cameras see (per-frame motion energy in vertical strips of each view, normalised
 * cross-correlation between views over the newest 20 s, sub-frame by a parabola through the
 * peak), refined every second, and applied with GstPad offset semantics (the value in ns added
 * to that input's running time). Clock drift is a straight line through the offsets measured
 * over consecutive 20 s windows, refitted from all of them each time. Each change is posted as
 * an element message `stitchsync-time-offsets` with `offset-N` (gint64 ns, relative to view 0),
 * `confidence-N` (0..1) and `rate-N` (seconds of view 0 per second of view N) for every view N,
 * and sent downstream as a custom event of the same structure (for stitchcalib to save). A view
 * with nothing to align on (a static scene) keeps offset 0 with a warning. With the cameras'
 * audio linked to a `stitchsyncaudio` element (`audio_N` for `sink_N`), a view whose sound gives a
 * distinct cross-correlation peak takes its offset from the audio (`source-N`: audio, vision or
 * none). `load-file` applies
 * the `time_offset_ns` saved per camera in a calibration JSON; offsets set by hand with
 * gst_pad_set_offset() on the sink pads add to either.
 *
 * The sink pads inherit GstVideoAggregatorPad's properties. `zorder` has no effect (views are
 * ordered by pad number), nor have `repeat-after-eos` (see `input-eos`) and
 * `max-last-buffer-repeat` (see `dropout-timeout`); `converter-config` applies to inputs
 * converted in system memory.
 *
 * ## Example launch lines
 * |[
 * gst-launch-1.0 stitchsync name=s ! stitchcalib rig-file=examples/testsrc_rig.json refine=none ! \
 *   stitchblend ! videoconvert ! autovideosink \
 *   videotestsrc pattern=ball ! video/x-raw,width=320,height=240 ! s.sink_0 \
 *   videotestsrc pattern=ball ! video/x-raw,width=320,height=240 ! s.sink_1
 * ]|
 * |[
 * gst-launch-1.0 stitchsync name=s framerate=30/1 input-eos=end-stream ! fakesink \
 *   filesrc location=data/limlight_2cam_apartment/left.mp4 ! decodebin ! s.sink_0 \
 *   filesrc location=data/limlight_2cam_apartment/right.mp4 ! decodebin ! s.sink_1
 * ]|
 * Live cameras, one of which may fail: its region is filled by its neighbours meanwhile.
 * |[
 * gst-launch-1.0 stitchsync name=s latency=100000000 dropout=fill dropout-timeout=300000000 ! \
 *   stitchcalib rig-file=examples/testsrc_rig.json refine=none ! stitchblend ! videoconvert ! \
 *   autovideosink \
 *   videotestsrc is-live=true pattern=ball ! video/x-raw,width=320,height=240 ! s.sink_0 \
 *   videotestsrc is-live=true pattern=ball ! video/x-raw,width=320,height=240 ! s.sink_1
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

#include "gststitchsyncpriv.h"

GST_DEBUG_CATEGORY(gst_stitch_sync_debug);
#define GST_CAT_DEFAULT gst_stitch_sync_debug

enum {
  PROP_0,
  PROP_FRAMERATE,
  PROP_INPUT_EOS,
  PROP_BACKEND,
  PROP_DROPOUT,
  PROP_DROPOUT_TIMEOUT,
  PROP_TIME_ALIGNMENT,
  PROP_LOAD_FILE
};

#define DEFAULT_FRAMERATE_N 0
#define DEFAULT_FRAMERATE_D 1
#define DEFAULT_INPUT_EOS GST_STITCH_SYNC_INPUT_EOS_REPEAT_LAST
#define DEFAULT_BACKEND stitch::Backend::Auto
#define DEFAULT_DROPOUT GST_STITCH_SYNC_DROPOUT_FREEZE
#define DEFAULT_DROPOUT_TIMEOUT (500 * GST_MSECOND)
#define DEFAULT_TIME_ALIGNMENT GST_STITCH_SYNC_TIME_ALIGNMENT_NONE

G_DEFINE_TYPE(GstStitchSync, gst_stitch_sync, GST_TYPE_VIDEO_AGGREGATOR);
GST_ELEMENT_REGISTER_DEFINE(stitchsync, "stitchsync", GST_RANK_NONE, GST_TYPE_STITCH_SYNC);

/* Input pads: GstVideoAggregator's converting pad, except for CUDA-memory bundles, which our
 * kernels convert: the frame is then handed over as it is, mapped where it lies (GST_MAP_CUDA
 * for CUDA memory of our context). Formats the kernels do not take still go through the CPU
 * converter and are uploaded as RGBA. */

G_DEFINE_TYPE(GstStitchSyncPad, gst_stitch_sync_pad, GST_TYPE_VIDEO_AGGREGATOR_CONVERT_PAD);

static gboolean gst_stitch_sync_pad_prepare_frame(GstVideoAggregatorPad* pad, GstVideoAggregator* vagg,
                                                  GstBuffer* buffer, GstVideoFrame* prepared) {
  StitchSyncState* st = GST_STITCH_SYNC(vagg)->state;
  /* non-square pixels are resampled by the converter (create_conversion_info), CUDA or not */
  if (!st->out_cuda || !converts_on_device(GST_VIDEO_INFO_FORMAT(&pad->info)) || !has_square_pixels(&pad->info))
    return GST_VIDEO_AGGREGATOR_PAD_CLASS(gst_stitch_sync_pad_parent_class)->prepare_frame(pad, vagg, buffer, prepared);
  if (!map_input_frame(st, &pad->info, buffer, prepared)) {
    GST_WARNING_OBJECT(pad, "cannot map the input frame");
    return FALSE;
  }
  return TRUE;
}

static void gst_stitch_sync_pad_finalize(GObject* object) {
  GstStitchSyncPad* pad = reinterpret_cast<GstStitchSyncPad*>(object);
  pad->st->release();
  delete pad->st;
  G_OBJECT_CLASS(gst_stitch_sync_pad_parent_class)->finalize(object);
}

/* The converted frame: RGBA at the input's size, or at its square-pixel size (probe3: a camera
 * with pixel-aspect-ratio 4/3, 540x404 for a 720x404 picture, was stitched squeezed: rms 18 px,
 * a narrowed view, no warning). */
static void gst_stitch_sync_pad_create_conversion_info(GstVideoAggregatorConvertPad* pad, GstVideoAggregator* agg,
                                                       GstVideoInfo* info) {
  GST_VIDEO_AGGREGATOR_CONVERT_PAD_CLASS(gst_stitch_sync_pad_parent_class)->create_conversion_info(pad, agg, info);
  const GstVideoInfo* in = &GST_VIDEO_AGGREGATOR_PAD(pad)->info;
  if (!info->finfo || GST_VIDEO_INFO_FORMAT(info) == GST_VIDEO_FORMAT_UNKNOWN || !in->finfo || has_square_pixels(in)) return;
  const std::array<int, 2> size = square_pixel_size(in);
  GstVideoInfo out;
  gst_video_info_set_interlaced_format(&out, GST_VIDEO_INFO_FORMAT(info), GST_VIDEO_INFO_INTERLACE_MODE(info), guint(size[0]),
                                       guint(size[1]));
  out.colorimetry = info->colorimetry;
  out.chroma_site = info->chroma_site;
  out.fps_n = info->fps_n;
  out.fps_d = info->fps_d;
  out.par_n = out.par_d = 1;
  *info = out;
  GST_INFO_OBJECT(pad, "pixel-aspect-ratio %d/%d: %dx%d frames are resampled to %dx%d square pixels", in->par_n, in->par_d,
                  GST_VIDEO_INFO_WIDTH(in), GST_VIDEO_INFO_HEIGHT(in), size[0], size[1]);
}

static void gst_stitch_sync_pad_class_init(GstStitchSyncPadClass* klass) {
  G_OBJECT_CLASS(klass)->finalize = gst_stitch_sync_pad_finalize;
  GST_VIDEO_AGGREGATOR_CONVERT_PAD_CLASS(klass)->create_conversion_info =
      GST_DEBUG_FUNCPTR(gst_stitch_sync_pad_create_conversion_info);
  GST_VIDEO_AGGREGATOR_PAD_CLASS(klass)->prepare_frame = GST_DEBUG_FUNCPTR(gst_stitch_sync_pad_prepare_frame);
}

static void gst_stitch_sync_pad_init(GstStitchSyncPad* pad) {
  pad->st = new SyncPadState();
  watch_arrivals(GST_PAD(pad));
}


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

#define GST_TYPE_STITCH_SYNC_TIME_ALIGNMENT (gst_stitch_sync_time_alignment_get_type())
static GType gst_stitch_sync_time_alignment_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {GST_STITCH_SYNC_TIME_ALIGNMENT_NONE, "Pair frames by running time (plus the pads' and load-file's offsets)",
       "none"},
      {GST_STITCH_SYNC_TIME_ALIGNMENT_AUTO, "Estimate each input's offset and clock rate from what the cameras see",
       "auto"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchSyncTimeAlignment", values);
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

/* Sink pads sorted by the number in their name: view i is the i-th. Each is held by a reference
 * for as long as the list lives, so that a pad released meanwhile (and its state) stays valid. */
struct SortedPads {
  std::vector<GstVideoAggregatorPad*> pads;
  explicit SortedPads(GstStitchSync* self) {
    std::vector<std::pair<guint, GstVideoAggregatorPad*>> named;
    GST_OBJECT_LOCK(self);
    for (GList* l = GST_ELEMENT(self)->sinkpads; l; l = l->next) {
      const gchar* name = GST_PAD_NAME(l->data);
      guint idx = 0;
      if (name && g_str_has_prefix(name, "sink_")) idx = guint(g_ascii_strtoull(name + 5, NULL, 10));
      named.emplace_back(idx, GST_VIDEO_AGGREGATOR_PAD(gst_object_ref(l->data)));
    }
    GST_OBJECT_UNLOCK(self);
    std::sort(named.begin(), named.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    for (auto& p : named) pads.push_back(p.second);
  }
  ~SortedPads() {
    for (GstVideoAggregatorPad* p : pads) gst_object_unref(p);
  }
  SortedPads(const SortedPads&) = delete;
  SortedPads& operator=(const SortedPads&) = delete;
};


/* Views in a bundle: one per input, at least two (bundles have 2 to 16 views: with a single
 * input left, after the others were released, the second view is marked missing). */
static guint bundle_views(const std::vector<GstVideoAggregatorPad*>& pads) { return guint(MAX(pads.size(), 2)); }


static GstPad* gst_stitch_sync_request_new_pad(GstElement* element, GstPadTemplate* templ,
                                               const gchar* name, const GstCaps* caps) {
  GstStitchSync* self = GST_STITCH_SYNC(element);
  GST_OBJECT_LOCK(self);
  const guint n = element->numsinkpads;
  GST_OBJECT_UNLOCK(self);
  if (n >= STITCH_MAX_VIEWS) {
    /* A warning on the bus, not an error: one camera too many must not stop the others. */
    GST_ELEMENT_WARNING(self, CORE, PAD,
                        ("stitchsync takes at most %d inputs: the request for %s is refused (release a pad first)",
                         STITCH_MAX_VIEWS, name ? name : "another sink pad"),
                        (NULL));
    return NULL;
  }
  /* Repeating an ended input is done here, not with the pads' repeat-after-eos, which
   * would keep the output running forever once every input has ended. */
  GstPad* pad = GST_ELEMENT_CLASS(gst_stitch_sync_parent_class)->request_new_pad(element, templ, name, caps);
  if (pad) {
    /* ...except before the first bundle: an input that ends before it (a photo, one frame then
     * EOS, before gst_parse_launch linked the other camera) keeps that frame for it, and is
     * repeated from there on like any ended input (wait_for_inputs turns this off). */
    if (!GST_CLOCK_TIME_IS_VALID(self->state->started)) g_object_set(pad, "repeat-after-eos", TRUE, NULL);
    const GstClockTime rt = gst_element_get_current_running_time(element);
    std::lock_guard<std::mutex> guard(self->state->lock);
    pad_state(pad)->requested_rt = rt;
  }
  return pad;
}

static void gst_stitch_sync_release_pad(GstElement* element, GstPad* pad) {
  GstStitchSync* self = GST_STITCH_SYNC(element);
  {
    /* the frames it holds go now; its state object goes with the pad's last reference (the
     * aggregate thread may hold one for the bundle it is making) */
    std::lock_guard<std::mutex> guard(self->state->lock);
    pad_state(pad)->release();
  }
  GST_OBJECT_LOCK(self);
  if (GST_STATE(self) <= GST_STATE_READY && GST_STATE_PENDING(self) <= GST_STATE_READY)
    self->state->expected.insert(GST_PAD_NAME(pad));
  GST_OBJECT_UNLOCK(self);
  GST_ELEMENT_CLASS(gst_stitch_sync_parent_class)->release_pad(element, pad);
  /* the view count changes: renegotiate the bundle */
  gst_pad_mark_reconfigure(GST_AGGREGATOR_SRC_PAD(self));
}

/* A frame that ends before the newest one this pad already took in comes from the past: the
 * base class would drop it silently, so it is dropped here, with a QoS message. */
static GstBuffer* gst_stitch_sync_clip(GstAggregator* agg, GstAggregatorPad* pad, GstBuffer* buf) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  /* our own stand-in for a silent input (gststitchsyncwatch.cpp) is no frame */
  const bool gap = is_standin_gap(buf);
  if (pad->segment.format != GST_FORMAT_TIME) {  /* its segment was refused (sink_event): an error is out */
    gst_buffer_unref(buf);
    return NULL;
  }
  if (!GST_BUFFER_PTS_IS_VALID(buf)) return buf;  /* an error, from the aggregate thread */
  GstClockTime pts = GST_BUFFER_PTS(buf), end = pts;
  if (GST_BUFFER_DURATION_IS_VALID(buf)) end += GST_BUFFER_DURATION(buf);
  GST_OBJECT_LOCK(pad);
  const GstClockTime end_rt = gst_segment_to_running_time(&pad->segment, GST_FORMAT_TIME, end);
  const GstClockTime start_rt = gst_segment_to_running_time(&pad->segment, GST_FORMAT_TIME, pts);
  const GstClockTime stream_time = gst_segment_to_stream_time(&pad->segment, GST_FORMAT_TIME, pts);
  GST_OBJECT_UNLOCK(pad);
  if (!GST_CLOCK_TIME_IS_VALID(end_rt)) return buf;
  std::lock_guard<std::mutex> guard(self->state->lock);
  SyncPadState& last = *pad_state(pad);
  if (last.standing_in()) {
    /* A camera stood in for has started (its frames are in the queue, behind our gaps). The gaps
     * still queued would hide it for their span while its frames for that span are thrown away,
     * and GstVideoAggregator drops its frames that end before the last gap shown one per output
     * frame ("from the past"): the output would go on without it, in step with the frames it
     * throws away, for as long as the camera was late. So the gaps left go, and so do its frames
     * from before the gaps shown (standin_end, see catching_up), here, all at once. */
    if (gap) {
      if (last.delivered) {
        GST_DEBUG_OBJECT(pad, "the camera has started: stand-in gap at %" GST_TIME_FORMAT " dropped", GST_TIME_ARGS(start_rt));
        gst_buffer_unref(buf);
        return NULL;
      }
      return buf;
    }
    if (GST_CLOCK_TIME_IS_VALID(last.standin_end) && end_rt < last.standin_end) {
      GST_LOG_OBJECT(pad, "frame ending at %" GST_TIME_FORMAT " is from before the stand-in's gaps; dropped",
                     GST_TIME_ARGS(end_rt));
      gst_buffer_unref(buf);
      return NULL;
    }
    GST_DEBUG_OBJECT(pad, "joins with its frame at %" GST_TIME_FORMAT, GST_TIME_ARGS(start_rt));
    last.standin_done = true;
  }
  if (gap) return buf;
  if (!GST_CLOCK_TIME_IS_VALID(last.newest_end) || end_rt >= last.newest_end) {
    last.newest_end = end_rt;
    last.processed++;
    return buf;
  }
  GST_DEBUG_OBJECT(pad, "frame ending at %" GST_TIME_FORMAT " is from the past; dropped", GST_TIME_ARGS(end_rt));
  ++last.late;
  /* rate-limited: a camera whose clock went back would otherwise post one per frame */
  if (last.qos.allow(g_get_monotonic_time() * 1000)) {
    GstMessage* qos = gst_message_new_qos(GST_OBJECT(pad), FALSE, start_rt, stream_time, pts, GST_BUFFER_DURATION(buf));
    gst_message_set_qos_stats(qos, GST_FORMAT_BUFFERS, last.processed, last.late);
    self->state->pending_qos.push_back(qos);
  }
  gst_buffer_unref(buf);
  return NULL;
}

/* Why input caps are refused (NULL: accepted): the CAPS handler and accept-caps both ask this,
 * so that accept-caps never accepts what the CAPS handler then refuses. */
static const char* caps_refusal(GstCaps* caps) {
  GstVideoInfo info;
  if (!caps || !gst_caps_is_fixed(caps) || !gst_video_info_from_caps(&info, caps))
    return "caps are not raw video stitchsync can read";
  if (GST_VIDEO_INFO_IS_INTERLACED(&info)) return "is interlaced; add a deinterlace element before stitchsync";
  if (GST_VIDEO_INFO_MULTIVIEW_MODE(&info) != GST_VIDEO_MULTIVIEW_MODE_NONE &&
      GST_VIDEO_INFO_MULTIVIEW_MODE(&info) != GST_VIDEO_MULTIVIEW_MODE_MONO)
    return "carries multiview (stereo) video; stitchsync takes one camera per input";
  return NULL;
}


static gboolean gst_stitch_sync_sink_event(GstAggregator* agg, GstAggregatorPad* pad,
                                           GstEvent* event) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  if (GST_EVENT_TYPE(event) == GST_EVENT_SEGMENT) {
    /* frames are paired by running time: a segment in bytes (appsrc's default format) has
     * none, and GstVideoAggregator would abort the process on it (an assertion) */
    const GstSegment* segment = NULL;
    gst_event_parse_segment(event, &segment);
    if (segment->format != GST_FORMAT_TIME) {
      GST_ELEMENT_ERROR(agg, STREAM, FORMAT,
                        ("Input %s sends a %s segment, not a time one: stitchsync pairs the cameras' frames by their timestamps",
                         GST_PAD_NAME(pad), gst_format_get_name(segment->format)),
                        ("an appsrc camera needs format=time (its default is bytes); a parser or decoder "
                         "belongs between a byte source and stitchsync"));
      gst_event_unref(event);
      return FALSE;
    }
  }
  if (GST_EVENT_TYPE(event) == GST_EVENT_SEGMENT || GST_EVENT_TYPE(event) == GST_EVENT_STREAM_START) {
    /* a new segment or a restarted camera: its running times start afresh */
    std::lock_guard<std::mutex> guard(self->state->lock);
    pad_state(pad)->newest_end = GST_CLOCK_TIME_NONE;
  }
  if (GST_EVENT_TYPE(event) == GST_EVENT_CAPS) {
    GstCaps* caps = NULL;
    gst_event_parse_caps(event, &caps);
    if (const char* why = caps_refusal(caps)) {
      GST_ELEMENT_ERROR(agg, STREAM, FORMAT, ("Input %s %s", GST_PAD_NAME(pad), why), ("caps: %" GST_PTR_FORMAT, caps));
      gst_event_unref(event);
      return FALSE;
    }
  }
  if (GST_EVENT_TYPE(event) == GST_EVENT_SEGMENT) {
    /* the base class copies the segment: the time offset we add goes on top of the new one */
    const gboolean ret = GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->sink_event(agg, pad, event);
    std::lock_guard<std::mutex> guard(self->state->lock);
    SyncPadState& st = *pad_state(pad);
    const gint64 target = st.applied_ns;
    st.applied_ns = 0;
    apply_time_offset(pad, st, target);
    return ret;
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
      const char* why = gst_caps_can_intersect(caps, accepted) ? caps_refusal(caps) : "caps are not raw video";
      gst_query_set_accept_caps_result(query, why == NULL);
      /* fixed caps refused for what they are: the CAPS event that follows would be refused with
       * only a debug line, so the reason goes on the bus here */
      if (why && gst_caps_is_fixed(caps) && gst_caps_can_intersect(caps, accepted))
        GST_ELEMENT_ERROR(agg, STREAM, FORMAT, ("Input %s %s", GST_PAD_NAME(pad), why), ("caps: %" GST_PTR_FORMAT, caps));
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

/* Seekable in time when every input is. The base class answers "not seekable" for any
 * aggregator, and players then disable their seek bar, although a flushing seek works: it goes
 * to every input, and the stages reset on the flush. The range spans the inputs' (the output
 * lasts as long as the longest input, input-eos=repeat-last). */
static gboolean answer_seeking(GstStitchSync* self, GstQuery* query) {
  GstFormat format = GST_FORMAT_UNDEFINED;
  gst_query_parse_seeking(query, &format, NULL, NULL, NULL);
  SortedPads sorted(self);
  bool seekable = format == GST_FORMAT_TIME && !sorted.pads.empty();
  gint64 start = -1, end = -1;
  for (GstVideoAggregatorPad* p : sorted.pads) {
    GstQuery* q = gst_query_new_seeking(GST_FORMAT_TIME);
    gboolean yes = FALSE;
    gint64 s = -1, e = -1;
    if (seekable && gst_pad_peer_query(GST_PAD(p), q)) gst_query_parse_seeking(q, NULL, &yes, &s, &e);
    seekable = seekable && yes;
    if (s >= 0) start = start < 0 ? s : MIN(start, s);
    if (e >= 0) end = MAX(end, e);
    gst_query_unref(q);
  }
  gst_query_set_seeking(query, format, seekable, seekable ? MAX(start, gint64(0)) : 0, seekable ? end : -1);
  return TRUE;
}

static gboolean gst_stitch_sync_src_query(GstAggregator* agg, GstQuery* query) {
  if (GST_STITCH_SYNC(agg)->state->cuda.handle_query(GST_ELEMENT(agg), query)) return TRUE;
  if (GST_QUERY_TYPE(query) == GST_QUERY_SEEKING) return answer_seeking(GST_STITCH_SYNC(agg), query);
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
  SortedPads sorted(self);
  const auto& pads = sorted.pads;
  gint width = 0, height = 0, n = 0;
  gdouble best_fps = -1;
  gint best_n = 0, best_d = 1;
  for (GstVideoAggregatorPad* p : pads) {
    if (!p->info.finfo || GST_VIDEO_INFO_FORMAT(&p->info) == GST_VIDEO_FORMAT_UNKNOWN) continue;
    if (n == 0) {
      const std::array<int, 2> size = square_pixel_size(&p->info);  // the view's size
      width = size[0];
      height = size[1];
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
  if (n == 0) {
    /* no input has caps yet: never 0/1 (GstVideoAggregator derives its latency from the rate,
     * and a zero rate is a CRITICAL there) */
    GST_OBJECT_LOCK(self);
    const gint want_n = self->fps_n > 0 ? self->fps_n : 30, want_d = self->fps_n > 0 ? self->fps_d : 1;
    GST_OBJECT_UNLOCK(self);
    caps = gst_caps_truncate(gst_caps_make_writable(caps));
    gst_structure_fixate_field_nearest_fraction(gst_caps_get_structure(caps, 0), "framerate", want_n, want_d);
    return gst_caps_fixate(caps);
  }
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
  /* the rate chosen, not a preference downstream lists first (a videorate branch of a tee) */
  GstStructure* wanted = gst_structure_new("video/x-raw", "framerate", GST_TYPE_FRACTION, best_n, best_d, NULL);
  caps = stitch_caps_first_holding(caps, wanted);
  gst_structure_free(wanted);
  caps = gst_caps_make_writable(caps);
  GstStructure* s = gst_caps_get_structure(caps, 0);
  gst_structure_fixate_field_nearest_int(s, "width", width);
  gst_structure_fixate_field_nearest_int(s, "height", height);
  gst_structure_fixate_field_nearest_fraction(s, "framerate", best_n, best_d);
  /* before the first bundle, pads still to be linked (see `expected`) count too */
  guint to_come = 0;
  GST_OBJECT_LOCK(self);
  for (const std::string& name : self->state->expected) {
    bool present = false;
    for (GstVideoAggregatorPad* p : pads) present = present || name == GST_PAD_NAME(p);
    to_come += present ? 0 : 1;
  }
  GST_OBJECT_UNLOCK(self);
  gst_structure_set(s, "views", G_TYPE_INT, gint(MIN(bundle_views(pads) + to_come, STITCH_MAX_VIEWS)),
                    "pixel-aspect-ratio", GST_TYPE_FRACTION, 1, 1, NULL);
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
  SortedPads sorted(self);
  const auto& pads = sorted.pads;
  const guint n = bundle_views(pads);
  if (!st->out_cuda || guint(GST_VIDEO_INFO_VIEWS(&vagg->info)) != n) {
    *outbuf = gst_buffer_new();
    return GST_FLOW_OK;
  }
  std::vector<std::array<int, 2>> sizes;
  for (guint i = 0; i < n; ++i) sizes.push_back(view_size(vagg, i < pads.size() ? pads[i] : NULL));
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

/* Dropouts (policy: stitch::sync::update_dropout). A camera has dropped out when it ended, when
 * it stalled (its newest frame ended more than dropout-timeout before the output time with
 * nothing queued after it; live inputs: the aggregator's latency timeout brings the output here
 * without it), or when it never delivered for dropout-timeout after the first bundle. A later
 * frame already queued is a gap in the timestamps (VFR, a file with holes), not a dropout. */
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

static gint64 as_time(GstClockTime t) { return GST_CLOCK_TIME_IS_VALID(t) ? gint64(t) : stitch::sync::kNoTime; }

static stitch::sync::InputFacts input_facts(GstVideoAggregatorPad* pad) {
  stitch::sync::InputFacts f;
  f.negotiated = is_negotiated(pad);
  f.has_frame = gst_video_aggregator_pad_get_prepared_frame(pad) != NULL;
  f.queued = gst_aggregator_pad_has_buffer(GST_AGGREGATOR_PAD(pad));
  f.eos = gst_aggregator_pad_is_eos(GST_AGGREGATOR_PAD(pad));
  if (f.has_frame) f.frame_end = as_time(current_frame_end(pad));
  return f;
}

/* Updates every pad's dropout state from its facts (gathered before the state lock: asking the
 * base class whether a buffer is queued clips it, which takes that lock); returns the views to
 * leave out. */
static guint64 track_dropouts(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads,
                              const std::vector<stitch::sync::InputFacts>& facts, GstClockTime now, bool live,
                              GstStitchSyncDropout mode, GstClockTime timeout, std::vector<DropoutChange>& changes) {
  guint64 left_out = 0;
  /* a camera that never delivers is counted from the start for those there at the first bundle,
   * from the first output it takes part in for one requested later (a pad linked while playing) */
  const bool first = self->state->tracks_from_start;
  self->state->tracks_from_start = false;
  for (guint id = 0; id < pads.size() && id < facts.size(); ++id) {
    if (!pads[id]) continue;
    SyncPadState& st = *pad_state(pads[id]);
    if (st.track.since == stitch::sync::kNoTime) {
      /* live: the clock's running time when it was requested, where the output lags behind it */
      GstClockTime since = first ? self->state->started : now;
      if (!first && live && GST_CLOCK_TIME_IS_VALID(st.requested_rt) && GST_CLOCK_TIME_IS_VALID(since))
        since = MAX(since, st.requested_rt);
      st.track.since = as_time(since);
    }
    std::string reason;
    if (stitch::sync::update_dropout(st.track, facts[id], as_time(now), as_time(self->state->started),
                                     gint64(timeout), reason))
      changes.push_back({GST_PAD_NAME(pads[id]), id, st.track.dropped, reason, mode});
    if (st.track.dropped && mode == GST_STITCH_SYNC_DROPOUT_FILL) left_out |= guint64(1) << id;
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

/* Non-live cameras stood in for (gststitchsyncwatch.cpp) that have started: the end of the gap
 * shown is noted (clip drops the camera's frames from before it), a gap still waiting at the head
 * of its queue goes, and while its frames so far were all from the past no bundle is made, so
 * that the others' video is not used up without it while it catches up (a non-live input that
 * delivered is waited for anyway). TRUE: hold this bundle. */
static bool catching_up(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads) {
  StitchSyncState* st = self->state;
  bool hold = false;
  for (GstVideoAggregatorPad* pad : pads) {
    bool standing_in, delivered;
    {
      std::lock_guard<std::mutex> guard(st->lock);
      standing_in = pad_state(pad)->standing_in();
      delivered = pad_state(pad)->delivered;
    }
    if (!standing_in) continue;
    GstBuffer* cur = gst_video_aggregator_pad_get_current_buffer(pad);
    if (cur && is_standin_gap(cur)) {
      const GstClockTime end = current_frame_end(pad);
      std::lock_guard<std::mutex> guard(st->lock);
      GstClockTime& shown = pad_state(pad)->standin_end;
      if (GST_CLOCK_TIME_IS_VALID(end) && (!GST_CLOCK_TIME_IS_VALID(shown) || end > shown)) shown = end;
    }
    if (!delivered) continue;
    /* (peeking clips: drops the gaps behind it, and its frames from the past) */
    GstAggregatorPad* apad = GST_AGGREGATOR_PAD(pad);
    while (GstBuffer* head = gst_aggregator_pad_peek_buffer(apad)) {
      const bool gap = is_standin_gap(head);
      gst_buffer_unref(head);
      if (!gap) break;
      gst_aggregator_pad_drop_buffer(apad);
    }
    std::lock_guard<std::mutex> guard(st->lock);
    if (pad_state(pad)->standing_in() && !gst_aggregator_pad_is_eos(apad)) {
      GST_LOG_OBJECT(pad, "has started; no bundle until its frames reach the output");
      hold = true;
    }
  }
  return hold;
}

/* Before the first bundle (stitch::sync::may_start): every requested pad negotiated, or
 * dropout-timeout since the first inputs were ready; never a single input. */
static GstFlowReturn wait_for_inputs(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads,
                                     GstClockTime now, GstClockTime timeout) {
  StitchSyncState* st = self->state;
  if (GST_CLOCK_TIME_IS_VALID(st->started)) return GST_FLOW_OK;
  /* counted from the first frame that came in (a silent non-live input holds the base class
   * until the stand-in gaps start) */
  if (st->first_ready_us < 0)
    st->first_ready_us = st->first_data_us >= 0 ? MIN(gint64(st->first_data_us), g_get_monotonic_time()) : g_get_monotonic_time();
  std::vector<stitch::sync::InputFacts> facts;
  for (GstVideoAggregatorPad* p : pads) facts.push_back(input_facts(p));
  GST_OBJECT_LOCK(self);
  for (const std::string& name : st->expected) {
    bool present = false;
    for (GstVideoAggregatorPad* p : pads) present = present || name == GST_PAD_NAME(p);
    if (!present) facts.push_back({});  // still to be linked: not negotiated
  }
  GST_OBJECT_UNLOCK(self);
  switch (stitch::sync::may_start(facts, (g_get_monotonic_time() - st->first_ready_us) * 1000, gint64(timeout))) {
    case stitch::sync::StartDecision::Wait:
      g_usleep(2000);
      return GST_AGGREGATOR_FLOW_NEED_DATA;
    case stitch::sync::StartDecision::TooFew:
      GST_ELEMENT_ERROR(self, CORE, PAD,
                        ("stitchsync needs at least two cameras; only %s is linked", pads.empty() ? "one input" : GST_PAD_NAME(pads[0])),
                        ("link more inputs to stitchsync's sink_%%u pads, or use the camera without stitching"));
      return GST_FLOW_ERROR;
    case stitch::sync::StartDecision::Go:
      /* no camera has delivered a frame yet (a live aggregator's timeout, RTSP still
       * connecting): nobody started, so nobody can be late; count from the first frame */
      bool any_frame = false;  // (a flush or restart clears first_data_us; queued frames count too)
      for (const stitch::sync::InputFacts& f : facts) any_frame = any_frame || f.has_frame || f.queued;
      if (st->first_data_us < 0 && !any_frame) {
        st->first_ready_us = -1;
        g_usleep(2000);
        return GST_AGGREGATOR_FLOW_NEED_DATA;
      }
      break;
  }
  if (!load_time_offsets(self, pads)) return GST_FLOW_ERROR;
  GST_OBJECT_LOCK(self);
  st->expected.clear();
  std::vector<GstPad*> all;
  for (GList* l = GST_ELEMENT(self)->sinkpads; l; l = l->next) all.push_back(GST_PAD(gst_object_ref(l->data)));
  GST_OBJECT_UNLOCK(self);
  for (GstPad* p : all) {  /* the first bundle holds every ended input's frame: stitchsync repeats it from here */
    g_object_set(p, "repeat-after-eos", FALSE, NULL);
    gst_object_unref(p);
  }
  /* the others started when the first of them was ready: a camera still silent after
   * dropout-timeout from then is out */
  const GstClockTime waited = GstClockTime(g_get_monotonic_time() - st->first_ready_us) * 1000;
  st->started = GST_CLOCK_TIME_IS_VALID(now) ? now - MIN(now, waited) : now;
  {
    std::lock_guard<std::mutex> guard(st->lock);
    st->tracks_from_start = true;
  }
  return GST_FLOW_OK;
}

static GstFlowReturn gst_stitch_sync_aggregate_frames(GstVideoAggregator* vagg, GstBuffer* outbuf) {
  GstStitchSync* self = GST_STITCH_SYNC(vagg);
  StitchSyncState* st = self->state;
  SortedPads sorted(self);
  std::vector<GstVideoAggregatorPad*> pads = sorted.pads;
  if (pads.empty()) return GST_AGGREGATOR_FLOW_NEED_DATA;
  GST_OBJECT_LOCK(self);
  const GstStitchSyncDropout mode = self->dropout;
  const GstClockTime timeout = self->dropout_timeout;
  const GstStitchSyncInputEos input_eos = self->input_eos;
  const bool automatic = self->time_alignment == GST_STITCH_SYNC_TIME_ALIGNMENT_AUTO;
  GST_OBJECT_UNLOCK(self);
  GstAggregator* agg = GST_AGGREGATOR(self);
  GST_OBJECT_LOCK(agg->srcpad);
  const GstClockTime now =
      gst_segment_to_running_time(&GST_AGGREGATOR_PAD(agg->srcpad)->segment, GST_FORMAT_TIME, GST_BUFFER_PTS(outbuf));
  GST_OBJECT_UNLOCK(agg->srcpad);
  {
    const GstFlowReturn ret = wait_for_inputs(self, pads, now, timeout);
    if (ret != GST_FLOW_OK) return ret;
  }
  if (catching_up(self, pads)) return GST_AGGREGATOR_FLOW_NEED_DATA;
  /* The view count follows the pads: a pad requested or released while playing renegotiates
   * the bundle (a pad without caps yet is a missing view), it never holds the output. */
  const guint n = bundle_views(pads);
  if (guint(GST_VIDEO_INFO_VIEWS(&vagg->info)) != n || (st->out_cuda && gst_buffer_n_memory(outbuf) != n)) {
    gst_pad_mark_reconfigure(GST_AGGREGATOR_SRC_PAD(self));
    g_usleep(1000);
    return GST_AGGREGATOR_FLOW_NEED_DATA;
  }
  bool all_ended = true;
  for (GstVideoAggregatorPad* pad : pads) {
    const bool ended = !gst_video_aggregator_pad_get_prepared_frame(pad) && gst_aggregator_pad_is_eos(GST_AGGREGATOR_PAD(pad));
    bool silent;  // never delivered, stood in for by gaps: it does not keep the stream going
    {
      std::lock_guard<std::mutex> guard(st->lock);
      silent = !pad_state(pad)->delivered && pad_state(pad)->standin.sent_until != stitch::sync::kNoTime;
    }
    if (ended && input_eos == GST_STITCH_SYNC_INPUT_EOS_END_STREAM) {
      GST_INFO_OBJECT(self, "%s ended; ending the stream (input-eos=end-stream)", GST_PAD_NAME(pad));
      return GST_FLOW_EOS;
    }
    all_ended = all_ended && (ended || silent);
  }
  /* Every input ended: the base class ends the stream itself only when it does not aggregate on
   * a timeout (live inputs, force-live), where it would repeat the end forever. */
  if (all_ended) {
    GST_INFO_OBJECT(self, "every input ended; ending the stream");
    return GST_FLOW_EOS;
  }
  std::vector<stitch::sync::InputFacts> facts;
  for (GstVideoAggregatorPad* pad : pads) facts.push_back(input_facts(pad));
  const bool live = GST_CLOCK_TIME_IS_VALID(gst_aggregator_get_latency(agg));
  while (pads.size() < n) pads.push_back(NULL);  // a single input left: the second view is missing
  std::vector<DropoutChange> changes;
  std::vector<GstMessage*> qos;
  std::vector<guint> no_signal;
  GstStructure* offsets = NULL;
  guint64 missing = 0;
  gint64 applied[STITCH_MAX_VIEWS] = {0};
  guint64 estimated = 0;
  {
    std::lock_guard<std::mutex> guard(st->lock);
    qos.swap(st->pending_qos);
    offsets = align_inputs(self, pads, automatic, no_signal);
    applied_offsets(self, pads, n, automatic, applied, estimated);
    const guint64 left_out = track_dropouts(self, pads, facts, now, live, mode, timeout, changes);
    const gboolean ok = st->out_cuda ? bundle_in_cuda_memory(self, pads, outbuf, left_out, missing)
                                     : bundle_in_system_memory(self, pads, outbuf, left_out, missing);
    if (!ok) {
      for (GstMessage* m : qos) gst_message_unref(m);
      if (offsets) gst_structure_free(offsets);
      return GST_FLOW_ERROR;
    }
  }
  /* posted without the state lock: bus sync handlers may call back into the element */
  for (GstMessage* m : qos) gst_element_post_message(GST_ELEMENT(self), m);
  for (const DropoutChange& c : changes) post_dropout_change(self, c);
  for (guint v : no_signal)
    GST_ELEMENT_WARNING(self, STREAM, FAILED,
                        ("time-alignment=auto: %s (view %u) shows no motion in common with view 0 to align on; its "
                         "offset stays %s",
                         GST_PAD_NAME(pads[v]), v, pad_state(pads[v])->file_offset_ns ? "load-file's" : "0"),
                        (NULL));
  if (offsets) {
    /* the application hears it on the bus; stitchcalib downstream can save it with the rig */
    gst_pad_push_event(GST_AGGREGATOR_SRC_PAD(self), gst_event_new_custom(GST_EVENT_CUSTOM_DOWNSTREAM, gst_structure_copy(offsets)));
    gst_element_post_message(GST_ELEMENT(self), gst_message_new_element(GST_OBJECT(self), offsets));
  }
  /* the offsets travel with the bundle: stitchcalib saves them with the rig */
  GstStitchBundleMeta* bundle_meta = gst_buffer_add_stitch_bundle_meta(outbuf, n, missing);
  gst_stitch_bundle_meta_set_time_offsets(bundle_meta, applied, n, estimated);
  /* which pad each view comes from: stitchcalib keeps the geometry of the cameras that stay when
   * one leaves (a released pad renumbers the views after it) */
  guint pad_numbers[STITCH_MAX_VIEWS] = {0};
  bool numbered = n <= STITCH_MAX_VIEWS;
  for (guint v = 0; numbered && v < n; ++v) {
    const gchar* name = v < pads.size() && pads[v] ? GST_PAD_NAME(pads[v]) : NULL;
    numbered = name && g_str_has_prefix(name, "sink_");
    if (numbered) pad_numbers[v] = guint(g_ascii_strtoull(name + 5, NULL, 10));
  }
  if (numbered) gst_stitch_bundle_meta_set_pad_numbers(bundle_meta, pad_numbers, n);
  return GST_FLOW_OK;
}

/* Before the first bundle, on the aggregate thread (no lock of ours held), from every input's
 * first frame: non-live inputs whose timestamps all start far from zero (an application's
 * capture clock) start the output at their first frame, and one input that starts far after the
 * others is named in a warning (stitch::sync::first_output_at, starts_far_apart). */
static void check_first_frames(GstStitchSync* self) {
  GstAggregator* agg = GST_AGGREGATOR(self);
  if (GST_CLOCK_TIME_IS_VALID(self->state->started)) return;
  GstClockTime earliest = GST_CLOCK_TIME_NONE, latest = GST_CLOCK_TIME_NONE;
  std::string latest_pad;
  bool every_pad_known = true;
  SortedPads sorted(self);
  for (GstVideoAggregatorPad* p : sorted.pads) {
    GstAggregatorPad* apad = GST_AGGREGATOR_PAD(p);
    GstBuffer* buf = gst_aggregator_pad_peek_buffer(apad);
    if (!buf) {
      every_pad_known = every_pad_known && gst_aggregator_pad_is_eos(apad);
    } else if (GST_BUFFER_PTS_IS_VALID(buf) && !is_standin_gap(buf)) {
      GST_OBJECT_LOCK(p);
      const GstClockTime rt = gst_segment_to_running_time(&apad->segment, GST_FORMAT_TIME, GST_BUFFER_PTS(buf));
      GST_OBJECT_UNLOCK(p);
      if (GST_CLOCK_TIME_IS_VALID(rt) && (!GST_CLOCK_TIME_IS_VALID(earliest) || rt < earliest)) earliest = rt;
      if (GST_CLOCK_TIME_IS_VALID(rt) && (!GST_CLOCK_TIME_IS_VALID(latest) || rt > latest)) {
        latest = rt;
        latest_pad = GST_PAD_NAME(p);
      }
    }
    if (buf) gst_buffer_unref(buf);
  }
  const bool live = GST_CLOCK_TIME_IS_VALID(gst_aggregator_get_latency(agg));
  GST_DEBUG_OBJECT(self, "first frames: earliest %" GST_TIME_FORMAT " latest %" GST_TIME_FORMAT " (%s), every pad known %d, live %d",
                   GST_TIME_ARGS(earliest), GST_TIME_ARGS(latest), latest_pad.c_str(), every_pad_known, live);
  if (live || !every_pad_known || !GST_CLOCK_TIME_IS_VALID(earliest)) return;
  if (stitch::sync::starts_far_apart(as_time(earliest), as_time(latest)) && !self->state->far_start_warned) {
    self->state->far_start_warned = true;
    GST_ELEMENT_WARNING(self, STREAM, FAILED,
                        ("Input %s's first frame is at running time %.3f s, %.3f s after the earliest input's: its "
                         "timestamps may come from another clock; the cameras are paired by running time",
                         latest_pad.c_str(), double(latest) / GST_SECOND, double(latest - earliest) / GST_SECOND),
                        ("give every camera the same time base, or shift this one (gst_pad_set_offset on its "
                         "stitchsync pad, time_offset_ns in load-file, or time-alignment=auto)"));
  }
  GST_OBJECT_LOCK(agg);
  GstSegment* out = &GST_AGGREGATOR_PAD(agg->srcpad)->segment;
  const GstClockTime position = GST_CLOCK_TIME_IS_VALID(out->position) ? MAX(out->position, out->start) : out->start;
  const GstClockTime out_rt = gst_segment_to_running_time(out, GST_FORMAT_TIME, position);
  const gint64 start_rt = stitch::sync::first_output_at(as_time(earliest), as_time(out_rt), gint64(self->dropout_timeout));
  if (start_rt != stitch::sync::kNoTime) {
    const GstClockTime to = gst_segment_position_from_running_time(out, GST_FORMAT_TIME, GstClockTime(start_rt));
    if (GST_CLOCK_TIME_IS_VALID(to)) {
      GST_INFO_OBJECT(self, "the inputs' first frame is at running time %" GST_TIME_FORMAT ": the output starts there, not at %" GST_TIME_FORMAT,
                      GST_TIME_ARGS(earliest), GST_TIME_ARGS(out_rt));
      out->position = to;
    }
  }
  GST_OBJECT_UNLOCK(agg);
}

/* A frame without a timestamp cannot be paired: GstVideoAggregator would stop the stream with a
 * bare flow error (the source then says "Internal data stream error"); this one names the input.
 * Then the first frames' checks, before the base class makes the bundle. */
static GstFlowReturn gst_stitch_sync_aggregate(GstAggregator* agg, gboolean timeout) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  std::string untimed;
  {
    SortedPads sorted(self);
    for (GstVideoAggregatorPad* p : sorted.pads)
      if (GstBuffer* buf = gst_aggregator_pad_peek_buffer(GST_AGGREGATOR_PAD(p))) {  /* (clipped: the frame that goes next) */
        if (!GST_BUFFER_PTS_IS_VALID(buf) && untimed.empty()) untimed = GST_PAD_NAME(p);
        gst_buffer_unref(buf);
      }
  }
  if (!untimed.empty()) {
    GST_ELEMENT_ERROR(self, STREAM, FORMAT,
                      ("Input %s sends frames without a timestamp (PTS): stitchsync pairs the cameras' frames by their timestamps",
                       untimed.c_str()),
                      ("set each buffer's PTS (and duration); an appsrc camera can stamp them itself with "
                       "is-live=true do-timestamp=true"));
    return GST_FLOW_ERROR;
  }
  check_first_frames(self);
  return GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->aggregate(agg, timeout);
}

static gboolean gst_stitch_sync_start(GstAggregator* agg) {
  if (!GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->start(agg)) return FALSE;
  watch_start(GST_STITCH_SYNC(agg));
  return TRUE;
}

static gboolean gst_stitch_sync_stop(GstAggregator* agg) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  watch_stop(self);
  {
    std::lock_guard<std::mutex> guard(self->state->lock);
    self->state->clear();
    SortedPads sorted(self);
    for (GstVideoAggregatorPad* p : sorted.pads) {
      SyncPadState& ps = *pad_state(p);
      ps.release();
      ps.track = {};
      ps.newest_end = GST_CLOCK_TIME_NONE;
      ps.applied_ns = 0;  // the segments go with the stop
      ps.delivered = false;
      ps.reset_standin();
    }
  }
  return GST_AGGREGATOR_CLASS(gst_stitch_sync_parent_class)->stop(agg);
}

static GstFlowReturn gst_stitch_sync_flush(GstAggregator* agg) {
  GstStitchSync* self = GST_STITCH_SYNC(agg);
  {
    std::lock_guard<std::mutex> guard(self->state->lock);
    self->state->clear_run();
    SortedPads sorted(self);
    for (GstVideoAggregatorPad* p : sorted.pads) {
      pad_state(p)->release();
      pad_state(p)->track = {};
      pad_state(p)->reset_standin();
    }
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
    case PROP_INPUT_EOS:
      GST_OBJECT_LOCK(self);
      self->input_eos = GstStitchSyncInputEos(g_value_get_enum(value));
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_TIME_ALIGNMENT:
      GST_OBJECT_LOCK(self);
      self->time_alignment = GstStitchSyncTimeAlignment(g_value_get_enum(value));
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_LOAD_FILE:
      GST_OBJECT_LOCK(self);
      g_free(self->load_file);
      self->load_file = g_value_dup_string(value);
      GST_OBJECT_UNLOCK(self);
      break;
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
    case PROP_INPUT_EOS:
      GST_OBJECT_LOCK(self);
      g_value_set_enum(value, self->input_eos);
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_TIME_ALIGNMENT:
      GST_OBJECT_LOCK(self);
      g_value_set_enum(value, self->time_alignment);
      GST_OBJECT_UNLOCK(self);
      break;
    case PROP_LOAD_FILE:
      GST_OBJECT_LOCK(self);
      g_value_set_string(value, self->load_file);
      GST_OBJECT_UNLOCK(self);
      break;
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
  g_free(self->load_file);
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

  g_object_class_install_property(
      gobject_class, PROP_TIME_ALIGNMENT,
      g_param_spec_enum("time-alignment", "Time alignment",
                        "none: frames are paired by running time (plus each pad's offset and load-file's); auto: "
                        "each input's offset to sink_0 and its clock rate are estimated from the motion the cameras "
                        "see, applied, and posted as stitchsync-time-offsets messages",
                        GST_TYPE_STITCH_SYNC_TIME_ALIGNMENT, DEFAULT_TIME_ALIGNMENT,
                        GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS | GST_PARAM_MUTABLE_PLAYING)));
  g_object_class_install_property(
      gobject_class, PROP_LOAD_FILE,
      g_param_spec_string("load-file", "Load file",
                          "Calibration JSON (stitchcalib's) whose cameras' time_offset_ns are added to the inputs' "
                          "running times (view i = camera i); with time-alignment=auto, until the first estimate",
                          NULL, GParamFlags(G_PARAM_READWRITE | G_PARAM_STATIC_STRINGS | GST_PARAM_MUTABLE_READY)));
  gst_element_class_add_static_pad_template_with_gtype(element_class, &sink_template,
                                                       gst_stitch_sync_pad_get_type());
  gst_element_class_add_static_pad_template_with_gtype(element_class, &src_template,
                                                       GST_TYPE_AGGREGATOR_PAD);
  gst_element_class_set_static_metadata(
      element_class, "Stitch synchronizer", "Video/Combiner",
      "Synchronises N camera streams by running time into one multiview bundle per output frame",
      "gst-stitch developers");

  element_class->request_new_pad = GST_DEBUG_FUNCPTR(gst_stitch_sync_request_new_pad);
  element_class->release_pad = GST_DEBUG_FUNCPTR(gst_stitch_sync_release_pad);
  element_class->set_context = GST_DEBUG_FUNCPTR(gst_stitch_sync_set_context);
  agg_class->sink_event = GST_DEBUG_FUNCPTR(gst_stitch_sync_sink_event);
  agg_class->clip = GST_DEBUG_FUNCPTR(gst_stitch_sync_clip);
  agg_class->aggregate = GST_DEBUG_FUNCPTR(gst_stitch_sync_aggregate);
  agg_class->sink_query = GST_DEBUG_FUNCPTR(gst_stitch_sync_sink_query);
  agg_class->src_query = GST_DEBUG_FUNCPTR(gst_stitch_sync_src_query);
  agg_class->fixate_src_caps = GST_DEBUG_FUNCPTR(gst_stitch_sync_fixate_src_caps);
  agg_class->negotiated_src_caps = GST_DEBUG_FUNCPTR(gst_stitch_sync_negotiated_src_caps);
  agg_class->start = GST_DEBUG_FUNCPTR(gst_stitch_sync_start);
  agg_class->stop = GST_DEBUG_FUNCPTR(gst_stitch_sync_stop);
  agg_class->flush = GST_DEBUG_FUNCPTR(gst_stitch_sync_flush);
  vagg_class->update_caps = GST_DEBUG_FUNCPTR(gst_stitch_sync_update_caps);
  vagg_class->create_output_buffer = GST_DEBUG_FUNCPTR(gst_stitch_sync_create_output_buffer);
  vagg_class->aggregate_frames = GST_DEBUG_FUNCPTR(gst_stitch_sync_aggregate_frames);

  gst_type_mark_as_plugin_api(GST_TYPE_STITCH_SYNC_INPUT_EOS, GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(GST_TYPE_STITCH_SYNC_DROPOUT, GstPluginAPIFlags(0));
  gst_type_mark_as_plugin_api(GST_TYPE_STITCH_SYNC_TIME_ALIGNMENT, GstPluginAPIFlags(0));
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
  self->time_alignment = DEFAULT_TIME_ALIGNMENT;
  self->load_file = NULL;
  self->state = new StitchSyncState();
}
