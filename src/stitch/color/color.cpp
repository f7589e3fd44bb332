#include "stitch/color/color.hpp"

#include "stitch/stage_profile.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "stitch/rig/lens.hpp"
#include "stitch/rig/overlap.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

namespace stitch {
namespace {

// Camera pixel of canvas point p, when it lies inside the image (one pixel from the border).
bool in_image(const CameraCanvasMap& m, const Eigen::Vector2d& p, int w, int h, double& x, double& y) {
  Eigen::Vector2d q;
  if (!m.to_camera(p, q)) return false;
  x = q.x();
  y = q.y();
  // Lenses (issue 15): outside the image circle the frame is black, not scene.
  if (m.lens && !lens_sees(m.camera, x, y)) return false;
  return x >= 1 && y >= 1 && x <= w - 2 && y <= h - 2;
}

Eigen::Matrix3d to_matrix(const Moments3& m) {
  Eigen::Matrix3d M;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) M(r, c) = double(m[3 * r + c]);
  return M;
}

// Mean level per channel of a histogram's samples.
Eigen::Vector3d channel_means(const ChannelHistograms& h, uint64_t count) {
  Eigen::Vector3d mean;
  for (int ch = 0; ch < 3; ++ch) {
    uint64_t sum = 0;
    for (int v = 0; v < 256; ++v) sum += uint64_t(v) * h[ch][v];
    mean[ch] = double(sum) / double(count);
  }
  return mean;
}

Eigen::Matrix3d clamp_matrix(const Eigen::Matrix3d& M) {
  Eigen::Matrix3d C = M;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) C(r, c) = r == c ? std::clamp(C(r, c), 0.2, 5.0) : std::clamp(C(r, c), -1.0, 1.0);
  return C;
}

}  // namespace

std::array<uint8_t, 256> histogram_specification(const std::array<uint32_t, 256>& src,
                                                 const std::array<uint32_t, 256>& ref) {
  std::array<uint8_t, 256> lut;
  double ns = 0, nr = 0;
  for (int v = 0; v < 256; ++v) {
    ns += src[v];
    nr += ref[v];
  }
  if (ns <= 0 || nr <= 0) {
    for (int v = 0; v < 256; ++v) lut[v] = uint8_t(v);
    return lut;
  }
  std::array<double, 256> cdf_ref;
  double acc = 0;
  for (int v = 0; v < 256; ++v) cdf_ref[v] = (acc += ref[v]) / nr;
  acc = 0;
  int u = 0;
  for (int v = 0; v < 256; ++v) {
    // Centre of this level's mass in the source CDF, matched to the first reference level
    // whose CDF reaches it.
    const double target = (acc + 0.5 * src[v]) / ns;
    acc += src[v];
    while (u < 255 && cdf_ref[u] < target) ++u;
    lut[v] = uint8_t(u);
  }
  return lut;
}

namespace {

// The piecewise curve's constants for one (m1, m2, lambda), computed once per curve.
struct PiecewiseBalance {
  bool identity = true;
  double m1 = 0, m2 = 0, t1 = 0, t2 = 0, s = 1, g_low = 1, g_high = 1;

  PiecewiseBalance(double m1_in, double m2_in, double lambda) : m1(m1_in), m2(m2_in) {
    if (!(m2 - m1 >= 1.0) || !std::isfinite(m1) || !std::isfinite(m2)) return;
    identity = false;
    // Targets: m1 -> lambda and m2 -> 1 - lambda of the range (a histogram stretch), but never
    // lifting a dark level or lowering a bright one by more than 2x ...
    t1 = std::min(255.0 * lambda, 2.0 * m1);
    t2 = std::max(255.0 * (1 - lambda), 255.0 - 2.0 * (255.0 - m2));
    // ... and never stretching the mid-tones more than 2x: move the targets back toward the
    // identity until the linear part's slope is at most 2.
    const double span = m2 - m1, wanted = t2 - t1;
    if (wanted > 2 * span) {
      const double beta = span / (wanted - span);  // (1-b) span + b wanted = 2 span
      t1 = m1 + beta * (t1 - m1);
      t2 = m2 + beta * (t2 - m2);
    }
    s = (t2 - t1) / span;
    // Gamma segments through (0, 0) and (m1, t1), and (255, 255) and (m2, t2), with the linear
    // part's slope where they meet it.
    if (m1 > 0 && t1 > 0) g_low = std::clamp(s * m1 / t1, 0.2, 5.0);
    if (m2 < 255 && t2 < 255) g_high = std::clamp(s * (255 - m2) / (255 - t2), 0.2, 5.0);
  }

