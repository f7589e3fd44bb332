// Color correction on real images: known distortions recovered, the balancing curve's shape,
// degenerate frames, bounded temporal behaviour.
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "stitch/color/color.hpp"
#include "stitch/cv_interop.hpp"
#include "test_data.hpp"

#include "color_cast.hpp"

using namespace stitch;

namespace {

// Two 640x480 crops of a real photo 320 px apart (50% overlap), exactly calibrated.
struct TwoViews {
  cv::Mat ref, other, other_truth;
  Rig rig;
};

TwoViews two_views(const std::string& photo_path) {
  TwoViews t;
  cv::Mat photo = testdata::load_rgba(photo_path);
  cv::resize(photo, photo, cv::Size(960, 640));
  t.ref = photo(cv::Rect(0, 80, 640, 480)).clone();
  t.other_truth = photo(cv::Rect(320, 80, 640, 480)).clone();
  t.other = t.other_truth.clone();
  t.rig = testdata::shifted_rig(2, 640, 480, 320);
  t.rig.reference = 0;
  return t;
}

using testdata::distort;

std::vector<std::string> photos() {
  std::vector<std::string> p = {testdata::repo_path("data/photos/boat1_1600.jpg")};
  const std::string shared = testdata::shared_path("images/eadcat_apap_demo/demo2/boat03.jpg");
  if (!shared.empty()) p.push_back(shared);
  return p;
}

double correct_once(TwoViews& t, const ColorOptions& o) {
  ColorCorrector cc(Backend::Cpu);
  cc.set_options(o);
  std::vector<ImageView> views = {as_view(t.ref), as_view(t.other)};
  cc.process(t.rig, 1, views);
  EXPECT_TRUE(cc.corrections()[0].isIdentity(1e-12));  // the reference is never changed
  return testdata::psnr_rgb(t.other, t.other_truth);
}

}  // namespace

TEST(ColorTransfer, Known3x3DistortionIsRecovered) {
  // Cross-channel mixing (no channel saturates): the 2D-M fit on co-located pixels inverts it.
  Eigen::Matrix3d M;
  M << 0.84, 0.08, 0.02, 0.05, 0.86, 0.03, 0.02, 0.06, 0.80;
  for (const auto& path : photos()) {
    TwoViews t = two_views(path);
    distort(t.other, M);
    const double before = testdata::psnr_rgb(t.other, t.other_truth);
    ColorOptions o;
    o.method = ColorMethod::Matrix2D;
    o.pairing = ColorPairing::Pixels;
    const double after = correct_once(t, o);
    std::printf("%s: PSNR %.2f dB -> %.2f dB\n", path.c_str(), before, after);
    EXPECT_LT(before, 30.0);
    EXPECT_GE(after, 40.0) << path;
  }
}

TEST(ColorTransfer, HistogramPairingRecoversPerChannelGains) {
  // Paper Step 3: matching histograms needs no pixel alignment; per-channel gains come back.
  Eigen::Matrix3d M = Eigen::Vector3d(0.8, 0.9, 0.75).asDiagonal();
  TwoViews t = two_views(photos()[0]);
  distort(t.other, M);
  const double before = testdata::psnr_rgb(t.other, t.other_truth);
  ColorOptions o;
  o.method = ColorMethod::Matrix3D;
  o.pairing = ColorPairing::Histogram;
  const double after = correct_once(t, o);
  EXPECT_GT(after, before + 10.0);
  EXPECT_GE(after, 35.0);
}

TEST(ColorTransfer, GainCompensationRecoversExposure) {
  TwoViews t = two_views(photos()[0]);
  distort(t.other, Eigen::Vector3d(0.7, 0.7, 0.7).asDiagonal());
  ColorOptions o;
  o.method = ColorMethod::Gain;
  const double after = correct_once(t, o);
  EXPECT_GE(after, 35.0);
}

