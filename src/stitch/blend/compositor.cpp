#include "stitch/blend/compositor.hpp"

#include "stitch/blend/blender_cpu.hpp"
#include "stitch/parallel.hpp"
#include "stitch/stage_profile.hpp"
#include "stitch/warp/warper_cpu.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace stitch {

namespace {
// The CPU blend's phases (warp, fuse, seams, mix, resample): STITCH_BLEND_PROFILE=1 (stage_profile.hpp).
StageProfile blend_profile() {
  static const bool enabled = StageProfile::enabled_for("blend");
  return StageProfile("blend", enabled);
}

// True when output = canvas shifted by whole pixels and inside it: the crop/scale pass is a copy.
bool crop_only(const Eigen::Matrix3d& A, const cv::Size& canvas, const cv::Size& out) {
  auto whole = [](double v) { return std::abs(v - std::round(v)) < 1e-9; };
  if (std::abs(A(0, 0) - 1) > 1e-12 || std::abs(A(1, 1) - 1) > 1e-12 || std::abs(A(0, 1)) > 1e-12 ||
      std::abs(A(1, 0)) > 1e-12 || !whole(A(0, 2)) || !whole(A(1, 2)))
    return false;
  const long tx = std::lround(-A(0, 2)), ty = std::lround(-A(1, 2));
  return tx >= 0 && ty >= 0 && tx + out.width <= canvas.width && ty + out.height <= canvas.height;
}

// The canvas rows [first, end) that compose_prewarped's crop/scale of the canvas into `out` reads
// (with a row to spare at each end); every row when the map is not a scale and translation.
std::pair<int, int> canvas_rows_read(const Eigen::Matrix3d& A, const cv::Size& canvas, const cv::Size& out) {
  if (crop_only(A, canvas, out)) {
    const int ty = int(std::lround(-A(1, 2)));
    return {ty, ty + out.height};
  }
  if (A(0, 1) != 0 || A(1, 0) != 0 || A(1, 1) <= 0) return {0, canvas.height};
  const double s = A(1, 1), t = A(1, 2);
  double first, last;  // canvas rows, centre coordinates
  if (A(0, 0) < 0.75 && s < 0.75) {  // resample_area: the footprints of rows 0 .. H-1
    first = (-0.5 - t) / s;
    last = (out.height - 0.5 - t) / s;
  } else if (A(0, 0) >= 0.75) {  // bilinear: the two rows around each sample
    first = (0 - t) / s;
    last = (out.height - 1 - t) / s + 1;
  } else {
    return {0, canvas.height};
  }
  const int y0 = std::max(0, int(std::floor(first)) - 1);
  const int y1 = std::min(canvas.height, int(std::ceil(last)) + 2);
  return y1 > y0 ? std::make_pair(y0, y1) : std::make_pair(0, canvas.height);
}

// One axis of an area resample: output pixel u covers [u - 0.5, u + 0.5], i.e. canvas
// [(u - 0.5 - t) / s, (u + 0.5 - t) / s]; each canvas pixel it overlaps weighs its overlap (pixels
// off the canvas left out, the rest renormalised). Weights in 1/2^14, summing to exactly 2^14 (the
// rounding remainder on the largest); `taps` entries per output pixel, padded with zero weights;
// count 0: the footprint misses the canvas (black).
struct AreaTaps {
  static constexpr int kBits = 14;
  int taps = 1;
  std::vector<int> index, count;
  std::vector<int32_t> weight;
  int first(int u) const { return index[std::size_t(u) * taps]; }
  int last(int u) const { return index[std::size_t(u) * taps + std::max(0, count[u] - 1)]; }
};

AreaTaps area_taps(double s, double t, int src, int dst) {
  AreaTaps a;
  a.taps = int(std::ceil(1.0 / s)) + 1;
  a.index.assign(std::size_t(dst) * a.taps, 0);
  a.weight.assign(a.index.size(), 0);
  a.count.assign(dst, 0);
  std::vector<double> w(a.taps);
  for (int u = 0; u < dst; ++u) {
    const double f0 = (u - 0.5 - t) / s, f1 = (u + 0.5 - t) / s;
    const int x0 = std::max(0, int(std::floor(f0 + 0.5))), x1 = std::min(src - 1, int(std::ceil(f1 + 0.5)) - 1);
    double total = 0;
    int n = 0;
    for (int x = x0; x <= x1 && n < a.taps; ++x) {
      const double o = std::min(f1, x + 0.5) - std::max(f0, x - 0.5);
      if (o <= 1e-9) continue;
      a.index[std::size_t(u) * a.taps + n] = x;
      w[n++] = o;
      total += o;
    }
    a.count[u] = n;
    if (n == 0) continue;
    int sum = 0, strongest = 0;
    for (int k = 0; k < n; ++k) {
      int32_t& q = a.weight[std::size_t(u) * a.taps + k];
      q = int32_t(std::lround(w[k] / total * (1 << AreaTaps::kBits)));
      sum += q;
      if (w[k] > w[strongest]) strongest = k;
    }
    a.weight[std::size_t(u) * a.taps + strongest] += (1 << AreaTaps::kBits) - sum;
    for (int k = n; k < a.taps; ++k) a.index[std::size_t(u) * a.taps + k] = a.index[std::size_t(u) * a.taps];
  }
  return a;
}

// dst = the area average of src under x -> sx x + tx, y -> sy y + ty (a downscale: s < 1), in one
// pass by output rows on every thread: each output row combines its canvas rows (int16, 7
// fraction bits), then resamples that row along x. Integers per pixel, so the same output on any
// thread count; SIMD pairs of taps (pmaddwd-style dot products). Replaces INTER_AREA to an integer
// grid followed by a bilinear warp (two passes; OpenCV's area resize at a non-integer scale is its
// slow generic path, 28% of the flow chain's time on one thread).
void resample_area(const cv::Mat& src, cv::Mat& dst, double sx, double tx, double sy, double ty) {
  const AreaTaps ax = area_taps(sx, tx, src.cols, dst.cols), ay = area_taps(sy, ty, src.rows, dst.rows);
  constexpr int kRowBits = 7;  // fraction bits of the combined rows: 255 << 7 fits int16
  constexpr int kOutShift = AreaTaps::kBits + kRowBits;
  // The canvas columns any output pixel reads, with room for the unused half of a last tap pair.
  int c0 = src.cols, c1 = -1;
  for (int u = 0; u < dst.cols; ++u)
    if (ax.count[u] > 0) c0 = std::min(c0, ax.first(u)), c1 = std::max(c1, ax.last(u));
  const int pairs_x = (ax.taps + 1) / 2, pairs_y = (ay.taps + 1) / 2;
  // Per output column and pair of taps: (w_k, w_k+1) as one int32 (low half first), and the
  // first tap's column relative to c0.
  std::vector<int32_t> wx(std::size_t(dst.cols) * pairs_x);
  std::vector<int> x0(dst.cols, 0);
  for (int u = 0; u < dst.cols; ++u) {
    x0[u] = std::max(0, ax.index[std::size_t(u) * ax.taps] - std::max(c0, 0));
    for (int j = 0; j < pairs_x; ++j) {
      const int k = 2 * j;
      const int32_t w0 = ax.count[u] ? ax.weight[std::size_t(u) * ax.taps + k] : 0;
      const int32_t w1 = ax.count[u] && k + 1 < ax.taps ? ax.weight[std::size_t(u) * ax.taps + k + 1] : 0;
      wx[std::size_t(u) * pairs_x + j] = int32_t(uint32_t(uint16_t(w0)) | uint32_t(uint16_t(w1)) << 16);
    }
  }
  const int span = c1 >= c0 ? c1 - c0 + 1 : 0;
  const int stripes = std::max(1, dst.rows / 8);
  cv::parallel_for_(cv::Range(0, dst.rows), [&](const cv::Range& range) {
    // one output row's canvas rows combined: span pixels, plus two pixels of zeros that an odd
    // tap count's padding tap reads (its weight is 0)
    std::vector<int16_t> row(std::size_t(span + 2) * 4 + 8, 0);
    for (int v = range.start; v < range.end; ++v) {
      uint8_t* pd = dst.ptr<uint8_t>(v);
      if (ay.count[v] == 0 || span == 0) {
        for (int u = 0; u < dst.cols; ++u) pd[4 * u] = pd[4 * u + 1] = pd[4 * u + 2] = 0, pd[4 * u + 3] = 255;
        continue;
      }
      // Along y: row = sum_k w_k src[y_k] (rounded to kRowBits fraction bits).
      const int n = span * 4;
      int x = 0;
#if CV_SIMD128
      for (; x + 16 <= n; x += 16) {
        cv::v_int32x4 acc0 = cv::v_setzero_s32(), acc1 = acc0, acc2 = acc0, acc3 = acc0;
        for (int j = 0; j < pairs_y; ++j) {
          const int k = 2 * j;
          const int32_t w0 = ay.weight[std::size_t(v) * ay.taps + k];
          const int32_t w1 = k + 1 < ay.taps ? ay.weight[std::size_t(v) * ay.taps + k + 1] : 0;
          const int ya = ay.index[std::size_t(v) * ay.taps + k];
          const int yb = k + 1 < ay.taps ? ay.index[std::size_t(v) * ay.taps + k + 1] : ya;
          const cv::v_int16x8 w = cv::v_reinterpret_as_s16(
              cv::v_setall_s32(int32_t(uint32_t(uint16_t(w0)) | uint32_t(uint16_t(w1)) << 16)));
          const cv::v_uint8x16 a = cv::v_load(src.ptr<uint8_t>(ya) + 4 * c0 + x);
          const cv::v_uint8x16 b = cv::v_load(src.ptr<uint8_t>(yb) + 4 * c0 + x);
          cv::v_uint16x8 a0, a1, b0, b1;
          cv::v_expand(a, a0, a1);
          cv::v_expand(b, b0, b1);
          cv::v_int16x8 ab0, ab1, ab2, ab3;
          cv::v_zip(cv::v_reinterpret_as_s16(a0), cv::v_reinterpret_as_s16(b0), ab0, ab1);
          cv::v_zip(cv::v_reinterpret_as_s16(a1), cv::v_reinterpret_as_s16(b1), ab2, ab3);
          acc0 += cv::v_dotprod(ab0, w);
          acc1 += cv::v_dotprod(ab1, w);
          acc2 += cv::v_dotprod(ab2, w);
          acc3 += cv::v_dotprod(ab3, w);
        }
        cv::v_store(row.data() + x, cv::v_rshr_pack<AreaTaps::kBits - kRowBits>(acc0, acc1));
        cv::v_store(row.data() + x + 8, cv::v_rshr_pack<AreaTaps::kBits - kRowBits>(acc2, acc3));
      }
#endif
      for (; x < n; ++x) {
        int32_t acc = 0;
        for (int k = 0; k < ay.taps; ++k)
          acc += ay.weight[std::size_t(v) * ay.taps + k] * src.ptr<uint8_t>(ay.index[std::size_t(v) * ay.taps + k])[4 * c0 + x];
        row[x] = int16_t((acc + (1 << (AreaTaps::kBits - kRowBits - 1))) >> (AreaTaps::kBits - kRowBits));
      }
      // Along x: each output pixel from its taps, two at a time.
      int u = 0;
#if CV_SIMD128
      for (; u + 2 <= dst.cols; u += 2) {
        cv::v_int32x4 acc[2];
        for (int e = 0; e < 2; ++e) {
          acc[e] = cv::v_setzero_s32();
          const int16_t* pr = row.data() + 4 * x0[u + e];
          const int32_t* w = wx.data() + std::size_t(u + e) * pairs_x;
          for (int j = 0; j < pairs_x; ++j) {
            const cv::v_int16x8 q = cv::v_load(pr + 8 * j);  // taps 2j, 2j+1: r g b a r g b a
            cv::v_int16x8 lo, hi;
            cv::v_zip(q, cv::v_rotate_right<4>(q), lo, hi);  // r r g g b b a a
            acc[e] += cv::v_dotprod(lo, cv::v_reinterpret_as_s16(cv::v_setall_s32(w[j])));
          }
        }
        cv::v_pack_u_store(pd + 4 * u, cv::v_rshr_pack<kOutShift>(acc[0], acc[1]));
      }
#endif
      for (; u < dst.cols; ++u) {
        const int16_t* pr = row.data() + 4 * x0[u];
        for (int ch = 0; ch < 4; ++ch) {
          int32_t acc = 0;
          for (int j = 0; j < pairs_x; ++j) {
            const int32_t w = wx[std::size_t(u) * pairs_x + j];
            acc += int32_t(int16_t(w & 0xffff)) * pr[8 * j + ch] + int32_t(int16_t(uint32_t(w) >> 16)) * pr[8 * j + 4 + ch];
          }
          pd[4 * u + ch] = uint8_t(std::min(255, std::max(0, (acc + (1 << (kOutShift - 1))) >> kOutShift)));
        }
      }
      for (u = 0; u < dst.cols; ++u)
        if (ax.count[u] == 0) pd[4 * u] = pd[4 * u + 1] = pd[4 * u + 2] = 0, pd[4 * u + 3] = 255;
    }
  }, stripes);
}
}  // namespace

