"""The event container and windowing.

An :class:`EventArray` holds events as named, contiguous columns:

* ``x``, ``y`` -- pixel column and row (uint16 on the sensor grid, float32 after
  undistortion), origin top-left;
* ``t`` -- int64 microseconds, absolute (file offsets already applied);
* ``p`` -- polarity stored as uint8 0/1; :attr:`EventArray.polarity` gives -1/+1.

plus the sensor size ``(height, width)``. Timestamps are sorted (non-decreasing); the
constructor checks this and the sensor bounds unless ``validate=False``.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from evmotion.catalog import MAX_SENSOR_SIDE, NS_EPOCH_US
from evmotion.errors import (
    EmptyWindowError,
    EventDataError,
    EvmotionWarning,
    ParameterError,
    UnsortedError,
)
from evmotion.utils import (
    MAX_TIME_US,
    check_not_seconds,
    check_number,
    is_finite_number,
    whole_number,
    whole_time_us,
)

__all__ = [
    "SORT_HINT",
    "EventArray",
    "check_follows",
    "fingerprint",
    "require_events",
    "Window",
    "concatenate",
    "make_windows",
    "window_bounds",
    "ambiguous_polarity",
    "as_timestamps_us",
    "events_for_windows",
]

# the share of events (and more than 10) stepping back in time beyond which the times are
# not a recorder's slips but another column (EventArray.check's hint)
MAX_UNSORTED_SHARE = 0.01
#: ... or all by at most this many µs and a hundredth of the span: the order of a sensor's
#: readout, not of a column mistaken for time (whose steps back are of the size of its
#: values, and of its span)
MAX_READOUT_STEP_US = 1000
#: What to do about times out of order that a sensor or recorder left (not another column).
SORT_HINT = "sort them: evmotion convert IN OUT --sort, or EventArray.sorted()"

#: Windows beyond the events' count that EventArray.windows_by_duration makes (empty ones,
#: whatever the count): ~330 MB and 3.5 s a million
MAX_EMPTY_WINDOWS = 1_000_000

TONIC_DTYPE = np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "<i1")])


@dataclass(frozen=True)
class Window:
    """A half-open time interval ``[t0, t1)`` in microseconds with its index range.

    Attributes
    ----------
    index : int
        Position of the window in its sequence.
    t0, t1 : int
        Start (inclusive) and end (exclusive) time in microseconds.
    start, stop : int
        Event index range ``[start, stop)`` in the parent array.
    """

    index: int
    t0: int
    t1: int
    start: int
    stop: int

    @property
    def duration_s(self) -> float:
        return (self.t1 - self.t0) * 1e-6

    @property
    def count(self) -> int:
        return self.stop - self.start


@dataclass(eq=False)
class EventArray:
    """Events from one sensor, as named columns sorted by time.

    Parameters
    ----------
    x, y : array_like
        Pixel column and row. Integer input is stored as uint16; float input (e.g.
        undistorted coordinates) as float32.
    t : array_like
        Timestamps in microseconds (int64, absolute, non-decreasing).
    p : array_like
        Polarity, 0/1 or -1/+1 (stored as 0/1 uint8); any other value raises
        :class:`~evmotion.errors.EventDataError`, even with ``validate=False``.
    sensor_size : (int, int)
        ``(height, width)`` in pixels.
    validate : bool
        Check sortedness, lengths and bounds (default True).
    meta : dict
        Free-form metadata (source file, calibration...).

    Examples
    --------
    >>> ev = EventArray(x=[1, 2], y=[0, 3], t=[10, 20], p=[1, 0], sensor_size=(4, 4))
    >>> len(ev), ev.duration_us
    (2, 10)
    >>> ev.polarity.tolist()
    [1.0, -1.0]
    """

    x: np.ndarray
    y: np.ndarray
    t: np.ndarray
    p: np.ndarray
    sensor_size: tuple[int, int]
    validate: bool = field(default=True, repr=False)
    meta: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.x = _coord(self.x, "x")
        self.y = _coord(self.y, "y")
        self.t = as_timestamps_us(self.t)
        self.p = _polarity(self.p)
        h, w = _sensor_size(self.sensor_size)
        self.sensor_size = (h, w)
        if self.t.ndim != 1:  # (the others were compared with its first axis: "field 'x'")
            raise EventDataError(f"field 't' has shape {self.t.shape}, expected (N,)")
        n = self.t.shape[0]
        for name in ("x", "y", "p"):
            if getattr(self, name).shape != (n,):
                raise EventDataError(
                    f"field '{name}' has shape {getattr(self, name).shape}, expected ({n},) like 't'"
                )
        if not (0 < h <= MAX_SENSOR_SIDE and 0 < w <= MAX_SENSOR_SIDE):
            # the readers' bound: a side beyond it is a corrupt or swapped value, which
            # failed later as a 74 GiB allocation (probe AU)
            raise EventDataError(f"sensor_size (height, width) = {(h, w)} is outside "
                                 f"1..{MAX_SENSOR_SIDE} px per side")
        if self.validate:
            self.check()

    def check_order(self) -> None:
        """Raise :class:`~evmotion.errors.UnsortedError` if the timestamps step back: what
        an estimator given an array built with ``validate=False`` checks (its windows are
        cut by binary search on ``t``).

        Examples
        --------
        >>> ev = EventArray(x=[0, 1], y=[0, 0], t=[20, 10], p=[1, 1], sensor_size=(2, 2),
        ...                 validate=False)
        >>> ev.check_order()
        Traceback (most recent call last):
        ...
        evmotion.errors.UnsortedError: timestamps are not sorted: t[0]=20 > t[1]=10 us (sort them: evmotion convert IN OUT --sort, or EventArray.sorted())
        """
        dt = np.diff(self.t)
        if dt.size and dt.min() < 0:
            i = int(np.argmax(dt < 0))
            back = int(np.count_nonzero(dt < 0))
            step = -int(dt.min())
            # a few events out of order are a recorder's, and so are many that step back
            # by a readout's few µs (a rolling readout: 47 % by up to 32 µs, probe AK);
            # many by more, a column taken for time that is not (sorting makes garbage)
            if back <= max(10, MAX_UNSORTED_SHARE * dt.size):
                hint = SORT_HINT
            elif (step <= MAX_READOUT_STEP_US
                  and 100 * step <= int(self.t.max()) - int(self.t.min())):
                hint = (f"{100 * back / dt.size:.0f} % of them step back, by at most "
                        f"{step} us: a sensor's readout order? {SORT_HINT}")
            else:
                hint = f"{100 * back / dt.size:.0f} % of them step back: " + _disorder_hint(
                    str(self.meta.get("format", "")))
            raise UnsortedError(i, self.t[i], self.t[i + 1], hint)

    def check(self) -> None:
        """Raise :class:`EventDataError` if timestamps are unsorted or coordinates off-sensor."""
        if len(self) == 0:
            return
        self.check_order()
        if self.t[-1] > NS_EPOCH_US:
            first = int(np.searchsorted(self.t, NS_EPOCH_US, side="right"))
            if 2 * first > len(self):
                # a few times past the year 5000 after many before: corrupt, not a unit
                raise EventDataError(
                    f"event {first} has t={int(self.t[first])}, as microseconds past the "
                    f"year 5000, where the {first:,} events before it reach "
                    f"{int(self.t[first - 1])}: {len(self) - first:,} corrupt time(s)?")
            raise EventDataError(
                f"field 't' reaches {int(self.t[-1])}, as microseconds past the year 5000: "
                "nanoseconds since the epoch? Give µs: (t + 500) // 1000, or "
                "EventArray.from_structured(..., time_unit_us=1e-3)")
        bad = _non_finite_coordinate(self)
        if bad is not None:
            raise EventDataError(bad)
        h, w = self.sensor_size
        for name, lim in (("x", w), ("y", h)):
            a = getattr(self, name)
            lo, hi = a.min(), a.max()
            if lo < 0 or hi > lim - 1:
                bad = int(np.argmax((a < 0) | (a > lim - 1)))
                # float coordinates are positions between pixel centres (bilinear votes):
                # 303.25 on a 304 px row is past the last centre, which the bare message
                # did not say (a probe read it as a bug)
                span = (f": float (undistorted) coordinates lie in [0, {lim - 1}], between "
                        "the first and last pixel centres" if a.dtype.kind == "f" else "")
                raise EventDataError(
                    f"event {bad} has {name}={a[bad]:g} outside the sensor "
                    f"(sensor_size (height, width) = {self.sensor_size}){span}"
                )

    # ------------------------------------------------------------------ basics
    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def height(self) -> int:
        return self.sensor_size[0]

    @property
    def width(self) -> int:
        return self.sensor_size[1]

    @property
    def duration_us(self) -> int:
        return int(self.t[-1] - self.t[0]) if len(self) else 0

    @property
    def t_start(self) -> int:
        if not len(self):
            raise EmptyWindowError("no events: the start time is undefined")
        return int(self.t[0])

    @property
    def t_end(self) -> int:
        """Last timestamp (inclusive), in microseconds."""
        if not len(self):
            raise EmptyWindowError("no events: the end time is undefined")
        return int(self.t[-1])

    @property
    def polarity(self) -> np.ndarray:
        """Polarity as float32 -1/+1."""
        return self.p.astype(np.float32) * 2.0 - 1.0

    @property
    def xf(self) -> np.ndarray:
        """x as contiguous float64 (for computation)."""
        return self.x.astype(np.float64)

    @property
    def yf(self) -> np.ndarray:
        """y as contiguous float64 (for computation)."""
        return self.y.astype(np.float64)

    def t_seconds(self, t_ref: int | None = None) -> np.ndarray:
        """Time relative to ``t_ref`` (default: the first event) in seconds, float64."""
        if t_ref is None:
            t_ref = self.t_start
        # (1e30 overflowed int64 and NaN failed in its conversion, probe API)
        t_ref = whole_time_us("t_ref (µs)", t_ref)
        return (self.t - np.int64(t_ref)).astype(np.float64) * 1e-6

    def t_normalized(self) -> np.ndarray:
        """Time mapped linearly to [0, 1] over the window (as in thesis eq. 3.7)."""
        if not len(self):
            raise EmptyWindowError("cannot normalize the time of an empty window")
        span = max(self.duration_us, 1)
        return (self.t - self.t[0]).astype(np.float64) / span

    def copy(self) -> EventArray:
        return EventArray(
            self.x.copy(), self.y.copy(), self.t.copy(), self.p.copy(),
            self.sensor_size, validate=False, meta=dict(self.meta),
        )

    def _take(self, key) -> EventArray:
        return EventArray(
            self.x[key], self.y[key], self.t[key], self.p[key],
            self.sensor_size, validate=False, meta=self.meta,
        )

    def __getitem__(self, key) -> EventArray:
        """Index by an int, a slice (a positive step subsamples), an integer array (taken
        in increasing order: events stay in time order) or a boolean mask; returns an
        EventArray."""
        if isinstance(key, (int, np.integer)):
            k = int(key)
            if not -len(self) <= k < len(self):
                raise IndexError(f"event {k} of {len(self)} events")
            k %= len(self)
            key = slice(k, k + 1)
        if isinstance(key, (float, np.floating, str)):
            raise ParameterError(f"index events with an int, a slice, an integer array or a "
                                 f"boolean mask, got {key!r}")
        if isinstance(key, slice) and key.step is not None and key.step < 0:
            raise EventDataError(f"a slice with step {key.step} would put the events out of "
                                 "time order; use ev.t[::-1] etc. for the reversed columns")
        if isinstance(key, slice) and key.step not in (None, 1):
            key = np.arange(len(self))[key]  # copied: the kernels take contiguous columns
        if not isinstance(key, slice):
            key = np.asarray(key)
            if key.dtype != bool:
                n = len(self)
                if key.size and key.dtype.kind in "iu" and (key.min() < -n or key.max() >= n):
                    k = int(key.min() if key.min() < -n else key.max())
                    raise IndexError(f"event {k} of {n} events")
                # negatives resolved before sorting: [-1, 0, 1] ends with the last event
                key = np.sort(np.where(key < 0, key + n, key))
        return self._take(key)

    def __iter__(self):
        raise TypeError("an EventArray is not iterated event by event: index it (ev[i]), "
                        "cut it into windows (ev.windows_by_count / windows_by_duration) or "
                        "pass it whole (a function taking chunks takes [ev])")

    def with_polarity_inverted(self) -> EventArray:
        """The same events with ON and OFF exchanged (a sensor or tool that stores them the
        other way round).

        Examples
        --------
        >>> ev = EventArray(x=[0, 1], y=[0, 0], t=[0, 5], p=[1, 0], sensor_size=(2, 2))
        >>> ev.with_polarity_inverted().p.tolist()
        [0, 1]
        """
        return EventArray(self.x, self.y, self.t, (1 - self.p).astype(np.uint8),
                          self.sensor_size, validate=False, meta=self.meta)

    def sorted(self) -> EventArray:
        """Return a copy sorted by time (stable)."""
        order = np.argsort(self.t, kind="stable")
        out = self._take(order)
        out.check()
        return out

    # ----------------------------------------------------------------- slicing
    def index_at(self, t_us: int | np.ndarray) -> int | np.ndarray:
        """Index of the first event with ``t >= t_us`` (binary search)."""
        return np.searchsorted(self.t, t_us, side="left")

    def slice_time(self, t0: int | None = None, t1: int | None = None) -> EventArray:
        """Events with ``t0 <= t < t1`` (microseconds; None means open)."""
        index = []
        for name, v, open_end in (("t0", t0, 0), ("t1", t1, len(self))):
            if v is None:
                index.append(open_end)
                continue
            # (a NaN bound gave no event without a word, probe CB)
            if not is_finite_number(v):
                raise ParameterError(f"slice_time: {name} must be a finite time in "
                                     f"microseconds or None, got {v!r}")
            check_not_seconds(f"slice_time: {name}", v)
            # within int64 for numpy's search (a Python int past it raised a TypeError,
            # probe OPT); every event's time lies inside
            index.append(int(self.index_at(min(max(v, -MAX_TIME_US), MAX_TIME_US))))
        i0, i1 = index
        return self._take(slice(i0, max(i0, i1)))

    def window(self, w: Window) -> EventArray:
        return self._take(slice(w.start, w.stop))

    # ----------------------------------------------------------------- windows
    def windows_by_duration(self, duration_us: int, *, t0: int | None = None,
                            t1: int | None = None, drop_empty: bool = False,
                            ) -> list[Window]:
        """Consecutive windows of ``duration_us`` microseconds covering ``[t0, t1)``
        (default from the first event to just after the last; the last window reaches
        ``t1`` or past it), without those holding no event when ``drop_empty``.

        Raises
        ------
        ParameterError
            ``t1 <= t0``, or, without ``drop_empty``, more than
            :data:`MAX_EMPTY_WINDOWS` windows beyond the number of events.

        Examples
        --------
        >>> ev = EventArray(x=[0, 1], y=[0, 0], t=[0, 2500], p=[1, 1], sensor_size=(2, 2))
        >>> [(w.t0, w.t1, w.count) for w in ev.windows_by_duration(1000)]
        [(0, 1000, 1), (1000, 2000, 0), (2000, 3000, 1)]
        >>> [w.index for w in ev.windows_by_duration(1000, drop_empty=True)]
        [0, 1]
        """
        # (past int64 or NaN, these had failed in numpy's or Python's conversions, probe API)
        duration_us = whole_number("window duration (duration_us, µs)", duration_us, lo=1,
                                   hi=MAX_TIME_US)
        if not len(self):
            return []
        t0 = self.t_start if t0 is None else whole_time_us("t0 (µs)", t0)
        t1 = self.t_end + 1 if t1 is None else whole_time_us("t1 (µs)", t1)
        _check_time_range(t0, t1)
        n = -(-(t1 - t0) // duration_us)  # the last window reaches t1
        end = t0 + n * duration_us
        if drop_empty:
            # without making the empty ones first, as make_windows does
            i0, i1 = int(self.index_at(t0)), int(self.index_at(end))
            return [Window(k, w.t0, w.t1, w.start + i0, w.stop + i0) for k, w in
                    enumerate(_occupied_windows(self[i0:i1], duration_us, t0))]
        if n > len(self) + MAX_EMPTY_WINDOWS:
            # (a span of 10**8 µs in 1 µs windows: 10**8 Window objects, tens of GB)
            raise ParameterError(
                f"[{t0}, {t1}) us in windows of {duration_us} us makes {n:,} windows for "
                f"{len(self):,} events: nearly all empty; pass drop_empty=True (or use "
                "make_windows), a longer duration_us, or check the unit of t0/t1")
        edges = t0 + np.arange(n + 1, dtype=np.int64) * duration_us
        return self._windows_from_edges(edges[:-1], edges[1:], False)

    def windows_by_count(self, n_events: int, *, drop_last_partial: bool = False,
                         ) -> list[Window]:
        """Consecutive windows of ``n_events`` events each (the last may be shorter), each
        ``[t_first, t_last + 1)`` µs of its own events (``[t_first, t_last)`` where the
        next window's first event shares its last one's microsecond: windows do not
        overlap).

        The window ends after its last event, not at the next window's first: across a gap
        in the recording (a camera that stopped, two recordings joined) the window had
        taken the gap's length, and its flow written as a displacement (``.flo``) came out
        2.19 s long, hundreds of times too large (probe CF).

        Examples
        --------
        >>> ev = EventArray(x=[1, 2, 3, 4], y=[0] * 4, t=[0, 10, 5_000, 5_010], p=[1] * 4,
        ...                 sensor_size=(4, 8))
        >>> [(w.t0, w.t1) for w in ev.windows_by_count(2)]
        [(0, 11), (5000, 5011)]
        """
        n_events = whole_number("events per window (n_events)", n_events, lo=1)
        n = len(self)
        out = []
        for k, s in enumerate(range(0, n, n_events)):
            e = min(s + n_events, n)
            if drop_last_partial and e - s < n_events:
                break
            t1 = int(self.t[e - 1]) + 1
            out.append(Window(k, int(self.t[s]), min(t1, int(self.t[e])) if e < n else t1,
                              s, e))
        return out

    def windows_at(self, timestamps_us: Sequence[int] | np.ndarray, *, dt: int = 1,
                   drop_empty: bool = False) -> list[Window]:
        """Windows between external timestamps, e.g. ground-truth frame times.

        Window ``k`` spans ``[ts[k], ts[k + dt])``, as in the MVSEC protocol where
        ``dt = 1`` or ``dt = 4`` frames; windows are spaced by ``dt`` frames.
        """
        ts = as_timestamps_us(timestamps_us, "timestamps_us")
        dt = whole_number("dt (frames)", dt, lo=1)
        if ts.ndim != 1 or ts.size < dt + 1:
            raise EventDataError(f"need at least {dt + 1} timestamps for dt={dt}, got {ts.size}")
        if np.any(np.diff(ts) < 0):
            raise EventDataError("external timestamps are not sorted")
        starts = ts[:-dt:dt]
        ends = ts[dt::dt]
        return self._windows_from_edges(starts, ends[: starts.size], drop_empty)

    def _windows_from_edges(self, starts: np.ndarray, ends: np.ndarray, drop_empty: bool,
                            ) -> list[Window]:
        i0 = np.searchsorted(self.t, starts, side="left")
        i1 = np.searchsorted(self.t, ends, side="left")
        out = []
        for a, b, s, e in zip(starts, ends, i0, i1, strict=True):
            if drop_empty and e <= s:
                continue
            out.append(Window(len(out), int(a), int(b), int(s), int(e)))
        return out

    def iter_windows(self, windows: Sequence[Window]) -> Iterator[tuple[Window, EventArray]]:
        for w in windows:
            yield w, self.window(w)

    # ------------------------------------------------------------ conversions
    def to_structured(self, dtype: np.dtype | None = None) -> np.ndarray:
        """Tonic-style structured array with fields ``x, y, t, p`` (p as 0/1)."""
        dtype = TONIC_DTYPE if dtype is None else np.dtype(dtype)
        out = np.empty(len(self), dtype=dtype)
        out["x"], out["y"], out["t"], out["p"] = self.x, self.y, self.t, self.p
        return out

    @classmethod
    def from_structured(cls, arr: np.ndarray, sensor_size: tuple[int, int],
                        *, time_unit_us: float | None = None, validate: bool = True
                        ) -> EventArray:
        """Build from a structured array with fields ``x, y, t, p`` (tonic, Prophesee).

        ``time_unit_us`` converts the ``t`` field to microseconds (1 for µs, 1e6 for s,
        1e-3 for ns); by default, the unit the field's name states (``t_ns``,
        ``timestamp_us``, ``t[s]``), else µs.

        Examples
        --------
        >>> arr = np.array([(3, 1, 2_000, 1), (4, 1, 5_000, 0)],
        ...                dtype=[("x", "<i2"), ("y", "<i2"), ("t_ns", "<i8"), ("p", "?")])
        >>> EventArray.from_structured(arr, (4, 8)).t.tolist()   # ns -> µs
        [2, 5]
        """
        from evmotion.io.base import TIME_UNIT_US, event_fields, time_unit_in_name

        names = arr.dtype.names or ()
        named = event_fields(names)
        if named is None:
            raise EventDataError(f"structured array lacks a field for each of x, y, t, p "
                                 f"(as x/xs, y/ys, t/ts/timestamp, p/pol/polarity); has "
                                 f"{names}")
        t = arr[named["t"]]
        if time_unit_us is None:
            time_unit_us = TIME_UNIT_US[time_unit_in_name(named["t"]) or "us"]
        # picoseconds to hours and beyond (1e-30 set every time to 0, unsaid; probe API)
        time_unit_us = check_number("time_unit_us", time_unit_us, 1e-6, 1e12,
                                    units="µs per unit of t")
        if time_unit_us != 1.0:
            t = np.round(t.astype(np.float64) * time_unit_us)
        return cls(arr[named["x"]], arr[named["y"]], t, arr[named["p"]], sensor_size,
                   validate=validate)

    def as_dict(self) -> dict[str, np.ndarray]:
        return {"x": self.x, "y": self.y, "t": self.t, "p": self.p}

    def summary(self) -> dict:
        """Counts, time range, rate and polarity balance as plain Python values."""
        n = len(self)
        d = {
            "sensor_size": {"height": self.height, "width": self.width},
            "events": n,
        }
        if n:
            dur = self.duration_us
            d.update(
                t_start_us=self.t_start,
                t_end_us=self.t_end,
                duration_s=dur * 1e-6,
                rate_ev_per_s=(n / (dur * 1e-6)) if dur > 0 else None,
                positive_fraction=float(self.p.mean()),
            )
        return d


def window_bounds(win, k: int) -> tuple[int, int]:
    """``(t0, t1)`` of window ``k`` of a caller's ``windows`` (each a :class:`Window`,
    which the caller takes as it is, or this) given as a pair of whole microseconds (a
    fraction had been floored, probe AU); each caller says which order of the two it
    accepts.

    Examples
    --------
    >>> window_bounds((0, 30_000.0), 0)
    (0, 30000)
    >>> window_bounds((0, 2.5), 3)
    Traceback (most recent call last):
    evmotion.errors.ParameterError: windows[3] t1 (us) must be a whole number, got 2.5
    """
    try:
        t0, t1 = win
    except (TypeError, ValueError):
        raise ParameterError(f"windows[{k}] must be a Window or a (t0, t1) pair of µs, "
                             f"got {win!r}") from None
    return (whole_number(f"windows[{k}] t0 (us)", t0),
            whole_number(f"windows[{k}] t1 (us)", t1))


def as_window(events: EventArray, k: int, win) -> Window:
    """``win``, window ``k`` of a caller's ``windows``, if a :class:`Window`, else one made
    of a ``(t0, t1)`` pair of µs (:func:`window_bounds`) with its index range in ``events``.

    Examples
    --------
    >>> ev = EventArray(x=[0, 1, 2], y=[0, 0, 0], t=[0, 10, 20], p=[1, 1, 1], sensor_size=(2, 4))
    >>> as_window(ev, 0, (5, 20))
    Window(index=0, t0=5, t1=20, start=1, stop=2)
    """
    if isinstance(win, Window):
        return win
    t0, t1 = window_bounds(win, k)
    if t1 <= t0:
        raise ParameterError(f"windows[{k}] = ({t0}, {t1}): t1 must be after t0")
    start, stop = (int(i) for i in np.searchsorted(events.t, [t0, t1]))
    return Window(k, t0, t1, start, stop)


#: Formats whose times are decoded from binary words: events far out of order there are a
#: corrupt file or one whose header names another format than its data
DECODED_TIME_FORMATS = ("evt2", "evt21", "evt3", "dat", "aedat2", "aedat3", "aedat4", "rosbag")


def _disorder_hint(fmt: str) -> str:
    """What events far out of time order say of a file of format ``fmt`` (a text's time
    column hint made no sense for a RAW file or a named field, probe AS)."""
    if fmt == "ecd":
        return ("is the time column where the format has it? (text: t x y p, or a header "
                "line naming the columns)")
    if fmt in DECODED_TIME_FORMATS:
        return ("a corrupt file, or one whose header names another format than its data "
                "holds?")
    return f"the events are stored in another order than time ({SORT_HINT}), or is another "\
        "field the time?"


def ambiguous_polarity(p: np.ndarray) -> str | None:
    """Why polarities ``p`` (signed) cannot be read, or None: -1 and 0 together, which
    0/1 and -1/+1 files never hold (without a +1 every event would read OFF; with one,
    -1 and 0 would both be OFF, or 0 is some third thing).

    Examples
    --------
    >>> ambiguous_polarity(np.array([-1, 0, 0])) is not None, ambiguous_polarity(np.array([-1, 1]))
    (True, None)
    >>> ambiguous_polarity(np.array([-1, 0, 1])) is not None
    True
    """
    if not p.size or p.min() != -1:
        return None
    zeros = int(np.count_nonzero(p == 0))
    if not zeros:
        return None
    ones = int(np.count_nonzero(p == 1))
    # every event OFF, unsaid (probe AS); -1/0/+1 read 0 as OFF, unsaid (probe BQ)
    return (f"field 'p' holds -1 ({int(np.count_nonzero(p == -1))} events) and 0 ({zeros})"
            + (f" and +1 ({ones})" if ones else " but no +1")
            + ": neither 0/1 nor -1/+1"
            + (", and both would read OFF; map the ON value to 1 first" if not ones else
               "; map each value to 0 (OFF) or 1 (ON) first"))


def _polarity(p) -> np.ndarray:
    """``p`` as contiguous uint8 0/1, or EventDataError if a value is not 0/1 (uint8 or
    unsigned input) or 0/1 or -1/+1 (signed or float input; -1 and 0 together refused).

    One min/max pass: a corrupt file whose polarity bytes read 255 must not pass as ON.
    """
    p = np.asarray(p)
    if p.dtype == np.bool_:
        return np.ascontiguousarray(p.view(np.uint8))
    if p.dtype.kind not in "iuf":
        raise EventDataError(f"field 'p' must be numeric, got dtype {p.dtype}")
    unsigned = p.dtype.kind == "u"
    if p.size:
        if unsigned:
            bad = p.max() > 1
        else:
            bad = not (p.min() >= -1 and p.max() <= 1)  # False for NaN too
            if not bad and p.dtype.kind == "f":
                bad = not np.all((p == 0) | (p == 1) | (p == -1))
        if bad:
            i = int(np.argmax(~np.isin(p, (0, 1) if unsigned else (-1, 0, 1))))
            want = "0/1" if unsigned else "0/1 or -1/+1"
            raise EventDataError(f"event {i} has polarity p={p[i]}, expected {want}")
        odd = None if unsigned else ambiguous_polarity(p)
        if odd is not None:
            raise EventDataError(odd)
    if p.dtype == np.uint8:
        return np.ascontiguousarray(p)
    return (p > 0).astype(np.uint8)


def fingerprint(events: EventArray, n: int = 1 << 16) -> str:
    """A short digest of a recording's events (their count and the first and last ``n``
    events' coordinates, times and polarities): what tells a resumed run that its input
    changed when the times alone do not (a mirrored or re-recorded file).

    Examples
    --------
    >>> ev = EventArray(x=[1, 2], y=[0, 3], t=[10, 20], p=[1, 0], sensor_size=(4, 4))
    >>> fingerprint(ev) == fingerprint(ev.copy()), fingerprint(ev) == fingerprint(ev[:1])
    (True, False)
    """
    h = _events_sha1(events, (slice(0, n), slice(max(len(events) - n, 0), len(events))))
    return f"{len(events)} events, sha1 {h.hexdigest()[:16]}"


def events_digest(events: EventArray) -> int:
    """The first 8 bytes of the SHA-1 of all the events' coordinates, times and
    polarities, as a signed 64-bit integer: a window's identity, which a resumed run
    checks each kept window against (:func:`fingerprint` sees a recording's ends only).

    Examples
    --------
    >>> ev = EventArray(x=[1, 2], y=[0, 3], t=[10, 20], p=[1, 0], sensor_size=(4, 4))
    >>> same = events_digest(ev) == events_digest(ev.copy())
    >>> same, events_digest(ev) == events_digest(ev[:1])
    (True, False)
    """
    return int(np.frombuffer(_events_sha1(events, (slice(None),)).digest()[:8], "<i8")[0])


def _events_sha1(events: EventArray, parts: tuple[slice, ...]):
    """The SHA-1 of the events' count and sensor size and of the coordinates, times and
    polarities of the events in ``parts``."""
    import hashlib

    h = hashlib.sha1(str((len(events), events.sensor_size)).encode())
    for part in parts:
        for a in (events.x, events.y, events.t, events.p):
            h.update(np.ascontiguousarray(a[part]).tobytes())
    return h


def _check_time_range(t0: int, t1: int) -> None:
    """Refuse a time range ``[t0, t1)`` (µs) that holds no time."""
    if t1 <= t0:
        raise ParameterError(f"t1 = {t1} µs must be after t0 = {t0} µs")


def _occupied_windows(sub: EventArray, duration_us: int, t0: int | None) -> list[Window]:
    """The windows of the grid ``t0 + k duration_us`` (``t0`` default the first event)
    that hold events, each with its grid position as index: what
    :meth:`EventArray.windows_by_duration` gives less its empty windows, without making
    them (a ``t0`` long before a recording on an absolute clock, or a pause of hours, made
    millions of empty windows first: minutes and gigabytes)."""
    duration_us = whole_number("window duration (duration_us, µs)", duration_us, lo=1)
    if not len(sub):
        return []
    start = sub.t_start if t0 is None else int(t0)
    k = (sub.t - start) // duration_us
    first = np.flatnonzero(np.r_[True, k[1:] != k[:-1]])
    stop = np.r_[first[1:], len(sub)]
    return [Window(int(k[a]), start + int(k[a]) * duration_us,
                   start + (int(k[a]) + 1) * duration_us, int(a), int(b))
            for a, b in zip(first, stop, strict=True)]


def events_for_windows(chunks: Iterable[EventArray], *, max_windows: int,
                       n_events: int | None = None, duration_us: int | None = None,
                       t0: int | None = None, min_events: int = 1) -> EventArray | None:
    """The events of a chunk stream as far as the first ``max_windows`` windows that
    :func:`make_windows` cuts with the same arguments need: ``make_windows`` on the result
    gives the windows it gives on the whole stream. Reads no further (the first windows of
    a long recording do not wait for all of it, nor hold it in memory).

    Parameters
    ----------
    chunks : iterable of EventArray
        Consecutive events, sorted by time, from ``t0`` on (e.g. :func:`evmotion.io.iter_events`
        with ``t0``/``t1``).
    max_windows : int
        Windows wanted.
    n_events, duration_us : int
        How windows are cut (exactly one), as in :func:`make_windows`.
    t0 : int, optional
        Start of the duration windows' grid (default the first event).
    min_events : int
        Windows holding fewer events do not count, as in :func:`make_windows`.

    Returns
    -------
    EventArray or None
        None when the stream holds no events.

    Examples
    --------
    >>> ev = EventArray(x=np.zeros(10), y=np.zeros(10), t=np.arange(0, 1000, 100),
    ...                 p=np.ones(10), sensor_size=(4, 4))
    >>> len(events_for_windows((ev[i:i + 2] for i in range(0, 10, 2)), max_windows=2,
    ...                        n_events=3))
    8
    """
    if (n_events is None) == (duration_us is None):
        raise ParameterError("events_for_windows needs exactly one of n_events, duration_us")
    max_windows = whole_number("max_windows", max_windows, lo=1)
    need = max(min_events, 1)
    parts: list[EventArray] = []
    seen = 0
    start = t0
    cells: dict[int, int] = {}
    for chunk in chunks:
        if not len(chunk):
            continue
        parts.append(chunk)
        seen += len(chunk)
        if n_events is not None:
            # the windows end at the first event of the next one: one event past them
            if seen > max_windows * whole_number("n_events", n_events, lo=1):
                break
            continue
        if start is None:
            start = int(chunk.t[0])
        k, counts = np.unique((chunk.t - start) // duration_us, return_counts=True)
        for a, b in zip(k.tolist(), counts.tolist(), strict=True):
            cells[a] = cells.get(a, 0) + b
        # a window is complete once an event past it arrived
        last = int(k[-1])
        if sum(1 for a, c in cells.items() if a < last and c >= need) >= max_windows:
            break
    return concatenate(parts) if parts else None


def require_events(events, func: str, *, on_sensor: bool = False) -> EventArray:
    """``events`` if it is an :class:`EventArray`, else :class:`ParameterError` naming
    ``func`` (a list or an array of rows would otherwise fail deep inside it).

    With ``on_sensor``, the events of an unchecked array (``validate=False``) that lie off
    the sensor are left out of what is returned, as the warning about them says.

    Examples
    --------
    >>> require_events([1, 2], "estimate_flow")
    Traceback (most recent call last):
    evmotion.errors.ParameterError: estimate_flow: events must be an EventArray (EventArray(x, y, t, p, sensor_size) or evmotion.io.read_events(path)), got list
    >>> ev = EventArray(np.array([1.0, -0.5]), np.array([2.0, 2.0]), np.array([0, 5]),
    ...                 np.array([1, 0]), (4, 4), validate=False)
    >>> len(require_events(ev, "estimate_flow", on_sensor=True))
    1
    """
    if not isinstance(events, EventArray):
        raise ParameterError(f"{func}: events must be an EventArray (EventArray(x, y, t, p, "
                             "sensor_size) or evmotion.io.read_events(path)), got "
                             f"{type(events).__name__}")
    # (one NaN x of an unchecked array made estimate_egomotion's warp zero motion, and
    # the other estimators dropped the event or failed deep inside numpy)
    bad = _non_finite_coordinate(events)
    if bad is not None:
        raise EventDataError(f"{func}: {bad}")
    off = _check_on_sensor(events, func)
    if not events.validate:
        # (estimate_bos cut its interval by binary search on unsorted times and solved
        # the wrong events without a word; egomotion reported a window running backwards)
        events.check_order()
    if on_sensor and off is not None:
        # (undistorted events kept past the borders, drop_outside=False, failed multicm's
        # flicker test in np.bincount and the network's voxel grid with an IndexError,
        # probe CB)
        return events[~off]
    return events


def _non_finite_coordinate(events: EventArray) -> str | None:
    """The first NaN or infinite coordinate of ``events`` as "field 'x' of event 5 is nan"
    (only float, undistorted, coordinates can hold one), or None."""
    for name in ("x", "y"):
        a = getattr(events, name)
        # min and max: NaN and inf show in them, without a mask of every event
        if (a.dtype.kind == "f" and a.size
                and not (np.isfinite(a.min()) and np.isfinite(a.max()))):
            i = int(np.argmax(~np.isfinite(a)))
            return (f"field '{name}' of event {i} is {a[i]}: coordinates must be finite, not "
                    "NaN or inf")
    return None


# Share of events off the sensor above which an unchecked array (validate=False) is
# suspect: undistortion without dropping leaves a few percent past the borders.
OFF_SENSOR_WARN = 0.1


def _check_on_sensor(events: EventArray, func: str) -> np.ndarray | None:
    """Refuse events of an unchecked array (``validate=False``) that all lie off the
    sensor, and warn when many do: an estimate from them was a silent zero, or came from
    the rest without a word (a sensor size given as (W, H)). Returns the mask of the
    events off the sensor, None where there is none."""
    if not len(events):
        return None
    h, w = events.sensor_size
    x, y = events.x, events.y
    if x.min() >= 0 and y.min() >= 0 and x.max() <= w - 1 and y.max() <= h - 1:
        return None
    mask = (x < 0) | (y < 0) | (x > w - 1) | (y > h - 1)
    off = int(np.count_nonzero(mask))
    where = (f"x {x.min():g}..{x.max():g}, y {y.min():g}..{y.max():g} on a {w}x{h} (W x H) "
             "sensor")
    if off == len(events):
        raise EventDataError(f"{func}: all {off} events lie off the sensor ({where}): "
                             "sensor_size is (height, width)")
    if off > OFF_SENSOR_WARN * len(events):
        warnings.warn(EvmotionWarning(
            f"{func}: {off} of {len(events)} events lie off the sensor ({where}) and are "
            "left out: sensor_size is (height, width)"), stacklevel=3)
    return mask


def _coord(a, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.size == 0:  # an empty list is float64 to numpy: no undistorted coordinates here
        return np.empty(a.shape, np.uint16)
    if a.dtype.kind == "f":
        return np.ascontiguousarray(a, dtype=np.float32)
    if a.dtype.kind not in "iub":
        raise EventDataError(f"field '{name}' must be numeric, got dtype {a.dtype}")
    if a.size and a.dtype != np.uint16 and (a.min() < 0 or a.max() > 65535):
        bad = int(np.argmax((a < 0) | (a > 65535)))
        raise EventDataError(f"event {bad} has {name}={a[bad]}, outside 0..65535")
    return np.ascontiguousarray(a, dtype=np.uint16)


# timestamps beyond +-2^62 us (146,000 years) are corrupt values, and int64 holds them
_MAX_ABS_T = 1 << 62


def as_timestamps_us(t, what: str = "field 't'") -> np.ndarray:
    """``t`` as contiguous int64 µs, refusing what the conversion would change: fractions
    (seconds given for µs would all become 0), NaN, values beyond +-2^62 (uint64 wraps),
    with :class:`~evmotion.errors.EventDataError` naming ``what``.

    Examples
    --------
    >>> as_timestamps_us(np.array([1.0, 2.0])).tolist()
    [1, 2]
    >>> as_timestamps_us([0.001])
    Traceback (most recent call last):
    evmotion.errors.EventDataError: field 't' has fractional values (t[0]=0.001): timestamps \
are integer microseconds; from seconds: np.round(t * 1e6).astype(np.int64)
    """
    a = np.asarray(t)
    if a.dtype == np.int64:
        return np.ascontiguousarray(a)
    if a.dtype.kind not in "iuf":  # bool, strings, objects
        if a.size == 0:
            return np.empty(a.shape, np.int64)
        raise EventDataError(f"{what} must be numeric (integer µs), got dtype {a.dtype}")
    if a.size and a.dtype.kind in "uf":
        # (Python floats: float16 against 2^62 warned of an overflow in numpy's cast)
        lo, hi = float(a.min()), float(a.max())
        if not (np.isfinite(lo) and np.isfinite(hi)):
            raise EventDataError(f"{what} contains NaN or inf")
        exact = 2.0 ** (np.finfo(a.dtype).nmant + 1) if a.dtype.kind == "f" else np.inf
        if max(hi, -lo) > exact:
            # float32 holds whole µs only up to 2^24 (16.8 s): an epoch's times all became
            # one and times of 1e9 µs were rounded to 64 µs, without a word (probe DB); said,
            # not refused: a file's float32 times are what it holds
            warnings.warn(EvmotionWarning(
                f"{what} is {a.dtype}, which holds whole microseconds exactly only up to "
                f"{exact:,.0f}, and reaches {max(hi, -lo):.6g}: its times were rounded "
                f"(steps of {np.spacing(np.asarray(max(hi, -lo), a.dtype)):.6g} µs there) "
                "before they came here; give int64 µs (or float64)"), stacklevel=3)
        if hi > _MAX_ABS_T or lo < -_MAX_ABS_T:
            raise EventDataError(f"{what} holds {hi if hi > _MAX_ABS_T else lo}, beyond "
                                 "+-2^62 µs: not a timestamp (corrupt, or another unit?)")
        if a.dtype.kind == "f":
            frac = a != np.floor(a)
            if frac.any():
                i = int(np.argmax(frac))
                raise EventDataError(
                    f"{what} has fractional values (t[{i}]={float(a[i])!r}): timestamps are "
                    "integer microseconds; from seconds: np.round(t * 1e6).astype(np.int64)")
    return np.ascontiguousarray(a, dtype=np.int64)


def _sensor_size(size) -> tuple[int, int]:
    try:
        if isinstance(size, (str, bytes)):
            raise TypeError  # "44" unpacked to (4, 4) (probe BE)
        h, w = size
        if float(h) != int(h) or float(w) != int(w):
            raise ValueError
        return int(h), int(w)
    except (TypeError, ValueError, OverflowError):
        raise EventDataError(f"sensor_size must be two whole numbers (height, width), "
                             f"got {size!r}") from None


def check_image_shape(name: str, shape) -> tuple[int, int]:
    """``shape`` as ``(height, width)``, or :class:`ParameterError` naming ``name`` unless
    it is two whole numbers in 1..MAX_SENSOR_SIDE px (-1 and 1e30 had failed as numpy's
    allocation errors, 0 given an empty mask unsaid, probe EVAL).

    Examples
    --------
    >>> check_image_shape("shape", (180, 240.0))
    (180, 240)
    >>> check_image_shape("shape", (0, 240))
    Traceback (most recent call last):
    evmotion.errors.ParameterError: shape must be two whole numbers of px (height, width) in 1..16384, got (0, 240)
    """
    from evmotion.errors import ParameterError

    try:
        h, w = _sensor_size(shape)
    except EventDataError:
        h = w = 0
    if not (0 < h <= MAX_SENSOR_SIDE and 0 < w <= MAX_SENSOR_SIDE):
        raise ParameterError(f"{name} must be two whole numbers of px (height, width) in "
                             f"1..{MAX_SENSOR_SIDE}, got {shape!r}")
    return h, w


def pixel_indices(a: np.ndarray, size: int) -> np.ndarray:
    """Contiguous int32 pixel indices of coordinates ``a``; float (undistorted) coordinates
    are rounded to the nearest pixel and clipped to ``[0, size - 1]``."""
    if a.dtype.kind == "f":
        a = np.clip(np.rint(a), 0, size - 1)
    return np.ascontiguousarray(a, dtype=np.int32)


def sensor_pixels(events: EventArray) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` as :func:`pixel_indices`, checked on the sensor: what compiled kernels
    that index per-pixel state with them need (an unvalidated EventArray may hold anything).
    """
    from evmotion.errors import ParameterError

    bad = _non_finite_coordinate(events)
    if bad is not None:  # (rounded, NaN became x=-2147483648)
        raise EventDataError(bad)
    h, w = events.sensor_size
    x, y = pixel_indices(events.x, w), pixel_indices(events.y, h)
    for name, a, lim in (("x", x, w), ("y", y, h)):
        if a.size and (a.min() < 0 or a.max() >= lim):
            bad = int(np.argmax((a < 0) | (a >= lim)))
            raise ParameterError(f"event {bad} has {name}={int(a[bad])} outside the sensor "
                                 f"(height, width) = {events.sensor_size}")
    return x, y


#: How far outside its events' span [first, last] a warp's reference time may lie: their
#: span, or this if longer (a window whose events bunch at one end of its interval is
#: warped to its interval's middle by the evaluation)
T_REF_REACH_US = 1_000_000


def check_reference_time(name: str, t_ref, t: np.ndarray) -> int:
    """``t_ref`` (µs) as an int, or :class:`ParameterError` naming ``name`` unless it is a
    whole number within ``max(span, 1 s)`` of the window's event times ``t`` (sorted,
    not empty), ``span = t[-1] - t[0]``: a reference far outside is another window's or
    another clock's, and warped every event off the sensor (zero motion, FWL 0.0).

    Examples
    --------
    >>> check_reference_time("t_ref", 5_000, np.array([0, 10_000]))
    5000
    >>> check_reference_time("t_ref", 10**12, np.array([0, 10_000]))
    Traceback (most recent call last):
    evmotion.errors.ParameterError: t_ref=1000000000000 us lies outside the window's events [0, 10000] us by more than max(their span, 1 s): a time of another window or clock?
    """
    v = whole_number(name, t_ref)
    first, last = int(t[0]), int(t[-1])
    reach = max(last - first, T_REF_REACH_US)
    if not first - reach <= v <= last + reach:
        raise ParameterError(f"{name}={v} us lies outside the window's events [{first}, "
                             f"{last}] us by more than max(their span, 1 s): a time of "
                             "another window or clock?")
    return v


def check_follows(t_last: int | None, chunk: EventArray, at: int = -1) -> None:
    """Raise :class:`~evmotion.errors.UnsortedError` when ``chunk`` starts before
    ``t_last``, the previous chunk's last time (None for the first chunk); ``at`` is the
    index of that last event in the whole stream (-1 where the caller shifts it).

    Examples
    --------
    >>> chunk = EventArray(x=[0], y=[0], t=[10], p=[1], sensor_size=(1, 1))
    >>> check_follows(30, chunk, at=4)
    Traceback (most recent call last):
    ...
    evmotion.errors.UnsortedError: timestamps are not sorted: t[4]=30 > t[5]=10 us (sort them: evmotion convert IN OUT --sort, or EventArray.sorted())
    """
    if t_last is not None and len(chunk) and chunk.t[0] < t_last:
        raise UnsortedError(at, t_last, int(chunk.t[0]), SORT_HINT)


def check_stream_order(t: np.ndarray, t_last: int | None) -> None:
    """Raise :class:`ParameterError` unless the chunk times ``t`` are sorted and start no
    earlier than ``t_last``, the previous chunk's last time (None for the first chunk):
    what streaming stages that keep per-pixel state must be fed."""
    from evmotion.errors import ParameterError

    if t_last is not None and t.size and t[0] < t_last:
        raise ParameterError(f"chunk starts at t={int(t[0])} us, before the previous "
                             f"chunk's last event at t={t_last} us (stream unsorted)")
    if t.size > 1 and np.any(t[1:] < t[:-1]):
        i = int(np.argmax(t[1:] < t[:-1]))
        raise ParameterError(f"chunk timestamps are not sorted at event {i + 1} "
                             f"(t={int(t[i])} then {int(t[i + 1])} us)")


def concatenate(arrays: Sequence[EventArray], *, validate: bool = True) -> EventArray:
    """Join event arrays of the same sensor, in the given (time) order."""
    if not arrays:
        raise EmptyWindowError("nothing to concatenate")
    for i, a in enumerate(arrays):
        if not isinstance(a, EventArray):
            raise ParameterError(f"concatenate: item {i} is a {type(a).__name__}, not an "
                                 "EventArray")
    sizes = {a.sensor_size for a in arrays}
    if len(sizes) != 1:
        raise EventDataError(f"cannot concatenate events of different sensor sizes {sizes}")
    cat = {k: np.concatenate([getattr(a, k) for a in arrays]) for k in "xytp"}
    return EventArray(**cat, sensor_size=arrays[0].sensor_size, validate=validate,
                      meta=dict(arrays[0].meta))


def make_windows(events: EventArray, *, n_events: int | None = None,
                 duration_us: int | None = None,
                 edges_us: Sequence[int] | np.ndarray | None = None, dt: int = 1,
                 t0: int | None = None, t1: int | None = None,
                 max_windows: int | None = None, min_events: int = 1) -> list[Window]:
    """The processing windows of a recording, cropped in time and limited in number.

    Exactly one of ``n_events`` (:meth:`EventArray.windows_by_count`), ``duration_us``
    (:meth:`EventArray.windows_by_duration`) or ``edges_us`` (:meth:`EventArray.windows_at`,
    ``dt`` edges per window) says how windows are cut. Only the events with
    ``t0 <= t < t1`` are windowed: count and duration windows start at ``t0`` (default the
    first event) and end by ``t1`` (the last one is cut there; without ``t1``, just after
    the last event); edge windows are kept when they lie within ``[t0, t1)``. Of the windows holding at least ``min_events`` events, the first
    ``max_windows`` are returned. ``start``/``stop`` index ``events`` itself.

    Parameters
    ----------
    events : EventArray
        The recording (timestamps sorted).
    n_events : int, optional
        Events per window.
    duration_us : int, optional
        Window duration in µs.
    edges_us : array_like of int, optional
        Window edges in µs (e.g. ground-truth frame times).
    dt : int
        Edges per window with ``edges_us`` (default 1).
    t0, t1 : int, optional
        Time range in absolute µs, ``[t0, t1)`` (None: open).
    max_windows : int, optional
        Keep at most this many windows (None: all).
    min_events : int
        Drop windows with fewer events (default 1: drop empty ones).

    Returns
    -------
    list of Window
        In time order; ``index`` counts from the first window of the range.

    Raises
    ------
    ParameterError
        ``t1 <= t0``, ``max_windows < 1`` or not exactly one way of cutting windows.

    Examples
    --------
    >>> ev = EventArray(x=np.zeros(10), y=np.zeros(10), t=np.arange(0, 1000, 100),
    ...                 p=np.ones(10), sensor_size=(4, 4))
    >>> [(w.t0, w.t1, w.count) for w in make_windows(ev, duration_us=300, t0=200, t1=700)]
    [(200, 500, 3), (500, 700, 2)]
    >>> [w.count for w in make_windows(ev, n_events=4, max_windows=2)]
    [4, 4]
    """
    given = [k for k, v in (("n_events", n_events), ("duration_us", duration_us),
                            ("edges_us", edges_us)) if v is not None]
    if len(given) != 1:
        raise ParameterError("make_windows needs exactly one of n_events, duration_us, "
                             f"edges_us; got {given or 'none'}")
    if t0 is not None and t1 is not None:
        _check_time_range(t0, t1)
    if max_windows is not None:  # (2.5 failed as a slice index)
        max_windows = whole_number("max_windows", max_windows, lo=1)
    i0 = 0 if t0 is None else int(events.index_at(t0))
    i1 = len(events) if t1 is None else max(i0, int(events.index_at(t1)))
    if edges_us is not None:
        windows = [w for w in events.windows_at(edges_us, dt=dt)
                   if (t0 is None or w.t0 >= t0) and (t1 is None or w.t1 <= t1)]
    else:
        sub = events[i0:i1]
        if n_events is not None:
            made = sub.windows_by_count(n_events)
        else:
            made = _occupied_windows(sub, duration_us, t0)
        # the last window ends with the recording (or t1): a duration window reaching
        # past the last event would state a longer interval than its events cover
        end = int(events.t[-1]) + 1 if t1 is None and len(events) else t1
        windows = [Window(w.index, w.t0, w.t1 if end is None else min(w.t1, int(end)),
                          w.start + i0, w.stop + i0) for w in made]
    windows = [w for w in windows if w.count >= max(min_events, 1)]
    return windows if max_windows is None else windows[:max_windows]
