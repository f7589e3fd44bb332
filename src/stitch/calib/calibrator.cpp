#include "stitch/calib/calibrator.hpp"

#include <functional>
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <mutex>
#include <numeric>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/stitching/detail/autocalib.hpp>
#include <queue>
#include <random>
#include <set>

#include "stitch/calib/area_align.hpp"
#include "stitch/calib/bundle_adjust.hpp"
#include "stitch/calib/dense_matches.hpp"
#include "stitch/calib/fisheye_guess.hpp"
#include "stitch/calib/photometric_refine.hpp"
#include "stitch/calib/plumb_line.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "stitch/rig/lens.hpp"
#include "stitch/rig/overlap.hpp"

namespace stitch {
namespace {

struct Features {
  std::vector<cv::KeyPoint> keypoints;  // full-resolution pixel coordinates
  cv::Mat descriptors;
};

cv::Ptr<cv::Feature2D> make_detector(FeatureType type, int max_features) {
  switch (type) {
    case FeatureType::Sift: return cv::SIFT::create(max_features);
    case FeatureType::Orb: return cv::ORB::create(max_features);
    case FeatureType::Akaze: return cv::AKAZE::create();
  }
  return cv::SIFT::create(max_features);
}

}  // namespace

void throw_if_cancelled(const CalibrationOptions& options) {
  if (options.cancel && options.cancel->load(std::memory_order_relaxed)) throw CalibrationCancelled();
  if (options.deadline && std::chrono::steady_clock::now() > *options.deadline) throw CalibrationCancelled();
}

namespace {

cv::Mat to_gray(const ImageView& v) {
  cv::Mat gray;
  cv::cvtColor(as_mat(v), gray, cv::COLOR_RGBA2GRAY);
  return gray;
}

Features detect(const cv::Mat& gray, const cv::Mat& mask, const CalibrationOptions& o) {
  throw_if_cancelled(o);
  const double mp = gray.total() / 1e6;
  const double s = mp > o.feature_megapixels ? std::sqrt(o.feature_megapixels / mp) : 1.0;
  cv::Mat img = gray, m = mask;
  if (s < 1.0) {
    cv::resize(gray, img, cv::Size(), s, s, cv::INTER_AREA);
    if (!mask.empty()) cv::resize(mask, m, img.size(), 0, 0, cv::INTER_NEAREST);
  }
  Features f;
  auto det = make_detector(o.features, o.max_features);
  det->detectAndCompute(img, m, f.keypoints, f.descriptors);
  if (o.features == FeatureType::Akaze && int(f.keypoints.size()) > o.max_features) {
    // AKAZE has no cap of its own: keep the strongest responses.
    std::vector<int> idx(f.keypoints.size());
    std::iota(idx.begin(), idx.end(), 0);
    std::partial_sort(idx.begin(), idx.begin() + o.max_features, idx.end(),
                      [&](int a, int b) { return f.keypoints[a].response > f.keypoints[b].response; });
    Features kept;
    for (int k = 0; k < o.max_features; ++k) {
      kept.keypoints.push_back(f.keypoints[idx[k]]);
      kept.descriptors.push_back(f.descriptors.row(idx[k]));
    }
    f = std::move(kept);
  }
  // OpenCV's SIFT detects on the image upsampled 2x (linear, pixel-centre convention) and
  // halves the coordinates, which puts every keypoint 0.25 px right of and below where it is.
  // A pairwise homography absorbs a common shift; the rotation model (principal points held)
  // does not, and turns it into focal/rotation errors that a planar canvas magnifies.
  const float bias = o.features == FeatureType::Sift ? 0.25f : 0.0f;
  for (auto& kp : f.keypoints) {
    // Back to full resolution, pixel-centre convention.
    kp.pt.x = float((kp.pt.x - bias + 0.5) / s - 0.5);
    kp.pt.y = float((kp.pt.y - bias + 0.5) / s - 0.5);
  }
  return f;
}

std::vector<cv::DMatch> match(const Features& a, const Features& b, FeatureType type) {
  std::vector<cv::DMatch> good;
  if (a.descriptors.empty() || b.descriptors.empty() || a.keypoints.size() < 2 || b.keypoints.size() < 2)
    return good;
  const int norm = type == FeatureType::Sift ? cv::NORM_L2 : cv::NORM_HAMMING;
  cv::BFMatcher matcher(norm);
  std::vector<std::vector<cv::DMatch>> knn;
  matcher.knnMatch(a.descriptors, b.descriptors, knn, 2);
  for (const auto& m : knn)
    if (m.size() == 2 && m[0].distance < 0.75f * m[1].distance) good.push_back(m[0]);
  return good;
}

// Canvas-space bounding box of the overlap of two views; empty when they do not overlap.
cv::Rect2d overlap_box(const Rig& rig, int a, int b) {
  float area = 0;
  const std::vector<cv::Point2f> inter = canvas_overlap(rig, a, b, &area);
  if (area <= 1.0f || inter.empty()) return {};
  float x0 = inter[0].x, y0 = inter[0].y, x1 = x0, y1 = y0;
  for (const auto& p : inter) {
    x0 = std::min(x0, p.x);
    y0 = std::min(y0, p.y);
    x1 = std::max(x1, p.x);
    y1 = std::max(y1, p.y);
  }
  return {x0, y0, x1 - x0, y1 - y0};
}

// Mask of the camera pixels that land in the (widened) canvas box. With a lens the box's border
// is sampled and mapped through the lens-aware canvas map (a straight canvas edge bends).
cv::Mat camera_mask(const Rig& rig, int cam, const cv::Rect2d& box) {
  const Camera& c = rig.cameras[cam];
  cv::Mat mask(c.height, c.width, CV_8U, cv::Scalar(0));
  if (!c.lens.pinhole()) {
    const CameraCanvasMap m = camera_canvas_map(rig, cam);
    std::vector<cv::Point> poly;
    constexpr int kSteps = 16;
    for (int side = 0; side < 4; ++side)
      for (int k = 0; k < kSteps; ++k) {
        const double t = double(k) / kSteps;
        Eigen::Vector2d q;
        switch (side) {
          case 0: q = {box.x + t * box.width, box.y}; break;
          case 1: q = {box.x + box.width, box.y + t * box.height}; break;
          case 2: q = {box.x + (1 - t) * box.width, box.y + box.height}; break;
          default: q = {box.x, box.y + (1 - t) * box.height}; break;
        }
        Eigen::Vector2d px;
        if (!m.to_camera(q, px) || !px.allFinite()) return cv::Mat(c.height, c.width, CV_8U, cv::Scalar(255));
        px = px.cwiseMax(-1e5).cwiseMin(1e5);
        poly.emplace_back(int(std::lround(px.x())), int(std::lround(px.y())));
      }
    cv::fillPoly(mask, std::vector<std::vector<cv::Point>>{poly}, cv::Scalar(255));
    return mask;
  }
  const Eigen::Matrix3d Hinv = c.homography->inverse();
  std::vector<cv::Point> poly;
  const Eigen::Vector2d corners[4] = {{box.x, box.y}, {box.x + box.width, box.y},
                                      {box.x + box.width, box.y + box.height}, {box.x, box.y + box.height}};
  for (const auto& p : corners) {
    Eigen::Vector3d q = Hinv * Eigen::Vector3d(p.x(), p.y(), 1);
    if (!(q.z() > 1e-9)) return cv::Mat(c.height, c.width, CV_8U, cv::Scalar(255));
    poly.emplace_back(int(std::lround(q.x() / q.z())), int(std::lround(q.y() / q.z())));
  }
  cv::fillConvexPoly(mask, poly, cv::Scalar(255));
  return mask;
}

// `p`: an IDEAL (undistorted) pixel; the plane homography maps ideal pixels to the canvas.
cv::Point2f to_canvas(const Camera& c, const cv::Point2f& p) {
  Eigen::Vector2d q = apply_homography(*c.homography, {p.x, p.y});
  return {float(q.x()), float(q.y())};
}

// Ideal pixel of raw pixel `p` (issue 15: fits happen on ideal pixels); false where the lens
// has none. Pinhole cameras: the pixel itself.
bool ideal_of(const Camera& c, const cv::Point2f& p, cv::Point2f& out) {
  if (c.lens.pinhole()) {
    out = p;
    return true;
  }
  Eigen::Vector2d q;
  if (!undistort_point(c, {p.x, p.y}, q) || !q.allFinite()) return false;
  out = {float(q.x()), float(q.y())};
  return true;
}

bool any_lens(const Rig& rig) {
  for (const auto& c : rig.cameras)
    if (!c.lens.pinhole()) return true;
  return false;
}

struct ScaleShift {
  double sx = 1, sy = 1, tx = 0, ty = 0, cx = 0, cy = 0;
  cv::Point2d apply(const cv::Point2f& p) const {
    return {sx * (p.x - cx) + cx + tx, sy * (p.y - cy) + cy + ty};
  }
  Eigen::Matrix3d matrix() const {
    Eigen::Matrix3d M;
    M << sx, 0, cx + tx - sx * cx, 0, sy, cy + ty - sy * cy, 0, 0, 1;
    return M;
  }
};

// Least squares for one axis: d = s * (p - c) + c + t; scale fixed at 1 when the spread is small.
void fit_axis(const std::vector<double>& p, const std::vector<double>& d, double c, double& s, double& t) {
  const double n = double(p.size());
  double mp = 0, md = 0;
  for (std::size_t k = 0; k < p.size(); ++k) {
    mp += p[k] - c;
    md += d[k] - c;
  }
  mp /= n;
  md /= n;
  double spp = 0, spd = 0;
  for (std::size_t k = 0; k < p.size(); ++k) {
    spp += (p[k] - c - mp) * (p[k] - c - mp);
    spd += (p[k] - c - mp) * (d[k] - c - md);
  }
  s = (spp / n > 100.0) ? std::clamp(spd / spp, 0.7, 1.4) : 1.0;
  t = md - s * mp;
}

// The paper's eq. 13-14 correction, robustly: RANSAC over 2-point samples, then least squares.
bool fit_scale_shift(const std::vector<cv::Point2f>& src, const std::vector<cv::Point2f>& dst,
                     double thr, ScaleShift& best, std::vector<uchar>& inliers) {
  const int n = int(src.size());
  if (n < 2) return false;
  ScaleShift base;
  for (const auto& p : src) {
    base.cx += p.x / n;
    base.cy += p.y / n;
  }
  std::mt19937 rng(12345);
  std::uniform_int_distribution<int> pick(0, n - 1);
  int best_count = -1;
  auto count = [&](const ScaleShift& m, std::vector<uchar>* mask) {
    int c = 0;
    for (int k = 0; k < n; ++k) {
      const cv::Point2d q = m.apply(src[k]);
      const bool in = std::hypot(q.x - dst[k].x, q.y - dst[k].y) < thr;
      c += in;
      if (mask) (*mask)[k] = in;
    }
    return c;
  };
  for (int it = 0; it < 500; ++it) {
    const int a = pick(rng), b = pick(rng);
    ScaleShift m = base;
    auto axis = [&](double pa, double pb, double da, double db, double c, double& s, double& t) {
      s = std::abs(pb - pa) > 20 ? (db - da) / (pb - pa) : 1.0;
      if (s < 0.7 || s > 1.4) s = 1.0;
      t = da - (s * (pa - c) + c);
    };
    axis(src[a].x, src[b].x, dst[a].x, dst[b].x, m.cx, m.sx, m.tx);
    axis(src[a].y, src[b].y, dst[a].y, dst[b].y, m.cy, m.sy, m.ty);
    const int c = count(m, nullptr);
    if (c > best_count) {
      best_count = c;
      best = m;
    }
  }
  inliers.assign(n, 0);
  for (int round = 0; round < 3; ++round) {
    count(best, &inliers);
    std::vector<double> px, py, dx, dy;
    for (int k = 0; k < n; ++k)
      if (inliers[k]) {
        px.push_back(src[k].x);
        py.push_back(src[k].y);
        dx.push_back(dst[k].x);
        dy.push_back(dst[k].y);
      }
    if (px.size() < 2) return false;
    fit_axis(px, dx, best.cx, best.sx, best.tx);
    fit_axis(py, dy, best.cy, best.sy, best.ty);
  }
  count(best, &inliers);
  return true;
}

double rms_of(const std::vector<cv::Point2f>& src, const std::vector<cv::Point2f>& dst,
              const std::vector<uchar>& inl, const Eigen::Matrix3d& C) {
  double sum = 0;
  int n = 0;
  for (std::size_t k = 0; k < src.size(); ++k) {
    if (!inl[k]) continue;
    Eigen::Vector2d q = apply_homography(C, {src[k].x, src[k].y});
    sum += (q - Eigen::Vector2d(dst[k].x, dst[k].y)).squaredNorm();
    ++n;
  }
  return n ? std::sqrt(sum / n) : 0;
}

// Overlap graph edges from the current homographies, weighted by overlap area.
std::vector<OverlapEdge> overlap_edges(const Rig& rig) {
  std::vector<OverlapEdge> edges;
  const int n = int(rig.cameras.size());
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      cv::Rect2d box = overlap_box(rig, a, b);
      if (box.area() > 0) edges.push_back({a, b, box.area()});
    }
  return edges;
}

void check_frames(const std::vector<ImageView>& frames) {
  for (std::size_t i = 0; i < frames.size(); ++i)
    if (frames[i].empty()) throw RigError("camera " + std::to_string(i) + " has no frame to calibrate on");
}

// Half the diagonal field of view of a camera, radians.
double half_diagonal_fov(const Camera& c) {
  return std::atan(0.5 * std::hypot(c.width / c.fx, c.height / c.fy));
}

constexpr double kPi = 3.14159265358979323846;
// Keypoints up to this size (pixels) weigh fully in the bundle adjustment, larger (coarser, less
// precisely placed) ones in inverse proportion to their size. Measured on rendered rigs
// (BENCHMARKS.md): 3-6 px all help, 4 is kept; unweighted, the worst corner error was 1.9 px.
constexpr double kWeightSize = 4.0;

Eigen::Matrix3d to_eigen(const cv::Mat& m) {
  Eigen::Matrix3d e;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) e(r, c) = m.at<double>(r, c);
  return e;
}

// A pairwise homography of a wide rotating rig may send part of the view to infinity (it looks
// past the other camera's plane): only the matched region must map sanely (in front, not mirrored).
bool homography_sane_on(const Eigen::Matrix3d& H, const std::vector<Eigen::Vector2d>& pts) {
  if (!H.allFinite() || pts.empty()) return false;
  double x0 = pts[0].x(), x1 = x0, y0 = pts[0].y(), y1 = y0;
  for (const auto& p : pts) {
    x0 = std::min(x0, p.x());
    x1 = std::max(x1, p.x());
    y0 = std::min(y0, p.y());
    y1 = std::max(y1, p.y());
  }
  const Eigen::Vector2d c[4] = {{x0, y0}, {x1, y0}, {x1, y1}, {x0, y1}};
  const double w0 = (H * Eigen::Vector3d(c[0].x(), c[0].y(), 1)).z();
  Eigen::Vector2d q[4];
  for (int k = 0; k < 4; ++k) {
    const Eigen::Vector3d v = H * Eigen::Vector3d(c[k].x(), c[k].y(), 1);
    if (!(v.z() * w0 > 0)) return false;
    q[k] = v.head<2>() / v.z();
  }
  double area = 0;
  for (int k = 0; k < 4; ++k) area += q[k].x() * q[(k + 1) % 4].y() - q[(k + 1) % 4].x() * q[k].y();
  return area > 0;  // the box's corners keep their (clockwise in image coordinates) order
}

// Matches of one camera pair, pooled over the frame sets: the RANSAC homography's inliers that
// agree with the expected geometry (when there is one). Every holdout_every-th is held out: it
// judges the models and fits none.
struct PairData {
  int a = -1, b = -1;
  int matches = 0, inliers = 0;
  bool ok = false;
  Eigen::Matrix3d H = Eigen::Matrix3d::Identity();  // a -> b pixels (RANSAC, all inliers)
  std::vector<Eigen::Vector2d> pa, pb;  // IDEAL pixels (undistorted through the rig's lenses)
  std::vector<Eigen::Vector2d> ra, rb;  // the raw keypoints (filled when a camera has a lens)
  std::vector<double> weight;  // 1 / the keypoints' scale (SIFT localises coarse blobs worse)
  std::vector<char> held;
  std::string note;
  // Ray path (wide lenses): pa/pb hold the raw pixels too, H is unused; residuals go through
  // the lenses (raw pixel -> ray -> raw pixel).
  bool rays = false;
  // Correspondences from an area alignment of the overlap (close_pairs_by_area), not features.
  bool area = false;
  int held_count() const { return int(std::count(held.begin(), held.end(), 1)); }
};

using FeatureSets = std::vector<std::vector<Features>>;  // [set][camera]

// Whole-frame detections of recent frames, by content and options: a file's failed first
// attempt is retried on the frame sets tried before plus a new one, and the lens test and fit
// detect on the first calibration's frames again (ering5ov8: 4 attempts on 1, 2, 3, 4 sets).
// The same pixels and options give the same features. Bounded; the oldest are forgotten.
class DetectionCache {
 public:
  static std::uint64_t key(const ImageView& v, const CalibrationOptions& o) {
    std::uint64_t h = 1469598103934665603ull;  // FNV-1a over 64-bit words
    const auto mix = [&h](std::uint64_t w) { h = (h ^ w) * 1099511628211ull; };
    mix(std::uint64_t(v.width) << 32 | std::uint32_t(v.height));
    mix(std::uint64_t(v.format));
    mix(std::uint64_t(o.features) << 32 | std::uint32_t(o.max_features));
    mix(std::uint64_t(o.feature_megapixels * 1e6));
    const std::size_t row_bytes = std::size_t(v.width) * 4, words = row_bytes / 8;
    for (int y = 0; y < v.height; ++y) {
      const std::uint8_t* r = v.row(y);
      std::uint64_t w;
      for (std::size_t k = 0; k < words; ++k) {
        std::memcpy(&w, r + 8 * k, 8);
        mix(w);
      }
      for (std::size_t k = 8 * words; k < row_bytes; ++k) mix(r[k]);
    }
    return h;
  }
  std::optional<Features> find(std::uint64_t key) {
    std::lock_guard<std::mutex> g(lock_);
    for (const auto& e : entries_)
      if (e.key == key) return e.features;
    return std::nullopt;
  }
  void put(std::uint64_t key, const Features& f) {
    std::lock_guard<std::mutex> g(lock_);
    const std::size_t bytes = f.descriptors.total() * f.descriptors.elemSize() + f.keypoints.size() * sizeof(cv::KeyPoint);
    entries_.push_back({key, f, bytes});
    bytes_ += bytes;
    while (bytes_ > kMaxBytes && entries_.size() > 1) {
      bytes_ -= entries_.front().bytes;
      entries_.pop_front();
    }
  }

 private:
  static constexpr std::size_t kMaxBytes = std::size_t(64) << 20;  // ~30 frames of 4000 SIFT features
  struct Entry {
    std::uint64_t key;
    Features features;
    std::size_t bytes;
  };
  std::mutex lock_;
  std::deque<Entry> entries_;
  std::size_t bytes_ = 0;
};

FeatureSets detect_all(const std::vector<std::vector<ImageView>>& sets, int n, const CalibrationOptions& o) {
  static DetectionCache cache;
  FeatureSets feats(sets.size(), std::vector<Features>(n));
  for (std::size_t t = 0; t < sets.size(); ++t)
    for (int i = 0; i < n; ++i) {
      const ImageView& v = sets[t][i];
      const bool cacheable = !v.on_device && v.format == PixelFormat::RGBA8 && !v.empty();
      const std::uint64_t key = cacheable ? DetectionCache::key(v, o) : 0;
      if (cacheable) {
        if (std::optional<Features> f = cache.find(key)) {
          throw_if_cancelled(o);
          feats[t][i] = std::move(*f);
          continue;
        }
      }
      feats[t][i] = detect(to_gray(v), cv::Mat(), o);
      if (cacheable) cache.put(key, feats[t][i]);
    }
  return feats;
}

// `predicted`: the rough a -> b homography; matches farther than `tolerance` px from it are
// dropped (a repeated texture elsewhere in the view would pull the pair together wrongly).
constexpr double kLensUnknownRansacScale = 4.0;

// `lens_rig`: cameras whose lenses undistort the keypoints before every fit (null: pinhole).
PairData match_pair(const FeatureSets& feats, int a, int b, const CalibrationOptions& o,
                    const Eigen::Matrix3d* predicted, double tolerance, const Rig* lens_rig = nullptr,
                    double ransac_scale = 1.0) {
  throw_if_cancelled(o);
  PairData p;
  p.a = a;
  p.b = b;
  const bool lens = lens_rig && any_lens(*lens_rig);
  std::vector<cv::Point2f> pa, pb, raw_a, raw_b;
  std::vector<double> size;
  for (const auto& f : feats)
    for (const auto& mt : match(f[a], f[b], o.features)) {
      const cv::Point2f qa = f[a].keypoints[mt.queryIdx].pt, qb = f[b].keypoints[mt.trainIdx].pt;
      cv::Point2f ia = qa, ib = qb;
      if (lens && (!ideal_of(lens_rig->cameras[a], qa, ia) || !ideal_of(lens_rig->cameras[b], qb, ib))) continue;
      pa.push_back(ia);
      pb.push_back(ib);
      raw_a.push_back(qa);
      raw_b.push_back(qb);
      size.push_back(0.5 * (f[a].keypoints[mt.queryIdx].size + f[b].keypoints[mt.trainIdx].size));
    }
  p.matches = int(pa.size());
  if (pa.size() < 8) {
    p.note = "too few feature matches (" + std::to_string(pa.size()) + ")";
    return p;
  }
  std::vector<uchar> inl;
  cv::Mat H = cv::findHomography(pa, pb, cv::RANSAC, o.ransac_threshold_px * ransac_scale, inl, 2000, 0.995);
  if (H.empty()) {
    p.note = "no consistent homography in " + std::to_string(pa.size()) + " matches";
    return p;
  }
  p.H = to_eigen(H);
  p.inliers = cv::countNonZero(inl);
  int kept = 0;
  for (std::size_t k = 0; k < pa.size(); ++k) {
    if (!inl[k]) continue;
    const Eigen::Vector2d qa(pa[k].x, pa[k].y), qb(pb[k].x, pb[k].y);
    if (predicted && (apply_homography(*predicted, qa) - qb).norm() > tolerance) continue;
    p.pa.push_back(qa);
    p.pb.push_back(qb);
    if (lens) {
      p.ra.emplace_back(raw_a[k].x, raw_a[k].y);
      p.rb.emplace_back(raw_b[k].x, raw_b[k].y);
    }
    p.weight.push_back(std::min(1.0, kWeightSize / std::max(size[k], 1e-3)));
    const int every = std::max(o.holdout_every, 0);
    p.held.push_back(every >= 2 && kept % every == every / 2);
    ++kept;
  }
  // Small views give few matches: a pair whose inliers are most of its matches counts too
  // (OpenCV's confidence test, inliers > 8 + 0.3 matches).
  if (kept < o.min_inliers && !(kept >= 10 && kept > 8 + 0.3 * p.matches)) {
    p.note = predicted ? "too few matches that agree with the rough rig (" + std::to_string(kept) + ")"
                       : "too few consistent matches (" + std::to_string(kept) + ", need " +
                             std::to_string(o.min_inliers) + ")";
    return p;
  }
  if (!predicted && !homography_sane_on(p.H, p.pa)) {
    p.note = "the matches give a degenerate homography";
    return p;
  }
  p.ok = true;
  return p;
}

