#!/usr/bin/env python3
"""The evaluation suite: our chain and OpenCV's stitcher on the same data, one report.

Ground-truth rigs are rendered from real photos (stitch-render-rig: exact homographies,
per-camera exposure, white balance, gamma and noise, a moving disc that crosses the overlaps,
a sudden illumination step). Real clips come from data/ and, when present, ../shared/data.
Every stitcher writes every panorama; the metrics (bench/eval/metrics.py) are computed here
the same way for all of them:

  ground-truth rigs  PSNR and SSIM against the true panorama, PSNR and seam visibility on the
                     overlaps, calibration corner error, flicker on static regions, coverage
  real clips         overlap alignment of independently matched features under each
                     stitcher's calibration, flicker on static regions
  both               time per frame on this machine's CPU and its ratio to OpenCV per-frame

Stitchers: our chain (stitchcolor ! stitchflowwarp ! stitchblend) and its ablations without
stitchcolor, without stitchflowwarp and without both; the chain with stitchblend
mode=multiband, and with mode=multiband seam=dp; cv::Stitcher per frame (the paper's
AutoStitch baseline) and estimated once then composing every frame.

Output (default out/eval): report.md (tables), results.json, per-frame PSNR and flicker plots
(PNG) and side-by-side seam crops.
usage: scripts/evaluate.sh [--out DIR] [--frames N] [--only NAME[,NAME]] [--no-shared]
                           [--variant NAME=CHAIN[|BLEND]]...
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time

import cv2
import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import metrics  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
SHARED = os.path.abspath(os.path.join(ROOT, "..", "shared", "data"))

# Our chain: (name, elements between stitchcalib and stitchblend, stitchblend properties).
OURS = [
    ("ours", "stitchcolor ! stitchflowwarp", ""),
    ("ours-no-color", "stitchflowwarp", ""),
    ("ours-no-flowwarp", "stitchcolor", ""),
    ("ours-blend-only", "", ""),
    ("ours-multiband", "stitchcolor ! stitchflowwarp", "mode=multiband"),
    ("ours-multiband-dp-seam", "stitchcolor ! stitchflowwarp", "mode=multiband seam=dp"),
]
OPENCV = [("opencv-per-frame", "per-frame"), ("opencv-once", "once")]
BASELINE = "opencv-per-frame"
SETTLE = 5  # stitchcalib's default calibration frames: geometry is final from here on


def rigs(shared):
    """Ground-truth rigs: (name, photo, stitch-render-rig options)."""
    out = [
        dict(name="boat-3cam", photo=os.path.join(ROOT, "data/photos/boat1_1600.jpg"),
             args=["--cameras", "3", "--width", "480", "--height", "360", "--hfov", "55", "--overlap", "0.35"]),
        dict(name="aero-2cam", photo=os.path.join(ROOT, "data/photos/aero3.jpg"),
             args=["--cameras", "2", "--width", "320", "--height", "240", "--hfov", "50", "--overlap", "0.4"]),
    ]
    if shared:
        out += [
            dict(name="harbour-5cam", photo=os.path.join(SHARED, "images/eadcat_apap_demo/demo2/boat03.jpg"),
                 args=["--cameras", "5", "--width", "400", "--height", "300", "--hfov", "30", "--overlap", "0.35"]),
            dict(name="newspaper-4cam", photo=os.path.join(SHARED, "images/eadcat_apap_demo/demo1/newspaper01.jpg"),
                 args=["--cameras", "4", "--width", "320", "--height", "400", "--hfov", "30", "--overlap", "0.35"]),
        ]
    return [r for r in out if os.path.exists(r["photo"])]


def clips(shared):
    """Real clips: (name, files)."""
    out = [dict(name="limlight-2cam", files=[os.path.join(ROOT, "data/limlight_2cam_apartment", f)
                                             for f in ("left.mp4", "right.mp4")])]
    if shared:
        house = os.path.join(SHARED, "video/karthik_3cam_house")
        out.append(dict(name="house-3cam", files=[os.path.join(house, f + ".mp4") for f in ("left", "middle", "right")]))
    return [c for c in out if all(os.path.exists(f) for f in c["files"])]


def run(cmd, log):
    t0 = time.time()
    with open(log, "w") as f:
        r = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, env=dict(os.environ))
    if r.returncode != 0:
        print("  failed (%s): %s" % (log, " ".join(cmd)), flush=True)
    return r.returncode == 0, time.time() - t0


def run_stitchers(build, files, work, frames, rough_rig, reference):
    """Runs every stitcher on `files`; returns {name: run folder or None}."""
    runs = {}
    clip_arg = ",".join(files)
    for name, chain, blend in OURS:
        d = os.path.join(work, name)
        cmd = [os.path.join(build, "bench", "stitch-eval-chain"), "--out", d, "--clips", clip_arg,
               "--frames", str(frames), "--chain", chain, "--blend", blend, "--backend", "cpu"]
        if rough_rig:
            cmd += ["--rig", rough_rig]
        ok, _ = run(cmd, d + ".log")
        runs[name] = d if ok else None
    for name, mode in OPENCV:
        d = os.path.join(work, name)
        cmd = [os.path.join(build, "bench", "stitch-eval-opencv"), "--out", d, "--clips", clip_arg,
               "--frames", str(frames), "--mode", mode, "--warper", "plane", "--reference", str(reference)]
        ok, _ = run(cmd, d + ".log")
        runs[name] = d if ok else None
    return runs


def load_run(d, frames):
    info = json.load(open(os.path.join(d, "run.json")))
    images, valid = [], []
    for t in range(frames):
        p = os.path.join(d, "pano_%04d.png" % t)
        img = cv2.imread(p, cv2.IMREAD_UNCHANGED) if os.path.exists(p) else None
        if img is None:
            images.append(None)
            valid.append(None)
            continue
        bgr = img[:, :, :3].copy()
        v = (img[:, :, 3] > 0) & (bgr.max(axis=2) > 0)
        v = cv2.erode(v.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0  # no interpolated borders
        images.append(bgr)
        valid.append(v)
    return info, images, valid


def rig_homographies(path):
    rig = json.load(open(path))
    Hs = [np.array(c["homography"], np.float64).reshape(3, 3) for c in rig["cameras"]]
    sizes = [(c["width"], c["height"]) for c in rig["cameras"]]
    return rig, Hs, sizes


def camera_to_reference(run_dir, info, reference, frame):
    """The stitcher's camera->reference homographies at `frame` (ours: its saved calibration)."""
    if info["stitcher"] == "gst-stitch":
        _, Hs, _ = rig_homographies(os.path.join(run_dir, "calib.json"))
        return metrics.to_reference(Hs, reference)
    per_frame = info.get("homographies_to_reference") or []
    if frame < len(per_frame) and per_frame[frame]:
        return [np.array(h, np.float64).reshape(3, 3) if h else None for h in per_frame[frame]]
    return None


