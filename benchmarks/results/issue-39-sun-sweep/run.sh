#!/bin/bash
# Interleaved: the sun sweep in one process, old binary (f183f7e) against new.
set -e
cd /work/main
for round in 1 2; do
  for b in old new; do
    bin=/tmp/sylva-old; [ $b = new ] && bin=./target/release/sylva
    out=/tmp/sweep/$b-$round
    /usr/bin/time -f "%e s wall" $bin render /tmp/sw/forest-0.02.json -o $out/day.png --frames 6 --sun-from 15,90 --sun-to 60,200 --local-workers 0 --width 320 --height 160 --spp 2 --lighting lb > $out.log 2>&1
    grep -E "rendered" $out.log | cut -c1-200
  done
done