// A pair refused for too few consistent matches, looked at again once the other pairs have
// placed both cameras: of its matches within `tolerance` px of `predicted` (a -> b pixels from
// the fitted rotations), the largest group that differs from the prediction by one shift (within
// kRescueShiftPx: over a seam a small rotation error is nearly a shift) is kept when it holds at
// least kRescueMinInliers. Chance does not put that many matches within a few pixels of one shift
// of a geometry fitted without them (a random match lands in such a disc with p ~ 0.02); without
// them a 360-degree ring's closing pair is tied by nothing and takes the ring's whole closure
// error on one seam (probe4: 8-21 px there, 0.2-0.4 px on the fitted pairs, no warning).
constexpr int kRescueMinInliers = 6;
constexpr double kRescueTolerancePx = 40.0, kRescueShiftPx = 5.0;
PairData rematch_pair_near(const FeatureSets& feats, int a, int b, const CalibrationOptions& o,
                           const Eigen::Matrix3d& predicted, double tolerance) {
  PairData p;
  p.a = a;
  p.b = b;
  std::vector<Eigen::Vector2d> pa, pb, shift;
  std::vector<double> size;
  for (const auto& f : feats)
    for (const auto& mt : match(f[a], f[b], o.features)) {
      const cv::Point2f qa = f[a].keypoints[mt.queryIdx].pt, qb = f[b].keypoints[mt.trainIdx].pt;
      ++p.matches;
      const Eigen::Vector3d h = predicted * Eigen::Vector3d(qa.x, qa.y, 1.0);
      if (!(h.z() > 1e-9)) continue;
      const Eigen::Vector2d d = Eigen::Vector2d(qb.x, qb.y) - h.head<2>() / h.z();
      if (d.norm() > tolerance) continue;
      pa.emplace_back(qa.x, qa.y);
      pb.emplace_back(qb.x, qb.y);
      shift.push_back(d);
      size.push_back(0.5 * (f[a].keypoints[mt.queryIdx].size + f[b].keypoints[mt.trainIdx].size));
    }
  // The shift most matches agree with.
  std::vector<int> best;
  for (std::size_t k = 0; k < shift.size(); ++k) {
    std::vector<int> in;
    for (std::size_t j = 0; j < shift.size(); ++j)
      if ((shift[j] - shift[k]).norm() <= kRescueShiftPx) in.push_back(int(j));
    if (in.size() > best.size()) best = std::move(in);
  }
  if (int(best.size()) < kRescueMinInliers) return p;
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (int k : best) mean += shift[std::size_t(k)];
  mean /= double(best.size());
  Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
  T.block<2, 1>(0, 2) = mean;
  p.H = T * predicted;
  p.inliers = int(best.size());
  const int every = std::max(o.holdout_every, 0);
  int kept = 0;
  for (int k : best) {
    p.pa.push_back(pa[std::size_t(k)]);
    p.pb.push_back(pb[std::size_t(k)]);
    p.weight.push_back(std::min(1.0, kWeightSize / std::max(size[std::size_t(k)], 1e-3)));
    p.held.push_back(every >= 2 && kept % every == every / 2);
    ++kept;
  }
  p.ok = true;
  p.note = "kept: " + std::to_string(kept) + " matches agree with the rotations the other pairs fit";
  return p;
}

// Whether the rig's rotations overlap pinhole views a and b (a 9 x 9 grid of A, at least 3
// points in B).
bool rotations_overlap(const Rig& rig, int a, int b, double margin_px = 0) {
  const Camera &A = rig.cameras[std::size_t(a)], &B = rig.cameras[std::size_t(b)];
  const Eigen::Matrix3d Hab = B.K() * B.R().transpose() * A.R() * A.K().inverse();
  int seen = 0;
  for (int gy = 0; gy < 9; ++gy)
    for (int gx = 0; gx < 9; ++gx) {
      const Eigen::Vector3d q = Hab * Eigen::Vector3d((A.width - 1) * gx / 8.0, (A.height - 1) * gy / 8.0, 1.0);
      if (q.z() > 1e-9 && q.x() >= -margin_px * q.z() && q.y() >= -margin_px * q.z() &&
          q.x() <= (B.width - 1 + margin_px) * q.z() && q.y() <= (B.height - 1 + margin_px) * q.z())
        ++seen;
    }
  return seen >= 3;
}

// Every refused pinhole pair whose views the fitted rotations overlap, matched again near that
// geometry (rematch_pair_near); true when one was kept.
bool rescue_pairs_by_rotations(const Rig& rig, const FeatureSets& feats, std::vector<PairData>& pairs,
                               const CalibrationOptions& o) {
  bool any = false;
  for (auto& p : pairs) {
    if (p.ok || p.rays) continue;
    const Camera &A = rig.cameras[std::size_t(p.a)], &B = rig.cameras[std::size_t(p.b)];
    if (!A.lens.pinhole() || !B.lens.pinhole()) continue;
    const Eigen::Matrix3d Hab = B.K() * B.R().transpose() * A.R() * A.K().inverse();
    if (!rotations_overlap(rig, p.a, p.b)) continue;
    PairData q = rematch_pair_near(feats, p.a, p.b, o, Hab, kRescueTolerancePx);
    if (!q.ok) continue;
    p = std::move(q);
    any = true;
  }
  return any;
}

// Ring closure (area_align.hpp). The search range: closure errors of 20-50 px were measured on
// 640 px views (probe4: 4 x hfov 100, 6 x hfov 65), so an eighth of the wider view.
constexpr double kAreaSearchFraction = 0.2;
constexpr double kAreaRefineSearchPx = 8.0;  // the second pass, through the refit
constexpr double kTiedSearchPx = 16.0;       // checking a pair that feature matches tie
// A pair this far off where the views overlap is reported (a seam a viewer sees); a rig joined on
// a looser pass (bridge_sparse_pairs) is kept only when every overlap is within kVerifiedPx.
constexpr double kMisalignedPx = 3.0, kVerifiedPx = 2.0;

AreaAlignment align_pair_by_area(const Rig& rig, int a, int b, const std::vector<cv::Mat>& gray, double search_px) {
  AreaAlignOptions ao;
  ao.search_px = search_px;
  return align_overlap_by_area(rig.cameras[std::size_t(a)], rig.cameras[std::size_t(b)], gray[std::size_t(a)],
                               gray[std::size_t(b)], ao);
}
double area_search_px(const Rig& rig, int a, int b) {
  return kAreaSearchFraction * std::max(rig.cameras[std::size_t(a)].width, rig.cameras[std::size_t(b)].width);
}

// An area alignment's correspondences as a usable pair (fitted like feature matches).
PairData pair_from_area(int a, int b, const AreaAlignment& al, const CalibrationOptions& o, int feature_matches) {
  PairData p;
  p.a = a;
  p.b = b;
  p.matches = feature_matches;
  p.inliers = al.agreeing;
  p.area = true;
  p.pa = al.pa;
  p.pb = al.pb;
  std::vector<cv::Point2f> s, d;
  for (std::size_t k = 0; k < al.pa.size(); ++k) {
    s.emplace_back(float(al.pa[k].x()), float(al.pa[k].y()));
    d.emplace_back(float(al.pb[k].x()), float(al.pb[k].y()));
  }
  const cv::Mat H = s.size() >= 8 ? cv::findHomography(s, d, 0) : cv::Mat();
  if (!H.empty()) p.H = to_eigen(H);
  const int every = std::max(o.holdout_every, 0);
  for (std::size_t k = 0; k < al.pa.size(); ++k) {
    p.weight.push_back(1.0);
    p.held.push_back(every >= 2 && int(k) % every == every / 2);
  }
  p.ok = true;
  p.note = "kept: the overlap aligned by area (" + std::to_string(al.agreeing) + " patches agree, " +
           std::to_string(al.offset_px).substr(0, 5) + " px off the rotations the other pairs fit)";
  return p;
}

// Every refused pinhole pair whose views the fitted rotations overlap, aligned by area over a
// range wide enough for a ring's closure error; the measured ones become usable pairs. A 360-degree
// ring's closing pair then ties its seam and the shared focal length follows the closure. True
// when one was kept.
bool close_pairs_by_area(const Rig& rig, const std::vector<cv::Mat>& gray, std::vector<PairData>& pairs,
                         const CalibrationOptions& o) {
  bool any = false;
  for (auto& p : pairs) {
    throw_if_cancelled(o);
    // Within the search range: a ring that does not close may predict its closing views apart.
    const double search = area_search_px(rig, p.a, p.b);
    if (p.ok || p.rays || !rotations_overlap(rig, p.a, p.b, search)) continue;
    const AreaAlignment al = align_pair_by_area(rig, p.a, p.b, gray, search);
    if (!al.measured) continue;
    p = pair_from_area(p.a, p.b, al, o, p.matches);
    any = true;
  }
  return any;
}

// The area pairs placed again through a refit (the patches warped with the better geometry,
// searched near it): their correspondences then hold to a fraction of a pixel.
void refresh_area_pairs(const Rig& rig, const std::vector<cv::Mat>& gray, std::vector<PairData>& pairs,
                        const CalibrationOptions& o) {
  for (auto& p : pairs) {
    if (!p.area || !p.ok) continue;
    const AreaAlignment al = align_pair_by_area(rig, p.a, p.b, gray, kAreaRefineSearchPx);
    if (al.measured) p = pair_from_area(p.a, p.b, al, o, p.matches);
  }
}

// How far off the rig is where the views of each pair overlap, measured on the pictures: every
// pair that feature matches do not tie (`all`: every pair), whose views the rig overlaps.
struct OverlapCheck {
  int a = -1, b = -1;
  AreaAlignment al;
};
std::vector<OverlapCheck> check_overlaps(const Rig& rig, const std::vector<cv::Mat>& gray,
                                         const std::vector<PairData>& pairs, bool all) {
  std::vector<OverlapCheck> out;
  for (const auto& p : pairs) {
    if (p.rays || (p.ok && !p.area && !all)) continue;
    if (!rig.cameras[std::size_t(p.a)].lens.pinhole() || !rig.cameras[std::size_t(p.b)].lens.pinhole()) continue;
    if (!rotations_overlap(rig, p.a, p.b)) continue;
    OverlapCheck c;
    c.a = p.a;
    c.b = p.b;
    // A pair the features tie cannot be far off: a narrow search (the wide one's template, most
    // of it beyond a thin overlap, correlates weakly).
    c.al = align_pair_by_area(rig, p.a, p.b, gray, p.ok && !p.area ? kTiedSearchPx : area_search_px(rig, p.a, p.b));
    out.push_back(std::move(c));
  }
  return out;
}

Eigen::Matrix3d nearest_rotation(const Eigen::Matrix3d& M);

// Half the field of view (radians) a camera sees through its lens: the largest angle off the
// axis of a frame corner or the image circle's rim (pinhole: the half diagonal).
double lens_half_fov(const Camera& c) {
  if (c.lens.pinhole()) return half_diagonal_fov(c);
  const double far = lens_far_radius(c);
  // Step in from the farthest normalised radius until the lens unprojects it.
  for (double t = far; t > 0.05 * far; t *= 0.97) {
    Eigen::Vector3d ray;
    if (lens_unproject(c, {c.cx + t * c.fx, c.cy}, ray)) return std::acos(std::clamp(ray.z(), -1.0, 1.0));
  }
  return half_diagonal_fov(c);
}

// Fisheyes and lenses of ~150 degrees or more: ideal pinhole pixels are missing (>= 90 degrees
// off the axis) or stretched past use, so such pairs are matched on rays.
constexpr double kRayMatchFovDeg = 150.0;
bool needs_rays(const Camera& c) {
  if (c.lens.pinhole()) return false;
  return c.lens.model == Lens::Model::Fisheye || 2 * lens_half_fov(c) * 180 / kPi >= kRayMatchFovDeg;
}

// Rotation Q minimising sum |Q a_k - b_k|^2 over `idx` (Kabsch).
Eigen::Matrix3d kabsch(const std::vector<Eigen::Vector3d>& a, const std::vector<Eigen::Vector3d>& b,
                       const std::vector<int>& idx) {
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  for (int k : idx) M += b[k] * a[k].transpose();
  return nearest_rotation(M);
}

// A rotation taking rays ua[k] to ub[k], for k in `candidates`: a RANSAC over 2-ray rotations
// (Kabsch; pairs of rays ~3 degrees apart or more) from `start`: the largest set of candidates
// within cos_thr of one rotation (start's own set unless a sample beats it).
std::vector<int> ray_rotation_inliers(const std::vector<Eigen::Vector3d>& ua, const std::vector<Eigen::Vector3d>& ub,
                                      const std::vector<int>& candidates, const Eigen::Matrix3d& start, double cos_thr,
                                      int iterations) {
  auto inliers_of = [&](const Eigen::Matrix3d& Q, std::vector<int>& in) {
    in.clear();
    for (int k : candidates)
      if ((Q * ua[std::size_t(k)]).dot(ub[std::size_t(k)]) >= cos_thr) in.push_back(k);
  };
  std::vector<int> best, in;
  inliers_of(start, best);
  if (candidates.empty()) return best;
  std::mt19937 rng(12345);
  std::uniform_int_distribution<int> pick(0, int(candidates.size()) - 1);
  for (int it = 0; it < iterations; ++it) {
    const int i = candidates[std::size_t(pick(rng))], j = candidates[std::size_t(pick(rng))];
    if (ua[std::size_t(i)].cross(ua[std::size_t(j)]).norm() < 0.05 || ub[std::size_t(i)].cross(ub[std::size_t(j)]).norm() < 0.05)
      continue;
    const Eigen::Matrix3d Qs = kabsch(ua, ub, {i, j});
    inliers_of(Qs, in);
    if (in.size() > best.size()) best = in;
  }
  return best;
}

// Every match of views a and b over the frame sets, as camera-frame rays through the lenses
// of A and B (matches a lens does not see are skipped): fn(ray_a, ray_b, keypoint_a, keypoint_b).
template <typename Fn>
void for_each_matched_ray(const FeatureSets& feats, int a, int b, const CalibrationOptions& o, const Camera& A,
                          const Camera& B, Fn&& fn) {
  for (const auto& f : feats)
    for (const auto& mt : match(f[a], f[b], o.features)) {
      const cv::KeyPoint &ka = f[a].keypoints[mt.queryIdx], &kb = f[b].keypoints[mt.trainIdx];
      Eigen::Vector3d ra, rb;
      if (!lens_sees(A, ka.pt.x, ka.pt.y) || !lens_sees(B, kb.pt.x, kb.pt.y)) continue;
      if (!lens_unproject(A, {ka.pt.x, ka.pt.y}, ra) || !lens_unproject(B, {kb.pt.x, kb.pt.y}, rb)) continue;
      fn(ra, rb, ka, kb);
    }
}

// Matches of a pair of wide-lens cameras on unit rays (issue 15, dual fisheye): raw keypoints
// -> rays through `rig`'s lenses; the ones the rig's rotations put within `tolerance_rad` are
// kept, then a RANSAC over 2-ray rotations (Kabsch, angular threshold `thr_rad`) picks the
// consistent ones. No pinhole pixel is needed, so rays 90 degrees or more off an axis (all of a
// back-to-back pair's overlap) match as well as central ones.
PairData match_pair_rays(const FeatureSets& feats, int a, int b, const CalibrationOptions& o, const Rig& rig,
                         double thr_rad, double tolerance_rad) {
  throw_if_cancelled(o);
  PairData p;
  p.a = a;
  p.b = b;
  p.rays = true;
  const Camera &A = rig.cameras[a], &B = rig.cameras[b];
  const Eigen::Matrix3d Q0 = B.R().transpose() * A.R();  // camera a frame -> camera b frame
  std::vector<Eigen::Vector3d> ua, ub;
  std::vector<Eigen::Vector2d> raw_a, raw_b;
  std::vector<double> size;
  const double cos_tol = std::cos(tolerance_rad);
  int matched = 0;
  for_each_matched_ray(feats, a, b, o, A, B,
                       [&](const Eigen::Vector3d& ra, const Eigen::Vector3d& rb, const cv::KeyPoint& ka, const cv::KeyPoint& kb) {
                         ++matched;
                         if ((Q0 * ra).dot(rb) < cos_tol) return;  // not where the rough rig puts it
                         ua.push_back(ra);
                         ub.push_back(rb);
                         raw_a.emplace_back(ka.pt.x, ka.pt.y);
                         raw_b.emplace_back(kb.pt.x, kb.pt.y);
                         size.push_back(0.5 * (ka.size + kb.size));
                       });
  p.matches = matched;
  const int n = int(ua.size());
  if (n < 8) {
    p.note = "too few feature matches that agree with the rough rig (" + std::to_string(n) + " of " +
             std::to_string(matched) + ", on rays)";
    return p;
  }
  const double cos_thr = std::cos(thr_rad);
  std::vector<int> all(static_cast<std::size_t>(n));
  std::iota(all.begin(), all.end(), 0);
  std::vector<int> best = ray_rotation_inliers(ua, ub, all, Q0, cos_thr, 1000);
  for (int round = 0; round < 3 && best.size() >= 3; ++round)
    best = ray_rotation_inliers(ua, ub, all, kabsch(ua, ub, best), cos_thr, 0);
  p.inliers = int(best.size());
  int kept = 0;
  for (int k : best) {
    p.pa.push_back(raw_a[k]);
    p.pb.push_back(raw_b[k]);
    p.ra.push_back(raw_a[k]);
    p.rb.push_back(raw_b[k]);
    p.weight.push_back(std::min(1.0, kWeightSize / std::max(size[k], 1e-3)));
    const int every = std::max(o.holdout_every, 0);
    p.held.push_back(every >= 2 && kept % every == every / 2);
    ++kept;
  }
  if (kept < o.min_inliers && !(kept >= 10 && kept > 8 + 0.3 * n)) {
    p.note = "too few matches that agree with the rough rig (" + std::to_string(kept) + ", on rays)";
    return p;
  }
  p.ok = true;
  return p;
}

// Lens estimation needs matches over this range of angles off the axis (5th to 95th percentile).
constexpr double kMinLensEstimateSpreadRad = 35.0 * kPi / 180.0;

// The 5th-95th percentile range (radians) of the angles off camera `cam`'s axis of its accepted
// matches' rays (through `c`'s rough lens).
double ray_angle_spread(const Camera& c, int cam, const std::vector<PairData>& pairs) {
  std::vector<double> th;
  for (const auto& p : pairs) {
    if (!p.ok || (p.a != cam && p.b != cam) || p.ra.size() != p.pa.size()) continue;
    for (const auto& q : p.a == cam ? p.ra : p.rb) {
      Eigen::Vector3d ray;
      if (lens_unproject(c, q, ray)) th.push_back(std::acos(std::clamp(ray.z(), -1.0, 1.0)));
    }
  }
  if (th.size() < 20) return 0;
  std::sort(th.begin(), th.end());
  return th[th.size() * 95 / 100] - th[th.size() * 5 / 100];
}

// Raw pixel of camera `from` -> raw pixel of camera `to` through both lenses and rotations.
bool raw_transfer(const Rig& rig, int from, int to, const Eigen::Vector2d& p, Eigen::Vector2d& q) {
  const Camera &F = rig.cameras[from], &T = rig.cameras[to];
  Eigen::Vector3d ray;
  if (!lens_unproject(F, p, ray)) return false;
  return lens_project(T, T.R().transpose() * (F.R() * ray), q);
}

// The fitted (not held-out) matches of the accepted pairs, at most `cap` a pair spread over the
// list: enough for the rotation model's 4 parameters a camera.
std::vector<PairMatches> training_matches(const std::vector<PairData>& pairs, std::size_t cap = 300) {
  std::vector<PairMatches> out;
  for (const auto& p : pairs) {
    if (!p.ok) continue;
    PairMatches m;
    m.a = p.a;
    m.b = p.b;
    std::vector<std::size_t> idx;
    for (std::size_t k = 0; k < p.pa.size(); ++k)
      if (!p.held[k]) idx.push_back(k);
    const std::size_t take = std::min(cap, idx.size());
    for (std::size_t k = 0; k < take; ++k) {
      const std::size_t j = idx[k * idx.size() / take];
      m.pa.push_back(p.pa[j]);
      m.pb.push_back(p.pb[j]);
      m.weight.push_back(p.weight[j]);
      if (p.ra.size() == p.pa.size()) {
        m.ra.push_back(p.ra[j]);
        m.rb.push_back(p.rb[j]);
      }
    }
    out.push_back(std::move(m));
  }
  return out;
}

// Camera a pixels -> camera b pixels under a calibrated rig: the planar canvas's homographies,
// or K and R (rotation model).
Eigen::Matrix3d pair_map(const Rig& rig, int a, int b, bool rotation) {
  if (rotation || !rig.cameras[a].homography || !rig.cameras[b].homography) {
    const Camera &A = rig.cameras[a], &B = rig.cameras[b];
    return B.K() * B.R().transpose() * A.R() * A.K().inverse();
  }
  return rig.cameras[b].homography->inverse() * *rig.cameras[a].homography;
}

// One-way rms transfer error (camera pixels, each match's error capped at 10 px) of a rig on
// the accepted pairs' matches: held out (heldout = true) or fitted.
struct Residuals {
  double rms_px = -1;
  int count = 0;
  std::vector<double> pair_rms;               // per entry of `pairs`, -1 when none
  std::vector<double> camera_sum;             // squared-error sums per camera
  std::vector<int> camera_count;
};

