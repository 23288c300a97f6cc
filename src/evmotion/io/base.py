"""The interface every format module implements.

Each module in :mod:`evmotion.io` that handles a file format defines a module-level
``FORMAT = FormatSpec(...)``; :mod:`evmotion.io.registry` finds them by name.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Self

from evmotion.events import EventArray
from evmotion.utils import interrupts_deferred


@dataclass(frozen=True)
class FormatSpec:
    """How to detect, read, stream and write one format.

    Attributes
    ----------
    name : str
        Short name used on the CLI (``--format``) and in ``info`` output, e.g. ``"evt3"``.
    extensions : tuple of str
        Lower-case file suffixes (with dot), or ``()`` for folder layouts.
    sniff : callable(path, head) -> bool
        True when the file (``head`` = its first 4096 bytes, ``b""`` for a folder)
        is of this format. Detection is by content; extensions only break ties.
    read : callable(path, **kw) -> EventArray
        Whole file (``t0``/``t1`` in µs may restrict it).
    iter_chunks : callable(path, chunk_events, **kw) -> Iterator[EventArray] or None
        Streaming in bounded memory.
    write : callable(path, events, **kw) -> None or None
        Atomic writer, if the format is writable.
    describe : callable(path) -> dict or None
        What else the file holds (frames, IMU, ground truth, calibration...).

    ``sniff``, ``read``, ``iter_chunks`` and ``describe`` are stored wrapped by
    :mod:`evmotion.io.guard`: whatever a corrupt file makes them raise reaches the caller
    as a one-line :class:`~evmotion.errors.FormatError` naming the file.
    """

    name: str
    extensions: tuple[str, ...]
    sniff: Callable[[Path, bytes], bool]
    read: Callable[..., EventArray]
    iter_chunks: Callable[..., Iterator[EventArray]] | None = None
    write: Callable[..., None] | None = None
    describe: Callable[[Path], dict] | None = None

    def __post_init__(self) -> None:
        from evmotion.io.guard import guard_call, guard_iter

        wrap = {"sniff": (guard_call, "recognise"), "read": (guard_call, "read"),
                "iter_chunks": (guard_iter, "read"), "describe": (guard_call, "describe")}
        for name, (guard, action) in wrap.items():
            fn = getattr(self, name)
            if fn is not None and not getattr(fn, "__evmotion_guarded__", False):
                # frozen dataclass: set once, at construction
                object.__setattr__(self, name, guard(fn, self.name, action))


class _WholeSteps(type):
    """Creating a writer and aborting it run with Ctrl-C and SIGTERM deferred
    (:func:`~evmotion.utils.interrupts_deferred`): an interrupt that came while the
    constructor was writing the new ``.part`` file's header aborts the writer as the
    constructor returns (the caller never held it, so nothing else could), and one that
    came during ``abort`` waits until the file is removed or closed."""

    def __new__(mcls, name, bases, namespace):
        if "abort" in namespace:
            namespace["abort"] = _deferring(namespace["abort"])
        return super().__new__(mcls, name, bases, namespace)

    def __call__(cls, *args, **kwargs):
        with interrupts_deferred() as held:
            writer = super().__call__(*args, **kwargs)
            if held:
                writer.abort()
        return writer


def _deferring(method: Callable) -> Callable:
    @functools.wraps(method)
    def run(self, *args, **kwargs):
        with interrupts_deferred():
            return method(self, *args, **kwargs)
    return run


class PartFileWriter(metaclass=_WholeSteps):
    """The context-manager protocol of the streaming writers, which write to a ``.part``
    file: leaving the ``with`` block normally calls :meth:`close` (finish the file and
    rename it onto the final name), leaving it by an exception calls :meth:`abort`.
    Neither creating a writer nor its ``abort`` is cut in two by Ctrl-C (see
    :class:`_WholeSteps`)."""

    def close(self) -> None:
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


#: Names other tools give the fields of events (lowercase): columns of text headers, arrays
#: of .npz files, fields of structured arrays. A time name may carry its unit
#: (:func:`time_unit_in_name`: ``t_ns``, ``timestamp_us``, ``t[s]``).
EVENT_FIELD_NAMES = {
    "t": ("t", "ts", "time", "times", "timestamp", "timestamps"),
    "x": ("x", "xs"), "y": ("y", "ys"),
    "p": ("p", "pol", "polarity", "polarities", "ps")}

# a name with a unit: t_ns, timestamp_us, t[s], t(ms), time_µs
#: Microseconds per unit of the time units a field name or ``time_unit`` may state.
TIME_UNIT_US = {"s": 1e6, "ms": 1e3, "us": 1.0, "ns": 1e-3}
_UNIT_NAME = re.compile(r"([a-z_]*?[a-z])(?:_|\[|\()(ns|us|µs|ms|s)[\])]?")


def split_unit(name: str) -> tuple[str, str | None]:
    """A field name without the time unit it ends with, and that unit (``"s"``, ``"ms"``,
    ``"us"`` or ``"ns"``; None when it states none).

    Examples
    --------
    >>> split_unit("timestamp_us"), split_unit("t[s]"), split_unit("x")
    (('timestamp', 'us'), ('t', 's'), ('x', None))
    """
    low = str(name).lower()
    m = _UNIT_NAME.fullmatch(low)
    if m is None or m[1] not in EVENT_FIELD_NAMES["t"]:
        return low, None
    return m[1], m[2].replace("µ", "u")


def event_fields(names) -> dict[str, str] | None:
    """Which of ``names`` holds each of ``t``, ``x``, ``y``, ``p`` (by
    :data:`EVENT_FIELD_NAMES`, case-insensitive; a time name may end with its unit), or
    None when one is missing.

    Examples
    --------
    >>> event_fields(["timestamp", "x", "y", "polarity"])
    {'t': 'timestamp', 'x': 'x', 'y': 'y', 'p': 'polarity'}
    >>> event_fields(["x", "y", "t_ns", "p"])["t"]
    't_ns'
    >>> event_fields(["a", "b"]) is None
    True
    """
    found = {}
    for key, aliases in EVENT_FIELD_NAMES.items():
        hit = next((n for n in names if split_unit(n)[0] in aliases), None)
        if hit is None:
            return None
        found[key] = hit
    return found


def time_unit_in_name(name: str) -> str | None:
    """The unit a time field's name states (``t_us`` -> ``"us"``), else None.

    Examples
    --------
    >>> time_unit_in_name("t_us"), time_unit_in_name("timestamp")
    ('us', None)
    """
    return split_unit(name)[1]
