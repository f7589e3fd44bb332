// Each CUDA stage against its CPU version on real frames (PSNR >= 45 dB). Needs a CUDA device:
// without one (or in a build without the toolkit) every test skips and says why.
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>

#include "stitch/backend.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/color/color.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/warp/warper.hpp"
#include "image_compare.hpp"
#include "cuda_test.hpp"
#include "ppm.hpp"

#ifdef STITCH_HAVE_CUDA
#include <cuda_runtime_api.h>

#include "stitch/blend/seam_math.hpp"
#include "stitch/cuda/view_geometry.hpp"
#endif

using namespace stitch;

namespace {

#define REQUIRE_CUDA() REQUIRE_CUDA_FOR("the CUDA stages")

#ifdef STITCH_HAVE_CUDA
using testdata::DeviceMat;
#endif

// Three overlapping cameras of a real photo on a rotating rig (real homographies, not shifts).
struct RigScene {
  Rig rig;
  std::vector<cv::Mat> frames;
};

using testdata::test_photo;

RigScene rig_scene() {
  RigScene s;
  const cv::Mat photo_rgba = test_photo();
  const int w = 480, h = 360;
  s.rig.reference = 1;
  for (int i = 0; i < 3; ++i) {
    Camera c;
    c.width = w;
    c.height = h;
    c.fx = c.fy = 420.0;
    c.cx = (w - 1) * 0.5;
    c.cy = (h - 1) * 0.5;
    c.yaw_deg = (i - 1) * 30.0;
    c.roll_deg = (i - 1) * 2.0;
    s.rig.cameras.push_back(c);
    cv::Mat f;
    cv::resize(photo_rgba(cv::Rect(i * 450, 100, 700, 525)), f, cv::Size(w, h), 0, 0, cv::INTER_AREA);
    s.frames.push_back(f);
  }
  rig_compute_rough_homographies(s.rig);
  return s;
}

// The same scene on `projection`'s canvas, laid out from the rotations as a calibration leaves it.
RigScene rig_scene_on(const std::string& projection) {
  RigScene s = rig_scene();
  if (projection != "plane") {
    s.rig.projection = projection;
    s.rig.canvas_scale = 0;
    rig_layout_canvas(s.rig);
  }
  return s;
}

#ifdef STITCH_HAVE_CUDA
// That scene's frames on the device (pitched: they take textures), their geometry and textures.
struct DeviceScene {
  RigScene scene;
  OutputGeometry canvas;
  std::vector<ViewPlacement> views;
  std::vector<std::unique_ptr<DeviceMat>> frames;
  std::vector<stitch_cuda::DeviceImage> images;
  std::vector<stitch_cuda::ViewGeometry> geometry;
  std::vector<unsigned long long> textures;
  explicit DeviceScene(const std::string& projection) : scene(rig_scene_on(projection)) {
    canvas = canvas_geometry(scene.rig);
    views = place_views(scene.rig, canvas);
    for (std::size_t i = 0; i < scene.frames.size(); ++i) {
      frames.push_back(std::make_unique<DeviceMat>(scene.frames[i]));
      images.push_back(to_device_image(frames.back()->view()));
      geometry.push_back(to_device_geometry(views[i]));
      textures.push_back(stitch_cuda::create_rgba_texture(images.back()));
      EXPECT_NE(textures.back(), 0u) << "pitched device frames take textures";
    }
  }
  ~DeviceScene() {
    for (auto t : textures) stitch_cuda::destroy_texture(t);
  }
};
#endif

}  // namespace

TEST(Cuda, WarpMatchesCpu) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  RigScene s = rig_scene();
  const OutputGeometry g = canvas_geometry(s.rig);
  const std::vector<ViewPlacement> views = place_views(s.rig, g);
  auto cpu = Warper::create(Backend::Cpu), gpu = Warper::create(Backend::Cuda);
  ASSERT_EQ(gpu->backend(), Backend::Cuda);
  cpu->prepare(views);
  gpu->prepare(views);
  for (int i = 0; i < 3; ++i) {
    const Rect& r = views[i].roi;
    cv::Mat expected(r.height, r.width, CV_8UC4, cv::Scalar::all(0));
    cpu->warp(i, as_view(s.frames[i]), as_view(expected));
    DeviceMat src(s.frames[i]);
    DeviceMat dst(cv::Mat(r.height, r.width, CV_8UC4, cv::Scalar::all(77)));  // poisoned
    gpu->warp(i, src.view(), dst.view());
    const double psnr = testdata::psnr_rgb(dst.download(), expected);
    std::printf("warp view %d: CUDA vs CPU PSNR %.2f dB\n", i, psnr);
    EXPECT_GE(psnr, 45.0);
  }
