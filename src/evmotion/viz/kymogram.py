"""Kymogram pictures: space-time panels with axes in ms and px, a colour bar, and the fitted
velocimetry line with its speed in the legend (thesis Fig. 6.11).

Drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas (never ``pyplot``).
"""

from __future__ import annotations

import io
import os
import textwrap
from collections.abc import Sequence

import numpy as np

from evmotion.errors import ParameterError
from evmotion.methods.kymogram import Kymogram, RidgeFit, px_per_s_to_m_per_s
from evmotion.utils import atomic_path

__all__ = ["RECORDING_CLOCK_SPANS", "kymogram_figure", "save_kymogram_png", "time_edges_s",
           "time_origin_s"]

UNITS = {"events": "events / px / bin", "events signed": "polarity sum / px / bin",
         "frame differences": "|frame difference| [8-bit grey levels]",
         "q": "q [px²/s]", "q (exact)": "q (exact) [px²/s]", "|flow| px/s": "|flow| [px/s]"}
#: Cells with no measurement (NaN: flow no event supports, a field outside its ROI).
NO_DATA_COLOUR = "#e8c77a"


#: The time axis is the recording's clock where the kymograms start within this many of their
#: spans of its zero (a 50 ms kymogram up to 50 s in); further out (a clock counting from
#: 1970) the ticks would carry a dozen digits, and the axis is ``t - t0`` with ``t0`` stated.
RECORDING_CLOCK_SPANS = 1000.0


def time_edges_s(kymo: Kymogram) -> np.ndarray:
    """The edges of a kymogram's time bins on the recording's clock, s: ``T + 1`` values,
    bin ``k`` covering ``[edges[k], edges[k + 1])``.

    ``kymo.meta["t_edges_s"]`` where given (the windows of a flow file, the frames' times);
    else half-way between the bins' times, the first and last bins as wide as their
    neighbour's distance (a single bin: ``1 / rate_hz`` wide).

    Examples
    --------
    >>> from evmotion.methods.kymogram import KymoLine
    >>> k = Kymogram(np.zeros((3, 2)), np.array([0.5, 1.5, 2.5]) / 1200, np.arange(2.0),
    ...              KymoLine.row(0, (1, 2)), 1200.0, "events")
    >>> (time_edges_s(k) * 1200).round(9).tolist()
    [0.0, 1.0, 2.0, 3.0]
    """
    t = np.asarray(kymo.t_s, dtype=np.float64).ravel()
    edges = kymo.meta.get("t_edges_s")
    if edges is not None:
        edges = np.asarray(edges, dtype=np.float64).ravel()
        if (edges.size != t.size + 1 or not np.all(np.diff(edges) > 0)
                or not np.all((edges[:-1] <= t) & (t <= edges[1:]))):
            raise ParameterError(f"meta['t_edges_s'] must hold {t.size + 1} increasing "
                                 f"edges around the {t.size} bins' times, got {edges.size}")
        return edges
    if t.size > 1:
        mid = 0.5 * (t[1:] + t[:-1])
        return np.concatenate([[2 * t[0] - mid[0]], mid, [2 * t[-1] - mid[-1]]])
    dt = (1.0 / kymo.rate_hz) if np.isfinite(kymo.rate_hz) and kymo.rate_hz > 0 else 1e-3
    return np.array([t[0] - dt / 2, t[0] + dt / 2])


def time_origin_s(kymos: Sequence[Kymogram]) -> float:
    """The time the panels' axes count from, s: 0 (the recording's clock) where the
    kymograms start within :data:`RECORDING_CLOCK_SPANS` spans of it, else their start.

    Examples
    --------
    >>> from evmotion.methods.kymogram import KymoLine
    >>> line = KymoLine.row(0, (1, 2))
    >>> time_origin_s([Kymogram(np.zeros((2, 2)), np.array([0.01, 0.02]), np.arange(2.0),
    ...                          line, 100.0, "q")])
    0.0
    >>> time_origin_s([Kymogram(np.zeros((2, 2)), 1.6e9 + np.array([0.01, 0.02]),
    ...                          np.arange(2.0), line, 100.0, "q")]) - 1.6e9 > 0
    True
    """
    edges = [time_edges_s(k) for k in kymos]
    start = min(float(e[0]) for e in edges)
    end = max(float(e[-1]) for e in edges)
    return 0.0 if abs(start) <= RECORDING_CLOCK_SPANS * (end - start) else start


def _axis_label(kymo: Kymogram) -> str:
    ln = kymo.line
    if ln.x0 == ln.x1:
        up = "up" if ln.y1 < ln.y0 else "down"
        return f"y [px] (column {ln.x0:g}; v > 0 {up})"
    if ln.y0 == ln.y1:
        right = "left" if ln.x1 < ln.x0 else "right"
        return f"x [px] (row {ln.y0:g}; v > 0 to the {right})"
    return (f"s [px] along ({ln.x0:g}, {ln.y0:g}) -> ({ln.x1:g}, {ln.y1:g})")


