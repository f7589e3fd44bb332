#include "stitch/calib/photometric_refine.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "stitch/rig/lens.hpp"

namespace stitch {

namespace {

struct View {
  cv::Mat img, gx, gy;  // CV_32F, smoothed; gradients per pixel
};

// Bilinear sample of a CV_32F image at (x, y); false outside [0, w-1) x [0, h-1).
inline bool bilinear(const cv::Mat& m, double x, double y, double& v) {
  if (!(x >= 0 && y >= 0 && x < m.cols - 1 && y < m.rows - 1)) return false;
  const int x0 = int(x), y0 = int(y);
  const double fx = x - x0, fy = y - y0;
  const float* r0 = m.ptr<float>(y0) + x0;
  const float* r1 = m.ptr<float>(y0 + 1) + x0;
  v = (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
  return true;
}

struct Sample {
  int set = 0, link = 0;
  Eigen::Vector3d ray;  // rig frame, fixed during the fit
};

// Where camera c's free parameters sit in the parameter vector (-1: held).
struct Slots {
  int rot = -1;   // 3 (axis-angle, right-multiplied: R <- R exp(w))
  int focal = -1; // 1 (relative)
  int lens = -1;  // 2 (k1, k2)
};


bool inside(const Camera& c, const Eigen::Vector2d& p, int margin) {
  return p.x() >= margin && p.y() >= margin && p.x() < c.width - 1 - margin && p.y() < c.height - 1 - margin &&
         lens_sees(c, p.x(), p.y());
}

// Camera c perturbed along its k-th local parameter (0-2 rotation, 3 focal, 4-5 k1 / k2) by h.
Camera perturbed(const Camera& c, int k, double h) {
  Camera p = c;
  if (k < 3) {
    Eigen::Vector3d w = Eigen::Vector3d::Zero();
    w[k] = h;
    p.set_R(c.R() * Eigen::AngleAxisd(h, w.normalized()).toRotationMatrix());
  } else if (k == 3) {
    p.fx *= 1 + h;
    p.fy *= 1 + h;
  } else if (k == 4) {
    p.lens.k1 += h;
  } else {
    p.lens.k2 += h;
  }
  return p;
}

}  // namespace

PhotometricRefineResult photometric_refine(Rig& rig, const std::vector<std::pair<int, int>>& links,
                                           const std::vector<std::vector<cv::Mat>>& gray,
                                           const std::vector<bool>& refine_lens, const PhotometricRefineOptions& o) {
  PhotometricRefineResult res;
  const int n = int(rig.cameras.size());
  if (links.empty() || gray.empty() || n < 2) return res;
  // Smoothed views and their gradients.
  std::vector<std::vector<View>> views(gray.size());
  for (std::size_t s = 0; s < gray.size(); ++s) {
    if (int(gray[s].size()) != n) return res;
    for (int i = 0; i < n; ++i) {
      View v;
      gray[s][i].convertTo(v.img, CV_32F);
      if (o.blur_sigma > 0) cv::GaussianBlur(v.img, v.img, cv::Size(), o.blur_sigma);
      cv::Sobel(v.img, v.gx, CV_32F, 1, 0, 3, 1.0 / 8);
      cv::Sobel(v.img, v.gy, CV_32F, 0, 1, 3, 1.0 / 8);
      views[s].push_back(std::move(v));
    }
  }
  // Samples keep clear of the frame's edge by the smoothing's reach (a blurred border is not the scene).
  const int kMargin = 3 + int(std::ceil(3 * std::max(o.blur_sigma, 0.0)));
  // Parameters.
  std::vector<Slots> slots(n);
  int P = 0;
  for (int i = 0; i < n; ++i) {
    if (i != rig.reference) slots[i].rot = P, P += 3;
    slots[i].focal = P++;
    if (i < int(refine_lens.size()) && refine_lens[i] && rig.cameras[i].lens.model == Lens::Model::Radtan)
      slots[i].lens = P, P += 2;
  }
  const int photo0 = P;
  P += 2 * int(links.size());  // per link: gain, offset (b's brightness -> a's)

  // Samples: scene rays on a grid of each camera of a pair, seen by both, with texture.
  std::vector<Sample> samples;
  for (std::size_t s = 0; s < gray.size(); ++s)
    for (int l = 0; l < int(links.size()); ++l)
      for (int side = 0; side < 2; ++side) {
        const int from = side ? links[l].second : links[l].first, to = side ? links[l].first : links[l].second;
        const Camera &F = rig.cameras[from], &T = rig.cameras[to];
        const Eigen::Matrix3d Rf = F.R(), Rt = T.R().transpose();
        const View& vf = views[s][from];
        for (int y = kMargin + 1; y < F.height - kMargin - 1; y += o.step_px)
          for (int x = kMargin + 1 + (y / o.step_px) % 2; x < F.width - kMargin - 1; x += o.step_px) {
            if (!lens_sees(F, x, y)) continue;
            const double g = std::hypot(vf.gx.at<float>(y, x), vf.gy.at<float>(y, x));
            if (g < o.min_gradient) continue;
            Eigen::Vector3d ray;
            Eigen::Vector2d q;
            if (!lens_unproject(F, {double(x), double(y)}, ray)) continue;
            const Eigen::Vector3d world = Rf * ray;
            if (!lens_project(T, Rt * world, q) || !inside(T, q, kMargin)) continue;
            samples.push_back({int(s), l, world});
          }
      }
  res.samples = int(samples.size());
  if (samples.size() < 200) return res;

  std::vector<Camera> cams = rig.cameras;
  Eigen::VectorXd photo(2 * links.size());
  for (std::size_t l = 0; l < links.size(); ++l) photo[2 * l] = 1, photo[2 * l + 1] = 0;

  // Residuals (a - (g b + h)) of every sample under `cs` / `ph`; NaN where a view is lost.
  auto residuals = [&](const std::vector<Camera>& cs, const Eigen::VectorXd& ph, std::vector<double>& r) {
    r.assign(samples.size(), std::numeric_limits<double>::quiet_NaN());
    std::vector<Eigen::Matrix3d> Rt(n);
    for (int i = 0; i < n; ++i) Rt[i] = cs[i].R().transpose();
    for (std::size_t k = 0; k < samples.size(); ++k) {
      const Sample& sm = samples[k];
      const int a = links[sm.link].first, b = links[sm.link].second;
      Eigen::Vector2d pa, pb;
      double ia, ib;
      if (!lens_project(cs[a], Rt[a] * sm.ray, pa) || !inside(cs[a], pa, kMargin - 2)) continue;
      if (!lens_project(cs[b], Rt[b] * sm.ray, pb) || !inside(cs[b], pb, kMargin - 2)) continue;
      if (!bilinear(views[sm.set][a].img, pa.x(), pa.y(), ia) || !bilinear(views[sm.set][b].img, pb.x(), pb.y(), ib))
        continue;
      r[k] = ia - (ph[2 * sm.link] * ib + ph[2 * sm.link + 1]);
    }
  };
  auto robust_sigma = [](const std::vector<double>& r) {
    std::vector<double> a;
    for (double v : r)
      if (std::isfinite(v)) a.push_back(std::abs(v));
    if (a.empty()) return 0.0;
    std::nth_element(a.begin(), a.begin() + a.size() / 2, a.end());
    return 1.4826 * a[a.size() / 2];
  };
  auto cost_of = [&](const std::vector<double>& r, double c) {
    double sum = 0;
    for (double v : r) sum += std::isfinite(v) ? std::log1p((v / c) * (v / c)) : std::log1p(9.0);
    return sum;
  };
  auto apply = [&](const std::vector<Camera>& cs, const Eigen::VectorXd& ph, const Eigen::VectorXd& d,
                   std::vector<Camera>& out_c, Eigen::VectorXd& out_ph) {
    out_c = cs;
    for (int i = 0; i < n; ++i) {
      Camera& c = out_c[i];
      if (slots[i].rot >= 0) {
        const Eigen::Vector3d w = d.segment<3>(slots[i].rot);
        if (w.norm() > 0) c.set_R(cs[i].R() * Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix());
      }
      c.fx = cs[i].fx * (1 + d[slots[i].focal]);
      c.fy = cs[i].fy * (1 + d[slots[i].focal]);
      if (slots[i].lens >= 0) c.lens.k1 = cs[i].lens.k1 + d[slots[i].lens], c.lens.k2 = cs[i].lens.k2 + d[slots[i].lens + 1];
    }
    out_ph = ph + d.segment(photo0, ph.size());
  };

  std::vector<double> r;
  residuals(cams, photo, r);
  const double sigma0 = robust_sigma(r);
  if (!(sigma0 > 0)) return res;
  res.rms_before = sigma0;
  double lambda = 1e-3;
  bool moved = false;
  for (int it = 0; it < o.iterations; ++it) {
    const double c = o.robust_scale * std::max(robust_sigma(r), 1e-3);
    const double cost = cost_of(r, c);
    // Normal equations (Cauchy weights), geometry's Jacobians by forward differences.
    std::vector<std::array<Camera, 6>> pert(n);
    for (int i = 0; i < n; ++i)
      for (int k = 0; k < 6; ++k) pert[i][k] = perturbed(cams[i], k, k < 3 ? 1e-6 : k == 3 ? 1e-6 : 1e-6);
    std::vector<Eigen::Matrix3d> Rt(n);
    for (int i = 0; i < n; ++i) Rt[i] = cams[i].R().transpose();
    Eigen::MatrixXd H = Eigen::MatrixXd::Zero(P, P);
    Eigen::VectorXd g = Eigen::VectorXd::Zero(P);
    std::vector<int> idx;
    std::vector<double> jrow;
    for (std::size_t k = 0; k < samples.size(); ++k) {
      if (!std::isfinite(r[k])) continue;
      const Sample& sm = samples[k];
      const int l = sm.link, a = links[l].first, b = links[l].second;
      idx.clear();
      jrow.clear();
      bool bad = false;
      for (int side = 0; side < 2 && !bad; ++side) {
        const int cam = side ? b : a;
        const View& v = views[sm.set][cam];
        Eigen::Vector2d p;
        lens_project(cams[cam], Rt[cam] * sm.ray, p);
        double gx, gy;
        if (!bilinear(v.gx, p.x(), p.y(), gx) || !bilinear(v.gy, p.x(), p.y(), gy)) {
          bad = true;
          break;
        }
        const double sign = side ? -photo[2 * l] : 1.0;
        auto add = [&](int slot, int local) {
          const Camera& pc = pert[cam][local];
          Eigen::Vector2d q;
          if (!lens_project(pc, pc.R().transpose() * sm.ray, q)) {
            bad = true;
            return;
          }
          const Eigen::Vector2d dp = (q - p) / 1e-6;
          idx.push_back(slot);
          jrow.push_back(sign * (gx * dp.x() + gy * dp.y()));
        };
        if (slots[cam].rot >= 0)
          for (int j = 0; j < 3; ++j) add(slots[cam].rot + j, j);
        add(slots[cam].focal, 3);
        if (slots[cam].lens >= 0) add(slots[cam].lens, 4), add(slots[cam].lens + 1, 5);
      }
      if (bad) continue;
      double ib;
      {
        Eigen::Vector2d pb;
        lens_project(cams[b], Rt[b] * sm.ray, pb);
        if (!bilinear(views[sm.set][b].img, pb.x(), pb.y(), ib)) continue;
      }
      idx.push_back(photo0 + 2 * l), jrow.push_back(-ib);
      idx.push_back(photo0 + 2 * l + 1), jrow.push_back(-1.0);
      const double u = r[k] / c, w = 1.0 / (1.0 + u * u);
      for (std::size_t p1 = 0; p1 < idx.size(); ++p1) {
        g[idx[p1]] += w * jrow[p1] * r[k];
        for (std::size_t p2 = 0; p2 < idx.size(); ++p2) H(idx[p1], idx[p2]) += w * jrow[p1] * jrow[p2];
      }
    }
    bool stepped = false;
    for (int tries = 0; tries < 6 && !stepped; ++tries) {
      Eigen::MatrixXd A = H;
      for (int j = 0; j < P; ++j) A(j, j) += lambda * std::max(H(j, j), 1e-9);
      const Eigen::VectorXd d = -A.ldlt().solve(g);
      if (!d.allFinite()) break;
      std::vector<Camera> c2;
      Eigen::VectorXd ph2;
      apply(cams, photo, d, c2, ph2);
      std::vector<double> r2;
      residuals(c2, ph2, r2);
      if (cost_of(r2, c) < cost) {
        cams = std::move(c2);
        photo = std::move(ph2);
        r = std::move(r2);
        lambda = std::max(lambda / 3, 1e-6);
        stepped = moved = true;
      } else {
        lambda *= 4;
      }
    }
    if (!stepped) break;
  }
  res.rms_after = robust_sigma(r);
  if (!moved) return res;
  for (int i = 0; i < n; ++i) rig.cameras[i] = cams[i];
  res.ok = true;
  return res;
}

}  // namespace stitch
