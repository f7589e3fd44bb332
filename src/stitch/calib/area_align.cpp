#include "stitch/calib/area_align.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

namespace stitch {

namespace {

constexpr double kPi = 3.14159265358979323846;

// A local cylindrical projection around the direction midway between two cameras' axes: there a
// rotation error between them is (nearly) a shift, also at the edges of wide lenses where in
// either camera's own pixels it stretches the picture.
struct LocalCylinder {
  Eigen::Matrix3d Rm;  // local frame -> rig
  double f = 1;        // pixels per radian
  int S = 0;           // the search range, pixels
  cv::Size size;
  double cu = 0, cv_ = 0;
  Eigen::Vector3d ray(double u, double v) const {
    const double t = (u - cu) / f, h = (v - cv_) / f;
    return Rm * Eigen::Vector3d(std::sin(t), h, std::cos(t));
  }
};

// Pixel of camera c (pinhole) seeing the rig-frame ray d; false behind it.
bool project(const Camera& c, const Eigen::Vector3d& d, Eigen::Vector2d& px) {
  const Eigen::Vector3d h = c.K() * (c.R().transpose() * d);
  if (!(h.z() > 1e-9)) return false;
  px = h.head<2>() / h.z();
  return true;
}

// Camera c's picture on the cylinder, and where it is valid (inside the frame).
void resample(const LocalCylinder& cyl, const Camera& c, const cv::Mat& gray, cv::Mat& out, cv::Mat& valid) {
  cv::Mat mx(cyl.size, CV_32F, cv::Scalar(-1)), my(cyl.size, CV_32F, cv::Scalar(-1));
  valid = cv::Mat(cyl.size, CV_8U, cv::Scalar(0));
  for (int y = 0; y < cyl.size.height; ++y)
    for (int x = 0; x < cyl.size.width; ++x) {
      Eigen::Vector2d q;
      if (!project(c, cyl.ray(x, y), q) || q.x() < 0 || q.y() < 0 || q.x() > gray.cols - 1 || q.y() > gray.rows - 1) continue;
      mx.at<float>(y, x) = float(q.x());
      my.at<float>(y, x) = float(q.y());
      valid.at<uchar>(y, x) = 255;
    }
  cv::remap(gray, out, mx, my, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
}

// The whole overlap's correlation map: its best shift `at`, when it stands out (min_strip_ncc, and
// the runner-up, the best other local maximum, min_peak_margin below it; a broad peak has none).
bool distinct_peak(cv::Mat& score, const AreaAlignOptions& o, cv::Point& at) {
  // Windows with no variance (a flat fill) give NaN or infinity.
  cv::patchNaNs(score, -1);
  score.setTo(-1, (score > 1.001) | (score < -1.001));
  double best = 0;
  cv::minMaxLoc(score, nullptr, &best, nullptr, &at);
  cv::Mat dil, rest = score.clone();
  cv::dilate(score, dil, cv::Mat::ones(5, 5, CV_8U));
  rest.setTo(-1, score < dil);
  cv::circle(rest, at, o.peak_exclusion_px, cv::Scalar(-1), cv::FILLED);
  double second = -1;
  cv::minMaxLoc(rest, nullptr, &second);
  return best >= o.min_strip_ncc && second <= best - o.min_peak_margin;
}

// Textured patches of `from_img` (centres where `centres` is set) located in `to_img` near
// the shift (gx, gy), to a sub-pixel by a parabola per axis.
void locate_patches(const cv::Mat& from_img, const cv::Mat& to_img, const cv::Mat& centres, int gx, int gy,
                    const AreaAlignOptions& o, std::vector<cv::Point2f>& from, std::vector<cv::Point2f>& to) {
  const int r = o.patch_radius, L = int(std::ceil(o.local_search_px));
  std::vector<cv::Point2f> corners;
  cv::goodFeaturesToTrack(from_img, corners, o.max_patches, 0.02, r, centres, 7);
  cv::Mat score;
  for (const cv::Point2f& c : corners) {
    const int cx = int(std::lround(c.x)), cy = int(std::lround(c.y));
    const cv::Rect tr(cx - r, cy - r, 2 * r + 1, 2 * r + 1);
    cv::Rect near(cx + gx - r - L, cy + gy - r - L, 2 * (r + L) + 1, 2 * (r + L) + 1);
    near &= cv::Rect(0, 0, to_img.cols, to_img.rows);
    if (near.width < tr.width + 2 || near.height < tr.height + 2) continue;
    cv::matchTemplate(to_img(near), from_img(tr), score, cv::TM_CCOEFF_NORMED);
    double best = 0;
    cv::Point at;
    cv::minMaxLoc(score, nullptr, &best, nullptr, &at);
    if (!(best >= o.min_ncc)) continue;
    double dx = 0, dy = 0;
    if (at.x > 0 && at.x < score.cols - 1) {
      const float l = score.at<float>(at.y, at.x - 1), m = score.at<float>(at), rr = score.at<float>(at.y, at.x + 1);
      const double den = l - 2 * m + rr;
      if (den < 0) dx = std::clamp(0.5 * (l - rr) / den, -0.5, 0.5);
    }
    if (at.y > 0 && at.y < score.rows - 1) {
      const float u = score.at<float>(at.y - 1, at.x), m = score.at<float>(at), d = score.at<float>(at.y + 1, at.x);
      const double den = u - 2 * m + d;
      if (den < 0) dy = std::clamp(0.5 * (u - d) / den, -0.5, 0.5);
    }
    from.emplace_back(float(cx), float(cy));
    to.emplace_back(float(near.x + at.x + r + dx), float(near.y + at.y + r + dy));
  }
}

// The patches that agree on one near-rigid motion (a rotation error over a seam is nearly a
// shift; a focal error adds a small scale): `inl`.
bool agree_on_one_motion(const std::vector<cv::Point2f>& from, const std::vector<cv::Point2f>& to,
                         const AreaAlignOptions& o, std::vector<uchar>& inl) {
  if (int(from.size()) < std::max(3, o.min_agreeing)) return false;
  const cv::Mat M = cv::estimateAffinePartial2D(from, to, inl, cv::RANSAC, o.agree_px, 2000, 0.995, 10);
  if (M.empty()) return false;
  const double scale = std::hypot(M.at<double>(0, 0), M.at<double>(1, 0));
  return scale > 0.9 && scale < 1.1;
}

// Textured patches located (locate_patches; their count in out.patches), and whether they agree
// on one motion (agree_on_one_motion; `inl` marks those that do).
bool patches_on_one_motion(const cv::Mat& from_img, const cv::Mat& to_img, const cv::Mat& centres, int gx, int gy,
                           const AreaAlignOptions& o, AreaAlignment& out, std::vector<cv::Point2f>& from,
                           std::vector<cv::Point2f>& to, std::vector<uchar>& inl) {
  locate_patches(from_img, to_img, centres, gx, gy, o, from, to);
  out.patches = int(from.size());
  return agree_on_one_motion(from, to, o, inl);
}

// Measured when most of the patches that correlated agree (chance agreement of a few in a plain
// or repeated texture is not a measurement): the offset is their median distance.
void conclude(AreaAlignment& out, std::vector<double> dist, const AreaAlignOptions& o) {
  out.agreeing = int(dist.size());
  if (out.agreeing < o.min_agreeing || out.agreeing * 5 < out.patches * 2) {
    out.pa.clear();
    out.pb.clear();
    return;
  }
  std::nth_element(dist.begin(), dist.begin() + dist.size() / 2, dist.end());
  out.offset_px = dist[dist.size() / 2];
  out.measured = true;
}

// In b's own pixels (a rotation error is a shift there away from wide lenses' edges): the
// first try, measured on every probe4 rig but one.
AreaAlignment align_in_b_frame(const Camera& a, const Camera& b, const cv::Mat& gray_a, const cv::Mat& gray_b,
                                    const AreaAlignOptions& o) {
  AreaAlignment out;
  if (!a.lens.pinhole() || !b.lens.pinhole() || gray_a.empty() || gray_b.empty() || gray_a.type() != CV_8UC1 ||
      gray_b.type() != CV_8UC1)
    return out;
  // b pixel -> a pixel through the rotations; a's picture resampled into b's frame where the ray
  // lies in front of a and inside its frame.
  const Eigen::Matrix3d Hba = a.K() * a.R().transpose() * b.R() * b.K().inverse();
  cv::Mat map_x(gray_b.size(), CV_32F), map_y(gray_b.size(), CV_32F), valid(gray_b.size(), CV_8U, cv::Scalar(0));
  for (int y = 0; y < gray_b.rows; ++y) {
    float* mx = map_x.ptr<float>(y);
    float* my = map_y.ptr<float>(y);
    uchar* v = valid.ptr<uchar>(y);
    for (int x = 0; x < gray_b.cols; ++x) {
      const Eigen::Vector3d h = Hba * Eigen::Vector3d(x, y, 1.0);
      mx[x] = my[x] = -1;
      if (!(h.z() > 1e-9)) continue;
      const double u = h.x() / h.z(), w = h.y() / h.z();
      if (u < 0 || w < 0 || u > gray_a.cols - 1 || w > gray_a.rows - 1) continue;
      mx[x] = float(u);
      my[x] = float(w);
      v[x] = 255;
    }
  }
  const int r = o.patch_radius;
  cv::Mat inner;
  cv::erode(valid, inner, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * r + 3, 2 * r + 3)));
  // Patches whole inside the frame too (erode keeps the frame's border).
  const int m = r + 1;
  if (inner.cols <= 2 * m || inner.rows <= 2 * m) return out;
  inner.rowRange(0, m).setTo(0);
  inner.rowRange(inner.rows - m, inner.rows).setTo(0);
  inner.colRange(0, m).setTo(0);
  inner.colRange(inner.cols - m, inner.cols).setTo(0);
  if (cv::countNonZero(inner) == 0) return out;
  out.overlap = true;
  cv::Mat a_in_b;
  cv::remap(gray_a, a_in_b, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  // 1. The whole overlap as one template (masked), searched over the full range: a small patch on
  // a straight or repeated structure (studs, a duct's seams) correlates all along it, the whole
  // overlap does not. Its peak must stand out (a distinct shift).
  const int S = int(std::ceil(o.search_px));
  const cv::Rect box = cv::boundingRect(valid);
  cv::Mat padded;
  cv::copyMakeBorder(gray_b, padded, S, S, S, S, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::Mat score;
  cv::matchTemplate(padded(cv::Rect(box.x, box.y, box.width + 2 * S, box.height + 2 * S)), a_in_b(box), score,
                    cv::TM_CCOEFF_NORMED, valid(box));
  cv::Point at;
  if (!distinct_peak(score, o, at)) return out;
  const int gx = at.x - S, gy = at.y - S;
  // 2. Textured patches located near that shift: the correspondences.
  std::vector<cv::Point2f> from, to;
  std::vector<uchar> inl;
  if (!patches_on_one_motion(a_in_b, gray_b, inner, gx, gy, o, out, from, to, inl)) return out;
  std::vector<double> dist;
  for (std::size_t k = 0; k < from.size(); ++k) {
    if (!inl[k]) continue;
    const Eigen::Vector3d h = Hba * Eigen::Vector3d(from[k].x, from[k].y, 1.0);
    out.pa.emplace_back(h.x() / h.z(), h.y() / h.z());
    out.pb.emplace_back(to[k].x, to[k].y);
    dist.push_back(std::hypot(to[k].x - from[k].x, to[k].y - from[k].y));
  }
  conclude(out, dist, o);
  return out;
}

// On a local cylinder: a ring that does not close by several degrees (wide4long, 8 degrees at
// hfov 100) predicts its closing views apart and stretched in b's pixels.
AreaAlignment align_on_local_cylinder(const Camera& a, const Camera& b, const cv::Mat& gray_a, const cv::Mat& gray_b,
                                    const AreaAlignOptions& o) {
  AreaAlignment out;
  if (!a.lens.pinhole() || !b.lens.pinhole() || gray_a.empty() || gray_b.empty() || gray_a.type() != CV_8UC1 ||
      gray_b.type() != CV_8UC1)
    return out;
  LocalCylinder cyl;
  {
    const Eigen::AngleAxisd rel(a.R().transpose() * b.R());
    cyl.Rm = a.R() * Eigen::AngleAxisd(0.5 * rel.angle(), rel.axis()).toRotationMatrix();
    cyl.f = std::sqrt(b.fx * b.fy);
    cyl.S = int(std::ceil(o.search_px));
    // Wide enough for both views' overlap and the search; at most a half turn.
    const double half = std::min(0.5 * kPi, 0.5 * rel.angle() + 0.25 * kPi);
    const int w = int(std::ceil(2 * half * cyl.f)), h = int(std::ceil(1.2 * std::max(a.height, b.height)));
    cyl.size = cv::Size(std::max(w, 8), std::max(h, 8));
    cyl.cu = 0.5 * (cyl.size.width - 1);
    cyl.cv_ = 0.5 * (cyl.size.height - 1);
  }
  cv::Mat ca, va, cb, vb;
  resample(cyl, a, gray_a, ca, va);
  resample(cyl, b, gray_b, cb, vb);
  // Outside b's frame: b's mean grey (no covariance with the template, no false edge).
  {
    cv::Mat outside_b;
    cv::bitwise_not(vb, outside_b);
    cb.setTo(cv::mean(cb, vb), outside_b);
  }
  const int S = cyl.S, r = o.patch_radius;
  // Where a's picture lies within the search range of b's: the template (masked).
  cv::Mat near_b, tmask;
  cv::dilate(vb, near_b, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * S + 1, 2 * S + 1)));
  cv::bitwise_and(va, near_b, tmask);
  if (cv::countNonZero(tmask) < (2 * r + 1) * (2 * r + 1)) return out;
  cv::Mat overlap_now;
  cv::bitwise_and(va, vb, overlap_now);
  out.overlap = cv::countNonZero(overlap_now) > 0;
  // 1. The whole overlap as one template, searched over the full range: a small patch on a
  // straight or repeated structure (studs, a duct's seams) correlates all along it, the whole
  // overlap does not. Its peak must stand out (a distinct shift).
  const cv::Rect box = cv::boundingRect(tmask);
  cv::Mat padded;
  cv::copyMakeBorder(cb, padded, S, S, S, S, cv::BORDER_CONSTANT, cv::mean(cb, vb));
  const cv::Rect win(box.x, box.y, box.width + 2 * S, box.height + 2 * S);  // padded coordinates
  cv::Mat score;
  cv::matchTemplate(padded(win), ca(box), score, cv::TM_CCOEFF_NORMED, tmask(box));
  cv::Point at;
  if (!distinct_peak(score, o, at)) return out;
  const int gx = at.x - S, gy = at.y - S;
  // 2. Textured patches of a located near that shift in b: the correspondences.
  cv::Mat inner_a, inner_b;
  const cv::Mat k = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * r + 3, 2 * r + 3));
  cv::erode(va, inner_a, k, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::erode(vb, inner_b, k, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  {
    // a's patch centres whose shifted place lies inside b.
    cv::Mat shifted(inner_b.size(), CV_8U, cv::Scalar(0));
    const cv::Mat M = (cv::Mat_<double>(2, 3) << 1, 0, -gx, 0, 1, -gy);
    cv::warpAffine(inner_b, shifted, M, inner_b.size(), cv::INTER_NEAREST, cv::BORDER_CONSTANT, cv::Scalar(0));
    cv::bitwise_and(inner_a, shifted, inner_a);
  }
  if (cv::countNonZero(inner_a) == 0) return out;
  std::vector<cv::Point2f> from, to;
  std::vector<uchar> inl;
  if (!patches_on_one_motion(ca, cb, inner_a, gx, gy, o, out, from, to, inl)) return out;
  // Back to camera pixels: a's patch centre in a; where b sees it, and where the rig predicts it
  // (the offset, b pixels).
  std::vector<double> dist;
  for (std::size_t k = 0; k < from.size(); ++k) {
    if (!inl[k]) continue;
    Eigen::Vector2d pa, pb, predicted;
    if (!project(a, cyl.ray(from[k].x, from[k].y), pa) || !project(b, cyl.ray(to[k].x, to[k].y), pb) ||
        !project(b, cyl.ray(from[k].x, from[k].y), predicted))
      continue;
    out.pa.push_back(pa);
    out.pb.push_back(pb);
    dist.push_back((pb - predicted).norm());
  }
  conclude(out, dist, o);
  return out;
}

}  // namespace

AreaAlignment align_overlap_by_area(const Camera& a, const Camera& b, const cv::Mat& gray_a, const cv::Mat& gray_b,
                                    const AreaAlignOptions& o) {
  AreaAlignOptions in_frame = o;
  in_frame.search_px = std::min(o.search_px, 0.125 * std::max(b.width, a.width));
  in_frame.min_peak_margin = 0.1;
  AreaAlignment al = align_in_b_frame(a, b, gray_a, gray_b, in_frame);
  if (al.measured) return al;
  AreaAlignment on_cylinder = align_on_local_cylinder(a, b, gray_a, gray_b, o);
  if (on_cylinder.measured || on_cylinder.overlap) return on_cylinder;
  return al;
}

}  // namespace stitch
