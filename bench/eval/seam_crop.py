#!/usr/bin/env python3
"""The seam crop picture of docs/: the same overlap crop of several chains' panoramas side by side.

usage: seam_crop.py --rig RIG.json --frames DIR --out PNG [--frame N] [--width 290] [--height 400]
                    NAME=PANO_DIR ...
The crop is centred on the overlap of cameras 0 and 1 (where both homography-warped views land).
"""
import argparse
import json
import os

import cv2
import numpy as np


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rig", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--frame", type=int, default=-1, help="panorama index (-1: the last)")
    ap.add_argument("--width", type=int, default=290)
    ap.add_argument("--height", type=int, default=400)
    ap.add_argument("--dx", type=int, default=0, help="shift of the crop from the overlap's centre")
    ap.add_argument("--dy", type=int, default=0)
    ap.add_argument("runs", nargs="+", metavar="NAME=DIR")
    args = ap.parse_args()
    rig = json.load(open(args.rig))
    W, H = rig["canvas"]["width"], rig["canvas"]["height"]
    cover = []
    for c in rig["cameras"][:2]:
        Hm = np.asarray(c["homography"], np.float64).reshape(3, 3)
        cover.append(cv2.warpPerspective(np.full((c["height"], c["width"]), 255, np.uint8), Hm, (W, H)) > 0)
    ys, xs = np.nonzero(cover[0] & cover[1])
    cx, cy = int(xs.mean()) + args.dx, int(ys.mean()) + args.dy
    x0 = int(np.clip(cx - args.width // 2, 0, W - args.width))
    y0 = int(np.clip(cy - args.height // 2, 0, H - args.height))
    crops = []
    for run in args.runs:
        name, _, d = run.partition("=")
        files = sorted(f for f in os.listdir(d) if f.startswith("pano_") and f.endswith(".png"))
        img = cv2.imread(os.path.join(d, files[args.frame]))
        crop = img[y0:y0 + args.height, x0:x0 + args.width].copy()
        cv2.putText(crop, name, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(crop, name, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 1, cv2.LINE_AA)
        crops.append(crop)
    cv2.imwrite(args.out, np.hstack(crops))
    print("crop x %d..%d, y %d..%d of %dx%d -> %s" % (x0, x0 + args.width, y0, y0 + args.height, W, H, args.out))


if __name__ == "__main__":
    main()