#endif
}

TEST(Cuda, ComposeMatchesCpuFromSystemAndDeviceMemory) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  RigScene s = rig_scene();
  CompositorSettings settings;
  settings.crop = CropMode::Auto;
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
  const double psnr_host = testdata::psnr_rgb(from_host, expected);
  std::vector<std::unique_ptr<DeviceMat>> dev;
  std::vector<ImageView> dv;
  for (auto& f : s.frames) {
    dev.push_back(std::make_unique<DeviceMat>(f));
    dv.push_back(dev.back()->view());
  }
  DeviceMat out(cv::Mat(g.height, g.width, CV_8UC4, cv::Scalar::all(77)));
  gpu.compose(dv, out.view());
  const double psnr_dev = testdata::psnr_rgb(out.download(), expected);
  std::printf("compose %dx%d: CUDA vs CPU PSNR %.2f dB (system memory), %.2f dB (device memory)\n", g.width,
              g.height, psnr_host, psnr_dev);
  EXPECT_GE(psnr_host, 45.0);
  EXPECT_GE(psnr_dev, 45.0);

  // A missing camera is left out on both.
  host[0] = ImageView();
  cpu.compose(host, as_view(expected));
  gpu.compose(host, as_view(from_host));
  EXPECT_GE(testdata::psnr_rgb(from_host, expected), 45.0);
#endif
}

// The compositor keeps a few texture objects per view, keyed by buffer (a buffer pool cycles a
// few): frames from more buffers than it keeps, each with its own picture, then the first buffers
// again with new pictures, must each give the CPU's panorama of that frame.
TEST(Cuda, ComposeFromManyBuffersSamplesEachFramesOwnPicture) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  RigScene s = rig_scene();
  Compositor cpu(Backend::Cpu), gpu(Backend::Cuda);
  cpu.prepare(s.rig, CompositorSettings{});
  gpu.prepare(s.rig, CompositorSettings{});
  const OutputGeometry& g = cpu.geometry();
  std::vector<std::unique_ptr<DeviceMat>> buffers;  // kept: every frame set in buffers of its own
  for (int k = 0; k < 14; ++k) {
    SCOPED_TRACE(testing::Message() << "frame " << k);
    std::vector<cv::Mat> frames;
    std::vector<ImageView> host, device;
    for (std::size_t i = 0; i < s.frames.size(); ++i) {
      frames.push_back(s.frames[i] + cv::Scalar(7 * k, 3 * k, 11 * k, 0));  // a picture of its own
      host.push_back(as_view(frames.back()));
      if (k < 12) {
        buffers.push_back(std::make_unique<DeviceMat>(frames.back()));
      } else {  // the first frame set's buffers again, with this frame's picture
        DeviceMat& b = *buffers[i];
        ASSERT_EQ(cudaMemcpy2D(b.ptr, b.pitch, frames.back().data, frames.back().step, std::size_t(b.width) * 4,
                               std::size_t(b.height), cudaMemcpyHostToDevice),
                  cudaSuccess);
      }
      device.push_back((k < 12 ? *buffers.back() : *buffers[i]).view());
    }
    cv::Mat expected(g.height, g.width, CV_8UC4);
    cpu.compose(host, as_view(expected));
    DeviceMat out(cv::Mat(g.height, g.width, CV_8UC4, cv::Scalar::all(77)));
    gpu.compose(device, out.view());
    EXPECT_GE(testdata::psnr_rgb(out.download(), expected), 45.0);
  }
#endif
}