Compositor::Compositor(Backend backend) : backend_(resolve_backend(backend, /*stage_has_cuda=*/true)) {
#ifdef STITCH_HAVE_CUDA
  if (backend_ == Backend::Cuda) {
    cuda_ = {new CudaComposer(), [](CudaComposer* c) { delete c; }};
    return;
  }
#endif
  warper_ = Warper::create(Backend::Cpu);
}

void Compositor::prepare(const Rig& rig, const CompositorSettings& settings, CompositorInput input) {
  if (!rig.calibrated()) throw RigError("the rig carries no calibration (homographies and canvas)");
  for (std::size_t i = 0; i < rig.cameras.size() && rig.planar(); ++i) {
    const Camera& c = rig.cameras[i];
    std::string problem = camera_homography_problem(c);  // lens-aware (issue 15)
    if (!problem.empty())
      throw RigError("camera " + std::to_string(i) + ": degenerate homography: " + problem);
  }
  geometry_ = plan_output(rig, settings.output_width, settings.output_height, settings.crop, settings.exact_output_size);
  // Seams cut multiband's masks; with the weighted mean they give the consensus blend (the
  // mean where the views agree, the seam's view where they disagree). Multiband needs no mix map.
  const bool find_seams = settings.seam != SeamMode::None;
  SeamSettings seam_settings = settings.seam_settings;
  if (settings.blend == BlendMode::Multiband) seam_settings.mix_radius = 0;
  seam_.reset();
#ifdef STITCH_HAVE_CUDA
  if (cuda_) cuda_->set_blend_mode(settings.blend, settings.bands, find_seams ? &seam_settings : nullptr);
#endif
  if (!cuda_) {
    blender_ = make_blender(Backend::Cpu, settings.blend, settings.bands);
    if (find_seams) seam_ = std::make_unique<SeamFinder>(seam_settings);
  }
  blend_mode_ = settings.blend;
  views_ = place_views(rig, geometry_);
  if (input == CompositorInput::CameraFrames) prefilter_sparse_views(views_);
  input_ = input;
  scratch_.assign(views_.size(), {});
  canvas_.clear();
  resample_ = false;
  if (input == CompositorInput::Prewarped) {
    // Fuse on the canvas, where the views were warped, then crop/scale into the output.
    blend_geometry_ = canvas_geometry(rig);
    blend_views_ = place_views(rig, blend_geometry_);
    resample_ = !(blend_geometry_.canvas_to_output.isApprox(geometry_.canvas_to_output) &&
                  blend_geometry_.width == geometry_.width && blend_geometry_.height == geometry_.height);
    if (resample_ && !cuda_)
      canvas_.resize(static_cast<std::size_t>(blend_geometry_.width) * blend_geometry_.height * 4);
  } else {
    blend_geometry_ = geometry_;
    blend_views_ = views_;
    if (warper_) {
      warper_->prepare(views_);
      for (std::size_t i = 0; i < views_.size(); ++i)
        scratch_[i].resize(static_cast<std::size_t>(views_[i].roi.width) * views_[i].roi.height * 4);
    }
  }
#ifdef STITCH_HAVE_CUDA
  if (cuda_) cuda_->prepare(blend_views_, blend_geometry_.width, blend_geometry_.height);
#endif
  if (!cuda_) blender_->prepare(blend_views_, blend_geometry_.width, blend_geometry_.height);
  if (!cuda_ && resample_) {
    // The weighted mean fuses only the canvas rows the crop/scale reads (crop=auto drops the
    // canvas' top and bottom: 18% of the 3x1080p ring's canvas).
    if (auto* weighted = dynamic_cast<BlenderCpu*>(blender_.get())) {
      const auto rows = canvas_rows_read(geometry_.canvas_to_output, {blend_geometry_.width, blend_geometry_.height},
                                         {geometry_.width, geometry_.height});
      weighted->set_rows(rows.first, rows.second);
    }
  }
  if (seam_) seam_->prepare(blend_views_, blend_geometry_.width, blend_geometry_.height);
}

