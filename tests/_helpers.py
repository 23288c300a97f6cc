"""Assertions shared by the tests (imported as ``from _helpers import ...``; pytest puts
this folder on sys.path)."""

from __future__ import annotations

import numpy as np
import pytest


def assert_same_events(a, b, *, dtypes: bool = False) -> None:
    """``a`` and ``b`` hold the same events: equal length, sensor size and x, y, t, p
    columns (and column dtypes with ``dtypes=True``)."""
    assert len(a) == len(b) and a.sensor_size == b.sensor_size
    for f in "xytp":
        if dtypes:
            assert getattr(a, f).dtype == getattr(b, f).dtype, f
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def assert_grad_matches_central_differences(fn, theta, g, step, rel, abs_frac) -> None:
    """Each component of the gradient ``g`` of ``fn`` at ``theta`` against a central
    difference of step ``step * max(1, |theta_j|)`` (tolerance ``rel``, and ``abs_frac`` of
    the largest gradient component)."""
    for j in range(theta.size):
        h = step * max(1.0, abs(theta[j]))
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        fd = (fn(tp) - fn(tm)) / (2 * h)
        assert g[j] == pytest.approx(fd, rel=rel, abs=abs_frac * np.abs(g).max())
