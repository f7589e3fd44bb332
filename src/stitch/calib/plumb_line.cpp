#include "stitch/calib/plumb_line.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <limits>
#include <opencv2/core/optim.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/cv_interop.hpp"
#include "stitch/rig/lens.hpp"

namespace stitch {

// Two cameras whose edge bends differ by this much have different lenses (a 1x phone camera:
// 0; a 0.5x ultra-wide: -0.25; an action camera: -0.35); a rectilinear camera measures within
// +-0.02 of 0 on the rendered rigs.
const double kPlumbMixedBend = 0.08;
// Straight windows at the best lens needed to judge a camera (a textureless view has none).
const int kPlumbMinWindows = 12;
const double kPlumbDistortedGain = 1.5;

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kMaxPixels = 0.5e6;     // frames are judged at about this size
constexpr double kWindowShare = 0.15;    // a window is this share of the frame's diagonal (chain points)
constexpr int kWindowSamples = 16;       // points of a window undistorted to judge it
constexpr double kStraightRmsPx = 0.5;   // a window is straight within this (raw-scale px)
constexpr double kCapPx = 1.5;           // each window's rms counts at most this in the refinement
constexpr std::size_t kMaxWindows = 4000;

using Window = std::vector<Eigen::Vector2d>;

// Long edge chains of the frame cut into overlapping windows of equal chain length, kept when
// their ends lie far apart (not a fold of a chain traced there and back, not a wiggle).
void edge_windows(const ImageView& frame, double scale, std::vector<Window>& out) {
  cv::Mat rgba = as_mat(frame), gray, small;
  cv::cvtColor(rgba, gray, cv::COLOR_RGBA2GRAY);
  cv::resize(gray, small, cv::Size(), scale, scale, cv::INTER_AREA);
  cv::GaussianBlur(small, small, cv::Size(0, 0), 1.0);
  cv::Mat edges;
  cv::Canny(small, edges, 40, 100, 3, true);
  std::vector<std::vector<cv::Point>> chains;
  cv::findContours(edges, chains, cv::RETR_LIST, cv::CHAIN_APPROX_NONE);
  const int w = std::max(20, int(kWindowShare * std::hypot(small.cols, small.rows)));
  for (const auto& ch : chains) {
    if (int(ch.size()) < w) continue;
    for (int s = 0; s + w <= int(ch.size()); s += w / 2) {
      const cv::Point d = ch[std::size_t(s + w - 1)] - ch[std::size_t(s)];
      if (std::hypot(d.x, d.y) < 0.9 * w) continue;
      Window win;
      for (int k = 0; k < kWindowSamples; ++k) {
        const cv::Point& p = ch[std::size_t(s + k * (w - 1) / (kWindowSamples - 1))];
        win.emplace_back(p.x, p.y);
      }
      out.push_back(std::move(win));
    }
  }
}

// The window's rms distance to its best line after the lens's undistortion, in raw-scale pixels
// (divided by the undistortion's stretch along the window); infinity where a point has no ideal
// pixel.
double window_rms(const Camera& c, const Window& win) {
  Eigen::Vector2d pts[kWindowSamples];
  Eigen::Vector2d mean = Eigen::Vector2d::Zero();
  for (int k = 0; k < kWindowSamples; ++k) {
    if (c.lens.pinhole()) pts[k] = win[std::size_t(k)];
    else if (!undistort_point(c, win[std::size_t(k)], pts[k])) return std::numeric_limits<double>::infinity();
    mean += pts[k] / kWindowSamples;
  }
  Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
  for (const auto& p : pts) cov += (p - mean) * (p - mean).transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(cov);
  const double off = std::sqrt(std::max(0.0, es.eigenvalues()(0)) / kWindowSamples);
  const double stretch = (pts[kWindowSamples - 1] - pts[0]).norm() / (win.back() - win.front()).norm();
  return stretch > 1e-6 ? off / stretch : std::numeric_limits<double>::infinity();
}

Camera centred(int width, int height, double fx) {
  Camera c;
  c.width = width;
  c.height = height;
  c.fx = c.fy = fx;
  c.cx = 0.5 * (width - 1);
  c.cy = 0.5 * (height - 1);
  return c;
}

Camera fisheye_of(int width, int height, double half_width_angle, double k1 = 0) {
  Camera c = centred(width, height, 0.5 * width / half_width_angle);
  c.lens.model = Lens::Model::Fisheye;
  c.lens.k1 = k1;
  return c;
}

// The nominal focal length radtan coefficients are found at: 70 degrees across the width.
double nominal_fx(int width) { return 0.5 * width / std::tan(35.0 * kPi / 180.0); }

Camera radtan_of(int width, int height, double k1, double k2) {
  Camera c = centred(width, height, nominal_fx(width));
  c.lens.model = Lens::Model::Radtan;
  c.lens.k1 = k1;
  c.lens.k2 = k2;
  return c;
}

int straight_windows(const Camera& c, const std::vector<Window>& wins, std::vector<char>* mark = nullptr) {
  int n = 0;
  if (mark) mark->assign(wins.size(), 0);
  for (std::size_t i = 0; i < wins.size(); ++i)
    if (window_rms(c, wins[i]) <= kStraightRmsPx) {
      ++n;
      if (mark) (*mark)[i] = 1;
    }
  return n;
}

double capped_cost(const Camera& c, const std::vector<const Window*>& wins) {
  if (!c.lens.pinhole() && !lens_problem(c).empty()) return 1e9;
  double sum = 0;
  for (const Window* w : wins) sum += std::min(kCapPx * kCapPx, std::pow(window_rms(c, *w), 2));
  return sum / std::max<std::size_t>(1, wins.size());
}

// Nelder-Mead (cv::DownhillSolver) over a lens family's parameters.
struct FamilyCost : cv::MinProblemSolver::Function {
  std::function<Camera(const double*)> make;
  const std::vector<const Window*>* wins = nullptr;
  int dims = 1;
  int getDims() const override { return dims; }
  double calc(const double* x) const override { return capped_cost(make(x), *wins); }
};

double minimise(FamilyCost& f, cv::Mat& x, const cv::Mat& step) {
  cv::Ptr<cv::DownhillSolver> solver = cv::DownhillSolver::create();
  solver->setFunction(cv::Ptr<cv::MinProblemSolver::Function>(&f, [](cv::MinProblemSolver::Function*) {}));
  solver->setInitStep(step);
  solver->setTermCriteria(cv::TermCriteria(cv::TermCriteria::MAX_ITER + cv::TermCriteria::EPS, 200, 1e-7));
  return solver->minimize(x);
}

// The lens's largest relative move of a radius out to the middle of the frame's side edge (raw
// radius over its pinhole one, minus 1), signed: a wide phone lens with a strong k2 bends the
// middle of the field by -20% and straightens again by the edge.
double edge_bend_of(const Camera& c) {
  if (c.lens.pinhole()) return 0;
  double extreme = 0;
  for (int k = 1; k <= 16; ++k) {
    const Eigen::Vector2d raw(c.cx + (c.width - 1 - c.cx) * k / 16.0, c.cy);
    Eigen::Vector2d ideal;
    if (!undistort_point(c, raw, ideal)) return -1;
    const double bend = (raw.x() - c.cx) / (ideal.x() - c.cx) - 1.0;
    if (std::abs(bend) > std::abs(extreme)) extreme = bend;
  }
  return extreme;
}

double judging_scale(int W, int H) { return std::min(1.0, std::sqrt(kMaxPixels / (double(W) * H))); }

// The windows of the first and last frames (at most kMaxWindows, evenly picked).
std::vector<Window> frame_windows(const std::vector<ImageView>& frames, double scale) {
  std::vector<Window> wins;
  for (std::size_t k = 0; k < frames.size() && k < 2; ++k) edge_windows(frames[k * (frames.size() - 1)], scale, wins);
  if (wins.size() > kMaxWindows) {
    std::vector<Window> kept;
    for (std::size_t i = 0; i < kMaxWindows; ++i) kept.push_back(wins[i * wins.size() / kMaxWindows]);
    wins.swap(kept);
  }
  return wins;
}

}  // namespace

