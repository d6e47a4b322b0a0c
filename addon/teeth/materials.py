"""Node groups "Enamel", "Dentin", "Gingiva" and the materials built on them (thesis Sec. 5.5).

* Surface (enamel, gums): OSL script ``cycles_osl/ms_enamel_boundary.osl``, the thin dielectric
  boundary of eq. 5.1-5.2: Fresnel mirror reflection F plus straight (non-bending) transmission
  a_t (1 - F) through a ``transparent`` closure; eta 1.631 (enamel) / 1.33 (gums).
* Volume (all three): absorption + two-lobe Henyey-Greenstein scattering (eq. 5.3-5.4) from built-in
  nodes, so it is homogeneous for Cycles: sigma_s = albedo sigma_t split over two Volume Scatter nodes
  mixed by beta, sigma_a = (1 - albedo) sigma_t from a Volume Absorption node (weight (1 - Color)
  Density, fed with Color = 1 - sigma_a, Density = 1).
* Units: sigma_t is in 1/mm like the core; the group input "mm per Unit" converts to Blender units
  (1000 for a scene in metres, 1 when one Blender unit is one millimetre).
* The enamel shell carries a face attribute ``ms_inner`` (1 on the faces that close it around the
  dentin core): those faces are fully transparent (index-matched interface, eq. 5.5).
"""

from __future__ import annotations

import bpy
import numpy as np

from ...render import load_osl_script, material_output, new_material
from ..common import add_eevee_fallback, add_group_input, group_material
from ..common import group_node as _group_node

MARKER = "material_structures_teeth"
SCRIPT_NODE = "Enamel Boundary"
INNER_ATTRIBUTE = "ms_inner"

ETA_ENAMEL = 1.631
ETA_GUMS = 1.33

# Typical defaults (synthetic ground truth of core.teeth.synthetic, within the literature ranges).
DEFAULTS = {
    "Enamel": {"sigma_t": (0.9, 1.1, 1.4), "albedo": (0.97, 0.96, 0.94), "g1": 0.6, "g2": -0.2, "beta": 0.85,
               "eta": ETA_ENAMEL},
    "Dentin": {"sigma_t": (2.2, 2.6, 3.2), "albedo": (0.93, 0.85, 0.72), "g1": 0.5, "g2": -0.1, "beta": 0.8},
    "Gingiva": {"sigma_t": (1.5, 2.5, 2.5), "albedo": (0.9, 0.55, 0.5), "g1": 0.7, "g2": -0.1, "beta": 0.9,
                "eta": ETA_GUMS},
}
GROUP_NAMES = tuple(DEFAULTS)
SURFACE_GROUPS = ("Enamel", "Gingiva")
BLENDED_GROUPS = ("Enamel", "Dentin")  # blended by a tooth's Blend Volume (blend_volume.py)
# 1: the material only attenuates (Volume Absorption of sigma_t); its tooth's Blend Volume scatters
BLEND_ROW = ("Blend Volume", "NodeSocketFloat", 0.0, 0.0, 1.0)
# Layout 2 only: the Dentin's input for the sharp step of the extinction its mesh carried (removed on upgrade)
STEP_ROW = ("Enamel Sigma_t", "NodeSocketVector", DEFAULTS["Enamel"]["sigma_t"], 1e-3, 1e3)
# The tooth object's say in it: the object custom property of this name (1 where the tooth's Blend Volume renders,
# set by blend_volume.ensure_blend) empties the medium like the input does. A material linked from another file (a
# library shade) cannot have its input changed here; its tooth's property still hands the medium to the Blend Volume.
# The property is read only in the file as written (the gate's link, :func:`set_gate`, made before every save and
# taken out after it and after a file is opened): an Attribute node in a volume makes Cycles treat the medium as
# varying in space and build a 128^3 density octree for every mesh wearing it (3.3 s of a one-tooth render that takes
# 0.4 s without), and this file's own materials have their input set.
BLEND_ATTRIBUTE = "ms_blend_volume"
BLEND_ATTRIBUTE_NODE = "Tooth Has Blend Volume"
GATE_NODE = "Tooth Gate"  # max(Blend Volume input, the object's property) where the gate is linked
# the volume subgraph's layout: 4 = as 3, the medium also emptied by the tooth object's BLEND_ATTRIBUTE; 3 = under
# Blend Volume, Enamel and Dentin only bound the medium (the Blend Volume carries it whole, its extinction step
# included); 2 = the Dentin's mesh carried the step; 1 = as 3, before the step input existed
VOLUME_VERSION_KEY = "ms_volume_version"
VOLUME_VERSION = 4

