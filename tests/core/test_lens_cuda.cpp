// Lenses on the GPU (issue 15): the CUDA warp and compose of radtan and fisheye rigs (planar
// and spherical, image circles; cubemap canvases, pinhole too) against the CPU, >= 45 dB.
// Exits 77 (skipped) without a device.
// Links no imgcodecs: it goes to the GPU host with the bundle.
#include <gtest/gtest.h>

#include <cstdio>

#include "cuda_test.hpp"
#include "image_compare.hpp"
#include "lens_rig.hpp"
#include "ppm.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/calib/calib_session.hpp"
#include "stitch/warp/flow_warper.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/warp/geometry.hpp"
#include "stitch/warp/warper.hpp"

using namespace stitch;

namespace {

Rig radtan_plane_rig() {
  Rig rig;
  for (int i = 0; i < 3; ++i) {
    Camera c;
    c.width = 640, c.height = 480, c.fx = c.fy = 520, c.cx = 319.5, c.cy = 239.5;
    c.lens.model = Lens::Model::Radtan;
    c.lens.k1 = -0.3, c.lens.k2 = 0.03, c.lens.p1 = 0.001, c.lens.p2 = -0.001;
    c.yaw_deg = 35.0 * (i - 1);
    rig.cameras.push_back(c);
  }
  rig.reference = 1;
  rig_compute_rough_homographies(rig);
  return rig;
}

// Pinhole cameras (no lens: the kernels' plain curved path) around the horizon, on a cubemap.
Rig pinhole_cubemap_rig() {
  Rig rig;
  rig.projection = "cubemap";
  for (int i = 0; i < 4; ++i) {
    Camera c;
    c.width = 400, c.height = 300, c.fx = c.fy = 170, c.cx = 199.5, c.cy = 149.5;
    c.yaw_deg = 90.0 * i - (i > 1 ? 360.0 : 0.0);
    c.pitch_deg = i % 2 ? 20.0 : -20.0;
    rig.cameras.push_back(c);
  }
  rig_layout_canvas(rig);
  return rig;
}

}  // namespace

