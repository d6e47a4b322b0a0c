"""The "SGGX Fabric" node group and materials built on it (thesis eq. 3.9 in Cycles).

Inside the group an OSL script node (``cycles_osl/ms_sggx_fabric.osl``) computes the exact lamp
contribution (emission) and the closure approximation for world/indirect light; a Tangent node
gives the UV frame. The group's second output, "Viewport", is an EEVEE / Material Preview look built
from the same inputs (so from the same maps, and brushing shows while painting): a Principled BSDF
with base colour Tint (k_d + k_s / 2), sheen tinted k_s, roughness s / (1 + s) for the mean sigma s,
anisotropy |sigma_x - sigma_y| / (sigma_x + sigma_y) along the basis' x axis, and the shading normal
halfway between the surface normal and the fibre axis (combed pile leans the highlight).

Light links: the exact path evaluates up to 4 lamps itself, so those lamps are light-linked off the
fabric objects, in Cycles with OSL only (elsewhere nothing evaluates them: EEVEE, or Cycles without
OSL, see every lamp). The add-on owns these links (collections it made, or the entries it added to a
user's collection, recorded on it) and removes them as soon as an object no longer needs them.
"""

from __future__ import annotations

import os

import bpy
import numpy as np

from ...core.fabric.closure_fit import CLOSURE_FILES, FIT_KEY_BUDGET, SHAPE_FILES, fit_closure_maps, load_closure_maps
from ...render import load_osl_script
from ..common import (
    NodeMath,
    add_eevee_fallback,
    add_group_input,
    add_osl_switch,
    array_to_image,
    describe_group_sockets,
    group_material,
    group_node,
    local_node_group,
    osl_switch,
    relink_osl_switch,
    wire_lamp_shader_group,
)
from ..lamp_sync import scene_shader_lamps, write_lamp_inputs
from .maps import CLOSURE_KEYS, closure_maps_to_images, load_fit_folder, maps_to_images
from .native_closures import build_native_closures
from .world_light import world_light_inputs, write_world_inputs

GROUP_NAME = "SGGX Fabric"
VIEWPORT_OUTPUT = "Viewport"
SCRIPT_NODE = "SGGX Exact"
MARKER = "material_structures_fabric"  # custom property on groups/materials made here
CLOSURE_NODE_PREFIX = "fit_"  # image nodes of the fitted closure maps (map_* are the parameter maps)

