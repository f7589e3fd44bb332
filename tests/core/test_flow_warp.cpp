// Coarse-to-fine warping: parallax inside an overlap is aligned by the flow; identical views,
// uniform frames and views without overlap give exactly the homography-only result. Every
// case runs on the CPU and on the GPU (skipped, and said so, without a CUDA device), and the
// CUDA warper is compared with the CPU one. Links no imgcodecs: it runs on the GPU host too.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "cuda_test.hpp"
#include "image_compare.hpp"
#include "ppm.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/warp/flow_warper.hpp"
#include "synthetic_rig.hpp"

using namespace stitch;

namespace {

constexpr int kW = 320, kH = 240, kShift = 200;  // 120 px of overlap
using testdata::with_parallax;

struct Scene {
  std::vector<cv::Mat> frames;
  std::vector<ViewPlacement> views;
  OutputGeometry geometry;
};

// Camera i sees the photo from x = i * kShift; camera 1 sees it with parallax.
Scene make_scene(int cameras, double parallax, bool uniform = false) {
  cv::Mat photo = testdata::test_photo();
  cv::resize(photo, photo, cv::Size(kW + (cameras - 1) * kShift, kH), 0, 0, cv::INTER_AREA);
  if (uniform) photo.setTo(cv::Scalar(90, 90, 90, 255));
  Scene s;
  const Rig rig = testdata::shifted_rig(cameras, kW, kH, kShift);
  s.geometry = canvas_geometry(rig);
  s.views = place_views(rig, s.geometry);
  for (int i = 0; i < cameras; ++i) {
    const cv::Mat source = i == 1 && parallax > 0 ? with_parallax(photo, parallax) : photo;
    s.frames.push_back(source(cv::Rect(i * kShift, 0, kW, kH)).clone());
  }
  return s;
}

std::vector<cv::Mat> warp_views(const Scene& s, FlowWarper& w, int repeat = 1) {
  std::vector<cv::Mat> out;
  std::vector<ImageView> dst, src;
  for (const auto& v : s.views) out.emplace_back(v.roi.height, v.roi.width, CV_8UC4, cv::Scalar::all(0));
  for (auto& m : out) dst.push_back(as_view(m));
  for (const auto& f : s.frames) src.push_back(as_view(const_cast<cv::Mat&>(f)));
  for (int k = 0; k < repeat; ++k) w.warp(src, dst);
  return out;
}

std::unique_ptr<FlowWarper> warper(const Scene& s, bool flow, Backend backend) {
  auto w = FlowWarper::create(backend);
  FlowWarpSettings settings;
  settings.flow = flow;
  w->set_settings(settings);
  w->prepare(s.views, s.geometry.width, s.geometry.height);
  return w;
}

// Mean absolute RGB difference between views a and b where both are valid, in their overlap.
double overlap_mad(const Scene& s, const std::vector<cv::Mat>& warped, int a, int b) {
  const Rect& ra = s.views[a].roi;
  const Rect& rb = s.views[b].roi;
  const cv::Rect box = cv::Rect(ra.x, ra.y, ra.width, ra.height) & cv::Rect(rb.x, rb.y, rb.width, rb.height);
  const cv::Mat va = warped[a](box - cv::Point(ra.x, ra.y)), vb = warped[b](box - cv::Point(rb.x, rb.y));
  // Leave out the outer 12 px, where the displaced content has no counterpart.
  const cv::Rect inner(12, 12, box.width - 24, box.height - 24);
  cv::Mat d;
  cv::absdiff(va(inner), vb(inner), d);
  const cv::Scalar m = cv::mean(d);
  return (m[0] + m[1] + m[2]) / 3.0;
}

bool all_equal(const std::vector<cv::Mat>& a, const std::vector<cv::Mat>& b) {
  for (std::size_t i = 0; i < a.size(); ++i)
    if (cv::norm(a[i], b[i], cv::NORM_INF) != 0) return false;
  return true;
}

}  // namespace

class FlowWarp : public ::testing::TestWithParam<Backend> {
 protected:
  void SetUp() override {
    if (GetParam() == Backend::Cuda && !cuda_device_available())
      GTEST_SKIP() << "no CUDA device here (or a build without the CUDA toolkit): the CUDA flow warper is not checked";
  }
  std::unique_ptr<FlowWarper> warper(const Scene& s, bool flow) const { return ::warper(s, flow, GetParam()); }
};

