#include "stitch/rig/rig.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <iterator>

#include "stitch/rig/canvas_map.hpp"
#include "stitch/rig/lens.hpp"
#include "stitch/rig/opencv_yaml.hpp"
#include "stitch/rig/pto.hpp"
#include <cstdio>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>

namespace stitch {
namespace {

using json = nlohmann::json;
constexpr double kPi = 3.14159265358979323846;
constexpr int kMaxCameras = 64;
constexpr int kMaxSide = 32768;

double deg2rad(double d) { return d * kPi / 180.0; }

[[noreturn]] void fail(const std::string& where, const std::string& what) {
  throw RigError(where.empty() ? what : where + ": " + what);
}

double get_number(const json& obj, const char* key, const std::string& where, bool required,
                  double fallback = 0.0) {
  auto it = obj.find(key);
  if (it == obj.end()) {
    if (required) fail(where, std::string("missing \"") + key + "\"");
    return fallback;
  }
  if (!it->is_number()) fail(where, std::string("\"") + key + "\" must be a number");
  double v = it->get<double>();
  if (!std::isfinite(v)) fail(where, std::string("\"") + key + "\" is not finite");
  return v;
}

int get_int(const json& obj, const char* key, const std::string& where, bool required,
            int fallback, int lo, int hi) {
  double v = get_number(obj, key, where, required, fallback);
  if (v != std::floor(v) || v < lo || v > hi)
    fail(where, std::string("\"") + key + "\" must be an integer in [" + std::to_string(lo) +
                    ", " + std::to_string(hi) + "]");
  return static_cast<int>(v);
}

// --- lens (issue 15) -------------------------------------------------------------------------
Lens lens_from_json(const json& j, const std::string& where) {
  if (!j.is_object()) fail(where, "\"lens\" must be an object");
  Lens l;
  auto m = j.find("model");
  if (m == j.end() || !m->is_string()) fail(where, "\"lens\" needs a \"model\" (pinhole, radtan or fisheye)");
  const std::string model = m->get<std::string>();
  const char* keys_radtan[] = {"k1", "k2", "k3", "p1", "p2"};
  const char* keys_fisheye[] = {"k1", "k2", "k3", "k4"};
  std::vector<const char*> keys;
  if (model == "pinhole") l.model = Lens::Model::Pinhole;
  else if (model == "radtan") l.model = Lens::Model::Radtan, keys.assign(std::begin(keys_radtan), std::end(keys_radtan));
  else if (model == "fisheye") l.model = Lens::Model::Fisheye, keys.assign(std::begin(keys_fisheye), std::end(keys_fisheye));
  else fail(where, "lens model \"" + model + "\" is not supported (supported: pinhole, radtan, fisheye)");
  const std::string lw = where + ": lens";
  bool any = false;
  for (const char* k : keys) any |= j.contains(k);
  l.k1 = get_number(j, "k1", lw, false);
  l.k2 = get_number(j, "k2", lw, false);
  l.k3 = get_number(j, "k3", lw, false);
  if (l.model == Lens::Model::Fisheye) l.k4 = get_number(j, "k4", lw, false);
  if (l.model == Lens::Model::Radtan) {
    l.p1 = get_number(j, "p1", lw, false);
    l.p2 = get_number(j, "p2", lw, false);
  }
  l.estimate = !keys.empty() && !any;
  if (auto c = j.find("circle"); c != j.end()) {
    if (!c->is_object()) fail(lw, "\"circle\" must be an object {cx, cy, radius}");
    LensCircle k;
    k.cx = get_number(*c, "cx", lw + " circle", true);
    k.cy = get_number(*c, "cy", lw + " circle", true);
    k.radius = get_number(*c, "radius", lw + " circle", true);
    l.circle = k;
  }
  return l;
}

json lens_to_json(const Lens& l) {
  json j = {{"model", lens_model_name(l.model)}};
  if (!l.estimate) {
    if (l.model == Lens::Model::Radtan) {
      j["k1"] = l.k1, j["k2"] = l.k2, j["k3"] = l.k3, j["p1"] = l.p1, j["p2"] = l.p2;
    } else if (l.model == Lens::Model::Fisheye) {
      j["k1"] = l.k1, j["k2"] = l.k2, j["k3"] = l.k3, j["k4"] = l.k4;
    }
  }
  if (l.circle) j["circle"] = {{"cx", l.circle->cx}, {"cy", l.circle->cy}, {"radius", l.circle->radius}};
  return j;
}
// --- end lens ----------------------------------------------------------------------------------

// Keys of `j` not in `known`, each named with `where` and the known key it most likely meant
// (one that starts with it or that it starts with, or within two edits).
void note_unknown(const json& j, std::initializer_list<const char*> known, const std::string& where,
                  std::vector<std::string>& out) {
  if (!j.is_object()) return;
  const auto distance = [](const std::string& a, const std::string& b) {
    std::vector<std::size_t> prev(b.size() + 1), cur(b.size() + 1);
    for (std::size_t k = 0; k <= b.size(); ++k) prev[k] = k;
    for (std::size_t i = 1; i <= a.size(); ++i) {
      cur[0] = i;
      for (std::size_t k = 1; k <= b.size(); ++k)
        cur[k] = std::min({prev[k] + 1, cur[k - 1] + 1, prev[k - 1] + (a[i - 1] == b[k - 1] ? 0 : 1)});
      std::swap(prev, cur);
    }
    return prev[b.size()];
  };
  for (auto it = j.begin(); it != j.end(); ++it) {
    const std::string key = it.key();
    bool found = false;
    std::string guess;
    for (const char* k : known) {
      const std::string kk = k;
      if (kk == key) found = true;
      else if (guess.empty() && !key.empty() && (kk.rfind(key, 0) == 0 || key.rfind(kk, 0) == 0 || distance(key, kk) <= 2))
        guess = kk;
    }
    if (found) continue;
    out.push_back((where.empty() ? "" : where + ": ") + "\"" + key + "\"" +
                  (guess.empty() ? std::string() : " (did you mean \"" + guess + "\"?)"));
  }
}

Camera camera_from_json(const json& j, int index) {
  const std::string where = "camera " + std::to_string(index);
  if (!j.is_object()) fail(where, "must be an object");
  Camera c;
  c.width = get_int(j, "width", where, true, 0, 1, kMaxSide);
  c.height = get_int(j, "height", where, true, 0, 1, kMaxSide);
  c.fx = get_number(j, "fx", where, true);
  c.fy = get_number(j, "fy", where, false, c.fx);
  c.cx = get_number(j, "cx", where, false, (c.width - 1) * 0.5);
  c.cy = get_number(j, "cy", where, false, (c.height - 1) * 0.5);
  if (c.fx <= 0 || c.fy <= 0) fail(where, "focal lengths must be positive");
  c.yaw_deg = get_number(j, "yaw_deg", where, false);
  c.pitch_deg = get_number(j, "pitch_deg", where, false);
  c.roll_deg = get_number(j, "roll_deg", where, false);
  if (auto it = j.find("t"); it != j.end()) {
    if (!it->is_array() || it->size() != 3) fail(where, "\"t\" must be an array of 3 numbers");
    Eigen::Vector3d t;
    for (int k = 0; k < 3; ++k) {
      if (!(*it)[k].is_number()) fail(where, "\"t\" must be an array of 3 numbers");
      t[k] = (*it)[k].get<double>();
      if (!std::isfinite(t[k])) fail(where, "\"t\" is not finite");
    }
    c.t = t;
  }
  if (auto it = j.find("homography"); it != j.end()) {
    if (!it->is_array() || it->size() != 9)
      fail(where, "\"homography\" must be an array of 9 numbers (row-major)");
    Eigen::Matrix3d H;
    for (int k = 0; k < 9; ++k) {
      if (!(*it)[k].is_number()) fail(where, "\"homography\" must hold numbers");
      H(k / 3, k % 3) = (*it)[k].get<double>();
    }
    c.homography = H;  // checked below, with the lens
  }
  // time alignment (stitchsync): an optional integer number of ns, within a day
  if (auto it = j.find("time_offset_ns"); it != j.end()) {
    if (!it->is_number_integer() || std::fabs(it->get<double>()) > 86400e9)
      fail(where, "\"time_offset_ns\" must be an integer number of ns within a day");
    c.time_offset_ns = it->get<int64_t>();
  }
  // --- lens (issue 15)
  if (auto it = j.find("lens"); it != j.end()) {
    c.lens = lens_from_json(*it, where);
    const std::string problem = lens_problem(c);
    if (!problem.empty()) fail(where, problem);
  }
  // --- end lens
  if (c.homography) {
    const std::string problem = camera_homography_problem(c);
    if (!problem.empty()) fail(where, "degenerate homography: " + problem);
  }
  return c;
}

}  // namespace

// --- lens (issue 15)
const char* lens_model_name(Lens::Model m) {
  switch (m) {
    case Lens::Model::Pinhole: return "pinhole";
    case Lens::Model::Radtan: return "radtan";
    case Lens::Model::Fisheye: return "fisheye";
  }
  return "?";
}

bool Lens::operator==(const Lens& o) const {
  const bool same_circle = bool(circle) == bool(o.circle) &&
                           (!circle || (circle->cx == o.circle->cx && circle->cy == o.circle->cy &&
                                        circle->radius == o.circle->radius));
  return model == o.model && k1 == o.k1 && k2 == o.k2 && k3 == o.k3 && k4 == o.k4 && p1 == o.p1 && p2 == o.p2 &&
         estimate == o.estimate && same_circle;
}
// --- end lens

Eigen::Matrix3d Camera::K() const {
  Eigen::Matrix3d k;
  k << fx, 0, cx, 0, fy, cy, 0, 0, 1;
  return k;
}

Eigen::Matrix3d Camera::R() const {
  const double y = deg2rad(yaw_deg), p = deg2rad(pitch_deg), r = deg2rad(roll_deg);
  Eigen::Matrix3d Ry, Rx, Rz;
  Ry << std::cos(y), 0, std::sin(y), 0, 1, 0, -std::sin(y), 0, std::cos(y);
  // +pitch looks up: the optical axis tilts towards -y (image up).
  Rx << 1, 0, 0, 0, std::cos(p), -std::sin(p), 0, std::sin(p), std::cos(p);
  Rz << std::cos(r), -std::sin(r), 0, std::sin(r), std::cos(r), 0, 0, 0, 1;
  return Ry * Rx * Rz;
}

void Camera::set_R(const Eigen::Matrix3d& R) {
  // R = Ry(yaw) Rx(pitch) Rz(roll): column 2 = (cos p sin y, -sin p, cos p cos y),
  // row 1 = (cos p sin r, cos p cos r, -sin p).
  pitch_deg = std::asin(std::clamp(-R(1, 2), -1.0, 1.0)) * 180.0 / kPi;
  yaw_deg = std::atan2(R(0, 2), R(2, 2)) * 180.0 / kPi;
  roll_deg = std::atan2(R(1, 0), R(1, 1)) * 180.0 / kPi;
}

const char* projection_name(Projection p) {
  switch (p) {
    case Projection::Plane: return "plane";
    case Projection::Cylindrical: return "cylindrical";
    case Projection::Spherical: return "spherical";
    case Projection::Cubemap: return "cubemap";
  }
  return "?";
}

Projection projection_from_name(const std::string& name) {
  if (name == "plane") return Projection::Plane;
  if (name == "cylindrical") return Projection::Cylindrical;
  if (name == "spherical") return Projection::Spherical;
  if (name == "cubemap") return Projection::Cubemap;
  throw RigError("projection \"" + name + "\" is not supported (supported: plane, cylindrical, spherical, cubemap)");
}

bool any_left_out(const Rig& rig) {
  for (const auto& c : rig.cameras)
    if (c.left_out) return true;
  return false;
}

bool Rig::calibrated() const {
  if (canvas_width <= 0 || canvas_height <= 0 || cameras.empty()) return false;
  if (!planar()) return canvas_scale > 0;
  for (const auto& c : cameras)
    if (!c.homography) return false;
  return true;
}

Rig rig_from_json_string(const std::string& text) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    /* parse errors, and numbers out of range (1e999): found by tests/fuzz */
    throw RigError(std::string("malformed JSON: ") + e.what());
  }
  if (!j.is_object()) fail("", "the rig must be a JSON object");
  if (auto it = j.find("format"); it != j.end() && (!it->is_string() || *it != "stitch-rig"))
    fail("", "\"format\" must be \"stitch-rig\"");
  if (auto it = j.find("version"); it != j.end() && (!it->is_number() || it->get<double>() != 1))
    fail("", "unsupported \"version\" (this build reads version 1)");
  Rig rig;
  if (auto it = j.find("projection"); it != j.end()) {
    if (!it->is_string()) fail("", "\"projection\" must be a string");
    rig.projection = it->get<std::string>();
  } else {
    rig.projection_default = true;
  }
  projection_from_name(rig.projection);  // throws, naming the supported ones
  auto cams = j.find("cameras");
  if (cams == j.end() || !cams->is_array() || cams->empty())
    fail("", "\"cameras\" must be a non-empty array");
  if (cams->size() > kMaxCameras) fail("", "too many cameras (at most 64)");
  for (std::size_t i = 0; i < cams->size(); ++i)
    rig.cameras.push_back(camera_from_json((*cams)[i], static_cast<int>(i)));
  note_unknown(j, {"format", "version", "projection", "reference", "canvas", "cameras", "plane_distance_m"}, "",
               rig.unknown_fields);
  for (std::size_t i = 0; i < cams->size(); ++i)
    note_unknown((*cams)[i],
                 {"width", "height", "fx", "fy", "cx", "cy", "yaw_deg", "pitch_deg", "roll_deg", "t", "homography",
                  "time_offset_ns", "lens"},
                 "camera " + std::to_string(i), rig.unknown_fields);
  if (auto it = j.find("canvas"); it != j.end())
    note_unknown(*it, {"width", "height", "scale", "origin_x", "origin_y", "wrap"}, "canvas", rig.unknown_fields);
  rig.reference = get_int(j, "reference", "", false, static_cast<int>(rig.cameras.size() / 2), 0,
                          static_cast<int>(rig.cameras.size()) - 1);
  rig.plane_distance_m = get_number(j, "plane_distance_m", "", false, 0.0);
  if (rig.plane_distance_m < 0) fail("", "\"plane_distance_m\" must be >= 0");
  if (auto it = j.find("canvas"); it != j.end()) {
    if (!it->is_object()) fail("", "\"canvas\" must be an object");
    rig.canvas_width = get_int(*it, "width", "canvas", true, 0, 1, kMaxSide);
    rig.canvas_height = get_int(*it, "height", "canvas", true, 0, 1, kMaxSide);
    if (!rig.planar()) {
      rig.canvas_scale = get_number(*it, "scale", "canvas", true);
      if (rig.canvas_scale <= 0) fail("canvas", "\"scale\" must be positive (pixels per radian)");
      rig.canvas_origin_x = get_number(*it, "origin_x", "canvas", true);
      rig.canvas_origin_y = get_number(*it, "origin_y", "canvas", true);
      if (auto w = it->find("wrap"); w != it->end()) {
        if (!w->is_boolean()) fail("canvas", "\"wrap\" must be true or false");
        rig.canvas_wrap = w->get<bool>();
      }
    }
  }
  return rig;
}

