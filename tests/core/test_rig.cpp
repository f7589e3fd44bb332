// Rig JSON I/O and the rough homographies (paper eq. 8-12).
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <fstream>

#include "stitch/rig/rig.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {
constexpr double kPi = 3.14159265358979323846;

Rig two_camera_rig(double yaw1) {
  Rig rig;
  rig.reference = 0;
  for (double yaw : {0.0, yaw1}) {
    Camera c = testdata::pinhole(640, 480, 600);
    c.yaw_deg = yaw;
    rig.cameras.push_back(c);
  }
  return rig;
}
}  // namespace

TEST(RoughHomography, PureYawMatchesRayGeometry) {
  // A camera yawed right by 20 degrees: its principal ray lands at x = cx + f*tan(20 deg) in the
  // reference image, and a pixel at horizontal angle a lands at cx + f*tan(a + 20 deg).
  Rig rig = two_camera_rig(20.0);
  const Eigen::Matrix3d H = rough_pairwise_homography(rig, 1, 0);
  const double f = 600, cx = 319.5, cy = 239.5;
  for (double a_deg : {-15.0, 0.0, 10.0}) {
    const double a = a_deg * kPi / 180;
    const Eigen::Vector2d p(cx + f * std::tan(a), cy);
    const Eigen::Vector2d q = apply_homography(H, p);
    EXPECT_NEAR(q.x(), cx + f * std::tan(a + 20 * kPi / 180), 1e-6);
    EXPECT_NEAR(q.y(), cy, 1e-6);
  }
  // Off-axis point: y scales by 1/cos of the rotated ray's depth.
  const Eigen::Vector2d p(cx, cy + 100);
  const Eigen::Vector2d q = apply_homography(H, p);
  const double c20 = std::cos(20 * kPi / 180);
  EXPECT_NEAR(q.y(), cy + 100 / c20, 1e-6);
}

TEST(RoughHomography, AnalyticFormulaWithPitchRoll) {
  Rig rig = two_camera_rig(-12.0);
  rig.cameras[1].pitch_deg = 5;
  rig.cameras[1].roll_deg = -3;
  rig.cameras[1].fx = 700;
  const Eigen::Matrix3d H = rough_pairwise_homography(rig, 1, 0);
  // H = K0 * R0^T * R1 * K1^-1 (eq. 12 for a rotating rig).
  const Eigen::Matrix3d expect =
      rig.cameras[0].K() * rig.cameras[0].R().transpose() * rig.cameras[1].R() * rig.cameras[1].K().inverse();
  EXPECT_LT((H - expect / expect(2, 2)).norm(), 1e-9);
  // +pitch looks up: the camera's centre pixel lands above the reference centre.
  const Eigen::Vector2d c = apply_homography(H, {rig.cameras[1].cx, rig.cameras[1].cy});
  EXPECT_LT(c.y(), rig.cameras[0].cy);
  EXPECT_LT(c.x(), rig.cameras[0].cx);  // negative yaw looks left
}

TEST(RoughHomography, CanvasCoversAllViews) {
  Rig rig = two_camera_rig(30.0);
  rig_compute_rough_homographies(rig);
  ASSERT_TRUE(rig.calibrated());
  for (const auto& cam : rig.cameras)
    for (const auto& q : camera_canvas_corners(cam)) {
      EXPECT_GE(q.x(), -1e-6);
      EXPECT_GE(q.y(), -1e-6);
      EXPECT_LE(q.x(), rig.canvas_width);
      EXPECT_LE(q.y(), rig.canvas_height);
    }
  EXPECT_GT(rig.canvas_width, 640);
}

TEST(RoughHomography, GrazingViewIsRejectedAsDegenerate) {
  Rig rig = two_camera_rig(95.0);  // looks away from the reference plane
  EXPECT_THROW(rig_compute_rough_homographies(rig), RigError);
}