void Compositor::fuse_cpu(const std::vector<ImageView>& views, const ImageView& out) {
  StageProfile profile = blend_profile();
  if (seam_ && blend_mode_ == BlendMode::Multiband) {
    static_cast<MultibandBlender&>(*blender_).set_labels(seam_->find(views).data());
    profile.mark("seams");
    blender_->fuse(views, out);
    profile.mark("multiband");
    return;
  }
  if (seam_) {  // the consensus blend: seams from the views, then the fuse with the mix in its pass
    const std::vector<uint8_t>& labels = seam_->find(views);
    profile.mark("seams");
    if (auto* weighted = dynamic_cast<BlenderCpu*>(blender_.get())) {
      std::vector<Rect> boxes;
      for (const SeamFinder::Pair& p : seam_->pairs()) boxes.push_back(p.box);
      weighted->fuse_mixed(views, out, labels, seam_->mix(), boxes);
      profile.mark("fuse + mix");
      return;
    }
    blender_->fuse(views, out);
    apply_seam_mix(blend_views_, views, labels, seam_->mix(), out);
    profile.mark("fuse, mix");
    return;
  }
  blender_->fuse(views, out);
  profile.mark("fuse");
}

void Compositor::compose_prewarped(const std::vector<ImageView>& views, const ImageView& out) {
  for (std::size_t i = 0; i < views.size(); ++i) {
    const Rect& r = blend_views_[i].roi;
    if (!views[i].empty() && (views[i].width != r.width || views[i].height != r.height))
      throw std::invalid_argument("pre-warped view " + std::to_string(i) + " is " +
                                  std::to_string(views[i].width) + "x" + std::to_string(views[i].height) +
                                  ", its canvas rectangle is " + std::to_string(r.width) + "x" +
                                  std::to_string(r.height));
  }
#ifdef STITCH_HAVE_CUDA
  if (cuda_ && !resample_) {
    cuda_->fuse(views, out);
    return;
  }
  if (cuda_) {
    const Eigen::Matrix3d& A = geometry_.canvas_to_output;
    const double affine[6] = {A(0, 0), A(0, 1), A(0, 2), A(1, 0), A(1, 1), A(1, 2)};
    cuda_->fuse_resampled(views, out, affine);
    return;
  }
#endif
  if (!resample_) {
    fuse_cpu(views, out);
    return;
  }
  ImageView canvas;
  canvas.data = canvas_.data();
  canvas.width = blend_geometry_.width;
  canvas.height = blend_geometry_.height;
  canvas.pitch = static_cast<std::size_t>(canvas.width) * 4;
  fuse_cpu(views, canvas);
  StageProfile profile = blend_profile();
  const cv::Mat src(canvas.height, canvas.width, CV_8UC4, canvas.data, canvas.pitch);
  cv::Mat dst(out.height, out.width, CV_8UC4, out.data, out.pitch);
  const Eigen::Matrix3d& A = geometry_.canvas_to_output;
  if (crop_only(A, src.size(), dst.size())) {
    // A crop (crop=auto at the canvas' scale, the default): rows copied on every core instead
    // of a bilinear pass that would sample whole pixels anyway.
    const int tx = int(std::lround(-A(0, 2))), ty = int(std::lround(-A(1, 2)));
    cv::parallel_for_(cv::Range(0, dst.rows), [&](const cv::Range& r) {
      for (int y = r.start; y < r.end; ++y)
        std::memcpy(dst.ptr(y), src.ptr(y + ty) + 4 * tx, std::size_t(dst.cols) * 4);
    });
    return;
  }
  const cv::Matx23d affine(A(0, 0), A(0, 1), A(0, 2), A(1, 0), A(1, 1), A(1, 2));
  if (A(0, 0) < 0.75 && A(1, 1) < 0.75 && A(0, 1) == 0 && A(1, 0) == 0) {
    // A strong downscale (crop=auto of an oversized canvas): area-averaged so that it does not
    // alias, straight from the canvas in one pass.
    resample_area(src, dst, A(0, 0), A(0, 2), A(1, 1), A(1, 2));
    profile.mark("resample (area)");
    return;
  }
  if (A(0, 0) < 0.75) {
    // Area-average first so that a strong downscale does not alias; then the rest of the
    // affine map (pixel centres: canvas x -> s·x + t, resized u <-> (u + 0.5)/k - 0.5).
    cv::Mat small;
    cv::resize(src, small, cv::Size(), A(0, 0), A(1, 1), cv::INTER_AREA);
    const double kx = double(small.cols) / src.cols, ky = double(small.rows) / src.rows;
    const double ax = A(0, 0) / kx, ay = A(1, 1) / ky;
    const cv::Matx23d rest(ax, 0, 0.5 * ax - 0.5 * A(0, 0) + A(0, 2), 0, ay, 0.5 * ay - 0.5 * A(1, 1) + A(1, 2));
    cv::warpAffine(small, dst, rest, dst.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0, 255));
    profile.mark("resample (area + bilinear)");
    return;
  }
  cv::warpAffine(src, dst, affine, dst.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0, 255));
  profile.mark("resample (bilinear)");
}

