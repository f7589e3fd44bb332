#include "gststitchbundle.h"

#include <unistd.h>

#include <cstring>

#include "gststitchcuda.h"

/* ---- bundle meta ---- */

GType gst_stitch_bundle_meta_api_get_type(void) {
  static GType type = 0;
  static const gchar* tags[] = {"stitch", NULL};
  if (g_once_init_enter(&type)) {
    GType t = gst_meta_api_type_register("GstStitchBundleMetaAPI", tags);
    g_once_init_leave(&type, t);
  }
  return type;
}

static gboolean bundle_meta_init(GstMeta* meta, gpointer, GstBuffer*) {
  auto* m = reinterpret_cast<GstStitchBundleMeta*>(meta);
  m->n_views = 0;
  m->missing_mask = 0;
  m->has_time_offsets = FALSE;
  m->estimated_mask = 0;
  std::memset(m->time_offsets_ns, 0, sizeof(m->time_offsets_ns));
  m->has_pad_numbers = FALSE;
  std::memset(m->pad_numbers, 0, sizeof(m->pad_numbers));
  return TRUE;
}

static gboolean bundle_meta_transform(GstBuffer* dest, GstMeta* meta, GstBuffer*, GQuark type,
                                      gpointer) {
  if (!GST_META_TRANSFORM_IS_COPY(type)) return FALSE;
  auto* m = reinterpret_cast<GstStitchBundleMeta*>(meta);
  GstStitchBundleMeta* d = gst_buffer_add_stitch_bundle_meta(dest, m->n_views, m->missing_mask);
  if (!d) return FALSE;
  d->has_time_offsets = m->has_time_offsets;
  d->estimated_mask = m->estimated_mask;
  std::memcpy(d->time_offsets_ns, m->time_offsets_ns, sizeof(d->time_offsets_ns));
  d->has_pad_numbers = m->has_pad_numbers;
  std::memcpy(d->pad_numbers, m->pad_numbers, sizeof(d->pad_numbers));
  return TRUE;
}

const GstMetaInfo* gst_stitch_bundle_meta_get_info(void) {
  static const GstMetaInfo* info = NULL;
  if (g_once_init_enter(&info)) {
    const GstMetaInfo* mi = gst_meta_register(
        gst_stitch_bundle_meta_api_get_type(), "GstStitchBundleMeta", sizeof(GstStitchBundleMeta),
        bundle_meta_init, NULL, bundle_meta_transform);
    g_once_init_leave(&info, mi);
  }
  return info;
}

GstStitchBundleMeta* gst_buffer_add_stitch_bundle_meta(GstBuffer* buffer, guint n_views,
                                                       guint64 missing_mask) {
  auto* m = reinterpret_cast<GstStitchBundleMeta*>(
      gst_buffer_add_meta(buffer, gst_stitch_bundle_meta_get_info(), NULL));
  if (m) {
    m->n_views = n_views;
    m->missing_mask = missing_mask;
  }
  return m;
}

GstStitchBundleMeta* gst_buffer_get_stitch_bundle_meta(GstBuffer* buffer) {
  return reinterpret_cast<GstStitchBundleMeta*>(
      gst_buffer_get_meta(buffer, gst_stitch_bundle_meta_api_get_type()));
}

void gst_stitch_bundle_meta_set_pad_numbers(GstStitchBundleMeta* meta, const guint* pad_numbers, guint n) {
  if (!meta) return;
  n = MIN(n, guint(STITCH_MAX_VIEWS));
  std::memset(meta->pad_numbers, 0, sizeof(meta->pad_numbers));
  for (guint v = 0; v < n; ++v) meta->pad_numbers[v] = pad_numbers[v];
  meta->has_pad_numbers = TRUE;
}

void gst_stitch_bundle_meta_set_time_offsets(GstStitchBundleMeta* meta, const gint64* offsets_ns, guint n,
                                             guint64 estimated_mask) {
  if (!meta) return;
  n = MIN(n, guint(STITCH_MAX_VIEWS));
  std::memset(meta->time_offsets_ns, 0, sizeof(meta->time_offsets_ns));
  meta->estimated_mask = estimated_mask;
  meta->has_time_offsets = estimated_mask != 0;
  for (guint v = 0; v < n; ++v) {
    meta->time_offsets_ns[v] = offsets_ns[v];
    if (offsets_ns[v] != 0) meta->has_time_offsets = TRUE;
  }
}

