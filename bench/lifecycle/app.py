#!/usr/bin/python3
# BENCHMARKS.md, "probe5". GST_PLUGIN_PATH=build/gst app.py MODE [FRAMES]
# probe5: an application using stitchbin from Python with appsrc cameras. usage: app.py MODE
# modes: plain, gaps (cam1 loses 1.5 s and resumes with DISCONT), frozen (cam1 repeats one frame),
#        vfr (cam1 at jittered intervals 20..50 ms), eos1 (cam1 ends at 2 s), slow (sync sink, cam1 late)
import sys, time, os, random
import gi
gi.require_version('Gst', '1.0')
from gi.repository import Gst
import numpy as np, cv2
Gst.init(None)
mode = sys.argv[1]
nframes = int(sys.argv[2]) if len(sys.argv) > 2 else 150
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
OUT = os.environ.get('PROBE_OUT', '/tmp/probe5_png')
os.makedirs(OUT, exist_ok=True)
clips = [REPO + '/data/limlight_2cam_apartment/left.mp4', REPO + '/data/limlight_2cam_apartment/right.mp4']
frames = []
for c in clips:
    cap = cv2.VideoCapture(c); fs = []
    while len(fs) < nframes:
        ok, f = cap.read()
        if not ok: break
        fs.append(cv2.cvtColor(f, cv2.COLOR_BGR2RGB))
    frames.append(fs)
h, w = frames[0][0].shape[:2]
sink_props = 'sync=true' if mode == 'slow' else 'sync=false'
desc = ('stitchbin name=b ! videoconvert ! video/x-raw,format=RGB ! appsink name=out %s max-buffers=2 '
        'appsrc name=c0 FMT is-live=%s ! b.sink_0 appsrc name=c1 FMT is-live=%s ! b.sink_1'
        % (sink_props, 'true' if mode in ('slow', 'dotslive') else 'false', 'true' if mode in ('slow', 'dotslive') else 'false'))
desc = desc.replace('FMT', '' if mode == 'bytesfmt' else ('format=time do-timestamp=true' if mode in ('dots', 'dotslive') else 'format=time'))
pipe = Gst.parse_launch(desc)
caps = Gst.Caps.from_string('video/x-raw,format=RGB,width=%d,height=%d,framerate=30/1' % (w, h))
srcs = [pipe.get_by_name('c0'), pipe.get_by_name('c1')]
for s in srcs:
    s.set_property('caps', caps); s.set_property('max-bytes', w * h * 3 * 4); s.set_property('block', True)
out = pipe.get_by_name('out')
pipe.set_state(Gst.State.PLAYING)
T = Gst.SECOND // 30
t0 = time.time()
res = {'frames': 0, 'pts': [], 'err': None, 'eos': False, 'warn': []}
import threading
def push(i):
    s = srcs[i]; rnd = random.Random(i); t = 0
    for k in range(len(frames[i])):
        disc = False
        if mode == 'gaps' and i == 1 and 45 <= k < 90: continue
        if mode == 'gaps' and i == 1 and k == 90: disc = True
        if mode == 'eos1' and i == 1 and k == 60: break
        img = frames[i][30 if (mode == 'frozen' and i == 1 and k > 30) else k]
        buf = Gst.Buffer.new_wrapped(img.tobytes())
        if mode == 'vfr' and i == 1:
            pts = t; dur = rnd.randint(20, 50) * Gst.MSECOND; t += dur
        else:
            pts = k * T; dur = T
        buf.pts = pts; buf.duration = dur
        if disc: buf.set_flags(Gst.BufferFlags.DISCONT)
        if mode in ('nopts', 'dots', 'dotslive'):
            buf.pts = Gst.CLOCK_TIME_NONE; buf.duration = Gst.CLOCK_TIME_NONE
        if mode == 'offset' and i == 1: buf.pts = pts + 100 * Gst.SECOND
        if mode == 'offset_both': buf.pts = pts + (100 + i * 0.0) * Gst.SECOND
        if mode in ('slow', 'dotslive'):
            # camera 1 is 80 ms late against its timestamps
            target = t0 + pts / 1e9 + (0.08 if i == 1 else 0)
            dt = target - time.time()
            if dt > 0: time.sleep(dt)
        if s.emit('push-buffer', buf) != Gst.FlowReturn.OK: return
    s.emit('end-of-stream')
ths = [threading.Thread(target=push, args=(i,), daemon=True) for i in range(2)]
for t in ths: t.start()
bus = pipe.get_bus()
last = None
deadline = time.time() + 90
saved = 0
while time.time() < deadline:
    smp = out.emit('try-pull-sample', 50 * Gst.MSECOND)
    if smp:
        b = smp.get_buffer(); st = smp.get_caps().get_structure(0)
        ow, oh = st.get_value('width'), st.get_value('height')
        ok, mi = b.map(Gst.MapFlags.READ)
        stride = (ow * 3 + 3) & ~3
        last = np.frombuffer(mi.data, np.uint8)[:stride * oh].reshape(oh, stride)[:, :ow * 3].reshape(oh, ow, 3).copy()
        b.unmap(mi)
        res['frames'] += 1; res['pts'].append(b.pts / 1e9); res.setdefault('wall', []).append(time.time() - t0)
        if res['frames'] in (60, 100):
            cv2.imwrite(OUT + '/app_%s_%d.png' % (mode, res['frames']), cv2.cvtColor(last, cv2.COLOR_RGB2BGR))
    while True:
        m = bus.pop()
        if not m: break
        if m.type == Gst.MessageType.ERROR:
            e_, d_ = m.parse_error(); print('  ERROR', m.src.get_name(), e_.message); res['err'] = res['err'] or m.src.get_name() + ': ' + e_.message + ' | ' + (d_ or '')[-300:]
        elif m.type == Gst.MessageType.WARNING:
            wm = m.parse_warning()[0].message
            if wm not in res['warn']: res['warn'].append(wm); print('  WARN', wm[:160])
        elif m.type == Gst.MessageType.EOS:
            res['eos'] = True
    if res['err'] or (res['eos'] and not smp): break
if last is not None:
    cv2.imwrite(OUT + '/app_%s_end.png' % mode, cv2.cvtColor(last, cv2.COLOR_RGB2BGR))
p = np.array(res['pts'])
d = np.diff(p) if len(p) > 1 else np.array([0])
print('mode=%s frames=%d eos=%s err=%s t=%.1fs pts %.2f..%.2f step median %.4f max %.4f min %.4f' % (
    mode, res['frames'], res['eos'], res['err'], time.time() - t0, p.min() if len(p) else -1, p.max() if len(p) else -1,
    np.median(d), d.max(), d.min()))
pipe.set_state(Gst.State.NULL)
wl = res.get('wall', [])
for k in (0, 1, 10, 50, 100, 150, 200, len(wl) - 1):
    if 0 <= k < len(wl): print('  frame %d pts %.2f wall %.2f lag %.2f' % (k, res['pts'][k], wl[k], wl[k] - res['pts'][k]))
