// The sync core without GStreamer: the start-up and dropout policy, the QoS rate limit, and the
// time aligner on synthetic signals (offsets, a synchronised rig, a static scene, clock drift),
// and on a real clip's frames when the repository's clip decodes (cv::VideoCapture).
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <random>

#include "stitch/rig/rig.hpp"
#include "stitch/sync/policy.hpp"
#include "stitch/sync/time_align.hpp"
#include "synthetic_rig.hpp"
#include "test_data.hpp"

using namespace stitch::sync;

namespace {

constexpr int64_t kMs = 1000000;

InputFacts frame_until(int64_t end, bool queued = false) {
  InputFacts f;
  f.negotiated = f.has_frame = true;
  f.frame_end = end;
  f.queued = queued;
  return f;
}

}  // namespace

TEST(SyncPolicy, DeadCameraDropsOutAfterTheTimeoutFromTheStart) {
  DropoutTrack t;
  InputFacts dead;  // no caps, no frame
  std::string why;
  EXPECT_FALSE(update_dropout(t, dead, 1000 * kMs, 1000 * kMs, 500 * kMs, why));
  EXPECT_FALSE(update_dropout(t, dead, 1400 * kMs, 1000 * kMs, 500 * kMs, why));
  EXPECT_TRUE(update_dropout(t, dead, 1600 * kMs, 1000 * kMs, 500 * kMs, why));
  EXPECT_TRUE(t.dropped);
  EXPECT_NE(why.find("never started"), std::string::npos) << why;
  // it starts: back
  EXPECT_TRUE(update_dropout(t, frame_until(1650 * kMs), 1640 * kMs, 1000 * kMs, 500 * kMs, why));
  EXPECT_FALSE(t.dropped);
  EXPECT_TRUE(why.empty());
}

TEST(SyncPolicy, StallDropsOutButATimestampGapDoesNot) {
  DropoutTrack t;
  std::string why;
  // the newest frame ended 600 ms ago: with nothing queued a stall, with a later frame waiting a gap
  EXPECT_FALSE(update_dropout(t, frame_until(400 * kMs, true), 1000 * kMs, 0, 500 * kMs, why));
  EXPECT_FALSE(t.dropped);
  EXPECT_TRUE(update_dropout(t, frame_until(400 * kMs, false), 1000 * kMs, 0, 500 * kMs, why));
  EXPECT_NE(why.find("no frame for 600 ms"), std::string::npos) << why;
  // frames queued for later do not bring it back; a fresh frame does
  EXPECT_FALSE(update_dropout(t, frame_until(400 * kMs, true), 1100 * kMs, 0, 500 * kMs, why));
  EXPECT_TRUE(t.dropped);
  EXPECT_TRUE(update_dropout(t, frame_until(1150 * kMs), 1120 * kMs, 0, 500 * kMs, why));
  EXPECT_FALSE(t.dropped);
  // ended
  InputFacts ended;
  ended.negotiated = ended.eos = true;
  DropoutTrack e;
  EXPECT_TRUE(update_dropout(e, ended, 0, 0, 500 * kMs, why));
  EXPECT_EQ(why, "it ended");
}

TEST(SyncPolicy, StartWaitsForEveryRequestedPad) {
  InputFacts ok, late;
  ok.negotiated = true;
  EXPECT_EQ(may_start({ok, ok, late}, 10 * kMs, 500 * kMs), StartDecision::Wait);
  EXPECT_EQ(may_start({ok, ok, ok}, 10 * kMs, 500 * kMs), StartDecision::Go);
  EXPECT_EQ(may_start({ok, ok, late}, 600 * kMs, 500 * kMs), StartDecision::Go);
  EXPECT_EQ(may_start({ok}, 10 * kMs, 500 * kMs), StartDecision::Wait);
  EXPECT_EQ(may_start({ok}, 600 * kMs, 500 * kMs), StartDecision::TooFew);
  EXPECT_EQ(may_start({late, late}, 600 * kMs, 500 * kMs), StartDecision::Wait);
}

TEST(SyncPolicy, RateLimitHoldsBackRepeats) {
  RateLimit r(1000 * kMs);
  uint64_t held = 99;
  EXPECT_TRUE(r.allow(0, &held));
  EXPECT_EQ(held, 0u);
  for (int i = 1; i < 30; ++i) EXPECT_FALSE(r.allow(i * 33 * kMs));
  EXPECT_TRUE(r.allow(1001 * kMs, &held));
  EXPECT_EQ(held, 29u);
}

