// The color stage on the GPU against the CPU: the same reductions bit for bit, and the same
// corrections and corrected views for every method x pairing x balance, on a real photo seen by
// three cameras with different exposures and white balances. Needs a CUDA device: without one
// (or in a build without the toolkit) every case skips and says why.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <opencv2/imgproc.hpp>
#include <string>
#include <tuple>

#include "image_compare.hpp"
#include "cuda_test.hpp"
#include "ppm.hpp"
#include "stitch/backend.hpp"
#include "stitch/color/color.hpp"
#include "stitch/cv_interop.hpp"

#ifdef STITCH_HAVE_CUDA
#include <cuda_runtime_api.h>
#endif

#include "color_cast.hpp"

using namespace stitch;

namespace {

#define REQUIRE_CUDA() REQUIRE_CUDA_FOR("the CUDA color stage")

#ifdef STITCH_HAVE_CUDA
using testdata::DeviceMat;

using testdata::test_photo;

using testdata::distort;

// Three cameras of a rotating rig (real homographies) over a real photo.
struct ColorScene {
  Rig rig;
  std::vector<cv::Mat> crops;  // undistorted
};

ColorScene color_scene(int reference) {
  ColorScene s;
  const cv::Mat photo_rgba = test_photo();
  const int w = 480, h = 360;
  s.rig.reference = reference;
  for (int i = 0; i < 3; ++i) {
    Camera c;
    c.width = w;
    c.height = h;
    c.fx = c.fy = 420.0;
    c.cx = (w - 1) * 0.5;
    c.cy = (h - 1) * 0.5;
    c.yaw_deg = (i - 1) * 22.0;  // camera 2 still projects onto camera 0's plane (reference 0)
    c.roll_deg = (i - 1) * 2.0;
    s.rig.cameras.push_back(c);
    cv::Mat f;
    cv::resize(photo_rgba(cv::Rect(i * 450, 100, 700, 525)), f, cv::Size(w, h), 0, 0, cv::INTER_AREA);
    s.crops.push_back(f);
  }
  rig_compute_rough_homographies(s.rig);
  return s;
}

// Frame f of camera i: its own exposure and white balance (camera 0 also mixes channels),
// drifting from frame to frame so that the temporal state matters.
cv::Mat camera_frame(const ColorScene& s, int camera, int frame) {
  Eigen::Matrix3d cast;
  if (camera == 0) cast << 0.82, 0.05, 0.02, 0.04, 0.88, 0.03, 0.01, 0.06, 0.95;
  else if (camera == 1) cast = Eigen::Vector3d(1.0, 0.97, 0.92).asDiagonal();
  else cast = Eigen::Vector3d(1.18, 1.05, 0.88).asDiagonal();
  const double drift = camera == 0 ? 1.0 + 0.04 * frame : camera == 2 ? 1.0 - 0.03 * frame : 1.0;
  cv::Mat img = s.crops[std::size_t(camera)].clone();
  distort(img, cast * drift);
  return img;
}

double max_abs_difference(const std::vector<Eigen::Matrix3d>& a, const std::vector<Eigen::Matrix3d>& b) {
  double d = 0;
  for (std::size_t i = 0; i < a.size() && i < b.size(); ++i) d = std::max(d, (a[i] - b[i]).cwiseAbs().maxCoeff());
  return a.size() == b.size() ? d : 1e9;
}

int lut_difference(const std::array<std::array<uint8_t, 256>, 3>& a, const std::array<std::array<uint8_t, 256>, 3>& b) {
  int d = 0;
  for (int c = 0; c < 3; ++c)
    for (int v = 0; v < 256; ++v) d = std::max(d, std::abs(int(a[c][v]) - int(b[c][v])));
  return d;
}

void expect_same_stats(const ColorStats& cpu, const ColorStats& gpu) {
  ASSERT_EQ(cpu.pairs.size(), gpu.pairs.size());
  ASSERT_EQ(cpu.balance.size(), gpu.balance.size());
  for (std::size_t k = 0; k < cpu.pairs.size(); ++k) {
    const PairStats &c = cpu.pairs[k], &g = gpu.pairs[k];
    EXPECT_EQ(c.count, g.count) << "pair " << k;
    EXPECT_EQ(c.hist_a, g.hist_a) << "pair " << k;
    EXPECT_EQ(c.hist_b, g.hist_b) << "pair " << k;
    EXPECT_EQ(c.aa, g.aa) << "pair " << k;
    EXPECT_EQ(c.bb, g.bb) << "pair " << k;
    EXPECT_EQ(c.ab, g.ab) << "pair " << k;
    EXPECT_EQ(c.matched, g.matched) << "pair " << k;
    EXPECT_EQ(c.inview, g.inview) << "pair " << k;
    EXPECT_EQ(c.moving, g.moving) << "pair " << k;
    EXPECT_EQ(c.misaligned, g.misaligned) << "pair " << k;
    EXPECT_EQ(c.global_change, g.global_change) << "pair " << k;
    EXPECT_EQ(c.sum_a, g.sum_a) << "pair " << k;
    EXPECT_EQ(c.sum_b, g.sum_b) << "pair " << k;
  }
  for (std::size_t i = 0; i < cpu.balance.size(); ++i) EXPECT_EQ(cpu.balance[i], gpu.balance[i]) << "view " << i;
}
#endif

const char* method_name(ColorMethod m) {
  switch (m) {
    case ColorMethod::None: return "none";
    case ColorMethod::Matrix2D: return "2dm";
    case ColorMethod::Matrix3D: return "3dm";
    case ColorMethod::Gain: return "gain";
  }
  return "?";
}

}  // namespace

