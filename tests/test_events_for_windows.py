"""Reading only what the first --max-windows windows need (events_for_windows and the CLI's
read_for_windows) gives the windows, and the results, of reading the whole recording."""

from __future__ import annotations

import json

import numpy as np
import pytest

from evmotion.cli import main
from evmotion.events import EventArray, events_for_windows, make_windows
from evmotion.io import write_events


def _recording(n=60_000, gap=False, seed=0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 2_000_000, n))
    if gap:  # a pause of a second, and sparse stretches that hold windows of few events
        t = np.where(t > 700_000, t + 1_000_000, t)
    return EventArray(x=rng.integers(0, 64, n), y=rng.integers(0, 48, n), t=t,
                      p=rng.integers(0, 2, n), sensor_size=(48, 64))


def _chunks(ev, size):
    return (ev[i:i + size] for i in range(0, len(ev), size))


@pytest.mark.parametrize("cut", [{"n_events": 5000}, {"n_events": 7}, {"duration_us": 90_000},
                                 {"duration_us": 3_000}])
@pytest.mark.parametrize("n_max", [1, 3, 40])
@pytest.mark.parametrize("chunk", [1000, 25_000])
@pytest.mark.parametrize("gap", [False, True])
def test_same_windows_as_the_whole_stream(cut, n_max, chunk, gap):
    ev = _recording(gap=gap)
    t0 = 650_000
    sub = ev.slice_time(t0, None)
    kw = dict(max_windows=n_max, min_events=10, **cut)
    part = events_for_windows(_chunks(sub, chunk), t0=t0, **kw)
    whole = make_windows(ev, t0=t0, **kw)
    got = make_windows(part, t0=t0, **kw)
    shift = ev.index_at(t0)  # start/stop index the array given
    assert [(w.t0, w.t1, w.count) for w in got] == [(w.t0, w.t1, w.count) for w in whole]
    assert [w.start + shift for w in got] == [w.start for w in whole]
    assert len(part) < len(sub) or len(whole) < n_max  # it stopped early when it could


def test_empty_stream_and_bad_arguments():
    assert events_for_windows(iter(()), max_windows=2, n_events=5) is None
    with pytest.raises(Exception, match="exactly one"):
        events_for_windows(iter(()), max_windows=2)
    with pytest.raises(Exception, match="max_windows"):
        events_for_windows(iter(()), max_windows=0, n_events=5)


CALIB = "60 60 31.5 23.5 -0.3 0.1 0 0 0"


@pytest.mark.parametrize("cmd", [
    ["flow", "--method", "multicm", "--scales", "1", "--max-iter", "3", "--window-events",
     "4000"],
    ["flow", "--method", "multicm", "--scales", "1", "--max-iter", "3", "--window-us",
     "100ms"],
    ["egomotion", "--warp", "translation", "--window-events", "4000", "--max-png", "0"],
])
def test_cli_max_windows_reads_a_prefix_with_the_same_results(tmp_path, capsys, cmd,
                                                              monkeypatch):
    """The same windows and numbers with and without the prefix read (the whole recording
    read when events_for_windows finds nothing), with undistortion (calib.txt) in the
    way."""
    import evmotion.cli.calib as calib
    import evmotion.events

    folder = tmp_path / "ecd"
    folder.mkdir()
    ev = _recording(n=40_000)
    write_events(folder / "events.txt", ev)
    (folder / "calib.txt").write_text(CALIB + "\n")
    common = ["--max-windows", "2", "--t0", "+0.3", "--json"]
    outs = {}
    monkeypatch.setattr(calib, "CHUNK_EVENTS", 3000)
    read = []
    monkeypatch.setattr(calib, "undistort_for",
                        lambda args, events, _f=calib.undistort_for, **k:
                        read.append(len(events)) or _f(args, events, **k))
    for name in ("prefix", "whole"):
        if name == "whole":
            monkeypatch.setattr(evmotion.events, "events_for_windows", lambda *a, **k: None)
        out = tmp_path / (f"{name}.h5" if cmd[0] == "flow" else name)
        assert main([cmd[0], str(folder), *cmd[1:], *common, "--out", str(out)]) == 0
        outs[name] = json.loads(capsys.readouterr().out)
    a, b = outs["prefix"], outs["whole"]
    keys = ("t0_us", "t1_us", "events", "n_events", "focus", "params")
    rows = [[{k: r[k] for k in keys if k in r} for r in s["windows"]] for s in (a, b)]
    assert rows[0] == rows[1] and len(rows[0]) == 2 and len(rows[0][0]) >= 3, rows
    # only the fallback read the recording, and of it only the span --t0 selects
    assert read == [int(np.count_nonzero(ev.t >= ev.t[0] + 300_000))]


def test_landscape_reads_only_its_window(tmp_path, capsys, monkeypatch):
    """landscape takes the --window-events events from --t0: it read the whole recording
    for them (2.9 GB for one window of a 97.5 M-event file, probe DL). Now only the chunks
    they lie in, with the curves of the whole read."""
    import evmotion.cli.calib as calib
    import evmotion.events
    import evmotion.io

    ev = _recording(n=60_000)
    path = tmp_path / "rec.h5"
    write_events(path, ev)
    monkeypatch.setattr(calib, "CHUNK_EVENTS", 3000)
    argv = ["landscape", str(path), "--warp", "translation", "--range", "-50", "50",
            "--steps", "5", "--window-events", "4000", "--t0", "+0.3", "--json"]
    whole_reads = []
    real = evmotion.io.read_events
    monkeypatch.setattr(evmotion.io, "read_events",
                        lambda *a, **k: whole_reads.append(1) or real(*a, **k))
    got = {}
    for name in ("prefix", "whole"):
        if name == "whole":
            monkeypatch.setattr(evmotion.events, "events_for_windows", lambda *a, **k: None)
        assert main([*argv, "--out", str(tmp_path / f"{name}.png")]) == 0
        got[name] = json.loads(capsys.readouterr().out)
        got[name].pop("out")
        assert len(whole_reads) == (name == "whole")
    assert got["prefix"] == got["whole"]
    assert got["prefix"]["window"]["n_events"] == 4000
