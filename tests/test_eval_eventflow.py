"""Accuracy of per-event flow (:func:`evmotion.eval.eventflow.event_flow_metrics`) and
``evmotion eval`` on per-event flow files: exact values on synthetic files, the triplet
matcher on a simulated translation end to end, one-line errors for bad inputs."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import evmotion.io as eio
import evmotion.sim as sim
from evmotion.cli import main
from evmotion.errors import EmptyWindowError, EventDataError, ParameterError
from evmotion.eval import event_flow_metrics
from evmotion.io.eventflow import EventFlowWriter, read_event_flow
from evmotion.io.flowfiles import FlowSequence, FlowWriter, read_gt_flow

H, W = 30, 40
# GT windows of different durations (µs), a gap [30_000, 40_000) and out of time order
T0 = np.array([10_000, 0, 40_000])
T1 = np.array([30_000, 10_000, 45_000])


def gt_flow(j: int, x, y) -> np.ndarray:
    """Ground truth of window j at (x, y) in px/s: affine in x and y (so that bilinear
    interpolation is exact) and different in every window."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    return np.stack([100.0 * (j + 1) + 3.0 * x - 2.0 * y, -50.0 * j + 1.5 * y + 0.5 * x],
                    axis=-1)


def make_gt() -> FlowSequence:
    yy, xx = np.mgrid[0:H, 0:W]
    flow = np.stack([gt_flow(j, xx, yy) for j in range(T0.size)]).astype(np.float32)
    return FlowSequence(flow=flow, t0=T0.copy(), t1=T1.copy(), valid=np.ones((3, H, W), bool))


