// Glass-to-glass latency through the stitch chain with live sources (issue 17 item 5), in the
// pipeline clock: for every panorama, from the capture time of the frames it contains to the time
// it reaches the sink.
//
// A live source's capture time is the running time of its buffer (GStreamer's convention for live
// sources; videotestsrc is-live pushes each frame at that time). stitchsync's output timestamps are
// NOT capture times: they lie on GstVideoAggregator's output grid (0, 1/fps, 2/fps, ... from the
// output segment's start), while each camera started at its own phase, and the frame a bundle holds
// for the grid slot [T, T + 1/fps) is the newest one that starts before T + 1/fps. "now - running
// time of the panorama" therefore measures from the grid slot, not from any capture, and is off by
// up to a frame either way. Here the capture times are looked up instead: a probe on the pad that
// feeds each stitchsync input records every frame's running time in its own (upstream) segment by
// PTS; a probe on stitchsync's source pad, which runs in the aggregator's thread right after the
// bundle was made, reads the frame each input holds (gst_video_aggregator_pad_get_current_buffer)
// and files the newest and oldest capture time under the bundle's PTS; the sink probe takes them
// back by PTS (the stages keep the bundle's timestamps).
//
// Header-only: used by bench/bench_e2e.cpp and tests/pipelines/test_latency.cpp.
#pragma once
#include <gst/gst.h>
#include <gst/video/video.h>

#include <algorithm>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>
#include <vector>

namespace livelat {

struct Sample {
  GstClockTime pts = GST_CLOCK_TIME_NONE;
  double newest_ms = 0;     // sink time - newest capture in the panorama (the brief's figure)
  double oldest_ms = 0;     // sink time - oldest capture in it (the stalest view on screen)
  double grid_ms = 0;       // sink time - running time of the panorama (the old, invalid probe)
  double sync_ms = 0;       // stitchsync's output time - newest capture (the aggregator's share)
  double stages_ms = 0;     // sink time - stitchsync's output time (calib, color, flow warp, blend)
  int views = 0, views_with_capture = 0;
};

struct Summary {
  int samples = 0, unmatched = 0;
  double frame_ms = 0;            // the panorama's frame period
  double configured_ms = 0;       // stitchsync's `latency` property (GstAggregator latency)
  bool query_live = false;        // the LATENCY query at stitchsync's source pad
  double query_min_ms = -1, query_max_ms = -1;
  double newest_median_ms = -1, newest_p99_ms = -1, newest_min_ms = -1, newest_max_ms = -1;
  double oldest_median_ms = -1, oldest_p99_ms = -1;
  double grid_median_ms = -1, grid_min_ms = -1;
  double sync_median_ms = -1, stages_median_ms = -1;
  // added latency of the stitch chain = measured (newest capture -> sink) - configured, in frames
  double added_median_frames = 0, added_p99_frames = 0;
};

inline double quantile(std::vector<double> v, double q) {
  if (v.empty()) return -1;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, size_t(q * double(v.size() - 1) + 0.5))];
}

class Meter {
 public:
  Meter() = default;
  Meter(const Meter&) = delete;
  Meter& operator=(const Meter&) = delete;
  ~Meter() { detach(); }

  // `sync`: stitchsync (or any GstVideoAggregator) whose sink pads are all linked already;
  // `sink_pad`: where the panorama arrives. Call before PLAYING. False when `sync` is no
  // GstVideoAggregator or has no linked input.
  bool attach(GstElement* pipeline, GstElement* sync, GstPad* sink_pad) {
    if (!GST_IS_VIDEO_AGGREGATOR(sync)) return false;
    pipeline_ = GST_ELEMENT(gst_object_ref(pipeline));
    sync_ = GST_ELEMENT(gst_object_ref(sync));
    GST_OBJECT_LOCK(sync);
    for (GList* l = GST_ELEMENT(sync)->sinkpads; l; l = l->next) inputs_.push_back(Input{GST_PAD(gst_object_ref(l->data))});
    GST_OBJECT_UNLOCK(sync);
    for (Input& in : inputs_) {
      in.peer = gst_pad_get_peer(in.pad);
      if (!in.peer) continue;
      in.probe = gst_pad_add_probe(in.peer, GST_PAD_PROBE_TYPE_BUFFER, &Meter::on_input, this, nullptr);
    }
    src_pad_ = gst_element_get_static_pad(sync, "src");
    src_probe_ = gst_pad_add_probe(src_pad_, GST_PAD_PROBE_TYPE_BUFFER, &Meter::on_bundle, this, nullptr);
    sink_pad_ = GST_PAD(gst_object_ref(sink_pad));
    sink_probe_ = gst_pad_add_probe(sink_pad_, GST_PAD_PROBE_TYPE_BUFFER, &Meter::on_panorama, this, nullptr);
    return !inputs_.empty();
  }

