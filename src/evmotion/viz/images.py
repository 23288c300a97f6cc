"""Event pictures and PNG output: histograms, IWE images, flow images with a legend, panels.

Figures are drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas directly, never
through ``pyplot``, so nothing leaks into (or depends on) matplotlib's global state.
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence

import numpy as np

from evmotion.errors import ParameterError
from evmotion.events import EventArray
from evmotion.utils import atomic_path
from evmotion.viz.colorwheel import colorwheel_image, flow_max_magnitude, flow_to_rgb

__all__ = [
    "event_histogram",
    "flow_figure",
    "iwe_to_rgb",
    "read_png",
    "save_flow_png",
    "save_flow_summary",
    "save_panel",
    "save_png",
]


def event_histogram(events: EventArray, *, signed: bool = False,
                    shape: tuple[int, int] | None = None) -> np.ndarray:
    """Events per pixel (the IWE of the identity warp with nearest-pixel voting).

    Parameters
    ----------
    events : EventArray
        Sub-pixel coordinates are rounded; events off the image are dropped.
    signed : bool
        Sum polarities (+1/-1) instead of counting.
    shape : (int, int), optional
        ``(height, width)``; default ``events.sensor_size``.

    Returns
    -------
    ndarray of float32, shape (H, W)

    Examples
    --------
    >>> ev = EventArray(x=[0, 0, 2], y=[1, 1, 0], t=[0, 1, 2], p=[1, 0, 1], sensor_size=(2, 3))
    >>> event_histogram(ev).tolist()
    [[0.0, 0.0, 1.0], [2.0, 0.0, 0.0]]
    >>> event_histogram(ev, signed=True)[1, 0]
    np.float32(0.0)
    """
    h, w = events.sensor_size if shape is None else (int(shape[0]), int(shape[1]))
    if not len(events):
        return np.zeros((h, w), dtype=np.float32)
    xi = np.rint(events.x).astype(np.int64)
    yi = np.rint(events.y).astype(np.int64)
    inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
    idx = yi[inside] * w + xi[inside]
    weights = events.polarity[inside] if signed else None
    hist = np.bincount(idx, weights=weights, minlength=h * w)
    return hist.reshape(h, w).astype(np.float32)


def iwe_to_rgb(iwe: np.ndarray, polarity: bool = False, *, percentile: float = 99.0,
               vmax: float | None = None, invert: bool = True) -> np.ndarray:
    """Render an image of (warped) events.

    Parameters
    ----------
    iwe : ndarray, shape (H, W)
        Event counts (``polarity=False``) or signed polarity sums (``polarity=True``).
    polarity : bool
        False: grayscale, 0 events white and ``vmax`` or more black (``invert=False``
        swaps). True: diverging map, positive red, negative blue, 0 white.
    percentile : float
        Default ``vmax``: this percentile of the nonzero ``|iwe|`` (robust to hot pixels).
    vmax : float, optional
        Value shown at full intensity.
    invert : bool
        For counts: dark events on white (the thesis' figures); False for white on black.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)

    Examples
    --------
    >>> iwe_to_rgb(np.array([[0.0, 2.0]]), vmax=2.0)[0].tolist()
    [[255, 255, 255], [0, 0, 0]]
    >>> iwe_to_rgb(np.array([[1.0, -1.0]]), polarity=True, vmax=1.0)[0].tolist()
    [[255, 0, 0], [0, 0, 255]]
    """
    iwe = np.asarray(iwe, dtype=np.float64)
    if iwe.ndim != 2:
        raise ParameterError(f"iwe must be 2-D (H, W), got shape {iwe.shape}")
    iwe = np.where(np.isfinite(iwe), iwe, 0.0)
    if vmax is None:
        nz = np.abs(iwe[iwe != 0])
        vmax = float(np.percentile(nz, percentile)) if nz.size else 1.0
    if not vmax > 0:
        vmax = 1.0
    if polarity:
        s = np.clip(iwe / vmax, -1.0, 1.0)
        pos, neg = np.clip(s, 0, 1), np.clip(-s, 0, 1)
        rgb = np.stack([1.0 - neg, 1.0 - pos - neg, 1.0 - pos], axis=-1)
    else:
        g = np.clip(np.abs(iwe) / vmax, 0.0, 1.0)
        g = 1.0 - g if invert else g
        rgb = np.repeat(g[..., None], 3, axis=-1)
    return np.round(255.0 * rgb).astype(np.uint8)


def _as_image(img: np.ndarray, what: str) -> np.ndarray:
    img = np.asarray(img)
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    if img.dtype != np.uint8:
        raise ParameterError(
            f"{what} must be uint8 (use iwe_to_rgb / flow_to_rgb first), got dtype {img.dtype}"
        )
    if img.ndim == 3 and img.shape[-1] == 1:
        img = img[..., 0]
    if not (img.ndim == 2 or (img.ndim == 3 and img.shape[-1] in (3, 4))):
        raise ParameterError(f"{what} must be (H, W), (H, W, 3) or (H, W, 4), got {img.shape}")
    if img.shape[0] == 0 or img.shape[1] == 0:
        raise ParameterError(f"{what} is empty (shape {img.shape})")
    return np.ascontiguousarray(img)


def save_png(path: str | os.PathLike, rgb: np.ndarray) -> None:
    """Write a uint8 image (gray, RGB or RGBA) as PNG, atomically.

    Examples
    --------
    >>> save_png("iwe.png", iwe_to_rgb(np.eye(4)))  # doctest: +SKIP
    """
    import png

    img = _as_image(rgb, "image")
    h, w = img.shape[:2]
    planes = 1 if img.ndim == 2 else img.shape[-1]
    writer = png.Writer(width=w, height=h, greyscale=planes == 1, alpha=planes == 4,
                        bitdepth=8, compression=6)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        writer.write(fh, img.reshape(h, w * planes))


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read an 8-bit PNG into uint8 (H, W) or (H, W, C) (used to check outputs)."""
    import png

    w, h, rows, info = png.Reader(filename=os.fspath(path)).asDirect()
    planes = info["planes"]
    arr = np.vstack([np.asarray(r, dtype=np.uint16) for r in rows])
    if info["bitdepth"] > 8:
        arr = arr >> (info["bitdepth"] - 8)
    arr = arr.astype(np.uint8).reshape(h, w, planes)
    return arr[..., 0] if planes == 1 else arr


def _figure(figsize: tuple[float, float], dpi: int):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def _save_figure(fig, path: str | os.PathLike, dpi: int) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.getvalue())


