"""BOS outputs through the shared flow output layer: extras (q, p, per-window numbers)
round trip in .h5 and .npz, `evmotion bos --out` in every container read back by
read_flow / info / eval with no BOS-specific code, and files of the layout before."""

import json

import numpy as np
import pytest

from bos_synth import plume_scene, run_cli
from evmotion.cli import main
from evmotion.errors import FormatError, ParameterError
from evmotion.io.bosfiles import read_bos, read_bos_h5
from evmotion.io.flowfiles import ExtraSpec, FlowWriter
from evmotion.io.flowout import open_flow_output
from evmotion.io.flowread import describe_flow, read_flow


def _extras(h=4, w=5):
    return {"q": ExtraSpec((h, w), units="px^2/s", meaning="Poisson field"),
            "p": ExtraSpec((h, w, 2), units="px"),
            "window/loss": ExtraSpec((), "<f8", units="")}


@pytest.mark.parametrize("name", ["x.h5", "x.npz"])
def test_extras_round_trip(tmp_path, name):
    rng = np.random.default_rng(0)
    path = tmp_path / name
    wins = [(rng.normal(size=(4, 5, 2)).astype(np.float32), rng.normal(size=(4, 5)),
             rng.normal(size=(4, 5, 2)), rng.random((4, 5)) > 0.3) for _ in range(3)]
    with open_flow_output(path, (4, 5), {"method": "m"}, extras=_extras()) as out:
        for i, (v, q, p, ok) in enumerate(wins):
            out.append(v, 100 * i, 100 * i + 50, valid=ok,
                       extras={"q": q, "p": p, "window/loss": 0.25 * i})
    seq = read_flow(path)
    np.testing.assert_array_equal(seq.t0, [0, 100, 200])
    np.testing.assert_array_equal(seq.t1, [50, 150, 250])
    for i, (v, q, p, ok) in enumerate(wins):
        np.testing.assert_array_equal(seq.flow[i], v)
        np.testing.assert_array_equal(seq.valid[i], ok)
        np.testing.assert_array_equal(seq.extras["q"][i], q.astype(np.float32))
        np.testing.assert_array_equal(seq.extras["p"][i], p.astype(np.float32))
    np.testing.assert_array_equal(seq.extras["window/loss"], [0.0, 0.25, 0.5])
    assert seq.extras["window/loss"].dtype == np.float64
    assert seq.attrs["extras_units"] == {"q": "px^2/s", "p": "px", "window/loss": ""}
    info = describe_flow(path)
    assert info["windows"] == 3 and info["units"] == "px/s"
    assert info["extras"] == {"q": "px^2/s", "p": "px", "window/loss": "-"}


def test_extras_checked_and_refused_per_window(tmp_path):
    with pytest.raises(ParameterError, match="holds the flow only"):
        open_flow_output(tmp_path / "f_{:05d}.flo", (4, 5), extras=_extras())
    out = open_flow_output(tmp_path / "a.h5", (4, 5), extras=_extras())
    z = np.zeros((4, 5, 2), np.float32)
    with pytest.raises(ParameterError, match=r"missing \['window/loss'\]"):
        out.append(z, 0, 1, extras={"q": z[..., 0], "p": z})
    with pytest.raises(ParameterError, match="extra 'q' has shape"):
        out.append(z, 0, 1, extras={"q": z, "p": z, "window/loss": 1.0})
    out.abort()


def test_resume_trims_extras_of_an_unfinished_window(tmp_path):
    path = tmp_path / "r.h5"
    z = np.zeros((4, 5, 2), np.float32)
    w = FlowWriter(path, (4, 5), with_valid=True, extras=_extras())
    w.append(z, 0, 10, extras={"q": z[..., 0] + 1, "p": z, "window/loss": 1.0})
    w.f["q"].resize(2, axis=0)  # a crash after q of window 1, before its t1
    w.f["window/loss"].resize(2, axis=0)
    w.abort()
    out = open_flow_output(path, (4, 5), resume=True, extras=_extras())
    assert out.done == [(0, 10)] and out.w.f["q"].shape[0] == 1
    out.append(z, 10, 20, extras={"q": z[..., 0] + 2, "p": z, "window/loss": 2.0})
    out.close()
    seq = read_flow(path)
    np.testing.assert_array_equal(seq.extras["q"][:, 0, 0], [1, 2])
    np.testing.assert_array_equal(seq.extras["window/loss"], [1, 2])
    with pytest.raises(FormatError, match="extra datasets"):
        FlowWriter(path, (4, 5), resume=True, extras={})


