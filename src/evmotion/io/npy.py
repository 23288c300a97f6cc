"""NumPy event files: structured ``.npy`` (fields x, y, t, p, as tonic writes), plain
``N×4`` arrays, and ``.npz`` archives with arrays ``x, y, t, p`` (+ ``sensor_size``, or
``height`` and ``width``, or ``resolution`` as (width, height)).

Plain ``N×4`` arrays have no field names: give ``columns=`` (e.g. ``"txyp"``); otherwise
the time column is the one sorted column (first: t x y p; third: x y t p; last, after a
polarity column: x y p t), and ``meta["columns"]`` says it was inferred. Float times
are seconds, integer times µs, unless ``time_unit=`` or the time field's name (``t_ns``, ``timestamp_us``) says otherwise.
"""

from __future__ import annotations

import os
import warnings
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from evmotion.catalog import NS_EPOCH_US
from evmotion.errors import EvmotionWarning, FormatError, ParameterError
from evmotion.events import EventArray, ambiguous_polarity
from evmotion.io.base import (
    EVENT_FIELD_NAMES,
    TIME_UNIT_US,
    FormatSpec,
    event_fields,
    time_unit_in_name,
)
from evmotion.io.guard import (
    MAX_SENSOR_SIDE,
    SENSOR_SIZE_HINT,
    check_sensor_size,
    warn_inferred_size,
)
from evmotion.io.timedoubt import rate_doubt, unit_doubt
from evmotion.utils import atomic_path

__all__ = ["read", "iter_chunks", "write", "describe", "events_from_columns", "split_columns",
           "FORMAT"]

NPY_MAGIC = b"\x93NUMPY"
# Largest |time| accepted, in µs (146,000 years): int64 arithmetic on it cannot overflow.
MAX_ABS_TIME_US = 1 << 62
# deflate cannot expand data more than 1032:1
_DEFLATE_MAX_RATIO = 1032
ZIP_MAGIC = b"PK\x03\x04"


def _time_us(t: np.ndarray, unit: str | None, how: str = "given"
             ) -> tuple[np.ndarray, str, float]:
    """``(times in whole µs, the unit's label, the µs a float time steps by where the
    times are largest (0 for integers))``; ValueError for times no µs hold."""
    if unit is None:
        unit = "s" if t.dtype.kind == "f" else "us"
        how = "inferred (float -> s, integer -> us)"
        if unit == "us" and t.size and int(t.min()) > NS_EPOCH_US:
            # as µs beyond the year 5000: nanoseconds since the epoch (ROS, Metavision
            # HDF5 exports and event_utils write them). Every time, not the largest: one
            # corrupt time had turned a recording's µs into ns, unsaid (probe)
            unit, how = "ns", "inferred (integer times past 1e17, as µs the year 5000+)"
    scale = TIME_UNIT_US.get(unit)
    if scale is None:
        raise ParameterError(f"time_unit must be 's', 'ms', 'us' or 'ns', got {unit!r}")
    if t.dtype.kind in "iu" and scale >= 1:
        if t.size and max(abs(int(t.min())), abs(int(t.max()))) * scale > MAX_ABS_TIME_US:
            raise ValueError(f"times reach {max(abs(int(t.min())), abs(int(t.max())))} {unit}")
        return t.astype(np.int64) * int(scale), f"{unit} ({how})", 0.0
    with np.errstate(all="ignore"):
        tf = t.astype(np.float64)
        us = np.rint(tf * scale)
    if (scale <= 1 and tf.size and np.isfinite(tf).all() and np.ptp(tf) < 1000
            and (tf != np.rint(tf)).any()):
        # float seconds read as µs or ns all fell on one or two µs ("0 .. 0 us", probe
        # BL): fractions of a µs over less than a millisecond are no such times
        k = int(np.argmax(tf != np.rint(tf)))
        raise TimeResolutionError(f"a time of {tf[k]:.9g} is not a whole number of {unit}, "
                                  f"and the times span under 1000 {unit}: they are in "
                                  "seconds? (leave out --time-unit / time_unit)")
    if us.size and not (np.abs(us).max() <= MAX_ABS_TIME_US):  # also catches NaN
        bad = int(np.argmax(~(np.abs(us) <= MAX_ABS_TIME_US)))
        raise ValueError(f"event {bad} has t={t[bad]} {unit}")
    step = 0.0
    if t.dtype.kind == "f" and t.size:
        # float32 seconds since the epoch (1.6e9) step by 128 s: every event of a window
        # at one time, read without a word (probe)
        top = np.abs(t).max()
        step = float(np.spacing(top)) * scale
        if step > MAX_FLOAT_TIME_STEP_US:
            raise TimeResolutionError(
                f"{t.dtype} times reaching {float(top):.6g} {unit} step by {step:.3g} us "
                f"there ({np.unique(t).size:,} distinct times for {t.size:,} events): store "
                "them as float64 or whole microseconds")
    return us.astype(np.int64), f"{unit} ({how})", step


