"""Keep lamp data in the inputs of shaders that evaluate lamps themselves (exact fabric path).

Lamp data does not reach OSL, so the add-on copies it into script-node inputs named
``Lamp<k>Type``, ``Lamp<k>Position``, ``Lamp<k>Direction``, ``Lamp<k>Color``, ``Lamp<k>SpotCos``,
``Lamp<k>SpotBlend`` (k = 1..4) and refreshes them from a depsgraph handler, so moving a lamp just
works. Units are converted here to what the shader needs (measured against Cycles' own diffuse
closure in tests/blender/test_fabric_shader.py):

* point and spot lamps: radiant intensity ``color * power / (4 pi)`` [W/sr] (spot: same intensity
  inside the cone, smoothstep blend at the edge);
* sun lamps: irradiance ``color * strength`` [W/m^2] on a surface facing the sun;
* area lamps (square, rectangle, disk, ellipse): one-sided Lambertian emitters of radiance
  ``color * power / (pi * area)``, with half-extent vectors ``Lamp<k>AxisU``, ``Lamp<k>AxisV``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

MAX_LAMPS = 4
LAMP_TYPE_CODES = {"POINT": 1, "SUN": 2, "SPOT": 3, "AREA_RECT": 4, "AREA_ELLIPSE": 5}


@dataclass(frozen=True)
class ShaderLamp:
    """One lamp as the shaders see it (world space)."""

    type_code: int
    position: tuple[float, float, float]
    direction: tuple[float, float, float]  # direction the light travels (lamp's -Z)
    color: tuple[float, float, float]  # intensity (point/spot) or irradiance (sun)
    spot_cos: float = -1.0
    spot_blend: float = 0.0
    axis_u: tuple[float, float, float] = (0.0, 0.0, 0.0)  # area lamps: half extents (world)
    axis_v: tuple[float, float, float] = (0.0, 0.0, 0.0)


def shader_lamp(
    light_type: str,
    energy: float,
    color: tuple[float, float, float],
    position: tuple[float, float, float],
    direction: tuple[float, float, float],
    spot_size: float = math.pi,
    spot_blend: float = 0.0,
    area_shape: str = "SQUARE",
    axis_u: tuple[float, float, float] = (0.0, 0.0, 0.0),
    axis_v: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> ShaderLamp | None:
    """Convert Blender lamp settings to :class:`ShaderLamp`; ``None`` for unsupported types.

    For area lamps, ``axis_u``/``axis_v`` are the world-space half extents of the emitter.
    """
    if light_type == "AREA":
        light_type = "AREA_ELLIPSE" if area_shape in {"DISK", "ELLIPSE"} else "AREA_RECT"
    code = LAMP_TYPE_CODES.get(light_type)
    if code is None:
        return None
    if light_type == "SUN":
        scale = energy
    elif light_type.startswith("AREA"):
        hu, hv = math.sqrt(sum(c * c for c in axis_u)), math.sqrt(sum(c * c for c in axis_v))
        area = (4.0 if light_type == "AREA_RECT" else math.pi) * hu * hv
        if area <= 0.0:
            return None
        scale = energy / (math.pi * area)
    else:
        scale = energy / (4.0 * math.pi)
    rgb = tuple(float(c) * scale for c in color[:3])
    spot_cos = math.cos(spot_size / 2.0) if light_type == "SPOT" else -1.0
    blend = float(spot_blend) if light_type == "SPOT" else 0.0
    return ShaderLamp(
        code,
        tuple(map(float, position)),
        tuple(map(float, direction)),
        rgb,
        spot_cos,
        blend,
        tuple(map(float, axis_u)),
        tuple(map(float, axis_v)),
    )


def scene_shader_lamps(scene, keep=None) -> list:
    """(object, ShaderLamp) of the scene's visible point/sun/spot/area lamps (those ``keep(obj)`` accepts, where
    given), by name, at most MAX_LAMPS."""
    out = []
    for obj in sorted(scene.objects, key=lambda o: o.name):
        if obj.type != "LIGHT" or obj.hide_render or (keep is not None and not keep(obj)):
            continue
        data = obj.data
        mw = obj.matrix_world
        direction = (-mw.col[2].xyz).normalized()
        axis_u = axis_v = (0.0, 0.0, 0.0)
        if data.type == "AREA":
            size_y = data.size_y if data.shape in {"RECTANGLE", "ELLIPSE"} else data.size
            axis_u = tuple(mw.col[0].xyz * (data.size / 2.0))
            axis_v = tuple(mw.col[1].xyz * (size_y / 2.0))
        lamp = shader_lamp(
            data.type,
            data.energy,
            tuple(data.color),
            tuple(mw.translation),
            tuple(direction),
            getattr(data, "spot_size", math.pi),
            getattr(data, "spot_blend", 0.0),
            getattr(data, "shape", "SQUARE"),
            axis_u,
            axis_v,
        )
        if lamp is not None:
            out.append((obj, lamp))
    return out[:MAX_LAMPS]


def write_lamp_inputs(node, lamps: list[ShaderLamp]) -> None:
    """Write ``lamps`` into a script node's ``Lamp<k>*`` inputs (unused slots switched off)."""
    for k in range(1, MAX_LAMPS + 1):
        prefix = f"Lamp{k}"
        if f"{prefix}Type" not in node.inputs:
            return
        lamp = lamps[k - 1] if k <= len(lamps) else None
        set_if_changed(node, f"{prefix}Type", lamp.type_code if lamp else 0)
        if lamp:
            set_if_changed(node, f"{prefix}Position", lamp.position)
            set_if_changed(node, f"{prefix}Direction", lamp.direction)
            set_if_changed(node, f"{prefix}Color", (*lamp.color, 1.0))
            set_if_changed(node, f"{prefix}SpotCos", lamp.spot_cos)
            set_if_changed(node, f"{prefix}SpotBlend", lamp.spot_blend)
            if f"{prefix}AxisU" in node.inputs:
                set_if_changed(node, f"{prefix}AxisU", lamp.axis_u)
                set_if_changed(node, f"{prefix}AxisV", lamp.axis_v)


def set_if_changed(node, name, value) -> None:
    """Write ``value`` into the node's input ``name`` unless it holds it already, compared as the socket
    stores it (a needless write tags the material: a depsgraph update, and handler recursion)."""
    sock = node.inputs[name]
    current = sock.default_value
    try:  # compared as the socket stores it (float32): a float64 value would never look equal
        same = bool(np.array_equal(np.asarray(current, np.float32), np.asarray(value, np.float32)))
    except (TypeError, ValueError):
        same = current == value
    if not same:
        sock.default_value = value
