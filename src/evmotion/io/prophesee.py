"""What the Prophesee RAW formats (EVT 2.0, EVT 2.1, EVT 3.0) share: the ``%`` text header,
sniffing, the time offset evmotion stores when timestamps exceed the counter range."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Iterator
from functools import partial
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError
from evmotion.events import EventArray, concatenate
from evmotion.io import binary
from evmotion.io.base import FormatSpec
from evmotion.io.binary import geometry_from_header, read_text_header
from evmotion.utils import atomic_path

# Header key evmotion writes when the first timestamp does not fit the format's counter;
# readers add it to every timestamp. Other tools ignore unknown header keys.
OFFSET_KEY = "evmotion_time_offset_us"
# Largest offset accepted either way (36,000 years): offset plus counter stays far inside
# int64. Negative offsets are the writers' for recordings whose times start below 0.
MAX_TIME_OFFSET_US = 1 << 60


def format_name(version: str) -> str:
    """The ``format`` header key's name of EVT ``version``: "2.0" -> "EVT2", "2.1" ->
    "EVT21", "3.0" -> "EVT3"."""
    major, _, minor = version.partition(".")
    return f"EVT{major}" + ("" if minor in ("", "0") else minor)


def sniff_raw(head: bytes, version: str) -> bool:
    """True if ``head`` is a Prophesee RAW header announcing EVT ``version`` ("2.0", "2.1"
    or "3.0")."""
    if not head.startswith(b"%"):
        return False
    text = head.split(b"\n% end", 1)[0]
    evt = f"% evt {version}".encode()
    fmt = format_name(version).encode()
    for line in text.split(b"\n"):
        line = line.strip()
        if line == evt:
            return True
        if line.startswith(b"% format "):
            return line[len(b"% format "):].split(b";")[0].strip().upper() == fmt
    return False


def parse_raw_header(path: Path, sensor_size: tuple[int, int] | None,
                     version: str | None = None
                     ) -> tuple[list[str], int, tuple[int, int], int]:
    """(header lines, data offset, (height, width), time offset µs) of a RAW file.

    With ``version`` ("2.0"/"2.1"/"3.0"), a header declaring another encoding raises
    FormatError; EVT 2.1 and 3.0 must be declared, EVT 2.0 may be implicit (early Gen3
    files). A file without a header (a stream recorded from the sensor's interface) reads
    as ``version``'s words from byte 0, given ``sensor_size``.
    """
    lines, offset = read_text_header(path, b"%", end_line=b"% end")
    if not lines:
        if version is None:
            raise FormatError(path, "no '%' header at byte 0", "not a Prophesee RAW file")
        if sensor_size is None:
            # (the format given as the registry's error asked still ended in "no '%'
            # header": a dead end)
            raise FormatError(path, f"no '%' header at byte 0: a header-less EVT {version} "
                              "stream states no sensor size", "give --sensor-size H W "
                              "(sensor_size= in Python): 720 1280 for a Gen4 or IMX636 "
                              "sensor, 480 640 for a Gen3")
        return [], 0, tuple(sensor_size), 0
    if version is not None:
        _check_version(path, header_dict(lines), version)
    size = sensor_size if sensor_size is not None else geometry_from_header(
        lines, path, default=plugin_geometry(lines))
    return lines, offset, size, header_time_offset(path, lines)


def header_time_offset(path: Path, lines: list[str]) -> int:
    """The µs that evmotion's writer took off the times and wrote as :data:`OFFSET_KEY`
    in the ``%`` header ``lines`` (0 without that line)."""
    t_offset = 0
    for line in lines:
        body = line.lstrip("%").strip()
        if body.startswith(OFFSET_KEY):
            try:
                t_offset = int(body.split()[1])
            except (IndexError, ValueError):
                raise FormatError(path, f"bad header line '{line}'") from None
            if abs(t_offset) > MAX_TIME_OFFSET_US:
                raise FormatError(path, f"header field '{OFFSET_KEY}' is {t_offset} us, "
                                  f"outside +-{MAX_TIME_OFFSET_US} (2^60 us)")
    return t_offset


def _check_version(path: Path, head: dict[str, str], version: str) -> None:
    evt = head.get("evt")
    fmt = head.get("format", "").split(";")[0].strip().upper()
    want = format_name(version)
    if evt is not None and evt != version:
        known = evt in ("2.0", "2.1", "3.0")
        raise FormatError(path, f"header field 'evt' is '{evt}', expected '{version}'",
                          "use the reader for that encoding or let evmotion detect it" if known
                          else "evmotion reads EVT 2.0, 2.1 and 3.0")
    if fmt and fmt != want:
        raise FormatError(path, f"header field 'format' is '{fmt}', expected '{want}'")
    if evt is None and not fmt and version != "2.0":
        raise FormatError(path, f"the '%' header does not declare 'evt {version}'",
                          "not an EVT 3.0 RAW file (a DAT file?)")


# Sensor of the camera plugins whose RAW headers predate the ``geometry`` key.
_PLUGIN_SIZES = (("gen31", (480, 640)), ("gen3", (480, 640)), ("gen41", (720, 1280)),
                 ("gen4", (720, 1280)), ("imx636", (720, 1280)))


def plugin_geometry(lines: list[str]) -> tuple[int, int] | None:
    """(height, width) implied by the ``plugin_name`` header key, if known."""
    plugin = header_dict(lines).get("plugin_name", "").lower()
    for key, size in _PLUGIN_SIZES:
        if key in plugin:
            return size
    return None


def header_dict(lines: list[str]) -> dict[str, str]:
    out = {}
    for line in lines:
        body = line.lstrip("%").strip()
        if body and body != "end":
            key, _, val = body.partition(" ")
            out[key] = val.strip()
    return out


def open_raw(path: Path, sensor_size: tuple[int, int] | None, block_bytes: int, *,
             version: str, word: str, decode_words: Callable, new_state: Callable,
             whole_bytes: int | None = None
             ) -> tuple[int, tuple[int, int], Iterator[binary.Block]]:
    """:data:`binary.OpenBlocks` of an EVT ``version`` file of ``word`` (numpy dtype)
    words: data offset, sensor size and the lazily decoded blocks (see :func:`raw_blocks`),
    times offset by the header's :data:`OFFSET_KEY`."""
    _, offset, size, t_offset = parse_raw_header(path, sensor_size, version)
    small = binary.small_payload(path, offset, np.dtype(word).itemsize)
    return offset, size, raw_blocks(path, offset, t_offset, block_bytes, word,
                                    partial(decode_words, plain=small), new_state(),
                                    whole_bytes)


def raw_blocks(path: Path, offset: int, t_offset: int, block_bytes: int, word: str,
               decode_words: Callable, state: np.ndarray, whole_bytes: int | None = None
               ) -> binary.Positioned:
    """Decoded ``(x, y, t, p)`` blocks of the payload from ``offset`` on, as
    :class:`binary.Positioned`; ``state`` is the decoder state carried from block to block. A payload of at most ``whole_bytes`` is
    decoded in one pass (no per-block buffers to concatenate)."""
    file_bytes = path.stat().st_size
    if whole_bytes is not None and file_bytes - offset <= whole_bytes:
        # lazily, as the blocks: a truncated file is refused by name before this reads it
        payload = ((file_bytes, np.fromfile(path, np.uint8, offset=offset).view(word))
                   for _ in range(1))
    else:
        payload = ((pos + len(buf), np.frombuffer(buf, word)) for pos, buf in
                   binary.iter_blocks(path, offset, block_bytes, np.dtype(word).itemsize))
    return binary.Positioned(_decoded(path, offset, payload, decode_words, state, t_offset),
                             file_bytes)


def _decoded(path: Path, offset: int, payload, decode_words: Callable, state: np.ndarray,
             t_offset: int):
    for end, words in payload:
        try:
            x, y, t, p = decode_words(words, state)
        except binary.CorruptTimeError as exc:
            # (the word may lie in an earlier block: its index counts from the payload's start)
            raise exc.at(path, f"TIME_HIGH word at byte offset "
                               f"{offset + exc.pos * words.itemsize}") from None
        if t_offset:
            t += t_offset
        yield end, (x, y, t, p)


def write_raw(path: str | Path, events: EventArray | Iterable[EventArray], *, version: str,
              wrap_us: int, encode: Callable, word: str, header: dict | None = None,
              lead_words: int | None = None) -> None:
    """Write an EVT ``version`` RAW file atomically: the ``%`` header (with ``header``'s
    extra keys and, past the ``wrap_us`` counter range, :data:`OFFSET_KEY`), then
    ``encode(events, t_base)`` as ``word`` words. With ``lead_words`` (the words ``encode``
    gives a lone first event: its state words and itself), ``events`` may be chunks in
    time order, streamed in bounded memory: each part is encoded after the previous
    part's last event, whose ``lead_words`` are dropped, and the parts are cut where the
    time changes, so the words continue as one whole encoding's (the same bytes)."""
    if not isinstance(events, EventArray) and lead_words is None:
        raise FormatError(path, f"EVT {version} is written from one EventArray, not chunks")
    first, chunks = binary.first_chunk(path, events)
    binary.check_writable(first[:0], f"EVT {version}", 2048, 2048)  # the header's sensor
    h, w = first.sensor_size
    t_base = int(first.t[0]) - int(first.t[0]) % wrap_us if len(first) else 0
    lines = [f"% evt {version}", f"% format {format_name(version)};height={h};width={w}",
             f"% geometry {w}x{h}", "% integrator_name evmotion"]
    if t_base:
        lines.append(f"% {OFFSET_KEY} {t_base}")
    for key, val in (header or {}).items():
        lines.append(f"% {key} {val}")
    lines.append("% end")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(binary.header_bytes(lines))
        last = held = None
        seen = 0
        for chunk in itertools.chain([first], chunks):
            binary.same_sensor(chunk, first)
            if not len(chunk):
                continue
            binary.check_writable(chunk, f"EVT {version}", 2048, 2048,
                                  after=None if held is None else int(held.t[-1]), seen=seen)
            seen += len(chunk)
            if held is not None:
                chunk = concatenate([held, chunk], validate=False)
            # the events at the chunk's last time wait for the next chunk: with its events
            # of that time they may make one vector word (one EventArray without
            # lead_words: encoded whole)
            cut = 0 if lead_words is None else int(np.searchsorted(chunk.t, chunk.t[-1],
                                                                   side="left"))
            if cut:
                fh.write(_encoded(chunk[:cut], last, t_base, encode, lead_words, word))
                last = chunk[cut - 1:cut]
            held = chunk[cut:]
        if held is not None:
            fh.write(_encoded(held, last, t_base, encode, lead_words, word))


def _encoded(events: EventArray, last: EventArray | None, t_base: int, encode: Callable,
             lead_words: int | None, word: str) -> bytes:
    """``encode``'s words for ``events`` continuing after the event ``last`` (None: the
    file's first), as bytes."""
    if last is None:
        words = encode(events, t_base)
    else:
        words = encode(concatenate([last, events], validate=False), t_base)[lead_words:]
    return words.astype(word).tobytes()


def describe_raw(path: str | Path, fmt: str, word_bytes: int) -> dict:
    """Header fields, geometry and payload size of a RAW file (``sensor_size`` None when
    the header does not parse as ``fmt``'s)."""
    path = Path(path)
    try:
        lines, offset, size, _ = parse_raw_header(path, None)
    except FormatError:
        lines, offset = read_text_header(path, b"%", end_line=b"% end")
        size = None
    return {"format": fmt, "sensor_size": size, "header": header_dict(lines),
            "data_offset": offset, "n_words": (path.stat().st_size - offset) // word_bytes,
            "frames": 0, "imu": 0}


def _sniff_version(path: Path, head: bytes, *, version: str) -> bool:
    return sniff_raw(head, version)


def raw_describe(name: str, word_bytes: int) -> Callable[[str | Path], dict]:
    """The ``describe`` of RAW format ``name``: header fields, geometry and payload size
    (:func:`describe_raw`)."""
    return partial(describe_raw, fmt=name, word_bytes=word_bytes)


def raw_format(name: str, version: str, describe: Callable, read: Callable,
               iter_chunks: Callable, write: Callable) -> FormatSpec:
    """The :class:`FormatSpec` of RAW format ``name`` (EVT ``version``), detected by its
    ``%`` header."""
    return FormatSpec(name=name, extensions=(".raw",),
                      sniff=partial(_sniff_version, version=version), read=read,
                      iter_chunks=iter_chunks, write=write, describe=describe)
