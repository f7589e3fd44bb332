// The GPU dense flow (pyramidal dense Lucas-Kanade, CudaDenseFlow) against ground truth and
// against the CPU DIS flow on a real photo; flat inputs, batches, the initial flow and the
// image bounds. Needs a CUDA device: without one (or in a build without the toolkit) every
// test skips and says why. Figures are printed with a "FLOW" prefix for the logs.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "cuda_test.hpp"
#include "ppm.hpp"
#include "stitch/backend.hpp"
#include "stitch/flow/flow.hpp"

#ifdef STITCH_HAVE_CUDA
#include <cuda_runtime_api.h>

#include "stitch/cuda/cuda_util.hpp"
#include "stitch/flow/flow_cuda.hpp"
#endif

#include "flow_fields.hpp"

using namespace stitch;

namespace {

#define REQUIRE_CUDA() REQUIRE_CUDA_FOR("the CUDA dense flow")

const FlowQuality kQualities[] = {FlowQuality::Fast, FlowQuality::Medium, FlowQuality::Fine};

const char* quality_name(FlowQuality q) {
  return q == FlowQuality::Fast ? "fast" : q == FlowQuality::Medium ? "medium" : "fine";
}

// data/photos/boat1_1600.jpg, decoded at build time (STITCH_TEST_PPM), as gray of `size`.
cv::Mat gray_photo(cv::Size size) {
  const cv::Mat rgba = testdata::test_photo();
  cv::Mat g;
  cv::cvtColor(rgba, g, cv::COLOR_RGBA2GRAY);
  cv::resize(g, g, size, 0, 0, cv::INTER_AREA);
  return g;
}

// A smooth field (a few pixels, varying over the image) like parallax in an overlap; the same
using testdata::displace;
using testdata::smooth_field;

// Borders have no match: errors are measured 16 px inside.
cv::Mat inner_mask(cv::Size size) {
  cv::Mat mask(size, CV_8U, cv::Scalar(0));
  mask(cv::Rect(16, 16, size.width - 32, size.height - 32)).setTo(255);
  return mask;
}

// Every displacement finite and landing inside the image.
void expect_inside(const cv::Mat& f) {
  ASSERT_EQ(f.type(), CV_32FC2);
  ASSERT_TRUE(cv::checkRange(f));
  for (int y = 0; y < f.rows; ++y)
    for (int x = 0; x < f.cols; ++x) {
      const cv::Vec2f d = f.at<cv::Vec2f>(y, x);
      ASSERT_GE(x + d[0], -1e-3) << x << "," << y;
      ASSERT_LE(x + d[0], f.cols - 1 + 1e-3) << x << "," << y;
      ASSERT_GE(y + d[1], -1e-3) << x << "," << y;
      ASSERT_LE(y + d[1], f.rows - 1 + 1e-3) << x << "," << y;
    }
}

#ifdef STITCH_HAVE_CUDA
// One pair in device memory with padded pitches (so that pitch != row size is exercised).
struct DevicePair {
  DeviceBuffer gray, field;
  DeviceFlowTask task;
  DevicePair(const cv::Mat& from, const cv::Mat& to, const cv::Mat& initial) {
    const int w = from.cols, h = from.rows;
    task.gray_pitch = std::size_t(w) + 13;
    task.flow_pitch = (std::size_t(w) + 5) * 2 * sizeof(float);
    gray.resize(2 * task.gray_pitch * std::size_t(h));
    field.resize(task.flow_pitch * std::size_t(h));
    STITCH_CUDA(cudaMemcpy2D(gray.data(), task.gray_pitch, from.data, from.step, std::size_t(w), std::size_t(h),
                             cudaMemcpyHostToDevice));
    uint8_t* to_ptr = gray.data() + task.gray_pitch * std::size_t(h);
    STITCH_CUDA(cudaMemcpy2D(to_ptr, task.gray_pitch, to.data, to.step, std::size_t(w), std::size_t(h),
                             cudaMemcpyHostToDevice));
    if (!initial.empty())
      STITCH_CUDA(cudaMemcpy2D(field.data(), task.flow_pitch, initial.data, initial.step, std::size_t(w) * 8,
                               std::size_t(h), cudaMemcpyHostToDevice));
    task.from = gray.data();
    task.to = to_ptr;
    task.width = w;
    task.height = h;
    task.flow = reinterpret_cast<float*>(field.data());
    task.use_initial = !initial.empty();
  }
  cv::Mat download() const {
    cv::Mat f(task.height, task.width, CV_32FC2);
    STITCH_CUDA(cudaMemcpy2D(f.data, f.step, field.data(), task.flow_pitch, std::size_t(task.width) * 8,
                             std::size_t(task.height), cudaMemcpyDeviceToHost));
    return f;
  }
};
#endif

}  // namespace

