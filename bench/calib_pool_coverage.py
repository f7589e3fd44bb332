#!/usr/bin/env python3
# Usage: [SHARED_DATA=../shared/data] GST_PLUGIN_PATH=build/gst python3 bench/calib_pool_coverage.py [BUNDLES] [CASE...]
# The default chain (stitchsync ! stitchcalib ! stitchcolor ! stitchflowwarp ! stitchblend) on
# real clip sets of ../shared/data, the first BUNDLES frames of each camera: every calibration
# installed or rejected (source, rms-px, previous-px) and the black share of the panorama
# (pixels with max(R,G,B) < 8) under each installed calibration. A still camera (a jpeg of the
# house rig through imagefreeze, or one decoded frame then EOS) is one of the cases.
import os, sys, time, gi
import numpy as np
gi.require_version("Gst", "1.0")
from gi.repository import Gst
Gst.init(None)
S = os.environ.get("SHARED_DATA") or os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data")
V = S + "/video/"
STILL = S + "/images/karthik_3cam_stills/house_cam7.jpg"
n = int(sys.argv[1]) if len(sys.argv) > 1 else 150
def vid(clip, cam): return "filesrc location=%s%s/%s.mp4 ! decodebin ! identity eos-after=%d" % (V, clip, cam, n)
def still(name):
    return "filesrc location=%s/images/karthik_3cam_stills/%s.jpg ! decodebin ! imagefreeze ! identity eos-after=%d ! videoconvert" % (S, name, n)
cases = {
    "house_still": [vid("karthik_3cam_house", "left"), vid("karthik_3cam_house", "middle"),
                    "filesrc location=%s ! decodebin ! imagefreeze ! identity eos-after=%d ! videoconvert" % (STILL, n)],
    "house_oneframe": [vid("karthik_3cam_house", "left"), vid("karthik_3cam_house", "middle"),
                       "filesrc location=%s ! decodebin ! videoconvert" % STILL],
    "house_right_still": [vid("karthik_3cam_house", "left"), vid("karthik_3cam_house", "middle"), still("house_cam5")],
    "house_left_still": [still("house_cam3"), vid("karthik_3cam_house", "middle"), vid("karthik_3cam_house", "right")],
    "house_3stills": [still("house_cam3"), still("house_cam7"), still("house_cam5")],
    "office_3stills": [still("office_cam2"), still("office_cam4"), still("office_cam6")],
    "house_3cam": [vid("karthik_3cam_house", c) for c in ("left", "middle", "right")],
    "house_left_middle": [vid("karthik_3cam_house", c) for c in ("left", "middle")],
    "limlight": [vid("limlight_2cam_apartment", c) for c in ("left", "right")],
    "office": [vid("karthik_2cam_office", c) for c in ("vid1", "vid2")],
    "hallway": [vid("unrival_stereo_hallway", c) for c in ("left", "right")],
}
want = sys.argv[2:] or list(cases)
for name in want:
    d = ("stitchsync name=s ! stitchcalib ! stitchcolor ! stitchflowwarp ! stitchblend ! videoconvert ! "
         "video/x-raw,format=RGBA ! appsink name=out sync=false emit-signals=false max-buffers=4 ")
    d += " ".join("%s ! s.sink_%d" % (c, i) for i, c in enumerate(cases[name]))
    p = Gst.parse_launch(d); bus = p.get_bus(); sink = p.get_by_name("out")
    p.set_state(Gst.State.PLAYING)
    t0 = time.time(); log = []; err = None; black = []; marks = [0]
    while True:
        smp = sink.emit("try-pull-sample", 20 * Gst.MSECOND)
        if smp:
            b = smp.get_buffer(); st = smp.get_caps().get_structure(0)
            w, h = st.get_value("width"), st.get_value("height")
            ok, m = b.map(Gst.MapFlags.READ)
            a = np.frombuffer(m.data, np.uint8); a = a.reshape(h, len(a) // h)[:, :w * 4].reshape(h, w, 4)
            black.append(float((a[..., :3].max(axis=2) < 8).mean())); b.unmap(m)
        while True:
            msg = bus.pop()
            if not msg: break
            if msg.type == Gst.MessageType.ELEMENT and msg.get_structure().get_name() in ("stitchcalib", "stitchcalib-rejected"):
                s = msg.get_structure()
                inst = s.get_name() == "stitchcalib"
                if inst: marks.append(len(black))
                log.append("%s v%d %s at output %d: rms-px %.2f previous %.2f matches %d canvas %dx%d model %s" % (
                    "installed" if inst else "REJECTED", s.get_value("version"), s.get_value("source"), len(black),
                    s.get_value("rms-px"), s.get_value("previous-px"), s.get_value("residual-matches"),
                    s.get_value("canvas-width"), s.get_value("canvas-height"),
                    s.get_value("model") if s.has_field("model") else "-")
                    + (" camera-px %.2f vs %.2f" % (s.get_value("alignment-camera-px"), s.get_value("previous-camera-px"))
                       if s.has_field("alignment-camera-px") else "")
                    + (" coverage %.3f vs %.3f" % (s.get_value("coverage"), s.get_value("previous-coverage"))
                       if s.has_field("coverage") else "")
                    + (" (%s)" % s.get_value("reason") if s.has_field("reason") else ""))
            elif msg.type == Gst.MessageType.WARNING and "judge" in msg.parse_warning()[0].message:
                log.append("warning: " + msg.parse_warning()[0].message)
            elif msg.type == Gst.MessageType.ERROR: err = msg.parse_error()[0].message
            elif msg.type == Gst.MessageType.EOS: err = err or "eos"
        if err or time.time() - t0 > 400: break
    p.set_state(Gst.State.NULL)
    marks.append(len(black))
    shares = ["%d-%d: %.3f" % (marks[k], marks[k + 1] - 1, np.mean(black[marks[k]:marks[k + 1]]))
              for k in range(1, len(marks) - 1) if marks[k + 1] > marks[k]]
    print("== %s: %s, %d panoramas, %.1f s wall; black share per installed calibration: %s" % (
        name, err, len(black), time.time() - t0, "; ".join(shares)), flush=True)
    for l in log: print("   " + l, flush=True)
