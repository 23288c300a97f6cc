"""Triplet matching (thesis ch. 5): equality with a literal Algorithm 1, chunk invariance,
exact flow on translating edges, bounded state, batch voxelization and filtering."""

from __future__ import annotations

import numpy as np
import pytest

from _triplet_reference import triplet_reference
from evmotion.errors import EmptyWindowError, ParameterError, PoorFitWarning
from evmotion.events import EventArray
from evmotion.methods.triplet import (
    TripletFlow,
    TripletMatcher,
    collapse_voxels,
    estimate_flow_triplet,
    neighbour_offsets,
    nonzero_average_filter,
    voxelize_flow,
)


def moving_dots(seed: int, n_dots: int = 14, size: int = 24, duration_us: int = 300_000,
                noise: int = 150) -> EventArray:
    """Dots at constant velocity firing an event whenever they enter a pixel, plus noise."""
    rng = np.random.default_rng(seed)
    xs, ys, ts, ps = [], [], [], []
    steps = np.arange(0, duration_us, 250)
    for _ in range(n_dots):
        pos = rng.uniform(4, size - 4, 2)
        vel = rng.uniform(-120, 120, 2)
        pol = rng.integers(0, 2)
        path = pos[None, :] + vel[None, :] * steps[:, None] * 1e-6
        pix = np.floor(path).astype(int)
        inside = np.all((pix >= 0) & (pix < size), axis=1)
        change = np.ones(len(steps), bool)
        change[1:] = np.any(pix[1:] != pix[:-1], axis=1)
        sel = change & inside
        xs.append(pix[sel, 0])
        ys.append(pix[sel, 1])
        ts.append(steps[sel] + rng.integers(0, 200, sel.sum()))
        ps.append(np.full(sel.sum(), pol))
    xs.append(rng.integers(0, size, noise))
    ys.append(rng.integers(0, size, noise))
    ts.append(rng.integers(0, duration_us, noise))
    ps.append(rng.integers(0, 2, noise))
    x, y, t, p = (np.concatenate(a) for a in (xs, ys, ts, ps))
    order = np.argsort(t, kind="stable")
    return EventArray(x[order], y[order], t[order], p[order], (size, size))


def edge_events(speed_px_s: float, angle_deg: float = 0.0, size: int = 40,
                p: int = 1) -> EventArray:
    """A straight edge sweeping the sensor at ``speed`` along ``angle`` (0 = +x, 90 = +y):
    each pixel fires once when the edge reaches it."""
    yy, xx = np.mgrid[0:size, 0:size]
    n = np.array([np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))])
    s = xx * n[0] + yy * n[1]
    t = np.rint((s - s.min()) / speed_px_s * 1e6).astype(np.int64).ravel()
    order = np.argsort(t, kind="stable")
    return EventArray(xx.ravel()[order], yy.ravel()[order], t[order],
                      np.full(t.size, p), (size, size))


