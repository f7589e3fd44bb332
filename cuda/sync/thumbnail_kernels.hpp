// Launcher of the time-alignment thumbnail kernel (definition in thumbnail_kernels.cu); the
// arithmetic is stitch/sync/thumbnail_math.hpp, the same the CPU runs.
#pragma once
#include <cuda_runtime_api.h>
#include <stddef.h>
#include <stdint.h>

namespace stitch_cuda {

// kThumbnailW x kThumbnailH floats into `out` (device) from an 8-bit plane on the device.
void launch_thumbnail(const uint8_t* data, int width, int height, size_t pitch, int bytes_per_pixel, int channel,
                      float* out, cudaStream_t stream);

}  // namespace stitch_cuda
