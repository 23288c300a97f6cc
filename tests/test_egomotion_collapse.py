"""Event collapse on simulated forward motion (zoom), with the thesis' weights (Sec. 3.6.1):
without a regularizer the best zoom rate is the collapsed one (events squeezed to the focus
of expansion near h = 1/T); with the divergence, deformation and (one-sided) RCAD penalties
the best rate is near the truth. Landscape scans keep this fast; the TPE tables are in
benchmarks/bench_collapse.py. Also: the penalty in the cost is the regularizer's value
times lambda, nothing more (no extra time scaling), and RCAD penalizes only contraction."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.core.regularizers import DEFAULT_WEIGHTS, regularizer_value_grad
from evmotion.events import EventArray
from evmotion.methods.egomotion import cost_landscape, make_cost
from evmotion.sim import simulate


@pytest.fixture(scope="module")
def zoom_events():
    # 0.05 s: the true zoom (h T = 0.07) lies inside the thesis' margins
    sim = simulate("zoom", duration_s=0.05, sensor_size=(120, 160), seed=0, texture="noise",
                   show_progress=False)
    return sim.events, sim.gt.params(int(sim.events.t[0]))["hz"]


@pytest.mark.parametrize("objective", ["variance", "gradient_magnitude"])
def test_collapse_without_regularizer_and_cured_with_thesis_weights(zoom_events, objective):
    ev, hz = zoom_events
    t_ref = int(ev.t[0])
    span = (int(ev.t[-1]) - t_ref) * 1e-6
    vals = np.linspace(-0.99 / span, 0.99 / span, 67)
    plain = cost_landscape(ev, "zoom", 0, vals, objective=objective, t_ref=t_ref)
    base = vals[np.argmin(plain["cost"])]
    collapsed = base > 0.8 / span
    if objective == "variance":
        assert collapsed  # contraction to the FOE
    for reg in ("divergence", "deformation", "rcad"):
        land = cost_landscape(ev, "zoom", 0, vals, objective=objective, regularizer=reg,
                              t_ref=t_ref, dataset="dsec")
        best = vals[np.argmin(land["cost"])]
        if collapsed:  # >= 90 % closer to the truth than the collapsed optimum
            assert abs(best - hz) <= 0.1 * abs(base - hz), (reg, best, hz, base)
        else:  # a sound estimate is not moved by more than the scan's step
            assert abs(best - base) <= 1.01 * (vals[1] - vals[0]), (reg, best, base)


def _window(scale: float) -> EventArray:
    rng = np.random.default_rng(3)
    n = 4000
    t = np.sort(rng.integers(0, int(50_000 * scale), n))
    return EventArray(rng.uniform(5, 150, n), rng.uniform(5, 110, n), t,
                      rng.integers(0, 2, n), sensor_size=(120, 160), validate=False)


@pytest.mark.parametrize("reg", ["divergence", "deformation", "rcad"])
def test_penalty_is_lambda_times_regularizer(reg):
    ev = _window(1.0)
    lam = DEFAULT_WEIGHTS["dsec"][reg]
    cost, _ = make_cost(ev, "zoom", regularizer=reg, dataset="dsec")
    assert cost.weight == lam
    theta = np.array([12.0])  # h T = 0.6: contraction, every penalty active
    r, g = regularizer_value_grad(reg, cost.warp, cost.x, cost.y, cost.dt, theta, cost.shape)
    assert r > 0
    assert cost.parts(theta)["penalty"] == pytest.approx(lam * r, rel=1e-12)
    _, g_data = make_cost(ev, "zoom")[0].value_grad(theta)
    np.testing.assert_allclose(cost.value_grad(theta)[1], g_data + lam * g, rtol=1e-9)


@pytest.mark.parametrize("reg", ["divergence", "deformation", "rcad"])
def test_penalty_does_not_depend_on_the_time_unit(reg):
    # the same event motion over a window twice as long at half the rate: the warped events,
    # hence the focus and any per-window penalty, are the same
    a, _ = make_cost(_window(1.0), "zoom", regularizer=reg, dataset="mvsec")
    b, _ = make_cost(_window(2.0), "zoom", regularizer=reg, dataset="mvsec")
    pa, pb = a.parts(np.array([12.0])), b.parts(np.array([6.0]))
    assert pa["penalty"] > 0
    assert pb["penalty"] == pytest.approx(pa["penalty"], rel=1e-3)
    assert pb["focus"] == pytest.approx(pa["focus"], rel=1e-3)


def test_divergence_margin_applies_per_window():
    # zoom divergence per window is -2 h T; the thesis' margin -0.2 sits at h T = 0.1
    ev = _window(1.0)
    cost, _ = make_cost(ev, "zoom", regularizer="divergence", weight=1.0)
    T = cost.dt.max() - cost.dt.min()
    assert cost.parts(np.array([0.09 / T]))["penalty"] == 0.0
    assert cost.parts(np.array([0.3 / T]))["penalty"] == pytest.approx(0.6, rel=1e-6)


def test_rcad_penalizes_contraction_only():
    ev = _window(1.0)
    cost, _ = make_cost(ev, "zoom", regularizer="rcad", weight=1.0)
    T = cost.dt.max() - cost.dt.min()
    for hT in (-0.9, -0.3, -1e-3):
        th = np.array([hT / T])
        # (3.21) is negative for expansion: a signed term would reward it
        r, _ = regularizer_value_grad("rcad", cost.warp, cost.x, cost.y, cost.dt, th,
                                      cost.shape)
        assert r < 0
        assert cost.parts(th)["penalty"] == 0.0
        _, g_pen = cost.value_grad(th)
        _, g_plain = make_cost(ev, "zoom")[0].value_grad(th)
        np.testing.assert_allclose(g_pen, g_plain, rtol=1e-12)
    pen = [cost.parts(np.array([hT / T]))["penalty"] for hT in (0.1, 0.5, 0.9, 0.99)]
    np.testing.assert_allclose(pen, [-2 * np.log(1 - hT) for hT in (0.1, 0.5, 0.9, 0.99)],
                               rtol=1e-6)


def test_inplane_4dof_collapse_is_the_optimum_only_without_regularizer(zoom_events):
    # the 4-DOF warp of the thesis' tables: its collapse (h_z -> 1/T) beats the true motion
    # without a regularizer and loses to it with each penalty (thesis DSEC weights)
    ev, hz = zoom_events
    t_ref = int(ev.t[0])
    span = (int(ev.t[-1]) - t_ref) * 1e-6
    truth, collapse = np.array([0.0, 0.0, 0.0, hz]), np.array([0.0, 0.0, 0.0, 0.99 / span])
    plain, _ = make_cost(ev, "inplane", t_ref=t_ref)
    assert plain.value(collapse) < plain.value(truth)
    for reg in ("divergence", "deformation", "rcad"):
        cost, _ = make_cost(ev, "inplane", regularizer=reg, t_ref=t_ref, dataset="dsec")
        assert cost.value(truth) < cost.value(collapse), reg


def test_a_regularized_estimate_held_at_rest_restarts_from_the_plain_optimum(monkeypatch):
    """At the identity the divergence penalty can leave BFGS no slope: a zoom of 2 1/s came
    out at hz = 0.000 (cost -1.00), flagged (probe AH, on a rendered forward motion). An
    estimate that never left its start is started again from the plain optimum, and the
    lower regularized cost kept: 2.02 here (cost -2.94)."""
    import evmotion.methods.egomotion as eg
    from egomotion_synth import synth
    from evmotion.errors import PoorFitWarning

    ev = synth("zoom", np.array([2.0]), n_events=20000, seed=1)[0]
    real = eg._from_plain_optimum
    monkeypatch.setattr(eg, "_from_plain_optimum", lambda *a: a[5])  # keep the first
    # referenced at the window's start (the synthetic zoom's), where the penalty holds
    # the warp at rest
    with pytest.warns(PoorFitWarning, match="divergence regularizer holding the warp"):
        stuck = eg.estimate_egomotion(ev, warp="zoom", regularizer="divergence",
                                      t_ref="start")
    assert stuck.params[0] == 0.0 and not stuck.valid
    monkeypatch.setattr(eg, "_from_plain_optimum", real)
    res = eg.estimate_egomotion(ev, warp="zoom", regularizer="divergence", t_ref="start")
    assert res.params[0] == pytest.approx(2.0, abs=0.1) and res.valid
    assert res.cost < stuck.cost


def test_a_regularizer_references_the_warp_at_the_start_by_default(tmp_path):
    """With t_ref at the window's middle (the default since it is more accurate), the
    collapse penalties of the window's two halves cancel: a zoom collapsed (hz -7.7, det J
    0.03) with a divergence penalty of 0 (probe). With a regularizer the default is the
    start, where the penalties are defined; another time is warned about."""
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.methods.egomotion import estimate_egomotion, reference_time
    from evmotion.sim import simulate

    assert reference_time(None, None) == "mid" and reference_time(None, "rcad") == "start"
    ev = simulate("zoom", duration_s=0.05, sensor_size=(60, 80), seed=0,
                  show_progress=False).events
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = estimate_egomotion(ev, "zoom", regularizer="divergence", maps=False)
    assert res.t_ref_us == int(ev.t[0])
    with pytest.warns(EvmotionWarning, match="t_ref='mid' with the divergence regularizer"):
        estimate_egomotion(ev, "zoom", regularizer="divergence", t_ref="mid", maps=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)  # the start as a time: no word
        assert reference_time(int(ev.t[0]), "rcad", int(ev.t[0])) == int(ev.t[0])
