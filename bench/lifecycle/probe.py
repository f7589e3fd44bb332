#!/usr/bin/python3
# probe5 harness (BENCHMARKS.md, "probe5"): seeks, state changes, caps changes, rates, formats,
# EOS on real clips, driven from Python. usage: GST_PLUGIN_PATH=build/gst probe.py CASE
# (cases: the CASES table at the end); PNGs go to $PROBE_OUT (default /tmp/probe5_png).
import sys, time, os, threading
import gi
gi.require_version('Gst', '1.0')
gi.require_version('GstApp', '1.0')
from gi.repository import Gst, GLib, GstApp
import numpy as np
import cv2

Gst.init(None)
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SH = os.environ.get('STITCH_SHARED_DATA', '/work/shared/data') + '/video'
L = REPO + '/data/limlight_2cam_apartment/left.mp4'
R = REPO + '/data/limlight_2cam_apartment/right.mp4'
H3 = [SH + '/karthik_3cam_house/%s.mp4' % n for n in ('left', 'middle', 'right')]
OUT = os.environ.get('PROBE_OUT', '/tmp/probe5_png')
os.makedirs(OUT, exist_ok=True)

_dn = [0]
def dec(path, extra=''):
    _dn[0] += 1
    return 'filesrc location=%s ! qtdemux name=dmx%d ! h264parse name=prs%d ! avdec_h264 ! %s' % (path, _dn[0], _dn[0], extra)

def relink_demuxers(pipe):
    # gst_parse_launch links a demuxer's sometimes pad once; after READY/NULL the demuxer makes new pads
    for e in [x for x in iter_elems(pipe)]:
        n = e.get_name()
        if n.startswith('dmx'):
            parser = pipe.get_by_name('prs' + n[3:])
            def added(el, pad, parser=parser):
                sink = parser.get_static_pad('sink')
                if not sink.is_linked() and pad.get_name().startswith('video'):
                    pad.link(sink)
            e.connect('pad-added', added)

def iter_elems(pipe):
    out = []
    it = pipe.iterate_recurse()
    while True:
        ok, e = it.next()
        if ok != Gst.IteratorResult.OK: break
        out.append(e)
    return out

TAIL = ' ! videoconvert ! video/x-raw,format=RGB ! appsink name=out sync=false max-buffers=4 emit-signals=false'

