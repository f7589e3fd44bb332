#include "stitch/calib/bundle_adjust.hpp"

#include <Eigen/Dense>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <unsupported/Eigen/NonLinearOptimization>
#include <unsupported/Eigen/NumericalDiff>

#include "stitch/rig/lens.hpp"

namespace stitch {
namespace {

// lm.minimize(x), one iteration at a time so that a cancelled calibration stops within one.
template <class LM>
void minimize(LM& lm, Eigen::VectorXd& x, const BundleAdjustOptions& o) {
  Eigen::LevenbergMarquardtSpace::Status status = lm.minimizeInit(x);
  if (status == Eigen::LevenbergMarquardtSpace::ImproperInputParameters) return;
  do {
    if (o.cancel && o.cancel->load(std::memory_order_relaxed)) return;
    if (o.deadline && std::chrono::steady_clock::now() > *o.deadline) return;
    status = lm.minimizeOneStep(x);
  } while (status == Eigen::LevenbergMarquardtSpace::Running);
}


struct Model {
  std::vector<Eigen::Matrix3d> R, K;
  std::vector<Camera> cam;  // K and lens applied (the lens path)
};

// Parameters: per camera a rotation increment (axis-angle, left-multiplied on the start
// rotation; absent for the reference) and, when refined, a relative focal change.
// Lens coefficients (k1, then k2 when asked) of the cameras that estimate them follow.
struct Layout {
  int n = 0, reference = 0;
  bool focal = true, shared = false;
  std::vector<int> lens_k;      // per camera: 0 (kept), 1 (k1) or 2 (k1, k2); group leaders only
  std::vector<int> lens_group;  // per camera: the camera whose coefficients it shares (itself: its own)
  int rot_index(int cam) const { return cam < reference ? 3 * cam : cam == reference ? -1 : 3 * (cam - 1); }
  int focal_index(int cam) const { return focal ? 3 * (n - 1) + (shared ? 0 : cam) : -1; }
  int base_size() const { return 3 * (n - 1) + (focal ? (shared ? 1 : n) : 0); }
  int lens_index(int cam) const {
    if (lens_k.empty()) return -1;
    const int g = lens_group[cam];
    if (!lens_k[g]) return -1;
    int i = base_size();
    for (int c = 0; c < g; ++c) i += lens_k[c];
    return i;
  }
  int lens_count(int cam) const { return lens_k.empty() ? 0 : lens_k[lens_group[cam]]; }
  int size() const {
    int s = base_size();
    for (int k : lens_k) s += k;
    return s;
  }
};

Eigen::Vector2d project(const Eigen::Matrix3d& K, const Eigen::Matrix3d& R, const Eigen::Vector3d& ray) {
  const Eigen::Vector3d p = K * (R.transpose() * ray);
  // Behind the camera: a large residual, so that the solver moves away from it.
  if (!(p.z() > 1e-9)) return {1e6, 1e6};
  return p.head<2>() / p.z();
}

// (half diagonal / f)^2: k1 times this is the radial bend at the frame's half diagonal.
double bend_scale(const Camera& c) { return 0.25 * (double(c.width) * c.width + double(c.height) * c.height) / (c.fx * c.fy); }

// How far (pixels) the lens of `c` folds inside its frame: 0 while the radius still grows at the
// farthest corner. A barrier residual keeps the adjustment out of folding lenses.
double fold_inside_px(const Camera& c) {
  const auto lp = lens_params(c);
  if (c.lens.model != Lens::Model::Radtan || !(lp.limit < 1e29)) return 0;
  const double r2 = lp.limit, r = std::sqrt(r2);
  const double rd = r * (1 + r2 * (c.lens.k1 + r2 * (c.lens.k2 + r2 * c.lens.k3)));
  const double far = std::sqrt(bend_scale(c));
  return std::max(0.0, 1.05 * far - rd) * c.fx;
}

struct Problem {
  const Rig* start;
  Layout layout;
  std::vector<std::array<int, 2>> cams;         // per match
  std::vector<Eigen::Vector2d> pa, pb;
  std::vector<Eigen::Vector2d> ra, rb;  // raw pixels (the lens path); empty: pinhole residuals
  std::vector<double> w;
  bool lens() const { return !ra.empty(); }
  int barriers() const {
    int b = 0;
    for (int i = 0; i < layout.n; ++i) b += layout.lens_index(i) >= 0 && layout.lens_group[i] == i;
    return b;
  }

