// The calibration policy (calib_session): frame quality, when it calibrates, what it accepts,
// how long it keeps trying, what it says, and canvases that equal the panorama.
#include <cstdio>
#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <thread>
#include <map>

#include <opencv2/imgproc.hpp>

#include "stitch/calib/calib_session.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"
#include "stitch/rig/overlap.hpp"
#include "stitch/warp/geometry.hpp"
#include "lens_rig.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

const cv::Mat& photo() {
  static cv::Mat p = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  return p;
}

// n crops 640x480 of the photo, `shift` px apart (the true geometry is a pure shift).
std::vector<cv::Mat> crops(int n = 2, int shift = 400) {
  std::vector<cv::Mat> v;
  for (int i = 0; i < n; ++i) v.push_back(photo()(cv::Rect(shift * i, 200, 640, 480)).clone());
  return v;
}

ImageView view_of(cv::Mat m) { return as_view(m); }  // a header sharing the pixels

std::vector<ImageView> views_of(const std::vector<cv::Mat>& m) {
  std::vector<ImageView> v;
  for (const auto& x : m) v.push_back(view_of(x));
  return v;
}

cv::Mat black() { return cv::Mat(480, 640, CV_8UC4, cv::Scalar(2, 2, 2, 255)); }

// Feeds frame f (time f/30 s) and runs any job synchronously. Returns the events.
std::vector<SessionEvent> feed(CalibSession& s, int f, const std::vector<cv::Mat>& frames, int* jobs = nullptr) {
  CalibSession::Frame fr;
  fr.time_s = f / 30.0;
  for (const auto& m : frames) fr.sizes.push_back({m.cols, m.rows});
  const auto views = views_of(frames);
  auto job = s.on_frame(fr, s.wants_pixels(fr) ? views : std::vector<ImageView>());
  if (job) {
    if (jobs) ++*jobs;
    std::atomic<bool> cancel{false};
    s.on_outcome(run_calib_job(*job, cancel));
  }
  if (s.current()) {
    s.bundle_passed();
  } else {
    s.bundle_dropped();
  }
  return s.take_events();
}

int count(const std::vector<SessionEvent>& e, SessionEvent::Type t) {
  int n = 0;
  for (const auto& x : e) n += x.type == t;
  return n;
}

const SessionEvent* find(const std::vector<SessionEvent>& e, SessionEvent::Type t) {
  for (const auto& x : e)
    if (x.type == t) return &x;
  return nullptr;
}

// Two pooled frame sets over 0.3 s after the first calibration.
SessionConfig pooling() {
  SessionConfig c;
  c.calibration_frames = 2;
  c.calibration_window_s = 0.3;
  return c;
}

// Feeds frames 1, 2, ... (no job run) until the session hands out a job; null after 30.
std::shared_ptr<CalibJob> next_job(CalibSession& s, const std::vector<cv::Mat>& frames) {
  CalibSession::Frame fr;
  for (const auto& m : frames) fr.sizes.push_back({m.cols, m.rows});
  for (int f = 1; f < 30; ++f) {
    fr.time_s = f / 30.0;
    auto job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(frames) : std::vector<ImageView>());
    s.bundle_passed();
    if (job) return job;
  }
  return nullptr;
}

SessionConfig quick() {
  SessionConfig c;
  c.calibration_frames = 1;  // no pooled refinement unless a test asks
  return c;
}

// quick(), loading a calibration of `cameras` crops 400 px apart, saved as `name`.
SessionConfig loading(const std::string& name, int cameras) {
  const std::string path = testdata::temp_dir() + "/" + name;
  rig_save(testdata::shifted_rig(cameras, 640, 480, 400), path);
  SessionConfig c = quick();
  c.load_file = path;
  return c;
}

}  // namespace

// ---- frame quality ---------------------------------------------------------------------------

TEST(FrameQuality, GoodDarkFlatBlurredAndTorn) {
  const cv::Mat good = crops(1)[0];
  EXPECT_EQ(assess_frame(view_of(good)).verdict, FrameVerdict::Good) << assess_frame(view_of(good)).describe();
  EXPECT_EQ(assess_frame(view_of(black())).verdict, FrameVerdict::Dark);
  const cv::Mat flat(480, 640, CV_8UC4, cv::Scalar(90, 90, 90, 255));
  EXPECT_EQ(assess_frame(view_of(flat)).verdict, FrameVerdict::Featureless);
  cv::Mat blurred;
  cv::GaussianBlur(good, blurred, cv::Size(0, 0), 9);
  EXPECT_EQ(assess_frame(view_of(blurred)).verdict, FrameVerdict::Blurred) << assess_frame(view_of(blurred)).describe();
  // A broken keyframe: the top of one picture over the bottom of another.
  cv::Mat torn = good.clone();
  photo()(cv::Rect(900, 700, 640, 272)).copyTo(torn(cv::Rect(0, 208, 640, 272)));
  const FrameQuality q = assess_frame(view_of(torn));
  EXPECT_EQ(q.verdict, FrameVerdict::Corrupt) << q.describe();
  // A strong horizontal edge of the scene (a shelf's shadow; studs seen by a camera on its side),
  // which the lens spreads over two rows, away from a coded block's boundary: content, not a
  // tear (probe4's rolled camera lost its first 3 s to it). The same edge glued without blur on
  // a block boundary is a tear.
  for (const int row : {203, 205, 211}) {
    cv::Mat shelf = good.clone();
    shelf.rowRange(row, shelf.rows) *= 0.3;
    shelf.row(row - 1) = 0.5 * good.row(row - 1) + 0.5 * shelf.row(row);
    shelf.col(0).setTo(cv::Scalar::all(255));  // alpha stays opaque after the scaling
    cv::Mat alpha;
    cv::extractChannel(good, alpha, 3);
    cv::insertChannel(alpha, shelf, 3);
    const FrameQuality natural = assess_frame(view_of(shelf));
    EXPECT_NE(natural.verdict, FrameVerdict::Corrupt) << row << ": " << natural.describe();
    EXPECT_GT(natural.tear, 0) << "the edge is not even a candidate: the test tests nothing";
  }
  // Every crop of the real photo passes (no false alarms on natural horizontal edges).
  for (int y = 0; y + 480 <= photo().rows; y += 100) {
    for (int x = 0; x + 640 <= photo().cols; x += 160) {
      const FrameQuality g = assess_frame(view_of(photo()(cv::Rect(x, y, 640, 480)).clone()));
      EXPECT_NE(g.verdict, FrameVerdict::Corrupt) << x << "," << y << ": " << g.describe();
    }
  }
}

// ---- canvas helpers --------------------------------------------------------------------------

TEST(CanvasHelpers, OddCanvasIsPaddedAndFitKeepsTheMappingInside) {
  Rig rig = testdata::shifted_rig(2, 640, 480, 401);
  rig.canvas_height = 481;
  ASSERT_EQ(rig.canvas_width, 1041);
  const Eigen::Matrix3d h1 = *rig.cameras[1].homography;
  EXPECT_TRUE(make_canvas_even(rig));
  EXPECT_EQ(rig.canvas_width, 1042);
  EXPECT_EQ(rig.canvas_height, 482);
  EXPECT_TRUE(rig.cameras[1].homography->isApprox(h1));  // padded, not moved
  // A recalibrated canvas fitted into the panorama it replaces: every corner lands inside.
  fit_canvas(rig, 800, 600);
  EXPECT_EQ(rig.canvas_width, 800);
  EXPECT_EQ(rig.canvas_height, 600);
  for (int c = 0; c < 2; ++c)
    for (const auto& p : camera_canvas_corners(rig.cameras[std::size_t(c)])) {
      EXPECT_GE(p.x(), -0.5);
      EXPECT_LE(p.x(), 799.5);
      EXPECT_GE(p.y(), -0.5);
      EXPECT_LE(p.y(), 599.5);
    }
}

// The panorama downstream shows the canvas smaller: the canvas is scaled to it, so the stages
// work at the output's size. Planar with a crop, 360 (which must keep closing), never enlarged.
TEST(CanvasHelpers, CanvasShrunkToTheOutputItIsShownAt) {
  Rig rig = testdata::shifted_rig(2, 640, 480, 400);
  make_canvas_even(rig);
  const int w0 = rig.canvas_width, h0 = rig.canvas_height;
  Rig same = rig;
  EXPECT_EQ(shrink_canvas_to_output(same, 0, 0, CropMode::None), 1.0);
  EXPECT_EQ(shrink_canvas_to_output(same, 2 * w0, 0, CropMode::None), 1.0) << "never enlarged";
  EXPECT_EQ(same.canvas_width, w0);
  for (CropMode crop : {CropMode::None, CropMode::Auto}) {
    Rig r = rig;
    const OutputGeometry before = plan_output(r, 400, 0, crop);
    const double s = shrink_canvas_to_output(r, 400, 0, crop);
    EXPECT_LT(s, 0.7);
    EXPECT_EQ(r.canvas_width % 2, 0);
    EXPECT_EQ(r.canvas_height % 2, 0);
    EXPECT_NEAR(r.canvas_height, h0 * s, 2.0);
    // The same output, now 1:1 (to a pixel's rounding) with the canvas.
    const OutputGeometry after = plan_output(r, 400, 0, crop);
    EXPECT_EQ(after.width, before.width);
    EXPECT_NEAR(after.height, before.height, 2);
    EXPECT_NEAR(after.canvas_to_output(0, 0), 1.0, 0.01);
    // Each camera lands where it did, in output pixels.
    for (std::size_t c = 0; c < 2; ++c) {
      const auto p0 = camera_canvas_corners(rig.cameras[c]), p1 = camera_canvas_corners(r.cameras[c]);
      for (std::size_t k = 0; k < p0.size(); ++k) {
        const Eigen::Vector3d o0 = before.canvas_to_output * Eigen::Vector3d(p0[k].x(), p0[k].y(), 1);
        const Eigen::Vector3d o1 = after.canvas_to_output * Eigen::Vector3d(p1[k].x(), p1[k].y(), 1);
        EXPECT_NEAR(o0.x(), o1.x(), 2.0);
        EXPECT_NEAR(o0.y(), o1.y(), 2.0);
      }
    }
  }
  // A full sphere shown at half size: half the canvas, still closing at the wrap, still 2:1.
  Rig sphere = testdata::dual_fisheye_rig(240, 200);
  ASSERT_TRUE(sphere.canvas_wrap);
  const int sw = sphere.canvas_width, half = (sw / 2 + 3) / 4 * 4;  // 2:1 with even sides: width a multiple of 4
  EXPECT_NEAR(shrink_canvas_to_output(sphere, sw / 2, sw / 4, CropMode::None), double(half) / sw, 1e-9);
  EXPECT_EQ(sphere.canvas_width, half);
  EXPECT_EQ(sphere.canvas_height, half / 2);
  EXPECT_TRUE(sphere.canvas_wrap);
  // Any output size: still exactly 2:1 with both sides even (a 360 player reads the latitude
  // from the height; an odd height would be padded by a row).
  for (int out_w : {1000, 998, 642, 333}) {
    Rig r = testdata::dual_fisheye_rig(240, 200);
    shrink_canvas_to_output(r, out_w, 0, CropMode::None);
    EXPECT_EQ(r.canvas_width, 2 * r.canvas_height) << out_w;
    EXPECT_EQ(r.canvas_height % 2, 0) << out_w;
  }
}

