"""The enamel/dentin sigmoid blend of the fit's model (eq. 5.15-5.21) as a Cycles volume: a "Blend Volume"
object per tooth.

The model (``core.teeth.scene``, ``core.teeth.path_tracer``): the extinction is the sharp sigma_t of the enamel
and dentin regions; at a scattering point at signed distance q from the dentin surface (q < 0 in the dentin) the
albedo and the two-lobe HG parameters g1, g2, beta are blended, x_mix = l x_enamel + (1 - l) x_dentin with
l = 1 / (1 + exp(-q / s)) (spread s, default 1 / ln 19 mm), and sigma_s = a_mix sigma_t (the thesis' vertex:
sigma_s never exceeds sigma_t).

In Cycles:

* the tooth's Enamel and Dentin materials keep their surfaces and give up their volumes (group input
  ``BLEND_INPUT`` = 1): their meshes only bound the medium;
* a mesh object parented to the enamel shell carries a geometry-nodes modifier (its own ``FIELD_GROUP``) that builds
  from the *evaluated* dentin core (its shape keys stay live) and the enamel's outer surface a volume with
  three grids, in the tooth's millimetre frame:
  ``ms_q`` the signed distance to the dentin surface (Mesh to SDF Grid; its narrow band is
  max(2.5 mm, 8 s), beyond which l is within 3.4e-4 of 0 or 1), ``ms_o`` the signed distance to the
  enamel's outer surface, ``ms_m`` the tooth's interior as a fog grid (its active voxels make Cycles'
  volume bounds cover the whole tooth);
* that volume's material (node group ``BLEND_GROUP``) is, in 1/mm (Cycles takes a volume object's density in
  its object space, the tooth's millimetre frame, whatever the scene's unit), inside the tooth (ms_o < 0), the
  extinction sigma_t of the region the sign of ``ms_q`` names, its scattering sigma_s = a_mix sigma_t through two
  Volume Scatter (Henyey-Greenstein) lobes with the mixed g1, g2, beta, and a Volume Absorption of
  sigma_t - sigma_s;
* the blend material's parameters are drivers on the tooth's Enamel and Dentin group nodes, so editing those
  materials or applying a fit changes the blend with them; its spread is ``Spread (mm)`` of its group node.

Why the step comes from the grid, not the dentin mesh: the extinction and the scattering at a point must come
from the same place, or a sliver where the grid says dentin and the mesh says enamel scatters more than it
attenuates (albedo above 1), which Cycles estimates with a heavy tail.

Approximation: q and the tooth's outline are trilinearly interpolated from grids of ``VOXEL_MM`` voxels (in the
viewport ``VIEWPORT_VOXEL_MM``, a preview five times faster to rebuild; the
enamel surface's reflection and a_t stay the mesh's); below ``SHARP_SPREAD_MM`` the meshes render the sharp
model instead. Measured in ``bench teeth-cycles`` (``default_spread_*``, docs/accuracy.md).
"""

from __future__ import annotations

import re

import bpy

from ...core.teeth.blend_spread import DEFAULT_SPREAD_MM
from ...render import material_output, new_material
from ..common import add_group_input, local_node_group
from .materials import BLEND_ATTRIBUTE, INNER_ATTRIBUTE, MARKER, describe_teeth_sockets, group_node

BLEND_INPUT = "Blend Volume"  # Enamel/Dentin group input: 1 = the Blend Volume carries the medium
BLEND_GROUP = "Tooth Blend"
FIELD_GROUP = "Tooth Blend Field"
MODIFIER = "Tooth Blend Field"
SPREAD = "Spread (mm)"
VOXEL_MM = 0.1
# in the viewport (Is Viewport): a tooth's grids rebuild when it moves or its dentin changes shape, 0.40 s a tooth at
# 0.1 mm, 0.08 s at 0.25 mm; renders use VOXEL_MM
VIEWPORT_VOXEL_MM = 0.25
# Below this spread (a tenth of a voxel) the blend is a step at the dentin surface: the meshes' sharp volumes
# are that model exactly, so the Blend Volume is left out of renders and the materials hold the whole medium.
SHARP_SPREAD_MM = 0.01
Q_BAND_MIN_MM = 2.5
Q_BAND_SPREADS = 8.0
GRID_Q, GRID_O, GRID_M = "ms_q", "ms_o", "ms_m"
# the Blend group's node layout: 4 = the thesis' vertex, sigma_s = a_mix sigma_t with the region's own sigma_t,
# the whole medium from the q grid's sign; 3 = coefficients per mm of the object's own frame (2: scaled by
# "mm per Unit", which Cycles applied twice in a scene in metres); 2 = sigma_s = a_mix sigma_t,mix, the sharp
# sigma_t step the Dentin mesh's (1: the q grid's sign)
VERSION_KEY = "ms_volume_version"
BLEND_VERSION = 4
UNIT = "mm per Unit"  # an input of layouts 1-2, removed
MEDIA = ("Enamel", "Dentin")
PARAMS = (("Sigma_t", 3), ("Albedo", 3), ("G1", 0), ("G2", 0), ("Beta", 0))  # (socket, components or 0)


