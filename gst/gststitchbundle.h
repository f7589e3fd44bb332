/* The bundle that travels between the stitch elements: one GstBuffer holding N views,
 * caps video/x-raw, format=RGBA, multiview-mode=separated, views=N; one GstMemory and one
 * GstVideoMeta (id = view index) per view; the rig travels as GstStitchRigMeta. */
#pragma once

#include <gst/gst.h>
#include <gst/video/video.h>

#include <array>
#include <memory>
#include <string>
#include <vector>

#include "stitch/backend.hpp"
#include "stitch/image.hpp"
#include "stitch/rig/rig.hpp"

G_BEGIN_DECLS

#define STITCH_BUNDLE_FIELDS                                                     \
  "format = (string) RGBA, width = (int) [ 1, 32767 ], "                       \
  "height = (int) [ 1, 32767 ], framerate = (fraction) [ 0/1, 2147483647/1 ], " \
  "multiview-mode = (string) separated, views = (int) [ 2, 16 ]"
#define STITCH_BUNDLE_CAPS "video/x-raw, " STITCH_BUNDLE_FIELDS

/* Bundle pad templates: the views in CUDA memory first, in system memory second. CUDA memory is
 * only offered where it can be had (stitch_caps_prefer_cuda in gststitchcuda.h). */
#ifdef STITCH_HAVE_GST_CUDA
#define STITCH_BUNDLE_TEMPLATE_CAPS "video/x-raw(memory:CUDAMemory), " STITCH_BUNDLE_FIELDS "; " STITCH_BUNDLE_CAPS
#else
#define STITCH_BUNDLE_TEMPLATE_CAPS STITCH_BUNDLE_CAPS
#endif

#define STITCH_MAX_VIEWS 16

/* Per-bundle facts from stitchsync: which views hold no real frame (camera missing), and the
 * time offsets it applies to the inputs (ns added to each view's running time: the pad's own
 * offset plus load-file's or time-alignment's; view 0 is the reference under time-alignment=auto).
 * `has_time_offsets`: some offset is non-zero or time-alignment estimated one; stitchcalib then
 * saves them as the cameras' "time_offset_ns". `estimated_mask`: views time-alignment estimated
 * (saved even when 0). Appended fields: the first ones keep their layout. */
typedef struct {
  GstMeta meta;
  guint n_views;
  guint64 missing_mask;
  gboolean has_time_offsets;
  guint64 estimated_mask;
  gint64 time_offsets_ns[STITCH_MAX_VIEWS];
  /* the number N of the sink pad (sink_N) each view comes from, when `has_pad_numbers`: a camera
   * that leaves (its pad released) is known by it, and stitchcalib keeps the others' geometry */
  gboolean has_pad_numbers;
  guint pad_numbers[STITCH_MAX_VIEWS];
} GstStitchBundleMeta;

/* The rig (geometry) attached by stitchcalib. `version` changes whenever the calibration
 * changes, so later stages rebuild their maps only then. */
typedef struct {
  GstMeta meta;
  std::shared_ptr<const stitch::Rig>* rig;
  guint64 version;
} GstStitchRigMeta;

GType gst_stitch_bundle_meta_api_get_type(void);
const GstMetaInfo* gst_stitch_bundle_meta_get_info(void);
GstStitchBundleMeta* gst_buffer_add_stitch_bundle_meta(GstBuffer* buffer, guint n_views,
                                                       guint64 missing_mask);
GstStitchBundleMeta* gst_buffer_get_stitch_bundle_meta(GstBuffer* buffer);
/* Sets the meta's time offsets (n <= STITCH_MAX_VIEWS values; has_time_offsets is derived). */
void gst_stitch_bundle_meta_set_time_offsets(GstStitchBundleMeta* meta, const gint64* offsets_ns, guint n,
                                             guint64 estimated_mask);

