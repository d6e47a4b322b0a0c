"""Accuracy of a closure representation of the fabric vs eq. 3.9, in numpy (``bench fabric-shader``).

Two lighting situations, both evaluated with the same directions for the reference and the closures:

* Point light: the benchmark's flat patch (1 x 1 plane, orthographic camera of scale 0.7 along the
  view direction, 24 x 24 pixels, a point lamp), ``L = f cos_i I / d^2`` per pixel.
* Environment: a procedural equirectangular HDRI (``sky_hdri``, ``interior_hdri``) and the midpoint
  quadrature over its upper-hemisphere texels, ``L(wo) = sum f(wi, wo) cos_i L_env(wi) dw`` with
  ``dw = sin(theta) dtheta dphi``; one value per view direction, for a cosine-stratified set of views.

Equirect convention here: row i covers polar angle theta in [i, i + 1] pi / H from +Z (zenith at row
0), column j azimuth phi in [j, j + 1] 2 pi / W from +X towards +Y. (Blender's world ``Environment
Texture`` maps direction d to u = atan2(d_y, -d_x) / 2 pi (mod 1), v = atan2(d_z, hypot(d_x, d_y)) / pi +
1/2 with v = 0 the bottom row (checked on Cycles renders of the background): ``to_blender_equirect``
resamples for a Cycles render; at the same size it is a permutation of the texels.)
"""

from __future__ import annotations

import numpy as np

from .closure_fit import hemisphere_grid
from .sggx_brdf import sggx_brdf


def _dirs(h, w):
    th = (np.arange(h) + 0.5) / h * np.pi
    ph = (np.arange(w) + 0.5) / w * 2 * np.pi
    t, p = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)
    return d, t, p


def sky_hdri(h: int = 128, w: int = 256) -> np.ndarray:
    """Sky gradient (bright bluish horizon to deeper zenith), a sun-like hot spot (3 degrees radius,
    theta 50, phi 120 degrees, ~500x the sky) and a dark ground. (H, W, 3) float32 radiance."""
    d, t, p = _dirs(h, w)
    mu = np.maximum(d[..., 2], 0.0)
    horizon, zenith = np.array([1.0, 1.05, 1.15]), np.array([0.25, 0.4, 0.8])
    sky = horizon + (zenith - horizon) * np.sqrt(mu)[..., None]
    sun_dir = np.array([np.sin(np.radians(50)) * np.cos(np.radians(120)),
                        np.sin(np.radians(50)) * np.sin(np.radians(120)), np.cos(np.radians(50))])
    ang = np.degrees(np.arccos(np.clip(np.sum(d * sun_dir, -1), -1, 1)))
    sun = 500.0 * np.exp(-0.5 * (ang / 2.0) ** 2)[..., None] * np.array([1.0, 0.92, 0.8])
    img = np.where((d[..., 2] > 0)[..., None], sky + sun, np.array([0.08, 0.07, 0.06]))
    return img.astype(np.float32)


def interior_hdri(h: int = 128, w: int = 256) -> np.ndarray:
    """A room: dim walls, a soft ceiling, two bright windows near the horizon. (H, W, 3) float32."""
    d, t, p = _dirs(h, w)
    td, pd = np.degrees(t), np.degrees(p)
    img = np.broadcast_to(np.array([0.06, 0.05, 0.045]), d.shape).copy()
    img[td < 25] = [0.4, 0.38, 0.35]
    win1 = (td > 55) & (td < 80) & (pd > 20) & (pd < 60)
    win2 = (td > 60) & (td < 86) & (pd > 200) & (pd < 235)
    img[win1] = [9.0, 9.5, 10.0]
    img[win2] = [5.0, 5.2, 5.8]
    return img.astype(np.float32)


