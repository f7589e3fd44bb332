#!/bin/bash
# probe4 reproducers (stitchbin, default properties). Needs build/ and ../shared data.
#   bench/eval/repro_probe4.sh ring|sideways|ring8|wide4 [OUT]
# ring:     360 ring of 6 pinholes (hfov 68, 14% overlap) from the jobsite equirect; the pair
#           whose overlap is a textureless duct does not match and takes the whole ring-closure
#           error (11 px, eval_geom pair 1-2) while the bus says alignment-camera-px 0.24.
# sideways: a camera rolled 90 deg beside an upright one (vertical studs become horizontal
#           rows): "camera 0 is corrupt (a torn picture ...)", first panorama at pts 3.0 s of 5 s
#           (fixed 2026-11-25: a tear must lie on a coded block's boundary; now pts 0).
# ring8:    a 6-camera ring with 8% overlap (hfov 65 at 60 deg steps): no output at all.
# wide4:    4 pinholes hfov 100 around 360 (10% overlap): no output.
# wide4long: the same ring seen from the jobsite panorama rolled by a third, 100 frames: 1728x486
#           (true 1687), closing seam 2-3 off by 48.7 px, rms 0.33 / alignment-camera-px 0.52, silent;
#           the pooled recalibration is rejected (the WORST case of probe4).
set -u
HERE=$(cd "$(dirname "$0")/../.." && pwd)
S=${STITCH_SHARED_DATA:-$HERE/../shared/data}
J=$S/images/equirect_jobsite/jobsite1.jpg
O=${2:-/tmp/probe4_repro}
L=640,480
R="/usr/bin/python3 $HERE/bench/eval/render_geom.py --photo $J --equirect 1 --frames 20"
ring() { local n=$1 h=$2 out="" k; for ((k = 0; k < n; k++)); do out="$out$((k * 360 / n - 180)),0,0,$h,$L;"; done; echo "$out"; }
case $1 in
  ring) $R --out $O/ring --cams="$(ring 6 68)" && EVAL_LINES=8 $HERE/bench/eval/probe_case.sh $O/ring ;;
  ring8) $R --out $O/ring8 --cams="$(ring 6 65)" && $HERE/bench/eval/probe_case.sh $O/ring8 ;;
  wide4) $R --out $O/wide4 --cams="$(ring 4 100)" && $HERE/bench/eval/probe_case.sh $O/wide4 ;;
  wide4long)
    mkdir -p $O && /usr/bin/python3 -c "import cv2,numpy as np,sys; im=cv2.imread(sys.argv[1]); cv2.imwrite(sys.argv[2], np.roll(im, im.shape[1]//3, axis=1), [cv2.IMWRITE_JPEG_QUALITY, 95])" $J $O/jobsite_roll.jpg &&
    /usr/bin/python3 $HERE/bench/eval/render_geom.py --photo $O/jobsite_roll.jpg --equirect 1 --frames 100 --out $O/wide4long --cams="$(ring 4 100)" &&
    TMO=400 EVAL_LINES=5 $HERE/bench/eval/probe_case.sh $O/wide4long ;;
  sideways)
    $R --frames 150 --out $O/sideways --cams="-20,0,90,55,$L;15,0,0,55,$L" &&
    GST_PLUGIN_PATH=$HERE/build/gst timeout 200 gst-launch-1.0 -e -v stitchbin name=s ! videoconvert ! \
      identity silent=false ! fakesink filesrc location=$O/sideways/cam0.avi ! decodebin ! s.sink_0 \
      filesrc location=$O/sideways/cam1.avi ! decodebin ! s.sink_1 2>&1 |
      grep -o 'identity0: last-message = chain.*pts: [0-9:.]*\|torn picture[^)]*' | sed -n '1p;$p' ;;
esac
