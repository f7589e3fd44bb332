#include "stitch/sync/time_align.hpp"

#include "stitch/sync/thumbnail.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <opencv2/core.hpp>

namespace stitch::sync {

namespace {

constexpr double kNan = std::numeric_limits<double>::quiet_NaN();

// x minus its moving average over `half` samples each side (NaN entries ignored and kept).
std::vector<double> high_pass(const std::vector<double>& x, int half) {
  std::vector<double> out(x.size(), kNan);
  const int n = int(x.size());
  double sum = 0;
  int count = 0, lo = 0, hi = 0;  // window [lo, hi)
  for (int i = 0; i < n; ++i) {
    while (hi < n && hi <= i + half) {
      if (!std::isnan(x[std::size_t(hi)])) {
        sum += x[std::size_t(hi)];
        ++count;
      }
      ++hi;
    }
    while (lo < i - half) {
      if (!std::isnan(x[std::size_t(lo)])) {
        sum -= x[std::size_t(lo)];
        --count;
      }
      ++lo;
    }
    if (!std::isnan(x[std::size_t(i)]) && count > 0) out[std::size_t(i)] = x[std::size_t(i)] - sum / count;
  }
  return out;
}

}  // namespace

std::vector<double> FrameSignal::update(const uint8_t* data, int width, int height, std::size_t pitch,
                                       int bytes_per_pixel, int channel) {
  cur_.assign(std::size_t(kThumbW) * kThumbH, 0.f);
  if (!data || width <= 0 || height <= 0) return std::vector<double>(kStrips, 0.0);
  frame_thumbnail_cpu(data, width, height, pitch, bytes_per_pixel, channel, cur_.data());
  return strips_from_current();
}

std::vector<double> FrameSignal::update_thumbnail(const float* thumbnail) {
  cur_.assign(thumbnail, thumbnail + std::size_t(kThumbW) * kThumbH);
  return strips_from_current();
}

std::vector<double> FrameSignal::strips_from_current() {
  std::vector<double> strips(kStrips, 0.0);
  if (prev_.size() == cur_.size()) {
    constexpr int per_strip = kThumbW / kStrips;
    for (int ty = 0; ty < kThumbH; ++ty)
      for (int tx = 0; tx < kThumbW; ++tx) {
        const std::size_t i = std::size_t(ty) * kThumbW + tx;
        strips[std::size_t(tx / per_strip)] += std::fabs(cur_[i] - prev_[i]);
      }
    for (double& v : strips) v /= double(per_strip * kThumbH);
  }
  prev_.swap(cur_);
  return strips;
}

TimeAligner::TimeAligner(int n_views, AlignSettings settings)
    : settings_(settings), signals_(std::size_t(std::max(n_views, 1))), start_t_(signals_.size(), kNan),
      drift_(signals_.size()) {
  keep_s_ = std::max(2 * settings_.window_s, settings_.drift_window_s) + 2 * settings_.max_offset_s + 5.0;
}

void TimeAligner::reset() {
  for (auto& s : signals_) s.clear();
  start_t_.assign(signals_.size(), kNan);
  for (auto& d : drift_) d.clear();
  have_origin_ = false;
}

void TimeAligner::add_sample(int view, int64_t t_ns, const std::vector<double>& value) {
  if (view < 0 || view >= views() || value.empty()) return;
  for (double v : value)
    if (!std::isfinite(v)) return;
  auto& s = signals_[std::size_t(view)];
  if (!s.empty() && s.back().v.size() != value.size()) s.clear();
  const double t = double(t_ns) * 1e-9;
  if (!s.empty() && t <= s.back().t) {
    if (t < s.back().t - 1.0) {
      s.clear();  // a jump back (a new segment): start over
      start_t_[std::size_t(view)] = kNan;
    } else {
      return;
    }
  }
  double& start = start_t_[std::size_t(view)];
  if (std::isnan(start)) start = t;
  if (t < start + settings_.skip_start_s) return;
  s.push_back({t, value});
  while (s.size() > 2 && s.front().t < t - keep_s_) s.pop_front();
  if (view == 0 && !have_origin_) {
    drift_origin_ = t;
    have_origin_ = true;
  }
  if (view == 0) {
    for (int v = 1; v < views(); ++v) measure_windows(v);
  } else {
    measure_windows(view);
  }
}

// Offsets of the drift windows that both views have passed (by the largest offset searched),
// measured once each while their signals are still kept.
void TimeAligner::measure_windows(int v) {
  if (!have_origin_ || signals_[0].empty() || signals_[std::size_t(v)].empty()) return;
  const double W = settings_.drift_window_s, M = settings_.max_offset_s;
  auto& meas = drift_[std::size_t(v)];
  while (true) {
    const double w0 = drift_origin_ + double(meas.size()) * W, w1 = w0 + W;
    if (w1 + M > signals_[0].back().t || w1 + M > signals_[std::size_t(v)].back().t) break;
    double off = 0, conf = 0;
    if (!correlate(0, v, w0, w1, off, conf)) conf = 0;
    meas.push_back({0.5 * (w0 + w1) - off, off, conf});
  }
}

double TimeAligner::newest_s(int view) const {
  if (view < 0 || view >= views() || signals_[std::size_t(view)].empty()) return 0;
  return signals_[std::size_t(view)].back().t;
}

double TimeAligner::step_s() const {
  if (settings_.step_s > 0) return settings_.step_s;
  const auto& s = signals_[0];
  if (s.size() < 3) return 1.0 / 30;
  std::vector<double> d;
  for (std::size_t i = 1; i < s.size(); ++i) d.push_back(s[i].t - s[i - 1].t);
  std::nth_element(d.begin(), d.begin() + long(d.size() / 2), d.end());
  return std::clamp(d[d.size() / 2], 1e-3, 0.5);
}

// View `view`'s signal at times from + k*step + shift, linearly interpolated; NaN where it has
// no samples on both sides (or the gap between them is longer than 3 steps).
std::vector<double> TimeAligner::resample(int view, int channel, double from_s, double to_s, double step) const {
  const auto& s = signals_[std::size_t(view)];
  const int n = std::max(0, int(std::floor((to_s - from_s) / step)));
  std::vector<double> out(std::size_t(n), kNan);
  std::size_t j = 0;
  for (int k = 0; k < n; ++k) {
    const double t = from_s + k * step;
    while (j + 1 < s.size() && s[j + 1].t <= t) ++j;
    if (j + 1 >= s.size() || s[j].t > t) continue;
    const double dt = s[j + 1].t - s[j].t;
    if (dt <= 0 || dt > 3 * step + 1e-9) continue;
    const double a = (t - s[j].t) / dt;
    out[std::size_t(k)] = s[j].v[std::size_t(channel)] * (1 - a) + s[j + 1].v[std::size_t(channel)] * a;
  }
  return out;
}

namespace {

struct Peak {
  double lag = 0;          // grid steps, sub-step
  double confidence = 0;   // peak correlation times its distinctness
  bool ok = false;
};

// Normalised cross-correlation of A with B shifted by L = -lag_max..lag_max (B[k + lag_max - L]
// pairs with A[k]), its peak refined by a parabola, and how far it stands above the strongest
// other local maximum outside its lobe.
Peak ncc_peak(const std::vector<double>& A, const std::vector<double>& B, int lag_max, int min_pairs, int half) {
  Peak p;
  const int n = int(A.size());
  int n_valid = 0;
  for (double v : A) n_valid += std::isnan(v) ? 0 : 1;
  std::vector<double> r(std::size_t(2 * lag_max + 1), kNan), z(r.size(), kNan);
  for (int L = -lag_max; L <= lag_max; ++L) {
    double sab = 0, saa = 0, sbb = 0, sa = 0, sb = 0;
    int m = 0;
    for (int k = 0; k < n; ++k) {
      const std::size_t j = std::size_t(k + lag_max - L);
      if (j >= B.size()) continue;
      const double x = A[std::size_t(k)], y = B[j];
      if (std::isnan(x) || std::isnan(y)) continue;
      sab += x * y;
      saa += x * x;
      sbb += y * y;
      sa += x;
      sb += y;
      ++m;
    }
    // lags that pair less than half the window are left out: a few seconds of overlap at the
    // edge of the search correlate high by chance
    if (m < std::max(min_pairs, n_valid / 2)) continue;
    const double cov = sab - sa * sb / m, va = saa - sa * sa / m, vb = sbb - sb * sb / m;
    if (va <= 1e-12 || vb <= 1e-12) continue;
    r[std::size_t(L + lag_max)] = cov / std::sqrt(va * vb);
    // how unlikely this correlation is by chance over m pairs (Fisher): a lag near the edge of
    // the search pairs fewer samples, so the same r means less there; picking by r alone lets a
    // short overlap's chance correlation win (the hallway clip: a -3 s alias at trims >= 13)
    z[std::size_t(L + lag_max)] = std::atanh(std::clamp(r[std::size_t(L + lag_max)], -0.999, 0.999)) *
                                  std::sqrt(std::max(m - 3, 1));
  }
  int best = -1;
  for (int i = 0; i < int(r.size()); ++i)
    if (!std::isnan(z[std::size_t(i)]) && (best < 0 || z[std::size_t(i)] > z[std::size_t(best)])) best = i;
  if (best < 0) return p;
  const double peak = r[std::size_t(best)];
  double sub = 0;
  if (best > 0 && best + 1 < int(r.size()) && !std::isnan(r[std::size_t(best - 1)]) &&
      !std::isnan(r[std::size_t(best + 1)])) {
    const double ym = r[std::size_t(best - 1)], yp = r[std::size_t(best + 1)];
    const double den = ym - 2 * peak + yp;
    if (den < 0) sub = std::clamp(0.5 * (ym - yp) / den, -0.5, 0.5);
  }
  int lo = best, hi = best;
  while (lo > 0 && !std::isnan(r[std::size_t(lo - 1)]) && r[std::size_t(lo - 1)] > 0.5 * peak && best - lo < 2 * half) --lo;
  while (hi + 1 < int(r.size()) && !std::isnan(r[std::size_t(hi + 1)]) && r[std::size_t(hi + 1)] > 0.5 * peak &&
         hi - best < 2 * half)
    ++hi;
  lo = std::min(lo, best - 2);
  hi = std::max(hi, best + 2);
  // the strongest other local maximum, by the same significance, in the peak's correlation units
  double second = 0;
  const double zb = z[std::size_t(best)];
  for (int i = 0; i < int(r.size()); ++i) {
    if (i >= lo && i <= hi) continue;
    const double y = z[std::size_t(i)];
    if (std::isnan(y)) continue;
    const bool left_ok = i == 0 || std::isnan(z[std::size_t(i - 1)]) || y >= z[std::size_t(i - 1)];
    const bool right_ok = i + 1 == int(z.size()) || std::isnan(z[std::size_t(i + 1)]) || y >= z[std::size_t(i + 1)];
    if (left_ok && right_ok && zb > 0) second = std::max(second, peak * y / zb);
  }
  p.lag = best - lag_max + sub;
  p.confidence = std::clamp(peak, 0.0, 1.0) * std::clamp((peak - second) / 0.2, 0.0, 1.0);
  p.ok = true;
  return p;
}

// Generalised cross-correlation with a partial phase transform (GCC-PHAT-beta) of A with B
// shifted by L = -lag_max..lag_max (B[k + lag_max - L] pairs A[k]; NaN entries count as 0 after
// the mean is removed). The cross-spectrum divided by its magnitude to the power `beta` weights
// every frequency about equally: the strong lines of a regular pattern (webcam frames repeated
// 3 or 4 times, a walker's steps) no longer dominate, and the irregular part, which only lines
// up at the true lag, decides. Returns the peak (sub-step), its peak-to-sidelobe ratio (the peak
// over the mean and spread of the correlation away from it) and how far the strongest other
// local maximum outside its lobe stays below it (1 - second / peak).
// 1: the whole spectrum whitened (the house clip's repeated-frame comb: PSR 9.6-10.5 vs 7.8-8.9
// at 0.8); the synthetic scenes' smooth bumps still give PSR 8-20 at 1.
constexpr double kPhatBeta = 1.0;

// The peak of a correlation curve c (lags -lag_max..lag_max) to a sub-step, and how it stands out:
// the sidelobes' mean and spread away from the peak's lobe (peak-to-sidelobe ratio) and how far
// the highest other local maximum is below it (distinctness). ok = false without a positive
// peak or with too few sidelobe samples.
struct CurvePeak {
  bool ok = false;
  double lag = 0, mean = 0, sd = 1, psr = 0, distinct = 0;
};
CurvePeak curve_peak(const std::vector<double>& c, int lag_max) {
  CurvePeak p;
  const int nk = int(c.size());
  if (nk == 0) return p;
  const int best = int(std::max_element(c.begin(), c.end()) - c.begin());
  const double peak = c[std::size_t(best)];
  if (!(peak > 0)) return p;
  double sub = 0;
  if (best > 0 && best + 1 < nk) {
    const double ym = c[std::size_t(best - 1)], yp = c[std::size_t(best + 1)];
    const double den = ym - 2 * peak + yp;
    if (den < 0) sub = std::clamp(0.5 * (ym - yp) / den, -0.5, 0.5);
  }
  int lo = best, hi = best;
  while (lo > 0 && c[std::size_t(lo - 1)] > 0.5 * peak && best - lo < 4) --lo;
  while (hi + 1 < nk && c[std::size_t(hi + 1)] > 0.5 * peak && hi - best < 4) ++hi;
  lo = std::min(lo, best - 2);
  hi = std::max(hi, best + 2);
  double s = 0, ss = 0, second = 0;
  int m = 0;
  for (int i = 0; i < nk; ++i) {
    if (i >= lo && i <= hi) continue;
    const double y = c[std::size_t(i)];
    s += y, ss += y * y, ++m;
    const bool l = i == 0 || y >= c[std::size_t(i - 1)];
    const bool r = i + 1 == nk || y >= c[std::size_t(i + 1)];
    if (l && r) second = std::max(second, y);
  }
  if (m < 8) return p;
  p.mean = s / m;
  p.sd = std::sqrt(std::max(ss / m - p.mean * p.mean, 1e-300));
  p.psr = (peak - p.mean) / p.sd;
  p.distinct = 1.0 - second / peak;
  p.lag = best - lag_max + sub;
  p.ok = true;
  return p;
}

struct PhatPeak {
  double lag = 0, psr = 0, distinct = 0;
  std::vector<double> r;  // the correlation at L + lag_max
  bool ok = false;
  double psr_at(double lag_steps, int lag_max) const {
    const int i = int(std::lround(lag_steps)) + lag_max;
    if (!ok || i < 0 || i >= int(r.size())) return 0;
    double best = r[std::size_t(i)];
    if (i > 0) best = std::max(best, r[std::size_t(i - 1)]);
    if (i + 1 < int(r.size())) best = std::max(best, r[std::size_t(i + 1)]);
    return (best - mean) / sd;
  }
  double mean = 0, sd = 1;
};

PhatPeak phat_peak(std::vector<double> A, std::vector<double> B, int lag_max, double beta, int ramp) {
  PhatPeak p;
  for (auto* x : {&A, &B}) {
    double s = 0;
    int n = 0;
    for (double v : *x)
      if (!std::isnan(v)) s += v, ++n;
    if (n < 8) return p;
    const double m = s / n;
    // each run of samples tapered in and out over `ramp` steps: where a stream starts or stops
    // is no event (two streams started at the same running time would line up on the step)
    const int len = int(x->size());
    for (int k = 0; k < len;) {
      if (std::isnan((*x)[std::size_t(k)])) {
        (*x)[std::size_t(k++)] = 0.0;
        continue;
      }
      int e = k;
      while (e < len && !std::isnan((*x)[std::size_t(e)])) ++e;
      for (int i = k; i < e; ++i) {
        const double w = std::min(1.0, double(std::min(i - k, e - 1 - i) + 1) / double(std::max(ramp, 1)));
        (*x)[std::size_t(i)] = ((*x)[std::size_t(i)] - m) * w;
      }
      k = e;
    }
  }
  const int na = int(A.size()), nb = int(B.size());
  const int N = cv::getOptimalDFTSize(na + nb);
  cv::Mat ra = cv::Mat::zeros(1, N, CV_64F), rb = cv::Mat::zeros(1, N, CV_64F), fa, fb;
  std::copy(A.begin(), A.end(), ra.ptr<double>());
  std::copy(B.begin(), B.end(), rb.ptr<double>());
  cv::dft(ra, fa, cv::DFT_COMPLEX_OUTPUT);
  cv::dft(rb, fb, cv::DFT_COMPLEX_OUTPUT);
  cv::Mat cs(1, N, CV_64FC2);
  {
    const auto* pa = fa.ptr<cv::Vec2d>();
    const auto* pb = fb.ptr<cv::Vec2d>();
    auto* pc = cs.ptr<cv::Vec2d>();
    double mean_mag = 0;
    for (int i = 0; i < N; ++i) mean_mag += std::hypot(pa[i][0], pa[i][1]) * std::hypot(pb[i][0], pb[i][1]);
    mean_mag /= N;
    for (int i = 0; i < N; ++i) {
      const double re = pa[i][0] * pb[i][0] + pa[i][1] * pb[i][1];
      const double im = pa[i][0] * pb[i][1] - pa[i][1] * pb[i][0];
      const double mag = std::hypot(re, im);
      const double w = mag > 1e-9 * mean_mag + 1e-300 ? std::pow(mag, -beta) : 0.0;
      pc[i] = cv::Vec2d(re * w, im * w);
    }
  }
  cv::Mat r;
  cv::dft(cs, r, cv::DFT_INVERSE | cv::DFT_SCALE | cv::DFT_COMPLEX_OUTPUT);
  // r[j] = sum_k A[k] B[k + j]: lag L = lag_max - j
  const auto* pr = r.ptr<cv::Vec2d>();
  const int nk = 2 * lag_max + 1;
  p.r.assign(std::size_t(nk), 0.0);
  for (int L = -lag_max; L <= lag_max; ++L) p.r[std::size_t(L + lag_max)] = pr[lag_max - L][0];
  const CurvePeak cp = curve_peak(p.r, lag_max);
  if (!cp.ok) return p;
  p.mean = cp.mean;
  p.sd = cp.sd;
  p.psr = cp.psr;
  p.distinct = cp.distinct;
  p.lag = cp.lag;
  p.ok = true;
  return p;
}

// A channel that barely changes (sensor noise of a static scene, < 0.05 grey levels rms after
// the high-pass) has nothing to align on.
bool has_signal(const std::vector<double>& x, int min_pairs) {
  double ss = 0;
  int n = 0;
  for (double v : x)
    if (!std::isnan(v)) ss += v * v, ++n;
  return n >= min_pairs && ss / n >= 0.0025;
}

}  // namespace

namespace {

// Peak of a z-curve (sub-step), and how sure it is: the same PSR and distinctness terms as the
// direct whole-frame estimate.
bool z_peak(const std::vector<double>& c, int lag_max, double& lag, double& confidence) {
  // the sum's own peak-to-sidelobe ratio: two curves that are one (a camera that sees what view
  // 0 sees, its noise included) add nothing; independent ones average their chance peaks down
  const CurvePeak p = curve_peak(c, lag_max);
  if (!p.ok) return false;
  lag = p.lag;
  confidence = std::clamp((p.psr - 6.0) / 6.0, 0.0, 1.0) * std::clamp(p.distinct / 0.5, 0.0, 1.0);
  return true;
}

}  // namespace

bool TimeAligner::correlate(int a, int b, double from_s, double to_s, double& offset_s, double& confidence,
                            double phat_from_s) const {
  offset_s = 0;
  confidence = 0;
  if (signals_[std::size_t(a)].empty() || signals_[std::size_t(b)].empty()) return false;
  const double h = step_s();
  const int lag_max = std::max(1, int(std::ceil(settings_.max_offset_s / h)));
  const int half = std::max(2, int(std::lround(0.5 / h)));  // high-pass: half a second each side
  const int min_pairs = int(settings_.min_signal_s / h);
  const int ca = int(signals_[std::size_t(a)].back().v.size()), cb = int(signals_[std::size_t(b)].back().v.size());
  std::vector<std::vector<double>> As, Bs;
  for (int c = 0; c < ca; ++c) As.push_back(high_pass(resample(a, c, from_s, to_s, h), half));
  // b at times t - offset for offset = L*h: B[k + lag_max - L] = b(from + k h - L h)
  for (int c = 0; c < cb; ++c)
    Bs.push_back(high_pass(resample(b, c, from_s - lag_max * h, to_s + lag_max * h + h, h), half));
  // Every pair of channels (strips): those in the overlap see the same events at once; the best
  // pair decides, and pairs that agree with it within a step back it up.
  std::vector<Peak> peaks;
  for (int i = 0; i < ca; ++i) {
    if (!has_signal(As[std::size_t(i)], min_pairs)) continue;
    for (int j = 0; j < cb; ++j) {
      if (!has_signal(Bs[std::size_t(j)], min_pairs)) continue;
      const Peak p = ncc_peak(As[std::size_t(i)], Bs[std::size_t(j)], lag_max, min_pairs, half);
      if (p.ok) peaks.push_back(p);
    }
  }
  double n_lag = 0, n_conf = 0;
  bool n_ok = false;
  if (!peaks.empty()) {
  // Across pairs: the lag that most pairs back (their confidences summed within a step and a
  // half) against the best other lag. A scene whose pairs point every which way (a person seen
  // by each camera at another time, no event common to an overlap: the hallway clip gives peaks
  // from -89 to -36 frames, each 0.4-0.6 sure in its own pair) is no estimate, however distinct
  // each pair's own peak is.
  auto support = [&](double lag) {
    double s = 0;
    for (const Peak& q : peaks)
      if (std::fabs(q.lag - lag) <= 1.5) s += q.confidence;
    return s;
  };
  const Peak* best = &peaks[0];
  double best_support = -1;
  for (const Peak& p : peaks) {
    const double sp = support(p.lag);
    if (sp > best_support + 1e-12 || (std::fabs(sp - best_support) <= 1e-12 && p.confidence > best->confidence)) {
      best = &p;
      best_support = sp;
    }
  }
  double rival = 0;
  for (const Peak& p : peaks)
    if (std::fabs(p.lag - best->lag) > 3.0) rival = std::max(rival, support(p.lag));
  const double agreement = best_support > 0 ? std::clamp((best_support - rival) / (0.5 * best_support), 0.0, 1.0) : 0.0;
  double sw = 0, sl = 0;
  for (const Peak& p : peaks)
    if (std::fabs(p.lag - best->lag) <= 1.0 && p.confidence >= 0.5 * best->confidence) {
      sw += p.confidence;
      sl += p.confidence * p.lag;
    }
  n_lag = sw > 0 ? sl / sw : best->lag;
  // many pairs: the best of many noise peaks is higher than one; ask more of a single pair
  const double noise_floor = peaks.size() > 1 ? 0.1 : 0.0;
  n_conf = std::clamp((best->confidence - noise_floor) / (1.0 - noise_floor), 0.0, 1.0) * agreement;
  n_ok = true;
  }
  // The whole frame's motion energy (the mean of the channels) by GCC-PHAT-beta: sure when its
  // peak stands well out of the rest of the correlation (PSR 6: nothing, 12: sure) and no other
  // peak comes close (a periodic pattern). Webcams that repeat frames (the house clip: 8 new
  // frames a second written at 30) share the instants new frames come; their energy is a comb
  // whose regular part correlates at every multiple of its period (NCC 0.87 there vs 0.97 at the
  // true lag), its irregular part only at the true lag (PSR 12-14, the next peak at 0.36).
  const std::vector<double> z = whole_curve(a, b, std::isnan(phat_from_s) ? from_s : std::min(phat_from_s, from_s), to_s);
  double p_lag = 0, p_conf = 0;
  const bool p_ok = z_peak(z, lag_max, p_lag, p_conf);
  auto z_at = [&](double lag) {  // the whole frame's support (PSR) at a lag, within a step
    const int i = int(std::lround(lag)) + lag_max;
    if (z.empty() || i < 0 || i >= int(z.size())) return 0.0;
    double v = z[std::size_t(i)];
    if (i > 0) v = std::max(v, z[std::size_t(i - 1)]);
    if (i + 1 < int(z.size())) v = std::max(v, z[std::size_t(i + 1)]);
    return v;
  };
  if (!n_ok && !p_ok) return false;
  if (std::getenv("STITCH_SYNC_DEBUG"))
    std::fprintf(stderr, "correlate %d-%d [%.1f,%.1f): ncc %s lag %+.2f conf %.2f (psr at it %.1f) | phat %s lag %+.2f conf %.2f\n",
                 a, b, from_s, to_s, n_ok ? "ok" : "--", n_lag, n_conf, z_at(n_lag), p_ok ? "ok" : "--", p_lag, p_conf);
  // The two must agree. Strip pairs alone are believed only as far as the whole frame's
  // correlation backs their lag (PSR 3: not at all, 6: fully): a scene with no event common to
  // the views (the hallway clip's two cameras) gives strip pairs that line up by chance, 0.3-0.6
  // sure, at lags where the whole frame shows nothing.
  if (n_ok && !z.empty()) n_conf *= std::clamp((z_at(n_lag) - 3.0) / 3.0, 0.0, 1.0);
  if (n_ok && p_ok && std::fabs(n_lag - p_lag) <= 1.5) {
    offset_s = n_lag * h;  // the strips' peak is the smoother (its parabola the better sub-step)
    confidence = std::max(n_conf, p_conf);
  } else if (p_ok && p_conf >= n_conf) {
    offset_s = p_lag * h;
    confidence = p_conf * (1.0 - n_conf);
  } else {
    offset_s = n_lag * h;
    confidence = n_conf * (1.0 - p_conf);
  }
  return true;
}

std::vector<double> TimeAligner::whole_curve(int a, int b, double from_s, double to_s) const {
  if (signals_[std::size_t(a)].empty() || signals_[std::size_t(b)].empty()) return {};
  const double h = step_s();
  const int lag_max = std::max(1, int(std::ceil(settings_.max_offset_s / h)));
  const int half = std::max(2, int(std::lround(0.5 / h)));
  const int min_pairs = int(settings_.min_signal_s / h);
  auto whole = [&](int view, double from, double to) {
    const int channels = int(signals_[std::size_t(view)].back().v.size());
    std::vector<double> w;
    for (int c = 0; c < channels; ++c) {
      const std::vector<double> x = high_pass(resample(view, c, from, to, h), half);
      if (w.empty()) w.assign(x.size(), 0.0);
      for (std::size_t k = 0; k < w.size() && k < x.size(); ++k) w[k] += x[k] / channels;
    }
    return w;
  };
  const std::vector<double> wa = whole(a, from_s, to_s), wb = whole(b, from_s - lag_max * h, to_s + lag_max * h + h);
  if (!has_signal(wa, min_pairs) || !has_signal(wb, min_pairs)) return {};
  const PhatPeak ph = phat_peak(wa, wb, lag_max, kPhatBeta, half);
  if (!ph.ok) return {};
  std::vector<double> z(ph.r.size());
  for (std::size_t i = 0; i < z.size(); ++i) z[i] = (ph.r[i] - ph.mean) / ph.sd;
  return z;
}

std::vector<Estimate> TimeAligner::estimate() {
  std::vector<Estimate> out(signals_.size());
  if (signals_[0].size() < 2) return out;
  const double t_end = signals_[0].back().t;
  const double t_from = std::max(signals_[0].front().t, t_end - settings_.window_s);
  // the whole-frame correlation is cheap (one FFT): it takes twice the window, where kept
  const double t_long = std::max(signals_[0].front().t, t_end - 2 * settings_.window_s);
  out[0].valid = true;
  out[0].confidence = 1;
  out[0].source = OffsetSource::Vision;
  // each view against view 0
  const std::size_t V = signals_.size();
  std::vector<double> offs(V, 0.0), confs(V, 0.0);
  std::vector<char> oks(V, 0);
  for (int v = 1; v < views(); ++v)
    if (signals_[std::size_t(v)].size() >= 2)
      oks[std::size_t(v)] = correlate(0, v, t_from, t_end, offs[std::size_t(v)], confs[std::size_t(v)], t_long);
  // Three views and more: offsets must add up (o_v = o_u + the offset of v against u), so
  // view v's whole-frame correlation with view 0 is summed with its correlation with every
  // other view u already sure of its offset, shifted by o_u. Where each pair alone is unsure
  // (the house clip's left and right cameras: PSR 6-7 each), the consistent lag adds up and the
  // chance peaks do not.
  if (V >= 3) {
    const double h = step_s();
    const int lag_max = std::max(1, int(std::ceil(settings_.max_offset_s / h)));
    std::vector<double> new_offs = offs, new_confs = confs;
    std::vector<char> new_oks = oks;
    for (int v = 1; v < views(); ++v) {
      if (signals_[std::size_t(v)].size() < 2) continue;
      std::vector<double> sum = whole_curve(0, v, t_long, t_end);
      if (sum.empty()) continue;
      int terms = 1;
      for (int u = 1; u < views(); ++u) {
        if (u == v || !oks[std::size_t(u)] || confs[std::size_t(u)] < settings_.min_confidence) continue;
        const double ou = offs[std::size_t(u)];
        const std::vector<double> z = whole_curve(u, v, t_long - ou, t_end - ou);
        if (z.size() != sum.size()) continue;
        const int shift = int(std::lround(ou / h));
        std::vector<double> add(sum.size(), 0.0);
        bool any = false;
        for (int L = -lag_max; L <= lag_max; ++L) {
          const int j = L - shift;  // o_v = o_u + L_uv
          if (j < -lag_max || j > lag_max) continue;
          add[std::size_t(L + lag_max)] = z[std::size_t(j + lag_max)];
          any = true;
        }
        if (!any) continue;
        for (std::size_t i = 0; i < sum.size(); ++i) sum[i] += add[i];
        ++terms;
      }
      if (terms < 2) continue;
      for (double& x : sum) x /= std::sqrt(double(terms));
      double lag = 0, c = 0;
      if (!z_peak(sum, lag_max, lag, c)) continue;
      // the direct estimate, where it lies elsewhere, is believed as far as the sum backs it
      const std::size_t sv0 = std::size_t(v);
      double direct = confs[sv0];
      if (oks[sv0] && std::fabs(offs[sv0] / h - lag) > 1.5) {
        const int i = int(std::lround(offs[sv0] / h)) + lag_max;
        double at = 0;
        for (int d = -1; d <= 1; ++d)
          if (i + d >= 0 && i + d < int(sum.size())) at = std::max(at, sum[std::size_t(i + d)]);
        // in the sum's own sidelobe units, as z_peak measures its peak
        double s1 = 0, s2 = 0;
        for (double x : sum) s1 += x, s2 += x * x;
        const double mu = s1 / double(sum.size()), sd = std::sqrt(std::max(s2 / double(sum.size()) - mu * mu, 1e-300));
        direct *= std::clamp(((at - mu) / sd - 3.0) / 3.0, 0.0, 1.0);
      }
      if (c <= direct) continue;
      if (std::getenv("STITCH_SYNC_DEBUG"))
        std::fprintf(stderr, "chain view %d: %d curves, lag %+.2f conf %.2f (direct %s %+.2f conf %.2f)\n", v, terms, lag, c,
                     oks[std::size_t(v)] ? "ok" : "--", offs[std::size_t(v)] / h, confs[std::size_t(v)]);
      const std::size_t sv = std::size_t(v);
      if (oks[sv] && std::fabs(offs[sv] / h - lag) <= 1.5) {
        new_confs[sv] = c;  // the same lag, surer
      } else {
        new_offs[sv] = lag * h;
        new_confs[sv] = c * (oks[sv] ? 1.0 - direct : 1.0);
        new_oks[sv] = 1;
      }
    }
    offs.swap(new_offs);
    confs.swap(new_confs);
    oks.swap(new_oks);
  }
  for (int v = 1; v < views(); ++v) {
    Estimate& e = out[std::size_t(v)];
    if (signals_[std::size_t(v)].size() < 2) continue;
    const auto& meas = drift_[std::size_t(v)];
    const double W = settings_.drift_window_s;
    const double off = offs[std::size_t(v)], conf = confs[std::size_t(v)];
    const bool ok = oks[std::size_t(v)];
    e.confidence = ok ? conf : 0;
    e.valid = ok && conf >= settings_.min_confidence;
    if (!e.valid) continue;
    e.source = OffsetSource::Vision;
    e.offset_ns = int64_t(std::llround(off * 1e9));
    e.base_offset_ns = e.offset_ns;
    // drift: a weighted line through the windows' offsets, once they span long enough
    double sw = 0, st = 0, so = 0, stt = 0, sto = 0, t_min = 1e300, t_max = -1e300;
    int good = 0;
    for (const Measurement& m : meas) {
      if (m.confidence < settings_.min_confidence) continue;
      const double w = m.confidence;
      sw += w;
      st += w * m.t_b;
      so += w * m.offset;
      stt += w * m.t_b * m.t_b;
      sto += w * m.t_b * m.offset;
      t_min = std::min(t_min, m.t_b);
      t_max = std::max(t_max, m.t_b);
      ++good;
    }
    if (good >= 3 && t_max - t_min >= settings_.min_drift_span_s - W) {
      const double den = sw * stt - st * st;
      if (den > 0) {
        const double slope = (sw * sto - st * so) / den;
        const double icpt = (so - slope * st) / sw;
        // only a drift that moved the offset by more than half a step over the span counts
        if (std::fabs(slope) * (t_max - t_min) > 0.5 * step_s()) {
          e.rate = 1.0 + slope;
          const double t_b_now = signals_[std::size_t(v)].back().t;
          e.offset_ns = int64_t(std::llround((icpt + slope * t_b_now) * 1e9));
          e.base_offset_ns = int64_t(std::llround(icpt * 1e9));
        }
      }
    }
  }
  return out;
}

}  // namespace stitch::sync

