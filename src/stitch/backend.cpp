#include "stitch/backend.hpp"

#include <stdexcept>

#ifdef STITCH_HAVE_CUDA
#include <cuda_runtime_api.h>
#endif

namespace stitch {

bool cuda_device_available() {
#ifdef STITCH_HAVE_CUDA
  int count = 0;
  if (cudaGetDeviceCount(&count) != cudaSuccess) {
    cudaGetLastError();  // clear the sticky error so later calls are not poisoned
    return false;
  }
  return count > 0;
#else
  return false;
#endif
}

Backend resolve_backend(Backend requested, bool stage_has_cuda) {
  if (requested == Backend::Cpu) return Backend::Cpu;
#ifndef STITCH_HAVE_CUDA
  stage_has_cuda = false;
#endif
  if (requested == Backend::Auto) return stage_has_cuda && cuda_device_available() ? Backend::Cuda : Backend::Cpu;
  if (!stage_has_cuda)
    throw std::runtime_error("backend=cuda requested, but this build has no CUDA implementation of this stage");
  if (!cuda_device_available())
    throw std::runtime_error("backend=cuda requested, but no CUDA device could be opened");
  return Backend::Cuda;
}

const char* backend_name(Backend b) {
  switch (b) {
    case Backend::Auto: return "auto";
    case Backend::Cpu: return "cpu";
    case Backend::Cuda: return "cuda";
  }
  return "?";
}

}  // namespace stitch
