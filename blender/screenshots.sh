#!/usr/bin/env bash
# Takes docs/images/blender-panel.png, blender-passes.png and
# blender-f12.png (and checks F12's render result against the farm's
# image, its exit status): a GUI Blender (apt-get install blender xvfb
# xdotool imagemagick; the pictures are from Debian 13's 4.3.2, Debian 12's
# is 3.4) under Xvfb with Mesa's software OpenGL, the add-on installed from target/sylva_blender.zip,
# "Render on Sylva" run against a coordinator and a worker started here on
# loopback ($SYLVA_BIN, default target/release/sylva). The add-on's Python
# dependencies come from $SYLVA_BLENDER_DEPS (default: pip-installed into
# target/blender-deps with python3, as its "Install dependencies" button
# would, for the Python Blender runs on).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
sylva="${SYLVA_BIN:-$root/target/release/sylva}"
zip="${SYLVA_BLENDER_ZIP:-$root/target/sylva_blender.zip}"
out="${1:-$root/docs/images}"
work="$(mktemp -d)"
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; rm -rf "$work"; }
trap cleanup EXIT
[ -f "$zip" ] || "$root/blender/build-zip.sh" "$zip"
pyver="$(blender -b --factory-startup --python-expr 'import sys; print("PYVER", "%d.%d" % sys.version_info[:2])' 2>/dev/null | sed -n 's/^PYVER //p')"
deps="${SYLVA_BLENDER_DEPS:-$root/target/blender-deps/py$pyver}"
if [ ! -d "$deps/grpc" ]; then
  "python$pyver" -m pip install -q --disable-pip-version-check --target "$deps" \
    -r <(unzip -p "$zip" sylva_blender/_vendor/requirements.txt)
fi
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/sylva-runtime-0}" SYLVA_PREPARED_CACHE_MIB=0
mkdir -p -m 700 "$XDG_RUNTIME_DIR"
token="$(head -c 16 /dev/urandom | od -An -tx1 | tr -d ' \n')"
"$sylva" coordinator --listen 127.0.0.1:0 --token "$token" --ephemeral >"$work/coord.out" 2>"$work/coord.log" &
pids+=($!)
for _ in $(seq 100); do grep -q "listening on" "$work/coord.out" 2>/dev/null && break; sleep 0.1; done
addr="$(sed -n 's/.* listening on //p' "$work/coord.out" | head -1)"
SYLVA_TOKEN="$token" "$sylva" worker --listen 127.0.0.1:0 --coordinator "$addr" >"$work/worker.out" 2>"$work/worker.log" &
pids+=($!)
sleep 2
mkdir -p "$out"
# Preferences saved once without the splash screen, so that the GUI run
# below (which reads them) opens on the window itself.
BLENDER_USER_CONFIG="$work/user/config" blender -b --factory-startup --python-expr \
  'import bpy; bpy.context.preferences.view.show_splash = False; bpy.ops.wm.save_userpref()' >/dev/null 2>&1
# An X server of our own (its display number from -displayfd), so that
# xdotool can open the Image Editor's pass menu for the second picture.
Xvfb -displayfd 3 -screen 0 1600x1300x24 -nolisten tcp 3>"$work/display" >/dev/null 2>&1 &
pids+=($!)
for _ in $(seq 100); do [ -s "$work/display" ] && break; sleep 0.1; done
export DISPLAY=":$(cat "$work/display")"
# A GUI Blender running SCRIPT against the farm, its output in LOG,
# waited for until it writes the ready file (or ends); false if it ended
# without.
blender_until_ready() {
  local script=$1 log=$2
  rm -f "$work/ready"
  SYLVA_COORDINATOR="$addr" SYLVA_TOKEN="$token" SYLVA_BLENDER_DEPS="$deps" SYLVA_SHOT_READY="$work/ready" \
  BLENDER_USER_SCRIPTS="$work/user/scripts" BLENDER_USER_CONFIG="$work/user/config" \
  LIBGL_ALWAYS_SOFTWARE=1 blender --window-geometry 0 0 1600 1300 --no-window-focus \
    --python "$root/blender/$script" -- "$zip" "$out" >"$log" 2>&1 &
  blender_pid=$!
  pids+=("$blender_pid")
  for _ in $(seq 1200); do [ -f "$work/ready" ] && break; kill -0 "$blender_pid" 2>/dev/null || break; sleep 0.5; done
  grep -E "screenshots:|Error|rror:|Traceback" "$log" || true
  [ -f "$work/ready" ]
}
blender_until_ready screenshots.py "$work/blender.log" || { echo "Blender did not get to its screenshots" >&2; exit 1; }
# The panel: the Properties editor cut out of the screen.
import -window root "$work/screen.png"
convert "$work/screen.png" -crop "$(cat "$out/blender-panel.crop")" +repage "$out/blender-panel.png"
rm -f "$out/blender-panel.crop"
# The pass selector ("Combined") in the Image Editor's header: open it.
xdotool mousemove "${SYLVA_SHOT_MENU_X:-1227}" "${SYLVA_SHOT_MENU_Y:-40}" click 1
sleep 1.5
import -window root "$out/blender-passes.png"
kill "$blender_pid" 2>/dev/null || true
wait "$blender_pid" 2>/dev/null || true
# F12 with the Sylva render engine, in the interface (f12_gui.py): the
# render result must hold the farm's beauty to the bit (the ready file
# says 0); the render window is cut out of the screen as blender-f12.png.
blender_until_ready f12_gui.py "$work/f12.log" || { echo "Blender did not get to F12's end" >&2; exit 1; }
sleep 1
import -window root "$work/screen.png"
convert "$work/screen.png" -crop "$(cat "$out/blender-f12.crop")" +repage "$out/blender-f12.png"
rm -f "$out/blender-f12.crop"
ls -l "$out"/blender-*.png
exit "$(cat "$work/ready")"
