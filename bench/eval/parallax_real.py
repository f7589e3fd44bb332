#!/usr/bin/env python3
"""Parallax on real data: how far each chain's overlaps are from showing one consistent view.

Real sets have no ground truth, so the overlap error of a *fused* panorama is measured against
the inputs: a panorama without ghosts shows, around every overlap pixel, the structure of one of
the views (a ghost shows both, half-transparent, and matches neither). Per overlap pixel
(both homography-warped views valid, eroded 6 px):

* detail MAD: |detail(pano) - detail(view i)| (detail = minus the Gaussian local mean, sigma 8
  px, so the colour stage's gains do not count), mean over r, g, b, box-averaged over 9 x 9
  px; the smaller over the views, averaged over the overlap;
* SSIM: the luma SSIM map (11 x 11 Gaussian) of the panorama against each view, the larger,
  averaged over the overlap.

Both are taken against the views warped by the same homographies the chain used (the rig
written by stitch-calibrate, loaded by every chain), so for stitchflowwarp (which moves the
views) they also count its displacement: its row says how far it strays from both views.
Also: flicker (mean |dY| between consecutive panoramas over overlap pixels where no view moved
by more than 2 grey levels) on the clips.

usage: parallax_real.py [--out DIR] [--build DIR] [--frames 12] [--sets a,b] [--variant NAME=CHAIN|BLEND]
"""
import argparse
import json
import os
import subprocess
import sys
import time

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import metrics  # noqa: E402
import parallax  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
DATA = os.path.abspath(os.path.join(ROOT, "..", "shared", "data"))
if not os.path.isdir(DATA):
    DATA = "/work/shared/data"

# name -> (kind, files, resize width or 0)
SETS = {
    "hallway": ("video", ["video/unrival_stereo_hallway/left.mp4", "video/unrival_stereo_hallway/right.mp4"], 0),
    "house": ("video", ["video/karthik_3cam_house/left.mp4", "video/karthik_3cam_house/middle.mp4",
                        "video/karthik_3cam_house/right.mp4"], 0),
    "limlight": ("video", ["video/limlight_2cam_apartment/left.mp4", "video/limlight_2cam_apartment/right.mp4"], 0),
    "railtracks": ("image", ["images/eadcat_apap_demo/demo5/P1010517.JPG",
                             "images/eadcat_apap_demo/demo5/P1010520.JPG"], 1000),
    "carpark": ("image", ["images/udis2_carpark_dhw/input1.jpg", "images/udis2_carpark_dhw/input2.jpg"], 0),
}

CHAINS = [
    ("homography", "stitchcolor", "seam=none"),
    ("flowwarp", "stitchcolor ! stitchflowwarp flow=true", "seam=none"),  # the old default chain
    ("consensus", "stitchcolor", "seam=dp"),  # the new default chain
]


def prepare_frames(name, out, frames):
    kind, files, width = SETS[name]
    os.makedirs(out, exist_ok=True)
    n_frames = frames if kind == "video" else 3
    for i, f in enumerate(files):
        path = os.path.join(DATA, f)
        if kind == "video":
            cap = cv2.VideoCapture(path)
            imgs = []
            while len(imgs) < n_frames:
                ok, img = cap.read()
                if not ok:
                    break
                imgs.append(img)
        else:
            img = cv2.imread(path)
            if img is None:
                raise SystemExit("cannot read " + path)
            imgs = [img] * n_frames
        for t, img in enumerate(imgs):
            if width and img.shape[1] != width:
                img = cv2.resize(img, (width, int(round(img.shape[0] * width / img.shape[1]))),
                                 interpolation=cv2.INTER_AREA)
            cv2.imwrite(os.path.join(out, "cam%d_%04d.png" % (i, t)), img)
    return len(files), n_frames


def calibrate(build, name, d, n):
    """The rig every chain loads: from the clips (several instants) or the images."""
    rig = os.path.join(d, "rig.json")
    if os.path.exists(rig):
        return rig
    kind, files, _ = SETS[name]
    inputs = [os.path.join(DATA, f) for f in files] if kind == "video" else \
        [os.path.join(d, "cam%d_0000.png" % i) for i in range(n)]
    cmd = [os.path.join(build, "tools", "stitch-calibrate"), "--projection", "plane", "--out", rig] + inputs
    with open(os.path.join(d, "calibrate.log"), "w") as log:
        if subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode != 0:
            raise SystemExit("calibration failed, see " + os.path.join(d, "calibrate.log"))
    return rig


def warped_views(rig, d, n, t):
    """Each view warped onto the canvas by its homography, and its coverage."""
    r = json.load(open(rig))
    W, H = r["canvas"]["width"], r["canvas"]["height"]
    out = []
    for i, c in enumerate(r["cameras"]):
        img = cv2.imread(os.path.join(d, "cam%d_%04d.png" % (i, t)))
        Hm = np.asarray(c["homography"], np.float64).reshape(3, 3)
        lens = c.get("lens") or {}
        coeffs = [lens.get(k, 0.0) for k in ("k1", "k2", "p1", "p2", "k3")]
        if any(abs(v) > 0 for v in coeffs):  # radtan: undistort first (the chain warps through the lens)
            K = np.array([[c["fx"], 0, c["cx"]], [0, c["fy"], c["cy"]], [0, 0, 1]])
            img = cv2.undistort(img, K, np.asarray(coeffs))
        v = cv2.warpPerspective(img, Hm, (W, H), flags=cv2.INTER_LINEAR)
        m = cv2.warpPerspective(np.full(img.shape[:2], 255, np.uint8), Hm, (W, H), flags=cv2.INTER_NEAREST) > 0
        out.append((v, m))
    return out, (W, H)


