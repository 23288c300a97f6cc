"""EVT 2.0: numba decoder vs a plain-Python reference, the shared Gen3 file, streaming,
time-high wrap and writer round-trips."""

from __future__ import annotations

import numpy as np
import pytest

from _helpers import assert_decoders_agree, assert_same_events, random_events
from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import evt2
from evmotion.io.prophesee import parse_raw_header
from evmotion.io.registry import detect_spec


def reference_decode(words):
    out, th, ovf, seen = [], 0, 0, False
    for w in (int(v) for v in words):
        typ = w >> 28
        if typ in (0, 1) and seen:
            out.append(((w >> 11) & 0x7FF, w & 0x7FF, ovf + (th << 6) + ((w >> 22) & 63), typ))
        elif typ == 0x8:
            h = w & 0xFFFFFFF
            if seen and h < th and th - h >= 1 << 27:
                ovf += 1 << 34
            th, seen = h, True
    return np.array(out, np.int64).reshape(-1, 4)


@pytest.fixture(scope="module")
def raw(shared_data):
    return shared_data / "formats" / "evt2.raw"


def test_shared_file(raw):
    ev = evt2.read(raw)
    assert len(ev) == 521_252
    assert ev.sensor_size == (480, 640)  # Gen3 plugin, no geometry line
    assert 0.09e6 < ev.duration_us < 0.11e6


def test_numba_matches_reference(raw, decoder):
    _, off, _, _ = parse_raw_header(raw, None)
    words = np.fromfile(raw, np.uint8)[off:].view("<u4")[:60_000]
    x, y, t, p = evt2.decode_words(words)
    np.testing.assert_array_equal(np.stack([x, y, t, p], 1).astype(np.int64),
                                  reference_decode(words))


def test_numpy_decoder_matches_the_kernel_on_random_words_in_blocks():
    """The numpy decoder of small files (binary.PLAIN_WORDS: a fresh process reading a
    one-window file spent 1-2 s loading numba, probe BD) against the kernel: random words
    of every type, time bases that wrap, blocks with the state carried across."""
    rng = np.random.default_rng(5)
    n = 20_000
    typ = rng.choice([0x0, 0x1, 0x8, 0xA, 0xE, 0xF], n, p=[.35, .35, .2, .04, .03, .03])
    payload = rng.integers(0, 1 << 28, n)
    # time bases that mostly count up, now and then fall back past half the counter
    payload[typ == 0x8] = np.cumsum(rng.integers(0, 1 << 26, int((typ == 0x8).sum()))) \
        % (1 << 28)
    words = ((typ << 28) | payload).astype(np.uint32)
    state = assert_decoders_agree(evt2, words, 30, rng)
    assert state[1] > 0  # the counter wrapped


def test_chunks_and_filter(raw, decoder):
    whole = evt2.read(raw)
    chunks = list(evt2.iter_chunks(raw, 100_000, block_bytes=1001))
    assert sum(len(c) for c in chunks) == len(whole)
    np.testing.assert_array_equal(np.concatenate([c.t for c in chunks]), whole.t)
    t0, t1 = int(whole.t[10]), int(whole.t[-10])
    assert_same_events(evt2.read(raw, t0=t0, t1=t1), whole.slice_time(t0, t1))


def test_round_trip(raw, tmp_path):
    ev = evt2.read(raw)
    evt2.write(tmp_path / "a.raw", ev)
    assert_same_events(evt2.read(tmp_path / "a.raw"), ev)
    assert detect_spec(tmp_path / "a.raw").name == "evt2"


def test_round_trip_wrap_and_offset(tmp_path, decoder):
    t = np.array([5, 70, (1 << 34) + 3, (1 << 35) + 100, (1 << 35) + 100]) + 3 * (1 << 34)
    ev = EventArray(x=[1, 2, 3, 4, 5], y=[0, 1, 2, 3, 4], t=t, p=[1, 0, 1, 0, 1],
                    sensor_size=(8, 8))
    evt2.write(tmp_path / "w.raw", ev)
    assert_same_events(evt2.read(tmp_path / "w.raw", block_bytes=8), ev)


