"""Time to contact from the expansion parameter of a collapse-enabled warp (Sec. 3.6.7).

For a camera moving along its optical axis with speed ``v_z`` towards a scene at the
(dominant) depth ``Z``, the motion field is ``v(x) = (v_z / Z) x`` (3.29) and the zoom warp's
parameter is ``h_z = v_z / Z`` (3.31): the inverse of the time to contact.

Here ``h_z`` is a rate in 1/s (the warps take time in seconds); the thesis' (3.7) value
for a window of ``T`` seconds is ``b_z = h_z T``. For warps other than the zoom the
expansion rate is half the divergence of the image velocity field at the image centre at
the reference time (``Warp.rcad`` there), which is ``h_z`` for the zoom and the in-plane
warp (with no rotation), ``s`` for the similarity and ``(g11 + g22) / 2`` for the affine
warp; translations, SE(2) and rotations, which never approach anything, are refused.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from evmotion.core.warps import Warp
from evmotion.errors import ParameterError
from evmotion.utils import is_finite_number

__all__ = ["NO_EXPANSION", "TimeToContact", "depth_from_ttc", "speed_from_ttc",
           "time_to_contact"]

#: Warps whose motion has no expansion term (their expansion rate is 0 by construction).
NO_EXPANSION = ("translation", "se2", "rotation")


@dataclass(frozen=True)
class TimeToContact:
    """Result of :func:`time_to_contact` (scalars, or arrays (M,) for M windows).

    Attributes
    ----------
    ttc_s : float or ndarray
        Time to contact in seconds, ``1 / expansion_rate``; negative when the scene recedes,
        ``inf`` when the rate is 0.
    expansion_rate : float or ndarray
        ``h_z = v_z / Z`` in 1/s (3.31).
    h_z_normalized : float or ndarray
        The thesis' per-window parameter of (3.7), ``expansion_rate * window_s``.
    approaching : bool or ndarray
        ``expansion_rate > 0``.
    """

    ttc_s: float | np.ndarray
    expansion_rate: float | np.ndarray
    h_z_normalized: float | np.ndarray
    approaching: bool | np.ndarray


def _expansion_rate(warp: Warp, theta: np.ndarray) -> float:
    if warp.name == "zoom":
        return float(theta[0])
    cx, cy = warp.center
    x = np.array([cx], dtype=np.float64)
    y = np.array([cy], dtype=np.float64)
    return 0.5 * float(warp.rcad(x, y, np.zeros(1), theta)[0])


def time_to_contact(params, warp: Warp, window_s: float) -> TimeToContact:
    """Time to contact from a warp's parameters (3.31).

    Parameters
    ----------
    params : array (P,) or (M, P)
        Warp parameters (rates per second, as :func:`evmotion.core.warps.make_warp` uses),
        one row per window.
    warp : Warp
        The warp the parameters belong to.
    window_s : float
        Window duration in seconds (used for the thesis' normalized ``h_z``).

    Returns
    -------
    TimeToContact

    Examples
    --------
    >>> from evmotion.core.warps import make_warp
    >>> r = time_to_contact(np.array([0.5]), make_warp("zoom", (260, 346)), 0.05)
    >>> r.ttc_s, r.h_z_normalized
    (2.0, 0.025)
    """
    if isinstance(warp, str):
        # what EgomotionResult.warp holds (probe BY: the docs' "estimate, then convert"
        # ended here with no word of how)
        raise ParameterError(f"warp must be a Warp, got the name {warp!r} (an "
                             "EgomotionResult's .warp is its name): give "
                             f"evmotion.core.warps.make_warp({warp!r}, events.sensor_size)")
    if not isinstance(warp, Warp):
        raise ParameterError(f"warp must be a Warp (evmotion.core.warps.make_warp(name, "
                             f"sensor_size)), got {warp!r}")
    if warp.name in NO_EXPANSION:
        raise ParameterError(f"the {warp.name} warp cannot expand the image, so it measures "
                             "no time to contact (it would always be infinite): use zoom, "
                             "inplane, similarity, affine or homography")
    if not (is_finite_number(window_s) and window_s > 0):
        raise ParameterError(f"window_s must be a positive number of seconds, got {window_s!r}")
    p = np.asarray(params, dtype=np.float64)
    single = p.ndim == 1
    p2 = np.atleast_2d(p)
    if p2.ndim != 2 or p2.shape[1] != warp.n_params:
        raise ParameterError(f"params for warp '{warp.name}' must have shape ({warp.n_params},) "
                             f"or (M, {warp.n_params}), got {p.shape}")
    if not np.all(np.isfinite(p2)):
        raise ParameterError(f"params must be finite, got {p!r}")
    rate = np.array([_expansion_rate(warp, th) for th in p2])
    with np.errstate(divide="ignore"):
        ttc = np.where(rate != 0, 1.0 / np.where(rate != 0, rate, 1.0), np.inf)
    norm = rate * float(window_s)
    if single:
        return TimeToContact(float(ttc[0]), float(rate[0]), float(norm[0]), bool(rate[0] > 0))
    return TimeToContact(ttc, rate, norm, rate > 0)


def depth_from_ttc(ttc_s, speed_mps):
    """Scene depth ``Z = v_z * TTC`` in metres from the speed along the optical axis (3.31).

    >>> depth_from_ttc(2.0, 10.0)
    20.0
    """
    if np.ndim(ttc_s) or np.ndim(speed_mps):
        return np.asarray(ttc_s, dtype=np.float64) * np.asarray(speed_mps, dtype=np.float64)
    return float(ttc_s) * float(speed_mps)


def speed_from_ttc(ttc_s, depth_m):
    """Speed along the optical axis ``v_z = Z / TTC`` in m/s from the scene depth (3.31).

    >>> speed_from_ttc(2.0, 20.0)
    10.0
    """
    if np.ndim(ttc_s) or np.ndim(depth_m):
        return np.asarray(depth_m, dtype=np.float64) / np.asarray(ttc_s, dtype=np.float64)
    return float(depth_m) / float(ttc_s)
