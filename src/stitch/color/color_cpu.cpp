#include <opencv2/core.hpp>
#include <opencv2/core/hal/intrin.hpp>
#include <algorithm>
#include <stdexcept>

#include "stitch/color/color.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/parallel.hpp"

#ifdef STITCH_HAVE_CUDA
#include "stitch/cuda/stages_cuda.hpp"
#endif

namespace stitch {
namespace {

bool usable(const uint8_t* p, const ColorReductionRequest& r) {
  const bool dark = p[0] <= r.dark_level && p[1] <= r.dark_level && p[2] <= r.dark_level;
  const bool bright = p[0] >= r.bright_level || p[1] >= r.bright_level || p[2] >= r.bright_level;
  return !dark && !bright;
}

// The pixel at (x, y), or nullptr outside the view.
const uint8_t* pixel(const ImageView& view, int32_t x, int32_t y) {
  if (x < 0 || y < 0 || x >= view.width || y >= view.height) return nullptr;
  return view.row(y) + 4 * std::size_t(x);
}

// L1 luma gradient at (x, y), central differences clamped to the view.
int luma_gradient(const ImageView& v, int x, int y) {
  const int x0 = std::max(0, x - 1), x1 = std::min(v.width - 1, x + 1);
  const int y0 = std::max(0, y - 1), y1 = std::min(v.height - 1, y + 1);
  const auto at = [&](int px, int py) { return mask_luma(v.row(py) + 4 * std::size_t(px)); };
  return std::abs(at(x1, y) - at(x0, y)) + std::abs(at(x, y1) - at(x, y0));
}

void add_moments(Moments3& m, const uint8_t* x, const uint8_t* y) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m[3 * r + c] += uint64_t(x[r]) * y[c];
}

// Samples are reduced in chunks of this many (a fixed split: the thread count does not matter).
// 1024, not 4096: a pair has 16384 samples at most, so 4096 gave 8 chunks on 3 cameras and left
// half of 16 threads idle in every pass (BENCHMARKS.md, "The colour stage on 16 threads").
constexpr int kChunk = 1024;
int chunk_count(int n) { return std::max(1, (n + kChunk - 1) / kChunk); }
// f(chunk, first, end) for every chunk of n samples, on OpenCV's threads.
template <class F>
void in_chunks(int n, const F& f) {
  cv::parallel_for_(cv::Range(0, chunk_count(n)), [&](const cv::Range& r) {
    for (int c = r.start; c < r.end; ++c) f(c, c * kChunk, std::min(n, (c + 1) * kChunk));
  });
}

// One row of n RGBA pixels in place, in one pass: out_c = sum_k in_k M(k, c) rounded to the
// nearest (ties to even, as cv::saturate_cast) and saturated, alpha kept (M: row-major M(k, c);
// nullptr: none); then the highlight roll-off where the input's brightest channel is above `knee`
// (255: none); then the balance curves (nullptr: none). Four pixels at a time in 4-lane float
// SIMD (cv::transform takes a scalar path for four channels: 3x slower, measured).
void apply_color_row(uint8_t* row, int n, const float* M, int knee, const uint8_t* const* curves) {
  uint8_t input[16];
  int x = 0;
  if (M) {
    const cv::v_float32x4 c0(M[0], M[1], M[2], 0.f), c1(M[3], M[4], M[5], 0.f), c2(M[6], M[7], M[8], 0.f),
        c3(0.f, 0.f, 0.f, 1.f);
    const auto transformed = [&](const cv::v_uint32x4& p) {
      return cv::v_round(cv::v_matmul(cv::v_cvt_f32(cv::v_reinterpret_as_s32(p)), c0, c1, c2, c3));
    };
    const cv::v_uint8x16 rgb(255, 255, 255, 0, 255, 255, 255, 0, 255, 255, 255, 0, 255, 255, 255, 0),
        knee_level = cv::v_setall_u8(uint8_t(knee));
    for (; x + 4 <= n; x += 4) {
      uint8_t* o = row + 4 * x;
      const cv::v_uint8x16 in = cv::v_load(o);
      // The roll-off only where a colour channel of one of the four is above the knee.
      const bool hot = knee < 255 && cv::v_check_any((in & rgb) > knee_level);
      cv::v_uint16x8 lo, hi;
      cv::v_expand(in, lo, hi);
      cv::v_uint32x4 p0, p1, p2, p3;
      cv::v_expand(lo, p0, p1);
      cv::v_expand(hi, p2, p3);
      const cv::v_uint8x16 out =
          cv::v_pack_u(cv::v_pack(transformed(p0), transformed(p1)), cv::v_pack(transformed(p2), transformed(p3)));
      if (hot) cv::v_store(input, in);
      cv::v_store(o, out);
      if (hot)
        for (int k = 0; k < 4; ++k) {
          const uint8_t* q = input + 4 * k;
          const int m = std::max({q[0], q[1], q[2]});
          if (m > knee)
            for (int c = 0; c < 3; ++c) o[4 * k + c] = highlight_blend(o[4 * k + c], q[c], m, knee);
        }
    }
    for (; x < n; ++x) {  // the last pixels of a row whose width is not a multiple of 4
      uint8_t* o = row + 4 * x;
      const uint8_t q[3] = {o[0], o[1], o[2]};
      for (int c = 0; c < 3; ++c)
        o[c] = cv::saturate_cast<uint8_t>(float(q[0]) * M[c] + float(q[1]) * M[3 + c] + float(q[2]) * M[6 + c]);
      const int m = std::max({q[0], q[1], q[2]});
      if (m > knee)
        for (int c = 0; c < 3; ++c) o[c] = highlight_blend(o[c], q[c], m, knee);
    }
  }
  if (curves)
    for (int k = 0; k < n; ++k) {
      uint8_t* o = row + 4 * k;
      o[0] = curves[0][o[0]], o[1] = curves[1][o[1]], o[2] = curves[2][o[2]];
    }
}

class ColorOpsCpu final : public ColorOps {
 public:
  void set_sampling(const ColorSampling& sampling) override {
    sampling_ = sampling;
    motion_.assign(sampling_.pairs.size(), {});
    for (std::size_t k = 0; k < sampling_.pairs.size(); ++k) motion_[k].assign(std::size_t(sampling_.pairs[k].count()), {});
    fresh_ = true;
  }
  void reset_motion() override { fresh_ = true; }

