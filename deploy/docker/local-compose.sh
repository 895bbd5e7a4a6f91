#!/usr/bin/env bash
# deploy/compose.yaml run for real on this Debian machine: Debian's Docker
# engine (docker.io) and docker-compose, the image built from
# deploy/Dockerfile, a coordinator and three lavapipe workers up, a scene
# submitted from the host with `sylva submit`, and a check that the image
# arrives. Run as root. Usage:
#   deploy/docker/local-compose.sh [SCENE] [OUT]
# Defaults: examples/tree.json, sylva-out/compose/tree.png.
#
# The Dockerfile's base images come from Docker Hub. Where that cannot be
# reached (a farm behind a registry mirror, or a machine that reaches only
# Debian's archive), stand-ins with the same names are made from Debian's
# archive first: `debian:bookworm-slim` by debootstrap (minbase), and
# `rust:1.95-bookworm` as that plus gcc and Rust 1.95 from rustup, as the
# official image has them. STANDINS=0 skips that and pulls.
# The engine runs without iptables (the network may not allow it), so
# images build with the host's network, and the stack's own network is a
# plain bridge: service names resolve, port 50150 is published by the
# userland proxy. Stopped at the end unless KEEP_COMPOSE=1.
set -euo pipefail
cd "$(dirname "$0")/../.."
SCENE=${1:-examples/tree.json}
OUT=$(realpath -m "${2:-sylva-out/compose/$(basename "${SCENE%.*}").png}")
mkdir -p "$(dirname "$OUT")"
rm -f "$OUT"

bash scripts/install-deps.sh
export PATH="$HOME/.cargo/bin:$PATH"
missing=()
for p in docker.io docker-compose debootstrap; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  apt-get update -q
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
fi
DOCKER=/usr/bin/docker
export SYLVA=${SYLVA:-$PWD/target/release/sylva}
[ -x "$SYLVA" ] || cargo build --release --locked -p sylva

started_engine=0
if ! $DOCKER info >/dev/null 2>&1; then
  echo "starting the Docker engine (vfs storage, no iptables)" >&2
  dockerd --iptables=false --storage-driver=vfs >/tmp/sylva-dockerd.log 2>&1 &
  started_engine=1
  for _ in $(seq 60); do $DOCKER info >/dev/null 2>&1 && break; sleep 1; done
  $DOCKER info >/dev/null
fi

if [ "${STANDINS:-1}" = 1 ]; then
  if ! $DOCKER image inspect debian:bookworm-slim >/dev/null 2>&1; then
    echo "making debian:bookworm-slim from Debian's archive (debootstrap minbase)" >&2
    root=$(mktemp -d)
    debootstrap --variant=minbase bookworm "$root" http://deb.debian.org/debian >&2
    # The image's own apt-get needs the machine's CA if its network intercepts TLS.
    cp /usr/local/share/ca-certificates/*.crt "$root/usr/local/share/ca-certificates/" 2>/dev/null || true
    rm -rf "$root"/var/lib/apt/lists/* "$root"/var/cache/apt/archives/*.deb
    tar -C "$root" -c . | $DOCKER import - debian:bookworm-slim >&2
    rm -rf "$root"
  fi
  if ! $DOCKER image inspect rust:1.95-bookworm >/dev/null 2>&1; then
    echo "making rust:1.95-bookworm: debian:bookworm-slim, gcc and Rust 1.95 (rustup)" >&2
    $DOCKER build --network host -t rust:1.95-bookworm - >&2 <<'EOF'
FROM debian:bookworm-slim
RUN apt-get update && apt-get install -y --no-install-recommends gcc libc6-dev pkg-config ca-certificates curl \
 && (update-ca-certificates || true) && rm -rf /var/lib/apt/lists/*
ENV RUSTUP_HOME=/usr/local/rustup CARGO_HOME=/usr/local/cargo PATH=/usr/local/cargo/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin
RUN curl --proto '=https' --tlsv1.2 -sSf -o /tmp/rustup-init https://static.rust-lang.org/rustup/dist/x86_64-unknown-linux-gnu/rustup-init \
 && chmod +x /tmp/rustup-init && /tmp/rustup-init -y --no-modify-path --profile minimal --default-toolchain 1.95.0 && rm /tmp/rustup-init
EOF
  fi
fi

compose=(docker-compose -p sylva -f deploy/compose.yaml)
echo "building sylva:latest from deploy/Dockerfile" >&2
$DOCKER build --network host -f deploy/Dockerfile -t sylva:latest . >&2
stop() {
  if [ "${KEEP_COMPOSE:-0}" != 1 ]; then
    "${compose[@]}" down --timeout 5 >&2 || true
    if ((started_engine)); then pkill -x dockerd || true; fi
  fi
}
trap stop EXIT
"${compose[@]}" up -d --no-build >&2
# Three workers register with the coordinator by their service names.
for _ in $(seq 120); do
  alive=$("$SYLVA" workers --coordinator 127.0.0.1:50150 --json 2>/dev/null | grep -c '"alive": true' || true)
  [ "$alive" -ge 3 ] && break
  sleep 1
done
"$SYLVA" workers --coordinator 127.0.0.1:50150
[ "$alive" -ge 3 ] || { "${compose[@]}" logs >&2; echo "only $alive workers registered" >&2; exit 1; }
start=$(date +%s)
"$SYLVA" submit "$SCENE" --coordinator 127.0.0.1:50150 -o "$OUT" --width 320 --height 240
"$SYLVA" jobs --coordinator 127.0.0.1:50150
[ -s "$OUT" ] || { echo "no image arrived" >&2; exit 1; }
"${compose[@]}" ps
echo "compose: image $OUT arrived $(( $(date +%s) - start )) s after submit, from 3 containerised lavapipe workers"
