// Projections (plane, cylindrical, spherical), the 360-degree wrap, bundle adjustment and wave
// correction. Reads the repository photo as PPM (links no imgcodecs), so it also runs on the
// GPU host, where the CUDA cases compare the device mapping with the CPU one.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <opencv2/imgproc.hpp>
#include <random>
#include <Eigen/Geometry>

#include "stitch/blend/blender_cpu.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/blend/multiband.hpp"
#include "stitch/color/color.hpp"
#include "stitch/calib/bundle_adjust.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "stitch/rig/overlap.hpp"
#include "stitch/warp/flow_pairs.hpp"
#include "stitch/warp/geometry.hpp"
#include "stitch/warp/warper.hpp"
#include "cuda_test.hpp"
#include "image_compare.hpp"
#include "ppm.hpp"
#include "ring_rig.hpp"

using namespace stitch;

namespace {

constexpr Projection kCurved[] = {Projection::Cylindrical, Projection::Spherical};

// Six 480x360 cameras (about 80 degrees wide) around 360 degrees, laid out on `kind`.
Rig ring_rig(Projection kind, double pitch_deg = 0) {
  Rig rig;
  rig.projection = projection_name(kind);
  for (int i = 0; i < 6; ++i) {
    Camera c;
    c.width = 480;
    c.height = 360;
    c.fx = c.fy = 290 + 3 * i;
    c.cx = 239.5 + i;
    c.cy = 179.5 - i;
    c.yaw_deg = 60.0 * i - (i > 3 ? 360 : 0);
    c.pitch_deg = pitch_deg + (i % 2 ? 4 : -3);
    c.roll_deg = i % 3 - 1.0;
    rig.cameras.push_back(c);
  }
  rig.reference = 0;
  rig_layout_canvas(rig);
  return rig;
}

double wrapped_dx(double dx, double period) { return dx - std::round(dx / period) * period; }

}  // namespace

TEST(Projection, ForwardAndBackwardAreInverses) {
  for (Projection kind : kCurved) {
    const Rig rig = ring_rig(kind);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> ux(0, 479), uy(0, 359);
    double worst_pixel = 0, worst_canvas = 0;
    for (int cam = 0; cam < 6; ++cam) {
      const CameraCanvasMap m = camera_canvas_map(rig, cam);
      for (int k = 0; k < 500; ++k) {
        // camera -> canvas -> camera
        const Eigen::Vector2d p(ux(rng), uy(rng));
        Eigen::Vector2d q, back;
        ASSERT_TRUE(m.to_canvas(p, q));
        ASSERT_TRUE(m.to_camera(q, back));
        worst_pixel = std::max(worst_pixel, (back - p).norm());
        // canvas -> camera -> canvas, from a canvas point the camera sees
        Eigen::Vector2d q2 = q + Eigen::Vector2d(ux(rng) - 240, uy(rng) - 180) * 0.05, p2, q3;
        if (!m.to_camera(q2, p2)) continue;
        ASSERT_TRUE(m.to_canvas(p2, q3));
        worst_canvas = std::max(worst_canvas, std::hypot(wrapped_dx(q3.x() - q2.x(), m.period), q3.y() - q2.y()));
      }
    }
    std::printf("%s: worst round trip %.2e px (camera), %.2e px (canvas)\n", projection_name(kind), worst_pixel,
                worst_canvas);
    EXPECT_LT(worst_pixel, 1e-8);
    EXPECT_LT(worst_canvas, 1e-8);
  }
  // The plane: the homography and its inverse.
  Rig plane = ring_rig(Projection::Cylindrical);
  plane.projection = "plane";
  plane.cameras.resize(3);
  plane.cameras[1].yaw_deg = 30;
  plane.cameras[2].yaw_deg = -30;
  rig_compute_rough_homographies(plane);
  const CameraCanvasMap m = camera_canvas_map(plane, 2);
  Eigen::Vector2d q, back;
  ASSERT_TRUE(m.to_canvas({100, 50}, q));
  ASSERT_TRUE(m.to_camera(q, back));
  EXPECT_LT((back - Eigen::Vector2d(100, 50)).norm(), 1e-9);
}