def _image_axis(kymo: Kymogram) -> tuple[float, float]:
    """``(a, b)``: the panel's position axis is ``a + b s`` for ``s`` along the line. A
    column or a row is drawn in image coordinates whichever way the line runs (its own
    ``s`` was labelled y or x: a line from y = 120 up to 10 drew the rising plume falling,
    probe BU), y increasing downwards as in the image, x upwards (so that motion to the
    right rises, probe BX); another line in ``s``, downwards."""
    ln = kymo.line
    if ln.x0 == ln.x1:
        return ln.y0, (1.0 if ln.y1 > ln.y0 else -1.0)
    if ln.y0 == ln.y1:
        return ln.x0, (1.0 if ln.x1 > ln.x0 else -1.0)
    return 0.0, 1.0


def _speed_label(fit: RidgeFit, geometry: dict | None, why: str | None = None) -> str:
    text = f"{fit.method} fit: {fit.velocity_px_s:.4g} ± {fit.velocity_std_px_s:.2g} px/s"
    if geometry:
        v = px_per_s_to_m_per_s(fit.speed_px_s, **geometry)
        dv = px_per_s_to_m_per_s(fit.velocity_std_px_s, **geometry)
        text += f"\n|v| = {v:.3g} ± {dv:.2g} m/s"
    if not fit.reliable:
        # the fit's own reason (spread over a quarter of the speed, or ridge residuals)
        text += "\n" + textwrap.fill(f"unreliable: {why or fit.unreliable_because}", 48)
    return text


#: Where a panel's legend or failed fit's reason starts, in axes units: below its x label
_BELOW = -0.15


