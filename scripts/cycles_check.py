"""Renders Sylva's glTF export in Blender Cycles and compares it with
Sylva's path-traced reference of the same scene: the whole-image mean per
channel, and every pixel against both renders' own noise.

Runs inside Blender's Python (`bpy` from PyPI, in its own venv); driven by
scripts/cycles-check.sh, which exports the scene and renders Sylva's side.
Never a dependency of Sylva itself.

The Cycles scene is built from what the export carries, nothing known by
hand: the geometry, instancing, camera and ground from the glTF; each
material's surface (`extras.sylva.surface`), its colour and texture; the
leaf optics, sun radiance and sky from the scene's `extras.sylva`. Leaves
are Sylva's one leaf BSDF (docs/lighting.md): alpha-masked Diffuse(ρ_r) +
Translucent(ρ_t) per side, baked per texel as the pbrt export bakes them.
"""

import argparse
import json
import math
import os
import struct
import sys
import tempfile

import bpy
import numpy as np


def read_glb(path):
    """The JSON document and binary chunk of a .glb file."""
    with open(path, "rb") as f:
        data = f.read()
    magic, _version, _length = struct.unpack_from("<III", data, 0)
    if magic != 0x46546C67:
        sys.exit(f"{path}: not a binary glTF file")
    n, kind = struct.unpack_from("<II", data, 12)
    doc = json.loads(data[20 : 20 + n])
    offset = 20 + n
    binary = b""
    if offset < len(data):
        m, _ = struct.unpack_from("<II", data, offset)
        binary = data[offset + 8 : offset + 8 + m]
    return doc, binary


def srgb_to_linear(c):
    """As the tracer decodes texels (shaders/trace/scene.wgsl)."""
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def texture_rgba(doc, binary, index):
    """A glTF texture's texels as float RGBA (colour still sRGB-encoded),
    rows bottom-up as Blender stores images, and its size."""
    image = doc["images"][doc["textures"][index]["source"]]
    view = doc["bufferViews"][image["bufferView"]]
    start = view.get("byteOffset", 0)
    png = binary[start : start + view["byteLength"]]
    with tempfile.NamedTemporaryFile(suffix=".png", delete=False) as f:
        f.write(png)
        name = f.name
    try:
        img = bpy.data.images.load(name)
        img.colorspace_settings.name = "Non-Color"
        w, h = img.size
        px = np.empty(w * h * 4, dtype=np.float32)
        img.pixels.foreach_get(px)
        bpy.data.images.remove(img)
    finally:
        os.unlink(name)
    return px.reshape(h, w, 4), (w, h)


def float_image(name, rgba, size):
    """A linear float image Cycles samples texel by texel, as the tracer does."""
    w, h = size
    img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=True)
    img.colorspace_settings.name = "Non-Color"
    img.pixels.foreach_set(rgba.astype(np.float32).ravel())
    img.pack()
    return img


def leaf_coefficients(albedo, optics):
    """(ρ_rf, ρ_rb, ρ_tf, ρ_tb) for linear colours `albedo` (…, 3), each
    side scaled back so it never scatters more than it receives, as
    LeafOptics::coefficients and the shader's leaf_coefficients do."""
    rf = albedo * np.array(optics["reflect_front"])
    rb = albedo * np.array(optics["reflect_back"])
    tf = albedo * np.array(optics["transmit_front"])
    tb = albedo * np.array(optics["transmit_back"])
    front = np.maximum(rf + tf, 1.0)
    back = np.maximum(rb + tb, 1.0)
    return rf / front, rb / back, tf / front, tb / back