TEST(SyncRig, TimeOffsetRoundTripsThroughJson) {
  stitch::Rig rig = testdata::shifted_rig(2, 64, 48, 40);
  rig.cameras[1].time_offset_ns = -123456789;
  const stitch::Rig back = stitch::rig_from_json_string(stitch::rig_to_json_string(rig));
  EXPECT_FALSE(back.cameras[0].time_offset_ns.has_value());
  ASSERT_TRUE(back.cameras[1].time_offset_ns.has_value());
  EXPECT_EQ(*back.cameras[1].time_offset_ns, -123456789);
  std::string text = stitch::rig_to_json_string(rig);
  text.replace(text.find("-123456789"), 10, "\"soon\"    ");
  EXPECT_THROW(stitch::rig_from_json_string(text), stitch::RigError);
}

// ---------------------------------------------------------------------------------------------
// Synthetic scenes: a common event signal (bursts of motion at random instants) seen by every
// camera with its own noise, sampled at each camera's frame times.

namespace {

struct Scene {
  std::vector<double> event_t, event_a;
  explicit Scene(double seconds, unsigned seed = 7) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(0, 1);
    for (double t = 0; t < seconds + 10; t += 0.2 + 0.8 * u(rng)) {
      event_t.push_back(t);
      event_a.push_back(2 + 8 * u(rng));
    }
  }
  // motion energy at scene time t: each event a short bump
  double at(double t) const {
    double v = 1.0;
    for (std::size_t i = 0; i < event_t.size(); ++i) {
      const double d = (t - event_t[i]) / 0.08;
      if (std::fabs(d) < 4) v += event_a[i] * std::exp(-0.5 * d * d);
    }
    return v;
  }
};

// Camera: its clock reads t_cam = (t_scene - start) * rate; frames every 1/fps of its clock.
struct Cam {
  double start, rate;
  unsigned seed;
};

// Feeds every camera frame by frame, interleaved as an element gets them, for `seconds` of
// camera 0's clock; each sees the scene with its own noise.
void feed(TimeAligner& a, const Scene& s, const std::vector<Cam>& cams, double seconds, double noise,
          double fps = 30) {
  std::vector<std::mt19937> rng;
  for (const Cam& c : cams) rng.emplace_back(c.seed);
  std::normal_distribution<double> n(0, noise);
  for (int f = 0; f < int(seconds * fps); ++f)
    for (std::size_t v = 0; v < cams.size(); ++v) {
      const double t_cam = f / fps;
      const double t_scene = t_cam / cams[v].rate + cams[v].start;
      a.add_sample(int(v), int64_t(std::llround(t_cam * 1e9)), s.at(t_scene) + n(rng[v]));
    }
}

}  // namespace

TEST(TimeAlign, RecoversStartOffsetsWithinAFrame) {
  const Scene scene(30);
  TimeAligner a(3);
  // camera 1 started 7 frames after camera 0, camera 2 started 12 frames before it
  feed(a, scene, {{0.0, 1.0, 1}, {7 / 30.0, 1.0, 2}, {-12 / 30.0, 1.0, 3}}, 25, 0.3);
  const auto e = a.estimate();
  ASSERT_EQ(e.size(), 3u);
  ASSERT_TRUE(e[1].valid);
  ASSERT_TRUE(e[2].valid);
  // camera 1's frame t shows scene time t + 7/30: it must be shown 7 frames later: +7 frames
  EXPECT_NEAR(e[1].offset_ns / 1e9 * 30, 7.0, 0.25);
  EXPECT_NEAR(e[2].offset_ns / 1e9 * 30, -12.0, 0.25);
  EXPECT_GT(e[1].confidence, 0.5);
  EXPECT_DOUBLE_EQ(e[1].rate, 1.0);
}

TEST(TimeAlign, SubFrameOffsetByParabolicPeak) {
  const Scene scene(30, 11);
  TimeAligner a(2);
  feed(a, scene, {{0.0, 1.0, 1}, {0.4 / 30.0, 1.0, 2}}, 25, 0.2);  // 0.4 frame
  const auto e = a.estimate();
  ASSERT_TRUE(e[1].valid);
  EXPECT_NEAR(e[1].offset_ns / 1e9 * 30, 0.4, 0.2);
}

TEST(TimeAlign, SynchronisedRigStaysAtZero) {
  for (unsigned seed : {1u, 2u, 3u, 4u}) {
    const Scene scene(30, seed);
    TimeAligner a(2);
    feed(a, scene, {{0, 1.0, seed * 10}, {0, 1.0, seed * 10 + 1}}, 25, 0.5);
    const auto e = a.estimate();
    ASSERT_TRUE(e[1].valid) << seed;
    EXPECT_NEAR(e[1].offset_ns / 1e9 * 30, 0.0, 0.5) << seed;
  }
}

