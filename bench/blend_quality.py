#!/usr/bin/env python3
"""Seam visibility, PSNR and flicker of stitchblend's modes on a ground-truth rig.

stitch-render-rig renders cameras of one real photo (exact geometry, per-camera exposure, white
balance, gamma, noise, a moving disc) and the true panorama of frame 0. Each variant runs the
full chain (stitchcalib with the true rig, so only colour, flow and blend differ) through
gst-launch-1.0, and is scored like the evaluation suite (bench/eval on main) scores it:

  PSNR        against the true panorama of frame 0, all covered pixels and the overlaps alone
  seam vis.   mean |Sobel gradient magnitude (luma) of output - of truth| over the overlaps,
              frame 0 (steps and doubled edges show as gradient the scene lacks)
  flicker     mean |luma change| between consecutive panoramas in the overlaps, frames 1..N-1
              (the scene there is static except for the disc; seams that jump add to it)

usage: blend_quality.py [--build build] [--frames 30] [--out out/blend_quality]
"""
import argparse
import json
import os
import subprocess
import sys

import cv2
import numpy as np

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
# What runs before stitchblend: the whole chain, or nothing (the views' exposure differences and
# misalignment then reach the blend, which is where blend modes differ most).
CHAINS = [("chain", "stitchcolor ! stitchflowwarp !"), ("blend-only", "")]
VARIANTS = [("weighted", ""), ("multiband", "mode=multiband"), ("multiband+dp", "mode=multiband seam=dp"),
            ("multiband-b8", "mode=multiband bands=8"), ("multiband-b8+dp", "mode=multiband bands=8 seam=dp")]
RIGS = [("boat-3cam", "data/photos/boat1_1600.jpg", ["--cameras", "3", "--width", "480", "--height", "360",
                                                       "--hfov", "55", "--overlap", "0.35"]),
        ("aero-2cam", "data/photos/aero3.jpg", ["--cameras", "2", "--width", "320", "--height", "240",
                                                "--hfov", "50", "--overlap", "0.4"])]


def luma(img):
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float64)


def gradient_magnitude(img):
    y = luma(img)
    return np.hypot(cv2.Sobel(y, cv2.CV_64F, 1, 0, ksize=3), cv2.Sobel(y, cv2.CV_64F, 0, 1, ksize=3))


def psnr(a, b, mask):
    mse = np.mean((a.astype(np.float64)[mask] - b.astype(np.float64)[mask]) ** 2)
    return 10 * np.log10(255.0 ** 2 / mse) if mse > 0 else float("inf")


def overlaps(rig, width, height):
    """Pixels of the canvas that two or more cameras see."""
    count = np.zeros((height, width), np.int32)
    for cam in rig["cameras"]:
        H = np.array(cam["homography"], np.float64).reshape(3, 3)
        corners = np.array([[-0.5, -0.5], [cam["width"] - 0.5, -0.5], [cam["width"] - 0.5, cam["height"] - 0.5],
                            [-0.5, cam["height"] - 0.5]])
        p = np.hstack([corners, np.ones((4, 1))]) @ H.T
        poly = (p[:, :2] / p[:, 2:3]).round().astype(np.int32)
        m = np.zeros((height, width), np.uint8)
        cv2.fillConvexPoly(m, poly, 1)
        count += m
    return count >= 2


def run_variant(build, rig_dir, n_cams, before, blend_props, width, height, out_raw):
    chain = ("stitchsync name=s ! stitchcalib load-file=%s ! %s stitchblend %s ! "
             "video/x-raw,format=RGBA ! filesink location=%s" % (os.path.join(rig_dir, "rig_true.json"), before,
                                                                  blend_props, out_raw))
    for i in range(n_cams):
        chain += " filesrc location=%s ! avidemux ! jpegdec ! videoconvert ! s.sink_%d" % (
            os.path.join(rig_dir, "cam%d.avi" % i), i)
    env = dict(os.environ, GST_PLUGIN_PATH=os.path.join(build, "gst"))
    r = subprocess.run(["gst-launch-1.0", "-q", "-e"] + chain.split(), env=env, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT, text=True)
    if r.returncode != 0:
        sys.exit("gst-launch failed: %s\n%s" % (chain, r.stdout[-2000:]))
    data = np.fromfile(out_raw, np.uint8)
    n = data.size // (width * height * 4)
    return data[: n * width * height * 4].reshape(n, height, width, 4)[..., :3]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "blend_quality"))
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    results = {}
    print("%-10s %-11s %-16s %9s %12s %10s %9s" % ("rig", "before", "blend", "PSNR dB", "overlap dB", "seam vis.",
                                                    "flicker"))
    for name, photo, opts in RIGS:
        rig_dir = os.path.join(args.out, name)
        subprocess.run([os.path.join(args.build, "tests", "stitch-render-rig"), "--photo", os.path.join(ROOT, photo),
                        "--out", rig_dir, "--frames", str(args.frames)] + opts, check=True, stdout=subprocess.DEVNULL)
        rig = json.load(open(os.path.join(rig_dir, "rig_true.json")))
        gt = cv2.imread(os.path.join(rig_dir, "gt_frame0.png"), cv2.IMREAD_UNCHANGED)
        covered = gt[..., 3] > 0
        truth = cv2.cvtColor(gt[..., :3], cv2.COLOR_BGR2RGB)
        h, w = truth.shape[:2]
        band = overlaps(rig, w, h) & covered
        for (chain, before), (variant, props) in [(c, v) for c in CHAINS for v in VARIANTS]:
            raw = os.path.join(rig_dir, variant.replace("+", "_") + ".raw")
            pano = run_variant(args.build, rig_dir, len(rig["cameras"]), before, props, w, h, raw)
            first = pano[0]
            vis = float(np.abs(gradient_magnitude(first) - gradient_magnitude(truth))[band].mean())
            lum = [luma(f)[band] for f in pano[1:]]
            flick = float(np.mean([np.abs(b - a).mean() for a, b in zip(lum, lum[1:])])) if len(lum) > 1 else float("nan")
            row = dict(psnr=psnr(first, truth, covered), psnr_overlap=psnr(first, truth, band), seam_visibility=vis,
                       flicker=flick, frames=int(pano.shape[0]))
            results["%s/%s/%s" % (name, chain, variant)] = row
            print("%-10s %-11s %-16s %9.2f %12.2f %10.2f %9.3f" % (name, chain, variant, row["psnr"], row["psnr_overlap"],
                                                                 vis, flick), flush=True)
            os.remove(raw)
    json.dump(results, open(os.path.join(args.out, "results.json"), "w"), indent=1)


if __name__ == "__main__":
    main()
