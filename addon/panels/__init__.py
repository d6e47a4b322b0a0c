"""Panels: the sidebar (N panel, "Material Structures" tab) and material properties."""

from . import sidebar

CLASSES: list[type] = [*sidebar.CLASSES]
