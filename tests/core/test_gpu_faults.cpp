// GPU faults (issue 7): without a device backend=auto runs on the CPU and backend=cuda is a
// clear error; a canvas that does not fit in device memory is a clear error that names the
// sizes, and the device works again afterwards. Runs in CI (no device: the no-device test runs,
// the memory test skips) and on the GPU host (both run).
#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>
#include <opencv2/core.hpp>
#include <vector>

#include "cuda_test.hpp"
#include "stitch/blend/compositor.hpp"
#include "synthetic_rig.hpp"

using namespace stitch;

namespace {

// Composes two frames of a `w` x `h` rig shifted by half a frame with `backend`.
void compose_once(Backend backend, int w, int h) {
  const Rig rig = testdata::shifted_rig(2, w, h, w / 2);
  Compositor c(backend);
  c.prepare(rig, CompositorSettings{});
  std::vector<cv::Mat> frames = {cv::Mat(h, w, CV_8UC4, cv::Scalar(200, 100, 50, 255)),
                                 cv::Mat(h, w, CV_8UC4, cv::Scalar(200, 100, 50, 255))};
  std::vector<ImageView> views;
  for (auto& f : frames) views.push_back(ImageView{f.data, f.step, f.cols, f.rows});
  cv::Mat out(c.geometry().height, c.geometry().width, CV_8UC4, cv::Scalar(0, 0, 0, 0));
  c.compose(views, ImageView{out.data, out.step, out.cols, out.rows});
  const cv::Scalar mean = cv::mean(out);
  if (std::abs(mean[0] - 200) > 2) throw std::logic_error("wrong panorama");
}

}  // namespace

// No device (hidden with CUDA_VISIBLE_DEVICES, before CUDA starts: in a fresh child process).
TEST(GpuFaultsDeathTest, NoDeviceMeansCpuOrAClearError) {
  GTEST_FLAG_SET(death_test_style, "threadsafe");
  EXPECT_EXIT(
      {
        setenv("CUDA_VISIBLE_DEVICES", "", 1);
        bool ok = !cuda_device_available() && resolve_backend(Backend::Auto, true) == Backend::Cpu;
        try {
          resolve_backend(Backend::Cuda, true);
          ok = false;
        } catch (const std::runtime_error& e) {
          ok = ok && std::strstr(e.what(), "no CUDA device") != nullptr;
        }
        Compositor auto_backend(Backend::Auto);
        ok = ok && auto_backend.backend() == Backend::Cpu;
        compose_once(Backend::Auto, 64, 48);
        std::exit(ok ? 0 : 1);
      },
      ::testing::ExitedWithCode(0), "");
}

#ifdef STITCH_HAVE_CUDA
// Fills the device, then asks for a 6144x4096 panorama on it: the error names the problem
// (out of GPU memory, the sizes) instead of crashing; with the memory back it composes.
TEST(GpuFaults, CanvasTooLargeForTheDeviceIsAClearError) {
  REQUIRE_CUDA_FOR("the out-of-memory path");
  std::size_t free_bytes = 0, total = 0;
  ASSERT_EQ(cudaMemGetInfo(&free_bytes, &total), cudaSuccess);
  std::vector<void*> filler;
  std::size_t filled = 0;
  for (std::size_t chunk : {std::size_t(256) << 20, std::size_t(16) << 20}) {  // leave < 16 MiB free
    void* p = nullptr;
    while (cudaMalloc(&p, chunk) == cudaSuccess) {
      filler.push_back(p);
      filled += chunk;
    }
    cudaGetLastError();
  }
  std::string error;
  try {
    compose_once(Backend::Cuda, 4096, 4096);
  } catch (const std::exception& e) {
    error = e.what();
  }
  for (void* p : filler) cudaFree(p);
  EXPECT_GE(filler.size(), 1u);
  std::printf("GPUFAULT filled %zu MiB of %zu MiB; error: %s\n", filled >> 20, total >> 20,
              error.c_str());
  EXPECT_NE(error.find("out of GPU memory"), std::string::npos) << "error: " << error;
  EXPECT_NE(error.find("MiB"), std::string::npos) << "error: " << error;
  // the device is usable again (the error was not sticky)
  EXPECT_NO_THROW(compose_once(Backend::Cuda, 640, 480));
}
#endif