# What each socket of the teeth groups means, by name (a medium's name, "Enamel " or "Dentin ", may lead it).
SOCKET_WORDS = {
    "Sigma_t": "Extinction coefficient per colour channel (R, G, B) in 1/mm: how quickly light is scattered or "
               "absorbed inside the tissue",
    "Albedo": "Single-scattering albedo per colour channel (0-1, no unit): the share of extinction that scatters",
    "G1": "Mean cosine of the first Henyey-Greenstein lobe (-1 back to 1 forward, no unit)",
    "G2": "Mean cosine of the second Henyey-Greenstein lobe (-1 back to 1 forward, no unit)",
    "Beta": "Weight of the first lobe in the two-lobe phase function (0-1, no unit)",
    "Eta": "Refractive index of the boundary (no unit; enamel 1.631, gums 1.33)",
    "At": "Transmittance of the thin boundary layer per colour channel (0-1, no unit)",
    "mm per Unit": "Millimetres per Blender unit (1000: the scene is in metres; 1: a unit is a millimetre)",
    "Blend Volume": "On (1): the tooth's Blend Volume object carries the medium with the blended enamel/dentin "
                    "boundary and this mesh only bounds it; off (0): this mesh's homogeneous medium, unless the "
                    "tooth wearing it has a Blend Volume",
    "Spread (mm)": "Width of the enamel/dentin transition in millimetres (the sigmoid's spread)",
    "Surface": "The boundary's surface shader (connect to the material output's Surface)",
    "Volume": "The medium (connect to the material output's Volume)",
    "EEVEE Surface": "A subsurface stand-in of the tissue for EEVEE and Material Preview (connect to an EEVEE "
                     "material output); Cycles renders Surface and Volume",
    "Geometry": "The tooth's volume grids for the blended boundary",
}


def describe_teeth_sockets(group) -> None:
    """Give every socket of a teeth group its words (:data:`SOCKET_WORDS`) where it has none."""
    for item in group.interface.items_tree:
        if item.item_type != "SOCKET" or item.description:
            continue
        name = item.name
        for prefix in ("Enamel ", "Dentin ", "Gingiva "):
            if name.startswith(prefix) and name[len(prefix):] in SOCKET_WORDS:
                name = name[len(prefix):]
        if name in SOCKET_WORDS:
            item.description = SOCKET_WORDS[name]


def _group_inputs(kind: str) -> list[tuple]:
    d = DEFAULTS[kind]
    rows = [
        # sigma_t is a vector: colour socket values are clamped to [0, 1] in the UI, sigma_t is not
        ("Sigma_t", "NodeSocketVector", d["sigma_t"], 1e-3, 1e3),
        ("Albedo", "NodeSocketColor", (*d["albedo"], 1.0), None, None),
        ("G1", "NodeSocketFloat", d["g1"], -0.95, 0.95),
        ("G2", "NodeSocketFloat", d["g2"], -0.95, 0.95),
        ("Beta", "NodeSocketFloat", d["beta"], 0.0, 1.0),
    ]
    if kind in SURFACE_GROUPS:
        rows += [("At", "NodeSocketColor", (1.0, 1.0, 1.0, 1.0), None, None),
                 ("Eta", "NodeSocketFloat", d["eta"], 1.0, 3.0)]
    rows.append(("mm per Unit", "NodeSocketFloat", 1000.0, 1e-6, 1e9))
    if kind in BLENDED_GROUPS:
        rows.append(BLEND_ROW)
    return rows


