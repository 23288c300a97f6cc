"""MVSEC ``*_data.hdf5`` files (Zhu et al. 2018).

Layout (per camera ``left`` / ``right``)::

    /davis/left/events         (N, 4) float64 rows [x, y, t(s), p(-1/+1)]
    /davis/left/image_raw      (M, 260, 346) uint8 APS frames
    /davis/left/image_raw_ts   (M,) s
    /davis/left/imu, imu_ts    (K, 6) and (K,) s (optional)

Times are converted to integer µs (rounded); the sensor is 346×260 (W×H). Events are read
in slices of rows, so streaming is bounded in memory. Ground-truth flow (``*_gt_flow_dist.npz``)
is read by :func:`evmotion.io.flowfiles.read_mvsec_gt_flow`.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from evmotion.errors import EvmotionWarning, FormatError, ParameterError
from evmotion.events import EventArray
from evmotion.io.base import TIME_UNIT_US, FormatSpec
from evmotion.io.guard import check_h5_dataset, check_sensor_size, open_h5
from evmotion.io.h5filters import HDF5_MAGIC
from evmotion.io.npy import events_from_columns

__all__ = ["read", "iter_chunks", "write", "describe", "read_frames", "read_imu", "FORMAT",
           "MVSEC_SENSOR_SIZE"]

MVSEC_SENSOR_SIZE = (260, 346)


def _open(path: Path, camera: str, quiet: bool = False):

    f = open_h5(path)
    key = f"davis/{camera}/events"
    other = f"davis/{'right' if camera == 'left' else 'left'}/events"
    if key not in f and other in f:
        # a file of the other camera only (the right one's, say): read it, said so
        if not quiet:
            warnings.warn(EvmotionWarning(f"{path}: no {key}; read {other}"), stacklevel=3)
        key = other
    if key not in f:
        f.close()
        raise FormatError(path, f"missing dataset '{key}' (not an MVSEC data file?)")
    try:
        ds = check_h5_dataset(path, f, key, ndim=2, kinds="iuf", row=4)
    except BaseException:
        f.close()
        raise
    return f, ds, key.split("/")[1]


def _make(path: Path, block: np.ndarray, size, meta, validate: bool,
          time_unit: str | None) -> EventArray:
    if size == MVSEC_SENSOR_SIZE and "sensor_size_from" not in meta:
        meta = {**meta, "sensor_size_from": "MVSEC's DAVIS346, 346 x 260 (the file states "
                "no size)"}
    return events_from_columns(path, block[:, 0], block[:, 1], block[:, 2], block[:, 3],
                               sensor_size=size, time_unit=time_unit, format_unit="s",
                               format_name="MVSEC", meta=meta, validate=validate)


def _locate(ds, tq_us: int, n: int, us_per_unit: float) -> int:
    # Bisection on rows read one at a time: O(log N) small reads, no full time column.
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) // 2
        if round(float(ds[mid, 2]) * us_per_unit) < tq_us:
            lo = mid + 1
        else:
            hi = mid
    return lo


def _size(path: Path, f, camera: str, sensor_size) -> tuple[int, int]:
    """The size asked for, else the one evmotion's writer stores (``sensor_size`` attribute
    of the camera's group, not part of MVSEC's layout), else the DAVIS346's 260 x 346."""
    if sensor_size:
        return tuple(sensor_size)
    attrs = f[f"davis/{camera}"].attrs
    if "sensor_size" in attrs:
        return check_sensor_size(path, attrs["sensor_size"],
                                 f"attribute 'davis/{camera}/sensor_size'")
    return MVSEC_SENSOR_SIZE


