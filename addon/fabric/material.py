"""The "SGGX Fabric" node group and materials built on it (thesis eq. 3.9 in Cycles).

Inside the group an OSL script node (``cycles_osl/ms_sggx_fabric.osl``) computes the exact lamp
contribution (emission) and the closure approximation for world/indirect light; a Tangent node
gives the UV frame. Materials made here add an EEVEE/viewport output (Principled with sheen) so the
fabric never shows pink or black outside Cycles + OSL.
"""

from __future__ import annotations

import os

import bpy

from ...render.osl import load_osl_script
from ..lamp_sync import scene_shader_lamps, write_lamp_inputs

GROUP_NAME = "SGGX Fabric"
SCRIPT_NODE = "SGGX Exact"
MARKER = "material_structures_fabric"  # custom property on groups/materials made here

# (socket name, socket type, default, min, max); the OSL input of the same name takes it.
GROUP_INPUTS = [
    ("Kd", "NodeSocketColor", (0.05, 0.02, 0.02, 1.0), None, None),
    ("Ks", "NodeSocketColor", (0.6, 0.2, 0.2, 1.0), None, None),
    ("SigmaX", "NodeSocketFloat", 0.5, 1e-3, 10.0),
    ("SigmaY", "NodeSocketFloat", 0.5, 1e-3, 10.0),
    # a vector, not a colour: colour socket values are clamped to >= 0, quaternions are signed
    ("QuatWXY", "NodeSocketVector", (1.0, 0.0, 0.0), -1.0, 1.0),
    ("QuatZ", "NodeSocketFloat", 0.0, -1.0, 1.0),
    ("Tint", "NodeSocketColor", (1.0, 1.0, 1.0, 1.0), None, None),
    ("SigmaScale", "NodeSocketFloat", 1.0, 0.05, 20.0),
    ("Anisotropy", "NodeSocketFloat", 0.0, 0.0, 0.95),
    ("FastPreview", "NodeSocketInt", 0, 0, 1),
]
SHADER_INPUTS = [name for name, *_ in GROUP_INPUTS] + ["Tangent"]


def _load_script(tree, scene):
    return load_osl_script(tree, "ms_sggx_fabric", scene, inputs=SHADER_INPUTS + ["Lamp1Type"], outputs=["Exact"],
                           name=SCRIPT_NODE)


def ensure_fabric_group(scene=None) -> bpy.types.ShaderNodeTree:
    """The shared "SGGX Fabric" node group (created once per file)."""
    scene = scene or bpy.context.scene
    group = bpy.data.node_groups.get(GROUP_NAME)
    if group is not None and group.get(MARKER):
        return group
    group = bpy.data.node_groups.new(GROUP_NAME, "ShaderNodeTree")
    group[MARKER] = 1
    for name, socket_type, default, lo, hi in GROUP_INPUTS:
        sock = group.interface.new_socket(name, in_out="INPUT", socket_type=socket_type)
        sock.default_value = default
        if lo is not None:
            sock.min_value, sock.max_value = lo, hi
    group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader")
    nodes, links = group.nodes, group.links
    gin = nodes.new("NodeGroupInput")
    gout = nodes.new("NodeGroupOutput")
    script = _load_script(group, scene)
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    add = nodes.new("ShaderNodeAddShader")
    for name, *_ in GROUP_INPUTS:
        links.new(gin.outputs[name], script.inputs[name])
    links.new(tangent.outputs["Tangent"], script.inputs["Tangent"])
    links.new(script.outputs["BSDF"], add.inputs[0])
    links.new(script.outputs["Exact"], add.inputs[1])
    links.new(add.outputs[0], gout.inputs["Shader"])
    gin.location, script.location, tangent.location = (-500, 0), (-150, 0), (-500, -350)
    add.location, gout.location = (150, 0), (350, 0)
    return group


