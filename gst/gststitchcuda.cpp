#include "gststitchcuda.h"

#include <mutex>

#ifdef STITCH_HAVE_GST_CUDA
#include <gst/cuda/gstcudaloader.h>
#include <gst/cuda/gstcudamemory.h>
#include <gst/cuda/gstcudautils.h>
#endif

/* ---- caps ---- */

gboolean stitch_cuda_memory_possible(void) {
#ifdef STITCH_HAVE_GST_CUDA
  static gboolean possible = FALSE;
  static gsize once = 0;
  if (g_once_init_enter(&once)) {
    possible = gst_cuda_load_library() && stitch::cuda_device_available();
    g_once_init_leave(&once, 1);
  }
  return possible;
#else
  return FALSE;
#endif
}

gboolean stitch_cuda_memory_offered(stitch::Backend backend) {
  return backend != stitch::Backend::Cpu && stitch_cuda_memory_possible();
}

gboolean stitch_memory_is_cuda(GstMemory* memory) {
#ifdef STITCH_HAVE_GST_CUDA
  return memory && gst_is_cuda_memory(memory);
#else
  (void)memory;
  return FALSE;
#endif
}

static gboolean features_are_cuda(const GstCapsFeatures* f) {
  return f && !gst_caps_features_is_any(f) && gst_caps_features_contains(f, STITCH_CAPS_FEATURE_CUDA_MEMORY);
}

gboolean stitch_caps_are_cuda_memory(const GstCaps* caps) {
  if (!caps || gst_caps_is_any(caps) || gst_caps_is_empty(caps)) return FALSE;
  return features_are_cuda(gst_caps_get_features(caps, 0));
}

GstCaps* stitch_caps_prefer_cuda(GstCaps* caps, gboolean offer_cuda) {
  if (gst_caps_is_any(caps)) return caps;
  GstCaps* cuda = gst_caps_new_empty();
  GstCaps* rest = gst_caps_new_empty();
  for (guint i = 0; i < gst_caps_get_size(caps); ++i) {
    const GstCapsFeatures* f = gst_caps_get_features(caps, i);
    const gboolean is_cuda = features_are_cuda(f);
    if (is_cuda && !offer_cuda) continue;
    gst_caps_append_structure_full(is_cuda ? cuda : rest, gst_structure_copy(gst_caps_get_structure(caps, i)),
                                   f ? gst_caps_features_copy(f) : NULL);
  }
  gst_caps_unref(caps);
  gst_caps_append(cuda, rest);
  return cuda;
}

GstCaps* stitch_caps_first_holding(GstCaps* caps, const GstStructure* wanted) {
  if (gst_caps_is_any(caps) || gst_caps_get_size(caps) <= 1) return gst_caps_truncate(caps);
  for (guint i = 0; i < gst_caps_get_size(caps); ++i) {
    /* fields `wanted` does not name are free: a structure holds it when the named ones intersect */
    if (gst_structure_can_intersect(gst_caps_get_structure(caps, i), wanted)) {
      GstCaps* one = gst_caps_copy_nth(caps, i);
      gst_caps_unref(caps);
      return one;
    }
  }
  return gst_caps_truncate(caps);
}

GstCaps* stitch_caps_same_memory(GstCaps* caps, GstCaps* filter, gboolean offer_cuda) {
  GstCaps* out = stitch_caps_prefer_cuda(gst_caps_copy(caps), offer_cuda);
  if (!filter) return out;
  GstCaps* tmp = gst_caps_intersect_full(filter, out, GST_CAPS_INTERSECT_FIRST);
  gst_caps_unref(out);
  return tmp;
}

GstCaps* stitch_caps_in_both_memories(GstCaps* caps, gboolean offer_cuda) {
  if (gst_caps_is_any(caps)) return caps;
  GstCaps* cuda = gst_caps_new_empty();
  GstCaps* system = gst_caps_new_empty();
  for (guint i = 0; i < gst_caps_get_size(caps); ++i) {
    const GstStructure* s = gst_caps_get_structure(caps, i);
    if (offer_cuda)
      cuda = gst_caps_merge_structure_full(cuda, gst_structure_copy(s),
                                           gst_caps_features_new(STITCH_CAPS_FEATURE_CUDA_MEMORY, NULL));
    system = gst_caps_merge_structure_full(system, gst_structure_copy(s), NULL);
  }
  gst_caps_unref(caps);
  gst_caps_append(cuda, system);
  return cuda;
}