TEST_P(FlowWarp, ParallaxInTheOverlapIsAligned) {
  const Scene s = make_scene(2, 4.0);
  auto coarse = warper(s, false);
  auto fine = warper(s, true);
  const double before = overlap_mad(s, warp_views(s, *coarse), 0, 1);
  const double after = overlap_mad(s, warp_views(s, *fine), 0, 1);
  std::printf("overlap MAD: homography %.2f, flow %.2f\n", before, after);
  EXPECT_GT(before, 3.0);  // the parallax is visible
  EXPECT_LT(after, 0.5 * before);
  ASSERT_EQ(fine->stats().size(), 1u);
  EXPECT_GT(fine->stats()[0].mean_magnitude, 0.5);
  EXPECT_GT(fine->stats()[0].confident_fraction, 0.5);
}

TEST_P(FlowWarp, IdenticalViewsGiveTheHomographyOnlyOutput) {
  const Scene s = make_scene(2, 0.0);
  auto coarse = warper(s, false);
  auto fine = warper(s, true);
  const auto a = warp_views(s, *coarse), b = warp_views(s, *fine, 3);
  ASSERT_EQ(fine->stats().size(), 1u);
  EXPECT_LT(fine->stats()[0].mean_magnitude, 0.05);
  EXPECT_TRUE(all_equal(a, b));
}

TEST_P(FlowWarp, UniformFramesGiveZeroFlowAndNoNaN) {
  const Scene s = make_scene(2, 0.0, true);
  auto coarse = warper(s, false);
  auto fine = warper(s, true);
  const auto a = warp_views(s, *coarse), b = warp_views(s, *fine, 2);
  ASSERT_EQ(fine->stats().size(), 1u);
  EXPECT_TRUE(std::isfinite(fine->stats()[0].mean_magnitude));
  EXPECT_EQ(fine->stats()[0].mean_magnitude, 0.0);
  EXPECT_TRUE(all_equal(a, b));
}

TEST_P(FlowWarp, ViewWithoutOverlapPassesThroughWithTheHomography) {
  Scene s = make_scene(2, 4.0);
  // A third camera far to the right of the others: no overlap with anyone.
  Rig rig = testdata::shifted_rig(3, kW, kH, kShift);
  rig.cameras[2].homography = (Eigen::Matrix3d() << 1, 0, 2 * kShift + kW + 100, 0, 1, 0, 0, 0, 1).finished();
  rig_layout_canvas(rig);
  s.geometry = canvas_geometry(rig);
  s.views = place_views(rig, s.geometry);
  s.frames.push_back(s.frames[0].clone());
  auto coarse = warper(s, false);
  auto fine = warper(s, true);
  const auto a = warp_views(s, *coarse), b = warp_views(s, *fine);
  EXPECT_EQ(fine->stats().size(), 1u);  // only the 0-1 pair
  EXPECT_EQ(cv::norm(a[2], b[2], cv::NORM_INF), 0.0);
  EXPECT_GT(cv::norm(a[1], b[1], cv::NORM_INF), 0.0);  // the overlapping ones did move
}

TEST_P(FlowWarp, ResetForgetsTheHistory) {
  const Scene moved = make_scene(2, 4.0), still = make_scene(2, 0.0);
  auto fresh = warper(moved, true);
  const auto expected = warp_views(moved, *fresh);
  auto used = warper(moved, true);
  warp_views(still, *used, 3);  // history from other content
  used->reset();
  EXPECT_TRUE(all_equal(warp_views(moved, *used), expected));
}

TEST_P(FlowWarp, MissingViewIsLeftOutAndOthersStillWarp) {
  const Scene s = make_scene(2, 4.0);
  auto coarse = warper(s, false);
  auto fine = warper(s, true);
  std::vector<cv::Mat> out;
  std::vector<ImageView> dst, src;
  for (const auto& v : s.views) out.emplace_back(v.roi.height, v.roi.width, CV_8UC4, cv::Scalar::all(7));
  for (auto& m : out) dst.push_back(as_view(m));
  src.push_back(as_view(const_cast<cv::Mat&>(s.frames[0])));
  src.push_back(ImageView());
  fine->warp(src, dst);
  EXPECT_TRUE(fine->stats().empty());
  const auto a = warp_views(s, *coarse);
  EXPECT_EQ(cv::norm(out[0], a[0], cv::NORM_INF), 0.0);  // alone: homography only
  EXPECT_EQ(cv::countNonZero(out[1].reshape(1) != 7), 0);  // untouched
}

