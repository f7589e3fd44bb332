#include <gst/gst.h>

#include "gststitch360sink.h"
#include "gststitchbin.h"
#include "gststitchblend.h"
#include "gststitchcalib.h"
#include "gststitchcolor.h"
#include "gststitchflowwarp.h"
#include "gststitchsync.h"
#include "gststitchsyncaudio.h"

static gboolean plugin_init(GstPlugin* plugin) {
  gboolean ok = FALSE;
  ok |= GST_ELEMENT_REGISTER(stitchsync, plugin);
  ok |= GST_ELEMENT_REGISTER(stitchsyncaudio, plugin);
  ok |= GST_ELEMENT_REGISTER(stitchcalib, plugin);
  ok |= GST_ELEMENT_REGISTER(stitchcolor, plugin);
  ok |= GST_ELEMENT_REGISTER(stitchflowwarp, plugin);
  ok |= GST_ELEMENT_REGISTER(stitchblend, plugin);
  ok |= GST_ELEMENT_REGISTER(stitchbin, plugin);  // after its children
  ok |= GST_ELEMENT_REGISTER(stitch360sink, plugin);
  return ok;
}

#define PACKAGE "gst-stitch"
GST_PLUGIN_DEFINE(GST_VERSION_MAJOR, GST_VERSION_MINOR, stitch,
                  "Real-time multi-camera video stitching (color correction, flow warping, "
                  "blending)",
                  plugin_init, "0.1.0", "LGPL", PACKAGE, "https://github.com/gst-stitch")
