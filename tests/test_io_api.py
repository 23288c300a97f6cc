"""The evmotion.io API: detection by content, windows, atomic writes, describe, calibration."""

from __future__ import annotations

import numpy as np
import pytest

import evmotion.io as eio
from evmotion.errors import EvmotionWarning, FormatError, ParameterError
from evmotion.events import EventArray


def _events(n=20_000, seed=0):
    rng = np.random.default_rng(seed)
    return EventArray(x=rng.integers(0, 240, n), y=rng.integers(0, 180, n),
                      t=1_000_000 + np.sort(rng.integers(0, 500_000, n)),
                      p=rng.integers(0, 2, n), sensor_size=(180, 240))


def test_detection_is_by_content_not_extension(tmp_path, shared_data):
    ecd_folder = shared_data / "ecd_30k_windows" / "boxes_rotation"
    assert eio.detect_format(ecd_folder) == "ecd"
    assert eio.detect_format(ecd_folder / "events.txt") == "ecd"
    ev = _events(100)
    eio.write_events(tmp_path / "a.h5", ev)
    (tmp_path / "misnamed.txt").write_bytes((tmp_path / "a.h5").read_bytes())
    assert eio.detect_format(tmp_path / "misnamed.txt") == "h5"
    eio.write_events(tmp_path / "b.npz", ev)
    assert eio.detect_format(tmp_path / "b.npz") == "npy"
    (tmp_path / "junk.txt").write_text("hello world\n")
    with pytest.raises(FormatError, match="junk.txt.*not recognised"):
        eio.read_events(tmp_path / "junk.txt")
    (tmp_path / "empty.h5").write_bytes(b"")
    with pytest.raises(FormatError, match="empty"):
        eio.detect_format(tmp_path / "empty.h5")


def test_iter_events_windows_match_in_memory_windows(tmp_path):
    ev = _events()
    eio.write_events(tmp_path / "a.h5", ev)
    got = list(eio.iter_events(tmp_path / "a.h5", 3000, window_us=25_000))
    ref = list(ev.windows_by_duration(25_000))
    assert len(got) == len(ref)
    for g, w in zip(got, ref, strict=True):
        np.testing.assert_array_equal(g.t, ev.window(w).t)
        assert g.meta["window"] == (w.t0, w.t1)


def test_iter_events_windows_keep_empty_ones(tmp_path):
    ev = _events(10)
    t = np.array([0, 1, 2, 50, 51, 200, 201, 202, 203, 204]) + 1000
    ev = EventArray(x=ev.x, y=ev.y, t=t, p=ev.p, sensor_size=ev.sensor_size)
    eio.write_events(tmp_path / "g.npz", ev)
    got = list(eio.iter_events(tmp_path / "g.npz", 2, window_us=40))
    assert [len(g) for g in got] == [3, 2, 0, 0, 0, 5]
    assert [len(g) for g in eio.iter_events(tmp_path / "g.npz", 2, window_us=40,
                                            drop_empty=True)] == [3, 2, 5]


def test_iter_events_time_range_generic(tmp_path, shared_data):
    folder = shared_data / "ecd_30k_windows" / "dynamic_rotation"
    whole = eio.read_events(folder)
    t0, t1 = int(whole.t[5000]), int(whole.t[25000])
    parts = list(eio.iter_events(folder, 4000, t0=t0, t1=t1))
    np.testing.assert_array_equal(np.concatenate([p.t for p in parts]),
                                  whole.slice_time(t0, t1).t)
    assert len(eio.read_events(folder, t0=t0, t1=t1)) == len(whole.slice_time(t0, t1))


@pytest.mark.parametrize("ext", [".h5", ".txt", ".npz"])
def test_write_events_streams_chunks_atomically(tmp_path, ext):
    ev = _events()
    chunks = (ev[s:s + 4000] for s in range(0, len(ev), 4000))
    eio.write_events(tmp_path / f"out{ext}", chunks)
    back = eio.read_events(tmp_path / f"out{ext}", sensor_size=(180, 240))
    for k in "xytp":
        np.testing.assert_array_equal(getattr(back, k), getattr(ev, k))

    def failing():
        yield ev[:100]
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError):
        eio.write_events(tmp_path / f"fail{ext}", failing())
    assert not [p for p in tmp_path.iterdir() if p.name.startswith((".fail", "fail"))]


