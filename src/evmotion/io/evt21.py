"""Prophesee EVT 2.1 RAW files (64-bit words after a ``%`` text header).

Word types (bits 60-63): ``0x0`` EVT_NEG and ``0x1`` EVT_POS (bits 54-59: the 6 low time
bits, bits 43-53: x aligned on 32, bits 32-42: y, bits 0-31: a mask whose bit ``n`` is an
event at ``x + n``), ``0x8`` EVT_TIME_HIGH (bits 32-59: time bits 6-33), ``0xA``
EXT_TRIGGER, ``0xE`` OTHERS. The 34-bit time wraps after 4.8 h; the decoder unwraps it.
Events before the first EVT_TIME_HIGH are dropped.

The sensors store a word in one of two byte orders: the IMX636 as two little-endian 32-bit
halves, the upper (type, time, x, y) first; the GenX320 as one little-endian 64-bit word,
the mask first. The header does not say which; the reader takes the order under which the
file's first words read as valid EVT 2.1 (time words with an empty lower half, event words
with a non-empty mask), and writes the IMX636's.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import binary, prophesee
from evmotion.io.binary import take_time_high
from evmotion.io.evt2 import (
    CHECK_SLOTS,
    SLOT_BASE,
    SLOT_ORDER,
    SLOT_OVF,
    SLOT_SEEN,
    SLOT_TH,
    STATE_SLOTS,
    TIME_SLOTS,
    time_high_words,
)
from evmotion.jitcache import lazy_njit

__all__ = ["read", "iter_chunks", "write", "describe", "decode_words", "FORMAT"]

WRAP_US = 1 << 34
_HALF = 1 << 27
# words looked at to tell the byte order
SNIFF_WORDS = 4096


@lazy_njit(cache=True)
def _count(words, upper_first):
    n = 0
    for i in range(words.shape[0]):
        w = np.uint64(words[i])
        hi = (w & np.uint64(0xFFFFFFFF)) if upper_first else (w >> np.uint64(32))
        lo = (w >> np.uint64(32)) if upper_first else (w & np.uint64(0xFFFFFFFF))
        if (hi >> np.uint64(28)) <= np.uint64(1):
            while lo:
                lo &= lo - np.uint64(1)
                n += 1
    return n


@lazy_njit(cache=True)
def _decode(words, upper_first, state, ox, oy, ot, op):
    """Decode a block; ``state`` (:func:`new_state`, EVT 2.0's slots) is updated in place.
    Stops at a time high between two others 2^34 µs or more apart (unwrapped): a corrupt
    one, taken for a jump and a rollover, noted in ``state[SLOT_BAD]``
    (:func:`binary.take_time_high`)."""
    th, ovf, seen = state[SLOT_TH], state[SLOT_OVF], state[SLOT_SEEN]
    n = 0
    for i in range(words.shape[0]):
        w = np.uint64(words[i])
        hi = np.int64((w & np.uint64(0xFFFFFFFF)) if upper_first else (w >> np.uint64(32)))
        lo = np.int64((w >> np.uint64(32)) if upper_first else (w & np.uint64(0xFFFFFFFF)))
        typ = hi >> 28
        if typ <= 1:
            if seen:
                x0 = (hi >> 11) & 0x7FF
                y = hi & 0x7FF
                t = ovf + (th << 6) + ((hi >> 22) & 0x3F)
                for b in range(32):
                    if (lo >> b) & 1:
                        ox[n] = x0 + b
                        oy[n] = y
                        ot[n] = t
                        op[n] = typ
                        n += 1
        elif typ == 0x8:
            if take_time_high(state, TIME_SLOTS, hi & 0xFFFFFFF, state[SLOT_BASE] + i, 34, 6):
                break
            th, ovf, seen = state[SLOT_TH], state[SLOT_OVF], 1
    return n


def new_state(upper_first: bool = True) -> np.ndarray:
    """A fresh decoder state: no time base seen yet; the byte order (1: the IMX636's)."""
    state = np.zeros(STATE_SLOTS, np.int64)
    state[SLOT_ORDER] = int(upper_first)
    return state


def decode_words(words: np.ndarray, state: np.ndarray | None = None) -> binary.Block:
    """Decode EVT 2.1 words (read as little-endian uint64) into ``(x, y, t, p)``; ``state``
    (:func:`new_state`) carries the time base and the byte order across blocks.

    Examples
    --------
    >>> th = np.uint64(0x8 << 28 | 1)                  # time high 1: t = 64 + ...
    >>> cd = np.uint64(0x1 << 28 | 3 << 22 | 32 << 11 | 7 | 0b101 << 32)
    >>> x, y, t, p = decode_words(np.array([th, cd], np.uint64))
    >>> x.tolist(), y.tolist(), t.tolist(), p.tolist()
    ([32, 34], [7, 7], [67, 67], [1, 1])
    """
    words = np.ascontiguousarray(words, dtype=np.uint64)
    state = new_state() if state is None else binary.check_state(state, new_state())
    upper_first = bool(state[SLOT_ORDER])
    n = _count(words, upper_first)
    ox = np.empty(n, np.uint16)
    oy = np.empty(n, np.uint16)
    ot = np.empty(n, np.int64)
    op = np.empty(n, np.uint8)
    k = _decode(words, upper_first, state, ox, oy, ot, op)
    binary.raise_noted(state, CHECK_SLOTS, 34, "TIME_HIGH word")
    state[SLOT_BASE] += words.shape[0]
    return ox[:k], oy[:k], ot[:k], op[:k]


def _validity(words: np.ndarray, upper_first: bool) -> float:
    """Share of ``words`` that read as EVT 2.1 in that byte order."""
    lo32 = words & np.uint64(0xFFFFFFFF)
    hi, lo = (lo32, words >> np.uint64(32)) if upper_first else (words >> np.uint64(32), lo32)
    typ = hi >> np.uint64(28)
    ok = (((typ <= 1) & (lo != 0)) | (((typ == 8) | (typ == 0xA)) & (lo == 0))
          | (typ == 0xE))
    return float(ok.mean()) if ok.size else 1.0


def byte_order(path: Path, offset: int) -> bool:
    """True where the file stores its words as the IMX636 does (upper half first)."""
    head = np.fromfile(path, np.uint8, count=8 * SNIFF_WORDS, offset=offset)
    words = head[:head.size - head.size % 8].view("<u8")
    upper, whole = _validity(words, True), _validity(words, False)
    if max(upper, whole) < 0.9:
        raise FormatError(path, f"the payload does not read as EVT 2.1 in either byte order "
                          f"({100 * upper:.0f} % / {100 * whole:.0f} % of the first "
                          f"{words.size} words valid)")
    return upper >= whole


def _open(path: Path, sensor_size: tuple[int, int] | None, block_bytes: int
          ) -> tuple[int, tuple[int, int], Iterator[binary.Block]]:
    _, offset, size, t_offset = prophesee.parse_raw_header(path, sensor_size, "2.1")
    state = new_state(byte_order(path, offset))
    return offset, size, prophesee.raw_blocks(path, offset, t_offset, block_bytes, "<u8",
                                              decode_words, state)


def read(path: str | Path, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True,
         block_bytes: int = binary.BLOCK_BYTES) -> EventArray:
    """Read an EVT 2.1 RAW file; the arguments are :func:`evmotion.io.evt2.read`'s (the
    sensor size by default from the header's geometry).

    Examples
    --------
    >>> write("evk4_evt21.raw", EventArray(x=np.arange(64), y=np.full(64, 7),
    ...       t=np.arange(64) // 8, p=np.ones(64), sensor_size=(720, 1280)))
    >>> back = read("evk4_evt21.raw")   # (EVT 2.1 packs up to 32 pixels of a row a word)
    >>> len(back), back.sensor_size, int(back.t.max())
    (64, (720, 1280), 7)
    """
    return binary.read_file(path, "evt21", 8, _open, t0, t1, sensor_size=sensor_size,
                            validate=validate, block_bytes=block_bytes)


def iter_chunks(path: str | Path, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                block_bytes: int = binary.BLOCK_BYTES) -> Iterator[EventArray]:
    """Stream an EVT 2.1 file in EventArrays of ``chunk_events`` events."""
    yield from binary.iter_file(path, chunk_events, "evt21", 8, _open, sensor_size=sensor_size,
                                validate=validate, block_bytes=block_bytes)


@lazy_njit(cache=True)
def _encode(x, y, t, p, out):
    """Events (sorted by time) to words: one time word per new ``t >> 6``, then one event
    word per run of events of one time, row, polarity and 32-px block."""
    k = 0
    cur = np.int64(-1)
    i = 0
    m = x.shape[0]
    while i < m:
        hi = t[i] >> 6
        if hi != cur:
            k = time_high_words(out, k, cur, hi)
            cur = hi
        block = np.int64(x[i]) >> 5
        mask = np.int64(0)
        j = i
        while (j < m and t[j] == t[i] and y[j] == y[i] and p[j] == p[i]
               and (np.int64(x[j]) >> 5) == block
               and not (mask >> (np.int64(x[j]) & 31)) & 1):
            mask |= np.int64(1) << (np.int64(x[j]) & 31)
            j += 1
        upper = ((np.int64(p[i]) << 28) | ((t[i] & 0x3F) << 22) | ((block << 5) << 11)
                 | np.int64(y[i]))
        out[k] = np.uint64(upper) | (np.uint64(mask) << np.uint64(32))
        k += 1
        i = j
    return k


def encode(events: EventArray, t_base: int = 0) -> np.ndarray:
    """EVT 2.1 words for ``events`` in the IMX636's byte order (as little-endian uint64),
    times relative to ``t_base`` µs."""
    t = np.ascontiguousarray(events.t - t_base)
    gaps = int(((t[-1] - t[0]) >> 6) // (_HALF - 1)) + 1 if len(t) else 0
    out = np.empty(2 * len(t) + gaps, np.uint64)
    k = _encode(np.ascontiguousarray(events.x, np.uint16),
                np.ascontiguousarray(events.y, np.uint16), t,
                np.ascontiguousarray(events.p, np.uint8), out)
    return out[:k]


def write(path: str | Path, events: EventArray | Iterable[EventArray]) -> None:
    """Write ``events`` (an EventArray, or chunks of one in time order, streamed in
    bounded memory) as an EVT 2.1 RAW file (atomically), in the IMX636's byte order;
    see :func:`evt3.write` for how times past the counter range (here 2^34 µs) are kept
    exact. Consecutive events of one timestamp, row, polarity and 32-pixel group share
    one vector word, so :func:`read` returns them ordered by x.

    Examples
    --------
    >>> events = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                     sensor_size=(180, 240))
    >>> write("out.raw", events)
    >>> read("out.raw").t.tolist()
    [100, 200, 300]
    """
    # a lone event is a TIME_HIGH word and its vector word
    prophesee.write_raw(path, events, version="2.1", wrap_us=WRAP_US, encode=encode,
                        word="<u8", lead_words=2)


describe = prophesee.raw_describe("evt21", 8)

FORMAT = prophesee.raw_format("evt21", "2.1", describe, read, iter_chunks, write)
