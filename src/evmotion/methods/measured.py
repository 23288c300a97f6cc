"""Whether an estimate measures anything: the light checks every method runs on its result
(contrast gain, event count), apart from :mod:`evmotion.methods.diagnostics`, whose collapse
and fit tests need the warps (imported by it, not by a network's or a flow's start-up)."""

from __future__ import annotations

import warnings

import numpy as np

from evmotion.errors import ParameterError, PoorFitWarning
from evmotion.events import EventArray

__all__ = ["CHANCE_DRAWS", "CHANCE_SEED", "DENSE_PIXELS_PER_EVENT", "MAX_GAP_SHARE",
           "MAX_ONE_POLARITY", "MAX_POLARITY_SWING", "MIN_BURST_CV", "MIN_CHANCE_Z",
           "MIN_CONTRAST_GAIN",
           "MIN_FIT_EVENTS", "MIN_FLOW_DENSITY", "MIN_FLOW_EVENTS",
           "MIN_FLOW_MOTION_PX", "MIN_HALVES_CORRELATION", "MIN_MOTION_PX",
           "MIN_TRANSLATION_MOTION_PX",
           "alignment_chance", "alignment_gain", "min_motion_px",
           "box_offsets", "framed_landing",
           "flow_alignment_chance", "flow_alignment_gain", "gap_share",
           "halves_consistency", "halves_correlation", "lit_not_moved", "local_swing",
           "min_flow_events", "pixel_counts", "polarity_bursts", "warn_by_chance", "warn_by_refit",
           "warn_flicker", "warn_gap", "warn_inconsistent_halves", "warn_no_gain",
           "warn_small_flow", "warn_small_motion", "warn_too_few", "warn_too_few_for_flow",
           "warp_alignment_chance"]

# an estimate whose image of warped events is not this much sharper (variance ratio) than
# the identity warp's measures nothing (a 3.3 ms ECD window: 1.002, its rotation wrong)
MIN_CONTRAST_GAIN = 1.05
#: Fewest events a window needs for its contrast to measure a motion: 20-30 events of a
#: 2 rad/s rotation sharpened by 6-10 % at random parameters (2026-11-29).
MIN_FIT_EVENTS = 100
#: Permutations of the events' times :func:`alignment_chance` draws for the spread of
#: what chance gives: 16 estimate its standard deviation within about 20 %, at 6-14 ms for
#: 3k-30k events (1-6 % of a multicm call, 1-4 % of a segmentation's; probe DB).
CHANCE_DRAWS = 16
#: Seed of those permutations: a verdict on the same events repeats; other seeds draw
#: other permutations (``seed=`` of the functions below; the z of a real motion moves by
#: tens of percent, probe DK, far above MIN_CHANCE_Z either way).
CHANCE_SEED = 0
#: Least distance (standard deviations of the permuted images' variances above their
#: mean) at which an alignment beats chance (:func:`warn_by_chance`'s ``z``). One more
#: draw of the null lies this far above it with a chance of about 1e-4 for a normal
#: spread, 1e-3 for the t spread of 16 draws. An estimate fitted to noise lies somewhat
#: above its own null, for it chose the motion that sharpened these very events (probe
#: DB, uniform noise, 12-40 seeds a size: multicm's flows up to 3.6 on 4x4 to 48x48, mean
#: 0-1.3; 5.8 and 6.2 on 64x64, whose many tiles' noise the ratio, halves and refit tests
#: flag; segmentation clusters' warps up to 4.5 on 8x8 to 40x40). Motions on the same
#: sensors (moving edges and dots, two motions on 16x16 and 32x32) lie at 17 and beyond.
MIN_CHANCE_Z = 5.0


