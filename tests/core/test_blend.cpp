// Warp + position-weighted blend (paper eq. 15-16) on real images.
#include <gtest/gtest.h>

#include <atomic>
#include <functional>

#include <Eigen/Dense>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>

#include "stitch/blend/blender_cpu.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/parallel.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

// Two cameras that are exact crops of one photo, 200 px apart: a perfect calibration.
struct CropRig {
  cv::Mat photo, cam0, cam1;
  Rig rig;
};

CropRig make_crop_rig(int shift = 200) {
  CropRig c;
  c.photo = testdata::load_rgba(testdata::repo_path("data/photos/aero1.jpg"));
  c.cam0 = c.photo(cv::Rect(0, 0, 400, 300)).clone();
  c.cam1 = c.photo(cv::Rect(shift, 0, 400, 300)).clone();
  c.rig = testdata::shifted_rig(2, 400, 300, shift);
  return c;
}

// The same with view 1 tilted a little, so that the canvas has uncovered corners.
CropRig make_tilted_crop_rig() {
  CropRig c = make_crop_rig();
  Eigen::Matrix3d R;
  const double a = 0.05;
  R << std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a), 0, 0, 0, 1;
  c.rig.cameras[1].homography = R * *c.rig.cameras[1].homography;
  rig_layout_canvas(c.rig);
  return c;
}

}  // namespace

TEST(Blend, ConsistentViewsReproduceThePhoto) {
  CropRig c = make_crop_rig();
  Compositor comp(Backend::Cpu);
  comp.prepare(c.rig, CompositorSettings{});
  ASSERT_EQ(comp.geometry().width, 600);
  ASSERT_EQ(comp.geometry().height, 300);
  cv::Mat out(comp.geometry().height, comp.geometry().width, CV_8UC4);
  comp.compose({as_view(c.cam0), as_view(c.cam1)}, as_view(out));
  const cv::Mat truth = c.photo(cv::Rect(0, 0, 600, 300));
  // Blending two identical overlaps gives the photo back (up to rounding).
  EXPECT_GT(testdata::psnr_rgb(out, truth), 50.0);
}

TEST(Blend, WeightsFollowPositionAcrossTheOverlap) {
  CropRig c = make_crop_rig();
  // Make the two views differ in brightness so the blend's weights become visible.
  cv::Mat dark = c.cam1.clone();
  dark.setTo(cv::Scalar(0, 0, 0, 255));
  cv::Mat bright = c.cam0.clone();
  bright.setTo(cv::Scalar(200, 200, 200, 255));
  Compositor comp(Backend::Cpu);
  comp.prepare(c.rig, CompositorSettings{});
  cv::Mat out(300, 600, CV_8UC4);
  comp.compose({as_view(bright), as_view(dark)}, as_view(out));
  // Outside the overlap: the single view. Inside: monotonic ramp from view 0 to view 1.
  EXPECT_EQ(out.at<cv::Vec4b>(150, 100)[0], 200);
  EXPECT_EQ(out.at<cv::Vec4b>(150, 500)[0], 0);
  int prev = 255;
  for (int x = 200; x < 400; x += 10) {
    const int v = out.at<cv::Vec4b>(150, x)[0];
    EXPECT_LE(v, prev) << "x=" << x;
    prev = v;
  }
  // Eq. 16: at the middle of the overlap both views weigh the same.
  EXPECT_NEAR(out.at<cv::Vec4b>(150, 300)[0], 100, 3);
  // The panorama is opaque.
  EXPECT_EQ(out.at<cv::Vec4b>(10, 10)[3], 255);
}