def kymogram_figure(kymos: Sequence[Kymogram], fits: Sequence[RidgeFit | None] | None = None,
                    *, titles: Sequence[str] | None = None, geometry: dict | None = None,
                    fit_errors: Sequence[str | None] | None = None,
                    unreliable: Sequence[str | None] | None = None,
                    cmap: str = "gray_r", percentile: float = 99.5, dpi: int = 100):
    """A Figure with one panel per kymogram: time (ms) across, position (px) down.

    Parameters
    ----------
    kymos : sequence of Kymogram
        Drawn side by side on one time axis: the recording's clock, in ms, or ``t - t0``
        with ``t0`` in the titles where the clock's zero lies far off
        (:func:`time_origin_s`); each bin over the interval it covers
        (:func:`time_edges_s`).
    fits : sequence of RidgeFit or None, optional
        A fit per panel: its line (over the inliers' time span with the ridge points for
        :func:`~evmotion.methods.kymogram.fit_ridge`, over the panel for
        :func:`~evmotion.methods.kymogram.fit_correlation`), the velocity in the legend.
    titles : sequence of str, optional
        Default: the source and rate of each kymogram.
    geometry : dict, optional
        ``focal_mm``, ``distance_m``, ``pixel_um``: the legend adds the speed in m/s.
    fit_errors : sequence of str or None, optional
        Why a panel has no fit: written across it ("no velocity fit: ...").
    unreliable : sequence of str or None, optional
        Why each unreliable fit is, worded by the caller (a command names its options
        where the library names its parameters); default the fit's own reason.
    cmap : str
        Matplotlib colour map (signed data use a diverging "RdBu_r" automatically).
    percentile : float
        Colour range: this percentile of |data|.
    """
    import matplotlib
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    kymos = list(kymos)
    if not kymos:
        raise ParameterError("kymogram_figure needs at least one kymogram")
    fits = [None] * len(kymos) if fits is None else list(fits)
    errors = [None] * len(kymos) if fit_errors is None else list(fit_errors)
    whys = [None] * len(kymos) if unreliable is None else list(unreliable)
    if (len(fits) != len(kymos) or len(errors) != len(kymos) or len(whys) != len(kymos)
            or (titles is not None and len(titles) != len(kymos))):
        raise ParameterError(f"{len(kymos)} kymograms need as many fits, fit errors, reasons and "
                             f"titles, got {len(fits)} fits, {len(errors)} fit errors, "
                             f"{None if titles is None else len(titles)} titles")
    n = len(kymos)
    # room below the panels for the fits' legends and the failed fits' reasons
    below = any(f is not None or e for f, e in zip(fits, errors, strict=True))
    fig = Figure(figsize=(4.6 * n, 4.9 if below else 4.2), dpi=dpi)
    FigureCanvasAgg(fig)
    # the recording's clock (the origin had been the first bin's centre: a BOS file's
    # intervals [0, 16.7) ms were drawn from -4.2 to 12.5 ms, and --t0 0.01 started the
    # axis at 0 again, probe DA)
    t_origin = time_origin_s(kymos)
    for i, (k, fit, error, why) in enumerate(zip(kymos, fits, errors, whys, strict=True)):
        ax = fig.add_subplot(1, n, i + 1)
        d = np.asarray(k.data, dtype=np.float64)
        finite = np.isfinite(d)
        signed = bool(finite.any() and d[finite].min() < 0)
        vmax = (float(np.percentile(np.abs(d[finite]), percentile)) if finite.any()
                else 0.0) or 1.0
        edges_ms = (time_edges_s(k) - t_origin) * 1e3
        a, b = _image_axis(k)
        pos = a + b * np.array([k.s_px[0], k.s_px[-1]])
        down = not (k.line.y0 == k.line.y1 and k.line.x0 != k.line.x1)  # all but a row
        ext = (edges_ms[0], edges_ms[-1],
               *((pos.max() + 0.5, pos.min() - 0.5) if down
                 else (pos.min() - 0.5, pos.max() + 0.5)))
        colours = matplotlib.colormaps["RdBu_r" if signed else cmap].with_extremes(
            bad=NO_DATA_COLOUR)
        norm = dict(cmap=colours, vmin=-vmax if signed else 0.0, vmax=vmax)
        widths = np.diff(edges_ms)
        if np.ptp(widths) <= 1e-3 * np.median(widths):
            # the image's first row is drawn at the axis' top
            first_at_top = (b > 0) == down
            im = ax.imshow(d.T if first_at_top else d.T[::-1], aspect="auto", extent=ext,
                           interpolation="nearest", **norm)
        else:
            # windows of unequal length (a camera's frame times): an image's equal
            # columns would draw the bins off their intervals
            s_edges = a + b * np.append(k.s_px - 0.5, k.s_px[-1] + 0.5)
            im = ax.pcolormesh(edges_ms, s_edges, np.ma.masked_invalid(d.T), **norm)
        cb = fig.colorbar(im, ax=ax, fraction=0.05, pad=0.02)
        label = UNITS.get(k.source, k.source)
        if not finite.all():
            # (no measurement had been drawn as zero, still air, probe BX)
            label += f"; {'ochre' if finite.any() else 'all ochre'}: no measurement"
        cb.set_label(label, fontsize=8)
        cb.ax.tick_params(labelsize=7)
        # ticks in the axis' own numbers (matplotlib's offset would move the origin again)
        ax.ticklabel_format(axis="x", style="plain", useOffset=False)
        ax.set_xlabel("t [ms], the recording's clock" if t_origin == 0 else "t - t0 [ms]")
        ax.set_ylabel(_axis_label(k))
        rate = f"{k.rate_hz:.4g} Hz" if np.isfinite(k.rate_hz) else "1 image"
        title = titles[i] if titles is not None else f"{k.source} at {rate}"
        if t_origin != 0:
            title += f"\nt0 = {t_origin:.6f} s on the recording's clock"
        ax.set_title(title, fontsize=10)
        if error:
            # a failed fit had left the panel looking like one drawn with --no-fit (probe BX)
            ax.text(0.5, _BELOW, textwrap.fill(f"no velocity fit: {error}", 52),
                    transform=ax.transAxes, ha="center", va="top", fontsize=7,
                    color="darkred")
        if fit is not None:
            if fit.method == "ridge":
                ti = fit.t_s[fit.inliers]
                ax.plot((fit.t_s - t_origin) * 1e3, a + b * fit.s_px, ".", ms=2.5,
                        color="tab:orange", label="ridge")
                tl = np.array([ti.min(), ti.max()])
            else:
                # a correlation fit's points are lags and shifts: draw its line over the
                # panel, on the strongest streak of that slope
                tl = np.array([k.t_s[0], k.t_s[-1]])
            ax.plot((tl - t_origin) * 1e3, a + b * fit.s_at(tl), "--" if fit.method != "ridge" else "-",
                    lw=1.8, color="tab:red", label=_speed_label(fit, geometry, why))
            # below the panel: inside, it hid the ridge's top right (a rising plume's)
            ax.legend(loc="upper center", bbox_to_anchor=(0.5, _BELOW), fontsize=7,
                      frameon=False)
        # the bins' span, not the lines' (nor pcolormesh's margins)
        ax.set_xlim(ext[0], ext[1])
        ax.set_ylim(ext[2], ext[3])
    fig.tight_layout()
    return fig


def save_kymogram_png(path: str | os.PathLike, kymos: Kymogram | Sequence[Kymogram],
                      fits: RidgeFit | Sequence[RidgeFit | None] | None = None, **kwargs,
                      ) -> None:
    """Save :func:`kymogram_figure` as a PNG, atomically.

    Examples
    --------
    >>> from evmotion.methods.kymogram import Kymogram, KymoLine, fit_ridge
    >>> t = np.arange(200) / 1200.0                       # 1200 Hz
    >>> s = np.arange(100.0)                              # a streak rising at 800 px/s
    >>> data = np.exp(-0.5 * ((s[None, :] - 90 + 800.0 * t[:, None]) / 2.0) ** 2)
    >>> kymo = Kymogram(data, t, s, KymoLine.column(0, (100, 1)), 1200.0, "test")
    >>> fit = fit_ridge(kymo, sigma_bins=0)
    >>> save_kymogram_png("kymo.png", kymo, fit, geometry={"focal_mm": 25.0,
    ...                   "distance_m": 1.7, "pixel_um": 4.86})
    >>> import os; os.path.getsize("kymo.png") > 0
    True
    """
    if isinstance(kymos, Kymogram):
        kymos = [kymos]
        fits = None if fits is None else [fits]
    fig = kymogram_figure(kymos, fits, **kwargs)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=fig.dpi)
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.getvalue())