def warn_no_gain(gain: float, warp: str, stacklevel: int = 3,
                 optimum_hint: str = "") -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when the estimate sharpens the
    image of the events by less than :data:`MIN_CONTRAST_GAIN` (its variance over the
    identity warp's): the window shows no motion the warp can measure; returns its
    message (else None). ``optimum_hint`` says how to escape a local optimum, where the
    method has a way."""
    if not gain < MIN_CONTRAST_GAIN:  # NaN (no contrast at all) is collapse's to say
        return None
    msg = (f"no focus: the {warp} warp sharpens the image of the events by only "
           f"{100 * (gain - 1):.1f} % (threshold {100 * (MIN_CONTRAST_GAIN - 1):.0f} %) -- "
           "too few events, no motion, hot or flickering pixels, a window too short or too "
           f"long for the motion, or a local optimum{optimum_hint}; the estimate is not a "
           "measurement")
    warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
    return msg


#: Least median displacement of the events over the window (px) for a contrast to
#: measure it: the IWE sharpens by events landing on the same pixels, so a motion under a
#: pixel or two is barely seen (the thesis: CMax needs about 3-5 px). Rotation windows of
#: 2,000 events moving ~1.3 px came out at errors up to 1.7 rad/s, marked valid (probe Y).
MIN_MOTION_PX = 1.5
#: ... for a translation, which moves every event by the same sub-pixel step: the bilinear
#: votes' bias at that step is then the same for all of them, not averaged over the image
#: as a rotation's or a zoom's spread of steps averages it. Textured translations at 346x260
#: rendered outside evmotion and by its simulator, 12 windows each: the median estimate off
#: the true velocity by 8.6 % / 10.2 % of |v| at 1.6 px, 2.9 % / 7.4 % at 2.1 px, 1.0 % /
#: 2.8 % at 2.6 px (probe EGOFOREIGN); rotations at 1.8-2.2 px came within 2.5-3.5 %.
MIN_TRANSLATION_MOTION_PX = 2.5


def min_motion_px(warp: str) -> float:
    """The least median displacement (px) over a window at which a ``warp`` estimate is a
    measurement: :data:`MIN_TRANSLATION_MOTION_PX` for ``translation``, else
    :data:`MIN_MOTION_PX`.

    Examples
    --------
    >>> min_motion_px("translation"), min_motion_px("rotation")
    (2.5, 1.5)
    """
    return MIN_TRANSLATION_MOTION_PX if warp == "translation" else MIN_MOTION_PX


#: Median displacement (px) of a dense flow's valid pixels over its window below which the
#: flow is said to be biased (a warning; its pixels stay valid): multicm's tiles are
#: translations, each with the one sub-pixel step whose vote bias does not average out.
#: Textured 346x260 windows moving under 2 px came out 11-14 % too fast, 8.5 deg off,
#: where 20-30 ms windows of the same recordings measured 0.3-1.2 % (probe FLOWFOREIGN);
#: flow_foreign.md's windows moving 1.2 px score an AEE of 0.16 px, 13 % of the motion.
#: The same bias as a translation warp's, so the same least motion.
MIN_FLOW_MOTION_PX = MIN_TRANSLATION_MOTION_PX


def _floored(px: float) -> float:
    """``px`` rounded down to 0.01 px, as the small-motion warnings print it (rounded to
    nearest, "1.5 px ... needs 1.5 px or more" read as a contradiction)."""
    return np.floor(px * 100) / 100


def warn_small_flow(moved_px: float, method: str, stacklevel: int = 3) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when a dense flow moves its valid
    pixels by less than :data:`MIN_FLOW_MOTION_PX` over the window (median), else None;
    returns its message. The flow stays a measurement, with a bias that is a large share of
    such a motion."""
    if not moved_px < MIN_FLOW_MOTION_PX:
        return None
    msg = (f"small motion: the {method} moves its pixels by {_floored(moved_px):.2f} px over "
           "the window (median): contrast maximization's sub-pixel bias is a large share of a "
           f"motion under {MIN_FLOW_MOTION_PX:g} px (11-14 % of the speed on textured windows "
           "moving under 2 px) -- longer windows measure it better")
    warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
    return msg


def warn_small_motion(moved_px: float, warp: str, stacklevel: int = 3) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when the estimate moves the
    window's events by less than :func:`min_motion_px` of ``warp`` (median over the
    events); returns its message (else None)."""
    least = min_motion_px(warp)
    if not moved_px < least:
        return None
    msg = (f"small motion: the estimate moves the events by {_floored(moved_px):.2f} px over the "
           f"window (median; contrast maximization needs about {least:g} px or more "
           f"to measure a {warp} motion): not a measurement -- use longer windows")
    warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
    return msg


#: Fewest events a window needs for a dense flow (a field of unknowns, where a warp has
#: 1-8) to be a measurement on a large sensor: on 240x180, windows of 100-600 events of
#: simulated scenes moving 0.06-0.2 px gave flows moving them 2-5 px that passed the focus,
#: chance and halves tests (3 of 160 windows; probe BQ, 2026-12-01), and no window under
#: 1,000 events of the shared recordings but the shapes' was valid at all. A small sensor
#: needs fewer (:func:`min_flow_events`).
MIN_FLOW_EVENTS = 1000
#: ... or this many events per pixel of the sensor, where that is fewer (and at least
#: :data:`MIN_FIT_EVENTS`): 500 events on 32x32 (0.5 a pixel, as 30,000 on 240x180)
#: measured a translation at AEE 0.30 px for 2.2 of no flow (probe BR).
MIN_FLOW_DENSITY = 0.05


def min_flow_events(sensor_size: tuple[int, int]) -> int:
    """The fewest events a window of a ``sensor_size`` (H, W) sensor needs for its dense
    flow to be a measurement: :data:`MIN_FLOW_EVENTS`, or :data:`MIN_FLOW_DENSITY` a
    pixel where that is fewer, and at least :data:`MIN_FIT_EVENTS`.

    Examples
    --------
    >>> min_flow_events((180, 240)), min_flow_events((64, 64)), min_flow_events((32, 32))
    (1000, 205, 100)
    """
    h, w = sensor_size
    return int(min(MIN_FLOW_EVENTS, max(MIN_FIT_EVENTS, np.ceil(MIN_FLOW_DENSITY * h * w))))


def warn_too_few(n_events: int, what: str, stacklevel: int = 3,
                 least: int = MIN_FIT_EVENTS) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when a window holds fewer than
    ``least`` events: too few for a contrast to measure ``what`` (a handful of events
    sharpen by chance); returns its message (else None). ``least``:
    :data:`MIN_FIT_EVENTS` for a warp's motion; a dense flow's is
    :func:`warn_too_few_for_flow`'s."""
    if n_events >= least:
        return None
    msg = (f"too few events: {n_events} (fewer than {least}) cannot measure a {what}; the "
           "estimate is not a measurement -- use longer windows")
    warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
    return msg


def warn_too_few_for_flow(events: EventArray, what: str = "dense flow") -> str | None:
    """:func:`warn_too_few` for a dense flow of ``events`` (multicm's, the network's): at
    least :func:`min_flow_events` of their sensor."""
    return warn_too_few(len(events), what, stacklevel=4,
                        least=min_flow_events(events.sensor_size))


#: A window whose longest stretch without an event exceeds this share of its span saw
#: the motion only on either side of it: a constant motion fitted across the gap lines
#: the two sides up whatever happened in between (a window across 100 s without events
#: gave 0.02 px/s for 220, contrast gain 1.19, valid; probe). Events of a moving scene
#: arrive far more evenly: 30k of them leave gaps of ~1e-3 of the span.
MAX_GAP_SHARE = 0.5


