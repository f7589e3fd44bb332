#pragma once
#include <gst/base/gstbasetransform.h>

G_BEGIN_DECLS
#define GST_TYPE_STITCH_FLOW_WARP (gst_stitch_flow_warp_get_type())
G_DECLARE_FINAL_TYPE(GstStitchFlowWarp, gst_stitch_flow_warp, GST, STITCH_FLOW_WARP, GstBaseTransform)
GST_ELEMENT_REGISTER_DECLARE(stitchflowwarp);
G_END_DECLS
