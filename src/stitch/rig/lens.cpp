#include "stitch/rig/lens.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace stitch {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kNoLimit = 1e30;

// The first x in (0, hi] where slope(x) <= 0 (a coarse scan, then bisection); `none` if none.
template <typename F>
double first_fold(F slope, double hi, double step, double none) {
  double prev = 0;
  for (double x = step; x <= hi + 1e-12; x += step) {
    if (slope(x) <= 0) {
      double lo = prev, up = x;
      for (int it = 0; it < 50; ++it) {
        const double mid = 0.5 * (lo + up);
        (slope(mid) <= 0 ? up : lo) = mid;
      }
      return lo;
    }
    prev = x;
  }
  return none;
}

// The fold limits scan the radius (up to ~2000 polynomial evaluations) and every projection asks
// for them: the calibration's adjustment projects millions of points through a handful of lenses.
// A small per-thread cache keyed by the exact coefficients returns the same values.
template <int N>
struct LimitCache {
  struct Entry {
    double k[N];
    double limit;
  };
  Entry e[8];
  int used = 0, next = 0;
  template <typename F>
  double get(const double (&k)[N], F compute) {
    for (int i = 0; i < used; ++i)
      if (std::equal(k, k + N, e[i].k)) return e[i].limit;
    Entry& slot = e[next];
    std::copy(k, k + N, slot.k);
    slot.limit = compute();
    next = (next + 1) % 8;
    used = std::min(used + 1, 8);
    return slot.limit;
  }
};

double radtan_limit_uncached(const Lens& l);
double fisheye_limit_uncached(const Lens& l);

double radtan_limit(const Lens& l) {
  thread_local LimitCache<3> cache;
  const double k[3] = {l.k1, l.k2, l.k3};
  return cache.get(k, [&] { return radtan_limit_uncached(l); });
}

double fisheye_limit(const Lens& l) {
  thread_local LimitCache<4> cache;
  const double k[4] = {l.k1, l.k2, l.k3, l.k4};
  return cache.get(k, [&] { return fisheye_limit_uncached(l); });
}

double radtan_limit_uncached(const Lens& l) {
  // The radius r (1 + k1 r^2 + k2 r^4 + k3 r^6) grows while 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6 > 0.
  const double r = first_fold(
      [&](double x) {
        const double r2 = x * x;
        return 1 + r2 * (3 * l.k1 + r2 * (5 * l.k2 + r2 * 7 * l.k3));
      },
      20.0, 0.01, -1.0);
  return r < 0 ? kNoLimit : r * r;
}

double fisheye_limit_uncached(const Lens& l) {
  return first_fold(
      [&](double t) {
        const double t2 = t * t;
        return 1 + t2 * (3 * l.k1 + t2 * (5 * l.k2 + t2 * (7 * l.k3 + t2 * 9 * l.k4)));
      },
      kPi, 0.005, kPi);
}

double fisheye_theta_d(const Lens& l, double t) {
  const double t2 = t * t;
  return t * (1 + t2 * (l.k1 + t2 * (l.k2 + t2 * (l.k3 + t2 * l.k4))));
}

}  // namespace

stitch_projection::LensParams<double> lens_params(const Camera& c) {
  stitch_projection::LensParams<double> p{};
  const Lens& l = c.lens;
  p.model = l.model == Lens::Model::Radtan ? stitch_projection::kLensRadtan
            : l.model == Lens::Model::Fisheye ? stitch_projection::kLensFisheye
                                              : stitch_projection::kLensPinhole;
  p.fx = c.fx;
  p.fy = c.fy;
  p.cx = c.cx;
  p.cy = c.cy;
  p.k1 = l.k1;
  p.k2 = l.k2;
  p.k3 = l.k3;
  p.k4 = l.k4;
  p.p1 = l.p1;
  p.p2 = l.p2;
  p.limit = l.model == Lens::Model::Radtan ? radtan_limit(l) : l.model == Lens::Model::Fisheye ? fisheye_limit(l) : kNoLimit;
  if (l.circle) {
    p.circle_cx = l.circle->cx;
    p.circle_cy = l.circle->cy;
    p.circle_r = l.circle->radius;
  }
  return p;
}

stitch_projection::LensParams<float> lens_params_f(const Camera& c) {
  const auto d = lens_params(c);
  stitch_projection::LensParams<float> f{};
  f.model = d.model;
  f.fx = float(d.fx), f.fy = float(d.fy), f.cx = float(d.cx), f.cy = float(d.cy);
  f.k1 = float(d.k1), f.k2 = float(d.k2), f.k3 = float(d.k3), f.k4 = float(d.k4);
  f.p1 = float(d.p1), f.p2 = float(d.p2);
  f.limit = float(std::min(d.limit, 1e30));
  f.circle_cx = float(d.circle_cx), f.circle_cy = float(d.circle_cy), f.circle_r = float(d.circle_r);
  return f;
}

