/* stitchsync: standing in for non-live inputs that deliver nothing.
 *
 * GstAggregator waits for data on every non-live sink pad before it aggregates, so a file or
 * appsrc branch that never delivers would hold every other camera forever. Once
 * `dropout-timeout` has passed since the first real frame came in, this thread sends such a pad
 * GAP events (stitch::sync::standin_gap_due: short spans, kept just ahead of the output): the base
 * class queues each as an empty GAP buffer, which GstVideoAggregator takes as "no frame", so the
 * others go on, the view is missing (the dropout policy warns, naming the pad), and the camera
 * joins with its first real frame. Live pipelines need none of this: the base class aggregates
 * on its latency timeout. */
#include <chrono>

#include "gststitchsyncpriv.h"

#define GST_CAT_DEFAULT gst_stitch_sync_debug

/* one gap: short, so that a camera that starts late is not held back by gaps queued far ahead */
#define STANDIN_SPAN (100 * GST_MSECOND)

static void stand_in(GstStitchSync* self) {
  StitchSyncState* st = self->state;
  const gint64 first = st->first_data_us;
  if (first < 0) return;
  GstAggregator* agg = GST_AGGREGATOR(self);
  const bool live = GST_CLOCK_TIME_IS_VALID(gst_aggregator_get_latency(agg));
  GST_OBJECT_LOCK(self);
  const GstClockTime timeout = self->dropout_timeout;
  std::vector<GstPad*> pads;
  for (GList* l = GST_ELEMENT(self)->sinkpads; l; l = l->next) pads.push_back(GST_PAD(gst_object_ref(l->data)));
  GST_OBJECT_UNLOCK(self);
  GST_OBJECT_LOCK(agg->srcpad);
  const GstClockTime out = GST_AGGREGATOR_PAD(agg->srcpad)->segment.position;
  GST_OBJECT_UNLOCK(agg->srcpad);
  const gint64 since = (g_get_monotonic_time() - first) * 1000;
  for (GstPad* pad : pads) {
    gint64 start = 0;
    bool due, first_gap;
    {
      std::lock_guard<std::mutex> guard(st->lock);
      SyncPadState& ps = *pad_state(pad);
      first_gap = ps.standin.sent_until == stitch::sync::kNoTime;
      due = stitch::sync::standin_gap_due(ps.standin, live, ps.delivered, since, gint64(timeout),
                                          GST_CLOCK_TIME_IS_VALID(out) ? gint64(out) : stitch::sync::kNoTime,
                                          gint64(STANDIN_SPAN), start);
    }
    if (due) {
      if (first_gap)
        GST_INFO_OBJECT(pad, "delivered nothing %" GST_TIME_FORMAT " after the first input: standing in with gaps",
                        GST_TIME_ARGS(GstClockTime(since)));
      /* a gap needs a time segment: a silent input may have sent none (appsrc sends it with the
       * first buffer); its own stream-start and segment replace ours when it starts */
      GST_OBJECT_LOCK(pad);
      const bool timed = GST_AGGREGATOR_PAD(pad)->segment.format == GST_FORMAT_TIME;
      GST_OBJECT_UNLOCK(pad);
      bool segment_sent;
      {
        std::lock_guard<std::mutex> guard(st->lock);
        segment_sent = pad_state(pad)->standin_segment;
        pad_state(pad)->standin_segment = true;
      }
      if (!timed && !segment_sent) {
        if (GstEvent* ss = gst_pad_get_sticky_event(pad, GST_EVENT_STREAM_START, 0)) {
          gst_event_unref(ss);
        } else {
          gchar* id = g_strdup_printf("stitchsync-standin-%s", GST_PAD_NAME(pad));
          gst_pad_send_event(pad, gst_event_new_stream_start(id));
          g_free(id);
        }
        GstSegment seg;
        gst_segment_init(&seg, GST_FORMAT_TIME);
        GstEvent* ev = gst_event_new_segment(&seg);
        {
          /* noted before it is sent: caps that come meanwhile find it (standin_caps) */
          std::lock_guard<std::mutex> guard(st->lock);
          pad_state(pad)->standin_seqnum = gst_event_get_seqnum(ev);
        }
        gst_pad_send_event(pad, ev);
      }
      /* (ours, while it is queued or in place, maps running time to itself) */
      GstClockTime ts = GST_CLOCK_TIME_NONE;
      GST_OBJECT_LOCK(pad);
      if (timed)
        ts = gst_segment_position_from_running_time(&GST_AGGREGATOR_PAD(pad)->segment, GST_FORMAT_TIME,
                                                    GstClockTime(start));
      GST_OBJECT_UNLOCK(pad);
      if (!GST_CLOCK_TIME_IS_VALID(ts)) ts = GstClockTime(start);
      gst_pad_send_event(pad, gst_event_new_gap(ts, STANDIN_SPAN));
    }
    gst_object_unref(pad);
  }
}

