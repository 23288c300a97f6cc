"""Burst means (one event per edge crossing of a pixel): against a plain-Python reference,
any chunking of a stream, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.errors import ParameterError
from evmotion.events import EventArray, concatenate
from evmotion.methods.bursts import BurstMeans, burst_means


def _reference(ev: EventArray, gap: int) -> list[tuple[int, int, int, int]]:
    """(t_mean, x, y, p) per burst, sorted by mean then by first event: the literal rule."""
    open_: dict[tuple[int, int, int], list[int]] = {}
    done = []
    for k in range(len(ev)):
        key = (int(ev.x[k]), int(ev.y[k]), int(ev.p[k]))
        t = int(ev.t[k])
        b = open_.get(key)
        if b is not None and t - b[-1][1] > gap:
            done.append((key, b))
            b = None
        if b is None:
            b = open_[key] = []
        b.append((k, t))
    done += list(open_.items())
    rows = []
    for (x, y, p), b in done:
        ts = [t for _, t in b]
        first = ts[0]
        rel = sum(t - first for t in ts)
        mean = first + (2 * rel + len(ts)) // (2 * len(ts))  # half up
        rows.append((mean, b[0][0], x, y, p))
    rows.sort()
    return [(m, x, y, p) for m, _, x, y, p in rows]


def _stream(seed: int, n: int = 3000, size=(6, 7)) -> EventArray:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 200_000, n))
    t[100:110] = t[100]  # equal timestamps
    return EventArray(rng.integers(0, size[1], n), rng.integers(0, size[0], n), t,
                      rng.integers(0, 2, n), size)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("gap", [1, 700, 5_000])
def test_burst_means_match_the_reference(seed, gap):
    ev = _stream(seed)
    b = burst_means(ev, gap)
    got = list(zip(b.t.tolist(), b.x.tolist(), b.y.tolist(), b.p.tolist(), strict=True))
    assert got == _reference(ev, gap)


@pytest.mark.parametrize("seed", [0, 3])
def test_any_chunking_gives_the_same_bursts(seed):
    ev = _stream(seed)
    whole = burst_means(ev, 2_000)
    rng = np.random.default_rng(seed)
    for _ in range(3):
        cuts = np.r_[0, np.sort(rng.integers(0, len(ev), 40)), len(ev)]
        bm = BurstMeans(ev.sensor_size, 2_000)
        parts = [bm.process(ev[a:c]) for a, c in zip(cuts[:-1], cuts[1:], strict=True)]
        parts.append(bm.flush())
        got = concatenate(parts, validate=False)
        for name in "xytp":
            np.testing.assert_array_equal(getattr(got, name), getattr(whole, name))
        # returned as soon as final, never out of order
        assert np.all(np.diff(got.t) >= 0)


def test_bursts_are_returned_once_final():
    ev = EventArray([1, 1, 1, 3], [0, 0, 0, 0], [0, 10, 21, 10_000], [1, 1, 1, 1], (2, 4))
    bm = BurstMeans((2, 4), gap_us=5_000)
    first = bm.process(ev)
    assert first.t.tolist() == [10] and first.x.tolist() == [1]  # (0 + 10 + 21) / 3 = 10.3
    assert bm.flush().t.tolist() == [10_000]
    assert len(bm.flush()) == 0


def test_bad_input_is_reported():
    bm = BurstMeans((4, 4), 1_000)
    with pytest.raises(ParameterError, match="sensor_size"):
        bm.process(EventArray([0], [0], [0], [1], (5, 5)))
    bm.process(EventArray([0], [0], [100], [1], (4, 4)))
    with pytest.raises(ParameterError, match="before the previous"):
        bm.process(EventArray([0], [0], [50], [1], (4, 4)))
    unsorted = EventArray([0, 1], [0, 0], [300, 200], [1, 1], (4, 4), validate=False)
    with pytest.raises(ParameterError, match="not sorted at event 1"):
        BurstMeans((4, 4), 1_000).process(unsorted)
    off = EventArray([0, 9], [0, 0], [0, 1], [1, 1], (4, 4), validate=False)
    with pytest.raises(ParameterError, match="x=9 outside"):
        BurstMeans((4, 4), 1_000).process(off)
    for gap in (0, -5, 2.5):
        with pytest.raises(ParameterError, match="gap_us"):
            BurstMeans((4, 4), gap)
