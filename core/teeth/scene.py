"""The teeth scene model (thesis Sec. 5.5): teeth with an enamel shell and a blend-shape dentin
core, gums and a diffuse oral-cavity proxy. Units: millimetres, sigma_t in 1/mm, RGB triples.

* enamel boundary: thin dielectric, reflection F and non-bending transmission a_t (1 - F)
  (eq. 5.1-5.2), eta = 1.631; a_t is a UV texture (1 x 1 = homogeneous).
* enamel and dentin volumes: sigma_t, RGB single-scattering albedo, two-lobe HG phase (eq. 5.3-5.4).
  Transmittance uses the sharp, piecewise-constant sigma_t of the enamel/dentin regions (eq. 5.30).
  At scattering vertices the albedo, the phase parameters *and* sigma_t (in sigma_s = albedo
  sigma_t) are blended with the logistic weight l(q) of the signed distance q to the dentin
  (eq. 5.15-5.21), which makes every path contribution continuous in the dentin shape so that the
  per-path derivatives (eq. 5.25-5.32) need no boundary term. Within about 1 mm of the dentin
  surface this makes sigma_s differ from albedo x (sharp sigma_t), a deliberate smoothing.
* enamel/dentin interface: index-matched, geometry from the blend shapes V = B0 + c (B - B0) (eq. 5.5).
* gums: same parameter types as enamel, eta = 1.33 (Sec. 5.5.3).
* oral cavity: opaque Lambertian proxy with RGB albedo.

Everything serialises to plain JSON (``to_dict`` / ``from_dict`` / ``save_scene`` / ``load_scene``).
"""

from __future__ import annotations

import copy
import json
import os
from dataclasses import dataclass, field

import numpy as np

from .dentin_blend_shapes import DentinBlendShape
from .fresnel import ETA_ENAMEL, ETA_GUMS
from .mesh import TriMesh
from .sigmoid_blend import DEFAULT_SPREAD_MM


def _rgb(x) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.shape != (3,):
        raise ValueError(f"expected an RGB triple, got {x!r}")
    return a


@dataclass
class VolumeMaterial:
    """Homogeneous participating medium (eq. 5.3-5.4): extinction sigma_t [1/mm], albedo, two-lobe HG."""

    sigma_t: np.ndarray
    albedo: np.ndarray
    g1: float = 0.6
    g2: float = -0.2
    beta: float = 0.8

    def __post_init__(self) -> None:
        self.sigma_t = _rgb(self.sigma_t)
        self.albedo = _rgb(self.albedo)
        self.g1, self.g2, self.beta = float(self.g1), float(self.g2), float(self.beta)
        if np.any(self.sigma_t <= 0) or np.any((self.albedo < 0) | (self.albedo >= 1)):
            raise ValueError("need sigma_t > 0 and 0 <= albedo < 1")
        if not (-1 < self.g1 < 1 and -1 < self.g2 < 1 and 0 <= self.beta <= 1):
            raise ValueError("need -1 < g1, g2 < 1 and 0 <= beta <= 1")

    def to_dict(self) -> dict:
        return {"sigma_t": self.sigma_t.tolist(), "albedo": self.albedo.tolist(), "g1": self.g1,
                "g2": self.g2, "beta": self.beta}

    @classmethod
    def from_dict(cls, d: dict) -> VolumeMaterial:
        return cls(d["sigma_t"], d["albedo"], d["g1"], d["g2"], d["beta"])


def _texture(a) -> np.ndarray:
    t = np.asarray(a, dtype=np.float64)
    if t.ndim == 1:
        t = _rgb(t).reshape(1, 1, 3)
    if t.ndim != 3 or t.shape[2] != 3:
        raise ValueError("a_t texture must be (H, W, 3) or an RGB triple")
    return t


