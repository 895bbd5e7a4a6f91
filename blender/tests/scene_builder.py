"""Builds, in bpy, the small forest the tests render: a tree mesh (a trunk
and a few leaf quads) scattered over a ground plane by geometry nodes
(Distribute Points on Faces + Instance on Points, fixed seed), one more
tree placed by a collection instance, a camera and a sun.

Works in Blender 3.4 (Debian's, for the screenshots) and 4.x (bpy from
PyPI, for the tests).
"""

from __future__ import annotations

import math

import bpy

#: The scatter's settings: points per square metre and seed.
DENSITY = 0.06
SEED = 7
GROUND_SIZE = 30.0


def _material(name: str, rgba: tuple[float, float, float, float]) -> bpy.types.Material:
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    bsdf = m.node_tree.nodes.get("Principled BSDF")
    if bsdf is not None:
        bsdf.inputs["Base Color"].default_value = rgba
    m.diffuse_color = rgba
    return m


def tree_mesh(name: str = "TreeMesh") -> bpy.types.Mesh:
    """A small tree, Z up: a square trunk 3 m tall (material "bark") and a
    crown of crossed leaf quads (material "leaf")."""
    verts: list[tuple[float, float, float]] = []
    faces: list[tuple[int, ...]] = []
    mats: list[int] = []
    r, h = 0.15, 3.0
    base = len(verts)
    for z in (0.0, h):
        verts += [(-r, -r, z), (r, -r, z), (r, r, z), (-r, r, z)]
    for i in range(4):
        j = (i + 1) % 4
        faces.append((base + i, base + j, base + 4 + j, base + 4 + i))
        mats.append(0)
    # Leaves: quads at three heights, each turned.
    for k in range(9):
        a = k * 2.4
        z = 1.6 + 0.35 * k
        c, s = math.cos(a), math.sin(a)
        w, l = 0.6, 1.4
        v0 = len(verts)
        for (u, t) in ((0.0, -w), (l, -w), (l, w), (0.0, w)):
            verts.append((c * u - s * t, s * u + c * t, z + 0.25 * u))
        faces.append((v0, v0 + 1, v0 + 2, v0 + 3))
        mats.append(1)
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    me.materials.append(_material("bark", (0.25, 0.15, 0.08, 1.0)))
    me.materials.append(_material("leaf", (0.15, 0.45, 0.1, 1.0)))
    for p, m in zip(me.polygons, mats):
        p.material_index = m
    me.update()
    return me


