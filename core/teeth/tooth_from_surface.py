"""A tooth of the model (sec. 5.3) from a closed enamel surface, such as a segmented intra-oral or micro-CT scan.

The enamel surface is the scan as it is (millimetres, the tooth's frame: z along the tooth axis, crown up). The
dentin starts as B0, the enamel surface moved inwards along its area-weighted vertex normals by the enamel
thickness, thicker towards the occlusal end:

    d(h) = d_side + (d_occlusal - d_side) h^4,   h = (z - z_min) / (z_max - z_min),

with the thesis' three deformation modes Delta B_k of B0 (eq. 5.5; ``dentin_blend_shapes.canonical_modes``), so
the fit can move the dentin. The default thicknesses are the enamel's typical 1.8 mm at the incisal edge and 1.1
mm on the labial side. This is what the add-on's **From Mesh** does with a Blender mesh.
"""

from __future__ import annotations

import numpy as np

from ..errors import UserError
from .dentin_blend_shapes import DentinBlendShape, canonical_modes
from .mesh import TriMesh


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (outward for counter-clockwise faces)."""
    t = vertices[faces]
    fn = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    vn = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-30)


def cylindrical_uv(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Per-corner UVs for a surface that has none: u the angle about the tooth axis, v down from the top."""
    c = vertices.mean(axis=0)
    u = (np.arctan2(vertices[:, 1] - c[1], vertices[:, 0] - c[0]) / (2 * np.pi)) % 1.0
    w = (vertices[:, 2].max() - vertices[:, 2]) / max(np.ptp(vertices[:, 2]), 1e-9)
    return np.stack([u, w], axis=1)[faces]


def tooth_from_enamel_surface(vertices_mm: np.ndarray, faces: np.ndarray, corner_uv: np.ndarray | None = None,
                              enamel_occlusal_mm: float = 1.8, enamel_side_mm: float = 1.1,
                              name: str = "surface") -> tuple[TriMesh, DentinBlendShape]:
    """The enamel ``TriMesh`` and the ``DentinBlendShape`` (B0 and its three modes) of a tooth whose enamel is the
    closed triangle surface (``vertices_mm`` (V, 3), ``faces`` (F, 3), optional per-corner UVs (F, 3, 2), else
    ``cylindrical_uv``). Faces wound inwards are turned outwards. A surface that is not closed is a
    ``UserError`` naming ``name``."""
    v = np.asarray(vertices_mm, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise UserError(f"'{name}': expected vertices (V, 3) and triangles (F, 3)")
    if not np.all(np.isfinite(v)):
        raise UserError(f"'{name}': a vertex is not finite")
    corner_uv = cylindrical_uv(v, f) if corner_uv is None else np.asarray(corner_uv, dtype=np.float64)
    enamel = TriMesh(v, f, corner_uv)
    if not enamel.is_watertight():
        raise UserError(f"'{name}' is not a closed (watertight) triangle mesh")
    if enamel.volume() < 0:
        f, corner_uv = f[:, [0, 2, 1]], corner_uv[:, [0, 2, 1]]
        enamel = TriMesh(v, f, corner_uv)
    thinnest = float(np.ptp(v, axis=0).min())
    if thinnest < 2.0 * enamel_side_mm:  # the dentin (the surface moved inwards by the enamel) would turn inside out
        raise UserError(f"'{name}' is {thinnest:.2g} mm across at its thinnest, less than twice the enamel "
                        f"({2.0 * enamel_side_mm:.2g} mm): flat or collapsed, or not at a tooth's size (a tooth is "
                        "5-12 mm across; check the scene's unit scale)")
    z = v[:, 2]
    h = np.clip((z - z.min()) / max(np.ptp(z), 1e-9), 0.0, 1.0)
    thickness = enamel_side_mm + (enamel_occlusal_mm - enamel_side_mm) * h ** 4
    base = TriMesh(v - thickness[:, None] * vertex_normals(v, f), f, corner_uv)
    shifted = TriMesh(base.vertices - np.array([0.0, 0.0, z.min()]), f, corner_uv)  # CEJ-ish at z = 0
    return enamel, DentinBlendShape(base, canonical_modes(shifted, float(np.ptp(z))))