@dataclass
class Tooth:
    """One tooth: enamel outer mesh (with UVs), dentin blend shapes, two volumes and a_t texture."""

    name: str
    enamel_mesh: TriMesh
    dentin_shape: DentinBlendShape
    enamel: VolumeMaterial
    dentin: VolumeMaterial
    a_t: np.ndarray = field(default_factory=lambda: np.ones((1, 1, 3)))
    c: np.ndarray = field(default_factory=lambda: np.zeros(3))
    eta: float = ETA_ENAMEL
    kind: str = "incisor"

    def __post_init__(self) -> None:
        self.a_t = _texture(self.a_t)
        self.c = np.asarray(self.c, dtype=np.float64).reshape(3)
        if self.enamel_mesh.corner_uv is None:
            raise ValueError(f"tooth {self.name!r}: the enamel mesh needs UVs for the a_t texture")

    def dentin_vertices(self) -> np.ndarray:
        return self.dentin_shape.vertices(self.c)

    def to_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "eta": self.eta, "enamel_mesh": self.enamel_mesh.to_dict(),
                "dentin_shape": self.dentin_shape.to_dict(), "enamel": self.enamel.to_dict(),
                "dentin": self.dentin.to_dict(), "a_t": self.a_t.tolist(), "c": self.c.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> Tooth:
        return cls(d["name"], TriMesh.from_dict(d["enamel_mesh"]), DentinBlendShape.from_dict(d["dentin_shape"]),
                   VolumeMaterial.from_dict(d["enamel"]), VolumeMaterial.from_dict(d["dentin"]),
                   np.array(d["a_t"]), np.array(d["c"]), d.get("eta", ETA_ENAMEL), d.get("kind", "incisor"))


@dataclass
class Gums:
    mesh: TriMesh
    material: VolumeMaterial
    a_t: np.ndarray = field(default_factory=lambda: np.ones((1, 1, 3)))
    eta: float = ETA_GUMS

    def __post_init__(self) -> None:
        self.a_t = _texture(self.a_t)
        if self.mesh.corner_uv is None:
            raise ValueError("the gums mesh needs UVs for the a_t texture")

    def to_dict(self) -> dict:
        return {"mesh": self.mesh.to_dict(), "material": self.material.to_dict(), "a_t": self.a_t.tolist(),
                "eta": self.eta}

    @classmethod
    def from_dict(cls, d: dict) -> Gums:
        return cls(TriMesh.from_dict(d["mesh"]), VolumeMaterial.from_dict(d["material"]), np.array(d["a_t"]),
                   d.get("eta", ETA_GUMS))


@dataclass
class OralCavity:
    """Opaque Lambertian proxy of the oral-cavity walls (Sec. 5.5.3)."""

    mesh: TriMesh
    albedo: np.ndarray

    def __post_init__(self) -> None:
        self.albedo = _rgb(self.albedo)

    def to_dict(self) -> dict:
        return {"mesh": self.mesh.to_dict(), "albedo": self.albedo.tolist()}

    @classmethod
    def from_dict(cls, d: dict) -> OralCavity:
        return cls(TriMesh.from_dict(d["mesh"]), d["albedo"])


@dataclass
class TeethScene:
    teeth: list[Tooth]
    gums: Gums | None = None
    cavity: OralCavity | None = None
    blend_spread: float = DEFAULT_SPREAD_MM

    def copy(self) -> TeethScene:
        return copy.deepcopy(self)

    def to_dict(self) -> dict:
        return {"format": "material_structures.teeth.scene/1", "blend_spread_mm": self.blend_spread,
                "teeth": [t.to_dict() for t in self.teeth],
                "gums": None if self.gums is None else self.gums.to_dict(),
                "cavity": None if self.cavity is None else self.cavity.to_dict()}

    @classmethod
    def from_dict(cls, d: dict) -> TeethScene:
        return cls([Tooth.from_dict(t) for t in d["teeth"]],
                   None if d.get("gums") is None else Gums.from_dict(d["gums"]),
                   None if d.get("cavity") is None else OralCavity.from_dict(d["cavity"]),
                   d.get("blend_spread_mm", DEFAULT_SPREAD_MM))


def save_scene(scene: TeethScene, path: str | os.PathLike) -> None:
    with open(path, "w") as f:
        json.dump(scene.to_dict(), f)


def load_scene(path: str | os.PathLike) -> TeethScene:
    if not os.path.exists(path):
        raise FileNotFoundError(f"scene file not found: {path}")
    with open(path) as f:
        return TeethScene.from_dict(json.load(f))
