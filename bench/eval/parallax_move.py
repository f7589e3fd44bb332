#!/usr/bin/env python3
"""A content-preserving move of near objects, prototyped on the rendered parallax rigs (issue 16,
item 2; task parallax-move idea 3), scored with parallax.py's metrics.

Per overlap of two neighbouring views a, b (pre-warped by their homographies, blend weights
theta_a + theta_b = 1 as stitchblend's position weights):

 1. disagreement: blur(|Y_a - Y_b|) > --disagree grey levels inside the overlap, closed;
    connected blobs larger than --min-area pixels.
 2. per blob, one displacement d (the object's parallax): the shift of view b, searched along
    the rows (the rig's baseline direction) over +-max_disparity px and +-2 rows, that matches
    the most disagreeing pixels (blur(|Y_a(p) - Y_b(p + d)|) < --match); coarse at half
    resolution, refined at full.
 3. the object's pixels in view a: disagreeing pixels that match at d (M_a), closed and with
    holes filled; in view b they lie at M_a + d.
 4. the output: the object drawn once, at q + theta_b(q) d for every q in M_a (both views meet in
    between, eq. 17 with the faded weights: at a's border a's geometry, at b's border b's), from
    both views (a at q, b at q + d, weighted by theta); the background everywhere else as the
    weighted mean of the views that see background there (a outside M_a, b outside M_b), i.e.
    the homography output wherever no object was found.
 5. --hold: d is held from the last frame of the same blob unless the new one matches clearly
    better (temporal stability).

--oracle uses the true object masks and disparities of scene.json instead of steps 1-3: what the
move itself can reach on the metric, with perfect estimation.

Writes pano_NNNN.png (RGBA) under OUT/<rig>-s<seed>/<name>/ and prints parallax.py's scores next
to the C++ chains already run there (parallax.py --reuse keeps them).

usage: parallax_move.py [--out DIR] [--rigs near,close,wide-near] [--seeds 1,2] [--frames 8]
                        [--oracle] [--name NAME]
"""
import argparse
import json
import os
import sys

import cv2
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import parallax  # noqa: E402


# Each view's background excludes its object copy widened by this window (px): the copy's
# anti-aliased edge and the mask's misses stay out of the background (STITCH_MOVE_EXCL overrides).
EXCL = int(os.environ.get("STITCH_MOVE_EXCL", "3"))


def position_weight_image(w, h):
    u = np.arange(w, dtype=np.float64)
    v = np.arange(h, dtype=np.float64)
    wx = np.minimum(u + 0.5, w - 0.5 - u) / (w * 0.5)
    wy = np.minimum(v + 0.5, h - 0.5 - v) / (h * 0.5)
    wx = np.clip(wx, 0, 1)
    wy = np.clip(wy, 0, 1)
    return (wy[:, None] * wx[None, :]).astype(np.float32)


