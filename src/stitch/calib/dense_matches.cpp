#include "stitch/calib/dense_matches.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "stitch/rig/lens.hpp"

namespace stitch {
namespace {

// Raw pixel of camera s -> raw pixel of camera t through both lenses and rotations.
struct Transfer {
  const Camera &S, &T;
  Eigen::Matrix3d R;  // s camera frame -> t camera frame
  Transfer(const Camera& s, const Camera& t) : S(s), T(t), R(t.R().transpose() * s.R()) {}
  bool operator()(const Eigen::Vector2d& p, Eigen::Vector2d& q) const {
    Eigen::Vector3d ray;
    if (!lens_unproject(S, p, ray)) return false;
    return lens_project(T, R * ray, q);
  }
};

// Sample of a CV_32F image by cubic convolution (Keys, a = -0.5): bilinear interpolation
// smooths by a sub-pixel-phase dependent amount and pulls the alignment towards whole-pixel shifts
// (a bias that varies smoothly over the overlap with the map's phase). False outside.
inline void keys(float t, float w[4]) {
  const float t2 = t * t, t3 = t2 * t;
  w[0] = -0.5f * t3 + t2 - 0.5f * t;
  w[1] = 1.5f * t3 - 2.5f * t2 + 1;
  w[2] = -1.5f * t3 + 2 * t2 + 0.5f * t;
  w[3] = 0.5f * t3 - 0.5f * t2;
}
inline bool sample(const cv::Mat& m, double x, double y, float& v) {
  if (!(x >= 1 && y >= 1 && x < m.cols - 2 && y < m.rows - 2)) return false;
  const int x0 = int(x), y0 = int(y);
  float wx[4], wy[4];
  keys(float(x - x0), wx);
  keys(float(y - y0), wy);
  float acc = 0;
  for (int j = 0; j < 4; ++j) {
    const float* r = m.ptr<float>(y0 - 1 + j) + x0 - 1;
    acc += wy[j] * (wx[0] * r[0] + wx[1] * r[1] + wx[2] * r[2] + wx[3] * r[3]);
  }
  v = acc;
  return true;
}

// A float copy of the square of half side `half` around (cx, cy) (integers), smoothed by the
// Gaussian of covariance `cov` (pixels^2; anisotropic), with its gradients when asked; false where
// the square leaves the image.
struct Roi {
  int x0 = 0, y0 = 0;
  cv::Mat img, gx, gy;
};
bool smoothed_roi(const cv::Mat& img, int cx, int cy, int half, const Eigen::Matrix2d& cov, bool gradients, Roi& out) {
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
  const double smax = std::sqrt(std::max(0.0, es.eigenvalues()[1]));
  const int kr = std::max(1, int(std::ceil(3 * smax)));
  const int pad = kr + 2;
  const cv::Rect r(cx - half - pad, cy - half - pad, 2 * (half + pad) + 1, 2 * (half + pad) + 1);
  if (r.x < 0 || r.y < 0 || r.x + r.width > img.cols || r.y + r.height > img.rows) return false;
  cv::Mat roi;
  if (smax > 0.05) {
    // Kernel of the covariance (regularised: the smaller axis at least 0.05 px).
    const Eigen::Matrix2d ci = (cov + 0.0025 * Eigen::Matrix2d::Identity()).inverse();
    cv::Mat k(2 * kr + 1, 2 * kr + 1, CV_32F);
    double sum = 0;
    for (int y = -kr; y <= kr; ++y)
      for (int x = -kr; x <= kr; ++x) {
        const Eigen::Vector2d v(x, y);
        const double w = std::exp(-0.5 * v.dot(ci * v));
        k.at<float>(y + kr, x + kr) = float(w);
        sum += w;
      }
    k /= sum;
    cv::filter2D(img(r), roi, CV_32F, k, cv::Point(-1, -1), 0, cv::BORDER_REPLICATE);
  } else {
    roi = img(r).clone();
  }
  out.x0 = r.x;
  out.y0 = r.y;
  out.img = roi;
  if (gradients) {
    cv::Sobel(roi, out.gx, CV_32F, 1, 0, 3, 1.0 / 8, 0, cv::BORDER_REPLICATE);
    cv::Sobel(roi, out.gy, CV_32F, 0, 1, 3, 1.0 / 8, 0, cv::BORDER_REPLICATE);
  }
  return true;
}

// Points picked in s, located in t: appended to (ps, pt).
void track(const Camera& cs, const Camera& ct, const DenseImage& S, const DenseImage& T, const DenseMatchOptions& o,
           std::vector<Eigen::Vector2d>& ps, std::vector<Eigen::Vector2d>& pt) {
  const Transfer tr(cs, ct);
  const int R = std::max(2, o.radius);
  // Where s pixels land well inside t (a coarse grid of the transfer).
  const int step = 4, border = R + 2;
  const double tmargin = 1.5 * R + o.max_shift_px + 2;
  cv::Mat mask = cv::Mat::zeros(S.gray.size(), CV_8U);
  // A patch wholly inside the image circle (a fisheye's black rim is a strong edge that no
  // other camera sees): `margin` pixels inside it, not its centre alone.
  auto sees_patch = [](const Camera& c, double x, double y, double margin) {
    if (!lens_sees(c, x, y) || !c.lens.circle) return lens_sees(c, x, y);
    return std::hypot(x - c.lens.circle->cx, y - c.lens.circle->cy) + margin < c.lens.circle->radius;
  };
  for (int y = border; y < S.gray.rows - border; y += step)
    for (int x = border; x < S.gray.cols - border; x += step) {
      Eigen::Vector2d q;
      if (!sees_patch(cs, x + 0.5 * step, y + 0.5 * step, 0.71 * step + 1.42 * R + 1) ||
          !tr({x + 0.5 * step, y + 0.5 * step}, q))
        continue;
      if (q.x() < tmargin || q.y() < tmargin || q.x() > ct.width - 1 - tmargin || q.y() > ct.height - 1 - tmargin ||
          !sees_patch(ct, q.x(), q.y(), 2 * R + 2))
        continue;
      mask(cv::Rect(x, y, std::min(step, S.gray.cols - border - x), std::min(step, S.gray.rows - border - y))) = 255;
    }
  if (cv::countNonZero(mask) == 0) return;
  std::vector<cv::Point2f> corners;
  cv::goodFeaturesToTrack(S.gray, corners, o.max_points, o.quality, o.min_distance, mask, 5);
  const int side = 2 * R + 1, np = side * side;
  std::vector<float> tmpl(np), smp(np);
  std::vector<Eigen::Vector2d> warp(np);
  for (const auto& c : corners) {
    const int px = int(std::lround(c.x)), py = int(std::lround(c.y));
    const Eigen::Vector2d p(px, py);
    // The patch's pixels through the rig, one by one: an affine approximation leaves the lens's
    // curvature (about 0.05 px at k1 -0.35 over a 15 px patch) as a shift that biases the focal.
    Eigen::Vector2d q0;
    if (!tr(p, q0)) continue;
    bool mapped = true;
    double reach = 0;
    for (int v = -R, k = 0; v <= R && mapped; ++v)
      for (int u = -R; u <= R && mapped; ++u, ++k) {
        Eigen::Vector2d q;
        mapped = tr(p + Eigen::Vector2d(u, v), q);
        warp[k] = q - q0;
        reach = std::max(reach, warp[k].lpNorm<Eigen::Infinity>());
      }
    if (!mapped) continue;
    // Equal resolution on both sides: scene detail of size 1 in s has the size of A (the map's
    // local Jacobian) in t, so a smoothing of covariance V in s looks like A V A^T in t. Both
    // cameras' own pixel blur (variance kPixelVar) counts too. Each side is smoothed up to the
    // common covariance C (at least either's, per axis of A A^T): with unequal smoothing a patch's
    // gradient imbalance turns into a shift that follows the scale, i.e. the position in the
    // frame, which biases the focal length (k1 +0.1: 0.6 %, 3 px at the corners).
    constexpr double kPixelVar = 1.0 / 12;
    Eigen::Matrix2d A;
    A.col(0) = 0.5 * (warp[R * side + R + 1] - warp[R * side + R - 1]);
    A.col(1) = 0.5 * (warp[(R + 1) * side + R] - warp[(R - 1) * side + R]);
    const double det = A.determinant();
    if (!(std::abs(det) > 0.0625 && std::abs(det) < 16)) continue;
    const double v0 = o.blur_sigma * o.blur_sigma + kPixelVar;
    const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(A * A.transpose());
    const Eigen::Vector2d lam = es.eigenvalues().cwiseMax(1.0);
    const Eigen::Matrix2d C = v0 * es.eigenvectors() * lam.asDiagonal() * es.eigenvectors().transpose();
    const Eigen::Matrix2d Ai = A.inverse();
    const Eigen::Matrix2d cov_t = C - kPixelVar * Eigen::Matrix2d::Identity();
    const Eigen::Matrix2d cov_s = Ai * C * Ai.transpose() - kPixelVar * Eigen::Matrix2d::Identity();
    Roi rs, rt;
    const int qx = int(std::lround(q0.x())), qy = int(std::lround(q0.y()));
    if (!smoothed_roi(S.img, px, py, R, cov_s, false, rs) ||
        !smoothed_roi(T.img, qx, qy, int(std::ceil(reach + o.max_shift_px)) + 2, cov_t, true, rt))
      continue;
    const double ox = q0.x() - rt.x0, oy = q0.y() - rt.y0;  // q0 in the t roi
    double tm = 0, tv = 0;
    for (int v = -R, k = 0; v <= R; ++v)
      for (int u = -R; u <= R; ++u, ++k) {
        tmpl[k] = rs.img.at<float>(py - rs.y0 + v, px - rs.x0 + u);
        tm += tmpl[k];
      }
    tm /= np;
    for (int k = 0; k < np; ++k) tv += (tmpl[k] - tm) * (tmpl[k] - tm);
    if (tv < np * 4.0) continue;  // flat (std below 2 grey levels)
    // Gauss-Newton on I_t(q0 + d + w(u)) = alpha tmpl(u) + beta.
    Eigen::Vector2d d(0, 0);
    double alpha = 1, beta = 0;
    bool ok = true, converged = false;
    for (int it = 0; it < 30 && ok; ++it) {
      Eigen::Matrix4d H = Eigen::Matrix4d::Zero();
      Eigen::Vector4d g = Eigen::Vector4d::Zero();
      for (int k = 0; k < np && ok; ++k) {
        const double x = ox + d.x() + warp[k].x(), y = oy + d.y() + warp[k].y();
        float iv, gxv, gyv;
        if (!sample(rt.img, x, y, iv) || !sample(rt.gx, x, y, gxv) || !sample(rt.gy, x, y, gyv)) {
          ok = false;
          break;
        }
        const double r = iv - alpha * tmpl[k] - beta;
        const Eigen::Vector4d j(gxv, gyv, -tmpl[k], -1.0);
        H += j * j.transpose();
        g += j * r;
      }
      if (!ok) break;
      const Eigen::Vector4d step4 = H.ldlt().solve(-g);
      if (!step4.allFinite()) {
        ok = false;
        break;
      }
      d += step4.head<2>();
      alpha += step4[2];
      beta += step4[3];
      if (d.norm() > o.max_shift_px || !(alpha > 0.2 && alpha < 5)) ok = false;
      if (step4.head<2>().norm() < 1e-4) {
        converged = true;
        break;
      }
    }
    if (!ok || !converged) continue;
    // Normalised cross-correlation at the solution.
    double sm = 0;
    for (int k = 0; k < np && ok; ++k) {
      ok &= sample(rt.img, ox + d.x() + warp[k].x(), oy + d.y() + warp[k].y(), smp[k]);
      sm += smp[k];
    }
    if (!ok) continue;
    sm /= np;
    double sxy = 0, syy = 0;
    for (int k = 0; k < np; ++k) {
      sxy += (smp[k] - sm) * (tmpl[k] - tm);
      syy += (smp[k] - sm) * (smp[k] - sm);
    }
    if (!(syy > 0) || sxy / std::sqrt(syy * tv) < o.min_ncc) continue;
    const Eigen::Vector2d q = q0 + d;
    if (!lens_sees(ct, q.x(), q.y())) continue;
    ps.push_back(p);
    pt.push_back(q);
  }
}

}  // namespace

DenseImage prepare_dense_image(const cv::Mat& gray8, const DenseMatchOptions&) {
  DenseImage d;
  d.gray = gray8;
  gray8.convertTo(d.img, CV_32F);
  return d;
}

PairMatches dense_pair_matches(const Rig& rig, int a, int b, const DenseImage& A, const DenseImage& B,
                               const DenseMatchOptions& o) {
  PairMatches m;
  m.a = a;
  m.b = b;
  const Camera &ca = rig.cameras.at(a), &cb = rig.cameras.at(b);
  std::vector<Eigen::Vector2d> pa, pb, qb, qa;
  track(ca, cb, A, B, o, pa, pb);  // picked in a
  track(cb, ca, B, A, o, qb, qa);  // picked in b
  pa.insert(pa.end(), qa.begin(), qa.end());
  pb.insert(pb.end(), qb.begin(), qb.end());
  for (std::size_t k = 0; k < pa.size(); ++k) {
    Eigen::Vector2d ia = pa[k], ib = pb[k];
    if (!o.rays && (!undistort_point(ca, pa[k], ia) || !undistort_point(cb, pb[k], ib))) continue;
    m.ra.push_back(pa[k]);
    m.rb.push_back(pb[k]);
    m.pa.push_back(ia);
    m.pb.push_back(ib);
    m.weight.push_back(1.0);
  }
  return m;
}

std::vector<PairMatches> dense_matches(const Rig& rig, const std::vector<std::pair<int, int>>& pairs,
                                       const std::vector<std::vector<DenseImage>>& images, const DenseMatchOptions& o) {
  std::vector<PairMatches> out;
  for (const auto& [a, b] : pairs) {
    PairMatches all;
    all.a = a;
    all.b = b;
    for (const auto& set : images) {
      if (o.cancel && o.cancel->load(std::memory_order_relaxed)) return out;
      const PairMatches m = dense_pair_matches(rig, a, b, set.at(a), set.at(b), o);
      all.pa.insert(all.pa.end(), m.pa.begin(), m.pa.end());
      all.pb.insert(all.pb.end(), m.pb.begin(), m.pb.end());
      all.ra.insert(all.ra.end(), m.ra.begin(), m.ra.end());
      all.rb.insert(all.rb.end(), m.rb.begin(), m.rb.end());
      all.weight.insert(all.weight.end(), m.weight.begin(), m.weight.end());
    }
    if (!all.pa.empty()) out.push_back(std::move(all));
  }
  return out;
}

int correct_phase_bias(const Rig& rig, std::vector<PairMatches>& matches) {
  auto whole = [](const Eigen::Vector2d& v) {
    return std::abs(v.x() - std::round(v.x())) < 1e-9 && std::abs(v.y() - std::round(v.y())) < 1e-9;
  };
  auto basis = [](double f, double* b) {
    const double t = 2 * M_PI * f;
    b[0] = 1, b[1] = std::sin(t), b[2] = std::cos(t), b[3] = std::sin(2 * t), b[4] = std::cos(2 * t);
  };
  // Per axis: normal equations of the residual on (1, sin, cos, sin 2, cos 2) of the phase.
  Eigen::Matrix<double, 5, 5> N[2] = {Eigen::Matrix<double, 5, 5>::Zero(), Eigen::Matrix<double, 5, 5>::Zero()};
  Eigen::Matrix<double, 5, 1> r[2] = {Eigen::Matrix<double, 5, 1>::Zero(), Eigen::Matrix<double, 5, 1>::Zero()};
  int used = 0;
  for (const auto& m : matches) {
    if (m.ra.size() != m.pa.size() || m.rb.size() != m.pb.size()) continue;
    const Camera &ca = rig.cameras.at(m.a), &cb = rig.cameras.at(m.b);
    const Transfer ab(ca, cb), ba(cb, ca);
    for (std::size_t k = 0; k < m.ra.size(); ++k) {
      const bool wa = whole(m.ra[k]), wb = whole(m.rb[k]);
      if (wa == wb) continue;
      const Eigen::Vector2d& loc = wa ? m.rb[k] : m.ra[k];
      Eigen::Vector2d pred;
      if (!(wa ? ab(m.ra[k], pred) : ba(m.rb[k], pred))) continue;
      const Eigen::Vector2d e = pred - loc;
      if (!(e.norm() < 0.5)) continue;
      for (int ax = 0; ax < 2; ++ax) {
        double b[5];
        basis(loc[ax] - std::floor(loc[ax]), b);
        const Eigen::Map<const Eigen::Matrix<double, 5, 1>> bv(b);
        N[ax] += bv * bv.transpose();
        r[ax] += bv * e[ax];
      }
      ++used;
    }
  }
  if (used < 200) return 0;
  Eigen::Matrix<double, 5, 1> c[2];
  for (int ax = 0; ax < 2; ++ax) {
    c[ax] = N[ax].ldlt().solve(r[ax]);
    c[ax][0] = 0;  // the mean is the rig's business
    if (!c[ax].allFinite()) return 0;
  }
  auto shift = [&](const Eigen::Vector2d& v) {
    Eigen::Vector2d s;
    for (int ax = 0; ax < 2; ++ax) {
      double b[5];
      basis(v[ax] - std::floor(v[ax]), b);
      s[ax] = Eigen::Map<const Eigen::Matrix<double, 5, 1>>(b).dot(c[ax]);
    }
    return s;
  };
  for (auto& m : matches) {
    if (m.ra.size() != m.pa.size() || m.rb.size() != m.pb.size()) continue;
    const Camera &ca = rig.cameras.at(m.a), &cb = rig.cameras.at(m.b);
    for (std::size_t k = 0; k < m.ra.size(); ++k) {
      const bool wa = whole(m.ra[k]), wb = whole(m.rb[k]);
      if (wa == wb) continue;
      Eigen::Vector2d& loc = wa ? m.rb[k] : m.ra[k];
      const Eigen::Vector2d moved = loc + shift(loc);
      Eigen::Vector2d ideal;
      if (!undistort_point(wa ? cb : ca, moved, ideal)) continue;
      loc = moved;
      (wa ? m.pb[k] : m.pa[k]) = ideal;
    }
  }
  return used;
}

}  // namespace stitch