  double operator()(double x) const {
    if (identity) return x;
    if (x < m1) {
      if (m1 <= 0 || t1 <= 0) return std::max(0.0, t1 * x / std::max(m1, 1e-9));
      return t1 * std::pow(std::max(0.0, x) / m1, g_low);
    }
    if (x > m2) {
      if (m2 >= 255 || t2 >= 255) return t2 + (x - m2) * (255.0 - t2) / std::max(255.0 - m2, 1e-9);
      return 255 - (255 - t2) * std::pow(std::max(0.0, 255 - x) / (255 - m2), g_high);
    }
    return t1 + (x - m1) * s;
  }
};

}  // namespace

double piecewise_balance_value(double x, double m1, double m2, double lambda) {
  return PiecewiseBalance(m1, m2, lambda)(x);
}

std::array<uint8_t, 256> piecewise_balance_curve(double m1, double m2, double lambda) {
  const PiecewiseBalance curve(m1, m2, lambda);  // every level: its constants once, not 256 times
  std::array<uint8_t, 256> lut;
  for (int v = 0; v < 256; ++v) lut[v] = uint8_t(std::clamp(std::lround(curve(v)), 0L, 255L));
  return lut;
}

ColorCorrector::ColorCorrector(Backend backend) : ops_(ColorOps::create(backend)) { reset(); }

void ColorCorrector::set_options(const ColorOptions& o) {
  const bool restart = o.method != options_.method || o.window != options_.window ||
                       o.pairing != options_.pairing || o.balance != options_.balance;
  options_ = o;
  options_.window = std::max(1, options_.window);
  if (restart) reset();
}

void ColorCorrector::reset() {
  for (auto& h : history_) {
    h.AtA.clear();
    h.AtB.clear();
  }
  std::fill(current_.begin(), current_.end(), Eigen::Matrix3d::Identity());
  std::fill(wanted_.begin(), wanted_.end(), Eigen::Matrix3d::Identity());
  std::fill(key_.begin(), key_.end(), Eigen::Matrix3d::Identity());
  std::fill(over_.begin(), over_.end(), 0);
  std::fill(follow_.begin(), follow_.end(), 0);
  std::fill(last_rgb_.begin(), last_rgb_.end(), Eigen::Vector3d::Constant(-1.0));
  std::fill(has_current_.begin(), has_current_.end(), false);
  report_ = FrameReport{};
  if (ops_) ops_->reset_motion();
  std::fill(gains_.begin(), gains_.end(), Eigen::Vector3d::Ones());
  thresholds_.clear();
  for (int c = 0; c < 3; ++c)
    for (int v = 0; v < 256; ++v) lut_[c][v] = uint8_t(v);
}

ColorSampling make_color_sampling(const Rig& rig, int max_samples_per_pair) {
  const int n = int(rig.cameras.size());
  ColorSampling s;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      float area = 0;
      const std::vector<cv::Point2f> inter = canvas_overlap(rig, a, b, &area);
      if (area < 64.0f || inter.empty()) continue;
      const cv::Rect box = cv::boundingRect(inter);
      const double step = std::max(1.0, std::sqrt(double(area) / std::max(1, max_samples_per_pair)));
      const CameraCanvasMap ma = camera_canvas_map(rig, a), mb = camera_canvas_map(rig, b);
      ColorSampling::Pair g;
      g.a = a;
      g.b = b;
      for (double y = box.y + step * 0.5; y < box.y + box.height; y += step)
        for (double x = box.x + step * 0.5; x < box.x + box.width; x += step) {
          if (cv::pointPolygonTest(inter, cv::Point2f(float(x), float(y)), false) < 0) continue;
          double xa, ya, xb, yb;
          if (!in_image(ma, {x, y}, rig.cameras[a].width, rig.cameras[a].height, xa, ya)) continue;
          if (!in_image(mb, {x, y}, rig.cameras[b].width, rig.cameras[b].height, xb, yb)) continue;
          g.xy_a.push_back(int32_t(std::lround(xa)));
          g.xy_a.push_back(int32_t(std::lround(ya)));
          g.xy_b.push_back(int32_t(std::lround(xb)));
          g.xy_b.push_back(int32_t(std::lround(yb)));
        }
      if (g.count() < 16) continue;
      s.pairs.push_back(std::move(g));
    }
  s.balance_xy.assign(n, {});
  for (int i = 0; i < n; ++i) {
    const Camera& c = rig.cameras[i];
    const int step = std::max(2, int(std::sqrt(double(c.width) * c.height / 4096.0)));
    for (int y = step / 2; y < c.height; y += step)
      for (int x = step / 2; x < c.width; x += step) {
        s.balance_xy[i].push_back(x);
        s.balance_xy[i].push_back(y);
      }
  }
  return s;
}

