// stitch-render-rig: renders N overlapping camera clips from ONE real photo with exact geometry.
//
// Model: the rig frame is a virtual "photo camera" looking at the photo (intrinsics K_p, its
// focal chosen so the union of the cameras' fields of view spans ~90% of the photo). Camera c
// is a pinhole (width x height, hfov) rotated by R_c = Ry(yaw) Rx(pitch) Rz(roll) (the
// convention of stitch::Camera::R(), camera -> rig), so camera pixel p shows photo pixel
// H_c p with H_c = K_p R_c K_c^-1. Every frame is rendered with cv::warpPerspective
// (bilinear, WARP_INVERSE_MAP with H_c, border replicate) at 2x and area-downscaled (a
// 2x2 box filter whose centre is exactly the output pixel centre, so the geometry stays
// exact), then each camera gets its own gain, white balance, gamma and sensor noise.
// A textured disc cut from another part of the photo moves across the photo plane, so the
// scene changes over time while staying geometrically consistent across cameras.
//
// Output in DIR: cam0.avi .. cam{N-1}.avi (MJPEG/AVI, OpenCV's built-in encoder),
// rig_true.json (exact rig with homographies and canvas), rig_rough.json (perturbed camera
// parameters, no homographies), gt_frame0.png (ground-truth panorama of frame 0 on the
// rig_true canvas as the reference camera sees the scene: its exposure, white balance and
// gamma, no noise; alpha 0 where no camera sees) and, with --ground-truth all, gt_NNNN.png
// for every frame. --illumination-step F dims the whole scene from frame F on (a light
// switched off), so the suite can see how color correction follows a sudden change.
//
// Lenses (issue 15): --lens radtan|fisheye with --k1 --k2 --k3 --k4 --p1 --p2 renders every
// camera through that lens (planar mode: radtan; the true rig carries the lens, the rough rig the
// model without coefficients, "estimate them"). --equirect 1: the photo is a 360-degree
// equirectangular panorama and the N cameras (yaws 360/N apart; N = 2: back-to-back) look out
// of its centre; --fov sets a fisheye's field of view across its image circle (--circle 1, the
// default for fisheyes); writes cam*.avi (a static scene), rig_true.json (spherical, laid out),
// rig_rough.json and gt_frame0.png (the equirectangular ground truth on the true canvas).
//
// --ring cylindrical|spherical: instead, N cameras (yaws 360/N apart) around a full circle, the
// photo taken as a 360-degree panorama of that projection (tests/common/ring_rig.hpp); writes
// cam*.avi (a static scene), rig_true.json (laid out, wrapping canvas) and rig_rough.json.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <random>
#include <string>
#include <vector>

#include "lens_rig.hpp"
#include "ring_rig.hpp"
#include "stitch/rig/rig.hpp"

namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr int kSupersample = 2;

struct Options {
  std::string photo, out;
  int cameras = 0;
  int width = 480, height = 360, frames = 60;
  double fps = 30, hfov = 55, overlap = 0.35;
  unsigned seed = 1;
  bool moving_object = true;
  bool ground_truth_every_frame = false;
  int illumination_step = 0;           // first frame of the dimmed scene; 0 = never
  double illumination_factor = 0.7;
  std::string ring;  // empty: a planar rig; else the projection of a 360-degree ring
  // Lenses (issue 15).
  std::string lens = "pinhole";
  double k1 = 0, k2 = 0, k3 = 0, k4 = 0, p1 = 0, p2 = 0;
  double fov = 200;   // fisheye: degrees across the image circle
  int circle = -1;    // -1: fisheyes have one, others not
  bool equirect = false;
};

void usage(std::FILE* f) {
  std::fprintf(f,
               "usage: stitch-render-rig --photo PATH --cameras N --out DIR [--width 480] "
               "[--height 360]\n"
               "         [--frames 60] [--fps 30] [--hfov 55] [--overlap 0.35] [--seed 1] "
               "[--moving-object 1] [--ring cylindrical|spherical]\n"
               "         [--ground-truth first|all] [--illumination-step FRAME] [--illumination-factor 0.7]\n"
               "         [--lens pinhole|radtan|fisheye] [--k1 0] [--k2 0] [--k3 0] [--k4 0] [--p1 0] [--p2 0]\n"
               "         [--fov 200] [--circle 0|1] [--equirect 0|1]\n"
               "Renders N overlapping camera clips (camK.avi) from one photo with exact geometry,\n"
               "plus rig_true.json, rig_rough.json and gt_frame0.png.\n");
}

