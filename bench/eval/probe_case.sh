#!/bin/bash
# probe4: run one rendered rig (DIR/camK.avi, pad K = camK) through stitchbin with DEFAULT
# properties (save-file only, to measure), keep the last panorama, the bus messages, rc and
# wall time, and score the calibration against DIR/truth.json when there is one.
#   bench/eval/probe_case.sh DIR [N]        (N: cameras, default: every camK.avi; PADS="2 0 1" feeds
#                                            camK.avi in that order to sink_0, sink_1, ...)
set -u
D=$1
HERE=$(cd "$(dirname "$0")/../.." && pwd)
export GST_PLUGIN_PATH=$HERE/build/gst
N=${2:-$(ls "$D"/cam*.avi | wc -l)}
PADS=${PADS:-$(seq 0 $((N - 1)))}
rm -f "$D"/out_*.png "$D"/calib.json "$D"/bus.log
SRC=""; k=0
for c in $PADS; do SRC="$SRC filesrc location=$D/cam$c.avi ! decodebin ! s.sink_$k"; k=$((k + 1)); done
t0=$(date +%s.%N)
timeout ${TMO:-240} gst-launch-1.0 -e -m stitchbin name=s save-file=$D/calib.json ! videoconvert ! pngenc ! \
  multifilesink location=$D/out_%03d.png max-files=1 $SRC > "$D"/bus.log 2>&1
rc=$?
t1=$(date +%s.%N)
wall=$(echo "$t1 - $t0" | bc)
last=$(ls "$D"/out_*.png 2>/dev/null | tail -1)
nout=$(grep -c "pngenc" /dev/null)
size=$( [ -n "$last" ] && /usr/bin/python3 -c "import cv2,sys;im=cv2.imread('$last');print(f'{im.shape[1]}x{im.shape[0]}')" || echo none)
echo "CASE $D rc=$rc wall=${wall}s last_png=${last:-none} size=$size"
grep 'element "calib".*stitchcalib, ' "$D"/bus.log | while read -r l; do echo "$l" | grep -o ' source=[^,]*\| cameras=[^,]*\| model=[^,]*\|projection=[^,]*\| rms-px=[^,]*\|alignment-camera-px=[^,]*\|left-out=[^;]*\|canvas-width=[^,]*\|canvas-height=[^,]*' | sed 's/(string)\|(double)\|(int)//' | tr '\n' ' '; echo; done | head -4
grep -o 'element "calib".*stitchcalib-[a-z]*' "$D"/bus.log | sed 's/.*(element): //' | sort | uniq -c | tr '\n' ' '; echo
n=$(grep -c 'stitchcalib, ' "$D"/bus.log); echo "calibrations: $n" 
grep -E 'ERROR|WARNING|error:|warning:' "$D"/bus.log | grep -v 'GST_DEBUG\|^Setting\|deprecated' | sed 's/^.*\(debug\|error\|warning\) *[:=]//' | cut -c1-300 | sort | uniq -c | head -8
[ -f "$D"/rig_true.json ] && [ ! -f "$D"/truth.json ] && ln -s rig_true.json "$D"/truth.json; [ -f "$D"/truth.json ] && [ -f "$D"/calib.json ] && /usr/bin/python3 "$HERE"/bench/eval/eval_geom.py "$D"/truth.json "$D"/calib.json "$PADS" | tail -${EVAL_LINES:-1}
exit 0
