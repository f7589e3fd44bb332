// Estimate once, compose every frame: the rig's geometry is turned into warp maps and
// blend weights once (prepare), then each bundle of camera frames becomes one panorama.
#pragma once

#include <memory>
#include <vector>

#include "stitch/blend/blender.hpp"
#include "stitch/blend/compositor_cuda.hpp"
#include "stitch/blend/debug_view.hpp"
#include "stitch/blend/multiband.hpp"
#include "stitch/blend/seam.hpp"
#include "stitch/rig/rig.hpp"
#include "stitch/warp/geometry.hpp"
#include "stitch/warp/warper.hpp"

namespace stitch {

// What compose() receives: the cameras' frames (warped here by the homographies), or views
// that stitchflowwarp already warped into their rectangles of canvas_geometry(rig).
enum class CompositorInput { CameraFrames, Prewarped };

struct CompositorSettings {
  int output_width = 0;   // 0: from the canvas / crop
  int output_height = 0;
  bool exact_output_size = false;  // both set: made as they are, odd or not (a size downstream fixed);
                                   // otherwise rounded to even sizes for 4:2:0 encoders
  CropMode crop = CropMode::None;
  Backend backend = Backend::Auto;
  BlendMode blend = BlendMode::Weighted;
  int bands = MultibandBlender::kDefaultBands;  // multiband only
  SeamMode seam = SeamMode::None;                // multiband: where each view's mask ends; weighted:
                                                 // the consensus blend (SeamSettings mix_*)
  SeamSettings seam_settings;
};

class Compositor {
 public:
  // Auto: CUDA when a device opens (frames may then be in system or device memory), else CPU.
  explicit Compositor(Backend backend = Backend::Auto);
  Backend backend() const { return backend_; }
  // Throws RigError when the rig is not calibrated or its geometry is degenerate.
  void prepare(const Rig& rig, const CompositorSettings& settings,
               CompositorInput input = CompositorInput::CameraFrames);
  CompositorInput input() const { return input_; }
  bool prepared() const { return geometry_.width > 0; }
  const OutputGeometry& geometry() const { return geometry_; }
  const std::vector<ViewPlacement>& placements() const { return views_; }

  // Where the views must lie for CompositorInput::Prewarped (the canvas, 1:1).
  const std::vector<ViewPlacement>& prewarped_placements() const { return blend_views_; }

  // DebugFlags to draw onto every panorama from now on (0: none), and the flow statistics of
  // the frame about to be composed (stitchflowwarp's) for kDebugFlow.
  void set_debug(unsigned flags) { debug_ = flags; }
  void set_flow_stats(std::vector<FlowPairStats> stats) { flow_stats_ = std::move(stats); }

  // frames[i] is camera i's frame, or its pre-warped view (empty view = camera missing).
  // `out` is output-sized.
  void compose(const std::vector<ImageView>& frames, const ImageView& out);

 private:
  void compose_prewarped(const std::vector<ImageView>& views, const ImageView& out);
  void fuse_cpu(const std::vector<ImageView>& views, const ImageView& out);  // seams, then the blender
  void compose_views(const std::vector<ImageView>& frames, const ImageView& out);
  void draw_debug(uint64_t present, const ImageView& out);

  Backend backend_ = Backend::Cpu;
  std::unique_ptr<Warper> warper_;    // CPU path
  std::unique_ptr<Blender> blender_;  // CPU path: the weighted mean or multiband
  std::unique_ptr<SeamFinder> seam_;  // CPU path: seam finding (multiband masks, or the consensus blend)
  BlendMode blend_mode_ = BlendMode::Weighted;
  // CUDA path; the deleter is set where it is created, so CPU-only builds need no CUDA code.
  std::unique_ptr<CudaComposer, void (*)(CudaComposer*)> cuda_{nullptr, nullptr};
  OutputGeometry geometry_;
  std::vector<ViewPlacement> views_;
  CompositorInput input_ = CompositorInput::CameraFrames;
  std::vector<ViewPlacement> blend_views_;     // where the blender finds each view
  OutputGeometry blend_geometry_;              // what the blender fills: output, or canvas
  std::vector<std::vector<uint8_t>> scratch_;  // warped rectangles, reused every frame
  FrameReducer reducer_;  // the frames of views with a level (prefilter_sparse_views), CPU
  bool resample_ = false;                      // pre-warped input: the output crops/scales the canvas
  std::vector<uint8_t> canvas_;                // CPU path: the canvas fused before crop/scale
  unsigned debug_ = 0;
  std::vector<FlowPairStats> flow_stats_;
  uint64_t debug_labels_mask_ = ~uint64_t(0);  // the present views debug_labels_ are for
  std::vector<uint8_t> debug_labels_;          // nearest-view labels on the blend grid
};

}  // namespace stitch
