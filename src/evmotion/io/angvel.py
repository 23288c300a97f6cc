"""Reference angular velocities for ego-motion estimates (the thesis scores the rotation
warp against the IMU's gyroscope, Tables 3.1-3.3): a recording's IMU samples, or a text
table of them.

Text layouts (``#`` comments; the time in seconds, as the ECD's files have it):

- ``t gx gy gz``: the angular velocity (rad/s) at time t;
- ``t ax ay az gx gy gz``: the ECD's ``imu.txt``, the acceleration (m/s²) then the angular
  velocity;
- ``gx gy gz``: one constant angular velocity (a window's, as the shared data's
  ``motion.txt``).

Anything else :func:`evmotion.io.read_imu` reads (an ECD folder's ``imu.txt``, AEDAT 2, 3.1
and 4, ROS bags, MVSEC, evmotion HDF5 with IMU samples) gives its gyroscope.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError

__all__ = ["TABLE_LAYOUTS", "AngularVelocity", "is_angular_velocity_table", "parse_axes",
           "read_angular_velocity", "text_columns"]

# the layouts of a text table, by their number of columns: where the gyroscope is
_GYRO_COLUMNS = {3: slice(0, 3), 4: slice(1, 4), 7: slice(4, 7)}
#: The layouts, as the errors about a table that has none of them name them.
TABLE_LAYOUTS = "'t gx gy gz' (s, rad/s), the ECD's 't ax ay az gx gy gz', or one line 'gx gy gz'"


@dataclass(frozen=True)
class AngularVelocity:
    """Reference angular velocities: ``t`` (N,) int64 µs, or None for one constant value;
    ``omega`` (N, 3) rad/s in the camera's axes; ``source`` says where they came from."""

    t: np.ndarray | None
    omega: np.ndarray
    source: str

    def __len__(self) -> int:
        return int(self.omega.shape[0])


def parse_axes(text: str) -> np.ndarray:
    """The camera's axes as signed IMU axes, ``"x,y,z"`` (the same) or e.g. ``"-x,y,-z"``:
    a 3 x 3 matrix ``M`` with ``omega_camera = M @ omega_imu``.

    Examples
    --------
    >>> parse_axes("-y,x,z") @ np.array([1.0, 2.0, 3.0])
    array([-2.,  1.,  3.])
    """
    parts = [p.strip().lower() for p in str(text).split(",")]
    m = np.zeros((3, 3))
    used = set()
    for row, part in enumerate(parts):
        match = re.fullmatch(r"([+-]?)([xyz])", part)
        if len(parts) != 3 or match is None or match.group(2) in used:
            raise ParameterError(f"--imu-axes {text!r}: give the camera's x, y and z as "
                                 "the IMU's axes, each once with a sign, e.g. x,y,z or "
                                 "-x,y,-z")
        used.add(match.group(2))
        m[row, "xyz".index(match.group(2))] = -1.0 if match.group(1) == "-" else 1.0
    return m


def is_angular_velocity_table(path: str | os.PathLike) -> bool:
    """Whether ``path`` is a text table of angular velocities (see the module's layouts),
    or a folder holding the ECD's ``imu.txt`` or a ``motion.txt``."""
    p = Path(path)
    if p.is_dir():
        return (p / "imu.txt").is_file() or (p / "motion.txt").is_file()
    if p.suffix.lower() not in (".txt", ".csv") or not p.is_file():
        return False
    return text_columns(p) in _GYRO_COLUMNS


def text_columns(path: str | os.PathLike) -> int | None:
    """The number of numeric columns of a text table's first data line (past one header
    line of names, ``t gx gy gz``), None if it has none."""
    header = False
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                text = line.strip()
                if not text or text.startswith("#"):
                    continue
                fields = re.split(r"[\s,;]+", text)
                try:
                    [float(f) for f in fields]
                except ValueError:
                    if header or not all(re.fullmatch(r"[A-Za-z_][\w\[\]/()]*", f)
                                         for f in fields):
                        return None
                    header = True  # a line of column names (probe BM: refused)
                    continue
                return len(fields)
    except OSError:
        return None
    return None


