"""Helpers shared by the binary camera-format readers: text headers, block streaming,
re-chunking and time filtering."""

from __future__ import annotations

import itertools
import re
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np

from evmotion.catalog import NS_EPOCH_US
from evmotion.errors import FormatError, ParameterError, UnsortedError
from evmotion.events import EventArray, check_follows
from evmotion.io.guard import SENSOR_SIZE_HINT, check_sensor_size
from evmotion.jitcache import lazy_njit

# Decoded blocks are 4-tuples of contiguous arrays (x uint16, y uint16, t int64, p uint8).
Block = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]

BLOCK_BYTES = 1 << 22
#: Blocks of at most this many words (events, for the checks) are decoded and checked by
#: numpy rather than by the numba kernels: a one-window file read in a fresh process spent
#: 1-2 s importing numba and loading its kernels (probe BD), which numpy's ~10-60 ms for
#: this many words does not pay back.
PLAIN_WORDS = 1 << 20


def small_payload(path: Path, offset: int, word_bytes: int) -> bool:
    """Whether the payload of ``path`` from ``offset`` holds at most ``PLAIN_WORDS`` words
    of ``word_bytes``: such a file is decoded by numpy, a larger one all by the kernel
    (numpy's temporaries would take twice the kernel's memory while streaming)."""
    return Path(path).stat().st_size - offset <= PLAIN_WORDS * word_bytes


def check_state(state, fresh: np.ndarray) -> np.ndarray:
    """A decoder's ``state`` as its kernel indexes it: an int64 array shaped as ``fresh``
    (its ``new_state()``), else ParameterError (a state of another length had the kernel
    write past its end, then an IndexError traceback; review CR).

    Examples
    --------
    >>> check_state(np.zeros(3, np.int64), np.zeros(11, np.int64))
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: state must be an int64 array of shape (11,), as new_state() makes it; got int64 (3,)
    """
    if not (isinstance(state, np.ndarray) and state.dtype == np.int64
            and state.shape == fresh.shape):
        got = (f"{state.dtype} {state.shape}" if isinstance(state, np.ndarray)
               else type(state).__name__)
        raise ParameterError(f"state must be an int64 array of shape {fresh.shape}, as "
                             f"new_state() makes it; got {got}")
    return state


def counter_wraps(values: np.ndarray, last: int, half: int, seen: bool = True) -> np.ndarray:
    """For each of a time counter's ``values`` (int64), how many times it has wrapped
    since ``last``, the value before them: a value below the one before it by ``half``
    or more has wrapped. With ``seen`` False the first value has no past (a fresh
    decoder) and is not compared.

    Examples
    --------
    >>> counter_wraps(np.array([10, 2, 9, 1]), last=12, half=8).tolist()
    [0, 1, 1, 2]
    """
    prev = np.concatenate(([last], values[:-1]))
    wrapped = (values < prev) & (prev - values >= half)
    wrapped[:1] &= seen
    return np.cumsum(wrapped)


class CorruptTimeError(FormatError):
    """A time counter's value that jumps ahead and falls back (or falls and jumps back)
    by half the counter or more: the decoders took the fall for a rollover of the counter,
    adding a whole counter period to every time after it (probe CG: a 20 ms recording read
    as 8,590 s). A genuine rollover follows a whole period of counting: the value after it,
    unwrapped, is less than one period after the value two before it; a value between two
    neighbours a period or more apart (unwrapped) is corrupt.

    ``pos`` is the corrupt value's place (a record, or a word of the payload), ``times``
    the stored times (µs, modulo the counter) of it and of its neighbours, ``bits`` the
    counter's width in µs; :meth:`at` names it in its file."""

    def __init__(self, pos: int, times: tuple[int, int, int], bits: int,
                 what: str = "time word"):
        self.pos, self.times, self.bits = int(pos), tuple(int(v) for v in times), bits
        super().__init__(None, self.text(f"{what} {self.pos} of the payload"))

    def text(self, where: str) -> str:
        before, at, after = self.times
        return (f"{where} holds time {at} us, out of line with the times around it "
                f"({before} us before, {after} us after; stored modulo 2^{self.bits} us): "
                "a corrupt time field (read as a rollover of the counter, it would put "
                f"2^{self.bits} us or more between its neighbours)")

    def at(self, path, where: str) -> FormatError:
        """The same error naming ``path`` and the value's place ``where`` in it."""
        return FormatError(path, self.text(where), "the file is corrupt")


