"""Keep lamp data in the inputs of shaders that evaluate lamps themselves (exact fabric path).

Lamp data does not reach OSL, so the add-on copies it into script-node inputs named
``Lamp<k>Type``, ``Lamp<k>Position``, ``Lamp<k>Direction``, ``Lamp<k>Color``, ``Lamp<k>SpotCos``,
``Lamp<k>SpotBlend`` (k = 1..4) and refreshes them from a depsgraph handler, so moving a lamp just
works. Units are converted here to what the shader needs (measured against Cycles' own diffuse
closure in tests/blender/test_fabric_shader.py):

* point and spot lamps: radiant intensity ``color * power / (4 pi)`` [W/sr] (spot: same intensity
  inside the cone, smoothstep blend at the edge);
* sun lamps: irradiance ``color * strength`` [W/m^2] on a surface facing the sun.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MAX_LAMPS = 4
LAMP_TYPE_CODES = {"POINT": 1, "SUN": 2, "SPOT": 3}


@dataclass(frozen=True)
class ShaderLamp:
    """One lamp as the shaders see it (world space)."""

    type_code: int
    position: tuple[float, float, float]
    direction: tuple[float, float, float]  # direction the light travels (lamp's -Z)
    color: tuple[float, float, float]  # intensity (point/spot) or irradiance (sun)
    spot_cos: float = -1.0
    spot_blend: float = 0.0


def shader_lamp(
    light_type: str,
    energy: float,
    color: tuple[float, float, float],
    position: tuple[float, float, float],
    direction: tuple[float, float, float],
    spot_size: float = math.pi,
    spot_blend: float = 0.0,
) -> ShaderLamp | None:
    """Convert Blender lamp settings to :class:`ShaderLamp`; ``None`` for unsupported types."""
    code = LAMP_TYPE_CODES.get(light_type)
    if code is None:
        return None
    scale = energy if light_type == "SUN" else energy / (4.0 * math.pi)
    rgb = tuple(float(c) * scale for c in color[:3])
    spot_cos = math.cos(spot_size / 2.0) if light_type == "SPOT" else -1.0
    blend = float(spot_blend) if light_type == "SPOT" else 0.0
    return ShaderLamp(code, tuple(map(float, position)), tuple(map(float, direction)), rgb, spot_cos, blend)


def scene_shader_lamps(scene) -> list:
    """(object, ShaderLamp) of the scene's visible point/sun/spot lamps, by name, at most MAX_LAMPS."""
    out = []
    for obj in sorted(scene.objects, key=lambda o: o.name):
        if obj.type != "LIGHT" or obj.hide_render:
            continue
        data = obj.data
        mw = obj.matrix_world
        direction = (-mw.col[2].xyz).normalized()
        lamp = shader_lamp(
            data.type,
            data.energy,
            tuple(data.color),
            tuple(mw.translation),
            tuple(direction),
            getattr(data, "spot_size", math.pi),
            getattr(data, "spot_blend", 0.0),
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
        _set(node, f"{prefix}Type", lamp.type_code if lamp else 0)
        if lamp:
            _set(node, f"{prefix}Position", lamp.position)
            _set(node, f"{prefix}Direction", lamp.direction)
            _set(node, f"{prefix}Color", (*lamp.color, 1.0))
            _set(node, f"{prefix}SpotCos", lamp.spot_cos)
            _set(node, f"{prefix}SpotBlend", lamp.spot_blend)


def _set(node, name, value) -> None:
    sock = node.inputs[name]
    current = sock.default_value
    try:
        same = tuple(current) == tuple(value)
    except TypeError:
        same = current == value
    if not same:  # avoid needless depsgraph updates (and handler recursion)
        sock.default_value = value