TEST(Cuda, PrewarpedFuseMatchesCpu) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  RigScene s = rig_scene();
  Compositor cpu(Backend::Cpu), gpu(Backend::Cuda);
  cpu.prepare(s.rig, CompositorSettings{}, CompositorInput::Prewarped);
  gpu.prepare(s.rig, CompositorSettings{}, CompositorInput::Prewarped);
  auto warper = Warper::create(Backend::Cpu);
  warper->prepare(cpu.prewarped_placements());
  std::vector<cv::Mat> warped;
  std::vector<ImageView> views;
  for (int i = 0; i < 3; ++i) {
    const Rect& r = cpu.prewarped_placements()[i].roi;
    warped.emplace_back(r.height, r.width, CV_8UC4);
    warper->warp(i, as_view(s.frames[i]), as_view(warped.back()));
  }
  for (auto& w : warped) views.push_back(as_view(w));
  const OutputGeometry& g = cpu.geometry();
  cv::Mat expected(g.height, g.width, CV_8UC4), got(g.height, g.width, CV_8UC4, cv::Scalar::all(77));
  cpu.compose(views, as_view(expected));
  gpu.compose(views, as_view(got));
  const double psnr = testdata::psnr_rgb(got, expected);
  std::printf("pre-warped fuse: CUDA vs CPU PSNR %.2f dB\n", psnr);
  EXPECT_GE(psnr, 45.0);

  // Cropped (a translation) and scaled (bilinear on both sides above 0.75x) into system and
  // into device memory.
  for (int scaled = 0; scaled < 2; ++scaled) {
    CompositorSettings settings;
    settings.crop = CropMode::Auto;
    if (scaled) settings.output_width = 1000;
    Compositor c2(Backend::Cpu), g2(Backend::Cuda);
    c2.prepare(s.rig, settings, CompositorInput::Prewarped);
    g2.prepare(s.rig, settings, CompositorInput::Prewarped);
    const OutputGeometry& og = c2.geometry();
    cv::Mat want(og.height, og.width, CV_8UC4), host(og.height, og.width, CV_8UC4, cv::Scalar::all(77));
    c2.compose(views, as_view(want));
    g2.compose(views, as_view(host));
    DeviceMat dev(cv::Mat(og.height, og.width, CV_8UC4, cv::Scalar::all(77)));
    g2.compose(views, dev.view());
    const double ph = testdata::psnr_rgb(host, want), pd = testdata::psnr_rgb(dev.download(), want);
    std::printf("pre-warped fuse %s to %dx%d: CUDA vs CPU PSNR %.2f dB (system), %.2f dB (device)\n",
                scaled ? "cropped + scaled" : "cropped", og.width, og.height, ph, pd);
    EXPECT_GE(ph, scaled ? 40.0 : 45.0);
    EXPECT_GE(pd, scaled ? 40.0 : 45.0);
  }
#endif
}