# the coarsest step of float times accepted: event cameras stamp microseconds
MAX_FLOAT_TIME_STEP_US = 1000.0


class TimeResolutionError(ValueError):
    """Float times too coarse, where they lie, to hold event times."""


def _refuse_negative_pixels(path, x: np.ndarray, y: np.ndarray) -> None:
    """FormatError naming the first event whose integer pixel coordinate is below 0."""
    for name, a in (("x", x), ("y", y)):
        if a.size and a.min() < 0:
            bad = int(np.argmax(a < 0))
            raise FormatError(path, f"event {bad} has {name}={a[bad]}: pixel coordinates "
                              "start at 0")


def events_from_columns(path, x, y, t, p, *, sensor_size=None, time_unit=None,
                        meta=None, validate=True, drop_outside=False,
                        time_field: str | None = None, format_unit: str | None = None,
                        format_name: str = "", format_unit_how: str | None = None
                        ) -> EventArray:
    """Build an EventArray from loose columns, with clear errors naming ``path``.

    ``time_field``, the name ``t`` had in the file: a unit it states (``t_ns``,
    ``timestamp_us``) is the unit when ``time_unit`` is None. ``format_unit``: the unit
    the format ``format_name`` states for its times, used when neither says one, and
    doubted as a guess is (MVSEC's seconds holding microseconds read 10^6 x long, unsaid);
    ``format_unit_how`` says how it was found (default: ``"<format_name>'s"``).

    Integer-valued coordinates become uint16; fractional ones (undistorted) float32.
    ``drop_outside`` drops events off the sensor (undistorted coordinates) instead of
    raising; ``meta["dropped_outside"]`` counts them. With ``validate=False`` they are kept
    unchecked.
    """
    path = Path(path) if path is not None else None
    meta = dict(meta or {})
    t = np.asarray(t)
    if t.dtype.kind not in "iuf":
        raise FormatError(path, f"field 't' has dtype {t.dtype}, expected numbers")
    how = "given"
    if time_unit is None and time_field is not None and time_unit_in_name(time_field):
        time_unit, how = time_unit_in_name(time_field), f"from the field name '{time_field}'"
    guessed = time_unit is None
    if guessed and format_unit is not None:
        time_unit, how = format_unit, format_unit_how or f"{format_name}'s"
    try:
        t_us, unit, step = _time_us(t, time_unit, how)
    except ValueError as exc:
        if isinstance(exc, ParameterError):
            raise
        if isinstance(exc, TimeResolutionError):
            raise FormatError(path, f"field 't': {exc}") from None
        raise FormatError(path, f"field 't': {exc}, not a time within +-2^62 us") from None
    meta["time_unit"] = unit
    if step > 1:
        # float32 seconds near 100 s step by 8 us: 1,959 distinct times read as 1,799,
        # unsaid (probe BL); steps over 1 ms are refused by _time_us
        top = float(np.abs(t).max())
        warnings.warn(f"{path}: field 't' is {t.dtype}: at {top:.6g} {unit.split()[0]} "
                      f"its values step by {step:.3g} us, so the times are rounded to "
                      "that; store them as float64 or whole microseconds",
                      EvmotionWarning, stacklevel=3)
    doubt = unit_doubt(t, unit) if guessed else None
    if doubt is not None:
        warnings.warn(f"{path}: field 't' {doubt}", EvmotionWarning, stacklevel=3)
    x = np.asarray(x)
    y = np.asarray(y)
    p = np.asarray(p)
    for name, a in (("x", x), ("y", y), ("t", t_us), ("p", p)):
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise FormatError(path, f"field '{name}' contains NaN or inf")
    frac = x.dtype.kind == "f" and (np.any(x != np.round(x)) or np.any(y != np.round(y)))
    if sensor_size is None:
        if x.size == 0:
            raise FormatError(path, "no events and no sensor size",
                              SENSOR_SIZE_HINT)
        if not frac:
            _refuse_negative_pixels(path, x, y)
        if max(x.max(), y.max()) >= MAX_SENSOR_SIDE:
            raise FormatError(path, f"coordinates span x {x.min()}..{x.max()}, y {y.min()}.."
                              f"{y.max()}: no sensor of at most {MAX_SENSOR_SIDE} px per side",
                              SENSOR_SIZE_HINT)
        sensor_size = (int(np.ceil(y.max())) + 1, int(np.ceil(x.max())) + 1)
        meta["sensor_size_from"] = "max coordinate (no sensor size in the file)"
    h, w = check_sensor_size(path, sensor_size)
    if doubt is None:
        # a unit given too (--time-unit mistyped)
        doubt = rate_doubt(t_us, x, y, (h, w), unit, given=not guessed, raw=t)
        if doubt is not None:
            warnings.warn(f"{path}: field 't' {doubt}", EvmotionWarning, stacklevel=3)
    if p.size and not np.all(np.isin(p, (-1, 0, 1))):
        bad = int(np.argmax(~np.isin(p, (-1, 0, 1))))
        raise FormatError(path, f"event {bad} has polarity p={p[bad]}, expected 0/1 or -1/+1")
    odd = ambiguous_polarity(p) if p.dtype.kind in "if" else None
    if odd is not None:
        raise FormatError(path, odd)
    inside = (x >= 0) & (y >= 0) & (x <= w - 1) & (y <= h - 1)
    if not inside.all():
        bad = int(np.argmax(~inside))
        if validate and not drop_outside and not frac:
            # no sensor size holds a negative pixel: the size hint would not help (float
            # coordinates, undistorted, do leave the sensor)
            _refuse_negative_pixels(path, x, y)
        if drop_outside:
            meta["dropped_outside"] = int((~inside).sum())
            x, y, t_us, p = x[inside], y[inside], t_us[inside], p[inside]
        elif validate:
            assumed = f", {meta['sensor_size_from']}" if meta.get("sensor_size_from") else ""
            raise FormatError(path, f"event {bad} at x={x[bad]}, y={y[bad]} lies outside the "
                              f"sensor {w}x{h} (W x H{assumed})", SENSOR_SIZE_HINT)
    if frac:
        x, y = x.astype(np.float32), y.astype(np.float32)
    else:
        x, y = x.astype(np.uint16), y.astype(np.uint16)
    try:
        return EventArray(x=x, y=y, t=t_us, p=(p > 0).astype(np.uint8), sensor_size=(h, w),
                          validate=validate, meta=meta)
    except Exception as exc:
        raise FormatError(path, str(exc)) from None


