"""Panels: the sidebar (N panel, "Material Structures" tab) and material properties."""

from . import fabric, scratch, sidebar, teeth

CLASSES: list[type] = [*sidebar.CLASSES, *fabric.CLASSES, *teeth.CLASSES, *scratch.CLASSES]
