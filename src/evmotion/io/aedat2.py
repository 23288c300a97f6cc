"""jAER AEDAT 2.0 files from DAVIS and DVS128 cameras (``#!AER-DAT2.0``).

After ``#`` header lines, every record is a big-endian u32 address and u32 timestamp
(µs). DAVIS address layout: bit 31 = APS/IMU flag; for DVS events (bit 31 = 0) y is in
bits 22-30, x in bits 12-21 and polarity in bit 11 (bit 10 marks external-input events,
which are skipped). IMU samples are APS-type addresses with bits 10-11 = 3, the sample
kind in bits 28-30 (0-2 accelerometer x/y/z, 3 temperature, 4-6 gyroscope x/y/z) and a
signed 16-bit value in bits 12-27. Other APS addresses are frame samples, not events.

jAER puts the origin at the bottom left and mirrors x; evmotion uses image coordinates
(origin top left), so ``x = width - 1 - x_raw`` and ``y = height - 1 - y_raw``.

Files of the DVS128 (``AEChip: ...DVS128``, 128x128) use that chip's address layout: x in
bits 1-7, y in bits 8-14 and bit 0 the OFF mark (jAER's extractor flips the type), mirrored
in x and y alike; they hold no APS or IMU data.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError
from evmotion.events import EventArray
from evmotion.io import binary
from evmotion.io.base import FormatSpec
from evmotion.io.guard import SENSOR_SIZE_HINT, check_sensor_size
from evmotion.io.prophesee import OFFSET_KEY, header_time_offset
from evmotion.utils import atomic_path

__all__ = ["read", "iter_chunks", "write", "read_imu", "describe", "ImuSamples", "FORMAT"]

MAGIC = b"#!AER-DAT2.0"
RECORD = 8
G = 9.80665
# (height, width) of the chips jAER names in the ``# AEChip:`` line
_CHIPS = (("DAVIS240", (180, 240)), ("DAVIS346", (260, 346)), ("DAVIS640", (480, 640)),
          ("DAVIS128", (128, 128)))
_ACCEL_LSB_PER_G = {"2": 16384.0, "4": 8192.0, "8": 4096.0, "16": 2048.0}
_GYRO_LSB_PER_DPS = {"250": 131.0, "500": 65.5, "1000": 32.8, "2000": 16.4}


@dataclass(frozen=True)
class ImuSamples:
    """IMU samples: ``t`` int64 µs, ``accel`` (N, 3) m/s², ``gyro`` (N, 3) rad/s,
    ``temperature`` (N,) °C, in the IMU's own axes."""

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray
    temperature: np.ndarray


def _parse_header(path: Path, sensor_size):
    with open(path, "rb") as fh:
        head = fh.read(len(MAGIC))
    if head != MAGIC:
        raise FormatError(path, f"bad magic at byte offset 0: {head!r}, expected {MAGIC!r}",
                          "not a jAER AEDAT 2.0 file")
    lines, offset = binary.read_text_header(path, b"#", max_bytes=1 << 24)
    text = "\n".join(lines)
    own = re.search(r"# sensor_size \(height, width\) = \((\d+), (\d+)\)", text)
    if sensor_size is None and own:
        sensor_size = check_sensor_size(path, (own.group(1), own.group(2)),
                                        "header sensor_size")
    if sensor_size is None:
        chip = re.search(r"AEChip:\s*(\S+)", text)
        name = chip.group(1).upper() if chip else ""
        sizes = (("DVS128", (128, 128)),) if _is_dvs128(lines) else _CHIPS
        sensor_size = next((size for key, size in sizes if key in name), None)
        if sensor_size is None:
            raise FormatError(path, f"unknown AEChip '{name or '(none)'}' in the header",
                              SENSOR_SIZE_HINT)
    return lines, offset, sensor_size


