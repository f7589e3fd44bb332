# BENCHMARKS.md, "probe5": the middle camera of karthik_3cam_house changes resolution mid-stream.
import os, sys
sys.argv = ['x', 'caps3_middle']
HERE = os.path.dirname(os.path.abspath(__file__))
exec(open(os.path.join(HERE, 'probe.py')).read().split("if __name__")[0])  # probe.py's helpers
d = ('stitchbin name=b' + TAIL + ' ' + dec(H3[0], 'b.sink_0 ') +
     dec(H3[1], 'videoscale ! capsfilter name=cf caps=video/x-raw,width=640,height=480 ! b.sink_1 ') + dec(H3[2], 'b.sink_2'))
r = Run('caps3_middle', d)
r.state(Gst.State.PLAYING, 20)
print(' ', r.loop(60, until_frames=90)); r.save('before')
r.pipe.get_by_name('cf').set_property('caps', Gst.Caps.from_string('video/x-raw,width=320,height=240'))
n0 = len(r.frames)
print(' ', r.loop(90, until_frames=n0 + 150)); r.save('after'); r.summary()
print('  post sizes', sorted(set((f[1], f[2]) for f in r.frames[n0:])))
r.stop()
