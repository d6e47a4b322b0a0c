"""Flat parameter vectors of a scene (the x of eq. 5.6) and the optimiser's dual domains.

Physical parameters (what the path tracer differentiates) are laid out by ``ParamLayout``; the
optimiser works on transformed values: xi = log sigma_t (eq. 5.24), kappa = log10(1 - albedo)
(eq. 5.22); the others are used directly. The optimiser's steps are projected onto the valid ranges
(``optimiser_bounds``), so a parameter at a bound moves off it as soon as its gradient turns.

The forward lobe g1 of enamel and dentin keeps to the dental literature's range (``TOOTH_G1_RANGE``, the
span of the literature search, thesis Sec. 5.7): a capture leaves the phase function open along the similarity
relation, and without the bound the fit of a forward-scattering dentin (g1 0.65) slid to g1 0.13, which
mispredicted grazing lights by 17 % (docs/teeth-fit.md, "The forward lobe keeps to the literature's range").
The gums keep the phase function's whole range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .parameterisation import albedo_from_kappa, dalbedo_dkappa, dsigma_dxi, kappa_from_albedo
from .scene import TeethScene, VolumeMaterial

# albedo and rho stay above 0: the path tracer weighs paths in log space (log albedo, log rho), and a
# zero there makes the derivatives inf x 0 = NaN (a fit whose steps crossed zero got NaN parameters)
RANGES = {"sigma_t": (1e-3, 1e3), "albedo": (1e-4, 0.999), "g": (-0.9, 0.95), "beta": (0.0, 1.0),
          "a_t": (0.02, 1.0), "c": (-0.8, 0.8), "rho": (1e-3, 0.99)}
# g1 of enamel and dentin: the range the dental literature reports (the literature search's g values span it)
TOOTH_G1_RANGE = (0.3, 0.9)
RANGES["tooth_g1"] = TOOTH_G1_RANGE


@dataclass(frozen=True)
class Entry:
    name: str
    start: int
    size: int
    kind: str  # sigma_t | albedo | g | tooth_g1 | beta | a_t | c | rho


class ParamLayout:
    """Ordered named slices of the physical parameter vector of a scene."""

    def __init__(self, scene: TeethScene):
        self.entries: list[Entry] = []
        self._index: dict[str, Entry] = {}
        for t in scene.teeth:
            for part in ("enamel", "dentin"):
                self._volume(f"{t.name}.{part}", g1_kind="tooth_g1")
            self._add(f"{t.name}.a_t", t.a_t.size, "a_t")
            self._add(f"{t.name}.c", 3, "c")
        if scene.gums is not None:
            self._volume("gums")
            self._add("gums.a_t", scene.gums.a_t.size, "a_t")
        if scene.cavity is not None:
            self._add("cavity.albedo", 3, "rho")
        self.size = sum(e.size for e in self.entries)

    def _volume(self, prefix: str, g1_kind: str = "g") -> None:
        self._add(f"{prefix}.sigma_t", 3, "sigma_t")
        self._add(f"{prefix}.albedo", 3, "albedo")
        self._add(f"{prefix}.g1", 1, g1_kind)
        self._add(f"{prefix}.g2", 1, "g")
        self._add(f"{prefix}.beta", 1, "beta")

    def _add(self, name: str, size: int, kind: str) -> None:
        start = self.entries[-1].start + self.entries[-1].size if self.entries else 0
        e = Entry(name, start, int(size), kind)
        self.entries.append(e)
        self._index[name] = e

    def __getitem__(self, name: str) -> Entry:
        return self._index[name]

    def __contains__(self, name: str) -> bool:
        return name in self._index

    def col(self, name: str) -> int:
        return self._index[name].start

    def slice(self, name: str) -> slice:
        e = self._index[name]
        return slice(e.start, e.start + e.size)

    def names(self) -> list[str]:
        return [e.name for e in self.entries]

    def kinds(self) -> np.ndarray:
        """Per-component kind labels, shape (size,)."""
        return np.concatenate([[e.kind] * e.size for e in self.entries])

    def component_names(self) -> list[str]:
        out = []
        for e in self.entries:
            out += [e.name] if e.size == 1 else [f"{e.name}[{i}]" for i in range(e.size)]
        return out


def _vol_get(m: VolumeMaterial) -> list[np.ndarray]:
    return [m.sigma_t, m.albedo, [m.g1], [m.g2], [m.beta]]


def scene_to_vector(scene: TeethScene, layout: ParamLayout | None = None) -> np.ndarray:
    layout = layout or ParamLayout(scene)
    parts: list = []
    for t in scene.teeth:
        parts += _vol_get(t.enamel) + _vol_get(t.dentin) + [t.a_t.ravel(), t.c]
    if scene.gums is not None:
        parts += _vol_get(scene.gums.material) + [scene.gums.a_t.ravel()]
    if scene.cavity is not None:
        parts += [scene.cavity.albedo]
    x = np.concatenate([np.asarray(p, dtype=np.float64).ravel() for p in parts])
    assert x.size == layout.size
    return x


def vector_to_scene(scene: TeethScene, x: np.ndarray, layout: ParamLayout | None = None) -> TeethScene:
    """A copy of ``scene`` with its parameters replaced by ``x`` (clamped to valid ranges)."""
    layout = layout or ParamLayout(scene)
    x = clamp(np.asarray(x, dtype=np.float64), layout)
    out = scene.copy()

    def vol(prefix: str) -> VolumeMaterial:
        return VolumeMaterial(x[layout.slice(f"{prefix}.sigma_t")], x[layout.slice(f"{prefix}.albedo")],
                              x[layout.col(f"{prefix}.g1")], x[layout.col(f"{prefix}.g2")],
                              x[layout.col(f"{prefix}.beta")])

    for t in out.teeth:
        t.enamel = vol(f"{t.name}.enamel")
        t.dentin = vol(f"{t.name}.dentin")
        t.a_t = x[layout.slice(f"{t.name}.a_t")].reshape(t.a_t.shape)
        t.c = x[layout.slice(f"{t.name}.c")].copy()
    if out.gums is not None:
        out.gums.material = vol("gums")
        out.gums.a_t = x[layout.slice("gums.a_t")].reshape(out.gums.a_t.shape)
    if out.cavity is not None:
        out.cavity.albedo = x[layout.slice("cavity.albedo")].copy()
    return out


def clamp(x: np.ndarray, layout: ParamLayout) -> np.ndarray:
    out = x.copy()
    for e in layout.entries:
        lo, hi = RANGES[e.kind]
        out[e.start:e.start + e.size] = np.clip(out[e.start:e.start + e.size], lo, hi)
    return out


def volume_pairs(layout: ParamLayout) -> tuple[np.ndarray, np.ndarray]:
    """Component indices of every volume's sigma_t and the matching albedo, aligned."""
    si, ai = [], []
    for e in layout.entries:
        if e.kind == "sigma_t":
            a = layout[e.name[: -len("sigma_t")] + "albedo"]
            si.extend(range(e.start, e.start + e.size))
            ai.extend(range(a.start, a.start + a.size))
    return np.asarray(si, dtype=np.int64), np.asarray(ai, dtype=np.int64)


