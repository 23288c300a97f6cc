"""iniVation AEDAT 4.0 files (DV software): events, frames and IMU samples.

Layout: ``#!AER-DAT4.0\\r\\n``, an int32 size and an ``IOHE`` flatbuffer (compression,
position of the packet index, infoNode XML listing the streams), then packets of
``int32 stream id, int32 size, payload``. A payload, once decompressed (LZ4 frame or
Zstandard), is a size-prefixed flatbuffer: ``EVTS`` (structs of int64 t µs, int16 x, y,
bool polarity), ``FRME`` (one image per packet), ``IMUS`` (tables of accelerometer in g,
gyroscope in °/s, temperature in °C). Flatbuffers are read with the small table reader
below; no flatbuffers package is needed.
"""

from __future__ import annotations

import itertools
import struct
import warnings
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evmotion.errors import EvmotionWarning, FormatError, ParameterError
from evmotion.events import EventArray
from evmotion.io import binary
from evmotion.io.base import FormatSpec
from evmotion.io.frames import Frames
from evmotion.io.guard import SENSOR_SIZE_HINT, check_sensor_size
from evmotion.utils import atomic_path

__all__ = ["read", "iter_chunks", "write", "read_frames", "read_imu", "describe",
           "Frames", "ImuSamples", "FORMAT"]

MAGIC = b"#!AER-DAT4.0\r\n"
G = 9.80665
COMPRESSION = {0: "none", 1: "lz4", 2: "lz4_high", 3: "zstd", 4: "zstd_high"}
# Largest decompressed packet accepted (DV writes packets of at most a few MiB).
MAX_PACKET_BYTES = 1 << 28
EVENT_DTYPE = np.dtype({"names": ["t", "x", "y", "on"],
                        "formats": ["<i8", "<i2", "<i2", "u1"],
                        "offsets": [0, 8, 10, 12], "itemsize": 16})


@dataclass(frozen=True)
class ImuSamples:
    """IMU samples: ``t`` int64 µs, ``accel`` (N, 3) m/s², ``gyro`` (N, 3) rad/s,
    ``temperature`` (N,) °C, ``mag`` (N, 3) µT, in the IMU's axes as DV reports them."""

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    temperature: np.ndarray
    mag: np.ndarray


# --------------------------------------------------------------- flatbuffer reading
class _Table:
    """A flatbuffer table at ``pos`` in ``buf``; fields by index, defaults when absent."""

    __slots__ = ("buf", "pos", "offs")

    def __init__(self, buf: bytes, pos: int):
        self.buf = buf
        self.pos = pos
        vt = pos - struct.unpack_from("<i", buf, pos)[0]
        vsize = struct.unpack_from("<H", buf, vt)[0]
        self.offs = struct.unpack_from(f"<{(vsize - 4) // 2}H", buf, vt + 4)

    def _off(self, i: int) -> int:
        return self.offs[i] if i < len(self.offs) else 0

    def scalar(self, i: int, fmt: str, default=0):
        o = self._off(i)
        return default if o == 0 else struct.unpack_from(fmt, self.buf, self.pos + o)[0]

    def _target(self, i: int) -> int | None:
        o = self._off(i)
        if o == 0:
            return None
        at = self.pos + o
        return at + struct.unpack_from("<I", self.buf, at)[0]

    def string(self, i: int) -> str:
        at = self._target(i)
        if at is None:
            return ""
        n = struct.unpack_from("<I", self.buf, at)[0]
        return self.buf[at + 4:at + 4 + n].decode("utf-8", "replace")

    def vector(self, i: int) -> tuple[int, int]:
        """(element start, count) of a vector field, (0, 0) when absent."""
        at = self._target(i)
        if at is None:
            return 0, 0
        return at + 4, struct.unpack_from("<I", self.buf, at)[0]

    def tables(self, i: int) -> Iterator[_Table]:
        start, n = self.vector(i)
        for k in range(n):
            at = start + 4 * k
            yield _Table(self.buf, at + struct.unpack_from("<I", self.buf, at)[0])


def _root(buf: bytes, ident: bytes | None, path: Path, offset: int) -> _Table:
    if len(buf) < 8:
        raise FormatError(path, f"flatbuffer at byte offset {offset} is {len(buf)} bytes long")
    if ident is not None and buf[4:8] != ident:
        raise FormatError(path, f"flatbuffer identifier at byte offset {offset + 4} is "
                          f"{bytes(buf[4:8])!r}, expected {ident!r}")
    return _Table(buf, struct.unpack_from("<I", buf, 0)[0])


