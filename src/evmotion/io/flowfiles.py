"""Optical-flow files: Middlebury ``.flo``, DSEC 16-bit PNG, and evmotion's flow HDF5.

Conventions: a *flow* is an ``(H, W, 2)`` float32 array of ``(u, v)`` in **px/s** (u to the
right, v down). A *displacement* is in **px** over an explicit interval; the functions that
read or write displacements say so and take the interval ``dt_s`` (seconds) to convert.

The flow HDF5 container (written by :class:`FlowWriter`, read by :func:`read_flow_h5`) holds
dense per-window flow::

    /flow   (N, H, W, 2) float32, px/s, chunked one window per chunk
    /t0, /t1 (N,) int64 µs, the window each flow belongs to
    /valid  (N, H, W) bool, optional
    /<extra> (N, ...) per-window extra datasets a method adds (BOS: ``q``, ``p``,
            ``window/<scalar>``), each with attributes ``units`` and ``meaning``; the file
            attribute ``extras`` lists their names (JSON)
    attrs: format="evmotion-flow", version, height, width, units="px/s", plus user attributes

It is written window by window to ``<name>.part`` and renamed onto ``<name>`` by
:meth:`FlowWriter.close`, so a crashed run never leaves a truncated file under the final
name, and ``FlowWriter(path, ..., resume=True)`` continues where it stopped.
"""

from __future__ import annotations

import os
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evmotion.errors import EvmotionWarning, FormatError, ParameterError
from evmotion.io.base import PartFileWriter
from evmotion.io.guard import guarded, open_h5, open_npz
from evmotion.io.h5attrs import read_attrs, read_attrs_many
from evmotion.io.h5filters import h5_compression
from evmotion.io.pngfile import read_png, write_png
from evmotion.utils import (
    atomic_path,
    check_number,
    ensure_file_target,
    ensure_room,
    is_file,
    whole_number,
)

__all__ = [
    "gt_in_folder",
    "FLO_MAGIC",
    "FLOW_COMPRESSION",
    "FlowSequence",
    "FlowWriter",
    "ExtraSpec",
    "create_extras",
    "extra_specs",
    "check_extras",
    "window_times_ok",
    "read_flo",
    "write_flo",
    "read_dsec_flow_png",
    "write_dsec_flow_png",
    "read_flow_h5",
    "flow_h5_done",
    "h5_compression",
    "write_flow_group",
    "read_flow_group",
    "read_gt_flow",
    "read_mvsec_gt_flow",
    "read_dsec_gt_flow",
    "dsec_gt_files",
]

FLO_MAGIC = 202021.25
#: Middlebury's value for "unknown flow" (readers treat anything above 1e9 as unknown)
FLO_UNKNOWN = 1e10
FLOW_FORMAT = "evmotion-flow"
FLOW_VERSION = 1
#: The filter of evmotion's dense flow datasets (:func:`h5_compression`): Blosc-LZ4, as its
#: event files; 8x faster to write than gzip on float32 flow for files 7 % larger
#: (``benchmarks/results/flow_output.md``), and the write is the serial part of a parallel
#: run. Other HDF5 readers need ``import hdf5plugin``.
FLOW_COMPRESSION = "lz4"
SIM_GT_FORMAT = "evmotion-sim-gt"


@dataclass(frozen=True)
class FlowSequence:
    """Dense flow for a sequence of windows.

    Attributes
    ----------
    flow : ndarray, (N, H, W, 2) float32
        ``(u, v)`` in px/s.
    t0, t1 : ndarray, (N,) int64
        Window start and end in microseconds.
    valid : ndarray, (N, H, W) bool or None
        Where the flow is defined (ground truth) or trusted.
    attrs : dict
        Metadata stored with the flow.
    extras : dict of str to ndarray
        Per-window extra arrays a method stored beside the flow (first axis N), e.g. BOS's
        ``q`` (N, H, W) and ``p`` (N, H, W, 2); their units are in
        ``attrs["extras_units"]``.
    """

    flow: np.ndarray
    t0: np.ndarray
    t1: np.ndarray
    valid: np.ndarray | None = None
    attrs: dict = field(default_factory=dict)
    extras: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.flow.shape[0])

    def displacement(self, i: int) -> np.ndarray:
        """Pixel displacement ``(H, W, 2)`` over window ``i`` (flow times its duration)."""
        return self.flow[i] * np.float32((self.t1[i] - self.t0[i]) * 1e-6)


def _check_flow(flow, name: str = "flow") -> np.ndarray:
    arr = np.asarray(flow)
    if arr.ndim != 3 or arr.shape[2] != 2:
        raise ParameterError(f"{name} must have shape (H, W, 2), got {arr.shape}")
    return np.ascontiguousarray(arr, dtype=np.float32)


# ---------------------------------------------------------------------------- .flo
def write_flo(path: str | os.PathLike, flow: np.ndarray, dt_s: float | None = None, *,
              valid: np.ndarray | None = None) -> None:
    """Write a Middlebury ``.flo`` file (atomically).

    ``.flo`` files hold pixel displacements. Give ``dt_s`` to convert a flow in px/s
    (displacement = flow · dt_s); without it ``flow`` is written as-is (a displacement in px).
    Pixels outside ``valid`` (and non-finite values) are written as Middlebury's "unknown"
    (1e10), which :func:`read_flo` returns as NaN.

    Parameters
    ----------
    path : path-like
        Output file.
    flow : ndarray, (H, W, 2)
        Flow in px/s if ``dt_s`` is given, else displacement in px.
    dt_s : float, optional
        Time interval in seconds, > 0 (0 only when no pixel is ``valid``).
    valid : ndarray (H, W) bool, optional
        Where the flow is known (default: where it is finite).

    Examples
    --------
    >>> write_flo("f.flo", np.full((4, 5, 2), 150, np.float32), dt_s=0.01)
    >>> read_flo("f.flo")[0, 0].tolist()  # px over 0.01 s
    [1.5, 1.5]
    """
    arr = _check_flow(flow)
    if dt_s is not None:
        # dt_s=0 wrote each known pixel as a zero displacement; a window without a valid
        # pixel (its events all at one time, kept by flowout to keep the numbering) has none
        some = valid is None or bool(np.asarray(valid).any())
        arr = arr * np.float32(check_number("dt_s", dt_s, 0.0, lo_open=some, units="seconds"))
    known = np.isfinite(arr).all(axis=2)
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape != arr.shape[:2]:
            raise ParameterError(f"valid must have shape {arr.shape[:2]}, got {v.shape}")
        known &= v
    if not known.all():
        arr = np.where(known[..., None], arr, np.float32(FLO_UNKNOWN))
    h, w = arr.shape[:2]
    header = struct.pack("<fii", FLO_MAGIC, w, h)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            fh.write(arr.astype("<f4").tobytes())


