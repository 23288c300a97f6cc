"""Other tools' HDF5 layouts (evmotion.io.h5generic): read through read_events, each
against the events it was written with."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from evmotion.errors import EvmotionWarning
from evmotion.io import read_events

N = 500
RNG = np.random.default_rng(0)
T = np.sort(RNG.integers(0, 100_000, N)).astype(np.int64)
X = RNG.integers(0, 320, N).astype(np.uint16)
Y = RNG.integers(0, 200, N).astype(np.uint16)
P = RNG.integers(0, 2, N).astype(np.uint8)
X[0], Y[0] = 319, 199  # the largest coordinates: the inferred sensor is 320 x 200


def _fields(f, group, names):
    g = f.require_group(group) if group else f
    for key, name in names.items():
        g[name] = {"t": T, "x": X, "y": Y, "p": P}[key]


def _compound(f, name, attrs=None):
    data = np.zeros(N, dtype=[("x", "<u2"), ("y", "<u2"), ("p", "<i2"), ("t", "<i8")])
    data["x"], data["y"], data["p"], data["t"] = X, Y, P, T
    f[name] = data
    f.attrs.update(attrs or {})


LAYOUTS = {
    "root x y t p": lambda f: _fields(f, "", {k: k for k in "xytp"}),
    "events/ without sensor attributes": lambda f: _fields(f, "events",
                                                           {k: k for k in "xytp"}),
    "event_utils xs ys ts ps": lambda f: _fields(f, "events", {"x": "xs", "y": "ys",
                                                               "t": "ts", "p": "ps"}),
    "compound events": lambda f: _compound(f, "events"),
    "Metavision CD/events": lambda f: _compound(f, "CD/events", {"geometry": "640x480"}),
    "v2e N x 4": lambda f: f.create_dataset("events", data=np.stack(
        [T, X, Y, P], 1).astype(np.uint32)),
}


@pytest.mark.parametrize("name", LAYOUTS)
def test_layouts_read_exactly(tmp_path, name):
    path = tmp_path / "ev.h5"
    with h5py.File(path, "w") as f:
        LAYOUTS[name](f)
    if name == "Metavision CD/events":
        ev = read_events(path)
        assert ev.sensor_size == (480, 640)
    else:
        with pytest.warns(EvmotionWarning, match="taken as 320x200"):
            ev = read_events(path)
        assert ev.sensor_size == (200, 320)
    assert ev.meta["format"] == "h5generic"
    np.testing.assert_array_equal(ev.t, T)
    np.testing.assert_array_equal(ev.x, X)
    np.testing.assert_array_equal(ev.y, Y)
    np.testing.assert_array_equal(ev.p, P)


def test_float_seconds_and_evmotions_own_files_stay_theirs(tmp_path):
    """events/t in float seconds with height/width went to the evmotion reader, which
    refused its dtype; evmotion's own files are still read by it."""
    from evmotion.events import EventArray
    from evmotion.io import write_events

    path = tmp_path / "f.h5"
    with h5py.File(path, "w") as f:
        _fields(f, "events", {k: k for k in "xyp"})
        f["events/t"] = T * 1e-6
        f.attrs.update(height=200, width=320)
    ev = read_events(path)
    assert ev.meta["format"] == "h5generic" and ev.sensor_size == (200, 320)
    np.testing.assert_array_equal(ev.t, T)
    own = tmp_path / "own.h5"
    write_events(own, EventArray(X, Y, T, P, sensor_size=(200, 320)))
    assert read_events(own).meta["format"] == "h5"


