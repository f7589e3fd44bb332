#include "stitch/warp/geometry.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <opencv2/imgproc.hpp>

#include "stitch/blend/blender.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "stitch/rig/lens.hpp"

namespace stitch {

namespace {
int even_at_least_2(double v) { return std::max(2, 2 * static_cast<int>(std::ceil(v / 2.0 - 1e-9))); }
}  // namespace

float view_position_weight(const ViewPlacement& v, double u, double w) {
  if (v.has_lens()) return float(stitch_projection::lens_position_weight(v.lens, u, w, v.camera_width, v.camera_height));
  return position_weight(u, w, v.camera_width, v.camera_height);
}

Rect largest_covered_rect(const Rig& rig) {
  // A cubemap is only one whole (its faces' layout fixed): never cropped.
  if (rig.projection_kind() == Projection::Cubemap) return {0, 0, rig.canvas_width, rig.canvas_height};
  // Rasterise the coverage at a reduced scale, then the classic max-rectangle-in-histogram.
  const double scale = std::min(1.0, 1024.0 / std::max(rig.canvas_width, rig.canvas_height));
  const int w = std::max(1, int(rig.canvas_width * scale)), h = std::max(1, int(rig.canvas_height * scale));
  cv::Mat cover(h, w, CV_8U, cv::Scalar(0));
  for (int i = 0; i < int(rig.cameras.size()); ++i) {
    const std::vector<Eigen::Vector2d> outline = camera_canvas_outline(rig, i);
    if (outline.empty()) continue;  // left out
    // A wrapping canvas also gets the copies of the outline one period to either side.
    for (int k = rig.canvas_wrap ? -1 : 0; k <= (rig.canvas_wrap ? 1 : 0); ++k) {
      std::vector<cv::Point> poly;
      for (const auto& q : outline)
        poly.emplace_back(int(std::lround((q.x() + k * rig.canvas_width) * scale)), int(std::lround(q.y() * scale)));
      if (rig.planar() && rig.cameras[i].lens.pinhole() && !rig.cameras[i].lens.circle)
        cv::fillConvexPoly(cover, poly, cv::Scalar(1));
      else cv::fillPoly(cover, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(1));
    }
  }
  // Shrink by one pixel so that rounding never lets an uncovered border in.
  cv::erode(cover, cover, cv::Mat::ones(3, 3, CV_8U));
  std::vector<int> heights(w, 0), stack;
  long best = 0;
  Rect best_rect;
  for (int y = 0; y < h; ++y) {
    const uint8_t* row = cover.ptr<uint8_t>(y);
    for (int x = 0; x < w; ++x) heights[x] = row[x] ? heights[x] + 1 : 0;
    stack.clear();
    for (int x = 0; x <= w; ++x) {
      const int hx = x < w ? heights[x] : 0;
      while (!stack.empty() && heights[stack.back()] >= hx) {
        const int top = heights[stack.back()];
        stack.pop_back();
        const int left = stack.empty() ? 0 : stack.back() + 1;
        const long area = long(top) * (x - left);
        if (area > best) {
          best = area;
          best_rect = {left, y - top + 1, x - left, top};
        }
      }
      stack.push_back(x);
    }
  }
  if (best == 0) return {0, 0, rig.canvas_width, rig.canvas_height};
  Rect r;
  r.x = int(std::ceil(best_rect.x / scale));
  r.y = int(std::ceil(best_rect.y / scale));
  r.width = std::min(rig.canvas_width - r.x, int(std::floor(best_rect.width / scale)));
  r.height = std::min(rig.canvas_height - r.y, int(std::floor(best_rect.height / scale)));
  if (rig.canvas_wrap && best_rect.width == w) {
    // Covered all round: keep exactly 360 degrees, so that the panorama still wraps.
    r.x = 0;
    r.width = rig.canvas_width;
  }
  return r;
}

OutputGeometry plan_output(const Rig& rig, int requested_w, int requested_h, CropMode crop, bool exact_size) {
  Rect src{0, 0, rig.canvas_width, rig.canvas_height};
  if (crop == CropMode::Auto) src = largest_covered_rect(rig);
  double sw = src.width, sh = src.height;
  double ow = sw, oh = sh;
  if (requested_w > 0 && requested_h > 0) {
    ow = requested_w;
    oh = requested_h;
  } else if (requested_w > 0) {
    ow = requested_w;
    oh = sh * requested_w / sw;
  } else if (requested_h > 0) {
    oh = requested_h;
    ow = sw * requested_h / sh;
  }
  OutputGeometry g;
  const bool exact = exact_size && requested_w > 0 && requested_h > 0;
  g.width = exact ? requested_w : even_at_least_2(ow);
  g.height = exact ? requested_h : even_at_least_2(oh);
  // No size requested: 1:1 with the canvas, padded to even sizes (no resampling).
  const bool requested = requested_w > 0 || requested_h > 0;
  const double s = requested ? std::min(g.width / sw, g.height / sh) : 1.0;
  const double ox = std::floor((g.width - sw * s) * 0.5), oy = std::floor((g.height - sh * s) * 0.5);
  // Pixel-centre convention: canvas (x+0.5) scales to output (x'+0.5).
  Eigen::Matrix3d A;
  A << s, 0, ox + (0.5 - src.x) * s - 0.5, 0, s, oy + (0.5 - src.y) * s - 0.5, 0, 0, 1;
  g.canvas_to_output = A;
  return g;
}

std::vector<ViewPlacement> place_views(const Rig& rig, const OutputGeometry& out) {
  std::vector<ViewPlacement> views;
  const Eigen::Matrix3d& A = out.canvas_to_output;  // axis-aligned scale + offset
  // The output shows the whole 360 degrees of a wrapping canvas (not a horizontal crop of it).
  const bool output_wraps = rig.canvas_wrap && std::abs(A(0, 0) * rig.canvas_width - out.width) < 1e-6 &&
                            std::abs(A(0, 2) - (0.5 * A(0, 0) - 0.5)) < 1e-6;
  for (int i = 0; i < int(rig.cameras.size()); ++i) {
    const Camera& cam = rig.cameras[i];
    ViewPlacement v;
    v.camera_width = cam.width;
    v.camera_height = cam.height;
    v.frame_width = cam.width;
    v.frame_height = cam.height;
    v.lens = lens_params(cam);
    if (rig.planar()) {
      const Eigen::Matrix3d cam_to_out = A * cam.homography.value();
      v.output_to_camera = cam_to_out.inverse();
      if (v.has_lens()) v.output_to_camera = cam.K().inverse() * v.output_to_camera;  // -> camera ray
    } else {
      // output -> canvas -> angles, both axis-aligned: a = ((x - A02) / A00 - origin_x) / scale.
      v.projection = rig.projection_kind();
      v.output_to_camera = v.has_lens() ? Eigen::Matrix3d(cam.R().transpose()) : Eigen::Matrix3d(cam.K() * cam.R().transpose());
      const double s = rig.canvas_scale;
      v.output_to_angles = {1 / (A(0, 0) * s), -(A(0, 2) / A(0, 0) + rig.canvas_origin_x) / s, 1 / (A(1, 1) * s),
                            -(A(1, 2) / A(1, 1) + rig.canvas_origin_y) / s};
    }
    double minx = 1e300, miny = 1e300, maxx = -1e300, maxy = -1e300;
    double canvas_minx = 1e300, canvas_maxx = -1e300;
    for (const auto& q : camera_canvas_outline(rig, i)) {
      const Eigen::Vector2d o = apply_homography(out.canvas_to_output, q);
      canvas_minx = std::min(canvas_minx, q.x());
      canvas_maxx = std::max(canvas_maxx, q.x());
      minx = std::min(minx, o.x());
      miny = std::min(miny, o.y());
      maxx = std::max(maxx, o.x());
      maxy = std::max(maxy, o.y());
    }
    if (rig.canvas_wrap && (canvas_minx < -0.5 || canvas_maxx > rig.canvas_width - 0.5)) {
      // The view crosses the 360-degree wrap: it shows at both edges. Its rectangle spans the
      // whole width; the angle mapping is periodic, so each column samples the right side.
      if (output_wraps) {
        const double margin = 2 + 0.02 * (maxx - minx);
        v.wrap_width = out.width;
        // Kept starting inside the output, so that only the left edge's columns need unwrapping.
        const double shift = minx - margin < 0 ? out.width : 0;
        v.span_x0 = minx - margin + shift;
        v.span_x1 = maxx + margin + shift;
      }
      minx = 0;
      maxx = out.width - 1;
    }
    const int x0 = std::max(0, int(std::floor(minx))), y0 = std::max(0, int(std::floor(miny)));
    const int x1 = std::min(out.width - 1, int(std::ceil(maxx)));
    const int y1 = std::min(out.height - 1, int(std::ceil(maxy)));
    if (x1 >= x0 && y1 >= y0) v.roi = {x0, y0, x1 - x0 + 1, y1 - y0 + 1};
    views.push_back(v);
  }
  return views;
}

namespace {

// Camera pixels between neighbouring output pixels over the view: the median, on a grid of the
// view, of the square root of the area one output pixel covers (the Jacobian's determinant).
// The median, not the smallest: a spherical canvas oversamples towards the poles.
double typical_spacing(const ViewPlacement& v) {
  constexpr int kGrid = 9;
  std::vector<double> spacing;
  for (int gy = 0; gy < kGrid; ++gy)
    for (int gx = 0; gx < kGrid; ++gx) {
      const double x = v.roi.x + (v.roi.width - 1) * (gx + 0.5) / kGrid;
      const double y = v.roi.y + (v.roi.height - 1) * (gy + 0.5) / kGrid;
      double u0, w0, u1, w1, u2, w2;
      if (!view_to_camera(v, x, y, u0, w0) || !view_to_camera(v, x + 1, y, u1, w1) || !view_to_camera(v, x, y + 1, u2, w2))
        continue;
      if (u0 < 0 || w0 < 0 || u0 > v.camera_width - 1 || w0 > v.camera_height - 1) continue;  // sees nothing here
      const double area = std::abs((u1 - u0) * (w2 - w0) - (w1 - w0) * (u2 - u0));
      if (std::isfinite(area)) spacing.push_back(std::sqrt(area));
    }
  if (spacing.empty()) return 0;
  std::nth_element(spacing.begin(), spacing.begin() + spacing.size() / 2, spacing.end());
  return spacing[spacing.size() / 2];
}

}  // namespace

void prefilter_sparse_views(std::vector<ViewPlacement>& views) {
  constexpr int kMaxLevel = 4;
  for (ViewPlacement& v : views) {
    if (v.roi.empty() || v.level > 0) continue;
    const double spacing = typical_spacing(v);
    if (!(spacing > 1.0)) continue;
    // Level L once the spacing reaches 1.32 * 2^L (measured on rendered rings and trios,
    // BENCHMARKS.md): the reduced frame is then read 1.32-2.64 px apart. Bilinear reads 2 px
    // apart are already a 2x2 mean, so a spacing of 2 keeps the full frame.
    const int level = std::clamp(int(std::floor(std::log2(spacing / 1.32))), 0, kMaxLevel);
    for (int l = 0; l < level; ++l) {
      // reduced pixel = (pixel + 0.5) / 2 - 0.5, after the lens when there is one
      auto half = [](double& p) { p = (p + 0.5) * 0.5 - 0.5; };
      if (v.has_lens()) {
        auto& L = v.lens;
        L.fx *= 0.5, L.fy *= 0.5;
        half(L.cx), half(L.cy);
        if (L.circle_r > 0) half(L.circle_cx), half(L.circle_cy), L.circle_r *= 0.5;
      } else {
        Eigen::Matrix3d S;
        S << 0.5, 0, -0.25, 0, 0.5, -0.25, 0, 0, 1;
        v.output_to_camera = S * v.output_to_camera;
      }
      v.camera_width = (v.camera_width + 1) / 2;
      v.camera_height = (v.camera_height + 1) / 2;
    }
    v.level = level;
  }
}

void halve_frame(const ImageView& src, const ImageView& dst) {
  for (int y = 0; y < dst.height; ++y) {
    const uint8_t* r0 = src.data + std::size_t(std::min(2 * y, src.height - 1)) * src.pitch;
    const uint8_t* r1 = src.data + std::size_t(std::min(2 * y + 1, src.height - 1)) * src.pitch;
    uint8_t* o = dst.data + std::size_t(y) * dst.pitch;
    for (int x = 0; x < dst.width; ++x) {
      const int a = 8 * x, b = 4 * std::min(2 * x + 1, src.width - 1);
      for (int c = 0; c < 4; ++c) o[4 * x + c] = uint8_t((r0[a + c] + r0[b + c] + r1[a + c] + r1[b + c] + 2) >> 2);
    }
  }
}

const std::vector<ImageView>& FrameReducer::reduce(const std::vector<ViewPlacement>& views,
                                                  const std::vector<ImageView>& frames) {
  // Most outputs read every view 1:1 or denser: no copy, no parallel region per frame.
  if (std::none_of(views.begin(), views.end(), [](const ViewPlacement& v) { return v.level > 0; })) return frames;
  out_ = frames;
  levels_.resize(frames.size());
  cv::parallel_for_(cv::Range(0, int(std::min(frames.size(), views.size()))), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i) {
      const ViewPlacement& v = views[std::size_t(i)];
      ImageView src = frames[std::size_t(i)];
      if (src.empty() || v.level == 0 || v.roi.empty()) continue;
      auto& levels = levels_[std::size_t(i)];
      levels.resize(std::size_t(v.level));
      for (int l = 0; l < v.level; ++l) {
        ImageView dst;
        dst.width = (src.width + 1) / 2;
        dst.height = (src.height + 1) / 2;
        dst.pitch = std::size_t(dst.width) * 4;
        levels[std::size_t(l)].resize(dst.pitch * std::size_t(dst.height));
        dst.data = levels[std::size_t(l)].data();
        halve_frame(src, dst);
        src = dst;
      }
      out_[std::size_t(i)] = src;
    }
  });
  return out_;
}

void check_frame_sizes(const std::vector<ViewPlacement>& views, const std::vector<ImageView>& frames) {
  for (std::size_t i = 0; i < frames.size() && i < views.size(); ++i)
    if (!frames[i].empty() && (frames[i].width != views[i].frame_width || frames[i].height != views[i].frame_height))
      throw std::invalid_argument("frame " + std::to_string(i) + " is " + std::to_string(frames[i].width) + "x" +
                                  std::to_string(frames[i].height) + ", the rig expects " +
                                  std::to_string(views[i].frame_width) + "x" + std::to_string(views[i].frame_height));
}

}  // namespace stitch
