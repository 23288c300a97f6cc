"""``--t0``/``--t1``/``--max-windows``: parsing (seconds by default, us/ms/s suffixes), the
library's window cropping (:func:`evmotion.events.make_windows`) against a plain-numpy
reference, and the one-line errors of the per-window commands."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest

from evmotion.cli import main
from evmotion.cli.options import time_us
from evmotion.errors import ParameterError
from evmotion.events import EventArray, make_windows
from evmotion.io import write_events


@pytest.mark.parametrize("text,us", [("1.5", 1_500_000), ("1500000us", 1_500_000),
                                     ("1500ms", 1_500_000), ("2s", 2_000_000), ("0", 0),
                                     ("250 µs", 250), ("1e-3", 1000), ("+2ms", 2000)])
def test_time_us_units(text, us):
    assert time_us(text) == us


@pytest.mark.parametrize("text", ["-1", "abc", "nan", "inf", "1.5h", "", "us", "+", "+-1"])
def test_time_us_rejects(text):
    with pytest.raises(argparse.ArgumentTypeError, match="time >= 0"):
        time_us(text)


def _events(n=1000, seed=0):
    rng = np.random.default_rng(seed)
    t = 5_000_000 + np.sort(rng.integers(0, 1_000_000, n))
    return EventArray(rng.integers(0, 40, n), rng.integers(0, 30, n), t, rng.integers(0, 2, n),
                      sensor_size=(30, 40))


def _check_windows(ev, windows, t0, t1):
    for w in windows:
        sl = ev.t[w.start:w.stop]
        # the window's events are exactly those of [w.t0, w.t1) within [t0, t1)
        mask = (ev.t >= max(w.t0, t0 or 0)) & (ev.t < min(w.t1, t1 or 2**62))
        np.testing.assert_array_equal(sl, ev.t[mask])


@pytest.mark.parametrize("t0,t1", [(None, None), (5_200_000, None), (None, 5_700_000),
                                   (5_200_123, 5_700_456)])
def test_make_windows_count_and_duration(t0, t1):
    ev = _events()
    inside = ev.t[(ev.t >= (t0 or 0)) & (ev.t < (t1 or 2**62))]
    by_count = make_windows(ev, n_events=64, t0=t0, t1=t1)
    assert sum(w.count for w in by_count) == inside.size
    assert all(w.count == 64 for w in by_count[:-1])
    assert by_count[0].t0 == inside[0]
    _check_windows(ev, by_count, t0, t1)
    by_time = make_windows(ev, duration_us=100_000, t0=t0, t1=t1)
    assert sum(w.count for w in by_time) == inside.size
    assert by_time[0].t0 == (t0 if t0 is not None else inside[0])
    if t1 is not None:
        assert by_time[-1].t1 <= t1
    _check_windows(ev, by_time, t0, t1)
    limited = make_windows(ev, duration_us=100_000, t0=t0, t1=t1, max_windows=2)
    assert limited == by_time[:2]


def test_make_windows_edges_min_events_and_errors():
    ev = _events()
    edges = np.arange(5_000_000, 6_000_001, 100_000)
    wins = make_windows(ev, edges_us=edges, t0=5_250_000, t1=5_800_000)
    # only the edge windows lying within [t0, t1), with their index in the full sequence
    assert [(w.t0, w.t1) for w in wins] == [(a, a + 100_000) for a in range(5_300_000,
                                                                          5_700_001, 100_000)]
    assert wins[0].index == 3
    big = make_windows(ev, duration_us=10_000, min_events=12)
    assert big and all(w.count >= 12 for w in big)
    with pytest.raises(ParameterError, match="t1"):
        make_windows(ev, n_events=10, t0=5, t1=5)
    with pytest.raises(ParameterError, match="exactly one"):
        make_windows(ev, n_events=10, duration_us=5)


@pytest.fixture
def rec(tmp_path):
    path = tmp_path / "rec.h5"
    write_events(path, _events(4000))
    return path


@pytest.mark.parametrize("argv,needles", [
    (["--t0", "7"], ["--t0 7 s (7000000 µs)", "after the last event", "[5.000", "µs)"]),
    (["--t1", "4.5"], ["--t1 4.5 s (4500000 µs)", "before the first event"]),
    (["--t0", "5.5", "--t1", "5.2"], ["--t1 5.2 s", "--t0 5.5 s"]),
    (["--t0", "5.5s", "--t1", "5500100us"], ["no window holds 10 events", "--t0 5.5 s",
                                               "--t1 5.5001 s", "spans"]),
    (["--t0", "-2"], ["argument --t0", "'-2'"]),
    (["--max-windows", "0"], ["argument --max-windows", "'0'"]),
])
def test_egomotion_time_errors_are_one_line(rec, tmp_path, capsys, argv, needles):
    rc = main(["egomotion", str(rec), "--warp", "translation", "--window-events", "200",
               "--out", str(tmp_path / "o"), *argv])
    err = capsys.readouterr().err
    assert rc == 2
    assert len(err.strip().splitlines()) == 1, err
    for needle in needles:
        assert needle in err, (needle, err)


def test_egomotion_t0_t1_max_windows(rec, tmp_path, capsys):
    ev = _events(4000)
    rc = main(["egomotion", str(rec), "--warp", "translation", "--window-us", "50000",
               "--t0", "5200ms", "--t1", "5.45", "--max-windows", "3", "--max-png", "0",
               "--out", str(tmp_path / "o"), "--json"])
    assert rc == 0
    rows = json.loads(capsys.readouterr().out)["windows"]
    assert [(r["t0_us"], r["t1_us"]) for r in rows] == [(5_200_000, 5_250_000),
                                                       (5_250_000, 5_300_000),
                                                       (5_300_000, 5_350_000)]
    for r in rows:
        assert r["n_events"] == int(((ev.t >= r["t0_us"]) & (ev.t < r["t1_us"])).sum())


def test_flow_and_segment_take_the_time_options(rec, tmp_path, capsys):
    from evmotion.io.flowfiles import read_flow_h5

    out = tmp_path / "f.h5"
    rc = main(["flow", str(rec), "--window-us", "100000", "--t0", "5.3", "--max-windows", "2",
               "--scales", "1", "--max-iter", "2", "--out", str(out)])
    cap = capsys.readouterr()
    assert rc == 0, cap.err
    assert cap.out.startswith("multicm: 2 windows, ")
    seq = read_flow_h5(out)
    assert list(np.asarray(seq.t0)) == [5_300_000, 5_400_000]
    rc = main(["segment", str(rec), "--warp", "translation", "--window-events", "500",
               "--t1", "5.2", "--max-windows", "5", "--iterations", "1",
               "--out", str(tmp_path / "seg"), "--json"])
    assert rc == 0
    rows = json.loads(capsys.readouterr().out)["clusters"]
    assert rows and max(r["t1_us"] for r in rows) <= 5_200_000
    assert len({r["window"] for r in rows}) <= 5


def test_times_after_the_first_event(rec, tmp_path, capsys):
    """``--t0 +TIME``: TIME after the recording's first event (a recording whose clock
    starts late needed its absolute times looked up with info first)."""
    from evmotion.io.flowfiles import read_flow_h5

    first = int(_events(4000).t[0])
    out = tmp_path / "f.h5"
    assert main(["flow", str(rec), "--window-us", "100000", "--t0", "+0.3", "--t1", "+500ms",
                 "--scales", "1", "--max-iter", "2", "--out", str(out)]) == 0
    seq = read_flow_h5(out)
    assert list(np.asarray(seq.t0)) == [first + 300_000, first + 400_000]
    assert int(np.asarray(seq.t1)[-1]) == first + 500_000
    capsys.readouterr()
    rc = main(["flow", str(rec), "--t0", "+3", "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "after the last event" in err
    assert main(["flow", str(rec), "--t0", "+x", "--out", str(out)]) == 2
    assert "got '+x'" in capsys.readouterr().err
    # a file that is no recording: the first event cannot be read, in one line
    rc = main(["kymogram", str(out), "--col", "3", "--t0", "+1ms", "--out",
               str(tmp_path / "k.png")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "cannot read the first event" in err


def test_flow_prints_one_summary_line(rec, tmp_path, capsys):
    ev = _events(4000)
    out = tmp_path / "f.h5"
    rc = main(["flow", str(rec), "--window-us", "100000", "--max-windows", "3", "--scales", "1",
               "--max-iter", "2", "--out", str(out)])
    cap = capsys.readouterr()
    assert rc == 0
    lines = cap.out.strip().splitlines()
    assert len(lines) == 1, cap.out
    n3 = int((ev.t < ev.t[0] + 300_000).sum())
    assert lines[0].startswith(f"multicm: 3 windows, {n3:,} events, ")
    assert lines[0].endswith(f" s -> {out}")
    rc = main(["flow", str(rec), "--method", "triplet", "--t1", "5.5",
               "--out", str(tmp_path / "t.npz")])
    line = capsys.readouterr().out.strip()
    assert rc == 0 and "\n" not in line
    assert line.startswith(f"triplet: {int((ev.t < 5_500_000).sum()):,} events, ")
    assert line.endswith(f" -> {tmp_path / 't.npz'}")
    # --json: the JSON alone on stdout
    rc = main(["flow", str(rec), "--method", "triplet", "--out", str(tmp_path / "t2.npz"),
               "--json"])
    assert rc == 0 and json.loads(capsys.readouterr().out)["events"] == 4000


def test_landscape_json_and_time_window(rec, tmp_path, capsys):
    ev = _events(4000)
    rc = main(["landscape", str(rec), "--warp", "translation", "--param", "vx", "--range",
               "-50", "50", "--steps", "5", "--t0", "5.25", "--window-events", "300",
               "--out", str(tmp_path / "l.png"), "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    i0 = int(np.searchsorted(ev.t, 5_250_000))
    assert doc["window"] == {"t0_us": int(ev.t[i0]), "t1_us": int(ev.t[i0 + 299]) + 1,
                             "n_events": 300}
    assert doc["values"] == [-50.0, -25.0, 0.0, 25.0, 50.0]
    assert len(doc["curves"]["no regularizer"]) == 5
    assert doc["minimum"] in doc["values"] and doc["param"] == "vx" and doc["unit"] == "px/s"
    rc = main(["landscape", str(rec), "--warp", "translation", "--range", "-1", "1",
               "--t0", "9", "--out", str(tmp_path / "l2.png")])
    err = capsys.readouterr().err
    assert rc == 2 and "--t0 9 s" in err and "spans" in err


def test_kymogram_out_of_range_names_the_recordings_span(rec, tmp_path, capsys):
    rc = main(["kymogram", str(rec), "--col", "3", "--t0", "7", "--out", str(tmp_path / "k.png")])
    err = capsys.readouterr().err
    assert rc == 2 and len(err.strip().splitlines()) == 1
    ev = _events(4000)
    assert "--t0 7 s (7000000 µs)" in err and f"[{ev.t[0]}, {ev.t[-1]}] µs" in err


def test_duration_windows_far_from_t0_or_across_a_pause():
    """--t0 0.5 s on a recording whose clock reads 1.6e9 s made 3e10 empty windows first
    (237 GiB asked of numpy); a pause of 2000 s at 1 ms windows, two million."""
    t = np.r_[1_600_000_000_000_000 + np.arange(0, 5000, 10),
              1_600_002_000_000_000 + np.arange(0, 5000, 10)]
    ev = EventArray(np.zeros(t.size, int), np.zeros(t.size, int), t, np.ones(t.size, int),
                    (4, 4))
    wins = make_windows(ev, duration_us=1000, t0=500_000)
    assert len(wins) == 10 and sum(w.count for w in wins) == t.size
    assert all((w.t0 - 500_000) % 1000 == 0 and w.t1 - w.t0 == 1000 for w in wins[:-1])
    assert wins[0].t0 <= t[0] < wins[0].t1 and wins[-1].t0 <= t[-1] < wins[-1].t1
    assert wins[5].index - wins[4].index == 2_000_000 - 4  # 2000 s of 1 ms windows