TEST(LensCuda, WarpAndComposeMatchCpuForEveryLensModel) {
#ifdef STITCH_HAVE_CUDA
  const cv::Mat photo = testdata::test_photo();
  struct Case {
    const char* name;
    Rig rig;
  };
  std::vector<Case> cases = {{"radtan plane", radtan_plane_rig()},
                             {"dual fisheye 200 sphere", testdata::dual_fisheye_rig(400, 200)},
                             {"fisheye ring of 4 sphere", testdata::fisheye_ring(4, 300, 190)},
                             {"dual fisheye 200 cubemap", testdata::reprojected(testdata::dual_fisheye_rig(400, 200), "cubemap")},
                             {"pinhole ring of 4 cubemap", pinhole_cubemap_rig()}};
  for (auto& cs : cases) {
    std::vector<cv::Mat> frames;
    for (const auto& c : cs.rig.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
    const std::vector<ViewPlacement> views = place_views(cs.rig, canvas_geometry(cs.rig));
    auto cpu = Warper::create(Backend::Cpu), gpu = Warper::create(Backend::Cuda);
    cpu->prepare(views);
    gpu->prepare(views);
    for (int i = 0; i < int(views.size()); ++i) {
      const Rect& r = views[i].roi;
      if (r.empty()) continue;
      cv::Mat expected(r.height, r.width, CV_8UC4, cv::Scalar::all(0));
      cpu->warp(i, as_view(frames[i]), as_view(expected));
      testdata::DeviceMat src(frames[i]);
      testdata::DeviceMat dst(cv::Mat(r.height, r.width, CV_8UC4, cv::Scalar::all(77)));
      gpu->warp(i, src.view(), dst.view());
      const double psnr = testdata::psnr_rgb(dst.download(), expected);
      std::printf("%s: warp view %d (%dx%d) CUDA vs CPU PSNR %.2f dB\n", cs.name, i, r.width, r.height, psnr);
      EXPECT_GE(psnr, 45.0) << cs.name;
    }
    std::vector<ImageView> host;
    for (auto& f : frames) host.push_back(as_view(f));
    Compositor c(Backend::Cpu), g(Backend::Cuda);
    c.prepare(cs.rig, CompositorSettings{});
    g.prepare(cs.rig, CompositorSettings{});
    const OutputGeometry& og = c.geometry();
    cv::Mat want(og.height, og.width, CV_8UC4), got(og.height, og.width, CV_8UC4, cv::Scalar::all(77));
    c.compose(host, as_view(want));
    g.compose(host, as_view(got));
    const double psnr = testdata::psnr_rgb(got, want);
    std::printf("%s: compose %dx%d CUDA vs CPU PSNR %.2f dB\n", cs.name, og.width, og.height, psnr);
    EXPECT_GE(psnr, 45.0) << cs.name;
  }
#endif
}

// An output a quarter of the cameras' size: the views read frames halved twice
// (prefilter_sparse_views); the CUDA compose (host and device frames) and the CUDA flow warp's
// pre-warp onto a canvas made that small agree with the CPU, >= 45 dB.
TEST(LensCuda, ReducedFramesOfSmallOutputsMatchCpu) {
#ifdef STITCH_HAVE_CUDA
  const cv::Mat photo = testdata::test_photo();
  for (Rig rig : {testdata::fisheye_ring(6, 720, 190), radtan_plane_rig()}) {
    std::vector<cv::Mat> frames;
    for (const auto& c : rig.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
    std::vector<ImageView> host;
    for (auto& f : frames) host.push_back(as_view(f));
    CompositorSettings s;
    s.output_width = rig.canvas_width / 4 / 2 * 2;
    Compositor c(Backend::Cpu), g(Backend::Cuda);
    c.prepare(rig, s);
    g.prepare(rig, s);
    const OutputGeometry& og = c.geometry();
    std::vector<ViewPlacement> views = place_views(rig, og);
    prefilter_sparse_views(views);
    int reduced = 0;
    for (const auto& v : views) reduced += v.level > 0;
    EXPECT_GT(reduced, 0) << "no view read a reduced frame";
    cv::Mat want(og.height, og.width, CV_8UC4), got(og.height, og.width, CV_8UC4, cv::Scalar::all(77));
    c.compose(host, as_view(want));
    g.compose(host, as_view(got));
    double psnr = testdata::psnr_rgb(got, want);
    std::printf("%s, output %dx%d (%d views reduced): compose CUDA vs CPU %.2f dB\n", rig.projection.c_str(), og.width,
                og.height, reduced, psnr);
    EXPECT_GE(psnr, 45.0);
    std::vector<std::unique_ptr<testdata::DeviceMat>> dev;
    std::vector<ImageView> on_device;
    for (const auto& f : frames) {
      dev.push_back(std::make_unique<testdata::DeviceMat>(f));
      on_device.push_back(dev.back()->view());
    }
    got.setTo(cv::Scalar::all(77));
    g.compose(on_device, as_view(got));
    psnr = testdata::psnr_rgb(got, want);
    std::printf("  device frames: compose CUDA vs CPU %.2f dB\n", psnr);
    EXPECT_GE(psnr, 45.0);

    // The flow warp's pre-warp (flow off) onto a canvas shrunk to a quarter.
    Rig small = rig;
    shrink_canvas_to_output(small, rig.canvas_width / 4 / 2 * 2, 0, CropMode::None);
    const OutputGeometry canvas = canvas_geometry(small);
    const std::vector<ViewPlacement> cv_views = place_views(small, canvas);
    auto fc = FlowWarper::create(Backend::Cpu), fg = FlowWarper::create(Backend::Cuda);
    FlowWarpSettings fs;
    fs.flow = false;
    for (auto* f : {fc.get(), fg.get()}) {
      f->set_settings(fs);
      f->prepare(cv_views, canvas.width, canvas.height);
    }
    std::vector<cv::Mat> wc, wg;
    std::vector<ImageView> vc, vg;
    for (const auto& v : cv_views) {
      wc.emplace_back(std::max(v.roi.height, 1), std::max(v.roi.width, 1), CV_8UC4, cv::Scalar::all(0));
      wg.emplace_back(std::max(v.roi.height, 1), std::max(v.roi.width, 1), CV_8UC4, cv::Scalar::all(0));
      vc.push_back(v.roi.empty() ? ImageView() : as_view(wc.back()));
      vg.push_back(v.roi.empty() ? ImageView() : as_view(wg.back()));
    }
    fc->warp(host, vc);
    fg->warp(host, vg);
    for (std::size_t i = 0; i < cv_views.size(); ++i) {
      if (cv_views[i].roi.empty()) continue;
      const double p = testdata::psnr_rgb(wg[i], wc[i]);
      std::printf("  flow warp pre-warp view %zu (%dx%d): CUDA vs CPU %.2f dB\n", i, cv_views[i].roi.width,
                  cv_views[i].roi.height, p);
      EXPECT_GE(p, 45.0);
    }
  }
#endif
}

int main(int argc, char** argv) {
  if (!stitch::cuda_device_available()) {
    std::printf("no CUDA device here (or a build without the CUDA toolkit): the lens kernels are not checked\n");
    return 77;
  }
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