  // Reads the configured and reported latency; call while PLAYING (after the first panorama).
  void read_configuration() {
    if (!sync_) return;
    GstClockTime configured = 0;
    g_object_get(sync_, "latency", &configured, nullptr);
    std::lock_guard<std::mutex> g(lock_);
    summary_config_.configured_ms = double(configured) / 1e6;
    GstQuery* q = gst_query_new_latency();
    if (gst_pad_query(src_pad_, q)) {
      gboolean live = FALSE;
      GstClockTime mn = 0, mx = GST_CLOCK_TIME_NONE;
      gst_query_parse_latency(q, &live, &mn, &mx);
      summary_config_.query_live = live;
      summary_config_.query_min_ms = double(mn) / 1e6;
      summary_config_.query_max_ms = GST_CLOCK_TIME_IS_VALID(mx) ? double(mx) / 1e6 : -1;
    }
    gst_query_unref(q);
  }

  void detach() {
    for (Input& in : inputs_) {
      if (in.peer && in.probe) gst_pad_remove_probe(in.peer, in.probe);
      if (in.peer) gst_object_unref(in.peer);
      gst_object_unref(in.pad);
    }
    inputs_.clear();
    if (src_pad_) {
      gst_pad_remove_probe(src_pad_, src_probe_);
      gst_object_unref(src_pad_);
      src_pad_ = nullptr;
    }
    if (sink_pad_) {
      gst_pad_remove_probe(sink_pad_, sink_probe_);
      gst_object_unref(sink_pad_);
      sink_pad_ = nullptr;
    }
    if (sync_) gst_object_unref(sync_);
    if (pipeline_) gst_object_unref(pipeline_);
    sync_ = pipeline_ = nullptr;
  }

  std::vector<Sample> samples() const {
    std::lock_guard<std::mutex> g(lock_);
    return samples_;
  }

  // Over the panoramas after the first `skip` (start-up).
  Summary summarize(size_t skip) const {
    std::lock_guard<std::mutex> g(lock_);
    Summary s = summary_config_;
    s.unmatched = unmatched_;
    s.frame_ms = frame_ms_;
    std::vector<double> newest, oldest, grid, sync, stages;
    for (size_t i = skip; i < samples_.size(); ++i) {
      const Sample& x = samples_[i];
      newest.push_back(x.newest_ms);
      oldest.push_back(x.oldest_ms);
      grid.push_back(x.grid_ms);
      sync.push_back(x.sync_ms);
      stages.push_back(x.stages_ms);
    }
    s.samples = int(newest.size());
    if (newest.empty()) return s;
    s.newest_median_ms = quantile(newest, 0.5);
    s.newest_p99_ms = quantile(newest, 0.99);
    s.newest_min_ms = quantile(newest, 0);
    s.newest_max_ms = quantile(newest, 1);
    s.oldest_median_ms = quantile(oldest, 0.5);
    s.oldest_p99_ms = quantile(oldest, 0.99);
    s.grid_median_ms = quantile(grid, 0.5);
    s.grid_min_ms = quantile(grid, 0);
    s.sync_median_ms = quantile(sync, 0.5);
    s.stages_median_ms = quantile(stages, 0.5);
    if (s.frame_ms > 0) {
      s.added_median_frames = (s.newest_median_ms - s.configured_ms) / s.frame_ms;
      s.added_p99_frames = (s.newest_p99_ms - s.configured_ms) / s.frame_ms;
    }
    return s;
  }

 private:
  struct Input {
    GstPad* pad;  // stitchsync's sink pad
    GstPad* peer = nullptr;
    gulong probe = 0;
  };
  struct Bundle {
    GstClockTime newest = GST_CLOCK_TIME_NONE, oldest = GST_CLOCK_TIME_NONE, out = GST_CLOCK_TIME_NONE;
    int views = 0, with_capture = 0;
  };

  // running time now, in the pipeline's clock
  GstClockTime now() const {
    GstClock* clock = gst_element_get_clock(pipeline_);
    if (!clock) return GST_CLOCK_TIME_NONE;
    const GstClockTime t = gst_clock_get_time(clock) - gst_element_get_base_time(pipeline_);
    gst_object_unref(clock);
    return t;
  }

