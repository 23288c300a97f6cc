"""Doubts about the unit of event times a reader guessed (from their type, or the unit
its format states): times whose rate or steps no event camera makes in that unit, and the
unit that would fit, for a warning that names it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["rate_doubt", "unit_doubt"]

#: Events a second per pixel, averaged over a recording's sensor and time, that no event
#: camera sustains (its pixels' refractory periods allow bursts, not such averages):
#: times denser than this are in a coarser unit than read.
MAX_PIXEL_RATE = 1000.0
#: Events a second per pixel below which a recording longer than :data:`SPARSE_SPAN_S`
#: is sparser than a still sensor's noise alone: its times are in a finer unit than read.
MIN_PIXEL_RATE = 0.02
SPARSE_SPAN_S = 30.0
#: The units of event times, each 1000 x the one before.
UNITS = ("ns", "us", "ms", "s")
UNIT_NAMES = {"ns": "nanoseconds", "us": "microseconds", "ms": "milliseconds",
              "s": "seconds"}


def _ns_in_whole_microseconds(t: np.ndarray, unit: str) -> bool:
    """Whether integer times read as µs look like nanoseconds of a sensor with µs steps:
    at least 100 events, all on multiples of 1000, spanning more than a second as µs.

    Examples
    --------
    >>> t = np.arange(0, 2_000_000_000, 1_000_000)
    >>> _ns_in_whole_microseconds(t, "us (inferred)"), _ns_in_whole_microseconds(t + 1, "us (x)")
    (True, False)
    """
    return (unit.startswith("us") and t.dtype.kind in "iu" and t.size >= 100
            and int(t.max()) - int(t.min()) > 1_000_000
            and not np.any(t[:1000] % 1000) and not np.any(t % 1000))


def _sparse_as_microseconds(t: np.ndarray, unit: str) -> tuple[float, float] | None:
    """``(rate ev/s, span s)`` when integer times read as µs by inference make a
    recording of at least 1000 events longer than 10 s at under 1000 events/s: event
    cameras make far more while anything moves, and nanoseconds of a simulator read as µs
    look so (1000x long, every speed 1000x small). None otherwise.

    Examples
    --------
    >>> t = np.arange(8000) * 50_003  # ns, 20 kev/s
    >>> [round(v) for v in _sparse_as_microseconds(t, "us (inferred)")]
    [20, 400]
    >>> _sparse_as_microseconds(t // 1000, "us (inferred)") is None
    True
    """
    if not (unit.startswith("us (") and t.dtype.kind in "iu" and t.size >= 1000):
        return None
    span = _bulk_span(t) * 1e-6
    return (t.size / span, span) if span > 10 and t.size / span < 1000 else None


def _bulk_span(t: np.ndarray) -> float:
    # the span of the times from that of their middle 99 %: one corrupt time far off made
    # the recording look sparse, and the warning then named a wrong unit (probe)
    lo, hi = np.percentile(t, [0.5, 99.5])
    return (float(hi) - float(lo)) / 0.99


def _sparse_as_seconds(t: np.ndarray, unit: str) -> tuple[float, float] | None:
    """``(rate ev/s, span s)`` when float times read as seconds by a guess make a
    recording of at least 1000 events longer than 1000 s at under 10 events/s, or longer
    than 100 s at under 1000 events/s: even a still event camera's noise makes far more,
    and microseconds or milliseconds read as seconds look so (10^6 or 1000 x long, every
    speed as much too small). None otherwise.

    Examples
    --------
    >>> t = np.arange(20_000) * 1.8   # µs, 0.55 Mev/s, as float
    >>> [round(v, 2) for v in _sparse_as_seconds(t, "s (inferred)")]
    [0.56, 35998.2]
    >>> _sparse_as_seconds(t * 1e-6, "s (inferred)") is None
    True
    """
    if not (unit.startswith("s (") and t.dtype.kind == "f" and t.size >= 1000):
        return None
    span = _bulk_span(t)
    rate = t.size / span if span > 0 else np.inf
    if (span > 1000 and rate < 10) or (span > 100 and rate < 1000):
        return rate, span
    return None


def unit_doubt(t: np.ndarray, unit: str) -> str | None:
    """What makes times read in a guessed ``unit`` (inferred from their type, or the
    format's own) doubtful, as the rest of a warning about field 't' (the unit to give
    instead), or None. ``unit`` is the reader's label: ``"us (inferred ...)"``,
    ``"s (MVSEC's)"``...

    Examples
    --------
    >>> t = np.arange(60_000) * 8.3  # µs at 120 kev/s, as float
    >>> "microseconds? If so, read with --time-unit us" in unit_doubt(t, "s (inferred)")
    True
    >>> "milliseconds? If so" in unit_doubt(t / 1000, "s (inferred)")  # ms read as s
    True
    >>> unit_doubt(t * 1e-6, "s (inferred)") is None
    True
    """
    if _ns_in_whole_microseconds(t, unit):
        return (f"holds integers, read as microseconds, that are all multiples of 1000 "
                f"({len(t)} events; as µs, millisecond steps, which event cameras do not "
                "make): nanoseconds? If so, read with --time-unit ns (time_unit='ns' in "
                "Python); every speed is 1000x too small otherwise")
    sparse = _sparse_as_microseconds(t, unit)
    if sparse is not None:
        return (f"holds integers, read as microseconds: {len(t)} events over "
                f"{sparse[1]:.0f} s, {sparse[0]:.3g} events/s (an event camera makes far "
                "more while anything moves): nanoseconds? If so, read with --time-unit ns "
                "(time_unit='ns' in Python); every speed is 1000x too small otherwise")
    sparse = _sparse_as_seconds(t, unit)
    if sparse is not None:
        rate, span = sparse
        # µs read as s: 10 k - 10 M events/s become 0.01 - 10; ms read as s, 10 - 10 k
        unit_name, unit_key, factor = (("microseconds", "us", "a million") if rate < 10
                                       else ("milliseconds", "ms", "1000"))
        return (f"holds floats, read as seconds: {len(t)} events over {span:.0f} s, "
                f"{rate:.3g} events/s (an event camera makes far more, even still): "
                f"{unit_name}? If so, read with --time-unit {unit_key} (time_unit="
                f"'{unit_key}' in Python); every speed is {factor} times too small otherwise")
    return None


def rate_doubt(t_us: np.ndarray, n_pixels: int, unit: str) -> str | None:
    """What makes the times ``t_us`` (µs, as read in ``unit``, a reader's label such as
    ``"us (inferred ...)"`` or ``"ms (given)"``) of events on a sensor of ``n_pixels``
    doubtful, as the rest of a warning about field 't', or None: at least 10,000 events
    at more than :data:`MAX_PIXEL_RATE` events/s per pixel (integer milliseconds read as
    µs, probe BJ), or over more than :data:`SPARSE_SPAN_S` s at fewer than
    :data:`MIN_PIXEL_RATE` (decimal milliseconds read as seconds, probe BK).

    Examples
    --------
    >>> t_ms = np.arange(20_000) // 50            # 50 events a millisecond, 64x64 sensor
    >>> "milliseconds? If so" in rate_doubt(t_ms, 64 * 64, "us (inferred)")
    True
    >>> rate_doubt(t_ms * 1000, 64 * 64, "ms (given)") is None
    True
    """
    if t_us.size < 10_000 or n_pixels <= 0:
        return None
    span = _bulk_span(t_us) * 1e-6
    if span <= 0:
        return None
    rate = t_us.size / span / n_pixels
    read = unit.split()[0]
    if read not in UNITS:
        return None
    at = UNITS.index(read)
    if rate > MAX_PIXEL_RATE and at + 1 < len(UNITS):
        other, what, wrong = UNITS[at + 1], "far fewer", "large"
    elif rate < MIN_PIXEL_RATE and span > SPARSE_SPAN_S and at > 0:
        other, what, wrong = UNITS[at - 1], "far more, even still", "small"
    else:
        return None
    how = unit.partition(" ")[2]
    how = how[1:-1] if how.startswith("(") and how.endswith(")") else how or "given"
    return (f"read as {UNIT_NAMES[read]}, {how}: "
            f"{t_us.size} events over {span:.3g} s on {n_pixels} pixels, {rate:.3g} "
            f"events/s per pixel (an event camera's pixels average {what}): "
            f"{UNIT_NAMES[other]}? If so, read with --time-unit {other} (time_unit="
            f"'{other}' in Python); every speed is 1000x too {wrong} otherwise")
