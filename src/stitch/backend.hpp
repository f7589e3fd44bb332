// Which implementation of a stage runs: every stage has a CPU and (when built) a CUDA one.
#pragma once
#include <string>

namespace stitch {

enum class Backend { Auto, Cpu, Cuda };

// True when this build contains the CUDA stages and a CUDA device can be opened.
bool cuda_device_available();
// Resolves Auto to Cuda when the stage has a CUDA implementation in this build and a device
// opens, else to Cpu; throws std::runtime_error when Cuda is asked for and cannot be had.
Backend resolve_backend(Backend requested, bool stage_has_cuda);
const char* backend_name(Backend b);

}  // namespace stitch