def _load_boundary_script(tree, scene):
    return load_osl_script(tree, "ms_enamel_boundary", scene, inputs=["Eta", "At", "Inner"], outputs=["BSDF"],
                           name=SCRIPT_NODE)


def _volume_subgraph(group, gin):
    """sigma_t, albedo, g1, g2, beta -> two-lobe HG scattering + absorption (returns the shader socket).

    With the input ``Blend Volume`` on, or (in the file as written: :func:`set_gate`) the tooth object's
    :data:`BLEND_ATTRIBUTE` property, the tooth's Blend Volume object carries the whole medium over the tooth
    (``blend_volume``): the Enamel's and the Dentin's volumes are empty, their meshes only bound it.
    """
    nodes, links = group.nodes, group.links
    group[VOLUME_VERSION_KEY] = VOLUME_VERSION
    st = nodes.new("ShaderNodeVectorMath")
    st.operation = "SCALE"
    links.new(gin.outputs["Sigma_t"], st.inputs[0])
    links.new(gin.outputs["mm per Unit"], st.inputs["Scale"])
    ss = nodes.new("ShaderNodeVectorMath")
    ss.operation = "MULTIPLY"
    links.new(gin.outputs["Albedo"], ss.inputs[0])
    links.new(st.outputs[0], ss.inputs[1])
    if BLEND_ROW[0] in gin.outputs:
        has = nodes.new("ShaderNodeAttribute")  # the object's property; 0 where it has none
        has.attribute_type = "OBJECT"
        has.attribute_name = BLEND_ATTRIBUTE
        has.name = has.label = BLEND_ATTRIBUTE_NODE
        either = nodes.new("ShaderNodeMath")
        either.operation = "MAXIMUM"
        either.name = either.label = GATE_NODE
        either.inputs[1].default_value = 0.0  # where the property is not read (set_gate)
        links.new(gin.outputs[BLEND_ROW[0]], either.inputs[0])
        has.location, either.location = (-660, -560), (-480, -500)
        given = either.outputs[0]
        keep = nodes.new("ShaderNodeMath")
        keep.operation = "SUBTRACT"
        keep.inputs[0].default_value = 1.0
        links.new(given, keep.inputs[1])
        for i, name in enumerate(("st", "ss")):
            own = nodes.new("ShaderNodeVectorMath")
            own.operation = "SCALE"
            links.new((st if name == "st" else ss).outputs[0], own.inputs[0])
            links.new(keep.outputs[0], own.inputs["Scale"])
            own.location = (-120, -500 - 150 * i)
            if name == "st":
                st = own
            else:
                ss = own
        keep.location = (-300, -500)
    sa = nodes.new("ShaderNodeVectorMath")
    sa.operation = "SUBTRACT"
    links.new(st.outputs[0], sa.inputs[0])
    links.new(ss.outputs[0], sa.inputs[1])
    one_minus = nodes.new("ShaderNodeVectorMath")
    one_minus.operation = "SUBTRACT"
    one_minus.inputs[0].default_value = (1.0, 1.0, 1.0)
    links.new(sa.outputs[0], one_minus.inputs[1])
    lobes = []
    for gname in ("G1", "G2"):
        sc = nodes.new("ShaderNodeVolumeScatter")
        if hasattr(sc, "phase"):
            sc.phase = "HENYEY_GREENSTEIN"
        links.new(ss.outputs[0], sc.inputs["Color"])
        sc.inputs["Density"].default_value = 1.0
        links.new(gin.outputs[gname], sc.inputs["Anisotropy"])
        lobes.append(sc)
    mix = nodes.new("ShaderNodeMixShader")  # (1 - Fac) shader 1 + Fac shader 2 = beta HG(g1) + (1 - beta) HG(g2)
    links.new(gin.outputs["Beta"], mix.inputs["Fac"])
    links.new(lobes[1].outputs[0], mix.inputs[1])
    links.new(lobes[0].outputs[0], mix.inputs[2])
    ab = nodes.new("ShaderNodeVolumeAbsorption")
    links.new(one_minus.outputs[0], ab.inputs["Color"])
    ab.inputs["Density"].default_value = 1.0
    add = nodes.new("ShaderNodeAddShader")
    links.new(mix.outputs[0], add.inputs[0])
    links.new(ab.outputs[0], add.inputs[1])
    for i, n in enumerate((st, ss, sa, one_minus)):
        n.location = (-300 + 180 * i, -300)
    lobes[0].location, lobes[1].location, ab.location = (450, -200), (450, -400), (450, -600)
    mix.location, add.location = (650, -300), (850, -300)
    return add.outputs[0]


