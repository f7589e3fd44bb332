// Lenses (issue 15): radtan and fisheye in every per-view mapping against OpenCV, the inverse,
// the JSON / OpenCV YAML / Hugin .pto loaders, bad lenses, and rigs stitched with their true
// lenses (planar radtan, dual fisheye to the full sphere) against ground truth. Reads the
// repository photo as PPM (taken as an equirectangular panorama); links no imgcodecs.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/calib3d.hpp>
#include <random>

#include "image_compare.hpp"
#include "lens_rig.hpp"
#include "ppm.hpp"
#include "stitch/blend/compositor.hpp"
#include "stitch/calib/calib_session.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "stitch/rig/lens.hpp"
#include "stitch/rig/opencv_yaml.hpp"
#include "stitch/rig/overlap.hpp"
#include "stitch/rig/pto.hpp"
#include "stitch/warp/geometry.hpp"

using namespace stitch;

namespace {

Camera radtan_camera(double k1, double k2, double k3, double p1, double p2) {
  Camera c;
  c.width = 640;
  c.height = 480;
  c.fx = 520;
  c.fy = 515;
  c.cx = 322.5;
  c.cy = 238.0;
  c.lens.model = Lens::Model::Radtan;
  c.lens.k1 = k1, c.lens.k2 = k2, c.lens.k3 = k3, c.lens.p1 = p1, c.lens.p2 = p2;
  return c;
}

cv::Mat camera_matrix(const Camera& c) { return (cv::Mat_<double>(3, 3) << c.fx, 0, c.cx, 0, c.fy, c.cy, 0, 0, 1); }

}  // namespace

TEST(Lens, RadtanMatchesOpenCvProjectPoints) {
  const double coeffs[][5] = {{-0.35, 0.12, -0.02, 0.001, -0.0005}, {-0.23, 0.055, 0, 0, 0}, {0.1, -0.01, 0, 0.002, 0.001}};
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-0.6, 0.6);
  for (const auto& k : coeffs) {
    const Camera c = radtan_camera(k[0], k[1], k[2], k[3], k[4]);
    std::vector<cv::Point3d> pts;
    for (int i = 0; i < 500; ++i) pts.emplace_back(u(rng), u(rng), 1.0);
    std::vector<cv::Point2d> ref;
    const cv::Mat D = (cv::Mat_<double>(1, 5) << k[0], k[1], k[3], k[4], k[2]);
    cv::projectPoints(pts, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), camera_matrix(c), D, ref);
    double worst = 0;
    for (std::size_t i = 0; i < pts.size(); ++i) {
      Eigen::Vector2d q;
      ASSERT_TRUE(lens_project(c, {pts[i].x, pts[i].y, pts[i].z}, q));
      worst = std::max(worst, std::hypot(q.x() - ref[i].x, q.y() - ref[i].y));
      // The float (device) evaluation of the same formula.
      float fu, fv;
      ASSERT_TRUE(stitch_projection::lens_project(lens_params_f(c), float(pts[i].x), float(pts[i].y), 1.f, fu, fv));
      EXPECT_NEAR(fu, ref[i].x, 2e-3);
      EXPECT_NEAR(fv, ref[i].y, 2e-3);
    }
    EXPECT_LT(worst, 1e-3) << "k1 " << k[0];
  }
}

TEST(Lens, RadtanPlanarViewMatchesInitUndistortRectifyMap) {
  // A planar canvas that is the camera's own ideal image: the warp map is OpenCV's undistort map.
  Rig rig;
  Camera c = radtan_camera(-0.3, 0.08, 0, 0.001, -0.001);
  c.homography = Eigen::Matrix3d::Identity();
  rig.cameras = {c};
  rig.canvas_width = c.width;
  rig.canvas_height = c.height;
  OutputGeometry g;
  g.width = c.width;
  g.height = c.height;
  const ViewPlacement v = place_views(rig, g)[0];
  ASSERT_TRUE(v.has_lens());
  cv::Mat mx, my;
  const cv::Mat D = (cv::Mat_<double>(1, 5) << -0.3, 0.08, 0.001, -0.001, 0);
  cv::initUndistortRectifyMap(camera_matrix(c), D, cv::Mat(), camera_matrix(c), cv::Size(c.width, c.height), CV_32FC1,
                              mx, my);
  double worst = 0;
  for (int y = 0; y < c.height; y += 7)
    for (int x = 0; x < c.width; x += 7) {
      double u, w;
      ASSERT_TRUE(view_to_camera(v, x, y, u, w));
      worst = std::max(worst, std::hypot(u - mx.at<float>(y, x), w - my.at<float>(y, x)));
    }
  // OpenCV's map is float: its own rounding is about 1e-4 px at 640 px.
  EXPECT_LT(worst, 1e-3);
}

