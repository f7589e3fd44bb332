// The paper's Tables 2-3 on real clips: PSNR and SSIM between the corrected overlap of each
// view and the overlap of its reference-side neighbour, for none / 2dm / 3dm / gain, per frame,
// with mean and sigma; plus the panorama's temporal flicker on static regions and the color
// stage's time per frame.
// usage: stitch-bench-color [--frames N] [--step K] [--calib CALIB.json] [--json OUT] CLIP0 CLIP1 [...]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <string>
#include <vector>

#include "stitch/blend/compositor.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/color/color.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/overlap.hpp"
#include "bench_common.hpp"

using namespace stitch;
using stitch_bench::Series;

namespace {

void overlap_images(const Rig& rig, int a, int b, const cv::Mat& va, const cv::Mat& vb, cv::Mat& oa, cv::Mat& ob,
                    cv::Mat& mask) {
  const std::vector<cv::Point2f> inter = canvas_overlap(rig.cameras[a], rig.cameras[b]);
  if (inter.empty()) {
    mask = cv::Mat();
    return;
  }
  const cv::Rect box = cv::boundingRect(inter) & cv::Rect(0, 0, rig.canvas_width, rig.canvas_height);
  auto warp = [&](const cv::Mat& v, int cam, cv::Mat& out, cv::Mat& valid) {
    Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
    T(0, 2) = -box.x;
    T(1, 2) = -box.y;
    const Eigen::Matrix3d H = T * *rig.cameras[cam].homography;
    cv::Mat Hm(3, 3, CV_64F);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) Hm.at<double>(r, c) = H(r, c);
    cv::Mat rgb;
    cv::cvtColor(v, rgb, cv::COLOR_RGBA2RGB);
    cv::warpPerspective(rgb, out, Hm, box.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
    cv::Mat ones(v.size(), CV_8U, cv::Scalar(255));
    cv::warpPerspective(ones, valid, Hm, box.size(), cv::INTER_NEAREST, cv::BORDER_CONSTANT);
    cv::erode(valid, valid, cv::Mat::ones(5, 5, CV_8U));
  };
  cv::Mat ma, mb;
  warp(va, a, oa, ma);
  warp(vb, b, ob, mb);
  mask = ma & mb;
}

}  // namespace

