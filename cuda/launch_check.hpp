// Every kernel launch is checked: a launch error becomes an exception naming the kernel.
#pragma once
#include <cuda_runtime_api.h>

#include <stdexcept>
#include <string>

namespace stitch_cuda {

inline void check_launch(const char* what) {
  const cudaError_t e = cudaGetLastError();
  if (e != cudaSuccess) throw std::runtime_error(std::string(what) + ": " + cudaGetErrorString(e));
}

}  // namespace stitch_cuda
