"""Scratched surfaces (thesis chapter 4): Werner et al. 2017 model, Velinov et al. 2018 integration.

Public API (all numpy, no bpy):

* scratch sets: :class:`ScratchSet`, :func:`make_scratch_set`, generators :func:`uniform_wear`,
  :func:`circular_polish`, :func:`hairline_brush`, :func:`from_curves`; files
  :func:`save_scratch_set`, :func:`load_scratch_set` (``.npz`` or EXR-table folder, see ``scratch_io``).
* shading entry point: :func:`scratch_radiance` (grid walk + footprint + light integral + colour) and
  :func:`scratch_radiance_pairs` for explicit point-segment pairs.
* lights: :class:`SphereLight`, :class:`PolygonLight`, :class:`DirectionalLight`, :class:`PointLight`.
* model terms (eq. 4.1-4.11) in ``scratch_model_terms`` and the coherent/incoherent BRDFs in
  ``scratch_brdf``; footprint (eq. 4.13-4.18) in ``scratch_footprint``; light integration
  (eq. 4.19-4.41) in ``light_integration``; Si (eq. 4.28-4.29) in ``sine_integral``; colour in
  ``cie_colour``; independent references in ``scratch_reference``.
"""

from .light_integration import DirectionalLight, PointLight, PolygonLight, SphereLight
from .scratch_generators import circular_polish, from_curves, hairline_brush, uniform_wear
from .scratch_io import load_scratch_set, save_scratch_set
from .scratch_radiance import ScratchShading, scratch_radiance, scratch_radiance_pairs
from .scratch_set import ScratchSet, make_scratch_set

__all__ = [
    "DirectionalLight",
    "PointLight",
    "PolygonLight",
    "ScratchSet",
    "ScratchShading",
    "SphereLight",
    "circular_polish",
    "from_curves",
    "hairline_brush",
    "load_scratch_set",
    "make_scratch_set",
    "save_scratch_set",
    "scratch_radiance",
    "scratch_radiance_pairs",
    "uniform_wear",
]
