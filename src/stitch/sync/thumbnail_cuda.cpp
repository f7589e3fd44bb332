#include <cuda_runtime_api.h>

#include <cstring>
#include <vector>

#include "../../../cuda/sync/thumbnail_kernels.hpp"
#include "stitch/cuda/cuda_util.hpp"
#include "stitch/sync/thumbnail.hpp"

namespace stitch::sync {

namespace {
constexpr std::size_t kCells = std::size_t(kThumbnailW) * kThumbnailH;
}

// One view's thumbnail in flight: device cells, their page-locked copy, the event after the copy.
struct ThumbnailSlot {
  DeviceBuffer cells{sizeof(float) * kCells};
  float* host = nullptr;
  cudaEvent_t done = nullptr;
  bool pending = false;
  ThumbnailSlot() {
    STITCH_CUDA(cudaMallocHost(reinterpret_cast<void**>(&host), sizeof(float) * kCells));
    const cudaError_t e = cudaEventCreateWithFlags(&done, cudaEventDisableTiming);
    if (e != cudaSuccess) {
      cudaFreeHost(host);
      cuda_check(e, "cudaEventCreateWithFlags");
    }
  }
  ThumbnailSlot(const ThumbnailSlot&) = delete;
  ThumbnailSlot& operator=(const ThumbnailSlot&) = delete;
  ~ThumbnailSlot() {
    if (done) cudaEventDestroy(done);
    if (host) cudaFreeHost(host);
  }
};

struct FrameThumbnailerCuda::Impl {
  CudaStream stream;
  std::vector<std::unique_ptr<ThumbnailSlot>> slots;
  std::unique_ptr<ThumbnailSlot> own;  // thumbnail()'s
  ~Impl() { cudaStreamSynchronize(stream.get()); }  // the kernels may still read the frames
  ThumbnailSlot* find(int slot) const {
    return slot >= 0 && std::size_t(slot) < slots.size() ? slots[std::size_t(slot)].get() : nullptr;
  }
  void queue(ThumbnailSlot& s, const uint8_t* device_data, int width, int height, std::size_t pitch,
             int bytes_per_pixel, int channel) {
    if (s.pending) STITCH_CUDA(cudaEventSynchronize(s.done));  // its host copy is about to be overwritten
    s.pending = false;
    stream.enter();  // after the frame's writers (stream-ordered hand-off)
    stitch_cuda::launch_thumbnail(device_data, width, height, pitch, bytes_per_pixel, channel,
                                  reinterpret_cast<float*>(s.cells.data()), stream.get());
    STITCH_CUDA(cudaMemcpyAsync(s.host, s.cells.data(), sizeof(float) * kCells, cudaMemcpyDeviceToHost, stream.get()));
    STITCH_CUDA(cudaEventRecord(s.done, stream.get()));
    s.pending = true;
  }
  static void collect(ThumbnailSlot& s, float* out) {
    s.pending = false;
    STITCH_CUDA(cudaEventSynchronize(s.done));
    std::memcpy(out, s.host, sizeof(float) * kCells);
  }
};

FrameThumbnailerCuda::FrameThumbnailerCuda() : impl_(std::make_unique<Impl>()) {}
FrameThumbnailerCuda::~FrameThumbnailerCuda() = default;

void FrameThumbnailerCuda::submit(int slot, const uint8_t* device_data, int width, int height, std::size_t pitch,
                                  int bytes_per_pixel, int channel) {
  if (slot < 0) throw std::runtime_error("thumbnail: negative slot");
  while (impl_->slots.size() <= std::size_t(slot)) impl_->slots.push_back(std::make_unique<ThumbnailSlot>());
  impl_->queue(*impl_->slots[std::size_t(slot)], device_data, width, height, pitch, bytes_per_pixel, channel);
}

bool FrameThumbnailerCuda::pending(int slot) const {
  const ThumbnailSlot* s = impl_->find(slot);
  return s && s->pending;
}

bool FrameThumbnailerCuda::ready(int slot) const {
  const ThumbnailSlot* s = impl_->find(slot);
  if (!s || !s->pending) return false;
  const cudaError_t e = cudaEventQuery(s->done);
  if (e == cudaErrorNotReady) {
    cudaGetLastError();
    return false;
  }
  cuda_check(e, "cudaEventQuery");
  return true;
}

bool FrameThumbnailerCuda::take(int slot, float* out) {
  ThumbnailSlot* s = impl_->find(slot);
  if (!s || !s->pending) return false;
  Impl::collect(*s, out);
  return true;
}

void FrameThumbnailerCuda::thumbnail(const uint8_t* device_data, int width, int height, std::size_t pitch,
                                     int bytes_per_pixel, int channel, float* out) {
  if (!impl_->own) impl_->own = std::make_unique<ThumbnailSlot>();
  impl_->queue(*impl_->own, device_data, width, height, pitch, bytes_per_pixel, channel);
  Impl::collect(*impl_->own, out);
}

}  // namespace stitch::sync
