// The CUDA multiband blender (with and without seam finding) against the CPU one. Needs a CUDA
// device: without one (or in a build without the toolkit) every test skips and says why.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "stitch/blend/compositor.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/warp/warper.hpp"
#include "cuda_test.hpp"
#include "image_compare.hpp"
#include "ppm.hpp"
#include "synthetic_rig.hpp"
#include "stitch/blend/multiband.hpp"
#include "stitch/blend/seam.hpp"
#ifdef STITCH_HAVE_CUDA
#include "stitch/blend/seam_cuda.hpp"
#endif

using namespace stitch;

namespace {

#define REQUIRE_CUDA() REQUIRE_CUDA_FOR("the CUDA multiband blender")

// Three cameras of a real photo on a rotating rig, each with its own exposure.
testdata::RotatingRig rig_scene() {
  const double gains[3] = {0.8, 1.0, 1.2};
  return testdata::rotating_rig(testdata::test_photo(), gains);
}

// Same views in: the backends differ only by float rounding (max_diff levels at most). Camera
// frames in: each backend warps them too (bilinear, differently rounded), so only the PSNR bound
// (max_diff < 0) applies.
void expect_close(const cv::Mat& got, const cv::Mat& expected, const char* what, int max_allowed = -1) {
  cv::Mat diff;
  cv::absdiff(got, expected, diff);
  double max_diff = 0;
  cv::minMaxLoc(diff.reshape(1), nullptr, &max_diff);
  cv::Mat gray;
  cv::cvtColor(diff, gray, cv::COLOR_RGBA2GRAY);
  const double off = double(cv::countNonZero(gray > 1)) / gray.total();
  const double psnr = testdata::psnr_rgb(got, expected);
  std::printf("MULTIBAND %s: CUDA vs CPU PSNR %.2f dB, max |diff| %.0f, %.4f%% of pixels off by > 1\n", what, psnr,
              max_diff, 100 * off);
  if (max_allowed >= 0) {
    EXPECT_GE(psnr, 55.0) << what;
    EXPECT_LE(max_diff, max_allowed) << what;
    EXPECT_LT(off, 0.001) << what;
  } else {
    EXPECT_GE(psnr, 42.0) << what;
  }
}

#ifdef STITCH_HAVE_CUDA
// frames warped (CPU) into their rectangles: in host memory and copied to the device.
struct WarpedViews {
  std::vector<cv::Mat> rois;
  std::vector<ImageView> host, device;
  std::vector<std::unique_ptr<testdata::DeviceMat>> device_mats;
  WarpedViews(const std::vector<ViewPlacement>& views, const std::vector<cv::Mat>& frames) {
    auto warper = Warper::create(Backend::Cpu);
    warper->prepare(views);
    for (std::size_t i = 0; i < views.size(); ++i) {
      rois.emplace_back(views[i].roi.height, views[i].roi.width, CV_8UC4, cv::Scalar::all(0));
      cv::Mat frame = frames[i];
      warper->warp(int(i), as_view(frame), as_view(rois.back()));
      host.push_back(as_view(rois.back()));
      device_mats.push_back(std::make_unique<testdata::DeviceMat>(rois.back()));
      device.push_back(device_mats.back()->view());
    }
  }
};
#endif

}  // namespace

TEST(CudaMultiband, BlenderMatchesCpuOnTheSameViewsAndLabels) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  testdata::RotatingRig s = rig_scene();
  const OutputGeometry g = canvas_geometry(s.rig);
  const std::vector<ViewPlacement> views = place_views(s.rig, g);
  WarpedViews w(views, s.frames);
  const std::vector<ImageView>&host = w.host, &dev_views = w.device;
  SeamFinder seams;
  seams.prepare(views, g.width, g.height);
  const std::vector<uint8_t> cut = seams.find(host);
  for (int bands : {3, 5}) {
    auto cpu = MultibandBlender::create(Backend::Cpu, bands), gpu = MultibandBlender::create(Backend::Cuda, bands);
    ASSERT_EQ(gpu->backend(), Backend::Cuda);
    cpu->prepare(views, g.width, g.height);
    gpu->prepare(views, g.width, g.height);
    for (int with_seams = 0; with_seams < 2; ++with_seams) {
      cpu->set_labels(with_seams ? cut.data() : nullptr);
      gpu->set_labels(with_seams ? cut.data() : nullptr);
      cv::Mat expected(g.height, g.width, CV_8UC4);
      testdata::DeviceMat out(cv::Mat(g.height, g.width, CV_8UC4, cv::Scalar::all(77)));
      cpu->fuse(host, as_view(expected));
      gpu->fuse(dev_views, out.view());
      const std::string what = std::to_string(bands) + " bands" + (with_seams ? ", dp seams" : ", middle seams");
      expect_close(out.download(), expected, what.c_str(), 2);
    }
  }
