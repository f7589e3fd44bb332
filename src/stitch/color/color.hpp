// Spatio-temporal color correction (paper §2): per-view 3x3 color transfer estimated on the
// overlaps (2D-M, 3D-M) or Brown-Lowe gains, chained outward from the reference camera, and
// online piecewise balancing (eq. 5-7). Corrections are applied to whole views, in place.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
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
  // Robust statistics (issue 16): fit only samples that are static and well aligned.
  bool static_mask = true;    // leave out moving and badly aligned overlap samples
  int motion_threshold = 12;  // a channel changing more than this since the last frame: moving
  int static_frames = 10;     // frames a sample must stay still before it is used again
  int align_tolerance = 12;   // |grad_a - grad_b| above this + max/3 (luma, L1): misaligned
  // Stabilisation over time (stitchEm-style sampled exposure/WB stabilisation).
  bool stabilize = true;      // hold the applied correction; re-key only on a lasting change
  double hold = 2.0;          // grey levels the wanted correction may differ from the held one
  int keyframe = 8;           // frames a difference beyond `hold` must last before a new keyframe
  double max_rate = 1.0;      // grey levels the applied correction moves per frame toward a keyframe
  // Clipped highlights (issue 16): their true colour is unknown, and a gain below 1 turns a
  // clipped white grey and makes it follow every change of the correction. Above this level
  // (brightest channel) the correction fades out, reaching none at 255. 255: off.
  int highlight_knee = 235;
  double step_threshold = 0.12;  // relative brightness change seen by every view at once: a
                                 // global illumination step (or cut): the correction jumps
};

// Where the color statistics are read, fixed per rig geometry (a backend uploads it once).
struct ColorSampling {
  // One overlapping view pair: sample k is pixel (xy_a[2k], xy_a[2k+1]) of view a and
  // (xy_b[2k], xy_b[2k+1]) of view b, the same canvas point.
  struct Pair {
    int a = -1, b = -1;
    std::vector<int32_t> xy_a, xy_b;
    int count() const { return int(xy_a.size() / 2); }
  };
  std::vector<Pair> pairs;
  std::vector<std::vector<int32_t>> balance_xy;  // per view: (x, y) of the sparse balance grid
};

// Every overlapping pair of a calibrated rig with up to ~max_samples_per_pair canvas points
// inside both views, and a ~4096-point grid per view for the balance histogram.
ColorSampling make_color_sampling(const Rig& rig, int max_samples_per_pair);

using ChannelHistograms = std::array<std::array<uint32_t, 256>, 3>;
// Sum over samples of x_r * y_c in 8-bit RGB units, row-major (r, c): integers, so every
// backend and every summation order gives the same value.
using Moments3 = std::array<uint64_t, 9>;

// Which side of a pair is histogram-specified onto the other (pairing=histogram).
enum class HistogramMatch : uint8_t { None, AOntoB, BOntoA };

// What one frame's reductions are asked for.
struct ColorReductionRequest {
  bool pairs = false;                  // per pair: count, histograms, moments
  std::vector<HistogramMatch> match;   // per pair (missing entries: None); needs `pairs`
  bool balance = false;                // per view: histograms of the balance grid ...
  std::vector<Eigen::Matrix3d> balance_matrices;  // ... of pixel * M, rounded and clamped
  int dark_level = 8, bright_level = 250;  // a sample is usable unless dark or bright on either side
  // Static/aligned mask (pairs only). The per-sample motion state lives in the ColorOps and is
  // advanced by every reduce() that asks for pairs.
  bool static_mask = false;
  int motion_threshold = 12, static_frames = 10, align_tolerance = 12;
};

// One pair's statistics over its usable samples (both pixels inside their views, neither
// all-dark nor with a saturated channel). All zero when a view of the pair is empty.
struct PairStats {
  uint64_t count = 0;
  ChannelHistograms hist_a{}, hist_b{};
  Moments3 aa{}, bb{}, ab{};  // sum a a^T, sum b b^T, sum a b^T
  // Sum s lut(s)^T for the matched side s, lut = histogram_specification of s's histogram
  // onto the other side's, per channel. Zero when not asked for.
  Moments3 matched{};
  // The mask (issue 16). Counted over samples inside both views, before any other test.
  uint64_t inview = 0;      // samples inside both views
  uint64_t moving = 0;      // ... that moved within the last static_frames frames
  uint64_t misaligned = 0;  // ... whose two views' gradients disagree
  uint64_t global_change = 0;  // 1: most samples moved at once (exposure step, cut): state restarted
  std::array<uint64_t, 3> sum_a{}, sum_b{};  // raw RGB sums over the in-view samples
};

// The per-sample motion and alignment test shared by the CPU and the CUDA kernels (same
// integers, same result). Luma in 8-bit integer arithmetic.
inline int mask_luma(const uint8_t* p) { return (77 * p[0] + 150 * p[1] + 29 * p[2] + 128) >> 8; }
inline bool mask_moved(const uint8_t* now, const uint8_t* before, int threshold) {
  for (int c = 0; c < 3; ++c)
    if (std::abs(int(now[c]) - int(before[c])) > threshold) return true;
  return false;
}
// The highlight roll-off (CPU and CUDA): the corrected level t of a channel whose input
// pixel's brightest channel is m and own level p, with the knee k < m.
inline uint8_t highlight_blend(int t, int p, int m, int k) {
  const float w = float(m - k) / float(255 - k);
  return uint8_t(float(t) + w * float(p - t) + 0.5f);
}
inline bool mask_aligned(int grad_a, int grad_b, int tolerance) {
  return std::abs(grad_a - grad_b) <= tolerance + std::max(grad_a, grad_b) / 3;
}

