// Time alignment on real clips (issue 18): decodes each camera of a clip (cv::VideoCapture),
// trims cameras by given numbers of frames at the start (as if started later), and reports the
// offsets and confidences the aligner finds, a synchronised run (no trim), a simulated 0.5% clock
// rate difference, and the CPU cost of `time-alignment=auto` per frame (thumbnail signal) and per
// estimate.
//
// With --audio, each camera also gets a synthetic sound track (speech-like noise bursts over a
// quiet tone, each microphone with its own gain, noise and rate, trimmed like the video) and the
// audio estimate (AudioAligner), the combined one (audio where sure, else vision) and the audio
// cost are reported too.
//
// With --sweep N, the cameras after the first are trimmed N times, by 1..N frames each and
// differently from one another (camera v by 1 + (k * (6v - 5) + 11 (v - 1)) mod N at run k), and
// every run is scored against the untrimmed one (or --truth F0,F1,..: the untrimmed clip's
// offsets in frames, where known otherwise): right (within a frame), no signal (said so), or
// wrong (a valid estimate more than a frame off); the worst case is printed last.
//
//   stitch-bench-sync DIR CAM0.mp4 CAM1.mp4 [CAM2.mp4 ...] [--trim N1,N2,...] [--audio] [--sweep N]
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "stitch/sync/audio_align.hpp"
#include "stitch/sync/time_align.hpp"
#include "../tests/common/synthetic_audio.hpp"

using stitch::sync::Estimate;
using stitch::sync::FrameSignal;
using stitch::sync::TimeAligner;
using Clock = std::chrono::steady_clock;

