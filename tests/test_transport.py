"""Upwind and Burgers transport (App. B): numpy reference of one step, CFL sub-stepping,
invariants, and the adjoint against finite differences."""

import numpy as np
import pytest

from evmotion.errors import ParameterError
from evmotion.methods import transport as tr


def _step_ref(v, dt, scheme):
    """Plain-numpy explicit step with Neumann (edge-replicated) borders."""
    vp = np.pad(v, ((0, 0), (1, 1), (1, 1)), mode="edge")
    c = vp[:, 1:-1, 1:-1]
    left, right = vp[:, 1:-1, :-2], vp[:, 1:-1, 2:]
    up, down = vp[:, :-2, 1:-1], vp[:, 2:, 1:-1]
    vx, vy = c[0], c[1]
    dx = np.where(vx > 0, c - left, right - c)  # upwind: info comes from behind the motion
    dy = np.where(vy > 0, c - up, down - c)
    if scheme == "upwind":
        ux = vx * dx[0]
        uy = vy * dy[1]
    else:
        ux = 0.5 * (vx * np.abs(vx) + np.where(right[0] < 0, right[0] ** 2, 0)
                    - np.where(left[0] > 0, left[0] ** 2, 0))
        uy = 0.5 * (vy * np.abs(vy) + np.where(down[1] < 0, down[1] ** 2, 0)
                    - np.where(up[1] > 0, up[1] ** 2, 0))
    return np.stack([vx - dt * (ux + vy * dy[0]), vy - dt * (vx * dx[1] + uy)])


@pytest.mark.parametrize("scheme", ["upwind", "burgers"])
def test_step_matches_numpy_reference(scheme):
    rng = np.random.default_rng(0)
    v = rng.normal(size=(2, 9, 11))
    out = np.empty_like(v)
    tr._step(v, 0.2, scheme == "burgers", out)
    np.testing.assert_allclose(out, _step_ref(v, 0.2, scheme), atol=1e-12)


@pytest.mark.parametrize("scheme", ["upwind", "burgers"])
def test_constant_flow_is_invariant(scheme):
    v = np.stack([np.full((8, 8), 3.0), np.full((8, 8), -2.0)])
    np.testing.assert_allclose(tr.transport(v, 5.0, scheme), v)
    np.testing.assert_allclose(tr.transport(v, -5.0, scheme), v)


@pytest.mark.parametrize("scheme", ["upwind", "burgers"])
def test_large_displacement_stays_stable(scheme):
    # 20 px of motion in one call: a single step would blow up; CFL sub-steps must not
    rng = np.random.default_rng(1)
    v = np.zeros((2, 32, 32))
    v[0, :, :16] = 20.0
    v[0] += rng.normal(scale=0.5, size=(32, 32))
    out = tr.transport(v, 1.0, scheme)
    assert np.isfinite(out).all()
    assert np.abs(out).max() <= np.abs(v).max() + 1e-9  # no new extrema (monotone schemes)


def test_edge_is_transported_with_the_flow():
    # a step of u moving right: after 1 time unit the front moved ~u px right
    v = np.zeros((2, 4, 40))
    v[0, :, :10] = 5.0
    out = tr.transport(v, 1.0, "burgers")
    front = np.argmax(out[0, 2] < 2.5)
    assert 13 <= front <= 17  # rarefaction/shock front of Burgers moves at ~u/2..u


@pytest.mark.parametrize("scheme", ["upwind", "burgers"])
def test_adjoint_matches_finite_differences(scheme):
    rng = np.random.default_rng(2)
    v0 = rng.normal(scale=2.0, size=(2, 10, 12))
    times = np.array([-0.9, -0.3, 0.0, 0.3, 0.9])
    grads = [rng.normal(size=v0.shape) for _ in times]

    def loss(v):
        plan = tr.transport_to_times(v, times, scheme)
        return sum((g * f).sum() for g, f in zip(grads, plan.flows, strict=True))

    plan = tr.transport_to_times(v0, times, scheme)
    ga = tr.transport_adjoint(plan, grads)
    d = rng.normal(size=v0.shape)
    e = 1e-6
    fd = (loss(v0 + e * d) - loss(v0 - e * d)) / (2 * e)
    assert (ga * d).sum() == pytest.approx(fd, rel=1e-6)


def test_plan_flows_match_direct_transport():
    rng = np.random.default_rng(3)
    v0 = rng.normal(size=(2, 6, 6))
    plan = tr.transport_to_times(v0, np.array([-0.7, 0.7]), "upwind")
    np.testing.assert_allclose(plan.flows[1], tr.transport(v0, 0.7, "upwind"))
    np.testing.assert_allclose(plan.flows[0], tr.transport(v0, -0.7, "upwind"))


def test_unknown_scheme_raises():
    with pytest.raises(ParameterError, match="scheme"):
        tr.transport(np.zeros((2, 3, 3)), 1.0, "lax")