def build_material(mat, spec, doc, binary, optics):
    """Replaces an imported material's nodes with Sylva's BSDF for it."""
    pbr = spec.get("pbrMetallicRoughness", {})
    base = np.array(pbr.get("baseColorFactor", [1, 1, 1, 1])[:3], dtype=np.float64)
    surface = spec.get("extras", {}).get("sylva", {}).get("surface", "leaf")
    cutoff = spec.get("alphaCutoff", 0.5) if spec.get("alphaMode") == "MASK" else None
    tex = pbr.get("baseColorTexture", {}).get("index")
    if tex is not None:
        rgba, size = texture_rgba(doc, binary, tex)
        albedo = base * srgb_to_linear(rgba[..., :3].astype(np.float64))
        alpha = rgba[..., 3]
    else:
        size = (1, 1)
        albedo = base.reshape(1, 1, 3)
        alpha = np.ones((1, 1))
    mask = np.ones_like(alpha) if cutoff is None else (alpha >= cutoff).astype(np.float64)
    if surface in ("wood", "ground"):
        # Lambertian, one colour on both sides, nothing through.
        layers = {"rf": albedo, "rb": albedo, "tf": np.zeros_like(albedo), "tb": np.zeros_like(albedo)}
    else:
        rf, rb, tf, tb = leaf_coefficients(albedo, optics)
        layers = {"rf": rf, "rb": rb, "tf": tf, "tb": tb}

    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")

    def texel(key):
        rgba = np.concatenate([layers[key], mask[..., None]], axis=-1)
        node = nt.nodes.new("ShaderNodeTexImage")
        node.image = float_image(f"{mat.name}-{key}", rgba, size)
        node.interpolation = "Closest"
        return node

    nodes = {k: texel(k) for k in layers}
    side = {}
    for name, refl, trans in (("front", "rf", "tb"), ("back", "rb", "tf")):
        d = nt.nodes.new("ShaderNodeBsdfDiffuse")
        t = nt.nodes.new("ShaderNodeBsdfTranslucent")
        add = nt.nodes.new("ShaderNodeAddShader")
        nt.links.new(nodes[refl].outputs["Color"], d.inputs["Color"])
        nt.links.new(nodes[trans].outputs["Color"], t.inputs["Color"])
        nt.links.new(d.outputs[0], add.inputs[0])
        nt.links.new(t.outputs[0], add.inputs[1])
        side[name] = add
    geo = nt.nodes.new("ShaderNodeNewGeometry")
    sides = nt.nodes.new("ShaderNodeMixShader")
    nt.links.new(geo.outputs["Backfacing"], sides.inputs[0])
    nt.links.new(side["front"].outputs[0], sides.inputs[1])
    nt.links.new(side["back"].outputs[0], sides.inputs[2])
    cut = nt.nodes.new("ShaderNodeMixShader")
    clear = nt.nodes.new("ShaderNodeBsdfTransparent")
    nt.links.new(nodes["rf"].outputs["Alpha"], cut.inputs[0])
    nt.links.new(clear.outputs[0], cut.inputs[1])
    nt.links.new(sides.outputs[0], cut.inputs[2])
    nt.links.new(cut.outputs[0], out.inputs["Surface"])


def build_world(sky):
    """Sylva's sky: horizon + (zenith − horizon) √max(ω_up, 0)."""
    world = bpy.data.worlds.new("sylva-sky")
    bpy.context.scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    nt.nodes.clear()
    coords = nt.nodes.new("ShaderNodeTexCoord")
    xyz = nt.nodes.new("ShaderNodeSeparateXYZ")
    up = nt.nodes.new("ShaderNodeMath")
    up.operation = "MAXIMUM"
    up.inputs[1].default_value = 0.0
    root = nt.nodes.new("ShaderNodeMath")
    root.operation = "POWER"
    root.inputs[1].default_value = 0.5
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.inputs["A"].default_value = (*sky["horizon"], 1.0)
    mix.inputs["B"].default_value = (*sky["zenith"], 1.0)
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = 1.0
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(coords.outputs["Generated"], xyz.inputs[0])
    nt.links.new(xyz.outputs["Z"], up.inputs[0])
    nt.links.new(up.outputs[0], root.inputs[0])
    nt.links.new(root.outputs[0], mix.inputs["Factor"])
    nt.links.new(mix.outputs["Result"], bg.inputs["Color"])
    nt.links.new(bg.outputs[0], out.inputs["Surface"])


def build_scene(glb, width, height, samples):
    doc, binary = read_glb(glb)
    extras = doc["scenes"][doc.get("scene", 0)].get("extras", {}).get("sylva")
    if not extras or "leaf_optics" not in extras or "radiance" not in extras.get("sun", {}):
        sys.exit(f"{glb}: no extras.sylva with leaf_optics and sun.radiance (export it with this Sylva)")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=glb)
    scene = bpy.context.scene

    # Materials: each imported one rebuilt from its glTF definition.
    by_name = {}
    for spec in doc.get("materials", []):
        by_name.setdefault(spec["name"], []).append(spec)
    for mat in list(bpy.data.materials):
        stem = mat.name.rsplit(".", 1)[0] if mat.name[-4:-3] == "." else mat.name
        specs = by_name.get(mat.name) or by_name.get(stem)
        if not specs:
            continue
        if any(s != specs[0] for s in specs):
            sys.exit(f"{glb}: materials named {stem!r} differ; cannot tell them apart after import")
        build_material(mat, specs[0], doc, binary, extras["leaf_optics"])

    # The ground: Sylva's is an infinite plane; the export's quad, widened.
    for obj in scene.objects:
        if obj.type == "MESH" and obj.name.startswith("ground"):
            obj.scale = (1000.0, 1000.0, 1000.0)
            obj.location = (0.0, 0.0, 0.0)

    # The sun: Blender's strength is the irradiance on a plane facing it,
    # which is π × Sylva's radiance (docs/lighting.md, "Units of the scene").
    for obj in [o for o in scene.objects if o.type == "LIGHT"]:
        bpy.data.objects.remove(obj)
    radiance = extras["sun"]["radiance"]
    peak = max(radiance)
    sun_node = next(n for n in doc["nodes"] if n.get("name") == "sun")
    qx, qy, qz, qw = sun_node["rotation"]
    light = bpy.data.lights.new("sun", "SUN")
    light.energy = math.pi * peak
    light.color = [c / peak for c in radiance]
    light.angle = 0.0
    sun = bpy.data.objects.new("sun", light)
    scene.collection.objects.link(sun)
    # glTF (y up) to Blender (z up): x, −z, y; the light shines down its −Z.
    from mathutils import Quaternion

    to_blender = Quaternion((1.0, 0.0, 0.0), math.pi / 2)
    sun.rotation_mode = "QUATERNION"
    sun.rotation_quaternion = to_blender @ Quaternion((qw, qx, qy, qz))

    build_world(extras["sky"])

    cam = next(o for o in scene.objects if o.type == "CAMERA")
    scene.camera = cam
    yfov = doc["cameras"][0]["perspective"]["yfov"]
    cam.data.sensor_fit = "VERTICAL"
    cam.data.angle_y = yfov
    cam.data.clip_start = 0.01
    cam.data.clip_end = 1.0e6

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 1.0
    # Sylva's reference: up to 16 bounces, Russian roulette, no clamping.
    scene.cycles.max_bounces = 16
    scene.cycles.diffuse_bounces = 16
    scene.cycles.transmission_bounces = 16
    scene.cycles.glossy_bounces = 0
    scene.cycles.volume_bounces = 0
    scene.cycles.transparent_max_bounces = 1024
    scene.cycles.sample_clamp_direct = 0.0
    scene.cycles.sample_clamp_indirect = 0.0
    scene.cycles.caustics_reflective = False
    scene.cycles.caustics_refractive = False
    scene.cycles.blur_glossy = 0.0
    scene.render.resolution_x = width
    scene.render.resolution_y = height
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.image_settings.color_mode = "RGBA"
    return scene


