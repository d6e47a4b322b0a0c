"""World (HDRI) light for the scratch term: the brightest regions of the environment as sphere lamps.

The base metal closure sees the world as usual; only the scratch term needs it through lamp inputs.
Approximation (opt-in: the scene setting World Lights, ``scene.material_structures.scratch_world_lamps
= K``, free lamp slots permitting; it is stored in the scene's ID property ``ms_scratch_world_lamps``,
where files and scripts from before it was a setting put it, so those keep working):

1. the environment image (the world's Environment Texture, equirectangular, read as the fabric's
   exact world light reads it: ``addon/world_environment.py``) is reduced to a 64 x 32 luminance map;
2. K seed directions are picked greedily, brightest first, at least ``MIN_SEPARATION_DEG`` apart;
   every texel above ``THRESHOLD`` x the brightest joins its nearest seed (angular Voronoi) if it
   lies within ``MIN_SEPARATION_DEG`` of it;
3. each region becomes a distant sphere lamp (radius r at distance ``DISTANCE``) centred on its
   radiance-weighted mean direction, with the region's solid angle (r = D tan(alpha),
   pi alpha^2 = Omega) and its mean radiance, so the analytic sphere integral of the shader applies.

Dim texels (the rest of the sky) are dropped. ``world_approximation_error`` measures the error of
the scratch term this gives against a reference that integrates every texel of the hemisphere as
a small polygon light (core ``PolygonLight``), on a set of points of a test plate.
"""

from __future__ import annotations

import math

import numpy as np

from ...core.fabric.environment_sampling import EnvironmentMapError
from ..lamp_sync import ShaderLamp
from ..world_environment import world_source, world_strength

WORLD_LAMPS_PROP = "ms_scratch_world_lamps"  # scene ID property holding World Lights (K)
MAX_WORLD_LAMPS = 4  # the shader's lamp slots
MAP_W, MAP_H = 64, 32
MIN_SEPARATION_DEG = 25.0
THRESHOLD = 0.05
DISTANCE = 1.0e3  # m


def equirect_directions(w: int = MAP_W, h: int = MAP_H):
    """Centre directions (h, w, 3) and solid angles (h, w) of an equirectangular map, Blender's
    convention: u = -atan2(y, x) / 2 pi + 0.5, v = atan2(z, hypot(x, y)) / pi + 0.5, row 0 = top."""
    u = (np.arange(w) + 0.5) / w
    v = 1.0 - (np.arange(h) + 0.5) / h  # row 0 = top = v near 1
    phi = (0.5 - u) * 2 * np.pi
    lat = (v - 0.5) * np.pi
    lat_g, phi_g = np.meshgrid(lat, phi, indexing="ij")
    d = np.stack([np.cos(lat_g) * np.cos(phi_g), np.cos(lat_g) * np.sin(phi_g), np.sin(lat_g)], -1)
    omega = (2 * np.pi / w) * (np.pi / h) * np.cos(lat_g)
    return d, omega