TEST(Blend, NormalisedWeightsSumToOne) {
  CropRig c = make_crop_rig(150);
  BlenderCpu blender;
  Compositor comp(Backend::Cpu);
  comp.prepare(c.rig, CompositorSettings{});
  blender.prepare(comp.placements(), comp.geometry().width, comp.geometry().height);
  const auto& w = blender.weights_for(0b11);
  cv::Mat sum(comp.geometry().height, comp.geometry().width, CV_32S, cv::Scalar(0));
  for (std::size_t i = 0; i < w.size(); ++i) {
    const Rect& r = comp.placements()[i].roi;
    cv::Mat w32;
    w[i].convertTo(w32, CV_32S);
    cv::Mat roi = sum(cv::Rect(r.x, r.y, r.width, r.height));
    roi += w32;
  }
  // Every covered pixel's weights sum to exactly 1 (Q14); uncovered ones to 0.
  for (int y = 1; y < sum.rows - 1; y += 7)
    for (int x = 1; x < sum.cols - 1; x += 7) ASSERT_EQ(sum.at<int>(y, x), 1 << BlenderCpu::kWeightBits);
}

TEST(Blend, MissingViewIsLeftOutNotBlendedAsBlack) {
  CropRig c = make_crop_rig();
  Compositor comp(Backend::Cpu);
  comp.prepare(c.rig, CompositorSettings{});
  cv::Mat out(300, 600, CV_8UC4);
  comp.compose({as_view(c.cam0), ImageView{}}, as_view(out));
  // The overlap shows view 0 at full strength; the rest of view 1's area is black.
  EXPECT_GT(testdata::psnr_rgb(out(cv::Rect(0, 0, 395, 300)), c.photo(cv::Rect(0, 0, 395, 300))), 45.0);
  EXPECT_EQ(out.at<cv::Vec4b>(150, 550)[0], 0);
}

TEST(Blend, OutputScalingAndAutoCrop) {
  CropRig c = make_tilted_crop_rig();
  CompositorSettings s;
  s.crop = CropMode::Auto;
  Compositor comp(Backend::Cpu);
  comp.prepare(c.rig, s);
  cv::Mat out(comp.geometry().height, comp.geometry().width, CV_8UC4);
  comp.compose({as_view(c.cam0), as_view(c.cam1)}, as_view(out));
  EXPECT_LT(comp.geometry().width, c.rig.canvas_width);
  // No black (uncovered) pixel is left after auto crop.
  cv::Mat gray;
  cv::cvtColor(out, gray, cv::COLOR_RGBA2GRAY);
  double minv;
  cv::minMaxLoc(gray, &minv);
  EXPECT_GT(minv, 0.0);
  s.crop = CropMode::None;
  s.output_width = 300;
  comp.prepare(c.rig, s);
  EXPECT_EQ(comp.geometry().width, 300);
  EXPECT_EQ(comp.geometry().height % 2, 0);
}

TEST(Blend, DegenerateRigIsRefused) {
  CropRig c = make_crop_rig();
  Eigen::Matrix3d mirror = Eigen::Matrix3d::Identity();
  mirror(0, 0) = -1;
  c.rig.cameras[1].homography = mirror;
  Compositor comp(Backend::Cpu);
  EXPECT_THROW(comp.prepare(c.rig, CompositorSettings{}), RigError);
}

// Pre-warped views with crop=auto at the canvas' scale: the crop/scale pass is a plain row copy
// of the fused canvas (issue 17), pixel for pixel what the canvas-sized fuse gives there.
TEST(Blend, PrewarpedAutoCropIsTheCanvasSubRectangle) {
  CropRig c = make_tilted_crop_rig();
  Compositor full(Backend::Cpu), cropped(Backend::Cpu);
  full.prepare(c.rig, CompositorSettings{}, CompositorInput::Prewarped);
  CompositorSettings s;
  s.crop = CropMode::Auto;
  cropped.prepare(c.rig, s, CompositorInput::Prewarped);
  const auto& g = cropped.geometry();
  ASSERT_LT(g.width, full.geometry().width);
  ASSERT_NEAR(g.canvas_to_output(0, 0), 1.0, 1e-12);
  std::vector<cv::Mat> warped;
  std::vector<ImageView> views;
  const std::vector<cv::Mat> cams = {c.cam0, c.cam1};
  for (std::size_t i = 0; i < cams.size(); ++i) {
    const ViewPlacement& p = full.prewarped_placements()[i];
    cv::Mat w;  // any content will do: both compositors fuse the same views
    cv::resize(cams[i], w, cv::Size(p.roi.width, p.roi.height));
    warped.push_back(w);
    views.push_back(as_view(warped.back()));
  }
  cv::Mat canvas(full.geometry().height, full.geometry().width, CV_8UC4);
  cv::Mat out(g.height, g.width, CV_8UC4);
  full.compose(views, as_view(canvas));
  cropped.compose(views, as_view(out));
  const int tx = int(std::lround(-g.canvas_to_output(0, 2))), ty = int(std::lround(-g.canvas_to_output(1, 2)));
  const cv::Mat expect = canvas(cv::Rect(tx, ty, g.width, g.height));
  EXPECT_EQ(cv::norm(out, expect, cv::NORM_INF), 0.0);
}

