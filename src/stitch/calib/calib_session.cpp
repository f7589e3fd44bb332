#include "stitch/calib/calib_session.hpp"

#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <regex>
#include <sstream>

#include "stitch/calib/area_align.hpp"
#include "stitch/cv_interop.hpp"
#include "stitch/rig/canvas_map.hpp"

namespace stitch {

namespace {

constexpr double kPi = 3.14159265358979323846;

std::string fmt(double v, int digits = 1) {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  s.precision(digits);
  s << v;
  return s.str();
}

SessionEvent make_event(SessionEvent::Type type, const std::string& text) {
  SessionEvent e;
  e.type = type;
  e.text = text;
  return e;
}

std::string size_text(const std::array<int, 2>& s) { return std::to_string(s[0]) + "x" + std::to_string(s[1]); }

}  // namespace

// ---- frame quality ---------------------------------------------------------------------------

const char* frame_verdict_name(FrameVerdict v) {
  switch (v) {
    case FrameVerdict::Good: return "good";
    case FrameVerdict::Dark: return "dark";
    case FrameVerdict::Featureless: return "featureless";
    case FrameVerdict::Blurred: return "blurred";
    case FrameVerdict::Corrupt: return "corrupt";
  }
  return "?";
}

double FrameQuality::score() const {
  if (verdict != FrameVerdict::Good) return 0;
  return std::log1p(sharpness) * std::min(corners, 800);
}

std::string FrameQuality::describe() const {
  switch (verdict) {
    case FrameVerdict::Good: return "good";
    case FrameVerdict::Dark: return "dark (mean luma " + fmt(mean_luma) + ")";
    case FrameVerdict::Featureless: return "featureless (" + std::to_string(corners) + " corners, contrast " + fmt(contrast) + ")";
    case FrameVerdict::Blurred: return "blurred (Laplacian variance " + fmt(sharpness) + ")";
    case FrameVerdict::Corrupt: return "corrupt (a torn picture: row discontinuity " + fmt(tear) + "x its surroundings)";
  }
  return "?";
}

namespace {

// A decoder that loses part of a frame loses whole coded blocks (JPEG MCUs of 8/16 rows,
// H.264/H.265/VP9/AV1 macroblocks and superblocks of 16-128 rows), so a broken keyframe's seam
// lies between two rows of a multiple of 8, and changes the picture at once: one row boundary,
// not an edge the lens spread over two rows. A strong horizontal edge of the scene (a shelf, a
// rolled camera's studs: probe4 lost the first 3 s of such a rig) sits anywhere.
// `row_fraction` is the tear as assess_frame found it on its small copy.
bool tear_on_a_block_boundary(const cv::Mat& rgba, double row_fraction) {
  const int h = rgba.rows, w = rgba.cols;
  if (h < 16) return true;
  const int centre = int(std::lround(row_fraction * h));
  const int reach = std::max(3, int(std::ceil(2.0 * w / 320.0)) + 2);  // the small copy's row, in full rows
  const int lo = std::max(0, centre - reach), hi = std::min(h - 2, centre + reach);
  std::vector<double> step;  // step[k]: mean |row (lo+k+1) - row (lo+k)| over the width
  cv::Mat grey;
  cv::cvtColor(rgba.rowRange(lo, hi + 2), grey, cv::COLOR_RGBA2GRAY);
  for (int y = 0; y + 1 < grey.rows; ++y) {
    const uint8_t* a = grey.ptr<uint8_t>(y);
    const uint8_t* b = grey.ptr<uint8_t>(y + 1);
    double sum = 0;
    for (int x = 0; x < w; ++x) sum += std::abs(int(a[x]) - int(b[x]));
    step.push_back(sum / w);
  }
  if (step.empty()) return true;
  const std::size_t at = std::size_t(std::max_element(step.begin(), step.end()) - step.begin());
  double next = 0;  // the strongest other boundary within two rows
  for (std::size_t k = at >= 2 ? at - 2 : 0; k <= std::min(step.size() - 1, at + 2); ++k)
    if (k != at) next = std::max(next, step[k]);
  const int first_row_below = lo + int(at) + 1;
  return first_row_below % 8 == 0 && step[at] >= 1.5 * next;
}

}  // namespace

FrameQuality assess_frame(const ImageView& v) {
  FrameQuality q;
  if (v.empty() || v.on_device) {
    q.verdict = FrameVerdict::Featureless;
    return q;
  }
  const cv::Mat rgba = as_mat(v);
  const double s = std::min(1.0, 320.0 / std::max(v.width, 1));
  cv::Mat small, grey;
  if (s < 1.0) cv::resize(rgba, small, cv::Size(), s, s, cv::INTER_AREA);
  else small = rgba;
  cv::cvtColor(small, grey, cv::COLOR_RGBA2GRAY);
  {
    std::uint64_t h = 1469598103934665603ull;  // FNV-1a over the grey copy
    for (int y = 0; y < grey.rows; ++y) {
      const uint8_t* r = grey.ptr<uint8_t>(y);
      for (int x = 0; x < grey.cols; ++x) h = (h ^ r[x]) * 1099511628211ull;
    }
    q.picture = h;
  }
  cv::Scalar mean, dev;
  cv::meanStdDev(grey, mean, dev);
  q.mean_luma = mean[0];
  q.contrast = dev[0];
  if (grey.cols >= 8 && grey.rows >= 8) {
    cv::Mat lap;
    cv::Laplacian(grey, lap, CV_64F);
    cv::meanStdDev(lap, mean, dev);
    q.sharpness = dev[0] * dev[0];
    std::vector<cv::KeyPoint> kp;
    cv::FAST(grey, kp, 20, true);
    q.corners = int(kp.size());
    // A broken keyframe glues two pictures: one row boundary changes much more, across most of
    // the width, than the rows around it.
    const int h = grey.rows, w = grey.cols;
    std::vector<double> d(std::size_t(h - 1)), cover(std::size_t(h - 1));
    for (int y = 0; y + 1 < h; ++y) {
      const uint8_t* a = grey.ptr<uint8_t>(y);
      const uint8_t* b = grey.ptr<uint8_t>(y + 1);
      double sum = 0;
      int big = 0;
      for (int x = 0; x < w; ++x) {
        const int diff = std::abs(int(a[x]) - int(b[x]));
        sum += diff;
        big += diff > 16;
      }
      d[std::size_t(y)] = sum / w;
      cover[std::size_t(y)] = double(big) / w;
    }
    for (int y = 4; y + 5 < h; ++y) {
      if (cover[std::size_t(y)] < 0.35) continue;
      std::vector<double> around;
      for (int k = y - 8; k <= y + 8; ++k)
        if (k >= 0 && k < h - 1 && std::abs(k - y) > 1) around.push_back(d[std::size_t(k)]);
      std::nth_element(around.begin(), around.begin() + around.size() / 2, around.end());
      const double tear = d[std::size_t(y)] / (around[around.size() / 2] + 2.0);
      if (tear > q.tear) {
        q.tear = tear;
        q.tear_row = double(y) / h;
      }
    }
  }
  if (q.tear > 4 && !tear_on_a_block_boundary(rgba, q.tear_row)) q.tear = std::min(q.tear, 4.0);
  if (q.mean_luma < 16) q.verdict = FrameVerdict::Dark;
  else if (q.tear > 4) q.verdict = FrameVerdict::Corrupt;  // natural frames of the real clips: <= 3.1
  else if (q.contrast >= 8 && q.sharpness < 20) q.verdict = FrameVerdict::Blurred;  // real clips: >= 440
  else if (q.corners < 12 || q.contrast < 4) q.verdict = FrameVerdict::Featureless;
  return q;
}

// ---- canvas helpers --------------------------------------------------------------------------

void transform_canvas(Rig& rig, double s, double tx, double ty, int width, int height) {
  // Pixel-centre convention: canvas (x + 0.5) * s + t lands on (x' + 0.5).
  const double ox = 0.5 * s - 0.5 + tx, oy = 0.5 * s - 0.5 + ty;
  if (rig.planar()) {
    Eigen::Matrix3d A;
    A << s, 0, ox, 0, s, oy, 0, 0, 1;
    for (auto& c : rig.cameras)
      if (c.homography) {
        Eigen::Matrix3d H = A * *c.homography;
        c.homography = H / H(2, 2);
      }
  } else {
    rig.canvas_origin_x = s * rig.canvas_origin_x + ox;
    rig.canvas_origin_y = s * rig.canvas_origin_y + oy;
    rig.canvas_scale *= s;
    if (rig.canvas_wrap && std::abs(2 * kPi * rig.canvas_scale - width) > 0.5) rig.canvas_wrap = false;
  }
  rig.canvas_width = width;
  rig.canvas_height = height;
}

bool make_canvas_even(Rig& rig) {
  const int w = rig.canvas_width, h = rig.canvas_height;
  if (w <= 0 || h <= 0 || (w % 2 == 0 && h % 2 == 0)) return false;
  const int ew = std::max(2, w + (w & 1)), eh = std::max(2, h + (h & 1));
  if (!rig.planar() && rig.canvas_wrap && (w & 1)) {
    // 360 degrees must stay exactly the width: scale (both axes alike) rather than pad.
    const double s = double(ew) / w;
    transform_canvas(rig, s, 0, 0, ew, std::max(eh, 2 * int(std::ceil(h * s / 2))));
    rig.canvas_wrap = true;
    return true;
  }
  transform_canvas(rig, 1, 0, 0, ew, eh);
  return true;
}

void fit_canvas(Rig& rig, int width, int height) {
  if (width <= 0 || height <= 0 || rig.canvas_width <= 0 || rig.canvas_height <= 0) return;
  if (rig.canvas_width == width && rig.canvas_height == height) return;
  const bool wrap = rig.canvas_wrap;
  const double s = std::min(double(width) / rig.canvas_width, double(height) / rig.canvas_height);
  const double tx = std::floor((width - rig.canvas_width * s) * 0.5), ty = std::floor((height - rig.canvas_height * s) * 0.5);
  transform_canvas(rig, s, tx, ty, width, height);
  if (wrap && std::abs(2 * kPi * rig.canvas_scale - width) <= 0.5) rig.canvas_wrap = true;
}

double shrink_canvas_to_output(Rig& rig, int output_width, int output_height, CropMode crop) {
  if ((output_width <= 0 && output_height <= 0) || rig.canvas_width <= 0 || rig.canvas_height <= 0) return 1;
  const double s = plan_output(rig, output_width, output_height, crop).canvas_to_output(0, 0);
  // A full sphere stays 2:1 with both sides even (its width a multiple of 4).
  const bool full_sphere = rig.canvas_wrap && rig.projection_kind() == Projection::Spherical &&
                           rig.canvas_width == 2 * rig.canvas_height;
  const int quantum = full_sphere ? 4 : 2;
  const int w = std::max(quantum, quantum * int(std::ceil(rig.canvas_width * s / quantum)));
  if (!(s > 0) || w >= rig.canvas_width) return 1;
  // The width sets the scale (a 360-degree canvas is 2 pi * canvas_scale wide, to the pixel).
  const double sw = double(w) / rig.canvas_width;
  const int h = full_sphere ? w / 2 : std::max(2, 2 * int(std::ceil(rig.canvas_height * sw * 0.5)));
  transform_canvas(rig, sw, 0, 0, w, h);  // keeps a 360-degree canvas wrapping: w = sw * width
  return sw;
}

// ---- jobs ------------------------------------------------------------------------------------

bool cancel_at_end_of_stream(JobKind kind, bool calibrated, bool saving) {
  if (kind == JobKind::Lens) return true;
  return !saving && (kind == JobKind::Pooled || (kind == JobKind::First && calibrated));
}

std::vector<std::pair<int, int>> identical_views(const std::vector<ImageView>& views, std::uint64_t skip) {
  constexpr int kAcross = 64;
  std::vector<cv::Mat> small(views.size());
  for (std::size_t i = 0; i < views.size(); ++i) {
    if ((i < 64 && (skip >> i & 1)) || views[i].empty()) continue;
    const int h = std::max(1, int(std::lround(double(kAcross) * views[i].height / views[i].width)));
    cv::resize(as_mat(views[i]), small[i], cv::Size(kAcross, h), 0, 0, cv::INTER_AREA);
  }
  std::vector<std::pair<int, int>> same;
  for (std::size_t i = 0; i < views.size(); ++i)
    for (std::size_t j = i + 1; j < views.size(); ++j) {
      if (small[i].empty() || small[j].empty() || views[i].width != views[j].width || views[i].height != views[j].height)
        continue;
      cv::Mat diff;
      cv::absdiff(small[i], small[j], diff);
      const cv::Scalar m = cv::mean(diff);
      if (m[0] + m[1] + m[2] < 3.0) same.emplace_back(int(i), int(j));
    }
  return same;
}

bool stream_waits_for_job(JobKind kind, bool calibrated, bool live) {
  return !calibrated || (kind == JobKind::First && !live);
}

const char* job_kind_name(JobKind k) {
  switch (k) {
    case JobKind::First: return "first";
    case JobKind::Pooled: return "pooled";
    case JobKind::Recalibration: return "recalibration";
    case JobKind::DriftCheck: return "drift-check";
    case JobKind::LoadCheck: return "load-check";
    case JobKind::Lens: return "lens";
  }
  return "?";
}

const char* job_stage_name(JobStage s) {
  switch (s) {
    case JobStage::Estimating: return "matching features and estimating the cameras";
    case JobStage::Measuring: return "measuring the alignment";
    case JobStage::LensTest: return "testing for lens distortion";
    case JobStage::LensFit: return "lens fit";
    case JobStage::LensJudging: return "judging the lens fit";
  }
  return "?";
}

std::string rig_lens_summary(const Rig& rig) {
  std::vector<std::string> models;
  bool any = false;
  for (const auto& c : rig.cameras) {
    if (c.left_out) continue;
    any |= !c.lens.pinhole();
    const std::string m = lens_model_name(c.lens.model);
    if (std::find(models.begin(), models.end(), m) == models.end()) models.push_back(m);
  }
  if (!any) return "pinhole";
  std::string out;
  for (const auto& m : models) out += (out.empty() ? "" : ", ") + m;
  return out;
}

std::vector<ImageView> FrameSet::views() const {
  std::vector<ImageView> v;
  for (cv::Mat m : images) v.push_back(as_view(m));  // a header sharing the pixels
  return v;
}

FrameSet FrameSet::copy_of(const std::vector<ImageView>& views) {
  FrameSet set;
  for (const auto& v : views) set.images.push_back(as_mat(v).clone());
  return set;
}

namespace {

bool bit(std::uint64_t mask, std::size_t i) { return i < 64 && (mask >> i & 1); }

// "camera 2", "cameras 0, 1"
std::string camera_list(std::uint64_t mask, std::size_t n) {
  std::string who;
  int count = 0;
  for (std::size_t i = 0; i < n; ++i)
    if (bit(mask, i)) who += (count++ ? ", " : "") + std::to_string(i);
  return (count > 1 ? "cameras " : "camera ") + who;
}
// `one` or `several` as the cameras in `mask` are one or more
const char* agree(std::uint64_t mask, const char* one, const char* several) {
  return (mask & (mask - 1)) ? several : one;
}

// The cameras not in `left_out` (and the reference's index among them; 0 when it is left out).
template <class T>
std::vector<T> kept_items(const std::vector<T>& all, std::uint64_t left_out) {
  std::vector<T> kept;
  for (std::size_t i = 0; i < all.size(); ++i)
    if (!bit(left_out, i)) kept.push_back(all[i]);
  return kept;
}
int kept_index(int full, std::uint64_t left_out) {
  if (full < 0 || bit(left_out, std::size_t(full))) return full < 0 ? full : 0;
  int k = 0;
  for (int i = 0; i < full; ++i) k += !bit(left_out, std::size_t(i));
  return k;
}
// A first calibration's job without the cameras in `leave` (its frames are already kept_items):
// the reference and the rough rig renumbered, the full sizes kept for its messages.
void leave_out_of_job(CalibJob& job, std::uint64_t leave, const std::vector<std::array<int, 2>>& sizes, int reference) {
  if (!leave) return;
  job.left_out = leave;
  job.sizes = sizes;
  job.config.reference = kept_index(reference, leave);
  if (job.rough) {
    job.rough->cameras = kept_items(job.rough->cameras, leave);
    job.rough->reference = kept_index(job.rough->reference, leave);
  }
}
std::vector<int> full_indices(std::size_t n, std::uint64_t left_out) {
  std::vector<int> idx;
  for (std::size_t i = 0; i < n; ++i)
    if (!bit(left_out, i)) idx.push_back(int(i));
  return idx;
}

// "camera K" of a calibration of the kept cameras, as the camera's index among all of them.
std::string renumbered(const std::string& text, const std::vector<int>& idx) {
  static const std::regex camera_index("camera (\\d+)");
  std::string out;
  auto last = text.cbegin();
  for (std::sregex_iterator m(text.cbegin(), text.cend(), camera_index), end; m != end; ++m) {
    const std::size_t k = std::stoul((*m)[1].str());
    out.append(last, (*m)[0].first);
    out += "camera " + std::to_string(k < idx.size() ? idx[k] : int(k));
    last = (*m)[0].second;
  }
  return out.append(last, text.cend());
}

// A calibration of the kept cameras as one of every camera: a placeholder for each left-out
// one (its frame size, on no canvas), indices and residuals renumbered.
void with_left_out_cameras(Rig& rig, RigResiduals& residuals, std::uint64_t left_out,
                           const std::vector<std::array<int, 2>>& sizes) {
  const std::vector<int> idx = full_indices(sizes.size(), left_out);
  if (idx.size() != rig.cameras.size()) return;
  std::vector<Camera> cams(sizes.size());
  for (std::size_t i = 0; i < sizes.size(); ++i) {
    Camera& c = cams[i];
    c.width = sizes[i][0];
    c.height = sizes[i][1];
    c.fx = c.fy = std::max(1, std::max(c.width, c.height));
    c.cx = 0.5 * (c.width - 1);
    c.cy = 0.5 * (c.height - 1);
    if (rig.planar()) c.homography = Eigen::Matrix3d::Identity();
    c.left_out = true;
  }
  for (std::size_t k = 0; k < idx.size(); ++k) cams[std::size_t(idx[k])] = rig.cameras[k];
  rig.cameras = std::move(cams);
  rig.reference = idx[std::size_t(std::clamp(rig.reference, 0, int(idx.size()) - 1))];
  std::vector<double> camera_px(sizes.size(), -1);
  for (std::size_t k = 0; k < idx.size() && k < residuals.camera_px.size(); ++k) camera_px[std::size_t(idx[k])] = residuals.camera_px[k];
  residuals.camera_px = camera_px;
  for (auto& p : residuals.pairs) p.a = idx[std::size_t(p.a)], p.b = idx[std::size_t(p.b)];
}

// Pinhole cameras whose optical axes lie further apart than their half diagonal fields of view
// together (plus a margin) cannot see one ray: a 360-degree ring's cameras that are not
// neighbours. Anything else (a lens, no intrinsics): they may overlap.
bool views_cannot_overlap(const Camera& a, const Camera& b) {
  if (!a.lens.pinhole() || !b.lens.pinhole() || a.fx <= 0 || a.fy <= 0 || b.fx <= 0 || b.fy <= 0) return false;
  const auto half_diagonal = [](const Camera& c) {
    return std::atan(std::hypot(0.5 * c.width / c.fx, 0.5 * c.height / c.fy));
  };
  const double cosine = std::clamp(a.R().col(2).dot(b.R().col(2)), -1.0, 1.0);
  constexpr double kMarginRad = 5.0 * kPi / 180;
  return std::acos(cosine) > half_diagonal(a) + half_diagonal(b) + kMarginRad;
}

// The share of b's frame that a sees too, through the rotations (pinhole cameras; 0 otherwise),
// on a grid of 48 x 36 samples.
double pinhole_overlap_share(const Camera& a, const Camera& b) {
  if (!a.lens.pinhole() || !b.lens.pinhole() || a.fx <= 0 || b.fx <= 0 || b.width <= 0 || b.height <= 0) return 0;
  const Eigen::Matrix3d Hba = a.K() * a.R().transpose() * b.R() * b.K().inverse();
  constexpr int kX = 48, kY = 36;
  int inside = 0;
  for (int j = 0; j < kY; ++j)
    for (int i = 0; i < kX; ++i) {
      const Eigen::Vector3d h = Hba * Eigen::Vector3d((i + 0.5) * b.width / kX - 0.5, (j + 0.5) * b.height / kY - 0.5, 1);
      if (!(h.z() > 1e-9)) continue;
      const double u = h.x() / h.z(), v = h.y() / h.z();
      inside += u >= 0 && v >= 0 && u <= a.width - 1 && v <= a.height - 1;
    }
  return double(inside) / (kX * kY);
}

bool boxes_overlap(const Rig& rig, int a, int b) {
  // Across the wrap the canvas boxes say nothing: the views' directions do (a 5-camera ring's
  // first calibration measured its 5 pairs that cannot overlap too: 10 pairs on every frame set).
  if (rig.canvas_wrap) return !views_cannot_overlap(rig.cameras[std::size_t(a)], rig.cameras[std::size_t(b)]);
  double box[2][4];
  for (int k = 0; k < 2; ++k) {
    box[k][0] = box[k][1] = 1e300;
    box[k][2] = box[k][3] = -1e300;
    for (const auto& p : camera_canvas_outline(rig, k ? b : a)) {
      box[k][0] = std::min(box[k][0], p.x());
      box[k][1] = std::min(box[k][1], p.y());
      box[k][2] = std::max(box[k][2], p.x());
      box[k][3] = std::max(box[k][3], p.y());
    }
  }
  return box[0][0] < box[1][2] && box[1][0] < box[0][2] && box[0][1] < box[1][3] && box[1][1] < box[0][3];
}

CalibrationResult calibrate(const SessionConfig& s, const std::optional<Rig>& rough,
                            const std::vector<std::vector<ImageView>>& sets) {
  if (rough) {
    Rig start = *rough;
    if (s.reference >= 0) start.reference = s.reference;
    if (s.projection && start.projection != projection_name(*s.projection)) {
      // Another canvas: what the file computed for its own one does not apply.
      start.projection = projection_name(*s.projection);
      for (auto& c : start.cameras) c.homography.reset();
      start.canvas_width = start.canvas_height = 0;
      start.canvas_scale = 0;
    }
    return calibrate_from_rig(start, sets, s.options);
  }
  // Images alone: focal lengths and rotations are estimated; unset, the projection is chosen
  // from the rig's field of view.
  CalibrationOptions options = s.options;
  options.projection = s.projection;
  // The lens-from-evidence fit is a second whole calibration: too slow for a live session's
  // attempts (2x per attempt). Sessions calibrate pinhole unless the rig gives a lens.
  options.lens_from_evidence = false;
  return calibrate_from_images(sets, s.reference, options);
}

}  // namespace

RigResiduals measure_residuals(const Rig& rig, const std::vector<FrameSet>& sets, const std::atomic<bool>* cancel) {
  RigResiduals r;
  const int n = int(rig.cameras.size());
  r.camera_px.assign(std::size_t(n), -1);
  std::vector<double> cam_sum(std::size_t(n), 0), cam_w(std::size_t(n), 0);
  double sum = 0, sum2 = 0, cam_sum_all = 0, cam_w_all = 0;
  for (int a = 0; a < n; ++a)
    for (int b = a + 1; b < n; ++b) {
      if (cancel && cancel->load()) return r;
      if (!boxes_overlap(rig, a, b)) continue;
      Rig sub = rig;
      sub.cameras = {rig.cameras[std::size_t(a)], rig.cameras[std::size_t(b)]};
      sub.reference = 0;
      PairResidual p;
      p.a = a;
      p.b = b;
      double pair_sum = 0, pair_cam_sum = 0;
      int cam_matches = 0;
      for (const auto& set : sets) {
        if (int(set.images.size()) != n) continue;
        const auto views = set.views();
        const AlignmentReport rep = measure_alignment(sub, {views[std::size_t(a)], views[std::size_t(b)]});
        if (rep.median_px < 0 || rep.matches <= 0) continue;
        pair_sum += rep.median_px * rep.matches;
        p.matches += rep.matches;
        if (rep.median_camera_px >= 0) {
          pair_cam_sum += rep.median_camera_px * rep.matches;
          cam_matches += rep.matches;
        }
      }
      if (p.matches == 0) {
        // No feature matches to measure by (a plain or thin overlap, a ring's closing pair):
        // the overlap aligned by area (area_align.hpp), so that a seam far off there is in the
        // figure too. Its patches count as matches; camera pixels stand for canvas pixels.
        bool overlap = false;
        for (const auto& set : sets) {
          if (int(set.images.size()) != n) continue;
          const auto views = set.views();
          cv::Mat ga, gb;
          cv::cvtColor(as_mat(views[std::size_t(a)]), ga, cv::COLOR_RGBA2GRAY);
          cv::cvtColor(as_mat(views[std::size_t(b)]), gb, cv::COLOR_RGBA2GRAY);
          const AreaAlignment al = align_overlap_by_area(rig.cameras[std::size_t(a)], rig.cameras[std::size_t(b)], ga, gb);
          overlap |= al.overlap;
          if (!al.measured) continue;
          p.matches = al.agreeing;
          pair_sum = pair_cam_sum = al.offset_px * al.agreeing;
          cam_matches = al.agreeing;
          break;
        }
        if (p.matches == 0) {
          const Camera &ca = rig.cameras[std::size_t(a)], &cb = rig.cameras[std::size_t(b)];
          if (overlap && std::max(pinhole_overlap_share(ca, cb), pinhole_overlap_share(cb, ca)) >= kMinVerifiableOverlap)
            r.unverified.emplace_back(a, b);
          continue;
        }
      }
      p.median_px = pair_sum / p.matches;
      if (cam_matches > 0) {
        p.median_camera_px = pair_cam_sum / cam_matches;
        cam_sum_all += p.median_camera_px * p.matches;
        cam_w_all += p.matches;
      }
      r.pairs.push_back(p);
      for (int c : {a, b}) {
        cam_sum[std::size_t(c)] += p.median_px * p.matches;
        cam_w[std::size_t(c)] += p.matches;
      }
      sum += p.median_px * p.matches;
      sum2 += p.median_px * p.median_px * p.matches;
      r.matches += p.matches;
    }
  for (int c = 0; c < n; ++c)
    if (cam_w[std::size_t(c)] > 0) r.camera_px[std::size_t(c)] = cam_sum[std::size_t(c)] / cam_w[std::size_t(c)];
  if (r.matches > 0) {
    r.median_px = sum / r.matches;
    r.rms_px = std::sqrt(sum2 / r.matches);
  }
  if (cam_w_all > 0) r.median_camera_px = cam_sum_all / cam_w_all;
  return r;
}

RigCoverage rig_coverage(const Rig& rig) {
  RigCoverage c;
  const int n = int(rig.cameras.size());
  c.camera_share.assign(std::size_t(n), 0);
  if (rig.canvas_width <= 0 || rig.canvas_height <= 0 || n == 0) return c;
  const double step = std::max(1.0, rig.canvas_width / 160.0);
  const int cols = std::max(1, int(std::ceil(rig.canvas_width / step))), rows = std::max(1, int(std::ceil(rig.canvas_height / step)));
  std::vector<CameraCanvasMap> maps;
  for (int k = 0; k < n; ++k) maps.push_back(camera_canvas_map(rig, k));
  std::vector<long> count(std::size_t(n), 0);
  long any = 0;
  for (int j = 0; j < rows; ++j)
    for (int i = 0; i < cols; ++i) {
      const Eigen::Vector2d q(std::min((i + 0.5) * step, rig.canvas_width - 0.5), std::min((j + 0.5) * step, rig.canvas_height - 0.5));
      bool seen = false;
      for (int k = 0; k < n; ++k) {
        const Camera& cam = rig.cameras[std::size_t(k)];
        Eigen::Vector2d p;
        if (cam.left_out || !maps[std::size_t(k)].to_camera(q, p)) continue;
        if (!(p.x() >= -0.5 && p.y() >= -0.5 && p.x() <= cam.width - 0.5 && p.y() <= cam.height - 0.5)) continue;
        ++count[std::size_t(k)];
        seen = true;
      }
      any += seen;
    }
  const double cells = double(cols) * rows;
  for (int k = 0; k < n; ++k) c.camera_share[std::size_t(k)] = count[std::size_t(k)] / cells;
  c.share = any / cells;
  return c;
}

// Measured (bench/calib_pool_coverage.py, BENCHMARKS.md): the pooled candidates installed on
// the real clips changed the covered share by -1.5 to +3.2 points (the stereo hallway: -6, for
// 13.4 vs 16.8 camera px), the degenerate ones of the house clip with a still camera by -10 to
// -25 points, camera 1's share falling to 0.36-0.64 of what it was.
constexpr double kKeepCameraShare = 2.0 / 3.0, kMaxCoverageLoss = 0.05;

Judgement judge_candidate(const RigResiduals& cand, const RigResiduals& cur, const RigCoverage& cand_cover,
                          const RigCoverage& cur_cover) {
  Judgement j;
  // Camera pixels where both have them (they do wherever the maps are differentiable).
  bool cam_units = cand.median_camera_px >= 0 && cur.median_camera_px >= 0;
  double c = cam_units ? cand.median_camera_px : cand.median_px;
  double now = cam_units ? cur.median_camera_px : cur.median_px;
  // Compared on the pairs both measure, with the same weights: a pair only one of them puts in
  // overlap (the house's left and right cameras, whose boxes touch on the candidate's canvas)
  // is measured on matches across views that share no scene, hundreds of pixels apart, and
  // decided the verdict on its own (rms-px 176 against 2.3).
  double common_c = 0, common_now = 0, common_cam_c = 0, common_cam_now = 0, weight = 0;
  bool common_cam = true;
  for (const auto& p : cur.pairs)
    for (const auto& q : cand.pairs) {
      if (q.a != p.a || q.b != p.b || p.matches <= 0 || q.matches <= 0 || p.median_px < 0 || q.median_px < 0) continue;
      common_c += p.matches * q.median_px;
      common_now += p.matches * p.median_px;
      common_cam &= p.median_camera_px >= 0 && q.median_camera_px >= 0;
      common_cam_c += p.matches * q.median_camera_px;
      common_cam_now += p.matches * p.median_camera_px;
      weight += p.matches;
    }
  if (weight > 0 && (cand.pairs.size() != cur.pairs.size() || weight < cur.matches)) {
    cam_units = common_cam;
    c = (common_cam ? common_cam_c : common_c) / weight;
    now = (common_cam ? common_cam_now : common_now) / weight;
  }
  const std::string unit = cam_units ? " camera px" : " px";
  if (c < 0) {
    j.reason = "nothing to measure it by on the held-out frames";
    return j;
  }
  // Every overlap the current calibration aligns must still be there.
  for (const auto& p : cur.pairs) {
    const double px = p.median_camera_px >= 0 ? p.median_camera_px : p.median_px;
    if (p.matches < 16 || px < 0 || px >= 10) continue;
    int kept = 0;
    for (const auto& q : cand.pairs)
      if (q.a == p.a && q.b == p.b) kept = q.matches;
    if (2 * kept < p.matches) {
      j.reason = "it loses the overlap of cameras " + std::to_string(p.a) + " and " + std::to_string(p.b) + " (" +
                 std::to_string(p.matches) + " held-out matches aligned to " + fmt(px, 2) + unit + " now, " +
                 std::to_string(kept) + " with it)";
      return j;
    }
  }
  // It must be better by 10% and 0.05 px: a static rig never flips between equal solutions.
  if (!(now < 0 || (c < 0.9 * now && c < now - 0.05))) {
    j.reason = "not better: " + fmt(c, 2) + unit + " against the current " + fmt(now, 2) + unit;
    return j;
  }
  // ...and keep the picture, unless the current calibration is badly off (it halves the residual).
  const bool much_better = now > 0 && c < 0.5 * now;
  if (!much_better) {
    const std::size_t n = std::min(cand_cover.camera_share.size(), cur_cover.camera_share.size());
    for (std::size_t k = 0; k < n; ++k)
      if (cur_cover.camera_share[k] > 0 && cand_cover.camera_share[k] < kKeepCameraShare * cur_cover.camera_share[k]) {
        j.reason = "camera " + std::to_string(k) + " shrinks to " + fmt(100 * cand_cover.camera_share[k], 0) +
                   "% of the canvas (" + fmt(100 * cur_cover.camera_share[k], 0) + "% now) for " + fmt(c, 2) + unit +
                   " against " + fmt(now, 2) + unit;
        return j;
      }
    if (cand_cover.share < cur_cover.share - kMaxCoverageLoss) {
      j.reason = "the cameras cover " + fmt(100 * cand_cover.share, 0) + "% of the canvas (" +
                 fmt(100 * cur_cover.share, 0) + "% now) for " + fmt(c, 2) + unit + " against " + fmt(now, 2) + unit;
      return j;
    }
  }
  j.install = true;
  return j;
}

Judgement judge_lens_candidate(const RigResiduals& candidate, const RigResiduals& current,
                               const RigCoverage& candidate_cover, const RigCoverage& current_cover) {
  Judgement verdict = judge_candidate(candidate, current, candidate_cover, current_cover);
  const double lens_px = candidate.median_camera_px, pin_px = current.median_camera_px;
  if (verdict.install && !lens_evidence_wins(pin_px, lens_px)) {
    verdict.install = false;
    verdict.reason = "no clear evidence of lens distortion: " + fmt(lens_px, 2) + " camera px with radtan k1/k2 against " +
                     fmt(pin_px, 2) + " pinhole (a lens needs below " + fmt(100 * kLensEvidenceRatio, 0) + "% and " +
                     fmt(kLensEvidenceMinPx, 2) + " px less)";
  }
  return verdict;
}

namespace {

// The background lens-from-evidence fit (JobKind::Lens): radtan k1/k2 for every camera, from the
// installed rig (lens_fit_starts), on the window's calibration frames; the best usable start by
// its own held-out error; then judged as a pooled candidate would be (residuals and coverage of
// both on the held-out frames). `cancel` stops it at the calibrator's next stage
// (CalibrationOptions::cancel) and is checked between the starts.
constexpr std::size_t kLensFitSets = 2;
constexpr int kLensJobBudgetS = 90;
constexpr double kLensFitGoodPx = 0.5;
// A lens fit installed before the output that leaves more than this (camera px) is said to be poor.
constexpr double kLensFitFairPx = 1.0;

// The frame sets a job's result is measured on: its held-out ones; without any (a first
// calibration), the newest kFirstResidualSets of its calibration sets. A file's failed first
// attempt is retried on up to calibration-frames pooled sets, and measuring every pair on each
// cost as much again (ering5ov8: 19 s of a 40 s attempt on 4 sets); the residual is the message's
// and the lens test's gate, and the lens candidate is judged on the same sets.
constexpr std::size_t kFirstResidualSets = 2;
std::vector<FrameSet> residual_sets(const CalibJob& job) {
  if (!job.holdout_sets.empty()) return job.holdout_sets;
  const std::size_t n = job.calib_sets.size(), keep = std::min(n, kFirstResidualSets);
  return std::vector<FrameSet>(job.calib_sets.end() - std::ptrdiff_t(keep), job.calib_sets.end());
}

// `fit_current_canvas`: the lens rig is fitted into the installed panorama's size (a background
// fit mid-stream); false (a first calibration): laid out as a first calibration's canvas.
// `pinhole_camera_px`: the installed calibration's measured residual when known (-1: not): past
// kPoorAlignmentCameraPx the pinhole fit is plainly wrong and the cheap test is skipped (its
// errors are capped at 3 px: a k1 -0.40 row at 17.5 px showed 2.8 -> 2.7 px there, "no sign").
CalibOutcome run_lens_job(const CalibJob& job, const std::atomic<bool>& cancel, bool fit_current_canvas = true,
                          double pinhole_camera_px = -1) {
  CalibOutcome o;
  o.kind = job.kind;
  o.serial = job.serial;
  auto cancelled = [&]() { return (o.cancelled = cancel.load()); };
  if (!job.current || job.calib_sets.empty()) {
    o.error = job.current ? "no usable frames" : "no calibration to start from";
    return o;
  }
  // Two of the window's sets (its first and last): a lens is the camera's, the same in every
  // frame; each set more costs the whole fit again (3 x 640x480, 5 sets: ~45 s a start on a
  // loaded core).
  std::vector<std::vector<ImageView>> sets;
  const std::size_t n = job.calib_sets.size();
  for (std::size_t k = 0; k < n; ++k)
    if (k == 0 || (k + 1 == n && sets.size() < kLensFitSets)) sets.push_back(job.calib_sets[k].views());
  const CalibrationOptions& opt = job.config.options;
  CameraModel model = opt.bundle_adjust ? CameraModel::Rotation : opt.model;
  if (model == CameraModel::Auto) model = job.current->planar() && job.current->cameras[0].homography ? CameraModel::Homography : CameraModel::Rotation;
  CalibrationOptions lo = opt;
  lo.model = CameraModel::Rotation;
  lo.bundle_adjust = false;
  lo.projection.reset();  // the installed canvas's (the start's)
  lo.cancel = &cancel;    // a cancelled job stops at the calibrator's next stage
  // A budget: on a clip that shows no distortion every start fails, slowly (the house clip: 143 s
  // of a core, taken from the chain on a CPU-only machine). A fit that wins took 3-64 s on the
  // loaded 2-core VM (k1 -0.3 from guessed focal lengths the longest).
  lo.deadline = std::chrono::steady_clock::now() + std::chrono::seconds(kLensJobBudgetS);
  // The cheap test first (lens_precheck: a k1 adjustment of sparse matches against a pinhole
  // one, a fraction of a second): on cameras without distortion the whole fit below found nothing
  // in 3-143 s of a core (every real clip measured).
  const auto stage = [&](JobStage st) {
    if (job.progress) job.progress->stage = st;
  };
  try {
    stage(JobStage::LensTest);
    if (pinhole_camera_px <= kPoorAlignmentCameraPx) o.lens_precheck = lens_precheck(*job.current, sets, lo);
  } catch (const CalibrationCancelled&) {
    if (cancelled()) return o;
    o.error = "no lens evidence within " + std::to_string(kLensJobBudgetS) + " s";
    return o;
  } catch (const std::exception& e) {
    o.error = std::string("no lens evidence: ") + e.what();
    return o;
  }
  if (o.lens_precheck && !o.lens_precheck->plausible) {
    o.error = "no sign of lens distortion in the matches (" + o.lens_precheck->describe() + ")";
    return o;
  }
  std::optional<CalibrationResult> best;
  bool out_of_time = false;
  stage(JobStage::LensFit);
  const auto fit_from = [&](const std::vector<Rig>& starts) {
    for (const Rig& start : starts) {
      // A start that fits within half a pixel held out is the lens: the others cost a whole fit each.
      if (cancelled() || out_of_time || (best && best->rotation_heldout_px < kLensFitGoodPx)) return;
      try {
        CalibrationResult r = calibrate_from_rig(start, sets, lo);
        if (lens_fit_usable(r) && (!best || r.rotation_heldout_px < best->rotation_heldout_px)) best = std::move(r);
      } catch (const CalibrationCancelled&) {
        if (cancelled()) return;
        out_of_time = true;  // the budget: the best start so far, if any, is still judged
        return;
      } catch (const std::exception&) {
        // no usable lens fit from this start
      }
    }
  };
  fit_from(lens_fit_starts(*job.current, model));
  // The pinhole fit of distorted cameras can hold focal lengths far off (a k1 -0.23 trio on a
  // plane canvas: 594 px for a true 260), and the lens fit from there runs off (the calibrator
  // keeps the rough rig). Then from focal lengths guessed from the frame width (60, 45, 80
  // degrees across), rotations read from the pinhole fit's pixel maps through them
  // (lens_fit_guessed_starts; a k1 -0.40 row: 3700 px for a true 763, no fit from there). Only
  // then, and only past the cheap test: on the real house clip (no distortion) three more starts
  // cost ~80 s of a core for nothing.
  if (!best && !out_of_time && model == CameraModel::Rotation) fit_from(lens_fit_guessed_starts(*job.current));
  if (cancelled()) return o;
  if (!best) {
    o.error = out_of_time ? "no usable lens fit within " + std::to_string(kLensJobBudgetS) + " s" : "no usable lens fit";
    return o;
  }
  o.result = std::move(best);
  Rig& rig = o.result->rig;
  if (fit_current_canvas) {
    fit_canvas(rig, job.current->canvas_width, job.current->canvas_height);
  } else {
    shrink_canvas_to_output(rig, job.config.output_width, job.config.output_height, job.config.output_crop);
    make_canvas_even(rig);
  }
  stage(JobStage::LensJudging);
  const bool heldout = !job.holdout_sets.empty();
  const std::vector<FrameSet> judge = residual_sets(job);
  o.residual_source = heldout ? "held-out" : "calibration frames";
  o.candidate = measure_residuals(rig, judge, &cancel);
  if (cancelled()) return o;
  o.current = measure_residuals(*job.current, judge, &cancel);
  o.candidate_cover = rig_coverage(rig);
  o.current_cover = rig_coverage(*job.current);
  cancelled();
  return o;
}

}  // namespace

CalibOutcome run_calib_job(const CalibJob& job, const std::atomic<bool>& cancel) {
  if (job.kind == JobKind::Lens) return run_lens_job(job, cancel);
  CalibOutcome o;
  o.kind = job.kind;
  o.serial = job.serial;
  auto cancelled = [&]() { return (o.cancelled = cancel.load()); };
  if (cancelled()) return o;
  if (job.kind == JobKind::DriftCheck || job.kind == JobKind::LoadCheck) {
    if (!job.current) {
      o.error = "nothing to check";
      return o;
    }
    o.current = measure_residuals(*job.current, job.holdout_sets, &cancel);
    o.residual_source = "held-out";
    cancelled();
    return o;
  }
  std::vector<std::vector<ImageView>> sets;
  for (const auto& s : job.calib_sets) sets.push_back(s.views());
  if (sets.empty()) {
    o.error = "no usable frames";
    return o;
  }
  // A job without some cameras speaks of all of them: its messages are renumbered.
  const std::vector<int> kept = full_indices(job.sizes.size(), job.left_out);
  const auto speak = [&](const std::string& text) {
    if (!job.left_out) return text;
    return renumbered(text, kept) + " (" + camera_list(job.left_out, job.sizes.size()) + " left out: no picture)";
  };
  SessionConfig config = job.config;
  config.options.cancel = &cancel;  // a cancelled job stops at the calibrator's next stage
  if (job.progress) job.progress->stage = JobStage::Estimating;
  try {
    if (!job.lenses.empty() && !job.rough && !job.left_out) {
      // Cameras whose lenses are known keep them; when the refit with them fails (another camera
      // plugged in?), the pinhole calibration as without them, judged as usual.
      CalibrationOptions lo = config.options;
      lo.projection = config.projection;
      try {
        o.result = calibrate_from_images_with_lenses(sets, config.reference, job.lenses, lo);
        o.kept_lenses = true;
      } catch (const RigError& e) {
        o.lens_error = e.what();
      }
    }
    if (!o.result) o.result = calibrate(config, job.rough, sets);
  } catch (const CalibrationCancelled&) {
    o.cancelled = true;
    return o;
  } catch (const RigError& e) {
    o.error = speak(e.what());
    // Degenerate rough geometry cannot be repaired by other frames.
    o.fatal = job.kind == JobKind::First && job.rough.has_value();
    return o;
  }
  if (cancelled()) return o;
  if (job.left_out) {
    const auto to_full = [&](int& camera) {
      if (camera >= 0 && std::size_t(camera) < kept.size()) camera = kept[std::size_t(camera)];
    };
    for (auto& w : o.result->warnings) w = speak(w);
    for (auto& c : o.result->cameras) to_full(c.camera);
    for (auto& p : o.result->pairs) to_full(p.camera), to_full(p.neighbour);
  }
  Rig& rig = o.result->rig;
  if (job.fit_width > 0 && job.fit_height > 0) {
    fit_canvas(rig, job.fit_width, job.fit_height);
  } else {
    shrink_canvas_to_output(rig, job.config.output_width, job.config.output_height, job.config.output_crop);
    make_canvas_even(rig);
  }
  const bool heldout = !job.holdout_sets.empty();
  const std::vector<FrameSet> judge = residual_sets(job);
  if (job.progress) job.progress->stage = JobStage::Measuring;
  o.residual_source = heldout ? "held-out" : "calibration frames";
  o.candidate = measure_residuals(rig, judge, &cancel);
  if (cancelled()) return o;
  if (job.kind != JobKind::First && job.current) {
    o.current = measure_residuals(*job.current, judge, &cancel);
    o.candidate_cover = rig_coverage(rig);
    o.current_cover = rig_coverage(*job.current);
  }
  if (job.kind == JobKind::First && job.lens_before_output && !job.left_out && !job.rough && !o.kept_lenses &&
      o.candidate.median_camera_px > kLensEvidenceMinPx && rig_lens_summary(rig) == "pinhole") {
    // The lens fit before the output starts (CalibJob::lens_before_output): the background job's
    // own fit, on this job's frames, from this pinhole calibration, judged the same way.
    CalibJob lens_job;
    lens_job.kind = JobKind::Lens;
    lens_job.serial = job.serial;
    lens_job.config = job.config;
    lens_job.current = std::make_shared<const Rig>(rig);
    lens_job.calib_sets = job.calib_sets;
    lens_job.holdout_sets = job.holdout_sets;
    lens_job.progress = job.progress;  // the stream that waits says which stage
    // From scratch mid-stream (fit_width set), the panorama keeps its size: the lens rig is fitted
    // into the pinhole one's canvas, which was fitted into it.
    CalibOutcome lens = run_lens_job(lens_job, cancel, job.fit_width > 0 && job.fit_height > 0, o.candidate.median_camera_px);
    if (cancelled()) return o;
    o.lens_tried = true;
    o.lens_precheck = lens.lens_precheck;
    if (!lens.result || !lens.error.empty()) {
      o.lens_not_kept = lens.error.empty() ? "no usable lens fit" : lens.error;
    } else {
      lens.candidate_cover = rig_coverage(lens.result->rig);
      lens.current_cover = rig_coverage(rig);
      const Judgement verdict =
          judge_lens_candidate(lens.candidate, o.candidate, lens.candidate_cover, lens.current_cover);
      if (verdict.install) {
        // Better is not good: a fisheye beside a 1x camera went 13.7 -> 4.7 camera px with two radtan
        // lenses, still 19 px off the truth (under the poor-alignment warning's 5 px): said.
        const double left = lens.candidate.median_camera_px;
        lens.result->warnings.push_back(
            "lens distortion found in the images (" + fmt(o.candidate.median_camera_px, 2) + " camera px pinhole, " +
            fmt(left, 2) + " with radtan k1/k2): the cameras get radtan lenses" +
            (left > kLensFitFairPx ? "; the overlaps still stay " + fmt(left, 2) +
                                         " camera px apart: the seams will show (a fisheye or mixed lenses?); a "
                                         "rig-file with the lenses helps"
                                   : std::string()));
        o.result = std::move(lens.result);
        o.candidate = lens.candidate;
      } else {
        o.lens_not_kept = verdict.reason;
      }
    }
  }
  if (job.left_out) with_left_out_cameras(rig, o.candidate, job.left_out, job.sizes);
  cancelled();
  return o;
}

// ---- the session -----------------------------------------------------------------------------

void CalibSession::set_config(const SessionConfig& config) { config_ = config; }

std::vector<SessionEvent> CalibSession::take_events() {
  std::vector<SessionEvent> e;
  e.swap(events_);
  return e;
}

void CalibSession::reset() {
  const SessionConfig config = config_;
  *this = CalibSession();
  config_ = config;
}

void CalibSession::note_time(double t) {
  if (have_t_ && t > last_t_) now_ += t - last_t_;  // a seek back does not stop the clock
  last_t_ = t;
  have_t_ = true;
}

std::string poor_alignment_text(const RigResiduals& r, double limit_camera_px) {
  const double px = r.median_camera_px;
  if (px < 0 || px <= limit_camera_px) return {};
  const PairResidual* worst = nullptr;
  for (const auto& p : r.pairs)
    if (p.median_camera_px >= 0 && (!worst || p.median_camera_px > worst->median_camera_px)) worst = &p;
  return "The calibration leaves the overlaps " + fmt(px) + " camera px apart (independent matches" +
         (worst ? "; worst cameras " + std::to_string(worst->a) + " and " + std::to_string(worst->b) + ", " +
                      fmt(worst->median_camera_px) + " px"
                : std::string()) +
         "): the seams will show. Likely a lens stronger than the model found (fisheye, strong barrel, mixed "
         "lenses), near objects with cameras far apart, or too little overlap; a rig-file with each camera's "
         "lens and rough placement helps";
}

std::string unverified_overlap_text(const RigResiduals& r) {
  if (r.unverified.empty()) return {};
  std::string pairs;
  for (std::size_t k = 0; k < r.unverified.size(); ++k)
    pairs += (k ? (k + 1 == r.unverified.size() ? " and " : ", ") : "") + std::to_string(r.unverified[k].first) + "-" +
             std::to_string(r.unverified[k].second);
  const bool one = r.unverified.size() == 1;
  return std::string("The overlap") + (one ? " of cameras " : "s of the camera pairs ") + pairs +
         " could not be verified: no feature matched there and the picture is too plain to align by area, so the "
         "alignment figures leave " + (one ? "it" : "them") + " out and the seam" + (one ? "" : "s") +
         " there may be off by several pixels (a 360-degree ring's closure error lands on such a seam). More "
         "texture in that overlap, a wider overlap, or a rig-file with the cameras' placement helps";
}

void CalibSession::say_poor_alignment(const CalibReport& rep) {
  // A loaded file that does not fit is said by its own check (the pairs it misaligns).
  if (rep.source == "file" || rep.residuals.median_camera_px < 0) return;
  const std::string text = poor_alignment_text(rep.residuals, kPoorAlignmentCameraPx);
  if (text.empty()) poor_alignment_said_ = false;
  else if (!poor_alignment_said_) {
    poor_alignment_said_ = true;
    warn(text);
  }
}

void CalibSession::warn(const std::string& s) {
  SessionEvent e = make_event(SessionEvent::Type::Warning, s);
  events_.push_back(e);
}

void CalibSession::fail(const std::string& s) {
  if (failed_) return;
  failed_ = true;
  SessionEvent e = make_event(SessionEvent::Type::Error, s);
  events_.push_back(e);
}

void CalibSession::pending(const std::string& why) {
  last_problem_ = why;
  const double waited = now_ - first_frame_at_;
  if (config_.calibration_timeout_s > 0 && waited > config_.calibration_timeout_s) {
    fail("Could not calibrate within " + fmt(config_.calibration_timeout_s) + " s of running time (calibration-timeout): " + why);
    return;
  }
  if (now_ - last_pending_at_ < config_.pending_interval_s) return;
  last_pending_at_ = now_;
  SessionEvent e = make_event(SessionEvent::Type::Pending, why);
  e.waited_s = waited;
  events_.push_back(e);
}

bool CalibSession::handle_sizes(const Frame& frame) {
  if (!current_ || sizes_.empty() || sizes_ == frame.sizes) return true;
  // a missing view's size is a placeholder, not its camera's (a loaded rig keeps the file's)
  auto differs = [&](std::size_t i) { return frame.sizes[i] != sizes_[i] && !bit(frame.missing_mask, i); };
  std::string what;
  if (frame.sizes.size() != sizes_.size()) {
    // A camera added while playing is calibrated in, whatever on-resize says; one that leaves
    // follows on-resize (its doc block).
    const std::string change = "The number of cameras changed mid-stream (" + std::to_string(sizes_.size()) +
                               " -> " + std::to_string(frame.sizes.size()) + ")";
    if (config_.resize_is_error && frame.sizes.size() < sizes_.size()) {
      fail(change + " and on-resize=error");
      return false;
    }
    if (keep_remaining_cameras(frame)) return true;
    warn(change + "; calibrating again with every camera");
    forget_calibration();
    return true;
  } else {
    bool any = false, only_left_out = true;
    for (std::size_t i = 0; i < sizes_.size(); ++i)
      if (differs(i)) any = true, only_left_out = only_left_out && bit(left_out_, i);
    if (!any) return true;
    if (only_left_out) {  // a left-out camera's placeholder size: it has started
      rejoin(left_out_ & ~frame.missing_mask, sizes_.size());
      return true;
    }
    for (std::size_t i = 0; i < sizes_.size(); ++i)
      if (differs(i))
        what += (what.empty() ? "" : ", ") + std::string("camera ") + std::to_string(i) + " " + size_text(sizes_[i]) +
                " -> " + size_text(frame.sizes[i]);
  }
  if (config_.resize_is_error) {
    fail("Input resolution changed mid-stream (" + what + ") and on-resize=error");
    return false;
  }
  warn("Input resolution changed mid-stream (" + what + "); recalibrating");
  forget_calibration();
  return true;
}

bool CalibSession::keep_remaining_cameras(const Frame& frame) {
  // Cameras that left (their pads released): the ones that stay have not moved, so their geometry
  // is kept and the panorama goes on at once. A calibration from scratch could fail for good
  // where the camera that left was the only link between the others (the middle one of three).
  if (frame.sizes.size() >= sizes_.size() || frame.sizes.size() < 2 || camera_ids_.size() != sizes_.size() ||
      frame.camera_ids.size() != frame.sizes.size() || current_->cameras.size() != sizes_.size())
    return false;
  std::vector<std::size_t> keep;
  for (std::size_t j = 0; j < frame.camera_ids.size(); ++j) {
    std::size_t i = 0;
    while (i < camera_ids_.size() && camera_ids_[i] != frame.camera_ids[j]) ++i;
    if (i == camera_ids_.size() || (!keep.empty() && i <= keep.back()) || frame.sizes[j] != sizes_[i]) return false;
    keep.push_back(i);
  }
  Rig rig = *current_;
  rig.cameras.clear();
  std::uint64_t left_out = 0;
  std::vector<double> absent;
  std::string gone;
  int reference = -1;
  for (std::size_t j = 0; j < keep.size(); ++j) {
    rig.cameras.push_back(current_->cameras[keep[j]]);
    if (bit(left_out_, keep[j])) left_out |= std::uint64_t(1) << j;
    if (keep[j] < absent_since_.size()) absent.resize(j + 1, -1), absent[j] = absent_since_[keep[j]];
    if (int(keep[j]) == current_->reference) reference = int(j);
  }
  for (std::size_t i = 0, j = 0; i < camera_ids_.size(); ++i) {
    if (j < keep.size() && keep[j] == i) { ++j; continue; }
    gone += (gone.empty() ? "" : ", ") + std::string("camera ") + std::to_string(i) + " (input " + std::to_string(camera_ids_[i]) + ")";
  }
  int live = 0;
  for (const Camera& c : rig.cameras) live += c.left_out ? 0 : 1;
  if (live < 2) return false;
  // The reference only anchors the rig frame and the colour correction: the middle one that stays.
  if (reference < 0) reference = int(keep.size() / 2);
  rig.reference = reference;
  warn("The number of cameras changed mid-stream (" + std::to_string(sizes_.size()) + " -> " +
       std::to_string(frame.sizes.size()) + "): " + gone + " left" +
       "; the other cameras keep their calibration");
  sizes_ = frame.sizes;
  camera_ids_ = frame.camera_ids;
  left_out_ = left_out;
  absent_since_ = absent;
  window_open_ = false;
  bins_.clear();
  job_in_flight_ = false;
  ++serial_;
  CalibrationResult r;
  r.rig = std::move(rig);
  if (installed_model_) r.model = *installed_model_;
  CalibReport rep;
  rep.source = installed_model_ ? "kept" : "file";  // a kept loaded file stays one (no model)
  const std::string source = "kept";
  const int w = panorama_w_, h = panorama_h_;
  // save-file keeps the whole rig's calibration: a part of it is nothing new (and a file for fewer
  // cameras would not load for the whole rig)
  const std::string save_file = config_.save_file;
  config_.save_file.clear();
  install(rep, &r);
  config_.save_file = save_file;
  if (!events_.empty() && events_.back().type == SessionEvent::Type::Installed) events_.back().report.source = source;
  panorama_w_ = w, panorama_h_ = h;
  return true;
}

void CalibSession::rejoin(std::uint64_t back, std::size_t cameras) {
  warn(camera_list(back, cameras) + agree(back, " delivers", " deliver") +
       " a picture now: calibrating again with every camera");
  forget_calibration();
}

std::shared_ptr<CalibJob> CalibSession::rejoin_in_background(std::uint64_t back, const Frame& frame,
                                                            const std::vector<ImageView>& views) {
  // The cameras still absent stay out; every camera in the job must show features.
  const std::uint64_t leave = left_out_ & frame.missing_mask;
  if (!bundle_problem(views, !rough_.has_value(), nullptr, leave).empty()) return nullptr;
  if (!rejoin_announced_)
    warn(camera_list(back, views.size()) + agree(back, " delivers", " deliver") +
         " a picture now: calibrating again with " + agree(back, "it", "them") +
         (frame.live ? std::string(", in the background; the panorama goes on without ") + agree(back, "it", "them") + " meanwhile"
                     : std::string(" (the stream waits for it: the cameras are not live)")));
  rejoin_announced_ = true;
  // From scratch (the rough rig or the images: the old geometry was made without it), in the
  // panorama the stream already has.
  auto job = make_job(JobKind::First);
  job->fit_width = panorama_w_;
  job->fit_height = panorama_h_;
  job->calib_sets.push_back(FrameSet::copy_of(kept_items(views, leave)));
  leave_out_of_job(*job, leave, frame.sizes, config_.reference);
  return job;
}

void CalibSession::forget_calibration() {
  // From scratch (the rough rig or the images), never from the old geometry: it was made for
  // other cameras. Jobs in flight are forgotten; the version keeps counting.
  current_.reset();
  left_out_ = 0;
  rejoin_announced_ = rejoin_failed_ = false;
  absent_since_.clear();
  rough_.reset();
  sizes_.clear();
  if (panorama_w_ > 0 && panorama_h_ > 0) refit_w_ = panorama_w_, refit_h_ = panorama_h_;
  panorama_w_ = panorama_h_ = 0;
  window_open_ = false;
  bins_.clear();
  load_check_due_ = false;
  job_in_flight_ = false;
  lens_wanted_ = lens_due_ = false;
  last_calib_sets_.clear();
  last_holdout_sets_.clear();
  failed_first_attempts_ = 0;
  tried_sets_.clear();
  ++serial_;
  first_frame_at_ = now_;
  next_attempt_at_ = now_;
  last_pending_at_ = -1e9;
}

void CalibSession::warn_unknown_fields(const std::string& property, const std::string& path, const Rig& rig) {
  if (rig.unknown_fields.empty()) return;
  std::string list;
  for (const auto& f : rig.unknown_fields) list += (list.empty() ? "" : "; ") + f;
  warn(property + " \"" + path + "\": ignored " + (rig.unknown_fields.size() > 1 ? "fields it does not know: " : "a field it does not know: ") + list);
}

bool CalibSession::load_file(uint64_t missing) {
  const SessionConfig& s = config_;
  Rig rig;
  try {
    rig = rig_load(s.load_file);
  } catch (const std::exception& e) {
    fail(e.what());
    return false;
  }
  warn_unknown_fields("load-file", s.load_file, rig);
  if (s.projection && rig.projection != projection_name(*s.projection))
    warn("load-file \"" + s.load_file + "\" holds a " + rig.projection + " calibration; projection=" +
         projection_name(*s.projection) + " applies to estimation only, the file is used as is");
  if (!rig.calibrated()) {
    fail("load-file \"" + s.load_file +
         "\" holds no calibration (a planar rig needs a \"homography\" per camera and a \"canvas\", a "
         "non-planar one a \"canvas\" with \"scale\"); use rig-file for rough parameters");
    return false;
  }
  if (rig.cameras.size() != sizes_.size()) {
    fail("load-file \"" + s.load_file + "\" describes " + std::to_string(rig.cameras.size()) + " cameras but " +
         std::to_string(sizes_.size()) + " streams are connected");
    return false;
  }
  for (std::size_t i = 0; i < sizes_.size() && i < 64; ++i)
    if (missing >> i & 1) sizes_[i] = {rig.cameras[i].width, rig.cameras[i].height};
  const bool adapted = rig_adapt_to_sizes(rig, sizes_);
  if (adapted) warn("The calibration was made for other frame sizes; it was scaled to the streams");
  try {
    // Laid out on a copy: that checks the geometry (degenerate homographies, grazing views). A
    // calibration used at the sizes it was made for keeps its own canvas, the panorama it was
    // saved as (a recalibration fitted into the stream's size): laid out again, a cylindrical
    // office rig saved at 1066x580 came back as a 1066x560 panorama.
    Rig laid = rig;
    rig_layout_canvas(laid);
    if (adapted) rig = std::move(laid);
  } catch (const std::exception& e) {
    fail(std::string("load-file: ") + e.what());
    return false;
  }
  make_canvas_even(rig);
  CalibrationResult r;
  r.rig = rig;
  CalibReport rep;
  rep.source = "file";
  install(rep, &r);
  load_check_due_ = true;
  return true;
}

bool CalibSession::load_rough() {
  const SessionConfig& s = config_;
  if (s.rig_file.empty()) {
    rough_.reset();
    return true;
  }
  if (rough_ && rough_from_ == s.rig_file && rough_sizes_ == sizes_) return true;
  try {
    rough_ = rig_load(s.rig_file);
  } catch (const std::exception& e) {
    fail(e.what());
    return false;
  }
  rough_from_ = s.rig_file;
  rough_sizes_ = sizes_;
  warn_unknown_fields("rig-file", s.rig_file, *rough_);
  if (rough_->cameras.size() != sizes_.size()) {
    fail("rig-file \"" + s.rig_file + "\" describes " + std::to_string(rough_->cameras.size()) + " cameras but " +
         std::to_string(sizes_.size()) + " streams are connected");
    return false;
  }
  if (rig_adapt_to_sizes(*rough_, sizes_)) warn("rig-file camera sizes differ from the streams; intrinsics were scaled");
  return true;
}

namespace {
void fill_report(CalibReport& rep, const CalibrationResult* result) {
  if (rep.source != "file") rep.model = camera_model_name(result->model);  // a loaded file: not estimated
  rep.refined_cameras = result->refined_cameras;
  rep.warnings = int(result->warnings.size());
  rep.ba_rms_px = result->ba_rms_after_px;
  double sum2 = 0;
  int accepted = 0;
  for (const auto& p : result->pairs) {
    rep.inliers += p.inliers;
    if (p.accepted && p.rms_px > 0) {
      sum2 += p.rms_px * p.rms_px;
      ++accepted;
    }
  }
  rep.fit_rms_px = accepted ? std::sqrt(sum2 / accepted) : -1;
}
}  // namespace

void CalibSession::install(CalibReport rep, CalibrationResult* result) {
  for (const auto& w : result->warnings) warn("Calibration: " + w);
  current_ = std::make_shared<const Rig>(result->rig);
  rep.rig = current_;
  rep.version = ++version_;
  fill_report(rep, result);
  if (!rep.model.empty()) installed_model_ = result->model;
  else installed_model_.reset();
  note_installed_lenses(rep.source);
  ever_installed_ = true;
  panorama_w_ = current_->canvas_width;
  panorama_h_ = current_->canvas_height;
  last_calibration_at_ = now_;
  if (rep.residuals.median_px >= 0) baseline_px_ = rep.residuals.median_px;
  say_poor_alignment(rep);
  // A seam that no figure covers is said too (once for the same pairs).
  const std::string unverified = rep.source == "file" ? std::string() : unverified_overlap_text(rep.residuals);
  if (!unverified.empty() && unverified != unverified_said_) warn(unverified);
  unverified_said_ = unverified;
  if (!config_.save_file.empty() && any_left_out(*current_)) {
    warn("save-file: not written while a camera is left out of the calibration");
  } else if (!config_.save_file.empty()) {
    try {
      rig_save(*current_, config_.save_file);
    } catch (const std::exception& e) {
      warn(std::string("save-file: ") + e.what());
    }
  }
  SessionEvent e = make_event(SessionEvent::Type::Installed, "");
  e.report = rep;
  events_.push_back(e);
}

void CalibSession::reject(CalibReport rep, const CalibrationResult& result) {
  rep.rig = std::make_shared<const Rig>(result.rig);
  rep.version = version_;
  fill_report(rep, &result);
  SessionEvent e = make_event(SessionEvent::Type::Rejected, "");
  e.report = rep;
  events_.push_back(e);
}

void CalibSession::start_window(JobKind kind) {
  window_open_ = true;
  window_kind_ = kind;
  window_start_ = now_;
  const int pool = std::max(1, config_.calibration_frames);
  const int holdout = std::max(1, (pool * 2 + 4) / 5);
  const int n = pool + holdout;
  const int stride = std::max(1, n / holdout);
  bins_.assign(std::size_t(n), Bin());
  int marked = 0;
  for (int i = 0; i < n && marked < holdout; ++i)
    if (i % stride == stride / 2 || n - i <= holdout - marked) {
      bins_[std::size_t(i)].holdout = true;
      ++marked;
    }
}

std::shared_ptr<CalibJob> CalibSession::make_job(JobKind kind) {
  auto job = std::make_shared<CalibJob>();
  job->kind = kind;
  job->serial = ++serial_;
  job->config = config_;
  job->rough = rough_;
  job->current = current_;
  if (kind == JobKind::First && refit_w_ > 0) {
    // From scratch mid-stream: new geometry, in the panorama the stream already has.
    job->fit_width = refit_w_;
    job->fit_height = refit_h_;
  }
  if (kind != JobKind::First && current_) {
    // Same cameras: the panorama keeps its size (the saved canvas stays the video's size).
    job->fit_width = current_->canvas_width;
    job->fit_height = current_->canvas_height;
    // ...and the model and projection the first calibration chose, where the user left them to
    // auto: measured in canvas pixels, a held-out comparison across projections favours the one
    // that shrinks the overlaps (a stretched plane beat a cylinder "0.52 vs 3.10 px" on a real
    // two-camera office clip and replaced it mid-stream).
    if (installed_model_ && job->config.options.model == CameraModel::Auto && !job->config.options.bundle_adjust)
      job->config.options.model = *installed_model_;
    if (installed_model_ && !job->config.projection) job->config.projection = current_->projection_kind();
  }
  if ((kind == JobKind::First || kind == JobKind::Pooled || kind == JobKind::Recalibration) && !rough_ &&
      config_.load_file.empty())
    job->lenses = known_lenses_now();
  job_in_flight_ = true;
  in_flight_kind_ = kind;
  return job;
}

void CalibSession::note_installed_lenses(const std::string& source) {
  // Only what was estimated from the images (not a file, a rig-file, nor a kept rig).
  if (!current_ || !(source == "images" || source == "pooled" || source == "recalibration" || source == "lens")) return;
  const Rig& rig = *current_;
  // Radtan lenses (what the lens fit finds): a fisheye rig from the images (image circles) is
  // calibrated as one again by calibrate_from_images, and no ideal pinhole picture holds its view.
  bool all = !rig.cameras.empty();
  for (const Camera& c : rig.cameras) all &= !c.left_out && c.lens.model == Lens::Model::Radtan && !c.lens.estimate;
  if (!all) {
    // Calibrated without them (none known yet, or the pinhole calibration won): forgotten.
    if (!any_left_out(rig)) known_lenses_.clear(), known_lens_keys_.clear();
    return;
  }
  for (std::size_t i = 0; i < rig.cameras.size(); ++i) {
    const long key = camera_ids_.size() == rig.cameras.size() ? long(camera_ids_[i]) : long(i);
    Camera c = rig.cameras[i];
    c.homography.reset();
    const auto it = std::find(known_lens_keys_.begin(), known_lens_keys_.end(), key);
    if (it == known_lens_keys_.end()) {
      known_lens_keys_.push_back(key);
      known_lenses_.push_back(c);
    } else {
      known_lenses_[std::size_t(it - known_lens_keys_.begin())] = c;
    }
  }
}

std::vector<Camera> CalibSession::known_lenses_now() const {
  std::vector<Camera> out;
  if (known_lenses_.empty() || sizes_.empty()) return out;
  for (std::size_t i = 0; i < sizes_.size(); ++i) {
    const long key = camera_ids_.size() == sizes_.size() ? long(camera_ids_[i]) : long(i);
    const auto it = std::find(known_lens_keys_.begin(), known_lens_keys_.end(), key);
    if (it == known_lens_keys_.end()) return {};
    out.push_back(known_lenses_[std::size_t(it - known_lens_keys_.begin())]);
  }
  return out;
}

std::string CalibSession::lens_skip_reason(double residual_camera_px) const {
  const CalibrationOptions& o = config_.options;
  if (!o.lens_from_evidence) return "off";
  if (!current_) return "no calibration";
  if (!config_.rig_file.empty() || !config_.load_file.empty()) return "the rig-file or load-file states the lenses";
  if (o.model == CameraModel::Homography && !o.bundle_adjust) return "camera-model=homography";
  if (left_out_ || any_left_out(*current_)) return "a camera is left out";
  for (const auto& c : current_->cameras)
    if (!c.lens.pinhole()) return "the cameras have lenses already";
  // Cheap check first: no lens can beat a residual that is already within the evidence margin.
  if (residual_camera_px >= 0 && residual_camera_px <= kLensEvidenceMinPx) return "the pinhole calibration fits";
  return "";
}

void CalibSession::maybe_lens_due(double residual_camera_px) {
  if (!lens_wanted_) return;
  lens_wanted_ = false;
  lens_due_ = lens_skip_reason(residual_camera_px).empty() && !last_calib_sets_.empty();
  if (!lens_due_) last_calib_sets_.clear(), last_holdout_sets_.clear();
}

bool CalibSession::give_way(bool at_eos) {
  if (!job_in_flight_ || in_flight_kind_ != JobKind::Lens) return false;
  const bool window_ready = window_open_ && window_kind_ != JobKind::Lens &&
                            now_ >= window_start_ + config_.calibration_window_s;
  if (!at_eos && !window_ready) return false;
  job_in_flight_ = false;
  ++serial_;  // its outcome is stale now
  lens_wanted_ = !at_eos;  // tried again after that window's job, on its frames
  return true;
}

std::string CalibSession::bundle_problem(const std::vector<ImageView>& views, bool features_needed, double* score,
                                         std::uint64_t skip) {
  std::string problem;
  double worst = 1e300;
  bool torn_only = true;
  tears_.resize(views.size());
  for (std::size_t i = 0; i < views.size(); ++i) {
    if (bit(skip, i)) continue;
    FrameQuality q = assess_frame(views[i]);
    // A broken keyframe lasts until the next keyframe (a GOP, 1-2 s); a "tear" at the same row
    // for longer is the picture's own (the column rules and text lines of a newspaper, a still).
    // The same picture again (a still: imagefreeze, a JPEG repeated) never heals by waiting, and
    // a camera's GOP after a broken keyframe is not bit-identical (noise, motion): its tear is
    // the picture's own at once. (Stills of a bridge and a newspaper, 1.2 s of imagefreeze each,
    // ended with "could not calibrate ... camera 0 is corrupt (a torn picture)"; longer ones lost
    // their first 3 s.)
    Tear& t = tears_[i];
    if (q.verdict == FrameVerdict::Corrupt) {
      const bool same_row = t.since_s >= 0 && std::abs(q.tear_row - t.row) < 0.02;
      const bool same_picture = same_row && q.picture == t.picture;
      if (!same_row) t.since_s = now_;
      t.row = q.tear_row;
      t.picture = q.picture;
      if (same_picture || accept_torn_ || now_ - t.since_s >= kTearIsContentAfterS) q.verdict = FrameVerdict::Good;
    } else {
      t.since_s = -1;
    }
    const bool bad = q.verdict == FrameVerdict::Dark || q.verdict == FrameVerdict::Corrupt ||
                     (features_needed && q.verdict != FrameVerdict::Good);
    if (bad) problem += (problem.empty() ? "" : ", ") + std::string("camera ") + std::to_string(i) + " is " + q.describe();
    if (bad && q.verdict != FrameVerdict::Corrupt) torn_only = false;
    worst = std::min(worst, q.verdict == FrameVerdict::Good ? q.score() : 0.0);
  }
  if (score) *score = views.empty() ? 0 : worst;
  torn_only_ = !problem.empty() && torn_only;
  return problem;
}

bool CalibSession::waits_for_a_camera(const Frame& frame) const {
  const std::size_t n = frame.sizes.size();
  const std::uint64_t all = n >= 64 ? ~std::uint64_t(0) : (std::uint64_t(1) << n) - 1;
  return !current_ && !failed_ && config_.load_file.empty() && frame.missing_mask != 0 &&
         (frame.missing_mask & all) != all;
}

bool CalibSession::absent_long_enough(std::size_t camera) const {
  return camera < absent_since_.size() && absent_since_[camera] >= 0 &&
         now_ - absent_since_[camera] >= config_.leave_out_after_s;
}

bool CalibSession::shows_nothing(const ImageView& view) const {
  // Dark (a lens cap, a dead sensor), or, for a calibration from the images alone, featureless:
  // a flat white or grey picture (blown out, fogged, a cap in the light) that no matcher can
  // place (probe3: two phone clips and a white camera made no panorama at all). A rig-file
  // places a featureless camera by its rough geometry, so there it stays in.
  const FrameVerdict v = assess_frame(view).verdict;
  return v == FrameVerdict::Dark || (v == FrameVerdict::Featureless && config_.rig_file.empty());
}

std::uint64_t CalibSession::cameras_to_leave_out(const Frame& frame, const std::vector<ImageView>& views) {
  const std::size_t n = frame.sizes.size();
  if (n > 64 || config_.leave_out_after_s <= 0) return 0;
  absent_since_.resize(n, -1);
  std::uint64_t absent = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const bool gone = bit(frame.missing_mask, i) || (views.size() == n && shows_nothing(views[i]));
    if (!gone) {
      absent_since_[i] = -1;
      continue;
    }
    if (absent_since_[i] < 0) absent_since_[i] = now_;
    absent |= std::uint64_t(1) << i;
  }
  leave_out_blocked_.clear();
  if (!absent) return 0;
  for (std::size_t i = 0; i < n; ++i)
    if (bit(absent, i) && !absent_long_enough(i)) return 0;
  if (n - std::size_t(__builtin_popcountll(absent)) < 2) {
    leave_out_blocked_ = " (not left out: two cameras at least must deliver a picture)";
    return 0;
  }
  return absent;
}