@guarded('Middlebury .flo')
def read_flo(path: str | os.PathLike, dt_s: float | None = None) -> np.ndarray:
    """Read a Middlebury ``.flo`` file.

    Parameters
    ----------
    path : path-like
        The file.
    dt_s : float, optional
        Interval in seconds the displacement spans. When given the result is a flow in
        px/s (displacement / dt_s); otherwise the stored displacement in px.

    Returns
    -------
    ndarray, (H, W, 2) float32
        Values above 1e9 (Middlebury's "unknown") are returned as NaN.

    Examples
    --------
    >>> write_flo("f.flo", np.ones((4, 5, 2), np.float32))
    >>> disp = read_flo("f.flo")
    >>> disp.shape, read_flo("f.flo", dt_s=0.01)[0, 0].tolist()
    ((4, 5, 2), [100.0, 100.0])
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FormatError(path, f"cannot read: {exc.strerror}") from None
    if len(data) < 12:
        raise FormatError(path, f"truncated .flo header ({len(data)} bytes, need 12)")
    magic, w, h = struct.unpack("<fii", data[:12])
    if magic != np.float32(FLO_MAGIC):
        raise FormatError(path, f"not a .flo file: magic number {magic!r}, expected {FLO_MAGIC}")
    if w <= 0 or h <= 0 or w * h > 1 << 28:
        raise FormatError(path, f"implausible .flo size width={w} height={h}")
    need = 12 + 8 * w * h
    if len(data) < need:
        raise FormatError(path, f"truncated .flo data: {len(data)} bytes, need {need} for "
                          f"{w}x{h}")
    arr = np.frombuffer(data, dtype="<f4", count=2 * w * h, offset=12).reshape(h, w, 2)
    arr = arr.astype(np.float32)
    arr[np.abs(arr) > 1e9] = np.nan
    if dt_s is not None:
        arr /= np.float32(check_number("dt_s", dt_s, 0.0, lo_open=True, units="seconds"))
    return arr


# ---------------------------------------------------------------------------- DSEC PNG
DSEC_MAX_PX = 256.0  # the 16-bit code's range: v * 128 + 2^15 in 0..65535
def write_dsec_flow_png(path: str | os.PathLike, displacement: np.ndarray,
                        valid: np.ndarray | None = None) -> None:
    """Write a DSEC optical-flow PNG (16-bit RGB, atomically).

    Channels: ``x`` and ``y`` displacement encoded as ``v · 128 + 2^15``, third channel the
    valid flag (1 = valid). Displacement is in px over the file's interval (DSEC's
    ``forward_timestamps.txt``), rounded to 1/128 px; a valid pixel moving more than the
    code holds (±256 px) is marked invalid, with an :class:`~evmotion.errors.EvmotionWarning`.

    Examples
    --------
    >>> write_dsec_flow_png("000000.png", np.full((4, 5, 2), -2.25))
    >>> read_dsec_flow_png("000000.png")[0][0, 0].tolist()
    [-2.25, -2.25]
    """
    d = _check_flow(displacement, "displacement")
    h, w = d.shape[:2]
    if valid is None:
        valid = np.isfinite(d).all(axis=2)
    valid = np.asarray(valid, dtype=bool)
    if valid.shape != (h, w):
        raise ParameterError(f"valid must have shape {(h, w)}, got {valid.shape}")
    # a NaN or infinite displacement is no displacement, whatever the mask says (its code
    # would be a valid zero)
    valid = valid & np.isfinite(d).all(axis=2)
    enc = np.zeros((h, w, 3), dtype=np.uint16)
    dd = np.where(valid[..., None], d, 0.0)
    # the 16-bit code holds -256 .. +255.99 px: a valid pixel beyond is not stored as a
    # wrong (clipped) displacement but marked invalid, and said
    beyond = valid & ((dd < -DSEC_MAX_PX) | (dd > DSEC_MAX_PX - 1 / 128)).any(axis=2)
    if beyond.any():
        warnings.warn(EvmotionWarning(
            f"{path}: {int(beyond.sum())} valid pixels move more than the DSEC PNG code's "
            f"{DSEC_MAX_PX:g} px (up to {float(np.abs(dd[beyond]).max()):.1f} px): marked "
            "invalid; write .h5, .npz or .flo to keep them"), stacklevel=2)
        valid = valid & ~beyond
        dd = np.where(valid[..., None], dd, 0.0)
    enc[..., :2] = np.clip(np.rint(dd * 128.0 + 2.0**15), 0, 65535).astype(np.uint16)
    enc[..., 2] = valid
    # zlib level 1: files ~1 % larger than level 6 in a third of the time
    write_png(path, enc, compression=1)


@guarded('DSEC flow PNG')
def read_dsec_flow_png(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a DSEC optical-flow PNG.

    Returns
    -------
    displacement : ndarray, (H, W, 2) float32
        ``(v − 2^15) / 128`` px over the file's interval, NaN where invalid.
    valid : ndarray, (H, W) bool
        The third channel.

    Examples
    --------
    >>> d = np.ones((4, 5, 2))
    >>> d[0, 0] = np.nan
    >>> write_dsec_flow_png("000002.png", d)
    >>> disp, valid = read_dsec_flow_png("000002.png")
    >>> disp.shape, int(valid.sum()), disp[0, :2, 0].tolist()
    ((4, 5, 2), 19, [nan, 1.0])
    """
    path = Path(path)
    img, info = read_png(path, direct=False, what="cannot decode DSEC flow PNG")
    planes = info.get("planes", 1)
    if info.get("bitdepth") != 16 or planes < 3:
        raise FormatError(path, f"DSEC flow PNG must be 16-bit RGB, got bitdepth "
                          f"{info.get('bitdepth')} with {planes} channel(s)")
    valid = img[..., 2] > 0
    disp = (img[..., :2].astype(np.float32) - np.float32(2**15)) / np.float32(128.0)
    disp[~valid] = np.nan
    return disp, valid


# ---------------------------------------------------------------------------- flow HDF5
def _part_path(path: Path) -> Path:
    return path.with_name(path.name + ".part")