class Run:
    def __init__(self, case, desc, sink_sync=False):
        self.case = case
        self.pipe = Gst.parse_launch(desc)
        relink_demuxers(self.pipe)
        self.sink = self.pipe.get_by_name('out')
        self.frames = []   # (pts, w, h, mean)
        self.msgs = []
        self.eos = False
        self.error = None
        self.saved = 0
        self.t0 = time.time()
        self.last = None

    def pull(self, timeout_s=0.05):
        s = self.sink.emit('try-pull-sample', int(timeout_s * Gst.SECOND))
        if s is None:
            return None
        buf = s.get_buffer(); caps = s.get_caps().get_structure(0)
        w = caps.get_value('width'); h = caps.get_value('height')
        ok, mi = buf.map(Gst.MapFlags.READ)
        stride = (w * 3 + 3) & ~3
        a = np.frombuffer(mi.data, dtype=np.uint8)
        img = a[:stride * h].reshape(h, stride)[:, :w * 3].reshape(h, w, 3).copy()
        buf.unmap(mi)
        self.frames.append((buf.pts, w, h, float(img.mean())))
        self.last = img
        return img

    def save(self, tag, img=None):
        img = self.last if img is None else img
        if img is None: return
        p = '%s/%s_%s.png' % (OUT, self.case, tag)
        cv2.imwrite(p, cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        print('  saved', p)

    def poll_bus(self):
        bus = self.pipe.get_bus()
        while True:
            m = bus.pop()
            if m is None: return
            t = m.type
            if t == Gst.MessageType.ERROR:
                e, dbg = m.parse_error(); self.error = '%s: %s' % (m.src.get_name(), e.message)
                print('  ERROR', self.error)
            elif t == Gst.MessageType.WARNING:
                e, dbg = m.parse_warning(); print('  WARN %s: %s' % (m.src.get_name(), e.message[:200]))
            elif t == Gst.MessageType.EOS:
                self.eos = True
            elif t == Gst.MessageType.SEGMENT_DONE:
                print('  SEGMENT_DONE', m.parse_segment_done())
                self.msgs.append('segment-done')
            elif t == Gst.MessageType.ELEMENT:
                st = m.get_structure()
                if st and st.get_name().startswith('stitch') and st.get_name() not in ('stitchsync-offsets',):
                    nm = st.get_name()
                    if nm not in self.msgs: print('  msg', nm)
                    self.msgs.append(nm)

    def loop(self, seconds, until_frames=None, stop_on_eos=True):
        end = time.time() + seconds
        while time.time() < end:
            self.pull()
            self.poll_bus()
            if self.error: return 'error'
            if self.eos and stop_on_eos:
                # drain
                while self.pull(0.01) is not None: pass
                return 'eos'
            if until_frames and len(self.frames) >= until_frames: return 'frames'
        return 'timeout'

    def state(self, st, wait=10):
        r = self.pipe.set_state(st)
        r2, cur, pend = self.pipe.get_state(wait * Gst.SECOND)
        print('  set_state', st.value_nick, '->', r.value_nick, r2.value_nick, cur.value_nick)
        return r2

    def summary(self):
        n = len(self.frames)
        pts = [f[0] for f in self.frames]
        sizes = sorted(set((f[1], f[2]) for f in self.frames))
        means = [f[3] for f in self.frames]
        black = sum(1 for m in means if m < 3)
        print('  frames=%d sizes=%s black=%d eos=%s error=%s t=%.1fs' % (n, sizes, black, self.eos, self.error, time.time() - self.t0))
        if pts:
            ps = [p / 1e9 if p != Gst.CLOCK_TIME_NONE else -1 for p in pts]
            print('  pts first=%.3f last=%.3f min=%.3f max=%.3f' % (ps[0], ps[-1], min(ps), max(ps)))

    def stop(self):
        self.pipe.set_state(Gst.State.NULL)

def pts_s(f): return f[0] / 1e9

def stitchbin_2(extra_bin='', srcs=None):
    srcs = srcs or (L, R)
    d = 'stitchbin name=b %s %s ' % (extra_bin, TAIL)
    for i, s in enumerate(srcs):
        d += ' ' + dec(s, 'b.sink_%d' % i)
    return d

CHAIN = 'stitchsync name=b ! stitchcalib ! stitchcolor ! stitchflowwarp ! stitchblend'
def chain_2(srcs=None):
    srcs = srcs or (L, R)
    d = CHAIN + TAIL
    for i, s in enumerate(srcs):
        d += ' ' + dec(s, 'b.sink_%d' % i)
    return d

def seek_flush(r, pos_s, flags=Gst.SeekFlags.FLUSH | Gst.SeekFlags.ACCURATE, rate=1.0, stop=-1):
    if rate >= 0:
        ok = r.pipe.seek(rate, Gst.Format.TIME, flags, Gst.SeekType.SET, int(pos_s * Gst.SECOND),
                         Gst.SeekType.SET if stop >= 0 else Gst.SeekType.NONE, int(stop * Gst.SECOND) if stop >= 0 else -1)
    else:
        ok = r.pipe.seek(rate, Gst.Format.TIME, flags, Gst.SeekType.SET, 0, Gst.SeekType.SET, int(pos_s * Gst.SECOND))
    print('  seek(rate=%s pos=%s) ->' % (rate, pos_s), ok)
    return ok

# ---------------- cases ----------------
def case_seek_mid(desc_fn):
    r = Run(sys.argv[1], desc_fn())
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(30, until_frames=40)); r.save('before')
    n0 = len(r.frames)
    seek_flush(r, 4.0)
    print(' ', r.loop(20, until_frames=n0 + 10))
    post = r.frames[n0:]
    print('  post-seek pts:', ['%.2f' % pts_s(f) for f in post[:6]])
    r.save('after_mid')
    n1 = len(r.frames)
    seek_flush(r, 0.0)
    print(' ', r.loop(20, until_frames=n1 + 10))
    print('  post-seek0 pts:', ['%.2f' % pts_s(f) for f in r.frames[n1:n1 + 6]])
    r.save('after_start')
    print(' ', r.loop(40))
    r.save('end')
    r.summary(); r.stop()

def case_seek_simple():
    r = Run(sys.argv[1], stitchbin_2())
    r.state(Gst.State.PLAYING, 20)
    r.loop(30, until_frames=30)
    n0 = len(r.frames)
    ok = r.pipe.seek_simple(Gst.Format.TIME, Gst.SeekFlags.FLUSH | Gst.SeekFlags.KEY_UNIT, 5 * Gst.SECOND)
    print('  seek_simple ->', ok)
    print(' ', r.loop(20, until_frames=n0 + 8))
    print('  post-seek pts:', ['%.2f' % pts_s(f) for f in r.frames[n0:n0 + 6]]); r.save('after')
    print(' ', r.loop(40)); r.summary(); r.stop()