@pytest.mark.parametrize("fmt", ["aedat2", "aedat3"])
@pytest.mark.parametrize("cut", [1, 777, 9000])
def test_aedat_writers_stream_chunks_into_the_bytes_of_one_array(tmp_path, fmt, cut):
    """AEDAT 2.0 and 3.1 are written chunk by chunk (convert held every event: probe DL),
    with the bytes of one array's writing (after the header, whose AEDAT 3.1 start time
    is the clock's): across AEDAT 2.0's 2^32 us wrap, AEDAT 3.1's 2^31 us epochs and its
    8,192-event packets; chunks out of order are refused as a whole array is."""
    from evmotion.io.registry import get_format

    rng = np.random.default_rng(4)
    n = 20_000
    t = np.sort(rng.integers(0, 4_500_000_000, n)).astype(np.int64)  # 75 min, gaps < 2^31
    ev = EventArray(rng.integers(0, 240, n), rng.integers(0, 180, n), t,
                    rng.integers(0, 2, n), (180, 240))
    spec = get_format(fmt)
    spec.write(tmp_path / "whole.aedat", ev)
    eio.write_events(tmp_path / "parts.aedat", (ev[s:s + cut] for s in range(0, n, cut)),
                     format=fmt)

    def payload(name):
        data = (tmp_path / name).read_bytes()
        return data[data.index(b"#!END-HEADER") if fmt == "aedat3" else 0:]

    assert payload("parts.aedat") == payload("whole.aedat")
    back = spec.read(tmp_path / "parts.aedat")
    for k in "xytp":
        np.testing.assert_array_equal(getattr(back, k), getattr(ev, k))
    with pytest.raises(FormatError, match="stores times in order"):
        spec.write(tmp_path / "bad.aedat", iter([ev[10:20], ev[:10]]))
    assert not (tmp_path / "bad.aedat").exists()


def test_write_events_unknown_extension(tmp_path):
    with pytest.raises(FormatError, match="extension '.xyz'"):
        eio.write_events(tmp_path / "a.xyz", _events(10))


def test_describe_and_calibration(tmp_path, shared_data):
    folder = shared_data / "ecd_rotation_windows" / "poster_rotation"
    d = eio.describe(folder, chunk_events=7000)
    assert d["format"] == "ecd" and d["n_events"] == 30_000
    assert d["sensor_size"] == (180, 240)
    assert 0 < d["positive_fraction"] < 1 and d["rate_ev_per_s"] > 0
    assert d["calibration"]["fx"] == pytest.approx(eio.read_calibration(folder)["fx"])
    ev = eio.read_events(folder)
    eio.write_events(tmp_path / "p.h5", ev, calibration=eio.read_calibration(folder))
    assert eio.read_calibration(tmp_path / "p.h5")["dist"][0] == pytest.approx(-0.368436311798)
    with pytest.raises(FormatError, match="no calibration"):
        eio.read_calibration(shared_data / "ecd_shapes_rotation_first120k" /
                             "shapes_rotation.mat")


def test_public_api_from_package_root():
    import evmotion

    assert evmotion.read_events is eio.read_events


def test_write_events_free_metadata(tmp_path):
    ev = _events(100)
    eio.write_events(tmp_path / "m.h5", ev, simulator_scene="rotation", simulator_seed=3)
    assert eio.read_events(tmp_path / "m.h5").meta["provenance"] == {
        "simulator_scene": "rotation", "simulator_seed": 3}
    # an EvmotionWarning, which filterwarnings(category=EvmotionWarning) reaches (probe BE:
    # a bare UserWarning)
    with pytest.warns(EvmotionWarning, match="simulator_seed"):
        eio.write_events(tmp_path / "m.npz", ev, simulator_seed=3)
    assert len(eio.read_events(tmp_path / "m.npz")) == 100


