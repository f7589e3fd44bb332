#pragma once
#include <gst/video/video.h>

G_BEGIN_DECLS
#define GST_TYPE_STITCH_SYNC (gst_stitch_sync_get_type())
G_DECLARE_FINAL_TYPE(GstStitchSync, gst_stitch_sync, GST, STITCH_SYNC, GstVideoAggregator)

typedef enum {
  GST_STITCH_SYNC_INPUT_EOS_REPEAT_LAST = 0,
  GST_STITCH_SYNC_INPUT_EOS_END_STREAM = 1,
} GstStitchSyncInputEos;

typedef enum {
  GST_STITCH_SYNC_DROPOUT_FREEZE = 0,
  GST_STITCH_SYNC_DROPOUT_FILL = 1,
} GstStitchSyncDropout;

typedef enum {
  GST_STITCH_SYNC_TIME_ALIGNMENT_NONE = 0,
  GST_STITCH_SYNC_TIME_ALIGNMENT_AUTO = 1,
} GstStitchSyncTimeAlignment;

GST_ELEMENT_REGISTER_DECLARE(stitchsync);
G_END_DECLS
