"""From points on a mesh (ray hits, recorded 3D strokes) to UV coordinates."""

from __future__ import annotations

from mathutils import Vector
from mathutils.bvhtree import BVHTree
from mathutils.geometry import barycentric_transform


class MeshUVLookup:
    """World-space BVH over an object's (evaluated) loop triangles with their UVs."""

    def __init__(self, obj, depsgraph=None):
        if obj.type != "MESH":
            raise ValueError(f"'{obj.name}' is not a mesh")
        source = obj.evaluated_get(depsgraph) if depsgraph is not None else obj
        mesh = source.to_mesh()
        try:
            if not mesh.uv_layers:
                raise ValueError(f"'{obj.name}' has no UV map")
            uv_layer = mesh.uv_layers.active or mesh.uv_layers[0]
            mesh.calc_loop_triangles()
            mw = obj.matrix_world
            self.verts = [mw @ v.co for v in mesh.vertices]
            self.tris = [tuple(t.vertices) for t in mesh.loop_triangles]
            self.tri_uvs = [
                tuple(Vector((*uv_layer.data[li].uv, 0.0)) for li in t.loops) for t in mesh.loop_triangles
            ]
        finally:
            source.to_mesh_clear()
        if not self.tris:
            raise ValueError(f"'{obj.name}' has no faces")
        self.bvh = BVHTree.FromPolygons(self.verts, self.tris)

    def _uv(self, location, index):
        a, b, c = (self.verts[i] for i in self.tris[index])
        ua, ub, uc = self.tri_uvs[index]
        uv = barycentric_transform(location, a, b, c, ua, ub, uc)
        return (uv.x, uv.y)

    def ray_cast(self, origin, direction):
        """UV of the first hit along the ray, or None."""
        location, _normal, index, _dist = self.bvh.ray_cast(Vector(origin), Vector(direction))
        return None if index is None else self._uv(location, index)

    def under_mouse(self, context, event):
        """UV under the mouse cursor of a 3D viewport event, or None."""
        from bpy_extras import view3d_utils

        region, rv3d = context.region, context.region_data
        coord = (event.mouse_region_x, event.mouse_region_y)
        origin = view3d_utils.region_2d_to_origin_3d(region, rv3d, coord)
        direction = view3d_utils.region_2d_to_vector_3d(region, rv3d, coord)
        return self.ray_cast(origin, direction)

    def nearest(self, point, max_distance: float = 1e30):
        """UV of the closest surface point to ``point``, or None."""
        location, _normal, index, _dist = self.bvh.find_nearest(Vector(point), max_distance)
        return None if index is None else self._uv(location, index)
