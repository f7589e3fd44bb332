"""Quality metrics of the evaluation suite (bench/eval/evaluate.py).

Images are numpy arrays (H x W x 3 uint8, OpenCV's BGR order; masks are H x W bool).
tests/eval/test_metrics.py checks these functions on cases with known answers.
"""
import math

import cv2
import numpy as np


def psnr(a, b, mask=None):
    """PSNR in dB over the pixels in `mask` (all when None); inf for identical images."""
    d = (a.astype(np.float64) - b.astype(np.float64)) ** 2
    if mask is not None:
        d = d[mask]
    if d.size == 0:
        return float("nan")
    mse = float(d.mean())
    return math.inf if mse == 0 else 10.0 * math.log10(255.0 ** 2 / mse)


def luma(img):
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY).astype(np.float64) if img.ndim == 3 else img.astype(np.float64)


def ssim(a, b, mask=None):
    """Mean SSIM of the luma (Wang et al. 2004: 11x11 Gaussian window, sigma 1.5) over `mask`.

    The statistics of a pixel whose window reaches outside the mask are not trusted, so the
    mask is eroded by the window radius first."""
    x, y = luma(a), luma(b)
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def blur(v):
        return cv2.GaussianBlur(v, (11, 11), 1.5, borderType=cv2.BORDER_REPLICATE)

    mx, my = blur(x), blur(y)
    sxx = blur(x * x) - mx * mx
    syy = blur(y * y) - my * my
    sxy = blur(x * y) - mx * my
    ssim_map = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    if mask is not None:
        mask = cv2.erode(mask.astype(np.uint8), np.ones((11, 11), np.uint8)) > 0
        values = ssim_map[mask]
    else:
        values = ssim_map.ravel()
    return float(values.mean()) if values.size else float("nan")


def gradient_magnitude(img):
    y = luma(img)
    gx = cv2.Sobel(y, cv2.CV_64F, 1, 0, ksize=3)
    gy = cv2.Sobel(y, cv2.CV_64F, 0, 1, ksize=3)
    return np.sqrt(gx * gx + gy * gy)


def seam_visibility(out, truth, band):
    """Mean absolute difference of the luma gradient magnitude (Sobel) between the output and
    the ground truth over the overlap band: steps in colour and doubled edges both show up as
    gradient that the scene does not have (or lacks). 0 when the output equals the truth."""
    if not band.any():
        return float("nan")
    return float(np.abs(gradient_magnitude(out) - gradient_magnitude(truth))[band].mean())


def apply_homography(H, points):
    p = np.hstack([np.asarray(points, np.float64), np.ones((len(points), 1))]) @ np.asarray(H, np.float64).T
    return p[:, :2] / p[:, 2:3]


def corner_error(estimated, truth, sizes, reference):
    """Calibration error against ground truth: each non-reference camera's four image corners
    mapped into the reference camera by the estimated and by the true camera->reference
    homography; the mean and the largest distance (px). `estimated` and `truth` are lists of
    3x3 camera->reference homographies, `sizes` the (width, height) of each camera."""
    distances = []
    for i, (He, Ht, (w, h)) in enumerate(zip(estimated, truth, sizes)):
        if i == reference:
            continue
        corners = [(0, 0), (w - 1, 0), (w - 1, h - 1), (0, h - 1)]
        if He is None:
            return float("inf"), float("inf")
        d = np.linalg.norm(apply_homography(He, corners) - apply_homography(Ht, corners), axis=1)
        distances.extend(d.tolist())
    if not distances:
        return float("nan"), float("nan")
    return float(np.mean(distances)), float(np.max(distances))


def to_reference(camera_to_canvas, reference):
    """camera->canvas homographies -> camera->reference-camera homographies."""
    inv_ref = np.linalg.inv(camera_to_canvas[reference])
    return [inv_ref @ H / (inv_ref @ H)[2, 2] for H in camera_to_canvas]


def flicker(frames, static_masks):
    """Temporal flicker on static regions: for every pair of consecutive frames, the mean
    absolute luma change over the pixels that the scene leaves unchanged (static_masks[t]
    for the pair (t-1, t); one mask for all pairs when a single array is given). Returns the
    per-pair values; frames of different sizes are compared on their common top-left area
    (a panorama that changes size jumps, and that is flicker too)."""
    values = []
    for t in range(1, len(frames)):
        a, b = frames[t - 1], frames[t]
        if a is None or b is None:
            values.append(float("nan"))
            continue
        h = min(a.shape[0], b.shape[0])
        w = min(a.shape[1], b.shape[1])
        m = static_masks if isinstance(static_masks, np.ndarray) else static_masks[t]
        m = m[:h, :w]
        if not m.any():
            values.append(float("nan"))
            continue
        values.append(float(np.abs(luma(a[:h, :w]) - luma(b[:h, :w]))[m].mean()))
    return values


