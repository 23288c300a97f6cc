"""jAER AEDAT 2.0 (DAVIS240C): address decoding, IMU samples, streaming, round-trips."""

from __future__ import annotations

import numpy as np
import pytest

from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import aedat2
from evmotion.io.registry import detect_spec


@pytest.fixture(scope="module")
def path(shared_data):
    return shared_data / "formats" / "davis240_translboxes_aedat2.aedat"


def reference_decode(path):
    data = path.read_bytes()
    end = data.index(b"#End of Preferences")
    off = data.index(b"\n", end) + 1
    rec = np.frombuffer(data[off:], ">u4").reshape(-1, 2).astype(np.int64)
    addr, t = rec[:, 0], rec[:, 1]
    keep = (addr >> 31 == 0) & ((addr >> 10) & 1 == 0)
    a = addr[keep]
    return 239 - ((a >> 12) & 1023), 179 - ((a >> 22) & 511), t[keep], (a >> 11) & 1


def test_events_match_reference(path):
    ev = aedat2.read(path)
    assert len(ev) == 162_771 and ev.sensor_size == (180, 240)
    for got, ref in zip((ev.x, ev.y, ev.t, ev.p), reference_decode(path), strict=True):
        np.testing.assert_array_equal(got, ref)
    assert 2.0e6 < ev.duration_us < 2.1e6
    assert detect_spec(path).name == "aedat2"


def test_imu(path):
    imu = aedat2.read_imu(path)
    assert len(imu.t) == 4833
    g = np.linalg.norm(imu.accel, axis=1)
    assert abs(np.median(g) - 9.81) < 0.3  # camera moved by hand: gravity dominates
    assert np.all(np.diff(imu.t) >= 0)
    assert 20 < np.median(imu.temperature) < 45
    assert np.abs(imu.gyro).max() < 10  # rad/s


def test_chunks(path):
    whole = aedat2.read(path)
    chunks = list(aedat2.iter_chunks(path, 40_000, block_bytes=8 * 999))
    assert [len(c) for c in chunks] == [40_000] * 4 + [2771]
    np.testing.assert_array_equal(np.concatenate([c.x for c in chunks]), whole.x)


def test_round_trip(path, tmp_path):
    ev = aedat2.read(path)
    aedat2.write(tmp_path / "a.aedat", ev)
    back = aedat2.read(tmp_path / "a.aedat")
    for f in "xytp":
        np.testing.assert_array_equal(getattr(back, f), getattr(ev, f))
    assert back.sensor_size == ev.sensor_size


def test_errors(path, tmp_path):
    data = path.read_bytes()
    cut = tmp_path / "cut.aedat"
    cut.write_bytes(data[:-3])
    with pytest.raises(FormatError, match=r"cut\.aedat.*byte offset"):
        aedat2.read(cut)
    bad = tmp_path / "bad.aedat"
    bad.write_bytes(b"#!AER-DAT3.1\r\n" + data[14:2000])
    with pytest.raises(FormatError, match="magic"):
        aedat2.read(bad)


def test_round_trip_other_sensor_size(tmp_path):
    from evmotion.events import EventArray

    ev = EventArray(x=[0, 345, 10], y=[0, 259, 5], t=[1, 2, 3], p=[1, 0, 1],
                    sensor_size=(260, 346))
    aedat2.write(tmp_path / "b.aedat", ev)
    back = aedat2.read(tmp_path / "b.aedat")
    assert back.sensor_size == (260, 346)
    np.testing.assert_array_equal(back.x, ev.x)
    np.testing.assert_array_equal(back.y, ev.y)


def test_dvs128_address_layout(tmp_path):
    """jAER's DVS128 files (x in bits 1-7, y in 8-14, bit 0 set for OFF, mirrored like
    the DAVIS) were refused; they read as the chip's 128x128 events."""
    rng = np.random.default_rng(0)
    n = 500
    x, y, p = rng.integers(0, 128, n), rng.integers(0, 128, n), rng.integers(0, 2, n)
    t = np.sort(rng.integers(0, 10**6, n))
    rec = np.zeros(n, [("a", ">u4"), ("t", ">i4")])
    rec["a"] = (127 - y) << 8 | (127 - x) << 1 | (1 - p)
    rec["t"] = t
    path = tmp_path / "dvs128.aedat"
    path.write_bytes(b"#!AER-DAT2.0\r\n# Timestamps tick is 1 us\r\n"
                     b"# AEChip: ch.unizh.ini.jaer.chip.retina.DVS128\r\n" + rec.tobytes())
    ev = aedat2.read(path)
    assert ev.sensor_size == (128, 128)
    for k, want in zip("xytp", (x, y, t, p), strict=True):
        np.testing.assert_array_equal(getattr(ev, k), want)
    assert aedat2.describe(path)["n_events"] == n


