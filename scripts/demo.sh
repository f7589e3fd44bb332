#!/usr/bin/env bash
# The main job on the embedded sample: two real phone clips (data/limlight_2cam_apartment,
# Apache-2.0) -> stitchsync ! stitchcalib ! stitchcolor ! stitchflowwarp ! stitchblend -> out/panorama.mp4 + .png.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
export GST_PLUGIN_PATH="$PWD/build/gst${GST_PLUGIN_PATH:+:$GST_PLUGIN_PATH}"
mkdir -p out
rm -f out/panorama.mp4 out/panorama.png out/calibration.json

left=data/limlight_2cam_apartment/left.mp4
right=data/limlight_2cam_apartment/right.mp4
gst-launch-1.0 -q \
  stitchsync name=s ! stitchcalib save-file=out/calibration.json recalibrate-interval=1 ! stitchcolor ! stitchflowwarp ! stitchblend crop=auto ! \
  tee name=t \
  t. ! queue ! videoconvert ! x264enc tune=zerolatency speed-preset=veryfast ! mp4mux ! \
       filesink location=out/panorama.mp4 \
  t. ! queue ! videoconvert ! pngenc compression-level=3 ! \
       multifilesink sync=false max-files=1 location=out/panorama.png \
  filesrc location="$left" ! decodebin ! s.sink_0 \
  filesrc location="$right" ! decodebin ! s.sink_1

for f in out/panorama.mp4 out/panorama.png out/calibration.json; do
  [ -s "$f" ] || { echo "demo: $f was not written" >&2; exit 1; }
done
echo "Panorama video:    $PWD/out/panorama.mp4"
echo "Panorama snapshot: $PWD/out/panorama.png (last frame)"
echo "Calibration:       $PWD/out/calibration.json"
