"""EVT 3.0: numba decoder vs a plain-Python reference, agreement with the DAT export of
the same recording, vectorized words, 24-bit wrap, streaming state and writer round-trips."""

from __future__ import annotations

import re

import numpy as np
import pytest

from _helpers import (
    assert_chunks_track_the_file,
    assert_decoders_agree,
    assert_same_events,
    random_events,
)
from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import dat, evt3
from evmotion.io.prophesee import parse_raw_header
from evmotion.io.registry import detect_spec


def reference_decode(words):
    """Literal EVT3 decoding, one word at a time (events before the first TIME_HIGH dropped)."""
    out = []
    y = th = tl = ovf = bx = vp = 0
    seen = False
    for w in (int(v) for v in words):
        typ, val = w >> 12, w & 0xFFF
        if typ == 0x0:
            y = val & 0x7FF
        elif typ == 0x2 and seen:
            out.append((val & 0x7FF, y, ovf + th * 4096 + tl, val >> 11))
        elif typ == 0x3:
            bx, vp = val & 0x7FF, val >> 11
        elif typ in (0x4, 0x5):
            nb = 12 if typ == 0x4 else 8
            if seen:
                out += [(bx + k, y, ovf + th * 4096 + tl, vp) for k in range(nb) if val >> k & 1]
            bx += nb
        elif typ == 0x6:
            tl = val
        elif typ == 0x8:
            if seen and val < th and th - val >= 2048:
                ovf += 1 << 24
            th, seen = val, True
    return np.array(out, np.int64).reshape(-1, 4)


def _words(path):
    _, off, _, _ = parse_raw_header(path, None)
    return np.fromfile(path, np.uint8)[off:].view("<u2")


@pytest.fixture(scope="module")
def raw(shared_data):
    return shared_data / "formats" / "evt3.raw"


def test_numba_matches_reference_on_a_slice_with_vectors(raw, decoder):
    words = _words(raw)
    typ = words >> 12
    i = int(np.argmax((typ == 0x4) | (typ == 0x5)))
    part = words[max(i - 20_000, 0):i + 20_000]
    assert ((part >> 12) == 0x4).any() and ((part >> 12) == 0x5).any()
    x, y, t, p = evt3.decode_words(part)
    ref = reference_decode(part)
    np.testing.assert_array_equal(np.stack([x, y, t, p], 1).astype(np.int64), ref)


def test_synthetic_vectors_and_wrap(decoder):
    w = [0x8000 | 4095, 0x6000 | 10, 0x0000 | 7, 0x3000 | (1 << 11) | 100,
         0x4000 | 0b100000000101, 0x5000 | 0b10000001,
         0x8000 | 3, 0x6000 | 1, 0x2000 | 5]
    x, y, t, p = evt3.decode_words(np.array(w, np.uint16))
    assert x.tolist() == [100, 102, 111, 112, 119, 5]
    assert y.tolist() == [7] * 6
    assert p.tolist() == [1, 1, 1, 1, 1, 0]
    assert t[:5].tolist() == [4095 * 4096 + 10] * 5
    assert t[5] == (1 << 24) + 3 * 4096 + 1  # 24-bit counter wrapped once


def test_numpy_decoder_matches_the_kernel_on_random_words_in_blocks():
    """The numpy decoder of small blocks (binary.PLAIN_WORDS: a fresh process reading a
    one-window file spent 1-2 s loading numba, probe BD) against the kernel: random words
    of every type, time bases that wrap and jump, split into blocks with the state carried
    from one to the next, from a fresh decoder."""
    rng = np.random.default_rng(3)
    types = np.array([0x0, 0x2, 0x3, 0x4, 0x5, 0x6, 0x8, 0x7, 0xA, 0xE])
    typ = rng.choice(types, 20_000, p=[.15, .2, .05, .1, .1, .15, .15, .04, .03, .03])
    low = rng.integers(0, 1 << 12, 20_000)
    # time bases that count up, by jumps of up to 1500 (of 4096) and wrapping, as a
    # counter does (random ones read as corrupt time words: test_corrupt_time_high...)
    low[typ == 0x8] = np.cumsum(rng.integers(0, 1500, int((typ == 0x8).sum()))) % (1 << 12)
    words = ((typ << 12) | low).astype(np.uint16)
    state = assert_decoders_agree(evt3, words, 40, rng)
    assert state[3] > 0  # the counter wrapped


