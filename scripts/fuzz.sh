#!/usr/bin/env bash
# Fuzzes the rig JSON loader (tests/fuzz/fuzz_rig.cpp, libFuzzer + ASan/UBSan) for a bounded
# time, starting from the seed corpus in tests/fuzz/corpus (copied: the seeds stay as they are).
# Usage: scripts/fuzz.sh [seconds=600] [fuzzer=build/tests/fuzz_rig] [work dir=a fresh temp dir]
# The meson test `fuzz_rig` runs it for 15 s; run it longer by hand. A crash leaves its input as
# <work dir>/crash-*; fix the loader, then add the input to tests/fuzz/corpus as a regression.
set -euo pipefail
here="$(cd "$(dirname "$0")/.." && pwd)"
seconds="${1:-600}"
fuzzer="$(realpath "${2:-$here/build/tests/fuzz_rig}")"
work="${3:-}"
own_work=0
if [ -z "$work" ]; then work="$(mktemp -d)"; own_work=1; fi
mkdir -p "$work/corpus"
cp "$here"/tests/fuzz/corpus/* "$work/corpus/"
cd "$work"
set +e
"$fuzzer" -max_total_time="$seconds" -timeout=5 -rss_limit_mb=2048 -max_len=4096 -print_final_stats=1 \
  corpus > fuzz.log 2>&1
rc=$?
set -e
grep -E "stat::number_of_executed_units|stat::peak_rss_mb|^Done" fuzz.log || true
if [ $rc -ne 0 ]; then
  tail -60 fuzz.log
  echo "fuzz: crash or timeout (exit $rc); input in $work:" $(ls "$work" | grep -E '^(crash|timeout|oom|leak)-' || true)
  exit 1
fi
echo "fuzz: no crash in ${seconds} s"
if [ $own_work -eq 1 ]; then rm -rf "$work"; fi
