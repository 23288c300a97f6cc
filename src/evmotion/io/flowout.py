"""One output layer for dense flow: every method and command writes its windows here.

:func:`open_flow_output` picks the container by the file name and returns a sink with
``append(flow, t0, t1, valid)``, ``close()`` and ``abort()``;
:func:`evmotion.io.flowread.read_flow` reads any of them back as a
:class:`~evmotion.io.flowfiles.FlowSequence` with its windows' times and validity masks,
and :func:`evmotion.io.flowread.describe_flow` summarises one (``evmotion info``).

Every container says its units, each window's ``[t0, t1)`` (µs) and its validity mask
(the pixels whose flow events support):

=================  ===========================================================================
``.h5``            the reference: ``flow`` (N, H, W, 2) float32 **px/s**, ``t0``/``t1`` (N,)
                   int64 µs, ``valid`` (N, H, W) bool; attributes ``units``, ``grid``,
                   ``method`` and the method's options; a method's extra per-window
                   datasets (``extras``: BOS's ``q``, ``p``) beside them, each with its
                   ``units``. Written window by window to ``OUT.part``, renamed when
                   complete, resumable (``resume=True``).
``.npz``           the same arrays (``flow`` px/s, ``t0``, ``t1``, ``valid``, the extras) with
                   ``units``, ``format``, ``attrs`` and ``extras`` (JSON: names, units);
                   windows spooled to hidden temporary files and stored (uncompressed)
                   when complete.
``.flo``           Middlebury **displacement** in px over the window (the convention of the
                   format), unknown (1e10) where not valid; ``NAME.flo.json`` beside it holds
                   ``t0_us``, ``t1_us``, ``dt_s``, ``units`` and the attributes.
``.png``           DSEC 16-bit flow PNG: **displacement** in px (``v · 128 + 2^15``, ±256 px,
                   1/128 px steps), third channel the valid flag; ``NAME.png.json`` beside it
                   as for ``.flo``.
=================  ===========================================================================

``.flo`` and ``.png`` hold the flow only (no extras): one window per file; several windows need an explicit pattern
(``flow_{:05d}.flo``, formatted with the window index from 0); a plain name with several
windows is an error, never a silent rename. A bare ``.npy`` (no times, units or mask) is
refused in favour of ``.npz``.

Writes are atomic: per-window files are written into a hidden ``.NAME.*.part`` folder and
moved into place by ``close()``; an interrupted or failed run leaves no file that looks
complete (only a ``.part`` file or folder, which ``abort()`` removes except for a
resumable ``.h5``).

Examples
--------
>>> with open_flow_output("flow.npz", (180, 240), {"method": "multicm"}) as out:
...     out.append(np.zeros((180, 240, 2), np.float32), t0=0, t1=10_000)
>>> from evmotion.io import read_flow
>>> read_flow("flow.npz").t1
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

from evmotion.errors import EvmotionError, ParameterError
from evmotion.io.base import PartFileWriter
from evmotion.io.flowfiles import (
    FLOW_COMPRESSION,
    FLOW_FORMAT,
    FlowWriter,
    check_extras,
    part_holds_nothing,
    window_times_ok,
    write_dsec_flow_png,
    write_flo,
)
from evmotion.io.h5filters import register_filters
from evmotion.utils import (
    HELD_NO_WINDOW,
    atomic_path,
    ensure_file_target,
    interrupts_deferred,
    keep_for_resume,
    staging_folder,
    warn_nothing_to_resume,
)

__all__ = [
    "CONTAINERS",
    "EXTRA_CONTAINERS",
    "FlowOutput",
    "H5FlowOutput",
    "NpzFlowOutput",
    "PerWindowFlowOutput",
    "check_flow_output",
    "flow_container",
    "is_pattern",
    "json_value",
    "open_flow_output",
    "sidecar_path",
    "window_path",
]

#: File suffix -> container name.
CONTAINERS = {".h5": "h5", ".hdf5": "h5", ".npz": "npz", ".flo": "flo", ".png": "png"}
#: Containers holding one window per file.
PER_WINDOW = ("flo", "png")
#: Containers that store a method's extra per-window datasets beside the flow.
EXTRA_CONTAINERS = ("h5", "npz")
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


def is_pattern(path: str | os.PathLike) -> bool:
    """Whether ``path`` names per-window files by a ``str.format`` pattern of its name."""
    return "{" in Path(path).name


def sidecar_path(path: str | os.PathLike) -> Path:
    """The JSON sidecar of a per-window file: ``NAME.json`` beside ``NAME``."""
    p = Path(path)
    return p.with_name(p.name + ".json")


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
    if is_pattern(p):
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


def json_value(value):
    """``value`` as plain Python that :mod:`json` writes (bytes decoded, numpy unboxed)."""
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
        ensure_file_target(self.path)
        h, w = (int(v) for v in sensor_size)
        if h <= 0 or w <= 0:
            raise ParameterError(f"sensor_size must be positive (height, width), got {(h, w)}")
        self.sensor_size = (h, w)
        self.attrs = _attrs(attrs)
        self.done: list[tuple[int, int]] = []
        self.n_written = 0
        self.extras: dict = {}

    def _checked(self, flow, t0: int, t1: int, valid) -> tuple[np.ndarray, np.ndarray]:
        arr = np.ascontiguousarray(flow, dtype=np.float32)
        if arr.shape != (*self.sensor_size, 2):
            raise ParameterError(f"{self.path}: flow has shape {arr.shape}, this output holds "
                                 f"{(*self.sensor_size, 2)}")
        if valid is None:
            valid = np.isfinite(arr).all(axis=2)
        v = np.asarray(valid, dtype=bool)
        if v.shape != self.sensor_size:
            raise ParameterError(f"{self.path}: valid has shape {v.shape}, expected "
                                 f"{self.sensor_size}")
        if not window_times_ok(t0, t1, v):
            raise ParameterError(f"{self.path}: window end t1={t1} us is not after "
                                 f"t0={t0} us" + (" and the window has valid pixels"
                                                  if int(t1) == int(t0) else ""))
        return arr, v

    def append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray | None = None,
               extras: dict | None = None) -> None:
        """Add one window: ``flow`` (H, W, 2) px/s over ``[t0, t1)`` µs, ``valid`` (H, W)
        bool (default: where the flow is finite), and the window's value of every extra
        dataset opened with the output (``extras``: name -> array)."""
        arr, v = self._checked(flow, t0, t1, valid)
        values = check_extras(self.extras, extras, self.path)
        self._append(arr, int(t0), int(t1), v, values)
        self.n_written += 1

    def _append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray,
                extras: dict) -> None:
        raise NotImplementedError

    def close(self) -> list[Path]:
        """Complete the output; return the files written."""
        raise NotImplementedError

    def abort(self) -> None:
        raise NotImplementedError

    def stored_at(self) -> Path:
        """The file a resumed output's windows are in (``OUT.part`` until it is complete)."""
        return self.path

    def check_count(self, n_windows: int) -> None:
        """The run makes ``n_windows``: a resumed output must not hold more."""
        if len(self.done) > n_windows:
            where = self.stored_at()
            self.abort()
            raise ParameterError(f"cannot resume (--resume): {where} holds "
                                 f"{len(self.done)} windows, this run makes {n_windows}; "
                                 "repeat the options of the first run, or start again")

    def check_done(self, index: int, t0: int, t1: int) -> None:
        """Raise ParameterError if window ``index`` of this run is not the ``index``-th
        window of the resumed output (other windowing options, or another recording)."""
        where = self.stored_at()
        if index >= len(self.done):
            self.abort()
            raise ParameterError(f"cannot resume (--resume): this run skipped window {index}, "
                                 f"which {where} does not hold")
        if (int(t0), int(t1)) != tuple(self.done[index]):
            self.abort()
            a, b = self.done[index]
            raise ParameterError(f"cannot resume (--resume): window {index} of {where} is "
                                 f"[{a}, {b}) µs but this run makes [{t0}, {t1}) µs; repeat "
                                 "the windowing options of the first run, or start again")