def _load(path: Path):
    """``np.load`` with what a corrupt file declares checked first: a ``.npy`` is
    memory-mapped (its header cannot claim more data than the file holds) and copied; the
    members of an ``.npz`` must not expand past what deflate can produce."""
    with open(path, "rb") as fh:
        magic = fh.read(len(NPY_MAGIC))
    if magic == NPY_MAGIC:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
        return np.array(arr)
    with zipfile.ZipFile(path) as z:
        for info in z.infolist():
            limit = info.compress_size * _DEFLATE_MAX_RATIO + 4096
            if info.file_size > limit:
                raise FormatError(path, f"npz member '{info.filename}' declares "
                                  f"{info.file_size} bytes from {info.compress_size} "
                                  "compressed (corrupt archive)")
    return np.load(path, allow_pickle=False)


def split_columns(path: Path, arr: np.ndarray, columns: str | None):
    """The columns ``{"t", "x", "y", "p"}`` of an N×4 (or 4×N) array, and how their
    order was known: ``columns`` (a permutation of "txyp") or the one sorted column."""
    if arr.ndim != 2 or 4 not in arr.shape:
        raise FormatError(path, f"expected a structured array (x, y, t, p) or an N×4 array, "
                          f"got shape {arr.shape} dtype {arr.dtype}")
    if arr.shape[1] != 4:
        arr = arr.T
    how = "given"
    if columns is None:
        # compared, not differenced: np.diff of unsigned columns wraps (all "sorted");
        # the share of steps forward, so that a few times out of order (which the
        # unsorted-time check then names) still tell time from a coordinate (~half)
        ahead = [float(np.mean(arr[1:, i] >= arr[:-1, i])) if len(arr) > 1 else 1.0
                 for i in range(4)]
        # (a polarity column, -1 / 0 / 1, is no time however ordered)
        binary = [bool(np.isin(arr[:, i], (-1, 0, 1)).all()) for i in range(4)]
        sorted_cols = [i for i in range(4) if ahead[i] >= 0.99 and not binary[i]]
        # the time column's place names the order: t x y p (ECD), x y t p (MVSEC),
        # x y p t (Prophesee's CD fields) where the third column holds polarities
        orders = {0: "txyp", 2: "xytp", 3: "xypt" if binary[2] else None}
        columns = orders.get(sorted_cols[0]) if len(sorted_cols) == 1 else None
        if columns is None:
            raise FormatError(path, "cannot tell which column is time in this N×4 array "
                              f"(share of steps forward per column: "
                              f"{', '.join(f'{a:.2f}' for a in ahead)})",
                              "in Python pass columns= (e.g. 'txyp', 'xytp', 'xypt'); for "
                              "any tool, save a structured array with fields t, x, y, p or "
                              "an .npz with arrays t, x, y, p")
        how = "inferred from the sorted column"
    if sorted(columns) != sorted("txyp"):
        raise ParameterError(f"columns must be a permutation of 'txyp', got {columns!r}")
    cols = {c: arr[:, i] for i, c in enumerate(columns)}
    return cols, f"{columns} ({how})"


