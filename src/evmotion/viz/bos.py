"""Pictures of schlieren estimates: the Poisson field q (diverging colours with a colour
bar), the flow (colour wheel with its scale) and the translation field p (colour wheel, px).

The three pictures of one interval show the field pixel for pixel at one magnification
(:func:`field_scale`, the flow picture's), framed, with the first and last pixel ticked on
``x [px]`` and ``y [px]`` axes, and their legend beside them; q's colour range follows one
rule wherever it is drawn (:func:`bos_q_limit`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evmotion.viz.colorwheel import GREY
from evmotion.viz.flowpic import (
    FlowPicture,
    flow_picture,
    picture_row,
    upscale,
    upscale_factor,
)
from evmotion.viz.images import save_png, title_row

__all__ = ["bos_flow_picture", "bos_q_limit", "field_scale", "flow_window_picture",
           "q_picture", "save_bos_flow_png", "save_bos_pngs", "save_bos_sequence_pngs",
           "save_q_png", "symmetric_limit"]

#: Grey of q where it is NaN (outside the ROI): the flow's grey of no measurement.
Q_NAN_GREY = tuple(c / 255 for c in GREY)
#: Margins of a framed field picture, px: left (y ticks and label), bottom (x ticks and
#: label), right of the frame; the colour bar's share of the width (q).
_LEFT, _BOTTOM, _RIGHT, _BAR = 44, 30, 14, 104


def symmetric_limit(values: np.ndarray, percentile: float = 99.0) -> float:
    """Colour limit ``c`` for a diverging map over ``[-c, c]``: the ``percentile`` of
    ``|values|`` over the finite values (1.0 when all are zero or none is finite).

    Examples
    --------
    >>> symmetric_limit(np.array([-2.0, 1.0, np.nan]), 100.0)
    2.0
    """
    a = np.abs(np.asarray(values, dtype=np.float64))
    a = a[np.isfinite(a)]
    c = float(np.percentile(a, percentile)) if a.size else 0.0
    return c if c > 0 else 1.0


def bos_q_limit(q: np.ndarray, valid: np.ndarray | None = None,
                flow: np.ndarray | None = None) -> float:
    """q's colour limit, the one rule of ``bos --png-dir`` and ``evmotion view``: the
    99th percentile of ``|q|`` (:func:`symmetric_limit`) over the measured windows.

    Parameters
    ----------
    q : ndarray, (H, W) or (N, H, W)
        One window's q or a sequence's.
    valid : ndarray of bool, (N, H, W), optional
        The flow's measured pixels (its output's ``valid``).
    flow : ndarray, (N, H, W, 2), optional
        The flow: a pixel whose flow is NaN is no measurement either.
        Windows with no measured pixel (the sensor's start-up, a failed fit) are left out,
        their q being no measurement (all windows are used where none has one).

    Examples
    --------
    >>> q = np.stack([np.full((2, 2), 50.0), np.full((2, 2), -3.0)])
    >>> valid = np.array([False, True])[:, None, None] & np.ones((2, 2, 2), bool)
    >>> bos_q_limit(q), bos_q_limit(q, valid)
    (50.0, 3.0)
    """
    q = np.asarray(q, dtype=np.float64)
    if q.ndim == 3 and (valid is not None or flow is not None):
        ok = np.ones(q.shape, bool)
        if valid is not None:
            ok &= np.asarray(valid, bool)
        if flow is not None:
            ok &= np.isfinite(np.asarray(flow)).all(axis=-1)
        measured = ok.reshape(q.shape[0], -1).any(axis=1)
        if measured.any():
            q = q[measured]
    # (view drew a window at its own 99th percentile, +-480, bos --png-dir the same window
    # at the sequence's, +-380, each by its own rule; probe DA)
    return symmetric_limit(q)


def _q_scale(q: np.ndarray, limit: float | None = None) -> tuple[float, float, bool]:
    """q's colour limit (default :func:`bos_q_limit`), its largest finite ``|q|``, and
    whether the limit clips it."""
    if limit is None:
        limit = bos_q_limit(q)
    finite = np.abs(q[np.isfinite(q)])
    peak = float(finite.max()) if finite.size else 0.0
    return limit, peak, peak > limit * (1 + 1e-9)


def _q_label(unit: str, peak: float, clipped: bool, has_nan: bool) -> str:
    """The colour bar's words, one text wherever q is drawn (view said "clipped",
    bos --png-dir "|q| up to 880 shown at the ends")."""
    text = f"q [{unit}]"
    if clipped:
        text += f"\n|q| up to {peak:.3g} shown at the ends"
    if has_nan:
        text += "\ngrey: no q (outside the ROI)"
    return text


def field_scale(shape: tuple[int, ...]) -> int:
    """Screen pixels per field pixel of a BOS picture, q, flow and p alike: the flow
    picture's integer upscale to at least :data:`~evmotion.viz.flowpic.MIN_HEIGHT` rows.

    Examples
    --------
    >>> field_scale((128, 160)), field_scale((180, 160))
    (2, 1)
    """
    return upscale_factor(shape[0])


def _framed(field: np.ndarray, k: int, title: str | None, *,
            colourbar: tuple | None = None, legend: np.ndarray | None = None) -> np.ndarray:
    """``field`` (RGB, already ``k`` screen pixels a pixel) pasted unresampled in a grey
    frame, its first and last pixels ticked on ``x [px]`` / ``y [px]`` axes, the title
    above, and beside it a colour bar (``(norm, cmap, label, extend)``) or a ``legend``
    strip as tall as the field."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.figure import Figure

    rows, cols = field.shape[:2]
    h, w = rows // k, cols // k
    top = 6
    fig_w = _LEFT + cols + 2 + (_BAR if colourbar is not None else _RIGHT)
    fig_h = top + rows + 2 + _BOTTOM
    # (+0.01 px: Agg truncates the size, and 4.68 in x 100 dpi came out 467.99... px)
    fig = Figure(figsize=((fig_w + 0.01) / 100.0, (fig_h + 0.01) / 100.0), dpi=100,
                 facecolor="white")
    FigureCanvasAgg(fig)
    # the axes box is the frame: one screen pixel around the field on each side
    ax = fig.add_axes((_LEFT / fig_w, _BOTTOM / fig_h, (cols + 2) / fig_w,
                       (rows + 2) / fig_h), facecolor="white")
    pad = 1.0 / k
    ax.set_xlim(-0.5 - pad, w - 0.5 + pad)
    ax.set_ylim(h - 0.5 + pad, -0.5 - pad)
    # the field's first and last pixel as the only ticks, as panel_png draws them
    ax.set_xticks([0, w - 1])
    ax.set_yticks([0, h - 1])
    ax.tick_params(labelsize=7, length=2, pad=1)
    ax.set_xlabel("x [px]", fontsize=7, labelpad=-6)
    ax.set_ylabel("y [px]", fontsize=7, labelpad=-10)
    for spine in ax.spines.values():
        spine.set_visible(False)
    if colourbar is not None:
        norm, cmap, label, extend = colourbar
        cax = fig.add_axes(((_LEFT + cols + 16) / fig_w, (_BOTTOM + 1) / fig_h,
                            12 / fig_w, rows / fig_h))
        bar = fig.colorbar(ScalarMappable(norm, cmap), cax=cax, extend=extend)
        bar.set_label(label, fontsize=7, linespacing=1.1)
        bar.ax.tick_params(labelsize=7)
    fig.canvas.draw()
    out = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
    r0, c0 = top + 1, _LEFT + 1
    out[r0:r0 + rows, c0:c0 + cols] = field
    # the frame: a white zero flow had run into the white page (probe DA)
    out[[r0 - 1, r0 + rows], c0 - 1:c0 + cols + 1] = 153
    out[r0 - 1:r0 + rows + 1, [c0 - 1, c0 + cols]] = 153
    if legend is not None:
        strip = np.full((fig_h, legend.shape[1], 3), 255, np.uint8)
        strip[r0:r0 + rows] = legend[:rows]
        out = np.concatenate([out, strip], axis=1)
    if title:
        # over the whole picture, wrapped to it as save_flow_png's (centred on a narrow
        # field it had run off both ends)
        out = np.concatenate([title_row(out.shape[1], title), out], axis=0)
    return out


