#include "stitch/blend/seam.hpp"
#include "stitch/parallel.hpp"
#include "stitch/stage_profile.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include <opencv2/core/utility.hpp>

#include "stitch/blend/blender_cpu.hpp"
#include "stitch/blend/multiband.hpp"
#include "stitch/blend/seam_math.hpp"

namespace stitch {

namespace {
// f(row) for every row on OpenCV's threads: each row's result is computed as in a plain loop, so
// the output does not depend on the thread count.
template <class F>
void for_rows(int rows, const F& f) {
  cv::parallel_for_(cv::Range(0, rows), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) f(y);
  });
}

// The bidirectional DP of seam_path in parts: the two sweeps (independent: rows [0, m) and
// [m, rows) of `step`) may run on two threads, then finish() meets them and walks the path.
struct SeamDp {
  const float* costs;
  int rows, cols;
  const int* previous;
  seam::Weights w;
  int8_t* step;  // rows * cols
  int m;
  std::vector<float> end[2];  // each sweep's last energy row, padded
  float sum[2] = {0.f, 0.f};  // last frame's path's cost, per sweep in its row order
  SeamDp(const float* c, int r, int n, const int* prev, const seam::Weights& weights, int8_t* s)
      : costs(c), rows(r), cols(n), previous(prev), w(weights), step(s), m(seam::dp_meeting_row(r)) {}
  // One sweep over rows first, first + dir, ... (count of them), on energy rows padded for
  // dp_cell_padded; keeps the last row's energies (with their pads) and last frame's path's
  // cost, summed in the sweep's row order.
  void sweep(int k) {
    const int first = k == 0 ? 0 : rows - 1, dir = k == 0 ? 1 : -1, count = k == 0 ? m : rows - m;
    std::vector<float> above(cols + 2, 0.f), here(cols + 2, 0.f);
    above[0] = above[cols + 1] = here[0] = here[cols + 1] = std::numeric_limits<float>::infinity();
    float previous_sum = 0.f;
    for (int j = 0, r = first; j < count; ++j, r += dir) {
      const float* cost_row = costs + std::size_t(r) * cols;
      const int prev = previous ? previous[r] : -1;
      for (int c = 0; c < cols; ++c)
        step[std::size_t(r) * cols + c] =
            int8_t(seam::dp_cell_padded(above.data() + 1, c, cost_row[c], w.stability, prev, here[c + 1]));
      if (previous) previous_sum = seam::add(previous_sum, cost_row[prev]);
      std::swap(above, here);
    }
    end[k] = std::move(above);
    sum[k] = previous_sum;
  }
  void finish(std::vector<int>& path) const {
    std::vector<float> total(cols);
    std::vector<int8_t> meet(cols);
    for (int c = 0; c < cols; ++c)
      meet[c] = int8_t(seam::meet_cell(end[0].data() + 1, end[1].data() + 1, c, cols, m == 0, total[c]));
    const int best = int(std::min_element(total.begin(), total.end()) - total.begin());
    path.assign(rows, 0);
    if (previous && seam::keep_previous(seam::add(sum[0], sum[1]), total[best], rows, w.hold)) {
      std::copy(previous, previous + rows, path.begin());  // the seam holds still until something crosses it
      return;
    }
    path[m] = best;
    for (int r = m + 1; r < rows; ++r) path[r] = path[r - 1] + step[std::size_t(r - 1) * cols + path[r - 1]];
    for (int r = m - 1, c = best + meet[best]; r >= 0; --r) {
      path[r] = c;
      c += step[std::size_t(r) * cols + c];
    }
  }
};

bool intersect(const Rect& a, const Rect& b) {
  return a.x < b.x + b.width && b.x < a.x + a.width && a.y < b.y + b.height && b.y < a.y + a.height;
}
Rect bounding(const Rect& a, const Rect& b) {
  const int x0 = std::min(a.x, b.x), y0 = std::min(a.y, b.y);
  const int x1 = std::max(a.x + a.width, b.x + b.width), y1 = std::max(a.y + a.height, b.y + b.height);
  return {x0, y0, x1 - x0, y1 - y0};
}
}  // namespace