bool lens_project(const Camera& c, const Eigen::Vector3d& ray, Eigen::Vector2d& raw) {
  return stitch_projection::lens_project(lens_params(c), ray.x(), ray.y(), ray.z(), raw.x(), raw.y());
}

bool lens_unproject(const Camera& c, const Eigen::Vector2d& raw, Eigen::Vector3d& ray) {
  const double xd = (raw.x() - c.cx) / c.fx, yd = (raw.y() - c.cy) / c.fy;
  const Lens& l = c.lens;
  if (l.model == Lens::Model::Pinhole) {
    ray = Eigen::Vector3d(xd, yd, 1).normalized();
    return true;
  }
  if (l.model == Lens::Model::Fisheye) {
    const double td = std::hypot(xd, yd), limit = fisheye_limit(l);
    if (td < 1e-12) {
      ray = {0, 0, 1};
      return true;
    }
    if (td > fisheye_theta_d(l, limit) + 1e-9) return false;
    // Newton on theta_d(theta) = td, kept inside [0, limit] where theta_d is monotonic.
    double t = std::min(td, limit);
    for (int it = 0; it < 50; ++it) {
      const double t2 = t * t;
      const double f = fisheye_theta_d(l, t) - td;
      const double df = 1 + t2 * (3 * l.k1 + t2 * (5 * l.k2 + t2 * (7 * l.k3 + t2 * 9 * l.k4)));
      double next = df > 1e-12 ? t - f / df : t;
      next = std::clamp(next, 0.0, limit);
      if (std::abs(next - t) < 1e-14) {
        t = next;
        break;
      }
      t = next;
    }
    if (std::abs(fisheye_theta_d(l, t) - td) > 1e-7) return false;
    const double s = std::sin(t) / td;
    ray = {xd * s, yd * s, std::cos(t)};
    return true;
  }
  // radtan: Newton on the 2-D distortion, from the distorted point.
  const double limit = radtan_limit(l);
  double x = xd, y = yd;
  for (int it = 0; it < 50; ++it) {
    const double r2 = x * x + y * y;
    const double rad = 1 + r2 * (l.k1 + r2 * (l.k2 + r2 * l.k3));
    const double drad = l.k1 + r2 * (2 * l.k2 + r2 * 3 * l.k3);  // d rad / d r2
    const double fx = x * rad + 2 * l.p1 * x * y + l.p2 * (r2 + 2 * x * x) - xd;
    const double fy = y * rad + l.p1 * (r2 + 2 * y * y) + 2 * l.p2 * x * y - yd;
    const double j00 = rad + 2 * x * x * drad + 2 * l.p1 * y + 6 * l.p2 * x;
    const double j01 = 2 * x * y * drad + 2 * l.p1 * x + 2 * l.p2 * y;
    const double j10 = 2 * x * y * drad + 2 * l.p1 * x + 2 * l.p2 * y;
    const double j11 = rad + 2 * y * y * drad + 6 * l.p1 * y + 2 * l.p2 * x;
    const double det = j00 * j11 - j01 * j10;
    if (!(std::abs(det) > 1e-15)) return false;
    double dx = (j11 * fx - j01 * fy) / det, dy = (j00 * fy - j10 * fx) / det;
    // Damped: never jump past the fold.
    for (int k = 0; k < 30 && (x - dx) * (x - dx) + (y - dy) * (y - dy) > limit; ++k) dx *= 0.5, dy *= 0.5;
    x -= dx;
    y -= dy;
    if (dx * dx + dy * dy < 1e-26) break;
  }
  const double r2 = x * x + y * y;
  if (!(r2 <= limit) || !std::isfinite(r2)) return false;
  Eigen::Vector2d check;
  if (!lens_project(c, {x, y, 1}, check) || (check - raw).norm() > 1e-4) return false;
  ray = Eigen::Vector3d(x, y, 1).normalized();
  return true;
}

bool undistort_point(const Camera& c, const Eigen::Vector2d& raw, Eigen::Vector2d& ideal) {
  if (c.lens.pinhole()) {
    ideal = raw;
    return true;
  }
  Eigen::Vector3d r;
  if (!lens_unproject(c, raw, r) || !(r.z() > 1e-9)) return false;
  ideal = {c.fx * r.x() / r.z() + c.cx, c.fy * r.y() / r.z() + c.cy};
  return true;
}

