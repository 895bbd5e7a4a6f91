"""The add-on's settings: the farm (address, token) in the add-on's
preferences, so that they stay out of .blend files; what to render
(samples, lighting, passes, …) per scene. Width and height are the
scene's render resolution."""

import bpy
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from . import deps

LIGHTINGS = [
    ("scene", "Scene default", "The scene file's own lighting method"),
    ("local", "Local", "Direct sun light only"),
    ("ambient", "Ambient", "Direct light plus a constant ambient term matched to the LB image"),
    ("lb", "LB", "Direct light plus LB (lattice-Boltzmann) indirect light"),
    ("gather", "Gather", "A final gather over the LB lattice"),
    ("gather-ambient", "Gather (ambient)", "The gather, its far end a matched constant"),
    ("boulanger", "Boulanger", "Boulanger et al. 2008, closed-form per-leaf lighting"),
    ("reference", "Reference", "The reference path tracer"),
    ("lb-visualize", "LB visualize", "The LB value alone"),
]
ACCELS = [
    ("auto", "Auto", "Each worker picks its fastest traversal"),
    ("rq", "Ray queries", "The device's own ray-query structures"),
    ("bvh", "BVH", "Sylva's four-wide BVH"),
    ("cwbvh", "Compressed wide BVH", "Sylva's eight-wide compressed BVH"),
    ("kd", "kd-tree", "Sylva's kd-tree"),
]
PASSES = [
    ("direct", "Direct", "Direct sun light"),
    ("indirect", "Indirect", "Indirect light"),
    ("albedo", "Albedo", "Surface colour (DiffCol)"),
    ("normal", "Normal", "World-space normals"),
    ("depth", "Depth", "Distance along the view (Depth)"),
    ("instance", "Instance", "Instance index + 1 (IndexOB)"),
    ("species", "Species", "Model index (IndexSpecies)"),
    ("sky", "Sky", "What the sky adds (Env)"),
]


def addon_prefs(context=None):  # noqa: ANN201
    """The add-on's preferences, or None where it is not enabled as an
    add-on (registered by hand)."""
    context = context or bpy.context
    a = context.preferences.addons.get(__package__)
    return a.preferences if a is not None else None


def _draw_deps(layout: bpy.types.UILayout) -> None:
    gone = deps.missing()
    box = layout.box()
    if gone:
        box.label(text=f"Missing Python packages: {', '.join(gone)}", icon="ERROR")
        box.operator("sylva.install_deps", icon="IMPORT")
        box.label(text=f"They go to {deps.target_dir()}")
    else:
        box.label(text="Python dependencies: installed", icon="CHECKMARK")
        box.operator("sylva.install_deps", text="Reinstall dependencies")


class SylvaPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    address: StringProperty(  # type: ignore[valid-type]
        name="Farm address",
        description="The coordinator's address, host:port",
        default="127.0.0.1:50150",
    )
    token: StringProperty(  # type: ignore[valid-type]
        name="Token",
        description="The farm's bearer token; empty: $SYLVA_TOKEN",
        subtype="PASSWORD",
        default="",
    )
    tls_ca: StringProperty(  # type: ignore[valid-type]
        name="TLS CA",
        description="A CA certificate (PEM) to connect over TLS; empty: plain connection",
        subtype="FILE_PATH",
        default="",
    )

    def draw(self, context: bpy.types.Context) -> None:
        col = self.layout.column()
        col.prop(self, "address")
        col.prop(self, "token")
        col.prop(self, "tls_ca")
        _draw_deps(self.layout)


class SylvaSceneSettings(bpy.types.PropertyGroup):
    spp: IntProperty(  # type: ignore[valid-type]
        name="Samples", description="Rays per pixel", default=4, min=1, max=4096
    )
    seed: IntProperty(  # type: ignore[valid-type]
        name="Seed", description="Seed of the per-pixel sample positions", default=1, min=0
    )
    lighting: EnumProperty(  # type: ignore[valid-type]
        name="Lighting", items=LIGHTINGS, default="scene"
    )
    accel: EnumProperty(name="Traversal", items=ACCELS, default="auto")  # type: ignore[valid-type]
    all_passes: BoolProperty(  # type: ignore[valid-type]
        name="All passes", description="Every render pass, as layers of the EXR", default=True
    )
    passes: EnumProperty(  # type: ignore[valid-type]
        name="Passes", items=PASSES, options={"ENUM_FLAG"}, default=set()
    )
    animation: BoolProperty(  # type: ignore[valid-type]
        name="Frame range",
        description=(
            "Render the scene's frame range (Start to End by Step) as one sequence job, the "
            "camera and the sun as animated on each frame; the rest of the scene as it is on "
            "the current frame. The frames load back as an image sequence"
        ),
        default=False,
    )
    keep_export: BoolProperty(  # type: ignore[valid-type]
        name="Keep export",
        description="Keep the exported scene (in the output folder) rather than a temporary one",
        default=False,
    )
    output_dir: StringProperty(  # type: ignore[valid-type]
        name="Output",
        description="Folder for the fetched images; empty: a temporary folder",
        subtype="DIR_PATH",
        default="",
    )


class SylvaStatus(bpy.types.PropertyGroup):
    """The running job, for the panel (on the window manager: not saved)."""

    running: BoolProperty(default=False)  # type: ignore[valid-type]
    job: StringProperty(default="")  # type: ignore[valid-type]
    stage: StringProperty(default="")  # type: ignore[valid-type]
    progress: FloatProperty(  # type: ignore[valid-type]
        name="Progress", default=0.0, min=0.0, max=1.0, subtype="FACTOR"
    )
    image: StringProperty(default="")  # type: ignore[valid-type]
    exr: StringProperty(default="")  # type: ignore[valid-type]
    #: Frames of the last job (0: one frame, not a sequence).
    frames: IntProperty(default=0)  # type: ignore[valid-type]
    scene_file: StringProperty(default="")  # type: ignore[valid-type]


CLASSES = (SylvaPreferences, SylvaSceneSettings, SylvaStatus)


def register() -> None:
    for c in CLASSES:
        bpy.utils.register_class(c)
    # Not `Scene.sylva`: the exporter writes the scene's properties as its
    # extras, and Sylva's importer reads extras["sylva"] as scene-file
    # fields (lighting, sky, ground) of its own exporter.
    bpy.types.Scene.sylva_farm = PointerProperty(type=SylvaSceneSettings)
    bpy.types.WindowManager.sylva_status = PointerProperty(type=SylvaStatus)


def unregister() -> None:
    del bpy.types.WindowManager.sylva_status
    del bpy.types.Scene.sylva_farm
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