void SeamFinder::prepare(const std::vector<ViewPlacement>& views, int width, int height) {
  if (views.size() >= kNoView) throw std::invalid_argument("too many views");
  views_ = views;
  width_ = width;
  height_ = height;
  pairs_.clear();
  nearest_mask_ = ~uint64_t(0);
  luma_.assign(views.size(), {});
  previous_labels_.clear();
  previous_luma_.assign(views.size(), {});
  std::vector<cv::Mat> weight(views.size());
  for (std::size_t i = 0; i < views.size(); ++i) weight[i] = position_weight_map(views[i]);
  for (std::size_t a = 0; a < views.size(); ++a)
    for (std::size_t b = a + 1; b < views.size(); ++b) {
      const Rect &ra = views[a].roi, &rb = views[b].roi;
      if (ra.empty() || rb.empty()) continue;
      const int x0 = std::max(ra.x, rb.x), y0 = std::max(ra.y, rb.y);
      const int x1 = std::min(ra.x + ra.width, rb.x + rb.width), y1 = std::min(ra.y + ra.height, rb.y + rb.height);
      if (x1 <= x0 || y1 <= y0) continue;
      // The overlap proper: where both views have weight; its bounding box.
      int bx0 = x1, by0 = y1, bx1 = x0, by1 = y0;
      for (int y = y0; y < y1; ++y)
        for (int x = x0; x < x1; ++x)
          if (weight[a].at<float>(y - ra.y, x - ra.x) > 0 && weight[b].at<float>(y - rb.y, x - rb.x) > 0) {
            bx0 = std::min(bx0, x), by0 = std::min(by0, y), bx1 = std::max(bx1, x + 1), by1 = std::max(by1, y + 1);
          }
      if (bx1 - bx0 < 3 || by1 - by0 < 3) continue;
      Pair p;
      p.box = {bx0, by0, bx1 - bx0, by1 - by0};
      // Side by side: a seam from top to bottom; one above the other: from left to right.
      const double dx = (rb.x + 0.5 * rb.width) - (ra.x + 0.5 * ra.width);
      const double dy = (rb.y + 0.5 * rb.height) - (ra.y + 0.5 * ra.height);
      p.vertical = std::abs(dx) >= std::abs(dy);
      const double ca = p.vertical ? ra.x + 0.5 * ra.width : ra.y + 0.5 * ra.height;
      const double cb = p.vertical ? rb.x + 0.5 * rb.width : rb.y + 0.5 * rb.height;
      p.a = int(ca <= cb ? a : b);
      p.b = int(ca <= cb ? b : a);
      const Rect &pa = views[p.a].roi, &pb = views[p.b].roi;
      p.centre_cost.assign(std::size_t(p.box.width) * p.box.height, -1.f);
      for (int y = 0; y < p.box.height; ++y)
        for (int x = 0; x < p.box.width; ++x) {
          const int cx = p.box.x + x, cy = p.box.y + y;
          const float wa = weight[p.a].at<float>(cy - pa.y, cx - pa.x), wb = weight[p.b].at<float>(cy - pb.y, cx - pb.x);
          if (wa > 0 && wb > 0)
            p.centre_cost[std::size_t(y) * p.box.width + x] = settings_.centre_weight * std::abs(wa - wb) / (wa + wb);
        }
      pairs_.push_back(std::move(p));
    }
  // Where each view's luma is read: its pairs' boxes grown by one pixel (the gradients), clipped
  // to its roi, in roi coordinates; overlapping rectangles merged, so that no pixel is written twice.
  luma_rects_.assign(views.size(), {});
  for (const Pair& p : pairs_)
    for (const int v : {p.a, p.b}) {
      const Rect& r = views[v].roi;
      const int x0 = std::max(p.box.x - 1, r.x), y0 = std::max(p.box.y - 1, r.y);
      const int x1 = std::min(p.box.x + p.box.width + 1, r.x + r.width);
      const int y1 = std::min(p.box.y + p.box.height + 1, r.y + r.height);
      if (x1 > x0 && y1 > y0) luma_rects_[v].push_back({x0 - r.x, y0 - r.y, x1 - x0, y1 - y0});
    }
  for (std::vector<Rect>& rects : luma_rects_)
    for (bool merged = true; merged;) {
      merged = false;
      for (std::size_t i = 0; i < rects.size() && !merged; ++i)
        for (std::size_t j = i + 1; j < rects.size() && !merged; ++j)
          if (intersect(rects[i], rects[j])) {
            rects[i] = bounding(rects[i], rects[j]);
            rects.erase(rects.begin() + std::ptrdiff_t(j));
            merged = true;
          }
    }
  boxes_disjoint_ = true;
  for (std::size_t i = 0; i < pairs_.size(); ++i)
    for (std::size_t j = i + 1; j < pairs_.size(); ++j)
      if (intersect(pairs_[i].box, pairs_[j].box)) boxes_disjoint_ = false;
  labels_fresh_ = false;
}

