"""cAER / DV AEDAT 3.1 files (``#!AER-DAT3.1``; also 3.0), e.g. the DVS128 Gesture data set.

Layout (iniVation's AEDAT 3.1 specification), all integers little-endian: ``#`` header lines
ending in CRLF (the version line, ``#Format: RAW``, one ``#Source <id>: <device>`` line per
source, ``#Start-Time: ...``, and ``#!END-HEADER``), then typed event packets. A packet is a
28-byte header (int16 eventType, int16 eventSource, int32 eventSize, eventTSOffset,
eventTSOverflow, eventCapacity, eventNumber, eventValid) followed by
``eventCapacity * eventSize`` bytes, of which the first ``eventNumber`` events are used.

Polarity events (type 1, 8 bytes): uint32 data with bit 0 the valid mark, bit 1 the
polarity, y in bits 2-16 and x in bits 17-31, then an int32 timestamp in µs; the full time is
``eventTSOverflow << 31 | timestamp``. Invalid events are skipped, and so are the packets of
other types (frames, special events); IMU6/IMU9 packets are read by :func:`read_imu`. The origin is the top left, as in evmotion.
AEDAT 3.0 differs in that its origin is the bottom left (y is mirrored here) and its header
has no end line.

The sensor size comes from the source's device name (``DVS128``, ``DAVIS240C``,
``DAVIS346B``...); for a device not listed here, ``sensor_size`` is needed or the size is
taken from the largest coordinates, with a warning.
"""

from __future__ import annotations

import re
import time
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from evmotion.catalog import NS_EPOCH_US
from evmotion.errors import EvmotionWarning, FormatError
from evmotion.events import EventArray, concatenate
from evmotion.io import binary
from evmotion.io.base import FormatSpec
from evmotion.io.guard import check_sensor_size, warn_inferred_size
from evmotion.utils import atomic_path

__all__ = ["read", "iter_chunks", "write", "describe", "read_imu", "DEVICE_SIZES", "FORMAT"]

MAGIC = b"#!AER-DAT3."
END_LINE = b"#!END-HEADER"
PACKET_HEADER = np.dtype([("type", "<i2"), ("source", "<i2"), ("size", "<i4"),
                          ("ts_offset", "<i4"), ("ts_overflow", "<i4"), ("capacity", "<i4"),
                          ("number", "<i4"), ("valid", "<i4")])
POLARITY = 1
POLARITY_BYTES = 8
# events per packet the writer puts (cAER's packets hold a few thousand)
WRITE_PACKET_EVENTS = 8192

#: (height, width) of the devices named in ``#Source`` lines, matched in this order on
#: the name in upper case without spaces, dashes or underscores.
DEVICE_SIZES: tuple[tuple[str, tuple[int, int]], ...] = (
    ("DVXPLORERLITE", (240, 320)), ("DVXPLORER", (480, 640)), ("DAVISHET640", (480, 640)),
    ("DAVIS640", (480, 640)), ("DAVIS346", (260, 346)), ("DAVIS240", (180, 240)),
    ("DAVIS208", (192, 208)), ("DAVIS128", (128, 128)), ("DVS132S", (104, 132)),
    ("DVS128", (128, 128)), ("EDVS", (128, 128)),
)
_OWN_SIZE = re.compile(r"#evmotion sensor_size \(height, width\) = \((\d+), (\d+)\)")


def _device_size(name: str) -> tuple[int, int] | None:
    key = re.sub(r"[\s_\-]", "", name).upper()
    for prefix, size in DEVICE_SIZES:
        if prefix in key:
            return size
    return None


