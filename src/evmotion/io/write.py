"""Writing events: the output format from a file name (:func:`format_for_output`) and the
atomic writer of any writable format (:func:`write_events`).

Examples
--------
>>> from evmotion.io.write import format_for_output
>>> format_for_output("out.aedat4")
'aedat4'
"""

from __future__ import annotations

import inspect
import os
import warnings
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from evmotion.errors import EvmotionWarning, FormatError, ParameterError
from evmotion.events import EventArray, check_follows, concatenate
from evmotion.io.registry import all_formats, get_format

__all__ = ["format_for_output", "suffix_formats", "write_events"]


# Extensions shared by several formats (jAER also used .dat) get their usual meaning.
_EXT_WRITERS = {".h5": "h5", ".hdf5": "h5", ".txt": "ecd", ".npy": "npy", ".npz": "npy",
                ".dat": "dat", ".raw": "evt3", ".aedat4": "aedat4", ".aedat": "aedat2"}


def format_for_output(path: str | os.PathLike, option: str = "format=") -> str:
    """Format name chosen for writing ``path`` from its extension; an unknown extension
    raises FormatError, whose hint names ``option``, the way the caller takes a format
    (``--format-out`` in ``evmotion convert``, ``--format`` in ``evmotion simulate``).

    Examples
    --------
    >>> format_for_output("out.h5")
    'h5'
    >>> format_for_output("out", "--format")
    Traceback (most recent call last):
    ...
    evmotion.errors.FormatError: out: cannot tell the output format from the extension '' (use one of ..., or name the format with --format)
    """
    named = suffix_formats(path)
    if named:
        return named[0]
    writable = sorted({s for f in all_formats() if f.write for s in f.extensions})
    raise FormatError(path, "cannot tell the output format from the extension "
                            f"'{Path(path).suffix.lower()}'",
                      f"use one of {', '.join(writable)}, or name the format with {option}")


def suffix_formats(path: str | os.PathLike) -> list[str]:
    """The writable formats whose files ``path``'s extension names, the one
    :func:`format_for_output` picks first; empty for an extension no writer knows.

    Examples
    --------
    >>> suffix_formats("out.raw")
    ['evt3', 'evt2', 'evt21']
    >>> suffix_formats("out.bin")
    []
    """
    suffix = Path(path).suffix.lower()
    named = [f.name for f in all_formats() if f.write is not None and suffix in f.extensions]
    usual = _EXT_WRITERS.get(suffix)
    if usual in named:
        named.remove(usual)
        named.insert(0, usual)
    return named


_STREAMING_WRITERS = ("h5", "ecd", "dat", "evt2", "evt21", "evt3", "aedat2", "aedat3",
                      "aedat4")


def write_events(path: str | os.PathLike, events: EventArray | Iterable[EventArray],
                 format: str | None = None, **meta) -> None:
    """Write events atomically (nothing appears at ``path`` until the file is complete).

    Parameters
    ----------
    path : path-like
        Output file; the format follows the extension (``.h5`` evmotion HDF5, ``.txt``
        ECD text, ``.npz``/``.npy``, ``.raw``, ``.dat``, ``.aedat4``...).
    events : EventArray or iterable of EventArray
        Chunks in time order are streamed in bounded memory by the ``h5``, ``ecd``,
        ``dat``, ``evt2``, ``evt21``, ``evt3``, ``aedat2``, ``aedat3`` and ``aedat4``
        writers (``npz``/``npy``, ``mvsec``, ``dsec`` and ``rosbag`` concatenate them first).
    format : str, optional
        Format name, overriding the extension.
    **meta
        Writer options (e.g. ``calibration={...}`` for ``h5``); any other keyword is
        metadata, stored in the ``h5`` provenance attribute (other formats cannot store
        it and warn).

    Examples
    --------
    >>> ev = EventArray(x=[1, 2, 3], y=[0, 1, 2], t=[10, 20, 30], p=[1, 0, 1],
    ...                 sensor_size=(180, 240))
    >>> write_events("out.h5", ev, provenance={"tool": "evmotion convert"})
    >>> from evmotion.io import read_events
    >>> read_events("out.h5").meta["provenance"]
    {'tool': 'evmotion convert'}
    """
    name = format or format_for_output(path)
    spec = get_format(name)
    if spec.write is None:
        raise FormatError(path, f"format '{name}' is read-only",
                          "write .h5, .txt, .npz or another writable format")
    if isinstance(events, np.ndarray) or not isinstance(events, (EventArray, Iterable)):
        raise ParameterError(f"write_events: events must be an EventArray or an iterable of "
                             f"them, got {type(events).__name__} (a structured array: "
                             "EventArray.from_structured(arr, sensor_size))")
    if not isinstance(events, EventArray):
        events = _event_arrays(events)
        if name not in _STREAMING_WRITERS:
            events = concatenate(list(events))
    if isinstance(events, EventArray) and name == "npy" and Path(path).suffix.lower() == ".npy":
        warnings.warn(f"{path}: a .npy file keeps no sensor size ({events.width}x"
                      f"{events.height} px is left out; reading it back takes the largest "
                      "coordinates): write .npz to keep it", EvmotionWarning, stacklevel=2)
    opts, extra = {}, {}
    for k, v in meta.items():
        (opts if _accepts_named(spec.write, k) else extra)[k] = v
    if extra:
        if _accepts_named(spec.write, "provenance"):
            opts["provenance"] = {**(opts.get("provenance") or {}), **extra}
        else:
            warnings.warn(f"format '{name}' cannot store metadata {sorted(extra)}; "
                          "write .h5 to keep it", EvmotionWarning, stacklevel=2)
    try:
        spec.write(Path(path), events, **opts)
    except FormatError as exc:
        if exc.path is not None:
            raise
        # a writer's check of the events (float coordinates, a sensor beyond its address
        # range) names no file: the output it was refused for is the one to name (probe)
        raise FormatError(path, exc.message, exc.hint) from None


def _event_arrays(items: Iterable) -> Iterator[EventArray]:
    """``items``, each checked to be an EventArray (a list of rows or a dict of columns
    had met an AttributeError deep in a writer: probe) that starts no earlier than the
    previous one ended: each chunk is sorted, but a step back between two had gone into
    a text file unsaid, which reading it then refused (probe DJ)."""
    seen, last_t = 0, None
    for i, item in enumerate(items):
        if not isinstance(item, EventArray):
            raise ParameterError(f"write_events: item {i} of events is a "
                                 f"{type(item).__name__}, not an EventArray (columns: "
                                 "EventArray(x, y, t, p, sensor_size))")
        if len(item):
            check_follows(last_t, item, at=seen - 1)
            last_t = int(item.t[-1])
            seen += len(item)
        yield item


def _accepts_named(fn, name: str) -> bool:
    try:
        return name in inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return False
