"""Flow, sharpness and rotation metrics against plain reference implementations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.eval import (
    FlowMetrics,
    aggregate_flow_metrics,
    angular_error_deg,
    endpoint_error,
    event_mask,
    flow_metrics,
    fwl,
    rms_error,
    sample_flow_bilinear,
    valid_gt_mask,
)
from evmotion.events import EventArray


def _ref_metrics(flow, gt, sel, out_px=3.0, out_rel=None):
    """Pixel-by-pixel loop, the textbook definitions."""
    ee, ae, out = [], [], []
    h, w = sel.shape
    for r in range(h):
        for c in range(w):
            if not sel[r, c]:
                continue
            u, v = float(flow[r, c, 0]), float(flow[r, c, 1])
            ug, vg = float(gt[r, c, 0]), float(gt[r, c, 1])
            e = math.sqrt((u - ug) ** 2 + (v - vg) ** 2)
            ee.append(e)
            cosang = (u * ug + v * vg + 1) / math.sqrt((u * u + v * v + 1) * (ug * ug + vg * vg + 1))
            ae.append(math.degrees(math.acos(max(-1.0, min(1.0, cosang)))))
            o = e > out_px
            if out_rel is not None:
                o = o and e > out_rel * math.hypot(ug, vg)
            out.append(o)
    ee = np.array(ee)
    return {"aee": ee.mean(), "ae": np.mean(ae), "out": 100 * np.mean(out),
            "npe": {n: 100 * np.mean(ee > n) for n in (1, 2, 3, 5, 10, 20)}, "n": len(ee)}


def _random_pair(seed=0, shape=(20, 30)):
    rng = np.random.default_rng(seed)
    gt = rng.normal(0, 6, shape + (2,)).astype(np.float32)
    est = (gt + rng.normal(0, 4, shape + (2,))).astype(np.float32)
    return est, gt


def test_flow_metrics_match_reference_loop():
    est, gt = _random_pair()
    m = flow_metrics(est, gt)
    ref = _ref_metrics(est, gt, np.ones(gt.shape[:2], bool))
    assert m.n_pixels == ref["n"] == 600
    assert m.aee == pytest.approx(ref["aee"], rel=1e-6)
    assert m.ae_deg == pytest.approx(ref["ae"], rel=1e-6)
    assert m.pct_out == pytest.approx(ref["out"])
    for n, v in ref["npe"].items():
        assert m.npe[n] == pytest.approx(v)
    assert m.pct_out == m.npe[3]  # the thesis' %Out is 3PE


def test_kitti_style_outliers_need_relative_error_too():
    gt = np.zeros((1, 2, 2), np.float32)
    gt[0, 0] = (100.0, 0.0)
    gt[0, 1] = (10.0, 0.0)
    est = gt.copy()
    est[..., 0] += 4.0  # EE 4 px: 4 % of 100 px, 40 % of 10 px
    assert flow_metrics(est, gt).pct_out == 100.0
    assert flow_metrics(est, gt, out_rel=0.05).pct_out == 50.0
    assert flow_metrics(est, gt, out_px=5.0).pct_out == 0.0
    ref = _ref_metrics(est, gt, np.ones((1, 2), bool), out_rel=0.05)
    assert flow_metrics(est, gt, out_rel=0.05).pct_out == ref["out"]


def test_known_values():
    gt = np.zeros((2, 2, 2), np.float32)
    est = gt.copy()
    est[0, 0] = (3.0, 4.0)  # EE 5
    est[1, 1] = (1.0, 0.0)  # EE 1, angle between (1,0,1) and (0,0,1) = 45 deg
    m = flow_metrics(est, gt)
    assert m.aee == pytest.approx(1.5)
    assert m.npe[1] == 25.0 and m.npe[3] == 25.0 and m.npe[5] == 0.0
    ae = angular_error_deg(est, gt)
    assert ae[1, 1] == pytest.approx(45.0)
    assert ae[0, 1] == 0.0
    assert endpoint_error(est, gt)[0, 0] == pytest.approx(5.0)
    assert set(m.as_dict()) >= {"AEE", "1PE", "3PE", "20PE", "%Out", "AE_deg", "n_pixels"}


def test_masks_restrict_the_evaluation():
    est, gt = _random_pair(1)
    gt[0, :] = np.nan  # invalid GT row
    gt[1, :] = 0.0  # "no GT" in MVSEC terms
    user = np.ones(gt.shape[:2], bool)
    user[:, :5] = False
    m = flow_metrics(est, gt, mask=user)
    sel = valid_gt_mask(gt) & user
    assert m.n_pixels == sel.sum() == 19 * 25
    assert m.aee == pytest.approx(_ref_metrics(est, gt, sel)["aee"], rel=1e-6)
    mv = flow_metrics(est, gt, mask=valid_gt_mask(gt, zero_is_invalid=True))
    assert mv.n_pixels == 18 * 30


def test_event_mask_and_events_argument():
    ev = EventArray(x=np.array([0.4, 2.6, 2.9, 5.0], np.float32),
                    y=np.array([0.0, 1.2, 0.8, 2.0], np.float32),
                    t=[0, 1, 2, 3], p=[1, 0, 1, 1], sensor_size=(3, 6))
    mask = event_mask(ev)
    expect = np.zeros((3, 6), bool)
    expect[0, 0] = expect[1, 3] = expect[2, 5] = True
    np.testing.assert_array_equal(mask, expect)
    est, gt = _random_pair(2, (3, 6))
    m = flow_metrics(est, gt, events=ev)
    assert m.n_pixels == 3
    assert m.aee == pytest.approx(_ref_metrics(est, gt, expect)["aee"], rel=1e-6)


def test_empty_selection_gives_nan_and_is_skipped_by_aggregate():
    est, gt = _random_pair()
    m = flow_metrics(est, gt, mask=np.zeros(gt.shape[:2], bool))
    assert m.n_pixels == 0 and math.isnan(m.aee) and math.isnan(m.npe[3])
    a = FlowMetrics(1.0, {3: 0.0}, 0.0, 1.0, 10)
    b = FlowMetrics(3.0, {3: 50.0}, 50.0, 3.0, 30)
    agg = aggregate_flow_metrics([a, m, b])
    assert (agg.aee, agg.npe[3], agg.n_pixels) == (2.0, 25.0, 40)
    assert aggregate_flow_metrics([a, b], weight="pixel").aee == pytest.approx(2.5)
    with pytest.raises(EmptyWindowError):
        aggregate_flow_metrics([m])
    with pytest.raises(ParameterError, match="weight"):
        aggregate_flow_metrics([a], weight="frames")


def test_integer_flows_are_compared_in_float():
    """uint8 differences wrapped (4 px read 252) and int16 squares overflowed."""
    from evmotion.eval.metrics import angular_error_deg, endpoint_error

    est, gt = np.zeros((2, 3, 2), np.uint8), np.zeros((2, 3, 2), np.uint8)
    gt[..., 0] = 4
    assert np.allclose(endpoint_error(est, gt), 4.0)
    a, b = np.zeros((1, 1, 2), np.int16), np.zeros((1, 1, 2), np.int16)
    a[..., 0], b[..., 0] = 200, 190
    assert np.allclose(angular_error_deg(a, b), angular_error_deg(a.astype(float),
                                                                  b.astype(float)))
    assert angular_error_deg(a, b)[0, 0] < 0.02


def test_bad_inputs_raise_clear_errors():
    est, gt = _random_pair()
    with pytest.raises(ParameterError, match="shape"):
        flow_metrics(est[:, :-1], gt)
    with pytest.raises(ParameterError, match=r"\(H, W, 2\)"):
        flow_metrics(est[..., 0], gt[..., 0])
    with pytest.raises(ParameterError, match="mask"):
        flow_metrics(est, gt, mask=np.ones((2, 2), bool))
    est[3, 4] = np.nan
    with pytest.raises(ParameterError, match="NaN/inf at 1 of the 600"):
        flow_metrics(est, gt)
    sel = np.ones(gt.shape[:2], bool)
    sel[3, 4] = False
    assert flow_metrics(est, gt, mask=sel).n_pixels == 599


def test_sample_flow_bilinear_matches_scipy():
    rng = np.random.default_rng(3)
    flow = rng.normal(size=(12, 17, 2))
    x = rng.uniform(-2, 18, 500)
    y = rng.uniform(-2, 13, 500)
    got = sample_flow_bilinear(flow, x, y)
    xc, yc = np.clip(x, 0, 16), np.clip(y, 0, 11)
    for c in range(2):
        ref = ndimage.map_coordinates(flow[..., c], [yc, xc], order=1, mode="nearest")
        np.testing.assert_allclose(got[:, c], ref, atol=1e-12)


def _ref_bilinear_iwe(xw, yw, shape):
    h, w = shape
    img = np.zeros(shape)
    for x, y in zip(xw, yw, strict=True):
        x0, y0 = math.floor(x), math.floor(y)
        for dx in (0, 1):
            for dy in (0, 1):
                xi, yi = x0 + dx, y0 + dy
                if 0 <= xi < w and 0 <= yi < h:
                    img[yi, xi] += (1 - abs(x - xi)) * (1 - abs(y - yi))
    return img


def _moving_edge(seed=0, speed=(800.0, -300.0)):
    """Events of a vertical random-dot edge translating at ``speed`` px/s over 20 ms."""
    rng = np.random.default_rng(seed)
    n = 3000
    t = np.sort(rng.integers(0, 20_000, n))
    y0 = rng.uniform(8, 35, n)
    x0 = 10.0 + rng.integers(0, 3, n) * 4.0
    x = x0 + speed[0] * t * 1e-6
    y = y0 + speed[1] * t * 1e-6
    ev = EventArray(x.astype(np.float32), y.astype(np.float32), t, rng.integers(0, 2, n),
                    sensor_size=(40, 48))
    flow = np.zeros((40, 48, 2), np.float32)
    flow[..., 0], flow[..., 1] = speed
    return ev, flow


def test_fwl_true_flow_sharper_than_zero_and_wrong_flow():
    ev, flow = _moving_edge()
    assert fwl(ev, np.zeros_like(flow)) == pytest.approx(1.0)
    good = fwl(ev, flow)
    assert good > 2.0
    assert fwl(ev, -flow) < good
    assert fwl(ev, 0.5 * flow) < good
    assert fwl(ev, flow, t_ref_us=10_000) == pytest.approx(good, rel=0.2)


def test_fwl_matches_reference_iwe():
    ev, flow = _moving_edge(1)
    rng = np.random.default_rng(4)
    flow = flow + rng.normal(0, 50, flow.shape).astype(np.float32)
    t_ref = 7_000
    x, y = ev.x.astype(np.float64), ev.y.astype(np.float64)
    dt = (t_ref - ev.t) * 1e-6
    uv = np.stack([ndimage.map_coordinates(flow[..., c], [y, x], order=1, mode="nearest")
                   for c in range(2)], axis=1)
    warped = _ref_bilinear_iwe(x + uv[:, 0] * dt, y + uv[:, 1] * dt, ev.sensor_size)
    ident = _ref_bilinear_iwe(x, y, ev.sensor_size)
    assert fwl(ev, flow, t_ref) == pytest.approx(warped.var() / ident.var(), rel=1e-9)


def test_fwl_errors():
    ev, flow = _moving_edge()
    with pytest.raises(EmptyWindowError):
        fwl(ev[:0], flow)
    with pytest.raises(ParameterError, match="sensor size"):
        fwl(ev, flow[:-1])


def test_rms_error():
    est = np.array([[1.0, 2.0, 0.0], [3.0, -2.0, 0.0], [np.nan, 0.0, 0.0]])
    gt = np.zeros((3, 3))
    r = rms_error(est, gt)
    assert r.n_samples == 2
    np.testing.assert_allclose(r.per_axis, [math.sqrt(5.0), 2.0, 0.0])
    assert r.overall == pytest.approx(math.sqrt((1 + 4 + 9 + 4) / 6))
    assert r.norm == pytest.approx(math.sqrt((5 + 13) / 2))
    assert r.as_dict()["rms_y"] == pytest.approx(2.0)
    assert rms_error(np.array([1.0, -1.0]), np.zeros(2)).overall == pytest.approx(1.0)
    with pytest.raises(ParameterError, match="shape"):
        rms_error(np.zeros((3, 3)), np.zeros((2, 3)))
    with pytest.raises(EmptyWindowError):
        rms_error(np.full((2, 3), np.nan), np.zeros((2, 3)))


def test_rms_error_of_huge_errors_does_not_overflow():
    """Errors past 1.3e154 overflowed when squared (inf and a RuntimeWarning, probe EVAL);
    the RMS of 1e200 is 1e200. It is the plain formula wherever that does not overflow."""
    import warnings

    rng = np.random.default_rng(3)
    est, gt = rng.normal(size=(7, 3)), rng.normal(size=(7, 3))
    d = est - gt
    r = rms_error(est, gt)
    np.testing.assert_allclose(r.per_axis, np.sqrt(np.mean(d * d, axis=0)), rtol=1e-14)
    assert r.norm == pytest.approx(np.sqrt(np.mean(np.sum(d * d, axis=1))), rel=1e-14)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        big = rms_error(est * 1e200, gt * 1e200)
    np.testing.assert_allclose(big.per_axis, r.per_axis * 1e200, rtol=1e-12)
    assert big.overall == pytest.approx(r.overall * 1e200, rel=1e-12)
    assert rms_error(np.zeros((2, 3)), np.zeros((2, 3))).norm == 0.0


@pytest.mark.realdata
@pytest.mark.parametrize("scene", ["boxes_rotation", "poster_rotation"])
def test_fwl_on_real_ecd_window_peaks_at_ground_truth(shared_data, scene):
    """ECD rotation windows: the IMU's rotational flow sharpens the IWE (FWL > 1.3) and
    beats its reverse, half and 1.5x, so FWL's warp direction and time sign are right."""
    from evmotion.io.calibration import read_ecd

    folder = shared_data / "ecd_rotation_windows" / scene
    a = np.loadtxt(folder / "events.txt")
    ev = EventArray(a[:, 1].astype(np.uint16), a[:, 2].astype(np.uint16),
                    np.round(a[:, 0] * 1e6).astype(np.int64), a[:, 3].astype(np.uint8),
                    sensor_size=(180, 240))
    undist = read_ecd(folder / "calib.txt").undistort_events(ev)
    disp = np.load(folder / "flow.npy")[0].transpose(1, 2, 0)  # px over the window
    flow = disp / ((ev.t[-1] - ev.t[0]) * 1e-6)
    best = fwl(undist, flow)
    assert best > 1.3
    for scale in (-1.0, 0.5, 1.5):
        assert fwl(undist, scale * flow) < best
    assert fwl(undist, flow, t_ref_us=int(ev.t[-1])) == pytest.approx(best, rel=0.05)


