#include <stdexcept>
#include <string>

#include "color_kernels.hpp"

namespace stitch_cuda {

namespace {

struct Matrix3 {
  float m[9];
};

__global__ void apply_kernel(uint8_t* data, size_t pitch, int width, int height, Matrix3 M, int has_matrix,
                             const uint8_t* lut) {
  const int x = blockIdx.x * blockDim.x + threadIdx.x, y = blockIdx.y * blockDim.y + threadIdx.y;
  if (x >= width || y >= height) return;
  uchar4* p = reinterpret_cast<uchar4*>(data + size_t(y) * pitch) + x;
  uchar4 c = *p;
  if (has_matrix) {
    const float r = c.x, g = c.y, b = c.z;
    c.x = uint8_t(fminf(fmaxf(r * M.m[0] + g * M.m[3] + b * M.m[6] + 0.5f, 0.f), 255.f));
    c.y = uint8_t(fminf(fmaxf(r * M.m[1] + g * M.m[4] + b * M.m[7] + 0.5f, 0.f), 255.f));
    c.z = uint8_t(fminf(fmaxf(r * M.m[2] + g * M.m[5] + b * M.m[8] + 0.5f, 0.f), 255.f));
  }
  if (lut) {
    c.x = lut[c.x];
    c.y = lut[256 + c.y];
    c.z = lut[512 + c.z];
  }
  *p = c;
}

__global__ void gather_kernel(const uint8_t* data, size_t pitch, const int32_t* xy, int count, uint8_t* out) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= count) return;
  const uint8_t* p = data + size_t(xy[2 * k + 1]) * pitch + size_t(xy[2 * k]) * 4;
  out[3 * k] = p[0];
  out[3 * k + 1] = p[1];
  out[3 * k + 2] = p[2];
}

void check_launch(const char* what) {
  const cudaError_t e = cudaGetLastError();
  if (e != cudaSuccess) throw std::runtime_error(std::string(what) + ": " + cudaGetErrorString(e));
}

}  // namespace

void launch_color_apply(uint8_t* data, size_t pitch, int width, int height, const float* M, const uint8_t* lut,
                        cudaStream_t stream) {
  if (width <= 0 || height <= 0 || (!M && !lut)) return;
  Matrix3 m{};
  if (M)
    for (int k = 0; k < 9; ++k) m.m[k] = M[k];
  const dim3 block(32, 8), grid((width + 31) / 32, (height + 7) / 8);
  apply_kernel<<<grid, block, 0, stream>>>(data, pitch, width, height, m, M != nullptr, lut);
  check_launch("color apply kernel");
}

void launch_gather(const uint8_t* data, size_t pitch, const int32_t* xy, int count, uint8_t* out,
                   cudaStream_t stream) {
  if (count <= 0) return;
  gather_kernel<<<(count + 255) / 256, 256, 0, stream>>>(data, pitch, xy, count, out);
  check_launch("gather kernel");
}

}  // namespace stitch_cuda