def corrupt_counter(u: np.ndarray, prev: np.ndarray, period: int) -> int | None:
    """Where, in the unwrapped counter values ``u`` (int64, after ``prev``, the last one
    or two values before them), the first value lies between two neighbours ``period`` or
    more apart (a corrupt value taken for a jump and a rollover, see
    :class:`CorruptTimeError`): its index in ``u`` (-1: the last of ``prev``), or None.

    Examples
    --------
    >>> corrupt_counter(np.array([10, 900, 1040]), np.array([5]), period=1024)
    1
    >>> corrupt_counter(np.array([1020, 1030]), np.array([5, 1000]), period=1024) is None
    True
    """
    seq = np.concatenate((prev, u)) if len(prev) else u
    bad = np.flatnonzero(seq[2:] - seq[:-2] >= period)
    return None if not bad.size else int(bad[0]) + 1 - len(prev)


def note_corrupt(state: np.ndarray, u: np.ndarray, pos: np.ndarray, period: int,
                 slots: tuple[int, ...]) -> bool:
    """For a numpy decoder whose time counter is checked by :func:`corrupt_counter`: the
    block's unwrapped counter values ``u`` (at words ``pos`` of the payload) checked after
    the state's last two; True, with the corrupt value noted in the state, where one is.
    ``slots`` are the state's slots of the last two values, how many are set, the last
    value's word, the corrupt word (+ 1; 0: none) and the value after it (the kernels keep
    the same)."""
    s_u1, s_u2, s_nu, s_p1, s_bad, s_after = slots
    prev = state[[s_u2, s_u1]][2 - min(int(state[s_nu]), 2):]
    bad = corrupt_counter(u, prev, period)
    seq = np.concatenate((prev, u))
    if bad is not None:
        k = bad + prev.size
        state[s_u2], state[s_u1], state[s_after] = seq[k - 1], seq[k], seq[k + 1]
        state[s_bad] = (state[s_p1] if bad < 0 else pos[bad]) + 1
        return True
    if u.size:
        state[s_u2] = seq[-2] if seq.size > 1 else state[s_u1]
        state[s_u1] = seq[-1]
        state[s_nu] += u.size
        state[s_p1] = pos[-1]
    return False


def raise_noted(state: np.ndarray, slots: tuple[int, ...], bits: int, what: str) -> None:
    """:class:`CorruptTimeError` for the corrupt counter value a decoder noted in its
    ``state`` (``slots`` as :func:`note_corrupt`'s), if any; ``bits``: the counter's width
    in µs, ``what`` the word's name."""
    s_u1, s_u2, _, _, s_bad, s_after = slots
    if state[s_bad]:
        mask = (1 << bits) - 1
        times = (int(state[s_u2]) & mask, int(state[s_u1]) & mask, int(state[s_after]) & mask)
        raise CorruptTimeError(int(state[s_bad]) - 1, times, bits, what)


