/* stitchsync: the bundle's views (system memory, zero-copy where it can; CUDA memory, converted
 * on the device) and the time offsets applied to the inputs. See gststitchsync.cpp. */
#include <cstring>

#include "gststitchsyncpriv.h"
#include "stitch/rig/rig.hpp"

#define GST_CAT_DEFAULT gst_stitch_sync_debug

gboolean converts_on_device(GstVideoFormat format) {
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
gboolean map_input_frame(StitchSyncState* st, const GstVideoInfo* info, GstBuffer* buffer,
                                GstVideoFrame* frame) {
  GstMapFlags flags = GST_MAP_READ;
  if (st->cuda.owns(gst_buffer_peek_memory(buffer, 0))) flags = GstMapFlags(flags | STITCH_MAP_CUDA);
  return gst_video_frame_map(frame, info, buffer, flags);
}

/* A pad's view size: its frames', or the bundle's while it has no caps. */
std::array<int, 2> square_pixel_size(const GstVideoInfo* info) {
  gint w = GST_VIDEO_INFO_WIDTH(info), h = GST_VIDEO_INFO_HEIGHT(info);
  if (!has_square_pixels(info) && w > 0 && h > 0) {
    if (info->par_n > info->par_d)
      w = gint(gst_util_uint64_scale_int_round(guint64(w), info->par_n, info->par_d));
    else
      h = gint(gst_util_uint64_scale_int_round(guint64(h), info->par_d, info->par_n));
  }
  return {MAX(w, 1), MAX(h, 1)};
}

std::array<int, 2> view_size(GstVideoAggregator* vagg, GstVideoAggregatorPad* pad) {
  const std::array<int, 2> square = pad && pad->info.finfo ? square_pixel_size(&pad->info) : std::array<int, 2>{0, 0};
  gint w = pad && pad->info.finfo && GST_VIDEO_INFO_WIDTH(&pad->info) > 0 ? square[0] : 0;
  gint h = pad && pad->info.finfo && GST_VIDEO_INFO_HEIGHT(&pad->info) > 0 ? square[1] : 0;
  if (w <= 0 || h <= 0) {
    w = GST_VIDEO_INFO_WIDTH(&vagg->info);
    h = GST_VIDEO_INFO_HEIGHT(&vagg->info);
  }
  return {w, h};
}

/* Time alignment: `target` ns added to the pad's running time from now on (its segment is
 * shifted by the change; aggregate thread or pad's object lock holder). */
void apply_time_offset(GstAggregatorPad* pad, SyncPadState& st, gint64 target) {
  if (target == st.applied_ns) return;
  GST_OBJECT_LOCK(pad);
  if (pad->segment.format == GST_FORMAT_TIME)
    gst_segment_offset_running_time(&pad->segment, GST_FORMAT_TIME, target - st.applied_ns);
  GST_OBJECT_UNLOCK(pad);
  st.applied_ns = target;
}

/* Appends one view: shares the frame's memory when it is a single block of system memory,
 * copies otherwise (CUDA memory is read through host memory: this bundle is in system memory).
 * FALSE when memory cannot be had or mapped. */
static gboolean append_view(GstBuffer* bundle, guint id, GstBuffer* src, gsize src_offset, gint width, gint height,
                            gint stride) {
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
    if (!mem) return FALSE;
    GstMapInfo dst, in;
    if (!gst_memory_map(mem, &dst, GST_MAP_WRITE)) {
      gst_memory_unref(mem);
      return FALSE;
    }
    if (!gst_buffer_map(src, &in, GST_MAP_READ)) {
      gst_memory_unmap(mem, &dst);
      gst_memory_unref(mem);
      return FALSE;
    }
    for (gint y = 0; y < height; ++y) memcpy(dst.data + y * row, in.data + src_offset + gsize(y) * stride, row);
    gst_buffer_unmap(src, &in);
    gst_memory_unmap(mem, &dst);
    gst_buffer_append_memory(bundle, mem);
    offset[0] = bundle_offset;
    strides[0] = gint(row);
  }
  GstVideoMeta* vm = gst_buffer_add_video_meta_full(bundle, GST_VIDEO_FRAME_FLAG_NONE, GST_VIDEO_FORMAT_RGBA, width,
                                                    height, 1, offset, strides);
  if (!vm) return FALSE;
  vm->id = gint(id);
  return TRUE;
}

