#pragma once
#include <gst/base/gstbasetransform.h>

G_BEGIN_DECLS
#define GST_TYPE_STITCH_BLEND (gst_stitch_blend_get_type())
G_DECLARE_FINAL_TYPE(GstStitchBlend, gst_stitch_blend, GST, STITCH_BLEND, GstBaseTransform)
GST_ELEMENT_REGISTER_DECLARE(stitchblend);
G_END_DECLS
