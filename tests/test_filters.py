import numpy as np
import pytest

from evmotion import EventArray
from evmotion.errors import EvmotionError, ParameterError, UnsortedError
from evmotion.filters import hot_line_mask, hot_pixel_mask, refractory_filter, remove_hot_pixels


def refractory_reference(ev, period):
    last = {}
    keep = []
    for k in range(len(ev)):
        key = (int(ev.x[k]), int(ev.y[k]))
        if key not in last or ev.t[k] - last[key] >= period:
            keep.append(k)
            last[key] = ev.t[k]
    return np.array(keep, dtype=int)


def test_refractory_matches_reference():
    rng = np.random.default_rng(1)
    n = 3000
    ev = EventArray(rng.integers(0, 5, n), rng.integers(0, 4, n), np.sort(rng.integers(0, 100000, n)),
                    rng.integers(0, 2, n), (4, 5))
    out = refractory_filter(ev, 1000)
    np.testing.assert_array_equal(out.t, ev.t[refractory_reference(ev, 1000)])
    assert len(refractory_filter(ev, 0)) == n


def test_filters_check_an_unchecked_array_like_the_estimators():
    # probe BE: with validate=False, the refractory kernel indexed its per-pixel state out of
    # bounds for off-sensor events and kept a meaningless subset of unsorted ones;
    # hot_pixel_mask counted x=9 of a 4-wide sensor on the next row
    off = EventArray([0, 1, 9], [0, 1, 0], [0, 10, 20], [1, 1, 1], (4, 4), validate=False)
    for f in (lambda e: refractory_filter(e, 5), hot_pixel_mask, remove_hot_pixels):
        with pytest.raises(EvmotionError, match=r"event 2 has x=9 outside the sensor"):
            f(off)
    back = EventArray([0, 1, 2], [0, 0, 0], [20, 10, 0], [1, 1, 1], (4, 4), validate=False)
    with pytest.raises(UnsortedError, match=r"t\[0\]=20 > t\[1\]=10"):
        refractory_filter(back, 5)
    with pytest.raises(EvmotionError, match="refractory_filter: events must be an EventArray"):
        refractory_filter([[0, 0, 0, 1]], 5)


def test_hot_pixel_removed():
    rng = np.random.default_rng(2)
    n = 5000
    x = rng.integers(0, 50, n)
    y = rng.integers(0, 40, n)
    x[:800], y[:800] = 7, 9
    order = np.argsort(rng.random(n))
    ev = EventArray(x[order], y[order], np.arange(n), np.zeros(n), (40, 50))
    mask = hot_pixel_mask(ev)
    assert mask[9, 7] and mask.sum() == 1
    clean = remove_hot_pixels(ev)
    at_hot = int(np.sum((ev.x == 7) & (ev.y == 9)))
    assert at_hot >= 800 and len(clean) == n - at_hot


