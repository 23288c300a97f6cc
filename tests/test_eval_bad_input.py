"""The evaluation functions and ``evmotion eval`` / ``view`` refuse arguments and files that
do not fit in one clear line: never a numpy traceback, a hang or a silent wrong score
(probe EVAL)."""

from __future__ import annotations

import warnings

import h5py
import numpy as np
import pytest

from evmotion.errors import EvmotionWarning, FormatError, ParameterError
from evmotion.events import EventArray
from evmotion.io.flowfiles import FlowSequence


def _gt(n: int = 3, h: int = 6, w: int = 8) -> FlowSequence:
    t = np.arange(n + 1) * 10_000
    return FlowSequence(flow=np.full((n, h, w, 2), 100.0, np.float32), t0=t[:-1], t1=t[1:],
                        valid=np.ones((n, h, w), bool))


@pytest.mark.parametrize("t0, t1, match", [
    (0, 10**30, "t1 must be a whole number in"),
    (0, 2**63, "t1 must be a whole number in"),
    (float("nan"), 20_000, "t0 must be a whole number"),
    (float("inf"), 20_000, "t0 must be a whole number"),
    (20_000, 0, r"\[20000, 0\] us is no interval"),
])
def test_gt_coverage_and_displacement_check_their_times(t0, t1, match):
    from evmotion.eval import gt_coverage, gt_displacement

    for fn in (gt_coverage, gt_displacement):
        with pytest.raises(ParameterError, match=match):
            fn(_gt(), t0, t1)


@pytest.mark.parametrize("shape", [(-1, 8), (1e30, 8), (float("nan"), 8), (0, 8), (1e-30, 8),
                                   "68", (6,)])
def test_event_mask_refuses_a_shape_that_is_no_image(shape):
    from evmotion.eval import event_mask

    ev = EventArray(x=[1], y=[1], t=[0], p=[1], sensor_size=(6, 8))
    with pytest.raises(ParameterError, match=r"event_mask: shape must be two whole numbers "
                                             r"of px \(height, width\) in 1\.\.16384"):
        event_mask(ev, shape=shape)
    assert event_mask(ev, shape=(6.0, 8)).sum() == 1


def test_params_flow_refuses_a_sensor_size_that_is_no_image():
    from evmotion.eval.egomotion import ParamsFlow
    from evmotion.io.paramsfiles import ParamsTable

    t = ParamsTable(np.array([[30.0, -10.0]]), ("vx", "vy"), ("px/s", "px/s"),
                    np.array([0]), np.array([10_000]), np.array([True]),
                    attrs={"warp": "translation", "grid": "sensor"})
    for size in ((-1, 5), (1e30, 5), (float("nan"), 5)):
        with pytest.raises(ParameterError, match="sensor_size must be two whole numbers"):
            ParamsFlow(t, size)
    assert ParamsFlow(t, (4, 5)).shape == (1, 4, 5, 2)


@pytest.mark.parametrize("flow, x, y, match", [
    (np.empty((0, 8, 2)), [1.0], [1.0], r"shape \(0, 8, 2\)"),  # an IndexError
    (np.zeros((6, 8)), [1.0], [1.0], r"shape \(6, 8\)"),  # came back as [[0.]]
    (np.zeros((6, 8, 2), bool), [1.0], [1.0], "dtype bool"),
    ([[1, 2]], [1.0], [1.0], r"shape \(1, 2\)"),  # an AttributeError
    (np.zeros((6, 8, 2)), [1.0, 2.0], [1.0], "one length, got 2 and 1"),  # an IndexError
    (np.zeros((6, 8, 2)), "abc", [1.0], "arrays of positions"),  # a ValueError
])
def test_sample_flow_bilinear_checks_its_arguments(flow, x, y, match):
    from evmotion.eval import sample_flow_bilinear

    with pytest.raises(ParameterError, match=match):
        sample_flow_bilinear(flow, x, y)


def test_evaluate_potential_checks_its_arrays_and_says_what_nan_means():
    from evmotion.eval import evaluate_potential

    yy, xx = np.mgrid[0:6, 0:8].astype(float)
    gt = (xx * yy)[None]
    t = np.array([0, 10_000])
    cases = [
        ((np.empty((0, 6, 8)), [0], [10_000], gt, t), "0 q windows for 1 t0s"),  # IndexError
        ((gt, [float("nan")], [10_000], gt, t), "whole microseconds"),
        ((gt, [0], [10_000, 20_000], gt, t), "1 q windows for 1 t0s and 2 t1s"),  # zip()
        ((gt, [0], [10_000], gt[:, :, :4], t), "not the same grid"),
        ((gt, [0], [10_000], gt, np.array([0])), "gt_t_us must be the 2 increasing"),
        ((None, [0], [10_000], gt, t), r"q must be numbers \(N, H, W\)"),  # TypeError
    ]
    for args, match in cases:
        with pytest.raises(ParameterError, match=match):
            evaluate_potential(*args)
    with pytest.raises(ParameterError, match="mask must be bool"):  # a ufunc casting error
        evaluate_potential(gt, [0], [10_000], gt, t, mask=np.ones((1, 6, 8), int))
    row = evaluate_potential(np.ones((1, 6, 8)), [0], [10_000], gt, t)[0]
    assert np.isnan(row["q_corr"]) and row["q_std_ratio"] == 0.0  # a constant estimate
    assert "NaN where either field is constant" in evaluate_potential.__doc__


