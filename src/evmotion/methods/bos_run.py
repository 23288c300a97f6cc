"""Event-based BOS over the frame intervals of a recording (what ``evmotion bos`` runs).

:func:`solve_bos_input` takes the checked input of :func:`evmotion.io.bosinput.
load_bos_input` and solves every selected frame interval with
:func:`evmotion.methods.bos.estimate_bos`: in order with a warm start from the previous
interval on one worker, or in contiguous chunks with
:func:`evmotion.methods.bos.estimate_bos_sequence` on several.

The contrast threshold C is a constant of the sensor, not of the interval: unless given,
it is estimated per interval (:func:`evmotion.methods.bos.estimate_contrast_threshold`,
from the two frames bracketing it and its events) on up to ``c_samples`` intervals spread
over the sequence, and their median is used for every interval. A single interval's
estimate can be far off where few pixels change (the first interval of a starting plume:
2.6 for C = 0.2 on a 48x40 simulation, against 0.25 for the next one).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evmotion.errors import EvmotionError, ParameterError
from evmotion.io.bosinput import BosInput

__all__ = ["BosRun", "sequence_contrast_threshold", "solve_bos_input"]


@dataclass(frozen=True)
class BosRun:
    """Results of :func:`solve_bos_input`.

    Attributes
    ----------
    results : list of BosResult
        One per selected interval, in time order.
    contrast_threshold : float or None
        The C used for every interval (None where no estimate was possible).
    c_source : str
        ``"given"``, ``"median of N intervals"`` or ``"none"``.
    c_samples : ndarray
        The per-interval estimates the median was taken over.
    """

    results: list
    contrast_threshold: float | None
    c_source: str
    c_samples: np.ndarray = field(default_factory=lambda: np.zeros(0))


def sequence_contrast_threshold(data: BosInput, *, samples: int = 15
                                ) -> tuple[float | None, np.ndarray]:
    """Median of the per-interval contrast-threshold estimates over up to ``samples``
    selected intervals evenly spread over the sequence (intervals where the frames do not
    change where events fire are skipped). Returns ``(C or None, estimates)``.

    Examples
    --------
    >>> c, per_interval = sequence_contrast_threshold(load_bos_input("scene/"))  # doctest: +SKIP
    """
    from evmotion.methods.bos import estimate_contrast_threshold

    if samples < 1:
        raise ParameterError(f"samples must be >= 1, got {samples}")
    pick = np.unique(np.linspace(0, len(data.intervals) - 1, min(samples, len(data.intervals)))
                     .round().astype(int))
    estimates = []
    for j in pick:
        i, t0, t1 = (int(v) for v in data.intervals[j])
        try:
            c = estimate_contrast_threshold(data.events, data.frames[i], data.frames[i + 1],
                                            t0_us=t0, t1_us=t1, roi=data.roi)
        except EvmotionError:
            continue
        if np.isfinite(c) and c > 0:
            estimates.append(c)
    est = np.asarray(estimates, dtype=np.float64)
    return (float(np.median(est)) if est.size else None), est


def solve_bos_input(data: BosInput, *, workers: int = 1, progress: bool = False,
                    contrast_threshold: float | None = None, c_samples: int = 15,
                    scheduler=None, **options) -> BosRun:
    """Solve every selected frame interval of ``data``.

    Parameters
    ----------
    data : BosInput
        From :func:`evmotion.io.bosinput.load_bos_input`.
    workers : int
        1: the intervals in order, each warm-started from the previous one (progress per
        interval). More: contiguous chunks in parallel processes, warm-started within a
        chunk (:func:`evmotion.methods.bos.estimate_bos_sequence`).
    progress : bool
        Progress bar (rate, ETA) on stderr.
    scheduler : str or distributed.Client, optional
        Run the ``workers`` chunks on this Dask cluster instead of local processes
        (:func:`evmotion.parallel.map_windows`).
    contrast_threshold : float, optional
        C in log-intensity units; default: :func:`sequence_contrast_threshold`.
    c_samples : int
        Intervals the sequence's C is estimated on.
    **options
        :class:`evmotion.methods.bos.BosOptions` fields (``param``, ``data_term``,
        ``iterations``, ``seed``...).

    Returns
    -------
    BosRun

    Examples
    --------
    >>> run = solve_bos_input(load_bos_input("scene/"), param="poisson")  # doctest: +SKIP
    >>> run.results[0].flow.shape  # doctest: +SKIP
    (720, 640, 2)
    """
    from evmotion.methods.bos import estimate_bos, estimate_bos_sequence
    from evmotion.utils import progress as progress_bar

    if int(workers) != workers or workers < 1:
        raise ParameterError(f"workers must be an integer >= 1, got {workers!r}")
    if contrast_threshold is not None:
        c, source, samples = float(contrast_threshold), "given", np.zeros(0)
    else:
        c, samples = sequence_contrast_threshold(data, samples=c_samples)
        source = f"median of {samples.size} intervals" if c is not None else "none"
    first, last = int(data.intervals[0, 0]), int(data.intervals[-1, 0]) + 1
    frames = data.frames[first:last + 1]
    times = data.frame_times[first:last + 1]
    if workers > 1 or scheduler is not None:
        results = estimate_bos_sequence(data.events, frames, times, roi=data.roi,
                                        workers=workers, scheduler=scheduler,
                                        progress=progress,
                                        contrast_threshold=c, **options)
        return BosRun(results, c, source, samples)
    results, prev = [], None
    for k in progress_bar(range(len(times) - 1), total=len(times) - 1, desc="bos",
                          unit="interval", disable=None if progress else True):
        prev = estimate_bos(data.events, frames[k], t0_us=int(times[k]),
                            t1_us=int(times[k + 1]), frame_next=frames[k + 1], roi=data.roi,
                            init=prev, contrast_threshold=c, **options)
        results.append(prev)
    return BosRun(results, c, source, samples)