int main(int argc, char** argv) {
  int frames = 30, step = 1;
  ColorOptions base;
  std::string calib_path, json_path;
  std::vector<std::string> clips;
  bool element_defaults = false;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--frames") && i + 1 < argc) frames = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--step") && i + 1 < argc) step = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--calib") && i + 1 < argc) calib_path = argv[++i];
    else if (!std::strcmp(argv[i], "--json") && i + 1 < argc) json_path = argv[++i];
    else if (!std::strcmp(argv[i], "--max-step") && i + 1 < argc) base.max_step = std::atof(argv[++i]);
    else if (!std::strcmp(argv[i], "--window") && i + 1 < argc) base.window = std::atoi(argv[++i]);
    else if (!std::strcmp(argv[i], "--deadband") && i + 1 < argc) base.deadband = std::atof(argv[++i]);
    else if (!std::strcmp(argv[i], "--follow") && i + 1 < argc) base.follow = std::atof(argv[++i]);
    else if (!std::strcmp(argv[i], "--pixels")) base.pairing = ColorPairing::Pixels;
    else if (!std::strcmp(argv[i], "--balance")) base.balance = true;
    // none vs stitchcolor's defaults before issue 16 (3dm, smoothing 0.8, no mask, no hold)
    // vs now (the same with static-mask and stabilize).
    else if (!std::strcmp(argv[i], "--element-defaults")) element_defaults = true;
    else if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) cv::setNumThreads(std::atoi(argv[++i]));
    else clips.push_back(argv[i]);
  }
  if (clips.size() < 2) {
    std::fprintf(stderr, "usage: %s [--frames N] [--step K] [--calib CALIB.json] [--json OUT] [--max-step X] [--window N] [--pixels] [--balance] CLIP0 CLIP1 [...]\n", argv[0]);
    return 2;
  }
  // Read the frames once.
  std::vector<std::vector<cv::Mat>> seq = stitch_bench::read_sets(clips, frames, step);
  if (seq.size() < 3) {
    std::fprintf(stderr, "too few frames\n");
    return 2;
  }
  auto views_of = [](std::vector<cv::Mat>& set) {
    std::vector<ImageView> v;
    for (auto& m : set) v.push_back(as_view(m));
    return v;
  };
  Rig rig;
  if (!calib_path.empty()) rig = rig_load(calib_path);
  else {
    std::vector<std::vector<ImageView>> pool;
    for (std::size_t t = 0; t < std::min<std::size_t>(5, seq.size()); ++t) pool.push_back(views_of(seq[t]));
    rig = calibrate_from_images(pool, -1, CalibrationOptions{}).rig;
  }
  // Pairs of the reference chain: (view, parent), as ColorCorrector chains them.
  ColorCorrector probe(Backend::Cpu);
  std::vector<std::pair<std::string, ColorOptions>> variants;
  if (element_defaults) {
    ColorOptions now = base;
    now.follow = 0.2;  // the element's smoothing=0.8
    ColorOptions before = now;
    before.static_mask = false;
    before.stabilize = false;
    before.highlight_knee = 255;
    ColorOptions none = now;
    none.method = ColorMethod::None;
    variants = {{"none", none}, {"before", before}, {"now", now}};
  } else {
    const char* names[] = {"none", "2dm", "3dm", "gain"};
    const ColorMethod methods[] = {ColorMethod::None, ColorMethod::Matrix2D, ColorMethod::Matrix3D, ColorMethod::Gain};
    for (int m = 0; m < 4; ++m) {
      ColorOptions o = base;
      o.method = methods[m];
      variants.emplace_back(names[m], o);
    }
  }
  std::string json = "{\"clips\":" + std::to_string(clips.size()) + ",\"frames\":" + std::to_string(seq.size()) + ",\"methods\":[";
  std::printf("%-6s %-10s %8s %8s %8s %8s %10s %10s\n", "method", "pair", "PSNR", "sigma", "SSIM", "sigma", "flicker", "ms/frame");
  for (int m = 0; m < int(variants.size()); ++m) {
    const char* name = variants[std::size_t(m)].first.c_str();
    ColorCorrector corrector(Backend::Cpu);
    corrector.set_options(variants[std::size_t(m)].second);
    Compositor comp(Backend::Cpu);
    comp.prepare(rig, CompositorSettings{});
    std::vector<Series> psnr, ssim;
    std::vector<std::pair<int, int>> pair_ids;
    Series flicker;
    double ms = 0;
    cv::Mat prev_pano, prev_raw;
    for (std::size_t t = 0; t < seq.size(); ++t) {
      std::vector<cv::Mat> set;
      for (auto& f : seq[t]) set.push_back(f.clone());
      std::vector<ImageView> views = views_of(set);
      // Raw panorama (for the static-region mask) before correction.
      cv::Mat raw(comp.geometry().height, comp.geometry().width, CV_8UC4);
      comp.compose(views, as_view(raw));
      const auto t0 = std::chrono::steady_clock::now();
      corrector.process(rig, 1, views);
      ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      cv::Mat pano(raw.size(), CV_8UC4);
      comp.compose(views, as_view(pano));
      // Every overlapping pair (a, b) with a < b.
      int k = 0;
      for (int a = 0; a < int(set.size()); ++a)
        for (int b = a + 1; b < int(set.size()); ++b) {
          cv::Mat oa, ob, mask;
          overlap_images(rig, a, b, set[a], set[b], oa, ob, mask);
          if (mask.empty() || cv::countNonZero(mask) < 500) continue;
          if (t == 0) {
            psnr.emplace_back();
            ssim.emplace_back();
            pair_ids.emplace_back(a, b);
          }
          const stitch_bench::Comparison s = stitch_bench::compare(oa, ob, mask);
          if (t == 0 && m == 0 && std::getenv("STITCH_DUMP")) {
            cv::Mat both;
            cv::hconcat(oa, ob, both);
            cv::cvtColor(both, both, cv::COLOR_RGB2BGR);
            cv::imwrite(std::string(std::getenv("STITCH_DUMP")) + "/overlap_" + std::to_string(a) + std::to_string(b) + ".png", both);
          }
          psnr[k].v.push_back(s.psnr);
          ssim[k].v.push_back(s.ssim);
          ++k;
        }
      if (!prev_pano.empty()) {
        // Static regions: the uncorrected input did not change there (< 3 levels).
        // Static: no channel of the uncorrected panorama moved by more than 2 levels.
        cv::Mat draw, dpano;
        cv::absdiff(raw, prev_raw, draw);
        std::vector<cv::Mat> ch;
        cv::split(draw, ch);
        cv::Mat statics = cv::max(cv::max(ch[0], ch[1]), ch[2]) <= 2;
        cv::Mat covered;
        cv::cvtColor(raw, covered, cv::COLOR_RGBA2GRAY);
        statics &= covered > 0;
        cv::absdiff(pano, prev_pano, dpano);
        const cv::Scalar f = cv::mean(dpano, statics);
        flicker.v.push_back((f[0] + f[1] + f[2]) / 3.0);
      }
      prev_pano = pano;
      prev_raw = raw;
    }
    json += std::string(m ? "," : "") + "{\"method\":\"" + name + "\",\"ms_per_frame\":" +
            std::to_string(ms / seq.size()) + ",\"flicker\":" + std::to_string(flicker.mean()) + ",\"pairs\":[";
    for (std::size_t k = 0; k < psnr.size(); ++k) {
      char pair[32];
      std::snprintf(pair, sizeof pair, "%d-%d", pair_ids[k].first, pair_ids[k].second);
      std::printf("%-6s %-10s %8.3f %8.3f %8.4f %8.4f %10.4f %10.2f\n", name, pair, psnr[k].mean(), psnr[k].sigma(),
                  ssim[k].mean(), ssim[k].sigma(), flicker.mean(), ms / seq.size());
      json += std::string(k ? "," : "") + "{\"pair\":\"" + pair + "\",\"psnr\":[";
      for (std::size_t t = 0; t < psnr[k].v.size(); ++t)
        json += (t ? "," : "") + std::to_string(psnr[k].v[t]);
      json += "],\"ssim\":[";
      for (std::size_t t = 0; t < ssim[k].v.size(); ++t)
        json += (t ? "," : "") + std::to_string(ssim[k].v[t]);
      json += "]}";
    }
    json += "]}";
  }
  json += "]}\n";
  if (!json_path.empty()) std::ofstream(json_path) << json;
  return 0;
}
