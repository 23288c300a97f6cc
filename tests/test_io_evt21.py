"""EVT 2.1: numba decoder vs a plain-Python reference written from Prophesee's word table,
both byte orders (IMX636: upper half first; GenX320: one 64-bit word), detection, the
writer's round trip, streaming and the time-high wrap."""

from __future__ import annotations

import numpy as np
import pytest

from _helpers import assert_same_events, random_events
from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import evt21, read_events
from evmotion.io.registry import detect_spec


def reference_decode(uppers, lowers):
    out, th, ovf, seen = [], 0, 0, False
    for hi, lo in zip((int(v) for v in uppers), (int(v) for v in lowers), strict=True):
        typ = hi >> 28
        if typ in (0, 1) and seen:
            x0, y, t = (hi >> 11) & 0x7FF, hi & 0x7FF, ovf + (th << 6) + ((hi >> 22) & 63)
            out += [(x0 + b, y, t, typ) for b in range(32) if lo >> b & 1]
        elif typ == 0x8:
            h = hi & 0xFFFFFFF
            if seen and h < th and th - h >= 1 << 27:
                ovf += 1 << 34
            th, seen = h, True
    return np.array(out, np.int64).reshape(-1, 4)


def _words(rng, n):
    """``n`` (upper, lower) halves: time words, CD words with random masks, triggers."""
    uppers, lowers, th, lsb = [], [], 1000, 0
    for _ in range(n):
        kind = rng.random()
        if kind < 0.1:
            th += int(rng.integers(1, 3))
            lsb = 0
            uppers.append(0x8 << 28 | th)
            lowers.append(0)
        elif kind < 0.13:
            uppers.append(0xA << 28 | lsb << 22 | 1 << 8 | 1)
            lowers.append(0)
        else:
            lsb = min(lsb + int(rng.integers(0, 2)), 63)  # time never steps back
            uppers.append(int(rng.integers(0, 2)) << 28 | lsb << 22
                          | int(rng.integers(0, 40)) * 32 << 11 | int(rng.integers(0, 720)))
            lowers.append(int(rng.integers(1, 1 << 32)))
    return np.array(uppers, np.uint64), np.array(lowers, np.uint64)


def _file(path, uppers, lowers, upper_first=True, header=None):
    lines = header or ["% evt 2.1", "% format EVT21;height=720;width=1280",
                       "% geometry 1280x720", "% plugin_name hal_plugin_imx636_evk4"]
    if upper_first:  # two little-endian 32-bit halves, the upper one first (IMX636)
        body = np.stack([uppers, lowers], 1).astype("<u4").tobytes()
    else:  # one little-endian 64-bit word (GenX320)
        body = (uppers << np.uint64(32) | lowers).astype("<u8").tobytes()
    path.write_bytes(("\n".join(lines + ["% end"]) + "\n").encode() + body)
    return path


@pytest.mark.parametrize("upper_first", [True, False])
def test_both_byte_orders_read_as_the_reference(tmp_path, upper_first):
    uppers, lowers = _words(np.random.default_rng(1), 5000)
    path = _file(tmp_path / "a.raw", uppers, lowers, upper_first)
    assert detect_spec(path).name == "evt21"
    ev = read_events(path)
    ref = reference_decode(uppers, lowers)
    np.testing.assert_array_equal(np.stack([ev.x, ev.y, ev.t, ev.p], 1).astype(np.int64), ref)
    assert ev.sensor_size == (720, 1280) and len(ev) > 30_000


def test_round_trip_merges_a_row_of_pixels_into_one_word(tmp_path):
    rng = np.random.default_rng(2)
    n = 20_000
    t = np.sort(rng.integers(0, 3_000_000, n))
    t[:64] = 500  # one row, one time, one polarity: 64 pixels in two words
    x = rng.integers(0, 1280, n)
    x[:64] = np.arange(64) + 96
    y = rng.integers(0, 720, n)
    y[:64] = 9
    p = rng.integers(0, 2, n)
    p[:64] = 1
    ev = EventArray(x=x, y=y, t=t, p=p, sensor_size=(720, 1280))
    evt21.write(tmp_path / "w.raw", ev)
    back = evt21.read(tmp_path / "w.raw")
    order = np.lexsort((back.x, back.t))
    want = np.lexsort((ev.x, ev.t))
    for k in "xytp":
        np.testing.assert_array_equal(getattr(back, k)[order], getattr(ev, k)[want])
    words = evt21.encode(ev[:64])
    assert ((words & np.uint64(0xFFFFFFFF)) >> np.uint64(28) == 1).sum() == 2
    assert_same_events(evt21.read(tmp_path / "w.raw"),
                       read_events(tmp_path / "w.raw", format="evt21"))
    chunks = list(evt21.iter_chunks(tmp_path / "w.raw", 3000))
    assert sum(len(c) for c in chunks) == n