/* ---- rig meta ---- */

GType gst_stitch_rig_meta_api_get_type(void) {
  static GType type = 0;
  static const gchar* tags[] = {"stitch", NULL};
  if (g_once_init_enter(&type)) {
    GType t = gst_meta_api_type_register("GstStitchRigMetaAPI", tags);
    g_once_init_leave(&type, t);
  }
  return type;
}

static gboolean rig_meta_init(GstMeta* meta, gpointer, GstBuffer*) {
  auto* m = reinterpret_cast<GstStitchRigMeta*>(meta);
  m->rig = NULL;
  m->version = 0;
  return TRUE;
}

static void rig_meta_free(GstMeta* meta, GstBuffer*) {
  auto* m = reinterpret_cast<GstStitchRigMeta*>(meta);
  delete m->rig;
  m->rig = NULL;
}

static gboolean rig_meta_transform(GstBuffer* dest, GstMeta* meta, GstBuffer*, GQuark type,
                                   gpointer) {
  if (!GST_META_TRANSFORM_IS_COPY(type)) return FALSE;
  auto* m = reinterpret_cast<GstStitchRigMeta*>(meta);
  if (!m->rig) return FALSE;
  return gst_buffer_add_stitch_rig_meta(dest, *m->rig, m->version) != NULL;
}

const GstMetaInfo* gst_stitch_rig_meta_get_info(void) {
  static const GstMetaInfo* info = NULL;
  if (g_once_init_enter(&info)) {
    const GstMetaInfo* mi =
        gst_meta_register(gst_stitch_rig_meta_api_get_type(), "GstStitchRigMeta",
                          sizeof(GstStitchRigMeta), rig_meta_init, rig_meta_free, rig_meta_transform);
    g_once_init_leave(&info, mi);
  }
  return info;
}

GstStitchRigMeta* gst_buffer_add_stitch_rig_meta(GstBuffer* buffer,
                                                 std::shared_ptr<const stitch::Rig> rig,
                                                 guint64 version) {
  auto* m = reinterpret_cast<GstStitchRigMeta*>(
      gst_buffer_add_meta(buffer, gst_stitch_rig_meta_get_info(), NULL));
  if (m) {
    m->rig = new std::shared_ptr<const stitch::Rig>(std::move(rig));
    m->version = version;
  }
  return m;
}

GstStitchRigMeta* gst_buffer_get_stitch_rig_meta(GstBuffer* buffer) {
  return reinterpret_cast<GstStitchRigMeta*>(
      gst_buffer_get_meta(buffer, gst_stitch_rig_meta_api_get_type()));
}

/* ---- warp meta ---- */

GType gst_stitch_warp_meta_api_get_type(void) {
  static GType type = 0;
  static const gchar* tags[] = {"stitch", NULL};
  if (g_once_init_enter(&type)) {
    GType t = gst_meta_api_type_register("GstStitchWarpMetaAPI", tags);
    g_once_init_leave(&type, t);
  }
  return type;
}

static gboolean warp_meta_init(GstMeta* meta, gpointer, GstBuffer*) {
  auto* m = reinterpret_cast<GstStitchWarpMeta*>(meta);
  m->rig_version = 0;
  m->canvas_width = m->canvas_height = 0;
  m->n_views = 0;
  std::memset(m->rois, 0, sizeof(m->rois));
  return TRUE;
}

static gboolean warp_meta_transform(GstBuffer* dest, GstMeta* meta, GstBuffer*, GQuark type,
                                    gpointer) {
  if (!GST_META_TRANSFORM_IS_COPY(type)) return FALSE;
  return gst_buffer_add_stitch_warp_meta(dest, reinterpret_cast<GstStitchWarpMeta*>(meta)) != NULL;
}

const GstMetaInfo* gst_stitch_warp_meta_get_info(void) {
  static const GstMetaInfo* info = NULL;
  if (g_once_init_enter(&info)) {
    const GstMetaInfo* mi = gst_meta_register(
        gst_stitch_warp_meta_api_get_type(), "GstStitchWarpMeta", sizeof(GstStitchWarpMeta),
        warp_meta_init, NULL, warp_meta_transform);
    g_once_init_leave(&info, mi);
  }
  return info;
}

