"""Time to contact (3.31) from the zoom parameter, against a pinhole forward motion."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.core.warps import make_warp
from evmotion.errors import ParameterError
from evmotion.methods.ttc import depth_from_ttc, speed_from_ttc, time_to_contact

H, W = 260, 346
K = np.array([[220.0, 0, (W - 1) / 2], [0, 220.0, (H - 1) / 2], [0, 0, 1]])


def _forward_motion(vz, Z, n=500, T=0.05, seed=0):
    """Events of a fronto-parallel plane at depth Z (m), camera moving forward at vz (m/s)."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1, 1, (n, 2)) * Z * 0.5
    t = np.sort(rng.uniform(0, T, n))
    depth = Z - vz * t
    u = K[0, 0] * X[:, 0] / depth + K[0, 2]
    v = K[1, 1] * X[:, 1] / depth + K[1, 2]
    u0 = K[0, 0] * X[:, 0] / Z + K[0, 2]
    v0 = K[1, 1] * X[:, 1] / Z + K[1, 2]
    return u, v, t, u0, v0


def test_zoom_rate_is_inverse_ttc_of_forward_motion():
    vz, Z = 10.0, 25.0
    u, v, t, u0, v0 = _forward_motion(vz, Z)
    w = make_warp("zoom", (H, W))
    hz = vz / Z  # (3.31)
    # the zoom warp with h_z = v_z / Z undoes the forward motion exactly (t_ref = 0)
    xw, yw = w.warp(u, v, t, np.array([hz]))
    np.testing.assert_allclose(xw, u0, atol=1e-9)
    np.testing.assert_allclose(yw, v0, atol=1e-9)
    # its motion field is (3.29) with V = (0, 0, v_z), omega = 0: v = (v_z / Z) x
    of = w.optical_flow(u0, v0, np.array([hz]))
    np.testing.assert_allclose(of[0], hz * (u0 - K[0, 2]))
    r = time_to_contact(np.array([hz]), w, window_s=0.05)
    assert r.ttc_s == pytest.approx(Z / vz)
    assert r.expansion_rate == pytest.approx(hz)
    assert r.h_z_normalized == pytest.approx(hz * 0.05)
    assert r.approaching
    assert depth_from_ttc(r.ttc_s, vz) == pytest.approx(Z)
    assert speed_from_ttc(r.ttc_s, Z) == pytest.approx(vz)


@pytest.mark.parametrize(("name", "theta", "rate"), [
    ("inplane", [3.0, 1.0, 0.0, 0.4], 0.4),
    ("similarity", [3.0, 1.0, 0.7, 0.4], 0.4),
    ("affine", [3.0, 1.0, 0.3, 0.2, -0.2, 0.5], 0.4),
    ("homography", [0.3, 0.2, 5.0, -0.2, 0.5, 1.0, 0.0, 0.0], 0.4),
])
def test_expansion_rate_of_other_warps(name, theta, rate):
    w = make_warp(name, (H, W), K=K)
    r = time_to_contact(np.array(theta), w, window_s=0.02)
    assert r.expansion_rate == pytest.approx(rate, abs=1e-12)


@pytest.mark.parametrize("name", ["translation", "se2", "rotation"])
def test_warps_without_expansion_are_refused(name):
    """They returned an infinite time to contact, which reads as a measurement (probe AI);
    a warp's name instead of the warp raised AttributeError."""
    from evmotion.errors import ParameterError

    w = make_warp(name, (H, W), K=K)
    with pytest.raises(ParameterError, match=f"the {name} warp cannot expand the image"):
        time_to_contact(np.zeros(w.n_params), w, window_s=0.02)
    # the name, as an EgomotionResult holds it, says what to give (probe BY)
    with pytest.raises(ParameterError, match=r"got the name 'zoom' .*make_warp\('zoom', "
                                             r"events.sensor_size\)"):
        time_to_contact(np.zeros(1), "zoom", window_s=0.02)
    with pytest.raises(ParameterError, match="warp must be a Warp"):
        time_to_contact(np.zeros(1), 3, window_s=0.02)


def test_many_windows_and_receding():
    w = make_warp("zoom", (H, W))
    r = time_to_contact(np.array([[0.5], [-0.25], [0.0]]), w, window_s=0.1)
    np.testing.assert_allclose(r.ttc_s, [2.0, -4.0, np.inf])
    np.testing.assert_array_equal(r.approaching, [True, False, False])


def test_bad_arguments():
    w = make_warp("zoom", (H, W))
    with pytest.raises(ParameterError, match="window_s"):
        time_to_contact(np.array([0.5]), w, window_s=0.0)
    with pytest.raises(ParameterError, match=r"shape \(1,\)"):
        time_to_contact(np.array([0.5, 1.0]), w, window_s=0.1)
    with pytest.raises(ParameterError, match="finite"):
        time_to_contact(np.array([np.nan]), w, window_s=0.1)
