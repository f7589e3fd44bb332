// One parallel loop over the parts of several items (rows of several views, bands of several
// images, chunks of several pairs): one wait for the threads instead of one loop per item.
#pragma once
#include <algorithm>
#include <cstdint>
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

// task(t) for t in [0, tasks) and f(item, part) for every part of every item, in one parallel
// loop: long serial tasks (the seam DP sweeps) run beside many short parts instead of before or
// after them, so the other threads are not idle while the tasks run. The tasks sit spread over the
// loop's range, so that its first splits hand them to different threads.
template <class T, class F>
void parallel_tasks_beside_parts(int tasks, const T& task, const std::vector<int>& parts, const F& f) {
  std::vector<int> first(parts.size() + 1, 0);
  for (std::size_t i = 0; i < parts.size(); ++i) first[i + 1] = first[i] + parts[i];
  const int n = tasks + first.back();
  if (n == 0) return;
  std::vector<int> at(std::size_t(std::max(tasks, 0)));  // task t's index in the range, increasing
  for (int t = 0; t < tasks; ++t) at[std::size_t(t)] = int(int64_t(t) * n / tasks);
  cv::parallel_for_(cv::Range(0, n), [&](const cv::Range& r) {
    for (int k = r.start; k < r.end; ++k) {
      const int before = int(std::upper_bound(at.begin(), at.end(), k) - at.begin());  // tasks at or before k
      if (before > 0 && at[std::size_t(before - 1)] == k) {
        task(before - 1);
        continue;
      }
      const int part = k - before;
      const std::size_t i = std::size_t(std::upper_bound(first.begin(), first.end(), part) - first.begin()) - 1;
      f(i, part - first[i]);
    }
  }, double(n));
}

}  // namespace stitch