const std::vector<uint8_t>& SeamFinder::find(const std::vector<ImageView>& warped) {
  if (warped.size() != views_.size()) throw std::invalid_argument("view count differs from prepare()");
  uint64_t mask = 0;
  // Luma of the views (r + 2g + b) / 4, where the cuts read it (the seams' costs are measured on
  // it): the rectangles of every view in one parallel loop.
  std::vector<std::pair<int, Rect>> luma_tasks;
  std::vector<int> luma_rows;
  for (std::size_t i = 0; i < warped.size(); ++i) {
    if (warped[i].empty() || views_[i].roi.empty()) {
      luma_[i].clear();
      continue;
    }
    if (warped[i].on_device) throw std::invalid_argument("the seam finder reads views in host memory");
    mask |= uint64_t(1) << i;
    const Rect& r = views_[i].roi;
    std::swap(luma_[i], previous_luma_[i]);
    luma_[i].resize(std::size_t(r.width) * r.height);
    for (const Rect& q : luma_rects_[i]) {
      luma_tasks.push_back({int(i), q});
      luma_rows.push_back(q.height);
    }
  }
  parallel_for_parts(luma_rows, [&](int t, int y) {
    const int i = luma_tasks[std::size_t(t)].first;
    const Rect& q = luma_tasks[std::size_t(t)].second;
    const uint8_t* p = warped[std::size_t(i)].row(q.y + y) + 4 * q.x;
    uint8_t* l = luma_[std::size_t(i)].data() + std::size_t(q.y + y) * views_[std::size_t(i)].roi.width + q.x;
    for (int x = 0; x < q.width; ++x) l[x] = seam::luma(p + 4 * x);
  });
  for (std::size_t i = 0; i < warped.size(); ++i)
    if (mask >> i & 1 && previous_luma_[i].size() != luma_[i].size()) previous_luma_[i] = luma_[i];
  if (mask != nearest_mask_) {
    nearest_ = nearest_view_labels(views_, width_, height_, mask);
    nearest_mask_ = mask;
    labels_fresh_ = false;
  }
  // Last frame's labels, for the view-switch cost (only when the hold is on: a full-frame copy).
  if (settings_.label_hold > 0.f && settings_.mix_radius > 0 && !labels_.empty()) previous_labels_ = labels_;
  else previous_labels_.clear();
  const bool mix_on = settings_.mix_radius > 0;
  if (!mix_on) mix_.clear();
  if (!labels_fresh_ || labels_.size() != nearest_.size() || (mix_on && mix_.size() != std::size_t(width_) * height_)) {
    // labels_ = nearest_ and a zeroed mix map, by rows on OpenCV's threads (full-frame byte maps:
    // a serial copy and fill were ~3 ms per 3x1080p canvas, a serial section on every core count)
    labels_.resize(nearest_.size());
    if (mix_on) mix_.resize(std::size_t(width_) * height_);
    for_rows(height_, [&](int y) {
      const std::size_t row = std::size_t(y) * width_;
      if (row + width_ <= nearest_.size()) std::copy_n(nearest_.data() + row, width_, labels_.data() + row);
      if (!mix_.empty()) std::fill_n(mix_.data() + row, width_, uint8_t(0));
    });
    labels_fresh_ = true;
  } else {
    // The cuts change labels_ and mix_ only inside the pairs' boxes: only those are reset (two
    // full-frame byte maps less to write per frame). By output rows: no byte written twice.
    int y0 = height_, y1 = 0;
    for (const Pair& p : pairs_) y0 = std::min(y0, p.box.y), y1 = std::max(y1, p.box.y + p.box.height);
    if (y1 > y0)
      for_rows(y1 - y0, [&](int k) {
        const int y = y0 + k;
        for (const Pair& p : pairs_) {
          if (y < p.box.y || y >= p.box.y + p.box.height) continue;
          const std::size_t row = std::size_t(y) * width_ + p.box.x;
          std::copy_n(nearest_.data() + row, p.box.width, labels_.data() + row);
          if (!mix_.empty()) std::fill_n(mix_.data() + row, p.box.width, uint8_t(0));
        }
      });
  }
  std::vector<int> cut;
  for (std::size_t k = 0; k < pairs_.size(); ++k) {
    Pair& p = pairs_[k];
    if (!(mask >> p.a & 1) || !(mask >> p.b & 1)) {
      p.path.clear();
      continue;
    }
    cut.push_back(int(k));
  }
  cut_all(cut, warped);
  return labels_;
}

