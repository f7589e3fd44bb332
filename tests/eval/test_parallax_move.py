"""Self-test of the parallax move prototype's estimator (bench/eval/parallax_move.py): a textured
near object seen by two views at a known disparity over a real photo's background (flat sky and
water included) is found once, with its displacement and its pixels in the first view; views that
agree, flat or black views, and an object that only one view shows give nothing to move (the
output there stays the homography's)."""
import os
import sys
import unittest

import cv2
import numpy as np

ROOT = os.environ.get("STITCH_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))
sys.path.insert(0, os.path.join(ROOT, "bench", "eval"))
import parallax_move as pm  # noqa: E402


def gray(name):
    img = cv2.imread(os.path.join(ROOT, "data", "photos", name), cv2.IMREAD_GRAYSCALE)
    assert img is not None, "data/photos/%s is missing" % name
    return img.astype(np.float32)


W, H = 360, 240
OBJ_X, OBJ_Y, OBJ_W, OBJ_H = 170, 60, 90, 120


def scene(d, in_a=True, in_b=True, noise=1.0, seed=3, top=OBJ_Y, height=OBJ_H):
    """Views a and b of one background (a crop of the boat photo: sky, water, buildings) with a
    textured object (a crop of the aerial photo) at OBJ_X in a and OBJ_X + d in b."""
    bg = cv2.resize(gray("boat1_1600.jpg"), (W * 2, H * 2), interpolation=cv2.INTER_AREA)[100:100 + H, 200:200 + W]
    tex = gray("aero1.jpg")[40:40 + height, 60:60 + OBJ_W]
    a, b = bg.copy(), bg.copy()
    if in_a:
        a[top:top + height, OBJ_X:OBJ_X + OBJ_W] = tex
    if in_b:
        b[top:top + height, OBJ_X + d:OBJ_X + d + OBJ_W] = tex
    rng = np.random.default_rng(seed)
    a += rng.normal(0, noise, a.shape).astype(np.float32)
    b += rng.normal(0, noise, b.shape).astype(np.float32)
    truth = np.zeros((H, W), bool)
    truth[top:top + height, OBJ_X:OBJ_X + OBJ_W] = True
    return a, b, truth


SETTINGS = pm.parser().parse_args([])
OVERLAP = np.ones((H, W), bool)


def estimate(a, b, direction=(-1.0, 0.0)):
    return pm.estimate_blobs(a, b, OVERLAP, SETTINGS, 150, direction)


class Move(unittest.TestCase):
    def test_a_near_object_is_found_once_with_its_disparity_and_pixels(self):
        for d in (-40, -75):
            a, b, truth = scene(d)
            blobs = [x for x in estimate(a, b) if x[0].any()]
            self.assertEqual(len(blobs), 1, "d = %d" % d)
            mask, dx, dy, _ = blobs[0]
            self.assertLessEqual(abs(dx - d), 2, "d = %d: found %d" % (d, dx))
            self.assertLessEqual(abs(dy), 2)
            iou = (mask & truth).sum() / (mask | truth).sum()
            self.assertGreater(iou, 0.85, "d = %d: mask IoU %.2f" % (d, iou))

    def test_without_a_baseline_both_directions_are_searched(self):
        a, b, truth = scene(-50)
        blobs = [x for x in estimate(a, b, direction=None) if x[0].any()]
        self.assertEqual(len(blobs), 1)
        self.assertLessEqual(abs(blobs[0][1] + 50), 2)

    def test_views_that_agree_move_nothing(self):
        a, b, _ = scene(0)
        self.assertEqual(estimate(a, b), [])

    def test_flat_and_black_views_move_nothing(self):
        flat = np.full((H, W), 128, np.float32)
        black = np.zeros((H, W), np.float32)
        self.assertEqual(estimate(flat, flat.copy()), [])
        self.assertEqual(estimate(black, black.copy()), [])
        a, _, _ = scene(-40)
        for blob in estimate(a, black):  # one view black: whatever is found must not be a move of it
            self.assertFalse(blob[0].any() and np.isnan(blob[1]))

    def test_a_disagreement_as_tall_as_the_overlap_is_not_moved(self):
        # a whole overlap of varying depth (a corridor, real hallway set) is no object in front
        # of a background: one displacement for it would tear the overlap apart
        a, b, _ = scene(-40, top=0, height=H)
        self.assertEqual([x for x in estimate(a, b) if x[0].any()], [])

    def test_an_object_only_one_view_shows_is_not_moved(self):
        for in_a in (False, True):
            a, b, _ = scene(-40, in_a=in_a, in_b=not in_a)
            self.assertEqual([x for x in estimate(a, b) if x[0].any()], [])


if __name__ == "__main__":
    unittest.main()
