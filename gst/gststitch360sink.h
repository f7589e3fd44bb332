#pragma once
#include <gst/gst.h>

G_BEGIN_DECLS
#define GST_TYPE_STITCH_360_SINK (gst_stitch_360_sink_get_type())
G_DECLARE_FINAL_TYPE(GstStitch360Sink, gst_stitch_360_sink, GST, STITCH_360_SINK, GstBin)
GST_ELEMENT_REGISTER_DECLARE(stitch360sink);
G_END_DECLS