def read(path: str | os.PathLike, t0: int | None = None, t1: int | None = None, *,
         sensor_size: tuple[int, int] | None = None, camera: str = "left",
         validate: bool = True, time_unit: str | None = None) -> EventArray:
    """Read events of one MVSEC camera.

    Parameters
    ----------
    t0, t1 : int, optional
        Keep ``t0 <= t < t1`` (µs, the file's clock).
    camera : {"left", "right"}
        Which DAVIS.
    time_unit : {"s", "ms", "us", "ns"}, optional
        The unit of the file's times where it is not MVSEC's seconds (other tools write
        the layout with µs); default seconds, with a warning where the times' rate says
        another unit.

    Examples
    --------
    >>> write("indoor_flying1_data.hdf5", EventArray(
    ...     x=[10, 20, 30], y=[5, 6, 7], t=[100, 200, 300], p=[1, 0, 1], sensor_size=(260, 346)))
    >>> ev = read("indoor_flying1_data.hdf5", t0=150, t1=400)
    >>> len(ev), ev.t.tolist(), ev.meta["camera"]
    (2, [200, 300], 'left')
    """
    path = Path(path)
    f, ds, camera = _open(path, camera)
    with f:
        n = ds.shape[0]
        scale = TIME_UNIT_US[time_unit or "s"]
        lo = 0 if t0 is None else _locate(ds, int(t0), n, scale)
        hi = n if t1 is None else _locate(ds, int(t1), n, scale)
        block = ds[lo:max(lo, hi)]
        size = _size(path, f, camera, sensor_size)
    meta = {"source": str(path), "format": "mvsec", "camera": camera}
    ev = _make(path, block, size, meta, validate, time_unit)
    return ev.slice_time(t0, t1) if (t0 is not None or t1 is not None) else ev


def iter_chunks(path: str | os.PathLike, chunk_events: int, *,
                sensor_size: tuple[int, int] | None = None, camera: str = "left",
                validate: bool = True, time_unit: str | None = None
                ) -> Iterator[EventArray]:
    """Stream one camera's events in chunks of ``chunk_events`` (``time_unit`` as in
    :func:`read`; the first chunk's times are doubted, the others read alike)."""
    if int(chunk_events) <= 0:
        raise ParameterError(f"chunk_events must be positive, got {chunk_events}")
    path = Path(path)
    f, ds, camera = _open(path, camera)
    size = _size(path, f, camera, sensor_size)
    meta = {"source": str(path), "format": "mvsec", "camera": camera}
    with f:
        for s in range(0, ds.shape[0], int(chunk_events)):
            yield _make(path, ds[s:s + int(chunk_events)], size, meta, validate,
                        time_unit if time_unit is not None or s == 0 else "s")


def read_frames(path: str | os.PathLike, camera: str = "left") -> dict:
    """APS frames: ``{"t": (M,) µs, "images": (M, H, W) uint8}``."""
    import h5py

    path = Path(path)
    with h5py.File(path, "r") as f:
        g = f"davis/{camera}"
        for k in ("image_raw", "image_raw_ts"):
            if f"{g}/{k}" not in f:
                raise FormatError(path, f"missing dataset '{g}/{k}'")
        return {"t": np.rint(f[f"{g}/image_raw_ts"][:] * 1e6).astype(np.int64),
                "images": f[f"{g}/image_raw"][:]}


def write(path: str | os.PathLike, events: EventArray, *, camera: str = "left",
          frames: dict | None = None) -> None:
    """Write events (and optional frames ``{"t": µs, "images": (M,H,W)}``) in the MVSEC
    layout, atomically. Times become float64 seconds, which read back to the µs up to
    about 2^50 µs (Unix times until the 2030s); where any does not, a warning says how
    many and by how much."""
    import h5py

    from evmotion.utils import atomic_path

    arr = np.column_stack([events.x.astype(np.float64), events.y.astype(np.float64),
                           events.t.astype(np.float64) * 1e-6,
                           np.where(events.p > 0, 1.0, -1.0)])
    off = np.abs(np.rint(arr[:, 2] * 1e6).astype(np.int64) - events.t)
    if off.any():
        # (probe DJ: 9 % of the times past 2^51 us came back 1 us off, unsaid)
        warnings.warn(f"{path}: {np.count_nonzero(off):,} of {len(off):,} times read back "
                      f"up to {int(off.max())} us off: MVSEC's layout holds float64 seconds, "
                      f"too coarse at {int(events.t[-1])} us; write .h5 to keep them exact",
                      EvmotionWarning, stacklevel=3)
    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            g = f.create_group(f"davis/{camera}")
            # not in MVSEC's layout (its DAVIS346 is 346 x 260): what a reader of another
            # size needs
            g.attrs["sensor_size"] = np.asarray(events.sensor_size, np.int64)
            g.create_dataset("events", data=arr.reshape(-1, 4),
                             chunks=(min(len(arr), 1 << 16), 4) if len(arr) else None)
            if frames is not None:
                g.create_dataset("image_raw", data=np.asarray(frames["images"]))
                g.create_dataset("image_raw_ts",
                                 data=np.asarray(frames["t"], np.float64) * 1e-6)