// A full sphere's canvas is laid out 2:1 with both sides even, whatever the lens and focal
// length (fisheyes of 190-220 degrees gave 1210x605 and 1094x547 before: an odd height).
TEST(CanvasHelpers, FullSphereIsTwoToOneWithEvenSides) {
  for (int side : {240, 250, 256, 300, 333, 640})
    for (double fov : {190.0, 200.0, 210.0, 220.0}) {
      const Rig rig = testdata::dual_fisheye_rig(side, fov);
      ASSERT_TRUE(rig.canvas_wrap);
      EXPECT_EQ(rig.canvas_width, 2 * rig.canvas_height) << side << " " << fov;
      EXPECT_EQ(rig.canvas_height % 2, 0) << side << " " << fov;
    }
}

// ---- the session -----------------------------------------------------------------------------

TEST(CalibSession, CalibratesOnTheFirstGoodBundleAndReportsResiduals) {
  CalibSession s;
  s.set_config(quick());
  int jobs = 0;
  const auto e = feed(s, 0, crops(3), &jobs);
  ASSERT_TRUE(s.current()) << (e.empty() ? "" : e[0].text);
  EXPECT_EQ(jobs, 1);
  const SessionEvent* in = find(e, SessionEvent::Type::Installed);
  ASSERT_NE(in, nullptr);
  EXPECT_EQ(in->report.source, "images");
  ASSERT_EQ(in->report.residuals.camera_px.size(), 3u);
  for (double px : in->report.residuals.camera_px) {
    EXPECT_GE(px, 0);
    EXPECT_LT(px, 1.5);
  }
  EXPECT_GT(in->report.residuals.rms_px, 0);  // a real number, not 0
  EXPECT_EQ(s.current()->canvas_width % 2, 0);
  EXPECT_EQ(s.current()->canvas_height % 2, 0);
}

// A camera dark for its first 5 s, with leaving out turned off: no attempt on those frames,
// rate-limited pending messages naming the right camera, rate-limited QoS, then a calibration.
// Not fatal.
TEST(CalibSession, DarkCameraForFiveSecondsIsNotFatal) {
  CalibSession s;
  SessionConfig c = quick();
  c.leave_out_after_s = 0;
  s.set_config(c);
  auto good = crops(3);
  auto dark = good;
  dark[1] = black();
  int jobs = 0, pending = 0, qos = 0;
  for (int f = 0; f < 150; ++f) {
    const auto e = feed(s, f, dark, &jobs);
    pending += count(e, SessionEvent::Type::Pending);
    qos += count(e, SessionEvent::Type::Qos);
    ASSERT_EQ(count(e, SessionEvent::Type::Error), 0) << "frame " << f;
    if (const SessionEvent* p = find(e, SessionEvent::Type::Pending)) {
      EXPECT_NE(p->text.find("camera 1 is dark"), std::string::npos) << p->text;
    }
  }
  EXPECT_EQ(jobs, 0);
  EXPECT_GE(pending, 4);
  EXPECT_LE(pending, 6);
  EXPECT_LE(qos, 6);
  const auto e = feed(s, 150, good, &jobs);
  EXPECT_TRUE(s.current());
  // The drops are summed up in one QoS message before the first bundle passes.
  const SessionEvent* q = find(e, SessionEvent::Type::Qos);
  ASSERT_NE(q, nullptr);
  EXPECT_EQ(q->dropped, 150u);
}

// The default: a camera dark for 4 s of running time is left out, the other two are calibrated
// and stitched (its view is on no canvas), and it joins with a calibration from scratch once it
// shows a picture. Both steps are announced, naming the camera.
TEST(CalibSession, DarkCameraIsLeftOutAndJoinsWhenItShowsAPicture) {
  CalibSession s;
  s.set_config(quick());
  const auto good = crops(3);
  auto dark = good;
  dark[2] = black();
  std::vector<SessionEvent> events;
  int f = 0;
  for (; f < 200 && !s.current(); ++f)
    for (auto& e : feed(s, f, dark)) events.push_back(e);
  ASSERT_TRUE(s.current()) << "the two cameras with a picture were never stitched";
  EXPECT_NEAR(f / 30.0, SessionConfig().leave_out_after_s, 0.2);
  EXPECT_EQ(count(events, SessionEvent::Type::Error), 0);
  const Rig& rig = *s.current();
  ASSERT_EQ(rig.cameras.size(), 3u);
  EXPECT_TRUE(rig.cameras[2].left_out);
  EXPECT_FALSE(rig.cameras[0].left_out);
  EXPECT_FALSE(rig.cameras[1].left_out);
  EXPECT_TRUE(camera_canvas_outline(rig, 2).empty());
  EXPECT_FALSE(camera_canvas_outline(rig, 1).empty());
  bool named = false;
  for (const auto& e : events)
    if (e.type == SessionEvent::Type::Warning && e.text.find("camera 2 delivered no picture") != std::string::npos)
      named = true;
  EXPECT_TRUE(named);
  EXPECT_THROW(rig_to_json_string(rig), RigError) << "a rig without a camera is never saved as if whole";
  // Still dark: nothing changes. Then it shows a picture: calibrated again, with all three.
  const auto version = s.version();
  for (int k = 0; k < 30; ++k, ++f) feed(s, f, dark);
  EXPECT_EQ(s.version(), version);
  events.clear();
  // The calibration with it runs in the background: every frame meanwhile has the two-camera
  // calibration (before, none: the output stopped for the whole calibration, ~7 s on the house).
  int without_calibration = 0;
  for (int k = 0; k < 60 && (!s.current() || any_left_out(*s.current())); ++k, ++f) {
    for (auto& e : feed(s, f, good)) events.push_back(e);
    without_calibration += !s.current();
  }
  EXPECT_EQ(without_calibration, 0);
  ASSERT_TRUE(s.current());
  EXPECT_FALSE(any_left_out(*s.current()));
  EXPECT_FALSE(camera_canvas_outline(*s.current(), 2).empty());
  const SessionEvent* w = find(events, SessionEvent::Type::Warning);
  ASSERT_NE(w, nullptr);
  EXPECT_NE(w->text.find("camera 2 delivers a picture now"), std::string::npos) << w->text;
}

// probe3: a camera that shows a flat white (or grey, or blown-out) picture is as useless to a
// calibration from the images as a dark one: it is left out the same way, and stays out while
// it shows nothing. Before, two good phone clips and a white camera gave no panorama at all
// ("Could not calibrate before the stream ended ... camera 2 is featureless").
TEST(CalibSession, FeaturelessCameraIsLeftOutLikeADarkOne) {
  for (const double level : {255.0, 128.0}) {
    CalibSession s;
    s.set_config(quick());
    auto frames = crops(3);
    frames[2] = cv::Mat(480, 640, CV_8UC4, cv::Scalar(level, level, level, 255));
    std::vector<SessionEvent> events;
    int f = 0;
    for (; f < 200 && !s.current(); ++f)
      for (auto& e : feed(s, f, frames)) events.push_back(e);
    ASSERT_TRUE(s.current()) << "level " << level << ": the two cameras with a picture were never stitched";
    EXPECT_NEAR(f / 30.0, SessionConfig().leave_out_after_s, 0.2);
    EXPECT_EQ(count(events, SessionEvent::Type::Error), 0);
    EXPECT_TRUE(s.current()->cameras[2].left_out);
    EXPECT_FALSE(s.current()->cameras[0].left_out);
    // still flat: no calibration from scratch every half second
    const auto version = s.version();
    for (int k = 0; k < 30; ++k, ++f) feed(s, f, frames);
    EXPECT_EQ(s.version(), version);
  }
}

// A camera that never delivers a frame (stitchsync marks it missing, at a placeholder size) is
// left out the same way; when it starts at its real size, the calibration is made again with it,
// not reported as a resolution change.
TEST(CalibSession, CameraThatNeverDeliversIsLeftOutAndJoinsWhenItStarts) {
  CalibSession s;
  s.set_config(quick());
  const auto frames = crops(3);
  CalibSession::Frame fr;
  fr.sizes = {{640, 480}, {640, 480}, {320, 240}};
  fr.missing_mask = 1u << 2;
  std::vector<SessionEvent> events;
  const cv::Mat placeholder(240, 320, CV_8UC4, cv::Scalar(0, 0, 0, 255));
  const std::vector<cv::Mat> with_placeholder = {frames[0], frames[1], placeholder};
  auto step = [&](int f, const std::vector<cv::Mat>& m) {
    fr.time_s = f / 30.0;
    auto job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(m) : std::vector<ImageView>());
    if (job) {
      std::atomic<bool> cancel{false};
      s.on_outcome(run_calib_job(*job, cancel));
    }
    for (auto& e : s.take_events()) events.push_back(e);
  };
  int f = 0;
  for (; f < 200 && !s.current(); ++f) step(f, with_placeholder);
  ASSERT_TRUE(s.current()) << "never stitched without the dead camera";
  EXPECT_NEAR(f / 30.0, SessionConfig().leave_out_after_s, 0.2);
  EXPECT_TRUE(s.current()->cameras[2].left_out);
  EXPECT_FALSE(s.current()->cameras[1].left_out);
  EXPECT_EQ(count(events, SessionEvent::Type::Error), 0);
  // The two calibrated cameras are 400 px apart, as rendered.
  const Rig& rig = *s.current();
  const auto c0 = camera_canvas_corners(rig.cameras[0]), c1 = camera_canvas_corners(rig.cameras[1]);
  EXPECT_NEAR(c1[0].x() - c0[0].x(), 400, 3);
  events.clear();
  fr.sizes[2] = {640, 480};
  fr.missing_mask = 0;
  for (int k = 0; k < 30 && (!s.current() || any_left_out(*s.current())); ++k, ++f) step(f, frames);
  ASSERT_TRUE(s.current());
  EXPECT_FALSE(any_left_out(*s.current()));
  for (const auto& e : events) EXPECT_EQ(e.text.find("resolution changed"), std::string::npos) << e.text;
  const SessionEvent* w = find(events, SessionEvent::Type::Warning);
  ASSERT_NE(w, nullptr);
  EXPECT_NE(w->text.find("camera 2 delivers a picture now"), std::string::npos) << w->text;
}