/* ---- context ---- */

#ifdef STITCH_HAVE_GST_CUDA

StitchCudaContext::~StitchCudaContext() { gst_clear_object(&ctx_); }

void StitchCudaContext::set_context(GstElement* element, GstContext* context) {
  gst_cuda_handle_set_context(element, context, -1, &ctx_);
}

gboolean StitchCudaContext::handle_query(GstElement* element, GstQuery* query) {
  return GST_QUERY_TYPE(query) == GST_QUERY_CONTEXT && ctx_ && gst_cuda_handle_context_query(element, query, ctx_);
}

std::shared_ptr<stitch::CudaEventPool> StitchCudaContext::events() {
  if (!events_ || events_ctx_ != ctx_) {
    events_ = stitch::CudaEventPool::create();
    events_ctx_ = ctx_;
    previous.reset();
  }
  return events_;
}

gboolean StitchCudaContext::ensure(GstElement* element) {
  if (gst_cuda_ensure_element_context(element, -1, &ctx_)) return TRUE;
  GST_ELEMENT_ERROR(element, RESOURCE, NOT_FOUND,
                    ("No CUDA context for video/x-raw(memory:CUDAMemory) (the CUDA driver did not open a device)"),
                    (NULL));
  return FALSE;
}

gboolean StitchCudaContext::valid() const { return ctx_ != nullptr; }

gboolean StitchCudaContext::owns(GstMemory* memory) const {
  if (!ctx_ || !memory || !gst_is_cuda_memory(memory)) return FALSE;
  GstCudaContext* other = GST_CUDA_MEMORY_CAST(memory)->context;
  return other == ctx_ || gst_cuda_context_get_handle(other) == gst_cuda_context_get_handle(ctx_);
}

StitchCudaPush::StitchCudaPush(GstCudaContext* ctx) {
  if (!ctx) return;
  if (!gst_cuda_context_push(ctx)) throw std::runtime_error("cannot make the CUDA context current");
  pushed_ = true;
}

StitchCudaPush::~StitchCudaPush() {
  if (pushed_) gst_cuda_context_pop(NULL);
}

#else

StitchCudaContext::~StitchCudaContext() = default;
void StitchCudaContext::set_context(GstElement*, GstContext*) {}
gboolean StitchCudaContext::handle_query(GstElement*, GstQuery*) { return FALSE; }
gboolean StitchCudaContext::ensure(GstElement* element) {
  GST_ELEMENT_ERROR(element, CORE, NEGOTIATION, ("This build has no CUDA memory support (gst-cuda)"), (NULL));
  return FALSE;
}
gboolean StitchCudaContext::valid() const { return FALSE; }
gboolean StitchCudaContext::owns(GstMemory*) const { return FALSE; }

#endif

/* ---- stream-ordered hand-off ---- */

#ifdef STITCH_HAVE_GST_CUDA

/* What a bundle's memory is still being written and read under. */
struct StitchCudaFence {
  std::mutex lock;
  GstCudaContext* ctx = nullptr; /* made current to wait on the host */
  std::vector<stitch::CudaEvent> ready;   /* the last writers' events */
  std::vector<stitch::CudaEvent> readers; /* the events of the stages that read it since */
  ~StitchCudaFence() { gst_clear_object(&ctx); }
};
using FencePtr = std::shared_ptr<StitchCudaFence>;

GType gst_stitch_cuda_fence_meta_api_get_type(void) {
  static GType type = 0;
  /* "memory": it describes the bundle's memory, so elements that make new views drop it */
  static const gchar* tags[] = {GST_META_TAG_MEMORY_STR, NULL};
  if (g_once_init_enter(&type)) {
    GType t = gst_meta_api_type_register("GstStitchCudaFenceMetaAPI", tags);
    g_once_init_leave(&type, t);
  }
  return type;
}

static gboolean fence_meta_init(GstMeta* meta, gpointer, GstBuffer*) {
  reinterpret_cast<GstStitchCudaFenceMeta*>(meta)->fence = new FencePtr(std::make_shared<StitchCudaFence>());
  return TRUE;
}

