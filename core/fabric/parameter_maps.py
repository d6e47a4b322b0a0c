"""Per-texel parameter maps of the fabric SVBRDF and their on-disk form (a fit's output folder).

Folder layout: ``kd.exr`` (RGB), ``ks.exr`` (RGB), ``sigma.exr`` (R = sigma_x, G = sigma_y;
sigma_z = 1), ``basis.exr`` (R, G, B, A = unit quaternion w, x, y, z of the fibre basis ``M`` of eq.
3.6, columns of ``M`` = axes with standard deviations sigma_x, sigma_y, 1) and ``params.json``.
"""

from __future__ import annotations

import dataclasses
import json
import os

import numpy as np

from ..errors import MissingFileError, UserError
from ..exr_io import ExrError, read_exr, write_exr
from ..json_schema import check as check_schema
from ..staged_write import staged_files
from .quaternion import quat_normalize

MAP_FILES = {"kd": ("kd.exr", 3), "ks": ("ks.exr", 3), "sigma": ("sigma.exr", 2), "basis": ("basis.exr", 4)}
PARAMS_VERSION = 1


SIGMA_RANGE = (0.01, 10.0)  # sigma_x, sigma_y: what the fitter fits (levenberg_marquardt) and the brushes keep to


@dataclasses.dataclass(frozen=True)
class FabricMaps:
    """SVBRDF parameter maps, all ``(H, W, C)`` float32: kd/ks (C=3), sigma (C=2), basis (C=4, wxyz)."""

    kd: np.ndarray
    ks: np.ndarray
    sigma: np.ndarray
    basis: np.ndarray

    def __post_init__(self) -> None:
        shape = None
        for name, (_, c) in MAP_FILES.items():
            a = getattr(self, name)
            if a.ndim != 3 or a.shape[2] != c:
                raise UserError(f"map {name!r} must be (H, W, {c}), got {a.shape}")
            if shape is None:
                shape = a.shape[:2]
            elif a.shape[:2] != shape:
                raise UserError(f"map {name!r} is {a.shape[:2]}, other maps are {shape}")

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.kd.shape[:2])

    def replace(self, **changes: np.ndarray) -> FabricMaps:
        """A new FabricMaps with some maps replaced (the others are shared, not copied)."""
        return dataclasses.replace(self, **changes)

    def copy(self) -> FabricMaps:
        return FabricMaps(*(np.array(getattr(self, n), copy=True) for n in MAP_FILES))

    def as_dict(self) -> dict[str, np.ndarray]:
        return {n: getattr(self, n) for n in MAP_FILES}


def make_maps(kd, ks, sigma, basis) -> FabricMaps:
    """Build float32 maps (normalising the quaternions)."""
    return FabricMaps(
        kd=np.asarray(kd, dtype=np.float32), ks=np.asarray(ks, dtype=np.float32),
        sigma=np.asarray(sigma, dtype=np.float32),
        basis=quat_normalize(np.asarray(basis, dtype=np.float64)).astype(np.float32),
    )


def save_params(out_dir: str | os.PathLike, maps: FabricMaps, extra: dict | None = None) -> None:
    """Write the four EXR maps and ``params.json`` describing them."""
    with staged_files(out_dir, "params.json") as stage:  # the maps and their params.json, or no params.json
        _write_params(stage, maps, extra)