TEST(TimeAlign, StaticSceneHasNoConfidence) {
  TimeAligner a(2);
  std::mt19937 rng(5);
  std::normal_distribution<double> n(0, 0.02);
  for (int f = 0; f < 600; ++f) {
    a.add_sample(0, int64_t(f) * 33333333, 0.5 + n(rng));
    a.add_sample(1, int64_t(f) * 33333333, 0.5 + n(rng));
  }
  const auto e = a.estimate();
  EXPECT_FALSE(e[1].valid);
  EXPECT_LT(e[1].confidence, 0.25);
  EXPECT_EQ(e[1].offset_ns, 0);
}

TEST(TimeAlign, HalfPercentRateDifferenceOverTwoMinutes) {
  const Scene scene(130, 21);
  TimeAligner a(2);
  // camera 1's clock runs 0.5% slow and it started 10 frames late: its t_cam = (t - 1/3)*0.995
  feed(a, scene, {{0.0, 1.0, 1}, {10 / 30.0, 0.995, 2}}, 120, 0.3);
  const auto e = a.estimate();
  ASSERT_TRUE(e[1].valid);
  // view 0 seconds per camera-1 second: 1 / 0.995
  EXPECT_NEAR(e[1].rate, 1.0 / 0.995, 0.0005);
  // the offset at the end: camera 1 at t_cam shows scene t_cam/0.995 + 1/3
  const double t_cam_end = 3599 / 30.0;
  const double want = t_cam_end / 0.995 + 10 / 30.0 - t_cam_end;
  EXPECT_NEAR(e[1].offset_ns / 1e9, want, 0.5 / 30);
  EXPECT_NEAR(e[1].base_offset_ns / 1e9, 10 / 30.0, 0.5 / 30);
}

TEST(FrameSignalTest, MotionEnergyOfAThumbnail) {
  FrameSignal s;
  std::vector<uint8_t> img(64 * 48 * 4, 100);
  EXPECT_EQ(s.update(img.data(), 64, 48, 64 * 4, 4, 1), std::vector<double>(FrameSignal::kStrips, 0.0));
  EXPECT_EQ(s.update(img.data(), 64, 48, 64 * 4, 4, 1), std::vector<double>(FrameSignal::kStrips, 0.0));
  // the right half brightens by 10 levels: the right strips move, the left ones do not
  for (int y = 0; y < 48; ++y)
    for (int x = 32; x < 64; ++x) img[std::size_t(y * 64 + x) * 4 + 1] = 110;
  const std::vector<double> strips = s.update(img.data(), 64, 48, 64 * 4, 4, 1);
  ASSERT_EQ(strips.size(), std::size_t(FrameSignal::kStrips));
  for (int i = 0; i < FrameSignal::kStrips; ++i)
    EXPECT_NEAR(strips[std::size_t(i)], i < FrameSignal::kStrips / 2 ? 0.0 : 10.0, 1e-6) << i;
}

// A real clip (the repository's two phones), camera 1 trimmed at its start as if started later.
TEST(TimeAlign, RealClipWithoutCommonMotionIsNotGuessed) {
  cv::VideoCapture left(testdata::repo_path("data/limlight_2cam_apartment/left.mp4"));
  cv::VideoCapture right(testdata::repo_path("data/limlight_2cam_apartment/right.mp4"));
  if (!left.isOpened() || !right.isOpened()) GTEST_SKIP() << "the clip does not decode here";
  std::vector<std::vector<double>> sig[2];
  FrameSignal fs[2];
  cv::Mat frame, grey;
  for (int v = 0; v < 2; ++v) {
    cv::VideoCapture& cap = v == 0 ? left : right;
    while (cap.read(frame)) {
      cv::cvtColor(frame, grey, cv::COLOR_BGR2GRAY);
      sig[v].push_back(fs[v].update(grey.data, grey.cols, grey.rows, grey.step, 1, 0));
    }
  }
  ASSERT_GT(sig[0].size(), 200u);
  // The phones film a far, nearly still scene (a few cars): too little common motion in 7.5 s
  // to align on. Whatever the trim, the aligner must say so rather than apply a guess.
  for (int trim : {0, 5, 9, 11}) {
    TimeAligner a(2);
    for (std::size_t f = 0; f < sig[0].size(); ++f) {
      a.add_sample(0, int64_t(f) * 33333333, sig[0][f]);
      if (f + std::size_t(trim) < sig[1].size()) a.add_sample(1, int64_t(f) * 33333333, sig[1][f + std::size_t(trim)]);
    }
    const Estimate e = a.estimate()[1];
    EXPECT_FALSE(e.valid) << "trim " << trim << ": offset " << e.offset_ns / 1e6 << " ms, confidence " << e.confidence;
    EXPECT_EQ(e.offset_ns, 0);
  }
}
