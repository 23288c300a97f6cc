"""CLI: evmotion egomotion / landscape / segment on a small synthetic recording and on a
real ECD window."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from _helpers import interrupt_at_call, with_hot_pixels
from egomotion_synth import synth
from evmotion.cli import main
from evmotion.events import concatenate
from evmotion.io import write_events


@pytest.fixture
def rec(tmp_path):
    a, _ = synth("translation", [300.0, -150.0], n_events=6000, seed=0)
    b, _ = synth("translation", [300.0, -150.0], n_events=6000, seed=1)
    b = type(b)(b.x, b.y, b.t + 50_000, b.p, b.sensor_size, validate=False)
    ev = concatenate([a, b], validate=False)
    # integer sensor coordinates, as a camera would give
    ev = type(ev)(np.round(ev.x).astype(np.uint16), np.round(ev.y).astype(np.uint16), ev.t,
                  ev.p, ev.sensor_size)
    path = tmp_path / "rec.h5"
    write_events(path, ev)
    return path


def test_egomotion_json_csv_h5_png(rec, tmp_path, capsys):
    out = tmp_path / "ego"
    rc = main(["egomotion", str(rec), "--warp", "translation", "--window-us", "50000",
               "--out", str(out), "--json", "--max-png", "1"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["windows"]) == 2 and not doc["failed"]
    for w in doc["windows"]:
        assert w["units"] == {"vx": "px/s", "vy": "px/s"}
        assert abs(w["params"]["vx"] - 300) < 10 and abs(w["params"]["vy"] + 150) < 10
    lines = (out / "params.csv").read_text().splitlines()
    assert lines[0].startswith("window,t0_us,t1_us,t_ref_us,n_events,vx [px/s],vy [px/s]")
    assert len(lines) == 3
    with h5py.File(out / "params.h5") as f:
        assert f["params"].shape == (2, 2)
        assert list(f.attrs["param_names"]) == ["vx", "vy"]
    assert (out / "window_00000.png").stat().st_size > 0
    assert not (out / "window_00001.png").exists()


def test_egomotion_errors(rec, tmp_path, capsys):
    rc = main(["egomotion", str(rec), "--warp", "rotation", "--window-us", "50000",
               "--out", str(tmp_path / "o")])
    assert rc == 2
    assert "intrinsics" in capsys.readouterr().err
    rc = main(["egomotion", str(rec), "--warp", "zoom", "--window-us", "-5",
               "--out", str(tmp_path / "o")])
    assert rc == 2


@pytest.mark.realdata
def test_egomotion_ecd_folder_picks_up_calibration(shared_data, tmp_path, capsys):
    folder = shared_data / "ecd_rotation_windows" / "poster_rotation"
    if not folder.is_dir():
        pytest.skip(f"{folder} missing")
    rc = main(["egomotion", str(folder), "--warp", "rotation", "--reg", "rcad",
               "--window-events", "30000", "--t-ref", "mid", "--out", str(tmp_path / "e"),
               "--json", "--max-png", "0"])
    assert rc == 0
    w = json.loads(capsys.readouterr().out)["windows"][0]
    omega = np.array([w["params"][k] for k in ("wx", "wy", "wz")])
    imu = np.loadtxt(folder / "motion.txt")
    assert np.sqrt(np.mean((omega - imu) ** 2)) < 0.12
    # eval says the same against the folder's motion.txt (the IMU's over the window)
    assert main(["eval", str(tmp_path / "e"), "--gt", str(folder), "--json"]) == 0
    rms = json.loads(capsys.readouterr().out)["parameters_rms"]
    assert rms["omega"] == pytest.approx(np.linalg.norm(omega - imu), rel=1e-6)


def test_landscape_png_and_csv(rec, tmp_path, capsys):
    png, csv_path = tmp_path / "land.png", tmp_path / "land.csv"
    rc = main(["landscape", str(rec), "--warp", "translation", "--param", "vx", "--range",
               "0", "600", "--steps", "31", "--reg", "rcad", "--window-events", "5000",
               "--out", str(png), "--csv", str(csv_path)])
    assert rc == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    data = np.loadtxt(csv_path, delimiter=",", skiprows=1)
    assert data.shape == (31, 4)
    assert csv_path.read_text().splitlines()[0].startswith("vx [px/s],no regularizer")
    assert abs(data[np.argmin(data[:, 1]), 0] - 300) <= 20
    assert main(["landscape", str(rec), "--warp", "translation", "--param", "hz", "--range",
                 "0", "1", "--out", str(png)]) == 2
    # a negative bound in scientific notation is a number, not an option (argparse alone
    # said "expected 2 arguments")
    assert main(["landscape", str(rec), "--warp", "translation", "--param", "vx", "--range",
                 "-3e2", "6e2", "--steps", "4", "--window-events", "5000", "--out", str(png),
                 "--csv", str(csv_path)]) == 0
    assert np.loadtxt(csv_path, delimiter=",", skiprows=1)[0, 0] == -300


def test_segment_cli(rec, tmp_path, capsys):
    out = tmp_path / "seg"
    rc = main(["segment", str(rec), "--warp", "translation", "--warps", "2", "--window-us",
               "50000", "--max-windows", "1", "--iterations", "3", "--out", str(out), "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["clusters"]) == 2
    assert (out / "clusters.csv").exists() and (out / "window_00000.png").exists()
    # each cluster says whether it is a measurement, in the JSON, the CSV and the .h5
    header = (out / "clusters.csv").read_text().splitlines()[0]
    assert header.endswith(",contrast_gain,valid,collapsed,chance_gain,chance_z")
    assert all(isinstance(c["valid"], bool) and c["contrast_gain"] > 0
               for c in doc["clusters"])
    with np.load(out / "labels.npz") as z:
        assert z["window_00000"].max() <= 1
        # which events they label (undistortion may drop some of the recording's)
        assert z["window_00000_t_us"].shape == z["window_00000"].shape
        assert z["window_00000_x"].shape == z["window_00000"].shape
        assert doc["clusters"][0]["t0_us"] <= z["window_00000_t_us"][0]
        # and per cluster what the JSON says (labels alone read as two motions where a
        # cluster repeats the other; probe Z)
        assert z["window_00000_valid"].tolist() == [c["valid"] for c in doc["clusters"]]
        assert z["window_00000_same_as"].tolist() == [c["same_as"] for c in doc["clusters"]]


def _whole_then_interrupted(argv, key, n_rows, job, journal, tmp_path, capsys, monkeypatch):
    """Run ``argv`` whole (its JSON's ``key``: ``n_rows`` rows), then into ``cut/`` with
    ``job`` = (module, function, n) interrupted at its n-th call, which must keep
    ``cut/<journal>``; returns the whole run's rows, the job's call list and ``cut/``."""
    assert main(argv + ["--out", str(tmp_path / "whole")]) == 0
    whole = json.loads(capsys.readouterr().out)[key]
    assert len(whole) == n_rows
    calls = interrupt_at_call(monkeypatch, *job)
    out = tmp_path / "cut"
    assert main(argv + ["--out", str(out)]) == 130
    assert "kept in" in capsys.readouterr().err and (out / journal).exists()
    return whole, calls, out


def test_segment_resume_after_an_interrupt(rec, tmp_path, capsys, monkeypatch):
    """segment wrote its outputs at the end only: an interrupted run lost every window
    (probe AD). The finished windows are kept in OUT/segment.part; --resume segments the
    others only and gives the clusters of an uninterrupted run."""
    import evmotion.cli.segment as seg

    argv = ["segment", str(rec), "--warp", "translation", "--warps", "2", "--window-us",
            "20000", "--max-windows", "3", "--iterations", "3", "--json"]
    whole, calls, out = _whole_then_interrupted(argv, "clusters", 6, (seg, "_segment_job", 3),
                                                "segment.part", tmp_path, capsys, monkeypatch)
    assert not (out / "clusters.csv").exists() and not list(out.glob("window_*.png"))
    assert main(argv + ["--out", str(out)]) == 2
    assert "--resume to continue" in capsys.readouterr().err
    assert main(argv + ["--out", str(out), "--resume", "--seed", "1"]) == 2
    assert "other seed" in capsys.readouterr().err
    calls.clear()
    assert main(argv + ["--out", str(out), "--resume"]) == 0
    resumed = json.loads(capsys.readouterr().out)["clusters"]
    assert len(calls) == 1 and not (out / "segment.part").exists()
    assert resumed == whole
    assert sorted(p.name for p in out.glob("window_*.png")) == [
        "window_00000.png", "window_00001.png", "window_00002.png"]
    # interrupted before any window: no journal, and no output folder it made
    interrupt_at_call(monkeypatch, seg, "_segment_job", 1)
    assert main(argv + ["--out", str(tmp_path / "none")]) == 130
    capsys.readouterr()
    assert not (tmp_path / "none").exists()


def test_egomotion_job_draws_its_panel_and_sends_no_images(rec, tmp_path):
    """A window up to the last PNG's start draws its panel in the job (a worker), the
    others none; no result carries IWEs or maps back (nothing reads them; 0.7 MB a
    window), and the estimate is the library's."""
    from evmotion.cli.egomotion import _window_job
    from evmotion.io import read_events
    from evmotion.methods.egomotion import estimate_egomotion
    from evmotion.viz import read_png

    ev = read_events(rec)
    w0, w1 = ev.windows_by_duration(50_000)[:2]
    kw = dict(warp="translation", objective="variance", reg="divergence", weight=None,
              optimizer="bfgs", K=None, t_ref="start", seed=0, dataset=None,
              last_png_t0_us=w0.t0)
    drawn = _window_job(ev.window(w0), w0.t0, w0.t1, **kw)
    assert drawn.panel[:4] == b"\x89PNG"
    assert drawn.result.iwe_after is None and drawn.result.maps == {}
    left = _window_job(ev.window(w1), w1.t0, w1.t1, **kw)
    assert left.panel is None
    assert left.result.iwe_before is None and left.result.iwe_after is None
    full = estimate_egomotion(ev.window(w1), "translation", regularizer="divergence",
                              t_ref="start")
    assert left.result.params.tobytes() == full.params.tobytes()
    assert left.result.cost == full.cost and left.result.diagnostics == full.diagnostics
    none = _window_job(ev.window(w0), w0.t0, w0.t1, **{**kw, "last_png_t0_us": None})
    assert none.panel is None
    assert none.result.params.tobytes() == drawn.result.params.tobytes()
    # the panel decodes: the IWE without and with the warp, in one row: a translation's
    # DIWE and IWA, 0 everywhere, are said in the title, not drawn (two blank panels were
    # half the picture, probe DA)
    png = tmp_path / "p.png"
    png.write_bytes(drawn.panel)
    h, w = read_png(png).shape[:2]
    assert w > 2 * ev.width and h < 0.75 * w


def test_egomotion_panel_title_says_when_not_a_measurement(rec):
    """A window's panel, looked at alone, says when its estimate is not a measurement."""
    import dataclasses

    from evmotion.cli.egomotion import _panel_title
    from evmotion.io import read_events
    from evmotion.methods.egomotion import estimate_egomotion
    from evmotion.viz.titles import duration_text

    ev = read_events(rec)
    w = ev.windows_by_duration(50_000)[0]
    r = estimate_egomotion(ev.window(w), "translation")
    assert r.valid and "NOT A MEASUREMENT" not in _panel_title(r, w.t0, w.t1)
    # the window as params.csv has it (probe BX: the first and last events, closed)
    assert _panel_title(r, w.t0, w.t1).startswith(
        f"translation, {r.n_events:,} events, [{w.t0:,}, {w.t1:,}) µs ({duration_text(w.t1 - w.t0)})")
    assert _panel_title(dataclasses.replace(r, collapsed=True), w.t0, w.t1).endswith(
        "NOT A MEASUREMENT: event collapse (valid = False)")
    poor = dataclasses.replace(r, diagnostics={**r.diagnostics, "too_few_events": True})
    assert "NOT A MEASUREMENT: poor fit" in _panel_title(poor, w.t0, w.t1)


def test_egomotion_png_panels_of_first_windows_less_failed(rec, tmp_path):
    """--max-png N draws the first N windows; one that failed has no panel and does not
    pass its turn to a later window (whose images were not kept)."""
    from evmotion.cli.egomotion import _window_job, _written, write_outputs
    from evmotion.io import read_events

    ev = read_events(rec)
    w0, w1 = ev.windows_by_duration(50_000)[:2]
    kw = dict(warp="translation", objective="variance", reg=None, weight=None,
              optimizer="bfgs", K=None, t_ref="start", seed=0, dataset=None)
    for folder, last in (("a", w0.t0), ("b", w1.t0)):
        out = tmp_path / folder
        out.mkdir()
        r1 = _written(out, w1, _window_job(ev.window(w1), w1.t0, w1.t1, **kw,
                                           last_png_t0_us=last))
        rows = write_outputs(out, [(w0, None, "RuntimeError: x"), (w1, r1, None)])
        assert [r["window"] for r in rows] == [w1.index]
    assert not list((tmp_path / "a").glob("*.png"))
    assert [p.name for p in (tmp_path / "b").glob("*.png")] == [f"window_{w1.index:05d}.png"]


def test_a_rerun_leaves_no_stale_pictures(rec, tmp_path, capsys):
    """A second run with fewer windows into the same folder left the first run's
    window_00001.png beside its own (egomotion, segment, flow --png-dir alike)."""
    out = tmp_path / "ego"
    argv = ["egomotion", str(rec), "--warp", "translation", "--window-us", "50000",
            "--out", str(out)]
    assert main(argv + ["--max-png", "2"]) == 0
    (out / "notes.png").write_bytes(b"mine")
    assert (out / "window_00001.png").is_file()
    assert main(argv + ["--max-png", "1"]) == 0
    assert (out / "window_00000.png").is_file() and not (out / "window_00001.png").exists()
    assert (out / "notes.png").read_bytes() == b"mine"
    png = tmp_path / "png"
    flow = ["flow", str(rec), "--scales", "2", "--out", str(tmp_path / "f.h5"), "--png-dir",
            str(png)]
    assert main(flow + ["--window-us", "50000"]) == 0
    assert (png / "flow_00001.png").is_file()
    assert main(flow + ["--window-us", "100000"]) == 0
    assert (png / "flow_00000.png").is_file() and not (png / "flow_00001.png").exists()
    capsys.readouterr()


def test_sensor_size_of_a_text_file_without_one(tmp_path, capsys):
    """Text events without a size got the ECD's 240x180 silently: the zoom warp then turned
    about the wrong centre (hz 0.35 for 0.8 on a 128x128 recording); --sensor-size gives
    the true one, in egomotion and flow alike."""
    from evmotion.io import read_events

    sim = tmp_path / "z.h5"
    assert main(["simulate", "zoom", "--size", "100x100", "--duration", "0.05",
                 "--out", str(sim)]) == 0
    ev = read_events(sim)
    txt = tmp_path / "z.txt"
    np.savetxt(txt, np.c_[ev.t * 1e-6, ev.x, ev.y, ev.p], fmt=["%.6f", "%d", "%d", "%d"])
    capsys.readouterr()
    argv = ["egomotion", str(txt), "--warp", "zoom", "--window-events", "5000",
            "--max-windows", "1", "--out", str(tmp_path / "o"), "--json"]
    assert main(argv) == 0
    assert "states no sensor size: taken as 240x180" in capsys.readouterr().err
    assert main([*argv, "--sensor-size", "100", "100"]) == 0
    cap = capsys.readouterr()
    assert "states no sensor size" not in cap.err
    assert main(["flow", str(txt), "--sensor-size", "100", "100", "--max-windows", "1",
                 "--window-events", "5000", "--scales", "2", "--out",
                 str(tmp_path / "f.h5"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["sensor_size"] == [100, 100]


def test_landscape_says_what_its_minimum_is(tmp_path, capsys):
    """On noise the curve is flat and its 'minimum at vx = 0' was printed as any other;
    with --reg only the unregularized minimum was reported; a window shorter than asked
    was not said."""
    noise = _noise_recording(tmp_path / "noise.h5", 20_000)
    out = tmp_path / "l.png"
    # (a range that keeps the events on the sensor: pushing noise off its edges raises the
    # variance of what is left, a contrast that is no motion)
    assert main(["landscape", str(noise), "--warp", "translation", "--param", "vx", "--range",
                 "-5", "5", "--steps", "11", "--out", str(out), "--json"]) == 0
    cap = capsys.readouterr()
    doc = json.loads(cap.out)
    assert doc["flat"] and doc["best_contrast_gain"] < 1.05 and "flat:" in cap.err
    assert "holds 20,000 events, not the 30,000 asked" in cap.err
    assert main(["landscape", str(noise), "--warp", "zoom", "--param", "hz", "--range", "-5",
                 "30", "--steps", "15", "--reg", "divergence", "--out", str(out),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["minimum_with_regularizer"] is not None


@pytest.mark.parametrize("extra", [[], ["--warm-start"]])
def test_egomotion_resume_after_an_interrupt(rec, tmp_path, capsys, monkeypatch, extra):
    """egomotion wrote its outputs at the end only: an interrupted run lost every window.
    The finished windows are now kept in OUT/params.part; --resume estimates the others
    only, and gives the numbers of an uninterrupted run."""
    import evmotion.cli.egomotion as ego

    argv = ["egomotion", str(rec), "--warp", "translation", "--window-events", "2000",
            "--max-png", "0", "--json", *extra]
    whole, calls, out = _whole_then_interrupted(argv, "windows", 6, (ego, "_window_job", 4),
                                                "params.part", tmp_path, capsys, monkeypatch)
    assert not (out / "params.csv").exists()
    # without --resume the kept windows are not overwritten
    assert main(argv + ["--out", str(out)]) == 2
    assert "--resume to continue" in capsys.readouterr().err
    # other options: refused, naming them
    assert main(argv + ["--out", str(out), "--resume", "--objective",
                        "gradient_magnitude"]) == 2
    assert "other objective" in capsys.readouterr().err
    calls.clear()
    assert main(argv + ["--out", str(out), "--resume"]) == 0
    resumed = json.loads(capsys.readouterr().out)["windows"]
    assert len(calls) == 3 and not (out / "params.part").exists()
    keys = ("window", "t0_us", "t1_us", "n_events", "params", "cost", "valid")
    assert [{k: r[k] for k in keys} for r in resumed] == [{k: r[k] for k in keys}
                                                          for r in whole]


@pytest.mark.parametrize("command", ["egomotion", "segment"])
def test_resume_checks_every_kept_window_s_events(rec, tmp_path, capsys, monkeypatch,
                                                   command):
    """The journal knew the recording by its first window only: events changed after it
    were resumed as if unchanged, the kept results describing other events (probe BH).
    Each kept window's events are now checked."""
    import pickle

    import evmotion.cli.egomotion as ego
    import evmotion.cli.segment as seg
    from evmotion.io import read_events

    if command == "egomotion":
        argv = ["egomotion", str(rec), "--warp", "translation", "--window-events", "2000",
                "--max-png", "0", "--json"]
        job, journal, key, n = (ego, "_window_job", 4), "params.part", "windows", 6
    else:
        argv = ["segment", str(rec), "--warp", "translation", "--warps", "2",
                "--window-events", "2000", "--max-windows", "4", "--iterations", "2",
                "--json"]
        job, journal, key, n = (seg, "_segment_job", 3), "segment.part", "clusters", 8
    _, _, out = _whole_then_interrupted(argv, key, n, job, journal, tmp_path, capsys,
                                        monkeypatch)
    monkeypatch.undo()
    ev = read_events(rec)
    p = ev.p.copy()
    p[2500:2600] ^= 1  # within the second window: the first's events stay as they were
    write_events(rec, type(ev)(ev.x, ev.y, ev.t, p, ev.sensor_size))
    assert main(argv + ["--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "the events of window 1 " in err and "the recording changed" in err, err
    assert (out / journal).exists()
    # a journal of the layout before these digests: refused by name, not misread
    with open(out / journal, "rb") as fh:
        head, first = pickle.load(fh), pickle.load(fh)
    (out / journal).write_bytes(pickle.dumps((head[0], 1, head[2]))
                                + pickle.dumps(first[:3] + first[4:]))
    assert main(argv + ["--out", str(out), "--resume"]) == 2
    assert "journal of another version of evmotion" in capsys.readouterr().err


def test_egomotion_without_a_window_option_takes_flows_default(rec, tmp_path, capsys):
    # it demanded one of --window-events / --window-us where flow has a default
    rc = main(["egomotion", str(rec), "--warp", "translation", "--out", str(tmp_path / "e"),
               "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["windows"]) == 1 and doc["windows"][0]["n_events"] == 12_000


@pytest.mark.parametrize("left", [b"", b"\x80\x05\x95"])
def test_a_journal_with_no_window_does_not_block_the_next_run(rec, tmp_path, capsys, left):
    # a full disk at the first write left a 0-byte params.part: the next run was refused
    # ('holds the windows of an interrupted run') and --resume called it not a journal
    out = tmp_path / "e"
    out.mkdir()
    (out / "params.part").write_bytes(left)
    argv = ["egomotion", str(rec), "--warp", "translation", "--window-events", "6000",
            "--max-png", "0", "--out", str(out)]
    assert main(argv) == 0
    assert (out / "params.csv").exists() and not (out / "params.part").exists()
    (out / "params.part").write_bytes(left)
    # an interrupted run's panel beside it (probe BH: it was published as this run's)
    (out / "panels.part").mkdir()
    (out / "panels.part" / "window_00000.png").write_bytes(b"an earlier run's panel")
    assert main(argv + ["--resume"]) == 0
    err = capsys.readouterr().err
    # (it said "params.part does not exist" of the journal it had found empty)
    assert "params.part held no finished window" in err, err
    assert sorted(p.name for p in out.iterdir()) == ["params.csv", "params.h5"]


def test_poor_fit_lines_stop_after_five_and_suggest_longer_windows(tmp_path, capsys):
    # 419 windows of an HD recording printed 419 'no focus' lines at once, each naming the
    # tpe optimizer though bfgs ran
    from evmotion.events import EventArray

    rng = np.random.default_rng(0)
    n = 12_000
    noise = EventArray(x=rng.integers(0, 60, n), y=rng.integers(0, 40, n),
                       t=np.sort(rng.integers(0, 10**6, n)), p=rng.integers(0, 2, n),
                       sensor_size=(40, 60))
    write_events(tmp_path / "noise.h5", noise)
    assert main(["egomotion", str(tmp_path / "noise.h5"), "--warp", "translation",
                 "--window-events", "1000", "--max-png", "0", "--out", str(tmp_path / "e")]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "window" in ln]
    assert sum(ln.startswith("evmotion: warning: window ") for ln in lines) == 5
    assert "more warnings of other windows" in lines[-1] and "too short" in lines[-1]
    assert not any("the tpe optimizer" in ln for ln in lines)


def test_an_interrupted_rerun_keeps_the_previous_results(rec, tmp_path, capsys, monkeypatch):
    """A new run deleted the folder's complete results as it started, so interrupting it
    lost them (probe X). They now stay until the new run's replace them; the interrupted
    run's panels wait beside its journal, and --resume moves them in at the end."""
    import evmotion.cli.egomotion as ego

    out = tmp_path / "e"
    argv = ["egomotion", str(rec), "--warp", "translation", "--window-events", "2000",
            "--out", str(out)]
    assert main(argv) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    assert "params.h5" in before and "window_00000.png" in before
    interrupt_at_call(monkeypatch, ego, "_window_job", 4)
    assert main(argv + ["--objective", "gradient_magnitude"]) == 130
    capsys.readouterr()
    for name, data in before.items():
        assert (out / name).read_bytes() == data
    assert (out / "params.part").exists() and any((out / "panels.part").iterdir())
    monkeypatch.undo()
    assert main(argv + ["--objective", "gradient_magnitude", "--resume"]) == 0
    # how much it reused (probe BH: only bos said it)
    assert "windows (3 kept from the interrupted run) -> " in capsys.readouterr().out
    assert not (out / "panels.part").exists() and not (out / "params.part").exists()
    assert (out / "params.h5").read_bytes() != before["params.h5"]
    assert sorted(p.name for p in out.glob("window_*.png")) == sorted(
        n for n in before if n.startswith("window_"))


def test_a_failed_window_says_why(rec, tmp_path, capsys, monkeypatch):
    # the text output said only "; 1 failed": the reason was in --json alone
    import evmotion.cli.egomotion as cli_ego
    from evmotion.io import read_events

    job = cli_ego._window_job
    second = int(read_events(rec).t[0]) + 50_000

    def failing(events, t0, t1, **kw):
        if t0 >= second:
            raise RuntimeError("deliberate failure")
        return job(events, t0, t1, **kw)

    monkeypatch.setattr(cli_ego, "_window_job", failing)
    rc = main(["egomotion", str(rec), "--warp", "translation", "--window-us", "50000",
               "--max-windows", "2", "--out", str(tmp_path / "e")])
    out = capsys.readouterr()
    assert rc == 0 and "1 window" in out.out and "1 failed" in out.out
    assert "window 1: RuntimeError: deliberate failure (no row" in out.err


def test_a_run_interrupted_before_any_window_leaves_nothing(rec, tmp_path, capsys,
                                                           monkeypatch):
    # it left an empty panels.part/ in the output folder it had made (probe AD)
    import evmotion.cli.egomotion as ego

    out = tmp_path / "new" / "e"
    interrupt_at_call(monkeypatch, ego, "_window_job", 1)
    assert main(["egomotion", str(rec), "--warp", "translation", "--window-events", "2000",
                 "--out", str(out)]) == 130
    capsys.readouterr()
    assert not out.exists()
    kept = tmp_path / "mine"
    kept.mkdir()
    (kept / "notes.txt").write_text("mine")
    monkeypatch.undo()
    interrupt_at_call(monkeypatch, ego, "_window_job", 1)
    assert main(["egomotion", str(rec), "--warp", "translation", "--window-events", "2000",
                 "--out", str(kept)]) == 130
    capsys.readouterr()
    assert [p.name for p in kept.iterdir()] == ["notes.txt"]


def test_remove_hot_pixels_drops_them_before_the_windows(tmp_path, capsys):
    """Hot pixels hold a warp at rest (probe AH: 4 at 1.5 kHz stopped 9 of 11 windows) and
    the command had no way to drop them, which the library has. --remove-hot-pixels drops
    their events, says how many, and the windows are estimated without them."""
    ev, _ = synth("translation", [300.0, -150.0], n_events=12000, seed=0)
    both = with_hot_pixels(ev, [20, 100, 200], [30, 90, 150], 3000)
    path = tmp_path / "hot.h5"
    write_events(path, both)
    argv = ["egomotion", str(path), "--warp", "translation", "--window-events", "21000",
            "--max-png", "0", "--json"]
    assert main(argv + ["--out", str(tmp_path / "a"), "--remove-hot-pixels"]) == 0
    cap = capsys.readouterr()
    assert "dropped 3 hot pixels (9,000 of 21,000 events)" in cap.err
    (win,) = json.loads(cap.out)["windows"]
    assert win["n_events"] == 12000 and win["valid"]
    assert np.allclose(list(win["params"].values()), [300.0, -150.0], atol=15.0)


def test_windows_of_time_left_out_for_want_of_events_are_said(tmp_path, capsys):
    # a 10 ms pause in the events: egomotion's CSV went from window 3 to 5 (probe)
    from evmotion.events import EventArray

    rng = np.random.default_rng(0)
    t = np.sort(rng.integers(0, 50_000, 6000))
    t = t[(t < 20_000) | (t >= 30_000)]
    ev = EventArray(x=rng.integers(0, 60, t.size), y=rng.integers(0, 40, t.size), t=t,
                    p=rng.integers(0, 2, t.size), sensor_size=(40, 60))
    write_events(tmp_path / "gap.h5", ev)
    assert main(["egomotion", str(tmp_path / "gap.h5"), "--warp", "translation",
                 "--window-us", "5ms", "--max-png", "0", "--out", str(tmp_path / "e")]) == 0
    err = capsys.readouterr().err
    assert ("gap.h5: 2 of the first 10 windows hold fewer than 10 event(s) and are left out"
            in err), err


def test_rotation_without_intrinsics_is_one_line(tmp_path, capsys):
    """A text recording with no size and no calibration: the rotation warp was warned to
    turn about the image centre (it turns about K's principal point), then refused
    (probe AW); the refusal alone is said."""
    rows = "".join(f"{k * 1e-4:.6f} {k % 50} {k % 40} {k % 2}\n" for k in range(3000))
    (tmp_path / "e.txt").write_text(rows)
    rc = main(["egomotion", str(tmp_path / "e.txt"), "--warp", "rotation", "--out",
               str(tmp_path / "o")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "needs camera intrinsics" in err[0], err


def test_landscape_says_a_regularized_minimum_at_the_range_edge(tmp_path, capsys,
                                                                monkeypatch):
    """rcad's minimum at the range's edge (past a zoom's 1/T the penalty falls and the
    image flips) was said as the cure of the unregularized one (probe AW)."""
    import evmotion.methods.egomotion as ego

    rec = _noise_recording(tmp_path / "r.h5", 5000)
    real = ego.cost_landscape

    def fake(events, w, j, values, theta, objective, reg, *a, **kw):
        out = real(events, w, j, values, theta, objective, reg, *a, **kw)
        if reg is not None:  # a regularized curve falling to the range's end
            out = {**out, "cost": -np.arange(len(values), dtype=float)}
        return out

    monkeypatch.setattr(ego, "cost_landscape", fake)
    assert main(["landscape", str(rec), "--warp", "zoom", "--param", "hz", "--range", "-5",
                 "30", "--steps", "8", "--reg", "rcad", "--out", str(tmp_path / "l.png"),
                 "--json"]) == 0
    cap = capsys.readouterr()
    doc = json.loads(cap.out)
    assert doc["minimum_with_regularizer"] == 30.0 and doc["minimum_with_regularizer_at_edge"]
    assert "with rcad the minimum (hz = 30" in cap.err and "moves the minimum" not in cap.err


def _noise_recording(path, n: int):
    """``n`` seeded uniform noise events on 80 x 60 px over 0.1 s, written to ``path``."""
    from evmotion.events import EventArray
    from evmotion.io import write_events

    rng = np.random.default_rng(0)
    write_events(path, EventArray(rng.integers(0, 80, n), rng.integers(0, 60, n),
                                  np.sort(rng.integers(0, 100_000, n)), rng.integers(0, 2, n),
                                  (60, 80)))
    return path


@pytest.mark.parametrize("command", ["egomotion", "segment"])
def test_an_interrupt_while_the_results_are_written_publishes_them_whole(
        rec, tmp_path, capsys, monkeypatch, command):
    """Probe BH: a Ctrl-C among the moves of the panels and the writes of the files left a
    rerun's params.csv beside the earlier run's params.h5 (egomotion), or clusters.csv and
    the pictures without labels.npz and clusters.h5 (segment), the journal kept, unnamed.
    The results are now written whole, then the interrupt lands."""
    import os
    import signal

    out = tmp_path / "e"
    argv = [command, str(rec), "--warp", "translation", "--window-events", "2000",
            "--out", str(out)]
    assert main(argv) == 0
    capsys.readouterr()
    real, fired = os.replace, []

    def then_ctrl_c(src, dst, *args, **kwargs):
        real(src, dst, *args, **kwargs)
        if not fired and os.path.dirname(src).endswith("panels.part") \
                and os.path.dirname(dst) == str(out):  # the first panel moved in
            fired.append(dst)
            signal.raise_signal(signal.SIGINT)

    if command == "segment":
        from evmotion.utils import atomic_write_bytes

        def written_then_ctrl_c(path, data):  # segment writes its panels in place
            atomic_write_bytes(path, data)
            if not fired:
                fired.append(path)
                signal.raise_signal(signal.SIGINT)

        import evmotion.utils
        monkeypatch.setattr(evmotion.utils, "atomic_write_bytes", written_then_ctrl_c)
    else:
        monkeypatch.setattr(os, "replace", then_ctrl_c)
    assert main(argv + ["--objective", "gradient_magnitude"]) == 130
    monkeypatch.undo()
    assert fired
    left = sorted(p.name for p in out.iterdir())
    assert not [n for n in left if n.endswith(".part")], left
    table = "params.h5" if command == "egomotion" else "clusters.h5"
    with h5py.File(out / table) as f:
        assert "gradient_magnitude" in str(dict(f.attrs)) or "gradient_magnitude" in str(
            {k: dict(v.attrs) for k, v in f.items()})