  Model model(const Eigen::VectorXd& x) const {
    Model m;
    for (int i = 0; i < layout.n; ++i) {
      const Camera& c = start->cameras[i];
      Eigen::Matrix3d R = c.R();
      if (const int r = layout.rot_index(i); r >= 0) {
        const Eigen::Vector3d w = x.segment<3>(r);
        const double angle = w.norm();
        if (angle > 1e-15) R = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix() * R;
      }
      Eigen::Matrix3d K = c.K();
      if (const int f = layout.focal_index(i); f >= 0) {
        K(0, 0) *= 1 + x[f];
        K(1, 1) *= 1 + x[f];
      }
      m.R.push_back(R);
      m.K.push_back(K);
      Camera cc = c;
      cc.fx = K(0, 0);
      cc.fy = K(1, 1);
      if (const int l = layout.lens_index(i); l >= 0) {
        // The unknowns are the bend at the half diagonal under the current focal (d1 = k1 s^2,
        // d2 = k2 s^4, s = half diagonal / f): a focal change then leaves the raw-pixel
        // distortion as it was instead of trading off against k1.
        const double s2 = bend_scale(cc);
        cc.lens.k1 = x[l] / s2;
        if (layout.lens_count(i) > 1) cc.lens.k2 = x[l + 1] / (s2 * s2);
      }
      m.cam.push_back(cc);
    }
    return m;
  }

