#pragma once
#include <gst/gst.h>

G_BEGIN_DECLS
#define GST_TYPE_STITCH_SYNC_AUDIO (gst_stitch_sync_audio_get_type())
G_DECLARE_FINAL_TYPE(GstStitchSyncAudio, gst_stitch_sync_audio, GST, STITCH_SYNC_AUDIO, GstElement)
GST_ELEMENT_REGISTER_DECLARE(stitchsyncaudio);
G_END_DECLS
