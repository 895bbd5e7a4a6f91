#!/bin/bash
# Trace time (ms) of the forest at scale 0.05, 896x448: old binary, new without passes, new with all passes.
export XDG_RUNTIME_DIR=/tmp/sylva-runtime-0 SYLVA_PREPARED_CACHE_MIB=0
spp=$1
for round in 1 2 3; do
  for v in old new passes; do
    case $v in
      old) bin=/tmp/sylva-old; extra=();;
      new) bin=/tmp/sylva-new; extra=();;
      passes) bin=/tmp/sylva-new; extra=(--passes all);;
    esac
    $bin render forest.json --local-workers 0 --accel bvh --lighting lb --spp $spp --width 896 --height 448 -o $v.png "${extra[@]}" >/dev/null 2>&1
    python3 -c "import json; s=json.load(open('$v.stats.json')); print('$v', $round, [p['ms'] for p in s['phases_ms'] if p['phase']=='trace'])"
  done
done
