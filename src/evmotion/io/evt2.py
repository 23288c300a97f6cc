"""Prophesee EVT 2.0 RAW files (32-bit little-endian words after a ``%`` text header).

Word types (bits 28-31): ``0x0`` CD_OFF and ``0x1`` CD_ON (bits 22-27: the 6 low time
bits, bits 11-21: x, bits 0-10: y), ``0x8`` TIME_HIGH (bits 0-27: time bits 6-33),
``0xA`` EXT_TRIGGER, ``0xE`` OTHERS, ``0xF`` CONTINUED. The 34-bit time wraps after
4.8 h; the decoder unwraps it. Events before the first TIME_HIGH are dropped.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from evmotion.events import EventArray
from evmotion.io import binary, prophesee
from evmotion.io.binary import take_time_high
from evmotion.jitcache import lazy_njit

__all__ = ["read", "iter_chunks", "write", "describe", "decode_words", "time_high_words",
           "FORMAT"]

WRAP_US = 1 << 34
_HALF = 1 << 27
# decoder state slots (EVT 2.1's too): the time high, the wrap offset, whether a time high
# was seen, (EVT 2.1: the byte order), then for the corrupt-time check the last two
# unwrapped time bases (µs) and how many are set, the word index of the last time high,
# the words decoded before the block, the corrupt word found (its index + 1; 0: none) and
# the time base after it
(SLOT_TH, SLOT_OVF, SLOT_SEEN, SLOT_ORDER, SLOT_U1, SLOT_U2, SLOT_NU, SLOT_P1, SLOT_BASE,
 SLOT_BAD, SLOT_AFTER) = range(11)
STATE_SLOTS = 11
CHECK_SLOTS = (SLOT_U1, SLOT_U2, SLOT_NU, SLOT_P1, SLOT_BAD, SLOT_AFTER)
TIME_SLOTS = (SLOT_TH, SLOT_OVF, SLOT_SEEN) + CHECK_SLOTS  # binary.take_time_high's


@lazy_njit(cache=True)
def _decode(words, state, ox, oy, ot, op):
    """Decode a block; ``state`` (:func:`new_state`) is updated in place. Stops at a time
    high between two others 2^34 µs or more apart (unwrapped): a corrupt one, taken for a
    jump and a rollover, noted in ``state[SLOT_BAD]`` (:func:`binary.take_time_high`)."""
    th, ovf, seen = state[SLOT_TH], state[SLOT_OVF], state[SLOT_SEEN]
    n = 0
    for i in range(words.shape[0]):
        w = np.int64(words[i])
        typ = w >> 28
        if typ <= 1:
            if seen:
                ox[n] = (w >> 11) & 0x7FF
                oy[n] = w & 0x7FF
                ot[n] = ovf + (th << 6) + ((w >> 22) & 0x3F)
                op[n] = typ
                n += 1
        elif typ == 0x8:
            if take_time_high(state, TIME_SLOTS, w & 0xFFFFFFF, state[SLOT_BASE] + i, 34, 6):
                break
            th, ovf, seen = state[SLOT_TH], state[SLOT_OVF], 1
    return n


def _decode_plain(words, state, ox, oy, ot, op):
    """:func:`_decode` by numpy (blocks of at most ``binary.PLAIN_WORDS`` words)."""
    w = words.astype(np.int64)
    typ = w >> 28
    is_th = typ == 0x8
    h = w[is_th] & 0xFFFFFFF
    wraps = binary.counter_wraps(h, state[SLOT_TH], _HALF, bool(state[SLOT_SEEN]))
    if binary.note_corrupt(state, state[SLOT_OVF] + (wraps << 34) + (h << 6),
                           state[SLOT_BASE] + np.flatnonzero(is_th), WRAP_US, CHECK_SLOTS):
        return 0
    # each word's time base: the last TIME_HIGH at or before it (slot 0: the state's)
    base = np.concatenate(([state[SLOT_TH]], h))
    offset = np.concatenate(([state[SLOT_OVF]], state[SLOT_OVF] + (wraps << 34)))
    k = np.cumsum(is_th)
    keep = (typ <= 1) & ((k > 0) | bool(state[SLOT_SEEN]))
    wk, kk = w[keep], k[keep]
    n = wk.size
    ox[:n] = (wk >> 11) & 0x7FF
    oy[:n] = wk & 0x7FF
    ot[:n] = offset[kk] + (base[kk] << 6) + ((wk >> 22) & 0x3F)
    op[:n] = typ[keep]
    if h.size:
        state[SLOT_TH], state[SLOT_OVF], state[SLOT_SEEN] = h[-1], offset[-1], 1
    return n


def new_state() -> np.ndarray:
    """A fresh decoder state (no time base seen yet)."""
    return np.zeros(STATE_SLOTS, np.int64)


def decode_words(words: np.ndarray, state: np.ndarray | None = None, *,
                 plain: bool | None = None) -> binary.Block:
    """Decode EVT2 words (uint32) into ``(x, y, t, p)``; ``state`` carries across blocks.
    ``plain``: decode by numpy rather than by the numba kernel (the same result; default
    for at most ``binary.PLAIN_WORDS`` words, which numba's start-up would not pay back).

    Examples
    --------
    >>> x, y, t, p = decode_words(np.array([0x80000001, 0x10000000 | (5 << 11) | 7],
    ...                                    np.uint32))
    >>> int(x[0]), int(y[0]), int(t[0]), int(p[0])
    (5, 7, 64, 1)
    """
    words = np.ascontiguousarray(words, dtype=np.uint32)
    state = new_state() if state is None else binary.check_state(state, new_state())
    n = words.shape[0]
    ox = np.empty(n, np.uint16)
    oy = np.empty(n, np.uint16)
    ot = np.empty(n, np.int64)
    op = np.empty(n, np.uint8)
    if plain is None:
        plain = n <= binary.PLAIN_WORDS
    decode = _decode_plain if plain else _decode
    k = decode(words, state, ox, oy, ot, op)
    binary.raise_noted(state, CHECK_SLOTS, 34, "TIME_HIGH word")
    state[SLOT_BASE] += n
    return ox[:k], oy[:k], ot[:k], op[:k]


def _open(path: Path, sensor_size: tuple[int, int] | None, block_bytes: int
          ) -> tuple[int, tuple[int, int], Iterator[binary.Block]]:
    return prophesee.open_raw(path, sensor_size, block_bytes, version="2.0", word="<u4",
                               decode_words=decode_words, new_state=new_state)


def read(path: str | Path, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True,
         block_bytes: int = binary.BLOCK_BYTES) -> EventArray:
    """Read an EVT 2.0 RAW file.

    Parameters
    ----------
    path : path-like
    t0, t1 : int, optional
        Keep ``t0 <= t < t1`` (µs).
    sensor_size : (int, int), optional
        ``(height, width)``; required when the header has no geometry (older Gen3
        files, e.g. 480x640).
    validate : bool
        Check sortedness and bounds.
    block_bytes : int
        Read granularity.

    Examples
    --------
    >>> ev = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                 sensor_size=(180, 240))
    >>> write("gen3.raw", ev)
    >>> ev = read("gen3.raw", sensor_size=(480, 640))
    >>> len(ev), ev.sensor_size
    (3, (480, 640))
    """
    return binary.read_file(path, "evt2", 4, _open, t0, t1, sensor_size=sensor_size,
                             validate=validate, block_bytes=block_bytes)


def iter_chunks(path: str | Path, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                block_bytes: int = binary.BLOCK_BYTES) -> Iterator[EventArray]:
    """Stream an EVT 2.0 file in EventArrays of ``chunk_events`` events."""
    yield from binary.iter_file(path, chunk_events, "evt2", 4, _open, sensor_size=sensor_size,
                                 validate=validate, block_bytes=block_bytes)


@lazy_njit(cache=True)
def time_high_words(out, k, cur, hi):
    """TIME_HIGH words (type 0x8, time bits 6-33 in bits 0-27; EVT 2.1 keeps them in its
    upper half, the lower 32 bits of its words as written) taking the time base from
    ``cur`` (-1: none yet) to ``hi``, at ``out[k:]``: a jump of half the counter or more
    gets intermediate words, so that the reader does not take it for a wrap. Returns the
    next free index."""
    if cur >= 0:
        while hi - cur >= _HALF:
            cur += _HALF - 1
            out[k] = (np.int64(0x8) << 28) | (cur & 0xFFFFFFF)
            k += 1
    out[k] = (np.int64(0x8) << 28) | (hi & 0xFFFFFFF)
    return k + 1


@lazy_njit(cache=True)
def _encode(x, y, t, p, out):
    k = 0
    cur = np.int64(-1)
    for i in range(x.shape[0]):
        hi = t[i] >> 6
        if hi != cur:
            k = time_high_words(out, k, cur, hi)
            cur = hi
        out[k] = ((np.int64(p[i]) << 28) | ((t[i] & 0x3F) << 22)
                  | (np.int64(x[i]) << 11) | np.int64(y[i]))
        k += 1
    return k


def encode(events: EventArray, t_base: int = 0) -> np.ndarray:
    """EVT2 words (uint32) for ``events``, times relative to ``t_base`` µs."""
    t = np.ascontiguousarray(events.t - t_base)
    gaps = int(((t[-1] - t[0]) >> 6) // (_HALF - 1)) + 1 if len(t) else 0
    out = np.empty(2 * len(t) + gaps, np.uint32)
    k = _encode(np.ascontiguousarray(events.x, np.uint16),
                np.ascontiguousarray(events.y, np.uint16), t, events.p, out)
    return out[:k]


def write(path: str | Path, events: EventArray | Iterable[EventArray]) -> None:
    """Write ``events`` (an EventArray, or chunks of one in time order, streamed in
    bounded memory) as an EVT 2.0 RAW file (atomically); see :func:`evt3.write` for how
    times past the counter range (here 2^34 µs) are kept exact.

    Examples
    --------
    >>> events = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                     sensor_size=(180, 240))
    >>> write("out.raw", events)
    >>> read("out.raw").t.tolist()
    [100, 200, 300]
    """
    # a lone event is a TIME_HIGH word and its own
    prophesee.write_raw(path, events, version="2.0", wrap_us=WRAP_US, encode=encode,
                         word="<u4", lead_words=2)


describe = prophesee.raw_describe("evt2", 4)

FORMAT = prophesee.raw_format("evt2", "2.0", describe, read, iter_chunks, write)