// A left-out camera is on no canvas, whatever the projection: no outline, no overlap with any
// camera (colour samples none), no view rectangle (the flow warp and the blend skip it). On a
// sphere with lenses the overlap came from a convex hull of the empty outline, which OpenCV
// rejects: stitchcolor stopped with an error on the first panorama of a real clip.
TEST(CalibSession, LeftOutCameraIsOnNoCanvas) {
  Rig plane = testdata::shifted_rig(3, 640, 480, 400);
  Rig sphere = testdata::dual_fisheye_rig(240, 200);
  for (Rig* rig : {&plane, &sphere}) {
    rig->cameras[1].left_out = true;
    EXPECT_TRUE(any_left_out(*rig));
    EXPECT_TRUE(camera_canvas_outline(*rig, 1).empty());
    for (int other = 0; other < int(rig->cameras.size()); ++other) {
      if (other == 1) continue;
      float area = -1;
      EXPECT_NO_THROW(EXPECT_TRUE(canvas_overlap(*rig, 1, other, &area).empty()));
      EXPECT_EQ(area, 0.f);
      EXPECT_NO_THROW(EXPECT_TRUE(canvas_overlap(*rig, other, 1, &area).empty()));
    }
    const OutputGeometry out = plan_output(*rig, 0, 0, CropMode::None);
    const std::vector<ViewPlacement> views = place_views(*rig, out);
    ASSERT_EQ(views.size(), rig->cameras.size());
    EXPECT_EQ(views[1].roi.width * views[1].roi.height, 0);
    EXPECT_GT(views[0].roi.width * views[0].roi.height, 0);
  }
}

// A camera added while playing (a pad requested in PLAYING) changes the bundle's view count:
// said as such, not as a resolution change, and not an error, even with on-resize=error (which
// still stops on a camera that leaves).
TEST(CalibSession, CameraAddedMidStreamIsCalibratedInNotAResolutionChange) {
  SessionConfig c = quick();
  c.resize_is_error = true;
  CalibSession s;
  s.set_config(c);
  const auto three = crops(3);
  const std::vector<cv::Mat> two = {three[0], three[1]};
  feed(s, 0, two);
  ASSERT_TRUE(s.current());
  ASSERT_EQ(s.current()->cameras.size(), 2u);
  std::vector<SessionEvent> events;
  for (int f = 1; f < 10 && s.current()->cameras.size() != 3; ++f)
    for (auto& e : feed(s, f, three)) events.push_back(e);
  EXPECT_EQ(count(events, SessionEvent::Type::Error), 0);
  ASSERT_TRUE(s.current());
  EXPECT_EQ(s.current()->cameras.size(), 3u);
  const SessionEvent* w = find(events, SessionEvent::Type::Warning);
  ASSERT_NE(w, nullptr);
  EXPECT_NE(w->text.find("number of cameras changed mid-stream (2 -> 3)"), std::string::npos) << w->text;
  EXPECT_EQ(w->text.find("resolution"), std::string::npos) << w->text;
  std::string error;
  for (int f = 20; f < 30 && error.empty(); ++f)
    for (auto& e : feed(s, f, two))
      if (e.type == SessionEvent::Type::Error) error = e.text;
  EXPECT_NE(error.find("number of cameras changed mid-stream (3 -> 2) and on-resize=error"), std::string::npos) << error;
}

// A dark middle camera leaves two cameras that share nothing: the failure names them by their
// own indices (the calibration of the kept ones numbers them 0 and 1) and says who is left out.
TEST(CalibSession, FailureWithoutALeftOutCameraNamesTheCamerasByTheirIndices) {
  CalibSession s;
  s.set_config(quick());
  auto frames = crops(3);
  frames[1] = black();
  std::string pending;
  for (int f = 0; f < 160 && !s.current(); ++f)
    for (const auto& e : feed(s, f, frames))
      if (e.type == SessionEvent::Type::Pending && e.text.find("attempt failed") != std::string::npos) pending = e.text;
  EXPECT_FALSE(s.current());
  EXPECT_NE(pending.find("camera 1 left out"), std::string::npos) << pending;
  EXPECT_EQ(pending.find("camera 1 shares"), std::string::npos) << pending;
}

// Two cameras, one dark: leaving it out would leave one camera, no panorama. The session waits,
// and says why it does not leave it out; several cameras that hold it up read as a plural.
TEST(CalibSession, SaysWhyADarkCameraOfTwoIsNotLeftOut) {
  CalibSession s;
  s.set_config(quick());
  const std::vector<cv::Mat> frames = {crops(1)[0], black()};
  std::string last;
  for (int f = 0; f < 180; ++f)
    for (const auto& e : feed(s, f, frames))
      if (e.type == SessionEvent::Type::Pending) last = e.text;
  EXPECT_FALSE(s.current());
  EXPECT_NE(last.find("camera 1 is dark"), std::string::npos) << last;
  EXPECT_NE(last.find("not left out: two cameras at least must deliver a picture"), std::string::npos) << last;

  CalibSession three;
  three.set_config(quick());
  CalibSession::Frame fr;
  fr.sizes = {{640, 480}, {320, 240}, {320, 240}};
  fr.missing_mask = 0b110;
  three.on_frame(fr, {});
  const auto events = three.take_events();
  const SessionEvent* p = find(events, SessionEvent::Type::Pending);
  ASSERT_NE(p, nullptr);
  EXPECT_NE(p->text.find("cameras 1, 2 have not delivered a frame yet"), std::string::npos) << p->text;
}

TEST(CalibSession, GivesUpAfterTheTimeoutNamingTheCamera) {
  SessionConfig c = quick();
  c.calibration_timeout_s = 2;
  CalibSession s;
  s.set_config(c);
  auto frames = crops(3);
  frames[2] = black();
  std::string error;
  for (int f = 0; f < 90 && error.empty(); ++f)
    for (const auto& e : feed(s, f, frames))
      if (e.type == SessionEvent::Type::Error) error = e.text;
  EXPECT_NE(error.find("calibration-timeout"), std::string::npos) << error;
  EXPECT_NE(error.find("camera 2 is dark"), std::string::npos) << error;
}

TEST(CalibSession, StreamEndingUncalibratedIsAnError) {
  CalibSession s;
  s.set_config(quick());
  auto frames = crops(2);
  frames[0] = cv::Mat(480, 640, CV_8UC4, cv::Scalar(90, 90, 90, 255));
  for (int f = 0; f < 5; ++f) feed(s, f, frames);
  s.on_eos();
  const auto e = s.take_events();
  const SessionEvent* err = find(e, SessionEvent::Type::Error);
  ASSERT_NE(err, nullptr);
  EXPECT_NE(err->text.find("Could not calibrate before the stream ended"), std::string::npos) << err->text;
  EXPECT_NE(err->text.find("camera 0 is featureless"), std::string::npos) << err->text;
}

// A torn first frame is never calibrated on: the next good one is.
TEST(CalibSession, CorruptFirstFrameIsSkipped) {
  CalibSession s;
  s.set_config(quick());
  auto frames = crops(2);
  auto torn = frames;
  torn[1] = frames[1].clone();
  photo()(cv::Rect(900, 700, 640, 272)).copyTo(torn[1](cv::Rect(0, 208, 640, 272)));
  int jobs = 0;
  feed(s, 0, torn, &jobs);
  EXPECT_EQ(jobs, 0);
  EXPECT_FALSE(s.current());
  feed(s, 1, frames, &jobs);
  EXPECT_EQ(jobs, 1);
  EXPECT_TRUE(s.current());
}

// Later calibrations of the same cameras keep the model and projection the first one chose (the
// user left both to auto): a held-out comparison in canvas pixels across projections favoured a
// stretched plane over a cylinder on a real clip and flipped the panorama mid-stream. The
// installed model goes on the bus ("model").
TEST(CalibSession, PooledCalibrationKeepsTheFirstOnesModelAndProjection) {
  SessionConfig c = pooling();
  CalibSession s;
  s.set_config(c);
  const auto frames = crops(2);
  const auto first = feed(s, 0, frames);
  ASSERT_TRUE(s.current());
  const SessionEvent* in = find(first, SessionEvent::Type::Installed);
  ASSERT_NE(in, nullptr);
  ASSERT_FALSE(in->report.model.empty());
  const std::shared_ptr<CalibJob> pooled = next_job(s, frames);
  ASSERT_TRUE(pooled);
  EXPECT_EQ(pooled->kind, JobKind::Pooled);
  EXPECT_STREQ(camera_model_name(pooled->config.options.model), in->report.model.c_str());
  ASSERT_TRUE(pooled->config.projection.has_value());
  EXPECT_EQ(*pooled->config.projection, s.current()->projection_kind());
  // A choice the user made is the user's: not replaced.
  c.options.model = CameraModel::Rotation;
  c.projection = Projection::Cylindrical;
  CalibSession t;
  t.set_config(c);
  feed(t, 0, frames);
  ASSERT_TRUE(t.current());
  const std::shared_ptr<CalibJob> job = next_job(t, frames);
  ASSERT_TRUE(job);
  EXPECT_EQ(job->config.options.model, CameraModel::Rotation);
  EXPECT_EQ(*job->config.projection, Projection::Cylindrical);
}

// A broken keyframe (two pictures glued at a row) is not calibrated on; the same "tear" at the
// same row for over 3 s is the picture's own (a newspaper's rules and text lines, a still) and
// no longer holds calibration up.
TEST(CalibSession, ATearThatStaysAtOneRowIsThePictureNotABrokenFrame) {
  CalibSession s;
  s.set_config(quick());
  std::vector<cv::Mat> frames = crops(2, 200);
  photo()(cv::Rect(900, 700, 640, 160)).copyTo(frames[1](cv::Rect(0, 320, 640, 160)));
  ASSERT_EQ(assess_frame(view_of(frames[1])).verdict, FrameVerdict::Corrupt);
  // A camera's frames are never bit-identical (sensor noise): the same picture again is a still.
  auto noisy = [&](int f) {
    std::vector<cv::Mat> out;
    for (const auto& m : frames) {
      cv::Mat n(m.size(), m.type()), o;
      cv::randu(n, cv::Scalar::all(0), cv::Scalar(3, 3, 3, 0));
      cv::theRNG().state = 1234 + f;
      cv::add(m, n, o);
      out.push_back(o);
    }
    return out;
  };
  std::vector<SessionEvent> early;
  for (int f = 0; f < 45; ++f)  // 1.5 s, a GOP
    for (const auto& e : feed(s, f, noisy(f))) early.push_back(e);
  EXPECT_FALSE(s.current()) << "calibrated on a torn frame";
  const SessionEvent* p = find(early, SessionEvent::Type::Pending);
  ASSERT_NE(p, nullptr);
  EXPECT_NE(p->text.find("camera 1 is corrupt"), std::string::npos) << p->text;
  std::string last;
  for (int f = 45; f < 150 && !s.current(); ++f)
    for (const auto& e : feed(s, f, noisy(f)))
      if (e.type == SessionEvent::Type::Pending) last = e.text;
  EXPECT_TRUE(s.current()) << "a tear that never moves held calibration up: " << last;
}

