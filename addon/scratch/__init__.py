"""Scratched metal in Blender (thesis ch. 4): shader group, packed scratch sets, lamp sync, tools."""