void ColorCorrector::prepare_geometry(const Rig& rig) {
  const int n = int(rig.cameras.size());
  reference_ = rig.reference;
  sampling_ = make_color_sampling(rig, options_.max_samples_per_pair);
  ops_->set_sampling(sampling_);
  // Chain outward from the reference along the largest overlaps (weighted by sample count).
  std::vector<OverlapEdge> edges;
  for (const auto& g : sampling_.pairs) edges.push_back({g.a, g.b, double(g.count())});
  chain_.clear();
  for (const auto& [view, parent] : max_spanning_order(n, reference_, edges))
    for (std::size_t k = 0; k < sampling_.pairs.size(); ++k) {
      const ColorSampling::Pair& g = sampling_.pairs[k];
      if ((g.a == view && g.b == parent) || (g.a == parent && g.b == view))
        chain_.push_back({view, parent, int(k), g.a == view});
    }
  history_.assign(chain_.size(), PairHistory{});
  if (int(current_.size()) != n) {
    current_.assign(n, Eigen::Matrix3d::Identity());
    wanted_.assign(n, Eigen::Matrix3d::Identity());
    key_.assign(n, Eigen::Matrix3d::Identity());
    over_.assign(n, 0);
    follow_.assign(n, 0);
    step_view_.assign(n, false);
    last_wanted_.assign(n, Eigen::Matrix3d::Identity());
    probe_.assign(n, Eigen::Vector3d::Constant(128));
    last_rgb_.assign(n, Eigen::Vector3d::Constant(-1.0));
    has_current_.assign(n, false);
    gains_.assign(n, Eigen::Vector3d::Ones());
  }
}

double ColorCorrector::effect_levels(int view, const Eigen::Matrix3d& d) const {
  // How far a change of the 3x3 moves an output colour, in grey levels: the worst channel
  // over the view's mean overlap colour and a dark and a bright grey.
  double worst = 0;
  const Eigen::Vector3d probes[3] = {probe_[std::size_t(view)], Eigen::Vector3d::Constant(64),
                                     Eigen::Vector3d::Constant(192)};
  for (const Eigen::Vector3d& p : probes) worst = std::max(worst, (p.transpose() * d).cwiseAbs().maxCoeff());
  return worst;
}

