"""Multi-reference flow over many windows in parallel, what
:func:`evmotion.methods.multicm.estimate_flow_sequence` runs with ``workers > 1`` or a
``scheduler``: the windows are split into contiguous chunks, one per worker, and each
chunk is estimated window after window, every window warm-started from the one before (the
first window of a chunk from zero flow), on local worker processes or a Dask cluster
(:func:`evmotion.parallel.map_windows`).

The same chunks give the same flow whoever runs them: ``workers`` chunks on a cluster equal
``workers`` local processes.
"""

from __future__ import annotations

import dataclasses
import functools
import re
import warnings
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from evmotion.errors import EvmotionWarning, ParameterError
from evmotion.events import EventArray, Window

__all__ = ["estimate_in_chunks", "iter_chunks"]


def _lean(res, keep_iwes: bool):
    # the four full-size IWEs are 15 MB a window at 1280x720: drop them unless wanted
    return res if keep_iwes else dataclasses.replace(res, iwes={})


def _chunk(events: EventArray, t0: int, t1: int, *, windows, kwargs, keep_iwes):
    """Worker: the windows of one chunk ``[t0, t1)`` µs, warm-started in sequence, each
    with the warnings it issued (said where its result arrives, :func:`iter_chunks`, so
    that a command names the window). ``events`` are the chunk's events; ``windows``
    carry their index ranges in the whole recording, so that each window gets exactly the
    events of a serial run (cutting by time would move events that share a timestamp
    across a boundary)."""
    from evmotion.methods.multicm import estimate_flow_sequence, warms
    from evmotion.parallel import collected_warnings

    mine = [w for w in windows if t0 <= w.t0 < t1]
    offset = mine[0].start if mine else 0
    out, init = [], None
    for w in mine:
        with collected_warnings() as said:
            [res] = estimate_flow_sequence(
                events, [Window(w.index, w.t0, w.t1, w.start - offset, w.stop - offset)],
                init=init, **kwargs)
        if warms(res, kwargs):
            init = res
        # a skipped window is said by iter_chunks, with its index in the whole recording
        out.append((_lean(res, keep_iwes), [s for s in said if not _SKIPPED.search(s[1])]))
    return out


_SKIPPED = re.compile(r"window \d+ .* skipped")


def estimate_in_chunks(events: EventArray, windows: Sequence[Window], *, workers: int = 2,
                          scheduler: Any = None, keep_iwes: bool = True,
                          **kwargs: Any) -> list:
    """Multi-reference flow of every window, in window order, from contiguous chunks of
    windows run in parallel (see the module).

    Parameters
    ----------
    events : EventArray
        The recording.
    windows : sequence of Window
        Windows with their index ranges (:func:`evmotion.events.make_windows`), in time
        order.
    workers : int
        Number of chunks (and local worker processes).
    scheduler : distributed.Client, optional
        Run the chunks on this Dask cluster instead of local processes.
    keep_iwes : bool
        Keep each result's images of warped events (large at high resolution).
    **kwargs
        Options of :func:`evmotion.methods.multicm.estimate_flow` (``init`` is refused:
        each chunk starts from zero flow).

    Returns
    -------
    list of MultiCMResult

    Raises
    ------
    ParameterError
        A chunk failed, or windows starting at the same µs could not be cut into chunks.
    """
    return list(iter_chunks(events, windows, workers=workers, scheduler=scheduler,
                            keep_iwes=keep_iwes, **kwargs))


def iter_chunks(events: EventArray, windows: Sequence[Window], *, workers: int = 2,
                scheduler: Any = None, keep_iwes: bool = True, **kwargs: Any) -> Iterator:
    """:func:`estimate_in_chunks` as a generator: the windows' results in window order,
    each chunk's as soon as it and the chunks before it are done, so that a caller writes
    the first chunk's windows while the others still run. The first chunk is the shortest
    (the windows are split as evenly as they go, the remainder to the later chunks), so
    it ends first. Parameters and errors as :func:`estimate_in_chunks`; the checks run
    at the first ``next()``.
    """
    from evmotion.parallel import imap_windows, reissue_warnings

    if isinstance(workers, bool) or not isinstance(workers, (int, np.integer)) or workers < 1:
        raise ParameterError(f"workers must be an integer >= 1, got {workers!r}")
    if kwargs.get("init") is not None:
        raise ParameterError("init cannot seed windows split into chunks (each chunk "
                             "starts from zero flow); use workers=1")
    fn = functools.partial(_chunk, windows=list(windows), kwargs=kwargs, keep_iwes=keep_iwes)
    bounds = np.linspace(0, len(windows), min(workers, len(windows)) + 1).astype(int)
    spans = [(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True) if b > a]
    # a Window is sent by its index range: the chunk's events, exactly
    chunks = [Window(k, windows[a].t0, windows[b - 1].t1, windows[a].start,
                     windows[b - 1].stop) for k, (a, b) in enumerate(spans)]
    made = 0
    for r in imap_windows(fn, events, chunks, workers=workers, scheduler=scheduler,
                          with_window=True, desc="multicm", units=[b - a for a, b in spans]):
        if not r.ok:
            raise ParameterError(f"window chunk [{r.t0}, {r.t1}) us failed: {r.error}")
        made += len(r.value)
        if made > len(windows):
            break
        for k, (res, said) in enumerate(r.value, made - len(r.value)):
            reissue_warnings(said)
            if "skipped" in res.meta:
                warnings.warn(EvmotionWarning(
                    f"window {windows[k].index} [{res.t0_us}, {res.t1_us}) us skipped: "
                    f"{res.meta['skipped']}"), stacklevel=2)
            yield res
    if made != len(windows):
        # only where more than a window's worth of events share one timestamp
        raise ParameterError(f"{len(windows)} windows but the chunks made {made}: "
                             "windows starting at the same µs; use --window-us")
