// Launchers of the frame conversion kernels (definitions in convert_kernels.cu). The pixel
// math is stitch/convert/yuv_math.hpp, the same the CPU implementation runs. Checked; throw
// std::runtime_error on a launch error.
#pragma once
#include <cuda_runtime_api.h>
#include <stddef.h>
#include <stdint.h>

#include "stitch/convert/yuv_math.hpp"

namespace stitch_cuda {

// 4:2:0 Y'CbCr (device planes) to RGBA (device).
void launch_yuv420_to_rgba(const stitch::Yuv420Planes& in, const stitch::YuvToRgbQ16& k, uint8_t* out,
                           size_t out_pitch, cudaStream_t stream);

// 4-byte RGB (device) to RGBA (device): `swap_rb` for B,G,R order, `opaque` when the 4th byte
// is padding.
void launch_rgb4_to_rgba(const uint8_t* in, size_t in_pitch, int width, int height, bool swap_rb, bool opaque,
                         uint8_t* out, size_t out_pitch, cudaStream_t stream);

}  // namespace stitch_cuda
