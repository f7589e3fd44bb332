// Where views overlap on the canvas, and the order in which stages chain outward from the
// reference camera (calibration refinement, color transfer).
#pragma once

#include <opencv2/core.hpp>
#include <utility>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace stitch {

// Canvas polygon shared by two calibrated views; empty when they do not overlap.
std::vector<cv::Point2f> canvas_overlap(const Camera& a, const Camera& b, float* area = nullptr);

// The same for views a and b of a calibrated rig of any projection: non-planar footprints are
// taken as their convex hulls, and on a wrapping canvas the overlap across the wrap counts
// (the polygon then reaches outside [0, width); canvas_to_camera maps it periodically).
// Cubemaps: the area both see (cube_coverage cells) and its bounding box, which may hold pixels
// only one of them sees: callers check each sample against both views.
std::vector<cv::Point2f> canvas_overlap(const Rig& rig, int a, int b, float* area = nullptr);

struct OverlapEdge {
  int a, b;
  double weight;  // how much the two views share (area, sample count, matches)
};

// (view, parent) pairs in the order Prim's maximum spanning tree reaches them from `root`:
// each view hangs off the neighbour it shares the most with. Unreached views are left out.
std::vector<std::pair<int, int>> max_spanning_order(int n, int root, const std::vector<OverlapEdge>& edges);

}  // namespace stitch
