#!/usr/bin/env python3
"""Parallax rigs: near objects in front of a background at infinity, and the ghost ratio.

The rig: N pinhole cameras (width x height, hfov) whose centres lie on a horizontal ring
(adjacent centres `baseline` metres apart) and whose yaws are spaced so neighbours overlap by
`overlap`; the background is a real photo at infinity (pure rotation between the cameras, so
the true homographies align it exactly); in every overlap stands a near object: a textured
planar rectangle facing the ring centre at `distance` metres, moving across the seam over the
frames. A point at distance Z appears in two neighbours' warped views about baseline * f / Z
pixels apart: the parallax no homography can remove.

Written per rig (render): camK_NNNN.png (lossless frames), rig_true.json (the exact rotations,
centres and homographies; canvas = the reference camera's image plane), gt_NNNN.png (truth:
the scene seen from the ring centre on the canvas, alpha 0 where no camera sees),
bg_NNNN.png (the truth without the near objects) and scene.json (cameras, canvas, objects per
frame) for the metrics.

Ghost ratio (metric): for sample points on the near objects' edges in the truth, the point's
copies in the canvas are where each camera's homography puts it (q_a, q_b: |q_a - q_b| is the
disparity). Along the line through the copies, extended by a margin, the truth's 11x11 patch
around the point is matched (normalised cross-correlation) against the output at every pixel;
the point appears twice when the NCC profile has two peaks above 0.5 at least 4 px apart. The
ghost ratio is the share of the points found at least once that are found twice. Distant
ghosts: the same test on background edge points near the objects, along the same line (the
homography puts both copies of a background point on the same pixel, so any second peak is a
copy the local warp made). Also: PSNR against the truth on the background (outside every
copy of the objects, dilated by 3 px; and from 15 px away) of the overlaps and of the whole
canvas, and flicker (mean
|dY| between consecutive frames on pixels whose truth did not change).

usage: parallax.py [--out DIR] [--build DIR] [--frames 20] [--seeds 1,2,3]
                   [--rigs default|all|NAME,...] [--chains NAME,...] [--variant NAME=CHAIN|BLEND] [--floor]

--floor also scores two outputs that take every pixel from one camera (no blend, no cut inside
an overlap): the ghost ratio a blend that shows each near object whole from one view can reach
(BENCHMARKS.md "Parallax: a per-object view choice").
"""
import argparse
import json
import math
import os
import subprocess
import sys
import time

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import metrics  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))

# (name, elements between stitchcalib and stitchblend, stitchblend properties)
CHAINS = [
    ("homography", "", "seam=none"),  # the paper's weighted mean (explicit: seam=dp is the default now)
    ("flowwarp", "stitchflowwarp flow=true", "seam=none"),  # the old default chain
    ("multiband-dp", "", "mode=multiband seam=dp"),
    ("flowwarp-multiband-dp", "stitchflowwarp flow=true", "mode=multiband seam=dp"),
    ("consensus", "", "seam=dp"),  # the weighted mean where the views agree, the seam's view where not
]

# Rigs: the (3 x 640x480, 1.5 m, ~33 px) and harder/easier ones.
RIGS = {
    "issue": dict(cameras=3, width=640, height=480, hfov=50, overlap=0.35, baseline=0.072, distance=1.5),
    "near": dict(cameras=3, width=640, height=480, hfov=50, overlap=0.35, baseline=0.05, distance=0.7),
    "wide": dict(cameras=3, width=640, height=480, hfov=50, overlap=0.35, baseline=0.2, distance=3.0),
    "2cam-far": dict(cameras=2, width=640, height=480, hfov=55, overlap=0.4, baseline=0.1, distance=2.5),
    # the extremes: 0.5 m objects (5 cm, ~69 px) and a 20 cm baseline at 1 m (~137 px)
    "close": dict(cameras=3, width=640, height=480, hfov=50, overlap=0.35, baseline=0.05, distance=0.5),
    "wide-near": dict(cameras=3, width=640, height=480, hfov=50, overlap=0.4, baseline=0.2, distance=1.0),
}


# ---------------------------------------------------------------------------------------------
# Geometry

def rot_y(deg):
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def intrinsics(width, height, hfov):
    f = (width / 2.0) / math.tan(math.radians(hfov) / 2)
    return np.array([[f, 0, (width - 1) / 2.0], [0, f, (height - 1) / 2.0], [0, 0, 1]])