namespace stitch::sync {

OffsetTracker::OffsetTracker(int n_views, AlignSettings settings)
    : aligner_(n_views, settings), settings_(settings), signals_(std::size_t(std::max(n_views, 1))),
      current_(signals_.size()), announced_(signals_.size()), warned_(signals_.size(), false) {}

void OffsetTracker::reset() {
  if (pending_.valid()) pending_.wait();  // its result belongs to the signals being forgotten
  pending_ = {};
  aligner_.reset();
  for (auto& s : signals_) s.reset();
  last_estimate_ = first_t_ = newest_t_ = -1;
}

void OffsetTracker::add_frame(int view, int64_t t_ns, const uint8_t* data, int width, int height, std::size_t pitch,
                              int bytes_per_pixel, int channel) {
  if (view < 0 || view >= views()) return;
  add_strips(view, t_ns, signals_[std::size_t(view)].update(data, width, height, pitch, bytes_per_pixel, channel));
}

void OffsetTracker::add_thumbnail(int view, int64_t t_ns, const float* thumbnail) {
  if (view < 0 || view >= views() || !thumbnail) return;
  add_strips(view, t_ns, signals_[std::size_t(view)].update_thumbnail(thumbnail));
}

void OffsetTracker::add_strips(int view, int64_t t_ns, const std::vector<double>& strips) {
  aligner_.add_sample(view, t_ns, strips);
  if (view == 0) {
    if (first_t_ < 0) first_t_ = t_ns;
    newest_t_ = std::max(newest_t_, t_ns);
  }
}

bool OffsetTracker::update(std::vector<Estimate>& estimates, std::vector<int>& no_signal,
                           const std::vector<AudioEstimate>* audio) {
  no_signal.clear();
  const bool due = newest_t_ >= 0 && (last_estimate_ < 0 || newest_t_ - last_estimate_ >= 1000000000);
  std::vector<Estimate> vision;
  bool have = false;
  if (asynchronous_) {
    // taken when done, and at the latest when the next one is due (a stream pushed faster than
    // real time waits here: its estimates stay at most a second of stream time behind)
    if (pending_.valid() && (due || pending_.wait_for(std::chrono::seconds(0)) == std::future_status::ready)) {
      try {
        vision = pending_.get();
        have = true;
      } catch (const std::exception&) {
        pending_ = {};  // (out of memory): no estimate this time
      }
    }
    if (due && !pending_.valid()) {
      last_estimate_ = newest_t_;
      pending_ = std::async(std::launch::async, [snapshot = aligner_]() mutable { return snapshot.estimate(); });
    }
  } else if (due) {
    last_estimate_ = newest_t_;
    vision = aligner_.estimate();
    have = true;
  }
  if (!have) return false;
  current_ = std::move(vision);
  // audio, where it is sure, is the sharper measurement (a sample is 0.125 ms, a frame 33 ms);
  // vision's rate (clock drift over minutes) is kept, the audio offset being the newest one
  if (audio) {
    for (std::size_t v = 1; v < current_.size() && v < audio->size(); ++v) {
      const AudioEstimate& a = (*audio)[v];
      if (!a.valid || a.confidence < settings_.audio_min_confidence) continue;
      Estimate& e = current_[v];
      if (a.rate_valid) {
        // the audio's own drift line (windows of its envelope over minutes): sharper than vision's
        e.rate = a.rate;
        e.offset_ns = a.offset_ns;
        e.base_offset_ns = a.base_offset_ns;
      } else {
        if (!e.valid) e.rate = 1.0;
        e.offset_ns = a.offset_ns;
        e.base_offset_ns = a.offset_ns - int64_t(std::llround((e.rate - 1.0) * aligner_.newest_s(int(v)) * 1e9));
      }
      e.confidence = a.confidence;
      e.valid = true;
      e.source = OffsetSource::Audio;
    }
    if (!audio->empty() && (*audio)[0].valid) current_[0].valid = true;
  }
  bool changed = false;
  const double window_ns = settings_.window_s * 1e9;
  for (std::size_t v = 1; v < current_.size(); ++v) {
    const Estimate &e = current_[v], &a = announced_[v];
    if (e.valid != a.valid || std::llabs(e.offset_ns - a.offset_ns) > 2000000 ||
        std::fabs(e.confidence - a.confidence) > 0.1 || std::fabs(e.rate - a.rate) > 1e-4 || e.source != a.source)
      changed = true;
    if (!e.valid && !warned_[v] && double(newest_t_ - first_t_) >= window_ns) {
      warned_[v] = true;
      no_signal.push_back(int(v));
    }
    if (e.valid) warned_[v] = false;
  }
  if (!announced_[0].valid && current_[0].valid) changed = true;  // the first estimate
  if (changed) announced_ = current_;
  estimates = current_;
  return changed;
}

int64_t OffsetTracker::offset_at(int view, int64_t t_ns) const {
  if (view <= 0 || view >= int(current_.size()) || !current_[std::size_t(view)].valid) return 0;
  const Estimate& e = current_[std::size_t(view)];
  return e.base_offset_ns + int64_t(std::llround((e.rate - 1.0) * double(t_ns)));
}

}  // namespace stitch::sync