Rig rig_load(const std::string& path) {
  // --- lens (issue 15): other calibration formats by extension
  auto ends_with = [&](const char* ext) {
    const std::string e(ext);
    if (path.size() < e.size()) return false;
    std::string tail = path.substr(path.size() - e.size());
    std::transform(tail.begin(), tail.end(), tail.begin(), [](unsigned char ch) { return char(std::tolower(ch)); });
    return tail == e;
  };
  if (ends_with(".yaml") || ends_with(".yml")) return rig_load_opencv_yaml(path);
  if (ends_with(".pto")) return rig_load_pto(path);
  // --- end lens
  std::ifstream in(path, std::ios::binary);
  if (!in) throw RigError("cannot open rig file \"" + path + "\"");
  std::ostringstream ss;
  ss << in.rdbuf();
  try {
    return rig_from_json_string(ss.str());
  } catch (const RigError& e) {
    throw RigError("rig file \"" + path + "\": " + e.what());
  }
}

std::string rig_to_json_string(const Rig& rig) {
  for (std::size_t i = 0; i < rig.cameras.size(); ++i)
    if (rig.cameras[i].left_out)
      throw RigError("camera " + std::to_string(i) + " is left out of this calibration (no usable frame when it was made): not written");
  json j;
  j["format"] = "stitch-rig";
  j["version"] = 1;
  j["projection"] = rig.projection;
  j["reference"] = rig.reference;
  if (rig.plane_distance_m > 0) j["plane_distance_m"] = rig.plane_distance_m;
  if (rig.canvas_width > 0 && rig.canvas_height > 0) {
    j["canvas"] = {{"width", rig.canvas_width}, {"height", rig.canvas_height}};
    if (!rig.planar() && rig.canvas_scale > 0) {
      j["canvas"]["scale"] = rig.canvas_scale;
      j["canvas"]["origin_x"] = rig.canvas_origin_x;
      j["canvas"]["origin_y"] = rig.canvas_origin_y;
      j["canvas"]["wrap"] = rig.canvas_wrap;
    }
  }
  j["cameras"] = json::array();
  for (const auto& c : rig.cameras) {
    json cj = {{"width", c.width}, {"height", c.height}, {"fx", c.fx},   {"fy", c.fy},
               {"cx", c.cx},       {"cy", c.cy},         {"yaw_deg", c.yaw_deg},
               {"pitch_deg", c.pitch_deg},               {"roll_deg", c.roll_deg}};
    if (c.t) cj["t"] = {(*c.t)[0], (*c.t)[1], (*c.t)[2]};
    if (c.homography) {
      json h = json::array();
      for (int k = 0; k < 9; ++k) h.push_back((*c.homography)(k / 3, k % 3));
      cj["homography"] = h;
    }
    if (c.time_offset_ns) cj["time_offset_ns"] = *c.time_offset_ns;
    if (!c.lens.pinhole() || c.lens.circle) cj["lens"] = lens_to_json(c.lens);  // lens (issue 15)
    j["cameras"].push_back(cj);
  }
  return j.dump(2);
}