Residuals residuals(const Rig& rig, const std::vector<PairData>& pairs, bool rotation, bool heldout) {
  Residuals r;
  const int n = int(rig.cameras.size());
  r.camera_sum.assign(n, 0);
  r.camera_count.assign(n, 0);
  double sum = 0;
  for (const auto& p : pairs) {
    double ps = 0;
    int pc = 0;
    if (p.ok) {
      if (p.rays) {
        // Wide lenses: raw pixel -> ray -> raw pixel, both ways (no pinhole pixels).
        for (std::size_t k = 0; k < p.ra.size(); ++k) {
          if (bool(p.held[k]) != heldout) continue;
          Eigen::Vector2d qb, qa;
          double e2 = 100.0;
          if (raw_transfer(rig, p.a, p.b, p.ra[k], qb) && raw_transfer(rig, p.b, p.a, p.rb[k], qa))
            e2 = 0.5 * ((qb - p.rb[k]).squaredNorm() + (qa - p.ra[k]).squaredNorm());
          ps += std::isfinite(e2) ? std::min(100.0, e2) : 100.0;
          ++pc;
        }
      }
      const Eigen::Matrix3d H = pair_map(rig, p.a, p.b, rotation), Hi = H.inverse();
      // With lenses: the raw keypoints undistorted through THIS rig's lenses and focal lengths
      // (an adjustment that refined them judges itself by its own ideal pixels).
      const bool lens = p.ra.size() == p.pa.size() && !p.ra.empty();
      for (std::size_t k = 0; k < p.pa.size() && !p.rays; ++k) {
        if (bool(p.held[k]) != heldout) continue;
        Eigen::Vector2d qa = p.pa[k], qb = p.pb[k];
        if (lens && (!undistort_point(rig.cameras[p.a], p.ra[k], qa) || !undistort_point(rig.cameras[p.b], p.rb[k], qb)))
          qa = p.pa[k], qb = p.pb[k];
        const double e2 = 0.5 * ((apply_homography(H, qa) - qb).squaredNorm() +
                                 (apply_homography(Hi, qb) - qa).squaredNorm());
        const double e = std::isfinite(e2) ? std::min(100.0, e2) : 100.0;
        ps += e;
        ++pc;
      }
    }
    r.pair_rms.push_back(pc ? std::sqrt(ps / pc) : -1);
    if (pc) {
      r.camera_sum[p.a] += ps;
      r.camera_sum[p.b] += ps;
      r.camera_count[p.a] += pc;
      r.camera_count[p.b] += pc;
    }
    sum += ps;
    r.count += pc;
  }
  if (r.count) r.rms_px = std::sqrt(sum / r.count);
  return r;
}

// The residuals the reports carry: held out when there are enough, else the fitted matches.
Residuals report_residuals(const Rig& rig, const std::vector<PairData>& pairs, bool rotation) {
  Residuals h = residuals(rig, pairs, rotation, true);
  if (h.count >= 20) {
    // Pairs with no held-out match of their own take their fitted residual.
    Residuals f = residuals(rig, pairs, rotation, false);
    for (std::size_t i = 0; i < h.pair_rms.size(); ++i)
      if (h.pair_rms[i] < 0) h.pair_rms[i] = f.pair_rms[i];
    return h;
  }
  return residuals(rig, pairs, rotation, false);
}

void fill_reports(CalibrationResult& res, const std::vector<PairData>& pairs, bool rotation) {
  const int n = int(res.rig.cameras.size());
  const Residuals r = report_residuals(res.rig, pairs, rotation);
  res.pairs.clear();
  res.cameras.assign(n, CameraReport{});
  for (int i = 0; i < n; ++i) res.cameras[i].camera = i;
  for (std::size_t i = 0; i < pairs.size(); ++i) {
    const PairData& p = pairs[i];
    if (!p.ok && p.matches == 0) continue;
    PairReport rep;
    rep.camera = p.b;
    rep.neighbour = p.a;
    rep.matches = p.matches;
    rep.inliers = p.ok ? int(p.pa.size()) : p.inliers;
    rep.accepted = p.ok;
    rep.rms_px = p.ok && r.pair_rms[i] >= 0 ? r.pair_rms[i] : 0;
    rep.note = p.note;
    res.pairs.push_back(rep);
    if (p.ok)
      for (int c : {p.a, p.b}) {
        res.cameras[c].neighbours++;
        res.cameras[c].matches += int(p.pa.size());
      }
  }
  for (int i = 0; i < n; ++i)
    if (r.camera_count[i]) res.cameras[i].rms_px = std::sqrt(r.camera_sum[i] / r.camera_count[i]);
}

// The overlap checks in the reports: each pair's measured offset, and a warning naming the two
// cameras for a pair far off (never a silent wrong seam: the fitted pairs' residuals do not see it).
void report_overlap_checks(CalibrationResult& res, const std::vector<OverlapCheck>& checks) {
  for (const auto& c : checks) {
    if (!c.al.measured) continue;
    PairReport* rep = nullptr;
    for (auto& r : res.pairs)
      if (r.camera == c.b && r.neighbour == c.a) rep = &r;
    if (!rep) {
      res.pairs.push_back(PairReport{});
      rep = &res.pairs.back();
      rep->camera = c.b;
      rep->neighbour = c.a;
      rep->note = "no feature matches";
    }
    rep->overlap_px = c.al.offset_px;
    if (c.al.offset_px > kMisalignedPx)
      res.warnings.push_back("cameras " + std::to_string(c.a) + " and " + std::to_string(c.b) + " are " +
                             std::to_string(c.al.offset_px).substr(0, 5) +
                             " px apart where their views overlap (measured on the pictures; too few feature "
                             "matches tie them): the seam between them will show it; give a rig-file or more "
                             "texture in that overlap");
  }
}

Eigen::Matrix3d nearest_rotation(const Eigen::Matrix3d& M) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d R = svd.matrixU() * svd.matrixV().transpose();
  if (R.determinant() < 0) {
    Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
    D(2, 2) = -1;
    R = svd.matrixU() * D * svd.matrixV().transpose();
  }
  return R;
}

std::vector<OverlapEdge> match_edges(const std::vector<PairData>& pairs) {
  std::vector<OverlapEdge> edges;
  for (const auto& p : pairs)
    if (p.ok) edges.push_back({p.a, p.b, double(p.pa.size())});
  return edges;
}

const PairData* find_pair(const std::vector<PairData>& pairs, int a, int b) {
  for (const auto& p : pairs)
    if (p.ok && ((p.a == a && p.b == b) || (p.a == b && p.b == a))) return &p;
  return nullptr;
}

// Camera `src` pixels -> camera `dst` pixels from the measured pair homography.
Eigen::Matrix3d measured_map(const PairData& p, int src) { return p.a == src ? p.H : Eigen::Matrix3d(p.H.inverse()); }

// Rotations from the measured pairwise homographies along the maximum spanning tree of the match
// graph, from the reference (its rotation kept), with the rig's K: K_p^-1 H_{c->p} K_c ~ R_p^T R_c.
void rotations_from_pairs(Rig& rig, const std::vector<PairData>& pairs) {
  const int n = int(rig.cameras.size());
  for (const auto& [cam, parent] : max_spanning_order(n, rig.reference, match_edges(pairs))) {
    const PairData* p = find_pair(pairs, cam, parent);
    const Camera &P = rig.cameras[parent];
    Camera& C = rig.cameras[cam];
    Eigen::Matrix3d M = P.K().inverse() * measured_map(*p, cam) * C.K();
    if (M.determinant() < 0) M = -M;
    C.set_R(P.R() * nearest_rotation(M));
  }
}

// Focal length estimates (pixels) from the measured homographies (OpenCV's estimate: the
// homography of two rotated cameras with centred principal points), one per pair where both
// ends give one.
std::vector<double> focal_estimates(const Rig& rig, const std::vector<PairData>& pairs) {
  std::vector<double> fs;
  for (const auto& p : pairs) {
    if (!p.ok) continue;
    const Camera &A = rig.cameras[p.a], &B = rig.cameras[p.b];
    Eigen::Matrix3d Ta = Eigen::Matrix3d::Identity(), Tb = Eigen::Matrix3d::Identity();
    Ta(0, 2) = -A.cx;
    Ta(1, 2) = -A.cy;
    Tb(0, 2) = -B.cx;
    Tb(1, 2) = -B.cy;
    const Eigen::Matrix3d Hc = Tb * p.H * Ta.inverse();
    cv::Mat H(3, 3, CV_64F);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) H.at<double>(r, c) = Hc(r, c);
    double f0 = 0, f1 = 0;
    bool ok0 = false, ok1 = false;
    cv::detail::focalsFromHomography(H, f0, f1, ok0, ok1);
    if (ok0 && ok1 && f0 > 0 && f1 > 0 && std::isfinite(f0 * f1)) fs.push_back(std::sqrt(f0 * f1));
  }
  return fs;
}

double median_of(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

struct RotationFit {
  Rig rig;
  BundleAdjustReport ba;
  bool ok = false;
  std::vector<std::string> warnings;
};

// How many cameras the usable pairs tie to `reference` (itself included), directly or through others.
int cameras_tied_to(const std::vector<PairData>& pairs, int n, int reference) {
  std::vector<bool> tied(std::size_t(n), false);
  if (reference < 0 || reference >= n) return 0;
  tied[std::size_t(reference)] = true;
  for (bool grew = true; grew;) {
    grew = false;
    for (const PairData& p : pairs)
      if (p.ok && tied[std::size_t(p.a)] != tied[std::size_t(p.b)]) tied[std::size_t(p.a)] = tied[std::size_t(p.b)] = grew = true;
  }
  return int(std::count(tied.begin(), tied.end(), true));
}

RotationFit adjust(const Rig& start, const std::vector<PairData>& pairs, const BundleAdjustOptions& options = {}) {
  RotationFit f;
  f.rig = start;
  const std::vector<PairMatches> train = training_matches(pairs);
  if (train.empty()) return f;
  f.ba = bundle_adjust(f.rig, train, options);
  f.ok = f.ba.ok;
  if (!f.ba.lens_warning.empty()) f.warnings.push_back(f.ba.lens_warning);
  return f;
}

// The best of several starts (the lowest rms after adjustment).
RotationFit best_of(RotationFit a, RotationFit b) {
  if (!b.ok) return a;
  if (!a.ok || b.ba.rms_after_px < a.ba.rms_after_px) return b;
  return a;
}

// Cameras the match graph leaves apart (rings of small overlaps: 6-12% of a 640 px view gives
// 8-15 consistent matches, under min_inliers, while pairs that see nothing in common reach 5-9
// by chance): a looser first pass. The refused pinhole pairs between the graph's parts with at
// least kBridgeMinInliers consistent matches, strongest first, join the parts (a spanning
// forest); the rotation model is fitted on every usable pair, and each joining pair is kept only
// when the fit explains its matches within kBridgePairPx rms (the rig's rms at most
// kBridgeRigPx). A pair the fit does not explain is struck off and the next strongest tried.
// Nothing changes on a graph that is already connected.
constexpr int kBridgeMinInliers = 8;
constexpr double kBridgePairPx = 1.5, kBridgeRigPx = 1.0;
constexpr int kBridgeTries = 8;
template <typename Fit>
bool bridge_sparse_pairs(int n, std::vector<PairData>& pairs, const Fit& fit_rotations) {
  std::vector<char> struck(pairs.size(), 0);
  for (int attempt = 0; attempt < kBridgeTries; ++attempt) {
    // The usable pairs' parts (union-find).
    std::vector<int> part(static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i) part[std::size_t(i)] = i;
    std::function<int(int)> root = [&](int i) { return part[std::size_t(i)] == i ? i : part[std::size_t(i)] = root(part[std::size_t(i)]); };
    int parts = n;
    for (const auto& p : pairs)
      if (p.ok && root(p.a) != root(p.b)) part[std::size_t(root(p.a))] = root(p.b), --parts;
    if (parts <= 1) return false;  // nothing apart
    std::vector<std::size_t> cand;
    for (std::size_t i = 0; i < pairs.size(); ++i) {
      const PairData& p = pairs[i];
      if (p.ok || p.rays || struck[i] || int(p.pa.size()) < kBridgeMinInliers || p.pa.size() != p.held.size()) continue;
      cand.push_back(i);
    }
    std::stable_sort(cand.begin(), cand.end(), [&](std::size_t x, std::size_t y) { return pairs[x].pa.size() > pairs[y].pa.size(); });
    std::vector<std::size_t> added;
    for (std::size_t i : cand) {
      const int ra = root(pairs[i].a), rb = root(pairs[i].b);
      if (ra == rb || !homography_sane_on(pairs[i].H, pairs[i].pa)) continue;  // joining pairs: a sane homography
      part[std::size_t(ra)] = rb;
      --parts;
      added.push_back(i);
    }
    if (parts > 1 || added.empty()) return false;  // still apart: the caller says so
    for (std::size_t i : added) pairs[i].ok = true;
    const auto fit = fit_rotations(pairs);
    bool all = fit.ok && fit.ba.rms_after_px <= kBridgeRigPx;
    if (fit.ok) {
      const Residuals r = residuals(fit.rig, pairs, true, false);
      for (std::size_t i : added)
        if (!(r.pair_rms[i] >= 0 && r.pair_rms[i] <= kBridgePairPx)) {
          struck[i] = 1;
          all = false;
        }
    }
    if (all) {
      for (std::size_t i : added)
        pairs[i].note = "kept on a looser pass: " + std::to_string(pairs[i].pa.size()) +
                        " consistent matches that the rotation fit explains";
      // The other such pairs whose views the fit overlaps (a ring's closing pair: left out, the
      // ring's whole closure error lands on its seam, 20-30 px on a 6-ring at 8% overlap), each
      // kept when the refit explains it and still explains the joining pairs.
      Rig rig = fit.rig;
      for (std::size_t i : cand) {
        if (pairs[i].ok || struck[i] || !rotations_overlap(rig, pairs[i].a, pairs[i].b)) continue;
        pairs[i].ok = true;
        const auto again = fit_rotations(pairs);
        bool keep = again.ok && again.ba.rms_after_px <= kBridgeRigPx;
        if (keep) {
          const Residuals r = residuals(again.rig, pairs, true, false);
          for (std::size_t j : added) keep &= r.pair_rms[j] >= 0 && r.pair_rms[j] <= kBridgePairPx;
          keep &= r.pair_rms[i] >= 0 && r.pair_rms[i] <= kBridgePairPx;
        }
        if (!keep) {
          pairs[i].ok = false;
          continue;
        }
        pairs[i].note = "kept on a looser pass: " + std::to_string(pairs[i].pa.size()) +
                        " consistent matches where the fitted rotations overlap the views, explained by the refit";
        rig = again.rig;
      }
      return true;
    }
    for (std::size_t i : added) pairs[i].ok = false;
    // A fit that failed as a whole strikes the weakest joining pair.
    if (!fit.ok || fit.ba.rms_after_px > kBridgeRigPx) {
      bool any_struck = false;
      for (std::size_t i : added) any_struck |= bool(struck[i]);
      if (!any_struck) struck[added.back()] = 1;
    }
  }
  return false;
}

// Expresses every rotation relative to camera `ref` (its rotation becomes the identity).
void rebase(Rig& rig, int ref) {
  const Eigen::Matrix3d Rt = rig.cameras[ref].R().transpose();
  for (auto& c : rig.cameras) c.set_R(Rt * c.R());
  rig.reference = ref;
}

// Headings relative to the rig's mean heading; the camera of the median one is its centre.
int median_heading_camera(const Rig& rig) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& c : rig.cameras) {
    const Eigen::Vector3d z = c.R().col(2);
    mean += Eigen::Vector3d(z.x(), 0, z.z()).normalized();
  }
  const double mean_yaw = mean.norm() > 1e-6 ? std::atan2(mean.x(), mean.z()) : 0.0;
  std::vector<std::pair<double, int>> yaws;
  for (std::size_t i = 0; i < rig.cameras.size(); ++i) {
    const Eigen::Vector3d z = rig.cameras[i].R().col(2);
    double d = std::atan2(z.x(), z.z()) - mean_yaw;
    d = std::remainder(d, 2 * kPi);
    yaws.emplace_back(d, int(i));
  }
  std::sort(yaws.begin(), yaws.end());
  return yaws[(yaws.size() - 1) / 2].second;
}

// The match graph's centre: the camera with the fewest spanning-tree hops to the farthest one
// (ties: the most matches).
int graph_centre(int n, const std::vector<PairData>& pairs) {
  const std::vector<OverlapEdge> edges = match_edges(pairs);
  std::vector<std::vector<int>> adj(n);
  for (const auto& [cam, parent] : max_spanning_order(n, 0, edges)) {
    adj[cam].push_back(parent);
    adj[parent].push_back(cam);
  }
  std::vector<double> weight(n, 0);
  for (const auto& e : edges) weight[e.a] += e.weight, weight[e.b] += e.weight;
  int best = 0, best_ecc = 1 << 30;
  for (int r = 0; r < n; ++r) {
    std::vector<int> depth(n, -1);
    std::queue<int> q;
    depth[r] = 0;
    q.push(r);
    int ecc = 0;
    while (!q.empty()) {
      const int u = q.front();
      q.pop();
      ecc = std::max(ecc, depth[u]);
      for (int v : adj[u])
        if (depth[v] < 0) depth[v] = depth[u] + 1, q.push(v);
    }
    if (ecc < best_ecc || (ecc == best_ecc && weight[r] > weight[best])) best = r, best_ecc = ecc;
  }
  return best;
}

// What a rotating rig covers: horizontal span (degrees; 360 for a closed ring), vertical span,
// the largest pitch of an optical axis, the largest angle of a view's border from the
// reference camera's axis (what stretches a planar canvas).
struct FieldOfView {
  double h_deg = 0, v_deg = 0, axis_pitch_deg = 0, off_reference_deg = 0;
  bool ring = false;
};

FieldOfView field_of_view(const Rig& rig) {
  FieldOfView f;
  constexpr int kBins = 720;
  std::vector<char> covered(kBins, 0);
  double pmin = 1e9, pmax = -1e9;
  const Eigen::Vector3d zref = rig.cameras[rig.reference].R().col(2);
  for (const auto& c : rig.cameras) {
    const Eigen::Matrix3d M = c.R() * c.K().inverse();
    const Eigen::Vector3d axis = c.R().col(2);
    f.axis_pitch_deg = std::max(f.axis_pitch_deg, std::abs(std::asin(std::clamp(-axis.y(), -1.0, 1.0))) * 180 / kPi);
    const double axis_yaw = std::atan2(axis.x(), axis.z());
    double ymin = 1e9, ymax = -1e9;
    for (int k = 0; k <= 64; ++k) {
      const double t = k / 64.0;
      const double w = c.width - 1, h = c.height - 1;
      for (const Eigen::Vector2d& p : {Eigen::Vector2d(t * w, 0), Eigen::Vector2d(t * w, h), Eigen::Vector2d(0, t * h),
                                       Eigen::Vector2d(w, t * h)}) {
        const Eigen::Vector3d r = (M * Eigen::Vector3d(p.x(), p.y(), 1)).normalized();
        const double yaw = std::remainder(std::atan2(r.x(), r.z()) - axis_yaw, 2 * kPi);
        ymin = std::min(ymin, yaw);
        ymax = std::max(ymax, yaw);
        const double pitch = std::asin(std::clamp(-r.y(), -1.0, 1.0));
        pmin = std::min(pmin, pitch);
        pmax = std::max(pmax, pitch);
        f.off_reference_deg = std::max(f.off_reference_deg, std::acos(std::clamp(r.dot(zref), -1.0, 1.0)) * 180 / kPi);
      }
    }
    // Looking straight up or down, a view covers every heading.
    if (std::abs(axis.y()) > 0.9) ymin = -kPi, ymax = kPi;
    for (double y = ymin; y <= ymax + 1e-9; y += kPi / kBins) {
      double a = axis_yaw + y;
      a -= std::floor(a / (2 * kPi)) * 2 * kPi;
      covered[std::min(kBins - 1, int(a / (2 * kPi) * kBins))] = 1;
    }
  }
  // The longest run of uncovered bins, around the circle.
  int longest = 0, run = 0;
  for (int k = 0; k < 2 * kBins; ++k) {
    run = covered[k % kBins] ? 0 : run + 1;
    longest = std::max(longest, std::min(run, kBins));
  }
  f.ring = longest == 0;
  f.h_deg = 360.0 * (kBins - longest) / kBins;
  f.v_deg = (pmax - pmin) * 180 / kPi;
  return f;
}

// Plane while the views fit on one (not absurdly stretched), cylindrical for wide rigs and
// rings, spherical for rigs that also look up or down.
Projection choose_projection(const FieldOfView& f) {
  const bool looks_up_down = f.axis_pitch_deg > 20 || f.v_deg > 120;
  if (!f.ring && f.h_deg <= 110 && f.v_deg <= 110 && f.off_reference_deg <= 65) return Projection::Plane;
  return looks_up_down ? Projection::Spherical : Projection::Cylindrical;
}

// Held-out keypoints that the homography chain must not fit on: (camera, other camera,
// quantised x, quantised y).
using HeldSet = std::set<std::array<long, 4>>;
std::array<long, 4> held_key(int cam, int other, const cv::Point2f& p) {
  return {cam, other, std::lround(p.x * 8), std::lround(p.y * 8)};
}
HeldSet held_points(const std::vector<PairData>& pairs) {
  HeldSet s;
  for (const auto& p : pairs)
    for (std::size_t k = 0; k < p.pa.size(); ++k)
      if (p.held[k]) {
        s.insert(held_key(p.a, p.b, cv::Point2f(float(p.pa[k].x()), float(p.pa[k].y()))));
        s.insert(held_key(p.b, p.a, cv::Point2f(float(p.pb[k].x()), float(p.pb[k].y()))));
      }
  return s;
}

// The homography model from a rough planar rig with homographies: each camera, outward from the
// reference along the largest overlaps, corrected by a homography (or the paper's skew-scale)
// fitted to feature matches in the widened overlaps with its already-placed neighbours.
// The features of a whole view that fall inside a mask (what detecting inside it would find,
// short of the detector's cap).
Features masked(const Features& f, const cv::Mat& mask) {
  Features out;
  for (std::size_t k = 0; k < f.keypoints.size(); ++k) {
    const int x = int(std::lround(f.keypoints[k].pt.x)), y = int(std::lround(f.keypoints[k].pt.y));
    if (x < 0 || y < 0 || x >= mask.cols || y >= mask.rows || !mask.at<uchar>(y, x)) continue;
    out.keypoints.push_back(f.keypoints[k]);
    out.descriptors.push_back(f.descriptors.row(int(k)));
  }
  return out;
}