OSL_SWITCH = "Shader Path"  # Mix Shader: the OSL boundary where the script runs, else the native one


def _native_boundary(group, gin, inner_attr):
    """The boundary of ms_enamel_boundary.osl from Cycles' own nodes, for Cycles without Open Shading Language
    (its SVM drops script nodes): F(|cos|, Eta) of the view direction (the same F from either side, no total
    internal reflection) mixing a sharp Glossy (weight F) and a Transparent of colour At (weight 1 - F); the
    ms_inner faces fully transparent."""
    nodes, links = group.nodes, group.links

    def op(name, a, b=None):
        n = nodes.new("ShaderNodeMath")
        n.operation = name
        for i, v in enumerate((a, b)):
            if v is None:
                continue
            if isinstance(v, float):
                n.inputs[i].default_value = v
            else:
                links.new(v, n.inputs[i])
        return n.outputs[0]

    geo = nodes.new("ShaderNodeNewGeometry")
    dot = nodes.new("ShaderNodeVectorMath")
    dot.operation = "DOT_PRODUCT"
    links.new(geo.outputs["Incoming"], dot.inputs[0])
    links.new(geo.outputs["Normal"], dot.inputs[1])
    c = op("MINIMUM", op("ABSOLUTE", dot.outputs["Value"]), 1.0)
    eta = gin.outputs["Eta"]
    s2 = op("DIVIDE", op("SUBTRACT", 1.0, op("MULTIPLY", c, c)), op("MULTIPLY", eta, eta))
    ct = op("SQRT", op("MAXIMUM", op("SUBTRACT", 1.0, s2), 0.0))
    eta_ct, eta_c = op("MULTIPLY", eta, ct), op("MULTIPLY", eta, c)
    rs = op("DIVIDE", op("SUBTRACT", c, eta_ct), op("ADD", c, eta_ct))
    rp = op("DIVIDE", op("SUBTRACT", eta_c, ct), op("ADD", eta_c, ct))
    f = op("MULTIPLY", op("ADD", op("MULTIPLY", rs, rs), op("MULTIPLY", rp, rp)), 0.5)
    glossy = nodes.new("ShaderNodeBsdfGlossy")
    glossy.inputs["Roughness"].default_value = 0.0
    glossy.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    through = nodes.new("ShaderNodeBsdfTransparent")
    links.new(gin.outputs["At"], through.inputs["Color"])
    outer = nodes.new("ShaderNodeMixShader")  # (1 - F) At transparent + F mirror
    links.new(f, outer.inputs["Fac"])
    links.new(through.outputs[0], outer.inputs[1])
    links.new(glossy.outputs[0], outer.inputs[2])
    inner = nodes.new("ShaderNodeBsdfTransparent")
    pick = nodes.new("ShaderNodeMixShader")
    links.new(op("GREATER_THAN", inner_attr.outputs["Fac"], 0.5), pick.inputs["Fac"])
    links.new(outer.outputs[0], pick.inputs[1])
    links.new(inner.outputs[0], pick.inputs[2])
    for i, n in enumerate([geo, dot, glossy, through, outer, inner, pick]):
        n.location = (-100 + 150 * i, 650)
    return pick.outputs[0]