// The tilted crop rig's two views pre-warped onto its canvas (stitchflowwarp's output), the
// canvas they fuse into, and a compositor that crops (auto) and scales it to an output
// `output_width(canvas width)` wide.
struct PrewarpedScale {
  CropRig c = make_tilted_crop_rig();
  Compositor full{Backend::Cpu}, scaled{Backend::Cpu};
  std::vector<cv::Mat> warped;
  std::vector<ImageView> views;
  cv::Mat canvas;
  explicit PrewarpedScale(const std::function<int(int)>& output_width) {
    full.prepare(c.rig, CompositorSettings{}, CompositorInput::Prewarped);
    CompositorSettings s;
    s.crop = CropMode::Auto;
    s.output_width = output_width(full.geometry().width);
    scaled.prepare(c.rig, s, CompositorInput::Prewarped);
    const std::vector<cv::Mat> cams = {c.cam0, c.cam1};
    for (std::size_t i = 0; i < cams.size(); ++i) {
      const ViewPlacement& p = full.prewarped_placements()[i];
      warped.emplace_back();
      cv::resize(cams[i], warped.back(), cv::Size(p.roi.width, p.roi.height));
    }
    for (auto& w : warped) views.push_back(as_view(w));
    canvas.create(full.geometry().height, full.geometry().width, CV_8UC4);
    full.compose(views, as_view(canvas));
  }
};

// Pre-warped views with crop=auto and a mild scale (bilinear): the output is OpenCV's bilinear warp
// of the whole fused canvas, byte for byte, although only the canvas rows it reads are fused.
TEST(Blend, PrewarpedBilinearScaleIsTheWarpOfTheWholeCanvas) {
  PrewarpedScale t([](int canvas_width) { return 2 * int(0.45 * canvas_width); });
  Compositor& scaled = t.scaled;
  const std::vector<ImageView>& views = t.views;
  const cv::Mat& canvas = t.canvas;
  const OutputGeometry& g = scaled.geometry();
  const Eigen::Matrix3d& A = g.canvas_to_output;
  ASSERT_GE(A(0, 0), 0.75);
  ASSERT_LT(A(0, 0), 1.0);
  cv::Mat out(g.height, g.width, CV_8UC4), expect;
  scaled.compose(views, as_view(out));
  const cv::Matx23d affine(A(0, 0), A(0, 1), A(0, 2), A(1, 0), A(1, 1), A(1, 2));
  cv::warpAffine(canvas, expect, affine, out.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0, 255));
  EXPECT_EQ(cv::norm(out, expect, cv::NORM_INF), 0.0);
}

