#include <cstring>
#include <stdexcept>

#include "../../../cuda/convert/convert_kernels.hpp"
#include "stitch/convert/convert_internal.hpp"
#include "stitch/cuda/cuda_util.hpp"

namespace stitch {
namespace {

cudaMemcpyKind copy_kind(bool src_on_device, bool dst_on_device) {
  if (src_on_device) return dst_on_device ? cudaMemcpyDeviceToDevice : cudaMemcpyDeviceToHost;
  return dst_on_device ? cudaMemcpyHostToDevice : cudaMemcpyHostToHost;
}

// Frames in system memory are uploaded once into a buffer that only grows; RGBA needs no
// kernel (one 2D copy to wherever the view lies), the other formats one kernel pass.
class FrameConverterCuda final : public FrameConverter {
 public:
  void convert(const FrameView& in, const ImageView& out) override {
    check_frame(in, out);
    stream_.enter();
    host_out_ = host_out_ || !out.on_device;
    const std::size_t row = std::size_t(in.width) * 4;
    if (in.format == FrameFormat::RGBA) {
      STITCH_CUDA(cudaMemcpy2DAsync(out.data, out.pitch, in.planes[0], in.pitches[0], row, std::size_t(in.height),
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
      STITCH_CUDA(cudaMemcpy2DAsync(out.data, out.pitch, dst, dst_pitch, row, std::size_t(in.height),
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
  // The frame's planes copied to the device, packed.
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
    staging_in_.resize(total);
    FrameView d = in;
    d.on_device = true;
    for (int p = 0; p < planes; ++p) {
      uint8_t* dst = staging_in_.data() + offsets[p];
      STITCH_CUDA(cudaMemcpy2DAsync(dst, widths[p], in.planes[p], in.pitches[p], widths[p], std::size_t(rows[p]),
                                    cudaMemcpyHostToDevice, stream_.get()));
      d.planes[p] = dst;
      d.pitches[p] = widths[p];
    }
    return d;
  }

  CudaStream stream_;
  DeviceBuffer staging_in_, staging_out_;
  bool host_out_ = false;  // a host output since the last finish()
};

}  // namespace

std::unique_ptr<FrameConverter> make_frame_converter_cuda() { return std::make_unique<FrameConverterCuda>(); }

}  // namespace stitch
