"""Triangle meshes with per-corner UVs; PLY/OBJ loading and saving (via trimesh)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import MissingFileError, UserError


@dataclass
class TriMesh:
    """``vertices`` (V, 3) float64 in mm, ``faces`` (F, 3) int64 (counter-clockwise = outward normal),
    ``corner_uv`` (F, 3, 2) per-corner UVs or None."""

    vertices: np.ndarray
    faces: np.ndarray
    corner_uv: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64).reshape(-1, 3)
        self.faces = np.asarray(self.faces, dtype=np.int64).reshape(-1, 3)
        if self.corner_uv is not None:
            self.corner_uv = np.asarray(self.corner_uv, dtype=np.float64).reshape(-1, 3, 2)
            if len(self.corner_uv) != len(self.faces):
                raise UserError("corner_uv must have one (3, 2) entry per face")
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise UserError("face index out of range")

    def triangles(self) -> np.ndarray:
        return self.vertices[self.faces]

    def transformed(self, matrix: np.ndarray) -> TriMesh:
        """Copy with vertices mapped by a 4 x 4 affine ``matrix``."""
        m = np.asarray(matrix, dtype=np.float64)
        v = self.vertices @ m[:3, :3].T + m[:3, 3]
        return TriMesh(v, self.faces.copy(), None if self.corner_uv is None else self.corner_uv.copy())

    def is_watertight(self) -> bool:
        edges = np.sort(self.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        _, counts = np.unique(edges, axis=0, return_counts=True)
        return bool(np.all(counts == 2))

    def volume(self) -> float:
        t = self.triangles()
        return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum() / 6.0)

    def to_dict(self) -> dict:
        d = {"vertices": self.vertices.round(9).tolist(), "faces": self.faces.tolist()}
        if self.corner_uv is not None:
            d["corner_uv"] = self.corner_uv.round(9).tolist()
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TriMesh:
        uv = d.get("corner_uv")
        return cls(np.array(d["vertices"]), np.array(d["faces"]), None if uv is None else np.array(uv))


def volume_problem(mesh: TriMesh) -> str | None:
    """Why ``mesh`` cannot bound a volume the path tracer enters and leaves, or None: vertices that are NaN or
    infinite, no triangles, an edge not shared by exactly two triangles (a hole: not closed; three or more:
    not manifold), neighbours that disagree on which side is out, or faces that point inwards."""
    v, f = mesh.vertices, mesh.faces
    if len(f) == 0:
        return "has no triangles"
    if not np.isfinite(v).all():
        return f"has {int((~np.isfinite(v)).any(axis=1).sum())} vertices that are NaN or infinite"
    directed = f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    if np.any(directed[:, 0] == directed[:, 1]) or np.any(f[:, 0] == f[:, 2]):
        return "has triangles that repeat a vertex"
    edges, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    if np.any(counts == 1):
        return f"is not closed ({int((counts == 1).sum())} edges belong to one triangle only)"
    if np.any(counts > 2):
        return f"is not manifold ({int((counts > 2).sum())} edges are shared by three or more triangles)"
    _, once = np.unique(directed, axis=0, return_counts=True)
    if np.any(once > 1):
        return f"is not consistently oriented ({int((once > 1).sum())} edges run the same way in both triangles)"
    if mesh.volume() <= 0:
        return "has its faces pointing inwards (negative volume)"
    return None


def check_volume_mesh(mesh: TriMesh, what: str) -> None:
    """Refuse a mesh that cannot bound a volume (``volume_problem``), naming it by ``what``."""
    problem = volume_problem(mesh)
    if problem is not None:
        raise UserError(f"{what} {problem}: a volume needs a closed, manifold, outward-facing mesh")


def load_mesh(path: str | os.PathLike) -> TriMesh:
    """Load a PLY or OBJ triangle mesh (UVs kept when the file has per-vertex UVs)."""
    import trimesh

    path = os.fspath(path)
    if not os.path.exists(path):
        raise MissingFileError(f"mesh file not found: {path}", path)
    if not path.lower().endswith((".ply", ".obj")):
        raise UserError(f"unsupported mesh format (use .ply or .obj): {path}")
    try:
        m = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many kinds on a malformed file
        raise UserError(f"{path}: not a readable mesh ({type(exc).__name__}: {exc})") from exc
    v, f = np.asarray(getattr(m, "vertices", np.zeros((0, 3))), dtype=np.float64), np.asarray(
        getattr(m, "faces", np.zeros((0, 3))))
    if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
        raise UserError(f"{path}: no triangles")
    if not np.isfinite(v).all():
        raise UserError(f"{path}: {int((~np.isfinite(v)).any(axis=1).sum())} vertices are NaN or infinite")
    if f.min() < 0 or f.max() >= len(v):
        raise UserError(f"{path}: faces refer to vertices that do not exist")
    uv = getattr(getattr(m, "visual", None), "uv", None)
    corner_uv = None if uv is None or len(uv) != len(v) else np.asarray(uv)[f]
    return TriMesh(v, f, corner_uv)


def save_mesh(mesh: TriMesh, path: str | os.PathLike) -> None:
    """Write ``mesh`` as PLY or OBJ (per-corner UVs are written to OBJ as split vertices)."""
    import trimesh

    path = os.fspath(path)
    if mesh.corner_uv is not None and path.lower().endswith(".obj"):
        v = mesh.vertices[mesh.faces].reshape(-1, 3)
        f = np.arange(len(v)).reshape(-1, 3)
        m = trimesh.Trimesh(v, f, process=False)
        m.visual = trimesh.visual.TextureVisuals(uv=mesh.corner_uv.reshape(-1, 2))
    else:
        m = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    m.export(path)
