"""Inference: estimate_flow(method="dnn"), DNN-initialized multicm, the shipped checkpoint
and ``evmotion flow --method dnn`` end to end."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from evmotion.cli import main  # noqa: E402
from evmotion.errors import ParameterError, PoorFitWarning  # noqa: E402
from evmotion.events import EventArray  # noqa: E402
from evmotion.methods.dnn.data import sim_window  # noqa: E402
from evmotion.methods.dnn.infer import (  # noqa: E402
    GAINS,
    estimate_flow_dnn,
    predict_displacement,
)
from evmotion.methods.dnn.model import DEFAULT_CHECKPOINT, load_model, save_model  # noqa: E402
from evmotion.methods.dnn.network import EVFlowNet  # noqa: E402
from evmotion.methods.multicm import estimate_flow  # noqa: E402


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory):
    torch.manual_seed(0)
    net = EVFlowNet(width=0.0625)
    for h in net.heads:  # a non-trivial flow, so units are tested on non-zero values
        torch.nn.init.normal_(h.weight, std=0.05)
        torch.nn.init.constant_(h.bias, 0.2)
    path = tmp_path_factory.mktemp("ckpt") / "tiny.pt"
    save_model(path, net)
    return path


@pytest.fixture(scope="module")
def window():
    return sim_window(11, scene="translation", texture="shapes", sensor_size=(50, 70),
                      window_events=6000)


def test_flow_units_and_shape(tiny_ckpt, window):
    ev = window.events
    disp = predict_displacement(ev, tiny_ckpt)
    assert disp.shape == (50, 70, 2) and disp.dtype == np.float32
    assert np.abs(disp).max() > 0.1
    res = estimate_flow_dnn(ev, tiny_ckpt, input_scales=(1,), time_reversal=False,
                            rescale=False, translation=False, planar=False, refine=False)
    dur = (int(ev.t[-1]) - int(ev.t[0])) * 1e-6
    np.testing.assert_allclose(res.flow * dur, disp, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(res.displacement(), disp, rtol=1e-4, atol=1e-4)
    assert set(res.iwes) == {"t1", "tmid", "tN", "identity"} and np.isfinite(res.focus)
    assert res.meta["method"] == "dnn"
    np.testing.assert_array_equal(estimate_flow(ev, method="dnn", checkpoint=tiny_ckpt).flow,
                                  estimate_flow_dnn(ev, tiny_ckpt).flow)
    # the padding is cropped off, whatever the sensor size
    sub = EventArray(x=ev.x % 33, y=ev.y % 17, t=ev.t, p=ev.p, sensor_size=(17, 33))
    assert predict_displacement(sub, tiny_ckpt).shape == (17, 33, 2)


def test_dnn_init_runs_the_finest_scales_only(tiny_ckpt, window):
    res = estimate_flow(window.events, init="dnn", checkpoint=tiny_ckpt, finest_level=5)
    assert len(res.params) == 3 and res.params[0].shape[:2] == (4, 4)
    full = estimate_flow(window.events, finest_level=5)
    assert len(full.params) == 5
    # 6,000 events: by default the finest level is 3 (8 x 8 tiles would hold ~94 events),
    # and init="dnn" runs its three scales from one tile
    assert len(window.events) < 6400
    res = estimate_flow(window.events, init="dnn", checkpoint=tiny_ckpt)
    assert [p.shape[:2] for p in res.params] == [(1, 1), (2, 2), (4, 4)]
    assert res.meta["finest_level"] == estimate_flow(window.events).meta["finest_level"] == 3
    with pytest.raises(ParameterError, match="init"):
        estimate_flow(window.events, init="zero")


def test_bad_checkpoint_is_one_line_error(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(ParameterError, match="bad.pt") as exc:
        load_model(bad)
    assert "\n" not in str(exc.value)
    with pytest.raises(ParameterError, match="no such file"):
        load_model(tmp_path / "missing.pt")


def test_checkpoint_keeps_its_norm_and_older_ones_load_without(tmp_path, window):
    torch.manual_seed(1)
    for norm, sym in (("batch", True), ("none", False)):
        net = EVFlowNet(width=0.0625, norm=norm, symmetric=sym)
        save_model(tmp_path / f"{norm}.pt", net)
        back = load_model(tmp_path / f"{norm}.pt")
        assert (back.norm, back.symmetric) == (norm, sym)
    # a checkpoint written before batch norm and the symmetric network: neither key, no
    # batch-norm tensors
    blob = torch.load(tmp_path / "none.pt", weights_only=True)
    del blob["norm"], blob["symmetric"]
    torch.save(blob, tmp_path / "old.pt")
    old = load_model(tmp_path / "old.pt")
    assert (old.norm, old.symmetric) == ("none", False)
    np.testing.assert_array_equal(predict_displacement(window.events, tmp_path / "old.pt"),
                                  predict_displacement(window.events, tmp_path / "none.pt"))


def test_shipped_checkpoint_is_small_and_sharpens_a_simulated_window():
    assert DEFAULT_CHECKPOINT.is_file()
    assert DEFAULT_CHECKPOINT.stat().st_size <= 10 * 2 ** 20
    net = load_model()
    assert net.width == 0.125
    win = sim_window(123_456_789, scene="rotation", texture="dots", sensor_size=(180, 240),
                     window_events=30_000)
    res = estimate_flow_dnn(win.events)
    fwl = np.var(res.iwes["tmid"]) / np.var(res.iwes["identity"])
    assert fwl > 1.1
    mask = res.iwes["identity"] > 0
    aee = np.linalg.norm(res.displacement() - win.gt, axis=-1)[mask].mean()
    zero = np.linalg.norm(win.gt, axis=-1)[mask].mean()
    assert aee < 0.8 * zero


def test_cli_flow_dnn_end_to_end(tmp_path, window, capsys):
    from evmotion.io import write_events
    from evmotion.io.flowfiles import read_flo

    rec = tmp_path / "win.h5"
    write_events(rec, window.events)
    out = tmp_path / "x.flo"
    assert main(["flow", str(rec), "--method", "dnn", "--window-events", "30000",
                 "--out", str(out)]) == 0
    capsys.readouterr()
    disp = read_flo(out)
    assert disp.shape == (50, 70, 2)
    # unknown (NaN) where no event supports the flow, the network's displacement elsewhere
    valid = np.isfinite(disp).all(axis=2)
    np.testing.assert_array_equal(valid, estimate_flow_dnn(window.events).valid)
    assert 0.05 < valid.mean() < 1
    np.testing.assert_allclose(disp[valid], estimate_flow_dnn(window.events).displacement()[valid],
                               atol=1e-3)
    assert main(["flow", str(rec), "--method", "dnn", "--input-scales", "1",
                 "--no-time-reversal", "--no-rescale", "--no-planar", "--no-refine",
                 "--out", str(out)]) == 0
    capsys.readouterr()
    np.testing.assert_allclose(read_flo(out)[valid], predict_displacement(window.events)[valid],
                               atol=1e-3)
    assert main(["flow", str(rec), "--method", "dnn", "--no-fuse", "--out", str(out)]) == 0
    capsys.readouterr()
    np.testing.assert_allclose(read_flo(out)[valid], estimate_flow_dnn(
        window.events, fuse=False).displacement()[valid], atol=1e-3)
    assert main(["flow", str(rec), "--method", "dnn", "--window-events", "1000",
                 "--out", str(tmp_path / "y.h5"), "--json",
                 "--png-dir", str(tmp_path / "png")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["method"] == "dnn" and summary["n_windows"] >= 2
    assert all(w["input_scale"] in (1, 2, 4) for w in summary["windows"])
    assert all(0.7 <= w["gain"] <= 1.6 for w in summary["windows"])
    assert all(isinstance(w["planar"], bool) for w in summary["windows"])
    assert all(isinstance(w["refined"], bool) for w in summary["windows"])
    assert (tmp_path / "png" / "flow_00000.png").is_file()
    assert main(["flow", str(rec), "--method", "multicm", "--init", "dnn",
                 "--out", str(tmp_path / "z.npz"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["method"] == "multicm"
    assert main(["flow", str(rec), "--method", "dnn", "--checkpoint",
                 str(tmp_path / "none.pt"), "--out", str(out)]) == 2
    assert "none.pt" in capsys.readouterr().err


def test_input_scales_one_is_the_plain_network(tiny_ckpt, window):
    res = estimate_flow_dnn(window.events, tiny_ckpt, input_scales=(1,), time_reversal=False,
                            rescale=False, translation=False, planar=False, refine=False)
    np.testing.assert_allclose(res.displacement(), predict_displacement(window.events, tiny_ckpt),
                               rtol=1e-4, atol=1e-4)
    assert res.meta["input_scale"] == 1
    for bad in ((), (0, 1), (1.5,), 3):
        with pytest.raises(ParameterError, match="input_scales"):
            estimate_flow_dnn(window.events, tiny_ckpt, input_scales=bad)
    # one scale as a plain number (was a TypeError)
    assert estimate_flow_dnn(window.events, tiny_ckpt, input_scales=1).meta["input_scale"] == 1
    with pytest.raises(ParameterError, match="checkpoint must be a path"):
        estimate_flow_dnn(window.events, 5)


def test_time_reversal_makes_the_flow_antisymmetric(tiny_ckpt, window):
    """The time-reversed window (events in reverse order, polarities flipped) moves the
    other way: with time reversal the estimate of it is exactly the negated estimate,
    whatever the network; a flow the network adds in both directions alike (here the
    tiny net's constant bias, ~2 px) cancels."""
    ev = window.events
    t = ev.t[::-1]
    rev = EventArray(x=ev.x[::-1], y=ev.y[::-1], t=int(t[0]) + int(t[-1]) - t,
                     p=1 - ev.p[::-1], sensor_size=ev.sensor_size)
    for scales in ((1,), (1, 2, 4)):
        fwd = estimate_flow_dnn(ev, tiny_ckpt, input_scales=scales, translation=False,
                                planar=False, refine=False).displacement()
        back = estimate_flow_dnn(rev, tiny_ckpt, input_scales=scales, translation=False,
                                 planar=False, refine=False).displacement()
        np.testing.assert_allclose(back, -fwd, atol=1e-4)
    plain = predict_displacement(ev, tiny_ckpt)
    sym = estimate_flow_dnn(ev, tiny_ckpt, input_scales=(1,), translation=False,
                            planar=False, refine=False).displacement()
    assert np.median(np.abs(plain)) > 1.0 > 10 * np.median(np.abs(sym))


def test_rescale_keeps_the_sharpest_gain(tiny_ckpt, window):
    from evmotion.methods.dnn.infer import GAINS, sharpness

    ev = window.events
    plain = estimate_flow_dnn(ev, tiny_ckpt, rescale=False, planar=False, refine=False)
    res = estimate_flow_dnn(ev, tiny_ckpt, planar=False, refine=False)
    gain = res.meta["gain"]
    assert gain in GAINS and plain.meta["gain"] == 1.0
    np.testing.assert_allclose(res.flow, plain.flow * np.float32(gain), rtol=1e-6)
    d = plain.displacement()
    scores = [sharpness(ev, d * g) for g in GAINS]
    assert sharpness(ev, res.displacement()) == pytest.approx(max(scores), rel=1e-9)
    # a flow no gain changes the image of (an empty window's zero flow) keeps gain 1
    zero = EventArray(x=[1, 2, 3] * 4, y=[0, 1, 2] * 4, t=np.arange(12) * 10,
                      p=[1] * 12, sensor_size=(8, 8))
    assert estimate_flow_dnn(zero, tiny_ckpt, input_scales=(1,)).meta["gain"] in GAINS


@pytest.mark.slow
def _zoom_aee(**options) -> float:
    """AEE (px, on the pixels with events) of the shipped network on bench_dnn's held-out
    zoom window (seed 900000002, 40k events at 346x260)."""
    from evmotion.sim import simulate

    sim = simulate("zoom", duration_s=0.2, sensor_size=(260, 346), seed=900_000_002,
                   show_progress=False)
    ev = sim.events
    win = ev[len(ev) // 2 - 20_000: len(ev) // 2 + 20_000]
    gt = sim.gt.displacement(int(win.t[0]), int(win.t[-1]))
    mask = np.zeros(win.sensor_size, bool)
    mask[win.y.astype(int), win.x.astype(int)] = True
    disp = estimate_flow_dnn(win, planar=False, refine=False, **options).displacement()
    return float(np.linalg.norm(disp - gt, axis=-1)[mask].mean())


def test_rescale_lowers_the_shipped_networks_error_on_a_zoom():
    # benchmarks/results/dnn.md: the network underestimates a zoom (least-squares gains
    # 0.81 / 0.91); the sharpest gain brings its AEE from 2.36 to 2.01 px (one scale for
    # the window)
    aee = [_zoom_aee(rescale=r, fuse=False) for r in (False, True)]
    assert aee[1] < 0.9 * aee[0], aee


def test_tile_sharpness_kernel_matches_a_numpy_reference():
    """The numba kernel's per-tile sums of squared counts against np.unique over (tile,
    warped pixel) pairs, events leaving the sensor dropped."""
    from evmotion.methods.dnn.infer import _pixels_and_times, _tile_groups, _tile_sharpness

    rng = np.random.default_rng(3)
    h, w, n = 70, 90, 5000
    ev = EventArray(x=rng.integers(0, w, n), y=rng.integers(0, h, n),
                    t=np.sort(rng.integers(0, 10**5, n)), p=rng.integers(0, 2, n),
                    sensor_size=(h, w))
    disp = rng.normal(0, 6, (h, w, 2)).astype(np.float32)
    xys = _pixels_and_times(ev)
    got = _tile_sharpness(xys, disp, _tile_groups(xys, (h, w), 32))
    x, y, pix, s = xys
    xw = np.rint(x - disp.reshape(-1, 2)[pix, 0] * s).astype(int)
    yw = np.rint(y - disp.reshape(-1, 2)[pix, 1] * s).astype(int)
    ok = (xw >= 0) & (xw < w) & (yw >= 0) & (yw < h)
    tiles = (y // 32) * 3 + x // 32
    keys, counts = np.unique(np.stack([tiles[ok], yw[ok] * w + xw[ok]]), axis=1,
                             return_counts=True)
    ref = np.bincount(keys[0], counts.astype(float) ** 2, minlength=9).reshape(3, 3)
    np.testing.assert_array_equal(got, ref)


def test_tile_sharpness_on_a_1920x1080_sensor_does_not_wrap():
    # tile x (H * W) passed int32 from ~1.5 Mpx: negative keys, a traceback (probe)
    from evmotion.methods.dnn.infer import _pixels_and_times, _tile_groups, _tile_sharpness

    h, w = 1080, 1920
    ev = EventArray(x=[1900, 1900, 1901, 5], y=[1070, 1070, 1070, 3], t=[0, 1, 2, 3],
                    p=[1, 1, 1, 1], sensor_size=(h, w))
    xys = _pixels_and_times(ev)
    got = _tile_sharpness(xys, np.zeros((h, w, 2), np.float32), _tile_groups(xys, (h, w), 32))
    assert got[-1, -1] == 2 * 2 + 1 and got[0, 0] == 1 and got.sum() == 6


def test_the_fusions_blur_is_scipys_gaussian():
    from scipy.ndimage import gaussian_filter

    from evmotion.methods.dnn.infer import _blurred

    maps = np.random.default_rng(0).random((3, 9, 11))
    ref = np.stack([gaussian_filter(m, 0.5, mode="nearest", truncate=2.0) for m in maps])
    np.testing.assert_allclose(_blurred(maps, 0.5), ref, atol=1e-12)


def test_fusion_takes_each_tiles_sharpest_candidate():
    """Dots in the left half move +4 px over the window, in the right half -4 px: of the
    candidates +4 and -4 everywhere, each tile keeps the one that focuses its events."""
    from evmotion.methods.dnn.infer import _fused, _pixels_and_times

    rng = np.random.default_rng(0)
    h, w, n = 64, 128, 20_000
    dots = np.column_stack([rng.uniform(4, w - 4, 400), rng.uniform(0, h, 400)])
    k = rng.integers(0, 400, n)
    s = np.sort(rng.uniform(-0.5, 0.5, n))
    shift = np.where(dots[k, 0] < w / 2, 4.0, -4.0)
    ev = EventArray(x=np.clip(np.rint(dots[k, 0] + shift * s), 0, w - 1).astype(int),
                    y=np.clip(np.rint(dots[k, 1]), 0, h - 1).astype(int),
                    t=((s + 0.5) * 1e5).astype(np.int64), p=np.ones(n, int),
                    sensor_size=(h, w))
    plus = np.zeros((h, w, 2), np.float32)
    plus[..., 0] = 4.0
    fused = _fused(_pixels_and_times(ev), [plus, -plus], plus, (h, w))
    # the choices blend over about a tile at the seam
    assert np.all(fused[:, :16, 0] > 3.9) and np.all(fused[:, -16:, 0] < -3.9)
    assert np.all(fused[..., 1] == 0.0)


def test_fusion_lowers_the_shipped_networks_error_on_a_zoom():
    # a zoom's flow grows from its centre outwards, and each part of the sensor is best
    # seen at another input scale: AEE 2.01 px with one scale for the window, 1.57 with
    # the choice made tile by tile
    aee = [_zoom_aee(fuse=f) for f in (False, True)]
    assert aee[1] < 0.85 * aee[0], aee


@pytest.mark.slow
def test_far_moving_window_is_seen_at_a_coarser_scale():
    # 23 px over the window, beyond the few px the network was trained on: on the sensor's
    # grid it falls short (AEE 8.4 px); on the events binned 2x coarser the window moves
    # within its range, and that prediction warps the events sharper
    from evmotion.sim import simulate

    sim = simulate("translation", duration_s=0.12, sensor_size=(120, 160), seed=5,
                   texture="shapes", params={"vx": 300.0, "vy": -120.0}, show_progress=False)
    ev = sim.events
    n = int(0.6 * len(ev))
    win = ev[len(ev) // 2 - n // 2: len(ev) // 2 + n // 2]
    gt = sim.gt.displacement(int(win.t[0]), int(win.t[-1]))
    mask = np.zeros(win.sensor_size, bool)
    mask[win.y.astype(int), win.x.astype(int)] = True
    assert np.linalg.norm(gt, axis=-1)[mask].mean() > 20
    plain = estimate_flow_dnn(win, input_scales=(1,), time_reversal=False, translation=False,
                              planar=False,
                              refine=False)
    chosen = estimate_flow_dnn(win, time_reversal=False, translation=False, planar=False,
                               refine=False)
    assert chosen.meta["input_scale"] > 1
    aee = [np.linalg.norm(r.displacement() - gt, axis=-1)[mask].mean() for r in (plain, chosen)]
    assert aee[1] < 0.75 * aee[0], aee  # measured 8.38 -> 4.88 px


@pytest.mark.realdata
def test_shipped_checkpoint_sharpens_a_held_out_ecd_window(shared_data):
    from evmotion.io import read_events

    path = shared_data / "ecd_30k_windows" / "poster_translation"
    if not path.is_dir():
        pytest.skip(f"{path} not found")
    res = estimate_flow_dnn(read_events(path))
    # never trained on; benchmarks/results/dnn.md: FWL 1.18 (multicm 1.69)
    assert np.var(res.iwes["tmid"]) / np.var(res.iwes["identity"]) > 1.1


@pytest.mark.realdata
def test_the_translation_is_weighed_against_the_fused_flow(shared_data):
    """A rotating ECD window: no one input scale's flow is as sharp as the fused one, and
    the window's sharpest translation, sharper than the best scale's, is not sharper than
    the fused flow; it is not taken (it was: FWL 3.24 -> 3.00)."""
    from evmotion.io import read_events
    from evmotion.methods.dnn.infer import sharpness

    path = shared_data / "ecd_30k_windows" / "shapes_rotation"
    if not path.is_dir():
        pytest.skip(f"{path} not found")
    ev = read_events(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PoorFitWarning)
        res = estimate_flow_dnn(ev, planar=False, refine=False, with_iwes=False)
        plain = estimate_flow_dnn(ev, planar=False, refine=False, with_iwes=False,
                                  translation=False)
    assert not res.meta["translation"]
    assert sharpness(ev, res.displacement()) >= sharpness(ev, plain.displacement())


def test_judged_command_then_its_sharpness_without_ground_truth(shared_data, tmp_path,
                                                                capsys):
    """``flow WINDOW --method dnn --window-events 30000 --out x.flo`` on an ECD window
    (undistorted by its calib.txt), then ``eval x.flo --events WINDOW``: the FWL of the
    events on the flow's own grid (the raw, distorted events gave 2.67 against 3.60)."""
    path = shared_data / "ecd_30k_windows" / "shapes_rotation"
    if not path.is_dir():
        pytest.skip(f"{path} not found")
    out = tmp_path / "x.flo"
    assert main(["flow", str(path), "--method", "dnn", "--window-events", "30000",
                 "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["eval", str(out), "--events", str(path), "--json"]) == 0
    fwl = json.loads(capsys.readouterr().out)["mean"]["FWL"]
    assert main(["flow", str(path), "--method", "dnn", "--window-events", "30000",
                 "--no-undistort", "--out", str(tmp_path / "raw.flo")]) == 0
    capsys.readouterr()
    assert main(["eval", str(tmp_path / "raw.flo"), "--events", str(path), "--json"]) == 0
    raw = json.loads(capsys.readouterr().out)["mean"]["FWL"]
    assert fwl > 3.0 and raw > 3.0  # each on its own grid (benchmarks/results/dnn.md: 3.24)


def test_device_is_checked_before_anything_loads(tmp_path, window, capsys):
    """A device torch does not know, or that this build or machine lacks, is one line
    naming it, not a traceback or a complaint about the checkpoint."""
    from evmotion.io import write_events
    from evmotion.methods.dnn.model import check_device
    from evmotion.methods.dnn.train import TrainConfig

    assert check_device("cpu") == check_device("cpu:0") == "cpu"
    # torch.load cannot map a checkpoint to "cpu:0": it was taken for a corrupt checkpoint
    np.testing.assert_array_equal(predict_displacement(window.events, device="cpu:0"),
                                  predict_displacement(window.events))
    missing = ["gpu", "meta", "cuda:99"]
    if not torch.cuda.is_available():
        missing.append("cuda")
    for dev in missing:
        # in the library a keyword, on the command line an option (the library's error
        # had named --device, probe BT)
        with pytest.raises(ParameterError, match=f"^device='{dev}'"):
            check_device(dev)
        with pytest.raises(ParameterError, match=f"^--device '{dev}'"):
            check_device(dev, option="--device")
        with pytest.raises(ParameterError, match=f"^device='{dev}'"):
            predict_displacement(window.events, device=dev)
        with pytest.raises(ParameterError, match=f"^device='{dev}'"):
            TrainConfig(sim_windows=1, device=dev).check()
        with pytest.raises(ParameterError, match=f"^device='{dev}'"):
            estimate_flow(window.events, method="dnn", device=dev)
    rec = tmp_path / "win.h5"
    write_events(rec, window.events)
    assert main(["flow", str(rec), "--method", "dnn", "--device", "cuda:99",
                 "--out", str(tmp_path / "x.flo")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--device 'cuda:99'" in err and "checkpoint" not in err
    assert main(["train", "--out", str(tmp_path / "t"), "--sim-windows", "1",
                 "--device", "gpu"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--device 'gpu'" in err


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_inference_matches_cpu(window):
    cpu = estimate_flow_dnn(window.events).displacement()
    gpu = estimate_flow_dnn(window.events, device="cuda").displacement()
    np.testing.assert_allclose(gpu, cpu, atol=1e-3)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_cuda_training_with_validation(tmp_path):
    """Validation windows go to the network's device (they stayed on the CPU: a device
    mismatch in the first epoch of every CUDA training with --val-sim)."""
    from evmotion.methods.dnn.train import TrainConfig, train

    cfg = dict(width=0.0625, batch_size=2, sim_windows=2, val_sim=1, window_events=2000,
               crop=(32, 32), sim_sensor=(40, 48), epochs=1)
    gpu = train(TrainConfig(device="cuda", **cfg), tmp_path / "gpu")
    cpu = train(TrainConfig(device="cpu", **cfg), tmp_path / "cpu")
    assert np.isfinite(gpu["val_FWL"]) and abs(gpu["val_loss"] - cpu["val_loss"]) < 0.05


def test_unusable_checkpoints_are_one_line(tmp_path, window):
    """Each used to be a traceback (IndexError while formatting an empty message, or on a
    file holding a bare tensor), or to blame a missing file for a folder."""
    empty = tmp_path / "empty.pt"
    empty.write_bytes(b"")
    tensor = tmp_path / "tensor.pt"
    torch.save(torch.zeros(3), tensor)
    wrong = tmp_path / "wrong.pt"
    torch.save({"n_bins": 5, "width": 0.125, "model": {"x": torch.zeros(1)}}, wrong)
    run = tmp_path / "run"
    run.mkdir()
    save_model(run / "model.pt", EVFlowNet(width=0.0625))
    text = tmp_path / "text.pt"  # torch's message was a paragraph on weights_only, cut
    text.write_text("garbage\n")
    # 400 flipped bytes inside a tensor: torch loaded other weights without a word
    flipped = bytearray((run / "model.pt").read_bytes())
    mid = len(flipped) // 2
    flipped[mid:mid + 400] = bytes(b ^ 0xFF for b in flipped[mid:mid + 400])
    damaged = tmp_path / "damaged.pt"
    damaged.write_bytes(bytes(flipped))
    # a width that its tensors do not have: torch's size-mismatch paragraph, cut
    narrow = tmp_path / "narrow.pt"
    torch.save({**torch.load(run / "model.pt", weights_only=True), "width": 0.125}, narrow)
    # the first half of a checkpoint (probe AP: "not a PyTorch file")
    truncated = tmp_path / "truncated.pt"
    truncated.write_bytes((run / "model.pt").read_bytes()[:len(flipped) // 2])
    # the archive's folder is not the atomic save's temporary name (probe AP saw it in the
    # damaged member's name)
    import zipfile

    with zipfile.ZipFile(run / "model.pt") as zf:
        assert {n.split("/")[0] for n in zf.namelist()} == {"archive"}
    # settings no network has (probe BG: the width's error named no file; n_bins 0 let
    # torch warn of zero-element tensors first)
    stored = torch.load(run / "model.pt", weights_only=True)
    minus, nobins = tmp_path / "minus.pt", tmp_path / "nobins.pt"
    torch.save({**stored, "width": -1.0}, minus)
    torch.save({**stored, "n_bins": 0}, nobins)
    for path, match in ((minus, r"settings make no network .*width must be in"),
                        (nobins, r"settings make no network .*n_bins must be a whole number"),
                        (empty, "not a PyTorch file"), (text, "not a PyTorch file"),
                        (truncated, "truncated or damaged: the start of a PyTorch archive"),
                        (tensor, "no 'n_bins'"), (wrong, "no tensor"),
                        (damaged, "damaged .*archive/.*CRC"),
                        (narrow, r"width 0.125.*enc.0.0.weight is \[4, 5, 3, 3\] in the "
                                 r"file, \[8, 5, 3, 3\] in the network"),
                        (run, "folder.*model.pt"), (tmp_path / "none.pt", "no such file"),
                        (Path("/dev/null"), "not a regular file")):
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            with pytest.raises(ParameterError, match=match) as exc:
                load_model(path)
        assert "\n" not in str(exc.value) and str(path) in str(exc.value)


def test_a_diverged_checkpoint_is_refused(tmp_path, window):
    """NaN weights (a training that diverged) gave an all-NaN flow marked valid, exit 0."""
    net = EVFlowNet(width=0.0625)
    with torch.no_grad():
        net.heads[0].bias.fill_(float("nan"))
    path = tmp_path / "nan.pt"
    save_model(path, net)
    with pytest.raises(ParameterError, match="non-finite flow"):
        estimate_flow_dnn(window.events, path)
    with pytest.raises(ParameterError, match="non-finite flow"):
        estimate_flow(window.events, init="dnn", checkpoint=path)


def test_multicm_init_dnn_records_its_checkpoint(tmp_path, window, tiny_ckpt, capsys):
    from evmotion.io import write_events
    from evmotion.io.flowread import read_flow

    rec = tmp_path / "win.h5"
    write_events(rec, window.events)
    out = tmp_path / "f.h5"
    assert main(["flow", str(rec), "--method", "multicm", "--init", "dnn", "--checkpoint",
                 str(tiny_ckpt), "--out", str(out)]) == 0
    capsys.readouterr()
    assert read_flow(out).attrs["checkpoint"] == str(tiny_ckpt)


def test_video_without_its_extra_fails_before_the_work(tmp_path, window, capsys):
    """The missing 'video' extra was reported after every window was computed and its
    files written."""
    import importlib.util

    from evmotion.io import write_events

    if importlib.util.find_spec("imageio_ffmpeg") is not None:
        pytest.skip("the 'video' extra is installed")
    rec = tmp_path / "win.h5"
    write_events(rec, window.events)
    assert main(["flow", str(rec), "--method", "dnn", "--out", str(tmp_path / "x_{:05d}.flo"),
                 "--video", str(tmp_path / "v.mp4")]) == 2
    assert "imageio-ffmpeg" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["win.h5"]


def _with_hot_pixels(ev, share, n_hot=5, seed=0):
    """``ev`` with ``share`` of its events moved onto ``n_hot`` fixed pixels."""
    rng = np.random.default_rng(seed)
    h, w = ev.sensor_size
    k = int(share * len(ev))
    idx = rng.choice(len(ev), k, replace=False)
    hx, hy = rng.integers(5, w - 5, n_hot), rng.integers(5, h - 5, n_hot)
    which = rng.integers(0, n_hot, k)
    x, y = ev.x.astype(np.int64), ev.y.astype(np.int64)
    x[idx], y[idx] = hx[which], hy[which]
    return EventArray(x=x, y=y, t=ev.t, p=ev.p, sensor_size=ev.sensor_size), hx, hy


def test_hot_pixels_get_zero_flow_and_do_not_blur_the_window():
    """2 % of a window's events on 5 hot pixels: the network's flow there smeared them, and
    the window came out blurrier than unwarped (FWL 0.80 on an ECD window). Their flow is
    now zero, and the FWL the result reports is that of the flow written."""
    from evmotion.methods.dnn.infer import sharpness

    win = sim_window(5, scene="translation", texture="shapes", sensor_size=(120, 160),
                     window_events=20000)
    ev, hx, hy = _with_hot_pixels(win.events, 0.02)
    res = estimate_flow_dnn(ev, with_iwes=False)
    assert res.meta["hot_pixels"] == 5
    assert np.all(res.flow[hy, hx] == 0)
    disp = res.displacement()
    # the FWL reported is that of the flow written, over the events off the hot pixels
    off = ev[np.flatnonzero(~np.isin(ev.y.astype(np.int64) * 160 + ev.x.astype(np.int64),
                                     hy * 160 + hx))]
    still = sharpness(off, np.zeros_like(disp))
    assert res.meta["fwl"] == pytest.approx(sharpness(off, disp) / still)
    moving = disp.copy()  # the flow around each hot pixel given to it too
    moving[hy, hx] = disp[hy + 2, hx]
    assert sharpness(ev, moving) < sharpness(ev, disp)
    # a clean window has no hot pixel
    assert estimate_flow_dnn(win.events, with_iwes=False).meta["hot_pixels"] == 0


@pytest.mark.parametrize("with_iwes", [False, True])
def test_hot_pixels_do_not_hide_a_good_flow(with_iwes):
    """8 hot pixels holding 11 % of a window's events: alike in the warped and the unwarped
    image, they pulled the contrast ratio to 1.003 and a flow of 1.8 px AEE (zero flow
    7.2) was thrown away as no measurement (probe W). They are left out of the checks."""
    win = sim_window(5, scene="translation", texture="shapes", sensor_size=(120, 160),
                     window_events=20000)
    ev, _, _ = _with_hot_pixels(win.events, 0.11, n_hot=8)
    with warnings.catch_warnings():
        warnings.simplefilter("error", PoorFitWarning)
        res = estimate_flow_dnn(ev, with_iwes=with_iwes)
    assert res.meta["hot_pixels"] == 8 and not res.meta["no_focus"]
    assert res.meta["fwl"] > 1.2 and res.valid.mean() > 0.2
    if with_iwes:
        assert res.focus > 1.05


def test_a_window_moving_far_past_the_network_takes_its_sharpest_translation():
    """A window moving 80 px came out of the network at a fraction of it; its sharpest
    translation, far sharper, is taken (probe BT: 47 px given as 19, valid, unwarned)."""
    from evmotion.core.translation import sharpest_translation
    from evmotion.methods.dnn.infer import _pixels_and_times

    rng = np.random.default_rng(0)
    n = 30000
    fx, fy = rng.uniform(0, 240, 300), rng.uniform(0, 180, 300)
    k = rng.integers(0, 300, n)
    t = np.sort(rng.integers(0, 20000, n))
    x, y = np.floor(fx[k] + 80 * t / 20000), np.floor(fy[k] - 30 * t / 20000)
    ok = (x >= 0) & (x < 240) & (y >= 0) & (y < 180)
    ev = EventArray(x=x[ok], y=y[ok], t=t[ok], p=rng.integers(0, 2, n)[ok],
                    sensor_size=(180, 240))
    x, y, _, s = _pixels_and_times(ev)
    assert sharpest_translation(x, y, s, ev.sensor_size) == (80.0, -30.0)
    res = estimate_flow_dnn(ev, with_iwes=False)
    assert res.meta["translation"] and not res.meta["beyond_range"]
    d = np.median(res.displacement()[res.valid], axis=0)
    np.testing.assert_allclose(d, [80.0, -30.0], atol=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PoorFitWarning)
        plain = estimate_flow_dnn(ev, with_iwes=False, translation=False, planar=False,
                                  refine=False)
    assert not plain.meta["translation"]  # the network alone: short, or no measurement
    assert not plain.valid.any() or np.median(
        np.linalg.norm(plain.displacement()[plain.valid], axis=-1)) < 60


def test_the_translation_search_matches_a_brute_force_one():
    from evmotion.core.translation import sharpest_translation

    rng = np.random.default_rng(1)
    x0, y0 = rng.uniform(0, 40, 60), rng.uniform(0, 30, 60)
    s = np.repeat(np.linspace(-0.5, 0.5, 12), 60)
    x = np.floor(np.tile(x0, 12) - 7 * s)
    y = np.floor(np.tile(y0, 12) + 5 * s)
    ok = (x >= 0) & (x < 40) & (y >= 0) & (y < 30)
    x, y, s = x[ok], y[ok], s[ok]

    def score(dx, dy):
        img = np.zeros((30, 40))
        xw, yw = np.floor(x - dx * s).astype(int), np.floor(y - dy * s).astype(int)
        inside = (xw >= 0) & (xw < 40) & (yw >= 0) & (yw < 30)
        np.add.at(img, (yw[inside], xw[inside]), 1.0)
        return (img ** 2).sum()

    brute = max(((score(dx, dy), (dx, dy)) for dx in range(-20, 21) for dy in range(-20, 21)),
                key=lambda sc: (sc[0], -abs(sc[1][0]) - abs(sc[1][1])))[1]
    assert brute == (-7, 5)
    assert sharpest_translation(x, y, s, (30, 40), reach=20) == (-7.0, 5.0)


def test_motion_beyond_the_network_is_a_lower_bound():
    """A window moving 80 px: the network's flow, at the largest gain tried, is a fraction
    of it; that is said (PoorFitWarning, meta["beyond_range"]), not returned silently.
    Where that flow does not even carry the window's first half onto its second, the
    window is no measurement at all."""
    rng = np.random.default_rng(0)
    n = 30000
    fx, fy = rng.uniform(0, 240, 300), rng.uniform(0, 180, 300)
    k = rng.integers(0, 300, n)
    t = np.sort(rng.integers(0, 20000, n))
    ev = EventArray(x=np.floor((fx[k] + 80 * t / 20000) % 240), y=np.floor(fy[k]), t=t,
                    p=rng.integers(0, 2, n), sensor_size=(180, 240))
    with pytest.warns(PoorFitWarning, match="largest gain tried.*lower bound|first half"):
        res = estimate_flow_dnn(ev, with_iwes=False, translation=False, planar=False,
                                refine=False)
    assert res.meta["gain"] == max(GAINS)
    assert res.meta["beyond_range"] or (res.meta["no_focus"] and not res.valid.any())
    # with the plane's polish (the default) the window is not given silently short either:
    # the plane reaches the motion's magnitude, or the flow is said to be a lower bound or
    # no measurement (measured: a plane kept, median 67 px; bent by its quadratic terms,
    # 26 px from the truth)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PoorFitWarning)
        res = estimate_flow_dnn(ev, with_iwes=False, translation=False)
    speed = np.linalg.norm(res.displacement()[res.valid], axis=-1)
    reached = res.meta["planar"] and speed.size and np.median(speed) > 0.75 * 80
    assert reached or res.meta["beyond_range"] or (res.meta["no_focus"]
                                                   and not res.valid.any())
    assert not estimate_flow_dnn(sim_window(5, scene="translation", texture="shapes",
                                            sensor_size=(120, 160), window_events=20000
                                            ).events, with_iwes=False).meta["beyond_range"]


def test_no_focus_is_checked_without_json_or_pictures(tmp_path, capsys):
    """The judged command (no --json, no --png-dir) skipped the focus check: a window of
    pure noise came out as valid flow, silently. Now stderr says so and the .flo holds
    only unknown values, as with --json."""
    rng = np.random.default_rng(3)
    n = 30000
    ev = EventArray(x=rng.integers(0, 240, n), y=rng.integers(0, 180, n),
                    t=np.sort(rng.integers(0, 30000, n)), p=rng.integers(0, 2, n),
                    sensor_size=(180, 240))
    from evmotion.io import read_flow, write_events

    write_events(tmp_path / "noise.h5", ev)

    for extra in ([], ["--json"]):
        out = tmp_path / f"n{len(extra)}.flo"
        with warnings.catch_warnings():
            warnings.simplefilter("always")  # each run is a process of its own
            assert main(["flow", str(tmp_path / "noise.h5"), "--method", "dnn",
                         "--window-events", "30000", "--out", str(out), *extra]) == 0
        assert "no focus" in capsys.readouterr().err
        assert not read_flow(out).valid.any()


def test_poor_fit_lines_name_their_window_and_stop_after_five(tmp_path, capsys):
    """A recording of noise said 'no focus' once per window with nothing to tell the
    windows apart (hundreds of lines on a long one): each line now names its window, and
    after five one closing line counts the rest."""
    from evmotion.io import read_flow, write_events

    rng = np.random.default_rng(0)
    n = 9 * 20000
    ev = EventArray(x=rng.integers(0, 240, n), y=rng.integers(0, 180, n),
                    t=np.sort(rng.integers(0, 900_000, n)), p=rng.integers(0, 2, n),
                    sensor_size=(180, 240))
    write_events(tmp_path / "noise.h5", ev)
    out = tmp_path / "f.h5"
    assert main(["flow", str(tmp_path / "noise.h5"), "--method", "dnn", "--window-events",
                 "20000", "--out", str(out)]) == 0
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 6, lines
    assert all(f"window {k} [" in lines[k] and "no focus" in lines[k] for k in range(5))
    assert "and 4 more such warnings" in lines[5]
    assert not read_flow(out).valid.any()


def test_the_network_runs_on_the_threads_asked_and_restores_torchs(window):
    # probe AP: the API ran on torch's default (2 threads here), 2-12x slower than the CLI
    import torch

    from evmotion.methods.dnn.infer import torch_threads

    before = torch.get_num_threads()
    seen = []
    with torch_threads(1):
        seen.append(torch.get_num_threads())
    assert seen == [1] and torch.get_num_threads() == before
    with torch_threads(None):
        assert torch.get_num_threads() == before
    res = estimate_flow_dnn(window.events, with_iwes=False, threads=1)
    assert res.flow.shape[:2] == window.events.sensor_size
    assert torch.get_num_threads() == before
    with pytest.raises(ParameterError, match=r"threads must be an integer in \[1, 256\]"):
        estimate_flow_dnn(window.events, threads=0)


def test_an_unchecked_flow_is_the_checked_ones_without_its_verdicts(window):
    """check=False (multicm's init="dnn") gives the same flow, none of the tests' warnings,
    and no_focus None (not 'measured')."""
    kw = dict(with_iwes=False, time_reversal=False, fuse=False, rescale=False)
    checked = estimate_flow_dnn(window.events, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        bare = estimate_flow_dnn(window.events, check=False, **kw)
    np.testing.assert_array_equal(bare.flow, checked.flow)
    assert bare.meta["no_focus"] is None and isinstance(checked.meta["no_focus"], bool)
    assert np.isnan(bare.meta["chance_gain"]) and np.isnan(bare.meta["halves_correlation"])


def test_time_reversal_runs_where_the_input_is_at_most_vga(tiny_ckpt, monkeypatch):
    """A 1280x720 window's pass on the sensor's grid runs once (its reversed twin cost
    0.47 s of the one-window command); the coarser inputs keep both passes."""
    import evmotion.methods.dnn.infer as inf

    seen = []
    real = inf._run

    def spy(net, vox, shape, device, time_reversal=False):
        seen.append((shape, time_reversal))
        return real(net, vox, shape, device, time_reversal)

    monkeypatch.setattr(inf, "_run", spy)
    rng = np.random.default_rng(0)
    ev = EventArray(x=rng.integers(0, 1280, 5000), y=rng.integers(0, 720, 5000),
                    t=np.arange(5000) * 10, p=rng.integers(0, 2, 5000), sensor_size=(720, 1280))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        inf.estimate_flow_dnn(ev, tiny_ckpt, input_scales=(1, 2), fuse=False, rescale=False,
                              planar=False, refine=False, with_iwes=False, check=False)
    assert seen == [((720, 1280), False), ((360, 640), True)]


def test_the_one_window_command_does_not_import_numba(tmp_path):
    """numba's import cost the one-window dnn command 0.4 s (the refinement's tile grid
    lived beside numba kernels, and the compile-time listener imported it): the command,
    refinement included, runs without it."""
    import subprocess
    import sys

    from evmotion.io import write_events

    write_events(tmp_path / "w.h5", sim_window(3, scene="rotation", sensor_size=(60, 80),
                                               window_events=4000).events)
    script = tmp_path / "probe.py"
    script.write_text(
        "import sys, warnings\n"
        "warnings.simplefilter('ignore')\n"
        "from evmotion.cli import main\n"
        "main(['flow', sys.argv[1], '--method', 'dnn', '--out', sys.argv[2]])\n"
        "print('numba' in sys.modules)\n")
    out = subprocess.run([sys.executable, str(script), str(tmp_path / "w.h5"),
                          str(tmp_path / "x.flo")], capture_output=True, text=True)
    assert (tmp_path / "x.flo").is_file(), out.stderr
    assert out.stdout.strip().splitlines()[-1] == "False", out.stdout + out.stderr


def test_warped_variance_is_the_count_images_variance():
    """_warped_variance from the counts of the pixels events land on equals np.var of the
    whole count image (what it computed before, 0.3 s a 1280 x 720 window)."""
    from evmotion.methods.dnn.infer import _warped_variance

    rng = np.random.default_rng(0)
    h, w, n = 37, 53, 5000
    x, y = rng.integers(0, w, n), rng.integers(0, h, n)
    s = rng.uniform(-0.5, 0.5, n)
    disp = rng.normal(0, 6, (h, w, 2))
    d = disp.reshape(-1, 2)[y * w + x]
    xw, yw = np.rint(x - d[:, 0] * s).astype(int), np.rint(y - d[:, 1] * s).astype(int)
    inside = (xw >= 0) & (xw < w) & (yw >= 0) & (yw < h)
    assert inside.mean() < 0.95  # some land outside
    ref = np.var(np.bincount(yw[inside] * w + xw[inside], minlength=h * w))
    assert _warped_variance(x, y, y * w + x, s, disp) == pytest.approx(ref, rel=1e-12)


def test_a_second_motion_the_network_does_not_follow_is_flagged():
    # probe BZ: a patch over a background moving otherwise came out of dnn with the
    # patch's motion everywhere (AEE above the zero flow's), valid; the tiles a motion of
    # their own sharpens 1.5x more are flagged, as multicm's
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_multicm import _patch_over_background

    ev, on, v = _patch_over_background(1)
    with pytest.warns(PoorFitWarning, match="another motion: in [1-9].* network's flow"):
        res = estimate_flow_dnn(ev, with_iwes=False)
    xi, yi = ev.x.astype(int), ev.y.astype(int)
    ok = res.valid[yi, xi]
    err = np.linalg.norm(res.flow[yi, xi] - v, axis=1) * res.duration_s
    assert res.meta["other_motion_tiles"] >= 3 and 0.5 < ok.mean() < 0.95
    assert err[ok].mean() < 0.6 * err.mean()  # the flagged pixels were the wrong ones
    with warnings.catch_warnings():
        warnings.simplefilter("error", PoorFitWarning)  # one motion: nothing flagged
        one = estimate_flow_dnn(sim_window(5, scene="translation").events, with_iwes=False)
    assert one.meta["other_motion_tiles"] == 0