TEST(Projection, OutputPlacementMapsLikeTheCanvas) {
  // A scaled, cropped output: view_to_camera (what every warper and blender evaluates) agrees
  // with the canvas map through canvas_to_output.
  for (Projection kind : kCurved) {
    const Rig rig = ring_rig(kind);
    const OutputGeometry g = plan_output(rig, 1280, 0, CropMode::Auto);
    const std::vector<ViewPlacement> views = place_views(rig, g);
    const Eigen::Matrix3d out_to_canvas = g.canvas_to_output.inverse();
    double worst = 0;
    int checked = 0;
    for (int cam = 0; cam < 6; ++cam) {
      const CameraCanvasMap m = camera_canvas_map(rig, cam);
      for (int y = 0; y < g.height; y += 17)
        for (int x = 0; x < g.width; x += 13) {
          double u = 0, v = 0;
          Eigen::Vector2d p;
          const bool a = view_to_camera(views[cam], x, y, u, v);
          const bool b = m.to_camera(apply_homography(out_to_canvas, {double(x), double(y)}), p);
          ASSERT_EQ(a, b);
          // Far outside the image the coordinates grow without bound; compare where they matter.
          if (!a || std::abs(p.x() - 240) > 500 || std::abs(p.y() - 180) > 400) continue;
          worst = std::max(worst, (p - Eigen::Vector2d(u, v)).norm());
          ++checked;
        }
    }
    EXPECT_GT(checked, 1000);
    EXPECT_LT(worst, 1e-6) << projection_name(kind);
  }
}

TEST(Projection, RingWrapsAndOverlapsAcrossTheWrap) {
  for (Projection kind : kCurved) {
    const Rig rig = ring_rig(kind);
    ASSERT_TRUE(rig.canvas_wrap) << projection_name(kind);
    EXPECT_EQ(rig.canvas_width % 2, 0);
    EXPECT_NEAR(rig.canvas_width, 2 * M_PI * rig.canvas_scale, 1e-9);
    EXPECT_TRUE(rig.calibrated());
    // Camera 3 looks at 180 degrees, the reference (0 degrees) sits mid-canvas: camera 3 crosses
    // the wrap, shows at both edges and overlaps cameras 2 and 4 (one on each side of the wrap).
    const std::vector<ViewPlacement> views = place_views(rig, canvas_geometry(rig));
    EXPECT_EQ(views[3].roi.x, 0);
    EXPECT_EQ(views[3].roi.width, rig.canvas_width);
    // Its reach, for the kernels' early exit: every column it covers lies in the span.
    ASSERT_EQ(views[3].wrap_width, rig.canvas_width);
    EXPECT_GE(views[3].span_x0, 0);
    EXPECT_GT(views[3].span_x1, rig.canvas_width);
    EXPECT_LT(views[3].span_x1 - views[3].span_x0, rig.canvas_width / 3);
    for (int x = 0; x < rig.canvas_width; ++x) {
      double u = 0, v = 0;
      const bool sees = view_to_camera(views[3], x, rig.canvas_origin_y, u, v) && u >= -1 && u <= 480;
      const double xu = x < views[3].span_x0 ? x + rig.canvas_width : x;
      if (sees) {
        EXPECT_LE(xu, views[3].span_x1) << "column " << x;
      }
    }
    for (int i : {0, 1, 2, 4, 5}) EXPECT_LT(views[i].roi.width, rig.canvas_width / 2) << i;
    for (int i = 0; i < 6; ++i) {
      float area = 0;
      canvas_overlap(rig, i, (i + 1) % 6, &area);
      EXPECT_GT(area, 1000.f) << "cameras " << i << " and " << (i + 1) % 6;
      canvas_overlap(rig, i, (i + 3) % 6, &area);
      EXPECT_EQ(area, 0.f) << "opposite cameras " << i << " and " << (i + 3) % 6;
    }
    // Auto-crop keeps the whole 360 degrees (only rows are cropped), so the panorama still wraps.
    const Rect covered = largest_covered_rect(rig);
    EXPECT_EQ(covered.x, 0);
    EXPECT_EQ(covered.width, rig.canvas_width);
    EXPECT_GT(covered.height, rig.canvas_height / 2);
    EXPECT_LT(covered.height, rig.canvas_height);
    // Every column of the canvas is covered at the horizon.
    std::vector<cv::Mat> weights;
    int uncovered = 0;
    for (int x = 0; x < rig.canvas_width; ++x) {
      bool any = false;
      for (int i = 0; i < 6 && !any; ++i) {
        double u = 0, v = 0;
        any = view_to_camera(views[i], x, rig.canvas_origin_y, u, v) && u >= 0 && v >= 0 && u <= 479 && v <= 359;
      }
      uncovered += !any;
    }
    EXPECT_EQ(uncovered, 0);
  }
}

