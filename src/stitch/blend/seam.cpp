#include "stitch/blend/seam.hpp"

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
}

const std::vector<uint8_t>& SeamFinder::find(const std::vector<ImageView>& warped) {
  if (warped.size() != views_.size()) throw std::invalid_argument("view count differs from prepare()");
  uint64_t mask = 0;
  for (std::size_t i = 0; i < warped.size(); ++i) {
    if (warped[i].empty() || views_[i].roi.empty()) {
      luma_[i].clear();
      continue;
    }
    if (warped[i].on_device) throw std::invalid_argument("the seam finder reads views in host memory");
    mask |= uint64_t(1) << i;
    // Luma of the view (r + 2g + b) / 4: the seam's costs are measured on it.
    const Rect& r = views_[i].roi;
    std::swap(luma_[i], previous_luma_[i]);
    luma_[i].resize(std::size_t(r.width) * r.height);
    for_rows(r.height, [&](int y) {
      const uint8_t* p = warped[i].row(y);
      uint8_t* l = luma_[i].data() + std::size_t(y) * r.width;
      for (int x = 0; x < r.width; ++x) l[x] = seam::luma(p + 4 * x);
    });
    if (previous_luma_[i].size() != luma_[i].size()) previous_luma_[i] = luma_[i];
  }
  if (mask != nearest_mask_) {
    nearest_ = nearest_view_labels(views_, width_, height_, mask);
    nearest_mask_ = mask;
  }
  // labels_ = nearest_ and a zeroed mix map, by rows on OpenCV's threads (full-frame byte maps:
  // a serial copy and fill were ~3 ms per 3x1080p canvas, a serial section on every core count)
  std::swap(labels_, previous_labels_);  // last frame's, for the view-switch cost
  labels_.resize(nearest_.size());
  if (settings_.mix_radius > 0)
    mix_.resize(std::size_t(width_) * height_);
  else
    mix_.clear();
  for_rows(height_, [&](int y) {
    const std::size_t row = std::size_t(y) * width_;
    if (row + width_ <= nearest_.size()) std::copy_n(nearest_.data() + row, width_, labels_.data() + row);
    if (!mix_.empty()) std::fill_n(mix_.data() + row, width_, uint8_t(0));
  });
  for (Pair& p : pairs_) {
    if (!(mask >> p.a & 1) || !(mask >> p.b & 1)) {
      p.path.clear();
      continue;
    }
    cut(p, warped);
  }
  return labels_;
}