#endif
}

TEST(CudaSeams, SameCutsAsTheCpuFrameAfterFrame) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  testdata::RotatingRig s = rig_scene();
  const OutputGeometry g = canvas_geometry(s.rig);
  const std::vector<ViewPlacement> views = place_views(s.rig, g);
  // With the default costs and with the clearance term on (its integer window sums).
  SeamSettings clear;
  clear.clearance_weight = 4.f;
  SeamSettings no_mix;  // multiband's: no consensus-blend mix map
  no_mix.mix_radius = 0;
  SeamSettings held, free;  // the view-switch cost on (strong) and off, whatever the default
  held.label_hold = 16.f;
  free.label_hold = 0.f;
  // (settings, near objects moving across the overlaps)
  for (const auto& [settings, objects] : std::vector<std::pair<SeamSettings, bool>>{
           {SeamSettings{}, false}, {clear, false}, {no_mix, false}, {held, true}, {free, true}}) {
  SeamFinder cpu(settings);
  SeamFinderCuda gpu(settings);
  cpu.prepare(views, g.width, g.height);
  gpu.prepare(views, g.width, g.height);
  ASSERT_GE(gpu.pairs().size(), 2u);  // neighbours (and the outer views, where they meet)
  cv::RNG rng(3);
  for (int frame = 0; frame < 5; ++frame) {  // frame 4: view 1 black (no signal; it loses its overlaps)
    // Each frame: the views shifted a little (motion) plus noise, the same on both backends.
    std::vector<cv::Mat> frames;
    for (std::size_t i = 0; i < views.size(); ++i) {
      cv::Mat f, noise(s.frames[i].size(), CV_8UC4);
      const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, 2.0 * frame, 0, 1, 0);
      cv::warpAffine(s.frames[i], f, shift, s.frames[i].size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
      rng.fill(noise, cv::RNG::UNIFORM, 0, 8);
      if (objects) {
        // near objects only one view shows, moving across the views' right sides: disagreement
        // whose view the hold keeps from frame to frame
        const int x = f.cols - 170 + 12 * frame;
        cv::rectangle(f, cv::Rect(x, f.rows / 3, 90, 120), i % 2 ? cv::Scalar(255, 0, 255, 255) : cv::Scalar(0, 200, 0, 255),
                      cv::FILLED);
      }
      if (frame == 4 && i == 1) f.setTo(cv::Scalar(0, 0, 0, 255));
      frames.push_back(f + noise);
    }
    WarpedViews w(views, frames);
    const std::vector<ImageView>&host = w.host, &dev_views = w.device;
    const std::vector<uint8_t>& want = cpu.find(host);
    const uint8_t* got_dev = gpu.find(dev_views);
    std::vector<uint8_t> got(want.size());
    ASSERT_EQ(cudaMemcpy(got.data(), got_dev, got.size(), cudaMemcpyDeviceToHost), cudaSuccess);
    std::size_t same_labels = 0;
    for (std::size_t k = 0; k < got.size(); ++k) same_labels += got[k] == want[k];
    const std::vector<std::vector<int>> paths = gpu.paths();
    std::size_t rows = 0, same_rows = 0;
    for (std::size_t p = 0; p < paths.size(); ++p) {
      ASSERT_EQ(paths[p].size(), cpu.pairs()[p].path.size());
      for (std::size_t r = 0; r < paths[p].size(); ++r) rows++, same_rows += paths[p][r] == cpu.pairs()[p].path[r];
    }
    std::printf("MULTIBAND seams frame %d: CUDA vs CPU: %.4f%% of path points and %.5f%% of labels equal\n", frame,
                100.0 * same_rows / rows, 100.0 * same_labels / got.size());
    EXPECT_GE(double(same_rows) / rows, 0.99);
    EXPECT_GE(double(same_labels) / got.size(), 0.999);
    // The consensus blend's mix levels: integer window sums, so equal on every pixel.
    const std::vector<uint8_t> mix = gpu.mix();
    ASSERT_EQ(mix.size(), cpu.mix().size());
    if (!mix.empty()) {
      std::size_t same_mix = 0, mixed = 0;
      for (std::size_t k = 0; k < mix.size(); ++k) same_mix += mix[k] == cpu.mix()[k], mixed += cpu.mix()[k] > 0;
      std::printf("MULTIBAND consensus mix frame %d: %.5f%% of levels equal (%zu pixels mixed)\n", frame,
                  100.0 * same_mix / mix.size(), mixed);
      EXPECT_EQ(same_mix, mix.size());
    }
  }
  }