GstStitchWarpMeta* gst_buffer_add_stitch_warp_meta(GstBuffer* buffer, const GstStitchWarpMeta* from) {
  auto* m = reinterpret_cast<GstStitchWarpMeta*>(
      gst_buffer_add_meta(buffer, gst_stitch_warp_meta_get_info(), NULL));
  if (m) {
    m->rig_version = from->rig_version;
    m->canvas_width = from->canvas_width;
    m->canvas_height = from->canvas_height;
    m->n_views = from->n_views;
    std::memcpy(m->rois, from->rois, sizeof(m->rois));
  }
  return m;
}

GstStitchWarpMeta* gst_buffer_get_stitch_warp_meta(GstBuffer* buffer) {
  return reinterpret_cast<GstStitchWarpMeta*>(
      gst_buffer_get_meta(buffer, gst_stitch_warp_meta_api_get_type()));
}

/* ---- flow meta ---- */

GType gst_stitch_flow_meta_api_get_type(void) {
  static GType type = 0;
  static const gchar* tags[] = {"stitch", NULL};
  if (g_once_init_enter(&type)) {
    GType t = gst_meta_api_type_register("GstStitchFlowMetaAPI", tags);
    g_once_init_leave(&type, t);
  }
  return type;
}

static gboolean flow_meta_init(GstMeta* meta, gpointer, GstBuffer*) {
  reinterpret_cast<GstStitchFlowMeta*>(meta)->n_pairs = 0;
  return TRUE;
}

static gboolean flow_meta_transform(GstBuffer* dest, GstMeta* meta, GstBuffer*, GQuark type, gpointer) {
  if (!GST_META_TRANSFORM_IS_COPY(type)) return FALSE;
  return gst_buffer_add_stitch_flow_meta(dest, reinterpret_cast<GstStitchFlowMeta*>(meta)) != NULL;
}

const GstMetaInfo* gst_stitch_flow_meta_get_info(void) {
  static const GstMetaInfo* info = NULL;
  if (g_once_init_enter(&info)) {
    const GstMetaInfo* mi = gst_meta_register(gst_stitch_flow_meta_api_get_type(), "GstStitchFlowMeta",
                                              sizeof(GstStitchFlowMeta), flow_meta_init, NULL, flow_meta_transform);
    g_once_init_leave(&info, mi);
  }
  return info;
}

GstStitchFlowMeta* gst_buffer_add_stitch_flow_meta(GstBuffer* buffer, const GstStitchFlowMeta* from) {
  auto* m = reinterpret_cast<GstStitchFlowMeta*>(gst_buffer_add_meta(buffer, gst_stitch_flow_meta_get_info(), NULL));
  if (m) {
    m->n_pairs = MIN(from->n_pairs, STITCH_MAX_FLOW_PAIRS);
    std::memcpy(m->pairs, from->pairs, sizeof(GstStitchFlowPair) * m->n_pairs);
  }
  return m;
}

GstStitchFlowMeta* gst_buffer_get_stitch_flow_meta(GstBuffer* buffer) {
  return reinterpret_cast<GstStitchFlowMeta*>(gst_buffer_get_meta(buffer, gst_stitch_flow_meta_api_get_type()));
}

/* ---- backend enum ---- */

GType gst_stitch_backend_get_type(void) {
  static GType type = 0;
  static const GEnumValue values[] = {
      {int(stitch::Backend::Auto), "CUDA when a device loads, otherwise the CPU", "auto"},
      {int(stitch::Backend::Cpu), "CPU (OpenCV)", "cpu"},
      {int(stitch::Backend::Cuda), "CUDA", "cuda"},
      {0, NULL, NULL}};
  if (g_once_init_enter(&type)) {
    GType t = g_enum_register_static("GstStitchBackend", values);
    g_once_init_leave(&type, t);
  }
  return type;
}

/* ---- view mapping ---- */

StitchBundleMapping::~StitchBundleMapping() {
  for (auto& m : mapped_) gst_video_meta_unmap(m.meta, 0, &m.info);
}

/* The RGBA GstVideoMeta of view `i`, or NULL with `error` set. */
static GstVideoMeta* view_meta(GstBuffer* buffer, guint i, std::string& error) {
  GstVideoMeta* vm = gst_buffer_get_video_meta_id(buffer, gint(i));
  if (!vm) {
    error = "the bundle has no view " + std::to_string(i);
    return NULL;
  }
  if (vm->format != GST_VIDEO_FORMAT_RGBA) {
    error = "view " + std::to_string(i) + " is not RGBA";
    return NULL;
  }
  return vm;
}