TEST(CudaFlow, KnownSmoothDisplacementMatchesCpuDis) {
  REQUIRE_CUDA();
  for (cv::Size size : {cv::Size(480, 360), cv::Size(250, 540)}) {
    const cv::Mat from = gray_photo(size);
    const cv::Mat field = smooth_field(size, 4.0);  // flow from -> to is the field itself
    const cv::Mat to = displace(from, field);
    const cv::Mat mask = inner_mask(size);
    for (FlowQuality q : kQualities) {
      auto gpu = DenseFlow::create(Backend::Cuda, FlowAlgorithm::Dis, q);
      auto cpu = DenseFlow::create(Backend::Cpu, FlowAlgorithm::Dis, q);
      ASSERT_EQ(gpu->backend(), Backend::Cuda);
      cv::Mat fg, fc;
      gpu->compute(from, to, fg, false);  // first call: allocations, module load
      const auto t0 = std::chrono::steady_clock::now();
      gpu->compute(from, to, fg, false);
      const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      cpu->compute(from, to, fc, false);
      expect_inside(fg);
      const double epe_gpu = median_endpoint_error(fg, field, mask);
      const double epe_cpu = median_endpoint_error(fc, field, mask);
      const double gpu_vs_cpu = median_endpoint_error(fg, fc, mask);
      std::printf("FLOW smooth field %dx%d %s: median EPE cuda %.3f px, cpu DIS %.3f px, cuda vs cpu %.3f px "
                  "(cuda %.2f ms with upload/download)\n",
                  size.width, size.height, quality_name(q), epe_gpu, epe_cpu, gpu_vs_cpu, ms);
      EXPECT_LT(epe_gpu, 0.5) << quality_name(q);
      EXPECT_LE(std::fabs(epe_gpu - epe_cpu), 0.3) << quality_name(q);
    }
  }
}

TEST(CudaFlow, BrightnessDifferenceBetweenViewsIsIgnored) {
  REQUIRE_CUDA();
  // Two cameras rarely expose alike: `to` is darker in contrast and brighter in level. DIS
  // normalises its patches' means; the GPU flow estimates a brightness offset per window.
  const cv::Mat from = gray_photo(cv::Size(480, 360));
  const cv::Mat field = smooth_field(from.size(), 4.0);
  cv::Mat to;
  displace(from, field).convertTo(to, -1, 0.9, 12.0);
  const cv::Mat mask = inner_mask(from.size());
  for (FlowQuality q : kQualities) {
    auto gpu = DenseFlow::create(Backend::Cuda, FlowAlgorithm::Dis, q);
    auto cpu = DenseFlow::create(Backend::Cpu, FlowAlgorithm::Dis, q);
    cv::Mat fg, fc;
    gpu->compute(from, to, fg, false);
    cpu->compute(from, to, fc, false);
    const double epe_gpu = median_endpoint_error(fg, field, mask), epe_cpu = median_endpoint_error(fc, field, mask);
    std::printf("FLOW brightness x0.9 +12 %s: median EPE cuda %.3f px, cpu DIS %.3f px\n", quality_name(q), epe_gpu,
                epe_cpu);
    EXPECT_LT(epe_gpu, 0.5) << quality_name(q);
    EXPECT_LE(epe_gpu, epe_cpu + 0.1) << quality_name(q);
  }
}

TEST(CudaFlow, FlatAndBlackImagesGiveExactlyZero) {
  REQUIRE_CUDA();
  const cv::Mat textured = gray_photo(cv::Size(160, 120));
  const cv::Mat nonzero_initial(textured.size(), CV_32FC2, cv::Scalar(2.5, -1.5));
  for (int level : {0, 128, 255}) {
    const cv::Mat flat(textured.size(), CV_8U, cv::Scalar(level));
    // Both flat, and one flat (the CPU flows give zero when either image is flat).
    const std::pair<cv::Mat, cv::Mat> pairs[] = {{flat, flat.clone()}, {flat, textured}, {textured, flat}};
    for (const auto& ab : pairs)
      for (FlowQuality q : kQualities)
        for (bool use_initial : {false, true}) {
          auto gpu = DenseFlow::create(Backend::Cuda, FlowAlgorithm::Dis, q);
          cv::Mat f = use_initial ? nonzero_initial.clone() : cv::Mat();
          gpu->compute(ab.first, ab.second, f, use_initial);
          ASSERT_EQ(f.type(), CV_32FC2);
          EXPECT_TRUE(cv::checkRange(f));
          EXPECT_EQ(cv::countNonZero(f.reshape(1)), 0)
              << "level " << level << ", " << quality_name(q) << ", initial " << use_initial;
        }
  }
}