static void fence_meta_free(GstMeta* meta, GstBuffer*) {
  auto* m = reinterpret_cast<GstStitchCudaFenceMeta*>(meta);
  delete static_cast<FencePtr*>(m->fence);
  m->fence = nullptr;
}

static gboolean fence_meta_transform(GstBuffer* dest, GstMeta* meta, GstBuffer*, GQuark type, gpointer) {
  if (!GST_META_TRANSFORM_IS_COPY(type)) return FALSE;
  /* a copy shares the memory, so it shares the fence */
  auto* m = reinterpret_cast<GstStitchCudaFenceMeta*>(meta);
  auto* d = reinterpret_cast<GstStitchCudaFenceMeta*>(gst_buffer_add_meta(dest, gst_stitch_cuda_fence_meta_get_info(), NULL));
  if (!d) return FALSE;
  *static_cast<FencePtr*>(d->fence) = *static_cast<FencePtr*>(m->fence);
  return TRUE;
}

const GstMetaInfo* gst_stitch_cuda_fence_meta_get_info(void) {
  static const GstMetaInfo* info = NULL;
  if (g_once_init_enter(&info)) {
    const GstMetaInfo* mi = gst_meta_register(gst_stitch_cuda_fence_meta_api_get_type(), "GstStitchCudaFenceMeta",
                                              sizeof(GstStitchCudaFenceMeta), fence_meta_init, fence_meta_free,
                                              fence_meta_transform);
    g_once_init_leave(&info, mi);
  }
  return info;
}

static FencePtr buffer_fence(GstBuffer* buffer) {
  auto* m = reinterpret_cast<GstStitchCudaFenceMeta*>(gst_buffer_get_meta(buffer, gst_stitch_cuda_fence_meta_api_get_type()));
  return m ? *static_cast<FencePtr*>(m->fence) : FencePtr();
}

/* Waits on the host for every event of `events`, with `ctx` current. */
static void host_wait(GstCudaContext* ctx, const std::vector<stitch::CudaEvent>& events) {
  if (events.empty()) return;
  StitchCudaPush push(ctx);
  stitch::cuda_events_sync(events);
}

gboolean stitch_cuda_fence_before_map(GstBuffer* buffer, gboolean all_on_device, std::string& error) {
  FencePtr fence = buffer_fence(buffer);
  if (!fence) return TRUE;
  StitchCudaHandoff* h = StitchCudaHandoff::current();
  if (h && h->active() && all_on_device) {
    h->add_input(fence);
    return TRUE;
  }
  std::vector<stitch::CudaEvent> events;
  GstCudaContext* ctx = nullptr;
  {
    std::lock_guard<std::mutex> guard(fence->lock);
    events = fence->ready;
    events.insert(events.end(), fence->readers.begin(), fence->readers.end());
    if (fence->ctx) ctx = static_cast<GstCudaContext*>(gst_object_ref(fence->ctx));
  }
  try {
    host_wait(ctx, events);
  } catch (const std::exception& e) {
    error = e.what();
  }
  if (ctx) gst_object_unref(ctx);
  return error.empty();
}

/* Elements that take the bundle and map it through StitchBundleMapping (which honours fences),
 * and elements that pass buffers on without reading them. Anything else (cudadownload,
 * cudaconvert, tee, appsink, ...) may read the memory without waiting: the producer then
 * synchronises. A walk over the links, not a query, because a reader such as cudadownload
 * would forward a query to one of ours behind it. */
static gboolean element_honours_fences(const gchar* type) {
  return g_str_equal(type, "GstStitchColor") || g_str_equal(type, "GstStitchFlowWarp") ||
         g_str_equal(type, "GstStitchBlend");
}
static gboolean element_passes_through(const gchar* type) {
  return g_str_equal(type, "GstStitchCalib") || g_str_equal(type, "GstQueue") || g_str_equal(type, "GstQueue2") ||
         g_str_equal(type, "GstCapsFilter");
}