  // Loops over the samples in fixed chunks on OpenCV's threads, partial integer sums added in
  // chunk order: the same integers as one plain loop (and as the CUDA kernels) at any thread count.
  void reduce(const std::vector<ImageView>& views, const ColorReductionRequest& request,
              ColorStats& out) override {
    if (views.size() != sampling_.balance_xy.size()) throw std::invalid_argument("color: views do not match the sampling");
    if (request.balance && request.balance_matrices.size() < views.size())
      throw std::invalid_argument("color: a balance matrix per view is needed");
    out.pairs.resize(sampling_.pairs.size());
    // Every pair's chunks in one parallel loop per pass (one wait for the threads per pass, not
    // one per pair and pass); each pair's partial sums are still added in its chunk order.
    std::vector<int> active;  // the pairs reduced this frame
    for (std::size_t k = 0; k < sampling_.pairs.size(); ++k) {
      out.pairs[k] = PairStats{};
      const ColorSampling::Pair& g = sampling_.pairs[k];
      if (request.pairs && !views[g.a].empty() && !views[g.b].empty()) active.push_back(int(k));
    }
    std::vector<int> chunks, first{0};  // active pair j's chunks are [first[j], first[j + 1])
    for (const int k : active) {
      chunks.push_back(chunk_count(sampling_.pairs[std::size_t(k)].count()));
      first.push_back(first.back() + chunks.back());
    }
    // f(j, chunk, i0, i1): chunk (global index) of active pair j, its samples [i0, i1)
    auto for_chunks = [&](const auto& f) {
      parallel_for_parts(chunks, [&](std::size_t j, int local) {
        const int n = sampling_.pairs[std::size_t(active[j])].count();
        f(j, first[j] + local, local * kChunk, std::min(n, (local + 1) * kChunk));
      });
    };
    std::vector<PairStats> part(std::size_t(first.back()));
    std::vector<uint64_t> moved(std::size_t(first.back()), 0);
    // Pass 1 (the mask): which samples changed since the last frame, and how many.
    for_chunks([&](std::size_t j, int c, int i0, int i1) {
      const ColorSampling::Pair& g = sampling_.pairs[std::size_t(active[j])];
      std::vector<SampleState>& state = motion_[std::size_t(active[j])];
      PairStats& ps = part[std::size_t(c)];
      for (int i = i0; i < i1; ++i) {
        const uint8_t* a = pixel(views[g.a], g.xy_a[2 * i], g.xy_a[2 * i + 1]);
        const uint8_t* b = pixel(views[g.b], g.xy_b[2 * i], g.xy_b[2 * i + 1]);
        SampleState& st = state[std::size_t(i)];
        st.moved = 0;
        if (!a || !b) continue;
        ++ps.inview;
        if (!fresh_ && (mask_moved(a, st.a, request.motion_threshold) || mask_moved(b, st.b, request.motion_threshold))) {
          st.moved = 1;
          ++moved[std::size_t(c)];
        }
        for (int ch = 0; ch < 3; ++ch) {
          st.a[ch] = a[ch];
          st.b[ch] = b[ch];
          ps.sum_a[ch] += a[ch];
          ps.sum_b[ch] += b[ch];
        }
      }
    });
    std::vector<char> restart(active.size(), 0);
    for (std::size_t j = 0; j < active.size(); ++j) {
      PairStats& s = out.pairs[std::size_t(active[j])];
      uint64_t moved_now = 0;
      for (int c = first[j]; c < first[j + 1]; ++c) {
        const PairStats& ps = part[std::size_t(c)];
        s.inview += ps.inview;
        moved_now += moved[std::size_t(c)];
        for (int ch = 0; ch < 3; ++ch) {
          s.sum_a[ch] += ps.sum_a[ch];
          s.sum_b[ch] += ps.sum_b[ch];
        }
      }
      // Most of the overlap changed at once: an exposure step or a cut, not people walking.
      // Motion cannot be told there, so the state restarts (every sample static).
      restart[j] = fresh_ || moved_now * 2 > s.inview;
      s.global_change = !fresh_ && restart[j] && s.inview > 0;
    }
    std::fill(part.begin(), part.end(), PairStats{});
    std::vector<std::vector<int>> kept(std::size_t(first.back()));
    for_chunks([&](std::size_t j, int c, int i0, int i1) {
      const ColorSampling::Pair& g = sampling_.pairs[std::size_t(active[j])];
      std::vector<SampleState>& state = motion_[std::size_t(active[j])];
      PairStats& ps = part[std::size_t(c)];
      std::vector<int>& use = kept[std::size_t(c)];
      for (int i = i0; i < i1; ++i) {
        const uint8_t* a = pixel(views[g.a], g.xy_a[2 * i], g.xy_a[2 * i + 1]);
        const uint8_t* b = pixel(views[g.b], g.xy_b[2 * i], g.xy_b[2 * i + 1]);
        if (!a || !b) continue;
        SampleState& st = state[std::size_t(i)];
        st.age = uint8_t(restart[j] ? request.static_frames : st.moved ? 0 : std::min(255, st.age + 1));
        const bool still = st.age >= request.static_frames;
        const bool aligned = mask_aligned(luma_gradient(views[g.a], g.xy_a[2 * i], g.xy_a[2 * i + 1]),
                                          luma_gradient(views[g.b], g.xy_b[2 * i], g.xy_b[2 * i + 1]),
                                          request.align_tolerance);
        ps.moving += !still;
        ps.misaligned += !aligned;
        if (!usable(a, request) || !usable(b, request)) continue;
        if (request.static_mask && (!still || !aligned)) continue;
        use.push_back(i);
        ++ps.count;
        for (int ch = 0; ch < 3; ++ch) {
          ps.hist_a[ch][a[ch]]++;
          ps.hist_b[ch][b[ch]]++;
        }
        add_moments(ps.aa, a, a);
        add_moments(ps.bb, b, b);
        add_moments(ps.ab, a, b);
      }
    });
    // The histogram matches' lookups (per pair, from its merged histograms), then the matched
    // moments of every matched pair's kept samples in one parallel loop.
    std::vector<std::array<std::array<uint8_t, 256>, 3>> luts(active.size());
    std::vector<char> matched_pair(active.size(), 0);
    for (std::size_t j = 0; j < active.size(); ++j) {
      const std::size_t k = std::size_t(active[j]);
      PairStats& s = out.pairs[k];
      for (int c = first[j]; c < first[j + 1]; ++c) {
        const PairStats& ps = part[std::size_t(c)];
        s.moving += ps.moving;
        s.misaligned += ps.misaligned;
        s.count += ps.count;
        for (int ch = 0; ch < 3; ++ch)
          for (int v = 0; v < 256; ++v) {
            s.hist_a[ch][v] += ps.hist_a[ch][v];
            s.hist_b[ch][v] += ps.hist_b[ch][v];
          }
        for (int m = 0; m < 9; ++m) {
          s.aa[m] += ps.aa[m];
          s.bb[m] += ps.bb[m];
          s.ab[m] += ps.ab[m];
        }
      }
      const HistogramMatch match = k < request.match.size() ? request.match[k] : HistogramMatch::None;
      if (match == HistogramMatch::None) continue;
      matched_pair[j] = 1;
      const bool a_onto_b = match == HistogramMatch::AOntoB;
      for (int ch = 0; ch < 3; ++ch)
        luts[j][std::size_t(ch)] = a_onto_b ? histogram_specification(s.hist_a[ch], s.hist_b[ch])
                                            : histogram_specification(s.hist_b[ch], s.hist_a[ch]);
    }
    std::vector<Moments3> matched(std::size_t(first.back()), Moments3{});
    if (std::find(matched_pair.begin(), matched_pair.end(), 1) != matched_pair.end())
      for_chunks([&](std::size_t j, int c, int, int) {
        if (!matched_pair[j]) return;
        const std::size_t k = std::size_t(active[j]);
        const ColorSampling::Pair& g = sampling_.pairs[k];
        const bool a_onto_b = request.match[k] == HistogramMatch::AOntoB;
        const ImageView& side = a_onto_b ? views[g.a] : views[g.b];
        const std::vector<int32_t>& xy = a_onto_b ? g.xy_a : g.xy_b;
        const auto& lut = luts[j];
        for (int i : kept[std::size_t(c)]) {
          const uint8_t* x = pixel(side, xy[2 * i], xy[2 * i + 1]);
          const uint8_t y[3] = {lut[0][x[0]], lut[1][x[1]], lut[2][x[2]]};
          add_moments(matched[std::size_t(c)], x, y);
        }
      });
    for (std::size_t j = 0; j < active.size(); ++j) {
      if (!matched_pair[j]) continue;
      PairStats& s = out.pairs[std::size_t(active[j])];
      for (int c = first[j]; c < first[j + 1]; ++c)
        for (int m = 0; m < 9; ++m) s.matched[m] += matched[std::size_t(c)][m];
    }
    if (request.pairs) fresh_ = false;
    // The balance histograms: every view's chunks in one parallel loop, added in chunk order.
    out.balance.resize(views.size());
    std::vector<int> bfirst{0};
    for (std::size_t i = 0; i < views.size(); ++i) {
      for (auto& channel : out.balance[i]) channel.fill(0);
      const bool on = request.balance && !views[i].empty();
      bfirst.push_back(bfirst.back() + (on ? chunk_count(int(sampling_.balance_xy[i].size() / 2)) : 0));
    }
    std::vector<ChannelHistograms> bpart(std::size_t(bfirst.back()));
    if (bfirst.back() > 0)
      cv::parallel_for_(cv::Range(0, bfirst.back()), [&](const cv::Range& r) {
        std::size_t i = std::size_t(std::upper_bound(bfirst.begin(), bfirst.end(), r.start) - bfirst.begin()) - 1;
        for (int c = r.start; c < r.end; ++c) {
          while (c >= bfirst[i + 1]) ++i;
          const Eigen::Matrix3d& M = request.balance_matrices[i];
          const std::vector<int32_t>& xy = sampling_.balance_xy[i];
          const int n = int(xy.size() / 2), i0 = (c - bfirst[i]) * kChunk, i1 = std::min(n, i0 + kChunk);
          ChannelHistograms& ph = bpart[std::size_t(c)];
          for (auto& channel : ph) channel.fill(0);
          for (int j = i0; j < i1; ++j) {
            const uint8_t* p = pixel(views[i], xy[2 * j], xy[2 * j + 1]);
            if (!p) continue;
            for (int ch = 0; ch < 3; ++ch) ph[ch][corrected_level(p, M, ch)]++;
          }
        }
      });
    for (std::size_t i = 0; i < views.size(); ++i)
      for (int c = bfirst[i]; c < bfirst[i + 1]; ++c)
        for (int ch = 0; ch < 3; ++ch)
          for (int v = 0; v < 256; ++v) out.balance[i][ch][v] += bpart[std::size_t(c)][ch][v];
  }

