"""``evmotion bos`` end to end on a tiny simulated ECD-style schlieren folder, ``evmotion
eval`` on its output, and a one-line error with exit code 2 for every bad input."""

import json
import re
import shutil
import warnings

import numpy as np
import pytest

from bos_synth import plume_scene, run_cli
from evmotion.errors import EvmotionWarning
from evmotion.io.bosfiles import read_bos_h5
from evmotion.io.flowfiles import read_flow_h5


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return plume_scene(tmp_path_factory.mktemp("bos") / "plume")


_run = run_cli


def test_no_options_then_eval(scene, tmp_path, capsys):
    out = tmp_path / "bos.h5"
    rc, _, err = _run(["bos", scene, "--out", out], capsys)
    assert rc == 0, err
    seq = read_flow_h5(out)
    assert seq.flow.shape == (2, 48, 40, 2)
    np.testing.assert_array_equal(seq.t0, [0, 8333])
    bos = read_bos_h5(out)
    assert bos.q.shape == (2, 48, 40) and bos.p.shape == (2, 48, 40, 2)
    assert np.isfinite(bos.q).all() and np.isfinite(bos.flow.flow).all()
    _readable_without_plugins(out)
    # one C for the sequence (the median of the intervals' estimates), near the simulator's
    c = bos.scalars["contrast_threshold"]
    assert np.all(c == c[0]) and abs(c[0] - 0.2) < 0.15
    assert bos.attrs["contrast_threshold"] == c[0]
    assert bos.attrs["contrast_threshold_source"] == "median of 2 intervals"
    rc, text, err = _run(["eval", out, "--gt", scene / "schlieren_gt.h5", "--events", scene,
                          "--json"], capsys)
    assert rc == 0, err
    summary = json.loads(text)
    assert summary["n_windows"] == 2 and summary["out_px"] == 1.0
    # eval's numbers are the endpoint errors of the file's flow over each frame interval
    # on the pixels with events where the file claims a measurement (a numpy reference)
    from evmotion.io import read_events

    gt = read_flow_h5(scene / "schlieren_gt.h5")
    events = read_events(scene)
    for i, w in enumerate(summary["windows"]):
        t0, t1 = int(bos.flow.t0[i]), int(bos.flow.t1[i])
        win = events.slice_time(t0, t1)
        mask = np.zeros((48, 40), bool)
        mask[win.y, win.x] = True
        mask &= bos.flow.valid[i]
        err = (bos.flow.flow[i] - gt.flow[i]) * (t1 - t0) * 1e-6
        ee = np.hypot(err[..., 0], err[..., 1])[mask]
        assert w["AEE"] == pytest.approx(ee.mean(), rel=1e-5)
        assert w["%Out"] == pytest.approx(100 * np.mean(ee > 1.0))
        assert w["AE_rad"] == pytest.approx(np.radians(w["AE_deg"]))
        # and the file's q against the simulator's exact q (numpy reference)
        from evmotion.sim.schlieren import read_schlieren_gt

        a = bos.q[i] - bos.q[i].mean()
        b = read_schlieren_gt(scene).q[i].astype(np.float64)
        b -= b.mean()
        assert w["q_corr"] == pytest.approx(np.mean(a * b) / (a.std() * b.std()), rel=1e-4)
        assert w["q_std_ratio"] == pytest.approx(a.std() / b.std(), rel=1e-4)
    assert summary["mean"]["q_corr"] == pytest.approx(
        np.mean([w["q_corr"] for w in summary["windows"]]))


def _readable_without_plugins(path):
    # fluid-dynamics users open bos.h5 in MATLAB or HDFView: no dataset may need a filter
    # of hdf5plugin (Blosc-LZ4, as the flow outputs use, did)
    import subprocess
    import sys

    code = ("import sys; sys.modules['hdf5plugin'] = None; import h5py\n"
            "f = h5py.File(sys.argv[1], 'r'); names = []\n"
            "f.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) "
            "else None)\n"
            "[f[n][()] for n in names]; print(len(names))")
    run = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True,
                         text=True, env={"HDF5_PLUGIN_PATH": "/nonexistent"})
    assert run.returncode == 0, run.stderr
    assert int(run.stdout) >= 6


def test_options_roi_png_json(scene, tmp_path, capsys):
    out = tmp_path / "roi.h5"
    rc, text, err = _run(["bos", scene, "--roi", 4, 8, 32, 32, "--param", "flow",
                          "--data-term", "normalized", "--iterations", 5, "--max-intervals", 1,
                          "--png-dir", tmp_path / "png", "--json", "--out", out], capsys)
    assert rc == 0, err
    summary = json.loads(text)
    assert summary["n_intervals"] == 1 and summary["roi"] == [4, 8, 32, 32]
    bos = read_bos_h5(out)
    # valid: the ROI's pixels with event support (was: the whole ROI; issue 15 §2)
    roi = np.zeros((48, 40), bool)
    roi[8:40, 4:36] = True
    assert not bos.flow.valid[0][~roi].any() and 0 < bos.flow.valid[0].sum() <= 32 * 32
    assert np.isfinite(bos.flow.flow[0][roi]).all()
    assert np.isnan(bos.flow.flow[0, 0, 0]).all()
    for name in ("q_00000.png", "flow_00000.png", "p_00000.png"):
        assert (tmp_path / "png" / name).stat().st_size > 1000
    rc, text, _ = _run(["eval", out, "--gt", scene / "schlieren_gt.h5", "--json"], capsys)
    # scored: the ROI's pixels the file claims (event support), not the whole ROI
    assert rc == 0 and json.loads(text)["mean"]["n_pixels"] == bos.flow.valid[0].sum() < 32 * 32
    # the scene's folder as --gt stands for its schlieren_gt.h5 (probe: "no
    # forward_timestamps.txt beside the flow PNGs", of a folder without any)
    rc, by_folder, _ = _run(["eval", out, "--gt", scene, "--json"], capsys)
    assert rc == 0 and json.loads(by_folder)["mean"] == json.loads(text)["mean"]
    no_gt = tmp_path / "no_gt"
    no_gt.mkdir()
    (no_gt / "events.txt").write_text("0.001 1 2 1\n")
    _one_line_error(["eval", out, "--gt", no_gt], capsys, "holds no ground truth")