def test_truncated(raw, tmp_path):
    _, off, _, _ = parse_raw_header(raw, None)
    cut = tmp_path / "cut.raw"
    cut.write_bytes(raw.read_bytes()[:off + 4000 + 3])
    with pytest.raises(FormatError, match=rf"byte offset {off + 4000}"):
        evt2.read(cut)


def test_data_starting_with_the_header_marker_is_not_eaten(tmp_path):
    """A RAW file without '% end' whose first event word begins with 0x25 ('%') lost the
    bytes up to the next 0x0A as a header line (19,980 of 20,000 events read)."""
    import numpy as np

    from evmotion.io import read_events

    words = []
    for k in range(100):
        t = 0x25 * 64 + 40 + k * 64
        words.append(0x80000000 | (t >> 6))  # EV_TIME_HIGH: first byte 0x25
        words += [(i % 2) << 28 | (t & 63) << 22 | (i * 7 % 640) << 11 | (i * 3 % 480)
                  for i in range(20)]
    path = tmp_path / "pct.raw"
    path.write_bytes(b"% evt 2.0\n% geometry 640x480\n"
                     + np.array(words, "<u4").tobytes())
    assert path.read_bytes()[len(b"% evt 2.0\n% geometry 640x480\n")] == 0x25
    ev = read_events(path)
    assert len(ev) == 2000 and ev.sensor_size == (480, 640)


def test_a_header_that_understates_the_sensor_says_how_to_give_it(tmp_path):
    ev = EventArray(x=[697, 3], y=[5, 6], t=[10, 20], p=[1, 0], sensor_size=(720, 1280))
    evt2.write(tmp_path / "a.raw", ev)
    raw = (tmp_path / "a.raw").read_bytes()
    raw = raw.replace(b"height=720;width=1280", b"height=480;width=640 ").replace(
        b"geometry 1280x720", b"geometry 640x480  ")
    (tmp_path / "a.raw").write_bytes(raw)
    from evmotion.io import read_events

    with pytest.raises(FormatError, match="x=697 outside the sensor.*--sensor-size.*"
                                          "sensor_size="):
        read_events(tmp_path / "a.raw")
    assert evt2.read(tmp_path / "a.raw", sensor_size=(720, 1280)).x.tolist() == [697, 3]


def test_header_lines_stating_different_sizes_are_refused(tmp_path):
    """'% format ...;height=480;width=640' beside '% geometry 1280x720': the geometry line
    won, unsaid (probe AS); a given size reads the file."""
    from evmotion.io import read_events

    ev = EventArray(x=[97, 3], y=[5, 6], t=[10, 20], p=[1, 0], sensor_size=(480, 640))
    evt2.write(tmp_path / "a.raw", ev)
    raw = (tmp_path / "a.raw").read_bytes().replace(b"geometry 640x480",
                                                    b"geometry 128x720")
    (tmp_path / "a.raw").write_bytes(raw)
    with pytest.raises(FormatError, match=r"different sensor sizes: '% format EVT2;height=480;"
                                          r"width=640'; '% geometry 128x720'"):
        read_events(tmp_path / "a.raw")
    assert read_events(tmp_path / "a.raw", sensor_size=(480, 640)).x.tolist() == [97, 3]


def _corrupted(tmp_path, shift: int, picks=(100, 200), t0=422):
    """A 20 ms recording from ``t0`` µs written as EVT 2.0, then TIME_HIGH words ``picks``
    moved ``shift`` (of 2^28) ahead: the events, the file, the byte offsets of the words
    and the first one's and its neighbours' words."""
    ev = random_events(3000, (60, 80), 20_000, seed=11, t0=t0)
    evt2.write(tmp_path / "a.raw", ev)
    data = (tmp_path / "a.raw").read_bytes()
    he = data.index(b"% end\n") + 6
    w = np.frombuffer(data[he:], "<u4").copy()
    th = np.flatnonzero(w >> 28 == 8)
    for j in picks:
        w[th[j]] = (8 << 28) | ((int(w[th[j]]) + shift) & 0xFFFFFFF)
    (tmp_path / "m.raw").write_bytes(data[:he] + w.tobytes())
    j = picks[0]
    return ev, tmp_path / "m.raw", [he + 4 * int(th[j]) for j in picks], w[th[j - 1:j + 2]]


