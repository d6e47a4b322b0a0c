"""Fabric parameter maps as Blender images (packed into the .blend, so save/undo/link keep them).

Core arrays are ``(H, W, C)`` with row 0 = the top row of the EXR file; Blender image pixels start
at the bottom row. Fit folders describe the fibre basis in the BTF tangent frame (x along image
columns, y along rows, i.e. *down* the image); on the mesh, the frame is (UV tangent, normal x
tangent = *up* the image, normal). The two differ by the reflection F = diag(1, -1, 1), under which
eq. 3.9 is invariant when the basis becomes F M F: quaternion (w, x, y, z) -> (w, -x, y, -z).
"""

from __future__ import annotations

import numpy as np

from ...core.fabric.closure_fit import ClosureMaps
from ...core.fabric.parameter_maps import MAP_FILES, FabricMaps, load_params, make_maps
from ..common import array_to_image, image_to_array

IMAGE_PREFIX = "SGGX"


def btf_quat_to_mesh(quat: np.ndarray) -> np.ndarray:
    """Basis quaternions from the BTF frame (y down the image) to the mesh frame (y up)."""
    q = np.array(quat, dtype=np.float32, copy=True)
    q[..., 1] *= -1.0
    q[..., 3] *= -1.0
    return q


mesh_quat_to_btf = btf_quat_to_mesh  # the reflection is its own inverse


def maps_to_images(maps: FabricMaps, prefix: str, btf_frame: bool = True) -> dict:
    """Four new images of a parameter set (basis converted to the mesh frame), owned by the material
    about to use them: importing the same maps again never touches an earlier import's (painted) images."""
    basis = btf_quat_to_mesh(maps.basis) if btf_frame else maps.basis
    arrays = {"kd": maps.kd, "ks": maps.ks, "sigma": maps.sigma, "basis": basis}
    return {key: array_to_image(arrays[key], f"{prefix} {key}", replace=False) for key in MAP_FILES}


def images_to_maps(images: dict, btf_frame: bool = True) -> FabricMaps:
    """Read the four images back as core maps (basis in the BTF frame when ``btf_frame``)."""
    arrays = {key: image_to_array(images[key], c) for key, (_, c) in MAP_FILES.items()}
    if btf_frame:
        arrays["basis"] = mesh_quat_to_btf(arrays["basis"])
    return make_maps(**arrays)


def load_fit_folder(params_dir: str) -> FabricMaps:
    """Validated maps from a fit's output folder (clear errors for missing/corrupt files)."""
    return load_params(params_dir)


# The fitted closure maps (core.fabric.closure_fit.ClosureMaps) as images: one RGBA image per closure
# holding its four view-basis coefficients, the shape (r_s, s_v, k_v, k_g), the GGX scale (R) and the
# second velvet's shape (s_v2, k_v2). They are frame-free (built from n and the fibre axes), so BTF and
# mesh frame share them.
CLOSURE_KEYS = ("diffuse", "sheen", "velvet", "ggx", "shape", "ggx_scale", "velvet2", "shape2")
WEIGHT_KEYS = ("diffuse", "sheen", "velvet", "ggx", "velvet2")  # ClosureMaps.weights[:, :, j] order
CLOSURE_CHANNELS = {"diffuse": 4, "sheen": 4, "velvet": 4, "ggx": 4, "shape": 4, "ggx_scale": 1, "velvet2": 4,
                    "shape2": 2}


def closure_arrays(cm: ClosureMaps) -> dict:
    """The (H, W, C) arrays of the closure images, by key (row 0 = top)."""
    out = {key: cm.weights[:, :, j, :] for j, key in enumerate(WEIGHT_KEYS)}
    out["shape"], out["shape2"], out["ggx_scale"] = cm.shape[:, :, :4], cm.shape[:, :, 4:6], cm.ggx_scale
    return out


def closure_maps_to_images(cm: ClosureMaps, prefix: str) -> dict:
    """New packed Non-Color images of fitted closure maps, owned by the material about to use them."""
    arrays = closure_arrays(cm)
    return {key: array_to_image(arrays[key], f"{prefix} fit {key}", replace=False) for key in CLOSURE_KEYS}


def images_to_closure_maps(images: dict) -> ClosureMaps:
    """Read the closure images back (inverse of :func:`closure_maps_to_images`)."""
    a = {key: image_to_array(images[key], CLOSURE_CHANNELS[key]) for key in CLOSURE_KEYS}
    return ClosureMaps(weights=np.stack([a[k] for k in WEIGHT_KEYS], axis=2),
                       shape=np.concatenate([a["shape"], a["shape2"]], axis=2), ggx_scale=a["ggx_scale"])
