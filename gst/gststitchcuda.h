/* The CUDA-memory plumbing every stitch element shares (gst-plugins-bad's gst-cuda library):
 * whether video/x-raw(memory:CUDAMemory) can be offered, the GstCudaContext shared with the
 * other elements through GstContext, running core code with that context current, bundle caps
 * with and without the CUDAMemory feature, and pools of bundles in CUDA or system memory.
 * Built without gst-cuda (no STITCH_HAVE_GST_CUDA), it is system memory only: nothing offers
 * CUDA memory and the context parts do nothing. */
#pragma once

#include <gst/gst.h>
#include <gst/video/video.h>

#include <array>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "stitch/backend.hpp"
#ifdef STITCH_HAVE_GST_CUDA
#include "stitch/cuda/handoff.hpp"
#endif

#ifdef STITCH_HAVE_GST_CUDA
#include <gst/cuda/gstcudacontext.h>
#include <gst/cuda/gstcudamemory.h>
/* Mapping CUDA memory with this flag gives device pointers. */
#define STITCH_MAP_CUDA GST_MAP_CUDA
#else
#define STITCH_MAP_CUDA GstMapFlags(0)
#endif

#define STITCH_CAPS_FEATURE_CUDA_MEMORY "memory:CUDAMemory"

/* TRUE when CUDA memory can be offered: gst-cuda is built in, the driver loads and a device
 * opens (checked once). */
gboolean stitch_cuda_memory_possible(void);

/* TRUE when an element with `backend` offers CUDA memory: possible, and not backend=cpu. */
gboolean stitch_cuda_memory_offered(stitch::Backend backend);

/* TRUE when `memory` is gst-cuda memory (of any context). */
gboolean stitch_memory_is_cuda(GstMemory* memory);

/* TRUE when the first structure of `caps` carries the memory:CUDAMemory feature. */
gboolean stitch_caps_are_cuda_memory(const GstCaps* caps);

/* `caps` (transfer full) for negotiation: with their CUDA-memory structures first when
 * `offer_cuda`, without any otherwise. */
GstCaps* stitch_caps_prefer_cuda(GstCaps* caps, gboolean offer_cuda);

/* One structure of `caps` (transfer full, non-empty) to fixate: the first whose fields hold every
 * value of `wanted` (the size or rate the element means to output), else the first. Downstream
 * often lists a preference before the range it takes (videoscale asked for 640x360, videorate
 * for 10/1): truncating to the first structure would take the preference as a constraint. */
GstCaps* stitch_caps_first_holding(GstCaps* caps, const GstStructure* wanted);

/* transform_caps of the elements whose two sides share one memory: `caps` (transfer none) as
 * they are, CUDA memory first or left out (stitch_caps_prefer_cuda), intersected with `filter`. */
GstCaps* stitch_caps_same_memory(GstCaps* caps, GstCaps* filter, gboolean offer_cuda);

/* Every structure of `caps` (transfer full) offered in CUDA memory (first, when `offer_cuda`)
 * and in system memory: for elements whose two sides may lie in different memories. */
GstCaps* stitch_caps_in_both_memories(GstCaps* caps, gboolean offer_cuda);

/* The element's share of the GstCudaContext. Every element answers context queries and takes
 * set_context with it, and ensures one when it negotiates CUDA memory, so a whole chain
 * (nvh264dec ! ... stitchsync ! ... stitchblend ! cudadownload) runs in one context. */
class StitchCudaContext {
 public:
  StitchCudaContext() = default;
  StitchCudaContext(const StitchCudaContext&) = delete;
  StitchCudaContext& operator=(const StitchCudaContext&) = delete;
  ~StitchCudaContext();

  /* GstElement::set_context: takes a context from the application or a neighbour. */
  void set_context(GstElement* element, GstContext* context);
  /* A GST_QUERY_CONTEXT on any pad: TRUE when answered with our context. */
  gboolean handle_query(GstElement* element, GstQuery* query);
  /* Finds the shared context (neighbours, application) or makes one; FALSE after an element
   * error when no context can be had. */
  gboolean ensure(GstElement* element);
  gboolean valid() const;
  /* TRUE when `memory` is CUDA memory of this context (its device pointers are valid here). */
  gboolean owns(GstMemory* memory) const;
#ifdef STITCH_HAVE_GST_CUDA
  GstCudaContext* get() const { return ctx_; }
  /* The element's pool of CUDA events of this context (stream-ordered hand-off). */
  std::shared_ptr<stitch::CudaEventPool> events();
  /* The event of the element's last frame (StitchCudaHandoff with wait_previous). */
  stitch::CudaEvent previous;