  void apply_all(const std::vector<ImageView>& views, const std::vector<Eigen::Matrix3d>& matrices,
                 const std::array<std::array<uint8_t, 256>, 3>& lut, int highlight_knee) override {
    if (matrices.size() < views.size()) throw std::invalid_argument("color: a matrix per view is needed");
    bool identity_lut = true;
    for (int c = 0; c < 3 && identity_lut; ++c)
      for (int v = 0; v < 256 && identity_lut; ++v) identity_lut = lut[c][v] == v;
    const int knee = std::clamp(highlight_knee, 0, 255);
    // Every view's bands of rows in one parallel loop (one wait for the threads, not one per view).
    constexpr int kBand = 16;  // 204 bands at 3x1080p: 16 threads end within a band of each other
    struct Job {
      ImageView view;
      std::array<float, 9> M;  // row-major M(k, c)
      bool matrix;
    };
    std::vector<Job> jobs;
    std::vector<int> bands;  // per job
    for (std::size_t i = 0; i < views.size(); ++i) {
      if (views[i].empty()) continue;
      const Eigen::Matrix3d& M = matrices[i];
      const bool matrix = !M.isIdentity(1e-9);
      if (!matrix && identity_lut) continue;
      Job job{views[i], {}, matrix};
      for (int k = 0; k < 3; ++k)
        for (int c = 0; c < 3; ++c) job.M[std::size_t(3 * k + c)] = float(M(k, c));
      jobs.push_back(job);
      bands.push_back((views[i].height + kBand - 1) / kBand);
    }
    if (jobs.empty()) return;
    int all_bands = 0;
    for (const int b : bands) all_bands += b;
    const uint8_t* const curves[3] = {lut[0].data(), lut[1].data(), lut[2].data()};
    parallel_for_parts(bands, [&](std::size_t j, int t) {
      const Job& job = jobs[j];
      const int y1 = std::min(job.view.height, (t + 1) * kBand);
      for (int y = t * kBand; y < y1; ++y)
        apply_color_row(job.view.row(y), job.view.width, job.matrix ? job.M.data() : nullptr, knee,
                        identity_lut ? nullptr : curves);
    }, double(all_bands));
  }

