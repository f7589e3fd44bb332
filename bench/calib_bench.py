#!/usr/bin/env python3
"""Calibration benchmark (issue 14), one command:

    bench/calib_bench.py [--build build] [--quick] [--json OUT]

1. Ground-truth rigs rendered from real photos by stitch-render-rig (data/photos and, when
   present, ../shared/data images): planar rigs of 2-5 cameras (yaw steps 30-60 degrees) and
   360-degree rings (cylindrical, spherical scenes), several seeds; each calibrated by
   stitch-calibrate with default settings from the rough rig the renderer writes (a perturbed
   copy of the truth) and from the images alone. Reported: the model and projection chosen and
   the mean corner error in camera pixels (every non-reference camera's corners sent to the
   reference camera by the estimate and back by the truth).
2. Every multi-camera clip and image set in the repository's data/ and ../shared/data: ours
   (stitch-calibrate, default settings, frames 10-14 pooled) against OpenCV's detail pipeline
   (stitch-calib-opencv: cv::Stitcher::estimateTransform with SIFT on frame 10, its cameras on
   the projection ours chose), both judged on later frames (60, 62, 64; image sets: the same
   images) by independent matches (stitch-eval-alignment: median and p90 over SIFT matches that a
   fundamental-matrix RANSAC keeps, mapped through each calibration), with failures counted.

Pure Python (no numpy); the binaries come from the build folder.
"""
import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SHARED = os.environ.get("STITCH_SHARED_DATA") or next(
    (p for p in (os.path.join(ROOT, "..", "shared", "data"), os.path.join(ROOT, "..", "..", "shared", "data"))
     if os.path.isdir(p)), os.path.join(ROOT, "..", "shared", "data"))


def mat_mul(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def mat_inv(m):
    a, b, c = m[0]
    d, e, f = m[1]
    g, h, i = m[2]
    det = a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)
    return [[(e * i - f * h) / det, (c * h - b * i) / det, (b * f - c * e) / det],
            [(f * g - d * i) / det, (a * i - c * g) / det, (c * d - a * f) / det],
            [(d * h - e * g) / det, (b * g - a * h) / det, (a * e - b * d) / det]]


def transpose(m):
    return [[m[j][i] for j in range(3)] for i in range(3)]


def apply(h, x, y):
    p = [h[r][0] * x + h[r][1] * y + h[r][2] for r in range(3)]
    return p[0] / p[2], p[1] / p[2]


def K(c):
    return [[c["fx"], 0, c["cx"]], [0, c["fy"], c["cy"]], [0, 0, 1]]


def R(c):
    y, p, r = (math.radians(c.get(k, 0.0)) for k in ("yaw_deg", "pitch_deg", "roll_deg"))
    ry = [[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]]
    rx = [[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]]
    rz = [[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]]
    return mat_mul(mat_mul(ry, rx), rz)


def homography(c):
    h = c["homography"]
    return [h[0:3], h[3:6], h[6:9]]


def pair_map(rig, a, b):
    """Camera a pixels -> camera b pixels."""
    ca, cb = rig["cameras"][a], rig["cameras"][b]
    if rig.get("projection", "plane") == "plane" and "homography" in ca and "homography" in cb:
        return mat_mul(mat_inv(homography(cb)), homography(ca))
    return mat_mul(mat_mul(K(cb), transpose(R(cb))), mat_mul(R(ca), mat_inv(K(ca))))


def corner_error(est, truth):
    ref = truth.get("reference", 0)
    errs = []
    for i, c in enumerate(truth["cameras"]):
        if i == ref:
            continue
        back = mat_mul(mat_inv(pair_map(truth, i, ref)), pair_map(est, i, ref))
        w, h = c["width"] - 1, c["height"] - 1
        for x, y in ((0, 0), (w, 0), (w, h), (0, h)):
            u, v = apply(back, x, y)
            errs.append(math.hypot(u - x, v - y))
    return sum(errs) / len(errs)


def run(cmd, timeout=600):
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=timeout)
    return p.returncode, p.stdout


def photos(quick):
    out = [os.path.join(ROOT, "data/photos/boat1_1600.jpg")]
    extra = ["images/eadcat_apap_demo/demo2/boat01.jpg", "images/eadcat_apap_demo/demo1/newspaper01.jpg",
]  # halfdome (256x171) is too small to render 480x360 views from
    for rel in extra[: 1 if quick else len(extra)]:
        p = os.path.join(SHARED, rel)
        if os.path.exists(p):
            out.append(p)
    return out


