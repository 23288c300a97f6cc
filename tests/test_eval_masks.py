"""evmotion eval's masks: ground truth with invalid pixels does not bias its valid
neighbours' displacement, and an estimate's own validity is honoured in every container."""

from __future__ import annotations

import json

import numpy as np
import pytest

from evmotion.cli import main
from evmotion.eval.windows import gt_displacement
from evmotion.io import open_flow_output, read_gt_flow

H, W = 20, 30


@pytest.fixture()
def gt_file(tmp_path):
    """Two GT frames of a uniform (130, 0) px/s translation, a 4 x 4 block invalid."""
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = 130.0
    valid = np.ones((H, W), bool)
    valid[8:12, 10:14] = False
    path = tmp_path / "gt.h5"
    with open_flow_output(path, (H, W), {"method": "gt"}) as o:
        o.append(flow, t0=0, t1=10_000, valid=valid)
        o.append(flow, t0=10_000, t1=20_000, valid=valid)
    return path, flow


@pytest.mark.parametrize("t1", [10_000, 15_000, 20_000])
def test_invalid_gt_pixels_do_not_leak_into_valid_ones(gt_file, tmp_path, capsys, t1):
    """The invalid block's unknown flow entered the bilinear sampling as zero: a window over
    1.5 frames gave valid pixels up to 0.5 px too little displacement, and a perfect
    estimate an AEE above zero."""
    path, flow = gt_file
    disp, ok, _ = gt_displacement(read_gt_flow(path), 0, t1)
    np.testing.assert_allclose(disp[ok], np.broadcast_to([130.0 * t1 * 1e-6, 0.0], disp[ok].shape),
                               atol=1e-9)
    assert ok.sum() > H * W // 2 and not ok[8:12, 10:14].any()
    est = tmp_path / "est.h5"
    with open_flow_output(est, (H, W), {"method": "perfect"}) as o:
        o.append(flow, t0=0, t1=t1)
    assert main(["eval", str(est), "--gt", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["mean"]["AEE"] == pytest.approx(0, abs=1e-9)


def test_the_estimate_own_validity_counts_in_every_container(gt_file, tmp_path, capsys):
    """An estimate claiming only its right half (zero flow, unclaimed, on the left) scored
    AEE 1 over every pixel from .h5/.npz and 0 over the claimed ones from .flo/.png."""
    path, flow = gt_file
    est = flow.copy()
    claimed = np.ones((H, W), bool)
    claimed[:, :15] = False
    est[:, :15] = 0.0
    scores = {}
    for name in ("e.h5", "e.npz", "e.flo", "e.png"):
        with open_flow_output(tmp_path / name, (H, W), {"method": "probe"}) as o:
            o.append(est, t0=0, t1=10_000, valid=claimed)
        assert main(["eval", str(tmp_path / name), "--gt", str(path), "--json"]) == 0
        m = json.loads(capsys.readouterr().out)["mean"]
        scores[name] = (round(m["AEE"], 6), m["n_pixels"])
    # the same pixels everywhere; the same error but for the PNG's 1/128 px steps
    assert {n for _, n in scores.values()} == {(claimed & ~_block()).sum()}, scores
    assert all(aee <= 1 / 256 for aee, _ in scores.values()), scores


def _block():
    b = np.zeros((H, W), bool)
    b[8:12, 10:14] = True
    return b


def test_windows_without_pixels_are_not_counted_as_scored(gt_file, tmp_path, capsys):
    """20 windows of which 2 had no valid pixel were reported as '20 windows' scored;
    half-frame windows against --dt 1 were not noted; an evmotion .npz is a reference too
    (it was read as MVSEC's), a .flo is refused as one in words."""
    path, flow = gt_file
    est = tmp_path / "est.h5"
    with open_flow_output(est, (H, W), {"method": "probe"}) as o:
        for k in range(4):
            valid = np.full((H, W), k != 3)
            o.append(flow, t0=k * 5000, t1=(k + 1) * 5000, valid=valid)
    assert main(["eval", str(est), "--gt", str(path), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["windows_scored"] == 3 and doc["windows_without_pixels"] == 1
    assert doc["windows_with_other_dt"] == 4  # half a GT frame each
    # the text says how many frames a window spans, and counts the scored windows as
    # the summary does (a warning had counted 7 where the summary said 6 of 7, probe BK)
    zero = np.zeros_like(flow)
    with open_flow_output(tmp_path / "zero.h5", (H, W), {"method": "probe"}) as o:
        for k in range(4):
            o.append(zero, t0=k * 5000, t1=(k + 1) * 5000, valid=np.full((H, W), k != 3))
    assert main(["eval", str(tmp_path / "zero.h5"), "--gt", str(path)]) == 0
    said = capsys.readouterr()
    assert "of GT frames other than --dt 1 (0.5 a window, median)" in said.out
    assert "the flow of 3 scored windows" in said.err and "3 of 4 windows scored" in said.out
    ref = tmp_path / "ref.npz"
    with open_flow_output(ref, (H, W), {"method": "gt"}) as o:
        o.append(flow, t0=0, t1=10_000)
        o.append(flow, t0=10_000, t1=20_000)
    assert main(["eval", str(est), "--gt", str(ref), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["windows_scored"] == 3
    flo = tmp_path / "g.flo"
    with open_flow_output(flo, (H, W), {"method": "gt"}) as o:
        o.append(flow, t0=0, t1=10_000)
    assert main(["eval", str(est), "--gt", str(flo)]) == 2
    assert "is not read as ground truth" in capsys.readouterr().err


def test_simulator_event_masks_are_united_over_the_frames_a_window_spans(tmp_path):
    # probe AN: the simulator's per-frame event masks were intersected along the
    # trajectories like GT validity: a window of several GT frames kept only the pixels
    # with events in every frame (3.6 %), not those with events in the window
    from evmotion.eval.metrics import event_mask
    from evmotion.sim import simulate
    from evmotion.sim.gtio import write_ground_truth

    sim = simulate("translation", duration_s=0.05, sensor_size=(60, 80), seed=1,
                   show_progress=False)
    gt = read_gt_flow(write_ground_truth(tmp_path / "sim_gt.h5", sim.gt))
    assert gt.attrs["valid_is_event_mask"] and gt.valid is not None
    t0, t1 = int(gt.t0[1]), int(gt.t1[3])  # three GT frames
    disp, valid, frames = gt_displacement(gt, t0, t1)
    assert frames == pytest.approx(3.0)
    fired = event_mask(sim.events.slice_time(t0, t1), (60, 80))
    union = gt.valid[1] | gt.valid[2] | gt.valid[3]
    np.testing.assert_array_equal(union, fired)
    # valid: where events fired and the point stays in the image (checked before each
    # frame's step: the last step may leave it)
    ys, xs = np.mgrid[0:60, 0:80]
    ex, ey = xs + disp[..., 0], ys + disp[..., 1]
    stays = (ex >= 0) & (ex <= 79) & (ey >= 0) & (ey <= 59)
    assert not (valid & ~fired).any() and not (fired & stays & ~valid).any()
    assert valid.sum() > 2 * (gt.valid[1] & gt.valid[2] & gt.valid[3]).sum()


def test_simulator_ground_truth_of_another_dtype_or_shape_is_refused(tmp_path):
    # probe AQ: an int8 or bool GT flow was scored as px/s (AEE 1.43 for 0.66), exit 0
    import h5py

    from evmotion.errors import FormatError
    from evmotion.sim import simulate
    from evmotion.sim.gtio import write_ground_truth

    sim = simulate("translation", duration_s=0.03, sensor_size=(30, 40), seed=1,
                   show_progress=False)
    path = write_ground_truth(tmp_path / "sim_gt.h5", sim.gt)
    assert read_gt_flow(path).flow.dtype == np.float32
    with h5py.File(path, "a") as f:
        flow = f["flow"][()]
        del f["flow"]
        f["flow"] = flow.astype(np.int8)
    with pytest.raises(FormatError, match=r"'flow' is int8 .* expected float"):
        read_gt_flow(path)


def test_fwl_of_the_ground_truth_leaves_out_where_it_is_unknown():
    """Probe BI: FWL_gt took the ground truth's unknown pixels (NaN, the right half) for
    a still scene: 4.15 against the estimate's 7.30 where the two flows are one wherever
    the truth is known. Both FWLs now read the events where both are defined."""
    from evmotion.eval.windows import evaluate_windows
    from evmotion.events import EventArray
    from evmotion.io.flowfiles import FlowSequence

    rng = np.random.default_rng(0)
    n, h, w = 20_000, 40, 60
    dots = rng.uniform([0, 0], [w - 10, h], (400, 2))
    k = rng.integers(0, 400, n)
    t = np.sort(rng.integers(0, 50_000, n))
    ev = EventArray(np.floor(dots[k, 0] + 100e-6 * t).astype(int),
                    np.floor(dots[k, 1]).astype(int), t, np.ones(n, int), (h, w))
    est = np.zeros((1, h, w, 2), np.float32)
    est[..., 0] = 100.0
    gt = est.copy()
    gt[:, :, w // 2:] = np.nan
    res = evaluate_windows(est, [0], [50_000],
                           FlowSequence(gt, np.array([0]), np.array([50_000])), events=ev)
    row = res.windows[0]
    assert row["FWL_gt"] == pytest.approx(row["FWL"]) and row["FWL"] > 1.5


def test_ground_truth_windows_that_overlap_are_refused_and_empty_windows_skipped():
    """Probe BI: a ground truth of 50 ms windows every 25 ms had its displacement summed
    over both windows holding an instant (AEE 5 px for an exact estimate, coverage 2.0
    passing the test); and one window of no time (t1 == t0, which flow outputs keep
    without a valid pixel) made eval refuse the whole output ('t0s and t1s swapped?')."""
    from evmotion.errors import ParameterError
    from evmotion.eval.windows import evaluate_windows
    from evmotion.io.flowfiles import FlowSequence

    flow = np.full((2, 8, 10, 2), 100.0, np.float32)
    sliding = FlowSequence(flow, np.array([0, 25_000]), np.array([50_000, 75_000]))
    with pytest.raises(ParameterError, match=r"windows overlap: \[25000, 75000\) us starts "
                                             r"before \[0, 50000\) us ends"):
        evaluate_windows(flow[:1], [25_000], [50_000], sliding)
    tiles = FlowSequence(flow, np.array([0, 50_000]), np.array([50_000, 100_000]))
    res = evaluate_windows(flow, [0, 50_000], [50_000, 50_000], tiles)
    assert res.windows[1] == {"window": 1, "t0_us": 50_000, "t1_us": 50_000, "n_pixels": 0}
    assert res.total["AEE"] == pytest.approx(0.0) and res.windows[0]["n_pixels"] == 80
    with pytest.raises(ParameterError, match=r"window 0: \[5, 4\] us .*swapped"):
        evaluate_windows(flow[:1], [5], [4], tiles)


def test_a_gap_in_the_ground_truth_is_named():
    """Probe BI: a window inside the ground truth's span but over a gap of it (90 %
    covered) was refused with 'no window lies within the ground truth's'."""
    from evmotion.errors import EmptyWindowError
    from evmotion.eval.windows import evaluate_windows
    from evmotion.io.flowfiles import FlowSequence

    flow = np.zeros((2, 8, 10, 2), np.float32)
    gapped = FlowSequence(flow, np.array([0, 60_000]), np.array([50_000, 110_000]))
    with pytest.raises(EmptyWindowError, match=r"the ground truth has gaps: .* \[0, "
                                               r"100000\) us, 90%"):
        evaluate_windows(flow[:1], [0], [100_000], gapped)


def test_events_in_text_take_the_sensor_size_and_time_unit_given(gt_file, tmp_path, capsys):
    """--events in text stating no sensor size was read at its largest coordinates, and
    the warning's advice, --sensor-size, was no eval option (probe BK)."""
    path, flow = gt_file
    est = tmp_path / "est.h5"
    with open_flow_output(est, (H, W), {"method": "x"}) as o:
        o.append(flow, t0=0, t1=20_000)
    rng = np.random.default_rng(0)
    n = 400
    t_ms = np.sort(rng.uniform(0, 20, n))  # decimal milliseconds
    x, y = rng.integers(0, W - 3, n), rng.integers(0, H - 2, n)  # short of the sensor's edge
    text = tmp_path / "ev.txt"
    text.write_text("".join(f"{t:.4f} {a} {b} 1\n" for t, a, b in zip(t_ms, x, y,
                                                                     strict=True)))
    argv = ["eval", str(est), "--gt", str(path), "--events", str(text), "--json"]
    assert main(argv) == 2
    assert "--sensor-size" in capsys.readouterr().err
    assert main(argv + ["--sensor-size", str(H), str(W), "--time-unit", "ms"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["mean"]["AEE"] < 1e-6 and doc["windows_scored"] == 1
    # without --events they read nothing: refused, not ignored
    assert main(["eval", str(est), "--gt", str(path), "--sensor-size", str(H), str(W)]) == 2
    assert "does not apply without --events" in capsys.readouterr().err


def test_the_dense_scores_carry_their_units(tmp_path, capsys):
    # "AEE=0.2146" said no unit, where the per-event score says px and px/s (probe CE)
    import json

    from evmotion.cli import main

    rec = tmp_path / "tr.h5"
    assert main(["simulate", "translation", "--duration", "0.03", "--sensor-size", "40", "50",
                 "--out", str(rec)]) == 0
    assert main(["flow", str(rec), "--window-events", "3000", "--out",
                 str(tmp_path / "f.h5")]) == 0
    capsys.readouterr()
    gt = tmp_path / "tr_gt.h5"
    assert main(["eval", str(tmp_path / "f.h5"), "--gt", str(gt)]) == 0
    line = capsys.readouterr().out.splitlines()[1]
    assert " px  AEE_zero=" in line and " %  AE_deg=" in line and " deg  n_pixels=" in line
    assert main(["eval", str(tmp_path / "f.h5"), "--gt", str(gt), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["units"]["AEE"] == "px over the window"
