"""Normal flow of the triplets' time-surface gradient and the ``dense="lsq"`` batch output
(an extension of thesis ch. 5): against a literal least-squares reference, exact on straight
edges, recovering the full flow where edges of two orientations meet, and on simulation."""

from __future__ import annotations

import numpy as np
import pytest

from _helpers import mean_window_aee
from _triplet_reference import triplet_reference
from evmotion.errors import ParameterError
from evmotion.events import EventArray
from evmotion.methods.triplet import (
    TripletFlow,
    TripletMatcher,
    add_normal_voxels,
    dense_lsq_from_sums,
    estimate_flow_triplet,
    max_normal_speed,
)
from test_triplet import edge_events, moving_dots


@pytest.mark.parametrize(("seed", "kw"), [(0, {}), (1, {"dx": 2.3, "tau_us": 1_000}),
                                          (2, {"quadruple": True}), (3, {"normal_kappa": 1}),
                                          (4, {"dx": 2.3, "tau_us": 1_000,
                                               "normal_kappa": 16})])
def test_normal_flow_matches_literal_least_squares(seed, kw):
    ev = moving_dots(seed, n_dots=20)
    flow = TripletMatcher(ev.sensor_size, depth=32, **kw).process(ev)
    *_, nx, ny = triplet_reference(ev.x, ev.y, ev.t, ev.p, with_normal=True, **kw)
    assert np.count_nonzero(nx) > 20
    np.testing.assert_allclose(flow.nx, nx, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(flow.ny, ny, rtol=1e-5, atol=1e-3)


def grating_events(v: np.ndarray, normals: list[tuple[float, float]], size: int = 48,
                   period: float = 12.0, duration_us: int = 400_000) -> EventArray:
    """Families of straight parallel edges (one per normal, ``period`` px apart) moving with
    the same velocity ``v`` (px/s): a pixel fires when an edge of a family reaches it, at
    ``t = (x . n - c) / (v . n)``. Family ``i`` has polarity ``i % 2`` (edges of opposite
    contrast), so that no triplet mixes two families."""
    yy, xx = np.mgrid[0:size, 0:size]
    xs, ys, ts, ps = [], [], [], []
    for i, n in enumerate(normals):
        n = np.asarray(n, float) / np.hypot(*n)
        s = xx * n[0] + yy * n[1]
        speed = float(v @ n)
        for c in np.arange(s.min() - speed * duration_us * 1e-6 - period, s.max() + period,
                           period):
            t = (s - c) / speed * 1e6
            ok = (t >= 0) & (t < duration_us)
            xs.append(xx[ok])
            ys.append(yy[ok])
            ts.append(np.rint(t[ok]).astype(np.int64))
            ps.append(np.full(ok.sum(), i % 2))
    x, y, t, p = (np.concatenate(a) for a in (xs, ys, ts, ps))
    order = np.argsort(t, kind="stable")
    return EventArray(x[order], y[order], t[order], p[order], (size, size))


@pytest.mark.parametrize(("speed", "angle"), [(120.0, 0.0), (80.0, 30.0), (150.0, 115.0)])
def test_straight_edge_gives_its_normal_flow(speed, angle):
    ev = edge_events(speed, angle)
    flow = TripletMatcher(ev.sensor_size).process(ev)
    n = np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    ok = np.hypot(flow.nx, flow.ny) > 0
    assert ok.sum() > 0.5 * len(ev)
    # rounding event times to 1 us is the only error
    u = np.stack([flow.nx[ok], flow.ny[ok]], 1)
    np.testing.assert_allclose(np.median(u, axis=0), speed * n, atol=0.01 * speed)
    assert np.percentile(np.hypot(*(u - speed * n).T), 90) < 0.05 * speed


def test_lsq_resolves_the_aperture_where_the_mean_cannot():
    v = np.array([60.0, -25.0])
    ev = grating_events(v, [(1.0, 0.2), (0.3, -1.0)])
    # after 100 ms of history, 300 ms: every pixel sees edges of both families
    win = ev.windows_at(np.array([100_000, 400_000]), dt=1)[0]
    lsq = estimate_flow_triplet(ev, [win], dense="lsq")
    mean = estimate_flow_triplet(ev, [win])
    inner = np.zeros(ev.sensor_size, bool)
    inner[8:-8, 8:-8] = True
    err_lsq = np.hypot(*(lsq.flow[0][inner & lsq.valid[0]] - v).T)
    err_mean = np.hypot(*(mean.flow[0][inner & mean.valid[0]] - v).T)
    assert np.median(err_lsq) < 0.03 * np.hypot(*v)
    assert np.median(err_mean) > 3 * np.median(err_lsq)


def test_single_orientation_stays_at_the_normal_flow():
    v = np.array([60.0, 40.0])
    n = np.array([1.0, 0.0])
    ev = grating_events(v, [tuple(n)])
    lsq = estimate_flow_triplet(ev, ev.windows_by_duration(100_000)[2:3], dense="lsq")
    f = lsq.flow[0][8:-8, 8:-8][lsq.valid[0][8:-8, 8:-8]]
    # the ridge shrinks the unconstrained component to 0 and the normal one by 1/(1 + ridge/2)
    np.testing.assert_allclose(np.median(f, axis=0), [60.0 / 1.005, 0.0], atol=1.0)


def _dense_lsq_numpy(acc, cnt, size, ridge):
    r = size // 2
    nb, h, w = cnt.shape
    out = np.zeros((h, w, 2))
    nbins = np.zeros((h, w))
    for b in range(nb):
        for yy in range(h):
            for xx in range(w):
                sl = (b, slice(max(yy - r, 0), yy + r + 1), slice(max(xx - r, 0), xx + r + 1))
                if cnt[sl].sum() == 0:
                    continue
                s = acc[sl].reshape(-1, 5).sum(0)
                m = np.array([[s[0], s[1]], [s[1], s[2]]]) + ridge * 0.5 * (s[0] + s[2]) * np.eye(2)
                out[yy, xx] += np.linalg.solve(m, s[3:])
                nbins[yy, xx] += 1
    mask = nbins > 0
    out[mask] /= nbins[mask][:, None]
    return out, mask


@pytest.mark.parametrize(("size", "n_bins"), [(1, 1), (3, 2), (5, 1)])
def test_dense_lsq_matches_numpy(size, n_bins):
    ev = moving_dots(7, n_dots=20)
    flow = TripletMatcher(ev.sensor_size).process(ev)
    acc = np.zeros((n_bins, *ev.sensor_size, 5))
    cnt = np.zeros((n_bins, *ev.sensor_size), np.int64)
    add_normal_voxels(ev, flow, ev.t_start, ev.t_end + 1, acc, cnt, vmax=1e9)
    assert cnt.sum() > 50
    got, mask = dense_lsq_from_sums(acc, cnt, filter_size=size, ridge=0.05)
    ref, rmask = _dense_lsq_numpy(acc, cnt, size, 0.05)
    np.testing.assert_array_equal(mask, rmask)
    np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-3)


