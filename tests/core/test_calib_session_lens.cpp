// The session's lens from evidence after it is found (issue 15): the cheap test before the lens
// fit (lens_precheck), and calibrations after the lens was installed (a recalibration, a rig that
// moved, a resize) that keep it instead of going back to pinhole cameras.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <map>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "lens_rig.hpp"
#include "stitch/calib/calib_session.hpp"
#include "stitch/cv_interop.hpp"
#include "test_data.hpp"

using namespace stitch;

namespace {

const cv::Mat& photo() {
  static cv::Mat p = testdata::load_rgba(testdata::repo_path("data/photos/boat1_1600.jpg"));
  return p;
}

std::vector<ImageView> views_of(std::vector<cv::Mat>& m) {
  std::vector<ImageView> v;
  for (auto& x : m) v.push_back(as_view(x));
  return v;
}

// The rig's cameras rendered from the photo (cached by `name`), 2 grey levels of sensor noise
// seeded by the frame.
std::vector<cv::Mat> frames_of(const std::string& name, const Rig& truth, int frame) {
  static std::map<std::string, std::vector<cv::Mat>> clean;
  if (!clean.count(name))
    for (const auto& c : truth.cameras) clean[name].push_back(testdata::render_camera_from_equirect(photo(), c));
  return testdata::with_sensor_noise(clean[name], frame, 2.0, true);
}

// A session with default settings but a short pooling window (2 sets over 0.3 s), fed at 30 fps,
// every job run synchronously; what it said and did.
struct Driver {
  CalibSession s;
  int frame = 0;
  std::vector<SessionEvent> events;
  struct Job {
    JobKind kind;
    std::size_t lenses;  // CalibJob::lenses given
    CalibOutcome outcome;
    double seconds;
  };
  std::vector<Job> jobs;
  Driver() {
    SessionConfig c;
    c.calibration_frames = 2;
    c.calibration_window_s = 0.3;
    s.set_config(c);
  }
  // One frame; returns the kind of the job it ran, if any.
  std::optional<JobKind> feed(std::vector<cv::Mat> m) {
    CalibSession::Frame fr;
    fr.time_s = frame++ / 30.0;
    for (const auto& x : m) fr.sizes.push_back({x.cols, x.rows});
    auto job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(m) : std::vector<ImageView>());
    std::optional<JobKind> ran;
    if (job) {
      std::atomic<bool> cancel{false};
      const auto t0 = std::chrono::steady_clock::now();
      CalibOutcome o = run_calib_job(*job, cancel);
      jobs.push_back({job->kind, job->lenses.size(), o,
                      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()});
      s.on_outcome(o);
      ran = job->kind;
    }
    if (s.current()) s.bundle_passed();
    for (auto& e : s.take_events()) events.push_back(e);
    return ran;
  }
  // Frames until a job of `kind` has run (at most `max` frames): whether one did.
  template <class F>
  bool until(JobKind kind, F frames, int max = 60) {
    for (int i = 0; i < max; ++i)
      if (feed(frames(frame)) == kind) return true;
    return false;
  }
  const SessionEvent* last_report(const std::string& source) const {
    for (auto it = events.rbegin(); it != events.rend(); ++it)
      if ((it->type == SessionEvent::Type::Installed || it->type == SessionEvent::Type::Rejected) &&
          it->report.source == source)
        return &*it;
    return nullptr;
  }
};

double seam_px(const Rig& rig, std::vector<cv::Mat> frames) {
  return measure_alignment(rig, views_of(frames)).median_camera_px;
}

}  // namespace