bool distort_point(const Camera& c, const Eigen::Vector2d& ideal, Eigen::Vector2d& raw) {
  return lens_project(c, {(ideal.x() - c.cx) / c.fx, (ideal.y() - c.cy) / c.fy, 1.0}, raw);
}

std::vector<cv::Point2f> undistort_points(const Camera& c, const std::vector<cv::Point2f>& raw) {
  std::vector<cv::Point2f> out;
  out.reserve(raw.size());
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (const auto& p : raw) {
    Eigen::Vector2d q;
    if (undistort_point(c, {p.x, p.y}, q)) out.emplace_back(float(q.x()), float(q.y()));
    else out.emplace_back(nan, nan);
  }
  return out;
}

bool lens_sees(const Camera& c, double u, double v) {
  if (!(u >= -0.5 && v >= -0.5 && u <= c.width - 0.5 && v <= c.height - 0.5)) return false;
  if (!c.lens.circle) return true;
  return std::hypot(u - c.lens.circle->cx, v - c.lens.circle->cy) < c.lens.circle->radius;
}

std::string lens_problem(const Camera& c) {
  const Lens& l = c.lens;
  if (l.circle) {
    const LensCircle& k = *l.circle;
    if (!(k.radius > 0)) return "the image circle's radius must be positive";
    // The circle must overlap the frame.
    const double nx = std::clamp(k.cx, -0.5, c.width - 0.5), ny = std::clamp(k.cy, -0.5, c.height - 0.5);
    if (std::hypot(nx - k.cx, ny - k.cy) >= k.radius) return "the image circle lies outside the frame";
  }
  if (l.model == Lens::Model::Pinhole) return {};
  // The raw radius (normalised) of the farthest image corner (or circle rim) must lie before the
  // distortion folds back.
  const double far = lens_far_radius(c);
  if (l.model == Lens::Model::Radtan) {
    const double lim = radtan_limit(l);
    if (lim >= kNoLimit) return {};
    const double r = std::sqrt(lim), rd = r * (1 + lim * (l.k1 + lim * (l.k2 + lim * l.k3)));
    if (rd < far * 0.999)
      return "the distortion coefficients fold the image (the radius stops growing at " + std::to_string(rd) +
             " focal lengths, inside the image which reaches " + std::to_string(far) + ")";
    return {};
  }
  const double lim = fisheye_limit(l);
  if (lim < kPi && fisheye_theta_d(l, lim) < far * 0.999)
    return "the fisheye coefficients fold the image (theta_d stops growing at " + std::to_string(lim * 180 / kPi) +
           " degrees from the axis)";
  return {};
}

bool lens_cap_at_fold(Camera& c, double min_share) {
  const Lens& l = c.lens;
  if (l.circle || l.pinhole() || !(c.fx > 0) || !(c.fy > 0) || lens_problem(c).empty()) return false;
  double rd;  // the normalised raw radius where the distortion stops growing
  if (l.model == Lens::Model::Radtan) {
    const double lim = radtan_limit(l);
    if (lim >= kNoLimit) return false;
    rd = std::sqrt(lim) * (1 + lim * (l.k1 + lim * (l.k2 + lim * l.k3)));
  } else {
    const double lim = fisheye_limit(l);
    if (!(lim < kPi)) return false;
    rd = fisheye_theta_d(l, lim);
  }
  const double radius = 0.99 * rd * std::min(c.fx, c.fy);
  if (!(radius >= min_share * 0.5 * std::min(c.width, c.height))) return false;
  c.lens.circle = LensCircle{c.cx, c.cy, radius};
  if (!lens_problem(c).empty()) {
    c.lens.circle.reset();
    return false;
  }
  return true;
}

double lens_far_radius(const Camera& c) {
  double far = 0;
  const double xs[2] = {-0.5, c.width - 0.5}, ys[2] = {-0.5, c.height - 0.5};
  for (double x : xs)
    for (double y : ys) far = std::max(far, std::hypot((x - c.cx) / c.fx, (y - c.cy) / c.fy));
  if (c.lens.circle)
    far = std::min(far, (std::hypot(c.lens.circle->cx - c.cx, c.lens.circle->cy - c.cy) + c.lens.circle->radius) /
                            std::min(c.fx, c.fy));
  return far;
}

