"""Pile fabric in Blender: the "SGGX Fabric" node group, material builder, map import, brushing."""