TEST(Lens, FisheyeMatchesOpenCvFisheyeProjectPoints) {
  Camera c;
  c.width = c.height = 1000;
  c.fx = c.fy = 310;
  c.cx = 501;
  c.cy = 498;
  c.lens.model = Lens::Model::Fisheye;
  c.lens.k1 = -0.0437, c.lens.k2 = 0.0217, c.lens.k3 = -0.0264, c.lens.k4 = 0.0084;  // the surround-view set's
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-3, 3);
  std::vector<cv::Point3d> pts;
  for (int i = 0; i < 500; ++i) pts.emplace_back(u(rng), u(rng), 1.0);  // up to ~77 degrees
  std::vector<cv::Point2d> ref;
  const cv::Vec4d D(c.lens.k1, c.lens.k2, c.lens.k3, c.lens.k4);
  cv::fisheye::projectPoints(pts, ref, cv::Vec3d(0, 0, 0), cv::Vec3d(0, 0, 0), cv::Matx33d((double*)camera_matrix(c).data), D);
  double worst = 0;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    Eigen::Vector2d q;
    ASSERT_TRUE(lens_project(c, {pts[i].x, pts[i].y, pts[i].z}, q));
    worst = std::max(worst, std::hypot(q.x() - ref[i].x, q.y() - ref[i].y));
  }
  EXPECT_LT(worst, 1e-3);
  // Beyond 90 degrees (behind the camera's plane) the same law continues: theta = 100 degrees.
  Camera wide = testdata::fisheye_camera(800, 200);
  const double t = 100 * CV_PI / 180;
  Eigen::Vector2d q;
  ASSERT_TRUE(lens_project(wide, {std::sin(t), 0, std::cos(t)}, q));
  EXPECT_NEAR(q.x() - wide.cx, wide.fx * t, 1e-6);
}

TEST(Lens, UndistortInvertsDistortAndMatchesOpenCv) {
  const Camera r = radtan_camera(-0.35, 0.12, -0.02, 0.001, -0.0005);
  std::vector<cv::Point2f> raw;
  for (int y = 0; y < r.height; y += 40)
    for (int x = 0; x < r.width; x += 40) raw.emplace_back(float(x), float(y));
  const std::vector<cv::Point2f> ours = undistort_points(r, raw);
  std::vector<cv::Point2f> ref;
  const cv::Mat D = (cv::Mat_<double>(1, 5) << -0.35, 0.12, 0.001, -0.0005, -0.02);
  cv::undistortPoints(raw, ref, camera_matrix(r), D, cv::noArray(), camera_matrix(r),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-12));
  double worst_cv = 0, worst_round = 0;
  for (std::size_t i = 0; i < raw.size(); ++i) {
    ASSERT_TRUE(std::isfinite(ours[i].x)) << raw[i];
    worst_cv = std::max(worst_cv, double(cv::norm(ours[i] - ref[i])));
    Eigen::Vector2d back;
    ASSERT_TRUE(distort_point(r, {ours[i].x, ours[i].y}, back));
    worst_round = std::max(worst_round, std::hypot(back.x() - raw[i].x, back.y() - raw[i].y));
  }
  EXPECT_LT(worst_cv, 2e-2);  // OpenCV's fixed-point iteration converges more loosely than Newton
  EXPECT_LT(worst_round, 1e-3);
  // Fisheye beyond 90 degrees: raw -> ray -> raw.
  const Camera f = testdata::fisheye_camera(800, 210, -0.01, 0.001);
  double worst_f = 0;
  for (int k = 0; k < 200; ++k) {
    const double a = k * 0.31, rad = (k % 20) * 19.5;
    const Eigen::Vector2d p(f.cx + rad * std::cos(a), f.cy + rad * std::sin(a));
    Eigen::Vector3d ray;
    ASSERT_TRUE(lens_unproject(f, p, ray));
    Eigen::Vector2d back;
    ASSERT_TRUE(lens_project(f, ray, back));
    worst_f = std::max(worst_f, (back - p).norm());
  }
  EXPECT_LT(worst_f, 1e-6);
}

TEST(Lens, JsonRoundTripAndPinholeFilesUnchanged) {
  const std::string pinhole = R"({"format":"stitch-rig","version":1,"cameras":[{"width":640,"height":480,"fx":600}]})";
  const Rig p = rig_from_json_string(pinhole);
  EXPECT_TRUE(p.cameras[0].lens.pinhole());
  EXPECT_EQ(rig_to_json_string(p).find("lens"), std::string::npos);
  const std::string text = R"({"cameras":[
    {"width":640,"height":480,"fx":500,"lens":{"model":"radtan","k1":-0.2,"k2":0.03,"p1":0.001}},
    {"width":960,"height":960,"fx":300,"lens":{"model":"fisheye","k1":0.01,"k4":-0.001,"circle":{"cx":480,"cy":479,"radius":470}}},
    {"width":640,"height":480,"fx":500,"lens":{"model":"radtan"}}]})";
  const Rig r = rig_from_json_string(text);
  EXPECT_EQ(r.cameras[0].lens.model, Lens::Model::Radtan);
  EXPECT_DOUBLE_EQ(r.cameras[0].lens.k1, -0.2);
  EXPECT_DOUBLE_EQ(r.cameras[0].lens.p1, 0.001);
  EXPECT_FALSE(r.cameras[0].lens.estimate);
  EXPECT_EQ(r.cameras[1].lens.model, Lens::Model::Fisheye);
  ASSERT_TRUE(r.cameras[1].lens.circle);
  EXPECT_DOUBLE_EQ(r.cameras[1].lens.circle->radius, 470);
  EXPECT_TRUE(r.cameras[2].lens.estimate);  // a model without coefficients: estimate them
  const Rig back = rig_from_json_string(rig_to_json_string(r));
  for (int i = 0; i < 3; ++i) EXPECT_TRUE(back.cameras[i].lens == r.cameras[i].lens) << i;
}

