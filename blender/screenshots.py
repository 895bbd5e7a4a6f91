"""Takes the add-on's screenshots for docs/images/ in a GUI Blender (run
by blender/screenshots.sh under Xvfb): installs the add-on from its zip,
builds the test forest (plus a few more collection instances of the tree,
which every Blender exports as instances), runs "Render on Sylva" as a
user would (the modal operator, against the farm in $SYLVA_COORDINATOR
with $SYLVA_TOKEN), and once the image is back takes
  blender-panel.png   the Properties editor's Sylva panel, and
  blender-passes.png  the window, its Image Editor showing the EXR's passes.
Arguments after `--`: the zip, the output folder."""

import math
import os
import sys
import time

import bpy

argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
ZIP, OUT = argv[0], argv[1]
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "tests"))
import scene_builder  # noqa: E402

started = time.monotonic()


def log(*a):
    print("screenshots:", *a, flush=True)


def areas(kind):
    win = bpy.context.window_manager.windows[0]
    return win, [a for a in win.screen.areas if a.type == kind]


def setup():
    bpy.ops.preferences.addon_install(filepath=ZIP, overwrite=True)
    bpy.ops.preferences.addon_enable(module="sylva_blender")
    objs = scene_builder.build_scene(480, 270)
    # More trees, placed by collection instances.
    coll = bpy.data.collections["TreeSource"]
    for i in range(10):
        e = bpy.data.objects.new(f"TreeInstance.{i}", None)
        e.instance_type = "COLLECTION"
        e.instance_collection = coll
        a = i * 2.4
        e.location = (math.cos(a) * (4 + i * 1.1), math.sin(a) * (4 + i * 1.1) + 4, 0)
        e.rotation_euler = (0, 0, a)
        bpy.context.scene.collection.objects.link(e)
    prefs = bpy.context.preferences.addons["sylva_blender"].preferences
    prefs.address = os.environ["SYLVA_COORDINATOR"]
    prefs.token = os.environ["SYLVA_TOKEN"]
    s = bpy.context.scene.sylva_farm
    s.spp, s.all_passes, s.lighting = 4, True, "scene"
    import tempfile

    s.output_dir = tempfile.mkdtemp(prefix="sylva-shots-")
    bpy.context.scene.render.engine = "BLENDER_WORKBENCH"  # fewer panels above ours
    win, view3d = areas("VIEW_3D")
    view3d[0].type = "IMAGE_EDITOR"
    _, props = areas("PROPERTIES")
    for a in props:
        a.spaces.active.context = "RENDER"
    del objs


def start_render():
    win, props = areas("PROPERTIES")
    with bpy.context.temp_override(window=win, area=props[0]):
        r = bpy.ops.sylva.render("INVOKE_DEFAULT")
    log("operator:", r)


def scroll_panel():
    win, props = areas("PROPERTIES")
    area = props[0]
    region = [r for r in area.regions if r.type == "WINDOW"][0]
    with bpy.context.temp_override(window=win, area=area, region=region):
        for _ in range(40):
            bpy.ops.view2d.scroll_down(deltax=0, deltay=200)


def show_pass():
    """Fits the loaded image in the Image Editor."""
    win, eds = areas("IMAGE_EDITOR")
    for a in eds:
        if a.spaces.active.image is not None:
            with bpy.context.temp_override(window=win, area=a,
                                           region=[r for r in a.regions if r.type == "WINDOW"][0]):
                bpy.ops.image.view_all(fit_view=True)


def crop_of(win, x, y, width, height):
    """ImageMagick's crop geometry of a rectangle of window `win` (x, y
    from its bottom left, as Blender gives them) on the root screen."""
    top = win.y + win.height - (y + height)
    return f"{width}x{height}+{win.x + x}+{top}"


def shoot():
    """Where the Properties editor is, for screenshots.sh to cut the panel
    out of the screen it takes (`import -window root`): Blender's own
    `screen.screenshot` and `screenshot_area` give black images on Mesa's
    software OpenGL in Blender 4.3."""
    win, props = areas("PROPERTIES")
    a = props[0]
    with open(os.path.join(OUT, "blender-panel.crop"), "w") as f:
        f.write(crop_of(win, a.x, a.y, a.width, a.height) + "\n")
    log("ready to take", OUT)


def quit_now(code):
    sys.stdout.flush()
    os._exit(code)  # quit_blender from a timer does not always quit


def run_steps(steps, state):
    """Runs `steps` one after another from a timer, 2 s apart: a step that
    returns a number is called again after that many seconds, one that
    returns "stay" ends the timer there (Blender stays open); any error
    ends Blender with status 1."""

    def tick():
        try:
            again = steps[state["step"]]()
        except Exception as e:  # noqa: BLE001
            import traceback

            traceback.print_exc()
            log("failed:", e)
            quit_now(1)
        if again == "stay":
            return None
        if again is not None:
            return again
        state["step"] += 1
        return 2.0

    bpy.app.timers.register(tick, first_interval=2.0)


def wait_for_render():
    st = bpy.context.window_manager.sylva_status
    if time.monotonic() - started > 240:
        log("timed out:", st.stage)
        quit_now(1)
    if st.running:
        log("progress:", st.stage, round(st.progress, 2))
        return 0.5
    log("finished:", st.stage, st.job, st.image)
    show_pass()
    scroll_panel()
    return None


def ready():
    if not os.environ.get("SYLVA_SHOT_READY"):
        quit_now(0)
    # screenshots.sh opens the pass menu and takes the screen itself,
    # then ends this Blender.
    open(os.environ["SYLVA_SHOT_READY"], "w").write("ready\n")
    return "stay"


if __name__ == "__main__":
    run_steps([setup, start_render, wait_for_render, shoot, ready], {"step": 0})