void rig_save(const Rig& rig, const std::string& path) {
  const std::string tmp = path + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    if (!out) throw RigError("cannot write calibration file \"" + path + "\"");
    out << rig_to_json_string(rig) << "\n";
    if (!out) throw RigError("cannot write calibration file \"" + path + "\"");
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    throw RigError("cannot write calibration file \"" + path + "\"");
}

Eigen::Vector2d apply_homography(const Eigen::Matrix3d& H, const Eigen::Vector2d& p) {
  Eigen::Vector3d q = H * Eigen::Vector3d(p.x(), p.y(), 1.0);
  return {q.x() / q.z(), q.y() / q.z()};
}

Eigen::Matrix3d rough_pairwise_homography(const Rig& rig, int src, int dst) {
  const Camera& s = rig.cameras.at(src);
  const Camera& d = rig.cameras.at(dst);
  // Ray in src camera -> rig frame -> dst camera.
  Eigen::Matrix3d R_ds = d.R().transpose() * s.R();
  Eigen::Matrix3d H = d.K() * R_ds * s.K().inverse();
  if (rig.plane_distance_m > 0 && (s.t || d.t)) {
    // Plane z = plane_distance_m in the dst camera frame (fronto-parallel scene plane).
    Eigen::Vector3d ts = s.t.value_or(Eigen::Vector3d::Zero());
    Eigen::Vector3d td = d.t.value_or(Eigen::Vector3d::Zero());
    Eigen::Vector3d C = d.R().transpose() * (ts - td);  // src centre in dst frame
    Eigen::Vector3d n(0, 0, 1);
    // X_src = R_sd (X_dst - C): the plane-induced map dst->src is K_s R_sd (I - C n^T/d) K_d^-1.
    Eigen::Matrix3d R_sd = R_ds.transpose();
    Eigen::Matrix3d H_ds =
        s.K() * R_sd * (Eigen::Matrix3d::Identity() - C * n.transpose() / rig.plane_distance_m) *
        d.K().inverse();
    H = H_ds.inverse();
  }
  return H / H(2, 2);
}

