"""Streaming triplet flow (:mod:`evmotion.methods.triplet_stream`): every window equals the
batch :func:`estimate_flow_triplet` on the whole recording, whatever the chunking."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.events import EventArray
from evmotion.methods.triplet import TripletFlow, TripletMatcher, estimate_flow_triplet
from evmotion.methods.triplet_stream import TripletStream, iter_flow_triplet


def two_edges(size: int = 48) -> EventArray:
    """A vertical edge moving right at 200 px/s and a horizontal one moving down at 120 px/s:
    two orientations, so the lsq/robust fits see more than one normal."""
    yy, xx = np.mgrid[0:size, 0:size]
    tx = np.rint(xx.ravel() / 200.0 * 1e6).astype(np.int64)
    ty = np.rint(yy.ravel() / 120.0 * 1e6).astype(np.int64) + 3_000
    x = np.concatenate([xx.ravel(), xx.ravel()])
    y = np.concatenate([yy.ravel(), yy.ravel()])
    t = np.concatenate([tx, ty])
    p = np.concatenate([np.ones(tx.size), np.zeros(ty.size)])
    order = np.argsort(t, kind="stable")
    return EventArray(x[order], y[order], t[order], p[order], (size, size))


def chunked(ev: EventArray, n: int):
    return (ev[s:s + n] for s in range(0, len(ev), n))


def assert_windows_equal(wins, ref):
    assert len(wins) == len(ref.windows)
    for w, rw, flow, mask in zip(wins, ref.windows, ref.flow, ref.valid, strict=True):
        assert (w.t0, w.t1) == (rw.t0, rw.t1)
        np.testing.assert_array_equal(w.valid, mask)
        np.testing.assert_allclose(w.flow, flow, rtol=1e-5, atol=1e-3)


@pytest.mark.parametrize("dense", ["mean", "lsq", "robust"])
@pytest.mark.parametrize("chunk", [97, 100_000])
def test_time_windows_equal_the_batch_function(dense, chunk):
    ev = two_edges()
    wins = list(iter_flow_triplet(chunked(ev, chunk), dense=dense, window_us=60_000,
                                  n_bins=2, filter_size=9 if dense != "mean" else 3))
    ref = estimate_flow_triplet(ev, ev.windows_by_duration(60_000), dense=dense, n_bins=2,
                                filter_size=9 if dense != "mean" else 3)
    assert_windows_equal(wins, ref)
    assert sum(w.valid.any() for w in wins) >= 3  # not a comparison of empty fields


@pytest.mark.parametrize("dense", ["mean", "lsq"])
def test_count_and_explicit_windows(dense):
    ev = two_edges()
    wins = list(iter_flow_triplet(chunked(ev, 333), dense=dense, window_events=700))
    assert_windows_equal(wins, estimate_flow_triplet(ev, ev.windows_by_count(700),
                                                     dense=dense))
    frames = np.arange(20_000, 400_000, 37_000)
    spans = list(zip(frames[:-1].tolist(), frames[1:].tolist(), strict=True))
    wins = list(iter_flow_triplet(chunked(ev, 500), dense=dense, windows=spans))
    assert_windows_equal(wins, estimate_flow_triplet(ev, ev.windows_at(frames), dense=dense))


@pytest.mark.parametrize("chunk", [97, 100_000])
def test_robust_count_windows_count_the_recordings_events(chunk):
    # they counted the burst means: --window-events 30000 held 42-64k events, unsaid
    ev = two_edges()
    ev = ev[:len(ev) // 700 * 700] if chunk == 97 else ev  # whole windows only, or not
    wins = list(iter_flow_triplet(chunked(ev, chunk), dense="robust", window_events=700,
                                  filter_size=9))
    ref = ev.windows_by_count(700)
    assert [(w.t0, w.t1) for w in wins] == [(w.t0, w.t1) for w in ref]
    assert_windows_equal(wins, estimate_flow_triplet(ev, ref, dense="robust", filter_size=9))
    assert sum(w.valid.any() for w in wins) >= 2


def test_per_event_flow_and_no_windows_without_dense():
    ev = two_edges()
    s = TripletStream(ev.sensor_size, dense=None)
    flows = []
    for c in chunked(ev, 250):
        flows.append(s.process(c))
        assert list(s.windows()) == []
    s.finish()
    assert list(s.windows()) == []
    got = TripletFlow.concatenate(flows)
    ref = TripletMatcher(ev.sensor_size).process(ev)
    np.testing.assert_array_equal(got.vx, ref.vx)
    np.testing.assert_array_equal(got.ny, ref.ny)
    assert s.overflow == 0


def test_windows_come_as_the_stream_passes_them():
    ev = two_edges()
    s = TripletStream(ev.sensor_size, dense="mean", window_us=50_000)
    s.process(ev[ev.t < 120_000])
    assert [w.t1 for w in s.windows()] == [50_000, 100_000]
    s.finish()
    assert s.windows().__next__().t0 == 100_000


def test_skip_delimits_without_computing():
    ev = two_edges()
    full = list(iter_flow_triplet(chunked(ev, 400), window_us=50_000, with_iwe=True))
    part = list(iter_flow_triplet(chunked(ev, 400), window_us=50_000, skip=3))
    assert [(w.t0, w.t1) for w in part] == [(w.t0, w.t1) for w in full]
    assert all(w.flow is None for w in part[:3])
    for a, b in zip(part[3:], full[3:], strict=True):
        np.testing.assert_array_equal(a.flow, b.flow)
        assert a.iwe is None and b.iwe is not None and b.iwe.sum() > 0


def test_bad_input_is_reported():
    ev = two_edges()
    with pytest.raises(ParameterError, match="at most one of window_us, window_events"):
        TripletStream(ev.sensor_size, window_us=10, window_events=10)
    with pytest.raises(ParameterError, match="filter_size must be an odd"):
        TripletStream(ev.sensor_size, filter_size=4)
    with pytest.raises(ParameterError, match="dense must be"):
        next(iter_flow_triplet([ev], dense="median"))
    with pytest.raises(EmptyWindowError):
        next(iter_flow_triplet([ev[:0]]))


def test_a_pause_in_the_recording_makes_no_empty_windows():
    # one stray timestamp 2^40 us on stepped through a billion empty 50 ms windows
    ev = two_edges()
    late = EventArray(x=ev.x[-1:], y=ev.y[-1:], t=ev.t[-1:] + (1 << 40), p=ev.p[-1:],
                      sensor_size=ev.sensor_size)
    from evmotion.events import concatenate

    wins = list(iter_flow_triplet(chunked(concatenate([ev, late]), 500), window_us=50_000))
    plain = list(iter_flow_triplet(chunked(ev, 500), window_us=50_000))
    assert len(wins) == len(plain) + 1
    assert wins[-1].t0 <= int(late.t[0]) < wins[-1].t1
    assert (wins[-1].t0 - wins[0].t0) % 50_000 == 0  # still on the grid of windows


def test_stretches_lit_not_moved_get_no_flow():
    """Under 120 Hz flicker the per-event flow was no better than zero flow (AEE 0.76
    against 0.80), valid (probe AK): those stretches now get none, and are counted."""
    from test_measured import moving

    lit = moving(n=60_000, flicker_share=0.8)
    s = TripletStream(lit.sensor_size, dense=None)
    flow = s.process(lit)
    assert s.lit_events == len(lit) and not flow.valid.any()
    assert not flow.vx.any() and not flow.vy.any()
    # nor a normal flow, from which the dense "lsq" windows are made
    flow = TripletStream(lit.sensor_size, dense="lsq").process(lit)
    assert flow.nx is not None and not flow.nx.any() and not flow.ny.any()
    still = moving(n=60_000)
    s = TripletStream(still.sensor_size, dense=None)
    assert s.process(still).valid.any() and s.lit_events == 0


def test_the_first_windows_read_backwards_are_right_and_mean_ones_marked():
    """The first windows of a stream lacked the older partners of slow steps' triplets and
    their flow came out too fast: a simulated translation at 30 px/s gave 72, 36, 33 px/s
    in its first three 50 ms windows (robust), valid, unsaid (probe: 1.8x at 100 px/s on
    another renderer's scene). The events of its first 2 (d_t + tau) now take the flow of
    the stream read backwards, as the batch function's do; the thesis' mean, not read
    backwards, marks those windows early."""
    from evmotion.sim.simulator import simulate

    ev = simulate("translation", duration_s=0.35, sensor_size=(96, 128), seed=2,
                  params={"vx": 30.0, "vy": 0.0}, show_progress=False).events
    s = TripletStream(ev.sensor_size, dense="robust", window_us=50_000)
    assert s.history_us == 2 * (100_000 + 1_000)
    s.process(ev)
    s.finish()
    wins = list(s.windows())
    speed = [float(np.median(w.flow[w.valid, 0])) for w in wins]
    assert not any(w.early for w in wins)
    assert all(abs(v / 30 - 1) < 0.1 for v in speed), speed
    batch = estimate_flow_triplet(ev, ev.windows_by_duration(50_000), dense="robust")
    np.testing.assert_allclose(np.stack([w.flow for w in wins]), batch.flow, atol=1e-3)
    m = TripletStream(ev.sensor_size, dense="mean", window_us=50_000)
    m.process(ev)
    m.finish()
    # marked while the stream's past is shorter than a triplet's two steps at the window's
    # speed (2 x 1.41 px at 30 px/s: ~94 ms), not for the whole history (202 ms)
    early = [w.early for w in m.windows()]
    assert early[:2] == [True, True] and not any(early[3:]), early


@pytest.mark.parametrize("dense", ["lsq", "robust"])
def test_a_stream_shorter_than_the_history_marks_its_slow_windows(dense):
    # 60 ms: events in its middle have under d_t + tau on both sides, which a triplet of
    # 2.3 px steps outlasts at 20 px/s (230 ms), not at the scene's 256 px/s (18 ms): every
    # window of short recordings was marked, however fast (probe CD)
    import warnings

    from evmotion.errors import PoorFitWarning
    from evmotion.sim.simulator import simulate

    for speed, slow in ((20.0, True), (None, False)):
        params = {"vx": speed, "vy": 0.0} if speed else None
        ev = simulate("translation", duration_s=0.06, sensor_size=(64, 80), seed=3,
                      params=params, show_progress=False).events
        wins = list(iter_flow_triplet(ev, dense=dense, window_us=20_000))
        assert [w.early for w in wins] == [slow] * len(wins)
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always")
            estimate_flow_triplet(ev, dense=dense)
        early = [w for w in said if issubclass(w.category, PoorFitWarning)
                 and "slow steps' triplets cannot be found" in str(w.message)]
        assert bool(early) == slow


def test_robust_time_windows_start_at_the_first_event():
    """Robust windows started at the first burst mean's time (1164 us for a first event at
    417 us), off the other dense flows' grid for the same window_us (probe AU)."""
    from evmotion.sim import simulate

    ev = simulate("translation", duration_s=0.03, sensor_size=(60, 80), seed=0,
                  show_progress=False).events
    grids = {dense: [(w.t0, w.t1) for w in iter_flow_triplet(ev, dense=dense,
                                                             window_us=10_000)]
             for dense in ("mean", "robust")}
    assert grids["robust"] == grids["mean"]
    assert grids["robust"][0][0] == int(ev.t[0])


