"""Per-tile translation search (multicm's restarts and its other-motion check): the numba
scores against plain numpy, and tiles told apart by their own motion."""

import numpy as np
import pytest

from evmotion.core import translation
from evmotion.core.tilegrid import TileGrid
from evmotion.core.tilesearch import box_scores_jit, tile_gains, tile_restarts
from evmotion.core.translation import (
    MIN_TILE_EVENTS,
    box_scores,
    sharpest_translation,
    translation_scores,
)


def _numpy_box_scores(x, y, s, k, dxs, dys):
    out = []
    for dx, dy in zip(dxs, dys, strict=True):
        cx = np.floor((x - dx * s) / k).astype(np.int64)
        cy = np.floor((y - dy * s) / k).astype(np.int64)
        _, counts = np.unique(np.stack([cx, cy]), axis=1, return_counts=True)
        out.append(float((counts.astype(np.float64) ** 2).sum()))
    return np.array(out)


@pytest.mark.parametrize("k", [1, 2, 8])
def test_box_scores_match_numpy(k):
    rng = np.random.default_rng(k)
    x, y = rng.uniform(-20, 60, 500), rng.uniform(-5, 40, 500)
    s = rng.uniform(-0.5, 0.5, 500)
    dxs, dys = rng.uniform(-30, 30, 40), rng.uniform(-30, 30, 40)
    reference = _numpy_box_scores(x, y, s, k, dxs, dys)
    np.testing.assert_array_equal(box_scores_jit(x, y, s, k, dxs, dys), reference)
    np.testing.assert_array_equal(box_scores(x, y, s, k, dxs, dys), reference)
    # inside a sensor that holds every moved event, the sensor's scores are the same
    np.testing.assert_array_equal(box_scores(x + 100, y + 100, s, k, dxs, dys),
                                  translation_scores(x + 100, y + 100, s, k, dxs, dys,
                                                     (400, 400)))
    assert box_scores_jit(x[:0], y[:0], s[:0], k, dxs, dys).tolist() == [0.0] * 40
    assert box_scores(x[:0], y[:0], s[:0], k, dxs, dys).tolist() == [0.0] * 40


def _two_halves(n_dots=300, repeats=15, move=12.0, seed=0):
    rng = np.random.default_rng(seed)
    x0, y0 = rng.uniform(0, 96, n_dots), rng.uniform(0, 48, n_dots)
    s = np.repeat(np.linspace(-0.5, 0.5, repeats), n_dots)
    left = np.tile(x0, repeats) < 48
    x = np.floor(np.tile(x0, repeats) + np.where(left, move, 0.0) * s)
    return x, np.floor(np.tile(y0, repeats)), s, left


def test_tile_gains_find_each_tiles_motion():
    x, y, s, left = _two_halves()
    grid = TileGrid(1, 2, (48, 96))
    truth = np.stack([np.where(left, 12.0, 0.0), np.zeros(x.size)], axis=1)
    best, gain = tile_gains(x, y, s, truth, grid, 24.0)
    assert best.tolist() == [[[12.0, 0.0], [0.0, 0.0]]]
    np.testing.assert_allclose(gain, 1.0, atol=0.02)  # the truth is as sharp as can be
    # under the left half's motion everywhere, the right half's tile stands out
    _, gain = tile_gains(x, y, s, np.tile([12.0, 0.0], (x.size, 1)), grid, 24.0)
    assert gain[0, 0] == pytest.approx(1.0, abs=0.02) and gain[0, 1] > 2.0
    # numpy's scores (the dnn path, which imports no numba) give the same
    np.testing.assert_array_equal(
        translation.tile_gains(x, y, s, np.tile([12.0, 0.0], (x.size, 1)), grid, 24.0)[1],
        gain)
    # too few events: no verdict
    few = slice(0, MIN_TILE_EVENTS - 1)
    assert np.isnan(tile_gains(x[few], y[few], s[few], truth[few], grid, 24.0)[1]).all()


def test_tile_restarts_leave_a_right_flow_alone():
    x, y, s, _ = _two_halves()
    grid = TileGrid(1, 2, (48, 96))
    right = np.array([[[12.0, 0.0], [0.0, 0.0]]])
    assert tile_restarts(x, y, s, right, grid, 24.0) is None
    wrong = np.array([[[12.0, 0.0], [12.0, 0.0]]])
    np.testing.assert_array_equal(tile_restarts(x, y, s, wrong, grid, 24.0), right)


def test_the_search_takes_another_scorer():
    x, y, s, left = _two_halves()
    calls = []

    def scores(*a):
        calls.append(a[3])
        return box_scores_jit(*(np.asarray(v, np.float64) for v in a[:3]), int(a[3]),
                              *(np.asarray(v, np.float64) for v in a[4:]))

    assert sharpest_translation(x[left], y[left], s[left], (48, 96), 24.0,
                                scores=scores) == (12.0, 0.0)
    assert calls[-1] == 1 and calls[0] > 1  # coarse to fine

