#include "stitch/rig/opencv_yaml.hpp"

#include <Eigen/Dense>
#include <cmath>
#include <opencv2/core.hpp>

#include "stitch/rig/lens.hpp"

namespace stitch {
namespace {

std::vector<double> numbers(const cv::FileNode& n) {
  std::vector<double> v;
  if (n.empty() || n.isNone()) return v;
  if (n.isMap()) {  // !!opencv-matrix
    cv::Mat m;
    n >> m;
    m.convertTo(m, CV_64F);
    for (int k = 0; k < int(m.total()); ++k) v.push_back(m.at<double>(k));
    return v;
  }
  if (n.isSeq()) {
    for (const auto& e : n) {
      if (e.isSeq()) {
        for (const auto& f : e) v.push_back(double(f));
      } else {
        v.push_back(double(e));
      }
    }
    return v;
  }
  if (n.isReal() || n.isInt()) v.push_back(double(n));
  return v;
}

std::string text(const cv::FileNode& n) { return n.isString() ? std::string(n) : std::string(); }

Camera camera_from_node(const cv::FileNode& n, const std::string& where, Eigen::Matrix3d* T_rot) {
  Camera c;
  std::vector<double> K = numbers(n["camera_matrix"]);
  std::vector<double> intr = numbers(n["intrinsics"]);
  if (K.size() == 9) {
    c.fx = K[0], c.fy = K[4], c.cx = K[2], c.cy = K[5];
  } else if (intr.size() == 4) {
    c.fx = intr[0], c.fy = intr[1], c.cx = intr[2], c.cy = intr[3];
  } else {
    throw RigError(where + ": needs a 3x3 \"camera_matrix\" (or Kalibr's 4 \"intrinsics\")");
  }
  std::vector<double> res = numbers(n["resolution"]);
  if (res.size() == 2) c.width = int(res[0]), c.height = int(res[1]);
  if (!n["image_width"].empty()) c.width = int(n["image_width"]), c.height = int(n["image_height"]);
  if (c.width <= 0 || c.height <= 0)
    throw RigError(where + ": needs the image size (\"resolution\" [w, h] or \"image_width\"/\"image_height\")");
  if (!(c.fx > 0 && c.fy > 0)) throw RigError(where + ": focal lengths must be positive");
  std::vector<double> d = numbers(n["dist_coeffs"]);
  if (d.empty()) d = numbers(n["distortion_coefficients"]);
  if (d.empty()) d = numbers(n["distortion_coeffs"]);
  std::string model = text(n["distortion_model"]);
  if (model.empty()) model = text(n["model"]);
  bool fisheye;
  if (model == "equidistant" || model == "fisheye" || model == "kannala_brandt") fisheye = true;
  else if (model == "plumb_bob" || model == "radtan" || model == "pinhole" || model == "rational_polynomial") fisheye = false;
  else if (!model.empty())
    throw RigError(where + ": distortion model \"" + model + "\" is not supported (radtan/plumb_bob, equidistant/fisheye)");
  else fisheye = d.size() == 4;
  if (fisheye) {
    if (d.size() != 4) throw RigError(where + ": a fisheye lens needs 4 coefficients (k1..k4)");
    c.lens.model = Lens::Model::Fisheye;
    c.lens.k1 = d[0], c.lens.k2 = d[1], c.lens.k3 = d[2], c.lens.k4 = d[3];
  } else if (!d.empty()) {
    if (d.size() < 4) throw RigError(where + ": radtan needs at least 4 coefficients (k1 k2 p1 p2 [k3])");
    for (std::size_t k = 5; k < d.size(); ++k)
      if (d[k] != 0)
        throw RigError(where + ": rational / thin-prism distortion terms (k4.. beyond k1 k2 p1 p2 k3) are not supported");
    c.lens.model = Lens::Model::Radtan;
    c.lens.k1 = d[0], c.lens.k2 = d[1], c.lens.p1 = d[2], c.lens.p2 = d[3], c.lens.k3 = d.size() > 4 ? d[4] : 0;
  }
  if (!n["yaw_deg"].empty()) c.yaw_deg = double(n["yaw_deg"]);
  if (!n["pitch_deg"].empty()) c.pitch_deg = double(n["pitch_deg"]);
  if (!n["roll_deg"].empty()) c.roll_deg = double(n["roll_deg"]);
  std::vector<double> T = numbers(n["T_cn_cnm1"]);
  if (T.size() == 16 && T_rot) {
    for (int r = 0; r < 3; ++r)
      for (int k = 0; k < 3; ++k) (*T_rot)(r, k) = T[4 * r + k];
  }
  // OpenCV's fits of wide lenses often fold back in the frame's black corners, outside what the
  // calibration saw (the surround-view set's left camera at 87 degrees): an image circle ends
  // the lens just before the fold rather than refusing the file. A fold well inside the frame
  // is still refused below.
  lens_cap_at_fold(c);
  const std::string problem = lens_problem(c);
  if (!problem.empty()) throw RigError(where + ": " + problem);
  return c;
}

}  // namespace

Rig rig_load_opencv_yaml(const std::string& path) {
  cv::FileStorage fs;
  try {
    if (!fs.open(path, cv::FileStorage::READ)) throw RigError("cannot open calibration file \"" + path + "\"");
  } catch (const cv::Exception& e) {
    throw RigError("calibration file \"" + path + "\": not readable YAML (" + e.err + ")");
  }
  Rig rig;
  try {
    const cv::FileNode root = fs.root();
    if (!text(root["projection"]).empty()) rig.projection = text(root["projection"]);
    else rig.projection_default = true;  // plane unless the views need more (check_plane_canvas)
    projection_from_name(rig.projection);
    if (!root["camera_matrix"].empty()) {
      rig.cameras.push_back(camera_from_node(root, "camera 0", nullptr));
    } else {
      Eigen::Matrix3d R_prev = Eigen::Matrix3d::Identity();
      for (int i = 0; i < 64; ++i) {
        const cv::FileNode n = root["cam" + std::to_string(i)];
        if (n.empty()) break;
        Eigen::Matrix3d T = Eigen::Matrix3d::Zero();
        Camera c = camera_from_node(n, "camera " + std::to_string(i), &T);
        if (i > 0 && T != Eigen::Matrix3d::Zero()) {
          // X_n = T X_{n-1}: camera n's ray in the rig (camera 0) frame is R_{n-1} T^T.
          const Eigen::Matrix3d R = R_prev * T.transpose();
          c.set_R(R);
        }
        R_prev = c.R();
        rig.cameras.push_back(c);
      }
    }
    if (rig.cameras.empty())
      throw RigError("holds no camera (\"camera_matrix\" at the top, or maps cam0, cam1, ...)");
    rig.reference = int(rig.cameras.size()) / 2;
    if (!root["reference"].empty()) rig.reference = int(root["reference"]);
    if (rig.reference < 0 || rig.reference >= int(rig.cameras.size())) throw RigError("\"reference\" out of range");
  } catch (const RigError& e) {
    throw RigError("calibration file \"" + path + "\": " + e.what());
  } catch (const cv::Exception& e) {
    throw RigError("calibration file \"" + path + "\": " + e.err);
  }
  if (rig.cameras.size() > 1) {
    try {
      rig_compute_rough_homographies(rig);
    } catch (const RigError&) {
      // Cameras that do not overlap (or a canvas that cannot hold them): left rough.
      for (auto& c : rig.cameras) c.homography.reset();
      rig.canvas_width = rig.canvas_height = 0;
      rig.canvas_scale = 0;
    }
  }
  return rig;
}

}  // namespace stitch
