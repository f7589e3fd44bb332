// Photometric correspondences for lens estimation (issue 15). SIFT places a keypoint to about
// 0.25 px on small frames and finds only ~150 matches in a 320x240 overlap: with k1, k2 and the
// focal length all free, that noise extrapolates to 1-2 px at the frame corners no match reaches.
// Once a rig is close (after the first bundle adjustment), correspondences are placed on the
// textured spots of each overlap (Shi-Tomasi corners on a pixel of one camera) and located in the
// other camera by aligning the patch through the rig's local map (lens included): Gauss-Newton on
// the sub-pixel shift with a gain and an offset (Lucas-Kanade), to a few hundredths of a pixel.
#pragma once

#include <atomic>

#include <opencv2/core.hpp>
#include <utility>
#include <vector>

#include "stitch/calib/bundle_adjust.hpp"
#include "stitch/rig/rig.hpp"

namespace stitch {

struct DenseMatchOptions {
  int max_points = 500;        // per pair and direction (points picked in a, in b)
  int radius = 5;              // patch half side, pixels
  int min_distance = 4;        // between picked points, pixels
  double quality = 0.01;       // corner strength, relative to the strongest (goodFeaturesToTrack)
  double blur_sigma = 0.7;     // smoothing of the sharper side (interpolation bias); the other is
                               // smoothed to the same resolution through the rig's local scale
  double max_shift_px = 3.0;   // how far off the rig's prediction may be
  double min_ncc = 0.92;       // normalised cross-correlation of an accepted alignment
  // Wide lenses matched on rays (a back-to-back fisheye ring, >= 90 degrees off the axis, has no
  // ideal pinhole pixel): pa / pb repeat the raw pixels, as the ray matches do (the adjustment
  // works on ra / rb). Off: matches without an ideal pixel are dropped.
  bool rays = false;
  // Set (by another thread): dense_matches stops before its next pair and frame set.
  const std::atomic<bool>* cancel = nullptr;
};

// A grey frame prepared for alignment.
struct DenseImage {
  cv::Mat gray;  // 8-bit, as given (corner picking)
  cv::Mat img;   // CV_32F
};
DenseImage prepare_dense_image(const cv::Mat& gray8, const DenseMatchOptions& o = {});

// Correspondences of cameras a and b under `rig`: raw pixels in ra/rb, the ideal pixels under the
// rig's lenses in pa/pb, unit weights. Points picked in both cameras (each tracked into the
// other). Empty when the rig puts no overlap between them.
PairMatches dense_pair_matches(const Rig& rig, int a, int b, const DenseImage& A, const DenseImage& B,
                               const DenseMatchOptions& o = {});

// The same for every listed camera pair, pooled over frame sets (images[set][camera]).
std::vector<PairMatches> dense_matches(const Rig& rig, const std::vector<std::pair<int, int>>& pairs,
                                       const std::vector<std::vector<DenseImage>>& images,
                                       const DenseMatchOptions& o = {});

// Sub-pixel "peak locking" (issue 15): the located point of a patch alignment is pulled towards
// a sub-pixel phase of the target grid by a few thousandths of a pixel, the same way all over the
// overlap. Tiny, but coherent over a thousand matches, and the moire of the two cameras' grids
// makes it vary smoothly across the overlap, where it leans on the rig's weakest direction (the
// common focal scale, and with it the side cameras' angles: 0.1 % on k1 -0.35 lenses). Under a
// fitted `rig`, the residual of each located point (the one off the whole-pixel grid: points are
// picked at whole pixels) is regressed on its sub-pixel phase (two harmonics per axis, pooled
// over all pairs) and the periodic part is taken off. Returns the matches used (0: too few, left
// as they were).
int correct_phase_bias(const Rig& rig, std::vector<PairMatches>& matches);

}  // namespace stitch
