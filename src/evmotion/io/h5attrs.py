"""HDF5 attributes that cannot hang the process: text written with a fixed length, and
variable-length attributes read in a child process with a time limit.

A variable-length attribute (what h5py writes for a Python ``str``) keeps its bytes in a
global heap elsewhere in the file. libhdf5 walks that heap's objects by their recorded
sizes, and one corrupt size (found by fuzzing: a free-space object of size 1) sends it
into a loop that never returns, in C code that no signal or alarm can interrupt. evmotion
therefore writes its own text attributes with a fixed length (stored in the attribute
itself, no heap), and reads any variable-length attribute of a file in a forked child
that is killed after :data:`ATTR_TIMEOUT_S`.

Examples
--------
>>> import pathlib, tempfile, h5py
>>> from evmotion.io.h5attrs import read_attrs, text_attr
>>> path = pathlib.Path(tempfile.mkdtemp()) / "attrs.h5"
>>> with h5py.File(path, "w") as f:
...     f.attrs["units"] = text_attr("px/s")
...     f.attrs["note"] = "variable length"
...     f.attrs["height"] = 180
>>> with h5py.File(path, "r") as f:
...     attrs = read_attrs(path, f)
>>> attrs["units"], attrs["note"], int(attrs["height"])
('px/s', 'variable length', 180)
"""

from __future__ import annotations

import contextlib
import math
import os
import pickle
import select
import time
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from evmotion.errors import FormatError, ParameterError

__all__ = ["ATTR_TIMEOUT_S", "file_attrs", "read_attrs", "read_attrs_many", "text_attr"]

#: Seconds a child process gets to read a file's variable-length attributes (a healthy
#: read takes microseconds; the margin is for a loaded machine).
ATTR_TIMEOUT_S = 5.0


def text_attr(value: str) -> np.bytes_:
    """``value`` as a fixed-length UTF-8 HDF5 string (no global heap; see the module).

    :func:`read_attrs` gives it back as ``str``.
    """
    return np.bytes_(str(value).encode("utf-8"))


def read_attrs(path: str | os.PathLike | None, obj: Any, keys: Iterable[str] | None = None,
               timeout_s: float = ATTR_TIMEOUT_S) -> dict[str, Any]:
    """The attributes ``keys`` (default: all) of the h5py file, group or dataset ``obj``,
    text decoded to ``str``; keys that ``obj`` lacks are left out.

    Variable-length attributes are read in a forked child process, killed after
    ``timeout_s`` seconds (a corrupt global heap makes libhdf5 loop forever); fixed-length
    and numeric ones in this process.

    Parameters
    ----------
    path : path-like or None
        The file, for the error message.
    obj : h5py.File, h5py.Group or h5py.Dataset
    keys : iterable of str, optional
    timeout_s : float
        Time limit of the child process, seconds.

    Raises
    ------
    FormatError
        An attribute cannot be read (corrupt file), naming the file and the attribute.
    """
    return read_attrs_many(path, [obj], keys, timeout_s)[0]


def file_attrs(path: str | os.PathLike, keys: Iterable[str] | None = None) -> dict[str, Any]:
    """The attributes ``keys`` (default: all) of the root of the HDF5 file ``path``, as
    :func:`read_attrs` reads them.

    Raises
    ------
    FormatError
        The file does not open as HDF5 (HDF5's reason, in one line).
    """
    import h5py

    from evmotion.io.guard import not_hdf5

    try:
        with h5py.File(path, "r") as f:
            return read_attrs(path, f, keys)
    except OSError as exc:
        raise not_hdf5(path, exc) from None