 private:
  GstCudaContext* ctx_ = nullptr;
  GstCudaContext* events_ctx_ = nullptr;  /* the context `events_` belongs to (not a reference) */
  std::shared_ptr<stitch::CudaEventPool> events_;
#endif
};

/* System-memory input frames come back frame after frame (a decoder's or source's pool, the
 * same buffer pushed again): each memory of `buffer` seen for the second time is page-locked in
 * `cuda`'s context, once, so that its upload is a DMA straight from it with no staging copy.
 * Memory seen once (allocated per frame) is left pageable. Does nothing without a context. */
void stitch_cuda_pin_reused_input(StitchCudaContext& cuda, GstBuffer* buffer);

#ifdef STITCH_HAVE_GST_CUDA
/* Makes `ctx` current for the calling thread until destroyed (nothing without a context). */
class StitchCudaPush {
 public:
  explicit StitchCudaPush(GstCudaContext* ctx);
  StitchCudaPush(const StitchCudaPush&) = delete;
  StitchCudaPush& operator=(const StitchCudaPush&) = delete;
  ~StitchCudaPush();

 private:
  bool pushed_ = false;
};
#endif

/* Runs `body` with the element's context current (as is without one); throws
 * std::runtime_error when the context cannot be made current. */
template <typename F>
void with_cuda_context(const StitchCudaContext& cuda, F&& body) {
#ifdef STITCH_HAVE_GST_CUDA
  StitchCudaPush push(cuda.get());
#else
  (void)cuda;
#endif
  body();
}

/* A core object that owns CUDA resources (streams, device buffers, kernels' textures). They
 * belong to the context that was current when it was made, so it is made, used and destroyed
 * with that context current, whatever the element's context becomes later. */
template <typename T>
class StitchCudaOwned {
 public:
  StitchCudaOwned() = default;
  StitchCudaOwned(const StitchCudaOwned&) = delete;
  StitchCudaOwned& operator=(const StitchCudaOwned&) = delete;
  ~StitchCudaOwned() { reset(); }

  /* Replaces the object by factory() (a std::unique_ptr<T>), run with `cuda` current. */
  template <typename Make>
  void make(const StitchCudaContext& cuda, Make&& factory) {
    reset();
    with_cuda_context(cuda, [&]() { obj_ = factory(); });
#ifdef STITCH_HAVE_GST_CUDA
    ctx_ = cuda.get() ? static_cast<GstCudaContext*>(gst_object_ref(cuda.get())) : nullptr;
#endif
  }
  /* body(T&) with the object's context current. */
  template <typename F>
  void run(F&& body) {
    if (!obj_) throw std::logic_error("stitch: core object used before it was made");
#ifdef STITCH_HAVE_GST_CUDA
    StitchCudaPush push(ctx_);
#endif
    body(*obj_);
  }
  /* Destroys the object with its context current; never throws. */
  void reset() noexcept {
#ifdef STITCH_HAVE_GST_CUDA
    if (obj_ && ctx_) {
      try {
        StitchCudaPush push(ctx_);
        obj_.reset();
      } catch (...) {
      }
    }
    obj_.reset();
    if (ctx_) gst_object_unref(ctx_);
    ctx_ = nullptr;
#else
    obj_.reset();
#endif
  }
  /* TRUE when the object exists and was made with `cuda`'s context. */
  bool made_with(const StitchCudaContext& cuda) const {
#ifdef STITCH_HAVE_GST_CUDA
    return obj_ && ctx_ == cuda.get();
#else
    (void)cuda;
    return bool(obj_);
#endif
  }
  T* get() const { return obj_.get(); }
  T* operator->() const { return obj_.get(); }
  T& operator*() const { return *obj_; }
  explicit operator bool() const { return bool(obj_); }

 private:
  std::unique_ptr<T> obj_;
#ifdef STITCH_HAVE_GST_CUDA
  GstCudaContext* ctx_ = nullptr;
#endif
};

/* An active pool of bundles: each buffer holds one GstMemory and one GstVideoMeta (id = view)
 * per entry of `sizes` (RGBA, width x height), in CUDA memory of `cuda`'s context when
 * `cuda_memory`, else in system memory. NULL with `error` set when it cannot be made. */
