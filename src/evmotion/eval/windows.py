"""Accuracy of dense flow windows against ground-truth flow: what ``evmotion eval`` reports
for a flow file.

For every estimated window ``[t0, t1)`` the ground-truth displacement is the GT flow
integrated over the window along the trajectories (:func:`gt_displacement`: each GT frame
weighted by its overlap, chained as in the MVSEC protocol), compared with the estimated flow
times the window's duration (:func:`evaluate_windows`).

Examples
--------
>>> import numpy as np
>>> from evmotion.io.flowfiles import FlowSequence
>>> from evmotion.eval.windows import evaluate_windows
>>> gt = FlowSequence(flow=np.full((2, 8, 8, 2), 100.0, np.float32),
...                   t0=np.array([0, 10_000]), t1=np.array([10_000, 20_000]))
>>> est = np.full((1, 8, 8, 2), 110.0, np.float32)   # px/s, 10 px/s too fast
>>> res = evaluate_windows(est, [0], [10_000], gt)
>>> round(res.total["AEE"], 4), res.mismatched   # 10 px/s * sqrt(2) over 10 ms
(0.1414, 0)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from evmotion.errors import EmptyWindowError, EventDataError, ParameterError
from evmotion.eval.metrics import (
    aggregate_flow_metrics,
    event_mask,
    events_where_defined,
    flow_metrics,
    fwl,
    warn_no_better_than_zero,
)
from evmotion.utils import MAX_TIME_US, whole_number, whole_time_us

if TYPE_CHECKING:
    from evmotion.events import EventArray
    from evmotion.io.flowfiles import FlowSequence

__all__ = ["WindowsEvaluation", "evaluate_potential", "evaluate_windows", "gt_coverage",
           "gt_displacement", "sharpness_windows"]

# a window is scored when the ground truth covers this share of it: the last window of a
# recording ends 1 us after its last event, maybe just past the ground truth's end; a 1 %
# shortfall moves its displacement by 1 % at most
FULL_COVERAGE = 0.99


@dataclass(frozen=True)
class WindowsEvaluation:
    """Accuracy of a sequence of dense flow windows.

    Attributes
    ----------
    windows : list of dict
        Per window: ``window``, ``t0_us``, ``t1_us``, the metrics of
        :func:`evmotion.eval.metrics.flow_metrics` (AEE and %Out in px of displacement
        over the window, AE in degrees), ``AE_rad``, ``gt_frames`` (GT frames spanned),
        and with events ``FWL`` / ``FWL_gt`` (the estimate's and the ground truth's).
    total : dict
        The metrics aggregated over the windows (and the mean FWL / FWL_gt).
    mismatched : int
        Windows spanning a number of GT frames other than ``dt`` (more than a fifth of
        ``dt`` off).
    mask : str
        Which pixels were scored, in words.
    uncovered : int
        Windows the ground truth covers less than 99 % of (they reach before its first or
        past its last time): listed with ``scored`` False and ``gt_coverage``, left out of
        ``total`` (their GT displacement would be only part of the motion).
    """

    windows: list[dict] = field(default_factory=list)
    total: dict = field(default_factory=dict)
    mismatched: int = 0
    mask: str = "valid GT"
    uncovered: int = 0


def gt_coverage(gt, t0: int, t1: int) -> float:
    """The share of ``[t0, t1)`` µs that the ground truth's windows cover.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> gt = SimpleNamespace(t0=np.array([0, 10]), t1=np.array([10, 20]))
    >>> gt_coverage(gt, 5, 25), gt_coverage(gt, 0, 20)
    (0.75, 1.0)
    """
    t0, t1 = _interval(t0, t1)
    a = np.maximum(gt.t0, t0)
    b = np.minimum(gt.t1, t1)
    return float(np.clip(b - a, 0, None).sum() / max(t1 - t0, 1))


def _interval(t0, t1) -> tuple[int, int]:
    """``(t0, t1)`` as ints, or ParameterError unless whole µs with ``t0 <= t1`` within
    ±2^62 (10**30 had met an OverflowError, NaN a cast error or no error, probe EVAL)."""
    a = whole_time_us("t0", t0)
    b = whole_time_us("t1", t1)
    if b < a:
        raise ParameterError(f"[t0, t1] = [{a}, {b}] us is no interval (t0 > t1)")
    return a, b


def gt_displacement(gt, t0: int, t1: int) -> tuple[np.ndarray, np.ndarray, float]:
    """GT displacement (px) over ``[t0, t1)`` µs, its validity mask, and the number of GT
    frames it spans (fractional).

    The GT frames are chained along the trajectories, as in the MVSEC protocol for
    ``dt = 4`` (Zhu et al. propagate each pixel through the per-frame flows): frame ``j``'s
    flow is sampled (bilinearly) where the pixel's scene point is after the previous
    frames, not at the pixel itself. Summing the frames at a fixed pixel instead is off
    by ``|grad v| |d|`` -- about 1 px at 20 px displacement for a camera rotation, and
    the whole object motion at a motion boundary. A pixel is valid while its point stays
    in the image on valid GT. The simulator's GT is defined everywhere and its masks say
    where events fired (``attrs["valid_is_event_mask"]``): there a pixel is valid where
    events fired in any of the frames spanned (intersected, as GT validity, a window of
    several frames kept 3.6 % of the pixels, the busiest; probe AN).
    """
    from scipy.ndimage import map_coordinates

    t0, t1 = _interval(t0, t1)
    a = np.maximum(gt.t0, t0)
    b = np.minimum(gt.t1, t1)
    overlap = np.clip(b - a, 0, None).astype(np.float64)
    sel = np.flatnonzero(overlap > 0)
    sel = sel[np.argsort(np.asarray(gt.t0)[sel], kind="stable")]
    h, w = gt.flow.shape[1:3]
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    px, py = xs.copy(), ys.copy()
    valid = np.ones((h, w), bool)
    event_masks = bool(getattr(gt, "attrs", {}).get("valid_is_event_mask", False))
    fired = np.zeros((h, w), bool)
    frames = 0.0
    for j in sel:
        inside = (px >= 0) & (px <= w - 1) & (py >= 0) & (py <= h - 1)
        valid &= inside
        coords = np.stack([np.clip(py, 0, h - 1), np.clip(px, 0, w - 1)])
        f = gt.flow[j].astype(np.float64)
        ok = np.isfinite(f).all(-1)
        if gt.valid is not None and event_masks:
            fired |= np.asarray(gt.valid[j], bool)
        elif gt.valid is not None:
            ok &= np.asarray(gt.valid[j], bool)
        # validity at the nearest GT pixel; the flow itself bilinear over the valid pixels
        # among the four (normalized by their weights: an invalid pixel's flow, unknown,
        # would otherwise enter as zero and pull its valid neighbours' GT towards it)
        iy = np.rint(coords[0]).astype(np.int64)
        ix = np.rint(coords[1]).astype(np.int64)
        valid &= ok[iy, ix]
        f = np.where(ok[..., None], f, 0.0)
        weight = map_coordinates(ok.astype(np.float64), coords, order=1, mode="nearest")
        weight = np.where(valid, np.maximum(weight, 1e-12), 1.0)
        dt_s = overlap[j] * 1e-6
        px = px + map_coordinates(f[..., 0], coords, order=1, mode="nearest") / weight * dt_s
        py = py + map_coordinates(f[..., 1], coords, order=1, mode="nearest") / weight * dt_s
        frames += overlap[j] / max(gt.t1[j] - gt.t0[j], 1)
    disp = np.stack([px - xs, py - ys], axis=-1)
    valid &= np.isfinite(disp).all(-1)
    if event_masks and gt.valid is not None:
        valid &= fired
    if sel.size == 0:
        valid[:] = False
    return disp, valid, frames


def ground_truth_arrays(gt) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """``flow`` (M, H, W, 2), ``t0``, ``t1`` (M,) int64 and ``valid`` (M, H, W) bool or
    None of the ground truth ``gt``, or :class:`ParameterError` where they do not fit
    together (a short ``t0`` had failed as a broadcast error, a (M, H, 1) ``valid`` been
    broadcast and a window scored on none of its pixels unsaid, probe EVAL)."""
    flow = np.asarray(gt.flow)
    try:
        t0 = np.asarray(gt.t0, dtype=np.int64)
        t1 = np.asarray(gt.t1, dtype=np.int64)
    except (TypeError, ValueError, OverflowError):
        raise ParameterError("ground truth t0, t1 must be whole µs") from None
    if flow.ndim != 4 or flow.shape[-1] != 2 or flow.dtype.kind not in "fiu" \
            or t0.shape != (flow.shape[0],) or t1.shape != t0.shape:
        raise ParameterError(f"ground truth flow must be numbers (M, H, W, 2) with t0, t1 "
                             f"(M,), got flow {flow.shape} {flow.dtype}, t0 {t0.shape}, t1 "
                             f"{t1.shape}")
    valid = None if gt.valid is None else np.asarray(gt.valid)
    if valid is not None and (valid.shape != flow.shape[:3] or valid.dtype.kind not in "biu"):
        raise ParameterError(f"ground truth valid is {valid.shape} {valid.dtype}, expected "
                             f"{flow.shape[:3]} bool")
    return flow, t0, t1, None if valid is None else valid.astype(bool, copy=False)


def _as_sequence(gt, t0s, t1s) -> FlowSequence:
    """``gt`` as a FlowSequence: a simulation's GroundTruth gives the exact flow of the
    windows (it failed with "'function' object has no attribute 'shape'", probe CB)."""
    from evmotion.io.flowfiles import FlowSequence

    if isinstance(gt, FlowSequence):
        ground_truth_arrays(gt)
        return gt
    if callable(getattr(gt, "flow_sequence", None)):
        return gt.flow_sequence(t0s, t1s)
    raise ParameterError(f"gt must be a FlowSequence (evmotion.io.flowfiles.read_gt_flow) or "
                         f"a simulation's GroundTruth, got {type(gt).__name__}")


def evaluate_windows(flow: np.ndarray, t0s: Sequence[int], t1s: Sequence[int],
                     gt: FlowSequence, *, events: EventArray | None = None, dt: int = 1,
                     out_px: float = 3.0, along_streamlines: bool = False
                     ) -> WindowsEvaluation:
    """Score dense flow windows against ground truth.

    Parameters
    ----------
    flow : ndarray, shape (N, H, W, 2)
        Estimated flow, px/s; NaN where the estimate is not defined (not scored).
    t0s, t1s : sequence of int
        Each window's interval ``[t0, t1)``, µs.
    gt : FlowSequence or GroundTruth
        Ground-truth flow windows (px/s) on the same grid, or a simulation's ground
        truth (:meth:`~evmotion.sim.groundtruth.GroundTruth.flow_sequence` of the windows).
    events : EventArray, optional
        The recording: restricts the score to pixels with an event in the window and adds
        the FWL of the estimate and of the ground truth.
    dt : int
        GT frames a window is meant to span (the MVSEC protocol's 1 or 4); windows that
        span another number are counted in ``mismatched``.
    out_px : float
        %Out threshold, px of displacement.
    along_streamlines : bool
        Compare the displacement of the point at each pixel at the window start: the
        window's flow (taken at its midpoint) transported to the start along its
        streamlines (eq. 4.7, Burgers) times the duration; default flow times duration.

    Returns
    -------
    WindowsEvaluation
    """
    dt = whole_number("dt", dt, lo=1)  # (NaN had counted every window as matching)
    gt = _as_sequence(gt, t0s, t1s)
    flow, t0s, t1s = _windows(flow, t0s, t1s, gt.flow.shape[1:3])
    if events is not None:
        _check_same_recording(events, flow.shape[1:3], t0s, t1s)
    _check_tiles(gt)
    rows, zeros, per_window, mismatched, unknown, uncovered = [], [], [], 0, False, 0
    for i, (t0, t1) in enumerate(zip(t0s, t1s, strict=True)):
        if t1 == t0:  # no time, nothing to score: a window without pixels
            per_window.append({"window": i, "t0_us": int(t0), "t1_us": int(t1),
                               "n_pixels": 0})
            continue
        cover = gt_coverage(gt, int(t0), int(t1))
        if cover < FULL_COVERAGE:
            uncovered += 1
            per_window.append({"window": i, "t0_us": int(t0), "t1_us": int(t1),
                               "scored": False, "gt_coverage": round(cover, 4)})
            continue
        disp_gt, valid, frames = gt_displacement(gt, int(t0), int(t1))
        if abs(frames - dt) > 0.2 * dt:  # a fifth of the frames asked for, or more
            mismatched += 1
        known = np.isfinite(flow[i]).all(axis=-1)
        est = flow[i].astype(np.float64) * (t1 - t0) * 1e-6
        if along_streamlines:
            from evmotion.methods.transport import transport_to_times

            try:
                est = transport_to_times(np.ascontiguousarray(
                    _filled(est, known).transpose(2, 0, 1)),
                    np.array([-0.5]), "burgers").flows[0].transpose(1, 2, 0)
            except ParameterError as exc:
                # which window (the refusal had named none, probe EVAL)
                raise ParameterError(f"window {i} [{int(t0)}, {int(t1)}) us: "
                                     f"{exc}") from None
        mask = valid
        # NaN where the estimate is not defined (outside a BOS ROI; .flo / .png "unknown")
        if not known.all():
            mask = mask & known
            unknown = True
        win = None
        if events is not None:
            win = events.slice_time(int(t0), int(t1))
            mask = mask & event_mask(win, flow.shape[1:3])
        gt_px = np.where(valid[..., None], disp_gt, np.nan)
        m = flow_metrics(est, gt_px, mask=mask, out_px=out_px)
        # the zero flow's AEE on the same pixels: what the estimate's AEE is to be read
        # against (a sub-pixel AEE of a window that barely moves is no achievement)
        zero = flow_metrics(np.zeros_like(est), gt_px, mask=mask, out_px=out_px)
        row = {"window": i, "t0_us": int(t0), "t1_us": int(t1), **m.as_dict(),
               "AEE_zero": zero.aee, "AE_rad": float(np.radians(m.ae_deg)),
               "gt_frames": float(f"{frames:.4g}")}
        # NaN where the ground truth is not known: its displacement there is a finite 0,
        # which kept those events in both FWLs, FWL_gt's as a still scene (probe BI)
        gt_flow = (gt_px / ((t1 - t0) * 1e-6)).astype(np.float32)
        if win is not None:
            # the events where the estimate and the ground truth are defined, for both
            # FWLs alike
            win = events_where_defined(events_where_defined(win, flow[i]), gt_flow)
        if win is not None and len(win) > 1:
            row["FWL"] = fwl(win, flow[i], t_ref_us=(int(t0) + int(t1)) // 2)
            row["FWL_gt"] = fwl(win, gt_flow, t_ref_us=(int(t0) + int(t1)) // 2)
        rows.append(m)
        zeros.append(zero)
        per_window.append(row)
    if not rows:
        raise EmptyWindowError(_nothing_to_score(t0s, t1s, gt))
    if not any(m.n_pixels for m in rows):
        # ("no window has evaluated pixels: nothing to aggregate" said not why, probe BJ)
        raise EmptyWindowError(f"none of the {len(rows)} windows has a pixel where the "
                               "estimate and the ground truth are both known"
                               + (" and an event fell" if events is not None else "")
                               + ": nothing to score")
    total = aggregate_flow_metrics(rows).as_dict()
    total["AEE_zero"] = aggregate_flow_metrics(zeros).aee
    total["AE_rad"] = float(np.radians(total["AE_deg"]))
    # (the windows without a pixel were counted here, not in the summary, probe BK)
    scored = sum(1 for r in per_window if r.get("n_pixels"))
    warn_no_better_than_zero(total["AEE"], total["AEE_zero"],
                             f"the flow of {scored} scored window{'' if scored == 1 else 's'} "
                             "against the ground truth")
    fwls = [r["FWL"] for r in per_window if "FWL" in r]
    if fwls:
        total["FWL"] = float(np.mean(fwls))
        total["FWL_gt"] = float(np.mean([r["FWL_gt"] for r in per_window if "FWL_gt" in r]))
    mask_text = ("valid GT" + (" & at least one event" if events is not None else "")
                 + (" & estimate known" if unknown else ""))
    return WindowsEvaluation(per_window, total, mismatched, mask_text, uncovered)


def sharpness_windows(flow: np.ndarray, t0s: Sequence[int], t1s: Sequence[int],
                      events: EventArray) -> list[dict]:
    """How much each dense flow window sharpens its events, with no ground truth: the FWL
    (:func:`evmotion.eval.metrics.fwl`, reference the window's middle) of the window's
    events where the estimate is known (NaN pixels: no event support, no focus, outside a
    BOS ROI, are left out, as :func:`evaluate_windows` leaves them out), with bilinear
    votes (the metric's definition) and with Gaussian votes of sigma 1 px. The bilinear
    FWL of events on integer pixels is biased low: unwarped, each event votes for one
    pixel; warped by any flow, over four (the exact flow of an 8 px translation scored
    0.95, its Gaussian FWL above 1).

    Parameters
    ----------
    flow : ndarray, shape (N, H, W, 2)
        Estimated flow in px/s, NaN where unknown.
    t0s, t1s : sequence of int
        Window bounds ``[t0, t1)`` in µs.
    events : EventArray
        The recording the flow was estimated on.

    Returns
    -------
    list of dict
        Per window: ``window``, ``t0_us``, ``t1_us``, ``n_events`` (those scored), and
        ``FWL`` and ``FWL_gauss`` where at least two events fall on known flow.

    Raises
    ------
    EventDataError
        ``events`` cannot be the recording (another sensor size, no overlap in time).

    Examples
    --------
    >>> from evmotion.events import EventArray
    >>> ev = EventArray(x=[2, 3, 4], y=[5, 5, 5], t=[0, 10_000, 20_000], p=[1, 1, 1],
    ...                 sensor_size=(10, 10))
    >>> flow = np.zeros((1, 10, 10, 2), np.float32); flow[..., 0] = 100.0
    >>> [round(r["FWL"], 2) for r in sharpness_windows(flow, [0], [20_001], ev)]
    [3.06]
    """
    flow, t0s, t1s = _windows(flow, t0s, t1s)
    _check_same_recording(events, flow.shape[1:3], t0s, t1s)
    rows = []
    for i, (t0, t1) in enumerate(zip(t0s, t1s, strict=True)):
        win = events_where_defined(events.slice_time(int(t0), int(t1)), flow[i])
        row = {"window": i, "t0_us": int(t0), "t1_us": int(t1), "n_events": len(win)}
        if len(win) > 1:
            mid = (int(t0) + int(t1)) // 2
            row["FWL"] = fwl(win, flow[i], t_ref_us=mid)
            row["FWL_gauss"] = fwl(win, flow[i], t_ref_us=mid, kernel="gaussian", sigma=1.0)
        rows.append(row)
    return rows


def _windows(flow, t0s, t1s, shape=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``flow`` (N, H, W, 2) and the windows' bounds as arrays, or ParameterError naming
    what does not fit: one flow per window, ``t0 < t1`` in whole µs, the ground truth's
    grid ``shape`` (a short flow failed as an IndexError, a list as an AttributeError)."""
    flow = np.asarray(flow)
    if flow.ndim != 4 or flow.shape[-1] != 2 or flow.dtype.kind not in "fiu":
        raise ParameterError(f"flow must be a numeric array (N, H, W, 2), got shape "
                             f"{flow.shape}, dtype {flow.dtype}")
    t0s, t1s = _bounds(len(flow), t0s, t1s, "flow")
    if shape is not None and tuple(flow.shape[1:3]) != tuple(shape):
        raise ParameterError(f"the flow is {flow.shape[2]}x{flow.shape[1]} px but the ground "
                             f"truth {shape[1]}x{shape[0]} px (W x H): not the same grid")
    return flow, t0s, t1s


def _bounds(n: int, t0s, t1s, what: str) -> tuple[np.ndarray, np.ndarray]:
    """The bounds of ``n`` windows of ``what`` as int64 arrays, or ParameterError unless
    one ``t0 <= t1`` pair of whole µs per window."""
    try:
        t0s, t1s = (np.asarray(t, dtype=np.float64).ravel() for t in (t0s, t1s))
    except (TypeError, ValueError):
        raise ParameterError("t0s and t1s must be numbers of µs") from None
    if not (n == t0s.size == t1s.size):
        raise ParameterError(f"{n} {what} windows for {t0s.size} t0s and {t1s.size} "
                             f"t1s: one {what} per window")
    # (t1 == t0: a window of no time, which flow outputs keep, without a valid pixel, so
    # that the windows' numbering holds; it was refused, and the whole output with it)
    # (past int64 the cast below warned "invalid value encountered in cast", probe OPT)
    bad = ~(np.isfinite(t0s) & np.isfinite(t1s)) | (t0s != np.round(t0s)) | (t1s < t0s) \
        | (np.abs(t0s) > MAX_TIME_US) | (np.abs(t1s) > MAX_TIME_US)
    if bad.any():
        i = int(np.argmax(bad))
        raise ParameterError(f"window {i}: [{t0s[i]:g}, {t1s[i]:g}] us is not an interval "
                             "t0 <= t1 of whole microseconds (at most 2^62)"
                             + (" (t0s and t1s swapped?)" if t1s[i] < t0s[i] else ""))
    return t0s.astype(np.int64), t1s.astype(np.int64)


def _check_tiles(gt) -> None:
    """ParameterError when the ground truth's windows overlap: each instant's motion would
    be added once per window holding it (sliding windows of 50 ms every 25 ms doubled the
    displacement, and passed the coverage test at 2.0, probe BI)."""
    order = np.argsort(np.asarray(gt.t0), kind="stable")
    t0, t1 = np.asarray(gt.t0)[order], np.asarray(gt.t1)[order]
    # (an overlap within the coverage test's 1 % of a window: times rounded to the µs)
    span = t1 - t0
    slack = (1.0 - FULL_COVERAGE) * np.minimum(span[:-1], span[1:])
    over = np.flatnonzero(t0[1:] < t1[:-1] - slack)
    if over.size:
        k = int(over[0])
        raise ParameterError(f"the ground truth's windows overlap: [{t0[k + 1]}, "
                             f"{t1[k + 1]}) us starts before [{t0[k]}, {t1[k]}) us ends; "
                             "a ground truth gives each instant's motion once (windows "
                             "that follow each other)")


def _check_same_recording(events: EventArray, shape, t0s, t1s) -> None:
    """EventDataError unless ``events`` can be the recording the flow windows were
    estimated on: the same sensor, and events within the windows' time span (events of
    another recording would mask the score with pixels that have nothing to do with it)."""
    if tuple(events.sensor_size) != tuple(shape):
        # a size the file does not state was guessed: the true one may be the flow's
        # (text events default to the ECD's 240x180, probe BK)
        guessed = events.meta.get("sensor_size_from")
        raise EventDataError(f"the events are on a {events.sensor_size[1]}x"
                             f"{events.sensor_size[0]} px sensor but the flow is {shape[1]}x"
                             f"{shape[0]} px (W x H): "
                             + (f"their size was not in the file ({guessed}): give it with "
                                f"--sensor-size {shape[0]} {shape[1]} (sensor_size="
                                f"({shape[0]}, {shape[1]}) in Python) if it is the flow's"
                                if guessed else "not the recording it was estimated on"))
    if not len(t0s):
        return
    a, b = int(np.min(t0s)), int(np.max(t1s))
    if not len(events) or int(events.t[-1]) < a or int(events.t[0]) >= b:
        span = f"[{int(events.t[0])}, {int(events.t[-1])}] us" if len(events) else "nothing"
        raise EventDataError(f"the events span {span} but the flow windows [{a}, {b}] us: "
                             "they do not overlap in time (another recording, or another "
                             "time origin?)")


def _nothing_to_score(t0s, t1s, gt) -> str:
    """Why no window was scored: the windows' and the ground truth's time spans."""
    if not len(gt.t0):
        return "the ground truth holds no window: nothing to score"
    a, b = int(np.min(t0s)), int(np.max(t1s))
    c, d = int(np.min(gt.t0)), int(np.max(gt.t1))
    inside = [(int(t0), int(t1)) for t0, t1 in zip(t0s, t1s, strict=True)
              if c <= t0 and t1 <= d and t1 > t0]
    if b <= c or a >= d:
        why = "they do not overlap in time (another recording, or another time origin?)"
    elif inside:
        # (it said no window lay within the ground truth's span of a window that did, in
        # a gap of the ground truth, probe BI)
        t0, t1 = inside[0]
        why = (f"the ground truth has gaps: it covers under {FULL_COVERAGE:.0%} of the "
               f"windows within its span (the first: [{t0}, {t1}) us, "
               f"{gt_coverage(gt, t0, t1):.0%})")
    else:
        why = "no window lies within the ground truth's"
    return f"the windows span [{a}, {b}] us but the ground truth [{c}, {d}] us: {why}"


def _filled(flow: np.ndarray, known: np.ndarray) -> np.ndarray:
    """``flow`` with each unknown pixel (NaN: .flo / .png "unknown", outside a ROI) given
    its nearest known pixel's flow, so that transporting it carries no NaN and no zero
    flow into the known pixels (zero where nothing is known)."""
    if known.all():
        return flow
    if not known.any():
        return np.zeros_like(flow)
    from scipy.ndimage import distance_transform_edt

    iy, ix = distance_transform_edt(~known, return_distances=False, return_indices=True)
    return flow[iy, ix]


def evaluate_potential(q: np.ndarray, t0s: Sequence[int], t1s: Sequence[int],
                       gt_q: np.ndarray, gt_t_us: np.ndarray,
                       mask: np.ndarray | None = None) -> list[dict]:
    """Score BOS potentials ``q`` (px^2/s, defined up to a constant) against ground truth
    on the same frame intervals.

    Parameters
    ----------
    q : ndarray, shape (N, H, W)
        Estimated potential of each window; NaN where not defined (not scored).
    t0s, t1s : sequence of int
        Each window's interval, µs.
    gt_q : ndarray, shape (M, H, W)
        Ground-truth potential of each frame interval ``[gt_t_us[j], gt_t_us[j + 1])``.
    gt_t_us : ndarray, shape (M + 1,)
        Frame times, µs.
    mask : ndarray of bool, shape (N, H, W), optional
        Pixels scored per window (default all known ones).

    Returns
    -------
    list of dict
        Per window matching a GT frame interval exactly: ``window``, ``q_corr`` (Pearson
        correlation after removing each field's mean; NaN where either field is constant
        over the scored pixels, which defines none) and ``q_std_ratio`` (standard
        deviation over the ground truth's: 1 is the right scale; NaN where the ground truth
        is constant). Windows that span no single frame interval, or with fewer than two
        scored pixels, are left out.

    Raises
    ------
    ParameterError
        Arrays whose shapes do not fit together, or bounds that are not whole µs.

    Examples
    --------
    >>> yy, xx = np.mgrid[0:8, 0:8].astype(float)
    >>> gt = (xx * yy)[None]
    >>> rows = evaluate_potential(2.0 * gt + 5.0, [0], [100], gt, np.array([0, 100]))
    >>> round(rows[0]["q_corr"], 6), round(rows[0]["q_std_ratio"], 6)
    (1.0, 2.0)
    """
    q, gt_q, gt_t_us, mask = _potentials(q, gt_q, gt_t_us, mask)
    t0s, t1s = _bounds(len(q), t0s, t1s, "q")
    start = {int(t): j for j, t in enumerate(gt_t_us[:-1])}
    rows = []
    for i, (t0, t1) in enumerate(zip(t0s, t1s, strict=True)):
        j = start.get(int(t0))
        if j is None or int(gt_t_us[j + 1]) != int(t1):
            continue
        est, ref = q[i].astype(np.float64), gt_q[j].astype(np.float64)
        sel = np.isfinite(est) & np.isfinite(ref)
        if mask is not None:
            sel &= mask[i]
        if sel.sum() < 2:
            continue
        a, b = est[sel] - est[sel].mean(), ref[sel] - ref[sel].mean()
        sa, sb = float(np.sqrt(np.mean(a * a))), float(np.sqrt(np.mean(b * b)))
        corr = float(np.mean(a * b) / (sa * sb)) if sa > 0 and sb > 0 else float("nan")
        rows.append({"window": i, "q_corr": corr,
                     "q_std_ratio": sa / sb if sb > 0 else float("nan")})
    return rows


def _potentials(q, gt_q, gt_t_us, mask):
    """The arrays of :func:`evaluate_potential` checked to fit together (an empty q had
    failed as an IndexError, an int mask as a ufunc casting error, probe EVAL)."""
    q, gt_q = np.asarray(q), np.asarray(gt_q)
    for name, a in (("q", q), ("gt_q", gt_q)):
        if a.ndim != 3 or a.dtype.kind not in "fiu":
            raise ParameterError(f"{name} must be numbers (N, H, W), got shape {a.shape}, "
                                 f"dtype {a.dtype}")
    if gt_q.shape[1:] != q.shape[1:]:
        raise ParameterError(f"gt_q is {gt_q.shape[2]}x{gt_q.shape[1]} px but q "
                             f"{q.shape[2]}x{q.shape[1]} px (W x H): not the same grid")
    try:
        t = np.asarray(gt_t_us, dtype=np.float64)
    except (TypeError, ValueError):
        t = np.full(1, np.nan)
    if t.shape != (gt_q.shape[0] + 1,) or not np.isfinite(t).all() \
            or (t != np.round(t)).any() or (np.diff(t) <= 0).any():
        raise ParameterError(f"gt_t_us must be the {gt_q.shape[0] + 1} increasing frame "
                             f"times (whole µs) around the {gt_q.shape[0]} intervals of gt_q")
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != q.shape or mask.dtype.kind != "b":
            raise ParameterError(f"mask must be bool {q.shape} like q, got {mask.shape} "
                                 f"{mask.dtype}")
    return q, gt_q, t.astype(np.int64), mask