gboolean stitch_pad_downstream_honours_fences(GstPad* srcpad) {
  if (!srcpad) return FALSE;
  GstPad* pad = GST_PAD(gst_object_ref(srcpad));
  gboolean honours = FALSE;
  for (int hop = 0; hop < 32 && pad; ++hop) {
    GstPad* peer = gst_pad_get_peer(pad);
    gst_object_unref(pad);
    pad = NULL;
    /* out of a bin: from the ghost src pad's internal pad to the ghost pad */
    while (peer && GST_IS_PROXY_PAD(peer) && !GST_IS_GHOST_PAD(peer)) {
      GstObject* ghost = gst_object_get_parent(GST_OBJECT(peer));
      gst_object_unref(peer);
      peer = NULL;
      if (ghost && GST_IS_GHOST_PAD(ghost)) peer = gst_pad_get_peer(GST_PAD(ghost));
      if (ghost) gst_object_unref(ghost);
    }
    /* into a bin: a ghost sink pad's target */
    while (peer && GST_IS_GHOST_PAD(peer)) {
      GstPad* target = gst_ghost_pad_get_target(GST_GHOST_PAD(peer));
      gst_object_unref(peer);
      peer = target;
    }
    if (!peer) break;
    GstElement* element = gst_pad_get_parent_element(peer);
    gst_object_unref(peer);
    if (!element) break;
    const gchar* type = G_OBJECT_TYPE_NAME(element);
    if (element_honours_fences(type)) {
      honours = TRUE;
    } else if (element_passes_through(type)) {
      pad = gst_element_get_static_pad(element, "src");
    }
    gst_object_unref(element);
    if (honours) break;
  }
  if (pad) gst_object_unref(pad);
  return honours;
}

static thread_local StitchCudaHandoff* t_handoff = nullptr;

StitchCudaHandoff::StitchCudaHandoff(StitchCudaContext& cuda, bool wait_previous)
    : cuda_(cuda), previous_(t_handoff), wait_previous_(wait_previous) {
  t_handoff = this;
  if (!cuda.valid() || stitch::cuda_host_sync()) return;
  core_ = std::make_unique<stitch::CudaHandoff>(cuda.events());
  if (wait_previous && cuda.previous) {
    try {
      host_wait(cuda.get(), {cuda.previous});
    } catch (...) {
      /* a CUDA error: the stage's own calls report it */
    }
    cuda.previous.reset();
  }
}

StitchCudaHandoff::~StitchCudaHandoff() {
  if (core_ && !finished_ && core_->done()) {
    /* an error path: nothing the device still uses may be released unfinished */
    try {
      host_wait(cuda_.get(), {core_->done()});
    } catch (...) {
    }
  }
  core_.reset();
  t_handoff = previous_;
}

StitchCudaHandoff* StitchCudaHandoff::current() { return t_handoff; }

bool StitchCudaHandoff::active() const { return bool(core_); }

void StitchCudaHandoff::add_input(const FencePtr& fence) {
  if (!core_) return;
  for (const auto& f : inputs_)
    if (f == fence) return;
  inputs_.push_back(fence);
  std::lock_guard<std::mutex> guard(fence->lock);
  for (const auto& e : fence->ready) core_->wait_for(e);
  for (const auto& e : fence->readers) core_->wait_for(e);
}

gboolean StitchCudaHandoff::finish(GstElement* element, GstBuffer* out, GstPad* srcpad) {
  finished_ = true;
  if (!core_) return TRUE;
  const stitch::CudaEvent done = core_->done();
  /* nothing ran on the device: what the inputs were written under passes on */
  std::vector<stitch::CudaEvent> events = done ? std::vector<stitch::CudaEvent>{done} : core_->waits();
  if (done) {
    for (const auto& f : inputs_) {
      std::lock_guard<std::mutex> guard(f->lock);
      f->readers.push_back(done);
    }
    if (wait_previous_) cuda_.previous = done;
  }
  if (!out) return TRUE;
  if (!events.empty() && !stitch_pad_downstream_honours_fences(srcpad)) {
    try {
      host_wait(cuda_.get(), events);
    } catch (const std::exception& e) {
      GST_ELEMENT_ERROR(element, STREAM, FAILED, ("%s: %s", GST_ELEMENT_NAME(element), e.what()), (NULL));
      return FALSE;
    }
    events.clear();
  }
  FencePtr fence = buffer_fence(out);
  if (!fence) {
    if (events.empty()) return TRUE;
    if (!gst_buffer_is_writable(out)) {
      /* cannot carry the event: the host waits */
      try {
        host_wait(cuda_.get(), events);
      } catch (const std::exception& e) {
        GST_ELEMENT_ERROR(element, STREAM, FAILED, ("%s: %s", GST_ELEMENT_NAME(element), e.what()), (NULL));
        return FALSE;
      }
      return TRUE;
    }
    GstMeta* meta = gst_buffer_add_meta(out, gst_stitch_cuda_fence_meta_get_info(), NULL);
    /* pooled: it stays on the bundle in its pool, for the readers' events */
    meta->flags = GstMetaFlags(meta->flags | GST_META_FLAG_POOLED);
    fence = *static_cast<FencePtr*>(reinterpret_cast<GstStitchCudaFenceMeta*>(meta)->fence);
  }
  std::lock_guard<std::mutex> guard(fence->lock);
  if (!fence->ctx && cuda_.get()) fence->ctx = static_cast<GstCudaContext*>(gst_object_ref(cuda_.get()));
  fence->ready = std::move(events);
  fence->readers.clear();
  return TRUE;
}

