#!/bin/bash
# probe4: render rig geometries nobody tuned for and run each through stitchbin with defaults.
#   bench/eval/probe4_cases.sh OUTDIR PHOTO [CASE...]     (no CASE: all)
# Each case: OUTDIR/CASE/{camK.avi,truth.json,out_NNN.png,calib.json,bus.log}; one summary
# block per case on stdout (bench/eval/probe_case.sh).
set -u
O=$1; P=$2; shift 2
HERE=$(cd "$(dirname "$0")/../.." && pwd)
R="/usr/bin/python3 $HERE/bench/eval/render_geom.py --photo $P --frames 20"
L="640,480"
declare -A C
# name -> "cams (yaw,pitch,roll,hfov,w,h;...)|pads"
C[base3]="-30,0,0,55,$L;0,0,0,55,$L;30,0,0,55,$L|0 1 2"
C[reverse4]="-45,0,0,55,$L;-15,0,0,55,$L;15,0,0,55,$L;45,0,0,55,$L|3 2 1 0"
C[shuffle5]="-40,0,0,50,$L;-20,0,0,50,$L;0,0,0,50,$L;20,0,0,50,$L;40,0,0,50,$L|2 4 0 3 1"
C[vstack3]="0,30,0,60,$L;0,0,0,60,$L;0,-30,0,60,$L|0 1 2"
C[grid2x2]="-18,14,0,55,$L;18,14,0,55,$L;-18,-14,0,55,$L;18,-14,0,55,$L|0 1 2 3"
C[portrait]="-22,0,0,55,$L;22,0,0,42,480,640|0 1"
C[roll90]="-20,0,0,55,$L;15,0,90,55,$L|0 1"
C[roll90x3]="-30,0,0,55,$L;0,0,90,55,$L;30,0,0,55,$L|0 1 2"
C[roll180]="-25,0,0,55,$L;25,0,180,55,$L|0 1"
C[roll180mid]="-30,0,0,55,$L;0,0,180,55,$L;30,0,0,55,$L|0 1 2"
C[zoom15]="-22,0,0,60,$L;20,0,0,41.8,$L|0 1"
C[mixres]="-25,0,0,60,1920,1080;25,0,0,60,1280,720|0 1"
C[overlap12]="-24.5,0,0,55,$L;24.5,0,0,55,$L|0 1"
C[overlap12x3]="-49,0,0,55,$L;0,0,0,55,$L;49,0,0,55,$L|0 1 2"
C[overlap75]="-6.5,0,0,55,$L;6.5,0,0,55,$L|0 1"
C[tilt20]="-30,20,0,55,$L;0,20,0,55,$L;30,20,0,55,$L|0 1 2"
C[handheld]="-30,4,-8,55,$L;0,-3,6,55,$L;30,5,10,55,$L|0 1 2"
# Equirectangular source (PHOTO must then be a 360x180 panorama): name -> "cams|pads|eq"
ring() { # N HFOV PITCH: N cameras around 360 degrees
  local n=$1 h=$2 p=$3 out="" k; for ((k = 0; k < n; k++)); do out="$out$((k * 360 / n - 180)),$p,0,$h,$L;"; done; echo "$out"; }
C[ering8rev]="$(ring 8 65 0)|7 6 5 4 3 2 1 0|eq"
C[ering6shuf]="$(ring 6 75 0)|3 0 5 1 4 2|eq"
C[ering8tilt20]="$(ring 8 65 20)|0 1 2 3 4 5 6 7|eq"
C[ering6ov8]="$(ring 6 65 0)|0 1 2 3 4 5|eq"
C[ering6ov12]="$(ring 6 68 0)|0 1 2 3 4 5|eq"
C[ering4wide]="$(ring 4 100 0)|0 1 2 3|eq"
C[evstack4]="0,60,0,60,$L;0,20,0,60,$L;0,-20,0,60,$L;0,-60,0,60,$L|0 1 2 3|eq"
C[evstack4b]="0,45,0,60,$L;0,15,0,60,$L;0,-15,0,60,$L;0,-45,0,60,$L|0 1 2 3|eq"
C[eupside0]="-25,0,180,55,$L;25,0,0,55,$L|0 1|eq"
C[eside0]="-20,0,90,55,$L;15,0,0,55,$L|0 1|eq"
C[egrid3x2]="-40,15,0,55,$L;0,15,0,55,$L;40,15,0,55,$L;-40,-15,0,55,$L;0,-15,0,55,$L;40,-15,0,55,$L|0 1 2 3 4 5|eq"
C[ezoom2]="-20,0,0,70,$L;15,0,0,38.6,$L;50,0,0,70,$L|0 1 2|eq"
EQCASES="ering8rev ering6shuf ering8tilt20 ering6ov8 ering6ov12 ering4wide evstack4 evstack4b eupside0 eside0 egrid3x2 ezoom2"
CASES=${*:-base3 reverse4 shuffle5 vstack3 grid2x2 portrait roll90 roll90x3 roll180 roll180mid zoom15 mixres overlap12 overlap12x3 overlap75 tilt20 handheld}
for c in $CASES; do
  spec=${C[$c]}
  IFS='|' read -r cams pads eq <<< "$spec"
  mkdir -p "$O/$c"
  [ -f "$O/$c/truth.json" ] || $R ${eq:+--equirect 1} --out "$O/$c" --cams="$cams" > /dev/null || { echo "CASE $c: render failed"; continue; }
  PADS="$pads" "$HERE"/bench/eval/probe_case.sh "$O/$c"
done