gboolean stitch_bundle_view_sizes(GstBuffer* buffer, guint n_views, std::vector<std::array<int, 2>>& sizes,
                                  std::string& error) {
  sizes.assign(n_views, {0, 0});
  for (guint i = 0; i < n_views; ++i) {
    GstVideoMeta* vm = view_meta(buffer, i, error);
    if (!vm) return FALSE;
    sizes[i] = {int(vm->width), int(vm->height)};
  }
  return TRUE;
}

gboolean StitchBundleMapping::map(GstBuffer* buffer, guint n_views, GstMapFlags flags, std::string& error,
                                  const StitchCudaContext* device) {
  GstStitchBundleMeta* bm = gst_buffer_get_stitch_bundle_meta(buffer);
  const guint64 missing = bm ? bm->missing_mask : 0;
  views_.assign(n_views, stitch::ImageView());
  if (!stitch_bundle_view_sizes(buffer, n_views, sizes_, error)) return FALSE;
  /* where each view lies decides how it is mapped */
  std::vector<bool> device_view(n_views, false);
  gboolean all_on_device = device != nullptr;
  for (guint i = 0; i < n_views; ++i) {
    if (missing >> i & 1) continue;
    GstVideoMeta* vm = gst_buffer_get_video_meta_id(buffer, gint(i));
    guint idx = 0, length = 0;
    gsize skip = 0;
    device_view[i] = device && gst_buffer_find_memory(buffer, vm->offset[0], 1, &idx, &length, &skip) &&
                     device->owns(gst_buffer_peek_memory(buffer, idx));
    all_on_device = all_on_device && device_view[i];
  }
  /* device work still writing or reading the bundle (stream-ordered hand-off): the stage's
   * streams wait for it, or the host does before a host mapping (gststitchcuda.h) */
  if (!stitch_cuda_fence_before_map(buffer, all_on_device, error)) return FALSE;
  for (guint i = 0; i < n_views; ++i) {
    if (missing >> i & 1) continue;
    GstVideoMeta* vm = gst_buffer_get_video_meta_id(buffer, gint(i));
    const bool on_device = device_view[i];
    const GstMapFlags view_flags = on_device ? GstMapFlags(flags | STITCH_MAP_CUDA) : flags;
    Mapped m{vm, {}};
    gpointer data = NULL;
    gint stride = 0;
    if (!gst_video_meta_map(vm, 0, &m.info, &data, &stride, view_flags)) {
      error = "cannot map view " + std::to_string(i);
      return FALSE;
    }
    mapped_.push_back(m);
    stitch::ImageView& v = views_[i];
    v.data = static_cast<uint8_t*>(data);
    v.pitch = std::size_t(stride);
    v.width = int(vm->width);
    v.height = int(vm->height);
    v.on_device = on_device;
  }
  return TRUE;
}

guint stitch_bundle_caps_views(const GstCaps* caps) {
  if (!caps || gst_caps_get_size(caps) < 1) return 0;
  const GstStructure* s = gst_caps_get_structure(caps, 0);
  gint views = 0;
  const gchar* mode = gst_structure_get_string(s, "multiview-mode");
  if (!mode || g_strcmp0(mode, "separated") != 0) return 0;
  if (!gst_structure_get_int(s, "views", &views) || views < 1) return 0;
  return guint(views);
}

gboolean stitch_bundle_accept_caps(GstElement* element, GstCaps* caps) {
  if (stitch_bundle_caps_views(caps) >= 2) return TRUE;
  GST_ELEMENT_ERROR(element, STREAM, FORMAT,
                    ("%s needs a bundle of at least 2 views (put stitchsync before it)",
                     GST_ELEMENT_NAME(element)),
                    ("caps %" GST_PTR_FORMAT, caps));
  return FALSE;
}

GstStitchRigMeta* stitch_bundle_require_rig(GstElement* element, GstBuffer* buffer) {
  GstStitchRigMeta* meta = gst_buffer_get_stitch_rig_meta(buffer);
  if (meta && meta->rig && *meta->rig) return meta;
  GstElementFactory* f = gst_element_get_factory(element);
  GST_ELEMENT_ERROR(element, STREAM, FORMAT,
                    ("The bundle carries no calibration: put stitchcalib before %s",
                     f ? GST_OBJECT_NAME(f) : GST_ELEMENT_NAME(element)),
                    (NULL));
  return NULL;
}