TEST(RigJson, SaveLoadIsLossless) {
  Rig rig = two_camera_rig(23.456789012345);
  rig.cameras[1].t = Eigen::Vector3d(0.1, -0.02, 0.003);
  rig.cameras[0].roll_deg = 0.123456789;
  rig_compute_rough_homographies(rig);
  const std::string path = testdata::temp_dir() + "/rig.json";
  rig_save(rig, path);
  Rig back = rig_load(path);
  ASSERT_EQ(back.cameras.size(), rig.cameras.size());
  EXPECT_EQ(back.reference, rig.reference);
  EXPECT_EQ(back.canvas_width, rig.canvas_width);
  EXPECT_EQ(back.canvas_height, rig.canvas_height);
  for (std::size_t i = 0; i < rig.cameras.size(); ++i) {
    const Camera &a = rig.cameras[i], &b = back.cameras[i];
    EXPECT_EQ(a.fx, b.fx);
    EXPECT_EQ(a.cy, b.cy);
    EXPECT_EQ(a.yaw_deg, b.yaw_deg);
    EXPECT_EQ(a.roll_deg, b.roll_deg);
    EXPECT_EQ(bool(a.t), bool(b.t));
    if (a.t) EXPECT_EQ(*a.t, *b.t);
    ASSERT_TRUE(b.homography);
    EXPECT_EQ(*a.homography, *b.homography);  // bit-exact
  }
  // Saving the loaded rig gives the same text.
  EXPECT_EQ(rig_to_json_string(rig), rig_to_json_string(back));
}

TEST(RigJson, DesignExampleLoads) {
  const char* text = R"({ "format": "stitch-rig", "version": 1, "projection": "plane", "reference": 1,
    "cameras": [ {"width": 640, "height": 480, "fx": 600.0, "fy": 600.0, "cx": 320.0, "cy": 240.0, "yaw_deg": -30.0},
                 {"width": 640, "height": 480, "fx": 600.0, "fy": 600.0, "cx": 320.0, "cy": 240.0, "yaw_deg": 0.0},
                 {"width": 640, "height": 480, "fx": 600.0, "fy": 600.0, "cx": 320.0, "cy": 240.0, "yaw_deg": 30.0, "t": [0,0,0]} ] })";
  Rig rig = rig_from_json_string(text);
  EXPECT_EQ(rig.cameras.size(), 3u);
  EXPECT_EQ(rig.reference, 1);
  EXPECT_FALSE(rig.calibrated());
}

static std::string error_of(const std::string& text) {
  try {
    rig_from_json_string(text);
  } catch (const RigError& e) {
    return e.what();
  }
  return "";
}

TEST(RigJson, MalformedInputGivesClearErrors) {
  EXPECT_NE(error_of("{ \"cameras\": [").find("malformed JSON"), std::string::npos);
  EXPECT_NE(error_of("[]").find("object"), std::string::npos);
  EXPECT_NE(error_of("{}").find("cameras"), std::string::npos);
  EXPECT_NE(error_of(R"({"cameras":[{"width":640,"height":480}]})").find("camera 0: missing \"fx\""),
            std::string::npos);
  EXPECT_NE(error_of(R"({"cameras":[{"width":-5,"height":480,"fx":1}]})").find("width"), std::string::npos);
  EXPECT_NE(error_of(R"({"cameras":[{"width":64,"height":48,"fx":"big"}]})").find("fx"), std::string::npos);
  EXPECT_NE(error_of(R"({"format":"other","cameras":[{"width":64,"height":48,"fx":1}]})").find("format"),
            std::string::npos);
  EXPECT_NE(error_of(R"({"reference":5,"cameras":[{"width":64,"height":48,"fx":1}]})").find("reference"),
            std::string::npos);
  EXPECT_NE(error_of(R"({"projection":"fisheye-dome","cameras":[{"width":64,"height":48,"fx":1}]})")
                .find("not supported"),
            std::string::npos);
  // Degenerate homographies: NaN, singular, mirrored.
  const std::string cam = R"({"cameras":[{"width":64,"height":48,"fx":50,"homography":)";
  EXPECT_NE(error_of(cam + "[1,0,0,0,1,0,0,0,0]}]}").find("degenerate"), std::string::npos);
  EXPECT_NE(error_of(cam + "[0,0,0,0,0,0,0,0,1]}]}").find("singular"), std::string::npos);
  EXPECT_NE(error_of(cam + "[-1,0,0,0,1,0,0,0,1]}]}").find("mirrored"), std::string::npos);
  EXPECT_NE(error_of(cam + "[1,0,0,0,1]}]}").find("9 numbers"), std::string::npos);
  EXPECT_THROW(rig_load("/nonexistent/rig.json"), RigError);
}

