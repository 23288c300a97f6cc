"""Voxel grid (numpy only): np.bincount implementation vs a plain per-event loop."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.events import EventArray
from evmotion.methods.dnn.voxel import (
    network_input,
    network_inputs,
    normalize_voxel,
    pad_to_multiple,
    voxel_grid,
)


def _reference(x, y, t, p, shape, n_bins):
    """Zhu et al.'s voxel grid written as the formula: every event adds
    pol * max(0, 1 - |t* - b|) to every bin b, t* = (t - t0) / (tN - t0) * (B - 1)."""
    h, w = shape
    grid = np.zeros((n_bins, h, w))
    span = t[-1] - t[0]
    for k in range(len(t)):
        ts = (t[k] - t[0]) / span * (n_bins - 1) if span > 0 else 0.0
        pol = 1.0 if p[k] > 0 else -1.0
        xi = min(max(int(np.rint(x[k])), 0), w - 1)
        yi = min(max(int(np.rint(y[k])), 0), h - 1)
        for b in range(n_bins):
            grid[b, yi, xi] += pol * max(0.0, 1.0 - abs(ts - b))
    return grid


@pytest.mark.parametrize(("shape", "n_bins", "subpixel"), [((13, 17), 5, False),
                                                           ((20, 9), 3, True),
                                                           ((7, 7), 9, False)])
def test_voxel_matches_loop_reference(shape, n_bins, subpixel):
    rng = np.random.default_rng(n_bins)
    n = 2000
    h, w = shape
    t = np.sort(rng.integers(1000, 50_000, n))
    x = rng.uniform(0, w - 1, n) if subpixel else rng.integers(0, w, n)
    y = rng.uniform(0, h - 1, n) if subpixel else rng.integers(0, h, n)
    p = rng.integers(0, 2, n)
    ev = EventArray(x=x, y=y, t=t, p=p, sensor_size=shape)
    got = voxel_grid(ev, n_bins)
    assert got.shape == (n_bins, h, w) and got.dtype == np.float32
    ref = _reference(np.asarray(ev.x, float), np.asarray(ev.y, float), t, p, shape, n_bins)
    np.testing.assert_allclose(got, ref, atol=1e-4)
    # each event's weights sum to 1: the grid sums to the net polarity
    assert got.sum() == pytest.approx(np.where(p > 0, 1, -1).sum(), abs=1e-2)


def test_voxel_first_and_last_event_land_in_end_bins():
    ev = EventArray(x=[0, 1], y=[0, 0], t=[0, 10], p=[1, 1], sensor_size=(1, 2))
    g = voxel_grid(ev, 5)
    assert g[:, 0, 0].tolist() == [1, 0, 0, 0, 0]
    assert g[:, 0, 1].tolist() == [0, 0, 0, 0, 1]


def test_voxel_errors():
    ev = EventArray(x=[0], y=[0], t=[0], p=[1], sensor_size=(2, 2))
    with pytest.raises(ParameterError, match="n_bins"):
        voxel_grid(ev, 1)
    with pytest.raises(EmptyWindowError):
        voxel_grid(ev[:0])


@pytest.mark.parametrize(("h", "w"), [(180, 240), (260, 346), (480, 640), (720, 1280),
                                      (1, 17)])
def test_pad_to_multiple_of_16(h, w):
    g = np.ones((5, h, w), np.float32)
    out = pad_to_multiple(g)
    assert out.shape[1] % 16 == 0 and out.shape[2] % 16 == 0
    assert out.shape[1] - h < 16 and out.shape[2] - w < 16
    np.testing.assert_array_equal(out[:, :h, :w], g)
    assert out.sum() == g.sum()


def test_normalize_voxel_is_density_invariant():
    g = np.array([[[0.0, 1.0, -3.0]]], np.float32)
    np.testing.assert_allclose(normalize_voxel(g), normalize_voxel(4 * g))
    assert normalize_voxel(np.zeros((1, 2, 2), np.float32)).sum() == 0


def test_network_inputs_are_the_binned_events_inputs():
    # one set of votes, summed over k x k blocks, is the input of the events binned k
    # times coarser, whatever the sensor size (here not a multiple of 4)
    rng = np.random.default_rng(1)
    h, w, n = 37, 53, 3000
    ev = EventArray(x=rng.integers(0, w, n), y=rng.integers(0, h, n),
                    t=np.sort(rng.integers(0, 10_000, n)), p=rng.integers(0, 2, n),
                    sensor_size=(h, w))
    grids = network_inputs(ev, (1, 2, 4))
    for k, grid in zip((1, 2, 4), grids, strict=True):
        binned = EventArray(x=ev.x // k, y=ev.y // k, t=ev.t, p=ev.p,
                            sensor_size=(-(-h // k), -(-w // k)))
        np.testing.assert_allclose(grid, network_input(binned), rtol=1e-6, atol=1e-6)
