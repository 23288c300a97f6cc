"""Dense flow windows streamed to the containers that are not the flow HDF5
(:class:`~evmotion.io.flowfiles.FlowWriter`): one ``.npy`` stack, or a ``.flo`` per window.

Both take the windows one at a time (``append(flow, t0, t1, valid=None)``), when their number
is not known in advance, and leave nothing behind when a run fails (:meth:`abort`).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from evmotion.errors import ParameterError
from evmotion.io.base import PartFileWriter
from evmotion.io.flowfiles import write_flo
from evmotion.utils import atomic_path

__all__ = ["FloSeriesWriter", "NpyFlowWriter"]


def _check(flow: np.ndarray, sensor_size: tuple[int, int]) -> np.ndarray:
    arr = np.asarray(flow)
    if arr.shape != (*sensor_size, 2):
        raise ParameterError(f"flow has shape {arr.shape}, expected {(*sensor_size, 2)}")
    return arr


class NpyFlowWriter(PartFileWriter):
    """Windows streamed to a raw temporary file, then written as one ``(N, H, W, 2)``
    float32 ``.npy`` (px/s) once N is known, without holding the windows in memory. The
    file holds no times and no mask (zero flow where not valid).

    Examples
    --------
    >>> with NpyFlowWriter("flow.npy", (180, 240)) as w:  # doctest: +SKIP
    ...     w.append(np.zeros((180, 240, 2), np.float32), 0, 10_000)
    """

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int]) -> None:
        self.path = Path(path)
        self.sensor_size = tuple(int(v) for v in sensor_size)
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        self._raw = tempfile.TemporaryFile(prefix=".flow-", dir=self.path.parent)
        self.n = 0

    def append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray | None = None
               ) -> None:
        """Add one window (px/s); pixels outside ``valid`` are stored as zero flow."""
        arr = _check(flow, self.sensor_size)
        if valid is not None:
            arr = np.where(np.asarray(valid, bool)[..., None], arr, np.float32(0))
        self._raw.write(np.ascontiguousarray(arr, dtype="<f4").tobytes())
        self.n += 1

    def close(self) -> None:
        self._raw.seek(0)
        with open(self._tmp, "wb") as dst:
            np.lib.format.write_array_header_1_0(
                dst, {"descr": "<f4", "fortran_order": False,
                      "shape": (self.n, *self.sensor_size, 2)})
            while block := self._raw.read(1 << 22):
                dst.write(block)
        self._raw.close()
        self._ctx.__exit__(None, None, None)

    def abort(self) -> None:
        self._raw.close()
        self._ctx.__exit__(RuntimeError, RuntimeError("aborted"), None)


class FloSeriesWriter(PartFileWriter):
    """Middlebury ``.flo`` displacement over each window (:func:`write_flo`): ``path``
    itself for a single window, ``<stem>_0000.flo``... otherwise; each file is written
    atomically as its window comes, and :meth:`abort` removes the files written.

    Examples
    --------
    >>> with FloSeriesWriter("flow.flo", (180, 240)) as w:  # doctest: +SKIP
    ...     w.append(np.zeros((180, 240, 2), np.float32), 0, 10_000)
    """

    def __init__(self, path: str | os.PathLike, sensor_size: tuple[int, int]) -> None:
        self.path = Path(path)
        self.sensor_size = tuple(int(v) for v in sensor_size)
        self._first: tuple | None = None
        self.n = 0
        self.written: list[Path] = []

    def _numbered(self, i: int) -> Path:
        return self.path.with_name(f"{self.path.stem}_{i:04d}.flo")

    def _write(self, path: Path, win: tuple) -> None:
        flow, t0, t1, valid = win
        if valid is not None:
            flow = np.where(np.asarray(valid, bool)[..., None], flow, np.float32(0))
        write_flo(path, flow, dt_s=(t1 - t0) * 1e-6)
        self.written.append(path)

    def append(self, flow: np.ndarray, t0: int, t1: int, valid: np.ndarray | None = None
               ) -> None:
        """Add one window: ``flow`` (H, W, 2) px/s over ``[t0, t1)`` µs."""
        win = (_check(flow, self.sensor_size), int(t0), int(t1), valid)
        if self.n == 0:
            self._first = win
        else:
            if self.n == 1:
                self._write(self._numbered(0), self._first)
                self._first = None
            self._write(self._numbered(self.n), win)
        self.n += 1

    def close(self) -> None:
        if self._first is not None:
            self._write(self.path, self._first)
            self._first = None

    def abort(self) -> None:
        self._first = None
        for path in self.written:
            path.unlink(missing_ok=True)
