"""Training: a tiny net learns on a simulated window; --resume reproduces the weights."""

from __future__ import annotations

import csv
import os
import warnings
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from evmotion.errors import ParameterError  # noqa: E402
from evmotion.methods.dnn.data import crop_window, sim_window  # noqa: E402
from evmotion.methods.dnn.loss import WindowLoss, multiscale_loss, window_problem  # noqa: E402
from evmotion.methods.dnn.network import EVFlowNet, upsample_flows  # noqa: E402
from evmotion.methods.dnn.train import TrainConfig, train  # noqa: E402
from evmotion.methods.dnn.voxel import normalize_voxel, pad_to_multiple, voxel_grid  # noqa: E402

TINY = dict(width=0.0625, batch_size=2, sim_windows=3, val_sim=1, window_events=4000,
            crop=(48, 64), sim_sensor=(48, 64), threads=1)


def test_network_shapes_and_width():
    net = EVFlowNet(width=0.0625)
    flows = net(torch.zeros(2, 5, 48, 64))
    assert [tuple(f.shape) for f in flows] == [(2, 2, 6, 8), (2, 2, 12, 16), (2, 2, 24, 32),
                                               (2, 2, 48, 64)]
    full = sum(p.numel() for p in EVFlowNet(width=1.0).parameters())
    small = sum(p.numel() for p in EVFlowNet(width=0.125).parameters())
    assert 10e6 < full < 16e6 and small < full / 40


def test_few_steps_reduce_the_loss_on_a_simulated_window():
    torch.manual_seed(0)
    torch.set_num_threads(1)
    win = sim_window(0, scene="translation", texture="shapes", sensor_size=(48, 64),
                     window_events=4000)
    prob = [WindowLoss(window_problem(win.events), (48, 64))]
    vox = torch.from_numpy(pad_to_multiple(normalize_voxel(voxel_grid(win.events)))[None])
    net = EVFlowNet(width=0.0625)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    losses = []
    for _ in range(25):
        opt.zero_grad()
        loss = multiscale_loss(upsample_flows(net(vox), (48, 64)), prob)
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    # 4 scales of 1/f at zero flow = 4; the sharper warp lowers it clearly
    assert losses[0] == pytest.approx(4.0, abs=0.01)
    assert losses[-1] < losses[0] - 0.1


def _weights(path):
    return torch.load(path, weights_only=True)["model"]


def test_resume_gives_the_weights_of_an_uninterrupted_run(tmp_path):
    cfg2 = TrainConfig(epochs=2, **TINY)
    summary = train(cfg2, tmp_path / "a")
    cfg1 = TrainConfig(epochs=1, **TINY)
    train(cfg1, tmp_path / "b")
    train(cfg2, tmp_path / "b", resume=True)
    wa, wb = _weights(tmp_path / "a" / "model.pt"), _weights(tmp_path / "b" / "model.pt")
    assert wa.keys() == wb.keys()
    for k in wa:
        assert torch.equal(wa[k], wb[k]), k
    # a different seed gives different weights (the comparison can fail)
    train(TrainConfig(epochs=1, **{**TINY, "seed": 1}), tmp_path / "c")
    wc = _weights(tmp_path / "c" / "model.pt")
    assert any(not torch.equal(wa[k], wc[k]) for k in wa)
    # a resume with nothing to do keeps the run's own settings in model.pt (it rewrote
    # them with the fewer epochs asked, probe CK)
    train(cfg1, tmp_path / "b", resume=True)
    meta = torch.load(tmp_path / "b" / "model.pt", weights_only=False)
    assert meta["meta"]["config"]["epochs"] == 2, meta["meta"]
    rows = list(csv.DictReader(open(tmp_path / "b" / "epochs.csv")))
    assert [int(r["epoch"]) for r in rows] == [0, 1]
    assert "val_AEE_px" in rows[0] and np.isfinite(summary["val_FWL"])
    assert (tmp_path / "b" / "loss.png").stat().st_size > 1000
    steps = list(csv.DictReader(open(tmp_path / "a" / "steps.csv")))
    assert {int(r["epoch"]) for r in steps} == {0, 1} and len(steps) >= 3