// The cheap test on rendered trios: barrel lenses are plausible (k1 found near the truth), none
// is for pinhole cameras, in well under the lens fit's seconds.
TEST(LensPrecheck, SeesBarrelLensesAndNoneWherePinhole) {
  for (const double k1 : {-0.2, -0.1, 0.0}) {
    const Rig truth = testdata::radtan_trio(320, 240, 260, 35.0, k1, k1 * k1, k1 != 0, "spherical", 0.0);
    const std::string name = "pre" + std::to_string(k1);
    std::vector<std::vector<cv::Mat>> frames{frames_of(name, truth, 0), frames_of(name, truth, 7)};
    std::vector<std::vector<ImageView>> sets{views_of(frames[0]), views_of(frames[1])};
    CalibrationOptions o;
    o.lens_from_evidence = false;  // the session's first calibration: pinhole
    const CalibrationResult pin = calibrate_from_images(sets, -1, o);
    for (const auto& c : pin.rig.cameras) ASSERT_TRUE(c.lens.pinhole());
    const LensPrecheck p = lens_precheck(pin.rig, sets, o);
    std::printf("k1 %+.2f: %s %s\n", k1, p.plausible ? "plausible" : "no", p.describe().c_str());
    EXPECT_EQ(p.plausible, k1 != 0) << p.describe();
    if (k1 != 0) EXPECT_NEAR(p.k1, k1, 0.3 * std::abs(k1)) << p.describe();
    EXPECT_GT(p.heldout, 30);
    EXPECT_LT(p.seconds, 5.0) << "the cheap test must stay cheap";
  }
}

// A real clip without distortion (../shared data; skipped without it): the lens job stops at the
// cheap test within seconds (it ran 79-143 s of a core for nothing before), and nothing changes.
TEST(LensPrecheck, RealClipStopsTheLensJobAtTheCheapTest) {
  std::vector<cv::VideoCapture> caps;
  for (const char* f : {"left.mp4", "middle.mp4", "right.mp4"}) {
    const std::string p = testdata::shared_path(std::string("video/karthik_3cam_house/") + f);
    if (p.empty()) GTEST_SKIP() << "../shared/data/video/karthik_3cam_house not found";
    caps.emplace_back(p);
    if (!caps.back().isOpened()) GTEST_SKIP() << "cannot decode " << p;
  }
  Driver d;
  SessionConfig c;  // the element's defaults: 5 pooled sets over 2 s
  d.s.set_config(c);
  const auto next = [&](int) {
    std::vector<cv::Mat> out;
    for (auto& cap : caps) {
      cv::Mat bgr, rgba;
      if (!cap.read(bgr)) return std::vector<cv::Mat>();
      cv::cvtColor(bgr, rgba, cv::COLOR_BGR2RGBA);
      out.push_back(rgba);
    }
    return out;
  };
  bool lens_job = false;
  for (int f = 0; f < 120 && !lens_job; ++f) {
    auto m = next(f);
    if (m.empty()) break;
    lens_job = d.feed(m) == JobKind::Lens;
  }
  ASSERT_TRUE(lens_job) << "no lens job on the house clip";
  const Driver::Job& j = d.jobs.back();
  std::printf("lens job: %.2f s, %s\n", j.seconds, j.outcome.error.c_str());
  ASSERT_TRUE(j.outcome.lens_precheck.has_value());
  EXPECT_FALSE(j.outcome.lens_precheck->plausible) << j.outcome.lens_precheck->describe();
  EXPECT_NE(j.outcome.error.find("no sign of lens distortion"), std::string::npos) << j.outcome.error;
  EXPECT_LT(j.seconds, 15.0);
  EXPECT_EQ(rig_lens_summary(*d.s.current()), "pinhole");
}