def _moving_bars(rng, n, size=(60, 80), vertical=True):
    """Events of 1-px bars 6 px apart sweeping across the sensor (no stuck line)."""
    h, w = size
    t = np.sort(rng.integers(0, 100_000, n))
    offset = (t * 30 // 100_000)  # 30 px over the window
    if vertical:  # horizontal bars moving down: each row in turn
        y = (rng.integers(0, h // 6, n) * 6 + offset) % h
        x = rng.integers(0, w, n)
    else:
        x = (rng.integers(0, w // 6, n) * 6 + offset) % w
        y = rng.integers(0, h, n)
    return x, y, t


def test_stuck_row_and_column_masked_moving_bars_kept():
    rng = np.random.default_rng(3)
    h, w = 60, 80
    x, y, t = _moving_bars(rng, 20_000, (h, w))
    # a stuck row and a stuck column firing all along, 60 events a pixel
    sx, sy = np.tile(np.arange(w), 60), np.full(60 * w, 17)
    cx, cy = np.full(60 * h, 41), np.tile(np.arange(h), 60)
    xx, yy = np.r_[x, sx, cx], np.r_[y, sy, cy]
    tt = np.r_[t, rng.integers(0, 100_000, sx.size + cx.size)]
    order = np.argsort(tt, kind="stable")
    ev = EventArray(xx[order], yy[order], tt[order], np.ones(tt.size), (h, w))
    mask = hot_pixel_mask(ev, neighbour_ratio=4)
    # (where the two cross, the row's pixels beside the column have busy neighbours)
    assert mask[17].sum() >= w - 3 and mask[:, 41].sum() >= h - 3
    rows = np.flatnonzero(mask.sum(1) > 8)
    cols = np.flatnonzero(mask.sum(0) > 8)
    assert rows.tolist() == [17] and cols.tolist() == [41]
    # the bars alone: busy rows in turn, none stuck
    for vertical in (True, False):
        bx, by, bt = _moving_bars(rng, 20_000, (h, w), vertical)
        bars = EventArray(bx, by, bt, np.ones(bt.size), (h, w))
        assert not hot_pixel_mask(bars, neighbour_ratio=4).any()


def test_hot_line_mask_matches_loop_reference():
    rng = np.random.default_rng(4)
    counts = rng.poisson(3.0, (12, 15)).astype(float)
    counts[5, 2:14] = 40 + rng.integers(0, 5, 12)
    counts[:, 9] += 30
    thr, ratio = 10.0, 4.0
    h, w = counts.shape
    ref = np.zeros((h, w), bool)
    for img, out_t in ((counts, False), (counts.T, True)):
        hh, ww = img.shape
        rows = img.sum(1)
        for r in range(hh):
            side = max(rows[r - 1] if r > 0 else 0.0, rows[r + 1] if r < hh - 1 else 0.0)
            busy = []
            for c in range(ww):
                nb = [img[rr, cc] for rr in (r - 1, r + 1) for cc in (c - 1, c, c + 1)
                      if 0 <= rr < hh and 0 <= cc < ww]
                if img[r, c] > thr and img[r, c] > ratio * max(nb + [0.0]):
                    busy.append(c)
            if rows[r] > ratio * side and len(busy) >= 8:
                for c in busy:
                    if out_t:
                        ref[c, r] = True
                    else:
                        ref[r, c] = True
    got = hot_line_mask(counts, thr, ratio)
    np.testing.assert_array_equal(got, ref)
    assert got[5, 2:8].all() and got[:, 9].sum() >= h - 3


@pytest.mark.parametrize("call, name", [
    (lambda ev: refractory_filter(ev, 10.5), "refractory_us"),
    (lambda ev: refractory_filter(ev, -1), "refractory_us"),
    (lambda ev: hot_pixel_mask(ev, n_sigma=-1), "n_sigma"),
    (lambda ev: hot_pixel_mask(ev, n_sigma=float("nan")), "n_sigma"),
    (lambda ev: hot_pixel_mask(ev, min_count=2.5), "min_count"),
    (lambda ev: hot_pixel_mask(ev, neighbour_ratio=0.5), "neighbour_ratio"),
])
def test_options_out_of_range_are_refused_by_name(call, name):
    """Probe BE: refractory_us=10.5 ran as 10 and n_sigma=-1 or nan marked the busy half
    of the pixels hot, without a word."""
    from evmotion.errors import ParameterError

    ev = EventArray([0, 1, 2], [0, 0, 1], [0, 10, 20], [1, 1, 0], (4, 5))
    with pytest.raises(ParameterError, match=name):
        call(ev)


def test_simulator_and_metrics_options_out_of_range_are_refused_by_name():
    from evmotion.errors import ParameterError
    from evmotion.eval.metrics import flow_metrics
    from evmotion.sim import simulate

    with pytest.raises(ParameterError, match="refractory_us"):
        simulate("translation", duration_s=0.01, sensor_size=(40, 50), refractory_us=10.5,
                 show_progress=False)
    with pytest.raises(ParameterError, match="out_rel"):
        flow_metrics(np.zeros((2, 2, 2)), np.ones((2, 2, 2)), out_rel=-1)


def test_hot_pixel_mask_of_chunk_counts_is_the_whole_recordings():
    """A recording read in chunks (egomotion streams a long one) finds the hot pixels of
    the whole: the chunks' pixel counts add up, and the mask is made from them."""
    from evmotion.filters import hot_pixel_mask_of_counts, pixel_counts

    rng = np.random.default_rng(3)
    n = 20_000
    ev = EventArray(x=np.r_[rng.integers(0, 40, n), np.full(500, 7)],
                    y=np.r_[rng.integers(0, 30, n), np.full(500, 11)],
                    t=np.arange(n + 500), p=np.ones(n + 500), sensor_size=(30, 40))
    counts = sum(pixel_counts(ev[i:i + 777]) for i in range(0, len(ev), 777))
    np.testing.assert_array_equal(counts, pixel_counts(ev))
    mask = hot_pixel_mask_of_counts(counts, neighbour_ratio=4)
    np.testing.assert_array_equal(mask, hot_pixel_mask(ev, neighbour_ratio=4))
    assert np.argwhere(mask).tolist() == [[11, 7]]
    with pytest.raises(ParameterError, match="shape"):
        hot_pixel_mask_of_counts(counts.ravel())