[[noreturn]] void die(int code, const std::string& msg) {
  std::fprintf(stderr, "stitch-render-rig: %s\n", msg.c_str());
  if (code == 2) usage(stderr);
  std::exit(code);
}

double parse_number(const std::string& key, const std::string& v) {
  char* end = nullptr;
  const double d = std::strtod(v.c_str(), &end);
  if (v.empty() || *end != '\0' || !std::isfinite(d))
    die(2, "option " + key + " needs a number, got \"" + v + "\"");
  return d;
}

int parse_int(const std::string& key, const std::string& v) {
  const double d = parse_number(key, v);
  if (d != std::floor(d) || std::abs(d) > 1e9)
    die(2, "option " + key + " needs an integer, got \"" + v + "\"");
  return int(d);
}

Options parse_args(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string key = argv[i];
    if (key == "-h" || key == "--help") {
      usage(stdout);
      std::exit(0);
    }
    if (key.rfind("--", 0) != 0) die(2, "unexpected argument \"" + key + "\"");
    if (i + 1 >= argc) die(2, "option " + key + " needs a value");
    const std::string v = argv[++i];
    if (key == "--photo") o.photo = v;
    else if (key == "--out") o.out = v;
    else if (key == "--cameras") o.cameras = parse_int(key, v);
    else if (key == "--width") o.width = parse_int(key, v);
    else if (key == "--height") o.height = parse_int(key, v);
    else if (key == "--frames") o.frames = parse_int(key, v);
    else if (key == "--fps") o.fps = parse_number(key, v);
    else if (key == "--hfov") o.hfov = parse_number(key, v);
    else if (key == "--overlap") o.overlap = parse_number(key, v);
    else if (key == "--seed") o.seed = unsigned(parse_int(key, v));
    else if (key == "--moving-object") o.moving_object = parse_int(key, v) != 0;
    else if (key == "--ground-truth") {
      if (v != "first" && v != "all") die(2, "--ground-truth must be first or all");
      o.ground_truth_every_frame = v == "all";
    } else if (key == "--illumination-step") o.illumination_step = parse_int(key, v);
    else if (key == "--illumination-factor") o.illumination_factor = parse_number(key, v);
    else if (key == "--ring") o.ring = v;
    else if (key == "--lens") o.lens = v;
    else if (key == "--k1") o.k1 = parse_number(key, v);
    else if (key == "--k2") o.k2 = parse_number(key, v);
    else if (key == "--k3") o.k3 = parse_number(key, v);
    else if (key == "--k4") o.k4 = parse_number(key, v);
    else if (key == "--p1") o.p1 = parse_number(key, v);
    else if (key == "--p2") o.p2 = parse_number(key, v);
    else if (key == "--fov") o.fov = parse_number(key, v);
    else if (key == "--circle") o.circle = parse_int(key, v);
    else if (key == "--equirect") o.equirect = parse_int(key, v) != 0;
    else die(2, "unknown option " + key);
  }
  if (o.photo.empty()) die(2, "--photo is required");
  if (o.out.empty()) die(2, "--out is required");
  if (o.cameras < 2 || o.cameras > 16) die(2, "--cameras must be between 2 and 16");
  if (o.lens != "pinhole" && o.lens != "radtan" && o.lens != "fisheye") die(2, "--lens must be pinhole, radtan or fisheye");
  if (o.lens == "fisheye" && !o.equirect) die(2, "--lens fisheye needs --equirect 1 (a planar photo cannot hold it)");
  // A full-frame fisheye (--circle 0, an action camera) sees 60-100 degrees across its shorter side.
  if (!(o.fov >= (o.circle == 0 ? 50 : 90) && o.fov <= 280))
    die(2, "--fov must be between 90 (50 with --circle 0) and 280 degrees");
  if (o.width < 16 || o.height < 16 || o.width > 8192 || o.height > 8192)
    die(2, "--width/--height must be between 16 and 8192");
  if (o.frames < 1 || o.frames > 100000) die(2, "--frames must be between 1 and 100000");
  if (!(o.fps > 0 && o.fps <= 1000)) die(2, "--fps must be in (0, 1000]");
  if (!(o.hfov >= 5 && o.hfov <= 150)) die(2, "--hfov must be between 5 and 150 degrees");
  if (!(o.overlap >= 0.05 && o.overlap <= 0.9)) die(2, "--overlap must be between 0.05 and 0.9");
  if (o.illumination_step < 0) die(2, "--illumination-step must be a frame index (0: none)");
  if (!(o.illumination_factor > 0 && o.illumination_factor <= 4))
    die(2, "--illumination-factor must be in (0, 4]");
  return o;
}

