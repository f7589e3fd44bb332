#!/usr/bin/python3
"""Render a rig of ANY geometry from one photo, with exact truth (probe4).

Each camera k (in pad order) is a pinhole: yaw, pitch, roll (degrees, stitch::Camera
convention R = Ry(yaw) Rx(pitch) Rz(roll), camera -> rig, +pitch looks up), hfov (degrees)
and its size. The scene is the photo on a plane seen by a virtual photo camera Kp looking
along +z of the rig (as bench/render_rig.cpp): camera pixel p shows photo pixel
Kp R_k K_k^-1 p, rendered at 2x and area-downscaled, with per-camera gain and sensor noise.

  render_geom.py --photo P --out DIR --cams "yaw,pitch,roll,hfov,w,h;..." [--frames 20]

Writes camK.avi (MJPEG, --frames frames, a static scene with fresh noise per frame),
camK.png (frame 0) and truth.json ({"cameras": [{"w","h","K","R"}...]}).
"""
import argparse, json, math, os
import numpy as np
import cv2


def rot(yaw, pitch, roll):
    y, p, r = (math.radians(v) for v in (yaw, pitch, roll))
    Ry = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
    Rx = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    Rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return Ry @ Rx @ Rz


def parse_cams(spec):
    cams = []
    for part in spec.split(';'):
        part = part.strip()
        if not part:
            continue
        yaw, pitch, roll, hfov, w, h = (float(v) for v in part.split(','))
        w, h = int(w), int(h)
        f = (w / 2.0) / math.tan(math.radians(hfov) / 2.0)
        K = np.array([[f, 0, (w - 1) / 2.0], [0, f, (h - 1) / 2.0], [0, 0, 1.0]])
        cams.append(dict(w=w, h=h, K=K, R=rot(yaw, pitch, roll)))
    return cams


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--photo', required=True)
    ap.add_argument('--out', required=True)
    ap.add_argument('--cams', required=True)
    ap.add_argument('--frames', type=int, default=20)
    ap.add_argument('--fps', type=float, default=30)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--fill', type=float, default=0.9, help='share of the photo the views span')
    ap.add_argument('--equirect', type=int, default=0,
                    help='1: the photo is a 360x180 equirectangular panorama seen from its centre '
                         '(any geometry: full rings, tilted rings, cameras looking up)')
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    photo = cv2.imread(a.photo, cv2.IMREAD_COLOR)
    assert photo is not None, a.photo
    cams = parse_cams(a.cams)
    # Photo focal: the union of the views spans `fill` of the photo.
    mx = my = 0.0
    for c in ([] if a.equirect else cams):
        H = c['R'] @ np.linalg.inv(c['K'])
        for x in np.linspace(0, c['w'] - 1, 9):
            for y in np.linspace(0, c['h'] - 1, 9):
                q = H @ np.array([x, y, 1.0])
                assert q[2] > 1e-3, 'a camera looks past the photo plane'
                mx, my = max(mx, abs(q[0] / q[2])), max(my, abs(q[1] / q[2]))
    fp = min(a.fill / 2 * photo.shape[1] / mx, a.fill / 2 * photo.shape[0] / my) if mx > 0 else 0.0
    Kp = np.array([[fp, 0, (photo.shape[1] - 1) / 2], [0, fp, (photo.shape[0] - 1) / 2], [0, 0, 1.0]])
    rng = np.random.default_rng(a.seed)
    s = 2
    A = np.array([[1.0 / s, 0, 0.5 / s - 0.5], [0, 1.0 / s, 0.5 / s - 0.5], [0, 0, 1]])
    truth = {'photo': a.photo, 'photo_focal': fp, 'cameras': []}
    for k, c in enumerate(cams):
        Hc = Kp @ c['R'] @ np.linalg.inv(c['K']) @ A
        if a.equirect:
            xs, ys = np.meshgrid(np.arange(c['w'] * s, dtype=np.float64), np.arange(c['h'] * s, dtype=np.float64))
            M = c['R'] @ np.linalg.inv(c['K']) @ A
            d = np.einsum('ij,jyx->iyx', M, np.stack([xs, ys, np.ones_like(xs)]))
            lon = np.arctan2(d[0], d[2])
            lat = np.arctan2(-d[1], np.hypot(d[0], d[2]))
            W, Hh = photo.shape[1], photo.shape[0]
            mapx = ((lon / (2 * np.pi) + 0.5) * W - 0.5).astype(np.float32)
            mapy = ((0.5 - lat / np.pi) * Hh - 0.5).astype(np.float32)
            big = cv2.remap(photo, mapx, mapy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
        else:
            big = cv2.warpPerspective(photo, Hc, (c['w'] * s, c['h'] * s),
                                      flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                      borderMode=cv2.BORDER_REPLICATE)
        lo = cv2.resize(big, (c['w'], c['h']), interpolation=cv2.INTER_AREA).astype(np.float32)
        gain = rng.uniform(0.85, 1.15, 3)
        lo = lo * gain
        vw = cv2.VideoWriter(os.path.join(a.out, f'cam{k}.avi'), cv2.VideoWriter_fourcc(*'MJPG'),
                             a.fps, (c['w'], c['h']))
        for f in range(a.frames):
            fr = np.clip(lo + rng.normal(0, 2.0, lo.shape), 0, 255).astype(np.uint8)
            if f == 0:
                cv2.imwrite(os.path.join(a.out, f'cam{k}.png'), fr)
            vw.write(fr)
        vw.release()
        truth['cameras'].append({'w': c['w'], 'h': c['h'], 'K': c['K'].tolist(), 'R': c['R'].tolist()})
    with open(os.path.join(a.out, 'truth.json'), 'w') as fh:
        json.dump(truth, fh, indent=1)
    print(f'render_geom: {len(cams)} cameras, photo focal {fp:.1f} -> {a.out}')


if __name__ == '__main__':
    main()
