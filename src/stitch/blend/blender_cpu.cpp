#include "stitch/blend/blender_cpu.hpp"

#include <algorithm>
#include <cstring>
#include "stitch/blend/seam_math.hpp"

#include <Eigen/Core>
#include <opencv2/core/hal/intrin.hpp>
#include <stdexcept>

#ifdef STITCH_HAVE_CUDA
#include "stitch/cuda/stages_cuda.hpp"
#endif

namespace stitch {

cv::Mat position_weight_map(const ViewPlacement& v) {
  if (v.roi.empty()) return cv::Mat();
  cv::Mat w(v.roi.height, v.roi.width, CV_32F);
  cv::parallel_for_(cv::Range(0, v.roi.height), [&](const cv::Range& r) {
    for (int y = r.start; y < r.end; ++y) {
      float* pw = w.ptr<float>(y);
      const double oy = v.roi.y + y;
      for (int x = 0; x < v.roi.width; ++x) {
        const double ox = v.roi.x + x;
        double u, vv;
        pw[x] = view_to_camera(v, ox, oy, u, vv) ? view_position_weight(v, u, vv) : 0.f;
      }
    }
  });
  return w;
}

void BlenderCpu::prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height) {
  if (views.size() > 64) throw std::invalid_argument("at most 64 views");
  views_ = views;
  out_w_ = out_width;
  out_h_ = out_height;
  row_first_ = 0;
  row_end_ = out_height;
  normalised_.clear();
  spans_.clear();
  cores_.clear();
  raw_.assign(views.size(), cv::Mat());
  for (std::size_t i = 0; i < views.size(); ++i) raw_[i] = position_weight_map(views[i]);
}

const std::vector<cv::Mat>& BlenderCpu::weights_for(uint64_t mask) {
  auto it = normalised_.find(mask);
  if (it != normalised_.end()) return it->second;
  if (normalised_.size() > 16) normalised_.clear();  // bounded: masks change only on dropouts
  const int one = 1 << kWeightBits;
  cv::Mat sum(out_h_, out_w_, CV_32F, cv::Scalar(0));
  for (std::size_t i = 0; i < raw_.size(); ++i) {
    if (!(mask >> i & 1) || raw_[i].empty()) continue;
    const Rect& r = views_[i].roi;
    cv::Mat roi = sum(cv::Rect(r.x, r.y, r.width, r.height));
    const cv::Mat& w = raw_[i];
    // whole rows on every core (cv::Mat's += runs on one); the views stay in order per pixel
    cv::parallel_for_(cv::Range(0, r.height), [&](const cv::Range& rows) {
      for (int y = rows.start; y < rows.end; ++y) {
        float* ps = roi.ptr<float>(y);
        const float* pw = w.ptr<float>(y);
        for (int x = 0; x < r.width; ++x) ps[x] += pw[x];
      }
    });
  }
  std::vector<cv::Mat> q(raw_.size());
  cv::Mat qsum(out_h_, out_w_, CV_32S, cv::Scalar(0));
  cv::Mat best(out_h_, out_w_, CV_8S, cv::Scalar(-1));
  cv::Mat bestw(out_h_, out_w_, CV_32F, cv::Scalar(0));
  for (std::size_t i = 0; i < raw_.size(); ++i) {
    if (!(mask >> i & 1) || raw_[i].empty()) continue;
    const Rect& r = views_[i].roi;
    q[i].create(r.height, r.width, CV_16U);
    cv::parallel_for_(cv::Range(0, r.height), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      const float* pw = raw_[i].ptr<float>(y);
      const float* ps = sum.ptr<float>(r.y + y) + r.x;
      uint16_t* pq = q[i].ptr<uint16_t>(y);
      int32_t* pqs = qsum.ptr<int32_t>(r.y + y) + r.x;
      int8_t* pb = best.ptr<int8_t>(r.y + y) + r.x;
      float* pbw = bestw.ptr<float>(r.y + y) + r.x;
      for (int x = 0; x < r.width; ++x) {
        const int v = ps[x] > 0 ? int(pw[x] / ps[x] * one + 0.5f) : 0;
        pq[x] = static_cast<uint16_t>(v);
        pqs[x] += v;
        if (pw[x] > pbw[x]) {
          pbw[x] = pw[x];
          pb[x] = static_cast<int8_t>(i);
        }
      }
    }
    });
  }
  // Give the rounding remainder to the strongest view so covered pixels sum to exactly 1.
  cv::parallel_for_(cv::Range(0, out_h_), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      const int32_t* pqs = qsum.ptr<int32_t>(y);
      const int8_t* pb = best.ptr<int8_t>(y);
      for (int x = 0; x < out_w_; ++x) {
        if (pb[x] < 0 || pqs[x] == one) continue;
        const Rect& r = views_[pb[x]].roi;
        uint16_t& w = q[pb[x]].at<uint16_t>(y - r.y, x - r.x);
        w = static_cast<uint16_t>(int(w) + one - pqs[x]);
      }
    }
  });
  return normalised_.emplace(mask, std::move(q)).first->second;
}

