// Time per panorama of the per-frame path (warp + blend) on the CPU, for N cameras of WxH.
// usage: stitch-bench-compose [--json out.json] [--frames 50]
// Prints a table; content is a real photo (data/photos/boat1_1600.jpg) seen by a rotating rig.
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "stitch/blend/compositor.hpp"
#include "stitch/color/color.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/warp/flow_warper.hpp"
#include "bench_common.hpp"

using namespace stitch;
using stitch_bench::Case;
using stitch_bench::ring;

namespace {

}  // namespace

int main(int argc, char** argv) {
  std::string json_path, photo_path = "data/photos/boat1_1600.jpg";
  int frames = 50;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--photo") && i + 1 < argc) photo_path = argv[++i];
    else {
      std::fprintf(stderr, "usage: %s [--json FILE] [--frames N] [--photo JPG]\n", argv[0]);
      return 2;
    }
  }
  cv::Mat photo = cv::imread(photo_path);
  if (photo.empty()) {
    std::fprintf(stderr, "cannot read %s (run from the repository root or pass --photo)\n", photo_path.c_str());
    return 2;
  }
  cv::cvtColor(photo, photo, cv::COLOR_BGR2RGBA);
  const std::vector<Case> cases = {{3, 640, 480}, {2, 1920, 1080}, {3, 1920, 1080}, {6, 1920, 1080}, {3, 3840, 2160}};
  std::printf("%-16s %-12s %10s %10s %14s %12s %12s %12s %12s %8s\n", "cameras", "panorama", "ms/frame", "fps",
              "memcpy ms", "color 3dm ms", "color gain", "prewarp ms", "flowwarp ms", "threads");
  std::string json = "[";
  for (const Case& c : cases) {
    Rig rig = ring(c);
    std::vector<cv::Mat> views = stitch_bench::ring_views(photo, c);
    std::vector<ImageView> vv;
    for (auto& v : views) vv.push_back(as_view(v));
    Compositor comp(Backend::Cpu);
    CompositorSettings s;
    s.crop = CropMode::Auto;
    s.output_width = int(0.85 * c.cameras * c.width) / 2 * 2;  // the paper's 3x1080p -> 4880x1080
    s.output_height = c.height;
    comp.prepare(rig, s);
    cv::Mat out(comp.geometry().height, comp.geometry().width, CV_8UC4);
    comp.compose(vv, as_view(out));  // warm-up
    const auto t0 = std::chrono::steady_clock::now();
    for (int k = 0; k < frames; ++k) comp.compose(vv, as_view(out));
    const double ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count() / frames;
    // Baseline in the same run: copying every input byte once and writing the output once,
    // the memory traffic any stitcher needs at least.
    std::vector<cv::Mat> copies(views.size());
    cv::Mat out_copy(out.size(), out.type());
    const auto m0 = std::chrono::steady_clock::now();
    for (int k = 0; k < frames; ++k) {
      for (std::size_t i = 0; i < views.size(); ++i) views[i].copyTo(copies[i]);
      out.copyTo(out_copy);
    }
    const double copy_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - m0).count() / frames;
    // The color stage (estimation on the overlaps + applying the correction to every view),
    // on views whose exposures differ.
    auto time_color = [&](ColorMethod method) {
      ColorCorrector cc(Backend::Cpu);
      ColorOptions o;
      o.method = method;
      cc.set_options(o);
      std::vector<cv::Mat> work(views.size());
      std::vector<ImageView> wv(views.size());
      double total = 0;
      for (int k = 0; k < frames; ++k) {
        for (std::size_t i = 0; i < views.size(); ++i) {
          views[i].convertTo(work[i], -1, i % 2 ? 0.85 : 1.0);
          wv[i] = as_view(work[i]);
        }
        const auto c0 = std::chrono::steady_clock::now();
        cc.process(rig, 1, wv);
        total += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - c0).count();
      }
      return total / frames;
    };
    const double color_ms = time_color(ColorMethod::Matrix3D), gain_ms = time_color(ColorMethod::Gain);
    // The stitchflowwarp stage on the canvas: homography pre-warp alone, and with the flow
    // (both directions in every overlap, default settings). Successive frames differ (noise),
    // as a camera's do.
    auto time_flowwarp = [&](bool flow) {
      const OutputGeometry canvas = canvas_geometry(rig);
      const std::vector<ViewPlacement> places = place_views(rig, canvas);
      auto fw = FlowWarper::create(Backend::Cpu);
      FlowWarpSettings fs;
      fs.flow = flow;
      fw->set_settings(fs);
      fw->prepare(places, canvas.width, canvas.height);
      std::vector<cv::Mat> dst;
      std::vector<ImageView> dv;
      for (const auto& p : places) dst.emplace_back(std::max(1, p.roi.height), std::max(1, p.roi.width), CV_8UC4);
      for (auto& d : dst) dv.push_back(as_view(d));
      std::vector<cv::Mat> noisy[2];
      for (int k = 0; k < 2; ++k)
        for (const auto& v : views) {
          cv::Mat n(v.size(), v.type());
          cv::randn(n, cv::Scalar::all(0), cv::Scalar::all(2));
          noisy[k].push_back(v + n);
        }
      const int runs = std::max(3, frames / 5);
      double total = 0;
      for (int k = 0; k <= runs; ++k) {
        std::vector<ImageView> in;
        for (auto& v : noisy[k % 2]) in.push_back(as_view(v));
        const auto f0 = std::chrono::steady_clock::now();
        fw->warp(in, dv);
        if (k > 0) total += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - f0).count();
      }
      return total / runs;
    };
    const double prewarp_ms = time_flowwarp(false), flowwarp_ms = time_flowwarp(true);
    char name[64], pano[64];
    std::snprintf(name, sizeof name, "%dx%dx%d", c.cameras, c.width, c.height);
    std::snprintf(pano, sizeof pano, "%dx%d", out.cols, out.rows);
    std::printf("%-16s %-12s %10.2f %10.1f %14.2f %12.2f %12.2f %12.2f %12.2f %8d\n", name, pano, ms, 1000.0 / ms,
                copy_ms, color_ms, gain_ms, prewarp_ms, flowwarp_ms, cv::getNumThreads());
    json += std::string(json.size() > 1 ? "," : "") + "{\"case\":\"" + name + "\",\"panorama\":\"" + pano +
            "\",\"backend\":\"cpu\",\"ms_per_frame\":" + std::to_string(ms) +
            ",\"memcpy_ms\":" + std::to_string(copy_ms) +
            ",\"color_3dm_ms\":" + std::to_string(color_ms) + ",\"color_gain_ms\":" + std::to_string(gain_ms) +
            ",\"prewarp_ms\":" + std::to_string(prewarp_ms) + ",\"flowwarp_ms\":" + std::to_string(flowwarp_ms) + "}";
  }
  json += "]\n";
  if (!json_path.empty()) std::ofstream(json_path) << json;
  return 0;
}