TEST(CudaColorOps, ReductionsMatchCpuExactly) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  const ColorScene s = color_scene(1);
  const ColorSampling sampling = make_color_sampling(s.rig, 16384);
  ASSERT_FALSE(sampling.pairs.empty());
  auto cpu = ColorOps::create(Backend::Cpu), gpu = ColorOps::create(Backend::Cuda);
  ASSERT_EQ(gpu->backend(), Backend::Cuda);
  cpu->set_sampling(sampling);
  gpu->set_sampling(sampling);
  std::vector<cv::Mat> frames;
  std::vector<std::unique_ptr<DeviceMat>> device;
  std::vector<ImageView> host_views, device_views;
  for (int i = 0; i < 3; ++i) frames.push_back(camera_frame(s, i, 0));
  for (auto& f : frames) {
    host_views.push_back(as_view(f));
    device.push_back(std::make_unique<DeviceMat>(f));
    device_views.push_back(device.back()->view());
  }
  ColorReductionRequest request;
  request.pairs = true;
  for (std::size_t k = 0; k < sampling.pairs.size(); ++k)
    request.match.push_back(k % 2 ? HistogramMatch::BOntoA : HistogramMatch::AOntoB);
  request.balance = true;
  Eigen::Matrix3d mix;
  mix << 1.12, 0.03, -0.02, -0.04, 0.95, 0.05, 0.02, -0.01, 1.2;
  request.balance_matrices = {mix, Eigen::Matrix3d::Identity(), mix.inverse()};
  ColorStats from_cpu, from_gpu;
  cpu->reduce(host_views, request, from_cpu);
  gpu->reduce(device_views, request, from_gpu);
  uint64_t usable = 0;
  for (const PairStats& p : from_cpu.pairs) usable += p.count;
  std::printf("COLOR reductions: %zu pairs, %llu usable samples, %zu balance grids\n", sampling.pairs.size(),
              (unsigned long long)usable, from_cpu.balance.size());
  EXPECT_GT(usable, 1000u);
  expect_same_stats(from_cpu, from_gpu);

  // A missing camera: its pairs and its grid are all zero on both.
  host_views[2] = ImageView();
  device_views[2] = ImageView();
  request.match.assign(sampling.pairs.size(), HistogramMatch::None);
  cpu->reduce(host_views, request, from_cpu);
  gpu->reduce(device_views, request, from_gpu);
  expect_same_stats(from_cpu, from_gpu);
#endif
}

TEST(CudaColorOps, StaticMaskMatchesCpuOverAMovingSequence) {
  // Issue 16: the motion/alignment mask keeps per-sample state across frames; a block of
  // changing colour crosses every camera, then all cameras' exposure steps (a restart).
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  const ColorScene s = color_scene(1);
  const ColorSampling sampling = make_color_sampling(s.rig, 16384);
  auto cpu = ColorOps::create(Backend::Cpu), gpu = ColorOps::create(Backend::Cuda);
  cpu->set_sampling(sampling);
  gpu->set_sampling(sampling);
  ColorReductionRequest request;
  request.pairs = true;
  request.static_mask = true;
  for (std::size_t k = 0; k < sampling.pairs.size(); ++k) request.match.push_back(HistogramMatch::AOntoB);
  uint64_t moving = 0, misaligned = 0, restarts = 0;
  for (int frame = 0; frame < 14; ++frame) {
    if (frame == 9) {
      cpu->reset_motion();
      gpu->reset_motion();
    }
    std::vector<cv::Mat> frames;
    std::vector<std::unique_ptr<DeviceMat>> device;
    std::vector<ImageView> host_views, device_views;
    for (int i = 0; i < 3; ++i) {
      cv::Mat f = camera_frame(s, i, 0);
      const cv::Scalar colour((frame * 53) % 200 + 40, (frame * 97) % 200 + 30, (frame * 31) % 200 + 50, 255);
      cv::rectangle(f, cv::Rect(20 + 30 * frame, 60, 70, 200), colour, cv::FILLED);
      if (frame >= 6) f.convertTo(f, -1, 0.6);  // every camera at once
      frames.push_back(f);
    }
    for (auto& f : frames) {
      host_views.push_back(as_view(f));
      device.push_back(std::make_unique<DeviceMat>(f));
      device_views.push_back(device.back()->view());
    }
    ColorStats from_cpu, from_gpu;
    cpu->reduce(host_views, request, from_cpu);
    gpu->reduce(device_views, request, from_gpu);
    expect_same_stats(from_cpu, from_gpu);
    for (const PairStats& p : from_cpu.pairs) {
      moving += p.moving;
      misaligned += p.misaligned;
      restarts += p.global_change;
    }
  }
  std::printf("COLOR mask: %llu moving, %llu misaligned sample-frames, %llu restarts\n", (unsigned long long)moving,
              (unsigned long long)misaligned, (unsigned long long)restarts);
  EXPECT_GT(moving, 100u);      // the block was seen moving
  EXPECT_GT(restarts, 0u);      // the exposure step restarted the state
#endif
}