TEST(ColorTransfer, ThreeViewsChainOutwardFromReference) {
  cv::Mat photo = testdata::load_rgba(photos()[0]);
  std::vector<cv::Mat> truth, views;
  for (int i = 0; i < 3; ++i) truth.push_back(photo(cv::Rect(400 * i, 200, 640, 480)).clone());
  views = {truth[0].clone(), truth[1].clone(), truth[2].clone()};
  Rig rig = testdata::shifted_rig(3, 640, 480, 400);
  rig.reference = 1;
  distort(views[0], Eigen::Vector3d(0.8, 0.85, 0.9).asDiagonal());
  distort(views[2], Eigen::Vector3d(0.75, 0.8, 0.7).asDiagonal());  // only reachable through view 1
  ColorCorrector cc(Backend::Cpu);
  ColorOptions o;
  o.method = ColorMethod::Matrix2D;
  o.pairing = ColorPairing::Pixels;
  cc.set_options(o);
  std::vector<ImageView> v = {as_view(views[0]), as_view(views[1]), as_view(views[2])};
  cc.process(rig, 1, v);
  EXPECT_GE(testdata::psnr_rgb(views[0], truth[0]), 38.0);
  EXPECT_GE(testdata::psnr_rgb(views[2], truth[2]), 38.0);
  EXPECT_EQ(cv::norm(views[1], truth[1], cv::NORM_INF), 0.0);  // the reference is untouched
}

TEST(BalanceCurve, ContinuousAndMonotonicForRandomThresholds) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 255), lam(0.01, 0.2);
  for (int trial = 0; trial < 500; ++trial) {
    double m1 = u(rng), m2 = u(rng);
    if (m1 > m2) std::swap(m1, m2);
    const double l = lam(rng);
    double prev = -1;
    for (double x = 0; x <= 255; x += 0.05) {
      const double y = piecewise_balance_value(x, m1, m2, l);
      ASSERT_TRUE(std::isfinite(y));
      ASSERT_GE(y, prev - 1e-9) << "not monotonic at x=" << x << " m1=" << m1 << " m2=" << m2;
      prev = y;
    }
    // Each piece is continuous; the curve is continuous where the pieces meet (the knees).
    if (m2 - m1 >= 1) {
      EXPECT_NEAR(piecewise_balance_value(m1 - 1e-7, m1, m2, l), piecewise_balance_value(m1 + 1e-7, m1, m2, l), 1e-4);
      EXPECT_NEAR(piecewise_balance_value(m2 - 1e-7, m1, m2, l), piecewise_balance_value(m2 + 1e-7, m1, m2, l), 1e-4);
    }
    const auto lut = piecewise_balance_curve(m1, m2, l);
    for (int v = 1; v < 256; ++v) ASSERT_GE(lut[v], lut[v - 1]);
  }
}

TEST(BalanceCurve, StretchesTheThresholdsApart) {
  // A low-contrast histogram [60, 180] is stretched toward [lambda, 1 - lambda] of the range.
  const auto lut = piecewise_balance_curve(60, 180, 0.05);
  EXPECT_LT(lut[60], 60);
  EXPECT_GT(lut[180], 180);
  EXPECT_EQ(lut[0], 0);
  EXPECT_EQ(lut[255], 255);
  // A histogram that already spans the range is (almost) left alone.
  const auto full = piecewise_balance_curve(255 * 0.05, 255 * 0.95, 0.05);
  for (int v = 0; v < 256; ++v) EXPECT_NEAR(full[v], v, 1);
}

TEST(HistogramSpecification, MatchesTheReferenceHistogram) {
  std::array<uint32_t, 256> src{}, ref{};
  for (int v = 0; v < 100; ++v) src[v] = 10;        // uniform on [0, 100)
  for (int v = 100; v < 200; ++v) ref[v] = 10;      // uniform on [100, 200)
  const auto lut = histogram_specification(src, ref);
  for (int v = 0; v < 100; ++v) EXPECT_NEAR(lut[v], 100 + v, 1);
}

TEST(ColorRobustness, DegenerateFramesGiveNoNaN) {
  const Rig rig = testdata::shifted_rig(2, 320, 240, 160);
  for (ColorMethod m : {ColorMethod::Matrix2D, ColorMethod::Matrix3D, ColorMethod::Gain}) {
    for (const cv::Scalar& fill : {cv::Scalar(0, 0, 0, 255), cv::Scalar(255, 255, 255, 255), cv::Scalar(30, 140, 220, 255)}) {
      cv::Mat a(240, 320, CV_8UC4, fill), b(240, 320, CV_8UC4, fill * 0.8);
      ColorCorrector cc(Backend::Cpu);
      ColorOptions o;
      o.method = m;
      o.balance = true;
      cc.set_options(o);
      std::vector<ImageView> v = {as_view(a), as_view(b)};
      for (int f = 0; f < 4; ++f) cc.process(rig, 1, v);
      for (const auto& M : cc.corrections()) EXPECT_TRUE(M.allFinite());
      // Single-colour views stay single-colour (the correction is applied, nothing breaks).
      double lo, hi;
      cv::Mat g;
      cv::cvtColor(b, g, cv::COLOR_RGBA2GRAY);
      cv::minMaxLoc(g, &lo, &hi);
      EXPECT_EQ(lo, hi);
    }
  }
}

