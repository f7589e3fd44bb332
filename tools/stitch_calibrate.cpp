// stitch-calibrate: the "calibrate once, reuse" workflow on the command line. Takes one clip
// (anything OpenCV's VideoCapture reads) or one image per camera, an optional rough rig, and
// writes the rig JSON (the same writer as stitchcalib's save-file), a preview panorama (the
// core compositor, CPU) and a per-pair report (matches, inliers, residuals, model chosen).
//
//   stitch-calibrate [--rig ROUGH.json] [--out rig.json] [--preview preview.png]
//                    [--report report.json] [--frames 5] [--step 10] [--start 0]
//                    [--model auto|rotation|homography] [--projection auto|plane|cylindrical|spherical]
//                    [--reference -1] CAMERA0 CAMERA1 ...
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <string>
#include <vector>

#include "stitch/blend/compositor.hpp"
#include "stitch/calib/calibrator.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/rig.hpp"

namespace {

struct Options {
  std::vector<std::string> inputs;
  std::string rig, out = "rig.json", preview, report;
  int frames = 5, step = 10, start = 0, reference = -1;
  stitch::CalibrationOptions calib;
};

void usage(std::FILE* f) {
  std::fprintf(f,
               "usage: stitch-calibrate [--rig ROUGH.json] [--out rig.json] [--preview PNG] [--report JSON]\n"
               "         [--frames 5] [--step 10] [--start 0] [--model auto|rotation|homography]\n"
               "         [--projection auto|plane|cylindrical|spherical] [--reference -1] CAMERA...\n"
               "Each CAMERA is a clip or an image (one per camera, any order). Clips: --frames instants,\n"
               "--step frames apart from --start, pooled. Without --rig: from the images alone.\n");
}

[[noreturn]] void die(int code, const std::string& msg) {
  std::fprintf(stderr, "stitch-calibrate: %s\n", msg.c_str());
  if (code == 2) usage(stderr);
  std::exit(code);
}

int to_int(const std::string& key, const std::string& v) {
  char* end = nullptr;
  const long x = std::strtol(v.c_str(), &end, 10);
  if (v.empty() || *end) die(2, key + " needs an integer, got \"" + v + "\"");
  return int(x);
}

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "-h" || a == "--help") {
      usage(stdout);
      std::exit(0);
    }
    if (a.rfind("--", 0) != 0) {
      o.inputs.push_back(a);
      continue;
    }
    if (i + 1 >= argc) die(2, a + " needs a value");
    const std::string v = argv[++i];
    if (a == "--rig") o.rig = v;
    else if (a == "--out") o.out = v;
    else if (a == "--preview") o.preview = v;
    else if (a == "--report") o.report = v;
    else if (a == "--frames") o.frames = to_int(a, v);
    else if (a == "--step") o.step = to_int(a, v);
    else if (a == "--start") o.start = to_int(a, v);
    else if (a == "--reference") o.reference = to_int(a, v);
    else if (a == "--model") {
      if (v == "auto") o.calib.model = stitch::CameraModel::Auto;
      else if (v == "rotation") o.calib.model = stitch::CameraModel::Rotation;
      else if (v == "homography") o.calib.model = stitch::CameraModel::Homography;
      else die(2, "--model must be auto, rotation or homography");
    } else if (a == "--projection") {
      if (v != "auto") {
        try {
          o.calib.projection = stitch::projection_from_name(v);
        } catch (const std::exception& e) {
          die(2, std::string("--projection: ") + e.what());
        }
      }
    } else die(2, "unknown option " + a);
  }
  if (o.inputs.size() < 2) die(2, "give at least two cameras");
  if (o.frames < 1 || o.step < 1 || o.start < 0) die(2, "--frames and --step must be positive, --start >= 0");
  return o;
}

bool is_image(const std::string& path) {
  std::string ext = path.substr(path.find_last_of('.') + 1);
  for (auto& c : ext) c = char(std::tolower(c));
  return ext == "jpg" || ext == "jpeg" || ext == "png" || ext == "bmp" || ext == "tif" || ext == "tiff" || ext == "ppm";
}

// frames[t][camera] as RGBA: every camera's t-th instant (clips), or its one image.
std::vector<std::vector<cv::Mat>> read_inputs(const Options& o) {
  const int n = int(o.inputs.size());
  std::vector<std::vector<cv::Mat>> per_camera(n);
  for (int c = 0; c < n; ++c) {
    const std::string& path = o.inputs[c];
    if (is_image(path)) {
      cv::Mat bgr = cv::imread(path, cv::IMREAD_COLOR);
      if (bgr.empty()) die(1, "cannot read the image \"" + path + "\"");
      per_camera[c].push_back(bgr);
      continue;
    }
    cv::VideoCapture cap(path);
    if (!cap.isOpened()) die(1, "cannot open \"" + path + "\" (not a clip or image OpenCV reads?)");
    cv::Mat f;
    for (int k = 0; int(per_camera[c].size()) < o.frames && cap.read(f); ++k)
      if (k >= o.start && (k - o.start) % o.step == 0) per_camera[c].push_back(f.clone());
    if (per_camera[c].empty()) die(1, "\"" + path + "\" has no frame at " + std::to_string(o.start));
  }
  std::size_t instants = per_camera[0].size();
  for (const auto& v : per_camera) instants = std::min(instants, v.size());
  std::vector<std::vector<cv::Mat>> sets(instants, std::vector<cv::Mat>(n));
  for (std::size_t t = 0; t < instants; ++t)
    for (int c = 0; c < n; ++c) cv::cvtColor(per_camera[c][t], sets[t][c], cv::COLOR_BGR2RGBA);
  return sets;
}