TEST(Projection, WrapOverlapsReachFlowAndColor) {
  // Odd and even rings: exactly one view crosses the wrap (it runs through that view's centre),
  // and the flow planner and the color sampler find every neighbouring overlap, the ones next
  // to the wrap included.
  for (int n : {5, 6}) {
    Rig rig;
    rig.projection = "cylindrical";
    for (int i = 0; i < n; ++i) {
      Camera c = testdata::pinhole(480, 360, 240 / std::tan((250.0 / n) * M_PI / 180));  // ~1.4 x spacing wide
      c.yaw_deg = std::remainder(360.0 * i / n + 10, 360.0);
      rig.cameras.push_back(c);
    }
    rig.reference = 1;
    rig_layout_canvas(rig);
    ASSERT_TRUE(rig.canvas_wrap) << n;
    const std::vector<ViewPlacement> views = place_views(rig, canvas_geometry(rig));
    int full = 0;
    std::vector<cv::Mat> weights;
    for (const auto& v : views) {
      full += v.roi.width == rig.canvas_width;
      weights.push_back(position_weight_map(v));
    }
    EXPECT_EQ(full, 1) << n;
    const std::vector<FlowPairPlan> plans = plan_flow_pairs(views, weights, 16, FlowQuality::Medium);
    const ColorSampling sampling = make_color_sampling(rig, 2000);
    for (int i = 0; i < n; ++i) {
      const int a = std::min(i, (i + 1) % n), b = std::max(i, (i + 1) % n);
      bool flow = false, color = false;
      for (const auto& p : plans) flow |= p.a == a && p.b == b && p.rect.width < rig.canvas_width / 2;
      for (const auto& p : sampling.pairs) color |= p.a == a && p.b == b && p.count() > 200;
      EXPECT_TRUE(flow) << n << " cameras: no flow for " << a << "-" << b;
      EXPECT_TRUE(color) << n << " cameras: no color samples for " << a << "-" << b;
    }
    EXPECT_EQ(int(plans.size()), n);
    EXPECT_EQ(int(sampling.pairs.size()), n);
  }
}

TEST(Projection, RigJsonKeepsTheCanvas) {
  const Rig rig = ring_rig(Projection::Spherical);
  const Rig back = rig_from_json_string(rig_to_json_string(rig));
  EXPECT_EQ(back.projection, "spherical");
  EXPECT_EQ(back.canvas_width, rig.canvas_width);
  EXPECT_EQ(back.canvas_scale, rig.canvas_scale);
  EXPECT_EQ(back.canvas_origin_x, rig.canvas_origin_x);
  EXPECT_TRUE(back.canvas_wrap);
  for (int i = 0; i < 6; ++i) EXPECT_LT((back.cameras[i].R() - rig.cameras[i].R()).norm(), 1e-12);
  // Laying out again keeps it (load-file re-lays the canvas).
  Rig again = back;
  rig_layout_canvas(again);
  EXPECT_EQ(again.canvas_width, rig.canvas_width);
  EXPECT_EQ(again.canvas_height, rig.canvas_height);
  EXPECT_DOUBLE_EQ(again.canvas_origin_y, rig.canvas_origin_y);
  // Streams of another size: the intrinsics scale and the canvas follows them (half the size).
  Rig half = back;
  ASSERT_TRUE(rig_adapt_to_sizes(half, std::vector<std::array<int, 2>>(6, {240, 180})));
  EXPECT_FALSE(half.calibrated());  // the canvas scale is laid out again
  rig_layout_canvas(half);
  EXPECT_TRUE(half.canvas_wrap);
  EXPECT_NEAR(half.canvas_width, rig.canvas_width / 2.0, 2);
  EXPECT_NEAR(half.canvas_height, rig.canvas_height / 2.0, 2);
  // Errors name the problem.
  try {
    rig_from_json_string(R"({"projection": "fisheye", "cameras": [{"width": 4, "height": 4, "fx": 2}]})");
    FAIL() << "an unknown projection loaded";
  } catch (const RigError& e) {
    EXPECT_NE(std::string(e.what()).find("cylindrical"), std::string::npos) << e.what();
  }
  EXPECT_THROW(rig_from_json_string(R"({"projection": "cylindrical", "canvas": {"width": 8, "height": 8},
      "cameras": [{"width": 4, "height": 4, "fx": 2}]})"),
               RigError);  // no scale
  // A camera looking at the zenith cannot go on a cylinder.
  Rig up = ring_rig(Projection::Cylindrical);
  up.cameras[1].pitch_deg = 80;
  up.canvas_scale = 0;
  EXPECT_THROW(rig_layout_canvas(up), RigError);
}

