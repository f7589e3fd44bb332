// One parallel loop over the parts of several items (rows of several views, bands of several
// images, chunks of several pairs): one wait for the threads instead of one loop per item.
#pragma once
#include <algorithm>
#include <vector>

#include <opencv2/core.hpp>

namespace stitch {

// f(item, part) for parts [0, parts[item]) of every item, spread over OpenCV's threads in one
// parallel_for_ (`nstripes` as there); each (item, part) is computed as in a plain loop.
template <class F>
void parallel_for_parts(const std::vector<int>& parts, const F& f, double nstripes = -1.) {
  std::vector<int> first(parts.size() + 1, 0);  // item i's parts are [first[i], first[i + 1])
  for (std::size_t i = 0; i < parts.size(); ++i) first[i + 1] = first[i] + parts[i];
  if (first.back() == 0) return;
  cv::parallel_for_(cv::Range(0, first.back()), [&](const cv::Range& r) {
    std::size_t i = std::size_t(std::upper_bound(first.begin(), first.end(), r.start) - first.begin()) - 1;
    for (int k = r.start; k < r.end; ++k) {
      while (k >= first[i + 1]) ++i;
      f(i, k - first[i]);
    }
  }, nstripes);
}

}  // namespace stitch
