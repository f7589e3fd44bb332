/* stitchsync's private parts, shared by gststitchsync.cpp (the element: negotiation, start-up,
 * dropouts, properties) and gststitchsyncviews.cpp (assembling the bundle's views, applying
 * time offsets). C++ only, not installed. */
#pragma once

#include <array>
#include <atomic>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <gst/audio/audio.h>

#include "gststitchbundle.h"
#include "gststitchcuda.h"
#include "gststitchsync.h"
#include "stitch/convert/convert.hpp"
#include "stitch/sync/audio_align.hpp"
#include "stitch/sync/policy.hpp"
#include "stitch/sync/thumbnail.hpp"
#include "stitch/sync/time_align.hpp"

GST_DEBUG_CATEGORY_EXTERN(gst_stitch_sync_debug);

/* at most one QoS message per input per second (each carries the running totals) */
#define QOS_INTERVAL GST_SECOND

/* One of our stand-in gaps as GstAggregator queues it: an empty GAP buffer. */
static inline bool is_standin_gap(GstBuffer* buf) {
  return GST_BUFFER_FLAG_IS_SET(buf, GST_BUFFER_FLAG_GAP) && gst_buffer_get_size(buf) == 0;
}

/* Per-input state, on the pad object itself (GstStitchSyncPad::st): it lives exactly as long as
 * the pad, so a released pad's state goes with it. Guarded by StitchSyncState::lock. */
struct SyncPadState {
  /* Last real frame, reused while a live camera is late. */
  /* system-memory bundles: the view's memory, held alive */
  GstBuffer* buffer = nullptr;
  gint width = 0, height = 0, stride = 0;
  gsize offset = 0;
  /* CUDA-memory bundles: the input frame, converted again when repeated */
  GstBuffer* frame = nullptr;
  GstVideoInfo frame_info;
  /* dropout bookkeeping (stitch::sync::update_dropout) */
  stitch::sync::DropoutTrack track;
  /* the element's clock running time when the pad was requested while playing (NONE before):
   * a live output that lags behind the clock must not count the pad as silent from its own,
   * earlier, time */
  GstClockTime requested_rt = GST_CLOCK_TIME_NONE;
  /* end (running time) of the newest frame taken in, to drop frames from the past (QoS) */
  GstClockTime newest_end = GST_CLOCK_TIME_NONE;
  guint64 processed = 0, late = 0;
  stitch::sync::RateLimit qos{gint64(QOS_INTERVAL)};
  /* time alignment: ns added to the segment's running time by us, the file's value, the
   * newest frame whose signal was taken */
  gint64 applied_ns = 0;
  gint64 file_offset_ns = 0;
  GstClockTime signal_pts = GST_CLOCK_TIME_NONE;
  /* CUDA-memory input: the frame whose thumbnail is in flight on the device (thumbnailer slot
   * thumb_slot, taken a bundle later), held until then, and its uncorrected running time */
  GstBuffer* thumb_frame = nullptr;
  gint64 thumb_t = 0;
  int thumb_slot = -1;
  /* a real frame came in (gaps do not count); the gaps sent in its stead while it had not */
  bool delivered = false;
  stitch::sync::StandIn standin;
  bool standin_segment = false;  // a time segment was sent for the gaps
  /* seqnum of that segment while it is stored on the pad as a sticky event (0: none): it goes
   * when the camera's own caps come (GStreamer wants stream-start, caps, segment in this order) */
  guint32 standin_seqnum = GST_SEQNUM_INVALID;
  /* the camera joins (clip): our gaps still queued ahead of its first frame are dropped, and so
   * are its frames that end before the gaps already shown (standin_end, running time), at once,
   * instead of one per output frame (GstVideoAggregator's "from the past"); done with its first
   * frame that is shown */
  GstClockTime standin_end = GST_CLOCK_TIME_NONE;
  bool standin_done = false;
  bool standing_in() const { return standin.sent_until != stitch::sync::kNoTime && !standin_done; }
  void reset_standin() {
    standin = {};
    standin_segment = false;
    standin_seqnum = GST_SEQNUM_INVALID;
    standin_end = GST_CLOCK_TIME_NONE;
    standin_done = false;
  }

  void release() {
    gst_clear_buffer(&buffer);
    gst_clear_buffer(&frame);
    signal_pts = GST_CLOCK_TIME_NONE;
    clear_thumbnail();
  }
  void clear_thumbnail() {
    gst_clear_buffer(&thumb_frame);
    thumb_slot = -1;
  }
};