  static GstClockTime running_time(GstPad* pad, GstBuffer* buf) {
    if (!GST_BUFFER_PTS_IS_VALID(buf)) return GST_CLOCK_TIME_NONE;
    GstEvent* ev = gst_pad_get_sticky_event(pad, GST_EVENT_SEGMENT, 0);
    if (!ev) return GST_CLOCK_TIME_NONE;
    const GstSegment* seg = nullptr;
    gst_event_parse_segment(ev, &seg);
    const GstClockTime rt = seg->format == GST_FORMAT_TIME ? gst_segment_to_running_time(seg, GST_FORMAT_TIME, GST_BUFFER_PTS(buf))
                                                          : GST_CLOCK_TIME_NONE;
    gst_event_unref(ev);
    return rt;
  }

  // upstream of a stitchsync input: the frame's capture time, filed by PTS
  static GstPadProbeReturn on_input(GstPad* pad, GstPadProbeInfo* info, gpointer data) {
    Meter* m = static_cast<Meter*>(data);
    GstBuffer* buf = GST_PAD_PROBE_INFO_BUFFER(info);
    const GstClockTime rt = running_time(pad, buf);
    if (!GST_CLOCK_TIME_IS_VALID(rt)) return GST_PAD_PROBE_OK;
    std::lock_guard<std::mutex> g(m->lock_);
    auto& by_pts = m->captures_[pad];
    by_pts[GST_BUFFER_PTS(buf)] = rt;
    while (by_pts.size() > 256) by_pts.erase(by_pts.begin());
    return GST_PAD_PROBE_OK;
  }

  // stitchsync's output, in its own thread right after the bundle was made: which frames it holds
  static GstPadProbeReturn on_bundle(GstPad*, GstPadProbeInfo* info, gpointer data) {
    Meter* m = static_cast<Meter*>(data);
    GstBuffer* out = GST_PAD_PROBE_INFO_BUFFER(info);
    Bundle b;
    b.out = m->now();
    std::lock_guard<std::mutex> g(m->lock_);
    for (const Input& in : m->inputs_) {
      ++b.views;
      GstBuffer* cur = gst_video_aggregator_pad_get_current_buffer(GST_VIDEO_AGGREGATOR_PAD(in.pad));
      if (!cur || !GST_BUFFER_PTS_IS_VALID(cur) || !in.peer) continue;
      auto pit = m->captures_.find(in.peer);
      if (pit == m->captures_.end()) continue;
      auto it = pit->second.find(GST_BUFFER_PTS(cur));
      if (it == pit->second.end()) continue;
      ++b.with_capture;
      const GstClockTime c = it->second;
      if (!GST_CLOCK_TIME_IS_VALID(b.newest) || c > b.newest) b.newest = c;
      if (!GST_CLOCK_TIME_IS_VALID(b.oldest) || c < b.oldest) b.oldest = c;
    }
    if (b.with_capture > 0 && GST_BUFFER_PTS_IS_VALID(out)) {
      m->bundles_[GST_BUFFER_PTS(out)] = b;
      while (m->bundles_.size() > 256) m->bundles_.erase(m->bundles_.begin());
    }
    return GST_PAD_PROBE_OK;
  }

  static GstPadProbeReturn on_panorama(GstPad* pad, GstPadProbeInfo* info, gpointer data) {
    Meter* m = static_cast<Meter*>(data);
    GstBuffer* buf = GST_PAD_PROBE_INFO_BUFFER(info);
    const GstClockTime t = m->now();
    const GstClockTime rt = running_time(pad, buf);
    double frame_ms = 0;
    if (GstCaps* caps = gst_pad_get_current_caps(pad)) {
      gint n = 0, d = 1;
      if (gst_structure_get_fraction(gst_caps_get_structure(caps, 0), "framerate", &n, &d) && n > 0)
        frame_ms = 1000.0 * d / n;
      gst_caps_unref(caps);
    }
    std::lock_guard<std::mutex> g(m->lock_);
    if (frame_ms > 0) m->frame_ms_ = frame_ms;
    auto it = GST_BUFFER_PTS_IS_VALID(buf) ? m->bundles_.find(GST_BUFFER_PTS(buf)) : m->bundles_.end();
    if (it == m->bundles_.end() || !GST_CLOCK_TIME_IS_VALID(t)) {
      ++m->unmatched_;
      return GST_PAD_PROBE_OK;
    }
    const Bundle& b = it->second;
    Sample s;
    s.pts = GST_BUFFER_PTS(buf);
    s.newest_ms = (double(t) - double(b.newest)) / 1e6;
    s.oldest_ms = (double(t) - double(b.oldest)) / 1e6;
    s.grid_ms = GST_CLOCK_TIME_IS_VALID(rt) ? (double(t) - double(rt)) / 1e6 : 0;
    s.sync_ms = (double(b.out) - double(b.newest)) / 1e6;
    s.stages_ms = (double(t) - double(b.out)) / 1e6;
    s.views = b.views;
    s.views_with_capture = b.with_capture;
    m->samples_.push_back(s);
    m->bundles_.erase(m->bundles_.begin(), std::next(it));
    return GST_PAD_PROBE_OK;
  }