def detail(img):
    f = img.astype(np.float32)
    return f - cv2.GaussianBlur(f, (0, 0), 8)


def ssim_map(a, b):
    x, y = metrics.luma(a), metrics.luma(b)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def blur(v):
        return cv2.GaussianBlur(v, (11, 11), 1.5, borderType=cv2.BORDER_REPLICATE)

    mx, my = blur(x), blur(y)
    sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    return ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))


def evaluate(run_dir, rig, d, n, frames):
    mads, ssims, flick = [], [], []
    prev = prev_views = None
    for t in range(frames):
        pano = cv2.imread(os.path.join(run_dir, "pano_%04d.png" % t), cv2.IMREAD_UNCHANGED)
        if pano is None:
            break
        pano = pano[:, :, :3]
        views, (W, H) = warped_views(rig, d, n, t)
        if 0 <= pano.shape[0] - H <= 1 and 0 <= pano.shape[1] - W <= 1:  # odd canvases are padded to even
            pano = pano[:H, :W]
        if pano.shape[:2] != (H, W):
            raise SystemExit("%s: panorama is not %dx%d" % (run_dir, W, H))
        cover = np.sum([m for _, m in views], axis=0)
        ov = cv2.erode((cover >= 2).astype(np.uint8), np.ones((13, 13), np.uint8)) > 0
        dp = detail(pano)
        err = np.full((H, W), np.inf, np.float32)
        sim = np.full((H, W), -np.inf)
        for v, m in views:
            e = cv2.blur(np.abs(dp - detail(v)).mean(axis=2), (9, 9))
            err = np.where(m, np.minimum(err, e), err)
            sim = np.where(m, np.maximum(sim, ssim_map(pano, v)), sim)
        mads.append(float(err[ov].mean()))
        ssims.append(float(sim[ov].mean()))
        if prev is not None and frames > 3:
            still = ov.copy()
            for (v, _), (pv, _) in zip(views, prev_views):
                still &= np.abs(metrics.luma(v) - metrics.luma(pv)) <= 2
            still = cv2.erode(still.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            if still.any():
                flick.append(float(np.abs(metrics.luma(pano) - metrics.luma(prev))[still].mean()))
        prev, prev_views = pano, views
    return dict(detail_mad=float(np.mean(mads)), ssim=float(np.mean(ssims)),
                flicker=float(np.mean(flick)) if flick else float("nan"), frames=len(mads))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "parallax_real"))
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--sets", default=",".join(SETS))
    ap.add_argument("--chains", default="")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=CHAIN[|BLEND]")
    ap.add_argument("--backend", default="cpu")
    ap.add_argument("--results", default="results.json", help="file name under --out")
    args = ap.parse_args()
    chains = parallax.select_chains(CHAINS, args.variant, args.chains)
    os.environ["GST_PLUGIN_PATH"] = os.path.join(args.build, "gst")
    os.environ.setdefault("GST_REGISTRY", os.path.join(args.build, "parallax-registry.bin"))
    results = {}
    t0 = time.time()
    for name in args.sets.split(","):
        d = os.path.join(args.out, name, "frames")
        n, frames = prepare_frames(name, d, args.frames)
        rig = calibrate(args.build, name, d, n)
        res = {}
        for cname, chain, blend in chains:
            od = os.path.join(args.out, name, cname)
            clips = ",".join(os.path.join(d, "cam%d_%%04d.png" % i) for i in range(n))
            cmd = [os.path.join(args.build, "bench", "stitch-eval-chain"), "--out", od, "--clips", clips, "--frames",
                   str(frames), "--chain", chain, "--blend", blend, "--backend", args.backend, "--calib", rig]
            with open(od + ".log", "w") as log:
                if subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT).returncode != 0:
                    res[cname] = dict(error="failed, see %s.log" % od)
                    print("%-10s %-12s failed" % (name, cname), flush=True)
                    continue
            res[cname] = evaluate(od, rig, d, n, frames)
            r, h = res[cname], res.get("homography")
            cut = (1 - r["detail_mad"] / h["detail_mad"]) * 100 if h and "detail_mad" in h else float("nan")
            print("%-10s %-12s detail MAD %.3f (cut %+.1f%%)  SSIM %.4f  flicker %.3f" % (
                name, cname, r["detail_mad"], cut, r["ssim"], r["flicker"]), flush=True)
        results[name] = res
    json.dump(results, open(os.path.join(args.out, args.results), "w"), indent=1)
    print("%.0f s; %s" % (time.time() - t0, os.path.join(args.out, args.results)))


if __name__ == "__main__":
    sys.exit(main())