_sift = None


def features(img, mask=None):
    global _sift
    if _sift is None:
        _sift = cv2.SIFT_create()
    m = None if mask is None else mask.astype(np.uint8) * 255
    return _sift.detectAndCompute(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY), m)


def match(fa, fb, ratio=0.75):
    (ka, da), (kb, db) = fa, fb
    if da is None or db is None or len(ka) < 8 or len(kb) < 8:
        return np.zeros((0, 2)), np.zeros((0, 2))
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
    good = [p[0] for p in pairs if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    pa = np.float64([ka[m.queryIdx].pt for m in good]).reshape(-1, 2)
    pb = np.float64([kb[m.trainIdx].pt for m in good]).reshape(-1, 2)
    return pa, pb


def register(image, image_mask, target_features, min_inliers=30):
    """Homography from `image` to the target frame by SIFT matches (RANSAC, then least squares
    on the inliers); None when it cannot be found reliably."""
    pa, pb = match(features(image, image_mask), target_features)
    if len(pa) < min_inliers:
        return None
    H, inliers = cv2.findHomography(pa, pb, cv2.RANSAC, 2.0)
    if H is None or int(inliers.sum()) < min_inliers:
        return None
    keep = inliers.ravel() > 0
    H, _ = cv2.findHomography(pa[keep], pb[keep], 0)
    return H


def alignment(frames, camera_to_reference, min_matches=20):
    """Overlap alignment on real clips: SIFT matches between every pair of views, outliers
    rejected by a fundamental-matrix RANSAC (no planarity assumed, so the calibration under
    test does not choose its own matches), both ends mapped into the reference camera by the
    calibration; the median distance (px) over all pairs, and the match count."""
    feats = [features(f) for f in frames]
    distances = []
    for a in range(len(frames)):
        for b in range(a + 1, len(frames)):
            pa, pb = match(feats[a], feats[b])
            if len(pa) < min_matches:
                continue
            F, inliers = cv2.findFundamentalMat(pa, pb, cv2.FM_RANSAC, 1.5, 0.999)
            if F is None or inliers is None:
                continue
            keep = inliers.ravel() > 0
            if keep.sum() < min_matches:
                continue
            qa = apply_homography(camera_to_reference[a], pa[keep])
            qb = apply_homography(camera_to_reference[b], pb[keep])
            distances.extend(np.linalg.norm(qa - qb, axis=1).tolist())
    if not distances:
        return float("nan"), 0
    return float(np.median(distances)), len(distances)


# StabStitch-style warp measures (Jia et al., StabStitch, ECCV 2024). The local warp of a chain
# is measured on its output: the dense flow from the homography-only output to the chain's
# output (both on the same canvas), on pixels where both show the same static scene.

def warp_field(base, out, mask):
    """Displacement (H x W x 2, px) that takes `base` to `out` (Farneback flow on the luma);
    0 outside `mask`."""
    f = cv2.calcOpticalFlowFarneback(luma(base).astype(np.uint8), luma(out).astype(np.uint8), None,
                                     0.5, 4, 15, 3, 5, 1.1, 0)
    f[~mask] = 0
    return f


def warp_stability(fields, masks):
    """Mean |d(t+1) - 2 d(t) + d(t-1)| (px) over the pixels in all three frames' masks: how much
    the local warp shakes over time (0 for a fixed warp or one that moves at constant speed)."""
    vals = []
    for t in range(1, len(fields) - 1):
        dd = fields[t + 1] - 2 * fields[t] + fields[t - 1]
        vals.append(np.linalg.norm(dd, axis=2)[masks[t - 1] & masks[t] & masks[t + 1]])
    return float(np.concatenate(vals).mean()) if vals and sum(v.size for v in vals) else float("nan")


def line_distortion(field, mask, stride=8, min_run=32):
    """How far the warp bends straight lines: every row (and column) `stride` px apart, in runs of
    at least `min_run` px inside `mask`, is moved by the field; the worst distance of the moved
    line from the straight chord through its moved ends, per run. Returns (mean, 95th
    percentile) over the runs, px (0 for a homography: it keeps lines straight)."""
    devs = []
    for axis in (0, 1):
        m = mask if axis == 0 else mask.T
        d = field[..., 1] if axis == 0 else field[..., 0].T  # displacement across the line
        for i in range(0, m.shape[0], stride):
            row = m[i]
            edges = np.flatnonzero(np.diff(np.concatenate([[0], row.astype(np.int8), [0]])))
            for a, b in zip(edges[0::2], edges[1::2]):
                if b - a < min_run:
                    continue
                v = d[i, a:b].astype(np.float64)
                chord = np.linspace(v[0], v[-1], b - a)
                devs.append(float(np.abs(v - chord).max()))
    if not devs:
        return float("nan"), float("nan")
    return float(np.mean(devs)), float(np.percentile(devs, 95))