bool CalibSession::retry_at_end() {
  if (current_ || failed_ || job_in_flight_ || failed_first_attempts_ == 0 || untried_bundles_ == 0) return false;
  bundles_to_next_attempt_ = 0;
  next_attempt_at_ = now_;
  return true;
}

bool CalibSession::wants_pixels(const Frame& frame) {
  if (failed_) return false;
  if (!current_ || (!sizes_.empty() && frame.sizes != sizes_)) {
    if (!config_.load_file.empty() || job_in_flight_) return false;
    if (frame.missing_mask == 0) return true;
    // the cameras that have delivered, once the missing ones may be left out
    for (std::size_t i = 0; i < frame.sizes.size(); ++i)
      if (bit(frame.missing_mask, i) && !absent_long_enough(i)) return false;
    return config_.leave_out_after_s > 0;
  }
  // a left-out camera that sends frames again: is it back (not dark)?
  if (left_out_)
    return !job_in_flight_ && (left_out_ & ~frame.missing_mask) != 0 && now_ - last_rejoin_check_ >= 0.5 &&
           now_ >= next_attempt_at_;
  if (frame.missing_mask) return false;
  if (window_open_ || load_check_due_ || recalibrate_requested_) return true;
  if (config_.recalibrate_interval_s > 0 && now_ + 0.5 >= last_calibration_at_ + config_.recalibrate_interval_s) return true;
  return config_.drift_threshold_px > 0 && now_ + 0.5 >= next_drift_check_at_;
}

