"""Sylva as a render engine: with Render Engine set to "Sylva", F12 (and
Ctrl F12, frame by frame) renders the frame on the farm and shows it in
Blender's render window, as Cycles' would be.

Blender calls `render()` on its render thread. The glTF exporter is an
operator, and operators run on the main thread only, so there the export
is handed to the main thread and the render thread waits for it: a queue
that a timer on the main thread empties (registered with the engine, on
the main thread: Blender's timers are not to be registered from another
thread). The interface keeps running while F12 renders. In background
mode (`blender -b … -f N`, `bpy.ops.render.render`) `render()` runs on
the main thread itself, and exports directly.
"""

from __future__ import annotations

import array
import dataclasses
import queue
import shutil
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable

import bpy

from . import deps, export, job

#: Panels of Blender's own that a render engine must list itself in to
#: be shown with it: the output and format panels, not the Eevee or
#: Cycles ones.
_SHARED_PANEL_MODULES = ("properties_output",)


#: Work the render thread hands to the main thread, run by `_drain`.
_MAIN: queue.Queue[Callable[[], None]] = queue.Queue()


def _drain() -> float:
    """Runs what the render thread handed over (a timer on the main thread)."""
    while True:
        try:
            _MAIN.get_nowait()()
        except queue.Empty:
            return 0.1


def _on_main_thread(work: Callable[[], Any], cancelled: Callable[[], bool]) -> Any:
    """`work()` run on Blender's main thread, waited for; its result or its
    exception. None if `cancelled()` first: the work, if not started, is
    then left undone."""
    if threading.current_thread() is threading.main_thread():
        return work()
    done, abandoned = threading.Event(), threading.Event()
    box: dict[str, Any] = {}

    def call() -> None:
        # `abandoned`, not the engine's `test_break`: the engine may be
        # gone by the time this runs.
        if not abandoned.is_set():
            try:
                box["value"] = work()
            except Exception as e:  # noqa: BLE001 (raised again on the render thread)
                box["error"] = e
        done.set()

    _MAIN.put(call)
    while not done.wait(0.1):
        if cancelled():
            abandoned.set()
            return None
    if "error" in box:
        raise box["error"]
    return box.get("value")


def _export(scene_name: str, layer_name: str, folder: Path) -> tuple[job.Settings, Path]:
    """The job's settings and its exported scene, made on the main thread
    from the scene named `scene_name` as it is now: one frame, its beauty.
    The context is given its scene, view layer and active object: a
    command-line render's (`blender -b … -f N`) has none, and the glTF
    exporter reads the active object."""
    from .ops import frame_settings  # the operator's own settings (no cycle at import)

    context = bpy.context
    scene = bpy.data.scenes[scene_name]
    layer = scene.view_layers.get(layer_name) or scene.view_layers[0]
    active = layer.objects.active
    override = {"scene": scene, "view_layer": layer, "active_object": active, "object": active}
    window = context.window or next(iter(context.window_manager.windows), None)
    if window is not None:
        override["window"] = window
    with context.temp_override(**override):
        # One frame (the renderer asks frame by frame).
        settings = frame_settings(bpy.context, sequence=False)
        exported = export.export_scene(bpy.context, folder)
    # Its beauty alone, the render result's Combined pass.
    return dataclasses.replace(settings, passes=[]), exported["scene"]


def _pixels(path: str, width: int, height: int) -> array.array:
    """The RGBA floats of the OpenEXR at `path`, rows from the bottom as
    Blender's render passes hold them; read on the main thread (Blender's
    image loader makes a data-block). Linear light, untouched: a float
    image's pixels are not colour-managed."""
    img = bpy.data.images.load(path, check_existing=False)
    try:
        if tuple(img.size) != (width, height):
            raise RuntimeError(f"{path} is {tuple(img.size)}, the frame {width} × {height}")
        out = array.array("f", bytes(4 * 4 * width * height))
        img.pixels.foreach_get(out)
        return out
    finally:
        bpy.data.images.remove(img)


