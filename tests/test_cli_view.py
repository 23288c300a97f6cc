"""``evmotion view``: slices by time or count, PNG output, JSON summary, clear errors."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

import evmotion.io as eio
from evmotion.cli import main
from evmotion.events import EventArray
from evmotion.viz import event_histogram, iwe_to_rgb, read_png


def _events(n=5000, seed=0):
    rng = np.random.default_rng(seed)
    return EventArray(rng.integers(0, 40, n), rng.integers(0, 30, n),
                      1_000_000 + np.sort(rng.integers(0, 100_000, n)), rng.integers(0, 2, n),
                      sensor_size=(30, 40))


@pytest.fixture
def fake_reader(monkeypatch):
    """A recording served by stand-in readers, recording how they were called."""
    ev = _events()
    calls = []

    def read_events(path, format=None, t0=None, t1=None, warn_empty=True):
        calls.append(("read", path, format, t0, t1))
        return ev.slice_time(t0, t1)

    def iter_events(path, chunk_events, format=None, t0=None, t1=None):
        calls.append(("iter", path, format, chunk_events, t0, t1))
        sl = ev.slice_time(t0, t1)
        for s in range(0, len(sl), chunk_events):
            yield sl[s:s + chunk_events]

    monkeypatch.setattr(eio, "read_events", read_events)
    monkeypatch.setattr(eio, "iter_events", iter_events)
    monkeypatch.setattr(eio, "describe", lambda path, format=None, **kw: {
        "t_first_us": int(ev.t[0]), "t_last_us": int(ev.t[-1])})
    return ev, calls


def test_time_slice_png_and_json(fake_reader, tmp_path, capsys):
    ev, calls = fake_reader
    out = tmp_path / "v.png"
    rc = main(["view", "rec.h5", "--t0", "1020000us", "--t1", "1050000us", "--out", str(out),
               "--json", "--raw"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    sl = ev.slice_time(1_020_000, 1_050_000)
    assert summary["events"] == len(sl)
    assert summary["t0_us"] >= 1_020_000 and summary["t1_us"] <= 1_050_000
    assert summary["sensor_size"] == {"height": 30, "width": 40}
    img = read_png(out)
    np.testing.assert_array_equal(img, iwe_to_rgb(event_histogram(sl)))
    assert calls[0][0] == "read" and calls[0][3:] == (1_020_000, 1_050_000)


def test_the_default_picture_has_a_title_axes_and_colour_bar(fake_reader, tmp_path, capsys):
    """The events' picture was the bare image: no time, count or scale on it."""
    out = tmp_path / "a.png"
    assert main(["view", "rec.h5", "--t0", "1020000us", "--t1", "1050000us", "--out",
                 str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    img = read_png(out)
    assert summary["image"] == {"height": img.shape[0], "width": img.shape[1]}
    assert img.shape[0] > 2 * 30 and img.shape[1] > 2 * 40  # axes, title and bar around it
    # the colour bar: a column running from white to black on the right
    col = img[:, int(img.shape[1] * 0.8):].mean(axis=2)
    assert col.min() < 100 and col.max() > 225


def test_count_window_streams_and_polarity(fake_reader, tmp_path, capsys):
    ev, calls = fake_reader
    out = tmp_path / "p.png"
    rc = main(["view", "rec.raw", "--t0", "1010000us", "--window-events", "700",
               "--out", str(out), "--polarity", "--scale", "2", "--json", "--raw"])
    assert rc == 0
    summary = json.loads(capsys.readouterr().out)
    sl = ev.slice_time(1_010_000, None)[:700]
    assert summary["events"] == 700 and summary["t0_us"] == int(sl.t[0])
    assert summary["image"] == {"height": 60, "width": 80}
    img = read_png(out)
    ref = iwe_to_rgb(event_histogram(sl, signed=True), polarity=True)
    np.testing.assert_array_equal(img[::2, ::2], ref)
    assert calls[0][0] == "iter" and calls[0][4:] == (1_010_000, None)
    # Red and blue both appear: positive and negative pixels.
    assert ((img[..., 0] > 200) & (img[..., 2] < 100)).any()
    assert ((img[..., 2] > 200) & (img[..., 0] < 100)).any()


def test_errors_are_reported_without_traceback(fake_reader, tmp_path, capsys):
    assert main(["view", "rec.h5", "--t0", "5", "--t1", "5", "--out", str(tmp_path / "a.png")]) == 2
    assert "--t1" in capsys.readouterr().err
    assert main(["view", "rec.h5", "--out", str(tmp_path / "a.jpg")]) == 2
    assert "PNG" in capsys.readouterr().err
    assert main(["view", "rec.h5", "--t0", "9000000us", "--t1", "9100000us",
                 "--out", str(tmp_path / "a.png")]) == 2
    err = capsys.readouterr().err
    assert "no events" in err and "--t0 9 s (9000000 µs)" in err
    # the recording's time range is named, so that the user can pick another slice
    assert f"[{int(_events().t[0])}, {int(_events().t[-1])}] µs" in err
    assert len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())


@pytest.mark.realdata
@pytest.mark.parametrize("rel,size", [
    ("formats/davis346_short.aedat4", (260, 346)),
    ("formats/evt2.raw", (480, 640)),  # Gen3 sensor (header: hal_plugin_gen3)
    ("ecd_rotation_windows/poster_rotation/events.txt", (180, 240)),
])
def test_real_recording(shared_data, tmp_path, capsys, rel, size):
    from evmotion.errors import FormatError
    from evmotion.io.registry import detect_spec

    path = shared_data / rel
    try:
        detect_spec(path)
    except FormatError as exc:
        pytest.skip(f"no reader for {rel} yet: {exc}")
    out = tmp_path / "real.png"
    assert main(["view", str(path), "--window-events", "5000", "--out", str(out),
                 "--json", "--raw"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["events"] == 5000
    assert summary["sensor_size"] == {"height": size[0], "width": size[1]}
    assert read_png(out).shape == size + (3,)
    assert summary["pixels_with_events"] > 500


def test_missing_file_is_a_clear_error(tmp_path, capsys):
    assert main(["view", str(tmp_path / "missing.h5"), "--out", str(tmp_path / "a.png")]) == 2
    err = capsys.readouterr().err
    assert "missing.h5" in err and "Traceback" not in err


def test_view_draws_a_window_of_a_flow_output(tmp_path, capsys):
    """Issue #12: the flow outputs (flow, bos) are viewable; 'view bos.h5' said 'format
    not recognised'."""
    from evmotion.io.flowfiles import FlowWriter

    flow = np.zeros((30, 40, 2), np.float32)
    flow[..., 0] = 5.0
    valid = np.zeros((30, 40), bool)
    valid[5:20, 5:30] = True
    path = tmp_path / "f.h5"
    with FlowWriter(path, (30, 40), with_valid=True) as fw:
        for k in range(3):
            fw.append(flow * (k + 1), t0=10_000 * k, t1=10_000 * (k + 1), valid=valid)
    out = tmp_path / "v.png"
    assert main(["view", str(path), "--t0", "0.015", "--out", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "flow" and info["window"] == 1 and info["has_q"] is False
    assert info["valid_fraction"] == pytest.approx(valid.mean())
    img = read_png(out)
    assert img.shape[0] >= 30 and img.shape[1] > 40
    assert main(["view", str(path), "--window", "2", "--out", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["t0_us"] == 20_000
    assert main(["view", str(path), "--window", "2", "--out", str(out)]) == 0
    assert capsys.readouterr().out.endswith("window 2 of 3 of " + str(path) + ", [0.02, 0.03) s\n")
    for argv, words in ((["--window", "3"], ("--window 3", "holds 3 windows")),
                        # in seconds, as typed (it echoed "--t0 500000 us")
                        (["--t0", "0.5"], ("--t0 0.5 s: no window", "holds it",
                                           "span [0, 0.03) s")),
                        (["--polarity"], ("--polarity", "flow output"))):
        assert main(["view", str(path), *argv, "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and all(w in err for w in words), err


def test_view_draws_the_first_measured_window_by_default(tmp_path, capsys):
    """Probe AM: a BOS run's first interval (the sensor's start-up, no valid pixel) was
    drawn by default, q over the whole frame and no word that it measured nothing."""
    from evmotion.io.flowfiles import FlowWriter

    flow = np.ones((30, 40, 2), np.float32)
    path = tmp_path / "f.h5"
    with FlowWriter(path, (30, 40), with_valid=True) as fw:
        for k in range(3):
            fw.append(flow, t0=10_000 * k, t1=10_000 * (k + 1),
                      valid=np.full((30, 40), k > 0))
    out = tmp_path / "v.png"
    assert main(["view", str(path), "--out", str(out), "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["window"] == 1
    assert "window 0 holds no valid pixel (no measurement): drawing window 1" in cap.err
    assert main(["view", str(path), "--window", "0", "--out", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["window"] == 0


def test_view_of_a_bos_output_shows_q(tmp_path, capsys):
    pytest.importorskip("cv2")
    from bos_synth import plume_scene

    scene = plume_scene(tmp_path / "scene")
    assert main(["bos", str(scene), "--out", str(tmp_path / "bos.h5")]) == 0
    capsys.readouterr()
    out = tmp_path / "b.png"
    assert main(["view", str(tmp_path / "bos.h5"), "--out", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["has_q"] is True
    assert read_png(out).shape[1] > 2 * 40
    assert main(["view", str(scene), "--window", "1", "--out", str(out)]) == 2
    assert "--window 1 does not apply to a recording" in capsys.readouterr().err


def test_a_long_title_on_a_small_sensor_is_wrapped_not_cut(tmp_path):
    # view's titles on a 128x128 sensor lost their start and end at the figure's edges
    from evmotion.io.pngfile import read_png
    from evmotion.viz.images import event_picture_png

    img = np.ones((128, 128))
    (tmp_path / "s.png").write_bytes(event_picture_png(img, title="w"))
    (tmp_path / "l.png").write_bytes(event_picture_png(
        img, title="a_long_recording_name.aedat: 30,000 events, [0.002539, 0.062113) s "
                   "(59.57 ms)"))
    short, long = read_png(tmp_path / "s.png")[0], read_png(tmp_path / "l.png")[0]
    assert long.shape[1] == short.shape[1] and long.shape[0] > short.shape[0]


def test_another_tools_flo_without_sidecar_is_drawn_as_displacement(tmp_path, capsys):
    # a RAFT / E-RAFT .flo carries no times: view asked for t0/t1, which it does not take
    from evmotion.io.flowfiles import write_flo

    disp = np.zeros((30, 40, 2), np.float32)
    disp[..., 0] = 2.5
    write_flo(tmp_path / "raft.flo", disp)
    assert main(["view", str(tmp_path / "raft.flo"), "--out", str(tmp_path / "v.png"),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["units"] == "px" and doc["t0_us"] is None and doc["valid_fraction"] == 1.0
    assert (tmp_path / "v.png").stat().st_size > 0

def test_a_folder_of_another_tools_flo_files_is_described_and_each_file_viewed(
        tmp_path, capsys):
    # info and view said "format not recognised" of a folder of .flo files without
    # sidecars (probe BM), though eval pairs them with a ground truth
    from evmotion.io.flowfiles import write_flo

    pred = tmp_path / "pred"
    pred.mkdir()
    for i in (0, 1, 10):  # 10 after 1: the numbers' order, not the text's
        write_flo(pred / f"{i}.flo", np.full((30, 40, 2), i + 0.5, np.float32))
    assert main(["info", str(pred), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert (doc["format"], doc["windows"], doc["files"]) == ("middlebury-flo", 3, 3)
    assert doc["sensor_size"] == [30, 40] and "t_first_us" not in doc
    assert main(["view", str(pred), "--window", "2", "--out", str(tmp_path / "v.png"),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["flow_file"].endswith("10.flo") and doc["n_windows"] == 3
    assert read_png(tmp_path / "v.png").shape[1] > 40
    assert main(["view", str(pred), "--window", "3", "--out", str(tmp_path / "w.png")]) == 2
    assert "holds 3 flow files (0 to 2)" in capsys.readouterr().err
    frames = tmp_path / "frames"  # 8-bit images: not flow
    frames.mkdir()
    from evmotion.viz import save_png

    save_png(frames / "0.png", np.zeros((30, 40, 3), np.uint8))
    from evmotion.io.flowread import undated_flow_files

    assert undated_flow_files(frames) == [] and undated_flow_files(tmp_path / "none") == []



def test_the_simulators_ground_truth_is_viewed_and_an_undated_flo_counts_one_window(
        tmp_path, capsys):
    # view called the *_gt.h5 'not a recording of events' and read no flow from it; info
    # said 'windows: 0' of a .flo without sidecar
    from evmotion.io.flowfiles import write_flo

    assert main(["simulate", "translation", "--duration", "0.03", "--size", "30x40", "--out",
                 str(tmp_path / "s.h5")]) == 0
    assert main(["view", str(tmp_path / "s_gt.h5"), "--out", str(tmp_path / "g.png")]) == 0
    assert "window 0 of" in capsys.readouterr().out
    write_flo(tmp_path / "raft.flo", np.ones((30, 40, 2), np.float32))
    assert main(["info", str(tmp_path / "raft.flo"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["windows"] == 1


def test_public_ground_truths_are_described_and_viewed_as_flow(tmp_path, capsys):
    # info answered "npz lacks arrays x, y, t, p" for MVSEC's *_gt_flow_dist.npz and "format
    # not recognised" for a DSEC flow folder
    import cv2

    ts = np.array([1.0, 1.05, 1.1])
    d = np.ones((3, 20, 30), np.float32)
    np.savez(tmp_path / "x_gt_flow_dist.npz", timestamps=ts, x_flow_dist=d, y_flow_dist=-d)
    assert main(["info", str(tmp_path / "x_gt_flow_dist.npz"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["format"] == "mvsec-gt-flow" and doc["windows"] == 2
    flow = tmp_path / "seq" / "flow"
    (flow / "forward").mkdir(parents=True)
    png = np.zeros((20, 30, 3), np.uint16)
    png[..., 2] = 2 ** 15 + 128  # u = 1 px (cv2 writes BGR: R is the last channel)
    png[..., 1] = 2 ** 15
    png[..., 0] = 1
    cv2.imwrite(str(flow / "forward" / "000000.png"), png)
    (flow / "forward_timestamps.txt").write_text("# from_us, to_us\n0, 50000\n")
    for target in (tmp_path / "seq", flow):
        assert main(["info", str(target), "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["format"] == "dsec-gt-flow"
    assert main(["view", str(flow), "--out", str(tmp_path / "d.png")]) == 0


def test_view_takes_the_sensor_size_and_time_unit_of_a_bare_file(tmp_path, capsys):
    # an .npz stating neither size nor unit could not be viewed at its true size (probe T)
    path = tmp_path / "a.npz"
    np.savez(path, x=[1, 2, 3], y=[1, 2, 3], t=np.array([0, 5_000_000, 10_000_000]),
             p=[1, 0, 1])
    assert main(["view", str(path), "--sensor-size", "40", "60", "--time-unit", "ns",
                 "--out", str(tmp_path / "v.png"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["sensor_size"] == {"height": 40, "width": 60}
    assert doc["events"] == 3


def test_the_title_of_epoch_times_shows_the_microseconds(tmp_path, monkeypatch):
    # "[1.58916e+09, 1.58916e+09) s" for 0.1 s of a DAVIS346 recording (probe)
    import evmotion.viz as viz

    titles = []
    real = viz.event_picture_png

    def spy(*args, title=None, **kw):
        titles.append(title)
        return real(*args, title=title, **kw)

    monkeypatch.setattr(viz, "event_picture_png", spy)
    t0 = 1_589_160_000_123_456
    rec = tmp_path / "epoch.h5"
    eio.write_events(rec, EventArray(x=np.arange(100) % 30, y=np.arange(100) % 20,
                                     t=t0 + np.arange(100) * 1000, p=np.ones(100, int),
                                     sensor_size=(20, 30)))
    assert main(["view", str(rec), "--out", str(tmp_path / "v.png")]) == 0
    assert "[1589160000.123456, 1589160000.222457) s (99 ms)" in titles[0], titles


def test_a_per_event_flow_file_is_drawn_with_its_flow(tmp_path, capsys, monkeypatch):
    # probe BK: view of --method triplet's per-event file drew its events alone
    import evmotion.viz.flowpic as fp
    from evmotion.io.eventflow import EventFlowWriter
    from evmotion.viz import read_png
    from evmotion.viz.flowpic import GREY

    titles = []
    row = fp.picture_row
    monkeypatch.setattr(fp, "picture_row",
                        lambda images, t=None, **kw: titles.append(t) or row(images, t, **kw))

    rng = np.random.default_rng(0)
    n = 3000
    x, y = rng.integers(0, 60, n), rng.integers(0, 40, n)
    vx = np.full(n, 100.0)  # +u everywhere: red on the wheel
    valid = np.arange(n) % 3 > 0
    path = tmp_path / "flow.h5"
    with EventFlowWriter(path, (40, 60)) as w:
        w.append(t=np.arange(n) * 10, x=x, y=y, p=np.ones(n, np.uint8), vx=vx,
                 vy=np.zeros(n), nx=vx, ny=np.zeros(n), valid=valid,
                 n_triplets=np.ones(n, np.int32))
    out = tmp_path / "v.png"
    assert main(["view", str(path), "--out", str(out)]) == 0
    capsys.readouterr()
    rgb = read_png(out).reshape(-1, 3).astype(int)
    red = (rgb[:, 0] > 200) & (rgb[:, 1] < 60) & (rgb[:, 2] < 60)
    assert red.sum() > 500 and (rgb == GREY).all(-1).sum() > 100
    # the events' panel states its scale (probe BX)
    assert re.fullmatch(r"events \(white 0, black >= [\d.]+ / px\)", titles[-1][0])
    assert main(["view", str(path), "--raw", "--out", str(out)]) == 0
    assert read_png(out).shape[:2] == (40, 60)  # --raw: the events alone, pixel for pixel
    assert main(["view", str(path), "--window", "1", "--out", str(out)]) == 2
    # it was "does not apply to a recording" (probe BM)
    assert "does not apply to a per-event flow file" in capsys.readouterr().err
