#!/usr/bin/env bash
# Runs on the GPU host: unpacks the bundle that `scripts/gpu_check.sh pack` made here, runs the
# CUDA-vs-CPU tests, the CUDA benchmarks (kernels, core chain, GStreamer pipelines) and GPU
# pipelines; writes logs and JSON to $OUT (default: out/gpu). The bundle must stay under the
# 64 MiB a device call carries, so it holds only binaries that link no OpenCV
# imgcodecs/videoio (their codec and GDAL trees are large).
# usage: scripts/gpu_check.sh pack [BUILD_DIR]   (here)
#        OUT=... scripts/gpu_check.sh [quick|blend|e2e|handoff|sysmem] (on the GPU host; quick: tests only;
#                                                   sysmem: tests, system-memory input A/B (RGBA, I420);
#                                                   handoff: tests, event vs host-sync hand-off A/B;
#                                                   blend: tests, blend modes, decoded pipelines)
set -uo pipefail
GPU_TESTS="test_cuda test_flow_warp test_cuda_flow test_cuda_color test_cuda_convert test_cuda_memory test_gpu_faults test_projection test_cuda_blend test_lens_cuda"
if [ "${1:-}" = pack ]; then
  BUILD=${2:-build}
  rm -rf .gpubundle && mkdir -p .gpubundle
  cp "$BUILD/tests/boat1_1600.ppm" .gpubundle/
  bins=""
  for t in $GPU_TESTS; do [ -x "$BUILD/tests/$t" ] && bins="$bins $BUILD/tests/$t"; done
  for b in stitch-bench-cuda stitch-bench-chain stitch-bench-pipeline stitch-bench-projection stitch-bench-blend stitch-bench-e2e stitch-bench-lens-timing; do
    [ -x "$BUILD/bench/$b" ] && bins="$bins $BUILD/bench/$b"
  done
  GST_PLUGINS="coreelements videoconvertscale app isomp4 videoparsersbad nvcodec typefindfunctions multifile videotestsrc x264 x265" \
    ../shared/tools/gpu-bundle .gpubundle/b.tar.gz $bins "$BUILD/gst/libgststitch.so"
  du -sh .gpubundle
  exit
fi
OUT=${OUT:-out/gpu}
mkdir -p "$OUT"
tar xzf .gpubundle/b.tar.gz && source gpubundle/env.sh
B=gpubundle/build  # the bundle keeps the binaries flat
export STITCH_SOURCE_DIR=$PWD GST_PLUGIN_PATH=$PWD/$B GST_REGISTRY=$PWD/$OUT/registry.bin GST_DEBUG='*:1'
export STITCH_TEST_PPM=$PWD/.gpubundle/boat1_1600.ppm XDG_RUNTIME_DIR=/tmp
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv | tee "$OUT/gpu.txt"
for t in $GPU_TESTS; do
  [ -x "$B/$t" ] || continue
  echo "== $t"
  timeout 300 "$B/$t" > "$OUT/$t.log" 2>&1
  echo "rc=$?"
  grep -E "PSNR|FLOW|COLOR|MULTIBAND|CONVERT|FLOWWARP|GPUFAULT|\[  (FAILED|PASSED|SKIPPED) |Failure|error" "$OUT/$t.log" | head -40
done 2>&1 | tee "$OUT/tests.txt"
if [ "${1:-}" = e2e ]; then
  echo "== end to end: NVDEC-decoded H.264/H.265 cameras into the chain, decode-only ceiling, rigs per process, live latency"
  timeout 560 $B/stitch-bench-e2e --photo "$STITCH_TEST_PPM" --frames ${E2E_FRAMES:-300} --dir /tmp/stitch-e2e --handoff ${E2E_HANDOFF:-event} \
    --json "$OUT/e2e.json" 2>&1 | grep -v "nvrtc\|gldisplay" | tee "$OUT/bench_e2e.txt"
  exit