def test_best_checkpoint_is_the_epoch_of_the_lowest_validation_loss(tmp_path, monkeypatch):
    # only the last epoch's weights were kept: a training that overfit in its later epochs
    # lost its best network (probe BG)
    import evmotion.methods.dnn.train as tr
    from evmotion.methods.dnn.infer import load_network

    real, val_losses = tr.evaluate_windows, iter([0.5, 0.3, 0.4])

    def scored(*args, **kw):
        rows = real(*args, **kw)
        loss = next(val_losses)
        return [{**r, "loss": loss} for r in rows]

    monkeypatch.setattr(tr, "evaluate_windows", scored)
    summary = train(TrainConfig(epochs=3, **TINY), tmp_path / "a")
    assert summary["best_epoch"] == 1 and summary["epoch"] == 2
    monkeypatch.undo()
    train(TrainConfig(epochs=2, **TINY), tmp_path / "b")
    best, second = _weights(tmp_path / "a" / "best.pt"), _weights(tmp_path / "b" / "model.pt")
    assert all(torch.equal(best[k], second[k]) for k in best)
    last = _weights(tmp_path / "a" / "model.pt")
    assert any(not torch.equal(best[k], last[k]) for k in best)
    x = np.random.default_rng(0).normal(size=(1, 5, 48, 64)).astype(np.float32)
    np.testing.assert_array_equal(load_network(tmp_path / "a" / "best.npz")(x),
                                  load_network(tmp_path / "b" / "model.npz")(x))
    # without validation windows there is no best
    summary = train(TrainConfig(epochs=1, **{**TINY, "val_sim": 0}), tmp_path / "c")
    assert summary["best_epoch"] is None and not (tmp_path / "c" / "best.pt").exists()


def test_resume_refuses_other_settings(tmp_path):
    from evmotion.errors import ParameterError

    train(TrainConfig(epochs=1, **TINY), tmp_path)
    with pytest.raises(ParameterError, match="width"):
        train(TrainConfig(epochs=2, **{**TINY, "width": 0.125}), tmp_path, resume=True)
    # without --resume, a second run would have overwritten the first's checkpoints
    before = (tmp_path / "last.pt").read_bytes()
    with pytest.raises(ParameterError, match="already holds a training.*--resume"):
        train(TrainConfig(epochs=1, **TINY), tmp_path)
    assert (tmp_path / "last.pt").read_bytes() == before


def test_a_simulated_window_without_events_is_dropped_not_a_crash():
    # probe AP: a zoom scene firing nothing at 32x32 was an IndexError traceback in
    # sim_window, and --resume met it again (the epoch's data is fixed by its seed)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the simulator says the scene fired nothing)
        win = sim_window(5_220_002, sensor_size=(32, 32), window_events=1000)
    assert len(win.events) == 0 and win.gt.shape == (32, 32, 2)
    assert crop_window(win, (32, 32), np.random.default_rng(0), min_events=10) is None


def test_crop_window_keeps_events_inside_and_shifts_them():
    win = sim_window(1, scene="rotation", sensor_size=(60, 80), window_events=3000)
    c = crop_window(win, (32, 48), np.random.default_rng(0), min_events=10)
    assert c.events.sensor_size == (32, 48) and c.gt.shape == (32, 48, 2)
    assert c.events.x.max() < 48 and c.events.y.max() < 32 and len(c.events) >= 10


