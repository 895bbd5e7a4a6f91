#!/usr/bin/env bash
# Here, before a device run: the stripped release binary in .dev/ and the
# Vulkan loader packages in .gl/ (both ignored by git, both carried by the
# device tool: carry [".dev", ".gl"]), then `bash benchmarks/gpu/run.sh`
# there. The binary is built here so the device's minutes go to measuring.
set -euo pipefail
cd "$(dirname "$0")/../.."
. scripts/env.sh
cargo build --release --locked --bin sylva
mkdir -p .dev .gl
cp target/release/sylva .dev/sylva
strip .dev/sylva
for d in .dev .gl; do
  grep -qx "/$d/" .git/info/exclude 2>/dev/null || echo "/$d/" >> .git/info/exclude
done
if ! ls .gl/libvulkan1_*.deb >/dev/null 2>&1; then
  o='-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists=/tmp/amd64'
  mkdir -p /tmp/amd64/partial
  apt-get $o update -qq
  (cd .gl && apt-get $o download libvulkan1 libegl1 libglvnd0 libopengl0 libgl1 libglx0 libgles2)
fi
ls -la .dev/sylva .gl