def gap_share(t: np.ndarray) -> float:
    """The longest interval between consecutive times ``t`` (sorted) over their span; 0
    for fewer than two times or no span.

    Examples
    --------
    >>> gap_share(np.array([0, 1, 2, 100]))
    0.98
    """
    t = np.asarray(t)
    if t.size < 2 or t[-1] <= t[0]:
        return 0.0
    return float(np.max(np.diff(t)) / (t[-1] - t[0]))


def warn_gap(t: np.ndarray, what: str, stacklevel: int = 3) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when the events' times ``t`` (µs,
    sorted) leave a gap longer than :data:`MAX_GAP_SHARE` of the window; returns its
    message (else None)."""
    share = gap_share(t)
    if share <= MAX_GAP_SHARE:
        return None
    t = np.asarray(t)
    gap_s = float(np.max(np.diff(t))) * 1e-6
    msg = (f"time gap: no event for {gap_s:.6g} s ({share:.0%} of the window): the {what} "
           "fitted across it lines up the events "
           "on either side whatever moved in between: not a measurement -- cut the windows "
           "by time (--window-us) or the recording at the gap")
    warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
    return msg


def flow_alignment_gain(events: EventArray, flow: np.ndarray, t_ref_us: int) -> float:
    """How much better a window's dense flow (px/s, (H, W, 2)) aligns its events than
    chance: the variance of their image warped to ``t_ref_us`` over that of the same warp
    with the events' times permuted (seeded). A flow's geometry alone (a converging field
    crowds any events, noise too: its image sharpens by up to 1.4 against the unwarped
    one) sharpens both alike; only a flow that follows the events' motion sharpens the
    first more. An optimizer that fits a flexible flow to the window's own image can make
    it sharper than the unwarped one with no motion to follow (multicm's focus 1.2 on a
    window moving half a pixel, 19 on a sparse 1280x720 window whose warped image was
    blurrier than the unwarped one); shuffled times keep that fit and lose the motion.
    Nearest-pixel votes; events where the flow is not finite (unknown) are left out; NaN
    when undefined (no events with a flow, a constant image).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.sort(rng.integers(0, 50_000, 2000))
    >>> ev = EventArray(x=np.round(rng.choice([10, 30], 2000) + 400 * t * 1e-6), y=
    ...                 rng.integers(0, 40, 2000), t=t, p=np.ones(2000), sensor_size=(40, 60))
    >>> flow = np.zeros((40, 60, 2), np.float32); flow[..., 0] = 400.0
    >>> bool(flow_alignment_gain(ev, flow, 0) > 2)
    True
    """
    return flow_alignment_chance(events, flow, t_ref_us, draws=1)[0]


def flow_alignment_chance(events: EventArray, flow: np.ndarray, t_ref_us: int,
                          draws: int = CHANCE_DRAWS,
                          seed: int = CHANCE_SEED) -> tuple[float, float]:
    """:func:`flow_alignment_gain` and how far the flow's alignment lies above chance's
    scatter, ``(gain, z)`` (:func:`alignment_chance`); NaN where undefined."""
    x, y, f = _flow_at_events(events, flow)
    known = np.isfinite(f).all(axis=1)
    if not known.any():
        return float("nan"), float("nan")
    t = np.asarray(events.t)
    if not known.all():
        x, y, t, f = x[known], y[known], t[known], f[known]
    return alignment_chance(x, y, t, f, t_ref_us, events.sensor_size, draws=draws, seed=seed)


def _flow_at_events(events: EventArray, flow) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The events' pixels (rounded, clipped to the sensor) and ``flow`` (checked to be the
    sensor's (H, W, 2)) there, (N, 2)."""
    h, w = events.sensor_size
    if np.ndim(flow) != 3 or np.shape(flow) != (h, w, 2):
        raise ParameterError(f"flow has shape {np.shape(flow)}, expected the sensor's "
                             f"(H, W, 2) = {(h, w, 2)}")
    x = np.clip(np.rint(events.x).astype(np.intp), 0, w - 1)
    y = np.clip(np.rint(events.y).astype(np.intp), 0, h - 1)
    return x, y, np.asarray(flow)[y, x]


def alignment_gain(x: np.ndarray, y: np.ndarray, t: np.ndarray, f: np.ndarray,
                   t_ref_us: int, shape: tuple[int, int]) -> float:
    """:func:`flow_alignment_gain` of events at integer pixels ``x, y``, times ``t`` (µs)
    with flows ``f`` (N, 2) px/s, on a sensor of ``shape`` (H, W)."""
    return alignment_chance(x, y, t, f, t_ref_us, shape, draws=1)[0]


#: A count image of the whole sensor is made where the sensor has at most this many pixels
#: an event (:func:`pixel_counts`), else the counts of the pixels the events touch.
DENSE_PIXELS_PER_EVENT = 4


def pixel_counts(x, y, shape: tuple[int, int]) -> np.ndarray:
    """Events per pixel (float64) of events at ``x, y`` (rounded to the nearest pixel;
    outside the sensor ``shape`` (H, W) ignored): every pixel's count where the sensor
    has at most :data:`DENSE_PIXELS_PER_EVENT` pixels an event (bincount, linear time),
    else the touched pixels' alone (a megapixel sensor's image costs more than sorting a
    few thousand events). Sums over the counts are the same either way.

    Examples
    --------
    >>> pixel_counts(np.array([0.0, 1.2, 0.9]), np.zeros(3), (1, 2)).tolist()
    [1.0, 2.0]
    """
    h, w = int(shape[0]), int(shape[1])
    xi = np.rint(np.asarray(x, dtype=np.float64)).astype(np.int64)
    yi = np.rint(np.asarray(y, dtype=np.float64)).astype(np.int64)
    keep = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    idx = yi[keep] * w + xi[keep]
    counts = (np.bincount(idx, minlength=h * w)
              if h * w <= DENSE_PIXELS_PER_EVENT * max(xi.size, 1)
              else np.unique(idx, return_counts=True)[1])
    return counts.astype(np.float64)