TEST(ColorRobustness, SuddenChangeMovesTheCorrectionBoundedly) {
  TwoViews t = two_views(photos()[0]);
  ColorCorrector cc(Backend::Cpu);
  ColorOptions o;
  o.method = ColorMethod::Matrix2D;
  o.pairing = ColorPairing::Pixels;
  cc.set_options(o);
  std::vector<Eigen::Matrix3d> seen;
  for (int f = 0; f < 12; ++f) {
    cv::Mat ref = t.ref.clone(), other = t.other_truth.clone();
    // Frames 0-5: a mild cast. From frame 6 on: the camera suddenly halves its exposure.
    distort(other, f < 6 ? Eigen::Matrix3d(Eigen::Vector3d(0.9, 0.95, 0.9).asDiagonal())
                         : Eigen::Matrix3d(Eigen::Vector3d(0.45, 0.5, 0.45).asDiagonal()));
    std::vector<ImageView> v = {as_view(ref), as_view(other)};
    cc.process(t.rig, 1, v);
    seen.push_back(cc.corrections()[1]);
  }
  for (std::size_t f = 1; f < seen.size(); ++f) {
    ASSERT_TRUE(seen[f].allFinite());
    EXPECT_LE((seen[f] - seen[f - 1]).norm(), o.max_step + 1e-9) << "frame " << f;
  }
  // It converges toward the new exposure (gain ~2) instead of exploding or freezing.
  EXPECT_GT(seen.back()(0, 0), seen[5](0, 0) + 0.2);
  EXPECT_LT(seen.back().maxCoeff(), 5.0 + 1e-9);
}

TEST(ColorRobustness, TooFewValidPixelsKeepTheLastCorrection) {
  TwoViews t = two_views(photos()[0]);
  ColorCorrector cc(Backend::Cpu);
  ColorOptions o;
  o.method = ColorMethod::Matrix2D;
  cc.set_options(o);
  cv::Mat ref = t.ref.clone(), other = t.other.clone();
  distort(other, Eigen::Vector3d(0.8, 0.8, 0.8).asDiagonal());
  std::vector<ImageView> v = {as_view(ref), as_view(other)};
  cc.process(t.rig, 1, v);
  const Eigen::Matrix3d first = cc.corrections()[1];
  EXPECT_FALSE(first.isIdentity(1e-3));
  // A black frame in the overlap (a covered lens): nothing valid to fit, the correction holds.
  cv::Mat black_ref(480, 640, CV_8UC4, cv::Scalar(0, 0, 0, 255)), black(480, 640, CV_8UC4, cv::Scalar(0, 0, 0, 255));
  std::vector<ImageView> vb = {as_view(black_ref), as_view(black)};
  cc.process(t.rig, 1, vb);
  EXPECT_TRUE(cc.corrections()[1].isApprox(first));
  // reset() forgets it (flush, seek, caps change).
  cc.reset();
  EXPECT_TRUE(cc.corrections()[1].isIdentity());
}

// ---- Issue 16: statistics from static, aligned pixels; corrections that hold still ----