def _scatter_group(ground: bpy.types.Object, tree: bpy.types.Object) -> bpy.types.NodeTree:
    ng = bpy.data.node_groups.new("SylvaScatter", "GeometryNodeTree")
    if hasattr(ng, "interface"):  # 4.0+
        ng.interface.new_socket(name="Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
        ng.interface.new_socket(name="Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    else:
        ng.inputs.new("NodeSocketGeometry", "Geometry")
        ng.outputs.new("NodeSocketGeometry", "Geometry")
    n = ng.nodes
    gin = n.new("NodeGroupInput")
    gout = n.new("NodeGroupOutput")
    ground_info = n.new("GeometryNodeObjectInfo")
    ground_info.inputs["Object"].default_value = ground
    ground_info.transform_space = "RELATIVE"
    dist = n.new("GeometryNodeDistributePointsOnFaces")
    dist.distribute_method = "RANDOM"
    dist.inputs["Density"].default_value = DENSITY
    dist.inputs["Seed"].default_value = SEED
    tree_info = n.new("GeometryNodeObjectInfo")
    tree_info.inputs["Object"].default_value = tree
    inst = n.new("GeometryNodeInstanceOnPoints")
    rnd = n.new("FunctionNodeRandomValue")
    rnd.data_type = "FLOAT"
    rnd.inputs[2].default_value = 0.0  # Min (float)
    rnd.inputs[3].default_value = 2 * math.pi  # Max (float)
    rnd.inputs["Seed"].default_value = SEED
    comb = n.new("ShaderNodeCombineXYZ")
    links = ng.links
    links.new(ground_info.outputs["Geometry"], dist.inputs["Mesh"])
    links.new(dist.outputs["Points"], inst.inputs["Points"])
    links.new(tree_info.outputs["Geometry"], inst.inputs["Instance"])
    links.new(rnd.outputs[1], comb.inputs["Z"])  # the float output
    links.new(comb.outputs["Vector"], inst.inputs["Rotation"])
    links.new(inst.outputs["Instances"], gout.inputs[0])
    del gin
    return ng


def build_scene(width: int = 96, height: int = 64) -> dict[str, bpy.types.Object]:
    """Empties the open file and builds the forest; returns its objects.
    (The file is emptied by hand: reading factory settings would also
    reset the preferences, and with them the enabled add-on.)"""
    for data in (bpy.data.objects, bpy.data.meshes, bpy.data.cameras, bpy.data.lights,
                 bpy.data.materials, bpy.data.node_groups, bpy.data.collections):
        for x in list(data):
            data.remove(x)
    scene = bpy.context.scene
    scene.render.resolution_x = width
    scene.render.resolution_y = height
    scene.render.resolution_percentage = 100

    # The tree lives in its own collection, left out of the view layer: it
    # is placed only by the scatter and by the collection instance.
    trees = bpy.data.collections.new("TreeSource")
    scene.collection.children.link(trees)
    tree = bpy.data.objects.new("Tree", tree_mesh())
    trees.objects.link(tree)
    bpy.context.view_layer.layer_collection.children["TreeSource"].exclude = True

    gmesh = bpy.data.meshes.new("GroundMesh")
    s = GROUND_SIZE / 2
    gmesh.from_pydata([(-s, -s, 0), (s, -s, 0), (s, s, 0), (-s, s, 0)], [], [(0, 1, 2, 3)])
    gmesh.materials.append(_material("ground", (0.1, 0.08, 0.05, 1.0)))
    ground = bpy.data.objects.new("Ground", gmesh)
    ground["sylva"] = "ground"  # Sylva's ground plane (extras {"sylva": "ground"})
    scene.collection.objects.link(ground)

    # The scatter: an object whose geometry nodes put trees on the ground.
    smesh = bpy.data.meshes.new("ScatterBase")
    scatter = bpy.data.objects.new("Scatter", smesh)
    scene.collection.objects.link(scatter)
    mod = scatter.modifiers.new("Scatter", "NODES")
    mod.node_group = _scatter_group(ground, tree)

    # One more tree: a collection instance beside the field.
    ci = bpy.data.objects.new("TreeInstance", None)
    ci.instance_type = "COLLECTION"
    ci.instance_collection = trees
    ci.location = (s + 4.0, 0.0, 0.0)
    ci.rotation_euler = (0.0, 0.0, 0.6)
    ci.scale = (1.5, 1.5, 1.5)
    scene.collection.objects.link(ci)

    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 30
    cam = bpy.data.objects.new("Camera", cam_data)
    cam.location = (0.0, -42.0, 14.0)
    cam.rotation_euler = (math.radians(72), 0.0, 0.0)
    scene.collection.objects.link(cam)
    scene.camera = cam

    sun_data = bpy.data.lights.new("Sun", "SUN")
    sun_data.energy = 3.0
    sun = bpy.data.objects.new("Sun", sun_data)
    sun.rotation_euler = (math.radians(40), math.radians(20), math.radians(30))
    scene.collection.objects.link(sun)
    bpy.context.view_layer.update()
    return {"tree": tree, "ground": ground, "scatter": scatter, "instance": ci,
            "camera": cam, "sun": sun}


def scattered_count() -> int:
    """How many trees the scatter placed (its evaluated instances)."""
    dg = bpy.context.evaluated_depsgraph_get()
    return sum(
        1 for i in dg.object_instances
        if i.is_instance and i.parent is not None and i.parent.original.name == "Scatter"
    )
