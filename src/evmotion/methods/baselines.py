"""Baselines of the schlieren benchmark (thesis Table 6.4) on frame intervals.

* MultiCM (thesis ch. 4, :func:`evmotion.methods.multicm.estimate_flow`) on the events
  between two consecutive frames: Table 6.4's "MCM" row.
* Farneback (:func:`evmotion.methods.farneback.farneback_flow`) on each pair of consecutive
  frames: the thesis' frame-based "ground truth".

Both return one flow per frame interval ``[t_i, t_{i+1})`` in px/s, the windows of the
simulator's exact flow and of the BOS solver's output, so all can be scored alike.
"""

from __future__ import annotations

import numpy as np

from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.events import EventArray, as_timestamps_us
from evmotion.methods.farneback import farneback_flow
from evmotion.methods.multicm import FlowResult, estimate_flow

__all__ = ["farneback_intervals", "multicm_interval", "multicm_intervals"]


def _check_times(frame_times_us, n_frames: int | None = None) -> np.ndarray:
    # (1e30 overflowed and NaN failed in numpy's int64 conversion, probe API)
    t = as_timestamps_us(np.ravel(frame_times_us), "frame_times_us")
    if t.size < 2:
        raise ParameterError(f"need at least two frame times, got {t.size}")
    if np.any(np.diff(t) <= 0):
        i = int(np.argmax(np.diff(t) <= 0))
        raise ParameterError(f"frame times must increase: t[{i + 1}]={t[i + 1]} us after "
                             f"t[{i}]={t[i]} us")
    if n_frames is not None and t.size != n_frames:
        raise ParameterError(f"{t.size} frame times for {n_frames} frames")
    return t


def multicm_interval(events: EventArray, t0_us: int, t1_us: int, **kwargs) -> FlowResult:
    """MultiCM flow (px/s) from the events of one frame interval ``[t0_us, t1_us)``.

    Parameters
    ----------
    events : EventArray
        The recording (or any part covering the interval).
    t0_us, t1_us : int
        The frame times bracketing the interval, µs.
    **kwargs
        Passed to :func:`evmotion.methods.multicm.estimate_flow` (``n_scales``, ``lam``,
        ``init`` ...).

    Returns
    -------
    FlowResult
        Its ``flow`` is the dense flow in px/s; its ``t0_us``/``t1_us`` those of the first
        and last event inside the interval.

    Raises
    ------
    EmptyWindowError
        Fewer than 10 events in the interval.

    Examples
    --------
    >>> from evmotion.sim import simulate
    >>> sim = simulate("translation", duration_s=0.02, sensor_size=(40, 60), seed=0,
    ...                show_progress=False)
    >>> res = multicm_interval(sim.events, 0, 8333, n_scales=3)
    >>> res.flow.shape, 0 <= res.t0_us < res.t1_us <= 8333   # its events' span, us
    ((40, 60, 2), True)
    """
    t0, t1 = int(t0_us), int(t1_us)
    if t1 <= t0:
        raise ParameterError(f"frame interval [{t0}, {t1}) us is empty")
    window = events.slice_time(t0, t1)
    if len(window) < 10:
        raise EmptyWindowError(f"frame interval [{t0}, {t1}) us holds {len(window)} events; "
                               "MultiCM needs at least 10")
    return estimate_flow(window, **kwargs)


def multicm_intervals(events: EventArray, frame_times_us, *, warm_start: bool = True,
                      **kwargs) -> list[FlowResult]:
    """MultiCM on every frame interval ``[t_i, t_{i+1})``, each warm-started from the last.

    Parameters
    ----------
    events : EventArray
    frame_times_us : array_like (N,)
        Increasing frame times, µs: ``N - 1`` intervals.
    warm_start : bool
        Start each interval from the previous flow (default True; §4.2.4).
    **kwargs
        Passed to :func:`evmotion.methods.multicm.estimate_flow`.
    """
    t = _check_times(frame_times_us)
    out: list[FlowResult] = []
    for a, b in zip(t[:-1], t[1:], strict=True):
        init = out[-1] if (warm_start and out) else kwargs.get("init")
        out.append(multicm_interval(events, int(a), int(b), **{**kwargs, "init": init}))
    return out


def farneback_intervals(frames: np.ndarray, frame_times_us, **kwargs) -> np.ndarray:
    """Farneback flow (px/s) of every pair of consecutive frames.

    Parameters
    ----------
    frames : ndarray (N, H, W)
    frame_times_us : array_like (N,)
        Increasing frame times, µs; interval ``i`` lasts ``t[i+1] - t[i]``.
    **kwargs
        Passed to :func:`evmotion.methods.farneback.farneback_flow` (``levels`` ...).

    Returns
    -------
    ndarray of float32, shape (N - 1, H, W, 2)

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> img = rng.random((48, 48)).repeat(2, 0).repeat(2, 1)
    >>> flows = farneback_intervals(np.stack([img, np.roll(img, 1, axis=0)]), [0, 10_000])
    >>> flows.shape, bool(abs(np.median(flows[0, 20:-20, 20:-20, 1]) - 100) < 5)
    ((1, 96, 96, 2), True)
    """
    fr = np.asarray(frames)
    if fr.ndim not in (3, 4):
        raise ParameterError(f"frames must be an array (N, H, W), got shape {fr.shape}")
    t = _check_times(frame_times_us, fr.shape[0])
    out = np.empty((fr.shape[0] - 1, fr.shape[1], fr.shape[2], 2), np.float32)
    for i in range(fr.shape[0] - 1):
        out[i] = farneback_flow(fr[i], fr[i + 1], (t[i + 1] - t[i]) * 1e-6, **kwargs)
    return out
