#!/usr/bin/env bash
# One device run that measures what issues 38-40 ask of an NVIDIA GPU, in
# at most 8 minutes: the traversal per ray kind timed by the GPU itself
# (camera, shadow and diffuse-bounce rays, at least 4 M rays each), whole
# frames at 1 and 4 spp, the cold and warm first frame, the LB solve,
# where a frame's time goes through the farm, a sun sweep, the guides'
# cost, the speed/accuracy front with the denoised methods, and what
# `--lighting auto` chooses for a sun sweep.
# Prepared here with benchmarks/gpu/prepare.sh; run there in the repo's
# root (the device tool: carry [".dev", ".gl"], command
# `bash benchmarks/gpu/run.sh`). Writes each command's JSON, its log and
# a summary (`summary.json`) to $OUT (the device tool's) or the folder
# given, by default benchmarks/results/gpu/.
set -uo pipefail
cd "$(dirname "$0")/../.."
BIN=${SYLVA_BIN:-$PWD/.dev/sylva}
DEST=${1:-${OUT:-benchmarks/results/gpu}}
mkdir -p "$DEST"
START=$SECONDS
BUDGET=${BUDGET:-470}   # seconds for everything, under the 8-minute call
# A dry run elsewhere (lavapipe): ALLOW_LLVMPIPE=1 SCALE=0.01
# KERNEL_RAYS=100000 BUDGET=200.
SCALE=${SCALE:-1}
KERNEL_RAYS=${KERNEL_RAYS:-4194304}
# The Vulkan loader, where the machine lacks one (prepare.sh fetched it).
if ls .gl/*.deb >/dev/null 2>&1 && ! ldconfig -p | grep -q libvulkan.so.1; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
if command -v nvidia-smi >/dev/null; then
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv > "$DEST/gpu.txt" 2>&1
else
  echo "no nvidia-smi on this machine" > "$DEST/gpu.txt"
fi
cat "$DEST/gpu.txt"
export RUST_LOG=${RUST_LOG:-info}
# One step: its JSON to DEST/NAME.json, at most LIMIT seconds (less where
# the budget has less left), its log appended to DEST/all.log.
step() {
  local name=$1 limit=$2; shift 2
  local left=$((BUDGET - (SECONDS - START)))
  (( left < limit )) && limit=$left
  if (( limit < 10 )); then echo "$name: skipped, the budget is spent"; return; fi
  local t0=$SECONDS
  timeout "$limit" "$BIN" "$@" > "$DEST/$name.json" 2>> "$DEST/all.log"
  echo "$name: rc=$? in $((SECONDS - t0)) s (limit $limit s)"
}
# wgpu must find the NVIDIA driver, not llvmpipe.
step probe 60 bench lb --grid 32 --backends gpu
if [ -z "${ALLOW_LLVMPIPE:-}" ] && { ! grep -q '"device"' "$DEST/probe.json" || grep -qi llvmpipe "$DEST/probe.json"; }; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  step probe 60 bench lb --grid 32 --backends gpu
  if ! grep -q '"device"' "$DEST/probe.json"; then
    echo "the NVIDIA Vulkan driver was not found either: measuring what wgpu finds"
    unset VK_DRIVER_FILES
    step probe 60 bench lb --grid 32 --backends gpu
  fi
fi
grep -o '"device": *"[^"]*"' "$DEST/probe.json" | head -1
# The full Table-2 forest: traversal per ray kind and backend (GPU
# timestamps), frames, and the first frame cold and warm.
# bvh: the four-wide BVH (private stacks); cwbvh: the eight-wide
# compressed one (stack in workgroup memory), issue 38's; kd: the paper's.
# The first frame's `auto` measures bvh against cwbvh and says why.
step trace-forest 280 bench trace --scale "$SCALE" --no-cpu --accel bvh,cwbvh,kd \
  --frames-accel bvh,cwbvh --kernel-rays "$KERNEL_RAYS"
step lb-128 50 bench lb --grid 128 --backends gpu --repeat 3
# Where one 0.05-forest frame's time goes through a coordinator and one
# warm worker (docs/farm-overhead.md).
"$BIN" scene forest --scale 0.05 -o "$DEST/forest-0.05.json" > /dev/null 2>> "$DEST/all.log"
step farm-0.05 60 bench farm "$DEST/forest-0.05.json" --repeat 5
# A 24-frame sun sweep of the 0.05 forest in one process (issue 39): the
# first frame pays for the scene, each other for its sun's light (LB
# solved on the device on kept grids and kernels, light uploaded beside
# the kept structures) and its trace; per frame in the JSON's `frames`.
step sweep-0.05 45 render "$DEST/forest-0.05.json" -o "$DEST/sweep/day.png" --frames 24 \
  --sun-from 15,90 --sun-to 60,200 --local-workers 0 --width 320 --height 160 --spp 1 \
  --lighting lb --json
# Issue 40: the guides' cost now that the frame's kernels write them
# (frames 2-3 of an in-process sequence under one sun are the steady
# state), and the speed/accuracy front of the 0.02 forest at 320 x 160
# (the issue's table), the path tracer's denoised families on it. Last:
# each runs only if the budget has room.
for p in beauty albedo,normal; do
  step "guides-${p%%,*}" 40 render "$DEST/forest-0.05.json" -o "$DEST/guides/${p%%,*}.png" \
    --frames 3 --sun-from 60,30 --sun-to 60,30 --local-workers 0 --width 896 --height 448 \
    --spp 4 --lighting gather --gather-filter 0 --accel bvh --passes "$p" --json
done
"$BIN" scene forest --scale 0.02 -o "$DEST/forest-0.02.json" > /dev/null 2>> "$DEST/all.log"
step compare-0.02 120 compare "$DEST/forest-0.02.json" --width 320 --height 160 \
  --gather-rays 4,16 --gather-filters 0,3 --out "$DEST/compare-0.02" --json
# `--lighting auto` on the GPU for the 0.05 forest's 24-suns sweep: what
# it chooses when each method is priced over the whole job (issue 40).
step auto-sweep-0.05 90 render "$DEST/forest-0.05.json" -o "$DEST/auto-sweep/day.png" \
  --frames 24 --sun-from 15,90 --sun-to 60,200 --local-workers 0 --width 320 --height 160 \
  --lighting auto --max-error 0.3 --json
# The figures the issues' tables quote, in one file.
python3 - "$DEST" <<'PY' || echo "summary: python3 missing or a step failed"
import json, pathlib, sys
d = pathlib.Path(sys.argv[1])
def load(n):
    try: return json.loads((d / f"{n}.json").read_text())
    except Exception: return None
t, lb, farm, sweep = load("trace-forest"), load("lb-128"), load("farm-0.05"), load("sweep-0.05")
guides, plain, cmp = load("guides-albedo"), load("guides-beauty"), load("compare-0.02")
auto = load("auto-sweep-0.05")
out = {"gpu": (d / "gpu.txt").read_text().strip().splitlines()[-1] if (d / "gpu.txt").exists() else None}
if t:
    out["adapter"] = t["adapter"]["name"]
    out["kernel_mrays_per_second"] = {r["accel"]: {k: (v or {}).get("mrays_per_second") for k, v in r["kernel"].items()} for r in t["traversal"]}
    out["wall_mrays_per_second"] = {r["accel"]: r["gpu"]["mrays_per_second"] for r in t["traversal"]}
    out["frames_ms"] = [{k: f.get(k) for k in ("accel", "spp", "frame_ms")} for f in t.get("frames", [])]
    out["first_frame"] = t.get("first_frame")
    ff = t.get("first_frame") or {}
    out["auto_chose"] = ((ff.get("cold") or {}).get("backend") or {}).get("why")
if farm:
    out["farm_0.05_median_ms"] = farm.get("median")
if sweep:
    fr = sweep.get("frames") or []
    rest = fr[1:]
    out["sweep_0.05"] = {
        "frames": len(fr),
        "total_ms": next((p["ms"] for p in sweep.get("phases_ms", []) if p["phase"] == "sequence"), None),
        "first_frame_ms": (fr[0]["prepare_ms"] + fr[0]["trace_ms"]) if fr else None,
        "next_frames_mean_ms": sum(f["prepare_ms"] + f["trace_ms"] for f in rest) / len(rest) if rest else None,
        "trace_mean_ms": sum(f["trace_ms"] for f in fr) / len(fr) if fr else None,
    }
if guides and plain:
    steady = lambda r: [f["trace_ms"] for f in (r.get("frames") or [])[1:]]
    out["guides_trace_ms"] = {"image": steady(plain), "with_albedo_normal": steady(guides)}
if cmp:
    out["compare_0.02_front"] = [{k: p.get(k) for k in ("name", "ms", "raw")} for p in cmp.get("front", [])]
    out["compare_0.02_reference_ms"] = (cmp.get("reference") or {}).get("ms")
if auto and auto.get("auto"):
    a = auto["auto"]
    out["auto_sweep_0.05"] = {"why": a.get("why"), "predicted_ms": (a.get("chosen") or {}).get("predicted_ms"),
        "sequence_ms": next((p["ms"] for p in auto.get("phases_ms", []) if p["phase"] == "sequence"), None),
        "pilot_ms": next((p["ms"] for p in auto.get("phases_ms", []) if p["phase"] == "pilot"), None)}
if lb:
    out["lb_128"] = [{k: r.get(k) for k in ("device", "mlups", "step_mlups")} for r in lb.get("results", [])]
(d / "summary.json").write_text(json.dumps(out, indent=1))
print(json.dumps(out, indent=1)[:3000])
PY
echo "total $((SECONDS - START)) s of a $BUDGET s budget"