class _Unwrap:
    """Unwraps u32 µs timestamps across blocks (jAER's counter wraps every 71.6 min); a
    record whose time jumps ahead and falls back (or falls and jumps back) by half the
    counter or more raises :class:`binary.CorruptTimeError` (it was taken for a
    rollover), its ``pos`` the record's index in the file."""

    def __init__(self, offset: int = 0) -> None:
        self.last = None
        self.start = self.offset = offset
        self.prev = np.empty(0, np.int64)  # the last two unwrapped times, for the check
        self.records = 0

    def __call__(self, t32: np.ndarray) -> np.ndarray:
        t = t32.astype(np.int64)
        if t.size == 0:
            return t
        prev = t[0] if self.last is None else self.last
        d = np.diff(t, prepend=prev)
        wraps = np.cumsum(d < -(1 << 31)) << 32
        out = t + wraps + self.offset
        bad = binary.corrupt_counter(out, self.prev, 1 << 32)
        if bad is not None:
            seq = np.concatenate((self.prev, out))
            k = bad + self.prev.size
            raise binary.CorruptTimeError(self.records + bad,
                                          (seq[k - 1:k + 2] - self.start) & 0xFFFFFFFF, 32,
                                          "record")
        self.prev = np.concatenate((self.prev, out))[-2:]
        self.records += t.size
        self.offset += int(wraps[-1])
        self.last = int(t[-1])
        return out


def _time_offset(path: Path, lines: list[str]) -> int:
    """The µs evmotion's writer took off the times (header line
    ``# evmotion_time_offset_us N``; 0 without it)."""
    return header_time_offset(path, [ln.lstrip("#") for ln in lines])


def _is_dvs128(lines: list[str]) -> bool:
    chip = re.search(r"AEChip:\s*(\S+)", "\n".join(lines))
    name = chip.group(1).upper() if chip else ""
    return "DVS128" in name and "DAVIS" not in name


def _decode_dvs128(addr: np.ndarray, t: np.ndarray, size) -> binary.Block:
    h, w = size
    x = (w - 1 - ((addr >> 1) & 0x7F)).astype(np.uint16)
    y = (h - 1 - ((addr >> 8) & 0x7F)).astype(np.uint16)
    p = (1 - (addr & 1)).astype(np.uint8)
    return x, y, np.ascontiguousarray(t), p


def _decode(addr: np.ndarray, t: np.ndarray, size) -> binary.Block:
    h, w = size
    dvs = (addr & 0x80000400) == 0
    a = addr[dvs]
    x = (w - 1 - ((a >> 12) & 0x3FF)).astype(np.uint16)
    y = (h - 1 - ((a >> 22) & 0x1FF)).astype(np.uint16)
    p = ((a >> 11) & 1).astype(np.uint8)
    return x, y, np.ascontiguousarray(t[dvs]), p


def _records(path: Path, offset: int, block_bytes: int, lines: list[str]):
    unwrap = _Unwrap(_time_offset(path, lines))
    for _, buf in binary.iter_blocks(path, offset, block_bytes, RECORD):
        rec = np.frombuffer(buf, ">u4").reshape(-1, 2)
        try:
            t = unwrap(rec[:, 1])
        except binary.CorruptTimeError as exc:
            raise exc.at(path, f"record {exc.pos} (timestamp at byte offset "
                               f"{offset + RECORD * exc.pos + 4})") from None
        yield rec[:, 0].astype(np.uint32), t


def _blocks(path, offset, size, block_bytes, decode, lines) -> Iterator[binary.Block]:
    for addr, t in _records(path, offset, block_bytes, lines):
        yield decode(addr, t, size)


def _open(path: Path, sensor_size: tuple[int, int] | None, block_bytes: int
          ) -> tuple[int, tuple[int, int], Iterator[binary.Block]]:
    lines, offset, size = _parse_header(path, sensor_size)
    decode = _decode_dvs128 if _is_dvs128(lines) else _decode
    return offset, size, _blocks(path, offset, size, block_bytes, decode, lines)


