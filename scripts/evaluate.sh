#!/usr/bin/env bash
# The evaluation suite: our chain, its ablations and OpenCV's stitcher (per frame and
# estimate-once) on ground-truth rigs rendered from real photos and on real clips; one report
# (Markdown table, plots, seam crops) in out/eval. Options: see bench/eval/evaluate.py.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
exec /usr/bin/python3 bench/eval/evaluate.py "$@"