const std::vector<std::vector<BlenderCpu::Span>>& BlenderCpu::spans_for(uint64_t mask) {
  auto it = spans_.find(mask);
  if (it != spans_.end()) return it->second;
  if (spans_.size() > 16) spans_.clear();
  const std::vector<cv::Mat>& weights = weights_for(mask);
  const uint16_t one = uint16_t(1 << kWeightBits);
  std::vector<std::vector<Span>> rows(static_cast<std::size_t>(out_h_));
  cv::parallel_for_(cv::Range(0, out_h_), [&](const cv::Range& range) {
    std::vector<int> state(static_cast<std::size_t>(out_w_));
    for (int y = range.start; y < range.end; ++y) {
      std::fill(state.begin(), state.end(), kUncovered);
      for (std::size_t i = 0; i < views_.size(); ++i) {
        if (!(mask >> i & 1) || weights[i].empty()) continue;
        const Rect& r = views_[i].roi;
        if (y < r.y || y >= r.y + r.height) continue;
        const uint16_t* pw = weights[i].ptr<uint16_t>(y - r.y);
        for (int x = 0; x < r.width; ++x) {
          if (!pw[x]) continue;
          int& st = state[static_cast<std::size_t>(r.x + x)];
          st = pw[x] == one && st == kUncovered ? int(i) : kMixed;
        }
      }
      std::vector<Span>& spans = rows[static_cast<std::size_t>(y)];
      for (int x = 0; x < out_w_;) {
        int e = x + 1;
        while (e < out_w_ && state[static_cast<std::size_t>(e)] == state[static_cast<std::size_t>(x)]) ++e;
        spans.push_back({x, e, state[static_cast<std::size_t>(x)]});
        x = e;
      }
    }
  });
  return spans_.emplace(mask, std::move(rows)).first->second;
}

void BlenderCpu::fuse(const std::vector<ImageView>& warped, const ImageView& out) {
  fuse_rows(warped, out, nullptr, nullptr, nullptr);
}

void BlenderCpu::fuse_mixed(const std::vector<ImageView>& warped, const ImageView& out,
                            const std::vector<uint8_t>& labels, const std::vector<uint8_t>& mix,
                            const std::vector<Rect>& regions) {
  if (mix.empty()) {
    fuse_rows(warped, out, nullptr, nullptr, nullptr);
    return;
  }
  if (mix.size() != std::size_t(out.width) * out.height || labels.size() != mix.size())
    throw std::invalid_argument("mix map size differs from the output");
  fuse_rows(warped, out, &labels, &mix, &regions);
}