gboolean stitch_bundle_require_camera_views(GstElement* element, GstBuffer* buffer) {
  if (!gst_buffer_get_stitch_warp_meta(buffer)) return TRUE;
  GstElementFactory* f = gst_element_get_factory(element);
  const gchar* name = f ? GST_OBJECT_NAME(f) : GST_ELEMENT_NAME(element);
  if (g_strcmp0(name, "stitchflowwarp") == 0)
    GST_ELEMENT_ERROR(element, CORE, NEGOTIATION,
                      ("The bundle went through stitchflowwarp already: keep one stitchflowwarp (stitchsync ! "
                       "stitchcalib ! stitchcolor ! stitchflowwarp ! stitchblend)"),
                      ("the bundle carries a GstStitchWarpMeta"));
  else
    GST_ELEMENT_ERROR(element, CORE, NEGOTIATION,
                      ("%s comes after stitchflowwarp, whose views are already warped onto the canvas: put %s "
                       "before stitchflowwarp (stitchsync ! stitchcalib ! stitchcolor ! stitchflowwarp ! "
                       "stitchblend)",
                       name, name),
                      ("the bundle carries a GstStitchWarpMeta"));
  return FALSE;
}

gboolean stitch_meta_survives_new_views(GstMeta* meta) {
  const GType api = meta->info->api;
  return !gst_meta_api_type_has_tag(api, g_quark_from_static_string("stitch")) &&
         !gst_meta_api_type_has_tag(api, g_quark_from_static_string(GST_META_TAG_VIDEO_STR)) &&
         !gst_meta_api_type_has_tag(api, g_quark_from_static_string(GST_META_TAG_MEMORY_STR));
}

guint64 stitch_memory_budget(guint limit_mib) {
  if (limit_mib > 0) return guint64(limit_mib) << 20;
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  if (pages <= 0 || page <= 0) return guint64(8) << 30;  /* unknown: 8 GiB */
  return guint64(pages) * guint64(page) / 2;
}

gboolean stitch_check_frame_size(const char* what, gint64 width, gint64 height, guint64 bytes, guint64 budget,
                                 std::string& error) {
  if (width > STITCH_MAX_FRAME_SIDE || height > STITCH_MAX_FRAME_SIDE) {
    error = std::string(what) + " would be " + std::to_string(width) + "x" + std::to_string(height) +
            ", beyond the " + std::to_string(STITCH_MAX_FRAME_SIDE) + "-pixel limit of video caps on a side";
    return FALSE;
  }
  if (budget > 0 && bytes > budget) {
    error = std::string(what) + " of " + std::to_string(width) + "x" + std::to_string(height) + " needs about " +
            std::to_string((bytes + (1 << 20) - 1) >> 20) + " MiB of working memory, beyond the budget of " +
            std::to_string(budget >> 20) + " MiB";
    return FALSE;
  }
  return TRUE;
}

GstQuery* stitch_output_size_query_new(void) {
  return gst_query_new_custom(GST_QUERY_CUSTOM, gst_structure_new_empty(STITCH_OUTPUT_SIZE_QUERY));
}

static GstStructure* output_size_structure(GstQuery* query, gboolean writable) {
  if (GST_QUERY_TYPE(query) != GST_QUERY_CUSTOM) return NULL;
  const GstStructure* s = gst_query_get_structure(query);
  if (!s || !gst_structure_has_name(s, STITCH_OUTPUT_SIZE_QUERY)) return NULL;
  return writable ? gst_query_writable_structure(query) : (GstStructure*)s;
}

gboolean stitch_output_size_query_answer(GstQuery* query, gint width, gint height, gint crop) {
  GstStructure* s = output_size_structure(query, TRUE);
  if (!s) return FALSE;
  gst_structure_set(s, "width", G_TYPE_INT, width, "height", G_TYPE_INT, height, "crop", G_TYPE_INT, crop, NULL);
  return TRUE;
}

gboolean stitch_output_size_query_parse(GstQuery* query, gint* width, gint* height, gint* crop) {
  const GstStructure* s = output_size_structure(query, FALSE);
  gint w = 0, h = 0, c = 0;
  if (!s || !gst_structure_get_int(s, "width", &w) || !gst_structure_get_int(s, "height", &h) ||
      !gst_structure_get_int(s, "crop", &c))
    return FALSE;
  *width = w;
  *height = h;
  *crop = c;
  return TRUE;
}