def test_cli_train_end_to_end(tmp_path, capsys):
    import json

    from evmotion.cli import main

    out = tmp_path / "run"
    argv = ["train", "--sim-windows", "2", "--epochs", "1", "--batch-size", "2", "--width",
            "0.0625", "--crop", "48x64", "--window-events", "4000", "--val-sim", "0",
            "--out", str(out), "--json"]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["epoch"] == 0 and summary["train_loss"] > 0
    assert summary["model"] == str(out / "model.pt") and summary["seconds"] > 0
    assert summary["best"] is None  # (--val-sim 0: no validation loss)
    # the last epoch's seconds, as epochs.csv has them (the run's were printed over them)
    epochs = (out / "epochs.csv").read_text().splitlines()
    col = epochs[0].split(",").index("seconds")
    assert summary["seconds"] == pytest.approx(float(epochs[-1].split(",")[col]), rel=1e-3)
    assert summary["total_seconds"] >= summary["seconds"]
    assert {p.name for p in out.iterdir()} >= {"last.pt", "model.pt", "model.npz",
                                                "steps.csv", "epochs.csv", "loss.png"}
    # the numpy export is the network of model.pt
    from evmotion.methods.dnn.infer import load_network

    x = np.random.default_rng(0).normal(size=(1, 5, 48, 64)).astype(np.float32)
    np.testing.assert_array_equal(load_network(out / "model.npz")(x),
                                  load_network(out / "model.pt", backend="numpy")(x))
    # the closing line counts the epochs and steps, and gives the loss and time
    assert main(argv[:-1] + ["--epochs", "2", "--resume"]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    # (the second epoch's crops keep too few events: no step, said as such, not counted)
    assert line.startswith("2 epochs, 1 step, last training loss ") and " s -> " in line
    assert "lowest validation loss" not in line
    assert main(argv[:-3] + ["--crop", "50x64", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--crop" in err and "multiple of 16" in err and "'50x64'" in err



def test_interrupted_training_names_the_checkpoint_to_resume(tmp_path, capsys, monkeypatch):
    import evmotion.methods.dnn.train as dnn_train
    from evmotion.cli import main

    out = tmp_path / "run"
    argv = ["train", "--sim-windows", "2", "--epochs", "1", "--batch-size", "2", "--width",
            "0.0625", "--crop", "48x64", "--window-events", "4000", "--val-sim", "0",
            "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(dnn_train, "train", interrupted)
    assert main(argv[:-2] + ["--epochs", "3", "--resume", "--out", str(out)]) == 130
    # model.pt / model.npz are said to be an unfinished training's (they looked finished
    # and flow took them without a word, probe BP)
    assert capsys.readouterr().err == (
        f"evmotion: interrupted; the work done so far is kept in {out / 'last.pt'}: model.pt "
        "and model.npz there are the network after 1 of 3 epochs (epochs.csv's epoch 0), "
        "not a finished training's; "
        "run the same command with --resume to continue\n")


def test_init_weights_starts_from_a_checkpoint(tmp_path):
    from evmotion.methods.dnn.model import save_model

    torch.manual_seed(5)
    start = EVFlowNet(width=0.0625)
    save_model(tmp_path / "start.pt", start)
    train(TrainConfig(epochs=1, lr=1e-12, val_sim=0, init_weights=str(tmp_path / "start.pt"),
                      **{k: v for k, v in TINY.items() if k != "val_sim"}), tmp_path / "run")
    got = _weights(tmp_path / "run" / "model.pt")
    # the parameters (at lr 1e-12); batch norm's running statistics move with each forward
    for k, v in start.named_parameters():
        torch.testing.assert_close(got[k], v.detach(), rtol=0, atol=1e-6)


def test_init_weights_of_another_network_is_one_line_error(tmp_path):
    from evmotion.methods.dnn.model import save_model

    save_model(tmp_path / "old.pt", EVFlowNet(width=0.0625, norm="none", symmetric=False))
    with pytest.raises(ParameterError, match="norm none, symmetric False") as exc:
        train(TrainConfig(epochs=1, val_sim=0, init_weights=str(tmp_path / "old.pt"),
                          **{k: v for k, v in TINY.items() if k != "val_sim"}),
              tmp_path / "run")
    assert "\n" not in str(exc.value)


def test_transpose_window_swaps_axes_and_flow_components():
    from evmotion.methods.dnn.data import transpose_window

    win = sim_window(4, scene="translation", sensor_size=(48, 64), window_events=3000)
    t = transpose_window(win)
    assert t.events.sensor_size == (64, 48) and t.gt.shape == (64, 48, 2)
    np.testing.assert_array_equal(t.events.x, win.events.y)
    # the swapped ground truth is the flow of the transposed events: the loss there equals
    # the loss of the original window at its ground truth (an unswapped (u, v) would not)
    lo = window_problem(win.events).value_grad(win.gt.astype(np.float64).ravel())[0]
    lt = window_problem(t.events).value_grad(t.gt.astype(np.float64).ravel())[0]
    lbad = window_problem(t.events).value_grad(
        win.gt.transpose(1, 0, 2).astype(np.float64).ravel())[0]
    assert lt == pytest.approx(lo, rel=1e-9) and lbad > 1.2 * lt


def test_transpose_and_kaiming_options(tmp_path):
    from evmotion.errors import ParameterError
    from evmotion.methods.dnn.train import _kaiming_init

    torch.manual_seed(0)
    net = EVFlowNet(width=0.0625)
    heads = [h.weight.detach().clone() for h in net.heads]
    _kaiming_init(net)
    assert all(float(m.bias.detach().abs().max()) == 0.0 for m in net.enc.modules()
               if isinstance(m, torch.nn.Conv2d))
    for h, w in zip(net.heads, heads, strict=True):
        assert torch.equal(h.weight, w)  # the flow heads keep their near-zero start
    with pytest.raises(ParameterError, match="init"):
        TrainConfig(init="xavier").check()
    s = train(TrainConfig(epochs=1, transpose=True, init="kaiming", sim_duration_s=0.02,
                          **TINY), tmp_path)
    assert np.isfinite(s["train_loss"]) and np.isfinite(s["val_AEE_px"])


def test_width_beyond_the_memory_is_refused(tmp_path, capsys):
    """--width 1e9 used to try to allocate 11.5 TB (a torch traceback): (0, MAX_WIDTH]."""
    from evmotion.cli import main
    from evmotion.errors import ParameterError
    from evmotion.methods.dnn import MAX_WIDTH
    from evmotion.methods.dnn.network import EVFlowNet

    for bad in (0.0, -1.0, float("nan"), 2 * MAX_WIDTH, 1e9):
        with pytest.raises(ParameterError, match="width"):
            EVFlowNet(width=bad)
        with pytest.raises(ParameterError, match="width"):
            TrainConfig(**{**TINY, "width": bad}).check()
    assert main(["train", "--out", str(tmp_path), "--sim-windows", "1", "--width", "1e9"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--width" in err and "1e9" in err


@pytest.mark.parametrize("bad", [{"max_steps_per_epoch": -1}, {"lr": float("inf")},
                                 {"lam": float("nan")}, {"lam": -1.0}, {"val_sim": -1},
                                 {"window_events": 1}, {"epochs": 1.5}, {"seed": -1},
                                 {"recordings": "/tmp/x.h5"}, {"crop": (32,)}])
def test_config_values_that_trained_nothing_or_nan_are_refused(bad):
    """Each was accepted and ran zero steps (max_steps -1), gave a NaN loss (lr inf, lam
    NaN), iterated a path letter by letter, or ended in a raw Python error."""
    from evmotion.errors import ParameterError

    with pytest.raises(ParameterError, match=next(iter(bad)).split("_")[0]):
        TrainConfig(**{**TINY, **bad}).check()


def test_an_epoch_without_windows_warns(tmp_path):
    from evmotion.errors import EvmotionWarning

    # epoch 1's two 32x32 crops both keep fewer than min_events (seeded: always so)
    cfg = TrainConfig(epochs=2, sim_windows=2, crop=(32, 32), sim_sensor=(40, 48),
                      window_events=2000, batch_size=2, max_steps_per_epoch=1, val_sim=0)
    with pytest.warns(EvmotionWarning, match="epoch 1: .* nothing was trained"):
        summary = train(cfg, tmp_path)
    assert np.isnan(summary["train_loss"])
    # the steps taken are counted, and the crops left out (it said 2 steps for 1)
    import csv

    with open(tmp_path / "epochs.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["step"] for r in rows] == ["1", "1"] and rows[1]["dropped_crops"] == "2"
    assert summary["step"] == 1


def test_runs_that_cannot_train_say_so(tmp_path):
    """A recording too short for a window is named; a run in which no crop keeps enough
    events is an error with nothing written (it used to exit 0 with an untrained
    model.pt); resuming a finished run reports its last epoch; a network whose flow is not
    finite stops the validation (a diverged training)."""
    from evmotion.errors import EvmotionWarning, ParameterError
    from evmotion.events import EventArray
    from evmotion.io import write_events
    from evmotion.methods.dnn.train import evaluate_windows

    short = tmp_path / "short.h5"
    write_events(short, sim_window(5, sensor_size=(48, 64), window_events=500).events)
    with pytest.warns(EvmotionWarning, match="short.h5: .* give no window"):
        # (it blamed the crop: 'no training window kept 500 events in a 48x64 crop')
        with pytest.raises(ParameterError, match="none of the 1 recording.* holds a window"):
            train(TrainConfig(**{**TINY, "sim_windows": 0, "recordings": [str(short)]}),
                  tmp_path / "a")
    assert not (tmp_path / "a").exists()  # nor an empty folder
    # all events at one time: trained on (loss 116 where a window's is ~4), and validated
    ev = sim_window(5, sensor_size=(48, 64), window_events=3000).events
    instant = tmp_path / "instant.h5"
    write_events(instant, EventArray(ev.x, ev.y, np.full(len(ev), 1000), ev.p,
                                     sensor_size=ev.sensor_size))
    with pytest.warns(EvmotionWarning, match=r"instant.h5: .* 1 window with all events at "
                                              r"one time \(0 us\)\): not used"):
        with pytest.raises(ParameterError, match="none of the 1 recording.* holds a window"):
            train(TrainConfig(**{**TINY, "sim_windows": 0, "recordings": [str(instant)],
                                 "window_events": 3000}), tmp_path / "c")
    lines = []
    train(TrainConfig(epochs=1, **TINY), tmp_path / "b")
    summary = train(TrainConfig(epochs=1, **TINY), tmp_path / "b", resume=True,
                    log=lines.append)
    assert summary["epoch"] == 0 and "already trained 1 of 1 epochs" in lines[0]
    net = EVFlowNet(width=0.0625)
    with torch.no_grad():
        net.heads[0].bias.fill_(float("nan"))
    with pytest.raises(ParameterError, match="diverged"):
        evaluate_windows(net, [sim_window(6, sensor_size=(48, 64), window_events=2000)])


def test_resume_rewrites_what_an_interruption_left_behind(tmp_path):
    """Interrupted between last.pt and model.pt of the final epoch, --resume said 'nothing
    to do' and left model.pt (and the logs) an epoch behind; it now writes them from
    last.pt. The epochs' lr column is the rate each trained at (it was the next one)."""
    cfg = TrainConfig(epochs=2, **TINY)
    train(cfg, tmp_path / "a")
    ref = _weights(tmp_path / "a" / "model.pt")
    train(TrainConfig(epochs=1, **TINY), tmp_path / "b")
    stale = (tmp_path / "b" / "model.pt").read_bytes()
    train(cfg, tmp_path / "b", resume=True)
    (tmp_path / "b" / "model.pt").write_bytes(stale)  # as if killed after last.pt
    (tmp_path / "b" / "epochs.csv").unlink()
    train(cfg, tmp_path / "b", resume=True)
    got = _weights(tmp_path / "b" / "model.pt")
    assert all(torch.equal(ref[k], got[k]) for k in ref)
    rows = list(csv.DictReader(open(tmp_path / "b" / "epochs.csv")))
    assert [float(r["lr"]) for r in rows] == pytest.approx([cfg.lr, cfg.lr * cfg.lr_decay])


def test_resume_and_out_are_checked(tmp_path):
    """A damaged last.pt was a traceback; another folder's model.pt was overwritten; the
    recordings were told apart by the path string only (another file at the same path
    resumed silently, the same file spelled otherwise was refused)."""
    from evmotion.errors import EvmotionWarning
    from evmotion.events import EventArray
    from evmotion.io import write_events

    rng = np.random.default_rng(0)
    n = 12000
    rec = tmp_path / "rec.h5"
    write_events(rec, EventArray(x=rng.integers(0, 64, n), y=rng.integers(0, 48, n),
                                 t=np.sort(rng.integers(0, 100_000, n)), p=rng.integers(0, 2, n),
                                 sensor_size=(48, 64)))
    cfg = {**TINY, "sim_windows": 1, "recordings": [str(rec)]}
    run = tmp_path / "run"
    with pytest.warns(EvmotionWarning, match=r"--val .*rec.h5: also trained on"):
        # (probe BG: a training recording given as --val was scored as held out, unsaid)
        first = train(TrainConfig(epochs=1, **{**cfg, "val_recordings": [str(rec)]}),
                      tmp_path / "val")
    # a --val recording's FWL on its own (it was only in the mean with the simulated ones)
    assert np.isfinite(first["val_rec_FWL"]) and first["val_rec_FWL"] != first["val_FWL"]
    train(TrainConfig(epochs=1, **cfg), run)
    # the same file by another path: resumed
    train(TrainConfig(epochs=2, **{**cfg, "recordings": [str(tmp_path / "." / "rec.h5")]}), run,
          resume=True)
    # the same bytes written again (a touch, a copy without -p): resumed (probe BG: its
    # modification time had refused it)
    rec.write_bytes(rec.read_bytes())
    os.utime(rec, ns=(1, 1))
    train(TrainConfig(epochs=2, **cfg), run, resume=True)
    # another file at the path: refused
    write_events(rec, EventArray(x=rng.integers(0, 64, n), y=rng.integers(0, 48, n),
                                 t=np.sort(rng.integers(0, 100_000, n)), p=rng.integers(0, 2, n),
                                 sensor_size=(48, 64)))
    with pytest.raises(ParameterError, match="rec.h5 changed since"):
        train(TrainConfig(epochs=3, **cfg), run, resume=True)
    (run / "last.pt").write_bytes(b"garbage")
    with pytest.raises(ParameterError, match="not a readable training checkpoint"):
        train(TrainConfig(epochs=3, **cfg), run, resume=True)
    other = tmp_path / "other"
    other.mkdir()
    (other / "model.pt").write_bytes(b"someone's")
    with pytest.raises(ParameterError, match="holds model.pt but no training"):
        train(TrainConfig(epochs=1, **TINY), other)
    assert (other / "model.pt").read_bytes() == b"someone's"


@pytest.mark.parametrize("held, match", [("model.pt", "holds model.pt but no training"),
                                          ("last.pt", "already holds a training")])
def test_cli_refuses_a_taken_folder_before_importing_torch(tmp_path, monkeypatch, capsys,
                                                          held, match):
    """The refusal took 4.7 s, torch's import and the trainer's, before it was said."""
    import evmotion.methods.dnn as dnn
    from evmotion.cli import main

    def no_torch(feature=""):
        raise AssertionError("torch was reached before the folder's check")

    monkeypatch.setattr(dnn, "require_torch", no_torch)
    (tmp_path / held).write_bytes(b"someone's")
    assert main(["train", "--out", str(tmp_path), "--sim-windows", "2"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err, err


@pytest.mark.parametrize("bad, match", [({"seed": 2000}, "seed must be below 2000"),
                                        ({"lr": 2.0}, "lr must be at most 1")])
def test_seeds_of_the_validation_scenes_and_runaway_rates_are_refused(bad, match):
    with pytest.raises(ParameterError, match=match):
        TrainConfig(**{**TINY, **bad}).check()


def test_interrupted_before_the_first_epoch_leaves_no_folder(tmp_path, capsys, monkeypatch):
    """Ctrl-C before the first checkpoint left an empty --out folder, which a later
    --resume took for a training ('no checkpoint'); a folder that was there stays."""
    import evmotion.methods.dnn.train as dnn_train
    from evmotion.cli import main

    def interrupted(cfg, out_dir, **k):
        Path(out_dir).mkdir(parents=True, exist_ok=True)  # as train() does once its data loads
        raise KeyboardInterrupt

    monkeypatch.setattr(dnn_train, "train", interrupted)
    argv = ["train", "--sim-windows", "2", "--epochs", "1", "--out"]
    assert main(argv + [str(tmp_path / "new")]) == 130
    assert not (tmp_path / "new").exists()
    (tmp_path / "mine").mkdir()
    assert main(argv + [str(tmp_path / "mine")]) == 130
    assert (tmp_path / "mine").is_dir()
    assert capsys.readouterr().err.count("evmotion: interrupted\n") == 2


def test_crops_find_events_gathered_in_a_corner():
    """2000 events in a 20 x 20 px corner of a 1280 x 720 sensor: every blind crop missed
    them, and a training failed or not by its seed; the crops around an event find them."""
    from evmotion.events import EventArray
    from evmotion.methods.dnn.data import TrainWindow

    rng = np.random.default_rng(0)
    n = 2000
    ev = EventArray(x=rng.integers(1200, 1220, n), y=rng.integers(690, 710, n),
                    t=np.sort(rng.integers(0, 10_000, n)), p=rng.integers(0, 2, n),
                    sensor_size=(720, 1280))
    for seed in range(10):
        got = crop_window(TrainWindow(ev, None, "corner"), (176, 240),
                          np.random.default_rng(seed), min_events=1000)
        assert got is not None and len(got.events) == n and got.events.sensor_size == (176, 240)


def test_a_recording_shorter_than_half_a_window_is_said(tmp_path):
    """It was trained on as one short window without a word (probe CK)."""
    from evmotion.errors import EvmotionWarning
    from evmotion.io import write_events
    from evmotion.methods.dnn.data import recording_windows

    ev = sim_window(5, sensor_size=(48, 64), window_events=4000).events
    write_events(tmp_path / "rec.h5", ev)
    with pytest.warns(EvmotionWarning, match=rf"{len(ev)} events, fewer than half a window "
                                             r"of --window-events 40000"):
        (win,) = recording_windows([tmp_path / "rec.h5"], 40_000)
    assert len(win.events) == len(ev)


def test_recordings_take_the_readers_format_and_sensor_size(tmp_path):
    """A text recording of a 48x64 sensor reads as the ECD's 240x180 unless its size is
    given; the reader's errors name --format and --sensor-size, which train now has."""
    from evmotion.cli import main
    from evmotion.io import write_events
    from evmotion.methods.dnn.data import recording_windows

    ev = sim_window(5, sensor_size=(48, 64), window_events=4000).events
    text = tmp_path / "rec.txt"
    write_events(text, ev)
    text.write_text("".join(ln for ln in text.read_text().splitlines(True)
                            if not ln.startswith("#")))  # as other tools write ECD text
    assert recording_windows([text], 4000)[0].events.sensor_size == (180, 240)
    (win,) = recording_windows([text], 4000, format="ecd", sensor_size=(48, 64))
    assert win.events.sensor_size == (48, 64) and len(win.events) == len(ev)
    with pytest.raises(ParameterError, match=r"^training recording \S*rec.txt: no '%'"):
        recording_windows([text], 4000, format="evt3")
    rc = main(["train", str(text), "--format", "ecd", "--sensor-size", "48", "64",
               "--out", str(tmp_path / "t"), "--sim-windows", "0", "--val-sim", "0",
               "--window-events", "4000", "--crop", "48x64", "--width", "0.0625",
               "--batch-size", "1", "--epochs", "1", "--max-steps", "1"])
    assert rc == 0 and (tmp_path / "t" / "model.pt").is_file()


def test_a_full_device_at_a_checkpoint_is_one_line(tmp_path, capsys, monkeypatch):
    # torch's zip writer said only 'unexpected pos 125760 vs 125656' (a traceback)
    import shutil

    from evmotion.cli import main

    real_usage = shutil.disk_usage

    def short_write(obj, f, *a, **k):
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 1 vs 2")

    monkeypatch.setattr(torch, "save", short_write)
    monkeypatch.setattr(shutil, "disk_usage",
                        lambda p: real_usage(p)._replace(free=4096))
    rc = main(["train", "--out", str(tmp_path / "t"), "--sim-windows", "2", "--val-sim", "0",
               "--window-events", "4000", "--crop", "48x64", "--width", "0.0625",
               "--batch-size", "2", "--epochs", "1", "--max-steps", "1"])
    err = capsys.readouterr().err
    assert rc == 1 and err.count("\n") == 1 and "no space left" in err, err


def test_cli_train_format_needs_recordings_and_a_known_name(tmp_path, capsys):
    """--format bogus with no recording to read had passed (exit 0; probe)."""
    from evmotion.cli import main

    base = ["train", "--sim-windows", "1", "--epochs", "1", "--val-sim", "0",
            "--out", str(tmp_path / "run")]
    assert main([*base, "--format", "h5"]) == 2
    assert "does not apply without recordings" in capsys.readouterr().err
    assert main([*base, "--format", "bogus"]) == 2
    assert "argument --format: unknown format 'bogus'" in capsys.readouterr().err
    rec = tmp_path / "rec.npz"
    np.savez(rec, x=[1, 2], y=[1, 2], t=[0, 10], p=[1, 0], sensor_size=[8, 8])
    assert main([*base, str(rec), "--format", "bogus"]) == 2
    assert "unknown format 'bogus'" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def test_init_weights_that_cannot_start_a_training_are_named(tmp_path, monkeypatch):
    """Probe BG: NaN weights trained one step, then 'training diverged ... a lower --lr, or
    --resume from the last good epoch' (there was none) after a torch UserWarning, and
    left an empty folder; a model.npz gave torch's '[enforce fail at inline_container...'.
    A training that diverges before its first epoch names no epoch to resume from."""
    from evmotion.methods.dnn.model import save_model

    net = EVFlowNet(width=0.0625)
    with torch.no_grad():
        net.heads[0].bias.fill_(float("nan"))
    save_model(tmp_path / "nan.pt", net)
    cfg = {k: v for k, v in TINY.items() if k != "val_sim"}
    with pytest.raises(ParameterError, match=r"--init-weights .*nan.pt: its weights are not "
                       r"all finite"):
        train(TrainConfig(epochs=1, val_sim=0, init_weights=str(tmp_path / "nan.pt"), **cfg),
              tmp_path / "run")
    (tmp_path / "m.npz").write_bytes(b"PK\x03\x04not really")
    with pytest.raises(ParameterError, match=r"m.npz: the numpy export .* give the model.pt"):
        train(TrainConfig(epochs=1, val_sim=0, init_weights=str(tmp_path / "m.npz"), **cfg),
              tmp_path / "run")
    import warnings

    from evmotion.methods.dnn import train as dnn_train

    def nan_loss(flows, probs):
        return flows[0].sum() * float("nan")  # a tensor that requires its gradient

    monkeypatch.setattr(dnn_train, "multiscale_loss", nan_loss)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # torch's "Converting a tensor ..."
        with pytest.raises(ParameterError, match=r"diverged: the loss is nan at epoch 0, "
                                                 r"step 0 .* lower --lr; nothing was written"):
            train(TrainConfig(epochs=1, val_sim=0, **cfg), tmp_path / "run")
    assert not (tmp_path / "run").exists()


def test_a_network_no_better_than_the_zero_flow_is_said(tmp_path, monkeypatch):
    # the run announced its best epoch without a word at AEE 5.124 px against the zero
    # flow's 5.109 (probe CE)
    import evmotion.methods.dnn.train as tr
    from evmotion.errors import PoorFitWarning

    scores = [{"loss": 1.0, "FWL": 1.0, "AEE_px": 5.124, "AEE_zero_px": 5.109}]
    monkeypatch.setattr(tr, "evaluate_windows", lambda *a, **k: scores)
    with pytest.warns(PoorFitWarning, match=r"no better than the zero flow \(AEE 5.124 px "
                                            r"against 5.109\)"):
        train(TrainConfig(epochs=1, **TINY), tmp_path / "a")
    scores[0]["AEE_px"] = 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", PoorFitWarning)
        train(TrainConfig(epochs=1, **TINY), tmp_path / "b")


def test_train_says_a_sensor_size_that_replaces_a_stated_one(tmp_path, monkeypatch, capsys):
    """Its --sensor-size help promised the warning the other commands give; train read
    its recordings without it (review CR)."""
    import evmotion.methods.dnn.train as tr
    from evmotion.cli import main
    from evmotion.io import write_events

    write_events(tmp_path / "rec.h5", sim_window(5, sensor_size=(48, 64),
                                                  window_events=4000).events)
    monkeypatch.setattr(tr, "train", lambda *a, **k: {"epoch": 0, "step": 0,
                                                     "train_loss": 1.0})
    assert main(["train", str(tmp_path / "rec.h5"), "--sensor-size", "60", "80",
                 "--sim-windows", "0", "--out", str(tmp_path / "run")]) == 0
    assert "--sensor-size 60 80 replaces the 64 x 48 px (W x H)" in capsys.readouterr().err


def test_loss_picture_gives_validation_its_own_axes_and_counts_steps_done():
    """loss.png: the validation loss (finest scale) and the AEE against the zero flow's
    on axes of their own, not the training loss' (a sum over 4 scales); per-step points at
    the steps done, where the epochs' are (probe DA: off by one, no AEE drawn)."""
    import matplotlib.pyplot as plt

    from evmotion.methods.dnn.train import _loss_figure

    steps = [{"epoch": k // 2, "step": k, "loss": 4.0 - 0.1 * k, "lr": 1e-3} for k in range(4)]
    epochs = [{"epoch": e, "step": 2 * e + 2, "train_loss": 3.9 - 0.2 * e, "val_loss": 1.0,
               "val_AEE_px": 1.5, "val_AEE_zero_px": 1.7} for e in range(2)]
    fig = _loss_figure(steps, epochs)
    try:
        ax_train, ax_loss, ax_aee = fig.axes
        per_step, per_epoch = ax_train.get_lines()
        assert list(per_step.get_xdata())[1::2] == list(per_epoch.get_xdata()) == [2, 4]
        assert ax_aee.get_ylabel() == "validation AEE [px]"
        assert [ln.get_label() for ln in ax_aee.get_lines()] == ["network", "zero flow"]
        assert ax_loss.get_ylabel() == "validation loss"
    finally:
        plt.close(fig)
    fig = _loss_figure(steps, [{k: v for k, v in r.items() if not k.startswith("val")}
                               for r in epochs])
    assert len(fig.axes) == 1
    plt.close(fig)
