"""``evmotion flow --method triplet``: streaming output (.npz sparse, .h5 dense), PNGs, JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest

import evmotion.io as eio
from evmotion.cli import main
from evmotion.events import EventArray
from evmotion.io.flowfiles import read_flow_h5
from evmotion.methods.triplet import TripletMatcher, estimate_flow_triplet


def edge_events(speed_px_s: float, size: int = 40) -> EventArray:
    """A vertical edge sweeping right: each pixel fires once when the edge reaches it."""
    yy, xx = np.mgrid[0:size, 0:size]
    t = np.rint(xx.ravel() / speed_px_s * 1e6).astype(np.int64)
    order = np.argsort(t, kind="stable")
    return EventArray(xx.ravel()[order], yy.ravel()[order], t[order], np.ones(t.size),
                      (size, size))


@pytest.fixture
def edge_file(monkeypatch, tmp_path):
    """A fake recording: the I/O layer is replaced by an in-memory chunked reader."""
    ev = edge_events(200.0, size=40)
    seen = {}

    def iter_events(path, chunk_events, **kw):
        seen["chunk_events"] = chunk_events
        for s in range(0, len(ev), chunk_events):
            yield ev[s:s + chunk_events]

    monkeypatch.setattr(eio, "iter_events", iter_events, raising=False)
    return tmp_path / "rec.dat", ev, seen


def test_sparse_npz_streams_and_matches_api(edge_file, tmp_path, capsys):
    path, ev, seen = edge_file
    out = tmp_path / "flow.npz"
    rc = main(["flow", str(path), "--method", "triplet", "--out", str(out),
               "--chunk-events", "333", "--json"])
    assert rc == 0 and seen["chunk_events"] == 333
    summary = json.loads(capsys.readouterr().out)
    assert summary["events"] == len(ev) and summary["overflow"] == 0
    # the keys every method's summary has
    assert summary["outputs"] == [str(out)] and summary["seconds"] > 0 and "n_windows" in summary
    ref = TripletMatcher(ev.sensor_size).process(ev)
    with np.load(out) as z:
        np.testing.assert_array_equal(z["vx"], ref.vx)
        np.testing.assert_array_equal(z["valid"], ref.valid)
        np.testing.assert_array_equal(z["t"], ev.t)
        np.testing.assert_array_equal(z["nx"], ref.nx)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_dense_h5_windows_and_pngs(edge_file, tmp_path):
    path, ev, _ = edge_file
    out = tmp_path / "flow.h5"
    rc = main(["flow", str(path), "--method", "triplet", "--out", str(out),
               "--window-us", "50000", "--chunk-events", "500",
               "--png-dir", str(tmp_path / "png")])
    assert rc == 0
    ref = estimate_flow_triplet(ev, ev.windows_by_duration(50_000))
    seq = read_flow_h5(out)
    assert seq.flow.shape == ref.flow.shape and seq.attrs["method"] == "triplet"
    np.testing.assert_array_equal(seq.valid, ref.valid)
    np.testing.assert_allclose(seq.flow, ref.flow, rtol=1e-5, atol=1e-3)
    np.testing.assert_array_equal(seq.t0, [w.t0 for w in ref.windows])
    # the last window ends with the data (its nominal end lay past the recording, beyond
    # any ground truth of it), as multicm's does
    ends = [w.t1 for w in ref.windows]
    ends[-1] = min(ends[-1], int(ev.t[-1]) + 1)
    assert ends[-1] < ref.windows[-1].t1
    np.testing.assert_array_equal(seq.t1, ends)
    pngs = sorted(p.name for p in (tmp_path / "png").iterdir())
    assert pngs[0] == "flow_00000.png" and f"iwe_{len(ref.windows) - 1:05d}.png" in pngs


def test_count_windows(edge_file, tmp_path):
    path, ev, _ = edge_file
    out = tmp_path / "flow.h5"
    assert main(["flow", str(path), "--method", "triplet", "--out", str(out),
                 "--window-events", "400", "--chunk-events", "170", "--bins", "2"]) == 0
    ref = estimate_flow_triplet(ev, ev.windows_by_count(400), n_bins=2)
    np.testing.assert_allclose(read_flow_h5(out).flow, ref.flow, rtol=1e-5, atol=1e-3)


def test_wider_filter_option(edge_file, tmp_path):
    path, ev, _ = edge_file
    out = tmp_path / "flow.h5"
    assert main(["flow", str(path), "--method", "triplet", "--out", str(out),
                 "--window-us", "50000", "--filter-size", "5"]) == 0
    ref = estimate_flow_triplet(ev, ev.windows_by_duration(50_000), filter_size=5)
    seq = read_flow_h5(out)
    np.testing.assert_array_equal(seq.valid, ref.valid)
    np.testing.assert_allclose(seq.flow, ref.flow, rtol=1e-5, atol=1e-3)
    assert seq.attrs["triplet_filter_size"] == 5


def test_dense_h5_and_flo_outputs_match_the_api(edge_file, tmp_path):
    from evmotion.io.flowfiles import read_flo

    path, ev, _ = edge_file
    wins = ev.windows_by_duration(50_000)
    ref = estimate_flow_triplet(ev, wins)
    assert main(["flow", str(path), "--method", "triplet", "--out", str(tmp_path / "f.h5"),
                 "--window-us", "50000", "--chunk-events", "300"]) == 0
    arr = read_flow_h5(tmp_path / "f.h5").flow
    assert arr.dtype == np.float32 and arr.shape == ref.flow.shape
    np.testing.assert_allclose(arr, ref.flow, rtol=1e-5, atol=1e-3)
    assert main(["flow", str(path), "--method", "triplet", "--out", str(tmp_path / "f.npy"),
                 "--window-us", "50000"]) == 2
    assert main(["flow", str(path), "--method", "triplet", "--out",
                 str(tmp_path / "f_{:05d}.flo"), "--window-us", "50000"]) == 0
    for i in range(len(wins)):
        disp = read_flo(tmp_path / f"f_{i:05d}.flo")
        known = np.isfinite(disp).all(axis=-1)  # Middlebury's "unknown" where not valid
        # the last window ends with the data: its displacement spans that much of it
        w = ref.windows[i]
        part = (min(w.t1, int(ev.t[-1]) + 1) - w.t0) / (w.t1 - w.t0)
        np.testing.assert_allclose(disp[known], ref.displacement(i)[known] * part,
                                   rtol=1e-5, atol=1e-4)
    assert not (tmp_path / "f.flo").exists()
    one = tmp_path / "one.flo"
    assert main(["flow", str(path), "--method", "triplet", "--out", str(one),
                 "--window-us", "1000000"]) == 0
    assert one.exists() and not (tmp_path / "one_00000.flo").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_dense_lsq_option_matches_the_api(edge_file, tmp_path):
    path, ev, _ = edge_file
    out = tmp_path / "flow.h5"
    assert main(["flow", str(path), "--method", "triplet", "--out", str(out),
                 "--window-us", "50000", "--chunk-events", "170", "--dense", "lsq",
                 "--bins", "2"]) == 0
    ref = estimate_flow_triplet(ev, ev.windows_by_duration(50_000), dense="lsq", n_bins=2)
    seq = read_flow_h5(out)
    np.testing.assert_array_equal(seq.valid, ref.valid)
    np.testing.assert_allclose(seq.flow, ref.flow, rtol=1e-5, atol=1e-3)
    assert seq.attrs["triplet_dense"] == "lsq" and seq.attrs["triplet_filter_size"] == 15
    # a straight edge: only its normal flow (200 px/s along +x) is observable
    inner = seq.flow[1:-1][seq.valid[1:-1]]
    np.testing.assert_allclose(np.median(inner, axis=0), [200.0 / 1.005, 0.0], atol=2.0)


def test_json_valid_fraction_is_the_outputs(edge_file, tmp_path, capsys):
    """--json's valid_fraction is what the output holds: its pixels for dense windows (as
    info and multicm give it), its events per event; the events that got a flow apart.
    A dense output had been given the events' share (0.207 beside a file with no valid
    pixel, probe DA)."""
    from evmotion.io.eventflow import describe_event_flow
    from evmotion.io.flowread import describe_flow

    path, ev, _ = edge_file
    for out, extra, describe in ((tmp_path / "flow.h5", ["--window-us", "50000"],
                                  describe_flow),
                                 (tmp_path / "flow.npz", [], describe_event_flow)):
        assert main(["flow", str(path), "--method", "triplet", "--out", str(out),
                     "--json", *extra]) == 0
        doc = json.loads(capsys.readouterr().out)
        held = describe(out)["valid_fraction"]
        assert doc["valid_fraction"] == pytest.approx(held)
        ref = TripletMatcher(ev.sensor_size).process(ev)
        assert doc["event_flow_fraction"] == pytest.approx(ref.valid.mean())
    assert held != pytest.approx(describe_flow(tmp_path / "flow.h5")["valid_fraction"])


@pytest.mark.parametrize("chunk", ["170", "1000000"])
def test_dense_robust_option_matches_the_api(edge_file, tmp_path, chunk):
    path, ev, _ = edge_file
    out = tmp_path / "flow.h5"
    assert main(["flow", str(path), "--method", "triplet", "--out", str(out),
                 "--window-us", "50000", "--chunk-events", chunk, "--dense", "robust",
                 "--filter-size", "9"]) == 0
    ref = estimate_flow_triplet(ev, ev.windows_by_duration(50_000), dense="robust",
                                filter_size=9)
    seq = read_flow_h5(out)
    np.testing.assert_array_equal(seq.valid, ref.valid)
    np.testing.assert_allclose(seq.flow, ref.flow, rtol=1e-5, atol=1e-3)
    assert seq.attrs["triplet_dense"] == "robust" and seq.attrs["triplet_gap_ms"] == 4.0
    inner = seq.flow[1:-1][seq.valid[1:-1]]
    np.testing.assert_allclose(np.median(inner, axis=0), [200.0, 0.0], atol=2.0)


def test_bad_options_are_reported(edge_file, tmp_path, capsys):
    path, _, _ = edge_file
    assert main(["flow", str(path), "--method", "triplet", "--out",
                 str(tmp_path / "x.txt")]) == 2
    assert "must end in .h5" in capsys.readouterr().err
    assert main(["flow", str(path), "--method", "triplet", "--out", str(tmp_path / "x.h5"),
                 "--dense", "lsq", "--ridge", "nan"]) == 2
    assert "--ridge" in capsys.readouterr().err
    assert main(["flow", str(path), "--method", "triplet", "--out", str(tmp_path / "x.h5"),
                 "--dense", "robust", "--gap-ms", "0"]) == 2
    assert "--gap-ms" in capsys.readouterr().err
    assert main(["flow", str(path), "--method", "triplet", "--out", str(tmp_path / "x.h5"),
                 "--dx", "0.3"]) == 2
    assert "dx" in capsys.readouterr().err
    assert not (tmp_path / "x.h5").exists()
    assert main(["flow", str(path), "--method", "triplet", "--out", str(tmp_path / "x.h5"),
                 "--filter-size", "4"]) == 2
    assert "--filter-size" in capsys.readouterr().err
    assert not (tmp_path / "x.h5").exists()
    # huge values raised an OverflowError / TypeError traceback (--gap-ms 1e16, 1e20), a
    # numpy error (--dx 1e308), or ran for minutes deaf to Ctrl-C (--dx 300; probe)
    for opt, value in (("--gap-ms", "1e16"), ("--gap-ms", "1e300"), ("--dx", "1e308"),
                       ("--dx", "300")):
        extra = ["--dense", "robust"] if opt == "--gap-ms" else []
        assert main(["flow", str(path), "--method", "triplet", "--out",
                     str(tmp_path / "x.h5"), *extra, opt, value]) == 2
        err = capsys.readouterr().err
        assert f"{opt} must be at most" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.h5").exists()


@pytest.mark.parametrize("gt_dt", [1, 2])
def test_gt_windows(edge_file, tmp_path, gt_dt):
    from evmotion.io.flowfiles import FlowWriter

    path, ev, _ = edge_file
    frames = np.arange(30_000, 190_000, 22_222)
    gt = tmp_path / "gt.h5"
    with FlowWriter(gt, ev.sensor_size) as fw:
        for a, b in zip(frames[:-1], frames[1:], strict=True):
            fw.append(np.zeros((*ev.sensor_size, 2), np.float32), int(a), int(b))
    out = tmp_path / "flow.h5"
    assert main(["flow", str(path), "--method", "triplet", "--out", str(out),
                 "--window-gt", str(gt), "--gt-dt", str(gt_dt), "--chunk-events", "250"]) == 0
    ref = estimate_flow_triplet(ev, ev.windows_at(frames, dt=gt_dt))
    seq = read_flow_h5(out)
    np.testing.assert_array_equal(seq.t0, [w.t0 for w in ref.windows])
    np.testing.assert_allclose(seq.flow, ref.flow, rtol=1e-5, atol=1e-3)
    assert seq.valid.any()


@pytest.mark.realdata
def test_real_evt3_file_streams(shared_data, tmp_path, capsys):
    path = shared_data / "formats" / "evt3.raw"
    if not path.exists():
        pytest.skip(f"{path} not found")
    from evmotion.io.registry import detect_spec

    ev = detect_spec(path).read(path)[:200_000]
    out = tmp_path / "flow.npz"
    rc = main(["flow", str(path), "--method", "triplet", "--out", str(out),
               "--chunk-events", "65536", "--json"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["sensor_size"] == [720, 1280]  # [H, W], as every flow method
    with np.load(out) as z:
        n = summary["events"]
        assert z["vx"].shape == (n,) and n > 1_000_000
        # The streamed file's first 200k events match the API on the same events.
        ref = TripletMatcher(ev.sensor_size).process(ev)
        np.testing.assert_array_equal(z["vx"][:len(ev)], ref.vx)
        np.testing.assert_array_equal(z["t"][:len(ev)], ev.t)


def test_h5_is_per_event_unless_windows_are_asked(edge_file, tmp_path, capsys):
    """Default output: per event (no dense field is computed or written); --dense (or a
    window option) asks for windows, written Blosc-compressed."""
    import h5py

    from evmotion.io.eventflow import read_event_flow

    path, ev, _ = edge_file
    out = tmp_path / "ev.h5"
    assert main(["flow", str(path), "--method", "triplet", "--out", str(out),
                 "--chunk-events", "300", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["output"] == "per event" and summary["windows"] == 0
    got = read_event_flow(out)
    ref = TripletMatcher(ev.sensor_size).process(ev)
    np.testing.assert_array_equal(got["vx"], ref.vx)
    np.testing.assert_array_equal(got["nx"], ref.nx)
    np.testing.assert_array_equal(got["x"], ev.x)
    assert got.attrs["method"] == "triplet" and got.attrs["units"] == "px/s"
    assert "triplet_dense" not in got.attrs
    with h5py.File(out) as f:
        assert "flow" not in f
    dense = tmp_path / "dense.h5"
    assert main(["flow", str(path), "--method", "triplet", "--out", str(dense),
                 "--dense", "mean"]) == 0
    ref = estimate_flow_triplet(ev, ev.windows_by_duration(50_000))
    seq = read_flow_h5(dense)
    np.testing.assert_allclose(seq.flow, ref.flow, rtol=1e-5, atol=1e-3)
    with h5py.File(dense) as f:
        assert "32001" in f["flow"]._filters  # Blosc
    capsys.readouterr()  # (the dense run's warning of its early windows)
    rc = main(["flow", str(path), "--method", "triplet", "--out", str(tmp_path / "r.h5"),
               "--resume"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "--resume" in err and "per-event" in err and "\n" not in err


@pytest.mark.realdata
def test_real_evt3_per_event_h5_equals_the_library(shared_data, tmp_path, capsys):
    """The default per-event .h5 of the real EVT3 file holds, column for column and bit for
    bit, the events and the flow the library's matcher gives on the same events."""
    path = shared_data / "formats" / "evt3.raw"
    if not path.exists():
        pytest.skip(f"{path} not found")
    from evmotion.io.eventflow import EVENT_FLOW_COLUMNS, read_event_flow
    from evmotion.io.registry import detect_spec

    ev = detect_spec(path).read(path)
    out = tmp_path / "flow.h5"
    assert main(["flow", str(path), "--method", "triplet", "--out", str(out),
                 "--chunk-events", "300000", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["events"] == len(ev)
    got = read_event_flow(out)
    ref = TripletMatcher(ev.sensor_size).process(ev)
    want = {"t": ev.t, "x": ev.x, "y": ev.y, "p": ev.p, "vx": ref.vx, "vy": ref.vy,
            "nx": ref.nx, "ny": ref.ny, "valid": ref.valid, "n_triplets": ref.n_triplets}
    for name, dt in EVENT_FLOW_COLUMNS:
        assert got[name].dtype == np.dtype(dt)
        np.testing.assert_array_equal(got[name], np.asarray(want[name]).astype(dt))


def test_progress_of_a_raw_file_has_a_total(tmp_path, monkeypatch, capsys):
    # an EVT RAW header states no event count: the bar's total (and ETA) comes from the
    # share of the file read, and it ends at the true count
    from evmotion.io import evt3

    rng = np.random.default_rng(1)
    n = 120_000  # four of the chunks the matcher is fed (stream_chunk_events)
    ev = EventArray(x=rng.integers(0, 40, n), y=rng.integers(0, 40, n),
                    t=np.sort(rng.integers(0, 400_000, n)), p=rng.integers(0, 2, n),
                    sensor_size=(40, 40))
    path = tmp_path / "noise.raw"
    evt3.write(path, ev)
    monkeypatch.setenv("EVMOTION_PROGRESS", "1")
    rc = main(["flow", str(path), "--method", "triplet", "--out", str(tmp_path / "f.npz"),
               "--chunk-events", "400"])
    assert rc == 0
    bars = [b for b in capsys.readouterr().err.replace("\r", "\n").splitlines()
            if b.startswith("triplet:") and "|" in b]
    assert bars and "25%" in bars[0] and "120k/120k" in bars[-1] and "100%" in bars[-1]


def test_ring_overflow_is_said(tmp_path, capsys):
    # 17-20 % of the shared EVT files' events overflowed their pixel's ring, said only
    # in the JSON (probe Z)
    from evmotion.io import write_events

    rng = np.random.default_rng(0)
    n = 4000  # 20 busy pixels, 200 events each within 40 ms
    busy = EventArray(x=rng.integers(10, 30, n), y=np.full(n, 5), p=np.ones(n, np.uint8),
                      t=np.sort(rng.integers(0, 40_000, n)), sensor_size=(20, 40))
    write_events(tmp_path / "busy.h5", busy)
    argv = ["flow", str(tmp_path / "busy.h5"), "--method", "triplet", "--json"]
    assert main([*argv, "--out", str(tmp_path / "a.h5")]) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)
    assert doc["overflow"] > 0.05 * doc["events"]
    assert f"{doc['overflow']:,} of {doc['events']:,} events" in err and "--depth 8" in err
    assert main([*argv, "--out", str(tmp_path / "b.h5"), "--depth", "255"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["overflow"] == 0 and "--depth" not in err


@pytest.mark.parametrize("per_window", [1000, 700, 500])
def test_one_flo_takes_a_window_with_its_remainder_or_the_first(tmp_path, capsys, per_window):
    """A .flo of 1.6 windows was refused ('several windows but one .flo file') where
    multicm and dnn estimate one window of all the events; of more windows the file holds
    the first, said (probe AV)."""
    ev = edge_events(200.0, size=40)  # 1600 events
    src = tmp_path / "rec.h5"
    eio.write_events(src, ev)
    out = tmp_path / "w.flo"
    rc = main(["flow", str(src), "--method", "triplet", "--window-events", str(per_window),
               "--out", str(out)])
    err = capsys.readouterr().err
    if per_window == 500:  # 3.2 windows: refused before the work
        assert rc == 2 and "4 windows but one .flo file" in err and not out.exists()
        return
    assert rc == 0, err
    seq = eio.read_flow(out)
    assert len(seq.t0) == 1 and int(seq.t0[0]) == int(ev.t[0])
    if per_window == 1000:
        assert "holds 1,600 events, one window of --window-events 1000" in err
        assert int(seq.t1[0]) == int(ev.t[-1]) + 1
    else:
        assert "3 windows; w.flo holds the first, 2 more were not written" in err
        assert int(seq.t1[0]) == int(ev.t[700])


def test_a_window_without_focus_says_so_in_its_picture(tmp_path, monkeypatch, capsys):
    """The warped events of a window without focus are titled as no measurement (they had
    been titled as any other window's, probe DA)."""
    import evmotion.viz as viz

    rng = np.random.default_rng(0)
    n = 5000
    ev = EventArray(rng.integers(0, 64, n), rng.integers(0, 48, n),
                    np.sort(rng.integers(0, 200_000, n)), rng.integers(0, 2, n), (48, 64))
    monkeypatch.setattr(eio, "iter_events", lambda path, chunk_events, **kw: iter([ev]),
                        raising=False)
    titles = []
    real = viz.event_picture_png
    monkeypatch.setattr(viz, "event_picture_png",
                        lambda img, **kw: titles.append(kw.get("title")) or real(img, **kw))
    assert main(["flow", str(tmp_path / "noise.dat"), "--method", "triplet", "--dense",
                 "robust", "--window-us", "200000", "--out", str(tmp_path / "f.h5"),
                 "--png-dir", str(tmp_path / "png")]) == 0
    assert "have no focus" in capsys.readouterr().err
    assert len(titles) == 1 and "NO FOCUS: not a measurement" in titles[0]


def test_per_event_flow_of_noise_is_said_and_left_out(tmp_path, capsys):
    """Probe DG: 'flow noise.npz --method triplet' gave 76 % of a noise recording's
    events a flow, valid, without a word (and then blamed the few left on tau)."""
    rng = np.random.default_rng(4)
    n = 120_000
    ev = EventArray(rng.integers(0, 160, n), rng.integers(0, 120, n),
                    np.sort(rng.integers(0, 300_000, n)), rng.integers(0, 2, n), (120, 160))
    rec = tmp_path / "noise.npz"
    eio.write_events(rec, ev)
    assert main(["flow", str(rec), "--method", "triplet", "--out", str(tmp_path / "o.h5"),
                 "--json"]) == 0
    out = capsys.readouterr()
    summary = json.loads(out.out)
    assert summary["valid_fraction"] < 0.02 and summary["unaligned_events"] > n // 2
    said = out.err.splitlines()
    assert any("does not carry their stretch's first half onto its second" in s
               for s in said), said
    assert not any("a triplet needs steps" in s for s in said), said