def to_blender_equirect(img: np.ndarray) -> np.ndarray:
    """Resample an environment in this module's convention to Blender's equirect layout (row 0 =
    bottom, as an image's pixel buffer), nearest texel."""
    h, w = img.shape[:2]
    v = (np.arange(h) + 0.5) / h
    u = (np.arange(w) + 0.5) / w
    uu, vv = np.meshgrid(u, v)
    elev = (vv - 0.5) * np.pi
    az = uu * 2 * np.pi  # = atan2(d_y, -d_x) (mod 2 pi)
    dx, dy, dz = -np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), np.sin(elev)
    th = np.arccos(np.clip(dz, -1, 1))
    ph = np.arctan2(dy, dx) % (2 * np.pi)
    i = np.clip((th / np.pi * h).astype(int), 0, h - 1)
    j = np.clip((ph / (2 * np.pi) * w).astype(int), 0, w - 1)
    return img[i, j]


def env_lights(img: np.ndarray):
    """Upper-hemisphere texel directions (N, 3) and radiance x solid angle (N, 3) of an env map."""
    h, w = img.shape[:2]
    d, t, _ = _dirs(h, w)
    dw = np.sin(t) * (np.pi / h) * (2 * np.pi / w)
    up = d[..., 2] > 0
    return d[up], img[up].astype(np.float64) * dw[up][:, None]


def env_radiance(eval_fn, wo, lights, chunk: int = 4096):
    """``sum_k eval_fn(wi_k, wo) L_k dw_k`` over the env's texels; eval_fn(wi, wo) -> (..., 3) radiance
    per unit incident radiance (f cos_i or a closure's eval). wo (V, 3) -> (V, 3)."""
    dirs, le = lights
    out = np.zeros((len(wo), 3))
    for c in range(0, len(dirs), chunk):
        f = eval_fn(dirs[None, c:c + chunk], wo[:, None, :])
        out += np.einsum("vkc,kc->vc", f, le[c:c + chunk])
    return out


def reference_eval(kd, ks, sigma, quat):
    """eq. 3.9 times cos_i, as an ``eval_fn``."""
    def fn(wi, wo):
        return sggx_brdf(wi, wo, kd, ks, sigma, quat) * np.maximum(wi[..., 2:3], 0.0)
    return fn


def patch_points(view=(30.0, 200.0), ortho_scale: float = 0.7, resolution: int = 24):
    """Shading points of the benchmark's flat patch seen by an orthographic camera along ``view``
    (theta, phi degrees): (P, 3) points on z = 0 inside the 1 x 1 plane, and the view direction."""
    th, ph = np.radians(view)
    wo = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    right = np.cross([0.0, 0.0, 1.0], wo)
    right = right / np.linalg.norm(right) if np.linalg.norm(right) > 1e-9 else np.array([1.0, 0.0, 0.0])
    up = np.cross(wo, right)
    s = ((np.arange(resolution) + 0.5) / resolution - 0.5) * ortho_scale
    a, b = np.meshgrid(s, s)
    p = a[..., None] * right + b[..., None] * up
    p = p - (p[..., 2:3] / wo[2]) * wo
    p = p.reshape(-1, 3)
    inside = np.all(np.abs(p[:, :2]) <= 0.5, axis=1)
    return p[inside], wo


def point_light_radiance(eval_fn, points, wo, lamp=(0.4, -0.3, 1.2), power: float = 50.0):
    """Radiance of each patch point under a point lamp of ``power`` W (I = P / 4 pi)."""
    d = np.asarray(lamp, float)[None, :] - points
    dist2 = np.sum(d * d, -1, keepdims=True)
    wi = d / np.sqrt(dist2)
    return eval_fn(wi, np.broadcast_to(wo, wi.shape)) * power / (4 * np.pi) / dist2


def rel_stats(approx, ref) -> dict:
    rel = (np.abs(approx - ref) / ref).ravel()
    return {"median": float(np.median(rel)), "p90": float(np.percentile(rel, 90))}


def view_set(n_theta: int = 6, n_phi: int = 12) -> np.ndarray:
    """Cosine-stratified view directions for the environment comparison (as a renderer sees them)."""
    return hemisphere_grid(n_theta, n_phi, offset=0.125)