def _write_params(out_dir: str, maps: FabricMaps, extra: dict | None) -> None:
    write_exr(os.path.join(out_dir, "kd.exr"), maps.kd)
    write_exr(os.path.join(out_dir, "ks.exr"), maps.ks)
    write_exr(os.path.join(out_dir, "sigma.exr"), maps.sigma)
    write_exr(os.path.join(out_dir, "basis.exr"), maps.basis)
    desc = {
        "model": "velinov2019-pile-fabric-sggx",
        "version": PARAMS_VERSION,
        "width": int(maps.shape[1]),
        "height": int(maps.shape[0]),
        "brdf": "f_r = ks * D(wh) / (4 cos_i cos_o (sigma(wo)/cos_o + sigma(wi)/cos_i)) + kd/pi (eq. 3.9)",
        "frame": "tangent frame: z = normal, x along image columns, y along rows",
        "maps": {
            "kd": {"file": "kd.exr", "channels": ["R", "G", "B"],
                   "meaning": "diffuse albedo k_d (linear RGB)"},
            "ks": {"file": "ks.exr", "channels": ["R", "G", "B"],
                   "meaning": "specular albedo k_s (linear RGB)"},
            "sigma": {"file": "sigma.exr", "channels": ["R", "G"],
                      "meaning": "projected standard deviations sigma_x, sigma_y of the SGGX basis axes; "
                                 "sigma_z = 1 (eq. 3.7-3.8)"},
            "basis": {"file": "basis.exr", "channels": ["R", "G", "B", "A"],
                      "meaning": "unit quaternion (w, x, y, z) rotating the tangent frame onto the SGGX "
                                 "basis M (eq. 3.6); columns of M are the axes of sigma_x, sigma_y, sigma_z"},
        },
    }
    if extra:
        desc.update(extra)
    with open(os.path.join(out_dir, "params.json"), "w") as f:
        json.dump(desc, f, indent=2)


def load_params(params_dir: str | os.PathLike) -> FabricMaps:
    """Load a fit's output folder (``params.json`` + EXR maps) as :class:`FabricMaps`."""
    params_dir = os.fspath(params_dir)
    jpath = os.path.join(params_dir, "params.json")
    if not os.path.isfile(jpath):
        raise MissingFileError(f"not a fabric parameter folder (no params.json): {params_dir}", params_dir)
    try:
        with open(jpath, encoding="utf-8") as f:
            desc = json.load(f)
    except ValueError as exc:  # not JSON, or not text
        raise UserError(f"{jpath}: not valid JSON ({exc})") from None
    check_schema(desc, "fabric-params", jpath)  # core/schemas/fabric-params.schema.json
    arrays = {}
    for name, (default_file, c) in MAP_FILES.items():
        entry = desc.get("maps", {}).get(name, {})
        file, chans = entry.get("file", default_file), entry.get("channels", ("R", "G", "B", "A")[:c])
        if len(chans) != c:
            raise UserError(f"{jpath}: maps.{name}.channels must name {c} channels, got {chans!r}")
        path, chans = os.path.join(params_dir, file), tuple(chans)
        try:
            arrays[name] = read_exr(path, channels=chans)
        except ExrError as exc:
            raise UserError(f"parameter map {name!r}: {exc}") from exc
    check_maps(arrays, params_dir)
    return make_maps(**arrays)


def check_maps(arrays: dict, source: str) -> None:
    """Refuse maps eq. 3.9 cannot shade: different sizes, NaN / inf, negative albedos, standard deviations
    that are not > 0 (NaN predictions), quaternions of zero length. One line naming the folder."""
    shapes = {name: a.shape[:2] for name, a in arrays.items()}
    if len(set(shapes.values())) > 1:
        raise UserError(f"{source}: the maps differ in size: {shapes}")
    for name, a in arrays.items():
        bad = ~np.isfinite(a)
        if bad.any():
            raise UserError(f"{source}: map {name!r} holds {int(bad.any(axis=-1).sum())} texels that are NaN or "
                            "infinite")
    for name in ("kd", "ks"):
        if (arrays[name] < 0).any():
            n_neg = int((arrays[name] < 0).any(axis=-1).sum())
            raise UserError(f"{source}: map {name!r} has negative albedo in {n_neg} texels")
    if (arrays["sigma"] <= 0).any():
        raise UserError(f"{source}: map 'sigma' must be > 0; {int((arrays['sigma'] <= 0).any(axis=-1).sum())} texels "
                        "are not")
    if (np.linalg.norm(arrays["basis"], axis=-1) < 1e-8).any():
        raise UserError(f"{source}: map 'basis' has quaternions of zero length")