TEST(Projection, WaveCorrectionRemovesATilt) {
  Rig rig = ring_rig(Projection::Spherical, 0.0);
  for (auto& c : rig.cameras) c.pitch_deg = c.roll_deg = 0;  // a level ring
  const Rig level = rig;
  const Eigen::Matrix3d tilt = (Eigen::AngleAxisd(0.09, Eigen::Vector3d::UnitX()) *
                                Eigen::AngleAxisd(-0.06, Eigen::Vector3d::UnitZ()))
                                   .toRotationMatrix();
  for (auto& c : rig.cameras) c.set_R(tilt * c.R());
  double tilted = 0;
  for (const auto& c : rig.cameras) tilted = std::max({tilted, std::abs(c.pitch_deg), std::abs(c.roll_deg)});
  EXPECT_GT(tilted, 3.0);
  wave_correct(rig);
  for (int i = 0; i < 6; ++i) {
    EXPECT_NEAR(rig.cameras[i].pitch_deg, 0, 1e-6) << i;
    EXPECT_NEAR(rig.cameras[i].roll_deg, 0, 1e-6) << i;
    // Relative headings stay.
    const double d = rig.cameras[i].yaw_deg - rig.cameras[0].yaw_deg - (level.cameras[i].yaw_deg - level.cameras[0].yaw_deg);
    EXPECT_NEAR(std::remainder(d, 360.0), 0, 1e-6) << i;
  }
}

// A camera mounted on its side (portrait in a landscape rig, probe3): its y axis is the
// horizontal one. Taking its x axis made "up" the viewing direction and turned the panorama on
// its side (limlight pair with the right clip rotated 90 degrees: a 4098x642 canvas, half black).
TEST(Projection, WaveCorrectionKeepsACameraMountedOnItsSide) {
  for (const double side : {90.0, -90.0}) {
    Rig rig = ring_rig(Projection::Spherical, 0.0);
    rig.cameras.resize(3);
    rig.reference = 0;
    const double yaws[3] = {0, 35, -35};
    for (int i = 0; i < 3; ++i) {
      rig.cameras[i].yaw_deg = yaws[i];
      rig.cameras[i].pitch_deg = rig.cameras[i].roll_deg = 0;
    }
    rig.cameras[1].roll_deg = side;
    const Rig level = rig;
    const Eigen::Matrix3d tilt = (Eigen::AngleAxisd(0.07, Eigen::Vector3d::UnitX()) *
                                  Eigen::AngleAxisd(-0.05, Eigen::Vector3d::UnitZ()))
                                     .toRotationMatrix();
    for (auto& c : rig.cameras) c.set_R(tilt * c.R());
    wave_correct(rig);
    for (int i = 0; i < 3; ++i) {
      // Every camera's rotation relative to the level rig is one common yaw.
      const Eigen::Matrix3d d = rig.cameras[i].R() * level.cameras[i].R().transpose();
      const Eigen::Matrix3d d0 = rig.cameras[0].R() * level.cameras[0].R().transpose();
      EXPECT_LT((d - d0).norm(), 1e-6) << "camera " << i << " side " << side;
      EXPECT_NEAR(d(1, 1), 1.0, 1e-6) << "camera " << i << ": the vertical is not kept";
    }
    EXPECT_NEAR(std::abs(rig.cameras[1].roll_deg), 90.0, 1e-4);
  }
}

namespace {

// The ring rendered from the photo with a rough rig off by a few degrees and percent.
testdata::RingScene perturbed_ring(Projection kind, Rig& rough) {
  // The photo's own edges meet inside camera 1 (yaw 60), away from the canvas wrap (yaw 180).
  testdata::RingScene s = testdata::render_ring(testdata::test_photo(), 6, 480, 360, 300.0, kind, 0.0, 60.0);
  rough = s.truth;
  for (int i = 0; i < 6; ++i) {
    Camera& c = rough.cameras[i];
    c.yaw_deg += 2.5 * std::sin(1.7 * i + 0.3);
    c.pitch_deg += 1.5 * std::cos(2.3 * i);
    c.roll_deg += 1.0 * std::sin(0.9 * i + 1);
    c.fx = c.fy = 300.0 * (1 + 0.03 * std::cos(1.1 * i));
  }
  return s;
}

// The worst seam error of cameras a and b (testdata::worst_seam_px every 5 px), with enough
// shared samples to mean something.
double worst_seam_error(const Rig& est, const Rig& truth, int a, int b) {
  int n = 0;
  const double worst = testdata::worst_seam_px(est, truth, a, b, 5, &n);
  EXPECT_GT(n, 50) << "cameras " << a << ", " << b << " share too little";
  return worst;
}

}  // namespace

