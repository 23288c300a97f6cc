"""Triplet matching on simulated translations with ground truth (evmotion.sim)."""

from __future__ import annotations

import numpy as np
import pytest

import evmotion.sim as sim
from evmotion.methods.triplet import estimate_flow_triplet


@pytest.mark.parametrize(("vx", "vy"), [(200.0, 0.0), (0.0, -180.0), (-120.0, 0.0)])
def test_simulated_translation_direction_and_speed(vx, vy):
    # One event per pixel crossing (threshold 0.5 on a checkerboard): the setting where
    # (5.2)'s equal-step condition holds exactly; bursts of several events per edge blur it.
    # Axis-aligned motions only: the checkerboard's edges are axis-aligned, so a diagonal
    # motion would show only normal flow along each edge (aperture problem).
    res = sim.simulate("translation", duration_s=0.12, sensor_size=(48, 64), seed=0,
                       params={"vx": vx, "vy": vy}, frame_rate=45.0, threshold=0.5,
                       texture="checker", show_progress=False)
    ev = res.events
    wins = ev.windows_at(res.gt.frame_times_us, dt=1)[2:]
    out = estimate_flow_triplet(ev, wins)
    for k, w in enumerate(wins):
        f = out.flow[k][out.valid[k]]
        gt = res.gt.flow((w.t0 + w.t1) // 2)[24, 32]
        np.testing.assert_allclose(gt, [vx, vy], atol=1e-3)
        med = np.median(f, axis=0)
        assert np.hypot(*(med - gt)) < 0.05 * np.hypot(vx, vy), (med, gt)