# (socket name, socket type, default, min, max, tooltip); the OSL input of the same name takes it. On/off inputs
# are booleans (no range); Cycles hands a boolean to the shader's int input as 0/1 (measured: renders identical to
# the integer sockets of older files, which keep their type).
_FIT = "Fitted closure mix (linked from the material's closure images)"
GROUP_INPUTS = [
    ("Kd", "NodeSocketColor", (0.05, 0.02, 0.02, 1.0), None, None,
     "Diffuse colour k_d of the pile (linear RGB albedo, 0-1; from the kd map when linked)"),
    ("Ks", "NodeSocketColor", (0.6, 0.2, 0.2, 1.0), None, None,
     "Specular (sheen) colour k_s of the fibres (linear RGB albedo, 0-1; from the ks map when linked)"),
    ("SigmaX", "NodeSocketFloat", 0.5, 1e-3, 10.0,
     "Fibre roughness sigma_x: spread of the fibre directions across the first fibre axis (SGGX, no unit; "
     "from the sigma map when linked)"),
    ("SigmaY", "NodeSocketFloat", 0.5, 1e-3, 10.0,
     "Fibre roughness sigma_y: spread of the fibre directions across the second fibre axis (SGGX, no unit; "
     "from the sigma map when linked)"),
    # a vector, not a colour: colour socket values are clamped to >= 0, quaternions are signed
    ("QuatWXY", "NodeSocketVector", (1.0, 0.0, 0.0), -1.0, 1.0,
     "Fibre orientation: w, x, y of the unit quaternion turning the UV frame into the fibre frame (no unit; "
     "from the basis map when linked)"),
    ("QuatZ", "NodeSocketFloat", 0.0, -1.0, 1.0,
     "Fibre orientation: z of the unit quaternion turning the UV frame into the fibre frame (no unit; "
     "from the basis map when linked)"),
    ("Tint", "NodeSocketColor", (1.0, 1.0, 1.0, 1.0), None, None,
     "Multiplies the diffuse and specular colours (linear RGB, 1 = as fitted)"),
    ("SigmaScale", "NodeSocketFloat", 1.0, 0.05, 20.0,
     "Roughness Scale: multiplies both fibre roughnesses (1 = as fitted; below 1 a sharper highlight)"),
    ("Anisotropy", "NodeSocketFloat", 0.0, 0.0, 0.95,
     "Shrinks the smaller fibre roughness by this fraction (0 = as fitted; 0-0.95)"),
    ("FastPreview", "NodeSocketBool", False, None, None,
     "Render with Cycles' closures only (quick, approximate) instead of the exact fabric light under the lights"),
]
# Fitted closures (issue 38): linked from the closure images, switched on by UseFittedClosures.
FIT_INPUTS = [
    ("UseFittedClosures", "NodeSocketBool", False, None, None,
     "Bounced and world light use the closure mix fitted per texel (on once its images are linked)"),
    ("FitDiffuse", "NodeSocketColor", (0.0, 0.0, 0.0, 1.0), None, None, f"{_FIT}: diffuse weight coefficients"),
    ("FitDiffuseA", "NodeSocketFloat", 0.0, 0.0, 1e4, f"{_FIT}: diffuse weight, 4th coefficient (no unit)"),
    ("FitSheen", "NodeSocketColor", (0.0, 0.0, 0.0, 1.0), None, None, f"{_FIT}: sheen weight coefficients"),
    ("FitSheenA", "NodeSocketFloat", 0.0, 0.0, 1e4, f"{_FIT}: sheen weight, 4th coefficient (no unit)"),
    ("FitVelvet", "NodeSocketColor", (0.0, 0.0, 0.0, 1.0), None, None, f"{_FIT}: velvet weight coefficients"),
    ("FitVelvetA", "NodeSocketFloat", 0.0, 0.0, 1e4, f"{_FIT}: velvet weight, 4th coefficient (no unit)"),
    ("FitGGX", "NodeSocketColor", (0.0, 0.0, 0.0, 1.0), None, None, f"{_FIT}: GGX weight coefficients"),
    ("FitGGXA", "NodeSocketFloat", 0.0, 0.0, 1e4, f"{_FIT}: GGX weight, 4th coefficient (no unit)"),
    ("FitShape", "NodeSocketColor", (1.0, 0.4, 0.0, 1.0), None, None,
     f"{_FIT}: sheen roughness, velvet sigma, velvet normal tilt toward the fibres (R, G, B; no unit)"),
    ("FitShapeA", "NodeSocketFloat", 0.0, 0.0, 1.0, f"{_FIT}: GGX normal tilt toward the fibres (0-1)"),
    ("FitGGXScale", "NodeSocketFloat", 1.0, 0.0, 10.0, f"{_FIT}: GGX roughness multiplier c_g (no unit)"),
]
# Exact world light (world_light.py): on by default; off gives the world to the fitted closures.
WORLD_INPUTS = [("ExactWorld", "NodeSocketBool", True, None, None,
                 "Exact World Light: light from the world's environment is computed exactly by the fabric shader "
                 "(off: the fitted closures see it, and bounced light too)")]
# The second velvet of the fitted mix (weight 0, i.e. the mix of older files, until its images are linked).
VELVET2_INPUTS = [
    ("FitVelvet2", "NodeSocketColor", (0.0, 0.0, 0.0, 1.0), None, None, f"{_FIT}: second velvet weight coefficients"),
    ("FitVelvet2A", "NodeSocketFloat", 0.0, 0.0, 1e4, f"{_FIT}: second velvet weight, 4th coefficient (no unit)"),
    ("FitShape2", "NodeSocketColor", (0.4, 0.0, 0.0, 1.0), None, None,
     f"{_FIT}: second velvet sigma and normal tilt toward the fibres (R, G; no unit)"),
]
FIT_INPUTS = FIT_INPUTS + WORLD_INPUTS + VELVET2_INPUTS  # added to groups from older files like the fit inputs
GROUP_INPUTS = GROUP_INPUTS + FIT_INPUTS
SHADER_INPUTS = [name for name, *_ in GROUP_INPUTS] + ["Tangent"]
SHADER_OUTPUT_DESCRIPTION = "The pile fabric for Cycles (exact with Open Shading Language, its closures without)"
VIEWPORT_OUTPUT_DESCRIPTION = "An approximate look of the fabric for EEVEE and Material Preview"
# closure image key -> (group input of its Color output, group input of its Alpha output)
CLOSURE_SOCKETS = {
    "diffuse": ("FitDiffuse", "FitDiffuseA"),
    "sheen": ("FitSheen", "FitSheenA"),
    "velvet": ("FitVelvet", "FitVelvetA"),
    "ggx": ("FitGGX", "FitGGXA"),
    "shape": ("FitShape", "FitShapeA"),
    "ggx_scale": ("FitGGXScale", None),
    "velvet2": ("FitVelvet2", "FitVelvet2A"),
    "shape2": ("FitShape2", None),
}
ONE_CHANNEL = {"ggx_scale"}  # closure images read through their R channel into a float input