def read(path: str | Path, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True,
         block_bytes: int = binary.BLOCK_BYTES) -> EventArray:
    """Read the DVS events of a jAER AEDAT 2.0 (DAVIS or DVS128) file.

    Parameters
    ----------
    path : path-like
    t0, t1 : int, optional
        Keep ``t0 <= t < t1`` (µs, as in the file).
    sensor_size : (int, int), optional
        ``(height, width)``; taken from the ``AEChip`` header line otherwise.
    validate : bool
        Check sortedness and bounds.
    block_bytes : int
        Read granularity.

    Examples
    --------
    >>> ev = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                 sensor_size=(180, 240))
    >>> write("davis240.aedat", ev)
    >>> ev = read("davis240.aedat")
    >>> len(ev), ev.sensor_size, ev.t.tolist()
    (3, (180, 240), [100, 200, 300])
    """
    return binary.read_file(path, "aedat2", RECORD, _open, t0, t1, sensor_size=sensor_size,
                             validate=validate, block_bytes=block_bytes)


def iter_chunks(path: str | Path, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                block_bytes: int = binary.BLOCK_BYTES) -> Iterator[EventArray]:
    """Stream the DVS events of an AEDAT 2.0 file in chunks of ``chunk_events``."""
    yield from binary.iter_file(path, chunk_events, "aedat2", RECORD, _open,
                                 sensor_size=sensor_size, validate=validate,
                                 block_bytes=block_bytes)


def _imu_scales(lines: list[str]) -> tuple[float, float]:
    text = "\n".join(lines)
    acc = re.search(r'key="ImuAccelScale" value="ImuAccelScaleG(\d+)"', text)
    gyr = re.search(r'key="ImuGyroScale" value="GyroFullScaleDegPerSec(\d+)"', text)
    a = _ACCEL_LSB_PER_G.get(acc.group(1) if acc else "8", 4096.0)
    g = _GYRO_LSB_PER_DPS.get(gyr.group(1) if gyr else "1000", 32.8)
    return a, g


def read_imu(path: str | Path) -> ImuSamples:
    """IMU samples embedded in a DAVIS AEDAT 2.0 file.

    Each sample is 7 consecutive IMU words (kinds 0-6); incomplete groups are dropped.
    Full-scale ranges come from the ``ImuAccelScale``/``ImuGyroScale`` preferences in the
    header (jAER defaults ±8 g, ±1000 °/s otherwise); temperature follows the MPU-6x50
    datasheet (raw / 340 + 36.53 °C).

    Returns
    -------
    ImuSamples
        ``t`` µs (time of the accelerometer-x word), accel m/s², gyro rad/s, °C.

    Examples
    --------
    >>> imu = read_imu("davis240.aedat")  # doctest: +SKIP
    >>> round(float(np.linalg.norm(imu.accel, axis=1).mean()), 1)  # doctest: +SKIP
    9.8
    """
    path = Path(path)
    lines, offset, _ = _parse_header(path, (1, 1))
    binary.trailing_partial(path, offset, RECORD)
    acc_lsb, gyr_lsb = _imu_scales(lines)
    codes, vals, ts = [], [], []
    for addr, t in _records(path, offset, binary.BLOCK_BYTES, lines):
        m = (addr & 0x80000C00) == 0x80000C00
        codes.append(((addr[m] >> 28) & 7).astype(np.int8))
        vals.append(((addr[m] >> 12) & 0xFFFF).astype(np.uint16).view(np.int16))
        ts.append(t[m])
    code = np.concatenate(codes) if codes else np.empty(0, np.int8)
    val = np.concatenate(vals).astype(np.float64) if vals else np.empty(0)
    t = np.concatenate(ts) if ts else np.empty(0, np.int64)
    # a sample starts at kind 0 followed by kinds 1..6 in order
    starts = np.nonzero(code == 0)[0]
    starts = starts[starts + 6 < code.size]
    ok = np.ones(starts.size, bool)
    for k in range(1, 7):
        ok &= code[np.minimum(starts + k, code.size - 1)] == k
    s = starts[ok]
    raw = np.stack([val[s + k] for k in range(7)], axis=1) if s.size else np.empty((0, 7))
    return ImuSamples(t=t[s], accel=raw[:, 0:3] / acc_lsb * G,
                      gyro=np.deg2rad(raw[:, 4:7] / gyr_lsb),
                      temperature=raw[:, 3] / 340.0 + 36.53)


