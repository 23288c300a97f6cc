"""Event pictures and PNG output: histograms, IWE images, flow images with a legend, panels.

Figures are drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas directly, never
through ``pyplot``, so nothing leaks into (or depends on) matplotlib's global state.
"""

from __future__ import annotations

import io
import os
import textwrap
from collections.abc import Sequence

import numpy as np

from evmotion.errors import ParameterError
from evmotion.events import EventArray
from evmotion.io import pngfile
from evmotion.utils import atomic_write_bytes, check_number, whole_number
from evmotion.viz.flowpic import FlowPicture, flow_panel, flow_picture
from evmotion.viz.titles import wrap_title

__all__ = [
    "event_histogram",
    "event_picture_png",
    "iwe_to_rgb",
    "panel_png",
    "full_scale",
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
    if shape is None:
        h, w = events.sensor_size
    else:
        h = whole_number("shape[0] (height)", shape[0], lo=1)
        w = whole_number("shape[1] (width)", shape[1], lo=1)
        if (w, h) == tuple(events.sensor_size) and h != w:
            # (a (W, H) dropped the events past the swapped border without a word, probe CB)
            raise ParameterError(f"shape {tuple(shape)} is the events' sensor_size "
                                 f"{tuple(events.sensor_size)} swapped: shape is (height, "
                                 "width)")
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
    _check_percentile(percentile)
    if vmax is None:
        vmax = full_scale(iwe, percentile)
        if not vmax > 0:  # an empty image
            vmax = 1.0
    else:
        vmax = check_number("vmax", vmax, 0.0, lo_open=True, units="events / px")
    if polarity:
        s = np.clip(iwe / vmax, -1.0, 1.0)
        pos, neg = np.clip(s, 0, 1), np.clip(-s, 0, 1)
        rgb = np.stack([1.0 - neg, 1.0 - pos - neg, 1.0 - pos], axis=-1)
    else:
        g = np.clip(np.abs(iwe) / vmax, 0.0, 1.0)
        g = 1.0 - g if invert else g
        rgb = np.repeat(g[..., None], 3, axis=-1)
    return np.round(255.0 * rgb).astype(np.uint8)


def _check_percentile(percentile) -> None:
    if not (isinstance(percentile, (int, float, np.number)) and 0 <= percentile <= 100):
        raise ParameterError(f"percentile must be in [0, 100], got {percentile!r}")


def full_scale(iwe: np.ndarray, percentile: float = 99.0) -> float:
    """The value :func:`iwe_to_rgb` shows at full intensity by default: ``percentile`` of
    the nonzero ``|iwe|`` (1 for an empty image); give it as ``vmax`` to draw several
    images on one scale, and state it in their titles.

    Examples
    --------
    >>> full_scale(np.array([[0.0, 2.0], [4.0, 0.0]]), 100)
    4.0
    """
    _check_percentile(percentile)
    nz = np.abs(iwe[iwe != 0])
    return float(np.percentile(nz, percentile)) if nz.size else 1.0


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
    >>> save_png("iwe.png", iwe_to_rgb(np.eye(4)))
    >>> read_png("iwe.png").shape
    (4, 4, 3)
    """
    pngfile.write_png(path, _as_image(rgb, "image"), compression=6)


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read an 8-bit PNG into uint8 (H, W) or (H, W, C) (used to check outputs)."""
    arr, info = pngfile.read_png(path)
    if info["bitdepth"] > 8:
        arr = arr >> (info["bitdepth"] - 8)
    arr = arr.astype(np.uint8)
    return arr[..., 0] if info["planes"] == 1 else arr


def _figure(figsize: tuple[float, float], dpi: int):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def _figure_png(fig, dpi: int) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _save_figure(fig, path: str | os.PathLike, dpi: int) -> None:
    atomic_write_bytes(path, _figure_png(fig, dpi))


def save_flow_png(path: str | os.PathLike, flow: np.ndarray, *,
                  max_speed: float | None = None, valid: np.ndarray | None = None,
                  unit: str = "px/s", legend: bool = True, title: str | None = None,
                  ) -> FlowPicture:
    """Save a colour-coded flow as PNG beside its legend (wheel, u/v arrows, rim speed).

    Parameters
    ----------
    flow : ndarray, shape (H, W, 2)
        Flow in px/s (or ``unit``).
    max_speed : float, optional
        Speed at the wheel's rim, in ``unit``; fix it to compare the pictures of a sequence
        (default: the largest valid speed of this flow, said so in the legend).
    valid : ndarray of bool, shape (H, W), optional
        Pixels with event support; the others are grey.
    legend : bool
        False: the bare :func:`flow_to_rgb` image (invalid pixels grey), pixel for pixel.
    title : str, optional
        A line of text above the picture.

    Returns
    -------
    FlowPicture
        What was drawn (scale, legend position, texts), without the title line.

    Examples
    --------
    >>> pic = save_flow_png("flow.png", np.zeros((8, 8, 2)), max_speed=100.0)
    >>> read_png("flow.png").shape[2]
    3
    """
    pic = flow_picture(flow, max_speed=max_speed, valid=valid, unit=unit, legend=legend)
    rgb = pic.rgb
    if title:
        rgb = np.concatenate([_title_row(rgb.shape[1], title), rgb], axis=0)
    save_png(path, rgb)
    return pic


def _title_row(width: int, title: str) -> np.ndarray:
    # wrapped to the picture's width: a long title was cut at both ends (a window with no
    # valid pixel says so after its times, probe BK); ~7.5 px a 10-pt character
    lines = wrap_title(title, width, 7.5) or [title]
    fig = _figure((width / 100.0, 0.06 + 0.18 * len(lines)), 100)
    fig.set_facecolor("white")
    fig.text(0.5, 0.5, "\n".join(lines), fontsize=10, va="center", ha="center",
             linespacing=1.1)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def panel_width_inches(width_px: int, dpi: int = 100) -> float:
    """Default width of one panel of :func:`panel_png` for images ``width_px`` wide: 3 in,
    or half their width in pixels where that is more (a 1280-px IWE squeezed into 300 px
    no longer shows whether the events are sharp).

    Examples
    --------
    >>> panel_width_inches(346), panel_width_inches(1280)
    (3.0, 6.4)
    """
    return max(3.0, float(width_px) / 2 / dpi)


def save_panel(path: str | os.PathLike, images: Sequence[np.ndarray],
               titles: Sequence[str] | None = None, *, ncols: int | None = None,
               suptitle: str | None = None, panel_inches: float | None = None,
               dpi: int = 100) -> None:
    """Save images side by side (a grid of ``ncols`` columns) as one PNG, atomically
    (:func:`panel_png`'s bytes).

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
    >>> from evmotion.viz import flow_to_rgb
    >>> a, f = np.eye(16), np.ones((16, 16, 2))
    >>> save_panel("panel.png", [iwe_to_rgb(a), flow_to_rgb(f)], ["IWE", "flow"])
    >>> read_png("panel.png").ndim
    3
    """
    atomic_write_bytes(path, panel_png(images, titles, ncols=ncols, suptitle=suptitle,
                                       panel_inches=panel_inches, dpi=dpi))


def event_picture_png(image: np.ndarray, *, polarity: bool = False, percentile: float = 99.0,
                      title: str = "", scale: int = 1, dpi: int = 100,
                      vmax: float | None = None) -> bytes:
    """An image of events (counts, or signed polarity sums with ``polarity``) as a PNG
    with its colour bar (events per pixel), pixel axes and ``title``: :func:`iwe_to_rgb`'s
    colours, each pixel ``scale`` screen pixels wide; full scale at ``vmax`` (default the
    ``percentile`` of the image: give one ``vmax`` to pictures compared side by side).

    Examples
    --------
    >>> event_picture_png(np.eye(8), title="8 events")[1:4]
    b'PNG'
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import LinearSegmentedColormap, Normalize

    image = np.asarray(image, dtype=np.float64)
    if vmax is None:
        vmax = full_scale(np.where(np.isfinite(image), image, 0.0), percentile)
    vmax = vmax if vmax > 0 else 1.0
    rgb = iwe_to_rgb(image, polarity, vmax=vmax)
    if polarity:
        cmap = LinearSegmentedColormap.from_list("evmotion_polarity", ["blue", "white", "red"])
        norm, label = Normalize(-vmax, vmax), "polarity sum per pixel (+ red, - blue)"
    else:
        cmap = LinearSegmentedColormap.from_list("evmotion_counts", ["white", "black"])
        norm, label = Normalize(0.0, vmax), "events per pixel"
    h, w = image.shape
    width_in = max(3.0, w * max(int(scale), 1) / dpi)
    # a title wider than a small sensor's figure was cut at both sides: wrapped to it
    lines = wrap_title(title, width_in + 1.4, 1 / 12)
    fig = _figure((width_in + 1.4, width_in * h / w + 0.9 + 0.16 * max(len(lines) - 1, 0)),
                  dpi)
    ax = fig.add_subplot(1, 1, 1)
    ax.imshow(rgb, interpolation="nearest")
    ax.set_xlabel("x [px]")
    ax.set_ylabel("y [px]")
    if lines:
        ax.set_title("\n".join(lines), fontsize=9)
    bar = fig.colorbar(ScalarMappable(norm, cmap), ax=ax, fraction=0.046, pad=0.03,
                       extend="max" if not polarity else "both")
    bar.set_label(label)
    fig.tight_layout()
    return _figure_png(fig, dpi)


#: Characters of a 10-point panel title per inch of panel width (wider lines wrap).
TITLE_CHARS_PER_INCH = 13


def panel_png(images: Sequence[np.ndarray], titles: Sequence[str] | None = None, *,
              ncols: int | None = None, suptitle: str | None = None,
              panel_inches: float | None = None, dpi: int = 100) -> bytes:
    """The PNG file :func:`save_panel` writes, as bytes: for a worker process that draws
    a picture the caller writes (a Dask worker need not see the output folder).
    ``panel_inches`` (width of a panel) defaults to :func:`panel_width_inches`.

    Examples
    --------
    >>> panel_png([np.eye(8)])[:8] == b"\\x89PNG\\r\\n\\x1a\\n"
    True
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
    if panel_inches is None:
        panel_inches = panel_width_inches(max(np.asarray(im).shape[1] for im in images), dpi)
    extra = 0
    if titles is not None:
        # a title wider than its panel ran into the next one and off the picture
        width = max(16, int(panel_inches * TITLE_CHARS_PER_INCH))
        titles = ["\n".join(textwrap.fill(ln, width) or ln for ln in str(t).splitlines())
                  for t in titles]
        extra = max(len(t.splitlines()) for t in titles) - 1
    fig = _figure((panel_inches * ncols, panel_inches * aspect * nrows
                   + (0.5 + 0.17 * extra) * nrows
                   + (0.4 * len(suptitle.splitlines()) if suptitle else 0.0)), dpi)
    for k, im in enumerate(images):
        im = np.asarray(im)
        # the sensor's first and last pixel as the only ticks: its extent and scale, framed
        # (white images on white lost their edges), without the default tick labels that
        # matplotlib formats and measures in every layout pass (a 2x2 panel of 240x180
        # images: 0.19 s with them, 0.16 s without)
        h, w = im.shape[:2]
        ax = fig.add_subplot(nrows, ncols, k + 1, xticks=[0, w - 1], yticks=[0, h - 1])
        if im.ndim == 2 and im.dtype != np.uint8:
            ax.imshow(im, cmap="gray", interpolation="nearest")
        else:
            ax.imshow(_as_image(im, f"images[{k}]"), cmap="gray" if im.ndim == 2 else None,
                      vmin=0, vmax=255, interpolation="nearest")
        ax.tick_params(labelsize=7, length=2, pad=1)
        # (the ticks' numbers had no unit, probe BX)
        ax.set_xlabel("x [px]", fontsize=7, labelpad=-6)
        ax.set_ylabel("y [px]", fontsize=7, labelpad=-10)
        for spine in ax.spines.values():
            spine.set_color("0.6")
            spine.set_linewidth(0.6)
        if titles is not None:
            ax.set_title(str(titles[k]), fontsize=10)
    if suptitle:
        fig.suptitle(suptitle, fontsize=10 if "\n" in suptitle else None)
    fig.tight_layout()
    return _figure_png(fig, dpi)


def save_flow_summary(path: str | os.PathLike, events: EventArray, flow_px_per_s: np.ndarray,
                      *, t_ref_us: int | None = None, polarity: bool = False,
                      valid: np.ndarray | None = None, max_speed: float | None = None,
                      title: str | None = None) -> float:
    """Save :func:`flow_panel` as PNG: the events (zero flow), the IWE warped by the flow to
    ``t_ref_us``, and the colour-coded flow with its legend (px/s).

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
    valid : ndarray of bool, optional
        Flow pixels with event support (e.g. ``evmotion.eval.event_mask(events)``); the
        others are grey.
    max_speed : float, optional
        Speed at the legend wheel's rim (px/s); fix it across a sequence.
    title : str, optional
        A line above the panels.

    Returns
    -------
    float
        The FWL of the flow on these events (shown in the middle panel's title).

    Examples
    --------
    >>> from evmotion.sim import simulate
    >>> sim = simulate("translation", duration_s=0.02, sensor_size=(40, 60), seed=0,
    ...                show_progress=False)
    >>> flow = sim.gt.flow(int(sim.events.t[0]))   # px/s, (H, W, 2)
    >>> fwl = save_flow_summary("w000.png", sim.events, flow)
    >>> fwl > 1   # the true flow sharpens the events
    True
    """
    rgb, info = flow_panel(events, flow_px_per_s, t_ref_us=t_ref_us, max_speed=max_speed,
                           valid=valid, polarity=polarity, title=title)
    save_png(path, rgb)
    return info["fwl"]