def flow_figure(flow: np.ndarray, *, max_magnitude: float | None = None,
                mask: np.ndarray | None = None, unit: str = "px/s", title: str | None = None,
                dpi: int = 100):
    """A matplotlib Figure (Agg) of a colour-coded flow with its colour-wheel legend.

    The legend's rim is labelled with ``max_magnitude`` in ``unit``.
    """
    if max_magnitude is None:
        max_magnitude = flow_max_magnitude(np.asarray(flow), mask)
    rgb = flow_to_rgb(flow, max_magnitude, mask)
    h, w = rgb.shape[:2]
    scale = 6.0 / max(h, w)
    fig = _figure((w * scale + 2.0, h * scale + 0.6), dpi)
    ax = fig.add_axes((0.02, 0.03, 0.74, 0.88))
    ax.imshow(rgb, interpolation="nearest")
    ax.set_axis_off()
    if title:
        ax.set_title(title)
    leg = fig.add_axes((0.79, 0.35, 0.19, 0.4))
    leg.imshow(colorwheel_image(129), extent=(-1, 1, 1, -1))
    leg.set_xticks([-1, 0, 1])
    leg.set_yticks([-1, 0, 1])
    leg.set_xticklabels([f"{-max_magnitude:.3g}", "0", f"{max_magnitude:.3g}"], fontsize=7)
    leg.set_yticklabels([f"{-max_magnitude:.3g}", "0", f"{max_magnitude:.3g}"], fontsize=7)
    leg.set_xlabel(f"u [{unit}]", fontsize=8)
    leg.set_ylabel(f"v [{unit}]", fontsize=8)
    return fig


def save_flow_png(path: str | os.PathLike, flow: np.ndarray, *,
                  max_magnitude: float | None = None, mask: np.ndarray | None = None,
                  unit: str = "px/s", legend: bool = True, title: str | None = None) -> None:
    """Save a colour-coded flow as PNG, with a colour-wheel legend (scale in ``unit``).

    With ``legend=False`` the PNG is the bare :func:`flow_to_rgb` image, pixel for pixel.

    Examples
    --------
    >>> save_flow_png("flow.png", np.zeros((8, 8, 2)), unit="px")  # doctest: +SKIP
    """
    if not legend:
        save_png(path, flow_to_rgb(flow, max_magnitude, mask))
        return
    fig = flow_figure(flow, max_magnitude=max_magnitude, mask=mask, unit=unit, title=title)
    _save_figure(fig, path, fig.dpi)