def test_file_of_the_layout_before_is_read(tmp_path):
    # a BOS file as BosWriter wrote it before the extras attribute: q, p, window/*
    path = tmp_path / "old.h5"
    rng = np.random.default_rng(3)
    q = rng.normal(size=(2, 4, 5)).astype(np.float32)
    with FlowWriter(path, (4, 5), with_valid=True,
                    attrs={"content": "evmotion-bos", "roi": [0, 0, 5, 4]}) as fw:
        for i in range(2):
            fw.append(np.zeros((4, 5, 2)), 10 * i, 10 * i + 10)
        fw.f["q"] = q
        fw.f["q"].attrs["units"] = "px^2/s"
        fw.f["p"] = np.zeros((2, 4, 5, 2), np.float32)
        fw.f["window/loss"] = np.array([1.0, 2.0])
    seq = read_flow(path)
    np.testing.assert_array_equal(seq.extras["q"], q)
    assert sorted(seq.extras) == ["p", "q", "window/loss"]
    assert seq.attrs["eval_out_px"] == 1.0  # eval's threshold for these files, as before
    for bos in (read_bos_h5(path), read_bos(path)):
        np.testing.assert_array_equal(bos.q, q)
        np.testing.assert_array_equal(bos.scalars["loss"], [1.0, 2.0])
        assert bos.attrs["q_units"] == "px^2/s"


# ---------------------------------------------------------------------------- CLI
@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return plume_scene(tmp_path_factory.mktemp("bosout") / "plume")


_run = run_cli


BOS_ARGS = ["--roi", 4, 8, 32, 32, "--iterations", 10, "--contrast-threshold", 0.2]