std::string PlumbLineLens::describe() const {
  char b[200];
  const char* m = lens_model_name(camera.lens.model);
  std::snprintf(b, sizeof b, "%s%s fx %.0f k1 %+.3f k2 %+.3f, edge bend %+.3f: %d straight edge windows (%d as they are), %.2f -> %.2f px",
                m, distorted || camera.lens.pinhole() ? "" : " (mild)", camera.fx, camera.lens.k1, camera.lens.k2, edge_bend, windows, pinhole_windows, pinhole_residual_px,
                residual_px);
  return b;
}

PlumbLineLens plumb_line_lens(const std::vector<ImageView>& frames) {
  PlumbLineLens out;
  if (frames.empty() || frames[0].width <= 0 || frames[0].height <= 0) return out;
  const int W = frames[0].width, H = frames[0].height;
  const double scale = judging_scale(W, H);
  const int w = std::max(1, int(std::lround(W * scale))), h = std::max(1, int(std::lround(H * scale)));
  const std::vector<Window> wins = frame_windows(frames, scale);
  out.camera = centred(W, H, nominal_fx(W));
  // Coarse: two families, the one that straightens the most windows: the equidistant fisheye
  // from 0.3 rad at the half width (a 3% bend) to 1.6 (180 degrees across), and radtan k1 at the
  // nominal focal length (k2 none, half, all of k1^2: phone lenses run near k2 = k1^2); no lens.
  const Camera pin = centred(w, h, nominal_fx(w));
  out.pinhole_windows = straight_windows(pin, wins);
  Camera best = pin, best_fe, best_rt;
  int best_count = out.pinhole_windows, fe_count = -1, rt_count = -1;
  for (double u = 0.3; u <= 1.601; u += 0.05) {
    const Camera c = fisheye_of(w, h, u);
    const int n = straight_windows(c, wins);
    if (n > fe_count) fe_count = n, best_fe = c;
  }
  for (double k1 = -2.0; k1 <= 0.301; k1 += 0.1)
    for (const double ratio : {0.0, 0.5, 1.0}) {
      const Camera c = radtan_of(w, h, k1, ratio * k1 * k1);
      if (std::abs(k1) < 1e-9 || !lens_problem(c).empty()) continue;
      const int n = straight_windows(c, wins);
      if (n > rt_count) rt_count = n, best_rt = c;
    }
  if (fe_count > best_count) best_count = fe_count, best = best_fe;
  if (rt_count > best_count) best_count = rt_count, best = best_rt;
  if (std::getenv("STITCH_DEBUG_PLUMB"))
    std::fprintf(stderr, "plumb: %zu windows; straight: pinhole %d, fisheye %d, radtan %d\n", wins.size(), out.pinhole_windows,
                 fe_count, rt_count);
  if (best_count < kPlumbMinWindows) return out;
  out.found = true;
  std::vector<char> mark;
  straight_windows(best, wins, &mark);
  std::vector<const Window*> chosen;
  for (std::size_t i = 0; i < wins.size(); ++i)
    if (mark[i]) chosen.push_back(&wins[i]);
  const double pin_cost = capped_cost(pin, chosen);
  out.pinhole_residual_px = std::sqrt(pin_cost);
  if (best.lens.pinhole()) {
    out.windows = best_count;
    out.residual_px = out.pinhole_residual_px;
    return out;
  }
  // Fine: each distorted family refined from its coarse best on the chosen windows (continuous
  // cost), the better kept.
  FamilyCost fe;
  fe.wins = &chosen;
  fe.dims = 2;  // the field of view and Kannala-Brandt's k1
  fe.make = [&](const double* x) { return fisheye_of(w, h, std::clamp(x[0], 0.05, 1.7), std::clamp(x[1], -0.3, 0.3)); };
  cv::Mat xf = (cv::Mat_<double>(1, 2) << 0.5 * w / best_fe.fx, 0.0);
  const double fe_cost = minimise(fe, xf, (cv::Mat_<double>(1, 2) << 0.05, 0.02));
  const Camera fe_cam = fe.make(xf.ptr<double>());
  FamilyCost rt;
  rt.wins = &chosen;
  rt.dims = 2;
  rt.make = [&](const double* x) { return radtan_of(w, h, x[0], x[1]); };
  cv::Mat xr = (cv::Mat_<double>(1, 2) << best_rt.lens.k1, best_rt.lens.k2);
  const double rt_cost = minimise(rt, xr, (cv::Mat_<double>(1, 2) << 0.05, 0.05));
  const Camera rt_cam = rt.make(xr.ptr<double>());
  if (std::getenv("STITCH_DEBUG_PLUMB"))
    std::fprintf(stderr, "plumb: windows pinhole %d fisheye %d (fx %.0f) radtan %d (k1 %.2f k2 %.2f); refined fisheye %.3f px (fx %.0f k1 %.3f) radtan %.3f px (k1 %.3f k2 %.3f)\n",
                 out.pinhole_windows, fe_count, best_fe.fx, rt_count, best_rt.lens.k1, best_rt.lens.k2,
                 std::sqrt(fe_cost), fe_cam.fx, fe_cam.lens.k1, std::sqrt(rt_cost), rt_cam.lens.k1, rt_cam.lens.k2);
  const bool fisheye = fe_cost <= rt_cost;
  Camera found = fisheye ? fe_cam : rt_cam;
  if (!lens_problem(found).empty()) found = fisheye ? rt_cam : fe_cam;
  if (!lens_problem(found).empty()) return out;
  out.residual_px = std::sqrt(std::min(fe_cost, rt_cost));
  out.windows = straight_windows(found, wins);
  out.edge_bend = edge_bend_of(found);
  out.distorted = out.windows >= std::max(kPlumbDistortedGain * out.pinhole_windows, double(out.pinhole_windows + kPlumbMinWindows));
  // Back at the frame's size: the focal length scales, the coefficients (normalised) stay.
  found.width = W;
  found.height = H;
  found.fx = found.fy = found.fx / scale;
  found.cx = 0.5 * (W - 1);
  found.cy = 0.5 * (H - 1);
  out.camera = found;
  return out;
}