// `feats`: the views' features when already detected (reused inside the overlaps).
void refine_homography_chain(CalibrationResult& res, const std::vector<std::vector<ImageView>>& sets,
                             const CalibrationOptions& o, const HeldSet& held, const FeatureSets* feats = nullptr) {
  throw_if_cancelled(o);
  Rig& rig = res.rig;
  const int n = int(rig.cameras.size());
  const std::vector<OverlapEdge> edges = overlap_edges(rig);
  std::vector<bool> connected(n, false);
  connected[rig.reference] = true;
  for (const auto& e : edges) connected[e.a] = connected[e.b] = true;
  for (int i = 0; i < n; ++i)
    if (!connected[i]) res.warnings.push_back("camera " + std::to_string(i) + " overlaps no other camera");
  if (o.refinement == Refinement::None || n < 2) return;

  // gray[set][camera]: matches are pooled over the sets (several instants of a static rig).
  std::vector<std::vector<cv::Mat>> gray(sets.size(), std::vector<cv::Mat>(n));
  if (!feats)
    for (std::size_t t = 0; t < sets.size(); ++t)
      for (int i = 0; i < n; ++i) gray[t][i] = to_gray(sets[t][i]);
  std::vector<bool> placed(n, false);
  placed[rig.reference] = true;
  for (const auto& [cam, parent] : max_spanning_order(n, rig.reference, edges)) {
    // Correspondences with every already-placed neighbour, in canvas coordinates.
    std::vector<cv::Point2f> src, dst;
    PairReport rep;
    rep.camera = cam;
    rep.neighbour = parent;
    for (const auto& e : edges) {
      if (e.a != cam && e.b != cam) continue;
      const int nb = e.a == cam ? e.b : e.a;
      if (!placed[nb]) continue;
      cv::Rect2d box = overlap_box(rig, cam, nb);
      const double m = o.overlap_margin * rig.cameras[cam].width;
      box.x -= m;
      box.y -= m;
      box.width += 2 * m;
      box.height += 2 * m;
      const cv::Mat mask_c = camera_mask(rig, cam, box), mask_n = camera_mask(rig, nb, box);
      for (std::size_t t = 0; t < gray.size(); ++t) {
        const Features fc = feats ? masked((*feats)[t][cam], mask_c) : detect(gray[t][cam], mask_c, o);
        const Features fn = feats ? masked((*feats)[t][nb], mask_n) : detect(gray[t][nb], mask_n, o);
        for (const auto& mt : match(fc, fn, o.features)) {
          // Ideal pixels: the homographies map those (the held-out set is keyed on them too).
          cv::Point2f pc, pn;
          if (!ideal_of(rig.cameras[cam], fc.keypoints[mt.queryIdx].pt, pc) ||
              !ideal_of(rig.cameras[nb], fn.keypoints[mt.trainIdx].pt, pn))
            continue;
          if (held.count(held_key(cam, nb, pc)) || held.count(held_key(nb, cam, pn))) continue;
          src.push_back(to_canvas(rig.cameras[cam], pc));
          dst.push_back(to_canvas(rig.cameras[nb], pn));
        }
      }
    }
    rep.matches = int(src.size());
    Eigen::Matrix3d C = Eigen::Matrix3d::Identity();
    std::vector<uchar> inl;
    bool ok = false;
    if (o.refinement == Refinement::Homography && src.size() >= 8) {
      cv::Mat Hc = cv::findHomography(src, dst, cv::RANSAC, o.ransac_threshold_px, inl, 2000, 0.995);
      if (!Hc.empty()) {
        C = to_eigen(Hc);
        // Polish: refit by least squares (+LM) on the matches that the first fit explains to
        // within a third of the RANSAC threshold; sloppy inliers otherwise bias the far corners.
        std::vector<cv::Point2f> s2, d2;
        for (std::size_t k = 0; k < src.size(); ++k) {
          if (!inl[k]) continue;
          const Eigen::Vector2d q = apply_homography(C, {src[k].x, src[k].y});
          if ((q - Eigen::Vector2d(dst[k].x, dst[k].y)).norm() < o.ransac_threshold_px / 3) {
            s2.push_back(src[k]);
            d2.push_back(dst[k]);
          }
        }
        if (s2.size() >= 8) {
          cv::Mat H2 = cv::findHomography(s2, d2, 0);
          if (!H2.empty()) C = to_eigen(H2);
        }
        rep.inliers = cv::countNonZero(inl);
        const Eigen::Matrix3d Hnew = C * *rig.cameras[cam].homography;
        const Camera& cc = rig.cameras[cam];
        ok = rep.inliers >= o.min_inliers && homography_problem(Hnew, cc.width, cc.height).empty();
        // A correction that moves the view by more than half its size is a false match.
        if (ok)
          for (const auto& q : camera_canvas_corners(cc)) {
            const Eigen::Vector2d moved = apply_homography(C, q);
            ok &= (moved - q).norm() < 0.5 * std::max(cc.width, cc.height);
          }
        if (!ok) rep.note = "homography rejected; trying skew-scale";
      }
    }
    if (!ok && src.size() >= 2) {
      ScaleShift ss;
      if (fit_scale_shift(src, dst, o.ransac_threshold_px, ss, inl)) {
        C = ss.matrix();
        rep.inliers = cv::countNonZero(inl);
        ok = rep.inliers >= o.min_inliers;
        if (ok && o.refinement == Refinement::Homography) rep.note = "skew-scale fallback";
      }
    }
    if (ok) {
      rep.accepted = true;
      rep.rms_px = rms_of(src, dst, inl, C);
      Eigen::Matrix3d H = C * *rig.cameras[cam].homography;
      rig.cameras[cam].homography = H / H(2, 2);
      ++res.refined_cameras;
    } else {
      rep.note = "too few feature matches (" + std::to_string(rep.inliers) + " inliers, need " +
                 std::to_string(o.min_inliers) + "): keeping the rough homography";
      res.warnings.push_back("camera " + std::to_string(cam) + ": " + rep.note);
    }
    placed[cam] = true;
    res.pairs.push_back(rep);
  }
  rig_layout_canvas(rig);
}

// Rotation model: rough K and R become a canvas (planar: the reference's image plane).
void finish_rotation_rig(Rig& rig, const CalibrationOptions& o, bool level) {
  if (!rig.planar()) {
    if (level && o.wave_correct) wave_correct(rig);
    rig.canvas_scale = 0;  // follow the refined focal lengths
  } else {
    for (std::size_t i = 0; i < rig.cameras.size(); ++i)
      rig.cameras[i].homography = rough_pairwise_homography(rig, int(i), rig.reference);
  }
  rig_layout_canvas(rig);
}

constexpr double kMaxHomographyStretch = 2.0;

// How unevenly a homography rig scales its cameras: the largest over the smallest ratio of a
// camera's area on the canvas to its image area (1: all at one scale, as cameras of one kind
// looking at one plane from one distance are).
double homography_stretch(const Rig& rig) {
  double lo = 1e300, hi = 0;
  for (const Camera& c : rig.cameras) {
    if (!c.homography) continue;
    const auto q = camera_canvas_corners(c);
    double twice = 0;
    for (int k = 0; k < 4; ++k) twice += q[k].x() * q[(k + 1) % 4].y() - q[(k + 1) % 4].x() * q[k].y();
    const double ratio = std::abs(0.5 * twice) / (double(c.width) * c.height);
    if (!(ratio > 0) || !std::isfinite(ratio)) return 1e300;
    lo = std::min(lo, ratio);
    hi = std::max(hi, ratio);
  }
  return hi > 0 ? hi / lo : 1;
}

// Rotation unless the free homographies explain the held-out matches clearly better.
bool homography_wins(double rotation_px, double homography_px) {
  if (homography_px < 0) return false;
  if (rotation_px < 0) return true;
  return homography_px * 1.5 < rotation_px && rotation_px - homography_px > 0.1;
}

CameraModel effective_model(const CalibrationOptions& o) {
  if (o.refinement == Refinement::SkewScale) return CameraModel::Homography;  // the paper's model asked for
  if (o.model == CameraModel::Auto && o.bundle_adjust) return CameraModel::Rotation;
  return o.model;
}

}  // namespace

const char* camera_model_name(CameraModel m) {
  switch (m) {
    case CameraModel::Auto: return "auto";
    case CameraModel::Rotation: return "rotation";
    case CameraModel::Homography: return "homography";
  }
  return "?";
}

const char* refinement_name(Refinement r) {
  switch (r) {
    case Refinement::None: return "none";
    case Refinement::SkewScale: return "skew-scale";
    case Refinement::Homography: return "homography";
  }
  return "?";
}

const char* feature_name(FeatureType f) {
  switch (f) {
    case FeatureType::Sift: return "sift";
    case FeatureType::Orb: return "orb";
    case FeatureType::Akaze: return "akaze";
  }
  return "?";
}

CalibrationResult calibrate_from_rig(const Rig& rough, const std::vector<ImageView>& frames,
                                     const CalibrationOptions& o) {
  return calibrate_from_rig(rough, std::vector<std::vector<ImageView>>{frames}, o);
}

namespace {

// Lenses being estimated (issue 15): the adjustment fitted on SIFT keypoints (~0.25 px noise,
// ~150 a pair on small frames) pins k1, k2 and the focal length only well enough for 1-2 px at
// the frame corners. Fit again on photometric correspondences all over the overlaps
// (dense_matches.hpp, ~0.06 px), located through the current fit, twice (the second pass through
// the first refit). A pair with too few of them keeps its keypoints. The refit is kept only when
// the held-out keypoint matches agree about as well as before (a wrong start tracks nothing sane).
// Each pass takes the alignment's sub-pixel phase bias off its matches first (correct_phase_bias).
// Cauchy's scale, in the matches' robust sigma: 1 (was 2) over 54 rendered rigs took the worst
// corner error 0.544 -> 0.486 px and the focal scale's rms error 0.109 -> 0.103 px with the
// phase-bias correction (BENCHMARKS.md, "Radtan registration"); 0 and 4 did worse on the PSNR bench.
constexpr double kDenseRobustScale = 1.0;
// The smoothings the dense matches are located at and pooled over (DenseMatchOptions::blur_sigma;
// 0.7 alone before branch radtan1: BENCHMARKS.md "Radtan PSNR on one frame").
constexpr double kDenseBlurs[] = {0.7, 1.4};
// Whether cameras of the same lens model and frame size should share one lens in the dense refit
// (BundleAdjustOptions::shared_lens): a side camera of a trio sees the others in its inner half
// only, so its own k1/k2 extrapolate to its outer corners, where the middle camera's other side
// would pin a shared lens. Decided on the data: every 5th dense match of each pair held out, both
// models fitted on the rest, and the shared lens kept unless the per-camera lenses explain the
// held-out matches clearly better (rms lower by more than kShareLensMargin). False also when no two
// estimating cameras are alike.
constexpr double kShareLensMargin = 0.05;
bool dense_lenses_alike(const Rig& rig) {
  for (std::size_t i = 0; i < rig.cameras.size(); ++i)
    for (std::size_t j = 0; j < i; ++j) {
      const Camera &a = rig.cameras[i], &b = rig.cameras[j];
      if (a.lens.estimate && b.lens.estimate && !a.lens.pinhole() && a.lens.model == b.lens.model &&
          a.width == b.width && a.height == b.height)
        return true;
    }
  return false;
}
double raw_heldout_rms(const Rig& rig, const std::vector<PairMatches>& held) {
  double sum = 0;
  int n = 0;
  for (const auto& m : held) {
    const Camera &A = rig.cameras.at(m.a), &B = rig.cameras.at(m.b);
    const Eigen::Matrix3d Rab = B.R().transpose() * A.R();
    for (std::size_t k = 0; k < m.ra.size(); ++k) {
      Eigen::Vector3d ray;
      Eigen::Vector2d q;
      if (!lens_unproject(A, m.ra[k], ray) || !lens_project(B, Rab * ray, q)) continue;
      const double e2 = (q - m.rb[k]).squaredNorm();
      if (!(e2 < 1.0)) continue;  // a match neither model explains says nothing about the lens
      sum += e2;
      ++n;
    }
  }
  return n ? std::sqrt(sum / n) : -1;
}
bool choose_shared_lens(const Rig& rig, const std::vector<PairMatches>& dense, const BundleAdjustOptions& bo) {
  std::vector<PairMatches> fit, held;
  for (const auto& m : dense) {
    PairMatches f, h;
    f.a = h.a = m.a;
    f.b = h.b = m.b;
    const bool raw = m.ra.size() == m.pa.size();
    for (std::size_t k = 0; k < m.pa.size(); ++k) {
      PairMatches& t = k % 5 == 2 && raw ? h : f;
      t.pa.push_back(m.pa[k]);
      t.pb.push_back(m.pb[k]);
      if (k < m.weight.size()) t.weight.push_back(m.weight[k]);
      if (raw) t.ra.push_back(m.ra[k]), t.rb.push_back(m.rb[k]);
    }
    fit.push_back(std::move(f));
    if (!h.ra.empty()) held.push_back(std::move(h));
  }
  if (held.empty()) return false;
  Rig per = rig, shared = rig;
  BundleAdjustOptions o1 = bo, o2 = bo;
  o1.shared_lens = false;
  o2.shared_lens = true;
  const BundleAdjustReport r1 = bundle_adjust(per, fit, o1), r2 = bundle_adjust(shared, fit, o2);
  if (!r2.ok || !r2.lens_warning.empty()) return false;
  if (!r1.ok || !r1.lens_warning.empty()) return true;
  const double e1 = raw_heldout_rms(per, held), e2 = raw_heldout_rms(shared, held);
  return e2 > 0 && e1 > 0 && e2 <= (1 + kShareLensMargin) * e1;
}

// `rays`: the ray-matched pairs (wide lenses) instead, adjusted with `base`'s options (a narrow
// ring's shared lens and focal). `refitted`: whether the dense fit was kept.
RotationFit refine_on_dense_matches(const RotationFit& start, const Rig& rough, const std::vector<PairData>& pairs,
                                    const std::vector<std::vector<ImageView>>& sets, bool rays = false,
                                    const BundleAdjustOptions& base = {}, bool* refitted = nullptr) {
  if (refitted) *refitted = false;
  std::vector<std::pair<int, int>> links;
  for (const auto& p : pairs)
    if (p.ok && p.rays == rays) links.emplace_back(p.a, p.b);
  if (links.empty() || sets.empty()) return start;
  std::vector<std::vector<DenseImage>> images;
  const std::size_t take = std::min<std::size_t>(sets.size(), 3);
  for (std::size_t k = 0; k < take; ++k) {
    std::vector<DenseImage> set;
    for (const auto& v : sets[k * sets.size() / take]) set.push_back(prepare_dense_image(to_gray(v)));
    images.push_back(std::move(set));
  }
  const std::vector<PairMatches> keypoints = training_matches(pairs);
  RotationFit rot = start;
  int accepted = 0;
  int share = -1;  // the dense refit's lens sharing, decided on the first pass (choose_shared_lens)
  for (int pass = 0; pass < 2; ++pass) {
    if ((base.cancel && base.cancel->load(std::memory_order_relaxed)) ||
        (base.deadline && std::chrono::steady_clock::now() > *base.deadline))
      return start;  // the caller throws
    DenseMatchOptions dopt;
    dopt.rays = rays;
    dopt.cancel = base.cancel;
    if (rays) dopt.max_points = 2000;
    // Pooled over two smoothings of the patches (kDenseBlurs): the alignment's bias depends on
    // the texture as it is smoothed, and two smoothings of the same overlap are partly
    // independent evidence (as more frames are, more so). Each set's phase bias is its own.
    const std::vector<double> blurs = rays ? std::vector<double>{dopt.blur_sigma}
                                           : std::vector<double>(std::begin(kDenseBlurs), std::end(kDenseBlurs));
    std::vector<PairMatches> dense;
    for (double bl : blurs) {
      DenseMatchOptions d2 = dopt;
      d2.blur_sigma = bl;
      std::vector<PairMatches> part = dense_matches(rot.rig, links, images, d2);
      if (!rays) correct_phase_bias(rot.rig, part);  // sub-pixel peak locking, under the fit the matches came through
      for (auto& m : part) {
        auto it = std::find_if(dense.begin(), dense.end(), [&](const PairMatches& d) { return d.a == m.a && d.b == m.b; });
        if (it == dense.end()) {
          dense.push_back(std::move(m));
          continue;
        }
        it->pa.insert(it->pa.end(), m.pa.begin(), m.pa.end());
        it->pb.insert(it->pb.end(), m.pb.begin(), m.pb.end());
        it->ra.insert(it->ra.end(), m.ra.begin(), m.ra.end());
        it->rb.insert(it->rb.end(), m.rb.begin(), m.rb.end());
        it->weight.insert(it->weight.end(), m.weight.begin(), m.weight.end());
      }
    }
    int dense_pairs = 0;
    for (const auto& k : keypoints) {
      auto it = std::find_if(dense.begin(), dense.end(), [&](const PairMatches& d) { return d.a == k.a && d.b == k.b; });
      if (it != dense.end() && it->pa.size() >= 40) {
        ++dense_pairs;
        continue;
      }
      if (it != dense.end()) *it = k;
      else dense.push_back(k);
    }
    if (dense_pairs == 0) break;
    RotationFit f;
    f.rig = rot.rig;
    for (std::size_t i = 0; i < f.rig.cameras.size(); ++i) f.rig.cameras[i].lens.estimate = rough.cameras[i].lens.estimate;
    BundleAdjustOptions bo = base;
    bo.robust_scale = kDenseRobustScale;
    // Alike estimating cameras share one lens unless held-out matches say otherwise.
    if (!rays && !base.shared_lens && dense_lenses_alike(f.rig)) {
      if (share < 0) share = choose_shared_lens(f.rig, dense, bo) ? 1 : 0;
      bo.shared_lens = share == 1;
    }
    f.ba = bundle_adjust(f.rig, dense, bo);
    if (!f.ba.ok || !f.ba.lens_warning.empty()) break;
    f.ok = true;
    f.warnings = start.warnings;
    rot = std::move(f);
    ++accepted;
  }
  const double before = residuals(start.rig, pairs, true, true).rms_px;
  const double after = residuals(rot.rig, pairs, true, true).rms_px;
  if (before > 0 && !(after <= 1.2 * before + 0.05)) return start;
  if (refitted) *refitted = accepted > 0;
  return rot;
}

}  // namespace