nlohmann::json report_json(const stitch::CalibrationResult& r, const Options& o) {
  nlohmann::json j;
  j["model"] = stitch::camera_model_name(r.model);
  j["projection"] = r.rig.projection;
  j["projection_chosen"] = r.projection_chosen;
  j["reference"] = r.rig.reference;
  j["canvas"] = {{"width", r.rig.canvas_width}, {"height", r.rig.canvas_height}, {"wrap", r.rig.canvas_wrap}};
  j["heldout"] = {{"matches", r.heldout_matches},
                  {"rotation_rms_px", r.rotation_heldout_px},
                  {"homography_rms_px", r.homography_heldout_px}};
  j["bundle_adjustment"] = {{"rms_before_px", r.ba_rms_before_px}, {"rms_after_px", r.ba_rms_after_px}};
  j["field_of_view_deg"] = {{"horizontal", r.hfov_deg}, {"vertical", r.vfov_deg}};
  for (const auto& p : r.pairs)
    j["pairs"].push_back({{"cameras", {p.neighbour, p.camera}},
                          {"inputs", {o.inputs[p.neighbour], o.inputs[p.camera]}},
                          {"matches", p.matches},
                          {"inliers", p.inliers},
                          {"rms_px", p.rms_px},
                          {"accepted", p.accepted},
                          {"note", p.note}});
  for (const auto& c : r.cameras)
    j["cameras"].push_back({{"camera", c.camera},
                            {"input", o.inputs[c.camera]},
                            {"neighbours", c.neighbours},
                            {"matches", c.matches},
                            {"rms_px", c.rms_px}});
  j["warnings"] = r.warnings;
  return j;
}

}  // namespace

int main(int argc, char** argv) {
  const Options o = parse(argc, argv);
  std::vector<std::vector<cv::Mat>> sets = read_inputs(o);
  std::vector<std::vector<stitch::ImageView>> views(sets.size());
  for (std::size_t t = 0; t < sets.size(); ++t)
    for (auto& m : sets[t]) views[t].push_back(stitch::as_view(m));
  stitch::CalibrationResult r;
  try {
    if (!o.rig.empty()) {
      stitch::Rig rough = stitch::rig_load(o.rig);
      std::vector<std::array<int, 2>> sizes;
      for (const auto& m : sets[0]) sizes.push_back({m.cols, m.rows});
      if (rough.cameras.size() != sizes.size())
        die(1, "the rig describes " + std::to_string(rough.cameras.size()) + " cameras but " +
                   std::to_string(sizes.size()) + " inputs are given");
      stitch::rig_adapt_to_sizes(rough, sizes);
      if (o.reference >= 0) rough.reference = o.reference;
      r = stitch::calibrate_from_rig(rough, views, o.calib);
    } else {
      r = stitch::calibrate_from_images(views, o.reference, o.calib);
    }
    stitch::rig_save(r.rig, o.out);
  } catch (const std::exception& e) {
    die(1, std::string("calibration failed: ") + e.what());
  }
  for (const auto& w : r.warnings) std::fprintf(stderr, "warning: %s\n", w.c_str());
  std::printf("%s model, %s canvas %dx%d%s, reference %d; held-out rms: rotation %.3f px, homography %.3f px (%d matches)\n",
              stitch::camera_model_name(r.model), r.rig.projection.c_str(), r.rig.canvas_width, r.rig.canvas_height,
              r.rig.canvas_wrap ? " (360)" : "", r.rig.reference, r.rotation_heldout_px, r.homography_heldout_px,
              r.heldout_matches);
  for (const auto& p : r.pairs)
    std::printf("  pair %d-%d: %d matches, %d inliers, rms %.3f px%s%s\n", p.neighbour, p.camera, p.matches, p.inliers,
                p.rms_px, p.accepted ? "" : " (not used)", p.note.empty() ? "" : (" - " + p.note).c_str());
  if (!o.report.empty()) {
    std::ofstream f(o.report);
    f << report_json(r, o).dump(2) << "\n";
    if (!f) die(1, "cannot write " + o.report);
  }
  if (!o.preview.empty()) {
    try {
      stitch::Compositor comp(stitch::Backend::Cpu);
      comp.prepare(r.rig, stitch::CompositorSettings{});
      const stitch::OutputGeometry& g = comp.geometry();
      cv::Mat pano(g.height, g.width, CV_8UC4, cv::Scalar::all(0)), bgra;
      comp.compose(views[0], stitch::as_view(pano));
      cv::cvtColor(pano, bgra, cv::COLOR_RGBA2BGRA);
      if (!cv::imwrite(o.preview, bgra)) die(1, "cannot write " + o.preview);
    } catch (const std::exception& e) {
      die(1, std::string("preview failed: ") + e.what());
    }
  }
  std::printf("wrote %s\n", o.out.c_str());
  return 0;
}