std::vector<Camera> plumb_line_fisheye_at(const std::vector<ImageView>& frames, const Camera& fisheye,
                                          const std::vector<double>& k1s) {
  std::vector<Camera> out;
  for (const double k1 : k1s) {
    out.push_back(fisheye);
    out.back().lens.k1 = k1;
  }
  if (frames.empty() || fisheye.lens.model != Lens::Model::Fisheye || frames[0].width != fisheye.width) return out;
  const double scale = judging_scale(fisheye.width, fisheye.height);
  const int w = std::max(1, int(std::lround(fisheye.width * scale))), h = std::max(1, int(std::lround(fisheye.height * scale)));
  const std::vector<Window> wins = frame_windows(frames, scale);  // once for every k1
  const double u0 = 0.5 * fisheye.width / fisheye.fx;
  for (Camera& cam : out) {
    const double k1 = cam.lens.k1;
    // The windows straight near the start; then golden-section search of the field of view.
    std::vector<char> mark;
    if (straight_windows(fisheye_of(w, h, u0, k1), wins, &mark) < kPlumbMinWindows) continue;
    std::vector<const Window*> chosen;
    for (std::size_t i = 0; i < wins.size(); ++i)
      if (mark[i]) chosen.push_back(&wins[i]);
    const auto cost = [&](double u) { return capped_cost(fisheye_of(w, h, u, k1), chosen); };
    const double g = 0.5 * (std::sqrt(5.0) - 1);
    double a = 0.8 * u0, b = 1.25 * u0, c = b - g * (b - a), d = a + g * (b - a), fc = cost(c), fd = cost(d);
    for (int it = 0; it < 30; ++it) {
      if (fc < fd) b = d, d = c, fd = fc, c = b - g * (b - a), fc = cost(c);
      else a = c, c = d, fc = fd, d = a + g * (b - a), fd = cost(d);
    }
    cam.fx = cam.fy = 0.5 * fisheye.width / (0.5 * (a + b));
  }
  return out;
}