def q_picture(q: np.ndarray, *, limit: float | None = None, unit: str = "px^2/s",
              title: str | None = None) -> tuple[np.ndarray, float]:
    """A Poisson field q as an RGB image: blue negative, white zero, red positive, each
    pixel :func:`field_scale` screen pixels wide (the flow's magnification), framed, on
    pixel axes, beside a colour bar in ``unit``; NaN (outside the ROI) is grey.

    Parameters
    ----------
    q : ndarray, (H, W)
        The field.
    limit : float, optional
        The colour bar spans ``[-limit, limit]`` (default: :func:`bos_q_limit`).

    Returns
    -------
    rgb : ndarray of uint8, (rows, cols, 3)
    limit : float
        The limit used.

    Examples
    --------
    >>> rgb, limit = q_picture(np.linspace(-1, 1, 64).reshape(8, 8))
    >>> rgb.dtype, rgb.shape[2], limit
    (dtype('uint8'), 3, 1.0)
    """

    q = np.asarray(q, dtype=np.float64)
    k = field_scale(q.shape)
    # (q had been drawn in a 6-inch figure, 3.5x beside the flow's 2x, resampled and
    # with no axes, probe DA)
    rgb, norm, cmap, limit, peak, clipped = _q_rgb(q, k, limit)
    label = _q_label(unit, peak, clipped, bool(np.isnan(q).any()))
    out = _framed(rgb, k, title, colourbar=(norm, cmap, label,
                                            "both" if clipped else "neither"))
    return out, float(limit)


