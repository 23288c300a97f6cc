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
from evmotion.viz.flowpic import FlowPicture, flow_panel, flow_picture, upscale
from evmotion.viz.titles import wrap_title

__all__ = [
    "event_histogram",
    "event_picture_png",
    "iwe_to_rgb",
    "picture_factor",
    "panel_png",
    "full_scale",
    "read_png",
    "save_flow_png",
    "save_flow_summary",
    "save_panel",
    "save_png",
    "title_row",
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
        rgb = np.concatenate([title_row(rgb.shape[1], title), rgb], axis=0)
    save_png(path, rgb)
    return pic


def title_row(width: int, title: str) -> np.ndarray:
    """A white RGB strip ``width`` px wide (uint8, (h, width, 3)) holding ``title`` in 10 pt,
    wrapped to that width, to stack above a picture drawn without matplotlib's axes.

    Examples
    --------
    >>> row = title_row(200, "flow, window 0")
    >>> row.shape[1:], row.dtype.name
    ((200, 3), 'uint8')
    """
    # wrapped to the picture's width: a long title was cut at both ends (a window with no
    # valid pixel says so after its times, probe BK); ~7.5 px a 10-pt character
    lines = wrap_title(title, width, 7.5) or [title]
    fig = _figure((width / 100.0, 0.06 + 0.18 * len(lines)), 100)
    fig.set_facecolor("white")
    fig.text(0.5, 0.5, "\n".join(lines), fontsize=10, va="center", ha="center",
             linespacing=1.1)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


#: Narrowest image (px) of :func:`event_picture_png`: narrower sensors are magnified by a
#: whole number (a 346-px DAVIS twice, a 640-px VGA sensor not).
MIN_PICTURE_PX = 480
#: Narrowest image (px) of a panel of :func:`panel_png`, where several share the picture.
MIN_PANEL_PX = 300
#: Widest image (px) of :func:`event_picture_png`: wider ones are reduced by a whole number.
MAX_PICTURE_PX = 2000
#: Widest row of images (px, margins aside) of :func:`panel_png`.
MAX_PANEL_ROW_PX = 2600


def picture_factor(width_px: int, *, least_px: int = MIN_PICTURE_PX,
                   most_px: int = MAX_PICTURE_PX, scale: int = 1) -> tuple[int, int]:
    """Whole-number magnification and reduction of an image ``width_px`` wide on a picture:
    ``(k, 1)`` draws each image pixel as k x k picture pixels, the least k (at least
    ``scale``) that reaches ``least_px`` without passing ``most_px``; ``(1, r)`` an image
    wider than ``most_px``, r x r image pixels to a picture pixel. A fractional scale had
    merged 79 of a 1280-px sensor's column pairs and doubled about one column in five of a
    240-px one (probe DA).

    Examples
    --------
    >>> picture_factor(240), picture_factor(346), picture_factor(1280), picture_factor(4096)
    ((2, 1), (2, 1), (1, 1), (1, 3))
    """
    w = max(int(width_px), 1)
    scale = max(int(scale), 1)
    if scale == 1 and w > most_px:
        return 1, -(-w // most_px)
    return max(scale, min(-(-int(least_px) // w), max(int(most_px) // w, 1))), 1


def _reduced_values(image: np.ndarray, r: int) -> np.ndarray:
    """Each r x r block's largest-magnitude value (with its sign): a lone event, or one
    hot pixel, stays drawn (a nearest-neighbour reduction drops most of them)."""
    if r == 1:
        return image
    h, w = image.shape
    pad = np.zeros((-(-h // r) * r, -(-w // r) * r), image.dtype)
    pad[:h, :w] = image
    blocks = pad.reshape(pad.shape[0] // r, r, pad.shape[1] // r, r).transpose(0, 2, 1, 3)
    blocks = blocks.reshape(*blocks.shape[:2], r * r)
    pick = np.abs(blocks).argmax(axis=-1)
    return np.take_along_axis(blocks, pick[..., None], axis=-1)[..., 0]


def _reduced_rgb(rgb: np.ndarray, r: int) -> np.ndarray:
    """Each r x r block's pixel farthest from the image's median colour (its background):
    the events, not the white around them, survive the reduction."""
    if r == 1:
        return rgb
    h, w = rgb.shape[:2]
    bg = np.median(rgb.reshape(-1, 3), axis=0).astype(np.uint8)
    pad = np.empty((-(-h // r) * r, -(-w // r) * r, 3), np.uint8)
    pad[...] = bg
    pad[:h, :w] = rgb
    blocks = pad.reshape(pad.shape[0] // r, r, pad.shape[1] // r, r, 3).transpose(0, 2, 1, 3, 4)
    blocks = blocks.reshape(*blocks.shape[:2], r * r, 3)
    far = np.abs(blocks.astype(np.int16) - bg.astype(np.int16)).sum(axis=-1).argmax(axis=-1)
    return np.take_along_axis(blocks, far[..., None, None], axis=2)[:, :, 0]


def _panel_rgb(im: np.ndarray, what: str) -> np.ndarray:
    """An image of :func:`panel_png` as uint8 RGB, as ``imshow`` had drawn it: a 2-D
    non-uint8 array grey from its minimum to its maximum (NaN white), 2-D uint8 grey,
    RGBA over white."""
    im = np.asarray(im)
    if im.ndim == 2 and im.dtype not in (np.uint8, bool):
        v = np.asarray(im, dtype=np.float64)
        ok = np.isfinite(v)
        lo, hi = (float(v[ok].min()), float(v[ok].max())) if ok.any() else (0.0, 1.0)
        g = np.where(ok, (v - lo) / (hi - lo) if hi > lo else 0.0, 1.0)
        return np.repeat(np.round(255 * g).astype(np.uint8)[..., None], 3, axis=-1)
    im = _as_image(im, what)
    if im.ndim == 2:
        return np.repeat(im[..., None], 3, axis=-1)
    if im.shape[-1] == 4:
        a = im[..., 3:].astype(np.float64) / 255.0
        return np.round(im[..., :3] * a + 255.0 * (1.0 - a)).astype(np.uint8)
    return im


def _place(fig, ax, left: float, top: float, width: float, height: float) -> None:
    """Put ``ax`` at ``left``, ``top`` (px from the figure's top left), ``width`` x
    ``height`` px."""
    fw, fh = fig.bbox.width, fig.bbox.height
    ax.set_position((left / fw, 1.0 - (top + height) / fh, width / fw, height / fh))


def _overflow(axes, renderer) -> tuple[float, float, float, float]:
    """How far past its box each of ``axes`` draws (ticks, labels, titles, colour bars):
    the most to the left, right, top and bottom, px."""
    out = [0.0, 0.0, 0.0, 0.0]
    for ax in axes:
        box = ax.get_window_extent(renderer)
        tight = ax.get_tightbbox(renderer)
        for i, d in enumerate((box.x0 - tight.x0, tight.x1 - box.x1, tight.y1 - box.y1,
                               box.y0 - tight.y0)):
            out[i] = max(out[i], d)
    return tuple(float(np.ceil(v)) for v in out)


def _picture_png(fig, pastes, dpi: int) -> bytes:
    """Draw ``fig`` and write each ``(ax, rgb)`` of ``pastes`` into its axes' box, one
    pixel inside the frame, pixel for pixel (matplotlib's own resampling of an image into
    a box of a fractional size merged and doubled columns, probe DA); PNG bytes."""
    from PIL import Image

    fig.canvas.draw()
    buf = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    for ax, rgb in pastes:
        box = ax.get_window_extent()
        col, row = int(round(box.x0)) + 1, buf.shape[0] - int(round(box.y1)) + 1
        buf[row:row + rgb.shape[0], col:col + rgb.shape[1]] = rgb
    out = io.BytesIO()
    Image.fromarray(buf).save(out, format="png", dpi=(dpi, dpi))
    return out.getvalue()


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
    colours, full scale at ``vmax`` (default the ``percentile`` of the image: give one
    ``vmax`` to pictures compared side by side).

    Each sensor pixel is k x k picture pixels, k a whole number (:func:`picture_factor`:
    at least ``scale``, 2 for 240 to 346 px, 1 from 480 px); a sensor wider than
    :data:`MAX_PICTURE_PX` is reduced r x r pixels to one, each block drawn as its largest
    value, so no event vanishes (the colour bar says so).

    Examples
    --------
    >>> event_picture_png(np.eye(8), title="8 events")[1:4]
    b'PNG'
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import LinearSegmentedColormap, Normalize
    from matplotlib.transforms import Bbox

    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 2 or not min(image.shape) > 0:
        raise ParameterError(f"image must be 2-D (H, W), got shape {image.shape}")
    image = np.where(np.isfinite(image), image, 0.0)
    if vmax is None:
        vmax = full_scale(image, percentile)
    vmax = vmax if vmax > 0 else 1.0
    h, w = image.shape
    # the longer side: a (720, 3) image magnified to 480 px wide was 115,276 px tall
    # (review DR)
    k, r = picture_factor(max(h, w), scale=scale)
    rgb = upscale(iwe_to_rgb(_reduced_values(image, r), polarity, vmax=vmax), k)
    if polarity:
        cmap = LinearSegmentedColormap.from_list("evmotion_polarity", ["blue", "white", "red"])
        norm, label = Normalize(-vmax, vmax), "polarity sum per pixel (+ red, - blue)"
    else:
        cmap = LinearSegmentedColormap.from_list("evmotion_counts", ["white", "black"])
        norm, label = Normalize(0.0, vmax), "events per pixel"
    if r > 1:
        label += f"\n(largest of each {r} x {r} px block)"
    # the frame round the image: a one-pixel ring, so that it covers no sensor pixel
    bw, bh = rgb.shape[1] + 2, rgb.shape[0] + 2
    px = dpi / 100.0
    # a title wider than a small sensor's figure was cut at both sides: wrapped to it
    lines = wrap_title(title, (bw + 100 * px) / dpi, 1 / 12)
    fig = _figure(((bw + 500 * px) / dpi, (bh + 400 * px) / dpi), dpi)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    cax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    step = r / k  # sensor pixels per picture pixel
    ax.set_xlim(-0.5 - step, -0.5 + (bw - 1) * step)
    ax.set_ylim(-0.5 + (bh - 1) * step, -0.5 - step)
    ax.set_xlabel("x [px]")
    ax.set_ylabel("y [px]")
    if lines:
        ax.set_title("\n".join(lines), fontsize=9)
    extend = "both" if polarity else "max"
    bar = fig.colorbar(ScalarMappable(norm, cmap), cax=cax, extend=extend)
    bar.set_label(label)
    # the colour bar as tall as the image, its extension triangles (5 % of its length
    # each, drawn outside its box) included
    ends = 2 if polarity else 1
    length = bh / (1 + 0.05 * ends)
    gap, bar_w = 12 * px, 18 * px

    def place(left, top):
        _place(fig, ax, left, top, bw, bh)
        _place(fig, cax, left + bw + gap, top + 0.05 * length, bar_w, length)

    place(250 * px, 200 * px)
    renderer = fig.canvas.get_renderer()
    box = ax.get_window_extent(renderer)
    tight = Bbox.union([ax.get_tightbbox(renderer), cax.get_tightbbox(renderer)])
    pad = 6 * px
    left, top = np.ceil(box.x0 - tight.x0 + pad), np.ceil(tight.y1 - box.y1 + pad)
    right, bottom = np.ceil(tight.x1 - box.x1 + pad), np.ceil(box.y0 - tight.y0 + pad)
    fig.set_size_inches((left + bw + right) / dpi, (top + bh + bottom) / dpi)
    place(left, top)
    return _picture_png(fig, [(ax, rgb)], dpi)


#: Characters of a 10-point panel title per inch of panel width (wider lines wrap).
TITLE_CHARS_PER_INCH = 13


def panel_png(images: Sequence[np.ndarray], titles: Sequence[str] | None = None, *,
              ncols: int | None = None, suptitle: str | None = None,
              panel_inches: float | None = None, dpi: int = 100) -> bytes:
    """The PNG file :func:`save_panel` writes, as bytes: for a worker process that draws
    a picture the caller writes (a Dask worker need not see the output folder).

    Each image pixel is k x k picture pixels, k a whole number (:func:`picture_factor`):
    the least that draws the widest image ``panel_inches`` wide (default
    :data:`MIN_PANEL_PX` px), 1 for large sensors; a row of images wider than
    :data:`MAX_PANEL_ROW_PX` is reduced r x r pixels to one, each block drawn as its pixel
    farthest from the image's median colour, so no event vanishes.

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
    rgbs = [_panel_rgb(im, f"images[{i}]") for i, im in enumerate(images)]
    wmax = max(im.shape[1] for im in rgbs)
    hmax = max(im.shape[0] for im in rgbs)
    least = MIN_PANEL_PX if panel_inches is None else max(1, round(panel_inches * dpi))
    k, r = picture_factor(max(wmax * ncols, hmax * nrows), least_px=least * ncols,
                          most_px=MAX_PANEL_ROW_PX)
    shown = [upscale(_reduced_rgb(im, r), k) for im in rgbs]
    # the frame round each image: a one-pixel ring, so that it covers no image pixel
    bw = max(im.shape[1] for im in shown) + 2
    bh = max(im.shape[0] for im in shown) + 2
    px = dpi / 100.0
    if titles is not None:
        # a title wider than its panel ran into the next one and off the picture
        width = max(16, int(bw / dpi * TITLE_CHARS_PER_INCH))
        titles = ["\n".join(textwrap.fill(ln, width) or ln for ln in str(t).splitlines())
                  for t in titles]
    step = r / k  # image pixels per picture pixel
    fig = _figure((ncols * (bw + 300 * px) / dpi, (nrows * (bh + 300 * px) + 300 * px) / dpi),
                  dpi)
    axes = []
    for i, im in enumerate(images):
        h, w = np.asarray(im).shape[:2]
        # the sensor's first and last pixel as the only ticks: its extent and scale, framed
        # (white images on white lost their edges), without the default tick labels that
        # matplotlib formats and measures in every layout pass
        ax = fig.add_axes((0.0, 0.0, 1.0, 1.0), xticks=[0, w - 1], yticks=[0, h - 1])
        ax.set_xlim(-0.5 - step, -0.5 + (shown[i].shape[1] + 1) * step)
        ax.set_ylim(-0.5 + (shown[i].shape[0] + 1) * step, -0.5 - step)
        ax.tick_params(labelsize=7, length=2, pad=1)
        # (the ticks' numbers had no unit, probe BX)
        ax.set_xlabel("x [px]", fontsize=7, labelpad=-6)
        ax.set_ylabel("y [px]", fontsize=7, labelpad=-10)
        for spine in ax.spines.values():
            spine.set_color("0.6")
            spine.set_linewidth(0.6)
        if titles is not None:
            ax.set_title(str(titles[i]), fontsize=10)
        axes.append(ax)
    sup = None
    if suptitle:
        sup = fig.text(0.5, 1.0, suptitle, ha="center", va="top",
                       fontsize=10 if "\n" in suptitle else 12)

    def place(left, top, cell_w, cell_h):
        for i, ax in enumerate(axes):
            row, col = divmod(i, ncols)
            ih, iw = shown[i].shape[:2]
            # a smaller image centred in its cell
            _place(fig, ax, left + col * cell_w + (bw - 2 - iw) // 2,
                   top + row * cell_h + (bh - 2 - ih) // 2, iw + 2, ih + 2)

    place(150 * px, 300 * px, bw + 300 * px, bh + 300 * px)
    renderer = fig.canvas.get_renderer()
    over_l, over_r, over_t, over_b = _overflow(axes, renderer)
    pad = 6 * px
    cell_w, cell_h = over_l + bw + over_r + pad, over_t + bh + over_b + pad
    sup_w = sup_h = 0.0
    if sup is not None:
        extent = sup.get_window_extent(renderer)
        sup_w, sup_h = np.ceil(extent.width), np.ceil(extent.height) + pad
    width = max(ncols * cell_w + pad, sup_w + 2 * pad)
    height = pad + sup_h + nrows * cell_h
    fig.set_size_inches(width / dpi, height / dpi)
    left = (width - ncols * cell_w + pad) / 2 + over_l
    place(np.floor(left), pad + sup_h + over_t, cell_w, cell_h)
    if sup is not None:
        sup.set_position((0.5, 1.0 - pad / fig.bbox.height))
    return _picture_png(fig, list(zip(axes, shown, strict=True)), dpi)


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