  void residuals(const Eigen::VectorXd& x, Eigen::VectorXd& f) const {
    const Model m = model(x);
    if (lens()) {
      // Raw pixel -> ray through the lens -> the other camera's raw pixel, both ways.
      auto transfer = [&](int from, int to, const Eigen::Vector2d& p, Eigen::Vector2d& q) {
        Eigen::Vector3d ray;
        if (!lens_unproject(m.cam[from], p, ray)) return false;
        return lens_project(m.cam[to], m.R[to].transpose() * (m.R[from] * ray), q);
      };
      for (std::size_t k = 0; k < ra.size(); ++k) {
        const int a = cams[k][0], b = cams[k][1];
        Eigen::Vector2d qb, qa;
        if (!transfer(a, b, ra[k], qb)) qb = rb[k] + Eigen::Vector2d(1e3, 1e3);
        if (!transfer(b, a, rb[k], qa)) qa = ra[k] + Eigen::Vector2d(1e3, 1e3);
        f.segment<2>(4 * k) = w[k] * (qb - rb[k]);
        f.segment<2>(4 * k + 2) = w[k] * (qa - ra[k]);
      }
      return;
    }
    for (std::size_t k = 0; k < pa.size(); ++k) {
      const int a = cams[k][0], b = cams[k][1];
      const Eigen::Vector3d ra = m.R[a] * (m.K[a].inverse() * Eigen::Vector3d(pa[k].x(), pa[k].y(), 1));
      const Eigen::Vector3d rb = m.R[b] * (m.K[b].inverse() * Eigen::Vector3d(pb[k].x(), pb[k].y(), 1));
      f.segment<2>(4 * k) = w[k] * (project(m.K[b], m.R[b], ra) - pb[k]);
      f.segment<2>(4 * k + 2) = w[k] * (project(m.K[a], m.R[a], rb) - pa[k]);
    }
  }
};

struct Functor {
  using Scalar = double;
  using InputType = Eigen::VectorXd;
  using ValueType = Eigen::VectorXd;
  using JacobianType = Eigen::MatrixXd;
  enum { InputsAtCompileTime = Eigen::Dynamic, ValuesAtCompileTime = Eigen::Dynamic };
  const Problem* problem;
  int inputs() const { return problem->layout.size(); }
  int values() const { return int(4 * problem->pa.size() + problem->barriers()); }
  int operator()(const Eigen::VectorXd& x, Eigen::VectorXd& f) const {
    problem->residuals(x, f);
    if (const int b = problem->barriers()) {
      const Model m = problem->model(x);
      int k = int(4 * problem->pa.size());
      for (int i = 0; i < problem->layout.n; ++i)
        if (problem->layout.lens_index(i) >= 0 && problem->layout.lens_group[i] == i) f[k++] = 10 * fold_inside_px(m.cam[i]);
      (void)b;
    }
    return 0;
  }
};

double rms(const Eigen::VectorXd& f) { return f.size() ? std::sqrt(f.squaredNorm() / (f.size() / 2)) : 0; }

void apply(Rig& rig, const Problem& p, const Eigen::VectorXd& x) {
  const Model m = p.model(x);
  for (int i = 0; i < p.layout.n; ++i) {
    Camera& c = rig.cameras[i];
    c.set_R(m.R[i]);
    c.fx = m.K[i](0, 0);
    c.fy = m.K[i](1, 1);
    if (p.layout.lens_index(i) >= 0) {
      c.lens.k1 = m.cam[i].lens.k1;
      c.lens.k2 = m.cam[i].lens.k2;
      c.lens.estimate = false;  // estimated now
    }
  }
}

// Whether the matches of the cameras of lens group `group` reach far enough out (beyond 60 % of
// the half diagonal) for k2 to be told apart from k1.
bool spread_for_k2(const Camera& c, const Problem& p, int group) {
  const double half_diag = 0.5 * std::hypot(c.width, c.height);
  int outer = 0;
  for (std::size_t k = 0; k < p.ra.size(); ++k)
    for (int e = 0; e < 2; ++e)
      if (p.layout.lens_group[p.cams[k][e]] == group) {
        const Eigen::Vector2d& q = e ? p.rb[k] : p.ra[k];
        outer += std::hypot(q.x() - c.cx, q.y() - c.cy) > 0.6 * half_diag;
      }
  return outer >= 20;
}

// Robust cost of a fit over all its matches: squared transfer errors truncated at `cap_px`,
// so that matches a candidate cannot explain (or cannot unproject) count the same for every one.
double truncated_cost(const Problem& p, const Eigen::VectorXd& x, double cap_px) {
  Eigen::VectorXd f(4 * p.pa.size());
  p.residuals(x, f);
  double cost = 0;
  for (std::size_t k = 0; k < p.pa.size(); ++k) {
    const double e2 = f.segment<4>(4 * k).squaredNorm() / (2 * p.w[k] * p.w[k]);
    cost += std::isfinite(e2) ? std::min(e2, cap_px * cap_px) : cap_px * cap_px;
  }
  return cost;
}

// Distortion and focal length trade off, and from k = 0 a strong barrel lens runs the focal off
// (k1 -0.35: f x60 and a folding lens). So before the joint fit, sweep one distortion for every
// estimating camera, as d = k1 (r/f)^2 at the half diagonal r (the same bend whatever the focal),
// fit rotations and focal lengths with the lens held, and start from the candidate whose
// truncated cost is lowest (coarse grid, then a finer one around the best).
double sweep_lens_start(const Problem& full, Eigen::VectorXd& x, double cap_px, int max_iterations,
                        const BundleAdjustOptions& stop) {
  std::vector<int> est;
  for (int i = 0; i < full.layout.n; ++i)
    if (full.layout.lens_index(i) >= 0 && full.layout.lens_group[i] == i) est.push_back(i);
  if (est.empty()) return 0;
  auto k1_of = [&](int i, double d) {
    const Camera& c = full.start->cameras[i];
    return d / bend_scale(c);
  };
  auto try_d = [&](double d, Eigen::VectorXd& xo) {
    Rig held = *full.start;
    for (int i = 0; i < full.layout.n; ++i) {
      const int g = full.layout.lens_group.empty() ? i : full.layout.lens_group[i];
      if (full.layout.lens_index(i) < 0) continue;
      held.cameras[i].lens.k1 = k1_of(g, d);
      held.cameras[i].lens.k2 = 0;
    }
    Problem q = full;
    q.start = &held;
    q.layout.lens_k.clear();
    q.layout.lens_group.clear();
    Eigen::VectorXd xq = x.head(q.layout.base_size());
    Functor fn{&q};
    Eigen::NumericalDiff<Functor> numdiff(fn);
    Eigen::LevenbergMarquardt<Eigen::NumericalDiff<Functor>> lm(numdiff);
    lm.parameters.maxfev = std::min(max_iterations, 30) * (q.layout.size() + 1);  // a ranking, not the fit
    minimize(lm, xq, stop);
    if (!xq.allFinite()) return 1e300;
    const double cost = truncated_cost(q, xq, cap_px);
    xo = x;
    xo.head(q.layout.base_size()) = xq;
    for (int i = 0; i < full.layout.n; ++i)
      if (const int l = full.layout.lens_index(i); l >= 0 && full.layout.lens_group[i] == i) {
        xo[l] = d;  // the bend is what was held (k1 follows the fitted focal)
        if (full.layout.lens_count(i) > 1) xo[l + 1] = 0;
      }
    return cost;
  };
  double best_d = 0, best = 1e300;
  Eigen::VectorXd best_x = x, xo;
  auto consider = [&](double d) {
    const double c = try_d(d, xo);
    if (c < best) best = c, best_d = d, best_x = xo;
  };
  for (double d = -0.32; d <= 0.161; d += 0.04) consider(d);
  const double centre = best_d;
  for (double d : {centre - 0.02, centre + 0.02}) consider(d);
  const double centre2 = best_d;
  for (double d : {centre2 - 0.01, centre2 + 0.01}) consider(d);
  x = best_x;
  return best_d;
}

}  // namespace

double transfer_error_px(const Rig& rig, int a, int b, const Eigen::Vector2d& pa, const Eigen::Vector2d& pb) {
  const Camera& A = rig.cameras.at(a);
  const Camera& B = rig.cameras.at(b);
  const Eigen::Vector3d ra = A.R() * (A.K().inverse() * Eigen::Vector3d(pa.x(), pa.y(), 1));
  const Eigen::Vector3d rb = B.R() * (B.K().inverse() * Eigen::Vector3d(pb.x(), pb.y(), 1));
  return std::sqrt((project(B.K(), B.R(), ra) - pb).squaredNorm() + (project(A.K(), A.R(), rb) - pa).squaredNorm());
}

BundleAdjustReport bundle_adjust(Rig& rig, const std::vector<PairMatches>& matches, const BundleAdjustOptions& o) {
  BundleAdjustReport rep;
  const int n = int(rig.cameras.size());
  if (n < 2 || rig.reference < 0 || rig.reference >= n) return rep;
  Problem p;
  p.start = &rig;
  p.layout = {n, rig.reference, o.refine_focal, o.shared_focal, {}};
  for (const auto& m : matches)
    for (std::size_t k = 0; k < m.pa.size() && k < m.pb.size(); ++k) {
      p.cams.push_back({m.a, m.b});
      p.pa.push_back(m.pa[k]);
      p.pb.push_back(m.pb[k]);
      p.w.push_back(k < m.weight.size() ? m.weight[k] : 1.0);
      if (m.ra.size() == m.pa.size() && m.rb.size() == m.pb.size()) {
        p.ra.push_back(m.ra[k]);
        p.rb.push_back(m.rb[k]);
      }
    }
  if (p.pa.empty()) return rep;
  if (p.ra.size() != p.pa.size()) {
    p.ra.clear();
    p.rb.clear();
  }
  rep.lens = p.lens();
  if (p.lens() && o.estimate_lens) {
    p.layout.lens_k.assign(n, 0);
    p.layout.lens_group.resize(n);
    for (int i = 0; i < n; ++i) {
      p.layout.lens_group[i] = i;
      const Camera& c = rig.cameras[i];
      if (!c.lens.estimate || c.lens.pinhole()) continue;
      rep.lens_estimated.push_back(i);
      // Identical cameras (same lens model and frame size, both estimating) share one lens: a
      // side camera's matches cover one side of its view only, the group's cover them all.
      if (o.shared_lens)
        for (int j = 0; j < i; ++j) {
          const Camera& d = rig.cameras[j];
          if (d.lens.estimate && d.lens.model == c.lens.model && d.width == c.width && d.height == c.height) {
            p.layout.lens_group[i] = p.layout.lens_group[j];
            break;
          }
        }
    }
    for (int i = 0; i < n; ++i)
      if (p.layout.lens_group[i] == i && rig.cameras[i].lens.estimate && !rig.cameras[i].lens.pinhole())
        p.layout.lens_k[i] = o.estimate_k2 && spread_for_k2(rig.cameras[i], p, i) ? 2 : 1;
  }
  Eigen::VectorXd x = Eigen::VectorXd::Zero(p.layout.size());
  for (int i = 0; i < n; ++i)
    if (const int l = p.layout.lens_index(i); l >= 0) {
      const double s2 = bend_scale(rig.cameras[i]);
      x[l] = rig.cameras[i].lens.k1 * s2;
      if (p.layout.lens_count(i) > 1) x[l + 1] = rig.cameras[i].lens.k2 * s2 * s2;
    }
  Eigen::VectorXd f(4 * p.pa.size());
  p.residuals(x, f);
  rep.rms_before_px = rms(f);
  bool from_zero = !p.layout.lens_k.empty();
  for (int i = 0; i < n; ++i)
    if (const int l = p.layout.lens_index(i); l >= 0) from_zero &= x[l] == 0 && (p.layout.lens_count(i) < 2 || x[l + 1] == 0);
  if (from_zero && o.sweep_lens) rep.lens_sweep_d = sweep_lens_start(p, x, o.outlier_px, o.max_iterations, o);
  for (int round = 0; round < 2; ++round) {
    Functor fn{&p};
    Eigen::NumericalDiff<Functor> numdiff(fn);
    Eigen::LevenbergMarquardt<Eigen::NumericalDiff<Functor>> lm(numdiff);
    lm.parameters.maxfev = o.max_iterations * (p.layout.size() + 1);
    if (p.lens()) lm.parameters.xtol = lm.parameters.ftol = 1e-12;  // a flat valley: focal vs k1, k2
    minimize(lm, x, o);
    if (round == 1) break;
    // Drop the matches the fit does not explain (false matches, parallax) and fit again.
    f.resize(4 * p.pa.size());
    p.residuals(x, f);
    // Estimating lenses: sub-pixel fits, where matches a few pixels off (kept by the loose
    // first-pass RANSAC) bias k2 and the focal; cut at 4x the rms (at least 1 px) instead.
    const double cut_px =
        p.layout.lens_k.empty() ? o.outlier_px : std::min(o.outlier_px, std::max(1.0, 4 * rms(f)));
    Problem kept = p;
    kept.cams.clear();
    kept.pa.clear();
    kept.pb.clear();
    kept.w.clear();
    kept.ra.clear();
    kept.rb.clear();
    for (std::size_t k = 0; k < p.pa.size(); ++k) {
      if (f.segment<4>(4 * k).norm() > cut_px * std::sqrt(2.0) * p.w[k]) continue;
      kept.cams.push_back(p.cams[k]);
      kept.pa.push_back(p.pa[k]);
      kept.pb.push_back(p.pb[k]);
      kept.w.push_back(p.w[k]);
      if (p.lens()) {
        kept.ra.push_back(p.ra[k]);
        kept.rb.push_back(p.rb[k]);
      }
    }
    rep.dropped = int(p.pa.size() - kept.pa.size());
    if (kept.pa.size() < 8) break;
    p = std::move(kept);
  }
  if (o.robust_scale > 0 && p.pa.size() >= 8) {
    // Cauchy's loss by reweighting (each match's weight times 1 / sqrt(1 + (e / c)^2)).
    for (int it = 0; it < 3; ++it) {
      f.resize(4 * p.pa.size());
      p.residuals(x, f);
      std::vector<double> e(p.pa.size());
      for (std::size_t k = 0; k < e.size(); ++k) e[k] = f.segment<4>(4 * k).norm() / (std::sqrt(2.0) * p.w[k]);
      std::vector<double> sorted = e;
      std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
      const double c = o.robust_scale * std::max(1.4826 * sorted[sorted.size() / 2], 1e-3);
      Problem q = p;
      for (std::size_t k = 0; k < e.size(); ++k) q.w[k] = p.w[k] / std::sqrt(1 + (e[k] / c) * (e[k] / c));
      Functor fn{&q};
      Eigen::NumericalDiff<Functor> numdiff(fn);
      Eigen::LevenbergMarquardt<Eigen::NumericalDiff<Functor>> lm(numdiff);
      lm.parameters.maxfev = o.max_iterations * (q.layout.size() + 1);
      if (q.lens()) lm.parameters.xtol = lm.parameters.ftol = 1e-12;
      Eigen::VectorXd xr = x;
      minimize(lm, xr, o);
      if (!xr.allFinite()) break;
      x = xr;
    }
  }
  f.resize(4 * p.pa.size());
  p.residuals(x, f);
  rep.rms_after_px = rms(f);
  rep.matches = int(p.pa.size());
  rep.ok = x.allFinite() && rep.rms_after_px <= rep.rms_before_px + 1e-9;
  if (rep.ok && !rep.lens_estimated.empty()) {
    // An estimate that folds the image (the radius turning back inside the frame) is no lens:
    // adjust again with the given coefficients.
    const Model m = p.model(x);
    for (int i : rep.lens_estimated)
      if (const std::string why = lens_problem(m.cam[i]); !why.empty()) {
        BundleAdjustOptions again = o;
        again.estimate_lens = false;
        BundleAdjustReport r2 = bundle_adjust(rig, matches, again);
        r2.lens_warning = "camera " + std::to_string(i) + ": the estimated lens was dropped (" + why + ")";
        return r2;
      }
  }
  if (rep.ok && !rep.lens_estimated.empty()) {
    // How well the matches determine each k1: sigma^2 (J^T J)^-1 at the solution.
    Functor fn{&p};
    Eigen::NumericalDiff<Functor> numdiff(fn);
    Eigen::MatrixXd J(fn.values(), fn.inputs());
    numdiff.df(x, J);
    const Eigen::MatrixXd JtJ = J.transpose() * J;
    const double dof = std::max(1.0, double(f.size()) - double(x.size()));
    const Eigen::MatrixXd cov = JtJ.completeOrthogonalDecomposition().pseudoInverse() * (f.squaredNorm() / dof);
    const Model m = p.model(x);
    rep.lens_k1_sigma.assign(n, 0.0);
    for (int i : rep.lens_estimated)
      if (const int l = p.layout.lens_index(i); l >= 0)
        rep.lens_k1_sigma[i] = std::sqrt(std::max(0.0, cov(l, l))) / bend_scale(m.cam[i]);
  }
  if (rep.ok) apply(rig, p, x);
  return rep;
}

Eigen::Matrix3d wave_correct(Rig& rig) {
  // The "up" direction is the one most orthogonal to every camera's x axis: the eigenvector of
  // the smallest eigenvalue of sum x x^T (OpenCV's horizontal wave correction does the same).
  // A camera mounted on its side (rolled by about 90 degrees relative to the reference camera: a
  // portrait-mounted camera in a landscape rig) has its y axis horizontal, not its x axis; taking
  // its x axis would make "up" the viewing direction and turn the panorama on its side. Each
  // camera's horizontal axis is the one of x, y further from the reference camera's down axis.
  Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
  Eigen::Vector3d down_sum = Eigen::Vector3d::Zero();
  const Eigen::Vector3d ref_down = rig.cameras.at(rig.reference).R().col(1);
  for (const auto& c : rig.cameras) {
    const Eigen::Matrix3d R = c.R();
    Eigen::Vector3d across = R.col(0), down = R.col(1);
    if (std::abs(R.col(1).dot(ref_down)) < std::abs(R.col(0).dot(ref_down))) {
      across = R.col(1);
      down = R.col(0).dot(ref_down) >= 0 ? Eigen::Vector3d(R.col(0)) : Eigen::Vector3d(-R.col(0));
    }
    S += across * across.transpose();
    down_sum += down;
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(S);
  // x axes that (almost) all point the same way span no plane: nothing to level.
  if (es.eigenvalues()(1) < 0.02 * double(rig.cameras.size())) return Eigen::Matrix3d::Identity();
  Eigen::Vector3d down = es.eigenvectors().col(0);
  if (down.dot(down_sum) < 0) down = -down;
  // Keep the reference camera's heading: its optical axis, made horizontal, stays forward.
  const Eigen::Matrix3d Rref = rig.cameras.at(rig.reference).R();
  Eigen::Vector3d fwd = Rref.col(2) - Rref.col(2).dot(down) * down;
  if (fwd.norm() < 1e-6) fwd = Rref.col(0).cross(down);
  fwd.normalize();
  const Eigen::Vector3d right = down.cross(fwd);
  // New rig frame: x = right, y = down, z = forward, with the reference yaw kept.
  Eigen::Matrix3d G;
  G.row(0) = right.transpose();
  G.row(1) = down.transpose();
  G.row(2) = fwd.transpose();
  const double yaw = rig.cameras.at(rig.reference).yaw_deg * 3.14159265358979323846 / 180.0;
  Eigen::Matrix3d Ry;
  Ry << std::cos(yaw), 0, std::sin(yaw), 0, 1, 0, -std::sin(yaw), 0, std::cos(yaw);
  const Eigen::Matrix3d C = Ry * G;
  for (auto& c : rig.cameras) c.set_R(C * c.R());
  return C;
}

}  // namespace stitch