// (method, pairing, balance, reference camera): reference 1 chains both cameras to the middle
// one; reference 0 chains camera 2 through camera 1 (its parent's correction enters its fit).
using ColorCase = std::tuple<ColorMethod, ColorPairing, bool, int>;

class CudaColorCorrector : public ::testing::TestWithParam<ColorCase> {};

TEST_P(CudaColorCorrector, MatchesCpuOverThreeFrames) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  const auto [method, pairing, balance, reference] = GetParam();
  const ColorScene s = color_scene(reference);
  ColorOptions o;
  o.method = method;
  o.pairing = pairing;
  o.balance = balance;
  ColorCorrector cpu(Backend::Cpu), gpu(Backend::Cuda);
  cpu.set_options(o);
  gpu.set_options(o);
  const std::string name = std::string(method_name(method)) + " pairing=" +
                           (pairing == ColorPairing::Histogram ? "histogram" : "pixels") +
                           " balance=" + (balance ? "on" : "off") + " reference=" + std::to_string(reference);
  for (int frame = 0; frame < 3; ++frame) {
    std::vector<cv::Mat> host;
    std::vector<std::unique_ptr<DeviceMat>> device;
    std::vector<ImageView> host_views, device_views;
    for (int i = 0; i < 3; ++i) host.push_back(camera_frame(s, i, frame));
    for (auto& f : host) {
      host_views.push_back(as_view(f));
      device.push_back(std::make_unique<DeviceMat>(f));
      device_views.push_back(device.back()->view());
    }
    cpu.process(s.rig, 1, host_views);
    gpu.process(s.rig, 1, device_views);
    const double dM = max_abs_difference(cpu.corrections(), gpu.corrections());
    const int dlut = lut_difference(cpu.balance_lut(), gpu.balance_lut());
    double worst = 1e9;
    std::string per_view;
    for (int i = 0; i < 3; ++i) {
      const double psnr = testdata::psnr_rgb(device[std::size_t(i)]->download(), host[std::size_t(i)]);
      worst = std::min(worst, psnr);
      char buf[32];
      std::snprintf(buf, sizeof buf, " %.2f", psnr);
      per_view += buf;
      EXPECT_GE(psnr, 45.0) << name << " frame " << frame << " view " << i;
    }
    std::printf("COLOR %s frame %d: max|M_cuda - M_cpu| = %.3g, balance LUT max diff %d, PSNR CUDA vs CPU (dB):%s\n",
                name.c_str(), frame, dM, dlut, per_view.c_str());
    EXPECT_LE(dM, 1e-3) << name << " frame " << frame;
  }
  // The corrections did something (the test is not comparing two identities).
  if (method != ColorMethod::None) {
    double moved = 0;
    for (const auto& M : cpu.corrections()) moved = std::max(moved, (M - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff());
    EXPECT_GT(moved, 0.02) << name;
  }
#endif
}

std::string case_name(const ::testing::TestParamInfo<ColorCase>& info) {
  const auto [method, pairing, balance, reference] = info.param;
  return std::string(method_name(method)) + (pairing == ColorPairing::Histogram ? "_histogram" : "_pixels") +
         (balance ? "_balance" : "_nobalance") + "_ref" + std::to_string(reference);
}

INSTANTIATE_TEST_SUITE_P(AllMethods, CudaColorCorrector,
                         ::testing::Combine(::testing::Values(ColorMethod::Matrix2D, ColorMethod::Matrix3D,
                                                              ColorMethod::Gain),
                                            ::testing::Values(ColorPairing::Histogram, ColorPairing::Pixels),
                                            ::testing::Bool(), ::testing::Values(1, 0)),
                         case_name);

