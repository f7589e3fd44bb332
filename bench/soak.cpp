// Soak: the whole CPU chain (stitchsync, stitchcalib, stitchcolor, stitchflowwarp, stitchblend)
// stitches `frames` panoramas from three synthetic cameras while camera 1 drops out every
// `dropout_every` frames for 1 s (a probe drops its frames: a stall, seen as a timestamp jump)
// and rejoins. Samples the process's RSS (VmRSS from /proc/self/status) every `sample_every`
// panoramas into a CSV and prints a summary; exits 1 when the stream stopped early, a dropout
// was not survived, or RSS grew more than `max_growth_mb` after the warm-up (first 10%).
//
//   stitch-soak [frames=20000] [csv=soak_rss.csv] [width=160] [max_growth_mb=16]
//   (GST_PLUGIN_PATH=build/gst; not part of CI: about a minute at 160x120)
#include <gst/gst.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <mutex>
#include <string>
#include <vector>

namespace {

long rss_kb() {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line))
    if (line.rfind("VmRSS:", 0) == 0) return std::atol(line.c_str() + 6);
  return -1;
}

struct Sample {
  long frame;
  double seconds;
  long rss_kb;
};

struct Soak {
  std::atomic<long> camera1{0};
  long dropout_every = 2000, dropout_frames = 30, sample_every = 250;
  std::atomic<long> frames{0};
  std::mutex lock;
  std::vector<Sample> samples;
  std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
};

// Camera 1 stalls for dropout_frames frames in the middle of every dropout_every.
GstPadProbeReturn on_camera1(GstPad*, GstPadProbeInfo*, gpointer data) {
  auto* soak = static_cast<Soak*>(data);
  const long phase = soak->camera1++ % soak->dropout_every - soak->dropout_every / 2;
  return phase >= 0 && phase < soak->dropout_frames ? GST_PAD_PROBE_DROP : GST_PAD_PROBE_OK;
}

GstPadProbeReturn on_panorama(GstPad*, GstPadProbeInfo*, gpointer data) {
  auto* soak = static_cast<Soak*>(data);
  const long n = ++soak->frames;
  if (n % soak->sample_every == 0 || n == 1) {
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - soak->start).count();
    std::lock_guard<std::mutex> g(soak->lock);
    soak->samples.push_back({n, s, rss_kb()});
  }
  return GST_PAD_PROBE_OK;
}

}  // namespace

