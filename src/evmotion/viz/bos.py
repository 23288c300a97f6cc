"""Pictures of schlieren estimates: the Poisson field q (diverging colours with a colour
bar), the flow (colour wheel with its scale) and the translation field p (colour wheel, px).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evmotion.viz.flowpic import flow_picture, picture_row
from evmotion.viz.images import save_flow_png, save_png

__all__ = ["flow_window_picture", "q_picture", "save_bos_pngs", "save_bos_sequence_pngs",
           "save_q_png",
           "symmetric_limit"]


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


def _q_scale(q: np.ndarray, limit: float | None = None) -> tuple[float, float, bool]:
    """q's colour limit (default :func:`symmetric_limit`), its largest finite ``|q|``, and
    whether the limit clips it."""
    if limit is None:
        limit = symmetric_limit(q)
    finite = np.abs(q[np.isfinite(q)])
    peak = float(finite.max()) if finite.size else 0.0
    return limit, peak, peak > limit * (1 + 1e-9)


def q_picture(q: np.ndarray, *, limit: float | None = None, unit: str = "px^2/s",
              title: str | None = None, dpi: int = 100) -> tuple[np.ndarray, float]:
    """A Poisson field q as an RGB image: blue negative, white zero, red positive, with a
    colour bar in ``unit``; NaN (outside the ROI) is grey.

    Parameters
    ----------
    q : ndarray, (H, W)
        The field.
    limit : float, optional
        The colour bar spans ``[-limit, limit]`` (default: 99th percentile of ``|q|``).

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
    limit, peak, clipped = _q_scale(q, limit)
    h, w = q.shape
    scale = 6.0 / max(h, w)
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w * scale + 1.6, h * scale + 0.7), dpi=dpi)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_axes((0.02, 0.04, 0.74, 0.86))

    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad=(0.6, 0.6, 0.6))
    im = ax.imshow(np.ma.masked_invalid(q), cmap=cmap, vmin=-limit, vmax=limit,
                   interpolation="nearest")
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=10)
    cax = fig.add_axes((0.8, 0.1, 0.04, 0.76))
    bar = fig.colorbar(im, cax=cax, extend="both" if clipped else "neither")
    # a scale that clips says so: the arrows' ends and the peak it does not show
    bar.set_label(f"q [{unit}]" + (f"; |q| up to {peak:.3g} shown at the ends" if clipped
                                   else ""), fontsize=8)
    bar.ax.tick_params(labelsize=7)
    canvas.draw()
    return np.ascontiguousarray(np.asarray(canvas.buffer_rgba())[..., :3]), float(limit)


def save_q_png(path: str | os.PathLike, q: np.ndarray, *, limit: float | None = None,
               unit: str = "px^2/s", title: str | None = None, dpi: int = 100) -> float:
    """Save :func:`q_picture` of ``q`` as a PNG, atomically; returns the colour limit.

    Examples
    --------
    >>> save_q_png("q.png", np.linspace(-1, 1, 64).reshape(8, 8))
    1.0
    """
    rgb, limit = q_picture(q, limit=limit, unit=unit, title=title, dpi=dpi)
    save_png(path, rgb)
    return limit


def flow_window_picture(flow: np.ndarray, *, valid: np.ndarray | None = None,
                        q: np.ndarray | None = None, title: str | None = None,
                        q_unit: str = "px^2/s", unit: str = "px/s") -> np.ndarray:
    """One window of a flow output as an RGB image: the colour-coded flow in ``unit``
    (grey where not ``valid`` or NaN) beside its legend, and with ``q`` (BOS outputs) the
    Poisson field beside it.

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
    return picture_row([pic.rgb, _q_panel(q, pic.scale, q_unit)], ["flow", "Poisson field q"],
                       title=title)


def _q_panel(q: np.ndarray, scale: int, unit: str) -> np.ndarray:
    """q in diverging colours (NaN grey), each pixel ``scale`` x ``scale``, beside a
    colour bar as tall."""
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    q = np.asarray(q, dtype=np.float64)
    limit, _, clipped = _q_scale(q)
    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad=(0.5, 0.5, 0.5))
    norm = Normalize(-limit, limit)
    rgb = (cmap(norm(np.ma.masked_invalid(q)))[..., :3] * 255 + 0.5).astype(np.uint8)
    rgb = np.repeat(np.repeat(rgb, scale, axis=0), scale, axis=1)
    height = rgb.shape[0]
    fig = Figure(figsize=(1.1, height / 100.0), dpi=100, facecolor="white")
    FigureCanvasAgg(fig)
    cax = fig.add_axes((0.1, 0.06, 0.16, 0.88))
    bar = fig.colorbar(ScalarMappable(norm, cmap), cax=cax,
                       extend="both" if clipped else "neither")
    bar.set_label(f"q [{unit}]" + ("; clipped" if clipped else ""), fontsize=7)
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
    save_flow_png(names[1], np.nan_to_num(flow), max_speed=flow_max, valid=mask,
                  unit="px/s", title=f"flow{suffix}")
    # p is solved at every pixel, events or not: unmasked, NaN grey (its legend said
    # "grey: no events" over a picture with no grey, probe BN)
    save_flow_png(names[2], np.asarray(p, np.float32), unit="px",
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
        sequence); q's colour limit is the 99th percentile of ``|q|`` over the measured
        intervals.

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
    q_limit = symmetric_limit(np.asarray(bos.q)[measured]) if measured.any() else None
    files: list[str] = []
    for k in range(n):
        label = f"[{seq.t0[k]}, {seq.t1[k]}) us"
        if not measured[k]:
            label += ": NOT A MEASUREMENT (no valid pixel)"
        files += save_bos_pngs(folder, k, seq.flow[k], bos.q[k], bos.p[k],
                               q_unit=bos.attrs.get("q_units") or "px^2/s",
                               flow_max=max_speed, q_limit=q_limit, label=label,
                               valid=valid[k])
    return files