#else

gboolean stitch_cuda_fence_before_map(GstBuffer*, gboolean, std::string&) { return TRUE; }
gboolean stitch_pad_downstream_honours_fences(GstPad*) { return FALSE; }
StitchCudaHandoff::StitchCudaHandoff(StitchCudaContext&, bool) {}
StitchCudaHandoff::~StitchCudaHandoff() = default;
StitchCudaHandoff* StitchCudaHandoff::current() { return nullptr; }
bool StitchCudaHandoff::active() const { return false; }
gboolean StitchCudaHandoff::finish(GstElement*, GstBuffer*, GstPad*) { return TRUE; }

#endif

/* ---- bundle pool ---- */

/* A GstBufferPool whose buffers are whole bundles: one memory and one pooled GstVideoMeta per
 * view, so a bundle comes back to the pool with its layout and is reused as it is. */
typedef struct {
  GstBufferPool parent;
  std::vector<std::array<int, 2>>* sizes;
  gboolean cuda_memory;
  gboolean pin_host; /* system memory page-locked in `context` (pinned staging for downloads) */
#ifdef STITCH_HAVE_GST_CUDA
  GstCudaContext* context;
#endif
} GstStitchBundlePool;

typedef struct {
  GstBufferPoolClass parent_class;
} GstStitchBundlePoolClass;

G_DEFINE_TYPE(GstStitchBundlePool, gst_stitch_bundle_pool, GST_TYPE_BUFFER_POOL);

#ifdef STITCH_HAVE_GST_CUDA
/* System-memory bundles and panoramas of an element with a CUDA context are page-locked once,
 * when the pool allocates them: the uploads and downloads of the CUDA stages then go straight
 * to and from them by DMA (no pageable staging, no per-frame allocation). */
struct PinnedMemory {
  GstCudaContext* ctx;
  void* ptr;
};

static void unpin_memory(gpointer data, GstMiniObject*) {
  auto* p = static_cast<PinnedMemory*>(data);
  try {
    StitchCudaPush push(p->ctx);
    stitch::cuda_host_unregister(p->ptr);
  } catch (...) {
  }
  gst_object_unref(p->ctx);
  delete p;
}

static void pin_memory(GstCudaContext* ctx, GstMemory* mem) {
  GstMapInfo info;
  if (!ctx || !gst_memory_map(mem, &info, GST_MAP_READ)) return;
  bool pinned = false;
  try {
    StitchCudaPush push(ctx);
    pinned = stitch::cuda_host_register(info.data, info.maxsize);
  } catch (...) {
  }
  if (pinned)
    gst_mini_object_weak_ref(GST_MINI_OBJECT(mem), unpin_memory,
                             new PinnedMemory{static_cast<GstCudaContext*>(gst_object_ref(ctx)), info.data});
  gst_memory_unmap(mem, &info);
}
#endif

/* qdata on an input memory: 1 once seen, 2 once page-locked (or refused) */
static GQuark input_pin_quark(void) {
  static GQuark q = g_quark_from_static_string("stitch-input-pin");
  return q;
}

