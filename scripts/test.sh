#!/usr/bin/env bash
# Set-up, then the whole test suite (core, elements, pipelines). CI runs exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
meson test -C build --print-errorlogs --num-processes 2 "$@"
