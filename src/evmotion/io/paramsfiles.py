"""Per-window motion parameters (``evmotion egomotion``'s ``params.h5``, ``evmotion
segment``'s ``clusters.h5``): one self-describing HDF5 table, written by
:func:`write_params_h5`, read by :func:`read_params` and summarised by
:func:`describe_params` (``evmotion info``).

Layout (one row per window, or per window and cluster)::

    /params  (N, P) float64, the warp's parameters; attributes ``names``, ``units``
    /t0_us, /t1_us (N,) int64 µs, each row's window [t0, t1)
    /valid   (N,) bool, the row is a measurement (not collapsed, not a poor fit)
    /<column> (N,) any per-row number or flag (``t_ref_us``, ``n_events``, ``cost``,
             ``collapsed``, ``poor_fit``, ``explained_share``...), attributes ``units``
             and ``meaning``
    attrs: format="evmotion-params", version, warp, grid (the pixel grid the events were
    on: distorted sensor or undistorted, see :mod:`evmotion.cli.calib`), param_names,
    param_units, units (JSON: parameter -> unit), time_units="us", valid_meaning, and the
    method's options

Examples
--------
>>> t = ParamsTable(np.array([[1.0, 2.0]]), ("vx", "vy"), ("px/s", "px/s"),
...                 np.array([0]), np.array([10_000]), np.array([True]),
...                 attrs={"warp": "translation", "grid": "sensor"})
>>> write_params_h5("params.h5", t)
>>> describe_params("params.h5")["parameters"]
{'vx': 'px/s', 'vy': 'px/s'}
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.io.h5attrs import read_attrs, read_attrs_many
from evmotion.io.h5filters import is_hdf5

__all__ = ["PARAMS_FORMAT", "ParamsTable", "describe_params", "read_params",
           "write_params_h5"]

PARAMS_FORMAT = "evmotion-params"
PARAMS_VERSION = 1
#: What ``valid`` means in every parameters file.
VALID_MEANING = "a measurement: not collapsed and not a poor fit (methods.diagnostics)"
_RESERVED = ("params", "t0_us", "t1_us", "valid")


@dataclass(frozen=True)
class ParamsTable:
    """Per-window motion parameters with their units, times, validity and checks.

    Attributes
    ----------
    params : ndarray (N, P) float64
        One row of warp parameters per window (or window and cluster).
    names, units : tuple of str
        Name and unit of each parameter (``px/s``, ``rad/s``, ``1/s``...).
    t0, t1 : ndarray (N,) int64
        Each row's window ``[t0, t1)`` in µs.
    valid : ndarray (N,) bool
        Rows that are measurements (not collapsed, not a poor fit).
    columns : dict of str to ndarray (N,)
        Other per-row values (reference time, events, cost, flags...).
    column_units : dict of str to str
        Unit of each column (``""`` for counts and flags); ``column_meanings`` the same
        for a sentence on each.
    attrs : dict
        ``warp``, ``grid`` and the method's options.
    """

    params: np.ndarray
    names: tuple
    units: tuple
    t0: np.ndarray
    t1: np.ndarray
    valid: np.ndarray
    columns: dict = field(default_factory=dict)
    column_units: dict = field(default_factory=dict)
    column_meanings: dict = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.params.shape[0])


def _check(t: ParamsTable) -> None:
    n = len(t)
    if t.params.ndim != 2 or len(t.names) != t.params.shape[1] or len(t.units) != len(t.names):
        raise ParameterError(f"params {t.params.shape} do not match {len(t.names)} names and "
                             f"{len(t.units)} units")
    reserved = sorted(set(t.columns) & set(_RESERVED))
    if reserved:
        raise ParameterError(f"column names {reserved} are reserved")
    for name, arr in (("t0", t.t0), ("t1", t.t1), ("valid", t.valid), *t.columns.items()):
        if np.shape(arr) != (n,):
            raise ParameterError(f"column '{name}' has shape {np.shape(arr)}, expected ({n},)")
    if n and np.any(np.asarray(t.t1) <= np.asarray(t.t0)):
        raise ParameterError("every window needs t1 > t0 (µs)")
    for key in ("warp", "grid"):
        if key not in t.attrs:
            raise ParameterError(f"a parameters file says its '{key}'; give attrs['{key}']")


def write_params_h5(path: str | os.PathLike, table: ParamsTable) -> None:
    """Write ``table`` to an HDF5 file (atomically), layout in the module notes.

    Examples
    --------
    >>> table = ParamsTable(np.array([[0.1, 0.0, -0.2]]), ("wx", "wy", "wz"),
    ...                     ("rad/s",) * 3, np.array([0]), np.array([10_000]),
    ...                     np.array([True]), attrs={"warp": "rotation", "grid": "sensor"})
    >>> write_params_h5("params.h5", table)
    >>> read_params("params.h5").params.tolist()
    [[0.1, 0.0, -0.2]]
    """
    import h5py

    from evmotion.utils import atomic_path

    _check(table)
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        ds = f.create_dataset("params", data=np.asarray(table.params, np.float64))
        ds.attrs["names"] = list(table.names)
        ds.attrs["units"] = list(table.units)
        for name, arr in (("t0_us", table.t0), ("t1_us", table.t1)):
            f.create_dataset(name, data=np.asarray(arr, np.int64)).attrs["units"] = "us"
        f.create_dataset("valid", data=np.asarray(table.valid, bool)).attrs["meaning"] = \
            VALID_MEANING
        for name, arr in table.columns.items():
            ds = f.create_dataset(name, data=np.asarray(arr))
            ds.attrs["units"] = table.column_units.get(name, "")
            ds.attrs["meaning"] = table.column_meanings.get(name, "")
        f.attrs["format"] = PARAMS_FORMAT
        f.attrs["version"] = PARAMS_VERSION
        f.attrs["param_names"] = list(table.names)
        f.attrs["param_units"] = list(table.units)
        f.attrs["units"] = json.dumps(dict(zip(table.names, table.units, strict=True)))
        f.attrs["time_units"] = "us"
        f.attrs["valid_meaning"] = VALID_MEANING
        for key, value in table.attrs.items():
            f.attrs[key] = "none" if value is None else value


def _text(v) -> str:
    return v.decode() if isinstance(v, bytes) else str(v)


def read_params(path: str | os.PathLike) -> ParamsTable:
    """Read a parameters file written by :func:`write_params_h5`.

    Examples
    --------
    >>> write_params_h5("params.h5", ParamsTable(
    ...     np.zeros((2, 3)), ("wx", "wy", "wz"), ("rad/s",) * 3, np.array([0, 10_000]),
    ...     np.array([10_000, 20_000]), np.array([True, False]),
    ...     attrs={"warp": "rotation", "grid": "sensor"}))
    >>> t = read_params("params.h5")
    >>> dict(zip(t.names, t.units))
    {'wx': 'rad/s', 'wy': 'rad/s', 'wz': 'rad/s'}
    """
    from evmotion.io.guard import open_h5

    path = Path(path)
    f = open_h5(path)
    with f:
        attrs = read_attrs(path, f)
        if attrs.get("format", "") != PARAMS_FORMAT:
            raise FormatError(path, f"not an evmotion parameters file (attribute format="
                              f"{attrs.get('format')!r}, expected {PARAMS_FORMAT!r})")
        for name in _RESERVED:
            if name not in f:
                raise FormatError(path, f"parameters file lacks dataset '/{name}'")
        labels = read_attrs(path, f["params"], ("names", "units"))
        if len(labels) < 2:
            raise FormatError(path, "dataset '/params' lacks attribute 'names' or 'units'")
        names = tuple(_text(v) for v in labels["names"])
        units = tuple(_text(v) for v in labels["units"])
        columns, cu, cm = {}, {}, {}
        found = {name: ds for name, ds in f.items()
                 if name not in _RESERVED and hasattr(ds, "shape")}
        texts = read_attrs_many(path, list(found.values()), ("units", "meaning"))
        for (name, ds), text in zip(found.items(), texts, strict=True):
            columns[name] = ds[()]
            cu[name] = _text(text.get("units", ""))
            cm[name] = _text(text.get("meaning", ""))
        return ParamsTable(params=f["params"][()], names=names, units=units,
                           t0=f["t0_us"][()], t1=f["t1_us"][()], valid=f["valid"][()],
                           columns=columns, column_units=cu, column_meanings=cm, attrs=attrs)


def describe_params(path: str | os.PathLike) -> dict | None:
    """What a parameters file holds (``evmotion info``), or None if ``path`` is not one.

    Returns
    -------
    dict or None
        ``format``, ``container``, ``rows``, ``windows`` (distinct), ``t_first_us``,
        ``t_last_us``, ``duration_s``, ``parameters`` (name -> unit), ``warp``, ``grid``,
        ``valid_fraction`` and ``flags`` (rows flagged per check).

    Examples
    --------
    >>> write_params_h5("params.h5", ParamsTable(
    ...     np.zeros((2, 3)), ("wx", "wy", "wz"), ("rad/s",) * 3, np.array([0, 10_000]),
    ...     np.array([10_000, 20_000]), np.array([True, False]),
    ...     attrs={"warp": "rotation", "grid": "sensor"}))
    >>> d = describe_params("params.h5")
    >>> d["warp"], d["windows"], d["valid_fraction"]
    ('rotation', 2, 0.5)
    """
    p = Path(path)
    if p.suffix.lower() not in (".h5", ".hdf5") or not p.is_file():
        return None
    if not is_hdf5(p):
        return None
    import h5py

    try:
        with h5py.File(p, "r") as f:
            if read_attrs(p, f, ("format",)).get("format", "") != PARAMS_FORMAT:
                return None
    except OSError:
        return None
    t = read_params(p)
    windows = np.unique(np.stack([t.t0, t.t1], axis=1), axis=0) if len(t) else []
    out: dict = {"path": str(p), "format": PARAMS_FORMAT, "container": "h5",
                 "rows": len(t), "windows": len(windows)}
    if len(t):
        out.update(t_first_us=int(np.min(t.t0)), t_last_us=int(np.max(t.t1)),
                   duration_s=(int(np.max(t.t1)) - int(np.min(t.t0))) * 1e-6)
    out["parameters"] = dict(zip(t.names, t.units, strict=True))
    for key in ("warp", "grid", "method", "objective", "regularizer", "source"):
        if key in t.attrs:
            out[key] = t.attrs[key]
    out["time_units"] = "us ([t0_us, t1_us) per row)"
    out["valid_fraction"] = float(np.mean(t.valid)) if len(t) else None
    out["flags"] = {k: int(np.count_nonzero(v)) for k, v in t.columns.items()
                    if np.asarray(v).dtype == bool}
    return out