@lazy_njit(cache=True)
def take_time_high(state, slots, h, pos, bits, shift):
    """The numba kernels' TIME_HIGH word (Prophesee EVT 2.0, 2.1, 3.0): its value ``h``
    (the time bits from ``shift`` on of a ``bits``-bit µs counter), at word ``pos`` of the
    payload, taken as the decoder ``state``'s time base. ``slots``: the state's slots of
    the time high, the wrap offset and whether one was seen, then :func:`note_corrupt`'s.

    A value below the last by half its range or more is a rollover (adding ``2^bits`` µs
    to the wrap offset); then the unwrapped base is checked as :func:`note_corrupt` does.
    Returns True where it is corrupt (noted in the state; the kernel stops); the kernel
    takes its time high and wrap offset from the state after a call (the words are rare,
    so the state is their one copy). numba's disk cache of a caller is keyed on the
    caller's file only: after editing this, touch evt2.py, evt21.py and evt3.py."""
    s_th, s_ovf, s_seen, s_u1, s_u2, s_nu, s_p1, s_bad, s_after = slots
    th = state[s_th]
    if state[s_seen] and h < th and th - h >= np.int64(1) << (bits - shift - 1):
        state[s_ovf] += np.int64(1) << bits
    state[s_th] = h
    state[s_seen] = 1
    u = state[s_ovf] + (h << shift)
    if state[s_nu] >= 2 and u - state[s_u2] >= np.int64(1) << bits:
        state[s_bad] = state[s_p1] + 1
        state[s_after] = u
        return True
    state[s_u2] = state[s_u1]
    state[s_u1] = u
    state[s_nu] += 1
    state[s_p1] = pos
    return False


# ``open_blocks(path, sensor_size, block_bytes) -> (data offset, (height, width), blocks)``:
# parses a file's header and returns its payload as a lazy iterator of decoded blocks.
OpenBlocks = Callable[[Path, "tuple[int, int] | None", int],
                      "tuple[int, tuple[int, int], Iterator[Block]]"]


def position_in_block(start: int, end: int, left: int, n_block: int) -> int:
    """The byte where a chunk that ends inside a block ends: the block spans bytes
    ``[start, end)`` of its file and holds ``n_block`` events, ``left`` of them after the
    chunk; the position is in proportion to them (for a progress bar's total).

    Examples
    --------
    >>> position_in_block(1000, 2000, 250, 1000)
    1750
    """
    return int(end - min(1.0, left / max(n_block, 1)) * (end - start))


class Positioned:
    """Decoded blocks that also tell how far into their file they have read: its
    ``bytes_read`` (the end of the last block decoded) and ``file_bytes``. Chunks made from
    them carry both in their meta, for a progress bar where the header states no event
    count (EVT RAW files).

    Examples
    --------
    >>> blocks = Positioned(iter([(4, "a"), (8, "b")]), 8)
    >>> [b for b in blocks], blocks.bytes_read
    (['a', 'b'], 8)
    """

    def __init__(self, ends_and_blocks: Iterator[tuple[int, Block]], file_bytes: int):
        self._it = ends_and_blocks
        self.file_bytes = int(file_bytes)
        self.bytes_read = 0

    def __iter__(self) -> Positioned:
        return self

    def __next__(self) -> Block:
        end, blk = next(self._it)
        self.bytes_read = int(end)
        return blk


def read_text_header(path: Path, marker: bytes, *, end_line: bytes | None = None,
                     max_bytes: int = 1 << 20) -> tuple[list[str], int]:
    """Lines starting with ``marker`` at the top of ``path`` and the offset of the first
    byte after them.

    Parsing stops at the first line that does not start with ``marker``, right after a
    line equal to ``end_line`` (Prophesee's ``% end``), or at a "line" holding control
    bytes: binary data that happens to begin with the marker byte (1 file in 256 of RAW
    files without ``% end``; jAER's AEDAT2 headers have no terminator) is not text, and
    is not eaten as header.
    """
    lines: list[str] = []
    pos = 0
    with open(path, "rb") as fh:
        head = fh.read(max_bytes)
    while pos < len(head) and head.startswith(marker, pos):
        nl = head.find(b"\n", pos)
        if nl >= 0 and _CONTROL.search(head, pos, nl):
            break  # event data starting with the marker byte
        if nl < 0:
            if _CONTROL.search(head, pos):
                break
            raise FormatError(path, f"header line at byte {pos} has no end of line",
                              "the file is truncated or not a text-header format")
        line = head[pos:nl].rstrip(b"\r")
        lines.append(line.decode("latin-1"))
        pos = nl + 1
        if end_line is not None and line == end_line:
            break
    return lines, pos