def test_frames_and_imu_from_any_format(tmp_path, shared_data):
    import png

    from evmotion.io import aux

    (tmp_path / "events.txt").write_text("0.1 1 2 1\n0.2 3 4 0\n")
    (tmp_path / "images").mkdir()
    img = np.arange(20 * 30, dtype=np.uint8).reshape(20, 30)
    with open(tmp_path / "images" / "frame_00000000.png", "wb") as fh:
        png.Writer(width=30, height=20, greyscale=True).write(fh, img)
    (tmp_path / "images.txt").write_text("0.05 images/frame_00000000.png\n")
    (tmp_path / "imu.txt").write_text("0.1 0 0 9.8 0.1 0.2 0.3\n")
    ev = eio.read_events(tmp_path)
    assert ev.sensor_size == (20, 30) and ev.meta["sensor_size_from"] == "images"
    fr = aux.read_frames(tmp_path)
    assert fr.t.tolist() == [50_000]
    np.testing.assert_array_equal(fr.images[0], img)
    imu = aux.read_imu(tmp_path)
    assert imu.gyro.tolist() == [[0.1, 0.2, 0.3]] and imu.accel[0, 2] == 9.8
    # given the events file, the IMU is the imu.txt beside it (the events file itself was
    # parsed as an IMU table: a second pass over the whole recording, to fail)
    imu = aux.read_imu(tmp_path / "events.txt", format="ecd")
    assert imu.gyro.tolist() == [[0.1, 0.2, 0.3]]
    (tmp_path / "imu.txt").unlink()
    with pytest.raises(FormatError, match="no imu.txt beside"):
        aux.read_imu(tmp_path / "events.txt", format="ecd")
    a4 = shared_data / "formats" / "davis346.aedat4"
    assert len(aux.read_imu(a4)) == 2363 and len(aux.read_frames(a4)) == 59
    with pytest.raises(FormatError, match="holds no APS frames"):
        aux.read_frames(shared_data / "formats" / "gen4.dat")


@pytest.mark.parametrize("ext", [".h5", ".npz"])
def test_truncated_files_name_the_file(tmp_path, ext):
    eio.write_events(tmp_path / f"t{ext}", _events(5000))
    data = (tmp_path / f"t{ext}").read_bytes()
    (tmp_path / f"cut{ext}").write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match=f"cut\\{ext}"):
        eio.read_events(tmp_path / f"cut{ext}", format=ext.lstrip(".").replace("npz", "npy"))


def test_a_truncated_hdf5_file_is_named_as_such_without_format(tmp_path):
    """Detected by content, a cut HDF5 file said 'format not recognised' (probe); its
    signature says HDF5, so HDF5's own reason is given."""
    eio.write_events(tmp_path / "t.h5", _events(5000))
    data = (tmp_path / "t.h5").read_bytes()
    (tmp_path / "cut.h5").write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match="cut.h5: not a readable HDF5 file .truncated file"):
        eio.read_events(tmp_path / "cut.h5")


def test_truncated_mat(tmp_path, shared_data):
    data = (shared_data / "ecd_shapes_rotation_first120k" / "shapes_rotation.mat").read_bytes()
    (tmp_path / "cut.mat").write_bytes(data[:5000])
    with pytest.raises(FormatError, match="cut.mat"):
        eio.read_events(tmp_path / "cut.mat")


def test_iter_events_explicit_overlapping_windows(tmp_path):
    ev = _events()
    eio.write_events(tmp_path / "a.npz", ev)
    rng = np.random.default_rng(2)
    starts = np.sort(rng.integers(ev.t[0] - 1000, ev.t[-1], 25))
    edges = np.column_stack([starts, starts + rng.integers(0, 80_000, 25)])
    got = list(eio.iter_events(tmp_path / "a.npz", 1500, windows=edges))
    assert len(got) == len(edges)
    for g, (a, b) in zip(got, edges, strict=True):
        np.testing.assert_array_equal(g.t, ev.slice_time(int(a), int(b)).t)
        assert g.meta["window"] == (a, b)
    with pytest.raises(ParameterError, match="sorted by start"):
        list(eio.iter_events(tmp_path / "a.npz", windows=[(10, 20), (5, 8)]))