TEST_P(FlowWarp, RejectsFramesOfTheWrongSize) {
  Scene s = make_scene(2, 0.0);
  auto fine = warper(s, true);
  cv::resize(s.frames[1], s.frames[1], cv::Size(kW / 2, kH / 2));
  EXPECT_THROW(warp_views(s, *fine), std::invalid_argument);
}

TEST_P(FlowWarp, HistorySurvivesARecalibrationThatKeepsTheOverlap) {
  // Two warpers see the same frames; one is re-prepared (a recalibration with the same
  // geometry) in between. The temporal state must carry over: identical outputs.
  const Scene s = make_scene(2, 4.0);
  auto steady = warper(s, true), recal = warper(s, true);
  warp_views(s, *steady, 2);
  warp_views(s, *recal, 2);
  recal->prepare(s.views, s.geometry.width, s.geometry.height);
  EXPECT_TRUE(all_equal(warp_views(s, *steady), warp_views(s, *recal)));
  // Without the carry-over, the re-prepared warper would start from scratch like a fresh one.
  auto fresh = warper(s, true);
  EXPECT_FALSE(all_equal(warp_views(s, *fresh), warp_views(s, *steady)));
}

// A near object in front of a background the homography aligns: view 1 sees the object 6 px
// to the right of where view 0 sees it, the background identically. The flow aligns the
// object, and the background around it keeps the homography output: no copy of a distant
// object is made beside a near one (the matching-cost gate, flow_gate_math.hpp).
Scene near_object_scene(int shift) {
  Scene s = make_scene(2, 0.0);
  cv::Mat photo = testdata::test_photo();
  cv::Mat object;
  cv::resize(photo(cv::Rect(photo.cols / 3, photo.rows / 4, photo.cols / 4, photo.rows / 3)), object, cv::Size(36, 56));
  cv::flip(object, object, 1);  // other content than the background behind it
  object.copyTo(s.frames[0](cv::Rect(kShift + 36, 90, 36, 56)));
  object.copyTo(s.frames[1](cv::Rect(36 + shift, 90, 36, 56)));
  return s;
}

TEST_P(FlowWarp, BackgroundBesideANearObjectKeepsTheHomography) {
  const Scene s = near_object_scene(6);
  auto coarse = warper(s, false);
  auto fine = warper(s, true);
  const auto a = warp_views(s, *coarse), b = warp_views(s, *fine, 3);
  // Canvas rect of the object (both copies) and the background 24 px and more away from it.
  const cv::Rect object(kShift + 36, 90, 36 + 6, 56);
  cv::Mat far(s.geometry.height, s.geometry.width, CV_8U, cv::Scalar(255));
  far(cv::Rect(object.x - 24, object.y - 24, object.width + 48, object.height + 48)) = 0;
  double worst = 0;
  for (int v = 0; v < 2; ++v) {
    const Rect& r = s.views[std::size_t(v)].roi;
    cv::Mat d;
    cv::absdiff(a[std::size_t(v)], b[std::size_t(v)], d);
    std::vector<cv::Mat> ch;
    cv::split(d, ch);
    double m = 0;
    cv::minMaxLoc(cv::max(cv::max(ch[0], ch[1]), ch[2]), nullptr, &m, nullptr, nullptr,
                  far(cv::Rect(r.x, r.y, r.width, r.height)));
    worst = std::max(worst, m);
  }
  std::printf("background beside the object: largest change %.0f grey levels\n", worst);
  EXPECT_LE(worst, 2.0);
  // ... while the object itself is aligned.
  auto object_mad = [&](const std::vector<cv::Mat>& w) {
    const Rect &ra = s.views[0].roi, &rb = s.views[1].roi;
    cv::Mat d;
    cv::absdiff(w[0](object - cv::Point(ra.x, ra.y)), w[1](object - cv::Point(rb.x, rb.y)), d);
    const cv::Scalar m = cv::mean(d);
    return (m[0] + m[1] + m[2]) / 3;
  };
  std::printf("object MAD: homography %.2f, flow %.2f\n", object_mad(a), object_mad(b));
  EXPECT_LT(object_mad(b), 0.8 * object_mad(a));
  ASSERT_EQ(fine->stats().size(), 1u);
  EXPECT_TRUE(fine->stats()[0].flow_on);
  EXPECT_LT(fine->stats()[0].error_flow, fine->stats()[0].error_homography);
}

