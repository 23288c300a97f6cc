"""evmotion's HDF5: round trip, appending in chunks, time index, extras, errors."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from _helpers import assert_same_events
from evmotion.errors import FormatError, ParameterError
from evmotion.events import EventArray
from evmotion.io import h5


def _events(n=20_000, seed=0, floats=False, size=(180, 240)):
    rng = np.random.default_rng(seed)
    h, w = size
    x = rng.uniform(0, w - 1, n).astype(np.float32) if floats else rng.integers(0, w, n)
    y = rng.uniform(0, h - 1, n).astype(np.float32) if floats else rng.integers(0, h, n)
    t = 5_000_123 + np.sort(rng.integers(0, 3_000_000, n))
    return EventArray(x=x, y=y, t=t, p=rng.integers(0, 2, n), sensor_size=size)


@pytest.mark.parametrize("floats", [False, True])
def test_round_trip_bit_equal(tmp_path, floats):
    ev = _events(floats=floats)
    h5.write(tmp_path / "a.h5", ev, provenance={"by": "test"}, calibration={"fx": 200.0})
    back = h5.read(tmp_path / "a.h5")
    assert_same_events(back, ev, dtypes=True)
    assert back.meta["provenance"] == {"by": "test"}
    assert back.meta["calibration"] == {"fx": 200.0}


def test_appending_chunks_equals_one_write(tmp_path):
    ev = _events()
    with h5.EventWriter(tmp_path / "c.h5", ev.sensor_size) as w:
        for s in range(0, len(ev), 3001):
            w.append(ev[s:s + 3001])
        assert not (tmp_path / "c.h5").exists()  # atomic: only the .part until close
    assert_same_events(h5.read(tmp_path / "c.h5"), ev, dtypes=True)
    chunks = list(h5.iter_chunks(tmp_path / "c.h5", 6000))
    assert [len(c) for c in chunks] == [6000, 6000, 6000, 2000]


def test_time_index_slices_match_reference(tmp_path):
    ev = _events()
    with h5.EventWriter(tmp_path / "c.h5", ev.sensor_size) as w:
        for s in range(0, len(ev), 777):
            w.append(ev[s:s + 777])
    with h5py.File(tmp_path / "c.h5") as f:
        ms = f["events/ms_to_idx"][:]
        base = f.attrs["t_index0"]
    ref = np.searchsorted(ev.t, base + 1000 * np.arange(ms.size - 1))
    np.testing.assert_array_equal(ms[:-1], ref)
    rng = np.random.default_rng(3)
    for a, b in np.sort(rng.integers(ev.t[0] - 5000, ev.t[-1] + 5000, (50, 2)), axis=1):
        got = h5.read(tmp_path / "c.h5", t0=int(a), t1=int(b))
        assert_same_events(got, ev.slice_time(int(a), int(b)), dtypes=True)


def test_frames_imu_describe(tmp_path):
    ev = _events(1000)
    frames = {"t": np.array([5_000_000, 5_050_000]), "images": np.zeros((2, 180, 240), np.uint8)}
    imu = {"t": np.arange(10) * 1000, "gyro": np.ones((10, 3)), "accel": np.zeros((10, 3))}
    h5.write(tmp_path / "x.h5", ev, frames=frames, imu=imu)
    d = h5.describe(tmp_path / "x.h5")
    assert d["n_events"] == 1000 and d["frames"] == 2 and d["imu"] == 10
    assert d["t_first_us"] == ev.t[0] and d["sensor_size"] == (180, 240)
    assert h5.read_frames(tmp_path / "x.h5")["t"].tolist() == [5_000_000, 5_050_000]
    np.testing.assert_array_equal(h5.read_imu(tmp_path / "x.h5")["gyro"], imu["gyro"])


def test_writer_rejects_out_of_order_chunks(tmp_path):
    ev = _events(1000)
    with pytest.raises(ParameterError, match="before the previous chunk"):
        with h5.EventWriter(tmp_path / "o.h5", ev.sensor_size) as w:
            w.append(ev[500:])
            w.append(ev[:500])
    assert not (tmp_path / "o.h5").exists()
    assert not list(tmp_path.iterdir())  # the partial file is removed too


def test_missing_field_error(tmp_path):
    with h5py.File(tmp_path / "bad.h5", "w") as f:
        f.attrs["format"] = h5.FORMAT_NAME
        f.attrs["height"], f.attrs["width"] = 10, 10
        for k in "ytp":
            f[f"events/{k}"] = np.zeros(3, np.int64)
    with pytest.raises(FormatError, match=r"bad.h5.*'events/x'"):
        h5.read(tmp_path / "bad.h5")


def test_unsorted_and_off_sensor_errors(tmp_path):
    with h5py.File(tmp_path / "u.h5", "w") as f:
        f.attrs["format"] = h5.FORMAT_NAME
        f.attrs["height"], f.attrs["width"] = 10, 10
        f["events/x"] = np.array([1, 2, 3], np.uint16)
        f["events/y"] = np.array([1, 2, 3], np.uint16)
        f["events/t"] = np.array([5, 3, 9], np.int64)
        f["events/p"] = np.array([0, 1, 0], np.uint8)
    with pytest.raises(FormatError, match=r"u.h5.*not sorted"):
        h5.read(tmp_path / "u.h5")
    with h5py.File(tmp_path / "u.h5", "a") as f:
        f["events/t"][...] = [1, 2, 3]
        f["events/x"][...] = [1, 2, 30]
    with pytest.raises(FormatError, match=r"x=30 outside the sensor"):
        h5.read(tmp_path / "u.h5")


def test_not_hdf5(tmp_path):
    (tmp_path / "z.h5").write_bytes(b"hello")
    with pytest.raises(FormatError, match=r"z.h5: not a readable HDF5 file \(file "
                                          r"signature not found\)$"):
        h5.read(tmp_path / "z.h5")
    # a folder given with --format h5: said so, not h5py's errno text with its buffer
    # address and time (probe)
    with pytest.raises(FormatError, match=r": is a folder, not an HDF5 file$"):
        h5.read(tmp_path)


def test_describe_mentions_ground_truth(tmp_path):
    from evmotion.io import flowfiles

    ev = _events(100)
    h5.write(tmp_path / "s.h5", ev)
    with h5py.File(tmp_path / "s.h5", "a") as f:
        flowfiles.write_flow_group(f.require_group("ground_truth/flow"),
                                   np.zeros((1, 180, 240, 2)), [0], [10])
    (tmp_path / "s_gt.h5").write_bytes(b"")
    d = h5.describe(tmp_path / "s.h5")
    assert d["ground_truth"] == ["flow"] and d["ground_truth_file"].endswith("s_gt.h5")


def test_the_time_index_stays_in_proportion_to_the_events(tmp_path):
    """100 events over 30 h made an 865 MB file (an entry per millisecond), 40 days ran out
    of memory; the index now coarsens its step, and time slices still read exactly."""
    from evmotion.io import h5

    rng = np.random.default_rng(0)
    hour = 3600 * 10 ** 6
    t = np.sort(np.concatenate([rng.integers(0, 10 ** 6, 50), rng.integers(0, 10 ** 6, 50)
                                + 40 * 24 * hour]))
    ev = EventArray(x=rng.integers(0, 64, 100), y=rng.integers(0, 48, 100), t=t,
                    p=rng.integers(0, 2, 100), sensor_size=(48, 64))
    path = tmp_path / "gap.h5"
    h5.write(path, (ev[i:i + 10] for i in range(0, 100, 10)))
    assert path.stat().st_size < 20 * 2 ** 20
    for t0, t1 in ((None, None), (0, 500_000), (int(t[37]), int(t[71])), (hour, 41 * 24 * hour),
                   (int(t[50]), None)):
        got = h5.read(path, t0=t0, t1=t1)
        np.testing.assert_array_equal(got.t, ev.slice_time(t0, t1).t)
    # a dense recording keeps the 1 ms step
    dense = EventArray(x=np.zeros(5000), y=np.zeros(5000), t=np.arange(5000) * 300,
                       p=np.ones(5000), sensor_size=(4, 4))
    h5.write(tmp_path / "dense.h5", dense)
    import h5py

    with h5py.File(tmp_path / "dense.h5") as f:
        assert "index_step_us" not in f.attrs and f["events/ms_to_idx"].shape[0] == 1501
    np.testing.assert_array_equal(h5.read(tmp_path / "dense.h5", t0=1000, t1=2000).t,
                                  [1200, 1500, 1800])


@pytest.mark.parametrize("mutate", ["t_index0 + 10 ms", "t_index0 huge", "ms_to_idx shifted"])
def test_a_stale_time_index_is_noticed_and_the_times_searched(tmp_path, mutate):
    # an index that no longer matches the timestamps gave another time range, silently
    from evmotion.errors import EvmotionWarning

    ev = _events()
    h5.write(tmp_path / "c.h5", ev)
    with h5py.File(tmp_path / "c.h5", "a") as f:
        if mutate == "t_index0 + 10 ms":
            f.attrs["t_index0"] = int(f.attrs["t_index0"]) + 10_000
        elif mutate == "t_index0 huge":
            f.attrs["t_index0"] = 1 << 50
        else:
            f["events/ms_to_idx"][:-1] = f["events/ms_to_idx"][1:] + 500
    t0, t1 = int(ev.t[5000]), int(ev.t[9000])
    with pytest.warns(EvmotionWarning, match="time index .* does not match its timestamps"):
        got = h5.read(tmp_path / "c.h5", t0=t0, t1=t1)
    assert_same_events(got, ev.slice_time(t0, t1), dtypes=True)


def test_a_fractional_width_attribute_is_refused(tmp_path):
    """Probe CG: attribute width = 10.5 was floored to 10, unsaid."""
    from evmotion.io import read_events

    ev = EventArray(x=[1, 9], y=[2, 3], t=[10, 20], p=[1, 0], sensor_size=(60, 10))
    h5.write(tmp_path / "a.h5", ev)
    with h5py.File(tmp_path / "a.h5", "a") as f:
        f.attrs["width"] = 10.5
    with pytest.raises(FormatError, match=r"a\.h5: attributes 'height', 'width' \(60, 10\.5\) "
                                          "is not two whole numbers"):
        read_events(tmp_path / "a.h5")