void stitch_cuda_pin_reused_input(StitchCudaContext& cuda, GstBuffer* buffer) {
#ifdef STITCH_HAVE_GST_CUDA
  /* STITCH_CUDA_NO_PIN_INPUT=1: staged through the pinned ring as before (for the A/B) */
  if (!cuda.valid() || !buffer || g_getenv("STITCH_CUDA_NO_PIN_INPUT")) return;
  const guint n = gst_buffer_n_memory(buffer);
  for (guint i = 0; i < n; ++i) {
    GstMemory* mem = gst_buffer_peek_memory(buffer, i);
    if (stitch_memory_is_cuda(mem)) continue;
    /* a shared region (gst_buffer_copy, a parser's sub-buffer) is a new GstMemory every frame:
     * the allocation it lies in is what comes back */
    while (mem->parent) mem = mem->parent;
    const gsize seen = GPOINTER_TO_SIZE(gst_mini_object_get_qdata(GST_MINI_OBJECT(mem), input_pin_quark()));
    if (seen >= 2) continue;
    if (seen == 1) pin_memory(cuda.get(), mem);  /* refused: stays pageable, staged as before */
    gst_mini_object_set_qdata(GST_MINI_OBJECT(mem), input_pin_quark(), GSIZE_TO_POINTER(seen + 1), NULL);
  }
#else
  (void)cuda;
  (void)buffer;
#endif
}

static GstMemory* alloc_view(GstStitchBundlePool* self, int width, int height, gint* stride) {
#ifdef STITCH_HAVE_GST_CUDA
  if (self->cuda_memory) {
    GstVideoInfo info;
    gst_video_info_set_format(&info, GST_VIDEO_FORMAT_RGBA, guint(width), guint(height));
    /* Debian's 1.22 gst-cuda takes no NULL allocator (later releases do): the registered one. */
    GstAllocator* allocator = gst_allocator_find(GST_CUDA_MEMORY_TYPE_NAME);
    if (!allocator) return NULL;
    GstMemory* mem = gst_cuda_allocator_alloc(GST_CUDA_ALLOCATOR(allocator), self->context, &info);
    gst_object_unref(allocator);
    if (mem) *stride = GST_CUDA_MEMORY_CAST(mem)->info.stride[0];
    return mem;
  }
#endif
  (void)self;
  GstAllocationParams params;
  gst_allocation_params_init(&params);
  params.align = 15;
  *stride = width * 4;
  GstMemory* mem = gst_allocator_alloc(NULL, gsize(width) * 4 * gsize(height), &params);
#ifdef STITCH_HAVE_GST_CUDA
  if (mem && self->pin_host) pin_memory(self->context, mem);
#endif
  return mem;
}

static gboolean gst_stitch_bundle_pool_set_config(GstBufferPool* pool, GstStructure* config) {
  auto* self = reinterpret_cast<GstStitchBundlePool*>(pool);
  GstCaps* caps = NULL;
  guint size = 0, min = 0, max = 0;
  if (!gst_buffer_pool_config_get_params(config, &caps, &size, &min, &max)) return FALSE;
  /* The pool discards buffers whose size differs from the configured one, and CUDA memory is
   * pitched by the driver: the size is learnt from one allocation of each view. */
  gsize total = 0;
  for (const auto& s : *self->sizes) {
    gint stride = 0;
    GstMemory* mem = alloc_view(self, s[0], s[1], &stride);
    if (!mem) return FALSE;
    total += gst_memory_get_sizes(mem, NULL, NULL);
    gst_memory_unref(mem);
  }
  if (caps) gst_caps_ref(caps);
  gst_buffer_pool_config_set_params(config, caps, guint(total), min, max);
  if (caps) gst_caps_unref(caps);
  return GST_BUFFER_POOL_CLASS(gst_stitch_bundle_pool_parent_class)->set_config(pool, config);
}

