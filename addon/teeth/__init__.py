"""Teeth in Blender (thesis chapter 5): Cycles materials, tooth object pairs with dentin shape keys,
fitting in a background process and the Cycles-vs-core cross-check. The model itself is ``core.teeth``.
"""