// Once the lens job installed radtan lenses, calibrations from the images keep them:
//  - recalibrations on request of the same rig (no ping-pong: every candidate has the lenses, and
//    the lens fit does not run again);
//  - a recalibration after the rig moved (camera 2 turned by 3 degrees): installed, with lenses,
//    seams closed again;
//  - a calibration from scratch after a resize (the same cameras at twice the resolution).
// Before, each of them was a pinhole calibration: rejected against the lens, or installed and the
// lens thrown away.
TEST(CalibSessionLensRecal, RecalibrationsKeepTheLens) {
  const double k1 = -0.23, k2 = 0.055;
  const Rig truth = testdata::radtan_trio(320, 240, 260, 35.0, k1, k2, true, "spherical", 0.0);
  Driver d;
  const auto still = [&](int f) { return frames_of("still", truth, f); };
  ASSERT_TRUE(d.until(JobKind::Lens, still, 60)) << "no lens job";
  ASSERT_TRUE(d.s.current());
  ASSERT_EQ(rig_lens_summary(*d.s.current()), "radtan") << "the lens job installed no lens";
  const std::uint64_t lens_version = d.s.version();
  std::printf("lens installed: k1 %+.4f, seams %.3f camera px\n", d.s.current()->cameras[0].lens.k1,
              seam_px(*d.s.current(), still(0)));

  // Recalibrations of the same rig: the candidate has the lenses; installed or not, the lens stays.
  for (int r = 0; r < 2; ++r) {
    d.s.request_recalibration();
    ASSERT_TRUE(d.until(JobKind::Recalibration, still, 30)) << "no recalibration job";
    const Driver::Job& j = d.jobs.back();
    EXPECT_EQ(j.lenses, 3u) << "the recalibration was not given the known lenses";
    EXPECT_TRUE(j.outcome.kept_lenses) << j.outcome.lens_error;
    const SessionEvent* e = d.last_report("recalibration");
    ASSERT_NE(e, nullptr);
    ASSERT_TRUE(e->report.rig);
    std::printf("recalibration %d: %s, %.3f camera px against %.3f; %s\n", r,
                e->type == SessionEvent::Type::Installed ? "installed" : "rejected", e->report.residuals.median_camera_px,
                e->report.previous_camera_px, e->report.rejected_because.c_str());
    EXPECT_EQ(rig_lens_summary(*e->report.rig), "radtan") << "the recalibration's candidate is pinhole";
    EXPECT_EQ(rig_lens_summary(*d.s.current()), "radtan");
    for (const auto& c : e->report.rig->cameras) EXPECT_NEAR(c.lens.k1, k1, 0.25 * std::abs(k1));
  }

  // The rig moved: the recalibration is installed, with the lenses, and the seams close again.
  Rig moved = truth;
  moved.cameras[2].yaw_deg += 3.0;
  const auto turned = [&](int f) { return frames_of("moved", moved, f); };
  const double off = seam_px(*d.s.current(), turned(0));
  d.s.request_recalibration();
  ASSERT_TRUE(d.until(JobKind::Recalibration, turned, 30)) << "no recalibration job";
  const SessionEvent* e = d.last_report("recalibration");
  ASSERT_NE(e, nullptr);
  std::printf("moved: %s (%s), seams %.3f -> %.3f camera px\n", e->type == SessionEvent::Type::Installed ? "installed" : "rejected",
              e->report.rejected_because.c_str(), off, seam_px(*d.s.current(), turned(0)));
  ASSERT_EQ(e->type, SessionEvent::Type::Installed) << e->report.rejected_because;
  EXPECT_EQ(rig_lens_summary(*d.s.current()), "radtan") << "the recalibration threw the lens away";
  EXPECT_LT(seam_px(*d.s.current(), turned(0)), 0.3);
  EXPECT_LT(seam_px(*d.s.current(), turned(0)), 0.5 * off);

  // A resize (the same cameras at twice the resolution): calibrated from scratch, with the lenses.
  Rig big = testdata::radtan_trio(640, 480, 520, 35.0, k1, k2, true, "spherical", 0.0);
  big.cameras[2].yaw_deg += 3.0;
  const auto large = [&](int f) { return frames_of("big", big, f); };
  const std::uint64_t before = d.s.version();
  for (int i = 0; i < 40 && d.s.version() == before; ++i) d.feed(large(d.frame));
  ASSERT_GT(d.s.version(), before) << "no calibration after the resize";
  const SessionEvent* first = d.last_report("images");
  ASSERT_NE(first, nullptr);
  EXPECT_EQ(d.jobs.back().kind, JobKind::First);
  EXPECT_EQ(d.jobs.back().lenses, 3u);
  EXPECT_EQ(rig_lens_summary(*d.s.current()), "radtan") << "the calibration after the resize is pinhole";
  for (const auto& c : d.s.current()->cameras) EXPECT_NEAR(c.lens.k1, k1, 0.25 * std::abs(k1));
  const double big_px = seam_px(*d.s.current(), large(0));
  std::printf("resized: seams %.3f camera px, k1 %+.4f\n", big_px, d.s.current()->cameras[0].lens.k1);
  EXPECT_LT(big_px, 0.3);
  // ...and its pooled window keeps them too; the lens fit never runs again.
  d.until(JobKind::Pooled, large, 30);
  EXPECT_EQ(rig_lens_summary(*d.s.current()), "radtan");
  int lens_jobs = 0;
  for (const auto& j : d.jobs) {
    lens_jobs += j.kind == JobKind::Lens;
    std::printf("  job %s, %zu known lenses%s: %.2f s\n", job_kind_name(j.kind), j.lenses,
                j.outcome.kept_lenses ? " (kept)" : "", j.seconds);
  }
  EXPECT_EQ(lens_jobs, 1) << "the lens fit ran again";
  EXPECT_GT(d.s.version(), lens_version);
}