def alignment_chance(x: np.ndarray, y: np.ndarray, t: np.ndarray, f: np.ndarray,
                     t_ref_us: int, shape: tuple[int, int], draws: int = CHANCE_DRAWS,
                     seed: int = CHANCE_SEED) -> tuple[float, float]:
    """How much better flows ``f`` (N, 2) px/s align events at integer pixels ``x, y``,
    times ``t`` (µs), sensor ``shape`` (H, W), than chance: ``(gain, z)``.

    ``gain`` is :func:`alignment_gain`: the variance of the events' image warped to
    ``t_ref_us`` over that of the same warp with their times permuted (the first of
    ``draws`` permutations, drawn with ``seed``). ``z`` is how many standard deviations of the
    ``draws`` permuted images' variances the warped image's lies above their mean (NaN for
    fewer than two draws): a ratio alone does not say how far chance itself scatters,
    and that is wide where the image has few pixels (uniform noise of 3,000 events on 8x8
    scattered the ratio to 1.31 with nothing moving; probe DB), narrow on a large one.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.sort(rng.integers(0, 30_000, 3000))
    >>> x, y = rng.integers(0, 8, 3000), rng.integers(0, 8, 3000)
    >>> f = np.tile([100.0, -50.0], (3000, 1))
    >>> gain, z = alignment_chance(x, y, t, f, 0, (8, 8))
    >>> bool(abs(z) < MIN_CHANCE_Z)
    True
    """
    h, w = shape
    dt = (t - np.int64(t_ref_us)).astype(np.float64) * 1e-6
    f = np.asarray(f, np.float64)
    n_px = float(h * w)

    def variance(times):
        # (a window of a few thousand events on a megapixel sensor: no image of a million
        # bins for each draw)
        counts = pixel_counts(x - f[:, 0] * times, y - f[:, 1] * times, shape)
        return float(np.sum(counts**2) / n_px - (np.sum(counts) / n_px) ** 2)

    rng = np.random.default_rng(seed)
    null = np.array([variance(rng.permutation(dt)) for _ in range(max(int(draws), 1))])
    v = variance(dt)
    gain = v / null[0] if null[0] > 0 else float("nan")
    if null.size < 2:
        return gain, float("nan")
    spread = float(np.std(null, ddof=1))
    above = v - float(np.mean(null))
    if not spread > 0:  # every permutation gave one image: a flow that moves nothing
        return gain, float(np.sign(above)) * float("inf") if above != 0 else 0.0
    return gain, above / spread


def warp_alignment_chance(x: np.ndarray, y: np.ndarray, dt: np.ndarray, xw: np.ndarray,
                          yw: np.ndarray, shape: tuple[int, int], draws: int = CHANCE_DRAWS,
                          seed: int = CHANCE_SEED) -> tuple[float, float]:
    """:func:`alignment_chance` of a warp that moves the events at ``x, y`` (px), ``dt``
    seconds from its reference time, to ``xw, yw`` there: each event's motion is its
    displacement over its time offset (events at the reference time itself: none), the
    reference is time 0. ``(NaN, NaN)`` where a motion is not finite.

    Examples
    --------
    >>> dt = np.linspace(0.0, 0.03, 3000)
    >>> x = np.tile(np.arange(10.0, 50.0, 4.0), 300) + 200.0 * dt
    >>> y = np.repeat(np.arange(300.0), 10) % 40
    >>> gain, z = warp_alignment_chance(x, y, dt, x - 200.0 * dt, y, (40, 60))
    >>> bool(gain > 2 and z > MIN_CHANCE_Z)
    True
    """
    dt = np.asarray(dt, np.float64)
    moving = np.abs(dt) > 1e-9
    f = np.zeros((dt.size, 2))
    f[moving, 0] = (x[moving] - xw[moving]) / dt[moving]
    f[moving, 1] = (y[moving] - yw[moving]) / dt[moving]
    if not np.isfinite(f).all():
        return float("nan"), float("nan")
    return alignment_chance(np.asarray(x, np.float64), np.asarray(y, np.float64), dt * 1e6,
                            f, 0, shape, draws=draws, seed=seed)


#: A tile whose events a translation of their own sharpens this much more than the flow
#: does (:func:`evmotion.core.translation.tile_gains`, 4 x 4 tiles) holds a motion the
#: flow does not follow. Flows that follow the motion scored at most 1.21 (simulated
#: translation, rotation, zoom; a probe's renderer) and 1.20 (the eight ECD 30k windows);
#: the background of a probe's moving patch under the patch's flow 1.35-2.6, the
#: simulator's moving object's worst tiles 1.40-1.49 (AEE 1.7-2.0 px there).
OTHER_MOTION_GAIN = 1.5
#: The tiles the check takes: 2^(level - 1) a side (3: 4 x 4).
OTHER_MOTION_LEVEL = 3


