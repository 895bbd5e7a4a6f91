"""The add-on end to end: a scattered forest built in bpy, "Render on
Sylva" against a real farm, the image and its passes back in Blender, the
same as `sylva render` of the same export."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import bpy
import numpy as np
import OpenEXR
import pytest

import scene_builder
from conftest import child_env

W, H, SPP = 96, 64, 2
#: Every pass but beauty, as the EXR names its layers (docs/passes.md).
LAYERS = ("Combined", "Direct", "Indirect", "Env", "DiffCol", "Normal", "Depth", "IndexOB",
          "IndexSpecies")


def channels(path: Path) -> dict[str, np.ndarray]:
    """An EXR's channels by name (float32 arrays)."""
    with OpenEXR.File(str(path), separate_channels=True) as f:
        return {k: np.array(v.pixels, dtype=np.float32) for k, v in f.parts[0].channels.items()}


@pytest.fixture(scope="session")
def rendered(addon, farm, tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The forest, rendered with "Render on Sylva"."""
    objs = scene_builder.build_scene(W, H)
    scattered = scene_builder.scattered_count()
    prefs = bpy.context.preferences.addons["sylva_blender"].preferences
    prefs.address = farm["addr"]
    prefs.token = farm["token"]
    s = bpy.context.scene.sylva_farm
    s.spp, s.seed, s.accel, s.lighting, s.all_passes = SPP, 1, "bvh", "scene", True
    s.output_dir = str(tmp_path_factory.mktemp("out"))
    s.keep_export = True
    assert bpy.ops.sylva.render() == {"FINISHED"}
    st = bpy.context.window_manager.sylva_status
    return {"status": st, "scattered": scattered, "objects": objs,
            "scene": Path(st.scene_file), "exr": Path(st.exr), "job": st.job}


def test_job_done_and_image_loaded(rendered: dict) -> None:
    st = rendered["status"]
    assert not st.running and st.stage == "done" and st.progress == 1.0
    assert rendered["job"]
    img = bpy.data.images[st.image]
    assert Path(bpy.path.abspath(img.filepath)) == rendered["exr"]
    assert img.type == "MULTILAYER"
    png = bpy.data.images.load(str(rendered["exr"].with_suffix(".png")), check_existing=False)
    assert tuple(png.size) == (W, H)


def test_beauty_matches_sylva_render(rendered: dict, sylva: Path, tmp_path: Path) -> None:
    """`sylva render` of the exported scene, in one process, gives the
    farm's image bit for bit (beauty and every pass)."""
    out = tmp_path / "x.png"
    r = subprocess.run(
        [str(sylva), "render", str(rendered["scene"]), "--local-workers", "0",
         "--width", str(W), "--height", str(H), "--spp", str(SPP), "--seed", "1",
         "--accel", "bvh", "--passes", "all", "--exr", "--out", str(out)],
        env=child_env(), capture_output=True, text=True, timeout=300, check=False,
    )
    assert r.returncode == 0, r.stderr
    farm, local = channels(rendered["exr"]), channels(out.with_suffix(".exr"))
    assert sorted(farm) == sorted(local)
    beauty = [f"ViewLayer.Combined.{c}" for c in "RGB"]
    for c in beauty:
        assert farm[c].shape == (H, W)
        assert np.isfinite(farm[c]).all() and farm[c].max() > 0
        np.testing.assert_array_equal(farm[c], local[c], err_msg=c)
    for c in farm:
        np.testing.assert_array_equal(farm[c], local[c], err_msg=c)


def test_passes_listed_in_blender(rendered: dict) -> None:
    """Blender opens the EXR as a multi-layer image; a compositor Image
    node reading it offers every pass as an output."""
    img = bpy.data.images.load(str(rendered["exr"]), check_existing=False)
    _ = tuple(img.size)  # reads the file
    assert img.type == "MULTILAYER"
    scene = bpy.context.scene
    scene.use_nodes = True
    node = scene.node_tree.nodes.new("CompositorNodeImage")
    node.image = img
    outputs = [o.name for o in node.outputs if o.enabled]
    print("passes in Blender:", outputs)
    # Combined is "Image" in some Blender versions, "Combined" in others.
    missing = [p for p in LAYERS if p not in outputs
               and not (p == "Combined" and "Image" in outputs)]
    assert not missing, f"{missing} not among {outputs}"
    scene.node_tree.nodes.remove(node)


def test_gltf_keeps_instancing(rendered: dict, addon) -> None:
    """The scatter is one mesh drawn by one EXT_mesh_gpu_instancing node
    (one transform per scattered point); the collection instance is a node
    that reuses that mesh; mesh names are unique."""
    glb = rendered["scene"].parent / "scene.glb"
    assert json.loads(rendered["scene"].read_text()) == {"import": "scene.glb"}
    summary = addon.glb.summary(glb)
    print(json.dumps(summary))
    meshes = summary["meshes"]
    assert len(meshes) == len(set(meshes)) == 2, meshes  # the ground and the tree
    nodes = {n["name"]: n for n in summary["nodes"]}
    scatter = nodes["Scatter"]
    assert scatter["instances"] == rendered["scattered"] > 10
    assert meshes[scatter["mesh"]] == "TreeMesh"
    inst = nodes["TreeInstance"]
    children = [summary["nodes"][i] for i in inst["children"]]
    assert [c["mesh"] for c in children] == [scatter["mesh"]]
    assert "EXT_mesh_gpu_instancing" in summary["extensionsUsed"]
    doc, _ = addon.glb.read_glb(glb)
    # Blender requires the lights' extension; Sylva's reader takes it (the sun).
    assert "KHR_lights_punctual" in doc.get("extensionsRequired", [])
    assert doc["nodes"][[n["name"] for n in doc["nodes"]].index("Ground")]["extras"] == {
        "sylva": "ground"}


def test_wrong_token_is_a_report(rendered: dict, farm: dict) -> None:
    """A refused job is the operator's error report (bpy raises it as a
    RuntimeError), not a traceback from inside the add-on."""
    prefs = bpy.context.preferences.addons["sylva_blender"].preferences
    prefs.token = "not-the-token"
    try:
        with pytest.raises(RuntimeError) as e:
            bpy.ops.sylva.render()
    finally:
        prefs.token = farm["token"]
    assert "Sylva: " in str(e.value) and "Unauthenticated" in str(e.value)
    assert "Traceback" not in str(e.value)
    assert not bpy.context.window_manager.sylva_status.running


def test_a_frame_range_renders_as_one_sequence_job(rendered: dict, addon, sylva: Path,
                                                   tmp_path: Path) -> None:
    """With "Frame range" on, the scene's range is one sequence job: the
    camera and the sun as animated on each frame, the frames fetched as
    files numbered by frame and loaded back as one image sequence. Each
    frame's view is the camera Sylva's importer reads from an export made
    on that frame."""
    scene = bpy.context.scene
    cam = rendered["objects"]["camera"]
    sun = rendered["objects"]["sun"]
    start_loc, start_rot = tuple(cam.location), tuple(sun.rotation_euler)
    scene.frame_start, scene.frame_end, scene.frame_step = 1, 3, 1
    scene.frame_set(1)
    cam.keyframe_insert("location", frame=1)
    sun.keyframe_insert("rotation_euler", frame=1)
    cam.location.x += 6.0
    sun.rotation_euler.x += 0.4
    cam.keyframe_insert("location", frame=3)
    sun.keyframe_insert("rotation_euler", frame=3)
    scene.frame_set(2)
    s = scene.sylva_farm
    s.animation = True
    try:
        assert bpy.ops.sylva.render() == {"FINISHED"}
        st = bpy.context.window_manager.sylva_status
        assert st.frames == 3 and st.stage == "done", st.stage
        assert scene.frame_current == 2, "the frame the scene was on is restored"
        first = Path(st.exr)
        files = [first.with_name(first.name.replace("-0001.", f"-{n:04d}.")) for n in (1, 2, 3)]
        assert first.name.endswith("-0001.exr") and all(f.is_file() for f in files), files
        img = bpy.data.images[st.image]
        assert img.source == "SEQUENCE" and Path(bpy.path.abspath(img.filepath)) == first
        # The camera moved: the frames differ.
        beauty = [channels(f)["ViewLayer.Combined.R"] for f in files]
        assert not np.array_equal(beauty[0], beauty[2])

        # Frame 3's view is what Sylva reads from an export made on frame 3.
        scene.frame_set(3)
        view = addon.export.camera_view(scene)
        towards = addon.export.sun_towards(scene)
        made = addon.export.export_scene(bpy.context, tmp_path / "f3")
        imported = tmp_path / "f3" / "imported.json"
        r = subprocess.run([str(sylva), "scene", "import", str(made["glb"]), "-o", str(imported)],
                           env=child_env(), capture_output=True, text=True, timeout=120,
                           check=False)
        assert r.returncode == 0, r.stderr
        read = json.loads(imported.read_text())
        for k in ("position", "look_at", "up"):
            np.testing.assert_allclose(view[k], read["camera"][k], atol=1e-3, err_msg=k)
        assert abs(view["fov_y_deg"] - read["camera"]["fov_y_deg"]) < 1e-3
        d = np.array(read["sun"]["direction"], dtype=float)
        np.testing.assert_allclose(np.array(towards) / np.linalg.norm(towards),
                                   d / np.linalg.norm(d), atol=1e-4)
    finally:
        s.animation = False
        cam.animation_data_clear()
        sun.animation_data_clear()
        cam.location, sun.rotation_euler = start_loc, start_rot
        scene.frame_set(1)


def test_f12_renders_on_the_farm_into_the_render_result(rendered: dict, tmp_path: Path) -> None:
    """With Render Engine set to "Sylva", Blender's own render (F12; here
    `render.render`, which runs the engine on the main thread as
    background mode does) exports, renders on the farm and fills the
    render result: the still Blender writes holds the farm's beauty to the
    bit, as linear light."""
    scene = bpy.context.scene
    out = Path(scene.sylva_farm.output_dir)
    before = set(out.glob("sylva-*.exr"))
    engine, filepath = scene.render.engine, scene.render.filepath
    fmt = scene.render.image_settings
    saved = (fmt.file_format, fmt.color_depth, fmt.color_mode)
    try:
        scene.render.engine = "SYLVA"
        fmt.file_format, fmt.color_depth, fmt.color_mode = "OPEN_EXR", "32", "RGB"
        scene.render.filepath = str(tmp_path / "f12.exr")
        assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    finally:
        scene.render.engine, scene.render.filepath = engine, filepath
        fmt.file_format, fmt.color_depth, fmt.color_mode = saved
    fetched = sorted(set(out.glob("sylva-*.exr")) - before)
    assert len(fetched) == 1, fetched
    farm, written = channels(fetched[0]), channels(tmp_path / "f12.exr")
    assert sorted(farm) == ["B", "G", "R"], sorted(farm)  # the beauty alone, plain RGB
    for c in "RGB":
        key = next(k for k in written if k.split(".")[-1] == c)
        assert written[key].shape == (H, W)
        assert farm[c].max() > 0
        np.testing.assert_array_equal(written[key], farm[c], err_msg=c)


def test_f12_without_a_farm_is_the_renders_error(rendered: dict) -> None:
    """A farm that cannot be reached is the render's error report, and the
    engine leaves Blender as it was."""
    scene = bpy.context.scene
    prefs = bpy.context.preferences.addons["sylva_blender"].preferences
    address, engine = prefs.address, scene.render.engine
    prefs.address = "127.0.0.1:1"
    scene.render.engine = "SYLVA"
    try:
        with pytest.raises(RuntimeError) as e:
            bpy.ops.render.render()
    finally:
        prefs.address, scene.render.engine = address, engine
    assert "Sylva: " in str(e.value), str(e.value)