def _load_script(tree, scene):
    return load_osl_script(tree, "ms_sggx_fabric", scene, inputs=SHADER_INPUTS + ["Lamp1Type"], outputs=["Exact"],
                           name=SCRIPT_NODE)


def ensure_fabric_group(scene=None) -> bpy.types.ShaderNodeTree:
    """The shared "SGGX Fabric" node group (created once per file)."""
    scene = scene or bpy.context.scene
    group = local_node_group(GROUP_NAME, MARKER)
    if group is not None:
        ensure_viewport_look(group)
        ensure_fit_inputs(group, scene)
        ensure_closures_without_osl(group)
        return group
    group = bpy.data.node_groups.new(GROUP_NAME, "ShaderNodeTree")
    group[MARKER] = 1
    for spec in GROUP_INPUTS:
        add_group_input(group, *spec)
    group.interface.new_socket("Shader", in_out="OUTPUT", socket_type="NodeSocketShader",
                               description=SHADER_OUTPUT_DESCRIPTION)
    group.interface.new_socket(VIEWPORT_OUTPUT, in_out="OUTPUT", socket_type="NodeSocketShader",
                               description=VIEWPORT_OUTPUT_DESCRIPTION)
    gin = group.nodes.new("NodeGroupInput")
    gout = group.nodes.new("NodeGroupOutput")
    script = _load_script(group, scene)
    tangent, add = wire_lamp_shader_group(group, gin, script, gout, [name for name, *_ in GROUP_INPUTS], "Exact")
    gin.location, script.location, tangent.location = (-500, 0), (-150, 0), (-500, -350)
    add.location, gout.location = (150, 0), (350, 0)
    _build_viewport_look(group)
    add_osl_switch(group, script, build_native_closures(group, gin))
    return group


def ensure_closures_without_osl(group) -> None:
    """Give a group from an older file the closure path that renders without OSL (``native_closures``), and
    link its switch to the script once the script has the ``OSLActive`` output; its sockets get their tooltips."""
    describe_group_sockets(group, GROUP_INPUTS, {"Shader": SHADER_OUTPUT_DESCRIPTION,
                                                 VIEWPORT_OUTPUT: VIEWPORT_OUTPUT_DESCRIPTION})
    script = next((n for n in group.nodes if n.type == "SCRIPT" and "Lamp1Type" in n.inputs), None)
    if script is None:
        return
    if osl_switch(group) is None:
        ensure_fit_inputs(group)
        gin = next(n for n in group.nodes if n.type == "GROUP_INPUT")
        add_osl_switch(group, script, build_native_closures(group, gin))
    else:
        relink_osl_switch(group, script)


def ensure_fit_inputs(group, scene=None) -> None:
    """Give a group from an older file the fitted-closure and world inputs (closures off until their maps
    are linked; exact world light on)."""
    have = {item.name for item in group.interface.items_tree if getattr(item, "in_out", "") == "INPUT"}
    missing = [spec for spec in FIT_INPUTS if spec[0] not in have]
    if not missing:
        return
    script = next((n for n in group.nodes if n.type == "SCRIPT" and "Lamp1Type" in n.inputs), None)
    if script is not None and any(spec[0] not in script.inputs for spec in missing):
        from ...render.osl import compile_script_node, shader_text

        if script.mode == "INTERNAL" and script.script is not None:
            shader_text("ms_sggx_fabric.osl")  # refresh the embedded text to the shipped shader
        compile_script_node(script, scene)
    gin = next(n for n in group.nodes if n.type == "GROUP_INPUT")
    for spec in missing:
        add_group_input(group, *spec)
        if script is not None and spec[0] in script.inputs:
            group.links.new(gin.outputs[spec[0]], script.inputs[spec[0]])


def ensure_viewport_look(group) -> None:
    """Give a group from an older file its "Viewport" output (EEVEE look from the same inputs)."""
    if VIEWPORT_OUTPUT not in group.interface.items_tree:
        group.interface.new_socket(VIEWPORT_OUTPUT, in_out="OUTPUT", socket_type="NodeSocketShader",
                                   description=VIEWPORT_OUTPUT_DESCRIPTION)
        _build_viewport_look(group)


