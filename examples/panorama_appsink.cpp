// Embedding gst-stitch in an application: the chain is one gst_parse_launch() line ending in an
// appsink, and the application pulls every panorama as an RGBA buffer. Here it counts them,
// prints their size and writes the last one as a PPM image.
//
// usage: panorama-appsink [--frames N] [--out FILE.ppm] [--chain "ELEMENTS"] VIDEO VIDEO [VIDEO...]
//   GST_PLUGIN_PATH must reach the stitch plugin (build/gst). --chain replaces the default
//   "stitchbin" (e.g. --chain "stitchsync name=s ! stitchcalib ! stitchblend mode=multiband").
//   Exits 0 when N panoramas arrived (or the clips ended after at least one), 1 otherwise.
#include <gst/app/gstappsink.h>
#include <gst/gst.h>
#include <gst/video/video.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

namespace {

// Writes an RGBA frame as a binary PPM (RGB).
bool write_ppm(const std::string& path, const GstVideoFrame& frame) {
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return false;
  const int w = GST_VIDEO_FRAME_WIDTH(&frame), h = GST_VIDEO_FRAME_HEIGHT(&frame);
  std::fprintf(f, "P6\n%d %d\n255\n", w, h);
  std::vector<unsigned char> row(std::size_t(w) * 3);
  for (int y = 0; y < h; ++y) {
    const auto* p = static_cast<const unsigned char*>(GST_VIDEO_FRAME_PLANE_DATA(&frame, 0)) +
                    std::size_t(y) * GST_VIDEO_FRAME_PLANE_STRIDE(&frame, 0);
    for (int x = 0; x < w; ++x) std::memcpy(&row[std::size_t(x) * 3], p + std::size_t(x) * 4, 3);
    std::fwrite(row.data(), 1, row.size(), f);
  }
  return std::fclose(f) == 0;
}

}  // namespace

int main(int argc, char** argv) {
  gst_init(&argc, &argv);
  int frames = 30;
  std::string out_path, chain = "stitchbin name=s";
  std::vector<std::string> videos;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--out") && i + 1 < argc) out_path = argv[++i];
    else if (!std::strcmp(argv[i], "--chain") && i + 1 < argc) chain = argv[++i];
    else videos.push_back(argv[i]);
  }
  if (videos.size() < 2 || frames < 1) {
    std::fprintf(stderr, "usage: %s [--frames N] [--out FILE.ppm] [--chain \"ELEMENTS\"] VIDEO VIDEO [VIDEO...]\n",
                 argv[0]);
    return 2;
  }
  // The chain's first element is named s; each camera goes to s.sink_N. The appsink asks for
  // RGBA in system memory (videoconvert also takes stitchblend's CUDA memory via cudadownload
  // when present; system memory is negotiated otherwise).
  std::string description = chain + " ! videoconvert ! video/x-raw,format=RGBA ! appsink name=panoramas sync=false";
  for (std::size_t i = 0; i < videos.size(); ++i)
    description += " filesrc location=\"" + videos[i] + "\" ! decodebin ! videoconvert ! s.sink_" + std::to_string(i);
  GError* error = nullptr;
  GstElement* pipeline = gst_parse_launch(description.c_str(), &error);
  if (!pipeline) {
    std::fprintf(stderr, "cannot build the pipeline: %s\n", error ? error->message : "?");
    g_clear_error(&error);
    return 1;
  }
  GstElement* sink = gst_bin_get_by_name(GST_BIN(pipeline), "panoramas");
  gst_element_set_state(pipeline, GST_STATE_PLAYING);

  int got = 0;
  GstSample* last = nullptr;
  while (got < frames) {
    // Blocks until a panorama arrives; NULL at EOS or on an error (read from the bus below).
    GstSample* sample = gst_app_sink_try_pull_sample(GST_APP_SINK(sink), 120 * GST_SECOND);
    if (!sample) break;
    ++got;
    if (last) gst_sample_unref(last);
    last = sample;
  }
  int rc = got == frames ? 0 : 1;
  GstBus* bus = gst_element_get_bus(pipeline);
  if (GstMessage* m = gst_bus_pop_filtered(bus, GST_MESSAGE_ERROR)) {
    GError* e = nullptr;
    gchar* dbg = nullptr;
    gst_message_parse_error(m, &e, &dbg);
    std::fprintf(stderr, "error from %s: %s\n%s\n", GST_OBJECT_NAME(m->src), e->message, dbg ? dbg : "");
    g_clear_error(&e);
    g_free(dbg);
    gst_message_unref(m);
    rc = 1;
  } else if (got > 0 && got < frames && gst_app_sink_is_eos(GST_APP_SINK(sink))) {
    rc = 0;  // the clips were shorter than asked
  }
  gst_object_unref(bus);
  if (last) {
    GstVideoInfo info;
    GstVideoFrame frame;
    gst_video_info_from_caps(&info, gst_sample_get_caps(last));
    std::printf("%d panoramas, %dx%d\n", got, GST_VIDEO_INFO_WIDTH(&info), GST_VIDEO_INFO_HEIGHT(&info));
    if (!out_path.empty() && gst_video_frame_map(&frame, &info, gst_sample_get_buffer(last), GST_MAP_READ)) {
      if (!write_ppm(out_path, frame)) {
        std::fprintf(stderr, "cannot write %s\n", out_path.c_str());
        rc = 1;
      }
      gst_video_frame_unmap(&frame);
    }
    gst_sample_unref(last);
  } else {
    std::fprintf(stderr, "no panorama arrived\n");
  }
  gst_element_set_state(pipeline, GST_STATE_NULL);
  gst_object_unref(sink);
  gst_object_unref(pipeline);
  return rc;
}
