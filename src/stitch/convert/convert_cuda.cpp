#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <vector>

#include <opencv2/core/utility.hpp>

#include "../../../cuda/convert/convert_kernels.hpp"
#include "stitch/convert/convert_internal.hpp"
#include "stitch/cuda/cuda_util.hpp"

namespace stitch {
namespace {

cudaMemcpyKind copy_kind(bool src_on_device, bool dst_on_device) {
  if (src_on_device) return dst_on_device ? cudaMemcpyDeviceToDevice : cudaMemcpyDeviceToHost;
  return dst_on_device ? cudaMemcpyHostToDevice : cudaMemcpyHostToHost;
}

// cudaMemcpy2DAsync, as one linear copy when both sides have the same pitch: a strided copy
// of narrow rows (a 1080p I420 chroma plane: 960-byte rows) moves far below the link's rate.
cudaError_t copy_2d_async(void* dst, std::size_t dst_pitch, const void* src, std::size_t src_pitch, std::size_t width,
                          std::size_t height, cudaMemcpyKind kind, cudaStream_t stream) {
  if (height > 0 && dst_pitch == src_pitch && width <= src_pitch)
    return cudaMemcpyAsync(dst, src, src_pitch * (height - 1) + width, kind, stream);
  return cudaMemcpy2DAsync(dst, dst_pitch, src, src_pitch, width, height, kind, stream);
}

// Page-locked staging for frames in system memory: a ring of slots that only grow, each reused
// once the upload from it is done (an event per slot). A copy from pageable memory would make
// the runtime synchronise the stream first and stage it itself; from a slot the upload is a
// true asynchronous DMA, so the stream-ordered chain keeps going (issue 17).
class PinnedRing {
 public:
  PinnedRing() = default;
  PinnedRing(const PinnedRing&) = delete;
  PinnedRing& operator=(const PinnedRing&) = delete;
  ~PinnedRing() {
    for (Slot& s : slots_) {
      if (s.event) cudaEventDestroy(s.event);
      if (s.data) cudaFreeHost(s.data);
    }
  }
  // A slot of at least `bytes`; done(stream) after the uploads from it are queued.
  uint8_t* take(std::size_t bytes) {
    // The next slot whose last upload is done; a new slot rather than a wait, up to a bound.
    std::size_t k = next_;
    if (slots_.empty() || (slots_[k].used && cudaEventQuery(slots_[k].event) == cudaErrorNotReady)) {
      cudaGetLastError();
      if (slots_.size() < kMaxSlots) {
        slots_.insert(slots_.begin() + std::ptrdiff_t(k), Slot());
        STITCH_CUDA(cudaEventCreateWithFlags(&slots_[k].event, cudaEventDisableTiming));
      } else {
        STITCH_CUDA(cudaEventSynchronize(slots_[k].event));
      }
    }
    Slot& s = slots_[k];
    if (s.bytes < bytes) {
      if (s.used) STITCH_CUDA(cudaEventSynchronize(s.event));
      if (s.data) cudaFreeHost(s.data);
      s.data = nullptr;
      s.bytes = 0;
      STITCH_CUDA(cudaMallocHost(reinterpret_cast<void**>(&s.data), bytes));
      s.bytes = bytes;
    }
    current_ = k;
    next_ = (k + 1) % slots_.size();
    return s.data;
  }
  void done(cudaStream_t stream) {
    Slot& s = slots_[current_];
    STITCH_CUDA(cudaEventRecord(s.event, stream));
    s.used = true;
  }

