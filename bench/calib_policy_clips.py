#!/usr/bin/env python3
# Usage: GST_PLUGIN_PATH=build/gst python3 bench/calib_policy_clips.py [BUNDLES]
# Real clips through stitchcalib (images alone, defaults) + stitchblend: every calibration
# message, rejected candidates, and whether the saved canvas equals the panorama size.
import os, sys, time, json, tempfile, gi
gi.require_version("Gst", "1.0")
from gi.repository import Gst
Gst.init(None)
D = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared", "data", "video") + "/"
TMP = tempfile.mkdtemp()
sets = {"limlight_2cam_apartment": ["left", "right"], "karthik_2cam_office": ["vid1", "vid2"],
        "karthik_3cam_house": ["left", "middle", "right"], "unrival_stereo_hallway": ["left", "right"]}
frames = int(sys.argv[1]) if len(sys.argv) > 1 else 150
for name, cams in sets.items():
    save = os.path.join(TMP, name + ".json")
    d = "stitchsync name=s ! identity eos-after=%d ! stitchcalib save-file=%s ! stitchblend ! fakesink name=out " % (frames, save)
    d += " ".join("filesrc location=%s%s/%s.mp4 ! decodebin ! s.sink_%d" % (D, name, c, i) for i, c in enumerate(cams))
    p = Gst.parse_launch(d); bus = p.get_bus(); p.set_state(Gst.State.PLAYING)
    t0 = time.time(); log = []; err = None
    while True:
        m = bus.timed_pop(100 * Gst.MSECOND)
        if time.time() - t0 > 300: err = "timeout"; break
        if not m: continue
        if m.type == Gst.MessageType.ELEMENT and m.get_structure().get_name() in ("stitchcalib", "stitchcalib-rejected") and m.get_structure().has_field("alignment-px"):
            s = m.get_structure()
            log.append("%s v%d %s canvas %dx%d alignment %.2f px (previous %.2f) rms %.2f cams %s" % (
                "installed" if s.get_name() == "stitchcalib" else "REJECTED", s.get_value("version"), s.get_value("source"),
                s.get_value("canvas-width"), s.get_value("canvas-height"), s.get_value("alignment-px"),
                s.get_value("previous-px"), s.get_value("rms-px"), s.to_string().split("camera-px=(double)")[-1].rstrip(";")))
        elif m.type == Gst.MessageType.ERROR: err = m.parse_error()[0].message; break
        elif m.type == Gst.MessageType.EOS: break
    pad = p.get_by_name("out").get_static_pad("sink"); caps = pad.get_current_caps()
    size = (caps.get_structure(0).get_value("width"), caps.get_structure(0).get_value("height")) if caps else None
    p.set_state(Gst.State.NULL)
    rig = json.load(open(save)) if not err else {}
    canvas = (rig.get("canvas", {}).get("width"), rig.get("canvas", {}).get("height"))
    print("== %s (%d frames, %.1f s): %s; panorama %s, saved canvas %s -> %s" % (name, frames, time.time() - t0, err or "ok", size, canvas,
          "EQUAL" if size == canvas else "DIFFERENT"), flush=True)
    for l in log: print("   " + l, flush=True)