def test_agrees_event_for_event_with_dat_export(shared_data, raw):
    a = evt3.read(raw)
    b = dat.read(shared_data / "formats" / "gen4.dat")
    assert len(a) == len(b) == 1_218_618
    assert a.sensor_size == b.sensor_size == (720, 1280)
    for f in "xyp":
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    shift = np.unique(a.t - b.t)
    # Metavision shifts DAT times by a whole number of TIME_HIGH periods
    assert shift.size == 1 and shift[0] % 4096 == 0
    assert 10.7e6 < a.duration_us < 10.9e6


def test_streaming_across_tiny_blocks_equals_whole_read(raw, decoder):
    whole = evt3.read(raw, t1=None)
    chunks = list(evt3.iter_chunks(raw, 300_001, block_bytes=4097 * 2 + 1))
    assert [len(c) for c in chunks[:-1]] == [300_001] * (len(chunks) - 1)
    assert_same_events(whole, EventArray(
        *(np.concatenate([getattr(c, f) for c in chunks]) for f in "xytp"),
        sensor_size=whole.sensor_size))


def test_time_filter(raw):
    whole = evt3.read(raw)
    t0, t1 = int(whole.t[1000]), int(whole.t[500_000])
    part = evt3.read(raw, t0=t0, t1=t1, block_bytes=65536)
    assert_same_events(part, whole.slice_time(t0, t1))


def test_round_trip_shared_file_bit_exact(raw, tmp_path):
    ev = evt3.read(raw)
    out = tmp_path / "copy.raw"
    evt3.write(out, ev)
    assert_same_events(evt3.read(out), ev)
    assert _words(out).size < _words(raw).size


def test_round_trip_long_gaps_and_large_times(tmp_path):
    rng = np.random.default_rng(0)
    n = 5000
    t = np.sort(rng.integers(0, 60_000_000, n)) + 1_600_000_000_000_000
    t[2000:] += 40_000_000  # a gap of more than two 24-bit wraps
    x = rng.integers(0, 640, n)
    y = rng.integers(0, 480, n)
    x[100:130], y[100:130], t[100:130] = np.arange(200, 230), 17, t[100]  # a vector run
    p = rng.integers(0, 2, n)
    p[100:130] = 1
    order = np.argsort(t, kind="stable")
    ev = EventArray(x=x[order], y=y[order], t=t[order], p=p[order], sensor_size=(480, 640))
    out = tmp_path / "syn.raw"
    evt3.write(out, ev)
    assert_same_events(evt3.read(out), ev)
    assert_same_events(evt3.read(out, block_bytes=64), ev)
    typ = _words(out) >> 12
    assert (typ == 0x3).sum() >= 1 and (typ == 0x4).sum() >= 2 and (typ == 0x5).sum() >= 1


def test_detected_by_content(raw, tmp_path):
    copy = tmp_path / "no_extension"
    copy.write_bytes(raw.read_bytes()[:100_000])
    assert detect_spec(copy).name == "evt3"


def test_truncated_file_names_offset(raw, tmp_path):
    _, off, _, _ = parse_raw_header(raw, None)
    cut = tmp_path / "cut.raw"
    cut.write_bytes(raw.read_bytes()[:off + 100_001])
    with pytest.raises(FormatError, match=rf"cut\.raw.*byte offset {off + 100_000}"):
        evt3.read(cut)
    with pytest.raises(FormatError, match="truncated"):
        next(evt3.iter_chunks(cut, 10))


def test_header_without_geometry(tmp_path):
    bad = tmp_path / "bad.raw"
    bad.write_bytes(b"% evt 3.0\n% end\n" + b"\x00\x80" * 4)
    with pytest.raises(FormatError, match="geometry"):
        evt3.read(bad)
    assert len(evt3.read(bad, sensor_size=(10, 10))) == 0


