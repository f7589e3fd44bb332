// stitch-eval-opencv: the OpenCV baseline of the evaluation suite. cv::Stitcher (PANORAMA
// mode, OpenCV's defaults: homography estimation, ray bundle adjustment, wave correction,
// block gain compensation, graph-cut seams, multiband blending; SIFT features by default,
// as our calibration uses, since OpenCV's default ORB loses cameras on wide yaw steps) run
// two ways:
//   per-frame  stitch() on every frame set: estimation and composition each frame, the
//              AutoStitch baseline of the paper;
//   once       estimateTransform() on the first frame set, composePanorama() on every one.
// Writes every panorama (PNG, BGRA, alpha = OpenCV's result mask), the time per frame and
// each frame's camera homographies to the reference camera (full-resolution pixels), so
// the suite can measure the calibration the same way as ours.
// usage: stitch-eval-opencv --out DIR --clips A,B[,C...] --mode per-frame|once [--frames 40]
//          [--warper spherical|plane|cylindrical] [--features sift|orb] [--reference K]
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/stitching.hpp>
#include <opencv2/videoio.hpp>
#include <sstream>
#include <string>
#include <vector>

namespace {

using Clock = std::chrono::steady_clock;

struct Options {
  std::string out, mode = "per-frame", warper = "spherical", features = "sift";
  std::vector<std::string> clips;
  int frames = 40, reference = -1;
};

[[noreturn]] void die(int code, const std::string& msg) {
  std::fprintf(stderr, "stitch-eval-opencv: %s\n", msg.c_str());
  std::exit(code);
}

Options parse_args(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    if (i + 1 >= argc) die(2, "option " + key + " needs a value");
    const std::string v = argv[++i];
    if (key == "--out") o.out = v;
    else if (key == "--clips") {
      std::stringstream ss(v);
      for (std::string p; std::getline(ss, p, ',');)
        if (!p.empty()) o.clips.push_back(p);
    } else if (key == "--mode") o.mode = v;
    else if (key == "--frames") o.frames = std::atoi(v.c_str());
    else if (key == "--warper") o.warper = v;
    else if (key == "--features") o.features = v;
    else if (key == "--reference") o.reference = std::atoi(v.c_str());
    else die(2, "unknown option " + key);
  }
  if (o.out.empty() || o.clips.size() < 2) die(2, "--out and at least two --clips are required");
  if (o.mode != "per-frame" && o.mode != "once") die(2, "--mode must be per-frame or once");
  if (o.frames < 1) die(2, "--frames must be at least 1");
  if (o.reference < 0) o.reference = int(o.clips.size()) / 2;
  if (o.reference >= int(o.clips.size())) die(2, "--reference is out of range");
  return o;
}

cv::Ptr<cv::WarperCreator> make_warper(const std::string& name) {
  if (name == "spherical") return cv::makePtr<cv::SphericalWarper>();
  if (name == "plane") return cv::makePtr<cv::PlaneWarper>();
  if (name == "cylindrical") return cv::makePtr<cv::CylindricalWarper>();
  die(2, "unknown --warper " + name);
}

// Homography from camera i to the reference camera, in full-resolution pixels: OpenCV's
// cameras live at the registration scale, rays r = R K^-1 x.
std::string homographies_json(const cv::Stitcher& s, int reference) {
  const std::vector<cv::detail::CameraParams> cams = s.cameras();
  if (cams.empty()) return "null";
  const double ws = s.workScale();
  const cv::Matx33d to_work(ws, 0, 0, 0, ws, 0, 0, 0, 1);
  std::vector<int> order = s.component();  // cameras() covers only the component's images
  int ref_slot = -1;
  for (std::size_t k = 0; k < order.size(); ++k)
    if (order[k] == reference) ref_slot = int(k);
  if (ref_slot < 0) return "null";
  auto Kd = [](const cv::detail::CameraParams& c) { return cv::Matx33d(cv::Mat(c.K())); };
  auto Rd = [](const cv::detail::CameraParams& c) {
    cv::Mat r;
    c.R.convertTo(r, CV_64F);
    return cv::Matx33d(r);
  };
  const cv::Matx33d ref_from_world = Kd(cams[ref_slot]) * Rd(cams[ref_slot]).t();
  std::string json = "[";
  const int n = int(order.size());
  std::vector<std::string> per_camera(std::size_t(*std::max_element(order.begin(), order.end()) + 1), "null");
  for (int k = 0; k < n; ++k) {
    cv::Matx33d H = to_work.inv() * ref_from_world * Rd(cams[k]) * Kd(cams[k]).inv() * to_work;
    H *= 1.0 / H(2, 2);
    std::ostringstream os;
    os.precision(12);
    os << "[";
    for (int e = 0; e < 9; ++e) os << (e ? "," : "") << H(e / 3, e % 3);
    os << "]";
    per_camera[std::size_t(order[k])] = os.str();
  }
  for (std::size_t i = 0; i < per_camera.size(); ++i) json += (i ? "," : "") + per_camera[i];
  return json + "]";
}

}  // namespace