void Compositor::draw_debug(uint64_t present, const ImageView& out) {
  DebugScene scene;
  scene.views = views_;
  scene.label_width = blend_geometry_.width;
  scene.label_height = blend_geometry_.height;
  if (resample_) scene.label_to_output = geometry_.canvas_to_output;
  std::vector<uint8_t> seams;  // the CUDA seam finder's labels (downloaded), if it ran
#ifdef STITCH_HAVE_CUDA
  if (cuda_) seams = cuda_->seam_labels();
#endif
  if (seam_) {
    scene.labels = seam_->labels().data();
  } else if (!seams.empty()) {
    scene.labels = seams.data();
  } else {
    // The weighted mean's weights, and multiband's default masks, meet where the nearest view changes.
    if (present != debug_labels_mask_) {
      debug_labels_ = nearest_view_labels(blend_views_, blend_geometry_.width, blend_geometry_.height, present);
      debug_labels_mask_ = present;
    }
    scene.labels = debug_labels_.data();
  }
  scene.flow = flow_stats_;
  scene.canvas_to_output = geometry_.canvas_to_output;
  auto draw = [&](const ImageView& host) { draw_debug_view(host, debug_, scene); };
#ifdef STITCH_HAVE_CUDA
  if (cuda_) {
    cuda_->draw_on_host(out, draw);
    return;
  }
#endif
  draw(out);
}

