// Diagnosis of the radtan corner error (issue 15): the trio of bench_calib_lens rendered from a
// photo, its SIFT matches and its dense photometric matches (dense_matches.hpp) checked against
// the true rig: residual quantiles, the noise-only (Fisher) 1-sigma corner error, and the corner
// error of the data's own least-squares optimum found from the truth (what any estimator on those
// matches converges to), also with k2 dropped, shared lenses and Cauchy losses.
//
//   stitch-diag-lens-corner PHOTO [k1 = -0.35] [spacing = 35] [SIFT cap = 300]
// Environment: SS (render supersampling, 2), RAD, BLUR, MAXP, MIND (DenseMatchOptions), TOP=1
// (the 15 worst matches), SAVE=1 (frames to /tmp/lr_cam*.png).
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <random>
#include <string>
#include <vector>

#include "lens_rig.hpp"
#include "stitch/calib/bundle_adjust.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/calib/dense_matches.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/lens.hpp"

using namespace stitch;

namespace {

struct Feat {
  std::vector<cv::KeyPoint> kp;
  cv::Mat desc;
};

Feat detect(const cv::Mat& rgba) {
  cv::Mat g;
  cv::cvtColor(rgba, g, cv::COLOR_RGBA2GRAY);
  Feat f;
  cv::SIFT::create(4000)->detectAndCompute(g, cv::Mat(), f.kp, f.desc);
  for (auto& k : f.kp) k.pt -= cv::Point2f(0.25f, 0.25f);
  return f;
}

bool transfer(const Rig& rig, int a, int b, const Eigen::Vector2d& p, Eigen::Vector2d& q) {
  Eigen::Vector3d ray;
  if (!lens_unproject(rig.cameras[a], p, ray)) return false;
  return lens_project(rig.cameras[b], rig.cameras[b].R().transpose() * (rig.cameras[a].R() * ray), q);
}

// Parameters: rotation increments of non-reference cameras, focal scale, d1, d2 per camera.
Rig apply(const Rig& t, const Eigen::VectorXd& x) {
  Rig r = t;
  int k = 0;
  for (std::size_t i = 0; i < r.cameras.size(); ++i) {
    Camera& c = r.cameras[i];
    if (int(i) != r.reference) {
      const Eigen::Vector3d w = x.segment<3>(k);
      k += 3;
      if (w.norm() > 0) c.set_R(Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix() * c.R());
    }
    const double s2 = 0.25 * (c.width * c.width + c.height * c.height) / (c.fx * c.fy);
    const double d1 = c.lens.k1 * s2 + x[k + 1], d2 = c.lens.k2 * s2 * s2 + x[k + 2];
    c.fx *= 1 + x[k];
    c.fy *= 1 + x[k];
    const double s2n = 0.25 * (c.width * c.width + c.height * c.height) / (c.fx * c.fy);
    c.lens.k1 = d1 / s2n;
    c.lens.k2 = d2 / (s2n * s2n);
    k += 3;
  }
  return r;
}

}  // namespace