TEST(Projection, RingOfSixStitchesWithTheWrapSeamAligned) {
  for (Projection kind : kCurved) {
    Rig rough;
    testdata::RingScene s = perturbed_ring(kind, rough);
    std::vector<ImageView> frames;
    for (auto& f : s.frames) frames.push_back(as_view(f));
    CalibrationOptions o;
    const CalibrationResult r = calibrate_from_rig(rough, frames, o);
    const Rig& est = r.rig;
    ASSERT_TRUE(est.canvas_wrap) << projection_name(kind);
    std::printf("%s ring: canvas %dx%d, BA rms %.3f -> %.3f px\n", projection_name(kind), est.canvas_width,
                est.canvas_height, r.ba_rms_before_px, r.ba_rms_after_px);
    EXPECT_LT(r.ba_rms_after_px, 0.5);
    EXPECT_EQ(r.refined_cameras, 6);
    // The rough rig is off by pixels at every seam; the estimate within a pixel, also at the
    // pair whose seam closes the ring across the wrap (cameras 3 and 4 here: 180 and -120 deg).
    Rig rough_laid = rough;
    rig_layout_canvas(rough_laid);
    double rough_worst = 0;
    for (int i = 0; i < 6; ++i) {
      const double e = worst_seam_error(est, s.truth, i, (i + 1) % 6);
      rough_worst = std::max(rough_worst, worst_seam_error(rough_laid, s.truth, i, (i + 1) % 6));
      std::printf("  seam %d-%d: worst %.3f px\n", i, (i + 1) % 6, e);
      EXPECT_LT(e, 1.0) << "seam " << i << "-" << (i + 1) % 6;
    }
    EXPECT_GT(rough_worst, 5.0);
    // The horizon is level again: the truth ring has no pitch or roll.
    for (const auto& c : est.cameras) {
      EXPECT_NEAR(c.pitch_deg, 0, 0.2);
      EXPECT_NEAR(c.roll_deg, 0, 0.2);
    }
    // Through the real blend: the panorama is covered all round and continuous at the wrap
    // (the last column and the first are neighbours on the ring).
    Compositor comp(Backend::Cpu);
    comp.prepare(est, CompositorSettings{});
    const OutputGeometry& g = comp.geometry();
    ASSERT_EQ(g.width, est.canvas_width);
    cv::Mat pano(g.height, g.width, CV_8UC4);
    comp.compose(frames, as_view(pano));
    cv::Mat gray;
    cv::cvtColor(pano, gray, cv::COLOR_RGBA2GRAY);
    const int y0 = int(est.canvas_origin_y) - 60, y1 = int(est.canvas_origin_y) + 60;
    auto column_diff = [&](int xa, int xb) {
      double d = 0;
      for (int y = y0; y < y1; ++y) d += std::abs(int(gray.at<uint8_t>(y, xa)) - int(gray.at<uint8_t>(y, xb)));
      return d / (y1 - y0);
    };
    // Compared with the steps between the columns next to it, on both sides of the wrap.
    double local = 0;
    for (int k = 1; k <= 10; ++k) local += column_diff(g.width - 1 - k, g.width - k) + column_diff(k - 1, k);
    local /= 20;
    int black = 0;
    for (int x = 0; x < g.width; ++x) black += gray.at<uint8_t>(int(est.canvas_origin_y), x) == 0;
    const double wrap = column_diff(g.width - 1, 0);
    std::printf("  wrap column step %.2f, neighbouring columns %.2f on average\n", wrap, local);
    EXPECT_LE(wrap, 1.5 * local);
    EXPECT_EQ(black, 0);
  }
}

TEST(Projection, MultibandAcrossTheWrapBlendsTheWrappingViewInTwoPieces) {
  // A ring of six: camera 3 crosses the wrap, its roi is the whole width. Its multiband
  // pyramids cover only the columns it reaches, one piece at each edge; the panorama is the
  // weighted mean's (same exposures, true rig) up to the blend's smoothing, continuous at the wrap.
  for (Projection kind : kCurved) {
    testdata::RingScene s = testdata::render_ring(testdata::test_photo(), 6, 480, 360, 300.0, kind, 0.0, 60.0);
    rig_layout_canvas(s.truth);
    const std::vector<ViewPlacement> views = place_views(s.truth, canvas_geometry(s.truth));
    const int W = s.truth.canvas_width, H = s.truth.canvas_height;
    const MultibandLayout layout = plan_multiband(views, W, H, 5);
    int pieces_of_3 = 0, width_of_3 = 0;
    for (const MultibandPiece& p : layout.pieces)
      if (p.view == 3) ++pieces_of_3, width_of_3 += p.rect.width;
    EXPECT_EQ(layout.pieces.size(), 7u) << projection_name(kind);
    EXPECT_EQ(pieces_of_3, 2);
    EXPECT_LT(width_of_3, W / 2);
    std::vector<ImageView> host;
    for (auto& f : s.frames) host.push_back(as_view(f));
    cv::Mat panos[2];
    for (int mb = 0; mb < 2; ++mb) {
      CompositorSettings settings;
      if (mb) settings.blend = BlendMode::Multiband;
      Compositor c(Backend::Cpu);
      c.prepare(s.truth, settings);
      const OutputGeometry& g = c.geometry();
      panos[mb].create(g.height, g.width, CV_8UC4);
      c.compose(host, as_view(panos[mb]));
    }
    const double psnr = testdata::psnr_rgb(panos[1], panos[0]);
    cv::Mat gray;
    cv::cvtColor(panos[1], gray, cv::COLOR_RGBA2GRAY);
    const int w = gray.cols, y0 = gray.rows / 2 - 40, y1 = gray.rows / 2 + 40;
    auto column_diff = [&](int xa, int xb) {
      double d = 0;
      for (int y = y0; y < y1; ++y) d += std::abs(int(gray.at<uint8_t>(y, xa)) - int(gray.at<uint8_t>(y, xb)));
      return d / (y1 - y0);
    };
    double local = 0;
    for (int k = 1; k <= 10; ++k) local += column_diff(w - 1 - k, w - k) + column_diff(k - 1, k);
    local /= 20;
    const double wrap = column_diff(w - 1, 0);
    std::printf("%s ring, multiband: camera 3 in %d pieces %d px wide of %d; vs weighted %.2f dB; wrap step %.2f, "
                "neighbours %.2f\n",
                projection_name(kind), pieces_of_3, width_of_3, W, psnr, wrap, local);
    EXPECT_GT(psnr, 30.0);
    EXPECT_LE(wrap, 1.5 * local);
  }
}