fi
if [ "${1:-}" = handoff ]; then
  echo "== stream-ordered hand-off vs per-element host synchronisation (STITCH_CUDA_HOST_SYNC=1)"
  Q="queue max-size-buffers=2 ! stitchcolor ! queue max-size-buffers=2 ! stitchflowwarp ! queue max-size-buffers=2 ! stitchblend"
  for mode in "--cuda-input" "" "--system-output"; do
    timeout 170 $B/stitch-bench-pipeline --photo "$STITCH_TEST_PPM" --frames 400 --handoff both $mode \
      --json "$OUT/handoff${mode//-/_}.json" 2>&1 | grep -v "nvrtc\|gldisplay" | tee -a "$OUT/bench_handoff.txt"
  done
  timeout 170 $B/stitch-bench-pipeline --photo "$STITCH_TEST_PPM" --frames 400 --handoff both --cuda-input \
    --chain "$Q" --json "$OUT/handoff_queues.json" 2>&1 | grep -v "nvrtc\|gldisplay" | tee -a "$OUT/bench_handoff.txt"
  echo "== CPU chain at 3x1080p on 1..16 threads (the host's idle cores)" | tee -a "$OUT/bench_handoff.txt"
  for t in 1 2 4 8 16; do
    timeout 100 $B/stitch-bench-chain --photo "$STITCH_TEST_PPM" --cpu-only --case 3x1920x1080 --cpu-frames 5 \
      --threads $t 2>&1 | grep -E "threads|^3x" | tee -a "$OUT/bench_handoff.txt"
  done
  exit
fi
if [ "${1:-}" = sysmem ]; then
  echo "== system-memory input (RGBA, I420) and CUDA input: the element chain vs stitchbin (its queue after stitchcalib)"
  run() {  # label, then bench arguments
    local label=$1; shift
    echo "-- $label" | tee -a "$OUT/bench_sysmem.txt"
    timeout 170 $B/stitch-bench-pipeline --photo "$STITCH_TEST_PPM" --frames 400 "$@" 2>&1 \
      | grep -v "nvrtc\|gldisplay\|nvenc" | tee -a "$OUT/bench_sysmem.txt"
  }
  for fmt in RGBA I420; do
    for o in "" "--system-output"; do
      run "$fmt chain ${o:-device output}" --input-format $fmt $o
      run "$fmt stitchbin ${o:-device output}" --input-format $fmt --chain stitchbin $o
    done
  done
  run "CUDA input, chain" --cuda-input
  run "CUDA input, stitchbin" --cuda-input --chain stitchbin
  for env in STITCH_CUDA_NO_PIN_INPUT=1 STITCH_CUDA_NO_PINNED=1; do
    export $env; run "RGBA stitchbin $env" --chain stitchbin; unset ${env%%=*}
  done
  exit
