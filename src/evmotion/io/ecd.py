"""Event Camera Dataset (ECD, Mueggler et al. 2017): text events and the folder layout.

A folder holds ``events.txt`` (one event per line: ``t[s] x y p``, p in {0, 1}), and
optionally ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``), ``imu.txt`` (``t ax ay az gx gy
gz``), ``groundtruth.txt`` (``t px py pz qx qy qz qw``) and ``images.txt`` (``t
images/frame_xxx.png``). A single ``events.txt`` file is read the same way.

Text is parsed by a numba kernel over raw bytes (``np.loadtxt`` is ~50x slower); times are
converted to integer microseconds exactly from the decimal digits (rounded to nearest),
never through a float (numbers in scientific notation, as numpy's ``savetxt`` writes them,
go through float64: exact to the µs below ~10^9 s). A text of at most ``PLAIN_TEXT_BYTES`` made only of digits, points
and white space is parsed by numpy string operations instead, to the same integers: loading
numba and its first kernel costs a process ~0.3 s (~1 s more to compile it into an empty
cache), more than numpy takes for ~100k lines (a one-window command reads ~30k).
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from evmotion.catalog import NS_EPOCH_US
from evmotion.errors import (
    EvmotionWarning,
    FormatError,
    ParameterError,
    TimeUnitGuessWarning,
    UnsortedError,
    UnusedCalibrationWarning,
)
from evmotion.events import EventArray, ambiguous_polarity, check_follows
from evmotion.io.base import TIME_UNIT_US, FormatSpec, event_fields, time_unit_in_name
from evmotion.io.binary import position_in_block
from evmotion.io.guard import (
    LARGEST_COORDINATE,
    MAX_ABS_TIME_US,
    check_sensor_size,
    extended_size,
    sensor_size_hint,
    time_to_us,
)
from evmotion.io.pngfile import read_png
from evmotion.io.timedoubt import rate_doubt
from evmotion.jitcache import lazy_njit
from evmotion.utils import atomic_path, is_file

__all__ = ["read", "iter_chunks", "write", "describe", "read_calibration", "parse_text",
           "read_imu", "read_groundtruth", "read_image_list", "read_frames", "FORMAT"]

ECD_SENSOR_SIZE = (180, 240)
# the sensor size in a comment line of an events file (what write() puts there when the
# sensor is not the ECD's)
HEADER_SIZE = re.compile(r"height\s+(\d+)\s+width\s+(\d+)")
BLOCK_BYTES = 1 << 24
#: Largest text parsed without numba (see the module docstring).
PLAIN_TEXT_BYTES = 1 << 22
_PLAIN = np.zeros(256, bool)
_PLAIN[list(b"0123456789. \t\r\n")] = True

_ERR_COLUMNS = 1
_ERR_CHAR = 2
_ERR_FRACTION = 3  # a pixel or polarity with a non-zero fraction ("146.5")
_ERR_RANGE = 4  # a time past 2^62 us, which int64 arithmetic on it would wrap
# the most whole seconds a time may have (2^62 us: 146,000 years)
_MAX_SECONDS = MAX_ABS_TIME_US // 1_000_000


@lazy_njit(cache=True)
def _parse(buf, start, end, ox, oy, ot, op, out_start):
    """Parse whole lines of ``t x y p`` in ``buf[start:end]`` into the outputs from index
    ``out_start``. Returns (events written, byte offset of the bad line or -1, error code,
    columns seen on the bad line)."""
    i = start
    k = out_start
    nmax = ox.shape[0]
    while i < end and k < nmax:
        # one line
        col = 0
        ip = np.int64(0)
        nip = 0
        frac = np.int64(0)
        nfrac = 0
        in_frac = False
        val = np.int64(0)
        in_num = False
        neg = False
        # x, y, p written as decimals ("146.0", other tools' float columns): the point
        # and zeros after it are read, any other fraction refused
        vfrac = False
        line_start = i
        while i < end:
            c = buf[i]
            if c == 10:  # '\n'
                break
            if c >= 48 and c <= 57:
                d = c - 48
                if not in_num:
                    in_num = True
                if col == 0:
                    if in_frac:
                        if nfrac < 9:
                            frac = frac * 10 + d
                            nfrac += 1
                    elif nip < 15:  # (more digits would wrap int64: said below)
                        ip = ip * 10 + d
                        nip += 1
                    else:
                        ip = _MAX_SECONDS + 1
                elif vfrac:
                    if d != 0 and col <= 3:  # (extra columns: the count's error)
                        return k - out_start, line_start, _ERR_FRACTION, col
                else:
                    val = val * 10 + d
            elif c == 46 and col == 0 and in_num and not in_frac:  # '.'
                in_frac = True
            elif c == 46 and col > 0 and in_num and not vfrac:
                vfrac = True
            elif c == 45 and not in_num:  # '-'
                neg = True
                in_num = True
            elif c == 32 or c == 9 or c == 44 or c == 13:  # space, tab, comma, CR
                if in_num:
                    if col == 1:
                        ox[k] = -val if neg else val
                    elif col == 2:
                        oy[k] = -val if neg else val
                    elif col == 3:
                        op[k] = -val if neg else val
                    elif col == 0 and neg:
                        return k - out_start, line_start, _ERR_CHAR, col
                    col += 1
                    val = 0
                    in_num = False
                    neg = False
                    vfrac = False
            else:
                return k - out_start, line_start, _ERR_CHAR, col
            i += 1
        if in_num:
            if col == 1:
                ox[k] = -val if neg else val
            elif col == 2:
                oy[k] = -val if neg else val
            elif col == 3:
                op[k] = -val if neg else val
            col += 1
        i += 1  # past '\n'
        if col == 0:
            continue  # blank line
        if col != 4:
            return k - out_start, line_start, _ERR_COLUMNS, col
        if ip > _MAX_SECONDS:
            # (9300000000000 s wrapped to -9.1e18 us, accepted: probe AQ)
            return k - out_start, line_start, _ERR_RANGE, 0
        if nfrac <= 6:
            us = frac
            for _ in range(6 - nfrac):
                us *= 10
        else:
            scale = np.int64(1)
            for _ in range(nfrac - 6):
                scale *= 10
            us = (frac + scale // 2) // scale
        ot[k] = ip * 1_000_000 + us
        k += 1
    return k - out_start, -1, 0, 0


def _line_error(path: Path, data: bytes, file_offset: int, bad: int, code: int, cols: int
                ) -> FormatError:
    line_end = data.find(b"\n", bad)
    text = data[bad: line_end if line_end >= 0 else len(data)].decode("latin-1").strip()
    lineno = 1 + data.count(b"\n", 0, bad)
    if file_offset > 0:  # a chunk of a file: count the lines before it in the file
        with open(path, "rb") as fh:
            remaining = file_offset
            while remaining > 0:
                blk = fh.read(min(remaining, 1 << 24))
                if not blk:
                    break
                lineno += blk.count(b"\n")
                remaining -= len(blk)
    fields = text.replace(",", " ").replace(";", " ").split()
    if code == _ERR_RANGE:
        return FormatError(path, f"line {lineno}: t = {fields[0] if fields else '?'} s is "
                           f"beyond +-2^62 us ({text[:80]!r}): not a time in seconds "
                           "(another unit? --time-unit)")
    first_decimal = next((k for k, f in enumerate(fields) if "." in f), 0)
    if code == _ERR_FRACTION and first_decimal == 0:
        name = ("t", "x", "y", "p")[cols]
        value = fields[cols] if cols < len(fields) else "?"
        return FormatError(path, f"line {lineno}: {name} = {value} is not a whole number "
                           f"({text[:80]!r}); the text layout holds whole pixels and "
                           "polarities (sub-pixel, undistorted events: save them as .npy / "
                           ".h5 with float x, y)")
    numeric = all(re.fullmatch(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?", f) for f in fields)
    if code == _ERR_COLUMNS or (numeric and len(fields) != 4):
        n = cols if code == _ERR_COLUMNS else len(fields)
        msg = (f"line {lineno} has {n} column(s), expected 4 ('t x y p'): {text[:80]!r}; "
               "keep those four columns of the table")
    elif numeric and len(fields) == 4 and any(f.startswith("-") for f in fields):
        k = next(k for k, f in enumerate(fields) if f.startswith("-"))
        name = ("t", "x", "y", "p")[k]
        fix = ("times count up from a clock's zero: add an offset to the column"
               if k == 0 else "pixels and polarities are whole numbers from 0")
        msg = f"line {lineno}: {name} = {fields[k]} is negative ({text[:80]!r}); {fix}"
    else:
        msg = f"line {lineno} is not 't[s] x y p' numbers: {text[:80]!r}"
        if numeric and len(fields) == 4 and first_decimal != 0:
            return FormatError(path, msg, f"column {first_decimal + 1} holds decimals, the "
                               "time in seconds? Name the columns in a first line (e.g. "
                               "'x y t p')")
    return FormatError(path, msg)


def parse_text(data: bytes, path: str | Path = "<bytes>", file_offset: int = 0
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Parse ECD text (whole lines) into ``x, y, t[µs], p`` arrays.

    Examples
    --------
    >>> x, y, t, p = parse_text(b"0.000001 3 4 1\\n0.5 5 6 0\\n")
    >>> t.tolist(), x.tolist()
    ([1, 500000], [3, 5])
    """
    if len(data) <= PLAIN_TEXT_BYTES:
        plain = _parse_plain(data)
        if plain is not None:
            return plain
    buf = np.frombuffer(data, dtype=np.uint8)
    n_max = data.count(b"\n") + 1
    ox = np.empty(n_max, np.int64)
    oy = np.empty(n_max, np.int64)
    ot = np.empty(n_max, np.int64)
    op = np.empty(n_max, np.int64)
    n, bad, code, cols = _parse(buf, 0, buf.shape[0], ox, oy, ot, op, 0)
    if bad >= 0:
        if code == _ERR_CHAR and _EXPONENT.search(data):
            parsed = _parse_exponents(data)
            if parsed is not None:
                return parsed
        raise _line_error(Path(path), data, file_offset, bad, code, cols)
    return ox[:n], oy[:n], ot[:n], op[:n]


