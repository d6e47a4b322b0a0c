"""Procedural, anatomically plausible tooth meshes (incisor, canine, premolar, molar) with UVs.

Each tooth is a closed, watertight enamel surface plus a dentin core B0 (with the three blend-shape
modes of eq. 5.5), built in canonical tooth space: x mesiodistal, y buccolingual (+y buccal),
z along the tooth axis with the cemento-enamel junction (CEJ) at z = 0 and the crown above it.
Dimensions are typical adult crown sizes in mm. The surface is a height-varying superellipse sweep
with an occlusal/incisal relief (incisal edge, canine cusp tip, two premolar cusps, four molar
cusps). UVs: u = azimuth / 2 pi around the tooth axis, v = 0 at the occlusal pole, 1 at the root.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import UserError
from .dentin_blend_shapes import DentinBlendShape, canonical_modes
from .mesh import TriMesh

TOOTH_TYPES = ("incisor", "canine", "premolar", "molar")


@dataclass(frozen=True)
class ToothShape:
    width: float  # mesiodistal crown width (mm)
    depth: float  # buccolingual crown depth (mm)
    crown: float  # crown height above the CEJ (mm)
    root: float  # length of the root stub kept below the CEJ (mm)
    incisal_taper: float  # how thin the crown gets towards the top in y (0..1)
    tip_taper: float  # how narrow it gets towards the top in x (0..1)
    cusps: tuple  # ((x, y, height), ...) in normalised crown coordinates
    exponent: float  # superellipse exponent of the cross-section


SHAPES = {
    "incisor": ToothShape(8.5, 7.0, 10.5, 1.5, 0.8, 0.0, (), 2.6),
    "canine": ToothShape(7.5, 8.0, 10.0, 1.5, 0.55, 0.7, ((0.0, 0.0, 1.2),), 2.4),
    "premolar": ToothShape(7.0, 9.0, 8.5, 1.5, 0.15, 0.1, ((0.0, 0.45, 1.2), (0.0, -0.45, 0.9)), 2.6),
    "molar": ToothShape(
        10.0, 11.0, 7.5, 1.5, 0.1, 0.05, ((0.45, 0.45, 1.1), (-0.45, 0.45, 1.0), (0.45, -0.45, 0.9),
                                          (-0.45, -0.45, 0.9)), 3.2),
}


@dataclass
class ToothGeometry:
    """Enamel outer surface and dentin blend-shape model of one tooth (canonical tooth space)."""

    kind: str
    enamel: TriMesh
    dentin: DentinBlendShape
    crown_height: float

    def transformed(self, matrix: np.ndarray) -> ToothGeometry:
        return ToothGeometry(self.kind, self.enamel.transformed(matrix), self.dentin.transformed(matrix),
                             self.crown_height)


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _sweep(shape: ToothShape, n_u: int, n_v: int, inset_side: float, inset_top: float,
           cusp_scale: float) -> TriMesh:
    """Closed sweep surface: ring k (1..n_v) at polar parameter v, poles at top and bottom."""
    z_top = shape.crown - inset_top
    z_bot = -shape.root + 0.5 * inset_side
    v = np.linspace(0.0, 1.0, n_v + 2)[1:-1]
    phi = np.linspace(0.0, 2.0 * np.pi, n_u, endpoint=False)
    vv, pp = np.meshgrid(v, phi, indexing="ij")  # (n_v, n_u)
    z = z_top - (z_top - z_bot) * 0.5 * (1.0 - np.cos(np.pi * vv))
    h = np.clip(z / shape.crown, -1.0, 1.0)  # normalised height, < 0 in the root
    a_max, b_max = 0.5 * shape.width, 0.5 * shape.depth
    bulge = np.where(h >= 0, 0.82 + 0.18 * np.sin(np.pi * np.clip(h, 0, 1) * 0.9), 0.82 + 0.25 * h)
    a = a_max * bulge * (1.0 - shape.tip_taper * _smoothstep(0.55, 1.0, h))
    b = b_max * bulge * (1.0 - shape.incisal_taper * _smoothstep(0.3, 1.0, h))
    side = inset_side * (0.3 / 1.0 + 0.7 * _smoothstep(0.0, 0.5, h))
    a = np.maximum(a - side, 0.3)
    b = np.maximum(b - side, 0.3)
    top_round = 0.35 if shape.cusps and shape.tip_taper < 0.5 else 0.6
    s = np.where(vv < 0.5, np.sin(np.pi * vv) ** top_round, np.sin(np.pi * vv) ** 0.5)
    e = 2.0 / shape.exponent
    cx = np.sign(np.cos(pp)) * np.abs(np.cos(pp)) ** e
    cy = np.sign(np.sin(pp)) * np.abs(np.sin(pp)) ** e
    x = a * s * cx
    y = b * s * cy
    top_w = 1.0 - _smoothstep(0.0, 0.3, vv)
    relief = np.zeros_like(z)
    xn, yn = s * cx, s * cy
    for (px, py, ch) in shape.cusps:
        relief += ch * np.exp(-((xn - px) ** 2 + (yn - py) ** 2) / 0.12)
    if shape.cusps:
        relief -= relief.max() * 0.35
    z = z + cusp_scale * relief * top_w
    verts = np.concatenate(
        [[[0.0, 0.0, z_top + cusp_scale * (relief[0].mean() if shape.cusps else 0.0)]],
         np.stack([x, y, z], axis=-1).reshape(-1, 3),
         [[0.0, 0.0, z_bot - 0.3]]]
    )
    ring = lambda k, j: 1 + k * n_u + (j % n_u)  # noqa: E731
    top, bot = 0, 1 + n_v * n_u
    faces, uvs = [], []
    du = 1.0 / n_u
    vs = np.concatenate([[0.0], v, [1.0]])
    for j in range(n_u):
        faces.append((top, ring(0, j + 1), ring(0, j)))
        uvs.append(((j + 0.5) * du, 0.0, (j + 1) * du, vs[1], j * du, vs[1]))
    for k in range(n_v - 1):
        for j in range(n_u):
            a0, a1, b0, b1 = ring(k, j), ring(k, j + 1), ring(k + 1, j), ring(k + 1, j + 1)
            u0, u1, v0, v1 = j * du, (j + 1) * du, vs[k + 1], vs[k + 2]
            faces.append((a0, a1, b1))
            uvs.append((u0, v0, u1, v0, u1, v1))
            faces.append((a0, b1, b0))
            uvs.append((u0, v0, u1, v1, u0, v1))
    for j in range(n_u):
        faces.append((bot, ring(n_v - 1, j), ring(n_v - 1, j + 1)))
        uvs.append(((j + 0.5) * du, 1.0, j * du, vs[-2], (j + 1) * du, vs[-2]))
    faces = np.array(faces)
    mesh = TriMesh(verts, faces, np.array(uvs).reshape(-1, 3, 2))
    if mesh.volume() < 0:  # make normals point outwards
        mesh = TriMesh(verts, faces[:, [0, 2, 1]], mesh.corner_uv[:, [0, 2, 1]])
    return mesh


def make_tooth(kind: str = "incisor", resolution: int = 40, enamel_occlusal_mm: float = 1.8,
               enamel_side_mm: float = 1.1) -> ToothGeometry:
    """Procedural tooth of ``kind`` (incisor, canine, premolar, molar) in canonical tooth space.

    ``resolution`` is the number of vertices around the enamel; the dentin uses 3/4 of it.
    The enamel thickness is ``enamel_occlusal_mm`` at the top and ``enamel_side_mm`` on the crown's
    sides, thinning to 0.3 mm at the CEJ.
    """
    if kind not in SHAPES:
        raise UserError(f"unknown tooth kind {kind!r}; use one of {', '.join(TOOTH_TYPES)}")
    if resolution < 8:
        raise UserError("resolution must be >= 8")
    shape = SHAPES[kind]
    n_v = max(6, int(round(resolution * 0.7)))
    enamel = _sweep(shape, resolution, n_v, 0.0, 0.0, 1.0)
    nd = max(8, int(round(resolution * 0.75)))
    base = _sweep(shape, nd, max(6, int(round(nd * 0.7))), enamel_side_mm, enamel_occlusal_mm, 0.6)
    dentin = DentinBlendShape(base, canonical_modes(base, shape.crown))
    return ToothGeometry(kind, enamel, dentin, shape.crown)