fi
if [ "${1:-}" = quick ]; then (cd "$OUT" && tar czf ../gpu_results.tgz . && rm -rf ./* && mv ../gpu_results.tgz .); exit; fi
MODE=${1:-}
if [ "$MODE" != blend ]; then
echo "== kernels"; timeout 300 $B/stitch-bench-cuda --photo "$STITCH_TEST_PPM" --json "$OUT/cuda.json" 2>&1 | tee "$OUT/bench_cuda.txt"
echo "== projections"; timeout 200 $B/stitch-bench-projection --photo "$STITCH_TEST_PPM" --frames 10 \
  --json "$OUT/projection.json" 2>&1 | tee "$OUT/bench_projection.txt"
echo "== core chain"; timeout 300 $B/stitch-bench-chain --photo "$STITCH_TEST_PPM" --frames 300 --cpu-frames 5 \
  --json "$OUT/chain.json" 2>&1 | tee "$OUT/bench_chain.txt"
echo "== GStreamer pipelines" | tee "$OUT/bench_pipeline.txt"
for mode in "--cuda-input" "" "--system-output"; do
  timeout 280 $B/stitch-bench-pipeline --photo "$STITCH_TEST_PPM" --frames 600 $mode \
    --json "$OUT/pipeline${mode//-/_}.json" 2>&1 | grep -v "nvrtc\|gldisplay" | tee -a "$OUT/bench_pipeline.txt"
done
fi
echo "== blend modes"; timeout 300 $B/stitch-bench-blend --photo "$STITCH_TEST_PPM" --frames 100 --cpu-frames 5 \
  --json "$OUT/blend.json" 2>&1 | tee "$OUT/bench_blend.txt"
echo "== decoded by nvh264dec (2 x 720x404 H.264)"
L=data/limlight_2cam_apartment
for chain in "stitchblend backend=cpu" "stitchblend" "stitchcolor ! stitchflowwarp ! stitchblend backend=cpu" \
             "stitchcolor ! stitchflowwarp ! stitchblend" "stitchcolor ! stitchflowwarp ! stitchblend mode=multiband" \
             "stitchcolor ! stitchflowwarp ! stitchblend mode=multiband seam=dp" \
             "stitchcolor ! stitchflowwarp ! stitchblend mode=multiband seam=dp debug=all" \
             "stitchbin mode=multiband seam=dp"; do
  t0=$EPOCHREALTIME
  head="stitchsync name=s ! stitchcalib ! $chain"
  [ "${chain#stitchbin}" != "$chain" ] && head="$chain name=s"
  gst-launch-1.0 -q $head ! fakesink \
    filesrc location=$L/left.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_0 \
    filesrc location=$L/right.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_1 2>&1 | grep -v "gldisplay\|nvrtc" | grep -A2 "^ERROR" | head -4
  echo "$chain: rc=${PIPESTATUS[0]} $(awk "BEGIN{print $EPOCHREALTIME - $t0}") s"
done 2>&1 | tee "$OUT/pipelines.txt"
if [ "$MODE" = blend ]; then (cd "$OUT" && tar czf ../gpu_results.tgz . && rm -rf ./* && mv ../gpu_results.tgz .); exit; fi
echo "== the whole chain in CUDA memory (nvh264dec ! stitchsync ... stitchblend ! cudadownload) vs the CPU chain"
# The CPU run calibrates and saves; the CUDA run loads that calibration, so both warp alike.
for b in cpu cuda; do
  if [ $b = cuda ]; then
    chain="stitchsync name=s ! stitchcalib load-file=$OUT/calib.json ! stitchcolor ! stitchflowwarp ! stitchblend ! cudadownload"
  else
    chain="stitchsync name=s backend=cpu ! stitchcalib save-file=$OUT/calib.json ! stitchcolor backend=cpu ! stitchflowwarp backend=cpu ! stitchblend backend=cpu"
  fi
  gst-launch-1.0 -v $chain ! video/x-raw,format=RGBA ! multifilesink location=$OUT/pano_$b.raw max-files=1 \
    filesrc location=$L/left.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_0 \
    filesrc location=$L/right.mp4 ! qtdemux ! h264parse ! nvh264dec ! s.sink_1 > "$OUT/interop_$b.log" 2>&1
  echo "$b: rc=$?"
  grep -E "stitch(sync|calib|color|flowwarp|blend)0.GstPad:src: caps" "$OUT/interop_$b.log" | sed 's/, multiview.*//' | cut -c1-150 | sort -u
done 2>&1 | tee "$OUT/interop.txt"
python3 - "$OUT" <<'PY' 2>&1 | tee -a "$OUT/interop.txt"
import sys, numpy as np, os
out = sys.argv[1]
a = np.fromfile(os.path.join(out, "pano_cuda.raw"), np.uint8).astype(np.float64)
b = np.fromfile(os.path.join(out, "pano_cpu.raw"), np.uint8).astype(np.float64)
print("last panorama bytes", a.size, b.size)
if a.size == b.size and a.size:
    mse = np.mean((a - b) ** 2)
    print("CUDA-memory chain vs CPU chain, last panorama: PSNR %.2f dB" % (10 * np.log10(255**2 / mse) if mse else float("inf")))
PY
rm -f "$OUT"/pano_*.raw "$OUT/registry.bin"
# A device call brings back at most 8 files: everything goes home in one archive.
(cd "$OUT" && tar czf ../gpu_results.tgz . && rm -rf ./* && mv ../gpu_results.tgz .)