#endif
}

TEST(CudaMultiband, ComposeMatchesCpuFromSystemAndDeviceMemory) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  testdata::RotatingRig s = rig_scene();
  // Multiband without and with seams, and the consensus blend (the weighted mean with seams).
  for (int variant = 0; variant < 3; ++variant) {
    const SeamMode seam = variant == 0 ? SeamMode::None : SeamMode::DynamicProgramming;
    CompositorSettings settings;
    settings.blend = variant == 2 ? BlendMode::Weighted : BlendMode::Multiband;
    settings.seam = seam;
    Compositor cpu(Backend::Cpu), gpu(Backend::Cuda);
    cpu.prepare(s.rig, settings);
    gpu.prepare(s.rig, settings);
    ASSERT_EQ(gpu.backend(), Backend::Cuda);
    const OutputGeometry& g = cpu.geometry();
    std::vector<ImageView> host;
    for (auto& f : s.frames) host.push_back(as_view(f));
    cv::Mat expected(g.height, g.width, CV_8UC4), from_host(g.height, g.width, CV_8UC4, cv::Scalar::all(77));
    cpu.compose(host, as_view(expected));
    gpu.compose(host, as_view(from_host));
    const char* name = variant == 0   ? "compose (system memory)"
                       : variant == 1 ? "compose + dp seams (system memory)"
                                      : "consensus compose: weighted + dp seams (system memory)";
    expect_close(from_host, expected, name);
    std::vector<std::unique_ptr<testdata::DeviceMat>> dev;
    std::vector<ImageView> dv;
    for (auto& f : s.frames) {
      dev.push_back(std::make_unique<testdata::DeviceMat>(f));
      dv.push_back(dev.back()->view());
    }
    testdata::DeviceMat out(cv::Mat(g.height, g.width, CV_8UC4, cv::Scalar::all(77)));
    gpu.compose(dv, out.view());
    expect_close(out.download(), expected,
                 variant == 0   ? "compose (device memory)"
                 : variant == 1 ? "compose + dp seams (device memory)"
                                : "consensus compose: weighted + dp seams (device memory)");
    // A missing camera is left out on both.
    host[0] = ImageView();
    cpu.compose(host, as_view(expected));
    gpu.compose(host, as_view(from_host));
    expect_close(from_host, expected, "compose, camera 0 missing");
  }
#endif
}