TEST(CudaFlow, IdenticalImagesGiveNearZeroFlow) {
  REQUIRE_CUDA();
  const cv::Mat img = gray_photo(cv::Size(320, 240));
  auto gpu = DenseFlow::create(Backend::Cuda, FlowAlgorithm::Dis, FlowQuality::Medium);
  cv::Mat f;
  gpu->compute(img, img, f, false);
  const double epe = median_endpoint_error(f, cv::Mat::zeros(f.size(), CV_32FC2));
  std::printf("FLOW identical images: median |flow| %.4f px\n", epe);
  EXPECT_LT(epe, 0.05);
}

#ifdef STITCH_HAVE_CUDA
TEST(CudaFlow, BatchEqualsOneByOne) {
  REQUIRE_CUDA();
  // Different sizes (and so pyramid depths) and one pair that starts from a previous field.
  const cv::Size sizes[] = {cv::Size(480, 360), cv::Size(250, 540), cv::Size(97, 61)};
  std::vector<cv::Mat> from, to, initial;
  for (int i = 0; i < 3; ++i) {
    from.push_back(gray_photo(sizes[i]));
    const cv::Mat field = smooth_field(sizes[i], 3.0 + i);
    to.push_back(displace(from.back(), field));
    initial.push_back(i == 1 ? cv::Mat(field * 0.8) : cv::Mat());
  }
  for (FlowQuality q : kQualities) {
    CudaStream stream;
    auto flow = CudaDenseFlow::create(q);
    std::vector<std::unique_ptr<DevicePair>> batch, single;
    std::vector<DeviceFlowTask> tasks;
    for (int i = 0; i < 3; ++i) {
      batch.push_back(std::make_unique<DevicePair>(from[i], to[i], initial[i]));
      single.push_back(std::make_unique<DevicePair>(from[i], to[i], initial[i]));
      tasks.push_back(batch.back()->task);
    }
    flow->compute(tasks, stream.get());
    for (int i = 0; i < 3; ++i) flow->compute({single[std::size_t(i)]->task}, stream.get());
    stream.sync();
    for (int i = 0; i < 3; ++i) {
      const cv::Mat a = batch[std::size_t(i)]->download(), b = single[std::size_t(i)]->download();
      expect_inside(a);
      const double diff = cv::norm(a, b, cv::NORM_INF);
      std::printf("FLOW batch vs one by one, %s, pair %d (%dx%d%s): max |diff| %.2e\n", quality_name(q), i,
                  sizes[i].width, sizes[i].height, initial[i].empty() ? "" : ", initial", diff);
      EXPECT_LE(diff, 1e-5) << quality_name(q) << " pair " << i;
    }
  }
}

TEST(CudaFlow, BatchTimingOfFourOverlaps) {
  REQUIRE_CUDA();
  // The chain's case: 4 flows of ~250x540 (two overlaps, both directions, half resolution).
  const cv::Size size(250, 540);
  const cv::Mat from = gray_photo(size), field = smooth_field(size, 4.0), to = displace(from, field);
  for (FlowQuality q : kQualities)
    for (bool use_initial : {false, true}) {
      CudaStream stream;
      auto flow = CudaDenseFlow::create(q);
      std::vector<std::unique_ptr<DevicePair>> pairs;
      std::vector<DeviceFlowTask> tasks;
      for (int i = 0; i < 4; ++i) {
        pairs.push_back(std::make_unique<DevicePair>(i % 2 ? to : from, i % 2 ? from : to, cv::Mat()));
        tasks.push_back(pairs.back()->task);
      }
      flow->compute(tasks, stream.get());  // allocations; later runs refine the previous field
      for (auto& t : tasks) t.use_initial = use_initial;
      cudaEvent_t start, stop;
      STITCH_CUDA(cudaEventCreate(&start));
      STITCH_CUDA(cudaEventCreate(&stop));
      const int runs = 50;
      STITCH_CUDA(cudaEventRecord(start, stream.get()));
      for (int r = 0; r < runs; ++r) flow->compute(tasks, stream.get());
      STITCH_CUDA(cudaEventRecord(stop, stream.get()));
      STITCH_CUDA(cudaEventSynchronize(stop));
      float ms = 0.f;
      STITCH_CUDA(cudaEventElapsedTime(&ms, start, stop));
      cudaEventDestroy(start);
      cudaEventDestroy(stop);
      const double epe = median_endpoint_error(pairs[0]->download(), field, inner_mask(size));
      std::printf("FLOW timing 4 x %dx%d %s%s: %.1f us per batch (median EPE %.3f px)\n", size.width, size.height,
                  quality_name(q), use_initial ? " (initial flow)" : "", 1000.0 * ms / runs, epe);
      EXPECT_LT(epe, 0.5);
    }
}
#endif

