"""One output layer for dense flow: every method and command writes its windows here.

:func:`open_flow_output` picks the container by the file name and returns a sink with
``append(flow, t0, t1, valid)``, ``close()`` and ``abort()``; :func:`read_flow` reads any
of them back as a :class:`~evmotion.io.flowfiles.FlowSequence` with its windows' times and
validity masks, and :func:`describe_flow` summarises one (``evmotion info``).

Every container says its units, each window's ``[t0, t1)`` (µs) and its validity mask
(the pixels whose flow events support):

=================  ===========================================================================
``.h5``            the reference: ``flow`` (N, H, W, 2) float32 **px/s**, ``t0``/``t1`` (N,)
                   int64 µs, ``valid`` (N, H, W) bool; attributes ``units``, ``grid``,
                   ``method`` and the method's options. Written window by window to
                   ``OUT.part``, renamed when complete, resumable (``resume=True``).
``.npz``           the same arrays (``flow`` px/s, ``t0``, ``t1``, ``valid``) with ``units``,
                   ``format`` and ``attrs`` (JSON); windows spooled to a hidden temporary file
                   and stored (uncompressed) when complete.
``.flo``           Middlebury **displacement** in px over the window (the convention of the
                   format), unknown (1e10) where not valid; ``NAME.flo.json`` beside it holds
                   ``t0_us``, ``t1_us``, ``dt_s``, ``units`` and the attributes.
``.png``           DSEC 16-bit flow PNG: **displacement** in px (``v · 128 + 2^15``, ±256 px,
                   1/128 px steps), third channel the valid flag; ``NAME.png.json`` beside it
                   as for ``.flo``.
=================  ===========================================================================

``.flo`` and ``.png`` hold one window per file: several windows need an explicit pattern
(``flow_{:05d}.flo``, formatted with the window index from 0); a plain name with several
windows is an error, never a silent rename. A bare ``.npy`` (no times, units or mask) is
refused in favour of ``.npz``.

Writes are atomic: per-window files are written into a hidden ``.NAME.*.part`` folder and
moved into place by ``close()``; an interrupted or failed run leaves no file that looks
complete (only a ``.part`` file or folder, which ``abort()`` removes except for a
resumable ``.h5``).

Examples
--------
>>> with open_flow_output("flow.npz", (180, 240), {"method": "multicm"}) as out:  # doctest: +SKIP
...     out.append(np.zeros((180, 240, 2), np.float32), t0=0, t1=10_000)
>>> read_flow("flow.npz").t1  # doctest: +SKIP
array([10000])
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.io.base import PartFileWriter
from evmotion.io.flowfiles import (
    FLOW_FORMAT,
    FlowSequence,
    FlowWriter,
    read_dsec_flow_png,
    read_flo,
    read_flow_h5,
    read_mvsec_gt_flow,
    write_dsec_flow_png,
    write_flo,
)
from evmotion.utils import atomic_path

__all__ = [
    "CONTAINERS",
    "FlowOutput",
    "H5FlowOutput",
    "NpzFlowOutput",
    "PerWindowFlowOutput",
    "check_flow_output",
    "describe_flow",
    "flow_container",
    "open_flow_output",
    "read_flow",
    "window_path",
]

#: File suffix -> container name.
CONTAINERS = {".h5": "h5", ".hdf5": "h5", ".npz": "npz", ".flo": "flo", ".png": "png"}
#: Containers holding one window per file.
PER_WINDOW = ("flo", "png")
SIDECAR_FORMAT = "evmotion-flow-window"
#: What the validity mask of every output means.
VALID_MEANING = "pixels whose flow events support"
#: Pixel grid of the flow when the caller does not say (the recording's, as read).
DEFAULT_GRID = "sensor"


# ---------------------------------------------------------------------------- names
def flow_container(path: str | os.PathLike) -> str:
    """Container of a flow output named ``path``: ``"h5"``, ``"npz"``, ``"flo"`` or
    ``"png"``; a ParameterError naming the file otherwise (``.npy`` points to ``.npz``).

    Examples
    --------
    >>> flow_container("out/flow_{:05d}.flo")
    'flo'
    """
    suffix = Path(path).suffix.lower()
    if suffix == ".npy":
        raise ParameterError(f"{os.fspath(path)}: a bare .npy holds no times, units or "
                             "validity mask; write .npz (flow, t0, t1, valid, units) instead")
    kind = CONTAINERS.get(suffix)
    if kind is None:
        raise ParameterError(f"{os.fspath(path)}: not a flow output name; use .h5, .npz, "
                             ".flo or .png (DSEC 16-bit)")
    return kind


def _is_pattern(path: Path) -> bool:
    return "{" in path.name


def window_path(pattern: str | os.PathLike, index: int) -> Path:
    """File of window ``index`` for a per-window ``pattern`` (``str.format`` of its name).

    Examples
    --------
    >>> window_path("out/flow_{:05d}.flo", 12).name
    'flow_00012.flo'
    """
    p = Path(pattern)
    try:
        name = p.name.format(index)
    except (IndexError, KeyError, ValueError) as exc:
        raise ParameterError(f"{os.fspath(pattern)}: not a file-name pattern for window "
                             f"numbers ({exc}); write e.g. flow_{{:05d}}{p.suffix}") from None
    return p.with_name(name)


def _several(path: Path, n: int | str) -> str:
    return (f"{os.fspath(path)}: {n} windows but one {path.suffix} file; give a pattern that "
            f"numbers them, e.g. {path.stem}_{{:05d}}{path.suffix}")


def check_flow_output(path: str | os.PathLike, n_windows: int | None = None) -> str:
    """Check a flow output name before any work; return its container.

    Per-window containers (``.flo``, ``.png``) take a pattern (``flow_{:05d}.flo``) for
    several windows, and a plain name for one; ``.h5`` and ``.npz`` hold every window and
    take no pattern. ``n_windows`` (when known) checks a plain per-window name.

    Examples
    --------
    >>> check_flow_output("flow_{:05d}.png", n_windows=3)
    'png'
    >>> check_flow_output("flow.flo", n_windows=3)
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: flow.flo: 3 windows but one .flo file; give a pattern that numbers them, e.g. flow_{:05d}.flo
    """
    p = Path(path)
    kind = flow_container(p)
    if "{" in os.fspath(p.parent):
        raise ParameterError(f"{os.fspath(p)}: a pattern numbers files, not folders; put "
                             "'{...}' in the file name only")
    if _is_pattern(p):
        if kind not in PER_WINDOW:
            raise ParameterError(f"{os.fspath(p)}: a {p.suffix} file holds every window; "
                                 "give a plain name without '{...}'")
        if window_path(p, 0) == window_path(p, 1):
            raise ParameterError(f"{os.fspath(p)}: the pattern must number the windows, "
                                 f"e.g. {p.stem.split('{')[0]}{{:05d}}{p.suffix}")
    elif kind in PER_WINDOW and n_windows is not None and n_windows > 1:
        raise ParameterError(_several(p, n_windows))
    return kind


def _attrs(attrs: dict | None) -> dict:
    out = dict(attrs or {})
    out.setdefault("grid", DEFAULT_GRID)
    out.setdefault("valid_meaning", VALID_MEANING)
    return out


def _jsonable(value):
    if isinstance(value, bytes):
        return value.decode(errors="replace")
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


# ---------------------------------------------------------------------------- sinks
class FlowOutput(PartFileWriter):
    """A flow output being written: ``append`` windows in time order, then ``close``
    (complete and in place) or ``abort`` (nothing that looks complete is left).

    Attributes
    ----------
    path : Path
        The output name given (a pattern for per-window files).
    container : str
        ``"h5"``, ``"npz"``, ``"flo"`` or ``"png"``.
    done : list of (int, int)
        ``(t0, t1)`` µs of the windows a resumed ``.h5`` already holds (else empty): the
        caller delimits them again (:meth:`check_done`) but does not recompute them.
    """

    container = ""

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int], attrs: dict):
        self.path = Path(path)
        h, w = (int(v) for v in sensor_size)
        if h <= 0 or w <= 0:
            raise ParameterError(f"sensor_size must be positive (height, width), got {(h, w)}")
        self.sensor_size = (h, w)
        self.attrs = _attrs(attrs)
        self.done: list[tuple[int, int]] = []
        self.n_written = 0

    def _checked(self, flow, t0: int, t1: int, valid) -> tuple[np.ndarray, np.ndarray]:
        arr = np.ascontiguousarray(flow, dtype=np.float32)
        if arr.shape != (*self.sensor_size, 2):
            raise ParameterError(f"{self.path}: flow has shape {arr.shape}, this output holds "
                                 f"{(*self.sensor_size, 2)}")
        if int(t1) <= int(t0):
            raise ParameterError(f"{self.path}: window end t1={t1} us is not after "
                                 f"t0={t0} us")
        if valid is None:
            valid = np.isfinite(arr).all(axis=2)
        v = np.asarray(valid, dtype=bool)
        if v.shape != self.sensor_size:
            raise ParameterError(f"{self.path}: valid has shape {v.shape}, expected "
                                 f"{self.sensor_size}")
        return arr, v

    def append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray | None = None
               ) -> None:
        """Add one window: ``flow`` (H, W, 2) px/s over ``[t0, t1)`` µs, ``valid`` (H, W)
        bool (default: where the flow is finite)."""
        arr, v = self._checked(flow, t0, t1, valid)
        self._append(arr, int(t0), int(t1), v)
        self.n_written += 1

    def _append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray) -> None:
        raise NotImplementedError

    def close(self) -> list[Path]:
        """Complete the output; return the files written."""
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError

    def check_count(self, n_windows: int) -> None:
        """The run makes ``n_windows``: a resumed output must not hold more."""
        if len(self.done) > n_windows:
            self.abort()
            raise ParameterError(f"cannot resume (--resume): {self.path} holds "
                                 f"{len(self.done)} windows, this run makes {n_windows}; "
                                 "repeat the options of the first run, or start again")

    def check_done(self, index: int, t0: int, t1: int) -> None:
        """Raise ParameterError if window ``index`` of this run is not the ``index``-th
        window of the resumed output (other windowing options, or another recording)."""
        if index >= len(self.done):
            self.abort()
            raise ParameterError(f"cannot resume (--resume): this run skipped window {index}, "
                                 f"which {self.path} does not hold")
        if (int(t0), int(t1)) != tuple(self.done[index]):
            self.abort()
            a, b = self.done[index]
            raise ParameterError(f"cannot resume (--resume): window {index} of {self.path} is "
                                 f"[{a}, {b}) µs but this run makes [{t0}, {t1}) µs; repeat "
                                 "the windowing options of the first run, or start again")


class H5FlowOutput(FlowOutput):
    """``.h5`` output written window by window to ``OUT.part``
    (:class:`~evmotion.io.flowfiles.FlowWriter`), renamed when complete, resumable.

    With ``resume`` it continues ``OUT.part`` (or a finished OUT) after checking that it
    was made with the same ``attrs`` (method, options, source); :attr:`done` lists the
    windows it already holds. :meth:`abort` keeps the ``.part`` file for a later resume
    (and puts back a finished OUT it had reopened). ``compression`` goes to FlowWriter.
    """

    container = "h5"

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int],
                 attrs: dict | None = None, *, resume: bool = False, with_valid: bool = True,
                 compression: str | None = "gzip"):
        super().__init__(path, sensor_size, attrs or {})
        attrs = self.attrs
        self.part = self.path.with_name(self.path.name + ".part")  # FlowWriter's own name
        self.reopened_final = resume and self.path.exists() and not self.part.exists()
        if not resume:
            self.w = FlowWriter(self.path, self.sensor_size, with_valid=with_valid,
                                attrs=attrs, compression=compression)
            return
        self.w = FlowWriter(self.path, self.sensor_size, with_valid=with_valid, resume=True)
        old = dict(self.w.f.attrs)
        for key, value in attrs.items():
            if self.w.n_done and key in old and not _same(old[key], value):
                self.abort()
                raise ParameterError(f"cannot resume (--resume): {self.part} was made with "
                                     f"{key}={_jsonable(old[key])!r}, this run has {value!r}; "
                                     "repeat the options of the first run, or start again")
            self.w.f.attrs[key] = value
        if self.w.with_valid != with_valid:
            self.abort()
            raise ParameterError(f"cannot resume (--resume): {self.part} has another layout "
                                 f"(valid masks: {self.w.with_valid}); start again")
        t1 = np.asarray(self.w.f["t1"][: self.w.n_done])
        self.done = list(zip(np.asarray(self.w.done_t0).tolist(), t1.tolist(), strict=True))

    def stored_flow(self, index: int) -> np.ndarray:
        """Flow (H, W, 2) float32 px/s of a window already in the file, as written."""
        return np.asarray(self.w.f["flow"][index])

    def append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray | None = None
               ) -> None:
        """Add one window (see :meth:`FlowOutput.append`)."""
        if not self.w.with_valid:  # a file made without masks (FlowWriter's choice)
            self.w.append(flow, t0, t1)
        else:
            self.w.append(flow, t0, t1, valid=valid)
        self.n_written += 1

    def close(self) -> list[Path]:
        self.w.close()
        return [self.path]

    def abort(self) -> None:
        self.w.abort()
        if self.reopened_final and self.part.exists():
            os.replace(self.part, self.path)
            self.reopened_final = False


def _same(a, b) -> bool:
    a = _jsonable(a)
    try:
        return bool(np.array_equal(np.asarray(a), np.asarray(b)))
    except (TypeError, ValueError):
        return str(a) == str(b)


class NpzFlowOutput(FlowOutput):
    """``.npz`` output: windows spooled to hidden temporary files (bounded memory), stored
    as ``flow`` (N, H, W, 2) float32 px/s, ``valid`` (N, H, W) bool, ``t0``/``t1`` (N,)
    int64 µs, ``units``, ``format`` and ``attrs`` (a JSON string) when complete."""

    container = "npz"

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int],
                 attrs: dict | None = None):
        super().__init__(path, sensor_size, attrs or {})
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        spool = dict(dir=self.path.parent, prefix=f".{self.path.name}.")
        # unnamed temporary files: the system removes them whatever ends the process
        self._flow = tempfile.TemporaryFile(suffix=".flow.part", **spool)
        self._valid = tempfile.TemporaryFile(suffix=".valid.part", **spool)
        self._t0: list[int] = []
        self._t1: list[int] = []

    def _append(self, flow, t0, t1, valid) -> None:
        self._flow.write(flow.astype("<f4", copy=False).tobytes())
        self._valid.write(valid.tobytes())
        self._t0.append(t0)
        self._t1.append(t1)

    def close(self) -> list[Path]:
        if self._ctx is None:
            return [self.path]
        n, (h, w) = len(self._t1), self.sensor_size
        small = {"t0": np.asarray(self._t0, "<i8"), "t1": np.asarray(self._t1, "<i8"),
                 "units": np.asarray("px/s"), "format": np.asarray(FLOW_FORMAT),
                 "attrs": np.asarray(json.dumps({k: _jsonable(v)
                                                  for k, v in self.attrs.items()}))}
        with zipfile.ZipFile(self._tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            for name, spool, dtype, shape in (("flow", self._flow, "<f4", (n, h, w, 2)),
                                              ("valid", self._valid, "|b1", (n, h, w))):
                spool.seek(0)
                with zf.open(f"{name}.npy", "w", force_zip64=True) as dst:
                    np.lib.format.write_array_header_1_0(
                        dst, {"descr": dtype, "fortran_order": False, "shape": shape})
                    shutil.copyfileobj(spool, dst, 1 << 22)
                spool.close()
            for name, arr in small.items():
                with zf.open(f"{name}.npy", "w") as dst:
                    np.lib.format.write_array(dst, arr, allow_pickle=False)
        self._ctx.__exit__(None, None, None)
        self._ctx = None
        return [self.path]

    def abort(self) -> None:
        if self._ctx is None:
            return
        self._flow.close()
        self._valid.close()
        err = RuntimeError("aborted")
        self._ctx.__exit__(type(err), err, None)  # removes the temporary file
        self._ctx = None


class PerWindowFlowOutput(FlowOutput):
    """``.flo`` / ``.png`` output, one displacement file per window (a plain name for one
    window, a pattern such as ``flow_{:05d}.flo`` for several), each with a JSON sidecar
    ``NAME.json`` (``t0_us``, ``t1_us``, ``dt_s``, ``units``, attributes). The files go
    to a hidden ``.part`` folder and are moved into place by :meth:`close`, which also
    removes the files a previous, longer run left under the same pattern."""

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int],
                 attrs: dict | None = None, *, n_windows: int | None = None):
        super().__init__(path, sensor_size, attrs or {})
        self.container = check_flow_output(self.path, n_windows)
        self.pattern = _is_pattern(self.path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        stem = self.path.name.split("{")[0] or "flow"
        self.stage: Path | None = Path(tempfile.mkdtemp(prefix=f".{stem}.", suffix=".part",
                                                        dir=self.path.parent))
        self.files: list[Path] = []

    def _append(self, flow, t0, t1, valid) -> None:
        i = len(self.files)
        if not self.pattern and i >= 1:
            raise ParameterError(_several(self.path, "several"))
        final = window_path(self.path, i) if self.pattern else self.path
        dt_s = (t1 - t0) * 1e-6
        tmp = self.stage / final.name
        if self.container == "flo":
            write_flo(tmp, flow, dt_s=dt_s, valid=valid)
            units, how = "px", "Middlebury unknown (1e10) where not valid"
        else:
            write_dsec_flow_png(tmp, flow * np.float32(dt_s), valid)
            units, how = "px", "third channel 0 where not valid"
        side = {"format": SIDECAR_FORMAT, "version": 1,
                "container": "middlebury-flo" if self.container == "flo" else "dsec-png",
                "file": final.name, "index": i, "t0_us": t0, "t1_us": t1, "dt_s": dt_s,
                "units": units, "quantity": "displacement over [t0_us, t1_us) (flow px/s "
                "times dt_s)", "height": self.sensor_size[0], "width": self.sensor_size[1],
                "valid": f"{self.attrs['valid_meaning']}; {how}",
                "valid_fraction": float(valid.mean()),
                "attrs": {k: _jsonable(v) for k, v in self.attrs.items()}}
        (self.stage / (final.name + ".json")).write_text(json.dumps(side, indent=1))
        self.files.append(final)

    def close(self) -> list[Path]:
        if self.stage is None:
            return list(self.files)
        for final in self.files:
            os.replace(self.stage / final.name, final)
            os.replace(self.stage / (final.name + ".json"), _sidecar(final))
        if self.pattern:  # a previous, longer run's windows are not this run's
            i = len(self.files)
            while (stale := window_path(self.path, i)).exists():
                stale.unlink()
                _sidecar(stale).unlink(missing_ok=True)
                i += 1
        shutil.rmtree(self.stage, ignore_errors=True)
        self.stage = None
        return list(self.files)

    def abort(self) -> None:
        if self.stage is not None:
            shutil.rmtree(self.stage, ignore_errors=True)
            self.stage = None


def open_flow_output(path: str | os.PathLike, sensor_size: tuple[int, int],
                     attrs: dict | None = None, *, resume: bool = False,
                     n_windows: int | None = None, compression: str | None = "gzip"
                     ) -> FlowOutput:
    """Open a dense flow output; the container follows the name (see the module notes).

    Parameters
    ----------
    path : path-like
        ``.h5``, ``.npz``, ``.flo`` or ``.png``; a pattern such as ``flow_{:05d}.flo``
        for several windows into per-window files.
    sensor_size : (int, int)
        ``(height, width)`` of every flow field.
    attrs : dict, optional
        Metadata stored with the flow (``method`` and its options, ``source``, ``grid``;
        ``grid`` defaults to ``"sensor"``: the recording's pixels, not undistorted).
    resume : bool
        ``.h5`` only: continue an interrupted run's ``OUT.part``.
    n_windows : int, optional
        Number of windows, when known: a plain per-window name is refused for several.
    compression : str or None
        ``.h5`` only: the flow dataset's filter (see :class:`FlowWriter`).

    Returns
    -------
    FlowOutput
        ``append(flow, t0, t1, valid)`` each window (flow px/s, times µs), then
        ``close()``; or use it as a context manager (an exception aborts it).

    Examples
    --------
    >>> with open_flow_output("flow_{:05d}.flo", (4, 5), {"method": "x"}) as out:  # doctest: +SKIP
    ...     out.append(np.ones((4, 5, 2), np.float32), t0=0, t1=10_000)
    """
    kind = check_flow_output(path, n_windows)
    if resume and kind != "h5":
        raise ParameterError(f"{os.fspath(path)}: only an .h5 output can be resumed (a "
                             f".{kind} output is written whole at the end)")
    if kind == "h5":
        return H5FlowOutput(path, sensor_size, attrs, resume=resume, compression=compression)
    if kind == "npz":
        return NpzFlowOutput(path, sensor_size, attrs)
    return PerWindowFlowOutput(path, sensor_size, attrs, n_windows=n_windows)


# ---------------------------------------------------------------------------- reading
def _sidecar(path: Path) -> Path:
    return path.with_name(path.name + ".json")


def _read_sidecar(path: Path) -> dict | None:
    side = _sidecar(path)
    if not side.exists():
        return None
    try:
        doc = json.loads(side.read_text())
    except (OSError, ValueError) as exc:
        raise FormatError(side, f"cannot read the flow sidecar: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != SIDECAR_FORMAT:
        raise FormatError(side, f"not an evmotion flow sidecar (format "
                          f"{doc.get('format') if isinstance(doc, dict) else None!r})")
    for key in ("t0_us", "t1_us"):
        if not isinstance(doc.get(key), int):
            raise FormatError(side, f"field '{key}' is {doc.get(key)!r}, expected an integer "
                              "in µs")
    if doc["t1_us"] <= doc["t0_us"]:
        raise FormatError(side, f"t1_us {doc['t1_us']} is not after t0_us {doc['t0_us']}")
    return doc


def _read_one_window(path: Path, t0_us: int | None, t1_us: int | None) -> FlowSequence:
    kind = CONTAINERS[path.suffix.lower()]
    if not path.is_file():
        raise FormatError(path, "no such file")
    side = _read_sidecar(path)
    if side is not None:
        if t0_us is not None or t1_us is not None:
            raise ParameterError(f"{path}: carries its window's times in "
                                 f"{_sidecar(path).name}; give no interval")
        t0_us, t1_us = side["t0_us"], side["t1_us"]
    elif t0_us is None or t1_us is None or t1_us <= t0_us:
        raise ParameterError(f"{path}: no {_sidecar(path).name} beside it, so no time "
                             "interval; give t0/t1 in µs (t1 > t0)")
    if kind == "flo":
        disp = read_flo(path)
        valid = np.isfinite(disp).all(axis=2)
    else:
        disp, valid = read_dsec_flow_png(path)
    flow = disp / np.float32((t1_us - t0_us) * 1e-6)
    attrs = dict(side.get("attrs", {})) if side else {}
    attrs.update(container="middlebury-flo" if kind == "flo" else "dsec-png",
                 units="px/s", stored_units="px")
    return FlowSequence(flow=flow[None], t0=np.array([t0_us], np.int64),
                        t1=np.array([t1_us], np.int64), valid=valid[None], attrs=attrs)


def _pattern_files(path: Path) -> list[Path]:
    files = []
    while (p := window_path(path, len(files))).exists():
        files.append(p)
    if not files:
        raise FormatError(path, f"no file of this pattern (looked for {window_path(path, 0)})")
    return files


def _read_npz(path: Path) -> FlowSequence:
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise FormatError(path, f"cannot read as .npz: {exc}") from None
    with z:
        names = set(z.files)
        if "format" in names and str(z["format"]) == FLOW_FORMAT:
            for key in ("flow", "t0", "t1", "valid", "units"):
                if key not in names:
                    raise FormatError(path, f"evmotion flow .npz lacks array '{key}'")
            flow, t0, t1 = z["flow"], z["t0"].astype(np.int64), z["t1"].astype(np.int64)
            valid = z["valid"].astype(bool)
            n = t1.shape[0]
            if flow.shape[0] != n or valid.shape != flow.shape[:3] or t0.shape != (n,):
                raise FormatError(path, f"inconsistent shapes: flow {flow.shape}, valid "
                                  f"{valid.shape}, t0 {t0.shape}, t1 {t1.shape}")
            try:
                attrs = json.loads(str(z["attrs"])) if "attrs" in names else {}
            except ValueError as exc:
                raise FormatError(path, f"array 'attrs' is not JSON: {exc}") from None
            attrs.update(format=FLOW_FORMAT, units=str(z["units"]), container="npz")
            return FlowSequence(flow=flow.astype(np.float32), t0=t0, t1=t1, valid=valid,
                                attrs=attrs)
        if {"timestamps", "x_flow_dist"} <= names:
            return read_mvsec_gt_flow(path)
        if {"t", "x", "y", "vx", "vy"} <= names:
            raise FormatError(path, "per-event flow (t, x, y, vx, vy per event), not dense "
                              "windows: read it with numpy.load")
    raise FormatError(path, f"not an evmotion flow .npz (arrays: {', '.join(sorted(names))})")


def read_flow(path: str | os.PathLike, *, t0_us: int | None = None,
              t1_us: int | None = None) -> FlowSequence:
    """Read dense flow back from any container, with its windows' times and masks.

    Parameters
    ----------
    path : path-like
        ``.h5`` (evmotion flow, BOS or simulator ground truth), ``.npz`` (evmotion flow or
        MVSEC ground truth), ``.flo``, DSEC ``.png``, or a per-window pattern
        (``flow_{:05d}.flo``: the files numbered from 0, in order).
    t0_us, t1_us : int, optional
        The interval of a single ``.flo`` / ``.png`` that has no JSON sidecar.

    Returns
    -------
    FlowSequence
        ``flow`` (N, H, W, 2) float32 in **px/s** whatever the container stores
        (``.flo``/``.png`` displacements are divided by their window's duration), ``t0``,
        ``t1`` (N,) µs, ``valid`` (N, H, W) bool.

    Examples
    --------
    >>> seq = read_flow("flow_{:05d}.flo")  # doctest: +SKIP
    >>> seq.t0[:2], seq.valid.mean()  # doctest: +SKIP
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix == ".npy":
        raise FormatError(p, "a bare .npy holds no times, units or validity mask; evmotion "
                          "writes .npz (flow, t0, t1, valid, units)")
    kind = CONTAINERS.get(suffix)
    if kind is None:
        raise FormatError(p, "not a flow file: expected .h5, .npz, .flo or .png (DSEC)")
    if _is_pattern(p):
        if kind not in PER_WINDOW:
            raise ParameterError(f"{p}: a {suffix} file holds every window; no pattern")
        seqs = [_read_one_window(f, None, None) for f in _pattern_files(p)]
        return FlowSequence(flow=np.concatenate([s.flow for s in seqs]),
                            t0=np.concatenate([s.t0 for s in seqs]),
                            t1=np.concatenate([s.t1 for s in seqs]),
                            valid=np.concatenate([s.valid for s in seqs]),
                            attrs=seqs[0].attrs)
    if kind in PER_WINDOW:
        return _read_one_window(p, t0_us, t1_us)
    if t0_us is not None or t1_us is not None:
        raise ParameterError(f"{p}: a {suffix} flow file carries its windows' times; give no "
                             "interval")
    if kind == "npz":
        if not p.is_file():
            raise FormatError(p, "no such file")
        return _read_npz(p)
    seq = read_flow_h5(p)
    if seq.valid is None:
        seq = FlowSequence(flow=seq.flow, t0=seq.t0, t1=seq.t1,
                           valid=np.isfinite(seq.flow).all(axis=3), attrs=seq.attrs)
    return seq


def describe_flow(path: str | os.PathLike) -> dict | None:
    """What a flow output holds (``evmotion info``), or None if ``path`` is not one.

    Returns
    -------
    dict or None
        ``format``, ``container``, ``sensor_size`` (H, W), ``windows``, ``t_first_us``,
        ``t_last_us``, ``duration_s``, ``units`` (as stored), ``grid``, ``method``,
        ``valid_fraction`` (over all windows) and ``files`` for a pattern; per-event
        ``.npz`` files give ``events`` instead of windows.

    Examples
    --------
    >>> describe_flow("flow.h5")["windows"]  # doctest: +SKIP
    2
    """
    p = Path(path)
    kind = CONTAINERS.get(p.suffix.lower())
    if kind is None:
        return None
    if _is_pattern(p):
        if kind not in PER_WINDOW or not window_path(p, 0).exists():
            return None
    elif not p.is_file():
        return None
    if kind == "h5":
        return _describe_h5(p)
    if kind == "npz":
        return _describe_npz(p)
    if not _is_pattern(p) and _read_sidecar(p) is None:
        if kind == "png" and not _is_dsec_png(p):
            return None
    seq = read_flow(p) if _is_pattern(p) or _read_sidecar(p) else _read_undated(p)
    out = {"path": str(p), "format": "middlebury-flo" if kind == "flo" else "dsec-flow-png",
           "container": kind}
    if _is_pattern(p):
        out["files"] = len(seq)
    out.update(_summary(seq.flow.shape[1:3], seq.t0, seq.t1, seq.valid, seq.attrs))
    out["units"] = "px (displacement over each window)"
    return out


def _read_undated(p: Path) -> FlowSequence:
    """A .flo / .png without a sidecar: no times (shown as such)."""
    if p.suffix.lower() == ".flo":
        disp = read_flo(p)
        valid = np.isfinite(disp).all(axis=2)
    else:
        disp, valid = read_dsec_flow_png(p)
    return FlowSequence(flow=disp[None], t0=np.zeros(0, np.int64), t1=np.zeros(0, np.int64),
                        valid=valid[None], attrs={})


def _is_dsec_png(p: Path) -> bool:
    import png

    try:
        _, _, _, info = png.Reader(filename=str(p)).read()
    except (png.Error, OSError, ValueError):
        return False
    return info.get("bitdepth") == 16 and info.get("planes", 1) >= 3


def _summary(size, t0, t1, valid_fraction_or_mask, attrs) -> dict:
    out: dict = {"sensor_size": [int(size[0]), int(size[1])], "windows": int(len(t0))}
    if len(t0):
        out.update(t_first_us=int(t0[0]), t_last_us=int(t1[-1]),
                   duration_s=(int(t1[-1]) - int(t0[0])) * 1e-6)
    else:
        out["times"] = "none stored (no JSON sidecar)"
    vf = valid_fraction_or_mask
    if isinstance(vf, np.ndarray):
        vf = float(vf.mean()) if vf.size else None
    out["valid_fraction"] = vf
    for key in ("grid", "method", "source"):
        if key in attrs:
            out[key] = _jsonable(attrs[key])
    return out


def _describe_h5(p: Path) -> dict | None:
    import h5py

    with open(p, "rb") as fh:
        if not fh.read(8).startswith(b"\x89HDF\r\n\x1a\n"):
            return None
    try:
        f = h5py.File(p, "r")
    except OSError:
        return None
    with f:
        if _jsonable(f.attrs.get("format")) != FLOW_FORMAT or "t1" not in f:
            return None
        n = int(f["t1"].shape[0])
        t0, t1 = f["t0"][:n], f["t1"][:n]
        vf = None
        if "valid" in f and n:
            vf = float(sum(int(np.count_nonzero(f["valid"][i])) for i in range(n))
                       / (n * f["valid"].shape[1] * f["valid"].shape[2]))
        attrs = {k: _jsonable(v) for k, v in f.attrs.items()}
        out = {"path": str(p), "format": FLOW_FORMAT, "container": "h5"}
        out.update(_summary(f["flow"].shape[1:3], t0, t1, vf, attrs))
        out["units"] = str(attrs.get("units", "px/s"))
        out["valid_masks"] = "valid" in f
        return out


def _describe_npz(p: Path) -> dict | None:
    try:
        z = np.load(p, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile):
        return None
    with z:
        names = set(z.files)
        if {"t", "x", "y", "vx", "vy"} <= names:
            t = z["t"]
            out = {"path": str(p), "format": "per-event-flow", "container": "npz",
                   "events": int(t.size), "units": "px/s",
                   "fields": sorted(names)}
            if t.size:
                out.update(t_first_us=int(t[0]), t_last_us=int(t[-1]),
                           duration_s=(int(t[-1]) - int(t[0])) * 1e-6)
            if "valid" in names:
                out["valid_fraction"] = float(z["valid"].mean()) if t.size else None
            return out
        if "format" not in names or str(z["format"]) != FLOW_FORMAT:
            return None
    seq = _read_npz(p)
    out = {"path": str(p), "format": FLOW_FORMAT, "container": "npz"}
    out.update(_summary(seq.flow.shape[1:3], seq.t0, seq.t1, seq.valid, seq.attrs))
    out["units"] = seq.attrs["units"]
    out["valid_masks"] = True
    return out