bool ColorCorrector::detect_step(const std::vector<ImageView>& views) {
  const int n = int(views.size());
  // Per view: mean raw luma over all its overlap samples (no mask), and whether an overlap
  // of it changed almost everywhere at once.
  std::vector<Eigen::Vector3d> rgb(n, Eigen::Vector3d::Zero());
  std::vector<double> count(n, 0);
  std::vector<bool> changed(n, false);
  bool every_pair_changed = true;
  int pairs_seen = 0;
  for (std::size_t k = 0; k < sampling_.pairs.size() && k < stats_.pairs.size(); ++k) {
    const ColorSampling::Pair& g = sampling_.pairs[k];
    const PairStats& s = stats_.pairs[k];
    if (s.inview == 0) continue;
    ++pairs_seen;
    every_pair_changed = every_pair_changed && s.global_change;
    if (s.global_change) changed[g.a] = changed[g.b] = true;
    for (int c = 0; c < 3; ++c) {
      rgb[g.a][c] += double(s.sum_a[c]);
      rgb[g.b][c] += double(s.sum_b[c]);
    }
    count[g.a] += double(s.inview);
    count[g.b] += double(s.inview);
    // The mean colour each view shows on its overlaps, for effect_levels.
    if (s.count > 0) {
      probe_[g.a] = channel_means(s.hist_a, s.count);
      probe_[g.b] = channel_means(s.hist_b, s.count);
    }
  }
  const double limit = std::log1p(std::max(0.0, options_.step_threshold));
  int up = 0, down = 0, seen = 0, recoloured = 0;
  for (int i = 0; i < n; ++i) {
    step_view_[i] = false;
    if (views[i].empty() || count[i] <= 0) continue;
    const Eigen::Vector3d now = rgb[i] / count[i];
    const Eigen::Vector3d before = last_rgb_[i];
    last_rgb_[i] = now;
    ++seen;
    if (before.minCoeff() < 0) continue;
    const auto luma = [](const Eigen::Vector3d& v) { return std::max(0.5, 0.30 * v[0] + 0.59 * v[1] + 0.11 * v[2]); };
    const double r = std::log(luma(now) / luma(before));
    if (r > limit) ++up;
    if (r < -limit) ++down;
    // A cut: the view's mean colour moved by the step threshold (any channel).
    const Eigen::Vector3d rel = (now - before).cwiseAbs().cwiseQuotient(before.cwiseMax(1.0));
    if (rel.maxCoeff() > limit) ++recoloured;
    // One camera's own step (its auto exposure): it follows at once, within max_step.
    step_view_[i] = changed[i] || std::abs(r) > limit;
  }
  // Global: every view brightened or darkened beyond the threshold, or every overlap changed
  // almost everywhere and every view's mean colour moved (a cut).
  const bool global = seen >= 2 && (up == seen || down == seen ||
                                    (pairs_seen > 0 && every_pair_changed && recoloured == seen));
  report_.step = global;
  report_.frames_since_step = global ? 0 : report_.frames_since_step + 1;
  return global;
}

void ColorCorrector::stabilize(const std::vector<ImageView>& views, const std::vector<bool>& was_established) {
  report_.rekeyed = false;
  uint64_t inview = 0, used = 0;
  for (const PairStats& s : stats_.pairs) {
    inview += s.inview;
    used += s.count;
  }
  report_.static_fraction = inview ? double(used) / double(inview) : 1.0;
  const int n = int(current_.size());
  for (int i = 0; i < n; ++i) {
    if (views[std::size_t(i)].empty() || !has_current_[std::size_t(i)]) continue;
    Eigen::Matrix3d& applied = current_[std::size_t(i)];
    const Eigen::Matrix3d& want = wanted_[std::size_t(i)];
    if (!options_.stabilize || !was_established[std::size_t(i)]) {
      // The paper's behaviour, or a first estimate (start, reset, global step): applied as is.
      applied = want;
      key_[std::size_t(i)] = want;
      over_[std::size_t(i)] = 0;
      follow_[std::size_t(i)] = 0;
      continue;
    }
    if (step_view_[std::size_t(i)]) follow_[std::size_t(i)] = 2;  // its camera changed: follow now
    const double off = effect_levels(i, want - applied);
    if (follow_[std::size_t(i)] == 0) {
      // Hold: estimation noise (people crossing, codec noise) must not move a static scene.
      over_[std::size_t(i)] = off > options_.hold ? over_[std::size_t(i)] + 1 : 0;
      if (over_[std::size_t(i)] >= std::max(1, options_.keyframe)) {
        follow_[std::size_t(i)] = 1;  // a lasting change: a new keyframe, reached at max_rate
        report_.rekeyed = true;
      }
    }
    if (follow_[std::size_t(i)] == 0) continue;
    key_[std::size_t(i)] = want;
    const double rate = follow_[std::size_t(i)] == 2 ? 1e9 : std::max(1e-3, options_.max_rate);
    if (off <= rate) applied = want;
    else applied += (want - applied) * (rate / off);
    // Reached and settled: hold again.
    if (effect_levels(i, want - applied) < 1e-9 && effect_levels(i, want - last_wanted_[std::size_t(i)]) < 0.25) {
      follow_[std::size_t(i)] = 0;
      over_[std::size_t(i)] = 0;
    }
  }
  last_wanted_ = wanted_;
  current_[std::size_t(reference_)] = Eigen::Matrix3d::Identity();
}

