// stitch-surround-view: the 4-fisheye automotive set (surround_view.hpp) -> a rig JSON (fisheye
// lens + ground homography per camera), the bird's-eye PNG (each view warped by the CPU warper,
// kept to its side of the car, corners blended: surround_view.hpp), the undistorted views, and the straightness of their long edges (raw vs
// undistorted with the yaml's lens).
//
//   stitch-surround-view --data ../shared/data/images/surround_view_4fisheye --out /tmp/sv
//
// Exit status: 0 done, 1 failed, 2 bad arguments.
#include <cstdio>
#include <filesystem>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "stitch/cv_interop.hpp"
#include "surround_view.hpp"

int main(int argc, char** argv) {
  std::string data, out;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if ((a == "--data" || a == "--out") && i + 1 < argc) (a == "--data" ? data : out) = argv[++i];
    else {
      std::fprintf(stderr, "usage: stitch-surround-view --data DIR --out DIR\n");
      return 2;
    }
  }
  if (data.empty() || out.empty()) {
    std::fprintf(stderr, "usage: stitch-surround-view --data DIR --out DIR\n");
    return 2;
  }
  try {
    std::filesystem::create_directories(out);
    const stitch::Rig rig = surround::load_rig(data);
    stitch::rig_save(rig, out + "/surround_rig.json");
    std::vector<cv::Mat> frames;
    for (std::size_t i = 0; i < rig.cameras.size(); ++i) {
      cv::Mat bgr = cv::imread(data + "/" + surround::kNames[i] + ".png", cv::IMREAD_COLOR), rgba;
      if (bgr.empty()) throw stitch::RigError(data + "/" + surround::kNames[i] + ".png: cannot read");
      if (bgr.cols != rig.cameras[i].width || bgr.rows != rig.cameras[i].height)
        throw stitch::RigError(std::string(surround::kNames[i]) + ".png is not the yaml's resolution");
      cv::cvtColor(bgr, rgba, cv::COLOR_BGR2RGBA);
      frames.push_back(rgba);
      // Undistorted to a wide pinhole (surround::kUndistortFocalScale): straight lines stay straight.
      const double f = surround::kUndistortFocalScale * 0.5 * (rig.cameras[i].fx + rig.cameras[i].fy);
      const cv::Mat und = surround::undistort(rig.cameras[i], bgr, f);
      cv::imwrite(out + "/undistorted_" + surround::kNames[i] + ".png", und);
      const surround::Straightness fixed = surround::measure_straightness(und);
      const surround::Straightness raw = surround::raw_straightness(rig.cameras[i], f, fixed);
      std::printf("%s: %d long edges, bend (sagitta over chord, median / worst): undistorted %.3f %% / %.3f %%; the "
                  "same edges raw (lens ignored) %.3f %% / %.3f %%\n",
                  surround::kNames[i], fixed.lines, fixed.median_bend_pct, fixed.worst_bend_pct, raw.median_bend_pct,
                  raw.worst_bend_pct);
    }
    const std::vector<cv::Mat> warped = surround::warp_views(rig, frames);
    for (std::size_t i = 0; i < warped.size(); ++i) {
      cv::Mat w;
      cv::cvtColor(warped[i], w, cv::COLOR_RGBA2BGRA);
      cv::imwrite(out + "/warped_" + surround::kNames[i] + ".png", w);
    }
    const cv::Mat pano = surround::compose_birdseye(warped);
    cv::Mat bgra;
    cv::cvtColor(pano, bgra, cv::COLOR_RGBA2BGRA);
    cv::imwrite(out + "/birdseye.png", bgra);
    const surround::Straightness bird = surround::measure_straightness(bgra);
    std::printf("bird's eye %dx%d: %d long edges, bend median %.3f %% (worst %.3f %%); wrote %s/birdseye.png\n",
                pano.cols, pano.rows, bird.lines, bird.median_bend_pct, bird.worst_bend_pct, out.c_str());
  } catch (const std::exception& e) {
    std::fprintf(stderr, "stitch-surround-view: %s\n", e.what());
    return 1;
  }
  return 0;
}