def case_seek_paused():
    r = Run(sys.argv[1], stitchbin_2())
    r.state(Gst.State.PAUSED, 30)
    seek_flush(r, 3.0)
    r.pipe.get_state(20 * Gst.SECOND)
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(20, until_frames=8))
    print('  first pts:', ['%.2f' % pts_s(f) for f in r.frames[:8]]); r.save('first')
    print(' ', r.loop(40)); r.summary(); r.stop()

def case_segment_seek():
    r = Run(sys.argv[1], stitchbin_2())
    r.state(Gst.State.PAUSED, 30)
    ok = r.pipe.seek(1.0, Gst.Format.TIME, Gst.SeekFlags.FLUSH | Gst.SeekFlags.SEGMENT | Gst.SeekFlags.ACCURATE,
                     Gst.SeekType.SET, 1 * Gst.SECOND, Gst.SeekType.SET, 2 * Gst.SECOND)
    print('  segment seek ->', ok)
    r.state(Gst.State.PLAYING, 20)
    res = 'timeout'
    end = time.time() + 40
    while time.time() < end:
        r.pull(); r.poll_bus()
        if 'segment-done' in r.msgs or r.eos or r.error: break
    print('  segment-done seen:', 'segment-done' in r.msgs, 'eos', r.eos)
    r.save('seg'); r.summary(); r.stop()

def case_rate(rate):
    r = Run(sys.argv[1], stitchbin_2())
    r.state(Gst.State.PLAYING, 20)
    r.loop(30, until_frames=30)
    n0 = len(r.frames)
    seek_flush(r, 3.0, rate=rate)
    print(' ', r.loop(40))
    post = r.frames[n0:]
    print('  post pts:', ['%.2f' % pts_s(f) for f in post[:5]], '...', ['%.2f' % pts_s(f) for f in post[-3:]])
    r.save('rate'); r.summary(); r.stop()

def case_pause_resume(live):
    d = stitchbin_live() if live else stitchbin_2()
    r = Run(sys.argv[1], d)
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(30, until_frames=30)); n0 = len(r.frames)
    r.state(Gst.State.PAUSED, 10)
    time.sleep(float(os.environ.get("PAUSE_S", "2"))); r.poll_bus()  # PAUSE_S: how long PAUSED lasts
    r.state(Gst.State.PLAYING, 10)
    print(' ', r.loop(20, until_frames=n0 + 20))
    print('  pts around pause:', ['%.2f' % pts_s(f) for f in r.frames[n0 - 3:n0 + 5]])
    r.save('resumed')
    print(' ', r.loop(40 if not live else 3)); r.summary(); r.stop()

def stitchbin_live():
    # live cameras: a videotestsrc pair (no features) placed by the limlight rig
    rig = REPO + '/examples/limlight_rig.json'
    caps = 'video/x-raw,width=720,height=404,framerate=30/1'
    return ('stitchbin name=b rig-file=%s refine=none %s videotestsrc is-live=true ! %s ! b.sink_0 '
            'videotestsrc is-live=true pattern=ball ! %s ! b.sink_1' % (rig, TAIL, caps, caps))

def case_ready_cycle(to, fn=None):
    r = Run(sys.argv[1], (fn or stitchbin_2)())
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(30, until_frames=30)); r.save('first')
    n0 = len(r.frames)
    r.state(to, 10)
    r.eos = False
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(60))
    post = r.frames[n0:]
    print('  second run frames=%d pts first:' % len(post), ['%.2f' % pts_s(f) for f in post[:4]])
    r.save('second'); r.summary()
    if to == Gst.State.NULL:
        n1 = len(r.frames)
        r.state(Gst.State.NULL); r.eos = False
        r.state(Gst.State.PLAYING, 20)
        print(' ', r.loop(60))
        print('  third run frames=%d' % (len(r.frames) - n1)); r.save('third')
    r.summary(); r.stop()

