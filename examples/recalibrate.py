#!/usr/bin/env python3
"""Recalibrating a running stitcher from Python (gst-python, Debian's python3-gst-1.0).

The chain runs from the given clips to the screen (or to fakesink with --headless). Press r
and Enter, or send SIGUSR1 (kill -USR1 PID), and stitchcalib recalibrates from the current
frames while the video goes on with the previous geometry; every calibration stitchcalib posts
(an element message named "stitchcalib") is printed.

usage: recalibrate.py [--headless] [--frames N] [--recalibrate-after K] [--calibration-frames C]
                      VIDEO VIDEO [VIDEO...]
  --frames N              stop after N panoramas (default: the clips' length)
  --recalibrate-after K   send ourselves SIGUSR1 after K panoramas, once stitchcalib's pooled
                          refinement of the first frames is in (or kept out); what CI does
  --calibration-frames C  stitchcalib's pooling of the first frames (default 5; 1: none, the
                          first calibration is final)
  GST_PLUGIN_PATH must reach the stitch plugin (build/gst).
Exits 0 when the pipeline ran without error and, with --recalibrate-after, a recalibration
was posted after the signal (installed, or kept out because it did not beat the current one:
stitchcalib-rejected); 1 otherwise.
"""
import argparse
import os
import signal
import sys

import gi

gi.require_version("Gst", "1.0")
gi.require_version("GLib", "2.0")
from gi.repository import GLib, Gst  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("videos", nargs="+")
    ap.add_argument("--headless", action="store_true", help="fakesink instead of a window")
    ap.add_argument("--frames", type=int, default=0)
    ap.add_argument("--recalibrate-after", type=int, default=0)
    ap.add_argument("--calibration-frames", type=int, default=5)
    args = ap.parse_args()
    if len(args.videos) < 2:
        ap.error("at least two videos")

    Gst.init(None)
    sink = "fakesink name=out sync=false signal-handoffs=true" if args.headless else "autovideosink name=out"
    desc = "stitchbin name=s calib::calibration-frames=%d ! videoconvert ! identity name=tap ! %s" % (
        args.calibration_frames, sink)
    for i, v in enumerate(args.videos):
        desc += ' filesrc location="%s" ! decodebin ! videoconvert ! s.sink_%d' % (v, i)
    pipeline = Gst.parse_launch(desc)
    stitcher = pipeline.get_by_name("s")
    loop = GLib.MainLoop()
    state = dict(frames=0, calibrations=[], settled=False, signalled=False, asked=False, recalibrated=False,
                 error=None)

    def recalibrate(*_):
        print("recalibrating (frame %d)" % state["frames"], flush=True)
        state["asked"] = True
        stitcher.emit("recalibrate")  # stitchbin's action signal, stitchcalib's own
        return GLib.SOURCE_CONTINUE

    # SIGUSR1 and "r" on stdin, both handled in the main loop (not in a signal handler).
    GLib.unix_signal_add(GLib.PRIORITY_DEFAULT, signal.SIGUSR1, recalibrate)
    if sys.stdin.isatty():
        def on_key(channel, _cond):
            if channel.readline().strip().lower() == "r":
                recalibrate()
            return GLib.SOURCE_CONTINUE
        GLib.io_add_watch(GLib.IOChannel.unix_new(sys.stdin.fileno()), GLib.IO_IN, on_key)
        print("press r + Enter (or kill -USR1 %d) to recalibrate" % os.getpid(), flush=True)

    def on_frame(_pad, _info):
        state["frames"] += 1
        maybe_signal()
        if done():
            GLib.idle_add(loop.quit)
        return Gst.PadProbeReturn.OK

    def maybe_signal():
        if (args.recalibrate_after and not state["signalled"] and state["settled"]
                and state["frames"] >= args.recalibrate_after):
            state["signalled"] = True
            os.kill(os.getpid(), signal.SIGUSR1)

    def done():
        # With --frames: stop there, but not while an asked-for recalibration is still running.
        waiting = args.recalibrate_after and not state["recalibrated"]
        return bool(args.frames) and state["frames"] >= args.frames and not waiting

    pipeline.get_by_name("tap").get_static_pad("src").add_probe(Gst.PadProbeType.BUFFER, on_frame)

    def on_message(_bus, msg):
        if msg.type == Gst.MessageType.ELEMENT and msg.get_structure().get_name() == "stitchcalib-rejected":
            # a pooled refinement or a recalibration that did not beat the current calibration
            s = msg.get_structure()
            state["settled"] |= s.get_value("source") == "pooled"
            state["recalibrated"] |= state["asked"] and s.get_value("source") == "recalibration"
            print("%s kept out: %.2f px against the current %.2f px" % (
                s.get_value("source"), s.get_value("alignment-px"), s.get_value("previous-px")), flush=True)
            if done():
                GLib.idle_add(loop.quit)
        elif msg.type == Gst.MessageType.ELEMENT and msg.get_structure().get_name() == "stitchcalib":
            s = msg.get_structure()
            state["calibrations"].append(s.get_value("version"))
            # settled: no pooled refinement of the first frames is still to come
            state["settled"] |= s.get_value("source") in ("pooled", "file") or args.calibration_frames <= 1
            # the result of the recalibrate signal (others: the first frames, their pooled refinement)
            state["recalibrated"] |= state["asked"] and s.get_value("source") == "recalibration"
            if done():
                GLib.idle_add(loop.quit)
            print("calibration %d (%s): %d cameras, canvas %dx%d, rms %.2f px" % (
                s.get_value("version"), s.get_value("source"), s.get_value("cameras"),
                s.get_value("canvas-width"), s.get_value("canvas-height"), s.get_value("rms-px")), flush=True)
        elif msg.type == Gst.MessageType.ERROR:
            err, dbg = msg.parse_error()
            state["error"] = "%s: %s" % (err.message, dbg)
            loop.quit()
        elif msg.type == Gst.MessageType.EOS:
            loop.quit()

    bus = pipeline.get_bus()
    bus.add_signal_watch()
    bus.connect("message", on_message)
    pipeline.set_state(Gst.State.PLAYING)
    try:
        loop.run()
    finally:
        pipeline.set_state(Gst.State.NULL)

    print("%d panoramas, %d calibrations" % (state["frames"], len(state["calibrations"])), flush=True)
    if state["error"]:
        print("error:", state["error"], file=sys.stderr)
        return 1
    if args.recalibrate_after:
        if not state["signalled"]:
            print("the clips ended before frame %d or before stitchcalib settled" % args.recalibrate_after,
                  file=sys.stderr)
            return 1
        if not state["recalibrated"]:
            print("no recalibration was posted after the recalibrate signal", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