class FlowWriter(PartFileWriter):
    """Append dense flow windows to an evmotion flow HDF5 file, in bounded memory.

    Parameters
    ----------
    path : path-like
        Final file name (``.h5``). Data go to ``<path>.part`` until :meth:`close`.
    sensor_size : (int, int)
        ``(height, width)`` of every flow field.
    with_valid : bool
        Store a per-window boolean mask (``append(..., valid=)``).
    resume : bool
        Reopen an unfinished ``.part`` file (or a finished file) and continue after its
        last window; :attr:`n_done` and :attr:`done_t0` tell which windows are present.
    attrs : dict, optional
        Metadata stored as HDF5 attributes (strings, numbers, small arrays).
    compression : str or None
        HDF5 filter of the flow and mask datasets (:func:`h5_compression`): ``"lz4"`` (the
        default, :data:`FLOW_COMPRESSION`) or ``"zstd"`` (Blosc with byte shuffle through
        hdf5plugin: fast; readers need ``import hdf5plugin``), ``"gzip"`` (readable
        everywhere, slow to write), ``"lzf"`` or None.
    extras : dict of str to ExtraSpec, optional
        Per-window datasets stored beside the flow (``append(..., extras=)`` gives each
        window's values); a name may hold a group (``window/loss``). Every window must
        give all of them.

    Examples
    --------
    >>> with FlowWriter("flow.h5", (180, 240)) as fw:
    ...     fw.append(np.zeros((180, 240, 2), np.float32), t0=0, t1=10_000)
    ...     fw.append(np.ones((180, 240, 2), np.float32), t0=10_000, t1=20_000)
    >>> read_flow_h5("flow.h5").t1.tolist()
    [10000, 20000]
    """

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int], *,
                 with_valid: bool = False, resume: bool = False, attrs: dict | None = None,
                 compression: str | None = FLOW_COMPRESSION, extras: dict | None = None):
        self.path = Path(path)
        ensure_file_target(self.path)
        self.part = _part_path(self.path)
        h, w = (int(v) for v in sensor_size)
        if h <= 0 or w <= 0:
            raise ParameterError(f"sensor_size must be positive (height, width), got {(h, w)}")
        self.sensor_size = (h, w)
        self._open: dict = {}
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if resume and self.part.exists() and part_holds_nothing(self.part):
            self.part.unlink()  # killed before its first window: nothing to resume
        moved = resume and not self.part.exists() and self.path.exists()
        if moved:
            os.replace(self.path, self.part)
        try:
            self._open_part(resume, with_valid, compression, extras)
        except FormatError as exc:
            if not moved:
                raise
            # the finished output it was asked to continue goes back under its own name,
            # and is named (probe AO: a truncated bos.h5 was left renamed to bos.h5.part)
            os.replace(self.part, self.path)
            raise FormatError(self.path, exc.message, exc.hint) from None
        for k, v in (attrs or {}).items():
            self.f.attrs[k] = v

    def _open_part(self, resume: bool, with_valid: bool, compression, extras) -> None:
        """Open ``.part`` for a resumed run (checked against this one) or a fresh one."""
        import h5py

        if resume and (self.part.exists() or self.part.is_symlink()):
            if not is_file(self.part):
                # (a FIFO hung the resume, probe AQ)
                raise FormatError(self.part, "cannot resume: not a regular file",
                                  "delete it to start again")
            try:
                self.f = h5py.File(self.part, "a")
            except OSError as exc:
                # (HDF5 says "unable to lock file"; a damaged file's "sblock" is no lock)
                if "lock file" in str(exc):  # another program has it open
                    raise FormatError(self.part, "cannot reopen to resume: another program "
                                      "has it open (HDF5 file lock)",
                                      "close it there and run again") from None
                if "truncated file" in str(exc):
                    raise FormatError(self.part, "cannot resume: the file is truncated (its "
                                      "run stopped during a write: a full device, a file-size "
                                      "limit, a kill)", START_AGAIN) from None
                raise FormatError(self.part, f"cannot reopen to resume: {exc}",
                                  "delete it to start again") from None
            try:
                old = read_attrs(self.part, self.f, ("height", "width", "format", "units"))
                got = (int(old.get("height", -1)), int(old.get("width", -1)))
                fmt = old.get("format")
                if fmt != FLOW_FORMAT or got != self.sensor_size:
                    raise FormatError(self.part, f"cannot resume: holds format {fmt!r} of "
                                      f"size {got}, expected {FLOW_FORMAT!r} of size "
                                      f"{self.sensor_size}")
                if old.get("units", "px/s") != "px/s":
                    raise FormatError(self.part, f"cannot resume: attribute 'units' is "
                                      f"{old.get('units')!r}, not 'px/s'")
                self.with_valid = "valid" in self.f
                self.extras = extra_specs(self.f, self.part)
                if extras is not None and set(extras) != set(self.extras):
                    raise FormatError(self.part, f"cannot resume: holds extra datasets "
                                      f"{sorted(self.extras)}, this run writes "
                                      f"{sorted(extras)}")
                self._check_layout()
                self._trim_partial()
                self._check_kept()
            except (FormatError, KeyError, OSError, ValueError, TypeError) as exc:
                self.f.close()
                if isinstance(exc, FormatError):
                    raise
                raise FormatError(self.part, "cannot resume: damaged ("
                                  f"{' '.join(str(exc).split())[:120]})",
                                  START_AGAIN) from None
        else:
            self.f = h5py.File(self.part, "w")
            self.with_valid = with_valid
            write_flow_group(self.f, None, None, None, sensor_size=self.sensor_size,
                             with_valid=with_valid, compression=compression)
            self.extras = dict(extras or {})
            create_extras(self.f, self.extras, compression)

    def _check_layout(self) -> None:
        """The datasets a resumed file must hold, as this writer made them: resizable,
        of their dtype and window shape, with a row for each window ``t1`` counts (one
        fewer ``flow`` row was filled with zeros and kept valid, probe AQ)."""
        h, w = self.sensor_size
        want = {"t0": ((), "i"), "t1": ((), "i"), "flow": ((h, w, 2), "f")}
        if self.with_valid:
            want["valid"] = ((h, w), "b")
        for name, spec in self.extras.items():
            want[name] = (tuple(int(v) for v in spec.shape), np.dtype(spec.dtype).kind)
        n = int(self.f["t1"].shape[0]) if "t1" in self.f else 0
        for name, (shape, kind) in want.items():
            ds = self.f.get(name)
            if ds is None or not hasattr(ds, "dtype"):
                raise FormatError(self.part, f"cannot resume: dataset '{name}' is missing",
                                  START_AGAIN)
            if (ds.dtype.kind != kind or tuple(ds.shape[1:]) != shape or ds.chunks is None
                    or ds.maxshape[0] is not None):
                raise FormatError(self.part, f"cannot resume: dataset '{name}' is "
                                  f"{ds.dtype} {tuple(ds.shape)}, not as this run writes it",
                                  START_AGAIN)
            if ds.shape[0] < n:
                raise FormatError(self.part, f"cannot resume: dataset '{name}' holds "
                                  f"{ds.shape[0]} windows, 't1' {n}",
                                  START_AGAIN)

    def _check_kept(self) -> None:
        """Every kept window read back once: a damaged one would be kept as done and the
        run said complete (probe AO: a bos.h5 with flipped bits, which eval refused,
        resumed with '4 kept from the interrupted run', exit 0)."""
        names = [n for n in ("t0", "t1", "flow", "valid", *self.extras) if n in self.f]
        for i in range(int(self.f["t1"].shape[0])):
            row = {}
            for name in names:
                try:
                    row[name] = self.f[name][i]
                except (OSError, ValueError) as exc:
                    raise FormatError(self.part, f"cannot resume: window {i}'s {name} is "
                                      f"damaged ({' '.join(str(exc).split())[:120]})",
                                      START_AGAIN) from None
            # (a NaN flow where pixels are valid was kept, probe AQ)
            if "valid" in row and not np.isfinite(row["flow"][row["valid"]]).all():
                raise FormatError(self.part, f"cannot resume: window {i}'s flow is damaged "
                                  "(a flow that is not finite where it is valid)", START_AGAIN)

    def _trim_partial(self) -> None:
        # A crash between resizing and writing t1 leaves a window that is not done.
        n = int(self.f["t1"].shape[0])
        for name in ("flow", "t0", "valid", *self.extras):
            if name in self.f and self.f[name].shape[0] != n:
                self.f[name].resize(n, axis=0)

    @property
    def n_done(self) -> int:
        """Number of windows written so far."""
        return int(self._dataset("t1").shape[0])

    @property
    def done_t0(self) -> np.ndarray:
        """Start times (µs) of the windows written so far."""
        return self.f["t0"][: self.n_done]

    def append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray | None = None,
               extras: dict | None = None) -> None:
        """Add one window: ``flow`` (H, W, 2) px/s over ``[t0, t1)`` µs, and the window's
        value of every extra dataset (``extras``, name -> array of its spec's shape)."""
        arr = _check_flow(flow)
        values = check_extras(self.extras, extras, self.path)
        if arr.shape[:2] != self.sensor_size:
            raise ParameterError(f"flow has size {arr.shape[:2]}, the file holds "
                                 f"{self.sensor_size}")
        # whole µs: 30000.7 was floored and "30000" taken (probe AU)
        t0, t1 = whole_number("t0 (us)", t0), whole_number("t1 (us)", t1)
        if t1 < t0:
            raise ParameterError(f"window end t1={t1} us is before t0={t0} us")
        ensure_room(self.part, arr.nbytes + arr.shape[0] * arr.shape[1]
                    + sum(np.asarray(v).nbytes for v in (values or {}).values()))
        if self.with_valid and valid is None:
            valid = np.isfinite(arr).all(axis=2)
        elif not self.with_valid and valid is not None:
            raise ParameterError("this flow file was created without valid masks "
                                 "(FlowWriter(..., with_valid=True))")
        if self.with_valid:
            valid = np.asarray(valid, dtype=bool)
            if valid.shape != self.sensor_size:
                raise ParameterError(f"valid has shape {valid.shape}, expected "
                                     f"{self.sensor_size}")
        n = self.n_done
        # t1 is written last: its length is the number of complete windows.
        rows = [("flow", arr), *([("valid", valid)] if self.with_valid else []),
                *values.items(), ("t0", int(t0)), ("t1", int(t1))]
        for name, value in rows:
            ds = self._dataset(name)
            ds.resize(n + 1, axis=0)
            ds[n] = value
        self.f.flush()

    def _dataset(self, name: str):
        # h5py opens a dataset afresh on every lookup by name (~0.1 ms each, 1.3 ms a
        # window: a third of a 180x240 window's append, all of it on the client's serial
        # path in a parallel run), so each is opened once
        ds = self._open.get(name)
        if ds is None:
            ds = self._open[name] = self.f[name]
        return ds

    def close(self) -> None:
        """Finish the file and rename it onto the final name; where the rename fails (a
        folder made read-only), FormatError names the finished ``.part`` it keeps."""
        if self.f.id.valid:
            self.f.close()
            try:
                os.replace(self.part, self.path)
            except OSError as exc:
                # every window is in the .part: said, not a bare "[Errno 1] ... ->" (probe BB)
                raise FormatError(self.path, f"cannot rename the finished {self.part.name} "
                                  f"onto it: {exc.strerror or exc}", f"every window is in "
                                  f"{self.part}: rename it by hand, or make the folder "
                                  "writable and run the command again with --resume") from None

    def abort(self) -> None:
        """Close without renaming: the ``.part`` file stays for ``resume=True``."""
        if self.f.id.valid:
            try:
                self.f.close()
            except RuntimeError:  # its flush failed again (a full device): the caller says
                pass


