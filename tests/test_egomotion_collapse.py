"""Event collapse on simulated forward motion (zoom): without a regularizer the best zoom
rate is the collapsed one (events squeezed to the focus of expansion at h = 1/T); with the
divergence, deformation and (one-sided) RCAD penalties the best rate is near the truth.
Landscape scans keep this fast; the TPE tables are in benchmarks/bench_collapse.py."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.methods.egomotion import cost_landscape
from evmotion.sim import simulate


@pytest.fixture(scope="module")
def zoom_events():
    sim = simulate("zoom", duration_s=0.1, sensor_size=(120, 160), seed=0, texture="noise",
                   show_progress=False)
    return sim.events, sim.gt.params(int(sim.events.t[0]))["hz"]


def test_collapse_without_regularizer_and_cured_with_each(zoom_events):
    ev, hz = zoom_events
    t_ref = int(ev.t[0])
    span = (int(ev.t[-1]) - t_ref) * 1e-6
    vals = np.linspace(-0.99 / span, 0.99 / span, 67)
    plain = cost_landscape(ev, "zoom", 0, vals, t_ref=t_ref)
    collapsed = vals[np.argmin(plain["cost"])]
    assert collapsed > 0.8 / span  # contraction to the FOE
    for reg, lam in (("divergence", 100.0), ("deformation", 100.0), ("rcad", 1.0)):
        land = cost_landscape(ev, "zoom", 0, vals, regularizer=reg, weight=lam, t_ref=t_ref)
        best = vals[np.argmin(land["cost"])]
        # >= 90 % closer to the truth than the collapsed optimum
        assert abs(best - hz) <= 0.1 * abs(collapsed - hz), (reg, best, hz, collapsed)
