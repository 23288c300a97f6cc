"""Prophesee EVT 3.0 RAW files (16-bit words after a ``%`` text header).

Word types (upper 4 bits): ``0x0`` ADDR_Y (y, bits 0-10), ``0x2`` ADDR_X (x + polarity
bit 11: one event), ``0x3`` VECT_BASE_X (base x + polarity), ``0x4`` VECT_12 and
``0x5`` VECT_8 (bit masks of events at base_x + i; base_x then advances by 12 or 8),
``0x6`` TIME_LOW and ``0x8`` TIME_HIGH (12 bits each). The 24-bit time wraps every
16.78 s; the decoder unwraps it into absolute int64 µs. Events before the first
TIME_HIGH have no time base and are dropped, as Prophesee's own decoder does.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from functools import partial
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import binary, prophesee
from evmotion.io.binary import take_time_high
from evmotion.jitcache import lazy_njit

__all__ = ["read", "iter_chunks", "write", "describe", "FORMAT"]

WRAP_US = 1 << 24
# Payloads up to this size are decoded in one piece by read() (the result is larger anyway)
WHOLE_FILE_BYTES = 1 << 28
# state slots carried from one block to the next; then, for the corrupt-time check, the
# last two unwrapped time bases (µs) and how many are set, the word index of the last
# TIME_HIGH, the words decoded before the block, the corrupt word found (its index + 1;
# 0: none) and the time base after it
_Y, _TH, _TL, _OVF, _BX, _VP, _SEEN, _U1, _U2, _NU, _P1, _BASE, _BAD, _AFTER = range(14)
CHECK_SLOTS = (_U1, _U2, _NU, _P1, _BAD, _AFTER)
TIME_SLOTS = (_TH, _OVF, _SEEN) + CHECK_SLOTS  # binary.take_time_high's


@lazy_njit(cache=True)
def _decode(words, start, state, ox, oy, ot, op):
    """Decode ``words[start:]`` into the output arrays until they might overflow.

    Returns ``(n_events, next_word)``; ``state`` (int64[14]) is updated in place so the
    next call, on the same block or the next one, continues seamlessly. Stops at a
    TIME_HIGH between two others 2^24 µs or more apart (unwrapped): a corrupt one, taken
    for a jump and a rollover, noted in ``state[_BAD]`` (:func:`binary.take_time_high`).
    """
    cap = ox.shape[0]
    y = state[_Y]
    th = state[_TH]
    tl = state[_TL]
    ovf = state[_OVF]
    bx = state[_BX]
    vp = state[_VP]
    nw = words.shape[0]
    i = start
    if not state[_SEEN]:
        # no time base yet: follow the addresses, emit nothing
        while i < nw:
            w = np.int64(words[i])
            typ = w >> 12
            i += 1
            if typ == 0x8:
                take_time_high(state, TIME_SLOTS, w & 0xFFF, state[_BASE] + i - 1, 24, 12)
                th = state[_TH]
                break
            if typ == 0x0:
                y = w & 0x7FF
            elif typ == 0x6:
                tl = w & 0xFFF
            elif typ == 0x3:
                bx = w & 0x7FF
                vp = (w >> 11) & 1
            elif typ == 0x4:
                bx += 12
            elif typ == 0x5:
                bx += 8
    n = 0
    tcur = ovf + (th << 12) + tl
    while i < nw and not state[_BAD]:
        # every word yields at most 12 events: no bounds check inside a span
        stop = min(nw, i + (cap - n) // 12)
        if stop <= i:
            break
        for j in range(i, stop):
            w = np.int64(words[j])
            typ = w >> 12
            if typ == 0x2:
                ox[n] = w & 0x7FF
                oy[n] = y
                ot[n] = tcur
                op[n] = (w >> 11) & 1
                n += 1
            elif typ == 0x0:
                y = w & 0x7FF
            elif typ == 0x6:
                tl = w & 0xFFF
                tcur = ovf + (th << 12) + tl
            elif typ == 0x8:
                bad = take_time_high(state, TIME_SLOTS, w & 0xFFF, state[_BASE] + j, 24, 12)
                th, ovf = state[_TH], state[_OVF]
                tcur = ovf + (th << 12) + tl
                if bad:
                    stop = j + 1
                    break
            elif typ == 0x3:
                bx = w & 0x7FF
                vp = (w >> 11) & 1
            elif typ == 0x4 or typ == 0x5:
                nb = 12 if typ == 0x4 else 8
                for k in range(nb):
                    if (w >> k) & 1:
                        ox[n] = bx + k
                        oy[n] = y
                        ot[n] = tcur
                        op[n] = vp
                        n += 1
                bx += nb
        i = stop
    if state[_BAD]:
        i = nw
    state[_Y] = y
    state[_TL] = tl
    state[_BX] = bx
    state[_VP] = vp
    return n, i


def _last(mask: np.ndarray) -> np.ndarray:
    """For each word, the index of the last word at or before it where ``mask`` holds, +1
    (0: none in the block, slot 0 of the arrays :func:`_decode_plain` prepends the state
    to)."""
    return np.maximum.accumulate(np.where(mask, np.arange(1, mask.size + 1), 0))


def _decode_plain(words: np.ndarray, state: np.ndarray) -> binary.Block:
    """What :func:`_decode` gives for the whole of ``words``, by numpy (blocks of at most
    ``binary.PLAIN_WORDS`` words): each word's address, time and vector base are the
    last ones set at or before it."""
    w = words.astype(np.int64)
    typ = w >> 12
    low = w & 0xFFF
    is_th = typ == 0x8
    seen = bool(state[_SEEN])
    first = int(np.argmax(is_th)) if is_th.any() else w.size
    h = low[is_th]
    offsets = state[_OVF] + (binary.counter_wraps(h, state[_TH], 2048, seen) << 24)
    if binary.note_corrupt(state, offsets + (h << 12), state[_BASE] + np.flatnonzero(is_th),
                           WRAP_US, CHECK_SLOTS):
        return tuple(np.empty(0, dt) for dt in (np.uint16, np.uint16, np.int64, np.uint8))
    ths = np.concatenate(([state[_TH]], h))[np.cumsum(is_th)]
    ovf = np.concatenate(([state[_OVF]], offsets))[np.cumsum(is_th)]
    is_y, is_tl, is_base = typ == 0x0, typ == 0x6, typ == 0x3
    y = np.concatenate(([state[_Y]], w & 0x7FF))[_last(is_y)]
    tl = np.concatenate(([state[_TL]], low))[_last(is_tl)]
    t = ovf + (ths << 12) + tl
    base_at = _last(is_base)
    vp = np.concatenate(([state[_VP]], (w >> 11) & 1))[base_at]
    step = np.where(typ == 0x4, 12, np.where(typ == 0x5, 8, 0))
    advanced = np.cumsum(step)
    # the vector base before each word: the last VECT_BASE_X's x plus the vectors since
    bx = (np.concatenate(([state[_BX]], w & 0x7FF))[base_at] + advanced - step
          - np.concatenate(([0], advanced))[base_at])
    live = np.ones(w.size, bool) if seen else np.arange(w.size) > first
    single = live & (typ == 0x2)
    vec = live & (step > 0)
    bits = ((w[vec, None] >> np.arange(12)) & 1).astype(bool) & \
        (np.arange(12) < step[vec, None])
    counts = np.zeros(w.size, np.int64)
    counts[single] = 1
    counts[vec] = bits.sum(axis=1)
    start = np.cumsum(counts) - counts
    n = int(counts.sum())
    ox = np.empty(n, np.uint16)
    oy = np.empty(n, np.uint16)
    ot = np.empty(n, np.int64)
    op = np.empty(n, np.uint8)
    at = start[single]
    ox[at], oy[at], ot[at], op[at] = w[single] & 0x7FF, y[single], t[single], \
        (w[single] >> 11) & 1
    rows, ks = np.nonzero(bits)
    words_of = np.flatnonzero(vec)[rows]
    at = start[words_of] + (np.cumsum(bits, axis=1) - 1)[rows, ks]
    ox[at], oy[at], ot[at], op[at] = bx[words_of] + ks, y[words_of], t[words_of], \
        vp[words_of]
    if w.size:
        state[_Y], state[_TH], state[_TL], state[_OVF] = y[-1], ths[-1], tl[-1], ovf[-1]
        state[_BX], state[_VP] = bx[-1] + step[-1], vp[-1]
        state[_SEEN] = seen or first < w.size
    return ox, oy, ot, op


def decode_words(words: np.ndarray, state: np.ndarray | None = None, *,
                 plain: bool | None = None) -> binary.Block:
    """Decode a block of EVT3 words (uint16) into ``(x, y, t, p)`` arrays.

    Parameters
    ----------
    words : ndarray of uint16
        Consecutive EVT3 words.
    state : ndarray of int64, shape (14,), optional
        Decoder state from the previous block (updated in place); a fresh decoder
        (no time base yet) when omitted.
    plain : bool, optional
        Decode by numpy rather than by the numba kernel (the same result); default for
        at most ``binary.PLAIN_WORDS`` words, which numba's start-up would not pay back.

    Returns
    -------
    x, y : uint16 ndarrays, t : int64 ndarray (µs, unwrapped), p : uint8 ndarray

    Examples
    --------
    >>> words = np.array([0x8001, 0x6005, 0x0007, 0x2803], np.uint16)  # TH, TL, Y, X+pol
    >>> x, y, t, p = decode_words(words)
    >>> int(x[0]), int(y[0]), int(t[0]), int(p[0])
    (3, 7, 4101, 1)
    """
    words = np.ascontiguousarray(words, dtype=np.uint16)
    state = new_state() if state is None else binary.check_state(state, new_state())
    if words.shape[0] <= binary.PLAIN_WORDS if plain is None else plain:
        out = _decode_plain(words, state)
    else:
        out = _decode_kernel(words, state)
    binary.raise_noted(state, CHECK_SLOTS, 24, "TIME_HIGH word")
    state[_BASE] += words.shape[0]
    return out


def _decode_kernel(words: np.ndarray, state: np.ndarray) -> binary.Block:
    """:func:`_decode` over the whole of ``words``, its output grown as needed."""
    parts = []
    i = 0
    while True:
        cap = max(words.shape[0] - i, 0) + 4096
        ox = np.empty(cap, np.uint16)
        oy = np.empty(cap, np.uint16)
        ot = np.empty(cap, np.int64)
        op = np.empty(cap, np.uint8)
        n, i = _decode(words, i, state, ox, oy, ot, op)
        parts.append((ox[:n], oy[:n], ot[:n], op[:n]))
        if i >= words.shape[0]:
            break
    if len(parts) == 1:
        return parts[0]
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(4))


def new_state() -> np.ndarray:
    """A fresh decoder state (no time base seen yet)."""
    return np.zeros(14, np.int64)


def _open(path: Path, sensor_size: tuple[int, int] | None, block_bytes: int,
          whole_bytes: int | None = None
          ) -> tuple[int, tuple[int, int], Iterator[binary.Block]]:
    return prophesee.open_raw(path, sensor_size, block_bytes, version="3.0", word="<u2",
                               decode_words=decode_words, new_state=new_state,
                               whole_bytes=whole_bytes)


def read(path: str | Path, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True,
         block_bytes: int = binary.BLOCK_BYTES) -> EventArray:
    """Read an EVT 3.0 RAW file.

    Parameters
    ----------
    path : path-like
        The ``.raw`` file.
    t0, t1 : int, optional
        Keep events with ``t0 <= t < t1`` (µs, absolute as in the file).
    sensor_size : (int, int), optional
        ``(height, width)`` if the header has no ``geometry`` line.
    validate : bool
        Check sortedness and bounds of the result.
    block_bytes : int
        Bytes read and decoded at a time when a time range is given or the payload
        exceeds 256 MiB (otherwise the payload is decoded in one pass, which is faster).

    Returns
    -------
    EventArray
        Timestamps unwrapped to int64 µs, as counted by the camera (Metavision's DAT
        export of the same recording subtracts a multiple of 4096 µs).

    Examples
    --------
    >>> ev = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                 sensor_size=(180, 240))
    >>> write("recording.raw", ev)
    >>> ev = read("recording.raw", t0=0, t1=250)
    >>> len(ev), ev.t.tolist()
    (2, [100, 200])
    """
    # without a time range, a payload up to WHOLE_FILE_BYTES is decoded in one pass
    opener = partial(_open, whole_bytes=WHOLE_FILE_BYTES) if t0 is None and t1 is None else _open
    return binary.read_file(path, "evt3", 2, opener, t0, t1, sensor_size=sensor_size,
                             validate=validate, block_bytes=block_bytes)


def iter_chunks(path: str | Path, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                block_bytes: int = binary.BLOCK_BYTES) -> Iterator[EventArray]:
    """Stream an EVT 3.0 file as EventArrays of ``chunk_events`` events (the last may be
    shorter), reading ``block_bytes`` at a time; decoder state carries across blocks.

    Examples
    --------
    >>> ev = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                 sensor_size=(180, 240))
    >>> write("recording.raw", ev)
    >>> for chunk in iter_chunks("recording.raw", 2):
    ...     print(len(chunk))
    2
    1
    """
    yield from binary.iter_file(path, chunk_events, "evt3", 2, _open, sensor_size=sensor_size,
                                 validate=validate, block_bytes=block_bytes)


@lazy_njit(cache=True)
def _encode(x, y, t, p, out):
    """EVT3 words for sorted events (times relative to the file's time base, ≥ 0).

    Runs of events sharing t, y and polarity with increasing x are packed into
    VECT_BASE_X + VECT_12/VECT_8 words when that is shorter than one ADDR_X per event.
    Returns the number of words written; ``out`` must hold ``4 * len(x) + 8 + gaps``.
    """
    n = x.shape[0]
    k = 0
    cur_hi = np.int64(-1)  # unwrapped (t >> 12) last announced
    cur_tl = np.int64(-1)
    cur_y = np.int64(-1)
    i = 0
    while i < n:
        ti = t[i]
        hi = ti >> 12
        if cur_hi < 0:
            cur_hi = hi
            out[k] = 0x8000 | (hi & 0xFFF)
            k += 1
            cur_tl = -1
        elif hi != cur_hi:
            # announce every half wrap on long gaps so the reader can count wraps
            while hi - cur_hi > 2047:
                cur_hi += 2047
                out[k] = 0x8000 | (cur_hi & 0xFFF)
                k += 1
            cur_hi = hi
            out[k] = 0x8000 | (hi & 0xFFF)
            k += 1
            cur_tl = -1
        tl = ti & 0xFFF
        if tl != cur_tl:
            out[k] = 0x6000 | tl
            k += 1
            cur_tl = tl
        yi = np.int64(y[i])
        if yi != cur_y:
            out[k] = yi & 0x7FF
            k += 1
            cur_y = yi
        # longest run from i with equal t, y, p and strictly increasing x
        j = i + 1
        while (j < n and t[j] == ti and y[j] == y[i] and p[j] == p[i]
               and x[j] > x[j - 1]):
            j += 1
        span = np.int64(x[j - 1]) - np.int64(x[i]) + 1
        n_vec = 1 + (span + 11) // 12
        if j - i >= 3 and n_vec < j - i:
            bx = np.int64(x[i])
            out[k] = 0x3000 | (np.int64(p[i]) << 11) | bx
            k += 1
            m = i
            while m < j:
                width = 12 if np.int64(x[j - 1]) - bx >= 8 else 8
                mask = np.int64(0)
                while m < j and np.int64(x[m]) < bx + width:
                    mask |= np.int64(1) << (np.int64(x[m]) - bx)
                    m += 1
                out[k] = (0x4000 if width == 12 else 0x5000) | mask
                k += 1
                bx += width
            i = j
        else:
            out[k] = 0x2000 | (np.int64(p[i]) << 11) | np.int64(x[i])
            k += 1
            i += 1
    return k


def encode(events: EventArray, t_base: int = 0) -> np.ndarray:
    """EVT3 words (uint16) for ``events``, times taken relative to ``t_base`` µs."""
    t = events.t - t_base
    n = len(events)
    gaps = 0
    if n:
        if t[0] < 0:
            raise FormatError(None, f"event time {events.t[0]} us is before the time base "
                              f"{t_base} us")
        gaps = int(((t[-1] >> 12) - (t[0] >> 12)) // 2047) + 1
    out = np.empty(4 * n + 8 + gaps, np.uint16)
    k = _encode(np.ascontiguousarray(events.x, np.uint16), np.ascontiguousarray(events.y, np.uint16),
                np.ascontiguousarray(t), events.p, out)
    return out[:k]


def write(path: str | Path, events: EventArray | Iterable[EventArray], *,
          header: dict | None = None) -> None:
    """Write ``events`` (an EventArray, or chunks of one in time order, streamed in
    bounded memory) as an EVT 3.0 RAW file (atomically).

    Integer coordinates below 2048 are required. When the first timestamp is at or past
    the 24-bit counter range (16.78 s), a multiple of 2^24 µs is stored in the header key
    ``evmotion_time_offset_us`` so :func:`read` restores the absolute times bit-exactly
    (other tools see times modulo 2^24, as a camera would produce them).

    Examples
    --------
    >>> events = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                     sensor_size=(180, 240))
    >>> write("out.raw", events)
    >>> read("out.raw").t.tolist()
    [100, 200, 300]
    """
    # a lone event: TIME_HIGH, TIME_LOW, ADDR_Y and its ADDR_X
    prophesee.write_raw(path, events, version="3.0", wrap_us=WRAP_US, encode=encode,
                         word="<u2", header=header, lead_words=4)


describe = prophesee.raw_describe("evt3", 2)

FORMAT = prophesee.raw_format("evt3", "3.0", describe, read, iter_chunks, write)
