"""Pure numpy/scipy implementation of the thesis' appearance models.

Nothing under ``core`` imports ``bpy``: everything here is usable and tested without Blender.
Subpackages: ``fabric`` (chapter 3), ``scratch`` (chapter 4), ``teeth`` (chapter 5).
"""