def render(scene, seed, path):
    scene.cycles.seed = seed
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)


def load_rgb(path):
    img = bpy.data.images.load(path)
    w, h = img.size
    px = np.empty(w * h * 4, dtype=np.float32)
    img.pixels.foreach_get(px)
    bpy.data.images.remove(img)
    return px.reshape(h, w, 4)[..., :3].astype(np.float64)


def compare(cycles, sylva, block):
    """Means and per-pixel agreement of two pairs of independent renders."""
    c, s = (cycles[0] + cycles[1]) / 2, (sylva[0] + sylva[1]) / 2
    # Each pair's spread estimates the variance of its mean: E[(a − b)²]/4.
    var = ((cycles[0] - cycles[1]) ** 2 + (sylva[0] - sylva[1]) ** 2) / 4
    d = c - s
    mean_c, mean_s = c.reshape(-1, 3).mean(0), s.reshape(-1, 3).mean(0)
    # The mean's own noise: both images' variance over the pixel count.
    mean_sigma = np.sqrt(var.reshape(-1, 3).sum(0)) / (c.shape[0] * c.shape[1])
    h, w = (c.shape[0] // block) * block, (c.shape[1] // block) * block
    db = d[:h, :w].reshape(h // block, block, w // block, block, 3).sum((1, 3))
    vb = var[:h, :w].reshape(h // block, block, w // block, block, 3).sum((1, 3))
    z = db / np.sqrt(np.maximum(vb, 1e-30))
    return {
        "mean_cycles": mean_c.tolist(),
        "mean_sylva": mean_s.tolist(),
        "mean_ratio": (mean_c / mean_s).tolist(),
        "mean_ratio_sigma": (mean_sigma / mean_s).tolist(),
        "luminance_ratio": float(
            (mean_c @ [0.2126, 0.7152, 0.0722]) / (mean_s @ [0.2126, 0.7152, 0.0722])
        ),
        # Squared difference over the variance both renders' noise explains:
        # 1 when they differ by noise alone.
        "pixel_chi2_per_dof": float((d**2).sum() / var.sum()),
        "block": block,
        "block_z_rms": float(np.sqrt((z**2).mean())),
        "blocks_beyond_3_sigma": float((np.abs(z) > 3).mean()),
    }


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--glb", required=True)
    ap.add_argument("--sylva", nargs=2, required=True, help="two EXRs of Sylva's reference, other seeds")
    ap.add_argument("--width", type=int, required=True)
    ap.add_argument("--height", type=int, required=True)
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--block", type=int, default=8)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    os.makedirs(a.out, exist_ok=True)
    scene = build_scene(os.path.abspath(a.glb), a.width, a.height, a.samples)
    paths = [os.path.abspath(os.path.join(a.out, f"cycles-{seed}.exr")) for seed in (1, 2)]
    for seed, p in zip((1, 2), paths):
        render(scene, seed, p)
    result = compare([load_rgb(p) for p in paths], [load_rgb(p) for p in a.sylva], a.block)
    result.update({"blender": bpy.app.version_string, "samples_per_render": a.samples, "glb": a.glb})
    with open(os.path.join(a.out, "cycles-check.json"), "w") as f:
        json.dump(result, f, indent=2)
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
