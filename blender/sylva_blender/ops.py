"""The operators: "Render on Sylva", its cancel, and "Install
dependencies"."""

import os
import tempfile
import time
from pathlib import Path

import bpy
from bpy.props import BoolProperty

from . import deps, export, job, props

#: Exporter options without which instancing is lost (older Blenders).
INSTANCING_OPTIONS = ("export_gpu_instances", "export_gn_mesh")

#: The running job's operator, so that the cancel button can reach it.
_RUNNING: list = []


def frame_settings(context: bpy.types.Context, sequence: bool | None = None) -> job.Settings:
    """The job's settings from the preferences and the scene: its frame
    range as one sequence where `sequence` says (by default, where the
    panel's "Frame range" does). Without the add-on's preferences
    (registered by hand), the farm is $SYLVA_COORDINATOR and the token
    $SYLVA_TOKEN."""
    scene = context.scene
    s = scene.sylva_farm
    r = scene.render
    pct = r.resolution_percentage / 100.0
    prefs = props.addon_prefs(context)
    address = (prefs.address if prefs else "") or os.environ.get("SYLVA_COORDINATOR", "")
    token = (prefs.token if prefs else "") or None  # None: the client reads $SYLVA_TOKEN
    tls_ca = bpy.path.abspath(prefs.tls_ca) if prefs and prefs.tls_ca else None
    if not address:
        raise RuntimeError("no farm address: set it in the Sylva panel or the add-on's preferences")
    passes: list[str] | str = "all" if s.all_passes else sorted(s.passes)
    sequence = s.animation if sequence is None else sequence
    frames, views = export.frame_views(scene) if sequence else ([], [])
    return job.Settings(
        frames=frames,
        views=views,
        address=address.strip(),
        token=token,
        tls_ca=tls_ca,
        width=max(1, int(r.resolution_x * pct)),
        height=max(1, int(r.resolution_y * pct)),
        spp=s.spp,
        seed=s.seed,
        lighting=None if s.lighting == "scene" else s.lighting,
        accel=s.accel,
        passes=passes,
        name=f"blender: {bpy.path.display_name_from_filepath(bpy.data.filepath) or scene.name}",
    )


def show_image(context: bpy.types.Context, img: bpy.types.Image) -> bool:
    """Shows `img` in every Image Editor of the open windows (a sequence
    following the scene's frame); whether there was one."""
    shown = False
    wm = context.window_manager
    for window in wm.windows if wm else []:
        for area in window.screen.areas:
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = img
                follow(area.spaces.active.image_user, img, context.scene)
                area.tag_redraw()
                shown = True
    return shown


def follow(user: bpy.types.ImageUser, img: bpy.types.Image, scene: bpy.types.Scene) -> None:
    """Sets an image user of a sequence whose files are numbered by frame
    to show, on scene frame F, the file numbered F."""
    if img.source != "SEQUENCE":
        return
    user.frame_start, user.frame_offset = 1, 0
    user.frame_duration = max(1, scene.frame_end)
    user.use_auto_refresh = True


def load_result(context: bpy.types.Context, p: job.Progress) -> bpy.types.Image:
    """Loads the fetched EXR (its passes as the layers of a multi-layer
    image) and shows it; a sequence's frames as one image sequence, each
    file numbered by its frame, so the timeline plays them."""
    img = bpy.data.images.load(p.exr, check_existing=False)
    img.name = f"Sylva {p.job}"
    if p.frames:
        img.source = "SEQUENCE"
    # Asking for its size reads the file, which settles the image's type
    # (MULTILAYER where it has passes; such an image's own size reads 0 × 0:
    # its pixels are per pass, read through an image user).
    _ = tuple(img.size)
    if not bpy.app.background and not show_image(context, img):
        try:  # no Image Editor: a new window with one
            bpy.ops.wm.window_new()
            area = context.window_manager.windows[-1].screen.areas[0]
            area.type = "IMAGE_EDITOR"
            area.spaces.active.image = img
            follow(area.spaces.active.image_user, img, context.scene)
        except Exception:  # noqa: BLE001 (the image is loaded all the same)
            pass
    return img


