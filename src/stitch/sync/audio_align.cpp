#include "stitch/sync/audio_align.hpp"

#include <algorithm>
#include <cmath>
#include <opencv2/core.hpp>

namespace stitch::sync {

AudioAligner::AudioAligner(int n_views, AudioAlignSettings settings)
    : settings_(settings), views_(std::size_t(std::max(n_views, 1))), current_(views_.size()),
      ends_at_estimate_(views_.size(), std::nan("")), drift_(views_.size()) {
  settings_.rate = std::max(settings_.rate, 100);
  settings_.drift_window_s = std::max(settings_.drift_window_s, 0.5);
}

void AudioAligner::reset() {
  for (auto& v : views_) v = View{};
  current_.assign(views_.size(), AudioEstimate{});
  ends_at_estimate_.assign(views_.size(), std::nan(""));
  for (auto& d : drift_) d.clear();
  have_origin_ = false;
}

void AudioAligner::reset_view(int view) {
  if (view < 0 || view >= views()) return;
  views_[std::size_t(view)] = View{};
  current_[std::size_t(view)] = AudioEstimate{};
  ends_at_estimate_[std::size_t(view)] = std::nan("");
  drift_[std::size_t(view)].clear();
  if (view == 0) {  // the windows are counted on view 0's time
    for (auto& d : drift_) d.clear();
    have_origin_ = false;
  }
}

bool AudioAligner::has_audio(int view) const {
  return view >= 0 && view < views() && !views_[std::size_t(view)].samples.empty();
}

void AudioAligner::add(int view, int64_t t_ns, const float* x, std::size_t frames, int channels, int rate) {
  if (view < 0 || view >= views() || !x || frames == 0 || channels <= 0 || rate <= 0) return;
  std::vector<float> mono(frames);
  for (std::size_t i = 0; i < frames; ++i) {
    double s = 0;
    for (int c = 0; c < channels; ++c) s += x[i * std::size_t(channels) + std::size_t(c)];
    mono[i] = std::isfinite(s) ? float(s / channels) : 0.f;
  }
  push_mono(view, double(t_ns) * 1e-9, mono, rate);
}

void AudioAligner::add(int view, int64_t t_ns, const int16_t* x, std::size_t frames, int channels, int rate) {
  if (view < 0 || view >= views() || !x || frames == 0 || channels <= 0 || rate <= 0) return;
  std::vector<float> mono(frames);
  for (std::size_t i = 0; i < frames; ++i) {
    int s = 0;
    for (int c = 0; c < channels; ++c) s += x[i * std::size_t(channels) + std::size_t(c)];
    mono[i] = float(s) / (32768.f * float(channels));
  }
  push_mono(view, double(t_ns) * 1e-9, mono, rate);
}

// Resampling by bins: every input sample falls into the output sample (1/rate wide) its time is
// in; a bin's value is the mean of its samples (a box low-pass before decimation; the usual
// 16-48 kHz inputs put 2-6 samples in each), and a bin no sample reached (inputs below 8 kHz)
// repeats the last one. Block timestamps that jitter by less than 50 ms are taken as contiguous:
// the sample count is the better clock.
void AudioAligner::push_mono(int view, double t, const std::vector<float>& mono, int rate) {
  View& v = views_[std::size_t(view)];
  const double R = settings_.rate;
  if (v.started) {
    const double expected = v.t0 + v.next_out / R;  // time of the next input sample
    if (t < expected - 1.0) {
      v = View{};  // a jump back (a new segment, a seek): start over
      drift_[std::size_t(view)].clear();
      if (view == 0) {
        for (auto& d : drift_) d.clear();
        have_origin_ = false;
      }
    } else if (t > expected + 0.05) {
      // a discontinuity: silence in between (finish the open bin first)
      const double gap = std::min(t - expected, settings_.keep_s);
      if (v.acc_n) {
        v.samples.push_back(float(v.acc / v.acc_n));
        v.acc = 0;
        v.acc_n = 0;
      }
      v.last_in = 0;
      v.next_out += gap * R;
    }
  }
  if (!v.started) {
    v.started = true;
    v.t0 = t;
    v.next_out = 0;
    if (view == 0 && !have_origin_) {
      origin_ = t;
      have_origin_ = true;
    }
  }
  const double step = R / rate;
  for (float x : mono) {
    const long bin = long(std::floor(v.next_out));
    while (long(v.samples.size()) < bin) {
      if (v.acc_n) v.last_in = float(v.acc / v.acc_n);
      v.samples.push_back(v.last_in);
      v.acc = 0;
      v.acc_n = 0;
    }
    v.acc += x;
    ++v.acc_n;
    v.next_out += step;
  }
  const std::size_t keep = std::size_t(settings_.keep_s * R);
  while (v.samples.size() > keep) {
    v.samples.pop_front();
    v.t0 += 1.0 / R;
    v.next_out -= 1.0;
  }
}

namespace {

// The samples of `s` (starting at time t0, `rate` per second) at times from + k/rate, k < n;
// zeros where it has none.
std::vector<float> span(const std::deque<float>& s, double t0, double rate, double from, int n) {
  std::vector<float> out(std::size_t(std::max(n, 0)), 0.f);
  const long first = std::lround((from - t0) * rate);
  for (int k = 0; k < n; ++k) {
    const long i = first + k;
    if (i >= 0 && i < long(s.size())) out[std::size_t(k)] = s[std::size_t(i)];
  }
  return out;
}

// The same with b's time mapped from a's along a drift line: sample k is b's sound at b-time
// (from + k / rate - base) / clock_rate (linearly interpolated).
std::vector<float> span_line(const std::deque<float>& s, double t0, double rate, double from, int n, double clock_rate,
                             double base) {
  if (clock_rate == 1.0 && base == 0.0) return span(s, t0, rate, from, n);
  std::vector<float> out(std::size_t(std::max(n, 0)), 0.f);
  for (int k = 0; k < n; ++k) {
    const double x = ((from + k / rate - base) / clock_rate - t0) * rate;
    const long i = long(std::floor(x));
    if (i < 0 || i + 1 >= long(s.size())) continue;
    const float f = float(x - double(i));
    out[std::size_t(k)] = s[std::size_t(i)] * (1 - f) + s[std::size_t(i + 1)] * f;
  }
  return out;
}

// Envelope (mean absolute value) of `s` in bins of `bin` samples from time `from`, n bins; NaN
// where the samples are not kept.
std::vector<double> envelope(const std::deque<float>& s, double t0, double rate, double from, int n, int bin) {
  std::vector<double> out(std::size_t(std::max(n, 0)), std::nan(""));
  const long first = std::lround((from - t0) * rate);
  for (int k = 0; k < n; ++k) {
    const long i0 = first + long(k) * bin;
    if (i0 < 0 || i0 + bin > long(s.size())) continue;
    double a = 0;
    for (int j = 0; j < bin; ++j) a += std::fabs(s[std::size_t(i0 + j)]);
    out[std::size_t(k)] = a / bin;
  }
  return out;
}

double rms(const std::vector<float>& x) {
  double ss = 0;
  for (float v : x) ss += double(v) * v;
  return x.empty() ? 0 : std::sqrt(ss / double(x.size()));
}

}  // namespace

bool AudioAligner::correlate(int a, int b, double& offset_s, double& confidence, double clock_rate,
                             double base_s) const {
  offset_s = 0;
  confidence = 0;
  if (!has_audio(a) || !has_audio(b) || !(clock_rate > 0)) return false;
  const View &va = views_[std::size_t(a)], &vb = views_[std::size_t(b)];
  const double R = settings_.rate, M = settings_.max_offset_s;
  // a's newest span that b has audio for (lags of either sign: b's span is widened by M); b's
  // times on a's axis along the drift line
  const double b_end = base_s + clock_rate * end_s(vb), b_start = base_s + clock_rate * vb.t0;
  const double te = std::min(end_s(va), b_end + M);
  const double ts = std::max({te - settings_.window_s, va.t0, b_start - M});
  if (te - ts < settings_.min_window_s) return false;
  const int na = int((te - ts) * R), lag_n = int(std::ceil(M * R));
  const int nb = na + 2 * lag_n;
  std::vector<float> A = span(va.samples, va.t0, R, ts, na);
  std::vector<float> B = span_line(vb.samples, vb.t0, R, ts - double(lag_n) / R, nb, clock_rate, base_s);
  if (rms(A) < 1e-5 || rms(B) < 1e-5) return false;  // silence
  // remove the means (a DC offset correlates at every lag)
  for (auto* x : {&A, &B}) {
    double m = 0;
    for (float v : *x) m += v;
    m /= double(x->size());
    for (float& v : *x) v = float(v - m);
  }
  const int N = cv::getOptimalDFTSize(na + nb);
  cv::Mat fa, fb;
  {
    cv::Mat ra = cv::Mat::zeros(1, N, CV_32F), rb = cv::Mat::zeros(1, N, CV_32F);
    std::copy(A.begin(), A.end(), ra.ptr<float>());
    std::copy(B.begin(), B.end(), rb.ptr<float>());
    cv::dft(ra, fa, cv::DFT_COMPLEX_OUTPUT);
    cv::dft(rb, fb, cv::DFT_COMPLEX_OUTPUT);
  }
  // GCC-PHAT: conj(FA) FB whitened; bins with (almost) no energy in either are left out
  cv::Mat cs(1, N, CV_32FC2);
  {
    const auto* pa = fa.ptr<cv::Vec2f>();
    const auto* pb = fb.ptr<cv::Vec2f>();
    auto* pc = cs.ptr<cv::Vec2f>();
    double mean_mag = 0;
    for (int i = 0; i < N; ++i) mean_mag += std::hypot(pa[i][0], pa[i][1]) * std::hypot(pb[i][0], pb[i][1]);
    mean_mag /= N;
    const double floor_mag = 1e-4 * mean_mag + 1e-30;
    for (int i = 0; i < N; ++i) {
      const double re = double(pa[i][0]) * pb[i][0] + double(pa[i][1]) * pb[i][1];
      const double im = double(pa[i][0]) * pb[i][1] - double(pa[i][1]) * pb[i][0];
      const double mag = std::hypot(re, im);
      pc[i] = mag > floor_mag ? cv::Vec2f(float(re / mag), float(im / mag)) : cv::Vec2f(0.f, 0.f);
    }
  }
  cv::Mat r;
  cv::dft(cs, r, cv::DFT_INVERSE | cv::DFT_SCALE | cv::DFT_COMPLEX_OUTPUT);
  // r[k] = sum_n A[n] B[n + k]: the event at A[n] is at B[n + lag_n - offset R]
  const auto* pr = r.ptr<cv::Vec2f>();
  const int nk = 2 * lag_n + 1;
  std::vector<double> c(static_cast<std::size_t>(nk));
  for (int k = 0; k < nk; ++k) c[std::size_t(k)] = pr[k][0];
  const int best = int(std::max_element(c.begin(), c.end()) - c.begin());
  const double peak = c[std::size_t(best)];
  if (!(peak > 0)) return false;
  double sub = 0;
  if (best > 0 && best + 1 < nk) {
    const double ym = c[std::size_t(best - 1)], yp = c[std::size_t(best + 1)];
    const double den = ym - 2 * peak + yp;
    if (den < 0) sub = std::clamp(0.5 * (ym - yp) / den, -0.5, 0.5);
  }
  // peak-to-sidelobe ratio, and the strongest other peak (a periodic sound: a tone, a beat)
  const int guard = std::max(4, int(0.0025 * R));
  double s = 0, ss = 0, second = 0;
  int m = 0;
  for (int k = 0; k < nk; ++k) {
    if (std::abs(k - best) <= guard) continue;
    const double y = c[std::size_t(k)];
    s += y;
    ss += y * y;
    second = std::max(second, y);
    ++m;
  }
  if (m < 2) return false;
  const double mean = s / m, sd = std::sqrt(std::max(ss / m - mean * mean, 1e-30));
  const double psr = (peak - mean) / sd;
  const double psr_term = std::clamp((psr - settings_.min_psr) / (settings_.full_psr - settings_.min_psr), 0.0, 1.0);
  const double distinct = std::clamp((1.0 - second / peak) / 0.5, 0.0, 1.0);
  offset_s = (double(lag_n) - (best + sub)) / R;
  confidence = psr_term * distinct;
  return true;
}

bool AudioAligner::envelope_offset(int a, int b, double from_s, double to_s, double& offset_s,
                                   double& confidence) const {
  offset_s = 0;
  confidence = 0;
  if (!has_audio(a) || !has_audio(b)) return false;
  const View &va = views_[std::size_t(a)], &vb = views_[std::size_t(b)];
  const double R = settings_.rate, M = settings_.max_offset_s;
  const int bin = std::max(1, int(std::lround(R / 200.0)));  // 5 ms
  const double h = double(bin) / R;
  const int na = int((to_s - from_s) / h), lag_n = int(std::ceil(M / h));
  if (na < 20) return false;
  const std::vector<double> A = envelope(va.samples, va.t0, R, from_s, na, bin);
  const std::vector<double> B = envelope(vb.samples, vb.t0, R, from_s - lag_n * h, na + 2 * lag_n, bin);
  int n_valid = 0;
  for (double x : A) n_valid += std::isnan(x) ? 0 : 1;
  if (n_valid < na / 2) return false;
  // normalised cross-correlation over the pairs both have: B[k + lag_n - L] pairs A[k] at lag
  // L (b's time + L h = a's time)
  const int nk = 2 * lag_n + 1;
  std::vector<double> r(std::size_t(nk), std::nan(""));
  for (int L = -lag_n; L <= lag_n; ++L) {
    double sab = 0, saa = 0, sbb = 0, sa = 0, sb = 0;
    int m = 0;
    for (int k = 0; k < na; ++k) {
      const double x = A[std::size_t(k)], y = B[std::size_t(k + lag_n - L)];
      if (std::isnan(x) || std::isnan(y)) continue;
      sab += x * y, saa += x * x, sbb += y * y, sa += x, sb += y;
      ++m;
    }
    if (m < n_valid / 2 || m < 20) continue;
    const double cov = sab - sa * sb / m, vA = saa - sa * sa / m, vB = sbb - sb * sb / m;
    if (vA <= 1e-18 || vB <= 1e-18) continue;
    r[std::size_t(L + lag_n)] = cov / std::sqrt(vA * vB);
  }
  int best = -1;
  for (int i = 0; i < nk; ++i)
    if (!std::isnan(r[std::size_t(i)]) && (best < 0 || r[std::size_t(i)] > r[std::size_t(best)])) best = i;
  if (best < 0 || !(r[std::size_t(best)] > 0)) return false;
  const double peak = r[std::size_t(best)];
  double sub = 0;
  if (best > 0 && best + 1 < nk && !std::isnan(r[std::size_t(best - 1)]) && !std::isnan(r[std::size_t(best + 1)])) {
    const double ym = r[std::size_t(best - 1)], yp = r[std::size_t(best + 1)];
    const double den = ym - 2 * peak + yp;
    if (den < 0) sub = std::clamp(0.5 * (ym - yp) / den, -0.5, 0.5);
  }
  // the main lobe (down to half the peak), and the strongest local maximum outside it
  int lo = best, hi = best;
  while (lo > 0 && !std::isnan(r[std::size_t(lo - 1)]) && r[std::size_t(lo - 1)] > 0.5 * peak) --lo;
  while (hi + 1 < nk && !std::isnan(r[std::size_t(hi + 1)]) && r[std::size_t(hi + 1)] > 0.5 * peak) ++hi;
  double second = 0;
  for (int i = 0; i < nk; ++i) {
    if (i >= lo && i <= hi) continue;
    const double y = r[std::size_t(i)];
    if (std::isnan(y)) continue;
    const bool l = i == 0 || std::isnan(r[std::size_t(i - 1)]) || y >= r[std::size_t(i - 1)];
    const bool rr = i + 1 == nk || std::isnan(r[std::size_t(i + 1)]) || y >= r[std::size_t(i + 1)];
    if (l && rr) second = std::max(second, y);
  }
  offset_s = (best - lag_n + sub) * h;
  confidence = std::clamp(peak, 0.0, 1.0) * std::clamp((peak - second) / 0.2, 0.0, 1.0);
  return true;
}

// The drift windows of view 0's time that both views have passed (by the largest offset
// searched), each measured once while its audio is kept.
void AudioAligner::measure_windows(int v) {
  if (!have_origin_ || !has_audio(0) || !has_audio(v)) return;
  const double W = settings_.drift_window_s, M = settings_.max_offset_s;
  auto& meas = drift_[std::size_t(v)];
  const View &v0 = views_[0], &vb = views_[std::size_t(v)];
  while (true) {
    const double w0 = origin_ + double(meas.size()) * W, w1 = w0 + W;
    if (w1 + M > end_s(v0) || w1 + M > end_s(vb)) break;
    double off = 0, conf = 0;
    if (w0 < v0.t0 || !envelope_offset(0, v, w0, w1, off, conf)) conf = 0;  // no longer kept
    meas.push_back({0.5 * (w0 + w1) - off, off, conf});
  }
}

// A weighted line offset = base + (rate - 1) t_b through the windows' offsets, refitted once
// without the windows more than 5 ms off it (a window whose envelope locked elsewhere).
bool AudioAligner::fit_drift(int v, double& rate, double& base_s) const {
  const auto& meas = drift_[std::size_t(v)];
  std::vector<char> use(meas.size());
  for (std::size_t i = 0; i < meas.size(); ++i) use[i] = meas[i].confidence >= settings_.drift_min_confidence;
  double slope = 0, icpt = 0;
  for (int pass = 0; pass < 2; ++pass) {
    double sw = 0, st = 0, so = 0, stt = 0, sto = 0, t_min = 1e300, t_max = -1e300;
    int good = 0;
    for (std::size_t i = 0; i < meas.size(); ++i) {
      if (!use[i]) continue;
      const Measurement& m = meas[i];
      const double w = m.confidence;
      sw += w, st += w * m.t_b, so += w * m.offset, stt += w * m.t_b * m.t_b, sto += w * m.t_b * m.offset;
      t_min = std::min(t_min, m.t_b);
      t_max = std::max(t_max, m.t_b);
      ++good;
    }
    if (good < 4 || t_max - t_min < settings_.min_drift_span_s - settings_.drift_window_s) return false;
    const double den = sw * stt - st * st;
    if (!(den > 0)) return false;
    slope = (sw * sto - st * so) / den;
    icpt = (so - slope * st) / sw;
    if (pass == 0)
      for (std::size_t i = 0; i < meas.size(); ++i)
        if (use[i] && std::fabs(meas[i].offset - (icpt + slope * meas[i].t_b)) > 0.005) use[i] = 0;
  }
  rate = 1.0 + slope;
  base_s = icpt;
  return true;
}

const std::vector<AudioEstimate>& AudioAligner::estimate() {
  if (!has_audio(0)) {
    current_.assign(views_.size(), AudioEstimate{});
    return current_;
  }
  // due when any view has a second of new audio (the views' streaming threads run at their own
  // pace: in a file pipeline one camera's audio may all be in before another's starts)
  bool due = false;
  for (int v = 0; v < views(); ++v) {
    if (!has_audio(v)) continue;
    const double was = ends_at_estimate_[std::size_t(v)], end = end_s(views_[std::size_t(v)]);
    due = due || std::isnan(was) || end - was >= 1.0 || end < was;
  }
  if (!due) return current_;
  for (int v = 0; v < views(); ++v)
    ends_at_estimate_[std::size_t(v)] = has_audio(v) ? end_s(views_[std::size_t(v)]) : std::nan("");
  current_.assign(views_.size(), AudioEstimate{});
  current_[0] = {0, 1.0, true};
  for (int v = 1; v < views(); ++v) {
    measure_windows(v);
    double rate = 1.0, base = 0;
    const bool drift = fit_drift(v, rate, base);
    // a drift too small to move the offset by a millisecond over the span: none
    const bool drifting = drift && std::fabs(rate - 1.0) * settings_.min_drift_span_s > 0.001;
    double off = 0, conf = 0;
    if (!correlate(0, v, off, conf, drifting ? rate : 1.0, drifting ? base : 0.0)) continue;
    AudioEstimate& e = current_[std::size_t(v)];
    e.confidence = conf;
    e.valid = true;
    e.rate_valid = drift;
    if (drifting) {
      // b read along the line: `off` corrects its base
      e.rate = rate;
      e.base_offset_ns = int64_t(std::llround((base + off) * 1e9));
      e.offset_ns = int64_t(std::llround((base + off + (rate - 1.0) * end_s(views_[std::size_t(v)])) * 1e9));
    } else {
      e.offset_ns = e.base_offset_ns = int64_t(std::llround(off * 1e9));
    }
  }
  return current_;
}

}  // namespace stitch::sync