std::array<Eigen::Vector2d, 4> camera_canvas_corners(const Camera& cam) {
  const Eigen::Matrix3d& H = cam.homography.value();
  const double w = cam.width - 1, h = cam.height - 1;
  return {apply_homography(H, {0, 0}), apply_homography(H, {w, 0}), apply_homography(H, {w, h}),
          apply_homography(H, {0, h})};
}

std::string camera_homography_problem(const Camera& c) {
  if (!c.homography) return "none";
  const Eigen::Matrix3d& H = *c.homography;
  if (c.lens.pinhole() && !c.lens.circle) return homography_problem(H, c.width, c.height);
  // A lens: H maps ideal pixels, and a wide lens may see past the plane's horizon (a fisheye
  // over the ground): the frame's corners need not land on the canvas, some of the image must
  // (its centre, or a corner or edge middle).
  if (!H.allFinite()) return "contains NaN or Inf";
  const double det = H.determinant();
  if (!std::isfinite(det) || std::abs(det) < 1e-12) return "singular";
  for (double y : {0.0, 0.5, 1.0})
    for (double x : {0.0, 0.5, 1.0})
      if ((H * Eigen::Vector3d(x * (c.width - 1), y * (c.height - 1), 1.0)).z() > 1e-9) return {};
  return "maps the whole image behind the canvas";
}

