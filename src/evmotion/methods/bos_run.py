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

import math
import warnings
from collections.abc import Collection, Iterator
from dataclasses import dataclass, field

import numpy as np

from evmotion.errors import (
    EventDataError,
    EvmotionError,
    EvmotionWarning,
    InvertedPolarityError,
    ParameterError,
    UnderfitWarning,
)
from evmotion.io.bosfiles import BOS_COMPRESSION
from evmotion.io.bosinput import BosInput
from evmotion.utils import seconds_text

__all__ = ["BOS_EVAL_OUT_PX", "BosRun", "append_bos_result", "check_input",
           "check_registration", "iter_bos_input", "registration_shift",
           "open_bos_output", "require_texture", "sequence_contrast_threshold",
           "sequence_threshold", "solve_bos_input", "solve_bos_into", "stored_warm_start",
           "unmeasured_intervals", "warn_mains_flicker", "warn_startup", "warn_uncovered",
           "write_bos_output"]

#: %Out threshold of BOS evaluations (thesis §6.6.1: displacements of a few px), stored
#: in the output as ``eval_out_px`` for ``evmotion eval``.
BOS_EVAL_OUT_PX = 1.0


@dataclass(frozen=True)
class BosRun:
    """Results of :func:`solve_bos_input`.

    Attributes
    ----------
    results : list of BosResult
        One per selected interval, in time order.
    contrast_threshold : float
        The C used for every interval.
    c_source : str
        ``"given"`` or ``"median of N intervals"``.
    c_samples : ndarray
        The per-interval estimates the median was taken over.
    """

    results: list
    contrast_threshold: float
    c_source: str
    c_samples: np.ndarray = field(default_factory=lambda: np.zeros(0))


#: Below this estimated contrast threshold (log intensity) a warning says it is lower than
#: event cameras are usually set to (10-50 % of illumination, the survey of Gallego et al.
#: 2020; a margin under 0.1 for the estimate's error): such an estimate comes from a weak
#: background or noisy frames more often than from the sensor (probes: 0.04-0.07 for a
#: true 0.15-0.2 on slow, weak or low-contrast scenes).
LOWEST_USUAL_C = 0.08


def sequence_contrast_threshold(data: BosInput, *, samples: int = 15,
                                exclude: Collection[int] = ()
                                ) -> tuple[float | None, np.ndarray]:
    """Median of the per-interval contrast-threshold estimates over up to ``samples``
    selected intervals evenly spread over the sequence (intervals where the frames do not
    change where events fire are skipped, and those of ``exclude``, indices of
    ``data.intervals``: :func:`unmeasured_intervals`, whose events under-count the change).
    Returns ``(C or None, estimates)``.

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> c, per_interval = sequence_contrast_threshold(load_bos_input("scene/"))
    >>> round(float(c), 1), len(per_interval)   # the simulator's sensor has C = 0.2
    (0.2, 3)
    """
    from evmotion.methods.bos import NEAR_EVENTS_PX, TIMED_NOISE, WEAK_CORRELATION

    pick = _sampled_intervals(data, samples, exclude)
    estimates, slopes, corrs, inverted, shares = [], [], [], [], []
    for j in pick:
        try:
            c, slope, corr = _interval_slope(data, j)
        except InvertedPolarityError as exc:
            inverted.append(exc)
            continue
        except EvmotionError:
            continue
        if np.isfinite(c) and c > 0:
            estimates.append(c)
            slopes.append(slope)
            corrs.append(corr)
            shares.append(multi_fire_share(data, j))
    if len(inverted) > len(estimates):
        raise inverted[0]
    warn_subthreshold(shares)
    est = np.asarray(estimates, dtype=np.float64)
    low = (f"; C = {np.median(est):.2g} is lower than event cameras are usually set to "
           "(0.1-0.5)" if est.size and np.median(est) < LOWEST_USUAL_C else "")
    if corrs and np.median(corrs) < WEAK_CORRELATION:
        warnings.warn(EvmotionWarning(
            f"the events follow the frames' change weakly around them (correlation "
            f"{np.median(corrs):.2f} within {NEAR_EVENTS_PX:g} px of the events, median of "
            f"{len(corrs)} intervals): few events, a low-contrast background, noise or still "
            f"air{low}; the flow's magnitude is uncertain, most often too small (0.06-1.2x "
            "the true one on such scenes); give --contrast-threshold if you know C"),
            stacklevel=2)
    elif low:
        warnings.warn(EvmotionWarning(
            f"the contrast threshold estimated from the frames{low}: a weak background or "
            "noisy frames make it low, and the flow's magnitude then too small; give "
            "--contrast-threshold if you know C"), stacklevel=2)
    if slopes.count(TIMED_NOISE) > len(slopes) / 2:
        # (probe CJ: 0.87-0.90x on whole-view flows, without a word)
        warnings.warn(EvmotionWarning(
            f"no still air in view in {slopes.count(TIMED_NOISE)} of {len(slopes)} "
            "intervals (air moving in the whole view): the frames' noise, which the "
            "contrast threshold is corrected for, is measured in time from the frame after "
            "each interval, and that counts the air's own change too: C = "
            f"{np.median(est):.3g} and the flow's magnitude come out low where the flow is "
            "steady (0.85-0.90x on scenes of steady flow over the whole view); give "
            "--contrast-threshold if you know C"),
            stacklevel=2)
    if slopes.count("events") > len(slopes) / 2:
        warnings.warn(EvmotionWarning(
            f"the contrast threshold C = {np.median(est):.3g} comes from the events alone in "
            f"{slopes.count('events')} of {len(slopes)} intervals: the frames' noise "
            "(dark or noisy frames, few grey levels) exceeds half their change, and the "
            "events' slope is low where the air changes the image by less than C, so the "
            "flow's magnitude may be too small; give --contrast-threshold"), stacklevel=2)
    return (float(np.median(est)) if est.size else None), est


def _sampled_intervals(data: BosInput, samples: int, exclude: Collection[int] = ()
                       ) -> np.ndarray:
    """Up to ``samples`` indices of ``data.intervals`` evenly spread over the sequence,
    without those of ``exclude`` (unless it holds them all)."""
    if samples < 1:
        raise ParameterError(f"samples must be >= 1, got {samples}")
    kept = np.setdiff1d(np.arange(len(data.intervals)), np.asarray(list(exclude), int))
    if not kept.size:
        kept = np.arange(len(data.intervals))
    return kept[np.unique(np.linspace(0, kept.size - 1, min(samples, kept.size))
                          .round().astype(int))]