/* Sets which sink pad each view comes from (n <= STITCH_MAX_VIEWS values). */
void gst_stitch_bundle_meta_set_pad_numbers(GstStitchBundleMeta* meta, const guint* pad_numbers, guint n);

GType gst_stitch_rig_meta_api_get_type(void);
const GstMetaInfo* gst_stitch_rig_meta_get_info(void);
GstStitchRigMeta* gst_buffer_add_stitch_rig_meta(GstBuffer* buffer,
                                                 std::shared_ptr<const stitch::Rig> rig,
                                                 guint64 version);
GstStitchRigMeta* gst_buffer_get_stitch_rig_meta(GstBuffer* buffer);

/* Set by stitchflowwarp: the views are no longer camera frames but already warped into their
 * rectangles (x, y, width, height) of the canvas, canvas_width x canvas_height, for the rig of
 * `rig_version`. stitchblend then only fuses. */
typedef struct {
  GstMeta meta;
  guint64 rig_version;
  gint canvas_width, canvas_height;
  guint n_views;
  gint rois[STITCH_MAX_VIEWS][4];
} GstStitchWarpMeta;

GType gst_stitch_warp_meta_api_get_type(void);
const GstMetaInfo* gst_stitch_warp_meta_get_info(void);
GstStitchWarpMeta* gst_buffer_add_stitch_warp_meta(GstBuffer* buffer, const GstStitchWarpMeta* from);
GstStitchWarpMeta* gst_buffer_get_stitch_warp_meta(GstBuffer* buffer);

/* Set by stitchflowwarp after warping: what the flow did in each overlap of the frame (rects in
 * canvas pixels); stitchblend's debug view draws it. */
#define STITCH_MAX_FLOW_PAIRS 64
typedef struct {
  gint view_a, view_b;
  gint rect[4];
  gdouble mean_magnitude, confident_fraction;
  /* the overlap's decision: matching error (grey levels) without / with the flow, whether the
   * flow is on and the gain it is applied with (0 = homography only) */
  gdouble error_homography, error_flow, gain;
  gboolean flow_on;
} GstStitchFlowPair;

typedef struct {
  GstMeta meta;
  guint n_pairs;
  GstStitchFlowPair pairs[STITCH_MAX_FLOW_PAIRS];
} GstStitchFlowMeta;

GType gst_stitch_flow_meta_api_get_type(void);
const GstMetaInfo* gst_stitch_flow_meta_get_info(void);
GstStitchFlowMeta* gst_buffer_add_stitch_flow_meta(GstBuffer* buffer, const GstStitchFlowMeta* from);
GstStitchFlowMeta* gst_buffer_get_stitch_flow_meta(GstBuffer* buffer);

/* backend=auto|cpu|cuda, shared by every element. */
#define GST_TYPE_STITCH_BACKEND (gst_stitch_backend_get_type())
GType gst_stitch_backend_get_type(void);

G_END_DECLS

class StitchCudaContext;

/* Maps every view of a bundle; unmaps in the destructor. Views that the bundle meta marks
 * missing come back as empty ImageViews. */
class StitchBundleMapping {
 public:
  StitchBundleMapping() = default;
  StitchBundleMapping(const StitchBundleMapping&) = delete;
  StitchBundleMapping& operator=(const StitchBundleMapping&) = delete;
  ~StitchBundleMapping();
  /* FALSE with `error` set when a view is absent or cannot be mapped. With `device`, views in
   * CUDA memory of that context are mapped with GST_MAP_CUDA (device pointers, on_device);
   * otherwise, and for views in system memory, views are host pointers (gst-cuda stages CUDA
   * memory through host memory). */
  gboolean map(GstBuffer* buffer, guint n_views, GstMapFlags flags, std::string& error,
               const StitchCudaContext* device = nullptr);
  const std::vector<stitch::ImageView>& views() const { return views_; }
  /* View sizes, including those of missing views. */
  const std::vector<std::array<int, 2>>& sizes() const { return sizes_; }