namespace {

// Correspondences between cameras a and b of `truth` (a grid over a, kept where b sees it too),
// with Gaussian noise of `noise_px`.
PairMatches true_matches(const Rig& truth, int a, int b, double noise_px, std::mt19937& rng, double step = 12) {
  std::normal_distribution<double> noise(0, noise_px);
  PairMatches m;
  m.a = a;
  m.b = b;
  const Camera &A = truth.cameras[a], &B = truth.cameras[b];
  for (double y = 4; y < A.height - 4; y += step)
    for (double x = 4; x < A.width - 4; x += step) {
      const Eigen::Vector3d p = B.K() * (B.R().transpose() * (A.R() * (A.K().inverse() * Eigen::Vector3d(x, y, 1))));
      if (p.z() <= 0) continue;
      const Eigen::Vector2d q = p.head<2>() / p.z();
      if (q.x() < 4 || q.y() < 4 || q.x() > B.width - 5 || q.y() > B.height - 5) continue;
      m.pa.emplace_back(x + noise(rng), y + noise(rng));
      m.pb.emplace_back(q.x() + noise(rng), q.y() + noise(rng));
    }
  return m;
}

// Rotation of camera i relative to camera j, in degrees.
double relative_angle_deg(const Rig& a, const Rig& b, int i, int j) {
  const Eigen::Matrix3d ra = a.cameras[j].R().transpose() * a.cameras[i].R();
  const Eigen::Matrix3d rb = b.cameras[j].R().transpose() * b.cameras[i].R();
  return Eigen::AngleAxisd(ra.transpose() * rb).angle() * 180 / M_PI;
}

}  // namespace