# a number in scientific notation, as numpy's savetxt writes every column by default
_EXPONENT = re.compile(rb"\d[eE][-+]?\d")


def _parse_exponents(data: bytes) -> tuple[np.ndarray, ...] | None:
    """``x, y, t[µs], p`` of lines of four numbers any of which may be in scientific
    notation (``1.418e-03 9.8e+01 4.2e+01 1``), through float64: times to the nearest
    µs (exact below ~10^9 s), pixels and polarities whole numbers. None where the text
    is not that (the kernel's error then names the line)."""
    lines = [ln.replace(b",", b" ").split() for ln in data.split(b"\n")]
    if any(len(ln) not in (0, 4) for ln in lines):
        return None
    try:
        table = np.array([v for ln in lines for v in ln], dtype=np.float64).reshape(-1, 4)
    except ValueError:
        return None
    t = table[:, 0] * 1e6
    xyp = table[:, 1:]
    if not (np.isfinite(table).all() and (np.abs(t) < MAX_ABS_TIME_US).all()
            and (t >= 0).all() and (xyp == np.rint(xyp)).all()
            # (1e30 cast to int64 with numpy's RuntimeWarning on stderr, then a negative
            # coordinate; probe CG: the kernel names the line instead)
            and (np.abs(xyp) < 2.0 ** 53).all()):
        return None
    ints = xyp.astype(np.int64)
    return (np.ascontiguousarray(ints[:, 0]), np.ascontiguousarray(ints[:, 1]),
            np.rint(t).astype(np.int64), np.ascontiguousarray(ints[:, 2]))


def _parse_plain(data: bytes) -> tuple[np.ndarray, ...] | None:
    """What :func:`_parse` gives for ``data``, by numpy: lines of four unsigned decimal
    integers (the first with at most one point and digits before it) or blank; None for
    any other text (the kernel then parses it, and reports the bad line)."""
    if not _PLAIN[np.frombuffer(data, dtype=np.uint8)].all():
        return None  # commas, signs, letters...: the kernel's cases
    lines = data.split(b"\n")  # only "\n" ends a line, as for the kernel
    if any(len(ln.split()) not in (0, 4) for ln in lines):
        return None
    tokens = data.split()
    if not tokens:
        return tuple(np.empty(0, np.int64) for _ in range(4))
    if max(map(len, tokens)) > 18:
        return None  # numbers that may not fit int64 (the kernel wraps them)
    ints = b" ".join(tokens[k] for k in range(len(tokens)) if k % 4)
    if b"." in ints:
        return None
    xyp = np.fromstring(ints, dtype=np.int64, sep=" ").reshape(-1, 3)
    whole, _, frac = np.strings.partition(np.array(tokens[0::4]), b".")
    if not (np.strings.str_len(whole) > 0).all() or np.strings.count(frac, b".").any():
        return None  # ".5" or "1.2.3"
    # the first 9 decimals, as the kernel keeps them, right-padded to nanoseconds; then
    # rounded to the nearest microsecond, halves up, exactly as the kernel rounds
    ns = np.strings.ljust(frac.astype("S9"), 9, b"0").astype(np.int64)
    seconds = whole.astype(np.int64)
    if seconds.size and seconds.max() > _MAX_SECONDS:
        return None  # the kernel names the line
    t = seconds * 1_000_000 + (ns + 500) // 1000
    return xyp[:, 0].copy(), xyp[:, 1].copy(), t, xyp[:, 2].copy()


def _events_file(path: Path) -> Path:
    if path.is_dir():
        f = path / "events.txt"
        if not f.exists():
            raise FormatError(path, "ECD folder has no events.txt")
        return f
    return path


def _image_size(folder: Path) -> tuple[int, int] | None:
    """Size of the first APS frame listed in ``images.txt`` (ECD frames share the sensor):
    from a PNG's header, other formats (JPEG, TIFF, BMP) decoded with OpenCV where it is
    installed."""
    from evmotion.errors import MissingDependencyError
    from evmotion.io.frames import frame_paths, image_size

    if not (folder / "images.txt").is_file():
        return None
    try:
        with warnings.catch_warnings():
            # only the files are needed here: their times' unit is said where the frames
            # are read
            warnings.simplefilter("ignore", EvmotionWarning)
            files = read_image_list(folder)["files"]
    except (FormatError, OSError, UnicodeDecodeError):
        return None  # reading the frames says what is wrong with the list
    first = frame_paths(folder, files[:1])[0] if files else None
    if first is None or not first.is_file():
        return None
    try:
        size = image_size(first)
    except (FormatError, MissingDependencyError):
        return None
    return check_sensor_size(first, size, "image size")


def _sensor_size(path: Path, sensor_size) -> tuple[tuple[int, int], str]:
    if sensor_size is not None:
        return (int(sensor_size[0]), int(sensor_size[1])), "given"
    folder = path if path.is_dir() else path.parent
    size = _image_size(folder)
    if size is not None:
        return size, "images"
    ev_path = _events_file(path)
    size = text_layout(ev_path)["size"]
    if size is not None:
        return check_sensor_size(ev_path, size, "header sensor size"), "header"
    return ECD_SENSOR_SIZE, "ECD default (DAVIS240C)"


