// Where stitchflowwarp estimates flow: every pair of views whose blend weights overlap, the
// overlap's bounding box widened by a margin, and the (smaller) resolution the flow runs at.
// Shared by the CPU and CUDA flow warpers so both align exactly the same regions.
#pragma once

#include <opencv2/core.hpp>
#include <vector>

#include "stitch/flow/flow.hpp"
#include "stitch/warp/geometry.hpp"

namespace stitch {

// Resolution of the flow relative to the output: half is ample for seams (the flow is
// smooth) and four times cheaper.
double flow_scale(FlowQuality quality);

struct FlowPairPlan {
  int a = 0, b = 0;  // view indices, a < b
  Rect rect;         // output pixels
  int work_width = 0, work_height = 0;  // flow resolution
};

// `weights[i]` is position_weight_map(views[i]). Pairs whose flow image would be smaller than
// 8 px on a side (slivers) are left out: there is nothing to align.
std::vector<FlowPairPlan> plan_flow_pairs(const std::vector<ViewPlacement>& views,
                                          const std::vector<cv::Mat>& weights, int margin, FlowQuality quality);

Rect intersect(const Rect& a, const Rect& b);

}  // namespace stitch