def make_scene(p, seed, frames, photo_shape, texture_shape):
    """Cameras, canvas and the objects' poses per frame (plain numbers, JSON-able)."""
    rng = np.random.default_rng(seed)
    n, w, h = p["cameras"], p["width"], p["height"]
    step = p["hfov"] * (1 - p["overlap"])
    ref = n // 2
    yaws = [(i - ref) * step for i in range(n)]
    # Centres on a ring of radius r around the origin, adjacent ones `baseline` apart.
    r = p["baseline"] / (2 * math.sin(math.radians(step) / 2))
    K = intrinsics(w, h, p["hfov"])
    cams = []
    for y in yaws:
        R = rot_y(y)
        C = R @ np.array([0.0, 0.0, r])
        cams.append(dict(yaw=y, R=R, C=C, K=K))
    # Canvas: the reference camera's image plane, shifted to cover every view.
    Rref = cams[ref]["R"]
    pts = []
    border = [(x, 0) for x in np.linspace(0, w - 1, 33)] + [(x, h - 1) for x in np.linspace(0, w - 1, 33)] + \
             [(0, y) for y in np.linspace(0, h - 1, 25)] + [(w - 1, y) for y in np.linspace(0, h - 1, 25)]
    for c in cams:
        G = K @ Rref.T @ c["R"] @ np.linalg.inv(K)
        q = np.array([[x, y, 1.0] for x, y in border]) @ G.T
        pts.append(q[:, :2] / q[:, 2:3])
    pts = np.vstack(pts)
    lo = np.floor(pts.min(axis=0))
    size = np.ceil(pts.max(axis=0) - lo).astype(int) + 1
    T = np.array([[1, 0, -lo[0]], [0, 1, -lo[1]], [0, 0, 1.0]])
    for c in cams:
        H = T @ K @ Rref.T @ c["R"] @ np.linalg.inv(K)
        c["H"] = H / H[2, 2]
    Kc = T @ K  # canvas pixel q <-> ray Rref Kc^-1 q from the ring centre
    # The photo at infinity: a pinhole of the canvas's orientation whose field spans the canvas
    # with 5% to spare on each side.
    ph, pw = photo_shape[:2]
    sx = 0.9 * pw / size[0]
    sy = min(sx, 0.9 * ph / size[1])
    s = min(sx, sy)
    P = np.array([[s, 0, pw / 2.0 - s * size[0] / 2.0], [0, s, ph / 2.0 - s * size[1] / 2.0], [0, 0, 1]]) @ Kc
    # One near object per overlap, sweeping across the seam; texture crops chosen by the seed.
    objects = []
    th, tw = texture_shape[:2]
    for i in range(n - 1):
        mid = 0.5 * (yaws[i] + yaws[i + 1])
        amp = 0.5 * p["hfov"] * p["overlap"] * (0.7 + 0.3 * rng.random())
        phase = rng.uniform(0, 2 * math.pi)
        ow = p.get("object_width", 0.38) * p["distance"] / 1.5 * (0.85 + 0.3 * rng.random())
        oh = ow * (1.2 + 0.4 * rng.random())
        dz = p["distance"] * (1 + 0.1 * (rng.random() - 0.5))
        crop_w = int(tw * 0.45)
        crop_h = min(th - 1, int(crop_w * oh / ow))
        cx0 = int(rng.integers(0, tw - crop_w))
        cy0 = int(rng.integers(0, max(1, th - crop_h)))
        lift = rng.uniform(-0.15, 0.15) * p["distance"]
        poses = []
        for t in range(frames):
            u = 2.0 * t / max(1, frames - 1) - 1.0  # -1 .. 1: one sweep
            yaw = mid + amp * math.sin(0.5 * math.pi * u + 0.3 * math.sin(phase))
            d = rot_y(yaw) @ np.array([0.0, 0.0, 1.0])
            centre = d * dz + np.array([0.0, lift, 0.0])
            n_vec = -d  # faces the ring centre
            ex = np.array([n_vec[2], 0.0, -n_vec[0]])
            ex /= np.linalg.norm(ex)
            if ex @ (rot_y(yaw) @ np.array([1.0, 0, 0])) < 0:
                ex = -ex
            poses.append(dict(centre=centre.tolist(), normal=n_vec.tolist(), ex=ex.tolist(), ey=[0.0, 1.0, 0.0]))
        objects.append(dict(width=ow, height=oh, crop=[cx0, cy0, crop_w, crop_h], poses=poses))
    return dict(reference=ref, canvas=[int(size[0]), int(size[1])], Kc=Kc.tolist(), Rref=Rref.tolist(),
                photo_camera=P.tolist(),
                cameras=[dict(yaw=c["yaw"], R=c["R"].tolist(), C=c["C"].tolist(), K=c["K"].tolist(),
                              H=c["H"].tolist(), width=w, height=h) for c in cams],
                objects=objects)


