// Which implementation of a stage runs: every stage has a CPU and (when built) a CUDA one.
#pragma once
#include <string>

namespace stitch {

enum class Backend { Auto, Cpu, Cuda };

// True when this build contains the CUDA stages and a CUDA device can be opened.
bool cuda_device_available();
// Resolves Auto to Cpu or Cuda; throws std::runtime_error when Cuda is asked for and unavailable.
Backend resolve_backend(Backend requested);
const char* backend_name(Backend b);

}  // namespace stitch
