#!/usr/bin/env bash
# Runs a small CPU stitching pipeline (3 videotestsrc cameras, 64x48, 12 frames, the whole
# chain: stitchsync, stitchcalib, stitchcolor, stitchflowwarp, stitchblend) and checks it for
# memory errors and leaks.
#   run.sh memcheck : valgrind memcheck; fails on any memory error or definite leak (GLib and
#                     GStreamer one-time allocations suppressed: gst-stitch.supp, glib.supp)
#   run.sh leaks    : GST_TRACERS=leaks; fails when any GstObject/GstMiniObject is alive at exit
# GST_PLUGIN_PATH must name the built plugin (meson test sets it).
set -euo pipefail
here="$(cd "$(dirname "$0")" && pwd)"
mode="${1:-memcheck}"
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
cam() { echo "videotestsrc num-buffers=12 pattern=$1 ! video/x-raw,width=64,height=48 ! s.sink_$2"; }
pipeline=(stitchsync name=s backend=cpu ! stitchcalib load-file="$here/rig3_64x48.json"
  ! stitchcolor backend=cpu ! stitchflowwarp backend=cpu ! stitchblend backend=cpu ! fakesink
  $(cam ball 0) $(cam snow 1) $(cam smpte 2))
# no CUDA device is opened with backend=cpu; hide any so that nothing initialises one
export CUDA_VISIBLE_DEVICES=""
case "$mode" in
  memcheck)
    supp=(--suppressions="$here/gst-stitch.supp")
    [ -f /usr/share/glib-2.0/valgrind/glib.supp ] && supp+=(--suppressions=/usr/share/glib-2.0/valgrind/glib.supp)
    set +e
    G_SLICE=always-malloc G_DEBUG=gc-friendly valgrind --leak-check=full --errors-for-leak-kinds=definite \
      --show-leak-kinds=definite --error-exitcode=3 --num-callers=30 "${supp[@]}" \
      gst-launch-1.0 -q "${pipeline[@]}" > "$log" 2>&1
    rc=$?
    set -e
    sed -n '/HEAP SUMMARY/,$p' "$log"
    if [ $rc -ne 0 ]; then cat "$log"; echo "memcheck: errors or definite leaks (exit $rc)"; exit 1; fi
    grep -q "definitely lost: 0 bytes" "$log" || { echo "memcheck: no clean leak summary"; exit 1; }
    echo "memcheck: clean"
    ;;
  leaks)
    GST_TRACERS=leaks GST_DEBUG="GST_TRACER:7" gst-launch-1.0 -q "${pipeline[@]}" > "$log" 2>&1
    grep -q "leaks" "$log" || { echo "leaks: the tracer did not run"; exit 1; }
    if grep -E "object-alive, type-name=\(string\)[A-Za-z]" "$log"; then echo "leaks: objects alive at exit"; exit 1; fi
    grep -q "Leaks detected" "$log" && { echo "leaks: GStreamer reports leaks"; exit 1; }
    echo "leaks: no GstObject or GstMiniObject alive at exit"
    ;;
  *) echo "usage: $0 memcheck|leaks"; exit 2 ;;
esac