def _interval_slope(data: BosInput, j: int) -> tuple[float, str, float]:
    """:func:`~evmotion.methods.bos.contrast_threshold_slope` of interval ``j``."""
    from evmotion.methods.bos import contrast_threshold_slope

    i, t0, t1 = (int(v) for v in data.intervals[j])
    # the frame after lets the frames' noise be measured in time where no still air is
    # in view
    after = data.frames[i + 2] if i + 2 < len(data.frames) else None
    return contrast_threshold_slope(data.events, data.frames[i], data.frames[i + 1],
                                    t0_us=t0, t1_us=t1, roi=data.roi, frame_after=after)


def check_polarity(data: BosInput, samples: int = 3) -> None:
    """:class:`~evmotion.errors.InvertedPolarityError` where the events of most of up to
    ``samples`` intervals anti-correlate with the frames' change: with a given C nothing
    else looks, and inverted events gave the reversed flow, unsaid (probe AT). The
    intervals whose events follow the frames' change are also judged by
    :func:`warn_subthreshold`."""
    inverted, shares = [], []
    for j in _sampled_intervals(data, samples):
        try:
            _interval_slope(data, j)
            shares.append(multi_fire_share(data, j))
        except InvertedPolarityError as exc:
            inverted.append(exc)
        except EvmotionError:
            continue
    if len(inverted) > len(shares):
        raise inverted[0]
    warn_subthreshold(shares)


#: Below this share of the next intervals' event gain (:func:`warn_startup`) the interval
#: where the events begin is said to be the sensor's start-up. The first interval scored
#: 0.55-0.74 on the simulator's scenes (which start every pixel at its reference; their
#: magnitude there 0.26-0.56x, the next two intervals' 0.68-1.07x) and 0.57-0.82 on two other
#: renderers' scenes, the next intervals 0.91-1.11 of each other.
STARTUP_GAIN = 0.8
#: After a start-up interval, the next one is start-up too below this share of the settled
#: gain (the median from the interval after it on). A third renderer's scenes (C 0.15-0.2,
#: pixels starting at their reference) scored 0.80, 0.80, 0.80, 0.90, 0.93 there, their flow
#: 0.68-0.81x of the settled intervals' where 0.80; the simulator's 1.01-1.18.
STARTUP_FOLLOW_GAIN = 0.85
#: Intervals whose event gain is below this share of the median of their neighbours' hold
#: (next to) no events: an interval of still air or a gap, which tells nothing of the rate
NEAR_EMPTY_GAIN = 0.25
#: Intervals :func:`warn_startup` scores against the first
STARTUP_CONTEXT = 8
#: The most the rates of the (up to four) intervals after the first may differ for it to
#: be told against them: more, as under flicker, is said instead
STARTUP_RATES_AGREE = 1.5


def check_input(data: BosInput, options=None) -> tuple[int, ...]:
    """What a run checks of its input before it estimates C and solves, each refused or
    said in a warning: frames with texture (:func:`require_texture`, with ``options``),
    frames and events that show the same view (:func:`warn_uncovered`,
    :func:`check_registration`), lamps flickering (:func:`warn_mains_flicker`); returns
    :func:`unmeasured_intervals`. :func:`solve_bos_input` and ``evmotion bos`` make
    them alike."""
    require_texture(data, options)
    warn_uncovered(data)
    check_registration(data)
    warn_mains_flicker(data)
    return unmeasured_intervals(data)


def unmeasured_intervals(data: BosInput) -> tuple[int, ...]:
    """The selected intervals whose flow is no measurement, each said in a warning: the
    sensor's start-up (:func:`warn_startup`) and those the recording was cut in
    (``data.cut``). Indices of ``data.intervals``, sorted."""
    return tuple(sorted(set(warn_startup(data)) | set(data.cut)))


