"""Flow pictures that explain themselves: the colour-coded flow beside a colour-wheel legend
(axis arrows u to the right, v down) that states the speed shown at the wheel's rim and
whether that scale is fixed or chosen for this image, with a ruler of the image's pixels;
pixels without event support in grey;
and the three-panel view (events | IWE warped by the flow | flow) used for summaries and
videos.

Pictures are returned as uint8 RGB arrays; the flow pixels are copied unresampled (an integer
nearest-neighbour upscale for images under :data:`MIN_HEIGHT` rows, so the legend stays
legible). Text is drawn with matplotlib's Agg canvas, never through ``pyplot``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from evmotion.errors import ParameterError
from evmotion.events import EventArray
from evmotion.utils import check_switches
from evmotion.viz.colorwheel import GREY, colorwheel_image, flow_max_magnitude, flow_to_rgb
from evmotion.viz.titles import wrap_title

__all__ = ["MIN_HEIGHT", "FlowPicture", "flow_panel", "flow_picture", "mean_event_flow",
           "picture_row", "sequence_max_speed", "upscale", "upscale_factor"]

#: Pictures with fewer rows are upscaled by an integer factor to at least this height.
MIN_HEIGHT = 160
_GAP = 4  # white columns between panels, px


@dataclass(frozen=True)
class FlowPicture:
    """A flow picture and what it shows.

    Attributes
    ----------
    rgb : ndarray of uint8, shape (rows, cols, 3)
        The picture: flow, then (with a legend) the legend strip on the right.
    max_speed : float
        Speed drawn fully saturated, at the legend wheel's rim, in ``unit``.
    fixed_scale : bool
        True when ``max_speed`` was given (comparable across pictures); False when it is the
        largest valid speed of this flow.
    unit : str
        Unit of the flow (``px/s`` for velocities).
    scale : int
        Integer upscale of the flow pixels (1 for images of at least :data:`MIN_HEIGHT` rows).
    flow_box, legend_box : (int, int, int, int)
        ``(row0, row1, col0, col1)`` of the flow and of the legend strip in ``rgb``
        (``legend_box`` is empty without a legend).
    texts : tuple of str
        The words drawn in the legend, the ruler's length last (``"50 px"``: the bar above
        it spans that many of the flow's pixels); without a fixed scale and with no flow
        drawn, ``"no flow drawn"`` and an empty line stand for the scale.
    """

    rgb: np.ndarray
    max_speed: float
    fixed_scale: bool
    unit: str
    scale: int
    flow_box: tuple[int, int, int, int]
    legend_box: tuple[int, int, int, int]
    texts: tuple[str, ...]


def _check_max_speed(max_speed: float | None) -> None:
    if max_speed is not None and not (math.isfinite(max_speed) and max_speed > 0):
        raise ParameterError(f"max_speed must be finite and > 0 (px/s), got {max_speed}")


def _check_valid(valid: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray | None:
    if valid is None:
        return None
    valid = np.asarray(valid)
    if valid.shape != shape:
        raise ParameterError(f"valid mask has shape {valid.shape}, expected {shape}")
    if valid.dtype != bool:
        # (0.5 was drawn as valid; the metrics refuse such a mask, probe CB)
        odd = valid[~np.isin(valid, (0, 1))]
        if odd.size:
            raise ParameterError(f"valid mask must hold True / False (or 0 / 1), got "
                                 f"{odd.flat[0]!r}")
    return valid.astype(bool, copy=False)


def upscale_factor(rows: int) -> int:
    """The whole number a flow picture of ``rows`` rows is upscaled by: to at least
    :data:`MIN_HEIGHT` rows.

    Examples
    --------
    >>> upscale_factor(128), upscale_factor(180)
    (2, 1)
    """
    return max(1, -(-MIN_HEIGHT // int(rows)))


def upscale(rgb: np.ndarray, k: int) -> np.ndarray:
    """Each pixel of ``rgb`` (H, W[, C]) as k x k pixels (k a whole number >= 1).

    Examples
    --------
    >>> upscale(np.arange(4).reshape(2, 2), 2).shape
    (4, 4)
    """
    return rgb if k == 1 else np.repeat(np.repeat(rgb, k, axis=0), k, axis=1)


def _render(fig) -> np.ndarray:
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def _figure_px(width: int, height: int):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width / 100.0, height / 100.0), dpi=100, facecolor="white")
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.0, 0.0, 1.0, 1.0))
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_axis_off()
    return fig, ax


def _legend_texts(max_speed: float, unit: str, fixed: bool, masked: bool,
                  has_nan: bool, empty: bool) -> tuple[str, ...]:
    # on a fixed scale, faster pixels are drawn darker (saturated beyond the rim); without
    # a mask every pixel's flow is drawn, those no event supports too (the legend said
    # "grey: no events" over a picture coloured everywhere, probe BK)
    # (a window whose mask holds nothing said "grey: no events" over its events, probe BX)
    grey = ("grey: nothing measured" if masked and empty else "grey: no events" if masked
            else "unmasked; grey: NaN" if has_nan else "unmasked: all pixels")
    if empty and not fixed:
        # no flow, no scale: the legend said "no flow drawn" over "max of image", the scale
        # of an image it had just said was not drawn (probe DA); the scale's line says so once
        return ("u", "v", "no flow drawn", "", grey)
    return ("u", "v", f"rim {max_speed:.3g} {unit}",
            "fixed; darker: beyond" if fixed else "max of image", grey)


#: Narrowest legend strip, px: its longest line, "fixed; darker: beyond", needs ~120 px at
#: the legend's 7-pt floor (a 96-px strip shrank it to 5-6 px, probe DE)
MIN_STRIP_PX = 130


def _wheel_room(height: int) -> int:
    """Width (px) the wheel and its 'u' label take in a strip ``height`` rows tall."""
    return int(np.clip(round(0.3 * height), 96, 200))


def _strip_width(height: int) -> int:
    return max(_wheel_room(height), MIN_STRIP_PX)


def _ruler_px(strip_width: int, k: int) -> int:
    """The ruler's length in the flow's pixels: the longest 1, 2 or 5 x 10^n whose bar,
    ``k`` screen pixels per flow pixel, spans at most half the legend strip (0: not even
    one pixel's bar fits, a flow of one or two rows upscaled past the strip's width)."""
    room = 0.5 * strip_width / k
    if room < 1:
        return 1 if k <= strip_width - 8 else 0
    mag = 10 ** math.floor(math.log10(room))
    return max(m * mag for m in (1, 2, 5) if m * mag <= room)


def _fit_width(fig, texts, room: float) -> None:
    """Shrink each centred text wider than ``room`` px to fit it: the font grows with the
    wheel, the strip's words do not wrap, and "grey: nothing measured" was cut at both
    sides of a 640 x 480 flow's strip (probe DA)."""
    renderer = fig.canvas.get_renderer()
    for text in texts:
        # measured again after each step: hinted small fonts do not scale with their size
        for _ in range(20):
            wide = text.get_window_extent(renderer).width
            if wide <= room:
                break
            text.set_fontsize(text.get_fontsize() * max(0.5, min(0.95, room / wide)))