# --------------------------------------------------------------- file structure
@dataclass(frozen=True)
class _Stream:
    id: int
    type: str
    name: str
    size: tuple[int, int] | None
    ts_offset: int


def _parse_header(path: Path):
    with open(path, "rb") as fh:
        head = fh.read(len(MAGIC) + 4)
        if not head.startswith(MAGIC):
            raise FormatError(path, f"bad magic at byte offset 0: {head[:14]!r}, expected "
                              f"{MAGIC!r}", "not an AEDAT 4.0 file")
        if len(head) < len(MAGIC) + 4:
            raise FormatError(path, f"truncated: the IOHeader size at byte offset {len(MAGIC)} "
                              "is missing")
        size = struct.unpack_from("<i", head, len(MAGIC))[0]
        buf = fh.read(size) if size > 0 else b""
    hpos = len(MAGIC) + 4
    if size <= 0 or len(buf) != size:
        raise FormatError(path, f"field 'IOHeader size' at byte offset {len(MAGIC)} is {size} "
                          f"but {len(buf)} bytes follow", "the file is truncated or corrupt")
    try:
        tab = _root(buf, b"IOHE", path, hpos)
        compression = tab.scalar(0, "<i", 0)
        table_pos = tab.scalar(1, "<q", -1)
        info = tab.string(2)
    except struct.error:
        raise FormatError(path, f"corrupt IOHeader flatbuffer at byte offset {hpos}") from None
    if compression not in COMPRESSION:
        raise FormatError(path, f"field 'compression' of the IOHeader is {compression}, "
                          f"expected one of {sorted(COMPRESSION)}")
    streams = _parse_info(info, path)
    return compression, table_pos, streams, hpos + size


def _parse_info(info: str, path: Path) -> dict[int, _Stream]:
    try:
        root = ET.fromstring(info)
    except ET.ParseError as exc:
        raise FormatError(path, f"infoNode XML of the IOHeader is malformed: {exc}") from None
    out = {}
    for node in root.iter("node"):
        if not node.get("name", "").isdigit():
            continue
        attrs = {a.get("key"): a.text for a in node.findall("attr")}
        if "typeIdentifier" not in attrs:
            continue
        info_attrs = {}
        for sub in node.findall("node"):
            if sub.get("name") == "info":
                info_attrs = {a.get("key"): a.text for a in sub.findall("attr")}
        size = None
        sid = int(node.get("name"))
        if "sizeX" in info_attrs and "sizeY" in info_attrs:
            size = check_sensor_size(path, (_int_attr(path, sid, "sizeY", info_attrs["sizeY"]),
                                            _int_attr(path, sid, "sizeX", info_attrs["sizeX"])),
                                     f"stream {sid} sizeY, sizeX")
        out[sid] = _Stream(sid, attrs["typeIdentifier"], attrs.get("originalOutputName", ""),
                           size, _int_attr(path, sid, "tsOffset", info_attrs.get("tsOffset")))
    return out


def _int_attr(path: Path, sid: int, key: str, text: str | None) -> int:
    """An integer attribute of the infoNode XML (absent or empty: 0)."""
    if text is None or not text.strip():
        return 0
    try:
        return int(text)
    except ValueError:
        raise FormatError(path, f"infoNode attribute '{key}' of stream {sid} is "
                          f"{text.strip()[:40]!r}, expected an integer") from None


def _packet_limit(n: int) -> int:
    """Most bytes a compressed packet of ``n`` bytes may expand to: LZ4 cannot exceed
    255:1; zstd can, but DV's packets stay far below this, and a corrupt frame header
    (which declares the content size) must not make the reader allocate gigabytes."""
    return min(255 * n + (1 << 16), MAX_PACKET_BYTES)


def _decompressor(compression: int):
    if compression in (1, 2):
        import lz4.frame

        def lz4_packet(b: bytes) -> bytes:
            d = lz4.frame.LZ4FrameDecompressor()
            out = d.decompress(b, max_length=_packet_limit(len(b)))
            if not d.eof:
                raise ValueError(f"expands past {_packet_limit(len(b))} bytes or is cut short")
            return out

        return lz4_packet
    if compression in (3, 4):
        import zstandard

        dctx = zstandard.ZstdDecompressor()
        return lambda b: dctx.decompress(b, max_output_size=_packet_limit(len(b)))
    return bytes