// A still (probe2: imagefreeze of a bridge or newspaper photo, whose edges and text lines read
// as a tear of 4-7x) repeats the very same picture: waiting cannot heal it, so its second
// sighting is the picture's own. 30 frames of a still used to end with "Could not calibrate ...
// camera 0 is corrupt (a torn picture ...)".
TEST(CalibSession, ATornStillIsThePictureAtItsSecondFrame) {
  CalibSession s;
  s.set_config(quick());
  std::vector<cv::Mat> frames = crops(2, 200);
  photo()(cv::Rect(900, 700, 640, 160)).copyTo(frames[1](cv::Rect(0, 320, 640, 160)));
  ASSERT_EQ(assess_frame(view_of(frames[1])).verdict, FrameVerdict::Corrupt);
  feed(s, 0, frames);
  EXPECT_FALSE(s.current()) << "the first sighting is not yet known to be a still";
  for (int f = 1; f < 3 && !s.current(); ++f) feed(s, f, frames);
  EXPECT_TRUE(s.current()) << "a torn still held calibration up";
}

// The pooled calibration over the window is judged on held-out frames against the first one;
// a worse candidate is never swapped in.
TEST(CalibSession, WorseCalibrationIsNeverSwappedIn) {
  CalibSession s;
  s.set_config(pooling());
  const auto frames = crops(2);
  feed(s, 0, frames);
  ASSERT_TRUE(s.current());
  // The pooled job: same frames, so it cannot clearly beat the first one: rejected.
  std::vector<SessionEvent> all;
  for (int f = 1; f < 20; ++f)
    for (const auto& e : feed(s, f, frames)) all.push_back(e);
  EXPECT_EQ(count(all, SessionEvent::Type::Installed), 0);
  ASSERT_EQ(count(all, SessionEvent::Type::Rejected), 1);
  EXPECT_EQ(s.version(), 1u);
  // Handing it a clearly worse outcome by hand: rejected too.
  s.request_recalibration();
  CalibSession::Frame fr;
  fr.time_s = 1;
  fr.sizes = {{640, 480}, {640, 480}};
  std::shared_ptr<CalibJob> job;
  for (int f = 30; f < 50 && !job; ++f) {
    fr.time_s = f / 30.0;
    job = s.on_frame(fr, views_of(frames));
  }
  ASSERT_TRUE(job);
  CalibOutcome bad;
  bad.kind = job->kind;
  bad.serial = job->serial;
  bad.result = CalibrationResult();
  bad.result->rig = testdata::shifted_rig(2, 640, 480, 300);
  bad.candidate.median_px = 50;
  bad.candidate.matches = 100;
  bad.current.median_px = 0.4;
  bad.current.matches = 100;
  s.on_outcome(bad);
  EXPECT_EQ(count(s.take_events(), SessionEvent::Type::Rejected), 1);
  EXPECT_EQ(s.version(), 1u);
}

// A still camera (a jpeg through imagefreeze, or one frame that stitchsync repeats) next to two
// video cameras, the still showing what camera 1 shows: its frame is identical in every pooled
// and held-out bundle. A degenerate pooled solve on the house clip spread the plane canvas
// wider, the fit into the same panorama size shrank every view (camera 1 from 39% of the canvas
// to 18%, black 0.33 -> 0.525), and the judge, in canvas pixels, took the shrink for a better
// alignment (0.62 vs 0.90 px) and installed it. Here the candidate is the current calibration
// shrunk to 45% in the same canvas: its canvas-pixel residuals fall by the same factor, its
// camera-pixel ones do not, so it is not better (and every camera shrinks): kept out.
TEST(CalibSession, CandidateThatOnlyShrinksTheCanvasIsKeptOutWithAStillCamera) {
  CalibSession s;
  s.set_config(pooling());
  const cv::Mat still = photo()(cv::Rect(400, 200, 640, 480)).clone();
  // Camera 0 sees the scene with a little parallax (a real scene is not a photo): the current
  // calibration's residuals are not ~0.
  const cv::Mat cam0 = testdata::with_parallax(crops(1)[0], 3.0);
  auto frames_at = [&](int f) {  // two video cameras (sensor noise differs per frame) + the still
    std::vector<cv::Mat> v = {cam0.clone(), crops(2)[1]};
    cv::RNG rng(std::uint64_t(1000 + f));
    for (auto& m : v) {
      cv::Mat noise(m.size(), CV_16SC4);
      rng.fill(noise, cv::RNG::NORMAL, 0, 2);
      cv::Mat n16;
      m.convertTo(n16, CV_16SC4);
      n16 += noise;
      n16.convertTo(m, CV_8UC4);
      m.reshape(1, int(m.total())).col(3).setTo(255);
    }
    v.push_back(still);
    return v;
  };
  feed(s, 0, frames_at(0));
  ASSERT_TRUE(s.current());
  const std::shared_ptr<const Rig> first = s.current();
  CalibSession::Frame fr;
  fr.sizes.assign(3, {640, 480});
  std::shared_ptr<CalibJob> job;
  for (int f = 1; f < 30 && !job; ++f) {
    fr.time_s = f / 30.0;
    const auto frames = frames_at(f);
    job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(frames) : std::vector<ImageView>());
    s.bundle_passed();
  }
  ASSERT_TRUE(job);
  ASSERT_EQ(job->kind, JobKind::Pooled);
  ASSERT_FALSE(job->holdout_sets.empty());
  // The still is the same picture in every set the job holds.
  for (const auto& set : job->holdout_sets) EXPECT_EQ(cv::norm(set.images[2], still, cv::NORM_INF), 0);
  std::atomic<bool> cancel{false};
  CalibOutcome o = run_calib_job(*job, cancel);
  ASSERT_TRUE(o.result);
  Rig shrunk = *first;
  const int w = shrunk.canvas_width, h = shrunk.canvas_height;
  transform_canvas(shrunk, 0.45, 0.275 * w, 0.275 * h, w, h);
  o.result->rig = shrunk;
  o.candidate = measure_residuals(shrunk, job->holdout_sets, nullptr);
  // In canvas pixels the shrunk one "wins" by the old rule (10% and 0.05 px better).
  const double c = o.candidate.median_px, now = o.current.median_px;
  ASSERT_GT(c, 0);
  ASSERT_TRUE(c < 0.9 * now && c < now - 0.05) << c << " vs " << now;
  s.on_outcome(o);
  const auto events = s.take_events();
  EXPECT_EQ(count(events, SessionEvent::Type::Installed), 0) << "a shrunk canvas was taken for a better alignment";
  ASSERT_EQ(count(events, SessionEvent::Type::Rejected), 1);
  EXPECT_EQ(s.version(), 1u);
  EXPECT_EQ(s.current(), first);
}

// The judge keeps what the current calibration has: every aligned overlap, and the picture (no
// camera shrinks to under 2/3 of its canvas share, the covered share falls by 5 points at most),
// unless the candidate halves the residual.
TEST(CalibSession, JudgeRefusesACandidateThatLosesAnOverlapOrThePicture) {
  const Rig cur_rig = testdata::shifted_rig(3, 640, 480, 400);  // 1440 x 480, pairs 0-1 and 1-2
  const RigCoverage cur_cover = rig_coverage(cur_rig);
  ASSERT_EQ(cur_cover.camera_share.size(), 3u);
  EXPECT_NEAR(cur_cover.camera_share[0], 640.0 / 1440, 0.02);
  EXPECT_NEAR(cur_cover.share, 1.0, 0.01);
  auto residuals = [](std::vector<std::array<int, 2>> pairs, double px, int matches) {
    RigResiduals r;
    for (const auto& ab : pairs) {
      PairResidual p;
      p.a = ab[0];
      p.b = ab[1];
      p.median_px = p.median_camera_px = px;
      p.matches = matches;
      r.pairs.push_back(p);
      r.matches += matches;
    }
    r.median_px = r.median_camera_px = px;
    return r;
  };
  const RigResiduals cur = residuals({{0, 1}, {1, 2}}, 2.0, 100);
  // Better, same picture: installed.
  EXPECT_TRUE(judge_candidate(residuals({{0, 1}, {1, 2}}, 1.5, 100), cur, cur_cover, cur_cover).install);
  // Not 10% better: kept out.
  EXPECT_FALSE(judge_candidate(residuals({{0, 1}, {1, 2}}, 1.9, 100), cur, cur_cover, cur_cover).install);
  // Better on both overlaps, and a pair only the candidate measures (cameras 0 and 2: boxes that
  // touch on its canvas, matches across views that share no scene, 200 px apart): judged on the
  // pairs both measure, installed. Before, the extra pair alone made it "67.7 px against 2.0".
  RigResiduals extra = residuals({{0, 1}, {1, 2}, {0, 2}}, 1.5, 100);
  extra.pairs[2].median_px = extra.pairs[2].median_camera_px = 200;
  extra.median_px = extra.median_camera_px = (1.5 + 1.5 + 200) / 3;
  const Judgement fair = judge_candidate(extra, cur, cur_cover, cur_cover);
  EXPECT_TRUE(fair.install) << fair.reason;
  // The same pairs, worse on the common ones: kept out, and the reason gives the common figures.
  RigResiduals worse = residuals({{0, 1}, {1, 2}, {0, 2}}, 3.0, 100);
  worse.pairs[2].median_px = worse.pairs[2].median_camera_px = 200;
  const Judgement unfair = judge_candidate(worse, cur, cur_cover, cur_cover);
  EXPECT_FALSE(unfair.install);
  EXPECT_NE(unfair.reason.find("3.00 camera px against the current 2.00"), std::string::npos) << unfair.reason;
  // Better on what is left, but camera 2 no longer overlaps camera 1 (pulled apart): kept out.
  const Judgement lost = judge_candidate(residuals({{0, 1}}, 0.5, 100), cur, cur_cover, cur_cover);
  EXPECT_FALSE(lost.install);
  EXPECT_NE(lost.reason.find("overlap of cameras 1 and 2"), std::string::npos) << lost.reason;
  // Better, but camera 1 shrinks to a third of its canvas share: kept out...
  Rig small = cur_rig;
  Eigen::Matrix3d S = Eigen::Matrix3d::Identity();
  S(0, 0) = S(1, 1) = 0.55;
  small.cameras[1].homography = Eigen::Matrix3d(*small.cameras[1].homography * S);
  const RigCoverage small_cover = rig_coverage(small);
  EXPECT_LT(small_cover.camera_share[1], 0.4 * cur_cover.camera_share[1]);
  const Judgement shrunk = judge_candidate(residuals({{0, 1}, {1, 2}}, 1.5, 100), cur, small_cover, cur_cover);
  EXPECT_FALSE(shrunk.install);
  EXPECT_NE(shrunk.reason.find("camera 1 shrinks"), std::string::npos) << shrunk.reason;
  // ...unless the current calibration is badly off (the candidate halves the residual).
  EXPECT_TRUE(judge_candidate(residuals({{0, 1}, {1, 2}}, 0.9, 100), cur, small_cover, cur_cover).install);
  // The whole layout shrunk in the same canvas: coverage falls, kept out.
  Rig all_small = cur_rig;
  transform_canvas(all_small, 0.6, 0.2 * all_small.canvas_width, 0.2 * all_small.canvas_height, all_small.canvas_width,
                   all_small.canvas_height);
  const RigCoverage all_cover = rig_coverage(all_small);
  EXPECT_NEAR(all_cover.share, 0.36, 0.03);
  EXPECT_FALSE(judge_candidate(residuals({{0, 1}, {1, 2}}, 1.5, 100), cur, all_cover, cur_cover).install);
  // Coverage: 4 points less passes, 7 points less does not.
  RigCoverage a = cur_cover, b = cur_cover;
  a.share -= 0.04;
  b.share -= 0.07;
  EXPECT_TRUE(judge_candidate(residuals({{0, 1}, {1, 2}}, 1.5, 100), cur, a, cur_cover).install);
  const Judgement less = judge_candidate(residuals({{0, 1}, {1, 2}}, 1.5, 100), cur, b, cur_cover);
  EXPECT_FALSE(less.install);
  EXPECT_NE(less.reason.find("cover"), std::string::npos) << less.reason;
  // A pooled job reports both coverages.
  CalibSession s;
  s.set_config(pooling());
  const auto frames = crops(2);
  feed(s, 0, frames);
  ASSERT_TRUE(s.current());
  const auto job = next_job(s, frames);
  ASSERT_TRUE(job);
  std::atomic<bool> cancel{false};
  const CalibOutcome o = run_calib_job(*job, cancel);
  ASSERT_EQ(o.current_cover.camera_share.size(), 2u);
  ASSERT_EQ(o.candidate_cover.camera_share.size(), 2u);
  EXPECT_GT(o.current_cover.share, 0.9);
  EXPECT_NEAR(o.candidate_cover.share, o.current_cover.share, 0.05);
}