 private:
  static constexpr std::size_t kMaxSlots = 64;  // 16 views, 4 frames in flight
  struct Slot {
    uint8_t* data = nullptr;
    std::size_t bytes = 0;
    cudaEvent_t event = nullptr;
    bool used = false;
  };
  std::vector<Slot> slots_;
  std::size_t next_ = 0, current_ = 0;
};

// Frames in system memory go through the pinned ring; RGBA needs no kernel (one 2D copy to
// wherever the view lies), the other formats one kernel pass.
class FrameConverterCuda final : public FrameConverter {
 public:
  void convert(const FrameView& in, const ImageView& out) override {
    check_frame(in, out);
    stream_.enter();
    host_out_ = host_out_ || !out.on_device;
    const std::size_t row = std::size_t(in.width) * 4;
    if (in.format == FrameFormat::RGBA && !in.on_device && out.on_device && pinned_ && !page_locked(in)) {
      uint8_t* slot = ring_.take(row * std::size_t(in.height));
      copy_rows(slot, row, in.planes[0], in.pitches[0], row, in.height);
      STITCH_CUDA(copy_2d_async(out.data, out.pitch, slot, row, row, std::size_t(in.height),
                                    cudaMemcpyHostToDevice, stream_.get()));
      ring_.done(stream_.get());
      return;
    }
    if (in.format == FrameFormat::RGBA) {
      STITCH_CUDA(copy_2d_async(out.data, out.pitch, in.planes[0], in.pitches[0], row, std::size_t(in.height),
                                    copy_kind(in.on_device, out.on_device), stream_.get()));
      return;
    }
    uint8_t* dst = out.data;
    std::size_t dst_pitch = out.pitch;
    if (!out.on_device) {
      staging_out_.resize(row * std::size_t(in.height));
      dst = staging_out_.data();
      dst_pitch = row;
    }
    const FrameView src = in.on_device ? in : upload(in);
    if (is_yuv420(src.format)) {
      const YuvColorimetry& c = src.colorimetry;
      stitch_cuda::launch_yuv420_to_rgba(yuv420_planes(src), yuv_to_rgb_q16(c.kr, c.kb, c.full_range), dst,
                                         dst_pitch, stream_.get());
    } else {
      const bool swap = src.format == FrameFormat::BGRA || src.format == FrameFormat::BGRx;
      const bool opaque = src.format == FrameFormat::RGBx || src.format == FrameFormat::BGRx;
      stitch_cuda::launch_rgb4_to_rgba(src.planes[0], src.pitches[0], src.width, src.height, swap, opaque, dst,
                                       dst_pitch, stream_.get());
    }
    if (!out.on_device)
      STITCH_CUDA(copy_2d_async(out.data, out.pitch, dst, dst_pitch, row, std::size_t(in.height),
                                    cudaMemcpyDeviceToHost, stream_.get()));
  }

  void clear(const ImageView& out) override {
    const std::size_t row = std::size_t(out.width) * 4;
    if (out.on_device) {
      stream_.enter();
      STITCH_CUDA(cudaMemset2DAsync(out.data, out.pitch, 0, row, std::size_t(out.height), stream_.get()));
      return;
    }
    for (int y = 0; y < out.height; ++y) std::memset(out.row(y), 0, row);
  }

  // Host outputs are read when this returns; device ones are handed on (CudaStream::leave).
  void finish() override {
    if (host_out_)
      stream_.sync();
    else
      stream_.leave();
    host_out_ = false;
  }
  Backend backend() const override { return Backend::Cuda; }

 private:
  // Staging copy into the pinned ring, in row blocks on several cores: one core's memcpy
  // (5-10 GB/s) would cap system-memory input at a few hundred bundles per second.
  static void copy_rows(uint8_t* dst, std::size_t dst_pitch, const uint8_t* src, std::size_t src_pitch,
                        std::size_t row, int rows) {
    const auto copy_block = [=](int y0, int y1) {
      if (dst_pitch == src_pitch && row == src_pitch) {
        std::memcpy(dst + std::size_t(y0) * dst_pitch, src + std::size_t(y0) * src_pitch, row * std::size_t(y1 - y0));
        return;
      }
      for (int y = y0; y < y1; ++y) std::memcpy(dst + std::size_t(y) * dst_pitch, src + std::size_t(y) * src_pitch, row);
    };
    const std::size_t bytes = row * std::size_t(rows);
    const int blocks = int(std::min<std::size_t>(kCopyBlocks, bytes / kMinBlockBytes));
    if (blocks <= 1) {
      copy_block(0, rows);
      return;
    }
    cv::parallel_for_(cv::Range(0, blocks), [&](const cv::Range& r) {
      for (int b = r.start; b < r.end; ++b) copy_block(rows * b / blocks, rows * (b + 1) / blocks);
    });
  }
  static constexpr std::size_t kCopyBlocks = 8, kMinBlockBytes = std::size_t(1) << 20;