def save_q_png(path: str | os.PathLike, q: np.ndarray, *, limit: float | None = None,
               unit: str = "px^2/s", title: str | None = None) -> float:
    """Save :func:`q_picture` of ``q`` as a PNG, atomically; returns the colour limit.

    Examples
    --------
    >>> save_q_png("q.png", np.linspace(-1, 1, 64).reshape(8, 8))
    1.0
    """
    rgb, limit = q_picture(q, limit=limit, unit=unit, title=title)
    save_png(path, rgb)
    return limit


def bos_flow_picture(flow: np.ndarray, *, max_speed: float | None = None,
                     valid: np.ndarray | None = None, unit: str = "px/s",
                     title: str | None = None) -> tuple[np.ndarray, FlowPicture]:
    """A flow (or p) as :func:`~evmotion.viz.flowpic.flow_picture` colours it, at its
    magnification (:func:`field_scale`), framed on pixel axes, its legend beside it.

    Returns
    -------
    rgb : ndarray of uint8, (rows, cols, 3)
    picture : FlowPicture
        What was drawn (scale, legend texts), without the frame and the title.

    Examples
    --------
    >>> rgb, pic = bos_flow_picture(np.zeros((8, 8, 2)), max_speed=100.0)
    >>> pic.scale, rgb.dtype
    (20, dtype('uint8'))
    """
    pic = flow_picture(flow, max_speed=max_speed, valid=valid, unit=unit)
    r0, r1, c0, c1 = pic.flow_box
    l0, l1, m0, m1 = pic.legend_box
    return _framed(pic.rgb[r0:r1, c0:c1], pic.scale, title,
                   legend=pic.rgb[l0:l1, m0:m1]), pic


def save_bos_flow_png(path: str | os.PathLike, flow: np.ndarray, **kwargs) -> FlowPicture:
    """Save :func:`bos_flow_picture` as a PNG, atomically; returns what was drawn.

    Examples
    --------
    >>> save_bos_flow_png("bos_flow.png", np.zeros((8, 8, 2)), unit="px").unit
    'px'
    """
    rgb, pic = bos_flow_picture(flow, **kwargs)
    save_png(path, rgb)
    return pic