Eigen::Matrix3d ColorCorrector::limited_update(const Eigen::Matrix3d& previous, const Eigen::Matrix3d& wanted,
                                               bool first) const {
  if (!wanted.allFinite()) return previous;
  if (first) return clamp_matrix(wanted);
  // Exponential smoothing toward the new estimate, then a bounded step.
  const Eigen::Matrix3d target = previous + std::clamp(options_.follow, 0.0, 1.0) * (clamp_matrix(wanted) - previous);
  const Eigen::Matrix3d delta = target - previous;
  const double norm = delta.norm();
  // Hysteresis: estimation noise must not make a static scene shimmer.
  if (norm < options_.deadband) return previous;
  if (norm <= options_.max_step) return target;
  return previous + delta * (options_.max_step / norm);
}

void ColorCorrector::estimate_matrices(const std::vector<ImageView>& views) {
  const double unit = 1.0 / (255.0 * 255.0);  // moments are in 8-bit units, the fit in [0, 1]
  for (std::size_t e = 0; e < chain_.size(); ++e) {
    const ChainEdge& edge = chain_[e];
    const int c = edge.view, p = edge.parent;
    if (views[c].empty() || views[p].empty()) continue;
    const PairStats& s = stats_.pairs[std::size_t(edge.pair)];
    if (s.count < uint64_t(std::max(0, options_.min_samples)) || s.count == 0) continue;  // keep the last correction
    // x: view c's samples; y: the target, i.e. the parent's pixels (pairing=pixels) or c's
    // histogram-specified to the parent's (pairing=histogram), in the parent's raw colours.
    const Eigen::Matrix3d XtX = to_matrix(edge.view_is_a ? s.aa : s.bb);
    Eigen::Matrix3d XtY;
    if (options_.pairing == ColorPairing::Histogram) XtY = to_matrix(s.matched);
    else XtY = edge.view_is_a ? to_matrix(s.ab) : Eigen::Matrix3d(to_matrix(s.ab).transpose());
    // The target is the parent as it will look after its own correction Mp (already updated
    // this frame: the chain runs outward): sum x (y Mp) = (sum x y^T) Mp, so the reductions
    // need no Mp and all of them run in one pass before any fit. Normalised per sample so
    // frames weigh the same whatever their overlap's valid count.
    const double norm = unit / double(s.count);
    // The chain of estimates (not the held corrections): each view is held on its own.
    const Eigen::Matrix3d AtA = XtX * norm, AtB = XtY * wanted_[p] * norm;
    PairHistory& h = history_[e];
    h.AtA.push_back(AtA);
    h.AtB.push_back(AtB);
    const std::size_t window = options_.method == ColorMethod::Matrix3D ? std::size_t(options_.window) : 1;
    while (h.AtA.size() > window) {
      h.AtA.pop_front();
      h.AtB.pop_front();
    }
    // Eq. 3: the stacked 3n x 3 system is the sum of the frames' normal equations.
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero(), B = Eigen::Matrix3d::Zero();
    for (std::size_t k = 0; k < h.AtA.size(); ++k) {
      A += h.AtA[k];
      B += h.AtB[k];
    }
    // Ridge toward the identity: an ill-conditioned overlap (one colour) cannot explode M.
    const double r = options_.ridge * std::max(1e-6, A.trace() / 3.0);
    const Eigen::Matrix3d M = (A + r * Eigen::Matrix3d::Identity()).ldlt().solve(B + r * Eigen::Matrix3d::Identity());
    wanted_[c] = limited_update(wanted_[c], M, !has_current_[c]);
    has_current_[c] = true;
  }
  wanted_[reference_] = Eigen::Matrix3d::Identity();
}

