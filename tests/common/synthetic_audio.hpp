// A sound scene heard by several cameras' microphones, for the audio time-alignment tests:
// speech-like bursts (noise shaped by random 80-300 ms syllables with pauses) over a quiet test
// tone, each camera with its own gain, sample rate and microphone noise, started at its own time.
#pragma once

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

namespace testdata {

class SoundScene {
 public:
  // `seconds` of scene sound at 48 kHz, from scene time -margin to seconds + margin.
  explicit SoundScene(double seconds, unsigned seed = 7, double margin = 5.0) : margin_(margin) {
    const std::size_t n = std::size_t((seconds + 2 * margin) * kRate);
    s_.assign(n, 0.f);
    std::mt19937 rng(seed);
    std::normal_distribution<float> g(0.f, 1.f);
    std::uniform_real_distribution<double> u(0, 1);
    // syllables: on for 80-300 ms, off for 50-400 ms; the noise low-passed (one pole) so that
    // it is voice-coloured rather than white
    std::size_t i = 0;
    float lp = 0;
    while (i < n) {
      const std::size_t on = std::size_t((0.08 + 0.22 * u(rng)) * kRate);
      const std::size_t off = std::size_t((0.05 + 0.35 * u(rng)) * kRate);
      const float amp = float(0.2 + 0.3 * u(rng));
      for (std::size_t k = 0; k < on && i < n; ++k, ++i) {
        lp = 0.7f * lp + 0.3f * g(rng);
        const float env = std::sin(float(M_PI) * float(k) / float(on));
        s_[i] = amp * env * lp;
      }
      i += off;
    }
    for (std::size_t k = 0; k < n; ++k) s_[k] += 0.05f * std::sin(float(2 * M_PI * 440.0 * double(k) / kRate));
  }
  // The sound at scene time t (s), linearly interpolated.
  float at(double t) const {
    const double x = (t + margin_) * kRate;
    if (x < 0 || x + 1 >= double(s_.size())) return 0.f;
    const std::size_t i = std::size_t(x);
    const float a = float(x - double(i));
    return s_[i] * (1 - a) + s_[i + 1] * a;
  }
  // What a camera records: `frames` samples at `rate`, `channels` interleaved, its sample k at
  // scene time start + k / (rate * speed), times `gain`, plus its own noise (rms `noise`).
  // `speed`: how fast the camera's clock runs (1.005: 0.5% fast, its `rate` samples take 1/1.005
  // of a scene second).
  std::vector<float> record(double start, std::size_t frames, int rate, int channels, float gain, float noise,
                            unsigned seed, double speed = 1.0) const {
    std::mt19937 rng(seed);
    std::normal_distribution<float> g(0.f, noise);
    std::vector<float> out(frames * std::size_t(channels));
    for (std::size_t k = 0; k < frames; ++k) {
      const float v = gain * at(start + double(k) / (rate * speed));
      for (int c = 0; c < channels; ++c) out[k * std::size_t(channels) + std::size_t(c)] = v + g(rng);
    }
    return out;
  }
  static constexpr double kRate = 48000;

 private:
  double margin_;
  std::vector<float> s_;
};

}  // namespace testdata
