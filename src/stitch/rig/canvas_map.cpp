#include "stitch/rig/canvas_map.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "stitch/rig/lens.hpp"
#include "stitch/rig/projection_math.hpp"

namespace stitch {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kMaxSide = 32768;
constexpr int kOutlineSteps = 16;  // border samples per image edge

// The canvas map of a non-planar camera with the given canvas scale and origin.
CameraCanvasMap projected_map(const Rig& rig, const Camera& c, double scale, double ox, double oy) {
  CameraCanvasMap m;
  m.kind = rig.projection_kind();
  m.KRt = c.K() * c.R().transpose();
  m.RKinv = c.R() * c.K().inverse();
  m.scale = scale;
  m.origin_x = ox;
  m.origin_y = oy;
  m.period = 2 * kPi * scale;
  m.camera = c;
  m.lens = stitch_projection::has_lens(lens_params(c));
  return m;
}

// The image border, clockwise from the top-left corner, kOutlineSteps samples per edge. With an
// image circle: its rim, clipped to the frame.
std::vector<Eigen::Vector2d> border_samples(const Camera& c) {
  const double w = c.width - 1, h = c.height - 1;
  std::vector<Eigen::Vector2d> pts;
  if (c.lens.circle) {
    const LensCircle& k = *c.lens.circle;
    const double r = k.radius - 1;  // just inside the rim
    for (int s = 0; s < 4 * kOutlineSteps; ++s) {
      const double a = 2 * kPi * s / (4 * kOutlineSteps);
      pts.emplace_back(std::clamp(k.cx + r * std::sin(-a + kPi), 0.0, w), std::clamp(k.cy + r * std::cos(-a + kPi), 0.0, h));
    }
    return pts;
  }
  for (int k = 0; k < kOutlineSteps; ++k) pts.emplace_back(w * k / kOutlineSteps, 0);
  for (int k = 0; k < kOutlineSteps; ++k) pts.emplace_back(w, h * k / kOutlineSteps);
  for (int k = 0; k < kOutlineSteps; ++k) pts.emplace_back(w - w * k / kOutlineSteps, h);
  for (int k = 0; k < kOutlineSteps; ++k) pts.emplace_back(0, h - h * k / kOutlineSteps);
  return pts;
}

// True when the rig direction `ray` lands inside the camera's image.
bool sees(const Camera& c, const Eigen::Vector3d& ray) {
  if (stitch_projection::has_lens(lens_params(c))) {
    Eigen::Vector2d q;
    return lens_project(c, c.R().transpose() * ray, q) && lens_sees(c, q.x(), q.y());
  }
  const Eigen::Vector3d p = c.K() * (c.R().transpose() * ray);
  if (!(p.z() > 1e-9)) return false;
  const double u = p.x() / p.z(), v = p.y() / p.z();
  return u >= -0.5 && v >= -0.5 && u <= c.width - 0.5 && v <= c.height - 0.5;
}

std::vector<Eigen::Vector2d> projected_outline(const Rig& rig, int cam, const CameraCanvasMap& m) {
  const Camera& c = rig.cameras.at(static_cast<std::size_t>(cam));
  Eigen::Vector2d centre;
  if (!m.to_canvas({c.cx, c.cy}, centre))
    throw RigError("camera " + std::to_string(cam) + " looks along the cylinder's axis");
  centre.x() -= std::floor((centre.x() + 0.5) / m.period) * m.period;  // the centre's turn of the canvas
  const bool north = sees(c, {0, -1, 0}), south = sees(c, {0, 1, 0});
  if ((north || south) && m.kind == Projection::Cylindrical)
    throw RigError("camera " + std::to_string(cam) +
                   " sees a pole, which a cylindrical canvas cannot hold: use projection=spherical");
  std::vector<Eigen::Vector2d> out;
  double ymin = 1e300, ymax = -1e300;
  for (const auto& p : border_samples(c)) {
    Eigen::Vector2d q;
    if (!m.to_canvas(p, q)) continue;
    q.x() += std::round((centre.x() - q.x()) / m.period) * m.period;  // continuous around the centre
    ymin = std::min(ymin, q.y());
    ymax = std::max(ymax, q.y());
    out.push_back(q);
  }
  if (north && south) {
    // Both poles (a fisheye wider than 180 degrees): every longitude, pole to pole.
    const double x0 = centre.x() - 0.5 * m.period, x1 = centre.x() + 0.5 * m.period;
    const double y0 = m.origin_y - 0.5 * kPi * m.scale, y1 = m.origin_y + 0.5 * kPi * m.scale;
    out = {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
  } else if (north || south) {
    // The view holds a pole: on the canvas it covers a full band from that pole.
    const double pole_y = m.origin_y + (north ? -0.5 : 0.5) * kPi * m.scale;
    const double far_y = north ? ymax : ymin;
    const double x0 = centre.x() - 0.5 * m.period, x1 = centre.x() + 0.5 * m.period;
    out = {{x0, std::min(pole_y, far_y)}, {x1, std::min(pole_y, far_y)}, {x1, std::max(pole_y, far_y)},
           {x0, std::max(pole_y, far_y)}};
  }
  return out;
}

// q = H p when p maps in front (positive homogeneous z).
bool apply_in_front(const Eigen::Matrix3d& H, const Eigen::Vector2d& p, Eigen::Vector2d& q) {
  const Eigen::Vector3d h = H * Eigen::Vector3d(p.x(), p.y(), 1.0);
  if (!(h.z() > 1e-9)) return false;
  q = h.head<2>() / h.z();
  return true;
}

}  // namespace

bool CameraCanvasMap::to_canvas(const Eigen::Vector2d& pixel, Eigen::Vector2d& canvas) const {
  if (lens) {
    Eigen::Vector3d ray;
    if (!lens_unproject(camera, pixel, ray)) return false;
    if (kind == Projection::Plane) {
      if (!(ray.z() > 1e-9)) return false;
      const Eigen::Vector3d ideal = camera.K() * (ray / ray.z());
      return apply_in_front(H, ideal.head<2>(), canvas);
    }
    const Eigen::Vector3d r = camera.R() * ray;
    double a, b;
    if (!stitch_projection::ray_to_angles(static_cast<int>(kind), r.x(), r.y(), r.z(), a, b)) return false;
    canvas = {origin_x + scale * a, origin_y + scale * b};
    return true;
  }
  if (kind == Projection::Plane) return apply_in_front(H, pixel, canvas);
  const Eigen::Vector3d r = RKinv * Eigen::Vector3d(pixel.x(), pixel.y(), 1.0);
  double a, b;
  if (!stitch_projection::ray_to_angles(static_cast<int>(kind), r.x(), r.y(), r.z(), a, b)) return false;
  canvas = {origin_x + scale * a, origin_y + scale * b};
  return true;
}

bool CameraCanvasMap::to_camera(const Eigen::Vector2d& canvas, Eigen::Vector2d& pixel) const {
  if (lens) {
    if (kind == Projection::Plane) {
      const Eigen::Vector3d h = H_inv * Eigen::Vector3d(canvas.x(), canvas.y(), 1.0);
      if (!(h.z() > 1e-12)) return false;
      return lens_project(camera, camera.K().inverse() * h, pixel);
    }
    Eigen::Vector3d ray;
    stitch_projection::angles_to_ray(static_cast<int>(kind), (canvas.x() - origin_x) / scale, (canvas.y() - origin_y) / scale,
                                     ray.x(), ray.y(), ray.z());
    if (ray.isZero()) return false;  // off a cubemap's layout
    return lens_project(camera, camera.R().transpose() * ray, pixel);
  }
  if (kind == Projection::Plane) return apply_in_front(H_inv, canvas, pixel);
  const double angle[4] = {1 / scale, -origin_x / scale, 1 / scale, -origin_y / scale};
  const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> M = KRt;
  return stitch_projection::canvas_to_camera(static_cast<int>(kind), angle, M.data(), canvas.x(), canvas.y(),
                                             pixel.x(), pixel.y());
}

CameraCanvasMap camera_canvas_map(const Rig& rig, int cam) {
  const Camera& c = rig.cameras.at(static_cast<std::size_t>(cam));
  if (!rig.planar()) return projected_map(rig, c, rig.canvas_scale, rig.canvas_origin_x, rig.canvas_origin_y);
  if (!c.homography) throw RigError("camera " + std::to_string(cam) + " has no homography");
  CameraCanvasMap m;
  m.H = *c.homography;
  m.H_inv = m.H.inverse();
  m.camera = c;
  m.lens = stitch_projection::has_lens(lens_params(c));
  return m;
}

CubeCoverage cube_coverage(const Rig& rig, int cam, int cells_per_face) {
  const Camera& c = rig.cameras.at(static_cast<std::size_t>(cam));
  CubeCoverage g;
  g.cols = 3 * cells_per_face;
  g.rows = 2 * cells_per_face;
  g.cell = 2 * rig.canvas_scale / cells_per_face;
  g.x0 = rig.canvas_origin_x;
  g.y0 = rig.canvas_origin_y;
  g.seen.assign(std::size_t(g.cols) * g.rows, 0);
  for (int j = 0; j < g.rows; ++j)
    for (int i = 0; i < g.cols; ++i) {
      Eigen::Vector3d ray;
      stitch_projection::cube_angles_to_ray(2.0 * (i + 0.5) / cells_per_face, 2.0 * (j + 0.5) / cells_per_face, ray.x(),
                                            ray.y(), ray.z());
      g.seen[std::size_t(j) * g.cols + i] = sees(c, ray) ? 1 : 0;
    }
  return g;
}

std::vector<Eigen::Vector2d> cube_cells_box(const CubeCoverage& g, const std::vector<uint8_t>& seen) {
  int i0 = g.cols, i1 = -1, j0 = g.rows, j1 = -1;
  for (int j = 0; j < g.rows; ++j)
    for (int i = 0; i < g.cols; ++i)
      if (seen[std::size_t(j) * g.cols + i]) {
        i0 = std::min(i0, i), i1 = std::max(i1, i);
        j0 = std::min(j0, j), j1 = std::max(j1, j);
      }
  if (i1 < 0) return {};
  // Cell i spans [x0 + i cell, x0 + (i + 1) cell); pixel centres lie half a pixel inside the layout.
  const double x_lo = g.x0 + 0.5, y_lo = g.y0 + 0.5, x_hi = g.x0 + g.cols * g.cell - 0.5, y_hi = g.y0 + g.rows * g.cell - 0.5;
  const double xa = std::max(x_lo, g.x0 + (i0 - 1) * g.cell), xb = std::min(x_hi, g.x0 + (i1 + 2) * g.cell);
  const double ya = std::max(y_lo, g.y0 + (j0 - 1) * g.cell), yb = std::min(y_hi, g.y0 + (j1 + 2) * g.cell);
  return {{xa, ya}, {xb, ya}, {xb, yb}, {xa, yb}};
}

std::vector<Eigen::Vector2d> camera_canvas_outline(const Rig& rig, int cam) {
  if (rig.cameras.at(static_cast<std::size_t>(cam)).left_out) return {};
  if (rig.projection_kind() == Projection::Cubemap) {
    const CubeCoverage g = cube_coverage(rig, cam);
    return cube_cells_box(g, g.seen);
  }
  if (rig.planar() && stitch_projection::has_lens(lens_params(rig.cameras.at(static_cast<std::size_t>(cam))))) {
    // The border, undistorted: curved on the canvas. A plane holds no ray at 90 degrees or more,
    // so rays are pulled in to kPlaneMaxTheta from the camera's axis.
    constexpr double kPlaneMaxTheta = 75.0 * kPi / 180.0;
    const Camera& c = rig.cameras[static_cast<std::size_t>(cam)];
    const Eigen::Matrix3d HK = *c.homography * c.K();
    std::vector<Eigen::Vector2d> out;
    bool lost = false;
    auto add = [&](const Eigen::Vector2d& p) {
      Eigen::Vector3d ray;
      if (!lens_unproject(c, p, ray)) return;
      const double theta = std::atan2(ray.head<2>().norm(), ray.z());
      if (theta > kPlaneMaxTheta) {
        const Eigen::Vector2d dir = ray.head<2>().normalized();
        ray = {dir.x() * std::sin(kPlaneMaxTheta), dir.y() * std::sin(kPlaneMaxTheta), std::cos(kPlaneMaxTheta)};
      }
      Eigen::Vector2d q;
      if (apply_in_front(HK, (ray.head<2>() / ray.z()).eval(), q)) out.push_back(q);
      else lost = true;
    };
    for (const auto& p : border_samples(c)) add(p);
    if (lost) {
      // Part of the view lies past the plane's horizon (a fisheye over the ground): its border
      // no longer bounds what lands on the canvas. The convex hull of a grid over the image does.
      for (int j = 1; j < kOutlineSteps; ++j)
        for (int i = 1; i < kOutlineSteps; ++i)
          add({(c.width - 1.0) * i / kOutlineSteps, (c.height - 1.0) * j / kOutlineSteps});
      std::vector<cv::Point2f> pts, hull;
      for (const auto& q : out) pts.emplace_back(float(q.x()), float(q.y()));
      if (pts.size() >= 3) cv::convexHull(pts, hull);
      out.clear();
      for (const auto& h : hull) out.emplace_back(h.x, h.y);
    }
    return out;
  }
  if (rig.planar()) {
    const auto q = camera_canvas_corners(rig.cameras.at(static_cast<std::size_t>(cam)));
    return {q.begin(), q.end()};
  }
  return projected_outline(rig, cam, camera_canvas_map(rig, cam));
}

void layout_projected_canvas(Rig& rig) {
  const int n = static_cast<int>(rig.cameras.size());
  if (rig.reference < 0 || rig.reference >= n) throw RigError("reference camera index out of range");
  double scale = rig.canvas_scale;
  if (!(scale > 0)) {
    std::vector<double> f;
    for (const auto& c : rig.cameras) f.push_back(0.5 * (c.fx + c.fy));
    std::nth_element(f.begin(), f.begin() + n / 2, f.end());
    scale = f[n / 2];
  }
  if (rig.projection_kind() == Projection::Cubemap) {
    // The whole cube, always (a cubemap is only one whole): faces of an even side 2 scale (so
    // that both canvas sides are even), the layout's top-left pixel edge at the canvas's.
    const int face = 2 * std::max(1, int(std::lround(scale)));
    if (3 * face > kMaxSide) throw RigError("degenerate geometry: the cubemap faces would be " + std::to_string(face) + " pixels");
    rig.canvas_scale = 0.5 * face;
    rig.canvas_origin_x = rig.canvas_origin_y = -0.5;
    rig.canvas_wrap = false;
    rig.canvas_width = 3 * face;
    rig.canvas_height = 2 * face;
    return;
  }
  // Outlines with the origin at angles (0, 0), each unwrapped next to the reference view.
  const CameraCanvasMap ref_map = projected_map(rig, rig.cameras[rig.reference], scale, 0, 0);
  Eigen::Vector2d ref_centre;
  if (!ref_map.to_canvas({rig.cameras[rig.reference].cx, rig.cameras[rig.reference].cy}, ref_centre))
    throw RigError("the reference camera looks along the cylinder's axis");
  const double period = 2 * kPi * scale;
  constexpr int kBins = 720;  // horizontal coverage, half a degree a bin
  std::vector<bool> covered(kBins, false);
  double minx = 1e300, maxx = -1e300, miny = 1e300, maxy = -1e300, input_area = 0;
  std::vector<double> centres;  // camera centres' canvas x
  for (int i = 0; i < n; ++i) {
    Eigen::Vector2d centre;
    const CameraCanvasMap map = projected_map(rig, rig.cameras[i], scale, 0, 0);
    centres.push_back(map.to_canvas({rig.cameras[i].cx, rig.cameras[i].cy}, centre) ? centre.x() : 0.0);
    std::vector<Eigen::Vector2d> q = projected_outline(rig, i, map);
    if (q.empty()) throw RigError("camera " + std::to_string(i) + " does not project onto the canvas");
    double x0 = 1e300, x1 = -1e300;
    for (const auto& p : q) {
      x0 = std::min(x0, p.x());
      x1 = std::max(x1, p.x());
      miny = std::min(miny, p.y());
      maxy = std::max(maxy, p.y());
    }
    const double shift = std::round((ref_centre.x() - 0.5 * (x0 + x1)) / period) * period;
    minx = std::min(minx, x0 + shift);
    maxx = std::max(maxx, x1 + shift);
    const int b0 = int(std::floor(x0 / period * kBins)), b1 = int(std::ceil(x1 / period * kBins));
    for (int b = b0; b < b1 && b < b0 + kBins; ++b) covered[((b % kBins) + kBins) % kBins] = true;
    input_area += double(rig.cameras[i].width) * rig.cameras[i].height;
  }
  const bool wrap = std::all_of(covered.begin(), covered.end(), [](bool v) { return v; });
  // Lenses (issue 15): a spherical canvas covered all round and pole to pole is the full sphere,
  // kept exactly 2:1 (equirectangular: row y at latitude ((y + 0.5) / height - 0.5) pi).
  const bool full_sphere = wrap && rig.projection_kind() == Projection::Spherical &&
                           miny <= -0.5 * kPi * scale + 1.0 && maxy >= 0.5 * kPi * scale - 1.0;
  double cw;
  if (wrap) {
    // An even width that is exactly 360 degrees. The wrap runs through the centre of the camera
    // most opposite the reference: that view alone crosses it, and no overlap is cut in two.
    // The full sphere's width is a multiple of 4, so that its 2:1 height is even too (panoramas
    // have even sizes: an odd height was padded to 1094x548, no longer 2:1 for 360 players).
    cw = full_sphere ? 4 * std::round(0.25 * period) : 2 * std::round(0.5 * period);
    const double ratio = cw / period;
    scale *= ratio;
    miny *= ratio;
    maxy *= ratio;
    const double opposite = ref_centre.x() + 0.5 * period;
    double wrap_x = centres[0];
    for (double c : centres)
      if (std::abs(std::remainder(c - opposite, period)) < std::abs(std::remainder(wrap_x - opposite, period)))
        wrap_x = c;
    rig.canvas_origin_x = -0.5 - wrap_x * ratio;
    rig.canvas_origin_x -= std::floor((rig.canvas_origin_x + ref_centre.x() * ratio) / cw) * cw;
  } else {
    cw = std::ceil(maxx - std::floor(minx)) + 1;
    rig.canvas_origin_x = -std::floor(minx);
  }
  double ch = std::ceil(maxy - std::floor(miny)) + 1;
  if (full_sphere) {
    ch = cw / 2;
    miny = -0.5 * (ch - 1);  // origin_y = ch / 2 - 0.5 below
  }
  if (cw > kMaxSide || ch > kMaxSide || cw * ch > 16.0 * input_area)
    throw RigError("degenerate geometry: the " + rig.projection + " canvas would be " + std::to_string(int(cw)) +
                   "x" + std::to_string(int(ch)) + " pixels (views close to the cylinder's axis?)");
  rig.canvas_origin_y = full_sphere ? 0.5 * ch - 0.5 : -std::floor(miny);
  rig.canvas_scale = scale;
  rig.canvas_wrap = wrap;
  rig.canvas_width = static_cast<int>(cw);
  rig.canvas_height = static_cast<int>(ch);
}

}  // namespace stitch