TEST(BundleAdjustment, RecoversTheRingAndClosesItUnlikePairwiseChaining) {
  // A 6-camera ring, sparse matches from the true geometry with 1 px noise, rough parameters off by
  // degrees and percent. Chaining pairwise fits (each camera fitted to its already-placed
  // neighbour, the same solver on two cameras) carries every pair's error into the last seam;
  // the joint fit spreads it and closes the ring.
  Rig truth = ring_rig(Projection::Cylindrical);
  Rig rough = truth;
  for (int i = 0; i < 6; ++i) {
    rough.cameras[i].yaw_deg += 2.0 * std::sin(1.3 * i + 0.5);
    rough.cameras[i].pitch_deg += 1.0 * std::cos(1.9 * i);
    rough.cameras[i].roll_deg += 0.7 * std::sin(0.4 * i);
    rough.cameras[i].fx *= 1 + 0.03 * std::sin(2.1 * i + 1);
    rough.cameras[i].fy = rough.cameras[i].fx * truth.cameras[i].fy / truth.cameras[i].fx;
  }
  std::mt19937 rng(3);
  std::vector<PairMatches> all, exact;
  for (int i = 0; i < 6; ++i) {
    all.push_back(true_matches(truth, i, (i + 1) % 6, 1.0, rng, 40));
    exact.push_back(true_matches(truth, i, (i + 1) % 6, 0.0, rng, 8));
  }

  Rig joint = rough;
  const BundleAdjustReport rep = bundle_adjust(joint, all);
  ASSERT_TRUE(rep.ok);
  EXPECT_GT(rep.rms_before_px, 10.0);
  EXPECT_LT(rep.rms_after_px, 3.0);  // noise of 1 px in each of 4 coordinates: about 2.8

  Rig chained = rough;
  for (int i = 1; i < 6; ++i) {
    Rig pair;
    pair.cameras = {chained.cameras[i - 1], chained.cameras[i]};
    pair.reference = 0;
    PairMatches m = all[i - 1];
    m.a = 0;
    m.b = 1;
    BundleAdjustOptions o;
    bundle_adjust(pair, {m}, o);
    chained.cameras[i] = pair.cameras[1];
    chained.cameras[i - 1].fx = pair.cameras[0].fx;  // the parent's focal as that pair saw it
    chained.cameras[i - 1].fy = pair.cameras[0].fy;
  }
  // Misalignment against the truth: the transfer error of exact correspondences.
  auto seam_rms = [&](const Rig& r, int k) {
    const PairMatches& m = exact[k];
    double sum = 0;
    for (std::size_t j = 0; j < m.pa.size(); ++j) sum += std::pow(transfer_error_px(r, m.a, m.b, m.pa[j], m.pb[j]), 2);
    return std::sqrt(sum / m.pa.size());
  };
  double worst_angle = 0, worst_f = 0;
  for (int i = 0; i < 6; ++i) {
    worst_angle = std::max(worst_angle, relative_angle_deg(joint, truth, i, 0));
    worst_f = std::max(worst_f, std::abs(joint.cameras[i].fx / truth.cameras[i].fx - 1));
  }
  std::printf("FIGURE: 6-camera ring, sparse 1 px matches: wrap seam (5-0) error %.3f px chained, %.3f px joint; "
              "joint: worst rotation error %.4f deg, worst focal error %.3f%%\n",
              seam_rms(chained, 5), seam_rms(joint, 5), worst_angle, 100 * worst_f);
  EXPECT_LT(worst_angle, 0.5);  // the rough rig is off by up to 2 degrees and 3%
  EXPECT_LT(worst_f, 0.01);
  EXPECT_LT(seam_rms(joint, 5), 0.5);
  EXPECT_GT(seam_rms(chained, 5), 2 * seam_rms(joint, 5));
}

namespace {

// Mean distance, in reference-camera pixels, between where the estimated and the true planar
// calibrations put camera `cam`'s corners.
double corner_error_ref_px(const Rig& est, const Rig& truth, int cam) {
  const int ref = truth.reference;
  const Camera& c = truth.cameras[cam];
  const Eigen::Matrix3d want = truth.cameras[ref].K() * truth.cameras[ref].R().transpose() * c.R() * c.K().inverse();
  const Eigen::Matrix3d got = est.cameras[ref].homography->inverse() * *est.cameras[cam].homography;
  double e = 0;
  for (Eigen::Vector2d p : {Eigen::Vector2d(0, 0), Eigen::Vector2d(c.width - 1, 0),
                            Eigen::Vector2d(c.width - 1, c.height - 1), Eigen::Vector2d(0, c.height - 1)})
    e += (apply_homography(got, p) - apply_homography(want, p)).norm();
  return e / 4;
}

}  // namespace

