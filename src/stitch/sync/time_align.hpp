// Time alignment of cameras that were not started together (phones, action cameras, webcams
// recorded by separate processes): each input's offset to view 0, and its clock rate, from
// what the cameras see.
//
// Signals: per view, one sample per input frame: the mean absolute difference between the frame
// and the one before it (a motion energy: a person walking, the rig moving, a light switched on
// changes every view at the same instant) on a small grey thumbnail (`frame_signal`). Any other
// per-frame or per-audio-block value works too (`add_sample`).
//
// Offsets: the signals are resampled onto one grid, high-passed (slow drifts in exposure are not
// events), and cross-correlated with view 0's over the newest window; the peak of the normalised
// cross-correlation, refined between grid steps by a parabola through it and its neighbours, is
// the offset. Confidence (0..1): the peak's correlation, lowered when another peak comes close
// (a periodic scene) or when the view barely moves (a static scene: 0).
//
// Clock drift: offsets are measured in consecutive windows; a straight line through them
// (weighted by confidence) gives offset(t) = offset + (rate - 1) * t. The line is refitted from
// all windows each time, so the correction never accumulates error.
//
// Conventions (the `stitchsync-time-offsets` contract): offset-N is in ns, with GstPad offset
// semantics: the value added to view N's running time so that its frames line up with view 0's.
// A camera started d seconds after view 0 has offset +d. rate-N is how many seconds of view 0's
// clock pass per second of view N's (1 when the clocks agree).
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <future>
#include <limits>
#include <vector>

#include "stitch/sync/audio_align.hpp"
#include "stitch/sync/thumbnail_math.hpp"

namespace stitch::sync {

struct AlignSettings {
  double max_offset_s = 3.0;    // offsets searched in [-max, +max]
  double window_s = 20.0;       // newest signal span correlated
  double min_signal_s = 4.0;    // no estimate before this much overlapping signal
  double step_s = 0.0;          // grid step; 0: the median frame interval of view 0
  double min_confidence = 0.3;  // below: the view has no usable signal (offset kept at 0)
  double drift_window_s = 20.0; // span of one offset measurement for the drift fit
  double min_drift_span_s = 40.0;  // rates are fitted once the measurements span this long
  double audio_min_confidence = 0.5;  // an audio estimate at least this sure replaces vision's
  // each view's first samples are left out: a camera's own start (exposure settling, a burst of
  // blocks as the encoder starts) is no scene event, and two streams that start at the same
  // running time would line up on it whatever their true offset
  double skip_start_s = 1.0;
};

enum class OffsetSource { None, Vision, Audio };

struct Estimate {
  int64_t offset_ns = 0;  // at the newest time (drift included): add to the view's running time
  double confidence = 0;  // 0..1
  double rate = 1.0;      // view 0 seconds per view N second
  int64_t base_offset_ns = 0;  // the fitted line's value at view-N time 0 (what a file stores)
  bool valid = false;     // confidence >= min_confidence
  OffsetSource source = OffsetSource::None;  // what the offset was measured from
};

// Motion energy of a frame: the mean absolute difference (0..255) of a grey thumbnail against
// the previous one of the same view, in kStrips vertical strips (left to right), so that the
// strips in the overlap of two views, which see the same events at the same instant, can be
// told from the rest (a person crossing the rig is seen by each camera at another time). Reads
// an 8-bit plane (`bytes_per_pixel` apart, `channel` of each: 4 and 1 for the G of RGBA, 1 and 0
// for a Y plane). The first frame of a view gives zeros.
class FrameSignal {
 public:
  static constexpr int kThumbW = kThumbnailW, kThumbH = kThumbnailH, kStrips = 8;
  std::vector<double> update(const uint8_t* data, int width, int height, std::size_t pitch, int bytes_per_pixel,
                             int channel);
  // The same from a thumbnail made elsewhere (kThumbW x kThumbH cells, e.g. on the device).
  std::vector<double> update_thumbnail(const float* thumbnail);
  void reset() { prev_.clear(); }

