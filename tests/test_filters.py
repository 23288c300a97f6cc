import numpy as np

from evmotion import EventArray
from evmotion.filters import hot_pixel_mask, refractory_filter, remove_hot_pixels


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