def test_time_past_the_counter_and_an_offset_round_trip(tmp_path):
    t = np.array([5, (1 << 34) - 3, (1 << 34) + 70, (1 << 35) + 9]) + 7 * (1 << 34)
    ev = EventArray(x=[1, 2, 3, 4], y=[0, 1, 2, 3], t=t, p=[1, 0, 1, 0],
                    sensor_size=(4, 5))
    evt21.write(tmp_path / "w.raw", ev)
    np.testing.assert_array_equal(evt21.read(tmp_path / "w.raw").t, t)


def test_other_encodings_are_named(tmp_path):
    uppers, lowers = _words(np.random.default_rng(3), 200)
    path = _file(tmp_path / "x.raw", uppers, lowers,
                 header=["% evt 3.1", "% geometry 1280x720"])
    with pytest.raises(FormatError, match="reads EVT 2.0, 2.1 and 3.0"):
        evt21.read(path)
    noise = _file(tmp_path / "n.raw", np.random.default_rng(4).integers(
        0, 1 << 32, 500).astype(np.uint64), np.random.default_rng(5).integers(
        0, 1 << 32, 500).astype(np.uint64))
    with pytest.raises(FormatError, match="does not read as EVT 2.1 in either byte order"):
        read_events(noise)


def test_a_time_high_that_jumps_and_falls_back_is_refused(tmp_path):
    """Probe CG (EVT 2.0's, the same time words): a TIME_HIGH moved 200,000,000 (of 2^28)
    ahead, its fall back counted as a rollover of the 34-bit counter (every later time
    4.8 h on, unsaid); now it is named as a corrupt time field."""
    ev = random_events(3000, (720, 1280), 20_000, seed=1, t0=422)
    evt21.write(tmp_path / "a.raw", ev)
    data = (tmp_path / "a.raw").read_bytes()
    he = data.index(b"% end\n") + 6
    w = np.frombuffer(data[he:], "<u4").copy()  # (upper, lower) halves
    upper = w[0::2]
    th = np.flatnonzero(upper >> 28 == 8)
    k = int(th[100])
    upper[k] = (8 << 28) | ((int(upper[k]) + 200_000_000) & 0xFFFFFFF)
    w[0::2] = upper
    (tmp_path / "m.raw").write_bytes(data[:he] + w.tobytes())
    for block_bytes in (1 << 22, 8 * 301, 8):
        with pytest.raises(FormatError, match=rf"m\.raw: TIME_HIGH word at byte offset "
                                              rf"{he + 8 * k} holds time .*corrupt time"):
            evt21.read(tmp_path / "m.raw", block_bytes=block_bytes)


@pytest.mark.parametrize("cut", [1, 2, 37, 5000])
def test_chunks_stream_into_the_bytes_of_one_array(tmp_path, cut):
    """EVT 2.1 is written chunk by chunk (convert held every event: probe DL), with the
    bytes of one array's writing: chunks cut within a vector word's events (one time, row,
    polarity and 32-pixel group) and across a pause of hours (intermediate TIME_HIGH
    words) still make one vector where the whole array does."""
    from evmotion.io import write_events

    rng = np.random.default_rng(5)
    n = 4000
    t = np.sort(rng.integers(0, 300, n)).astype(np.int64)  # ~13 events a microsecond
    t[2500:] += 3 * 3600 * 10**6
    ev = EventArray(x=rng.integers(0, 64, n), y=rng.integers(0, 3, n), t=t,
                    p=rng.integers(0, 2, n), sensor_size=(480, 640))
    evt21.write(tmp_path / "whole.raw", ev)
    words = (tmp_path / "whole.raw").stat().st_size
    assert words < 8 * n  # vectors: fewer words than events
    write_events(tmp_path / "parts.raw", (ev[s:s + cut] for s in range(0, n, cut)),
                 format="evt21")
    assert (tmp_path / "parts.raw").read_bytes() == (tmp_path / "whole.raw").read_bytes()
    back = evt21.read(tmp_path / "parts.raw")
    np.testing.assert_array_equal(back.t, t)
    with pytest.raises(FormatError, match="stores times in order"):
        evt21.write(tmp_path / "bad.raw", iter([ev[10:20], ev[:10]]))
    assert not (tmp_path / "bad.raw").exists()