def flow_window_picture(flow: np.ndarray, *, valid: np.ndarray | None = None,
                        q: np.ndarray | None = None, title: str | None = None,
                        q_unit: str = "px^2/s", unit: str = "px/s",
                        q_limit: float | None = None) -> np.ndarray:
    """One window of a flow output as an RGB image: the colour-coded flow in ``unit``
    (grey where not ``valid`` or NaN) beside its legend, and with ``q`` (BOS outputs) the
    Poisson field beside it, its colour bar over ``[-q_limit, q_limit]`` (default
    :func:`bos_q_limit` of this window; give the file's, as ``bos --png-dir`` draws it).

    Examples
    --------
    >>> f = np.zeros((40, 50, 2), np.float32); f[..., 0] = 3.0
    >>> flow_window_picture(f, q=np.zeros((40, 50)), title="window 0").dtype
    dtype('uint8')
    """
    flow = np.asarray(flow, dtype=np.float32)
    ok = np.isfinite(flow).all(axis=-1)
    valid = ok if valid is None else (np.asarray(valid, bool) & ok)
    pic = flow_picture(np.nan_to_num(flow), valid=valid, unit=unit)
    if q is None:
        return picture_row([pic.rgb], title=title)
    # q pixel for pixel at the flow's scale beside its colour bar (a figure of its own
    # had drawn it larger than the flow and lower, probe BX)
    return picture_row([pic.rgb, _q_panel(q, pic.scale, q_unit, q_limit)],
                       ["flow", "Poisson field q"], title=title)


def _q_rgb(q: np.ndarray, k: int, limit: float | None):
    """q in diverging colours (NaN grey), each pixel k x k: ``(rgb, norm, cmap, limit,
    peak, clipped)``."""
    import matplotlib
    from matplotlib.colors import Normalize

    limit, peak, clipped = _q_scale(q, limit)
    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad=Q_NAN_GREY)
    norm = Normalize(-limit, limit)
    rgb = (cmap(norm(np.ma.masked_invalid(q)))[..., :3] * 255 + 0.5).astype(np.uint8)
    return upscale(rgb, k), norm, cmap, limit, peak, clipped


def _q_panel(q: np.ndarray, scale: int, unit: str, limit: float | None = None) -> np.ndarray:
    """q in diverging colours (NaN grey), each pixel ``scale`` x ``scale``, beside a
    colour bar as tall."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.figure import Figure

    q = np.asarray(q, dtype=np.float64)
    rgb, norm, cmap, limit, peak, clipped = _q_rgb(q, scale, limit)
    height = rgb.shape[0]
    fig = Figure(figsize=(1.1, height / 100.0), dpi=100, facecolor="white")
    FigureCanvasAgg(fig)
    cax = fig.add_axes((0.1, 0.06, 0.16, 0.88))
    bar = fig.colorbar(ScalarMappable(norm, cmap), cax=cax,
                       extend="both" if clipped else "neither")
    bar.set_label(_q_label(unit, peak, clipped, bool(np.isnan(q).any())), fontsize=7,
                  linespacing=1.1)
    bar.ax.tick_params(labelsize=6)
    fig.canvas.draw()
    strip = np.asarray(fig.canvas.buffer_rgba())[..., :3]
    return np.concatenate([rgb, strip[:height]], axis=1)


def save_bos_pngs(folder: str | os.PathLike, index: int, flow: np.ndarray, q: np.ndarray,
                  p: np.ndarray, *, q_unit: str = "px^2/s", flow_max: float | None = None,
                  q_limit: float | None = None, label: str = "",
                  valid: np.ndarray | None = None) -> list[str]:
    """Write ``q_XXXX.png``, ``flow_XXXX.png`` and ``p_XXXX.png`` for window ``index``.

    Parameters
    ----------
    flow : ndarray, (H, W, 2)
        Flow in px/s (colour wheel with its scale in px/s).
    q : ndarray, (H, W)
        Poisson field (diverging colours, colour bar in ``q_unit``).
    p : ndarray, (H, W, 2)
        Translation field in px (colour wheel, scale in px).
    flow_max : float, optional
        Rim of the flow colour wheel in px/s (default: the largest finite magnitude).
    q_limit : float, optional
        q's colour bar spans ``[-q_limit, q_limit]`` (default: :func:`symmetric_limit`).
    label : str
        Text added to each title (e.g. the window's time).
    valid : ndarray, (H, W) bool, optional
        The flow's measured pixels (the output's ``valid``, where events support it):
        the others are drawn grey, as ``evmotion view`` draws them, and the colour
        wheel's rim is the largest valid magnitude (default: every finite pixel).

    Returns
    -------
    list of str
        The files written.

    Examples
    --------
    >>> files = save_bos_pngs("png", 0, np.zeros((8, 8, 2)), np.zeros((8, 8)),
    ...                       np.zeros((8, 8, 2)))
    >>> len(files) > 0
    True
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    suffix = f" {label}" if label else ""
    names = [folder / f"q_{index:05d}.png", folder / f"flow_{index:05d}.png",
             folder / f"p_{index:05d}.png"]
    save_q_png(names[0], q, limit=q_limit, unit=q_unit, title=f"Poisson field q{suffix}")
    mask = np.isfinite(flow).all(axis=-1)
    if valid is not None:
        mask &= np.asarray(valid, bool)
    save_bos_flow_png(names[1], np.nan_to_num(flow), max_speed=flow_max, valid=mask,
                      unit="px/s", title=f"flow{suffix}")
    # p is solved at every pixel, events or not: unmasked, NaN grey (its legend said
    # "grey: no events" over a picture with no grey, probe BN)
    save_bos_flow_png(names[2], np.asarray(p, np.float32), unit="px",
                      title=f"translation p{suffix}")
    return [str(n) for n in names]