void seam_path(const std::vector<float>& costs, int rows, int cols, const int* previous, const seam::Weights& w,
               std::vector<int>& path) {
  std::vector<int8_t> step(std::size_t(rows) * cols);
  SeamDp dp(costs.data(), rows, cols, previous, w, step.data());
  cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& r) {
    for (int k = r.start; k < r.end; ++k) dp.sweep(k);
  }, 2);
  dp.finish(path);
}

void SeamFinder::cut_all(const std::vector<int>& cut, const std::vector<ImageView>& warped) {
  // Each pair works in its seam's frame: "rows" run along the seam, "columns" across it.
  auto rows_of = [](const Pair& p) { return p.vertical ? p.box.height : p.box.width; };
  auto cols_of = [](const Pair& p) { return p.vertical ? p.box.width : p.box.height; };
  auto luma = [](const std::vector<uint8_t>& l, const Rect& r, int x, int y) {
    x = std::min(std::max(x, r.x), r.x + r.width - 1);
    y = std::min(std::max(y, r.y), r.y + r.height - 1);
    return int(l[std::size_t(y - r.y) * r.width + (x - r.x)]);
  };
  // (x, y) and its four neighbours lie inside r.
  auto inside_by_one = [](const Rect& r, int x, int y) {
    return x > r.x && y > r.y && x + 1 < r.x + r.width && y + 1 < r.y + r.height;
  };
  static const bool profiling = StageProfile::enabled_for("seams");
  StageProfile profile("seams", profiling);
  const seam::Weights w = weights();
  const bool clearance = w.clearance_radius > 0 && w.clearance > 0.f, mixing = w.mix_radius > 0;
  const bool holding = mixing && w.label_hold > 0.f && previous_labels_.size() == labels_.size();
  std::vector<int> rows(cut.size());
  for (std::size_t k = 0; k < cut.size(); ++k) {
    Pair& p = pairs_[std::size_t(cut[k])];
    rows[k] = rows_of(p);
    const std::size_t cells = std::size_t(rows_of(p)) * cols_of(p);
    p.costs.resize(cells);
    p.step.resize(cells);
    p.row_cells.resize(std::size_t(rows[k]));
    p.row_dark_a.resize(std::size_t(rows[k]));
    p.row_dark_b.resize(std::size_t(rows[k]));
    if (clearance || mixing) {
      p.diff.resize(cells);
      p.across.resize(cells);
    }
    p.levels.resize(holding ? cells : 0);
  }
  // Window sums of the differences across the seam, one row (integers: exact in any order).
  auto across_row = [&](Pair& p, int r, int R) {
    const int cols = cols_of(p);
    const int* d = p.diff.data() + std::size_t(r) * cols;
    int* a = p.across.data() + std::size_t(r) * cols;
    int sum = 0;
    for (int k = 0; k <= std::min(cols - 1, R); ++k) sum += d[k];
    for (int c = 0; c < cols; ++c) {
      a[c] = sum;
      if (c + R + 1 < cols) sum += d[c + R + 1];
      if (c - R >= 0) sum -= d[c - R];
    }
  };
  // Phase 1, every pair's rows: each cell's cost once (the DP and last frame's path read it), the
  // dark pixels of each view counted per row (a blank view loses the overlap), the views' colour
  // differences and their sums across the seam (one read of the two views' pixels for all three).
  const int first_radius = clearance ? w.clearance_radius : w.mix_radius;
  parallel_for_parts(rows, [&](int k, int r) {
    Pair& p = pairs_[std::size_t(cut[std::size_t(k)])];
    const int cols = cols_of(p);
    const Rect &ra = views_[p.a].roi, &rb = views_[p.b].roi;
    const std::vector<uint8_t> &la = luma_[p.a], &lb = luma_[p.b], &pa = previous_luma_[p.a], &pb = previous_luma_[p.b];
    int cells = 0, dark_a = 0, dark_b = 0;
    for (int c = 0; c < cols; ++c) {
      const int bx = p.vertical ? c : r, by = p.vertical ? r : c;
      const std::size_t at = std::size_t(r) * cols + c;
      const float centre = p.centre_cost[std::size_t(by) * p.box.width + bx];
      if (centre < 0) {
        p.costs[at] = seam::kOutside;
        if (clearance || mixing) p.diff[at] = 0;
        continue;
      }
      const int x = p.box.x + bx, y = p.box.y + by;
      int a, b, gradients, motion;
      if (inside_by_one(ra, x, y) && inside_by_one(rb, x, y)) {
        // Every neighbour inside both rectangles (nearly every cell): no clamping, the same values.
        const std::size_t ia = std::size_t(y - ra.y) * ra.width + (x - ra.x), ib = std::size_t(y - rb.y) * rb.width + (x - rb.x);
        const uint8_t *ca = la.data() + ia, *cb = lb.data() + ib;
        a = ca[0], b = cb[0];
        gradients = std::abs(ca[1] - ca[-1]) + std::abs(ca[ra.width] - ca[-ra.width]) + std::abs(cb[1] - cb[-1]) +
                    std::abs(cb[rb.width] - cb[-rb.width]);
        motion = std::abs(a - pa[ia]) + std::abs(b - pb[ib]);
      } else {
        a = luma(la, ra, x, y), b = luma(lb, rb, x, y);
        gradients = std::abs(luma(la, ra, x + 1, y) - luma(la, ra, x - 1, y)) +
                    std::abs(luma(la, ra, x, y + 1) - luma(la, ra, x, y - 1)) +
                    std::abs(luma(lb, rb, x + 1, y) - luma(lb, rb, x - 1, y)) +
                    std::abs(luma(lb, rb, x, y + 1) - luma(lb, rb, x, y - 1));
        motion = std::abs(a - luma(pa, ra, x, y)) + std::abs(b - luma(pb, rb, x, y));
      }
      const uint8_t* pixel_a = warped[std::size_t(p.a)].row(y - ra.y) + 4 * (x - ra.x);
      const uint8_t* pixel_b = warped[std::size_t(p.b)].row(y - rb.y) + 4 * (x - rb.x);
      const float v = p.costs[at] =
          seam::pixel_cost(w, seam::color_difference(pixel_a, pixel_b), gradients, motion, centre);
      if (clearance || mixing) p.diff[at] = v == seam::kOutside ? 0 : seam::color_difference_sum(pixel_a, pixel_b);
      if (v == seam::kOutside) continue;
      cells++;
      dark_a += a <= seam::kDark;
      dark_b += b <= seam::kDark;
    }
    p.row_cells[std::size_t(r)] = cells;
    p.row_dark_a[std::size_t(r)] = dark_a;
    p.row_dark_b[std::size_t(r)] = dark_b;
    if (clearance || mixing) across_row(p, r, first_radius);
  });
  profile.mark("costs");
  for (const int index : cut) {
    Pair& p = pairs_[std::size_t(index)];
    int cells = 0, dark_a = 0, dark_b = 0;
    for (int r = 0; r < rows_of(p); ++r) cells += p.row_cells[r], dark_a += p.row_dark_a[r], dark_b += p.row_dark_b[r];
    p.blank_a = seam::view_blank(dark_a, dark_b, cells);
    p.blank_b = seam::view_blank(dark_b, dark_a, cells);
  }
  // Rows of every pair at once where the pairs write disjoint boxes of labels_ / mix_; else pair
  // after pair, in order (a later pair sees the labels an earlier one set, as before).
  auto write_rows = [&](const auto& f) {
    if (boxes_disjoint_) {
      parallel_for_parts(rows, f);
      return;
    }
    for (std::size_t k = 0; k < cut.size(); ++k) for_rows(rows[k], [&](int r) { f(int(k), r); });
  };
  if (clearance) {
    parallel_for_parts(rows, [&](int k, int r) {
      Pair& p = pairs_[std::size_t(cut[std::size_t(k)])];
      const int cols = cols_of(p), R = w.clearance_radius, n = rows[std::size_t(k)];
      for (int c = 0; c < cols; ++c) {
        float& v = p.costs[std::size_t(r) * cols + c];
        if (v == seam::kOutside) continue;
        int sum = 0;
        for (int q = std::max(0, r - R); q <= std::min(n - 1, r + R); ++q) sum += p.across[std::size_t(q) * cols + c];
        v = seam::add(v, seam::clearance_cost(w, sum));
      }
    });
    if (mixing) parallel_for_parts(rows, [&](int k, int r) { across_row(pairs_[std::size_t(cut[std::size_t(k)])], r, w.mix_radius); });
  }
  // The consensus blend's mix level of every overlap pixel (max over pairs), one row; each (r, c)
  // is its own output pixel: no two rows write one byte.
  auto mix_row = [&](int k, int r) {
    Pair& p = pairs_[std::size_t(cut[std::size_t(k)])];
    const int cols = cols_of(p), R = w.mix_radius, n = rows[std::size_t(k)];
    for (int c = 0; c < cols; ++c) {
      if (p.costs[std::size_t(r) * cols + c] == seam::kOutside) continue;
      int sum = 0;
      for (int q = std::max(0, r - R); q <= std::min(n - 1, r + R); ++q) sum += p.across[std::size_t(q) * cols + c];
      const int bx = p.vertical ? c : r, by = p.vertical ? r : c;
      const int level = p.blank_a || p.blank_b ? 255 : seam::mix_level(w, sum);
      uint8_t& m = mix_[std::size_t(p.box.y + by) * width_ + p.box.x + bx];
      m = uint8_t(std::max(int(m), level));
      if (holding) p.levels[std::size_t(r) * cols + c] = uint8_t(level);
      if (w.crossing > 0.f) {
        float& v = p.costs[std::size_t(r) * cols + c];
        v = seam::crossing_cost(w, v, p.centre_cost[std::size_t(by) * p.box.width + bx], level);
      }
    }
  };
  // The DPs read the costs, which the mix pass changes only with a crossing or view-switch cost;
  // without them (the defaults) the sweeps run beside the mix rows, in one loop.
  const bool sweeps_beside_mix = mixing && boxes_disjoint_ && !holding && !(w.crossing > 0.f);
  if (mixing && !sweeps_beside_mix) write_rows(mix_row);
  if (holding) {  // the view-switch cost of every seam point: per row, sums before and after it
    parallel_for_parts(rows, [&](int k, int r) {
      Pair& p = pairs_[std::size_t(cut[std::size_t(k)])];
      if (int(p.previous_path.size()) != rows_of(p)) return;  // no last frame for this pair
      const int cols = cols_of(p);
      auto last = [&](int c) {
        const int bx = p.vertical ? c : r, by = p.vertical ? r : c;
        return previous_labels_[std::size_t(p.box.y + by) * width_ + p.box.x + bx];
      };
      int after_a = 0;  // sum of levels from column c on that showed view a last frame
      for (int c = 0; c < cols; ++c)
        if (last(c) == p.a) after_a += p.levels[std::size_t(r) * cols + c];
      int before_b = 0;  // sum of levels before column c that showed view b last frame
      for (int c = 0; c < cols; ++c) {
        float& v = p.costs[std::size_t(r) * cols + c];
        v = seam::view_switch_cost(w, v, before_b + after_a);
        const int level = p.levels[std::size_t(r) * cols + c], l = last(c);
        if (l == p.b) before_b += level;
        if (l == p.a) after_a -= level;
      }
    });
  }
  if (!sweeps_beside_mix) profile.mark("mix");
  // The DPs: both sweeps of every pair at once (2 tasks a pair), then each pair's path.
  std::vector<SeamDp> dps;
  dps.reserve(cut.size());
  for (const int index : cut) {
    Pair& p = pairs_[std::size_t(index)];
    const bool has_previous = int(p.previous_path.size()) == rows_of(p);
    dps.emplace_back(p.costs.data(), rows_of(p), cols_of(p), has_previous ? p.previous_path.data() : nullptr, w,
                     p.step.data());
  }
  const auto sweep = [&](int t) { dps[std::size_t(t / 2)].sweep(t % 2); };
  if (sweeps_beside_mix)
    parallel_tasks_beside_parts(int(2 * dps.size()), sweep, rows, mix_row);
  else if (!dps.empty())
    cv::parallel_for_(cv::Range(0, int(2 * dps.size())), [&](const cv::Range& r) {
      for (int t = r.start; t < r.end; ++t) sweep(t);
    }, double(2 * dps.size()));
  for (std::size_t k = 0; k < cut.size(); ++k) {
    Pair& p = pairs_[std::size_t(cut[k])];
    std::vector<int> path;
    dps[k].finish(path);
    p.path = path;
    p.previous_path = std::move(path);
  }
  profile.mark(sweeps_beside_mix ? "dp + mix" : "dp");
  // Every overlap pixel labelled a or b goes to a before the seam and to b after it.
  write_rows([&](int k, int r) {
    const Pair& p = pairs_[std::size_t(cut[std::size_t(k)])];
    const int cols = cols_of(p);
    for (int cc = 0; cc < cols; ++cc) {
      const int bx = p.vertical ? cc : r, by = p.vertical ? r : cc;
      if (p.centre_cost[std::size_t(by) * p.box.width + bx] < 0) continue;
      uint8_t& l = labels_[std::size_t(p.box.y + by) * width_ + p.box.x + bx];
      if (l == p.a || l == p.b) l = uint8_t(p.blank_a ? p.b : p.blank_b ? p.a : cc < p.path[std::size_t(r)] ? p.a : p.b);
    }
  });
  profile.mark("labels");
}