def case_caps_change(fmt_change=False, chain=False):
    # camera 1 through videoscale ! capsfilter, changed at run time
    blk = CHAIN if chain else 'stitchbin name=b'
    if fmt_change:
        d = (blk + TAIL + ' ' + dec(L, 'videoconvert ! capsfilter name=cf caps=video/x-raw,format=I420 ! b.sink_0 ') +
             dec(R, 'b.sink_1'))
    else:
        d = (blk + TAIL + ' ' + dec(L, 'videoscale ! capsfilter name=cf caps=video/x-raw,width=720,height=404 ! b.sink_0 ') +
             dec(R, 'b.sink_1'))
    r = Run(sys.argv[1], d)
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(30, until_frames=60)); r.save('before')
    cf = r.pipe.get_by_name('cf')
    cf.set_property('caps', Gst.Caps.from_string('video/x-raw,format=NV12' if fmt_change else 'video/x-raw,width=960,height=540'))
    print('  caps changed at frame', len(r.frames))
    n0 = len(r.frames)
    print(' ', r.loop(60))
    r.save('after'); r.summary()
    post = r.frames[n0:]
    print('  post sizes', sorted(set((f[1], f[2]) for f in post)), 'post frames', len(post))
    r.stop()

def case_rates(r0, r1):
    d = ('stitchbin name=b' + TAIL + ' ' + dec(L, 'videorate ! video/x-raw,framerate=%s ! b.sink_0 ' % r0) +
         dec(R, 'videorate ! video/x-raw,framerate=%s ! b.sink_1' % r1))
    r = Run(sys.argv[1], d)
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(90)); r.save('end'); r.summary()
    ps = [pts_s(f) for f in r.frames]
    d = np.diff(ps)
    print('  out frame interval: median %.4f min %.4f max %.4f' % (np.median(d), d.min(), d.max()))
    r.stop()

def case_formats(fmt):
    d = ('stitchbin name=b' + TAIL + ' ' + dec(L, 'videoconvert ! video/x-raw,format=%s ! b.sink_0 ' % fmt) + dec(R, 'b.sink_1'))
    try:
        r = Run(sys.argv[1], d)
    except Exception as e:
        print('  parse error', e); return
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(60)); r.save('end'); r.summary(); r.stop()

def case_eos_one():
    d = ('stitchbin name=b' + TAIL + ' ' + dec(L, 'b.sink_0 ') +
         'filesrc location=%s ! qtdemux ! h264parse ! avdec_h264 ! identity eos-after=60 ! b.sink_1' % R)
    r = Run(sys.argv[1], d)
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(90)); r.save('end'); r.summary(); r.stop()

def case_eos_chain_one():
    d = (CHAIN + TAIL + ' ' + dec(L, 'b.sink_0 ') +
         'filesrc location=%s ! qtdemux ! h264parse ! avdec_h264 ! identity eos-after=60 ! b.sink_1' % R)
    r = Run(sys.argv[1], d)
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(90)); r.save('end'); r.summary(); r.stop()

CASES = {
    'seek_mid_bin': lambda: case_seek_mid(stitchbin_2),
    'seek_mid_chain': lambda: case_seek_mid(chain_2),
    'seek_mid_3cam': lambda: case_seek_mid(lambda: stitchbin_2(srcs=H3)),
    'seek_simple': case_seek_simple,
    'seek_paused': case_seek_paused,
    'segment_seek': case_segment_seek,
    'rate2': lambda: case_rate(2.0),
    'rate_neg': lambda: case_rate(-1.0),
    'pause_nonlive': lambda: case_pause_resume(False),
    'pause_live': lambda: case_pause_resume(True),
    'ready_cycle': lambda: case_ready_cycle(Gst.State.READY),
    'null_cycle': lambda: case_ready_cycle(Gst.State.NULL),
    'ready_cycle_chain': lambda: case_ready_cycle(Gst.State.READY, chain_2),
    'null_cycle_chain': lambda: case_ready_cycle(Gst.State.NULL, chain_2),
    'caps_size': lambda: case_caps_change(False),
    'caps_size_chain': lambda: case_caps_change(False, True),
    'caps_format': lambda: case_caps_change(True),
    'rates_25_30': lambda: case_rates('25/1', '30/1'),
    'rates_60_30': lambda: case_rates('60/1', '30/1'),
    'eos_one': case_eos_one,
    'eos_one_chain': case_eos_chain_one,
}
for f in ('I420_10LE', 'P010_10LE', 'GRAY8', 'BGRx', 'RGB', 'Y444', 'YUY2', 'GRAY16_LE', 'I422_10LE', 'v210'):
    CASES['fmt_' + f] = (lambda f=f: case_formats(f))


def case_seek_during_calib():
    r = Run(sys.argv[1], stitchbin_2())
    r.state(Gst.State.PLAYING, 20)
    r.loop(0.3)
    seek_flush(r, 5.0)
    print(' ', r.loop(30, until_frames=5))
    print('  first pts:', ['%.2f' % pts_s(f) for f in r.frames[:6]]); r.save('after')
    print(' ', r.loop(40)); r.summary(); r.stop()