@functools.lru_cache(maxsize=32)
def _legend_strip(height: int, texts: tuple[str, ...], ruler: int) -> np.ndarray:
    """White strip ``height`` rows tall: the wheel with u/v arrows, the scale below it and
    a bar ``ruler`` screen pixels long above its length in the flow's pixels."""
    width = _strip_width(height)
    # the wheel and the font follow the height, the strip's width gives the words room
    d = _wheel_room(height) - 26  # wheel diameter, px; the margin holds the 'u' label
    pt = max(7.0, d / 11.0)  # font size, points (1 pt = 1.39 px at 100 dpi)
    line = 1.5 * pt * 100 / 72
    top = max(2.0, (height - d - 4.6 * line) / 2)
    x0 = 6.0 + (width - _wheel_room(height)) / 2
    cx, cy, r = x0 + d / 2, top + d / 2, d / 2
    fig, ax = _figure_px(width, height)
    ax.imshow(colorwheel_image(d | 1), extent=(x0, x0 + d, top + d, top),
              interpolation="bilinear")
    arrow = dict(arrowstyle="-|>", lw=1.2, color="black", mutation_scale=pt * 1.3)
    ax.annotate("", xy=(cx + r, cy), xytext=(cx, cy), arrowprops=arrow)
    ax.annotate("", xy=(cx, cy + r), xytext=(cx, cy), arrowprops=arrow)
    ax.text(cx + r + 3, cy, texts[0], fontsize=pt, va="center", ha="left")
    ax.text(cx - 3, cy + 0.75 * r, texts[1], fontsize=pt, va="center", ha="right")
    lines = [ax.text(width / 2, top + d + 5, texts[2], fontsize=pt, va="top", ha="center"),
             ax.text(width / 2, top + d + 5 + line, texts[3], fontsize=pt * 0.85, va="top",
                     ha="center", color="#444444"),
             # the pixels drawn grey: no event supports a flow there (not valid)
             ax.text(width / 2, top + d + 5 + 2 * line, texts[4], fontsize=pt * 0.85,
                     va="top", ha="center", color="#444444")]
    # a flow pixel's size on screen changes with the upscale and the image's size: without
    # a ruler a picture did not say how far its features lie apart
    bar_y = top + d + 5 + 3.3 * line
    if ruler:
        ax.plot([(width - ruler) / 2, (width + ruler) / 2], [bar_y, bar_y], color="black",
                lw=2.5, solid_capstyle="butt")
        lines.append(ax.text(width / 2, bar_y + 0.25 * line, texts[5], fontsize=pt * 0.85,
                             va="top", ha="center"))
    _fit_width(fig, lines, width - 6)
    strip = _render(fig)
    strip.setflags(write=False)
    return strip


