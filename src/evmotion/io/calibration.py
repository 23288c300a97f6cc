"""The camera calibration stored with a recording: an ECD ``calib.txt`` or the
``calibration`` attribute of an evmotion HDF5 file (:func:`read_calibration`).

Examples
--------
>>> from evmotion.io.calibration import read_calibration
>>> read_calibration("boxes_rotation/")["fx"]  # doctest: +SKIP
199.092366542
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from evmotion.errors import FormatError
from evmotion.io.guard import guard_call

__all__ = ["read_calibration"]


def read_calibration(path: str | os.PathLike) -> dict:
    """Camera calibration stored with a recording.

    Accepts an ECD ``calib.txt`` or a folder holding one, or an evmotion HDF5 file with a
    ``calibration`` attribute.

    Returns
    -------
    dict
        ``K`` (3x3 nested list, px), ``dist`` (``[k1, k2, p1, p2, k3]`` radial-tangential),
        ``fx, fy, cx, cy``, ``model``, ``source`` and ``sensor_size`` when known.

    Examples
    --------
    >>> read_calibration("boxes_rotation/")["dist"][:2]  # doctest: +SKIP
    [-0.368436311798, 0.150947243557]
    """
    from evmotion.io import ecd

    path = Path(path)
    if not path.exists():
        raise FormatError(path, "no such file or folder")
    if path.is_dir() or path.suffix.lower() == ".txt":
        return ecd.read_calibration(path)
    with open(path, "rb") as fh:
        head = fh.read(8)
    if head.startswith(b"\x89HDF\r\n\x1a\n"):
        return guard_call(_h5_calibration, "HDF5", "read the calibration")(path)
    raise FormatError(path, "no calibration found",
                      "give an ECD calib.txt or an evmotion .h5 with calibration; YAML "
                      "calibrations are read by evmotion.camera.Camera.from_file")


def _h5_calibration(path: Path) -> dict:
    import h5py

    with h5py.File(path, "r") as f:
        if "calibration" in f.attrs:
            cal = json.loads(f.attrs["calibration"])
            if not isinstance(cal, dict):
                raise FormatError(path, "attribute 'calibration' is not a JSON object")
            cal.setdefault("sensor_size", [int(f.attrs["height"]), int(f.attrs["width"])]
                           if "height" in f.attrs else None)
            return cal
    raise FormatError(path, "no 'calibration' attribute in this HDF5 file")