def read(path: str | os.PathLike, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, columns: str | None = None,
         time_unit: str | None = None, validate: bool = True) -> EventArray:
    """Read events from ``.npy`` / ``.npz``.

    Parameters
    ----------
    t0, t1 : int, optional
        Keep ``t0 <= t < t1`` (µs).
    sensor_size : (int, int), optional
        ``(height, width)``; default from the file, else the max coordinate (meta says so).
    columns : str, optional
        Column order of a plain N×4 array, e.g. ``"txyp"``.
    time_unit : {"s", "ms", "us", "ns"}, optional
        Unit of ``t`` in the file (default: float -> s, integer -> µs).

    Examples
    --------
    >>> np.savez("events.npz", x=[3, 5], y=[4, 6], t=[0.0005, 0.001], p=[1, 0])
    >>> ev = read("events.npz", sensor_size=(8, 8))  # float times: seconds
    >>> len(ev), ev.t.tolist()
    (2, [500, 1000])
    """
    path = Path(path)
    meta = {"source": str(path), "format": "npy"}
    time_field = None
    try:
        obj = _load(path)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        if isinstance(exc, FormatError):
            raise
        raise FormatError(path, f"cannot read as .npy/.npz: {exc}") from None
    if isinstance(obj, np.lib.npyio.NpzFile):
        with obj:
            files = set(obj.files)
            named = event_fields(sorted(files))
            if named is not None:
                cols = {k: obj[named[k]] for k in "xytp"}
                time_field = named["t"]
            elif "events" in files:
                arr = obj["events"]
                cols = None
            else:
                raise FormatError(path, f"npz lacks arrays x, y, t, p (has {sorted(files)}); "
                                  f"names read: {_names_read()}")
            if sensor_size is None:
                sensor_size = _stated_size(path, obj, files)
            if time_unit is None and "time_unit" in files:
                time_unit = str(obj["time_unit"])
    else:
        arr = obj
        cols = None
    if cols is None:
        if arr.dtype.names:
            named = event_fields(arr.dtype.names)
            if named is None:
                raise FormatError(path, "structured array lacks a field for each of t, x, "
                                  f"y, p (has {list(arr.dtype.names)}); names read: "
                                  f"{_names_read()}")
            cols = {k: arr[named[k]] for k in "xytp"}
            time_field = named["t"]
        else:
            cols, meta["columns"] = split_columns(path, arr, columns)
    lens = {k: np.shape(v) for k, v in cols.items()}
    if len(set(lens.values())) != 1 or len(lens["t"]) != 1:
        raise FormatError(path, f"fields x, y, t, p have different shapes: {lens}")
    ev = events_from_columns(path, cols["x"], cols["y"], cols["t"], cols["p"],
                             sensor_size=sensor_size, time_unit=time_unit, meta=meta,
                             validate=validate, time_field=time_field)
    if sensor_size is None:  # as the other readers of files without one say it
        warn_inferred_size(path, ev.sensor_size)
    return ev.slice_time(t0, t1) if (t0 is not None or t1 is not None) else ev


def _names_read() -> str:
    """The field names the readers take, for an error that finds none of them."""

    return "; ".join(f"{k}: {', '.join(v)}" for k, v in EVENT_FIELD_NAMES.items()) + (
        " (a time name may end with its unit: t_ns, timestamp_us, t[s])")


