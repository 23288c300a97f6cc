"""Windows cut from a chunk stream (make_windows_streaming) are those make_windows cuts from
the whole recording, and window_blocks hands out their events, whatever the chunk and
block sizes."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from evmotion.errors import ParameterError
from evmotion.events import EventArray, make_windows
from evmotion.streamed_windows import make_windows_streaming, window_blocks


def _recording(n=20_000, seed=0, gap=True, ties=False):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 2_000_000, n))
    if ties:  # tens of events a microsecond: windows end where the next one starts
        t = t // 1000 * 1000
    if gap:  # a pause of a second, and sparse stretches that hold windows of few events
        t = np.where(t > 700_000, t + 1_000_000, t)
    return EventArray(x=rng.integers(0, 64, n), y=rng.integers(0, 48, n), t=t,
                      p=rng.integers(0, 2, n), sensor_size=(48, 64))


def _chunks(ev, size):
    return (ev[i:i + size] for i in range(0, len(ev), size))


def _key(windows):
    return [(w.index, w.t0, w.t1, w.start, w.stop) for w in windows]


def _streamed_vs_whole(ev, chunk, t0=None, t1=None, **kw):
    sub = ev.slice_time(t0, t1)
    got = make_windows_streaming(_chunks(sub, chunk), t0=t0, t1=t1, **kw)
    whole = make_windows(ev, t0=t0, t1=t1, **kw)
    shift = ev.index_at(t0) if t0 is not None else 0
    want = [(w.index, w.t0, w.t1, w.start - shift, w.stop - shift) for w in whole]
    return _key(got), want


@pytest.mark.parametrize("cut", [{"n_events": 5000}, {"n_events": 7}, {"n_events": 4096},
                                 {"duration_us": 90_000}, {"duration_us": 3_000},
                                 {"duration_us": 1}])
@pytest.mark.parametrize("chunk", [1, 999, 4096, 50_000])
@pytest.mark.parametrize("span", [(None, None), (650_000, None), (None, 2_500_000),
                                  (123_457, 1_900_001)])
@pytest.mark.parametrize("ties", [False, True])
def test_same_windows_as_the_whole_recording(cut, chunk, span, ties):
    ev = _recording(n=3000 if chunk == 1 else 20_000, ties=ties)
    for min_events in (1, 10):
        got, want = _streamed_vs_whole(ev, chunk, *span, min_events=min_events, **cut)
        assert got == want
        assert len(want) >= 1 or min_events > 1


@pytest.mark.parametrize("cut", [{"n_events": 500}, {"duration_us": 20_000}])
@pytest.mark.parametrize("n_max", [1, 3, 40])
def test_max_windows_as_the_whole_recording(cut, n_max):
    ev = _recording()
    got, want = _streamed_vs_whole(ev, 777, max_windows=n_max, min_events=10, **cut)
    assert got == want and len(want) == n_max


@settings(max_examples=150, deadline=None)
@given(st.lists(st.integers(0, 40), min_size=1, max_size=300), st.integers(1, 50),
       st.integers(1, 60), st.booleans(), st.integers(1, 5), st.integers(0, 30))
def test_any_stream(steps, chunk, size, by_count, min_events, t0_shift):
    # times with ties and gaps, cut anywhere, windows of any size
    t = np.cumsum(steps).astype(np.int64)
    n = len(t)
    ev = EventArray(x=np.zeros(n), y=np.zeros(n), t=t, p=np.ones(n), sensor_size=(2, 2))
    t0 = int(t[0]) + t0_shift if t0_shift else None
    if t0 is not None and t0 > int(t[-1]):
        return
    cut = {"n_events": size} if by_count else {"duration_us": size}
    got, want = _streamed_vs_whole(ev, chunk, t0, min_events=min_events, **cut)
    assert got == want


def test_empty_stream_and_bad_arguments():
    assert make_windows_streaming(iter(()), n_events=5) == []
    assert make_windows_streaming(iter(()), duration_us=5) == []
    with pytest.raises(ParameterError, match="exactly one"):
        make_windows_streaming(iter(()))
    with pytest.raises(ParameterError, match="max_windows"):
        make_windows_streaming(iter(()), n_events=5, max_windows=0)
    with pytest.raises(ParameterError, match="must be after"):
        make_windows_streaming(iter(()), n_events=5, t0=10, t1=10)


@pytest.mark.parametrize("block", [1, 4000, 12_345, 10**9])
@pytest.mark.parametrize("chunk", [333, 20_000])
def test_blocks_hold_the_windows_events(block, chunk):
    ev = _recording()
    windows = make_windows(ev, duration_us=20_000, min_events=10)
    assert sum(w.count for w in windows) < len(ev)  # some events are in no window
    seen = []
    for part, bw, pos in window_blocks(_chunks(ev, chunk), windows, block_events=block):
        assert len(bw) == len(pos) >= 1
        assert bw[0].start == 0 and bw[-1].stop == len(part)
        assert len(part) <= block or len(bw) == 1
        for w, k in zip(bw, pos, strict=True):
            whole = ev.window(windows[k])
            np.testing.assert_array_equal(part.window(w).t, whole.t)
            np.testing.assert_array_equal(part.window(w).x, whole.x)
            assert (w.index, w.t0, w.t1) == (windows[k].index, windows[k].t0, windows[k].t1)
        seen += pos
    assert seen == list(range(len(windows)))
    if block == 10**9:
        assert len(list(window_blocks(_chunks(ev, chunk), windows, block_events=block))) == 1


def test_blocks_of_another_stream_are_refused():
    ev = _recording()
    windows = make_windows(ev, n_events=1000)
    with pytest.raises(ParameterError, match="not the stream the windows were cut from"):
        list(window_blocks(_chunks(ev[:5000], 700), windows, block_events=3000))