struct StitchSyncState {
  std::mutex lock;  // guards the pads' SyncPadState and what follows
  /* CUDA-memory bundles (aggregate thread; the pads read out_cuda) */
  std::atomic<bool> out_cuda{false};
  StitchCudaContext cuda;
  StitchCudaOwned<stitch::FrameConverter> converter;
  /* time-alignment=auto on CUDA-memory inputs: each frame's thumbnail made on the device */
  StitchCudaOwned<stitch::sync::FrameThumbnailerCuda> thumbnailer;
  GstBufferPool* pool = nullptr;
  std::vector<std::array<int, 2>> pool_sizes;
  /* QoS messages for frames dropped in clip, posted from aggregate_frames (clip runs under the
   * element's object lock, which posting takes) */
  std::vector<GstMessage*> pending_qos;
  /* start-up: running time of the first bundle, monotonic time the first aggregate came */
  GstClockTime started = GST_CLOCK_TIME_NONE;
  gint64 first_ready_us = -1;
  /* the first bundle's dropout tracking is still to come: the pads then present count from
   * `started`, those requested later from the output they first take part in */
  bool tracks_from_start = false;
  /* the warning about inputs whose first frames lie far apart was posted (aggregate thread) */
  bool far_start_warned = false;
  /* time-alignment=auto (aggregate thread) */
  std::unique_ptr<stitch::sync::OffsetTracker> tracker;
  /* the cameras' audio (stitchsyncaudio's streaming threads; its own lock, taken alone or inside
   * `lock`, never the other way round) */
  std::mutex audio_lock;
  std::unique_ptr<stitch::sync::AudioAligner> audio;
  std::vector<stitch::sync::AudioEstimate> audio_seen;  // aggregate thread: the last taken
  /* pads requested and released before the element started: gst_parse_launch does that for
   * `decodebin ! s.sink_2` and links the pad again once decodebin exposes its own; the first
   * bundle waits for them too (guarded by the element's object lock) */
  std::set<std::string> expected;
  /* non-live inputs that deliver nothing: a thread stands in for them with gaps
   * (gststitchsyncwatch.cpp); monotonic time (us) the first real frame came in */
  std::atomic<gint64> first_data_us{-1};
  std::mutex watch_lock;
  std::condition_variable watch_cv;
  bool watch_run = false;  // watch_lock
  std::thread watch;

  void clear_run() {
    for (GstMessage* m : pending_qos) gst_message_unref(m);
    pending_qos.clear();
    started = GST_CLOCK_TIME_NONE;
    first_ready_us = -1;
    tracks_from_start = false;
    far_start_warned = false;
    first_data_us = -1;
    if (tracker) tracker->reset();
    std::lock_guard<std::mutex> guard(audio_lock);
    audio.reset();
    audio_seen.clear();
  }
  void clear() {
    clear_run();
    tracker.reset();
    converter.reset();
    thumbnailer.reset();
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
  GstStitchSyncTimeAlignment time_alignment;
  gchar* load_file;
  /* state */
  StitchSyncState* state;
};

typedef struct {
  GstVideoAggregatorConvertPad parent;
  SyncPadState* st;
} GstStitchSyncPad;
typedef struct {
  GstVideoAggregatorConvertPadClass parent_class;
} GstStitchSyncPadClass;

/* The pad's own state (every sink pad of stitchsync is a GstStitchSyncPad). */
static inline SyncPadState* pad_state(gpointer pad) { return reinterpret_cast<GstStitchSyncPad*>(pad)->st; }

static inline bool is_negotiated(GstVideoAggregatorPad* p) {
  return p->info.finfo && GST_VIDEO_INFO_FORMAT(&p->info) != GST_VIDEO_FORMAT_UNKNOWN;
}

/* gststitchsyncviews.cpp */
gboolean converts_on_device(GstVideoFormat format);
/* Maps `buffer` as a frame of `info`: device pointers when it is CUDA memory of our context. */
gboolean map_input_frame(StitchSyncState* st, const GstVideoInfo* info, GstBuffer* buffer, GstVideoFrame* frame);
/* A pad's view size: its frames', or the bundle's while it has no caps (or no pad). */
std::array<int, 2> view_size(GstVideoAggregator* vagg, GstVideoAggregatorPad* pad);
/* The view size of a frame of `info`: non-square pixels (pixel-aspect-ratio other than 1/1, an
 * anamorphic or DV/HDV camera) are resampled to square ones, widened or heightened so that no
 * detail is lost; the calibration and the blend take square pixels. */
std::array<int, 2> square_pixel_size(const GstVideoInfo* info);
inline bool has_square_pixels(const GstVideoInfo* info) {
  return info->par_n <= 0 || info->par_d <= 0 || info->par_n == info->par_d;
}
/* `target` ns added to the pad's running time from now on (state lock held). */
void apply_time_offset(GstAggregatorPad* pad, SyncPadState& st, gint64 target);
/* The bundle's views from the pads (NULL: a view without an input), in system or CUDA memory;
 * FALSE after an element error (state lock held). */
gboolean bundle_in_system_memory(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads,
                                 GstBuffer* outbuf, guint64 left_out, guint64& missing);
gboolean bundle_in_cuda_memory(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads,
                               GstBuffer* outbuf, guint64 left_out, guint64& missing);
/* time-alignment: signals in, offsets applied; the message to post when they moved. */
GstStructure* align_inputs(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads, bool automatic,
                           std::vector<guint>& no_signal);
gboolean load_time_offsets(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads);
/* The offset each of the `n` views gets now (its pad's own, set by hand, plus load-file's or
 * time-alignment's), and the views whose value time-alignment estimated (state lock held). */
void applied_offsets(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads, guint n, bool automatic,
                     gint64* offsets_ns, guint64& estimated_mask);
/* stitchsyncaudio: `frames` interleaved frames of `info` (F32 or S16) of view `view`'s audio, the
 * first at running time `rt`; used with time-alignment=auto only. */
void stitch_sync_add_audio(GstStitchSync* self, guint view, GstClockTime rt, const GstAudioInfo* info,
                           const void* data, gsize frames);
/* gststitchsyncwatch.cpp: the thread that stands in for silent non-live inputs, from start to
 * stop (a live pipeline's own timeout does it there). */
void watch_start(GstStitchSync* self);
/* Notes each sink pad's first real frame (a probe: GstAggregator clips, and so shows us, a
 * buffer only once every pad has one). */
void watch_arrivals(GstPad* pad);
void watch_stop(GstStitchSync* self);
/* A view's audio flushed: its samples are forgotten. */
void stitch_sync_reset_audio(GstStitchSync* self, guint view);