GstBufferPool* stitch_bundle_pool_new(const StitchCudaContext& cuda, gboolean cuda_memory,
                                      const std::vector<std::array<int, 2>>& sizes, GstCaps* caps,
                                      std::string& error);

/* A bundle from `pool`; an allocation failure (out of device memory) is an element error. */
GstFlowReturn stitch_bundle_pool_acquire(GstElement* element, GstBufferPool* pool, GstBuffer** buffer);

/* Deactivates and releases a pool made by stitch_bundle_pool_new (NULL is fine). */
void stitch_bundle_pool_clear(GstBufferPool** pool);

/* ---- stream-ordered hand-off between our elements (issue 17) ----
 *
 * A stage no longer synchronises its CUDA stream before pushing: it records a pooled CUDA event
 * (stitch::CudaHandoff, src/stitch/cuda/handoff.hpp) and puts it on the output bundle in a
 * GstStitchCudaFenceMeta; the next stage's streams wait on it (cudaStreamWaitEvent). The fence
 * also collects the readers' events, so that a pooled bundle is rewritten only after every
 * stage that read it is done (the meta is POOLED: it stays on the bundle in its pool).
 *
 * - StitchBundleMapping::map registers a bundle's fence with the element's hand-off when every
 *   view is mapped on the device; a view mapped for the host (CPU stage, calibration, no
 *   hand-off) makes the host wait for the fence first.
 * - Only our elements honour fences: an element follows its src link (through queues,
 *   capsfilters, stitchcalib and bins' ghost pads) and synchronises before pushing unless it
 *   reaches stitchcolor, stitchflowwarp or stitchblend (cudadownload, appsink, tee, fakesink
 *   and stitchblend's panorama get finished memory).
 * - STITCH_CUDA_HOST_SYNC=1 installs no hand-off: every stage synchronises, as before. */
typedef struct {
  GstMeta meta;
  gpointer fence; /* std::shared_ptr<StitchCudaFence>* (gststitchcuda.cpp) */
} GstStitchCudaFenceMeta;

GType gst_stitch_cuda_fence_meta_api_get_type(void);
const GstMetaInfo* gst_stitch_cuda_fence_meta_get_info(void);

/* For StitchBundleMapping::map, before any view of `buffer` is mapped: with a hand-off on this
 * thread and every view on the device, its fence joins the hand-off; otherwise the host waits
 * for it. Throws nothing; FALSE with `error` on a CUDA error. */
gboolean stitch_cuda_fence_before_map(GstBuffer* buffer, gboolean all_on_device, std::string& error);

/* TRUE when the element downstream of `srcpad` honours fences (one of ours, maybe behind
 * queues, capsfilters, stitchcalib or ghost pads). */
gboolean stitch_pad_downstream_honours_fences(GstPad* srcpad);

/* One frame of an element's CUDA work, stream-ordered. Make it before mapping the bundles,
 * run the core stage, then finish(). Inactive (every stage synchronises) without a context or
 * with STITCH_CUDA_HOST_SYNC=1. */
class StitchCudaHandoff {
 public:
  /* wait_previous: the host first waits for this element's previous frame (stitchsync: the
   * decoder's input buffers it read are released one frame late, and must be read by then). */
  explicit StitchCudaHandoff(StitchCudaContext& cuda, bool wait_previous = false);
  ~StitchCudaHandoff();
  StitchCudaHandoff(const StitchCudaHandoff&) = delete;
  StitchCudaHandoff& operator=(const StitchCudaHandoff&) = delete;
  static StitchCudaHandoff* current();
  bool active() const;
  /* The stage ran: its event goes on `out`'s fence when `srcpad`'s downstream honours fences
   * (srcpad NULL: never), else the host waits for it here; the inputs' fences get it as a
   * reader. FALSE after an element error (a CUDA error). */
  gboolean finish(GstElement* element, GstBuffer* out, GstPad* srcpad);

#ifdef STITCH_HAVE_GST_CUDA
  void add_input(const std::shared_ptr<struct StitchCudaFence>& fence);

 private:
  StitchCudaContext& cuda_;
  std::unique_ptr<stitch::CudaHandoff> core_;
  std::vector<std::shared_ptr<struct StitchCudaFence>> inputs_;
  StitchCudaHandoff* previous_ = nullptr;
  bool finished_ = false;
  bool wait_previous_ = false;
#endif
};