def make_events(n: int = 3000, seed: int = 0) -> dict:
    """Events inside the GT windows at sub-pixel positions, with the exact GT flow."""
    rng = np.random.default_rng(seed)
    t = np.sort(np.concatenate([rng.integers(0, 30_000, n - n // 5),
                                rng.integers(40_000, 45_000, n // 5)]))
    x = rng.uniform(0, W - 1, n)
    y = rng.uniform(0, H - 1, n)
    j = np.where(t < 10_000, 1, np.where(t < 30_000, 0, 2))
    v = np.array([gt_flow(int(jj), xx, yy) for jj, xx, yy in zip(j, x, y, strict=True)])
    return {"t": t, "x": x, "y": y, "p": rng.integers(0, 2, n), "vx": v[:, 0],
            "vy": v[:, 1], "nx": v[:, 0] / 2, "ny": v[:, 1] / 2, "valid": rng.random(n) < 0.8,
            "n_triplets": np.full(n, 3), "window": j}


def write(path, ev, size=(H, W)):
    with EventFlowWriter(path, size, attrs={"method": "test"}) as w:
        w.append(**{k: v for k, v in ev.items() if k != "window"})
    return path


def write_gt(path, gt: FlowSequence):
    with FlowWriter(path, gt.flow.shape[1:3], with_valid=True) as fw:
        for i in np.argsort(gt.t0):
            fw.append(gt.flow[i], t0=int(gt.t0[i]), t1=int(gt.t1[i]), valid=gt.valid[i])
    return path


def eval_json(argv, capsys) -> dict:
    assert main(["eval", *map(str, argv), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


# --------------------------------------------------------------- exact values, library
def test_exact_flow_scores_zero_and_an_offset_scores_exactly_itself():
    gt, ev = make_gt(), make_events()
    m = event_flow_metrics(ev, gt, per_window=True)
    valid = ev["valid"]
    assert m.n_events == len(ev["t"]) and m.n_scored == valid.sum() and m.n_no_gt == 0
    assert m.n_no_flow == (~valid).sum()
    assert m.aee < 1e-4 and m.aee_px_s < 1e-2 and m.pct_out == 0.0 and m.ae_deg < 1e-2

    # 60 px/s: 1.2 px over 20 ms, 0.6 px over 10 ms, 0.3 px over 5 ms (x4 with frames=4)
    shifted = {**ev, "vx": ev["vx"] + 36.0, "vy": ev["vy"] - 48.0}
    for frames in (1, 4):
        m = event_flow_metrics(shifted, gt, frames=frames, per_window=True)
        dur = np.array([20_000, 10_000, 5_000])[ev["window"][valid]] * 1e-6 * frames
        np.testing.assert_allclose(m.aee_px_s, 60.0, atol=1e-3)
        np.testing.assert_allclose(m.aee, np.mean(60.0 * dur), rtol=1e-6)
        assert m.pct_out == pytest.approx(100.0 * np.mean(60.0 * dur > 3.0))
        assert m.npe[1] == pytest.approx(100.0 * np.mean(60.0 * dur > 1.0))
        assert 0 < m.pct_out < 100 if frames == 4 else m.pct_out == 0
        rows = {r["window"]: r for r in m.windows}
        assert sorted(rows) == [0, 1, 2]
        for j, seconds in ((0, 0.02), (1, 0.01), (2, 0.005)):
            r = rows[j]
            assert (r["t0_us"], r["t1_us"]) == (T0[j], T1[j])
            assert r["n_events"] == np.sum(valid & (ev["window"] == j))
            assert r["AEE"] == pytest.approx(60.0 * seconds * frames, rel=1e-6)
            assert r["AEE_px_s"] == pytest.approx(60.0, abs=1e-3)


def test_events_without_ground_truth_are_counted_not_scored():
    gt, ev = make_gt(), make_events(300)
    ev["valid"][:] = True
    # none near the pixel made invalid below (interpolating beside it is not exact)
    far = (np.abs(ev["x"] - 20) > 1.5) | (np.abs(ev["y"] - 10) > 1.5)
    ev = {k: v[far] for k, v in ev.items()}
    n = len(ev["t"])
    # in the gap between windows, after the last one, off the grid, on an invalid GT pixel
    ev["t"][:3] = [35_000, 45_000, 99_000]
    ev["x"][3], ev["y"][4] = W - 0.9, -0.2
    gt.valid[:, 10, 20] = False
    ev["x"][5], ev["y"][5] = 20.3, 9.6  # nearest pixel (20, 10)
    order = np.argsort(ev["t"], kind="stable")
    ev = {k: v[order] for k, v in ev.items()}
    m = event_flow_metrics(ev, gt)
    assert (m.n_scored, m.n_no_gt, m.n_no_flow) == (n - 6, 6, 0)
    assert m.aee < 1e-4


def test_invalid_neighbours_do_not_pull_the_ground_truth_to_zero():
    """MVSEC marks pixels without depth invalid with a zero flow: an event beside one gets
    the valid pixels' interpolation, not a mix with the zero."""
    flow = np.zeros((1, 4, 4, 2), np.float32)
    flow[0, :, :2] = (100.0, 0.0)
    valid = np.zeros((1, 4, 4), bool)
    valid[0, :, :2] = True
    gt = FlowSequence(flow=flow, t0=np.array([0]), t1=np.array([10_000]), valid=valid)
    ev = {"t": np.array([5]), "x": np.array([1.4]), "y": np.array([1.0]),
          "vx": np.array([100.0]), "vy": np.array([0.0])}
    assert event_flow_metrics(ev, gt).aee_px_s == pytest.approx(0.0, abs=1e-9)


def test_library_refuses_bad_input():
    gt, ev = make_gt(), make_events(50)
    with pytest.raises(EmptyWindowError, match="no events"):
        event_flow_metrics({k: v[:0] for k, v in ev.items()}, gt)
    late = {**ev, "t": ev["t"] + 1_000_000}
    with pytest.raises(EmptyWindowError, match=r"t = 1000\d+\.\.10\d+ µs.*t = 0\.\.45000 µs"):
        event_flow_metrics(late, gt)
    with pytest.raises(ParameterError, match="one length"):
        event_flow_metrics({**ev, "vx": ev["vx"][:-1]}, gt)
    bad = {**ev, "vx": ev["vx"].copy()}
    bad["vx"][np.flatnonzero(ev["valid"])[0]] = np.nan
    with pytest.raises(ParameterError, match="1 events marked valid have a NaN"):
        event_flow_metrics(bad, gt)
    with pytest.raises(ParameterError, match="frames"):
        event_flow_metrics(ev, gt, frames=0)
    # seconds for µs were floored to 0 and scored against the first window
    with pytest.raises(EventDataError, match="field 't' has fractional values"):
        event_flow_metrics({**ev, "t": ev["t"] * 1e-6 + 1e-3}, gt)


# ------------------------------------------------------------------------- the CLI
@pytest.mark.parametrize("suffix", [".h5", ".npz"])
def test_cli_scores_a_per_event_file(tmp_path, capsys, suffix):
    gt = write_gt(tmp_path / "gt.h5", make_gt())
    ev = make_events()
    exact = write(tmp_path / f"exact{suffix}", ev)
    res = eval_json([exact, "--gt", gt], capsys)
    assert res["kind"] == "per-event" and res["n_windows"] == 3
    assert {"AEE", "AEE_px_s", "%Out", "AE_deg", "AE_rad"} <= set(res["units"])  # probe CI
    assert res["mean"]["AEE"] < 1e-4 and res["mean"]["%Out"] == 0.0
    assert res["mean"]["n_scored"] == ev["valid"].sum()
    # the zero flow's AEE beside it: each scored event's GT displacement over its window
    ok = ev["valid"]
    dur = (T1 - T0)[ev["window"][ok]] * 1e-6
    want = np.mean(np.hypot(ev["vx"][ok], ev["vy"][ok]) * dur)
    assert res["mean"]["AEE_zero"] == pytest.approx(want, rel=1e-4)
    assert res["mean"]["valid_fraction"] == pytest.approx(ev["valid"].mean())
    # 200 px/s: 4 px over the 20 ms window, 2 px and 1 px over the others
    shifted = write(tmp_path / f"off{suffix}", {**ev, "vx": ev["vx"] + 200.0})
    res = eval_json([shifted, "--gt", gt], capsys)
    in_long = ev["window"][ev["valid"]] == 0
    assert res["mean"]["AEE_px_s"] == pytest.approx(200.0, abs=1e-2)
    assert res["mean"]["%Out"] == pytest.approx(100.0 * in_long.mean())
    res = eval_json([shifted, "--gt", gt, "--out-px", "1.5"], capsys)
    assert res["mean"]["%Out"] == pytest.approx(100.0 * np.mean(
        ev["window"][ev["valid"]] != 2))
    res = eval_json([shifted, "--gt", gt, "--dt", "4"], capsys)
    assert res["mean"]["%Out"] == pytest.approx(100.0)  # 4, 8 and 16 px
    assert main(["eval", str(shifted), "--gt", str(gt)]) == 0
    line = capsys.readouterr().out.strip()
    assert "\n" not in line and f"{ev['valid'].sum()} of {len(ev['t'])} events" in line
    assert " %Out=" in line and re.search(r"%Out=[\d.e+-]+ % ", line), line  # (as dense)


def test_triplet_on_a_simulated_translation_end_to_end(tmp_path, capsys):
    """The triplet CLI's per-event output of a simulated translation, scored against the
    simulator's ground truth, is far better than zero flow; the events after the last GT
    frame are counted as without ground truth."""
    res = sim.simulate("translation", duration_s=0.12, sensor_size=(48, 64), seed=0,
                       params={"vx": 200.0, "vy": 0.0}, frame_rate=45.0, threshold=0.5,
                       texture="checker", show_progress=False)
    rec, gt_path = tmp_path / "s.h5", tmp_path / "s_gt.h5"
    eio.write_events(rec, res.events)
    sim.write_ground_truth(gt_path, res.gt)
    out = tmp_path / "tri.h5"
    assert main(["flow", str(rec), "--method", "triplet", "--out", str(out)]) == 0
    capsys.readouterr()
    got = eval_json([out, "--gt", gt_path], capsys)["mean"]
    ef, gt = read_event_flow(out), read_gt_flow(gt_path)
    zero = {k: ef[k] for k in ("t", "x", "y", "valid")}
    zero.update(vx=np.zeros(len(ef)), vy=np.zeros(len(ef)))
    ref = event_flow_metrics(zero, gt)
    assert ref.aee > 4.0  # 200 px/s over 22.2 ms frame intervals: 4.44 px
    assert np.isfinite(got["AEE"]) and got["AEE"] < 0.25 * ref.aee
    assert got["%Out"] < 2.0 and got["n_scored"] > 1000
    # every event with a flow lies on its frame interval's event mask: no GT only after
    # the last GT frame
    assert got["n_no_gt"] == np.count_nonzero(ef["valid"] & (ef["t"] >= gt.t1.max()))
    assert got["AEE"] == pytest.approx(got["AEE_px_s"] * 0.022222, rel=1e-4)


def test_cli_bad_inputs_are_one_line(tmp_path, capsys):
    gt = make_gt()
    gt_file = write_gt(tmp_path / "gt.h5", gt)
    ev = make_events(100)
    flow = write(tmp_path / "ev.h5", ev)

    def fails(argv, *needles):
        assert main(["eval", *map(str, argv)]) == 2
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "Traceback" not in err, err
        for n in needles:
            assert n in err, (n, err)

    late = FlowSequence(gt.flow, gt.t0 + 10_000_000, gt.t1 + 10_000_000, gt.valid)
    late_file = write_gt(tmp_path / "late.h5", late)
    fails([flow, "--gt", late_file], "ev.h5", "late.h5", f"t = {ev['t'].min()}..",
          "10000000..10045000 µs")
    fails([write(tmp_path / "empty.h5", {k: v[:0] for k, v in ev.items()}), "--gt", gt_file],
          "empty.h5", "events=0")
    fails([write(tmp_path / "big.h5", ev, size=(H + 1, W)), "--gt", gt_file],
          "big.h5", "(31, 40)", "(30, 40)")
    fails([flow, "--gt", gt_file, "--events", flow], "--events", "does not apply", "ev.h5")
    fails([flow, "--gt", gt_file, "--along-streamlines"], "--along-streamlines")
    fails([flow, "--gt", gt_file, "--t0-us", "0"], "--t0-us")
    fails([flow, "--gt", flow], "ground truth itself")


def test_scoring_in_chunks_gives_the_numbers_of_one_pass(monkeypatch):
    # 15 M events took 5.2 GB in one pass; the chunked sums must not change a digit
    import evmotion.eval.eventflow as mod
    from evmotion.io.flowfiles import FlowSequence

    rng = np.random.default_rng(4)
    gt = FlowSequence(flow=rng.normal(0, 50, (3, 12, 16, 2)).astype(np.float32),
                      t0=np.array([0, 10_000, 20_000]), t1=np.array([10_000, 20_000, 30_000]),
                      valid=rng.random((3, 12, 16)) > 0.2)
    n = 5000
    ev = {"t": np.sort(rng.integers(-2000, 32_000, n)), "x": rng.uniform(-1, 16, n),
          "y": rng.uniform(0, 11, n), "vx": rng.normal(0, 60, n), "vy": rng.normal(0, 60, n),
          "valid": rng.random(n) > 0.1}
    whole = mod.event_flow_metrics(ev, gt, per_window=True)
    monkeypatch.setattr(mod, "EVAL_CHUNK", 37)
    parts = mod.event_flow_metrics(ev, gt, per_window=True)
    assert parts.n_scored == whole.n_scored and parts.n_no_gt == whole.n_no_gt
    for key in ("aee", "aee_px_s", "pct_out", "ae_deg"):
        assert getattr(parts, key) == pytest.approx(getattr(whole, key), rel=1e-12)
    assert parts.npe == pytest.approx(whole.npe, rel=1e-12)
    assert [r["n_events"] for r in parts.windows] == [r["n_events"] for r in whole.windows]
    assert [r["AEE"] for r in parts.windows] == pytest.approx([r["AEE"] for r in whole.windows])
