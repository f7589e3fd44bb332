#!/usr/bin/env python3
# Old vs new stitchcalib: NULL during a calibration, a bus sync handler touching properties,
# a camera dark for its first 5 s. Usage: GST_PLUGIN_PATH=build/gst python3 bench/calib_threads.py data/photos/boat1_1600.jpg
import sys, time, threading, cv2, numpy as np, gi
gi.require_version("Gst", "1.0"); gi.require_version("GstApp", "1.0")
from gi.repository import Gst, GstApp
Gst.init(None)
photo = cv2.cvtColor(cv2.imread(sys.argv[1]), cv2.COLOR_BGR2RGBA)

def pipe(n, props, w, h):
    d = "stitchsync name=s ! stitchcalib name=c %s ! stitchblend ! appsink name=out sync=false max-buffers=400 wait-on-eos=false " % props
    d += " ".join("appsrc name=a%d format=time ! queue max-size-buffers=400 max-size-bytes=0 max-size-time=0 ! s.sink_%d" % (i, i) for i in range(n))
    p = Gst.parse_launch(d)
    caps = Gst.Caps.from_string("video/x-raw,format=RGBA,width=%d,height=%d,framerate=30/1" % (w, h))
    srcs = [p.get_by_name("a%d" % i) for i in range(n)]
    for s in srcs: s.set_property("caps", caps)
    return p, srcs

def push(src, img, f):
    b = Gst.Buffer.new_wrapped(img.tobytes()); b.pts = f * Gst.SECOND // 30; b.duration = Gst.SECOND // 30
    src.emit("push-buffer", b)

# (a) NULL during the first calibration
big = cv2.resize(photo, (3200, 2132))
views = [np.ascontiguousarray(big[:, 700 * i:700 * i + 1800]) for i in range(3)]
p, srcs = pipe(3, "", 1800, 2132)
p.set_state(Gst.State.PLAYING)
for s, v in zip(srcs, views): push(s, v, 0)
time.sleep(0.4)
t = time.time(); p.set_state(Gst.State.NULL); print("null_during_calibration_s %.3f" % (time.time() - t), flush=True)

# (b) bus sync handler reading and setting properties on the calibration message
crops = [np.ascontiguousarray(photo[200:680, 400 * i:400 * i + 640]) for i in range(2)]
p, srcs = pipe(2, "calibration-frames=1", 640, 480)
hits = []
def sync(bus, msg):
    s = msg.get_structure()
    if msg.type == Gst.MessageType.ELEMENT and s and s.get_name().startswith("stitchcalib"):
        c = p.get_by_name("c"); c.get_property("min-inliers"); c.set_property("min-inliers", 20); hits.append(1)
    return Gst.BusSyncReply.PASS
bus = p.get_bus(); bus.set_sync_handler(sync)
p.set_state(Gst.State.PLAYING)
def feed():
    for f in range(10):
        for s, v in zip(srcs, crops): push(s, v, f)
    for s in srcs: s.emit("end-of-stream")
th = threading.Thread(target=feed, daemon=True); th.start()
msg = bus.timed_pop_filtered(20 * Gst.SECOND, Gst.MessageType.EOS | Gst.MessageType.ERROR)
print("sync_handler: %s (handler ran %d times)" % ("finished" if msg else "HUNG for 20 s", len(hits)), flush=True)
if not msg:
    print("(stuck: not setting NULL)"); sys.stdout.flush(); import os; os._exit(0)
p.set_state(Gst.State.NULL)

# (c) camera 1 dark for its first 5 s, then 3 s of good frames
p, srcs = pipe(2, "calibration-frames=1", 640, 480)
bus = p.get_bus(); p.set_state(Gst.State.PLAYING)
dark = np.zeros((480, 640, 4), np.uint8); dark[..., 3] = 255
def feed2():
    for f in range(240):
        for i, s in enumerate(srcs): push(s, dark if (i == 1 and f < 150) else crops[i], f)
    for s in srcs: s.emit("end-of-stream")
threading.Thread(target=feed2, daemon=True).start()
qos = pending = 0; result = "?"; out = 0; sink = p.get_by_name("out")
t0 = time.time()
while time.time() - t0 < 120:
    m = bus.timed_pop(10 * Gst.MSECOND)
    while sink.try_pull_sample(0): out += 1
    if not m: continue
    if m.type == Gst.MessageType.QOS: qos += 1
    elif m.type == Gst.MessageType.ELEMENT and m.get_structure().get_name() == "stitchcalib-pending": pending += 1
    elif m.type == Gst.MessageType.ERROR: result = "error: " + m.parse_error()[0].message; break
    elif m.type == Gst.MessageType.EOS: result = "eos"; break
while sink.try_pull_sample(0): out += 1
print("dark_first_5s: %s, panoramas %d of 240, qos messages %d, pending messages %d" % (result, out, qos, pending), flush=True)
p.set_state(Gst.State.NULL)