def test_an_estimate_no_better_than_zero_flow_is_flagged():
    # a flow scored against another scene's ground truth read like a poor estimate (probe
    # BA: AEE 0.24 px against the zero flow's 0.064, no word)
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.eval.eventflow import event_flow_metrics
    from evmotion.eval.windows import evaluate_windows
    from evmotion.io.flowfiles import FlowSequence

    gt = FlowSequence(flow=np.zeros((1, 8, 8, 2), np.float32) + np.float32([0.0, 100.0]),
                      t0=np.array([0]), t1=np.array([10_000]))
    across = np.zeros((1, 8, 8, 2), np.float32) + np.float32([100.0, 0.0])
    near = np.zeros((1, 8, 8, 2), np.float32) + np.float32([10.0, 90.0])
    with pytest.warns(EvmotionWarning, match="no lower than the zero flow's 1 px"):
        evaluate_windows(across, [0], [10_000], gt)
    n = 50
    events = {"t": np.arange(n) * 100, "x": np.full(n, 3.5), "y": np.full(n, 4.0),
              "vx": np.full(n, 100.0), "vy": np.zeros(n)}
    with pytest.warns(EvmotionWarning, match="flow of 50 events"):
        event_flow_metrics(events, gt)
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)
        assert evaluate_windows(near, [0], [10_000], gt).total["AEE"] < 1.0
        event_flow_metrics({**events, "vx": np.full(n, 10.0), "vy": np.full(n, 90.0)}, gt)
        # a ground truth that does not move gives no verdict
        still = FlowSequence(flow=np.zeros((1, 8, 8, 2), np.float32), t0=np.array([0]),
                             t1=np.array([10_000]))
        evaluate_windows(across, [0], [10_000], still)