def case_null_during_calib():
    r = Run(sys.argv[1], stitchbin_2(srcs=H3))
    for i in range(4):
        t = time.time()
        r.state(Gst.State.PLAYING, 20)
        r.loop(0.2 + 0.3 * i, stop_on_eos=False)
        t1 = time.time(); r.state(Gst.State.NULL, 30)
        print('  cycle %d: to NULL took %.2fs' % (i, time.time() - t1))
    r.eos = False; r.error = None; n0 = len(r.frames)
    r.state(Gst.State.PLAYING, 20)
    print(' ', r.loop(60, until_frames=n0 + 60)); r.save('last'); r.summary()
    t1 = time.time(); r.stop(); print('  final NULL %.2fs' % (time.time() - t1))

def case_seek_to(pos):
    r = Run(sys.argv[1], stitchbin_2())
    r.state(Gst.State.PLAYING, 20)
    r.loop(30, until_frames=20); n0 = len(r.frames)
    seek_flush(r, pos)
    print(' ', r.loop(40))
    print('  post pts:', ['%.2f' % pts_s(f) for f in r.frames[n0:n0 + 5]], 'n', len(r.frames) - n0)
    r.save('after'); r.summary(); r.stop()

def case_segment_loop():
    r = Run(sys.argv[1], stitchbin_2())
    r.state(Gst.State.PAUSED, 30)
    r.pipe.seek(1.0, Gst.Format.TIME, Gst.SeekFlags.FLUSH | Gst.SeekFlags.SEGMENT | Gst.SeekFlags.ACCURATE,
                Gst.SeekType.SET, 0, Gst.SeekType.SET, 2 * Gst.SECOND)
    r.state(Gst.State.PLAYING, 20)
    loops = 0; end = time.time() + 60
    while time.time() < end and loops < 3:
        r.pull(); r.poll_bus()
        if r.error or r.eos: break
        if r.msgs.count('segment-done') > loops:
            loops += 1
            ok = r.pipe.seek(1.0, Gst.Format.TIME, Gst.SeekFlags.SEGMENT | Gst.SeekFlags.ACCURATE,
                             Gst.SeekType.SET, 0, Gst.SeekType.SET, 2 * Gst.SECOND)
            print('  loop %d at frame %d, non-flushing seek %s' % (loops, len(r.frames), ok))
    while r.pull(0.5) is not None: pass
    ps = [pts_s(f) for f in r.frames]
    print('  frames', len(ps), 'pts head', ['%.2f' % p for p in ps[:3]], 'around loop', ['%.2f' % p for p in ps[55:65]])
    r.save('loop'); r.summary(); r.stop()

def case_caps_twice():
    d = ('stitchbin name=b' + TAIL + ' ' + dec(L, 'videoscale ! capsfilter name=cf caps=video/x-raw,width=720,height=404 ! b.sink_0 ') + dec(R, 'b.sink_1'))
    r = Run(sys.argv[1], d)
    r.state(Gst.State.PLAYING, 20)
    r.loop(30, until_frames=40)
    cf = r.pipe.get_by_name('cf')
    cf.set_property('caps', Gst.Caps.from_string('video/x-raw,width=480,height=270'))
    r.loop(30, until_frames=45)
    cf.set_property('caps', Gst.Caps.from_string('video/x-raw,width=1280,height=720'))
    r.loop(30, until_frames=100); r.save('mid')
    print(' ', r.loop(60)); r.save('end'); r.summary(); r.stop()

def case_send_eos():
    r = Run(sys.argv[1], stitchbin_2(srcs=H3))
    r.state(Gst.State.PLAYING, 20)
    r.loop(0.5, stop_on_eos=False)
    t1 = time.time()
    r.pipe.send_event(Gst.Event.new_eos())
    print(' ', r.loop(60), 'eos after %.2fs' % (time.time() - t1)); r.save('end'); r.summary(); r.stop()

CASES.update({
    'seek_during_calib': case_seek_during_calib,
    'null_during_calib': case_null_during_calib,
    'seek_past_short': lambda: case_seek_to(7.6),
    'seek_past_end': lambda: case_seek_to(20.0),
    'segment_loop': case_segment_loop,
    'caps_twice': case_caps_twice,
    'send_eos': case_send_eos,
})
if __name__ == '__main__':
    print('==', sys.argv[1])
    CASES[sys.argv[1]]()
    print('== done', sys.argv[1])