CalibrationResult calibrate_from_rig(const Rig& rough_in, const std::vector<std::vector<ImageView>>& sets,
                                     const CalibrationOptions& o) {
  throw_if_cancelled(o);
  if (sets.empty()) throw RigError("no frames to calibrate on");
  for (const auto& frames : sets) {
    if (frames.size() != rough_in.cameras.size())
      throw RigError("the rig has " + std::to_string(rough_in.cameras.size()) + " cameras but " +
                     std::to_string(frames.size()) + " streams are connected");
    check_frames(frames);
  }
  Rig rough = rough_in;
  if (o.projection && rough.projection != projection_name(*o.projection)) {
    // Another canvas: what the rig computed for its own one does not apply.
    rough.projection = projection_name(*o.projection);
    for (auto& c : rough.cameras) c.homography.reset();
    rough.canvas_width = rough.canvas_height = 0;
    rough.canvas_scale = 0;
    rough.canvas_wrap = false;
  }
  const int n = int(rough.cameras.size());
  if (rough.reference < 0 || rough.reference >= n) throw RigError("reference camera index out of range");
  // Lens views beyond what a plane canvas shows (a fisheye rig on the default plane): the
  // canvas its views need when no one chose the plane, else a warning naming the cameras.
  std::vector<std::string> plane_notes;
  bool plane_switched = false;
  if (const PlaneCanvasCheck pc = check_plane_canvas(rough); !pc.projection.empty()) {
    const bool chosen = o.projection || !rough.projection_default;
    for (const auto& p : pc.problems)
      plane_notes.push_back(p + (chosen ? "; only rays within 90 degrees of that axis are drawn, the rest is black: use "
                                          "projection " + pc.projection
                                        : "; the rig file names no projection: using a " + pc.projection + " canvas"));
    if (!chosen) {
      rough.projection = pc.projection;
      for (auto& c : rough.cameras) c.homography.reset();
      rough.canvas_width = rough.canvas_height = 0;
      rough.canvas_scale = 0;
      rough.canvas_wrap = false;
      plane_switched = true;
    }
  }
  CameraModel model = effective_model(o);
  const bool plane_induced = rough.planar() && rough.plane_distance_m > 0;
  if (plane_induced) {
    if (model == CameraModel::Rotation)
      throw RigError("bundle adjustment models a rotating rig: it cannot refine plane-induced homographies "
                     "(plane_distance_m with camera positions); turn bundle-adjust off");
    model = CameraModel::Homography;
  }
  if (!rough.planar()) model = CameraModel::Rotation;
  bool have_all = rough.planar();
  for (const auto& c : rough.cameras) have_all &= bool(c.homography);

  CalibrationResult res;
  res.warnings = plane_notes;
  res.projection_chosen = plane_switched;
  for (int i = 0; i < n; ++i)
    if (const std::string w = lens_warning(rough.cameras[i]); !w.empty())
      res.warnings.push_back("camera " + std::to_string(i) + ": " + w);
  res.rig = rough;
  if (o.refinement == Refinement::None || n < 2) {
    // Rough geometry only.
    if (rough.planar()) {
      if (!have_all) rig_compute_rough_homographies(res.rig);
      else rig_layout_canvas(res.rig);
      refine_homography_chain(res, sets, o, {});
    } else {
      rig_layout_canvas(res.rig);
    }
    res.model = rough.planar() && have_all ? CameraModel::Homography : CameraModel::Rotation;
    return res;
  }

  // The planar start: the rig's homographies, or those of its rough rotations.
  Rig start = rough;
  if (start.planar()) {
    if (!have_all) rig_compute_rough_homographies(start);
    else rig_layout_canvas(start);
  }
  if (model == CameraModel::Homography) {
    // Nothing to compare: the chain alone, on features detected inside the overlaps.
    res.rig = start;
    refine_homography_chain(res, sets, o, {});
    res.model = CameraModel::Homography;
    return res;
  }
  // Matches of every pair that the start says may overlap, checked against it.
  const FeatureSets feats = detect_all(sets, n, o);
  // `lens_rig`: whose lenses undistort the keypoints (the start; again with estimated lenses).
  // Wide lenses on a rotating rig are matched on rays (see match_pair_rays).
  auto ray_pair = [&](int a, int b) {
    return !start.planar() && (needs_rays(start.cameras[a]) || needs_rays(start.cameras[b]));
  };
  bool any_rays = false;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) any_rays |= ray_pair(a, b);
  // `ray_thr_rad` > 0: the ray pairs' RANSAC threshold; rotations and lenses from `lens_rig`,
  // or from `ray_rig` for the ray pairs when given.
  auto match_all = [&](const Rig& lens_rig, double ransac_scale = 1.0, double ray_thr_rad = 0,
                       const Rig* ray_rig = nullptr) {
    std::vector<PairData> out;
    for (int a = 0; a < n; ++a)
      for (int b = a + 1; b < n; ++b) {
        const Camera &A = start.cameras[a], &B = start.cameras[b];
        if (ray_pair(a, b)) {
          const Rig& rays_through = ray_rig ? *ray_rig : lens_rig;
          const Camera &LA = rays_through.cameras[a], &LB = rays_through.cameras[b];
          const double axes = std::acos(std::clamp(LA.R().col(2).dot(LB.R().col(2)), -1.0, 1.0));
          if (axes > (lens_half_fov(LA) + lens_half_fov(LB)) * (1 + o.overlap_margin)) continue;
          const double f = std::min(LA.fx, LB.fx);
          // First pass: a rough focal length bends every ray (3 % is 3 degrees at 100 degrees
          // off the axis, which no rotation absorbs): match loosely, the adjustment cleans up.
          const double thr = ray_thr_rad > 0 ? ray_thr_rad : std::max(4 * o.ransac_threshold_px / f, 0.12);
          out.push_back(match_pair_rays(feats, a, b, o, rays_through, thr, 0.3));
          continue;
        }
        if (start.planar()) {
          if (overlap_box(start, a, b).area() <= 0) continue;
        } else {
          const double axes = std::acos(std::clamp(A.R().col(2).dot(B.R().col(2)), -1.0, 1.0));
          if (axes > (half_diagonal_fov(A) + half_diagonal_fov(B)) * (1 + o.overlap_margin)) continue;
        }
        const Eigen::Matrix3d predicted = start.planar() ? Eigen::Matrix3d(B.homography->inverse() * *A.homography)
                                                         : rough_pairwise_homography(start, a, b);
        out.push_back(match_pair(feats, a, b, o, &predicted, 0.25 * std::max(B.width, B.height), &lens_rig,
                                 ransac_scale));
      }
    return out;
  };
  bool estimating = false;
  for (const auto& c : rough.cameras) estimating |= c.lens.estimate && !c.lens.pinhole();
  // Lenses still unknown: the distorted periphery is off any homography by pixels, and a tight
  // RANSAC keeps only the matches that fit a wrong (undistorted) model, which then pulls the
  // lens estimate to a wrong focal. Match loosely; the adjustment drops the outliers.
  std::vector<PairData> pairs = match_all(start, estimating ? kLensUnknownRansacScale : 1.0);
  std::vector<bool> matched(n, false);
  int held = 0;
  auto count_matched = [&] {
    matched.assign(n, false);
    held = 0;
    for (const auto& p : pairs)
      if (p.ok) matched[p.a] = matched[p.b] = true, held += p.held_count();
    res.heldout_matches = held;
  };
  count_matched();
  // Cameras whose matches lie in a narrow band of angles off the axis (a back-to-back overlap
  // ring): per-camera focal, k1 and k2 trade off there (measured: k1 -0.03 came out +0.04 / -0.09
  // with the focal 35 % off, seams still sub-pixel). Identical lenses (same model and frame) share
  // one k1 (no k2): the ring's shape (how far the two radii stray from mirror images of each
  // other) then pins it down, unless its standard error says otherwise (checked after the fit).
  // A re-match whose pairs tie fewer cameras to the reference than the current ones lets the
  // cut-off part turn freely (a 5 x 185 ring: 122 degrees off at 0.36 px rms): not taken.
  const auto loses_cameras = [&](const std::vector<PairData>& rematched) {
    return cameras_tied_to(rematched, n, rough.reference) < cameras_tied_to(pairs, n, rough.reference);
  };
  BundleAdjustOptions ba_options;
  ba_options.cancel = o.cancel;
  ba_options.deadline = o.deadline;
  std::vector<int> narrow;
  std::vector<double> narrow_spread(n, 0);
  if (estimating && any_rays)
    for (int i = 0; i < n; ++i) {
      if (!rough.cameras[i].lens.estimate || !needs_rays(rough.cameras[i])) continue;
      const double spread = ray_angle_spread(rough.cameras[i], i, pairs);
      if (spread >= kMinLensEstimateSpreadRad) continue;
      narrow.push_back(i);
      narrow_spread[i] = spread;
    }
  if (!narrow.empty()) ba_options.shared_lens = true, ba_options.estimate_k2 = false;
  // Every camera on a narrow ring with the same lens and frame (a back-to-back pair of identical
  // fisheyes): the ring pins the sum of their angles at the seam, not how it splits between the
  // two focal lengths (seams do not see the split; the panorama does: f 0.8 % off cost 6 dB on
  // a sharp photo). One focal length for both, from the mean of the rough ones.
  bool identical_ring = int(narrow.size()) == n && n >= 2;
  for (int i : narrow)
    identical_ring &= rough.cameras[i].lens.model == rough.cameras[0].lens.model &&
                      rough.cameras[i].width == rough.cameras[0].width && rough.cameras[i].height == rough.cameras[0].height;
  if (identical_ring) {
    ba_options.shared_focal = true;
    double f = 0;
    for (const auto& c : rough.cameras) f += 0.5 * (c.fx + c.fy) / n;
    for (auto& c : rough.cameras) c.fx = c.fy = f;
  }
  auto decline_narrow = [&](int i, const std::string& why) {
    rough.cameras[i].lens.estimate = false;
    res.warnings.push_back("camera " + std::to_string(i) + ": its matches lie " +
                           std::to_string(int(std::lround(narrow_spread[i] * 180 / kPi))) +
                           " degrees apart off its axis (a back-to-back overlap ring): too narrow to estimate the "
                           "lens (" + why + "); keeping the rough rig's coefficients (none given, as without a rig file: an "
                           "ideal equidistant lens); give them, e.g. from an OpenCV calibration");
  };
  for (int i : narrow) {
    // A lens no other camera shares: its focal and k1 trade off freely.
    bool twin = false;
    for (int j = 0; j < n; ++j)
      twin |= j != i && rough.cameras[j].lens.estimate && rough.cameras[j].lens.model == rough.cameras[i].lens.model &&
              rough.cameras[j].width == rough.cameras[i].width && rough.cameras[j].height == rough.cameras[i].height;
    if (!twin) decline_narrow(i, "no identical lens to share it with");
  }
  // After the fit: the shared k1 of narrow-ring cameras is kept when the matches determine it (2
  // sigma within 10 % of it, or within 0.004 for a lens near equidistant), kept with a warning
  // when it is loose but clearly not 0 (more than 5 sigma: far closer than the k = 0 it replaces;
  // measured k1 -0.0177 +- 0.003 for -0.02; 3 sigma let k1 -0.021 +- 0.005 through for a true
  // 0: the ring's sigma is optimistic), and declined otherwise. True when any was declined
  // (the caller adjusts again without them).
  bool ring_unrefined = false;  // ray pairs whose photometric refit failed (below)
  auto decline_unpinned = [&](const RotationFit& fit) {
    bool declined = false;
    for (int i : narrow) {
      if (!rough.cameras[i].lens.estimate) continue;
      const double k1 = fit.rig.cameras[i].lens.k1;
      const double sigma = i < int(fit.ba.lens_k1_sigma.size()) ? fit.ba.lens_k1_sigma[i] : 1e9;
      if (2 * sigma <= std::max(0.1 * std::abs(k1), 0.004)) continue;
      char why[96];
      if (std::abs(k1) > 5 * sigma && !ring_unrefined) {
        std::snprintf(why, sizeof why, "k1 %+.4f +- %.4f", k1, sigma);
        res.warnings.push_back("camera " + std::to_string(i) + ": " + why +
                               " estimated loosely from a narrow overlap ring (a back-to-back pair); give the lens "
                               "coefficients (e.g. from an OpenCV calibration) for a better panorama");
        continue;
      }
      std::snprintf(why, sizeof why, "k1 %+.4f +- %.4f", k1, sigma);
      decline_narrow(i, why);
      declined = true;
    }
    if (declined) {
      estimating = false;
      for (const auto& c : rough.cameras) estimating |= c.lens.estimate && !c.lens.pinhole();
    }
    return declined;
  };
  estimating = false;
  for (const auto& c : rough.cameras) estimating |= c.lens.estimate && !c.lens.pinhole();

  // The rotation model from the rough rotations (or, for a rig given by homographies, from
  // those: each camera's rotation relative to the reference's through its K).
  RotationFit rot;
  if (model != CameraModel::Homography) {
    Rig r0 = rough;
    if (have_all) {
      const Camera& ref = start.cameras[start.reference];
      for (int i = 0; i < n; ++i) {
        if (i == start.reference) continue;
        const Eigen::Matrix3d Hi = ref.homography->inverse() * *start.cameras[i].homography;
        r0.cameras[i].set_R(ref.R() * nearest_rotation(ref.K().inverse() * Hi * r0.cameras[i].K()));
      }
    }
    {
      // Narrow-ring lenses are held in this first, loosely matched pass (from k = 0 the loose
      // matches ran focal and k1 off along their trade-off: f 96 px for 146, k1 +0.18); the
      // rig adjusted with them pins the ring's radius, and the passes below estimate from there.
      Rig r0h = r0;
      for (int i : narrow) r0h.cameras[i].lens.estimate = false;
      rot = adjust(r0h, pairs, ba_options);
    }
    throw_if_cancelled(o);
    if (rot.ok && estimating) {
      // The first pass matched with lenses still unknown: the homography RANSAC (3 px) dropped
      // much of the distorted periphery, which is what tells k2 and the focal length apart.
      // Match again through the estimated lenses and adjust again from the first estimate.
      Rig lens_rig = start;
      for (int i = 0; i < n; ++i)
        if (rough.cameras[i].lens.estimate) {
          lens_rig.cameras[i].lens = rot.rig.cameras[i].lens;
          lens_rig.cameras[i].lens.estimate = true;
        }
      // Ray pairs through the adjusted rig as a whole: an estimated fisheye lens belongs to its
      // estimated focal length (k1 from f 103 px on the rough f 91 bent the rim rays by 7 degrees),
      // and the rough rotations can be 20 degrees off (ring of 5 x 185: four pairs lost).
      std::vector<PairData> pairs2 = match_all(lens_rig, 1.0, 0, &rot.rig);
      Rig r1 = rot.rig;
      for (int i = 0; i < n; ++i) r1.cameras[i].lens.estimate = rough.cameras[i].lens.estimate;
      RotationFit rot2 = adjust(r1, pairs2, ba_options);
      if (loses_cameras(pairs2)) rot2.ok = false;
      if (rot2.ok) {
        rot = std::move(rot2);
        pairs = std::move(pairs2);
        start = lens_rig;  // the homography chain works on the same ideal pixels
        count_matched();
      }
    }
    if (rot.ok && any_rays) {
      // Ray pairs were matched loosely around the rough focal lengths: match again through the
      // adjusted rig with the usual threshold (in radians at the focal length) and adjust again.
      double f = 1e30;
      for (const auto& c : rot.rig.cameras) f = std::min(f, c.fx);
      Rig r1 = rot.rig;
      for (int i = 0; i < n; ++i) r1.cameras[i].lens.estimate = rough.cameras[i].lens.estimate;
      std::vector<PairData> pairs2 = match_all(rot.rig, 1.0, o.ransac_threshold_px / f);
      RotationFit rot2 = adjust(r1, pairs2, ba_options);
      if (loses_cameras(pairs2)) rot2.ok = false;
      if (rot2.ok) {
        rot = std::move(rot2);
        pairs = std::move(pairs2);
        count_matched();
      }
    }
    if (rot.ok && estimating && any_rays && o.dense_lens_matches) {
      // Wide lenses: keypoints on a fisheye's rim are placed with a bias that follows the lens's
      // anisotropy (a patch 100 degrees off the axis is stretched 1.8x along the rim in one
      // camera, 1.4x at 80 degrees in the other), which a narrow ring turns into k1 and focal
      // error. Photometric matches aligned through the rig's own lens map carry no such bias
      // and cover the whole ring, not only the corners SIFT finds.
      bool refitted = false;
      throw_if_cancelled(o);
      rot = refine_on_dense_matches(rot, rough, pairs, sets, true, ba_options, &refitted);
      throw_if_cancelled(o);
      // No photometric refit (a ring too narrow or bare to track 40 patches on, e.g. 190
      // degrees): the keypoint fit's sigma is optimistic (k1 -0.021 +- 0.0025 for a true 0, 10 dB
      // lost), so a loosely determined k1 is declined rather than kept with a warning.
      ring_unrefined = !refitted;
    }
    if (rot.ok && decline_unpinned(rot)) {
      // Again on the final (tight) matches; declined: the same matches, the given lens.
      Rig r1 = rot.rig;
      for (int i : narrow)
        if (!rough.cameras[i].lens.estimate) r1.cameras[i].lens = rough.cameras[i].lens;
      for (int i = 0; i < n; ++i) r1.cameras[i].lens.estimate = rough.cameras[i].lens.estimate;
      RotationFit rot2 = adjust(r1, pairs, ba_options);
      if (rot2.ok) rot = std::move(rot2);
    }
    throw_if_cancelled(o);
    if (rot.ok && estimating && !any_rays && o.dense_lens_matches) {
      BundleAdjustOptions dense_options;
      dense_options.cancel = o.cancel;
      dense_options.deadline = o.deadline;
      rot = refine_on_dense_matches(rot, rough, pairs, sets, false, dense_options);
    }
    throw_if_cancelled(o);
    if (rot.ok && estimating && !any_rays && o.dense_lens_matches && o.photometric_refit) {
      // The overlaps' brightness itself, no located points (photometric_refine.hpp).
      std::vector<std::pair<int, int>> links;
      for (const auto& p : pairs)
        if (p.ok && !p.rays) links.emplace_back(p.a, p.b);
      std::vector<std::vector<cv::Mat>> gray;
      const std::size_t take = std::min<std::size_t>(sets.size(), 3);
      for (std::size_t k = 0; k < take; ++k) {
        gray.emplace_back();
        for (const auto& v : sets[k * sets.size() / take]) gray.back().push_back(to_gray(v));
      }
      std::vector<bool> free_lens(n);
      for (int i = 0; i < n; ++i) free_lens[i] = rough.cameras[i].lens.estimate;
      Rig refit = rot.rig;
      PhotometricRefineOptions po;
      po.blur_sigma = o.photometric_blur_sigma;
      const PhotometricRefineResult pr = photometric_refine(refit, links, gray, free_lens, po);
      const double before = residuals(rot.rig, pairs, true, true).rms_px;
      const double after = residuals(refit, pairs, true, true).rms_px;
      if (pr.ok && (!(before > 0) || after <= 1.2 * before + 0.05)) rot.rig = refit;
    }
    res.warnings.insert(res.warnings.end(), rot.warnings.begin(), rot.warnings.end());
    if (rot.ok && estimating)
      for (int i = 0; i < n; ++i) {
        // Focal and distortion trade off: an estimate that more than halves or doubles a rough
        // focal length ran off (seen on k1 -0.35 barrel lenses from a zero start). Say so and
        // keep the rough rig rather than a degenerate one.
        const double ratio = rot.rig.cameras[i].fx / rough.cameras[i].fx;
        if (ratio > 0.5 && ratio < 2.0) continue;
        res.warnings.push_back("camera " + std::to_string(i) + ": estimating the lens ran off (focal length " +
                               std::to_string(rough.cameras[i].fx) + " -> " + std::to_string(rot.rig.cameras[i].fx) +
                               " px): keeping the rough rig; give the lens coefficients");
        res.lens_ran_off = true;
        rot.ok = false;
        break;
      }
    if (rot.ok) {
      res.rotation_heldout_px = residuals(rot.rig, pairs, true, true).rms_px;
    } else if (model == CameraModel::Rotation && !pairs.empty()) {
      bool any = false;
      for (const auto& p : pairs) any |= p.ok;
      if (any) res.warnings.push_back("bundle adjustment did not converge: keeping the rough rotations");
    }
  }
  // The homography model: the chain, kept off the held-out matches.
  CalibrationResult chain;
  bool chain_done = false;
  if (model != CameraModel::Rotation) {
    chain.rig = start;
    refine_homography_chain(chain, sets, o, held_points(pairs), &feats);
    chain_done = true;
    if (chain.refined_cameras > 0) res.homography_heldout_px = residuals(chain.rig, pairs, false, true).rms_px;
  }

  bool use_rotation;
  if (model == CameraModel::Rotation) use_rotation = true;
  else if (model == CameraModel::Homography) use_rotation = false;
  else if (!rot.ok) use_rotation = !have_all;  // no evidence: the rough rig's own form
  else if (chain.refined_cameras == 0) use_rotation = true;
  else use_rotation = !homography_wins(res.rotation_heldout_px, res.homography_heldout_px) ||
                      homography_stretch(chain.rig) > kMaxHomographyStretch;  // as calibrate_from_images

  if (use_rotation) {
    res.model = CameraModel::Rotation;
    if (rot.ok) {
      res.rig = rot.rig;
      res.ba_rms_before_px = rot.ba.rms_before_px;
      res.ba_rms_after_px = rot.ba.rms_after_px;
      // A planar canvas is the reference camera's image plane: its own mapping never changes.
      for (int i = 0; i < n; ++i) res.refined_cameras += matched[i] && !(rough.planar() && i == rough.reference);
    } else {
      res.rig = rough;
      res.ba_rms_before_px = rot.ba.rms_before_px;
      res.ba_rms_after_px = rot.ba.rms_after_px;
    }
    for (int i = 0; i < n; ++i) {
      if (matched[i]) continue;
      // Matches that the rough rig puts elsewhere: most likely the cameras are in another order.
      const PairData* elsewhere = nullptr;
      for (const auto& p : pairs)
        if ((p.a == i || p.b == i) && p.inliers >= o.min_inliers && (!elsewhere || p.inliers > elsewhere->inliers))
          elsewhere = &p;
      if (elsewhere)
        res.warnings.push_back("camera " + std::to_string(i) + ": its view matches camera " +
                               std::to_string(elsewhere->a == i ? elsewhere->b : elsewhere->a) + " (" +
                               std::to_string(elsewhere->inliers) +
                               " matches) but not where the rough rig puts them (are the cameras in the rig's "
                               "order?); keeping its rough rotation and focal length");
      else
        res.warnings.push_back("camera " + std::to_string(i) + ": no feature matches with any other camera; "
                               "keeping its rough rotation and focal length");
    }
    finish_rotation_rig(res.rig, o, true);
    const std::vector<std::string> warnings = res.warnings;
    fill_reports(res, pairs, true);
    res.warnings = warnings;
  } else {
    const double hr = res.rotation_heldout_px, hh = res.homography_heldout_px;
    const int heldc = res.heldout_matches;
    if (!chain_done) {
      chain.rig = start;
      refine_homography_chain(chain, sets, o, {});
    }
    res = chain;
    res.warnings.insert(res.warnings.begin(), plane_notes.begin(), plane_notes.end());
    res.model = CameraModel::Homography;
    res.rotation_heldout_px = hr;
    res.homography_heldout_px = hh;
    res.heldout_matches = heldc;
    // The chain's own pair reports (the tree it fitted) with camera-pixel residuals.
    const Residuals r = report_residuals(res.rig, pairs, false);
    res.cameras.assign(n, CameraReport{});
    for (int i = 0; i < n; ++i) {
      res.cameras[i].camera = i;
      if (r.camera_count[i]) res.cameras[i].rms_px = std::sqrt(r.camera_sum[i] / r.camera_count[i]);
    }
    for (std::size_t i = 0; i < pairs.size(); ++i)
      if (pairs[i].ok)
        for (int c : {pairs[i].a, pairs[i].b}) {
          res.cameras[c].neighbours++;
          res.cameras[c].matches += int(pairs[i].pa.size());
        }
    for (auto& rep : res.pairs)
      for (std::size_t i = 0; i < pairs.size(); ++i)
        if ((pairs[i].a == rep.camera && pairs[i].b == rep.neighbour) ||
            (pairs[i].b == rep.camera && pairs[i].a == rep.neighbour))
          if (r.pair_rms[i] >= 0) rep.rms_px = r.pair_rms[i];
  }
  return res;
}

CalibrationResult calibrate_from_images(const std::vector<ImageView>& frames, int reference,
                                        const CalibrationOptions& o) {
  return calibrate_from_images(std::vector<std::vector<ImageView>>{frames}, reference, o);
}

namespace {
CalibrationResult calibrate_from_images_pinhole(const std::vector<std::vector<ImageView>>& sets, int reference,
                                                const CalibrationOptions& o);
}  // namespace

// The held-out error of a lens fit must fall below this share of the pinhole one (and by at
// least kLensEvidenceMinPx) before images alone are taken as evidence of distortion.
constexpr double kLensEvidenceRatio = 0.7, kLensEvidenceMinPx = 0.2;

// The ring order of N >= 3 circular fisheyes from their images: users connect pads in any order.
// For every pair, the ratio-test matches (pooled over the frame sets) whose rays, through the
// rough rig's lenses, agree with b one ring step after a, and those that agree with b one step
// before a: prefiltered loosely around that rotation (a guessed field of view moves the overlap
// by up to ~15 degrees, as a common yaw), then counted under the best rotation of a RANSAC over
// 2-ray rotations, as in match_pair_rays. The ring is the cyclic order, camera 0 first, whose
// steps gather the most such matches: the heaviest Hamiltonian cycle, found exactly by dynamic
// programming over subsets (Held-Karp, N <= 16: 2^15 x 16 x 16 steps); ties keep pad order.
// slots[camera] = its place around the ring; empty for N < 3 or when no pair matches.
constexpr int kMaxOrderedRing = 16;

// The cyclic order (camera 0 first) with the largest sum of score[order[k]][order[k + 1]]:
// best[mask][j] is the heaviest path from 0 through the cameras in mask (bits for 1..n-1)
// ending at j. Exact, O(2^(n-1) n^2).
static std::vector<int> heaviest_ring(const std::vector<std::vector<int>>& score) {
  const int n = int(score.size()), m = n - 1, full = (1 << m) - 1;
  constexpr long kNone = std::numeric_limits<long>::min();
  std::vector<long> best(std::size_t(full + 1) * m, kNone);
  std::vector<int8_t> from(best.size(), -1);
  auto at = [&](int mask, int j) { return std::size_t(mask) * m + j; };  // j: camera j + 1
  for (int j = 0; j < m; ++j) best[at(1 << j, j)] = score[0][j + 1];
  for (int mask = 1; mask <= full; ++mask)
    for (int j = 0; j < m; ++j) {
      const long here = best[at(mask, j)];
      if (here == kNone) continue;
      for (int k = 0; k < m; ++k) {
        if (mask & (1 << k)) continue;
        const int next = mask | (1 << k);
        const long total = here + score[j + 1][k + 1];
        if (total > best[at(next, k)]) best[at(next, k)] = total, from[at(next, k)] = int8_t(j);
      }
    }
  int last = 0;
  long top = kNone;
  for (int j = 0; j < m; ++j) {
    const long total = best[at(full, j)] + score[j + 1][0];
    if (total > top) top = total, last = j;
  }
  std::vector<int> order(n, 0);
  for (int mask = full, j = last, k = n - 1; k >= 1; --k) {
    order[k] = j + 1;
    const int prev = from[at(mask, j)];
    mask &= ~(1 << j);
    j = prev;
  }
  return order;
}