def test_nanoseconds_since_the_epoch_and_event_utils_resolution(tmp_path):
    """Integer times that as µs lie past the year 5000 are ns since the epoch (they read
    as a 96 s recording in the year 55,000, every flow 1000x too small); event_utils'
    ``sensor_resolution`` (H, W) attribute is the sensor, not the largest coordinate."""
    from evmotion.cli import main

    rng = np.random.default_rng(0)
    n = 1000
    t_us = 1_700_000_000_000_000 + np.sort(rng.integers(0, 95_800, n))
    with h5py.File(tmp_path / "ns.h5", "w") as f:
        f["x"], f["y"] = rng.integers(0, 346, n), rng.integers(0, 260, n)
        f["t"], f["p"] = t_us * 1000, rng.integers(0, 2, n)
        f.attrs["width"], f.attrs["height"] = 346, 260
    ev = read_events(tmp_path / "ns.h5")
    assert np.array_equal(ev.t, t_us) and ev.meta["time_unit"].startswith("ns (inferred")
    # relative ns stay ambiguous: --time-unit (convert) states them, for HDF5 too
    with h5py.File(tmp_path / "rel.h5", "w") as f:
        f["x"], f["y"] = rng.integers(0, 346, n), rng.integers(0, 260, n)
        f["t"], f["p"] = (t_us - t_us[0]) * 1000, rng.integers(0, 2, n)
    assert main(["convert", str(tmp_path / "rel.h5"), str(tmp_path / "o.h5"),
                 "--time-unit", "ns", "--sensor-size", "260", "346"]) == 0
    assert read_events(tmp_path / "o.h5").t[-1] == t_us[-1] - t_us[0]
    with h5py.File(tmp_path / "eu.h5", "w") as f:
        g = f.create_group("events")
        g["xs"], g["ys"] = rng.integers(0, 346, n), rng.integers(0, 260, n)
        g["ts"], g["ps"] = np.sort(rng.uniform(0, 0.1, n)), rng.integers(0, 2, n)
        f.attrs["sensor_resolution"] = (480, 640)
    assert read_events(tmp_path / "eu.h5").sensor_size == (480, 640)


def test_metavision_hdf5_with_the_ecf_codec_names_the_plugin(tmp_path):
    # Metavision compresses CD/events with its own ECF filter (id 36559); without that
    # plugin the read failed as a corrupt file. A lzf pipeline relabelled as ECF stands in.
    from evmotion.errors import FormatError

    dt = np.dtype([("x", "<u2"), ("y", "<u2"), ("p", "<i2"), ("t", "<i8")])
    path = tmp_path / "mv.hdf5"
    with h5py.File(path, "w") as f:
        f.create_dataset("CD/events", data=np.zeros(5000, dt), chunks=(1024,),
                         compression="lzf")
        f.attrs["geometry"] = "346x260"
    raw = bytearray(path.read_bytes())
    at = raw.find(b"lzf")
    filter_id = raw.rfind((32000).to_bytes(2, "little"), 0, at)
    assert at > 0 and at - filter_id < 16
    raw[filter_id:filter_id + 2] = (36559).to_bytes(2, "little")
    raw[at:at + 3] = b"ecf"
    path.write_bytes(raw)
    with pytest.raises(FormatError, match=r"filter 'ecf' \(id 36559\) is not available.*"
                                          r"Metavision"):
        read_events(path)


