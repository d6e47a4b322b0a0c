"""Dentin blend-shape model V = B0 + c . (B - B0)^T (eq. 5.5) with three deformation modes.

The modes deform the enamel-dentin interface along the major axes of the canonical tooth space
(Fig. 5.5): buccal (y), proximal (x, mesiodistal) and occlusal (z). The derivative of the vertices
w.r.t. the coefficients is the constant Delta B = B - B0 (eq. 5.26).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mesh import TriMesh

MODE_NAMES = ("buccal", "proximal", "occlusal")


@dataclass
class DentinBlendShape:
    """``base`` is B0 (a TriMesh), ``deltas`` is Delta B = B - B0 with shape (3 modes, V, 3)."""

    base: TriMesh
    deltas: np.ndarray

    def __post_init__(self) -> None:
        self.deltas = np.asarray(self.deltas, dtype=np.float64)
        if self.deltas.shape != (len(MODE_NAMES), len(self.base.vertices), 3):
            raise ValueError(f"deltas must have shape (3, {len(self.base.vertices)}, 3)")

    def vertices(self, c: np.ndarray) -> np.ndarray:
        """V = B0 + sum_k c_k Delta B_k (eq. 5.5)."""
        return self.base.vertices + np.tensordot(np.asarray(c, dtype=np.float64), self.deltas, axes=1)

    def mesh(self, c: np.ndarray) -> TriMesh:
        return TriMesh(self.vertices(c), self.base.faces, self.base.corner_uv)

    def mode_mesh(self, k: int) -> TriMesh:
        """The fully deformed mode mesh B_k (c = e_k)."""
        return TriMesh(self.base.vertices + self.deltas[k], self.base.faces, self.base.corner_uv)

    def transformed(self, matrix: np.ndarray) -> DentinBlendShape:
        m = np.asarray(matrix, dtype=np.float64)
        return DentinBlendShape(self.base.transformed(m), self.deltas @ m[:3, :3].T)

    def to_dict(self) -> dict:
        return {"base": self.base.to_dict(), "deltas": self.deltas.round(9).tolist(), "modes": list(MODE_NAMES)}

    @classmethod
    def from_dict(cls, d: dict) -> DentinBlendShape:
        return cls(TriMesh.from_dict(d["base"]), np.array(d["deltas"]))


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def canonical_modes(base: TriMesh, crown_height: float, amplitude_mm: float = 1.0) -> np.ndarray:
    """Delta B for the buccal, proximal and occlusal modes in canonical tooth space.

    Tooth space: x mesiodistal, y buccolingual, z along the tooth axis (cemento-enamel junction at
    z = 0, crown up to ``crown_height``). c_k = 1 moves the extreme dentin points outwards by
    ``amplitude_mm`` along the mode's axis; the deformation fades out towards the cervical region so
    that the dentin stays inside the enamel.
    """
    v = base.vertices
    center = 0.5 * (v.max(axis=0) + v.min(axis=0))
    half = 0.5 * (v.max(axis=0) - v.min(axis=0))
    crown = _smoothstep(0.0, 0.5 * crown_height, v[:, 2])
    d = np.zeros((3, len(v), 3))
    d[0, :, 1] = (v[:, 1] - center[1]) / half[1] * amplitude_mm * crown
    d[1, :, 0] = (v[:, 0] - center[0]) / half[0] * amplitude_mm * crown
    top = v[:, 2].max()
    d[2, :, 2] = _smoothstep(0.3 * top, top, v[:, 2]) * amplitude_mm
    return d