def test_per_event_flow_of_noise_is_left_out():
    """Probe DG: the per-event output of a noise recording gave 76 % of its events a flow,
    valid, without a word. Stretches whose flows do not carry their first half onto their
    second lose theirs (counted in unaligned_events); a moving scene keeps all of its."""
    from evmotion.sim import simulate

    rng = np.random.default_rng(2)
    n = 120_000
    noise = EventArray(rng.integers(0, 160, n), rng.integers(0, 120, n),
                       np.sort(rng.integers(0, 300_000, n)), rng.integers(0, 2, n),
                       (120, 160))
    s = TripletStream(noise.sensor_size, dense=None)
    flow = s.process(noise)
    assert flow.valid.mean() < 0.05 and s.unaligned_events > 0.5 * n
    assert not flow.vx[~flow.valid].any()
    moving = simulate("translation", duration_s=0.1, sensor_size=(120, 160), seed=1,
                      show_progress=False).events
    s = TripletStream(moving.sensor_size, dense=None)
    flow = s.process(moving)
    assert s.unaligned_events == 0 and flow.valid.mean() > 0.5


def test_per_event_tests_judge_the_same_stretches_whatever_the_chunks():
    """The flicker and noise tests judged stretches spread over each chunk, and none in a
    chunk under 2,000 events: --chunk-events 1000 left a noise recording's flows valid
    that 300,000 took away (probe DK). Fed through stream_chunks, any chunking of the
    stream gives the same per-event flow."""
    from evmotion.methods.triplet_stream import stream_chunks

    rng = np.random.default_rng(4)
    n = 75_000
    noise = EventArray(rng.integers(0, 80, n), rng.integers(0, 60, n),
                       np.sort(rng.integers(0, 200_000, n)), rng.integers(0, 2, n), (60, 80))
    runs = []
    for read, feed in ((n, n), (1000, 1000), (7000, 50_000), (29_999, 30_000)):
        s = TripletStream(noise.sensor_size, dense=None)
        flows = [s.process(c) for c in stream_chunks(chunked(noise, read), feed)]
        runs.append((TripletFlow.concatenate(flows), s.unaligned_events))
    ref, unaligned = runs[0]
    assert unaligned > 0.5 * n
    for flow, count in runs[1:]:
        assert count == unaligned
        np.testing.assert_array_equal(flow.valid, ref.valid)
        np.testing.assert_array_equal(flow.vx, ref.vx)


