"""AEDAT 4.0: events/frames/IMU of the shared DAVIS346 files, streaming, writer
round-trips (uncompressed and LZ4), truncated and corrupt files."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from _helpers import assert_same_events
from evmotion.errors import FormatError, ParameterError
from evmotion.events import EventArray
from evmotion.io import aedat4
from evmotion.io.registry import detect_spec


@pytest.fixture(scope="module")
def full(shared_data):
    return shared_data / "formats" / "davis346.aedat4"


@pytest.fixture(scope="module")
def short(shared_data):
    return shared_data / "formats" / "davis346_short.aedat4"


def test_counts_and_content(full):
    ev = aedat4.read(full)
    assert len(ev) == 78_830 and ev.sensor_size == (260, 346)
    assert 2.3e6 < ev.duration_us < 2.4e6
    d = aedat4.describe(full)
    assert (d["n_events"], d["frames"], d["imu"]) == (78_830, 59, 2_363)
    assert d["compression"] == "lz4"
    assert detect_spec(full).name == "aedat4"


def test_frames(full):
    fr = aedat4.read_frames(full)
    assert len(fr.images) == 59 == fr.t.size
    assert fr.images[0].shape == (260, 346) and fr.images[0].dtype == np.uint8
    assert np.all(np.diff(fr.t) > 0)
    assert np.all(fr.exposure_end >= fr.exposure_start)
    assert fr.images[10].std() > 1  # a real picture, not a constant


def test_imu_units(full):
    imu = aedat4.read_imu(full)
    assert imu.t.size == 2_363
    assert abs(np.median(np.linalg.norm(imu.accel, axis=1)) - 9.81) < 0.5  # m/s^2
    assert abs(np.median(np.diff(imu.t)) - 1000) < 5  # 1 kHz
    assert np.abs(imu.gyro).max() < 20  # rad/s, not deg/s


def test_chunks_and_filter(full):
    whole = aedat4.read(full)
    chunks = list(aedat4.iter_chunks(full, 10_000))
    assert [len(c) for c in chunks[:-1]] == [10_000] * 7 and len(chunks[-1]) == 8_830
    np.testing.assert_array_equal(np.concatenate([c.t for c in chunks]), whole.t)
    t0, t1 = int(whole.t[100]), int(whole.t[50_000])
    assert_same_events(aedat4.read(full, t0=t0, t1=t1), whole.slice_time(t0, t1))


@pytest.mark.parametrize("compression", ["none", "lz4"])
def test_round_trip(short, tmp_path, compression):
    ev = aedat4.read(short)
    out = tmp_path / f"{compression}.aedat4"
    aedat4.write(out, ev, compression=compression, packet_events=1000)
    assert_same_events(aedat4.read(out), ev)
    d = aedat4.describe(out)
    assert d["compression"] == compression and d["streams"][0]["packets"] == 7


def test_written_flatbuffer_layout(tmp_path):
    ev = EventArray(x=[1, 2], y=[3, 4], t=[10, 20], p=[1, 0], sensor_size=(5, 6))
    out = tmp_path / "tiny.aedat4"
    aedat4.write(out, ev, compression="none")
    data = out.read_bytes()
    hsize = struct.unpack_from("<i", data, 14)[0]
    pos = 18 + hsize
    sid, size = struct.unpack_from("<ii", data, pos)
    payload = data[pos + 8:pos + 8 + size]
    assert sid == 0 and payload[8:12] == b"EVTS"
    # event structs start 8-byte aligned relative to the size-prefixed buffer
    assert struct.unpack_from("<I", payload, 28)[0] == 2
    assert struct.unpack_from("<qhh?", payload, 32) == (10, 1, 3, True)


def test_errors(full, tmp_path):
    data = full.read_bytes()
    cut = tmp_path / "cut.aedat4"
    cut.write_bytes(data[:200_000])
    with pytest.raises(FormatError, match=r"cut\.aedat4.*packet size.*byte offset"):
        aedat4.read(cut)
    bad = tmp_path / "bad.aedat4"
    bad.write_bytes(data[:14] + struct.pack("<i", 99_999_999) + data[18:5000])
    with pytest.raises(FormatError, match="IOHeader size"):
        aedat4.read(bad)
    wrong = tmp_path / "wrong.aedat4"
    wrong.write_bytes(b"#!AER-DAT3.1\r\n" + data[14:1000])
    with pytest.raises(FormatError, match="magic"):
        aedat4.read(wrong)
    with pytest.raises(ParameterError):
        aedat4.write(tmp_path / "z.aedat4", aedat4.read(full, t1=0), compression="zip")


def test_first_packet_matches_struct_reference(short):
    import lz4.frame

    data = short.read_bytes()
    pos = 18 + struct.unpack_from("<i", data, 14)[0]
    while True:
        sid, size = struct.unpack_from("<ii", data, pos)
        if sid == 0:
            break
        pos += 8 + size
    buf = lz4.frame.decompress(data[pos + 8:pos + 8 + size])[4:]
    table = struct.unpack_from("<I", buf, 0)[0]
    vtable = table - struct.unpack_from("<i", buf, table)[0]
    field = table + struct.unpack_from("<H", buf, vtable + 4)[0]
    vec = field + struct.unpack_from("<I", buf, field)[0]
    n = struct.unpack_from("<I", buf, vec)[0]
    ref = [struct.unpack_from("<qhh?", buf, vec + 4 + 16 * i) for i in range(n)]
    ev = aedat4.read(short)
    got = list(zip(ev.t[:n].tolist(), ev.x[:n].tolist(), ev.y[:n].tolist(),
                   (ev.p[:n] == 1).tolist(), strict=True))
    assert got == ref


def test_zstd_packets(short, tmp_path):
    import zstandard

    ev = aedat4.read(short)
    plain = tmp_path / "plain.aedat4"
    aedat4.write(plain, ev, compression="none", packet_events=2000)
    data = plain.read_bytes()
    hsize = struct.unpack_from("<i", data, 14)[0]
    header = bytearray(data[:18 + hsize])
    table = 18 + struct.unpack_from("<I", header, 18)[0]
    struct.pack_into("<i", header, table + 4, 3)  # IOHeader.compression = ZSTD
    out, pos = bytes(header), 18 + hsize
    cctx = zstandard.ZstdCompressor()
    while pos < len(data):
        sid, size = struct.unpack_from("<ii", data, pos)
        packed = cctx.compress(data[pos + 8:pos + 8 + size])
        out += struct.pack("<ii", sid, len(packed)) + packed
        pos += 8 + size
    z = tmp_path / "z.aedat4"
    z.write_bytes(out)
    assert aedat4.describe(z)["compression"] == "zstd"
    assert_same_events(aedat4.read(z), ev)


def _one_packet_file_patched(tmp_path, at: int, value: bytes):
    """A three-event AEDAT4 file whose first packet has ``value`` written ``at`` bytes
    past its header's start."""
    ev = EventArray(x=[1, 2, 3], y=[0, 1, 2], t=[10, 20, 30], p=[1, 0, 1], sensor_size=(4, 5))
    path = tmp_path / "a.aedat4"
    aedat4.write(path, ev, compression="none")
    _, _, pos = next(aedat4._packets(path))
    raw = bytearray(path.read_bytes())
    raw[pos + at:pos + at + len(value)] = value
    path.write_bytes(raw)
    return path