def warn_startup(data: BosInput) -> tuple[int, ...]:
    """Say when the events begin inside a selected frame interval and follow the frames'
    change there at less than :data:`STARTUP_GAIN` of the rate of the next intervals: a
    sensor, or a simulator, that starts with the recording fires less until its pixels'
    reference levels have spread over the threshold band, and the solver takes the missing
    events for missing motion. The next interval is start-up too where its rate is below
    :data:`STARTUP_FOLLOW_GAIN` of the settled one (the median from the interval after it
    on). The rate of an interval: its events' polarity sums regressed on the frames' log
    difference, both Gaussian-smoothed (2 px), over the ROI less an 8 px border; intervals
    the recording was cut in (``data.cut``), and those of (next to) no events
    (:data:`NEAR_EMPTY_GAIN`), tell nothing of it and are left out. Returns the indices (in
    ``data.intervals``) of the intervals it names, whose flow is no measurement (the
    solvers write them with no valid pixel): empty where nothing is said (the events begin
    before the selection, or the share is higher) or where it is said that it cannot be
    told (fewer than two intervals follow the one the events begin in, or their rates
    differ by more than :data:`STARTUP_RATES_AGREE`, as under flicker).

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> import warnings
    >>> with warnings.catch_warnings(record=True):   # (it also says so in a warning)
    ...     first = warn_startup(load_bos_input("scene/"))
    >>> first   # the simulated sensor starts with the recording: its first interval
    (0,)
    """
    first = int(data.events.t[0])
    starts = [k for k, (_, t0, t1) in enumerate(data.intervals) if t0 <= first < t1]
    if not starts:
        return ()
    if len(data.intervals) < starts[0] + 3:
        # nothing to tell it by (probe AM: two frames of a simulated scene gave 0.19x,
        # valid, unsaid)
        _warn_startup_untold(data.intervals[starts[0]])
        return ()
    k0 = starts[0]
    context = data.intervals[k0:k0 + STARTUP_CONTEXT + 1]
    textured = _textured(data, [int(iv[0]) + d for iv in context for d in (0, 1)])
    gains = np.array([_event_gain(data, iv, textured) for iv in context])
    usable = np.isfinite(gains) & (gains > 0)
    usable[0] = False
    usable[[k - k0 for k in data.cut if k0 < k < k0 + len(context)]] = False
    if usable.any():
        usable &= gains >= NEAR_EMPTY_GAIN * np.median(gains[usable])
    later = gains[usable][:4]
    if not np.isfinite(gains[0]):
        return ()
    if len(later) < 2:
        if len(later) == 1:
            # one interval tells a rate, the others are cut or nearly empty: a start-up
            # at 0.19x had gone out valid, unsaid (probe CJ). (None tells one in still
            # air, which the contrast threshold's estimate refuses.)
            _warn_startup_untold(data.intervals[k0])
        return ()
    if later.max() > STARTUP_RATES_AGREE * later.min():
        # (probe BF: 100 Hz flicker of 2-10 % spread them 2.1-4.3, and a start-up interval
        # went out at 0.59x, valid, with no word)
        _, t0, t1 = (int(v) for v in data.intervals[k0])
        warnings.warn(EvmotionWarning(
            f"the events begin in the frame interval [{t0}, {t1}) us, and the next "
            "intervals' events follow the frames' change at rates "
            f"{later.max() / later.min():.1f}x apart (schlieren too faint or too small "
            "for their events to tell a rate, flickering light, or a gain that "
            "drifts): whether that interval is the "
            "sensor's start-up cannot be told; if the sensor started with the recording, "
            f"its flow is too small (0.26-0.81x on simulated scenes): --t0 {seconds_text(t1)} "
            "leaves it out. Under flicker the flow's direction and size vary with its "
            "phase"), stacklevel=2)
        return ()
    share = float(gains[0] / np.median(later))
    if not share < STARTUP_GAIN:
        return ()
    named = [k0]
    settled = gains[2:][usable[2:]]
    if usable[1] and len(settled) >= 2:
        follow = float(gains[1] / np.median(settled))
        if follow < STARTUP_FOLLOW_GAIN:
            named.append(k0 + 1)
    _, t0, t1 = (int(v) for v in data.intervals[k0])
    end = int(data.intervals[named[-1], 2])
    also = ("" if len(named) == 1 else
            f" (and the next, [{t1}, {end}) us, at {follow:.2f} of the settled rate)")
    # a start-up fires about half as much (0.55-0.82); next to nothing is air that had not
    # come yet, or noise (probe BF: 0.05-0.07 said as start-up)
    why = ("a sensor (or a simulator) that starts with the recording fires less until its "
           "pixels settle; the flow there is too small (0.26-0.81x on simulated scenes)"
           if share >= NEAR_EMPTY_GAIN else
           "next to no change the events follow: still air, or noise events, or a sensor "
           "that starts with the recording")
    warnings.warn(EvmotionWarning(
        f"the events begin in the frame interval [{t0}, {t1}) us and follow the frames' "
        f"change there at {share:.2f} of the next intervals' rate{also}: {why}; it is "
        f"written with no valid pixel; --t0 {seconds_text(end)} leaves "
        f"{'it' if len(named) == 1 else 'them'} out"), stacklevel=2)
    return tuple(named)


def _warn_startup_untold(interval) -> None:
    """Say that whether the ``interval`` the events begin in is the sensor's start-up
    cannot be told: fewer than two intervals that tell a rate follow it."""
    _, t0, t1 = (int(v) for v in interval)
    warnings.warn(EvmotionWarning(
        f"the events begin in the frame interval [{t0}, {t1}) us and fewer than two "
        "intervals that follow tell the events' rate (too few frames, or intervals cut "
        "or nearly empty), so whether it is the sensor's start-up cannot be told: if the "
        "sensor started with the recording, it fires less there until its pixels settle "
        "and that interval's flow comes out too small (0.26-0.81x on simulated scenes, as "
        "the other start-up warnings say); frames over more of the recording tell"),
        stacklevel=3)


#: Above this ratio of the frames' change (mean square of the smoothed log difference)
#: far from every event to that near them, :func:`warn_uncovered` speaks: frames and
#: events do not show the same view. 1.6-1.8 on a scene whose events covered only the
#: top-left 200x150 px of 346x260 frames (probe AF, C 0.7x), 1.19 on a rendered uniform
#: shift cut the same way. On AF's plume and white-noise scenes the frames far from the
#: events change by less than twice their noise (still air: no ratio; without that test
#: 0.05-0.11 and 0.5-0.6).
UNCOVERED_CHANGE = 0.8


def warn_mains_flicker(data: BosInput) -> tuple[float, float] | None:
    """An :class:`~evmotion.errors.EvmotionWarning` where the events' rate over the
    selected intervals carries a line of lamps on mains power
    (:func:`evmotion.methods.measured.mains_flicker`): the events then follow the light as
    well as the air (probe BF: 100 Hz flicker of 5-10 % turned the flow's direction by
    6-24 degrees with its phase, 5-7 without, and nothing said it). Returns the line's
    ``(frequency Hz, strength)``, else None.

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.06, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> warn_mains_flicker(load_bos_input("scene/")) is None   # steady light
    True
    """
    from evmotion.methods.measured import mains_flicker

    t0, t1 = int(data.intervals[0, 1]), int(data.intervals[-1, 2])
    t = data.events.t
    found = mains_flicker(t[np.searchsorted(t, t0):np.searchsorted(t, t1)])
    if found is not None:
        f0, strength = found
        warnings.warn(EvmotionWarning(
            f"the events' rate carries a {f0:g} Hz line, {strength:.0f}x its spectrum's "
            "median: lamps flickering on mains power? The events then follow the light as "
            "well as the air, and the flow's direction and size can vary with the flicker's "
            "phase (6-24 degrees of error at 5-10 % flicker, 5-7 without, on an independent "
            "renderer's plume); light the background without flicker (DC-driven LEDs)"),
            stacklevel=2)
    return found