def _parse_header(path: Path) -> tuple[list[str], int, str, dict[int, str]]:
    """Header lines, payload offset, version ("3.0"/"3.1") and the sources by id."""
    with open(path, "rb") as fh:
        head = fh.read(len(MAGIC) + 1)
    if not head.startswith(MAGIC) or head[-1:] not in (b"0", b"1"):
        raise FormatError(path, f"bad magic at byte offset 0: {head!r}, expected "
                          "b'#!AER-DAT3.1' or b'#!AER-DAT3.0'", "not an AEDAT 3 file")
    version = "3." + head[-1:].decode()
    lines, offset = binary.read_text_header(path, b"#", end_line=END_LINE,
                                            max_bytes=1 << 24)
    if version == "3.1" and (not lines or lines[-1].encode("latin-1") != END_LINE):
        raise FormatError(path, "the header has no '#!END-HEADER' line",
                          "the file is truncated or not AEDAT 3.1")
    fmt = next((ln.split(":", 1)[1].strip() for ln in lines if ln.startswith("#Format:")),
               "RAW")
    if fmt.split()[0].upper() != "RAW":
        raise FormatError(path, f"header '#Format: {fmt}' is not RAW",
                          "only uncompressed AEDAT 3.1 packets are read")
    sources = {}
    for ln in lines:
        m = re.match(r"#Source (\d+):\s*(.*)$", ln)
        if m:
            sources[int(m.group(1))] = m.group(2).strip()
    return lines, offset, version, sources


def _packets(path: Path, offset: int, *, payload_of=(POLARITY,)
             ) -> Iterator[tuple[int, np.void, bytes | None]]:
    """``(file offset, header, payload)`` of every packet; the payload (its first
    ``eventNumber`` events) is read only for the types in ``payload_of``."""
    size = path.stat().st_size
    hsize = PACKET_HEADER.itemsize
    with open(path, "rb") as fh:
        fh.seek(offset)
        pos = offset
        while pos < size:
            raw = fh.read(hsize)
            if len(raw) < hsize:
                raise FormatError(path, f"truncated: {len(raw)} byte(s) at byte offset {pos}, "
                                  f"where a {hsize}-byte packet header was expected",
                                  "the file was cut short")
            h = np.frombuffer(raw, PACKET_HEADER)[0]
            esize, cap, num = int(h["size"]), int(h["capacity"]), int(h["number"])
            if esize <= 0 or cap < 0 or not 0 <= num <= cap or not 0 <= int(h["valid"]) <= num:
                raise FormatError(path, f"packet header at byte offset {pos} is corrupt "
                                  f"(eventSize {esize}, eventCapacity {cap}, eventNumber "
                                  f"{num}, eventValid {int(h['valid'])})")
            body = esize * cap
            if pos + hsize + body > size:
                raise FormatError(path, f"truncated: the packet at byte offset {pos} needs "
                                  f"{body} bytes of events, the file has "
                                  f"{size - pos - hsize} left", "the file was cut short")
            payload = None
            if int(h["type"]) in payload_of:
                payload = fh.read(esize * num)
                fh.seek(body - esize * num, 1)
            else:
                fh.seek(body, 1)
            yield pos, h, payload
            pos += hsize + body


_RECORD = np.dtype([("data", "<u4"), ("ts", "<i4")])


def _check_polarity(path: Path, pos: int, h) -> None:
    if int(h["size"]) != POLARITY_BYTES:
        raise FormatError(path, f"polarity packet at byte offset {pos} has eventSize "
                          f"{int(h['size'])}, expected {POLARITY_BYTES}")
    _check_overflow(path, pos, h, "polarity")


def _check_overflow(path: Path, pos: int, h, kind: str) -> None:
    """FormatError for a packet whose ``eventTSOverflow`` puts its times before the
    clock's zero or past the year 5000 (both were read as given, probe CG)."""
    over = int(h["ts_overflow"])
    if over < 0:
        raise FormatError(path, f"{kind} packet at byte offset {pos} has eventTSOverflow "
                          f"{over}: negative, where times count up from the clock's zero",
                          "a corrupt packet header")
    if over << 31 > NS_EPOCH_US:
        # (read as given, 4.6e18 us; the file's h5 copy was then refused)
        raise FormatError(path, f"{kind} packet at byte offset {pos} has eventTSOverflow "
                          f"{over}: its times, from {over << 31} us, lie past the year 5000",
                          "a corrupt packet header")


