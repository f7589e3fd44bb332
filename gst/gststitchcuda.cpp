#include "gststitchcuda.h"

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

/* ---- bundle pool ---- */

/* A GstBufferPool whose buffers are whole bundles: one memory and one pooled GstVideoMeta per
 * view, so a bundle comes back to the pool with its layout and is reused as it is. */
typedef struct {
  GstBufferPool parent;
  std::vector<std::array<int, 2>>* sizes;
  gboolean cuda_memory;
#ifdef STITCH_HAVE_GST_CUDA
  GstCudaContext* context;
#endif
} GstStitchBundlePool;

typedef struct {
  GstBufferPoolClass parent_class;
} GstStitchBundlePoolClass;

G_DEFINE_TYPE(GstStitchBundlePool, gst_stitch_bundle_pool, GST_TYPE_BUFFER_POOL);

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
  return gst_allocator_alloc(NULL, gsize(width) * 4 * gsize(height), &params);
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
  if (cuda_memory) {
    gst_cuda_memory_init_once();
    self->context = static_cast<GstCudaContext*>(gst_object_ref(cuda.get()));
  }
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
