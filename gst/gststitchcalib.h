#pragma once
#include <gst/base/gstbasetransform.h>

G_BEGIN_DECLS
#define GST_TYPE_STITCH_CALIB (gst_stitch_calib_get_type())
G_DECLARE_FINAL_TYPE(GstStitchCalib, gst_stitch_calib, GST, STITCH_CALIB, GstBaseTransform)
GST_ELEMENT_REGISTER_DECLARE(stitchcalib);
G_END_DECLS