cv::Matx33d to_cv(const Eigen::Matrix3d& e) {
  cv::Matx33d m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m(r, c) = e(r, c);
  return m;
}

Eigen::Vector2d apply(const Eigen::Matrix3d& H, double x, double y) {
  Eigen::Vector3d q = H * Eigen::Vector3d(x, y, 1);
  return {q.x() / q.z(), q.y() / q.z()};
}

// Camera pixel -> photo pixel.
Eigen::Matrix3d camera_to_photo(const Eigen::Matrix3d& Kp, const stitch::Camera& c) {
  Eigen::Matrix3d H = Kp * c.R() * c.K().inverse();
  return H / H(2, 2);
}

struct Photometric {
  double gain = 1, gamma = 1;
  double wb[3] = {1, 1, 1};  // B, G, R (OpenCV order)
  cv::Mat lut;               // 1x256 CV_8UC3
};

Photometric make_photometric(std::mt19937& rng) {
  std::uniform_real_distribution<double> g(0.8, 1.2), w(-0.08, 0.08), ga(0.9, 1.1);
  Photometric p;
  p.gain = g(rng);
  for (double& k : p.wb) k = 1.0 + w(rng);
  p.gamma = ga(rng);
  p.lut = cv::Mat(1, 256, CV_8UC3);
  for (int v = 0; v < 256; ++v)
    for (int ch = 0; ch < 3; ++ch) {
      const double out = 255.0 * p.gain * p.wb[ch] * std::pow(v / 255.0, p.gamma);
      p.lut.at<cv::Vec3b>(0, v)[ch] = cv::saturate_cast<uchar>(out);
    }
  return p;
}

// A textured disc (BGR patch + soft alpha) cut from the most textured candidate spot of
// the photo that no camera sees (or the least seen one), mirrored so it is not a copy.
struct Disc {
  cv::Mat patch;  // CV_8UC3, (2r+1)^2
  cv::Mat alpha;  // CV_32F
  int radius = 0;
};

Disc make_disc(const cv::Mat& photo, int radius, const cv::Mat& seen_mask) {
  Disc d;
  d.radius = radius;
  const int size = 2 * radius + 1;
  cv::Mat gray;
  cv::cvtColor(photo, gray, cv::COLOR_BGR2GRAY);
  double best = -1;
  cv::Rect best_rect(0, 0, size, size);
  for (int gy = 0; gy < 7; ++gy)
    for (int gx = 0; gx < 9; ++gx) {
      const int x = int((photo.cols - size) * (gx + 0.5) / 9.0);
      const int y = int((photo.rows - size) * (gy + 0.5) / 7.0);
      if (x < 0 || y < 0 || x + size > photo.cols || y + size > photo.rows) continue;
      const cv::Rect r(x, y, size, size);
      cv::Mat lap;
      cv::Laplacian(gray(r), lap, CV_32F);
      cv::Scalar mean, stddev;
      cv::meanStdDev(lap, mean, stddev);
      const double seen = cv::mean(seen_mask(r))[0] / 255.0;  // fraction seen by a camera
      const double score = stddev[0] * (1.0 - 0.3 * seen);
      if (score > best) {
        best = score;
        best_rect = r;
      }
    }
  if (size > photo.cols || size > photo.rows) die(1, "the photo is too small for the moving disc");
  cv::flip(photo(best_rect), d.patch, 1);
  d.alpha = cv::Mat(size, size, CV_32F);
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      const double r = std::hypot(x - radius, y - radius);
      d.alpha.at<float>(y, x) = float(std::clamp(radius + 0.5 - r, 0.0, 1.0));
    }
  // A thin dark rim so the disc stands out against any background.
  for (int y = 0; y < size; ++y)
    for (int x = 0; x < size; ++x) {
      const double r = std::hypot(x - radius, y - radius);
      if (r > radius - 2.5 && r <= radius + 0.5) d.patch.at<cv::Vec3b>(y, x) *= 0.25;
    }
  return d;
}