def rays(K, R, width, height, ss):
    xs = (np.arange(width * ss) + 0.5) / ss - 0.5
    ys = (np.arange(height * ss) + 0.5) / ss - 0.5
    X, Y = np.meshgrid(xs, ys)
    pix = np.stack([X, Y, np.ones_like(X)], axis=-1)
    d = pix @ (R @ np.linalg.inv(K)).T
    return d


def render(scene, K, R, C, width, height, photo, textures, t, with_objects=True, ss=2):
    """One view (BGR) and the coverage of each object (float 0..1), supersampled ss x ss."""
    d = rays(np.asarray(K), np.asarray(R), width, height, ss)
    P = np.asarray(scene["photo_camera"]) @ np.asarray(scene["Rref"]).T
    q = d @ P.T
    mx = (q[..., 0] / q[..., 2]).astype(np.float32)
    my = (q[..., 1] / q[..., 2]).astype(np.float32)
    img = cv2.remap(photo, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT).astype(np.float32)
    zbuf = np.full(d.shape[:2], np.inf)
    cover = []
    C = np.asarray(C, np.float64)
    for k, ob in enumerate(scene["objects"]):
        m = np.zeros(d.shape[:2], np.float32)
        if with_objects:
            pose = ob["poses"][t]
            n = np.asarray(pose["normal"])
            P0 = np.asarray(pose["centre"])
            ex, ey = np.asarray(pose["ex"]), np.asarray(pose["ey"])
            denom = d @ n
            with np.errstate(divide="ignore", invalid="ignore"):
                s = ((P0 - C) @ n) / denom
            X = C + s[..., None] * d
            a = (X - P0) @ ex
            b = (X - P0) @ ey
            inside = (s > 0) & (np.abs(a) <= ob["width"] / 2) & (np.abs(b) <= ob["height"] / 2) & (s < zbuf)
            tex = textures[k]
            th, tw = tex.shape[:2]
            tx = ((a / ob["width"] + 0.5) * tw - 0.5).astype(np.float32)
            ty = ((b / ob["height"] + 0.5) * th - 0.5).astype(np.float32)
            o = cv2.remap(tex, tx, ty, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float32)
            img[inside] = o[inside]
            zbuf[inside] = s[inside]
            m[inside] = 1
        cover.append(m)
    small = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    covers = [cv2.resize(m, (width, height), interpolation=cv2.INTER_AREA) for m in cover]
    return small, covers


def load_textures(scene, texture):
    out = []
    for ob in scene["objects"]:
        x, y, w, h = ob["crop"]
        out.append(texture[y:y + h, x:x + w].copy())
    return out


def render_rig(p, seed, frames, out, photo_path, texture_path, noise=1.0):
    os.makedirs(out, exist_ok=True)
    photo = cv2.imread(photo_path)
    texture = cv2.imread(texture_path)
    if photo is None or texture is None:
        raise SystemExit("cannot read %s or %s" % (photo_path, texture_path))
    scene = make_scene(p, seed, frames, photo.shape, texture.shape)
    textures = load_textures(scene, texture)
    rng = np.random.default_rng(seed + 1000)
    W, H = scene["canvas"]
    Kc = np.asarray(scene["Kc"])
    Rref = np.asarray(scene["Rref"])
    # Where some camera sees (canvas alpha).
    seen = np.zeros((H, W), np.uint8)
    for c in scene["cameras"]:
        seen |= cv2.warpPerspective(np.full((c["height"], c["width"]), 255, np.uint8), np.asarray(c["H"]), (W, H),
                                    flags=cv2.INTER_NEAREST) > 0
    for t in range(frames):
        for i, c in enumerate(scene["cameras"]):
            img, _ = render(scene, c["K"], c["R"], c["C"], c["width"], c["height"], photo, textures, t)
            if noise > 0:
                img = img + rng.normal(0, noise, img.shape)
            cv2.imwrite(os.path.join(out, "cam%d_%04d.png" % (i, t)), np.clip(np.rint(img), 0, 255).astype(np.uint8))
        for name, objs in (("gt", True), ("bg", False)):
            if name == "bg" and t > 0:
                continue  # the background does not move
            g, covers = render(scene, Kc, Rref, [0.0, 0.0, 0.0], W, H, photo, textures, t, with_objects=objs)
            g = np.dstack([np.clip(np.rint(g), 0, 255).astype(np.uint8), (seen > 0).astype(np.uint8) * 255])
            cv2.imwrite(os.path.join(out, "%s_%04d.png" % (name, t)), g)
    rig = {"format": "stitch-rig", "version": 1, "projection": "plane", "reference": scene["reference"],
           "canvas": {"width": W, "height": H}, "cameras": []}
    for c in scene["cameras"]:
        K = np.asarray(c["K"])
        rig["cameras"].append({"width": c["width"], "height": c["height"], "fx": K[0, 0], "fy": K[1, 1],
                               "cx": K[0, 2], "cy": K[1, 2], "yaw_deg": c["yaw"], "pitch_deg": 0.0,
                               "roll_deg": 0.0, "t": c["C"], "homography": np.asarray(c["H"]).ravel().tolist()})
    json.dump(rig, open(os.path.join(out, "rig_true.json"), "w"), indent=1)
    scene["frames"] = frames
    scene["params"] = p
    scene["seed"] = seed
    json.dump(scene, open(os.path.join(out, "scene.json"), "w"))
    return scene


