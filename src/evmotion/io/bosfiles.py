"""Schlieren (BOS) outputs: flow, Poisson field q and translation field p in one HDF5 file.

The file *is* an evmotion flow HDF5 file (:mod:`evmotion.io.flowfiles`): one window per
frame interval, so :func:`~evmotion.io.flowfiles.read_flow_h5` and ``evmotion eval`` read
its flow unchanged. Beside the flow datasets it holds::

    /q      (N, H, W)    float32, the Poisson field (v = Sobel(q)), attribute units
    /p      (N, H, W, 2) float32, px, per-pixel translation of the frame (x, y)
    /window/<name> (N,)  float64, per-window scalars (contrast threshold, loss, events...)
    attrs: content="evmotion-bos", roi=(x, y, w, h), plus the writer's attributes

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
from evmotion.io.flowfiles import FlowSequence, FlowWriter, read_flow_group
from evmotion.io.guard import open_h5

__all__ = ["BOS_CONTENT", "BosSequence", "BosWriter", "read_bos_h5", "roi_mask"]

BOS_CONTENT = "evmotion-bos"


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
    if rw <= 0 or rh <= 0 or x < 0 or y < 0 or x + rw > w or y + rh > h:
        raise ParameterError(f"roi (x={x}, y={y}, w={rw}, h={rh}) lies outside the "
                             f"{w}x{h} (W x H) sensor")
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


class BosWriter(FlowWriter):
    """Append per-interval schlieren estimates (flow, q, p) to a BOS HDF5 file.

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
    >>> with BosWriter("bos.h5", (4, 5)) as bw:  # doctest: +SKIP
    ...     bw.append(np.zeros((4, 5, 2)), 0, 8333, q=np.zeros((4, 5)),
    ...               p=np.zeros((4, 5, 2)), scalars={"loss": 0.1})
    """

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int], *,
                 roi: tuple[int, int, int, int] | None = None, attrs: dict | None = None,
                 q_units: str = "px^2/s", resume: bool = False,
                 compression: str | None = "gzip"):
        self.mask = roi_mask(sensor_size, roi)
        h, w = self.mask.shape
        all_attrs = {"content": BOS_CONTENT,
                     "roi": np.asarray(roi if roi is not None else (0, 0, w, h), np.int64),
                     **(attrs or {})}
        super().__init__(path, (h, w), with_valid=True, resume=resume, attrs=all_attrs,
                         compression=compression)
        if "q" not in self.f:
            kw = {"compression": compression} if compression else {}
            q = self.f.create_dataset("q", shape=(0, h, w), maxshape=(None, h, w),
                                      dtype="<f4", chunks=(1, h, w), **kw)
            q.attrs["units"] = q_units
            q.attrs["meaning"] = "Poisson field: flow = Sobel(q), q proportional to drho/dt"
            p = self.f.create_dataset("p", shape=(0, h, w, 2), maxshape=(None, h, w, 2),
                                      dtype="<f4", chunks=(1, h, w, 2), **kw)
            p.attrs["units"] = "px"
            p.attrs["meaning"] = "per-pixel translation (x, y) of the frame, W(x; p) = x + p"
            self.f.require_group("window")
        self._trim_partial()

    def _trim_partial(self) -> None:
        super()._trim_partial()
        n = int(self.f["t1"].shape[0])
        for name in ("q", "p"):
            if name in self.f and self.f[name].shape[0] != n:
                self.f[name].resize(n, axis=0)
        if "window" in self.f:
            for ds in self.f["window"].values():
                if ds.shape[0] != n:
                    ds.resize(n, axis=0)

    def append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray | None = None,
               *, q: np.ndarray | None = None, p: np.ndarray | None = None,
               scalars: dict | None = None) -> None:
        """Add one frame interval ``[t0, t1)`` µs: flow (H, W, 2) px/s, q (H, W), p (H, W, 2)
        px, and per-window numbers ``scalars``. Values outside the ROI are set to NaN."""
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
        f = self.f
        # q, p and scalars first: t1 (written last by FlowWriter.append) marks completion.
        for name, arr in (("q", q), ("p", p)):
            f[name].resize(n + 1, axis=0)
            f[name][n] = arr
        group = f["window"]
        for key, value in (scalars or {}).items():
            if key not in group:
                if n > 0:
                    raise ParameterError(f"scalar '{key}' was not given for the earlier "
                                         f"{n} windows")
                group.create_dataset(key, shape=(0,), maxshape=(None,), dtype="<f8",
                                     chunks=(1024,))
            group[key].resize(n + 1, axis=0)
            group[key][n] = float(value)
        missing = set(group) - set(scalars or {})
        if missing:
            raise ParameterError(f"window {n} lacks scalars {sorted(missing)}")
        super().append(flow, t0, t1, valid=self.mask if valid is None else valid & self.mask)


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
    >>> bos = read_bos_h5("bos.h5")  # doctest: +SKIP
    >>> bos.q.shape  # doctest: +SKIP
    (3, 720, 640)
    """

    path = Path(path)
    f = open_h5(path)
    with f:
        if f.attrs.get("content") != BOS_CONTENT:
            raise FormatError(path, f"not a BOS file (attribute content="
                              f"{f.attrs.get('content')!r}, expected {BOS_CONTENT!r})")
        for name in ("q", "p"):
            if name not in f:
                raise FormatError(path, f"BOS file lacks dataset '/{name}'")
        flow = read_flow_group(f, path, index)
        n = int(f["t1"].shape[0])
        sel = np.arange(n)[slice(None) if index is None else index]
        sel = np.atleast_1d(sel)
        q = np.stack([f["q"][int(i)] for i in sel]) if sel.size else \
            np.zeros((0, *f["q"].shape[1:]), np.float32)
        p = np.stack([f["p"][int(i)] for i in sel]) if sel.size else \
            np.zeros((0, *f["p"].shape[1:]), np.float32)
        scalars = {k: ds[:n][sel] for k, ds in f["window"].items()} if "window" in f else {}
        attrs = dict(flow.attrs)
        attrs["q_units"] = f["q"].attrs.get("units", "")
    return BosSequence(flow=flow, q=q, p=p, scalars=scalars, attrs=attrs)