void apply_seam_mix(const std::vector<ViewPlacement>& views, const std::vector<ImageView>& warped,
                    const std::vector<uint8_t>& labels, const std::vector<uint8_t>& mix, const ImageView& out) {
  if (mix.empty()) return;
  if (mix.size() != std::size_t(out.width) * out.height || labels.size() != mix.size())
    throw std::invalid_argument("mix map size differs from the output");
  cv::parallel_for_(cv::Range(0, out.height), [&](const cv::Range& range) {
    for (int y = range.start; y < range.end; ++y) {
      const uint8_t* m = mix.data() + std::size_t(y) * out.width;
      const uint8_t* l = labels.data() + std::size_t(y) * out.width;
      uint8_t* o = out.row(y);
      for (int x = 0; x < out.width; ++x) {
        if (!m[x] || l[x] >= warped.size() || warped[l[x]].empty()) continue;
        const Rect& r = views[l[x]].roi;
        if (x < r.x || y < r.y || x >= r.x + r.width || y >= r.y + r.height) continue;
        const uint8_t* v = warped[l[x]].row(y - r.y) + 4 * (x - r.x);
        for (int k = 0; k < 3; ++k) o[4 * x + k] = seam::mix_value(o[4 * x + k], v[k], m[x]);
      }
    }
  });
}

}  // namespace stitch
