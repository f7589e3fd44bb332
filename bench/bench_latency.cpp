// Glass-to-glass latency through the stitch chain with live 30 fps cameras (issue 17 item 5):
// per panorama, from the capture time of the newest (and of the oldest) camera frame it holds to
// the time it reaches the sink, in the pipeline clock (tests/common/live_latency.hpp says why the
// panorama's own running time is not a capture time). Reports stitchsync's configured latency
// (its `latency` property) and its LATENCY query, and the chain's added latency = measured -
// configured, in frames.
// usage: stitch-bench-latency [--cameras N] [--width W] [--height H] [--frames N] [--skip N]
//                             [--chains cpu,bin,cuda,bin-cuda] [--sync-props PROPS] [--json FILE]
//                             [--dump PREFIX]
// cpu: stitchsync ! stitchcalib ! stitchcolor ! stitchflowwarp ! stitchblend, backend=cpu;
// bin: stitchbin with its defaults; cuda / bin-cuda: the same with cudaupload after each camera.
#include <gst/gst.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "live_latency.hpp"
#include "stitch/rig/rig.hpp"

namespace {

std::string description(const std::string& chain, const std::string& rig, int cameras, int w, int h, int frames,
                        const std::string& sync_props) {
  const bool cuda = chain == "cuda" || chain == "bin-cuda";
  const bool bin = chain == "bin" || chain == "bin-cuda";
  const std::string backend = cuda ? " backend=cuda" : chain == "cpu" ? " backend=cpu" : "";
  std::string d = bin ? "stitchbin name=s rig-file=\"" + rig + "\" refine=none " + sync_props + " ! fakesink name=sink sync=false"
                      : "stitchsync name=s " + sync_props + " ! stitchcalib rig-file=\"" + rig + "\" refine=none ! stitchcolor" +
                            backend + " ! stitchflowwarp" + backend + " ! stitchblend" + backend +
                            " ! fakesink name=sink sync=false";
  for (int i = 0; i < cameras; ++i)
    d += " videotestsrc is-live=true pattern=ball num-buffers=" + std::to_string(frames) +
         " ! video/x-raw,format=RGBA,width=" + std::to_string(w) + ",height=" + std::to_string(h) + ",framerate=30/1" +
         (cuda ? " ! cudaupload" : "") + " ! s.sink_" + std::to_string(i);
  return d;
}

}  // namespace

int main(int argc, char** argv) {
  gst_init(&argc, &argv);
  int cameras = 3, width = 640, height = 480, frames = 300, skip = 30;
  std::string chains = "cpu,bin", json_path, dump, sync_props;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--cameras") && i + 1 < argc) cameras = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--width") && i + 1 < argc) width = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--height") && i + 1 < argc) height = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--skip") && i + 1 < argc) skip = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--chains") && i + 1 < argc) chains = argv[++i];
    else if (!std::strcmp(argv[i], "--sync-props") && i + 1 < argc) sync_props = argv[++i];
    else if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else if (!std::strcmp(argv[i], "--dump") && i + 1 < argc) dump = argv[++i];
    else {
      std::fprintf(stderr,
                   "usage: %s [--cameras N] [--width W] [--height H] [--frames N] [--skip N] "
                   "[--chains cpu,bin,cuda,bin-cuda] [--sync-props PROPS] [--json FILE] [--dump PREFIX]\n",
                   argv[0]);
      return 2;
    }
  }
  const std::string rig = "/tmp/stitch-bench-latency-rig.json";
  stitch::rig_save(stitch_bench::ring({cameras, width, height}), rig);
  std::string json = "{\"cameras\":" + std::to_string(cameras) + ",\"width\":" + std::to_string(width) +
                     ",\"height\":" + std::to_string(height) + ",\"runs\":[";
  for (const char* s = chains.c_str(); *s;) {
    const char* comma = std::strchr(s, ',');
    const std::string chain = comma ? std::string(s, comma) : std::string(s);
    s = comma ? comma + 1 : s + std::strlen(s);
    const livelat::LiveRun r =
        livelat::run_live(description(chain, rig, cameras, width, height, frames, sync_props), size_t(skip), frames / 30 + 60);
    const livelat::Summary& m = r.summary;
    std::printf("%-8s %dx%dx%d live 30 fps, %d panoramas (%d after the first %d, %d unmatched)%s%s\n"
                "  newest capture -> sink: median %.1f ms, p99 %.1f ms, min %.1f, max %.1f\n"
                "  oldest capture -> sink: median %.1f ms, p99 %.1f ms\n"
                "  shares (median): stitchsync %.1f ms, stages after it %.1f ms\n"
                "  old probe (sink - panorama running time): median %.1f ms, min %.1f ms\n"
                "  stitchsync latency property %.1f ms; LATENCY query live=%d min %.1f ms max %.1f ms; frame %.1f ms\n"
                "  added latency (newest -> sink - configured): median %.2f frames, p99 %.2f frames\n",
                chain.c_str(), cameras, width, height, r.panoramas, m.samples, skip, m.unmatched,
                r.error.empty() ? "" : " ERROR: ", r.error.c_str(), m.newest_median_ms, m.newest_p99_ms, m.newest_min_ms,
                m.newest_max_ms, m.oldest_median_ms, m.oldest_p99_ms, m.sync_median_ms, m.stages_median_ms,
                m.grid_median_ms, m.grid_min_ms, m.configured_ms, int(m.query_live), m.query_min_ms, m.query_max_ms,
                m.frame_ms, m.added_median_frames, m.added_p99_frames);
    std::fflush(stdout);
    if (!dump.empty()) {
      std::ofstream f(dump + "_" + chain + ".csv");
      f << "pts_ms,newest_ms,oldest_ms,grid_ms,sync_ms,stages_ms,views_with_capture\n";
      for (const livelat::Sample& x : r.samples)
        f << double(x.pts) / 1e6 << "," << x.newest_ms << "," << x.oldest_ms << "," << x.grid_ms << "," << x.sync_ms << ","
          << x.stages_ms << "," << x.views_with_capture << "\n";
    }
    char buf[1024];
    std::snprintf(buf, sizeof buf,
                  "{\"chain\":\"%s\",\"panoramas\":%d,\"samples\":%d,\"unmatched\":%d,\"newest_median_ms\":%.2f,"
                  "\"newest_p99_ms\":%.2f,\"newest_min_ms\":%.2f,\"oldest_median_ms\":%.2f,\"oldest_p99_ms\":%.2f,"
                  "\"sync_median_ms\":%.2f,\"stages_median_ms\":%.2f,\"grid_median_ms\":%.2f,\"grid_min_ms\":%.2f,"
                  "\"configured_ms\":%.2f,\"query_min_ms\":%.2f,\"frame_ms\":%.2f,\"added_median_frames\":%.3f,"
                  "\"added_p99_frames\":%.3f,\"error\":\"%s\"}",
                  chain.c_str(), r.panoramas, m.samples, m.unmatched, m.newest_median_ms, m.newest_p99_ms, m.newest_min_ms,
                  m.oldest_median_ms, m.oldest_p99_ms, m.sync_median_ms, m.stages_median_ms, m.grid_median_ms, m.grid_min_ms,
                  m.configured_ms, m.query_min_ms, m.frame_ms, m.added_median_frames, m.added_p99_frames, r.error.c_str());
    json += std::string(json.back() == '[' ? "" : ",") + buf;
  }
  json += "]}";
  if (!json_path.empty()) std::ofstream(json_path) << json << "\n";
  return 0;
}