TEST(BundleAdjustment, PlanarRigOfFiveFromImages) {
  // Five cameras 22 degrees apart (a planar canvas, reference in the middle), rough parameters
  // off by degrees and percent (one focal length for all, as for identical cameras); the chained
  // pairwise refinement (8 degrees of freedom a camera) against one global fit of the rotation
  // model. Measured, not assumed: see BENCHMARKS.md (the chain's homographies absorb SIFT's
  // small systematic keypoint offsets that the 4-parameter rotation model cannot).
  Rig truth;
  truth.reference = 2;
  for (int i = 0; i < 5; ++i) {
    Camera c;
    c.width = 400;
    c.height = 300;
    c.fx = c.fy = 360;
    c.cx = 199.5;
    c.cy = 149.5;
    c.yaw_deg = 22.0 * (i - 2);
    c.pitch_deg = 1.5 * std::sin(i);
    c.roll_deg = 0.8 * std::cos(2 * i);
    truth.cameras.push_back(c);
  }
  std::vector<cv::Mat> frames =
      testdata::render_from_panorama(testdata::test_photo(), truth, Projection::Spherical, 180.0);
  std::vector<ImageView> views;
  for (auto& f : frames) views.push_back(as_view(f));
  Rig rough = truth;
  for (int i = 0; i < 5; ++i) {
    rough.cameras[i].yaw_deg += 2.0 * std::sin(1.3 * i + 0.5);
    rough.cameras[i].pitch_deg += 1.0 * std::cos(1.9 * i);
    rough.cameras[i].fx = rough.cameras[i].fy = 360 * 1.03;
  }
  CalibrationOptions chain_opts, ba_opts;
  chain_opts.model = CameraModel::Homography;  // the default chooses by held-out matches
  ba_opts.bundle_adjust = true;
  const CalibrationResult chained = calibrate_from_rig(rough, views, chain_opts);
  const CalibrationResult adjusted = calibrate_from_rig(rough, views, ba_opts);
  double chain_worst = 0, ba_worst = 0, chain_mean = 0, ba_mean = 0;
  for (int cam = 0; cam < 5; ++cam) {
    if (cam == truth.reference) continue;
    const double ec = corner_error_ref_px(chained.rig, truth, cam), eb = corner_error_ref_px(adjusted.rig, truth, cam);
    std::printf("camera %d: corner error vs truth %.3f px chained, %.3f px bundle-adjusted\n", cam, ec, eb);
    chain_worst = std::max(chain_worst, ec);
    ba_worst = std::max(ba_worst, eb);
    chain_mean += ec / 4;
    ba_mean += eb / 4;
  }
  const AlignmentReport ac = measure_alignment(chained.rig, views), ab = measure_alignment(adjusted.rig, views);
  std::printf("FIGURE: 5-camera planar rig: corner error mean/worst %.3f/%.3f px chained, %.3f/%.3f px "
              "bundle-adjusted; alignment median %.3f vs %.3f px; BA rms %.3f -> %.3f px\n",
              chain_mean, chain_worst, ba_mean, ba_worst, ac.median_px, ab.median_px, adjusted.ba_rms_before_px,
              adjusted.ba_rms_after_px);
  // Both align the overlaps equally well; the rough rig was off by tens of pixels.
  EXPECT_LT(adjusted.ba_rms_after_px, 0.1 * adjusted.ba_rms_before_px);
  EXPECT_LE(ab.median_px, ac.median_px + 0.02);
  EXPECT_LT(ba_mean, 3.0);
  EXPECT_LT(chain_mean, 3.0);
}

// The device evaluates the same mapping: warping and composing a ring on the GPU matches the CPU
// (the view across the wrap included), for both curved projections.
TEST(ProjectionCuda, WarpAndComposeMatchCpu) {
  REQUIRE_CUDA_FOR("the CUDA warp and compose of curved projections");
#ifdef STITCH_HAVE_CUDA
  for (Projection kind : kCurved) {
    testdata::RingScene s = testdata::render_ring(testdata::test_photo(), 6, 480, 360, 300.0, kind, 0.0, 60.0);
    rig_layout_canvas(s.truth);
    const std::vector<ViewPlacement> views = place_views(s.truth, canvas_geometry(s.truth));
    auto cpu = Warper::create(Backend::Cpu), gpu = Warper::create(Backend::Cuda);
    cpu->prepare(views);
    gpu->prepare(views);
    for (int i = 0; i < 6; ++i) {
      const Rect& r = views[i].roi;
      cv::Mat expected(r.height, r.width, CV_8UC4, cv::Scalar::all(0));
      cpu->warp(i, as_view(s.frames[i]), as_view(expected));
      testdata::DeviceMat src(s.frames[i]);
      testdata::DeviceMat dst(cv::Mat(r.height, r.width, CV_8UC4, cv::Scalar::all(77)));
      gpu->warp(i, src.view(), dst.view());
      const double psnr = testdata::psnr_rgb(dst.download(), expected);
      std::printf("%s warp view %d (%dx%d): CUDA vs CPU PSNR %.2f dB\n", projection_name(kind), i, r.width, r.height,
                  psnr);
      EXPECT_GE(psnr, 45.0);
    }
    std::vector<ImageView> host;
    for (auto& f : s.frames) host.push_back(as_view(f));
    auto compose_agrees = [&](const CompositorSettings& settings, const char* what) {
      Compositor c(Backend::Cpu), g(Backend::Cuda);
      c.prepare(s.truth, settings);
      g.prepare(s.truth, settings);
      const OutputGeometry& og = c.geometry();
      cv::Mat want(og.height, og.width, CV_8UC4), got(og.height, og.width, CV_8UC4, cv::Scalar::all(77));
      c.compose(host, as_view(want));
      g.compose(host, as_view(got));
      const double psnr = testdata::psnr_rgb(got, want);
      std::printf("%s %scompose %dx%d: CUDA vs CPU PSNR %.2f dB\n", projection_name(kind), what, og.width, og.height, psnr);
      EXPECT_GE(psnr, 45.0) << what;
    };
    CompositorSettings settings;
    compose_agrees(settings, "");
    settings.output_width = 1280;
    compose_agrees(settings, "");
    CompositorSettings multiband;  // the view across the wrap in two pieces on both backends
    multiband.blend = BlendMode::Multiband;
    compose_agrees(multiband, "multiband ");
  }
#endif
}