std::string lens_warning(const Camera& c) {
  if (c.lens.model != Lens::Model::Fisheye || !(c.fx > 0) || !(c.fy > 0)) return {};
  // theta of the farthest frame corner (or the circle's rim) through the lens.
  const double far = lens_far_radius(c);
  Eigen::Vector3d ray;
  const double u = c.cx + far * c.fx, v = c.cy;
  double theta = far;  // equidistant: theta = theta_d
  if (lens_unproject(c, {u, v}, ray)) theta = std::acos(std::clamp(ray.z(), -1.0, 1.0));
  const double fov = 2 * theta * 180 / kPi;
  if (fov >= kFisheyeMinDiagonalFovDeg) return {};
  return "the fisheye lens sees only " + std::to_string(int(std::lround(fov))) +
         " degrees across the frame's diagonal (focal " + std::to_string(int(std::lround(c.fx))) +
         " px): a rectilinear image given the fisheye model? Use \"radtan\" or \"pinhole\"";
}

PlaneCanvasCheck check_plane_canvas(const Rig& rig) {
  PlaneCanvasCheck out;
  const int n = int(rig.cameras.size());
  if (!rig.planar() || rig.reference < 0 || rig.reference >= n) return out;
  bool lenses = false, homographies = true;
  for (const auto& c : rig.cameras) {
    lenses |= !c.lens.pinhole();
    homographies &= bool(c.homography);
  }
  if (!lenses || homographies || rig.plane_distance_m > 0) return out;
  const Eigen::Vector3d zref = rig.cameras[rig.reference].R().col(2);
  double max_pitch = 0;
  for (int i = 0; i < n; ++i) {
    const Camera& c = rig.cameras[i];
    if (!(c.fx > 0) || !(c.fy > 0) || c.width <= 0 || c.height <= 0) continue;
    // The view's outline: along rays from the principal point, the farthest raw pixel that the
    // lens sees and unprojects (the frame's border, the image circle, or the lens's limit).
    const Eigen::Matrix3d R = c.R();
    const double reach = std::hypot(std::max(c.cx, c.width - c.cx), std::max(c.cy, c.height - c.cy));
    double off = 0, view = 0;
    for (int k = 0; k < 72; ++k) {
      const double phi = 2 * kPi * k / 72, du = std::cos(phi), dv = std::sin(phi);
      Eigen::Vector3d last(0, 0, 1);
      auto at = [&](double t, Eigen::Vector3d& ray) {
        return lens_sees(c, c.cx + t * du, c.cy + t * dv) && lens_unproject(c, {c.cx + t * du, c.cy + t * dv}, ray);
      };
      const double step = std::max(1.0, reach / 64);
      double good = 0;
      for (double t = 0; t <= reach; t += step) {
        Eigen::Vector3d ray;
        if (!at(t, ray)) break;
        last = ray, good = t;
      }
      // The outline to a hundredth of a pixel (bisection past the last step seen).
      for (double lo = good, hi = good + step; hi - lo > 0.01;) {
        const double mid = 0.5 * (lo + hi);
        Eigen::Vector3d ray;
        if (at(mid, ray)) lo = mid, last = ray;
        else hi = mid;
      }
      const Eigen::Vector3d r = (R * last).normalized();
      off = std::max(off, std::acos(std::clamp(r.dot(zref), -1.0, 1.0)) * 180 / kPi);
      view = std::max(view, std::acos(std::clamp(last.z(), -1.0, 1.0)) * 180 / kPi);
      max_pitch = std::max(max_pitch, std::abs(std::asin(std::clamp(-r.y(), -1.0, 1.0))) * 180 / kPi);
    }
    // A view that holds the point opposite the reference axis (a back-to-back camera) reaches
    // 180 degrees, inside its outline.
    // (A camera facing away from it, the reference itself, has no direction to that point.)
    const Eigen::Vector3d back = R.transpose() * (-zref);
    Eigen::Vector2d q;
    if (back.z() > -1 + 1e-9 && lens_project(c, back, q) && lens_sees(c, q.x(), q.y())) off = 180;
    out.worst_off_deg = std::max(out.worst_off_deg, off);
    if (off < kPlaneCanvasMaxOffDeg) continue;
    const char* model = c.lens.model == Lens::Model::Fisheye ? "fisheye" : c.lens.model == Lens::Model::Radtan ? "radtan" : "pinhole";
    out.problems.push_back(
        "camera " + std::to_string(i) + " (" + model + ", " + std::to_string(int(std::lround(2 * view))) +
        " degrees across) sees rays " + std::to_string(int(std::lround(off))) +
        " degrees off the reference camera's axis: " +
        (off >= 90 ? std::string("a plane canvas cannot show them (it ends at 90)")
                   : std::string("a plane canvas stretches them ") +
                         std::to_string(int(std::lround(1 / std::pow(std::cos(off * kPi / 180), 2)))) + "x"));
  }
  if (!out.problems.empty()) out.projection = max_pitch >= 60 ? "spherical" : "cylindrical";
  return out;
}

}  // namespace stitch
