#!/usr/bin/python3
"""Seam error of a calibrated rig with lenses against a rendered truth (branch probe-lens).

  eval_lens.py TRUTH CALIB.json [PADS]

TRUTH: a stitch rig JSON with lenses (stitch-render-rig's rig_true.json), or several joined by
'+' with PADS naming "file_index:camera" per pad (mixed rigs cut from several renders, e.g.
"0:0 1:1"). PADS without ':' picks cameras of one truth ("0 1 2"). For every pair of pads that
truly overlap, a grid of camera i's pixels is carried into camera j through the truth (lens ->
ray -> rotation -> lens) and through the calibration (its lenses; planar rigs through their
homographies between ideal pixels); prints each pair's median / p95 distance in camera-j
pixels and WORST_PAIR_MEDIAN_PX, and the lenses found. eval_geom.py is its pinhole sibling.
"""
import json, math, os, sys
import numpy as np
import cv2

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from render_geom import rot  # noqa: E402


def cam_of(c):
    lens = c.get('lens', {}) or {}
    return dict(w=c['width'], h=c['height'],
                K=np.array([[c['fx'], 0, c['cx']], [0, c['fy'], c['cy']], [0, 0, 1.0]]),
                R=rot(c.get('yaw_deg', 0), c.get('pitch_deg', 0), c.get('roll_deg', 0)),
                H=np.array(c['homography']).reshape(3, 3) if 'homography' in c else None,
                model=lens.get('model', 'pinhole'),
                k=[lens.get(n, 0.0) for n in ('k1', 'k2', 'k3', 'k4', 'p1', 'p2')])


def to_ideal(c, px):
    """Raw pixels -> normalised pinhole coordinates (x, y), NaN where there is none."""
    p = px.reshape(-1, 1, 2).astype(np.float64)
    k1, k2, k3, k4, p1, p2 = c['k']
    if c['model'] == 'fisheye':
        n = cv2.fisheye.undistortPoints(p, c['K'], np.array([k1, k2, k3, k4]),
                                        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10))
    elif c['model'] == 'radtan':
        n = cv2.undistortPointsIter(p, c['K'], np.array([k1, k2, p1, p2, k3]), None, None,
                                    (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10))
    else:
        n = cv2.undistortPoints(p, c['K'], None)
    n = n.reshape(-1, 2)
    back = from_ideal(c, np.c_[n, np.ones(len(n))])[0]  # the iteration can land on another branch
    n[np.linalg.norm(back - px, axis=1) > 0.05] = np.nan
    return n


def from_ideal(c, rays):
    """Camera-frame rays -> raw pixels and whether they are in front."""
    z = rays[:, 2]
    front = z > 1e-9
    zz = np.where(front, z, 1.0)
    x, y = rays[:, 0] / zz, rays[:, 1] / zz
    k1, k2, k3, k4, p1, p2 = c['k']
    if c['model'] == 'fisheye':
        r = np.hypot(x, y)
        th = np.arctan(r)
        t2 = th * th
        td = th * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
        s = np.where(r > 1e-12, td / np.maximum(r, 1e-12), 1.0)
        xd, yd = x * s, y * s
    elif c['model'] == 'radtan':
        r2 = x * x + y * y
        rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    else:
        xd, yd = x, y
    K = c['K']
    return np.c_[K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], front


def carry(ci, cj, px, planar):
    n = to_ideal(ci, px)
    rays = np.c_[n, np.ones(len(n))]
    if planar:
        ideal_i = (ci['K'] @ rays.T).T
        q = (np.linalg.inv(cj['H']) @ ci['H'] @ ideal_i.T).T
        rays_j = (np.linalg.inv(cj['K']) @ q.T).T
    else:
        rays_j = (cj['R'].T @ ci['R'] @ rays.T).T
    return from_ideal(cj, rays_j)


def main():
    files = sys.argv[1].split('+')
    truths = [[cam_of(c) for c in json.load(open(f))['cameras']] for f in files]
    pads = sys.argv[3].split() if len(sys.argv) > 3 else [str(k) for k in range(len(truths[0]))]
    truth = [truths[int(p.split(':')[0])][int(p.split(':')[1])] if ':' in p else truths[0][int(p)] for p in pads]
    est_json = json.load(open(sys.argv[2]))
    planar = est_json.get('projection', 'plane') == 'plane'
    est = [cam_of(c) for c in est_json['cameras']]
    worst, rows = 0.0, []
    for i in range(len(truth)):
        ti = truth[i]
        xs, ys = np.meshgrid(np.linspace(0, ti['w'] - 1, 48), np.linspace(0, ti['h'] - 1, 27))
        px = np.c_[xs.ravel(), ys.ravel()]
        for j in range(i + 1, len(truth)):
            tj = truth[j]
            t, front = carry(ti, tj, px, False)
            ok = front & np.isfinite(t).all(1) & (t[:, 0] >= 0) & (t[:, 0] <= tj['w'] - 1) & \
                (t[:, 1] >= 0) & (t[:, 1] <= tj['h'] - 1)
            if ok.sum() < 0.03 * len(px):
                continue
            if i >= len(est) or j >= len(est) or (planar and (est[i]['H'] is None or est[j]['H'] is None)):
                med = p95 = float('inf')
            else:
                e, efront = carry(est[i], est[j], px[ok], planar)
                d = np.linalg.norm(e - t[ok], axis=1)
                d[~efront | ~np.isfinite(d)] = 1e6
                med, p95 = float(np.median(d)), float(np.percentile(d, 95))
            rows.append((i, j, ok.mean(), med, p95))
            worst = max(worst, med)
    for i, j, ov, med, p95 in rows:
        print(f'pair {i}-{j}: overlap {ov:.2f} median {med:.2f} px p95 {p95:.2f} px')
    lenses = ' '.join(f"{c['model']}({c['k'][0]:+.3f})" if c['model'] != 'pinhole' else 'pinhole' for c in est)
    fx = ' '.join(f"{c['K'][0, 0]:.0f}/{t['K'][0, 0]:.0f}" for c, t in zip(est, truth))
    print(f'WORST_PAIR_MEDIAN_PX {worst:.2f} projection {est_json.get("projection")} lenses {lenses} fx est/true {fx}')


if __name__ == '__main__':
    main()