def _build_viewport_look(group) -> None:
    """The "Viewport" output: a Principled BSDF driven by the group's inputs (module docstring)."""
    nodes, links = group.nodes, group.links
    gin = next(n for n in nodes if n.type == "GROUP_INPUT")
    gout = next(n for n in nodes if n.type == "GROUP_OUTPUT")
    m = NodeMath(group, -300, -700)
    # Quaternion (w, x, y, z) of the fibre basis in the UV frame (x = UV tangent, z = normal).
    q = nodes.new("ShaderNodeSeparateXYZ")
    q.location = (-500, -700)
    links.new(gin.outputs["QuatWXY"], q.inputs[0])
    w, x, y, z = q.outputs[0], q.outputs[1], q.outputs[2], gin.outputs["QuatZ"]
    xx, yy, zz = m.f("MULTIPLY", x, x), m.f("MULTIPLY", y, y), m.f("MULTIPLY", z, z)
    ax_x = m.f("SUBTRACT", 1.0, m.f("MULTIPLY", 2.0, m.f("ADD", yy, zz)))  # basis x axis, tangent-plane part
    ax_y = m.f("MULTIPLY", 2.0, m.f("ADD", m.f("MULTIPLY", x, y), m.f("MULTIPLY", w, z)))
    fz_x = m.f("MULTIPLY", 2.0, m.f("ADD", m.f("MULTIPLY", x, z), m.f("MULTIPLY", w, y)))  # fibre (z) axis
    fz_y = m.f("MULTIPLY", 2.0, m.f("SUBTRACT", m.f("MULTIPLY", y, z), m.f("MULTIPLY", w, x)))
    fz_z = m.f("SUBTRACT", 1.0, m.f("MULTIPLY", 2.0, m.f("ADD", xx, yy)))
    # World frame: UV tangent T, normal N, bitangent N x T.
    tangent = nodes.new("ShaderNodeTangent")
    tangent.direction_type = "UV_MAP"
    tangent.location = (-500, -1000)
    geo = nodes.new("ShaderNodeNewGeometry")
    geo.location = (-500, -1200)
    t, n = tangent.outputs["Tangent"], geo.outputs["Normal"]
    b = m.v("CROSS_PRODUCT", n, t)
    axis = m.v("NORMALIZE", m.v("ADD", m.scale(t, ax_x), m.scale(b, ax_y)))
    fibre = m.v("ADD", m.v("ADD", m.scale(t, fz_x), m.scale(b, fz_y)), m.scale(n, fz_z))
    normal = m.v("NORMALIZE", m.v("ADD", n, fibre))
    # Colour, roughness, anisotropy.
    half_ks = m.scale(gin.outputs["Ks"], 0.5)
    base = m.v("MULTIPLY", gin.outputs["Tint"], m.v("ADD", gin.outputs["Kd"], half_ks))
    sheen = m.v("MULTIPLY", gin.outputs["Tint"], gin.outputs["Ks"])
    sx, sy = gin.outputs["SigmaX"], gin.outputs["SigmaY"]
    ssum = m.f("ADD", sx, sy)
    s_mean = m.f("MULTIPLY", m.f("MULTIPLY", ssum, 0.5), gin.outputs["SigmaScale"])
    rough = m.f("DIVIDE", s_mean, m.f("ADD", s_mean, 1.0))
    aniso = m.f("DIVIDE", m.f("ABSOLUTE", m.f("SUBTRACT", sx, sy)), m.f("MAXIMUM", ssum, 1e-6))
    bsdf = nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.location = (100, -700)
    ins = bsdf.inputs
    links.new(base, ins["Base Color"])
    links.new(rough, ins["Roughness"])
    links.new(normal, ins["Normal"])
    for key, sock in (("Anisotropic", aniso), ("Tangent", axis), ("Sheen Tint", sheen)):
        if key in ins:
            links.new(sock, ins[key])
    for key in ("Sheen Weight", "Sheen"):
        if key in ins:
            ins[key].default_value = 1.0
            break
    links.new(bsdf.outputs[0], gout.inputs[VIEWPORT_OUTPUT])