# ---------------------------------------------------------------------------------------------
# Metrics

def object_point(scene, ob, t, q):
    """3D points of the object (at frame t) seen at canvas pixels q (n x 2) from the ring centre;
    NaN where the ray misses it."""
    Kc, Rref = np.asarray(scene["Kc"]), np.asarray(scene["Rref"])
    pose = ob["poses"][t]
    n, P0 = np.asarray(pose["normal"]), np.asarray(pose["centre"])
    d = np.hstack([q, np.ones((len(q), 1))]) @ (Rref @ np.linalg.inv(Kc)).T
    s = (P0 @ n) / (d @ n)
    return s[:, None] * d


def canvas_copies(scene, X):
    """Per camera: canvas positions (n x 2) of the points X and whether the camera sees them."""
    out = []
    for c in scene["cameras"]:
        K, R, C, H = (np.asarray(c[k]) for k in ("K", "R", "C", "H"))
        x = (X - C) @ R  # camera frame: R^T (X - C)
        front = x[:, 2] > 1e-6
        pix = x @ K.T
        pix = pix[:, :2] / np.where(front, pix[:, 2], 1.0)[:, None]
        inside = front & (pix[:, 0] >= 0) & (pix[:, 1] >= 0) & (pix[:, 0] <= c["width"] - 1) & \
                 (pix[:, 1] <= c["height"] - 1)
        q = np.hstack([pix, np.ones((len(pix), 1))]) @ H.T
        out.append((q[:, :2] / q[:, 2:3], inside))
    return out


PATCH = 5  # half size: 11 x 11


def ncc_profiles(out_luma, truth_luma, centres, starts, ends, margin):
    """For every sample i: the NCC of the truth patch around centres[i] against the output at
    positions along the line starts[i] -> ends[i] (extended by `margin` px), 1 px apart.
    Returns (profiles n x L, valid n x L)."""
    n = len(centres)
    direction = ends - starts
    length = np.linalg.norm(direction, axis=1)
    unit = direction / np.maximum(length, 1e-9)[:, None]
    L = int(np.ceil(length.max())) + 2 * margin + 1 if n else 1
    steps = np.arange(L) - margin
    valid = steps[None, :] <= length[:, None] + margin
    pos = starts[:, None, :] + steps[None, :, None] * unit[:, None, :]  # n x L x 2
    off = np.arange(-PATCH, PATCH + 1)
    oy, ox = np.meshgrid(off, off, indexing="ij")
    ox, oy = ox.ravel().astype(np.float32), oy.ravel().astype(np.float32)
    # truth patches
    tc = np.rint(centres).astype(np.float32)
    tmx = (tc[:, 0:1] + ox[None, :]).astype(np.float32)
    tmy = (tc[:, 1:2] + oy[None, :]).astype(np.float32)
    tp = np.vstack([cv2.remap(truth_luma, tmx[k:k + 30000], tmy[k:k + 30000], cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE) for k in range(0, len(tmx), 30000)])
    tp = tp - tp.mean(axis=1, keepdims=True)
    tn = np.linalg.norm(tp, axis=1)
    # output patches along the lines
    mx = (pos[..., 0].reshape(-1, 1) + ox[None, :]).astype(np.float32)
    my = (pos[..., 1].reshape(-1, 1) + oy[None, :]).astype(np.float32)
    op = np.vstack([cv2.remap(out_luma, mx[k:k + 30000], my[k:k + 30000], cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE) for k in range(0, len(mx), 30000)]).reshape(n, L, -1)
    op = op - op.mean(axis=2, keepdims=True)
    on = np.linalg.norm(op, axis=2)
    ncc = np.einsum("nlk,nk->nl", op, tp) / np.maximum(on * tn[:, None], 1e-6)
    ncc[on < 1e-3] = 0
    return ncc, valid, tn