// Where the flow cannot improve on the homography (aligned views with sensor noise), the
// overlap's decision turns the flow off and its gain ramps down over a few frames to exactly
// the homography output; where it helps (parallax) it stays on at full gain.
TEST_P(FlowWarp, FlowThatDoesNotHelpFallsBackSmoothlyToTheHomography) {
  Scene s = make_scene(2, 0.0);
  cv::Mat noise(s.frames[1].size(), CV_8UC4);
  cv::randu(noise, cv::Scalar::all(0), cv::Scalar(5, 5, 5, 1));
  s.frames[1] += noise;  // the cameras' noise differs
  auto coarse = warper(s, false);
  auto fine = warper(s, true);
  const auto homography = warp_views(s, *coarse);
  std::vector<double> gains;
  for (int k = 0; k < 6; ++k) {
    warp_views(s, *fine);
    ASSERT_EQ(fine->stats().size(), 1u);
    gains.push_back(fine->stats()[0].gain);
  }
  const FlowPairStats& st = fine->stats()[0];
  std::printf("aligned views: error %.2f without flow, %.2f with; gains", st.error_homography, st.error_flow);
  for (double g : gains) std::printf(" %.2f", g);
  std::printf("\n");
  EXPECT_FALSE(st.flow_on);
  EXPECT_GT(st.error_homography, 0.5);
  for (std::size_t k = 1; k < gains.size(); ++k) {
    EXPECT_LE(gains[k], gains[k - 1]);
    EXPECT_GE(gains[k], gains[k - 1] - 0.26);  // smooth: a bounded step per frame
  }
  EXPECT_EQ(gains.back(), 0.0);
  EXPECT_TRUE(all_equal(warp_views(s, *fine), homography));

  const Scene parallax = make_scene(2, 4.0);
  auto helps = warper(parallax, true);
  warp_views(parallax, *helps, 4);
  EXPECT_TRUE(helps->stats()[0].flow_on);
  EXPECT_EQ(helps->stats()[0].gain, 1.0);
  EXPECT_LT(helps->stats()[0].error_flow, 0.7 * helps->stats()[0].error_homography);
}

INSTANTIATE_TEST_SUITE_P(Backends, FlowWarp, ::testing::Values(Backend::Cpu, Backend::Cuda),
                         [](const ::testing::TestParamInfo<Backend>& i) { return std::string(backend_name(i.param)); });

// The CUDA warper against the CPU one: the homography-only warp equal within PSNR >= 45 dB; with
// the flow (a different dense-flow implementation) the same alignment within 0.3 grey levels.
TEST(FlowWarpBackends, CudaMatchesCpu) {
  if (!cuda_device_available()) GTEST_SKIP() << "no CUDA device here: CUDA vs CPU flow warp not compared";
  const Scene s = make_scene(3, 4.0);
  for (bool flow : {false, true}) {
    auto cpu = warper(s, flow, Backend::Cpu), gpu = warper(s, flow, Backend::Cuda);
    ASSERT_EQ(gpu->backend(), Backend::Cuda);
    const auto a = warp_views(s, *cpu, 2), b = warp_views(s, *gpu, 2);
    for (std::size_t i = 0; i < a.size(); ++i) {
      const double psnr = testdata::psnr_rgb(a[i], b[i]);
      std::printf("FLOWWARP flow=%d view %zu: CUDA vs CPU PSNR %.2f dB\n", int(flow), i, psnr);
      EXPECT_GE(psnr, flow ? 30.0 : 45.0);
    }
    if (flow) {  // the same decision, from matching errors of the same size
      ASSERT_EQ(cpu->stats().size(), gpu->stats().size());
      for (std::size_t p = 0; p < cpu->stats().size(); ++p) {
        const FlowPairStats &c = cpu->stats()[p], &g = gpu->stats()[p];
        std::printf("FLOWWARP pair %zu: error without flow CPU %.3f CUDA %.3f, with CPU %.3f CUDA %.3f\n", p,
                    c.error_homography, g.error_homography, c.error_flow, g.error_flow);
        EXPECT_NEAR(g.error_homography, c.error_homography, 0.05 * c.error_homography + 0.1);
        EXPECT_NEAR(g.error_flow, c.error_flow, 0.25 * c.error_homography + 0.2);
        EXPECT_EQ(g.flow_on, c.flow_on);
      }
    }
    const double mad_cpu = overlap_mad(s, a, 0, 1), mad_gpu = overlap_mad(s, b, 0, 1);
    std::printf("FLOWWARP flow=%d overlap MAD 0-1: CPU %.3f, CUDA %.3f\n", int(flow), mad_cpu, mad_gpu);
    EXPECT_LE(mad_gpu, mad_cpu + (flow ? 0.3 : 0.05));
  }
}