// Pre-warped views with crop=auto and a strong downscale (stitchflowwarp's canvas into a smaller
// panorama): each output pixel is the area average of the canvas under its footprint (one pass,
// no bilinear second pass, not shifted), within one level of rounding, and the same on any
// thread count.
TEST(Blend, PrewarpedDownscaleIsTheCanvasAreaAverage) {
  for (const int width : {320, 210}) {  // 3 and 4 canvas pixels under an output pixel
  SCOPED_TRACE(width);
  PrewarpedScale t([&](int) { return width; });
  Compositor& scaled = t.scaled;
  const std::vector<ImageView>& views = t.views;
  const cv::Mat& canvas = t.canvas;
  const OutputGeometry& g = scaled.geometry();
  const Eigen::Matrix3d& A = g.canvas_to_output;
  ASSERT_LT(A(0, 0), 0.75);
  ASSERT_LT(A(1, 1), 0.75);
  const int threads = cv::getNumThreads();
  cv::Mat out1(g.height, g.width, CV_8UC4), out3(g.height, g.width, CV_8UC4);
  cv::setNumThreads(3);
  scaled.compose(views, as_view(out3));
  cv::setNumThreads(1);
  scaled.compose(views, as_view(out1));
  cv::setNumThreads(threads);
  EXPECT_EQ(cv::norm(out1, out3, cv::NORM_INF), 0.0);
  // The reference: exact overlaps in doubles (canvas pixel x covers [x - 0.5, x + 0.5]).
  auto overlaps = [](double s, double t, int u, int n) {
    std::vector<std::pair<int, double>> o;
    const double f0 = (u - 0.5 - t) / s, f1 = (u + 0.5 - t) / s;
    for (int x = std::max(0, int(std::floor(f0)) - 1); x <= std::min(n - 1, int(std::ceil(f1)) + 1); ++x) {
      const double w = std::min(f1, x + 0.5) - std::max(f0, x - 0.5);
      if (w > 1e-9) o.push_back({x, w});
    }
    return o;
  };
  double worst = 0;
  for (int v = 0; v < g.height; ++v) {
    const auto oy = overlaps(A(1, 1), A(1, 2), v, canvas.rows);
    for (int u = 0; u < g.width; ++u) {
      const auto ox = overlaps(A(0, 0), A(0, 2), u, canvas.cols);
      for (int k = 0; k < 3; ++k) {
        double sum = 0, total = 0;
        for (const auto& [y, wy] : oy)
          for (const auto& [x, wx] : ox) {
            sum += wy * wx * canvas.at<cv::Vec4b>(y, x)[k];
            total += wy * wx;
          }
        const double expect = total > 0 ? sum / total : 0;
        worst = std::max(worst, std::abs(out1.at<cv::Vec4b>(v, u)[k] - expect));
      }
    }
  }
  EXPECT_LE(worst, 1.0) << "largest difference from the canvas' area average";
  std::printf("downscale %.3f x %.3f to %dx%d: largest difference from the area average %.3f\n", A(0, 0), A(1, 1),
              g.width, g.height, worst);
  }
}

// parallel_tasks_beside_parts (the seam DP sweeps beside the mix rows): every task and every
// (item, part) runs exactly once, at any thread count, and no two tasks share a stripe index.
TEST(Parallel, EveryTaskAndPartRunsOnceBesideEachOther) {
  const int threads = cv::getNumThreads();
  for (const int n : {1, 2, 7, 16})
    for (const int tasks : {0, 1, 4}) {
      cv::setNumThreads(n);
      const std::vector<int> parts = {5, 0, 739, 3};
      std::vector<std::atomic<int>> task_runs(static_cast<std::size_t>(tasks));
      std::vector<std::vector<std::atomic<int>>> part_runs;
      for (const int p : parts) part_runs.emplace_back(std::size_t(p));
      parallel_tasks_beside_parts(tasks, [&](int t) { task_runs[std::size_t(t)]++; }, parts,
                                  [&](std::size_t i, int k) { part_runs[i][std::size_t(k)]++; });
      for (auto& r : task_runs) EXPECT_EQ(r.load(), 1) << n << " threads, " << tasks << " tasks";
      for (auto& item : part_runs)
        for (auto& r : item) EXPECT_EQ(r.load(), 1) << n << " threads, " << tasks << " tasks";
    }
  cv::setNumThreads(threads);
  // Only tasks, and nothing at all.
  int runs = 0;
  parallel_tasks_beside_parts(3, [&](int) { ++runs; }, {}, [&](std::size_t, int) { ADD_FAILURE(); });
  cv::setNumThreads(threads);
  EXPECT_EQ(runs, 3);
  parallel_tasks_beside_parts(0, [&](int) { ADD_FAILURE(); }, {0, 0}, [&](std::size_t, int) { ADD_FAILURE(); });
}