def _packets(path: Path, want: set[int] | None = None) -> Iterator[tuple[int, bytes, int]]:
    """(stream id, flatbuffer bytes without size prefix, file offset) per packet."""
    compression, table_pos, streams, pos = _parse_header(path)
    decompress = _decompressor(compression)
    end = path.stat().st_size
    if table_pos >= 0:
        end = min(end, table_pos)
    undeclared: dict[int, int] = {}
    with open(path, "rb") as fh:
        fh.seek(pos)
        while pos < end:
            head = fh.read(8)
            if len(head) < 8:
                raise FormatError(path, f"truncated: packet header at byte offset {pos} has "
                                  f"{len(head)} of 8 bytes")
            sid, size = struct.unpack("<ii", head)
            if size < 0 or pos + 8 + size > path.stat().st_size:
                raise FormatError(path, f"truncated or corrupt: field 'packet size' at byte "
                                  f"offset {pos + 4} is {size}, beyond the end of the file")
            if sid not in streams:
                undeclared[sid] = undeclared.get(sid, 0) + 1
            if want is not None and sid not in want:
                fh.seek(size, 1)
                pos += 8 + size
                continue
            raw = fh.read(size)
            try:
                buf = decompress(raw)
            except Exception as exc:
                raise FormatError(path, f"packet at byte offset {pos}: {COMPRESSION[compression]}"
                                  f" decompression failed ({exc})") from None
            yield sid, memoryview(buf)[4:].tobytes(), pos
            pos += 8 + size
    if table_pos >= 0:
        _warn_after_table(path, table_pos, compression)
    if undeclared:
        # a stream id the infoNode does not list: a corrupt packet header, most likely
        warnings.warn(EvmotionWarning(
            f"{path}: skipped {sum(undeclared.values())} packet(s) of stream id(s) "
            f"{sorted(undeclared)} that the header does not declare (declared: "
            f"{sorted(streams)}): a corrupt packet header? Their data is not read"),
            stacklevel=4)


def _warn_after_table(path: Path, table_pos: int, compression: int) -> None:
    """Say where bytes follow the file's data table (a compressed frame at the end of the
    file): appended to the recording, they were read past without a word, where the other
    formats refuse trailing bytes (probe CF: 700 bytes)."""
    with open(path, "rb") as fh:
        fh.seek(table_pos)
        data = fh.read()
    try:
        if compression in (1, 2):
            import lz4.frame

            d = lz4.frame.LZ4FrameDecompressor()
            d.decompress(data, max_length=_packet_limit(len(data)))
            extra = len(d.unused_data or b"") if d.eof else 0
        elif compression in (3, 4):
            import zstandard

            d = zstandard.ZstdDecompressor().decompressobj()
            d.decompress(data)
            extra = len(d.unused_data or b"")
        else:
            return  # an uncompressed table states no end of its own
    except Exception:  # a table that does not decode: the events are read all the same
        return
    if extra:
        warnings.warn(EvmotionWarning(
            f"{path}: {extra:,} byte(s) follow the file's data table (from byte offset "
            f"{len(data) - extra + table_pos}): not part of the recording, they are not "
            "read (appended data, or two files joined?)"), stacklevel=5)


def _stream_of(path: Path, streams: dict[int, _Stream], type_id: str,
               stream: int | None) -> _Stream | None:
    if stream is not None:
        if stream not in streams or streams[stream].type != type_id:
            raise ParameterError(f"{path}: stream {stream} is not a {type_id} stream "
                                 f"(streams: {[(s.id, s.type) for s in streams.values()]})")
        return streams[stream]
    for s in streams.values():
        if s.type == type_id:
            return s
    return None


