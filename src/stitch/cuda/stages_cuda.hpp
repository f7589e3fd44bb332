// Factories of the CUDA implementations (compiled only with STITCH_HAVE_CUDA); the stages'
// create(Backend) call them.
#pragma once
#include <memory>

#include "stitch/blend/blender.hpp"
#include "stitch/blend/multiband.hpp"
#include "stitch/color/color.hpp"
#include "stitch/warp/flow_warper.hpp"
#include "stitch/warp/warper.hpp"

namespace stitch {
std::unique_ptr<Warper> make_warper_cuda();
std::unique_ptr<Blender> make_blender_cuda();
std::unique_ptr<MultibandBlender> make_multiband_blender_cuda(int bands);
std::unique_ptr<ColorOps> make_color_ops_cuda();
std::unique_ptr<FlowWarper> make_flow_warper_cuda();
}  // namespace stitch