struct RingOrder {
  std::vector<int> slots;
  bool reordered = false;
};
static RingOrder ring_order(const FeatureSets& feats, const Rig& rough, const CalibrationOptions& o) {
  RingOrder out;
  const int n = int(rough.cameras.size());
  if (n < 3 || n > kMaxOrderedRing) return out;
  constexpr double kTolRad = 0.45, kThrRad = 0.12;
  const double cos_tol = std::cos(kTolRad), cos_thr = std::cos(kThrRad);
  // score[a][b]: matches that agree with b one step after a around the ring.
  std::vector<std::vector<int>> score(n, std::vector<int>(n, 0));
  auto R_of = [&](int cam, double yaw_deg) {
    Camera c = rough.cameras[cam];
    c.yaw_deg = yaw_deg;
    return c.R();
  };
  const double step = 360.0 / n;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      const Camera &A = rough.cameras[a], &B = rough.cameras[b];
      std::vector<Eigen::Vector3d> ua, ub;
      for_each_matched_ray(feats, a, b, o, A, B,
                           [&](const Eigen::Vector3d& ra, const Eigen::Vector3d& rb, const cv::KeyPoint&, const cv::KeyPoint&) {
                             ua.push_back(ra);
                             ub.push_back(rb);
                           });
      for (const int dir : {+1, -1}) {
        const Eigen::Matrix3d Q0 = R_of(b, dir * step).transpose() * R_of(a, 0);  // a's frame -> b's frame
        std::vector<int> cand;
        for (int k = 0; k < int(ua.size()); ++k)
          if ((Q0 * ua[k]).dot(ub[k]) >= cos_tol) cand.push_back(k);
        if (cand.size() < 3) continue;
        (dir > 0 ? score[a][b] : score[b][a]) = int(ray_rotation_inliers(ua, ub, cand, Q0, cos_thr, 300).size());
      }
    }
  const std::vector<int> best_order = heaviest_ring(score);
  long best_total = 0, pad_total = 0;
  for (int k = 0; k < n; ++k) {
    best_total += score[best_order[k]][best_order[(k + 1) % n]];
    pad_total += score[k][(k + 1) % n];
  }
  if (best_total <= pad_total) return out;  // pad order, as good as any (or nothing matched)
  out.slots.assign(n, 0);
  for (int k = 0; k < n; ++k) {
    out.slots[best_order[k]] = k;
    out.reordered |= best_order[k] != k;
  }
  return out;
}

// Frames that all show an image circle are circular fisheyes (a 360 camera): calibrated from the
// rough rig circular_fisheye_rig guesses, over a few fields of view (the circle gives the focal
// length only with one), keeping the fit the held-out matches like best. nullopt: not such frames.
static std::optional<CalibrationResult> calibrate_circular_fisheyes(const std::vector<std::vector<ImageView>>& sets,
                                                                    int reference, const CalibrationOptions& o) {
  std::optional<CalibrationResult> best;
  double best_error = std::numeric_limits<double>::infinity(), best_fov = 0;
  bool best_whole = false;  // the best fit matched every camera
  std::string last_error;
  // A ring's order around the camera, from the images (pads in any order), read through each
  // field-of-view guess: a guess far off the lens (195 degrees for 120-degree lenses) bends the
  // rays enough to read a wrong order.
  RingOrder ring;
  if (sets[0].size() < 2) return std::nullopt;
  // The circles once (a rim fit per frame), the rough rigs of every guess from them.
  const std::optional<std::vector<LensCircle>> circles = find_image_circles(sets[0]);
  if (!circles) return std::nullopt;
  std::optional<FeatureSets> ring_feats;
  if (sets[0].size() >= 3) ring_feats = detect_all(sets, int(sets[0].size()), o);
  // Two back to back need more than 180 degrees each; a ring of N covers the circle with lenses
  // down to a little more than 360 / N (a ring of 4 x 150 or 6 x 120 degrees: the 195-225 guesses
  // put their focal lengths 25-40 % off, which no fit recovers from).
  std::vector<double> fovs = {195.0, 185.0, 210.0, 225.0};
  const int cams = int(sets[0].size());
  if (cams >= 3)
    for (const double fov : {170.0, 150.0, 130.0, 115.0})
      if (fov > 360.0 / cams + 15.0) fovs.push_back(fov);
  // A fit this poor is no fisheye rig (a vignetted rectilinear camera, a spotlit scene): the
  // pinhole path gets its turn.
  constexpr double kFisheyeFitMaxPx = 1.5;
  for (const double fov : fovs) {
    // The narrow-lens guesses only when the usual ones found no usable fit (their cost: one
    // calibration each).
    if (fov < 185.0 && best_whole && best_error < kFisheyeFitMaxPx) break;
    RingOrder order;
    if (ring_feats) {
      const std::optional<Rig> guess = circular_fisheye_rig(sets[0], *circles, fov);
      if (!guess) return std::nullopt;
      order = ring_order(*ring_feats, *guess, o);
    }
    std::optional<Rig> rough = circular_fisheye_rig(sets[0], *circles, fov, order.slots);
    if (!rough) return std::nullopt;
    rough->reference = reference >= 0 && reference < int(rough->cameras.size()) ? reference : 0;
    try {
      CalibrationResult r = calibrate_from_rig(*rough, sets, o);
      const double error = r.rotation_heldout_px > 0 ? r.rotation_heldout_px : r.ba_rms_after_px;
      // A fit that leaves cameras unmatched measures its error on the few pairs it did match (a
      // ring of 6 x 120 degrees read through the 210-degree guess: 4 cameras kept their rough
      // pose at 0.68 px): any fit that matches every camera beats it.
      const bool whole = r.refined_cameras >= cams;
      if (!(error > 0) || (best_whole && !whole) || (whole == best_whole && !(error < best_error))) continue;
      best_error = error;
      best_whole = whole;
      best_fov = fov;
      best = std::move(r);
      ring = order;
    } catch (const CalibrationCancelled&) {
      throw;
    } catch (const std::exception& e) {
      last_error = e.what();
      continue;
    }
    if (best_whole && best_error < 0.7) break;  // a good fit: the guess was close enough
  }
  if (best && !(best_error < kFisheyeFitMaxPx)) {
    last_error = "held-out error " + std::to_string(best_error) + " px";
    best.reset();
  }
  if (!best)
    throw RigError("the cameras show image circles (circular fisheye lenses) but no 360 rig of them fits the images" +
                   (last_error.empty() ? std::string() : " (" + last_error + ")") +
                   ": give a rig-file with their \"lens\"");
  // The images show the circles: these are fisheyes, whatever their field of view (a ring of
  // 6 x 130 degrees sees less than lens_warning's "rectilinear given the fisheye model" bound).
  best->warnings.erase(std::remove_if(best->warnings.begin(), best->warnings.end(),
                                      [](const std::string& w) {
                                        return w.find("given the fisheye model") != std::string::npos;
                                      }),
                       best->warnings.end());
  const int n = int(sets[0].size());
  std::string ring_note;
  if (ring.reordered) {
    std::vector<int> order(n);
    for (int i = 0; i < n; ++i) order[ring.slots[i]] = i;
    ring_note = " whose pads are not in ring order: the images put them around in the order";
    for (int i = 0; i < n; ++i) ring_note += (i ? ", " : " ") + std::to_string(order[i]);
  }
  best->warnings.push_back("every camera shows an image circle: calibrated as " +
                           (n == 2 ? std::string("two circular fisheyes back to back") :
                                     "a ring of " + std::to_string(n) + " circular fisheyes" + ring_note) +
                           " (field of view first guessed " + std::to_string(int(best_fov)) +
                           " degrees; focal lengths and lenses estimated; held-out error " + std::to_string(best_error) +
                           " px); give a rig-file to set them");
  return best;
}

// Full-frame fisheyes (action cameras, branch probe-lens): no image circle, 120-170 degrees across
// the frame, so a pinhole fit folds or bends (a ring of 4 x 148 degrees: "degenerate homography").
// For each guessed field of view across the width (equidistant lens: f = (w / 2) / (fov / 2)),
// every pair's rotation is read from its matched rays alone (a RANSAC over 2-ray rotations, as
// match_pair_rays once it has a start), and the cameras are placed along the tree of pairs with the
// most inliers from the reference: side by side, a ring or any layout, pads in any order. That
// rough rig (fisheye lenses to estimate, spherical canvas) goes to calibrate_from_rig; the fit the
// held-out matches like best is kept. `pinhole`: the pinhole path's rig, when it gave one: the same
// count of ray inliers (within 2 px) through its (rectilinear) cameras must be beaten by a quarter, else the
// lenses are not wide fisheyes and nothing more is tried (a second of matching, no calibration).
// A fit that sees less than kFullFrameFisheyeMinFovDeg across the widest frame is a normal lens,
// left to the radtan lens fit. nullopt: no guess gave a whole, usable wide fit (why_not says why).
constexpr double kFullFrameFisheyeFitMaxPx = 1.5, kFullFrameFisheyeInlierGain = 1.25, kLensCompareThrPx = 2.0,
                 kFullFrameFisheyeMinFovDeg = 100.0;
namespace {
struct RayRotations {
  std::vector<std::vector<int>> count;  // inliers of each pair's rotation (0: none)
  std::vector<std::vector<Eigen::Matrix3d>> Q;  // Q[a][b] takes a's rays to b's
  long total = 0;
};
}  // namespace
// thr_px > 0: inliers within thr_px camera pixels (at the rig's smallest focal length), to
// compare lens guesses fairly; else within 1.5 degrees.
static RayRotations pairwise_ray_rotations(const FeatureSets& feats, const Rig& rig, const CalibrationOptions& o,
                                           double thr_px = 0) {
  const int n = int(rig.cameras.size());
  // A guess off the lens by 20 degrees moves the frame's edge rays by a few degrees: the rough
  // rotations need only be close enough for calibrate_from_rig's ray matching (its tolerance).
  double f = std::numeric_limits<double>::infinity();
  for (const auto& c : rig.cameras) f = std::min(f, c.fx);
  const double cos_thr = std::cos(thr_px > 0 ? thr_px / f : 1.5 * kPi / 180.0);
  constexpr int kMinPairInliers = 20;
  RayRotations out;
  out.count.assign(std::size_t(n), std::vector<int>(std::size_t(n), 0));
  out.Q.assign(std::size_t(n), std::vector<Eigen::Matrix3d>(std::size_t(n), Eigen::Matrix3d::Identity()));
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      throw_if_cancelled(o);
      std::vector<Eigen::Vector3d> ua, ub;
      for_each_matched_ray(feats, a, b, o, rig.cameras[std::size_t(a)], rig.cameras[std::size_t(b)],
                           [&](const Eigen::Vector3d& ra, const Eigen::Vector3d& rb, const cv::KeyPoint&,
                               const cv::KeyPoint&) {
                             ua.push_back(ra.normalized());
                             ub.push_back(rb.normalized());
                           });
      if (ua.size() < std::size_t(kMinPairInliers)) continue;
      std::vector<int> all(ua.size());
      std::iota(all.begin(), all.end(), 0);
      std::vector<int> in = ray_rotation_inliers(ua, ub, all, Eigen::Matrix3d::Identity(), cos_thr, 1000);
      for (int round = 0; round < 3 && in.size() >= 3; ++round)
        in = ray_rotation_inliers(ua, ub, all, kabsch(ua, ub, in), cos_thr, 0);
      if (int(in.size()) < kMinPairInliers) continue;
      const Eigen::Matrix3d q = kabsch(ua, ub, in);
      out.count[std::size_t(a)][std::size_t(b)] = out.count[std::size_t(b)][std::size_t(a)] = int(in.size());
      out.Q[std::size_t(a)][std::size_t(b)] = q;
      out.Q[std::size_t(b)][std::size_t(a)] = q.transpose();
      out.total += long(in.size());
    }
  return out;
}

static std::optional<CalibrationResult> calibrate_full_frame_fisheyes(const std::vector<std::vector<ImageView>>& sets,
                                                                      int reference, const CalibrationOptions& o,
                                                                      const Rig* pinhole, std::string& why_not) {
  const int n = sets.empty() ? 0 : int(sets[0].size());
  if (n < 2) return std::nullopt;
  reference = reference >= 0 && reference < n ? reference : 0;
  const FeatureSets feats = detect_all(sets, n, o);
  struct Guess {
    double fov;
    Rig rough;
    RayRotations rotations;
  };
  std::vector<Guess> guesses;
  long best_total = 0;
  for (const double fov : {150.0, 125.0, 170.0}) {
    Rig rough;
    rough.projection = "spherical";
    rough.reference = reference;
    for (int i = 0; i < n; ++i) {
      Camera c;
      c.width = sets[0][std::size_t(i)].width;
      c.height = sets[0][std::size_t(i)].height;
      c.fx = c.fy = 0.5 * c.width / (0.5 * fov * kPi / 180.0);
      c.cx = 0.5 * (c.width - 1);
      c.cy = 0.5 * (c.height - 1);
      c.lens.model = Lens::Model::Fisheye;
      c.lens.estimate = true;
      rough.cameras.push_back(c);
    }
    RayRotations rot = pairwise_ray_rotations(feats, rough, o);
    if (pinhole) best_total = std::max(best_total, pairwise_ray_rotations(feats, rough, o, kLensCompareThrPx).total);
    guesses.push_back({fov, std::move(rough), std::move(rot)});
  }
  if (pinhole && int(pinhole->cameras.size()) == n) {
    Rig flat = *pinhole;
    for (auto& c : flat.cameras) c.lens = Lens{}, c.homography.reset();
    const long pinhole_total = pairwise_ray_rotations(feats, flat, o, kLensCompareThrPx).total;
    if (!(double(best_total) > kFullFrameFisheyeInlierGain * double(pinhole_total))) {
      why_not = "the matches fit rectilinear lenses as well (" + std::to_string(pinhole_total) + " ray inliers vs " +
                std::to_string(best_total) + " through a fisheye guess)";
      return std::nullopt;
    }
  }
  std::optional<CalibrationResult> best;
  double best_error = std::numeric_limits<double>::infinity(), best_fov = 0;
  for (Guess& g : guesses) {
    // The tree of the strongest pairs from the reference (Prim): R_b = R_a Q_ab^T.
    std::vector<char> placed(std::size_t(n), 0);
    std::vector<Eigen::Matrix3d> R(std::size_t(n), Eigen::Matrix3d::Identity());
    placed[std::size_t(reference)] = 1;
    for (int added = 1; added < n; ++added) {
      int from = -1, to = -1, top = 0;
      for (int a = 0; a < n; ++a)
        for (int b = 0; b < n; ++b)
          if (placed[std::size_t(a)] && !placed[std::size_t(b)] && g.rotations.count[std::size_t(a)][std::size_t(b)] > top)
            top = g.rotations.count[std::size_t(a)][std::size_t(b)], from = a, to = b;
      if (to < 0) break;
      R[std::size_t(to)] = R[std::size_t(from)] * g.rotations.Q[std::size_t(from)][std::size_t(to)].transpose();
      placed[std::size_t(to)] = 1;
    }
    if (std::count(placed.begin(), placed.end(), 1) < n) {
      why_not = "at a guessed " + std::to_string(int(g.fov)) + "-degree fisheye lens, not every camera shares matched "
                "rays with the others";
      continue;
    }
    for (int i = 0; i < n; ++i) g.rough.cameras[std::size_t(i)].set_R(R[std::size_t(i)]);
    try {
      CalibrationResult r = calibrate_from_rig(g.rough, sets, o);
      const double error = r.rotation_heldout_px > 0 ? r.rotation_heldout_px : r.ba_rms_after_px;
      if (r.refined_cameras < n || !(error > 0) || !(error < best_error)) continue;
      best_error = error;
      best_fov = g.fov;
      best = std::move(r);
    } catch (const CalibrationCancelled&) {
      throw;
    } catch (const std::exception& e) {
      why_not = e.what();
      continue;
    }
    if (best_error < 0.7) break;  // the guess was close enough
  }
  if (best && !(best_error < kFullFrameFisheyeFitMaxPx)) {
    why_not = "the best full-frame fisheye fit leaves " + std::to_string(best_error) + " px held out";
    best.reset();
  }
  if (!best) return std::nullopt;
  // A barrel lens of a normal field of view (a phone's k1 -0.35 over 66 degrees) fits the
  // fisheye model too, but it is the radtan lens fit's (lens_fit_starts; the elements' lens job).
  double widest = 0;
  for (const auto& c : best->rig.cameras) {
    Eigen::Vector3d left, right;
    if (lens_unproject(c, {0.0, c.cy}, left) && lens_unproject(c, {c.width - 1.0, c.cy}, right))
      widest = std::max(widest, std::acos(std::clamp(left.normalized().dot(right.normalized()), -1.0, 1.0)) * 180 / kPi);
  }
  if (widest < kFullFrameFisheyeMinFovDeg) {
    why_not = "the fisheye fit sees " + std::to_string(int(widest)) + " degrees across, a normal lens";
    return std::nullopt;
  }
  best->warnings.erase(std::remove_if(best->warnings.begin(), best->warnings.end(),
                                      [](const std::string& w) {
                                        return w.find("given the fisheye model") != std::string::npos;
                                      }),
                       best->warnings.end());
  best->warnings.push_back("the cameras fit poorly as rectilinear (pinhole) cameras: calibrated as " + std::to_string(n) +
                           " full-frame fisheye lenses (wide action-camera lenses; field of view first guessed " +
                           std::to_string(int(best_fov)) + " degrees across; focal lengths, lenses and rotations "
                           "estimated; held-out error " + std::to_string(best_error) + " px); give a rig-file to set them");
  return best;
}

bool lens_evidence_wins(double pinhole_px, double lens_px) {
  return pinhole_px > 0 && lens_px >= 0 && lens_px < kLensEvidenceRatio * pinhole_px && pinhole_px - lens_px > kLensEvidenceMinPx;
}

bool lens_fit_usable(const CalibrationResult& lens) {
  bool usable = lens.model == CameraModel::Rotation && lens.rotation_heldout_px > 0;
  for (const auto& c : lens.rig.cameras) usable &= !c.lens.estimate && lens_problem(c).empty();
  return usable;
}

std::vector<Rig> lens_fit_guessed_starts(const Rig& pin) {
  std::vector<Rig> starts;
  const int n = int(pin.cameras.size());
  if (n == 0) return starts;
  const int ref = std::clamp(pin.reference, 0, n - 1);
  bool homographies = pin.planar();
  for (const auto& c : pin.cameras) homographies &= bool(c.homography);
  // Each camera's pixels -> the reference's, as the pinhole fit maps them (what its matches hold).
  const Camera& rc = pin.cameras[std::size_t(ref)];
  std::vector<Eigen::Matrix3d> to_ref(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    const Camera& c = pin.cameras[std::size_t(i)];
    to_ref[std::size_t(i)] = homographies ? Eigen::Matrix3d(rc.homography->inverse() * *c.homography)
                                          : Eigen::Matrix3d(rc.K() * rc.R().transpose() * c.R() * c.K().inverse());
  }
  for (const double hfov : {60.0, 45.0, 80.0}) {
    Rig r = pin;
    r.canvas_width = r.canvas_height = 0;
    r.canvas_scale = 0;
    r.canvas_wrap = false;
    for (auto& c : r.cameras) {
      c.fx = c.fy = 0.5 * rc.width / std::tan(0.5 * hfov * kPi / 180.0) * double(c.width) / rc.width;
      c.cx = 0.5 * (c.width - 1);
      c.cy = 0.5 * (c.height - 1);
    }
    const Eigen::Matrix3d Kr = r.cameras[std::size_t(ref)].K();
    for (int i = 0; i < n; ++i) {
      Camera& c = r.cameras[std::size_t(i)];
      c.set_R(nearest_rotation(Kr.inverse() * to_ref[std::size_t(i)] * c.K()));
      c.homography.reset();
      c.lens = Lens{};
      c.lens.model = Lens::Model::Radtan;
      c.lens.estimate = true;
    }
    // The pinhole fit's canvas may not hold the views at the fitted focal length (3 strong
    // barrel phones 45 degrees apart: 170 degrees across at 80, a "degenerate" plane canvas):
    // the one their field of view asks for at half the guessed focal length (a fit moves it by
    // up to 2x, CalibrationResult::lens_ran_off); a projection given in the options still wins.
    Rig wide = r;
    for (auto& c : wide.cameras) c.fx *= 0.5, c.fy *= 0.5;
    r.projection = projection_name(choose_projection(field_of_view(wide)));
    starts.push_back(r);
  }
  return starts;
}

std::vector<Rig> lens_fit_starts(const Rig& pin, CameraModel model) {
  // Rough rigs of a lens fit (radtan, coefficients estimated): the pinhole rotation rig; or, when
  // homographies won (strong distortion, k1 -0.35, bends the rotation model more than a free
  // homography: 3.3 px vs 1.5 px held out, and its focal lengths run off, ~9700 px for a true
  // 554; branch probe360), rotations read from those homographies through a few guessed focal
  // lengths (lens_fit_guessed_starts).
  if (model != CameraModel::Rotation) {
    bool all = pin.planar() && !pin.cameras.empty();
    for (const auto& c : pin.cameras) all &= bool(c.homography);
    return all ? lens_fit_guessed_starts(pin) : std::vector<Rig>{};
  }
  std::vector<Rig> starts{pin};
  for (Rig& rough : starts)
    for (auto& c : rough.cameras) {
      c.lens = Lens{};
      c.lens.model = Lens::Model::Radtan;
      c.lens.estimate = true;
    }
  return starts;
}

// Measured (BENCHMARKS.md, "The cheap test before the lens fit"): see lens_precheck.
const double kLensPrecheckRatio = 0.85, kLensPrecheckMinPx = 0.05, kLensPrecheckSignificance = 3.5,
             kLensPrecheckMaxBend = 0.5;

std::string LensPrecheck::describe() const {
  char b[160];
  std::snprintf(b, sizeof b, "k1 %+.3f (corner bend %+.3f): %.3f -> %.3f px held out (%d matches, %.1f standard errors, %.2f s)",
                k1, bend, pinhole_px, lens_px, heldout, significance, seconds);
  return b;
}

