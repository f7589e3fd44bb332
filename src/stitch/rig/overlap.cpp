#include "stitch/rig/overlap.hpp"

#include <opencv2/imgproc.hpp>

#include "stitch/rig/canvas_map.hpp"

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

std::vector<cv::Point2f> canvas_overlap(const Rig& rig, int a, int b, float* area) {
  if (rig.cameras.at(a).left_out || rig.cameras.at(b).left_out) {  // on no canvas
    if (area) *area = 0.f;
    return {};
  }
  if (rig.planar() && rig.cameras.at(a).lens.pinhole() && rig.cameras.at(b).lens.pinhole() &&
      !rig.cameras[a].lens.circle && !rig.cameras[b].lens.circle)
    return canvas_overlap(rig.cameras.at(a), rig.cameras.at(b), area);
  if (rig.projection_kind() == Projection::Cubemap) {
    // Footprints fall apart over the faces: the cells both views see, their area and bounding box.
    const CubeCoverage ga = cube_coverage(rig, a), gb = cube_coverage(rig, b);
    std::vector<uint8_t> both(ga.seen.size());
    std::size_t count = 0;
    for (std::size_t k = 0; k < both.size(); ++k) count += (both[k] = uint8_t(ga.seen[k] && gb.seen[k]));
    std::vector<cv::Point2f> box;
    if (count > 0)
      for (const auto& p : cube_cells_box(ga, both)) box.emplace_back(float(p.x()), float(p.y()));
    if (area) *area = box.empty() ? 0.f : float(count * ga.cell * ga.cell);
    return box;
  }
  // Lenses (curved borders) and non-planar footprints: convex hulls of the outlines.
  auto hull = [&](int cam, double shift) {
    std::vector<cv::Point2f> pts, h;
    for (const auto& p : camera_canvas_outline(rig, cam)) pts.emplace_back(float(p.x() + shift), float(p.y()));
    if (pts.size() >= 3) cv::convexHull(pts, h);
    return h;
  };
  const std::vector<cv::Point2f> ha = hull(a, 0);
  std::vector<cv::Point2f> best;
  float best_area = 0;
  for (int k = rig.canvas_wrap ? -1 : 0; k <= (rig.canvas_wrap ? 1 : 0); ++k) {
    std::vector<cv::Point2f> inter;
    const float s = cv::intersectConvexConvex(ha, hull(b, double(k) * rig.canvas_width), inter, true);
    if (inter.size() >= 3 && s > best_area) {
      best_area = s;
      best = inter;
    }
  }
  if (area) *area = best_area;
  return best;
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