def registrations(images, valid, target_features, fixed):
    """Per frame, the homography output -> target frame. Outputs whose geometry is fixed after
    calibration are registered once (on the first settled frame); per-frame outputs every frame."""
    Hs = [None] * len(images)
    if fixed:
        order = [t for t in range(SETTLE, len(images)) if images[t] is not None]
        order += [t for t in range(min(SETTLE, len(images))) if images[t] is not None]
        for t in order:
            H = metrics.register(images[t], valid[t], target_features)
            if H is not None:
                return [H if images[k] is not None else None for k in range(len(images))]
        return Hs
    for t, img in enumerate(images):
        if img is not None:
            Hs[t] = metrics.register(img, valid[t], target_features)
    return Hs


def warp(img, H, size, nearest=False):
    return cv2.warpPerspective(img, H, size, flags=cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def mask_into(mask, H_out_to_target, out_shape):
    """A target-frame mask in an output's own pixels."""
    m = warp(mask.astype(np.uint8), np.linalg.inv(H_out_to_target), (out_shape[1], out_shape[0]), nearest=True)
    return m > 0


def frame_flicker(images, valid, regs, static_target, t):
    """Flicker between output frames t-1 and t, in the output's own pixels, on the pixels
    that are static in the target frame and valid in both outputs."""
    if images[t] is None or images[t - 1] is None or regs[t] is None:
        return float("nan")
    m = mask_into(static_target, regs[t], images[t].shape) & valid[t]
    h = min(m.shape[0], valid[t - 1].shape[0])
    w = min(m.shape[1], valid[t - 1].shape[1])
    m = m[:h, :w] & valid[t - 1][:h, :w]
    return metrics.flicker([images[t - 1], images[t]], m)[0]


def nanmean(values):
    v = [x for x in values if x is not None and not math.isnan(x)]
    return float(np.mean(v)) if v else float("nan")


def coverage_count(Hs, sizes, shape):
    count = np.zeros(shape, np.int32)
    for H, (w, h) in zip(Hs, sizes):
        count += warp(np.ones((h, w), np.uint8), H, (shape[1], shape[0]), nearest=True)
    return count


def seam_centres(Hs, sizes, shape):
    """The middle of each overlap of horizontal neighbours (cameras ordered by where they land)."""
    centres = []
    order = sorted(range(len(Hs)), key=lambda i: Hs[i][0, 2])
    for a, b in zip(order, order[1:]):
        pair = (warp(np.ones(sizes[a][::-1], np.uint8), Hs[a], (shape[1], shape[0]), True) > 0) & \
               (warp(np.ones(sizes[b][::-1], np.uint8), Hs[b], (shape[1], shape[0]), True) > 0)
        ys, xs = np.nonzero(pair)
        if len(xs):
            centres.append((int(np.median(xs)), int(np.median(ys))))
    return centres


def seam_crops(seams, rows, out_png, crop):
    """Side-by-side crops around each seam: one row per seam, one column per stitcher."""
    tiles = []
    for cx, cy in seams:
        row = []
        for label, img in rows:
            h, w = img.shape[:2]
            x0 = int(np.clip(cx - crop // 2, 0, max(0, w - crop)))
            y0 = int(np.clip(cy - crop // 2, 0, max(0, h - crop)))
            tile = np.zeros((crop + 22, crop, 3), np.uint8)
            part = img[y0:y0 + crop, x0:x0 + crop]
            tile[22:22 + part.shape[0], :part.shape[1]] = part
            cv2.putText(tile, label, (3, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
            row.append(tile)
            row.append(np.zeros((crop + 22, 4, 3), np.uint8))
        tiles.append(np.hstack(row[:-1]))
        tiles.append(np.zeros((4, tiles[-1].shape[1], 3), np.uint8))
    if tiles:
        cv2.imwrite(out_png, np.vstack(tiles[:-1]))


def plot(series, ylabel, title, path):
    plt.figure(figsize=(7, 3.2))
    for label, values in series:
        plt.plot(range(len(values)), values, label=label, linewidth=1.2)
    plt.xlabel("frame")
    plt.ylabel(ylabel)
    plt.title(title)
    plt.grid(alpha=0.3)
    plt.legend(fontsize=7, ncol=3)
    plt.tight_layout()
    plt.savefig(path, dpi=110)
    plt.close()


def evaluate_rig(rig, build, report, frames):
    name = rig["name"]
    work = os.path.join(report, "work", name)
    render_dir = os.path.join(work, "rig")
    os.makedirs(work, exist_ok=True)
    step = max(2, (2 * frames) // 3)
    ok, _ = run([os.path.join(build, "tests", "stitch-render-rig"), "--photo", rig["photo"], "--out", render_dir,
                 "--frames", str(frames), "--ground-truth", "all", "--illumination-step", str(step)] + rig["args"],
                os.path.join(work, "render.log"))
    if not ok:
        return None
    truth, H_true, sizes = rig_homographies(os.path.join(render_dir, "rig_true.json"))
    reference = truth["reference"]
    true_to_ref = metrics.to_reference(H_true, reference)
    n = len(H_true)
    files = [os.path.join(render_dir, "cam%d.avi" % i) for i in range(n)]
    gts, gt_valid = [], []
    for t in range(frames):
        g = cv2.imread(os.path.join(render_dir, "gt_%04d.png" % t), cv2.IMREAD_UNCHANGED)
        gts.append(g[:, :, :3].copy())
        gt_valid.append(g[:, :, 3] > 0)
    shape = gts[0].shape[:2]
    band = (coverage_count(H_true, sizes, shape) >= 2) & gt_valid[0]
    # Static: the true panorama does not change there between two frames (the disc and the
    # illumination step are the only changes), with a margin around what moved.
    static = [None]
    for t in range(1, frames):
        moved = (gts[t] != gts[t - 1]).any(axis=2).astype(np.uint8)
        moved = cv2.dilate(moved, np.ones((7, 7), np.uint8))
        static.append((moved == 0) & gt_valid[t])
    gt_features = metrics.features(gts[0], gt_valid[0])

    runs = run_stitchers(build, files, work, frames, os.path.join(render_dir, "rig_rough.json"), reference)
    results, psnr_series, flicker_series, registered_mid = {}, [], [], {}
    mid = min(frames - 1, max(SETTLE, step - 2))
    for sname, d in runs.items():
        if d is None:
            results[sname] = dict(error="the stitcher did not run (see work/%s/%s.log)" % (name, sname))
            continue
        info, images, valid = load_run(d, frames)
        fixed = not (info["stitcher"] == "opencv" and info["mode"] == "per-frame")
        regs = registrations(images, valid, gt_features, fixed)
        psnr_t, ssim_t, psnr_overlap_t, seam_t, coverage_t = [], [], [], [], []
        for t in range(frames):
            if images[t] is None or regs[t] is None:
                psnr_t.append(float("nan"))
                continue
            size = (shape[1], shape[0])
            reg = warp(images[t], regs[t], size)
            reg_valid = warp(valid[t].astype(np.uint8), regs[t], size, nearest=True) > 0
            m = reg_valid & gt_valid[t]
            psnr_t.append(metrics.psnr(reg, gts[t], m))
            ssim_t.append(metrics.ssim(reg, gts[t], m))
            psnr_overlap_t.append(metrics.psnr(reg, gts[t], m & band))
            seam_t.append(metrics.seam_visibility(reg, gts[t], m & band))
            coverage_t.append(float(m.sum()) / float(gt_valid[t].sum()))
            if t == mid:
                registered_mid[sname] = reg
        fl = [float("nan")] + [frame_flicker(images, valid, regs, static[t], t) for t in range(1, frames)]
        errors = []
        for t in range(frames):
            est = camera_to_reference(d, info, reference, t)
            if est is not None and images[t] is not None:
                errors.append(metrics.corner_error(est, true_to_ref, sizes, reference)[0])
            if info["stitcher"] == "gst-stitch":
                break
        results[sname] = dict(
            psnr_db=nanmean(psnr_t), ssim=nanmean(ssim_t), psnr_overlap_db=nanmean(psnr_overlap_t),
            seam_visibility=nanmean(seam_t), corner_error_px=nanmean(errors), flicker=nanmean(fl[1:]),
            flicker_after_step=nanmean(fl[step:min(frames, step + 3)]),
            coverage=nanmean(coverage_t), ms_per_frame=info["ms_per_frame"], failures=info.get("failures", 0),
            frames=frames)
        psnr_series.append((sname, psnr_t))
        flicker_series.append((sname, fl))
        print("  %-18s PSNR %6.2f dB  SSIM %.4f  seam %.2f  corner %.2f px  flicker %.2f  %.1f ms/frame" % (
            sname, results[sname]["psnr_db"], results[sname]["ssim"], results[sname]["seam_visibility"],
            results[sname]["corner_error_px"], results[sname]["flicker"], info["ms_per_frame"]), flush=True)
    plot(psnr_series, "PSNR vs ground truth (dB)", "%s: per-frame PSNR (illumination step at frame %d)" % (name, step),
         os.path.join(report, "psnr_%s.png" % name))
    plot(flicker_series, "flicker (mean |dY|, static pixels)", "%s: flicker over time" % name,
         os.path.join(report, "flicker_%s.png" % name))
    rows = [("ground truth", gts[mid])] + [(s, registered_mid[s]) for s in registered_mid]
    seam_crops(seam_centres(H_true, sizes, shape), rows, os.path.join(report, "seams_%s.png" % name),
               crop=min(200, shape[0] // 2))
    return dict(kind="ground-truth rig", cameras=n, camera_size=list(sizes[0]), frames=frames,
                illumination_step=step, canvas=[shape[1], shape[0]], stitchers=results)


def read_inputs(files, frames):
    out = []
    caps = [cv2.VideoCapture(f) for f in files]
    for _ in range(frames):
        row = []
        for c in caps:
            ok, f = c.read()
            if not ok:
                return out
            row.append(f)
        out.append(row)
    return out


def evaluate_clip(clip, build, report, frames):
    name = clip["name"]
    work = os.path.join(report, "work", name)
    os.makedirs(work, exist_ok=True)
    inputs = read_inputs(clip["files"], frames)
    frames = len(inputs)
    n = len(clip["files"])
    reference = n // 2
    runs = run_stitchers(build, clip["files"], work, frames, None, reference)
    if runs.get("ours") is None:
        return None
    # Static camera pixels: the input hardly changes there over the clip (cameras are fixed;
    # codec noise stays under the thresholds).
    static_cam = []
    for i in range(n):
        stack = np.stack([metrics.luma(inputs[t][i]) for t in range(frames)])
        static_cam.append((stack.std(axis=0) < 2.5) & (np.abs(np.diff(stack, axis=0)).max(axis=0) < 12))
    ref_info, ref_images, ref_valid = load_run(runs["ours"], frames)
    _, ours_H, sizes = rig_homographies(os.path.join(runs["ours"], "calib.json"))
    shape = ref_images[SETTLE if frames > SETTLE else 0].shape[:2]
    covered = coverage_count(ours_H, sizes, shape)
    moving = np.zeros(shape, np.int32)
    for H, (w, h), s in zip(ours_H, sizes, static_cam):
        moving += warp((~s).astype(np.uint8), H, (shape[1], shape[0]), nearest=True)
    canvas_static = (covered > 0) & (moving == 0)
    canvas_static = cv2.erode(canvas_static.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    target_t = SETTLE if frames > SETTLE else 0
    target_features = metrics.features(ref_images[target_t], ref_valid[target_t])
    results, flicker_series, registered_mid = {}, [], {}
    mid = frames // 2
    for sname, d in runs.items():
        if d is None:
            results[sname] = dict(error="the stitcher did not run (see work/%s/%s.log)" % (name, sname))
            continue
        info, images, valid = load_run(d, frames)
        fixed = not (info["stitcher"] == "opencv" and info["mode"] == "per-frame")
        if info["stitcher"] == "gst-stitch":
            regs = [np.eye(3) if img is not None else None for img in images]  # the same canvas as "ours"
            if images[target_t] is not None and images[target_t].shape[:2] != shape:
                regs = registrations(images, valid, target_features, True)
        else:
            regs = registrations(images, valid, target_features, fixed)
        fl = [float("nan")] + [frame_flicker(images, valid, regs, canvas_static, t) for t in range(1, frames)]
        if images[mid] is not None and regs[mid] is not None:
            registered_mid[sname] = warp(images[mid], regs[mid], (shape[1], shape[0]))
        # The calibration at the target frame, else at the first frame that has one.
        candidates = (camera_to_reference(d, info, reference, t) for t in [target_t] + list(range(frames)))
        est = next((h for h in candidates if h is not None), None)
        align, matches = (metrics.alignment(inputs[target_t], est) if est is not None and all(h is not None for h in est)
                          else (float("nan"), 0))
        results[sname] = dict(alignment_px=align, alignment_matches=matches, flicker=nanmean(fl[1:]),
                              ms_per_frame=info["ms_per_frame"], failures=info.get("failures", 0), frames=frames)
        flicker_series.append((sname, fl))
        print("  %-18s alignment %.2f px (%d)  flicker %.2f  %.1f ms/frame  failures %d" % (
            sname, align, matches, results[sname]["flicker"], info["ms_per_frame"], results[sname]["failures"]),
            flush=True)
    plot(flicker_series, "flicker (mean |dY|, static pixels)", "%s: flicker over time" % name,
         os.path.join(report, "flicker_%s.png" % name))
    seam_crops(seam_centres(ours_H, sizes, shape), list(registered_mid.items()),
               os.path.join(report, "seams_%s.png" % name), crop=min(200, shape[0] // 2))
    return dict(kind="real clip", cameras=n, camera_size=[int(inputs[0][0].shape[1]), int(inputs[0][0].shape[0])],
                frames=frames, stitchers=results)


def fmt(v, digits=2, unit=""):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "–"
    if isinstance(v, float) and math.isinf(v):
        return "∞"
    return ("%." + str(digits) + "f%s") % (v, unit)


def speed_ratio(base_ms, v):
    """OpenCV per-frame time / this stitcher's; None when the stitcher did not run."""
    if "error" in v:
        return None
    return base_ms / v["ms_per_frame"] if base_ms and base_ms > 0 and v["ms_per_frame"] > 0 else float("nan")


def write_report(report, results, args, elapsed):
    lines = ["# Evaluation report", "",
             "Made by `scripts/evaluate.sh` (bench/eval/evaluate.py) in %.0f s; %d frames per dataset; "
             "all stitchers on this machine's CPU (%d cores)." % (elapsed, args.frames, os.cpu_count()), "",
             "Stitchers: **ours** = `stitchcolor ! stitchflowwarp ! stitchblend` (defaults; calibrated by "
             "`stitchcalib` from the rough rig on ground-truth rigs, from the images alone on real clips); "
             "ablations without stitchcolor, without stitchflowwarp, and without both (blend only); "
             "the chain with `stitchblend mode=multiband` and with `mode=multiband seam=dp`; "
             "**opencv-per-frame** = `cv::Stitcher::stitch()` on every frame set (the paper's AutoStitch "
             "baseline), **opencv-once** = `estimateTransform()` on the first frame set then "
             "`composePanorama()` on each; both PANORAMA mode with SIFT features and the plane warper "
             "(the scene model of these rigs).", "",
             "Metrics: PSNR/SSIM against the ground-truth panorama (the scene as the reference camera "
             "sees it) after registering each output to the true canvas by SIFT + RANSAC homography (once "
             "for outputs with fixed geometry, every frame for per-frame stitching); *overlap PSNR* and "
             "*seam visibility* (mean |Sobel gradient difference| to the truth, grey levels) on pixels "
             "two or more cameras see; *corner error*: the cameras' corners mapped into the reference "
             "camera by the estimated vs the true homographies (px); *flicker*: mean |ΔY| between "
             "consecutive output frames on pixels whose scene does not change (lower is better; the "
             "cameras' sensor noise sets a floor); *alignment* (real clips): median distance, in "
             "reference-camera pixels, between the two ends of independently matched SIFT features "
             "(fundamental-matrix RANSAC) under each stitcher's calibration; *speed ×*: OpenCV per-frame "
             "time / this stitcher's time.", ""]
    for name, r in results.items():
        if r is None:
            lines += ["## %s" % name, "", "Could not be evaluated (see work/%s)." % name, ""]
            continue
        s = r["stitchers"]
        base_ms = s.get(BASELINE, {}).get("ms_per_frame")
        lines += ["## %s (%s: %d cameras of %dx%d, %d frames%s)" % (
            name, r["kind"], r["cameras"], r["camera_size"][0], r["camera_size"][1], r["frames"],
            ", illumination step at frame %d" % r["illumination_step"] if "illumination_step" in r else ""), ""]
        if r["kind"] == "ground-truth rig":
            lines += ["| stitcher | PSNR dB | SSIM | overlap PSNR dB | seam visibility | corner error px | flicker "
                      "| flicker after step | coverage | ms/frame | speed × | failed frames |",
                      "|---|---|---|---|---|---|---|---|---|---|---|---|"]
            for sname, v in s.items():
                speed = speed_ratio(base_ms, v)
                if speed is None:
                    lines.append("| %s | %s |" % (sname, v["error"]))
                    continue
                lines.append("| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %d |" % (
                    sname, fmt(v["psnr_db"]), fmt(v["ssim"], 4), fmt(v["psnr_overlap_db"]), fmt(v["seam_visibility"]),
                    fmt(v["corner_error_px"]), fmt(v["flicker"]), fmt(v["flicker_after_step"]), fmt(v["coverage"], 3),
                    fmt(v["ms_per_frame"], 1), fmt(speed, 1), v["failures"]))
            lines += ["", "![per-frame PSNR](psnr_%s.png)" % name]
        else:
            lines += ["| stitcher | alignment px (matches) | flicker | ms/frame | speed × | failed frames |",
                      "|---|---|---|---|---|---|"]
            for sname, v in s.items():
                speed = speed_ratio(base_ms, v)
                if speed is None:
                    lines.append("| %s | %s |" % (sname, v["error"]))
                    continue
                lines.append("| %s | %s (%d) | %s | %s | %s | %d |" % (
                    sname, fmt(v["alignment_px"]), v["alignment_matches"], fmt(v["flicker"]),
                    fmt(v["ms_per_frame"], 1), fmt(speed, 1), v["failures"]))
        lines += ["", "![flicker over time](flicker_%s.png)" % name, "",
                  "Seams (middle frame; columns: %s):" % ", ".join(
                      (["ground truth"] if r["kind"] == "ground-truth rig" else []) + list(s.keys())), "",
                  "![seam crops](seams_%s.png)" % name, ""]
    lines += targets(results)
    open(os.path.join(report, "report.md"), "w").write("\n".join(lines) + "\n")


def targets(results):
    """The issue's targets, checked on every dataset."""
    lines = ["## Targets", "", "| dataset | ours PSNR > OpenCV per-frame | ours flicker < OpenCV per-frame "
             "| ours ≥ 20× faster on the CPU |", "|---|---|---|---|"]
    for name, r in results.items():
        if r is None:
            continue
        s = r["stitchers"]
        o, b = s.get("ours", {}), s.get(BASELINE, {})
        if "ms_per_frame" not in o or "ms_per_frame" not in b:
            continue
        if b["ms_per_frame"] <= 0:
            lines.append("| %s | OpenCV failed on every frame (%d of %d) | – | – |" % (name, b["failures"], b["frames"]))
            continue

        def verdict(ok, a, c, unit):
            return "%s (%s vs %s%s)" % ("yes" if ok else "**no**", fmt(a), fmt(c), unit)

        psnr = verdict(o["psnr_db"] > b["psnr_db"], o["psnr_db"], b["psnr_db"], " dB") if "psnr_db" in o else "n/a"
        flick = verdict(o["flicker"] < b["flicker"], o["flicker"], b["flicker"], "")
        ratio = b["ms_per_frame"] / o["ms_per_frame"]
        speed = "%s (%.1f×)" % ("yes" if ratio >= 20 else "**no**", ratio)
        lines.append("| %s | %s | %s | %s |" % (name, psnr, flick, speed))
    return lines + [""]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "eval"))
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--only", default="", help="comma-separated dataset names")
    ap.add_argument("--no-shared", action="store_true", help="only the repository's own data")
    ap.add_argument("--report-only", action="store_true", help="rewrite report.md from OUT/results.json")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=CHAIN[|BLEND]",
                    help="another configuration of our chain, e.g. 'smooth=stitchcolor smoothing=0.95 ! "
                         "stitchflowwarp' (CHAIN: elements between stitchcalib and stitchblend; BLEND: "
                         "stitchblend properties)")
    args = ap.parse_args()
    for v in args.variant:
        name, _, spec = v.partition("=")
        chain, _, blend = spec.partition("|")
        if not name or not spec:
            ap.error("--variant needs NAME=CHAIN[|BLEND]")
        OURS.append((name.strip(), chain.strip(), blend.strip()))
    if args.frames < SETTLE + 3:
        ap.error("--frames must be at least %d" % (SETTLE + 3))
    os.environ["GST_PLUGIN_PATH"] = os.path.join(args.build, "gst")
    os.environ.setdefault("GST_REGISTRY", os.path.join(args.build, "eval-registry.bin"))
    if args.report_only:
        saved = json.load(open(os.path.join(args.out, "results.json")))
        args.frames = saved["frames"]
        write_report(args.out, saved["datasets"], args, saved["seconds"])
        return 0
    shared = os.path.isdir(SHARED) and not args.no_shared
    only = set(filter(None, args.only.split(",")))
    if os.path.isdir(os.path.join(args.out, "work")):
        shutil.rmtree(os.path.join(args.out, "work"))
    os.makedirs(args.out, exist_ok=True)
    t0 = time.time()
    results = {}
    for rig in rigs(shared):
        if only and rig["name"] not in only:
            continue
        print("%s (ground-truth rig)" % rig["name"], flush=True)
        results[rig["name"]] = evaluate_rig(rig, args.build, args.out, args.frames)
    for clip in clips(shared):
        if only and clip["name"] not in only:
            continue
        print("%s (real clip)" % clip["name"], flush=True)
        results[clip["name"]] = evaluate_clip(clip, args.build, args.out, args.frames)
    elapsed = time.time() - t0
    json.dump(dict(frames=args.frames, seconds=elapsed, datasets=results), open(os.path.join(args.out, "results.json"), "w"),
              indent=1, default=lambda x: None)
    write_report(args.out, results, args, elapsed)
    print("report: %s (%.0f s)" % (os.path.join(args.out, "report.md"), elapsed))
    return 0 if results and all(r is not None for r in results.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