// The fuse's tiles (a tile one view covers alone is copied from it) give the bytes of the
// per-pixel weighted mean: plain, with the consensus mix, with a view missing, and on a
// spherical canvas; and they do skip work (some tiles are one view's alone, some are mixed).
// The blend's warp of every view in one launch (launch_warps), with gathers and with the texture
// units' bilinear taps, into rows that take vector stores and rows that do not (the rectangles'
// own widths), with the seam finder's luma: the CPU warper's pixels, the luma of the written ones.
TEST(Cuda, OneLaunchWarpOfEveryViewMatchesTheCpu) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  for (const char* projection : {"plane", "spherical"}) {
    SCOPED_TRACE(projection);
    DeviceScene d(projection);
    const std::vector<ViewPlacement>& views = d.views;
    const std::vector<stitch_cuda::DeviceImage>& srcs = d.images;
    auto cpu = Warper::create(Backend::Cpu);
    cpu->prepare(views);
    std::vector<cv::Mat> expected;
    for (int i = 0; i < 3; ++i) {
      const Rect& r = views[std::size_t(i)].roi;
      expected.emplace_back(r.height, r.width, CV_8UC4, cv::Scalar::all(0));
      cpu->warp(i, as_view(d.scene.frames[std::size_t(i)]), as_view(expected.back()));
    }
    for (int textured = 0; textured < 2; ++textured)
      for (int packed = 0; packed < 2; ++packed) {
        SCOPED_TRACE(testing::Message() << "textured " << textured << " packed " << packed);
        std::vector<DeviceBuffer> rects, lumas;
        std::vector<stitch_cuda::DeviceImage> dsts;
        std::vector<uint8_t*> luma_ptrs;
        for (int i = 0; i < 3; ++i) {
          const Rect& r = views[std::size_t(i)].roi;
          // packed: rows of exactly the width (vector stores only where the width allows);
          // else rows padded to 64 bytes.
          const std::size_t pitch = packed ? std::size_t(r.width) * 4 : (std::size_t(r.width) * 4 + 63) / 64 * 64;
          rects.emplace_back(pitch * std::size_t(r.height));
          lumas.emplace_back(std::size_t(r.width) * r.height);
          ASSERT_EQ(cudaMemset(rects.back().data(), 77, pitch * std::size_t(r.height)), cudaSuccess);  // poisoned
          stitch_cuda::DeviceImage rect;
          rect.data = rects.back().data();
          rect.pitch = pitch;
          rect.width = r.width;
          rect.height = r.height;
          dsts.push_back(rect);
          luma_ptrs.push_back(lumas.back().data());
        }
        stitch_cuda::launch_warps(3, srcs.data(), d.geometry.data(), dsts.data(), luma_ptrs.data(),
                                  textured ? d.textures.data() : nullptr, nullptr);
        ASSERT_EQ(cudaDeviceSynchronize(), cudaSuccess);
        for (int i = 0; i < 3; ++i) {
          const stitch_cuda::DeviceImage& rect = dsts[std::size_t(i)];
          cv::Mat got(rect.height, rect.width, CV_8UC4), luma(rect.height, rect.width, CV_8UC1);
          ASSERT_EQ(cudaMemcpy2D(got.data, got.step, rect.data, rect.pitch, std::size_t(rect.width) * 4,
                                 std::size_t(rect.height), cudaMemcpyDeviceToHost),
                    cudaSuccess);
          ASSERT_EQ(cudaMemcpy(luma.data, luma_ptrs[std::size_t(i)], luma.total(), cudaMemcpyDeviceToHost), cudaSuccess);
          const double psnr = testdata::psnr_rgb(got, expected[std::size_t(i)]);
          std::printf("one-launch warp (%s, %s, %s rows) view %d: CUDA vs CPU PSNR %.2f dB\n", projection,
                      textured ? "texture" : "gathers", packed ? "packed" : "padded", i, psnr);
          EXPECT_GT(psnr, 45.0) << "view " << i;
          int luma_off = 0;
          for (int y = 0; y < rect.height; ++y)
            for (int x = 0; x < rect.width; ++x)
              luma_off += luma.at<uint8_t>(y, x) != stitch::seam::luma(got.ptr<uint8_t>(y) + 4 * x);
          EXPECT_EQ(luma_off, 0) << "view " << i;
        }
      }
  }
#endif
}