TEST(CudaFlow, InitialFlowIsNoWorseThanZero) {
  REQUIRE_CUDA();
  const cv::Mat from = gray_photo(cv::Size(480, 360));
  const cv::Mat field = smooth_field(from.size(), 4.0), to = displace(from, field);
  const cv::Mat mask = inner_mask(from.size());
  for (FlowQuality q : kQualities) {
    auto gpu = DenseFlow::create(Backend::Cuda, FlowAlgorithm::Dis, q);
    cv::Mat from_zero, from_truth = field.clone();
    gpu->compute(from, to, from_zero, false);
    gpu->compute(from, to, from_truth, true);
    expect_inside(from_truth);
    const double e0 = median_endpoint_error(from_zero, field, mask);
    const double e1 = median_endpoint_error(from_truth, field, mask);
    std::printf("FLOW initial flow %s: median EPE from zero %.3f px, from the true field %.3f px\n", quality_name(q),
                e0, e1);
    EXPECT_LE(e1, e0 + 0.01) << quality_name(q);
  }
}

TEST(CudaFlow, TranslationIsRecovered) {
  REQUIRE_CUDA();
  const cv::Mat from = gray_photo(cv::Size(480, 360));
  const double tx = 3.5, ty = -2.25;
  const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, tx, 0, 1, ty);
  cv::Mat to;
  cv::warpAffine(from, to, shift, from.size(), cv::INTER_CUBIC, cv::BORDER_REFLECT);
  const cv::Mat mask = inner_mask(from.size());
  for (FlowQuality q : kQualities) {
    auto gpu = DenseFlow::create(Backend::Cuda, FlowAlgorithm::Dis, q);
    cv::Mat f;
    gpu->compute(from, to, f, false);
    std::vector<float> us, vs;
    for (int y = 0; y < f.rows; ++y)
      for (int x = 0; x < f.cols; ++x)
        if (mask.at<uint8_t>(y, x)) {
          us.push_back(f.at<cv::Vec2f>(y, x)[0]);
          vs.push_back(f.at<cv::Vec2f>(y, x)[1]);
        }
    std::nth_element(us.begin(), us.begin() + long(us.size() / 2), us.end());
    std::nth_element(vs.begin(), vs.begin() + long(vs.size() / 2), vs.end());
    const double mu = us[us.size() / 2], mv = vs[vs.size() / 2];
    const double err = std::hypot(mu - tx, mv - ty);
    const double epe = median_endpoint_error(f, cv::Mat(f.size(), CV_32FC2, cv::Scalar(tx, ty)), mask);
    std::printf("FLOW translation (%.2f, %.2f) %s: median flow (%.3f, %.3f), off by %.3f px; median EPE %.3f px\n",
                tx, ty, quality_name(q), mu, mv, err, epe);
    EXPECT_LE(err, 0.3) << quality_name(q);
  }
}

TEST(CudaFlow, FlowNeverPointsOutsideTheImage) {
  REQUIRE_CUDA();
  const cv::Mat from = gray_photo(cv::Size(200, 150));
  cv::Mat shifted;
  const cv::Mat M = (cv::Mat_<double>(2, 3) << 1, 0, 12, 0, 1, -7);
  cv::warpAffine(from, shifted, M, from.size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  for (FlowQuality q : kQualities) {
    auto gpu = DenseFlow::create(Backend::Cuda, FlowAlgorithm::Dis, q);
    cv::Mat f;
    gpu->compute(from, shifted, f, false);
    expect_inside(f);
    // A wild initial field is brought inside too.
    cv::Mat wild(from.size(), CV_32FC2, cv::Scalar(500.f, -500.f));
    wild.at<cv::Vec2f>(3, 4) = {std::nanf(""), 1.f};
    gpu->compute(from, shifted, wild, true);
    expect_inside(wild);
  }
}