void BlenderCpu::fuse_rows(const std::vector<ImageView>& warped, const ImageView& out,
                           const std::vector<uint8_t>* labels, const std::vector<uint8_t>* mix,
                           const std::vector<Rect>* regions) {
  if (warped.size() != views_.size()) throw std::invalid_argument("view count differs from prepare()");
  if (out.width != out_w_ || out.height != out_h_) throw std::invalid_argument("output size differs from prepare()");
  if (out.on_device) throw std::invalid_argument("CPU blender got device memory");
  uint64_t mask = 0;
  for (std::size_t i = 0; i < warped.size(); ++i)
    if (!warped[i].empty() && !views_[i].roi.empty()) mask |= uint64_t(1) << i;
  const std::vector<cv::Mat>& weights = weights_for(mask);
  const std::vector<std::vector<Span>>& row_spans = spans_for(mask);
  cv::parallel_for_(cv::Range(row_first_, row_end_), [&](const cv::Range& range) {
    std::vector<uint32_t> acc(static_cast<std::size_t>(out_w_) * 4);
    std::vector<std::pair<int, int>> spans;  // this row's columns [x0, x1) that the mix may touch
    for (int y = range.start; y < range.end; ++y) {
      uint8_t* po = out.row(y);
      for (const Span& span : row_spans[static_cast<std::size_t>(y)]) {
        if (span.view == kUncovered) {  // the panorama is opaque: uncovered corners are black
          for (int x = span.x0; x < span.x1; ++x) po[4 * x] = po[4 * x + 1] = po[4 * x + 2] = 0, po[4 * x + 3] = 255;
          continue;
        }
        if (span.view >= 0) {  // one view's weight is 1: (w p + half) >> kWeightBits = p
          const std::size_t v = static_cast<std::size_t>(span.view);
          const Rect& r = views_[v].roi;
          auto copy = [&](int x0, int x1) {
            if (x1 <= x0) return;
            std::memcpy(po + 4 * x0, warped[v].row(y - r.y) + 4 * (x0 - r.x), static_cast<std::size_t>(x1 - x0) * 4);
            for (int x = x0; x < x1; ++x) po[4 * x + 3] = 255;
          };
          // The view's core on this row is in the output already (set_cores): the rest is copied.
          std::pair<int, int> core{0, 0};
          const int band = (y - r.y) / kCoreBand;
          if (v < cores_.size() && band < int(cores_[v].size())) core = cores_[v][static_cast<std::size_t>(band)];
          if (core.second <= core.first) {
            copy(span.x0, span.x1);
          } else {
            copy(span.x0, std::min(span.x1, core.first));
            copy(std::max(span.x0, core.second), span.x1);
          }
          continue;
        }
        // Several views: the weighted sum of the span's pixels.
        std::fill(acc.begin() + 4 * span.x0, acc.begin() + 4 * span.x1, 0u);
        for (std::size_t i = 0; i < warped.size(); ++i) {
          if (!(mask >> i & 1)) continue;
          const Rect& r = views_[i].roi;
          if (y < r.y || y >= r.y + r.height) continue;
          const int x0 = std::max(span.x0, r.x), x1 = std::min(span.x1, r.x + r.width);
          if (x1 <= x0) continue;
          const uint16_t* pw = weights[i].ptr<uint16_t>(y - r.y) + (x0 - r.x);
          const uint8_t* pp = warped[i].row(y - r.y) + 4 * (x0 - r.x);
          uint32_t* pa = acc.data() + static_cast<std::size_t>(x0) * 4;
          const int width = x1 - x0;
          int x = 0;
#if CV_SIMD128
          // 4 pixels at a time: each pixel's weight times its 4 channels (exact integers, as below)
          for (; x + 4 <= width; x += 4) {
            cv::v_uint16x8 p0, p1, w2, w2b, w01, w23;
            cv::v_expand(cv::v_load(pp + 4 * x), p0, p1);
            const cv::v_uint16x8 w4 = cv::v_load_low(pw + x);
            cv::v_zip(w4, w4, w2, w2b);     // w0 w0 w1 w1 w2 w2 w3 w3
            cv::v_zip(w2, w2, w01, w23);    // w0 x4, w1 x4 | w2 x4, w3 x4
            cv::v_uint32x4 m0, m1, m2, m3;
            cv::v_mul_expand(p0, w01, m0, m1);
            cv::v_mul_expand(p1, w23, m2, m3);
            uint32_t* q = pa + 4 * x;
            cv::v_store(q, cv::v_load(q) + m0);
            cv::v_store(q + 4, cv::v_load(q + 4) + m1);
            cv::v_store(q + 8, cv::v_load(q + 8) + m2);
            cv::v_store(q + 12, cv::v_load(q + 12) + m3);
          }
#endif
          for (; x < width; ++x) {
            const uint32_t w = pw[x];
            pa[4 * x + 0] += w * pp[4 * x + 0];
            pa[4 * x + 1] += w * pp[4 * x + 1];
            pa[4 * x + 2] += w * pp[4 * x + 2];
            pa[4 * x + 3] += w * pp[4 * x + 3];
          }
        }
        constexpr uint32_t half = 1u << (kWeightBits - 1);
        const int n = (span.x1 - span.x0) * 4;
        const uint32_t* pa = acc.data() + static_cast<std::size_t>(span.x0) * 4;
        uint8_t* ps = po + 4 * span.x0;
        int x = 0;
#if CV_SIMD128
        // (acc + half) >> kWeightBits (at most 255: the weights sum to 1), alpha set to 255
        const cv::v_uint8x16 opaque = cv::v_reinterpret_as_u8(cv::v_setall_u32(0xff000000u));
        for (; x + 16 <= n; x += 16) {
          const cv::v_uint16x8 lo = cv::v_rshr_pack<kWeightBits>(cv::v_load(pa + x), cv::v_load(pa + x + 4));
          const cv::v_uint16x8 hi = cv::v_rshr_pack<kWeightBits>(cv::v_load(pa + x + 8), cv::v_load(pa + x + 12));
          cv::v_store(ps + x, cv::v_pack(lo, hi) | opaque);
        }
#endif
        for (; x < n; ++x) ps[x] = static_cast<uint8_t>((pa[x] + half) >> kWeightBits);
        for (int u = span.x0; u < span.x1; ++u) po[4 * u + 3] = 255;
      }
      if (!mix) continue;
      // The consensus blend's mix on this row (apply_seam_mix's arithmetic), in its regions'
      // columns, each column once.
      spans.clear();
      for (const Rect& g : *regions)
        if (y >= g.y && y < g.y + g.height) spans.push_back({std::max(0, g.x), std::min(out_w_, g.x + g.width)});
      std::sort(spans.begin(), spans.end());
      int done = 0;
      const uint8_t* m = mix->data() + std::size_t(y) * out_w_;
      const uint8_t* l = labels->data() + std::size_t(y) * out_w_;
      for (const auto& s : spans)
        for (int x = std::max(s.first, done); x < s.second; ++x) {
          done = x + 1;
          if (!m[x] || l[x] >= warped.size() || warped[l[x]].empty()) continue;
          const Rect& r = views_[l[x]].roi;
          if (x < r.x || y < r.y || x >= r.x + r.width || y >= r.y + r.height) continue;
          const uint8_t* v = warped[l[x]].row(y - r.y) + 4 * (x - r.x);
          for (int k = 0; k < 3; ++k) po[4 * x + k] = seam::mix_value(po[4 * x + k], v[k], m[x]);
        }
    }
  });
}

std::unique_ptr<Blender> Blender::create(Backend backend) {
  switch (resolve_backend(backend, /*stage_has_cuda=*/true)) {
#ifdef STITCH_HAVE_CUDA
    case Backend::Cuda: return make_blender_cuda();
#endif
    case Backend::Cpu: return std::make_unique<BlenderCpu>();
    default: break;
  }
  throw std::runtime_error("no blender for this backend");
}

}  // namespace stitch