// The rig moved (a camera shifted 40 px): the recalibration beats the old geometry on the new
// frames and is installed, fitted into the same panorama size.
TEST(CalibSession, BetterRecalibrationIsInstalledInTheSamePanoramaSize) {
  SessionConfig c = quick();
  c.calibration_window_s = 0.2;
  CalibSession s;
  s.set_config(c);
  feed(s, 0, crops(2, 400));
  ASSERT_TRUE(s.current());
  const int w = s.current()->canvas_width, h = s.current()->canvas_height;
  s.request_recalibration();
  std::vector<SessionEvent> all;
  for (int f = 1; f < 20; ++f)
    for (const auto& e : feed(s, f, crops(2, 360))) all.push_back(e);
  const SessionEvent* in = find(all, SessionEvent::Type::Installed);
  ASSERT_NE(in, nullptr);
  EXPECT_EQ(in->report.source, "recalibration");
  EXPECT_GT(in->report.previous_px, 10);
  EXPECT_LT(in->report.residuals.median_px, 1.5);
  EXPECT_EQ(s.current()->canvas_width, w);
  EXPECT_EQ(s.current()->canvas_height, h);
}

// A resize (or a camera leaving) calibrates from scratch: the job carries no old geometry.
TEST(CalibSession, ResizeRecalibratesFromScratch) {
  CalibSession s;
  s.set_config(quick());
  feed(s, 0, crops(3));
  ASSERT_TRUE(s.current());
  const int panorama_w = s.current()->canvas_width, panorama_h = s.current()->canvas_height;
  CalibSession::Frame fr;
  fr.time_s = 1;
  const auto two = crops(2);
  fr.sizes = {{640, 480}, {640, 480}};
  auto job = s.on_frame(fr, views_of(two));
  ASSERT_TRUE(job);
  EXPECT_EQ(job->kind, JobKind::First);
  EXPECT_FALSE(job->current);
  // New geometry, fitted into the panorama the stream has (stitchblend's output cannot change
  // size under an encoder and a muxer).
  EXPECT_EQ(job->fit_width, panorama_w);
  EXPECT_EQ(job->fit_height, panorama_h);
  const auto e = s.take_events();
  const SessionEvent* w = find(e, SessionEvent::Type::Warning);
  ASSERT_NE(w, nullptr);
  EXPECT_NE(w->text.find("number of cameras changed mid-stream (3 -> 2)"), std::string::npos) << w->text;
}

// probe3: the middle one of three cameras leaves while playing (its pad released). Calibrated
// again from scratch, the two that stay share nothing and the panorama stopped for good ("camera
// 0 shares too few features", 7 panoramas of the house clips, then none). The cameras that stay
// have not moved: they keep their geometry, at once, on the same canvas.
TEST(CalibSession, ACameraThatLeavesKeepsTheOthersCalibration) {
  CalibSession s;
  SessionConfig config = quick();
  config.save_file = testdata::temp_dir() + "/leaves_keeps.json";
  std::remove(config.save_file.c_str());
  s.set_config(config);
  int jobs = 0;
  auto feed_ids = [&](int f, const std::vector<cv::Mat>& frames, const std::vector<unsigned>& ids) {
    CalibSession::Frame fr;
    fr.time_s = f / 30.0;
    for (const auto& m : frames) fr.sizes.push_back({m.cols, m.rows});
    fr.camera_ids = ids;
    auto job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(frames) : std::vector<ImageView>());
    if (job) {
      ++jobs;
      std::atomic<bool> cancel{false};
      s.on_outcome(run_calib_job(*job, cancel));
    }
    if (s.current()) s.bundle_passed();
    else s.bundle_dropped();
    return s.take_events();
  };
  const auto three = crops(3);
  feed_ids(0, three, {0, 1, 2});
  ASSERT_TRUE(s.current());
  ASSERT_EQ(s.current()->cameras.size(), 3u);
  const Rig before = *s.current();
  jobs = 0;
  std::vector<SessionEvent> events;
  for (int f = 1; f < 40; ++f)
    for (auto& e : feed_ids(f, {three[0], three[2]}, {0, 2})) events.push_back(e);
  EXPECT_EQ(count(events, SessionEvent::Type::Error), 0);
  EXPECT_EQ(count(events, SessionEvent::Type::Pending), 0);
  EXPECT_EQ(jobs, 0);
  const SessionEvent* in = find(events, SessionEvent::Type::Installed);
  ASSERT_NE(in, nullptr);
  EXPECT_EQ(in->report.source, "kept");
  const SessionEvent* w = find(events, SessionEvent::Type::Warning);
  ASSERT_NE(w, nullptr);
  EXPECT_NE(w->text.find("camera 1 (input 1) left"), std::string::npos) << w->text;
  ASSERT_TRUE(s.current());
  const Rig& now = *s.current();
  ASSERT_EQ(now.cameras.size(), 2u);
  EXPECT_EQ(now.canvas_width, before.canvas_width);
  EXPECT_EQ(now.canvas_height, before.canvas_height);
  ASSERT_TRUE(now.cameras[0].homography && now.cameras[1].homography);
  EXPECT_LT((*now.cameras[0].homography - *before.cameras[0].homography).norm(), 1e-9);
  EXPECT_LT((*now.cameras[1].homography - *before.cameras[2].homography).norm(), 1e-9);
  // the saved calibration stays the whole rig's: a part of it is nothing new to save
  EXPECT_EQ(rig_load(config.save_file).cameras.size(), 3u);
  // without the pad numbers (an older stitchsync) it is still a calibration from scratch
  CalibSession t;
  t.set_config(quick());
  feed(t, 0, three);
  CalibSession::Frame fr;
  fr.time_s = 1;
  fr.sizes = {{640, 480}, {640, 480}};
  auto job = t.on_frame(fr, views_of({three[0], three[2]}));
  ASSERT_TRUE(job);
  EXPECT_FALSE(job->current);
}

TEST(CalibSession, DriftWatchNeedsTwoBadChecksInARow) {
  SessionConfig c = quick();
  c.drift_threshold_px = 3;
  c.drift_check_interval_s = 1;
  CalibSession s;
  s.set_config(c);
  feed(s, 0, crops(2));
  ASSERT_TRUE(s.current());
  CalibSession::Frame fr;
  fr.sizes = {{640, 480}, {640, 480}};
  const auto frames = crops(2);
  auto check = [&](double t, double px) {
    fr.time_s = t;
    auto job = s.on_frame(fr, views_of(frames));
    if (!job) return false;
    EXPECT_EQ(job->kind, JobKind::DriftCheck);
    CalibOutcome o;
    o.kind = job->kind;
    o.serial = job->serial;
    o.current.median_px = px;
    o.current.matches = 50;
    s.on_outcome(o);
    return true;
  };
  ASSERT_TRUE(check(1.1, 9));   // one bad check: nothing yet
  EXPECT_EQ(count(s.take_events(), SessionEvent::Type::Warning), 0);
  ASSERT_TRUE(check(2.2, 1));   // good again: strikes reset
  ASSERT_TRUE(check(3.3, 9));
  EXPECT_EQ(count(s.take_events(), SessionEvent::Type::Warning), 0);
  ASSERT_TRUE(check(4.4, 9));   // second in a row: recalibrate
  const auto e = s.take_events();
  const SessionEvent* w = find(e, SessionEvent::Type::Warning);
  ASSERT_NE(w, nullptr);
  EXPECT_NE(w->text.find("drifted"), std::string::npos);
}

TEST(CalibSession, LoadedCalibrationThatDoesNotFitWarnsNamingTheCameras) {
  const SessionConfig c = loading("other_rig.json", 2);
  CalibSession s;
  s.set_config(c);
  std::vector<SessionEvent> all;
  for (int f = 0; f < 3; ++f)
    for (const auto& e : feed(s, f, crops(2, 330))) all.push_back(e);
  ASSERT_TRUE(s.current());
  const SessionEvent* w = find(all, SessionEvent::Type::Warning);
  ASSERT_NE(w, nullptr);
  EXPECT_NE(w->text.find("does not fit the images"), std::string::npos) << w->text;
  EXPECT_NE(w->text.find("cameras 0, 1"), std::string::npos) << w->text;
  // The right file: no warning.
  CalibSession ok;
  ok.set_config(c);
  std::vector<SessionEvent> fine;
  for (int f = 0; f < 3; ++f)
    for (const auto& e : feed(ok, f, crops(2, 400))) fine.push_back(e);
  EXPECT_EQ(count(fine, SessionEvent::Type::Warning), 0);
}

