// What convert_cpu.cpp and convert_cuda.cpp share: plane layout, checks, the CUDA factory.
#pragma once
#include <memory>

#include "stitch/convert/convert.hpp"
#include "stitch/convert/yuv_math.hpp"

namespace stitch {

Yuv420Planes yuv420_planes(const FrameView& in);
// Throws std::invalid_argument when `out` is not the frame's size or a plane is missing.
void check_frame(const FrameView& in, const ImageView& out);

#ifdef STITCH_HAVE_CUDA
std::unique_ptr<FrameConverter> make_frame_converter_cuda();
#endif

}  // namespace stitch