// The compose on the fuse's tiles: a tile one view covers alone takes that view's sample without
// the weights. Against the untiled compose: one level at most (w c / w may round a tie the other
// way), on a sliver of the pixels; gathers and texture, colour matrices, each view missing in turn.
TEST(Cuda, ComposeTilesGiveTheWeightedMeanWithinOneLevel) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  for (const char* projection : {"plane", "spherical"}) {
    SCOPED_TRACE(projection);
    DeviceScene d(projection);
    const OutputGeometry& g = d.canvas;
    const float color[27] = {1.05f, 0.01f, 0, 0, 0.97f, 0, 0, 0.02f, 1.02f, 1, 0, 0, 0, 1, 0, 0, 0, 1,
                             0.9f, 0, 0.03f, 0, 1.1f, 0, 0, 0, 0.95f};
    DeviceBuffer tiles(stitch_cuda::fuse_tile_count(g.width, g.height));
    stitch_cuda::launch_fuse_tiles(3, d.geometry.data(), g.width, g.height, tiles.data(), nullptr);
    for (int missing = -1; missing < 3; ++missing)
      for (int textured = 0; textured < 2; ++textured) {
        SCOPED_TRACE(testing::Message() << "missing " << missing << " textured " << textured);
        std::vector<stitch_cuda::DeviceImage> present = d.images;
        std::vector<unsigned long long> present_tex = d.textures;
        if (missing >= 0) present[std::size_t(missing)].data = nullptr, present_tex[std::size_t(missing)] = 0;
        DeviceMat plain(cv::Mat(g.height, g.width, CV_8UC4, cv::Scalar::all(77)));
        DeviceMat tiled(cv::Mat(g.height, g.width, CV_8UC4, cv::Scalar::all(78)));
        for (int use_tiles = 0; use_tiles < 2; ++use_tiles) {
          const stitch_cuda::DeviceImage out = to_device_image((use_tiles ? tiled : plain).view());
          const uint8_t* t = use_tiles ? tiles.data() : nullptr;
          if (textured) stitch_cuda::launch_compose_tex(3, d.geometry.data(), present_tex.data(), color, out, nullptr, t);
          else stitch_cuda::launch_compose(3, d.geometry.data(), present.data(), color, out, nullptr, t);
        }
        ASSERT_EQ(cudaDeviceSynchronize(), cudaSuccess);
        const cv::Mat a = plain.download(), b = tiled.download();
        cv::Mat diff;
        cv::absdiff(a, b, diff);
        EXPECT_LE(cv::norm(diff, cv::NORM_INF), 1.0);
        const double off = double(cv::countNonZero(diff.reshape(1))) / double(diff.total() * 4);
        std::printf("compose tiles (%s, %s, missing %d): %.4f%% of channels one level off\n", projection,
                    textured ? "texture" : "gathers", missing, 100 * off);
        EXPECT_LT(off, 0.01);
        // Two pixels a thread: an odd output width and rows off 16 bytes (no vector stores)
        // give the same bytes on the columns they cover and leave the next column alone.
        const int odd_w = g.width % 2 ? g.width - 2 : g.width - 3;  // a spare column after it
        DeviceMat narrow(cv::Mat(g.height, g.width, CV_8UC4, cv::Scalar::all(79)));
        stitch_cuda::DeviceImage nout = to_device_image(narrow.view());
        nout.data += 4;  // rows start 4 bytes in: off 16
        nout.width = odd_w;
        if (textured) stitch_cuda::launch_compose_tex(3, d.geometry.data(), present_tex.data(), color, nout, nullptr);
        else stitch_cuda::launch_compose(3, d.geometry.data(), present.data(), color, nout, nullptr);
        ASSERT_EQ(cudaDeviceSynchronize(), cudaSuccess);
        const cv::Mat n = narrow.download();
        EXPECT_EQ(cv::norm(n(cv::Rect(1, 0, odd_w, g.height)), a(cv::Rect(0, 0, odd_w, g.height)), cv::NORM_INF), 0.0);
        EXPECT_EQ(cv::norm(n.col(odd_w + 1), cv::Mat(g.height, 1, CV_8UC4, cv::Scalar::all(79)), cv::NORM_INF), 0.0);
      }
  }
#endif
}

TEST(Cuda, FuseTilesGiveTheSameBytesAsTheWeightedMean) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  for (const char* projection : {"plane", "spherical"}) {
    SCOPED_TRACE(projection);
    RigScene s = rig_scene_on(projection);
    Compositor cpu(Backend::Cpu);
    cpu.prepare(s.rig, CompositorSettings{}, CompositorInput::Prewarped);
    const std::vector<ViewPlacement>& placements = cpu.prewarped_placements();
    auto warper = Warper::create(Backend::Cpu);
    warper->prepare(placements);
    std::vector<std::unique_ptr<DeviceMat>> warped;
    std::vector<stitch_cuda::ViewGeometry> geometry;
    std::vector<stitch_cuda::DeviceImage> images;
    for (int i = 0; i < 3; ++i) {
      const Rect& r = placements[std::size_t(i)].roi;
      cv::Mat w(r.height, r.width, CV_8UC4);
      warper->warp(i, as_view(s.frames[std::size_t(i)]), as_view(w));
      warped.push_back(std::make_unique<DeviceMat>(w));
      geometry.push_back(to_device_geometry(placements[std::size_t(i)]));
      images.push_back(to_device_image(warped.back()->view()));
    }
    const int W = cpu.geometry().width, H = cpu.geometry().height;
    DeviceBuffer tiles(stitch_cuda::fuse_tile_count(W, H)), labels(std::size_t(W) * H), mix(std::size_t(W) * H);
    stitch_cuda::launch_fuse_tiles(3, geometry.data(), W, H, tiles.data(), nullptr);
    std::vector<uint8_t> classes(stitch_cuda::fuse_tile_count(W, H));
    ASSERT_EQ(cudaMemcpy(classes.data(), tiles.data(), classes.size(), cudaMemcpyDeviceToHost), cudaSuccess);
    int alone = 0, mixed = 0;
    for (uint8_t c : classes) (c < 3 ? alone : c == stitch_cuda::kFuseTileMixed ? mixed : alone) += 1;
    EXPECT_GT(alone, int(classes.size()) / 4);
    EXPECT_GT(mixed, 0);
    // Labels by thirds of the width, a mix level that varies everywhere.
    cv::Mat label_host(H, W, CV_8UC1), mix_host(H, W, CV_8UC1);
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        label_host.at<uint8_t>(y, x) = uint8_t(std::min(2, 3 * x / W));
        mix_host.at<uint8_t>(y, x) = uint8_t((x * 7 + y * 13) % 256);
      }
    ASSERT_EQ(cudaMemcpy(labels.data(), label_host.data, label_host.total(), cudaMemcpyHostToDevice), cudaSuccess);
    ASSERT_EQ(cudaMemcpy(mix.data(), mix_host.data, mix_host.total(), cudaMemcpyHostToDevice), cudaSuccess);
    for (int missing = -1; missing < 3; ++missing)
      for (int consensus = 0; consensus < 2; ++consensus) {
        SCOPED_TRACE(testing::Message() << "missing " << missing << " consensus " << consensus);
        std::vector<stitch_cuda::DeviceImage> present = images;
        if (missing >= 0) present[std::size_t(missing)].data = nullptr;
        DeviceMat plain(cv::Mat(H, W, CV_8UC4, cv::Scalar::all(77))), tiled(cv::Mat(H, W, CV_8UC4, cv::Scalar::all(78)));
        const uint8_t* l = consensus ? labels.data() : nullptr;
        const uint8_t* m = consensus ? mix.data() : nullptr;
        stitch_cuda::launch_fuse(3, geometry.data(), present.data(), to_device_image(plain.view()), nullptr, l, m);
        stitch_cuda::launch_fuse(3, geometry.data(), present.data(), to_device_image(tiled.view()), nullptr, l, m,
                                 tiles.data());
        ASSERT_EQ(cudaDeviceSynchronize(), cudaSuccess);
        const cv::Mat a = plain.download(), b = tiled.download();
        EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0.0);
      }
  }