namespace {

// A "person": a block of changing colour crossing the overlap, drawn at the same canvas place
// in both views of a TwoViews rig (the other view is shifted 320 px).
void draw_walker(cv::Mat& ref, cv::Mat& other, int frame) {
  const int x = 330 + 14 * frame, y = 120;
  const cv::Scalar colour((frame * 53) % 200 + 40, (frame * 97) % 200 + 30, (frame * 31) % 200 + 50, 255);
  cv::rectangle(ref, cv::Rect(x, y, 90, 260), colour, cv::FILLED);
  cv::rectangle(other, cv::Rect(x - 320, y, 90, 260), colour, cv::FILLED);
}

std::vector<Eigen::Matrix3d> run_walker(const ColorOptions& o, int frames, std::vector<double>* static_fraction) {
  TwoViews t = two_views(photos()[0]);
  ColorCorrector cc(Backend::Cpu);
  cc.set_options(o);
  std::vector<Eigen::Matrix3d> seen;
  const Eigen::Matrix3d cast = Eigen::Vector3d(0.85, 0.95, 0.8).asDiagonal();
  for (int f = 0; f < frames; ++f) {
    cv::Mat ref = t.ref.clone(), other = t.other_truth.clone();
    if (f >= 3) draw_walker(ref, other, f);  // enters after the first estimate
    distort(other, cast);
    std::vector<ImageView> v = {as_view(ref), as_view(other)};
    cc.process(t.rig, 1, v);
    seen.push_back(cc.corrections()[1]);
    if (static_fraction) static_fraction->push_back(cc.report().static_fraction);
  }
  return seen;
}

double largest_change(const std::vector<Eigen::Matrix3d>& seen, std::size_t from) {
  double worst = 0;
  for (std::size_t f = from; f < seen.size(); ++f) worst = std::max(worst, (seen[f] - seen[f - 1]).norm());
  return worst;
}

}  // namespace

TEST(ColorStability, WalkerInTheOverlapDoesNotMoveTheCorrection) {
  // The paper's behaviour: the walker's colours enter the overlap statistics and move M.
  ColorOptions paper;
  paper.static_mask = false;
  paper.stabilize = false;
  const auto moved = run_walker(paper, 16, nullptr);
  // The default: the walker's samples are masked as moving, the correction holds still.
  std::vector<double> fraction;
  const auto held = run_walker(ColorOptions{}, 16, &fraction);
  const double paper_change = largest_change(moved, 1), held_change = largest_change(held, 1);
  std::printf("largest per-frame change of M: paper %.4f, default %.6f\n", paper_change, held_change);
  EXPECT_GT(paper_change, 0.01);
  EXPECT_EQ(held_change, 0.0);  // bit-identical: nothing to flicker
  // The mask saw the walker (fewer samples fitted while it crosses).
  EXPECT_NEAR(fraction[1], fraction[0], 0.02);
  EXPECT_LT(*std::min_element(fraction.begin() + 4, fraction.end()), fraction[0] - 0.03);
  // The held correction is the clean scene's estimate (the walker happens to improve the
  // paper's histogram fit on this photo, so only sanity is asked of the error here).
  const Eigen::Matrix3d inverse = Eigen::Vector3d(1 / 0.85, 1 / 0.95, 1 / 0.8).asDiagonal();
  const double held_error = (held.back() - inverse).norm(), paper_error = (moved.back() - inverse).norm();
  std::printf("|M - cast^-1|: default %.4f, paper %.4f\n", held_error, paper_error);
  EXPECT_LT(held_error, 0.5 * (Eigen::Matrix3d::Identity() - inverse).norm());
  EXPECT_EQ((held.back() - moved[0]).norm(), 0.0);
}

TEST(ColorStability, MaskLeavesOutMisalignedEdges) {
  // The same view content, but the other view shifted by 6 px (a calibration error): edges no
  // longer coincide, so the alignment test drops a good share of the overlap's samples.
  TwoViews t = two_views(photos()[0]);
  ColorCorrector cc(Backend::Cpu);
  cc.set_options(ColorOptions{});
  std::vector<ImageView> v = {as_view(t.ref), as_view(t.other)};
  cc.process(t.rig, 1, v);
  const double aligned = cc.report().static_fraction;
  ColorCorrector shifted(Backend::Cpu);
  shifted.set_options(ColorOptions{});
  cv::Mat other(t.other.size(), t.other.type());
  const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, 6, 0, 1, 0);
  cv::warpAffine(t.other, other, shift, other.size(), cv::INTER_NEAREST, cv::BORDER_REPLICATE);
  std::vector<ImageView> vs = {as_view(t.ref), as_view(other)};
  shifted.process(t.rig, 1, vs);
  std::printf("fitted share: aligned %.3f, shifted by 6 px %.3f\n", aligned, shifted.report().static_fraction);
  EXPECT_GT(aligned, 0.8);
  EXPECT_LT(shifted.report().static_fraction, aligned - 0.03);
}

