"""Other tools' files whose layout states a time unit or a sensor size in its own way
(probe Q): each written here with known content and read back by what it states."""

from __future__ import annotations

import json
import warnings

import h5py
import numpy as np
import pytest

from evmotion.cli import main
from evmotion.errors import EvmotionWarning, FormatError
from evmotion.io import read_events

N = 2000
RNG = np.random.default_rng(3)
T_US = 1_234_567 + np.sort(RNG.integers(0, 400_000, N)).astype(np.int64)
X = RNG.integers(0, 320, N).astype(np.uint16)
Y = RNG.integers(0, 240, N).astype(np.uint16)
P = RNG.integers(0, 2, N).astype(np.uint8)
X[0], Y[0] = 319, 239


def _run(capsys, *argv):
    rc = main(list(argv))
    out = capsys.readouterr()
    return rc, out.out, out.err


@pytest.mark.parametrize(("name", "values"), [
    ("t_us", T_US.astype(np.float64)),  # float, but µs by its name (it read as seconds)
    ("timestamp_us", T_US.astype(np.float64)),
    ("t_ns", T_US * 1000 + 7),
    ("t_ms", T_US / 1000.0),
])
def test_time_unit_in_the_field_name(tmp_path, name, values):
    cols = {"x": X, "y": Y, name: values, "p": P}
    npz = tmp_path / "ev.npz"
    np.savez(npz, **cols, sensor_size=np.array([240, 320]))
    h5 = tmp_path / "ev.h5"
    with h5py.File(h5, "w") as f:
        for k, v in cols.items():
            f[f"events/{k}"] = v
        f.attrs["height"], f.attrs["width"] = 240, 320
    for path in (npz, h5):
        ev = read_events(path)
        np.testing.assert_array_equal(ev.t, T_US)
        unit = name.rsplit("_", 1)[1]
        assert ev.meta["time_unit"] == f"{unit} (from the field name '{name}')"


def test_structured_npy_with_unit_in_the_name(tmp_path):
    arr = np.zeros(N, [("x", "<u2"), ("y", "<u2"), ("p", "i1"), ("t_us", "<f8")])
    arr["x"], arr["y"], arr["p"], arr["t_us"] = X, Y, P, T_US
    np.save(tmp_path / "ev.npy", arr)
    with pytest.warns(EvmotionWarning, match="no sensor size"):
        ev = read_events(tmp_path / "ev.npy")
    np.testing.assert_array_equal(ev.t, T_US)


def test_an_npz_without_event_arrays_names_what_is_read(tmp_path):
    np.savez(tmp_path / "ev.npz", a=X, b=Y)
    with pytest.raises(FormatError, match=r"names read: t: t, ts, .*t_ns, timestamp_us"):
        read_events(tmp_path / "ev.npz")


def _group_file(path, t, *, evmotion_marker=False):
    with h5py.File(path, "w") as f:
        for k, v in {"x": X, "y": Y, "t": t, "p": P}.items():
            f[f"events/{k}"] = v
        f.attrs["height"], f.attrs["width"] = 240, 320
        if evmotion_marker:
            f.attrs["format"] = np.bytes_(b"evmotion-events")


def test_a_group_with_size_attributes_is_not_taken_for_evmotions(tmp_path, capsys):
    # events/{x,y,t,p} + width/height, no 'format': it was read as evmotion's own layout,
    # and --time-unit was then refused as a unit the file carries
    path = tmp_path / "other.h5"
    ns = (T_US - T_US[0]) * 1000 + 13
    _group_file(path, ns)
    with pytest.warns(EvmotionWarning, match="1000x too small"):
        ev = read_events(path)
    assert ev.meta["format"] == "h5generic"
    rc, out, err = _run(capsys, "info", str(path), "--time-unit", "ns", "--json")
    assert rc == 0
    info = json.loads(out)
    assert info["format"] == "h5generic" and info["time_unit"] == "ns (given)"
    assert info["duration_s"] == pytest.approx((T_US[-1] - T_US[0]) * 1e-6, abs=1e-6)


def test_time_unit_refused_where_the_format_carries_it(tmp_path, capsys):
    path = tmp_path / "own.h5"
    _group_file(path, T_US, evmotion_marker=True)
    rc, _, err = _run(capsys, "info", str(path), "--time-unit", "ns")
    assert rc == 2
    assert "whose times carry their unit" in err and "--format h5generic" in err
    assert len(err.strip().splitlines()) == 1


