#include "stitch/blend/compositor.hpp"

#include <cmath>
#include <cstring>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

namespace stitch {

namespace {
// True when output = canvas shifted by whole pixels and inside it: the crop/scale pass is a copy.
bool crop_only(const Eigen::Matrix3d& A, const cv::Size& canvas, const cv::Size& out) {
  auto whole = [](double v) { return std::abs(v - std::round(v)) < 1e-9; };
  if (std::abs(A(0, 0) - 1) > 1e-12 || std::abs(A(1, 1) - 1) > 1e-12 || std::abs(A(0, 1)) > 1e-12 ||
      std::abs(A(1, 0)) > 1e-12 || !whole(A(0, 2)) || !whole(A(1, 2)))
    return false;
  const long tx = std::lround(-A(0, 2)), ty = std::lround(-A(1, 2));
  return tx >= 0 && ty >= 0 && tx + out.width <= canvas.width && ty + out.height <= canvas.height;
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
  geometry_ = plan_output(rig, settings.output_width, settings.output_height, settings.crop);
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
  if (seam_) seam_->prepare(blend_views_, blend_geometry_.width, blend_geometry_.height);
}

void Compositor::fuse_cpu(const std::vector<ImageView>& views, const ImageView& out) {
  if (seam_ && blend_mode_ == BlendMode::Multiband) {
    static_cast<MultibandBlender&>(*blender_).set_labels(seam_->find(views).data());
    blender_->fuse(views, out);
    return;
  }
  blender_->fuse(views, out);
  if (seam_) {  // the consensus blend
    const std::vector<uint8_t>& labels = seam_->find(views);
    apply_seam_mix(blend_views_, views, labels, seam_->mix(), out);
  }
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
  if (A(0, 0) < 0.75) {
    // Area-average first so that a strong downscale does not alias; then the rest of the
    // affine map (pixel centres: canvas x -> s·x + t, resized u <-> (u + 0.5)/k - 0.5).
    cv::Mat small;
    cv::resize(src, small, cv::Size(), A(0, 0), A(1, 1), cv::INTER_AREA);
    const double kx = double(small.cols) / src.cols, ky = double(small.rows) / src.rows;
    const double ax = A(0, 0) / kx, ay = A(1, 1) / ky;
    const cv::Matx23d rest(ax, 0, 0.5 * ax - 0.5 * A(0, 0) + A(0, 2), 0, ay, 0.5 * ay - 0.5 * A(1, 1) + A(1, 2));
    cv::warpAffine(small, dst, rest, dst.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0, 255));
    return;
  }
  cv::warpAffine(src, dst, affine, dst.size(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0, 255));
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

void Compositor::compose_views(const std::vector<ImageView>& frames, const ImageView& out) {
  if (input_ == CompositorInput::Prewarped) {
    compose_prewarped(frames, out);
    return;
  }
  std::vector<ImageView> warped(frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i) {
    if (cuda_ && !frames[i].empty() &&
        (frames[i].width != views_[i].camera_width || frames[i].height != views_[i].camera_height))
      throw std::invalid_argument("frame " + std::to_string(i) + " is " + std::to_string(frames[i].width) + "x" +
                                  std::to_string(frames[i].height) + ", the rig expects " +
                                  std::to_string(views_[i].camera_width) + "x" +
                                  std::to_string(views_[i].camera_height));
    if (cuda_) continue;
    const ViewPlacement& v = views_[i];
    if (frames[i].empty() || v.roi.empty()) continue;
    if (frames[i].width != v.camera_width || frames[i].height != v.camera_height)
      throw std::invalid_argument("frame " + std::to_string(i) + " is " +
                                  std::to_string(frames[i].width) + "x" +
                                  std::to_string(frames[i].height) + ", the rig expects " +
                                  std::to_string(v.camera_width) + "x" +
                                  std::to_string(v.camera_height));
    ImageView dst;
    dst.data = scratch_[i].data();
    dst.width = v.roi.width;
    dst.height = v.roi.height;
    dst.pitch = static_cast<std::size_t>(v.roi.width) * 4;
    warper_->warp(static_cast<int>(i), frames[i], dst);
    warped[i] = dst;
  }
#ifdef STITCH_HAVE_CUDA
  if (cuda_) {
    cuda_->compose(frames, out);
    return;
  }
#endif
  fuse_cpu(warped, out);
}

}  // namespace stitch