def _compare(ev: EventArray, flow: TripletFlow, **kw) -> None:
    vx, vy, valid, n = triplet_reference(ev.x, ev.y, ev.t, ev.p, **kw)
    np.testing.assert_array_equal(flow.n_triplets, n)
    np.testing.assert_array_equal(flow.valid, valid)
    np.testing.assert_allclose(flow.vx, vx, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(flow.vy, vy, rtol=1e-5, atol=1e-3)
    assert valid.sum() > 20, "the test stream must produce triplets"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_literal_algorithm1(seed):
    ev = moving_dots(seed)
    m = TripletMatcher(ev.sensor_size, depth=32)
    flow = m.process(ev)
    assert m.overflow == 0
    _compare(ev, flow)


def test_matches_literal_algorithm1_other_parameters():
    ev = moving_dots(3, duration_us=200_000)
    m = TripletMatcher(ev.sensor_size, dx=2.0, dt_us=30_000, tau_us=1_000, depth=32)
    _compare(ev, m.process(ev), dx=2.0, dt_us=30_000, tau_us=1_000)
    m = TripletMatcher(ev.sensor_size, dx=2.3, dt_us=50_000, tau_us=1, depth=32)
    _compare(ev, m.process(ev), dx=2.3, dt_us=50_000, tau_us=1)


def test_quadruple_matches_literal():
    ev = moving_dots(4, n_dots=20)
    m = TripletMatcher(ev.sensor_size, quadruple=True, depth=32)
    _compare(ev, m.process(ev), quadruple=True)


@pytest.mark.parametrize("lag_us", [42_000, 60_000])
def test_far_tail_weights_match_reference(lag_us):
    # One triplet whose 3rd event is 38 (or 56) widths off its predicted time: the weight
    # is a subnormal float64 (or 0) in the exact Gaussian, and must stay so.
    t = np.array([0, 100_000 - lag_us + 2_000, 99_000, 100_000]) + 10**6
    ev = EventArray([9, 2, 3, 4], [0, 5, 5, 5], t, [1, 1, 1, 1], (10, 10))
    flow = TripletMatcher(ev.sensor_size, tau_us=1).process(ev)
    vx, _, valid, n = triplet_reference(ev.x, ev.y, ev.t, ev.p, tau_us=1)
    assert n[3] == flow.n_triplets[3] == 1
    assert valid[3] == flow.valid[3]
    np.testing.assert_allclose(flow.vx, vx, rtol=1e-6)


def test_thesis_map_limit_is_equivalent_when_large_enough():
    ev = moving_dots(5, duration_us=150_000)
    a = triplet_reference(ev.x, ev.y, ev.t, ev.p, max_maps=20_000)
    b = triplet_reference(ev.x, ev.y, ev.t, ev.p)
    for u, v in zip(a, b, strict=True):
        np.testing.assert_array_equal(u, v)


@pytest.mark.parametrize("seed", range(6))
def test_any_chunking_is_bit_identical(seed):
    ev = moving_dots(10 + seed, n_dots=20)
    whole = TripletMatcher(ev.sensor_size).process(ev)
    rng = np.random.default_rng(seed)
    cuts = np.sort(rng.choice(np.arange(1, len(ev)), size=rng.integers(1, 40), replace=False))
    m = TripletMatcher(ev.sensor_size)
    parts = [m.process(ev[a:b]) for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(ev)],
                                                strict=True)]
    parts.append(m.process(ev[len(ev):]))
    joined = TripletFlow.concatenate(parts)
    for name in ("vx", "vy", "valid", "n_triplets", "nx", "ny"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(whole, name))


def test_rebase_of_relative_times_is_invisible():
    chunks = []
    for i in range(8):
        e = moving_dots(20 + i, duration_us=300_000)
        chunks.append(EventArray(e.x, e.y, e.t + i * 300_000 + 5_000_000_000, e.p,
                                 e.sensor_size))
    a = TripletMatcher(chunks[0].sensor_size, dt_us=20_000, tau_us=1_000)
    b = TripletMatcher(chunks[0].sensor_size, dt_us=20_000, tau_us=1_000)
    b._rebase_span = 2**18  # forces a rebase every ~130 ms of stream
    for c in chunks:
        fa, fb = a.process(c), b.process(c)
        np.testing.assert_array_equal(fa.vx, fb.vx)
        np.testing.assert_array_equal(fa.n_triplets, fb.n_triplets)
    assert b._base > a._base


@pytest.mark.parametrize(("speed", "angle"), [(200.0, 0.0), (137.0, 180.0), (90.0, 90.0),
                                             (250.0, 270.0)])
def test_translating_edge_gives_exact_flow(speed, angle):
    ev = edge_events(speed, angle)
    flow = TripletMatcher(ev.sensor_size).process(ev)
    # Interior events only: at the borders the symmetric diagonal votes are cut off.
    inner = (ev.x > 2) & (ev.x < 37) & (ev.y > 2) & (ev.y < 37) & flow.valid
    assert inner.sum() > 500
    expect = speed * np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    np.testing.assert_allclose(np.median(flow.vx[inner]), expect[0], atol=0.02 * speed)
    np.testing.assert_allclose(np.median(flow.vy[inner]), expect[1], atol=0.02 * speed)
    err = np.hypot(flow.vx[inner] - expect[0], flow.vy[inner] - expect[1])
    assert np.percentile(err, 90) < 0.03 * speed


def test_diagonal_edge_direction():
    ev = edge_events(150.0, 45.0)
    res = estimate_flow_triplet(ev)
    f = res.flow[0][5:35, 5:35][res.valid[0][5:35, 5:35]]
    ang = np.degrees(np.arctan2(f[:, 1], f[:, 0]))
    assert abs(np.median(ang) - 45.0) < 2.0
    # a diagonal edge moving at 150 px/s along 45 deg crosses 150*sqrt2 px/s along x+y steps;
    # the triplet votes are along pixel steps, so speed is exact only along the normal.
    assert abs(np.median(np.hypot(f[:, 0], f[:, 1])) - 150.0) < 0.1 * 150.0