def other_motion(x: np.ndarray, y: np.ndarray, s: np.ndarray, disp: np.ndarray,
                 valid: np.ndarray, what: str, *, scores=None) -> tuple[np.ndarray, int]:
    """``valid`` less the tiles whose events a translation of their own sharpens
    :data:`OTHER_MOTION_GAIN` times more than the dense displacement ``disp`` does (a
    PoorFitWarning names them), and how many tiles that is.

    Parameters
    ----------
    x, y, s : ndarray
        The events, as :func:`evmotion.core.translation.tile_gains` takes them.
    disp : ndarray, (H, W, 2)
        The flow's displacement over the window, px (dense: read at each event's pixel).
    valid : ndarray of bool, (H, W)
    what : str
        The flow, as the warning names it.
    scores : callable, optional
        As for :func:`evmotion.core.translation.tile_gains` (default numpy).
    """
    from evmotion.core.tilegrid import pixel_tiles, scale_grid
    from evmotion.core.translation import TILE_REACH, tile_gains

    h, w = valid.shape
    grid = scale_grid(OTHER_MOTION_LEVEL, (h, w))
    xi = np.clip(np.rint(x).astype(np.int64), 0, w - 1)
    yi = np.clip(np.rint(y).astype(np.int64), 0, h - 1)
    _, gain = tile_gains(x, y, s, np.asarray(disp, np.float64)[yi, xi], grid,
                         TILE_REACH * max(h, w), scores=scores)
    bad = gain >= OTHER_MOTION_GAIN
    if not bad.any():
        return valid, 0
    warnings.warn(f"another motion: in {int(bad.sum())} of {bad.size} tiles a translation "
                  f"of their own sharpens the events up to {np.nanmax(gain):.2f}x more than "
                  f"the {what} (an independently moving object the flow does not "
                  "follow?); their pixels are not a measurement (valid = False)",
                  PoorFitWarning, stacklevel=3)
    ty, tx = pixel_tiles((h, w), grid)
    return valid & ~bad[ty, tx], int(bad.sum())


def warn_by_refit(gain: float, what: str, stacklevel: int = 3) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when a dense flow sharpens the
    window's events less than :data:`MIN_CONTRAST_GAIN` more than the same solver
    sharpens them with their times shuffled (``gain``: the ratio of the two focuses);
    returns its message (else None)."""
    if not gain < MIN_CONTRAST_GAIN:  # NaN: nothing to test
        return None
    warnings.warn(msg := f"no focus: the {what} sharpens the events only "
                  f"{100 * (gain - 1):+.1f} % more than the same fit to them with their times "
                  f"shuffled (threshold {100 * (MIN_CONTRAST_GAIN - 1):.0f} %) -- too few "
                  "events for the flow's unknowns, or noise; the estimate is not a "
                  "measurement", PoorFitWarning, stacklevel=stacklevel)
    return msg


def warn_by_chance(gain: float, what: str, stacklevel: int = 3,
                   z: float = float("nan")) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when a dense flow aligns the
    window's events less than :data:`MIN_CONTRAST_GAIN` better than chance
    (:func:`flow_alignment_gain`), or, given its ``z`` (:func:`alignment_chance`), less
    than :data:`MIN_CHANCE_Z` standard deviations of chance's scatter above it; returns
    its message (else None)."""
    causes = ("noise, no texture, a motion of a pixel or so, or one the window cannot hold "
              "(too long, too fast, not constant)")
    if not np.isfinite(gain):
        # nothing to test (every event warped off the sensor): "+nan % better ... 0.0
        # standard deviations" had been said (review DR)
        return None
    if gain < MIN_CONTRAST_GAIN:
        msg = (f"no focus: the {what} aligns the events only {100 * (gain - 1):+.1f} % "
               f"better than with their times shuffled (threshold "
               f"{100 * (MIN_CONTRAST_GAIN - 1):.0f} %) -- {causes}; the estimate is not a "
               "measurement")
    elif z < MIN_CHANCE_Z:
        msg = (f"no focus: the {what} aligns the events {100 * (gain - 1):+.1f} % better "
               f"than with their times shuffled, but shuffled times scatter as far: "
               f"{z:.1f} standard deviations of {CHANCE_DRAWS} shuffles above their mean "
               f"(threshold {MIN_CHANCE_Z:g}) -- {causes}, or a sensor too small for its "
               "image to tell; the estimate is not a measurement")
    else:
        return None
    warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
    return msg


#: Time bins of :func:`polarity_bursts`.
POLARITY_BINS = 16
#: A window whose events' mean polarity swings over time by this much in every quarter of
#: the sensor is lit, not moved (:func:`polarity_bursts`): flicker lights the whole
#: sensor at once, a moving edge of one sign only its part. The shared real recordings
#: (2k-30k event windows) reach 0.48 (a bursty 640x480 Prophesee file; the others 0.34),
#: probe AK's 50-120 Hz flicker 0.5-1.0 where it fell inside a window.
MAX_POLARITY_SWING = 0.5
#: ... or whose events are this share of one polarity and come in bursts, the time bins'
#: counts varying by :data:`MIN_BURST_CV` of their mean or more: a window inside one
#: flicker phase (probe AK: 97-100 %, 2.3-3.4) or a light switched on or off. One
#: polarity at a steady rate is motion: a single edge of one sign (probe AL: a dark bar
#: entering, 98 % OFF, the rest noise, rate 0.01-0.03), a sensor whose OFF threshold the
#: scene's contrast never reaches (AL: 97-98 % ON), data without polarity. The shared
#: recordings' counts vary by at most 1.17, 1 ms time stamps 0.62.
MAX_ONE_POLARITY = 0.95
MIN_BURST_CV = 1.5