def synthetic(args, tmp, results):
    render = os.path.join(args.build, "tests", "stitch-render-rig")
    calib = os.path.join(args.build, "tools", "stitch-calibrate")
    cases = []
    # (cameras, hfov, overlap) -> yaw steps from ~30 to ~60 degrees on a plane canvas.
    planar = [(2, 60, 0.3), (3, 55, 0.35), (3, 60, 0.3), (4, 45, 0.45)]
    seeds = [1] if args.quick else [1, 2, 3]
    for photo in photos(args.quick):
        for n, hfov, ov in planar[: 2 if args.quick else len(planar)]:
            for seed in seeds:
                cases.append(("plane", photo, n, hfov, ov, seed))
        for ring in ([] if args.quick else ["cylindrical", "spherical"]):
            cases.append((ring, photo, 6, 80, 0.0, 1))
    for kind, photo, n, hfov, ov, seed in cases:
        name = "%s_%s_n%d_h%d_s%d" % (kind, os.path.splitext(os.path.basename(photo))[0], n, hfov, seed)
        d = os.path.join(tmp, name)
        cmd = [render, "--photo", photo, "--cameras", str(n), "--out", d, "--frames", "1", "--hfov", str(hfov),
               "--seed", str(seed), "--moving-object", "0", "--width", "480", "--height", "360"]
        if kind == "plane":
            cmd += ["--overlap", str(ov)]
        else:
            cmd += ["--ring", kind]
        rc, out = run(cmd)
        if rc != 0:
            print("%-40s render failed: %s" % (name, out.strip().splitlines()[-1] if out.strip() else rc))
            continue
        truth = json.load(open(os.path.join(d, "rig_true.json")))
        clips = [os.path.join(d, "cam%d.avi" % i) for i in range(n)]
        for start in ("rough", "images"):
            outj = os.path.join(d, "est_%s.json" % start)
            rep = os.path.join(d, "rep_%s.json" % start)
            cmd = [calib, "--frames", "1", "--out", outj, "--report", rep] + clips
            if start == "rough":
                cmd[1:1] = ["--rig", os.path.join(d, "rig_rough.json")]
            rc, out = run(cmd)
            row = {"case": name, "start": start, "cameras": n}
            if rc != 0:
                row["failed"] = out.strip().splitlines()[-1] if out.strip() else str(rc)
            else:
                est = json.load(open(outj))
                r = json.load(open(rep))
                row.update(model=r["model"], projection=r["projection"], error_px=corner_error(est, truth))
                if kind != "plane":
                    row["seam_px"] = max((p["rms_px"] for p in r["pairs"] if p["accepted"]), default=-1)
            results.append(row)
            print("%-40s %-6s %s" % (name, start, "FAILED " + row["failed"] if "failed" in row else
                                     "%-10s %-11s corner error %.3f px" % (row["model"], row["projection"], row["error_px"])))
            sys.stdout.flush()


def real_sets(quick):
    """(name, inputs, is_clip): every multi-camera clip and image set we have."""
    sets = [("limlight_2cam_apartment (repo)",
             [os.path.join(ROOT, "data/limlight_2cam_apartment", f) for f in ("left.mp4", "right.mp4")], True)]
    videos = (("video/karthik_3cam_house", ["left.mp4", "middle.mp4", "right.mp4"]),
              ("video/karthik_2cam_office", ["vid1.mp4", "vid2.mp4"]),
              ("video/limlight_2cam_apartment", ["left.mp4", "right.mp4"]),
              ("video/unrival_stereo_hallway", ["left.mp4", "right.mp4"]))
    images = (("images/eadcat_apap_demo/demo2", ["boat0%d.jpg" % i for i in range(1, 7)]),
              ("images/eadcat_apap_demo/demo1", ["newspaper0%d.jpg" % i for i in range(1, 5)]),
              ("images/eadcat_apap_demo/demo5", ["P1010517.JPG", "P1010520.JPG"]),
              ("images/eadcat_apap_demo/demo3", ["prague1.jpg", "prague2.jpg"]),
              ("images/eadcat_apap_demo/demo4", ["scottsdale01.jpg", "scottsdale02.jpg", "scottsdale03.jpg"]),
              ("images/udis2_carpark_dhw", ["input1.jpg", "input2.jpg"]),
              ("images/opencv_doc_aero", ["aero1.jpg", "aero3.jpg"]),
              ("images/karthik_3cam_stills", ["house_cam3.jpg", "house_cam5.jpg", "house_cam7.jpg"]),
              ("images/karthik_3cam_stills", ["office_cam2.jpg", "office_cam4.jpg", "office_cam6.jpg"]))
    for rel, files in videos + images:
        paths = [os.path.join(SHARED, rel, f) for f in files]
        if all(os.path.exists(p) for p in paths):
            sets.append((rel + ("" if rel.startswith("video") else " " + files[0]), paths, rel.startswith("video")))
    for d in ("goldengate", "halfdome"):
        base = os.path.join(SHARED, "images/adobe_panoramas", d)
        if os.path.isdir(base):
            files = sorted(f for f in os.listdir(base) if f.lower().endswith((".png", ".jpg")))
            sets.append(("adobe_panoramas/" + d, [os.path.join(base, f) for f in files], False))
    return sets[:2] if quick else sets


