"""Accuracy of ego-motion estimates (``evmotion egomotion``'s per-window warp parameters)
against ground truth.

A window's warp parameters are a motion model: at every pixel they give the image velocity
at the window's reference time (:meth:`evmotion.core.warps.Warp.optical_flow`). Scored as
a flow (:func:`evmotion.eval.windows.evaluate_windows`), any warp meets any ground truth
that has flow (MVSEC, DSEC, the simulator's), and warps of different families compare on
one scale (px). Where the ground truth is the simulator's and its scene is one motion of
the same warp (same centre), the parameters are also compared directly, in their own units
(rad/s for the rotation's angular velocity, the thesis' Tables 3.1-3.3).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from evmotion.core.warps import make_warp
from evmotion.errors import ParameterError
from evmotion.eval.windows import WindowsEvaluation, evaluate_windows, sharpness_windows
from evmotion.events import check_image_shape

if TYPE_CHECKING:
    from evmotion.events import EventArray
    from evmotion.io.angvel import AngularVelocity
    from evmotion.io.flowfiles import FlowSequence
    from evmotion.io.paramsfiles import ParamsTable
    from evmotion.sim.groundtruth import GroundTruth

__all__ = ["EgomotionEvaluation", "ParamsFlow", "angular_velocity_errors", "evaluate_egomotion",
           "parameter_errors",
           "sharpness_egomotion"]


class ParamsFlow:
    """The flow ``(N, H, W, 2)`` in px/s that each row of a parameters table gives at
    every pixel, computed one window at a time when indexed (``flow[i]``), NaN for rows
    that are not measurements (``valid`` False: collapsed, poor fit).

    Parameters
    ----------
    table : ParamsTable
        Per-window warp parameters (:func:`evmotion.io.paramsfiles.read_params`); its
        ``attrs["warp"]`` names the warp.
    sensor_size : (int, int)
        ``(height, width)`` of the pixel grid the events were on.
    K : ndarray (3, 3), optional
        Intrinsics (the rotation warp needs them).

    Examples
    --------
    >>> from evmotion.io.paramsfiles import ParamsTable
    >>> t = ParamsTable(np.array([[30.0, -10.0]]), ("vx", "vy"), ("px/s", "px/s"),
    ...                 np.array([0]), np.array([10_000]), np.array([True]),
    ...                 attrs={"warp": "translation", "grid": "sensor"})
    >>> f = ParamsFlow(t, (4, 5))
    >>> f.shape, f[0][2, 3].tolist()
    ((1, 4, 5, 2), [30.0, -10.0])
    """

    def __init__(self, table: ParamsTable, sensor_size: tuple[int, int], K=None):
        h, w = check_image_shape("sensor_size", sensor_size)
        name = str(table.attrs.get("warp", ""))
        if name == "rotation" and K is None:
            raise ParameterError("the rotation warp's parameters give a flow only with the "
                                 "camera's intrinsics K")
        self.warp = make_warp(name, (h, w), K)
        if tuple(table.names) != tuple(self.warp.param_names):
            raise ParameterError(f"parameters {', '.join(table.names)} are not the "
                                 f"{name} warp's ({', '.join(self.warp.param_names)})")
        self.table = table
        self.shape = (len(table), h, w, 2)
        ys, xs = np.mgrid[0:h, 0:w]
        self._xy = (xs.ravel().astype(np.float64), ys.ravel().astype(np.float64))
        self._last: tuple[int, np.ndarray] | None = None

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, i: int) -> np.ndarray:
        i = int(i)
        if self._last is not None and self._last[0] == i:
            return self._last[1]
        h, w = self.shape[1:3]
        if not bool(self.table.valid[i]):
            out = np.full((h, w, 2), np.nan, np.float32)
        else:
            u, v = self.warp.optical_flow(*self._xy, np.asarray(self.table.params[i],
                                                                np.float64))
            out = np.stack([u, v], axis=-1).reshape(h, w, 2).astype(np.float32)
        self._last = (i, out)
        return out


@dataclass(frozen=True)
class EgomotionEvaluation:
    """Accuracy of per-window ego-motion parameters.

    Attributes
    ----------
    flow : WindowsEvaluation
        The parameters' flow scored as dense flow (AEE in px over each window, %Out, AE,
        and the FWL with events); windows that are not measurements are not scored.
    parameters : list of dict
        Per window: ``window``, the estimate and the ground truth of each parameter at the
        window's reference time and their difference (``<name>_err``); empty when the
        parameters are not comparable (``reason`` says why).
    parameters_rms : dict
        The RMS of each parameter's error over the valid windows (``<name>``), and for
        the rotation the RMS of the angular velocity error's norm (``omega``).
    units : dict
        Unit of each parameter.
    reason : str
        Why the parameters were not compared ("" when they were).
    """

    flow: WindowsEvaluation
    parameters: list[dict] = field(default_factory=list)
    parameters_rms: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)
    reason: str = ""


def parameter_errors(table: ParamsTable, truth: GroundTruth
                     ) -> tuple[list[dict], dict, str]:
    """Each window's parameters against the simulator's at the window's reference time.

    Comparable when the scene is one motion of the table's warp about the same centre
    (the image centre, as ``evmotion egomotion`` takes it); otherwise the rows are empty
    and the reason says why.

    Returns
    -------
    rows, rms, reason : list of dict, dict, str
        See :class:`EgomotionEvaluation`.

    Examples
    --------
    >>> from evmotion.io.paramsfiles import ParamsTable
    >>> from evmotion.sim import simulate
    >>> gt = simulate("translation", duration_s=0.01, sensor_size=(40, 60), seed=0).gt
    >>> t = ParamsTable(np.array([[221.0, -130.0]]), ("vx", "vy"), ("px/s", "px/s"),
    ...                 np.array([0]), np.array([10_000]), np.array([True]),
    ...                 columns={"t_ref_us": np.array([0])},
    ...                 attrs={"warp": "translation", "grid": "sensor"})
    >>> rows, rms, reason = parameter_errors(t, gt)
    >>> round(rms["vx"], 3), round(rms["vy"], 3), reason
    (1.0, 0.0, '')
    """
    warp = str(table.attrs.get("warp", ""))
    if len(truth.layers) != 1:
        return [], {}, (f"the scene has {len(truth.layers)} motions (layers): one set of "
                        "parameters is compared through its flow only")
    motion = truth.layers[0].motion
    if motion.warp.name != warp:
        return [], {}, (f"the scene moves by a {motion.warp.name} warp, the estimate is "
                        f"{warp}: compared through its flow only")
    if warp != "rotation":
        # the centre egomotion's warps take: the warp's default
        centre = make_warp(warp, truth.sensor_size).center
        if not np.allclose(motion.warp.center, centre, atol=1e-6):
            return [], {}, (f"the scene's {warp} is about ({motion.warp.center[0]:g}, "
                            f"{motion.warp.center[1]:g}) px, the estimate's about the image "
                            "centre: compared through its flow only")
    t_ref = np.asarray(table.columns.get("t_ref_us", table.t0), np.int64)
    rows, errs = [], []
    for i in range(len(table)):
        exact = np.asarray(motion.params_at(float(t_ref[i]) * 1e-6), np.float64)
        est = np.asarray(table.params[i], np.float64)
        row = {"window": i, "t_ref_us": int(t_ref[i]), "valid": bool(table.valid[i])}
        for n, e, g in zip(table.names, est, exact, strict=True):
            row.update({n: float(e), f"{n}_gt": float(g), f"{n}_err": float(e - g)})
        rows.append(row)
        if table.valid[i]:
            errs.append(est - exact)
    rms: dict = {}
    if errs:
        err = np.asarray(errs)
        rms = {n: float(np.sqrt(np.mean(err[:, k] ** 2))) for k, n in enumerate(table.names)}
        if warp == "rotation":
            rms["omega"] = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
    return rows, rms, ""


def angular_velocity_errors(table: ParamsTable, ref: AngularVelocity
                            ) -> tuple[list[dict], dict, str]:
    """The rotation warp's angular velocity of each window against reference samples (an
    IMU's gyroscope, :func:`evmotion.io.angvel.read_angular_velocity`): their mean over
    the window ``[t0, t1)``, or where no sample falls in it their linear interpolation at
    its middle; a window beyond the samples is not compared.

    Returns
    -------
    rows, rms, reason : list of dict, dict, str
        As :func:`parameter_errors`, the rows with ``n_samples`` (0: interpolated, -1:
        beyond the samples), ``rms["n_windows"]``, the valid windows compared, and
        ``rms["omega_zero"]``, the zero rotation's error on them.

    Examples
    --------
    >>> from evmotion.io.angvel import AngularVelocity
    >>> from evmotion.io.paramsfiles import ParamsTable
    >>> t = ParamsTable(np.array([[0.1, 0.0, 1.0]]), ("wx", "wy", "wz"), ("rad/s",) * 3,
    ...                 np.array([0]), np.array([10_000]), np.array([True]),
    ...                 attrs={"warp": "rotation"})
    >>> ref = AngularVelocity(np.array([0, 5_000]), np.array([[0.0, 0.0, 1.0]] * 2), "imu")
    >>> rows, rms, reason = angular_velocity_errors(t, ref)
    >>> round(rms["wx"], 3), round(rms["omega"], 3), rows[0]["n_samples"]
    (0.1, 0.1, 2)
    """
    warp = str(table.attrs.get("warp", ""))
    if warp != "rotation" or tuple(table.names) != ("wx", "wy", "wz"):
        return [], {}, (f"an angular velocity scores the rotation warp's parameters; these "
                        f"are the {warp or 'unknown'} warp's")
    rows, errs, refs = [], [], []
    for i in range(len(table)):
        t0, t1 = int(table.t0[i]), int(table.t1[i])
        if ref.t is None:
            omega, n = ref.omega[0], 1
        else:
            inside = (ref.t >= t0) & (ref.t < t1)
            n = int(inside.sum())
            mid = 0.5 * (t0 + t1)
            if n:
                omega = ref.omega[inside].mean(axis=0)
            elif len(ref.t) and ref.t[0] <= mid <= ref.t[-1]:
                omega = np.array([np.interp(mid, ref.t, ref.omega[:, k]) for k in range(3)])
            else:
                omega, n = None, -1
        row = {"window": i, "t0_us": t0, "t1_us": t1, "valid": bool(table.valid[i]),
               "n_samples": n}
        est = np.asarray(table.params[i], np.float64)
        for k, name in enumerate(table.names):
            row[name] = float(est[k])
            if omega is not None:
                row.update({f"{name}_gt": float(omega[k]),
                            f"{name}_err": float(est[k] - omega[k])})
        rows.append(row)
        if omega is not None and table.valid[i]:
            errs.append(est - omega)
            refs.append(omega)
    if not errs:
        beyond = sum(r["n_samples"] < 0 for r in rows)
        return rows, {}, ("no valid window to compare" if beyond < len(rows) else
                          f"the reference samples ({ref.source}) span none of the windows' "
                          "times (another recording, or another clock?)")
    err = np.asarray(errs)
    rms = {n: float(np.sqrt(np.mean(err[:, k] ** 2))) for k, n in enumerate(table.names)}
    rms["omega"] = float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))
    # the zero rotation's error on the same windows: what omega is read against (a wrong
    # recording's reference scored 1.156 rad/s unsaid, where no rotation scores 1.18;
    # probe CE)
    rms["omega_zero"] = float(np.sqrt(np.mean(np.sum(np.asarray(refs) ** 2, axis=1))))
    rms["n_windows"] = len(errs)
    return rows, rms, ""


def evaluate_egomotion(table: ParamsTable, gt: FlowSequence, *,
                       truth: GroundTruth | None = None,
                       sensor_size: tuple[int, int] | None = None, K=None,
                       events: EventArray | None = None, dt: int = 1,
                       out_px: float = 3.0) -> EgomotionEvaluation:
    """Score per-window ego-motion parameters against ground truth.

    Parameters
    ----------
    table : ParamsTable
        ``evmotion egomotion``'s parameters (:func:`evmotion.io.paramsfiles.read_params`).
    gt : FlowSequence
        Ground-truth flow (:func:`evmotion.io.flowfiles.read_gt_flow`).
    truth : GroundTruth, optional
        The simulator's ground truth of the same scene
        (:func:`evmotion.sim.gtio.read_ground_truth`): the parameters are compared too.
    sensor_size, K : optional
        The pixel grid and intrinsics the estimate was made on; default the table's
        ``sensor_size`` and ``K`` attributes (written by ``evmotion egomotion``).
    events, dt, out_px
        As :func:`evmotion.eval.windows.evaluate_windows`.

    Returns
    -------
    EgomotionEvaluation
    """
    flow = _params_flow(table, sensor_size, K)
    if tuple(gt.flow.shape[1:3]) != flow.shape[1:3]:
        raise ParameterError(f"the estimate is on a {flow.shape[2]}x{flow.shape[1]} px grid, "
                             f"the ground truth {gt.flow.shape[2]}x{gt.flow.shape[1]} px "
                             "(W x H)")
    scored = evaluate_windows(flow, table.t0, table.t1, gt, events=events, dt=dt,
                              out_px=out_px)
    units = dict(zip(table.names, table.units, strict=True))
    if truth is None:
        return EgomotionEvaluation(scored, units=units,
                                   reason="the ground truth is not the simulator's: "
                                          "compared through the flow only")
    rows, rms, reason = parameter_errors(table, truth)
    return EgomotionEvaluation(scored, rows, rms, units, reason)


def sharpness_egomotion(table: ParamsTable, events: EventArray, *,
                        sensor_size: tuple[int, int] | None = None, K=None) -> list[dict]:
    """How much each window's parameters sharpen its events, with no ground truth: the FWL
    of their flow (:func:`evmotion.eval.windows.sharpness_windows`)."""
    flow = _params_flow(table, sensor_size or events.sensor_size, K)
    return sharpness_windows(flow, table.t0, table.t1, events)


def _params_flow(table: ParamsTable, sensor_size, K) -> ParamsFlow:
    """The table's flow on ``sensor_size`` (else its attribute) with ``K`` (else its)."""
    size = sensor_size if sensor_size is not None else table.attrs.get("sensor_size")
    if size is None:
        raise ParameterError("the parameters file does not say its sensor size (written "
                             "before 2026-11-30): give the events or the ground truth")
    if K is None and table.attrs.get("K") is not None:
        K = np.asarray(table.attrs["K"], np.float64).reshape(3, 3)
    return ParamsFlow(table, size, K)