static GstFlowReturn gst_stitch_bundle_pool_alloc_buffer(GstBufferPool* pool, GstBuffer** buffer,
                                                         GstBufferPoolAcquireParams*) {
  auto* self = reinterpret_cast<GstStitchBundlePool*>(pool);
  GstBuffer* buf = gst_buffer_new();
  gsize offset = 0;
  for (std::size_t i = 0; i < self->sizes->size(); ++i) {
    const auto& s = (*self->sizes)[i];
    gint stride = 0;
    GstMemory* mem = alloc_view(self, s[0], s[1], &stride);
    if (!mem) {
      gst_buffer_unref(buf);
      return GST_FLOW_ERROR;
    }
    const gsize size = gst_memory_get_sizes(mem, NULL, NULL);
    gst_buffer_append_memory(buf, mem);
    gsize offsets[GST_VIDEO_MAX_PLANES] = {offset};
    gint strides[GST_VIDEO_MAX_PLANES] = {stride};
    GstVideoMeta* vm = gst_buffer_add_video_meta_full(buf, GST_VIDEO_FRAME_FLAG_NONE, GST_VIDEO_FORMAT_RGBA,
                                                      guint(s[0]), guint(s[1]), 1, offsets, strides);
    vm->id = gint(i);
    offset += size;
  }
  *buffer = buf;
  return GST_FLOW_OK;
}

static void gst_stitch_bundle_pool_finalize(GObject* object) {
  auto* self = reinterpret_cast<GstStitchBundlePool*>(object);
  delete self->sizes;
  self->sizes = nullptr;
#ifdef STITCH_HAVE_GST_CUDA
  gst_clear_object(&self->context);
#endif
  G_OBJECT_CLASS(gst_stitch_bundle_pool_parent_class)->finalize(object);
}

static void gst_stitch_bundle_pool_class_init(GstStitchBundlePoolClass* klass) {
  G_OBJECT_CLASS(klass)->finalize = gst_stitch_bundle_pool_finalize;
  GST_BUFFER_POOL_CLASS(klass)->set_config = gst_stitch_bundle_pool_set_config;
  GST_BUFFER_POOL_CLASS(klass)->alloc_buffer = gst_stitch_bundle_pool_alloc_buffer;
}

static void gst_stitch_bundle_pool_init(GstStitchBundlePool* self) {
  self->sizes = new std::vector<std::array<int, 2>>();
}

GstBufferPool* stitch_bundle_pool_new(const StitchCudaContext& cuda, gboolean cuda_memory,
                                      const std::vector<std::array<int, 2>>& sizes, GstCaps* caps,
                                      std::string& error) {
  if (cuda_memory && !cuda.valid()) {
    error = "no CUDA context for CUDA-memory bundles";
    return NULL;
  }
  auto* self = static_cast<GstStitchBundlePool*>(g_object_new(gst_stitch_bundle_pool_get_type(), NULL));
  gst_object_ref_sink(self);
  GstBufferPool* pool = GST_BUFFER_POOL(self);
  *self->sizes = sizes;
  self->cuda_memory = cuda_memory;
#ifdef STITCH_HAVE_GST_CUDA
  if (cuda_memory) gst_cuda_memory_init_once();
  if (cuda.valid()) self->context = static_cast<GstCudaContext*>(gst_object_ref(cuda.get()));
  self->pin_host = !cuda_memory && cuda.valid() && !g_getenv("STITCH_CUDA_NO_PINNED");
#endif
  GstStructure* config = gst_buffer_pool_get_config(pool);
  gst_buffer_pool_config_set_params(config, caps, 0, 2, 0);
  if (!gst_buffer_pool_set_config(pool, config) || !gst_buffer_pool_set_active(pool, TRUE)) {
    error = std::string("cannot allocate ") + (cuda_memory ? "CUDA" : "system") + " memory for " +
            std::to_string(sizes.size()) + " views";
    gst_object_unref(pool);
    return NULL;
  }
  return pool;
}

GstFlowReturn stitch_bundle_pool_acquire(GstElement* element, GstBufferPool* pool, GstBuffer** buffer) {
  const GstFlowReturn ret = gst_buffer_pool_acquire_buffer(pool, buffer, NULL);
  if (ret == GST_FLOW_ERROR)
    GST_ELEMENT_ERROR(element, RESOURCE, NO_SPACE_LEFT,
                      ("Cannot allocate %s memory for a bundle",
                       reinterpret_cast<GstStitchBundlePool*>(pool)->cuda_memory ? "CUDA" : "system"),
                      (NULL));
  return ret;
}

void stitch_bundle_pool_clear(GstBufferPool** pool) {
  if (!*pool) return;
  gst_buffer_pool_set_active(*pool, FALSE);
  gst_object_unref(*pool);
  *pool = NULL;
}