def ensure_blend_input(group) -> bool:
    """Give an Enamel/Dentin group from an older file the ``Blend Volume`` input, its volume rebuilt to the current
    :data:`VOLUME_VERSION` (a Dentin of layout 2 loses its step input ``Enamel Sigma_t`` and the drivers that fed
    it). Returns whether it changed the group (a current one is left untouched)."""
    kind = group.get(MARKER)
    if kind not in BLENDED_GROUPS or group.library is not None:  # linked: not ours to change
        return False
    have = {s.name for s in group.interface.items_tree if s.item_type == "SOCKET" and s.in_out == "INPUT"}
    if (BLEND_ROW[0] in have and group.get(VOLUME_VERSION_KEY, 1) >= VOLUME_VERSION
            and group.nodes.get(BLEND_ATTRIBUTE_NODE) is not None):
        return False
    if BLEND_ROW[0] not in have:
        add_group_input(group, *BLEND_ROW)
    if STEP_ROW[0] in have:
        _remove_step_input(group)
    _rebuild_volume(group)
    describe_teeth_sockets(group)
    return True


def _rebuild_volume(group) -> None:
    """The volume subgraph of an Enamel/Dentin ``group`` made again (the current layout, the gate unlinked); its
    surface nodes stay."""
    keep = {"GROUP_INPUT", "GROUP_OUTPUT", "SCRIPT", "ATTRIBUTE"}
    gout = next(n for n in group.nodes if n.type == "GROUP_OUTPUT")
    volume_nodes = _upstream(gout.inputs["Volume"])
    gate = [n for n in group.nodes if n.name == BLEND_ATTRIBUTE_NODE]  # read or not (set_gate)
    for node in [n for n in volume_nodes if n.type not in keep] + gate:
        group.nodes.remove(node)
    gin = next(n for n in group.nodes if n.type == "GROUP_INPUT")
    group.links.new(_volume_subgraph(group, gin), gout.inputs["Volume"])


def set_gate(group, on: bool) -> bool:
    """Link (``on``) or unlink the tooth object's :data:`BLEND_ATTRIBUTE` into a local Enamel/Dentin ``group``'s
    medium. Linked in the file as written, so that a material another file links, whose Blend Volume input cannot
    be set there, still hands its medium to the tooth's Blend Volume; unlinked here, where this file's materials have
    their input set and an unread Attribute node costs Cycles nothing. Only the link changes (no node is made or
    removed). Returns whether it changed the group."""
    has = group.nodes.get(BLEND_ATTRIBUTE_NODE)
    if group.library is not None or group.get(MARKER) not in BLENDED_GROUPS or has is None:
        return False
    out = has.outputs["Fac"]
    if out.links:  # linked (a file of layout 4 names its Maximum node only here)
        either = out.links[0].to_node
        if either.name != GATE_NODE:
            either.name = either.label = GATE_NODE
        if on:
            return False
        group.links.remove(out.links[0])
        either.inputs[1].default_value = 0.0  # unread: the input alone decides
        return True
    either = group.nodes.get(GATE_NODE)
    if not on or either is None:
        return False
    group.links.new(out, either.inputs[1])
    return True


def gate_for_linking() -> None:
    """Before a file is written: every local Enamel/Dentin group reads the wearing object's property (a shade another
    file links from it hands its medium to the tooth's Blend Volume there)."""
    for group in bpy.data.node_groups:
        set_gate(group, True)


def ungate_local() -> None:
    """After a file is written or opened: this file's own Enamel/Dentin groups leave the property out."""
    for group in bpy.data.node_groups:
        set_gate(group, False)