int main(int argc, char** argv) {
  gst_init(&argc, &argv);
  const long frames = argc > 1 ? std::atol(argv[1]) : 20000;
  const std::string csv = argc > 2 ? argv[2] : "soak_rss.csv";
  const int width = argc > 3 ? std::atoi(argv[3]) : 160;
  const double max_growth_mb = argc > 4 ? std::atof(argv[4]) : 16.0;
  const int height = width * 3 / 4, shift = width * 5 / 8;

  // An exact-enough calibration for three cameras `shift` px apart (the patterns differ: this
  // soaks the machinery, not the seams).
  const std::string calib = "/tmp/stitch_soak_rig.json";
  {
    std::ofstream f(calib);
    f << R"({"format":"stitch-rig","version":1,"projection":"plane","reference":0,"canvas":{"width":)"
      << 2 * shift + width << R"(,"height":)" << height << R"(},"cameras":[)";
    for (int i = 0; i < 3; ++i)
      f << (i ? "," : "") << R"({"width":)" << width << R"(,"height":)" << height << R"(,"fx":)" << width
        << R"(,"fy":)" << width << R"(,"cx":)" << (width - 1) / 2.0 << R"(,"cy":)" << (height - 1) / 2.0
        << R"(,"homography":[1,0,)" << shift * i << ",0,1,0,0,0,1]}";
    f << "]}";
  }
  const std::string caps = "video/x-raw,width=" + std::to_string(width) + ",height=" + std::to_string(height) +
                           ",framerate=30/1";
  const std::string n = std::to_string(frames + 60);  // the output ends with the inputs
  const std::string desc =
      "stitchsync name=s backend=cpu dropout=fill dropout-timeout=200000000 ! stitchcalib load-file=" + calib +
      " ! stitchcolor backend=cpu ! stitchflowwarp backend=cpu ! stitchblend backend=cpu name=b ! fakesink "
      "videotestsrc num-buffers=" + n + " pattern=ball ! " + caps + " ! s.sink_0 "
      "videotestsrc num-buffers=" + n + " pattern=smpte ! " + caps + " ! identity name=cam1 ! s.sink_1 "
      "videotestsrc num-buffers=" + n + " pattern=pinwheel ! " + caps + " ! s.sink_2";
  GError* err = nullptr;
  GstElement* pipe = gst_parse_launch(desc.c_str(), &err);
  if (!pipe) {
    std::fprintf(stderr, "soak: %s\n", err ? err->message : "parse failed");
    return 2;
  }
  Soak soak;
  GstElement* cam1 = gst_bin_get_by_name(GST_BIN(pipe), "cam1");
  GstPad* cam1_src = gst_element_get_static_pad(cam1, "src");
  gst_pad_add_probe(cam1_src, GST_PAD_PROBE_TYPE_BUFFER, on_camera1, &soak, nullptr);
  GstElement* blend = gst_bin_get_by_name(GST_BIN(pipe), "b");
  GstPad* src = gst_element_get_static_pad(blend, "src");
  gst_pad_add_probe(src, GST_PAD_PROBE_TYPE_BUFFER, on_panorama, &soak, nullptr);
  GstBus* bus = gst_element_get_bus(pipe);
  gst_element_set_state(pipe, GST_STATE_PLAYING);
  int dropouts = 0, rejoins = 0, warnings = 0;
  bool ok = true;
  while (soak.frames < frames) {
    GstMessage* m = gst_bus_timed_pop(bus, 100 * GST_MSECOND);
    if (!m) continue;
    if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR) {
      GError* e = nullptr;
      gst_message_parse_error(m, &e, nullptr);
      std::fprintf(stderr, "soak: error after %ld frames: %s\n", soak.frames.load(), e->message);
      g_error_free(e);
      ok = false;
    } else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_EOS) {
      ok = soak.frames >= frames;
    } else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_WARNING) {
      ++warnings;
    } else if (GST_MESSAGE_TYPE(m) == GST_MESSAGE_ELEMENT &&
               gst_structure_has_name(gst_message_get_structure(m), "stitchsync-dropout")) {
      gboolean dropped = FALSE;
      gst_structure_get_boolean(gst_message_get_structure(m), "dropped", &dropped);
      (dropped ? dropouts : rejoins)++;
    }
    const bool stop = GST_MESSAGE_TYPE(m) == GST_MESSAGE_ERROR || GST_MESSAGE_TYPE(m) == GST_MESSAGE_EOS;
    gst_message_unref(m);
    if (stop) break;
  }
  gst_element_set_state(pipe, GST_STATE_NULL);
  gst_object_unref(src);
  gst_object_unref(blend);
  gst_object_unref(cam1_src);
  gst_object_unref(cam1);
  gst_object_unref(bus);
  gst_object_unref(pipe);

  std::ofstream out(csv);
  out << "frame,seconds,rss_kb\n";
  for (const Sample& s : soak.samples) out << s.frame << "," << s.seconds << "," << s.rss_kb << "\n";
  if (soak.samples.size() < 3) {
    std::fprintf(stderr, "soak: only %zu samples\n", soak.samples.size());
    return 1;
  }
  const Sample& first = soak.samples.front();
  const Sample& warm = soak.samples[soak.samples.size() / 10];
  const Sample& last = soak.samples.back();
  long peak = 0;
  for (const Sample& s : soak.samples) peak = std::max(peak, s.rss_kb);
  const double growth_mb = (last.rss_kb - warm.rss_kb) / 1024.0;
  const long half = soak.dropout_every / 2;
  const long stalls = soak.camera1 > half ? (soak.camera1 - half - 1) / soak.dropout_every + 1 : 0;
  const long expected_dropouts = std::max(0L, stalls - 1);  // the last one may still be under way
  std::printf(
      "soak: %ld panoramas (%dx%d, 3 cameras, CPU) in %.1f s (%.0f/s)\n"
      "soak: RSS %ld kB at frame %ld, %ld kB after warm-up (frame %ld), %ld kB at the end (frame %ld), peak %ld kB; "
      "growth after warm-up %.2f MB\n"
      "soak: camera 1 dropped out %d times and rejoined %d times (%ld stalls of %ld frames scheduled); %d warnings\n"
      "soak: RSS samples in %s\n",
      soak.frames.load(), 2 * shift + width, height, last.seconds, soak.frames / last.seconds, first.rss_kb,
      first.frame, warm.rss_kb, warm.frame, last.rss_kb, last.frame, peak, growth_mb, dropouts, rejoins,
      stalls, soak.dropout_frames, warnings, csv.c_str());
  if (!ok || soak.frames < frames) {
    std::fprintf(stderr, "soak: the stream stopped after %ld frames\n", soak.frames.load());
    return 1;
  }
  if (dropouts < expected_dropouts || rejoins < expected_dropouts) {
    std::fprintf(stderr, "soak: not every dropout was announced and survived\n");
    return 1;
  }
  if (growth_mb > max_growth_mb) {
    std::fprintf(stderr, "soak: RSS grew %.2f MB after warm-up (limit %.1f)\n", growth_mb, max_growth_mb);
    return 1;
  }
  return 0;
}
