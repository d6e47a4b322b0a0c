"""Pile fabric appearance model (thesis chapter 3): SGGX-based BRDF, BTF fitting, brushing.

Public API (pure numpy, no bpy):

- model: :func:`sggx_brdf` (eq. 3.9), :func:`sggx_specular`, :func:`sggx_matrix` (eq. 3.6-3.8),
  :func:`sggx_ndf` (eq. 3.5), :func:`projected_area`, :func:`sample_specular`, :func:`specular_pdf`.
"""

from .quaternion import matrix_to_quat, quat_slerp, quat_to_matrix
from .sggx_brdf import sggx_brdf, sggx_btf_value, sggx_specular
from .sggx_matrix import projected_area, sggx_matrix
from .sggx_ndf import sggx_ndf
from .sggx_sampling import sample_specular, sample_visible_normal, specular_pdf

__all__ = [
    "matrix_to_quat",
    "projected_area",
    "quat_slerp",
    "quat_to_matrix",
    "sample_specular",
    "sample_visible_normal",
    "sggx_brdf",
    "sggx_btf_value",
    "sggx_matrix",
    "sggx_ndf",
    "sggx_specular",
    "specular_pdf",
]