def downsample(rgb: np.ndarray, w: int = MAP_W, h: int = MAP_H) -> np.ndarray:
    """Box-filter an (H, W, 3) equirect image (row 0 = top) to (h, w, 3); a cell no texel falls in (an image
    smaller than the map) takes the texel it lies in."""
    H, W = rgb.shape[:2]
    ys = (np.arange(H) * h // H)
    xs = (np.arange(W) * w // W)
    out = np.zeros((h, w, 3))
    cnt = np.zeros((h, w, 1))
    np.add.at(out, (ys[:, None], xs[None, :]), rgb[..., :3])
    np.add.at(cnt, (ys[:, None], xs[None, :]), 1.0)
    yy, xx = np.nonzero(cnt[..., 0] == 0)
    out[yy, xx] = rgb[yy * H // h, xx * W // w, :3]
    return out / np.maximum(cnt, 1)


def bright_regions(env: np.ndarray, k: int, rotation=None) -> list[dict]:
    """Up to ``k`` regions {direction, omega, radiance (3,)} of a (h, w, 3) radiance map (step 2-3);
    ``rotation`` M (lookup direction = M d, the world's Mapping) turns the map's directions into the
    world's before the upper hemisphere is taken."""
    d, omega = equirect_directions(env.shape[1], env.shape[0])
    if rotation is not None:
        d = d @ np.asarray(rotation, float)  # rows: d = M^T (lookup direction)
    lum = env @ np.array([0.2126, 0.7152, 0.0722])
    up = d[..., 2] > 0.0
    lum = np.where(up, lum, 0.0)
    if k <= 0 or lum.max() <= 0:
        return []
    order = np.argsort(lum.ravel())[::-1]
    flat_d = d.reshape(-1, 3)
    seeds: list[int] = []
    cos_sep = math.cos(math.radians(MIN_SEPARATION_DEG))
    for i in order:
        if lum.ravel()[i] < THRESHOLD * lum.max() or len(seeds) >= k:
            break
        if all(flat_d[i] @ flat_d[j] < cos_sep for j in seeds):
            seeds.append(int(i))
    keep = (lum.ravel() >= THRESHOLD * lum.max())
    idx = np.flatnonzero(keep)
    cosines = flat_d[idx] @ flat_d[seeds].T
    owner = np.argmax(cosines, axis=1)
    near = cosines[np.arange(idx.size), owner] >= cos_sep  # texels far from every seed are dropped
    idx, owner = idx[near], owner[near]
    out = []
    for s in range(len(seeds)):
        mem = idx[owner == s]
        om = omega.ravel()[mem]
        rad = env.reshape(-1, 3)[mem]
        w = om * (rad @ np.array([0.2126, 0.7152, 0.0722]))
        direction = (flat_d[mem] * w[:, None]).sum(0)
        direction /= np.linalg.norm(direction)
        total_om = float(om.sum())
        out.append({"direction": direction, "omega": total_om, "radiance": (rad * om[:, None]).sum(0) / total_om})
    return out


def region_sphere(region: dict, distance: float = DISTANCE) -> tuple[np.ndarray, float, np.ndarray]:
    """(centre offset, radius, radiance) of the distant sphere standing for a region."""
    alpha = math.sqrt(region["omega"] / math.pi)
    return region["direction"] * distance, distance * math.tan(min(alpha, 1.2)), region["radiance"]


def world_environment(scene):
    """((h, w, 3) radiance map of the world's environment image x Background strength, row 0 = top, in
    lookup directions; the lookup rotation M: lookup direction = M d) or None for a world without an
    environment image the add-on can read (``addon/world_environment.py``: an equirectangular Environment
    Texture on the Background, optionally turned by a Mapping)."""
    if scene is None or scene.world is None:
        return None
    key, load, rotation = world_source(scene)
    if key is None or key[0] != "image":
        return None
    env = _downsampled.get(key)
    if env is None:  # read and reduced once per image (a lamp drag updates the lamps on every step)
        try:
            rgb = load()  # linear, row 0 = bottom
        except EnvironmentMapError:
            return None
        env = downsample(np.asarray(rgb[::-1], np.float64))
        _downsampled.clear()  # one world at a time is plenty
        _downsampled[key] = env
    return env * world_strength(scene), rotation


_downsampled: dict = {}  # world_source key (the image, its file, size, colour space, edits) -> downsampled map


def world_lamp_count(scene) -> int:
    """World Lights of ``scene`` (0 = off), clamped to the shader's lamp slots."""
    if scene is None:
        return 0
    try:
        k = int(scene.get(WORLD_LAMPS_PROP, 0))
    except (TypeError, ValueError):
        return 0
    return max(0, min(MAX_WORLD_LAMPS, k))


def world_lamps_with_radii(scene, slots: int) -> list:
    """(ShaderLamp, radius) of the K brightest world regions as distant sphere lamps (K = World Lights,
    at most ``slots``); [] when World Lights is 0 or the world has no environment image."""
    k = min(world_lamp_count(scene), slots)
    if k <= 0:
        return []
    found = world_environment(scene)
    if found is None:
        return []
    env, rotation = found
    out = []
    for reg in bright_regions(env, k, rotation):
        c, r, rad = region_sphere(reg)
        intensity = rad * math.pi * r * r  # the shader's sphere radiance is I / (pi r^2)
        lamp = ShaderLamp(1, tuple(map(float, c)), tuple(map(float, -reg["direction"])),
                          tuple(map(float, intensity)))
        out.append((lamp, r))
    return out


def world_approximation_error(env: np.ndarray, k: int, scratch_set, points_um, wo, footprint_um=100.0) -> dict:
    """Relative error of the scratch term under the K-sphere approximation vs the texel-polygon reference.

    Points are on a plate facing +z (local frame = world frame); ``env`` (h, w, 3) radiance map.
    """
    from ...core.scratch.light_integration import PolygonLight, SphereLight  # measurement only: not at start-up
    from ...core.scratch.scratch_radiance import scratch_radiance

    h, w = env.shape[:2]
    n = len(points_um)
    ref = np.zeros((n, 3))
    lat_edges = np.pi * (0.5 - np.arange(h + 1) / h)
    phi_edges = (0.5 - np.arange(w + 1) / w) * 2 * np.pi
    for i in range(h):
        if lat_edges[i + 1] < 0:  # texel entirely below the horizon
            continue
        for j in range(w):
            L = env[i, j]
            if not np.any(L > 0):
                continue
            la0, la1 = max(lat_edges[i + 1], 0.0), lat_edges[i]
            corners = [(la0, phi_edges[j]), (la0, phi_edges[j + 1]), (la1, phi_edges[j + 1]), (la1, phi_edges[j])]
            verts = np.array([[math.cos(a) * math.cos(p), math.cos(a) * math.sin(p), math.sin(a)] for a, p in corners])
            if la1 >= np.pi / 2 - 1e-9:  # polar texel: a triangle
                verts = verts[[0, 1, 2]]
            sh = scratch_radiance(points_um, footprint_um, wo, PolygonLight(verts * DISTANCE, _per_band(L)),
                                  scratch_set)
            ref += sh.rgb
    approx = np.zeros((n, 3))
    for reg in bright_regions(env, k):
        c0, r, rad = region_sphere(reg)
        sh = scratch_radiance(points_um, footprint_um, wo, SphereLight(c0, r, _per_band(rad)), scratch_set)
        approx += sh.rgb
    a = np.abs(approx - ref).sum(-1)
    b = np.abs(ref).sum(-1)
    lit = b > 0.01 * np.percentile(b[b > 0], 99) if np.any(b > 0) else np.zeros(n, bool)
    rel = a[lit] / b[lit]
    return {"median_rel_err": float(np.median(rel)) if rel.size else float("nan"),
            "p99_rel_err": float(np.percentile(rel, 99)) if rel.size else float("nan"),
            "total_rel_err": float(abs(approx.sum() - ref.sum()) / max(abs(ref.sum()), 1e-300)),
            "points": int(lit.sum())}


def _per_band(rgb) -> np.ndarray:
    """Per-wavelength radiance of an RGB light as the shader takes it (ms_lamp_at, 'rgb' mode:
    465 nm <- B, 532 nm <- G, 630 nm <- R)."""
    return np.array([rgb[2], rgb[1], rgb[0]], dtype=np.float64)
