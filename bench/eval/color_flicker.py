#!/usr/bin/env python3
"""Static-region flicker of a real clip with and without stitchcolor (issue 16, colour that
holds still): the evaluation suite's flicker (bench/eval/evaluate.py: mean |dY| between
consecutive panoramas on canvas pixels whose input never changes over the clip) for a few
chains only, so one dataset is quick to re-measure while tuning.

usage: color_flicker.py [--clip DIR] [--frames 60] [--out DIR] [--variant NAME=CHAIN]...
"""
import argparse
import os
import sys

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import evaluate as ev  # noqa: E402

CHAINS = [("no-color", ""), ("color", "stitchcolor")]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--clip", default=os.path.join(ev.SHARED, "video/karthik_3cam_house"),
                    help="folder of the clips (the shared data: ../shared/data/video/...)")
    ap.add_argument("--names", default="left,middle,right")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--out", default=os.path.join(ev.ROOT, "out", "color_flicker"))
    ap.add_argument("--build", default=os.path.join(ev.ROOT, "build"))
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=CHAIN")
    args = ap.parse_args()
    chains = CHAINS + [tuple(v.split("=", 1)) for v in args.variant]
    os.environ["GST_PLUGIN_PATH"] = os.path.join(args.build, "gst")
    os.environ.setdefault("GST_REGISTRY", os.path.join(args.build, "flicker-registry.bin"))
    files = [os.path.join(args.clip, n + ".mp4") for n in args.names.split(",")]
    inputs = ev.read_inputs(files, args.frames)
    frames = len(inputs)
    os.makedirs(args.out, exist_ok=True)
    # Static camera pixels (as evaluate_clip): the input hardly changes there over the clip.
    static_cam = []
    for i in range(len(files)):
        stack = np.stack([ev.metrics.luma(inputs[t][i]) for t in range(frames)])
        static_cam.append((stack.std(axis=0) < 2.5) & (np.abs(np.diff(stack, axis=0)).max(axis=0) < 12))
    results = {}
    canvas_static = None
    for name, chain in chains:
        d = os.path.join(args.out, name)
        ok, _ = ev.run([os.path.join(args.build, "bench", "stitch-eval-chain"), "--out", d, "--clips", ",".join(files),
                        "--frames", str(frames), "--chain", chain, "--backend", "cpu"], d + ".log")
        if not ok:
            results[name] = None
            continue
        info, images, valid = ev.load_run(d, frames)
        if canvas_static is None:
            _, Hs, sizes = ev.rig_homographies(os.path.join(d, "calib.json"))
            last = [img for img in images if img is not None]  # a chain may drop frames
            if not last:
                results[name] = None
                continue
            shape = last[-1].shape[:2]
            covered = ev.coverage_count(Hs, sizes, shape)
            moving = np.zeros(shape, np.int32)
            for H, s in zip(Hs, static_cam):
                moving += ev.warp((~s).astype(np.uint8), H, (shape[1], shape[0]), nearest=True)
            canvas_static = cv2.erode(((covered > 0) & (moving == 0)).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        regs = [np.eye(3) if img is not None else None for img in images]
        fl = [ev.frame_flicker(images, valid, regs, canvas_static, t) for t in range(ev.SETTLE + 1, frames)]
        results[name] = ev.nanmean(fl)
        print("%-24s flicker %.3f" % (name, results[name]), flush=True)
    base = results.get("no-color")
    for name, v in results.items():
        if v is not None and base:
            print("%-24s %+.0f%% over no colour" % (name, 100 * (v - base) / base))
    return 0


if __name__ == "__main__":
    sys.exit(main())