int main(int argc, char** argv) {
  std::string path = argc > 1 ? argv[1] : "data/photos/boat1_1600.jpg";
  const double k1 = argc > 2 ? std::stod(argv[2]) : -0.35;
  const double spacing = argc > 3 ? std::stod(argv[3]) : 35;
  const int cap = argc > 4 ? std::stoi(argv[4]) : 300;
  const double k2 = k1 < 0 ? k1 * k1 : 0.0;
  cv::Mat bgr = cv::imread(path), photo;
  cv::cvtColor(bgr, photo, cv::COLOR_BGR2RGBA);
  // RESIZE=1: the photo at most 2688 px wide, as stitch-bench-lens-psnr renders it.
  if (getenv("RESIZE") && photo.cols > 2688)
    cv::resize(photo, photo, cv::Size(2688, 2688 * photo.rows / photo.cols), 0, 0, cv::INTER_AREA);
  const Rig truth = testdata::radtan_trio(320, 240, 260, spacing, k1, k2, k1 != 0, "spherical");
  std::vector<cv::Mat> frames;
  std::vector<Feat> feats;
  for (const auto& c : truth.cameras) {
    frames.push_back(testdata::render_camera_from_equirect(photo, c, getenv("SS") ? atoi(getenv("SS")) : 2));
    if (getenv("SAVE")) {
      cv::Mat bgr2;
      cv::cvtColor(frames.back(), bgr2, cv::COLOR_RGBA2BGR);
      cv::imwrite("/tmp/lr_cam" + std::to_string(frames.size() - 1) + ".png", bgr2);
    }
    feats.push_back(detect(frames.back()));
  }
  std::vector<PairMatches> pms;
  cv::BFMatcher bf(cv::NORM_L2);
  for (int a = 0; a < 3; ++a)
    for (int b = a + 1; b < 3; ++b) {
      std::vector<std::vector<cv::DMatch>> knn;
      bf.knnMatch(feats[a].desc, feats[b].desc, knn, 2);
      PairMatches m;
      m.a = a, m.b = b;
      // bias by x bins of camera b (raw) -- mean residual of b
      std::vector<Eigen::Vector2d> bsum(8, Eigen::Vector2d::Zero());
      std::vector<int> bcnt(8, 0);
      for (auto& k : knn) {
        if (k.size() < 2 || k[0].distance >= 0.75f * k[1].distance) continue;
        const auto& ka = feats[a].kp[k[0].queryIdx];
        const auto& kb = feats[b].kp[k[0].trainIdx];
        Eigen::Vector2d pa(ka.pt.x, ka.pt.y), pb(kb.pt.x, kb.pt.y), q;
        if (!transfer(truth, a, b, pa, q) || (q - pb).norm() > 2.0) continue;
        m.ra.push_back(pa);
        m.rb.push_back(pb);
        Eigen::Vector2d ia, ib;
        undistort_point(truth.cameras[a], pa, ia);
        undistort_point(truth.cameras[b], pb, ib);
        m.pa.push_back(ia);
        m.pb.push_back(ib);
        const double size = 0.5 * (ka.size + kb.size);
        m.weight.push_back(std::min(1.0, 4.0 / std::max(size, 1e-3)));
        const int bin = std::clamp(int(pb.x() / 40), 0, 7);
        bsum[bin] += q - pb;
        bcnt[bin]++;
      }
      if (m.ra.size() < 10) continue;
      std::printf("pair %d-%d: %zu matches under truth (<2px)\n  bias (a->b transfer minus b) by b's x bin:", a, b,
                  m.ra.size());
      for (int i = 0; i < 8; ++i)
        if (bcnt[i]) std::printf(" [%d:%d %+.2f,%+.2f]", i * 40, bcnt[i], bsum[i].x() / bcnt[i], bsum[i].y() / bcnt[i]);
      std::printf("\n");
      pms.push_back(m);
    }
  auto analyse = [&](const std::vector<PairMatches>& pms, const char* label) -> Rig {
    std::printf("== %s\n", label);
  double sum2 = 0;
    int cnt = 0;
    for (const auto& m : pms)
      for (std::size_t k = 0; k < m.ra.size(); ++k) {
        Eigen::Vector2d q;
        if (transfer(truth, m.a, m.b, m.ra[k], q)) sum2 += (q - m.rb[k]).squaredNorm(), ++cnt;
      }
    const double sigma = std::sqrt(sum2 / std::max(cnt, 1) / 2);
    {
      std::vector<double> e;
      for (const auto& m : pms)
        for (std::size_t k = 0; k < m.ra.size(); ++k) {
          Eigen::Vector2d q;
          if (transfer(truth, m.a, m.b, m.ra[k], q)) e.push_back((q - m.rb[k]).norm());
        }
      {
        std::vector<std::pair<double, std::string>> top;
        for (const auto& m : pms)
          for (std::size_t k = 0; k < m.ra.size(); ++k) {
            Eigen::Vector2d q;
            if (!transfer(truth, m.a, m.b, m.ra[k], q)) continue;
            char buf[160];
            std::snprintf(buf, sizeof buf, "%d-%d a(%.0f,%.0f) b(%.1f,%.1f) err(%+.2f,%+.2f)", m.a, m.b, m.ra[k].x(),
                          m.ra[k].y(), m.rb[k].x(), m.rb[k].y(), (q - m.rb[k]).x(), (q - m.rb[k]).y());
            top.emplace_back((q - m.rb[k]).norm(), buf);
          }
        std::sort(top.rbegin(), top.rend());
        if (getenv("TOP"))
          for (std::size_t i = 0; i < std::min<std::size_t>(top.size(), 15); ++i) std::printf("   %s\n", top[i].second.c_str());
      }
      std::sort(e.begin(), e.end());
      if (!e.empty())
        std::printf("truth residual quantiles 50/90/99/max: %.3f %.3f %.3f %.3f\n", e[e.size() / 2], e[e.size() * 9 / 10],
                    e[e.size() * 99 / 100], e.back());
    }
  std::printf("one-axis residual sigma at truth %.3f px over %d matches\n", sigma, cnt);

  // Fisher prediction: residuals (one-way, both directions) linearised at truth.
  const int np = 3 * 2 + 3 * 3;
  auto resid = [&](const Eigen::VectorXd& x) {
    const Rig r = apply(truth, x);
    std::vector<double> v;
    for (const auto& m : pms) {
      const std::size_t take = std::min<std::size_t>(cap, m.ra.size());
      for (std::size_t t = 0; t < take; ++t) {
        const std::size_t k = t * m.ra.size() / take;
        Eigen::Vector2d q1, q2;
        transfer(r, m.a, m.b, m.ra[k], q1);
        transfer(r, m.b, m.a, m.rb[k], q2);
        v.push_back(m.weight[k] * (q1 - m.rb[k]).x());
        v.push_back(m.weight[k] * (q1 - m.rb[k]).y());
        v.push_back(m.weight[k] * (q2 - m.ra[k]).x());
        v.push_back(m.weight[k] * (q2 - m.ra[k]).y());
      }
    }
    return Eigen::Map<Eigen::VectorXd>(v.data(), v.size()).eval();
  };
  // Central differences of resid at x (rows residuals).
  auto jacobian = [&](const Eigen::VectorXd& x, Eigen::Index rows) {
    Eigen::MatrixXd J(rows, x.size());
    for (Eigen::Index j = 0; j < x.size(); ++j) {
      Eigen::VectorXd xp = x, xm = x;
      xp[j] += 1e-6;
      xm[j] -= 1e-6;
      J.col(j) = (resid(xp) - resid(xm)) / 2e-6;
    }
    return J;
  };
  auto corners = [&](const Eigen::VectorXd& x) {
    const Rig r = apply(truth, x);
    std::vector<double> v;
    const Eigen::Matrix3d Re = r.cameras[1].R().transpose(), Rt = truth.cameras[1].R().transpose();
    for (int i : {0, 2}) {
      const Camera &E = r.cameras[i], &T = truth.cameras[i];
      for (const Eigen::Vector2d& p : {Eigen::Vector2d(0, 0), Eigen::Vector2d(T.width - 1, 0),
                                       Eigen::Vector2d(T.width - 1, T.height - 1), Eigen::Vector2d(0, T.height - 1)}) {
        Eigen::Vector3d ray;
        Eigen::Vector2d q(1e9, 1e9);
        if (lens_unproject(E, p, ray)) lens_project(T, T.R().transpose() * (Rt.transpose() * (Re * E.R() * ray)), q);
        v.push_back(q.x() - p.x());
        v.push_back(q.y() - p.y());
      }
    }
    return Eigen::Map<Eigen::VectorXd>(v.data(), v.size()).eval();
  };
  Eigen::VectorXd x0 = Eigen::VectorXd::Zero(np);
  const Eigen::VectorXd r0 = resid(x0), c0 = corners(x0);
  Eigen::MatrixXd J(r0.size(), np), G(c0.size(), np);
  for (int j = 0; j < np; ++j) {
    Eigen::VectorXd x = x0;
    const double h = 1e-6;
    x[j] += h;
    const Eigen::VectorXd r1 = resid(x), c1 = corners(x);
    x[j] -= 2 * h;
    J.col(j) = (r1 - resid(x)) / (2 * h);
    G.col(j) = (c1 - corners(x)) / (2 * h);
  }
  const Eigen::MatrixXd cov = sigma * sigma * (J.transpose() * J).inverse();
  const Eigen::MatrixXd cc = G * cov * G.transpose();
  std::printf("Fisher (cap %d, sigma %.3f): corner-error std per corner (x,y):", cap, sigma);
  double worst = 0;
  for (int i = 0; i < int(c0.size()) / 2; ++i) {
    const double s = std::sqrt(cc(2 * i, 2 * i) + cc(2 * i + 1, 2 * i + 1));
    worst = std::max(worst, s);
    std::printf(" %.3f", s);
  }
  std::printf("\n  worst corner 1-sigma %.3f px; focal std per cam %.3f %.3f %.3f %%\n", worst,
              100 * std::sqrt(cov(6, 6)), 100 * std::sqrt(cov(9, 9)), 100 * std::sqrt(cov(12, 12)));
  // Gauss-Newton from the truth on the real (biased/noisy) data: the data's optimum.
  Eigen::VectorXd x = x0;
  for (int it = 0; it < 8; ++it) {
    const Eigen::VectorXd r = resid(x);
    const Eigen::MatrixXd Jx = jacobian(x, r.size());
    x -= (Jx.transpose() * Jx).ldlt().solve(Jx.transpose() * r);
  }
  const Rig opt = apply(truth, x);
  // Reduced models: P maps reduced params to full ones.
  auto reduced = [&](const Eigen::MatrixXd& P, const char* name) {
    Eigen::VectorXd z = Eigen::VectorXd::Zero(P.cols());
    for (int it = 0; it < 8; ++it) {
      const Eigen::VectorXd r = resid(P * z);
      Eigen::MatrixXd Jx(r.size(), P.cols());
      for (int j = 0; j < P.cols(); ++j) {
        Eigen::VectorXd zp = z, zm = z;
        zp[j] += 1e-6;
        zm[j] -= 1e-6;
        Jx.col(j) = (resid(P * zp) - resid(P * zm)) / 2e-6;
      }
      z -= (Jx.transpose() * Jx).ldlt().solve(Jx.transpose() * r);
    }
    const Rig o2 = apply(truth, P * z);
    std::printf("  %s: corner error %.3f px (rms %.4f), f %.2f %.2f %.2f k1 %.4f k2 %.4f\n", name,
                testdata::lens_corner_error(o2, truth), std::sqrt(resid(P * z).squaredNorm() / resid(P * z).size()),
                o2.cameras[0].fx, o2.cameras[1].fx, o2.cameras[2].fx, o2.cameras[0].lens.k1, o2.cameras[0].lens.k2);
  };
  {
    // layout: cam0 rot(0..2) f3 d1 4 d2 5 | cam1 f6 d1 7 d2 8 | cam2 rot 9..11 f12 d1 13 d2 14
    Eigen::MatrixXd P = Eigen::MatrixXd::Identity(np, np);
    Eigen::MatrixXd noK2(np, np - 3);
    int c = 0;
    for (int j = 0; j < np; ++j)
      if (j != 5 && j != 8 && j != 14) noK2.col(c++) = P.col(j);
    reduced(noK2, "no k2");
    Eigen::MatrixXd sh = Eigen::MatrixXd::Zero(np, 9);
    for (int j = 0; j < 3; ++j) sh(j, j) = 1, sh(9 + j, 3 + j) = 1;
    for (int cam = 0; cam < 3; ++cam)
      for (int q = 0; q < 3; ++q) sh((cam == 0 ? 3 : cam == 1 ? 6 : 12) + q, 6 + q) = 1;
    reduced(sh, "shared f, k1, k2");
    reduced(sh.leftCols(8), "shared f, k1; no k2");
  }
  for (double c : {0.1, 0.05}) {
    Eigen::VectorXd xr = x;
    for (int it = 0; it < 10; ++it) {
      const Eigen::VectorXd r = resid(xr);
      Eigen::VectorXd w(r.size());
      for (int i = 0; i < r.size(); i += 2) {
        const double e2 = r[i] * r[i] + r[i + 1] * r[i + 1];
        w[i] = w[i + 1] = 1.0 / (1.0 + e2 / (c * c));
      }
      const Eigen::MatrixXd Jx = jacobian(xr, r.size());
      xr -= (Jx.transpose() * w.asDiagonal() * Jx).ldlt().solve(Jx.transpose() * w.asDiagonal() * r);
    }
    const Rig o2 = apply(truth, xr);
    std::printf("  Cauchy %.2f: corner error %.3f px, f %.2f %.2f %.2f\n", c, testdata::lens_corner_error(o2, truth),
                o2.cameras[0].fx, o2.cameras[1].fx, o2.cameras[2].fx);
  }
  std::printf("data optimum from truth: corner error %.3f px (rms %.3f), f %.2f %.2f %.2f, k1 %.4f %.4f %.4f\n",
              testdata::lens_corner_error(opt, truth), std::sqrt(resid(x).squaredNorm() / resid(x).size()),
              opt.cameras[0].fx, opt.cameras[1].fx, opt.cameras[2].fx, opt.cameras[0].lens.k1, opt.cameras[1].lens.k1,
              opt.cameras[2].lens.k1);
    return opt;
  };
  const Rig sift_opt = analyse(pms, "SIFT");
  std::vector<DenseImage> dimg;
  for (const auto& f : frames) {
    cv::Mat g;
    cv::cvtColor(f, g, cv::COLOR_RGBA2GRAY);
    DenseMatchOptions dop; if (getenv("BLUR")) dop.blur_sigma = atof(getenv("BLUR")); if (getenv("MAXP")) dop.max_points = atoi(getenv("MAXP")); if (getenv("MIND")) dop.min_distance = atoi(getenv("MIND")); if (getenv("QL")) dop.quality = atof(getenv("QL")); dimg.push_back(prepare_dense_image(g, dop));
  }
  for (int variant = 0; variant < 2; ++variant) {
    const Rig& guide = variant == 0 ? truth : sift_opt;
    std::vector<PairMatches> dm;
    for (int a = 0; a < 3; ++a)
      for (int b = a + 1; b < 3; ++b) {
        DenseMatchOptions dop; if (getenv("RAD")) dop.radius = atoi(getenv("RAD")); if (getenv("BLUR")) dop.blur_sigma = atof(getenv("BLUR")); if (getenv("MAXP")) dop.max_points = atoi(getenv("MAXP")); if (getenv("MIND")) dop.min_distance = atoi(getenv("MIND")); if (getenv("QL")) dop.quality = atof(getenv("QL")); PairMatches m = dense_pair_matches(guide, a, b, dimg[a], dimg[b], dop);
        // drop gross errors vs truth (>2 px) and report how many
        PairMatches k = m;
        k.ra.clear(); k.rb.clear(); k.pa.clear(); k.pb.clear(); k.weight.clear();
        int bad = 0;
        for (std::size_t i = 0; i < m.ra.size(); ++i) {
          Eigen::Vector2d q;
          if (!transfer(truth, a, b, m.ra[i], q) || (q - m.rb[i]).norm() > 2.0) { ++bad; continue; }
          k.ra.push_back(m.ra[i]); k.rb.push_back(m.rb[i]); k.pa.push_back(m.pa[i]); k.pb.push_back(m.pb[i]); k.weight.push_back(1);
        }
        std::printf("dense %d-%d: %zu matches, %d off by > 2 px under truth\n", a, b, m.ra.size(), bad);
        if (variant == 0 && k.ra.size() >= 10) {
          // Signed bias of the dense matches under the truth, by b's x bin (x and y of a->b minus b).
          std::vector<Eigen::Vector2d> bsum(8, Eigen::Vector2d::Zero());
          std::vector<int> bcnt(8, 0);
          for (std::size_t i = 0; i < k.ra.size(); ++i) {
            Eigen::Vector2d q;
            transfer(truth, a, b, k.ra[i], q);
            const int bin = std::clamp(int(k.rb[i].x() / 40), 0, 7);
            bsum[bin] += q - k.rb[i];
            bcnt[bin]++;
          }
          {
            // By the sub-pixel phase of the located point (points picked in a: rb not whole).
            double ps[4] = {0, 0, 0, 0}, py[4] = {0, 0, 0, 0};
            int pn[4] = {0, 0, 0, 0};
            for (std::size_t i = 0; i < k.ra.size(); ++i) {
              if (std::abs(k.rb[i].x() - std::round(k.rb[i].x())) < 1e-9) continue;
              Eigen::Vector2d q;
              transfer(truth, a, b, k.ra[i], q);
              const double fx = k.rb[i].x() - std::floor(k.rb[i].x()), fy = k.rb[i].y() - std::floor(k.rb[i].y());
              ps[std::min(3, int(fx * 4))] += (q - k.rb[i]).x();
              pn[std::min(3, int(fx * 4))]++;
              py[std::min(3, int(fy * 4))] += (q - k.rb[i]).y();
            }
            std::printf("  dense x bias by frac(x) quarter:");
            for (int i = 0; i < 4; ++i) std::printf(" %+.4f(%d)", pn[i] ? ps[i] / pn[i] : 0.0, pn[i]);
            std::printf("\n");
          }
          std::printf("  dense bias (a->b transfer minus b) by b's x bin:");
          for (int i = 0; i < 8; ++i)
            if (bcnt[i]) std::printf(" [%d:%d %+.3f,%+.3f]", i * 40, bcnt[i], bsum[i].x() / bcnt[i], bsum[i].y() / bcnt[i]);
          std::printf("\n");
        }
        if (k.ra.size() >= 10) dm.push_back(k);
      }
    if (getenv("PHASE")) std::printf("phase correction over %d matches\n", correct_phase_bias(guide, dm));
    analyse(dm, variant == 0 ? "dense, guided by the truth" : "dense, guided by the SIFT optimum");
  }
  return 0;
}
