#!/bin/bash
# first-frames: how many panoramas stitchbin (DEFAULT properties, save-file only) makes from
# non-live files, against the frames each camera gives; one JPEG per panorama is kept.
#   bench/eval/frames_out.sh PLUGIN_DIR OUT FILE...     (FILE k goes to sink_k)
# Prints: frames in (the shortest file's, counted by the decoder), panoramas out, the first
# panorama's pts, wall time, the calibrations announced and any error.
set -u
PLUG=$1; O=$2; shift 2
mkdir -p "$O"; rm -f "$O"/pano_*.jpg "$O"/bus.log
SRC=""; k=0
for f in "$@"; do SRC="$SRC filesrc location=$f ! decodebin ! s.sink_$k"; k=$((k + 1)); done
in=999999
for f in "$@"; do
  n=$(GST_PLUGIN_PATH=$PLUG gst-launch-1.0 -v filesrc location=$f ! decodebin ! fakesink silent=false 2>/dev/null | grep -c "last-message = chain")
  [ "$n" -lt "$in" ] && in=$n
done
t0=$(date +%s.%N)
GST_PLUGIN_PATH=$PLUG timeout ${TMO:-600} gst-launch-1.0 -e -m -v stitchbin name=s save-file=$O/calib.json ! videoconvert ! \
  identity silent=false ! jpegenc ! multifilesink location=$O/pano_%04d.jpg $SRC > "$O"/bus.log 2>&1
rc=$?
wall=$(echo "$(date +%s.%N) - $t0" | bc)
out=$(ls "$O"/pano_*.jpg 2>/dev/null | wc -l)
first=$(grep -o 'identity0: last-message = chain.*pts: [0-9:.]*' "$O"/bus.log | head -1 | grep -o 'pts: [0-9:.]*')
echo "RUN $O rc=$rc frames_in=$in panoramas_out=$out first_$first wall=${wall}s"
grep -o 'stitchcalib[-a-z]*, \(version\|reason\)=[^;]*source=(string)[a-z]*\|stitchcalib-pending, reason=(string)"[^"]*' "$O"/bus.log | cut -c1-160 | sort | uniq -c | head -6
grep -o 'ERROR.*\|WARNING: from element[^:]*: [^\n]*' "$O"/bus.log | cut -c1-200 | sort | uniq -c | head -4
exit 0
