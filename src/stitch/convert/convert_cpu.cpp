#include <cstring>
#include <opencv2/core.hpp>
#include <stdexcept>

#include "stitch/convert/convert.hpp"
#include "stitch/convert/convert_internal.hpp"
#include "stitch/convert/yuv_math.hpp"

namespace stitch {

bool is_yuv420(FrameFormat format) { return format == FrameFormat::NV12 || format == FrameFormat::I420; }

Yuv420Planes yuv420_planes(const FrameView& in) {
  Yuv420Planes p;
  p.y = in.planes[0];
  p.y_pitch = in.pitches[0];
  p.cb = in.planes[1];
  p.cb_pitch = in.pitches[1];
  if (in.format == FrameFormat::NV12) {
    p.cr = in.planes[1] + 1;
    p.cr_pitch = in.pitches[1];
    p.step = 2;
  } else {
    p.cr = in.planes[2];
    p.cr_pitch = in.pitches[2];
    p.step = 1;
  }
  p.width = in.width;
  p.height = in.height;
  p.cosited_x = in.colorimetry.chroma_cosited_x;
  p.cosited_y = in.colorimetry.chroma_cosited_y;
  return p;
}

void check_frame(const FrameView& in, const ImageView& out) {
  if (in.width != out.width || in.height != out.height)
    throw std::invalid_argument("frame conversion: the output is not the frame's size");
  const int planes = in.format == FrameFormat::I420 ? 3 : in.format == FrameFormat::NV12 ? 2 : 1;
  for (int p = 0; p < planes; ++p)
    if (!in.planes[p]) throw std::invalid_argument("frame conversion: a plane is missing");
}

namespace {

class FrameConverterCpu final : public FrameConverter {
 public:
  void convert(const FrameView& in, const ImageView& out) override {
    if (in.on_device || out.on_device) throw std::invalid_argument("the CPU frame converter takes system memory only");
    check_frame(in, out);
    if (is_yuv420(in.format)) {
      const Yuv420Planes p = yuv420_planes(in);
      const YuvToRgbQ16 k = yuv_to_rgb_q16(in.colorimetry.kr, in.colorimetry.kb, in.colorimetry.full_range);
      cv::parallel_for_(cv::Range(0, in.height), [&](const cv::Range& rows) {
        for (int y = rows.start; y < rows.end; ++y) {
          uint8_t* o = out.row(y);
          for (int x = 0; x < in.width; ++x) yuv420_pixel(p, k, x, y, o + 4 * x);
        }
      });
      return;
    }
    const bool swap = in.format == FrameFormat::BGRA || in.format == FrameFormat::BGRx;
    const bool opaque = in.format == FrameFormat::RGBx || in.format == FrameFormat::BGRx;
    // Whole rows per thread: a 1080p copy is memory-bound, but a swizzle is not.
    cv::parallel_for_(cv::Range(0, in.height), [&](const cv::Range& rows) {
      for (int y = rows.start; y < rows.end; ++y) {
        const uint8_t* i = in.planes[0] + std::size_t(y) * in.pitches[0];
        uint8_t* o = out.row(y);
        if (!swap && !opaque) {
          std::memcpy(o, i, std::size_t(in.width) * 4);
          continue;
        }
        for (int x = 0; x < in.width; ++x) rgb4_pixel(i + 4 * x, swap, opaque, o + 4 * x);
      }
    });
  }

  void clear(const ImageView& out) override {
    if (out.on_device) throw std::invalid_argument("the CPU frame converter takes system memory only");
    cv::parallel_for_(cv::Range(0, out.height), [&](const cv::Range& rows) {
      for (int y = rows.start; y < rows.end; ++y) std::memset(out.row(y), 0, std::size_t(out.width) * 4);
    });
  }

  void finish() override {}
  Backend backend() const override { return Backend::Cpu; }
};

}  // namespace

std::unique_ptr<FrameConverter> FrameConverter::create(Backend backend) {
  switch (resolve_backend(backend, /*stage_has_cuda=*/true)) {
#ifdef STITCH_HAVE_CUDA
    case Backend::Cuda: return make_frame_converter_cuda();
#endif
    case Backend::Cpu: return std::make_unique<FrameConverterCpu>();
    default: break;
  }
  throw std::runtime_error("no frame converter for this backend");
}

}  // namespace stitch