// recalibrate-interval counts running time that has passed, not timestamps: a seek back (the
// timestamps start again) does not stop it.
TEST(CalibSession, IntervalCountsRunningTimeAcrossASeekBack) {
  SessionConfig c = quick();
  c.recalibrate_interval_s = 1;
  c.calibration_window_s = 0.1;
  CalibSession s;
  s.set_config(c);
  const auto frames = crops(2);
  feed(s, 0, frames);
  ASSERT_TRUE(s.current());
  CalibSession::Frame fr;
  fr.sizes = {{640, 480}, {640, 480}};
  std::shared_ptr<CalibJob> job;
  for (int f = 1; f <= 24 && !job; ++f) {  // 0.8 s
    fr.time_s = f / 30.0;
    job = s.on_frame(fr, views_of(frames));
  }
  EXPECT_FALSE(job);
  for (int f = 0; f <= 20 && !job; ++f) {  // the timestamps restart at 0 (a flushing seek back)
    fr.time_s = f / 30.0;
    job = s.on_frame(fr, views_of(frames));
  }
  ASSERT_TRUE(job) << "the interval stopped after the seek back";
  EXPECT_EQ(job->kind, JobKind::Recalibration);
}

// Uncalibrated (a dark camera) when the resolution changes: the rough rig is adapted to the
// new sizes, not kept for the old ones.
TEST(CalibSession, RoughRigFollowsASizeChangeBeforeTheFirstCalibration) {
  const std::string path = testdata::temp_dir() + "/rough_sizes.json";
  Rig rough = testdata::shifted_rig(2, 640, 480, 400);
  for (auto& cam : rough.cameras) cam.homography.reset();
  rough.canvas_width = rough.canvas_height = 0;
  for (auto& cam : rough.cameras) cam.fx = cam.fy = 600;
  rig_save(rough, path);
  SessionConfig c = quick();
  c.rig_file = path;
  CalibSession s;
  s.set_config(c);
  feed(s, 0, {black(), black()});
  EXPECT_FALSE(s.current());
  cv::Mat small;
  cv::resize(crops(1)[0], small, cv::Size(320, 240));
  CalibSession::Frame fr;
  fr.time_s = 0.1;
  fr.sizes = {{320, 240}, {320, 240}};
  auto job = s.on_frame(fr, views_of({small, small}));
  ASSERT_TRUE(job);
  ASSERT_TRUE(job->rough);
  EXPECT_EQ(job->rough->cameras[0].width, 320);
}

// A complete calibration file needs no pixels: with a camera still missing (a dead camera, a slow
// decoder) it is used at once, the missing view taking the file's size, and the camera joins it
// when it starts: no waiting, no "resolution changed" recalibration.
TEST(CalibSession, CompleteLoadFileDoesNotWaitForMissingViews) {
  const SessionConfig c = loading("three_rig.json", 3);
  CalibSession s;
  s.set_config(c);
  CalibSession::Frame fr;
  fr.sizes = {{640, 480}, {640, 480}, {640, 480}};
  fr.sizes[2] = {320, 240};  // stitchsync's placeholder for a view without caps
  fr.missing_mask = 1u << 2;
  fr.time_s = 0;
  EXPECT_FALSE(s.on_frame(fr, {}));
  ASSERT_TRUE(s.current()) << "waited for the missing camera";
  const auto installed = s.take_events();
  EXPECT_EQ(count(installed, SessionEvent::Type::Pending), 0);
  EXPECT_EQ(count(installed, SessionEvent::Type::Installed), 1);
  ASSERT_EQ(s.current()->cameras.size(), 3u);
  EXPECT_EQ(s.current()->cameras[2].width, 640);  // the file's, not the placeholder's
  const auto version = s.version();
  // more bundles without it, then with it at its real size
  for (int f = 1; f < 5; ++f) {
    fr.time_s = f / 30.0;
    s.on_frame(fr, {});
  }
  fr.sizes[2] = {640, 480};
  fr.missing_mask = 0;
  for (int f = 5; f < 10; ++f) {
    fr.time_s = f / 30.0;
    s.on_frame(fr, {});
  }
  const auto later = s.take_events();
  EXPECT_EQ(count(later, SessionEvent::Type::Warning), 0);
  EXPECT_EQ(s.version(), version);
  EXPECT_TRUE(s.current());
}

// A first calibration from the images waits for a camera that has not started: its bundles are
// held (non-live inputs only), for 200 ms each and 10 s in all, so the others do not run ahead.
// A complete load-file, a calibration in place, live inputs, or every view missing: no hold.
TEST(CalibSession, BundlesWithoutALateCameraAreHeldBeforeTheFirstCalibrationOnly) {
  CalibSession s;
  s.set_config(quick());
  CalibSession::Frame fr;
  fr.sizes = {{640, 480}, {640, 480}, {320, 240}};
  fr.missing_mask = 1u << 2;
  s.on_frame(fr, {});
  EXPECT_TRUE(s.waits_for_a_camera(fr));
  CalibSession::Frame none_yet = fr;
  none_yet.missing_mask = 7;  // a live aggregator's first timeout: nobody has started
  EXPECT_FALSE(s.waits_for_a_camera(none_yet));
  LateCameraHold hold;
  EXPECT_EQ(hold.wait_us(true, true), 0) << "live cameras are never held";
  std::int64_t total = 0;
  int held = 0;
  while (const std::int64_t w = hold.wait_us(s.waits_for_a_camera(fr), false)) total += w, ++held;
  EXPECT_EQ(total, LateCameraHold::kBudgetUs);
  EXPECT_EQ(held, 12) << "0.2 + 0.4 + 0.8 s, eight slices of 1 s, then the 0.6 s left";
  // calibrated: nothing waits
  fr.sizes[2] = {640, 480};
  fr.missing_mask = 0;
  const std::vector<cv::Mat> frames = crops(3);
  for (int f = 1; f < 10 && !s.current(); ++f) feed(s, f, frames);
  ASSERT_TRUE(s.current());
  fr.missing_mask = 1u << 2;
  EXPECT_FALSE(s.waits_for_a_camera(fr));
  // a load-file is complete without it
  const SessionConfig c = loading("late_rig.json", 3);
  CalibSession loaded;
  loaded.set_config(c);
  EXPECT_FALSE(loaded.waits_for_a_camera(fr));
}

// A saved calibration is used as saved (probe2): its canvas is the panorama it was written as
// (after a recalibration, the new canvas fitted into the stream's panorama, with a margin). It
// used to be laid out again on load, so a round trip changed the output: the office clip's
// cylindrical calibration saved at 1066x580 came back as a 1066x560 panorama, shifted.
TEST(CalibSession, LoadFileKeepsTheSavedCanvas) {
  Rig rig = testdata::shifted_rig(2, 640, 480, 400);  // canvas 1040x480
  const int margin = 12;
  Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
  T(0, 2) = margin;
  T(1, 2) = margin;
  for (auto& cam : rig.cameras) cam.homography = T * *cam.homography;
  rig.canvas_width += 2 * margin;
  rig.canvas_height += 2 * margin;
  const std::string path = testdata::temp_dir() + "/saved_with_margin.json";
  rig_save(rig, path);
  SessionConfig c = quick();
  c.load_file = path;
  CalibSession s;
  s.set_config(c);
  feed(s, 0, crops(2));
  ASSERT_TRUE(s.current());
  EXPECT_EQ(s.current()->canvas_width, 1040 + 2 * margin);
  EXPECT_EQ(s.current()->canvas_height, 480 + 2 * margin);
  EXPECT_NEAR((*s.current()->cameras[0].homography)(1, 2), double(margin), 1e-9);
}

// The session warns about them, naming the file and the field (rig-file and load-file).
TEST(CalibSession, UnknownRigFieldsAreWarnedAbout) {
  Rig rig = testdata::shifted_rig(2, 640, 480, 400);
  std::string text = rig_to_json_string(rig);
  const std::size_t at = text.find("\"fx\"");
  ASSERT_NE(at, std::string::npos);
  text.insert(at, "\"yaw\": 12, ");
  const std::string path = testdata::temp_dir() + "/typo_rig.json";
  {
    std::ofstream(path) << text;
  }
  SessionConfig c = quick();
  c.load_file = path;
  CalibSession s;
  s.set_config(c);
  const auto events = feed(s, 0, crops(2));
  ASSERT_TRUE(s.current());
  const SessionEvent* w = find(events, SessionEvent::Type::Warning);
  ASSERT_NE(w, nullptr);
  EXPECT_NE(w->text.find("typo_rig.json\": ignored a field it does not know: camera 0: \"yaw\" (did you mean \"yaw_deg\"?)"),
            std::string::npos)
      << w->text;
}

// ---- lens from evidence in the background (issue 15) -------------------------------------------

namespace {

// Three cameras 35 degrees apart with a radtan lens (k1, k2; pinhole when both are 0), rendered
// from the photo taken as an equirectangular panorama; `noise` grey levels of sensor noise per
// frame (seeded by the frame), so that held-out frames are not the calibration frames.
std::vector<cv::Mat> lens_trio_frames(const Rig& truth, int frame, double noise = 2.0) {
  static std::map<std::pair<double, double>, std::vector<cv::Mat>> clean;
  const auto key = std::make_pair(truth.cameras[0].lens.k1, truth.cameras[0].fx);
  if (!clean.count(key))
    for (const auto& c : truth.cameras) clean[key].push_back(testdata::render_camera_from_equirect(photo(), c));
  return testdata::with_sensor_noise(clean[key], frame, noise, true);
}

struct LensRun {
  std::vector<SessionEvent> events;
  std::vector<JobKind> jobs;
  std::shared_ptr<const Rig> first, last;
};

// Default session settings but a short pooling window (2 sets over 0.3 s): frames fed at 30 fps,
// every job run synchronously, until the lens job has come and gone (or `frames` frames).
LensRun run_lens_session(const Rig& truth, int frames = 40) {
  SessionConfig c;
  c.calibration_frames = 2;
  c.calibration_window_s = 0.3;
  CalibSession s;
  s.set_config(c);
  LensRun run;
  for (int f = 0; f < frames; ++f) {
    const auto views = lens_trio_frames(truth, f);
    CalibSession::Frame fr;
    fr.time_s = f / 30.0;
    for (const auto& m : views) fr.sizes.push_back({m.cols, m.rows});
    auto job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(views) : std::vector<ImageView>());
    if (job) {
      run.jobs.push_back(job->kind);
      std::atomic<bool> cancel{false};
      s.on_outcome(run_calib_job(*job, cancel));
    }
    if (s.current()) s.bundle_passed();
    if (!run.first && s.current()) run.first = s.current();
    for (auto& e : s.take_events()) run.events.push_back(e);
    if (!run.jobs.empty() && run.jobs.back() == JobKind::Lens && !s.job_in_flight()) break;
  }
  run.last = s.current();
  return run;
}

