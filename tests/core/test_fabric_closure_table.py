"""The precomputed closure table (core.fabric.closure_table) against the fit it tabulates."""

from __future__ import annotations

import numpy as np

from material_structures.core.fabric import closure_table as T
from material_structures.core.fabric.closure_fit import _canonical_params, closure_eval, fit_keys
from material_structures.core.fabric.preset_maps import tilted_quat
from material_structures.core.fabric.quaternion import quat_from_axis_angle, quat_multiply


def _mix(sigma, quat, params):
    """The k_s = 1 closure mix of (K,) geometries on a direction grid (K, L, V, 1)."""
    from material_structures.core.fabric.closure_fit import hemisphere_grid

    w, s, c = params
    wi = hemisphere_grid(8, 16)[None, :, None, :]
    wo = hemisphere_grid(4, 8, offset=0.3)[None, None, :, :]
    return closure_eval(wi, wo, 0.0, 1.0, sigma[:, None, None, :], quat[:, None, None, :],
                        (w[:, None, None], s[:, None, None], c[:, None, None]))


def _rel(a, b):
    return np.sqrt(np.mean((a - b) ** 2, axis=(1, 2, 3)) / np.mean(b**2, axis=(1, 2, 3)))


def test_table_holds_the_current_fit():
    """The stored nodes' closure mixes = those of fit_keys now (relative RMS 5e-3: the table is built
    with numpy 2.x; numpy 1.26 gives up to 2e-3 from near-ties between the fit's active sets, and a
    closure of zero weight may differ in shape). Fails when the fit changes and the table was not
    rebuilt (python -m material_structures.core.fabric.closure_table)."""
    with np.load(T.TABLE_PATH) as data:
        keys, params = data["keys"].astype(float), data["params"].astype(float)
    exact = T.table_keys()  # the build's float64 keys (stored as float32: near-ties would flip)
    np.testing.assert_allclose(keys, exact, atol=1e-5)
    pick = np.random.default_rng(0).choice(len(keys), 6, replace=False)
    sigma, quat = _canonical_params(exact[pick])
    p = params[pick]
    stored = (p[:, :20].reshape(-1, 5, 4), p[:, 20:26], p[:, 26:27])
    assert np.all(_rel(_mix(sigma, quat, stored), _mix(sigma, quat, fit_keys(sigma, quat)[:3])) <= 5e-3)


def test_lookup_at_a_node_is_the_fit_and_between_nodes_interpolates():
    key = np.array([[T.LOG_SIGMA[3], T.LOG_SIGMA[7], T.TILT[2], T.TWIST[1]]])
    sigma, quat = _canonical_params(key)
    table, fit = T.lookup_closure_texels(sigma, quat), fit_keys(sigma, quat)[:3]
    assert _rel(_mix(sigma, quat, table), _mix(sigma, quat, fit))[0] <= 5e-3  # as above
    # halfway along the tilt axis: the mean of the two nodes' parameters (multilinear), 1e-5
    mid = key.copy()
    mid[0, 2] = 0.5 * (T.TILT[2] + T.TILT[3])
    other = key.copy()
    other[0, 2] = T.TILT[3]
    expect = 0.5 * (T.interpolate(key) + T.interpolate(other))
    np.testing.assert_allclose(T.interpolate(mid), expect, atol=1e-5)


def test_swapped_sigma_with_quarter_turn_is_the_same_ellipsoid():
    """(sigma_x, sigma_y) with a0 turned 90 degrees about a2 and the sigmas swapped is the same SGGX
    lobe: the same closures (1e-6)."""
    q = tilted_quat(25.0, 70.0)
    quarter = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), np.pi / 2)  # about the fibre z axis
    q2 = quat_multiply(q, quarter)
    a = T.lookup_closure_texels(np.array([[0.4, 1.3]]), q[None])
    b = T.lookup_closure_texels(np.array([[1.3, 0.4]]), q2[None])
    for x, y in zip(a, b, strict=True):
        np.testing.assert_allclose(x, y, atol=1e-6)


def test_table_closures_close_to_the_fit_off_the_nodes():
    """Off-node geometries: the interpolated mix against the exact fit's mix, relative RMS over light
    and view directions of the k_s = 1 term, median over 12 random geometries <= 0.1 (measured 0.0x)."""
    rng = np.random.default_rng(5)
    keys = np.stack([rng.uniform(np.log(0.1), np.log(3.0), 12), rng.uniform(np.log(0.1), np.log(3.0), 12),
                     rng.uniform(0, 40, 12), rng.uniform(0, 180, 12)], -1)
    sigma, quat = _canonical_params(keys)
    rel = _rel(_mix(sigma, quat, T.lookup_closure_texels(sigma, quat)), _mix(sigma, quat, fit_keys(sigma, quat)[:3]))
    assert np.median(rel) <= 0.1, rel
