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