def test_normal_voxels_drop_inadmissible_speeds():
    ev = EventArray([1, 2], [1, 1], [0, 10], [1, 1], (4, 4))
    flow = TripletFlow(np.zeros(2, np.float32), np.zeros(2, np.float32), np.ones(2, bool),
                       np.ones(2, np.int32), np.array([50.0, 5000.0], np.float32),
                       np.zeros(2, np.float32))
    acc = np.zeros((1, 4, 4, 5))
    cnt = np.zeros((1, 4, 4), np.int64)
    add_normal_voxels(ev, flow, 0, 11, acc, cnt, vmax=max_normal_speed(np.sqrt(2), 3_000))
    assert cnt[0, 1, 1] == 1 and cnt[0, 1, 2] == 0
    np.testing.assert_allclose(acc[0, 1, 1], [1.0, 0.0, 0.0, 50.0, 0.0])


def test_bad_dense_options():
    ev = edge_events(100.0)
    with pytest.raises(ParameterError, match="dense"):
        estimate_flow_triplet(ev, dense="median")
    with pytest.raises(ParameterError, match="ridge"):
        dense_lsq_from_sums(np.zeros((1, 2, 2, 5)), np.zeros((1, 2, 2), np.int64),
                            ridge=float("nan"))
    with pytest.raises(ParameterError, match="normal flow"):
        add_normal_voxels(ev, TripletFlow(*(np.zeros(len(ev)) for _ in range(4))), 0, 1,
                          np.zeros((1, 40, 40, 5)), np.zeros((1, 40, 40), np.int64), 1e3)