std::string homography_problem(const Eigen::Matrix3d& H, int width, int height) {
  if (!H.allFinite()) return "contains NaN or Inf";
  const double det = H.determinant();
  if (!std::isfinite(det) || std::abs(det) < 1e-12) return "singular";
  const double w = width - 1, h = height - 1;
  const Eigen::Vector2d corners[4] = {{0, 0}, {w, 0}, {w, h}, {0, h}};
  Eigen::Vector2d q[4];
  for (int k = 0; k < 4; ++k) {
    Eigen::Vector3d p = H * Eigen::Vector3d(corners[k].x(), corners[k].y(), 1.0);
    if (!(p.z() > 1e-9)) return "maps part of the image behind the canvas (the view folds over)";
    q[k] = p.head<2>() / p.z();
  }
  // The warped quad must stay convex with the same orientation as the image (no mirror).
  for (int k = 0; k < 4; ++k) {
    Eigen::Vector2d a = q[(k + 1) % 4] - q[k], b = q[(k + 2) % 4] - q[(k + 1) % 4];
    if (a.x() * b.y() - a.y() * b.x() <= 0) return "mirrored or folded (the warped image is not convex)";
  }
  double area = 0;
  for (int k = 0; k < 4; ++k) area += q[k].x() * q[(k + 1) % 4].y() - q[(k + 1) % 4].x() * q[k].y();
  area *= 0.5;
  const double src_area = std::max(1.0, w * h);
  if (area < src_area * 1e-4) return "collapses the image to (almost) nothing";
  if (area > src_area * 1e4) return "blows the image up more than 100x";
  return {};
}