TEST(ColorStability, GlobalIlluminationStepIsFollowedWithinTwoFrames) {
  // Three cameras over a real photo. At frame k the light drops to 60% for every camera and
  // camera 0's white balance jumps as well (real auto exposure/white balance react so). The
  // held correction must reach the fresh estimate of the new light within 2 frames.
  cv::Mat photo = testdata::load_rgba(photos()[0]);
  std::vector<cv::Mat> truth;
  for (int i = 0; i < 3; ++i) truth.push_back(photo(cv::Rect(400 * i, 200, 640, 480)).clone());
  Rig rig = testdata::shifted_rig(3, 640, 480, 400);
  rig.reference = 1;
  const int k = 8;
  const auto frame = [&](int f, int cam) {
    cv::Mat img = truth[std::size_t(cam)].clone();
    const double light = f < k ? 1.0 : 0.6;
    Eigen::Vector3d wb = cam == 0 ? (f < k ? Eigen::Vector3d(0.8, 0.85, 0.9) : Eigen::Vector3d(1.1, 0.9, 0.7))
                         : cam == 2 ? Eigen::Vector3d(0.75, 0.8, 0.7)
                                    : Eigen::Vector3d(1, 1, 1);
    distort(img, Eigen::Matrix3d((wb * light).asDiagonal()));
    return img;
  };
  ColorCorrector cc(Backend::Cpu);
  cc.set_options(ColorOptions{});  // the defaults: stabilised, smoothing as the element's default
  for (int f = 0; f < k + 4; ++f) {
    std::vector<cv::Mat> views = {frame(f, 0), frame(f, 1), frame(f, 2)};
    std::vector<ImageView> v = {as_view(views[0]), as_view(views[1]), as_view(views[2])};
    const std::vector<Eigen::Matrix3d> before = cc.corrections();
    cc.process(rig, 1, v);
    if (f > 1 && f < k) {
      EXPECT_FALSE(cc.report().step) << "frame " << f;
      EXPECT_EQ((cc.corrections()[0] - before[0]).norm(), 0.0) << "held before the step, frame " << f;
    }
    if (f == k) EXPECT_TRUE(cc.report().step);
    if (f >= k + 1) {
      // What a corrector that only ever saw the new light would apply.
      ColorCorrector fresh(Backend::Cpu);
      fresh.set_options(ColorOptions{});
      std::vector<cv::Mat> again = {frame(f, 0), frame(f, 1), frame(f, 2)};
      std::vector<ImageView> va = {as_view(again[0]), as_view(again[1]), as_view(again[2])};
      fresh.process(rig, 1, va);
      for (int cam : {0, 2}) {
        const double psnr = testdata::psnr_rgb(views[std::size_t(cam)], again[std::size_t(cam)]);
        std::printf("frame %d camera %d: output vs fresh estimate %.2f dB\n", f, cam, psnr);
        EXPECT_GE(psnr, 40.0) << "frame " << f << " camera " << cam;
      }
    }
  }
}

TEST(ColorStability, SlowDriftIsFollowedByKeyframesAtBoundedRate) {
  // One camera's gain drifts 0.4% per frame for 25 frames (auto exposure creeping), then stays:
  // no step, so the held correction waits for a lasting change, moves at most max_rate levels
  // per frame, and holds still again once the drift stopped.
  TwoViews t = two_views(photos()[0]);
  ColorCorrector cc(Backend::Cpu);
  ColorOptions o;
  cc.set_options(o);
  const auto gain = [](int f) { return 0.9 - 0.004 * std::min(f, 25); };
  std::vector<Eigen::Matrix3d> seen;
  for (int f = 0; f < 50; ++f) {
    cv::Mat ref = t.ref.clone(), other = t.other_truth.clone();
    distort(other, Eigen::Matrix3d(Eigen::Vector3d::Constant(gain(f)).asDiagonal()));
    std::vector<ImageView> v = {as_view(ref), as_view(other)};
    cc.process(t.rig, 1, v);
    seen.push_back(cc.corrections()[1]);
  }
  int moves = 0;
  for (std::size_t f = 1; f < seen.size(); ++f) {
    const double levels = 255.0 * (seen[f] - seen[f - 1]).cwiseAbs().maxCoeff();
    EXPECT_LE(levels, 255.0 / 192.0 * o.max_rate + 1e-6) << "frame " << f;  // the bright probe moves <= max_rate
    moves += levels > 0.0;
    if (f >= 40) EXPECT_EQ(levels, 0.0) << "still after the drift, frame " << f;
  }
  EXPECT_GT(moves, 3);  // it did follow
  EXPECT_NEAR(seen.back()(0, 0), 1.0 / gain(49), 0.04);
}

