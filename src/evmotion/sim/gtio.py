"""Saving and loading simulator ground truth (HDF5).

Layout (a file of its own, ``<events stem>_gt.h5``, or a ``/ground_truth`` group):

* attributes ``scene``, ``sensor_size`` (height, width), ``duration_us``, ``format``
  (``evmotion-sim-gt``), ``version``;
* ``K`` (3, 3) pinhole intrinsics, pixels;
* ``frame_times_us`` (F,) int64 virtual GT frame times;
* ``flow`` (F, H, W, 2) float32, px/s, u right, v down, at the frame times;
* ``displacement`` (F-1, H, W, 2) float32 px: where each pixel's scene point at frame
  ``i`` is at frame ``i + 1`` (integrated along the trajectory, as MVSEC's GT);
* ``angular_velocity`` (F, 3) rad/s, camera frame (NaN where not a camera rotation);
* ``event_masks`` (F-1, H, W) bool: events between consecutive frames;
* ``layers/<i>`` (bottom first): attributes ``name``, ``warp``, ``center``, ``t_ref_s``,
  ``param_names``, ``param_units``; datasets ``theta`` (P,) (the warp's parameters
  referenced at ``t_ref_s``), ``params`` (F, P) (referenced at each frame time), and for
  occluding layers ``alpha`` (Ht, Wt) float32 with attribute ``origin``.

:func:`read_ground_truth` rebuilds a :class:`~evmotion.sim.groundtruth.GroundTruth` that
evaluates flow, displacement and parameters at any time, exactly as after simulation.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from evmotion.errors import FormatError
from evmotion.io.h5attrs import read_attrs
from evmotion.sim.groundtruth import GroundTruth, Layer
from evmotion.sim.motions import make_motion
from evmotion.utils import atomic_path

__all__ = ["gt_path_for", "read_ground_truth", "write_ground_truth"]

GT_FORMAT = "evmotion-sim-gt"
GT_VERSION = 1


def gt_path_for(events_path: str | Path) -> Path:
    """``<dir>/<stem>_gt.h5`` beside an events file."""
    p = Path(events_path)
    return p.with_name(p.stem + "_gt.h5")


def _write_group(g, gt: GroundTruth) -> None:
    g.attrs["format"] = GT_FORMAT
    g.attrs["version"] = GT_VERSION
    g.attrs["scene"] = gt.scene
    g.attrs["sensor_size"] = np.asarray(gt.sensor_size, dtype=np.int64)
    g.attrs["duration_us"] = int(gt.duration_us)
    g["K"] = np.asarray(gt.K, dtype=np.float64)
    ft = np.asarray(gt.frame_times_us, dtype=np.int64)
    g["frame_times_us"] = ft
    h, w = gt.sensor_size
    flow = g.create_dataset("flow", shape=(len(ft), h, w, 2), dtype=np.float32,
                            chunks=(1, h, w, 2), compression="gzip", compression_opts=4)
    for i, t in enumerate(ft):
        flow[i] = gt.flow(int(t))
    nd = max(0, len(ft) - 1)
    disp = g.create_dataset("displacement", shape=(nd, h, w, 2), dtype=np.float32,
                            **({"chunks": (1, h, w, 2), "compression": "gzip",
                                "compression_opts": 4} if nd else {}))
    for i in range(len(ft) - 1):
        disp[i] = gt.displacement(int(ft[i]), int(ft[i + 1]))
    g["angular_velocity"] = np.repeat(gt.angular_velocity()[None], len(ft), axis=0)
    masks = np.stack([gt.event_mask(int(a), int(b)) for a, b in zip(ft[:-1], ft[1:],
                                                                    strict=True)]) \
        if len(ft) > 1 else np.zeros((0, h, w), bool)
    g.create_dataset("event_masks", data=masks, compression="gzip", compression_opts=4)
    lg = g.create_group("layers")
    for i, layer in enumerate(gt.layers):
        m = layer.motion
        li = lg.create_group(str(i))
        li.attrs["name"] = layer.name
        li.attrs["warp"] = m.warp.name
        li.attrs["center"] = np.asarray(m.warp.center, dtype=np.float64)
        li.attrs["t_ref_s"] = float(m.t_ref_s)
        li.attrs["param_names"] = ",".join(m.warp.param_names)
        li.attrs["param_units"] = ",".join(m.warp.param_units)
        li["theta"] = m.theta
        li["params"] = np.array([m.params_at(t * 1e-6) for t in ft]).reshape(len(ft), -1)
        if layer.alpha is not None:
            li.create_dataset("alpha", data=layer.alpha, compression="gzip")
            li["alpha"].attrs["origin"] = np.asarray(layer.origin, dtype=np.float64)


def write_ground_truth(path: str | Path, gt: GroundTruth, *, group: str | None = None,
                       events_file: str | None = None) -> Path:
    """Write ``gt`` to HDF5 at ``path`` (atomically), or into ``group`` of an existing file.

    Parameters
    ----------
    path : str or Path
        Output file (``.h5``).
    gt : GroundTruth
    group : str, optional
        Write into this group (e.g. ``"ground_truth"``) of an existing HDF5 file, in place.
    events_file : str, optional
        Name of the recording this is the ground truth of (attribute ``events_file``).

    Returns
    -------
    Path

    Examples
    --------
    >>> from evmotion.sim import simulate
    >>> res = simulate("translation", duration_s=0.01, sensor_size=(20, 30))
    >>> write_ground_truth("sim_gt.h5", res.gt).name
    'sim_gt.h5'
    """
    import h5py

    path = Path(path)
    if group is not None:
        with h5py.File(path, "a") as f:
            if group in f:
                del f[group]
            _write_group(f.create_group(group), gt)
        return path
    with atomic_path(path) as tmp, h5py.File(tmp, "w") as f:
        _write_group(f, gt)
        if events_file is not None:
            f.attrs["events_file"] = str(events_file)
    return path


def read_ground_truth(path: str | Path) -> GroundTruth:
    """Read simulator ground truth written by :func:`write_ground_truth`.

    Accepts the ``_gt.h5`` file itself, a file with a ``/ground_truth`` group, or an events
    file whose ``<stem>_gt.h5`` sits beside it.

    Examples
    --------
    >>> from evmotion.sim import simulate
    >>> res = simulate("translation", duration_s=0.01, sensor_size=(20, 30))
    >>> gt = read_ground_truth(write_ground_truth("sim_gt.h5", res.gt))
    >>> gt.flow(gt.frame_times_us[1]).shape
    (20, 30, 2)
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        alt = gt_path_for(path)
        if alt.is_file():
            path = alt
        else:
            raise FormatError(path, "ground-truth file not found")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise FormatError(path, f"not an HDF5 file ({exc})") from None
    with f:
        g, ga = f, read_attrs(path, f)
        if ga.get("format") != GT_FORMAT and "ground_truth" in f:
            g = f["ground_truth"]
            ga = read_attrs(path, g)
        if ga.get("format") != GT_FORMAT:
            alt = gt_path_for(path)
            if alt != path and alt.is_file():
                return read_ground_truth(alt)
            raise FormatError(path, "no simulator ground truth here",
                              hint=f"expected attribute format={GT_FORMAT!r} at / or "
                                   "/ground_truth, or a <stem>_gt.h5 file beside it")
        try:
            sensor_size = tuple(int(v) for v in ga["sensor_size"])
            K = g["K"][()]
            layers = []
            for key in sorted(g["layers"], key=int):
                li = g["layers"][key]
                la = read_attrs(path, li)
                warp = str(la["warp"])
                motion = make_motion(warp, li["theta"][()], sensor_size,
                                     K=K if warp == "rotation" else None,
                                     center=tuple(la["center"]),
                                     t_ref_s=float(la["t_ref_s"]))
                alpha, origin = None, (0.0, 0.0)
                if "alpha" in li:
                    alpha = li["alpha"][()].astype(np.float32)
                    origin = tuple(float(v) for v in
                                   read_attrs(path, li["alpha"], ("origin",))["origin"])
                layers.append(Layer(str(la["name"]), motion, alpha, origin))
            av = g["angular_velocity"][()]
            omega = None if av.shape[0] == 0 or np.isnan(av[0]).all() else av[0]
            return GroundTruth(scene=str(ga["scene"]), sensor_size=sensor_size, K=K,
                               layers=layers, frame_times_us=g["frame_times_us"][()],
                               duration_us=int(ga["duration_us"]),
                               angular_velocity_rad_s=omega,
                               frame_masks=g["event_masks"][()])
        except KeyError as exc:
            raise FormatError(path, f"ground truth is missing {exc}") from None


def sim_calibration(K, sensor_size) -> dict:
    """The simulator's pinhole camera as the calibration dict that evmotion HDF5 stores
    (read back by :func:`evmotion.io.read_calibration`): no distortion."""
    K = np.asarray(K, dtype=np.float64)
    return {"K": K.tolist(), "dist": [0.0] * 5, "fx": float(K[0, 0]), "fy": float(K[1, 1]),
            "cx": float(K[0, 2]), "cy": float(K[1, 2]), "model": "pinhole-radtan",
            "source": "evmotion simulator", "sensor_size": [int(v) for v in sensor_size]}
