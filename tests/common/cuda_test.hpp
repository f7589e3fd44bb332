// What the CUDA tests share: skipping (and saying so) without a device, and an RGBA image in
// device memory. Header-only: these binaries go to the GPU host and link no test_data.cpp.
#pragma once
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "stitch/backend.hpp"
#include "stitch/image.hpp"

#ifdef STITCH_HAVE_CUDA
#include <cuda_runtime_api.h>
#endif

#include <cstdio>
#include <cstdlib>

// meson's SKIP: a binary in which every test that ran was skipped (no device) and none failed
// exits 77, so that `meson test` shows SKIP instead of OK. Checked at exit, after gtest has
// printed its summary and written its reports. tests/meson.build runs the binaries that also
// hold device-free tests twice: those tests alone, and the device ones alone.
namespace testdata {
inline void exit_77_when_all_skipped() {
  const ::testing::UnitTest* u = ::testing::UnitTest::GetInstance();
  if (u->test_to_run_count() > 0 && u->failed_test_count() == 0 && u->successful_test_count() == 0 &&
      u->skipped_test_count() > 0) {
    std::fflush(stdout);
    std::fflush(stderr);
    std::_Exit(77);
  }
}
// The UnitTest singleton first: it is then destroyed after the handler has run.
inline const bool kExit77Registered =
    (::testing::UnitTest::GetInstance(), std::atexit(exit_77_when_all_skipped) == 0);
}  // namespace testdata

// Skips the test without a CUDA device (or in a build without the toolkit); `what` names the
// stage left unchecked.
#define REQUIRE_CUDA_FOR(what)                                                                   \
  do {                                                                                          \
    if (!stitch::cuda_device_available())                                                       \
      GTEST_SKIP() << "no CUDA device here (or a build without the CUDA toolkit): " what        \
                      " is not checked";                                                        \
  } while (0)

namespace testdata {

#ifdef STITCH_HAVE_CUDA
// An RGBA image in device memory, copied from / to a cv::Mat.
struct DeviceMat {
  uint8_t* ptr = nullptr;
  std::size_t pitch = 0;
  int width = 0, height = 0;
  explicit DeviceMat(const cv::Mat& m) : width(m.cols), height(m.rows) {
    void* p = nullptr;
    EXPECT_EQ(cudaMallocPitch(&p, &pitch, std::size_t(width) * 4, std::size_t(height)), cudaSuccess);
    ptr = static_cast<uint8_t*>(p);
    EXPECT_EQ(cudaMemcpy2D(ptr, pitch, m.data, m.step, std::size_t(width) * 4, std::size_t(height),
                           cudaMemcpyHostToDevice),
              cudaSuccess);
  }
  DeviceMat(const DeviceMat&) = delete;
  ~DeviceMat() { cudaFree(ptr); }
  stitch::ImageView view() const {
    stitch::ImageView v;
    v.data = ptr;
    v.pitch = pitch;
    v.width = width;
    v.height = height;
    v.on_device = true;
    return v;
  }
  cv::Mat download() const {
    cv::Mat m(height, width, CV_8UC4);
    EXPECT_EQ(cudaMemcpy2D(m.data, m.step, ptr, pitch, std::size_t(width) * 4, std::size_t(height),
                           cudaMemcpyDeviceToHost),
              cudaSuccess);
    return m;
  }
};
#endif

}  // namespace testdata