def create_fabric_material(
    name: str = "SGGX Fabric",
    kd=(0.05, 0.02, 0.02),
    ks=(0.6, 0.2, 0.2),
    sigma=(0.5, 0.5),
    quat=(1.0, 0.0, 0.0, 0.0),
    maps: dict | None = None,
    scene=None,
    closures: dict | None = None,
) -> bpy.types.Material:
    """A material on the SGGX Fabric group, from constants or from images.

    ``maps`` may hold Blender images under ``"kd"``, ``"ks"``, ``"sigma"`` (R = sigma_x,
    G = sigma_y) and ``"basis"`` (RGBA = quaternion w, x, y, z); each is read with closest-texel
    sampling at the UV map and overrides the constant. ``closures``: the fitted closure images
    (``maps.closure_maps_to_images``, keys ``maps.CLOSURE_KEYS``) that world and indirect light see.
    """
    scene = scene or bpy.context.scene
    group = ensure_fabric_group(scene)
    mat, gnode, out_cycles = group_material(name, group, MARKER, label=GROUP_NAME)
    gnode.inputs["Kd"].default_value = (*kd[:3], 1.0)
    gnode.inputs["Ks"].default_value = (*ks[:3], 1.0)
    gnode.inputs["SigmaX"].default_value, gnode.inputs["SigmaY"].default_value = sigma[:2]
    gnode.inputs["QuatWXY"].default_value = tuple(quat[:3])
    gnode.inputs["QuatZ"].default_value = quat[3]
    # EEVEE / Material Preview: the group's viewport look, from the same inputs and maps.
    add_eevee_fallback(mat, out_cycles, gnode.outputs[VIEWPORT_OUTPUT], location=(400, -200))
    if maps:
        _link_maps(mat.node_tree, gnode, maps)
    if closures:
        link_closure_images(mat, closures)
    return mat


def link_closure_images(mat, closures: dict) -> None:
    """Read the fitted closure images (closest texel at the UV map) into the group and switch the shader
    to them; replaces images linked before."""
    tree = mat.node_tree
    gnode = fabric_group_node(mat)
    old = material_closure_images(mat)
    for node in tree.nodes:
        if node.type == "TEX_IMAGE" and node.name.startswith(CLOSURE_NODE_PREFIX):
            node.image = closures[node.name[len(CLOSURE_NODE_PREFIX):]]
    missing = [key for key in CLOSURE_KEYS if key not in old]
    if missing:
        y = -900 - 60 * (len(CLOSURE_KEYS) - len(missing))
        _add_closure_nodes(mat, {key: closures[key] for key in missing}, y=y)
    gnode.inputs["UseFittedClosures"].default_value = 1


def complete_closure_images(mat) -> dict:
    """The closure images of ``mat``, completed for a material from a file made before the second velvet:
    its (missing) images are added at weight 0, which is the mix its closures were fitted as. Returns
    the images by key; empty (and nothing added) for a material without fitted closures."""
    have = material_closure_images(mat)
    missing = [key for key in CLOSURE_KEYS if key not in have]
    if not have or not missing or set(missing) - {"velvet2", "shape2"}:
        return have
    w, h = have["shape"].size
    name = have["shape"].name.rsplit(" fit ", 1)[0]
    arrays = {"velvet2": np.zeros((h, w, 4), np.float32),
              "shape2": np.broadcast_to(np.array([0.4, 0.0], np.float32), (h, w, 2))}
    added = {key: array_to_image(arrays[key], f"{name} fit {key}", replace=False) for key in missing}
    _add_closure_nodes(mat, added, y=-900 - 60 * len(have))
    return material_closure_images(mat)


def _add_closure_nodes(mat, closures: dict, y: int) -> None:
    tree = mat.node_tree
    gnode = fabric_group_node(mat)
    if any(CLOSURE_SOCKETS[key][0] not in gnode.inputs for key in closures):
        ensure_fit_inputs(gnode.node_tree)  # a group from a file made before these inputs
    uv = next((n for n in tree.nodes if n.type == "UVMAP"), None) or tree.nodes.new("ShaderNodeUVMap")
    for key in CLOSURE_KEYS:
        if key not in closures:
            continue
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.name = tex.label = CLOSURE_NODE_PREFIX + key
        tex.image = closures[key]
        tex.interpolation = "Closest"
        tex.extension = "EXTEND"
        tex.location = (-650, y)
        tex.hide = True
        y -= 60
        tree.links.new(uv.outputs["UV"], tex.inputs["Vector"])
        color_in, alpha_in = CLOSURE_SOCKETS[key]
        if key in ONE_CHANNEL:
            sep = tree.nodes.new("ShaderNodeSeparateColor")
            sep.location = (-400, y + 60)
            sep.hide = True
            tree.links.new(tex.outputs["Color"], sep.inputs["Color"])
            tree.links.new(sep.outputs[0], gnode.inputs[color_in])
        else:
            tree.links.new(tex.outputs["Color"], gnode.inputs[color_in])
            if alpha_in is not None:
                tree.links.new(tex.outputs["Alpha"], gnode.inputs[alpha_in])