@dataclass(frozen=True)
class ExtraSpec:
    """A per-window dataset stored beside the flow.

    Attributes
    ----------
    shape : tuple of int
        Shape of one window's value (``()`` for a number, ``(H, W)`` for an image).
    dtype : str
        numpy dtype of the stored values (default float32; ``"<f8"`` for numbers).
    units : str
        Unit of the values (``"px"``, ``"px^2/s"``, ``""`` for a count or a flag).
    meaning : str
        What the values are, in a sentence.

    Examples
    --------
    >>> ExtraSpec((4, 5), units="px").shape
    (4, 5)
    """

    shape: tuple = ()
    dtype: str = "<f4"
    units: str = ""
    meaning: str = ""


#: File attribute listing the extra datasets (JSON list of names).
EXTRAS_ATTR = "extras"


def create_extras(group, extras: dict, compression: str | None = "gzip") -> None:
    """Create the empty, resizable extra datasets ``extras`` (name -> :class:`ExtraSpec`)
    in an open flow group and add them to its ``extras`` attribute (none: no attribute)."""
    import json

    if not extras:
        return
    kw = h5_compression(compression)
    for name, spec in extras.items():
        shape = tuple(int(v) for v in spec.shape)
        big = len(shape) > 0
        ds = group.create_dataset(name, shape=(0, *shape), maxshape=(None, *shape),
                                  dtype=spec.dtype, chunks=(1, *shape) if big else (1024,),
                                  **(kw if big else {}))
        ds.attrs["units"] = spec.units
        ds.attrs["meaning"] = spec.meaning
    listed = [n for n in extra_specs(group) if n not in extras] if EXTRAS_ATTR in \
        group.attrs else []
    group.attrs[EXTRAS_ATTR] = json.dumps(listed + list(extras))