// A short file of a strong barrel phone row (branch lens-short): 3 x radtan k1 -0.40 k2 0.16, 80
// degrees across the width, 45 degrees apart (probe-lens's phone3_k040 at 320 x 180). The cameras
// are not live, so the first calibration itself carries the lens fit: the first panorama (and every
// one after it: a 20-30 frame file ends before a background fit) has the lens. Before, the first
// calibration was pinhole (homographies on a plane, 1280 px: 22 px seams) and the background lens
// fit was cancelled at the end of the file.
TEST(CalibSessionLensShortFile, NonLiveFirstCalibrationHasTheLens) {
  const double k1 = -0.40, k2 = 0.16;
  const int w = 320, h = 180;
  const double f = 0.5 * w / std::tan(40.0 * 3.14159265358979 / 180);
  const Rig truth = testdata::radtan_trio(w, h, f, 45.0, k1, k2, true, "spherical", 0.0);
  Driver d;
  const auto row = [&](int frame) { return frames_of("barrel row", truth, frame); };
  std::optional<JobKind> ran;
  for (int i = 0; i < 10 && !ran; ++i) {
    CalibSession::Frame fr;
    fr.time_s = d.frame / 30.0;
    fr.live = false;
    std::vector<cv::Mat> m = row(d.frame++);
    for (const auto& x : m) fr.sizes.push_back({x.cols, x.rows});
    auto job = d.s.on_frame(fr, d.s.wants_pixels(fr) ? views_of(m) : std::vector<ImageView>());
    if (!job) continue;
    ASSERT_EQ(job->kind, JobKind::First);
    EXPECT_TRUE(job->lens_before_output);
    std::atomic<bool> cancel{false};
    const auto t0 = std::chrono::steady_clock::now();
    const CalibOutcome o = run_calib_job(*job, cancel);
    std::printf("first calibration: %.2f s, lens fit %s%s; precheck %s\n",
                std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
                o.lens_tried ? "tried" : "not tried", o.lens_not_kept.empty() ? "" : (": " + o.lens_not_kept).c_str(),
                o.lens_precheck ? o.lens_precheck->describe().c_str() : "-");
    d.s.on_outcome(o);
    for (auto& e : d.s.take_events()) d.events.push_back(e);
    ran = job->kind;
  }
  ASSERT_TRUE(ran) << "no first calibration";
  ASSERT_TRUE(d.s.current()) << "nothing installed";
  const Rig& rig = *d.s.current();
  const double seams = seam_px(rig, row(0));
  std::printf("installed: %s, k1 %+.3f %+.3f %+.3f, fx %.1f (true %.1f), seams %.3f camera px\n",
              rig_lens_summary(rig).c_str(), rig.cameras[0].lens.k1, rig.cameras[1].lens.k1, rig.cameras[2].lens.k1,
              rig.cameras[1].fx, f, seams);
  ASSERT_EQ(rig_lens_summary(rig), "radtan") << "the first calibration of a non-live barrel row is pinhole";
  for (const auto& c : rig.cameras) EXPECT_NEAR(c.lens.k1, k1, 0.1 * std::abs(k1));
  EXPECT_LT(seams, 0.5);
  for (const auto& j : d.events) EXPECT_FALSE(j.type == SessionEvent::Type::Installed && j.report.source == "lens");

  // Live cameras must not stall: their first calibration stays pinhole (the fit follows in the
  // background, JobKind::Lens).
  CalibSession live;
  SessionConfig c;
  live.set_config(c);
  for (int i = 0; i < 10; ++i) {
    CalibSession::Frame fr;
    fr.time_s = i / 30.0;
    std::vector<cv::Mat> m = row(i);
    for (const auto& x : m) fr.sizes.push_back({x.cols, x.rows});
    if (auto job = live.on_frame(fr, live.wants_pixels(fr) ? views_of(m) : std::vector<ImageView>())) {
      EXPECT_FALSE(job->lens_before_output);
      break;
    }
  }
}