def _blocks(path: Path, block_bytes: int, time_unit: str | None = "s",
            where: dict | None = None) -> Iterator[tuple[np.ndarray, ...]]:
    """Parsed blocks ``x, y, t [us], p`` of an events text file. ``time_unit`` is that of
    the first column: "s" (ECD), or "ms" / "us" / "ns" for whole numbers (other tools'
    exports); None sniffs it (:func:`sniff_time_unit`). ``where["bytes_read"]`` is set to
    the end of each block as it is yielded."""
    unit = sniff_time_unit(path) if time_unit is None else time_unit
    if unit not in TEXT_TIME_UNITS:
        raise ParameterError(f"time_unit must be one of {sorted(TEXT_TIME_UNITS)} (or None: "
                             f"from the text), got {time_unit!r}")
    layout = text_layout(path)
    order, offset = layout["order"], layout["offset"]
    with open(path, "rb") as fh:
        fh.seek(offset)
        carry = b""
        while True:
            blk = fh.read(block_bytes)
            data = carry + blk
            if not blk:
                if data.strip():
                    if where is not None:
                        where.update(block_start=offset, bytes_read=offset + len(data))
                    yield _parse_block(data, path, offset, unit, order)
                return
            cut = data.rfind(b"\n") + 1
            if cut == 0:
                carry = data
                continue
            if where is not None:
                where.update(block_start=offset, bytes_read=offset + cut)
            yield _parse_block(data[:cut], path, offset, unit, order)
            offset += cut
            carry = data[cut:]


# the time units of the first column of an events text file, in us per unit ("s": the
# ECD's decimal seconds, parsed exactly; the others whole numbers)
TEXT_TIME_UNITS = {"s": 1_000_000, "ms": 1_000, "us": 1, "ns": None}


def _times_us(tcol: np.ndarray, unit: str) -> np.ndarray:
    """The time column's text in ``unit`` as whole µs: whole numbers exactly, decimals
    (seconds, or another tool's decimal milliseconds) rounded to the µs."""
    if unit != "s":
        try:
            t = tcol.astype(np.int64)
        except ValueError:
            pass
        else:
            return (t + 500) // 1000 if unit == "ns" else t * TEXT_TIME_UNITS[unit]
    with np.errstate(all="ignore"):
        v = tcol.astype(np.float64)
        if unit == "ns" and v.size and (v != np.rint(v)).any():
            # decimal seconds read as ns all fell on 0 us ("30000 events spanning 0 us",
            # probe BD): no tool writes fractions of a nanosecond
            k = int(np.argmax(v != np.rint(v)))
            raise ValueError(f"a time of {tcol[k].decode()} is not a whole number of "
                             "nanoseconds: the times are in seconds? (leave out "
                             "--time-unit / time_unit)")
        if (unit == "us" and v.size and (v != np.rint(v)).any()
                and np.abs(v).max() < 1000):
            # decimal seconds read as µs fell on 0-1 us ("all at one time (0 us)", probe
            # BJ): fractions of a µs over less than a millisecond are no µs times
            k = int(np.argmax(v != np.rint(v)))
            raise ValueError(f"a time of {tcol[k].decode()} is not a whole number of "
                             "microseconds, and the times span under 1 ms as such: the "
                             "times are in seconds? (leave out --time-unit / time_unit)")
        t = np.rint(v * (TEXT_TIME_UNITS[unit] or 1e-3))
    if t.size and not np.all(np.abs(t) < 2.0**62):
        raise ValueError("a time beyond +-2^62 us")
    return t.astype(np.int64)


def _blank_comments(data: bytes) -> bytes:
    """``data`` with each line that starts with ``#`` (after spaces) turned into spaces
    of the same length: comments anywhere in a file, not only above its events (a
    comment line among them was 'not t[s] x y p numbers', probe BL); the offsets the
    errors name stay right.

    Examples
    --------
    >>> _blank_comments(b"1 2 3 1\\n# note\\n4 5 6 0\\n")
    b'1 2 3 1\\n      \\n4 5 6 0\\n'
    """
    if b"#" not in data:
        return data
    return re.sub(rb"(?m)^[ \t]*#[^\n]*", lambda m: b" " * len(m.group(0)), data)


def _parse_block(data: bytes, path: Path, offset: int, unit: str, order: str = "txyp"):
    data = _blank_comments(data)
    if unit == "s" and order == "txyp":
        return parse_text(data, path, offset)
    rows = data.replace(b",", b" ").replace(b";", b" ").split()
    cols = {k: order.index(k) for k in "txyp"}
    n_cols = len(order)
    try:
        lines = sum(1 for ln in data.split(b"\n") if ln.strip())
        if len(rows) != n_cols * lines:
            raise ValueError(f"not {n_cols} numbers a line, as the header names")
        table = np.array(rows, dtype="S32").reshape(-1, n_cols)
        xyp = table[:, [cols["x"], cols["y"], cols["p"]]].astype(np.int64)
        t = _times_us(table[:, cols["t"]], unit)
    except ValueError as exc:
        if order == "txyp":
            parse_text(data, path, offset)  # names the bad line, if not numbers at all
        raise FormatError(path, f"cannot read '{' '.join(order)}' numbers ({unit} in the "
                          f"time column) near byte {offset}: {exc}") from None
    return (np.ascontiguousarray(xyp[:, 0]), np.ascontiguousarray(xyp[:, 1]),
            np.ascontiguousarray(t), np.ascontiguousarray(xyp[:, 2]))


def sniff_time_unit(path: str | Path) -> str:
    """The unit of an events text file's time column: "s" (the ECD's decimal seconds) if
    a time among the first lines has a decimal point or exponent, else "us" (whole
    numbers: other tools' microseconds; a file of whole seconds does not occur), with a
    :class:`~evmotion.errors.TimeUnitGuessWarning` saying so.

    Examples
    --------
    >>> _ = Path("events.txt").write_text("0.000500 3 4 1\\n0.001000 5 6 0\\n")
    >>> sniff_time_unit("events.txt")
    's'
    """
    unit, note = _sniffed_unit(path)
    if note is not None:
        warnings.warn(TimeUnitGuessWarning(note), stacklevel=3)
    return unit


def _sniffed_unit(path: str | Path) -> tuple[str, str | None]:
    """:func:`sniff_time_unit`'s unit and its warning (None when it has none), for a
    reader to say once the columns are known to be read right: a Metavision CSV without
    its header had two warnings about times and sizes, then the refusal naming its column
    order, all three about the same misreading (probe CF)."""
    path = _events_file(Path(path))
    layout = text_layout(path)
    if layout["time_unit"] is not None:  # a header line named it (t_ns, timestamp_us...)
        # or the layout has one (Metavision's CSV)
        return layout["time_unit"], None
    col = layout["order"].index("t")
    with open(path, "rb") as fh:
        fh.seek(layout["offset"])
        head = fh.read(SNIFF_BYTES)
    lines = head.split(b"\n")[:-1] if len(head) == SNIFF_BYTES else head.split(b"\n")
    fields = [ln.replace(b",", b" ").replace(b";", b" ").split() for ln in lines]
    firsts = [f[col] for f in fields if len(f) > col]
    if not firsts or any(re.search(rb"[.eE]", f) for f in firsts):
        return "s", None
    order = layout["order"]
    if any(_FRACTION.fullmatch(v) for f in fields for k, v in enumerate(f)
           if k != col and k < len(order) and order[k] != "-"):
        # another column holds the decimals ('x y p t[s]' without a header): the parser
        # names that column; a warning about whole-number times would mislead (probe)
        return "us", None
    if all(f.lstrip(b"-").isdigit() for f in firsts) and int(firsts[0]) > NS_EPOCH_US:
        return "ns", (f"{path}: the times are whole numbers past 1e17, as microseconds "
                      "beyond the year 5000: read as nanoseconds since the epoch (other "
                      "units: time_unit=, or --time-unit)")
    ts = [int(f) for f in firsts if f.lstrip(b"-").isdigit()]
    span = ts[-1] - ts[0] if ts else 0
    ns_like = len(ts) >= 100 and span >= 100_000 and not any(v % 1000 for v in ts)
    # over MAX_EVENTS_PER_US (a readout of 1 G events/s) no sensor reads out
    ms_like = len(ts) >= 1000 and len(ts) > MAX_EVENTS_PER_US * (span + 1)
    hint = ""
    if ns_like:
        hint = ("; they are all multiples of 1000 (as µs, millisecond steps, which event "
                "cameras do not make): nanoseconds? every speed is 1000x too small otherwise")
    elif ms_like:
        hint = (f"; as µs the first {len(ts)} events span {span + 1} µs, faster than any "
                "sensor reads out: milliseconds? every speed is 1000x too large otherwise")
    return "us", (f"{path}: every time is a whole number: read as microseconds (ECD text "
                  "holds decimal seconds; other units: --time-unit, or time_unit= in "
                  "Python)" + hint)