def test_a_packet_whose_flatbuffer_points_outside_is_named_by_describe(tmp_path):
    # a packet without DV's size prefix read as one: info leaked struct's 'unpack_from
    # requires a buffer of at least 1398036041 bytes'
    path = _one_packet_file_patched(tmp_path, 12, struct.pack("<I", 1_398_036_037))
    with pytest.raises(FormatError, match=r"corrupt EVTS packet at byte offset \d+$"):
        aedat4.describe(path)


def test_a_packet_of_an_undeclared_stream_is_said(tmp_path):
    # a corrupt stream id dropped the packet's events silently (6676 -> 6274, probe AE)
    from evmotion.errors import EvmotionWarning

    path = _one_packet_file_patched(tmp_path, 0, struct.pack("<i", 77))
    with pytest.warns(EvmotionWarning, match=r"skipped 1 packet\(s\) of stream id\(s\) \[77\]"):
        assert len(aedat4.read(path)) == 0  # its only event packet


def test_a_negative_pixel_is_named_as_such(tmp_path):
    # probe BL: an int16 x of -3 was said as "x=65533 outside the sensor"
    import struct

    from evmotion.errors import FormatError
    from evmotion.events import EventArray
    from evmotion.io import aedat4

    path = tmp_path / "r.aedat4"
    aedat4.write(path, EventArray(x=[7777, 2], y=[5, 6], t=[10, 20], p=[1, 0],
                                  sensor_size=(8000, 8000)), compression="none")
    data = path.read_bytes()
    assert data.count(struct.pack("<h", 7777)) == 1
    path.write_bytes(data.replace(struct.pack("<h", 7777), struct.pack("<h", -3)))
    with pytest.raises(FormatError, match=r"event 0 of the EVTS packet .* has x=-3: pixel "
                                          r"coordinates start at 0"):
        aedat4.read(path)


