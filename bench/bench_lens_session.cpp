// The elements' background lens fit (issue 15, calib_session.hpp "lens from evidence"), measured
// through the calibration session the element runs, with its default settings (no rig-file: a
// pinhole first calibration, 5 pooled frame sets over 2 s, then the lens job on their frames),
// jobs run synchronously at 30 fps of running time.
//  - rendered rigs (--photo, repeatable): three 320x240 cameras (f 260) `spacing` degrees apart
//    with a radtan lens k1 (k2 = k1^2 for barrel lenses), rendered from the photo taken as an
//    equirectangular panorama, turned per seed; 2 grey levels of sensor noise per frame. Before
//    (the pinhole calibration) and after (what is installed once the lens job is done): seam
//    error (independent matches of the overlaps: median in camera px, 90th percentile in canvas
//    px) and, for rotation-model rigs, panorama PSNR against the truth on the truth's canvas.
//  - real clips (--clip dir/a.mp4,dir/b.mp4, repeatable): the same, without truth: the lens
//    found (none expected) and the seams before / after.
//   stitch-bench-lens-session --photo data/photos/boat1_1600.jpg [--seeds 2] [--k1 -0.05,-0.3]
//                             [--spacing 30,40] [--clip a.mp4,b.mp4] [--skip 0,150,300]
//   (--skip: each clip again from these frames on; LENS_SESSION_PRECHECK_ONLY=1: the lens job's
//   cheap test alone, lens_precheck, instead of the job)
#include <chrono>
#include <cstdlib>
#include <cmath>
#include <cstdio>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <sstream>
#include <string>
#include <sys/resource.h>
#include <vector>

#include "bench_photo.hpp"
#include "image_compare.hpp"
#include "lens_quality.hpp"
#include "lens_rig.hpp"
#include "stitch/calib/calib_session.hpp"
#include "stitch/cv_interop.hpp"

using namespace stitch;

namespace {

// CPU seconds of the whole process (every thread: OpenCV's pool too), user + system.
double process_cpu_s() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) + 1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

std::vector<ImageView> views_of(std::vector<cv::Mat>& m) {
  std::vector<ImageView> v;
  for (auto& x : m) v.push_back(as_view(x));
  return v;
}


struct Run {
  std::shared_ptr<const Rig> first, last;
  std::string lens = "skipped";
  std::string precheck;  // the lens job's cheap test, when it passed
  std::string first_model;  // installed / rejected: reason / skipped / failed
  double lens_s = 0, lens_cpu_s = 0, total_s = 0;
  int frames = 0;
};

// Frames until the lens job is done (or `max_frames`); frame(f) gives frame f (empty: the end).
template <class F>
Run run_session(F frame, int max_frames) {
  CalibSession s;
  SessionConfig config;
  if (const char* e = std::getenv("LENS_SESSION_FRAMES")) config.calibration_frames = std::atoi(e);
  if (const char* e = std::getenv("LENS_SESSION_WINDOW")) config.calibration_window_s = std::atof(e);
  s.set_config(config);
  Run run;
  const auto t0 = std::chrono::steady_clock::now();
  for (int f = 0; f < max_frames; ++f) {
    std::vector<cv::Mat> m = frame(f);
    if (m.empty()) break;
    run.frames = f + 1;
    CalibSession::Frame fr;
    fr.time_s = f / 30.0;
    for (const auto& x : m) fr.sizes.push_back({x.cols, x.rows});
    auto job = s.on_frame(fr, s.wants_pixels(fr) ? views_of(m) : std::vector<ImageView>());
    bool lens_done = false;
    if (job && job->kind == JobKind::Lens && std::getenv("LENS_SESSION_PRECHECK_ONLY")) {
      // The cheap test alone (lens_precheck), on the sets the lens job fits: for tuning it.
      std::vector<std::vector<ImageView>> sets{job->calib_sets.front().views()};
      if (job->calib_sets.size() > 1) sets.push_back(job->calib_sets.back().views());
      const double c0 = process_cpu_s();
      const LensPrecheck p = lens_precheck(*job->current, sets, job->config.options);
      run.lens_cpu_s = process_cpu_s() - c0;
      run.lens_s = p.seconds;
      run.lens = std::string(p.plausible ? "plausible " : "no ") + p.describe();
      break;
    }
    if (job) {
      std::atomic<bool> cancel{false};
      const auto j0 = std::chrono::steady_clock::now();
      const double c0 = process_cpu_s();
      const CalibOutcome o = run_calib_job(*job, cancel);
      if (job->kind == JobKind::Lens) {
        run.lens_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - j0).count();
        run.lens_cpu_s = process_cpu_s() - c0;
        lens_done = true;
        if (!o.error.empty()) run.lens = "failed: " + o.error;
        if (o.lens_precheck && o.lens_precheck->plausible) run.precheck = "plausible, " + o.lens_precheck->describe();
        if (o.lens_precheck) std::fprintf(stderr, "precheck: %s %s\n", o.lens_precheck->plausible ? "plausible" : "no", o.lens_precheck->describe().c_str());
      }
      s.on_outcome(o);
    }
    if (s.current()) s.bundle_passed();
    if (!run.first && s.current()) run.first = s.current();
    for (const auto& e : s.take_events())
      if (e.type == SessionEvent::Type::Installed && run.first_model.empty()) run.first_model = e.report.model;
      else if (e.report.source == "lens")
        run.lens = (e.type == SessionEvent::Type::Installed ? "installed" : "rejected: " + e.report.rejected_because) +
                   (run.precheck.empty() ? "" : " (" + run.precheck + ")");
    if (lens_done) break;
  }
  run.last = s.current();
  run.total_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return run;
}