@pytest.mark.parametrize("ext, name", [(".h5", "h5"), (".txt", "ecd"), (".npz", "npy"),
                                       (".dat", "dat"), (".raw", "evt3"),
                                       (".aedat4", "aedat4"), (".aedat", "aedat2")])
def test_output_format_from_extension(ext, name):
    if name not in {f.name for f in eio.all_formats()}:
        pytest.skip(f"format module {name} not present")
    assert eio.format_for_output(f"out{ext}") == name


def test_own_outputs_are_named_not_unrecognised(tmp_path, capsys):
    """egomotion or view on params.h5 (or a ground truth) said 'format not recognised'."""
    from evmotion.cli import main

    sim = tmp_path / "s.h5"
    assert main(["simulate", "translation", "--size", "40x50", "--duration", "0.02",
                 "--out", str(sim)]) == 0
    assert main(["egomotion", str(sim), "--warp", "translation", "--window-events", "500",
                 "--max-windows", "1", "--out", str(tmp_path / "e")]) == 0
    capsys.readouterr()
    for path, what in ((tmp_path / "e" / "params.h5", "evmotion-params of egomotion"),
                       (tmp_path / "s_gt.h5", "evmotion-sim-gt")):
        with pytest.raises(FormatError, match=f"is an evmotion output \\({what}\\)"):
            eio.read_events(path)


def test_a_sensor_no_reader_takes_back_cannot_be_made():
    """20000 x 20000 px was written by most writers, then refused by every reader as a
    corrupt header (over 16384 px per side): no EventArray holds such a sensor."""
    from evmotion.errors import EventDataError
    from evmotion.events import EventArray

    with pytest.raises(EventDataError, match=r"outside 1\.\.16384 px per side"):
        EventArray(x=[0, 19999], y=[0, 5], t=[0, 1], p=[1, 0], sensor_size=(20000, 20000))


def test_npz_size_keys_and_the_inferred_size_warning(tmp_path, capsys):
    """height/width and resolution (width, height) arrays were ignored, and a file without
    any took its largest coordinates as the sensor silently (text, .mat and .h5 said so);
    the CLI says a warning once even when it reads the file twice (summary, events)."""
    import warnings

    from evmotion.cli import main
    from evmotion.errors import EvmotionWarning

    cols = {"x": np.array([0, 5, 100]), "y": np.array([0, 3, 50]), "t": np.array([0, 10, 20]),
            "p": np.array([0, 1, 1])}
    for name, extra, size in (("a", {"height": 180, "width": 240}, (180, 240)),
                              ("b", {"resolution": np.array([346, 260])}, (260, 346)),
                              ("c", {}, (51, 101))):
        np.savez(tmp_path / f"{name}.npz", **cols, **extra)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            assert eio.read_events(tmp_path / f"{name}.npz").sensor_size == size
        said = [w for w in caught if issubclass(w.category, EvmotionWarning)]
        assert (len(said) == 1 and "no sensor size in the file" in str(said[0].message)) \
            == (not extra)
    assert main(["info", str(tmp_path / "c.npz")]) == 0
    assert capsys.readouterr().err.count("no sensor size in the file") == 1


@pytest.mark.parametrize("name", ["e.txt", "e.npz", "e.h5", "e.aedat4", "e.raw", "e.dat",
                                  "e.aedat", "e.bag"])
@pytest.mark.parametrize("size", [(180, 240), (100, 120)])
def test_empty_recording_round_trips_with_its_sensor(tmp_path, name, size):
    # an empty text file reads as a mistake and a bag without messages has no size: the
    # writers keep both for an empty recording
    if name.endswith(".bag"):
        pytest.importorskip("rosbags")
    empty = EventArray(x=np.zeros(0, int), y=np.zeros(0, int), t=np.zeros(0, int),
                       p=np.zeros(0, int), sensor_size=size)
    eio.write_events(tmp_path / name, empty)
    back = eio.read_events(tmp_path / name)
    assert len(back) == 0 and tuple(back.sensor_size) == size


def test_an_unfinished_part_file_is_named_as_such(tmp_path):
    # what a killed convert leaves ('c.h5.part') was 'format not recognised' (probe X)
    part = tmp_path / "c.h5.part"
    part.write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 20)
    with pytest.raises(FormatError, match="unfinished output of an interrupted evmotion "
                                          "run.*--resume.*delete it"):
        eio.read_events(part)


