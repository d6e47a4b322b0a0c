"""The standard preview stage: floor, camera and studio lamps shared by the library scenes."""

from __future__ import annotations

import math

import bpy
from mathutils import Vector

from ..render import add_lamp, ensure_node_tree, point_along


def add_studio_stage(scene, target=(0.0, 0.0, 0.7), distance: float = 4.2, floor: bool = True):
    """Perspective camera, a key area lamp, a fill and a rim lamp, and a matte floor."""
    if floor:
        bpy.ops.mesh.primitive_plane_add(size=20.0, location=(0.0, 0.0, 0.0))
        plane = bpy.context.active_object
        plane.name = "MS Floor"
        mat = bpy.data.materials.get("MS Floor") or bpy.data.materials.new("MS Floor")
        bsdf = next(n for n in ensure_node_tree(mat).nodes if n.type == "BSDF_PRINCIPLED")
        bsdf.inputs["Base Color"].default_value = (0.18, 0.18, 0.19, 1.0)
        bsdf.inputs["Roughness"].default_value = 0.8
        plane.data.materials.append(mat)

    cam_data = bpy.data.cameras.new("MS Stage Camera")
    cam_data.lens = 55.0
    cam = bpy.data.objects.new("MS Stage Camera", cam_data)
    elevation = math.radians(18.0)
    cam.location = (0.0, -distance * math.cos(elevation), target[2] + distance * math.sin(elevation))
    point_along(cam, Vector(target) - cam.location)
    scene.collection.objects.link(cam)
    scene.camera = cam

    lamps = [
        ("MS Key", (3.0, -3.0, 4.0), 250.0, 2.0),
        ("MS Fill", (-4.0, -2.0, 2.0), 60.0, 3.0),
        ("MS Rim", (0.5, 4.0, 3.0), 120.0, 1.5),
    ]
    for name, location, power, size in lamps:
        add_lamp(scene, "AREA", location, power, name, size=size, target=target)
    return cam
