# Sourced by the other scripts: the toolchain on PATH and a private runtime
# folder, which silences a harmless warning from the Vulkan loader.
export PATH="$HOME/.cargo/bin:$PATH"
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/sylva-runtime-$(id -u)}"
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
