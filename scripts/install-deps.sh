#!/usr/bin/env bash
# Installs what Sylva needs on a Debian machine: a C toolchain for build
# scripts, lavapipe (Mesa's Vulkan driver that runs on the CPU, so the GPU
# code works without a GPU) and, if absent, a Rust toolchain through rustup.
# Idempotent: packages already present are not fetched again.
set -euo pipefail
cd "$(dirname "$0")/.."

# Lavapipe from Mesa 25 or later. Debian 12's own Mesa (22.3) runs the
# traversal kernels about half as fast (docs/tracing.md, "Mesa 25"); on
# Debian 12 Mesa 25 comes from Debian's bookworm-backports, installed below
# (not first from Debian 12 and then again).
mesa="$(dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true)"
codename="$(. /etc/os-release && echo "${VERSION_CODENAME:-}")"
backports=0
if [ "$codename" = bookworm ] && ! dpkg --compare-versions "$mesa" ge 25; then
  backports=1
fi

# libc6-dev is only a recommendation of gcc, and rustc links through it (crt1.o, libc.so).
packages=(libvulkan1 gcc libc6-dev pkg-config ca-certificates curl)
((backports)) || packages+=(mesa-vulkan-drivers)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
# With --test, what only the tests use: Node.js and npm run the Khronos
# glTF validator on exported scenes (a Node.js installed otherwise, with its
# own npm, is used as it is), headless Chromium drives the dashboard, and
# PostgreSQL serves the durable queue's second database.
tests=0
[ "${1:-}" = "--test" ] && tests=1
if ((tests)); then
  # The fuzz targets are built by the test command; libfuzzer-sys compiles
  # libFuzzer's C++ sources.
  dpkg-query -W -f='${Status}' g++ 2>/dev/null | grep -q "install ok installed" || missing+=(g++)
  command -v node >/dev/null 2>&1 || missing+=(nodejs)
  command -v npm >/dev/null 2>&1 || missing+=(npm)
  command -v chromium >/dev/null 2>&1 || missing+=(chromium)
  # The durable queue's tests run once more on a PostgreSQL server
  # (scripts/postgres-check.sh starts a throwaway one).
  ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || missing+=(postgresql)
  # The Python client's tests (python/run-tests.sh) run in a venv of their own.
  command -v python3 >/dev/null 2>&1 || missing+=(python3)
  python3 -c "import ensurepip, venv" >/dev/null 2>&1 || missing+=(python3-venv)
  # The disk-full test mounts a small tmpfs in a mount namespace of its own.
  command -v unshare >/dev/null 2>&1 || missing+=(util-linux)
  command -v mount >/dev/null 2>&1 || missing+=(mount)
fi
sudo=""
[ "$(id -u)" -eq 0 ] || sudo="sudo"
if ((${#missing[@]})); then
  echo "installing: ${missing[*]}" >&2
  $sudo apt-get update -q
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends "${missing[@]}"
fi

if ((backports)); then
  echo "installing Mesa 25 (lavapipe) from bookworm-backports" >&2
  # (a line that names it, not commented out)
  if ! grep -rqsE "^[^#]*bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
    printf '%s\n' "Types: deb" "URIs: http://deb.debian.org/debian" "Suites: bookworm-backports" \
      "Components: main" "Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg" |
      $sudo tee /etc/apt/sources.list.d/sylva-backports.sources >/dev/null
  fi
  $sudo apt-get update -q
  DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -q --no-install-recommends -t bookworm-backports mesa-vulkan-drivers
fi

if ! command -v cargo >/dev/null 2>&1; then
  if [ -x "$HOME/.cargo/bin/cargo" ]; then
    :
  else
    echo "installing Rust through rustup" >&2
    # rustup-init straight from the Rust project's distribution server
    # (what https://sh.rustup.rs fetches too), so a network that reaches
    # only static.rust-lang.org still works.
    # It must be called rustup-init: rustup picks its role by its own name.
    dir="$(mktemp -d)"
    curl --proto '=https' --tlsv1.2 -sSf -o "$dir/rustup-init" "https://static.rust-lang.org/rustup/dist/$(uname -m)-unknown-linux-gnu/rustup-init"
    chmod +x "$dir/rustup-init"
    # Pinned to the version the project is developed and checked with (and
    # the Dockerfile builds with): a newer stable's new clippy lints would
    # fail the test command on a fresh machine only.
    "$dir/rustup-init" -y --no-modify-path --profile minimal --default-toolchain 1.95.0 --component rustfmt,clippy
    rm -rf "$dir"
  fi
fi

# The test command checks formatting and lints too.
export PATH="$HOME/.cargo/bin:$PATH"
if ! cargo fmt --version >/dev/null 2>&1 || ! cargo clippy --version >/dev/null 2>&1; then
  echo "installing rustfmt and clippy" >&2
  rustup component add rustfmt clippy
fi

# The Khronos glTF validator (npm registry), for the export tests; pinned.
if ((tests)) && [ ! -f .tools/node_modules/gltf-validator/package.json ]; then
  echo "installing gltf-validator" >&2
  npm install --silent --no-audit --no-fund --prefix .tools gltf-validator@2.0.0-dev.3.10 >&2
fi

# Intel Open Image Denoise for `--denoise` (docs/denoising.md).
if [ ! -f .tools/oidn/lib/libOpenImageDenoise.so.2 ] && command -v python3 >/dev/null 2>&1; then
  bash scripts/fetch-oidn.sh .tools/oidn
fi