def warp_views(scene, rd, t):
    W, H = scene["canvas"]
    views, valid, weight = [], [], []
    for i, c in enumerate(scene["cameras"]):
        img = cv2.imread(os.path.join(rd, "cam%d_%04d.png" % (i, t))).astype(np.float32)
        Hm = np.asarray(c["H"])
        views.append(cv2.warpPerspective(img, Hm, (W, H), flags=cv2.INTER_LINEAR))
        m = cv2.warpPerspective(np.full(img.shape[:2], 255, np.uint8), Hm, (W, H), flags=cv2.INTER_NEAREST)
        valid.append(cv2.erode((m > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
        pw = cv2.warpPerspective(position_weight_image(c["width"], c["height"]), Hm, (W, H), flags=cv2.INTER_LINEAR)
        weight.append(np.where(valid[-1], pw, 0).astype(np.float32))
    return views, valid, weight


def luma(img):
    return (0.114 * img[..., 0] + 0.587 * img[..., 1] + 0.299 * img[..., 2]).astype(np.float32)


def shift(img, dx, dy):
    """img sampled at p + (dx, dy) (zero outside)."""
    M = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(img, M, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT)


def estimate_blobs(ya, yb, overlap, args, max_disp, direction=None):
    """[(mask_a, dx, dy, score)] for the disagreement blobs of one overlap."""
    diff = cv2.GaussianBlur(np.abs(ya - yb), (0, 0), 2.0)
    dis = (diff > args.disagree) & overlap
    # the overlap's rim (resampling at the views' borders) disagrees a little everywhere, and
    # joins every blob to it: the tallness test below looks inside the rim only
    inner = cv2.erode(overlap.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    dis = cv2.morphologyEx(dis.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((7, 7), np.uint8))
    n, lab, stats, _ = cv2.connectedComponentsWithStats(dis, connectivity=8)
    out = []
    for k in range(1, n):
        if stats[k, cv2.CC_STAT_AREA] < args.min_area:
            continue
        blob = lab == k
        x, y, w, h = stats[k, :4]
        # A near object is a compact blob in front of an aligned background: a blob as tall as the
        # overlap itself (a whole overlap of varying depth, e.g. a corridor) is no object to move.
        rows = np.nonzero(inner[:, x:x + w].any(axis=1))[0]
        own = np.nonzero((blob & inner)[:, x:x + w].any(axis=1))[0]
        if len(rows) and len(own) and own[-1] - own[0] + 1 >= args.tallest * (rows[-1] - rows[0] + 1):
            continue
        # the search line: the epipolar direction (near points move one way only), or both ways
        # along the rows when the rig has no baseline
        ux, uy = direction if direction is not None else (1.0, 0.0)
        signs = (1,) if direction is not None else (1, -1)
        px, py = -uy, ux  # across the line
        pad = max_disp + 8
        x0, y0 = max(0, x - pad), max(0, y - int(abs(uy) * max_disp) - 8)
        x1, y1 = min(ya.shape[1], x + w + pad), min(ya.shape[0], y + h + int(abs(uy) * max_disp) + 8)
        A, B, Bm = ya[y0:y1, x0:x1], yb[y0:y1, x0:x1], blob[y0:y1, x0:x1]
        Ov = overlap[y0:y1, x0:x1]
        best = None
        # coarse: half resolution, 1 px steps along the line (2 at full), +-1 across it
        As, Bs = cv2.resize(A, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA), \
            cv2.resize(B, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        Ms = cv2.resize(Bm.astype(np.uint8), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_NEAREST) > 0
        for sgn in signs:
            for t in range(2, max_disp // 2 + 1):
                for c in (-1, 0, 1):
                    dx, dy = sgn * t * ux + c * px, sgn * t * uy + c * py
                    e = cv2.GaussianBlur(np.abs(As - shift(Bs, dx, dy)), (0, 0), 1.0)
                    score = int(((e < args.match) & Ms).sum())
                    if best is None or score > best[0]:
                        best = (score, 2 * dx, 2 * dy)
        if best is None:
            continue
        cx, cy = int(round(best[1])), int(round(best[2]))
        best = None
        for dx in range(cx - 2, cx + 3):
            for dy in range(cy - 2, cy + 3):
                e = cv2.GaussianBlur(np.abs(A - shift(B, dx, dy)), (0, 0), 2.0)
                m = (e < args.match) & Bm
                score = int(m.sum())
                if best is None or score > best[0]:
                    best = (score, dx, dy, m)
        score, dx, dy, m = best
        if score < args.min_area // 2:
            continue
        # The object's pixels in a. The disagreement D is the union of the object's two copies,
        # M_a and M_a + d; where the copies' union is solid, M_a = D & (D - d) (p and p + d both
        # disagree). A flat background matches at any shift, so matching alone cannot tell an
        # object pixel of a from a background pixel of a behind b's copy; this shape test can.
        D = fill_holes(Bm)
        seen_b = shift(Ov.astype(np.float32), dx, dy) > 0.5  # b sees p + d
        seen_a = shift(Ov.astype(np.float32), -dx, -dy) > 0.5  # a sees p - d
        keep = D & (shift(D.astype(np.float32), dx, dy) > 0.5) & Ov & seen_b
        keep = cv2.morphologyEx(keep.astype(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8)) > 0
        # Near the overlap's borders one view cannot see the object's match: the disagreeing
        # pixels there that touch the object found so far are the object (a's side: b does not
        # see p + d; b's side: a does not see p - d, moved into a's frame).
        touch = cv2.dilate(keep.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
        ext_a = touching(D & Ov & ~seen_b, touch)
        touch_b = shift(touch.astype(np.float32), -dx, -dy) > 0.5
        ext_b = shift(touching(D & Ov & ~seen_a, touch_b).astype(np.float32), dx, dy) > 0.5
        # Check the shape test by matching: on the textured pixels it keeps, b shifted by d must
        # match clearly better than b unshifted (one copy alone, or a wrong d, does not).
        e0 = cv2.GaussianBlur(np.abs(A - B), (0, 0), 2.0)
        ed = cv2.GaussianBlur(np.abs(A - shift(B, dx, dy)), (0, 0), 2.0)
        textured = keep & (e0 > args.disagree)
        better = (textured & (ed + args.margin < e0)).sum()
        if textured.sum() < args.min_area // 4 or better < args.support * textured.sum():
            continue
        ma = np.zeros_like(blob)
        ma[y0:y1, x0:x1] = fill_holes(keep | ext_a | ext_b)
        out.append((ma, dx, dy, score / max(1, blob.sum())))
    return out


def touching(m, seed):
    """The connected parts of m that meet seed."""
    n, lab = cv2.connectedComponents(m.astype(np.uint8), connectivity=8)
    ids = np.unique(lab[seed & m])
    return np.isin(lab, ids[ids > 0])


def fill_holes(m):
    h, w = m.shape
    flood = np.pad(~m, 1, constant_values=True).astype(np.uint8)
    cv2.floodFill(flood, None, (0, 0), 2)
    holes = flood[1:-1, 1:-1] == 1
    return m | holes


def epipolar_direction(scene, a, b, overlap):
    """Unit canvas direction in which a point nearer than infinity seen by a at the overlap's
    centre moves in b's warped view (from the rig's camera centres); None without a baseline."""
    ca, cb = scene["cameras"][a], scene["cameras"][b]
    Ca, Cb = np.asarray(ca["C"]), np.asarray(cb["C"])
    if np.linalg.norm(Ca - Cb) < 1e-6:
        return None
    ys, xs = np.nonzero(overlap)
    p = np.array([xs.mean(), ys.mean(), 1.0])
    Ka, Ra, Ha = (np.asarray(ca[k]) for k in ("K", "R", "H"))
    Kb, Rb, Hb = (np.asarray(cb[k]) for k in ("K", "R", "H"))
    u = np.linalg.solve(Ha, p)
    ray = Ra @ np.linalg.solve(Ka, u)
    ray /= np.linalg.norm(ray)
    X = Ca + 2.0 * np.linalg.norm(Ca - Cb) * 10 * ray  # 10 baselines away
    x = Kb @ (Rb.T @ (X - Cb))
    q = Hb @ (x / x[2])
    d = q[:2] / q[2] - p[:2]
    n = np.linalg.norm(d)
    return None if n < 1e-9 else (float(d[0] / n), float(d[1] / n))


def oracle_blobs(scene, t, a, b, W, H):
    """True masks of every object in view a (canvas) and its disparity a -> b."""
    out = []
    for ob in scene["objects"][a:a + 1]:  # object i sweeps across overlap (i, i + 1)
        pose = ob["poses"][t]
        P0, ex, ey = (np.asarray(pose[k]) for k in ("centre", "ex", "ey"))
        corners = np.asarray([P0 + sx * ob["width"] / 2 * ex + sy * ob["height"] / 2 * ey
                              for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
        cps = parallax.canvas_copies(scene, np.vstack([corners, P0[None]]))
        qa, qb = cps[a][0], cps[b][0]
        m = np.zeros((H, W), np.uint8)
        cv2.fillConvexPoly(m, np.rint(qa[:4]).astype(np.int32), 1)
        d = qb[4] - qa[4]
        out.append((m > 0, float(d[0]), float(d[1]), 1.0))
    return out


def compose(scene, rd, t, args, state):
    W, H = scene["canvas"]
    views, valid, weight = warp_views(scene, rd, t)
    n = len(views)
    wsum = np.maximum(sum(weight), 1e-9)
    theta = [w / wsum for w in weight]
    out = sum(theta[i][..., None] * views[i] for i in range(n))
    if args.base:  # a C++ chain's panorama (e.g. the consensus blend) where nothing is moved
        out = cv2.imread(os.path.join(args.out, args.key, args.base, "pano_%04d.png" % t))[:, :, :3].astype(np.float32)
    alpha = np.zeros((H, W), bool)
    for v in valid:
        alpha |= v
    if args.homography_only:
        return out, alpha
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    lumas = [luma(v) for v in views]
    for a in range(n - 1):
        b = a + 1
        overlap = valid[a] & valid[b]
        if overlap.sum() < 64:
            continue
        # the disparity search range: the overlap's width (no object shifts further and stays in it)
        cols = np.nonzero(overlap.any(axis=0))[0]
        max_disp = min(args.max_disparity, int(cols[-1] - cols[0]))
        blobs = oracle_blobs(scene, t, a, b, W, H) if args.oracle else \
            estimate_blobs(lumas[a], lumas[b], overlap, args, max_disp,
                           None if args.no_epipolar else epipolar_direction(scene, a, b, overlap))
        if args.hold and not args.oracle:
            blobs = hold(blobs, state.setdefault((a, b), []), lumas[a], lumas[b], args)
        out = apply_moves(out, views, valid, theta, a, b, blobs)
    return out, alpha


def apply_moves(out, views, valid, theta, a, b, blobs):
    """out with each blob's object drawn once between its copies in views a and b (step 4)."""
    H, W = out.shape[:2]
    overlap = valid[a] & valid[b]
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float32)
    tb = theta[b] / np.maximum(theta[a] + theta[b], 1e-9)
    # tb must be defined beyond the overlap too: 0 on a's side, 1 on b's side
    tb = np.where(overlap, tb, np.where(valid[a], 0.0, 1.0)).astype(np.float32)
    for ma, dx, dy, _ in blobs:
        if not ma.any():
            continue
        # backward map of the moved object: output p shows q with q + tb(q) d = p
        qx, qy = xs.copy(), ys.copy()
        for _ in range(4):
            s = cv2.remap(tb, qx, qy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            qx, qy = xs - s * dx, ys - s * dy
        s = cv2.remap(tb, qx, qy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        inside = cv2.remap(ma.astype(np.float32), qx, qy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        va = cv2.remap(valid[a].astype(np.float32), qx, qy, cv2.INTER_NEAREST) * (1 - s)
        vb = cv2.remap(valid[b].astype(np.float32), qx + dx, qy + dy, cv2.INTER_NEAREST) * s
        sa = cv2.remap(views[a], qx, qy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        sb = cv2.remap(views[b], qx + dx, qy + dy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        obj = (va[..., None] * sa + vb[..., None] * sb) / np.maximum(va + vb, 1e-6)[..., None]
        # background: each view only where it does not show this object
        mb = shift(ma.astype(np.float32), -dx, -dy) > 0.5  # b's copy: M_a + d
        na = valid[a] & ~cv2.dilate(ma.astype(np.uint8), np.ones((EXCL, EXCL), np.uint8)).astype(bool)
        nb = valid[b] & ~cv2.dilate(mb.astype(np.uint8), np.ones((EXCL, EXCL), np.uint8)).astype(bool)
        ga, gb = theta[a] * na, theta[b] * nb
        # recomposed: the pair's whole overlap and the copies (once the views agree on the object,
        # a blend after the move is their weighted mean there; keeping the base output around the
        # copies kept its cuts through them: near s1 background 48.13 dB instead of 48.32)
        region = (overlap | ma | mb) & (valid[a] | valid[b])
        gsum = ga + gb
        bg = (ga[..., None] * views[a] + gb[..., None] * views[b]) / np.maximum(gsum, 1e-9)[..., None]
        use_bg = region & (gsum > 1e-6)
        out = np.where(use_bg[..., None], bg, out)
        k = np.clip(inside, 0, 1)[..., None] * ((va + vb) > 0)[..., None]
        out = k * obj + (1 - k) * out
    return out


def compose_real(rig_path, d, t, base, args):
    """The move on a real set (parallax_real.py's frames and rig; no baseline: both directions)."""
    import parallax_real
    r = json.load(open(rig_path))
    raw, (W, H) = parallax_real.warped_views(rig_path, d, len(r["cameras"]), t)
    views = [v.astype(np.float32) for v, _ in raw]
    valid = [cv2.erode(m.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0 for _, m in raw]
    weight = []
    for c, m in zip(r["cameras"], valid):
        Hm = np.asarray(c["homography"], np.float64).reshape(3, 3)
        pw = cv2.warpPerspective(position_weight_image(c["width"], c["height"]), Hm, (W, H), flags=cv2.INTER_LINEAR)
        weight.append(np.where(m, pw, 0).astype(np.float32))
    wsum = np.maximum(sum(weight), 1e-9)
    theta = [w / wsum for w in weight]
    out = base[:H, :W].astype(np.float32)
    lumas = [luma(v) for v in views]
    for a in range(len(views)):
        for b in range(a + 1, len(views)):
            overlap = valid[a] & valid[b]
            if overlap.sum() < 64:
                continue
            cols = np.nonzero(overlap.any(axis=0))[0]
            max_disp = min(args.max_disparity, int(cols[-1] - cols[0]))
            blobs = estimate_blobs(lumas[a], lumas[b], overlap, args, max_disp, None)
            out = apply_moves(out, views, valid, theta, a, b, blobs)
    return out


def hold(blobs, last, ya, yb, args):
    """Keep last frame's displacement of an overlapping blob unless the new one is clearly better."""
    new = []
    for ma, dx, dy, sc in blobs:
        for lma, ldx, ldy, _ in last:
            if (ma & lma).sum() > 0.3 * min(ma.sum(), lma.sum()) and abs(ldx - dx) <= 3 and abs(ldy - dy) <= 1:
                dx, dy = ldx, ldy
                break
        new.append((ma, dx, dy, sc))
    last[:] = new
    return new


def parser():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=os.path.join(parallax.ROOT, "out", "parallax"))
    ap.add_argument("--rigs", default="near")
    ap.add_argument("--seeds", default="1")
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--name", default="")
    ap.add_argument("--oracle", action="store_true")
    ap.add_argument("--hold", action="store_true")
    ap.add_argument("--base", default="", help="chain whose panorama is kept where no object is moved "
                    "(run by parallax.py in the same --out; default: the weighted mean of the views)")
    ap.add_argument("--real", default="", help="parallax_real.py's --out: move on its sets (base: --base, "
                    "default consensus) and score with its metrics")
    ap.add_argument("--homography-only", action="store_true", help="the prototype's own weighted mean (check)")
    ap.add_argument("--disagree", type=float, default=12.0)
    ap.add_argument("--match", type=float, default=8.0)
    ap.add_argument("--min-area", type=int, default=400)
    ap.add_argument("--margin", type=float, default=4.0, help="grey levels the shifted match must beat the unshifted one by")
    ap.add_argument("--max-disparity", type=int, default=400)
    ap.add_argument("--tallest", type=float, default=0.9, help="blobs this share of the overlap's height or "
                    "taller are left alone (not an object in front of a background)")
    ap.add_argument("--support", type=float, default=0.5, help="share of the object's textured pixels the shift must match")
    ap.add_argument("--no-epipolar", action="store_true", help="search both ways along the rows (no baseline known)")
    return ap


def main():
    args = parser().parse_args()
    if args.real:
        return main_real(args)
    name = args.name or ("move-oracle" if args.oracle else "py-homography" if args.homography_only else "move")
    for rname in args.rigs.split(","):
        for seed in [int(s) for s in args.seeds.split(",")]:
            key = "%s-s%d" % (rname, seed)
            args.key = key
            rd = os.path.join(args.out, key, "rig")
            scene = json.load(open(os.path.join(rd, "scene.json")))
            od = os.path.join(args.out, key, name)
            os.makedirs(od, exist_ok=True)
            state = {}
            for t in range(args.frames):
                img, alpha = compose(scene, rd, t, args, state)
                rgba = np.dstack([np.clip(np.rint(img), 0, 255).astype(np.uint8), alpha.astype(np.uint8) * 255])
                cv2.imwrite(os.path.join(od, "pano_%04d.png" % t), rgba)
            r = parallax.evaluate_output(od, rd, scene, args.frames)
            line = "%-14s %-24s ghost %.3f (%d points)  distant %.3f  PSNR bg-overlap %.2f  PSNR %.2f  flicker %.3f" % (
                key, name, r["ghost_ratio"], r["object_samples"], r["distant_ghost_ratio"],
                r["psnr_overlap_background"], r["psnr"], r["flicker"])
            print(line, flush=True)
            res_path = os.path.join(args.out, key, "move_results.json")
            allr = json.load(open(res_path)) if os.path.exists(res_path) else {}
            allr[name] = r
            json.dump(allr, open(res_path, "w"), indent=1)
    return 0


def main_real(args):
    import parallax_real
    base_name = args.base or "consensus"
    for name in sorted(os.listdir(args.real)):
        top = os.path.join(args.real, name)
        d = os.path.join(top, "frames")
        rig = os.path.join(d, "rig.json")
        if not os.path.exists(rig) or not os.path.exists(os.path.join(top, base_name, "pano_0000.png")):
            continue
        n = len(json.load(open(rig))["cameras"])
        od = os.path.join(top, "move")
        os.makedirs(od, exist_ok=True)
        t = 0
        while os.path.exists(os.path.join(top, base_name, "pano_%04d.png" % t)) and t < args.frames:
            base = cv2.imread(os.path.join(top, base_name, "pano_%04d.png" % t), cv2.IMREAD_UNCHANGED)
            out = compose_real(rig, d, t, base[:, :, :3], args)
            pano = base.copy()
            pano[:out.shape[0], :out.shape[1], :3] = np.clip(np.rint(out), 0, 255).astype(np.uint8)
            cv2.imwrite(os.path.join(od, "pano_%04d.png" % t), pano)
            t += 1
        h = None
        for cname in ("homography", base_name, "move"):
            r = parallax_real.evaluate(os.path.join(top, cname), rig, d, n, t)
            h = h or r
            print("%-12s %-12s detail MAD %.3f (cut %+.1f%%) SSIM %.4f flicker %.3f" % (
                name, cname, r["detail_mad"], (1 - r["detail_mad"] / h["detail_mad"]) * 100, r["ssim"], r["flicker"]),
                flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
