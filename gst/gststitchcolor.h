#pragma once
#include <gst/base/gstbasetransform.h>

G_BEGIN_DECLS
#define GST_TYPE_STITCH_COLOR (gst_stitch_color_get_type())
G_DECLARE_FINAL_TYPE(GstStitchColor, gst_stitch_color, GST, STITCH_COLOR, GstBaseTransform)
GST_ELEMENT_REGISTER_DECLARE(stitchcolor);
G_END_DECLS