@pytest.fixture(scope="module")
def bos_h5(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("bosh5") / "bos.h5"
    assert main([str(a) for a in ["bos", scene, *BOS_ARGS, "--out", out]]) == 0
    return out


def _support(events, t0, t1, shape):
    """numpy reference: >= 2 events in the 5x5 square around the pixel."""
    win = events.slice_time(int(t0), int(t1))
    cnt = np.zeros(shape)
    np.add.at(cnt, (win.y, win.x), 1)
    pad = np.pad(cnt, 2)
    box = sum(pad[dy:dy + shape[0], dx:dx + shape[1]] for dy in range(5) for dx in range(5))
    return box >= 2


def test_bos_h5_is_a_regular_flow_file(scene, bos_h5):
    from evmotion.io import read_events

    seq = read_flow(bos_h5)
    bos = read_bos_h5(bos_h5)
    assert seq.flow.shape == (2, 48, 40, 2) and seq.attrs["units"] == "px/s"
    assert seq.attrs["grid"] == "sensor" and seq.attrs["method"] == "bos"
    np.testing.assert_array_equal(seq.t0, [0, 8333])
    np.testing.assert_array_equal(seq.t1, bos.flow.t1)
    roi = np.zeros((48, 40), bool)
    roi[8:40, 4:36] = True
    events = read_events(scene)
    for i in range(2):
        want = _support(events, seq.t0[i], seq.t1[i], (48, 40)) & roi
        np.testing.assert_array_equal(seq.valid[i], want)
        assert 0 < want.sum() < roi.sum()
        assert np.isfinite(seq.flow[i][roi]).all() and np.isnan(seq.flow[i][~roi]).all()
    np.testing.assert_array_equal(seq.extras["q"], bos.q)
    np.testing.assert_array_equal(seq.extras["p"], bos.p)
    assert seq.attrs["extras_units"]["q"] == "px^2/s" and seq.attrs["extras_units"]["p"] == "px"
    np.testing.assert_array_equal(seq.extras["window/n_events"], bos.scalars["n_events"])
    assert bos.scalars["contrast_threshold"].tolist() == [0.2, 0.2]


def test_info_and_eval_on_a_bos_output(scene, bos_h5, capsys):
    rc, text, err = _run(["info", bos_h5, "--json"], capsys)
    assert rc == 0, err
    info = json.loads(text)
    assert info["format"] == "evmotion-flow" and info["windows"] == 2
    assert info["units"] == "px/s" and info["method"] == "bos" and info["grid"] == "sensor"
    assert info["extras"]["q"] == "px^2/s" and 0 < info["valid_fraction"] < 32 * 32 / 48 / 40
    rc, text, err = _run(["eval", bos_h5, "--gt", scene / "schlieren_gt.h5", "--json"], capsys)
    assert rc == 0, err
    summary = json.loads(text)
    # the file's eval_out_px (1 px), and the pixels the estimate claims (the ROI's with
    # event support), as a .flo of the same estimate (its other pixels unknown) is scored
    valid = read_flow(bos_h5).valid
    assert summary["out_px"] == 1.0
    assert summary["mean"]["n_pixels"] == valid.sum() < 2 * 32 * 32


def test_bos_other_containers(scene, bos_h5, tmp_path, capsys):
    ref = read_flow(bos_h5)
    npz = tmp_path / "bos.npz"
    rc, _, err = _run(["bos", scene, *BOS_ARGS, "--out", npz], capsys)
    assert rc == 0, err
    seq = read_flow(npz)
    np.testing.assert_array_equal(seq.flow, ref.flow)
    np.testing.assert_array_equal(seq.valid, ref.valid)
    np.testing.assert_array_equal(seq.extras["q"], ref.extras["q"])
    np.testing.assert_array_equal(read_bos(npz).p, read_bos_h5(bos_h5).p)
    for source, label in (("q", "q"), ("flow", "|flow| px/s")):  # kymogram reads .npz too
        rc, text, err = _run(["kymogram", npz, "--from", source, "--col", 20, "--no-fit",
                              "--out", tmp_path / f"k_{source}.png", "--json"], capsys)
        assert rc == 0, err
        assert json.loads(text)["panels"][0]["source"] == label
    flo = tmp_path / "bos_{:05d}.flo"
    rc, _, err = _run(["bos", scene, *BOS_ARGS, "--out", flo], capsys)
    assert rc == 0, err
    seq = read_flow(flo)
    np.testing.assert_array_equal(seq.t0, ref.t0)
    np.testing.assert_array_equal(seq.valid, ref.valid)  # unknown where not valid
    np.testing.assert_allclose(seq.flow[ref.valid], ref.flow[ref.valid], rtol=1e-5)
    assert seq.extras == {}
    with pytest.raises(FormatError, match="holds the flow only|no 'q'"):
        read_bos(flo)
    side = json.loads((tmp_path / "bos_00001.flo.json").read_text())
    assert side["t0_us"] == 8333 and side["units"] == "px"
    png = tmp_path / "bos_{:05d}.png"
    rc, _, err = _run(["bos", scene, *BOS_ARGS, "--out", png], capsys)
    assert rc == 0, err
    seq = read_flow(png)
    dt = (ref.t1 - ref.t0)[:, None, None, None] * 1e-6
    np.testing.assert_array_equal(seq.valid, ref.valid)
    np.testing.assert_allclose((seq.flow * dt)[ref.valid], (ref.flow * dt)[ref.valid],
                               atol=0.5 / 128 + 1e-4)  # 1/128 px steps, float32 product
    rc, text, err = _run(["eval", png, "--gt", scene / "schlieren_gt.h5", "--json"], capsys)
    assert rc == 0, err
    assert json.loads(text)["out_px"] == 1.0


def test_eval_q_checks_the_ground_truth_and_means_the_scored_windows(tmp_path, capsys):
    """Probe AQ: a schlieren GT whose frame_t had another length scored other intervals
    (q_corr 0.606 -> 0.523, exit 0) or was an IndexError traceback; the q means took in
    the start-up window, which bos writes with no valid pixel (q_std_ratio 0.389)."""
    import json

    import h5py

    from bos_synth import plume_scene, run_cli

    scene = plume_scene(tmp_path / "plume", intervals=3)
    out = tmp_path / "bos.h5"
    assert run_cli(["bos", scene, "--iterations", 20, "--out", out], capsys)[0] == 0
    gt = scene / "schlieren_gt.h5"
    rc, stdout, _ = run_cli(["eval", out, "--gt", gt, "--json"], capsys)
    res = json.loads(stdout)
    rows = [w for w in res["windows"] if "q_corr" in w]
    scored = [w for w in rows if w.get("n_pixels", 0) > 0]
    assert rc == 0 and len(scored) < len(rows)  # the start-up window is not scored
    assert res["mean"]["q_corr"] == pytest.approx(np.mean([w["q_corr"] for w in scored]))
    with h5py.File(gt, "a") as f:
        t = f["frame_t"][()]
        del f["frame_t"]
        f["frame_t"] = t[:-1]
    rc, _, err = run_cli(["eval", out, "--gt", gt], capsys)
    assert rc == 2 and "'frame_t' is int64" in err and "one more than 'q' windows" in err, err