def material_closure_images(mat) -> dict:
    """The fitted closure images a fabric material reads, by key (empty when it has none)."""
    out = {}
    for node in mat.node_tree.nodes:
        if node.type == "TEX_IMAGE" and node.name.startswith(CLOSURE_NODE_PREFIX) and node.image is not None:
            out[node.name[len(CLOSURE_NODE_PREFIX):]] = node.image
    return out


def fit_closure_images(maps, prefix: str, progress=None, cache: dict | None = None, info: dict | None = None) -> dict:
    """Fit the closure mix to core ``maps`` (``closure_fit.fit_closure_maps``) and make its images.

    Each distinct fibre geometry is fitted once: a 256 x 256 preset takes well under a second. Maps
    with more than ``FIT_KEY_BUDGET`` distinct geometries (a measured fit varies per texel) take every
    texel's closures from the precomputed table (``info["table"]``). ``progress(done, total)`` reports
    the geometries fitted (or texels looked up)."""
    cm = fit_closure_maps(maps.sigma, maps.basis, cache=cache, progress=progress, max_keys=FIT_KEY_BUDGET, info=info)
    return closure_maps_to_images(cm, prefix)


def _folder_closures(params_dir: str, shape):
    """Closure maps saved beside a fit folder's maps (the fitter writes them), if complete and of its size."""
    names = [*CLOSURE_FILES, *SHAPE_FILES]
    if not all(os.path.isfile(os.path.join(params_dir, n)) for n in names):
        return None
    try:
        cm = load_closure_maps(params_dir)
    except (OSError, ValueError, KeyError):
        return None
    return cm if cm.shape.shape[:2] == tuple(shape) else None


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


def import_fit_material(params_dir: str, scene=None, progress=None):
    """Material from a fit folder; images are packed into the .blend. The fitted closure maps come from
    the folder when the fitter wrote them there, else they are fitted now (``progress`` as in
    :func:`fit_closure_images`)."""
    maps = load_fit_folder(params_dir)
    name = os.path.basename(os.path.normpath(params_dir)) or "fit"
    images = maps_to_images(maps, f"SGGX {name}")
    cm = _folder_closures(params_dir, maps.shape)
    closures = (closure_maps_to_images(cm, f"SGGX {name}") if cm is not None
                else fit_closure_images(maps, f"SGGX {name}", progress=progress))
    mat = create_fabric_material(f"Fabric {name}", maps=images, scene=scene, closures=closures)
    mat["material_structures_source"] = params_dir
    return mat


def fabric_group_node(mat):
    """The SGGX Fabric group node of a material (None if it has none)."""
    return group_node(mat, MARKER)


def material_map_images(mat) -> dict:
    """The map images (kd/ks/sigma/basis) a fabric material reads, by key."""
    out = {}
    for node in mat.node_tree.nodes:
        if node.type == "TEX_IMAGE" and node.name.startswith("map_") and node.image is not None:
            out[node.name[4:]] = node.image
    return out


def fabric_material(obj):
    """The active material of a mesh object when it is a fabric material, else None."""
    mat = obj.active_material if obj is not None and obj.type == "MESH" else None
    return mat if mat is not None and mat.get(MARKER) else None


def fabric_script_nodes():
    """Every SGGX script node in the file (inside the group, or placed directly in materials)."""
    trees = [g for g in bpy.data.node_groups if g.get(MARKER)]
    trees += [m.node_tree for m in bpy.data.materials if m.node_tree is not None and m.get(MARKER)]
    for tree in trees:
        for node in tree.nodes:
            if node.type == "SCRIPT" and "Lamp1Type" in node.inputs:
                yield node


def _cycles_output(mat):
    """The material output Cycles renders (the active one of those targeting Cycles or all engines)."""
    outs = [n for n in mat.node_tree.nodes if n.type == "OUTPUT_MATERIAL" and n.target in {"ALL", "CYCLES"}]
    return next((n for n in outs if n.is_active_output), outs[0] if outs else None)