// The seam error of a rig on the frames: independent matches of the overlaps, camera pixels.
AlignmentReport seams(const Rig& rig, const Rig& truth) {
  auto frames = lens_trio_frames(truth, 0, 0.0);
  return measure_alignment(rig, views_of(frames));
}

}  // namespace

// Barrel-distorted cameras (k1 -0.23, k2 0.055) calibrated by a session with default settings:
// the first calibration is pinhole (fast), the background lens fit gives every camera a radtan
// lens near the truth, installed as source "lens", and the seams close.
TEST(CalibSessionLens, DistortedRigGetsARadtanLensInTheBackground) {
  const Rig truth = testdata::radtan_trio(320, 240, 260, 35.0, -0.23, 0.055, true, "spherical", 0.0);
  const LensRun run = run_lens_session(truth);
  ASSERT_TRUE(run.first && run.last);
  for (const auto& c : run.first->cameras) EXPECT_TRUE(c.lens.pinhole()) << "the first calibration is pinhole";
  ASSERT_FALSE(run.jobs.empty());
  EXPECT_EQ(run.jobs.back(), JobKind::Lens) << "no lens job after the pooled one";
  const SessionEvent* lens = nullptr;
  for (const auto& e : run.events)
    if ((e.type == SessionEvent::Type::Installed || e.type == SessionEvent::Type::Rejected) && e.report.source == "lens")
      lens = &e;
  ASSERT_NE(lens, nullptr);
  std::printf("lens job: %s, %.3f camera px (pinhole %.3f) %s\n", lens->type == SessionEvent::Type::Installed ? "installed" : "rejected",
              lens->report.residuals.median_camera_px, lens->report.previous_camera_px, lens->report.rejected_because.c_str());
  ASSERT_EQ(lens->type, SessionEvent::Type::Installed) << lens->report.rejected_because;
  EXPECT_EQ(lens->report.model, "rotation");
  EXPECT_EQ(rig_lens_summary(*run.last), "radtan");
  for (const auto& c : run.last->cameras) {
    std::printf("  k1 %+.4f k2 %+.4f f %.1f\n", c.lens.k1, c.lens.k2, c.fx);
    EXPECT_EQ(c.lens.model, Lens::Model::Radtan);
    EXPECT_NEAR(c.lens.k1, -0.23, 0.25 * 0.23);
  }
  const AlignmentReport before = seams(*run.first, truth), after = seams(*run.last, truth);
  std::printf("seams: median %.3f -> %.3f camera px, p90 %.3f -> %.3f canvas px\n", before.median_camera_px,
              after.median_camera_px, before.p90_px, after.p90_px);
  EXPECT_LT(after.median_camera_px, 0.7 * before.median_camera_px);
  EXPECT_LT(after.p90_px, before.p90_px);
  // The panorama keeps its size.
  EXPECT_EQ(run.last->canvas_width, run.first->canvas_width);
  EXPECT_EQ(run.last->canvas_height, run.first->canvas_height);
}

// Undistorted cameras: no lens is invented (the fit is skipped by the cheap check, or it does not
// win by the evidence rule); the pinhole calibration stays.
TEST(CalibSessionLens, UndistortedRigStaysPinhole) {
  const Rig truth = testdata::radtan_trio(320, 240, 260, 35.0, 0, 0, false, "spherical", 0.0);
  const LensRun run = run_lens_session(truth);
  ASSERT_TRUE(run.last);
  for (const auto& e : run.events)
    if (e.report.source == "lens")
      std::printf("lens job: %s %s\n", e.type == SessionEvent::Type::Installed ? "installed" : "rejected",
                  e.report.rejected_because.c_str());
  for (const auto& c : run.last->cameras) EXPECT_TRUE(c.lens.pinhole()) << "no lens invented for undistorted cameras";
  EXPECT_EQ(rig_lens_summary(*run.last), "pinhole");
}

// The lens fit is a background job: it gives way to a recalibration whose frames are collected
// and to the end of the stream (its outcome is then ignored), and it is skipped with a rig-file.
TEST(CalibSessionLens, LensJobGivesWayAndIsSkippedWithARigFile) {
  const Rig truth = testdata::radtan_trio(320, 240, 260, 35.0, -0.23, 0.055, true, "spherical", 0.0);
  SessionConfig c;
  c.calibration_frames = 1;  // no pooling: the lens fit collects a window of its own
  c.calibration_window_s = 0.3;
  CalibSession s;
  s.set_config(c);
  std::shared_ptr<CalibJob> lens;
  for (int f = 0; f < 40 && !lens; ++f) {
    const auto views = lens_trio_frames(truth, f);
    CalibSession::Frame fr;
    fr.time_s = f / 30.0;
    for (const auto& m : views) fr.sizes.push_back({m.cols, m.rows});
    auto job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(views) : std::vector<ImageView>());
    if (job && job->kind == JobKind::Lens) lens = job;
    else if (job) {
      std::atomic<bool> cancel{false};
      s.on_outcome(run_calib_job(*job, cancel));
    }
  }
  ASSERT_TRUE(lens) << "no lens job";
  EXPECT_FALSE(s.give_way(false)) << "nothing waits for it";
  EXPECT_TRUE(s.give_way(true)) << "the end of the stream does not wait for it";
  EXPECT_FALSE(s.job_in_flight());
  // Cancelled while it runs (the end of the stream), the lens job stops at the calibrator's next
  // stage, and its outcome is ignored.
  std::atomic<bool> cancel{false};
  CalibOutcome out;
  const auto t0 = std::chrono::steady_clock::now();
  std::thread worker([&]() { out = run_calib_job(*lens, cancel); });
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  cancel = true;
  const auto t1 = std::chrono::steady_clock::now();
  worker.join();
  const double stop_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  std::printf("lens job cancelled after %.2f s: stopped %.2f s later\n",
              std::chrono::duration<double>(t1 - t0).count(), stop_s);
  EXPECT_TRUE(out.cancelled);
  EXPECT_LT(stop_s, 2.0);
  s.on_outcome(out);
  EXPECT_EQ(s.version(), 1u);
  // With a rig-file the file states the lenses: no lens job.
  const std::string path = testdata::temp_dir() + "/lens_trio_rough.json";
  rig_save(testdata::rough_trio(truth, 1), path);
  c.rig_file = path;
  CalibSession t;
  t.set_config(c);
  for (int f = 0; f < 30; ++f) {
    const auto views = lens_trio_frames(truth, f);
    CalibSession::Frame fr;
    fr.time_s = f / 30.0;
    for (const auto& m : views) fr.sizes.push_back({m.cols, m.rows});
    auto job = t.on_frame(fr, t.wants_pixels(fr) ? views_of(views) : std::vector<ImageView>());
    if (job) {
      EXPECT_NE(job->kind, JobKind::Lens);
      std::atomic<bool> no{false};
      t.on_outcome(run_calib_job(*job, no));
    }
  }
  EXPECT_TRUE(t.current());
}

// At the end of the stream: the jobs whose result only later frames would use are cancelled;
// the first calibration and a requested recalibration are finished; save-file keeps the
// automatic ones (their result is written).
TEST(CalibSession, EndOfStreamCancelsOnlyJobsNoFrameWillUse) {
  EXPECT_TRUE(cancel_at_end_of_stream(JobKind::Lens, true, false));
  EXPECT_TRUE(cancel_at_end_of_stream(JobKind::Lens, true, true));
  EXPECT_TRUE(cancel_at_end_of_stream(JobKind::Pooled, true, false));
  EXPECT_FALSE(cancel_at_end_of_stream(JobKind::Pooled, true, true));
  EXPECT_TRUE(cancel_at_end_of_stream(JobKind::First, true, false));  // a returning camera's
  EXPECT_FALSE(cancel_at_end_of_stream(JobKind::First, false, false));
  EXPECT_FALSE(cancel_at_end_of_stream(JobKind::Recalibration, true, false));
}

// The stream waits for a first calibration (no panorama yet), and for a returning camera's only
// when the cameras are files (non-live): live ones go on without it meanwhile. Background jobs
// (pooled, recalibration, lens) never hold the stream.
TEST(CalibSession, StreamWaitsForAReturningCameraOnlyWhenTheCamerasAreNotLive) {
  EXPECT_TRUE(stream_waits_for_job(JobKind::First, false, true));
  EXPECT_TRUE(stream_waits_for_job(JobKind::First, false, false));
  EXPECT_TRUE(stream_waits_for_job(JobKind::First, true, false));   // a returning file camera
  EXPECT_FALSE(stream_waits_for_job(JobKind::First, true, true));   // a returning live camera
  for (const JobKind k : {JobKind::Pooled, JobKind::Recalibration, JobKind::Lens, JobKind::DriftCheck})
    for (const bool live : {false, true}) EXPECT_FALSE(stream_waits_for_job(k, true, live)) << job_kind_name(k);
}

// The same source given to two pads: said once, by the cameras' indices; a camera that only
// looks alike (another crop of the photo) or is dark is not taken for it.
TEST(CalibSession, TheSameSourceTwiceIsSaid) {
  const auto good = crops(3);
  std::vector<cv::Mat> noisy = {good[0], good[0].clone(), good[1]};
  cv::Mat noise(noisy[1].size(), CV_8UC4);
  cv::randu(noise, 0, 2);  // a re-encode's differences
  noisy[1] += noise;
  std::vector<ImageView> views;
  for (const auto& m : noisy) views.push_back(view_of(m));
  const auto same = identical_views(views);
  ASSERT_EQ(same.size(), 1u);
  EXPECT_EQ(same[0], std::make_pair(0, 1));
  EXPECT_TRUE(identical_views(views, 0b10).empty());  // camera 1 skipped (left out)
  std::vector<ImageView> distinct;
  for (const auto& m : good) distinct.push_back(view_of(m));
  EXPECT_TRUE(identical_views(distinct).empty());
  // Through the session: the warning names both cameras, once.
  CalibSession s;
  s.set_config(quick());
  const std::vector<cv::Mat> twice = {good[0], good[0], good[1]};
  int said = 0;
  for (int f = 0; f < 3; ++f)
    for (const SessionEvent& e : feed(s, f, twice))
      said += e.type == SessionEvent::Type::Warning && e.text.find("camera 0 and camera 1 show the same picture") != std::string::npos;
  EXPECT_EQ(said, 1);
}

