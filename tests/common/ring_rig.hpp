// A synthetic ring of cameras around one centre, rendered from a real photo taken as a 360-degree
// panorama (cylindrical or equirectangular): exact ground truth for the projection tests and the
// ring benchmark. Header-only (the GPU-host binaries link no test_data.cpp).
#pragma once
#include <Eigen/Dense>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "stitch/rig/canvas_map.hpp"
#include "stitch/rig/projection_math.hpp"
#include "stitch/rig/rig.hpp"
#include "synthetic_rig.hpp"

namespace testdata {

struct RingScene {
  stitch::Rig truth;            // K and R of every camera (projection set, canvas not laid out)
  std::vector<cv::Mat> frames;  // RGBA, one per camera
};

// Renders every camera of `rig` (K, R) from the photo taken as a 360-degree panorama: its
// columns span 360 degrees, its rows the same scale (pixels per radian) about its middle row, as
// `kind` (cylindrical or spherical) maps them. The photo's left and right edges (a jump in
// content) meet at yaw `seam_deg`.
inline std::vector<cv::Mat> render_from_panorama(const cv::Mat& panorama, const stitch::Rig& rig,
                                                 stitch::Projection kind, double seam_deg = 180.0) {
  std::vector<cv::Mat> frames;
  const double scale = panorama.cols / (2 * CV_PI);
  for (const auto& c : rig.cameras) {
    const Eigen::Matrix3d M = c.R() * c.K().inverse();
    cv::Mat mx(c.height, c.width, CV_32F), my(c.height, c.width, CV_32F);
    for (int y = 0; y < c.height; ++y)
      for (int x = 0; x < c.width; ++x) {
        const Eigen::Vector3d r = M * Eigen::Vector3d(x, y, 1);
        double a = 0, b = 0;
        stitch_projection::ray_to_angles(int(kind), r.x(), r.y(), r.z(), a, b);
        double px = (panorama.cols - 1) * 0.5 + scale * (a - seam_deg * CV_PI / 180 + CV_PI);
        px -= std::floor((px + 0.5) / panorama.cols) * panorama.cols;  // the panorama wraps
        mx.at<float>(y, x) = float(px);
        my.at<float>(y, x) = float((panorama.rows - 1) * 0.5 + scale * b);
      }
    cv::Mat frame;
    // Columns wrap; rows never leave the panorama for the fields of view used here.
    cv::remap(panorama, frame, mx, my, cv::INTER_LINEAR, cv::BORDER_WRAP);
    frames.push_back(frame);
  }
  return frames;
}

// `n` cameras of width x height and focal f, yaws 360/n apart (camera 0 at yaw 0, the
// reference), each with the given pitch, rendered by render_from_panorama.
inline RingScene render_ring(const cv::Mat& panorama, int n, int width, int height, double f, stitch::Projection kind,
                             double pitch_deg = 0.0, double seam_deg = 180.0) {
  RingScene s;
  s.truth.projection = stitch::projection_name(kind);
  s.truth.reference = 0;
  for (int i = 0; i < n; ++i) {
    stitch::Camera c = pinhole(width, height, f);
    c.yaw_deg = 360.0 * i / n;
    if (c.yaw_deg > 180) c.yaw_deg -= 360;
    c.pitch_deg = pitch_deg;
    s.truth.cameras.push_back(c);
  }
  s.frames = render_from_panorama(panorama, s.truth, kind, seam_deg);
  return s;
}

// Worst canvas distance (wrap-aware) between where the estimated rig puts the two images of one
// scene point seen by cameras a and b, over ground-truth correspondences in their overlap
// (every `step` px of camera a); `samples` counts them.
inline double worst_seam_px(const stitch::Rig& est, const stitch::Rig& truth, int a, int b, double step = 10,
                            int* samples = nullptr) {
  const stitch::CameraCanvasMap ma = stitch::camera_canvas_map(est, a), mb = stitch::camera_canvas_map(est, b);
  const stitch::Camera &A = truth.cameras[a], &B = truth.cameras[b];
  double worst = 0;
  int n = 0;
  for (double y = 20; y < A.height - 20; y += 20)
    for (double x = 5; x < A.width - 5; x += step) {
      const Eigen::Vector3d ray = A.R() * (A.K().inverse() * Eigen::Vector3d(x, y, 1));
      const Eigen::Vector3d pb = B.K() * (B.R().transpose() * ray);
      if (pb.z() <= 0) continue;
      const Eigen::Vector2d qb = pb.head<2>() / pb.z();
      if (qb.x() < 5 || qb.y() < 5 || qb.x() > B.width - 6 || qb.y() > B.height - 6) continue;
      Eigen::Vector2d ca, cb;
      if (!ma.to_canvas({x, y}, ca) || !mb.to_canvas(qb, cb)) continue;
      double dx = ca.x() - cb.x();
      if (est.canvas_wrap) dx -= std::round(dx / est.canvas_width) * est.canvas_width;
      worst = std::max(worst, std::hypot(dx, ca.y() - cb.y()));
      ++n;
    }
  if (samples) *samples = n;
  return worst;
}

}  // namespace testdata