// Hostile and truncated files (issue 7; the first was found by tests/fuzz/fuzz_rig.cpp): a
// RigError that says why, never another exception, a crash or a hang.
TEST(RigJson, HostileInputGivesClearErrors) {
  // a number beyond double (nlohmann throws out_of_range, not parse_error)
  EXPECT_NE(error_of("777777777777E777777").find("malformed JSON"), std::string::npos);
  EXPECT_NE(error_of(R"({"cameras":[{"width":64,"height":48,"fx":1e999}]})").find("malformed JSON"),
            std::string::npos);
  // deep nesting, truncation, binary junk, an empty file
  EXPECT_NE(error_of(std::string(100000, '[')).find("malformed JSON"), std::string::npos);
  EXPECT_NE(error_of(R"({"cameras":[{"width":640,"height":4)").find("malformed JSON"), std::string::npos);
  EXPECT_NE(error_of(std::string("\xff\xfe\x00\x01", 4)).find("malformed JSON"), std::string::npos);
  EXPECT_NE(error_of("").find("malformed JSON"), std::string::npos);
  // absurd sizes are refused by name, not allocated
  EXPECT_NE(error_of(R"({"cameras":[{"width":2000000000,"height":48,"fx":1}]})").find("width"), std::string::npos);
}

TEST(RigAdapt, ScalingToStreamSizeKeepsGeometry) {
  Rig rig = two_camera_rig(25.0);
  rig_compute_rough_homographies(rig);
  Rig half = rig;
  ASSERT_TRUE(rig_adapt_to_sizes(half, {{{320, 240}}, {{320, 240}}}));
  // The centre of a half-size frame lands where the full-size centre did.
  const Eigen::Vector2d a = apply_homography(*rig.cameras[1].homography, {319.5, 239.5});
  const Eigen::Vector2d b = apply_homography(*half.cameras[1].homography, {159.5, 119.5});
  EXPECT_LT((a - b).norm(), 1e-6);
  EXPECT_NEAR(half.cameras[1].fx, 300, 1e-9);
}

// A field the loader does not know is ignored, but named (probe2: a hand-written rig with
// `"yaw": 15` instead of "yaw_deg" loaded silently with the camera looking straight ahead).
TEST(RigJson, UnknownFieldsAreNamedWithTheLikelyOne) {
  const char* text = R"({ "format": "stitch-rig", "version": 1, "refrence": 1, "canvas_size": 3,
    "cameras": [ {"width": 640, "height": 480, "fx": 600.0, "yaw_deg": -30.0},
                 {"width": 640, "height": 480, "fx": 600.0, "yaw": 30.0, "comment": "left door"} ] })";
  const Rig rig = rig_from_json_string(text);
  EXPECT_EQ(rig.cameras[1].yaw_deg, 0.0);  // ignored, as before
  std::string all;
  for (const auto& f : rig.unknown_fields) all += f + "\n";
  ASSERT_EQ(rig.unknown_fields.size(), 4u) << all;
  EXPECT_NE(all.find("camera 1: \"yaw\" (did you mean \"yaw_deg\"?)"), std::string::npos) << all;
  EXPECT_NE(all.find("\"refrence\" (did you mean \"reference\"?)"), std::string::npos) << all;
  EXPECT_NE(all.find("camera 1: \"comment\"\n"), std::string::npos) << all;
  EXPECT_NE(all.find("\"canvas_size\" (did you mean \"canvas\"?)"), std::string::npos) << all;
  // What rig_save writes is all known.
  Rig full = two_camera_rig(10);
  full.cameras[0].t = Eigen::Vector3d(0.1, 0, 0);
  full.cameras[1].time_offset_ns = 5;
  rig_compute_rough_homographies(full);
  EXPECT_TRUE(rig_from_json_string(rig_to_json_string(full)).unknown_fields.empty());
}