@pytest.mark.parametrize("valid_share", [1.0, 0.3])
def test_event_flow_consistency_matches_the_dense_field(valid_share):
    """event_flow_consistency looks the 3x3 non-zero average up at the events' pixels;
    it equals the halves test of the dense field made by nonzero_average_filter."""
    from evmotion.methods.measured import halves_consistency
    from evmotion.methods.triplet import event_flow_consistency, nonzero_average_filter

    rng = np.random.default_rng(7)
    n, h, w = 4000, 30, 40
    ev = EventArray(rng.integers(0, w, n), rng.integers(0, h, n),
                    np.sort(rng.integers(0, 20_000, n)), np.ones(n, int), (h, w))
    valid = rng.random(n) < valid_share
    vx, vy = (rng.normal(0, 200, n).astype(np.float32) for _ in range(2))
    flow = TripletFlow(np.where(valid, vx, 0), np.where(valid, vy, 0), valid,
                       valid.astype(np.int32))
    acc, cnt = np.zeros((h, w, 2)), np.zeros((h, w))
    np.add.at(acc, (ev.y[valid], ev.x[valid]), np.stack([vx, vy], 1)[valid])
    np.add.at(cnt, (ev.y[valid], ev.x[valid]), 1)
    mean = acc / np.maximum(cnt, 1)[..., None]
    dense, support = nonzero_average_filter(mean, cnt > 0)
    dense[~support] = 0
    ref = halves_consistency(ev, dense, (int(ev.t[0]) + int(ev.t[-1])) // 2)
    assert event_flow_consistency(ev, flow) == pytest.approx(ref, rel=1e-6, abs=1e-9)
