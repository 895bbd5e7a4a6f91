"""Exports the open scene for Sylva: a .glb with its instancing kept, and
the small scene file beside it that imports it (``{"import": "scene.glb"}``)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import bpy
from mathutils import Vector

from . import glb

#: The glTF exporter's options, where this Blender's exporter has them:
#: geometry-node instances as instances (``export_gn_mesh``), shared
#: meshes as EXT_mesh_gpu_instancing (``export_gpu_instances``), the
#: camera and the sun, modifiers applied, what renders only, custom
#: properties as extras (the ground marker), Blender's sun strength as
#: the light's intensity unconverted (Sylva's sun ``intensity``), the
#: current frame's pose.
OPTIONS: dict[str, Any] = {
    "export_format": "GLB",
    "export_gpu_instances": True,
    "export_gn_mesh": True,
    "export_cameras": True,
    "export_lights": True,
    "export_apply": True,
    "export_extras": True,
    "export_yup": True,
    "use_visible": True,
    "use_renderable": True,
    "use_selection": False,
    "export_animations": False,
    # The scene as it is on the current frame (the exporter's default is
    # frame 0's pose: an animated camera would render from the wrong place).
    "export_current_frame": True,
    "export_import_convert_lighting_mode": "RAW",
    "convert_lighting_mode": "RAW",  # its name in Blender 3.4
    "export_materials": "EXPORT",
    "export_image_format": "AUTO",
}


def exporter_options() -> tuple[dict[str, Any], list[str]]:
    """`OPTIONS` that this Blender's glTF exporter takes, and the names of
    those it lacks (instancing ones lost are worth a warning)."""
    props = bpy.ops.export_scene.gltf.get_rna_type().properties
    have = {k: v for k, v in OPTIONS.items() if k in props}
    return have, [k for k in OPTIONS if k not in props]


def ground_objects(scene: bpy.types.Scene) -> list[bpy.types.Object]:
    """Objects marked as Sylva's ground (custom property sylva = "ground")."""
    return [o for o in scene.objects if o.get("sylva") == "ground"]


def export_scene(
    context: bpy.types.Context, folder: str | Path, overrides: dict[str, Any] | None = None
) -> dict[str, Any]:
    """Exports `context`'s scene into `folder` as ``scene.glb`` and writes
    ``scene.json`` importing it (plus `overrides`, scene-file fields that
    replace the imported ones). Returns {"scene": path of the JSON,
    "glb": path, "fixes": what glb.fix_glb changed, "lacking": exporter
    options this Blender lacks, "summary": glb.summary}. Raises
    RuntimeError with the reason where it cannot."""
    scene = context.scene
    if scene.camera is None:
        raise RuntimeError("the scene has no active camera: Sylva renders from the scene's camera")
    if scene.camera.type != "CAMERA" or scene.camera.data.type != "PERSP":
        raise RuntimeError("the scene's camera must be a perspective camera")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    glb_path = folder / "scene.glb"
    opts, lacking = exporter_options()
    # The exporter runs on the view layer's objects; object mode keeps
    # edit-mode changes in.
    # (A command-line render's context has no active object.)
    active = getattr(context, "object", None)
    if active is not None and active.mode != "OBJECT":
        bpy.ops.object.mode_set(mode="OBJECT")
    result = bpy.ops.export_scene.gltf(filepath=str(glb_path), **opts)
    if "FINISHED" not in result or not glb_path.is_file():
        raise RuntimeError(f"the glTF exporter did not finish ({result})")
    fixes = glb.fix_glb(glb_path, camera=scene.camera.name)
    file: dict[str, Any] = {"import": glb_path.name}
    file.update(overrides or {})
    scene_path = folder / "scene.json"
    scene_path.write_text(json.dumps(file, indent=2) + "\n")
    return {"scene": scene_path, "glb": glb_path, "fixes": fixes, "lacking": lacking,
            "summary": glb.summary(glb_path)}


def _to_gltf(v: Any) -> list[float]:
    """A vector of Blender's world (Z up) in the exported file's (Y up),
    as the glTF exporter turns it (``export_yup``): (x, z, −y)."""
    return [float(v[0]), float(v[2]), -float(v[1])]


def camera_view(scene: bpy.types.Scene) -> dict[str, Any]:
    """The scene's camera now, as Sylva's importer reads the exported one:
    its position, a point ahead (its local −Z), its up (local +Y) and the
    vertical field of view the glTF exporter writes for this render size
    and sensor fit."""
    cam = scene.camera
    m = cam.matrix_world
    rot = m.to_3x3().normalized()
    eye = m.translation
    ahead = eye + rot @ Vector((0.0, 0.0, -10.0))
    up = rot @ Vector((0.0, 1.0, 0.0))
    r = scene.render
    width = r.pixel_aspect_x * r.resolution_x
    height = r.pixel_aspect_y * r.resolution_y
    aspect = width / height
    angle = cam.data.angle
    fit = cam.data.sensor_fit
    # The exporter's rule: the sensor's angle spans the wider side unless
    # the fit says otherwise.
    if (width >= height and fit != "VERTICAL") or (width < height and fit == "HORIZONTAL"):
        fov_y = 2.0 * math.atan(math.tan(angle * 0.5) / aspect)
    else:
        fov_y = angle
    return {"position": _to_gltf(eye), "look_at": _to_gltf(ahead), "up": _to_gltf(up),
            "fov_y_deg": math.degrees(fov_y)}


def sun_towards(scene: bpy.types.Scene) -> list[float] | None:
    """A vector towards the scene's first rendered sun lamp now (a sun
    shines along its local −Z), as the importer reads the exported light;
    None without one (the scene file's sun stays)."""
    for o in scene.objects:
        if o.type == "LIGHT" and o.data.type == "SUN" and not o.hide_render:
            return _to_gltf(o.matrix_world.to_3x3().normalized() @ Vector((0.0, 0.0, 1.0)))
    return None


def frame_views(scene: bpy.types.Scene) -> tuple[list[int], list[dict[str, Any]]]:
    """The scene's frame range (start to end by its step) and, per frame,
    the camera and the sun as they are animated there: the views of one
    sequence job. The frame the scene was on is restored."""
    now = scene.frame_current
    frames = list(range(scene.frame_start, scene.frame_end + 1, max(1, scene.frame_step)))
    views = []
    try:
        for f in frames:
            scene.frame_set(f)
            views.append({"camera": camera_view(scene), "sun_towards": sun_towards(scene)})
    finally:
        scene.frame_set(now)
    return frames, views