def _time_bins(t: np.ndarray) -> np.ndarray:
    """Each time's bin of :data:`POLARITY_BINS` equal bins over ``t``'s span."""
    span = max(int(t[-1] - t[0]), 1)
    return np.minimum((t - t[0]) * POLARITY_BINS // span, POLARITY_BINS - 1)


def _swing(t: np.ndarray, pol: np.ndarray) -> float:
    """Event-weighted standard deviation over :data:`POLARITY_BINS` time bins of each
    bin's mean polarity (+-1, or polarities less their block's mean), less what the bins'
    finite counts give by chance."""
    b = _time_bins(t)
    n = np.bincount(b, minlength=POLARITY_BINS)
    sums = np.bincount(b, pol, minlength=POLARITY_BINS)
    ok = n > 0
    mu = pol.mean()
    var = np.sum((sums[ok] - n[ok] * mu) ** 2 / n[ok]) / len(pol)
    chance = ok.sum() * np.mean((pol - mu) ** 2) / len(pol)
    return float(np.sqrt(max(var - chance, 0.0)))


def _pixel_coords(events: EventArray) -> tuple[np.ndarray, np.ndarray]:
    """The events' pixels as int64, those off the sensor (undistorted and kept past its
    border) on its edge: a stream's stretch is not filtered before these tests, and a
    negative pixel failed np.bincount (probe CB)."""
    h, w = events.sensor_size
    return (np.clip(np.asarray(events.x, np.int64), 0, w - 1),
            np.clip(np.asarray(events.y, np.int64), 0, h - 1))


def _quarters_swing(events: EventArray, pol: np.ndarray) -> float:
    """:func:`_swing` in the quarter of the sensor where it is least, of the quarters
    holding a tenth of the events or more (the whole sensor's with fewer than two)."""
    t = np.asarray(events.t, np.int64)
    h, w = events.sensor_size
    xi, yi = _pixel_coords(events)
    quarter = (yi * 2 // h) * 2 + xi * 2 // w
    # (a mask only for the quarters that hold enough events: this runs on every stretch
    # of a triplet stream)
    held = np.flatnonzero(np.bincount(quarter, minlength=4) >= 0.1 * len(t))
    swings = [_swing(t[q], pol[q]) for q in (quarter == k for k in held)]
    return min(swings) if len(swings) >= 2 else _swing(t, pol)


def polarity_bursts(events: EventArray) -> tuple[float, float, float]:
    """How much the window's events come in bursts of one polarity, as flickering light or
    a lighting change fires them, not motion: ``(swing, one, burst)``. ``swing``: how
    much the mean polarity varies over the window's time (:func:`_swing`) in the quarter
    of the sensor where it varies least, of the quarters holding a tenth of the events or
    more; ``one``: the share of the commoner polarity; ``burst``: the coefficient of
    variation of the event counts of :data:`POLARITY_BINS` time bins, less a steady
    rate's.

    Examples
    --------
    >>> t = np.arange(4000)
    >>> lit = EventArray(x=t % 30, y=(t // 30) % 20, t=t, p=t < 2000, sensor_size=(20, 30))
    >>> [round(v, 2) for v in polarity_bursts(lit)]
    [0.96, 0.5, 0.0]
    >>> moved = EventArray(x=t % 30, y=(t // 30) % 20, t=t, p=t % 2, sensor_size=(20, 30))
    >>> [round(v, 2) for v in polarity_bursts(moved)]
    [0.0, 0.5, 0.0]
    """
    if len(events) == 0:
        return float("nan"), float("nan"), float("nan")
    t = np.asarray(events.t, np.int64)
    on = np.asarray(events.p) > 0
    swing = _quarters_swing(events, np.where(on, 1.0, -1.0))
    n = np.bincount(_time_bins(t), minlength=POLARITY_BINS)
    # (less the variation of a steady rate's counts, as _swing takes off its own)
    cv2 = (n.std() / n.mean()) ** 2 - POLARITY_BINS / len(t)
    n_on = np.count_nonzero(on)
    return (swing, float(max(n_on, len(t) - n_on) / len(t)), float(np.sqrt(max(cv2, 0.0))))


#: Side (px) of the blocks of :func:`local_swing`: smaller than a calibration
#: checkerboard's squares, large enough to hold events of both polarities under flicker.
SWING_BLOCK_PX = 8
#: A window whose polarity swings (:data:`MAX_POLARITY_SWING`) is lit, not moved, only if
#: its blocks' polarities swing in step by this much too (:func:`local_swing`): a
#: translating checkerboard's swings 0.48-0.53 over the sensor, its blocks' 0.02-0.06
#: (each block sees one edge's sign); flicker of 80 % of the events 0.77 and 0.75; the
#: shared real recordings' blocks 0.01-0.28, 30k-event windows.
MIN_LOCAL_SWING = 0.3


def local_swing(events: EventArray, block_px: int = SWING_BLOCK_PX) -> float:
    """How much the window's polarities swing in step over time within small blocks of
    the sensor: :func:`polarity_bursts`' swing of each event's polarity less the mean
    polarity of its ``block_px`` square. Flickering light turns every pixel ON and then
    OFF together, so its swing stays; motion swings the sensor's mean polarity only by
    moving edges of one sign in and out of view at once (a periodic texture: all of them),
    each block keeping its own sign, and its swing goes.

    Examples
    --------
    >>> t = np.arange(4000)
    >>> lit = EventArray(x=t % 30, y=(t // 30) % 20, t=t, p=t < 2000, sensor_size=(20, 30))
    >>> round(local_swing(lit), 2)
    0.95

    Stripes 8 px wide, ON edges crossing every other one early, OFF edges the others late:

    >>> early = t < 2000
    >>> stripe = np.where(early, 0, 1) + 2 * (t % 2)
    >>> edges = EventArray(x=8 * stripe + (t // 2) % 8, y=(t // 16) % 16, t=t, p=early,
    ...                    sensor_size=(16, 32))
    >>> round(polarity_bursts(edges)[0], 2), round(local_swing(edges), 2)
    (0.96, 0.0)
    """
    if len(events) == 0:
        return float("nan")
    pol = np.where(np.asarray(events.p) > 0, 1.0, -1.0)
    nbx = -(-events.sensor_size[1] // block_px)
    xi, yi = _pixel_coords(events)
    block = yi // block_px * nbx + xi // block_px
    mean = np.bincount(block, pol) / np.maximum(np.bincount(block), 1)
    return _quarters_swing(events, pol - mean[block])


def lit_not_moved(events: EventArray) -> str | None:
    """Why the window's events come in bursts of one polarity (:func:`polarity_bursts`
    beyond :data:`MAX_POLARITY_SWING`, in small blocks too (:func:`local_swing`), or
    :data:`MAX_ONE_POLARITY` with :data:`MIN_BURST_CV`), or None when they do not."""
    swing, one, burst = polarity_bursts(events)
    if swing >= MAX_POLARITY_SWING and (local := local_swing(events)) >= MIN_LOCAL_SWING:
        # (probe BG: a translating checkerboard, flow right, was flagged on the first alone)
        return (f"their mean polarity swings by {swing:.2f} over the window in every quarter "
                f"of the sensor, and by {local:.2f} in its {SWING_BLOCK_PX} px blocks "
                f"(thresholds {MAX_POLARITY_SWING:g}, {MIN_LOCAL_SWING:g})")
    if one >= MAX_ONE_POLARITY and burst >= MIN_BURST_CV:
        return f"{one:.0%} of them have one polarity (threshold {MAX_ONE_POLARITY:.0%})"
    return None


def warn_flicker(events: EventArray, what: str, stacklevel: int = 3) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when the window's events come in
    bursts of one polarity (:func:`lit_not_moved`): an estimate there sharpens the bursts,
    not a motion (probe AK: the network's flow 20-800x the truth under flicker, marked
    valid); returns its message (else None)."""
    how = lit_not_moved(events)
    if how is None:
        return None
    warnings.warn(msg := f"no measurement: the window's events come in bursts of one polarity "
                  f"({how}) -- flickering light or a lighting change, not motion; the "
                  f"{what} is not a measurement", PoorFitWarning, stacklevel=stacklevel)
    return msg


#: Lamps on mains power flicker at twice its frequency (100 Hz on 50 Hz mains, 120 Hz on
#: 60 Hz) and a sensor fires on each rise and fall: the event rate carries a line at one of
#: these frequencies (Hz).
MAINS_FLICKER_HZ = (100.0, 120.0, 200.0, 240.0)
#: A line this many times the median power of the event rate's spectrum over 40-1000 Hz
#: is flicker: 264 at 2 % flicker of 100 Hz and 9363 at 10 % of 120 Hz (probe BF's
#: renderer), 54 on the shared DAVIS346 recording; 0.1-26 on 12 scenes without flicker of
#: two BOS renderers, the probes' and the simulator (the largest on runs of 0.05 s, whose
#: 20 Hz bins hold the air's slow changes), 10.8 on the shared EVT3 recording
MAINS_FLICKER_LINE = 50.0
#: Shorter recordings are not looked at (five periods of 100 Hz)
MAINS_FLICKER_MIN_SPAN_US = 50_000


def mains_flicker(t: np.ndarray) -> tuple[float, float] | None:
    """``(frequency Hz, strength)`` of the strongest line of :data:`MAINS_FLICKER_HZ` in
    the event rate of the times ``t`` (µs, sorted) where it is at least
    :data:`MAINS_FLICKER_LINE` times the spectrum's median over 40-1000 Hz, else None.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> steady = np.sort(rng.integers(0, 200_000, 20_000))
    >>> lit = steady[rng.random(steady.size) < 0.5 + 0.5 * np.sin(2 * np.pi * 1e-4 * steady)]
    >>> mains_flicker(steady) is None, mains_flicker(lit)[0]
    (True, 100.0)
    """
    t = np.asarray(t, np.int64)
    if t.size < 2 or t[-1] - t[0] < MAINS_FLICKER_MIN_SPAN_US:
        return None
    bin_us = 250  # 4 kHz: 2 kHz of spectrum
    rate = np.bincount((t - t[0]) // bin_us).astype(np.float64)
    rate -= rate.mean()
    power = np.abs(np.fft.rfft(rate * np.hanning(rate.size))) ** 2
    freq = np.fft.rfftfreq(rate.size, bin_us * 1e-6)
    floor = np.median(power[(freq >= 40.0) & (freq <= 1000.0)])
    if not floor > 0:
        return None
    near = [(float(power[np.abs(freq - f0) <= max(3.0, freq[1])].max()) / floor, f0)
            for f0 in MAINS_FLICKER_HZ]
    strength, f0 = max(near)
    return (f0, strength) if strength >= MAINS_FLICKER_LINE else None


#: A dense flow that carries the window's first half onto its second less than this
#: (:func:`halves_consistency`) measures no motion: a constant pan in an 8 s window
#: (the scene crossed the image twice) came out at 2.6 px/s for 67, valid (probe AJ),
#: correlation -0.14; 30k noise events on 128x128 -0.11. Correct flows: the ECD 30k
#: windows 0.80-0.98 (the network's 0.59-0.96), simulated windows of 2k-40k events
#: 0.32-0.996, probe AC's 89 well-estimated sparse windows (2k-12k events) 0.21 and up.
#: It catches gross failures only: AC's 38 valid bad windows score 0.35 and up.
MIN_HALVES_CORRELATION = 0.15


def halves_consistency(events: EventArray, flow: np.ndarray, t_ref_us: int) -> float:
    """How well a dense flow (px/s, (H, W, 2)) carries the window's events of its first
    half (by time) onto those of its second: the correlation of their two images, each
    warped to ``t_ref_us`` by the flow at its events' pixels (nearest pixel, 3x3 box blur).
    Where the flow follows the motion both halves show the same edges; a flow far from it
    (a window the scene crossed, noise) leaves them unrelated. NaN when undefined.

    Examples
    --------
    A vertical bar moving right at 400 px/s for 50 ms: the right flow carries the first
    half onto the second, no flow does not.

    >>> t = np.arange(0, 50_000, 10)
    >>> bar = EventArray(x=np.round(10 + 400e-6 * t), y=t % 40, t=t, p=np.ones(t.size),
    ...                  sensor_size=(40, 60))
    >>> right = np.broadcast_to(np.float32([400.0, 0.0]), (40, 60, 2))
    >>> [round(halves_consistency(bar, f, 25_000), 1) for f in (right, 0 * right)]
    [1.0, 0.0]
    """
    x, y, f = _flow_at_events(events, flow)
    return halves_correlation(x, y, events.t, f, t_ref_us, events.sensor_size)


def box_offsets(width: int, radius: int = 1) -> np.ndarray:
    """The offsets of a square box of ``2 radius + 1`` px on a row-major grid ``width``
    wide (a flat index's neighbours, itself included).

    Examples
    --------
    >>> box_offsets(10).tolist()
    [-11, -10, -9, -1, 0, 1, 9, 10, 11]
    """
    r = np.arange(-int(radius), int(radius) + 1)
    return (r[:, None] * int(width) + r).ravel()


def framed_landing(x: np.ndarray, y: np.ndarray, t: np.ndarray, f: np.ndarray,
                   t_ref_us: int, shape: tuple[int, int], frame: int = 1
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Where events at pixels ``x, y``, times ``t`` (µs), moved by flows ``f`` (N, 2)
    px/s to ``t_ref_us``, land (nearest pixel): their flat indices on the sensor's grid
    with a frame of ``frame`` px (``(H + 2 frame) x (W + 2 frame)``, so that a box of that
    radius around any of them, :func:`box_offsets`, stays on it; 0 for those off the
    sensor) and whether each landed on the sensor.

    Examples
    --------
    >>> framed, inside = framed_landing(np.array([1, 2]), np.array([0, 0]),
    ...                                np.array([0, 0]), np.full((2, 2), [100.0, 0.0]),
    ...                                10_000, (2, 3))
    >>> framed.tolist(), inside.tolist()  # x 1 -> 2: row 1, column 3 of a 5-wide grid
    ([8, 0], [True, False])
    """
    h, w = shape
    f = np.nan_to_num(np.asarray(f, np.float64))
    dt = (int(t_ref_us) - np.asarray(t, np.int64)) * 1e-6
    xw = np.rint(x + f[:, 0] * dt).astype(np.int64)
    yw = np.rint(y + f[:, 1] * dt).astype(np.int64)
    inside = (xw >= 0) & (xw < w) & (yw >= 0) & (yw < h)
    return np.where(inside, (yw + frame) * (w + 2 * frame) + xw + frame, 0), inside


def halves_correlation(x: np.ndarray, y: np.ndarray, t: np.ndarray, f: np.ndarray,
                       t_ref_us: int, shape: tuple[int, int]) -> float:
    """:func:`halves_consistency` of events at integer pixels ``x, y``, times ``t`` (µs),
    each moved by its own flow ``f`` (N, 2) px/s (a per-event flow), on a sensor of
    ``shape`` (H, W).

    Each event adds one to the 3x3 pixels around where it lands, on the sensor's grid
    with a one-pixel frame that is then left out (the box blur of its half's image,
    scattered rather than convolved: padding and shifting the sensor's whole images nine
    times took 35 ms a window at 1280x720)."""
    h, w = shape
    if len(t) < 2:
        return float("nan")
    t = np.asarray(t, np.int64)
    framed, inside = framed_landing(x, y, t, f, t_ref_us, shape)
    first = (t < (int(t[0]) + int(t[-1])) // 2)[inside]
    framed = framed[inside]
    size = (h + 2) * (w + 2)
    images = []
    for half in (framed[first], framed[~first]):
        img = np.bincount((half[:, None] + box_offsets(w + 2)).ravel(), minlength=size)
        frame = img.reshape(h + 2, w + 2)
        frame[0] = frame[-1] = frame[:, 0] = frame[:, -1] = 0  # off the sensor
        images.append(img)
    a, b = images
    n = float(h * w)
    sa, sb = float(a.sum()), float(b.sum())
    cov = float(a @ b) - sa * sb / n
    var = (float(a @ a) - sa * sa / n) * (float(b @ b) - sb * sb / n)
    return cov / float(np.sqrt(var)) if var > 0 else float("nan")


def warn_inconsistent_halves(corr: float, what: str, stacklevel: int = 3) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when ``corr``
    (:func:`halves_consistency`) is below :data:`MIN_HALVES_CORRELATION`; returns its
    message (else None)."""
    if not corr < MIN_HALVES_CORRELATION:  # NaN: nothing to test
        return None
    warnings.warn(msg := f"no measurement: the {what} does not carry the window's first half "
                  f"onto its second (their warped images correlate {corr:.2f}, threshold "
                  f"{MIN_HALVES_CORRELATION:g}) -- a window too long for its motion (the scene "
                  "crossed the image), noise, or a local optimum; use shorter windows",
                  PoorFitWarning, stacklevel=stacklevel)
    return msg
