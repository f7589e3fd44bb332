#!/usr/bin/env bash
# Runs on the GPU host: unpacks the bundle that `scripts/gpu_check.sh pack` made here, runs the
# CUDA-vs-CPU tests, the CUDA benchmark and GPU pipelines; writes logs and JSON to $OUT
# (default: out/gpu). The bundle must stay under the 64 MiB a device call carries, so it holds
# only binaries that link no OpenCV imgcodecs/videoio (their codec and GDAL trees are large).
set -uo pipefail
if [ "${1:-}" = pack ]; then
  rm -rf .gpubundle && mkdir -p .gpubundle
  cp build/tests/boat1_1600.ppm .gpubundle/
  GST_PLUGINS="coreelements videoconvertscale app isomp4 videoparsersbad nvcodec typefindfunctions multifile" \
    ../shared/tools/gpu-bundle .gpubundle/b.tar.gz build/tests/test_cuda build/bench/stitch-bench-cuda \
    build/gst/libgststitch.so
  exit
fi
OUT=${OUT:-out/gpu}
mkdir -p "$OUT"
tar xzf .gpubundle/b.tar.gz && source gpubundle/env.sh
B=gpubundle/build
export STITCH_SOURCE_DIR=$PWD GST_PLUGIN_PATH=$PWD/$B GST_REGISTRY=$PWD/$OUT/registry.bin GST_DEBUG='*:1'
export STITCH_TEST_PPM=$PWD/.gpubundle/boat1_1600.ppm
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$OUT/gpu.txt"
echo "== test_cuda"; $B/test_cuda 2>&1 | tee "$OUT/test_cuda.txt" | grep -E "PSNR|OK|FAIL|SKIP" | head -30
echo "== bench"; $B/stitch-bench-cuda --photo "$STITCH_TEST_PPM" --json "$OUT/cuda.json" 2>&1 | tee "$OUT/bench_cuda.txt"
echo "== pipelines (2 x 720x404 H.264 decoded by nvh264dec)"
L=data/limlight_2cam_apartment
for chain in "stitchblend backend=cpu" "stitchblend backend=cuda" "stitchcolor ! stitchflowwarp ! stitchblend backend=cpu" \
             "stitchcolor ! stitchflowwarp ! stitchblend backend=cuda"; do
  t0=$EPOCHREALTIME
  XDG_RUNTIME_DIR=/tmp gst-launch-1.0 -q stitchsync name=s ! stitchcalib ! $chain ! fakesink \
    filesrc location=$L/left.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_0 \
    filesrc location=$L/right.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_1 2>&1 | grep -v "gldisplay\|nvrtc" | grep -A2 "^ERROR" | head -4
  echo "$chain: rc=${PIPESTATUS[0]} $(awk "BEGIN{print $EPOCHREALTIME - $t0}") s"
done | tee "$OUT/pipelines.txt"
echo "== CUDA memory out of stitchblend (stitchblend ! cudadownload) vs the CPU path"
for b in cuda cpu; do
  if [ $b = cuda ]; then tail="stitchblend ! cudadownload"; else tail="stitchblend backend=cpu"; fi
  XDG_RUNTIME_DIR=/tmp gst-launch-1.0 -v stitchsync name=s ! stitchcalib ! $tail ! video/x-raw,format=RGBA ! \
    multifilesink location=$OUT/pano_$b.raw max-files=1 \
    filesrc location=$L/left.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_0 \
    filesrc location=$L/right.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_1 > "$OUT/interop_$b.log" 2>&1
  echo "$b: rc=$? $(grep -c 'memory:CUDAMemory' "$OUT/interop_$b.log") caps lines with memory:CUDAMemory"
  grep -m2 "stitchblend0.GstPad:src: caps" "$OUT/interop_$b.log" | cut -c1-160
done
python3 - "$OUT" <<'PY'
import sys, numpy as np, os
out = sys.argv[1]
a = np.fromfile(os.path.join(out, "pano_cuda.raw"), np.uint8).astype(np.float64)
b = np.fromfile(os.path.join(out, "pano_cpu.raw"), np.uint8).astype(np.float64)
print("last panorama bytes", a.size, b.size)
if a.size == b.size and a.size:
    mse = np.mean((a - b) ** 2)
    print("CUDA-memory panorama vs CPU panorama: PSNR %.2f dB" % (10 * np.log10(255**2 / mse) if mse else float("inf")))
PY
