"""Regularizer weights derived from the window, not from a data set's name.

The thesis tunes the weight ``lambda`` of (3.6) per data set (Sec. 3.6.1) and names a
scene-independent weight as future work: the data term depends on the scene. With the data
term normalized by its value at the identity warp (``G / G(0)``, see
:mod:`evmotion.methods.egomotion`), what still depends on the window is how much focus a
collapse can buy: the variance of the count image grows at most by the events' *effective
pixel count* ``n_eff = N^2 / sum(n_i^2)`` (:func:`evmotion.methods.diagnostics.effective_pixels`;
``N`` events, ``n_i`` per pixel) when they all land on one pixel. ``n_eff`` grows with the
event count, falls as events pile up on few pixels (long windows, slow motion, small
sensors), and is bounded by the sensor's pixel count. The default weight scales with it:

    ``lambda = LAMBDA_UNIT[regularizer] * n_eff / N_EFF_REF``

with the thesis' ECD weights (divergence 5, deformation 10; RCAD 1, its DSEC value, as the
thesis gives none for ECD) at ``N_EFF_REF = 10,000``: the ECD 30k-event windows cover
6,700-21,000 effective pixels, so they keep weights near the thesis' own; the simulated
forward motion of ``benchmarks/results/collapse.md`` (13,600 events on 240x180,
``n_eff`` 10,400) gets RCAD 1.04, which cures the 4-DOF collapse that the MVSEC weight (0.2)
leaves (``benchmarks/results/collapse_derived.md``). DSEC's 500k-event windows get the
larger weights the thesis found necessary there.

Examples
--------
>>> import numpy as np
>>> x = np.arange(10_000) % 100; y = np.arange(10_000) // 100   # 10,000 distinct pixels
>>> window_weight("divergence", x, y, (100, 100))
5.0
>>> window_weight("divergence+deformation", x, y, (100, 100))
{'divergence': 5.0, 'deformation': 10.0}
"""

from __future__ import annotations

from evmotion.errors import ParameterError
from evmotion.methods.diagnostics import effective_pixels

__all__ = ["LAMBDA_UNIT", "N_EFF_REF", "window_weight"]

#: Weight per regularizer at ``n_eff = N_EFF_REF`` (the thesis' ECD set, Sec. 3.6.1).
LAMBDA_UNIT: dict[str, float] = {"divergence": 5.0, "deformation": 10.0, "rcad": 1.0}

#: Effective pixel count at which :data:`LAMBDA_UNIT` applies.
N_EFF_REF = 10_000.0

_COMBINED = {"divergence+deformation": ("divergence", "deformation")}


def window_weight(regularizer: str | None, x, y, shape) -> float | dict[str, float]:
    """Default ``lambda`` of ``regularizer`` for the window of events at ``x, y``.

    Parameters
    ----------
    regularizer : str or None
        ``"divergence"``, ``"deformation"``, ``"rcad"``, ``"divergence+deformation"``
        (one weight per term); None or ``"whitening"`` take no weight (0.0).
    x, y : array (N,)
        Event pixels of the window.
    shape : (int, int)
        ``(H, W)`` of the sensor.

    Returns
    -------
    float, or dict of float per term for ``"divergence+deformation"``.
    """
    if regularizer in (None, "whitening"):
        return 0.0
    names = _COMBINED.get(regularizer, (regularizer,))
    if any(n not in LAMBDA_UNIT for n in names):
        raise ParameterError(f"unknown regularizer '{regularizer}'; choose one of "
                             f"{sorted(LAMBDA_UNIT) + sorted(_COMBINED)}")
    scale = effective_pixels(x, y, shape) / N_EFF_REF
    lams = {n: float(LAMBDA_UNIT[n] * scale) for n in names}
    return lams if regularizer in _COMBINED else lams[regularizer]