def test_evaluate_windows_checks_the_ground_truth_and_dt():
    from evmotion.eval import evaluate_windows

    gt = _gt()
    est = np.full((1, 6, 8, 2), 110.0, np.float32)
    short = FlowSequence(gt.flow, gt.t0[:2], gt.t1, gt.valid)  # a broadcast error
    with pytest.raises(ParameterError, match=r"t0 \(2,\), t1 \(3,\)"):
        evaluate_windows(est, [0], [10_000], short)
    narrow = FlowSequence(gt.flow, gt.t0, gt.t1, gt.valid[..., :1])  # broadcast unsaid
    with pytest.raises(ParameterError, match=r"valid is \(3, 6, 1\) bool, expected "
                                             r"\(3, 6, 8\)"):
        evaluate_windows(est, [0], [10_000], narrow)
    for dt in (float("nan"), -1, 0, 1e-30, float("inf"), 1.5):  # NaN had matched all
        with pytest.raises(ParameterError, match="dt must be a whole number >= 1"):
            evaluate_windows(est, [0], [10_000], gt, dt=dt)
    assert evaluate_windows(est, [0], [10_000], gt, dt=1.0).mismatched == 0


@pytest.mark.parametrize("bad", ["13", (-1, 0, 1), (1.5,), (float("nan"),), 3])
def test_event_flow_metrics_checks_npe_thresholds_as_flow_metrics_does(bad):
    from evmotion.eval import event_flow_metrics, flow_metrics

    ev = {"t": np.array([1_000, 9_000]), "x": np.array([1.0, 2.5]), "y": np.array([1.0, 2.0]),
          "vx": np.array([100.0, 400.0]), "vy": np.zeros(2)}
    for call in (lambda: event_flow_metrics(ev, _gt(1), npe_thresholds=bad),
                 lambda: flow_metrics(np.zeros((2, 2, 2)), np.zeros((2, 2, 2)),
                                      npe_thresholds=bad)):
        with pytest.raises(ParameterError, match="npe_thresholds must be"):
            call()
    gt = _gt(1)
    gt.flow[..., 1] = 0.0  # errors 0 and 300 px/s: 0 and 3 px over the 10 ms window
    with pytest.warns(EvmotionWarning, match="no lower than the zero flow's"):
        m = event_flow_metrics(ev, gt, npe_thresholds=(1, 3.0))
    assert m.npe == {1: 50.0, 3: 0.0}


def test_warn_no_better_than_zero_and_unit_conversions_take_any_value():
    from evmotion.eval import warn_no_better_than_zero
    from evmotion.methods.kymogram import px_per_s_to_m_per_s

    assert warn_no_better_than_zero(10**30, 10**31, "x") is False  # a TypeError
    with pytest.raises(ParameterError, match="'v_px_s' must be a finite number, got 'abc'"):
        px_per_s_to_m_per_s("abc", 25, 1.7, 4.86)  # a bare ValueError


def test_transport_of_a_flow_no_image_holds_is_refused_not_run_for_ever():
    from evmotion.methods.transport import MAX_SUBSTEPS, transport_to_times

    v = np.full((2, 6, 8), 1e20)
    with pytest.raises(ParameterError, match=f"more than {MAX_SUBSTEPS:,} CFL sub-steps"):
        transport_to_times(v, np.array([-0.5]))
    assert transport_to_times(np.full((2, 6, 8), 4.0), np.array([-0.5])).flows[0].shape == \
        (2, 6, 8)


def test_eval_along_streamlines_names_the_window_it_cannot_transport():
    """The transport's refusal named no window of the file (probe EVAL, left alone then)."""
    from evmotion.eval.windows import evaluate_windows
    from evmotion.sim import simulate

    sim = simulate("translation", duration_s=0.02, sensor_size=(20, 24), show_progress=False)
    windows = sim.gt.flow_sequence([0, 10_000], [10_000, 20_000])
    flow = np.zeros((2, 20, 24, 2))
    flow[1] = 1e20
    with pytest.warns(EvmotionWarning, match="no lower than the zero flow"):
        assert evaluate_windows(flow[:1], [0], [10_000], windows,
                                along_streamlines=True).windows[0]["n_pixels"] > 0
    with pytest.raises(ParameterError, match=r"^window 1 \[10000, 20000\) us: transport: "):
        evaluate_windows(flow, [0, 10_000], [10_000, 20_000], windows, along_streamlines=True)


