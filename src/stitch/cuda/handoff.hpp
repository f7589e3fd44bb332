// Stream-ordered hand-off between stages (issue 17): instead of synchronising its stream
// before the next stage reads its output, a stage records a CUDA event and the next stage's
// stream waits on it (cudaStreamWaitEvent), so the host never waits between stages.
//
// The element installs a CudaHandoff on its thread around one frame's work, adds the events
// its inputs are still being written under (wait_for), and runs the core stage. The stage's
// CudaStream::enter() makes its stream wait on those events before it touches the inputs;
// CudaStream::leave(), where the stage used to synchronise, records the hand-off's event
// instead. Without a CudaHandoff on the thread (tests, benchmarks, STITCH_CUDA_HOST_SYNC=1),
// enter() does nothing and leave() synchronises as before.
//
// No CUDA headers here (the GStreamer layer includes it): streams and events are void*.
// Only built with STITCH_HAVE_CUDA.
#pragma once
#include <cstddef>
#include <memory>
#include <mutex>
#include <vector>

namespace stitch {

class CudaEventPool;

// One pooled CUDA event; it goes back to its pool when the last reference is dropped, so a
// frame allocates nothing once the pool holds as many events as frames are in flight.
struct CudaEventSlot {
  void* event = nullptr;  // cudaEvent_t
  std::shared_ptr<CudaEventPool> pool;
};
using CudaEvent = std::shared_ptr<CudaEventSlot>;

class CudaEventPool : public std::enable_shared_from_this<CudaEventPool> {
 public:
  static std::shared_ptr<CudaEventPool> create();
  ~CudaEventPool();
  // An event of the CUDA context current on this thread (made when the pool has none free).
  CudaEvent acquire();

 private:
  CudaEventPool() = default;
  friend struct CudaEventRelease;
  std::mutex lock_;
  std::vector<void*> free_;
};

// Blocks the host until `e`'s work is done (nothing for a null event).
void cuda_event_sync(const CudaEvent& e);
// The same, for several.
void cuda_events_sync(const std::vector<CudaEvent>& events);

// True when STITCH_CUDA_HOST_SYNC=1 (unless set_cuda_host_sync overrides it in this copy of the
// library): every stage synchronises its stream before handing its output on, as before.
bool cuda_host_sync();
void set_cuda_host_sync(bool on);

// Page-locks `bytes` of system memory at `p` for the context current on this thread, so that
// copies to and from the device run at full speed without a staging pass (false, with the
// memory left as it was, when the driver refuses). Undone by cuda_host_unregister.
bool cuda_host_register(void* p, std::size_t bytes);
void cuda_host_unregister(void* p);

class CudaHandoff {
 public:
  // Installs itself as this thread's hand-off (the previous one comes back in the destructor).
  explicit CudaHandoff(std::shared_ptr<CudaEventPool> pool);
  ~CudaHandoff();
  CudaHandoff(const CudaHandoff&) = delete;
  CudaHandoff& operator=(const CudaHandoff&) = delete;
  static CudaHandoff* current();

  // The stage's streams must wait on `e` before they read or write its data.
  void wait_for(const CudaEvent& e);
  const std::vector<CudaEvent>& waits() const { return waits_; }
  // Called by CudaStream: the stream waits on every event so far ...
  void enter(void* stream);
  // ... and records the stage's event after its work (on a second stream, after that stream
  // waited on the first record, so that the one event covers both).
  void leave(void* stream);
  // The stage's event: null when no stream left (nothing ran on the device).
  const CudaEvent& done() const { return done_; }

 private:
  std::shared_ptr<CudaEventPool> pool_;
  std::vector<CudaEvent> waits_;
  CudaEvent done_;
  void* last_stream_ = nullptr;
  CudaHandoff* previous_ = nullptr;
};

}  // namespace stitch
