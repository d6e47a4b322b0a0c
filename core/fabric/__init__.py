"""Pile fabric appearance model (thesis chapter 3): SGGX-based BRDF, BTF fitting, brushing.

Pure numpy/scipy, no bpy; runs on numpy 1.26 and 2.x. Public API:

Model (eq. 3.5-3.10)
    sggx_brdf(wi, wo, kd, ks, sigma, quat) -> f_r (..., 3)            eq. 3.9, broadcasting
    sggx_btf_value(...)                    -> f_r cos(theta_i)          what a BTF texel stores
    sggx_specular(wi, wo, sigma, quat)     -> specular term, k_s = 1
    sggx_matrix(quat, sigma) -> S (..., 3, 3)   eq. 3.6-3.8;  sggx_ndf(wh, S) eq. 3.5
    projected_area(w, S) = sigma(w)
    sample_specular(wo, sigma, quat, u1, u2) -> (wi, pdf);  specular_pdf(wi, wo, sigma, quat)
Parameter maps
    FabricMaps(kd, ks, sigma, basis)  (H, W, 3/3/2/4) float32, basis = quaternion (w, x, y, z)
    load_params(dir) / save_params(dir, maps)      kd.exr, ks.exr, sigma.exr, basis.exr, params.json
BTF and fitting
    load_btf(path) / save_btf(path, values, wi, wo);  fit_btf(btf, out_dir, ...) -> (maps, stats)
    predict_btf(maps, wi, wo) -> (N, H, W, 3);  synthetic_maps(...), render_btf(...)
Brushing (pure: maps in, maps out)
    brush_fibres(maps, p0, p1, radius, strength, fibre_length)   one stroke segment
    brush_stroke(maps, points, radius, ...);  brush_edit(maps, p0, p1, radius, kd=, ks=, ...)
    recolor(maps, kd, ks, weight);  smoothness(maps, factor, weight);  anisotropy(maps, factor, weight)
    BrushStates(8 FabricMaps);  brush_data_driven(maps, p0, p1, radius, states)

Only the fitter needs scipy (``fit_btf``, ``FitOptions`` are imported lazily), so the model, the
parameter maps and the brushing work with numpy alone (e.g. inside Blender).
"""

from .brushing import (
    BrushStates,
    anisotropy,
    brush_data_driven,
    brush_edit,
    brush_fibres,
    brush_stroke,
    brushed_basis,
    capsule_window,
    max_tilt,
    recolor,
    smoothness,
    stroke_weight_map,
)
from .btf_io import Btf, load_btf, read_btf_header, read_directions, save_btf
from .btf_prediction import predict_btf, psnr, texel_psnr
from .parameter_maps import FabricMaps, load_params, make_maps, save_params
from .quaternion import matrix_to_quat, quat_slerp, quat_to_matrix
from .sggx_brdf import sggx_brdf, sggx_btf_value, sggx_specular
from .sggx_matrix import projected_area, sggx_matrix
from .sggx_ndf import sggx_ndf
from .sggx_sampling import sample_specular, sample_visible_normal, specular_pdf
from .synthetic_btf import light_view_pairs, render_btf, synthetic_maps

__all__ = [
    "Btf",
    "BrushStates",
    "FabricMaps",
    "FitOptions",
    "anisotropy",
    "brush_data_driven",
    "brush_edit",
    "brush_fibres",
    "brush_stroke",
    "brushed_basis",
    "capsule_window",
    "fit_btf",
    "light_view_pairs",
    "load_btf",
    "load_params",
    "make_maps",
    "matrix_to_quat",
    "max_tilt",
    "predict_btf",
    "projected_area",
    "psnr",
    "quat_slerp",
    "quat_to_matrix",
    "read_btf_header",
    "read_directions",
    "recolor",
    "render_btf",
    "sample_specular",
    "sample_visible_normal",
    "save_btf",
    "save_params",
    "sggx_brdf",
    "sggx_btf_value",
    "sggx_matrix",
    "sggx_ndf",
    "sggx_specular",
    "smoothness",
    "specular_pdf",
    "stroke_weight_map",
    "synthetic_maps",
    "texel_psnr",
]


def __getattr__(name: str):
    if name == "fit_btf":
        from .btf_fitter import fit_btf

        return fit_btf
    if name == "FitOptions":
        from .tile_fit import FitOptions

        return FitOptions
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