def flow_picture(flow: np.ndarray, *, max_speed: float | None = None,
                 valid: np.ndarray | None = None, unit: str = "px/s",
                 legend: bool = True) -> FlowPicture:
    """Colour-code a flow field (Middlebury wheel) beside a legend stating its scale.

    Parameters
    ----------
    flow : ndarray, shape (H, W, 2)
        u (+x right), v (+y down), px/s (or ``unit``).
    max_speed : float, optional
        Speed shown fully saturated (the legend wheel's rim), in ``unit``. Give it to fix the
        colour scale across a sequence; default: the largest valid speed of this flow.
    valid : ndarray of bool, shape (H, W), optional
        Pixels whose flow is supported by events (e.g. ``FlowResult.valid``, triplet counts
        ``> 0``); the others, and NaN flow, are drawn grey (:data:`GREY`). Without it
        every finite flow is drawn, and the legend says so ("unmasked").
    unit : str
        Unit written in the legend.
    legend : bool
        False: the bare colour-coded flow (:func:`flow_to_rgb`), pixel for pixel.

    Returns
    -------
    FlowPicture

    Examples
    --------
    >>> f = np.zeros((120, 160, 2), np.float32); f[..., 0] = 30.0
    >>> pic = flow_picture(f, max_speed=60.0)
    >>> pic.texts[2], pic.texts[4], pic.fixed_scale, pic.rgb.shape[0]
    ('rim 60 px/s', 'unmasked: all pixels', True, 240)
    >>> flow_picture(f, valid=np.zeros((120, 160), bool), legend=False).rgb[0, 0].tolist()
    [128, 128, 128]
    """
    check_switches(legend=legend)
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[-1] != 2 or not min(flow.shape[:2]) > 0:
        raise ParameterError(f"flow must have shape (H, W, 2) with H, W >= 1, got "
                             f"{flow.shape}")
    _check_max_speed(max_speed)
    valid = _check_valid(valid, flow.shape[:2])
    fixed = max_speed is not None
    speed = float(max_speed) if fixed else flow_max_magnitude(flow, valid)
    rgb = flow_to_rgb(flow, speed, valid, invalid_color=GREY)
    h, w = rgb.shape[:2]
    if not legend:
        return FlowPicture(rgb, speed, fixed, unit, 1, (0, h, 0, w), (0, 0, w, w), ())
    k = upscale_factor(h)
    finite = np.isfinite(flow).all(axis=-1)
    # (a window with no valid pixel drew "rim 1 px/s", a scale of nothing, probe BK)
    empty = not (finite if valid is None else finite & valid).any()
    ruler = _ruler_px(_strip_width(h * k), k)
    texts = (*_legend_texts(speed, unit, fixed, valid is not None, not finite.all(), empty),
             f"{ruler} px" if ruler else "")
    strip = _legend_strip(h * k, texts, ruler * k)
    out = np.concatenate([upscale(rgb, k), strip], axis=1)
    return FlowPicture(out, speed, fixed, unit, k, (0, h * k, 0, w * k),
                       (0, h * k, w * k, out.shape[1]), texts)


