"""Farneback baseline: recovers known sub-pixel translations and smooth warps of dot images."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from scipy import ndimage

from evmotion.errors import MissingDependencyError, ParameterError
from evmotion.methods.farneback import farneback_flow, frame_to_float

pytest.importorskip("cv2")

H, W = 96, 112
DT = 1 / 120


def _texture(seed: int = 0) -> np.ndarray:
    # random dots blurred to ~2 px: a BOS-style background, smooth enough to resample exactly
    rng = np.random.default_rng(seed)
    dots = (rng.random((H, W)) < 0.15).astype(np.float64)
    img = ndimage.gaussian_filter(dots, 1.0)
    return img / img.max()


def _warp(img: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    # frame1(x) = frame0(x - d): content moves by +d (cubic spline, periodic texture off)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    return ndimage.map_coordinates(img, [yy - dy, xx - dx], order=3, mode="reflect")


def _interior(a: np.ndarray, m: int = 16) -> np.ndarray:
    return a[m:-m, m:-m]


@pytest.mark.parametrize("shift", [(0.3, -0.2), (0.75, 0.5), (-1.6, 0.9)])
def test_subpixel_translation(shift):
    img = _texture()
    dx, dy = shift
    f1 = _warp(img, np.full((H, W), dx), np.full((H, W), dy))
    flow = farneback_flow(img, f1, DT)
    assert flow.shape == (H, W, 2) and flow.dtype == np.float32
    err = np.hypot(flow[..., 0] * DT - dx, flow[..., 1] * DT - dy)
    assert np.median(_interior(err)) < 0.03
    np.testing.assert_allclose(np.median(_interior(flow[..., 0])) * DT, dx, atol=0.02)
    np.testing.assert_allclose(np.median(_interior(flow[..., 1])) * DT, dy, atol=0.02)


def test_smooth_warp():
    img = _texture(1)
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    # a schlieren-like field: 0.6 px peak displacement varying over ~50 px
    dx = 0.6 * np.sin(2 * np.pi * xx / 80) * np.cos(2 * np.pi * yy / 100)
    dy = 0.4 * np.cos(2 * np.pi * xx / 90)
    f1 = _warp(img, dx, dy)
    flow = farneback_flow(img, f1, DT) * DT
    aee = np.hypot(flow[..., 0] - dx, flow[..., 1] - dy)
    assert _interior(aee).mean() < 0.08
    # the zero-flow guess is far worse, so the test can fail
    assert _interior(np.hypot(dx, dy)).mean() > 0.3
    # the sign and pattern: strongly correlated with the true field
    assert np.corrcoef(_interior(flow[..., 0]).ravel(), _interior(dx).ravel())[0, 1] > 0.95


def test_dtypes_agree():
    img = _texture(2)
    f1 = _warp(img, np.full((H, W), 0.5), np.zeros((H, W)))
    ref = farneback_flow(img, f1, DT)
    u16 = farneback_flow(np.round(img * 65535).astype(np.uint16),
                         np.round(f1 * 65535).astype(np.uint16), DT)
    np.testing.assert_allclose(u16, ref, atol=0.05 / DT)
    u8 = farneback_flow(np.round(img * 255).astype(np.uint8),
                        np.round(np.clip(f1, 0, 1) * 255).astype(np.uint8), DT)
    assert abs(np.median(_interior(u8[..., 0])) * DT - 0.5) < 0.03
    rgb = np.repeat(img[..., None], 3, axis=2)
    rgb1 = np.repeat(f1[..., None], 3, axis=2)
    np.testing.assert_allclose(farneback_flow(rgb, rgb1, DT), ref, atol=1e-3 / DT)


def test_levels_and_dt_scale():
    img = _texture(3)
    f1 = _warp(img, np.full((H, W), 0.4), np.zeros((H, W)))
    a = farneback_flow(img, f1, 0.01, levels=1)
    b = farneback_flow(img, f1, 0.02, levels=1)
    np.testing.assert_allclose(a, 2 * b, rtol=1e-5, atol=1e-3)


def test_frame_to_float():
    assert frame_to_float(np.array([[0, 255]], np.uint8)).tolist() == [[0.0, 255.0]]
    assert frame_to_float(np.array([[65535]], np.uint16)).tolist() == [[255.0]]
    with pytest.raises(ParameterError, match="shape"):
        frame_to_float(np.zeros((2, 2, 2)))
    with pytest.raises(ParameterError, match="NaN"):
        frame_to_float(np.array([[np.nan]]))


@pytest.mark.parametrize("kw, match", [
    ({"dt_s": 0.0}, "dt_s"), ({"dt_s": float("nan")}, "dt_s"), ({"levels": 0}, "levels"),
    ({"pyr_scale": 1.0}, "pyr_scale"), ({"winsize": 1}, "winsize"),
])
def test_bad_parameters(kw, match):
    img = _texture()
    args = {"dt_s": DT, **kw}
    dt = args.pop("dt_s")
    with pytest.raises(ParameterError, match=match):
        farneback_flow(img, img, dt, **args)


def test_size_mismatch():
    with pytest.raises(ParameterError, match="differ in size"):
        farneback_flow(np.zeros((8, 8)), np.zeros((8, 9)), DT)


def test_missing_opencv(monkeypatch):
    monkeypatch.setitem(sys.modules, "cv2", None)
    with pytest.raises(MissingDependencyError, match=r"opencv-python-headless.*evmotion\[bos\]"):
        farneback_flow(np.zeros((8, 8)), np.zeros((8, 8)), DT)


# ------------------------------------------------------------------ frame intervals
def test_farneback_intervals_per_interval_dt():
    from evmotion.methods.baselines import farneback_intervals

    img = _texture(4)
    f1 = _warp(img, np.full((H, W), 0.5), np.zeros((H, W)))
    f2 = _warp(img, np.full((H, W), 1.0), np.zeros((H, W)))
    flows = farneback_intervals(np.stack([img, f1, f2]), [0, 5000, 15_000])
    assert flows.shape == (2, H, W, 2)
    # 0.5 px in 5 ms, then 0.5 px in 10 ms
    assert np.median(_interior(flows[0, ..., 0])) == pytest.approx(100.0, rel=0.05)
    assert np.median(_interior(flows[1, ..., 0])) == pytest.approx(50.0, rel=0.05)
    with pytest.raises(ParameterError, match="increase"):
        farneback_intervals(np.stack([img, f1]), [10, 10])
    with pytest.raises(ParameterError, match="3 frame times for 2 frames"):
        farneback_intervals(np.stack([img, f1]), [0, 1, 2])


def test_multicm_intervals_window_events():
    from evmotion.errors import EmptyWindowError
    from evmotion.methods.baselines import multicm_interval, multicm_intervals
    from evmotion.sim import simulate

    sim = simulate("translation", duration_s=0.03, sensor_size=(48, 64), seed=0,
                   params={"vx": 300.0, "vy": -150.0}, show_progress=False)
    ev = sim.events
    times = [0, 10_000, 20_000, 30_000]
    kw = {"n_scales": 2, "finest_level": 2}
    res = multicm_intervals(ev, times, **kw)
    assert len(res) == 3
    for r, a, b in zip(res, times[:-1], times[1:], strict=True):
        inside = ev.t[(ev.t >= a) & (ev.t < b)]
        assert (r.t0_us, r.t1_us, r.n_events) == (inside[0], inside[-1], inside.size)
        # a coarse 2x2-tile MultiCM on ~1200 events: right direction and size (260-270,
        # -147 to -163 px/s measured)
        assert np.median(r.flow[..., 0]) == pytest.approx(300.0, rel=0.25)
        assert np.median(r.flow[..., 1]) == pytest.approx(-150.0, rel=0.25)
    # the first interval (no warm start) is estimate_flow on exactly its events
    from evmotion.methods.multicm import estimate_flow

    ref = estimate_flow(ev.slice_time(0, 10_000), **kw)
    np.testing.assert_array_equal(res[0].flow, ref.flow)
    # warm start: the second interval started from the first's flow
    cold = multicm_interval(ev, 10_000, 20_000, **kw)
    assert cold.n_events == res[1].n_events
    with pytest.raises(EmptyWindowError, match="holds 0 events"):
        multicm_interval(ev, 50_000, 60_000)
    with pytest.raises(ParameterError, match="empty"):
        multicm_interval(ev, 100, 100)
