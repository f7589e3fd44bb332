// 360 cameras with no rig file: frames that show a lit disc on black are circular fisheyes.
// Their image circle, and a rough rig of them (back to back for two, a ring for more, on a
// spherical canvas) that calibrate_from_rig refines like a hand-written rough rig.
#pragma once

#include <optional>
#include <vector>

#include "stitch/image.hpp"
#include "stitch/rig/rig.hpp"

namespace stitch {

// The image circle of a circular fisheye frame (RGBA): the lit disc, when the frame's corners
// are black and the lit part is one disc of at least 30% of the shorter side in radius, not far
// from the centre; nullopt for any other frame (rectilinear, full-frame fisheye, a dark scene).
std::optional<LensCircle> find_image_circle(const ImageView& frame);

// A rough rig for frames that all show an image circle (nullopt otherwise): fisheye lenses
// whose coefficients are to be estimated, focal length from the circle and a guessed field of
// view (equidistant: radius = f * fov / 2), two cameras back to back or N evenly around,
// spherical canvas. `slots`: camera i's place around the ring (yaw 360 * slots[i] / N; pads come
// in any order, see calibrator.cpp ring_slots); empty: pad order.
std::optional<Rig> circular_fisheye_rig(const std::vector<ImageView>& frames, double fov_deg,
                                        const std::vector<int>& slots = {});

// The same in two steps, for a caller that tries several fields of view and orders: every
// frame's image circle (nullopt when a frame shows none), found once; the rig from those.
std::optional<std::vector<LensCircle>> find_image_circles(const std::vector<ImageView>& frames);
std::optional<Rig> circular_fisheye_rig(const std::vector<ImageView>& frames, const std::vector<LensCircle>& circles,
                                        double fov_deg, const std::vector<int>& slots = {});

}  // namespace stitch