def _without_startup(err: str) -> str:
    """stderr without the warnings that the tiny simulated scenes' first interval is the
    sensor's start-up (their pixels start at their reference: bos_run.warn_startup), and
    that their plume leaves no still air in view (48 x 40 px)."""
    return "".join(ln for ln in err.splitlines(keepends=True)
                   if not ln.startswith(("evmotion: warning: the events begin in the frame",
                                         "evmotion: warning: no still air in view")))


def _one_line_error(argv, capsys, *words):
    rc, _, err = _run(argv, capsys)
    assert rc == 2
    lines = _without_startup(err).strip().splitlines()
    assert len(lines) == 1, err
    for w in words:
        assert w in lines[0], lines[0]


@pytest.mark.parametrize("opt,value,word", [
    ("--iterations", "0", "[1, 100000]"), ("--iterations", "x", "integer"),
    ("--contrast-threshold", "nan", "finite"), ("--contrast-threshold", "-0.1", "[0.001, 10]"),
    ("--workers", "0", "[1, 256]"), ("--max-intervals", "0", ">= 1"), ("--param", "q", "invalid"),
    ("--data-term", "l2", "invalid"),
])
def test_bad_options_at_parse_time(scene, tmp_path, capsys, opt, value, word):
    _one_line_error(["bos", scene, opt, value, "--out", tmp_path / "x.h5"], capsys, opt, value,
                    word)


def test_bad_inputs(scene, tmp_path, capsys):
    out = tmp_path / "x.h5"
    _one_line_error(["bos", scene, "--roi", 30, 0, 20, 20, "--out", out], capsys, "roi",
                    "reaches beyond the 40x48")
    _one_line_error(["bos", scene, "--roi", 60, 0, 20, 20, "--out", out], capsys, "roi",
                    "lies outside the 40x48")
    _one_line_error(["bos", scene, "--t0", 10, "--t1", 5, "--out", out], capsys, "--t1")
    _one_line_error(["bos", tmp_path / "nothing", "--out", out], capsys, "no such")
    blocker = tmp_path / "file"
    blocker.write_text("")
    _one_line_error(["bos", scene, "--out", blocker / "x.h5"], capsys, "cannot write")
    # .png is a flow output now (DSEC 16-bit, one file per interval): two intervals need
    # a pattern, and --png-dir needs q and p (.h5 / .npz)
    _one_line_error(["bos", scene, "--out", tmp_path / "x.png"], capsys, "pattern")
    _one_line_error(["bos", scene, "--png-dir", tmp_path / "pngs", "--out",
                     tmp_path / "x_{:05d}.png"], capsys, "--png-dir", ".npz")
    _one_line_error(["bos", scene, "--out", tmp_path / "x.npy"], capsys, "--out", ".npz")
    assert not out.exists()


def test_frames_inside_the_recording(scene, tmp_path, capsys):
    """A recording that holds its frames (here an evmotion HDF5 with a frames group, as
    AEDAT4 holds DAVIS APS frames) needs no --frames: the same result as the folder; one
    without frames names the recording and --frames."""
    import h5py

    from evmotion.io import read_events, write_events
    from evmotion.io.frames import read_frames

    rec = tmp_path / "with_frames.h5"
    write_events(rec, read_events(scene))
    fr = read_frames(scene)
    with h5py.File(rec, "a") as f:
        f["frames/t"], f["frames/images"] = fr.t, fr.images
    outs = []
    for argv in (["bos", rec], ["bos", scene]):
        outs.append(tmp_path / f"{len(outs)}.h5")
        rc, _, err = _run([*argv, "--out", outs[-1]], capsys)
        assert rc == 0, err
    a, b = read_bos_h5(outs[0]), read_bos_h5(outs[1])
    np.testing.assert_array_equal(a.flow.flow, b.flow.flow)
    np.testing.assert_array_equal(a.q, b.q)
    bare = tmp_path / "bare.h5"
    write_events(bare, read_events(scene))
    _one_line_error(["bos", bare, "--out", tmp_path / "x.h5"], capsys, "bare.h5",
                    "no frames", "--frames")


def _copy(scene, tmp_path, name):
    d = tmp_path / name
    shutil.copytree(scene, d)
    return d


def test_bad_recordings(scene, tmp_path, capsys):
    import png

    out = tmp_path / "x.h5"
    # missing frames: no images.txt, and a listed frame file that is gone
    d = _copy(scene, tmp_path, "noframes")
    (d / "images.txt").unlink()
    _one_line_error(["bos", d, "--out", out], capsys, "no frames", "--frames")
    # ECD-style events under another name: the same (a raw "[Errno 2] ... images.txt",
    # exit 1; probe BP)
    (d / "events.txt").rename(d / "ev.txt")
    _one_line_error(["bos", d / "ev.txt", "--out", out], capsys, "no images.txt beside",
                    "--frames")
    # frames but no events: said so (was "format not recognised")
    d = _copy(scene, tmp_path, "noevents")
    (d / "events.txt").unlink()
    _one_line_error(["bos", d, "--out", out], capsys, "noevents", "no events.txt")
    # a corrupt frame names the frame, not 'no frames'
    d = _copy(scene, tmp_path, "corrupt")
    f = d / "images" / "frame_00000001.png"
    f.write_bytes(f.read_bytes()[:60])
    _one_line_error(["bos", d, "--out", out], capsys, "frame_00000001.png", "corrupt PNG")
    d = _copy(scene, tmp_path, "gone")
    (d / "images" / "frame_00000001.png").unlink()
    _one_line_error(["bos", d, "--out", out], capsys, "frame_00000001.png")
    # frames of another size than the events' sensor
    d = _copy(scene, tmp_path, "size")
    _one_line_error(["bos", d, "--frames", _small_frames(tmp_path), "--out", out], capsys,
                    "sensor")
    # frames and events not overlapping in time
    d = _copy(scene, tmp_path, "late")
    lines = (d / "images.txt").read_text().splitlines()
    (d / "images.txt").write_text("".join(f"{float(t) + 100:.6f} {f}\n"
                                          for t, f in (ln.split() for ln in lines)))
    _one_line_error(["bos", d, "--out", out], capsys, "do not overlap")
    # frames that do not change (still air) under the events: said of the sequence, not
    # as the first interval's fit ("covariance 0", probe BN)
    d = _copy(scene, tmp_path, "still")
    first = (d / "images" / "frame_00000000.png").read_bytes()
    for f in (d / "images").glob("*.png"):
        f.write_bytes(first)
    _one_line_error(["bos", d, "--out", out], capsys, "in none of the",
                    "frame intervals tried do the events follow", "--contrast-threshold")
    # textureless frames only: nothing to measure against
    d = _copy(scene, tmp_path, "flat")
    for f in sorted((d / "images").glob("*.png")):
        with open(f, "wb") as fh:
            png.Writer(width=40, height=48, greyscale=True).write(
                fh, np.full((48, 40), 128, np.uint8))
    _one_line_error(["bos", d, "--out", out, "--contrast-threshold", "0.2"], capsys,
                    "none of the 2 frames that start an interval has texture")
    assert not out.exists()