def extra_specs(group, path: str | os.PathLike | None = None,
                attrs: dict | None = None) -> dict:
    """The extra datasets of a flow group (name -> :class:`ExtraSpec`), from its
    ``extras`` attribute; a BOS file written before that attribute existed lists ``q``,
    ``p`` and ``window/*``. ``attrs``: the group's attributes, when already read."""
    import json

    if attrs is None:
        attrs = read_attrs(path, group, (EXTRAS_ATTR, "content"))
    raw = attrs.get(EXTRAS_ATTR)
    if raw is not None:
        names = json.loads(raw)
    elif _legacy_bos(attrs):
        names = [n for n in ("q", "p") if n in group]
        if "window" in group:
            names += [f"window/{k}" for k in group["window"]]
    else:
        names = []
    out = {}
    datasets = [group[name] for name in names]
    texts = read_attrs_many(path, datasets, ("units", "meaning"))
    for name, ds, text in zip(names, datasets, texts, strict=True):
        out[name] = ExtraSpec(tuple(ds.shape[1:]), ds.dtype.str, str(text.get("units", "")),
                              str(text.get("meaning", "")))
    return out


def _legacy_bos(attrs: dict) -> bool:
    """A BOS file written before the ``extras`` attribute (same datasets, ``valid`` = the
    ROI, evaluated at 1 px by ``evmotion eval``), by its group's attributes."""
    return attrs.get("content") == "evmotion-bos" and EXTRAS_ATTR not in attrs


def check_extras(specs: dict, values: dict | None, path=None) -> dict:
    """One window's extra values, checked against ``specs`` (same names, shapes) and cast
    to their dtypes; a ParameterError naming the file and the dataset otherwise."""
    values = dict(values or {})
    if set(values) != set(specs):
        missing, unknown = sorted(set(specs) - set(values)), sorted(set(values) - set(specs))
        raise ParameterError(f"{path}: extra datasets of a window: missing {missing}, "
                             f"unknown {unknown}")
    out = {}
    for name, spec in specs.items():
        arr = np.asarray(values[name], dtype=spec.dtype)
        if arr.shape != tuple(spec.shape):
            raise ParameterError(f"{path}: extra '{name}' has shape {arr.shape}, expected "
                                 f"{tuple(spec.shape)}")
        out[name] = arr
    return out


def write_flow_group(group, flow: np.ndarray | None, t0, t1, valid=None, *,
                     sensor_size: tuple[int, int] | None = None, with_valid: bool | None = None,
                     compression: str | None = "gzip") -> None:
    """Create the flow datasets in an open h5py group (e.g. ``ground_truth/flow`` in an
    evmotion events file), optionally filled with ``flow`` (N, H, W, 2) px/s and ``t0``,
    ``t1`` (N,) µs. The datasets stay resizable along the first axis for appending.

    Examples
    --------
    >>> import h5py
    >>> flow, t0, t1 = np.zeros((2, 4, 5, 2)), [0, 10_000], [10_000, 20_000]
    >>> with h5py.File("sim.h5", "a") as f:
    ...     write_flow_group(f.require_group("ground_truth/flow"), flow, t0, t1)
    >>> read_flow_h5("sim.h5").flow.shape
    (2, 4, 5, 2)
    """
    if flow is not None:
        flow = np.ascontiguousarray(flow, dtype=np.float32)
        if flow.ndim != 4 or flow.shape[3] != 2:
            raise ParameterError(f"flow must have shape (N, H, W, 2), got {flow.shape}")
        sensor_size = flow.shape[1:3]
    if sensor_size is None:
        raise ParameterError("give flow or sensor_size")
    h, w = (int(v) for v in sensor_size)
    n = 0 if flow is None else flow.shape[0]
    if with_valid is None:
        with_valid = valid is not None
    kw = h5_compression(compression)
    group.attrs["format"] = FLOW_FORMAT
    group.attrs["version"] = FLOW_VERSION
    group.attrs["height"] = h
    group.attrs["width"] = w
    group.attrs["units"] = "px/s"
    group.create_dataset("flow", shape=(n, h, w, 2), maxshape=(None, h, w, 2),
                         dtype="<f4", chunks=(1, h, w, 2), data=flow, **kw)
    for name, vals in (("t0", t0), ("t1", t1)):
        data = None if flow is None else np.asarray(vals, dtype=np.int64).reshape(n)
        group.create_dataset(name, shape=(n,), maxshape=(None,), dtype="<i8",
                             chunks=(1024,), data=data)
    if with_valid:
        data = None if valid is None else np.asarray(valid, dtype=bool).reshape(n, h, w)
        group.create_dataset("valid", shape=(n, h, w), maxshape=(None, h, w), dtype=bool,
                             chunks=(1, h, w), data=data, **kw)


def window_times_ok(t0: int, t1: int, valid: np.ndarray | None) -> bool:
    """Whether ``[t0, t1)`` µs can hold a flow window: ``t1 > t0``, or ``t1 == t0`` for a
    window without a valid pixel (``valid`` given and all False: a window of events all at
    one time, which the estimators skip and the outputs keep, so the windows stay
    numbered as the recording's).

    Examples
    --------
    >>> window_times_ok(5, 5, np.zeros((2, 2), bool)), window_times_ok(5, 5, None)
    (True, False)
    """
    if int(t1) != int(t0):
        return int(t1) > int(t0)
    return valid is not None and not np.asarray(valid).any()


