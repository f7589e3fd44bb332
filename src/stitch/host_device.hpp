// STITCH_HD: functions compiled for both the host and the CUDA device (shared arithmetic that
// the CPU implementation and the kernels must agree on).
#pragma once

#ifdef __CUDACC__
#define STITCH_HD __host__ __device__ __forceinline__
#else
#define STITCH_HD inline
#endif