def save_panel(path: str | os.PathLike, images: Sequence[np.ndarray],
               titles: Sequence[str] | None = None, *, ncols: int | None = None,
               suptitle: str | None = None, panel_inches: float = 3.0, dpi: int = 100) -> None:
    """Save images side by side (a grid of ``ncols`` columns) as one PNG, atomically.

    Parameters
    ----------
    images : sequence of ndarray
        uint8 (H, W, 3) RGB images, or 2-D arrays shown in grayscale.
    titles : sequence of str, optional
        One per image.
    ncols : int, optional
        Columns of the grid (default: all images in one row).

    Examples
    --------
    >>> save_panel("panel.png", [iwe_to_rgb(a), flow_to_rgb(f)], ["IWE", "flow"])  # doctest: +SKIP
    """
    images = list(images)
    if not images:
        raise ParameterError("save_panel needs at least one image")
    if titles is not None and len(titles) != len(images):
        raise ParameterError(f"{len(titles)} titles for {len(images)} images")
    n = len(images)
    ncols = n if ncols is None else max(1, min(int(ncols), n))
    nrows = -(-n // ncols)
    aspect = max(np.asarray(im).shape[0] / max(np.asarray(im).shape[1], 1) for im in images)
    fig = _figure((panel_inches * ncols, panel_inches * aspect * nrows + 0.5 * nrows
                   + (0.4 if suptitle else 0.0)), dpi)
    for k, im in enumerate(images):
        im = np.asarray(im)
        ax = fig.add_subplot(nrows, ncols, k + 1)
        if im.ndim == 2 and im.dtype != np.uint8:
            ax.imshow(im, cmap="gray", interpolation="nearest")
        else:
            ax.imshow(_as_image(im, f"images[{k}]"), cmap="gray" if im.ndim == 2 else None,
                      vmin=0, vmax=255, interpolation="nearest")
        ax.set_axis_off()
        if titles is not None:
            ax.set_title(str(titles[k]), fontsize=10)
    if suptitle:
        fig.suptitle(suptitle)
    fig.tight_layout()
    _save_figure(fig, path, dpi)


def save_flow_summary(path: str | os.PathLike, events: EventArray, flow_px_per_s: np.ndarray,
                      *, t_ref_us: int | None = None, polarity: bool = False,
                      mask: np.ndarray | None = None, max_magnitude: float | None = None,
                      title: str | None = None, dpi: int = 100) -> float:
    """Three panels in one PNG: the events (zero flow), the IWE warped by the flow to
    ``t_ref_us``, and the colour-coded flow with its colour-wheel legend (px/s).

    Parameters
    ----------
    events : EventArray
        Events of the window.
    flow_px_per_s : ndarray, shape (H, W, 2)
        Flow in px/s on the sensor grid.
    t_ref_us : int, optional
        Reference time of the warp in µs (default: first event).
    polarity : bool
        Signed (red/blue) images instead of counts.
    mask : ndarray of bool, optional
        Flow pixels to draw (e.g. ``evmotion.eval.event_mask(events)``).

    Returns
    -------
    float
        The FWL of the flow on these events (shown in the middle panel's title).

    Examples
    --------
    >>> save_flow_summary("w000.png", events, flow)  # doctest: +SKIP
    """
    from evmotion.core.iwe import accumulate
    from evmotion.eval.metrics import fwl, warp_by_flow

    xw, yw = warp_by_flow(events, flow_px_per_s, t_ref_us)
    weights = events.polarity.astype(np.float64) if polarity else None
    x = events.x.astype(np.float64)
    y = events.y.astype(np.float64)
    shape = events.sensor_size
    iwe0 = accumulate(x, y, shape, weights=weights)
    iwe1 = accumulate(xw, yw, shape, weights=weights)
    vmax = float(np.percentile(np.abs(iwe0[iwe0 != 0]), 99.0)) if np.any(iwe0) else 1.0
    value = fwl(events, flow_px_per_s, t_ref_us)
    flow = np.asarray(flow_px_per_s)
    if max_magnitude is None:
        max_magnitude = flow_max_magnitude(flow, mask)
    h, w = shape
    panel = 3.2
    fig = _figure((3 * panel + 1.2, panel * h / w + 0.8 + (0.3 if title else 0.0)), dpi)
    axes = [fig.add_axes((0.01 + k * 0.305, 0.05, 0.29, 0.8)) for k in range(3)]
    axes[0].imshow(iwe_to_rgb(iwe0, polarity, vmax=vmax), interpolation="nearest")
    axes[0].set_title("events (zero flow)", fontsize=9)
    axes[1].imshow(iwe_to_rgb(iwe1, polarity, vmax=vmax), interpolation="nearest")
    axes[1].set_title(f"IWE with flow (FWL {value:.3f})", fontsize=9)
    axes[2].imshow(flow_to_rgb(flow, max_magnitude, mask), interpolation="nearest")
    axes[2].set_title("flow", fontsize=9)
    for ax in axes:
        ax.set_axis_off()
    leg = fig.add_axes((0.925, 0.35, 0.07, 0.3))
    leg.imshow(colorwheel_image(65))
    leg.set_axis_off()
    leg.set_title(f"{max_magnitude:.3g}\npx/s", fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    _save_figure(fig, path, dpi)
    return value
