"""Whether an estimate measures anything: the light checks every method runs on its result
(contrast gain, event count), apart from :mod:`evmotion.methods.diagnostics`, whose collapse
and fit tests need the warps (imported by it, not by a network's or a flow's start-up)."""

from __future__ import annotations

import warnings

from evmotion.errors import PoorFitWarning

__all__ = ["MIN_CONTRAST_GAIN", "MIN_FIT_EVENTS", "MIN_MOTION_PX", "warn_no_gain",
           "warn_small_motion", "warn_too_few"]

# an estimate whose image of warped events is not this much sharper (variance ratio) than
# the identity warp's measures nothing (a 3.3 ms ECD window: 1.002, its rotation wrong)
MIN_CONTRAST_GAIN = 1.05
#: Fewest events a window needs for its contrast to measure a motion: 20-30 events of a
#: 2 rad/s rotation sharpened by 6-10 % at random parameters (2026-11-29).
MIN_FIT_EVENTS = 100


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


def warn_small_motion(moved_px: float, warp: str, stacklevel: int = 3) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when the estimate moves the
    window's events by less than :data:`MIN_MOTION_PX` (median over the events); returns
    its message (else None)."""
    if not moved_px < MIN_MOTION_PX:
        return None
    msg = (f"small motion: the estimate moves the events by {moved_px:.2g} px over the "
           f"window (median; contrast maximization needs about {MIN_MOTION_PX:g} px or more "
           f"to measure a {warp} motion): not a measurement -- use longer windows")
    warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
    return msg


def warn_too_few(n_events: int, warp: str, stacklevel: int = 3) -> str | None:
    """Issue a :class:`~evmotion.errors.PoorFitWarning` when a window holds fewer than
    :data:`MIN_FIT_EVENTS` events: too few for a contrast to measure a motion (a handful
    of events sharpen by chance); returns its message (else None)."""
    if n_events >= MIN_FIT_EVENTS:
        return None
    msg = (f"too few events: {n_events} (fewer than {MIN_FIT_EVENTS}) cannot measure a "
           f"{warp} motion; the estimate is not a measurement -- use longer windows")
    warnings.warn(msg, PoorFitWarning, stacklevel=stacklevel)
    return msg