def judge(args, rig, inputs, is_clip):
    tool = os.path.join(args.build, "bench", "stitch-eval-alignment")
    meds, p90s = [], []
    for frame in ((60, 62, 64) if is_clip else (0,)):
        rc, o = run([tool, rig, str(frame)] + inputs)
        m = re.search(r"median ([0-9.]+) px p90 ([0-9.]+) px", o)
        if m:
            meds.append(float(m.group(1)))
            p90s.append(float(m.group(2)))
    if not meds:
        return None, None
    return sorted(meds)[len(meds) // 2], sorted(p90s)[len(p90s) // 2]


def clips(args, tmp, results):
    calib = os.path.join(args.build, "tools", "stitch-calibrate")
    opencv = os.path.join(args.build, "bench", "stitch-calib-opencv")
    for k, (name, inputs, is_clip) in enumerate(real_sets(args.quick)):
        row = {"case": name, "inputs": len(inputs), "judged_on": "frames 60-64" if is_clip else "the same images"}
        ours = os.path.join(tmp, "real%d_ours.json" % k)
        rc, out = run([calib, "--frames", "5", "--step", "1", "--start", "10", "--out", ours] + inputs)
        m = re.search(r"^(\w+) model, (\w+) canvas", out, re.M)
        if rc != 0 or not m:
            row["ours_failed"] = out.strip().splitlines()[-1] if out.strip() else str(rc)
        else:
            row["model"], row["projection"] = m.group(1), m.group(2)
            row["ours_median_px"], row["ours_p90_px"] = judge(args, ours, inputs, is_clip)
        theirs = os.path.join(tmp, "real%d_opencv.json" % k)
        rc, out = run([opencv, "--start", "10" if is_clip else "0", "--projection", row.get("projection", "plane"),
                       "--out", theirs] + inputs)
        if rc != 0:
            row["opencv_failed"] = out.strip().splitlines()[-1] if out.strip() else str(rc)
        else:
            row["opencv_median_px"], row["opencv_p90_px"] = judge(args, theirs, inputs, is_clip)
        results.append(row)

        def fmt(prefix):
            if prefix + "_failed" in row:
                return "FAILED (%s)" % row[prefix + "_failed"][:60]
            med, p90 = row.get(prefix + "_median_px"), row.get(prefix + "_p90_px")
            return "no matches to judge" if med is None else "%.2f / %.2f px" % (med, p90)
        print("%-48s ours %-10s %-11s %-22s opencv %s" % (name, row.get("model", "-"), row.get("projection", "-"),
                                                          fmt("ours"), fmt("opencv")))
        sys.stdout.flush()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--quick", action="store_true", help="a few cases only")
    ap.add_argument("--json", help="write every row here")
    ap.add_argument("--only", choices=["synthetic", "real"], help="one half of the benchmark")
    args = ap.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        if args.only != "real":
            synthetic(args, tmp, results)
        if args.only != "synthetic":
            clips(args, tmp, results)
    errs = [r for r in results if "error_px" in r]
    fails = [r for r in results if "failed" in r]
    if errs:
        worst = max(errs, key=lambda r: r["error_px"])
        mean = sum(r["error_px"] for r in errs) / len(errs)
        within = sum(r["error_px"] <= 0.5 for r in errs)
        print("synthetic: %d calibrations, %d within 0.5 px, mean %.3f px, worst %.3f px (%s, %s); %d failed"
              % (len(errs), within, mean, worst["error_px"], worst["case"], worst["start"], len(fails)))
    real = [r for r in results if "inputs" in r]
    if real:
        print("real sets: %d; ours failed on %d, OpenCV on %d; ours failed where OpenCV succeeded: %d; "
              "ours median above OpenCV's: %d; above 2 px where OpenCV <= 10 px: %d" % (
                  len(real), sum("ours_failed" in r for r in real), sum("opencv_failed" in r for r in real),
                  sum("ours_failed" in r and "opencv_failed" not in r for r in real),
                  sum((r.get("ours_median_px") or 0) > (r.get("opencv_median_px") or 1e9) for r in real),
                  sum((r.get("ours_median_px") or 0) > 2 and (r.get("opencv_median_px") or 1e9) <= 10 for r in real)))
    if args.json:
        json.dump(results, open(args.json, "w"), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