def _remove_step_input(group) -> None:
    """Remove layout 2's ``Enamel Sigma_t`` input from ``group`` and, first, the drivers on it in every material
    that uses the group (they would otherwise point at a socket that is gone)."""
    for mat in bpy.data.materials:
        tree = mat.node_tree
        if tree is None or mat.library is not None:
            continue
        for node in tree.nodes:
            if node.type == "GROUP" and node.node_tree == group and STEP_ROW[0] in node.inputs:
                i = next(k for k, sock in enumerate(node.inputs) if sock.name == STEP_ROW[0])
                for k in range(3):
                    tree.driver_remove(f'nodes["{node.name}"].inputs[{i}].default_value', k)
    group.interface.remove(next(s for s in group.interface.items_tree
                                if s.item_type == "SOCKET" and s.in_out == "INPUT" and s.name == STEP_ROW[0]))


def _upstream(socket) -> set:
    """The nodes that feed ``socket`` (transitively)."""
    seen, todo = set(), [lk.from_node for lk in socket.links]
    while todo:
        n = todo.pop()
        if n in seen:
            continue
        seen.add(n)
        todo.extend(lk.from_node for s in n.inputs for lk in s.links)
    return seen


def ensure_group(kind: str, scene=None) -> bpy.types.ShaderNodeTree:
    """The shared node group ``kind`` ("Enamel", "Dentin" or "Gingiva"), created once per file."""
    if kind not in DEFAULTS:
        raise ValueError(f"unknown teeth node group {kind!r}; use one of {', '.join(GROUP_NAMES)}")
    scene = scene or bpy.context.scene
    # this file's own (a shade linked from another file brings that file's group of the same name), by that name
    # where it has it (an artist's own group may hold the name)
    mine = [g for g in bpy.data.node_groups if g.library is None and g.get(MARKER) == kind]
    group = next((g for g in mine if g.name == kind), mine[0] if mine else None)
    if group is not None:
        describe_teeth_sockets(group)  # a group from a file made before the sockets had words
        ensure_stand_in(group)  # ... or before the stand-in followed the sliders
        return group
    group = bpy.data.node_groups.new(kind, "ShaderNodeTree")
    group[MARKER] = kind
    for spec in _group_inputs(kind):
        add_group_input(group, *spec)
    if kind in SURFACE_GROUPS:
        group.interface.new_socket("Surface", in_out="OUTPUT", socket_type="NodeSocketShader")
    group.interface.new_socket("Volume", in_out="OUTPUT", socket_type="NodeSocketShader")
    if kind in SURFACE_GROUPS:
        group.interface.new_socket(EEVEE_OUTPUT, in_out="OUTPUT", socket_type="NodeSocketShader")
    nodes, links = group.nodes, group.links
    gin = nodes.new("NodeGroupInput")
    gout = nodes.new("NodeGroupOutput")
    gin.location, gout.location = (-600, 0), (1100, 0)
    if kind in SURFACE_GROUPS:
        script = _load_boundary_script(group, scene)
        attr = nodes.new("ShaderNodeAttribute")
        attr.attribute_type = "GEOMETRY"
        attr.attribute_name = INNER_ATTRIBUTE
        links.new(gin.outputs["Eta"], script.inputs["Eta"])
        links.new(gin.outputs["At"], script.inputs["At"])
        links.new(attr.outputs["Fac"], script.inputs["Inner"])
        native = _native_boundary(group, gin, attr)
        switch = nodes.new("ShaderNodeMixShader")  # Fac: the script's OSLActive, 0 where no script runs
        switch.name = switch.label = OSL_SWITCH
        switch.inputs["Fac"].default_value = 0.0
        if "OSLActive" in script.outputs:
            links.new(script.outputs["OSLActive"], switch.inputs["Fac"])
        links.new(native, switch.inputs[1])
        links.new(script.outputs["BSDF"], switch.inputs[2])
        links.new(switch.outputs[0], gout.inputs["Surface"])
        script.location, attr.location, switch.location = (200, 200), (-300, 250), (900, 200)
    links.new(_volume_subgraph(group, gin), gout.inputs["Volume"])
    if kind in SURFACE_GROUPS:
        links.new(_stand_in_subgraph(group, gin), gout.inputs[EEVEE_OUTPUT])
    describe_teeth_sockets(group)
    return group