def rendered_fabric_node(mat):
    """The SGGX Fabric group node whose shader reaches the surface Cycles renders for ``mat`` (None when the
    material has none, or the artist disconnected or replaced it, e.g. by a Principled BSDF)."""
    if mat is None or mat.node_tree is None:
        return None
    out = _cycles_output(mat)
    if out is None or not out.inputs["Surface"].is_linked:
        return None
    seen, todo = set(), [out.inputs["Surface"].links[0].from_node]
    while todo:
        node = todo.pop()
        if node.name in seen or node.mute:
            continue
        seen.add(node.name)
        if node.type == "GROUP" and node.node_tree is not None and node.node_tree.get(MARKER):
            return node
        todo += [link.from_node for sock in node.inputs for link in sock.links if not link.is_muted]
    return None


def _exact_path_on(mat) -> bool:
    """Whether a fabric material evaluates lamps itself: its fabric group renders (reaches the Cycles output)
    with FastPreview off."""
    node = rendered_fabric_node(mat)
    if node is None:
        return False
    sock = node.inputs["FastPreview"]
    return sock.is_linked or not sock.default_value


def fabric_objects(scene, exact_only: bool = False):
    """Meshes with a fabric material (``exact_only``: one whose exact lamp path renders: the fabric group
    reaches the material's Cycles output and FastPreview is off)."""
    out = []
    for obj in scene.objects:
        if obj.type != "MESH":
            continue
        mats = [s.material for s in obj.material_slots if s.material is not None and s.material.get(MARKER)]
        if mats and (not exact_only or any(_exact_path_on(m) for m in mats)):
            out.append(obj)
    return out


def exact_path_renders(scene) -> bool:
    """Whether the scene renders the exact lamp path (Cycles with OSL); elsewhere nothing evaluates it."""
    return scene.render.engine == "CYCLES" and bool(scene.cycles.shading_system)


def sync_fabric_lamps(scene, update_matrices: bool = True) -> int:
    """Copy the scene's lamps and its world environment (world_light.py) into every fabric shader;
    light-link the lamps off the objects whose shader evaluates them (Cycles with OSL, exact path on)
    and off no other object.

    ``update_matrices`` evaluates the view layer first so freshly moved lamps have current world
    matrices (pass False from depsgraph handlers, where they are current already).
    Returns the number of lamps the exact path evaluates.
    """
    if update_matrices:
        for layer in scene.view_layers:
            layer.update()
    receivers = fabric_objects(scene, exact_only=True) if exact_path_renders(scene) else []
    # a lamp whose light linking cannot change here (linked from another file) is evaluated by the shader only where
    # it already leaves every receiver out; elsewhere Cycles lights the fabric with it, as without the exact path
    pairs = scene_shader_lamps(scene, keep=lambda obj: not _linking_fixed(obj) or _excludes(obj, receivers))
    lamps = [lamp for _, lamp in pairs]
    nodes = list(fabric_script_nodes())
    for node in nodes:
        write_lamp_inputs(node, lamps)
    if nodes:  # tables only where the exact path renders
        folder, width, height, _status, rotation, strength = world_light_inputs(
            scene, tables=exact_path_renders(scene))
        for node in nodes:
            write_world_inputs(node, folder, width, height, rotation, strength)
    in_shader = {obj.name_full for obj, _ in pairs}
    wants = {obj: (receivers if obj.name_full in in_shader else []) for obj in scene.objects
             if obj.type == "LIGHT" and not _linking_fixed(obj)}
    _unshare_receivers(wants)
    for obj, want in wants.items():
        _link_off(obj, want)
    return len(lamps)


def _unshare_receivers(wants: dict) -> None:
    """Lamps that share one receiver collection (a lamp copied with Shift+D keeps its original's) but need other
    fabric exclusions (one evaluated by the shader, the other not: hidden from renders, past the shader's fourth)
    each get a copy of it, the artist's own links included: else each sync took back what the other lamp needs, and
    a lamp lit the cloth twice, through the shader and through Cycles."""
    sharing: dict = {}
    for obj in wants:
        coll = obj.light_linking.receiver_collection
        if coll is not None and coll.library is None:
            sharing.setdefault(coll.name_full, []).append(obj)
    for objs in sharing.values():
        first = {o.name_full for o in wants[objs[0]]}
        for obj in objs[1:]:
            if {o.name_full for o in wants[obj]} != first:
                coll = obj.light_linking.receiver_collection
                own = coll.copy()
                own.name = f"{coll.name} ({obj.name})"
                obj.light_linking.receiver_collection = own


def _linking_fixed(lamp_obj) -> bool:
    """Whether the lamp's light linking cannot change in this file (the lamp, or its receiver collection, is linked
    from another file: its data is read-only here and a change would not be saved)."""
    coll = lamp_obj.light_linking.receiver_collection
    return lamp_obj.library is not None or (coll is not None and coll.library is not None)


