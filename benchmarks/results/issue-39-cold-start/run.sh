#!/bin/bash
# Interleaved: the full forest's cold first frame (no prepared data on
# disk), the binary at d8020c0 (before) against this commit's (after); then
# a cold and a warm process on the 0.05 forest, sharing a prepared-data
# cache, for the kernels' share. Run from the repository root with the two
# release binaries at /tmp/cold/sylva-before and ./target/release/sylva.
set -e
. scripts/env.sh
out=benchmarks/results/issue-39-cold-start
mkdir -p /tmp/cold
./target/release/sylva scene forest --scale 1 -o /tmp/cold/forest-1.json
./target/release/sylva scene forest --scale 0.05 -o /tmp/cold/f05.json
bin() { if [ "$1" = before ]; then echo /tmp/cold/sylva-before; else echo ./target/release/sylva; fi; }
for round in 1 2; do
  for b in before after; do
    /usr/bin/time -f "$b $round: %e s wall, %U s user" "$(bin $b)" render /tmp/cold/forest-1.json \
      --local-workers 0 --width 896 --height 448 --spp 1 --prepared-cache-mib 0 \
      -o /tmp/cold/$b-$round.png > /tmp/cold/$b-$round.log 2>&1
    tail -1 /tmp/cold/$b-$round.log
    cp /tmp/cold/$b-$round.stats.json $out/forest-1-$b-$round.stats.json
  done
done
cmp /tmp/cold/before-1.png /tmp/cold/after-1.png && echo "the same PNG"
for b in before after; do
  rm -rf /tmp/cold/cache-$b
  for run in cold warm; do
    "$(bin $b)" render /tmp/cold/f05.json --local-workers 0 --width 896 --height 448 --spp 1 \
      --lighting lb --prepared-cache-dir /tmp/cold/cache-$b --prepared-cache-mib 65536 \
      -o /tmp/cold/f05-$b-$run.png > /dev/null 2>&1
    cp /tmp/cold/f05-$b-$run.stats.json $out/forest-0.05-$b-$run.stats.json
  done
done
