"""Assertions shared by the I/O tests (imported as ``from _helpers import ...``; pytest puts
this folder on sys.path)."""

from __future__ import annotations

import numpy as np


def assert_same_events(a, b, *, dtypes: bool = False) -> None:
    """``a`` and ``b`` hold the same events: equal length, sensor size and x, y, t, p
    columns (and column dtypes with ``dtypes=True``)."""
    assert len(a) == len(b) and a.sensor_size == b.sensor_size
    for f in "xytp":
        if dtypes:
            assert getattr(a, f).dtype == getattr(b, f).dtype, f
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
