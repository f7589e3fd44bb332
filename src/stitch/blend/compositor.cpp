#include "stitch/blend/compositor.hpp"

#include <stdexcept>

namespace stitch {

Compositor::Compositor(Backend backend)
    : warper_(Warper::create(backend)), blender_(Blender::create(backend)) {}

void Compositor::prepare(const Rig& rig, const CompositorSettings& settings) {
  if (!rig.calibrated()) throw RigError("the rig carries no calibration (homographies and canvas)");
  for (std::size_t i = 0; i < rig.cameras.size(); ++i) {
    const Camera& c = rig.cameras[i];
    std::string problem = homography_problem(*c.homography, c.width, c.height);
    if (!problem.empty())
      throw RigError("camera " + std::to_string(i) + ": degenerate homography: " + problem);
  }
  geometry_ = plan_output(rig, settings.output_width, settings.output_height, settings.crop);
  views_ = place_views(rig, geometry_);
  warper_->prepare(views_);
  blender_->prepare(views_, geometry_.width, geometry_.height);
  scratch_.assign(views_.size(), {});
  for (std::size_t i = 0; i < views_.size(); ++i)
    scratch_[i].resize(static_cast<std::size_t>(views_[i].roi.width) * views_[i].roi.height * 4);
}

void Compositor::compose(const std::vector<ImageView>& frames, const ImageView& out) {
  if (!prepared()) throw std::logic_error("compose() before prepare()");
  if (frames.size() != views_.size())
    throw std::invalid_argument("got " + std::to_string(frames.size()) + " frames for " +
                                std::to_string(views_.size()) + " cameras");
  std::vector<ImageView> warped(frames.size());
  for (std::size_t i = 0; i < frames.size(); ++i) {
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
  blender_->fuse(warped, out);
}

}  // namespace stitch
