"""Optical flow as colour: the Middlebury colour wheel of Baker et al. (2011).

Hue encodes direction and saturation the magnitude: zero flow is white, flow at
``max_magnitude`` is fully saturated, and longer flow is darkened. With image axes (u to
the right, v down) the cardinal directions are: right red, down yellow-orange, left
cyan-blue, up blue-violet -- the same picture as the Middlebury ``flowToColor`` code.
"""

from __future__ import annotations

import numpy as np

from evmotion.errors import ParameterError
from evmotion.utils import check_number

__all__ = ["GREY", "colorwheel", "colorwheel_image", "flow_max_magnitude", "flow_to_rgb"]

#: RGB of flow pixels without event support (or NaN). No flow colour is grey: every wheel
#: colour keeps one channel at 255 inside the rim and one at 0 beyond it.
GREY = (128, 128, 128)
#: Relative margin of the colour wheel's rim: a few float32 roundings of the flow's magnitude.
RIM_TOLERANCE = 1e-6

# Segment lengths of the wheel (red-yellow, yellow-green, green-cyan, cyan-blue,
# blue-magenta, magenta-red), chosen by Baker et al. for perceptual uniformity.
_SEGMENTS = (("RY", 15), ("YG", 6), ("GC", 4), ("CB", 11), ("BM", 13), ("MR", 6))


def colorwheel() -> np.ndarray:
    """The 55 colours of the Middlebury wheel, float64 in [0, 1], shape (55, 3).

    Examples
    --------
    >>> colorwheel().shape
    (55, 3)
    """
    rows = []
    for name, n in _SEGMENTS:
        ramp = np.arange(n) / n
        seg = np.zeros((n, 3))
        if name == "RY":
            seg[:, 0], seg[:, 1] = 1, ramp
        elif name == "YG":
            seg[:, 0], seg[:, 1] = 1 - ramp, 1
        elif name == "GC":
            seg[:, 1], seg[:, 2] = 1, ramp
        elif name == "CB":
            seg[:, 1], seg[:, 2] = 1 - ramp, 1
        elif name == "BM":
            seg[:, 2], seg[:, 0] = 1, ramp
        else:
            seg[:, 2], seg[:, 0] = 1 - ramp, 1
        rows.append(seg)
    return np.concatenate(rows)


def flow_max_magnitude(flow: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Largest finite flow magnitude (over ``mask``), or 1.0 when there is none > 0."""
    # in float64: float32 flows near their range overflowed in hypot (a RuntimeWarning)
    mag = np.hypot(flow[..., 0].astype(np.float64), flow[..., 1].astype(np.float64))
    ok = np.isfinite(mag)
    if mask is not None:
        ok &= mask
    m = float(mag[ok].max()) if ok.any() else 0.0
    return m if m > 0 else 1.0


def flow_to_rgb(
    flow: np.ndarray,
    max_magnitude: float | None = None,
    mask: np.ndarray | None = None,
    *,
    invalid_color: tuple[int, int, int] = GREY,
) -> np.ndarray:
    """Colour-code a flow field with the Middlebury wheel.

    Parameters
    ----------
    flow : ndarray, shape (H, W, 2)
        u (+x right), v (+y down), in any unit (px or px/s).
    max_magnitude : float, optional
        Magnitude shown fully saturated, in the flow's unit. Default: the largest finite
        magnitude over ``mask``. Fix it to compare several images.
    mask : ndarray of bool, shape (H, W), optional
        Pixels to draw (those with event support); the others (and NaN flow) get
        ``invalid_color``.
    invalid_color : (int, int, int)
        RGB of masked-out pixels (default :data:`GREY`).

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)

    Examples
    --------
    >>> f = np.zeros((1, 2, 2), np.float32); f[0, 1, 0] = 1.0
    >>> flow_to_rgb(f, max_magnitude=1.0).tolist()
    [[[255, 255, 255], [255, 0, 0]]]
    """
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[-1] != 2:
        raise ParameterError(f"flow must have shape (H, W, 2), got {flow.shape}")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != flow.shape[:2]:
            raise ParameterError(f"mask has shape {mask.shape}, expected {flow.shape[:2]}")
    if max_magnitude is None:
        max_magnitude = flow_max_magnitude(flow, mask)
    else:
        max_magnitude = check_number("max_magnitude", max_magnitude, 0.0, lo_open=True)
    u = flow[..., 0].astype(np.float64)
    v = flow[..., 1].astype(np.float64)
    valid = np.isfinite(u) & np.isfinite(v)
    if mask is not None:
        valid &= mask
    u = np.where(valid, u, 0.0) / max_magnitude
    v = np.where(valid, v, 0.0) / max_magnitude
    rad = np.hypot(u, v)
    wheel = colorwheel()
    ncols = wheel.shape[0]
    # The wheel starts at red for angle pi of (-u, -v), i.e. for flow pointing right. It
    # spans all ncols colours around the circle (Middlebury's flowToColor scales by ncols - 1,
    # which leaves a seam between the last colour and red along the +u axis).
    a = np.arctan2(-v, -u) / np.pi
    fk = (a + 1.0) / 2.0 * ncols
    k0 = np.floor(fk).astype(np.int64) % ncols
    k1 = (k0 + 1) % ncols
    frac = (fk - np.floor(fk))[..., None]
    col = (1 - frac) * wheel[k0] + frac * wheel[k1]
    # the rim with a float32 tolerance: the default max_magnitude, the largest |flow| of
    # a float32 flow, put its own pixels just beyond it (drawn dimmed, probe AU)
    inside = (rad <= 1.0 + RIM_TOLERANCE)[..., None]
    rad = np.minimum(rad, 1.0)
    col = np.where(inside, 1.0 - rad[..., None] * (1.0 - col), col * 0.75)
    rgb = np.round(255.0 * col).astype(np.uint8)
    rgb[~valid] = np.asarray(invalid_color, dtype=np.uint8)
    return rgb


def colorwheel_image(size: int = 129, *, background: tuple[int, int, int] = (255, 255, 255),
                     ) -> np.ndarray:
    """The colour wheel as an image (the legend): the rim shows magnitude ``max_magnitude``.

    Parameters
    ----------
    size : int
        Side in pixels (odd sizes put the zero flow on a pixel centre).
    background : (int, int, int)
        RGB outside the disc.

    Returns
    -------
    ndarray of uint8, shape (size, size, 3)

    Examples
    --------
    >>> colorwheel_image(5)[2, 2].tolist()
    [255, 255, 255]
    """
    if size < 3:
        raise ParameterError(f"size must be >= 3 px, got {size}")
    c = (size - 1) / 2.0
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    flow = np.stack([(xx - c) / c, (yy - c) / c], axis=-1)
    disc = np.hypot(flow[..., 0], flow[..., 1]) <= 1.0
    return flow_to_rgb(flow, 1.0, mask=disc, invalid_color=background)
