"""The IWE kernel of ego-motion is chosen explicitly, never from the dtype: the same events
give the same answer whether their pixels are integers or floats holding integers."""

from __future__ import annotations

import numpy as np
import pytest

from egomotion_synth import K240, synth
from evmotion.core.iwe import dequantize
from evmotion.errors import ParameterError
from evmotion.events import EventArray
from evmotion.methods.egomotion import estimate_egomotion

DTYPES = (np.uint16, np.int32, np.float32, np.float64)
TRUTH = {"rotation": ([0.5, -1.0, 0.8], [0.05, 0.05, 0.05]),
         "translation": ([300.0, -150.0], [8.0, 8.0])}


def _on_grid(name: str, dtype) -> EventArray:
    """Exact synthetic events rounded to the pixel grid (what a sensor reports)."""
    ev, _ = synth(name, TRUTH[name][0])
    return EventArray(np.round(ev.x).astype(dtype), np.round(ev.y).astype(dtype), ev.t, ev.p,
                      sensor_size=ev.sensor_size, validate=False)


@pytest.mark.parametrize("kernel", ["bilinear", "gaussian"])
@pytest.mark.parametrize("name", sorted(TRUTH))
def test_same_answer_whatever_the_coordinate_dtype(name, kernel):
    theta, tol = TRUTH[name]
    est = [estimate_egomotion(_on_grid(name, d), name, K=K240, kernel=kernel, maps=False).params
           for d in DTYPES]
    for p in est:
        # not the identity warp: on-grid events must not trap the optimizer at zero motion
        assert np.all(np.abs(p - theta) <= tol), (p, theta)
        np.testing.assert_allclose(p, est[0], rtol=1e-9, atol=1e-9)


def test_default_kernel_is_bilinear_and_agrees_with_gaussian():
    ev = _on_grid("rotation", np.float64)
    default = estimate_egomotion(ev, "rotation", K=K240, maps=False)
    bil = estimate_egomotion(ev, "rotation", K=K240, kernel="bilinear", maps=False)
    gau = estimate_egomotion(ev, "rotation", K=K240, kernel="gaussian", maps=False)
    np.testing.assert_array_equal(default.params, bil.params)
    np.testing.assert_allclose(bil.params, gau.params, atol=0.05)


def test_kernel_must_be_named():
    ev = _on_grid("translation", np.int32)
    for bad in ("auto", "box", None):
        with pytest.raises(ParameterError, match="kernel"):
            estimate_egomotion(ev, "translation", kernel=bad, maps=False)


def test_dequantize_spreads_grid_events_only():
    x = np.array([3, 3, 3, 0, 7])
    y = np.array([1, 1, 1, 5, 2])
    outs = [dequantize(x.astype(d), y.astype(d)) for d in DTYPES]
    for xd, yd in outs:
        np.testing.assert_array_equal(xd, outs[0][0])
        np.testing.assert_array_equal(yd, outs[0][1])
        assert xd.dtype == np.float64
    xd, yd = outs[0]
    # within the event's own pixel, and three events of one pixel at three places
    assert np.all(np.abs(xd - x) < 0.5) and np.all(np.abs(yd - y) < 0.5)
    assert len(set(zip(xd.tolist(), yd.tolist(), strict=True))) == 5
    # R2 sequence: the k-th event's offsets are frac(k a) - 1/2, frac(k b) - 1/2
    k = np.arange(1, 6)
    np.testing.assert_allclose(xd - x, np.mod(k * 0.7548776662466927, 1.0) - 0.5)
    np.testing.assert_allclose(yd - y, np.mod(k * 0.5698402909980532, 1.0) - 0.5)
    # off-grid (undistorted) coordinates are kept
    xf = np.array([1.25, 2.0])
    np.testing.assert_array_equal(dequantize(xf, np.array([0.0, 1.0]))[0], xf)