def test_slicing_and_concatenation_keep_normal_flow():
    ev = moving_dots(3)
    f = TripletMatcher(ev.sensor_size).process(ev)
    parts = [f[:100], f[100:]]
    j = TripletFlow.concatenate(parts)
    np.testing.assert_array_equal(j.nx, f.nx)
    assert TripletFlow.concatenate([f[:10], TripletFlow(*f._arrays()[:4])]).nx is None
    with pytest.raises(TypeError):
        f[3]


def test_simulated_quarter_speed_translation_lsq_beats_mean():
    from evmotion.sim import simulate

    res = simulate("translation", duration_s=0.15, seed=0, frame_rate=45.0,
                   params={"vx": 55.0, "vy": -32.5}, show_progress=False)
    wins = res.events.windows_at(res.gt.frame_times_us, dt=1, drop_empty=True)[2:5]
    a_lsq = mean_window_aee(res, wins, dense="lsq")
    # measured 0.22 px vs 0.99 px over the whole 0.3 s scene (benchmarks/)
    assert a_lsq < 0.35
    assert a_lsq < 0.5 * mean_window_aee(res, wins)


def test_normal_kappa_narrows_only_the_normal_flow():
    ev = moving_dots(5, n_dots=20)
    a = TripletMatcher(ev.sensor_size, normal_kappa=1).process(ev)
    b = TripletMatcher(ev.sensor_size).process(ev)
    for name in ("vx", "vy", "valid", "n_triplets"):  # (5.3) is the thesis' in both
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.nx, b.nx)
    for bad in (0, 3, 2.5, 2**17):
        with pytest.raises(ParameterError, match="normal_kappa"):
            TripletMatcher(ev.sensor_size, normal_kappa=bad)


def test_burst_consistent_weights_on_fast_simulated_rotation():
    # Default-speed rotation (~300 px/s, several events per edge crossing): the first
    # version of dense="lsq" (thesis triplets, (5.3)-shaped weights, 11 x 11) against the
    # defaults (d_x = 2.3, tau = 1 ms, sigma = delta / 16, 15 x 15).
    from evmotion.eval.metrics import flow_metrics
    from evmotion.sim import simulate

    res = simulate("rotation", duration_s=0.15, seed=0, frame_rate=45.0, show_progress=False)
    ev = res.events
    wins = ev.windows_at(res.gt.frame_times_us, dt=1, drop_empty=True)[2:5]
    new = estimate_flow_triplet(ev, wins, dense="lsq")
    old = estimate_flow_triplet(ev, wins, dense="lsq", dx=float(np.sqrt(2.0)), tau_us=3_000,
                                normal_kappa=1, filter_size=11)
    a_new, a_old = [], []
    for k, w in enumerate(wins):
        gt = res.gt.displacement(w.t0, w.t1)
        a_new.append(flow_metrics(new.displacement(k), gt, events=ev.window(w)).aee)
        a_old.append(flow_metrics(old.displacement(k), gt, events=ev.window(w)).aee)
    # whole 0.3 s scene (benchmarks/): 0.47 px vs 1.38 px, GT 6.65 px, MultiCM 0.23 px
    assert np.mean(a_new) < 0.7, a_new
    assert np.mean(a_new) < 0.5 * np.mean(a_old), (a_new, a_old)