static gboolean append_black_view(GstBuffer* bundle, guint id, gint width, gint height) {
  const gsize size = gsize(width) * 4 * height;
  GstMemory* mem = gst_allocator_alloc(NULL, size, NULL);
  if (!mem) return FALSE;
  GstMapInfo map;
  if (!gst_memory_map(mem, &map, GST_MAP_WRITE)) {
    gst_memory_unref(mem);
    return FALSE;
  }
  memset(map.data, 0, size);
  gst_memory_unmap(mem, &map);
  GstBuffer* tmp = gst_buffer_new();
  gst_buffer_append_memory(tmp, mem);
  const gboolean ok = append_view(bundle, id, tmp, 0, width, height, width * 4);
  gst_buffer_unref(tmp);
  return ok;
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

/* System memory: views reference the inputs' memory (zero-copy for single-block frames). `pads`
 * holds NULL for a view without an input (a single input left). FALSE after an element error. */
gboolean bundle_in_system_memory(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads,
                                        GstBuffer* outbuf, guint64 left_out, guint64& missing) {
  GstVideoAggregator* vagg = GST_VIDEO_AGGREGATOR(self);
  for (guint id = 0; id < pads.size(); ++id) {
    GstVideoAggregatorPad* pad = pads[id];
    GstVideoFrame* frame = pad ? gst_video_aggregator_pad_get_prepared_frame(pad) : NULL;
    SyncPadState* last = pad ? pad_state(pad) : NULL;
    gboolean ok = TRUE;
    if (!pad || (left_out >> id & 1) || (!frame && !last->buffer)) {
      /* no input, dropped out with dropout=fill, or never had a frame: black, marked missing
       * so that stitchblend leaves it out (the last frame is kept) */
      const auto size = view_size(vagg, pad);
      ok = append_black_view(outbuf, id, size[0], size[1]);
      missing |= guint64(1) << id;
    } else if (frame) {
      ok = append_view(outbuf, id, frame->buffer, GST_VIDEO_FRAME_PLANE_OFFSET(frame, 0), GST_VIDEO_FRAME_WIDTH(frame),
                       GST_VIDEO_FRAME_HEIGHT(frame), GST_VIDEO_FRAME_PLANE_STRIDE(frame, 0));
      if (ok) {
        /* Keep only what the bundle already references: the view's memory. */
        GstBuffer* keep = gst_buffer_new();
        gst_buffer_append_memory(keep, gst_buffer_get_memory(outbuf, id));
        gst_clear_buffer(&last->buffer);
        last->buffer = keep;
        GstVideoMeta* vm = gst_buffer_get_video_meta_id(outbuf, gint(id));
        last->width = gint(vm->width);
        last->height = gint(vm->height);
        last->stride = vm->stride[0];
        last->offset = vm->offset[0] - (gst_buffer_get_size(outbuf) - gst_buffer_get_size(keep));
      }
    } else {
      /* a live camera that is late or gone: freeze its last frame */
      ok = append_view(outbuf, id, last->buffer, last->offset, last->width, last->height, last->stride);
    }
    if (!ok) {
      GST_ELEMENT_ERROR(self, RESOURCE, NO_SPACE_LEFT,
                        ("Cannot allocate or map the view of %s (view %u)", pad ? GST_PAD_NAME(pad) : "no input", id),
                        (NULL));
      return FALSE;
    }
  }
  return TRUE;
}

/* CUDA memory: every view of the pooled bundle is written on the device from its input frame
 * (uploaded once when it is in system memory). FALSE after an element error. */
gboolean bundle_in_cuda_memory(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads,
                                      GstBuffer* outbuf, guint64 left_out, guint64& missing) {
  StitchSyncState* st = self->state;
  const guint n = guint(pads.size());  // NULL entries: views without an input
  /* stream-ordered: the bundle is handed on with an event; the inputs (a decoder's buffers)
   * are released one frame late, after the host waited for that frame (wait_previous) */
  StitchCudaHandoff handoff(st->cuda, /*wait_previous=*/true);
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
        if (!pad) {
          converter.clear(view);
          missing |= guint64(1) << id;
          continue;
        }
        GstVideoFrame* frame = gst_video_aggregator_pad_get_prepared_frame(pad);
        SyncPadState& last = *pad_state(pad);
        if (left_out >> id & 1) {
          converter.clear(view);
          missing |= guint64(1) << id;
        } else if (frame) {
          const stitch::FrameView in = frame_view(frame);
          if (!in.on_device) stitch_cuda_pin_reused_input(st->cuda, frame->buffer);
          converter.convert(in, view);
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
  const gboolean handed = ok && handoff.finish(GST_ELEMENT(self), outbuf, GST_AGGREGATOR_SRC_PAD(self));
  for (guint i = 0; i < n_repeated; ++i) gst_video_frame_unmap(&repeated[i]);
  return handed;
}

/* Time alignment. The pads' offsets from load-file, then (time-alignment=auto) from the
 * tracker, fed one motion signal per new input frame at its uncorrected running time. Returns
 * the message to post when the estimates moved (state lock held). */
static const char* source_name(const stitch::sync::Estimate& e) {
  if (!e.valid) return "none";
  return e.source == stitch::sync::OffsetSource::Audio ? "audio" : "vision";
}

void stitch_sync_add_audio(GstStitchSync* self, guint view, GstClockTime rt, const GstAudioInfo* info, const void* data,
                           gsize frames) {
  GST_OBJECT_LOCK(self);
  const bool automatic = self->time_alignment == GST_STITCH_SYNC_TIME_ALIGNMENT_AUTO;
  GST_OBJECT_UNLOCK(self);
  if (!automatic || view >= STITCH_MAX_VIEWS || !GST_CLOCK_TIME_IS_VALID(rt)) return;
  const GstAudioFormat f = GST_AUDIO_INFO_FORMAT(info);
  std::lock_guard<std::mutex> guard(self->state->audio_lock);
  if (!self->state->audio) self->state->audio = std::make_unique<stitch::sync::AudioAligner>(STITCH_MAX_VIEWS);
  if (f == GST_AUDIO_FORMAT_F32)
    self->state->audio->add(int(view), gint64(rt), static_cast<const float*>(data), frames, GST_AUDIO_INFO_CHANNELS(info),
                            GST_AUDIO_INFO_RATE(info));
  else if (f == GST_AUDIO_FORMAT_S16)
    self->state->audio->add(int(view), gint64(rt), static_cast<const int16_t*>(data), frames,
                            GST_AUDIO_INFO_CHANNELS(info), GST_AUDIO_INFO_RATE(info));
  self->state->audio->estimate();  // once a second of view 0's audio; a no-op otherwise
}

void stitch_sync_reset_audio(GstStitchSync* self, guint view) {
  std::lock_guard<std::mutex> guard(self->state->audio_lock);
  if (self->state->audio) self->state->audio->reset_view(int(view));
}

GstStructure* align_inputs(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads, bool automatic,
                                  std::vector<guint>& no_signal) {
  StitchSyncState* st = self->state;
  guint n = 0;
  while (n < pads.size() && pads[n]) ++n;
  if (!automatic) {
    st->tracker.reset();
    for (guint v = 0; v < n; ++v) pad_state(pads[v])->clear_thumbnail();  // nothing reads them now
    for (guint v = 0; v < n; ++v) apply_time_offset(GST_AGGREGATOR_PAD(pads[v]), *pad_state(pads[v]), pad_state(pads[v])->file_offset_ns);
    return NULL;
  }
  if (!st->tracker || st->tracker->views() != int(n)) {
    st->tracker = std::make_unique<stitch::sync::OffsetTracker>(int(n));
    /* live: the estimate (tens of ms once a second) off the aggregate thread, so no camera
     * waits for it; files: in place, so the offsets apply at the same stream time on any machine */
    st->tracker->set_asynchronous(GST_CLOCK_TIME_IS_VALID(gst_aggregator_get_latency(GST_AGGREGATOR(self))));
    for (guint v = 0; v < n; ++v) pad_state(pads[v])->clear_thumbnail();  // for the old views
  }
  /* CUDA memory: the thumbnail submitted with the pad's previous frame, normally done by now
   * (`wait`: take it even if not, its slot is needed); false after a CUDA error (warned) */
  auto take_thumbnail = [&](guint v, bool wait) -> bool {
    SyncPadState& ps = *pad_state(pads[v]);
    if (!ps.thumb_frame) return true;
    if (!st->thumbnailer.made_with(st->cuda)) {  // remade (new caps): its slots went with it
      ps.clear_thumbnail();
      return true;
    }
    try {
      bool fed = false;
      st->thumbnailer.run([&](stitch::sync::FrameThumbnailerCuda& t) {
        if (ps.thumb_slot != int(v)) {
          fed = true;  // the views were renumbered: dropped
          return;
        }
        if (!wait && !t.ready(ps.thumb_slot)) return;
        float thumb[stitch::sync::kThumbnailW * stitch::sync::kThumbnailH];
        if (t.take(ps.thumb_slot, thumb)) st->tracker->add_thumbnail(int(v), ps.thumb_t, thumb);
        fed = true;
      });
      if (fed) ps.clear_thumbnail();
      return true;
    } catch (const std::exception& e) {
      ps.clear_thumbnail();
      GST_ELEMENT_WARNING(self, STREAM, FAILED,
                          ("time-alignment: cannot read %s's frame on the device", GST_PAD_NAME(pads[v])), ("%s", e.what()));
      return false;
    }
  };
  for (guint v = 0; v < n; ++v) {
    GstVideoAggregatorPad* pad = pads[v];
    SyncPadState& ps = *pad_state(pad);
    GstVideoFrame* frame = gst_video_aggregator_pad_get_prepared_frame(pad);
    if (frame && GST_BUFFER_PTS(frame->buffer) != ps.signal_pts) {
      ps.signal_pts = GST_BUFFER_PTS(frame->buffer);
      /* the previous frame's device thumbnail first: a view's samples go in in time order */
      if (!take_thumbnail(v, /*wait=*/true)) continue;
      GST_OBJECT_LOCK(pad);
      const GstClockTime rt =
          gst_segment_to_running_time(&GST_AGGREGATOR_PAD(pad)->segment, GST_FORMAT_TIME, GST_BUFFER_PTS(frame->buffer));
      GST_OBJECT_UNLOCK(pad);
      if (!GST_CLOCK_TIME_IS_VALID(rt)) continue;
      const GstVideoFormat f = GST_VIDEO_FRAME_FORMAT(frame);
      const bool luma = f == GST_VIDEO_FORMAT_NV12 || f == GST_VIDEO_FORMAT_I420;  // the Y plane; else RGBA-like
      const auto* plane = static_cast<const uint8_t*>(GST_VIDEO_FRAME_PLANE_DATA(frame, 0));
      const int width = GST_VIDEO_FRAME_WIDTH(frame), height = GST_VIDEO_FRAME_HEIGHT(frame);
      const std::size_t pitch = std::size_t(GST_VIDEO_FRAME_PLANE_STRIDE(frame, 0));
      if (STITCH_MAP_CUDA != 0 && (frame->map[0].flags & STITCH_MAP_CUDA)) {
        /* CUDA memory: reduced where it lies; the 9 KB come back to page-locked memory while the
         * bundle goes on, and are read with the view's next frame (the same values as the CPU's) */
        try {
          if (!st->thumbnailer.made_with(st->cuda)) {
            for (guint w = 0; w < n; ++w) pad_state(pads[w])->clear_thumbnail();  // slots of the old one
            st->thumbnailer.make(st->cuda, []() { return std::make_unique<stitch::sync::FrameThumbnailerCuda>(); });
          }
          st->thumbnailer.run([&](stitch::sync::FrameThumbnailerCuda& t) {
            t.submit(int(v), plane, width, height, pitch, luma ? 1 : 4, luma ? 0 : 1);
          });
          ps.thumb_frame = gst_buffer_ref(frame->buffer);  // read by the kernel until taken
          ps.thumb_t = gint64(rt) - ps.applied_ns;
          ps.thumb_slot = int(v);
        } catch (const std::exception& e) {
          GST_ELEMENT_WARNING(self, STREAM, FAILED, ("time-alignment: cannot read %s's frame on the device", GST_PAD_NAME(pad)),
                              ("%s", e.what()));
        }
      } else {
        st->tracker->add_frame(int(v), gint64(rt) - ps.applied_ns, plane, width, height, pitch, luma ? 1 : 4,
                               luma ? 0 : 1);
      }
    } else {
      take_thumbnail(v, /*wait=*/false);  // a repeated frame: the last one's result, if it is in
    }
  }
  /* the audio estimate is made on the audio's streaming thread (tens of ms once a second);
   * this thread takes its result when the lock is free, never waits for one in progress */
  {
    std::unique_lock<std::mutex> lk(st->audio_lock, std::try_to_lock);
    if (lk.owns_lock()) st->audio_seen = st->audio ? st->audio->current() : std::vector<stitch::sync::AudioEstimate>{};
  }
  const std::vector<stitch::sync::AudioEstimate>& audio = st->audio_seen;
  std::vector<stitch::sync::Estimate> est;
  std::vector<int> quiet;
  const bool changed = st->tracker->update(est, quiet, audio.empty() ? nullptr : &audio);
  for (int v : quiet) no_signal.push_back(guint(v));
  for (guint v = 0; v < n; ++v) {
    SyncPadState& ps = *pad_state(pads[v]);
    const auto& cur = st->tracker->current();
    const bool valid = v < cur.size() && cur[v].valid;
    /* the estimate is measured on the uncorrected times: it replaces the file's value */
    GstBuffer* buf = gst_video_aggregator_pad_get_current_buffer(pads[v]);
    GstClockTime rt = GST_CLOCK_TIME_NONE;
    if (buf && GST_BUFFER_PTS_IS_VALID(buf)) {
      GST_OBJECT_LOCK(pads[v]);
      rt = gst_segment_to_running_time(&GST_AGGREGATOR_PAD(pads[v])->segment, GST_FORMAT_TIME, GST_BUFFER_PTS(buf));
      GST_OBJECT_UNLOCK(pads[v]);
    }
    const gint64 raw = GST_CLOCK_TIME_IS_VALID(rt) ? gint64(rt) - ps.applied_ns : 0;
    apply_time_offset(GST_AGGREGATOR_PAD(pads[v]), ps, valid ? st->tracker->offset_at(int(v), raw) : ps.file_offset_ns);
  }
  if (!changed) return NULL;
  GstStructure* s = gst_structure_new_empty("stitchsync-time-offsets");
  for (guint v = 0; v < n && v < est.size(); ++v) {
    gchar* k = g_strdup_printf("offset-%u", v);
    gst_structure_set(s, k, G_TYPE_INT64, est[v].valid ? gint64(est[v].offset_ns) : gint64(0), NULL);
    g_free(k);
    k = g_strdup_printf("confidence-%u", v);
    gst_structure_set(s, k, G_TYPE_DOUBLE, est[v].confidence, NULL);
    g_free(k);
    k = g_strdup_printf("rate-%u", v);
    gst_structure_set(s, k, G_TYPE_DOUBLE, est[v].valid ? est[v].rate : 1.0, NULL);
    g_free(k);
    k = g_strdup_printf("source-%u", v);
    gst_structure_set(s, k, G_TYPE_STRING, source_name(est[v]), NULL);
    g_free(k);
  }
  return s;
}

/* The calibration file's per-camera time offsets (stitchcalib's rig JSON, "time_offset_ns"),
 * read at the first bundle. FALSE after an element error. */
gboolean load_time_offsets(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads) {
  GST_OBJECT_LOCK(self);
  const std::string path = self->load_file ? self->load_file : "";
  GST_OBJECT_UNLOCK(self);
  if (path.empty()) return TRUE;
  try {
    const stitch::Rig rig = stitch::rig_load(path);
    for (guint v = 0; v < pads.size() && v < rig.cameras.size(); ++v)
      if (pads[v]) pad_state(pads[v])->file_offset_ns = rig.cameras[v].time_offset_ns.value_or(0);
  } catch (const std::exception& e) {
    GST_ELEMENT_ERROR(self, RESOURCE, READ, ("Cannot read the time offsets of %s: %s", path.c_str(), e.what()), (NULL));
    return FALSE;
  }
  return TRUE;
}


void applied_offsets(GstStitchSync* self, const std::vector<GstVideoAggregatorPad*>& pads, guint n, bool automatic,
                     gint64* offsets_ns, guint64& estimated_mask) {
  estimated_mask = 0;
  const auto* tracker = self->state->tracker.get();
  for (guint v = 0; v < n && v < STITCH_MAX_VIEWS; ++v) {
    offsets_ns[v] = 0;
    if (v >= pads.size() || !pads[v]) continue;  // a missing view: nothing applied
    offsets_ns[v] = pad_state(pads[v])->applied_ns + gst_pad_get_offset(GST_PAD(pads[v]));
    /* the same test align_inputs applies the estimate by */
    if (automatic && tracker && v < tracker->current().size() && tracker->current()[v].valid)
      estimated_mask |= guint64(1) << v;
  }
}