def read_attrs_many(path: str | os.PathLike | None, objs: Sequence[Any],
                    keys: Iterable[str] | None = None,
                    timeout_s: float = ATTR_TIMEOUT_S) -> list[dict[str, Any]]:
    """:func:`read_attrs` of several objects of one file (the same ``keys`` of each), with
    one child process for all their variable-length attributes: a reader that needs the
    attributes of every dataset of a group forks once, not once a dataset.

    Returns
    -------
    list of dict
        One per object, in the order of ``objs``.
    """
    if not isinstance(timeout_s, (int, float)) or not math.isfinite(timeout_s) \
            or timeout_s <= 0:
        raise ParameterError(f"timeout_s must be a finite number > 0 s, got {timeout_s!r}")
    path = None if path is None else Path(path)
    keys = None if keys is None else list(keys)
    names = [_names(path, obj, keys) for obj in objs]
    out = [{k: _read_one(path, obj, k) for k in ks if not _variable_length(obj, k)}
           for obj, ks in zip(objs, names, strict=True)]
    heap = [(i, obj, [k for k in ks if k not in got])
            for i, (obj, ks, got) in enumerate(zip(objs, names, out, strict=True))]
    heap = [job for job in heap if job[2]]
    if heap:
        jobs = [(obj, ks) for _, obj, ks in heap]
        values = _read_in_child(path, jobs, timeout_s) if hasattr(os, "fork") else \
            [{k: _read_one(path, obj, k) for k in ks} for obj, ks in jobs]
        for (i, _, _), value in zip(heap, values, strict=True):
            out[i].update(value)
    return [{k: got[k] for k in ks} for got, ks in zip(out, names, strict=True)]


def _names(path: Path | None, obj: Any, keys: list[str] | None) -> list[str]:
    try:
        return list(obj.attrs) if keys is None else [k for k in keys if k in obj.attrs]
    except (OSError, RuntimeError, KeyError, ValueError) as exc:
        raise FormatError(path, f"cannot list the attributes of '{obj.name}': {exc}") from None


def _variable_length(obj: Any, key: str) -> bool:
    import h5py

    try:
        tid = obj.attrs.get_id(key).get_type()
    except (OSError, RuntimeError, KeyError, ValueError):
        return True  # unreadable metadata: let the guarded read report it
    if isinstance(tid, h5py.h5t.TypeStringID):
        return bool(tid.is_variable_str())
    # compound and array types may hold variable-length members
    return isinstance(tid, (h5py.h5t.TypeVlenID, h5py.h5t.TypeCompoundID,
                            h5py.h5t.TypeArrayID))


def _read_one(path: Path | None, obj: Any, key: str) -> Any:
    try:
        value = obj.attrs[key]
    except (OSError, RuntimeError, KeyError, ValueError, TypeError, MemoryError) as exc:
        raise FormatError(path, f"cannot read attribute '{key}' of '{obj.name}' (corrupt "
                          f"file?): {exc}") from None
    return _decoded(value)


def _decoded(value: Any) -> Any:
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray) and value.dtype.kind in "SO":
        return np.array([_decoded(v) for v in value.ravel()], dtype=object).reshape(
            value.shape)
    return value


def _read_in_child(path: Path | None, jobs: list[tuple[Any, list[str]]],
                   timeout_s: float) -> list[dict]:
    r, w = os.pipe()
    with _h5py_lock():
        # Holding h5py's lock across fork: a lock held by another thread at that moment
        # would stay locked forever in the child.
        pid = os.fork()
    if pid == 0:  # the child: read, send, exit without running the parent's clean-up
        code = 0
        try:
            os.close(r)
            try:
                payload = ("ok", [{k: _read_one(path, obj, k) for k in keys}
                                  for obj, keys in jobs])
            except FormatError as exc:
                payload = ("error", exc.message)
            data = pickle.dumps(payload, protocol=pickle.HIGHEST_PROTOCOL)
            view = memoryview(data)
            while view:
                view = view[os.write(w, view):]
        except BaseException:
            code = 1
        finally:
            os._exit(code)
    os.close(w)
    chunks, deadline, done = [], time.monotonic() + timeout_s, False
    try:
        while not done:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([r], [], [], left)[0]:
                break
            chunk = os.read(r, 1 << 16)
            chunks.append(chunk)
            done = not chunk
    finally:
        os.close(r)
        if not done:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, 9)
        os.waitpid(pid, 0)
    names = "; ".join(", ".join(f"'{k}'" for k in keys) + f" of '{obj.name}'"
                      for obj, keys in jobs)
    if not done:
        raise FormatError(path, f"reading attribute {names} did not finish in {timeout_s:g} "
                          "s (corrupt variable-length data)")
    try:
        status, value = pickle.loads(b"".join(chunks))
    except Exception:  # a child that died mid-write leaves any bytes
        raise FormatError(path, f"cannot read attribute {names} (corrupt file?)") from None
    if status != "ok":
        raise FormatError(path, value)
    return value


def _h5py_lock():
    try:
        from h5py._objects import phil
    except ImportError:
        return contextlib.nullcontext()
    return phil