def _stated_size(path, obj, files) -> tuple[int, int] | None:
    """The sensor size an .npz states: ``sensor_size`` (height, width; tonic's three
    values are width, height, polarities), ``height`` and ``width``, or ``resolution``
    (width, height, as tonic and Metavision write it)."""
    if "sensor_size" in files:
        size = np.ravel(obj["sensor_size"])
        if size.size == 3 and size[2] in (1, 2):
            return check_sensor_size(path, (size[1], size[0]),
                                     "array 'sensor_size' (tonic's width, height, polarities)")
        h, w = check_sensor_size(path, size, "array 'sensor_size'")
        if h > w:
            warnings.warn(EvmotionWarning(
                f"{path}: array 'sensor_size' [{h}, {w}] read as (height, width), as "
                f"evmotion writes it: a sensor {w} px wide and {h} px tall. Tools that write "
                f"(width, height) mean {h} px wide and {w} tall: if so, give --sensor-size "
                f"{w} {h} (sensor_size=({w}, {h}) in Python)"), stacklevel=4)
        return h, w
    if "height" in files and "width" in files:
        return check_sensor_size(path, (np.ravel(obj["height"])[0], np.ravel(obj["width"])[0]),
                                 "arrays 'height', 'width'")
    if "resolution" in files:
        res = np.ravel(obj["resolution"])
        if res.size != 2:
            raise FormatError(path, f"array 'resolution' holds {res.size} values, not (width, "
                              "height)")
        return check_sensor_size(path, (res[1], res[0]), "array 'resolution' (width, height)")
    return None


def iter_chunks(path: str | os.PathLike, chunk_events: int, **kw) -> Iterator[EventArray]:
    """Chunks of ``chunk_events`` (the file is memory-mapped-free, read once)."""
    yield from chunks_of_read(read, path, chunk_events, **kw)


def chunks_of_read(read: Callable[..., EventArray], path: str | os.PathLike,
                   chunk_events: int, **kw) -> Iterator[EventArray]:
    """``read(path, **kw)`` (a whole-file reader) cut into chunks of ``chunk_events``."""
    if int(chunk_events) <= 0:
        raise ParameterError(f"chunk_events must be positive, got {chunk_events}")
    ev = read(path, **kw)
    for s in range(0, len(ev), int(chunk_events)):
        yield ev[s:s + int(chunk_events)]


def write(path: str | os.PathLike, events: EventArray) -> None:
    """Write ``.npz`` (arrays x, y, t[µs], p, sensor_size) or a structured ``.npy``
    (fields x, y, t[µs], p; the sensor size is not stored), atomically.

    Examples
    --------
    >>> write("out.npz", EventArray(x=[10, 20], y=[5, 6], t=[100, 200], p=[1, 0],
    ...                             sensor_size=(180, 240)))
    >>> read("out.npz").sensor_size                     # the .npz keeps it
    (180, 240)
    >>> write("out.npy", read("out.npz"))
    >>> read("out.npy", sensor_size=(180, 240)).t.tolist()   # the .npy does not
    [100, 200]
    """
    if not isinstance(events, EventArray):
        from evmotion.events import concatenate

        events = concatenate(list(events))
    path = Path(path)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".npy":
            dt = np.dtype([("x", events.x.dtype), ("y", events.y.dtype), ("t", "<i8"),
                           ("p", "u1")])
            arr = np.empty(len(events), dt)
            for k in "xytp":
                arr[k] = getattr(events, k)
            with open(tmp, "wb") as fh:
                np.save(fh, arr)
        else:
            with open(tmp, "wb") as fh:
                np.savez(fh, x=events.x, y=events.y, t=events.t, p=events.p,
                         sensor_size=np.asarray(events.sensor_size, np.int64),
                         time_unit=np.asarray("us"))


def describe(path: str | os.PathLike) -> dict:
    path = Path(path)
    with warnings.catch_warnings():  # the size's origin is in the description itself
        warnings.simplefilter("ignore", EvmotionWarning)
        ev = read(path, validate=False)
    return {"format": "npy", "sensor_size": ev.sensor_size, "n_events": len(ev),
            **{k: v for k, v in ev.meta.items() if k not in ("source", "format")}}


def _sniff(path: Path, head: bytes) -> bool:
    if head.startswith(NPY_MAGIC):
        return True
    if not head.startswith(ZIP_MAGIC):
        return False
    if path.suffix.lower() == ".npz":
        return True
    # an archive of .npy arrays under another name (convert o.bin --format-out npy wrote
    # one that nothing then recognised, probe AZ); other zip files are not events
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            names = z.namelist()
    except (OSError, zipfile.BadZipFile):
        return False
    return bool(names) and all(n.endswith(".npy") for n in names)


FORMAT = FormatSpec(name="npy", extensions=(".npy", ".npz"), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
