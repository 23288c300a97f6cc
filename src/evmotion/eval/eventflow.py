"""Accuracy of per-event flow (one velocity per event, e.g. the triplet matcher's output)
against dense ground-truth flow windows.

Each event ``k`` at ``(x_k, y_k, t_k)`` with a flow (its ``valid`` flag) is compared with the
ground truth of the GT window ``[t0_j, t1_j)`` that contains ``t_k``, held constant over
the window (as ``evmotion eval`` integrates the same ground truth for dense windows; the
simulator's windows are its frame intervals with the flow at their start, MVSEC's and
DSEC's the displacement over the interval divided by its duration), looked up bilinearly
at the event's sub-pixel position. The errors are reported in px/s and, as in the MVSEC
protocol, as displacements in px over ``frames`` GT frame intervals: both vectors times
``frames * (t1_j - t0_j)``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from evmotion.errors import EmptyWindowError, ParameterError
from evmotion.eval.metrics import NPE_THRESHOLDS, check_npe_thresholds, warn_no_better_than_zero
from evmotion.eval.windows import ground_truth_arrays
from evmotion.events import as_timestamps_us
from evmotion.utils import is_finite_number

if TYPE_CHECKING:
    from evmotion.io.eventflow import EventFlow
    from evmotion.io.flowfiles import FlowSequence

__all__ = ["EventFlowMetrics", "event_flow_metrics"]


@dataclass(frozen=True)
class EventFlowMetrics:
    """Per-event flow accuracy over the scored events (valid flow and valid ground truth).

    Attributes
    ----------
    aee : float
        Average endpoint error in px of displacement over ``frames`` GT frame intervals.
    aee_px_s : float
        Average endpoint error of the velocities in px/s.
    npe : dict of int to float
        ``npe[N]``: percentage of scored events with a displacement error > N px.
    pct_out : float
        Percentage of scored events with a displacement error > ``out_px`` px.
    ae_deg : float
        Mean angle in degrees between the space-time vectors ``(dx, dy, 1)`` of the
        displacements (so it depends on ``frames``, as the dense AE on the window).
    n_events : int
        Events in the file.
    n_scored : int
        Events with a flow and ground truth: the ones averaged over.
    n_no_flow : int
        Events the estimator gave no flow (``valid`` false).
    n_no_gt : int
        Events with a flow but no ground truth: outside every GT window, off the GT grid,
        or on a pixel whose ground truth is invalid.
    frames : float
        GT frame intervals the displacements span (MVSEC ``dt``).
    out_px : float
        %Out threshold in px.
    windows : tuple of dict
        One row per GT window with scored events (``window`` index in the GT,
        ``t0_us``, ``t1_us``, ``n_events``, ``AEE``, ``AEE_px_s``, ``%Out``, ``AE_deg``),
        when asked for; empty otherwise.
    aee_zero : float
        The zero flow's AEE on the same events, px over ``frames`` GT frame intervals:
        the ground truth's mean displacement, against which ``aee`` is read.
    """

    aee: float
    aee_px_s: float
    npe: dict[int, float]
    pct_out: float
    ae_deg: float
    n_events: int
    n_scored: int
    n_no_flow: int
    n_no_gt: int
    frames: float
    out_px: float
    windows: tuple[dict, ...] = field(default_factory=tuple)
    aee_zero: float = float("nan")

    @property
    def valid_fraction(self) -> float:
        """Share of the events that have a flow (0..1)."""
        return (self.n_events - self.n_no_flow) / self.n_events

    @property
    def scored_fraction(self) -> float:
        """Share of the events scored (0..1)."""
        return self.n_scored / self.n_events

    def as_dict(self) -> dict[str, float | int]:
        """Flat dict (``"3PE"`` style keys, as :meth:`FlowMetrics.as_dict`) without the
        per-window rows."""
        d: dict[str, float | int] = {"AEE": self.aee, "AEE_px_s": self.aee_px_s,
                                     "AEE_zero": self.aee_zero}
        d.update({f"{n}PE": v for n, v in self.npe.items()})
        d.update({"%Out": self.pct_out, "AE_deg": self.ae_deg, "n_events": self.n_events,
                  "n_scored": self.n_scored, "n_no_flow": self.n_no_flow,
                  "n_no_gt": self.n_no_gt, "valid_fraction": self.valid_fraction,
                  "scored_fraction": self.scored_fraction})
        return d


# events scored at a time (bounded memory)
EVAL_CHUNK = 1 << 21


def event_flow_metrics(
    event_flow: EventFlow | Mapping[str, np.ndarray],
    gt: FlowSequence,
    *,
    frames: float = 1.0,
    out_px: float = 3.0,
    npe_thresholds: Iterable[int] = NPE_THRESHOLDS,
    per_window: bool = False,
) -> EventFlowMetrics:
    """Accuracy of a per-event flow against ground-truth flow windows.

    Parameters
    ----------
    event_flow : EventFlow or mapping of str to ndarray
        Per-event columns (:func:`evmotion.io.eventflow.read_event_flow`): ``t`` (N,) int
        µs, ``x``, ``y`` (N,) px (column, row; sub-pixel when undistorted), ``vx``, ``vy``
        (N,) px/s (u right, v down) and optionally ``valid`` (N,) bool (default: every
        event has a flow). An :class:`~evmotion.io.eventflow.EventFlow`'s ``sensor_size``
        must equal the ground truth's.
    gt : FlowSequence
        Ground truth (:func:`evmotion.io.flowfiles.read_gt_flow`): ``flow`` (M, H, W, 2)
        px/s, ``t0``, ``t1`` (M,) µs, ``valid`` (M, H, W) bool or None.
    frames : float
        The displacements span ``frames`` times the duration of the GT window that holds
        the event (MVSEC ``dt = 1`` or ``4``; > 0).
    out_px : float
        %Out threshold in px of displacement (thesis §4.3.1: 3 px).
    npe_thresholds : iterable of int
        N values for the NPE percentages in px (default 1, 2, 3, 5, 10, 20).
    per_window : bool
        Also return one row per GT window (:attr:`EventFlowMetrics.windows`).

    Returns
    -------
    EventFlowMetrics
        Means over the scored events (each event weighs the same, whatever its window).
        The GT at an event is the bilinear interpolation of the valid GT pixels around it;
        the event is scored when the GT pixel nearest to it is valid (finite, and in
        ``gt.valid``).

    Raises
    ------
    EmptyWindowError
        No event, or no event with both a flow and ground truth (the message gives the
        events' and the ground truth's time spans).
    EventDataError
        Timestamps that are not whole µs (seconds, NaN).
    ParameterError
        Columns of different lengths, a grid other than the ground truth's, an event with
        a flow that is NaN/inf, ``frames`` or ``out_px`` not finite and > 0.

    Examples
    --------
    >>> from evmotion.io.flowfiles import FlowSequence
    >>> gt = FlowSequence(flow=np.full((1, 4, 5, 2), [100.0, 0.0], np.float32),
    ...                   t0=np.array([0]), t1=np.array([10_000]))
    >>> ev = {"t": np.array([1_000, 9_000]), "x": np.array([1.0, 2.5]),
    ...       "y": np.array([1.0, 2.0]), "vx": np.array([100.0, 400.0]), "vy": np.zeros(2)}
    >>> m = event_flow_metrics(ev, gt)  # errors 0 and 300 px/s, 0 and 3 px over 10 ms
    >>> m.aee_px_s, m.aee, m.pct_out, m.n_scored
    (150.0, 1.5, 0.0, 2)
    """
    for name, value in (("frames", frames), ("out_px", out_px)):
        if not (is_finite_number(value) and value > 0):
            raise ParameterError(f"{name} must be a finite number > 0, got {value!r}")
    cols = {k: np.asarray(event_flow[k]) for k in ("t", "x", "y", "vx", "vy")}
    if _has_valid(event_flow):
        cols["valid"] = np.asarray(event_flow["valid"])
    shapes = {k: a.shape for k, a in cols.items()}
    if len(set(shapes.values())) != 1 or cols["t"].ndim != 1:
        raise ParameterError(f"per-event columns must be 1-D of one length, got shapes {shapes}")
    n = cols["t"].shape[0]
    if n == 0:
        raise EmptyWindowError("no events: the per-event flow is empty")
    # µs as the ground truth's windows; seconds were floored to 0 and scored against the
    # first window (probe AU)
    cols["t"] = as_timestamps_us(cols["t"])
    gflow, gt0, gt1, gvalid = ground_truth_arrays(gt)
    if gflow.shape[0] == 0:
        raise EmptyWindowError("the ground truth has no window")
    h, w = gflow.shape[1:3]
    size = getattr(event_flow, "sensor_size", None)
    if size is not None and tuple(int(s) for s in size) != (h, w):
        raise ParameterError(f"the per-event flow is on a {tuple(size)} px grid but the ground "
                             f"truth is {(h, w)} px (height, width)")
    thresholds = check_npe_thresholds(npe_thresholds)
    order = np.argsort(gt0, kind="stable")
    # sums of the endpoint error px, px/s, %Out hits, AE degrees and the GT's displacement
    acc = np.zeros(5)
    npe = np.zeros(len(thresholds))
    per = np.zeros((5, gt0.size))  # per GT window: count, then the four sums
    n_scored = n_flow = 0
    # in chunks: a whole recording's float64 temporaries took 5 GB at 15 M events
    for a in range(0, n, EVAL_CHUNK):
        part = slice(a, min(a + EVAL_CHUNK, n))
        t = cols["t"][part].astype(np.int64)
        x = cols["x"][part].astype(np.float64)
        y = cols["y"][part].astype(np.float64)
        vel = np.stack([cols["vx"][part], cols["vy"][part]], axis=1).astype(np.float64)
        valid = cols["valid"][part].astype(bool) if "valid" in cols else np.ones(t.size, bool)
        n_flow += int(valid.sum())
        bad = valid & ~np.isfinite(vel).all(axis=1)
        if bad.any():
            every = ~(np.isfinite(cols["vx"]) & np.isfinite(cols["vy"]))
            if "valid" in cols:
                every &= cols["valid"].astype(bool)
            raise ParameterError(f"{int(every.sum())} events marked valid have a NaN/inf flow "
                                 f"(first at t={int(t[bad][0])} µs)")
        # the GT window holding each event: the latest one starting at or before it
        k = np.searchsorted(gt0[order], t, side="right") - 1
        win = order[np.clip(k, 0, None)]
        has_gt = (k >= 0) & (t < gt1[win]) & (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
        cand = np.flatnonzero(valid & has_gt)
        gvel, ok = _sample_gt(gflow, gvalid, win[cand], x[cand], y[cand])
        sel = cand[ok]
        if not sel.size:
            continue
        win = win[sel]
        dur_s = (gt1[win] - gt0[win]).astype(np.float64) * 1e-6 * float(frames)
        est = vel[sel]
        ref = gvel[ok]
        err_s = np.hypot(est[:, 0] - ref[:, 0], est[:, 1] - ref[:, 1])
        ee = err_s * dur_s
        de, dg = est * dur_s[:, None], ref * dur_s[:, None]
        num = (de * dg).sum(axis=1) + 1.0
        den = np.sqrt((de * de).sum(axis=1) + 1.0) * np.sqrt((dg * dg).sum(axis=1) + 1.0)
        ae = np.degrees(np.arccos(np.clip(num / den, -1.0, 1.0)))
        out = (ee > out_px).astype(np.float64)
        n_scored += int(sel.size)
        acc += [ee.sum(), err_s.sum(), out.sum(), ae.sum(),
                (np.hypot(ref[:, 0], ref[:, 1]) * dur_s).sum()]
        npe += [np.count_nonzero(ee > m) for m in thresholds]
        for row, v in enumerate((None, ee, err_s, out, ae)):
            per[row] += np.bincount(win, weights=v, minlength=gt0.size)
    n_no_flow = n - n_flow
    if n_scored == 0:
        t_all = cols["t"]
        raise EmptyWindowError(
            f"no event has both a flow and ground truth: {n} events ({n_flow} with a "
            f"flow) at t = {int(t_all.min())}..{int(t_all.max())} µs, ground truth {gt0.size} "
            f"windows at t = {int(gt0.min()) if gt0.size else 0}.."
            f"{int(gt1.max()) if gt1.size else 0} µs")
    rows: tuple[dict, ...] = ()
    if per_window:
        rows = _window_rows(per, gt0, gt1)
    mean = acc / n_scored
    warn_no_better_than_zero(float(mean[0]), float(mean[4]),
                             f"the flow of {n_scored} events against the ground truth")
    return EventFlowMetrics(
        aee=float(mean[0]), aee_px_s=float(mean[1]),
        npe={m: float(100.0 * c / n_scored) for m, c in zip(thresholds, npe, strict=True)},
        pct_out=float(100.0 * mean[2]), ae_deg=float(mean[3]), n_events=int(n),
        n_scored=int(n_scored), n_no_flow=n_no_flow, n_no_gt=int(n - n_no_flow - n_scored),
        frames=float(frames), out_px=float(out_px), windows=rows, aee_zero=float(mean[4]))


def _has_valid(event_flow) -> bool:
    try:
        event_flow["valid"]
    except KeyError:
        return False
    return True


def _sample_gt(flow: np.ndarray, valid: np.ndarray | None, j: np.ndarray, x: np.ndarray,
               y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GT flow of window ``j[k]`` at ``(x[k], y[k])`` (inside the grid): bilinear over the
    valid ones of the four pixels around it, renormalised, so that an invalid neighbour
    (MVSEC's zero, NaN) does not pull the value towards zero; usable where the nearest
    pixel is valid (its weight is then >= 1/4)."""
    h, w = flow.shape[1:3]
    x0 = np.minimum(np.floor(x).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(h - 2, 0))
    ax, ay = x - x0, y - y0
    num = np.zeros((x.size, 2))
    den = np.zeros(x.size)
    for dy, dx, wgt in ((0, 0, (1 - ax) * (1 - ay)), (0, 1, ax * (1 - ay)),
                        (1, 0, (1 - ax) * ay), (1, 1, ax * ay)):
        yy, xx = np.minimum(y0 + dy, h - 1), np.minimum(x0 + dx, w - 1)
        f = flow[j, yy, xx].astype(np.float64)
        good = np.isfinite(f).all(axis=1)
        if valid is not None:
            good &= valid[j, yy, xx]
        wk = np.where(good, wgt, 0.0)
        num += np.where(good[:, None], f, 0.0) * wk[:, None]
        den += wk
    yi, xi = np.rint(y).astype(np.int64), np.rint(x).astype(np.int64)
    near = flow[j, yi, xi]
    ok = np.isfinite(near).all(axis=1)
    if valid is not None:
        ok &= valid[j, yi, xi]
    return num / np.where(ok, den, 1.0)[:, None], ok


def _window_rows(per: np.ndarray, gt0, gt1) -> tuple[dict, ...]:
    """One row per GT window holding scored events, from ``per``: counts, then the sums of
    the endpoint error (px, px/s), the %Out hits and the AE (degrees) per window."""
    ids = np.flatnonzero(per[0])
    c = per[0][ids]
    return tuple({"window": int(i), "t0_us": int(gt0[i]), "t1_us": int(gt1[i]),
                  "n_events": int(n), "AEE": float(a / n), "AEE_px_s": float(s / n),
                  "%Out": float(100.0 * o / n), "AE_deg": float(d / n)}
                 for i, n, a, s, o, d in zip(ids, c, per[1][ids], per[2][ids], per[3][ids],
                                             per[4][ids], strict=True))
