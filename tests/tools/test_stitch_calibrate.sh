#!/bin/bash
# stitch-calibrate on the repository's 2-camera clip (data/limlight_2cam_apartment): it must write
# a loadable rig with a canvas, a preview PNG and a report that names the model and the pair.
set -eu
tool="$1"
src="${STITCH_SOURCE_DIR:?}"
out=$(mktemp -d)
trap 'rm -rf "$out"' EXIT
"$tool" --frames 2 --step 15 --out "$out/rig.json" --preview "$out/preview.png" --report "$out/report.json" \
  "$src/data/limlight_2cam_apartment/left.mp4" "$src/data/limlight_2cam_apartment/right.mp4"
for f in rig.json preview.png report.json; do
  [ -s "$out/$f" ] || { echo "missing $f"; exit 1; }
done
grep -q '"canvas"' "$out/rig.json" || { echo "no canvas in the rig"; exit 1; }
grep -Eq '"model": "(rotation|homography)"' "$out/report.json" || { echo "no model in the report"; exit 1; }
grep -q '"rms_px"' "$out/report.json" || { echo "no residuals in the report"; exit 1; }
# A bad input is a clear error, not a crash.
if "$tool" --out "$out/x.json" "$src/data/limlight_2cam_apartment/left.mp4" /nonexistent.mp4 2>"$out/err"; then
  echo "a missing input succeeded"; exit 1
fi
grep -q "cannot open" "$out/err" || { cat "$out/err"; exit 1; }
echo "ok"