def sequence_max_speed(flows, valids=None) -> float:
    """One colour scale for a sequence: the largest valid speed over all flows, px/s.

    Examples
    --------
    >>> a = np.zeros((2, 2, 2)); b = np.full((2, 2, 2), 3.0); b[0, 0] = 40.0
    >>> sequence_max_speed([a, b], [np.ones((2, 2), bool), np.eye(2, dtype=bool)[::-1]])
    4.242640687119285
    """
    flows = list(flows)
    valids = [None] * len(flows) if valids is None else list(valids)
    if len(valids) != len(flows):
        raise ParameterError(f"{len(valids)} valid masks for {len(flows)} flows")
    best = 0.0
    for f, m in zip(flows, valids, strict=True):
        f = np.asarray(f)
        mag = np.hypot(f[..., 0], f[..., 1])
        ok = np.isfinite(mag) if m is None else np.isfinite(mag) & np.asarray(m, bool)
        if ok.any():
            best = max(best, float(mag[ok].max()))
    return best if best > 0 else 1.0


def _header(width: int, titles: list[tuple[float, str]], title: str | None, pt: float,
            ) -> np.ndarray:
    line = int(round(1.6 * pt * 100 / 72))
    # wrapped to the width: a long title was cut at both ends (probe BK); a character of
    # the title's font is ~0.85 of its size in px at 100 dpi
    lines = wrap_title(title, width, 0.85 * pt * 1.1)
    height = line * (len(lines) + 1) + 4
    fig, ax = _figure_px(width, height)
    y = 2
    for text in lines:
        ax.text(width / 2, y, text, fontsize=pt * 1.1, va="top", ha="center")
        y += line
    for x, text in titles:
        ax.text(x, y, text, fontsize=pt, va="top", ha="center")
    return _render(fig)


def picture_row(images, titles=None, *, title: str | None = None,
                font_pt: float | None = None) -> np.ndarray:
    """Pictures side by side at their own resolution (no resampling, unlike
    :func:`~evmotion.viz.images.save_panel`), each under its title, on white.

    Parameters
    ----------
    images : sequence of ndarray of uint8, shape (H_k, W_k, 3)
        Shorter images are padded white at the bottom.
    titles : sequence of str, optional
        One per image, centred above it.
    title : str, optional
        A line above everything.
    font_pt : float, optional
        Title size in points (default: from the tallest image, 7-11 pt).

    Returns
    -------
    ndarray of uint8, shape (rows, cols, 3)

    Examples
    --------
    >>> a = np.zeros((20, 30, 3), np.uint8); b = np.zeros((10, 10, 3), np.uint8)
    >>> picture_row([a, b], ["a", "b"]).shape[1]
    44
    """
    images = [np.asarray(im) for im in images]
    if not images:
        raise ParameterError("picture_row needs at least one image")
    for k, im in enumerate(images):
        if im.ndim != 3 or im.shape[2] != 3 or im.dtype != np.uint8:
            raise ParameterError(f"images[{k}] must be uint8 (H, W, 3), got {im.dtype} "
                                 f"{im.shape}")
    if titles is not None and len(titles) != len(images):
        raise ParameterError(f"{len(titles)} titles for {len(images)} images")
    h = max(im.shape[0] for im in images)
    parts, centres, x = [], [], 0
    for k, im in enumerate(images):
        if k:
            parts.append(np.full((h, _GAP, 3), 255, np.uint8))
            x += _GAP
        parts.append(np.pad(im, ((0, h - im.shape[0]), (0, 0), (0, 0)), constant_values=255))
        centres.append(x + im.shape[1] / 2)
        x += im.shape[1]
    body = np.concatenate(parts, axis=1)
    if titles is None and not title:
        return body
    pt = float(np.clip(h / 30.0, 7.0, 11.0)) if font_pt is None else float(font_pt)
    named = [] if titles is None else list(zip(centres, map(str, titles), strict=True))
    return np.concatenate([_header(body.shape[1], named, title, pt), body], axis=0)


