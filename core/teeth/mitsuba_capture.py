"""The teeth scene in Mitsuba 3, and synthetic captures rendered by it (``teeth synth --renderer mitsuba``).

Mitsuba computes the same image as our tracer when the enamel/dentin boundary is sharp (blend spread -> 0):
enamel, dentin and gum media with two-lobe HG phase functions (``blendphase``), a two-sided diffuse oral cavity,
point lights and perspective cameras matching our ``Camera`` (tests/core/test_teeth_mitsuba.py). Rendered with
``volpath`` and all bounces (``max_depth -1``). Index-matched boundaries (eta 1, a_t 1) are Mitsuba ``null``
interfaces; the thin dielectric boundary of eq. 5.1-5.2 (reflect with the Fresnel factor F, else pass straight on
with weight a_t) is the BSDF plugin ``teeth_thin_boundary`` defined here, for an a_t constant over each part.
Mitsuba is imported lazily, inside the functions; the variant is ``llvm_ad_rgb`` where Dr.Jit's LLVM backend is
available, otherwise ``scalar_rgb`` (same images, much slower).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable

import numpy as np

from ..errors import UserError
from .capture import Camera, Capture, PointLight
from .scene import TeethScene

LIBLLVM = "/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1"
LLVM_VARIANT = "llvm_ad_rgb"
SCALAR_VARIANT = "scalar_rgb"
MEDIUM_PARAMS = ("sigma_t.value.value", "albedo.value.value", "phase_function.weight.value.value",
                 "phase_function.phase_0.g", "phase_function.phase_1.g")
CAVITY_PARAM = "cavity.bsdf.brdf_0.reflectance.value"


def import_mitsuba(variant: str | None = None) -> tuple[object, str]:
    """Mitsuba 3 with ``variant`` set, and the variant's name. ``None`` picks ``llvm_ad_rgb`` where Dr.Jit's LLVM
    backend loads (it finds Debian's libLLVM 19 through DRJIT_LIBLLVM_PATH, set here where that library is
    installed and the variable is not), else ``scalar_rgb``. Raises RuntimeError where Mitsuba is not installed."""
    if os.path.exists(LIBLLVM):
        os.environ.setdefault("DRJIT_LIBLLVM_PATH", LIBLLVM)
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as e:
        raise UserError(f"rendering with Mitsuba needs Mitsuba 3 (the project .venv has the version uv.lock pins; "
                           f"elsewhere: pip install mitsuba) ({e})") from e
    if variant is None:
        variant = LLVM_VARIANT if dr.has_backend(dr.JitBackend.LLVM) else SCALAR_VARIANT
    mi.set_variant(variant)
    return mi, variant


THIN_BOUNDARY = "teeth_thin_boundary"
_REGISTERED: set[str] = set()


def register_thin_boundary(mi) -> None:
    """Register the BSDF plugin ``teeth_thin_boundary`` for Mitsuba's current variant (once per variant).

    The thin, non-bending boundary of eq. 5.1-5.2 from either side: with the unpolarised Fresnel factor F(|cos|,
    eta) of ``path_tracer.fresnel_dielectric`` (F = 1 past the critical angle where eta < 1) the light is
    reflected (weight 1, a delta reflection); otherwise it passes straight on with weight a_t, as a ``null``
    interface that attenuates (Mitsuba then counts no bounce, and ``volpath``'s shadow rays take
    ``eval_null_transmission`` = a_t (1 - F) at each crossing, as our next-event estimation does). Properties:
    ``eta`` (float), ``a_t`` (RGB)."""
    import drjit as dr

    if mi.variant() in _REGISTERED:
        return

    def fresnel(cos_i, eta):
        c = dr.minimum(dr.abs(cos_i), 1.0)
        cos_t = dr.sqrt(dr.maximum(1.0 - (1.0 - c * c) / (eta * eta), 0.0))
        rs = (c - eta * cos_t) / (c + eta * cos_t)
        rp = (eta * c - cos_t) / (eta * c + cos_t)
        return 0.5 * (rs * rs + rp * rp)

    class ThinBoundary(mi.BSDF):
        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            self.eta = float(props.get("eta", 1.0))
            a_t = props.get("a_t", mi.ScalarColor3f(1.0))
            self.a_t = mi.Color3f(float(a_t[0]), float(a_t[1]), float(a_t[2]))
            sides = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
            reflection, transmission = mi.BSDFFlags.DeltaReflection | sides, mi.BSDFFlags.Null | sides
            self.m_components = [reflection, transmission]
            self.m_flags = reflection | transmission

        def sample(self, ctx, si, sample1, sample2, active=True):
            f = fresnel(mi.Frame3f.cos_theta(si.wi), self.eta)
            reflect = sample1 < f
            bs = mi.BSDFSample3f()
            bs.wo = dr.select(reflect, mi.reflect(si.wi), -si.wi)
            bs.pdf = dr.select(reflect, f, 1.0 - f)
            bs.eta = mi.Float(1.0)
            bs.sampled_component = dr.select(reflect, mi.UInt32(0), mi.UInt32(1))
            bs.sampled_type = dr.select(reflect, mi.UInt32(+mi.BSDFFlags.DeltaReflection),
                                        mi.UInt32(+mi.BSDFFlags.Null))
            value = dr.select(reflect, mi.Color3f(1.0), self.a_t)
            return bs, dr.select(active, value, mi.Color3f(0.0))

        def eval(self, ctx, si, wo, active=True):
            return mi.Color3f(0.0)

        def pdf(self, ctx, si, wo, active=True):
            return mi.Float(0.0)

        def eval_pdf(self, ctx, si, wo, active=True):
            return mi.Color3f(0.0), mi.Float(0.0)

        def eval_null_transmission(self, si, active=True):
            value = self.a_t * (1.0 - fresnel(mi.Frame3f.cos_theta(si.wi), self.eta))
            return dr.select(active, value, mi.Color3f(0.0))

        def to_string(self):
            return f"ThinBoundary[eta={self.eta}]"

    mi.register_bsdf(THIN_BOUNDARY, lambda props: ThinBoundary(props))
    _REGISTERED.add(mi.variant())


def _boundary(name: str, part) -> dict:
    """The Mitsuba BSDF of a tooth's or the gums' outer boundary: ``null`` where index-matched, else the thin
    boundary plugin (a ValueError where a_t varies over the part: the plugin takes one a_t per part)."""
    a_t = np.asarray(part.a_t, dtype=np.float64).reshape(-1, 3)
    if part.eta == 1.0 and np.all(a_t == 1.0):
        return {"type": "null"}
    if not np.all(a_t == a_t[0]):
        raise UserError(f"Mitsuba renders one a_t per part; {name} has a_t in "
                        f"[{float(a_t.min()):g}, {float(a_t.max()):g}]")
    return {"type": THIN_BOUNDARY, "eta": float(part.eta), "a_t": {"type": "rgb", "value": a_t[0].tolist()}}


def _medium(m) -> dict:
    """Mitsuba ``homogeneous`` medium of a ``VolumeMaterial`` (sigma_t as an RGB in [0, 1] times ``scale``;
    ``blendphase``: (1 - beta) HG(g2) + beta HG(g1))."""
    smax = float(m.sigma_t.max())
    return {"type": "homogeneous", "sigma_t": {"type": "rgb", "value": (m.sigma_t / smax).tolist()}, "scale": smax,
            "albedo": {"type": "rgb", "value": m.albedo.tolist()},
            "phase": {"type": "blendphase", "weight": m.beta,
                      "phase1": {"type": "hg", "g": m.g2}, "phase2": {"type": "hg", "g": m.g1}}}


def mitsuba_scene(mi, sc: TeethScene, cameras: list[Camera], folder: str, spp: int = 16) -> tuple[object, list[str]]:
    """``sc`` as a Mitsuba scene (meshes written as PLY into ``folder``): one sensor per camera (``sensor{k}``,
    ``spp`` samples by default), one point light ``light`` (moved by ``set_light``), one medium per tooth part and
    the gums, referenced by the shapes that bound them. Loaded with ``optimize=False``: Mitsuba would otherwise
    merge the teeth's media (equal values) into one, and their meshes with them. The outer boundaries are ``null``
    interfaces where index-matched, else ``teeth_thin_boundary`` (``register_thin_boundary``; a ValueError where
    a_t varies over a part); the enamel/dentin boundary is sharp. Returns (scene, the names of the parameters that
    map to ours)."""
    from .mesh import TriMesh, save_mesh

    bsdfs = [_boundary(t.name, t) for t in sc.teeth] + ([_boundary("gums", sc.gums)] if sc.gums is not None else [])
    if any(b["type"] == THIN_BOUNDARY for b in bsdfs):
        register_thin_boundary(mi)

    def ply(name: str, mesh) -> str:
        path = os.path.join(folder, f"{name}.ply")
        save_mesh(TriMesh(mesh.vertices, mesh.faces), path)
        return path

    d: dict = {"type": "scene"}
    media = []
    for i, t in enumerate(sc.teeth):
        enamel, dentin = f"tooth{i}_enamel", f"tooth{i}_dentin"
        d[enamel], d[dentin] = _medium(t.enamel), _medium(t.dentin)
        media += [enamel, dentin]
        d[f"{enamel}_mesh"] = {"type": "ply", "filename": ply(enamel, t.enamel_mesh), "face_normals": True,
                               "bsdf": bsdfs[i], "interior": {"type": "ref", "id": enamel}}
        d[f"{dentin}_mesh"] = {"type": "ply", "filename": ply(dentin, t.dentin_shape.mesh(t.c)), "face_normals": True,
                               "bsdf": {"type": "null"}, "interior": {"type": "ref", "id": dentin},
                               "exterior": {"type": "ref", "id": enamel}}
    if sc.gums is not None:
        d["gums"] = _medium(sc.gums.material)
        media.append("gums")
        d["gums_mesh"] = {"type": "ply", "filename": ply("gums", sc.gums.mesh), "face_normals": True,
                          "bsdf": bsdfs[-1], "interior": {"type": "ref", "id": "gums"}}
    keys = [f"{m}.{p}" for m in media for p in MEDIUM_PARAMS]
    if sc.cavity is not None:
        d["cavity"] = {"type": "ply", "filename": ply("cavity", sc.cavity.mesh), "face_normals": True,
                       "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance":
                                                             {"type": "rgb", "value": sc.cavity.albedo.tolist()}}}}
        keys.append(CAVITY_PARAM)
    for k, cam in enumerate(cameras):
        eye, fwd, up = cam.center, cam.R[2], -cam.R[1]
        fov = float(np.degrees(2 * np.arctan(0.5 * cam.width / cam.K[0, 0])))
        d[f"sensor{k}"] = {
            "type": "perspective", "fov": fov, "fov_axis": "x",
            "to_world": mi.ScalarTransform4f().look_at(origin=eye.tolist(), target=(eye + fwd).tolist(),
                                                       up=up.tolist()),
            "sampler": {"type": "independent", "sample_count": int(spp)},
            "film": {"type": "hdrfilm", "width": cam.width, "height": cam.height, "rfilter": {"type": "box"},
                     "pixel_format": "rgb"}}
    d["light"] = {"type": "point", "position": [0.0, 0.0, 0.0], "intensity": {"type": "rgb", "value": [1.0] * 3}}
    return mi.load_dict(d, optimize=False), keys


def set_light(mi, params, light: PointLight) -> None:
    """Move the scene's point light (opaque values: the rendering kernels are reused, not recompiled)."""
    import drjit as dr

    pos = mi.Point3f(*(float(v) for v in light.position))
    val = mi.Color3f(*(float(v) for v in light.intensity))
    dr.make_opaque(pos, val)
    params["light.position"] = pos
    params["light.intensity.value"] = val
    params.update()