@pytest.mark.parametrize("suffix", [".h5", ".txt", ".npz"])
def test_items_that_are_not_event_arrays_are_named(tmp_path, suffix):
    # a list of rows or a dict of columns met "AttributeError: 'list' object has no
    # attribute 'sensor_size'" in every writer (probe)
    for bad, kind in (([[1, 2, 3, 1]], "list"), (dict(x=[1], y=[1], t=[1], p=[1]), "str")):
        with pytest.raises(ParameterError, match=rf"write_events: item 0 of events is a "
                                                 rf"{kind}, not an EventArray"):
            eio.write_events(tmp_path / f"w{suffix}", bad)
        assert not (tmp_path / f"w{suffix}").exists()


@pytest.mark.parametrize("size", ["big", (1, 2, 3), (-120, 160), (120.5, 160)])
@pytest.mark.parametrize("suffix", [".txt", ".h5"])
def test_a_bad_sensor_size_argument_is_named_for_every_format(tmp_path, size, suffix):
    # the text reader took "big" for a corrupt file, cut (1, 2, 3) to (1, 2) and
    # floored 120.5 (probe)
    rec = tmp_path / f"r{suffix}"
    eio.write_events(rec, EventArray(x=[1, 2], y=[0, 1], t=[10, 20], p=[1, 0],
                                     sensor_size=(120, 160)))
    with pytest.raises(ParameterError, match=r"^sensor_size "):
        eio.read_events(rec, sensor_size=size)
    with pytest.raises(ParameterError, match=r"^sensor_size "):
        list(eio.iter_events(rec, 1, sensor_size=size))


@pytest.mark.parametrize("chunk", ["3", 1.5, True, 0])
def test_a_chunk_size_must_be_a_whole_number(tmp_path, chunk):
    rec = tmp_path / "r.h5"
    eio.write_events(rec, EventArray(x=[1, 2], y=[0, 1], t=[10, 20], p=[1, 0],
                                     sensor_size=(120, 160)))
    with pytest.raises(ParameterError, match="chunk_events must be a whole number >= 1"):
        list(eio.iter_events(rec, chunk))


def test_concatenate_and_fwl_name_what_is_not_events():
    from evmotion.eval import fwl
    from evmotion.events import concatenate

    with pytest.raises(ParameterError, match="concatenate: item 0 is a list"):
        concatenate([[1, 2]])
    with pytest.raises(ParameterError, match="fwl: events must be an EventArray"):
        fwl([1, 2], np.zeros((3, 4, 2)))


def test_float32_epoch_seconds_are_refused_as_too_coarse(tmp_path):
    # float32 resolves 128 s at 1.6e9 s: 30,000 events at one time, duration 0 (probe)
    t = (1.6e9 + np.arange(1000) * 1e-4).astype(np.float32)
    np.savez(tmp_path / "f32.npz", t=t, x=np.arange(1000) % 50, y=np.arange(1000) % 40,
             p=np.arange(1000) % 2)
    with pytest.raises(FormatError, match=r"f32.npz: field 't': float32 times reaching "
                                          r"1.6e\+09 s step by 1.28e\+08 us there \(1 "
                                          r"distinct times for 1,000 events\)") as exc:
        eio.read_events(tmp_path / "f32.npz", sensor_size=(40, 50))
    assert "\n" not in str(exc.value)
    # float32 seconds from the recording's start resolve microseconds: read
    np.savez(tmp_path / "ok.npz", t=(np.arange(1000) * 1e-4).astype(np.float32),
             x=np.arange(1000) % 50, y=np.arange(1000) % 40, p=np.arange(1000) % 2)
    assert len(eio.read_events(tmp_path / "ok.npz", sensor_size=(40, 50))) == 1000