TEST(Lens, BadLensesAreRejectedNamingTheCamera) {
  auto error_of = [](const std::string& lens) {
    try {
      rig_from_json_string(R"({"cameras":[{"width":640,"height":480,"fx":600},{"width":640,"height":480,"fx":400,"lens":)" +
                           lens + "}]}");
    } catch (const RigError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const std::string fold = error_of(R"({"model":"radtan","k1":-0.9})");  // the radius folds inside the frame
  EXPECT_NE(fold.find("camera 1"), std::string::npos) << fold;
  EXPECT_NE(fold.find("fold"), std::string::npos) << fold;
  const std::string circle = error_of(R"({"model":"fisheye","circle":{"cx":2000,"cy":240,"radius":100}})");
  EXPECT_NE(circle.find("outside the frame"), std::string::npos) << circle;
  EXPECT_NE(error_of(R"({"model":"brown"})").find("not supported"), std::string::npos);
  EXPECT_TRUE(error_of(R"({"model":"radtan","k1":-0.1})").empty());
}

TEST(Lens, OpenCvYamlLoadsPinholeFisheyeAndKalibr) {
  const auto dir = std::filesystem::temp_directory_path() / ("stitch_lens_yaml_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  {
    cv::FileStorage fs((dir / "fish.yaml").string(), cv::FileStorage::WRITE);
    fs << "camera_matrix" << (cv::Mat_<double>(3, 3) << 302.45, 0, 496.64, 0, 320.75, 331.2, 0, 0, 1);
    fs << "dist_coeffs" << (cv::Mat_<double>(4, 1) << -0.0437, 0.0217, -0.0264, 0.0084);
    fs << "resolution" << (cv::Mat_<int>(2, 1) << 960, 640);
  }
  const Rig f = rig_load((dir / "fish.yaml").string());  // by extension
  ASSERT_EQ(f.cameras.size(), 1u);
  EXPECT_EQ(f.cameras[0].lens.model, Lens::Model::Fisheye);
  EXPECT_EQ(f.cameras[0].width, 960);
  EXPECT_DOUBLE_EQ(f.cameras[0].lens.k4, 0.0084);
  {
    std::ofstream out(dir / "pair.yml");
    out << "%YAML:1.0\n---\nprojection: plane\n"
           "cam0:\n  camera_matrix: !!opencv-matrix\n    rows: 3\n    cols: 3\n    dt: d\n"
           "    data: [ 500., 0., 319.5, 0., 500., 239.5, 0., 0., 1. ]\n"
           "  distortion_coefficients: [ -0.2, 0.05, 0.0, 0.0, 0.0 ]\n  image_width: 640\n  image_height: 480\n"
           "cam1:\n  distortion_model: radtan\n  intrinsics: [ 500., 500., 319.5, 239.5 ]\n"
           "  distortion_coeffs: [ -0.2, 0.05, 0.0, 0.0 ]\n  resolution: [ 640, 480 ]\n"
           "  T_cn_cnm1: [ 0.9396926, 0., -0.3420201, 0.1, 0., 1., 0., 0., 0.3420201, 0., 0.9396926, 0., 0., 0., 0., 1. ]\n";
  }
  const Rig pair = rig_load((dir / "pair.yml").string());
  ASSERT_EQ(pair.cameras.size(), 2u);
  EXPECT_EQ(pair.cameras[0].lens.model, Lens::Model::Radtan);
  EXPECT_NEAR(pair.cameras[1].yaw_deg, 20.0, 1e-4);  // T rotates camera 0 rays by -20 degrees about y
  EXPECT_TRUE(pair.calibrated());                     // overlapping: laid out
  // The real surround-view calibration, where the shared data is present.
  const char* shared = std::getenv("STITCH_SHARED_DATA");
  const std::string real = std::string(shared ? shared : "") + "/images/surround_view_4fisheye/front.yaml";
  if (shared && std::filesystem::exists(real)) {
    const Rig s = rig_load(real);
    EXPECT_EQ(s.cameras[0].lens.model, Lens::Model::Fisheye);
    EXPECT_EQ(s.cameras[0].width, 960);
  }
  std::filesystem::remove_all(dir);
}

// OpenCV fisheye calibrations of wide lenses fold back in the frame's corners, beyond what the
// calibration saw (../shared's surround-view left camera: theta_d peaks at 87 degrees). The YAML
// loader refused such files ("the fisheye coefficients fold the image"), so the documented
// rig-file=cams.yaml failed on real data; now the lens gets an image circle that ends just
// before the fold. A fold well inside the frame is still refused, naming the camera.
TEST(Lens, OpenCvYamlFisheyeFoldingInTheCornersGetsAnImageCircle) {
  const auto dir = std::filesystem::temp_directory_path() / ("stitch_lens_fold_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  auto write = [&](const std::string& name, double k1, double k3) {
    cv::FileStorage fs((dir / name).string(), cv::FileStorage::WRITE);
    fs << "camera_matrix" << (cv::Mat_<double>(3, 3) << 300, 0, 479.5, 0, 300, 319.5, 0, 0, 1);
    fs << "dist_coeffs" << (cv::Mat_<double>(4, 1) << k1, 0.0, k3, 0.0);
    fs << "resolution" << (cv::Mat_<int>(2, 1) << 960, 640);
  };
  write("corners.yaml", -0.02, -0.01);  // folds at 87 degrees: 375 px out, the corners 577 px
  Rig r;
  ASSERT_NO_THROW(r = rig_load((dir / "corners.yaml").string()));
  ASSERT_EQ(r.cameras.size(), 1u);
  const Camera& c = r.cameras[0];
  EXPECT_EQ(c.lens.model, Lens::Model::Fisheye);
  ASSERT_TRUE(c.lens.circle);
  EXPECT_NEAR(c.lens.circle->cx, 479.5, 1e-9);
  EXPECT_NEAR(c.lens.circle->cy, 319.5, 1e-9);
  EXPECT_GT(c.lens.circle->radius, 340);
  EXPECT_LT(c.lens.circle->radius, 380);
  EXPECT_EQ(lens_problem(c), "");
  // Inside the circle the lens unprojects and projects back (no fold).
  for (double x = 479.5; x < 479.5 + c.lens.circle->radius - 1; x += 20) {
    Eigen::Vector3d ray;
    Eigen::Vector2d q;
    ASSERT_TRUE(lens_unproject(c, {x, 319.5}, ray)) << x;
    ASSERT_TRUE(lens_project(c, ray, q)) << x;
    EXPECT_NEAR(q.x(), x, 1e-3);
  }
  write("inside.yaml", -0.3, 0.0);  // folds at 60 degrees, 210 px out: most of the frame
  try {
    rig_load((dir / "inside.yaml").string());
    ADD_FAILURE() << "a fold well inside the frame must be refused";
  } catch (const RigError& e) {
    EXPECT_NE(std::string(e.what()).find("camera 0"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("fold"), std::string::npos) << e.what();
  }
  std::filesystem::remove_all(dir);
}

TEST(Lens, PtoLoadsAndFitsThePanotoolsPolynomial) {
  const std::string pto =
      "# hugin project\n"
      "p f2 w4000 h2000 v360 E0 R0 n\"TIFF_m c:LZW\"\n"
      "i w1600 h1200 f0 v70 Ra0 Rb0 Rc0 Rd0 Re0 Eev0 Er1 Eb1 r0 p0 y0 TrX0 TrY0 TrZ0 j0 a0.002 b-0.02 c0.005 d12 e-8 g0 t0 "
      "Va1 Vb0 Vc0 Vd0 Vx0 Vy0 Vm5 n\"img 0.jpg\"\n"
      "i w1600 h1200 f0 v=0 r1.5 p-2 y50 a=0 b=0 c=0 d=0 e=0 n\"img1.jpg\"\n"
      "i w1600 h1200 f0 v=0 r0 p3 y100 a=0 b=0 c=0 d=0 e=0 n\"img2.jpg\"\n";
  PtoReport rep;
  const Rig rig = rig_from_pto_string(pto, &rep);
  ASSERT_EQ(rig.cameras.size(), 3u);
  EXPECT_EQ(rig.projection, "spherical");
  EXPECT_TRUE(rig.calibrated());
  const Camera& c = rig.cameras[1];
  const double f_pano = 800 / std::tan(35 * CV_PI / 180);  // panotools' ideal image
  EXPECT_NEAR(c.fx, f_pano * (1 - 0.002 + 0.02 - 0.005), 0.05 * f_pano);
  EXPECT_DOUBLE_EQ(c.yaw_deg, 50);
  EXPECT_DOUBLE_EQ(c.pitch_deg, -2);
  EXPECT_NEAR(c.cx, 799.5 + 12, 1e-9);
  EXPECT_NEAR(c.cy, 599.5 - 8, 1e-9);
  EXPECT_EQ(c.lens.model, Lens::Model::Radtan);
  // Our lens against panotools' radius law, across the image.
  const double half = 600, d = 1 - 0.002 + 0.02 - 0.005;
  double worst = 0;
  for (double r_ideal = 10; r_ideal < 900; r_ideal += 10) {
    const double rn = r_ideal / half;
    const double raw = (((0.002 * rn - 0.02) * rn + 0.005) * rn + d) * rn * half;
    Eigen::Vector2d q;
    ASSERT_TRUE(lens_project(c, {r_ideal / f_pano, 0, 1}, q));
    worst = std::max(worst, std::abs(q.x() - c.cx - raw));
  }
  EXPECT_LT(worst, 0.5);
  ASSERT_EQ(rep.fit_residual_px.size(), 3u);
  EXPECT_LT(rep.fit_residual_px[0], 0.5);
  std::printf("pto: panotools a,b,c -> radtan k1 %.5f k2 %.5f k3 %.5f, worst residual %.3f px (checked %.3f)\n", c.lens.k1,
              c.lens.k2, c.lens.k3, rep.fit_residual_px[0], worst);
  // A circular fisheye lens: the image circle from the crop.
  const Rig fish = rig_from_pto_string(
      "p f2 w2000 h1000 v360\ni w1000 h1000 f2 v200 y0 p0 r0 S20,980,20,980\ni w1000 h1000 f2 v=0 y180 p0 r0 S20,980,20,980\n");
  EXPECT_EQ(fish.cameras[0].lens.model, Lens::Model::Fisheye);
  ASSERT_TRUE(fish.cameras[0].lens.circle);
  EXPECT_NEAR(fish.cameras[0].lens.circle->radius, 480, 1e-9);
  EXPECT_THROW(rig_from_pto_string("p f0 w100 v50\ni w100 h100 f4 v50\n"), RigError);
  // rig_load (what stitchcalib's rig-file / load-file call) reads .pto by extension.
  const auto path = std::filesystem::temp_directory_path() / ("stitch_lens_" + std::to_string(::getpid()) + ".pto");
  {
    std::ofstream out(path);
    out << pto;
  }
  EXPECT_EQ(rig_load(path.string()).cameras.size(), 3u);
  std::filesystem::remove(path);
}

TEST(Lens, DualFisheyeStitchesTheFullSphere) {
  const cv::Mat photo = testdata::test_photo();
  for (double fov : {190.0, 220.0}) {
    const Rig rig = testdata::dual_fisheye_rig(240, fov);
    EXPECT_TRUE(rig.canvas_wrap);
    EXPECT_EQ(rig.canvas_width, 2 * rig.canvas_height) << "a full sphere is 2:1";
    std::vector<cv::Mat> frames;
    for (const auto& c : rig.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
    const cv::Mat pano = testdata::compose_cpu(rig, frames);
    ASSERT_EQ(pano.cols, rig.canvas_width);
    cv::Mat gt = testdata::equirect_ground_truth(photo, rig);
    // The output is the canvas padded to even sizes.
    cv::Mat padded(pano.size(), gt.type(), cv::Scalar::all(0));
    gt.copyTo(padded(cv::Rect(0, 0, gt.cols, gt.rows)));
    gt = padded;
    // Every pixel covered, poles included: no black rows at the top or bottom.
    cv::Mat gray;
    cv::cvtColor(pano, gray, cv::COLOR_RGBA2GRAY);
    const double top = cv::mean(gray.row(0))[0], bottom = cv::mean(gray.row(rig.canvas_height - 1))[0];
    EXPECT_GT(top, 5.0);
    EXPECT_GT(bottom, 5.0);
    cv::Mat all(pano.size(), CV_8U, cv::Scalar(0));
    all(cv::Rect(0, 0, rig.canvas_width, rig.canvas_height)).setTo(255);
    const double psnr = testdata::masked_psnr_rgb(pano, gt, all);
    std::printf("dual fisheye %.0f deg, 2x %dx%d -> %dx%d sphere: PSNR vs ground truth %.2f dB\n", fov, 240, 240,
                pano.cols, pano.rows, psnr);
    EXPECT_GT(psnr, 24.0);
  }
}

TEST(Lens, RadtanRigStitchesMuchBetterWithItsLens) {
  // Three barrel-distorted cameras on a plane canvas, rendered with their lenses; stitched with
  // the true calibration, lens on versus the same rig with the lens ignored.
  const cv::Mat photo = testdata::test_photo();
  for (double k1 : {-0.35, -0.2, 0.1}) {
    Rig rig;
    for (int i = 0; i < 3; ++i) {
      Camera c = radtan_camera(k1, k1 < 0 ? 0.25 * k1 * k1 : 0.0, 0, 0, 0);
      c.width = 320, c.height = 240;
      c.fx = c.fy = 260;
      c.cx = 159.5, c.cy = 119.5;
      c.yaw_deg = 35.0 * (i - 1);
      rig.cameras.push_back(c);
    }
    rig.reference = 1;
    rig_compute_rough_homographies(rig);
    std::vector<cv::Mat> frames;
    for (const auto& c : rig.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
    const cv::Mat gt = testdata::plane_ground_truth(photo, rig);
    const cv::Mat with = testdata::compose_cpu(rig, frames);
    Rig ignored = rig;
    for (auto& c : ignored.cameras) c.lens = Lens{};
    const cv::Mat without = testdata::compose_cpu(ignored, frames);
    // Compare where the lens-aware panorama is covered (the inner 90 %, away from the border).
    cv::Mat gray, mask;
    cv::cvtColor(with, gray, cv::COLOR_RGBA2GRAY);
    mask = gray > 0;
    cv::erode(mask, mask, cv::Mat::ones(9, 9, CV_8U));
    const double p_with = testdata::masked_psnr_rgb(with, gt, mask), p_without = testdata::masked_psnr_rgb(without, gt, mask);
    std::printf("radtan k1 %+.2f, 3x 320x240 -> %dx%d plane: PSNR lens on %.2f dB, lens ignored %.2f dB\n", k1,
                with.cols, with.rows, p_with, p_without);
    EXPECT_GT(p_with, 27.0);
    if (k1 < -0.1) {
      EXPECT_GT(p_with, p_without + 3.0);
    }
  }
}

TEST(Lens, OverlapAndOutlinesFollowTheLens) {
  const Rig rig = testdata::fisheye_ring(4, 300, 200);
  EXPECT_TRUE(rig.canvas_wrap);
  EXPECT_EQ(rig.canvas_width, 2 * rig.canvas_height);
  for (int a = 0; a < 4; ++a) {
    float area = 0;
    canvas_overlap(rig, a, (a + 1) % 4, &area);
    EXPECT_GT(area, 0.f) << a;
    // Raw pixel -> canvas -> raw pixel through the lens, beyond 90 degrees too.
    const CameraCanvasMap m = camera_canvas_map(rig, a);
    for (double r : {10.0, 80.0, 140.0}) {
      const Eigen::Vector2d p(rig.cameras[a].cx + r, rig.cameras[a].cy - 0.5 * r);
      Eigen::Vector2d q, back;
      ASSERT_TRUE(m.to_canvas(p, q));
      ASSERT_TRUE(m.to_camera(q, back));
      EXPECT_LT((back - p).norm(), 1e-6);
    }
  }
  // A pinhole rig keeps the pinhole path (the kernels' planar instantiation).
  Rig plain;
  for (int i = 0; i < 2; ++i) {
    Camera c = radtan_camera(0, 0, 0, 0, 0);
    c.lens = Lens{};
    c.yaw_deg = 30.0 * i;
    plain.cameras.push_back(c);
  }
  rig_compute_rough_homographies(plain);
  for (const auto& v : place_views(plain, canvas_geometry(plain))) EXPECT_FALSE(v.has_lens());
}

// Cubemap canvas (issue 15): Spherical Video V2 cbmp layout 0, every face where the layout says,
// rays round-trip, neighbouring faces meet pixel to pixel at all 12 cube edges, and a dual
// fisheye stitched to a cubemap matches the cubemap ground truth of the photo.
TEST(Lens, CubemapFacesRoundTripAndMeetAtTheirEdges) {
  using namespace stitch_projection;
  // The layout: right left up / down front back; up's top towards the front, down's to the back.
  const struct {
    double a, b;
    Eigen::Vector3d ray;
  } spec[] = {{1, 1, {1, 0, 0}},          {3, 1, {-1, 0, 0}},         {5, 1, {0, -1, 0}},
              {1, 3, {0, 1, 0}},          {3, 3, {0, 0, 1}},          {5, 3, {0, 0, -1}},
              {5, 1e-9, {0, -1, 1}},      {1, 2 + 1e-9, {0, 1, -1}},  {4 - 1e-9, 3, {1, 0, 1}},
              {1e-9, 1, {1, 0, 1}},       {2 + 1e-9, 3, {-1, 0, 1}},  {3, 4 - 1e-9, {0, 1, 1}}};
  for (const auto& e : spec) {
    Eigen::Vector3d r;
    angles_to_ray(kCubemap, e.a, e.b, r.x(), r.y(), r.z());
    EXPECT_LT((r.normalized() - e.ray.normalized()).norm(), 1e-6) << e.a << "," << e.b;
  }
  std::mt19937 rng(5);
  std::normal_distribution<double> g(0, 1);
  for (int i = 0; i < 2000; ++i) {
    const Eigen::Vector3d r(g(rng), g(rng), g(rng));
    double a, b;
    ASSERT_TRUE(ray_to_angles(kCubemap, r.x(), r.y(), r.z(), a, b));
    EXPECT_TRUE(a >= 0 && a <= 6 && b >= 0 && b <= 4);
    Eigen::Vector3d back;
    angles_to_ray(kCubemap, a, b, back.x(), back.y(), back.z());
    EXPECT_LT((back.normalized() - r.normalized()).norm(), 1e-12);
  }
  double off_x, off_y, off_z;
  angles_to_ray(kCubemap, 6.1, 1.0, off_x, off_y, off_z);
  EXPECT_EQ(off_x * off_x + off_y * off_y + off_z * off_z, 0.0) << "off the layout: no ray";

  const cv::Mat photo = testdata::test_photo();
  const Rig sphere = testdata::dual_fisheye_rig(240, 200);
  const Rig rig = testdata::reprojected(sphere, "cubemap");
  const int F = rig.canvas_height / 2;
  EXPECT_EQ(rig.canvas_width, 3 * F);
  EXPECT_EQ(F % 2, 0);
  EXPECT_DOUBLE_EQ(rig.canvas_scale, 0.5 * F);
  // crop=auto keeps the whole cubemap; each view's rectangle covers what it sees.
  const Rect crop = largest_covered_rect(rig);
  EXPECT_EQ(crop.width, rig.canvas_width);
  EXPECT_EQ(crop.height, rig.canvas_height);
  const OutputGeometry auto_geom = plan_output(rig, 0, 0, CropMode::Auto);
  EXPECT_EQ(auto_geom.width, rig.canvas_width);
  EXPECT_EQ(auto_geom.height, rig.canvas_height);
  // The JSON keeps it.
  const Rig loaded = rig_from_json_string(rig_to_json_string(rig));
  EXPECT_EQ(loaded.projection, "cubemap");
  EXPECT_DOUBLE_EQ(loaded.canvas_scale, rig.canvas_scale);

  std::vector<cv::Mat> frames;
  for (const auto& c : rig.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
  const cv::Mat cube = testdata::compose_cpu(rig, frames);
  ASSERT_EQ(cube.cols, rig.canvas_width);
  ASSERT_EQ(cube.rows, rig.canvas_height);
  const cv::Mat gt = testdata::cubemap_ground_truth(photo, rig);
  cv::Mat all(cube.size(), CV_8U, cv::Scalar(255));
  const double psnr = testdata::masked_psnr_rgb(cube, gt, all);
  cv::Mat gray, gt_gray;
  cv::cvtColor(cube, gray, cv::COLOR_RGBA2GRAY);
  cv::cvtColor(gt, gt_gray, cv::COLOR_RGBA2GRAY);
  const int black = cv::countNonZero((gray <= 2) & (gt_gray > 10));  // black where the photo is not

  // Every border pixel of every face: one pixel further along its face's plane lands on the
  // neighbouring face, within a pixel of its edge, and the border's consecutive pixels stay one
  // pixel apart there (no jump, no flip). Colours across the edge agree as in the ground truth.
  auto canvas_of = [&](const Eigen::Vector3d& r) {
    double a, b;
    ray_to_angles(kCubemap, r.x(), r.y(), r.z(), a, b);
    return Eigen::Vector2d(rig.canvas_origin_x + rig.canvas_scale * a, rig.canvas_origin_y + rig.canvas_scale * b);
  };
  cv::Mat cube_f, gt_f;
  gray.convertTo(cube_f, CV_32F);
  cv::cvtColor(gt, gt_f, cv::COLOR_RGBA2GRAY);
  gt_f.convertTo(gt_f, CV_32F);
  auto bilinear = [](const cv::Mat& m, const Eigen::Vector2d& p) {
    cv::Mat patch;
    cv::getRectSubPix(m, cv::Size(1, 1), cv::Point2f(float(p.x()), float(p.y())), patch);
    return double(patch.at<float>(0, 0));
  };
  double worst_step = 0, worst_edge = 0, diff_cube = 0, diff_gt = 0;
  int samples = 0;
  for (int face = 0; face < 6; ++face)
    for (int side = 0; side < 4; ++side) {
      Eigen::Vector2d prev(0, 0);
      for (int k = 0; k < F; ++k) {
        // Border pixel (px, py) of the face, and the face coordinates' step across the edge.
        int px = (face % 3) * F, py = (face / 3) * F;
        double ds = 0, dt = 0;
        switch (side) {
          case 0: px += k, ds = 0, dt = -1; break;             // top
          case 1: px += F - 1, py += k, ds = 1, dt = 0; break;  // right
          case 2: px += k, py += F - 1, ds = 0, dt = 1; break;  // bottom
          default: py += k, ds = -1, dt = 0; break;             // left
        }
        const double a = (px - rig.canvas_origin_x) / rig.canvas_scale, b = (py - rig.canvas_origin_y) / rig.canvas_scale;
        const double s = a - 2 * (face % 3) - 1 + ds * 2.0 / F, t = b - 2 * (face / 3) - 1 + dt * 2.0 / F;
        Eigen::Vector3d r;
        cube_face_ray(face, s, t, r.x(), r.y(), r.z());
        const Eigen::Vector2d q = canvas_of(r);
        const int qf = int(std::floor((q.x() + 0.5) / F)) + 3 * int(std::floor((q.y() + 0.5) / F));
        EXPECT_NE(qf, face) << "face " << face << " side " << side;
        const double fx = std::fmod(q.x() + 0.5, F), fy = std::fmod(q.y() + 0.5, F);
        const double to_edge = std::min(std::min(fx, F - fx), std::min(fy, F - fy));
        worst_edge = std::max(worst_edge, to_edge);
        if (k > 0) worst_step = std::max(worst_step, std::abs((q - prev).norm() - 1.0));
        prev = q;
        diff_cube += std::abs(bilinear(cube_f, {double(px), double(py)}) - bilinear(cube_f, q));
        diff_gt += std::abs(bilinear(gt_f, {double(px), double(py)}) - bilinear(gt_f, q));
        ++samples;
      }
    }
  diff_cube /= samples;
  diff_gt /= samples;
  std::printf("cubemap %dx%d (faces %d) from a dual fisheye 200 deg, 2x 240x240: PSNR vs ground truth %.2f dB, "
              "black px %d; face edges: neighbour within %.3f px of its edge, along-edge step error %.3f px, "
              "mean |colour across the edge| %.2f (ground truth %.2f)\n",
              cube.cols, cube.rows, F, psnr, black, worst_edge, worst_step, diff_cube, diff_gt);
  EXPECT_LE(worst_edge, 1.0);
  EXPECT_LE(worst_step, 0.5);
  EXPECT_LT(std::abs(diff_cube - diff_gt), 3.0);
  EXPECT_GT(psnr, 24.0);
  EXPECT_EQ(black, 0) << "the whole cube is covered";
  // Outlines and overlaps on the cubemap: the back-to-back views share the band at 90 degrees.
  float area = 0;
  const auto inter = canvas_overlap(rig, 0, 1, &area);
  EXPECT_GT(area, 0.f);
  EXPECT_EQ(inter.size(), 4u);
  for (int i = 0; i < 2; ++i) {
    const auto outline = camera_canvas_outline(rig, i);
    ASSERT_EQ(outline.size(), 4u);
  }
}

// ---- outputs smaller than the cameras: prefiltered frames ------------------------------------

namespace {

// PSNR over the pixels whose whole footprint (3 output pixels around) every view covers.
double covered_psnr(const cv::Mat& a, const cv::Mat& b, const cv::Mat& full, int div) {
  cv::Mat cov(full.rows, full.cols, CV_8U), mask;
  for (int y = 0; y < full.rows; ++y)
    for (int x = 0; x < full.cols; ++x) {
      const cv::Vec4b p = full.at<cv::Vec4b>(y, x);
      cov.at<uint8_t>(y, x) = p[0] + p[1] + p[2] > 0 ? 255 : 0;
    }
  cv::erode(cov, cov, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(4 * div + 1, 4 * div + 1)));
  cv::resize(cov, mask, a.size(), 0, 0, cv::INTER_AREA);
  return testdata::masked_psnr_rgb(a, b, mask == 255);
}

cv::Mat compose_at_width(const Rig& rig, std::vector<cv::Mat>& frames, int width) {
  Compositor comp(Backend::Cpu);
  CompositorSettings s;
  s.output_width = width;
  comp.prepare(rig, s);
  cv::Mat pano(comp.geometry().height, comp.geometry().width, CV_8UC4);
  std::vector<ImageView> views;
  for (auto& f : frames) views.push_back(as_view(f));
  comp.compose(views, as_view(pano));
  return pano;
}

}  // namespace

// An output a quarter or a sixth of the cameras' size reads each camera every 4-6 pixels: without
// a prefilter fine detail aliases (ring at 1/6: 32.7 dB against the area-averaged truth, trio at
// 1/6: 37.8 dB, measured before the prefilter). The views read frames averaged over 2x2 blocks
// once per halving (prefilter_sparse_views): 38.9 and 46.1 dB. At 1/2 a bilinear read already is
// a 2x2 mean: no level, the same picture.
TEST(Prefilter, SmallOutputsReadAveragedFramesAndDoNotAlias) {
  const cv::Mat photo = testdata::test_photo();
  struct Case {
    const char* name;
    Rig rig;
    int width;  // canvas width: a multiple of 12, so 1/2, 1/4 and 1/6 are whole pixels
    std::vector<std::pair<int, double>> min_psnr;  // output 1/div: at least this many dB
  };
  std::vector<Case> cases;
  cases.push_back({"6 fisheyes, sphere", testdata::fisheye_ring(6, 720, 190), 1416, {{2, 42.0}, {4, 39.0}, {6, 37.0}}});
  Rig trio = testdata::radtan_trio(960, 720, 700, 50, 0, 0, false, "spherical");
  rig_layout_canvas(trio);
  cases.push_back({"pinhole trio, sphere", trio, 2064, {{2, 52.0}, {6, 43.0}}});
  for (Case& cs : cases) {
    shrink_canvas_to_output(cs.rig, cs.width, 0, CropMode::None);
    ASSERT_EQ(cs.rig.canvas_width, cs.width);
    std::vector<cv::Mat> frames;
    for (const auto& c : cs.rig.cameras) frames.push_back(testdata::render_camera_from_equirect(photo, c));
    const cv::Mat truth = testdata::equirect_ground_truth(photo, cs.rig);
    const cv::Mat full = compose_at_width(cs.rig, frames, 0);
    for (const auto& [div, min_db] : cs.min_psnr) {
      const int w = cs.rig.canvas_width / div, h = cs.rig.canvas_height / div;
      std::vector<ViewPlacement> views = place_views(cs.rig, plan_output(cs.rig, w, 0, CropMode::None));
      prefilter_sparse_views(views);
      for (const auto& v : views)
        if (!v.roi.empty()) EXPECT_EQ(v.level, div == 2 ? 0 : div == 4 ? 1 : 2) << cs.name << " 1/" << div;
      const cv::Mat small = compose_at_width(cs.rig, frames, w)(cv::Rect(0, 0, w, h));
      cv::Mat area_truth;
      cv::resize(truth, area_truth, small.size(), 0, 0, cv::INTER_AREA);
      const double psnr = covered_psnr(small, area_truth, full, div);
      std::printf("%s, output 1/%d (%dx%d): %.2f dB against the area-averaged truth\n", cs.name, div, w, h, psnr);
      EXPECT_GE(psnr, min_db) << cs.name << " 1/" << div;
    }
  }
}

TEST(Prefilter, HalvingAveragesEachTwoByTwoBlock) {
  cv::Mat src(3, 5, CV_8UC4);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 5; ++x) src.at<cv::Vec4b>(y, x) = cv::Vec4b(uchar(10 * x + y), uchar(40 * y), 7, 255);
  cv::Mat dst(2, 3, CV_8UC4, cv::Scalar::all(0));
  halve_frame(as_view(src), as_view(dst));
  // (0,0): x 0..1, y 0..1 -> R (0+1+10+11+2)/4 = 6, G (0+0+40+40+2)/4 = 20
  EXPECT_EQ(dst.at<cv::Vec4b>(0, 0), cv::Vec4b(6, 20, 7, 255));
  // the last column and row repeat the edge: (2,1) reads x 4,4 and y 2,2 -> R 42, G 80
  EXPECT_EQ(dst.at<cv::Vec4b>(1, 2), cv::Vec4b(42, 80, 7, 255));
}