def _excludes(lamp_obj, receivers) -> bool:
    """Whether the lamp's light linking leaves out every object of ``receivers``."""
    coll = lamp_obj.light_linking.receiver_collection
    if coll is None:
        return not receivers
    excluded = _excluded_by(coll)
    return all(obj.name_full in excluded for obj in receivers)


def _excluded_by(coll, fabric_made_only: bool = False) -> set[str]:
    """Full names of the objects a lamp's receiver collection leaves out (``fabric_made_only``: those the fabric left
    out: every one of a collection it made, else the names it noted in the artist's)."""
    made = None if not fabric_made_only or coll.get(LINKS_MADE) else set(coll.get(LINKS_ADDED, []))
    return {obj.name_full for obj, entry in zip(coll.objects, coll.collection_objects, strict=True)
            if entry.light_linking.link_state == "EXCLUDE" and (made is None or obj.name in made)}


def lamps_leaving_fabric_unlit(scene) -> list[tuple[bpy.types.Object, list[bpy.types.Object]]]:
    """Lamps linked from another file whose fabric-made light links leave fabric objects out where nothing here
    lights them instead (no exact path: Cycles without OSL, EEVEE, Fast Preview, or a lamp the shader does not
    evaluate, e.g. beyond the fourth): ``[(lamp, [fabric objects it leaves unlit])]``. Their file made the links for
    its own exact path; they are read-only here, so the panel says so. Exclusions the artist made in that file
    (not marked as the fabric's) are theirs, not reported."""
    if not bpy.data.libraries:  # nothing linked (the panel draws this often)
        return []
    exact = fabric_objects(scene, exact_only=True) if exact_path_renders(scene) else []
    in_shader = {obj.name_full for obj, _ in scene_shader_lamps(
        scene, keep=lambda obj: not _linking_fixed(obj) or _excludes(obj, exact))} if exact else set()
    fabric = fabric_objects(scene)
    out = []
    for lamp in scene.objects:
        if lamp.type != "LIGHT" or lamp.hide_render or not _linking_fixed(lamp):
            continue  # a lamp hidden from renders lights nothing anywhere
        coll = lamp.light_linking.receiver_collection
        if coll is None:
            continue
        excluded = _excluded_by(coll, fabric_made_only=True)
        evaluated = {obj.name_full for obj in exact} if lamp.name_full in in_shader else set()
        unlit = [obj for obj in fabric if obj.name_full in excluded and obj.name_full not in evaluated]
        if unlit:
            out.append((lamp, unlit))
    return out


LINKS_MADE = "material_structures_links"  # on a receiver collection the add-on made for a lamp
LINKS_ADDED = "material_structures_excluded"  # names of the objects the add-on excluded in a user's one


def has_fabric_links() -> bool:
    """Whether any lamp carries light links that the fabric made (they may need cleaning up)."""
    return any(c.get(LINKS_MADE) or c.get(LINKS_ADDED) for c in bpy.data.collections)


def _link_off(lamp_obj, receivers) -> None:
    """Make the fabric's exclusions on ``lamp_obj`` exactly ``receivers``, touching nothing else."""
    link = lamp_obj.light_linking
    coll = link.receiver_collection
    if coll is None:
        if not receivers:
            return
        coll = bpy.data.collections.new(f"MS Exact Lamp {lamp_obj.name}")
        coll[LINKS_MADE] = 1
        link.receiver_collection = coll
    made = bool(coll.get(LINKS_MADE))
    added = {o.name for o in coll.objects} if made else set(coll.get(LINKS_ADDED, []))
    want = {obj.name for obj in receivers}
    for obj in list(coll.objects):
        if obj.name in added and obj.name not in want:
            coll.objects.unlink(obj)
    for obj in receivers:
        if obj.name not in coll.objects:
            coll.objects.link(obj)
            added.add(obj.name)
    # collection_objects runs parallel to objects (its entries do not name their object).
    for obj, entry in zip(coll.objects, coll.collection_objects, strict=True):
        if obj.name in want and entry.light_linking.link_state != "EXCLUDE":
            entry.light_linking.link_state = "EXCLUDE"
    if made and not coll.objects:
        link.receiver_collection = None
        bpy.data.collections.remove(coll)
    elif not made:
        names = sorted(added & want)
        if names:
            coll[LINKS_ADDED] = names
        elif LINKS_ADDED in coll:
            del coll[LINKS_ADDED]
