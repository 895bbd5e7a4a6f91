#!/bin/bash
# The guides' cost, old binary against new, interleaved: frames 2-4 of an
# in-process 4-frame sequence under one sun are the steady state.
# OLD and NEW: two `sylva` binaries (here: the debug builds of 8902c1a and
# of the commit that folded the guides). Run from the repository root.
set -euo pipefail
: "${OLD:?path to the old sylva}" "${NEW:?path to the new sylva}"
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp/xdg}
. scripts/env.sh
out=$(mktemp -d)
for round in 1 2; do
  for bin in old new; do
    exe=$OLD; [ $bin = new ] && exe=$NEW
    for light in "local" "gather --gather-filter 0"; do
      for spp in 4 16; do
        for passes in beauty albedo,normal; do
          # shellcheck disable=SC2086
          "$exe" render examples/tree.json --local-workers 0 --width 448 --height 224 \
            --spp $spp --lighting $light --accel bvh --passes $passes \
            --frames 4 --sun-from 60,30 --sun-to 60,30 -o "$out/q.png" >/dev/null 2>&1
          t=$(python3 -c "import json;d=json.load(open('$out/q.stats.json'));print(' '.join(str(round(x['trace_ms'])) for x in d['frames']))")
          echo "$round $bin ${light%% *} spp=$spp $passes trace_ms: $t"
        done
      done
    done
  done
done
rm -rf "$out"