static GstPadProbeReturn arrived(GstPad* pad, GstPadProbeInfo* info, gpointer) {
  if (GST_PAD_PROBE_INFO_TYPE(info) & GST_PAD_PROBE_TYPE_BUFFER) {
    GstBuffer* b = GST_PAD_PROBE_INFO_BUFFER(info);
    if (is_standin_gap(b)) return GST_PAD_PROBE_OK;
  }
  GstObject* parent = gst_pad_get_parent(pad);
  if (parent && GST_IS_STITCH_SYNC(parent)) {
    StitchSyncState* st = GST_STITCH_SYNC(parent)->state;
    gint64 none = -1;
    st->first_data_us.compare_exchange_strong(none, g_get_monotonic_time());
    std::lock_guard<std::mutex> guard(st->lock);
    pad_state(pad)->delivered = true;
  }
  if (parent) gst_object_unref(parent);
  return GST_PAD_PROBE_OK;
}

/* Our stand-in segment is stored on the pad as a sticky event. The camera's own stream-start
 * replaces ours, but its caps would come after a segment: GStreamer stores sticky events in
 * their order (stream-start, caps, segment) and warns "Sticky event misordering, got 'segment'
 * before 'caps'". So when its caps come (this probe runs before they are stored), our segment
 * goes; the base class keeps using it until the camera's own segment, which follows the caps. */
static gboolean drop_standin_segment(GstPad*, GstEvent** event, gpointer seqnum) {
  if (GST_EVENT_TYPE(*event) == GST_EVENT_SEGMENT && gst_event_get_seqnum(*event) == GPOINTER_TO_UINT(seqnum))
    gst_clear_event(event);
  return TRUE;
}

static GstPadProbeReturn standin_caps(GstPad* pad, GstPadProbeInfo* info, gpointer) {
  if (GST_EVENT_TYPE(GST_PAD_PROBE_INFO_EVENT(info)) != GST_EVENT_CAPS) return GST_PAD_PROBE_OK;
  GstObject* parent = gst_pad_get_parent(pad);
  if (parent && GST_IS_STITCH_SYNC(parent)) {
    guint32 seqnum;
    {
      std::lock_guard<std::mutex> guard(GST_STITCH_SYNC(parent)->state->lock);
      seqnum = pad_state(pad)->standin_seqnum;
      pad_state(pad)->standin_seqnum = GST_SEQNUM_INVALID;
    }
    if (seqnum != GST_SEQNUM_INVALID) {
      GST_DEBUG_OBJECT(pad, "the camera's caps came: the stand-in segment goes");
      gst_pad_sticky_events_foreach(pad, drop_standin_segment, GUINT_TO_POINTER(seqnum));
    }
  }
  if (parent) gst_object_unref(parent);
  return GST_PAD_PROBE_OK;
}

void watch_arrivals(GstPad* pad) {
  gst_pad_add_probe(pad, GstPadProbeType(GST_PAD_PROBE_TYPE_BUFFER | GST_PAD_PROBE_TYPE_BUFFER_LIST), arrived, NULL, NULL);
  gst_pad_add_probe(pad, GST_PAD_PROBE_TYPE_EVENT_DOWNSTREAM, standin_caps, NULL, NULL);
}

void watch_start(GstStitchSync* self) {
  StitchSyncState* st = self->state;
  watch_stop(self);
  {
    std::lock_guard<std::mutex> guard(st->watch_lock);
    st->watch_run = true;
  }
  st->watch = std::thread([self, st]() {
    std::unique_lock<std::mutex> lk(st->watch_lock);
    while (st->watch_run) {
      st->watch_cv.wait_for(lk, std::chrono::milliseconds(5));
      if (!st->watch_run) break;
      lk.unlock();
      stand_in(self);
      lk.lock();
    }
  });
}

void watch_stop(GstStitchSync* self) {
  StitchSyncState* st = self->state;
  {
    std::lock_guard<std::mutex> guard(st->watch_lock);
    st->watch_run = false;
  }
  st->watch_cv.notify_all();
  if (st->watch.joinable()) st->watch.join();
}