# attributes that describe a run without identifying its input: the recording's path
# (``./rec`` and ``/data/rec`` are one recording, and a file replaced in place is
# another), which the events' fingerprint (``source_events``) identifies instead, the
# network checkpoint's, which its digest (``checkpoint_sha1``) identifies, and a BOS run's
# frames' (``frames_digest``)
NOT_COMPARED = frozenset({"source", "checkpoint", "frames"})


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
                 compression: str | None = FLOW_COMPRESSION, extras: dict | None = None):
        super().__init__(path, sensor_size, attrs or {})
        attrs = self.attrs
        self.part = self.path.with_name(self.path.name + ".part")  # FlowWriter's own name
        emptied = self.part.exists() and part_holds_nothing(self.part)
        if emptied:
            self.part.unlink()  # a run killed before its first window left it: no work
        self.reopened_final = resume and self.path.exists() and not self.part.exists()
        if resume and emptied and not self.path.exists():
            # (it was dropped without a word, the run starting afresh, probe BH)
            warn_nothing_to_resume(self.part, HELD_NO_WINDOW)
            resume = False
        if not resume and self.part.exists():
            # a fresh run would overwrite an interrupted run's windows at its first window
            raise ParameterError(f"{self.part} holds the work of an interrupted run: add "
                                 "--resume to continue it, or delete it to start again")
        if not resume:
            self.w = FlowWriter(self.path, self.sensor_size, with_valid=with_valid,
                                attrs=attrs, compression=compression, extras=extras)
            self.extras = self.w.extras
            return
        if not self.path.exists() and not self.part.exists():
            warn_nothing_to_resume(self.part)
        register_filters()  # the stored windows are read back (Blosc-compressed)
        # (the compression of a file made afresh when there was nothing to resume: the
        # caller's, as on the other path to a fresh file)
        self.w = FlowWriter(self.path, self.sensor_size, with_valid=with_valid, resume=True,
                            compression=compression, extras=dict(extras or {}))
        self.extras = self.w.extras
        old = dict(self.w.f.attrs)
        made = self.path if self.reopened_final else self.part
        for key, value in attrs.items():
            if (self.w.n_done and key in old and key not in NOT_COMPARED
                    and not _same(old[key], value)):
                self.abort()
                raise ParameterError(f"cannot resume (--resume): {made} was made with "
                                     f"{key}={json_value(old[key])!r}, this run has "
                                     f"{json_value(value)!r}; repeat the options of the first "
                                     "run, or start again")
            self.w.f.attrs[key] = value
        if self.w.with_valid != with_valid:
            self.abort()
            raise ParameterError(f"cannot resume (--resume): {self.part} has another layout "
                                 f"(valid masks: {self.w.with_valid}); start again")
        t1 = np.asarray(self.w.f["t1"][: self.w.n_done])
        self.done = list(zip(np.asarray(self.w.done_t0).tolist(), t1.tolist(), strict=True))

    def stored_at(self) -> Path:
        return self.path if self.reopened_final else self.part

    def stored_flow(self, index: int) -> np.ndarray:
        """Flow (H, W, 2) float32 px/s of a window already in the file, as written."""
        return self.stored("flow", index)

    def stored(self, name: str, index: int) -> np.ndarray:
        """Dataset ``name`` (``flow``, ``valid`` or an extra) of a window already in the
        file, as written."""
        return np.asarray(self.w.f[name][index])

    def append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray | None = None,
               extras: dict | None = None) -> None:
        """Add one window (see :meth:`FlowOutput.append`)."""
        # (the .part file: a finished OUT reopened to be continued is in it until close;
        # its own name, gone meanwhile, was taken for a file deleted, probe BH)
        where = self.part
        if not where.exists():
            # the file was deleted under the open handle (its folder removed): the windows
            # would go on into a file nobody can reach, and the run fail only at its end
            raise EvmotionError(f"{where} was removed during the run (its folder deleted?): "
                              "the windows done so far are lost; run the command again")
        if not self.w.with_valid:  # a file made without masks (FlowWriter's choice)
            self.w.append(flow, t0, t1, extras=extras)
        else:
            self.w.append(flow, t0, t1, valid=valid, extras=extras)
        self.n_written += 1

    def close(self) -> list[Path]:
        self.w.close()
        return [self.path]

    def abort(self) -> None:
        empty = self.w.f.id.valid and self.w.n_done == 0
        self.w.abort()
        if self.reopened_final and self.part.exists():
            os.replace(self.part, self.path)
            self.reopened_final = False
        elif empty and self.part.exists():
            self.part.unlink()  # no window to resume from: leave nothing behind
        elif self.part.exists():
            keep_for_resume(self.part)