def to_optimiser(x: np.ndarray, layout: ParamLayout) -> np.ndarray:
    """Physical -> optimiser domain: xi = log sigma_t (eq. 5.24), kappa = log10(1 - albedo) (eq. 5.22),
    identity otherwise."""
    k = layout.kinds()
    y = x.astype(np.float64).copy()
    y[k == "sigma_t"] = np.log(x[k == "sigma_t"])
    y[k == "albedo"] = kappa_from_albedo(np.minimum(x[k == "albedo"], RANGES["albedo"][1]))
    return y


def from_optimiser(y: np.ndarray, layout: ParamLayout) -> np.ndarray:
    k = layout.kinds()
    x = y.astype(np.float64).copy()
    x[k == "sigma_t"] = np.exp(y[k == "sigma_t"])
    x[k == "albedo"] = albedo_from_kappa(y[k == "albedo"])
    return clamp(x, layout)


def optimiser_bounds(layout: ParamLayout) -> tuple[np.ndarray, np.ndarray]:
    """Per-component bounds (lo, hi) of the optimiser variables: the valid ranges (``RANGES``) mapped to
    the optimiser domain. Every map is monotone per component, so clipping y to these bounds is the
    projection onto the valid set (kappa = log10(1 - albedo) decreases with the albedo)."""
    lo, hi = np.empty(layout.size), np.empty(layout.size)
    for e in layout.entries:
        a, b = RANGES[e.kind]
        if e.kind == "sigma_t":
            a, b = np.log(a), np.log(b)
        elif e.kind == "albedo":
            a, b = float(kappa_from_albedo(b)), float(kappa_from_albedo(a))
        lo[e.start:e.start + e.size], hi[e.start:e.start + e.size] = a, b
    return lo, hi


def chain_to_optimiser(grad_x: np.ndarray, y: np.ndarray, layout: ParamLayout) -> np.ndarray:
    """Gradient w.r.t. the optimiser variables from the physical gradient (eq. 5.22, 5.24)."""
    k = layout.kinds()
    g = grad_x.astype(np.float64).copy()
    g[k == "sigma_t"] *= dsigma_dxi(y[k == "sigma_t"])
    g[k == "albedo"] *= dalbedo_dkappa(y[k == "albedo"])
    return g