def test_an_empty_npz_is_named_empty_by_info(tmp_path, capsys):
    # info tries an .npz as a flow file first: "cannot describe as flow file: EOFError:
    # No data left in file" (probe)
    from evmotion.cli import main

    (tmp_path / "empty.npz").write_bytes(b"")
    assert main(["info", str(tmp_path / "empty.npz")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("empty.npz: the file is empty") and "\n" not in err, err


def test_a_frame_list_given_as_the_recording_is_named_as_such(tmp_path):
    # bos FOLDER/images.txt was 'format not recognised' (probe)
    images = tmp_path / "images.txt"
    images.write_text("# frames\n0.000000 images/frame_00000.png\n"
                      "0.008333 images/frame_00001.png\n")
    with pytest.raises(FormatError, match=r"images.txt: is a list of frames \('t path' "
                                          r"lines\), not events.*give its folder") as exc:
        eio.read_events(images)
    assert "\n" not in str(exc.value)


def test_a_recording_that_pauses_for_most_of_its_span_is_said(tmp_path):
    # 16 flipped bytes in an EVT3 body moved 55 % of its events 10.6 s on: read, and
    # described by info, without a word (probe AE)
    import warnings

    from evmotion.errors import EvmotionWarning

    rng = np.random.default_rng(0)
    n = 4000
    t = np.sort(rng.integers(0, 600_000, n))
    t[n // 2:] += 10_000_000
    ev = EventArray(x=rng.integers(0, 64, n), y=rng.integers(0, 48, n), t=t,
                    p=rng.integers(0, 2, n), sensor_size=(48, 64))
    eio.write_events(tmp_path / "jump.h5", ev)
    for fn in (eio.read_events, lambda p: eio.describe(p, chunk_events=1000)):
        with pytest.warns(EvmotionWarning, match=rf"no event for 10(\.\d)? s between events "
                                                 rf"{n // 2 - 1} and {n // 2}.*2,000 events"):
            fn(tmp_path / "jump.h5")
    eio.write_events(tmp_path / "steady.h5", ev[: n // 2])
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)
        eio.read_events(tmp_path / "steady.h5")
        eio.describe(tmp_path / "steady.h5", chunk_events=1000)


@pytest.mark.parametrize("suffix", [".npy", ".txt", None])
@pytest.mark.parametrize(("values", "said"), [
    ([-1, 0], r"holds -1 \(5 events\) and 0 \(5\) but no \+1: neither 0/1 nor -1/\+1"),
    ([-1, 0, 1, 1, 1], r"holds -1 \(2 events\) and 0 \(2\) and \+1 \(6\): neither")],
    ids=["no-plus-one", "three-values"])
def test_polarities_minus_one_and_zero_together_are_refused(tmp_path, suffix, values, said):
    """-1 and 0 both read OFF: such a file was read as all OFF, unsaid (probe AS), and
    -1/0/+1 as 0/0/1 (probe BQ)."""
    from evmotion.errors import EventDataError, FormatError
    from evmotion.events import EventArray
    from evmotion.io import read_events

    p = np.resize(values, 10)
    t, x, y = np.arange(10) * 10, np.arange(10) % 4, np.zeros(10, int)
    if suffix is None:
        with pytest.raises(EventDataError, match=said):
            EventArray(x=x, y=y, t=t, p=p, sensor_size=(4, 4))
        return
    path = tmp_path / f"e{suffix}"
    if suffix == ".npy":
        np.save(path, np.rec.fromarrays([t, x, y, p.astype(np.int8)], names="t,x,y,p"))
    else:
        path.write_text("".join(f"{a * 1e-6:.6f} {b} {c} {d}\n" for a, b, c, d in zip(
            t, x, y, p, strict=True)))
    with pytest.raises(FormatError, match=said):
        read_events(path, sensor_size=(4, 4))


def test_compressed_or_utf16_files_are_named_as_such(tmp_path):
    # probe BL: a gzip'd events.txt and a UTF-16 one were "format not recognised"
    import gzip
    import zipfile

    text = "0.000500 3 4 1\n0.001000 5 6 0\n"
    (tmp_path / "ev.txt.gz").write_bytes(gzip.compress(text.encode()))
    (tmp_path / "u16.txt").write_text(text, encoding="utf-16")
    with zipfile.ZipFile(tmp_path / "rec.zip", "w") as z:
        z.writestr("events.txt", text)
    for name, said in (("ev.txt.gz", "is gzip-compressed.*gunzip"),
                       ("u16.txt", "is text in UTF-16.*UTF-8"),
                       ("rec.zip", "is a zip archive.*extract")):
        with pytest.raises(FormatError, match=said):
            eio.read_events(tmp_path / name)


def test_time_unit_for_a_format_that_states_its_own_is_refused_in_words(tmp_path):
    # probe BL: "dat read: got an unexpected keyword argument 'time_unit'"
    ev = EventArray(x=[1, 2], y=[0, 1], t=[10, 20], p=[1, 0], sensor_size=(4, 5))
    eio.write_events(tmp_path / "r.dat", ev)
    for call in (eio.read_events, lambda p, **kw: next(eio.iter_events(p, 10, **kw))):
        with pytest.raises(ParameterError, match=r"time_unit='ms': .*r\.dat is 'dat', whose "
                                                 r"times carry their unit"):
            call(tmp_path / "r.dat", time_unit="ms")


def test_polarities_of_one_convention_then_another_are_refused_when_streamed(tmp_path):
    """-1/+1 in the first part of a text file, 0/1 after: each chunk passed alone, and
    info and convert read the whole file (probe BR)."""
    from evmotion.errors import FormatError
    from evmotion.io import ecd

    n = 4000
    p = np.r_[np.tile([-1, 1], n // 4), np.tile([0, 1], n // 4)]
    path = tmp_path / "mixed.txt"
    path.write_text("".join(f"{k * 1e-5:.6f} {k % 7} {k % 5} {v}\n" for k, v in enumerate(p)))
    with pytest.raises(FormatError, match=r"holds -1 \(event 0\) and 0 \(event 2000\)"):
        for _ in ecd.iter_chunks(path, 500, sensor_size=(8, 8), block_bytes=4096):
            pass


def test_explicit_windows_are_whole_microseconds_and_all_yielded(tmp_path):
    # seconds became (1, 1) and yielded nothing, a NaN or a 3-tuple failed in numpy, and a
    # window past the recording was not yielded at all, though one is promised per window
    # (probe CB)
    p = tmp_path / "rec.raw"
    eio.write_events(p, EventArray(x=[1, 2, 3, 4], y=[0, 0, 0, 0], t=[10, 20, 30, 40],
                                   p=[1, 0, 1, 1], sensor_size=(180, 240)))
    got = list(eio.iter_events(p, windows=[(15, 35), (100, 200)]))
    assert [len(e) for e in got] == [2, 0] and got[1].meta["window"] == (100, 200)
    after = list(eio.iter_events(p, windows=[(1000, 2000)]))
    assert len(after) == 1 and len(after[0]) == 0 and after[0].sensor_size == (180, 240)
    for bad, match in (([(1e-5, 3.5e-5)], r"whole µs, got \[1e-05, 3.5e-05\]: seconds"),
                       ([(0, np.nan)], "finite"), ([(1, 2, 3)], r"shape \(1, 3\)"),
                       ("ab", "pairs of whole µs, got 'ab'")):
        with pytest.raises(ParameterError, match=match):
            list(eio.iter_events(p, windows=bad))


@pytest.mark.parametrize("fmt", [None, "npy", "ecd", "evt2"])
def test_a_device_or_pipe_is_refused(tmp_path, fmt):
    # /dev/zero read with --format npy filled 24 GB of memory and ignored Ctrl-C; evt2
    # said "[Errno 20] Not a directory" (probe CE). A pipe in a child process (with no
    # writer, reading it blocks: a timeout, not a hang, where the check is gone); the
    # device only through the format's resolution (reading it would fill the memory)
    import os
    import subprocess
    import sys

    from evmotion.io.registry import resolve_format

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    code = ("import evmotion.io as eio\n"
            "try:\n"
            f"    eio.read_events({str(fifo)!r}, format={fmt!r})\n"
            "except Exception as e:\n"
            "    print(type(e).__name__, e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60).stdout
    assert out.startswith("FormatError") and "is not a regular file or folder" in out, out
    with pytest.raises(FormatError, match="is not a regular file or folder"):
        resolve_format("/dev/zero", fmt)