def warn_uncovered(data: BosInput, samples: int = 5) -> float | None:
    """Say when the frames change as much far from every event (more than
    :data:`~evmotion.methods.bos.NEAR_EVENTS_PX` away, in the ROI) as near them, over up to
    ``samples`` intervals (median): where no event fires the air is still, so the frames
    and the events do not show the same view (events from a smaller or shifted sensor, a
    crop, frames not registered). The contrast threshold and the flow's magnitude then come
    out wrong. Intervals whose frames change far from the events by less than twice
    their noise there (the second difference of three frames) say nothing: still air.
    Returns the ratio (None: under 5 % of the ROI is far from the events, or no interval
    changes there beyond its noise).

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> ratio = warn_uncovered(load_bos_input("scene/"))
    >>> ratio < UNCOVERED_CHANGE   # far from the events the frames hardly change: no warning
    True
    """
    from scipy.ndimage import distance_transform_edt, gaussian_filter

    from evmotion.methods.bos import (
        NEAR_EVENTS_PX,
        event_sums,
        exposure_change,
        log_difference_noise,
        log_frame,
    )

    x, y, w, h = _roi_box(data)
    counts = event_sums(data.events, (x, y, w, h))[1]
    far = distance_transform_edt(counts == 0) > NEAR_EVENTS_PX
    if far.mean() < 0.05 or far.all():
        return None
    pick = np.unique(np.linspace(0, len(data.intervals) - 1, min(samples, len(data.intervals)))
                     .round().astype(int))

    ratios = []
    starts = [int(data.intervals[j][0]) for j in pick]
    textured = _textured(data, [i + d for i in starts if i + 2 < len(data.frames)
                                for d in (0, 1, 2)])
    for i in starts:
        if i + 2 >= len(data.frames) or not all(textured[k] for k in (i, i + 1, i + 2)):
            # a blank frame changes everywhere, far from the events too: no view mismatch
            # (probe AT)
            continue
        logs = [log_frame(data.frames[k])[y:y + h, x:x + w] for k in (i, i + 1, i + 2)]
        d = gaussian_filter(logs[1] - logs[0], 2.0, mode="nearest")
        d = (d - exposure_change(d, far)) ** 2
        # the frames' noise far from the events: still air in noisy frames is no change
        noise = log_difference_noise(*logs, 2.0, far)
        near, away = float(np.mean(d[~far])), float(np.mean(d[far]))
        if near > 0 and away > 2.0 * noise:
            ratios.append(away / near)
    if not ratios:
        return None
    ratio = float(np.median(ratios))
    if ratio > UNCOVERED_CHANGE:
        ys, xs = np.nonzero(counts)
        box = (x + int(xs.min()), y + int(ys.min()), int(xs.max() - xs.min()) + 1,
               int(ys.max() - ys.min()) + 1)
        warnings.warn(EvmotionWarning(
            f"{data.source}: the frames change where no event fires (more than "
            f"{NEAR_EVENTS_PX:g} px from any, {ratio:.2f}x their change near the events); "
            "the air should be still there, so frames and events do not show the same view "
            "(events from a smaller or shifted sensor, a crop, or frames not registered with "
            "them); "
            "the contrast threshold and the flow's magnitude come out wrong (0.7x on such a "
            f"scene); register them, or keep to the events with --roi {' '.join(map(str, box))}"
            ), stacklevel=2)
    return ratio


#: Shifts (px, each axis) :func:`check_registration` tries between frames and events.
REGISTRATION_PX = 3
#: Above this gain in correlation at a shift over none, :func:`check_registration` speaks;
#: at a shift of 2 px or more, or an unshifted correlation under
#: :data:`REGISTRATION_REFUSE` of the best, it refuses (probe AM: frames 2 px off gave 0.31
#: against 0.70 at their shift and an AEE worse than the zero flow's, valid; 1 px off 0.64
#: against 0.70, AEE 0.158 against 0.149; every registered scene tried peaked unshifted:
#: 12 simulated and rendered ones, the DAVIS346 file).
REGISTRATION_GAIN = 0.05
REGISTRATION_REFUSE = 0.5
#: Area (px²) over which the smoothed images (σ = 2 px) vary together, about 4πσ²: a
#: correlation over an ROI of A px² and n intervals rests on about n A / this samples.
REGISTRATION_CELL_PX2 = 50.0


def registration_shift(data: BosInput, samples: int = 5, radius: int = REGISTRATION_PX
                       ) -> tuple[tuple[int, int], float, float]:
    """``((dx, dy), best, unshifted)``: the shift of the frames (px, within ``radius``)
    at which their smoothed log difference correlates best with the events' smoothed
    polarity sums over the same interval (mean over up to ``samples`` intervals), that
    correlation, and the correlation unshifted. Events and frames of one registered view
    peak at (0, 0): the events measure the very change the frames show.

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(64, 80), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> registration_shift(load_bos_input("scene/"))[0]
    (0, 0)
    """
    from scipy.ndimage import gaussian_filter

    from evmotion.methods.bos import event_sums, log_frame

    r = int(radius)
    x, y, w, h = _roi_box(data)
    if w <= 4 * r or h <= 4 * r:
        return (0, 0), float("nan"), float("nan")
    pick = np.unique(np.linspace(0, len(data.intervals) - 1, min(samples, len(data.intervals)))
                     .round().astype(int))
    # every k-th row and column: ~40k pixels are plenty for a correlation (a 640x720
    # frame at every pixel took 0.2 s an interval)
    k = max(1, round(np.sqrt((h - 2 * r) * (w - 2 * r) / 40_000)))
    total, n = np.zeros((2 * r + 1, 2 * r + 1)), 0
    for j in pick:
        i, t0, t1 = (int(v) for v in data.intervals[j])
        s = gaussian_filter(event_sums(data.events, data.roi, t0_us=t0, t1_us=t1)[0], 2.0,
                            mode="nearest")[r:h - r:k, r:w - r:k]
        s = s - s.mean()
        d = log_frame(data.frames[i + 1]) - log_frame(data.frames[i])
        d = gaussian_filter(d, 2.0, mode="nearest")[y:y + h, x:x + w]
        ss = float(np.sum(s * s))
        if ss == 0:
            continue
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                dd = d[r + dy:h - r + dy:k, r + dx:w - r + dx:k]
                dd = dd - dd.mean()
                den = np.sqrt(ss * float(np.sum(dd * dd)))
                total[dy + r, dx + r] += float(np.sum(s * dd)) / den if den > 0 else 0.0
        n += 1
    if n == 0:
        return (0, 0), float("nan"), float("nan")
    total /= n
    ky, kx = np.unravel_index(int(np.argmax(total)), total.shape)
    return (int(kx) - r, int(ky) - r), float(total[ky, kx]), float(total[r, r])