def _event_blocks(path: Path, sid: int) -> Iterator[binary.Block]:
    for _, buf, pos in _packets(path, {sid}):
        try:
            tab = _root(buf, b"EVTS", path, pos + 8)
            start, n = tab.vector(0)
            ev = np.frombuffer(buf, EVENT_DTYPE, count=n, offset=start)
        except (struct.error, ValueError):
            raise FormatError(path, f"corrupt EVTS packet at byte offset {pos}") from None
        for name in ("x", "y"):
            # (an int16 -3 was said as 65533 "outside the sensor", probe BL)
            if n and ev[name].min() < 0:
                k = int(np.argmax(ev[name] < 0))
                raise FormatError(path, f"event {k} of the EVTS packet at byte offset {pos} "
                                  f"has {name}={int(ev[name][k])}: pixel coordinates start "
                                  "at 0 (a corrupt packet?)")
        yield (ev["x"].astype(np.uint16), ev["y"].astype(np.uint16),
               np.ascontiguousarray(ev["t"]), ev["on"].astype(np.uint8))


def _event_stream(path: Path, stream: int | None, sensor_size):
    _, _, streams, _ = _parse_header(path)
    s = _stream_of(path, streams, "EVTS", stream)
    if s is None:
        raise FormatError(path, "the file has no event (EVTS) stream",
                          f"streams: {[(v.id, v.type) for v in streams.values()]}")
    size = sensor_size or s.size
    if size is None:
        raise FormatError(path, f"stream {s.id} gives no sizeX/sizeY",
                          SENSOR_SIZE_HINT)
    meta = {"source": str(path), "format": "aedat4", "stream": s.id}
    return s, size, meta


def read(path: str | Path, t0: int | None = None, t1: int | None = None, *,
         stream: int | None = None, sensor_size: tuple[int, int] | None = None,
         validate: bool = True) -> EventArray:
    """Read the events of an AEDAT 4.0 file.

    Parameters
    ----------
    path : path-like
    t0, t1 : int, optional
        Keep ``t0 <= t < t1`` (µs; AEDAT4 times are absolute Unix-epoch µs).
    stream : int, optional
        Stream id of the event stream (default: the first ``EVTS`` stream).
    sensor_size : (int, int), optional
        Overrides the stream's ``sizeY``/``sizeX``.
    validate : bool
        Check sortedness and bounds.

    Examples
    --------
    >>> ev = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                 sensor_size=(180, 240))
    >>> write("recording.aedat4", ev)
    >>> ev = read("recording.aedat4", t0=150)
    >>> len(ev), ev.sensor_size, ev.t.tolist()
    (2, (180, 240), [200, 300])
    """
    path = Path(path)
    s, size, meta = _event_stream(path, stream, sensor_size)
    return binary.collect(_event_blocks(path, s.id), size, meta, t0, t1, validate=validate)


def iter_chunks(path: str | Path, chunk_events: int, *, stream: int | None = None,
                sensor_size: tuple[int, int] | None = None,
                validate: bool = True) -> Iterator[EventArray]:
    """Stream the events of an AEDAT 4.0 file, one packet in memory at a time."""
    chunk_events = binary.check_chunk_events(chunk_events)
    path = Path(path)
    s, size, meta = _event_stream(path, stream, sensor_size)
    yield from binary.rechunk(_event_blocks(path, s.id), chunk_events, size, meta,
                               validate=validate)


def read_frames(path: str | Path, *, stream: int | None = None) -> Frames:
    """The APS frames (``FRME`` stream) of an AEDAT 4.0 file.

    Returns
    -------
    Frames
        Timestamps in µs, exposure windows, positions; images (N, H, W) uint8 for grey,
        (N, H, W, 3/4) for BGR/BGRA.

    Examples
    --------
    >>> fr = read_frames("recording.aedat4")  # doctest: +SKIP
    >>> fr.images[0].shape  # doctest: +SKIP
    (260, 346)
    """
    path = Path(path)
    _, _, streams, _ = _parse_header(path)
    s = _stream_of(path, streams, "FRME", stream)
    ts, es, ee, imgs, posn = [], [], [], [], []
    if s is not None:
        for _, buf, pos in _packets(path, {s.id}):
            try:
                f = _root(buf, b"FRME", path, pos + 8)
                fmt = f.scalar(5, "<b", 0)
                w, h = f.scalar(6, "<h"), f.scalar(7, "<h")
                start, n = f.vector(10)
                ch = {0: 1, 16: 3, 24: 4}.get(fmt)
                if ch is None or n != w * h * ch:
                    raise FormatError(path, f"FRME packet at byte offset {pos}: format {fmt}, "
                                      f"{w}x{h}, {n} pixel bytes do not agree")
                img = np.frombuffer(buf, np.uint8, count=n, offset=start).reshape(
                    (h, w) if ch == 1 else (h, w, ch)).copy()
            except struct.error:
                raise FormatError(path, f"corrupt FRME packet at byte offset {pos}") from None
            ts.append(f.scalar(0, "<q"))
            es.append(f.scalar(3, "<q"))
            ee.append(f.scalar(4, "<q"))
            posn.append((f.scalar(8, "<h"), f.scalar(9, "<h")))
            imgs.append(img)
    shapes = {im.shape for im in imgs}
    if len(shapes) > 1:
        raise FormatError(path, f"FRME stream {s.id} holds frames of different sizes "
                          f"{sorted(shapes)}")
    stack = np.stack(imgs) if imgs else np.zeros((0, 0, 0), np.uint8)
    return Frames(images=stack, t=np.array(ts, np.int64), source=str(path), bit_depth=8,
                  exposure_start=np.array(es, np.int64), exposure_end=np.array(ee, np.int64),
                  position=np.array(posn, np.int64).reshape(-1, 2))


