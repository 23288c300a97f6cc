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