def test_polarities_are_separate():
    ev = edge_events(200.0)
    mixed = EventArray(ev.x, ev.y, ev.t, (ev.x % 2).astype(np.uint8), ev.sensor_size)
    flow = TripletMatcher(ev.sensor_size).process(mixed)
    assert not flow.valid.any()  # consecutive columns alternate polarity: no same-sign triplet


def test_state_is_bounded_and_overflow_reported():
    m = TripletMatcher((20, 30), depth=4)
    n0 = m.state_nbytes
    assert n0 == 2 * 20 * 30 * 4 * 4 + 8
    hot = EventArray(np.full(50, 3), np.full(50, 3), np.arange(50) * 1000, np.ones(50),
                     (20, 30))
    m.process(hot)
    assert m.state_nbytes == n0
    assert m.overflow == 50 - 4
    m.reset()
    assert m.overflow == 0 and m.events_seen == 0


def test_float_coordinates_are_rounded():
    ev = edge_events(200.0)
    jitter = np.random.default_rng(0).uniform(-0.3, 0.3, len(ev))
    fl = EventArray(np.clip(ev.x + jitter, 0, 39), ev.y.astype(np.float32), ev.t, ev.p,
                    ev.sensor_size)
    a = TripletMatcher(ev.sensor_size).process(ev)
    b = TripletMatcher(ev.sensor_size).process(fl)
    np.testing.assert_array_equal(a.vx, b.vx)


def test_bad_input_raises_clear_errors():
    with pytest.raises(ParameterError, match="dx"):
        TripletMatcher((10, 10), dx=0.5)
    with pytest.raises(ParameterError, match="dt_us"):
        TripletMatcher((10, 10), dt_us=0)
    with pytest.raises(ParameterError, match="tau_us"):
        TripletMatcher((10, 10), tau_us=0)
    m = TripletMatcher((10, 10))
    with pytest.raises(ParameterError, match="sensor_size"):
        m.process(EventArray([1], [1], [5], [1], (10, 11)))
    m.process(EventArray([1], [1], [5], [1], (10, 10)))
    with pytest.raises(ParameterError, match="before the previous"):
        m.process(EventArray([1], [1], [4], [1], (10, 10)))
    with pytest.raises(ParameterError, match="not sorted"):
        m.process(EventArray([1, 1], [1, 1], [9, 8], [1, 1], (10, 10), validate=False))
    with pytest.raises(ParameterError, match="x=12"):
        m.process(EventArray([12], [1], [20], [1], (10, 10), validate=False))
    with pytest.raises(EmptyWindowError):
        estimate_flow_triplet(EventArray([], [], [], [], (10, 10)))
    # a window outside the events came back empty unsaid (probe BQ)
    ev = EventArray([2, 3, 4], [5, 5, 5], [0, 10_000, 20_000], [1, 1, 1], (10, 10))
    with pytest.warns(PoorFitWarning, match=r"1 of 2 window\(s\) hold no event \(first: "
                                            r"window 0, \[1000000, 1001000\) us\)"):
        r = estimate_flow_triplet(ev, windows=[(1_000_000, 1_001_000), (0, 20_001)])
    assert not r.valid[0].any() and r.valid[1].any()


def test_neighbour_offsets():
    assert len(neighbour_offsets(np.sqrt(2))) == 8
    assert len(neighbour_offsets(1.0)) == 4
    assert len(neighbour_offsets(2.0)) == 12
    assert not np.any(np.all(neighbour_offsets(3.0) == 0, axis=1))


def _nonzero_average_reference(field, mask, radius=1):
    h, w = mask.shape
    out = np.zeros_like(field, dtype=np.float64)
    sup = np.zeros(mask.shape, bool)
    for r in range(h):
        for c in range(w):
            vals = [field[rr, cc] for rr in range(max(r - radius, 0), min(r + radius + 1, h))
                    for cc in range(max(c - radius, 0), min(c + radius + 1, w))
                    if mask[rr, cc]]
            if vals:
                out[r, c] = np.mean(vals, axis=0)
                sup[r, c] = True
    return out, sup