def read_imu(path: str | Path, *, stream: int | None = None) -> ImuSamples:
    """The IMU samples (``IMUS`` stream) of an AEDAT 4.0 file, converted to SI.

    Returns
    -------
    ImuSamples
        ``t`` µs, accel m/s² (DV stores g), gyro rad/s (DV stores °/s), °C, µT.

    Examples
    --------
    >>> imu = read_imu("recording.aedat4")  # doctest: +SKIP
    """
    path = Path(path)
    _, _, streams, _ = _parse_header(path)
    s = _stream_of(path, streams, "IMUS", stream)
    rows = []
    if s is not None:
        for _, buf, pos in _packets(path, {s.id}):
            try:
                for imu in _root(buf, b"IMUS", path, pos + 8).tables(0):
                    rows.append((imu.scalar(0, "<q"),) + tuple(
                        imu.scalar(k, "<f", 0.0) for k in range(1, 11)))
            except struct.error:
                raise FormatError(path, f"corrupt IMUS packet at byte offset {pos}") from None
    a = np.array(rows, np.float64).reshape(-1, 11)
    return ImuSamples(t=np.array([r[0] for r in rows], np.int64), accel=a[:, 2:5] * G,
                      gyro=np.deg2rad(a[:, 5:8]), temperature=a[:, 1], mag=a[:, 8:11])


def describe(path: str | Path) -> dict:
    """Streams (id, type, name, size), compression and per-stream packet/element counts."""
    path = Path(path)
    compression, table_pos, streams, _ = _parse_header(path)
    counts = {sid: 0 for sid in streams}
    packets = {sid: 0 for sid in streams}
    for sid, buf, pos in _packets(path):
        if sid not in streams:
            continue
        packets[sid] += 1
        kind = streams[sid].type
        if kind == "FRME":
            counts[sid] += 1
            continue
        try:
            counts[sid] += _root(buf, None, path, pos + 8).vector(0)[1]
        except (struct.error, ValueError):
            raise FormatError(path, f"corrupt {kind} packet at byte offset {pos}") from None
    out = {"format": "aedat4", "compression": COMPRESSION[compression],
           "streams": [{"id": s.id, "type": s.type, "name": s.name, "sensor_size": s.size,
                        "packets": packets[s.id], "elements": counts[s.id]}
                       for s in streams.values()]}
    by_type = {}
    for s in streams.values():
        by_type[s.type] = by_type.get(s.type, 0) + counts[s.id]
    out["n_events"] = by_type.get("EVTS", 0)
    out["frames"] = by_type.get("FRME", 0)
    out["imu"] = by_type.get("IMUS", 0)
    ev = [s for s in streams.values() if s.type == "EVTS" and s.size]
    out["sensor_size"] = ev[0].size if ev else None
    return out


# --------------------------------------------------------------- writing
def _ioheader(compression: int, info: str) -> bytes:
    text = info.encode() + b"\0"
    buf = bytearray()
    buf += struct.pack("<I4s", 24, b"IOHE")
    buf += struct.pack("<HHHHH", 10, 20, 4, 12, 8)  # vtable: compression, table pos, infoNode
    buf += b"\0" * (24 - len(buf))
    buf += struct.pack("<iiIq", 24 - 8, compression, 44 - 32, -1)
    buf += struct.pack("<I", len(text) - 1) + text
    buf += b"\0" * (-len(buf) % 4)
    return bytes(buf)


