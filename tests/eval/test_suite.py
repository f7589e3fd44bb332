"""The evaluation suite end to end on the smallest repository rig (a few frames): every
stitcher runs, the report is written, and the metrics see what each stage does (without
stitchcolor the panorama is farther from the ground truth; per-frame OpenCV flickers more
than its estimate-once mode, which composes with fixed geometry)."""
import json
import math
import os
import subprocess
import sys
import tempfile
import unittest

ROOT = os.environ.get("STITCH_SOURCE_DIR", os.path.join(os.path.dirname(__file__), "..", ".."))
BUILD = os.environ.get("STITCH_BUILD_DIR", os.path.join(ROOT, "build"))


class EvaluationSuite(unittest.TestCase):
    def test_report_on_a_ground_truth_rig(self):
        with tempfile.TemporaryDirectory() as out:
            r = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "eval", "evaluate.py"), "--build", BUILD,
                                "--out", out, "--only", "aero-2cam", "--frames", "10", "--no-shared"],
                               capture_output=True, text=True, timeout=280)
            self.assertEqual(r.returncode, 0, r.stdout + r.stderr)
            results = json.load(open(os.path.join(out, "results.json")))["datasets"]["aero-2cam"]["stitchers"]
            for name in ("ours", "ours-no-color", "ours-no-flowwarp", "ours-blend-only", "opencv-per-frame",
                         "opencv-once"):
                self.assertIn(name, results)
                self.assertNotIn("error", results[name], name)
                self.assertTrue(math.isfinite(results[name]["psnr_db"]), name)
                self.assertGreater(results[name]["coverage"], 0.9, name)
                self.assertGreater(results[name]["ms_per_frame"], 0, name)
            # The cameras differ in exposure and white balance: colour correction must show.
            self.assertGreater(results["ours"]["psnr_db"], results["ours-no-color"]["psnr_db"] + 3)
            self.assertLess(results["ours"]["corner_error_px"], 3.0)
            report = open(os.path.join(out, "report.md")).read()
            self.assertIn("| ours |", report)
            for f in ("psnr_aero-2cam.png", "flicker_aero-2cam.png", "seams_aero-2cam.png"):
                self.assertGreater(os.path.getsize(os.path.join(out, f)), 1000, f)


if __name__ == "__main__":
    unittest.main()