  // True when every plane of a system-memory frame is page-locked (stitchsync pins input memory
  // that comes back frame after frame): the device then reads it by DMA, no staging copy.
  static bool page_locked(const FrameView& in) {
    const int planes = in.format == FrameFormat::I420 ? 3 : in.format == FrameFormat::NV12 ? 2 : 1;
    for (int p = 0; p < planes; ++p) {
      cudaPointerAttributes a{};
      if (cudaPointerGetAttributes(&a, in.planes[p]) != cudaSuccess) {
        cudaGetLastError();
        return false;
      }
      if (a.type != cudaMemoryTypeHost) return false;
    }
    return true;
  }

  // The frame's planes copied to the device, packed (through the pinned ring).
  FrameView upload(const FrameView& in) {
    const int cw = (in.width + 1) / 2, ch = (in.height + 1) / 2;
    std::size_t widths[3] = {std::size_t(in.width) * 4, 0, 0};
    int rows[3] = {in.height, 0, 0};
    int planes = 1;
    if (in.format == FrameFormat::NV12) {
      widths[0] = std::size_t(in.width);
      widths[1] = std::size_t(cw) * 2;
      rows[1] = ch;
      planes = 2;
    } else if (in.format == FrameFormat::I420) {
      widths[0] = std::size_t(in.width);
      widths[1] = widths[2] = std::size_t(cw);
      rows[1] = rows[2] = ch;
      planes = 3;
    }
    std::size_t offsets[3] = {0, 0, 0}, total = 0;
    for (int p = 0; p < planes; ++p) {
      offsets[p] = total;
      total += (widths[p] * std::size_t(rows[p]) + 255) & ~std::size_t(255);
    }
    // One device buffer: the stream runs the next upload after the kernel that reads this one.
    DeviceBuffer& staging = staging_in_;
    staging.resize(total);
    FrameView d = in;
    d.on_device = true;
    // page-locked input: each plane straight from it; else through a pinned slot
    uint8_t* slot = pinned_ && !page_locked(in) ? ring_.take(total) : nullptr;
    for (int p = 0; p < planes; ++p) {
      uint8_t* dst = staging.data() + offsets[p];
      if (slot) {
        copy_rows(slot + offsets[p], widths[p], in.planes[p], in.pitches[p], widths[p], rows[p]);
      } else {
        STITCH_CUDA(copy_2d_async(dst, widths[p], in.planes[p], in.pitches[p], widths[p], std::size_t(rows[p]),
                                      cudaMemcpyHostToDevice, stream_.get()));
      }
      d.planes[p] = dst;
      d.pitches[p] = widths[p];
    }
    if (slot) {
      STITCH_CUDA(cudaMemcpyAsync(staging.data(), slot, total, cudaMemcpyHostToDevice, stream_.get()));
      ring_.done(stream_.get());
    }
    return d;
  }

  CudaStream stream_;
  DeviceBuffer staging_in_, staging_out_;
  PinnedRing ring_;
  // STITCH_CUDA_NO_PINNED=1: uploads from pageable memory as before (for the A/B)
  const bool pinned_ = !std::getenv("STITCH_CUDA_NO_PINNED");
  bool host_out_ = false;  // a host output since the last finish()
};

}  // namespace

std::unique_ptr<FrameConverter> make_frame_converter_cuda() { return std::make_unique<FrameConverterCuda>(); }

}  // namespace stitch
