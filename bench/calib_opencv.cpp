// stitch-calib-opencv: OpenCV's detail pipeline as a calibrator, for the calibration benchmark
// (bench/calib_bench.py). cv::Stitcher::estimateTransform (SIFT features, best-of-2-nearest
// matching, homography-based initial estimate, ray bundle adjustment, horizontal wave
// correction: OpenCV's defaults apart from SIFT) on the frames given, its cameras (K, R) written
// as a stitch rig of the requested projection, so that the same independent check
// (stitch-eval-alignment) judges both calibrations.
// usage: stitch-calib-opencv --out RIG.json [--projection plane|cylindrical|spherical]
//          [--start 10] [--reference K] CAMERA0 CAMERA1 ...   (clips or images)
#include <Eigen/Dense>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <opencv2/features2d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/stitching.hpp>
#include <opencv2/videoio.hpp>
#include <string>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace {

[[noreturn]] void die(int code, const std::string& msg) {
  std::fprintf(stderr, "stitch-calib-opencv: %s\n", msg.c_str());
  std::exit(code);
}

bool is_image(const std::string& path) {
  std::string ext = path.substr(path.find_last_of('.') + 1);
  for (auto& c : ext) c = char(std::tolower(c));
  return ext == "jpg" || ext == "jpeg" || ext == "png" || ext == "bmp" || ext == "tif" || ext == "tiff" || ext == "ppm";
}

cv::Mat read_frame(const std::string& path, int index) {
  if (is_image(path)) return cv::imread(path, cv::IMREAD_COLOR);
  cv::VideoCapture cap(path);
  cv::Mat f;
  for (int k = 0; k <= index; ++k)
    if (!cap.read(f)) return {};
  return f;
}

}  // namespace

int main(int argc, char** argv) {
  std::string out, projection = "plane";
  int start = 10, reference = -1;
  std::vector<std::string> inputs;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a.rfind("--", 0) != 0) {
      inputs.push_back(a);
      continue;
    }
    if (i + 1 >= argc) die(2, a + " needs a value");
    const std::string v = argv[++i];
    if (a == "--out") out = v;
    else if (a == "--projection") projection = v;
    else if (a == "--start") start = std::atoi(v.c_str());
    else if (a == "--reference") reference = std::atoi(v.c_str());
    else die(2, "unknown option " + a);
  }
  if (out.empty() || inputs.size() < 2) die(2, "usage: stitch-calib-opencv --out RIG.json CAMERA0 CAMERA1 ...");
  std::vector<cv::Mat> frames;
  for (const auto& p : inputs) {
    cv::Mat f = read_frame(p, start);
    if (f.empty()) die(1, "cannot read frame " + std::to_string(start) + " of " + p);
    frames.push_back(f);
  }
  cv::Ptr<cv::Stitcher> st = cv::Stitcher::create(cv::Stitcher::PANORAMA);
  st->setFeaturesFinder(cv::SIFT::create());
  const cv::Stitcher::Status status = st->estimateTransform(frames);
  if (status != cv::Stitcher::OK) die(1, "OpenCV could not estimate the cameras (status " + std::to_string(int(status)) + ")");
  const std::vector<int> used = st->component();
  if (used.size() != frames.size())
    die(1, "OpenCV kept " + std::to_string(used.size()) + " of " + std::to_string(frames.size()) + " cameras");
  const std::vector<cv::detail::CameraParams> cams = st->cameras();
  // Its cameras are at the registration resolution (0.6 megapixels by default).
  const double area = double(frames[0].cols) * frames[0].rows;
  const double work_scale = st->registrationResol() < 0 ? 1.0 : std::min(1.0, std::sqrt(st->registrationResol() * 1e6 / area));
  stitch::Rig rig;
  rig.projection = projection;
  rig.reference = reference >= 0 ? reference : int(frames.size()) / 2;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const cv::detail::CameraParams& c = cams[i];
    stitch::Camera cam;
    cam.width = frames[i].cols;
    cam.height = frames[i].rows;
    cam.fx = c.focal / work_scale;
    cam.fy = c.focal * c.aspect / work_scale;
    cam.cx = c.ppx / work_scale;
    cam.cy = c.ppy / work_scale;
    cv::Mat R;
    c.R.convertTo(R, CV_64F);
    Eigen::Matrix3d e;
    for (int r = 0; r < 3; ++r)
      for (int k = 0; k < 3; ++k) e(r, k) = R.at<double>(r, k);
    cam.set_R(e);
    rig.cameras.push_back(cam);
  }
  try {
    if (rig.planar()) stitch::rig_compute_rough_homographies(rig);
    else stitch::rig_layout_canvas(rig);
    stitch::rig_save(rig, out);
  } catch (const std::exception& e) {
    die(1, std::string("OpenCV's cameras give no usable canvas: ") + e.what());
  }
  std::printf("opencv: %zu cameras, %s canvas %dx%d\n", frames.size(), projection.c_str(), rig.canvas_width,
              rig.canvas_height);
  return 0;
}