@pytest.mark.parametrize("block_bytes", [1 << 22, 4 * 401, 4])
def test_a_time_high_that_jumps_and_falls_back_is_refused(tmp_path, decoder, block_bytes):
    """Probe CG: TIME_HIGH words 100 and 200 moved 200,000,000 (of 2^28) ahead: each
    fall back was counted as a rollover of the 34-bit counter (a 20 ms recording read as
    34,360 s, unsaid); now the first is named as a corrupt time field."""
    _, path, offsets, (before, at, after) = _corrupted(tmp_path, 200_000_000)
    t = [(int(v) & 0xFFFFFFF) << 6 for v in (before, at, after)]
    with pytest.raises(FormatError, match=rf"m\.raw: TIME_HIGH word at byte offset "
                                          rf"{offsets[0]} holds time {t[1]} us, .*\({t[0]} us "
                                          rf"before, {t[2]} us after.*corrupt time field"):
        evt2.read(path, block_bytes=block_bytes)
    with pytest.raises(FormatError, match="TIME_HIGH word at byte offset .*corrupt time"):
        list(evt2.iter_chunks(path, 500, block_bytes=block_bytes))


def test_a_time_high_that_falls_and_jumps_back_is_refused(tmp_path, decoder):
    """Three hours into the counter, a TIME_HIGH moved 150,000,000 (of 2^28) back."""
    _, path, offsets, _ = _corrupted(tmp_path, (1 << 28) - 150_000_000, picks=(100,),
                                     t0=3 * 3600 * 10 ** 6)
    with pytest.raises(FormatError, match=rf"word at byte offset {offsets[0]} .*corrupt time"):
        evt2.read(path)


def test_the_corrupt_time_check_agrees_in_both_decoders_across_blocks():
    """Time bases counting by 1,000,000 (of 2^28, wrapping once), one moved half the
    counter ahead: both decoders stop at it, wherever the blocks are cut."""
    rng = np.random.default_rng(2)
    h = np.arange(400) * 1_000_000 % (1 << 28)
    words = ((8 << 28) | h).astype(np.uint32)
    assert assert_decoders_agree(evt2, words, 30, rng)[1] == 1 << 34  # no fault: a wrap
    words[100] = (8 << 28) | (int(h[100]) + (1 << 27) + (1 << 21))
    for plain in (True, False):
        for cuts in ([7, 100, 250], [101, 300], [100, 101, 102]):
            state = evt2.new_state()
            with pytest.raises(FormatError, match="TIME_HIGH word 100 of the payload"):
                for part in np.split(words, cuts):
                    evt2.decode_words(part, state, plain=plain)


@pytest.mark.parametrize("cut", [1, 3, 700])
def test_evt2_chunks_stream_into_the_same_file(tmp_path, cut):
    """EVT 2.0 is written chunk by chunk, each encoded after the previous chunk's last event
    (probe DL: converting to .raw held every event): the same bytes as the whole array's,
    across time-high changes and a pause past half the 2^34 us counter."""
    from evmotion.io import write_events

    rng = np.random.default_rng(8)
    t = np.sort(rng.integers(5_000, 9_000, 1500)).astype(np.int64)
    t[900:] += 3 * 3600 * 10**6  # three hours: intermediate TIME_HIGH words
    ev = EventArray(x=rng.integers(0, 640, 1500), y=rng.integers(0, 480, 1500), t=t,
                    p=rng.integers(0, 2, 1500), sensor_size=(480, 640))
    evt2.write(tmp_path / "whole.raw", ev)
    write_events(tmp_path / "parts.raw", (ev[s:s + cut] for s in range(0, len(ev), cut)),
                 format="evt2")
    assert (tmp_path / "parts.raw").read_bytes() == (tmp_path / "whole.raw").read_bytes()
    np.testing.assert_array_equal(evt2.read(tmp_path / "parts.raw").t, t)
    with pytest.raises(FormatError, match="stores times in order"):
        evt2.write(tmp_path / "bad.raw", iter([ev[10:20], ev[:10]]))
    assert not (tmp_path / "bad.raw").exists()
