"""MATLAB ``.mat`` event excerpts (read with :func:`scipy.io.loadmat`).

Two layouts are known:

* ECD struct ``events.e_data``: 4×N, rows ``t[s], x, y, p``;
* a 2-D variable (``seq`` in the ECD *dynamic* excerpt): N×4 ``t[µs], x, y, p``, where the
  coordinates may already be undistorted (fractional, possibly off-sensor).

Any other 4×N / N×4 numeric variable is read as ``t, x, y, p`` too. The time unit is
inferred (a span under 100 with fractional values -> seconds, else µs) unless
``time_unit=`` is given; ``meta["time_unit"]`` records which.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from evmotion.errors import EvmotionWarning, FormatError
from evmotion.events import EventArray
from evmotion.io.base import FormatSpec
from evmotion.io.guard import LARGEST_COORDINATE, extended_size
from evmotion.io.npy import chunks_of_read, events_from_columns

__all__ = ["read", "iter_chunks", "describe", "FORMAT"]

DEFAULT_SENSOR_SIZE = (180, 240)


def _load(path: Path) -> dict:
    import scipy.io

    try:
        _check_sizes(path, scipy.io.whosmat(path))
        return scipy.io.loadmat(path)
    except (ValueError, TypeError, OSError, NotImplementedError) as exc:
        hint = "MATLAB v7.3 files are HDF5: read them with format='h5'" if \
            "v7.3" in str(exc) or "HDF" in str(exc) else None
        raise FormatError(path, f"cannot read as MATLAB .mat: {exc}", hint) from None


def _check_sizes(path: Path, variables: list) -> None:
    """FormatError if a variable's declared shape needs more memory than the file can
    hold (16 bytes per element, deflate's 1032:1 at most): a corrupt dimension must fail
    here, before ``loadmat`` allocates it."""
    limit = max(1032 * path.stat().st_size, 1 << 24)
    for name, shape, _ in variables:
        count = 1
        for s in shape:
            count *= int(s)
        if 16 * count > limit:
            raise FormatError(path, f"variable '{name}' declares shape {tuple(shape)}, more "
                              f"than this {path.stat().st_size}-byte file can hold")


def _find(path: Path, m: dict, variable: str | None) -> tuple[str, np.ndarray]:
    if variable is not None:
        if variable not in m:
            raise FormatError(path, f"no variable '{variable}'",
                              f"variables: {', '.join(k for k in m if not k.startswith('__'))}")
        return variable, np.asarray(m[variable])
    ev = m.get("events")
    if isinstance(ev, np.ndarray) and ev.dtype.names and "e_data" in ev.dtype.names:
        return "events.e_data", np.asarray(ev["e_data"][0, 0])
    for k, v in m.items():
        if k.startswith("__") or not isinstance(v, np.ndarray) or v.dtype.kind not in "fiu":
            continue
        if v.ndim == 2 and 4 in v.shape and v.size > 4:
            return k, v
    names = [k for k in m if not k.startswith("__")]
    raise FormatError(path, f"no 4×N event array found (variables: {', '.join(names)})",
                      "pass variable='name'")


# events a second beyond any sensor's sustained rate: times that would mean it are not us
MAX_RATE = 1e8


def read(path: str | os.PathLike, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, variable: str | None = None,
         time_unit: str | None = None, drop_outside: bool = True,
         validate: bool = True) -> EventArray:
    """Read events from a ``.mat`` excerpt.

    Parameters
    ----------
    t0, t1 : int, optional
        Keep ``t0 <= t < t1`` (µs).
    sensor_size : (int, int), optional
        ``(height, width)``; default 180×240 (the ECD's DAVIS240C).
    variable : str, optional
        Variable holding the events (default: ``events.e_data`` or the first 4×N array).
    time_unit : {"s", "us", ...}, optional
        Unit of the time row (default inferred).
    drop_outside : bool
        Drop undistorted events that fall off the sensor (counted in
        ``meta["dropped_outside"]``) instead of raising.

    Examples
    --------
    >>> import scipy.io
    >>> e_data = np.array([[0.0001, 0.0002], [3, 5], [4, 6], [1, 0]])  # rows t [s], x, y, p
    >>> scipy.io.savemat("shapes_rotation.mat", {"events": {"e_data": e_data}})
    >>> ev = read("shapes_rotation.mat")
    >>> ev.t.tolist(), ev.x.tolist(), ev.meta["variable"]
    ([100, 200], [3, 5], 'events.e_data')
    """
    path = Path(path)
    name, arr = _find(path, _load(path), variable)
    if arr.ndim != 2 or 4 not in arr.shape:
        raise FormatError(path, f"variable '{name}' has shape {arr.shape}, expected 4×N or N×4")
    if arr.shape[0] == 4 and arr.shape[1] != 4:
        arr = arr.T
    t, x, y, p = (np.ascontiguousarray(arr[:, i]) for i in range(4))
    meta = {"source": str(path), "format": "mat", "variable": name}
    guess = None
    if time_unit is None:
        # whole numbers are us; fractional ones seconds when they span under 100, or
        # when as us they would mean more than MAX_RATE events a second (a 150 s
        # recording in seconds); interpolated us (the ECD excerpts') stay us
        # (in float: an int8 column's span overflowed, a RuntimeWarning on stderr, probe CG)
        span = float(t.max()) - float(t.min()) if t.size else 0.0
        fractional = bool(np.any(t != np.round(t)))
        too_fast = span > 0 and t.size / (span * 1e-6) > MAX_RATE
        guess = "s" if fractional and (span < 100 or too_fast) else "us"
        meta["time_unit_inferred"] = True
    if sensor_size is None:
        sensor_size = DEFAULT_SENSOR_SIZE
        meta["sensor_size_from"] = "default 180x240 (DAVIS240C)"
        whole = x.size and np.all(x == np.round(x)) and np.all(y == np.round(y))
        if whole and x.min() >= 0 and y.min() >= 0:
            # raw pixels of a larger sensor (whole numbers; undistorted ones are not):
            # every event kept, on the smallest sensor holding them
            wider = extended_size(path, sensor_size, int(x.max()), int(y.max()),
                                  ", pixels beyond the DAVIS240C's 240x180")
            if wider is not None:
                sensor_size = wider
                meta["sensor_size_from"] = LARGEST_COORDINATE
    p = np.where(p > 0, 1, 0) if p.size and np.all(np.isin(p, (-1, 0, 1))) else p
    ev = events_from_columns(path, x, y, t.astype(np.float64), p, sensor_size=sensor_size,
                             time_unit=time_unit, meta=meta, validate=validate,
                             drop_outside=drop_outside, format_unit=guess,
                             format_unit_how="inferred from the times' values")
    lost = ev.meta.get("dropped_outside", 0)
    if lost:
        warnings.warn(EvmotionWarning(
            f"{path}: {lost:,} of {lost + len(ev):,} events lie outside the "
            f"{ev.sensor_size[1]}x{ev.sensor_size[0]} sensor (undistorted coordinates, or "
            "another sensor's: give its size) and are left out"), stacklevel=2)
    return ev.slice_time(t0, t1) if (t0 is not None or t1 is not None) else ev


def iter_chunks(path: str | os.PathLike, chunk_events: int, **kw) -> Iterator[EventArray]:
    """Chunks of ``chunk_events`` (``.mat`` files are loaded whole)."""
    yield from chunks_of_read(read, path, chunk_events, **kw)


def describe(path: str | os.PathLike) -> dict:
    path = Path(path)
    m = _load(path)
    name, arr = _find(path, m, None)
    return {"format": "mat", "variable": name, "shape": list(arr.shape),
            "variables": [k for k in m if not k.startswith("__")]}


def _sniff(path: Path, head: bytes) -> bool:
    return head.startswith(b"MATLAB 5.0 MAT-file") or (
        path.suffix.lower() == ".mat" and len(head) >= 128 and b"MATLAB" in head[:116])


FORMAT = FormatSpec(name="mat", extensions=(".mat",), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, describe=describe)