struct ColorStats {
  std::vector<PairStats> pairs;             // per sampling pair (zero unless asked for)
  std::vector<ChannelHistograms> balance;   // per view (zero for empty views, unless asked for)
};

// The level of channel c of pixel rgb after the 3x3 M: clamp(round(sum_k rgb_k M(k, c))), the
// bin of the balance histogram. The CUDA kernel evaluates the same expression in the same
// order, without fused multiply-adds.
inline int corrected_level(const uint8_t* rgb, const Eigen::Matrix3d& M, int c) {
  const double v = (double(rgb[0]) * M(0, c) + double(rgb[1]) * M(1, c)) + double(rgb[2]) * M(2, c);
  return int(std::clamp(std::lround(v), 0L, 255L));
}

// The per-frame pixel work, one implementation per backend.
class ColorOps {
 public:
  virtual ~ColorOps() = default;
  // Takes the sample positions of a new geometry (the CUDA backend keeps them on the device).
  virtual void set_sampling(const ColorSampling& sampling) = 0;
  // This frame's statistics at the sampling's positions (see ColorReductionRequest). The CUDA
  // backend returns them with one stream synchronisation.
  virtual void reduce(const std::vector<ImageView>& views, const ColorReductionRequest& request,
                      ColorStats& out) = 0;
  // Every non-empty view in place: out = clamp(lut[c](round(sum_k in_k * M_i(k, c)))), alpha
  // untouched. The CUDA backend runs one launch for all views and returns once they are done.
  // highlight_knee < 255: a pixel whose brightest channel is above the knee keeps a growing
  // share of its input (all of it at 255): clipped highlights stay white and still.
  virtual void apply_all(const std::vector<ImageView>& views, const std::vector<Eigen::Matrix3d>& matrices,
                         const std::array<std::array<uint8_t, 256>, 3>& lut, int highlight_knee = 255) = 0;
  // One view: apply_all of a single view.
  void apply(const ImageView& view, const Eigen::Matrix3d& M, const std::array<std::array<uint8_t, 256>, 3>& lut) {
    apply_all({view}, {M}, lut);
  }
  // Reads the pixels at the given integer coordinates (x, y pairs) of a view (tests, tools).
  virtual void gather(const ImageView& view, const std::vector<int32_t>& xy,
                      std::vector<std::array<uint8_t, 3>>& out) = 0;
  // Forgets the per-sample motion state: the next frame's samples count as static.
  virtual void reset_motion() = 0;
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
  // What the last frame did (bus messages, tests).
  struct FrameReport {
    bool step = false;        // a global illumination step or cut was detected
    bool rekeyed = false;     // a view got a new keyframe (its applied correction moves)
    double static_fraction = 1;  // usable samples after the mask / in-view samples, all pairs
    int frames_since_step = 0;
  };
  const FrameReport& report() const { return report_; }
  const std::vector<Eigen::Matrix3d>& wanted() const { return wanted_; }

 private:
  struct PairHistory {
    std::deque<Eigen::Matrix3d> AtA, AtB;  // normal equations per frame, newest last
  };
  // A view fitted to its parent in the chain, and the sampling pair they share.
  struct ChainEdge {
    int view, parent, pair;
    bool view_is_a;
  };
  void prepare_geometry(const Rig& rig);
  void estimate_matrices(const std::vector<ImageView>& views);
  void estimate_gains(const std::vector<ImageView>& views);
  void update_balance(const std::vector<ImageView>& views);
  Eigen::Matrix3d limited_update(const Eigen::Matrix3d& previous, const Eigen::Matrix3d& wanted,
                                 bool first) const;
  bool detect_step(const std::vector<ImageView>& views);
  void stabilize(const std::vector<ImageView>& views, const std::vector<bool>& was_established);
  double effect_levels(int view, const Eigen::Matrix3d& d) const;

  std::unique_ptr<ColorOps> ops_;
  ColorOptions options_;
  uint64_t rig_version_ = ~uint64_t(0);
  int reference_ = 0;
  ColorSampling sampling_;
  std::vector<ChainEdge> chain_;           // outward from the reference
  std::vector<PairHistory> history_;       // per chain edge
  ColorReductionRequest request_;          // reused every frame
  ColorStats stats_;                       // this frame's reductions
  std::vector<Eigen::Matrix3d> current_;   // applied (held) corrections
  std::vector<Eigen::Matrix3d> wanted_;    // this frame's smoothed estimates
  std::vector<Eigen::Matrix3d> key_;       // the keyframe each applied correction moves toward
  std::vector<Eigen::Matrix3d> last_wanted_;
  std::vector<int> over_;                  // frames the wanted has been beyond `hold`
  std::vector<int> follow_;                // 0 hold, 1 ramp to a keyframe, 2 follow (camera step)
  std::vector<bool> step_view_;            // this frame: the view's camera stepped
  std::vector<Eigen::Vector3d> probe_;     // mean overlap colour per view (levels)
  std::vector<Eigen::Vector3d> last_rgb_;  // per view: mean raw colour of its overlaps last frame
  std::vector<bool> has_current_;
  FrameReport report_;
  std::vector<Eigen::Vector3d> gains_;
  std::deque<std::array<double, 6>> thresholds_;  // (m1, m2) per channel, last 3 frames
  std::array<std::array<uint8_t, 256>, 3> lut_{};
};

}  // namespace stitch