// Draws the disc centred at (cx, cy) (photo pixels, sub-pixel) into `img`.
void draw_disc(cv::Mat& img, const Disc& d, double cx, double cy) {
  // Sub-pixel placement: shift the patch and its alpha by the fractional part.
  const int ix = int(std::floor(cx)), iy = int(std::floor(cy));
  const double fx = cx - ix, fy = cy - iy;
  const cv::Matx23d shift(1, 0, fx, 0, 1, fy);
  const int size = 2 * d.radius + 3;
  cv::Mat patch, alpha;
  cv::Mat padded_patch, padded_alpha;
  cv::copyMakeBorder(d.patch, padded_patch, 1, 1, 1, 1, cv::BORDER_REPLICATE);
  cv::copyMakeBorder(d.alpha, padded_alpha, 1, 1, 1, 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::warpAffine(padded_patch, patch, shift, cv::Size(size, size), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
  cv::warpAffine(padded_alpha, alpha, shift, cv::Size(size, size), cv::INTER_LINEAR, cv::BORDER_CONSTANT);
  const int x0 = ix - d.radius - 1, y0 = iy - d.radius - 1;
  for (int y = 0; y < size; ++y) {
    const int py = y0 + y;
    if (py < 0 || py >= img.rows) continue;
    for (int x = 0; x < size; ++x) {
      const int px = x0 + x;
      if (px < 0 || px >= img.cols) continue;
      const float a = alpha.at<float>(y, x);
      if (a <= 0) continue;
      cv::Vec3b& dst = img.at<cv::Vec3b>(py, px);
      const cv::Vec3b& src = patch.at<cv::Vec3b>(y, x);
      for (int ch = 0; ch < 3; ++ch) dst[ch] = cv::saturate_cast<uchar>(a * src[ch] + (1 - a) * dst[ch]);
    }
  }
}

}  // namespace

// The lens of the options on camera `cam` (its K set from --hfov, or for a fisheye from --fov
// across the inscribed image circle).
void apply_lens(const Options& o, stitch::Camera& cam) {
  if (o.lens == "fisheye") {
    const stitch::Camera f = testdata::fisheye_camera(std::min(o.width, o.height), o.fov, o.k1, o.k2);
    cam.fx = cam.fy = f.fx;
    cam.lens = f.lens;
    cam.lens.k3 = o.k3;
    cam.lens.k4 = o.k4;
    cam.lens.circle->cx = cam.cx;
    cam.lens.circle->cy = cam.cy;
    if (o.circle == 0) cam.lens.circle.reset();
    return;
  }
  if (o.lens == "radtan") {
    cam.lens.model = stitch::Lens::Model::Radtan;
    cam.lens.k1 = o.k1, cam.lens.k2 = o.k2, cam.lens.k3 = o.k3, cam.lens.p1 = o.p1, cam.lens.p2 = o.p2;
  }
  if (o.circle == 1)
    cam.lens.circle = stitch::LensCircle{cam.cx, cam.cy, 0.5 * std::min(cam.width, cam.height) - 1};
  const std::string problem = stitch::lens_problem(cam);
  if (!problem.empty()) die(2, "the lens: " + problem);
}

// The rough rig of a true one: perturbed focal and angles, lenses without coefficients.
stitch::Rig rough_of(const stitch::Rig& truth, std::mt19937& rng) {
  stitch::Rig rough = truth;
  rough.canvas_width = rough.canvas_height = 0;
  rough.canvas_scale = 0;
  std::uniform_real_distribution<double> df(-0.03, 0.03), dyaw(-2.0, 2.0), dpitch(-1.0, 1.0);
  for (auto& cam : rough.cameras) {
    cam.homography.reset();
    cam.fx *= 1.0 + df(rng);
    cam.fy = cam.fx;
    cam.yaw_deg += dyaw(rng);
    cam.pitch_deg += dpitch(rng);
    if (!cam.lens.pinhole()) {
      const auto circle = cam.lens.circle;
      const auto model = cam.lens.model;
      cam.lens = stitch::Lens{};
      cam.lens.model = model;
      cam.lens.estimate = true;
      cam.lens.circle = circle;
    }
  }
  return rough;
}

void open_writers(const Options& o, std::vector<cv::VideoWriter>& writers);

// --equirect: cameras looking out of the centre of a 360-degree photo.
int render_equirect_clips(const Options& o, const cv::Mat& photo) {
  if (photo.cols != 2 * photo.rows)
    std::fprintf(stderr, "stitch-render-rig: warning: the photo is %dx%d, not 2:1 (taken as 360 degrees wide)\n",
                 photo.cols, photo.rows);
  stitch::Rig truth;
  truth.projection = "spherical";
  truth.reference = 0;
  const double f = (o.width / 2.0) / std::tan(o.hfov * kPi / 360.0);
  for (int c = 0; c < o.cameras; ++c) {
    stitch::Camera cam;
    cam.width = o.width;
    cam.height = o.height;
    cam.fx = cam.fy = f;
    cam.cx = (o.width - 1) * 0.5;
    cam.cy = (o.height - 1) * 0.5;
    cam.yaw_deg = 360.0 * c / o.cameras;
    if (cam.yaw_deg > 180) cam.yaw_deg -= 360;
    apply_lens(o, cam);
    truth.cameras.push_back(cam);
  }
  std::mt19937 rng(o.seed);
  try {
    stitch::rig_layout_canvas(truth);
    stitch::rig_save(truth, (std::filesystem::path(o.out) / "rig_true.json").string());
    stitch::rig_save(rough_of(truth, rng), (std::filesystem::path(o.out) / "rig_rough.json").string());
  } catch (const std::exception& e) {
    die(1, std::string("cannot build the rig: ") + e.what());
  }
  cv::Mat gt = testdata::equirect_ground_truth(photo, truth), bgra;
  cv::cvtColor(gt, bgra, cv::COLOR_BGR2BGRA);
  if (!cv::imwrite((std::filesystem::path(o.out) / "gt_frame0.png").string(), bgra)) die(1, "cannot write gt_frame0.png");
  std::vector<cv::VideoWriter> writers;
  open_writers(o, writers);
  for (int c = 0; c < o.cameras; ++c) {
    const cv::Mat frame = testdata::render_camera_from_equirect(photo, truth.cameras[c], kSupersample);
    for (int t = 0; t < o.frames; ++t) writers[c].write(frame);
  }
  std::printf("%d cameras (%s) from a 360-degree photo in %s: canvas %dx%d, wraps: %s\n", o.cameras, o.lens.c_str(),
              o.out.c_str(), truth.canvas_width, truth.canvas_height, truth.canvas_wrap ? "yes" : "no");
  return 0;
}

void open_writers(const Options& o, std::vector<cv::VideoWriter>& writers) {
  writers.resize(o.cameras);
  const cv::Size size(o.width, o.height);
  for (int c = 0; c < o.cameras; ++c) {
    const std::string path = (std::filesystem::path(o.out) / ("cam" + std::to_string(c) + ".avi")).string();
    const int fourcc = cv::VideoWriter::fourcc('M', 'J', 'P', 'G');
    if (!writers[c].open(path, cv::CAP_OPENCV_MJPEG, fourcc, o.fps, size, true) &&
        !writers[c].open(path, cv::CAP_ANY, fourcc, o.fps, size, true))
      die(1, "cannot open a video writer for \"" + path + "\"");
    writers[c].set(cv::VIDEOWRITER_PROP_QUALITY, 95);
  }
}

// --ring: a 360-degree ring from the photo taken as a panorama.
int render_ring_clips(const Options& o, const cv::Mat& photo) {
  stitch::Projection kind;
  try {
    kind = stitch::projection_from_name(o.ring);
  } catch (const std::exception& e) {
    die(2, std::string("--ring: ") + e.what());
  }
  if (kind == stitch::Projection::Plane) die(2, "--ring needs cylindrical or spherical");
  if (o.cameras < 3) die(2, "--ring needs at least 3 cameras");
  const double f = (o.width / 2.0) / std::tan(o.hfov * kPi / 360.0);
  if (o.hfov * o.cameras < 370) die(2, "the ring leaves gaps: --hfov times --cameras must exceed 370 degrees");
  cv::Mat rgba;
  cv::cvtColor(photo, rgba, cv::COLOR_BGR2RGBA);
  // The photo's own left and right edges meet inside camera 1, away from the canvas wrap.
  testdata::RingScene s = testdata::render_ring(rgba, o.cameras, o.width, o.height, f, kind, 0.0, 360.0 / o.cameras);
  std::mt19937 rng(o.seed);
  stitch::Rig rough = s.truth;
  try {
    stitch::rig_layout_canvas(s.truth);
    stitch::rig_save(s.truth, (std::filesystem::path(o.out) / "rig_true.json").string());
    std::uniform_real_distribution<double> df(-0.03, 0.03), dyaw(-2.0, 2.0), dpitch(-1.0, 1.0);
    for (auto& cam : rough.cameras) {
      cam.fx *= 1.0 + df(rng);
      cam.fy = cam.fx;
      cam.yaw_deg += dyaw(rng);
      cam.pitch_deg += dpitch(rng);
    }
    stitch::rig_save(rough, (std::filesystem::path(o.out) / "rig_rough.json").string());
  } catch (const std::exception& e) {
    die(1, std::string("cannot build the ring: ") + e.what());
  }
  std::vector<cv::VideoWriter> writers;
  open_writers(o, writers);
  for (int c = 0; c < o.cameras; ++c) {
    cv::Mat bgr;
    cv::cvtColor(s.frames[c], bgr, cv::COLOR_RGBA2BGR);
    for (int t = 0; t < o.frames; ++t) writers[c].write(bgr);
  }
  std::printf("ring of %d cameras (%s) in %s: canvas %dx%d, wraps: %s\n", o.cameras, o.ring.c_str(), o.out.c_str(),
              s.truth.canvas_width, s.truth.canvas_height, s.truth.canvas_wrap ? "yes" : "no");
  return 0;
}

int main(int argc, char** argv) {
  const Options o = parse_args(argc, argv);
  if (!std::filesystem::exists(o.photo)) die(2, "photo \"" + o.photo + "\" does not exist");
  cv::Mat photo = cv::imread(o.photo, cv::IMREAD_COLOR);
  if (photo.empty()) die(2, "cannot read the photo \"" + o.photo + "\" (not an image?)");
  std::error_code ec;
  std::filesystem::create_directories(o.out, ec);
  if (!std::filesystem::is_directory(o.out)) die(1, "cannot create the output folder \"" + o.out + "\"");
  if (!o.ring.empty()) return render_ring_clips(o, photo);
  if (o.equirect) return render_equirect_clips(o, photo);

  const int n = o.cameras;
  const double hfov = o.hfov * kPi / 180.0;
  const double f_cam = (o.width / 2.0) / std::tan(hfov / 2.0);
  // Yaw step so that the last `overlap` of camera c's width shows what the first `overlap`
  // of camera c+1's width shows: the neighbour's edge ray sits at x = w (1 - overlap), i.e.
  // tan(step - hfov/2) = (1 - 2 overlap) tan(hfov/2).
  const double step_deg =
      (hfov / 2.0 + std::atan((1.0 - 2.0 * o.overlap) * std::tan(hfov / 2.0))) * 180.0 / kPi;
  const double span_deg = o.hfov + (n - 1) * step_deg;
  if (span_deg >= 160.0)
    die(2, "the cameras would span " + std::to_string(span_deg) +
               " degrees; a planar photo cannot show more than 160: use fewer cameras, a "
               "narrower --hfov or a larger --overlap");

  std::mt19937 rng(o.seed);
  std::uniform_real_distribution<double> jitter(-1.5, 1.5);
  stitch::Rig truth;
  truth.reference = n / 2;
  for (int c = 0; c < n; ++c) {
    stitch::Camera cam;
    cam.width = o.width;
    cam.height = o.height;
    cam.fx = cam.fy = f_cam;
    cam.cx = (o.width - 1) * 0.5;
    cam.cy = (o.height - 1) * 0.5;
    cam.yaw_deg = (c - (n - 1) / 2.0) * step_deg;
    cam.pitch_deg = jitter(rng);
    cam.roll_deg = jitter(rng);
    apply_lens(o, cam);
    truth.cameras.push_back(cam);
  }

  // Photo intrinsics: with a unit focal, the farthest camera corner from the photo centre
  // decides the scale; the union of the views spans 90% of the photo width (or 94% of its
  // height, whichever binds).
  const double pcx = (photo.cols - 1) * 0.5, pcy = (photo.rows - 1) * 0.5;
  double max_x = 0, max_y = 0;
  for (const auto& cam : truth.cameras) {
    Eigen::Matrix3d K1 = Eigen::Matrix3d::Identity();
    const Eigen::Matrix3d H = camera_to_photo(K1, cam);
    const double w = cam.width - 1, h = cam.height - 1;
    for (const auto& p : {Eigen::Vector2d(0, 0), Eigen::Vector2d(w, 0), Eigen::Vector2d(w, h),
                          Eigen::Vector2d(0, h), Eigen::Vector2d(w / 2, 0), Eigen::Vector2d(w / 2, h)}) {
      Eigen::Vector3d q = H * Eigen::Vector3d(p.x(), p.y(), 1);
      if (!(q.z() > 1e-6)) die(2, "a camera looks past the photo plane: narrow the rig");
      max_x = std::max(max_x, std::abs(q.x() / q.z()));
      max_y = std::max(max_y, std::abs(q.y() / q.z()));
    }
  }
  const double f_photo = std::min(0.45 * photo.cols / max_x, 0.47 * photo.rows / max_y);
  Eigen::Matrix3d Kp;
  Kp << f_photo, 0, pcx, 0, f_photo, pcy, 0, 0, 1;

  std::vector<Eigen::Matrix3d> cam2photo;
  for (const auto& cam : truth.cameras) cam2photo.push_back(camera_to_photo(Kp, cam));

  // The exact rig: homographies and canvas from the true parameters.
  try {
    stitch::rig_compute_rough_homographies(truth);
    stitch::rig_save(truth, (std::filesystem::path(o.out) / "rig_true.json").string());
  } catch (const std::exception& e) {
    die(1, std::string("cannot build the true rig: ") + e.what());
  }

  // The rough rig: perturbed parameters, no homographies (lenses: the model, no coefficients).
  stitch::Rig rough = rough_of(truth, rng);
  try {
    stitch::rig_save(rough, (std::filesystem::path(o.out) / "rig_rough.json").string());
  } catch (const std::exception& e) {
    die(1, e.what());
  }

  // Where the cameras see the photo (to cut the disc texture elsewhere).
  cv::Mat seen(photo.size(), CV_8U, cv::Scalar(0));
  for (int c = 0; c < n; ++c) {
    std::vector<cv::Point> quad;
    for (const auto& p : stitch::camera_canvas_corners(
             [&] { stitch::Camera t = truth.cameras[c]; t.homography = cam2photo[c]; return t; }()))
      quad.emplace_back(int(std::lround(p.x())), int(std::lround(p.y())));
    cv::fillConvexPoly(seen, quad, cv::Scalar(255));
  }

  // The disc path: left to right across the union of the views, slightly below the centre.
  const double disc_radius_photo = std::max(4.0, (o.height / 8.0) * f_photo / f_cam);
  const Disc disc = make_disc(photo, int(std::lround(disc_radius_photo)), seen);
  double path_y, path_x0, path_x1;
  {
    const Eigen::Vector2d centre = apply(Kp * truth.cameras[truth.reference].R(), 0, 0.08);
    path_y = centre.y();
    // Horizontal extent of the seen area on that row, inset by the radius.
    const int row = std::clamp(int(std::lround(path_y)), 0, photo.rows - 1);
    int first = -1, last = -1;
    for (int x = 0; x < photo.cols; ++x)
      if (seen.at<uchar>(row, x)) {
        if (first < 0) first = x;
        last = x;
      }
    if (first < 0) first = 0, last = photo.cols - 1;
    path_x0 = first + disc.radius;
    path_x1 = last - disc.radius;
  }

  // Writers.
  std::vector<cv::VideoWriter> writers;
  open_writers(o, writers);
  const cv::Size size(o.width, o.height);

  std::vector<Photometric> photometric;
  for (int c = 0; c < n; ++c) photometric.push_back(make_photometric(rng));

  // Supersampled pixel q <-> output pixel p (pixel-centre convention): p = (q + 0.5)/s - 0.5.
  Eigen::Matrix3d A;
  A << 1.0 / kSupersample, 0, 0.5 / kSupersample - 0.5, 0, 1.0 / kSupersample,
      0.5 / kSupersample - 0.5, 0, 0, 1;
  const cv::Size big(o.width * kSupersample, o.height * kSupersample);

  // Ground truth: canvas -> reference pixel -> photo, and where any camera sees.
  const int ref = truth.reference;
  const Eigen::Matrix3d canvas2photo = cam2photo[ref] * truth.cameras[ref].homography->inverse();
  cv::Mat coverage(truth.canvas_height, truth.canvas_width, CV_8U, cv::Scalar(0));
  for (const auto& cam : truth.cameras) {
    std::vector<cv::Point> quad;
    for (const auto& p : stitch::camera_canvas_corners(cam))
      quad.emplace_back(int(std::lround(p.x())), int(std::lround(p.y())));
    cv::fillConvexPoly(coverage, quad, cv::Scalar(255));
  }
  auto write_ground_truth = [&](const cv::Mat& scene, const std::string& name) {
    cv::Mat gt, bgra;
    cv::warpPerspective(scene, gt, cv::Mat(to_cv(canvas2photo)), cv::Size(truth.canvas_width, truth.canvas_height),
                        cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_REPLICATE);
    cv::LUT(gt, photometric[std::size_t(ref)].lut, gt);
    cv::cvtColor(gt, bgra, cv::COLOR_BGR2BGRA);
    bgra.setTo(cv::Scalar(0, 0, 0, 0), coverage == 0);
    if (!cv::imwrite((std::filesystem::path(o.out) / name).string(), bgra, {cv::IMWRITE_PNG_COMPRESSION, 1}))
      die(1, "cannot write " + name);
  };

  // Lenses: supersampled raw pixel -> ray -> ideal pixel -> photo pixel.
  std::vector<cv::Mat> lens_mx(n), lens_my(n);
  for (int c = 0; c < n; ++c) {
    const stitch::Camera& cam = truth.cameras[c];
    if (cam.lens.pinhole() && !cam.lens.circle) continue;
    lens_mx[c].create(big, CV_32F);
    lens_my[c].create(big, CV_32F);
    for (int y = 0; y < big.height; ++y)
      for (int x = 0; x < big.width; ++x) {
        const Eigen::Vector2d raw = apply(A, x, y);
        Eigen::Vector3d ray;
        float px = -1e6f, py = -1e6f;
        if (stitch::lens_unproject(cam, raw, ray) && ray.z() > 1e-9) {
          const Eigen::Vector2d q = apply(cam2photo[c] * cam.K(), ray.x() / ray.z(), ray.y() / ray.z());
          px = float(q.x()), py = float(q.y());
        }
        lens_mx[c].at<float>(y, x) = px;
        lens_my[c].at<float>(y, x) = py;
      }
  }

  cv::Mat plane;
  cv::RNG noise_rng(o.seed * 7919u + 17u);
  for (int f = 0; f < o.frames; ++f) {
    photo.copyTo(plane);
    if (o.moving_object) {
      const double t = o.frames > 1 ? double(f) / (o.frames - 1) : 0.5;
      draw_disc(plane, disc, path_x0 + t * (path_x1 - path_x0), path_y);
    }
    if (o.illumination_step > 0 && f >= o.illumination_step) plane.convertTo(plane, -1, o.illumination_factor);
    if (f == 0) write_ground_truth(plane, "gt_frame0.png");
    if (o.ground_truth_every_frame) {
      char name[32];
      std::snprintf(name, sizeof name, "gt_%04d.png", f);
      write_ground_truth(plane, name);
    }
    for (int c = 0; c < n; ++c) {
      cv::Mat hi, lo;
      if (lens_mx[c].empty())
        cv::warpPerspective(plane, hi, cv::Mat(to_cv(cam2photo[c] * A)), big,
                            cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_REPLICATE);
      else
        cv::remap(plane, hi, lens_mx[c], lens_my[c], cv::INTER_LINEAR, cv::BORDER_REPLICATE);
      cv::resize(hi, lo, size, 0, 0, cv::INTER_AREA);
      cv::LUT(lo, photometric[c].lut, lo);
      cv::Mat noise(lo.size(), CV_16SC3);
      noise_rng.fill(noise, cv::RNG::NORMAL, cv::Scalar::all(0), cv::Scalar::all(2.0));
      cv::Mat lo16;
      lo.convertTo(lo16, CV_16SC3);
      lo16 += noise;
      lo16.convertTo(lo, CV_8UC3);
      writers[c].write(lo);
    }
  }
  for (auto& w : writers) w.release();

  std::printf(
      "stitch-render-rig: %d cameras %dx%d hfov %.1f (yaw step %.2f deg, overlap %.2f), %d frames "
      "@ %.3g fps, photo %dx%d focal %.1f, canvas %dx%d, reference %d, moving object %s -> %s\n",
      n, o.width, o.height, o.hfov, step_deg, o.overlap, o.frames, o.fps, photo.cols, photo.rows,
      f_photo, truth.canvas_width, truth.canvas_height, truth.reference,
      o.moving_object ? "yes" : "no", o.out.c_str());
  return 0;
}
