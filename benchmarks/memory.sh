#!/usr/bin/env bash
# Peak resident memory (VmHWM) of the processes issue 27 bounds:
#  - the coordinator over one 600-frame 256 × 128 sequence (frames go to
#    disk as they finish);
#  - a worker over 50 jobs of 50 different bundles (it keeps what the
#    scenes hold within --memory-mib, 1024 here).
# Prints one JSON object. Uses the release binary (cargo build --release).
set -euo pipefail
cd "$(dirname "$0")/.."
S=${SYLVA:-$PWD/target/release/sylva}
out=$(mktemp -d /tmp/sylva-memory.XXXXXX)
pids=()
trap 'kill ${pids[*]} 2>/dev/null; wait 2>/dev/null; rm -rf "$out"' EXIT
# Starts `sylva ARGS` in the background; sets $addr and $pid.
serve() {
    local name=$1; shift
    "$S" "$@" > "$out/$name.out" 2> "$out/$name.log" &
    pid=$!; pids+=("$pid")
    until grep -q "listening on" "$out/$name.out" 2>/dev/null; do sleep 0.1; done
    addr=$(awk '/listening on/ {print $NF}' "$out/$name.out")
}
hwm() { awk '/VmHWM/ {printf "%d", $2 * 1024}' "/proc/$1/status"; }
rss() { awk '/VmRSS/ {printf "%d", $2 * 1024}' "/proc/$1/status"; }

cat > "$out/scene.json" <<'JSON'
{ "models": { "maple": { "tree": { "species": "red_maple", "triangles": 3000, "seed": 1 } } },
  "instances": [ { "model": "maple", "position": [0, 0, 0] }, { "model": "maple", "position": [8, 0, 4] } ],
  "camera": { "position": [4, 8, -26], "look_at": [4, 7, 0], "fov_y_deg": 45 },
  "sun": { "elevation_deg": 50, "azimuth_deg": 120 }, "lighting": "local" }
JSON
serve w1 worker --listen 127.0.0.1:0; w1=$addr
serve w2 worker --listen 127.0.0.1:0 --memory-mib 1024 -v; w2=$addr; wpid=$pid
serve c coordinator --listen 127.0.0.1:0 --ephemeral --workers "$w1,$w2"; c=$addr; cpid=$pid
c_start=$(rss "$cpid")
t0=$(date +%s)
"$S" submit "$out/scene.json" --coordinator "$c" -o "$out/seq/f.png" --width 256 --height 128 \
    --frames 600 --sun-from 60,100 --sun-to 20,220 > "$out/seq.txt"
seq_s=$(( $(date +%s) - t0 ))
c_peak=$(hwm "$cpid")
frames=$(ls "$out/seq" | grep -c '^f-[0-9]*\.png$')

# 50 different bundles, one job each, on the budgeted worker alone.
kill "${pids[2]}"; wait "${pids[2]}" 2>/dev/null || true
serve c2 coordinator --listen 127.0.0.1:0 --ephemeral --workers "$w2"; c2=$addr
w_start=$(rss "$wpid")
series=""
for seed in $(seq 1 50); do
    mkdir -p "$out/b$seed"
    cat > "$out/b$seed/scene.json" <<JSON
{ "models": { "t": { "tree": { "species": "red_maple", "triangles": 100000, "seed": $seed } } },
  "instances": [ { "model": "t", "position": [0, 0, 0] } ],
  "camera": { "position": [0, 8, -26], "look_at": [0, 7, 0], "fov_y_deg": 45 },
  "sun": { "elevation_deg": 50, "azimuth_deg": 120 }, "lighting": "lb", "lb": { "grid": 32 } }
JSON
    "$S" submit "$out/b$seed/scene.json" --coordinator "$c2" -o "$out/b$seed/out.png" \
        --width 64 --height 32 > /dev/null
    series="$series${series:+, }$(( $(rss "$wpid") >> 20 ))"
done
w_peak=$(hwm "$wpid")
evicted=$(grep -c "evicted a scene" "$out/w2.log" || true)
cat <<JSON
{
  "coordinator": { "frames": $frames, "size": [256, 128], "seconds": $seq_s,
                   "rss_at_start_bytes": $c_start, "peak_rss_bytes": $c_peak },
  "worker": { "bundles": 50, "triangles_each": 100000, "memory_mib": 1024,
              "rss_at_start_bytes": $w_start, "peak_rss_bytes": $w_peak,
              "rss_after_each_job_mib": [$series],
              "scenes_evicted_logged": $evicted }
}
JSON
