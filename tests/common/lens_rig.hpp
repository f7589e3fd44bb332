// Cameras with lenses rendered from a photo taken as an equirectangular 360-degree panorama
// (issue 15): exact ground truth for the lens tests, the CUDA comparison and
// stitch-render-rig --equirect. Header-only (the GPU-host binaries link no test_data.cpp).
#pragma once
#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <string>
#include <opencv2/imgproc.hpp>

#include "stitch/blend/compositor.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/lens.hpp"
#include "stitch/rig/projection_math.hpp"
#include "stitch/rig/rig.hpp"

namespace testdata {

// Equirectangular pixel (px, py) of rig ray angles (a = longitude, b = latitude, +b down):
// longitude 0 at the middle column, latitude 0 at the middle row.
inline void equirect_pixel(const cv::Mat& pano, double a, double b, float& px, float& py) {
  const double scale = pano.cols / (2 * CV_PI);
  double x = pano.cols * 0.5 - 0.5 + scale * a;
  x -= std::floor((x + 0.5) / pano.cols) * pano.cols;
  px = float(x);
  py = float(pano.rows * 0.5 - 0.5 + scale * b);
}

// The frame camera `c` (K, R, lens) sees of the panorama; black outside its image circle and
// where the lens sees nothing. `supersample` > 1 renders bigger and area-averages (anti-aliasing).
inline cv::Mat render_camera_from_equirect(const cv::Mat& pano, const stitch::Camera& c, int supersample = 2) {
  const int s = std::max(1, supersample);
  cv::Mat mx(c.height * s, c.width * s, CV_32F), my(c.height * s, c.width * s, CV_32F);
  const Eigen::Matrix3d R = c.R();
  for (int y = 0; y < mx.rows; ++y)
    for (int x = 0; x < mx.cols; ++x) {
      const double u = (x + 0.5) / s - 0.5, v = (y + 0.5) / s - 0.5;
      Eigen::Vector3d ray;
      if (!stitch::lens_sees(c, u, v) || !stitch::lens_unproject(c, {u, v}, ray)) {
        mx.at<float>(y, x) = my.at<float>(y, x) = -1e6f;
        continue;
      }
      const Eigen::Vector3d r = R * ray;
      double a, b;
      stitch_projection::ray_to_angles(stitch_projection::kSpherical, r.x(), r.y(), r.z(), a, b);
      equirect_pixel(pano, a, b, mx.at<float>(y, x), my.at<float>(y, x));
    }
  cv::Mat big, out;
  cv::remap(pano, big, mx, my, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  if (s == 1) return big;
  cv::resize(big, out, cv::Size(c.width, c.height), 0, 0, cv::INTER_AREA);
  return out;
}

// The ground truth of a spherical canvas of `rig` (laid out): each canvas pixel's angles looked
// up in the panorama.
inline cv::Mat equirect_ground_truth(const cv::Mat& pano, const stitch::Rig& rig) {
  cv::Mat mx(rig.canvas_height, rig.canvas_width, CV_32F), my(rig.canvas_height, rig.canvas_width, CV_32F);
  for (int y = 0; y < mx.rows; ++y)
    for (int x = 0; x < mx.cols; ++x)
      equirect_pixel(pano, (x - rig.canvas_origin_x) / rig.canvas_scale, (y - rig.canvas_origin_y) / rig.canvas_scale,
                     mx.at<float>(y, x), my.at<float>(y, x));
  cv::Mat out;
  cv::remap(pano, out, mx, my, cv::INTER_LINEAR, cv::BORDER_WRAP);
  return out;
}

// The ground truth of a cubemap canvas (laid out, issue 15): each canvas pixel's ray looked up in
// the panorama; black off the cube's layout.
inline cv::Mat cubemap_ground_truth(const cv::Mat& pano, const stitch::Rig& rig) {
  cv::Mat mx(rig.canvas_height, rig.canvas_width, CV_32F), my(rig.canvas_height, rig.canvas_width, CV_32F);
  for (int y = 0; y < mx.rows; ++y)
    for (int x = 0; x < mx.cols; ++x) {
      double rx, ry, rz, a, b;
      stitch_projection::angles_to_ray(stitch_projection::kCubemap, (x - rig.canvas_origin_x) / rig.canvas_scale,
                                       (y - rig.canvas_origin_y) / rig.canvas_scale, rx, ry, rz);
      if (!stitch_projection::ray_to_angles(stitch_projection::kSpherical, rx, ry, rz, a, b)) {
        mx.at<float>(y, x) = my.at<float>(y, x) = -1e6f;
        continue;
      }
      equirect_pixel(pano, a, b, mx.at<float>(y, x), my.at<float>(y, x));
    }
  cv::Mat out;
  cv::remap(pano, out, mx, my, cv::INTER_LINEAR, cv::BORDER_WRAP);
  return out;
}

// A laid-out copy of `rig` on another canvas projection (its own scale unless `scale` > 0).
inline stitch::Rig reprojected(stitch::Rig rig, const std::string& projection, double scale = 0) {
  rig.projection = projection;
  rig.canvas_scale = scale;
  rig.canvas_width = rig.canvas_height = 0;
  rig.canvas_wrap = false;
  stitch::rig_layout_canvas(rig);
  return rig;
}

// The ground truth of a plane canvas (laid out): canvas pixel -> reference ideal pixel -> ray -> the panorama.
inline cv::Mat plane_ground_truth(const cv::Mat& pano, const stitch::Rig& rig) {
  const stitch::Camera& ref = rig.cameras[rig.reference];
  const Eigen::Matrix3d M = ref.R() * ref.K().inverse() * ref.homography->inverse();
  cv::Mat mx(rig.canvas_height, rig.canvas_width, CV_32F), my = mx.clone();
  for (int y = 0; y < mx.rows; ++y)
    for (int x = 0; x < mx.cols; ++x) {
      const Eigen::Vector3d r = M * Eigen::Vector3d(x, y, 1);
      double a, b;
      stitch_projection::ray_to_angles(stitch_projection::kSpherical, r.x(), r.y(), r.z(), a, b);
      equirect_pixel(pano, a, b, mx.at<float>(y, x), my.at<float>(y, x));
    }
  cv::Mat gt;
  cv::remap(pano, gt, mx, my, cv::INTER_LINEAR, cv::BORDER_WRAP);
  return gt;
}

// A fisheye camera (equidistant-ish Kannala-Brandt) of side `size` seeing `fov_deg` across its
// inscribed image circle.
inline stitch::Camera fisheye_camera(int size, double fov_deg, double k1 = 0.0, double k2 = 0.0) {
  stitch::Camera c;
  c.width = c.height = size;
  c.cx = c.cy = (size - 1) * 0.5;
  const double radius = size * 0.5 - 1;
  const double theta = 0.5 * fov_deg * CV_PI / 180.0, t2 = theta * theta;
  c.fx = c.fy = radius / (theta * (1 + t2 * (k1 + t2 * k2)));  // the rim at theta
  c.lens.model = stitch::Lens::Model::Fisheye;
  c.lens.k1 = k1;
  c.lens.k2 = k2;
  c.lens.circle = stitch::LensCircle{c.cx, c.cy, radius};
  return c;
}

// Back-to-back dual fisheye (yaw 0 and 180) on a spherical canvas of scale `scale`, laid out.
inline stitch::Rig dual_fisheye_rig(int size, double fov_deg, double scale = 0, double k1 = 0.0, double k2 = 0.0) {
  stitch::Rig rig;
  rig.projection = "spherical";
  for (int i = 0; i < 2; ++i) {
    stitch::Camera c = fisheye_camera(size, fov_deg, k1, k2);
    c.yaw_deg = i == 0 ? 0.0 : 180.0;
    rig.cameras.push_back(c);
  }
  rig.reference = 0;
  rig.canvas_scale = scale;
  stitch::rig_layout_canvas(rig);
  return rig;
}

// n fisheye cameras around the horizon, yaws 360/n apart, laid out on a spherical canvas.
inline stitch::Rig fisheye_ring(int n, int size, double fov_deg, double scale = 0) {
  stitch::Rig rig;
  rig.projection = "spherical";
  for (int i = 0; i < n; ++i) {
    stitch::Camera c = fisheye_camera(size, fov_deg, -0.02, 0.001);
    c.yaw_deg = 360.0 * i / n;
    if (c.yaw_deg > 180) c.yaw_deg -= 360;
    c.pitch_deg = i % 2 ? 10.0 : -10.0;
    rig.cameras.push_back(c);
  }
  rig.reference = 0;
  rig.canvas_scale = scale;
  stitch::rig_layout_canvas(rig);
  return rig;
}

// The rig's panorama composed from `frames` (RGBA) with default settings on the CPU.
inline cv::Mat compose_cpu(const stitch::Rig& rig, std::vector<cv::Mat>& frames) {
  stitch::Compositor comp(stitch::Backend::Cpu);
  comp.prepare(rig, stitch::CompositorSettings{});
  cv::Mat pano(comp.geometry().height, comp.geometry().width, CV_8UC4);
  std::vector<stitch::ImageView> views;
  for (auto& f : frames) views.push_back(stitch::as_view(f));
  comp.compose(views, stitch::as_view(pano));
  return pano;
}

// Three cameras `spacing` degrees apart (the middle one the reference, the third pitched by
// `pitch2_deg`), with a radtan lens (k1, k2) unless both are 0 and `lens` is false.
inline stitch::Rig radtan_trio(int w, int h, double f, double spacing, double k1, double k2, bool lens,
                               const std::string& projection, double pitch2_deg = 2.0) {
  stitch::Rig rig;
  rig.projection = projection;
  for (int i = 0; i < 3; ++i) {
    stitch::Camera c;
    c.width = w, c.height = h;
    c.fx = c.fy = f;
    c.cx = 0.5 * (w - 1), c.cy = 0.5 * (h - 1);
    c.yaw_deg = spacing * (i - 1);
    c.pitch_deg = i == 2 ? pitch2_deg : 0.0;
    if (lens) {
      c.lens.model = stitch::Lens::Model::Radtan;
      c.lens.k1 = k1;
      c.lens.k2 = k2;
    }
    rig.cameras.push_back(c);
  }
  rig.reference = 1;
  return rig;
}

// A rough rig of a radtan trio (radtan_trio): focal +-5 %, yaw +-3 degrees (signs and sizes from
// the seed), pitch dropped, no canvas; lenses unchanged (see without_coefficients).
inline stitch::Rig rough_trio(const stitch::Rig& truth, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.6, 1.0);
  stitch::Rig r = truth;
  r.canvas_width = r.canvas_height = 0, r.canvas_scale = 0, r.canvas_wrap = false;
  for (std::size_t i = 0; i < r.cameras.size(); ++i) {
    stitch::Camera& c = r.cameras[i];
    const double s = 1 + (i % 2 ? 1 : -1) * 0.05 * u(rng) * (seed % 2 ? -1 : 1);
    c.fx *= s, c.fy *= s;
    c.yaw_deg += (i % 2 ? -3.0 : 3.0) * u(rng);
    c.pitch_deg = 0;
  }
  return r;
}

// A rough rig of a fisheye rig (dual_fisheye_rig, fisheye_ring): focal +-3 %, yaw / pitch / roll
// +-2 degrees off (seeded), no canvas; lenses unchanged.
inline stitch::Rig rough_sphere(const stitch::Rig& truth, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> df(-0.03, 0.03), da(-2.0, 2.0);
  stitch::Rig r = truth;
  r.canvas_width = r.canvas_height = 0, r.canvas_scale = 0, r.canvas_wrap = false;
  for (auto& c : r.cameras) {
    c.fx = c.fy = c.fx * (1 + df(rng));
    c.yaw_deg += da(rng), c.pitch_deg += da(rng), c.roll_deg += da(rng);
  }
  return r;
}

// The lens models without coefficients ("estimate them"); the image circle kept (it is measured,
// not estimated).
inline stitch::Rig without_coefficients(stitch::Rig r) {
  for (auto& c : r.cameras)
    if (!c.lens.pinhole()) {
      stitch::Lens l;
      l.model = c.lens.model;
      l.circle = c.lens.circle;
      l.estimate = true;
      c.lens = l;
    }
  return r;
}

// Where a calibration puts each non-reference camera's image corners, in that camera's raw
// pixels under the truth: corner -> ray (estimated lens, K, R, relative to the reference) ->
// the true camera. The worst corner over the cameras (1e9 when a corner maps nowhere).
inline double lens_corner_error(const stitch::Rig& est, const stitch::Rig& truth) {
  double worst = 0;
  const int ref = truth.reference;
  const Eigen::Matrix3d Re = est.cameras[est.reference].R().transpose(), Rt = truth.cameras[ref].R().transpose();
  for (std::size_t i = 0; i < truth.cameras.size(); ++i) {
    if (int(i) == ref) continue;
    const stitch::Camera &E = est.cameras[i], &T = truth.cameras[i];
    for (const Eigen::Vector2d& p : {Eigen::Vector2d(0, 0), Eigen::Vector2d(T.width - 1, 0),
                                     Eigen::Vector2d(T.width - 1, T.height - 1), Eigen::Vector2d(0, T.height - 1)}) {
      Eigen::Vector3d ray;
      Eigen::Vector2d q;
      if (!stitch::lens_unproject(E, p, ray)) return 1e9;
      const Eigen::Vector3d d = Re * E.R() * ray;  // reference-camera frame
      if (!stitch::lens_project(T, T.R().transpose() * (Rt.transpose() * d), q)) return 1e9;
      worst = std::max(worst, (q - p).norm());
    }
  }
  return worst;
}

// `clean` frames (RGBA) with Gaussian sensor noise of `sigma` grey levels, seeded by `frame`, so
// that successive frames of a static rig differ; opaque. `keep_black`: pixels black in the clean
// frame (outside an image circle, say) stay black.
inline std::vector<cv::Mat> with_sensor_noise(const std::vector<cv::Mat>& clean, int frame, double sigma,
                                              bool keep_black) {
  std::vector<cv::Mat> out;
  cv::RNG rng(std::uint64_t(1000 + frame));
  for (const auto& m : clean) {
    cv::Mat n(m.size(), CV_16SC4), f;
    rng.fill(n, cv::RNG::NORMAL, 0, sigma);
    m.convertTo(f, CV_16SC4);
    f += n;
    f.convertTo(f, CV_8UC4);
    if (keep_black) f.setTo(cv::Scalar(0, 0, 0, 255), m == 0);
    std::vector<cv::Mat> ch;
    cv::split(f, ch);
    ch[3].setTo(255);
    cv::merge(ch, f);
    out.push_back(f);
  }
  return out;
}

}  // namespace testdata