TEST(CudaMultiband, PrewarpedFuseAndResampleMatchCpu) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  testdata::RotatingRig s = rig_scene();
  // Multiband + dp seams, and the consensus blend (the default chain: stitchflowwarp's
  // pre-warped views into stitchblend's weighted mean with dp seams), cropped and scaled, and
  // the consensus blend fused 1:1 on the canvas (CudaComposer::fuse).
  for (int variant = 0; variant < 3; ++variant) {
  CompositorSettings settings;
  settings.blend = variant == 0 ? BlendMode::Multiband : BlendMode::Weighted;
  settings.seam = SeamMode::DynamicProgramming;
  if (variant < 2) {
    settings.crop = CropMode::Auto;
    settings.output_width = 1000;  // above 0.75x: both backends resample bilinearly (test_cuda's case)
  }
  Compositor cpu(Backend::Cpu), gpu(Backend::Cuda);
  cpu.prepare(s.rig, settings, CompositorInput::Prewarped);
  gpu.prepare(s.rig, settings, CompositorInput::Prewarped);
  // The views pre-warped onto the canvas, as stitchflowwarp hands them on.
  const WarpedViews w(cpu.prewarped_placements(), s.frames);
  const std::vector<ImageView>& host = w.host;
  const OutputGeometry& g = cpu.geometry();
  cv::Mat expected(g.height, g.width, CV_8UC4), got(g.height, g.width, CV_8UC4, cv::Scalar::all(77));
  cpu.compose(host, as_view(expected));
  gpu.compose(host, as_view(got));
  // The crop/scale differs between the backends (OpenCV's warpAffine vs our kernel) as it does
  // for the weighted mean, so the bound is the one test_cuda uses for that path.
  const double psnr = testdata::psnr_rgb(got, expected);
  const char* what = variant == 0   ? "MULTIBAND pre-warped + dp seams, cropped and scaled"
                     : variant == 1 ? "consensus (weighted + dp) pre-warped, cropped and scaled"
                                    : "consensus (weighted + dp) pre-warped, canvas 1:1";
  std::printf("%s to %dx%d: CUDA vs CPU PSNR %.2f dB\n", what, g.width, g.height, psnr);
  EXPECT_GE(psnr, variant == 2 ? 42.0 : 40.0) << what;  // 1:1: no resampling (a few labels may differ)
  }
#endif
}

TEST(CudaMultiband, DebugViewDrawsOnDeviceOutputLikeOnHost) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  testdata::RotatingRig s = rig_scene();
  CompositorSettings settings;
  settings.blend = BlendMode::Multiband;
  settings.seam = SeamMode::DynamicProgramming;
  Compositor cpu(Backend::Cpu), gpu(Backend::Cuda);
  cpu.prepare(s.rig, settings);
  gpu.prepare(s.rig, settings);
  cpu.set_debug(kDebugSeams | kDebugOutlines);
  gpu.set_debug(kDebugSeams | kDebugOutlines);
  const OutputGeometry& g = cpu.geometry();
  std::vector<ImageView> host;
  for (auto& f : s.frames) host.push_back(as_view(f));
  std::vector<std::unique_ptr<testdata::DeviceMat>> dev;
  std::vector<ImageView> dv;
  for (auto& f : s.frames) {
    dev.push_back(std::make_unique<testdata::DeviceMat>(f));
    dv.push_back(dev.back()->view());
  }
  cv::Mat expected(g.height, g.width, CV_8UC4);
  testdata::DeviceMat out(cv::Mat(g.height, g.width, CV_8UC4, cv::Scalar::all(77)));
  cpu.compose(host, as_view(expected));
  gpu.compose(dv, out.view());
  const cv::Mat got = out.download();
  // The seams (white) and outlines are drawn into the device panorama where the CPU draws them.
  auto white = [](const cv::Mat& m) {
    cv::Mat w;
    cv::inRange(m, cv::Scalar(255, 255, 255, 0), cv::Scalar(255, 255, 255, 255), w);
    return w;
  };
  const cv::Mat a = white(got), b = white(expected);
  const double both = cv::countNonZero(a & b), either = cv::countNonZero(a | b);
  std::printf("MULTIBAND debug view on device memory: %.0f white seam pixels, %.1f%% shared with the CPU's\n",
              double(cv::countNonZero(a)), 100 * both / std::max(1.0, either));
  EXPECT_GT(cv::countNonZero(a), g.height);  // at least one seam's worth
  EXPECT_GT(both / either, 0.9);
#endif
}
