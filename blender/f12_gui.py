"""F12 in a GUI Blender (run by blender/screenshots.sh under Xvfb, after
the panel's screenshots): the test forest with Render Engine set to
"Sylva", Blender's own render started as F12 starts it (`render.render`
invoked: a render job on Blender's render thread, the interface running
on), then, once it is done, the render result compared with the OpenEXR
the engine fetched from the farm, and the render window taken as
  blender-f12.png.
Exits 0 when the result holds the farm's beauty to the bit.
Arguments after `--`: the zip, the output folder."""

import array
import os
import tempfile
import time
from pathlib import Path

import bpy

def _load_screenshots():
    """screenshots.py, for its setup (the add-on from the zip, the forest,
    the farm), loaded from its file: with this folder on sys.path,
    `sylva_blender` would be imported from the source tree rather than the
    installed add-on (which vendors the client)."""
    import importlib.util

    path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "screenshots.py")
    spec = importlib.util.spec_from_file_location("sylva_screenshots", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


screenshots = _load_screenshots()

log, quit_now = screenshots.log, screenshots.quit_now
state = {"step": 0, "t0": time.monotonic()}


def pixels(path: str) -> array.array:
    img = bpy.data.images.load(path, check_existing=False)
    try:
        buf = array.array("f", bytes(4 * 4 * img.size[0] * img.size[1]))
        img.pixels.foreach_get(buf)
        return buf
    finally:
        bpy.data.images.remove(img)


def start() -> None:
    scene = bpy.context.scene
    scene.render.engine = "SYLVA"
    scene.sylva_farm.all_passes = False
    bpy.context.preferences.view.render_display_type = "WINDOW"
    win = bpy.context.window_manager.windows[0]
    with bpy.context.temp_override(window=win):
        log("F12:", bpy.ops.render.render("INVOKE_DEFAULT"))


def check() -> int:
    scene = bpy.context.scene
    out = Path(scene.sylva_farm.output_dir)
    fetched = sorted(out.glob("sylva-*.exr"), key=lambda p: p.stat().st_mtime)
    if not fetched:
        log("F12: no image fetched from the farm")
        return 1
    mine = os.path.join(tempfile.mkdtemp(), "f12.exr")
    fmt = scene.render.image_settings
    fmt.file_format, fmt.color_depth, fmt.color_mode = "OPEN_EXR", "32", "RGBA"
    bpy.data.images["Render Result"].save_render(mine, scene=scene)
    a, b = pixels(str(fetched[-1])), pixels(mine)
    worst = max((abs(x - y) for i, (x, y) in enumerate(zip(a, b)) if i % 4 != 3), default=0.0)
    same = len(a) == len(b) and worst == 0.0
    log(f"F12: render result against {fetched[-1].name}: {len(b) // 4} pixels, "
        f"largest difference {worst}", "(identical)" if same else "(DIFFERENT)")
    return 0 if same else 1


def wait_and_check():
    if time.monotonic() - state["t0"] > 300:
        log("F12: timed out")
        quit_now(1)
    if bpy.app.is_job_running("RENDER"):
        return 0.5
    state["code"] = check()
    return None


def ready():
    # screenshots.sh takes the screen, cuts the render window out of it,
    # then ends this Blender.
    win = bpy.context.window_manager.windows[-1]
    crop = screenshots.crop_of(win, 0, 0, win.width, win.height)
    with open(os.path.join(screenshots.OUT, "blender-f12.crop"), "w") as f:
        f.write(crop + "\n")
    with open(os.environ["SYLVA_SHOT_READY"], "w") as f:
        f.write(f"{state.get('code', 1)}\n")
    return "stay"


screenshots.run_steps([screenshots.setup, start, wait_and_check, ready], state)
