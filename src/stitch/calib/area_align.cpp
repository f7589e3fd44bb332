#include "stitch/calib/area_align.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

namespace stitch {

AreaAlignment align_overlap_by_area(const Camera& a, const Camera& b, const cv::Mat& gray_a, const cv::Mat& gray_b,
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
  cv::patchNaNs(score, -1);
  double best = 0;
  cv::Point at;
  cv::minMaxLoc(score, nullptr, &best, nullptr, &at);
  {
    // The runner-up: the best other local maximum (a broad peak has none near it).
    cv::Mat dil, rest = score.clone();
    cv::dilate(score, dil, cv::Mat::ones(5, 5, CV_8U));
    rest.setTo(-1, score < dil);
    cv::circle(rest, at, o.peak_exclusion_px, cv::Scalar(-1), cv::FILLED);
    double second = -1;
    cv::minMaxLoc(rest, nullptr, &second);
    if (!(best >= o.min_strip_ncc) || second > best - o.min_peak_margin) return out;
  }
  const int gx = at.x - S, gy = at.y - S;
  // 2. Textured patches located near that shift: the correspondences.
  std::vector<cv::Point2f> corners;
  cv::goodFeaturesToTrack(a_in_b, corners, o.max_patches, 0.02, r, inner, 7);
  const int L = int(std::ceil(o.local_search_px));
  std::vector<cv::Point2f> from, to;
  for (const cv::Point2f& c : corners) {
    const int cx = int(std::lround(c.x)), cy = int(std::lround(c.y));
    const cv::Rect tr(cx - r, cy - r, 2 * r + 1, 2 * r + 1);
    cv::Rect win(cx + gx - r - L, cy + gy - r - L, 2 * (r + L) + 1, 2 * (r + L) + 1);
    win &= cv::Rect(0, 0, gray_b.cols, gray_b.rows);
    if (win.width < tr.width + 2 || win.height < tr.height + 2) continue;
    cv::matchTemplate(gray_b(win), a_in_b(tr), score, cv::TM_CCOEFF_NORMED);
    cv::minMaxLoc(score, nullptr, &best, nullptr, &at);
    if (!(best >= o.min_ncc)) continue;
    // Sub-pixel peak (a parabola per axis) where the peak is inside the score map.
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
    to.emplace_back(float(win.x + at.x + r + dx), float(win.y + at.y + r + dy));
  }
  out.patches = int(from.size());

  if (out.patches < std::max(3, o.min_agreeing)) return out;
  // The patches that agree on one near-rigid motion (a rotation error over a seam is nearly a
  // shift; a focal error adds a small scale).
  std::vector<uchar> inl;
  const cv::Mat M = cv::estimateAffinePartial2D(from, to, inl, cv::RANSAC, o.agree_px, 2000, 0.995, 10);
  if (M.empty()) return out;
  const double scale = std::hypot(M.at<double>(0, 0), M.at<double>(1, 0));
  if (!(scale > 0.9 && scale < 1.1)) return out;
  std::vector<double> dist;
  for (std::size_t k = 0; k < from.size(); ++k) {
    if (!inl[k]) continue;
    const Eigen::Vector3d h = Hba * Eigen::Vector3d(from[k].x, from[k].y, 1.0);
    out.pa.emplace_back(h.x() / h.z(), h.y() / h.z());
    out.pb.emplace_back(to[k].x, to[k].y);
    dist.push_back(std::hypot(to[k].x - from[k].x, to[k].y - from[k].y));
  }
  out.agreeing = int(dist.size());
  // Most of the patches that correlated: chance agreement of a few in a plain or repeated
  // texture is not a measurement.
  if (out.agreeing < o.min_agreeing || out.agreeing * 5 < out.patches * 2) {
    out.pa.clear();
    out.pb.clear();
    return out;
  }
  std::nth_element(dist.begin(), dist.begin() + dist.size() / 2, dist.end());
  out.offset_px = dist[dist.size() / 2];
  out.measured = true;
  return out;
}

}  // namespace stitch