#endif
}

TEST(Cuda, ColorApplyAndGatherMatchCpu) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  RigScene s = rig_scene();
  auto cpu = ColorOps::create(Backend::Cpu), gpu = ColorOps::create(Backend::Cuda);
  ASSERT_EQ(gpu->backend(), Backend::Cuda);
  Eigen::Matrix3d M;
  M << 1.1, 0.02, -0.01, 0.03, 0.92, 0.0, -0.02, 0.05, 1.05;
  std::array<std::array<uint8_t, 256>, 3> lut;
  for (int c = 0; c < 3; ++c) lut[c] = piecewise_balance_curve(20 + 5 * c, 230 - 4 * c, 0.05);
  cv::Mat expected = s.frames[0].clone();
  cpu->apply(as_view(expected), M, lut);
  DeviceMat d(s.frames[0]);
  gpu->apply(d.view(), M, lut);
  const cv::Mat got = d.download();
  const double psnr = testdata::psnr_rgb(got, expected);
  std::printf("color apply: CUDA vs CPU PSNR %.2f dB\n", psnr);
  EXPECT_GE(psnr, 45.0);
  std::vector<int32_t> xy;
  for (int k = 0; k < 500; ++k) xy.insert(xy.end(), {(k * 37) % got.cols, (k * 53) % got.rows});
  std::vector<std::array<uint8_t, 3>> a, b;
  cpu->gather(as_view(expected), xy, a);
  gpu->gather(d.view(), xy, b);
  ASSERT_EQ(a.size(), b.size());
  int same = 0;
  for (std::size_t k = 0; k < a.size(); ++k) same += a[k] == b[k] ? 1 : 0;
  EXPECT_GE(same, int(a.size()) * 9 / 10);  // the same pixels up to rounding
#endif
}

TEST(Cuda, AutoPicksCpuWithoutADevice) {
  if (cuda_device_available()) {
    EXPECT_EQ(resolve_backend(Backend::Auto, true), Backend::Cuda);
  } else {
    EXPECT_EQ(resolve_backend(Backend::Auto, true), Backend::Cpu);
    EXPECT_THROW(resolve_backend(Backend::Cuda, true), std::runtime_error);
  }
  EXPECT_EQ(resolve_backend(Backend::Auto, false), Backend::Cpu);
  EXPECT_THROW(resolve_backend(Backend::Cuda, false), std::runtime_error);
}