def check_flow_arrays(path, flow, t0, t1, valid, units) -> None:
    """FormatError naming ``path`` unless the arrays read from a flow file make windows:
    ``flow`` (N, H, W, 2) numbers, ``t0``/``t1`` N whole µs with ``t1 > t0``
    (:func:`window_times_ok`), ``valid`` (N, H, W) or None, and ``units`` px/s (the only
    units evmotion writes: a flow stated in other units would be scored as px/s)."""
    flow, t0, t1 = np.asarray(flow), np.asarray(t0), np.asarray(t1)
    if flow.ndim != 4 or flow.shape[-1] != 2 or flow.dtype.kind not in "fiu":
        raise FormatError(path, f"'flow' has shape {flow.shape} and dtype {flow.dtype}: "
                          "expected (windows, height, width, 2) numbers")
    n = flow.shape[0]
    if t0.shape != (n,) or t1.shape != (n,):
        raise FormatError(path, f"'t0' has {t0.size} and 't1' {t1.size} values for "
                          f"{n} flow windows")
    if n and (t0.dtype.kind not in "iu" or t1.dtype.kind not in "iu"):
        raise FormatError(path, f"'t0'/'t1' are {t0.dtype}/{t1.dtype}: expected whole µs")
    bad = [k for k in range(n) if not window_times_ok(
        t0[k], t1[k], None if valid is None else np.asarray(valid[k]))]
    if bad:
        k = bad[0]
        raise FormatError(path, f"window {k} has t1 = {int(t1[k])} us not after t0 = "
                          f"{int(t0[k])} us" + (" and valid pixels" if t1[k] == t0[k] else ""))
    if valid is not None and np.shape(valid) != flow.shape[:3]:
        raise FormatError(path, f"'valid' has shape {np.shape(valid)}, the flow windows "
                          f"{flow.shape[:3]}")
    if units is not None and str(units) != "px/s":
        raise FormatError(path, f"attribute 'units' is {str(units)!r}: evmotion reads flow in "
                          "px/s (flow over the window's duration)")


def read_flow_group(group, path: str | os.PathLike | None = None,
                    index: int | slice | None = None, attrs: dict | None = None) -> FlowSequence:
    """Read a flow group written by :func:`write_flow_group` / :class:`FlowWriter`
    (``attrs``: the group's attributes, when already read)."""
    attrs = read_attrs(path, group) if attrs is None else dict(attrs)
    if attrs.get("format") != FLOW_FORMAT:
        raise FormatError(path, f"group '{group.name}' is not an evmotion flow container "
                          f"(attribute format={attrs.get('format')!r})")
    for name in ("flow", "t0", "t1"):
        if name not in group:
            raise FormatError(path, f"flow container lacks dataset '{group.name}/{name}'")
    n = int(group["t1"].shape[0])
    sel = slice(0, n) if index is None else index
    idx = _selected(n, sel)
    if np.ndim(idx) == 0:
        idx = np.array([int(idx)])
        sel = slice(int(idx[0]), int(idx[0]) + 1)
    flow = group["flow"][sel]
    valid = group["valid"][sel] if "valid" in group else None
    specs = extra_specs(group, path, attrs)
    extras = {name: group[name][sel] for name in specs}
    if specs:
        attrs["extras_units"] = {name: spec.units for name, spec in specs.items()}
    if _legacy_bos(attrs):
        attrs.setdefault("eval_out_px", 1.0)
    t0, t1 = group["t0"][sel], group["t1"][sel]
    if index is None:
        check_flow_arrays(path, flow, group["t0"][:], t1, valid, attrs.get("units"))
    else:
        check_flow_arrays(path, flow, t0, t1, valid, attrs.get("units"))
    return FlowSequence(flow=flow, t0=t0, t1=t1, valid=valid, attrs=attrs, extras=extras)


def _selected(n: int, index: int | slice) -> np.ndarray:
    """The windows ``index`` selects of ``n``, or ParameterError naming it: an index out
    of range had read as "the file is corrupt, truncated or not in this format"."""
    try:
        return np.arange(n)[index]
    except (IndexError, TypeError):
        raise ParameterError(f"index={index!r} selects no window of the {n} the file "
                             "holds") from None


@guarded('flow HDF5')
def read_flow_h5(path: str | os.PathLike, index: int | slice | None = None) -> FlowSequence:
    """Read dense flow windows from an evmotion flow HDF5 file.

    Parameters
    ----------
    path : path-like
        A file written by :class:`FlowWriter` (a ``.part`` file too), simulator ground
        truth (``*_gt.h5``, or an events file with a ``ground_truth`` group or such a
        file beside it).
    index : int or slice, optional
        Which windows (default all complete windows).

    Examples
    --------
    >>> with FlowWriter("flow.h5", (180, 240)) as fw:
    ...     for i in range(3):
    ...         fw.append(np.full((180, 240, 2), i, np.float32), i * 10_000, (i + 1) * 10_000)
    >>> seq = read_flow_h5("flow.h5", index=slice(0, 2))
    >>> seq.flow.shape, seq.t0.tolist()
    ((2, 180, 240, 2), [0, 10000])
    """
    path = Path(path)
    f = open_h5(path)  # registers the Blosc filters of lz4/zstd flow files
    with f:
        root = read_attrs(path, f)
        if root.get("format") == FLOW_FORMAT:
            return read_flow_group(f, path, index, root)
        if root.get("format") == SIM_GT_FORMAT:
            return _read_sim_gt(f, path, index, root)
        if "ground_truth" in f:
            g = f["ground_truth"]
            gt_attrs = read_attrs(path, g)
            if gt_attrs.get("format") == SIM_GT_FORMAT:
                return _read_sim_gt(g, path, index, gt_attrs)
            if "flow" in g:
                return read_flow_group(g["flow"], path, index)
    beside = path.with_name(path.stem + "_gt.h5")
    if beside.exists():
        return read_flow_h5(beside, index)
    raise FormatError(path, "no flow: neither an evmotion flow file (attribute "
                      "format='evmotion-flow'), simulator ground truth, a 'ground_truth' "
                      f"group, nor a {beside.name} beside it")