def read_angular_velocity(path: str | os.PathLike, *, axes: str = "x,y,z",
                          format: str | None = None) -> AngularVelocity:
    """Angular velocities to score a rotation estimate against: a text table (see the
    module's layouts), a folder's ``imu.txt`` / ``motion.txt``, or any recording's IMU
    (:func:`evmotion.io.read_imu`).

    Parameters
    ----------
    path : path-like
    axes : str
        The camera's axes as the source's (:func:`parse_axes`): an IMU's are its own (a
        DAVIS's differ from the camera's); default the same.
    format : str, optional
        The recording's format, for an IMU read from a recording.

    Examples
    --------
    >>> _ = Path("gyro.txt").write_text("# t gx gy gz\\n0.0 0.1 0.2 0.3\\n0.001 0.1 0.2 0.4\\n")
    >>> ref = read_angular_velocity("gyro.txt", axes="x,-y,z")
    >>> ref.t.tolist(), ref.omega[1].tolist()
    ([0, 1000], [0.1, -0.2, 0.4])
    """
    m = parse_axes(axes)
    p = Path(path)
    if p.is_dir():
        p = next((p / n for n in ("imu.txt", "motion.txt") if (p / n).is_file()), p)
    if p.is_file() and is_angular_velocity_table(p):
        t, omega = _read_table(p)
    elif p.is_file() and p.suffix.lower() in (".txt", ".csv"):
        # a text file is a table or nothing: read as a recording, a 5-column table beside
        # an imu.txt was scored against that imu.txt (probe BM)
        cols = text_columns(p)
        raise FormatError(p, f"{'no numeric line' if cols is None else f'{cols} columns'}: "
                          f"an angular-velocity table has {TABLE_LAYOUTS}")
    else:
        from evmotion.io import read_imu

        imu = read_imu(p, format=format)
        t, omega = np.asarray(imu.t, np.int64), np.asarray(imu.gyro, np.float64)
    if omega.size == 0:
        raise FormatError(p, "holds no angular velocity sample")
    if not np.isfinite(omega).all():
        bad = int(np.argmax(~np.isfinite(omega).all(axis=1)))
        raise FormatError(p, f"sample {bad} has a NaN or infinite angular velocity")
    if t is not None and t.size > 1 and np.any(np.diff(t) < 0):
        bad = int(np.argmax(np.diff(t) < 0)) + 1
        raise FormatError(p, f"sample {bad} (t = {t[bad]} us) comes before the one above it: "
                          "the samples must be in time order")
    return AngularVelocity(t=t, omega=omega @ m.T, source=str(p))


def _read_table(path: Path) -> tuple[np.ndarray | None, np.ndarray]:
    text = path.read_text(encoding="utf-8", errors="replace")
    rows = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if rows and re.search(r"[A-Za-z_]", rows[0].replace("e-", "").replace("e+", "")):
        rows = rows[1:]  # its header line of names
    try:
        arr = np.array([[float(v) for v in re.split(r"[\s,;]+", ln.strip())] for ln in rows],
                       dtype=np.float64)
    except ValueError as exc:
        raise FormatError(path, f"cannot read the table of angular velocities: {exc}"
                          ) from None
    if arr.ndim != 2 or not arr.size:
        raise FormatError(path, "holds no angular velocity sample, or lines of different "
                          "lengths")
    cols = arr.shape[1]
    if cols not in _GYRO_COLUMNS:
        raise FormatError(path, f"{cols} columns: an angular-velocity table has {TABLE_LAYOUTS}")
    omega = arr[:, _GYRO_COLUMNS[cols]].astype(np.float64)
    if cols == 3:
        if len(arr) != 1:
            raise FormatError(path, f"{len(arr)} lines of 'gx gy gz' with no time: give "
                              "one line (a constant), or a time column first")
        return None, omega
    t = arr[:, 0]
    if not np.isfinite(t).all() or np.abs(t).max() > 2.0**62 / 1e6:
        raise FormatError(path, "a time that is not a number of seconds")
    return np.rint(t * 1e6).astype(np.int64), omega
