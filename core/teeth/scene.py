"""The teeth scene model (thesis Sec. 5.5): teeth with an enamel shell and a blend-shape dentin
core, gums and a diffuse oral-cavity proxy. Units: millimetres, sigma_t in 1/mm, RGB triples.

* enamel boundary: thin dielectric, reflection F and non-bending transmission a_t (1 - F)
  (eq. 5.1-5.2), eta = 1.631; a_t is a UV texture (1 x 1 = homogeneous).
* enamel and dentin volumes: sigma_t, RGB single-scattering albedo, two-lobe HG phase (eq. 5.3-5.4).
  The extinction is piecewise constant: the sharp sigma_t of the enamel/dentin regions, in the
  transmittance (eq. 5.30) and at scattering vertices alike. At a scattering vertex the albedo and the
  phase parameters are blended with the logistic weight l(q) of the signed distance q to the dentin
  (eq. 5.15-5.21): sigma_s = albedo_mix sigma_t, so sigma_s <= sigma_t everywhere (a valid medium, which
  Cycles renders without a heavy tail: ``addon/teeth/blend_volume.py``).
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

from ..errors import MissingFileError, UserError
from ..json_schema import check as check_schema
from .dentin_blend_shapes import DentinBlendShape
from .fresnel import ETA_ENAMEL, ETA_GUMS
from .mesh import TriMesh, check_volume_mesh
from .sigmoid_blend import DEFAULT_SPREAD_MM

SCENE_FORMAT = "material_structures.teeth.scene/1"


def _rgb(x) -> np.ndarray:
    # a copy: a scene owns its values (a shared default edited in place would change every scene made from it)
    a = np.array(x, dtype=np.float64).reshape(-1)
    if a.size == 1:
        a = np.repeat(a, 3)
    if a.shape != (3,):
        raise UserError(f"expected an RGB triple, got {x!r}")
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
        if not (np.all(self.sigma_t > 0) and np.all(np.isfinite(self.sigma_t))
                and np.all((self.albedo >= 0) & (self.albedo < 1))):
            raise UserError("need sigma_t > 0 and 0 <= albedo < 1")
        if not (-1 < self.g1 < 1 and -1 < self.g2 < 1 and 0 <= self.beta <= 1):
            raise UserError("need -1 < g1, g2 < 1 and 0 <= beta <= 1")

    def to_dict(self) -> dict:
        return {"sigma_t": self.sigma_t.tolist(), "albedo": self.albedo.tolist(), "g1": self.g1,
                "g2": self.g2, "beta": self.beta}

    @classmethod
    def from_dict(cls, d: dict) -> VolumeMaterial:
        return cls(d["sigma_t"], d["albedo"], d["g1"], d["g2"], d["beta"])


def _texture(a) -> np.ndarray:
    t = np.array(a, dtype=np.float64)  # its own copy (see _rgb)
    if t.ndim == 1:
        t = _rgb(t).reshape(1, 1, 3)
    if t.ndim != 3 or t.shape[2] != 3:
        raise UserError("a_t texture must be (H, W, 3) or an RGB triple")
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
        # the tooth's own media: teeth made from one material (the synthetic truth, a library shade) must not
        # share it, or editing one tooth's (a fit, a test) edits them all and every scene made from it later
        self.enamel, self.dentin = copy.deepcopy(self.enamel), copy.deepcopy(self.dentin)
        self.a_t = _texture(self.a_t)
        self.c = np.array(self.c, dtype=np.float64).reshape(3)
        if self.enamel_mesh.corner_uv is None:
            raise UserError(f"tooth {self.name!r}: the enamel mesh needs UVs for the a_t texture")

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
        self.material = copy.deepcopy(self.material)  # its own (see Tooth)
        self.a_t = _texture(self.a_t)
        if self.mesh.corner_uv is None:
            raise UserError("the gums mesh needs UVs for the a_t texture")

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
        return {"format": SCENE_FORMAT, "blend_spread_mm": self.blend_spread,
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
    """The scene of a ``scene.json``; a file that is not one (not JSON, a field missing or of the wrong kind, a
    mesh that cannot bound a volume) is refused in one line naming the file and the field."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise MissingFileError(f"scene file not found: {path}", path)
    if os.path.isdir(path):
        raise UserError(f"{path}: a folder, not a scene file (scene.json)")
    try:
        with open(path, encoding="utf-8") as f:
            d = json.load(f)
    except ValueError as exc:  # not JSON, or not text
        raise UserError(f"{path}: not a JSON file ({exc})") from None
    return scene_from_dict(d, path)


def _part(source: str, where: str, build, d):
    """``build(d)``, with any complaint about ``d`` said as ``SOURCE: WHERE ...``."""
    if not isinstance(d, dict):
        raise UserError(f"{source}: {where} is not a JSON object")
    try:
        return build(d)
    except KeyError as exc:
        raise UserError(f"{source}: {where} lacks the field {exc.args[0]!r}") from None
    except UserError as exc:
        raise UserError(f"{source}: {where}: {exc}") from None
    except (TypeError, ValueError, AttributeError, IndexError) as exc:
        raise UserError(f"{source}: {where} holds a field of the wrong kind ({exc})") from None


def _finite_tooth(d: dict) -> Tooth:
    t = Tooth.from_dict(d)
    t.name, t.eta = str(t.name), float(t.eta)
    if not (np.isfinite(t.a_t).all() and np.isfinite(t.c).all() and np.isfinite(t.dentin_shape.deltas).all()):
        raise UserError("holds a_t, c or dentin deltas that are NaN or infinite")
    if not 1.0 <= t.eta < 4.0:
        raise UserError(f"eta must be a refractive index in [1, 4), got {t.eta}")
    return t


def scene_from_dict(d, source: str = "scene") -> TeethScene:
    """``TeethScene.from_dict`` for a scene a user gave (``source`` names it in errors): every field checked,
    and every mesh that bounds a volume (enamel, dentin, gums) closed, manifold and finite."""
    # core/schemas/teeth-scene.schema.json: the fields, their kinds, sizes and ranges; below what it cannot say
    check_schema(d, "teeth-scene", source)
    teeth = []
    names = [t["name"] for t in d["teeth"]]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:  # the fit's parameters, its report and the Blender panel find a tooth by its name
        raise UserError(f"{source}: two teeth are named {twice[0]!r}; every tooth needs a name of its own")
    for k, t in enumerate(d["teeth"]):
        tooth = _part(source, f"teeth[{k}]", _finite_tooth, t)
        check_volume_mesh(tooth.enamel_mesh, f"{source}: teeth[{k}] ({tooth.name}): the enamel mesh")
        check_volume_mesh(tooth.dentin_shape.base, f"{source}: teeth[{k}] ({tooth.name}): the dentin mesh")
        teeth.append(tooth)
    gums = None if d.get("gums") is None else _part(source, "gums", Gums.from_dict, d["gums"])
    if gums is not None:
        check_volume_mesh(gums.mesh, f"{source}: the gums mesh")
    cavity = None if d.get("cavity") is None else _part(source, "cavity", OralCavity.from_dict, d["cavity"])
    if cavity is not None and not np.isfinite(cavity.mesh.vertices).all():
        raise UserError(f"{source}: the cavity mesh has vertices that are NaN or infinite")
    spread = d.get("blend_spread_mm", DEFAULT_SPREAD_MM)
    if isinstance(spread, bool) or not isinstance(spread, (int, float)) or not np.isfinite(spread) or spread <= 0:
        raise UserError(f"{source}: blend_spread_mm must be a number > 0, got {spread!r}")
    return TeethScene(teeth, gums, cavity, float(spread))
