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
#: Events a second on each pixel that fired below which a recording longer than
#: :data:`SPARSE_SPAN_S` is sparser than a still sensor's noise: its times are in a finer
#: unit than read.
MIN_PIXEL_RATE = 0.02
SPARSE_SPAN_S = 30.0
#: Below this rate on each pixel that fired, seconds are likelier microseconds than
#: milliseconds (a camera's 1-100 events/s a pixel, read a million times slow).
MICROSECONDS_RATE = 1e-4
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


def _bulk_span(t: np.ndarray) -> float:
    # the span of the times from that of their middle 99 %: one corrupt time far off made
    # the recording look sparse, and the warning then named a wrong unit (probe)
    lo, hi = np.percentile(t, [0.5, 99.5])
    return (float(hi) - float(lo)) / 0.99


def unit_doubt(t: np.ndarray, unit: str) -> str | None:
    """What makes integer times read as µs by a guess (``unit``, the reader's label:
    ``"us (inferred ...)"``) doubtful, as the rest of a warning about field 't', or None:
    all on multiples of 1000 (nanoseconds of a sensor with µs steps). Rates no camera
    makes are :func:`rate_doubt`'s, which knows the sensor.

    Examples
    --------
    >>> t = np.arange(0, 2_000_000_000, 1_000_000)
    >>> "nanoseconds? If so, read with --time-unit ns" in unit_doubt(t, "us (inferred)")
    True
    >>> unit_doubt(t + 1, "us (inferred)") is None
    True
    """
    if _ns_in_whole_microseconds(t, unit):
        return (f"holds integers, read as microseconds, that are all multiples of 1000 "
                f"({len(t)} events; as µs, millisecond steps, which event cameras do not "
                "make): nanoseconds? If so, read with --time-unit ns (time_unit='ns' in "
                "Python); every speed is 1000x too small otherwise")
    return None


def rate_doubt(t_us: np.ndarray, x: np.ndarray, y: np.ndarray,
               sensor_size: tuple[int, int], unit: str, *, given: bool = False,
               raw: np.ndarray | None = None) -> str | None:
    """What makes the times ``t_us`` (µs, as read in ``unit``, a reader's label such as
    ``"us (inferred ...)"``) of events at pixels ``x, y`` of a sensor of ``sensor_size``
    doubtful, as the rest of a warning about field 't', or None:

    - sparse: at least 1000 events over more than :data:`SPARSE_SPAN_S` s at fewer than
      :data:`MIN_PIXEL_RATE` events/s on each pixel that fired (decimal milliseconds
      read as seconds, probe BK; a unit ``given`` wrongly). Counted on the pixels that
      fired, not the sensor's: a lit region of a large sensor is no sparse recording
      (probe BM). The unit one step finer is named, and from seconds both milliseconds
      and microseconds, the latter first where the times as read (``raw``) are floats
      all whole numbers (µs stored as floats) or under :data:`MICROSECONDS_RATE`;
    - dense, for a guessed unit only (a unit given is the user's word: probe BM): at least
      10,000 events at more than :data:`MAX_PIXEL_RATE` events/s per sensor pixel
      (integer milliseconds read as µs, probe BJ).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> x, y = rng.integers(0, 64, 20_000), rng.integers(0, 64, 20_000)
    >>> t_ms = np.arange(20_000) // 50            # 50 events a millisecond, 64x64 sensor
    >>> "milliseconds? If so" in rate_doubt(t_ms, x, y, (64, 64), "us (inferred)")
    True
    >>> rate_doubt(t_ms * 1000, x, y, (64, 64), "ms (given)", given=True) is None
    True
    """
    n = t_us.size
    h, w = (int(v) for v in sensor_size)
    if n < 1000 or h * w <= 0:
        return None
    span = _bulk_span(t_us) * 1e-6
    read = unit.split()[0]
    if span <= 0 or read not in UNITS:
        return None
    at = UNITS.index(read)
    rate = n / span
    how = unit.partition(" ")[2]
    how = how[1:-1] if how.startswith("(") and how.endswith(")") else how or "given"
    said = f"read as {UNIT_NAMES[read]}, {how}: {n} events over {span:.3g} s"
    if span > SPARSE_SPAN_S and at > 0 and rate / h / w < MIN_PIXEL_RATE:
        xi = np.clip(np.asarray(x, np.int64), 0, w - 1)
        yi = np.clip(np.asarray(y, np.int64), 0, h - 1)
        fired = int(np.count_nonzero(np.bincount(yi * w + xi, minlength=h * w)))
        each = rate / max(fired, 1)
        if each < MIN_PIXEL_RATE:
            # seconds that are milliseconds or microseconds: the rate cannot tell a quiet
            # recording in ms from a busy one in µs; the likelier first (probe BM)
            finer = [UNITS[at - 1]] + (["us"] if read == "s" else [])
            whole = raw is not None and raw.dtype.kind == "f" and bool(
                np.all(raw == np.rint(raw)))
            if read == "s" and (whole or each < MICROSECONDS_RATE):
                finer.reverse()
            other = finer[0]
            alt, alt_name = ((f" (or {finer[1]})", f" (or {UNIT_NAMES[finer[1]]})")
                             if len(finer) > 1 else ("", ""))
            return (f"{said} on the {fired} pixels that fired, {each:.3g} events/s each "
                    f"(an event camera's pixels make far more, even still): "
                    f"{UNIT_NAMES[other]}{alt_name}? If so, read with --time-unit {other}{alt} "
                    f"(time_unit='{other}' in Python); every speed is "
                    f"{'a million times' if other == 'us' and read == 's' else '1000x'} "
                    "too small otherwise")
    if not given and n >= 10_000 and at + 1 < len(UNITS) and rate / h / w > MAX_PIXEL_RATE:
        other = UNITS[at + 1]
        return (f"{said} on {h * w} pixels, {rate / h / w:.3g} events/s per pixel (an event "
                f"camera's pixels average far fewer): {UNIT_NAMES[other]}? If so, read with "
                f"--time-unit {other} (time_unit='{other}' in Python); every speed is 1000x "
                "too large otherwise")
    return None
