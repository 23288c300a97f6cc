"""APS frames and IMU samples from any recording that holds them, in one shape.

Each format module may define ``read_frames(path)`` and ``read_imu(path)``; these helpers
find the module through the registry and return the same small dataclasses whatever the
source (ECD folder, evmotion HDF5, MVSEC, AEDAT4, AEDAT2...).
"""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError
from evmotion.io.registry import resolve_format

__all__ = ["FrameSequence", "ImuSequence", "read_frames", "read_imu"]


@dataclass(frozen=True)
class FrameSequence:
    """APS frames: ``t`` (N,) int64 µs and ``images``, a list of (H, W) or (H, W, C) uint8
    arrays (an (N, H, W) array when the source stores a stack)."""

    t: np.ndarray
    images: list | np.ndarray

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True)
class ImuSequence:
    """IMU samples: ``t`` (N,) int64 µs, ``gyro`` (N, 3) rad/s, ``accel`` (N, 3) m/s², in
    the IMU's own axes as the source stores them."""

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray

    def __len__(self) -> int:
        return int(self.t.shape[0])


def _module(path: Path, format: str | None):
    spec = resolve_format(path, format or None)
    return spec.name, importlib.import_module(spec.read.__module__)


def _get(obj, key: str):
    return obj[key] if isinstance(obj, dict) else getattr(obj, key)


def read_frames(path: str | os.PathLike, format: str | None = None) -> FrameSequence:
    """APS frames of a recording.

    Examples
    --------
    >>> from evmotion import EventArray
    >>> from evmotion.io import write_events
    >>> write_events("davis346.h5", EventArray(x=[1], y=[2], t=[0], p=[1],
    ...              sensor_size=(260, 346)), frames={"t": np.array([0, 40_000]),
    ...                                            "images": np.zeros((2, 260, 346), np.uint8)})
    >>> fr = read_frames("davis346.h5")
    >>> fr.t[:2].tolist(), fr.images[0].shape
    ([0, 40000], (260, 346))
    """
    path = Path(path)
    name, mod = _module(path, format)
    if not hasattr(mod, "read_frames"):
        raise FormatError(path, f"format '{name}' holds no APS frames")
    fr = mod.read_frames(path)
    return FrameSequence(t=np.asarray(_get(fr, "t"), np.int64), images=_get(fr, "images"))


def read_imu(path: str | os.PathLike, format: str | None = None) -> ImuSequence:
    """IMU samples of a recording, whatever its format.

    Reads ``imu.txt`` of an ECD folder, the IMU packets of AEDAT4, cAER AEDAT 3.1 and jAER
    AEDAT 2.0 files, MVSEC's ``davis/<camera>/imu``, the ``imu`` group of evmotion HDF5 and
    the IMU messages of ROS1 bags.

    Parameters
    ----------
    path : str or path-like
        Recording file or folder.
    format : str, optional
        Format name (see :func:`evmotion.io.all_formats`); default detected by content.

    Returns
    -------
    ImuSequence
        ``t`` (N,) int64 µs on the events' clock; ``gyro`` (N, 3) float64 angular velocity
        in rad/s; ``accel`` (N, 3) float64 linear acceleration in m/s² (gravity included).
        Axes are the IMU's own as the source stores them (a DAVIS IMU is not the camera
        frame: rotate with the extrinsics before comparing with a rotation estimate).

    Raises
    ------
    FormatError
        The format holds no IMU samples, or this file has none.

    Examples
    --------
    >>> import tempfile, numpy as np
    >>> from evmotion.events import EventArray
    >>> from evmotion.io import h5
    >>> ev = EventArray(np.array([1, 2]), np.array([0, 1]), np.array([10, 20]),
    ...                 np.array([1, 0]), sensor_size=(2, 3))
    >>> path = tempfile.mkdtemp() + "/rec.h5"
    >>> h5.write(path, ev, imu={"t": [0, 1000], "gyro": np.zeros((2, 3)),
    ...                         "accel": [[0.0, -9.81, 0.0]] * 2})
    >>> imu = read_imu(path)
    >>> len(imu), imu.t.tolist(), imu.accel[0].tolist()
    (2, [0, 1000], [0.0, -9.81, 0.0])
    """
    path = Path(path)
    name, mod = _module(path, format)
    if not hasattr(mod, "read_imu"):
        raise FormatError(path, f"format '{name}' holds no IMU samples")
    if name == "ecd" and path.is_file() and path.name != "imu.txt":
        # an ECD events file: its IMU is the imu.txt beside it (reading the events file
        # as an IMU table cost a second pass over the whole recording, to fail)
        if not (path.parent / "imu.txt").is_file():
            raise FormatError(path, "no imu.txt beside this ECD events file")
        path = path.parent / "imu.txt"
    s = mod.read_imu(path)
    return ImuSequence(t=np.asarray(_get(s, "t"), np.int64),
                       gyro=np.asarray(_get(s, "gyro"), np.float64),
                       accel=np.asarray(_get(s, "accel"), np.float64))