  void gather(const ImageView& view, const std::vector<int32_t>& xy,
              std::vector<std::array<uint8_t, 3>>& out) override {
    out.resize(xy.size() / 2);
    for (std::size_t k = 0; k < out.size(); ++k) {
      const uint8_t* p = view.row(xy[2 * k + 1]) + 4 * xy[2 * k];
      out[k] = {p[0], p[1], p[2]};
    }
  }

  Backend backend() const override { return Backend::Cpu; }

 private:
  // Per pair sample: its pixels last frame, frames since it last moved (saturating), whether
  // it moved this frame.
  struct SampleState {
    uint8_t a[3] = {0, 0, 0}, b[3] = {0, 0, 0};
    uint8_t age = 0, moved = 0;
  };
  ColorSampling sampling_;
  std::vector<std::vector<SampleState>> motion_;
  bool fresh_ = true;
};

}  // namespace

std::unique_ptr<ColorOps> ColorOps::create(Backend backend) {
  switch (resolve_backend(backend, /*stage_has_cuda=*/true)) {
#ifdef STITCH_HAVE_CUDA
    case Backend::Cuda: return make_color_ops_cuda();
#endif
    case Backend::Cpu: return std::make_unique<ColorOpsCpu>();
    default: break;
  }
  throw std::runtime_error("no color stage for this backend");
}

}  // namespace stitch
