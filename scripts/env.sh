# Sourced by the other scripts: the toolchain on PATH and a private runtime
# folder, which silences a harmless warning from the Vulkan loader.
export PATH="$HOME/.cargo/bin:$PATH"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/sylva-runtime-$(id -u)}"
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
# The denoiser's library, as scripts/install-deps.sh installs it.
oidn="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)/.tools/oidn/lib/libOpenImageDenoise.so.2"
[ -f "$oidn" ] && export SYLVA_OIDN_LIB="${SYLVA_OIDN_LIB:-$oidn}"
unset oidn
