#include "stitch/cuda/handoff.hpp"

#include <cuda_runtime_api.h>

#include <atomic>
#include <cstdlib>
#include <cstring>

#include "stitch/cuda/cuda_util.hpp"

namespace stitch {

struct CudaEventRelease {
  void operator()(CudaEventSlot* slot) const {
    if (slot->pool) {
      std::lock_guard<std::mutex> guard(slot->pool->lock_);
      slot->pool->free_.push_back(slot->event);
    } else if (slot->event) {
      cudaEventDestroy(static_cast<cudaEvent_t>(slot->event));
    }
    delete slot;
  }
};

std::shared_ptr<CudaEventPool> CudaEventPool::create() {
  return std::shared_ptr<CudaEventPool>(new CudaEventPool());
}

CudaEventPool::~CudaEventPool() {
  // Every event is back (each slot holds the pool). The driver finds an event's context from
  // the handle, so this needs no context current.
  for (void* e : free_) cudaEventDestroy(static_cast<cudaEvent_t>(e));
}

CudaEvent CudaEventPool::acquire() {
  void* event = nullptr;
  {
    std::lock_guard<std::mutex> guard(lock_);
    if (!free_.empty()) {
      event = free_.back();
      free_.pop_back();
    }
  }
  if (!event) {
    cudaEvent_t e = nullptr;
    STITCH_CUDA(cudaEventCreateWithFlags(&e, cudaEventDisableTiming));
    event = e;
  }
  auto* slot = new CudaEventSlot{event, shared_from_this()};
  return CudaEvent(slot, CudaEventRelease());
}

void cuda_event_sync(const CudaEvent& e) {
  if (e && e->event) STITCH_CUDA(cudaEventSynchronize(static_cast<cudaEvent_t>(e->event)));
}

void cuda_events_sync(const std::vector<CudaEvent>& events) {
  for (const CudaEvent& e : events) cuda_event_sync(e);
}

namespace {
std::atomic<int> g_host_sync{-1};
thread_local CudaHandoff* t_current = nullptr;
}  // namespace

bool cuda_host_sync() {
  const int v = g_host_sync.load(std::memory_order_relaxed);
  if (v >= 0) return v == 1;
  // Read at every frame (a getenv is cheap): a benchmark switches it between pipelines, and
  // the plugin holds its own copy of this library.
  const char* env = std::getenv("STITCH_CUDA_HOST_SYNC");
  return env && *env && std::strcmp(env, "0") != 0;
}

bool cuda_host_register(void* p, std::size_t bytes) {
  if (!p || !bytes) return false;
  if (cudaHostRegister(p, bytes, cudaHostRegisterDefault) != cudaSuccess) {
    cudaGetLastError();  // e.g. a page shared with another registration: stays pageable
    return false;
  }
  return true;
}

void cuda_host_unregister(void* p) {
  if (p && cudaHostUnregister(p) != cudaSuccess) cudaGetLastError();
}

void set_cuda_host_sync(bool on) { g_host_sync.store(on ? 1 : 0); }

CudaHandoff::CudaHandoff(std::shared_ptr<CudaEventPool> pool) : pool_(std::move(pool)), previous_(t_current) {
  t_current = this;
}

CudaHandoff::~CudaHandoff() { t_current = previous_; }

CudaHandoff* CudaHandoff::current() { return t_current; }

void CudaHandoff::wait_for(const CudaEvent& e) {
  if (!e) return;
  for (const CudaEvent& w : waits_)
    if (w == e) return;
  waits_.push_back(e);
}

void CudaHandoff::enter(void* stream) {
  for (const CudaEvent& e : waits_)
    STITCH_CUDA(cudaStreamWaitEvent(static_cast<cudaStream_t>(stream), static_cast<cudaEvent_t>(e->event), 0));
}

void CudaHandoff::leave(void* stream) {
  auto s = static_cast<cudaStream_t>(stream);
  if (!done_) {
    done_ = pool_->acquire();
  } else if (last_stream_ != stream) {
    STITCH_CUDA(cudaStreamWaitEvent(s, static_cast<cudaEvent_t>(done_->event), 0));
  }
  STITCH_CUDA(cudaEventRecord(static_cast<cudaEvent_t>(done_->event), s));
  last_stream_ = stream;
}

}  // namespace stitch