def _decode(path: Path, payloads: list[bytes], overflows: list[int]):
    """Valid polarity events of several packets' payloads (the packets' ``eventTSOverflow``
    in ``overflows``): raw x, raw y, t (µs), p. One numpy pass for many packets: files
    of small packets cost little more than files of large ones."""
    rec = np.frombuffer(b"".join(payloads), _RECORD)
    over = np.repeat(np.asarray(overflows, np.int64),
                     [len(b) // POLARITY_BYTES for b in payloads])
    keep = (rec["data"] & 1).astype(bool)
    data, ts, over = rec["data"][keep], rec["ts"][keep], over[keep]
    if ts.size and int(ts.min()) < 0:
        raise FormatError(path, f"a polarity event has a negative timestamp {int(ts.min())}")
    t = (over << 31) | ts.astype(np.int64)
    return (data >> 17) & 0x7FFF, (data >> 2) & 0x7FFF, t, ((data >> 1) & 1).astype(np.uint8)


class _Stream:
    """The polarity events of one source, decoded a group of packets at a time."""

    def __init__(self, path: Path, offset: int, version: str, sources: dict[int, str]):
        self.path, self.offset, self.mirror = path, offset, version == "3.0"
        self.source = None
        for _, h, _ in _packets(path, offset, payload_of=()):
            if int(h["type"]) == POLARITY:
                self.source = int(h["source"])
                break
        self.device = sources.get(self.source) if self.source is not None else None
        if self.device is None and len(sources) == 1:
            self.device = next(iter(sources.values()))

    def raw(self, target_events: int = 1 << 19) -> Iterator[tuple[np.ndarray, ...]]:
        """Decoded groups of about ``target_events`` events (whole packets)."""
        others = set()
        payloads, overflows, n = [], [], 0
        for pos, h, payload in _packets(self.path, self.offset):
            if int(h["type"]) != POLARITY:
                continue
            if int(h["source"]) != self.source:
                others.add(int(h["source"]))
                continue
            _check_polarity(self.path, pos, h)
            payloads.append(payload)
            overflows.append(int(h["ts_overflow"]))
            n += len(payload) // POLARITY_BYTES
            if n >= target_events:
                yield _decode(self.path, payloads, overflows)
                payloads, overflows, n = [], [], 0
        if payloads:
            yield _decode(self.path, payloads, overflows)
        if others:
            warnings.warn(EvmotionWarning(
                f"{self.path}: polarity events of source(s) {sorted(others)} skipped; read "
                f"those of source {self.source} ({self.device or 'unnamed'})"), stacklevel=2)

    def max_xy(self) -> tuple[int, int]:
        xm = ym = -1
        for x, y, _, _ in self.raw():
            if x.size:
                xm, ym = max(xm, int(x.max())), max(ym, int(y.max()))
        return xm, ym

    def blocks(self, size: tuple[int, int], block_bytes: int) -> Iterator[binary.Block]:
        for x, y, t, p in self.raw(max(int(block_bytes) // POLARITY_BYTES, 1)):
            if self.mirror:
                bad = y >= size[0]
                if bad.any():
                    raise FormatError(self.path, f"event y = {int(y[bad][0])} is outside the "
                                      f"{size[1]}x{size[0]} sensor")
                y = size[0] - 1 - y
            # 15-bit addresses fit uint16
            yield x.astype(np.uint16), y.astype(np.uint16), t, p


def _sensor(path: Path, lines: list[str], stream: _Stream, sensor_size) -> tuple[int, int]:
    if sensor_size is not None:
        return check_sensor_size(path, sensor_size, "sensor_size")
    own = _OWN_SIZE.search("\n".join(lines))
    if own:
        return check_sensor_size(path, (own.group(1), own.group(2)), "header sensor_size")
    size = _device_size(stream.device or "")
    if size is not None:
        return size
    xm, ym = stream.max_xy()
    size = (max(ym + 1, 1), max(xm + 1, 1))
    check_sensor_size(path, size, "largest coordinates")
    warn_inferred_size(path, size, f" (device '{stream.device or 'none'}' not known)",
                       stacklevel=5)
    return size


def _open(path: Path, sensor_size: tuple[int, int] | None, block_bytes: int
          ) -> tuple[int, tuple[int, int], Iterator[binary.Block]]:
    lines, offset, version, sources = _parse_header(path)
    stream = _Stream(path, offset, version, sources)
    size = _sensor(path, lines, stream, sensor_size)
    return offset, size, stream.blocks(size, block_bytes)


def read(path: str | Path, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True,
         block_bytes: int = binary.BLOCK_BYTES) -> EventArray:
    """Read the polarity events of an AEDAT 3.1 / 3.0 file: those with ``t0 <= t < t1``
    (µs, as in the file) when given, on ``sensor_size`` ``(height, width)`` when given (else
    the ``#Source`` device's), checked for order and bounds unless ``validate=False``,
    ``block_bytes`` at a time.

    Examples
    --------
    >>> import tempfile
    >>> path = tempfile.mkdtemp() + "/gesture.aedat"
    >>> ev = EventArray(x=[3, 100], y=[5, 120], t=[10, 2000], p=[1, 0], sensor_size=(128, 128))
    >>> write(path, ev)
    >>> back = read(path)
    >>> back.sensor_size, back.x.tolist(), back.t.tolist()
    ((128, 128), [3, 100], [10, 2000])
    """
    return binary.read_file(path, "aedat3", 1, _open, t0, t1, sensor_size=sensor_size,
                             validate=validate, block_bytes=block_bytes)


def iter_chunks(path: str | Path, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                block_bytes: int = binary.BLOCK_BYTES) -> Iterator[EventArray]:
    """Stream the polarity events of an AEDAT 3.1 / 3.0 file in chunks of
    ``chunk_events``."""
    yield from binary.iter_file(path, chunk_events, "aedat3", 1, _open,
                                 sensor_size=sensor_size, validate=validate,
                                 block_bytes=block_bytes)


def write(path: str | Path, events: EventArray | Iterable[EventArray], *,
          device: str | None = None) -> None:
    """Write events (an EventArray, or chunks of one in time order, streamed in bounded
    memory) as an AEDAT 3.1 file (atomically), polarity packets of source 1.

    ``device`` (the ``#Source 1:`` name) defaults to the device of that sensor size
    (``DVS128``, ``DAVIS240C``, ``DAVIS346B``, ``DAVIS640``); the size itself is also
    written to the header, so any size reads back.

    Examples
    --------
    >>> events = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                     sensor_size=(180, 240))
    >>> write("out.aedat", events)
    >>> back = read("out.aedat")
    >>> back.sensor_size, back.x.tolist()
    ((180, 240), [10, 20, 30])
    """
    first, chunks = binary.first_chunk(path, events)
    h, w = first.sensor_size
    if device is None:
        device = {(128, 128): "DVS128", (180, 240): "DAVIS240C", (260, 346): "DAVIS346B",
                  (480, 640): "DAVIS640"}.get((h, w), "evmotion")
    binary.check_writable(first[:0], "AEDAT 3.1", 0x8000, 0x8000)  # the header's sensor
    if len(first) and first.t[0] < 0:
        raise FormatError(None, f"first timestamp {first.t[0]} us is negative; AEDAT 3.1 "
                          "stores times from 0", "subtract a time offset first")
    start = time.strftime("%Y-%m-%d %H:%M:%S (TZ+0000)", time.gmtime())
    header = (f"#!AER-DAT3.1\r\n#Format: RAW\r\n#Source 1: {device}\r\n"
              f"#evmotion sensor_size (height, width) = ({h}, {w})\r\n"
              f"#Start-Time: {start}\r\n{END_LINE.decode()}\r\n")
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("latin-1"))
        held = None
        for chunk in binary.checked_chunks(first, chunks, "AEDAT 3.1", 0x8000, 0x8000):
            if held is not None:
                chunk = concatenate([held, chunk], validate=False)
            held = _write_packets(fh, chunk, last=False)
        if held is not None:
            _write_packets(fh, held, last=True)


def _write_packets(fh, events: EventArray, *, last: bool) -> EventArray | None:
    """Write ``events`` as polarity packets, each of one overflow epoch (2^31 µs) and at
    most :data:`WRITE_PACKET_EVENTS` events, from each epoch's first event; unless
    ``last``, the events of the last epoch short of a full packet are returned, not
    written (the next chunk's may join them: the packets of a whole array's writing)."""
    t = np.asarray(events.t, np.int64)
    data = ((events.x.astype(np.uint32) << 17) | (events.y.astype(np.uint32) << 2)
            | (events.p.astype(np.uint32) << 1) | np.uint32(1))
    overflow = t >> 31
    cuts = np.flatnonzero(np.diff(overflow)) + 1
    starts, stops = np.r_[0, cuts], np.r_[cuts, len(t)]
    held = None
    for a0, b0 in zip(starts, stops, strict=True):
        for a in range(int(a0), int(b0), WRITE_PACKET_EVENTS):
            b = min(a + WRITE_PACKET_EVENTS, int(b0))
            if not last and b == len(t) and b - a < WRITE_PACKET_EVENTS:
                held = events[a:]
                break
            n = b - a
            hdr = np.array([(POLARITY, 1, POLARITY_BYTES, 4, int(overflow[a]), n, n, n)],
                           PACKET_HEADER)
            rec = np.empty(n, np.dtype([("data", "<u4"), ("ts", "<i4")]))
            rec["data"] = data[a:b]
            rec["ts"] = (t[a:b] & 0x7FFFFFFF).astype(np.int32)
            fh.write(hdr.tobytes())
            fh.write(rec.tobytes())
    return held


IMU6, IMU9 = 3, 4
G = 9.80665


def read_imu(path: str | Path) -> dict:
    """The IMU samples (IMU6 and IMU9 packets: uint32 info with bit 0 the valid mark, int32
    timestamp, accelerometer x, y, z in g, gyroscope x, y, z in °/s, temperature, float32
    each; IMU9 adds the magnetometer) as ``{"t": µs, "accel": m/s², "gyro": rad/s}``.

    >>> read_imu("davis346.aedat")["gyro"].shape  # doctest: +SKIP
    (1200, 3)
    """
    path = Path(path)
    _, offset, _, _ = _parse_header(path)
    parts = []
    for pos, h, payload in _packets(path, offset, payload_of=(IMU6, IMU9)):
        if payload is None:
            continue
        size = int(h["size"])
        if size < 36:
            raise FormatError(path, f"IMU packet at byte offset {pos} has eventSize {size} "
                              "(an IMU6 event is 36 bytes)")
        _check_overflow(path, pos, h, "IMU")
        rec = np.frombuffer(payload, np.uint8).reshape(-1, size)
        info = rec[:, 0:4].copy().view("<u4").ravel()
        ts = rec[:, 4:8].copy().view("<i4").ravel().astype(np.int64)
        vals = rec[:, 8:32].copy().view("<f4").astype(np.float64)
        keep = (info & 1).astype(bool)
        parts.append((ts[keep] | (int(h["ts_overflow"]) << 31), vals[keep]))
    if not parts or not sum(len(t) for t, _ in parts):
        raise FormatError(path, "no IMU samples (IMU6 / IMU9 packets)")
    t = np.concatenate([p[0] for p in parts])
    vals = np.concatenate([p[1] for p in parts])
    if not np.isfinite(vals).all():
        raise FormatError(path, "IMU samples hold NaN or inf")
    order = np.argsort(t, kind="stable")
    return {"t": t[order], "accel": vals[order, 0:3] * G,
            "gyro": np.deg2rad(vals[order, 3:6])}


def describe(path: str | Path) -> dict:
    """Device, sensor size, counts of polarity events, frames and IMU samples, and the
    time span of the polarity events."""
    path = Path(path)
    lines, offset, version, sources = _parse_header(path)
    stream = _Stream(path, offset, version, sources)
    size = _sensor(path, lines, stream, None)
    counts = {"n_events": 0, "frames": 0, "imu": 0}
    kinds = {POLARITY: "n_events", 2: "frames", 3: "imu", 4: "imu"}
    t_first = t_last = None
    for pos, h, payload in _packets(path, offset):
        kind = kinds.get(int(h["type"]))
        if kind is None:
            continue
        if kind != "n_events":
            counts[kind] += int(h["valid"])
            continue
        if int(h["source"]) != stream.source:
            continue
        _check_polarity(path, pos, h)
        _, _, t, _ = _decode(path, [payload], [int(h["ts_overflow"])])
        counts["n_events"] += int(t.size)
        if t.size:
            t_first = int(t[0]) if t_first is None else t_first
            t_last = int(t[-1])
    return {"format": "aedat3", "version": version, "device": stream.device,
            "sources": {str(k): v for k, v in sources.items()}, "sensor_size": size,
            **counts, "t_first_us": t_first, "t_last_us": t_last}


def _sniff(path: Path, head: bytes) -> bool:
    return head.startswith(MAGIC) and head[len(MAGIC):len(MAGIC) + 1] in (b"0", b"1")


FORMAT = FormatSpec(name="aedat3", extensions=(".aedat", ".aedat3"), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