def count_peaks(profile, valid, threshold=0.5, separation=4, dip=0.25):
    """Peaks of one NCC profile above `threshold`, at least `separation` px apart and with a
    dip of at least `dip` below the lower of two peaks between them (one broad peak is one)."""
    p = np.where(valid, profile, -1.0)
    peaks = []
    for i in np.argsort(-p):
        if p[i] < threshold:
            break
        lo, hi = max(0, i - 1), min(len(p), i + 2)
        if p[i] < p[lo:hi].max():
            continue
        distinct = True
        for j in peaks:
            a, b = min(i, j), max(i, j)
            if b - a < separation or p[a:b + 1].min() > min(p[i], p[j]) - dip:
                distinct = False
                break
        if distinct:
            peaks.append(i)
    return len(peaks)


def sample_edges(truth_luma, mask, stride=3, max_points=600, rng=None):
    edges = cv2.Canny(np.clip(truth_luma, 0, 255).astype(np.uint8), 40, 110) > 0
    edges &= mask
    ys, xs = np.nonzero(edges)
    keep = ((xs // stride) + (ys // stride)) % 2 == 0  # thin out, keep spread
    xs, ys = xs[keep], ys[keep]
    if len(xs) > max_points:
        idx = (rng or np.random.default_rng(0)).choice(len(xs), max_points, replace=False)
        xs, ys = xs[idx], ys[idx]
    return np.stack([xs, ys], axis=1).astype(np.float64)


def copies_counted(out_l, ref_l, pts, qa, qb):
    """For sample points pts (reference-image pixels) whose two copies an output may show at
    qa and qb: (found, doubled) counts. Only distinctive samples count: those whose reference
    patch matches the reference itself exactly once along the same direction over twice the
    span (no repeated texture, no edge parallel to the search line), and at most once along
    the output's search line."""
    if len(pts) == 0:
        return 0, 0
    span = qb - qa
    own, own_valid, tn = ncc_profiles(ref_l, ref_l, pts, pts - span, pts + span, margin=6)
    line, line_valid, _ = ncc_profiles(ref_l, ref_l, pts, qa, qb, margin=6)
    prof, valid, _ = ncc_profiles(out_l, ref_l, pts, qa, qb, margin=6)
    found = doubled = 0
    for k in range(len(pts)):
        if tn[k] < 8 * (2 * PATCH + 1) or count_peaks(own[k], own_valid[k]) != 1 or \
                count_peaks(line[k], line_valid[k]) > 1:
            continue
        c = count_peaks(prof[k], valid[k])
        found += c >= 1
        doubled += c >= 2
    return found, doubled


def ghost_stats(out_bgr, scene, t, truth_bgr, bg_bgr, rng):
    """(object samples found, doubled, background samples found, doubled) at frame t."""
    out_l = metrics.luma(out_bgr).astype(np.float32)
    tru_l = metrics.luma(truth_bgr).astype(np.float32)
    bg_l = metrics.luma(bg_bgr).astype(np.float32)
    W, H = scene["canvas"]
    found = doubled = bfound = bdoubled = 0
    ys, xs = np.mgrid[0:H, 0:W]
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    for ob in scene["objects"]:
        # the object's silhouette in the truth: pixels whose ray from the centre hits it
        X = object_point(scene, ob, t, grid)
        pose = ob["poses"][t]
        P0, ex, ey = np.asarray(pose["centre"]), np.asarray(pose["ex"]), np.asarray(pose["ey"])
        a, b = (X - P0) @ ex, (X - P0) @ ey
        sil = ((np.abs(a) <= ob["width"] / 2) & (np.abs(b) <= ob["height"] / 2)).reshape(H, W)
        if not sil.any():
            continue
        near = cv2.dilate(sil.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        pts = sample_edges(tru_l, near, rng=rng)
        if len(pts) == 0:
            continue
        copies = canvas_copies(scene, object_point(scene, ob, t, pts))
        seen = np.stack([v for _, v in copies], axis=1)
        qa = np.zeros((len(pts), 2))
        qb = np.zeros((len(pts), 2))
        two = seen.sum(axis=1) >= 2
        for i in np.nonzero(two)[0]:
            cs = [copies[c][0][i] for c in range(len(copies)) if seen[i, c]]
            qa[i], qb[i] = cs[0], cs[-1]
        sel = two & (np.linalg.norm(qb - qa, axis=1) >= 6)
        if not sel.any():
            continue
        f, d = copies_counted(out_l, tru_l, pts[sel], qa[sel], qb[sel])
        found, doubled = found + f, doubled + d
        # Distant objects beside it: background edge points near (not on) any copy of the
        # object; both copies of a point at infinity fall on the same pixel, so a second
        # match along the object's disparity is a copy the local warp made.
        disp = np.median(qb[sel] - qa[sel], axis=0)
        reach = int(np.ceil(np.linalg.norm(disp))) + 8
        around = cv2.dilate(sil.astype(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)) > 0
        footprint = object_footprint(scene, ob, t, W, H)
        around &= ~(cv2.dilate(footprint.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0)
        bpts = sample_edges(bg_l, around, max_points=300, rng=rng)
        if len(bpts):
            half = np.tile(disp / 2.0, (len(bpts), 1))
            f, d = copies_counted(out_l, bg_l, bpts, bpts - half, bpts + half)
            bfound, bdoubled = bfound + f, bdoubled + d
    return found, doubled, bfound, bdoubled


_footprints = {}


def object_footprint(scene, ob, t, W, H):
    """Canvas pixels where any camera's warped view shows the object at frame t."""
    key = (id(scene), id(ob), t)
    if key in _footprints:
        return _footprints[key]
    pose = ob["poses"][t]
    P0, ex, ey = (np.asarray(pose[k]) for k in ("centre", "ex", "ey"))
    corners = [P0 + sx * ob["width"] / 2 * ex + sy * ob["height"] / 2 * ey for sx, sy in
               ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    m = np.zeros((H, W), np.uint8)
    for q, v in canvas_copies(scene, np.asarray(corners)):
        if v.any():
            cv2.fillConvexPoly(m, np.rint(q).astype(np.int32), 1)
    _footprints[key] = m > 0
    return _footprints[key]


# Bands of distance (px) from the nearest copy of an object, for the background PSNR profile.
RINGS = [(3, 8), (8, 15), (15, 30), (30, 60), (60, 120), (120, 100000)]


def evaluate_output(run_dir, render_dir, scene, frames):
    W, H = scene["canvas"]
    rng = np.random.default_rng(7)
    bg = cv2.imread(os.path.join(render_dir, "bg_0000.png"), cv2.IMREAD_UNCHANGED)
    bg_bgr = bg[:, :, :3]
    band = np.zeros((H, W), np.int32)
    for c in scene["cameras"]:
        band += cv2.warpPerspective(np.ones((c["height"], c["width"]), np.uint8), np.asarray(c["H"]), (W, H),
                                    flags=cv2.INTER_NEAREST)
    band = band >= 2
    f = d = bf = bd = 0
    psnr_bg, psnr_bg_far, psnr_bg_all, psnr_all, flick = [], [], [], [], []
    mad_ov, ssim_ov, fields, field_masks = [], [], [], []
    ring_err = np.zeros(len(RINGS))
    ring_n = np.zeros(len(RINGS))
    base_dir = os.path.join(os.path.dirname(run_dir), "homography")
    prev = prev_t = None
    for t in range(frames):
        img = cv2.imread(os.path.join(run_dir, "pano_%04d.png" % t), cv2.IMREAD_UNCHANGED)
        g = cv2.imread(os.path.join(render_dir, "gt_%04d.png" % t), cv2.IMREAD_UNCHANGED)
        if img is None or img.shape[:2] != (H, W):
            raise SystemExit("%s: panorama %d missing or not %dx%d" % (run_dir, t, W, H))
        out = img[:, :, :3]
        valid = (img[:, :, 3] > 0) & (g[:, :, 3] > 0)
        valid = cv2.erode(valid.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
        objs = np.zeros((H, W), bool)
        for ob in scene["objects"]:
            objs |= object_footprint(scene, ob, t, W, H)
        background = valid & ~(cv2.dilate(objs.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0)
        far = valid & ~(cv2.dilate(objs.astype(np.uint8), np.ones((31, 31), np.uint8)) > 0)
        psnr_bg.append(metrics.psnr(out, g[:, :, :3], background & band))
        psnr_bg_far.append(metrics.psnr(out, g[:, :, :3], far & band))
        psnr_bg_all.append(metrics.psnr(out, g[:, :, :3], background))
        psnr_all.append(metrics.psnr(out, g[:, :, :3], valid))
        # Overlap alignment against the truth (StabStitch reports PSNR/SSIM in the overlaps).
        ov = valid & band
        mad_ov.append(float(np.abs(out.astype(np.float64) - g[:, :, :3]).mean(axis=2)[ov].mean()))
        ssim_ov.append(metrics.ssim(out, g[:, :, :3], ov))
        # Background error by distance from the objects' copies: where a halo comes from.
        dist = cv2.distanceTransform((~objs).astype(np.uint8), cv2.DIST_L2, 5)
        err = ((out.astype(np.float64) - g[:, :, :3]) ** 2).mean(axis=2)
        for k, (lo, hi) in enumerate(RINGS):
            sel = ov & (dist >= lo) & (dist < hi)
            ring_err[k] += err[sel].sum()
            ring_n[k] += sel.sum()
        # The local warp, measured against the homography-only output on the static background.
        base = cv2.imread(os.path.join(base_dir, "pano_%04d.png" % t), cv2.IMREAD_UNCHANGED)
        if base is not None and base.shape == img.shape:
            fm = far & band
            fields.append(metrics.warp_field(base[:, :, :3], out, fm))
            field_masks.append(fm)
        if t >= 1:
            a, b, c, e = ghost_stats(out, scene, t, g[:, :, :3], bg_bgr, rng)
            f, d, bf, bd = f + a, d + b, bf + c, bd + e
        if prev is not None:
            moved = (g[:, :, :3] != prev_t).any(axis=2).astype(np.uint8)
            static = (cv2.dilate(moved, np.ones((7, 7), np.uint8)) == 0) & valid
            flick.append(metrics.flicker([prev, out], static)[0])
        prev, prev_t = out, g[:, :, :3]
    warp = dict(stability=float("nan"), distortion=float("nan"), distortion_p95=float("nan"))
    if len(fields) >= 3:
        dmean, dp95 = zip(*[metrics.line_distortion(fl, fm) for fl, fm in zip(fields, field_masks)])
        warp = dict(stability=metrics.warp_stability(fields, field_masks), distortion=float(np.nanmean(dmean)),
                    distortion_p95=float(np.nanmax(dp95)))
    rings = {"%d-%d" % r: (10 * math.log10(255.0 ** 2 / (e / n)) if n and e else float("nan"))
             for r, e, n in zip(RINGS, ring_err, ring_n)}
    return dict(ghost_ratio=d / f if f else float("nan"), object_samples=f,
                mad_overlap=float(np.nanmean(mad_ov)), ssim_overlap=float(np.nanmean(ssim_ov)),
                psnr_by_distance=rings, **warp,
                distant_ghost_ratio=bd / bf if bf else float("nan"), background_samples=bf,
                psnr_overlap_background=float(np.nanmean(psnr_bg)),
                psnr_overlap_background_far=float(np.nanmean(psnr_bg_far)),
                psnr_background=float(np.nanmean(psnr_bg_all)),
                psnr=float(np.nanmean(psnr_all)), flicker=float(np.nanmean(flick)) if flick else float("nan"))


def truth_self_check(render_dir, scene, frames):
    """The metric on the truth itself (every point once): its false-positive floor."""
    f = d = bf = bd = 0
    rng = np.random.default_rng(7)
    bg = cv2.imread(os.path.join(render_dir, "bg_0000.png"))
    for t in range(1, frames):
        g = cv2.imread(os.path.join(render_dir, "gt_%04d.png" % t))
        a, b, c, e = ghost_stats(g, scene, t, g, bg, rng)
        f, d, bf, bd = f + a, d + b, bf + c, bd + e
    return dict(ghost_ratio=d / f if f else float("nan"), distant_ghost_ratio=bd / bf if bf else float("nan"))


# ---------------------------------------------------------------------------------------------

def write_single_view(render_dir, scene, frames, out_dir, first):
    """The metric's floor for outputs that take every pixel from one camera (no blend): each
    camera's frame warped by its true homography (bilinear), every overlap pixel from the
    lowest-numbered camera that sees it (first='low') or the highest ('high'). A near object then
    comes whole from one view except where it crosses an overlap's border (cut there); nothing
    is shown twice, so the ghost ratio of these outputs is what the metric finds in a single
    view's copy of the object against the ring-centre truth (resampling blur, sensor noise)."""
    os.makedirs(out_dir, exist_ok=True)
    W, H = scene["canvas"]
    order = list(range(len(scene["cameras"])))
    if first == "low":
        order.reverse()  # painted last wins
    for t in range(frames):
        out = np.zeros((H, W, 4), np.uint8)
        for i in order:
            c = scene["cameras"][i]
            img = cv2.imread(os.path.join(render_dir, "cam%d_%04d.png" % (i, t)))
            Hm = np.asarray(c["H"])
            w = cv2.warpPerspective(img, Hm, (W, H), flags=cv2.INTER_LINEAR)
            m = cv2.warpPerspective(np.full(img.shape[:2], 255, np.uint8), Hm, (W, H), flags=cv2.INTER_NEAREST)
            m = cv2.erode((m > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            out[m, :3] = w[m]
            out[m, 3] = 255
        cv2.imwrite(os.path.join(out_dir, "pano_%04d.png" % t), out)


def select_chains(chains, variants, wanted):
    """`chains` plus each --variant NAME=CHAIN[|BLEND], kept to the names in `wanted`
    (a comma-separated --chains; all when empty)."""
    chains = list(chains)
    for v in variants:
        name, _, spec = v.partition("=")
        chain, _, blend = spec.partition("|")
        chains.append((name.strip(), chain.strip(), blend.strip()))
    if wanted:
        names = wanted.split(",")
        chains = [c for c in chains if c[0] in names]
    return chains


def run_chain(build, render_dir, out_dir, frames, n, chain, blend, backend):
    clips = ",".join(os.path.join(render_dir, "cam%d_%%04d.png" % i) for i in range(n))
    cmd = [os.path.join(build, "bench", "stitch-eval-chain"), "--out", out_dir, "--clips", clips, "--frames",
           str(frames), "--chain", chain, "--blend", blend, "--backend", backend, "--calib",
           os.path.join(render_dir, "rig_true.json")]
    with open(out_dir + ".log", "w") as log:
        r = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT)
    return r.returncode == 0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "parallax"))
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--seeds", default="1")
    ap.add_argument("--rigs", default="issue")
    ap.add_argument("--chains", default="")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=CHAIN[|BLEND]")
    ap.add_argument("--backend", default="cpu")
    ap.add_argument("--photo", default=os.path.join(ROOT, "data/photos/boat1_1600.jpg"))
    ap.add_argument("--texture", default=os.path.join(ROOT, "data/photos/aero1.jpg"))
    ap.add_argument("--render-only", action="store_true")
    ap.add_argument("--reuse", action="store_true", help="keep rendered rigs that exist")
    ap.add_argument("--results", default="results.json", help="file name under --out (runs side by side)")
    ap.add_argument("--floor", action="store_true",
                    help="also score single-view outputs (single-view-low/-high: each overlap from one camera, "
                         "no blend): the ghost ratio any output showing each object from one view gets")
    args = ap.parse_args()
    chains = select_chains(CHAINS, args.variant, args.chains)
    rig_names = list(RIGS) if args.rigs == "all" else args.rigs.split(",")
    os.environ["GST_PLUGIN_PATH"] = os.path.join(args.build, "gst")
    os.environ.setdefault("GST_REGISTRY", os.path.join(args.build, "parallax-registry.bin"))
    results = {}
    t0 = time.time()
    for rname in rig_names:
        for seed in [int(s) for s in args.seeds.split(",")]:
            key = "%s-s%d" % (rname, seed)
            rd = os.path.join(args.out, key, "rig")
            if not (args.reuse and os.path.exists(os.path.join(rd, "scene.json"))):
                scene = render_rig(RIGS[rname], seed, args.frames, rd, args.photo, args.texture)
            else:
                scene = json.load(open(os.path.join(rd, "scene.json")))
            if args.render_only:
                continue
            res = {"truth": truth_self_check(rd, scene, args.frames)}
            # the homography baseline first: the warp measures compare every chain with it
            for name, chain, blend in sorted(chains, key=lambda c: c[0] != "homography"):
                od = os.path.join(args.out, key, name)
                done = os.path.exists(os.path.join(od, "pano_%04d.png" % (args.frames - 1)))
                if not (args.reuse and done) and not run_chain(args.build, rd, od, args.frames, len(scene["cameras"]), chain, blend, args.backend):
                    res[name] = dict(error="failed, see %s.log" % od)
                    continue
                res[name] = evaluate_output(od, rd, scene, args.frames)
            if args.floor:
                for first in ("low", "high"):
                    od = os.path.join(args.out, key, "single-view-" + first)
                    write_single_view(rd, scene, args.frames, od, first)
                    res["single-view-" + first] = evaluate_output(od, rd, scene, args.frames)
            results[key] = res
            for name, r in res.items():
                if "error" in r:
                    print("%-14s %-24s %s" % (key, name, r["error"]), flush=True)
                    continue
                print("%-14s %-24s ghost %.3f (%s points)  distant %.3f  PSNR bg-overlap %s (15 px away: %s)  PSNR %s  "
                      "flicker %s" % (
                    key, name, r["ghost_ratio"], r.get("object_samples", "-"), r["distant_ghost_ratio"],
                    "%.2f" % r["psnr_overlap_background"] if "psnr" in r else "-",
                    "%.2f" % r["psnr_overlap_background_far"] if "psnr" in r else "-",
                    "%.2f" % r["psnr"] if "psnr" in r else "-",
                    "%.3f" % r["flicker"] if "flicker" in r else "-"), flush=True)
                if "mad_overlap" in r:
                    print("%-14s %-24s overlap MAD %.2f SSIM %.4f  warp stability %.3f px  distortion %.3f (p95 "
                          "%.3f) px  bg PSNR by distance %s" % (
                        key, name, r["mad_overlap"], r["ssim_overlap"], r["stability"], r["distortion"],
                        r["distortion_p95"], " ".join("%s:%.1f" % kv for kv in r["psnr_by_distance"].items())),
                          flush=True)
    if results:
        json.dump(results, open(os.path.join(args.out, args.results), "w"), indent=1)
        print("%.0f s; %s" % (time.time() - t0, os.path.join(args.out, args.results)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