 private:
  struct Mapped {
    GstVideoMeta* meta;
    GstMapInfo info;
  };
  std::vector<Mapped> mapped_;
  std::vector<stitch::ImageView> views_;
  std::vector<std::array<int, 2>> sizes_;
};

/* The views' sizes from their GstVideoMetas, without mapping them. */
gboolean stitch_bundle_view_sizes(GstBuffer* buffer, guint n_views, std::vector<std::array<int, 2>>& sizes,
                                  std::string& error);

/* Number of views that bundle caps announce, 0 when the caps are no bundle. */
guint stitch_bundle_caps_views(const GstCaps* caps);

/* For set_caps: TRUE when `caps` are a bundle of at least 2 views, else an element error. */
gboolean stitch_bundle_accept_caps(GstElement* element, GstCaps* caps);

/* The bundle's rig, or NULL after an element error telling to put stitchcalib before `element`. */
GstStitchRigMeta* stitch_bundle_require_rig(GstElement* element, GstBuffer* buffer);

/* For the stages that read camera frames (stitchcolor, stitchflowwarp): FALSE after an element
 * error naming the fix when stitchflowwarp already warped the bundle's views onto the canvas
 * (its GstStitchWarpMeta is the mark): they must come before stitchflowwarp. */
gboolean stitch_bundle_require_camera_views(GstElement* element, GstBuffer* buffer);

/* transform_meta of the elements whose output views are new pixels (stitchflowwarp: views
 * warped onto the canvas; stitchblend: one panorama): TRUE for the metas that describe the
 * frame as a whole (reference timestamps, timecodes, metas without tags, e.g. an
 * application's), FALSE for those that describe the input views' layout or memory (tags
 * "video", "memory": per-view GstVideoMeta, crop, regions of interest) and for the stitch metas,
 * which the element attaches anew. */
gboolean stitch_meta_survives_new_views(GstMeta* meta);

/* The panorama stitchblend will output, asked by stitchcalib downstream through the stages
 * between (a custom query, not serialized: queues and base transforms pass it on). stitchblend
 * answers with its output-width/-height, or else the size its downstream fixes (a capsfilter),
 * 0 for a side left free, and its crop mode (0 none, 1 auto). */
#define STITCH_OUTPUT_SIZE_QUERY "stitch-output-size"
GstQuery* stitch_output_size_query_new(void);
gboolean stitch_output_size_query_answer(GstQuery* query, gint width, gint height, gint crop);
/* TRUE when `query` was answered; the fields are left untouched otherwise. */
gboolean stitch_output_size_query_parse(GstQuery* query, gint* width, gint* height, gint* crop);

/* Size limits, checked before anything is allocated. */
#define STITCH_MAX_FRAME_SIDE 32767 /* video caps' width/height range, as in STITCH_BUNDLE_FIELDS */

/* The memory budget in bytes for `limit_mib` (0: half the physical memory). */
guint64 stitch_memory_budget(guint limit_mib);

/* FALSE, with `error` naming the size and the limit, when a `what` of width x height would not
 * fit in caps, or when `bytes` (its estimated working memory) exceed `budget`. */
gboolean stitch_check_frame_size(const char* what, gint64 width, gint64 height, guint64 bytes, guint64 budget,
                                 std::string& error);

/* Runs `body`; a C++ exception becomes a GST_ELEMENT_ERROR naming `what`, never escaping
 * into GStreamer. Returns FALSE when an exception was caught. */
template <typename F>
gboolean stitch_guard(GstElement* element, const char* what, F&& body) {
  try {
    body();
    return TRUE;
  } catch (const std::exception& e) {
    GST_ELEMENT_ERROR(element, STREAM, FAILED, ("%s: %s", what, e.what()), (NULL));
  } catch (...) {
    GST_ELEMENT_ERROR(element, STREAM, FAILED, ("%s: unknown error", what), (NULL));
  }
  return FALSE;
}