int main(int argc, char** argv) {
  const Options o = parse_args(argc, argv);
  std::filesystem::create_directories(o.out);
  std::vector<cv::VideoCapture> caps;
  for (const auto& path : o.clips) {
    caps.emplace_back(path);
    if (!caps.back().isOpened()) die(1, "cannot open the clip \"" + path + "\"");
  }
  // Decode everything first: only stitching is timed.
  std::vector<std::vector<cv::Mat>> sets;
  for (int k = 0; k < o.frames; ++k) {
    std::vector<cv::Mat> set;
    for (auto& cap : caps) {
      cv::Mat f;
      if (!cap.read(f)) break;
      set.push_back(f);
    }
    if (set.size() != caps.size()) break;
    sets.push_back(std::move(set));
  }
  if (sets.empty()) die(1, "no frames could be read");

  cv::Ptr<cv::Stitcher> stitcher = cv::Stitcher::create(cv::Stitcher::PANORAMA);
  stitcher->setWarper(make_warper(o.warper));
  if (o.features == "sift") stitcher->setFeaturesFinder(cv::SIFT::create());
  else if (o.features != "orb") die(2, "--features must be sift or orb");
  std::vector<double> ms;
  std::vector<std::string> homographies;
  int failures = 0;
  double estimate_ms = 0;
  bool estimated = false;
  std::vector<int> png = {cv::IMWRITE_PNG_COMPRESSION, 1};
  for (std::size_t k = 0; k < sets.size(); ++k) {
    cv::Mat pano;
    cv::Stitcher::Status status = cv::Stitcher::OK;
    const Clock::time_point t0 = Clock::now();
    const bool all_cameras_before = estimated;
    try {
      if (o.mode == "per-frame") {
        status = stitcher->stitch(sets[k], pano);
      } else {
        if (!estimated) {
          // Until an estimate keeps every camera, try again on the next frame set.
          status = stitcher->estimateTransform(sets[k]);
          estimate_ms = 1e3 * std::chrono::duration<double>(Clock::now() - t0).count();
          estimated = status == cv::Stitcher::OK && stitcher->component().size() == sets[k].size();
        }
        if (estimated) status = stitcher->composePanorama(sets[k], pano);
      }
    } catch (const cv::Exception& e) {
      std::fprintf(stderr, "stitch-eval-opencv: frame %zu: %s\n", k, e.what());
      status = cv::Stitcher::ERR_CAMERA_PARAMS_ADJUST_FAIL;
    }
    const double elapsed = 1e3 * std::chrono::duration<double>(Clock::now() - t0).count();
    char name[32];
    std::snprintf(name, sizeof name, "pano_%04zu.png", k);
    const std::string path = (std::filesystem::path(o.out) / name).string();
    if (status != cv::Stitcher::OK || pano.empty() ||
        int(stitcher->component().size()) != int(sets[k].size())) {
      // A failed frame (or one that left cameras out) is counted; the viewer would see the
      // previous panorama or nothing, so no image is written for it.
      if (failures++ == 0)
        std::fprintf(stderr, "stitch-eval-opencv: frame %zu failed: status %d, %zu of %zu cameras stitched\n", k,
                     int(status), stitcher->component().size(), sets[k].size());
      homographies.push_back("null");
      std::filesystem::remove(path);
      continue;
    }
    ms.push_back(o.mode == "once" && !all_cameras_before ? elapsed - estimate_ms : elapsed);
    homographies.push_back(homographies_json(*stitcher, o.reference));
    cv::Mat mask = stitcher->resultMask().getMat(cv::ACCESS_READ), bgra;
    cv::cvtColor(pano, bgra, cv::COLOR_BGR2BGRA);
    if (mask.size() == pano.size()) {
      std::vector<cv::Mat> ch;
      cv::split(bgra, ch);
      ch[3] = mask.clone();
      cv::merge(ch, bgra);
    }
    if (!cv::imwrite(path, bgra, png)) die(1, "cannot write " + path);
  }
  double mean_ms = 0;
  for (double v : ms) mean_ms += v;
  mean_ms = ms.empty() ? -1 : mean_ms / double(ms.size());
  std::ofstream json(std::filesystem::path(o.out) / "run.json");
  json << "{\"stitcher\":\"opencv\",\"mode\":\"" << o.mode << "\",\"warper\":\"" << o.warper
       << "\",\"features\":\"" << o.features
       << "\",\"cameras\":" << caps.size() << ",\"frames\":" << sets.size() << ",\"failures\":" << failures
       << ",\"ms_per_frame\":" << mean_ms << ",\"estimate_ms\":" << estimate_ms << ",\"reference\":" << o.reference
       << ",\"homographies_to_reference\":[";
  for (std::size_t k = 0; k < homographies.size(); ++k) json << (k ? "," : "") << homographies[k];
  json << "]}\n";
  std::printf("stitch-eval-opencv %s: %zu frame sets, %d failed, %.1f ms per frame (estimate %.1f ms) -> %s\n",
              o.mode.c_str(), sets.size(), failures, mean_ms, estimate_ms, o.out.c_str());
  return 0;
}