def test_flow_takes_time_unit(tmp_path, capsys):
    path = tmp_path / "ns.npz"
    t = np.arange(N, dtype=np.int64) * 200_003  # ns: 5000 events/s over 0.4 s
    np.savez(path, x=X, y=Y, t=t, p=P, sensor_size=np.array([240, 320]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ev = read_events(path, time_unit="ns")
    assert ev.t[-1] - ev.t[0] == pytest.approx(t[-1] / 1000, abs=1)
    rc, out, _ = _run(capsys, "flow", str(path), "--time-unit", "ns", "--window-events",
                      "1000", "--max-windows", "1", "--out", str(tmp_path / "f.h5"), "--json")
    assert rc == 0
    row = json.loads(out)["windows"][0]
    assert (row["t1_us"] - row["t0_us"]) < 300_000  # as µs it spanned 200 s


def test_dsec_layout_takes_the_size_its_attributes_state(tmp_path):
    path = tmp_path / "events.h5"
    x = (X.astype(np.int64) * 4).astype(np.uint16)  # up to 1276: beyond DSEC's 640
    with h5py.File(path, "w") as f:
        f["events/x"], f["events/y"] = x, Y
        f["events/t"], f["events/p"] = (T_US - T_US[0]).astype(np.uint32), P
        f["t_offset"] = np.int64(T_US[0])
        f["ms_to_idx"] = np.searchsorted(T_US - T_US[0], np.arange(0, 401) * 1000)
        f.attrs["width"], f.attrs["height"] = 1280, 720
    ev = read_events(path)
    assert ev.meta["format"] == "dsec" and ev.sensor_size == (720, 1280)
    assert "sensor_size_from" not in ev.meta
    del h5py.File(path, "a").attrs["width"]
    with pytest.raises(FormatError, match="DSEC's 640 x 480 was assumed"):
        read_events(path)


def test_dsec_default_size_is_said(tmp_path):
    path = tmp_path / "events.h5"
    with h5py.File(path, "w") as f:
        f["events/x"], f["events/y"] = X, Y
        f["events/t"], f["events/p"] = (T_US - T_US[0]).astype(np.uint32), P
        f["t_offset"] = np.int64(T_US[0])
        f["ms_to_idx"] = np.searchsorted(T_US - T_US[0], np.arange(0, 401) * 1000)
    ev = read_events(path)
    assert ev.sensor_size == (480, 640)
    assert ev.meta["sensor_size_from"].startswith("DSEC's 640 x 480")


def test_a_table_with_two_times_swapped_says_unsorted(tmp_path, capsys):
    # one out-of-order pair made the time column unknowable ('pass columns=', which no
    # command takes); it is the sorted-time check's to name, and convert --sort mends it
    table = np.stack([T_US, X, Y, P], 1).astype(np.uint32)
    table[[100, 101], 0] = table[[101, 100], 0] + np.array([0, 50])
    path = tmp_path / "v2e.h5"
    with h5py.File(path, "w") as f:
        f["events"] = table
        f.attrs["height"], f.attrs["width"] = 240, 320
    rc, _, err = _run(capsys, "info", str(path))
    assert rc != 0 and "timestamps are not sorted" in err
    rc, _, err = _run(capsys, "convert", str(path), str(tmp_path / "s.h5"), "--sort")
    assert rc == 0, err
    assert np.all(np.diff(read_events(tmp_path / "s.h5").t) >= 0)


def test_metavision_csv_export_reads_x_y_p_t(tmp_path):
    path = tmp_path / "mv.csv"
    rows = "\n".join(f"{x},{y},{p},{t}" for x, y, p, t in zip(X, Y, P, T_US, strict=True))
    path.write_text("%geometry:320,240\n" + rows + "\n")
    ev = read_events(path)
    assert ev.sensor_size == (240, 320)
    np.testing.assert_array_equal(ev.t, T_US)
    np.testing.assert_array_equal(ev.x, X)
    np.testing.assert_array_equal(ev.p, P)


def test_mvsec_outside_error_names_the_assumed_size(tmp_path):
    path = tmp_path / "data.hdf5"
    ev = np.stack([X.astype(np.float64) * 2, Y, T_US * 1e-6, P], 1)  # x up to 638
    with h5py.File(path, "w") as f:
        f["davis/left/events"] = ev
    with pytest.raises(FormatError, match=r"346x260 \(W x H, MVSEC's DAVIS346.*--sensor-size"):
        read_events(path)
    assert read_events(path, sensor_size=(480, 640)).sensor_size == (480, 640)


def _denser_rates(tmp_path):
    """20,000 events at 180 kev/s on a 240x320 sensor (2.4 events/s per pixel): in µs,
    in integer ms, and in decimal ms."""
    rng = np.random.default_rng(5)
    n = 20_000
    t_us = np.cumsum(rng.integers(2, 9, n)).astype(np.int64)
    x, y, p = rng.integers(0, 320, n), rng.integers(0, 240, n), rng.integers(0, 2, n)
    np.savez(tmp_path / "us.npz", x=x, y=y, t=t_us, p=p, sensor_size=[240, 320])
    np.savez(tmp_path / "ms_int.npz", x=x, y=y, t=t_us // 1000, p=p, sensor_size=[240, 320])
    (tmp_path / "ms_dec.txt").write_text("".join(
        f"{v / 1000:.3f} {a} {b} {c}\n" for v, a, b, c in zip(t_us, x, y, p, strict=True)))
    return t_us


def test_times_at_a_rate_per_pixel_no_sensor_makes_are_questioned(tmp_path, capsys):
    """Integer milliseconds read as µs (a recording 1000x dense, every speed 1000x too
    large: probe BJ) and decimal milliseconds read as seconds over 82 s (probe BK), or a
    wrong --time-unit, gave results marked valid without a word: the events' rate per
    pixel now questions the unit, naming the one that fits."""
    t_us = _denser_rates(tmp_path)

    def said(path, **kw):
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            ev = read_events(path, **kw)
        return ev, " ".join(str(w.message) for w in rec
                            if "If so, read with --time-unit" in str(w.message))

    ev, text = said(tmp_path / "ms_int.npz")
    assert "read as microseconds" in text and "--time-unit ms" in text and "large" in text
    ev, text = said(tmp_path / "ms_int.npz", time_unit="ms")
    assert not text and ev.duration_us == pytest.approx(t_us[-1] - t_us[0], abs=1000)
    ev, text = said(tmp_path / "ms_dec.txt", sensor_size=(240, 320))
    assert ev.duration_us > 30e6  # read as seconds: 1000x long
    assert "read as seconds" in text and "--time-unit ms" in text and "small" in text
    _, text = said(tmp_path / "ms_dec.txt", sensor_size=(240, 320), time_unit="ms")
    assert not text
    # a unit given wrongly is questioned too where it makes the recording sparse, and
    # the right ones are not; a dense one given is the user's word (probe BM)
    _, text = said(tmp_path / "us.npz", time_unit="ms")
    assert "read as milliseconds, given" in text and "--time-unit us" in text
    assert not said(tmp_path / "us.npz")[1]
    assert not said(tmp_path / "ms_int.npz", time_unit="us")[1]
    rc, _, err = _run(capsys, "info", str(tmp_path / "ms_int.npz"))
    assert rc == 0 and "--time-unit ms" in err



def test_quiet_recordings_or_a_lit_region_in_the_right_unit_are_not_questioned(tmp_path):
    """Probe BM: a still 64x64 sensor's noise (0.05 events/s a pixel, 60 s, integer µs)
    was told 'nanoseconds?' (a rule on the total rate), and events in a 64x64 region of
    a 1280x720 sensor (2 events/s a pixel, 40 s) too (the rate over the whole sensor);
    float milliseconds read as seconds were told 'microseconds?'."""
    rng = np.random.default_rng(2)

    def noise(side, hz, seconds, region=None):
        n = int(side * side * hz * seconds)
        t = np.sort(rng.integers(0, int(seconds * 1e6), n))
        return rng.integers(0, side, n), rng.integers(0, side, n), t

    x, y, t = noise(64, 0.05, 60)
    np.savez(tmp_path / "quiet.npz", x=x, y=y, t=t, p=t % 2, sensor_size=[64, 64])
    x, y, t = noise(64, 2.0, 40)
    np.savez(tmp_path / "roi.npz", x=x + 600, y=y + 300, t=t, p=t % 2,
             sensor_size=[720, 1280])
    np.savez(tmp_path / "quiet_ms.npz", x=x, y=y, t=t / 1000.0, p=t % 2,
             sensor_size=[64, 64])
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        read_events(tmp_path / "quiet.npz")
        read_events(tmp_path / "roi.npz")
        read_events(tmp_path / "quiet_ms.npz")
    said = [str(w.message) for w in rec if "If so, read with" in str(w.message)]
    assert len(said) == 1 and "quiet_ms.npz" in said[0], said
    assert "milliseconds (or microseconds)? If so, read with --time-unit ms" in said[0]
