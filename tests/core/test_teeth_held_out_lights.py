"""The fit's check holds out the lights farthest off the capture's axis (``optimise.held_out_light_ids``), so it
measures how the fit predicts lights outside the cone it was trained in."""

from __future__ import annotations

import numpy as np

from material_structures.core.teeth.capture import Camera, Capture, PointLight
from material_structures.core.teeth.optimise import held_out_light_ids, light_angles_deg


def _rig(light_deg: list[float], azimuth_deg: list[float]) -> tuple[Capture, np.ndarray]:
    """Two cameras symmetric about the +z axis through the target (5, 0, 0); lights 100 mm away at the given
    angles off +z, turned about it by the given azimuths."""
    target = np.array([5.0, 0.0, 0.0])
    cams = [Camera.look_at(target + 80.0 * np.array([np.sin(a), 0.0, np.cos(a)]), target, (0, 1, 0), 20.0, 8, 8)
            for a in np.radians([-15.0, 15.0])]
    lights = []
    for theta, phi in zip(np.radians(light_deg), np.radians(azimuth_deg), strict=True):
        d = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
        lights.append(PointLight(target + 100.0 * d, np.ones(3)))
    return Capture(cams, lights), target


def test_light_angles_are_measured_off_the_mean_camera_direction():
    deg = [0.0, 10.0, 35.0, 60.0, 84.0, 120.0]
    cap, target = _rig(deg, [0.0, 90.0, 200.0, 45.0, 300.0, 10.0])
    np.testing.assert_allclose(light_angles_deg(cap, target), deg, atol=1e-9)


def test_the_check_holds_out_the_lights_farthest_off_the_axis():
    deg = [5.0, 84.0, 20.0, 30.0, 56.0, 10.0, 70.0, 45.0, 15.0, 25.0, 35.0, 40.0]
    cap, target = _rig(deg, [37.0 * i for i in range(len(deg))])
    assert held_out_light_ids(cap, target, 3).tolist() == [1, 4, 6]  # 84, 56 and 70 degrees
    assert held_out_light_ids(cap, target, 1).tolist() == [1]
    assert held_out_light_ids(cap, target, 10).tolist() == [1, 4, 6]  # at most a quarter of the 12 lights
    assert held_out_light_ids(cap, target, 0).tolist() == []
    few, _ = _rig(deg[:3], [0.0, 0.0, 0.0])
    assert held_out_light_ids(few, target, 3).tolist() == []  # fewer than 4 lights: no check
