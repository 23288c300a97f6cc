"""`evmotion info` and `evmotion convert` through the registry, on real and written files."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import evmotion.io as eio
from evmotion.cli import main
from evmotion.errors import FormatError, ParameterError, UnsortedError
from evmotion.events import EventArray


def _run(capsys, *argv):
    rc = main(list(argv))
    out = capsys.readouterr()
    return rc, out.out, out.err


def test_info_ecd_folder_json(capsys, shared_data):
    rc, out, _ = _run(capsys, "info", str(shared_data / "ecd_rotation_windows" /
                                          "boxes_rotation"), "--json")
    assert rc == 0
    d = json.loads(out)
    assert d["format"] == "ecd" and d["n_events"] == 30_000
    assert d["sensor_size"] == [180, 240] and "calibration" in d
    assert d["duration_s"] == pytest.approx((d["t_last_us"] - d["t_first_us"]) * 1e-6)


def test_info_text(capsys, shared_data):
    rc, out, _ = _run(capsys, "info", str(shared_data / "ecd_shapes_rotation_first120k" /
                                          "shapes_rotation.mat"))
    assert rc == 0
    assert "events:      120,000" in out and "240 x 180" in out


def test_convert_round_trips(tmp_path, capsys, shared_data):
    src = shared_data / "ecd_30k_windows" / "shapes_translation"
    ev = eio.read_events(src)
    rc, out, _ = _run(capsys, "convert", str(src), str(tmp_path / "a.h5"), "--json",
                      "--chunk-events", "7000")
    assert rc == 0 and json.loads(out)["n_events"] == 30_000
    rc, *_ = _run(capsys, "convert", str(tmp_path / "a.h5"), str(tmp_path / "b.txt"))
    assert rc == 0
    back = eio.read_events(tmp_path / "b.txt")
    for k in "xytp":
        np.testing.assert_array_equal(getattr(back, k), getattr(ev, k))
    assert eio.read_calibration(tmp_path / "a.h5")["fx"] == pytest.approx(
        eio.read_calibration(src)["fx"])


def test_convert_time_range(tmp_path, capsys, shared_data):
    src = shared_data / "ecd_30k_windows" / "boxes_translation"
    ev = eio.read_events(src)
    t0, t1 = int(ev.t[100]), int(ev.t[9000])
    rc, *_ = _run(capsys, "convert", str(src), str(tmp_path / "c.npz"), "--t0", f"{t0}us",
                  "--t1", f"{t1}us")
    assert rc == 0
    np.testing.assert_array_equal(eio.read_events(tmp_path / "c.npz").t,
                                  ev.slice_time(t0, t1).t)


def test_clear_errors(tmp_path, capsys):
    rc, _, err = _run(capsys, "info", str(tmp_path / "missing.h5"))
    assert rc == 2 and "missing.h5: no such file" in err and "Traceback" not in err
    bad = tmp_path / "events.txt"
    bad.write_text("0.1 1 2 1\n0.2 1 2\n")
    rc, _, err = _run(capsys, "convert", str(bad), str(tmp_path / "o.h5"))
    assert rc == 2 and "line 2 has 3 column" in err
    assert not (tmp_path / "o.h5").exists()
    rc, _, err = _run(capsys, "convert", str(bad), str(tmp_path / "o.xyz"))
    assert rc == 2 and ".xyz" in err


def test_other_formats_through_the_registry(tmp_path, capsys, shared_data):
    src = shared_data / "formats" / "davis346_short.aedat4"
    rc, out, _ = _run(capsys, "info", str(src), "--json")
    assert rc == 0
    d = json.loads(out)
    assert d["format"] == "aedat4" and d["n_events"] == 6_676 and d["sensor_size"] == [260, 346]
    rc, *_ = _run(capsys, "convert", str(src), str(tmp_path / "a.h5"), "--chunk-events", "1000")
    assert rc == 0
    ev, back = eio.read_events(src), eio.read_events(tmp_path / "a.h5")
    assert back.sensor_size == ev.sensor_size
    for k in "xytp":
        np.testing.assert_array_equal(getattr(back, k), getattr(ev, k))


def test_info_on_flow_file(tmp_path, capsys):
    from evmotion.io.flowfiles import FlowWriter

    with FlowWriter(tmp_path / "flow.h5", (6, 7)) as fw:
        fw.append(np.zeros((6, 7, 2)), 0, 10_000)
        fw.append(np.zeros((6, 7, 2)), 10_000, 20_000)
    rc, out, _ = _run(capsys, "info", str(tmp_path / "flow.h5"), "--json")
    d = json.loads(out)
    assert rc == 0 and d["format"] == "evmotion-flow" and d["windows"] == 2
    assert d["sensor_size"] == [6, 7] and d["duration_s"] == pytest.approx(0.02)


def test_convert_sort_mends_unsorted_timestamps(tmp_path, capsys):
    """An unsorted recording was refused everywhere with a hint (EventArray.sorted()) no
    command could follow; convert --sort sorts it (and the refusal names that)."""
    from evmotion.cli import main
    from evmotion.events import EventArray
    from evmotion.io import read_events, write_events

    t = np.arange(200, dtype=np.int64) * 10
    t[2], t[3] = t[3], t[2]  # one event out of order: a recorder's slip
    ev = EventArray(x=np.arange(200) % 8, y=np.zeros(200, int), t=t, p=np.arange(200) % 2,
                    sensor_size=(4, 8), validate=False)
    write_events(tmp_path / "u.h5", ev)
    assert main(["info", str(tmp_path / "u.h5")]) == 2
    assert "convert IN OUT --sort" in capsys.readouterr().err
    assert main(["convert", str(tmp_path / "u.h5"), str(tmp_path / "s.h5"), "--sort",
                 "--t1", "45us"]) == 0
    back = read_events(tmp_path / "s.h5")
    assert back.t.tolist() == [0, 10, 20, 30, 40] and back.x.tolist() == [0, 1, 3, 2, 4]


@pytest.mark.parametrize("out", ["o.txt", "o.raw", "o.npz", "o.h5"])
def test_convert_refuses_a_step_back_between_chunks_naming_the_input(tmp_path, capsys, out):
    """Each chunk read is sorted, but one starting before the previous one ended had gone
    into a text file unsaid (which reading then refused), and the other writers' refusals
    named no file (probe DJ)."""
    t = np.array([30, 10, 20, 10, 40])
    ev = EventArray(x=np.arange(5), y=np.ones(5, int), t=t, p=np.arange(5) % 2,
                    sensor_size=(180, 240), validate=False)
    eio.write_events(tmp_path / "uns.h5", ev)
    rc, _, err = _run(capsys, "convert", str(tmp_path / "uns.h5"), str(tmp_path / out),
                      "--chunk-events", "1")
    assert rc == 2 and not (tmp_path / out).exists()
    assert err.count("\n") == 1 and "uns.h5: timestamps are not sorted" in err, err
    assert "--sort" in err
    rc, _, _ = _run(capsys, "convert", str(tmp_path / "uns.h5"), str(tmp_path / out),
                    "--chunk-events", "1", "--sort")
    assert rc == 0 and eio.read_events(tmp_path / out).t.tolist() == [10, 10, 20, 30, 40]
    # the library's chunked writing refuses it too
    chunks = [ev[i:i + 1] for i in range(5)]
    with pytest.raises(UnsortedError, match=r"t\[0\]=30 > t\[1\]=10"):
        eio.write_events(tmp_path / "lib.txt", iter(chunks))
    assert not (tmp_path / "lib.txt").exists()


def test_info_sensor_size_rescues_a_header_that_cannot_size(tmp_path, capsys):
    """info --sensor-size still failed on the header ('unknown AEChip ... pass
    sensor_size') that convert --sensor-size read."""
    from evmotion.cli import main

    head = (b"#!AER-DAT2.0\r\n# Data format is int32 address, int32 timestamp (8 bytes "
            b"total), repeated for each event\r\n# AEChip: eu.seebetter.ini.chips.davis."
            b"DVXplorer\r\n")
    x, y, p, t = np.array([1, 600]), np.array([2, 400]), np.array([1, 0]), np.array([10, 20])
    rec = np.empty((2, 2), ">u4")
    rec[:, 0] = ((479 - y) << 22) | ((639 - x) << 12) | (p << 11)
    rec[:, 1] = t
    (tmp_path / "x.aedat").write_bytes(head + rec.tobytes())
    assert main(["info", str(tmp_path / "x.aedat")]) == 2
    assert "unknown AEChip" in capsys.readouterr().err
    assert main(["info", str(tmp_path / "x.aedat"), "--sensor-size", "480", "640"]) == 0
    assert "events:      2" in capsys.readouterr().out


def test_info_time_range_in_seconds_too(tmp_path, capsys):
    """info printed the time range in µs only, while --t0/--t1 take seconds: pasting it
    selected nothing. The seconds are given beside."""
    from evmotion.events import EventArray

    ev = EventArray(x=[0, 1], y=[0, 1], t=[11_200_224, 21_968_221], p=[1, 0],
                    sensor_size=(4, 4))
    eio.write_events(tmp_path / "r.h5", ev)
    assert main(["info", str(tmp_path / "r.h5")]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("time range"))
    assert "11,200,224 .. 21,968,221 us (11.200224 .. 21.968221 s" in line


def test_info_says_where_the_size_it_prints_came_from(tmp_path, capsys):
    # text events beyond the ECD's 240x180: the size is the largest coordinates', and info
    # said it came from the ECD default beside printing 346 x 260
    (tmp_path / "e.txt").write_text("0.001 345 0 1\n0.002 3 259 0\n")
    assert main(["info", str(tmp_path / "e.txt"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["sensor_size"] == [260, 346]
    assert info["sensor_size_from"].startswith("largest coordinate")


def test_convert_to_a_read_only_format_is_one_line(tmp_path, capsys):
    # --format-out mat crashed with a 25-line traceback (TypeError in the aux streams)
    src = tmp_path / "a.npz"
    np.savez(src, x=[1, 2], y=[1, 1], t=[0, 10], p=[1, 0], sensor_size=[10, 10])
    rc, _, err = _run(capsys, "convert", str(src), str(tmp_path / "o.h5"), "--format-out",
                      "mat")
    assert rc == 2 and len(err.strip().splitlines()) == 1
    assert "reads only" in err and "h5" in err


def test_convert_with_sensor_size_does_not_ask_for_it(tmp_path, capsys):
    # the aux streams' look at the file read it without the size and warned 'give the
    # true size (--sensor-size H W)' beside the --sensor-size given
    src = tmp_path / "a.npz"
    np.savez(src, x=[1, 2, 3], y=[1, 1, 3], t=[0, 10, 20], p=[1, 0, 1])
    rc, _, err = _run(capsys, "convert", str(src), str(tmp_path / "o.h5"), "--sensor-size",
                      "10", "10")
    assert rc == 0 and err == ""
    assert eio.read_events(tmp_path / "o.h5").sensor_size == (10, 10)


def test_landscape_of_noise_says_no_measurement(tmp_path, capsys):
    from evmotion import EventArray

    rng = np.random.default_rng(0)
    n = 30000
    eio.write_events(tmp_path / "n.h5", EventArray(
        x=rng.integers(0, 240, n), y=rng.integers(0, 180, n), t=np.sort(rng.integers(0, 20_000, n)),
        p=rng.integers(0, 2, n), sensor_size=(180, 240)))
    rc, out, err = _run(capsys, "landscape", str(tmp_path / "n.h5"), "--warp", "translation",
                        "--param", "vx", "--range", "-500", "500", "--steps", "21",
                        "--theta", "0,0", "--out", str(tmp_path / "l.png"))
    assert rc == 0 and "flat" in err
    assert "(no measurement: flat)" in out and (tmp_path / "l.png").stat().st_size > 0


def test_json_summary_lists_the_warnings_said_on_stderr(tmp_path, capsys):
    """A result flagged on stderr only looked normal to a program reading --json (probe V):
    the summary now lists every warning line of the run, and an empty list when none."""
    a = np.zeros(100, dtype=[("x", "<u2"), ("y", "<u2"), ("t", "<i8"), ("p", "u1")])
    a["t"], a["x"], a["y"] = np.arange(100) * 10, np.arange(100) % 30, 5
    np.save(tmp_path / "w.npy", a)
    assert main(["info", str(tmp_path / "w.npy"), "--json"]) == 0
    out, err = capsys.readouterr()
    said = [ln.removeprefix("evmotion: warning: ") for ln in err.splitlines()
            if ln.startswith("evmotion: warning: ")]
    assert said and json.loads(out)["warnings"] == said
    assert main(["info", str(tmp_path / "w.npy"), "--sensor-size", "6", "30", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []


@pytest.mark.parametrize("ext", ["raw", "dat", "aedat", "aedat4", "h5", "npz"])
def test_negative_times_round_trip(tmp_path, ext):
    # times before 0 (a clock zeroed at a trigger): EVT3 wrote a negative header offset
    # that its own reader refused, and DAT / AEDAT 2.0 refused to write them at all
    t = np.array([-4997, -12, 0, 4980, 9000], np.int64)
    ev = EventArray(x=[0, 1, 2, 3, 4], y=[0, 1, 2, 3, 4], t=t, p=[0, 1, 1, 0, 1],
                        sensor_size=(80, 100))
    eio.write_events(tmp_path / f"n.{ext}", ev)
    back = eio.read_events(tmp_path / f"n.{ext}")
    np.testing.assert_array_equal(back.t, t)
    np.testing.assert_array_equal(back.x, ev.x)


def test_negative_times_refused_by_ecd_text(tmp_path):
    ev = EventArray(x=[0, 1], y=[0, 1], t=[-5, 3], p=[0, 1], sensor_size=(80, 100))
    with pytest.raises(ParameterError, match="non-negative times"):
        eio.write_events(tmp_path / "n.txt", ev)


def test_read_events_says_where_the_events_are_when_the_span_holds_none(tmp_path):
    """An ECD excerpt starting at 13.58 s read from 0 returned nothing, unsaid (probe AI)."""
    ev = EventArray(x=[0, 1, 2], y=[0, 1, 2], t=[5000, 6000, 7000], p=[0, 1, 1],
                    sensor_size=(8, 8))
    eio.write_events(tmp_path / "r.h5", ev)
    with pytest.warns(UserWarning, match=r"no event in \[0, 100\) us: the recording spans "
                                         r"5000\.\.7000 us"):
        assert len(eio.read_events(tmp_path / "r.h5", t0=0, t1=100)) == 0


def test_convert_takes_out_as_the_other_commands_do(tmp_path, capsys):
    # 'convert in.h5 --out x.txt' said "unrecognized arguments: --out (did you mean
    # --sort?)": every other command names its output --out
    src = tmp_path / "in.npz"
    ev = EventArray(t=np.arange(10, dtype=np.int64) * 100, x=np.arange(10) % 4,
                    y=np.arange(10) % 3, p=np.arange(10) % 2, sensor_size=(3, 4))
    eio.write_events(src, ev)
    rc, *_ = _run(capsys, "convert", str(src), "--out", str(tmp_path / "o.txt"))
    assert rc == 0
    np.testing.assert_array_equal(eio.read_events(tmp_path / "o.txt").t, ev.t)
    rc, _, err = _run(capsys, "convert", str(src))
    assert rc == 2 and "as the second argument or as --out" in err
    rc, _, err = _run(capsys, "convert", str(src), str(tmp_path / "a.h5"), "--out",
                      str(tmp_path / "b.h5"))
    assert rc == 2 and "two outputs" in err and not (tmp_path / "a.h5").exists()


def test_convert_help_examples_cut_from_the_first_event(tmp_path, capsys, monkeypatch):
    """'convert rec.h5 out.aedat4 --t1 30ms' in --help cut nothing from a recording whose
    clock does not start near 0 (probe): its examples that cut a time range of rec.h5 run
    on one whose clock starts at 1000 s."""
    import shlex

    from evmotion.cli.convert import EXAMPLES

    n = 2000
    ev = EventArray(t=10**9 + np.arange(n, dtype=np.int64) * 50, x=np.arange(n) % 40,
                    y=np.arange(n) % 30, p=np.arange(n) % 2, sensor_size=(30, 40))
    eio.write_events(tmp_path / "rec.h5", ev)
    monkeypatch.chdir(tmp_path)
    lines = [shlex.split(line, comments=True)[1:] for line in EXAMPLES.splitlines()
             if line.strip().startswith("evmotion convert rec.h5")]
    cutting = [argv for argv in lines if "--t0" in argv or "--t1" in argv]
    assert cutting
    for argv in cutting:
        rc, _, err = _run(capsys, *argv)
        assert rc == 0, (argv, err)


@pytest.mark.parametrize("fmt", ["txt", "raw"])
def test_convert_progress_has_a_total_where_no_header_counts_events(tmp_path, capsys,
                                                                    monkeypatch, fmt):
    """Text and EVT RAW files state no event count: convert's bar counted events with no
    total, rate against nothing and no ETA; the share of the file read gives the total."""
    rng = np.random.default_rng(0)
    n = 6000
    ev = EventArray(x=rng.integers(0, 64, n), y=rng.integers(0, 48, n),
                    t=np.sort(rng.integers(0, 500_000, n)), p=rng.integers(0, 2, n),
                    sensor_size=(48, 64))
    src = tmp_path / f"ev.{fmt}"
    eio.write_events(src, ev, format="ecd" if fmt == "txt" else "evt3")
    monkeypatch.setenv("EVMOTION_PROGRESS", "1")
    assert main(["convert", str(src), str(tmp_path / "out.h5"), "--chunk-events", "500"]) == 0
    err = capsys.readouterr().err.replace("\r", "\n")
    # tqdm's "n/total [elapsed<left, rate]" (a bare "n [elapsed, rate]" without a total)
    shown = re.findall(r"([\d.]+k?)/([\d.]+k?) \[\d\d:\d\d<\d\d:\d\d", err)
    assert shown and shown[-1] == ("6.00k", "6.00k"), err[-500:]


@pytest.mark.parametrize("chunk", ["1000", "250"])  # the pause inside a chunk, or between
def test_convert_says_a_pause_that_looks_like_a_corrupt_time(tmp_path, capsys, chunk):
    # probe BL: one corrupt EVT3 time field moved half a file 16.8 s on; info and
    # read_events said so, convert wrote it unsaid
    from evmotion.io import write_events

    t = np.arange(1000) * 100
    t[500:] += 20_000_000
    write_events(tmp_path / "j.h5", EventArray(x=np.arange(1000) % 50, y=np.arange(1000) % 40,
                                               t=t, p=np.arange(1000) % 2,
                                               sensor_size=(40, 50)))
    assert main(["convert", str(tmp_path / "j.h5"), str(tmp_path / "j.txt"),
                 "--chunk-events", chunk]) == 0
    err = capsys.readouterr().err
    assert "no event for 20 s between events 499 and 500" in err, err


def test_a_recording_named_like_another_format_is_described_as_its_own(tmp_path, capsys):
    # probe BL: an EVT2 file named .aedat4 read as EVT2, but info added AEDAT4 frames'
    # "bad magic" error, the extension steering part of the description
    from evmotion.io import write_events

    write_events(tmp_path / "r.aedat4", EventArray(x=[1, 2], y=[0, 1], t=[10, 20], p=[1, 0],
                                                   sensor_size=(40, 50)), format="evt2")
    assert main(["info", str(tmp_path / "r.aedat4"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["format"] == "evt2" and "frames_info" not in doc


@pytest.mark.parametrize("name, data, argv", [
    ("bad.raw", b"garbage\n", ["--format", "evt3"]),
    ("empty.raw", b"", ["--format", "evt2"]),
    ("hdr.raw", b"% evt 3.0\n% end\n", []),
])
def test_info_on_a_raw_file_with_no_event_takes_the_size_given(tmp_path, capsys, name, data,
                                                                argv):
    # probe BY: following info's own advice (--format, --sensor-size) ended in a TypeError
    # traceback, the size given being nowhere in the summary
    (tmp_path / name).write_bytes(data)
    rc, out, err = _run(capsys, "info", str(tmp_path / name), *argv, "--sensor-size", "180",
                        "240")
    assert rc == 0, err
    assert "sensor:      240 x 180 px (W x H)" in out and "events:      0" in out
    rc, out, err = _run(capsys, "info", str(tmp_path / name), *argv, "--sensor-size", "180",
                        "240", "--json")
    assert rc == 0 and json.loads(out)["sensor_size"] == [180, 240]
    # --header-only too (probe CA: "unknown (... --sensor-size H W)" beside the size given)
    rc, out, err = _run(capsys, "info", str(tmp_path / name), *argv, "--sensor-size", "180",
                        "240", "--header-only")
    assert rc == 0 and "sensor:      240 x 180 px (W x H)" in out, out


def test_info_of_an_empty_raw_file_takes_the_size_given_over_its_header(tmp_path, capsys):
    # probe CA: a header's 1280x720 silently replaced --sensor-size 100 200, which the
    # readers take over the header
    path = tmp_path / "h.raw"
    path.write_bytes(b"% evt 3.0\n% format EVT3\n% geometry 1280x720\n% end\n")
    for extra in ([], ["--header-only"]):
        rc, out, err = _run(capsys, "info", str(path), "--sensor-size", "100", "200", *extra)
        assert rc == 0 and "sensor:      200 x 100 px (W x H)" in out, (extra, out, err)
    rc, out, _ = _run(capsys, "info", str(path))
    assert "sensor:      1280 x 720 px (W x H)" in out


def test_sensor_size_replacing_a_stated_one_is_said(tmp_path, capsys):
    """--sensor-size replaced the size a file's header states without a word (probe CI);
    for text that states none, it is what the option is for."""
    ev = EventArray(x=[1, 2, 3], y=[0, 1, 2], t=[0, 10, 20], p=[1, 0, 1], sensor_size=(30, 40))
    eio.write_events(tmp_path / "r.h5", ev)
    (tmp_path / "r.txt").write_text("0.000000 1 0 1\n0.000010 2 1 0\n0.000020 3 2 1\n")
    # a DAT header without a size, DSEC (which stores none): defaults, not stated sizes
    # (review CR: both were said to be replaced)
    eio.write_events(tmp_path / "r.dat", ev)
    data = (tmp_path / "r.dat").read_bytes()
    (tmp_path / "r.dat").write_bytes(b"".join(
        ln for ln in data.splitlines(keepends=True)
        if not ln.startswith((b"% Width", b"% Height", b"% geometry"))))
    eio.write_events(tmp_path / "r_dsec.h5", ev, format="dsec")
    import h5py

    with h5py.File(tmp_path / "r_dsec.h5", "r+") as f:
        for k in list(f.attrs):
            del f.attrs[k]
    for name, said in (("r.h5", True), ("r.txt", False), ("r.dat", False),
                       ("r_dsec.h5", False)):
        assert main(["view", str(tmp_path / name), "--sensor-size", "60", "80",
                     "--out", str(tmp_path / f"{name}.png")]) == 0
        err = capsys.readouterr().err
        assert ("--sensor-size 60 80 replaces" in err) is said, (name, err)
        assert not said or "the 40 x 30 px (W x H)" in err


@pytest.mark.parametrize("ext, fmt", [(".raw", "evt3"), (".raw", "evt2"), (".raw", "evt21"),
                                      (".dat", "dat"), (".aedat", "aedat2"),
                                      (".aedat", "aedat3")])
def test_binary_writers_refuse_times_out_of_order(tmp_path, ext, fmt):
    """The binary formats store times as steps or modulo a counter: an array built with
    validate=False out of order had come back with other times (EVT 3.0: 10 us read as
    16777226) or a bare ValueError (probe DJ)."""
    ev = EventArray(x=[1, 2, 3], y=[1, 1, 1], t=[20_000_000, 10, 30], p=[1, 0, 1],
                    sensor_size=(180, 240), validate=False)
    with pytest.raises(FormatError, match=r"out\S*: .*stores times in order: timestamps "
                                              r"are not sorted: t\[0\]=20000000 > t\[1\]=10"):
        eio.write_events(tmp_path / f"out{ext}", ev, format=fmt)
    assert not (tmp_path / f"out{ext}").exists()


def test_info_says_an_unreadable_calib_txt_once(tmp_path, capsys):
    """An ECD folder's calib.txt that is not numbers was said three times by ``info``: the
    reader's warning, the intrinsics line and a calibration_error line (carried from probe
    BOSIN). The intrinsics line says it; --json keeps the field; other commands still
    warn (they say nothing else of it)."""
    from evmotion.errors import UnusedCalibrationWarning
    from evmotion.io import read_events

    eio.write_events(tmp_path / "events.txt", EventArray(
        x=[1, 2, 3], y=[1, 2, 3], t=[0, 10, 20], p=[1, 0, 1], sensor_size=(4, 5)))
    (tmp_path / "calib.txt").write_text("foo bar\n")
    rc, out, err = _run(capsys, "info", str(tmp_path))
    assert rc == 0 and err == ""
    assert len(re.findall("must hold numbers", out)) == 1
    assert "intrinsics:  none (" in out and "calibration_error" not in out
    rc, out, _ = _run(capsys, "info", str(tmp_path), "--json")
    assert "must hold numbers" in json.loads(out)["calibration_error"]
    with pytest.warns(UnusedCalibrationWarning, match="must hold numbers"):
        read_events(tmp_path)


def test_info_shows_progress_over_a_long_read(tmp_path, capsys, monkeypatch):
    """info read a 97.5 M event file for 9-18 s without a word (probe DL): a bar with a
    total (from the header, or the share of an EVT RAW file read) now counts the events."""
    rng = np.random.default_rng(0)
    n = 30_000
    ev = EventArray(x=rng.integers(0, 40, n), y=rng.integers(0, 30, n),
                    t=np.sort(rng.integers(0, 10**6, n)), p=rng.integers(0, 2, n),
                    sensor_size=(30, 40))
    monkeypatch.setenv("EVMOTION_PROGRESS", "1")
    for name in ("rec.h5", "rec.raw"):
        eio.write_events(tmp_path / name, ev)
        rc, out, err = _run(capsys, "info", str(tmp_path / name))
        assert rc == 0 and "events:      30,000" in out
        bars = [b for b in err.replace("\r", "\n").splitlines() if b.startswith("info:")]
        assert bars and "30.0k/30.0k" in bars[-1] and "100%" in bars[-1], err