namespace {

double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

// Runs the aligner on the signals, view v starting at frame trim[v]; frames at 1/fps of each
// camera's clock, the clock of view v running `rate[v]` times as fast as view 0's.
std::vector<Estimate> align(const std::vector<std::vector<std::vector<double>>>& sig, const std::vector<int>& trim, double fps,
                            const std::vector<double>& rate, double& estimate_ms, int& estimates) {
  TimeAligner a(int(sig.size()));
  std::size_t longest = 0;
  for (const auto& s : sig) longest = std::max(longest, s.size());
  std::vector<Estimate> e;
  estimate_ms = 0;
  estimates = 0;
  for (std::size_t f = 0; f < longest; ++f) {
    for (std::size_t v = 0; v < sig.size(); ++v) {
      const std::size_t src = f + std::size_t(trim[v]);
      if (src >= sig[v].size()) continue;
      a.add_sample(int(v), int64_t(double(f) / fps * 1e9 * rate[v]), sig[v][src]);
    }
    if (f % std::size_t(fps) == 0 || f + 1 == longest) {  // the element estimates once a second
      const auto t0 = Clock::now();
      e = a.estimate();
      estimate_ms += ms_since(t0);
      ++estimates;
    }
  }
  return e;
}

void print(const char* label, const std::vector<Estimate>& e, const std::vector<int>& trim, double fps) {
  std::printf("%s\n", label);
  for (std::size_t v = 1; v < e.size(); ++v) {
    const double frames = e[v].offset_ns / 1e9 * fps;
    const double want = trim[v] - trim[0];
    std::printf("  view %zu: offset %+8.2f ms = %+6.2f frames (expected %+d, error %+5.2f) confidence %.2f rate %.5f%s\n",
                v, e[v].offset_ns / 1e6, frames, int(want), frames - want, e[v].confidence, e[v].rate,
                e[v].valid ? "" : "  (no signal)");
  }
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: %s DIR CAM0.mp4 CAM1.mp4 [...] [--trim N1,N2,...]\n", argv[0]);
    return 2;
  }
  const std::string dir = argv[1];
  std::vector<std::string> cams;
  std::vector<int> trim;
  bool audio = false;
  int sweep = 0;
  std::vector<double> truth;  // --truth: the untrimmed clip's offsets (frames), known otherwise
  for (int i = 2; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--audio") {
      audio = true;
    } else if (a == "--truth" && i + 1 < argc) {
      std::stringstream ss(argv[++i]);
      std::string item;
      while (std::getline(ss, item, ',')) truth.push_back(std::atof(item.c_str()));
    } else if (a == "--sweep" && i + 1 < argc) {
      sweep = std::atoi(argv[++i]);
    } else if (a == "--trim" && i + 1 < argc) {
      std::stringstream ss(argv[++i]);
      std::string item;
      trim.push_back(0);
      while (std::getline(ss, item, ',')) trim.push_back(std::atoi(item.c_str()));
    } else {
      cams.push_back(a);
    }
  }
  if (trim.empty()) {
    trim.push_back(0);
    for (std::size_t v = 1; v < cams.size(); ++v) trim.push_back(int(4 + 7 * v));
  }
  trim.resize(cams.size(), 0);
  std::vector<std::vector<std::vector<double>>> sig(cams.size());
  double fps = 30, signal_ms = 0;
  long frames = 0;
  int width = 0, height = 0;
  for (std::size_t v = 0; v < cams.size(); ++v) {
    cv::VideoCapture cap(dir + "/" + cams[v]);
    if (!cap.isOpened()) {
      std::fprintf(stderr, "cannot open %s/%s\n", dir.c_str(), cams[v].c_str());
      return 1;
    }
    if (v == 0 && cap.get(cv::CAP_PROP_FPS) > 1) fps = cap.get(cv::CAP_PROP_FPS);
    FrameSignal fs;
    cv::Mat frame, rgba;
    while (cap.read(frame)) {
      cv::cvtColor(frame, rgba, cv::COLOR_BGR2RGBA);  // what stitchsync's system-memory views hold
      width = rgba.cols;
      height = rgba.rows;
      const auto t0 = Clock::now();
      sig[v].push_back(fs.update(rgba.data, rgba.cols, rgba.rows, rgba.step, 4, 1));
      signal_ms += ms_since(t0);
      ++frames;
    }
  }
  std::printf("%s: %zu cameras, %dx%d, %.2f fps, %zu frames in camera 0\n", dir.c_str(), cams.size(), width, height,
              fps, sig[0].size());
  const std::vector<double> same(cams.size(), 1.0);
  double est_ms = 0;
  int n_est = 0;
  std::vector<int> zero(cams.size(), 0);
  auto e = align(sig, zero, fps, same, est_ms, n_est);
  print("synchronised (no trim):", e, zero, fps);
  std::vector<Estimate> base = e;
  e = align(sig, trim, fps, same, est_ms, n_est);
  if (sweep > 0) {
    // every run against the untrimmed one: within a frame, said "no signal", or wrong
    int right = 0, quiet = 0, wrong = 0;
    double worst = 0, worst_conf = 0;
    std::string worst_what = "none";
    for (int k = 0; k < sweep; ++k) {
      std::vector<int> tr(cams.size(), 0);
      for (std::size_t v = 1; v < cams.size(); ++v) tr[v] = 1 + int((k * (6 * int(v) - 5) + 11 * (int(v) - 1)) % sweep);
      double ms = 0;
      int ne = 0;
      const auto r = align(sig, tr, fps, same, ms, ne);
      std::printf("sweep trims");
      for (int t : tr) std::printf(" %2d", t);
      std::printf(":");
      for (std::size_t v = 1; v < r.size(); ++v) {
        if (!r[v].valid) {
          ++quiet;
          std::printf("  v%zu none (%.2f)", v, r[v].confidence);
          continue;
        }
        if (v < truth.size()) {
          // scored against the known offsets of the untrimmed clip
          base[v].valid = true;
          base[v].offset_ns = int64_t(std::llround(truth[v] / fps * 1e9));
        }
        if (!base[v].valid) {
          // the untrimmed run had nothing: a trimmed run that claims an offset is not verifiable
          ++wrong;
          std::printf("  v%zu %+6.2f UNVERIFIED (%.2f)", v, r[v].offset_ns / 1e9 * fps, r[v].confidence);
          if (worst < 1e9) worst = 1e9, worst_what = "a valid offset where the untrimmed run had none";
          continue;
        }
        const double err = (r[v].offset_ns - base[v].offset_ns) / 1e9 * fps - tr[v];
        (std::fabs(err) <= 1.0 ? right : wrong) += 1;
        std::printf("  v%zu %+6.2f (%.2f)%s", v, err, r[v].confidence, std::fabs(err) <= 1.0 ? "" : " WRONG");
        if (std::fabs(err) > worst) {
          worst = std::fabs(err);
          worst_conf = r[v].confidence;
          char b[128];
          std::snprintf(b, sizeof b, "view %zu at trims %d/%d: %+.2f frames, confidence %.2f", v, tr[1],
                        cams.size() > 2 ? tr[2] : 0, err, r[v].confidence);
          worst_what = b;
        }
      }
      std::printf("\n");
    }
    std::printf("sweep: %d right (within 1 frame), %d no signal, %d wrong; worst: %s\n", right, quiet, wrong,
                worst_what.c_str());
    (void)worst_conf;
  }
  std::printf("trimmed:");
  for (int t : trim) std::printf(" %d", t);
  std::printf(" frames (errors are relative to the untrimmed run's offsets)\n");
  for (std::size_t v = 1; v < e.size(); ++v) {
    const double got = (e[v].offset_ns - base[v].offset_ns) / 1e9 * fps;
    std::printf("  view %zu: offset change %+6.2f frames (expected %+d, error %+5.2f) confidence %.2f%s\n", v, got,
                trim[v], got - trim[v], e[v].confidence, e[v].valid ? "" : "  (no signal)");
  }
  if (audio) {
    // the sound each camera records, started where its video starts (trim[v] frames late)
    const double seconds = double(sig[0].size()) / fps;
    const testdata::SoundScene scene(seconds + 2, 11);
    stitch::sync::AudioAligner aa(int(cams.size()));
    double feed_ms = 0;
    for (std::size_t v = 0; v < cams.size(); ++v) {
      const int rate = v % 2 ? 44100 : 48000, channels = v % 2 ? 1 : 2;
      const std::size_t n = std::size_t((double(sig[v].size()) - trim[v]) / fps * rate);
      const std::vector<float> x =
          scene.record(trim[v] / fps, n, rate, channels, 0.6f + 0.3f * float(v), 0.03f, unsigned(v + 1));
      const auto t0 = Clock::now();
      for (std::size_t f = 0; f < n; f += std::size_t(rate / 50))
        aa.add(int(v), int64_t(double(f) / rate * 1e9), x.data() + f * std::size_t(channels),
               std::min<std::size_t>(std::size_t(rate / 50), n - f), channels, rate);
      feed_ms += ms_since(t0);
    }
    const auto t0 = Clock::now();
    const auto ae = aa.estimate();
    const double audio_est_ms = ms_since(t0);
    std::printf("with a synthetic audio track (errors are absolute: the sound is in sync before the trim):\n");
    for (std::size_t v = 1; v < e.size(); ++v) {
      const double got = ae[v].offset_ns / 1e9 * fps;
      const bool use_audio = ae[v].valid && ae[v].confidence >= stitch::sync::AlignSettings{}.audio_min_confidence;
      std::printf("  view %zu: audio %+6.2f frames (expected %+d, error %+5.2f) confidence %.2f -> offset from %s\n", v,
                  got, trim[v], got - trim[v], ae[v].confidence, use_audio ? "audio" : e[v].valid ? "vision" : "none");
    }
    std::printf("audio cost: %.3f ms per second of audio per camera (downmix, resample to 8 kHz), estimate %.2f ms "
                "(%zu views, 8 s window, GCC-PHAT)\n",
                feed_ms / (double(cams.size()) * seconds), audio_est_ms, cams.size());
  }
  std::printf("cost: thumbnail signal %.3f ms per frame (%dx%d RGBA), estimate %.3f ms each (%d views, %d estimates, "
              "one per second of video)\n",
              signal_ms / double(frames), width, height, est_ms / std::max(1, n_est), int(cams.size()), n_est);
  return 0;
}