def check_registration(data: BosInput) -> tuple[int, int]:
    """Say when the frames' change follows the events better shifted by a pixel
    (:func:`registration_shift`), and refuse when by two or more, or when unshifted it
    follows them by less than half as well: the frames and the events do not show the same
    pixels (a second camera or a beam splitter off by a few px, a crop or border), and the
    flow would be no measurement (the frame's gradient and the events' increment meet on
    other dots). Returns the shift (``(0, 0)`` when registered)."""
    from evmotion.methods.bos import MIN_CORRELATION

    (dx, dy), best, zero = registration_shift(data)
    if (dx, dy) == (0, 0) or not best >= max(MIN_CORRELATION,
                                             zero + _registration_margin(data, zero)):
        return (0, 0)
    what = (f"{data.frames_source}: the frames' change follows the events' best with the "
            f"frames shifted by ({dx:+d}, {dy:+d}) px (x, y; correlation {best:.2f}, against "
            f"{zero:.2f} unshifted): frames and events are not registered (a second camera "
            "or a beam splitter off by a pixel or two, a crop or a border)")
    if max(abs(dx), abs(dy)) >= 2 or zero < REGISTRATION_REFUSE * best:
        raise EventDataError(what + "; the flow would be no measurement: register them")
    warnings.warn(EvmotionWarning(what + "; the flow is degraded: register them"),
                  stacklevel=2)
    return (dx, dy)


def _roi_box(data: BosInput) -> tuple[int, int, int, int]:
    """``(x, y, width, height)`` of the ROI, px, the whole sensor without one."""
    if data.roi is not None:
        return tuple(data.roi)
    h, w = data.events.sensor_size
    return 0, 0, w, h


def _registration_margin(data: BosInput, zero: float) -> float:
    """The gain in correlation over the unshifted one a shift needs to be told from chance:
    :data:`REGISTRATION_GAIN`, or twice a correlation's sampling error on a small ROI or
    few intervals (probe OPT: one interval of a 40x40 px ROI where the air was weak
    peaked at a 2 px shift, 0.64 against 0.53, and the scene was refused)."""
    r = REGISTRATION_PX
    w, h = _roi_box(data)[2:]
    samples = min(5, len(data.intervals)) * (w - 2 * r) * (h - 2 * r) / REGISTRATION_CELL_PX2
    return max(REGISTRATION_GAIN, 2.0 * (1.0 - zero * zero) / math.sqrt(max(samples, 1.0)))


def _textured(data: BosInput, frames) -> dict[int, bool]:
    """Whether each frame of ``frames`` (indices) has texture in the ROI, not a dropped,
    black or uniform one: :func:`~evmotion.methods.bos.frame_texture` on every other
    pixel of the ROI (38 ms a 640 x 720 frame in full, and these checks look at up to 25
    frames; a frame without texture has none at any scale)."""
    from evmotion.methods.bos import BosOptions, frame_texture

    x, y, w, h = _roi_box(data)
    least = BosOptions().min_texture
    # every pixel of an ROI under 32 px: halved, it was under the 16 px frame_texture
    # takes, and a 30 x 30 ROI was refused as "the sensor (15x15 px)" (probe BN)
    step = 2 if min(w, h) >= 32 else 1
    return {int(i): frame_texture(data.frames[int(i)][y:y + h:step, x:x + w:step]) >= least
            for i in set(frames)}


def _event_gain(data: BosInput, interval, textured: dict[int, bool]) -> float:
    """The events' polarity sums of ``interval`` regressed on the frames' log difference
    (:func:`warn_startup`)."""
    from scipy.ndimage import gaussian_filter

    from evmotion.methods.bos import event_sums, log_frame

    i, t0, t1 = (int(v) for v in interval)
    if not (textured[i] and textured[i + 1]):
        return float("nan")  # a blank frame's change is none the events saw (probe AT)
    s = gaussian_filter(event_sums(data.events, data.roi, t0_us=t0, t1_us=t1)[0], 2.0,
                        mode="nearest")
    d = log_frame(data.frames[i + 1]) - log_frame(data.frames[i])
    if data.roi is not None:
        x, y, w, h = data.roi
        d = d[y:y + h, x:x + w]
    d = gaussian_filter(d, 2.0, mode="nearest")[8:-8, 8:-8]
    s = s[8:-8, 8:-8]
    den = float(np.sum(d * d))
    return float(np.sum(s * d)) / den if den > 0 else float("nan")


def sequence_threshold(data: BosInput, contrast_threshold: float | None = None, *,
                       samples: int = 15, exclude: Collection[int] = ()
                       ) -> tuple[float | None, str, np.ndarray]:
    """The C of a run: ``(C, source, per-interval estimates)``, the source being
    ``"given"`` or ``"median of N intervals"`` (:func:`sequence_contrast_threshold`, without
    the intervals of ``exclude``); an EventDataError where no interval gives one.

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> sequence_threshold(load_bos_input("scene/"), 0.2)[:2]
    (0.2, 'given')
    """
    if contrast_threshold is not None:
        check_polarity(data)
        return float(contrast_threshold), "given", np.zeros(0)
    c, est = sequence_contrast_threshold(data, samples=samples, exclude=exclude)
    if c is None:
        _refuse_blank_frames(data)
        # said of the sequence (the first interval's fit had been named, "covariance 0",
        # as if that interval alone were at fault; probe BN)
        n = len(_sampled_intervals(data, samples, exclude))
        raise EventDataError(
            f"cannot estimate the contrast threshold: in none of the {n} frame intervals "
            "tried do the events follow the frames' change (still air, events that are "
            "noise, or frames not of these events): no flow to measure; give "
            "--contrast-threshold (contrast_threshold=) to solve with a known C")
    return c, f"median of {est.size} intervals", est