MAX_EVENTS_PER_US = 1000
# a decimal with a non-zero fraction ("13.582595999"; not "146.0")
_FRACTION = re.compile(rb"[-+]?\d*\.\d*[1-9]\d*")


SNIFF_BYTES = 65_536  # the lines sniff_time_unit looks at


def _skip_comments(fh) -> tuple[int, list[bytes]]:
    """Past a UTF-8 byte-order mark and the comment lines (``#`` or ``%``) that open some
    tools' event text files: the offset after them, and the comments that begin in the
    first :data:`HEADER_BYTES` (where :func:`write`'s size line is looked for)."""
    pos = 3 if fh.read(3) == b"\xef\xbb\xbf" else 0
    fh.seek(pos)
    comments = []
    while True:
        line = fh.readline()
        if not line.lstrip(b" \t").startswith((b"#", b"%")):
            fh.seek(pos)
            return pos, comments
        if pos < HEADER_BYTES:
            comments.append(line)
        pos = fh.tell()


HEADER_BYTES = 4096


# Metavision's CSV export: '%geometry:W,H' (or '% geometry WxH')
METAVISION_GEOMETRY = re.compile(r"^\s*%\s*geometry\s*[:\s]\s*(\d+)\s*[,x]\s*(\d+)", re.I)


def _comment_size(comments: list[bytes]) -> tuple[int, int] | None:
    """``(height, width)`` a comment line states: :func:`write`'s ``# ... height H width W``
    or Metavision's ``%geometry:W,H``."""
    for c in comments:
        text = c.decode("ascii", "replace")
        m = HEADER_SIZE.search(text)
        if m:
            return int(m[1]), int(m[2])
        m = METAVISION_GEOMETRY.search(text)
        if m:
            return int(m[2]), int(m[1])
    return None


def _size_line(line: bytes) -> tuple[int, int] | None:
    """``(height, width)`` from a line of two whole numbers ``W H`` (the first line of
    the rpg / E2VID event text)."""
    fields = line.split()
    if len(fields) == 2 and all(f.isdigit() for f in fields):
        return int(fields[1]), int(fields[0])
    return None


# columns a header line may name: t, x, y, p and others read past
MAX_TEXT_COLUMNS = 16


def _names_line(line: bytes) -> str | None:
    """The column order (a permutation of "txyp") a line of column names states, if it is
    one: ``t,x,y,p``, ``timestamp x y polarity``, Metavision's ``x,y,p,t``, ``t_ns,x,y,p``
    (:func:`_names_and_unit` also gives the time unit such a name states)."""
    found = _names_and_unit(line)
    return None if found is None else found[0]


def _names_and_unit(line: bytes) -> tuple[str, str | None] | None:
    """``(order, time unit or None)`` of a line of column names, or None when it is not
    one."""
    try:
        text = line.decode().strip()
    except UnicodeDecodeError:
        return None
    # a comma-separated header keeps its empty names: pandas' to_csv writes its index as
    # a first column named '' (",t,x,y,p"), read past as any other column (probe BL)
    sep = r"\s*[,;]\s*" if re.search(r"[,;]", text) else r"\s+"
    fields = [f.lower() for f in re.split(sep, text)]
    if not 4 <= len(fields) <= MAX_TEXT_COLUMNS or \
            not all(re.fullmatch(r"[a-zµ_\[\]()][a-zµ_\[\]()0-9]*", f)
                    for f in fields if f):
        return None
    named = event_fields(fields)
    if named is None or len(set(named.values())) != 4:
        return None
    # a column of another name (a trigger, a camera id) is read past: "-" in the order
    order = "".join(next((k for k, n in named.items() if n == name), "-") for name in fields)
    return order, time_unit_in_name(named["t"])


def text_layout(path: str | Path) -> dict:
    """How an events text file is laid out: ``order`` of its columns ("txyp" for the
    ECD's ``t x y p``, "xypt" for Metavision's CSV export, told by its ``%geometry``
    comment, in µs; a header line of column names, or the last comment line holding
    them, states another, e.g. ``x,y,p,t`` or ``# x y p t``);
    ``size`` ``(height, width)`` when a comment line (``# ... height H width W``, as
    :func:`write` puts it) or a first line of two numbers ``W H`` (rpg / E2VID text)
    states it, else None; ``offset``, the byte where the events start (past a
    byte-order mark, comments and those lines); and ``time_unit``, the unit a column name
    states (``t_ns``, ``timestamp_us``, ``t[s]``), else None.

    Examples
    --------
    >>> _ = Path("events.txt").write_text("240 180\\n0.000500 3 4 1\\n")
    >>> text_layout("events.txt")
    {'order': 'txyp', 'size': (180, 240), 'offset': 8, 'time_unit': None}
    """
    path = _events_file(Path(path))
    with open(path, "rb") as fh:
        pos, comments = _skip_comments(fh)
        # Metavision's CSV export states its geometry in a comment and writes x,y,p,t
        metavision = any(METAVISION_GEOMETRY.search(c.decode("ascii", "replace"))
                         for c in comments)
        out = {"order": "xypt" if metavision else "txyp", "size": _comment_size(comments),
               "offset": pos, "time_unit": "us" if metavision else None}
        # the column names in the last comment line ('# x y p t'): the refusal had asked
        # for a first line naming them (probe AS)
        named = _names_and_unit(comments[-1].lstrip(b" \t#%")) if comments else None
        if named is not None:
            out["order"], out["time_unit"] = named
        for _ in range(2):
            line = fh.readline()
            size, names = _size_line(line), _names_and_unit(line)
            if size is not None:
                out["size"] = out["size"] or size
            elif names is not None:
                out["order"], out["time_unit"] = names
            else:
                break
            out["offset"] = fh.tell()
    return out


def _folder_meta(ev_path: Path) -> dict:
    """Calibration and companion files of the sequence folder, attached to every chunk."""
    folder = ev_path.parent
    meta: dict = {}
    if (folder / "calib.txt").is_file():
        try:
            meta["calibration"] = read_calibration(folder / "calib.txt")
        except FormatError as exc:
            # the events are read all the same (a garbage calib.txt stopped them, probe
            # BL); what needs intrinsics then says it has none
            warnings.warn(UnusedCalibrationWarning(f"{exc} (not used: no calibration "
                                                   "taken from the folder)"), stacklevel=4)
    for name in ("imu.txt", "groundtruth.txt", "images.txt"):
        if (folder / name).is_file():
            meta[name.removesuffix(".txt")] = str(folder / name)
    return meta


def _order_hint(t, x, y, p) -> str | None:
    """When the columns read as ``t x y p`` look like another order (a Metavision CSV is
    ``x,y,p,t``): the order they look like and how to state it, else None. A time column
    never decreases and varies; a polarity column holds only -1, 0 and 1."""
    cols = {"t": np.asarray(t), "x": np.asarray(x), "y": np.asarray(y), "p": np.asarray(p)}
    as_read = ["t", "x", "y", "p"]
    times = [k for k in as_read if cols[k].size > 1 and np.all(np.diff(cols[k]) >= 0)
             and cols[k][-1] > cols[k][0]]
    pols = [k for k in as_read if np.isin(cols[k], (-1, 0, 1)).all()]
    if len(times) != 1 or len(pols) != 1 or (times[0], pols[0]) == ("t", "p"):
        return None
    xy = iter(("x", "y"))  # the other two columns, x first
    order = ["t" if k == times[0] else "p" if k == pols[0] else next(xy) for k in as_read]
    return (f"the columns look like '{' '.join(order)}', not ECD's 't x y p': a first line "
            f"naming them ({','.join(order)}) reads the file so")


