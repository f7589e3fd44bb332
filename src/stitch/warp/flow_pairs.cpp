#include "stitch/warp/flow_pairs.hpp"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

namespace stitch {

double flow_scale(FlowQuality q) { return q == FlowQuality::Fine ? 1.0 : 0.5; }

Rect intersect(const Rect& a, const Rect& b) {
  const int x0 = std::max(a.x, b.x), y0 = std::max(a.y, b.y);
  const int x1 = std::min(a.x + a.width, b.x + b.width), y1 = std::min(a.y + a.height, b.y + b.height);
  if (x1 <= x0 || y1 <= y0) return {};
  return {x0, y0, x1 - x0, y1 - y0};
}

std::vector<FlowPairPlan> plan_flow_pairs(const std::vector<ViewPlacement>& views,
                                          const std::vector<cv::Mat>& weights, int margin, FlowQuality quality) {
  std::vector<FlowPairPlan> plans;
  const double scale = flow_scale(quality);
  const int m = std::max(0, margin);
  for (int a = 0; a < int(views.size()); ++a) {
    for (int b = a + 1; b < int(views.size()); ++b) {
      const Rect common = intersect(views[a].roi, views[b].roi);
      if (common.empty() || weights[a].empty() || weights[b].empty()) continue;
      const Rect& ra = views[a].roi;
      const Rect& rb = views[b].roi;
      const cv::Rect in_a(common.x - ra.x, common.y - ra.y, common.width, common.height);
      const cv::Rect in_b(common.x - rb.x, common.y - rb.y, common.width, common.height);
      const cv::Mat both = (weights[a](in_a) > 0) & (weights[b](in_b) > 0);
      const cv::Rect box = cv::boundingRect(both);
      if (box.empty()) continue;
      FlowPairPlan p;
      p.a = a;
      p.b = b;
      p.rect = intersect({common.x + box.x - m, common.y + box.y - m, box.width + 2 * m, box.height + 2 * m}, common);
      p.work_width = std::max(1, int(std::lround(p.rect.width * scale)));
      p.work_height = std::max(1, int(std::lround(p.rect.height * scale)));
      if (p.work_width < 8 || p.work_height < 8) continue;
      plans.push_back(p);
    }
  }
  return plans;
}

}  // namespace stitch