LensPrecheck lens_precheck(const Rig& pin, const std::vector<std::vector<ImageView>>& sets, const CalibrationOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  LensPrecheck r;
  const auto done = [&]() {
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return r;
  };
  const int n = int(pin.cameras.size());
  if (n < 2 || sets.empty() || pin.reference < 0 || pin.reference >= n) return done();
  for (const auto& frames : sets) {
    if (int(frames.size()) != n) return done();
    check_frames(frames);
  }
  // Matches of every pair the pinhole rig puts in overlap, checked loosely against it (lenses
  // unknown: the distorted periphery is off the pinhole maps by pixels).
  const FeatureSets feats = detect_all(sets, n, o);
  bool homographies = pin.planar();
  for (const auto& c : pin.cameras) homographies &= bool(c.homography);
  std::vector<PairData> pairs;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      const Camera &A = pin.cameras[std::size_t(a)], &B = pin.cameras[std::size_t(b)];
      Eigen::Matrix3d predicted;
      if (homographies) {
        if (overlap_box(pin, a, b).area() <= 0) continue;
        predicted = B.homography->inverse() * *A.homography;
      } else {
        const double axes = std::acos(std::clamp(A.R().col(2).dot(B.R().col(2)), -1.0, 1.0));
        if (axes > (half_diagonal_fov(A) + half_diagonal_fov(B)) * (1 + o.overlap_margin)) continue;
        predicted = rough_pairwise_homography(pin, a, b);
      }
      PairData p = match_pair(feats, a, b, o, &predicted, 0.25 * std::max(B.width, B.height), nullptr,
                              kLensUnknownRansacScale);
      if (!p.ok || p.held_count() == 0) continue;
      p.ra = p.pa;  // raw = ideal under the starts' zero lenses
      p.rb = p.pb;
      pairs.push_back(std::move(p));
    }
  throw_if_cancelled(o);
  if (pairs.empty()) return done();
  std::vector<PairData> pin_pairs = pairs;
  for (auto& p : pin_pairs) p.ra.clear(), p.rb.clear();
  // Held-out error of a fitted rig, raw pixel to raw pixel (a -> b), each match capped: a match
  // neither model explains (a false one, parallax) weighs alike in both.
  constexpr double kCapPx = 3.0;
  const auto heldout_errors = [&](const Rig& rig) {
    std::vector<double> e;
    for (const auto& p : pairs)
      for (std::size_t k = 0; k < p.ra.size(); ++k) {
        if (!p.held[k]) continue;
        Eigen::Vector2d q;
        e.push_back(raw_transfer(rig, p.a, p.b, p.ra[k], q) ? std::min(kCapPx, (q - p.rb[k]).norm()) : kCapPx);
      }
    return e;
  };
  const auto rms = [](const std::vector<double>& e) {
    double sum = 0;
    for (const double x : e) sum += x * x;
    return e.empty() ? -1.0 : std::sqrt(sum / double(e.size()));
  };
  // The starts: the pinhole rig's K and R; with homographies, rotations read from them through
  // a guessed focal length too (lens_fit_starts: a pinhole fit of distorted cameras on a plane
  // can hold focal lengths 20x the truth, from where k1 is not found).
  std::vector<Rig> starts{pin};
  {
    // One guess (60 degrees across) is enough: the adjustment's distortion sweep fits the focal
    // for each candidate, and 45 / 80 degrees led to the same fit on every rendered rig. A
    // rotation rig gets it too: a pinhole fit of strong barrel lenses holds focal lengths 5x off
    // (a k1 -0.40 row at 1280 px: 3700 for a true 763).
    std::vector<Rig> guessed = lens_fit_guessed_starts(pin);
    // (A homography-model rig's own K and R are that guess already: not twice.)
    bool same = !guessed.empty();
    for (std::size_t i = 0; same && i < pin.cameras.size(); ++i)
      same = std::abs(guessed.front().cameras[i].fx - pin.cameras[i].fx) < 1e-6 * pin.cameras[i].fx &&
             guessed.front().cameras[i].R().isApprox(pin.cameras[i].R(), 1e-9);
    if (!guessed.empty() && !same) starts.push_back(std::move(guessed.front()));
  }
  // 60 fitted matches a pair (of ~150-300): the adjustment's cost is linear in them (numerical
  // derivatives), and 4 parameters a camera plus one k1 need far fewer.
  constexpr std::size_t kTrainCap = 60;
  const std::vector<PairMatches> train_pin = training_matches(pin_pairs, kTrainCap),
                                 train_lens = training_matches(pairs, kTrainCap);
  BundleAdjustOptions bo;
  bo.cancel = o.cancel;
  bo.deadline = o.deadline;
  BundleAdjustOptions pin_o = bo, lens_o = bo;
  pin_o.estimate_lens = false;
  lens_o.shared_lens = true;  // one k1 for alike cameras: the test asks "any distortion?"
  lens_o.estimate_k2 = false;
  std::vector<double> pin_e, lens_e;
  for (const Rig& st : starts) {
    Rig ps = st, ls = st;
    for (auto& c : ps.cameras) c.lens = Lens{}, c.homography.reset();
    for (auto& c : ls.cameras) {
      c.lens = Lens{};
      c.lens.model = Lens::Model::Radtan;
      c.lens.estimate = true;
      c.homography.reset();
    }
    const BundleAdjustReport bp = bundle_adjust(ps, train_pin, pin_o);
    throw_if_cancelled(o);
    if (bp.ok)
      if (std::vector<double> e = heldout_errors(ps); pin_e.empty() || rms(e) < rms(pin_e)) pin_e = std::move(e);
    const BundleAdjustReport bl = bundle_adjust(ls, train_lens, lens_o);
    throw_if_cancelled(o);
    bool sane = bl.ok && bl.lens_warning.empty();
    for (const auto& c : ls.cameras) sane &= lens_problem(c).empty();
    if (sane)
      if (std::vector<double> e = heldout_errors(ls); lens_e.empty() || rms(e) < rms(lens_e)) {
        lens_e = std::move(e);
        const Camera& c = ls.cameras[std::size_t(pin.reference)];
        r.k1 = c.lens.k1;
        r.bend = c.lens.k1 * 0.25 * (double(c.width) * c.width + double(c.height) * c.height) / (c.fx * c.fy);
      }
  }
  if (pin_e.empty() || lens_e.size() != pin_e.size()) return done();
  r.heldout = int(pin_e.size());
  r.pinhole_px = rms(pin_e);
  r.lens_px = rms(lens_e);
  // Paired over the same held-out matches: the mean drop of the squared error in its standard
  // errors (a few dozen matches of a real scene's parallax move the rms by 10-20 % either way).
  double mean = 0, var = 0;
  const double m = double(pin_e.size());
  for (std::size_t k = 0; k < pin_e.size(); ++k) mean += (pin_e[k] * pin_e[k] - lens_e[k] * lens_e[k]) / m;
  for (std::size_t k = 0; k < pin_e.size(); ++k) {
    const double d = pin_e[k] * pin_e[k] - lens_e[k] * lens_e[k] - mean;
    var += d * d / std::max(1.0, m - 1);
  }
  r.significance = var > 0 ? mean / std::sqrt(var / m) : (mean > 0 ? 1e9 : 0.0);
  // A k1 that bends the frame's corners by more than half their radius is no lens the fit could
  // find (the adjustment sweeps -0.32..+0.16): it bent parallax or motion (the real stereo hallway
  // clip: k1 +279, a bend of +1.8, for 18 held-out matches).
  r.plausible = r.pinhole_px > 0 && r.lens_px < kLensPrecheckRatio * r.pinhole_px &&
                r.pinhole_px - r.lens_px > kLensPrecheckMinPx && r.significance > kLensPrecheckSignificance &&
                std::abs(r.bend) <= kLensPrecheckMaxBend;
  return done();
}

// Ideal pinhole pictures of the frames through each camera's known lens (same size, the camera's
// fx, fy, cx, cy): each ideal pixel's raw pixel (cv::remap); black where the lens sees nothing.
static void ideal_pictures(const Rig& known, const std::vector<std::vector<ImageView>>& sets,
                           std::vector<std::vector<cv::Mat>>& ideal, std::vector<std::vector<ImageView>>& ideal_views) {
  const std::size_t n = known.cameras.size();
  std::vector<std::pair<cv::Mat, cv::Mat>> maps(n);
  for (std::size_t i = 0; i < n; ++i) {
    const Camera& c = known.cameras[i];
    cv::Mat mx(c.height, c.width, CV_32F), my(c.height, c.width, CV_32F);
    for (int y = 0; y < c.height; ++y)
      for (int x = 0; x < c.width; ++x) {
        Eigen::Vector2d raw;
        const bool ok = distort_point(c, Eigen::Vector2d(x, y), raw);
        mx.at<float>(y, x) = ok ? float(raw.x()) : -1.f;
        my.at<float>(y, x) = ok ? float(raw.y()) : -1.f;
      }
    maps[i] = {mx, my};
  }
  ideal.assign(sets.size(), {});
  ideal_views.assign(sets.size(), {});
  for (std::size_t t = 0; t < sets.size(); ++t) {
    for (std::size_t i = 0; i < n; ++i) {
      cv::Mat out;
      cv::remap(as_mat(sets[t][i]), out, maps[i].first, maps[i].second, cv::INTER_LINEAR, cv::BORDER_CONSTANT,
                cv::Scalar(0, 0, 0, 255));
      ideal[t].push_back(out);
    }
    for (auto& m : ideal[t]) ideal_views[t].push_back(as_view(m));
  }
}

// Options for calibrating ideal pinhole pictures (ideal_pictures): the lenses are known, so no
// lens path runs again; lens rigs are rotation rigs (the homography chain takes none).
static CalibrationOptions ideal_picture_options(const CalibrationOptions& o) {
  CalibrationOptions po = o;
  po.lens_from_evidence = false;
  po.per_camera_lenses = false;
  po.circular_fisheyes = false;
  po.model = CameraModel::Rotation;
  po.bundle_adjust = false;
  return po;
}

CalibrationResult calibrate_from_images_with_lenses(const std::vector<std::vector<ImageView>>& sets, int reference,
                                                    const std::vector<Camera>& lenses_in, const CalibrationOptions& o) {
  throw_if_cancelled(o);
  if (sets.empty()) throw RigError("no frames to calibrate on");
  const std::size_t n = lenses_in.size();
  for (const auto& frames : sets) {
    if (frames.size() != n)
      throw RigError("the cameras' lenses are known for " + std::to_string(n) + " cameras but " +
                     std::to_string(frames.size()) + " streams are connected");
    check_frames(frames);
  }
  // The known intrinsics at the frames' sizes.
  Rig known;
  for (const Camera& c : lenses_in) known.cameras.push_back(c);
  std::vector<std::array<int, 2>> sizes;
  for (const auto& v : sets[0]) sizes.push_back({v.width, v.height});
  for (std::size_t i = 0; i < n; ++i) {
    const Camera& c = known.cameras[i];
    if (c.width <= 0 || c.height <= 0 ||
        std::abs(double(sizes[i][0]) / c.width - double(sizes[i][1]) / c.height) > 0.01 * double(sizes[i][0]) / c.width)
      throw RigError("camera " + std::to_string(i) + ": its known lens was found at " + std::to_string(c.width) + "x" +
                     std::to_string(c.height) + ", another picture than " + std::to_string(sizes[i][0]) + "x" +
                     std::to_string(sizes[i][1]));
  }
  rig_adapt_to_sizes(known, sizes);
  for (std::size_t i = 0; i < n; ++i)
    if (const std::string p = lens_problem(known.cameras[i]); !p.empty())
      throw RigError("camera " + std::to_string(i) + ": its known lens is unusable: " + p);
  std::vector<std::vector<cv::Mat>> ideal;
  std::vector<std::vector<ImageView>> ideal_views;
  ideal_pictures(known, sets, ideal, ideal_views);
  throw_if_cancelled(o);
  const CalibrationResult pin = calibrate_from_images(ideal_views, reference, ideal_picture_options(o));
  // Rotations from the ideal pictures; the known intrinsics and lenses (held); the canvas laid
  // out again by the refit.
  Rig start = pin.rig;
  for (std::size_t i = 0; i < n; ++i) {
    Camera& c = start.cameras[i];
    const Camera& k = known.cameras[i];
    c.fx = k.fx, c.fy = k.fy, c.cx = k.cx, c.cy = k.cy;
    c.lens = k.lens;
    c.lens.estimate = false;
    c.homography.reset();
  }
  start.canvas_width = start.canvas_height = 0;
  start.canvas_scale = 0;
  start.canvas_wrap = false;
  CalibrationOptions ro = o;
  ro.model = CameraModel::Rotation;
  ro.bundle_adjust = false;
  ro.projection.reset();  // the pinhole fit's (o.projection when given)
  CalibrationResult r = calibrate_from_rig(start, sets, ro);
  r.projection_chosen = pin.projection_chosen;
  if (r.model != CameraModel::Rotation || !(r.rotation_heldout_px > 0))
    throw RigError("the refit with the cameras' lenses found no rotation rig");
  return r;
}

// A pinhole stand-in of a lens camera for choosing the canvas (field_of_view reads K alone): the
// focal length that sees the lens's own half-width angle (at most 80 degrees) at the frame's edge.
static Camera pinhole_stand_in(const Camera& c) {
  Camera p = c;
  Eigen::Vector3d ray;
  if (!c.lens.pinhole() && lens_unproject(c, {c.width - 1.0, c.cy}, ray)) {
    const double angle = std::min(std::atan2(std::hypot(ray.x(), ray.y()), ray.z()), 80.0 * kPi / 180.0);
    p.fx = p.fy = (c.width - 1.0 - c.cx) / std::tan(std::max(angle, 1e-3));
  }
  p.lens = Lens{};
  return p;
}

// The per-camera lens path of calibrate_from_images (CalibrationOptions::per_camera_lenses): each
// camera's plumb-line lens (from its own frames, no other camera), its frames undistorted into
// ideal pinhole pictures (calibrate_from_images_with_lenses's), those calibrated as pinhole
// cameras (rotations, and each camera's focal length: a radtan lens's coefficients are rescaled
// to it, plumb_line_rescaled), then everything refined on the raw frames with each lens
// estimated from there (calibrate_from_rig; fisheyes from a few k1 starts too). nullopt when the
// cameras' lenses do not clearly differ (plumb_lenses_mixed) or no fit is usable.
static std::optional<CalibrationResult> calibrate_with_plumb_lenses(const std::vector<std::vector<ImageView>>& sets,
                                                                    int reference, const CalibrationOptions& o) {
  const std::size_t n = sets.empty() ? 0 : sets[0].size();
  if (n < 2) return std::nullopt;
  std::vector<PlumbLineLens> plumb;
  for (std::size_t i = 0; i < n; ++i) plumb.push_back(plumb_line_lens({sets.front()[i], sets.back()[i]}));
  const bool debug = std::getenv("STITCH_DEBUG_PLUMB") != nullptr;
  if (debug)
    for (std::size_t i = 0; i < n; ++i)
      std::fprintf(stderr, "plumb camera %zu: %s%s\n", i, plumb[i].found ? "" : "(not judged) ", plumb[i].describe().c_str());
  if (!plumb_lenses_mixed(plumb)) return std::nullopt;
  throw_if_cancelled(o);
  Rig known;
  for (const auto& l : plumb) known.cameras.push_back(l.camera);
  std::vector<std::vector<cv::Mat>> ideal;
  std::vector<std::vector<ImageView>> ideal_views;
  ideal_pictures(known, sets, ideal, ideal_views);
  CalibrationOptions po = ideal_picture_options(o);
  po.full_frame_fisheyes = false;
  CalibrationResult pin;
  try {
    pin = calibrate_from_images(ideal_views, reference, po);
  } catch (const RigError& e) {
    if (debug) std::fprintf(stderr, "plumb: the ideal pictures calibrate no rig: %s\n", e.what());
    return std::nullopt;
  }
  if (pin.model != CameraModel::Rotation) return std::nullopt;
  Rig start = pin.rig;
  for (std::size_t i = 0; i < n; ++i) {
    Camera& c = start.cameras[i];
    const Camera k = plumb_line_rescaled(known.cameras[i], c.fx);
    c.fx = c.fy = k.fx;
    c.cx = k.cx;
    c.cy = k.cy;
    c.lens = k.lens;
    c.homography.reset();
  }
  start.canvas_width = start.canvas_height = 0;
  start.canvas_scale = 0;
  start.canvas_wrap = false;
  if (o.projection) {
    start.projection = projection_name(*o.projection);
  } else {
    Rig stand_in = start;
    bool fisheye = false;
    for (auto& c : stand_in.cameras) fisheye |= c.lens.model == Lens::Model::Fisheye, c = pinhole_stand_in(c);
    const Projection p = choose_projection(field_of_view(stand_in));
    start.projection = projection_name(fisheye && p != Projection::Plane ? Projection::Spherical : p);
  }
  CalibrationOptions ro = o;
  ro.model = CameraModel::Rotation;
  ro.bundle_adjust = false;
  ro.projection.reset();  // the start's
  // The starts: the plumb-line lenses; with fisheyes, also Kannala-Brandt k1 -0.05, -0.02, +0.02
  // with each fisheye's focal length from its straight edges at that k1 (plumb_line_fisheye_at:
  // the edges pin f and k1 together poorly, and a fisheye beside a rectilinear camera shares too
  // narrow a band of angles with it for the adjustment to split them); the best by held-out error.
  const std::vector<double> k1_starts{-0.05, -0.02, 0.02};
  std::vector<std::vector<Camera>> fisheye_starts(n);  // [camera][k1 start]; empty: not a fisheye
  for (std::size_t i = 0; i < n; ++i)
    if (start.cameras[i].lens.model == Lens::Model::Fisheye)
      fisheye_starts[i] = plumb_line_fisheye_at({sets.front()[i], sets.back()[i]}, start.cameras[i], k1_starts);
  std::vector<Rig> starts{start};
  for (std::size_t k = 0; k < k1_starts.size(); ++k) {
    Rig r = start;
    bool any = false;
    for (std::size_t i = 0; i < n; ++i) {
      if (fisheye_starts[i].empty()) continue;
      Camera& c = r.cameras[i];
      c.lens.k1 = k1_starts[k];
      c.fx = c.fy = fisheye_starts[i][k].fx;
      any = true;
    }
    if (any) starts.push_back(std::move(r));
  }
  std::optional<CalibrationResult> best;
  bool found_again = false;
  for (const Rig& st : starts) {
    // A start that ends at the best fit's held-out error (within 1%) found the same fit again (a
    // fisheye beside a 1x camera: k1 -0.05 and -0.02 both end at k1 -0.020): the rest cost a
    // whole fit each for nothing.
    if (found_again) break;
    Rig rough = st;
    for (auto& c : rough.cameras) c.lens.estimate = !c.lens.pinhole();
    try {
      CalibrationResult r = calibrate_from_rig(rough, sets, ro);
      if (debug) {
        std::fprintf(stderr, "plumb fit: held out %.3f px, model %s, usable %d, ran off %d;", r.rotation_heldout_px,
                     camera_model_name(r.model), int(lens_fit_usable(r)), int(r.lens_ran_off));
        for (std::size_t i = 0; i < n; ++i)
          std::fprintf(stderr, " [start fx %.0f k1 %.3f -> %s fx %.0f k1 %.3f k2 %.3f]", st.cameras[i].fx, st.cameras[i].lens.k1,
                       lens_model_name(r.rig.cameras[i].lens.model), r.rig.cameras[i].fx, r.rig.cameras[i].lens.k1,
                       r.rig.cameras[i].lens.k2);
        std::fprintf(stderr, "\n");
      }
      if (!lens_fit_usable(r) || r.lens_ran_off) continue;
      const double px = r.rotation_heldout_px;
      found_again = best && std::abs(px - best->rotation_heldout_px) < 0.01 * px;
      if (!best || px < best->rotation_heldout_px) best = std::move(r);
    } catch (const CalibrationCancelled&) {
      throw;
    } catch (const std::exception& e) {
      if (debug) std::fprintf(stderr, "plumb fit: %s\n", e.what());
    }
  }
  if (!best) return std::nullopt;
  // A camera whose fitted radtan lens moves its frame's corner by under a tenth of a pixel (a 1x
  // camera the edges read a trace of distortion in) is a pinhole camera.
  for (auto& c : best->rig.cameras) {
    Eigen::Vector2d raw;
    if (c.lens.model == Lens::Model::Radtan && distort_point(c, {0.0, 0.0}, raw) && raw.norm() < 0.1) c.lens = Lens{};
  }
  best->projection_chosen = !o.projection;
  std::string said = "the cameras' lenses differ (straight edges in each camera's own frames:";
  for (std::size_t i = 0; i < n; ++i) {
    const Camera& c = best->rig.cameras[i];
    char b[96];
    std::snprintf(b, sizeof b, " camera %zu %s, fx %.0f%s", i, lens_model_name(c.lens.model), c.fx, i + 1 < n ? ";" : ")");
    said += b;
  }
  said += ": each camera calibrated with its own lens (held-out error " + std::to_string(best->rotation_heldout_px) +
          " px); give a rig-file to set them";
  best->warnings.push_back(said);
  return best;
}

constexpr double kFisheyeFallbackPoorPx = 1.5;
// The full-frame fisheye attempt of calibrate_from_images: when the pinhole path failed
// (pin null) or left more than kWideLensPoorPinholePx held out, and the matched rays fit a
// guessed fisheye clearly better than its rectilinear cameras (calibrate_full_frame_fisheyes);
// kept only when it wins by the lens evidence rule (lens_evidence_wins). Pixels alone do not tell: a row of 3 x 140 degrees
// at 384 px held 1.1 px out with homographies, its seams 40-130 px at 1280.
constexpr double kWideLensPoorPinholePx = 0.3;
static std::optional<CalibrationResult> full_frame_fisheyes_instead(const std::vector<std::vector<ImageView>>& sets,
                                                                    int reference, const CalibrationOptions& o,
                                                                    const CalibrationResult* pin, double pinhole_px,
                                                                    std::string& why_not) {
  if (!o.full_frame_fisheyes || sets.empty() || sets[0].size() < 2) return std::nullopt;
  // A pinhole fit that holds within a third of a pixel is not bent by a wide lens.
  if (pin && !(pinhole_px > kWideLensPoorPinholePx)) return std::nullopt;
  std::optional<CalibrationResult> wide = calibrate_full_frame_fisheyes(sets, reference, o, pin ? &pin->rig : nullptr, why_not);
  const double error = !wide ? -1 : wide->rotation_heldout_px > 0 ? wide->rotation_heldout_px : wide->ba_rms_after_px;
  if (std::getenv("STITCH_DEBUG_WIDE"))
    std::fprintf(stderr, "full-frame fisheyes: pinhole %.3f px, fisheye %.3f px; %s\n", pinhole_px, error, why_not.c_str());
  if (!wide) return std::nullopt;
  if (pin && !lens_evidence_wins(pinhole_px, error)) return std::nullopt;  // as any lens from the images
  return wide;
}