def _event_line(path: Path, k: int) -> int | None:
    """The line number (from 1) of the file's ``k``-th event (from 0), counting the
    non-blank lines after its header; None where the file cannot be read again."""
    try:
        start = text_layout(path)["offset"]
        with open(path, "rb") as fh:
            line = fh.read(start).count(b"\n")
            for raw in fh:
                line += 1
                if raw.strip():
                    if k == 0:
                        return line
                    k -= 1
    except OSError:
        return None
    return None


def _which_event(path: Path, k: int, whole: bool) -> str:
    """The ``k``-th event named in a message: by its line where the events are the
    ``whole`` file's, by its place otherwise."""
    line = _event_line(path, k) if whole else None
    return f"event {k}" if line is None else f"line {line}: the event"


def _column_error(path: Path, t, x, y, p, whole: bool) -> FormatError | None:
    """The refusal of a polarity outside -1..1 or a coordinate no sensor has (outside
    0..65535), naming the column order the columns look like (:func:`_order_hint`), or
    None: said before the warnings about the times and sizes such columns give."""
    if x.size == 0:
        return None
    if x.min() < 0 or y.min() < 0:
        bad = int(np.argmax((x < 0) | (y < 0)))
        return FormatError(path, f"{_which_event(path, bad, whole)} has a negative pixel "
                           f"coordinate: x={x[bad]}, y={y[bad]}")
    if max(x.max(), y.max()) > MAX_COORDINATE:
        bad = int(np.argmax((x > MAX_COORDINATE) | (y > MAX_COORDINATE)))
        return FormatError(path, f"{_which_event(path, bad, whole)} at x={x[bad]}, "
                           f"y={y[bad]} lies outside any sensor (coordinates 0.."
                           f"{MAX_COORDINATE})", _order_hint(t, x, y, p))
    if p.min() < -1 or p.max() > 1:
        bad = int(np.argmax((p < -1) | (p > 1)))
        return FormatError(path, f"{_which_event(path, bad, whole)} has polarity "
                           f"p={p[bad]}, expected 0/1 or -1/+1", _order_hint(t, x, y, p))
    return None


MAX_COORDINATE = 65535  # events hold uint16 coordinates


def _to_events(path: Path, x, y, t, p, size, size_src, validate: bool,
               extra: dict | None = None, streamed: bool = False,
               whole: bool = False) -> EventArray:
    """The parsed columns as an EventArray, what no sensor records refused naming the
    event: its line where they are the ``whole`` file's events, its place otherwise."""
    def which(k: int) -> str:
        return _which_event(path, k, whole)

    h, w = size
    if x.size:
        if x.min() < 0 or y.min() < 0:
            raise _column_error(path, t, x, y, p, whole)
        if x.max() >= w or y.max() >= h:
            bad = int(np.argmax((x >= w) | (y >= h)))
            raise FormatError(path, f"{which(bad)} at x={x[bad]}, y={y[bad]} lies outside the "
                              f"sensor {w}x{h} (W x H, {size_src})",
                              _order_hint(t, x, y, p) or sensor_size_hint(size_src == "given"))
        bad_polarity = _column_error(path, t, x, y, p, whole)
        if bad_polarity is not None:
            raise bad_polarity
        odd = ambiguous_polarity(p)
        if odd is not None:
            raise FormatError(path, odd)
    meta = {"source": str(path), "format": "ecd", "sensor_size_from": size_src, **(extra or {})}
    try:
        return EventArray(x=x.astype(np.uint16), y=y.astype(np.uint16), t=t,
                          p=(p > 0).astype(np.uint8), sensor_size=size, validate=validate,
                          meta=meta)
    except UnsortedError as exc:
        if streamed:
            raise  # the guard names the file, and the event by its place in it
        raise FormatError(path, str(exc)) from None
    except Exception as exc:
        raise FormatError(path, str(exc)) from None


def read(path: str | Path, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, validate: bool = True,
         block_bytes: int = BLOCK_BYTES, time_unit: str | None = None) -> EventArray:
    """Read ECD events (``events.txt`` or a folder holding one).

    Parameters
    ----------
    path : path-like
        ``events.txt`` or an ECD sequence folder.
    t0, t1 : int, optional
        Keep events with ``t0 <= t < t1`` (µs).
    sensor_size : (int, int), optional
        ``(height, width)``; default from the APS images, else 180x240 (DAVIS240C).
    validate : bool
        Check sortedness and bounds.
    time_unit : {"s", "ms", "us", "ns"}, optional
        Unit of the first column: decimal seconds (ECD) or whole numbers of ms, us or ns
        (other tools' exports); default from the text (:func:`sniff_time_unit`).

    Returns
    -------
    EventArray
        ``meta["sensor_size_from"]`` says where the sensor size came from;
        ``meta["calibration"]`` holds ``calib.txt`` when the folder has one, and
        ``meta["imu"]``, ``["groundtruth"]``, ``["images"]`` the companion files' paths.

    Examples
    --------
    >>> write("shapes_rotation/events.txt", EventArray(
    ...     x=[3, 5], y=[4, 6], t=[500, 1_000], p=[1, 0], sensor_size=(180, 240)))
    >>> ev = read("shapes_rotation/")
    >>> len(ev), ev.sensor_size, ev.t.tolist()
    (2, (180, 240), [500, 1000])
    """
    path = Path(path)
    ev_path = _events_file(path)
    size, src = _sensor_size(path, sensor_size)
    unit, note = _sniffed_unit(ev_path) if time_unit is None else (time_unit, None)
    parts = []
    for x, y, t, p in _blocks(ev_path, block_bytes, unit):
        if t0 is not None or t1 is not None:
            m = np.ones(t.shape, bool)
            if t0 is not None:
                m &= t >= t0
            if t1 is not None:
                m &= t < t1
            x, y, t, p = x[m], y[m], t[m], p[m]
        parts.append((x, y, t, p))
    if parts:
        x, y, t, p = (np.concatenate([q[i] for q in parts]) for i in range(4))
    else:
        x = y = t = p = np.zeros(0, np.int64)
    whole = t0 is None and t1 is None
    misread = _column_error(ev_path, t, x, y, p, whole)
    if misread is not None:
        raise misread  # before the warnings about times and sizes read from wrong columns
    if note is not None:
        warnings.warn(TimeUnitGuessWarning(note), stacklevel=2)
    if src.startswith("ECD default") and x.size and x.min() >= 0 and y.min() >= 0:
        size, src = _extended_size(ev_path, size, src, int(x.max()), int(y.max()))
    _doubt_unit(ev_path, t, x, y, size, unit, given=time_unit is not None)
    # the unit the times were read in: a span that slips by 1000x against the frames'
    # names the next smaller one (BOS, probe CC)
    return _to_events(ev_path, x, y, t, p, size, src, validate,
                      {**_folder_meta(ev_path), "time_unit": unit}, whole=whole)


def _doubt_unit(path: Path, t_us: np.ndarray, x: np.ndarray, y: np.ndarray,
                sensor_size: tuple[int, int], unit: str, given: bool) -> None:
    """Warn where the sniffed or ``given`` ``unit`` gives the times (``t_us``, µs) of
    events at ``x, y`` a rate no event camera makes
    (:func:`~evmotion.io.timedoubt.rate_doubt`): decimal milliseconds read as seconds,
    nanoseconds not on whole µs read as µs (those on whole µs the sniffer names
    itself)."""
    doubt = rate_doubt(t_us, x, y, sensor_size,
                       f"{unit} ({'given' if given else 'inferred'})", given=given)
    if doubt is not None:
        warnings.warn(EvmotionWarning(f"{path}: the time column {doubt}"), stacklevel=4)


def _extended_size(ev_path: Path, size, src: str, x_max: int, y_max: int):
    """Text from another sensor, its size stated nowhere: ``(size, src)`` of
    :func:`evmotion.io.guard.extended_size`, unchanged when the events fit the ECD's."""
    wider = extended_size(ev_path, size, x_max, y_max, ", events beyond the ECD's 240x180")
    return (size, src) if wider is None else (wider, LARGEST_COORDINATE)