def test_small_chunks_from_large_blocks(raw):
    head = evt3.read(raw, t1=11_300_000)
    it = evt3.iter_chunks(raw, 7)
    got = [next(it) for _ in range(len(head) // 7)]
    assert all(len(c) == 7 for c in got)
    np.testing.assert_array_equal(np.concatenate([c.t for c in got]),
                                  head.t[:7 * len(got)])


def test_describe(raw):
    d = evt3.describe(raw)
    assert d["sensor_size"] == (720, 1280) and d["header"]["evt"] == "3.0"


def test_wrong_format_is_refused(shared_data, raw):
    from evmotion.io import evt2

    with pytest.raises(FormatError, match="evt 3.0"):
        evt3.read(shared_data / "formats" / "gen4.dat")
    with pytest.raises(FormatError, match="'evt' is '3.0'"):
        evt2.read(raw)
    with pytest.raises(FormatError, match="event size"):
        dat.read(raw)


def test_writer_refuses_float_and_oversized(tmp_path):
    fl = EventArray(x=[0.5], y=[1.0], t=[0], p=[1], sensor_size=(4, 4))
    with pytest.raises(FormatError, match="float"):
        evt3.write(tmp_path / "f.raw", fl)
    big = EventArray(x=[3000], y=[1], t=[0], p=[1], sensor_size=(4, 4000))
    with pytest.raises(FormatError, match="2048"):
        evt3.write(tmp_path / "b.raw", big)
    assert not (tmp_path / "b.raw").exists()


def test_streaming_memory_is_bounded(raw):
    import tracemalloc

    next(evt3.iter_chunks(raw, 10))  # load the compiled kernels outside the measurement
    tracemalloc.start()
    try:
        n = 0
        for chunk in evt3.iter_chunks(raw, 50_000, block_bytes=1 << 18):
            n += len(chunk)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert n == 1_218_618
    assert peak < 10 << 20  # the whole recording decoded takes 16 MB


@pytest.mark.parametrize("block_bytes", [4096, 1 << 30])  # many blocks; the whole at once
def test_chunks_say_how_far_into_the_file_they_are(tmp_path, block_bytes):
    # EVT headers state no event count: the share of the file read gives a progress
    # bar its total; the events' share and the bytes' share agree for uniform data
    out = tmp_path / "pos.raw"
    evt3.write(out, random_events(40_000, (480, 640), 2_000_000))
    assert_chunks_track_the_file(evt3, out, 40_000, block_bytes)


@pytest.mark.parametrize("fmt", ["evt2", "evt21", "evt3"])
def test_a_file_without_its_header_reads_with_format_and_size(tmp_path, fmt):
    """A stream recorded from the sensor's interface has no '%' header. Detection said
    "give --format explicitly", and the format given said "no '%' header": a dead end.
    Now the registry names the RAW formats and --sensor-size, and the format given reads
    the words from byte 0 with that size."""
    from evmotion.io import read_events, write_events

    ev = random_events(3000, (180, 240), 50_000)
    full = tmp_path / "with_header.raw"
    write_events(full, ev, format=fmt)
    _, off, _, _ = parse_raw_header(full, None)
    bare = tmp_path / "bare.raw"
    bare.write_bytes(full.read_bytes()[off:])
    with pytest.raises(FormatError, match=r"bare\.raw: a \.raw file with no '%' header.*"
                       r"--format evt3 \(or evt2, evt21\) and --sensor-size H W"):
        detect_spec(bare)
    with pytest.raises(FormatError, match=r"header-less EVT \d\.\d stream states no sensor "
                       r"size .*--sensor-size H W"):
        read_events(bare, format=fmt)
    assert_same_events(read_events(bare, format=fmt, sensor_size=(180, 240)), ev)


@pytest.mark.parametrize("fmt", ["evt3", "dat"])
def test_a_file_cut_within_a_word_says_how_to_read_the_rest(tmp_path, fmt):
    # probe BL: the raw and dat refusals said only "the file was cut short"
    import evmotion.io as eio

    ev = EventArray(x=np.arange(200) % 30, y=np.arange(200) % 20, t=np.arange(200) * 7,
                    p=np.arange(200) % 2, sensor_size=(20, 30))
    path = tmp_path / f"r.{'raw' if fmt == 'evt3' else 'dat'}"
    eio.write_events(path, ev, format=fmt)
    whole = path.read_bytes()
    path.write_bytes(whole[:-1])
    with pytest.raises(FormatError, match=r"stray byte.*head -c (\d+) FILE > TRIMMED") as exc:
        eio.read_events(path)
    keep = int(re.search(r"head -c (\d+)", str(exc.value)).group(1))
    path.write_bytes(whole[:keep])
    assert 0 < len(eio.read_events(path)) <= 200


@pytest.mark.parametrize("fmt, word", [("evt2", 4), ("evt3", 2)])
def test_two_recordings_joined_are_named(tmp_path, fmt, word):
    # "truncated: N stray byte(s) ... the file was cut short": following it, the second
    # header was read as events, "timestamps are not sorted" (probe CF)
    import evmotion.io as eio

    ev = EventArray(x=np.arange(200) % 30, y=np.arange(200) % 20, t=np.arange(200) * 7,
                    p=np.arange(200) % 2, sensor_size=(20, 30))
    path = tmp_path / "r.raw"
    eio.write_events(path, ev, format=fmt)
    one = path.read_bytes()
    head = one.index(b"% end\n") + len(b"% end\n")
    # the joined payload (the second header in it) is not whole words, as probe CF's was
    extra = next(k for k in range(word) if (2 * len(one) - head + k) % word)
    joined = tmp_path / "j.raw"
    joined.write_bytes(one + one + b"\0" * extra)
    with pytest.raises(FormatError, match=r"a header line \('% evt .*'\) at byte offset "
                                          rf"{len(one)}, inside the events: two recordings "
                                          rf"joined\? .*head -c {len(one)} FILE > FIRST"):
        eio.read_events(joined, format=fmt)
    first = tmp_path / "first.raw"
    first.write_bytes(joined.read_bytes()[:len(one)])
    assert len(eio.read_events(first)) == 200


@pytest.mark.parametrize(("t0", "shift"), [(0, 3000), (13_000_000, 4096 - 3000)])
def test_a_corrupt_time_high_is_refused_not_taken_for_a_rollover(tmp_path, decoder, t0,
                                                                 shift):
    """Probe CG (as in EVT 2.0): a TIME_HIGH word moved 3000 (of 4096) ahead of its
    neighbours, or (13 s into the counter) behind them: the fall (or the fall after the jump) was counted as a rollover
    of the 24-bit counter, every later time 16.8 s on, unsaid; now it is named as a
    corrupt time field."""
    ev = random_events(3000, (480, 640), 1_000_000, seed=4)
    ev = EventArray(ev.x, ev.y, ev.t + t0, ev.p, ev.sensor_size)  # (13 s: time high 3173..)
    evt3.write(tmp_path / "a.raw", ev)
    data = (tmp_path / "a.raw").read_bytes()
    he = data.index(b"% end\n") + 6
    w = np.frombuffer(data[he:], "<u2").copy()
    th = np.flatnonzero(w >> 12 == 8)
    k = int(th[100])
    w[k] = 0x8000 | ((int(w[k]) + shift) & 0xFFF)
    (tmp_path / "m.raw").write_bytes(data[:he] + w.tobytes())
    at = (int(w[k]) & 0xFFF) << 12
    for read in (evt3.read, lambda p: list(evt3.iter_chunks(p, 100, block_bytes=2 * 99))):
        with pytest.raises(FormatError, match=rf"m\.raw: TIME_HIGH word at byte offset "
                                              rf"{he + 2 * k} holds time {at} us.*corrupt"):
            read(tmp_path / "m.raw")


@pytest.mark.parametrize("module, dtype", [("evt2", np.uint32), ("evt21", np.uint64),
                                           ("evt3", np.uint16)])
def test_a_decoder_state_of_another_length_is_refused(module, dtype):
    """The state grew when the decoders learnt to refuse corrupt times: an old 3-slot
    state had the kernel write past its end, then an IndexError (review CR)."""
    import importlib

    from evmotion.errors import ParameterError

    mod = importlib.import_module(f"evmotion.io.{module}")
    with pytest.raises(ParameterError, match=r"state must be an int64 array of shape"):
        mod.decode_words(np.zeros(4, dtype), np.zeros(3, np.int64))


@pytest.mark.parametrize("cut", [1, 5, 7, 700])
def test_chunks_stream_into_the_same_file(tmp_path, cut):
    """EVT 3.0 is written chunk by chunk (probe DL: converting to .raw held every event):
    cut where the time changes and each part encoded after the previous part's last event,
    the same bytes as the whole array's, vector words of events of one time across a
    chunk boundary, the 24-bit wrap and a long pause included."""
    from evmotion.io import write_events

    rng = np.random.default_rng(9)
    k = 400  # times, each with a run of 6 events of one row and polarity: vector words
    t = np.repeat(np.arange(k, dtype=np.int64) * 50 + (1 << 24) - 9000, 6)
    t[6 * 300:] += 40 * 10**6  # a 40 s pause: intermediate TIME_HIGH words
    x = np.tile([0, 1, 2, 3, 5, 7], k) + np.repeat(rng.integers(0, 600, k), 6)
    ev = EventArray(x=x, y=np.repeat(np.arange(k) % 5, 6), t=t,
                    p=np.repeat(np.arange(k) % 2, 6), sensor_size=(480, 640))
    n = len(ev)
    words = evt3.encode(ev)
    assert np.count_nonzero(words >> 12 == 0x3) == k  # a VECT_BASE_X for every run
    evt3.write(tmp_path / "whole.raw", ev)
    write_events(tmp_path / "parts.raw", (ev[s:s + cut] for s in range(0, n, cut)),
                 format="evt3")
    assert (tmp_path / "parts.raw").read_bytes() == (tmp_path / "whole.raw").read_bytes()
    np.testing.assert_array_equal(evt3.read(tmp_path / "parts.raw").t, t)
    with pytest.raises(FormatError, match="stores times in order"):
        evt3.write(tmp_path / "bad.raw", iter([ev[10:20], ev[:10]]))
    assert not (tmp_path / "bad.raw").exists()