def new_teeth_material(kind: str, name: str | None = None, scene=None, volume=None, a_t=None,
                       mm_per_unit: float = 1000.0) -> bpy.types.Material:
    """A material on the ``kind`` group; ``volume`` is a core ``VolumeMaterial`` (defaults otherwise)."""
    group = ensure_group(kind, scene)
    surface = "Surface" if kind in SURFACE_GROUPS else None
    mat, node, out = group_material(name or kind, group, MARKER, kind, label=kind, surface=surface, volume="Volume")
    node.inputs["mm per Unit"].default_value = mm_per_unit
    if surface:
        add_eevee_fallback(mat, out, node.outputs[EEVEE_OUTPUT], location=(400, -350), name="EEVEE Output")
    mat.diffuse_color = (*[min(1.0, x) for x in DEFAULTS[kind]["albedo"]], 1.0)  # solid-view colour
    if volume is not None:
        set_volume(mat, volume)
    if a_t is not None:
        set_a_t(mat, a_t)
    return mat


EEVEE_OUTPUT = "EEVEE Surface"  # the surface group's output for EEVEE and Material Preview
STAND_IN_NODE = "EEVEE Stand-in"


def _stand_in_subgraph(group, gin):
    """EEVEE / Material Preview stand-in (the OSL boundary and the volumes are Cycles-only): a Principled BSDF with
    random-walk subsurface scattering, colour = Albedo, radius = 1 / Sigma_t in mm (scaled by 1 / mm per Unit),
    IOR = Eta. Inside the group, so it follows every edit of the material's sliders (returns the shader socket)."""
    nodes, links = group.nodes, group.links
    p = nodes.new("ShaderNodeBsdfPrincipled")
    p.name = p.label = STAND_IN_NODE
    p.inputs["Roughness"].default_value = 0.08
    weight = p.inputs.get("Subsurface Weight") or p.inputs.get("Subsurface")
    if weight is not None:
        weight.default_value = 1.0
    links.new(gin.outputs["Albedo"], p.inputs["Base Color"])
    links.new(gin.outputs["Eta"], p.inputs["IOR"])
    reach = nodes.new("ShaderNodeVectorMath")
    reach.operation = "DIVIDE"
    reach.inputs[0].default_value = (1.0, 1.0, 1.0)
    links.new(gin.outputs["Sigma_t"], reach.inputs[1])
    unit = nodes.new("ShaderNodeMath")
    unit.operation = "DIVIDE"
    unit.inputs[0].default_value = 1.0
    links.new(gin.outputs["mm per Unit"], unit.inputs[1])
    radius = p.inputs.get("Subsurface Radius")
    if radius is not None:
        links.new(reach.outputs[0], radius)
    scale = p.inputs.get("Subsurface Scale")
    if scale is not None:
        links.new(unit.outputs[0], scale)
    reach.location, unit.location, p.location = (300, -900), (300, -1100), (600, -900)
    return p.outputs[0]


def ensure_stand_in(group) -> bool:
    """Give a local Enamel/Gingiva ``group`` of an older file its :data:`EEVEE_OUTPUT` and move every local material
    wearing it from the material's own stand-in (fixed values, set at creation and by fits only) onto it. Returns
    whether it changed anything."""
    kind = group.get(MARKER)
    if kind not in SURFACE_GROUPS or group.library is not None:
        return False
    gout = next((n for n in group.nodes if n.type == "GROUP_OUTPUT"), None)
    gin = next((n for n in group.nodes if n.type == "GROUP_INPUT"), None)
    if gout is None or gin is None:
        return False
    changed = False
    if EEVEE_OUTPUT not in gout.inputs:
        group.interface.new_socket(EEVEE_OUTPUT, in_out="OUTPUT", socket_type="NodeSocketShader")
        group.links.new(_stand_in_subgraph(group, gin), gout.inputs[EEVEE_OUTPUT])
        changed = True
    for mat in bpy.data.materials:
        tree = mat.node_tree
        own = tree.nodes.get(STAND_IN_NODE) if tree is not None and mat.library is None else None
        if own is not None and (own.type != "BSDF_PRINCIPLED"
                                or any(lk.to_node.type != "OUTPUT_MATERIAL" for lk in own.outputs[0].links)):
            continue  # not the stand-in older versions made (an artist's node of that name)
        node = group_node(mat) if own is not None else None
        if node is None or node.node_tree != group or EEVEE_OUTPUT not in node.outputs:
            continue
        for link in list(own.outputs[0].links):
            tree.links.new(node.outputs[EEVEE_OUTPUT], link.to_socket)
        tree.nodes.remove(own)
        changed = True
    return changed