# a text file without a sensor size is scanned once for its largest coordinates before
# it is streamed, up to this size (beyond, events outside 240x180 are refused)
PRESCAN_BYTES = 1 << 29


def iter_chunks(path: str | Path, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, validate: bool = True,
                block_bytes: int = BLOCK_BYTES, time_unit: str | None = None
                ) -> Iterator[EventArray]:
    """Stream ECD events in chunks of ``chunk_events`` (the last may be shorter).

    Examples
    --------
    >>> write("events.txt", EventArray(x=[1, 2, 3], y=[0, 0, 0], t=[10, 20, 30],
    ...                                p=[1, 0, 1], sensor_size=(180, 240)))
    >>> for chunk in iter_chunks("events.txt", 2):
    ...     print(len(chunk))
    2
    1
    """
    if int(chunk_events) <= 0:
        raise ParameterError(f"chunk_events must be positive, got {chunk_events}")
    path = Path(path)
    ev_path = _events_file(path)
    size, src = _sensor_size(path, sensor_size)
    unit, note = _sniffed_unit(ev_path) if time_unit is None else (time_unit, None)
    if src.startswith("ECD default") and ev_path.stat().st_size <= PRESCAN_BYTES:
        # the chunks must share one sensor size: the whole file's, as read() finds it
        x_max = y_max = -1
        for x, y, t, p in _blocks(ev_path, block_bytes, unit):
            misread = _column_error(ev_path, t, x, y, p, whole=False)
            if misread is not None:
                raise misread  # before the warnings about columns misread
            if x.size and x.min() >= 0 and y.min() >= 0:
                x_max, y_max = max(x_max, int(x.max())), max(y_max, int(y.max()))
        size, src = _extended_size(ev_path, size, src, x_max, y_max)
    extra = _folder_meta(ev_path)
    # how far into the file each chunk is, for a progress bar's ETA (the text states no
    # event count): the end of the block it came from
    file_bytes = ev_path.stat().st_size
    where = {"block_start": 0, "bytes_read": 0}
    buf = [np.zeros(0, np.int64)] * 4
    last_t = None
    signs = _PolaritySigns(ev_path)
    for block in _blocks(ev_path, block_bytes, unit, where):
        signs.check(block[3])
        buf = [np.concatenate([a, b]) for a, b in zip(buf, block, strict=True)]
        while buf[2].size >= chunk_events:
            part = [a[:chunk_events] for a in buf]
            buf = [a[chunk_events:] for a in buf]
            at = position_in_block(where["block_start"], where["bytes_read"], buf[2].size,
                                   block[2].size)
            ev = _to_events(ev_path, *part, size, src, validate,
                            {**extra, "bytes_read": at, "file_bytes": file_bytes},
                            streamed=True)
            note = _say(note)
            if validate:
                check_follows(last_t, ev)
            if last_t is None:
                _doubt_unit(ev_path, ev.t, ev.x, ev.y, size, unit,
                            given=time_unit is not None)
            last_t = int(ev.t[-1])
            yield ev
    if buf[2].size:
        ev = _to_events(ev_path, *buf, size, src, validate,
                        {**extra, "bytes_read": where["bytes_read"], "file_bytes": file_bytes},
                        streamed=True)
        _say(note)
        if validate:
            check_follows(last_t, ev)
        if last_t is None:
            _doubt_unit(ev_path, ev.t, ev.x, ev.y, size, unit, given=time_unit is not None)
        yield ev


def _say(note: str | None) -> None:
    """Warn ``note`` (a reader's deferred guess of the time unit) when there is one;
    None, said."""
    if note is not None:
        warnings.warn(TimeUnitGuessWarning(note), stacklevel=4)


class _PolaritySigns:
    """The polarity values a streamed file has shown so far: -1 in one part and 0 in
    another is refused as :func:`~evmotion.events.ambiguous_polarity` refuses them in one
    array (checked chunk by chunk, a file of -1/+1 then 0/1 was read whole; probe BR)."""

    def __init__(self, path: Path):
        self.path, self.negative, self.zero, self.seen = path, None, None, 0

    def check(self, p: np.ndarray) -> None:
        if p.size:
            if self.negative is None and p.min() == -1:
                self.negative = self.seen + int(np.argmax(p == -1))
            if self.zero is None and (p == 0).any():
                self.zero = self.seen + int(np.argmax(p == 0))
        self.seen += p.size
        if self.negative is not None and self.zero is not None:
            raise FormatError(self.path, f"field 'p' holds -1 (event {self.negative}) and 0 "
                              f"(event {self.zero}): neither 0/1 nor -1/+1; map each value "
                              "to 0 (OFF) or 1 (ON) first")


@lazy_njit(cache=True)
def _put_uint(buf, pos, v):
    if v == 0:
        buf[pos] = 48
        return pos + 1
    n = 0
    w = v
    while w > 0:
        w //= 10
        n += 1
    for i in range(n - 1, -1, -1):
        buf[pos + i] = 48 + v % 10
        v //= 10
    return pos + n


@lazy_njit(cache=True)
def _format(x, y, t, p, buf):
    pos = 0
    for i in range(t.shape[0]):
        sec = t[i] // 1_000_000
        us = t[i] - sec * 1_000_000
        pos = _put_uint(buf, pos, sec)
        buf[pos] = 46  # '.'
        for j in range(5, -1, -1):
            buf[pos + 1 + j] = 48 + us % 10
            us //= 10
        buf[pos + 7] = 32
        pos = _put_uint(buf, pos + 8, np.int64(x[i]))
        buf[pos] = 32
        pos = _put_uint(buf, pos + 1, np.int64(y[i]))
        buf[pos] = 32
        buf[pos + 1] = 48 + p[i]
        buf[pos + 2] = 10
        pos += 3
    return pos


def format_text(events: EventArray) -> bytes:
    """ECD text for ``events``: ``t`` in seconds with 6 decimals (exact µs), integer x, y, p.

    Examples
    --------
    >>> ev = EventArray(x=[3], y=[4], t=[1_500_000], p=[1], sensor_size=(10, 10))
    >>> format_text(ev)
    b'1.500000 3 4 1\\n'
    """
    if events.x.dtype.kind == "f":
        raise ParameterError("ECD text holds integer pixel coordinates; these events are "
                             "undistorted (float x, y): write them to .h5 or .npz instead")
    if len(events) and events.t[0] < 0:
        raise ParameterError(f"ECD text needs non-negative times, got t={events.t[0]} us")
    buf = np.empty(len(events) * 48, np.uint8)
    n = _format(events.x, events.y, events.t, events.p, buf)
    return buf[:n].tobytes()


def write(path: str | Path, events: EventArray | Iterator[EventArray], *,
          header: bool = True) -> None:
    """Write ECD ``events.txt`` (atomically); accepts one EventArray or an iterable of
    chunks (streamed). A folder path gets ``events.txt`` inside it. A sensor other than
    the ECD's 240x180 is stated in a first comment line (``# ... sensor height H width
    W``), which :func:`read` takes its size from, unless ``header`` is False (a folder
    whose frames give the size, for tools that read the lines as numbers only).

    Examples
    --------
    >>> ev = EventArray(x=[3, 5], y=[4, 6], t=[500, 1_000], p=[1, 0], sensor_size=(8, 8))
    >>> write("out/events.txt", ev)
    >>> print(Path("out/events.txt").read_text(), end="")
    # evmotion ECD text: t[s] x y p; sensor height 8 width 8
    0.000500 3 4 1
    0.001000 5 6 0
    """
    path = _in_folder(path, "events.txt")
    chunks = [events] if isinstance(events, EventArray) else events
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            for k, ev in enumerate(chunks):
                if k == 0 and header and (tuple(ev.sensor_size) != ECD_SENSOR_SIZE
                                          or len(ev) == 0):
                    # ECD text has no header; a comment line (which ECD readers skip)
                    # keeps the sensor size for reading back, and an empty recording
                    # from an empty file (which reads as a mistake)
                    h, w = ev.sensor_size
                    fh.write(f"# evmotion ECD text: t[s] x y p; sensor height {h} width "
                             f"{w}\n".encode())
                try:
                    for s in range(0, len(ev), 200_000):
                        fh.write(format_text(ev[s:s + 200_000]))
                except ParameterError as exc:
                    # (the file was not named, probe BL)
                    raise ParameterError(f"cannot write {path}: {exc}") from None


