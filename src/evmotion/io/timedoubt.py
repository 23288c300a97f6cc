"""Doubts about the unit of event times a reader guessed (from their type, or the unit
its format states): times whose rate or steps no event camera makes in that unit, and the
unit that would fit, for a warning that names it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["unit_doubt"]


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
