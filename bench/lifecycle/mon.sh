#!/bin/bash
# usage: mon.sh LOG cmd...   runs cmd in background, samples RSS/fds/threads every 3 s
log=$1; shift
"$@" > $log.out 2>&1 &
P=$!
while kill -0 $P 2>/dev/null; do
  echo "$(date +%s) rss_kb=$(awk '/VmRSS/{print $2}' /proc/$P/status 2>/dev/null) fds=$(ls /proc/$P/fd 2>/dev/null | wc -l) thr=$(ls /proc/$P/task 2>/dev/null | wc -l)" >> $log
  sleep 3
done
wait $P; echo "rc=$?" >> $log
