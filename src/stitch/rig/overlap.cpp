#include "stitch/rig/overlap.hpp"

#include <opencv2/imgproc.hpp>

namespace stitch {

std::vector<cv::Point2f> canvas_overlap(const Camera& a, const Camera& b, float* area) {
  auto quad = [](const Camera& c) {
    std::vector<cv::Point2f> q;
    for (const auto& p : camera_canvas_corners(c)) q.emplace_back(float(p.x()), float(p.y()));
    return q;
  };
  std::vector<cv::Point2f> inter;
  const float s = cv::intersectConvexConvex(quad(a), quad(b), inter, true);
  if (area) *area = inter.size() >= 3 ? s : 0.f;
  if (inter.size() < 3) inter.clear();
  return inter;
}

std::vector<std::pair<int, int>> max_spanning_order(int n, int root, const std::vector<OverlapEdge>& edges) {
  std::vector<std::pair<int, int>> order;
  std::vector<bool> in(n, false);
  in[root] = true;
  for (;;) {
    const OverlapEdge* best = nullptr;
    for (const auto& e : edges)
      if (in[e.a] != in[e.b] && (!best || e.weight > best->weight)) best = &e;
    if (!best) break;
    const int child = in[best->a] ? best->b : best->a;
    const int parent = in[best->a] ? best->a : best->b;
    in[child] = true;
    order.emplace_back(child, parent);
  }
  return order;
}

}  // namespace stitch
