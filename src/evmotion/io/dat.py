"""Prophesee DAT files (``% Data file containing CD events``; the ATIS / Gen1 ``_td.dat``
files of ``Event2D`` events alike).

After ``%`` header lines come two bytes (event type: 0x0C CD, or 0x00 the generic 2D event
of the ATIS files, laid out the same; event size = 8), then 8-byte
little-endian records: u32 timestamp (µs) and u32 with x in bits 0-13, y in bits 14-27
and polarity in bit 28. The 32-bit timestamp wraps after 71.6 min; the reader unwraps it.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import binary, prophesee
from evmotion.io.base import FormatSpec
from evmotion.jitcache import lazy_njit
from evmotion.utils import atomic_path

__all__ = ["read", "iter_chunks", "write", "describe", "FORMAT"]

CD_TYPE = 0x0C
# Event2d (the ATIS / Gen1 "TD" files): the same address word as CD events
EVENT2D_TYPE = 0x00
_OTHER_TYPES = {0x0E: "external trigger events", 0x0D: "exposure measurement (APS) events"}
RECORD = 8
# Sensor size of the ATIS (Gen1) files, whose header has no geometry.
DEFAULT_SIZE = (240, 304)


# decoder state slots: the last raw time, the wrap offset, the last two unwrapped times
# and how many of them are set (for the corrupt-time check), records decoded before the
# block, and the corrupt record found (its index + 1; 0: none)
_LAST, _OVF, _U1, _U2, _NU, _BASE, _BAD = range(7)


def new_state(t_offset: int = 0) -> np.ndarray:
    """A fresh decoder state, its wrap offset starting at ``t_offset`` µs."""
    state = np.zeros(7, np.int64)
    state[_OVF] = t_offset
    return state


@lazy_njit(cache=True)
def _decode(ts, data, state, ox, oy, ot, op):
    """Unwrap u32 times and split the address word (``state``: see :func:`new_state`,
    updated in place); stops at a time 2^32 µs or more from both neighbours' (unwrapped),
    a corrupt one taken for a rollover, setting ``state[_BAD]``."""
    last = state[_LAST]
    ovf = state[_OVF]
    u1 = state[_U1]
    u2 = state[_U2]
    nu = state[_NU]
    for i in range(ts.shape[0]):
        t = np.int64(ts[i])
        if t < last and last - t > (np.int64(1) << 31):
            ovf += np.int64(1) << 32
        last = t
        u = t + ovf
        if nu >= 2 and u - u2 >= (np.int64(1) << 32):
            state[_BAD] = state[_BASE] + i  # the record before this one, + 1
            return
        u2 = u1
        u1 = u
        nu += 1
        d = data[i]
        ox[i] = d & 0x3FFF
        oy[i] = (d >> 14) & 0x3FFF
        op[i] = (d >> 28) & 1
        ot[i] = u
    state[_LAST] = last
    state[_OVF] = ovf
    state[_U1] = u1
    state[_U2] = u2
    state[_NU] = nu
    state[_BASE] += ts.shape[0]


def _decode_plain(ts, data, state, ox, oy, ot, op):
    """:func:`_decode` by numpy (blocks of at most ``binary.PLAIN_WORDS`` records)."""
    t = ts.astype(np.int64)
    wraps = binary.counter_wraps(t, state[_LAST], (1 << 31) + 1)  # (the kernel's "> 2^31")
    u = t + state[_OVF] + (wraps << 32)
    prev = state[[_U2, _U1]][2 - min(int(state[_NU]), 2):]
    bad = binary.corrupt_counter(u, prev, 1 << 32)
    if bad is not None:
        state[_BAD] = state[_BASE] + bad + 1
        return
    ot[:] = u
    ox[:] = data & 0x3FFF
    oy[:] = (data >> 14) & 0x3FFF
    op[:] = (data >> 28) & 1
    if t.size:
        state[_LAST] = t[-1]
        state[_OVF] += int(wraps[-1]) << 32
        state[_U2], state[_U1] = (u[-2], u[-1]) if t.size > 1 else (state[_U1], u[-1])
        state[_NU] += t.size
        state[_BASE] += t.size


def _corrupt(path: Path, offset: int, state: np.ndarray, blocks: list) -> FormatError:
    """The error for the corrupt record ``state[_BAD] - 1``: its time and its neighbours',
    as stored (``blocks``: the raw times of the blocks read so far, the last two kept)."""
    k = int(state[_BAD]) - 1
    ts = np.concatenate(blocks)
    first = int(state[_BASE]) - (ts.size - blocks[-1].size)  # record index of ts[0]
    times = ts[k - 1 - first:k + 2 - first]
    return binary.CorruptTimeError(k, times, 32, "event").at(
        path, f"event {k} (timestamp at byte offset {offset + RECORD * k})")


def _parse_header(path: Path, sensor_size):
    lines, offset = binary.read_text_header(path, b"%")
    if not lines:
        raise FormatError(path, "no '%' header at byte 0", "not a Prophesee DAT file")
    with open(path, "rb") as fh:
        fh.seek(offset)
        pair = fh.read(2)
    if len(pair) < 2:
        raise FormatError(path, f"truncated: the event type/size bytes at byte offset {offset} "
                          "are missing")
    ev_type, ev_size = pair[0], pair[1]
    if ev_size != RECORD:
        raise FormatError(path, f"field 'event size' at byte offset {offset + 1} is {ev_size}, "
                          f"expected {RECORD}", "corrupt header or not a CD-event DAT file")
    if ev_type not in (CD_TYPE, EVENT2D_TYPE):
        what = _OTHER_TYPES.get(ev_type, "an unknown event type")
        raise FormatError(path, f"field 'event type' at byte offset {offset} is {ev_type:#x} "
                          f"({what}); only CD ({CD_TYPE:#x}) and 2D / TD ({EVENT2D_TYPE:#x}) "
                          "events are read")
    size = sensor_size or binary.geometry_from_header(lines, path, DEFAULT_SIZE)
    return lines, offset + 2, size


def _blocks(path: Path, offset: int, block_bytes: int, t_offset: int = 0
            ) -> Iterator[binary.Block]:
    state = new_state(t_offset)  # the unwrapping offset starts at the header's time offset
    decode = _decode_plain if binary.small_payload(path, offset, RECORD) else _decode
    kept: list[np.ndarray] = []  # the raw times of the last blocks, for an error message
    for _, buf in binary.iter_blocks(path, offset, block_bytes, RECORD):
        rec = np.frombuffer(buf, "<u4").reshape(-1, 2)
        n = rec.shape[0]
        x = np.empty(n, np.uint16)
        y = np.empty(n, np.uint16)
        t = np.empty(n, np.int64)
        p = np.empty(n, np.uint8)
        ts = np.ascontiguousarray(rec[:, 0])
        kept = [*kept[-2:], ts]
        decode(ts, np.ascontiguousarray(rec[:, 1]), state, x, y, t, p)
        if state[_BAD]:
            raise _corrupt(path, offset, state, kept)
        yield x, y, t, p


def _open(path: Path, sensor_size: tuple[int, int] | None, block_bytes: int
          ) -> tuple[int, tuple[int, int], Iterator[binary.Block]]:
    lines, offset, size = _parse_header(path, sensor_size)
    return offset, size, _blocks(path, offset, block_bytes,
                                 prophesee.header_time_offset(path, lines))


def read(path: str | Path, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True,
         block_bytes: int = binary.BLOCK_BYTES) -> EventArray:
    """Read a Prophesee DAT (CD events) file.

    Parameters
    ----------
    path : path-like
    t0, t1 : int, optional
        Keep ``t0 <= t < t1`` (µs).
    sensor_size : (int, int), optional
        ``(height, width)``; from the ``% Height``/``% Width`` header lines, else
        304x240 (ATIS).
    validate : bool
        Check sortedness and bounds.
    block_bytes : int
        Read granularity.

    Examples
    --------
    >>> gen4 = EventArray(x=[1279, 640, 0], y=[719, 360, 0], t=[100, 200, 300],
    ...                   p=[1, 0, 1], sensor_size=(720, 1280))    # a Prophesee Gen4
    >>> write("recording_td.dat", gen4)
    >>> read("recording_td.dat").x.tolist()
    [1279, 640, 0]
    """
    return binary.read_file(path, "dat", RECORD, _open, t0, t1, sensor_size=sensor_size,
                             validate=validate, block_bytes=block_bytes)


def iter_chunks(path: str | Path, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                block_bytes: int = binary.BLOCK_BYTES) -> Iterator[EventArray]:
    """Stream a DAT file in EventArrays of ``chunk_events`` events, in bounded memory."""
    yield from binary.iter_file(path, chunk_events, "dat", RECORD, _open,
                                 sensor_size=sensor_size, validate=validate,
                                 block_bytes=block_bytes)


def write(path: str | Path, events: EventArray | Iterable[EventArray]) -> None:
    """Write ``events`` (an EventArray, or chunks of one in time order, streamed in
    bounded memory) as a DAT file (atomically).

    Times are stored modulo 2^32 µs, as cameras do; :func:`read` restores them exactly
    when consecutive events are less than 2^31 µs (35.8 min) apart. A first time past
    2^32 µs (a clock since the epoch), or before 0, is written from the multiple of 2^32 µs
    at or below it, kept in the header as ``% evmotion_time_offset_us`` (other readers see
    times from there); coordinates past DAT's 14 bits are refused (FormatError).

    Examples
    --------
    >>> events = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                     sensor_size=(180, 240))
    >>> write("out_td.dat", events)
    >>> read("out_td.dat").x.tolist()
    [10, 20, 30]
    >>> write("out_td.dat", iter([events[:2], events[2:]]))   # in chunks
    >>> read("out_td.dat").t.tolist()
    [100, 200, 300]
    """
    first, chunks = binary.first_chunk(path, events)
    # the header states the first chunk's sensor and the first event's time base
    t_base = binary.u32_time_base(first[:1], "DAT")
    h, w = first.sensor_size
    header = ("% Data file containing CD events.\n% Version 2\n"
              f"% Width {w}\n% Height {h}\n"
              + (f"% {prophesee.OFFSET_KEY} {t_base}\n" if t_base else "")).encode()
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header)
        fh.write(bytes([CD_TYPE, RECORD]))
        # 14-bit x and y address fields
        for chunk in binary.checked_chunks(first, chunks, "DAT", 1 << 14, 1 << 14,
                                           u32_base=t_base):
            rec = np.empty((len(chunk), 2), "<u4")
            rec[:, 0] = (chunk.t & 0xFFFFFFFF).astype(np.uint32)
            rec[:, 1] = (chunk.x.astype(np.uint32) | (chunk.y.astype(np.uint32) << 14)
                         | (chunk.p.astype(np.uint32) << 28))
            fh.write(rec.tobytes())


def describe(path: str | Path) -> dict:
    """Header fields, geometry and event count of a DAT file."""
    path = Path(path)
    lines, offset, size = _parse_header(path, None)
    out = {"format": "dat", "sensor_size": size, "header": prophesee.header_dict(lines),
           "n_events": (path.stat().st_size - offset) // RECORD, "frames": 0, "imu": 0}
    if binary.geometry_from_header(lines, path, (0, 0)) == (0, 0):  # the header's none
        # a default, which --sensor-size does not replace as stated (probe CR)
        out["sensor_size_from"] = (f"DAT's default {DEFAULT_SIZE[1]} x {DEFAULT_SIZE[0]} "
                                   "(the header states no size)")
    return out


def _sniff(path: Path, head: bytes) -> bool:
    if not head.startswith(b"%"):
        return False
    if b"% Data file containing CD events" in head:
        return True
    # recent DAT files carry no title line; they are '%' headers with Width/Height or
    # Version but no 'evt' key (which marks RAW files)
    text = head.split(b"\n")
    keys = {line[2:].split(b" ")[0].lower() for line in text if line.startswith(b"% ")}
    return b"evt" not in keys and b"format" not in keys and (
        b"width" in keys or b"height" in keys or b"version" in keys)


FORMAT = FormatSpec(name="dat", extensions=(".dat",), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
