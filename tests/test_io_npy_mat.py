"""npy/npz and MATLAB excerpts: real .mat files, structured/plain arrays, round trips."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import evmotion.io as eio
from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import mat, npy


def _events(n=3000, seed=0):
    rng = np.random.default_rng(seed)
    return EventArray(x=rng.integers(0, 240, n), y=rng.integers(0, 180, n),
                      t=np.sort(rng.integers(10**6, 10**8, n)), p=rng.integers(0, 2, n),
                      sensor_size=(180, 240))


def test_mat_ecd_struct(shared_data):
    path = shared_data / "ecd_shapes_rotation_first120k" / "shapes_rotation.mat"
    assert eio.detect_format(path) == "mat"
    ev = eio.read_events(path)
    assert len(ev) == 120_000 and ev.meta["variable"] == "events.e_data"
    assert ev.t[0] == 0 and ev.t[1] == 11 and ev.t[-1] == 1_428_658  # seconds -> µs
    assert ev.x.dtype == np.uint16 and ev.sensor_size == (180, 240)


def test_mat_undistorted_seq(shared_data):
    from evmotion.errors import EvmotionWarning

    path = shared_data / "ecd_dynamic_undistorted_excerpt" / "event.mat"
    with pytest.warns(EvmotionWarning, match="4,039 of 18,978 events lie outside"):
        kept = mat.read(path)
    assert kept.x.dtype == np.float32  # undistorted coordinates stay fractional
    assert len(kept) + kept.meta["dropped_outside"] == 18_978
    raw = mat.read(path, drop_outside=False, validate=False)
    assert len(raw) == 18_978
    with pytest.raises(FormatError, match="outside the sensor"):
        mat.read(path, drop_outside=False)
    assert raw.t[-1] == 9997  # µs already


def test_mat_missing_variable(tmp_path):
    import scipy.io

    scipy.io.savemat(tmp_path / "m.mat", {"foo": np.zeros((2, 2))})
    with pytest.raises(FormatError, match=r"m.mat.*no 4×N event array"):
        mat.read(tmp_path / "m.mat")


@pytest.mark.parametrize("name", ["a.npz", "a.npy"])
def test_npy_round_trip_bit_equal(tmp_path, name):
    ev = _events()
    eio.write_events(tmp_path / name, ev)
    back = eio.read_events(tmp_path / name, sensor_size=(180, 240))
    for k in "xytp":
        np.testing.assert_array_equal(getattr(back, k), getattr(ev, k))
    assert back.sensor_size == (180, 240)


def test_npz_keeps_sensor_size(tmp_path):
    ev = _events()
    npy.write(tmp_path / "a.npz", ev)
    assert npy.read(tmp_path / "a.npz").sensor_size == (180, 240)


def test_npz_sensor_size_of_other_tools(tmp_path):
    # tonic's sensor_size is (width, height, polarities): it was refused as "not two whole
    # numbers"; a two-value size that reads as a portrait sensor may be (width, height):
    # it is read as evmotion writes it, (height, width), and the other reading is said
    import warnings

    from evmotion.errors import EvmotionWarning

    ev = _events()
    cols = {"x": ev.x, "y": ev.y, "t": ev.t, "p": ev.p}
    np.savez(tmp_path / "tonic.npz", **cols, sensor_size=np.array([240, 180, 2]))
    assert npy.read(tmp_path / "tonic.npz").sensor_size == (180, 240)
    fits = ev[ev.x < 180]
    np.savez(tmp_path / "wh.npz", x=fits.x, y=fits.y, t=fits.t, p=fits.p,
             sensor_size=np.array([240, 180]))
    with pytest.warns(EvmotionWarning, match=r"\[240, 180\] read as \(height, width\).*"
                                             r"--sensor-size 180 240"):
        assert npy.read(tmp_path / "wh.npz").sensor_size == (240, 180)
    assert npy.read(tmp_path / "wh.npz", sensor_size=(180, 240)).sensor_size == (180, 240)
    np.savez(tmp_path / "hw.npz", **cols, sensor_size=np.array([180, 240]))
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        assert npy.read(tmp_path / "hw.npz").sensor_size == (180, 240)
    assert not any("(height, width)" in str(w.message) for w in rec)  # landscape: unsaid


def test_tonic_structured_and_size_inference(tmp_path):
    from evmotion.events import TONIC_DTYPE

    ev = _events()
    arr = np.empty(len(ev), TONIC_DTYPE)
    arr["x"], arr["y"], arr["t"], arr["p"] = ev.x, ev.y, ev.t, ev.p
    np.save(tmp_path / "tonic.npy", arr)
    back = npy.read(tmp_path / "tonic.npy")
    np.testing.assert_array_equal(back.t, ev.t)
    assert "max coordinate" in back.meta["sensor_size_from"]


def test_plain_n_by_4(tmp_path):
    ev = _events()
    txyp = np.column_stack([ev.t * 1e-6, ev.x, ev.y, ev.p])
    np.save(tmp_path / "p.npy", txyp)
    back = npy.read(tmp_path / "p.npy", sensor_size=(180, 240))
    np.testing.assert_array_equal(back.t, ev.t)
    assert "inferred" in back.meta["columns"]
    xytp = np.column_stack([ev.x, ev.y, ev.t, ev.p]).astype(np.int64)
    np.save(tmp_path / "q.npy", xytp)
    np.testing.assert_array_equal(npy.read(tmp_path / "q.npy", sensor_size=(180, 240)).x, ev.x)


def test_npy_errors(tmp_path):
    np.savez(tmp_path / "bad.npz", a=np.zeros(3))
    with pytest.raises(FormatError, match=r"bad.npz.*lacks arrays x, y, t, p"):
        npy.read(tmp_path / "bad.npz")
    np.save(tmp_path / "bad.npy", np.zeros((5, 3)))
    with pytest.raises(FormatError, match=r"bad.npy.*N×4"):
        npy.read(tmp_path / "bad.npy")
    np.savez(tmp_path / "u.npz", x=[1, 2], y=[1, 2], t=[5, 1], p=[0, 1])
    with pytest.raises(FormatError, match=r"u.npz.*not sorted"):
        npy.read(tmp_path / "u.npz")
    np.savez(tmp_path / "o.npz", x=[1, 500], y=[1, 2], t=[1, 5], p=[0, 1],
             sensor_size=[180, 240])
    with pytest.raises(FormatError, match=r"o.npz.*x=500.*outside"):
        npy.read(tmp_path / "o.npz")


def test_mat_of_a_larger_sensor_keeps_every_event_and_drops_are_said(tmp_path):
    """A .mat of 346x260 pixels lost every event beyond 240x180 silently (14,500 of
    30,000 read); undistorted events off the sensor are still left out, now with a
    warning."""
    import scipy.io as sio

    from evmotion.errors import EvmotionWarning
    from evmotion.io import mat

    i = np.arange(3000)
    sio.savemat(tmp_path / "big.mat", {"ev": np.stack([1 + i * 1e-6, i % 346, i % 260,
                                                      i % 2], 1)})
    with pytest.warns(EvmotionWarning, match="taken as 346x260"):
        ev = mat.read(tmp_path / "big.mat")
    assert len(ev) == 3000 and ev.sensor_size == (260, 346)
    und = np.stack([1 + i * 1e-6, (i % 250) + 0.5, (i % 170) + 0.25, i % 2], 1)
    sio.savemat(tmp_path / "und.mat", {"ev": und})
    with pytest.warns(EvmotionWarning, match="of 3,000 events lie outside the 240x180"):
        ev = mat.read(tmp_path / "und.mat")
    assert len(ev) == int(np.sum((i % 250) + 0.5 <= 239))


def test_mat_seconds_over_a_long_recording(tmp_path):
    """Float seconds spanning 150 s were read as us (1 .. 151 us)."""
    import scipy.io as sio

    from evmotion.io import mat

    i = np.arange(30000)
    sio.savemat(tmp_path / "long.mat", {"ev": np.stack([1 + i * 0.005, i % 240, i % 180,
                                                       i % 2], 1)})
    ev = mat.read(tmp_path / "long.mat")
    assert ev.t[0] == 1_000_000 and ev.t[-1] == 150_995_000


def test_npz_and_structured_arrays_with_other_tools_names(tmp_path):
    """Arrays named timestamp/polarity or ts/pol were refused ('lacks arrays x, y, t, p')."""
    from evmotion.io import npy

    t = np.array([10, 20, 30], np.int64)
    np.savez(tmp_path / "a.npz", x=[1, 2, 3], y=[0, 1, 2], timestamp=t, polarity=[1, 0, 1])
    ev = npy.read(tmp_path / "a.npz")
    assert ev.t.tolist() == [10, 20, 30] and ev.p.tolist() == [1, 0, 1]
    rec = np.zeros(3, dtype=[("ts", "<i8"), ("x", "<u2"), ("y", "<u2"), ("pol", "?")])
    rec["ts"], rec["x"], rec["y"], rec["pol"] = t, [4, 5, 6], [1, 1, 1], [True, False, True]
    np.save(tmp_path / "s.npy", rec)
    ev = npy.read(tmp_path / "s.npy")
    assert ev.x.tolist() == [4, 5, 6] and ev.p.tolist() == [1, 0, 1]


def test_n_by_4_unsigned_finds_its_time_column(tmp_path):
    """np.diff of unsigned columns wraps, so every column of a uint32 N x 4 array looked
    sorted: 'cannot tell which column is time'."""
    from evmotion.io import npy

    arr = np.array([[0, 192, 13, 0], [5, 7, 13, 1], [9, 3, 2, 1]], np.uint32)
    np.save(tmp_path / "u.npy", arr)
    ev = npy.read(tmp_path / "u.npy")
    assert ev.t.tolist() == [0, 5, 9] and ev.x.tolist() == [192, 7, 3]


def test_n_by_4_with_time_last_reads_as_prophesee_fields(tmp_path):
    """x y p t (Prophesee's CD field order) was refused, its hint naming two orders that
    did not fit and a Python keyword no command has (probe AS)."""
    from evmotion.errors import FormatError
    from evmotion.io import npy

    rng = np.random.default_rng(0)
    n = 500
    t, x, y, p = np.arange(n) * 7, rng.integers(0, 300, n), rng.integers(0, 200, n), \
        rng.integers(0, 2, n)
    np.save(tmp_path / "xypt.npy", np.column_stack([x, y, p, t]))
    ev = npy.read(tmp_path / "xypt.npy", sensor_size=(200, 300))
    assert ev.t.tolist() == t.tolist() and ev.p.tolist() == p.tolist()
    assert ev.meta["columns"] == "xypt (inferred from the sorted column)"
    np.save(tmp_path / "xyzt.npy", np.column_stack([x, y, x, t]))  # no polarity column
    with pytest.raises(FormatError, match="cannot tell which column is time.*structured"):
        npy.read(tmp_path / "xyzt.npy", sensor_size=(200, 300))


def test_nanoseconds_of_a_microsecond_sensor_are_questioned(tmp_path):
    # relative ns times (a 1.5 s recording from t = 0) cannot be told from µs by their
    # size, but a µs sensor's ns are all multiples of 1000: warned, read as stated
    import warnings

    from evmotion.errors import EvmotionWarning

    n = 500
    cols = dict(x=np.arange(n) % 300, y=np.arange(n) % 200, p=np.arange(n) % 2)
    ns = tmp_path / "ns.npz"
    np.savez(ns, t=np.arange(n, dtype=np.int64) * 3_000_000, sensor_size=[200, 300], **cols)
    with pytest.warns(EvmotionWarning, match=r"multiples of 1000.*time_unit='ns'"):
        assert eio.read_events(ns).t[-1] == (n - 1) * 3_000_000
    assert eio.read_events(ns, time_unit="ns").t[-1] == (n - 1) * 3_000
    us = tmp_path / "us.npz"
    np.savez(us, t=np.arange(n, dtype=np.int64) * 3_001, sensor_size=[200, 300], **cols)
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)
        eio.read_events(us)


def test_microseconds_as_floats_read_as_seconds_are_questioned(tmp_path):
    # probe AN: float µs in a .npy were read as seconds (a 37 ms window spanning 10 h),
    # without a word
    from evmotion.errors import EvmotionWarning

    n = 20_000
    t = np.arange(n) * 1.85
    cols = dict(x=np.arange(n) % 300, y=np.arange(n) % 200, p=np.arange(n) % 2)
    path = tmp_path / "float_us.npz"
    np.savez(path, t=t, sensor_size=[200, 300], **cols)
    # (both finer units named: the rate cannot tell busy µs from quiet ms, probe BM)
    with pytest.warns(EvmotionWarning, match=r"read as seconds, .*20000 events over 3\.7e\+04 "
                      r"s.*milliseconds \(or microseconds\)\? If so, read with --time-unit "
                      r"ms \(or us\)"):
        eio.read_events(path)
    assert eio.read_events(path, time_unit="us").duration_us == 36_998
    # seconds are seconds: no warning
    np.savez(path, t=t * 1e-6, sensor_size=[200, 300], **cols)
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)
        assert eio.read_events(path).duration_us == 36_998


def test_a_negative_coordinate_is_named(tmp_path):
    """x = -5 in a file with no sensor size said 'no sensor of at most 16384 px per side
    (give the size...)', which no size given could help (probe)."""
    np.savez(tmp_path / "neg.npz", x=np.array([3, -5, 7]), y=np.array([1, 1, 1]),
             t=np.array([0, 10, 20]), p=np.array([1, 0, 1]))
    with pytest.raises(FormatError, match="event 1 has x=-5: pixel coordinates start at 0"):
        eio.read_events(tmp_path / "neg.npz")


def test_writers_refusals_name_the_output(tmp_path):
    """'events have float (undistorted) coordinates; DAT stores integer pixels' named no
    file (probe)."""
    ev = EventArray(x=np.array([1.5, 2.0], np.float32), y=np.array([1.0, 2.0], np.float32),
                    t=[0, 10], p=[1, 0], sensor_size=(10, 10))
    with pytest.raises(FormatError, match=r"x\.dat: events have float"):
        eio.write_events(tmp_path / "x.dat", ev)
    assert not (tmp_path / "x.dat").exists()


def test_an_npz_under_another_name_is_recognised_by_content(tmp_path):
    """convert o.bin --format-out npy writes an archive of .npy arrays that nothing then
    recognised (probe AZ: the format is told by content, its name is no reason); a zip of
    other files stays unrecognised."""
    import zipfile

    from evmotion.errors import FormatError
    from evmotion.events import EventArray
    from evmotion.io import detect_format, read_events, write_events

    ev = EventArray(x=[1, 2], y=[0, 1], t=[10, 20], p=[1, 0], sensor_size=(4, 5))
    write_events(tmp_path / "o.bin", ev, format="npy")
    assert detect_format(tmp_path / "o.bin") == "npy"
    assert read_events(tmp_path / "o.bin").t.tolist() == [10, 20]
    with zipfile.ZipFile(tmp_path / "other.bin", "w") as z:
        z.writestr("a.txt", "x")
    # (said as what it is since probe BL: "format not recognised" before)
    with pytest.raises(FormatError, match="is a zip archive, not a recording"):
        detect_format(tmp_path / "other.bin")


def test_float_times_given_a_unit_they_are_not_in_or_too_coarse_are_said(tmp_path):
    """Probe BL: float seconds with --time-unit us all fell on 0 us, unsaid; float32
    seconds near 100 s step by 7.6 us, 1,959 distinct times read as 1,799, unsaid."""


    from evmotion.errors import EvmotionWarning, FormatError
    from evmotion.io import read_events

    rng = np.random.default_rng(1)
    t_us = 1018 + np.cumsum(rng.integers(1, 40, 5000))
    cols = dict(x=np.arange(5000) % 64, y=np.arange(5000) % 48, p=np.arange(5000) % 2,
                sensor_size=[48, 64])
    np.savez(tmp_path / "s.npz", t=t_us / 1e6, **cols)
    with pytest.raises(FormatError, match=r"not a whole number of us, and the times span "
                                          r"under 1000 us: they are in seconds\?"):
        read_events(tmp_path / "s.npz", time_unit="us")
    assert read_events(tmp_path / "s.npz").t.tolist() == t_us.tolist()
    np.savez(tmp_path / "f32.npz", t=(100 + t_us / 1e6).astype(np.float32), **cols)
    with pytest.warns(EvmotionWarning, match=r"field 't' is float32: at 100\.\d+ s its "
                                             r"values step by 7\.63 us"):
        read_events(tmp_path / "f32.npz")
    np.savez(tmp_path / "f64.npz", t=100 + t_us / 1e6, **cols)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_events(tmp_path / "f64.npz").t[0] == 100_000_000 + t_us[0]


def test_mat_time_unit_says_whether_it_was_inferred(tmp_path):
    """A unit the reader guessed was labelled "(given)" (probe CI), and so was not doubted
    as guesses are."""
    import scipy.io

    from evmotion.io import read_events

    scipy.io.savemat(tmp_path / "m.mat", {"seq": np.array([[0.001, 3, 4, 1],
                                                          [0.002, 5, 6, 0]])})
    assert read_events(tmp_path / "m.mat").meta["time_unit"] == \
        "s (inferred from the times' values)"
    assert read_events(tmp_path / "m.mat", time_unit="ms").meta["time_unit"] == "ms (given)"


def test_an_int8_mat_array_reads_without_numpy_warnings(tmp_path):
    """Probe CG: an int8 N x 4 array whose times span more than 127 overflowed in the
    time-unit guess ('mat.py: RuntimeWarning: overflow encountered in scalar subtract' on
    stderr, before the file's own lines)."""
    import scipy.io

    from evmotion.io import read_events

    rng = np.random.default_rng(0)
    n = 200
    t = np.sort(rng.integers(0, 220, n)) - 100  # -100 .. 119: a span past int8's 127
    assert t.max() - t.min() > 127
    a = np.stack([t, rng.integers(0, 100, n), rng.integers(0, 100, n),
                  rng.integers(0, 2, n)], 1).astype(np.int8)
    scipy.io.savemat(tmp_path / "i8.mat", {"ev": a})
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        ev = read_events(tmp_path / "i8.mat")
    np.testing.assert_array_equal(ev.t, t)
    np.testing.assert_array_equal(ev.x, a[:, 1])


def test_a_fractional_npz_sensor_size_is_refused(tmp_path):
    """Probe CG: an .npz 'sensor_size' of [60.9, 80.9] was floored to (60, 80), unsaid."""
    ev = EventArray(x=[1, 9], y=[2, 3], t=[10, 20], p=[1, 0], sensor_size=(60, 80))
    eio.write_events(tmp_path / "a.npz", ev)
    arrays = dict(np.load(tmp_path / "a.npz"))
    arrays["sensor_size"] = np.array([60.9, 80.9])
    np.savez(tmp_path / "m.npz", **arrays)
    with pytest.raises(FormatError, match=r"m\.npz: array 'sensor_size' \[60\.9, 80\.9\] is "
                                          "not two whole numbers"):
        eio.read_events(tmp_path / "m.npz")
