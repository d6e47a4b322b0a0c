"""Tooth object pairs (enamel shell + dentin core) with the dentin blend modes as shape keys.

The dentin core is the blend-shape model V = B0 + sum_k c_k (B_k - B0) (eq. 5.5): Basis = B0 and one
relative shape key per mode (buccal, proximal, occlusal) whose value is c_k, so Blender evaluates
exactly eq. 5.5 in the viewport and in Cycles.

Cycles adds up the coefficients of nested volumes, so the dentin cannot simply sit inside a closed
enamel volume. The enamel object is therefore a *shell*: its outer enamel surface plus the dentin
surface B0 with reversed winding (face attribute ``ms_inner`` = 1, fully transparent in the Enamel
shader), carrying the same three shape keys on those inner vertices. The dentin object is B0 moved
inwards by ``GAP_MM`` along the vertex normals, so the two surfaces never coincide (a coincident pair
would be missed by Cycles' ray offsetting). The air gap changes a path's optical depth by at most
sigma_t GAP_MM / cos per crossing (2e-4 mm: below 1e-3 for sigma_t < 5/mm at 60 degrees).

Mesh coordinates are in millimetres (the core's units); objects get scale 1 / mm_per_unit. A tooth made
from a mesh object has that object's world scale baked into its millimetre vertices and the object's
world location and rotation.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ...core.teeth.blend_spread import DEFAULT_SPREAD_MM
from ...core.teeth.dentin_blend_shapes import MODE_NAMES
from ...core.teeth.tooth_from_surface import tooth_from_enamel_surface, vertex_normals
from .blend_volume import ensure_blend
from .materials import INNER_ATTRIBUTE

GAP_MM = 2e-4
UV_NAME = "UVMap"


def make_mesh(name: str, vertices: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray | None = None,
              inner: np.ndarray | None = None, smooth: bool = False) -> bpy.types.Mesh:
    """A Blender mesh from triangles; per-corner UVs and an optional face attribute ``ms_inner``."""
    me = bpy.data.meshes.new(name)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    me.vertices.add(len(v))
    me.vertices.foreach_set("co", v.astype(np.float32).ravel())
    me.loops.add(3 * len(f))
    me.loops.foreach_set("vertex_index", f.astype(np.int32).ravel())
    me.polygons.add(len(f))
    me.polygons.foreach_set("loop_start", (3 * np.arange(len(f))).astype(np.int32))
    me.update(calc_edges=True)
    uv = me.uv_layers.new(name=UV_NAME)
    if corner_uv is not None:
        uv.data.foreach_set("uv", np.asarray(corner_uv, dtype=np.float32).reshape(-1))
    if inner is not None:
        attr = me.attributes.new(INNER_ATTRIBUTE, "FLOAT", "FACE")
        attr.data.foreach_set("value", np.asarray(inner, dtype=np.float32))
    me.polygons.foreach_set("use_smooth", np.full(len(f), smooth, dtype=bool))
    me.validate()
    me.update()
    return me


def add_mode_keys(obj, deltas: np.ndarray, rows: np.ndarray | None = None, values=(0.0, 0.0, 0.0)) -> None:
    """Basis + one relative shape key per dentin mode; ``rows`` selects the vertices the deltas move."""
    obj.shape_key_add(name="Basis", from_mix=False)
    base = np.empty(len(obj.data.vertices) * 3, dtype=np.float32)
    obj.data.vertices.foreach_get("co", base)
    base = base.reshape(-1, 3).astype(np.float64)
    for k, name in enumerate(MODE_NAMES):
        kb = obj.shape_key_add(name=name, from_mix=False)
        co = base.copy()
        if rows is None:
            co += deltas[k]
        else:
            co[rows] += deltas[k]
        kb.data.foreach_set("co", co.astype(np.float32).ravel())
        kb.slider_min, kb.slider_max = -1.0, 1.0
        kb.value = float(values[k])


def key_values(obj) -> np.ndarray:
    keys = obj.data.shape_keys
    return np.array([keys.key_blocks[name].value for name in MODE_NAMES])


def evaluated_vertices(obj, depsgraph=None) -> np.ndarray:
    """Vertex positions of the evaluated (shape-keyed) mesh, in mesh coordinates."""
    depsgraph = depsgraph or bpy.context.evaluated_depsgraph_get()
    ev = obj.evaluated_get(depsgraph)
    me = ev.to_mesh()
    co = np.empty(len(me.vertices) * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    return co.reshape(-1, 3).astype(np.float64)


def build_tooth_pair(name: str, enamel_mesh, dentin_shape, c=(0.0, 0.0, 0.0), enamel_mat=None, dentin_mat=None,
                     collection=None, mm_per_unit: float = 1000.0, kind: str = "custom", tooth_name: str = "",
                     smooth: bool = False, spread: float = DEFAULT_SPREAD_MM):
    """Enamel shell + dentin core objects from core meshes (``TriMesh`` + ``DentinBlendShape``) and, with both
    materials, the tooth's Blend Volume of enamel/dentin blend ``spread`` (mm; ``blend_volume``)."""
    collection = collection or bpy.context.scene.collection
    ev, ef, euv = enamel_mesh.vertices, enamel_mesh.faces, enamel_mesh.corner_uv
    base = dentin_shape.base
    bv, bf = base.vertices, base.faces
    buv = base.corner_uv if base.corner_uv is not None else np.zeros((len(bf), 3, 2))
    shell_v = np.concatenate([ev, bv])
    shell_f = np.concatenate([ef, bf[:, [0, 2, 1]] + len(ev)])
    shell_uv = np.concatenate([euv if euv is not None else np.zeros((len(ef), 3, 2)), buv[:, [0, 2, 1]]])
    inner = np.concatenate([np.zeros(len(ef)), np.ones(len(bf))])
    me_e = make_mesh(f"{name} Enamel", shell_v, shell_f, shell_uv, inner, smooth=smooth)
    core_v = bv - GAP_MM * vertex_normals(bv, bf)
    me_d = make_mesh(f"{name} Dentin", core_v, bf, buv, smooth=smooth)
    enamel = bpy.data.objects.new(f"{name} Enamel", me_e)
    dentin = bpy.data.objects.new(f"{name} Dentin", me_d)
    collection.objects.link(enamel)
    collection.objects.link(dentin)
    dentin.parent = enamel
    s = 1.0 / mm_per_unit
    enamel.scale = (s, s, s)
    rows = np.arange(len(ev), len(ev) + len(bv))
    add_mode_keys(enamel, dentin_shape.deltas, rows, c)
    add_mode_keys(dentin, dentin_shape.deltas, None, c)
    if enamel_mat is not None:
        me_e.materials.append(enamel_mat)
    if dentin_mat is not None:
        me_d.materials.append(dentin_mat)
    for obj, role in ((enamel, "ENAMEL"), (dentin, "DENTIN")):
        st = obj.ms_tooth
        st.role = role
        st.kind = kind
        st.tooth_name = tooth_name or name
        st.mm_per_unit = mm_per_unit
    enamel.ms_tooth.partner = dentin
    dentin.ms_tooth.partner = enamel
    enamel.ms_tooth.set_coefficients(c)
    if enamel_mat is not None and dentin_mat is not None:
        ensure_blend(enamel, spread, collection)
    return enamel, dentin