void ColorCorrector::estimate_gains(const std::vector<ImageView>& views) {
  const int n = int(current_.size());
  // Brown & Lowe: minimise sum N_ij ((g_i I_ij - g_j I_ji)^2 / sN^2 + (1 - g)^2 / sg^2).
  // Their prior (sg = 0.1) pulls every gain toward 1 as strongly as the data pulls the views
  // together; here the reference camera fixes the scale, so it alone gets the strong prior and
  // the others a weak one that only keeps the system well posed.
  constexpr double sN = 10.0, sg_ref = 0.1, sg = 3.0;
  Eigen::MatrixXd A[3];
  Eigen::VectorXd b[3];
  for (int ch = 0; ch < 3; ++ch) {
    A[ch] = Eigen::MatrixXd::Zero(n, n);
    b[ch] = Eigen::VectorXd::Zero(n);
  }
  std::vector<int> overlaps(n, 0);
  for (std::size_t k = 0; k < sampling_.pairs.size(); ++k) {
    const ColorSampling::Pair& g = sampling_.pairs[k];
    if (views[g.a].empty() || views[g.b].empty()) continue;
    const PairStats& s = stats_.pairs[k];
    if (s.count < uint64_t(std::max(0, options_.min_samples)) || s.count == 0) continue;
    const Eigen::Vector3d ma = channel_means(s.hist_a, s.count), mb = channel_means(s.hist_b, s.count);
    const double N = double(s.count);
    ++overlaps[g.a];
    ++overlaps[g.b];
    for (int ch = 0; ch < 3; ++ch) {
      const double Ia = ma[ch], Ib = mb[ch];
      const double pa = 1 / std::pow(g.a == reference_ ? sg_ref : sg, 2);
      const double pb = 1 / std::pow(g.b == reference_ ? sg_ref : sg, 2);
      A[ch](g.a, g.a) += N * (Ia * Ia / (sN * sN) + pa);
      A[ch](g.b, g.b) += N * (Ib * Ib / (sN * sN) + pb);
      A[ch](g.a, g.b) -= N * Ia * Ib / (sN * sN);
      A[ch](g.b, g.a) -= N * Ia * Ib / (sN * sN);
      b[ch](g.a) += N * pa;
      b[ch](g.b) += N * pb;
    }
  }
  Eigen::MatrixXd gains(n, 3);
  for (int ch = 0; ch < 3; ++ch) {
    for (int i = 0; i < n; ++i)
      if (overlaps[i] == 0) {
        A[ch](i, i) = 1;
        b[ch](i) = 1;
      }
    gains.col(ch) = A[ch].ldlt().solve(b[ch]);
  }
  if (!gains.allFinite() || gains(reference_, 0) <= 0 || gains(reference_, 1) <= 0 || gains(reference_, 2) <= 0)
    return;  // keep the last gains
  const double alpha = 1.0 / std::max(1, options_.window);  // gains averaged over ~window frames
  for (int i = 0; i < n; ++i) {
    if (overlaps[i] == 0 && i != reference_) continue;
    Eigen::Vector3d g;
    for (int ch = 0; ch < 3; ++ch) g[ch] = std::clamp(gains(i, ch) / gains(reference_, ch), 0.25, 4.0);
    gains_[i] = has_current_[i] ? Eigen::Vector3d(gains_[i] + alpha * (g - gains_[i])) : g;
    wanted_[i] = limited_update(wanted_[i], gains_[i].asDiagonal().toDenseMatrix(), !has_current_[i]);
    has_current_[i] = true;
  }
}

void ColorCorrector::update_balance(const std::vector<ImageView>& views) {
  std::array<uint64_t, 256> hist[3] = {};
  for (std::size_t i = 0; i < views.size(); ++i) {
    if (views[i].empty()) continue;
    for (int ch = 0; ch < 3; ++ch)
      for (int v = 0; v < 256; ++v) hist[ch][v] += stats_.balance[i][ch][v];
  }
  uint64_t total = 0;  // every grid sample lands in one bin per channel
  for (int v = 0; v < 256; ++v) total += hist[0][v];
  if (total == 0) return;
  std::array<double, 6> t;
  for (int ch = 0; ch < 3; ++ch) {
    uint64_t acc = 0;
    double m1 = 0, m2 = 255;
    bool got1 = false;
    for (int v = 0; v < 256; ++v) {
      acc += hist[ch][v];
      if (!got1 && acc >= options_.lambda * total) {
        m1 = v;
        got1 = true;
      }
      if (acc >= (1 - options_.lambda) * total) {
        m2 = v;
        break;
      }
    }
    t[2 * ch] = m1;
    t[2 * ch + 1] = m2;
  }
  // Eq. 6-7: thresholds averaged over the current and previous two frames (frame 1 alone,
  // frame 2 the mean of two).
  thresholds_.push_back(t);
  while (thresholds_.size() > 3) thresholds_.pop_front();
  for (int ch = 0; ch < 3; ++ch) {
    double m1 = 0, m2 = 0;
    for (const auto& f : thresholds_) {
      m1 += f[2 * ch];
      m2 += f[2 * ch + 1];
    }
    lut_[ch] = piecewise_balance_curve(m1 / thresholds_.size(), m2 / thresholds_.size(), options_.lambda);
  }
}