def test_blosc_compressed_layout_reads_in_a_fresh_process(tmp_path):
    # event_utils files compressed with Blosc read under `info` but not `convert`/`flow`:
    # only some paths had registered hdf5plugin's filters before h5generic opened the file
    import subprocess
    import sys

    import hdf5plugin

    path = tmp_path / "blosc.h5"
    with h5py.File(path, "w") as f:
        for key, name in {"t": "ts", "x": "xs", "y": "ys", "p": "ps"}.items():
            f.create_dataset(f"events/{name}", data={"t": T, "x": X, "y": Y, "p": P}[key],
                             **hdf5plugin.Blosc(cname="lz4"))
    code = ("import sys; from evmotion.io.h5generic import read; "
            "ev = read(sys.argv[1]); print(len(ev), int(ev.t[-1]), int(ev.x.sum()))")
    out = subprocess.run([sys.executable, "-W", "ignore", "-c", code, str(path)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(N), str(T[-1]), str(int(X.sum()))]


def test_missing_or_uneven_event_fields_are_named(tmp_path):
    """An events/ group without p said 'format not recognised'; fields of different
    lengths gave numpy's 'operands could not be broadcast' (probe)."""
    from evmotion.errors import FormatError

    with h5py.File(tmp_path / "nop.h5", "w") as f:
        for k in "xyt":
            f[f"events/{k}"] = np.arange(10)
    with pytest.raises(FormatError, match="events/t, events/x, events/y hold no event field p"):
        read_events(tmp_path / "nop.h5")
    with h5py.File(tmp_path / "uneven.h5", "w") as f:
        f["events/x"] = np.arange(9)
        for k in "ytp":
            f[f"events/{k}"] = np.arange(10) % 2
    with pytest.raises(FormatError, match="fields differ in length: events/t 10, events/x 9"):
        read_events(tmp_path / "uneven.h5")


@pytest.mark.parametrize("suffix", [".h5", ".npz"])
def test_one_corrupt_time_is_named_not_taken_for_nanoseconds(tmp_path, capsys, suffix):
    """One time of 2e17 at the end of a µs recording turned every time into ns (the
    largest time decided the unit): 1,234,567 us read as 1,235, said nowhere but in --json
    (probe). The unit is that of every time; the corrupt one is named, in one line."""
    from evmotion.cli import main
    from evmotion.errors import FormatError

    rng = np.random.default_rng(0)
    n = 5000
    t = 1_234_567 + np.sort(rng.integers(0, 200_000, n))
    t[-1] = 2 * 10 ** 17
    x, y, p = rng.integers(0, 346, n), rng.integers(0, 260, n), rng.integers(0, 2, n)
    path = tmp_path / f"glitch{suffix}"
    if suffix == ".h5":
        with h5py.File(path, "w") as f:
            f["x"], f["y"], f["t"], f["p"] = x, y, t, p
    else:
        np.savez(path, x=x, y=y, t=t, p=p)
    with pytest.raises(FormatError, match=r"event 4999 has t=200000000000000000, as "
                                             r"microseconds past the year 5000, where the "
                                             r"4,999 events before it reach \d+: 1 corrupt"):
        read_events(path, sensor_size=(260, 346))
    assert main(["info", str(path)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "nanoseconds" not in err


def test_a_corrupt_geometry_attribute_is_named_and_overridden(tmp_path):
    """geometry='abc' was ignored: the size came from the coordinates with a warning that
    the file states none (probe AS); --sensor-size then reads it."""
    from evmotion.errors import FormatError

    path = tmp_path / "cd.h5"
    with h5py.File(path, "w") as f:
        _compound(f, "CD/events", {"geometry": "abc"})
    with pytest.raises(FormatError, match="attribute 'geometry' is 'abc', not a sensor size"):
        read_events(path)
    assert read_events(path, sensor_size=(240, 320)).sensor_size == (240, 320)


def test_a_second_event_layout_is_said_and_the_header_described(tmp_path):
    """events/ beside CD/events: the second was left unsaid; info --header-only gave no
    size or count for other tools' files (probe AS)."""
    import evmotion.io as eio

    path = tmp_path / "two.h5"
    with h5py.File(path, "w") as f:
        _fields(f, "events", {k: k for k in "xytp"})
        _compound(f, "CD/events", {"geometry": "640x480"})
    with pytest.warns(EvmotionWarning, match=r"read the events of events \(x, y, t, p\) "
                                             r"\(500\); the file also holds CD/events \(500\)"):
        read_events(path, sensor_size=(480, 640))
    with pytest.warns(EvmotionWarning, match="also holds CD/events"):  # (its time span)
        d = eio.describe(path)
    assert d["n_events"] == N and d["layout"] == "events (x, y, t, p)"
    one = tmp_path / "cd.h5"
    with h5py.File(one, "w") as f:
        _compound(f, "CD/events", {"geometry": "640x480"})
    d = eio.describe(one)
    assert d["n_events"] == N and tuple(d["sensor_size"]) == (480, 640)


@pytest.mark.parametrize("chunks", [(1 << 20,), None])
def test_declared_values_the_file_does_not_store_are_refused_before_reading(tmp_path,
                                                                            chunks):
    """Probe BL: a 2 KiB file declaring 50 M values per field (written without data) was
    read as 50 M events at t = 0, 2.9 GB in memory; 3e9 took 23 GB and was killed."""
    from evmotion.errors import FormatError

    path = tmp_path / "empty.h5"
    with h5py.File(path, "w") as f:
        for k in "xytp":
            f.create_dataset(k, shape=(50_000_000,), dtype="i8", chunks=chunks)
    assert path.stat().st_size < 100_000
    with pytest.raises(FormatError, match=r"empty\.h5: dataset '[xytp]' .*(stored|stores 0)"):
        read_events(path)