def _same(a, b) -> bool:
    a = json_value(a)
    try:
        return bool(np.array_equal(np.asarray(a), np.asarray(b)))
    except (TypeError, ValueError):
        return str(a) == str(b)


class NpzFlowOutput(FlowOutput):
    """``.npz`` output: windows spooled to hidden temporary files (bounded memory), stored
    as ``flow`` (N, H, W, 2) float32 px/s, ``valid`` (N, H, W) bool, ``t0``/``t1`` (N,)
    int64 µs, ``units``, ``format`` and ``attrs`` (a JSON string) when complete; each
    extra dataset under its name, and ``extras`` (JSON: name -> units, meaning)."""

    container = "npz"

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int],
                 attrs: dict | None = None, extras: dict | None = None):
        super().__init__(path, sensor_size, attrs or {})
        self.extras = dict(extras or {})
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        spool = dict(dir=self.path.parent, prefix=f".{self.path.name}.")
        # unnamed temporary files: the system removes them whatever ends the process
        self._flow = tempfile.TemporaryFile(suffix=".flow.part", **spool)
        self._valid = tempfile.TemporaryFile(suffix=".valid.part", **spool)
        self._extra = {name: tempfile.TemporaryFile(suffix=".extra.part", **spool)
                       for name in self.extras}
        self._t0: list[int] = []
        self._t1: list[int] = []

    def _append(self, flow, t0, t1, valid, extras) -> None:
        self._flow.write(flow.astype("<f4", copy=False).tobytes())
        self._valid.write(valid.tobytes())
        for name, value in extras.items():
            self._extra[name].write(np.ascontiguousarray(value).tobytes())
        self._t0.append(t0)
        self._t1.append(t1)

    def close(self) -> list[Path]:
        if self._ctx is None:
            return [self.path]
        n, (h, w) = len(self._t1), self.sensor_size
        small = {"t0": np.asarray(self._t0, "<i8"), "t1": np.asarray(self._t1, "<i8"),
                 "units": np.asarray("px/s"), "format": np.asarray(FLOW_FORMAT),
                 "attrs": np.asarray(json.dumps({k: json_value(v)
                                                  for k, v in self.attrs.items()}))}
        if self.extras:
            small["extras"] = np.asarray(json.dumps(
                {k: {"units": s.units, "meaning": s.meaning} for k, s in self.extras.items()}))
        big = [("flow", self._flow, "<f4", (n, h, w, 2)),
               ("valid", self._valid, "|b1", (n, h, w))]
        big += [(name, self._extra[name], np.dtype(s.dtype).str, (n, *s.shape))
                for name, s in self.extras.items()]
        with zipfile.ZipFile(self._tmp, "w", zipfile.ZIP_STORED, allowZip64=True) as zf:
            for name, spool, dtype, shape in big:
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
        for spool in (self._flow, self._valid, *self._extra.values()):
            spool.close()
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
        self.pattern = is_pattern(self.path)
        names = ([window_path(self.path, i) for i in range(n_windows or 0)] if self.pattern
                 else [self.path])
        for name in names:
            for target in (name, sidecar_path(name)):
                if target.is_dir():  # found before the work, not when moving its files in
                    raise ParameterError(f"--out {self.path}: {target} is a folder; choose "
                                         "another name")
        self.stage: Path | None = staging_folder(
            self.path.with_name(self.path.name.split("{")[0] or "flow"))
        self.files: list[Path] = []

    def _append(self, flow, t0, t1, valid, extras) -> None:
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
                "attrs": {k: json_value(v) for k, v in self.attrs.items()}}
        (self.stage / (final.name + ".json")).write_text(json.dumps(side, indent=1))
        self.files.append(final)

    def close(self) -> list[Path]:
        if self.stage is None:
            return list(self.files)
        # the set is published whole: an interrupt among the moves had left part of it
        # (9 of 18 windows, a file without its sidecar), or a new run's first window among
        # a previous run's others, looking complete (probe BH); the renames take
        # milliseconds
        with interrupts_deferred():
            return self._publish()

    def _publish(self) -> list[Path]:
        for final in self.files:
            os.replace(self.stage / final.name, final)
            os.replace(self.stage / (final.name + ".json"), sidecar_path(final))
        if self.pattern:  # a previous, longer run's windows are not this run's
            i = len(self.files)
            while (stale := window_path(self.path, i)).exists():
                stale.unlink()
                sidecar_path(stale).unlink(missing_ok=True)
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
                     n_windows: int | None = None, compression: str | None = FLOW_COMPRESSION,
                     extras: dict | None = None) -> FlowOutput:
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
        ``.h5`` only: the flow dataset's filter (see :class:`FlowWriter`; default
        :data:`~evmotion.io.flowfiles.FLOW_COMPRESSION`, Blosc-LZ4).
    extras : dict of str to ExtraSpec, optional
        ``.h5`` and ``.npz`` only (:data:`EXTRA_CONTAINERS`): a method's per-window
        datasets stored beside the flow (:class:`~evmotion.io.flowfiles.ExtraSpec`: shape
        of one window's value, dtype, units, meaning); ``append(..., extras=)`` gives
        each window's values. A name may hold a group (``window/loss``).

    Returns
    -------
    FlowOutput
        ``append(flow, t0, t1, valid)`` each window (flow px/s, times µs), then
        ``close()``; or use it as a context manager (an exception aborts it).

    Examples
    --------
    >>> with open_flow_output("flow_{:05d}.flo", (4, 5), {"method": "x"}) as out:
    ...     out.append(np.ones((4, 5, 2), np.float32), t0=0, t1=10_000)
    ...     out.append(np.ones((4, 5, 2), np.float32), t0=10_000, t1=20_000)
    >>> sorted(p.name for p in Path().glob("flow_*.flo"))
    ['flow_00000.flo', 'flow_00001.flo']
    """
    kind = check_flow_output(path, n_windows)
    if extras and kind not in EXTRA_CONTAINERS:
        raise ParameterError(f"{os.fspath(path)}: a .{kind} file holds the flow only, not "
                             f"{', '.join(extras)}; write .h5 or .npz to keep them")
    if resume and kind != "h5":
        raise ParameterError(f"{os.fspath(path)}: only an .h5 output can be resumed (a "
                             f".{kind} output is written whole at the end)")
    if kind == "h5":
        return H5FlowOutput(path, sensor_size, attrs, resume=resume, compression=compression,
                            extras=extras)
    if kind == "npz":
        return NpzFlowOutput(path, sensor_size, attrs, extras=extras)
    return PerWindowFlowOutput(path, sensor_size, attrs, n_windows=n_windows)
