// Launchers of the color kernels (definitions in color_kernels.cu). Checked; throw on error.
#pragma once
#include <cuda_runtime_api.h>
#include <stddef.h>
#include <stdint.h>

namespace stitch_cuda {

// In place on an RGBA device image: c' = lut[c](round(sum_k in_k M[k][c])), alpha untouched.
// M: row-major 3x3 (nullptr: identity); lut: device pointer to 3 x 256 bytes (nullptr: none).
void launch_color_apply(uint8_t* data, size_t pitch, int width, int height, const float* M,
                        const uint8_t* lut, cudaStream_t stream);

// out[k] = RGB of the pixel at (xy[2k], xy[2k+1]); xy and out are device pointers.
void launch_gather(const uint8_t* data, size_t pitch, const int32_t* xy, int count, uint8_t* out,
                   cudaStream_t stream);

}  // namespace stitch_cuda