TEST(CudaColorCorrectorMemory, MissingCameraAndSystemMemoryViews) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  const ColorScene s = color_scene(1);
  ColorOptions o;
  o.balance = true;
  ColorCorrector cpu(Backend::Cpu), gpu_device(Backend::Cuda), gpu_host(Backend::Cuda);
  for (ColorCorrector* c : {&cpu, &gpu_device, &gpu_host}) c->set_options(o);
  for (int frame = 0; frame < 2; ++frame) {
    std::vector<cv::Mat> host, host_for_gpu;
    std::vector<std::unique_ptr<DeviceMat>> device;
    std::vector<ImageView> host_views, gpu_host_views, device_views;
    for (int i = 0; i < 3; ++i) {
      host.push_back(camera_frame(s, i, frame));
      host_for_gpu.push_back(host.back().clone());
      device.push_back(std::make_unique<DeviceMat>(host.back()));
      // Frame 1: camera 0 delivered nothing.
      const bool missing = frame == 1 && i == 0;
      host_views.push_back(missing ? ImageView() : as_view(host.back()));
      gpu_host_views.push_back(missing ? ImageView() : as_view(host_for_gpu.back()));
      device_views.push_back(missing ? ImageView() : device.back()->view());
    }
    cpu.process(s.rig, 1, host_views);
    gpu_device.process(s.rig, 1, device_views);
    gpu_host.process(s.rig, 1, gpu_host_views);  // system memory: the CPU implementation
    const double d_device = max_abs_difference(cpu.corrections(), gpu_device.corrections());
    const double d_host = max_abs_difference(cpu.corrections(), gpu_host.corrections());
    EXPECT_LE(d_device, 1e-3);
    EXPECT_EQ(d_host, 0.0);
    for (int i = frame == 1 ? 1 : 0; i < 3; ++i) {
      const double psnr = testdata::psnr_rgb(device[std::size_t(i)]->download(), host[std::size_t(i)]);
      EXPECT_GE(psnr, 45.0) << "frame " << frame << " view " << i;
      EXPECT_EQ(cv::norm(host_for_gpu[std::size_t(i)], host[std::size_t(i)], cv::NORM_INF), 0.0);
      std::printf("COLOR missing-camera/system-memory frame %d view %d: PSNR CUDA vs CPU %.2f dB\n", frame, i, psnr);
    }
    // The missing camera's pixels are left alone.
    if (frame == 1) {
      EXPECT_EQ(cv::norm(device[0]->download(), camera_frame(s, 0, frame), cv::NORM_INF), 0.0);
    }
  }
#endif
}

// Not a pass/fail check: how long process() takes on three 1920x1080 views in device memory
// (the chain's budget for color + flow + blend is 1 ms per frame on an H100).
TEST(CudaColorCorrectorTiming, ThreeFullHdViews) {
  REQUIRE_CUDA();
#ifdef STITCH_HAVE_CUDA
  cv::Mat big;
  cv::resize(test_photo(), big, cv::Size(3840, 2560), 0, 0, cv::INTER_LINEAR);
  Rig rig;
  rig.reference = 1;
  std::vector<std::unique_ptr<DeviceMat>> device;
  std::vector<ImageView> views;
  for (int i = 0; i < 3; ++i) {
    Camera c;
    c.width = 1920;
    c.height = 1080;
    c.fx = c.fy = 1400.0;
    c.cx = (c.width - 1) * 0.5;
    c.cy = (c.height - 1) * 0.5;
    c.yaw_deg = (i - 1) * 25.0;
    rig.cameras.push_back(c);
    cv::Mat frame = big(cv::Rect(i * 900, 700, 1920, 1080)).clone();
    distort(frame, Eigen::Vector3d(0.9 + 0.1 * i, 1.0, 1.1 - 0.1 * i).asDiagonal());
    device.push_back(std::make_unique<DeviceMat>(frame));
    views.push_back(device.back()->view());
  }
  rig_compute_rough_homographies(rig);
  for (ColorMethod method : {ColorMethod::Matrix3D, ColorMethod::Gain}) {
    ColorCorrector gpu(Backend::Cuda);
    ColorOptions o;
    o.method = method;
    o.balance = true;
    gpu.set_options(o);
    std::vector<double> us;
    for (int frame = 0; frame < 23; ++frame) {
      const auto t0 = std::chrono::steady_clock::now();
      gpu.process(rig, 1, views);
      const double t = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
      if (frame >= 3) us.push_back(t);  // after the geometry upload and the first fits
    }
    std::sort(us.begin(), us.end());
    std::printf("COLOR timing %s balance=on, 3x1920x1080 device views: process() median %.1f us, min %.1f us\n",
                method_name(method), us[us.size() / 2], us.front());
  }
#endif
}