TEST(ColorStability, SameCorrectionsOnAnyThreadCount) {
  // The CPU reductions run in fixed chunks on OpenCV's threads (issue 17): the integer sums,
  // and so every correction, must not depend on the thread count.
  const int threads = cv::getNumThreads();
  ColorOptions paper;
  paper.static_mask = false;
  for (const ColorOptions& o : {ColorOptions{}, paper}) {
    cv::setNumThreads(1);
    const auto one = run_walker(o, 8, nullptr);
    cv::setNumThreads(4);
    const auto four = run_walker(o, 8, nullptr);
    ASSERT_EQ(one.size(), four.size());
    for (std::size_t f = 0; f < one.size(); ++f) EXPECT_EQ((one[f] - four[f]).norm(), 0.0) << "frame " << f;
  }
  cv::setNumThreads(threads);
}

TEST(ColorApply, EveryPixelIsTheMatrixThenTheHighlightRollOffThenTheCurves) {
  // apply_all's one-pass SIMD rows against the per-pixel definition (color.hpp), on widths that
  // are and are not multiples of the four pixels a step takes, saturating both ways, alpha kept.
  std::mt19937 rng(7);
  std::uniform_int_distribution<int> byte(0, 255);
  Eigen::Matrix3d M;
  M << 1.31, 0.04, -0.02, -0.06, 0.87, 0.03, 0.02, -0.05, 1.12;  // out_c = sum_k in_k M(k, c)
  std::array<std::array<uint8_t, 256>, 3> lut;
  for (int c = 0; c < 3; ++c)
    for (int v = 0; v < 256; ++v) lut[std::size_t(c)][std::size_t(v)] = uint8_t(std::min(255, v * (9 + c) / 10 + 3));
  auto ops = ColorOps::create(Backend::Cpu);
  for (const int width : {1, 3, 4, 37, 640})
    for (const int knee : {255, 200}) {
      SCOPED_TRACE(testing::Message() << "width " << width << " knee " << knee);
      cv::Mat img(5, width, CV_8UC4);
      for (int y = 0; y < img.rows; ++y)
        for (int x = 0; x < img.cols * 4; ++x) img.ptr<uint8_t>(y)[x] = uint8_t(byte(rng));
      const cv::Mat before = img.clone();
      ops->apply_all({as_view(img)}, {M}, lut, knee);
      int off = 0, alpha_changed = 0;
      for (int y = 0; y < img.rows; ++y)
        for (int x = 0; x < img.cols; ++x) {
          const uint8_t* p = before.ptr<uint8_t>(y) + 4 * x;
          const uint8_t* o = img.ptr<uint8_t>(y) + 4 * x;
          const int m = std::max({p[0], p[1], p[2]});
          for (int c = 0; c < 3; ++c) {
            const double t = p[0] * M(0, c) + p[1] * M(1, c) + p[2] * M(2, c);
            int want = int(std::clamp(std::nearbyint(t), 0.0, 255.0));
            // float sums may round a tie the other way: one level before the curve at most, rarely
            const auto curve_of = [&](int level) {
              level = std::clamp(level, 0, 255);
              if (m > knee) level = highlight_blend(level, p[c], m, knee);
              return int(lut[std::size_t(c)][std::size_t(level)]);
            };
            off += o[c] != curve_of(want);
            EXPECT_TRUE(o[c] == curve_of(want) || o[c] == curve_of(want - 1) || o[c] == curve_of(want + 1))
                << x << "," << y << " channel " << c << ": " << int(o[c]) << " for " << curve_of(want);
          }
          alpha_changed += o[3] != p[3];
        }
      EXPECT_EQ(alpha_changed, 0);
      EXPECT_LE(off, img.rows * img.cols * 3 / 100 + 1);
    }
}