def _refuse_blank_frames(data: BosInput) -> None:
    """EventDataError where every interval has a frame without texture (dropped, black,
    uniform) at one end: no C can be estimated, and the error of an interval's fit
    ("covariance -0.0587") had not said why (probe AY, a black frame in two intervals)."""
    ends = {int(i) + d for i in data.intervals[:, 0] for d in (0, 1)}
    textured = _textured(data, ends)
    if all(not (textured[int(i)] and textured[int(i) + 1]) for i in data.intervals[:, 0]):
        blank = min(k for k in ends if not textured[k])
        raise EventDataError(
            f"cannot estimate the contrast threshold: every frame interval has a frame "
            f"without texture at one end (the first: frame {blank} at "
            f"{int(data.frame_times[blank])} us; dropped, black or uniform); more intervals, "
            "or --contrast-threshold, let the others be measured")


#: Below this share of the pixels that fired in a frame interval firing more than once
#: (median of the sampled intervals), the air changes nearly every pixel by less than C
#: between two frames and the flow comes out too small, unsaid before (probe AY). On 28
#: scenes of two renderers (the simulator's four at 240x320 and at 640x720, 20 of an
#: independent one at 60-240 fps), the 8 below it came out at 0.38-0.92x the true
#: magnitude (6 of them below 0.9x), the 20 above at 0.77-1.14x (15 of them within
#: [0.9, 1.1]).
MULTI_FIRE_SHARE = 0.05


def multi_fire_share(data: BosInput, j: int) -> float:
    """The share of the pixels (in ``data.roi``) that fired in interval ``j`` of
    ``data.intervals`` which fired more than once (nan where none fired). Under a change
    of a pixel's log intensity by ``D`` between two frames a sensor of threshold C fires
    about ``|D| / C`` times: where nearly every pixel that fired fired once, ``|D| < C``
    nearly everywhere, and most of the air's change goes unseen."""
    from evmotion.methods.bos import event_sums

    _, t0, t1 = (int(v) for v in data.intervals[j])
    _, counts = event_sums(data.events, data.roi, t0_us=t0, t1_us=t1)
    fired = counts[counts > 0]
    return float(np.mean(fired >= 2)) if fired.size else float("nan")


def warn_subthreshold(shares: list[float]) -> None:
    """An :class:`~evmotion.errors.EvmotionWarning` where the median of ``shares``
    (:func:`multi_fire_share` of the intervals whose events follow the frames' change) is
    below :data:`MULTI_FIRE_SHARE`, with C estimated or given (on such a scene at 240 fps
    the true C gave 0.86x)."""
    shares = [v for v in shares if np.isfinite(v)]
    if shares and np.median(shares) < MULTI_FIRE_SHARE:
        warnings.warn(EvmotionWarning(
            f"only {100 * np.median(shares):.1f} % of the pixels that fire in a frame interval "
            f"fire more than once (median of {len(shares)} intervals): the air changes "
            "nearly every pixel by less than the contrast threshold between two frames "
            "(slow or faint air, or a high frame rate), and the flow's magnitude comes out "
            "too small (0.38-0.92x the true one on such scenes); frames further apart "
            "(every second line of images.txt) see more of it"), stacklevel=3)


def iter_bos_input(data: BosInput, contrast_threshold: float | None, *, start: int = 0,
                   init=None, workers: int = 1, progress: bool = False, scheduler=None,
                   unmeasured: Collection[int] = (), **options) -> Iterator:
    """The results of the selected frame intervals ``data.intervals[start:]``, in time
    order, each as soon as it is done (a chunk at a time with several workers).

    Parameters
    ----------
    data : BosInput
    contrast_threshold : float or None
        C of every interval (:func:`sequence_threshold`).
    start : int
        First selected interval to solve (those before are done: ``--resume``).
    init : BosResult or list of ndarray, optional
        Warm start of interval ``start`` (the previous interval's result or its
        :attr:`~evmotion.methods.bos.BosResult.params`).
    unmeasured : collection of int
        Intervals (indices of ``data.intervals``: :func:`unmeasured_intervals`) whose
        results come with no valid pixel.
    workers, progress, scheduler, **options
        As :func:`solve_bos_input`.

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> first = next(iter_bos_input(load_bos_input("scene/"), 0.2))
    >>> first.flow.shape   # px/s, (H, W, 2)
    (48, 64, 2)
    """
    from evmotion.methods.bos import iter_bos_sequence

    n = len(data.intervals)
    if isinstance(start, bool) or not isinstance(start, (int, np.integer)) or \
            not 0 <= start <= n:
        raise ParameterError(f"start must be an integer in [0, {n}], got {start!r}")
    if start == n:
        return iter(())
    sel = data.intervals[start:]
    first, last = int(sel[0, 0]), int(sel[-1, 0]) + 1
    frames = data.frames[first:last + 1]
    times = data.frame_times[first:last + 1]
    if workers != 1 or scheduler is not None:
        # (iter_bos_sequence checks workers: 0, 1.5 or NaN are refused there)
        results = iter_bos_sequence(data.events, frames, times, roi=data.roi,
                                    workers=workers, scheduler=scheduler, progress=progress,
                                    init=init, contrast_threshold=contrast_threshold,
                                    **options)
    else:
        results = _in_order(data, frames, times, contrast_threshold, init, progress, options)
    ks = {int(k) - start for k in unmeasured if k >= start}
    return _unmeasured_at(results, ks) if ks else results


def _unmeasured_at(results: Iterator, ks: set[int]) -> Iterator:
    """``results`` with the ``valid`` of those at positions ``ks`` all False (flows that
    are no measurement: :func:`unmeasured_intervals`); closing it closes ``results`` (a
    worker pool)."""
    import dataclasses

    try:
        for i, res in enumerate(results):
            yield dataclasses.replace(res, valid=np.zeros_like(res.valid)) if i in ks else res
    finally:
        if hasattr(results, "close"):
            results.close()