void Compositor::compose(const std::vector<ImageView>& frames, const ImageView& out) {
  if (!prepared()) throw std::logic_error("compose() before prepare()");
  if (frames.size() != views_.size())
    throw std::invalid_argument("got " + std::to_string(frames.size()) + " frames for " +
                                std::to_string(views_.size()) + " cameras");
  compose_views(frames, out);
  if (!debug_) return;
  uint64_t present = 0;
  for (std::size_t i = 0; i < frames.size(); ++i)
    if (!frames[i].empty()) present |= uint64_t(1) << i;
  draw_debug(present, out);
}

void Compositor::compose_views(const std::vector<ImageView>& camera_frames, const ImageView& out) {
  if (input_ == CompositorInput::Prewarped) {
    compose_prewarped(camera_frames, out);
    return;
  }
  StageProfile profile = blend_profile();
  check_frame_sizes(views_, camera_frames);
  // Sparsely sampled views read a reduced copy (prefilter_sparse_views); CUDA reduces on the device.
  const std::vector<ImageView>& frames = cuda_ ? camera_frames : reducer_.reduce(views_, camera_frames);
  std::vector<ImageView> warped(frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i) {
    if (cuda_) continue;
    const ViewPlacement& v = views_[i];
    if (frames[i].empty() || v.roi.empty()) continue;
    ImageView dst;
    dst.data = scratch_[i].data();
    dst.width = v.roi.width;
    dst.height = v.roi.height;
    dst.pitch = static_cast<std::size_t>(v.roi.width) * 4;
    warped[i] = dst;
  }
  if (!cuda_) {
    // Every view's bands of rows warped in one parallel loop (one wait for the threads, not one
    // per view); a band's pixels are the ones the whole view's warp gives (WarperCpu::warp_part).
    auto* cpu = dynamic_cast<WarperCpu*>(warper_.get());
    constexpr int kBand = BlenderCpu::kCoreBand;
    std::vector<int> bands(frames.size(), 0);  // per view
    int all_bands = 0;
    for (std::size_t i = 0; i < frames.size(); ++i)
      all_bands += bands[i] = warped[i].empty() ? 0 : (warped[i].height + kBand - 1) / kBand;
    // With the weighted mean (and the consensus blend), the part of a band where the view has the
    // whole weight on every row is warped straight into the output (its core): the fuse would
    // only copy it there from the view's rectangle. Never within 2 px of a seam pair's box, whose
    // pixels (and their neighbours, for the gradients) the seams and the mix read from the views.
    auto* weighted = dynamic_cast<BlenderCpu*>(blender_.get());
    BlenderCpu::Cores cores(frames.size());
    if (cpu && weighted && out.width == blend_geometry_.width && out.height == blend_geometry_.height) {
      uint64_t mask = 0;
      for (std::size_t i = 0; i < frames.size(); ++i)
        if (!warped[i].empty()) mask |= uint64_t(1) << i;
      const std::vector<std::vector<BlenderCpu::Span>>& spans = weighted->spans_for(mask);
      std::vector<Rect> keep_out;
      if (seam_)
        for (const SeamFinder::Pair& p : seam_->pairs())
          keep_out.push_back({p.box.x - 2, p.box.y - 2, p.box.width + 4, p.box.height + 4});
      for (std::size_t i = 0; i < frames.size(); ++i) {
        if (warped[i].empty()) continue;
        const Rect& r = views_[i].roi;
        cores[i].assign(std::size_t((r.height + kBand - 1) / kBand), {0, 0});
        for (std::size_t t = 0; t < cores[i].size(); ++t) {
          const int y0 = r.y + int(t) * kBand, y1 = std::min(r.y + r.height, y0 + kBand);
          int lo = r.x, hi = r.x + r.width;  // what every row of the band has of this view alone
          for (int y = y0; y < y1 && hi > lo; ++y) {
            if (y < 0 || y >= out.height) {
              hi = lo;
              break;
            }
            int best0 = 0, best1 = 0;  // the row's longest run of this view alone
            for (const BlenderCpu::Span& sp : spans[std::size_t(y)])
              if (sp.view == int(i) && sp.x1 - sp.x0 > best1 - best0) best0 = sp.x0, best1 = sp.x1;
            lo = std::max(lo, best0);
            hi = std::min(hi, best1);
          }
          for (const Rect& g : keep_out) {
            if (hi <= lo || g.y >= y1 || g.y + g.height <= y0 || g.x >= hi || g.x + g.width <= lo) continue;
            const int left = g.x - lo, right = hi - (g.x + g.width);  // keep the longer side
            if (left >= right) hi = std::max(lo, g.x);
            else lo = std::min(hi, g.x + g.width);
          }
          if (hi > lo) cores[i][t] = {lo, hi};
        }
      }
    }
    if (cpu && all_bands > 0) {
      parallel_for_parts(bands, [&](std::size_t i, int band) {
        const int y0 = band * kBand, rows = std::min(kBand, warped[i].height - y0);
        const int w = warped[i].width;
        const Rect& r = views_[i].roi;
        const std::pair<int, int> core = cores[i].empty() ? std::make_pair(0, 0) : cores[i][std::size_t(band)];
        if (core.second <= core.first) {
          cpu->warp_part(int(i), frames[i], warped[i], {0, y0, w, rows});
          return;
        }
        const int a = core.first - r.x, b = core.second - r.x;  // roi columns of the core
        if (a > 0) cpu->warp_part(int(i), frames[i], warped[i], {0, y0, a, rows});
        if (b < w) cpu->warp_part(int(i), frames[i], warped[i], {b, y0, w - b, rows});
        uint8_t* o = out.row(r.y + y0) + 4 * std::size_t(core.first);
        cpu->warp_part_to(int(i), frames[i], {a, y0, b - a, rows}, o, out.pitch);
        for (int y = 0; y < rows; ++y) {  // the panorama is opaque
          uint8_t* p = o + std::size_t(y) * out.pitch;
          for (int x = 0; x < b - a; ++x) p[4 * x + 3] = 255;
        }
      }, double(all_bands));
      if (weighted) weighted->set_cores(std::move(cores));
    } else {
      for (std::size_t i = 0; i < frames.size(); ++i)
        if (!warped[i].empty()) warper_->warp(static_cast<int>(i), frames[i], warped[i]);
    }
  }
#ifdef STITCH_HAVE_CUDA
  if (cuda_) {
    cuda_->compose(frames, out);
    return;
  }
#endif
  profile.mark("warp");
  fuse_cpu(warped, out);
  if (auto* weighted = dynamic_cast<BlenderCpu*>(blender_.get())) weighted->set_cores({});
}

}  // namespace stitch