def save_bos_sequence_pngs(folder: str | os.PathLike, bos, *,
                           max_speed: float | None = None) -> list[str]:
    """:func:`save_bos_pngs` for every interval of a BOS output, on one colour scale for
    the flow and one for q, so that the pictures of a sequence compare (each had been
    scaled to its own maximum, probe BX); an interval with no valid pixel (the sensor's
    start-up, a failed fit) is titled NOT A MEASUREMENT.

    Parameters
    ----------
    folder : path-like
    bos : BosSequence
        :func:`~evmotion.io.bosfiles.read_bos`'s result.
    max_speed : float, optional
        Rim of the flow's colour wheel in px/s (default: the largest valid speed of the
        sequence); q's colour limit is :func:`bos_q_limit`'s, the 99th percentile of
        ``|q|`` over the measured intervals (as ``evmotion view`` draws each).

    Returns
    -------
    list of str
        The files written, three per interval.

    Examples
    --------
    >>> from evmotion.io.bosfiles import BosSequence
    >>> from evmotion.io.flowfiles import FlowSequence
    >>> flow = np.zeros((2, 8, 8, 2), np.float32); flow[1] = 3.0
    >>> seq = FlowSequence(flow=flow, t0=np.array([0, 10]), t1=np.array([10, 20]),
    ...                    valid=np.ones((2, 8, 8), bool), attrs={})
    >>> bos = BosSequence(flow=seq, q=np.zeros((2, 8, 8)), p=np.zeros((2, 8, 8, 2)),
    ...                   scalars={}, attrs={"q_units": "px^2/s"})
    >>> len(save_bos_sequence_pngs("png_seq", bos))
    6
    """
    from evmotion.viz.flowpic import sequence_max_speed

    seq = bos.flow
    n = len(seq.t0)
    valid = (np.isfinite(seq.flow).all(axis=-1) if seq.valid is None
             else np.asarray(seq.valid, bool) & np.isfinite(seq.flow).all(axis=-1))
    measured = valid.reshape(n, -1).any(axis=1)
    if max_speed is None:
        max_speed = sequence_max_speed(np.nan_to_num(seq.flow), valid)
    q_limit = bos_q_limit(bos.q, valid)  # (valid: the flow's mask and its finite pixels)
    files: list[str] = []
    for k in range(n):
        label = f"[{seq.t0[k]}, {seq.t1[k]}) µs"
        if not measured[k]:
            label += ": NOT A MEASUREMENT (no valid pixel)"
        files += save_bos_pngs(folder, k, seq.flow[k], bos.q[k], bos.p[k],
                               q_unit=bos.attrs.get("q_units") or "px^2/s",
                               flow_max=max_speed, q_limit=q_limit, label=label,
                               valid=valid[k])
    return files