def _in_folder(path: str | Path, name: str) -> Path:
    """``path``, or ``path / name`` when ``path`` is a folder."""
    path = Path(path)
    return path / name if path.is_dir() else path


def _to_read(path: str | Path, name: str) -> Path:
    """:func:`_in_folder`, refused when it is there but no regular file (a link to
    /dev/zero was read until memory ran out, probe AO)."""
    path = _in_folder(path, name)
    if path.exists() and not is_file(path):
        raise FormatError(path, "not a regular file")
    return path


def _load_table(path: str | Path, name: str, columns: str) -> tuple[np.ndarray, np.ndarray]:
    """``(t µs, table)`` of the text table ``path`` (``path / name`` for a folder), one row
    of the space-separated ``columns`` (time in s first) per line."""
    path = _to_read(path, name)
    ncols = len(columns.split())
    what = f"{name} ({columns})"
    try:
        arr = np.loadtxt(path, ndmin=2, comments="#")
    except ValueError as exc:
        raise FormatError(path, f"cannot parse {what}: {exc}") from None
    if arr.size and arr.shape[1] != ncols:
        raise FormatError(path, f"{what} has {arr.shape[1]} columns, expected {ncols}")
    return np.rint(arr[:, 0] * 1e6).astype(np.int64), arr


def read_imu(path: str | Path) -> dict:
    """ECD ``imu.txt``: returns ``t`` (µs int64), ``accel`` (N,3) m/s², ``gyro`` (N,3) rad/s."""
    t, a = _load_table(path, "imu.txt", "t ax ay az gx gy gz")
    return {"t": t, "accel": a[:, 1:4], "gyro": a[:, 4:7]}


def read_groundtruth(path: str | Path) -> dict:
    """ECD ``groundtruth.txt``: ``t`` (µs), ``position`` (N,3) m, ``quaternion`` (N,4)
    ``qx qy qz qw``."""
    t, a = _load_table(path, "groundtruth.txt", "t px py pz qx qy qz qw")
    return {"t": t, "position": a[:, 1:4], "quaternion": a[:, 4:8]}


def read_image_list(path: str | Path, time_unit: str | None = None) -> dict:
    """ECD ``images.txt``: ``t`` (µs), ``files`` (paths relative to the folder),
    ``whole_numbers`` (whether its times were whole numbers, which state no unit) and
    ``unit`` (the unit its header line names, else None).

    Lines are ``t path`` (t in seconds; a comma after t is taken as a space); lines
    starting with ``#`` are comments. Other tools' variants are read where the file they
    name exists: a path with spaces, Windows separators (``images\\x.png``), further
    columns after the path (an exposure, say), ``path t`` lines, a first line of column
    names (whose unit, as in ``timestamp[ms]``, reads the times). ``time_unit`` (``"s"``,
    ``"ms"``, ``"us"``, ``"ns"``) reads every time in that unit; without it (or a header's),
    times that are all whole numbers state no unit and are read as µs (ns past 1e17) with a
    warning; decimal times are seconds.

    Examples
    --------
    >>> import os
    >>> os.makedirs("lst", exist_ok=True)
    >>> _ = Path("lst/a.png").write_bytes(b""), Path("lst/b.png").write_bytes(b"")
    >>> _ = Path("lst/images.txt").write_text("timestamp[ms] file\\n0 a.png\\n10 b.png\\n")
    >>> read_image_list("lst/images.txt")["t"].tolist()
    [0, 10000]
    >>> _ = Path("lst/images.txt").write_text("a.png 0.0\\nb.png 0.01\\n")
    >>> read_image_list("lst/images.txt")["files"]
    ['a.png', 'b.png']
    """
    if time_unit is not None and time_unit not in TEXT_TIME_UNITS:
        raise ParameterError(f"time_unit must be one of {sorted(TEXT_TIME_UNITS)}, got "
                             f"{time_unit!r}")
    path = _to_read(path, "images.txt")
    folder = path.parent
    raw, files, first, stated = [], [], True, None
    with open(path, encoding="utf-8-sig") as fh:
        for i, line in enumerate(fh, 1):
            text = line.strip()
            if not text or text.startswith("#"):
                continue
            fields = re.split(r"[\s,]+", text, maxsplit=1)
            if len(fields) != 2:
                raise FormatError(path, f"line {i}: expected 't file', got {text!r}")
            if first and _COLUMN_NAME.fullmatch(fields[0]) and \
                    _listed_path(folder, fields[0]) is None:
                # a header line ("timestamp filename", "t[ms],file"); only the first line
                # (every 'path t' line had been skipped as one, probe BOSIN)
                stated = _header_unit(text)
                first = False
                continue
            first = False
            t_field, rest = _time_first(folder, fields)
            raw.append((i, t_field))
            files.append(_listed_file(folder, rest, path, i, text))
    # as events.txt: whole numbers are microseconds (frames a second or more apart in
    # whole seconds is no rate a camera beside an event sensor runs at)
    whole = len(raw) > 1 and all(f.lstrip("+-").isdigit() for _, f in raw) and not stated
    time_unit = time_unit or stated
    scale = 1e6
    if time_unit is not None:
        # every time, decimals too (--frames-time-unit ms had been ignored for "10.000",
        # the refusal that named it repeated, probe BOSIN)
        scale = TIME_UNIT_US[time_unit]
    elif whole:
        # past 1e17, nanoseconds since the epoch, as events.txt and timestamps files read
        # them (probe AM: images.txt in ns beside events.txt in ns was 1000x apart)
        ns = int(raw[0][1]) > NS_EPOCH_US
        scale = 1e-3 if ns else 1.0
        warnings.warn(TimeUnitGuessWarning(
            f"{path}: every time is a whole number: read as "
            f"{'nanoseconds since the epoch (past 1e17)' if ns else 'microseconds'} "
            "(images.txt holds decimal seconds)"), stacklevel=2)
    t = [time_to_us(path, f, scale, f"line {i}") for i, f in raw]
    return {"t": np.asarray(t, np.int64), "files": files, "whole_numbers": whole,
            "unit": stated}


def _header_unit(text: str) -> str | None:
    """The time unit a header line of ``images.txt`` names (``timestamp[ms] file``,
    ``t_us,path``, ``timestamp [ns] filename``), else None."""
    first = re.split(r"[\s,]+", text.lower())
    for cand in (first[0], "".join(first[:2])):
        unit = time_unit_in_name(cand.replace("µs", "us"))
        if unit is not None:
            return unit
    return None


def _time_first(folder: Path, fields: list[str]) -> tuple[str, str]:
    """A line's time field and the rest (its file), for ``t path`` lines and ``path t``
    ones (the file first, a single number after it)."""
    rest = fields[1].strip()
    if not _is_number(fields[0]) and _is_number(rest) \
            and _listed_path(folder, fields[0]) is not None:
        return rest, fields[0]
    return fields[0], rest


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _listed_path(folder: Path, name: str) -> str | None:
    """``name`` as an existing file of ``folder`` (Windows separators read as ``/``)."""
    for cand in (name, name.replace("\\", "/")):
        if is_file(folder / cand):
            return cand
    return None


# the first field of a header line: a name, not a number's spelling (nan, inf: a bad time)
_COLUMN_NAME = re.compile(r"(?!(?i:[-+]?(nan|inf|infinity))$)[A-Za-z_][\w\[\]()./-]*")