void seam_path(const std::vector<float>& costs, int rows, int cols, const int* previous, const seam::Weights& w,
               std::vector<int>& path) {
  const int m = seam::dp_meeting_row(rows);
  std::vector<float> total(cols);
  std::vector<int8_t> step(std::size_t(rows) * cols), meet(cols);
  // One sweep over rows first, first + dir, ... (count of them), on energy rows padded for
  // dp_cell_padded; returns the last row's energies (with their pads) and last frame's path's
  // cost, summed in the sweep's row order.
  auto sweep = [&](int first, int dir, int count, float& previous_sum) {
    std::vector<float> above(cols + 2, 0.f), here(cols + 2, 0.f);
    above[0] = above[cols + 1] = here[0] = here[cols + 1] = std::numeric_limits<float>::infinity();
    previous_sum = 0.f;
    for (int k = 0, r = first; k < count; ++k, r += dir) {
      const float* cost_row = costs.data() + std::size_t(r) * cols;
      const int prev = previous ? previous[r] : -1;
      for (int c = 0; c < cols; ++c)
        step[std::size_t(r) * cols + c] =
            int8_t(seam::dp_cell_padded(above.data() + 1, c, cost_row[c], w.stability, prev, here[c + 1]));
      if (previous) previous_sum = seam::add(previous_sum, cost_row[prev]);
      std::swap(above, here);
    }
    return above;
  };
  float down_sum = 0.f, up_sum = 0.f;
  const std::vector<float> down = sweep(0, 1, m, down_sum), up = sweep(rows - 1, -1, rows - m, up_sum);
  for (int c = 0; c < cols; ++c)
    meet[c] = int8_t(seam::meet_cell(down.data() + 1, up.data() + 1, c, cols, m == 0, total[c]));
  const int best = int(std::min_element(total.begin(), total.end()) - total.begin());
  path.assign(rows, 0);
  if (previous && seam::keep_previous(seam::add(down_sum, up_sum), total[best], rows, w.hold)) {
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

void SeamFinder::cut(Pair& p, const std::vector<ImageView>& warped) {
  // Work in the seam's frame: "rows" run along the seam, "columns" across it.
  const int rows = p.vertical ? p.box.height : p.box.width, cols = p.vertical ? p.box.width : p.box.height;
  const Rect &ra = views_[p.a].roi, &rb = views_[p.b].roi;
  const std::vector<uint8_t> &la = luma_[p.a], &lb = luma_[p.b], &pa = previous_luma_[p.a], &pb = previous_luma_[p.b];
  auto luma = [](const std::vector<uint8_t>& l, const Rect& r, int x, int y) {
    x = std::min(std::max(x, r.x), r.x + r.width - 1);
    y = std::min(std::max(y, r.y), r.y + r.height - 1);
    return int(l[std::size_t(y - r.y) * r.width + (x - r.x)]);
  };
  const seam::Weights w = weights();
  auto cost = [&](int row, int col) {
    const int bx = p.vertical ? col : row, by = p.vertical ? row : col;
    const float centre = p.centre_cost[std::size_t(by) * p.box.width + bx];
    if (centre < 0) return seam::kOutside;
    const int x = p.box.x + bx, y = p.box.y + by;
    const int a = luma(la, ra, x, y), b = luma(lb, rb, x, y);
    const int gradients = std::abs(luma(la, ra, x + 1, y) - luma(la, ra, x - 1, y)) +
                          std::abs(luma(la, ra, x, y + 1) - luma(la, ra, x, y - 1)) +
                          std::abs(luma(lb, rb, x + 1, y) - luma(lb, rb, x - 1, y)) +
                          std::abs(luma(lb, rb, x, y + 1) - luma(lb, rb, x, y - 1));
    const int motion = std::abs(a - luma(pa, ra, x, y)) + std::abs(b - luma(pb, rb, x, y));
    const float difference = seam::color_difference(warped[p.a].row(y - ra.y) + 4 * (x - ra.x),
                                                    warped[p.b].row(y - rb.y) + 4 * (x - rb.x));
    return seam::pixel_cost(w, difference, gradients, motion, centre);
  };
  const bool has_previous = int(p.previous_path.size()) == rows;
  // Every cell's cost once (the DP and last frame's path read it), then the clearance term.
  std::vector<float> costs(std::size_t(rows) * cols);
  // A blank (black, missing-signal) view loses the overlap: its dark pixels counted per row (the
  // rows run in parallel; integer sums, so the same in any order).
  std::vector<int> row_cells(rows, 0), row_dark_a(rows, 0), row_dark_b(rows, 0);
  for_rows(rows, [&](int r) {
    for (int c = 0; c < cols; ++c) {
      const float v = costs[std::size_t(r) * cols + c] = cost(r, c);
      if (v == seam::kOutside) continue;
      const int x = p.box.x + (p.vertical ? c : r), y = p.box.y + (p.vertical ? r : c);
      row_cells[r]++;
      row_dark_a[r] += luma(la, ra, x, y) <= seam::kDark;
      row_dark_b[r] += luma(lb, rb, x, y) <= seam::kDark;
    }
  });
  int cells = 0, dark_a = 0, dark_b = 0;
  for (int r = 0; r < rows; ++r) cells += row_cells[r], dark_a += row_dark_a[r], dark_b += row_dark_b[r];
  const bool blank_a = seam::view_blank(dark_a, dark_b, cells), blank_b = seam::view_blank(dark_b, dark_a, cells);
  const bool clearance = w.clearance_radius > 0 && w.clearance > 0.f, mixing = w.mix_radius > 0;
  std::vector<int> diff, across;
  const bool holding = mixing && w.label_hold > 0.f && has_previous && previous_labels_.size() == labels_.size();
  std::vector<uint8_t> levels(holding ? costs.size() : 0);  // this pair's mix levels, for the view-switch cost
  if (clearance || mixing) {
    diff.assign(costs.size(), 0);
    across.resize(costs.size());
    for_rows(rows, [&](int r) {
      for (int c = 0; c < cols; ++c) {
        if (costs[std::size_t(r) * cols + c] == seam::kOutside) continue;
        const int bx = p.vertical ? c : r, by = p.vertical ? r : c, x = p.box.x + bx, y = p.box.y + by;
        diff[std::size_t(r) * cols + c] = seam::color_difference_sum(warped[p.a].row(y - ra.y) + 4 * (x - ra.x),
                                                                     warped[p.b].row(y - rb.y) + 4 * (x - rb.x));
      }
    });
  }
  auto across_sums = [&](int R) {  // window sums across the seam (then along it: integers, exact)
    for_rows(rows, [&](int r) {
      for (int c = 0; c < cols; ++c) {
        int sum = 0;
        for (int k = std::max(0, c - R); k <= std::min(cols - 1, c + R); ++k) sum += diff[std::size_t(r) * cols + k];
        across[std::size_t(r) * cols + c] = sum;
      }
    });
  };
  if (clearance) {
    const int R = w.clearance_radius;
    across_sums(R);
    for_rows(rows, [&](int r) {
      for (int c = 0; c < cols; ++c) {
        float& v = costs[std::size_t(r) * cols + c];
        if (v == seam::kOutside) continue;
        int sum = 0;
        for (int k = std::max(0, r - R); k <= std::min(rows - 1, r + R); ++k) sum += across[std::size_t(k) * cols + c];
        v = seam::add(v, seam::clearance_cost(w, sum));
      }
    });
  }
  if (mixing) {  // the consensus blend's mix level of every overlap pixel (max over pairs)
    const int R = w.mix_radius;
    across_sums(R);
    for_rows(rows, [&](int r) {  // each (r, c) is its own output pixel: no two rows write one byte
      for (int c = 0; c < cols; ++c) {
        if (costs[std::size_t(r) * cols + c] == seam::kOutside) continue;
        int sum = 0;
        for (int k = std::max(0, r - R); k <= std::min(rows - 1, r + R); ++k) sum += across[std::size_t(k) * cols + c];
        const int bx = p.vertical ? c : r, by = p.vertical ? r : c;
        const int level = blank_a || blank_b ? 255 : seam::mix_level(w, sum);
        uint8_t& m = mix_[std::size_t(p.box.y + by) * width_ + p.box.x + bx];
        m = uint8_t(std::max(int(m), level));
        if (holding) levels[std::size_t(r) * cols + c] = uint8_t(level);
        float& v = costs[std::size_t(r) * cols + c];
        v = seam::crossing_cost(w, v, p.centre_cost[std::size_t(by) * p.box.width + bx], level);
      }
    });
  }
  if (holding) {  // the view-switch cost of every seam point: per row, sums before and after it
    for_rows(rows, [&](int r) {
      int after_a = 0;  // sum of levels from column c on that showed view a last frame
      auto last = [&](int c) {
        const int bx = p.vertical ? c : r, by = p.vertical ? r : c;
        return previous_labels_[std::size_t(p.box.y + by) * width_ + p.box.x + bx];
      };
      for (int c = 0; c < cols; ++c)
        if (last(c) == p.a) after_a += levels[std::size_t(r) * cols + c];
      int before_b = 0;  // sum of levels before column c that showed view b last frame
      for (int c = 0; c < cols; ++c) {
        float& v = costs[std::size_t(r) * cols + c];
        v = seam::view_switch_cost(w, v, before_b + after_a);
        const int level = levels[std::size_t(r) * cols + c], l = last(c);
        if (l == p.b) before_b += level;
        if (l == p.a) after_a -= level;
      }
    });
  }
  std::vector<int> path;
  seam_path(costs, rows, cols, has_previous ? p.previous_path.data() : nullptr, w, path);
  p.path = path;
  p.previous_path = path;
  // Every overlap pixel labelled a or b goes to a before the seam and to b after it.
  for_rows(rows, [&](int r) {
    for (int cc = 0; cc < cols; ++cc) {
      const int bx = p.vertical ? cc : r, by = p.vertical ? r : cc;
      if (p.centre_cost[std::size_t(by) * p.box.width + bx] < 0) continue;
      uint8_t& l = labels_[std::size_t(p.box.y + by) * width_ + p.box.x + bx];
      if (l == p.a || l == p.b) l = uint8_t(blank_a ? p.b : blank_b ? p.a : cc < path[r] ? p.a : p.b);
    }
  });
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
