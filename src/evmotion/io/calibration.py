"""The camera calibration stored with a recording, as a plain dict: an ECD ``calib.txt``,
the ``calibration`` attribute of an evmotion HDF5 file, or a calibration file
(:func:`read_calibration`). The file-format readers returning a
:class:`~evmotion.camera.Camera` live in :mod:`evmotion.io.calib`.

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
from evmotion.io.h5attrs import read_attrs
from evmotion.io.h5filters import is_hdf5

__all__ = ["read_calibration"]


def read_calibration(path: str | os.PathLike) -> dict:
    """Camera calibration stored with a recording.

    Accepts an ECD ``calib.txt`` or a folder holding one, an evmotion HDF5 file with a
    ``calibration`` attribute, or any calibration file :func:`evmotion.io.calib.read_calibration`
    reads (Kalibr / ROS / DSEC YAML, DV XML, JSON). For a
    :class:`~evmotion.camera.Camera`, use :func:`evmotion.io.calib.read_calibration`.

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
    if is_hdf5(path):
        return guard_call(_h5_calibration, "HDF5", "read the calibration")(path)
    if path.suffix.lower() in (".yaml", ".yml", ".xml", ".json"):
        from evmotion.io import calib

        return calib.camera_to_dict(calib.read_calibration(path))
    raise FormatError(path, "no calibration found",
                      "give an ECD calib.txt, an evmotion .h5 with calibration, or a "
                      "calibration .yaml/.xml/.json")


def _h5_calibration(path: Path) -> dict:
    import h5py

    with h5py.File(path, "r") as f:
        attrs = read_attrs(path, f, ("calibration", "height", "width"))
        if "calibration" in attrs:
            try:
                cal = json.loads(attrs["calibration"])
            except (TypeError, ValueError):
                raise FormatError(path, "attribute 'calibration' is not valid JSON") from None
            if not isinstance(cal, dict):
                raise FormatError(path, "attribute 'calibration' is not a JSON object")
            cal.setdefault("sensor_size", [int(attrs["height"]), int(attrs["width"])]
                           if "height" in attrs and "width" in attrs else None)
            return cal
    raise FormatError(path, "no 'calibration' attribute in this HDF5 file")
