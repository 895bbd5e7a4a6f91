#!/bin/bash
# One device run: the trace and LB benchmarks on the NVIDIA GPU.
for f in .gl/*.deb; do dpkg -x $f /; done; ldconfig
B=$PWD/.dev/sylva
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv > $OUT/gpu.txt 2>&1
cat $OUT/gpu.txt
export RUST_LOG=info
run() { local name=$1; shift; local t0=$SECONDS
  timeout $LIMIT "$B" "$@" > $OUT/$name.json 2>> $OUT/all.log; local rc=$?
  echo "$name rc=$rc $((SECONDS - t0)) s"; tail -3 $OUT/all.log; }
LIMIT=60 run probe bench lb --grid 32 --backends gpu
if ! grep -q '"device"' $OUT/probe.json || grep -qi llvmpipe $OUT/probe.json; then
  export VK_DRIVER_FILES=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  LIMIT=60 run probe bench lb --grid 32 --backends gpu
fi
head -c 600 $OUT/probe.json; echo
LIMIT=200 run trace-forest-scale1 bench trace --scale 1 --no-cpu
LIMIT=100 run trace-forest-0.05 bench trace --scale 0.05
LIMIT=60 run lb-128 bench lb --grid 128 --backends gpu --repeat 3
LIMIT=60 run lb-64 bench lb --grid 64 --repeat 3
