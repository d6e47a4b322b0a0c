"""The fabric presets offered in the UI (their maps: ``core.fabric.preset_maps``)."""

from ...core.fabric.preset_maps import PRESETS, preset_maps, tilted_quat

__all__ = ["PRESETS", "PRESET_ITEMS", "preset_maps", "tilted_quat"]

PRESET_ITEMS = [
    ("VELVET", "Velvet", "Short dense upright pile: strong grazing sheen"),
    ("CORDUROY", "Corduroy", "Anisotropic pile in ridges (wales)"),
    ("PLUSH", "Plush", "Long pile combed over by 30 degrees"),
]
