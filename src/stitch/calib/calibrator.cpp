#include "stitch/calib/calibrator.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <numeric>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <queue>
#include <random>

#include "stitch/calib/bundle_adjust.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
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

cv::Mat to_gray(const ImageView& v) {
  cv::Mat gray;
  cv::cvtColor(as_mat(v), gray, cv::COLOR_RGBA2GRAY);
  return gray;
}

Features detect(const cv::Mat& gray, const cv::Mat& mask, const CalibrationOptions& o) {
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
  for (auto& kp : f.keypoints) {
    // Back to full resolution, pixel-centre convention.
    kp.pt.x = float((kp.pt.x + 0.5) / s - 0.5);
    kp.pt.y = float((kp.pt.y + 0.5) / s - 0.5);
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

// Mask of the camera pixels that land in the (widened) canvas box.
cv::Mat camera_mask(const Camera& c, const cv::Rect2d& box) {
  cv::Mat mask(c.height, c.width, CV_8U, cv::Scalar(0));
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

cv::Point2f to_canvas(const Camera& c, const cv::Point2f& p) {
  Eigen::Vector2d q = apply_homography(*c.homography, {p.x, p.y});
  return {float(q.x()), float(q.y())};
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

// The rotation model (every camera turns about one centre): feature matches of every pair that
// the rough rotations say may overlap, checked against the rough pairwise homography, then one
// bundle adjustment of all rotations and focal lengths, wave correction (non-planar), and the
// canvas (planar: the reference camera's image plane).
CalibrationResult calibrate_rotations(const Rig& rough, const std::vector<std::vector<ImageView>>& sets,
                                      const CalibrationOptions& o) {
  CalibrationResult res;
  res.rig = rough;
  Rig& rig = res.rig;
  const int n = int(rig.cameras.size());
  std::vector<std::vector<Features>> feats(sets.size(), std::vector<Features>(n));
  for (std::size_t t = 0; t < sets.size(); ++t)
    for (int i = 0; i < n; ++i) feats[t][i] = detect(to_gray(sets[t][i]), cv::Mat(), o);
  std::vector<PairMatches> matches;
  std::vector<bool> matched(n, false);
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      const Camera &A = rig.cameras[a], &B = rig.cameras[b];
      const double axes = std::acos(std::clamp(A.R().col(2).dot(B.R().col(2)), -1.0, 1.0));
      if (axes > (half_diagonal_fov(A) + half_diagonal_fov(B)) * (1 + o.overlap_margin)) continue;
      PairReport rep;
      rep.camera = b;
      rep.neighbour = a;
      std::vector<cv::Point2f> pa, pb;
      for (const auto& f : feats)
        for (const auto& mt : match(f[a], f[b], o.features)) {
          pa.push_back(f[a].keypoints[mt.queryIdx].pt);
          pb.push_back(f[b].keypoints[mt.trainIdx].pt);
        }
      rep.matches = int(pa.size());
      std::vector<uchar> inl;
      cv::Mat H;
      if (pa.size() >= 8) H = cv::findHomography(pa, pb, cv::RANSAC, o.ransac_threshold_px, inl, 2000, 0.995);
      rep.inliers = H.empty() ? 0 : cv::countNonZero(inl);
      // The matches must agree with the rough geometry: a repeated texture elsewhere in the
      // view would otherwise pull the pair together wrongly.
      const Eigen::Matrix3d predicted = rough_pairwise_homography(rig, a, b);
      PairMatches pm;
      pm.a = a;
      pm.b = b;
      for (std::size_t k = 0; k < pa.size() && rep.inliers >= o.min_inliers; ++k) {
        if (!inl[k]) continue;
        const Eigen::Vector2d q = apply_homography(predicted, {pa[k].x, pa[k].y});
        if ((q - Eigen::Vector2d(pb[k].x, pb[k].y)).norm() > 0.25 * std::max(B.width, B.height)) continue;
        pm.pa.emplace_back(pa[k].x, pa[k].y);
        pm.pb.emplace_back(pb[k].x, pb[k].y);
      }
      rep.accepted = int(pm.pa.size()) >= o.min_inliers;
      if (rep.accepted) {
        // At most 300 matches a pair, spread over the list: enough for 4 parameters a camera.
        if (pm.pa.size() > 300) {
          PairMatches thin = pm;
          thin.pa.clear();
          thin.pb.clear();
          for (std::size_t k = 0; k < 300; ++k) {
            thin.pa.push_back(pm.pa[k * pm.pa.size() / 300]);
            thin.pb.push_back(pm.pb[k * pm.pb.size() / 300]);
          }
          pm = std::move(thin);
        }
        matches.push_back(pm);
        matched[a] = matched[b] = true;
      } else if (rep.matches > 0) {
        rep.note = "too few matches that agree with the rough rig (" + std::to_string(pm.pa.size()) + ")";
      }
      res.pairs.push_back(rep);
    }
  for (int i = 0; i < n; ++i)
    if (!matched[i])
      res.warnings.push_back("camera " + std::to_string(i) + ": no feature matches with any other camera; "
                             "keeping its rough rotation and focal length");
  if (!matches.empty()) {
    const BundleAdjustReport ba = bundle_adjust(rig, matches);
    res.ba_rms_before_px = ba.rms_before_px;
    res.ba_rms_after_px = ba.rms_after_px;
    if (ba.ok) {
      for (int i = 0; i < n; ++i) res.refined_cameras += matched[i];
      for (auto& rep : res.pairs) {
        if (!rep.accepted) continue;
        double sum = 0;
        int count = 0;
        for (const auto& pm : matches)
          if (pm.a == rep.neighbour && pm.b == rep.camera)
            for (std::size_t k = 0; k < pm.pa.size(); ++k, ++count)
              sum += std::pow(transfer_error_px(rig, pm.a, pm.b, pm.pa[k], pm.pb[k]), 2);
        rep.rms_px = count ? std::sqrt(sum / count) : 0;
      }
    } else {
      res.warnings.push_back("bundle adjustment did not converge: keeping the rough rotations");
    }
  }
  if (!rig.planar()) {
    if (o.wave_correct) wave_correct(rig);
    rig.canvas_scale = 0;  // follow the refined focal lengths
  } else {
    for (int i = 0; i < n; ++i) rig.cameras[i].homography = rough_pairwise_homography(rig, i, rig.reference);
  }
  rig_layout_canvas(rig);
  return res;
}

}  // namespace

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

CalibrationResult calibrate_from_rig(const Rig& rough, const std::vector<std::vector<ImageView>>& sets,
                                     const CalibrationOptions& o) {
  if (sets.empty()) throw RigError("no frames to calibrate on");
  for (const auto& frames : sets) {
    if (frames.size() != rough.cameras.size())
      throw RigError("the rig has " + std::to_string(rough.cameras.size()) + " cameras but " +
                     std::to_string(frames.size()) + " streams are connected");
    check_frames(frames);
  }
  if (o.refinement != Refinement::None && (!rough.planar() || o.bundle_adjust)) {
    if (rough.planar() && rough.plane_distance_m > 0)
      throw RigError("bundle adjustment models a rotating rig: it cannot refine plane-induced homographies "
                     "(plane_distance_m with camera positions); turn bundle-adjust off");
    if (rough.reference < 0 || rough.reference >= int(rough.cameras.size()))
      throw RigError("reference camera index out of range");
    return calibrate_rotations(rough, sets, o);
  }
  CalibrationResult res;
  res.rig = rough;
  bool have_all = true;
  for (const auto& c : rough.cameras) have_all &= bool(c.homography);
  if (!have_all) rig_compute_rough_homographies(res.rig);
  else rig_layout_canvas(res.rig);
  Rig& rig = res.rig;
  const int n = int(rig.cameras.size());

  const std::vector<OverlapEdge> edges = overlap_edges(rig);
  std::vector<bool> connected(n, false);
  connected[rig.reference] = true;
  for (const auto& e : edges) connected[e.a] = connected[e.b] = true;
  for (int i = 0; i < n; ++i)
    if (!connected[i]) res.warnings.push_back("camera " + std::to_string(i) + " overlaps no other camera");
  if (o.refinement == Refinement::None || n < 2) return res;

  // gray[set][camera]: matches are pooled over the sets (several instants of a static rig).
  std::vector<std::vector<cv::Mat>> gray(sets.size(), std::vector<cv::Mat>(n));
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
      const cv::Mat mask_c = camera_mask(rig.cameras[cam], box), mask_n = camera_mask(rig.cameras[nb], box);
      for (const auto& g : gray) {
        Features fc = detect(g[cam], mask_c, o);
        Features fn = detect(g[nb], mask_n, o);
        for (const auto& mt : match(fc, fn, o.features)) {
          src.push_back(to_canvas(rig.cameras[cam], fc.keypoints[mt.queryIdx].pt));
          dst.push_back(to_canvas(rig.cameras[nb], fn.keypoints[mt.trainIdx].pt));
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
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) C(r, c) = Hc.at<double>(r, c);
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
          if (!H2.empty())
            for (int r = 0; r < 3; ++r)
              for (int c = 0; c < 3; ++c) C(r, c) = H2.at<double>(r, c);
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
  return res;
}

CalibrationResult calibrate_from_images(const std::vector<ImageView>& frames, int reference,
                                        const CalibrationOptions& o) {
  return calibrate_from_images(std::vector<std::vector<ImageView>>{frames}, reference, o);
}

CalibrationResult calibrate_from_images(const std::vector<std::vector<ImageView>>& sets, int reference,
                                        const CalibrationOptions& o) {
  if (sets.empty()) throw RigError("no frames to calibrate on");
  if (o.bundle_adjust)
    throw RigError("bundle adjustment needs rough camera parameters (focal lengths, rotations): give a rig-file");
  const std::vector<ImageView>& frames = sets[0];
  const int n = int(frames.size());
  if (n < 2) throw RigError("calibration needs at least two cameras");
  for (const auto& set : sets) {
    if (int(set.size()) != n) throw RigError("every frame set needs one frame per camera");
    check_frames(set);
  }
  if (reference < 0) reference = n / 2;
  if (reference >= n) throw RigError("reference camera index out of range");
  std::vector<std::vector<Features>> feats(sets.size(), std::vector<Features>(n));
  for (std::size_t t = 0; t < sets.size(); ++t)
    for (int i = 0; i < n; ++i) feats[t][i] = detect(to_gray(sets[t][i]), cv::Mat(), o);

  struct PairH {
    Eigen::Matrix3d H;  // a -> b pixels
    int inliers = 0, matches = 0;
  };
  std::vector<std::vector<PairH>> pair(n, std::vector<PairH>(n));
  std::vector<OverlapEdge> edges;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      std::vector<cv::Point2f> pa, pb;
      for (const auto& f : feats)
        for (const auto& mt : match(f[a], f[b], o.features)) {
          pa.push_back(f[a].keypoints[mt.queryIdx].pt);
          pb.push_back(f[b].keypoints[mt.trainIdx].pt);
        }
      pair[a][b].matches = int(pa.size());
      if (pa.size() < 8) continue;
      std::vector<uchar> inl;
      cv::Mat H = cv::findHomography(pa, pb, cv::RANSAC, o.ransac_threshold_px, inl, 2000, 0.995);
      if (H.empty()) continue;
      const int count = cv::countNonZero(inl);
      if (count < o.min_inliers) continue;
      Eigen::Matrix3d E;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) E(r, c) = H.at<double>(r, c);
      if (!homography_problem(E, frames[a].width, frames[a].height).empty()) continue;
      pair[a][b] = {E, count, int(pa.size())};
      pair[b][a] = {E.inverse(), count, int(pa.size())};
      edges.push_back({a, b, double(count)});
    }
  CalibrationResult res;
  Rig& rig = res.rig;
  rig.reference = reference;
  rig.cameras.resize(n);
  for (int i = 0; i < n; ++i) {
    Camera& c = rig.cameras[i];
    c.width = frames[i].width;
    c.height = frames[i].height;
    // No camera model is known: record a nominal 60-degree lens so the file stays valid.
    c.fx = c.fy = c.width / (2 * std::tan(30.0 * 3.14159265358979 / 180));
    c.cx = (c.width - 1) * 0.5;
    c.cy = (c.height - 1) * 0.5;
  }
  rig.cameras[reference].homography = Eigen::Matrix3d::Identity();
  for (const auto& [cam, parent] : max_spanning_order(n, reference, edges)) {
    const Eigen::Matrix3d H = *rig.cameras[parent].homography * pair[cam][parent].H;
    rig.cameras[cam].homography = H / H(2, 2);
    PairReport rep;
    rep.camera = cam;
    rep.neighbour = parent;
    rep.matches = pair[cam][parent].matches;
    rep.inliers = pair[cam][parent].inliers;
    rep.accepted = true;
    res.pairs.push_back(rep);
    ++res.refined_cameras;
  }
  for (int i = 0; i < n; ++i)
    if (!rig.cameras[i].homography)
      throw RigError("camera " + std::to_string(i) +
                     " shares too few features with the other cameras (no overlap, or a "
                     "textureless view): give a rig-file");
  rig_layout_canvas(rig);
  return res;
}

AlignmentReport measure_alignment(const Rig& rig, const std::vector<ImageView>& frames) {
  AlignmentReport rep;
  const int n = int(rig.cameras.size());
  if (int(frames.size()) != n) throw RigError("frame count differs from the rig");
  CalibrationOptions o;
  o.features = FeatureType::Sift;
  std::vector<Features> feats(n);
  for (int i = 0; i < n; ++i) feats[i] = detect(to_gray(frames[i]), cv::Mat(), o);
  std::vector<double> all;
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
      cv::Mat F = cv::findFundamentalMat(pa, pb, inl, cv::FM_RANSAC, 1.5, 0.999);
      if (F.empty()) continue;
      std::vector<double> d;
      const CameraCanvasMap ma = camera_canvas_map(rig, a), mb = camera_canvas_map(rig, b);
      for (std::size_t k = 0; k < pa.size(); ++k) {
        Eigen::Vector2d qa, qb;
        if (!inl[k] || !ma.to_canvas({pa[k].x, pa[k].y}, qa) || !mb.to_canvas({pb[k].x, pb[k].y}, qb)) continue;
        double dx = qa.x() - qb.x();
        if (rig.canvas_wrap) dx -= std::round(dx / rig.canvas_width) * rig.canvas_width;  // across the wrap
        d.push_back(std::hypot(dx, qa.y() - qb.y()));
      }
      if (d.size() < 8) continue;
      std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
      rep.pair_median_px.push_back(d[d.size() / 2]);
      all.insert(all.end(), d.begin(), d.end());
    }
  if (!all.empty()) {
    std::nth_element(all.begin(), all.begin() + all.size() / 2, all.end());
    rep.median_px = all[all.size() / 2];
    rep.matches = int(all.size());
  }
  return rep;
}

}  // namespace stitch