def mitsuba_image(mi, scene, sensor: int, spp: int, seed: int, integrator) -> np.ndarray:
    """One Mitsuba image (H, W, 3) in host memory."""
    return np.asarray(mi.render(scene, sensor=int(sensor), integrator=integrator, spp=int(spp), seed=int(seed)))


def render_capture_mitsuba(scene: TeethScene, cameras: list[Camera], lights: list[PointLight], spp: int = 16,
                           seed: int = 12345, progress: Callable[[int], object] | None = None,
                           variant: str | None = None) -> Capture:
    """Synthetic capture of ``scene`` rendered by Mitsuba 3 ``volpath`` with all bounces (``max_depth -1``, its
    default Russian roulette): images float32 (n_cam, n_light, H, W, 3), every pixel at ``spp`` samples, one
    render per (camera, light) with seed ``seed + n_cam * light + camera`` (mod 2^32), and the ``tooth_masks``, as
    ``synthetic.render_capture`` returns them. Each tooth's and the gums' a_t must be one value (a ValueError
    otherwise, nothing is changed; boundaries as in ``mitsuba_scene``); the blend spread is ignored (Mitsuba's
    enamel/dentin boundary is sharp). ``progress(1)`` is called after each light; ``variant`` as in
    ``import_mitsuba``."""
    from .synthetic import tooth_masks

    if spp < 1:
        raise UserError("need spp >= 1")
    mi, _ = import_mitsuba(variant)
    masks = tooth_masks(scene, cameras)
    n_cam = len(cameras)
    h, w = cameras[0].height, cameras[0].width
    images = np.zeros((n_cam, len(lights), h, w, 3), dtype=np.float32)
    with tempfile.TemporaryDirectory() as folder:
        mscene, _ = mitsuba_scene(mi, scene, cameras, folder, spp=spp)
    params = mi.traverse(mscene)
    volpath = mi.load_dict({"type": "volpath", "max_depth": -1})
    for li, light in enumerate(lights):
        set_light(mi, params, light)
        for k in range(n_cam):
            img = mitsuba_image(mi, mscene, k, spp, (seed + n_cam * li + k) % 2**32, volpath)
            images[k, li] = img[:, :, :3]
        if progress is not None:
            progress(1)
    return Capture(list(cameras), list(lights), images, masks)

