// Host-side CUDA helpers for the core's CUDA stages: checked calls, owned device buffers, an
// owned stream. Only built with STITCH_HAVE_CUDA.
#pragma once
#include <cuda_runtime_api.h>

#include <cstddef>
#include <stdexcept>
#include <string>

#include "stitch/cuda/handoff.hpp"

namespace stitch {

// Every CUDA call goes through this: an error becomes an exception naming the call.
inline void cuda_check(cudaError_t e, const char* what) {
  if (e != cudaSuccess) {
    cudaGetLastError();  // clear a non-sticky error
    throw std::runtime_error(std::string("CUDA error in ") + what + ": " + cudaGetErrorString(e));
  }
}
#define STITCH_CUDA(call) ::stitch::cuda_check((call), #call)

class DeviceBuffer {
 public:
  DeviceBuffer() = default;
  explicit DeviceBuffer(std::size_t bytes) { resize(bytes); }
  DeviceBuffer(const DeviceBuffer&) = delete;
  DeviceBuffer& operator=(const DeviceBuffer&) = delete;
  DeviceBuffer(DeviceBuffer&& o) noexcept : ptr_(o.ptr_), bytes_(o.bytes_) { o.ptr_ = nullptr, o.bytes_ = 0; }
  DeviceBuffer& operator=(DeviceBuffer&& o) noexcept {
    std::swap(ptr_, o.ptr_);
    std::swap(bytes_, o.bytes_);
    return *this;
  }
  ~DeviceBuffer() {
    if (ptr_) cudaFree(ptr_);
  }
  // Grows only (no allocation per frame once the sizes are known).
  void resize(std::size_t bytes) {
    if (bytes <= bytes_) return;
    if (ptr_) cudaFree(ptr_);
    ptr_ = nullptr;
    bytes_ = 0;
    const cudaError_t e = cudaMalloc(&ptr_, bytes);
    if (e == cudaErrorMemoryAllocation) {
      cudaGetLastError();
      std::size_t free_bytes = 0, total = 0;
      cudaMemGetInfo(&free_bytes, &total);
      ptr_ = nullptr;
      throw std::runtime_error("out of GPU memory: cannot allocate " + std::to_string(bytes >> 20) + " MiB (" +
                               std::to_string(free_bytes >> 20) + " of " + std::to_string(total >> 20) +
                               " MiB free); use a smaller canvas or output, or backend=cpu");
    }
    cuda_check(e, "cudaMalloc");
    bytes_ = bytes;
  }
  uint8_t* data() const { return static_cast<uint8_t*>(ptr_); }
  std::size_t size() const { return bytes_; }

 private:
  void* ptr_ = nullptr;
  std::size_t bytes_ = 0;
};

class CudaStream {
 public:
  CudaStream() { STITCH_CUDA(cudaStreamCreateWithFlags(&s_, cudaStreamNonBlocking)); }
  CudaStream(const CudaStream&) = delete;
  CudaStream& operator=(const CudaStream&) = delete;
  ~CudaStream() {
    if (s_) cudaStreamDestroy(s_);
  }
  cudaStream_t get() const { return s_; }
  void sync() const { STITCH_CUDA(cudaStreamSynchronize(s_)); }
  // A stage's entry: with a CudaHandoff on this thread (handoff.hpp) the stream waits on the
  // events its inputs are written under; otherwise nothing (the producer synchronised).
  void enter() const {
    if (CudaHandoff* h = CudaHandoff::current()) h->enter(s_);
  }
  // A stage's exit, where its output is handed on: records the hand-off's event, or
  // synchronises without one (or with STITCH_CUDA_HOST_SYNC=1, which installs none).
  void leave() const {
    if (CudaHandoff* h = CudaHandoff::current())
      h->leave(s_);
    else
      sync();
  }

 private:
  cudaStream_t s_ = nullptr;
};

}  // namespace stitch