def write(path: str | Path, events: EventArray | Iterable[EventArray], *,
          chip: str | None = None) -> None:
    """Write DVS events (an EventArray, or chunks of one in time order, streamed in
    bounded memory) as a jAER AEDAT 2.0 file (atomically), DAVIS address layout.

    Timestamps are stored modulo 2^32 µs (a first time past 2^32 µs, a clock since the
    epoch, from the multiple of 2^32 µs below it, kept in the header as
    ``# evmotion_time_offset_us``), coordinates mirrored back to jAER's raw addresses, so
    :func:`read` returns exactly ``events``. ``chip`` (the ``AEChip``
    header line) defaults to the DAVIS model of that sensor size; the size itself is
    also written to the header.

    Examples
    --------
    >>> events = EventArray(x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1],
    ...                     sensor_size=(180, 240))
    >>> write("out.aedat", events)
    >>> read("out.aedat").x.tolist()
    [10, 20, 30]
    """
    first, chunks = binary.first_chunk(path, events)
    h, w = first.sensor_size
    if chip is None:
        chip = {(180, 240): "DAVIS240C", (260, 346): "DAVIS346B"}.get((h, w), "DAVIS")
    fmt = "AEDAT 2.0 (DAVIS)"
    hint = "AEDAT 3.1 (--format-out aedat3) holds sensors up to 32768 px"
    binary.check_writable(first[:0], fmt, 512, 1024, hint=hint)  # the header's sensor
    t_base = binary.u32_time_base(first[:1], "AEDAT 2.0")
    header = (f"{MAGIC.decode()}\r\n# This is a raw AE data file written by evmotion\r\n"
              "# Data format is int32 address, int32 timestamp (8 bytes total), repeated "
              "for each event\r\n# Timestamps tick is 1 us\r\n"
              f"# AEChip: {chip}\r\n# sensor_size (height, width) = ({h}, {w})\r\n"
              + (f"# {OFFSET_KEY} {t_base}\r\n" if t_base else ""))
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(header.encode("latin-1"))
        for chunk in binary.checked_chunks(first, chunks, fmt, 512, 1024, hint=hint,
                                           u32_base=t_base):
            rec = np.empty((len(chunk), 2), ">u4")
            xr = (w - 1 - chunk.x.astype(np.int64)).astype(np.uint32)
            yr = (h - 1 - chunk.y.astype(np.int64)).astype(np.uint32)
            rec[:, 0] = (yr << 22) | (xr << 12) | (chunk.p.astype(np.uint32) << 11)
            rec[:, 1] = (chunk.t & 0xFFFFFFFF).astype(np.uint32)
            fh.write(rec.tobytes())


def describe(path: str | Path) -> dict:
    """Chip, sensor size and counts of DVS events, APS samples and IMU samples."""
    path = Path(path)
    lines, offset, size = _parse_header(path, None)
    dvs128 = _is_dvs128(lines)
    n_dvs = n_imu_words = n_aps = 0
    t_first = t_last = None
    for addr, t in _records(path, offset, binary.BLOCK_BYTES, lines):
        if dvs128:  # every record is a DVS event
            addr = np.zeros_like(addr)
        n_dvs += int(((addr & 0x80000400) == 0).sum())
        imu = (addr & 0x80000C00) == 0x80000C00
        n_imu_words += int(imu.sum())
        n_aps += int(((addr >> 31) == 1).sum() - imu.sum())
        if t.size:
            t_first = int(t[0]) if t_first is None else t_first
            t_last = int(t[-1])
    chip = re.search(r"AEChip:\s*(\S+)", "\n".join(lines))
    return {"format": "aedat2", "chip": chip.group(1) if chip else None,
            "sensor_size": size, "n_events": n_dvs, "imu": n_imu_words // 7,
            "aps_samples": n_aps, "frames": 0, "t_first_us": t_first, "t_last_us": t_last}


def _sniff(path: Path, head: bytes) -> bool:
    return head.startswith(MAGIC)


FORMAT = FormatSpec(name="aedat2", extensions=(".aedat", ".dat"), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