def load_map_image(path: str, name: str | None = None):
    """Load a float EXR parameter map as a Non-Color, channel-packed image (values untouched)."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"parameter map not found: {path}")
    image = bpy.data.images.load(path, check_existing=False)
    if name:
        image.name = name
    image.colorspace_settings.name = "Non-Color"
    image.alpha_mode = "CHANNEL_PACKED"
    return image


def create_fabric_material(
    name: str = "SGGX Fabric",
    kd=(0.05, 0.02, 0.02),
    ks=(0.6, 0.2, 0.2),
    sigma=(0.5, 0.5),
    quat=(1.0, 0.0, 0.0, 0.0),
    maps: dict | None = None,
    scene=None,
) -> bpy.types.Material:
    """A material on the SGGX Fabric group, from constants or from images.

    ``maps`` may hold Blender images under ``"kd"``, ``"ks"``, ``"sigma"`` (R = sigma_x,
    G = sigma_y) and ``"basis"`` (RGBA = quaternion w, x, y, z); each is read with closest-texel
    sampling at the UV map and overrides the constant.
    """
    scene = scene or bpy.context.scene
    group = ensure_fabric_group(scene)
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # 4.5
        mat.use_nodes = True
    mat[MARKER] = 1
    tree = mat.node_tree
    for node in list(tree.nodes):
        tree.nodes.remove(node)
    gnode = tree.nodes.new("ShaderNodeGroup")
    gnode.node_tree = group
    gnode.name = gnode.label = GROUP_NAME
    gnode.inputs["Kd"].default_value = (*kd[:3], 1.0)
    gnode.inputs["Ks"].default_value = (*ks[:3], 1.0)
    gnode.inputs["SigmaX"].default_value, gnode.inputs["SigmaY"].default_value = sigma[:2]
    gnode.inputs["QuatWXY"].default_value = tuple(quat[:3])
    gnode.inputs["QuatZ"].default_value = quat[3]
    out_cycles = tree.nodes.new("ShaderNodeOutputMaterial")
    out_cycles.target = "CYCLES"
    tree.links.new(gnode.outputs["Shader"], out_cycles.inputs["Surface"])
    out_cycles.location = (400, 100)

    # EEVEE / viewport fallback: principled with sheen, coloured by the constants.
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    base = [min(1.0, d + 0.5 * s) for d, s in zip(kd[:3], ks[:3], strict=True)]
    bsdf.inputs["Base Color"].default_value = (*base, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.9
    for key in ("Sheen Weight", "Sheen"):
        if key in bsdf.inputs:
            bsdf.inputs[key].default_value = 1.0
            break
    if "Sheen Tint" in bsdf.inputs and len(bsdf.inputs["Sheen Tint"].default_value) == 4:
        bsdf.inputs["Sheen Tint"].default_value = (*ks[:3], 1.0)
    out_eevee = tree.nodes.new("ShaderNodeOutputMaterial")
    out_eevee.target = "EEVEE"
    tree.links.new(bsdf.outputs[0], out_eevee.inputs["Surface"])
    bsdf.location, out_eevee.location = (0, -400), (400, -400)
    out_cycles.is_active_output = True

    if maps:
        _link_maps(tree, gnode, maps)
    mat.cycles.emission_sampling = "NONE"
    return mat


def _link_maps(tree, gnode, maps: dict) -> None:
    uv = tree.nodes.new("ShaderNodeUVMap")
    uv.location = (-900, 0)
    y = 300
    for key, image in maps.items():
        if image is None:
            continue
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.name = tex.label = f"map_{key}"
        tex.image = image
        tex.interpolation = "Closest"
        tex.extension = "EXTEND"
        tex.location = (-650, y)
        y -= 280
        tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
        if key in ("kd", "ks"):
            tree.links.new(tex.outputs["Color"], gnode.inputs["Kd" if key == "kd" else "Ks"])
        elif key == "sigma":
            sep = tree.nodes.new("ShaderNodeSeparateColor")
            sep.location = (-350, y + 280)
            tree.links.new(tex.outputs["Color"], sep.inputs["Color"])
            tree.links.new(sep.outputs[0], gnode.inputs["SigmaX"])
            tree.links.new(sep.outputs[1], gnode.inputs["SigmaY"])
        elif key == "basis":
            tree.links.new(tex.outputs["Color"], gnode.inputs["QuatWXY"])
            tree.links.new(tex.outputs["Alpha"], gnode.inputs["QuatZ"])
        else:
            raise ValueError(f"unknown fabric map {key!r}")


def fabric_script_nodes():
    """Every SGGX script node in the file (inside the group, or placed directly in materials)."""
    trees = [g for g in bpy.data.node_groups if g.get(MARKER)]
    trees += [m.node_tree for m in bpy.data.materials if m.node_tree is not None and m.get(MARKER)]
    for tree in trees:
        for node in tree.nodes:
            if node.type == "SCRIPT" and "Lamp1Type" in node.inputs:
                yield node


def _exact_path_on(mat) -> bool:
    """Whether a fabric material evaluates lamps itself (FastPreview off on its group node)."""
    for node in mat.node_tree.nodes:
        if node.type == "GROUP" and node.node_tree is not None and node.node_tree.get(MARKER):
            sock = node.inputs["FastPreview"]
            return sock.is_linked or not sock.default_value
    return True


def fabric_objects(scene, exact_only: bool = False):
    """Meshes with a fabric material (``exact_only``: one whose exact lamp path is on)."""
    out = []
    for obj in scene.objects:
        if obj.type != "MESH":
            continue
        mats = [s.material for s in obj.material_slots if s.material is not None and s.material.get(MARKER)]
        if mats and (not exact_only or any(_exact_path_on(m) for m in mats)):
            out.append(obj)
    return out


def sync_fabric_lamps(scene, update_matrices: bool = True) -> int:
    """Copy the scene's lamps into every fabric shader and light-link them off fabric objects.

    ``update_matrices`` evaluates the view layer first so freshly moved lamps have current world
    matrices (pass False from depsgraph handlers, where they are current already).
    Returns the number of lamps the exact path evaluates.
    """
    if update_matrices:
        for layer in scene.view_layers:
            layer.update()
    pairs = scene_shader_lamps(scene)
    lamps = [lamp for _, lamp in pairs]
    for node in fabric_script_nodes():
        write_lamp_inputs(node, lamps)
    # Exact path on: the lamp is light-linked off (the shader has it). Fast preview: closures see it.
    receivers = fabric_objects(scene, exact_only=True)
    previews = [o for o in fabric_objects(scene) if o not in receivers]
    for lamp_obj, _ in pairs:
        _exclude_receivers(lamp_obj, receivers)
        coll = lamp_obj.light_linking.receiver_collection
        for obj in previews:
            if coll is not None and obj.name in coll.objects:
                coll.objects.unlink(obj)
    return len(lamps)


def _exclude_receivers(lamp_obj, receivers) -> None:
    """Light-link ``lamp_obj`` off ``receivers`` (their closures must not see it: the shader has it)."""
    link = lamp_obj.light_linking
    coll = link.receiver_collection
    if coll is None:
        coll = bpy.data.collections.new(f"MS Exact Lamp {lamp_obj.name}")
        link.receiver_collection = coll
    for obj in receivers:
        if obj.name not in coll.objects:
            coll.objects.link(obj)
    names = {obj.name for obj in receivers}
    # collection_objects runs parallel to objects (its entries do not name their object).
    for obj, entry in zip(coll.objects, coll.collection_objects, strict=True):
        if obj.name in names and entry.light_linking.link_state != "EXCLUDE":
            entry.light_linking.link_state = "EXCLUDE"
