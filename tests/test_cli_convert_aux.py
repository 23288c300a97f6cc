"""``evmotion convert`` keeps IMU samples and APS frames where the output format holds them
(evmotion ``.h5``) and names each stream it drops otherwise (one line per stream)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import evmotion.io as eio
from evmotion.cli import main
from evmotion.events import EventArray
from evmotion.io import h5


@pytest.fixture
def rec_with_aux(tmp_path):
    """An evmotion .h5 with events, 40 IMU samples and 6 frames over 5.0..5.1 s."""
    rng = np.random.default_rng(3)
    n = 3000
    ev = EventArray(rng.integers(0, 40, n), rng.integers(0, 30, n),
                    5_000_000 + np.sort(rng.integers(0, 100_000, n)), rng.integers(0, 2, n),
                    sensor_size=(30, 40))
    imu = {"t": 5_000_000 + np.arange(40) * 2_500, "gyro": rng.normal(size=(40, 3)),
           "accel": rng.normal(size=(40, 3))}
    frames = {"t": 5_000_000 + np.arange(6) * 20_000,
              "images": rng.integers(0, 256, (6, 30, 40), dtype=np.uint8)}
    path = tmp_path / "rec.h5"
    h5.write(path, ev, imu=imu, frames=frames)
    return path, imu, frames


def test_convert_to_h5_keeps_imu_and_frames_within_t0_t1(rec_with_aux, tmp_path, capsys):
    src, imu, frames = rec_with_aux
    out = tmp_path / "out.h5"
    rc = main(["convert", str(src), str(out), "--t0", "5.02", "--t1", "5060ms", "--json"])
    cap = capsys.readouterr()
    assert rc == 0 and cap.err == ""
    doc = json.loads(cap.out)
    sel_i = (imu["t"] >= 5_020_000) & (imu["t"] < 5_060_000)
    sel_f = (frames["t"] >= 5_020_000) & (frames["t"] < 5_060_000)
    assert doc["kept"] == {"imu": int(sel_i.sum()), "frames": int(sel_f.sum())}
    assert doc["dropped"] == {}
    got = eio.read_imu(out)
    np.testing.assert_array_equal(got.t, imu["t"][sel_i])
    np.testing.assert_allclose(got.gyro, imu["gyro"][sel_i])
    np.testing.assert_allclose(got.accel, imu["accel"][sel_i])
    fr = eio.read_frames(out)
    np.testing.assert_array_equal(fr.t, frames["t"][sel_f])
    np.testing.assert_array_equal(np.asarray(fr.images), frames["images"][sel_f])


def test_convert_to_a_format_without_imu_names_each_dropped_stream(rec_with_aux, tmp_path,
                                                                    capsys):
    src, imu, frames = rec_with_aux
    out = tmp_path / "out.raw"
    rc = main(["convert", str(src), str(out)])
    cap = capsys.readouterr()
    assert rc == 0 and out.exists()
    lines = cap.err.strip().splitlines()
    assert len(lines) == 2, cap.err
    assert "dropped the 40 IMU samples" in lines[0] and "'evt3'" in lines[0]
    assert "dropped the 6 APS frames" in lines[1] and ".h5" in lines[1]
    assert len(eio.read_events(out)) == 3000


def test_convert_real_davis346_keeps_imu_and_frames(tmp_path, capsys, shared_data):
    src = shared_data / "formats" / "davis346.aedat4"
    if not src.exists():
        pytest.skip(f"{src} not found (see shared/data/README.md)")
    out = tmp_path / "d.h5"
    rc = main(["convert", str(src), str(out), "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    # the README's figures: 59 APS frames, 2,363 IMU samples
    assert doc["kept"] == {"imu": 2363, "frames": 59}
    a, b = eio.read_imu(src), eio.read_imu(out)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_allclose(a.gyro, b.gyro)
    fa, fb = eio.read_frames(src), eio.read_frames(out)
    np.testing.assert_array_equal(fa.t, fb.t)
    np.testing.assert_array_equal(np.asarray(fa.images[5]), np.asarray(fb.images[5]))


def test_convert_names_a_dropped_calibration(tmp_path, capsys):
    """.h5 -> .raw / .npz dropped the calibration with '"dropped": {}'."""
    import json

    from evmotion.cli import main
    from evmotion.events import EventArray
    from evmotion.io import write_events

    ev = EventArray(x=[1, 2, 3], y=[1, 2, 3], t=[10, 20, 30], p=[1, 0, 1],
                    sensor_size=(40, 50))
    calib = {"K": [40.0, 40.0, 25.0, 20.0], "dist": [0.1, 0.0, 0.0, 0.0, 0.0],
             "resolution": [40, 50]}
    write_events(tmp_path / "c.h5", ev, calibration=calib)
    capsys.readouterr()
    assert main(["convert", str(tmp_path / "c.h5"), str(tmp_path / "c.npz"), "--json"]) == 0
    cap = capsys.readouterr()
    assert json.loads(cap.out)["dropped"] == {"calibration": 1}
    assert "dropped the calibration" in cap.err and "does not store it" in cap.err
    assert main(["convert", str(tmp_path / "c.h5"), str(tmp_path / "d.h5"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["dropped"] == {}


def test_a_listed_stream_that_cannot_be_read_is_named_not_dropped_silently(
        rec_with_aux, tmp_path, capsys, monkeypatch):
    from evmotion.errors import FormatError

    def unreadable(path, format=None):
        raise FormatError(path, "corrupt IMUS packet at byte offset 8")

    monkeypatch.setattr(eio, "read_imu", unreadable)
    path = rec_with_aux[0]
    assert main(["convert", str(path), str(tmp_path / "o.h5"), "--json"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["dropped"] == {"imu": 40}
    assert "dropped the 40 IMU samples" in out.err and "corrupt IMUS packet" in out.err