def test_one_textureless_frame_is_skipped_not_the_run(tmp_path, capsys):
    """A dropped (uniform) frame among textured ones aborted the whole run, naming no
    frame (probe V): its interval is now written with no valid pixel and a warning
    naming the frame's time; the other intervals are measured."""
    import png

    from evmotion.io import read_flow

    scene = plume_scene(tmp_path / "scene", intervals=2)
    with open(scene / "images" / "frame_00000001.png", "wb") as fh:
        png.Writer(width=40, height=48, greyscale=True).write(
            fh, np.full((48, 40), 128, np.uint8))
    out = tmp_path / "bos.h5"
    rc, _, err = run_cli(["bos", scene, "--out", out, "--contrast-threshold", "0.2"], capsys)
    assert rc == 0, err
    assert "the frame at 8333 us (interval [8333, 16667) us) is textureless" in err
    seq = read_flow(out)
    assert seq.valid[0].any() and not seq.valid[1].any()


def _small_frames(tmp_path):
    import png

    d = tmp_path / "small"
    (d / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    lines = []
    for i in range(3):
        name = f"images/f{i}.png"
        with open(d / name, "wb") as fh:
            png.Writer(width=20, height=20, greyscale=True).write(
                fh, rng.integers(0, 255, (20, 20), dtype=np.uint8))
        lines.append(f"{i / 120:.6f} {name}\n")
    (d / "images.txt").write_text("".join(lines))
    return d


def test_workers_give_the_cold_start_solutions(scene, tmp_path, capsys):
    # two workers: two chunks of one interval each, both started cold, so each equals a
    # one-worker run of that interval alone
    out2 = tmp_path / "w2.h5"
    rc, _, err = _run(["bos", scene, "--workers", 2, "--iterations", 20,
                       "--contrast-threshold", 0.2, "--out", out2], capsys)
    assert rc == 0, err
    two = read_bos_h5(out2)
    assert len(two) == 2
    for k, t0 in enumerate(two.flow.t0):
        out1 = tmp_path / f"w1_{k}.h5"
        rc, _, err = _run(["bos", scene, "--t0", f"{t0}us", "--max-intervals", 1, "--iterations", 20,
                           "--contrast-threshold", 0.2, "--out", out1], capsys)
        assert rc == 0, err
        one = read_bos_h5(out1)
        np.testing.assert_allclose(one.flow.flow[0], two.flow.flow[k], rtol=1e-5, atol=1e-4)
        np.testing.assert_allclose(one.q[0], two.q[k], rtol=1e-5, atol=1e-3)


def test_aedat4_aps_frames_without_frames_option(shared_data, tmp_path, capsys):
    """A DAVIS346 AEDAT4 recording brings its own APS frames (25 fps)."""
    out = tmp_path / "bos.h5"
    rc, text, err = _run(["bos", shared_data / "formats" / "davis346.aedat4", "--max-intervals",
                          "1", "--out", out, "--json"], capsys)
    assert rc == 0, err
    summary = json.loads(text)
    assert summary["n_intervals"] == 1 and summary["sensor_size"] == [260, 346]
    assert summary["windows"][0]["t1_us"] - summary["windows"][0]["t0_us"] == 40_000


def test_interrupted_bos_resumes_to_the_uninterrupted_output(tmp_path, capsys, monkeypatch):
    """Ctrl-C after some intervals keeps them in OUT.part; the same command with --resume
    solves only the others, the first of them warm-started from the stored solver state,
    and writes the file an uninterrupted run writes, bit for bit."""
    import h5py

    import evmotion.methods.bos as bos

    scene = plume_scene(tmp_path / "scene", intervals=4)
    real, calls, stop_at = bos.estimate_bos, [], [0]

    def counted(*args, **kwargs):
        calls.append(kwargs["t0_us"])
        if len(calls) == stop_at[0]:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(bos, "estimate_bos", counted)
    summaries = []  # what the run's underfit warning is decided on
    monkeypatch.setattr(bos, "warn_underfit", lambda g, d=(), finest=None: summaries.append(
        (list(g), list(d))))
    full, out = tmp_path / "full.h5", tmp_path / "out.h5"
    argv = ["bos", scene, "--iterations", "30"]
    assert _run([*argv, "--out", full], capsys)[0] == 0
    n = len(calls)
    assert n == 4
    calls.clear()
    stop_at[0] = 3
    rc, _, err = _run([*argv, "--out", out], capsys)
    part = tmp_path / "out.h5.part"
    assert rc == 130 and _without_startup(err) == (
        f"evmotion: interrupted; the work done so far is kept in {part}: run the same "
        "command with --resume to continue\n")
    assert part.exists() and not out.exists()
    with h5py.File(part) as f:
        assert f["t1"].shape[0] == 2
    # other options: one line, the .part kept
    _one_line_error([*argv[:-1], "20", "--out", out, "--resume"], capsys, "--resume",
                    "iterations")
    _one_line_error([*argv, "--out", out, "--resume", "--workers", "2"], capsys, "--workers 1")
    # another selection is named as such (C, estimated on it, used to be blamed)
    _one_line_error([*argv, "--out", out, "--resume", "--max-intervals", "3"], capsys,
                    "frame_intervals")
    assert part.exists()
    calls.clear()
    stop_at[0] = 0
    rc, text, err = _run([*argv, "--out", out, "--resume", "--json"], capsys)
    assert rc == 0, err
    assert len(calls) == n - 2 and not part.exists()
    assert [w.get("resumed", False) for w in json.loads(text)["windows"]] == [True] * 2 + [False] * 2
    # the resumed run's summary covers the kept intervals too, as the full run's did
    assert len(summaries) == 2 and len(summaries[0][0]) == 4
    np.testing.assert_array_equal(summaries[1], summaries[0])
    with h5py.File(full) as a, h5py.File(out) as b:
        for name in ("flow", "valid", "q", "p", "t0", "t1", "window/objective", "warm/scale3",
                     "window/fit_gain", "window/displacement_q95"):
            np.testing.assert_array_equal(a[name][()], b[name][()], err_msg=name)


def test_an_interval_without_events_is_written_invalid(tmp_path, capsys):
    """Still air over one frame interval (no event in it) used to abort the whole run;
    it is written with no valid pixel, a warning names it, the next interval starts from
    the one before, and --json stays strict JSON (NaN objective as null)."""
    scene = plume_scene(tmp_path / "scene", intervals=4)
    quiet = _copy(scene, tmp_path, "quiet")
    lines = (scene / "events.txt").read_text().splitlines()
    t0, t1 = 2 / 120, 3 / 120
    (quiet / "events.txt").write_text("".join(ln + "\n" for ln in lines
                                              if not t0 <= float(ln.split()[0]) < t1))
    out = tmp_path / "q.h5"
    rc, text, err = _run(["bos", quiet, "--out", out, "--json"], capsys)
    assert rc == 0, err
    said = [ln for ln in err.splitlines() if "no events in the window" in ln]
    assert len(said) == 1 and "[16667, 25000) us" in said[0]
    summary = json.loads(text, parse_constant=lambda c: pytest.fail(f"not JSON: {c}"))
    # (interval 0, where the simulated events begin, is the sensor's start-up: not valid)
    assert [w["valid_fraction"] > 0 for w in summary["windows"]] == [False, True, False, True]
    assert summary["windows"][2]["objective"] is None
    bos = read_bos_h5(out)
    assert not bos.flow.valid[2].any() and np.isnan(bos.flow.flow[2]).all()
    assert np.isfinite(bos.flow.flow[3][bos.flow.valid[3]]).all()
    # an ROI under 32 px: its frames' texture was checked on every other pixel, under the
    # 16 px it takes, and the run refused as "the sensor (12x12 px) is smaller" (probe BN)
    rc, _, err = _run(["bos", quiet, "--out", tmp_path / "r.h5", "--roi", "8", "8", "24",
                       "24", "--contrast-threshold", "0.2"], capsys)
    assert rc == 0, err
    assert "no events in the window [16667, 25000) us inside the ROI" in err


def test_frame_times_in_another_unit(scene, tmp_path, capsys):
    """images.txt written in us (or ms) made one interval of 8333 s holding every event,
    solved and written without a word."""
    for unit, scale in (("us", 1e6), ("ms", 1e3)):
        d = _copy(scene, tmp_path, unit)
        lines = (d / "images.txt").read_text().splitlines()
        (d / "images.txt").write_text("".join(f"{float(t) * scale:.6f} {f}\n"
                                              for t, f in (ln.split() for ln in lines)))
        _one_line_error(["bos", d, "--out", tmp_path / "x.h5"], capsys, "images.txt",
                        " s apart", "another unit")
    # ordinary frames (8.3 ms apart) around events that span 20 us are no unit slip
    from evmotion.io import read_events
    from evmotion.io.bosinput import load_bos_input

    d = _copy(scene, tmp_path, "sparse")
    ev = read_events(scene)
    keep = [ln for ln, t in zip((scene / "events.txt").read_text().splitlines(), ev.t,
                                strict=True) if 9000 <= t < 9020]
    (d / "events.txt").write_text("".join(ln + "\n" for ln in keep))
    assert len(load_bos_input(d).intervals) == 1


def test_other_tools_time_units_and_partial_coverage(scene, tmp_path, capsys):
    """Both files in us ran with the flow a million times too small; events in us or ms
    gave no unit hint; intervals the events cover half of were solved at half the
    magnitude without a word."""
    from evmotion.io.bosinput import load_bos_input

    def rewrite(d, name, scale, keep=lambda t: True):
        lines = (d / name).read_text().splitlines()
        (d / name).write_text("".join(f"{float(a) * scale:.6f} {b}\n" for a, b in
                                      (ln.split(None, 1) for ln in lines)
                                      if keep(float(a))))

    both = _copy(scene, tmp_path, "both")
    rewrite(both, "images.txt", 1e6)
    rewrite(both, "events.txt", 1e6)
    _one_line_error(["bos", both, "--out", tmp_path / "x.h5"], capsys, "images.txt",
                    "8333", "s apart (median)", "another unit")
    ev_us = _copy(scene, tmp_path, "ev_us")
    rewrite(ev_us, "events.txt", 1e6)
    _one_line_error(["bos", ev_us, "--out", tmp_path / "x.h5"], capsys,
                    "do not overlap in time", "event times in microseconds read as seconds?",
                    "--time-unit us")
    late = _copy(scene, tmp_path, "late")
    rewrite(late, "events.txt", 1.0, keep=lambda t: t >= 0.5 / 120)
    with pytest.warns(EvmotionWarning, match=r"stop or start inside frame intervals as "
                                             r"densely .*\(\[0, 8333\) us 50 % covered\)"):
        assert load_bos_input(late).cut == (0,)
    # decimal milliseconds in both lists read as seconds: 1000x too small a flow, unsaid
    # (probe); said, and read in ms with --time-unit ms
    ms = _copy(scene, tmp_path, "ms")
    rewrite(ms, "images.txt", 1e3)
    rewrite(ms, "events.txt", 1e3)
    with pytest.warns(EvmotionWarning, match=r"frames are 8.333\d* s apart \(median\), slower "
                                             r"than a BOS video.*--time-unit ms"):
        load_bos_input(ms)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_bos_input(ms, time_unit="ms").intervals[:, 1:].tolist() == \
            load_bos_input(scene).intervals[:, 1:].tolist()
    # relative nanoseconds, whole numbers in both lists, read as µs: the warning named
    # milliseconds, which were then refused (probe AT); it names ns
    ns = _copy(scene, tmp_path, "ns_both")
    for name in ("images.txt", "events.txt"):
        lines = (ns / name).read_text().splitlines()
        (ns / name).write_text("".join(f"{round(float(a) * 1e9) + 10**9} {b}\n" for a, b in
                                       (ln.split(None, 1) for ln in lines)))
    with pytest.warns(EvmotionWarning, match=r"slower than a BOS video runs: times in "
                                             r"nanoseconds read as microseconds\?.*--time-unit ns"):
        load_bos_input(ns)
    assert np.diff(load_bos_input(ns, time_unit="ns").intervals[:, 1:]).tolist() == \
        np.diff(load_bos_input(scene).intervals[:, 1:]).tolist()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(load_bos_input(scene).intervals) == 2  # the simulated scene: no warning
        # the simulated jet's events begin 45 % into its first interval, sparse: the air
        # starting to move, not a cut recording
        from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

        write_schlieren(simulate_schlieren("jet", sensor_size=(48, 40), duration_s=2 / 120,
                                           seed=0), tmp_path / "jet")
        load_bos_input(tmp_path / "jet")


def test_events_without_a_sensor_size_take_the_frames(scene, tmp_path, capsys):
    """events.txt alone with --frames elsewhere was read on the 240x180 ECD default and
    refused as 'frames ... but the events' sensor is 240x180'."""
    ev_dir = tmp_path / "ev"
    ev_dir.mkdir()
    shutil.copy(scene / "events.txt", ev_dir / "events.txt")
    frames = _copy(scene, tmp_path, "frames")
    (frames / "events.txt").unlink()
    rc, _, err = _run(["bos", ev_dir / "events.txt", "--frames", frames, "--out",
                       tmp_path / "o.h5"], capsys)
    assert rc == 0, err
    assert read_flow_h5(tmp_path / "o.h5").flow.shape[1:3] == (48, 40)


def test_mostly_clipped_frames_are_flagged(scene, tmp_path):
    from evmotion.io.bosinput import load_bos_input
    from evmotion.io.pngfile import read_png, write_png

    d = _copy(scene, tmp_path, "bright")
    for f in (d / "images").glob("*.png"):
        img = read_png(f)[0][..., 0].astype(int)
        write_png(f, np.minimum(img * 4, 255).astype(np.uint8))
    with pytest.warns(EvmotionWarning, match="clipped at full scale"):
        load_bos_input(d)


def test_events_beyond_240x180_without_a_size_take_the_frames(tmp_path, capsys):
    """events.txt alone whose pixels reach beyond 240x180 was sized to its largest
    coordinates, then refused against the (larger) frames' grid."""
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    write_schlieren(simulate_schlieren("plume", sensor_size=(200, 300), duration_s=2 / 120,
                                       seed=0), tmp_path / "scene")
    (tmp_path / "ev").mkdir()
    shutil.copy(tmp_path / "scene" / "events.txt", tmp_path / "ev" / "events.txt")
    rc, _, err = _run(["bos", tmp_path / "ev" / "events.txt", "--frames", tmp_path / "scene",
                       "--out", tmp_path / "o.h5"], capsys)
    assert rc == 0, err
    assert read_flow_h5(tmp_path / "o.h5").flow.shape[1:3] == (200, 300)


def test_events_off_the_frames_grid_are_named_as_such(scene, tmp_path, capsys):
    """An event outside the frames' size was told to 'pass sensor_size=(height, width)',
    an option bos does not have; a negative coordinate named no event nor value. Both name
    the event's line (they had named its place from 0, after the header, probe AY)."""
    import shutil

    for name, x, words in (("outside", "45", ["the event at x=45", "frames' pixel grid, 40x48"]),
                           ("negative", "-3", ["the event has a negative pixel coordinate: x=-3"])):
        bad = tmp_path / name
        shutil.copytree(scene, bad)
        lines = (bad / "events.txt").read_text().splitlines()
        header = [k for k, line in enumerate(lines) if line.startswith("#")]
        k = len(header) + 3
        t, _, y, p = lines[k].split()
        lines[k] = f"{t} {x} {y} {p}"
        (bad / "events.txt").write_text("\n".join(lines) + "\n")
        _one_line_error(["bos", bad, "--out", tmp_path / f"{name}.h5"], capsys,
                        f"events.txt: line {k + 1}: ", *words)


def test_frame_intervals_without_events_are_said_to_be_left_out(scene, tmp_path):
    # air that stops (or a recording of events shorter than the frames'): the intervals
    # with no event were dropped from the output without a word
    from evmotion.io.bosinput import load_bos_input

    short = tmp_path / "short"
    shutil.copytree(scene, short)
    lines = (short / "events.txt").read_text().splitlines(True)
    keep = [ln for ln in lines if ln.startswith("#") or float(ln.split()[0]) < 0.008]
    (short / "events.txt").write_text("".join(keep))
    with pytest.warns(EvmotionWarning, match=r"1 of 2 frame intervals hold no event") as rec:
        data = load_bos_input(short)
    assert len(data.intervals) == 1
    assert not any("another unit" in str(w.message) for w in rec)
    # seconds read as milliseconds (probe): the events had covered a sliver of the frames;
    # --time-unit ms now reads images.txt's decimals in ms too, and frames 8 us apart say it
    with pytest.warns(EvmotionWarning, match=r"frames are 8\.\d+ us apart \(median\), "
                                             r"faster than a camera"):
        assert len(load_bos_input(scene, time_unit="ms").intervals) == 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(load_bos_input(scene).intervals) == 2


def test_resume_knows_the_recording_by_its_events_not_its_path(tmp_path, capsys,
                                                                monkeypatch):
    """An interrupted run resumed on a recording replaced in place spliced two recordings
    (the path was all it compared); the same recording named by another path was refused.
    Now the events' fingerprint decides."""
    import evmotion.methods.bos as bos

    scene = plume_scene(tmp_path / "scene", intervals=3)
    real, calls = bos.estimate_bos, []

    def stop_second(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(bos, "estimate_bos", stop_second)
    out = tmp_path / "out.h5"
    argv = ["--iterations", "20", "--contrast-threshold", "0.2", "--out", out]
    assert _run(["bos", scene, *argv], capsys)[0] == 130
    monkeypatch.setattr(bos, "estimate_bos", real)
    # the same recording by another path: resumed
    other_path = tmp_path / "." / "scene" / ".." / "scene"
    keep = out.with_name("out.h5.part").read_bytes()
    rc, _, err = _run(["bos", other_path, *argv, "--resume"], capsys)
    assert rc == 0, err
    # a copy of the folder elsewhere: resumed too (probe BH: its frames' path was compared)
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(scene, copy)
    out.unlink()
    out.with_name("out.h5.part").write_bytes(keep)
    rc, _, err = _run(["bos", copy, *argv, "--resume"], capsys)
    assert rc == 0, err
    # another recording in the same place: refused, the interrupted work kept
    out.unlink()
    out.with_name("out.h5.part").write_bytes(keep)
    other = plume_scene(tmp_path / "other", intervals=3)
    # other frames under the same names: refused by their content
    from evmotion.io.pngfile import write_png
    from evmotion.viz import read_png

    frame = copy / "images" / "frame_00000001.png"
    write_png(frame, read_png(frame)[:, ::-1].copy())
    _one_line_error(["bos", copy, *argv, "--resume"], capsys, "frames_digest")
    assert out.with_name("out.h5.part").exists()
    events = (other / "events.txt").read_text().splitlines()
    (scene / "events.txt").write_text("\n".join(events[:-7]) + "\n")
    _one_line_error(["bos", scene, *argv, "--resume"], capsys, "source_events")
    assert out.with_name("out.h5.part").exists()


def test_where_the_frames_come_from(shared_data, tmp_path, capsys):
    """ECD events without images.txt: one line (a raw FileNotFoundError before); an AEDAT4
    with APS frames beside another scene's images.txt: its own frames, said (the other
    scene's were used silently)."""
    scene = plume_scene(tmp_path / "scene")
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(scene / "events.txt", bare / "events.txt")
    _one_line_error(["bos", bare / "events.txt", "--out", tmp_path / "b.h5"], capsys,
                    "no images.txt beside", "--frames")
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    (mixed / "rec.aedat4").symlink_to(shared_data / "formats" / "davis346.aedat4")
    shutil.copytree(scene / "images", mixed / "images")
    shutil.copy(scene / "images.txt", mixed / "images.txt")
    rc, text, err = _run(["bos", mixed / "rec.aedat4", "--max-intervals", "1", "--out",
                          tmp_path / "m.h5", "--json"], capsys)
    assert rc == 0, err
    assert "holds frames of its own, which are used" in err
    assert json.loads(text)["frames"].endswith("davis346.aedat4")


def test_images_and_a_timestamps_file_beside_the_events(tmp_path, capsys):
    """Probe BC: events.txt beside images/ and timestamps.txt (read_frames' documented
    layout) was "no images.txt beside the events", and --frames named either way said the
    folder "holds no frames"."""
    scene = plume_scene(tmp_path / "scene")
    folder = tmp_path / "stamped"
    folder.mkdir()
    shutil.copy(scene / "events.txt", folder / "events.txt")
    shutil.copytree(scene / "images", folder / "images")
    lines = (scene / "images.txt").read_text().split("\n")
    (folder / "timestamps.txt").write_text("".join(f"{ln.split()[0]}\n" for ln in lines
                                                   if ln.strip()))
    ref = tmp_path / "ref.h5"
    rc, _, err = _run(["bos", scene, "--max-intervals", "1", "--iterations", "20", "--out",
                       ref], capsys)
    assert rc == 0, err
    for args in ([folder], [folder / "events.txt"],
                 [folder / "events.txt", "--frames", folder / "timestamps.txt"],
                 [folder, "--frames", folder]):
        out = tmp_path / "o.h5"
        rc, _, err = _run(["bos", *args, "--max-intervals", "1", "--iterations", "20",
                           "--out", out], capsys)
        assert rc == 0, (args, err)
        np.testing.assert_array_equal(read_flow_h5(out).flow, read_flow_h5(ref).flow)


def test_rows_count_the_rois_events_and_no_speed_without_support(tmp_path, capsys):
    """The rows counted the whole sensor's events under --roi, and said 0 px/s (still air)
    where no pixel was valid (the file holds NaN there)."""
    from evmotion.io.ecd import read as read_ecd

    scene = plume_scene(tmp_path / "scene")
    rc, text, err = _run(["bos", scene, "--roi", "10", "16", "20", "16", "--iterations",
                          "20", "--out", tmp_path / "b.h5", "--json"], capsys)
    assert rc == 0, err
    ev = read_ecd(scene)
    for row in json.loads(text)["windows"]:
        w = ev.slice_time(row["t0_us"], row["t1_us"])
        inside = (w.x >= 10) & (w.x < 30) & (w.y >= 16) & (w.y < 32)
        assert row["n_events"] == int(inside.sum()) < len(w)
        assert (row["median_speed_px_s"] is None) == (row["valid_fraction"] == 0)


def test_time_units_of_other_labs(scene, tmp_path, capsys):
    """Probe AM: events.txt in integer ns had no --time-unit to say so (the warning named
    one bos did not have); images.txt in integer ms was refused without naming a unit."""
    ns = tmp_path / "ns"
    shutil.copytree(scene, ns)
    lines = (ns / "events.txt").read_text().splitlines()
    (ns / "events.txt").write_text("".join(
        f"{round(float(t) * 1e9)} {x} {y} {p}\n" for t, x, y, p in map(str.split, lines)))
    rc, _, err = run_cli(["bos", ns, "--max-intervals", 1, "--iterations", 10, "--out",
                          tmp_path / "ns.h5"], capsys)
    assert rc == 2 and "event times in nanoseconds read as microseconds?" in err, err
    rc, _, err = run_cli(["bos", ns, "--time-unit", "ns", "--max-intervals", 1,
                          "--iterations", 10, "--out", tmp_path / "ns.h5"], capsys)
    assert rc == 0, err
    ms = tmp_path / "ms"
    shutil.copytree(scene, ms)
    rows = [ln.split(maxsplit=1) for ln in (ms / "images.txt").read_text().splitlines()]
    (ms / "images.txt").write_text("".join(f"{round(float(t) * 1e3)} {f}\n" for t, f in rows))
    # whole ms read as µs lie closer than any camera's frames: read as ms, said (they had
    # been refused, and a 100 fps list in whole ms blamed on the contrast threshold, probe
    # BOSIN)
    rc, _, err = run_cli(["bos", ms, "--out", tmp_path / "ms.h5"], capsys)
    assert rc == 0 and "read as milliseconds, which span the events" in err, err
    assert read_flow_h5(tmp_path / "ms.h5").t0.tolist()[:2] == [0, 8000]


def test_frames_in_nanoseconds_beside_events_in_microseconds_are_named(tmp_path, capsys):
    """Frames spanning 1000x the events' span gave 'they do not overlap in time' without
    a unit hint (probe AT)."""
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    d = tmp_path / "rec"
    write_schlieren(simulate_schlieren("plume", sensor_size=(48, 40), duration_s=13 / 120,
                                       seed=0), d)
    rows = [ln.split(None, 1) for ln in (d / "images.txt").read_text().splitlines()]
    (d / "images.txt").write_text("".join(f"{round(float(a) * 1e9) + 10**9} {b}\n"
                                          for a, b in rows))
    rc, _, err = run_cli(["bos", d, "--out", tmp_path / "x.h5"], capsys)
    assert rc == 2 and "do not overlap in time" in err and \
        re.search(r"us, 10\d\dx: frame times in another unit\?", err), err


def test_inverted_polarity_is_named_with_or_without_a_contrast_threshold(scene, tmp_path,
                                                                          capsys):
    """Events with ON and OFF the other way round: without C the refusal spoke of 'no
    texture, still air or noise'; with --contrast-threshold the flow came out reversed,
    unsaid (probe AT). convert --invert-polarity mends the file."""
    flipped = _copy(scene, tmp_path, "flipped")
    rows = [ln.split() for ln in (scene / "events.txt").read_text().splitlines()]
    (flipped / "events.txt").write_text("".join(f"{t} {x} {y} {1 - int(p)}\n"
                                                for t, x, y, p in rows))
    for extra in ([], ["--contrast-threshold", "0.2"]):
        _one_line_error(["bos", flipped, "--out", tmp_path / "x.h5", *extra], capsys,
                        "anti-correlate with the frames' log difference",
                        "polarity is inverted", "--invert-polarity")
    mended = _copy(scene, tmp_path, "mended")
    rc, _, err = run_cli(["convert", flipped / "events.txt", mended / "events.txt",
                          "--invert-polarity"], capsys)
    assert rc == 0, err
    assert (mended / "events.txt").read_text().splitlines()[1:] == \
        (scene / "events.txt").read_text().splitlines()


def test_frames_at_twice_the_event_resolution_are_refused(scene, tmp_path, capsys):
    """Frames at 2x the events' resolution (events.txt stating no size) were solved on the
    frames' grid after warnings naming other causes, the flow 3x too small (probe AT)."""
    from evmotion.io.pngfile import read_png, write_png

    big = _copy(scene, tmp_path, "big")
    rows = [ln.split() for ln in (scene / "events.txt").read_text().splitlines()
            if not ln.startswith("#")]
    # the sensor's noise over its whole extent, as a recording has it
    rng = np.random.default_rng(0)
    t_end = float(rows[-1][0])
    rows += [[f"{t:.6f}", str(x), str(y), str(p)] for t, x, y, p in zip(
        rng.uniform(0, t_end, 1500), rng.integers(0, 40, 1500), rng.integers(0, 48, 1500),
        rng.integers(0, 2, 1500), strict=True)]
    rows.sort(key=lambda r: float(r[0]))
    (big / "events.txt").write_text("".join(" ".join(r) + "\n" for r in rows))
    for png in sorted((big / "images").glob("*.png")):
        img = read_png(png)[0]
        write_png(png, img.repeat(2, axis=0).repeat(2, axis=1))
    _one_line_error(["bos", big, "--out", tmp_path / "x.h5"], capsys,
                    "the frames are 80x96 px but every event lies within",
                    "1/2 of them", "resize them to 40x48")


def test_frames_at_twice_the_event_resolution_away_from_the_edge_are_refused(tmp_path,
                                                                              capsys):
    """The same frames at 2x, the events those of the air only, none in the last 8 rows
    and columns of the events' grid: the events' extent left the edge unreached, and with
    C given the run went on on the frames' grid (probe AY). Where the events fire (the
    frames' change binned 2 x 2, not at full size) says it."""
    from evmotion.io.pngfile import read_png, write_png
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    write_schlieren(simulate_schlieren("plume", sensor_size=(96, 80), duration_s=2 / 120,
                                       seed=0), tmp_path / "same")
    big = _copy(tmp_path / "same", tmp_path, "big")
    rows = [ln.split() for ln in (big / "events.txt").read_text().splitlines()
            if not ln.startswith("#")]
    rows = [r for r in rows if int(r[1]) < 72 and int(r[2]) < 88]
    assert len(rows) >= 1000
    (big / "events.txt").write_text("".join(" ".join(r) + "\n" for r in rows))
    for png in sorted((big / "images").glob("*.png")):
        write_png(png, read_png(png)[0].repeat(2, axis=0).repeat(2, axis=1))
    for extra in ([], ["--contrast-threshold", "0.2"]):
        _one_line_error(["bos", big, "--out", tmp_path / "x.h5", *extra], capsys,
                        "1/2 of them", "binned 2x2", "resize them to 80x96")
    # the frames at the events' size: solved
    rc, _, err = run_cli(["bos", tmp_path / "same", "--out", tmp_path / "y.h5",
                          "--contrast-threshold", "0.2", "--max-intervals", "1"], capsys)
    assert rc == 0, err


@pytest.mark.parametrize("unit, factor", [("ms", 1e3), ("us", 1e6)])
def test_event_times_in_a_smaller_unit_are_named(scene, tmp_path, capsys, unit, factor):
    """events.txt in milliseconds beside images.txt in seconds: a warning, then the
    first thousandth of the events met the frames and the run was refused as inverted
    polarity; flipped as that said, it ran to nothing with rc 0 (probe CC)."""
    slow = _copy(scene, tmp_path, "slow")
    rows = [ln.split() for ln in (scene / "events.txt").read_text().splitlines()
            if not ln.startswith("#")]
    # from the frames' start: the first thousandth of the events overlaps them
    t_first = float(rows[0][0])
    (slow / "events.txt").write_text("".join(f"{(float(t) - t_first) * factor:.6f} {x} {y} "
                                             f"{p}\n" for t, x, y, p in rows))
    _one_line_error(["bos", slow, "--out", tmp_path / "x.h5"], capsys,
                    f"event times in {'milliseconds' if unit == 'ms' else 'microseconds'} "
                    "read as seconds?", f"--time-unit {unit} reads the events' times")
    rc, _, err = run_cli(["bos", slow, "--out", tmp_path / "y.h5", "--time-unit", unit],
                         capsys)
    assert rc == 0, err


def test_frames_holding_the_events_view_at_an_offset_are_refused(tmp_path, capsys):
    """Frames larger than the events' view, which they hold 12 px in and 8 px down
    (events.txt stating no size): refused as 'frames not of these events', and with C
    given solved to a flow no better than zero, rc 0 (probe CC). Where the events follow
    the frames' change best says it; the same events at the frames' corner are solved."""
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    write_schlieren(simulate_schlieren("plume", sensor_size=(96, 120), duration_s=6 / 120,
                                       seed=0), tmp_path / "full")
    rows = [ln.split() for ln in (tmp_path / "full" / "events.txt").read_text().splitlines()
            if not ln.startswith("#")]
    for name, (ox, oy) in (("offset", (12, 8)), ("corner", (0, 0))):
        view = _copy(tmp_path / "full", tmp_path, name)
        kept = [(t, int(x) - ox, int(y) - oy, p) for t, x, y, p in rows
                if ox <= int(x) < ox + 100 and oy <= int(y) < oy + 80]
        (view / "events.txt").write_text("".join(f"{t} {x} {y} {p}\n" for t, x, y, p in kept))
        if name == "offset":
            for extra in ([], ["--contrast-threshold", "0.2"]):
                _one_line_error(["bos", view, "--out", tmp_path / "x.h5", *extra], capsys,
                                "the frames are 120x96 px and the events lie within",
                                "at (12, 8) px into the frames",
                                "crop them to the event sensor's size from x 12, y 8")
        else:
            rc, _, err = run_cli(["bos", view, "--out", tmp_path / "y.h5",
                                  "--contrast-threshold", "0.2", "--max-intervals", "1"],
                                 capsys)
            assert rc == 0, err


@pytest.mark.parametrize("blank", [0, 3])
def test_a_blank_frame_is_said_as_such_only(tmp_path, capsys, blank):
    """A uniform frame among textured ones changes the frames everywhere: it was said as
    frames and events not showing the same view, and, first, as the sensor's start-up,
    both advising wrong actions (probe AT)."""
    from evmotion.io.pngfile import read_png, write_png

    d = plume_scene(tmp_path / "rec", intervals=8)
    png = sorted((d / "images").glob("*.png"))[blank]
    img = read_png(png)[0]
    write_png(png, np.full_like(img, 128))
    rc, _, err = run_cli(["bos", d, "--iterations", 10, "--out", tmp_path / "b.h5"], capsys)
    assert rc == 0, err
    assert "textureless" in err and "do not show the same view" not in err, err
    if blank == 0:  # (the simulated sensor's real start-up is in its first interval)
        assert "follow the frames' change there" not in err, err


def test_q_left_unscored_against_another_frame_rate_is_said(scene, tmp_path, capsys):
    """Probe BA: against the ground truth of the same scene at 240 fps, eval scored the
    flow and dropped q_corr without a word (no window spans one of its intervals)."""
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    fast = tmp_path / "fast"
    write_schlieren(simulate_schlieren("plume", sensor_size=(48, 40), duration_s=2 / 120,
                                       fps=240.0, seed=0), fast)
    out = tmp_path / "b.h5"
    assert _run(["bos", scene, "--iterations", "20", "--out", out], capsys)[0] == 0
    rc, text, _ = _run(["eval", out, "--gt", scene / "schlieren_gt.h5"], capsys)
    assert rc == 0 and "q_corr=" in text and "q is not scored" not in text
    rc, text, _ = _run(["eval", out, "--gt", fast / "schlieren_gt.h5"], capsys)
    assert rc == 0, text
    assert "q_corr" not in text.split("\n")[1]
    assert "windows span no single frame interval of the ground truth: their q is not scored" \
        in text
    rc, text, _ = _run(["eval", out, "--gt", fast / "schlieren_gt.h5", "--json"], capsys)
    assert json.loads(text)["windows_q_scored"] == 0


def test_frames_in_milliseconds_beside_events_in_seconds(tmp_path, capsys):
    """Probe BS: a timestamps file in decimal ms beside events.txt in s was blamed on the
    cameras' registration; --time-unit ms, the hint, re-read the events too, and nothing
    read the frames' unit on its own."""
    scene = plume_scene(tmp_path / "scene")
    folder = tmp_path / "ms"
    folder.mkdir()
    shutil.copy(scene / "events.txt", folder / "events.txt")
    shutil.copytree(scene / "images", folder / "frames")
    lines = [ln.split() for ln in (scene / "images.txt").read_text().splitlines() if ln]
    (folder / "frames" / "timestamps.txt").write_text(
        "".join(f"{float(t) * 1e3:.6f}\n" for t, _ in lines))
    argv = ["bos", folder / "events.txt", "--frames", folder / "frames", "--iterations", "20",
            "--out", tmp_path / "o.h5"]
    _one_line_error(argv, capsys, "timestamps.txt", "another unit",
                    "--frames-time-unit ms")
    rc, _, err = _run([*argv, "--frames-time-unit", "ms"], capsys)
    assert rc == 0, err
    ref = tmp_path / "ref.h5"
    assert _run(["bos", scene, "--iterations", "20", "--out", ref], capsys)[0] == 0
    np.testing.assert_array_equal(read_flow_h5(tmp_path / "o.h5").flow,
                                  read_flow_h5(ref).flow)


def test_frame_list_faults_are_named_by_their_files(tmp_path, capsys):
    """Probe BS: duplicate times were 'entries 4 and 5' (from 0, comment lines not
    counted); info called a folder with a truncated frame fine."""
    scene = plume_scene(tmp_path / "scene")
    lines = (scene / "images.txt").read_text().splitlines()
    t1 = lines[1].split()[0]
    (scene / "images.txt").write_text("# t path\n\n" + "\n".join(
        [lines[0], f"{t1} {lines[1].split()[1]}", f"{t1} {lines[2].split()[1]}"]) + "\n")
    _one_line_error(["bos", scene, "--out", tmp_path / "x.h5"], capsys,
                    "duplicate frame timestamps", "frame_00000001.png and frame_00000002.png")
    scene = plume_scene(tmp_path / "cut")
    frame = sorted((scene / "images").iterdir())[1]
    frame.write_bytes(frame.read_bytes()[:-20])
    rc, text, err = _run(["info", scene, "--json"], capsys)
    assert rc == 0, err
    said = json.loads(text)["frames_info"]["error"]
    assert frame.name in said and "truncated PNG" in said


def test_png_dir_takes_max_speed(scene, tmp_path, capsys, monkeypatch):
    # probe BX: bos had no --max-speed, flow had
    import evmotion.viz.bos as vb

    rims = []
    real = vb.save_bos_pngs

    def spy(*a, **kw):
        rims.append(kw["flow_max"])
        return real(*a, **kw)

    monkeypatch.setattr(vb, "save_bos_pngs", spy)
    rc, _, err = _run(["bos", scene, "--iterations", 5, "--max-intervals", 2, "--max-speed",
                       123, "--png-dir", tmp_path / "png", "--out", tmp_path / "b.h5"], capsys)
    assert rc == 0, err
    assert rims == [123.0, 123.0]