def _read_sim_gt(g, path: Path, index, attrs: dict) -> FlowSequence:
    # The simulator stores instantaneous flow at frame times; window i is
    # [frame_i, frame_i+1) with the flow at its start and the event mask as valid.
    for name in ("flow", "frame_times_us"):
        if name not in g:
            raise FormatError(path, f"simulator ground truth lacks dataset '{g.name}/{name}'")
    fl, fts = g["flow"], g["frame_times_us"]
    # (an int8 or bool flow was scored as px/s, event masks of another shape a broadcast
    # traceback: probe AQ)
    if fl.dtype.kind != "f" or fl.ndim != 4 or fl.shape[-1] != 2:
        raise FormatError(path, f"simulator ground truth 'flow' is {fl.dtype} {fl.shape}: "
                          "expected float (frames, height, width, 2)")
    if fts.ndim != 1 or fts.dtype.kind not in "iu" or fts.shape[0] != fl.shape[0]:
        raise FormatError(path, f"simulator ground truth 'frame_times_us' is {fts.dtype} "
                          f"{fts.shape}: expected {fl.shape[0]} integer times, one per flow")
    if "event_masks" in g and (g["event_masks"].dtype != bool or g["event_masks"].shape
                               != (max(0, fl.shape[0] - 1), *fl.shape[1:3])):
        raise FormatError(path, f"simulator ground truth 'event_masks' is "
                          f"{g['event_masks'].dtype} {g['event_masks'].shape}: expected bool "
                          f"({max(0, fl.shape[0] - 1)}, {fl.shape[1]}, {fl.shape[2]})")
    ft = fts[:].astype(np.int64)
    n = max(0, ft.size - 1)
    idx = _selected(n, slice(None) if index is None else index)
    idx = np.atleast_1d(idx)
    flow = np.stack([g["flow"][int(i)] for i in idx]) if idx.size else \
        np.zeros((0, *g["flow"].shape[1:]), np.float32)
    valid = None
    if "event_masks" in g:  # (its shape checked above)
        valid = np.stack([g["event_masks"][int(i)] for i in idx]) if idx.size else None
    # (the masks say where events fired, not where the GT is defined: it is everywhere)
    return FlowSequence(flow=flow.astype(np.float32), t0=ft[idx], t1=ft[idx + 1], valid=valid,
                        attrs={**attrs, "valid_is_event_mask": valid is not None})


#: What to do with an unfinished output that cannot be resumed.
START_AGAIN = "delete it and run again without --resume"


def part_holds_nothing(part: str | os.PathLike) -> bool:
    """Whether an unfinished ``.part`` flow file holds no finished window: no such file,
    one with no window, or one too short to hold any that HDF5 cannot open (a run killed
    before HDF5 wrote its first page, 2 KiB: 'truncated file: eof = 96')."""
    import h5py

    part = Path(part)
    if not part.exists():
        return True
    if not is_file(part):
        return False  # (h5py would block on a FIFO: the resume refuses it, naming it)
    try:
        with h5py.File(part, "r") as f:
            return "t1" not in f or int(f["t1"].shape[0]) == 0
    except OSError:
        return part.stat().st_size < 4096


def flow_h5_done(path: str | os.PathLike) -> int:
    """Number of complete windows in a flow file or its unfinished ``.part`` (0 if none)."""
    import h5py

    path = Path(path)
    for p in (_part_path(path), path):
        if p.exists():
            with h5py.File(p, "r") as f:
                return int(f["t1"].shape[0]) if "t1" in f else 0
    return 0


# ---------------------------------------------------------------------------- ground truth
@guarded('MVSEC ground-truth flow')
def read_mvsec_gt_flow(path: str | os.PathLike) -> FlowSequence:
    """Read MVSEC ground-truth flow (``*_gt_flow_dist.npz``).

    The file holds ``timestamps`` (N,) in seconds and ``x_flow_dist``, ``y_flow_dist``
    (N, H, W): pixel displacement from ``timestamps[i]`` to ``timestamps[i+1]``. They are
    returned as px/s over those intervals (N−1 windows). Pixels with zero displacement in
    both components (no depth) are marked invalid.

    Examples
    --------
    >>> dist = np.full((3, 4, 5), 0.5, np.float32)
    >>> np.savez("outdoor_day1_gt_flow_dist.npz", timestamps=[0.0, 0.05, 0.1],
    ...          x_flow_dist=dist, y_flow_dist=-dist)
    >>> gt = read_mvsec_gt_flow("outdoor_day1_gt_flow_dist.npz")
    >>> gt.flow.shape, gt.t1.tolist(), gt.flow[0, 0, 0].tolist()  # px/s
    ((2, 4, 5, 2), [50000, 100000], [10.0, -10.0])
    """
    path = Path(path)
    with open_npz(path) as z:
        if {"vx", "vy", "t"} <= set(z.files):
            # what --method triplet writes: a flow to score, not a ground truth
            raise FormatError(path, "is a per-event flow file (vx, vy per event), not a "
                              "ground truth", "give it as the flow, and the MVSEC-style "
                              "ground truth as --gt")
        for k in ("timestamps", "x_flow_dist", "y_flow_dist"):
            if k not in z.files:
                raise FormatError(path, f"MVSEC ground truth lacks array '{k}'",
                                  f"found {', '.join(z.files)}")
        ts = np.asarray(z["timestamps"], dtype=np.float64)
        xd = np.asarray(z["x_flow_dist"], dtype=np.float32)
        yd = np.asarray(z["y_flow_dist"], dtype=np.float32)
    if xd.shape != yd.shape or xd.ndim != 3 or xd.shape[0] != ts.shape[0]:
        raise FormatError(path, f"inconsistent shapes: timestamps {ts.shape}, x_flow_dist "
                          f"{xd.shape}, y_flow_dist {yd.shape}")
    if ts.shape[0] < 2:
        raise FormatError(path, "need at least two timestamps to know the flow interval")
    t_us = np.rint(ts * 1e6).astype(np.int64)
    dt = np.diff(ts).astype(np.float32)
    if np.any(dt <= 0):
        raise FormatError(path, "field 'timestamps' is not strictly increasing")
    disp = np.stack([xd[:-1], yd[:-1]], axis=-1)
    valid = np.isfinite(disp).all(axis=3) & ((disp[..., 0] != 0) | (disp[..., 1] != 0))
    flow = disp / dt[:, None, None, None]
    return FlowSequence(flow=flow, t0=t_us[:-1], t1=t_us[1:], valid=valid,
                        attrs={"source": str(path), "format": "mvsec-gt"})


@guarded('DSEC ground-truth flow')
def _dsec_gt_layout(path: Path) -> tuple[Path, Path]:
    """The folder of a DSEC flow ground truth's PNGs and its timestamps file."""
    if path.is_file():
        folder = path.parent / "forward" if (path.parent / "forward").is_dir() else path.parent
        return folder, path
    if not (path / "forward").is_dir() and (path / "flow" / "forward").is_dir():
        path = path / "flow"  # the sequence folder that holds flow/
    folder = path / "forward" if (path / "forward").is_dir() else path
    cands = [folder / "forward_timestamps.txt", folder.parent / "forward_timestamps.txt",
             path / "forward_timestamps.txt"]
    ts_file = next((c for c in cands if c.exists()), None)
    if ts_file is None:
        if not any(folder.glob("*.png")):
            raise FormatError(path, "holds no ground truth: no DSEC flow PNGs and "
                              "forward_timestamps.txt, nor one *gt*.h5 / *gt*.npz file "
                              "(give the ground-truth file itself)")
        if (path / "events.txt").is_file():
            # an ECD folder's APS frames taken for DSEC's flow PNGs (probe CI)
            raise FormatError(path, "is an event recording (ECD: events.txt), not a flow "
                              "ground truth: its PNGs are camera frames; its camera motion "
                              "scores egomotion (evmotion eval EGO_DIR --gt FOLDER)")
        raise FormatError(path, "no forward_timestamps.txt beside the flow PNGs")
    return folder, ts_file


