"""egomotion on a recording longer than a block (evmotion.cli.windowed): read as a stream,
a block of windows at a time, it gives the outputs of the recording read whole, and
resumes as it does (the block size made small here, so that the test's recordings span
many blocks)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import evmotion.cli.calib as calib
import evmotion.cli.windowed as windowed
import evmotion.streamed_windows as streamed_windows
from _helpers import interrupt_at_call, with_hot_pixels
from egomotion_synth import synth
from evmotion.cli import main
from evmotion.events import EventArray, concatenate
from evmotion.io import write_events


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    parts = []
    for k in range(6):
        a, _ = synth("translation", [300.0 - 40 * k, -150.0], n_events=4000, seed=k)
        parts.append(EventArray(a.x, a.y, a.t + 55_000 * k, a.p, a.sensor_size, validate=False))
    ev = concatenate(parts, validate=False)
    ev = EventArray(np.round(ev.x).astype(np.uint16), np.round(ev.y).astype(np.uint16),
                    ev.t, ev.p, ev.sensor_size)
    # two hot pixels holding 5 % of the events: said, or dropped with --remove-hot-pixels
    ev = with_hot_pixels(ev, [120, 150], [90, 60], 600)
    folder = tmp_path_factory.mktemp("streamed")
    write_events(folder / "rec.h5", ev)  # its header states the count
    write_events(folder / "rec.txt", ev)  # and this one's does not
    # an ECD folder whose lens moves 20 % of the events off the image (said, either way)
    (folder / "ecd").mkdir()
    write_events(folder / "ecd" / "events.txt", ev)
    (folder / "ecd" / "calib.txt").write_text("100 100 119.5 89.5 -0.6 0.2 0 0 0\n")
    return folder


def _streamed(monkeypatch, block=5000, chunk=1700):
    """Blocks of ``block`` events read in chunks of ``chunk``, for any file; returns the
    list the blocks made are counted in."""
    monkeypatch.setattr(streamed_windows, "BLOCK_EVENTS", block)
    monkeypatch.setattr(windowed, "MIN_EVENT_BYTES", 0)
    monkeypatch.setattr(calib, "CHUNK_EVENTS", chunk)
    made = []
    real = streamed_windows.window_blocks

    def counted(*a, **k):
        for item in real(*a, **k):
            made.append(len(item[0]))
            yield item

    monkeypatch.setattr(streamed_windows, "window_blocks", counted)
    return made


def _outputs(out):
    """params.csv less its timing column, and the panels written."""
    rows = [ln.split(",") for ln in (out / "params.csv").read_text().splitlines()]
    drop = rows[0].index("seconds")
    return ([r[:drop] + r[drop + 1:] for r in rows],
            sorted(p.name for p in out.glob("window_*.png")))


CASES = [
    ["--window-events", "2000"],
    ["--window-us", "15000"],
    ["--window-events", "1500", "--t0", "30ms", "--t1", "170ms"],
    ["--window-us", "12000", "--t0", "25ms", "--remove-hot-pixels"],
    ["--window-events", "2500", "--workers", "2"],
    ["--window-events", "3000", "--warm-start", "--max-png", "2"],
]


@pytest.mark.parametrize("extra", CASES, ids=lambda a: " ".join(a[:2] + a[2:3]))
@pytest.mark.parametrize("name", ["rec.h5", "rec.txt", "ecd"])
def test_streamed_outputs_are_those_of_the_whole_read(recording, tmp_path, monkeypatch,
                                                      capsys, extra, name):
    if name != "rec.h5" and ("--workers" in extra or "--warm-start" in extra):
        pytest.skip("one format is enough for the workers and the warm start")
    argv = ["egomotion", str(recording / name), "--warp", "translation", "--max-png", "3",
            *extra]
    assert main(argv + ["--out", str(tmp_path / "whole")]) == 0
    whole_err = capsys.readouterr().err
    made = _streamed(monkeypatch)
    assert main(argv + ["--out", str(tmp_path / "streamed")]) == 0
    streamed_err = capsys.readouterr().err
    assert len(made) >= 3 and max(made) <= 5000 + 3000  # several blocks, none held whole
    rows, panels = _outputs(tmp_path / "whole")
    assert _outputs(tmp_path / "streamed") == (rows, panels)
    assert len(rows) > 4
    # the same lines said (hot pixels, dropped or not), but for the bars
    said = [[ln for ln in err.splitlines() if "evmotion:" in ln]
            for err in (whole_err, streamed_err)]
    assert said[0] == said[1]
    assert any("hot pixels" in ln for ln in said[0])
    assert any("undistortion moved" in ln for ln in said[0]) == (name == "ecd")


def test_streamed_run_resumes_and_refuses_a_changed_recording(recording, tmp_path,
                                                               monkeypatch, capsys):
    import evmotion.cli.egomotion as ego

    argv = ["egomotion", str(recording / "rec.h5"), "--warp", "translation",
            "--window-events", "2000", "--max-png", "0", "--json"]
    assert main(argv + ["--out", str(tmp_path / "whole")]) == 0
    whole = json.loads(capsys.readouterr().out)["windows"]
    made = _streamed(monkeypatch)
    out = tmp_path / "o"
    calls = interrupt_at_call(monkeypatch, ego, "_window_job", 6)
    assert main(argv + ["--out", str(out)]) == 130
    capsys.readouterr()
    assert (out / "params.part").exists() and len(made) >= 2
    monkeypatch.undo()
    made = _streamed(monkeypatch)
    calls = interrupt_at_call(monkeypatch, ego, "_window_job", 10**9)
    assert main(argv + ["--out", str(out), "--resume"]) == 0
    resumed = json.loads(capsys.readouterr().out)["windows"]
    assert len(calls) == len(whole) - 5  # only the windows the first run did not finish

    def values(rows):
        return [(r["window"], r["t0_us"], r["t1_us"], r["params"]) for r in rows]

    assert values(resumed) == values(whole)
    # a recording changed after the interruption, in a window past the first block
    calls = interrupt_at_call(monkeypatch, ego, "_window_job", 6)
    assert main(argv + ["--out", str(out)]) == 130
    capsys.readouterr()
    from evmotion.io import read_events

    ev = read_events(recording / "rec.h5")
    x = ev.x.copy()
    x[5000] = (x[5000] + 1) % ev.width
    changed = tmp_path / "changed.h5"
    write_events(changed, EventArray(x, ev.y, ev.t, ev.p, ev.sensor_size))
    argv[1] = str(changed)
    assert main(argv + ["--out", str(out), "--resume"]) == 2
    err = capsys.readouterr().err
    assert "the events of window 2" in err and "recording changed" in err