Camera plumb_line_rescaled(const Camera& plumb, double fx) {
  Camera c = plumb;
  if (c.lens.model == Lens::Model::Radtan && plumb.fx > 0) {
    const double s2 = (fx / plumb.fx) * (fx / plumb.fx);
    c.lens.k1 *= s2;
    c.lens.k2 *= s2 * s2;
    c.lens.k3 *= s2 * s2 * s2;
  }
  c.fx = c.fy = fx;
  return c;
}

bool plumb_lenses_mixed(const std::vector<PlumbLineLens>& lenses) {
  if (lenses.size() < 2) return false;
  double lo = 1e9, hi = -1e9;
  bool distorted = false;
  for (const auto& l : lenses) {
    if (!l.found) return false;
    const double bend = l.distorted ? l.edge_bend : 0.0;
    lo = std::min(lo, bend);
    hi = std::max(hi, bend);
    distorted |= std::abs(bend) > kPlumbMixedBend;
  }
  if (!distorted || !(hi - lo > kPlumbMixedBend)) return false;
  // Every camera read as a fisheye: alike action cameras, whose views' different edges trade
  // focal length against k1 (a ring of four 148-degree lenses reads fx 138-186, bends -0.50 to
  // -0.66). The full-frame fisheye path fits those with one model.
  for (const auto& l : lenses)
    if (l.camera.lens.model != Lens::Model::Fisheye) return true;
  return false;
}

}  // namespace stitch