def test_bytes_after_the_data_table_are_said(shared_data, tmp_path):
    # 700 bytes appended to a DV recording were read past without a word, where the other
    # formats refuse trailing bytes (probe CF)
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.io import read_events

    src = shared_data / "formats" / "davis346_short.aedat4"
    with warnings.catch_warnings():
        warnings.simplefilter("error", EvmotionWarning)
        clean = read_events(src)
    bad = tmp_path / "appended.aedat4"
    bad.write_bytes(src.read_bytes() + bytes(range(256)) * 3)
    with pytest.warns(EvmotionWarning, match=r"768 byte\(s\) follow the file's data table "
                                             rf"\(from byte offset {src.stat().st_size}\)"):
        ev = read_events(bad)
    assert len(ev) == len(clean)


def test_a_time_past_the_year_5000_is_refused_as_other_readers_refuse_it(tmp_path):
    """Probe CG: the last event's time set to 2^63 - 1 us was read as given (info, view
    and egomotion ran, with a warning about a gap of 9.2e12 s): the binary readers' fast
    check had left out the container's bound on times. Now the same one-line error as
    the h5 / npz / ECD readers give."""
    rng = np.random.default_rng(4)
    n = 500
    ev = EventArray(x=rng.integers(0, 80, n), y=rng.integers(0, 60, n),
                    t=422 + np.sort(rng.integers(0, 20_000, n)), p=rng.integers(0, 2, n),
                    sensor_size=(60, 80))
    aedat4.write(tmp_path / "a.aedat4", ev, compression="none")
    data = bytearray((tmp_path / "a.aedat4").read_bytes())
    assert struct.unpack("<q", data[-16:-8])[0] == ev.t[-1]
    data[-16:-8] = struct.pack("<q", 2 ** 63 - 1)
    (tmp_path / "m.aedat4").write_bytes(bytes(data))
    want = (rf"m\.aedat4: event {n - 1} has t=9223372036854775807, as microseconds past the "
            rf"year 5000, where the {n - 1} events before it reach {ev.t[-2]}")
    with pytest.raises(FormatError, match=want):
        aedat4.FORMAT.read(tmp_path / "m.aedat4")  # (as read_events calls it: guarded)
    with pytest.raises(FormatError, match=r"m\.aedat4: .*past the year 5000"):
        list(aedat4.FORMAT.iter_chunks(tmp_path / "m.aedat4", 100))


@pytest.mark.parametrize("cut", [1000, 70_000])
def test_chunks_stream_into_the_same_file(tmp_path, cut):
    """AEDAT4 is written chunk by chunk into the packets one array makes (probe DL:
    converting to .aedat4 held every event): the same bytes, whatever the chunks."""
    from evmotion.io import write_events

    rng = np.random.default_rng(10)
    n = 140_000  # two full packets of 65,536 and a partial one
    ev = EventArray(x=rng.integers(0, 346, n), y=rng.integers(0, 260, n),
                    t=np.sort(rng.integers(0, 10**6, n)), p=rng.integers(0, 2, n),
                    sensor_size=(260, 346))
    aedat4.write(tmp_path / "whole.aedat4", ev)
    parts = [ev[:0], ev[:1], ev[1:3], *(ev[s:s + cut] for s in range(3, n, cut))]
    write_events(tmp_path / "parts.aedat4", iter(parts))
    assert (tmp_path / "parts.aedat4").read_bytes() == \
        (tmp_path / "whole.aedat4").read_bytes()
    np.testing.assert_array_equal(aedat4.read(tmp_path / "parts.aedat4").t, ev.t)
