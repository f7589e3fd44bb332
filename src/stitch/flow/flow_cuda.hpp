// Dense optical flow on the GPU (compiled only with STITCH_HAVE_CUDA): our own pyramidal
// implementation, run on a batch of image pairs at once (every overlap, both directions) so
// that a frame costs one set of launches, not one per pair.
#pragma once
#include <cuda_runtime_api.h>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "stitch/flow/flow.hpp"

namespace stitch {

// One flow to compute: from -> to, 8-bit gray, both width x height, device memory.
struct DeviceFlowTask {
  const uint8_t* from = nullptr;
  const uint8_t* to = nullptr;
  std::size_t gray_pitch = 0;  // bytes per row of both gray images
  int width = 0, height = 0;
  float* flow = nullptr;       // interleaved (u, v) floats, device; in/out
  std::size_t flow_pitch = 0;  // bytes per row of `flow`
  bool use_initial = false;    // `flow` holds last frame's estimate: start from it
};

class CudaDenseFlow {
 public:
  virtual ~CudaDenseFlow() = default;
  // Computes every task's flow (flow(y, x) = displacement taking pixel (x, y) of `from` to its
  // match in `to`), enqueued on `stream`; no host synchronisation. Flat or black inputs give
  // zero flow, never NaN; displacements stay inside the image. Working buffers are pooled:
  // no allocation once the task sizes repeat.
  virtual void compute(const std::vector<DeviceFlowTask>& tasks, cudaStream_t stream) = 0;
  static std::unique_ptr<CudaDenseFlow> create(FlowQuality quality);
};

// DenseFlow (host cv::Mat interface) over CudaDenseFlow: uploads, computes, downloads. Used by
// DenseFlow::create(Backend::Cuda, ...) and the CUDA-vs-CPU tests.
std::unique_ptr<DenseFlow> make_dense_flow_cuda(FlowQuality quality);

}  // namespace stitch