def world_split(obj) -> tuple[Matrix, Matrix]:
    """``obj.matrix_world`` split into a placement (world location and rotation, no scale) and the rest of
    its linear part (scale, the parents' scale and any shear, in the object's rotated frame):
    ``matrix_world = placement @ rest``. The rest is what a tooth baked from the mesh keeps in its vertices."""
    mw = obj.matrix_world
    loc, rot, _ = mw.decompose()
    r3 = rot.to_matrix()
    rest = r3.transposed() @ mw.to_3x3()
    return Matrix.LocRotScale(loc, rot, None), rest.to_4x4()


def placement_from_mesh_object(obj, mm_per_unit: float = 1000.0) -> Matrix:
    """World matrix of a tooth made from ``obj`` by ``tooth_from_mesh_object``: the source's world location
    and rotation, scale 1 / mm_per_unit (the tooth's mesh is in millimetres)."""
    placement, _ = world_split(obj)
    s = 1.0 / float(mm_per_unit)
    return placement @ Matrix.Diagonal((s, s, s, 1.0))


def tooth_from_mesh_object(obj, enamel_occlusal_mm: float = 1.8, enamel_side_mm: float = 1.1,
                           mm_per_unit: float = 1000.0) -> tuple:
    """Core ``TriMesh`` + ``DentinBlendShape`` from an arbitrary closed mesh object (its local frame is taken
    as the canonical tooth space: z along the tooth axis, crown up). B0 is the enamel surface moved
    inwards along the vertex normals by the enamel thickness (thicker towards the occlusal end).

    The vertices are in millimetres at the size the object is seen: its world scale (parents included;
    ``world_split``) is baked in once. Placed with ``placement_from_mesh_object`` the tooth's enamel surface
    lies exactly on the source's surface. ``obj.matrix_world`` must be up to date (a depsgraph update after
    moving it from Python)."""
    me = obj.data
    me.calc_loop_triangles()
    tris = np.empty(len(me.loop_triangles) * 3, dtype=np.int32)
    me.loop_triangles.foreach_get("vertices", tris)
    loops = np.empty(len(me.loop_triangles) * 3, dtype=np.int32)
    me.loop_triangles.foreach_get("loops", loops)
    co = np.empty(len(me.vertices) * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    _, rest = world_split(obj)
    v = co.reshape(-1, 3).astype(np.float64) @ (np.array(rest.to_3x3()) * float(mm_per_unit)).T
    f = tris.reshape(-1, 3).astype(np.int64)
    corner_uv = None
    if me.uv_layers:
        uv = np.empty(len(me.loops) * 2, dtype=np.float32)
        me.uv_layers.active.data.foreach_get("uv", uv)
        corner_uv = uv.reshape(-1, 2)[loops.reshape(-1, 3)].astype(np.float64)
    # a surface that is not closed: a UserError (a ValueError), which the operators report in one line
    return tooth_from_enamel_surface(v, f, corner_uv, enamel_occlusal_mm, enamel_side_mm, name=obj.name)
