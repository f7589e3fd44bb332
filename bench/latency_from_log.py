#!/usr/bin/env python3
# Live latency from a GStreamer debug log, for builds without stitch-bench-latency (how the H100
# figures of BENCHMARKS.md "Live latency, measured from capture" were taken with main's build).
# Log: GST_DEBUG=videoaggregator:6,basesink:6,basesrc:6 gst-launch-1.0 stitchsync ... ! fakesink
# name=sink sync=false <live videotestsrc cameras>, filtered to lines with videoaggregator,
# <sink> or basesrc (gzip or plain). The log's clock is put on the pipeline clock through the
# sources' clock waits (the earliest wake-up); each output slot's frames are videoaggregator's
# "Taking new buffer" lines before its "Producing buffer" line; the sink's time is basesink's
# "reset rc_time" line for that slot.
# usage: bench/latency_from_log.py LOG[.gz] [--skip-seconds 1.0]
import gzip, re, sys, statistics, collections
skip = float(sys.argv[sys.argv.index('--skip-seconds') + 1]) if '--skip-seconds' in sys.argv else 1.0
def t(s):
    h,m,sec = s.split(':'); return int(h)*3600+int(m)*60+float(sec)
lines = (gzip.open if sys.argv[1].endswith('.gz') else open)(sys.argv[1], 'rt').read().splitlines()
off=None; prev={}
for l in lines:
    m=re.search(r'<(videotestsrc\d+)>',l)
    if not m: continue
    src=m.group(1)
    if 'waiting for clock' in l: prev[src]=t(l.split('stream_start ')[1])
    if 'clock entry done: 0' in l and src in prev:
        o=t(l.split()[0])-prev.pop(src)
        off=o if off is None else min(off,o)
cur={}; slots=[]; sink={}
pending={}
for l in lines:
    D=t(l.split()[0])-off
    if 'Taking new buffer' in l or 'replacing old' in l:
        m=re.search(r'<\w+:(sink_\d+)>',l)
        if not m: continue
        pad=m.group(1)
        s = t(l.split('start time ')[1]) if 'Taking' in l else t(l.split('start ')[1].split(' out')[0])
        cur[pad]=s
    elif 'Producing buffer for' in l:
        T=t(l.split('running time start ')[1].split(',')[0])
        slots.append((T, dict(cur), D))
    elif 'reset rc_time to time' in l:
        sink[round(t(l.split('reset rc_time to time ')[1]),6)]=D
rows=[]
for T,c,D in slots:
    k=round(T,6)
    if k not in sink or not c or T<skip: continue
    S=sink[k]; newest=max(c.values()); oldest=min(c.values())
    rows.append(((S-newest)*1e3,(S-oldest)*1e3,(S-T)*1e3,(D-newest)*1e3, {p:round((v-T)*1e3,1) for p,v in c.items()}))
print('slots measured', len(rows), 'offset', round(off,4))
for name,i in (('newest->sink',0),('oldest->sink',1),('old probe (sink - slot)',2),('newest->stitchsync aggregate',3)):
    v=sorted(r[i] for r in rows); print('%-30s median %.1f ms  p99 %.1f  min %.1f max %.1f'%(name, statistics.median(v), v[int(0.99*(len(v)-1))], v[0], v[-1]))
print('frame start - slot start per pad (ms), most common:', {p: collections.Counter(r[4][p] for r in rows).most_common(2) for p in rows[-1][4]})