class SylvaRenderEngine(bpy.types.RenderEngine):
    """Renders the frame on the Sylva farm set in the Sylva panel."""

    bl_idname = "SYLVA"
    bl_label = "Sylva"
    bl_use_preview = False
    bl_use_postprocess = True

    def render(self, depsgraph: bpy.types.Depsgraph) -> None:
        work = Path(tempfile.mkdtemp(prefix="sylva-f12-"))
        try:
            self._render(depsgraph, work)
        finally:
            shutil.rmtree(work, ignore_errors=True)

    def _render(self, depsgraph: bpy.types.Depsgraph, work: Path) -> None:
        scene = depsgraph.scene
        width, height = self.resolution_x, self.resolution_y
        s = scene.sylva_farm
        out = Path(bpy.path.abspath(s.output_dir)) if s.output_dir else \
            Path(tempfile.gettempdir()) / "sylva-blender"
        self.update_stats("", "Sylva: exporting the scene")
        try:
            client_mod = deps.client_module()
            layer = depsgraph.view_layer.name
            made = _on_main_thread(lambda: _export(scene.name, layer, work), self.test_break)
        except Exception as e:  # noqa: BLE001 (every error is the render's report)
            self.report({"ERROR"}, f"Sylva: {e}")
            return
        if made is None:
            return
        settings, scene_file = made
        if (settings.width, settings.height) != (width, height):
            self.report({"ERROR"}, f"Sylva: the frame is {width} × {height}, the export "
                        f"{settings.width} × {settings.height}")
            return

        def say(p: job.Progress) -> None:
            self.update_progress(p.fraction)
            self.update_stats("", f"Sylva: {p.error or p.stage}" + (f" — job {p.job}" if p.job else ""))

        last = job.run(client_mod, settings, scene_file, out, say, cancelled=self.test_break)
        if last.error:
            if last.error != "cancelled":
                self.report({"ERROR"}, f"Sylva: {last.error}")
            return
        # The frame's plain RGB OpenEXR, linear light, as Blender's own
        # Combined pass holds it. (`RenderLayer.load_from_file` reads an
        # OpenEXR as a render result, by pass names a plain file lacks.)
        try:
            pixels = _on_main_thread(lambda: _pixels(last.exr, width, height), self.test_break)
        except Exception as e:  # noqa: BLE001
            self.report({"ERROR"}, f"Sylva: cannot load {last.exr}: {e}")
            return
        if pixels is None:
            return
        # Blender renders each view layer in a call of its own; the farm
        # renders the scene whole, into the layer asked for.
        result = self.begin_result(0, 0, width, height, layer=depsgraph.view_layer.name)
        result.layers[0].passes["Combined"].rect.foreach_set(pixels)
        self.end_result(result)


def _shared_panels() -> list[type]:
    """Blender's panels that show for every engine listed in them."""
    out = []
    for name in _SHARED_PANEL_MODULES:
        module = getattr(__import__("bl_ui", fromlist=[name]), name, None)
        for cls in vars(module).values() if module else ():
            if isinstance(cls, type) and hasattr(cls, "COMPAT_ENGINES"):
                out.append(cls)
    return out


def register() -> None:
    bpy.utils.register_class(SylvaRenderEngine)
    if not bpy.app.timers.is_registered(_drain):
        bpy.app.timers.register(_drain, persistent=True)
    for panel in _shared_panels():
        panel.COMPAT_ENGINES.add(SylvaRenderEngine.bl_idname)


def unregister() -> None:
    if bpy.app.timers.is_registered(_drain):
        bpy.app.timers.unregister(_drain)
    for panel in _shared_panels():
        panel.COMPAT_ENGINES.discard(SylvaRenderEngine.bl_idname)
    bpy.utils.unregister_class(SylvaRenderEngine)