# -- geometry nodes: the grids ----------------------------------------------------------------------------
def _math(nodes, links, op, a, b=None, loc=(0, 0)):
    n = nodes.new("ShaderNodeMath")
    n.operation = op
    n.location = loc
    for i, v in enumerate((a, b)):
        if v is None:
            continue
        if isinstance(v, (int, float)):
            n.inputs[i].default_value = float(v)
        else:
            links.new(v, n.inputs[i])
    return n.outputs[0]


def field_group(name: str, enamel, dentin, material) -> bpy.types.GeometryNodeTree:
    """A tooth's geometry-nodes group: (enamel, dentin) -> a volume with the grids ms_q, ms_o, ms_m and
    ``material``. The objects and the material sit in its nodes (no group inputs: the modifier's input API
    differs between 4.5 and 5.x); its "Spread" value node holds the material's spread (:func:`sync_spread`)."""
    group = bpy.data.node_groups.new(name, "GeometryNodeTree")
    group[MARKER] = "BlendField"
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = group.nodes, group.links
    gout = nodes.new("NodeGroupOutput")
    gout.location = (900, 0)
    vox = nodes.new("ShaderNodeValue")
    vox.name = vox.label = "Voxel Size"
    vox.outputs[0].default_value = VOXEL_MM
    spread = nodes.new("ShaderNodeValue")
    spread.name = spread.label = "Spread"
    spread.outputs[0].default_value = DEFAULT_SPREAD_MM
    voxel = _viewport_voxel(group, vox)

    dobj = nodes.new("GeometryNodeObjectInfo")
    dobj.name = "Dentin"
    dobj.transform_space = "RELATIVE"
    dobj.inputs["Object"].default_value = dentin
    sdf_q = nodes.new("GeometryNodeMeshToSDFGrid")
    links.new(dobj.outputs["Geometry"], sdf_q.inputs["Mesh"])
    links.new(voxel, sdf_q.inputs["Voxel Size"])
    band_mm = _math(nodes, links, "MAXIMUM", _math(nodes, links, "MULTIPLY", spread.outputs[0], Q_BAND_SPREADS),
                    Q_BAND_MIN_MM)
    links.new(_math(nodes, links, "CEIL", _math(nodes, links, "DIVIDE", band_mm, voxel)), sdf_q.inputs["Band Width"])

    eobj = nodes.new("GeometryNodeObjectInfo")
    eobj.name = "Enamel"
    eobj.transform_space = "RELATIVE"
    eobj.inputs["Object"].default_value = enamel
    inner = nodes.new("GeometryNodeInputNamedAttribute")
    inner.data_type = "FLOAT"
    inner.inputs["Name"].default_value = INNER_ATTRIBUTE
    outer = nodes.new("GeometryNodeSeparateGeometry")
    outer.domain = "FACE"
    links.new(eobj.outputs["Geometry"], outer.inputs["Geometry"])
    links.new(_math(nodes, links, "LESS_THAN", inner.outputs["Attribute"], 0.5), outer.inputs["Selection"])
    sdf_o = nodes.new("GeometryNodeMeshToSDFGrid")
    links.new(outer.outputs["Selection"], sdf_o.inputs["Mesh"])
    links.new(voxel, sdf_o.inputs["Voxel Size"])
    sdf_o.inputs["Band Width"].default_value = 3
    fog = nodes.new("GeometryNodeMeshToDensityGrid")
    links.new(outer.outputs["Selection"], fog.inputs["Mesh"])
    links.new(voxel, fog.inputs["Voxel Size"])
    fog.inputs["Density"].default_value = 1.0

    volume = None
    for grid, node in ((GRID_Q, sdf_q), (GRID_O, sdf_o), (GRID_M, fog)):
        store = nodes.new("GeometryNodeStoreNamedGrid")
        store.data_type = "FLOAT"
        store.inputs["Name"].default_value = grid
        links.new(node.outputs[0], store.inputs["Grid"])
        if volume is not None:
            links.new(volume, store.inputs["Volume"])
        volume = store.outputs["Volume"]
    setmat = nodes.new("GeometryNodeSetMaterial")
    setmat.name = "Material"
    links.new(volume, setmat.inputs["Geometry"])
    setmat.inputs["Material"].default_value = material
    links.new(setmat.outputs["Geometry"], gout.inputs["Geometry"])
    for i, node in enumerate(n for n in nodes if n.type != "GROUP_OUTPUT"):
        node.location = (-900 + 160 * (i % 10), -220 * (i // 10))
    # the grids' band follows the material's spread: set where it changes (sync_spread), not by a driver
    node = group_node(material)
    if node is not None:
        spread.outputs[0].default_value = node.inputs[SPREAD].default_value
    describe_teeth_sockets(group)
    return group


def _viewport_voxel(group, vox):
    """The grids' voxel size: ``VOXEL_MM`` in renders, ``VIEWPORT_VOXEL_MM`` in the viewport (Is Viewport)."""
    nodes = group.nodes
    is_viewport = nodes.new("GeometryNodeIsViewport")
    is_viewport.name = "Is Viewport"
    coarse = nodes.new("ShaderNodeValue")
    coarse.name = coarse.label = "Viewport Voxel Size"
    coarse.outputs[0].default_value = VIEWPORT_VOXEL_MM
    switch = nodes.new("GeometryNodeSwitch")
    switch.name = "Voxel Size Here"
    switch.input_type = "FLOAT"
    for i, node in enumerate((is_viewport, coarse, switch)):
        node.location = (vox.location.x + 160 * (i // 2 + 1), vox.location.y - 120 * (i % 2 + 1))
    group.links.new(is_viewport.outputs[0], switch.inputs["Switch"])
    group.links.new(vox.outputs[0], switch.inputs["False"])
    group.links.new(coarse.outputs[0], switch.inputs["True"])
    return switch.outputs[0]


def ensure_viewport_voxel(group) -> bool:
    """A field group of an earlier version (one voxel size everywhere) gets the viewport's coarser one: the links
    from "Voxel Size" are moved to the switch. True when the group changed."""
    if group.library is not None or "Is Viewport" in group.nodes or "Voxel Size" not in group.nodes:
        return False
    vox = group.nodes["Voxel Size"]
    targets = [lk.to_socket for lk in group.links if lk.from_node == vox]
    voxel = _viewport_voxel(group, vox)
    for sock in targets:
        group.links.new(voxel, sock)
    return True


# -- the blend material ------------------------------------------------------------------------------------
def _vec(nodes, links, op, a, b=None, scale=None):
    n = nodes.new("ShaderNodeVectorMath")
    n.operation = op
    for i, v in enumerate((a, b)):
        if v is None:
            continue
        if isinstance(v, tuple):
            n.inputs[i].default_value = v
        else:
            links.new(v, n.inputs[i])
    if scale is not None:
        links.new(scale, n.inputs["Scale"])
    return n.outputs[0]


def ensure_blend_group() -> bpy.types.ShaderNodeTree:
    """The shader group of the blended medium's scattering (one per file): see the module docstring. A group
    from a file made before :data:`BLEND_VERSION` gets its nodes rebuilt (its inputs and their values stay)."""
    from .materials import DEFAULTS

    group = local_node_group(BLEND_GROUP, MARKER)
    if group is not None:
        if group.get(VERSION_KEY, 1) < BLEND_VERSION:
            for node in list(group.nodes):
                group.nodes.remove(node)
            for item in [i for i in group.interface.items_tree if i.item_type == "SOCKET" and i.name == UNIT]:
                group.interface.remove(item)
            _blend_nodes(group)
        return group
    group = bpy.data.node_groups.new(BLEND_GROUP, "ShaderNodeTree")
    group[MARKER] = "Blend"
    for medium in MEDIA:
        d = DEFAULTS[medium]
        add_group_input(group, f"{medium} Sigma_t", "NodeSocketVector", d["sigma_t"], 1e-3, 1e3)
        add_group_input(group, f"{medium} Albedo", "NodeSocketColor", (*d["albedo"], 1.0))
        add_group_input(group, f"{medium} G1", "NodeSocketFloat", d["g1"], -0.95, 0.95)
        add_group_input(group, f"{medium} G2", "NodeSocketFloat", d["g2"], -0.95, 0.95)
        add_group_input(group, f"{medium} Beta", "NodeSocketFloat", d["beta"], 0.0, 1.0)
    add_group_input(group, SPREAD, "NodeSocketFloat", DEFAULT_SPREAD_MM, 0.0, 100.0)
    group.interface.new_socket("Volume", in_out="OUTPUT", socket_type="NodeSocketShader")
    _blend_nodes(group)
    describe_teeth_sockets(group)
    return group


def _blend_nodes(group) -> None:
    """The Blend Volume medium inside the tooth's outline: extinction the sharp sigma_t of the region the q grid's
    sign names (dentin where q < 0), scattering sigma_s = a_mix sigma_t through the mixed two-lobe HG."""
    group[VERSION_KEY] = BLEND_VERSION
    nodes, links = group.nodes, group.links
    gin, gout = nodes.new("NodeGroupInput"), nodes.new("NodeGroupOutput")
    gin.location, gout.location = (-1200, 0), (900, 0)
    attrs = {}
    for name in (GRID_Q, GRID_O, GRID_M):
        a = nodes.new("ShaderNodeAttribute")
        a.attribute_type = "GEOMETRY"
        a.attribute_name = name
        attrs[name] = a.outputs["Fac"]
    # l = 1 / (1 + exp(-q / s)); q / s clamped to +-60 (l within 1e-26 of 0 or 1) so that exp stays finite
    s = _math(nodes, links, "MAXIMUM", gin.outputs[SPREAD], 1e-9)
    x = _math(nodes, links, "DIVIDE", attrs[GRID_Q], s)
    x = _math(nodes, links, "MINIMUM", _math(nodes, links, "MAXIMUM", x, -60.0), 60.0)
    e = _math(nodes, links, "EXPONENT", _math(nodes, links, "MULTIPLY", x, -1.0))
    lw = _math(nodes, links, "DIVIDE", 1.0, _math(nodes, links, "ADD", e, 1.0))
    inside = _math(nodes, links, "MULTIPLY", _math(nodes, links, "LESS_THAN", attrs[GRID_O], 0.0),
                   _math(nodes, links, "GREATER_THAN", attrs[GRID_M], 0.0))

    def mixed_vec(name):  # D + l (E - D)
        diff = _vec(nodes, links, "SUBTRACT", gin.outputs[f"Enamel {name}"], gin.outputs[f"Dentin {name}"])
        return _vec(nodes, links, "ADD", _vec(nodes, links, "SCALE", diff, scale=lw), gin.outputs[f"Dentin {name}"])

    def mixed(name):
        diff = _math(nodes, links, "SUBTRACT", gin.outputs[f"Enamel {name}"], gin.outputs[f"Dentin {name}"])
        n = nodes.new("ShaderNodeMath")
        n.operation = "MULTIPLY_ADD"
        links.new(diff, n.inputs[0])
        links.new(lw, n.inputs[1])
        links.new(gin.outputs[f"Dentin {name}"], n.inputs[2])
        return n.outputs[0]

    # coefficients per millimetre: Cycles takes a volume object's density in its object space, here the tooth's
    # millimetre frame, whatever the scene's unit (measured: x 1000 in a scene in metres gave 1e24 pixels)
    scale = inside
    # the region's own sigma_t: the dentin's where q < 0 (eq. 5.30), the enamel's elsewhere
    in_dentin = _math(nodes, links, "LESS_THAN", attrs[GRID_Q], 0.0)
    step = _vec(nodes, links, "SUBTRACT", gin.outputs["Dentin Sigma_t"], gin.outputs["Enamel Sigma_t"])
    step = _vec(nodes, links, "SCALE", step, scale=in_dentin)
    sigma_t = _vec(nodes, links, "ADD", step, gin.outputs["Enamel Sigma_t"])
    sigma_s = _vec(nodes, links, "MULTIPLY", mixed_vec("Albedo"), sigma_t)
    sigma_s = _vec(nodes, links, "SCALE", sigma_s, scale=scale)
    sigma_t = _vec(nodes, links, "SCALE", sigma_t, scale=scale)
    lobes = []
    for gname in ("G1", "G2"):
        sc = nodes.new("ShaderNodeVolumeScatter")
        if hasattr(sc, "phase"):
            sc.phase = "HENYEY_GREENSTEIN"
        links.new(sigma_s, sc.inputs["Color"])
        sc.inputs["Density"].default_value = 1.0
        links.new(mixed(gname), sc.inputs["Anisotropy"])
        lobes.append(sc)
    mix = nodes.new("ShaderNodeMixShader")  # beta HG(g1) + (1 - beta) HG(g2)
    links.new(mixed("Beta"), mix.inputs["Fac"])
    links.new(lobes[1].outputs[0], mix.inputs[1])
    links.new(lobes[0].outputs[0], mix.inputs[2])
    ab = nodes.new("ShaderNodeVolumeAbsorption")  # weight (1 - Color) Density = sigma_t - sigma_s
    links.new(_vec(nodes, links, "ADD", _vec(nodes, links, "SUBTRACT", sigma_s, sigma_t), (1.0, 1.0, 1.0)),
              ab.inputs["Color"])
    ab.inputs["Density"].default_value = 1.0
    add = nodes.new("ShaderNodeAddShader")
    links.new(mix.outputs[0], add.inputs[0])
    links.new(ab.outputs[0], add.inputs[1])
    links.new(add.outputs[0], gout.inputs["Volume"])
    for i, node in enumerate(n for n in nodes if n.type not in {"GROUP_INPUT", "GROUP_OUTPUT"}):
        node.location = (-1000 + 110 * (i % 16), -200 * (i // 16))


def _add_driver(owner, dst_path: str, index: int, src_mat, src_path: str) -> None:
    """``owner``'s property ``dst_path[index]`` follows ``src_mat``'s ``src_path`` (a plain driver: evaluated
    without Python, saved with the file)."""
    owner.driver_remove(dst_path, index)
    fc = owner.driver_add(dst_path, index)
    drv = fc.driver
    drv.type = "AVERAGE"
    for v in list(drv.variables):
        drv.variables.remove(v)
    var = drv.variables.new()
    var.name = "v"
    var.type = "SINGLE_PROP"
    var.targets[0].id_type = "MATERIAL"
    var.targets[0].id = src_mat
    var.targets[0].data_path = src_path


def _input_index(node, name: str) -> int:
    return next(i for i, s in enumerate(node.inputs) if s.name == name)


def link_materials(blend_mat, enamel_mat, dentin_mat) -> None:
    """Drive the blend material's parameters from the tooth's Enamel and Dentin materials (none where the Blend
    Volume wears a material of the artist's)."""
    bnode = group_node(blend_mat)
    if bnode is None:
        return
    for medium, src in (("Enamel", enamel_mat), ("Dentin", dentin_mat)):
        snode = group_node(src)
        if snode is None:
            continue
        for sock, n in PARAMS:
            di = _input_index(bnode, f"{medium} {sock}")
            si = _input_index(snode, sock)
            dst = f'nodes["{bnode.name}"].inputs[{di}].default_value'
            srcp = f'node_tree.nodes["{snode.name}"].inputs[{si}].default_value'
            bnode.inputs[di].default_value = snode.inputs[si].default_value
            for k in range(n) if n else (-1,):
                _add_driver(blend_mat.node_tree, dst, k, src, srcp if k < 0 else f"{srcp}[{k}]")


def new_blend_material(name: str, spread: float) -> bpy.types.Material:
    group = ensure_blend_group()
    mat = new_material(name)
    mat[MARKER] = "Blend"
    tree = mat.node_tree
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    node.name = node.label = BLEND_GROUP
    out = material_output(mat)
    out.target = "CYCLES"  # EEVEE: the Enamel group's stand-in and the Dentin's volume
    tree.links.new(node.outputs["Volume"], out.inputs["Volume"])
    node.inputs[SPREAD].default_value = float(spread)
    mat.diffuse_color = (1.0, 1.0, 1.0, 0.0)
    return mat


# -- per tooth -----------------------------------------------------------------------------------------------
def blend_object(enamel):
    """The Blend Volume object of a tooth's enamel shell (None if it has none)."""
    return next((o for o in enamel.children if getattr(o, "ms_tooth", None) is not None
                 and o.ms_tooth.role == "BLEND"), None)


def set_blending(mat, on: bool) -> None:
    """An Enamel/Dentin material attenuates only (``on``: its tooth's Blend Volume scatters) or is whole. A material
    linked from another file is left as it is (its data cannot change here: :func:`set_tooth_blending` does it)."""
    node = group_node(mat)
    if node is not None and BLEND_INPUT in node.inputs and mat.library is None:
        node.inputs[BLEND_INPUT].default_value = 1.0 if on else 0.0


def set_tooth_blending(obj, on: bool) -> None:
    """The tooth object's own say (``materials.BLEND_ATTRIBUTE``): ``on`` empties the medium of whatever Enamel/Dentin
    material it wears, one linked from a library included (its Blend Volume carries the medium)."""
    value = 1.0 if on else 0.0
    if obj.library is None and obj.get(BLEND_ATTRIBUTE) != value:
        obj[BLEND_ATTRIBUTE] = value
        obj.update_tag()


def set_spread(enamel, spread: float) -> None:
    """The blend spread s (mm) of a tooth: its Blend Volume material, and the grids' band with it."""
    obj = blend_object(enamel)
    node = group_node(obj.active_material) if obj is not None else None
    if node is not None:
        node.inputs[SPREAD].default_value = float(spread)
        _sync_object_spread(obj)


SPREAD_PATH = 'nodes["Spread"].outputs[0].default_value'


def sync_spread(group) -> bool:
    """The band of a Blend Volume's q grid follows its material's spread: the field group's "Spread" value is set
    where it differs (True then). Not a driver: a driver reading the material re-evaluated the grids (0.4 s a tooth)
    on every edit of the tooth's materials, whose parameters the blend material follows by drivers. Where the
    spread is keyframed or driven, a driver it is, so every frame of a render gets its own band. A field group
    from another file is left as it is."""
    if group.library is not None or group.get(MARKER) != "BlendField" or "Spread" not in group.nodes:
        return False
    ensure_viewport_voxel(group)
    setmat = group.nodes.get("Material")
    material = setmat.inputs["Material"].default_value if setmat is not None else None
    node = group_node(material) if material is not None else None
    if node is None or SPREAD not in node.inputs:
        return False
    driven = group.animation_data is not None and group.animation_data.drivers.find(SPREAD_PATH) is not None
    if _spread_animated(material, node):
        if not driven:
            _add_driver(group, SPREAD_PATH, -1, material,
                        f'node_tree.nodes["{node.name}"].inputs["{SPREAD}"].default_value')
        return False
    if driven:
        group.driver_remove(SPREAD_PATH)
    value = group.nodes["Spread"].outputs[0]
    want = node.inputs[SPREAD].default_value
    if value.default_value == want:
        return False
    value.default_value = want
    return True


def _spread_animated(material, node) -> bool:
    """Whether the spread of ``material``'s Blend group node is keyframed (in the active action or an NLA strip's)
    or driven."""
    anim = material.node_tree.animation_data
    if anim is None:
        return False
    index = next(i for i, sock in enumerate(node.inputs) if sock.name == SPREAD)
    paths = {f'nodes["{node.name}"].inputs[{index}].default_value',
             f'nodes["{node.name}"].inputs["{SPREAD}"].default_value'}
    if any(fc.data_path in paths for fc in anim.drivers):
        return True
    actions = [(anim.action, getattr(anim, "action_slot", None))]
    actions += [(strip.action, getattr(strip, "action_slot", None)) for track in anim.nla_tracks
                for strip in track.strips]
    return any(fc.data_path in paths for action, slot in actions if action is not None
               for fc in _action_curves(action, slot))


def _action_curves(action, slot) -> list:
    """The F-curves of ``action`` for ``slot`` (4.4+: they live in the slot's channel bag)."""
    try:
        from bpy_extras.anim_utils import action_get_channelbag_for_slot
    except ImportError:
        return list(action.fcurves)
    bag = action_get_channelbag_for_slot(action, slot)
    return list(bag.fcurves) if bag is not None else []


def _sync_object_spread(blend_obj) -> None:
    """:func:`sync_spread` for a Blend Volume's own field group (none where the artist removed its modifier or its
    group)."""
    mod = blend_obj.modifiers.get(MODIFIER)
    if mod is not None and mod.type == "NODES" and mod.node_group is not None:
        sync_spread(mod.node_group)


def sync_spreads() -> None:
    """:func:`sync_spread` for every field group of this file (before a depsgraph evaluates: a value set after it,
    in ``depsgraph_update_post``, is not evaluated until something else changes)."""
    for group in bpy.data.node_groups:
        if group.get(MARKER) == "BlendField":
            sync_spread(group)


def ensure_blend(enamel, spread: float | None = None, collection=None):
    """Give the tooth of ``enamel`` its Blend Volume (made once, in ``collection`` or the enamel's collections of this
    file; its materials linked again each call) and, unless ``spread`` is None, set the spread. Returns the Blend
    Volume object (None without a dentin, or where it has none and no collection of this file could hold one)."""
    dentin = enamel.ms_tooth.partner
    em = enamel.active_material
    dm = dentin.active_material if dentin is not None else None
    if dentin is None or group_node(em) is None or group_node(dm) is None:
        return None
    from .materials import ensure_blend_input, set_gate

    obj = blend_object(enamel)
    # a new Blend Volume goes where its enamel is, in collections of this file (one of another file is read-only)
    colls = [collection] if collection is not None else [c for c in enamel.users_collection if c.library is None]
    if obj is None and not colls:
        return None
    for m in (em, dm):
        ensure_blend_input(group_node(m).node_tree)
        set_gate(group_node(m).node_tree, False)  # a shade appended from a file: its input is set here
    name = enamel.ms_tooth.tooth_name or enamel.name
    if obj is None:
        mat = new_blend_material(f"Blend {name}", DEFAULT_SPREAD_MM if spread is None else spread)
        me = bpy.data.meshes.new(f"{name} Blend Volume")
        me.materials.append(mat)
        obj = bpy.data.objects.new(f"{name} Blend Volume", me)
        for c in colls:
            c.objects.link(obj)
        obj.parent = enamel  # identity: the grids are in the enamel's millimetre frame
        obj.ms_tooth.role = "BLEND"
        obj.ms_tooth.tooth_name = enamel.ms_tooth.tooth_name
        obj.ms_tooth.partner = enamel
        obj.ms_tooth.mm_per_unit = enamel.ms_tooth.mm_per_unit
        obj.display_type = "BOUNDS"
        obj.hide_select = True
        mod = obj.modifiers.new(MODIFIER, "NODES")
        mod.node_group = field_group(f"{FIELD_GROUP} {name}", enamel, dentin, mat)
    mat = obj.active_material
    link_materials(mat, em, dm)
    if spread is not None:
        set_spread(enamel, spread)
    _sync_object_spread(obj)
    node = group_node(mat)
    on = node is not None and node.inputs[SPREAD].default_value >= SHARP_SPREAD_MM
    set_blending(em, on)
    set_blending(dm, on)
    set_tooth_blending(enamel, on)
    set_tooth_blending(dentin, on)
    obj.hide_render = not on
    return obj


def linked_materials(blend_mat) -> tuple:
    """The (Enamel, Dentin) materials whose parameters drive ``blend_mat`` (read from its drivers; None for a
    medium no driver names)."""
    bnode = group_node(blend_mat)
    anim = blend_mat.node_tree.animation_data if bnode is not None else None
    found = {}
    for fc in anim.drivers if anim is not None else ():
        index = re.search(r"inputs\[(\d+)\]", fc.data_path)
        if index is None or not fc.driver.variables or int(index.group(1)) >= len(bnode.inputs):
            continue
        medium = bnode.inputs[int(index.group(1))].name.split(" ", 1)[0]
        if medium in MEDIA:
            found.setdefault(medium, fc.driver.variables[0].targets[0].id)
    return found.get("Enamel"), found.get("Dentin")


def own_dentin(enamel):
    """The dentin core of ``enamel``. A copy of an enamel shell alone (Shift+D or Alt+D of what a click on a tooth
    selects: the dentin, a child of the original, is not copied with it) points at the original's dentin; it gets a
    copy of that dentin of its own, parented to it, so the copy's Blend Volume is built from its own dentin. After
    Shift+D the new dentin has a mesh of its own (the copy's sliders leave the original's shape alone); after Alt+D
    it shares the original dentin's mesh, as the enamel's is shared, and with it the shape keys: a linked duplicate's
    dentin shape moves with the original's, as its enamel mesh does. None without a dentin."""
    dentin = enamel.ms_tooth.partner
    original = dentin.ms_tooth.partner if dentin is not None else None
    if original is None or original == enamel or dentin.ms_tooth.role != "DENTIN" or dentin.library is not None:
        return dentin
    copy = dentin.copy()  # its parent inverse too: the same place in the copy's frame
    if enamel.data is not original.data:
        copy.data = dentin.data.copy()
    for coll in enamel.users_collection:
        coll.objects.link(copy)
    copy.parent = enamel
    copy.ms_tooth.partner = enamel
    enamel.ms_tooth.partner = copy
    return copy


def follow_places() -> int:
    """Blend Volumes follow their tooth's place: one whose enamel shell is in no collection (the tooth was deleted,
    or a script took it out for a while) leaves every collection too (it is hidden and cannot be selected, and it
    went on rendering the deleted tooth's inside, saved with the file); it stays the enamel's child, so a tooth put
    back finds it, spread and all. One whose enamel moved to other collections, or was linked into another scene,
    moves with it (left behind, the tooth rendered hollow where the old collection was excluded, and in the other
    scene). One this file made for a linked tooth leaves when the tooth's own file brings its Blend Volume (else the
    medium would count twice). Collections that cannot change here (linked, overridden) are left as they are.
    Returns how many changed."""
    changed = 0
    for obj in _local_blend_volumes():
        enamel = obj.parent if obj.parent is not None else obj.ms_tooth.partner
        have = {c.as_pointer(): c for c in obj.users_collection}
        redundant = enamel is not None and any(c.library is not None and c.ms_tooth.role == "BLEND"
                                               for c in enamel.children)
        if enamel is None or not enamel.users_collection or redundant:
            want = {}
        else:
            want = {c.as_pointer(): c for c in enamel.users_collection if c.library is None}
            if not want:
                continue  # the tooth lives in collections of another file only: nothing here to follow
        if want.keys() == have.keys():
            continue
        for key, coll in want.items():
            if key not in have:
                _try(coll.objects.link, obj)
        for key, coll in have.items():
            if key not in want:
                _try(coll.objects.unlink, obj)
        changed += 1
    return changed


def _try(change, obj) -> None:
    """A collection change that a library override may refuse ("Collection ... is overridden"): then it stays."""
    try:
        change(obj)
    except RuntimeError:
        pass


def _local_blend_volumes() -> list:
    """This file's Blend Volume objects (a scan of every object, 1.4 us each: run on collection changes only)."""
    return [o for o in bpy.data.objects if o.library is None and getattr(o, "ms_tooth", None) is not None
            and o.ms_tooth.role == "BLEND"]


def follow_materials(enamels) -> list:
    """Teeth (enamel shells) whose Blend Volume is driven by other materials than the ones their enamel and dentin
    wear now (an artist gave the dentin another material, e.g. a library Dentin Shade) get the new ones linked: the
    Blend Volume takes their parameters and they stop carrying a medium of their own, which the dentin would
    otherwise hold twice (a material linked from a library included: the tooth object's own property empties it). A
    tooth without a Blend Volume whose materials or objects expect one (a Shift+D copy, or a tooth linked from another
    file without it) gets its own (a copy of the enamel alone first its own dentin: :func:`own_dentin`). A tooth
    whose new material is not an Enamel/Dentin material, or that comes from another file with its Blend Volume, is
    left alone. Returns the enamel shells relinked or given a Blend Volume."""
    done = []
    for enamel in enamels:
        if not enamel.users_collection:  # deleted (or out of every collection for a while): follow_places' part
            continue
        dentin = own_dentin(enamel)
        if dentin is None:
            continue
        em, dm = enamel.active_material, dentin.active_material
        if group_node(em) is None or group_node(dm) is None:
            continue
        obj = blend_object(enamel)
        if obj is None:
            # a copy (Shift+D) of a tooth, its Blend Volume not selected (it cannot be), or a tooth linked from another
            # file without it (File > Link of what one sees): its materials give their medium to a Blend Volume, so
            # it gets its own (this file's), at the spread of the tooth it was copied from
            if (any(BLEND_INPUT in group_node(m).inputs and group_node(m).inputs[BLEND_INPUT].default_value == 1.0
                    for m in (em, dm)) or any(o.get(BLEND_ATTRIBUTE) == 1.0 for o in (enamel, dentin))) \
                    and ensure_blend(enamel, _twin_spread(em, dm)) is not None:
                done.append(enamel)
            continue
        if enamel.library is not None:
            continue  # a linked tooth's Blend Volume (its file's, or one made here): left as it is
        blend_node = group_node(obj.active_material) if obj.active_material is not None else None
        if blend_node is None or SPREAD not in blend_node.inputs:
            continue  # the artist gave the Blend Volume a material of their own: theirs to keep
        on = blend_node.inputs[SPREAD].default_value >= SHARP_SPREAD_MM
        stale = [m for m in (em, dm) if m.library is None and BLEND_INPUT in group_node(m).inputs
                 and (group_node(m).inputs[BLEND_INPUT].default_value == 1.0) != on]
        stale += [o for o in (enamel, dentin) if o.library is None and o.get(BLEND_ATTRIBUTE, 0.0) != float(on)]
        if linked_materials(obj.active_material) != (em, dm) or stale:
            ensure_blend(enamel)
            done.append(enamel)
    return done


def _twin_spread(enamel_mat, dentin_mat) -> float | None:
    """The spread of a Blend Volume that ``enamel_mat`` and ``dentin_mat`` drive (None where none does)."""
    for obj in bpy.data.objects:
        if getattr(obj, "ms_tooth", None) is not None and obj.ms_tooth.role == "BLEND" and obj.active_material:
            node = group_node(obj.active_material)
            if node is not None and linked_materials(obj.active_material) == (enamel_mat, dentin_mat):
                return float(node.inputs[SPREAD].default_value)
    return None


def upgrade_after_load() -> None:
    """Teeth of a file made by an older version: the Enamel/Dentin groups and the Blend group get the current
    node layouts (the Enamel/Gingiva groups their EEVEE stand-in), and every tooth with a Blend Volume its materials
    linked again (their drivers made anew).
    A file of the current layouts is left as it was opened (nothing rebuilt, no driver made again)."""
    from .materials import SURFACE_GROUPS, ensure_blend_input, ensure_stand_in

    for group in bpy.data.node_groups:
        if group.library is None and group.get(MARKER) in SURFACE_GROUPS:
            ensure_stand_in(group)
    changed = False
    for group in bpy.data.node_groups:
        if group.library is None and group.get(MARKER) in MEDIA:
            changed |= ensure_blend_input(group)
    blend = bpy.data.node_groups.get(BLEND_GROUP)
    if blend is not None and blend.get(MARKER) and blend.library is None:
        changed |= blend.get(VERSION_KEY, 1) < BLEND_VERSION
        ensure_blend_group()
    if not changed:
        return
    for obj in bpy.data.objects:
        ms = getattr(obj, "ms_tooth", None)
        if obj.library is None and ms is not None and ms.role == "ENAMEL" and blend_object(obj) is not None:
            ensure_blend(obj)