def _listed_file(folder: Path, rest: str, path: Path, i: int, text: str) -> str:
    """The file a line of ``images.txt`` names after its time: the longest start of the
    rest of the line that is an existing file (a name may hold spaces; further columns are
    ignored), with Windows separators read as ``/`` where that finds the file."""
    words = rest.split()
    for cand in (rest, *(" ".join(words[:k]) for k in range(len(words) - 1, 0, -1))):
        name = _listed_path(folder, cand)
        if name is not None:
            return name
    if len(words) != 1:
        raise FormatError(path, f"line {i}: expected 't file', got {text!r} (no "
                          f"file {rest!r} nor {words[0]!r} in {folder})")
    return words[0].replace("\\", "/")


def read_frames(path: str | Path) -> dict:
    """APS frames of an ECD folder (``images.txt`` + PNGs): ``t`` (N,) µs and ``images``
    (N, H, W) uint8 (colour PNGs are converted to grey by their mean)."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    if not (folder / "images.txt").exists():
        # (probe OPT: an ECD events file given as frames said only "[Errno 2] No such file
        # or directory: '.../images.txt'")
        raise FormatError(path, "ECD events, no frames: no images.txt beside them")
    lst = read_image_list(folder)
    images = []
    for name in lst["files"]:
        img, info = read_png(folder / name, what="cannot read frame listed in images.txt")
        if info.get("bitdepth", 8) > 8:
            img = img >> (info["bitdepth"] - 8)
        planes = img.shape[2]
        grey = img[..., 0] if planes <= 2 else img[..., :3].mean(axis=2)
        images.append(np.asarray(grey, dtype=np.uint8))
    stack = np.stack(images) if images else np.zeros((0, *ECD_SENSOR_SIZE), np.uint8)
    return {"t": lst["t"], "images": stack}


def calib_file(path: str | Path) -> Path:
    """``path``, or the ``calib.txt`` in it when ``path`` is an ECD folder."""
    return _in_folder(path, "calib.txt")


def parse_calib(path: Path) -> np.ndarray:
    """The 9 numbers ``fx fy cx cy k1 k2 p1 p2 k3`` of an ECD ``calib.txt`` (float64),
    which may also hold just the first 4 to 8 (the missing coefficients are 0), or a 3x3
    camera matrix ``fx 0 cx / 0 fy cy / 0 0 1`` (no distortion), as other tools write K.

    Raises FormatError naming the file and the offending value or count.

    Examples
    --------
    >>> _ = Path("K.txt").write_text("199.1 0 132.2\\n0 198.8 110.7\\n0 0 1\\n")
    >>> parse_calib(Path("K.txt"))[:5].tolist()
    [199.1, 198.8, 132.2, 110.7, 0.0]
    """
    try:
        # (a "# fx fy cx cy ..." line naming the numbers was refused as no number, probe)
        text = "\n".join(line for line in path.read_text(errors="replace").splitlines()
                         if not line.lstrip().startswith(("#", "%")))
        vals = np.array(text.replace(",", " ").split(), dtype=np.float64)
    except ValueError as exc:
        raise FormatError(path, f"calib.txt must hold numbers: {exc}") from None
    if vals.size == 9 and vals[1] == 0 and vals[3] == 0 and vals[6:].tolist() == [0, 0, 1]:
        # (read as fx fy cx cy k1..., a 3x3 K was refused for its focal length fy = 0,
        # probe AR)
        return np.array([vals[0], vals[4], vals[2], vals[5], 0, 0, 0, 0, 0], np.float64)
    if not 4 <= vals.size <= 9:
        raise FormatError(path, f"calib.txt holds {vals.size} numbers, expected fx fy cx cy "
                          "and up to 5 radial-tangential coefficients (k1 k2 p1 p2 k3), or a "
                          "3x3 camera matrix; models of more coefficients are not supported")
    return np.concatenate([vals, np.zeros(9 - vals.size)])


def read_calibration(path: str | Path) -> dict:
    """ECD ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``, or just the first four).

    Returns
    -------
    dict
        ``K`` (3x3 list), ``dist`` ``[k1, k2, p1, p2, k3]`` (radial-tangential),
        ``fx, fy, cx, cy``, ``model``, ``source``.

    Examples
    --------
    >>> Path("boxes_rotation").mkdir(exist_ok=True)
    >>> _ = Path("boxes_rotation/calib.txt").write_text(
    ...     "199.092366542 198.82882047 132.192071378 110.712660011 "
    ...     "-0.368436311798 0.150947243557 -0.000296130534385 -0.000759431726241 0.0\\n")
    >>> cal = read_calibration("boxes_rotation/calib.txt")
    >>> cal["fx"], cal["dist"][:2]
    (199.092366542, [-0.368436311798, 0.150947243557])
    """
    path = calib_file(path)
    if not path.exists():
        raise FormatError(path, "calibration file not found")
    vals = parse_calib(path)
    fx, fy, cx, cy = vals[:4].tolist()
    dist = vals[4:].tolist()
    out = {"fx": fx, "fy": fy, "cx": cx, "cy": cy,
           "K": [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], "dist": dist,
           "model": "radtan", "source": str(path)}
    size = _image_size(path.parent)
    if size is not None:
        out["sensor_size"] = size
    return out


# the columns of the ECD's companion tables (images.txt's paths may hold spaces)
_COMPANION_COLUMNS = {"imu.txt": 7, "groundtruth.txt": 8}


def describe(path: str | Path) -> dict:
    """What an ECD folder holds besides events (calibration, IMU, ground truth, frames)."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    size, src = _sensor_size(path, None)
    out: dict = {"format": "ecd", "sensor_size": size, "sensor_size_from": src}
    if (folder / "calib.txt").exists():
        try:
            out["calibration"] = read_calibration(folder / "calib.txt")
        except FormatError as exc:
            # said beside the rest, as the events' reader warns and reads on (a garbage
            # calib.txt had hidden the events and frames of the folder, probe BOSIN)
            out["calibration_error"] = exc.message
    for name, key in (("imu.txt", "imu"), ("groundtruth.txt", "groundtruth"),
                      ("images.txt", "frames")):
        f = folder / name
        if f.exists():
            f = _to_read(f, name)
            count, first = 0, None
            with open(f, "rb") as fh:  # counted, not held: an IMU logs thousands a second
                for line in fh:
                    if line.strip() and not line.startswith(b"#"):
                        count += 1
                        first = line if first is None else first
            out[key] = count
            want = _COMPANION_COLUMNS.get(name)
            got = len(first.replace(b",", b" ").split()) if first is not None else want
            if want is not None and got != want:
                # counted as samples that convert then dropped as unreadable (probe BL)
                out[key] = 0
                out[f"{key}_error"] = f"{name} has {got} columns, expected {want}"
    if "frames" not in out:
        # Loose PNGs are not ECD frames (no timestamps); count them but do not size from them.
        out["frames"] = 0
        n_png = len(list(folder.glob("*.png")))
        if n_png:
            out["images_without_timestamps"] = n_png
    return out


def _sniff(path: Path, head: bytes) -> bool:
    if path.is_dir():
        return (path / "events.txt").is_file()
    lines = [ln.strip() for ln in head.removeprefix(b"\xef\xbb\xbf").split(b"\n")
             if not ln.lstrip().startswith((b"#", b"%"))]
    if not any(lines) and head.startswith(b"# evmotion ECD text"):
        return True  # an empty recording written by :func:`write`
    for _ in range(2):
        if lines and (_size_line(lines[0]) is not None or _names_line(lines[0]) is not None):
            lines = lines[1:]
    parts = (lines[0] if lines else b"").replace(b",", b" ").replace(b";", b" ").split()
    if len(parts) < 4:
        return False
    try:
        [float(v) for v in parts]
    except ValueError:
        return False
    # a table of numbers: ECD's 't x y p', or columns in another order or more of them,
    # which the reader then names (rather than "format not recognised")
    return True


FORMAT = FormatSpec(name="ecd", extensions=(".txt", ".csv"), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