def _event_packet(ev: np.ndarray) -> bytes:
    body = bytearray(struct.pack("<I4sHHH", 16, b"EVTS", 6, 8, 4))
    body += b"\0" * 2
    body += struct.pack("<iII", 16 - 8, 4, len(ev))
    body += ev.tobytes()
    return struct.pack("<I", len(body)) + bytes(body)


def _info_xml(size: tuple[int, int], comp: str) -> str:
    h, w = size
    base = "/mainloop/Recorder/outInfo/"
    return (f'<dv version="2.0">\n    <node name="outInfo" path="{base}">\n'
            f'        <node name="0" path="{base}0/">\n'
            f'            <attr key="compression" type="string">{comp}</attr>\n'
            '            <attr key="originalModuleName" type="string">evmotion</attr>\n'
            '            <attr key="originalOutputName" type="string">events</attr>\n'
            '            <attr key="typeDescription" type="string">Array of events '
            '(polarity ON/OFF).</attr>\n'
            '            <attr key="typeIdentifier" type="string">EVTS</attr>\n'
            f'            <node name="info" path="{base}0/info/">\n'
            f'                <attr key="sizeX" type="int">{w}</attr>\n'
            f'                <attr key="sizeY" type="int">{h}</attr>\n'
            '                <attr key="source" type="string">evmotion</attr>\n'
            '            </node>\n        </node>\n    </node>\n</dv>\n')


def write(path: str | Path, events: EventArray | Iterable[EventArray], *,
          compression: str = "lz4", packet_events: int = 65536) -> None:
    """Write ``events`` as an AEDAT 4.0 file with one event stream (atomically).

    Parameters
    ----------
    path : path-like
    events : EventArray or iterable of EventArray
        Integer coordinates; times are written as they are (µs). Chunks (in time order)
        are streamed in bounded memory, into the packets one array of them all makes.
    compression : {"lz4", "none"}
        Packet compression (LZ4 frame format, as DV writes it).
    packet_events : int
        Events per packet.

    Examples
    --------
    >>> events = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                     sensor_size=(180, 240))
    >>> write("out.aedat4", events, compression="none")
    >>> describe("out.aedat4")["compression"], read("out.aedat4").p.tolist()
    ('none', [1, 0, 1])
    """
    if compression not in ("lz4", "none"):
        raise ParameterError(f"compression must be 'lz4' or 'none', got {compression!r}")
    if int(packet_events) <= 0:
        raise ParameterError(f"packet_events must be positive, got {packet_events}")
    size = int(packet_events)
    first, chunks = binary.first_chunk(path, events)
    code = 1 if compression == "lz4" else 0
    if code:
        import lz4.frame

        compress = lz4.frame.compress
    else:
        compress = bytes
    header = _ioheader(code, _info_xml(first.sensor_size, "LZ4" if code else "NONE"))
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(MAGIC + struct.pack("<i", len(header)) + header)
        rest = np.zeros(0, EVENT_DTYPE)
        last_t, seen = None, 0
        for chunk in itertools.chain([first], chunks):
            if chunk.x.dtype.kind == "f":
                raise FormatError(None, "events have float (undistorted) coordinates; AEDAT4 "
                                  "stores integer pixels")
            binary.same_sensor(chunk, first)
            # (written unsorted, the file could not be read back, probe DM)
            binary.check_in_order(chunk, "AEDAT4", last_t, seen)
            if len(chunk):
                last_t, seen = int(chunk.t[-1]), seen + len(chunk)
            ev = np.zeros(len(rest) + len(chunk), EVENT_DTYPE)
            ev[:len(rest)] = rest
            part = ev[len(rest):]
            part["t"], part["x"], part["y"], part["on"] = chunk.t, chunk.x, chunk.y, chunk.p
            full = len(ev) - len(ev) % size
            for a in range(0, full, size):
                payload = compress(_event_packet(ev[a:a + size]))
                fh.write(struct.pack("<ii", 0, len(payload)) + payload)
            rest = ev[full:]
        if len(rest):
            payload = compress(_event_packet(rest))
            fh.write(struct.pack("<ii", 0, len(payload)) + payload)


def _sniff(path: Path, head: bytes) -> bool:
    return head.startswith(MAGIC)


FORMAT = FormatSpec(name="aedat4", extensions=(".aedat4",), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
