// Time alignment from the cameras' audio (issue 18): when the inputs carry sound, a clap, a voice
// or street noise reaches every microphone within a millisecond or so (the rig is small), so the
// offset between two recordings is the lag that best lines their sound up, far sharper than what
// the motion in the frames gives (a frame is 33 ms; here a sample is 0.125 ms).
//
// Method: each view's audio is downmixed to mono and resampled to a fixed rate (8 kHz: speech and
// noise carry enough there; cheap), kept for a minute. Once a second the newest common window of
// view 0 is cross-correlated with view N's over lags +-max_offset by GCC-PHAT (the cross-spectrum
// whitened to unit magnitude: a sharp peak whatever the spectrum, robust to the microphones'
// different colouring), the peak refined by a parabola, and its confidence taken from the
// peak-to-sidelobe ratio (the peak against the mean and spread of the correlation away from it):
// silence, or sound that only one camera hears, gives no distinct peak.
//
// Conventions as in time_align.hpp: offset-N is the value (ns) added to view N's running time so
// that it lines up with view 0 (a camera started d s later: +d). Times are the audio's own
// (uncorrected) running times, on the same clock as the view's video.
#pragma once

#include <cstddef>
#include <cstdint>
#include <deque>
#include <vector>

namespace stitch::sync {

struct AudioAlignSettings {
  int rate = 8000;              // Hz the audio is resampled to
  double max_offset_s = 3.0;    // lags searched in [-max, +max]
  double window_s = 8.0;        // view 0's newest span correlated
  double min_window_s = 2.0;    // no estimate with less common audio than this
  double keep_s = 60.0;         // audio kept per view
  double min_psr = 8.0;         // peak-to-sidelobe ratio giving confidence 0 ...
  double full_psr = 20.0;       // ... and 1
  // clock drift: offsets measured in consecutive windows of view 0's time from the sound's
  // envelope (tolerant of the smear a drift causes inside a window), a line through them
  double drift_window_s = 4.0;
  double min_drift_span_s = 30.0;  // rates are fitted once the measured windows span this long
  double drift_min_confidence = 0.3;  // windows less sure than this are left out of the fit
};

struct AudioEstimate {
  int64_t offset_ns = 0;  // at the view's newest audio time (drift included)
  double confidence = 0;  // 0..1 (0: no audio, silence, no common sound)
  bool valid = false;     // has audio on both views and a peak
  double rate = 1.0;      // view 0 seconds per view N second (time_align.hpp's convention)
  bool rate_valid = false;     // a drift line was fitted (rate may still be 1: no drift)
  int64_t base_offset_ns = 0;  // the line's value at view-N time 0 (offset_ns without drift)
};

class AudioAligner {
 public:
  explicit AudioAligner(int n_views, AudioAlignSettings settings = {});
  int views() const { return int(views_.size()); }
  // Interleaved samples of view `view`, the first at its running time t_ns. Float samples; the
  // int16 overload scales by 1/32768. A gap of more than 50 ms to the previous block (a
  // discontinuity) is filled with silence; a jump back restarts the view.
  void add(int view, int64_t t_ns, const float* interleaved, std::size_t frames, int channels, int rate);
  void add(int view, int64_t t_ns, const int16_t* interleaved, std::size_t frames, int channels, int rate);
  // Estimates of every view against view 0 (view 0: valid, offset 0, confidence 1 when it has
  // audio). Recomputed only when a view has a second of new audio since the last estimate.
  const std::vector<AudioEstimate>& estimate();
  const std::vector<AudioEstimate>& current() const { return current_; }  // the last estimate
  bool has_audio(int view) const;
  void reset();
  void reset_view(int view);  // a flush on that camera's audio

  // Lower level, for the tests: offset of b against a over a's newest common window (b read
  // along the line base + rate * t_b, when its drift is known: the offset returned is then the
  // line's correction at t_b = 0).
  bool correlate(int a, int b, double& offset_s, double& confidence, double rate = 1.0, double base_s = 0) const;
  // Offset of b against a over [from, to) of a's time from the sound envelopes (1 ms steps).
  bool envelope_offset(int a, int b, double from_s, double to_s, double& offset_s, double& confidence) const;

 private:
  struct View {
    std::deque<float> samples;  // mono at settings_.rate
    double t0 = 0;              // running time (s) of samples.front()
    bool started = false;
    // resampler state: input position (s) of the next output sample
    double next_out = 0;
    float last_in = 0;
    double last_in_t = -1;
    double acc = 0;
    int acc_n = 0;
  };
  void push_mono(int view, double t, const std::vector<float>& mono, int rate);
  double end_s(const View& v) const { return v.t0 + double(v.samples.size()) / settings_.rate; }
  AudioAlignSettings settings_;
  std::vector<View> views_;
  std::vector<AudioEstimate> current_;
  std::vector<double> ends_at_estimate_;  // each view's end (s) at the last estimate; NaN: none
  struct Measurement {
    double t_b, offset, confidence;  // view-b time at the window's middle, the offset there
  };
  void measure_windows(int view);
  bool fit_drift(int view, double& rate, double& base_s) const;
  std::vector<std::vector<Measurement>> drift_;  // per view: one per drift window passed
  double origin_ = 0;                            // view 0's time the drift windows start at
  bool have_origin_ = false;
};

}  // namespace stitch::sync