# bytes no text header line holds (tab and carriage return allowed)
_CONTROL = re.compile(rb"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


def check_chunk_events(chunk_events: int) -> int:
    if int(chunk_events) <= 0:
        raise ParameterError(f"chunk_events must be a positive event count, got {chunk_events}")
    return int(chunk_events)


def rechunk(blocks: Iterator[Block], chunk_events: int, sensor_size: tuple[int, int],
            meta: dict, *, validate: bool = True) -> Iterator[EventArray]:
    """Regroup decoded blocks of any size into EventArrays of exactly ``chunk_events``
    events (the last one may be shorter). Chunks inside one block are views of it, so
    small chunks of large blocks cost no copying."""
    pending: deque[Block] = deque()
    n_pending = 0
    start = end = 0  # bytes of the file before and after the last block decoded
    for blk in blocks:
        if len(blk[2]) == 0:
            continue
        pending.append(blk)
        n_pending += len(blk[2])
        if isinstance(blocks, Positioned):
            start, end = end, blocks.bytes_read
        while n_pending >= chunk_events:
            n_pending -= chunk_events
            if end:
                # the chunk ends inside the last block (the whole payload, when decoded in
                # one pass)
                meta = {**meta, "file_bytes": blocks.file_bytes,
                        "bytes_read": position_in_block(start, end, n_pending, len(blk[2]))}
            yield _take(pending, chunk_events, sensor_size, meta, validate)
    if end:
        meta = {**meta, "bytes_read": end, "file_bytes": blocks.file_bytes}
    if n_pending:
        yield _take(pending, n_pending, sensor_size, meta, validate)


def _take(pending: deque, count: int, sensor_size, meta, validate) -> EventArray:
    parts = []
    need = count
    while need:
        blk = pending[0]
        m = len(blk[2])
        if m <= need:
            parts.append(pending.popleft())
            need -= m
        else:
            parts.append(tuple(c[:need] for c in blk))
            pending[0] = tuple(c[need:] for c in blk)
            need = 0
    cols = parts[0] if len(parts) == 1 else [np.concatenate([b[k] for b in parts])
                                             for k in range(4)]
    return _make(cols, 0, count, sensor_size, meta, validate)


def _valid_plain(x, y, t, width, height) -> bool:
    """:func:`_valid` by numpy (for at most ``PLAIN_WORDS`` events)."""
    return bool((x < width).all() and (y < height).all()
                and (t.size < 2 or (t[1:] >= t[:-1]).all()))


def _make(cols, a: int, b: int, sensor_size, meta, validate) -> EventArray:
    ev = EventArray(x=cols[0][a:b], y=cols[1][a:b], t=cols[2][a:b], p=cols[3][a:b],
                    sensor_size=sensor_size, meta=dict(meta), validate=False)
    valid = _valid_plain if len(ev) <= PLAIN_WORDS else _valid
    # (the fast check had left out the container's bound on times, past the year 5000: an
    # aedat4 time of 2^63 - 1 us, an aedat3 packet's overflow counter of 2^31 - 1, probe CG)
    if validate and len(ev) and (not valid(ev.x, ev.y, ev.t, sensor_size[1], sensor_size[0])
                                 or ev.t[-1] > NS_EPOCH_US):
        ev.check()  # raises the container's own error message
    return ev


@lazy_njit(cache=True)
def _valid(x, y, t, width, height):
    """One fused pass for what EventArray.check tests (sorted t, on-sensor x, y); the
    numpy version takes several passes and a temporary, a large share of decode time."""
    for i in range(t.shape[0]):
        if x[i] >= width or y[i] >= height:
            return False
        if i and t[i] < t[i - 1]:
            return False
    return True


def collect(blocks: Iterator[Block], sensor_size: tuple[int, int], meta: dict,
            t0: int | None = None, t1: int | None = None, *,
            validate: bool = True) -> EventArray:
    """Concatenate decoded blocks into one EventArray keeping ``t0 <= t < t1`` (µs).

    Stops reading once a block starts at or after ``t1`` (timestamps are sorted).
    """
    keep: list[Block] = []
    for blk in blocks:
        t = blk[2]
        if len(t) == 0:
            continue
        if t1 is not None and t[0] >= t1:
            break
        if t0 is not None or t1 is not None:
            lo = 0 if t0 is None else int(np.searchsorted(t, t0, side="left"))
            hi = len(t) if t1 is None else int(np.searchsorted(t, t1, side="left"))
            if lo >= hi:
                continue
            blk = tuple(c[lo:hi] for c in blk)
        keep.append(blk)
    if len(keep) == 1:
        cols = list(keep[0])
    elif keep:
        cols = [np.concatenate([b[k] for b in keep]) for k in range(4)]
    else:
        cols = [np.empty(0, np.uint16), np.empty(0, np.uint16), np.empty(0, np.int64),
                np.empty(0, np.uint8)]
    return _make(cols, 0, len(cols[2]), sensor_size, meta, validate)


def _open_payload(path: Path, fmt: str, word_bytes: int, open_blocks: OpenBlocks,
                  sensor_size: tuple[int, int] | None, block_bytes: int
                  ) -> tuple[tuple[int, int], dict, Iterator[Block]]:
    offset, size, blocks = open_blocks(path, sensor_size, block_bytes)
    trailing_partial(path, offset, word_bytes)
    return size, {"source": str(path), "format": fmt}, blocks


def read_file(path: str | Path, fmt: str, word_bytes: int, open_blocks: OpenBlocks,
              t0: int | None = None, t1: int | None = None, *,
              sensor_size: tuple[int, int] | None = None, validate: bool = True,
              block_bytes: int = BLOCK_BYTES) -> EventArray:
    """The ``read`` of a fixed-word binary format: header, truncation check, then the
    blocks of ``open_blocks`` collected with ``t0 <= t < t1`` (µs); meta ``format=fmt``."""
    path = Path(path)
    size, meta, blocks = _open_payload(path, fmt, word_bytes, open_blocks, sensor_size,
                                       block_bytes)
    return collect(blocks, size, meta, t0, t1, validate=validate)


def iter_file(path: str | Path, chunk_events: int, fmt: str, word_bytes: int,
              open_blocks: OpenBlocks, *, sensor_size: tuple[int, int] | None = None,
              validate: bool = True, block_bytes: int = BLOCK_BYTES) -> Iterator[EventArray]:
    """The ``iter_chunks`` of a fixed-word binary format: as :func:`read_file`, streamed in
    EventArrays of ``chunk_events`` events."""
    chunk_events = check_chunk_events(chunk_events)
    path = Path(path)
    size, meta, blocks = _open_payload(path, fmt, word_bytes, open_blocks, sensor_size,
                                       block_bytes)
    yield from rechunk(blocks, chunk_events, size, meta, validate=validate)


def iter_blocks(path: Path, offset: int, block_bytes: int, word_bytes: int
                ) -> Iterator[tuple[int, bytes]]:
    """``(file offset, bytes)`` blocks from ``offset`` on, each a multiple of
    ``word_bytes`` long; a trailing partial word raises FormatError (truncated file)."""
    block_bytes = max(int(block_bytes) - int(block_bytes) % word_bytes, word_bytes)
    with open(path, "rb") as fh:
        fh.seek(offset)
        pos = offset
        while True:
            buf = fh.read(block_bytes)
            if not buf:
                return
            if len(buf) % word_bytes:
                extra = fh.read(word_bytes - len(buf) % word_bytes)
                buf += extra
                if len(buf) % word_bytes:
                    _refuse_second_header(path, pos)
                    cut = len(buf) - len(buf) % word_bytes
                    raise FormatError(
                        path, f"truncated: {len(buf) % word_bytes} stray byte(s) at byte offset "
                        f"{pos + cut}, where a {word_bytes}-byte word was expected",
                        _trim_hint(pos + cut))
            yield pos, buf
            pos += len(buf)


def geometry_from_header(lines: list[str], path: Path, default: tuple[int, int] | None
                         ) -> tuple[int, int]:
    """(height, width) from Prophesee header lines (``% geometry WxH``, ``% Width``,
    ``% Height``, ``% format EVT3;height=..;width=..``); lines that state different sizes
    are refused (one silently won, probe AS).

    Examples
    --------
    >>> geometry_from_header(["% format EVT3;height=480;width=640", "% geometry 640x480"],
    ...                      Path("a.raw"), None)
    (480, 640)
    """
    stated: dict[str, tuple[int | None, int | None]] = {}
    for line in lines:
        body = line.lstrip("%").strip()
        key, _, val = body.partition(" ")
        key = key.lower()
        try:
            if key == "geometry":
                w, h = val.strip().lower().split("x")
                stated[line] = (int(w), int(h))
            elif key in ("width", "height"):
                stated[line] = (int(val), None) if key == "width" else (None, int(val))
            elif key == "format" and ";" in val:
                items = dict(item.partition("=")[::2] for item in val.split(";")[1:])
                items = {k.strip(): v for k, v in items.items()}
                stated[line] = (int(items["width"]) if "width" in items else None,
                                int(items["height"]) if "height" in items else None)
        except ValueError as exc:
            raise FormatError(path, f"bad header line '{line}': {exc}") from None
    widths = {w for w, _ in stated.values() if w is not None}
    heights = {h for _, h in stated.values() if h is not None}
    if len(widths) > 1 or len(heights) > 1:
        said = "; ".join(f"'{ln.strip()}'" for ln, (w, h) in stated.items()
                         if w is not None or h is not None)
        raise FormatError(path, f"the header states different sensor sizes: {said}",
                          "give the true one (--sensor-size H W, or sensor_size=(H, W))")
    if not widths or not heights:
        if default is None:
            raise FormatError(path, "the header gives no sensor geometry",
                              SENSOR_SIZE_HINT)
        return default
    return check_sensor_size(path, (heights.pop(), widths.pop()), "header geometry")


def first_chunk(path, events: EventArray | Iterable[EventArray]
                ) -> tuple[EventArray, Iterator[EventArray]]:
    """A streaming writer's first chunk (the first holding events, else the last empty
    one: the sensor and the time base its header states) and the chunks after it;
    ``events`` is one EventArray or chunks of one. FormatError where there is no chunk.

    Examples
    --------
    >>> ev = EventArray(x=[1, 2], y=[0, 0], t=[5, 9], p=[1, 0], sensor_size=(2, 4))
    >>> first, rest = first_chunk("out.dat", iter([ev[:0], ev[:1], ev[1:]]))
    >>> first.t.tolist(), [c.t.tolist() for c in rest]
    ([5], [[9]])
    """
    chunks = iter([events]) if isinstance(events, EventArray) else iter(events)
    first = next(chunks, None)
    if first is None:
        raise FormatError(path, "no events to write (not even an empty chunk to say the "
                          "sensor size)")
    while not len(first):
        more = next(chunks, None)
        if more is None:
            break
        same_sensor(more, first)
        first = more
    return first, chunks


def checked_chunks(first: EventArray, rest: Iterator[EventArray], fmt: str, height: int,
                   width: int, hint: str | None = None,
                   u32_base: int | None = None) -> Iterator[EventArray]:
    """The chunks of a streaming writer holding events (``first`` and ``rest``, from
    :func:`first_chunk`), each checked as a whole array would be: of ``first``'s sensor
    (:func:`same_sensor`), writable and after the chunk before (:func:`check_writable`)
    and, for a format storing times modulo 2^32 µs from ``u32_base``, restorable
    (:func:`check_u32_times`).

    Examples
    --------
    >>> ev = EventArray(x=[1, 2], y=[0, 0], t=[5, 9], p=[1, 0], sensor_size=(2, 4))
    >>> [c.t.tolist() for c in checked_chunks(ev[:1], iter([ev[:0], ev[1:]]), "DAT", 8, 8)]
    [[5], [9]]
    """
    before, seen = None, 0
    for chunk in itertools.chain([first], rest):
        same_sensor(chunk, first)
        if not len(chunk):
            continue
        check_writable(chunk, fmt, height, width, hint=hint,
                       after=None if before is None else int(before[-1]), seen=seen)
        if u32_base is not None:
            check_u32_times(chunk, fmt, u32_base, before, seen)
        # the last two times written (a chunk of one event, and the one before it)
        tail = np.asarray(chunk.t[-2:], np.int64)
        before = tail if before is None or tail.size == 2 else \
            np.concatenate([before, tail])[-2:]
        seen += len(chunk)
        yield chunk


def same_sensor(chunk: EventArray, first: EventArray) -> None:
    """FormatError unless ``chunk`` (empty or not) is of ``first``'s sensor: one file holds
    one sensor's events (an empty chunk of another had passed, probe DM)."""
    if chunk.sensor_size != first.sensor_size:
        raise FormatError(None, f"a chunk of events of sensor {chunk.sensor_size} after "
                          f"{first.sensor_size}: one file holds one sensor's")


def check_in_order(events: EventArray, fmt: str, after: int | None = None,
                   seen: int = 0) -> None:
    """FormatError unless ``events`` are in time order and, a chunk of a stream, start no
    earlier than ``after`` (µs), the last time written before them, ``seen`` events in
    (``fmt`` names the format in the message)."""
    try:
        events.check_order()
        check_follows(after, events, at=seen - 1)
    except UnsortedError as exc:
        raise FormatError(None, f"{fmt} stores times in order: {exc}") from None


def check_writable(events: EventArray, fmt: str, height: int, width: int,
                   hint: str | None = None, after: int | None = None,
                   seen: int = 0) -> None:
    """FormatError unless ``events`` fit a format that stores integer pixels of at most
    ``height`` rows and ``width`` columns (``fmt`` names it in the message, ``hint`` says
    what holds a larger sensor), in time order (:func:`check_in_order`, ``after`` and
    ``seen`` for a chunk of a stream): the formats store times as steps or modulo a
    counter, and an array built with ``validate=False`` out of order came back with other
    times (EVT 3.0: 10 us read as 16777226, probe DJ)."""
    check_in_order(events, fmt, after, seen)
    if events.x.dtype.kind == "f":
        raise FormatError(None, f"events have float (undistorted) coordinates; {fmt} stores "
                          "integer pixels")
    h, w = events.sensor_size
    if w > width or h > height:
        raise FormatError(None, f"sensor_size {events.sensor_size} exceeds {fmt}'s address "
                          f"range ({height} rows, {width} columns)", hint)


def u32_time_base(events: EventArray, fmt: str) -> int:
    """The µs a format that stores times modulo 2^32 µs writes ``events``' times from:
    the multiple of 2^32 µs at or below the first time (0 for a first time within
    ``[0, 2^32)``, -2^32 for one in ``[-2^32, 0)``); the writer keeps it in its header.
    Checked with :func:`check_u32_times` (``fmt`` names the format in its errors).

    Examples
    --------
    >>> ev = EventArray(x=[0], y=[0], t=[(1 << 32) + 5], p=[1], sensor_size=(1, 1))
    >>> u32_time_base(ev, "DAT") == 1 << 32
    True
    """
    first = int(events.t[0]) if len(events) else 0
    t_base = first - first % (1 << 32)
    check_u32_times(events, fmt, t_base)
    return t_base


def check_u32_times(events: EventArray, fmt: str, t_base: int = 0,
                    before: np.ndarray | None = None, seen: int = 0) -> None:
    """FormatError unless ``events``' times, less ``t_base`` µs, survive a format that
    stores them modulo 2^32 µs and is unwrapped on reading wherever the stored time drops
    by more than 2^31 µs: the first time within ``[0, 2^32)`` µs, no gap the reader
    cannot tell from a wrap (one of 2^31 µs, 35.8 min, or more may be), and no two
    consecutive gaps spanning 2^32 µs or more, which the reader takes for a corrupt time
    (:class:`CorruptTimeError`) (``fmt`` names the format in the message). A chunk of a
    stream: ``before``, the times (µs) of the last events written before it (up to two),
    and ``seen``, how many events were, which number its events in the message."""
    if not len(events):
        return
    lead = np.zeros(0, np.int64) if before is None else np.asarray(before, np.int64)[-2:]
    t = np.concatenate([lead, np.asarray(events.t, np.int64)]) - t_base
    first = seen - lead.size  # the number of t[0] in the stream
    if lead.size == 0 and (t[0] < 0 or t[0] >= 1 << 32):
        raise FormatError(None, f"first timestamp {int(t[0])} us is outside {fmt}'s u32 range",
                          "subtract a time offset first")
    raw = t & 0xFFFFFFFF
    wraps = (np.concatenate([[0], np.cumsum(np.diff(raw) < -(1 << 31))]) << 32) + (t[0] - raw[0])
    lost = np.flatnonzero(raw + wraps != t)
    if lost.size:
        k = int(lost[0])
        raise FormatError(None, f"events {first + k - 1} and {first + k} are "
                          f"{int(t[k] - t[k - 1])} us apart: "
                          f"{fmt} stores times modulo 2^32 us and cannot restore them across "
                          "that gap (gaps under 2^31 us, 35.8 min, are always restored)",
                          "write the parts before and after the gap to separate files, or "
                          "write .h5, whose times are 64-bit")
    # the readers take a time 2^32 us or more from both neighbours' for a corrupt one
    far = np.flatnonzero(t[2:] - t[:-2] >= 1 << 32)
    if far.size:
        k = int(far[0])
        raise FormatError(None, f"events {first + k} and {first + k + 2} are "
                          f"{int(t[k + 2] - t[k])} us apart "
                          f"with one event between: {fmt} stores times modulo 2^32 us, and "
                          "its readers take a time 2^32 us or more from both neighbours' for "
                          "a corrupt time field",
                          "write the parts before and after the gap to separate files, or "
                          "write .h5, whose times are 64-bit")


def header_bytes(lines: list[str]) -> bytes:
    return "".join(line + "\n" for line in lines).encode("latin-1")


def trailing_partial(path: Path, offset: int, word_bytes: int) -> None:
    """Raise FormatError if the payload after ``offset`` is not whole words: a second
    recording's header inside it is named as such, else the file was cut short."""
    size = path.stat().st_size
    if (size - offset) % word_bytes:
        _refuse_second_header(path, offset)
        cut = size - (size - offset) % word_bytes
        raise FormatError(path, f"truncated: {(size - offset) % word_bytes} stray byte(s) at "
                          f"byte offset {cut}, where a {word_bytes}-byte word was expected",
                          _trim_hint(cut))


#: A header line of a Prophesee / DAT recording: what a second recording joined to the first
#: begins with (a bare "% " in binary words is chance, once in some 64 kB; with one of
#: these words after it, once in some 2^40 bytes).
SECOND_HEADER = re.compile(rb"(% (?:date|evt|format|geometry|Date|Version|Height|Width) "
                           rb"[^\n]{0,60})\n")


def _refuse_second_header(path: Path, offset: int) -> None:
    """FormatError where the payload after ``offset`` holds a header line of its own (two
    recordings joined: the truncation advice led to a second error, unsorted times, as
    the second header was read as events; probe CF)."""
    import mmap

    with open(path, "rb") as fh:
        try:
            mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        except ValueError:  # an empty file
            return
        with mm:
            m = SECOND_HEADER.search(mm, offset)
            if m is None:
                return
            where, line = m.start(1), m.group(1).decode("latin-1", "replace")
    raise FormatError(path, f"a header line ({line[:40]!r}) at byte offset {where}, inside the "
                      "events: two recordings joined?",
                      f"the first recording's events are readable from a copy trimmed to "
                      f"{where} bytes: head -c {where} FILE > FIRST")


def _trim_hint(whole: int) -> str:
    """How to read the whole words of a file cut short at byte ``whole`` (the raw and
    dat refusals said only that it was cut, probe BL)."""
    return (f"the file was cut short, or bytes were appended to it; the events before are "
            f"readable from a copy trimmed "
            f"to {whole} bytes: head -c {whole} FILE > TRIMMED")