  mutable std::mutex lock_;
  GstElement *pipeline_ = nullptr, *sync_ = nullptr;
  std::vector<Input> inputs_;
  GstPad *src_pad_ = nullptr, *sink_pad_ = nullptr;
  gulong src_probe_ = 0, sink_probe_ = 0;
  std::map<GstPad*, std::map<GstClockTime, GstClockTime>> captures_;
  std::map<GstClockTime, Bundle> bundles_;
  std::vector<Sample> samples_;
  int unmatched_ = 0;
  double frame_ms_ = 0;
  Summary summary_config_;
};

// stitchsync in `pipeline` (at any depth: stitchbin holds one), or null; a new reference.
inline GstElement* find_stitchsync(GstElement* pipeline) {
  GstElement* found = nullptr;
  GstIterator* it = gst_bin_iterate_recurse(GST_BIN(pipeline));
  GValue v = G_VALUE_INIT;
  while (!found && gst_iterator_next(it, &v) == GST_ITERATOR_OK) {
    GstElement* e = GST_ELEMENT(g_value_get_object(&v));
    GstElementFactory* f = gst_element_get_factory(e);
    if (f && !g_strcmp0(GST_OBJECT_NAME(f), "stitchsync")) found = GST_ELEMENT(gst_object_ref(e));
    g_value_reset(&v);
  }
  g_value_unset(&v);
  gst_iterator_free(it);
  return found;
}

struct LiveRun {
  Summary summary;
  std::vector<Sample> samples;
  int panoramas = 0;
  std::string error;
};

// Runs `description` (live sources into a stitchsync, the panorama into an element named "sink")
// to EOS, an error or `timeout_s`; summarises the panoramas after the first `skip`.
inline LiveRun run_live(const std::string& description, size_t skip, int timeout_s) {
  LiveRun r;
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(description.c_str(), &err);
  if (!pipe || err) {
    r.error = err ? err->message : "parse error";
    g_clear_error(&err);
    if (pipe) gst_object_unref(pipe);
    return r;
  }
  GstElement* sync = find_stitchsync(pipe);
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipe), "sink");
  GstPad* pad = sink ? gst_element_get_static_pad(sink, "sink") : nullptr;
  Meter meter;
  if (!sync || !pad || !meter.attach(pipe, sync, pad)) {
    r.error = !sync ? "no stitchsync" : !pad ? "no element named sink" : "stitchsync has no linked input";
  } else {
    gst_element_set_state(pipe, GST_STATE_PLAYING);
    GstBus* bus = gst_element_get_bus(pipe);
    const gint64 until = g_get_monotonic_time() + gint64(timeout_s) * G_USEC_PER_SEC;
    bool configured = false, done = false;
    while (!done) {
      GstMessage* m = gst_bus_timed_pop_filtered(bus, 50 * GST_MSECOND, GstMessageType(GST_MESSAGE_EOS | GST_MESSAGE_ERROR));
      if (m) {
        if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) {
          GError* e = nullptr;
          gst_message_parse_error(m, &e, nullptr);
          r.error = e ? e->message : "error";
          g_clear_error(&e);
        }
        gst_message_unref(m);
        done = true;
      }
      if (!configured && !meter.samples().empty()) {
        meter.read_configuration();
        configured = true;
      }
      if (!done && g_get_monotonic_time() > until) {
        r.error = "timed out";
        done = true;
      }
    }
    gst_object_unref(bus);
    gst_element_set_state(pipe, GST_STATE_NULL);
  }
  r.samples = meter.samples();
  r.panoramas = int(r.samples.size());
  r.summary = meter.summarize(skip);
  meter.detach();
  if (pad) gst_object_unref(pad);
  if (sink) gst_object_unref(sink);
  if (sync) gst_object_unref(sync);
  gst_object_unref(pipe);
  return r;
}

}  // namespace livelat