def gt_in_folder(path: str | os.PathLike) -> Path:
    """The ground truth a folder given as one stands for: the folder itself where it is a
    DSEC flow ground truth (``forward``, ``flow/forward`` or ``forward_timestamps.txt``),
    else its one file named ``*gt*.h5`` / ``*gt*.npz`` (the simulator's
    ``schlieren_gt.h5`` beside a schlieren scene's events and frames, ``sim_gt.h5``); any
    other path unchanged.

    Examples
    --------
    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp()); _ = (d / "schlieren_gt.h5").write_bytes(b"")
    >>> gt_in_folder(d).name
    'schlieren_gt.h5'
    """
    path = Path(path)
    if not path.is_dir() or any((path / n).exists() for n in
                                ("forward", "flow", "forward_timestamps.txt")):
        return path
    found = sorted(f for f in path.iterdir()
                   if f.suffix.lower() in (".h5", ".npz") and "gt" in f.stem.lower()
                   and f.is_file())
    return found[0] if len(found) == 1 else path


def dsec_gt_files(path: str | os.PathLike) -> list[Path]:
    """The PNGs of a DSEC flow ground truth (folder, its ``flow`` parent, or timestamps
    file), in the order of its timestamps' lines (:func:`read_dsec_gt_flow`)."""
    return sorted(_dsec_gt_layout(Path(path))[0].glob("*.png"))


def read_dsec_gt_flow(path: str | os.PathLike) -> FlowSequence:
    """Read DSEC ground-truth flow: a ``flow/forward`` folder of 16-bit PNGs with
    ``forward_timestamps.txt`` (``from_us, to_us`` per line) beside or inside it.

    Parameters
    ----------
    path : path-like
        The folder of PNGs, its parent ``flow`` folder, or the timestamps file.

    Returns
    -------
    FlowSequence
        Flow in px/s (displacement / interval), NaN and invalid where the PNG says so.
    """
    path = Path(path)
    folder, ts_file = _dsec_gt_layout(path)
    try:
        ts = np.loadtxt(ts_file, delimiter=",", comments="#", dtype=np.int64, ndmin=2)
    except ValueError as exc:
        raise FormatError(ts_file, f"cannot parse 'from_us, to_us' lines: {exc}") from None
    pngs = dsec_gt_files(path)
    if ts.shape[1] == 3:  # from_us, to_us, file_index (the test set's listing)
        ts = ts[:, :2]
    if ts.shape[1] != 2:
        raise FormatError(ts_file, f"expected 2 columns (from_us, to_us), got {ts.shape[1]}")
    if len(pngs) != ts.shape[0]:
        raise FormatError(folder, f"{len(pngs)} flow PNGs but {ts.shape[0]} lines in "
                          f"{ts_file.name}")
    flows, valids = [], []
    for i, p in enumerate(pngs):
        disp, valid = read_dsec_flow_png(p)
        dt = (ts[i, 1] - ts[i, 0]) * 1e-6
        if dt <= 0:
            raise FormatError(ts_file, f"line {i + 1}: to_us {ts[i, 1]} <= from_us {ts[i, 0]}")
        flows.append(disp / np.float32(dt))
        valids.append(valid)
    return FlowSequence(flow=np.stack(flows), t0=ts[:, 0].copy(), t1=ts[:, 1].copy(),
                        valid=np.stack(valids),
                        attrs={"source": str(path), "format": "dsec-gt"})


def _refuse_recording(path: Path) -> None:
    """FormatError where ``path``, given as a ground truth that did not parse as one, is a
    recording of events (an events.txt heard of DSEC's "from_us, to_us" lines, probe
    CC)."""
    from evmotion.io import detect_format

    try:
        fmt = detect_format(path)
    except (FormatError, OSError):
        return
    raise FormatError(path, f"is a recording of events ({fmt}), not a ground truth: give a "
                      "flow (an evmotion flow .h5 / .npz, the simulator's *_gt.h5, MVSEC "
                      "*_gt_flow_dist.npz or a DSEC flow folder / forward_timestamps.txt)")


@guarded('ground-truth flow')
def read_gt_flow(path: str | os.PathLike) -> FlowSequence:
    """Ground-truth flow from MVSEC ``.npz``, a DSEC flow folder / timestamps file, or an
    evmotion HDF5 file (flow container or the simulator's ``ground_truth/flow``).

    Examples
    --------
    >>> with FlowWriter("sim.h5", (4, 5)) as fw:
    ...     fw.append(np.full((4, 5, 2), 20, np.float32), t0=0, t1=10_000)
    >>> gt = read_gt_flow("sim.h5")
    >>> len(gt), gt.t1.tolist(), gt.flow[0, 0, 0].tolist()
    (1, [10000], [20.0, 20.0])
    """
    path = gt_in_folder(path)
    if not path.exists():
        raise FormatError(path, "no such file or folder")
    suffix = path.suffix.lower()
    if path.is_dir() or suffix == ".txt":
        try:
            return read_dsec_gt_flow(path)
        except FormatError:
            if path.is_file():  # (a folder's own words: it "holds no ground truth")
                _refuse_recording(path)
            raise
    if suffix == ".npz":
        with open_npz(path) as z:
            own = "format" in z.files and str(z["format"]) == FLOW_FORMAT
        if own:  # an evmotion flow output as the reference
            from evmotion.io.flowread import read_flow

            return read_flow(path)
        return read_mvsec_gt_flow(path)
    if suffix in (".flo", ".png", ".npy"):
        raise FormatError(path, f"a {suffix} file is not read as ground truth (no times or "
                          "mask of its own): give an evmotion flow .h5 / .npz, the "
                          "simulator's *_gt.h5, MVSEC *_gt_flow_dist.npz or a DSEC flow "
                          "folder / forward_timestamps.txt")
    return read_flow_h5(path)