double psnr_on_truth(const Rig& rig, const Rig& truth, std::vector<cv::Mat>& frames, const cv::Mat& gt, const cv::Mat& mask) {
  const Rig est = testdata::aligned_to_truth(rig, truth);
  const cv::Mat pano = testdata::compose_cpu(est, frames);
  cv::Mat g(pano.size(), gt.type(), cv::Scalar::all(0)), m(pano.size(), mask.type(), cv::Scalar::all(0));
  gt(cv::Rect(0, 0, std::min(gt.cols, pano.cols), std::min(gt.rows, pano.rows))).copyTo(g(cv::Rect(0, 0, std::min(gt.cols, pano.cols), std::min(gt.rows, pano.rows))));
  mask(cv::Rect(0, 0, std::min(gt.cols, pano.cols), std::min(gt.rows, pano.rows))).copyTo(m(cv::Rect(0, 0, std::min(gt.cols, pano.cols), std::min(gt.rows, pano.rows))));
  return testdata::masked_psnr_rgb(pano, g, m);
}

std::string k1_text(const Rig& r) {
  if (r.cameras[0].lens.pinhole()) return "pinhole";
  char b[64];
  double lo = 1e9, hi = -1e9;
  for (const auto& c : r.cameras) lo = std::min(lo, c.lens.k1), hi = std::max(hi, c.lens.k1);
  std::snprintf(b, sizeof b, "radtan %+.3f..%+.3f", lo, hi);
  return b;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> photos, clips;
  int seeds = 2;
  std::vector<double> skips{0};  // --skip: clips from these frame numbers on (comma list)
  std::vector<double> k1s{0, -0.05, -0.1, -0.2, -0.3}, spacings{30, 40};
  for (int i = 1; i + 1 < argc; i += 2) {
    const std::string k = argv[i], v = argv[i + 1];
    if (k == "--photo") photos.push_back(v);
    else if (k == "--clip") clips.push_back(v);
    else if (k == "--seeds") seeds = std::stoi(v);
    else if (k == "--skip") skips = stitch_bench::comma_numbers(v);
    else if (k == "--k1") k1s = stitch_bench::comma_numbers(v);
    else if (k == "--spacing") spacings = stitch_bench::comma_numbers(v);
    else {
      std::fprintf(stderr, "unknown option %s\n", k.c_str());
      return 2;
    }
  }
  if (!photos.empty()) {
    std::printf("| photo | k1 | spacing | seed | first model | lens job | installed lens | seam median camera px before -> after | seam p90 canvas px before -> after | PSNR dB before -> after | lens job s | lens job CPU s |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
  }
  for (const auto& path : photos) {
    const cv::Mat photo = stitch_bench::read_photo_rgba(path, 2688);
    if (photo.empty()) return 1;
    const std::string name = path.substr(path.find_last_of('/') + 1);
    for (const double k1 : k1s)
      for (const double spacing : spacings)
        for (int seed = 0; seed < seeds; ++seed) {
          Rig truth = testdata::radtan_trio(320, 240, 260, spacing, k1, k1 < 0 ? k1 * k1 : 0.0, k1 != 0, "spherical", 0.0);
          for (auto& c : truth.cameras) c.yaw_deg += 100.0 * seed, c.pitch_deg += seed % 2 ? -8.0 : 4.0;
          rig_layout_canvas(truth);
          std::vector<cv::Mat> clean;
          for (const auto& c : truth.cameras) clean.push_back(testdata::render_camera_from_equirect(photo, c));
          const Run run = run_session([&](int f) { return testdata::with_sensor_noise(clean, f, 2.0, false); }, 200);
          if (!run.first || !run.last) {
            std::printf("| %s | %+.2f | %.0f | %d | no calibration | | | | | | |\n", name.c_str(), k1, spacing, seed);
            continue;
          }
          std::vector<cv::Mat> frames = clean;
          const auto views = views_of(frames);
          const AlignmentReport a = measure_alignment(*run.first, views), b = measure_alignment(*run.last, views);
          const cv::Mat gt = testdata::equirect_ground_truth(photo, truth);
          cv::Mat gray, mask;
          cv::cvtColor(testdata::compose_cpu(truth, frames), gray, cv::COLOR_RGBA2GRAY);
          mask = gray > 0;
          cv::erode(mask, mask, cv::Mat::ones(9, 9, CV_8U));
          const bool first_rot = run.first_model == "rotation";
          double pa = -1, pb = -1;
          try {
            pa = first_rot ? psnr_on_truth(*run.first, truth, frames, gt, mask) : -1;
            pb = psnr_on_truth(*run.last, truth, frames, gt, mask);
          } catch (const std::exception& e) {
            std::fprintf(stderr, "PSNR: %s\n", e.what());
          }
          std::printf("| %s | %+.2f | %.0f | %d | %s %s | %s | %s | %.3f -> %.3f | %.2f -> %.2f | %.2f -> %.2f | %.1f | %.1f |\n",
                      name.c_str(), k1, spacing, seed, run.first->projection.c_str(),
                      run.first_model.c_str(), run.lens.c_str(),
                      k1_text(*run.last).c_str(), a.median_camera_px, b.median_camera_px, a.p90_px, b.p90_px, pa, pb,
                      run.lens_s, run.lens_cpu_s);
          std::fflush(stdout);
        }
  }
  if (!clips.empty()) {
    std::printf("\n| clip | from frame + frames | first | lens job | installed lens | seam median camera px before -> after | seam p90 canvas px before -> after | lens job s | lens job CPU s |\n");
    std::printf("|---|---|---|---|---|---|---|---|---|\n");
  }
  for (const auto& clip : clips)
  for (const double skip : skips) {
    std::vector<cv::VideoCapture> caps;
    for (const auto& f : stitch_bench::comma_list(clip)) caps.emplace_back(f);
    for (auto& c : caps) c.set(cv::CAP_PROP_POS_FRAMES, skip);
    std::vector<cv::Mat> last;
    const Run run = run_session(
        [&](int) {
          std::vector<cv::Mat> out;
          for (auto& c : caps) {
            cv::Mat bgr, rgba;
            if (!c.read(bgr)) return std::vector<cv::Mat>();
            cv::cvtColor(bgr, rgba, cv::COLOR_BGR2RGBA);
            out.push_back(rgba);
          }
          last = out;
          return out;
        },
        900);
    if (!run.first || !run.last || last.empty()) {
      std::printf("| %s | %d+%d | no calibration | | | | | |\n", clip.c_str(), int(skip), run.frames);
      continue;
    }
    const auto views = views_of(last);
    const AlignmentReport a = measure_alignment(*run.first, views), b = measure_alignment(*run.last, views);
    std::printf("| %s | %d+%d | %s %s | %s | %s | %.3f -> %.3f | %.2f -> %.2f | %.1f | %.1f |\n", clip.c_str(), int(skip), run.frames,
                run.first->projection.c_str(), run.first_model.c_str(), run.lens.c_str(), k1_text(*run.last).c_str(), a.median_camera_px,
                b.median_camera_px, a.p90_px, b.p90_px, run.lens_s, run.lens_cpu_s);
    std::fflush(stdout);
  }
  return 0;
}