def write_flow(path, flow, t0, t1, valid, **attrs):
    from evmotion.io.flowfiles import FlowWriter

    with FlowWriter(path, flow.shape[1:3], with_valid=True, attrs=attrs) as fw:
        for i in range(len(flow)):
            fw.append(flow[i], t0=int(t0[i]), t1=int(t1[i]), valid=valid[i])


def _flow_file(path, **attrs):
    gt = _gt()
    write_flow(path, gt.flow, gt.t0, gt.t1, gt.valid)
    if attrs:
        with h5py.File(path, "a") as f:
            f.attrs.update(attrs)
    return gt


def test_eval_refuses_a_flow_file_whose_out_px_is_no_number(tmp_path, capsys):
    from evmotion.cli import main

    gt = _flow_file(tmp_path / "f.h5", eval_out_px="abc")  # a traceback
    write_flow(tmp_path / "gt.h5", gt.flow, gt.t0, gt.t1, gt.valid)
    assert main(["eval", str(tmp_path / "f.h5"), "--gt", str(tmp_path / "gt.h5")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "f.h5: attribute eval_out_px='abc' is not a number of " \
        "px > 0 (give the threshold with --out-px)" in err, err
    assert main(["eval", str(tmp_path / "f.h5"), "--gt", str(tmp_path / "gt.h5"),
                 "--out-px", "2"]) == 0


@pytest.mark.parametrize("content, said", [(b"", "the file is empty"),  # an EOFError
                                           (b"garbage", "not a zip archive (it begins with "
                                                        "b'garb')")])
def test_eval_of_an_empty_or_foreign_npz_is_one_line(tmp_path, capsys, content, said):
    from evmotion.cli import main

    bad = tmp_path / "f.npz"
    bad.write_bytes(content)
    gt = _gt()
    write_flow(tmp_path / "gt.h5", gt.flow, gt.t0, gt.t1, gt.valid)
    for argv in (["eval", str(bad), "--gt", str(tmp_path / "gt.h5")],
                 ["eval", str(tmp_path / "gt.h5"), "--gt", str(bad)]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"f.npz: cannot read as .npz: {said}" in err, err


def test_view_of_a_flow_near_float32_range_warns_nothing_foreign(tmp_path, capsys):
    from evmotion.cli import main

    gt = _gt()
    write_flow(tmp_path / "f.h5", np.full_like(gt.flow, 3e38), gt.t0, gt.t1, gt.valid)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # "overflow encountered in hypot"
        assert main(["view", str(tmp_path / "f.h5"), "--out", str(tmp_path / "v.png")]) == 0
    assert capsys.readouterr().err == ""


def test_view_of_a_flow_refuses_sensor_size_and_says_a_window_measured_nothing(tmp_path,
                                                                               capsys):
    from evmotion.cli import main

    gt = _gt()
    write_flow(tmp_path / "f.h5", gt.flow, gt.t0, gt.t1, np.zeros_like(gt.valid))
    out = str(tmp_path / "v.png")
    assert main(["view", str(tmp_path / "f.h5"), "--out", out, "--sensor-size", "10",
                 "10"]) == 2
    assert "--sensor-size 10 10 does not apply to" in capsys.readouterr().err
    assert main(["view", str(tmp_path / "f.h5"), "--out", out]) == 0
    assert capsys.readouterr().out.rstrip().endswith(": no valid pixel, no measurement")


def test_open_npz_names_the_file(tmp_path):
    from evmotion.io.guard import open_npz

    with pytest.raises(FormatError, match=r"x\.npz: cannot read as \.npz: the file is empty"):
        (tmp_path / "x.npz").write_bytes(b"")
        open_npz(tmp_path / "x.npz")


def test_fwl_says_when_its_events_leave_the_image_and_refuses_a_needle_vote():
    from evmotion.eval import fwl

    rng = np.random.default_rng(0)
    ev = EventArray(x=rng.integers(0, 8, 200), y=rng.integers(0, 6, 200),
                    t=np.sort(rng.integers(0, 10_000, 200)), p=np.ones(200, int),
                    sensor_size=(6, 8))
    with pytest.warns(EvmotionWarning, match=r"FWL: the flow warps 100 % of the 200 events "
                                             "off the image"):
        fwl(ev, np.full((6, 8, 2), 1e6), t_ref_us=5_000)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fwl(ev, np.full((6, 8, 2), 10.0), t_ref_us=5_000)
    with pytest.raises(ParameterError, match=r"sigma must be finite and >= 0.1 \(px\)"):
        fwl(ev, np.zeros((6, 8, 2)), kernel="gaussian", sigma=1e-30)