def _in_order(data, frames, times, c, prev, progress, options):
    """One interval after the other, each warm-started from the previous (``prev`` first)."""
    from evmotion.methods.bos import estimate_bos
    from evmotion.utils import progress as progress_bar

    for k in progress_bar(range(len(times) - 1), total=len(times) - 1, desc="bos",
                          unit="interval", disable=None if progress else True):
        t0, t1 = int(times[k]), int(times[k + 1])
        try:
            with warnings.catch_warnings():  # said once for the run, by its median
                warnings.simplefilter("ignore", UnderfitWarning)
                prev = estimate_bos(data.events, frames[k], t0_us=t0, t1_us=t1,
                                    frame_next=frames[k + 1], roi=data.roi, init=prev,
                                    contrast_threshold=c, on_empty="skip", **options)
        except (ParameterError, EventDataError) as exc:
            # which interval of a long recording (a dark or blurred frame, say), unless
            # the message names it or is about the ROI, the same for every interval
            text = str(exc)
            if f"[{t0}, {t1})" in text or text.startswith(("roi ", "the sensor ")):
                raise
            raise type(exc)(f"frame interval [{t0}, {t1}) us: {text}") from None
        yield prev


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
        (:func:`evmotion.parallel.imap_windows`).
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
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> import warnings
    >>> with warnings.catch_warnings(record=True):   # (start-up, fit: said in warnings)
    ...     run = solve_bos_input(load_bos_input("scene/"), param="poisson")
    >>> len(run.results), run.results[0].flow.shape
    (3, (48, 64, 2))
    """
    from evmotion.methods.bos import single_solve_displacements, warn_underfit

    unmeasured = check_input(data)
    c, source, samples = sequence_threshold(data, contrast_threshold, samples=c_samples,
                                            exclude=unmeasured)
    results = list(iter_bos_input(data, c, workers=workers, progress=progress,
                                  scheduler=scheduler, unmeasured=unmeasured, **options))
    warn_underfit((r.fit_gain for r in results), single_solve_displacements(results),
                  finest_px=min(results[0].options.scales) if results else None)
    return BosRun(results, c, source, samples)


#: The per-window numbers a BOS output stores (``window/<name>``).
WINDOW_NUMBERS = ("frame_index", "contrast_threshold", "calibrated", "objective", "n_events",
                  "seconds", "fit_gain", "relinearized", "displacement_q95")
WARM_MEANING = "the solver's patch-grid parameters of this scale (warm start of the next interval)"


def open_bos_output(path, data: BosInput, attrs: dict, options, *, resume: bool = False,
                    compression: str | None = BOS_COMPRESSION):
    """The flow output of a BOS run (:func:`evmotion.io.flowout.open_flow_output`: ``.h5``,
    ``.npz``, ``.flo`` / ``.png`` patterns) with ``q``, ``p`` and the per-window numbers as
    extra datasets where the container holds them (``.h5``, ``.npz``); an ``.h5`` also keeps
    each interval's solver parameters (``warm/scale<s>``, :func:`stored_warm_start`), so
    that ``resume`` continues it as an uninterrupted run would have (the next interval's
    warm start). ``options``: the run's :class:`~evmotion.methods.bos.BosOptions`.

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> from evmotion.methods.bos import BosOptions
    >>> data = load_bos_input("scene/")
    >>> out = open_bos_output("bos.h5", data, {"method": "bos"}, BosOptions())
    >>> out.abort()   # nothing written: no bos.h5 is left
    """
    from evmotion.io.bosfiles import BOS_CONTENT, bos_extras
    from evmotion.io.flowfiles import ExtraSpec
    from evmotion.io.flowout import EXTRA_CONTAINERS, flow_container, open_flow_output

    h, w = data.events.sensor_size
    roi = _roi_box(data)
    kind = flow_container(path)
    extras = bos_extras((h, w), scalars=WINDOW_NUMBERS) if kind in EXTRA_CONTAINERS else None
    if kind == "h5":
        for s, shape in enumerate(options.param_shapes(roi[3], roi[2])):
            extras[f"warm/scale{s}"] = ExtraSpec(shape, "<f8", "", WARM_MEANING)
    full = {"content": BOS_CONTENT, "roi": np.asarray(roi, np.int64),
            "eval_out_px": BOS_EVAL_OUT_PX, **attrs}
    return open_flow_output(path, (h, w), full, n_windows=len(data.intervals), resume=resume,
                            compression=compression, extras=extras)


def stored_warm_start(out, index: int) -> list[np.ndarray]:
    """The solver parameters of window ``index`` of a resumed ``.h5`` BOS output
    (:func:`open_bos_output`): the warm start of window ``index + 1``, as in memory."""
    names = sorted((n for n in out.extras if n.startswith("warm/scale")),
                   key=lambda n: int(n.removeprefix("warm/scale")))
    return [out.stored(n, index) for n in names]


def require_texture(data: BosInput, options=None) -> None:
    """Refuse a run none of whose intervals' frames has texture in the ROI (black,
    uniform): a textureless frame among textured ones is skipped, with a warning, by the
    solver (``on_empty="skip"``). Stops at the first textured frame, and warns when its
    texture varies from one pixel to the next
    (:func:`~evmotion.methods.bos.texture_correlation`)."""
    from evmotion.methods.bos import (
        MIN_TEXTURE_CORRELATION,
        BosOptions,
        TexturelessFrameError,
        frame_texture,
        texture_correlation,
    )

    o = options if isinstance(options, BosOptions) else BosOptions()
    best = 0.0
    for i in data.intervals[:, 0]:
        t = frame_texture(data.frames[int(i)], data.roi, o.log_eps)
        if t >= o.min_texture:
            corr = texture_correlation(data.frames[int(i)], data.roi, o.log_eps)
            if corr < MIN_TEXTURE_CORRELATION:
                warnings.warn(EvmotionWarning(
                    f"{data.frames_source}: the frames vary from one pixel to the next "
                    f"without structure (neighbouring pixels correlate {corr:.2f} < "
                    f"{MIN_TEXTURE_CORRELATION}): noise on a flat background, or a texture "
                    "finer than a pixel, whose gradient does not predict how it moves; the "
                    "flow is unreliable (on white noise worse than the zero flow). BOS "
                    "needs a background of dots of 2 px or more (or slightly defocused)"),
                    stacklevel=2)
            return
        best = max(best, t)
    raise TexturelessFrameError(
        f"{data.frames_source}: none of the {len(data.intervals)} frames that start an "
        f"interval has texture in the ROI (the 90th percentile of |grad log I| is "
        f"{'0 (a uniform image)' if best == 0 else f'{best:.3g}'} in the best one, "
        f"below {o.min_texture}): BOS needs a textured background")


def append_bos_result(out, data: BosInput, interval, res) -> dict:
    """Append one interval's :class:`~evmotion.methods.bos.BosResult` to ``out``
    (:func:`open_bos_output`) and return its summary row (times, numbers, median speed
    over the valid pixels).

    The flow, q and p are NaN outside the ROI; ``valid`` is the ROI's pixels with event
    support (:attr:`~evmotion.methods.bos.BosResult.valid`).
    """
    i, t0, t1 = (int(v) for v in interval)
    c = res.contrast_threshold
    numbers = {"frame_index": i, "contrast_threshold": float("nan") if c is None else c,
               "calibrated": float(res.calibrated), "objective": res.objective,
               "n_events": _events_in(data, t0, t1),
               "seconds": float(sum(res.timings_s)), "fit_gain": res.fit_gain,
               "relinearized": res.relinearized, "displacement_q95": res.displacement_q95}
    inside = np.zeros(res.valid.shape, bool)
    if np.isfinite(res.objective):  # NaN: an interval without events, nothing estimated
        x, y, w, h = res.roi
        inside[y:y + h, x:x + w] = True
    fields = [np.array(a, np.float32) for a in (res.flow, res.q, res.p)]
    for arr in fields:
        arr[~inside] = np.nan
    valid = res.valid
    values = None
    if out.extras:
        values = {"q": fields[1], "p": fields[2],
                  **{f"window/{k}": v for k, v in numbers.items()}}
        values.update({f"warm/scale{s}": a for s, a in enumerate(res.params)
                       if f"warm/scale{s}" in out.extras})
    out.append(fields[0], t0, t1, valid=valid, extras=values)
    speed = np.hypot(res.flow[..., 0], res.flow[..., 1])[valid]
    return {"t0_us": t0, "t1_us": t1, **numbers, "contrast_threshold": c,
            "valid_fraction": float(valid.mean()),
            # no valid pixel: no speed measured (not 0 px/s, which reads as still air)
            "median_speed_px_s": float(np.median(speed)) if speed.size else float("nan")}


def _events_in(data: BosInput, t0: int, t1: int) -> int:
    """Events of the interval inside the ROI (all of the sensor without one)."""
    ev = data.events.slice_time(t0, t1)
    if data.roi is None:
        return len(ev)
    x, y, w, h = data.roi
    return int(np.count_nonzero((ev.x >= x) & (ev.x < x + w) & (ev.y >= y) & (ev.y < y + h)))


def solve_bos_into(out, data: BosInput, contrast_threshold: float | None, *,
                   workers: int = 1, progress: bool = False, scheduler=None,
                   unmeasured: Collection[int] = (), **options) -> list[dict]:
    """Solve every selected interval of ``data`` into ``out`` (:func:`open_bos_output`),
    in order, each written as soon as it is solved, and close it; on any error or
    interrupt ``out`` is aborted (an ``.h5`` keeps its ``.part`` for ``resume``). The
    intervals a resumed output already holds are checked against ``data``'s and kept, and
    the last one's stored solver state warm-starts the next, so the result is the file an
    uninterrupted run writes. Returns one summary row per interval (``{"t0_us", "t1_us",
    "resumed": True}`` for the kept ones). The intervals of ``unmeasured`` (indices of
    ``data.intervals``, :func:`unmeasured_intervals`) are written with no valid pixel.

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> import warnings
    >>> from evmotion.methods.bos import BosOptions
    >>> data = load_bos_input("scene/")
    >>> out = open_bos_output("bos.h5", data, {"method": "bos"}, BosOptions(), resume=True)
    >>> with warnings.catch_warnings(record=True):
    ...     rows = solve_bos_into(out, data, 0.2)
    >>> [(r["t0_us"], r["t1_us"]) for r in rows]
    [(0, 8333), (8333, 16667), (16667, 25000)]
    """
    from evmotion.methods.bos import single_solve_displacements, warn_underfit

    rows, gains, moved, finest = [], [], [], None
    try:
        out.check_count(len(data.intervals))
        for i, (_, t0, t1) in enumerate(data.intervals[:len(out.done)]):
            out.check_done(i, int(t0), int(t1))
            rows.append({"t0_us": int(t0), "t1_us": int(t1), "resumed": True})
            # the run's underfit warning covers the kept intervals too
            gains.append(float(out.stored("window/fit_gain", i)))
            once = out.stored("window/relinearized", i) == 0
            moved.append(float(out.stored("window/displacement_q95", i)) if once
                         else float("nan"))
        start = len(out.done)
        init = stored_warm_start(out, start - 1) if start else None
        results = iter_bos_input(data, contrast_threshold, start=start, init=init,
                                 workers=workers, progress=progress, scheduler=scheduler,
                                 unmeasured=unmeasured, **options)
        for interval, res in zip(data.intervals[start:], results, strict=True):
            rows.append(append_bos_result(out, data, interval, res))
            # (the run's one underfit warning, by the medians over the intervals solved)
            gains.append(res.fit_gain)
            moved += single_solve_displacements([res])
            finest = min(res.options.scales)
        out.close()
        warn_underfit(gains, moved, finest)
    except BaseException:
        out.abort()
        raise
    return rows


def write_bos_output(path, data: BosInput, run: BosRun, attrs: dict, *,
                     compression: str | None = BOS_COMPRESSION) -> list[dict]:
    """Write every interval of ``run`` (:func:`open_bos_output`,
    :func:`append_bos_result`); returns one summary row per window.

    Examples
    --------
    >>> from evmotion.io.bosinput import load_bos_input
    >>> from evmotion.sim.schlieren import simulate_schlieren, write_schlieren
    >>> sim = simulate_schlieren("plume", sensor_size=(48, 64), duration_s=0.03, seed=0)
    >>> folder = write_schlieren(sim, "scene")
    >>> import warnings
    >>> data = load_bos_input("scene/")
    >>> with warnings.catch_warnings(record=True):
    ...     run = solve_bos_input(data)
    >>> rows = write_bos_output("bos.h5", data, run, {"method": "bos"})
    >>> len(rows)
    3
    """
    rows = []
    with open_bos_output(path, data, attrs, run.results[0].options,
                         compression=compression) as out:
        for interval, res in zip(data.intervals, run.results, strict=True):
            rows.append(append_bos_result(out, data, interval, res))
    return rows