 private:
  std::vector<double> strips_from_current();
  std::vector<float> prev_, cur_;
};

class TimeAligner {
 public:
  explicit TimeAligner(int n_views, AlignSettings settings = {});
  int views() const { return int(signals_.size()); }
  // One sample of view `view` at its own (uncorrected) running time `t_ns`: one value per
  // channel (FrameSignal's strips; one for an audio envelope). Every sample of a view has the
  // same number of channels.
  void add_sample(int view, int64_t t_ns, const std::vector<double>& values);
  void add_sample(int view, int64_t t_ns, double value) { add_sample(view, t_ns, std::vector<double>{value}); }
  // Estimates for every view (view 0: 0 offset, confidence 1 when it has signal, rate 1).
  std::vector<Estimate> estimate();
  // Forgets the signals (a seek, a flush).
  void reset();
  // Newest sample time (s) of a view; 0 without samples.
  double newest_s(int view) const;

  // Lower level, exposed for the tests: offset of `b` relative to `a` (b's time + offset =
  // a's time) over [from, to) of a's time, with a confidence; false when there is too little.
  // phat_from_s: where the whole-frame correlation starts (earlier than from_s: a longer span).
  bool correlate(int a, int b, double from_s, double to_s, double& offset_s, double& confidence,
                 double phat_from_s = std::numeric_limits<double>::quiet_NaN()) const;

 private:
  struct Sample {
    double t;
    std::vector<double> v;
  };
  double step_s() const;
  void measure_windows(int view);
  std::vector<double> resample(int view, int channel, double from_s, double to_s, double step) const;
  // The whole-frame GCC-PHAT of b against a over [from, to) of a's time, in units of its own
  // spread away from the peak (a z-score per lag, -lag_max..lag_max); empty without signal.
  std::vector<double> whole_curve(int a, int b, double from_s, double to_s) const;
  struct Measurement {
    double t_b, offset, confidence;  // view-b time at the window's middle, offset there
  };
  AlignSettings settings_;
  std::vector<std::deque<Sample>> signals_;
  std::vector<double> start_t_;  // per view: the time its samples started (NaN: not yet)
  std::vector<std::vector<Measurement>> drift_;  // per view: one per completed drift window
  double drift_origin_ = 0;                       // view-0 time the drift windows start at
  bool have_origin_ = false;
  double keep_s_;
};

}  // namespace stitch::sync

namespace stitch::sync {

// What an element runs with time-alignment=auto: per-view frame signals, an estimate once per
// second of view 0's time, the offsets to apply, and when to tell the application.
class OffsetTracker {
 public:
  explicit OffsetTracker(int n_views, AlignSettings settings = {});
  int views() const { return aligner_.views(); }
  // A new frame of `view` at its uncorrected running time (8-bit plane as FrameSignal reads it).
  void add_frame(int view, int64_t t_ns, const uint8_t* data, int width, int height, std::size_t pitch,
                 int bytes_per_pixel, int channel);
  // The same from the frame's thumbnail (FrameThumbnailer, on the device for CUDA memory).
  void add_thumbnail(int view, int64_t t_ns, const float* thumbnail);
  // Re-estimates when a second has passed since the last estimate; true when the estimates
  // moved enough to be announced again (or for the first time). `no_signal` turns true once,
  // when a view still has nothing to align on after a whole window.
  // `audio` (optional): the audio estimates (AudioAligner); a view whose audio estimate is at
  // least `audio_min_confidence` sure takes its offset from the audio (sharper), otherwise the
  // vision estimate stands. The rate is the audio's drift line once it has one (AudioEstimate::rate_valid),
  // else vision's.
  bool update(std::vector<Estimate>& estimates, std::vector<int>& no_signal,
              const std::vector<AudioEstimate>* audio = nullptr);
  // The offset (ns) to add to `view`'s running time at its uncorrected time t_ns (drift
  // included); 0 while the view has no valid estimate.
  int64_t offset_at(int view, int64_t t_ns) const;
  const std::vector<Estimate>& current() const { return current_; }
  void reset();
  // true: each estimate runs on a copy of the signals in a worker thread (tens of ms once a
  // second: a live stream's thread must not stall) and update() takes it when it is done, a
  // frame or a few later, or waits for it when the next one is due; false (the default,
  // deterministic): update() estimates in place.
  void set_asynchronous(bool on) { asynchronous_ = on; }

 private:
  void add_strips(int view, int64_t t_ns, const std::vector<double>& strips);
  TimeAligner aligner_;
  AlignSettings settings_;
  std::vector<FrameSignal> signals_;
  std::vector<Estimate> current_, announced_;
  std::vector<bool> warned_;
  int64_t last_estimate_ = -1, first_t_ = -1, newest_t_ = -1;
  bool asynchronous_ = false;
  std::future<std::vector<Estimate>> pending_;  // the estimate running in a worker (asynchronous_)
};

}  // namespace stitch::sync