CalibrationResult calibrate_from_images(const std::vector<std::vector<ImageView>>& sets, int reference,
                                        const CalibrationOptions& o) {
  // Circles that no fisheye rig fits (a spotlit stage in a dark room?) fall back to the pinhole
  // path; when that fails too, the error says both.
  std::string fisheye_error;
  if (o.circular_fisheyes && !sets.empty()) {
    try {
      if (std::optional<CalibrationResult> fisheyes = calibrate_circular_fisheyes(sets, reference, o)) return *fisheyes;
    } catch (const RigError& e) {
      fisheye_error = e.what();
    }
  }
  CalibrationResult pin;
  try {
    pin = calibrate_from_images_pinhole(sets, reference, o);
  } catch (const RigError& e) {
    if (fisheye_error.empty()) {
      std::string why_not;
      if (std::optional<CalibrationResult> wide = full_frame_fisheyes_instead(sets, reference, o, nullptr, -1, why_not)) return *wide;
      // Said only when a fisheye rig got as far as a fit: cameras that share no matches either
      // way (a textureless view) keep the pinhole path's error alone.
      if (why_not.empty() || why_not.rfind("at a guessed", 0) == 0) throw;
      throw RigError(std::string(e.what()) + "; as full-frame fisheyes: " + why_not);
    }
    throw RigError(fisheye_error + "; as pinhole cameras: " + e.what());
  }
  const double pin_heldout = pin.model == CameraModel::Rotation ? pin.rotation_heldout_px : pin.homography_heldout_px;
  if (fisheye_error.empty()) {
    // Cameras whose own frames show different lenses (a mixed rig) get each its own lens: the
    // rig-wide choices below (one fisheye model for all, one radtan fit) cannot fit them.
    std::optional<CalibrationResult> mixed;
    if (o.per_camera_lenses) {
      mixed = calibrate_with_plumb_lenses(sets, reference, o);
      if (mixed && !(pin_heldout > 0 && mixed->rotation_heldout_px < pin_heldout)) mixed.reset();
    }
    // Alike full-frame fisheyes whose straight edges read a little differently (a ring's views
    // differ) may look mixed: the one fisheye model for all competes on held-out matches.
    std::string why_not;
    std::optional<CalibrationResult> wide = full_frame_fisheyes_instead(sets, reference, o, &pin, pin_heldout, why_not);
    if (mixed && (!wide || mixed->rotation_heldout_px < wide->rotation_heldout_px)) return *mixed;
    if (wide) return *wide;
  }
  // Image circles that no fisheye rig fitted, and a pinhole fit that is poor too (a fisheye ring
  // the guesses missed: 40 px held out): say so rather than hand back a panorama of discs
  // without a word. Vignetted rectilinear cameras fit as pinholes well: nothing to say there.
  if (!fisheye_error.empty() && pin_heldout > kFisheyeFallbackPoorPx)
    pin.warnings.push_back(fisheye_error + "; calibrated as pinhole (rectilinear) cameras instead, which fit them "
                           "poorly (held-out error " + std::to_string(pin_heldout) + " px)");
  else
    fisheye_error.clear();
  if (!o.lens_from_evidence || o.model == CameraModel::Homography || !(pin.rotation_heldout_px > 0)) return pin;
  if (!(pin_heldout > 0)) return pin;
  std::optional<CalibrationResult> best;
  for (const Rig& rough : lens_fit_starts(pin.rig, pin.model)) {
    CalibrationResult lens;
    try {
      CalibrationOptions lo = o;
      lo.model = CameraModel::Rotation;
      lens = calibrate_from_rig(rough, sets, lo);
    } catch (const CalibrationCancelled&) {
      throw;
    } catch (const std::exception&) {
      continue;  // no usable lens fit from this start
    }
    if (lens_fit_usable(lens) && (!best || lens.rotation_heldout_px < best->rotation_heldout_px)) best = std::move(lens);
  }
  if (!best) return pin;
  CalibrationResult& lens = *best;
  const double hl = lens.rotation_heldout_px;
  if (lens_evidence_wins(pin_heldout, hl)) {
    if (!fisheye_error.empty()) lens.warnings.insert(lens.warnings.begin(), pin.warnings.back());
    lens.warnings.push_back("lens distortion found in the images (held-out error " + std::to_string(pin_heldout) + " px pinhole, " +
                            std::to_string(hl) + " px with radtan k1/k2): the cameras get radtan lenses");
    return lens;
  }
  return pin;
}

namespace {
CalibrationResult calibrate_from_images_pinhole(const std::vector<std::vector<ImageView>>& sets, int reference,
                                                const CalibrationOptions& o) {
  throw_if_cancelled(o);
  if (sets.empty()) throw RigError("no frames to calibrate on");
  const std::vector<ImageView>& frames = sets[0];
  const int n = int(frames.size());
  if (n < 2) throw RigError("calibration needs at least two cameras");
  for (const auto& set : sets) {
    if (int(set.size()) != n) throw RigError("every frame set needs one frame per camera");
    check_frames(set);
  }
  if (reference >= n) throw RigError("reference camera index out of range");
  const FeatureSets feats = detect_all(sets, n, o);
  std::vector<cv::Mat> gray;  // area alignment (ring closure, overlap checks): the first instant
  for (const ImageView& f : frames) gray.push_back(to_gray(f));
  std::vector<PairData> pairs;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b)
      pairs.push_back(match_pair(feats, a, b, o, nullptr, 0));
  // The rotation model's fit of the usable pairs: focal lengths from the pairwise homographies
  // (median; sensible fields of view when they give none), rotations along the spanning tree,
  // bundle adjustment.
  auto fit_rotations = [&](const std::vector<PairData>& ps) {
    Rig r0;
    r0.reference = graph_centre(n, ps);
    r0.projection = "plane";
    for (int i = 0; i < n; ++i) {
      Camera c;
      c.width = frames[i].width;
      c.height = frames[i].height;
      c.cx = (c.width - 1) * 0.5;
      c.cy = (c.height - 1) * 0.5;
      r0.cameras.push_back(c);
    }
    auto start_with = [&](double hfov_deg, double f_px) {
      Rig r = r0;
      for (auto& c : r.cameras) c.fx = c.fy = f_px > 0 ? f_px : c.width / (2 * std::tan(hfov_deg * kPi / 360));
      rotations_from_pairs(r, ps);
      throw_if_cancelled(o);
      BundleAdjustOptions bo;
      bo.cancel = o.cancel;
      bo.deadline = o.deadline;
      return adjust(r, ps, bo);
    };
    RotationFit fit;
    const std::vector<double> fs = focal_estimates(r0, ps);
    if (!fs.empty()) fit = start_with(0, median_of(fs));
    if (!fit.ok || fit.ba.rms_after_px > 1.0)
      for (double hfov : {40.0, 60.0, 80.0, 100.0}) fit = best_of(fit, start_with(hfov, 0));
    return fit;
  };
  // Cameras the pairs leave apart: refused pairs with a few consistent matches between them,
  // kept when the rotation fit explains them (bridge_sparse_pairs).
  // Such a rig is kept only when every overlap its fit gives is verified by area below.
  std::string apart_error;
  const bool bridged = effective_model(o) != CameraModel::Homography && bridge_sparse_pairs(n, pairs, fit_rotations);
  // Every camera must hang on the match graph.
  {
    std::vector<bool> reach(n, false);
    reach[0] = true;
    for (const auto& e : max_spanning_order(n, 0, match_edges(pairs))) reach[e.first] = true;
    std::vector<int> alone, apart;
    for (int i = 0; i < n; ++i) {
      bool any = false;
      for (const auto& p : pairs) any |= p.ok && (p.a == i || p.b == i);
      if (!any) alone.push_back(i);
      else if (!reach[i]) apart.push_back(i);
    }
    if (bridged) {
      // The error the rig would have given without the looser pass (said when it is not verified).
      std::vector<PairData> strict = pairs;
      for (auto& p : strict)
        if (p.note.rfind("kept on a looser pass", 0) == 0) p.ok = false;
      std::vector<bool> r2(n, false);
      r2[0] = true;
      for (const auto& e : max_spanning_order(n, 0, match_edges(strict))) r2[e.first] = true;
      for (int i = 0; i < n && apart_error.empty(); ++i) {
        bool any = false;
        for (const auto& p : strict) any |= p.ok && (p.a == i || p.b == i);
        if (!any)
          apart_error = "camera " + std::to_string(i) + " shares too few features with the other cameras";
        else if (!r2[i])
          apart_error = "camera " + std::to_string(i) + " matches no camera of the group that camera 0 belongs to";
      }
    }
    if (!alone.empty())
      throw RigError("camera " + std::to_string(alone[0]) +
                     " shares too few features with the other cameras (no overlap, or a "
                     "textureless view): give a rig-file");
    if (!apart.empty())
      throw RigError("camera " + std::to_string(apart[0]) +
                     " matches no camera of the group that camera 0 belongs to (the cameras form "
                     "separate groups): give a rig-file");
  }
  int held = 0;
  for (const auto& p : pairs)
    if (p.ok) held += p.held_count();

  CameraModel model = effective_model(o);
  if (o.projection && *o.projection != Projection::Plane) model = CameraModel::Rotation;
  const std::vector<OverlapEdge> edges = match_edges(pairs);

  // The rotation model: focal lengths from the pairwise homographies (median; sensible fields
  // of view when they give none), rotations along the spanning tree, bundle adjustment.
  RotationFit rot;
  if (model != CameraModel::Homography) {
    rot = fit_rotations(pairs);
    // Refused pairs the fitted rotations overlap, matched again near them (rescue_pairs_by_
    // rotations); kept only when the refit explains them as well as the others.
    std::vector<PairData> before = pairs;
    if (rot.ok && rot.ba.rms_after_px <= 2.0 && rescue_pairs_by_rotations(rot.rig, feats, pairs, o)) {
      BundleAdjustOptions bo;
      bo.cancel = o.cancel;
      bo.deadline = o.deadline;
      const RotationFit again = adjust(rot.rig, pairs, bo);
      if (again.ok && again.ba.rms_after_px <= std::max(1.0, 1.5 * rot.ba.rms_after_px)) rot = again;
      else pairs = std::move(before);
    }
    // Pairs still refused, aligned by area (close_pairs_by_area): a ring closes on its closing pair.
    before = pairs;
    if (rot.ok && rot.ba.rms_after_px <= 2.0 && close_pairs_by_area(rot.rig, gray, pairs, o)) {
      BundleAdjustOptions bo;
      bo.cancel = o.cancel;
      bo.deadline = o.deadline;
      RotationFit again = adjust(rot.rig, pairs, bo);
      if (again.ok) {
        refresh_area_pairs(again.rig, gray, pairs, o);
        again = best_of(again, adjust(again.rig, pairs, bo));
      }
      if (again.ok && again.ba.rms_after_px <= std::max(1.0, 1.5 * rot.ba.rms_after_px)) rot = again;
      else pairs = std::move(before);
    }
  }
  // Every overlap feature matches do not tie, measured on the pictures (a rig joined on a looser
  // pass: every overlap). Far off: said; a looser pass that does not hold everywhere: refused.
  std::vector<OverlapCheck> checks;
  if (rot.ok) checks = check_overlaps(rot.rig, gray, pairs, bridged);
  if (bridged) {
    std::string why;
    for (const auto& c : checks)
      if (why.empty() && !(c.al.measured && c.al.offset_px <= kVerifiedPx))
        why = "cameras " + std::to_string(c.a) + " and " + std::to_string(c.b) +
              (c.al.measured ? " are " + std::to_string(c.al.offset_px).substr(0, 5) + " px apart where they overlap"
                             : " overlap where nothing could be verified");
    if (!rot.ok) why = "the rotation model does not fit the few matches";
    if (!why.empty())
      throw RigError(apart_error + " (no overlap, a textureless view, or too small an overlap; joined on fewer "
                     "matches, " + why + "): give a rig-file");
  }
  for (const auto& p : pairs)
    if (p.ok && p.area) held += p.held_count();
  CalibrationResult res;
  res.heldout_matches = held;
  Projection projection = o.projection ? *o.projection : Projection::Plane;
  if (rot.ok) {
    res.rotation_heldout_px = residuals(rot.rig, pairs, true, true).rms_px;
    rebase(rot.rig, reference >= 0 ? reference : median_heading_camera(rot.rig));
    if (o.wave_correct) wave_correct(rot.rig);
    const FieldOfView fov = field_of_view(rot.rig);
    res.hfov_deg = fov.h_deg;
    res.vfov_deg = fov.v_deg;
    // A rotation model that explains the matches badly (a translating rig) says nothing of the
    // field of view: such a rig stays on a plane.
    if (!o.projection && rot.ba.rms_after_px < 2.0) {
      projection = choose_projection(fov);
      res.projection_chosen = true;
    }
  } else if (model == CameraModel::Rotation) {
    throw RigError("the rotation model does not fit the matches (bundle adjustment failed)");
  }
  // The homography model (planar canvases): measured pairwise homographies refitted on the
  // fitted matches, chained from the match graph's centre along the strongest matches.
  Rig hrig;
  bool have_h = false;
  // Fitted also when the field of view asked for a curved canvas: a rig that the rotation model
  // explains clearly worse (lens distortion, translating cameras) is better off on a plane.
  if ((!o.projection || *o.projection == Projection::Plane) && model != CameraModel::Rotation) {
    hrig.reference = reference >= 0 ? reference : graph_centre(n, pairs);
    for (int i = 0; i < n; ++i) {
      Camera c;
      c.width = frames[i].width;
      c.height = frames[i].height;
      // No camera model: a nominal 60-degree lens so the file stays valid.
      c.fx = c.fy = c.width / (2 * std::tan(30.0 * kPi / 180));
      c.cx = (c.width - 1) * 0.5;
      c.cy = (c.height - 1) * 0.5;
      hrig.cameras.push_back(c);
    }
    hrig.cameras[hrig.reference].homography = Eigen::Matrix3d::Identity();
    for (const auto& [cam, parent] : max_spanning_order(n, hrig.reference, edges)) {
      const PairData& p = *find_pair(pairs, cam, parent);
      std::vector<cv::Point2f> s, d;
      for (std::size_t k = 0; k < p.pa.size(); ++k)
        if (!p.held[k]) {
          s.emplace_back(float(p.pa[k].x()), float(p.pa[k].y()));
          d.emplace_back(float(p.pb[k].x()), float(p.pb[k].y()));
        }
      Eigen::Matrix3d Hab = p.H;
      if (s.size() >= 8) {
        cv::Mat H = cv::findHomography(s, d, 0);
        if (!H.empty()) Hab = to_eigen(H);
      }
      const Eigen::Matrix3d Hcp = p.a == cam ? Hab : Eigen::Matrix3d(Hab.inverse());
      const Eigen::Matrix3d H = *hrig.cameras[parent].homography * Hcp;
      hrig.cameras[cam].homography = H / H(2, 2);
    }
    have_h = true;
    res.homography_heldout_px = residuals(hrig, pairs, false, true).rms_px;
  }
  bool use_rotation = rot.ok && (!have_h || model == CameraModel::Rotation ||
                                 !homography_wins(res.rotation_heldout_px, res.homography_heldout_px));
  // Auto: free homographies that scale one camera over 2x another are a layout no rig of like
  // cameras looking at one plane gives. A rotating pair over a near plane (a desk) lets the 8
  // free parameters fit that plane: on a real two-phone office clip they won 1.5-1.7x on 10-40
  // held-out matches, frame after frame, at 2.3-4.3x (a stretched plane, 40% black). Planar
  // scenes measured 1.0-1.7x (newspaper, prague, uttower, snow, carpark; the synthetic pairs 1.0).
  if (!use_rotation && rot.ok && model == CameraModel::Auto && homography_stretch(hrig) > kMaxHomographyStretch)
    use_rotation = true;
  if (!use_rotation) {
    try {
      res.model = CameraModel::Homography;
      res.rig = hrig;
      res.projection_chosen = false;
      rig_layout_canvas(res.rig);
    } catch (const RigError& e) {
      if (!rot.ok) throw;
      res.warnings.push_back(std::string("the homography model fits better but gives no usable plane canvas (") +
                             e.what() + "): using the rotation model");
      use_rotation = true;
    }
  }
  if (use_rotation) {
    res.model = CameraModel::Rotation;
    res.rig = rot.rig;
    res.rig.projection = projection_name(projection);
    res.ba_rms_before_px = rot.ba.rms_before_px;
    res.ba_rms_after_px = rot.ba.rms_after_px;
    finish_rotation_rig(res.rig, o, false);
  }
  res.refined_cameras = res.rig.planar() ? n - 1 : n;  // the plane is the reference's image plane
  fill_reports(res, pairs, use_rotation);
  if (use_rotation) report_overlap_checks(res, checks);
  return res;
}
}  // namespace

namespace {
// Canvas pixels per camera pixel around `p` (which maps to `q`): the square root of the map's
// local area scale; <= 0 where the neighbours do not map.
double local_canvas_scale(const CameraCanvasMap& m, const Eigen::Vector2d& p, const Eigen::Vector2d& q, double wrap) {
  Eigen::Vector2d qx, qy;
  if (!m.to_canvas(p + Eigen::Vector2d(1, 0), qx) || !m.to_canvas(p + Eigen::Vector2d(0, 1), qy)) return -1;
  Eigen::Vector2d dx = qx - q, dy = qy - q;
  if (wrap > 0) {
    dx.x() -= std::round(dx.x() / wrap) * wrap;
    dy.x() -= std::round(dy.x() / wrap) * wrap;
  }
  return std::sqrt(std::abs(dx.x() * dy.y() - dx.y() * dy.x()));
}
}  // namespace

AlignmentReport measure_alignment(const Rig& rig, const std::vector<ImageView>& frames) {
  AlignmentReport rep;
  const int n = int(rig.cameras.size());
  if (int(frames.size()) != n) throw RigError("frame count differs from the rig");
  CalibrationOptions o;
  o.features = FeatureType::Sift;
  std::vector<Features> feats(n);
  for (int i = 0; i < n; ++i) feats[i] = detect(to_gray(frames[i]), cv::Mat(), o);
  std::vector<double> all, all_cam;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      if (overlap_box(rig, a, b).area() <= 0) continue;
      auto m = match(feats[a], feats[b], o.features);
      if (m.size() < 8) continue;
      std::vector<cv::Point2f> pa, pb;
      for (const auto& mt : m) {
        pa.push_back(feats[a].keypoints[mt.queryIdx].pt);
        pb.push_back(feats[b].keypoints[mt.trainIdx].pt);
      }
      std::vector<uchar> inl;
      const Camera &A = rig.cameras[a], &B = rig.cameras[b];
      const bool on_rays = !rig.planar() && (needs_rays(A) || needs_rays(B));
      if (on_rays) {
        // Wide lenses on a curved canvas (a dual fisheye's overlap lies 80-100 degrees off both
        // axes, where ideal pinhole pixels do not exist and the epipolar test below took wrong
        // matches: the exact rig of a dual fisheye read 400-800 px misaligned). The cameras turn
        // about one centre: inliers are the matches one rotation of the rays explains, found
        // from the matches alone (RANSAC over 2-ray rotations), not from the rig's rotations.
        std::vector<Eigen::Vector3d> ra, rb;
        std::vector<cv::Point2f> ka, kb;
        for (std::size_t k = 0; k < pa.size(); ++k) {
          Eigen::Vector3d x, y;
          if (!lens_sees(A, pa[k].x, pa[k].y) || !lens_sees(B, pb[k].x, pb[k].y)) continue;
          if (!lens_unproject(A, {pa[k].x, pa[k].y}, x) || !lens_unproject(B, {pb[k].x, pb[k].y}, y)) continue;
          ra.push_back(x.normalized());
          rb.push_back(y.normalized());
          ka.push_back(pa[k]);
          kb.push_back(pb[k]);
        }
        if (ra.size() < 8) continue;
        std::vector<int> all(ra.size());
        for (std::size_t k = 0; k < all.size(); ++k) all[k] = int(k);
        const double thr = std::cos(2.0 / std::max(1.0, std::min({A.fx, A.fy, B.fx, B.fy})));  // ~2 px
        std::vector<int> in = ray_rotation_inliers(ra, rb, all, Eigen::Matrix3d::Identity(), thr, 1000);
        if (in.size() >= 8) in = ray_rotation_inliers(ra, rb, all, kabsch(ra, rb, in), thr, 0);
        if (in.size() < 8) continue;
        inl.assign(ra.size(), 0);
        for (int k : in) inl[std::size_t(k)] = 1;
        pa = std::move(ka);
        pb = std::move(kb);
      } else {
        // The epipolar test holds for ideal pixels: undistort through the rig's lenses first
        // (the distances below map the raw keypoints through the lens-aware canvas maps).
        std::vector<cv::Point2f> ua = pa, ub = pb;
        if (!rig.cameras[a].lens.pinhole() || !rig.cameras[b].lens.pinhole()) {
          std::vector<cv::Point2f> ka, kb, ra, rb;
          const std::vector<cv::Point2f> ia = undistort_points(rig.cameras[a], pa), ib = undistort_points(rig.cameras[b], pb);
          for (std::size_t k = 0; k < pa.size(); ++k)
            if (std::isfinite(ia[k].x) && std::isfinite(ia[k].y) && std::isfinite(ib[k].x) && std::isfinite(ib[k].y)) {
              ka.push_back(ia[k]);
              kb.push_back(ib[k]);
              ra.push_back(pa[k]);
              rb.push_back(pb[k]);
            }
          if (ka.size() < 8) continue;
          ua = std::move(ka);
          ub = std::move(kb);
          pa = std::move(ra);
          pb = std::move(rb);
        }
        cv::Mat F = cv::findFundamentalMat(ua, ub, inl, cv::FM_RANSAC, 1.5, 0.999);
        if (F.empty()) continue;
      }
      std::vector<double> d, dc;
      const CameraCanvasMap ma = camera_canvas_map(rig, a), mb = camera_canvas_map(rig, b);
      const double wrap = rig.canvas_wrap ? double(rig.canvas_width) : 0.0;
      for (std::size_t k = 0; k < pa.size(); ++k) {
        Eigen::Vector2d qa, qb;
        const Eigen::Vector2d xa(pa[k].x, pa[k].y), xb(pb[k].x, pb[k].y);
        if (!inl[k] || !ma.to_canvas(xa, qa) || !mb.to_canvas(xb, qb)) continue;
        double dx = qa.x() - qb.x();
        if (rig.canvas_wrap) dx -= std::round(dx / rig.canvas_width) * rig.canvas_width;  // across the wrap
        d.push_back(std::hypot(dx, qa.y() - qb.y()));
        const double sa = local_canvas_scale(ma, xa, qa, wrap), sb = local_canvas_scale(mb, xb, qb, wrap);
        if (sa > 0 && sb > 0) dc.push_back(d.back() / std::sqrt(sa * sb));
      }
      // Views that share no scene still give a few matches a fundamental matrix takes (7-10 of
      // 13-21 across unrelated pictures, 200-660 px apart on the canvas); a real overlap gives
      // dozens. Fewer than 16 measure nothing. One rotation of the rays (2 px, 3 unknowns) takes
      // no chance matches: 8 do (a 190-degree dual fisheye's thin ring gives ~10).
      const std::size_t min_matches = on_rays ? 8 : 16;
      if (d.size() < min_matches) continue;
      std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
      rep.pair_median_px.push_back(d[d.size() / 2]);
      all.insert(all.end(), d.begin(), d.end());
      rep.pair_median_camera_px.push_back(dc.empty() ? -1 : median_of(dc));
      all_cam.insert(all_cam.end(), dc.begin(), dc.end());
    }
  if (!all_cam.empty()) rep.median_camera_px = median_of(std::move(all_cam));
  if (!all.empty()) {
    std::nth_element(all.begin(), all.begin() + all.size() * 9 / 10, all.end());
    rep.p90_px = all[all.size() * 9 / 10];
    std::nth_element(all.begin(), all.begin() + all.size() / 2, all.end());
    rep.median_px = all[all.size() / 2];
    rep.matches = int(all.size());
  }
  return rep;
}

}  // namespace stitch
