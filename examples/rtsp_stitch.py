#!/usr/bin/python3
"""Stitches live RTSP cameras into one panorama.

Without --url it first starts an RTSP server on loopback (gst-rtsp-server) that serves three
overlapping crops of a clip (default: the repository's limlight left.mp4), as three "cameras";
then it stitches them, live, through rtspsrc with its latency set, and writes the panorama to
an MP4 file. A camera that drops out is filled from its neighbours (stitchsync dropout=fill)
and rejoins when it is back; dropouts are printed.

  examples/rtsp_stitch.py --seconds 5 --out /tmp/rtsp_pano.mp4
  examples/rtsp_stitch.py --url rtsp://cam-a/stream --url rtsp://cam-b/stream --out pano.mp4

Needs python3-gi, gir1.2-gst-rtsp-server-1.0, the plugin built (GST_PLUGIN_PATH=build/gst)
and gstreamer1.0-plugins-{good,bad,ugly}, gstreamer1.0-libav (scripts/setup.sh installs them).
"""
import argparse
import json
import os
import sys
import tempfile
import threading

import gi

gi.require_version("Gst", "1.0")
gi.require_version("GstRtspServer", "1.0")
from gi.repository import GLib, Gst, GstRtspServer  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
CROP_W, CROP_H, SHIFT, TOP = 320, 240, 200, 80


def serve_crops(clip, width, height):
    """An RTSP server on a free loopback port serving /cam0../cam2; returns (urls, loop)."""
    server = GstRtspServer.RTSPServer()
    server.set_address("127.0.0.1")
    server.set_service("0")
    mounts = server.get_mount_points()
    for i in range(3):
        left = SHIFT * i
        factory = GstRtspServer.RTSPMediaFactory()
        factory.set_launch(
            f"( filesrc location={clip} ! qtdemux ! h264parse ! avdec_h264 ! "
            f"videocrop left={left} right={width - left - CROP_W} top={TOP} bottom={height - TOP - CROP_H} ! "
            "videoconvert ! x264enc tune=zerolatency speed-preset=ultrafast key-int-max=10 bitrate=3000 ! "
            "rtph264pay name=pay0 pt=96 config-interval=1 )")
        factory.set_shared(False)
        mounts.add_factory(f"/cam{i}", factory)
    context = GLib.MainContext.new()
    server.attach(context)
    loop = GLib.MainLoop.new(context, False)
    threading.Thread(target=loop.run, daemon=True).start()
    port = server.get_bound_port()
    return [f"rtsp://127.0.0.1:{port}/cam{i}" for i in range(3)], (server, loop)


def exact_calibration(path):
    """The served crops are shifts of one frame: their exact calibration."""
    cams = [{"width": CROP_W, "height": CROP_H, "fx": CROP_W, "fy": CROP_W, "cx": (CROP_W - 1) / 2,
             "cy": (CROP_H - 1) / 2, "homography": [1, 0, SHIFT * i, 0, 1, 0, 0, 0, 1]} for i in range(3)]
    rig = {"format": "stitch-rig", "version": 1, "projection": "plane", "reference": 0,
           "canvas": {"width": 2 * SHIFT + CROP_W, "height": CROP_H}, "cameras": cams}
    with open(path, "w") as f:
        json.dump(rig, f)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--url", action="append", help="an RTSP camera (repeat; none: serve crops of --clip)")
    ap.add_argument("--clip", default=os.path.join(HERE, "..", "data", "limlight_2cam_apartment", "left.mp4"))
    ap.add_argument("--calib", help="saved calibration (load-file); default: exact for the served crops, "
                                    "else calibrated from the images")
    ap.add_argument("--latency-ms", type=int, default=200, help="rtspsrc jitter buffer and stitchsync latency")
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--out", default="rtsp_panorama.mp4")
    args = ap.parse_args()

    Gst.init(None)
    keep = None
    calib = args.calib
    urls = args.url
    if not urls:
        urls, keep = serve_crops(os.path.abspath(args.clip), 720, 404)
        if not calib:
            calib = os.path.join(tempfile.mkdtemp(), "rtsp_crops.json")
            exact_calibration(calib)
        print("serving", " ".join(urls))
    calib_props = f"load-file={calib}" if calib else ""
    desc = (f"stitchsync name=s latency={args.latency_ms * 1000000} dropout=fill ! stitchcalib {calib_props} ! "
            f"stitchblend ! videoconvert ! x264enc tune=zerolatency ! mp4mux ! filesink location={args.out} ")
    for i, url in enumerate(urls):
        desc += (f"rtspsrc location={url} latency={args.latency_ms} ! rtph264depay ! h264parse ! "
                 f"avdec_h264 ! videoconvert ! s.sink_{i} ")
    pipe = Gst.parse_launch(desc)
    bus = pipe.get_bus()
    pipe.set_state(Gst.State.PLAYING)
    frames = [0]

    def count(pad, info):
        frames[0] += 1
        return Gst.PadProbeReturn.OK

    pipe.get_by_name("s").get_static_pad("src").add_probe(Gst.PadProbeType.BUFFER, count)
    deadline = GLib.get_monotonic_time() + int(args.seconds * 1e6)
    ok = True
    while GLib.get_monotonic_time() < deadline:
        msg = bus.timed_pop(50 * Gst.MSECOND)
        if not msg:
            continue
        if msg.type == Gst.MessageType.ERROR:
            err, dbg = msg.parse_error()
            print("error:", err.message, file=sys.stderr)
            ok = False
            break
        if msg.type == Gst.MessageType.WARNING:
            print("warning:", msg.parse_warning()[0].message)
        if msg.type == Gst.MessageType.ELEMENT and msg.get_structure().get_name() == "stitchsync-dropout":
            s = msg.get_structure()
            print(f"{s.get_string('pad')}: {'dropped out' if s.get_value('dropped') else 'back'}")
    # finish the MP4 properly
    pipe.send_event(Gst.Event.new_eos())
    bus.timed_pop_filtered(5 * Gst.SECOND, Gst.MessageType.EOS | Gst.MessageType.ERROR)
    pipe.set_state(Gst.State.NULL)
    print(f"{frames[0]} panoramas from {len(urls)} RTSP cameras in {args.seconds:.1f} s -> {args.out}")
    del keep
    return 0 if ok and frames[0] > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