// One frame, one code path for every backend:
//   1. ops_->reduce: every statistic of the frame in one pass over the fixed sample positions
//      (CUDA: a few small kernels, a few KB back, ONE stream synchronisation);
//   2. the fits on the host (3x3 solves, ridge, limits, temporal window, gains, balance curve:
//      O(1) per frame);
//   3. ops_->apply_all: every view corrected (CUDA: one launch, one synchronisation at the end
//      so that the next stage sees finished pixels).
// Doing all the reductions before any fit needs them independent of this frame's fits:
// - the chain's targets are in the parent's raw colours and the parent's correction Mp is
//   applied to the sums afterwards (estimate_matrices). Where the parent is the reference
//   (Mp = I: every view of a 2- or 3-camera rig around its reference) this is exactly the fit
//   against the corrected parent; further out, pairing=pixels differs only where the
//   corrected parent would clip, and pairing=histogram specifies onto the parent's raw
//   histogram and then applies Mp, instead of specifying onto the corrected parent's;
// - the balance histogram is of the views under the corrections the frame starts with (the
//   previous frame's). The thresholds are averaged over three frames and a correction moves
//   by at most max_step per frame, so this shifts them by a level or two; the frame on which
//   a correction is first set takes the histogram again under the new corrections.
void ColorCorrector::process(const Rig& rig, uint64_t rig_version, const std::vector<ImageView>& views) {
  if (views.size() != rig.cameras.size()) throw RigError("view count differs from the rig");
  if (rig_version != rig_version_ || current_.size() != views.size()) {
    prepare_geometry(rig);
    rig_version_ = rig_version;
  }
  const bool fit = options_.method != ColorMethod::None;
  if (!fit && !options_.balance) return;
  static const bool profiling = StageProfile::enabled_for("color");
  StageProfile profile("color", profiling);
  request_.pairs = fit;
  request_.match.assign(sampling_.pairs.size(), HistogramMatch::None);
  const bool matrices = options_.method == ColorMethod::Matrix2D || options_.method == ColorMethod::Matrix3D;
  if (matrices && options_.pairing == ColorPairing::Histogram)
    for (const ChainEdge& edge : chain_)
      request_.match[std::size_t(edge.pair)] = edge.view_is_a ? HistogramMatch::AOntoB : HistogramMatch::BOntoA;
  request_.balance = options_.balance;
  request_.balance_matrices = current_;
  request_.dark_level = options_.dark_level;
  request_.bright_level = options_.bright_level;
  request_.static_mask = options_.static_mask;
  request_.motion_threshold = std::clamp(options_.motion_threshold, 0, 255);
  request_.static_frames = std::clamp(options_.static_frames, 0, 255);
  request_.align_tolerance = std::clamp(options_.align_tolerance, 0, 1 << 20);
  ops_->reduce(views, request_, stats_);
  profile.mark("reduce");
  const bool step = fit && detect_step(views);
  if (step) {
    // A global illumination step or a cut: what came before no longer describes the scene.
    // Every estimate starts again from this frame and is applied at once (no ramp).
    for (auto& h : history_) {
      h.AtA.clear();
      h.AtB.clear();
    }
    thresholds_.clear();
    std::fill(has_current_.begin(), has_current_.end(), false);
  }
  const auto established = [this] { return std::count(has_current_.begin(), has_current_.end(), true); };
  const auto established_before = established();
  std::vector<bool> was_established = has_current_;
  switch (options_.method) {
    case ColorMethod::None: break;
    case ColorMethod::Matrix2D:
    case ColorMethod::Matrix3D: estimate_matrices(views); break;
    case ColorMethod::Gain: estimate_gains(views); break;
  }
  if (fit) stabilize(views, was_established);
  if (options_.balance) {
    if (established() > established_before) {
      // A correction was set outright (its first fit, after a start or reset): the views under
      // the previous corrections are far from what this frame shows, so the balance histogram
      // is taken again under the new ones (a second synchronisation, on such frames only).
      // Afterwards a correction moves by at most max_step per frame.
      request_.pairs = false;
      request_.balance_matrices = current_;
      ops_->reduce(views, request_, stats_);
    }
    update_balance(views);
  }
  profile.mark("fit");
  ops_->apply_all(views, current_, lut_, fit ? std::clamp(options_.highlight_knee, 0, 255) : 255);
  profile.mark("apply");
}

}  // namespace stitch
