// The sync core without GStreamer: the start-up and dropout policy, the QoS rate limit, and the
// time aligner on synthetic signals (offsets, a synchronised rig, a static scene, clock drift),
// and on a real clip's frames when the repository's clip decodes (cv::VideoCapture).
#include <gtest/gtest.h>

#include <cmath>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <algorithm>
#include <random>

#include "stitch/rig/rig.hpp"
#include "stitch/sync/policy.hpp"
#include "stitch/sync/thumbnail.hpp"
#include "stitch/sync/time_align.hpp"
#include "synthetic_audio.hpp"
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

// A camera added while the stream runs (a pad requested and linked in PLAYING) is counted from
// the output it first takes part in, not from the start: with the start's clock it would be
// "out" at once.
TEST(SyncPolicy, CameraAddedLaterIsCountedFromWhenItWasAdded) {
  DropoutTrack t;
  t.since = 3000 * kMs;  // added 2 s after the others started at 1 s
  InputFacts linked;
  linked.negotiated = true;  // caps, no frame yet
  std::string why;
  EXPECT_FALSE(update_dropout(t, linked, 3030 * kMs, 1000 * kMs, 500 * kMs, why)) << why;
  EXPECT_FALSE(update_dropout(t, linked, 3400 * kMs, 1000 * kMs, 500 * kMs, why)) << why;
  EXPECT_TRUE(update_dropout(t, linked, 3600 * kMs, 1000 * kMs, 500 * kMs, why));
  EXPECT_EQ(why, "no frame since it was added (600 ms)");
  // there from the start: `since` is the start, and the message says so
  DropoutTrack s;
  s.since = 1000 * kMs;
  EXPECT_TRUE(update_dropout(s, linked, 1600 * kMs, 1000 * kMs, 500 * kMs, why));
  EXPECT_EQ(why, "no frame since the start (600 ms)");
  // without caps
  DropoutTrack n;
  n.since = 3000 * kMs;
  EXPECT_FALSE(update_dropout(n, InputFacts{}, 3100 * kMs, 1000 * kMs, 500 * kMs, why));
  EXPECT_TRUE(update_dropout(n, InputFacts{}, 3700 * kMs, 1000 * kMs, 500 * kMs, why));
  EXPECT_EQ(why, "it never started (no caps after 700 ms)");
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

// Non-live cameras stamped from 100 s start the output there; a start within the timeout (or
// before the output) leaves it where it was; one camera 10 s or more after the others is far apart.
TEST(SyncPolicy, OutputStartsAtTheFirstFramesOnlyWhenTheyAreFarAhead) {
  const int64_t s = 1'000'000'000, timeout = s / 2;
  EXPECT_EQ(first_output_at(100 * s, 0, timeout), 100 * s);
  EXPECT_EQ(first_output_at(s / 4, 0, timeout), kNoTime);
  EXPECT_EQ(first_output_at(0, 0, timeout), kNoTime);
  EXPECT_EQ(first_output_at(3 * s, 4 * s, timeout), kNoTime);
  EXPECT_EQ(first_output_at(kNoTime, 0, timeout), kNoTime);
  EXPECT_TRUE(starts_far_apart(0, 100 * s));
  EXPECT_FALSE(starts_far_apart(0, 3 * s));
  EXPECT_FALSE(starts_far_apart(kNoTime, 100 * s));
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

// A thumbnail made elsewhere (the device, for CUDA-memory inputs) gives the same strips as the
// frame itself: OffsetTracker::add_thumbnail and add_frame feed the same signal.
TEST(FrameSignalTest, ThumbnailPathGivesTheSameStrips) {
  FrameSignal from_frame, from_thumbnail;
  std::vector<uint8_t> img(200 * 90 * 4);
  std::vector<float> thumb(std::size_t(FrameSignal::kThumbW) * FrameSignal::kThumbH);
  for (int k = 0; k < 3; ++k) {
    for (std::size_t i = 0; i < img.size(); ++i) img[i] = uint8_t((i * 7 + std::size_t(k) * 31 * (i % 13)) & 255);
    stitch::sync::frame_thumbnail_cpu(img.data(), 200, 90, 200 * 4, 4, 1, thumb.data());
    EXPECT_EQ(from_frame.update(img.data(), 200, 90, 200 * 4, 4, 1), from_thumbnail.update_thumbnail(thumb.data()))
        << "frame " << k;
  }
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


namespace {

// Every camera of a clip in ../shared as FrameSignal strips (RGBA as stitchsync's system-memory
// views hold it); empty when the clip is not here.
std::vector<std::vector<std::vector<double>>> clip_signals(const std::string& dir, const std::vector<std::string>& files) {
  std::vector<std::vector<std::vector<double>>> sig;
  if (dir.empty()) return sig;
  for (const std::string& f : files) {
    cv::VideoCapture cap(dir + "/" + f);
    if (!cap.isOpened()) return {};
    FrameSignal fs;
    cv::Mat frame, rgba;
    sig.emplace_back();
    while (cap.read(frame)) {
      cv::cvtColor(frame, rgba, cv::COLOR_BGR2RGBA);
      sig.back().push_back(fs.update(rgba.data, rgba.cols, rgba.rows, rgba.step, 4, 1));
    }
  }
  return sig;
}

// The aligner over the cameras' signals, camera v starting trim[v] frames into its clip, fed
// frame by frame; the estimates at the end.
std::vector<Estimate> align_trimmed(const std::vector<std::vector<std::vector<double>>>& sig, const std::vector<int>& trim,
                                    double fps) {
  TimeAligner a(int(sig.size()));
  for (std::size_t f = 0; f < sig[0].size(); ++f)
    for (std::size_t v = 0; v < sig.size(); ++v)
      if (f + std::size_t(trim[v]) < sig[v].size())
        a.add_sample(int(v), int64_t(double(f) / fps * 1e9), sig[v][f + std::size_t(trim[v])]);
  return a.estimate();
}

}  // namespace

// Issue 18's "real 3-camera clip, two cameras trimmed by different numbers of frames at the
// start, offsets within a frame without audio": the house clip (../shared: three webcams, a
// static hall; their only common signal is the instants new frames come, 8 a second written at
// 30, and the exposure's settling). Untrimmed, the three are in step (each pair's whole-frame
// GCC-PHAT peaks at 0 over the 30 s); trimmed, every camera must come out within a frame of its
// trim, and sure of it. The clips without an event common to their cameras (the hallway pair,
// two takes) must say "no signal", never a confident wrong offset, while a camera that repeats
// camera 0 is found exactly.
TEST(TimeAlign, RealClipsTrimmedWithinAFrameOrNoSignal) {
  const double fps = 30;
  const auto house = clip_signals(testdata::shared_path("video/karthik_3cam_house"), {"left.mp4", "middle.mp4", "right.mp4"});
  if (house.empty()) GTEST_SKIP() << "../shared/data is not here (or does not decode)";
  ASSERT_GT(house[0].size(), 800u);
  const auto sync = align_trimmed(house, {0, 0, 0}, fps);
  for (int v = 1; v < 3; ++v) {
    ASSERT_TRUE(sync[std::size_t(v)].valid) << v;
    // a synchronised rig stays at 0 +- 0.5 frame
    EXPECT_NEAR(sync[std::size_t(v)].offset_ns / 1e9 * fps, 0.0, 0.5) << v;
  }
  for (const std::vector<int>& trim : {std::vector<int>{0, 1, 12}, {0, 9, 3}, {0, 17, 30}, {0, 30, 5}, {0, 23, 24}}) {
    const auto e = align_trimmed(house, trim, fps);
    for (int v = 1; v < 3; ++v) {
      ASSERT_TRUE(e[std::size_t(v)].valid) << "trims " << trim[1] << "/" << trim[2] << " view " << v << " confidence "
                                           << e[std::size_t(v)].confidence;
      EXPECT_NEAR(e[std::size_t(v)].offset_ns / 1e9 * fps, trim[std::size_t(v)], 1.0)
          << "trims " << trim[1] << "/" << trim[2] << " view " << v;
    }
  }
  const auto hall = clip_signals(testdata::shared_path("video/unrival_stereo_hallway"), {"left.mp4", "right.mp4"});
  if (hall.empty()) return;
  const std::vector<std::vector<std::vector<double>>> trio = {hall[0], hall[1], hall[0]};
  for (const std::vector<int>& trim : {std::vector<int>{0, 3, 26}, {0, 13, 6}, {0, 14, 13}, {0, 27, 14}, {0, 22, 1}}) {
    const auto e = align_trimmed(trio, trim, fps);
    EXPECT_FALSE(e[1].valid) << "trims " << trim[1] << "/" << trim[2] << ": " << e[1].offset_ns / 1e9 * fps
                             << " frames, confidence " << e[1].confidence;
    EXPECT_EQ(e[1].offset_ns, 0);
    ASSERT_TRUE(e[2].valid);
    EXPECT_NEAR(e[2].offset_ns / 1e9 * fps, trim[2], 0.1);
  }
}

// A strictly periodic scene (a bump every 15 frames: a walker's steps, a blinking light) matches
// at every multiple of the period: whatever lag wins, it must not be trusted. With three cameras
// the chain must not make it surer either.
TEST(TimeAlign, PeriodicSceneIsNotTrusted) {
  for (unsigned seed : {1u, 2u, 3u}) {
    TimeAligner a(3);
    std::mt19937 rng(seed);
    std::normal_distribution<double> n(0, 0.3);
    const int start[3] = {0, 7, -4};
    auto at = [](int f) {
      const double d = double(((f % 15) + 15) % 15) - 7.0;  // a bump in the middle of every period
      return 1.0 + 6.0 * std::exp(-0.5 * d * d / 4.0);
    };
    for (int f = 0; f < 25 * 30; ++f)
      for (int v = 0; v < 3; ++v) a.add_sample(v, int64_t(f) * 1000000000 / 30, at(f + start[v]) + n(rng));
    const auto e = a.estimate();
    for (int v = 1; v < 3; ++v) {
      const double got = e[std::size_t(v)].offset_ns / 1e9 * 30;
      if (e[std::size_t(v)].valid)
        EXPECT_NEAR(got, start[v], 1.0) << "seed " << seed << " view " << v << ": a confident alias, confidence "
                                        << e[std::size_t(v)].confidence;
      else
        EXPECT_EQ(e[std::size_t(v)].offset_ns, 0);
    }
  }
}

// "A synchronised rig stays at 0 +- 0.5 frame with auto": three cameras in step, through the
// tracker the element runs (estimates once a second, offsets applied by offset_at), at every
// second from the 10th to the 35th, not only at the end, and for every seed.
TEST(TimeAlign, SynchronisedRigStaysAtZeroThroughTheTracker) {
  for (unsigned seed : {5u, 6u}) {
    const Scene scene(40, seed);
    OffsetTracker tr(3);
    std::mt19937 rng(seed);
    std::normal_distribution<double> noise(0, 0.4);
    std::vector<Estimate> est;
    std::vector<int> quiet;
    std::vector<uint8_t> img(64 * 36);
    int checked = 0;
    for (int f = 0; f < 35 * 30; ++f) {
      const int64_t t = int64_t(f) * 1000000000 / 30;
      for (int v = 0; v < 3; ++v) {
        // a grey frame whose brightness follows the scene's motion energy (each camera's noise)
        const uint8_t g = uint8_t(std::clamp(60.0 + 10.0 * scene.at(f / 30.0) + noise(rng), 0.0, 255.0));
        std::fill(img.begin(), img.end(), g);
        tr.add_frame(v, t, img.data(), 64, 36, 64, 1, 0);
      }
      tr.update(est, quiet);
      if (f % 30 == 29 && f > 10 * 30)
        for (int v = 1; v < 3; ++v) {
          ASSERT_TRUE(est[std::size_t(v)].valid) << "seed " << seed << " view " << v << " at " << f / 30 << " s";
          EXPECT_NEAR(tr.offset_at(v, t) / 1e9 * 30, 0.0, 0.5) << "seed " << seed << " view " << v << " at " << f / 30 << " s";
          ++checked;
        }
    }
    EXPECT_GT(checked, 40);
  }
}

// The element's live mode: each estimate on a copy in a worker thread. It is taken when done or
// at the latest when the next is due, so it gives the synchronous tracker's estimates at most one
// second of stream time later, whatever the worker's speed.
TEST(TimeAlign, AsynchronousTrackerGivesTheSameEstimatesAtMostASecondLate) {
  const Scene scene(30, 7);
  OffsetTracker sync_tr(2), async_tr(2);
  async_tr.set_asynchronous(true);
  std::vector<Estimate> es, ea;
  std::vector<int> quiet;
  std::vector<uint8_t> img(64 * 36);
  for (int f = 0; f < 30 * 30; ++f) {
    const int64_t t = int64_t(f) * 1000000000 / 30;
    for (int v = 0; v < 2; ++v) {
      // camera 1 started 5 frames late: its frame f shows the scene at f + 5
      const uint8_t g = uint8_t(std::clamp(60.0 + 10.0 * scene.at((f + 5 * v) / 30.0), 0.0, 255.0));
      std::fill(img.begin(), img.end(), g);
      sync_tr.add_frame(v, t, img.data(), 64, 36, 64, 1, 0);
      async_tr.add_frame(v, t, img.data(), 64, 36, 64, 1, 0);
    }
    sync_tr.update(es, quiet);
    async_tr.update(ea, quiet);
    if (f % 30 == 29 && f > 12 * 30) {
      // by now both have settled: the same offset (the asynchronous one from a second earlier)
      ASSERT_TRUE(sync_tr.current()[1].valid);
      ASSERT_TRUE(async_tr.current()[1].valid) << "at " << f / 30 << " s";
      EXPECT_NEAR(async_tr.current()[1].offset_ns / 1e9 * 30, sync_tr.current()[1].offset_ns / 1e9 * 30, 0.5);
      EXPECT_NEAR(std::fabs(async_tr.current()[1].offset_ns / 1e9 * 30), 5.0, 0.5);
    }
  }
}

// ---- audio (AudioAligner, GCC-PHAT) ----

namespace {

// Feeds a camera's recording in 20 ms blocks, timestamped by its own running time from 0.
void feed_audio(AudioAligner& a, int view, const std::vector<float>& x, int rate, int channels, bool as_s16 = false) {
  const std::size_t block = std::size_t(rate / 50), frames = x.size() / std::size_t(channels);
  for (std::size_t f = 0; f < frames; f += block) {
    const std::size_t n = std::min(block, frames - f);
    const int64_t t = int64_t(double(f) / rate * 1e9);
    if (as_s16) {
      std::vector<int16_t> s(n * std::size_t(channels));
      for (std::size_t i = 0; i < s.size(); ++i)
        s[i] = int16_t(std::clamp(x[f * std::size_t(channels) + i] * 32767.f, -32768.f, 32767.f));
      a.add(view, t, s.data(), n, channels, rate);
    } else {
      a.add(view, t, x.data() + f * std::size_t(channels), n, channels, rate);
    }
  }
}

}  // namespace

TEST(AudioAlign, RecoversOffsetsAcrossRatesFormatsAndChannels) {
  const testdata::SoundScene scene(20);
  AudioAligner a(3);
  // camera 1 started 7 frames (of 30 fps) after camera 0, camera 2 0.4 s before it; each with
  // its own microphone (gain, noise about 10 dB under the speech), rate and layout
  feed_audio(a, 0, scene.record(0.0, 48000 * 15, 48000, 2, 1.0f, 0.03f, 1), 48000, 2);
  feed_audio(a, 1, scene.record(7 / 30.0, 44100 * 15, 44100, 1, 0.6f, 0.03f, 2), 44100, 1, true);
  feed_audio(a, 2, scene.record(-0.4, 16000 * 15, 16000, 2, 1.5f, 0.05f, 3), 16000, 2);
  const auto& e = a.estimate();
  ASSERT_EQ(e.size(), 3u);
  ASSERT_TRUE(e[1].valid);
  ASSERT_TRUE(e[2].valid);
  // within a millisecond: a sample at 8 kHz is 0.125 ms
  EXPECT_NEAR(e[1].offset_ns / 1e9, 7 / 30.0, 0.001);
  EXPECT_NEAR(e[2].offset_ns / 1e9, -0.4, 0.001);
  EXPECT_GT(e[1].confidence, 0.8);
  EXPECT_GT(e[2].confidence, 0.8);
}

TEST(AudioAlign, SilenceAndUnrelatedSoundHaveNoConfidence) {
  const testdata::SoundScene scene(12, 3), other(12, 99);
  AudioAligner a(3);
  std::vector<float> silence(48000 * 10, 0.f);
  feed_audio(a, 0, scene.record(0.0, 48000 * 10, 48000, 1, 1.0f, 0.02f, 1), 48000, 1);
  feed_audio(a, 1, silence, 48000, 1);
  feed_audio(a, 2, other.record(0.0, 48000 * 10, 48000, 1, 1.0f, 0.02f, 2), 48000, 1);  // another room
  const auto& e = a.estimate();
  EXPECT_FALSE(e[1].valid);
  EXPECT_LT(e[2].confidence, 0.2);
}

TEST(AudioAlign, APureToneIsAmbiguous) {
  AudioAligner a(2);
  std::vector<float> x0(48000 * 10), x1(48000 * 10);
  for (std::size_t k = 0; k < x0.size(); ++k) {
    x0[k] = 0.3f * std::sin(float(2 * M_PI * 1000.0 * double(k) / 48000));
    x1[k] = 0.3f * std::sin(float(2 * M_PI * 1000.0 * (double(k) / 48000 + 0.1)));
  }
  feed_audio(a, 0, x0, 48000, 1);
  feed_audio(a, 1, x1, 48000, 1);
  // a 1 kHz tone matches every millisecond: whatever peak wins, it must not be trusted
  EXPECT_LT(a.estimate()[1].confidence, 0.5);
}

TEST(AudioAlign, DiscontinuityIsSilenceNotAShift) {
  const testdata::SoundScene scene(20, 5);
  AudioAligner a(2);
  feed_audio(a, 0, scene.record(0.0, 48000 * 15, 48000, 1, 1.0f, 0.02f, 1), 48000, 1);
  // camera 1 (started 0.25 s late) loses 0.5 s at 5 s: the blocks after it are timestamped
  // where they belong
  const std::vector<float> x = scene.record(0.25, 48000 * 15, 48000, 1, 1.0f, 0.02f, 2);
  std::vector<float> head(x.begin(), x.begin() + 48000 * 5), tail(x.begin() + 48000 * 5 + 24000, x.end());
  feed_audio(a, 1, head, 48000, 1);
  for (std::size_t f = 0; f < tail.size(); f += 960)
    a.add(1, int64_t((5.5 + double(f) / 48000) * 1e9), tail.data() + f, std::min<std::size_t>(960, tail.size() - f), 1, 48000);
  const auto& e = a.estimate();
  ASSERT_TRUE(e[1].valid);
  EXPECT_NEAR(e[1].offset_ns / 1e9, 0.25, 0.001);
}

// Audio takes over where it is sure: a static scene (no motion to align on) with sound.
TEST(AudioAlign, TrackerTakesTheAudioOffsetWhereVisionHasNone) {
  const testdata::SoundScene scene(14, 9);
  AudioAligner audio(2);
  feed_audio(audio, 0, scene.record(0.0, 48000 * 12, 48000, 1, 1.0f, 0.02f, 1), 48000, 1);
  feed_audio(audio, 1, scene.record(0.3, 48000 * 12, 48000, 1, 1.0f, 0.02f, 2), 48000, 1);
  OffsetTracker tr(2);
  std::vector<uint8_t> img(64 * 36, 100);
  std::vector<Estimate> est;
  std::vector<int> quiet;
  for (int f = 0; f < 360; ++f) {
    for (int v = 0; v < 2; ++v) tr.add_frame(v, int64_t(f) * 33333333, img.data(), 64, 36, 64, 1, 0);
    tr.update(est, quiet, &audio.estimate());
  }
  ASSERT_EQ(est.size(), 2u);
  ASSERT_TRUE(est[1].valid);
  EXPECT_EQ(est[1].source, OffsetSource::Audio);
  EXPECT_NEAR(est[1].offset_ns / 1e9, 0.3, 0.001);
  EXPECT_NEAR(tr.offset_at(1, 5000000000) / 1e9, 0.3, 0.001);
  // without the audio, nothing to align on
  OffsetTracker blind(2);
  for (int f = 0; f < 360; ++f) {
    for (int v = 0; v < 2; ++v) blind.add_frame(v, int64_t(f) * 33333333, img.data(), 64, 36, 64, 1, 0);
    blind.update(est, quiet);
  }
  EXPECT_FALSE(est[1].valid);
}

namespace {

// Two cameras' sound over `seconds` of camera 0's clock, fed interleaved in 20 ms blocks as the
// element gets them, with an estimate every 5 s; camera 1 started `start` s after camera 0
// and its clock runs `speed` times as fast.
const std::vector<AudioEstimate>& feed_drifting(AudioAligner& a, double seconds, double start, double speed,
                                                unsigned seed) {
  const testdata::SoundScene scene(seconds + 5, seed);
  const int rate0 = 48000, rate1 = 44100;
  const std::vector<float> x0 = scene.record(0.0, std::size_t(seconds * rate0), rate0, 1, 1.0f, 0.03f, 1);
  const std::vector<float> x1 = scene.record(start, std::size_t(seconds * rate1), rate1, 1, 0.7f, 0.03f, 2, speed);
  for (int block = 0; block < int(seconds * 50); ++block) {
    a.add(0, int64_t(block) * 20000000, x0.data() + std::size_t(block) * 960, 960, 1, rate0);
    a.add(1, int64_t(block) * 20000000, x1.data() + std::size_t(block) * 882, 882, 1, rate1);
    if (block % 250 == 249) a.estimate();  // every 5 s (the element: every second)
  }
  return a.estimate();
}

}  // namespace

// Clock drift from the sound (issue 18): camera 1's clock runs 0.5% fast (or slow), and it was
// started 10 frames late. Over 2 minutes the audio's windowed offsets give the rate, and the
// offset now (drift included) within half a frame; view 0 seconds per camera-1 second is 1/speed.
TEST(AudioAlign, HalfPercentRateDifferenceOverTwoMinutes) {
  for (const double speed : {1.005, 0.995}) {
    AudioAligner a(2);
    const auto& e = feed_drifting(a, 120, 10 / 30.0, speed, 31);
    ASSERT_TRUE(e[1].valid) << speed;
    ASSERT_TRUE(e[1].rate_valid) << speed;
    std::printf("speed %.3f: rate %.6f (want %.6f, error %.2e), offset at the end %+.3f ms off, confidence %.2f\n", speed,
                e[1].rate, 1.0 / speed, e[1].rate - 1.0 / speed,
                (e[1].offset_ns / 1e9 - (10 / 30.0 + (1.0 / speed - 1.0) * (120.0 - 0.02))) * 1e3, e[1].confidence);
    EXPECT_NEAR(e[1].rate, 1.0 / speed, 0.0005) << speed;
    EXPECT_NEAR(e[1].rate, 1.0 / speed, 0.00005) << speed << ": the line should be far better than the target";
    // camera 1's time t_b shows scene time start + t_b / speed: offset(t_b) = start + (1/speed - 1) t_b
    const double t_b_end = 120.0 - 0.02;
    EXPECT_NEAR(e[1].offset_ns / 1e9, 10 / 30.0 + (1.0 / speed - 1.0) * t_b_end, 0.5 / 30) << speed;
    EXPECT_NEAR(e[1].offset_ns / 1e9, 10 / 30.0 + (1.0 / speed - 1.0) * t_b_end, 0.002) << speed;
    EXPECT_NEAR(e[1].base_offset_ns / 1e9, 10 / 30.0, 0.002) << speed;
    EXPECT_GE(e[1].confidence, AlignSettings{}.audio_min_confidence) << speed;
    // the tracker applies the audio's line: offset(t) = base + (rate - 1) t at any time
    OffsetTracker tr(2);
    std::vector<uint8_t> img(64 * 36, 100);
    std::vector<Estimate> est;
    std::vector<int> quiet;
    for (int f = 0; f < 40; ++f) {
      for (int v = 0; v < 2; ++v) tr.add_frame(v, int64_t(f) * 33333333, img.data(), 64, 36, 64, 1, 0);
      tr.update(est, quiet, &e);
    }
    ASSERT_TRUE(est[1].valid);
    EXPECT_EQ(est[1].source, OffsetSource::Audio);
    EXPECT_NEAR(est[1].rate, 1.0 / speed, 0.00005);
    for (double t : {0.0, 60.0, 120.0})
      EXPECT_NEAR(tr.offset_at(1, int64_t(t * 1e9)) / 1e9, 10 / 30.0 + (1.0 / speed - 1.0) * t, 0.002) << t;
  }
}

// A synchronised rig's sound: rate 1 (no drift applied) and the offset stays at 0.
TEST(AudioAlign, SynchronisedClocksShowNoDrift) {
  AudioAligner a(2);
  const auto& e = feed_drifting(a, 60, 0.0, 1.0, 32);
  ASSERT_TRUE(e[1].valid);
  EXPECT_TRUE(e[1].rate_valid);
  EXPECT_DOUBLE_EQ(e[1].rate, 1.0);
  EXPECT_NEAR(e[1].offset_ns / 1e9, 0.0, 0.001);
}

// A real clip (../shared: the hallway stereo pair, a person walking) as three cameras: left,
// right, and left again; cameras 1 and 2 trimmed by 4 and 9 frames at the start as if started
// later. Each camera also records a synthetic sound track (speech-like noise over a tone, its own
// microphone), trimmed like its video. Without audio (vision) camera 2 (camera 0's own video) is
// recovered within a frame, camera 1 within a frame of the untrimmed run's estimate or not at all
// (its strips disagree: low confidence); with audio both within half a frame, absolutely.
TEST(AudioAlign, RealClipThreeCamerasTrimmedWithAndWithoutAudio) {
  const std::string dir = testdata::shared_path("video/unrival_stereo_hallway");
  if (dir.empty()) GTEST_SKIP() << "../shared/data is not here";
  std::vector<std::vector<double>> sig[2];
  for (int v = 0; v < 2; ++v) {
    cv::VideoCapture cap(dir + (v == 0 ? "/left.mp4" : "/right.mp4"));
    if (!cap.isOpened()) GTEST_SKIP() << "the clip does not decode here";
    FrameSignal fs;
    cv::Mat frame, rgba;
    while (cap.read(frame)) {
      cv::cvtColor(frame, rgba, cv::COLOR_BGR2RGBA);
      sig[v].push_back(fs.update(rgba.data, rgba.cols, rgba.rows, rgba.step, 4, 1));
    }
  }
  ASSERT_GT(sig[0].size(), 300u);
  const std::vector<const std::vector<std::vector<double>>*> cams = {&sig[0], &sig[1], &sig[0]};
  const double fps = 30;
  auto vision = [&](const std::vector<int>& trim) {
    TimeAligner a(3);
    for (std::size_t f = 0; f < sig[0].size(); ++f)
      for (int v = 0; v < 3; ++v)
        if (f + std::size_t(trim[std::size_t(v)]) < cams[std::size_t(v)]->size())
          a.add_sample(v, int64_t(double(f) / fps * 1e9), (*cams[std::size_t(v)])[f + std::size_t(trim[std::size_t(v)])]);
    return a.estimate();
  };
  const std::vector<int> trim = {0, 4, 9};
  const auto base = vision({0, 0, 0}), e = vision(trim);
  ASSERT_TRUE(e[2].valid);
  EXPECT_NEAR(e[2].offset_ns / 1e9 * fps, 9.0, 1.0);
  // the stereo pair's strips disagree (a person seen by each camera at another time): vision
  // must either find the trim or say it has nothing, never apply a confident wrong offset
  if (e[1].valid && base[1].valid) EXPECT_NEAR((e[1].offset_ns - base[1].offset_ns) / 1e9 * fps, 4.0, 1.0);
  if (!e[1].valid) EXPECT_EQ(e[1].offset_ns, 0);
  // audio
  const double seconds = double(sig[0].size()) / fps;
  const testdata::SoundScene scene(seconds + 2, 11);
  AudioAligner audio(3);
  for (int v = 0; v < 3; ++v) {
    const int rate = v == 1 ? 44100 : 48000;
    const std::size_t n = std::size_t((double(cams[std::size_t(v)]->size()) - trim[std::size_t(v)]) / fps * rate);
    feed_audio(audio, v, scene.record(trim[std::size_t(v)] / fps, n, rate, 1, 0.6f + 0.3f * float(v), 0.03f, unsigned(v + 1)),
               rate, 1);
  }
  const auto& ae = audio.estimate();
  for (int v = 1; v < 3; ++v) {
    ASSERT_TRUE(ae[std::size_t(v)].valid) << v;
    EXPECT_GE(ae[std::size_t(v)].confidence, AlignSettings{}.audio_min_confidence) << v;
    EXPECT_NEAR(ae[std::size_t(v)].offset_ns / 1e9 * fps, trim[std::size_t(v)], 0.5) << v;
  }
}

// A silent non-live input: gaps only after the timeout, only while it has delivered nothing,
// never in a live pipeline, kept just ahead of the output.
TEST(SyncPolicy, StandInGapsForASilentNonLiveInput) {
  const int64_t span = 250 * kMs, timeout = 500 * kMs;
  StandIn s;
  int64_t start = -1;
  EXPECT_FALSE(standin_gap_due(s, false, false, kNoTime, timeout, kNoTime, span, start));  // nothing came in
  EXPECT_FALSE(standin_gap_due(s, false, false, 400 * kMs, timeout, kNoTime, span, start));  // too early
  EXPECT_FALSE(standin_gap_due(s, true, false, 900 * kMs, timeout, kNoTime, span, start));   // live
  EXPECT_FALSE(standin_gap_due(s, false, true, 900 * kMs, timeout, kNoTime, span, start));   // delivered
  ASSERT_TRUE(standin_gap_due(s, false, false, 600 * kMs, timeout, kNoTime, span, start));
  EXPECT_EQ(start, 0);
  EXPECT_FALSE(standin_gap_due(s, false, false, 600 * kMs, timeout, 0, span, start));  // a span ahead already
  ASSERT_TRUE(standin_gap_due(s, false, false, 700 * kMs, timeout, 100 * kMs, span, start));
  EXPECT_EQ(start, span);
  EXPECT_FALSE(standin_gap_due(s, false, false, 700 * kMs, timeout, 200 * kMs, span, start));
  // the output jumped ahead (a seek): the next gap starts there
  ASSERT_TRUE(standin_gap_due(s, false, false, 800 * kMs, timeout, 5000 * kMs, span, start));
  EXPECT_EQ(start, 5000 * kMs);
}