std::shared_ptr<CalibJob> CalibSession::on_frame(const Frame& frame, const std::vector<ImageView>& views) {
  note_time(frame.time_s);
  torn_only_ = false;
  if (failed_) return nullptr;
  if (!handle_sizes(frame)) return nullptr;
  const bool have_pixels = !views.empty() && views.size() == frame.sizes.size();
  if (!current_) {
    if (first_frame_at_ < 0) first_frame_at_ = now_;
    sizes_ = frame.sizes;
    camera_ids_ = frame.camera_ids;
    if (!config_.load_file.empty()) {
      load_file(frame.missing_mask);
      return nullptr;
    }
    // A camera missing (or dark) for leave_out_after_s is left out: the others go on.
    const std::uint64_t leave = cameras_to_leave_out(frame, have_pixels ? views : std::vector<ImageView>());
    if (frame.missing_mask & ~leave) {
      const std::uint64_t waiting = frame.missing_mask & ~leave;
      pending(camera_list(waiting, frame.sizes.size()) + agree(waiting, " has", " have") + " not delivered a frame yet" +
              leave_out_blocked_);
      return nullptr;
    }
    if (!load_rough()) return nullptr;
    if (job_in_flight_) return nullptr;
    // Files: a failed attempt is followed on the next bundles (see failed_first_attempts_).
    const bool files_retry_now = !frame.live && failed_first_attempts_ > 0 && --bundles_to_next_attempt_ <= 0;
    if (now_ < next_attempt_at_ && !files_retry_now) {
      ++untried_bundles_;
      pending(last_problem_);
      return nullptr;
    }
    if (!have_pixels && !(rough_ && config_.options.refinement == Refinement::None)) return nullptr;
    // A rough rig holds geometry without features (refine=none reads no pixels at all); the
    // images alone need them in every camera.
    const std::string problem = rough_ && config_.options.refinement == Refinement::None
                                    ? std::string()
                                    : bundle_problem(views, !rough_.has_value(), nullptr, leave);
    if (!problem.empty()) {
      pending(problem + leave_out_blocked_);
      return nullptr;
    }
    if (have_pixels && !identical_warned_)
      for (const auto& [a, b] : identical_views(views, leave)) {
        warn("camera " + std::to_string(a) + " and camera " + std::to_string(b) +
             " show the same picture (the same source given twice?): they overlap completely and are stitched as one view");
        identical_warned_ = true;
      }
    untried_bundles_ = 0;
    auto job = make_job(JobKind::First);
    job->attempt = failed_first_attempts_ + 1;
    // Files wait for the first calibration: the lens fit goes in it (CalibJob::lens_before_output).
    const CalibrationOptions& co = config_.options;
    job->lens_before_output = !frame.live && have_pixels && co.lens_from_evidence && !rough_ && !leave &&
                              config_.rig_file.empty() && config_.load_file.empty() && job->lenses.empty() &&
                              !(co.model == CameraModel::Homography && !co.bundle_adjust);
    if (have_pixels) {
      job->calib_sets.push_back(FrameSet::copy_of(kept_items(views, leave)));
    } else {
      std::vector<cv::Mat> grey;  // refine=none: the frames are not read
      for (const auto& sz : kept_items(frame.sizes, leave)) grey.push_back(cv::Mat(sz[1], sz[0], CV_8UC4, cv::Scalar(0, 0, 0, 255)));
      job->calib_sets.push_back({grey});
    }
    if (have_pixels && !frame.live) {
      // Files: pooled with the newest frame sets tried before (of the same cameras).
      if (leave != tried_leave_) tried_sets_.clear();
      tried_leave_ = leave;
      const std::size_t keep = std::size_t(std::max(1, config_.calibration_frames)) - 1;
      if (tried_sets_.size() > keep) tried_sets_.erase(tried_sets_.begin(), tried_sets_.end() - std::ptrdiff_t(keep));
      tried_sets_.push_back(job->calib_sets.back());  // cv::Mat headers: shared, not copied
      job->calib_sets = tried_sets_;
    }
    leave_out_of_job(*job, leave, frame.sizes, config_.reference);
    return job;
  }
  if (left_out_) {
    // Calibrated without some cameras: nothing is pooled or recalibrated until they are back.
    // One that delivers a picture again (not dark) brings a calibration from scratch with it.
    const std::uint64_t back = left_out_ & ~frame.missing_mask;
    if (!back || !have_pixels || job_in_flight_ || (frame.missing_mask & ~left_out_)) return nullptr;
    last_rejoin_check_ = now_;
    for (std::size_t i = 0; i < views.size(); ++i)
      if (bit(back, i) && shows_nothing(views[i])) return nullptr;
    if (now_ < next_attempt_at_) return nullptr;  // a failed attempt waits retry_interval_s
    return rejoin_in_background(back, frame, views);
  }
  if (frame.missing_mask) return nullptr;
  // Triggers of a recalibration window. A lens window (the background lens fit collecting its
  // own frames) gives way to it: the lens is fitted after the recalibration, on its frames.
  if (!window_open_ || window_kind_ == JobKind::Lens) {
    bool due = false;
    if (recalibrate_requested_ && config_.load_file.empty()) due = true;
    if (config_.recalibrate_interval_s > 0 && config_.load_file.empty() &&
        now_ >= last_calibration_at_ + config_.recalibrate_interval_s)
      due = true;
    recalibrate_requested_ = false;
    if (due && window_open_) lens_wanted_ = true;
    if (due) start_window(JobKind::Recalibration);
  } else {
    recalibrate_requested_ = false;  // one window answers every request made while it collects
  }
  if (have_pixels && window_open_) {
    const double length = std::max(1e-3, config_.calibration_window_s);
    const int n = int(bins_.size());
    const int k = std::min(n - 1, int((now_ - window_start_) / (length / n)));
    double score = 0;
    if (k >= 0 && bundle_problem(views, true, &score).empty() && score > bins_[std::size_t(k)].score) {
      bins_[std::size_t(k)].best = FrameSet::copy_of(views);
      bins_[std::size_t(k)].score = score;
    }
  }
  if (job_in_flight_) return nullptr;
  if (window_open_ && now_ >= window_start_ + config_.calibration_window_s) {
    window_open_ = false;
    auto job = make_job(window_kind_);
    for (auto& b : bins_)
      if (b.best) (b.holdout ? job->holdout_sets : job->calib_sets).push_back(std::move(*b.best));
    bins_.clear();
    if (window_kind_ != JobKind::Lens) last_calibration_at_ = now_;
    if (job->calib_sets.empty()) {
      job_in_flight_ = false;
      if (window_kind_ == JobKind::Recalibration)
        warn("Recalibration skipped: no usable frames in the calibration window; keeping the current calibration");
      if (window_kind_ != JobKind::Lens) maybe_lens_due(-1);
      return nullptr;
    }
    // Too few frames to hold any out: judge on the calibration frames themselves.
    if (job->holdout_sets.empty() && job->calib_sets.size() > 1) {
      job->holdout_sets.push_back(std::move(job->calib_sets.back()));
      job->calib_sets.pop_back();
    }
    // The lens fit that may follow uses the same frames (cv::Mat headers: shared, not copied).
    last_calib_sets_ = job->calib_sets;
    last_holdout_sets_ = job->holdout_sets;
    return job;
  }
  if (lens_due_ && !window_open_) {
    lens_due_ = false;
    auto job = make_job(JobKind::Lens);
    job->calib_sets = std::move(last_calib_sets_);
    job->holdout_sets = std::move(last_holdout_sets_);
    last_calib_sets_.clear();
    last_holdout_sets_.clear();
    return job;
  }
  if (window_open_ || !have_pixels) return nullptr;
  const bool check_load = load_check_due_;
  const bool check_drift = config_.drift_threshold_px > 0 && now_ >= next_drift_check_at_;
  if (check_load || check_drift) {
    if (!bundle_problem(views, true, nullptr).empty()) return nullptr;  // try the next bundle
    auto job = make_job(check_load ? JobKind::LoadCheck : JobKind::DriftCheck);
    job->holdout_sets.push_back(FrameSet::copy_of(views));
    load_check_due_ = false;
    if (!check_load) next_drift_check_at_ = now_ + config_.drift_check_interval_s + drift_backoff_s_;
    return job;
  }
  return nullptr;
}

