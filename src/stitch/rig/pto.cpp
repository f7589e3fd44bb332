#include "stitch/rig/pto.hpp"

#include <Eigen/Dense>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>

#include "stitch/rig/lens.hpp"

namespace stitch {
namespace {

constexpr double kPi = 3.14159265358979323846;

struct Line {
  std::map<std::string, std::string> v;  // key -> value text ("=0" for back-references)
};

// Splits "w1920 h1080 f0 v50 n\"a b.jpg\"" into key/value pairs (keys: leading letters).
Line parse_line(const std::string& body) {
  Line l;
  std::size_t i = 0;
  while (i < body.size()) {
    while (i < body.size() && std::isspace(static_cast<unsigned char>(body[i]))) ++i;
    if (i >= body.size()) break;
    std::size_t k = i;
    while (k < body.size() && std::isalpha(static_cast<unsigned char>(body[k]))) ++k;
    std::string key = body.substr(i, k - i), val;
    if (key.empty()) {  // stray token
      while (i < body.size() && !std::isspace(static_cast<unsigned char>(body[i]))) ++i;
      continue;
    }
    if (k < body.size() && body[k] == '"') {
      const std::size_t e = body.find('"', k + 1);
      val = body.substr(k + 1, e == std::string::npos ? std::string::npos : e - k - 1);
      i = e == std::string::npos ? body.size() : e + 1;
    } else {
      std::size_t e = k;
      while (e < body.size() && !std::isspace(static_cast<unsigned char>(body[e]))) ++e;
      val = body.substr(k, e - k);
      i = e;
    }
    // Multi-letter keys that panotools uses (Eev, Er, Eb, Ra.., Va.., Tr..): keep as they are;
    // single-letter keys may be glued to their value (v50): split at the first letter.
    l.v[key] = val;
  }
  return l;
}

}  // namespace

double fit_panotools_radial(double a, double b, double c, double f, double half_short, double max_radius_px,
                            bool fisheye, Lens& lens, double& focal) {
  const double d = 1 - a - b - c;
  auto raw_radius = [&](double r_ideal_px) {  // panotools: ideal -> raw, normalised by half_short
    const double r = r_ideal_px / half_short;
    return (((a * r + b) * r + c) * r + d) * r * half_short;
  };
  // Sample the ideal radius up to where the raw radius reaches max_radius_px.
  double r_max = max_radius_px;
  for (int it = 0; it < 60 && raw_radius(r_max) < max_radius_px; ++it) r_max *= 1.05;
  // Raw radius R = focal t (1 + k1 t^2 + ...), t = r / f (the ray's tangent, or its angle for a
  // fisheye): linear in (focal, focal k1, focal k2, ...).
  const int n = 400, terms = fisheye ? 5 : 4;
  Eigen::MatrixXd A(n, terms);
  Eigen::VectorXd y(n);
  for (int k = 0; k < n; ++k) {
    const double r_px = r_max * (k + 1) / n, t = r_px / f;
    double p = t;
    for (int j = 0; j < terms; ++j, p *= t * t) A(k, j) = p;
    y[k] = raw_radius(r_px);
  }
  const Eigen::VectorXd sol = A.colPivHouseholderQr().solve(y);
  focal = sol[0];
  lens = Lens{};
  lens.model = fisheye ? Lens::Model::Fisheye : Lens::Model::Radtan;
  lens.k1 = sol[1] / focal;
  lens.k2 = sol[2] / focal;
  lens.k3 = sol[3] / focal;
  if (fisheye) lens.k4 = sol[4] / focal;
  return (A * sol - y).cwiseAbs().maxCoeff();
}

Rig rig_from_pto_string(const std::string& text, PtoReport* report) {
  Rig rig;
  std::istringstream in(text);
  std::string line;
  std::vector<Line> images;
  double pano_w = 0, pano_v = 0;
  int pano_f = 0;
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.size() < 2 || line[1] != ' ') continue;
    if (line[0] == 'i') images.push_back(parse_line(line.substr(2)));
    if (line[0] == 'p') {
      // p-line keys are glued to their values: f2 w3000 h1500 v360.
      std::istringstream ps(line.substr(2));
      std::string tok;
      while (ps >> tok) {
        if (tok.size() < 2) continue;
        const char k = tok[0];
        const double val = std::atof(tok.c_str() + 1);
        if (k == 'f' && std::isdigit(static_cast<unsigned char>(tok[1]))) pano_f = int(val);
        if (k == 'w') pano_w = val;
        if (k == 'v') pano_v = val;
      }
    }
  }
  if (images.empty()) throw RigError("the project holds no image (\"i\" lines)");
  if (images.size() > 64) throw RigError("too many images (at most 64)");
  if (pano_f == 0) rig.projection = "plane";
  else if (pano_f == 1) rig.projection = "cylindrical";
  else if (pano_f == 2) rig.projection = "spherical";
  else throw RigError("panorama projection f" + std::to_string(pano_f) +
                      " is not supported (0 rectilinear, 1 cylindrical, 2 equirectangular)");
  if (report) report->fit_residual_px.clear();
  // Split glued single-letter keys: "w1920" parses as key "w" value "1920" already; "v=0" as "v", "=0".
  auto value = [&](std::size_t i, const std::string& key, double fallback, bool required) -> double {
    for (int hop = 0; hop < 65; ++hop) {
      auto it = images[i].v.find(key);
      if (it == images[i].v.end()) {
        if (required) throw RigError("image " + std::to_string(i) + ": missing \"" + key + "\"");
        return fallback;
      }
      if (!it->second.empty() && it->second[0] == '=') {
        const long j = std::strtol(it->second.c_str() + 1, nullptr, 10);
        if (j < 0 || j >= long(images.size())) throw RigError("image " + std::to_string(i) + ": bad back-reference");
        i = std::size_t(j);
        continue;
      }
      char* end = nullptr;
      const double v = std::strtod(it->second.c_str(), &end);
      if (end == it->second.c_str() || !std::isfinite(v))
        throw RigError("image " + std::to_string(i) + ": \"" + key + "\" is not a number");
      return v;
    }
    throw RigError("image " + std::to_string(i) + ": circular back-reference");
  };
  for (std::size_t i = 0; i < images.size(); ++i) {
    const std::string where = "image " + std::to_string(i);
    Camera c;
    c.width = int(value(i, "w", 0, true));
    c.height = int(value(i, "h", 0, true));
    if (c.width <= 0 || c.height <= 0 || c.width > 32768 || c.height > 32768) throw RigError(where + ": bad size");
    const int type = int(value(i, "f", 0, false));
    const double hfov = value(i, "v", 0, true) * kPi / 180.0;
    if (!(hfov > 0 && hfov < 2 * kPi)) throw RigError(where + ": \"v\" (hfov) must be in (0, 360) degrees");
    const bool fisheye = type == 2 || type == 3;
    if (type != 0 && !fisheye)
      throw RigError(where + ": lens type f" + std::to_string(type) +
                     " is not supported (0 rectilinear, 2 circular fisheye, 3 full-frame fisheye)");
    if (!fisheye && hfov >= kPi) throw RigError(where + ": a rectilinear lens cannot see 180 degrees or more");
    c.fx = c.fy = fisheye ? c.width / hfov : 0.5 * c.width / std::tan(0.5 * hfov);
    c.cx = 0.5 * (c.width - 1) + value(i, "d", 0, false);
    c.cy = 0.5 * (c.height - 1) + value(i, "e", 0, false);
    c.yaw_deg = value(i, "y", 0, false);
    c.pitch_deg = value(i, "p", 0, false);
    c.roll_deg = value(i, "r", 0, false);
    const double a = value(i, "a", 0, false), b = value(i, "b", 0, false), cc = value(i, "c", 0, false);
    const double half_short = 0.5 * std::min(c.width, c.height);
    double max_r = std::hypot(0.5 * c.width, 0.5 * c.height);
    if (type == 2) {
      LensCircle k{c.cx, c.cy, half_short};
      auto s = images[i].v.find("S");  // crop left,right,top,bottom
      if (s != images[i].v.end()) {
        double l = 0, r = 0, t = 0, bt = 0;
        if (std::sscanf(s->second.c_str(), "%lf,%lf,%lf,%lf", &l, &r, &t, &bt) == 4 && r > l && bt > t)
          k = {0.5 * (l + r) - 0.5, 0.5 * (t + bt) - 0.5, 0.5 * std::min(r - l, bt - t)};
      }
      c.lens.circle = k;
      max_r = k.radius;
    }
    double residual = 0;
    if (a != 0 || b != 0 || cc != 0) {
      const auto circle = c.lens.circle;
      double focal = c.fx;
      residual = fit_panotools_radial(a, b, cc, c.fx, half_short, max_r, fisheye, c.lens, focal);
      c.fx = c.fy = focal;
      c.lens.circle = circle;
    } else if (fisheye) {
      c.lens.model = Lens::Model::Fisheye;  // equidistant, no polynomial
    }
    if (report) report->fit_residual_px.push_back(residual);
    const std::string problem = lens_problem(c);
    if (!problem.empty()) throw RigError(where + ": " + problem);
    rig.cameras.push_back(c);
  }
  rig.reference = 0;
  if (!rig.planar() && pano_w > 0 && pano_v > 0) rig.canvas_scale = pano_w / (pano_v * kPi / 180.0);
  rig_compute_rough_homographies(rig);
  return rig;
}

Rig rig_load_pto(const std::string& path, PtoReport* report) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw RigError("cannot open project file \"" + path + "\"");
  std::ostringstream ss;
  ss << in.rdbuf();
  try {
    return rig_from_pto_string(ss.str(), report);
  } catch (const RigError& e) {
    throw RigError("project file \"" + path + "\": " + e.what());
  }
}

}  // namespace stitch