// A calibration whose overlaps stay far apart is said, naming the worst pair (probe-lens: a
// strong barrel phone row calibrated pinhole left 17.5 camera px and said nothing).
TEST(CalibSession, PoorAlignmentIsSaidNamingTheWorstPair) {
  RigResiduals r;
  r.pairs = {{0, 1, 20.0, 14.0, 300}, {1, 2, 30.0, 21.9, 250}};
  r.median_camera_px = 17.5;
  const std::string text = poor_alignment_text(r, kPoorAlignmentCameraPx);
  EXPECT_NE(text.find("17.5 camera px apart"), std::string::npos) << text;
  EXPECT_NE(text.find("worst cameras 1 and 2, 21.9 px"), std::string::npos) << text;
  r.median_camera_px = 1.8;  // the real clips with parallax: 0.5-1.8
  EXPECT_TRUE(poor_alignment_text(r, kPoorAlignmentCameraPx).empty());
  r.median_camera_px = -1;  // nothing measured
  EXPECT_TRUE(poor_alignment_text(r, kPoorAlignmentCameraPx).empty());
}

// ---- files: no frame set lost to a failed first attempt (first-frames) ------------------------

namespace {
// Three crops whose camera 2 shows its picture mirrored: it passes the quality checks (sharp,
// textured) but matches no other camera, so a calibration on it fails ("camera 2 shares too few
// features"), as the first frame set of a 6-camera ring at 8% overlap did.
std::vector<cv::Mat> mirrored_camera2() {
  auto v = crops(3);
  cv::flip(v[2].clone(), v[2], 1);
  return v;
}

// Feeds frame f (live or not) and runs any job; returns the job's frame sets (0: no job).
int feed_counting_sets(CalibSession& s, int f, const std::vector<cv::Mat>& frames, bool live) {
  CalibSession::Frame fr;
  fr.time_s = f / 30.0;
  fr.live = live;
  for (const auto& m : frames) fr.sizes.push_back({m.cols, m.rows});
  auto job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(frames) : std::vector<ImageView>());
  if (!job) return 0;
  std::atomic<bool> cancel{false};
  s.on_outcome(run_calib_job(*job, cancel));
  return int(job->calib_sets.size());
}
}  // namespace

// Files: the failed first attempt is tried again on the very next bundle (the bundles between
// are held by the element, nothing is lost), pooled with the frame set tried before; live
// cameras keep retry_interval_s (0.5 s) between attempts. Without the change the file stream
// waited 15 bundles, all dropped.
TEST(CalibSession, FilesRetryAFailedFirstAttemptOnTheNextBundlePooled) {
  for (const bool live : {false, true}) {
    SessionConfig c;
    c.calibration_frames = 3;
    CalibSession s;
    s.set_config(c);
    EXPECT_EQ(feed_counting_sets(s, 0, mirrored_camera2(), live), 1);
    ASSERT_FALSE(s.current());
    const auto events = s.take_events();
    const SessionEvent* p = find(events, SessionEvent::Type::Pending);
    ASSERT_NE(p, nullptr);
    EXPECT_NE(p->text.find("camera 2"), std::string::npos) << p->text;
    int f = 1, sets = 0;
    for (; f < 30 && !s.current(); ++f) sets = std::max(sets, feed_counting_sets(s, f, crops(3), live));
    ASSERT_TRUE(s.current()) << (live ? "live" : "files");
    if (live) {
      EXPECT_GE(f - 1, 15);  // 0.5 s at 30 fps: the bundles between are dropped
      EXPECT_EQ(sets, 1);
    } else {
      EXPECT_EQ(f - 1, 1);  // calibrated on frame 1
      EXPECT_EQ(sets, 2);   // frame 0's set pooled with frame 1's
    }
  }
}

// Files whose attempts keep failing are tried again 1, 2, 4, 8 bundles apart and then at the
// live pace (retry_interval_s): a clip that never calibrates costs no more attempts than today.
// The pool holds the newest calibration_frames sets.
TEST(CalibSession, FilesBackOffBetweenFailedFirstAttempts) {
  SessionConfig c;
  c.calibration_frames = 3;
  c.calibration_timeout_s = 0;
  CalibSession s;
  s.set_config(c);
  std::vector<int> attempts, sets;
  const auto frames = crops(3);
  for (int f = 0; f < 60; ++f) {
    CalibSession::Frame fr;
    fr.time_s = f / 30.0;
    fr.live = false;
    fr.sizes.assign(3, {640, 480});
    auto job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(frames) : std::vector<ImageView>());
    if (!job) continue;
    attempts.push_back(f);
    sets.push_back(int(job->calib_sets.size()));
    CalibOutcome failed;  // every attempt fails (not run: a failed calibration takes seconds)
    failed.kind = job->kind;
    failed.serial = job->serial;
    failed.error = "camera 2 shares too few features with the other cameras";
    s.on_outcome(failed);
  }
  EXPECT_FALSE(s.current());
  ASSERT_GE(attempts.size(), 6u);
  EXPECT_EQ(std::vector<int>(attempts.begin(), attempts.begin() + 5), (std::vector<int>{0, 1, 3, 7, 15}));
  for (std::size_t i = 5; i < attempts.size(); ++i) EXPECT_GE(attempts[i] - attempts[i - 1], 14);
  EXPECT_EQ(sets.front(), 1);
  EXPECT_EQ(sets.back(), 3);
}

// The element's hold of the bundles before the first calibration: in order, within the bound
// (the oldest dropped beyond, said once), a layout change drops the older ones, live holds none.
TEST(EarlyBundles, HoldsInOrderWithinTheBound) {
  EXPECT_TRUE(EarlyBundles<int>::holds(false, false, 0));
  EXPECT_FALSE(EarlyBundles<int>::holds(true, false, 0));   // live: today's behaviour
  EXPECT_FALSE(EarlyBundles<int>::holds(false, true, 0));   // the session failed
  EXPECT_FALSE(EarlyBundles<int>::holds(false, false, 2));  // a camera missing
  const std::vector<std::array<int, 2>> vga = {{640, 480}, {640, 480}}, hd = {{1280, 720}, {1280, 720}};
  EarlyBundles<int> b(300);
  for (int i = 0; i < 3; ++i) EXPECT_TRUE(b.keep(i, 100, vga).empty());
  EXPECT_FALSE(b.bound_reached());
  EXPECT_EQ(b.keep(3, 100, vga), std::vector<int>{0});  // over 300 bytes: the oldest goes
  EXPECT_TRUE(b.bound_reached());
  EXPECT_EQ(b.keep(4, 100, vga), std::vector<int>{1});
  EXPECT_FALSE(b.bound_reached());  // said once
  EXPECT_EQ(b.bytes(), 300u);
  EXPECT_EQ(b.keep(5, 100, hd), (std::vector<int>{2, 3, 4}));  // another layout
  EXPECT_EQ(b.keep(6, 1000, hd), std::vector<int>{5});         // one bundle over the bound stays
  EXPECT_EQ(b.take(), std::vector<int>{6});
  EXPECT_TRUE(b.empty());
  EXPECT_EQ(b.bytes(), 0u);
}

// ---- a seam nothing measured is said (calib-wait) --------------------------------------------

// Three pinhole cameras 35 degrees apart whose overlap 1-2 shows a plain wall (flat grey with
// sensor noise, like the duct of a 5-camera ring at 8% overlap): no feature matches there and
// area alignment finds nothing, so the residuals leave the pair out. It is listed as unverified
// (and said); the textured overlap 0-1 is measured, and the same rig on the textured photo has
// nothing unverified. Camera 0 and 2 (70 degrees apart, 63 across each) do not overlap: not
// listed.
TEST(CalibSession, AnOverlapNothingCouldMeasureIsListedAndSaid) {
  Rig truth = testdata::radtan_trio(320, 240, 260, 35.0, 0, 0, false, "spherical", 0.0);
  rig_layout_canvas(truth);
  cv::Mat plain = photo().clone();
  const int from = plain.cols / 2, to = plain.cols / 2 + plain.cols * 40 / 360;  // yaw 0..40 degrees
  plain.colRange(from, to).setTo(cv::Scalar(150, 150, 150, 255));
  std::vector<cv::Mat> textured_views, plain_views;
  for (const auto& c : truth.cameras) {
    textured_views.push_back(testdata::render_camera_from_equirect(photo(), c));
    plain_views.push_back(testdata::render_camera_from_equirect(plain, c));
  }
  const auto set_of = [](const std::vector<cv::Mat>& clean) {
    return std::vector<FrameSet>{FrameSet::copy_of(views_of(testdata::with_sensor_noise(clean, 1, 2.0, true)))};
  };
  const RigResiduals textured = measure_residuals(truth, set_of(textured_views), nullptr);
  EXPECT_TRUE(textured.unverified.empty());
  EXPECT_EQ(textured.pairs.size(), 2u);
  EXPECT_TRUE(unverified_overlap_text(textured).empty());

  const RigResiduals r = measure_residuals(truth, set_of(plain_views), nullptr);
  ASSERT_EQ(r.unverified.size(), 1u) << "the plain overlap went unnoticed";
  EXPECT_EQ(r.unverified[0], std::make_pair(1, 2));
  ASSERT_EQ(r.pairs.size(), 1u);
  EXPECT_EQ(r.pairs[0].a, 0);
  EXPECT_EQ(r.pairs[0].b, 1);
  const std::string text = unverified_overlap_text(r);
  EXPECT_NE(text.find("overlap of cameras 1-2 could not be verified"), std::string::npos) << text;
}

// The calibrator keeps recent frames' detections (a file's retried first attempts pool the frame
// sets tried before, and the lens test detects on them again): by content, so that other pixels
// in the same buffers (a frame pool reused) get their own features. Crops 400 px apart, then
// crops 300 px apart written into the same buffers: each calibration fits its own pictures.
TEST(CalibSession, CachedDetectionsFollowThePixelsNotTheBuffers) {
  CalibrationOptions o;
  o.model = CameraModel::Homography;
  std::vector<cv::Mat> frames = crops(2, 400);
  const CalibrationResult first = calibrate_from_images(views_of(frames), 0, o);
  const CalibrationResult again = calibrate_from_images(views_of(frames), 0, o);  // detections reused
  EXPECT_LT(measure_alignment(first.rig, views_of(frames)).median_px, 1.0);
  EXPECT_LT(measure_alignment(again.rig, views_of(frames)).median_px, 1.0);
  const std::vector<cv::Mat> other = crops(2, 300);
  const uchar* buffer = frames[0].data;
  for (std::size_t i = 0; i < frames.size(); ++i) other[i].copyTo(frames[i]);
  ASSERT_EQ(frames[0].data, buffer) << "not the same buffers";
  const CalibrationResult moved = calibrate_from_images(views_of(frames), 0, o);
  const AlignmentReport fit = measure_alignment(moved.rig, views_of(frames));
  EXPECT_LT(fit.median_px, 1.0) << "the calibration of new pixels used the old pixels' features";
  EXPECT_GT(measure_alignment(first.rig, views_of(frames)).median_px, 10.0) << "the test tests nothing";
}