void rig_layout_canvas(Rig& rig) {
  if (!rig.planar()) return layout_projected_canvas(rig);
  double minx = std::numeric_limits<double>::max(), miny = minx;
  double maxx = -minx, maxy = -minx;
  double input_area = 0;
  for (std::size_t i = 0; i < rig.cameras.size(); ++i) {
    const Camera& c = rig.cameras[i];
    if (c.left_out) continue;
    if (!c.homography) throw RigError("camera " + std::to_string(i) + " has no homography");
    std::string problem = camera_homography_problem(c);
    if (!problem.empty())
      throw RigError("camera " + std::to_string(i) + ": degenerate homography: " + problem);
    std::vector<Eigen::Vector2d> outline;  // lens (issue 15): the undistorted border
    if (c.lens.pinhole() && !c.lens.circle) {
      const auto q4 = camera_canvas_corners(c);
      outline.assign(q4.begin(), q4.end());
    } else {
      outline = camera_canvas_outline(rig, static_cast<int>(i));
    }
    for (const auto& q : outline) {
      minx = std::min(minx, q.x());
      miny = std::min(miny, q.y());
      maxx = std::max(maxx, q.x());
      maxy = std::max(maxy, q.y());
    }
    input_area += double(c.width) * c.height;
  }
  // Pixel centres span [min, max]; after shifting by floor(min) the last centre is at
  // max - floor(min), so the canvas needs that many pixels plus one.
  const double cw = std::ceil(maxx - std::floor(minx)) + 1, ch = std::ceil(maxy - std::floor(miny)) + 1;
  if (cw > kMaxSide || ch > kMaxSide || cw * ch > 16.0 * input_area)
    throw RigError("degenerate geometry: the planar canvas would be " + std::to_string(int(cw)) +
                   "x" + std::to_string(int(ch)) +
                   " pixels (views at grazing angles to the reference plane)");
  Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
  T(0, 2) = -std::floor(minx);
  T(1, 2) = -std::floor(miny);
  for (auto& c : rig.cameras) {
    Eigen::Matrix3d H = T * *c.homography;
    c.homography = H / H(2, 2);
  }
  rig.canvas_width = static_cast<int>(cw);
  rig.canvas_height = static_cast<int>(ch);
}

