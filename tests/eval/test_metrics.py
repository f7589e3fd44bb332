"""Self-test of the evaluation suite's metrics (bench/eval/metrics.py) on cases whose answer is
known: identical images, a known intensity offset, a known shift of the calibration, a static
clip, a known homography. Runs from a fresh clone (the photo is in data/)."""
import math
import os
import sys
import unittest

import cv2
import numpy as np

ROOT = os.environ.get("STITCH_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))
sys.path.insert(0, os.path.join(ROOT, "bench", "eval"))
import metrics  # noqa: E402


def photo():
    img = cv2.imread(os.path.join(ROOT, "data", "photos", "aero1.jpg"), cv2.IMREAD_COLOR)
    assert img is not None, "data/photos/aero1.jpg is missing"
    return img


def translation(dx, dy):
    return np.array([[1, 0, dx], [0, 1, dy], [0, 0, 1]], np.float64)


class PsnrSsim(unittest.TestCase):
    def test_identical_images_give_infinite_psnr_and_ssim_one(self):
        img = photo()
        self.assertEqual(metrics.psnr(img, img.copy()), math.inf)
        self.assertAlmostEqual(metrics.ssim(img, img.copy()), 1.0, places=12)

    def test_a_known_offset_gives_the_expected_psnr(self):
        img = np.clip(photo().astype(np.int32), 0, 250).astype(np.uint8)
        brighter = img + np.uint8(5)
        self.assertAlmostEqual(metrics.psnr(img, brighter), 20 * math.log10(255 / 5), places=9)

    def test_mask_limits_the_comparison(self):
        img = photo()
        other = img.copy()
        other[:, : img.shape[1] // 2] = 0
        mask = np.zeros(img.shape[:2], bool)
        mask[:, img.shape[1] // 2:] = True
        self.assertEqual(metrics.psnr(img, other, mask), math.inf)
        self.assertLess(metrics.psnr(img, other), 20)

    def test_blur_lowers_ssim(self):
        img = photo()
        s = metrics.ssim(img, cv2.GaussianBlur(img, (9, 9), 3))
        self.assertLess(s, 0.9)
        self.assertGreater(s, 0.2)


class Calibration(unittest.TestCase):
    def test_known_shift_gives_the_expected_corner_error(self):
        truth = [np.eye(3), np.eye(3), np.eye(3)]
        estimated = [translation(3, 4), np.eye(3), translation(-6, 8)]
        mean, worst = metrics.corner_error(estimated, truth, [(640, 480)] * 3, reference=1)
        self.assertAlmostEqual(mean, (5 + 10) / 2, places=9)
        self.assertAlmostEqual(worst, 10, places=9)

    def test_known_scale_gives_the_expected_corner_error(self):
        s = np.diag([1.01, 1.01, 1.0])
        mean, _ = metrics.corner_error([s, np.eye(3)], [np.eye(3), np.eye(3)], [(641, 481)] * 2, reference=1)
        expected = 0.01 * (0 + 640 + math.hypot(640, 480) + 480) / 4
        self.assertAlmostEqual(mean, expected, places=9)

    def test_reference_frame_is_independent_of_the_canvas(self):
        cam_to_canvas = [translation(100, 5), translation(400, 0)]
        moved = [translation(7, -3) @ H for H in cam_to_canvas]  # same rig, another canvas origin
        a = metrics.to_reference(cam_to_canvas, 1)
        b = metrics.to_reference(moved, 1)
        for x, y in zip(a, b):
            np.testing.assert_allclose(x, y, atol=1e-12)
        np.testing.assert_allclose(a[0], translation(-300, 5), atol=1e-12)


class Flicker(unittest.TestCase):
    def test_a_static_clip_has_zero_flicker(self):
        img = photo()
        mask = np.ones(img.shape[:2], bool)
        self.assertEqual(metrics.flicker([img, img.copy(), img.copy()], mask), [0.0, 0.0])

    def test_a_brightness_step_shows_as_flicker_on_static_pixels_only(self):
        img = np.clip(photo().astype(np.int32), 0, 240).astype(np.uint8)
        step = img.copy()
        step[:, :100] += 10
        static = np.zeros(img.shape[:2], bool)
        static[:, :100] = True
        values = metrics.flicker([img, step], static)
        self.assertAlmostEqual(values[0], 10.0, delta=0.6)  # luma of +10 in B, G and R
        moving_only = ~static
        self.assertEqual(metrics.flicker([img, step], moving_only), [0.0])


class SeamAndRegistration(unittest.TestCase):
    def test_seam_visibility_is_zero_for_the_truth_and_grows_with_a_step(self):
        img = photo()
        band = np.zeros(img.shape[:2], bool)
        band[:, 300:340] = True
        self.assertEqual(metrics.seam_visibility(img, img.copy(), band), 0.0)
        stepped = img.copy()
        stepped[:, 320:] = np.clip(stepped[:, 320:].astype(np.int32) + 30, 0, 255).astype(np.uint8)
        self.assertGreater(metrics.seam_visibility(stepped, img, band), 1.0)

    def test_register_recovers_a_known_homography(self):
        img = photo()
        H = np.array([[0.97, 0.03, 12.0], [-0.02, 1.01, -7.0], [1e-5, -2e-5, 1.0]])
        h, w = img.shape[:2]
        warped = cv2.warpPerspective(img, H, (w, h))
        valid = cv2.warpPerspective(np.full((h, w), 255, np.uint8), H, (w, h)) > 0
        found = metrics.register(warped, valid, metrics.features(img))
        self.assertIsNotNone(found)
        mean, _ = metrics.corner_error([found, np.eye(3)], [np.linalg.inv(H), np.eye(3)], [(w, h)] * 2, 1)
        self.assertLess(mean, 0.5)

    def test_alignment_measures_a_known_calibration_error(self):
        img = photo()
        left, right = img[:, :400], img[:, 240:]
        exact = [np.eye(3), translation(240, 0)]
        median, count = metrics.alignment([left, right], exact)
        self.assertGreater(count, 50)
        self.assertLess(median, 0.5)
        off = [np.eye(3), translation(243, 4)]
        median, _ = metrics.alignment([left, right], off)
        self.assertAlmostEqual(median, 5.0, delta=0.5)

    def test_warp_measures(self):
        img = photo()[:200, :300]
        mask = np.ones(img.shape[:2], bool)
        # a homography-only chain: no local warp, straight lines, no shake
        same = metrics.warp_field(img, img, mask)
        self.assertLess(np.abs(same).mean(), 0.02)
        self.assertLess(metrics.line_distortion(same, mask)[1], 0.3)
        # a local bump bends rows by ~3 px; a constant shift bends nothing
        bump = np.zeros(img.shape[:2] + (2,), np.float32)
        yy, xx = np.mgrid[0:200, 0:300]
        bump[..., 1] = 3.0 * np.exp(-((xx - 150) ** 2) / (2 * 20.0 ** 2))
        self.assertAlmostEqual(metrics.line_distortion(bump, mask)[1], 3.0, delta=0.2)
        shift = np.full(img.shape[:2] + (2,), 2.0, np.float32)
        self.assertLess(metrics.line_distortion(shift, mask)[1], 1e-6)
        # a warp moving at constant speed is stable; one that jumps back and forth is not
        steady = [shift * t for t in range(4)]
        self.assertLess(metrics.warp_stability(steady, [mask] * 4), 1e-6)
        jitter = [shift * (t % 2) for t in range(4)]
        self.assertAlmostEqual(metrics.warp_stability(jitter, [mask] * 4), 2 * 2 * np.sqrt(2), delta=1e-4)


if __name__ == "__main__":
    unittest.main()
