"""Scene building blocks for deterministic Cycles renders."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def reset_scene():
    """An empty scene (keeps enabled extensions, unlike ``read_factory_settings``)."""
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    return bpy.context.scene


def configure_cycles(
    scene,
    resolution: tuple[int, int] = (64, 64),
    samples: int = 16,
    seed: int = 0,
    osl: bool = True,
    max_bounces: int | None = None,
) -> None:
    """Cycles on the CPU, fixed seed and samples, denoising and adaptive sampling off.

    The pixel filter is made tiny so that every sample stays inside its own pixel: a pixel then
    shows exactly what lies under it (texel tests rely on this).
    """
    scene.render.engine = "CYCLES"
    cyc = scene.cycles
    cyc.device = "CPU"
    cyc.shading_system = osl
    cyc.samples = samples
    cyc.seed = seed
    cyc.use_animated_seed = False
    cyc.use_denoising = False
    cyc.use_adaptive_sampling = False
    cyc.filter_width = 0.01
    if max_bounces is not None:
        cyc.max_bounces = max_bounces
    scene.render.resolution_x, scene.render.resolution_y = resolution
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0


def dark_world(scene, strength: float = 0.0):
    """Give the scene its own world whose background adds ``strength`` (default: no light)."""
    import bpy

    world = bpy.data.worlds.new("MS Dark World")
    if world.node_tree is None:  # 4.5
        world.use_nodes = True
    bg = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    bg.inputs["Strength"].default_value = strength
    bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    scene.world = world
    return world


def ensure_node_tree(material):
    """The material's node tree (4.5 has none until ``use_nodes``; 5.x deprecates the flag)."""
    if material.node_tree is None:
        material.use_nodes = True
    return material.node_tree


def new_material(name: str, clear: bool = True):
    """A new material with a node tree; ``clear`` removes the default nodes but the output."""
    import bpy

    mat = bpy.data.materials.new(name)
    tree = ensure_node_tree(mat)
    if clear:
        for node in list(tree.nodes):
            if node.type != "OUTPUT_MATERIAL":
                tree.nodes.remove(node)
        if not any(n.type == "OUTPUT_MATERIAL" for n in tree.nodes):
            tree.nodes.new("ShaderNodeOutputMaterial")
    return mat


def material_output(material):
    return next(n for n in material.node_tree.nodes if n.type == "OUTPUT_MATERIAL")


def add_textured_plane(scene, size: float = 2.0, material=None, name: str = "MS Plane"):
    """A ``size`` x ``size`` plane at the origin facing +Z with a UV map covering [0, 1]^2.

    UV (0, 0) is the corner at (-size/2, -size/2); u grows with +X and v with +Y.
    """
    import bpy

    h = size / 2.0
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(-h, -h, 0.0), (h, -h, 0.0), (h, h, 0.0), (-h, h, 0.0)], [], [(0, 1, 2, 3)])
    uv = mesh.uv_layers.new(name="UVMap")
    for loop in mesh.loops:
        x, y, _ = mesh.vertices[loop.vertex_index].co
        uv.data[loop.index].uv = ((x + h) / size, (y + h) / size)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    if material is not None:
        mesh.materials.append(material)
    return obj


def add_orthographic_camera(
    scene,
    ortho_scale: float = 2.0,
    location: Sequence[float] = (0.0, 0.0, 5.0),
    rotation: Sequence[float] = (0.0, 0.0, 0.0),
    name: str = "MS Camera",
):
    """An orthographic camera (default: looking down -Z at the origin, image up = +Y)."""
    import bpy

    cam = bpy.data.cameras.new(name)
    cam.type = "ORTHO"
    cam.ortho_scale = ortho_scale
    cam.clip_start = 0.01
    cam.clip_end = 100.0
    obj = bpy.data.objects.new(name, cam)
    obj.location = location
    obj.rotation_euler = rotation
    scene.collection.objects.link(obj)
    scene.camera = obj
    return obj


def point_along(obj, direction) -> None:
    """Turn ``obj`` (a camera or lamp: it looks down its -Z, +Y up) to look along ``direction``."""
    from mathutils import Vector

    obj.rotation_euler = Vector(tuple(direction)).to_track_quat("-Z", "Y").to_euler()


def view_direction(theta_deg: float, phi_deg: float) -> np.ndarray:
    """Unit vector at polar angle ``theta`` from +Z and azimuth ``phi`` from +X (degrees)."""
    th, ph = math.radians(theta_deg), math.radians(phi_deg)
    return np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])


def look_from(cam, direction, distance: float = 5.0) -> None:
    """Place ``cam`` ``distance`` units from the origin along ``direction``, looking at the origin."""
    d = np.asarray(direction, dtype=np.float64)
    cam.location = tuple(distance * d)
    point_along(cam, -d)


def add_lamp(
    scene,
    kind: str = "POINT",
    location: Sequence[float] = (0.0, 0.0, 0.0),
    power: float = 10.0,
    name: str = "MS Lamp",
    radius: float = 0.0,
    size: float | Sequence[float] | None = None,
    shape: str | None = None,
    target: Sequence[float] | None = None,
    color: Sequence[float] | None = None,
):
    """A lamp object of Blender light type ``kind`` (POINT, SUN, SPOT, AREA) at ``location``.

    ``radius``: the point/spot lamp's radius, or the sun's angular diameter (radians; 0 = a hard sun).
    ``size``, ``shape``: an area lamp's size (one number, or x and y) and shape. ``target``: a point the
    lamp faces (its -Z turned toward it). ``power``: Blender's power (W), or a sun's strength.
    """
    import bpy
    from mathutils import Vector

    light = bpy.data.lights.new(name, kind)
    light.energy = power
    if color is not None:
        light.color = tuple(color)
    if kind == "SUN":
        light.angle = radius
    elif kind == "AREA":
        if shape is not None:
            light.shape = shape
        if isinstance(size, Sequence):
            light.size, light.size_y = size
        elif size is not None:
            light.size = size
    else:
        light.shadow_soft_size = radius
    obj = bpy.data.objects.new(name, light)
    obj.location = tuple(location)
    if target is not None:
        point_along(obj, Vector(tuple(target)) - Vector(tuple(location)))
    scene.collection.objects.link(obj)
    return obj


def denoise_for_display(scene) -> None:
    """Cycles' OpenImageDenoise and its standard 1.5 px pixel filter: for pictures people look at (the
    showcase). Tests and references stay exact and noise-honest with :func:`configure_cycles` alone."""
    cyc = scene.cycles
    cyc.use_denoising = True
    cyc.denoiser = "OPENIMAGEDENOISE"
    cyc.filter_width = 1.5
