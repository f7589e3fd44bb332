// Spatio-temporal color correction (paper §2): per-view 3x3 color transfer estimated on the
// overlaps (2D-M, 3D-M) or Brown-Lowe gains, chained outward from the reference camera, and
// online piecewise balancing (eq. 5-7). Corrections are applied to whole views, in place.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <deque>
#include <memory>
#include <vector>

#include "stitch/backend.hpp"
#include "stitch/image.hpp"
#include "stitch/rig/rig.hpp"

namespace stitch {

enum class ColorMethod {
  None,      // no transfer (balance may still run)
  Matrix2D,  // Tian's 2D-M: least squares over the current frame's overlap
  Matrix3D,  // the paper's 3D-M: the same over the current and previous frames (eq. 2-4)
  Gain,      // Brown-Lowe per-channel gains solved jointly over all overlaps, smoothed in time
};

// What the transfer is fitted against (paper Step 3).
enum class ColorPairing {
  Histogram,  // view i's overlap histogram-specified to view j's: robust to misalignment
  Pixels,     // the co-located pixels of view j under the calibration: recovers cross-channel
              // mixing exactly where the overlap is well aligned
};

struct ColorOptions {
  ColorMethod method = ColorMethod::Matrix3D;
  ColorPairing pairing = ColorPairing::Histogram;
  int window = 3;             // frames in the 3-D fit / gain smoothing
  bool balance = false;       // online piecewise balancing (eq. 5-7)
  double lambda = 0.05;       // balance thresholds at lambda and 1 - lambda of the histogram
  int min_samples = 300;      // fewer valid overlap pixels: keep the last correction
  double max_step = 0.05;     // largest change of a correction per frame (Frobenius norm)
  double deadband = 0.0;      // changes smaller than this are noise: the correction holds still
  double follow = 1.0;        // fraction of the way to the new estimate taken per frame
                              // (1 = the paper; stitchcolor's smoothing = 1 - follow)
  double ridge = 1e-3;        // Tikhonov weight (relative to trace) pulling M toward identity
  int dark_level = 8;         // pixels with every channel <= this are left out of fits
  int bright_level = 250;     // pixels with any channel >= this are left out of fits
  int max_samples_per_pair = 16384;
};

// Paired overlap samples of one view pair: RGB rows of view a and of view b.
struct OverlapSamples {
  int a = -1, b = -1;
  std::vector<std::array<uint8_t, 3>> va, vb;
};

// The per-frame pixel work, one implementation per backend.
class ColorOps {
 public:
  virtual ~ColorOps() = default;
  // Reads the pixels at the given integer coordinates (x, y pairs) of a view.
  virtual void gather(const ImageView& view, const std::vector<int32_t>& xy,
                      std::vector<std::array<uint8_t, 3>>& out) = 0;
  // out = clamp(lut[c](round(sum_k in_k * M(k, c)))) per pixel, alpha untouched. In place.
  virtual void apply(const ImageView& view, const Eigen::Matrix3d& M,
                     const std::array<std::array<uint8_t, 256>, 3>& lut) = 0;
  virtual Backend backend() const = 0;
  static std::unique_ptr<ColorOps> create(Backend backend);
};

// Histogram specification (Step 3): the lookup that gives `src` the histogram of `ref`.
std::array<uint8_t, 256> histogram_specification(const std::array<uint32_t, 256>& src,
                                                 const std::array<uint32_t, 256>& ref);

// The piecewise balancing curve (eq. 5): gamma below m1, linear between m1 and m2, gamma above
// m2. The linear part stretches [m1, m2] to [lambda, 1 - lambda] of the range, the gammas meet it
// with the same slope; the curve is continuous and monotonic. m2 <= m1 gives the identity.
std::array<uint8_t, 256> piecewise_balance_curve(double m1, double m2, double lambda);
// The same curve evaluated at any x in [0, 255] (the LUT samples it at integers).
double piecewise_balance_value(double x, double m1, double m2, double lambda);

class ColorCorrector {
 public:
  explicit ColorCorrector(Backend backend = Backend::Auto);
  void set_options(const ColorOptions& options);  // a new method or window resets the history
  const ColorOptions& options() const { return options_; }
  // Forgets every temporal state (flush, seek, caps change).
  void reset();
  // Estimates this frame's corrections on the overlaps and applies them to every view in
  // place. Empty views (missing cameras) are skipped and keep their last correction.
  void process(const Rig& rig, uint64_t rig_version, const std::vector<ImageView>& views);

  const std::vector<Eigen::Matrix3d>& corrections() const { return current_; }
  const std::array<std::array<uint8_t, 256>, 3>& balance_lut() const { return lut_; }

 private:
  struct PairHistory {
    std::deque<Eigen::Matrix3d> AtA, AtB;  // normal equations per frame, newest last
  };
  void prepare_geometry(const Rig& rig);
  void estimate_matrices(const std::vector<ImageView>& views);
  void estimate_gains(const std::vector<ImageView>& views);
  void update_balance(const std::vector<ImageView>& views);
  Eigen::Matrix3d limited_update(const Eigen::Matrix3d& previous, const Eigen::Matrix3d& wanted,
                                 bool first) const;

  std::unique_ptr<ColorOps> ops_;
  ColorOptions options_;
  uint64_t rig_version_ = ~uint64_t(0);
  int reference_ = 0;
  std::vector<std::pair<int, int>> tree_;  // (view, parent) outward from the reference
  struct PairGeometry {
    int a, b;
    std::vector<int32_t> xy_a, xy_b;
  };
  std::vector<PairGeometry> pairs_;        // every overlapping pair
  std::vector<std::vector<int32_t>> balance_xy_;  // per view: sparse grid for the histogram
  std::vector<PairHistory> history_;       // per tree edge
  std::vector<Eigen::Matrix3d> current_;
  std::vector<bool> has_current_;
  std::vector<Eigen::Vector3d> gains_;
  std::deque<std::array<double, 6>> thresholds_;  // (m1, m2) per channel, last 3 frames
  std::array<std::array<uint8_t, 256>, 3> lut_{};
};

}  // namespace stitch
