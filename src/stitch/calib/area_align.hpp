// Area alignment of an overlap (branch ring-closure). Feature matching ties only the pairs whose
// overlaps hold enough distinctive keypoints; a 360-degree ring whose closing pair has a thin or
// plain overlap is then tied by nothing there, and the ring's closure error (a focal length a few
// percent off) lands on that one seam, tens of pixels, while every measured pair reads 0.2-0.4 px.
// Here the overlap is compared as pictures: camera a's view is warped into camera b through the
// fitted rotations, textured patches of it are searched for in b over a range wide enough for a
// closure error (normalised cross-correlation), and the patches that agree on one near-rigid
// motion (RANSAC similarity) measure how far off the rig is there and give correspondences that a
// bundle adjustment can use like feature matches.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <vector>

#include "stitch/rig/rig.hpp"

namespace stitch {

struct AreaAlignOptions {
  double search_px = 64;   // how far off (camera b pixels) the rig's prediction may be
  int patch_radius = 10;   // patch half side, pixels (overlaps of 6-10% are 40-90 px wide)
  int max_patches = 120;   // textured patches tried per pair
  double min_ncc = 0.8;    // a patch's best correlation, to count at all
  double min_strip_ncc = 0.3;     // the whole overlap's correlation at its best shift (a third of a
                                  // predicted overlap may lie beyond the true one)
  int peak_exclusion_px = 4;      // the runner-up shift is sought this far from the best
  double min_peak_margin = 0.05;  // and must correlate this much less (a distinct shift)
  double local_search_px = 8;     // patches are then sought this far around that shift
  int min_agreeing = 8;    // patches that agree on one motion, to call the pair measured
  double agree_px = 2.0;   // RANSAC tolerance of that motion
};

struct AreaAlignment {
  bool overlap = false;    // the rig's rotations overlap the two views (patches could be placed)
  bool measured = false;   // enough patches agreed on one motion
  int patches = 0;         // patches whose best correlation passed min_ncc
  int agreeing = 0;
  double offset_px = -1;   // median distance between predicted and found positions (b pixels)
  std::vector<Eigen::Vector2d> pa, pb;  // the agreeing patches' centres: a pixel <-> b pixel
};

// Pinhole cameras only (a lens camera: overlap false). gray_a / gray_b: 8-bit frames of the
// cameras' sizes.
AreaAlignment align_overlap_by_area(const Camera& a, const Camera& b, const cv::Mat& gray_a, const cv::Mat& gray_b,
                                    const AreaAlignOptions& o = {});

}  // namespace stitch
