#!/usr/bin/python3
"""Seam error of a calibrated rig against render_geom.py's truth (probe4).

  eval_geom.py truth.json calibrated.json

For every pair of cameras (i, j) that truly overlap, grid points of camera i that camera j
truly sees are carried into camera j by the calibration (planar: H_j^-1 H_i; curved: through
the cameras' rays R K^-1, pinhole) and by the truth (K_j R_j^T R_i K_i^-1); prints each pair's
median and 95th percentile distance in camera-j pixels and the worst pair. A camera the
calibration left out counts as a failed pair (inf).
"""
import json, math, os, sys
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from render_geom import rot  # noqa: E402  (the truth's rotation convention)


def main():
    truth = json.load(open(sys.argv[1]))['cameras']
    if truth and 'fx' in truth[0]:  # a stitch rig JSON (stitch-render-rig's rig_true.json)
        truth = [{'w': c['width'], 'h': c['height'],
                  'K': [[c['fx'], 0, c['cx']], [0, c['fy'], c['cy']], [0, 0, 1]],
                  'R': rot(c.get('yaw_deg', 0), c.get('pitch_deg', 0), c.get('roll_deg', 0)).tolist()}
                 for c in truth]
    if len(sys.argv) > 3:  # pads fed in this order of the truth's cameras (a camera left off: a gap)
        truth = [truth[int(k)] for k in sys.argv[3].split()]
    est = json.load(open(sys.argv[2]))
    planar = est.get('projection', 'plane') == 'plane'
    ecams = est['cameras']
    n = len(truth)
    T = [(np.array(c['K']), np.array(c['R']), c['w'], c['h']) for c in truth]
    def est_map(i, j, pts):
        ci, cj = ecams[i], ecams[j]
        if planar:
            if 'homography' not in ci or 'homography' not in cj:
                return None
            Hi = np.array(ci['homography']).reshape(3, 3)
            Hj = np.array(cj['homography']).reshape(3, 3)
            M = np.linalg.inv(Hj) @ Hi
        else:
            Ki = np.array([[ci['fx'], 0, ci['cx']], [0, ci['fy'], ci['cy']], [0, 0, 1]])
            Kj = np.array([[cj['fx'], 0, cj['cx']], [0, cj['fy'], cj['cy']], [0, 0, 1]])
            Ri = rot(ci.get('yaw_deg', 0), ci.get('pitch_deg', 0), ci.get('roll_deg', 0))
            Rj = rot(cj.get('yaw_deg', 0), cj.get('pitch_deg', 0), cj.get('roll_deg', 0))
            M = Kj @ Rj.T @ Ri @ np.linalg.inv(Ki)
        q = (M @ pts.T).T
        return q[:, :2] / q[:, 2:3], q[:, 2]
    worst = 0.0
    rows = []
    for i in range(n):
        Ki, Ri, wi, hi = T[i]
        xs, ys = np.meshgrid(np.linspace(0, wi - 1, 40), np.linspace(0, hi - 1, 30))
        pts = np.stack([xs.ravel(), ys.ravel(), np.ones(xs.size)], 1)
        for j in range(n):
            if i == j:
                continue
            Kj, Rj, wj, hj = T[j]
            q = (Kj @ Rj.T @ Ri @ np.linalg.inv(Ki) @ pts.T).T
            ok = q[:, 2] > 0
            t = q[:, :2] / q[:, 2:3]
            ok &= (t[:, 0] >= 0) & (t[:, 0] <= wj - 1) & (t[:, 1] >= 0) & (t[:, 1] <= hj - 1)
            if ok.sum() < 0.05 * len(pts) or i > j:
                continue
            e = est_map(i, j, pts[ok])
            if e is None:
                med = p95 = float('inf')
            else:
                d = np.linalg.norm(e[0] - t[ok], axis=1)
                d[e[1] <= 0] = 1e6
                med, p95 = float(np.median(d)), float(np.percentile(d, 95))
            rows.append((i, j, ok.mean(), med, p95))
            worst = max(worst, med)
    for i, j, ov, med, p95 in rows:
        print(f'pair {i}-{j}: overlap {ov:.2f} median {med:.2f} px p95 {p95:.2f} px')
    print(f'WORST_PAIR_MEDIAN_PX {worst:.2f} projection {est.get("projection")} canvas '
          f'{est.get("canvas", {}).get("width")}x{est.get("canvas", {}).get("height")} reference {est.get("reference")}')


if __name__ == '__main__':
    main()