def test_epoch_times_round_trip_through_the_header_offset(tmp_path):
    # a DAVIS recording's epoch µs was refused ("outside AEDAT 2.0's u32 range (subtract a
    # time offset first)"), which convert cannot do; the header keeps the offset
    t = 1_589_163_147_368_868 + np.array([0, 10, 1 << 30, 3 << 30, (1 << 32) + 7], np.int64)
    ev = EventArray(x=[0, 1, 2, 3, 4], y=[0, 1, 2, 3, 4], t=t, p=[0, 1, 1, 0, 1],
                    sensor_size=(180, 240))
    aedat2.write(tmp_path / "e.aedat", ev)
    assert b"# evmotion_time_offset_us 1589159374356480\r\n" in (tmp_path / "e.aedat").read_bytes()
    back = aedat2.read(tmp_path / "e.aedat")
    np.testing.assert_array_equal(back.t, t)
    np.testing.assert_array_equal(back.x, ev.x)
    assert aedat2.describe(tmp_path / "e.aedat")["n_events"] == 5


def _recording(n=3000, t0=422, span=20_000):
    """A 20 ms recording of ``n`` events on a DAVIS240 (times from ``t0`` µs)."""
    rng = np.random.default_rng(7)
    return EventArray(x=rng.integers(0, 240, n), y=rng.integers(0, 180, n),
                      t=t0 + np.sort(rng.integers(0, span, n)), p=rng.integers(0, 2, n),
                      sensor_size=(180, 240))


def _payload_offset(data: bytes) -> int:
    he = 0
    while data.startswith(b"#", he):
        he = data.index(b"\n", he) + 1
    return he


@pytest.mark.parametrize("block_bytes", [1 << 22, 8 * 500])
def test_a_time_that_jumps_and_falls_back_is_refused_not_taken_for_a_rollover(
        tmp_path, block_bytes):
    """Probe CG: the top byte of record 500's timestamp set to 0xAE (a jump of 48 min)
    and the next record back at 3.9 ms: the fall was counted as a rollover of the 32-bit
    µs clock, and every later time moved 71.6 min on (a 20 ms recording read as 8,590 s,
    unsaid); now the record is named as a corrupt time field."""
    ev = _recording()
    aedat2.write(tmp_path / "a.aedat", ev)
    data = bytearray((tmp_path / "a.aedat").read_bytes())
    he = _payload_offset(bytes(data))
    for k in (500, 1500):
        data[he + 8 * k + 4] = 0xAE
    (tmp_path / "m.aedat").write_bytes(bytes(data))
    at = int(np.frombuffer(bytes(data[he + 8 * 500 + 4:he + 8 * 500 + 8]), ">u4")[0])
    with pytest.raises(FormatError, match=rf"m\.aedat: record 500 \(timestamp at byte offset "
                                          rf"{he + 8 * 500 + 4}\) holds time {at} us, .*"
                                          rf"{ev.t[499]} us before, {ev.t[501]} us after.*"
                                          "corrupt time field"):
        aedat2.read(tmp_path / "m.aedat", block_bytes=block_bytes)
    with pytest.raises(FormatError, match="record 500 .*corrupt time field"):
        aedat2.describe(tmp_path / "m.aedat")


def test_a_time_that_falls_and_jumps_back_is_refused(tmp_path):
    """The same the other way: a timestamp's top byte cleared at 50 min into the clock
    read as a rollover, the times after it 71.6 min late."""
    ev = _recording(t0=3_000_000_000)
    aedat2.write(tmp_path / "a.aedat", ev)
    data = bytearray((tmp_path / "a.aedat").read_bytes())
    data[_payload_offset(bytes(data)) + 8 * 700 + 4] = 0
    (tmp_path / "m.aedat").write_bytes(bytes(data))
    with pytest.raises(FormatError, match="record 700 .*corrupt time field"):
        aedat2.read(tmp_path / "m.aedat")


def test_a_genuine_rollover_of_the_clock_still_reads(tmp_path):
    """A DAVIS clock counting through 2^32 µs (71.6 min) mid-recording: the times near the
    top of the counter, then near zero, read on as one clock."""
    ev = _recording(t0=(1 << 32) - 10_000)
    aedat2.write(tmp_path / "w.aedat", ev)
    back = aedat2.read(tmp_path / "w.aedat", block_bytes=8 * 333)
    np.testing.assert_array_equal(back.t, ev.t)
    assert (ev.t >= 1 << 32).any() and (ev.t < 1 << 32).any()