def test_nonzero_average_filter_matches_loop():
    rng = np.random.default_rng(0)
    field = rng.normal(size=(9, 11, 2))
    mask = rng.random((9, 11)) < 0.3
    got, sup = nonzero_average_filter(field, mask)
    ref, rsup = _nonzero_average_reference(field, mask)
    np.testing.assert_array_equal(sup, rsup)
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-6)
    stack, _ = nonzero_average_filter(np.stack([field, field]), np.stack([mask, mask]))
    np.testing.assert_allclose(stack[1], ref, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("size", [1, 5, 7])
def test_wider_nonzero_average_filter_matches_loop(size):
    rng = np.random.default_rng(size)
    field = rng.normal(size=(9, 11, 2))
    mask = rng.random((9, 11)) < 0.3
    got, sup = nonzero_average_filter(field, mask, size)
    ref, rsup = _nonzero_average_reference(field, mask, size // 2)
    np.testing.assert_array_equal(sup, rsup)
    np.testing.assert_allclose(got, ref, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("size", [0, 2, 4, -3, 2.5])
def test_filter_size_must_be_odd_positive(size):
    with pytest.raises(ParameterError, match="odd"):
        nonzero_average_filter(np.zeros((3, 3, 2)), np.zeros((3, 3), bool), size)
    with pytest.raises(ParameterError, match="odd"):
        estimate_flow_triplet(edge_events(200.0), filter_size=size)


def test_voxelize_matches_numpy():
    ev = moving_dots(7)
    flow = TripletMatcher(ev.sensor_size).process(ev)
    t0, t1, nb = 50_000, 250_000, 4
    vox, mask = voxelize_flow(ev, flow, t0, t1, nb)
    sel = flow.valid & (ev.t >= t0) & (ev.t < t1)
    b = np.minimum((ev.t[sel] - t0) * nb // (t1 - t0), nb - 1)
    acc = np.zeros((nb, 24, 24, 2))
    cnt = np.zeros((nb, 24, 24))
    np.add.at(acc, (b, ev.y[sel], ev.x[sel]), flow.flow[sel])
    np.add.at(cnt, (b, ev.y[sel], ev.x[sel]), 1)
    np.testing.assert_array_equal(mask, cnt > 0)
    np.testing.assert_allclose(vox[mask], acc[mask] / cnt[mask][:, None], rtol=1e-6)
    dense, dmask = collapse_voxels(vox, mask, smooth=False)
    assert dense.shape == (24, 24, 2) and dmask.sum() == np.any(mask, axis=0).sum()


def test_batch_windows_use_prior_history():
    ev = edge_events(200.0)
    wins = ev.windows_by_duration(50_000)
    res = estimate_flow_triplet(ev, wins, n_bins=2)
    assert res.flow.shape == (len(wins), 40, 40, 2) and res.overflow == 0
    later = res.flow[2][res.valid[2]]
    assert np.median(later[:, 0]) == pytest.approx(200.0, rel=0.02)
    np.testing.assert_allclose(res.displacement(2), res.flow[2] * 0.05, rtol=1e-6)


def test_event_fwl_matches_dense_fwl_for_uniform_flow():
    from evmotion.eval.metrics import fwl
    from evmotion.methods.triplet import event_fwl

    full = edge_events(200.0)
    est = TripletMatcher(full.sensor_size).process(full)
    a, b = full.index_at(50_000), full.index_at(100_000)
    ev = full[a:b]
    n = len(ev)
    f = TripletFlow(np.full(n, 200.0, np.float32), np.zeros(n, np.float32),
                    np.ones(n, bool), np.ones(n, np.int32))
    dense = np.zeros((40, 40, 2), np.float32)
    dense[..., 0] = 200.0
    assert event_fwl(ev, f) == pytest.approx(fwl(ev, dense), rel=1e-9)
    sub = TripletFlow(est.vx[a:b], est.vy[a:b], est.valid[a:b], est.n_triplets[a:b])
    assert event_fwl(ev, sub) > 1.5


@pytest.mark.parametrize(("smooth", "size"), [(True, 3), (False, 3), (True, 5), (True, 9)])
def test_fused_dense_matches_numpy_path(smooth, size):
    from evmotion.methods.triplet import add_voxels, dense_from_sums

    ev = moving_dots(8)
    flow = TripletMatcher(ev.sensor_size).process(ev)
    t0, t1, nb = 20_000, 280_000, 3
    acc = np.zeros((nb, 24, 24, 2))
    cnt = np.zeros((nb, 24, 24), np.int64)
    add_voxels(ev, flow, t0, t1, acc, cnt)
    got, gmask = dense_from_sums(acc, cnt, smooth=smooth, filter_size=size)
    ref, rmask = collapse_voxels(*voxelize_flow(ev, flow, t0, t1, nb), smooth=smooth,
                                 filter_size=size)
    np.testing.assert_array_equal(gmask, rmask)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-4)