// A tall overlap (flow resolution 360 rows): its flows run in bands of rows side by side
// (issue 17). The parallax is still aligned, the views outside the flow's rectangles are the
// homography warp's exactly (they are warped apart from the bands now), every pixel is written,
// and the output is the same on 1 and 3 threads.
TEST(FlowWarpCpu, TallOverlapInBandsIsAlignedCompleteAndThreadIndependent) {
  constexpr int w = 400, h = 720, shift = 250;
  cv::Mat photo = testdata::test_photo();
  cv::resize(photo, photo, cv::Size(w + shift, h), 0, 0, cv::INTER_LINEAR);
  Scene s;
  const Rig rig = testdata::shifted_rig(2, w, h, shift);
  s.geometry = canvas_geometry(rig);
  s.views = place_views(rig, s.geometry);
  s.frames.push_back(photo(cv::Rect(0, 0, w, h)).clone());
  s.frames.push_back(with_parallax(photo, 4.0)(cv::Rect(shift, 0, w, h)).clone());
  const int threads = cv::getNumThreads();
  auto run = [&](bool flow, int n) {
    cv::setNumThreads(n);
    auto wp = warper(s, flow, Backend::Cpu);
    std::vector<cv::Mat> out;
    std::vector<ImageView> dst, src;
    // A sentinel no warp writes: a pixel left unwritten shows.
    for (const auto& v : s.views) out.emplace_back(v.roi.height, v.roi.width, CV_8UC4, cv::Scalar(1, 2, 3, 7));
    for (auto& m : out) dst.push_back(as_view(m));
    for (const auto& f : s.frames) src.push_back(as_view(const_cast<cv::Mat&>(f)));
    for (int k = 0; k < 2; ++k) wp->warp(src, dst);
    return out;
  };
  const auto coarse = run(false, 1);
  const auto one = run(true, 1), three = run(true, 3);
  cv::setNumThreads(threads);
  EXPECT_TRUE(all_equal(one, three));
  const double before = overlap_mad(s, coarse, 0, 1), after = overlap_mad(s, one, 0, 1);
  std::printf("tall overlap MAD: homography %.2f, flow in bands %.2f\n", before, after);
  EXPECT_GT(before, 3.0);
  EXPECT_LT(after, 0.5 * before);
  const Rect& ra = s.views[0].roi;
  const Rect& rb = s.views[1].roi;
  const cv::Rect overlap = cv::Rect(ra.x, ra.y, ra.width, ra.height) & cv::Rect(rb.x, rb.y, rb.width, rb.height);
  constexpr int margin = 16;  // FlowWarpSettings::margin: the flow's rectangle around the overlap
  for (int v = 0; v < 2; ++v) {
    const Rect& r = s.views[v].roi;
    cv::Mat sentinel;
    cv::inRange(one[v], cv::Scalar(1, 2, 3, 7), cv::Scalar(1, 2, 3, 7), sentinel);
    EXPECT_EQ(cv::countNonZero(sentinel), 0) << "view " << v << " has pixels no warp wrote";
    cv::Mat outside(r.height, r.width, CV_8U, cv::Scalar(255));
    outside(((overlap - cv::Point(r.x, r.y)) + cv::Size(2 * margin, 2 * margin)) - cv::Point(margin, margin) &
            cv::Rect(0, 0, r.width, r.height))
        .setTo(0);
    cv::Mat diff;
    cv::absdiff(one[v], coarse[v], diff);
    diff = diff.reshape(1, r.height * r.width) * 1;
    cv::Mat any;
    cv::reduce(diff, any, 1, cv::REDUCE_MAX);
    any = any.reshape(1, r.height);
    EXPECT_EQ(cv::countNonZero(any & outside), 0) << "view " << v << " differs from the homography warp outside the flow";
    EXPECT_GT(cv::countNonZero(any), 0) << "view " << v << ": the flow moved nothing";
  }
}
