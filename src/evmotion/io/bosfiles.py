"""Schlieren (BOS) outputs: flow, Poisson field q and translation field p.

A BOS output *is* an evmotion flow output (:mod:`evmotion.io.flowout`): one window per
frame interval, so :func:`~evmotion.io.flowread.read_flow`, ``evmotion info`` and
``evmotion eval`` read its flow, times and validity unchanged. Its extra datasets
(:func:`bos_extras`; ``.h5`` and ``.npz`` only) are::

    /q      (N, H, W)    float32, the Poisson field (v = Sobel(q)), attribute units
    /p      (N, H, W, 2) float32, px, per-pixel translation of the frame (x, y)
    /window/<name> (N,)  float64, per-window scalars (contrast threshold, loss, events...)
    attrs: content="evmotion-bos", roi=(x, y, w, h), extras (their names), plus the
    writer's attributes

Files written before the ``extras`` attribute existed (same datasets, ``valid`` = the ROI)
are read the same way.

Pixels outside the ROI are NaN in flow, q and p and False in ``/valid``. The file is
written to ``<name>.part`` and renamed by :meth:`BosWriter.close` (atomic), as
:class:`~evmotion.io.flowfiles.FlowWriter` does.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.io.flowfiles import (
    ExtraSpec,
    FlowSequence,
    FlowWriter,
    create_extras,
    read_flow_group,
)
from evmotion.io.guard import guarded, open_h5
from evmotion.io.h5attrs import read_attrs

__all__ = ["BOS_COMPRESSION", "BOS_CONTENT", "BosSequence", "BosWriter", "bos_extras", "read_bos",
           "read_bos_h5", "roi_mask"]

BOS_CONTENT = "evmotion-bos"
#: The filter of a BOS output's datasets: none, so that every HDF5 reader opens it (MATLAB's
#: h5read, HDFView, plain h5py), where the flow outputs' Blosc-LZ4 needs hdf5plugin. A
#: plume's 640x720 flow, q and p compress only 1.3x (LZ4 45.6 MB, none 58.1 MB for six
#: intervals) and gzip took 446 ms a window against 37 (an interval's solve: about 3 s).
BOS_COMPRESSION = None


def roi_mask(sensor_size: tuple[int, int], roi: tuple[int, int, int, int] | None
             ) -> np.ndarray:
    """Boolean (H, W) mask of ``roi = (x, y, w, h)`` px (the whole sensor when None).

    Examples
    --------
    >>> int(roi_mask((4, 5), (1, 2, 3, 2)).sum())
    6
    """
    h, w = (int(v) for v in sensor_size)
    mask = np.zeros((h, w), bool)
    if roi is None:
        mask[:] = True
        return mask
    x, y, rw, rh = (int(v) for v in roi)
    if rw <= 0 or rh <= 0:
        raise ParameterError(f"roi (x={x}, y={y}, w={rw}, h={rh}) is empty: its width and "
                             "height must be > 0")
    if x < 0 or y < 0 or x + rw > w or y + rh > h:
        inside = x < w and y < h and x + rw > 0 and y + rh > 0
        raise ParameterError(f"roi (x={x}, y={y}, w={rw}, h={rh}) "
                             f"{'reaches beyond' if inside else 'lies outside'} the {w}x{h} "
                             "(W x H) sensor")
    mask[y:y + rh, x:x + rw] = True
    return mask


@dataclass(frozen=True)
class BosSequence:
    """Schlieren estimates of a sequence of frame intervals.

    Attributes
    ----------
    flow : FlowSequence
        Flow (N, H, W, 2) px/s with each window's ``[t0, t1)`` µs and the ROI as ``valid``.
    q : ndarray, (N, H, W) float32
        Poisson field; ``flow = Sobel(q)`` inside the ROI (units in ``attrs["q_units"]``).
    p : ndarray, (N, H, W, 2) float32
        Translation field of the frame in px.
    scalars : dict of str to ndarray (N,)
        Per-window numbers (e.g. ``contrast_threshold``, ``loss``, ``n_events``).
    attrs : dict
        File attributes.
    """

    flow: FlowSequence
    q: np.ndarray
    p: np.ndarray
    scalars: dict = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.flow)


def bos_extras(sensor_size: tuple[int, int], q_units: str = "px^2/s",
               scalars: tuple[str, ...] = ()) -> dict:
    """The extra datasets of a BOS flow output (name -> :class:`~evmotion.io.flowfiles.
    ExtraSpec`): ``q`` (H, W), ``p`` (H, W, 2) px, and one float64 ``window/<name>`` per
    per-window number in ``scalars``.

    Examples
    --------
    >>> sorted(bos_extras((4, 5), scalars=("loss",)))
    ['p', 'q', 'window/loss']
    """
    h, w = (int(v) for v in sensor_size)
    out = {"q": ExtraSpec((h, w), "<f4", q_units, Q_MEANING),
           "p": ExtraSpec((h, w, 2), "<f4", "px", P_MEANING)}
    for name in scalars:
        out[f"window/{name}"] = ExtraSpec((), "<f8", SCALAR_UNITS.get(name, ""),
                                          SCALAR_MEANINGS.get(name, "per-window number"))
    return out


Q_MEANING = "Poisson field: flow = Sobel(q), q proportional to drho/dt"
P_MEANING = "per-pixel translation (x, y) of the frame, W(x; p) = x + p"
#: Units and meanings of the per-window numbers ``evmotion bos`` stores.
SCALAR_UNITS = {"contrast_threshold": "log intensity", "objective": "", "n_events": "events",
                "seconds": "s", "frame_index": "", "calibrated": "", "fit_gain": "",
                "relinearized": "", "displacement_q95": "px"}
SCALAR_MEANINGS = {
    "contrast_threshold": "event contrast threshold C used (NaN: unknown)",
    "objective": "final objective (6.10) at full resolution",
    "n_events": "events in the window",
    "seconds": "wall time of the estimate",
    "frame_index": "index of the frame the window's events are compared with",
    "calibrated": "1: the flow magnitude is physical; 0: only its direction is measured",
    "fit_gain": "measured increment regressed on the predicted one where events fired "
                "(about 1: the flow explains the events; NaN: not calibrated)",
    "relinearized": "further solves with the frame warped by the flow",
    "displacement_q95": "95th percentile of the flow's displacement over the window on "
                        "the valid pixels",
}


class BosWriter(FlowWriter):
    """Append per-interval schlieren estimates (flow, q, p) to a BOS HDF5 file: an
    evmotion flow file whose extra datasets (:func:`bos_extras`) are ``q``, ``p`` and
    ``window/<name>``.

    Parameters
    ----------
    path : path-like
        Final file name (``.h5``); data go to ``<path>.part`` until :meth:`close`.
    sensor_size : (int, int)
        ``(height, width)`` of every field.
    roi : (int, int, int, int), optional
        ``(x, y, w, h)`` px where the fields are estimated; outside they are stored as NaN
        and the ``valid`` mask is False. Default: the whole sensor.
    attrs : dict, optional
        File attributes (method, parameters, source...).
    q_units : str
        Unit of q, stored as the ``units`` attribute of ``/q``.
    resume : bool
        Continue an unfinished ``.part`` file (see :class:`FlowWriter`).

    Examples
    --------
    >>> with BosWriter("bos.h5", (4, 5), roi=(1, 1, 3, 2)) as bw:
    ...     bw.append(np.zeros((4, 5, 2)), 0, 8333, q=np.zeros((4, 5)),
    ...               p=np.zeros((4, 5, 2)), scalars={"loss": 0.1})
    >>> bos = read_bos_h5("bos.h5")
    >>> int(bos.flow.valid.sum()), bos.scalars["loss"].tolist()  # the 3x2 ROI
    (6, [0.1])
    """

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int], *,
                 roi: tuple[int, int, int, int] | None = None, attrs: dict | None = None,
                 q_units: str = "px^2/s", resume: bool = False,
                 compression: str | None = BOS_COMPRESSION):
        self.mask = roi_mask(sensor_size, roi)
        h, w = self.mask.shape
        all_attrs = {"content": BOS_CONTENT,
                     "roi": np.asarray(roi if roi is not None else (0, 0, w, h), np.int64),
                     **(attrs or {})}
        self._compression = compression
        super().__init__(path, (h, w), with_valid=True, resume=resume, attrs=all_attrs,
                         compression=compression,
                         extras=None if resume else bos_extras((h, w), q_units))

    def append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray | None = None,
               extras: dict | None = None, *, q: np.ndarray | None = None,
               p: np.ndarray | None = None, scalars: dict | None = None) -> None:
        """Add one frame interval ``[t0, t1)`` µs: flow (H, W, 2) px/s, q (H, W), p (H, W, 2)
        px, and per-window numbers ``scalars`` (the first window creates their datasets).
        Values outside the ROI are set to NaN."""
        h, w = self.sensor_size
        if q is None or p is None:
            raise ParameterError("BosWriter.append needs q (H, W) and p (H, W, 2)")
        q = np.array(q, dtype=np.float32)
        p = np.array(p, dtype=np.float32)
        if q.shape != (h, w):
            raise ParameterError(f"q has shape {q.shape}, expected {(h, w)}")
        if p.shape != (h, w, 2):
            raise ParameterError(f"p has shape {p.shape}, expected {(h, w, 2)}")
        flow = np.array(flow, dtype=np.float32)
        outside = ~self.mask
        for arr in (flow, q, p):
            arr[outside] = np.nan
        n = self.n_done
        values = {"q": q, "p": p, **{f"window/{k}": float(v) for k, v in
                                     (scalars or {}).items()}}
        new = {k: v for k, v in bos_extras((h, w), scalars=tuple(scalars or {})).items()
               if k.startswith("window/") and k not in self.extras}
        if new:
            if n > 0:
                raise ParameterError(f"scalar '{sorted(new)[0][7:]}' was not given for the "
                                     f"earlier {n} windows")
            create_extras(self.f, new, self._compression)
            self.extras.update(new)
        missing = sorted(k[7:] for k in set(self.extras) - set(values))
        if missing:
            raise ParameterError(f"window {n} lacks scalars {missing}")
        super().append(flow, t0, t1, valid=self.mask if valid is None else valid & self.mask,
                       extras=values)


@guarded('BOS file')
def read_bos(path: str | os.PathLike) -> BosSequence:
    """Read a BOS output from any container that holds q and p (``.h5``, ``.npz``).

    Examples
    --------
    >>> from evmotion.io.flowout import open_flow_output
    >>> with open_flow_output("bos.npz", (4, 5), extras=bos_extras((4, 5))) as out:
    ...     for i in range(3):
    ...         out.append(np.zeros((4, 5, 2), np.float32), i * 8333, (i + 1) * 8333,
    ...                    extras={"q": np.ones((4, 5)), "p": np.zeros((4, 5, 2))})
    >>> bos = read_bos("bos.npz")
    >>> bos.q.shape, bos.attrs["q_units"]
    ((3, 4, 5), 'px^2/s')
    """
    from evmotion.io.flowread import read_flow

    seq = read_flow(path)
    for name in ("q", "p"):
        if name not in seq.extras:
            raise FormatError(path, f"not a BOS output: no '{name}' beside the flow (the "
                              ".flo / .png containers hold the flow only)")
    scalars = {k[len("window/"):]: np.asarray(v) for k, v in seq.extras.items()
               if k.startswith("window/")}
    attrs = dict(seq.attrs)
    attrs["q_units"] = attrs.get("extras_units", {}).get("q", "")
    flow = FlowSequence(flow=seq.flow, t0=seq.t0, t1=seq.t1, valid=seq.valid, attrs=attrs)
    return BosSequence(flow=flow, q=np.asarray(seq.extras["q"]),
                       p=np.asarray(seq.extras["p"]), scalars=scalars, attrs=attrs)


@guarded('BOS HDF5')
def read_bos_h5(path: str | os.PathLike, index: int | slice | None = None) -> BosSequence:
    """Read a BOS file written by :class:`BosWriter`.

    Parameters
    ----------
    path : path-like
        The ``.h5`` file.
    index : int or slice, optional
        Which windows (default all complete windows).

    Examples
    --------
    >>> with BosWriter("bos.h5", (4, 5)) as bw:
    ...     for i in range(3):
    ...         bw.append(np.zeros((4, 5, 2)), i * 8333, (i + 1) * 8333,
    ...                   q=np.full((4, 5), i), p=np.zeros((4, 5, 2)))
    >>> bos = read_bos_h5("bos.h5")
    >>> bos.q.shape, bos.q[:, 0, 0].tolist()
    ((3, 4, 5), [0.0, 1.0, 2.0])
    """

    path = Path(path)
    f = open_h5(path)
    with f:
        root = read_attrs(path, f)
        content = root.get("content")
        if content != BOS_CONTENT:
            raise FormatError(path, f"not a BOS file (attribute content={content!r}, "
                              f"expected {BOS_CONTENT!r})")
        for name in ("q", "p"):
            if name not in f:
                raise FormatError(path, f"BOS file lacks dataset '/{name}'")
        flow = read_flow_group(f, path, index, root)
        n = int(f["t1"].shape[0])
        sel = np.arange(n)[slice(None) if index is None else index]
        sel = np.atleast_1d(sel)
        q = np.stack([f["q"][int(i)] for i in sel]) if sel.size else \
            np.zeros((0, *f["q"].shape[1:]), np.float32)
        p = np.stack([f["p"][int(i)] for i in sel]) if sel.size else \
            np.zeros((0, *f["p"].shape[1:]), np.float32)
        scalars = {k: ds[:n][sel] for k, ds in f["window"].items()} if "window" in f else {}
        attrs = dict(flow.attrs)
        attrs["q_units"] = attrs.get("extras_units", {}).get("q", "")
    return BosSequence(flow=flow, q=q, p=p, scalars=scalars, attrs=attrs)