def group_node(mat):
    """The Enamel/Dentin/Gingiva group node of a material (None if it has none)."""
    return _group_node(mat, MARKER)


def set_volume(mat, volume) -> None:
    """Write a core ``VolumeMaterial`` (sigma_t [1/mm], albedo, g1, g2, beta) into the material."""
    node = group_node(mat)
    if node is None:
        raise ValueError(f"material {mat.name!r} has no teeth node group")
    node.inputs["Sigma_t"].default_value = tuple(float(x) for x in volume.sigma_t)
    node.inputs["Albedo"].default_value = (*(float(x) for x in volume.albedo), 1.0)
    node.inputs["G1"].default_value = float(volume.g1)
    node.inputs["G2"].default_value = float(volume.g2)
    node.inputs["Beta"].default_value = float(volume.beta)
    mat.diffuse_color = (*(float(x) for x in volume.albedo), 1.0)
    if node.node_tree is not None:
        ensure_stand_in(node.node_tree)  # a material appended from an older file: EEVEE reads what was just set


def set_a_t(mat, a_t) -> None:
    """a_t as a constant colour (1 x 1 texture) or a packed float image on the UV map (H x W)."""
    node = group_node(mat)
    tex = np.asarray(a_t, dtype=np.float64)
    if tex.ndim == 1:
        tex = tex.reshape(1, 1, -1)
    tree = mat.node_tree
    for old in [n for n in tree.nodes if n.type == "TEX_IMAGE" and n.name == "a_t"]:
        tree.nodes.remove(old)
    if tex.shape[:2] == (1, 1):
        node.inputs["At"].default_value = (*(float(x) for x in tex[0, 0, :3]), 1.0)
        return
    h, w = tex.shape[:2]
    image = bpy.data.images.new(f"{mat.name} a_t", w, h, alpha=False, float_buffer=True)
    image.colorspace_settings.name = "Non-Color"
    rgba = np.ones((h, w, 4), dtype=np.float32)
    rgba[:, :, :3] = tex[:, :, :3]  # row 0 = v = 0, Blender's bottom row: the core's convention
    image.pixels.foreach_set(rgba.ravel())
    image.pack()
    img = tree.nodes.new("ShaderNodeTexImage")
    img.name = img.label = "a_t"
    img.image = image
    img.interpolation = "Linear"
    img.extension = "REPEAT"
    uv = tree.nodes.new("ShaderNodeUVMap")
    tree.links.new(uv.outputs["UV"], img.inputs["Vector"])
    tree.links.new(img.outputs["Color"], node.inputs["At"])
    img.location, uv.location = (-300, 0), (-500, 0)


def new_cavity_material(albedo, name: str = "Oral Cavity") -> bpy.types.Material:
    """Opaque Lambertian proxy of the oral-cavity walls (Sec. 5.5.3)."""
    mat = new_material(name)
    mat[MARKER] = "Cavity"
    bsdf = mat.node_tree.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (*(float(x) for x in albedo), 1.0)
    bsdf.inputs["Roughness"].default_value = 0.0
    mat.node_tree.links.new(bsdf.outputs["BSDF"], material_output(mat).inputs["Surface"])
    mat.diffuse_color = (*(float(x) for x in albedo), 1.0)
    return mat
