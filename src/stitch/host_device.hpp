// STITCH_HD marks arithmetic shared by the CPU code and the CUDA kernels (one definition, the
// same numbers on both sides).
#pragma once

#ifdef __CUDACC__
#define STITCH_HD __host__ __device__ __forceinline__
#else
#define STITCH_HD inline
#endif