void rig_compute_rough_homographies(Rig& rig) {
  if (rig.reference < 0 || rig.reference >= static_cast<int>(rig.cameras.size()))
    throw RigError("reference camera index out of range");
  if (!rig.planar()) return rig_layout_canvas(rig);  // K and R are the whole model
  for (std::size_t i = 0; i < rig.cameras.size(); ++i)
    rig.cameras[i].homography = rough_pairwise_homography(rig, static_cast<int>(i), rig.reference);
  rig_layout_canvas(rig);
}

bool rig_adapt_to_sizes(Rig& rig, const std::vector<std::array<int, 2>>& sizes) {
  bool changed = false;
  for (std::size_t i = 0; i < rig.cameras.size() && i < sizes.size(); ++i) {
    Camera& c = rig.cameras[i];
    const int w = sizes[i][0], h = sizes[i][1];
    if (c.width == w && c.height == h) continue;
    // Stream pixel -> rig pixel with pixel-centre convention: p_r = (p_s + 0.5) * s - 0.5.
    const double sx = double(c.width) / w, sy = double(c.height) / h;
    Eigen::Matrix3d S;
    S << sx, 0, 0.5 * sx - 0.5, 0, sy, 0.5 * sy - 0.5, 0, 0, 1;
    if (c.homography) {
      Eigen::Matrix3d H = *c.homography * S;
      c.homography = H / H(2, 2);
    }
    c.fx /= sx;
    c.fy /= sy;
    c.cx = (c.cx + 0.5) / sx - 0.5;
    c.cy = (c.cy + 0.5) / sy - 0.5;
    if (c.lens.circle) {  // lens (issue 15)
      c.lens.circle->cx = (c.lens.circle->cx + 0.5) / sx - 0.5;
      c.lens.circle->cy = (c.lens.circle->cy + 0.5) / sy - 0.5;
      c.lens.circle->radius /= 0.5 * (sx + sy);
    }
    c.width = w;
    c.height = h;
    changed = true;
  }
  // A projected canvas follows the cameras' new focal lengths (rig_layout_canvas picks it again).
  if (changed && !rig.planar()) rig.canvas_scale = 0;
  return changed;
}

}  // namespace stitch