class SYLVA_OT_render(bpy.types.Operator):
    """Export the scene (instancing kept), render it on the Sylva farm and load the image with its passes"""

    bl_idname = "sylva.render"
    bl_label = "Render on Sylva"
    bl_options = {"REGISTER"}

    synchronous: BoolProperty(  # type: ignore[valid-type]
        name="Wait",
        description="Block until the job is done (always so in background mode)",
        default=False,
        options={"SKIP_SAVE"},
    )

    _bg = None  # job.Background while running
    _timer = None

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        return context.scene is not None and not context.window_manager.sylva_status.running

    def _status(self, context: bpy.types.Context, p: job.Progress) -> None:
        st = context.window_manager.sylva_status
        st.stage = p.error or p.stage
        st.progress = p.fraction
        if p.job:
            st.job = p.job
        if not bpy.app.background:
            text = f"Sylva: {st.stage}" + (f" — job {p.job}" if p.job else "")
            try:
                context.workspace.status_text_set(text)
            except Exception:  # noqa: BLE001 (no workspace in some contexts)
                pass
            for window in context.window_manager.windows:
                for area in window.screen.areas:
                    if area.type == "PROPERTIES":
                        area.tag_redraw()

    def execute(self, context: bpy.types.Context):  # noqa: ANN201
        st = context.window_manager.sylva_status
        try:
            client_mod = deps.client_module()
            settings = frame_settings(context)
        except (ImportError, RuntimeError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        s = context.scene.sylva_farm
        if s.output_dir:
            out = Path(bpy.path.abspath(s.output_dir))
        else:
            out = Path(tempfile.gettempdir()) / "sylva-blender"
        work = Path(tempfile.mkdtemp(prefix="export-", dir=str(_mkdir(out)))) if s.keep_export \
            else Path(tempfile.mkdtemp(prefix="sylva-export-"))
        try:
            exported = export.export_scene(context, work)
        except Exception as e:  # noqa: BLE001 (the exporter's errors are many)
            self.report({"ERROR"}, f"export failed: {e}")
            return {"CANCELLED"}
        lacking = [o for o in INSTANCING_OPTIONS if o in exported["lacking"]]
        if lacking:
            self.report({"WARNING"}, "this Blender's glTF exporter lacks "
                        f"{', '.join(lacking)}: instances may be lost or copied")
        st.scene_file = str(exported["scene"])
        st.image = st.exr = st.job = ""
        st.frames = 0
        st.running = True
        if bpy.app.background or self.synchronous:
            def say(p: job.Progress) -> None:
                self._status(context, p)
                if bpy.app.background:
                    print(f"sylva: {p.error or p.stage}" + (f" [{p.job}]" if p.job else ""),
                          flush=True)

            last = job.run(client_mod, settings, exported["scene"], out, say)
            return self._finish(context, last)
        self._bg = job.Background(client_mod, settings, exported["scene"], out)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 100)
        _RUNNING.append(self)
        self.report({"INFO"}, "Sylva: submitting the scene")
        return {"RUNNING_MODAL"}

    def modal(self, context: bpy.types.Context, event: bpy.types.Event):  # noqa: ANN201
        if event.type == "ESC" and self._bg is not None:
            self._bg.cancel()
        if event.type != "TIMER" or self._bg is None:
            return {"PASS_THROUGH"}
        for p in self._bg.poll():
            self._status(context, p)
            context.window_manager.progress_update(int(p.fraction * 100))
            if p.done:
                return self._finish(context, p)
        return {"PASS_THROUGH"}

    def cancel_job(self) -> None:
        if self._bg is not None:
            self._bg.cancel()

    def _finish(self, context: bpy.types.Context, p: job.Progress):  # noqa: ANN201
        wm = context.window_manager
        st = wm.sylva_status
        st.running = False
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
            wm.progress_end()
            try:
                context.workspace.status_text_set(None)
            except Exception:  # noqa: BLE001
                pass
        if self in _RUNNING:
            _RUNNING.remove(self)
        if p.error:
            st.stage = p.error
            self.report({"ERROR"}, f"Sylva: {p.error}")
            return {"CANCELLED"}
        try:
            img = load_result(context, p)
        except Exception as e:  # noqa: BLE001
            self.report({"ERROR"}, f"Sylva: cannot load {p.exr}: {e}")
            return {"CANCELLED"}
        st.image, st.exr, st.stage, st.progress = img.name, p.exr, "done", 1.0
        st.frames = len(p.frames)
        what = f"{len(p.frames)} frames from {p.exr}" if p.frames else p.exr
        self.report({"INFO"}, f"Sylva: job {p.job} done; image \"{img.name}\" ({what})")
        return {"FINISHED"}


def _mkdir(p: Path) -> Path:
    p.mkdir(parents=True, exist_ok=True)
    return p


class SYLVA_OT_cancel(bpy.types.Operator):
    """Cancel the running Sylva job"""

    bl_idname = "sylva.cancel"
    bl_label = "Cancel Sylva Job"

    def execute(self, context: bpy.types.Context):  # noqa: ANN201
        for op in list(_RUNNING):
            op.cancel_job()
        return {"FINISHED"}


class SYLVA_OT_install_deps(bpy.types.Operator):
    """pip-install grpcio, protobuf and blake3 into the add-on's own folder of Blender's user scripts"""

    bl_idname = "sylva.install_deps"
    bl_label = "Install dependencies"

    def execute(self, context: bpy.types.Context):  # noqa: ANN201
        t = time.monotonic()
        try:
            deps.install()
        except Exception as e:  # noqa: BLE001
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        gone = deps.missing()
        if gone:
            self.report({"ERROR"}, f"installed, but still not importable: {', '.join(gone)} "
                        "(restart Blender)")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Sylva: dependencies installed in {deps.target_dir()} "
                    f"({time.monotonic() - t:.0f} s)")
        return {"FINISHED"}


CLASSES = (SYLVA_OT_render, SYLVA_OT_cancel, SYLVA_OT_install_deps)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
