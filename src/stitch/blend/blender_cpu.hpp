#pragma once
#include <algorithm>
#include <map>
#include <opencv2/core.hpp>

#include "stitch/blend/blender.hpp"

namespace stitch {

// position_weight() of every pixel of the view's roi (CV_32F, roi-sized; empty for an empty roi).
cv::Mat position_weight_map(const ViewPlacement& view);

// A view (RGBA, alpha = coverage) as the multiband blender reads it: its colours where it has
// content, filled where it has none from its own content, coarse to fine (pull-push), so that
// its coarse bands carry no black into its neighbours'. CV_32FC4 (rgb, coverage), view-sized.
// `bands`: the blender's (effective) levels.
cv::Mat multiband_filled_view(const ImageView& view, int bands);

class BlenderCpu final : public Blender {
 public:
  static constexpr int kWeightBits = 14;  // weights are Q14 and sum to exactly 1 << 14

  void prepare(const std::vector<ViewPlacement>& views, int out_width, int out_height) override;
  void fuse(const std::vector<ImageView>& warped, const ImageView& out) override;
  // fuse() and then the consensus blend's mix (apply_seam_mix: each pixel with mix > 0 moved
  // towards its label's view) in the same pass over the output, row by row while the row is in
  // cache: the same bytes as fuse() followed by apply_seam_mix(). `mix` must be 0 outside
  // `regions` (the seam finder's pair boxes; only they are read).
  void fuse_mixed(const std::vector<ImageView>& warped, const ImageView& out, const std::vector<uint8_t>& labels,
                  const std::vector<uint8_t>& mix, const std::vector<Rect>& regions);
  Backend backend() const override { return Backend::Cpu; }

  // Normalised Q14 weights of each view (roi-sized, CV_16U) for a set of present views.
  const std::vector<cv::Mat>& weights_for(uint64_t present_mask);
  // Per output row, runs of pixels by what the fuse does there: one view has the whole weight
  // (view >= 0: the pixel is that view's, copied), several views share it (kMixed: the weighted
  // sum), or none covers it (kUncovered: opaque black). Per set of present views, like the weights.
  struct Span {
    int x0, x1, view;
  };
  static constexpr int kMixed = -1, kUncovered = -2;
  const std::vector<std::vector<Span>>& spans_for(uint64_t present_mask);
  // Cores: per view and band of kCoreBand rows of its roi, output columns [first, second) whose
  // pixels the caller has already written into the output (the view's own warp, alpha 255,
  // where the view has the whole weight on every row of the band). The next fuse() leaves them
  // as they are; cleared by prepare() and by set_cores({}).
  static constexpr int kCoreBand = 32;
  using Cores = std::vector<std::vector<std::pair<int, int>>>;
  void set_cores(Cores cores) { cores_ = std::move(cores); }
  // Only output rows [first, end) are fused from now on (the rest left as they are): a canvas
  // that is cropped/scaled afterwards needs only the rows the output reads. prepare() resets it
  // to every row.
  void set_rows(int first, int end) {
    row_first_ = std::clamp(first, 0, out_h_);
    row_end_ = std::clamp(end, row_first_, out_h_);
  }

 private:
  std::vector<ViewPlacement> views_;
  std::vector<cv::Mat> raw_;  // CV_32F, roi-sized
  int out_w_ = 0, out_h_ = 0;
  int row_first_ = 0, row_end_ = 0;
  std::map<uint64_t, std::vector<cv::Mat>> normalised_;
  std::map<uint64_t, std::vector<std::vector<Span>>> spans_;
  Cores cores_;
  void fuse_rows(const std::vector<ImageView>& warped, const ImageView& out, const std::vector<uint8_t>* labels,
                 const std::vector<uint8_t>* mix, const std::vector<Rect>* regions);
};

}  // namespace stitch
