// Ghosting benchmark for stitchflowwarp: in every overlap, the photometric error (mean
// absolute difference and SSIM) between the two views as the blender receives them, with the
// homography alone and with flow warping; the temporal flicker of the fused panorama on static
// parts of the overlaps; and the CPU time of the warp stage per frame.
// usage: stitch-bench-flow [--frames N] [--step K] [--quality fast|medium|fine] [--smoothing S]
//          [--margin M] [--json OUT] [--dump DIR] INPUT0 INPUT1 [...]
// INPUTs are synchronised clips, or still images (one instant).
#include <chrono>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "stitch/blend/blender.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/color/color.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/warp/flow_warper.hpp"

using namespace stitch;
using stitch_bench::Series;

namespace {

struct Variant {
  const char* name;
  std::unique_ptr<FlowWarper> warper;
  std::vector<cv::Mat> views;  // roi-sized RGBA
  cv::Mat pano, prev_pano;
  Series flicker;
  double ms = 0;
};

struct PairSeries {
  int a, b;
  cv::Rect box;  // output pixels, both rois
  Series mad[2], ssim[2], detail[2];
};

cv::Mat alpha_mask(const cv::Mat& rgba) {
  std::vector<cv::Mat> ch;
  cv::split(rgba, ch);
  return ch[3] > 0;
}

cv::Mat rgb(const cv::Mat& rgba) {
  cv::Mat out;
  cv::cvtColor(rgba, out, cv::COLOR_RGBA2RGB);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  int frames = 30, step = 1;
  FlowWarpSettings settings;
  std::string json_path, dump_dir;
  bool color = true;  // as in the chain: stitchcolor runs before stitchflowwarp
  std::vector<std::string> inputs;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--step") && i + 1 < argc) step = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else if (!std::strcmp(argv[i], "--dump") && i + 1 < argc) dump_dir = argv[++i];
    else if (!std::strcmp(argv[i], "--smoothing") && i + 1 < argc) settings.temporal_smoothing = std::atof(argv[++i]);
    else if (!std::strcmp(argv[i], "--margin") && i + 1 < argc) settings.margin = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--consistency") && i + 1 < argc) settings.consistency_px = std::atof(argv[++i]);
    else if (!std::strcmp(argv[i], "--no-color")) color = false;
    else if (!std::strcmp(argv[i], "--farneback")) settings.algorithm = FlowAlgorithm::Farneback;
    else if (!std::strcmp(argv[i], "--quality") && i + 1 < argc) {
      const std::string q = argv[++i];
      settings.quality = q == "fast" ? FlowQuality::Fast : q == "fine" ? FlowQuality::Fine : FlowQuality::Medium;
    } else inputs.push_back(argv[i]);
  }
  if (inputs.size() < 2) {
    std::fprintf(stderr, "usage: %s [--frames N] [--step K] [--quality fast|medium|fine] [--smoothing S] "
                 "[--margin M] [--farneback] [--json OUT] [--dump DIR] INPUT0 INPUT1 [...]\n", argv[0]);
    return 2;
  }
  try {
    std::vector<std::vector<cv::Mat>> seq = stitch_bench::read_sets(inputs, frames, step);
    if (seq.empty()) return 2;
    auto views_of = [](const std::vector<cv::Mat>& set) {
      std::vector<ImageView> v;
      for (const auto& m : set) v.push_back(as_view(const_cast<cv::Mat&>(m)));
      return v;
    };
    std::vector<std::vector<ImageView>> pool;
    for (std::size_t t = 0; t < std::min<std::size_t>(5, seq.size()); ++t) pool.push_back(views_of(seq[t]));
    const Rig rig = calibrate_from_images(pool, -1, CalibrationOptions{}).rig;
    const OutputGeometry geo = canvas_geometry(rig);
    const std::vector<ViewPlacement> places = place_views(rig, geo);
    const int n = int(places.size());

    Variant variants[2] = {{"homography", nullptr, {}, {}, {}, {}, 0}, {"flow", nullptr, {}, {}, {}, {}, 0}};
    for (int k = 0; k < 2; ++k) {
      FlowWarpSettings s = settings;
      s.flow = k == 1;
      variants[k].warper = FlowWarper::create(Backend::Cpu);
      variants[k].warper->set_settings(s);
      variants[k].warper->prepare(places, geo.width, geo.height);
      for (const auto& p : places)
        variants[k].views.emplace_back(std::max(p.roi.height, 1), std::max(p.roi.width, 1), CV_8UC4, cv::Scalar::all(0));
      variants[k].pano.create(geo.height, geo.width, CV_8UC4);
    }
    auto blender = Blender::create(Backend::Cpu);
    blender->prepare(places, geo.width, geo.height);

    std::vector<PairSeries> pairs;
    for (int a = 0; a < n; ++a)
      for (int b = a + 1; b < n; ++b) {
        const cv::Rect ra(places[a].roi.x, places[a].roi.y, places[a].roi.width, places[a].roi.height);
        const cv::Rect rb(places[b].roi.x, places[b].roi.y, places[b].roi.width, places[b].roi.height);
        const cv::Rect box = ra & rb;
        if (box.area() > 0) pairs.push_back({a, b, box, {}, {}});
      }

    ColorCorrector corrector(Backend::Cpu);
    std::vector<cv::Mat> prev_coarse;
    for (std::size_t t = 0; t < seq.size(); ++t) {
      const std::vector<ImageView> frames_t = views_of(seq[t]);
      if (color) corrector.process(rig, 1, frames_t);
      for (auto& v : variants) {
        std::vector<ImageView> out;
        for (auto& m : v.views) out.push_back(as_view(m));
        const auto t0 = std::chrono::steady_clock::now();
        v.warper->warp(frames_t, out);
        v.ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
        blender->fuse(out, as_view(v.pano));
      }
      for (auto& p : pairs) {
        for (int k = 0; k < 2; ++k) {
          const auto& pa = places[p.a].roi;
          const auto& pb = places[p.b].roi;
          const cv::Mat va = variants[k].views[p.a](p.box - cv::Point(pa.x, pa.y));
          const cv::Mat vb = variants[k].views[p.b](p.box - cv::Point(pb.x, pb.y));
          // The same mask for both variants: where the homography-warped views are both valid.
          const cv::Mat ca = variants[0].views[p.a](p.box - cv::Point(pa.x, pa.y));
          const cv::Mat cb = variants[0].views[p.b](p.box - cv::Point(pb.x, pb.y));
          cv::Mat mask = alpha_mask(ca) & alpha_mask(cb) & alpha_mask(va) & alpha_mask(vb);
          cv::erode(mask, mask, cv::Mat::ones(5, 5, CV_8U));
          const stitch_bench::Comparison c = stitch_bench::compare(rgb(va), rgb(vb), mask);
          if (c.pixels < 100) continue;
          p.mad[k].v.push_back(c.mad);
          p.ssim[k].v.push_back(c.ssim);
          p.detail[k].v.push_back(c.mad_detail);
        }
      }
      // Flicker on the static parts of the overlaps: where no view's homography warp changed
      // its local mean (Gaussian, sigma 2 px) by more than 1 level since the previous frame,
      // and at least two views are present. Local means, not pixels: a per-pixel threshold
      // would pick the pixels whose noise happened to be small in the homography variant only.
      if (!prev_coarse.empty()) {
        cv::Mat count(geo.height, geo.width, CV_8U, cv::Scalar(0)), moving(geo.height, geo.width, CV_8U, cv::Scalar(0));
        for (int i = 0; i < n; ++i) {
          if (places[i].roi.empty()) continue;
          const cv::Rect r(places[i].roi.x, places[i].roi.y, places[i].roi.width, places[i].roi.height);
          cv::Mat now, before, d;
          variants[0].views[i].convertTo(now, CV_32F);
          prev_coarse[i].convertTo(before, CV_32F);
          cv::GaussianBlur(now, now, cv::Size(0, 0), 2.0);
          cv::GaussianBlur(before, before, cv::Size(0, 0), 2.0);
          cv::absdiff(now, before, d);
          std::vector<cv::Mat> ch;
          cv::split(d, ch);
          cv::Mat changed = cv::max(cv::max(ch[0], ch[1]), ch[2]) > 1.0;
          cv::Mat valid = alpha_mask(variants[0].views[i]);
          count(r) += valid / 255;
          moving(r).setTo(255, changed & valid);
        }
        const cv::Mat statics = (count >= 2) & (moving == 0);
        if (cv::countNonZero(statics) > 100)
          for (auto& v : variants) {
            cv::Mat d;
            cv::absdiff(v.pano, v.prev_pano, d);
            const cv::Scalar f = cv::mean(d, statics);
            v.flicker.v.push_back((f[0] + f[1] + f[2]) / 3.0);
          }
      }
      prev_coarse.clear();
      for (auto& m : variants[0].views) prev_coarse.push_back(m.clone());
      for (auto& v : variants) v.prev_pano = v.pano.clone();

      if (!dump_dir.empty() && t + 1 == seq.size()) {
        // Side by side at the pair whose error dropped most: homography | flow.
        int best = -1;
        double gain = -1e9;
        for (std::size_t k = 0; k < pairs.size(); ++k)
          if (!pairs[k].mad[0].v.empty() && pairs[k].mad[0].v.back() - pairs[k].mad[1].v.back() > gain) {
            gain = pairs[k].mad[0].v.back() - pairs[k].mad[1].v.back();
            best = int(k);
          }
        if (best >= 0) {
          const cv::Rect box = pairs[best].box;
          cv::Mat both;
          cv::hconcat(rgb(variants[0].pano(box)), rgb(variants[1].pano(box)), both);
          cv::cvtColor(both, both, cv::COLOR_RGB2BGR);
          cv::imwrite(dump_dir + "/flow_seam.png", both);
          cv::Mat full;
          cv::vconcat(rgb(variants[0].pano), rgb(variants[1].pano), full);
          cv::cvtColor(full, full, cv::COLOR_RGB2BGR);
          cv::imwrite(dump_dir + "/flow_panorama.png", full);
        }
      }
    }

    std::printf("%zu instants, canvas %dx%d, %d views\n", seq.size(), geo.width, geo.height, n);
    std::printf("%-6s %9s %9s %8s %9s %9s %8s %8s %8s\n", "pair", "MAD homog", "MAD flow", "cut %", "detail h",
                "detail f", "cut %", "SSIM h", "SSIM f");
    std::string json = "{\"inputs\":" + std::to_string(inputs.size()) + ",\"instants\":" + std::to_string(seq.size()) +
                       ",\"canvas\":[" + std::to_string(geo.width) + "," + std::to_string(geo.height) + "],\"pairs\":[";
    Series cut_all, detail_cut_all;
    bool first = true;
    for (const auto& p : pairs) {
      if (p.mad[0].v.empty()) continue;
      const double cut = p.mad[0].mean() > 0 ? 100.0 * (1 - p.mad[1].mean() / p.mad[0].mean()) : 0;
      cut_all.v.push_back(cut);
      const double dcut = p.detail[0].mean() > 0 ? 100.0 * (1 - p.detail[1].mean() / p.detail[0].mean()) : 0;
      detail_cut_all.v.push_back(dcut);
      std::printf("%d-%d    %9.3f %9.3f %8.1f %9.3f %9.3f %8.1f %8.4f %8.4f\n", p.a, p.b, p.mad[0].mean(), p.mad[1].mean(),
                  cut, p.detail[0].mean(), p.detail[1].mean(), dcut, p.ssim[0].mean(), p.ssim[1].mean());
      char buf[512];
      std::snprintf(buf, sizeof buf, "%s{\"pair\":\"%d-%d\",\"mad_homography\":%.4f,\"mad_flow\":%.4f,\"cut_percent\":%.2f,"
                    "\"detail_mad_homography\":%.4f,\"detail_mad_flow\":%.4f,\"detail_cut_percent\":%.2f,"
                    "\"ssim_homography\":%.5f,\"ssim_flow\":%.5f}", first ? "" : ",", p.a, p.b, p.mad[0].mean(),
                    p.mad[1].mean(), cut, p.detail[0].mean(), p.detail[1].mean(), dcut, p.ssim[0].mean(), p.ssim[1].mean());
      json += buf;
      first = false;
    }
    const double fh = variants[0].flicker.mean(), ff = variants[1].flicker.mean();
    for (const auto& st : variants[1].warper->stats())
      std::printf("last frame, pair %d-%d: mean flow %.2f px, %.0f%% forward-backward consistent\n", st.view_a,
                  st.view_b, st.mean_magnitude, 100 * st.confident_fraction);
    std::printf("flicker on static overlap: homography %.4f, flow %.4f (%+.1f%%)\n", fh, ff,
                fh > 0 ? 100.0 * (ff / fh - 1) : 0.0);
    std::printf("warp stage ms/frame: homography %.2f, flow %.2f\n", variants[0].ms / seq.size(), variants[1].ms / seq.size());
    char tail[256];
    std::snprintf(tail, sizeof tail, "],\"mean_cut_percent\":%.2f,\"mean_detail_cut_percent\":%.2f,\"flicker_homography\":%.5f,\"flicker_flow\":%.5f,"
                  "\"ms_homography\":%.3f,\"ms_flow\":%.3f}\n", cut_all.mean(), detail_cut_all.mean(), fh, ff, variants[0].ms / seq.size(),
                  variants[1].ms / seq.size());
    json += tail;
    if (!json_path.empty()) std::ofstream(json_path) << json;
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
}