def flow_panel(events: EventArray, flow_px_per_s: np.ndarray, *, t_ref_us: int | None = None,
               max_speed: float | None = None, valid: np.ndarray | None = None,
               polarity: bool = False, title: str | None = None,
               ) -> tuple[np.ndarray, dict]:
    """Events | IWE warped by the flow | flow with its legend, side by side, as one picture.

    The first two panels share one intensity scale, so the sharpening the flow brings (the
    story of contrast maximization) shows directly; the middle title gives the Flow Warp
    Loss (FWL > 1: the flow sharpens the events).

    Parameters
    ----------
    events : EventArray
        Events of the window.
    flow_px_per_s : ndarray, shape (H, W, 2)
        Flow in px/s on the sensor grid.
    t_ref_us : int, optional
        Reference time of the warp in µs (default: first event).
    max_speed, valid :
        As for :func:`flow_picture`.
    polarity : bool
        Signed (red/blue) event images instead of counts.
    title : str, optional
        A line above the panels.

    Returns
    -------
    rgb : ndarray of uint8, shape (rows, cols, 3)
    info : dict
        ``fwl`` (float), ``max_speed`` (px/s), ``fixed_scale`` (bool), ``titles`` (list).

    Examples
    --------
    >>> from evmotion.sim import simulate
    >>> sim = simulate("translation", duration_s=0.02, sensor_size=(40, 60), seed=0,
    ...                show_progress=False)
    >>> flow = sim.gt.flow(int(sim.events.t[0]))   # px/s, (H, W, 2)
    >>> rgb, info = flow_panel(sim.events, flow, max_speed=500.0)
    >>> rgb.dtype, rgb.shape[2], info["max_speed"], info["fwl"] > 1
    (dtype('uint8'), 3, 500.0, True)
    """
    from evmotion.core.iwe import accumulate
    from evmotion.eval.metrics import events_where_defined, fwl, warp_by_flow
    from evmotion.viz.images import iwe_to_rgb

    flow = np.asarray(flow_px_per_s)
    shape = tuple(events.sensor_size)
    if flow.shape != (*shape, 2):
        raise ParameterError(f"flow has shape {flow.shape}, expected {(*shape, 2)} "
                             "(the events' sensor size)")
    pic = flow_picture(flow, max_speed=max_speed, valid=valid)
    xw, yw = warp_by_flow(events, flow, t_ref_us)
    weights = events.polarity.astype(np.float64) if polarity else None
    iwe0 = accumulate(events.x.astype(np.float64), events.y.astype(np.float64), shape,
                      weights=weights)
    iwe1 = accumulate(xw, yw, shape, weights=weights)
    # one scale for both: the 99th percentile of the unwarped counts
    vmax = float(np.percentile(np.abs(iwe0[iwe0 != 0]), 99.0)) if np.any(iwe0) else 1.0
    defined = events_where_defined(events, flow)
    value = float(fwl(defined, flow, t_ref_us)) if len(defined) else float("nan")
    k = pic.scale
    titles = ["events (zero flow)", f"IWE warped by the flow (FWL {value:.3f})",
              f"flow ({pic.unit})"]
    rgb = picture_row([upscale(iwe_to_rgb(iwe0, polarity, vmax=vmax), k),
                       upscale(iwe_to_rgb(iwe1, polarity, vmax=vmax), k), pic.rgb],
                      titles, title=title)
    return rgb, {"fwl": value, "max_speed": pic.max_speed, "fixed_scale": pic.fixed_scale,
                 "titles": titles if title is None else [title, *titles]}


def mean_event_flow(x, y, vx, vy, valid, sensor_size: tuple[int, int]
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Per-event flow (a triplet file's columns) drawn as a field: at each pixel the mean
    flow of its ``valid`` events, px/s ``(H, W, 2)``, NaN where none, and the pixels with
    one (``(H, W)`` bool). Coordinates are rounded to the pixel (undistorted ones too).

    Examples
    --------
    >>> f, has = mean_event_flow([1, 1, 2], [0, 0, 1], [10.0, 30.0, 5.0], [0.0, 0.0, 1.0],
    ...                          [True, True, False], (2, 3))
    >>> f[0, 1].tolist(), int(has.sum())
    ([20.0, 0.0], 1)
    """
    h, w = (int(v) for v in sensor_size)
    xi = np.rint(np.asarray(x, np.float64)).astype(np.int64)
    yi = np.rint(np.asarray(y, np.float64)).astype(np.int64)
    ok = (np.asarray(valid, bool) & (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h))
    idx = yi[ok] * w + xi[ok]
    cnt = np.bincount(idx, minlength=h * w)
    has = cnt > 0
    flow = np.full((h * w, 2), np.nan)
    for c, v in enumerate((vx, vy)):
        flow[has, c] = (np.bincount(idx, weights=np.asarray(v, np.float64)[ok],
                                    minlength=h * w)[has] / cnt[has])
    return flow.reshape(h, w, 2).astype(np.float32), has.reshape(h, w)
