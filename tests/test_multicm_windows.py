"""estimate_flow_sequence with workers: contiguous chunks of windows, warm-started within
each chunk (methods/multicm_windows.py)."""

import numpy as np
import pytest

from evmotion.errors import ParameterError
from evmotion.events import make_windows
from evmotion.methods.multicm import estimate_flow, estimate_flow_sequence
from evmotion.sim import simulate

KW = {"n_scales": 2, "max_iter": 5}


@pytest.fixture(scope="module")
def rec():
    ev = simulate("translation", sensor_size=(48, 64), duration_s=0.06, seed=3).events
    return ev, make_windows(ev, n_events=len(ev) // 4)[:4]


def _serial(ev, wins):
    out, init = [], None
    for w in wins:
        init = estimate_flow(ev.window(w), init=init, **KW)
        out.append(init)
    return out


def test_chunks_equal_a_serial_warm_started_run_per_chunk(rec):
    ev, wins = rec
    got = estimate_flow_sequence(ev, wins, workers=2, keep_iwes=False, **KW)
    want = _serial(ev, wins[:2]) + _serial(ev, wins[2:])   # chunk 2 starts from zero flow
    assert len(got) == len(wins)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g.flow, w.flow)
        assert g.iwes == {}
    one = estimate_flow_sequence(ev, wins, **KW)
    for g, w in zip(one, _serial(ev, wins), strict=True):
        np.testing.assert_array_equal(g.flow, w.flow)


def test_chunks_refuse_what_they_cannot_honour(rec):
    from evmotion.methods.multicm_windows import estimate_in_chunks

    ev, wins = rec
    with pytest.raises(ParameterError, match="workers must be an integer >= 1, got 0"):
        estimate_in_chunks(ev, wins, workers=0)
    for bad in (0, -2, float("nan"), 2.5):
        with pytest.raises(ParameterError, match="workers must be an integer >= 1, got"):
            estimate_flow_sequence(ev, wins, workers=bad)
    with pytest.raises(ParameterError, match="init cannot seed"):
        estimate_flow_sequence(ev, wins, workers=2, init=np.zeros((48, 64, 2), np.float32))
    with pytest.raises(ParameterError, match="warm_start=False"):
        estimate_flow_sequence(ev, wins, workers=2, warm_start=False)


def test_iter_chunks_streams_the_same_windows_first_chunk_shortest(rec):
    from evmotion.methods.multicm_windows import iter_chunks

    ev, wins = rec
    wins = wins[:3]
    got = list(iter_chunks(ev, wins, workers=2, keep_iwes=False, **KW))
    # 3 windows in 2 chunks: [w0] then [w1, w2] (the first chunk the shorter, ending first)
    want = _serial(ev, wins[:1]) + _serial(ev, wins[1:])
    assert len(got) == 3
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g.flow, w.flow)
    lazy = iter_chunks(ev, wins, workers=0, **KW)  # checked when the work starts
    with pytest.raises(ParameterError, match="workers"):
        next(lazy)


def test_on_empty_skip_keeps_every_window_and_warm_starts_past_it(rec):
    """A window whose events share one time: ``on_empty="raise"`` (default) stops the
    sequence; ``"skip"`` gives it no valid pixel and a warning, and the window after it
    starts from the last estimated one, serially and in chunks."""
    from evmotion.errors import EmptyWindowError, EvmotionWarning
    from evmotion.events import EventArray

    ev, wins = rec
    t = ev.t.copy()
    w = wins[1]
    t[w.start:w.stop] = t[w.start]
    t[w.stop:] = np.maximum(t[w.stop:], t[w.start])
    stuck = EventArray(x=ev.x, y=ev.y, t=t, p=ev.p, sensor_size=ev.sensor_size)
    with pytest.raises(EmptyWindowError, match="spanning 0 us"):
        estimate_flow_sequence(stuck, wins, **KW)
    with pytest.raises(ParameterError, match="on_empty"):
        estimate_flow_sequence(stuck, wins, on_empty="ignore", **KW)
    for workers in (1, 2):
        with pytest.warns(EvmotionWarning, match=r"window 1 \[.* skipped: .*spanning 0 us"):
            got = estimate_flow_sequence(stuck, wins, on_empty="skip", workers=workers, **KW)
        assert [("skipped" in r.meta) for r in got] == [False, True, False, False]
        assert not got[1].valid.any() and np.isnan(got[1].focus)
    with pytest.warns(EvmotionWarning):
        serial = estimate_flow_sequence(stuck, wins, on_empty="skip", **KW)
    after = estimate_flow(stuck.window(wins[2]), init=serial[0], **KW)
    np.testing.assert_array_equal(serial[2].flow, after.flow)


@pytest.mark.parametrize("restart", [False, True])
def test_a_warm_start_is_not_kept_by_the_next_window(rec, restart):
    """estimate_flow's coarse-to-fine closure referred to itself: a cycle that kept each
    window's events, problem and warm start (the previous window's result, and so back)
    until a full garbage collection, so a 1280 x 720 flow run grew by some 15 MB a
    window. Nothing of a call outlives it but its result."""
    import gc
    import weakref

    ev, wins = rec
    gc.collect()
    gc.disable()
    try:
        first = estimate_flow(ev.window(wins[0]), restart=restart, **KW)
        gone = weakref.ref(first)
        second = estimate_flow(ev.window(wins[1]), init=first, restart=restart, **KW)
        del first
        assert gone() is None
        assert second.flow.shape[:2] == ev.sensor_size
    finally:
        gc.enable()