void CalibSession::on_outcome(const CalibOutcome& o) {
  if (!job_in_flight_ || o.serial != serial_) return;  // forgotten (a reset, a resize)
  job_in_flight_ = false;
  if (o.cancelled || failed_) return;
  if (!o.lens_error.empty() && o.result)
    warn("calibrating with the cameras' known lenses failed (" + o.lens_error + "): calibrated as pinhole cameras");
  switch (o.kind) {
    case JobKind::First: {
      if ((!o.error.empty() || !o.result) && current_) {
        // A camera's background rejoin: the panorama goes on without it; tried again later (each
        // attempt is a calibration from scratch: not every half second), said once.
        constexpr double kRejoinRetryS = 5.0;
        next_attempt_at_ = now_ + std::max(config_.retry_interval_s, kRejoinRetryS);
        if (!rejoin_failed_)
          warn("calibrating with the camera that came back failed (" + o.error + "): going on without it; trying again every " +
               fmt(std::max(config_.retry_interval_s, kRejoinRetryS)) + " s");
        rejoin_failed_ = true;
        return;
      }
      if (!o.error.empty() || !o.result) {
        if (o.fatal) {
          fail("Calibration failed: " + o.error);
          return;
        }
        next_attempt_at_ = now_ + config_.retry_interval_s;
        // Files lose no frame meanwhile (EarlyBundles): tried again 1, 2, 4, ... bundles later,
        // on the frame sets pooled so far, and at the live pace at least.
        ++failed_first_attempts_;
        bundles_to_next_attempt_ = 1 << std::min(failed_first_attempts_ - 1, 20);
        pending("calibration attempt failed (" + o.error + ")");
        return;
      }
      failed_first_attempts_ = 0;
      tried_sets_.clear();
      CalibrationResult r = *o.result;
      CalibReport rep;
      rep.source = rough_ ? "rig" : "images";
      rejoin_announced_ = rejoin_failed_ = false;
      rep.residuals = o.candidate;
      rep.residual_source = o.residual_source;
      left_out_ = 0;
      for (std::size_t i = 0; i < r.rig.cameras.size() && i < 64; ++i)
        if (r.rig.cameras[i].left_out) left_out_ |= std::uint64_t(1) << i;
      if (left_out_)
        warn(camera_list(left_out_, r.rig.cameras.size()) + " delivered no picture (no frame, a dark one, or a featureless one) for " +
             fmt(config_.leave_out_after_s) + " s: calibrated and stitched without " +
             agree(left_out_, "it; it joins", "them; each joins") +
             " with a calibration from scratch once it delivers (the panorama keeps its size)");
      install(rep, &r);
      // Pool better frames (refine=none reads none: nothing to gain).
      const bool pool =
          !left_out_ && config_.calibration_frames > 1 && !(rough_ && config_.options.refinement == Refinement::None);
      if (pool) start_window(JobKind::Pooled);
      // Then the lens from evidence, in the background: after the pooled window, on its frames,
      // or on a window of its own.
      lens_wanted_ = !o.lens_tried && lens_skip_reason(o.candidate.median_camera_px).empty();
      if (lens_wanted_ && !pool) start_window(JobKind::Lens);
      next_drift_check_at_ = now_ + config_.drift_check_interval_s;
      return;
    }
    case JobKind::Pooled:
    case JobKind::Recalibration: {
      const char* what = o.kind == JobKind::Pooled ? "pooled" : "recalibration";
      if (!o.error.empty() || !o.result) {
        warn(std::string(o.kind == JobKind::Pooled ? "Pooled calibration" : "Recalibration") + " failed (" + o.error +
             "); keeping the current calibration");
        maybe_lens_due(-1);
        return;
      }
      CalibReport rep;
      rep.source = what;
      rep.residuals = o.candidate;
      rep.residual_source = o.residual_source;
      rep.previous_px = o.current.median_px;
      rep.previous_camera_px = o.current.median_camera_px;
      const double cur = o.current.median_px;
      // It must beat the current one clearly on the same frames (no flipping between equals),
      // in camera pixels, and keep every overlap and the picture (judge_candidate).
      const Judgement verdict = judge_candidate(o.candidate, o.current, o.candidate_cover, o.current_cover);
      rep.rejected_because = verdict.reason;
      if (!o.candidate_cover.camera_share.empty()) rep.coverage = o.candidate_cover.share;
      if (!o.current_cover.camera_share.empty()) rep.previous_coverage = o.current_cover.share;
      if (verdict.install) {
        CalibrationResult r = *o.result;
        install(rep, &r);
      } else {
        maybe_lens_due(o.current.median_camera_px);
        if (cur >= 0) baseline_px_ = cur;
        reject(rep, *o.result);
      }
      // A recalibration installed (the rig moved) is pinhole: the lens is fitted again after it.
      if (verdict.install && o.kind == JobKind::Recalibration) lens_wanted_ = true;
      if (verdict.install) maybe_lens_due(o.candidate.median_camera_px);
      return;
    }
    case JobKind::Lens: {
      // No usable fit: the pinhole calibration stays, nothing to announce.
      if (!o.error.empty() || !o.result) return;
      CalibReport rep;
      rep.source = "lens";
      rep.residuals = o.candidate;
      rep.residual_source = o.residual_source;
      rep.previous_px = o.current.median_px;
      rep.previous_camera_px = o.current.median_camera_px;
      if (!o.candidate_cover.camera_share.empty()) rep.coverage = o.candidate_cover.share;
      if (!o.current_cover.camera_share.empty()) rep.previous_coverage = o.current_cover.share;
      // Judged as any candidate, and it must win by the evidence rule of calibrate_from_images
      // (a lens only where the images show distortion), in camera pixels on the same frames.
      const Judgement verdict = judge_lens_candidate(o.candidate, o.current, o.candidate_cover, o.current_cover);
      const double lens_px = o.candidate.median_camera_px, pin_px = o.current.median_camera_px;
      rep.rejected_because = verdict.reason;
      if (verdict.install) {
        CalibrationResult r = *o.result;
        r.warnings.push_back("lens distortion found in the images (" + fmt(pin_px, 2) + " camera px pinhole, " +
                             fmt(lens_px, 2) + " with radtan k1/k2, held out): the cameras get radtan lenses");
        install(rep, &r);
      } else {
        reject(rep, *o.result);
      }
      return;
    }
    case JobKind::DriftCheck: {
      const double px = o.current.median_px;
      const double limit = std::max(config_.drift_threshold_px, 2 * std::max(0.0, baseline_px_));
      if (px > limit) {
        if (++drift_strikes_ >= 2) {
          // Two checks in a row: recalibrate, and check less often until the alignment is back.
          drift_strikes_ = 0;
          drift_backoff_s_ = std::min(60.0, std::max(config_.drift_check_interval_s, 2 * drift_backoff_s_));
          warn("Alignment drifted to " + fmt(px) + " px (drift-threshold " + fmt(config_.drift_threshold_px) +
               " px); recalibrating");
          start_window(JobKind::Recalibration);
        }
      } else if (px >= 0 && px < 0.7 * limit) {
        drift_strikes_ = 0;
        drift_backoff_s_ = 0;
      }
      return;
    }
    case JobKind::LoadCheck: {
      const auto& r = o.current;
      if (r.matches == 0) return;  // nothing to judge by (flat or dark views)
      const int n = int(r.camera_px.size());
      std::string bad_pairs;
      std::vector<int> bad_count(std::size_t(n), 0), pair_count(std::size_t(n), 0);
      for (const auto& p : r.pairs) {
        ++pair_count[std::size_t(p.a)];
        ++pair_count[std::size_t(p.b)];
        if (p.median_px > config_.load_misfit_px) {
          bad_pairs += (bad_pairs.empty() ? "" : ", ") + std::to_string(p.a) + "-" + std::to_string(p.b) + " " +
                       fmt(p.median_px) + " px";
          ++bad_count[std::size_t(p.a)];
          ++bad_count[std::size_t(p.b)];
        }
      }
      if (bad_pairs.empty()) return;
      std::string who;
      int named = 0;
      for (int c = 0; c < n; ++c)
        if (pair_count[std::size_t(c)] > 0 && bad_count[std::size_t(c)] == pair_count[std::size_t(c)]) {
          who += (who.empty() ? "" : ", ") + std::to_string(c);
          ++named;
        }
      warn("load-file \"" + config_.load_file + "\" does not fit the images: " +
           (named ? std::string(named > 1 ? "cameras " : "camera ") + who + " misaligned" : std::string("misaligned")) +
           " (pairs " + bad_pairs + "; independent matches); it was made for another rig, or a camera moved: "
           "recalibrate (unset load-file) or fix the file");
      return;
    }
  }
}

void CalibSession::bundle_passed() {
  if (dropped_ > dropped_reported_) {
    // The drops since the last QoS message, summed up before the first bundle passes.
    dropped_reported_ = dropped_;
    SessionEvent e = make_event(SessionEvent::Type::Qos, "");
    e.processed = passed_;
    e.dropped = dropped_;
    events_.push_back(e);
  }
  ++passed_;
}

void CalibSession::bundle_dropped() {
  ++dropped_;
  if (dropped_reported_ != 0 && now_ - last_qos_at_ < config_.qos_interval_s) return;
  last_qos_at_ = now_;
  dropped_reported_ = dropped_;
  SessionEvent e = make_event(SessionEvent::Type::Qos, "");
  e.processed = passed_;
  e.dropped = dropped_;
  events_.push_back(e);
}

void CalibSession::abandon_job() {
  job_in_flight_ = false;
  ++serial_;
}

void CalibSession::on_eos() {
  if (ever_installed_ || failed_) return;
  fail("Could not calibrate before the stream ended, so no panorama was made" +
       (last_problem_.empty() ? std::string() : ": " + last_problem_));
}

}  // namespace stitch