def read_imu(path: str | os.PathLike, camera: str = "left") -> dict:
    """The DAVIS IMU samples (``davis/<camera>/imu``, ``imu_ts`` in s) as ``{"t": µs,
    "accel": m/s², "gyro": rad/s}``.

    The (K, 6) rows hold the two triples of a ``sensor_msgs/Imu``; which one comes first is
    told by gravity: the triple whose mean norm is nearer 9.81 m/s² is the acceleration (the
    file does not say, and the two orders are both in use). Where neither is near it (a
    free-falling or mislabelled IMU), the message's order is taken, angular velocity first,
    with a warning.

    >>> import h5py
    >>> write("indoor_flying1_data.hdf5", EventArray(
    ...     x=[10], y=[5], t=[100], p=[1], sensor_size=(260, 346)))
    >>> with h5py.File("indoor_flying1_data.hdf5", "a") as f:  # rows: gyro, then accel
    ...     f["davis/left/imu"] = np.tile([0.0, 0.0, 0.1, 0.0, -9.81, 0.0], (5, 1))
    ...     f["davis/left/imu_ts"] = np.arange(5) * 0.001
    >>> imu = read_imu("indoor_flying1_data.hdf5")
    >>> imu["accel"].shape, imu["accel"][0].tolist(), imu["t"][:2].tolist()
    ((5, 3), [0.0, -9.81, 0.0], [0, 1000])
    """
    path = Path(path)
    f, _, camera = _open(path, camera, quiet=True)
    with f:
        g = f[f"davis/{camera}"]
        if "imu" not in g or "imu_ts" not in g:
            raise FormatError(path, f"no IMU samples (davis/{camera}/imu, imu_ts)")
        ts = check_h5_dataset(path, f, f"davis/{camera}/imu_ts", ndim=1, kinds="iuf")[()]
        data = check_h5_dataset(path, f, f"davis/{camera}/imu", ndim=2, kinds="iuf",
                                length=ts.shape[0], row=6)[()]
    ts = np.asarray(ts, np.float64)
    data = np.asarray(data, np.float64)
    if not (np.isfinite(data).all() and np.isfinite(ts).all()):
        raise FormatError(path, f"davis/{camera}/imu or imu_ts holds NaN or inf")
    norms = [float(np.mean(np.linalg.norm(data[:, k:k + 3], axis=1))) if len(data) else 0.0
             for k in (0, 3)]
    near = [abs(n - 9.81) < 4.0 for n in norms]
    accel_first = near[0] and (not near[1] or abs(norms[0] - 9.81) < abs(norms[1] - 9.81))
    if len(data) and not any(near):
        warnings.warn(EvmotionWarning(
            f"{path}: neither triple of davis/{camera}/imu averages near gravity (mean norms "
            f"{norms[0]:.3g}, {norms[1]:.3g}): taken as angular velocity, then acceleration"),
            stacklevel=2)
    a, w = (data[:, 0:3], data[:, 3:6]) if accel_first else (data[:, 3:6], data[:, 0:3])
    return {"t": np.rint(ts * 1e6).astype(np.int64), "accel": a, "gyro": w}


def describe(path: str | os.PathLike, camera: str = "left") -> dict:
    path = Path(path)
    f, ds, camera = _open(path, camera, quiet=True)
    with f:
        n = ds.shape[0]
        g = f[f"davis/{camera}"]
        out: dict = {"format": "mvsec", "camera": camera,
                     "sensor_size": _size(path, f, camera, None),
                     "n_events": int(n), "cameras": sorted(f["davis"].keys())}
        if n:
            out["t_first_us"] = round(float(ds[0, 2]) * 1e6)
            out["t_last_us"] = round(float(ds[n - 1, 2]) * 1e6)
        out["frames"] = int(g["image_raw_ts"].shape[0]) if "image_raw_ts" in g else 0
        out["imu"] = int(g["imu_ts"].shape[0]) if "imu_ts" in g else 0
    return out


def _sniff(path: Path, head: bytes) -> bool:
    if not head.startswith(HDF5_MAGIC):
        return False
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return "davis" in f
    except OSError:
        return False


FORMAT = FormatSpec(name="mvsec", extensions=(".hdf5", ".h5"), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
