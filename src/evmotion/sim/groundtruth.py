"""Ground truth of a simulated recording: parameters, dense flow, displacement, masks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evmotion.errors import ParameterError
from evmotion.sim.motions import Motion, apply_generator
from evmotion.sim.render import sample_wrap_numpy
from evmotion.utils import check_not_seconds, whole_time_us

__all__ = ["GroundTruth", "Layer"]


@dataclass(frozen=True, eq=False)
class Layer:
    """One moving layer: a motion and, for layers over others, an opacity raster.

    Attributes
    ----------
    name : str
        ``background`` or ``object``.
    motion : Motion
    alpha : ndarray (Ht, Wt) float32 or None
        Opacity in reference coordinates (None: opaque everywhere).
    origin : (float, float)
        Reference pixel ``(x, y)`` of raster pixel (0, 0).
    """

    name: str
    motion: Motion
    alpha: np.ndarray | None = None
    origin: tuple[float, float] = (0.0, 0.0)


@dataclass(eq=False)
class GroundTruth:
    """Exact ground truth of a simulated scene.

    Times are integer microseconds from the start of the recording (``t = 0``).

    Attributes
    ----------
    scene : str
    sensor_size : (int, int)
        ``(height, width)``.
    K : ndarray (3, 3)
        Pinhole intrinsics in pixels (no distortion).
    layers : list of Layer
        Bottom (background) first.
    frame_times_us : ndarray int64
        Virtual GT frame times (window at ``dt = 1`` or ``4`` frames as in MVSEC).
    duration_us : int
    events_xyt : tuple of arrays or None
        ``(x, y, t)`` of the simulated events (for :meth:`event_mask` on any window).
    frame_masks : ndarray (F-1, H, W) bool or None
        Event masks between consecutive frames (used when events are not held).

    Examples
    --------
    >>> from evmotion.sim import simulate
    >>> res = simulate("translation", duration_s=0.01, sensor_size=(40, 60), seed=0)
    >>> res.gt.flow(5000)[20, 30].round(1).tolist()
    [220.0, -130.0]
    """

    scene: str
    sensor_size: tuple[int, int]
    K: np.ndarray
    layers: list[Layer]
    frame_times_us: np.ndarray
    duration_us: int
    angular_velocity_rad_s: np.ndarray | None = None
    events_xyt: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    frame_masks: np.ndarray | None = field(default=None, repr=False)

    def _grid(self):
        h, w = self.sensor_size
        ys, xs = np.mgrid[0:h, 0:w]
        return xs.astype(np.float64), ys.astype(np.float64)

    def _t(self, t_us, name="t_us") -> float:
        try:
            t = np.asarray(t_us, dtype=np.float64)
        except (TypeError, ValueError):  # ("a" failed in numpy's float conversion, probe CB)
            t = np.asarray(np.nan)
        if t.ndim != 0 or not np.isfinite(t):
            raise ParameterError(f"{name} must be a finite time in microseconds, got {t_us!r}")
        check_not_seconds(name, float(t))
        # the motion models run on past the simulation, where they are the truth of
        # nothing (gt.params(1e10) of a 0.03 s zoom gave hz -0.0001 without a word, probe
        # DB); the larger of its duration and 1 s either side keeps a window's end past the
        # last event and the models' own checks (a zoom's transport over 0.25 s)
        d = int(self.duration_us)
        margin = max(d, 1_000_000)
        if not -margin <= float(t) <= d + margin:
            raise ParameterError(f"{name} = {float(t):.6g} µs lies outside the simulated "
                                 f"0..{d} µs by more than {margin} µs: no ground truth "
                                 "there")
        return float(t) * 1e-6

    def visible_layer(self, t_us) -> np.ndarray:
        """(H, W) int8: index of the layer seen at each pixel at time ``t_us``."""
        t = self._t(t_us)
        xs, ys = self._grid()
        top = np.zeros(self.sensor_size, dtype=np.int8)
        for k, layer in enumerate(self.layers[1:], start=1):
            if layer.alpha is None:
                top[:] = k
                continue
            m = layer.motion.matrix(t)
            den = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
            xr = (m[0, 0] * xs + m[0, 1] * ys + m[0, 2]) / den - layer.origin[0]
            yr = (m[1, 0] * xs + m[1, 1] * ys + m[1, 2]) / den - layer.origin[1]
            top[sample_wrap_numpy(layer.alpha, xr, yr) >= 0.5] = k
        return top

    def flow(self, t_us) -> np.ndarray:
        """Dense optical flow at time ``t_us`` (µs): (H, W, 2) float32, px/s, u right,
        v down, of the layer visible at each pixel."""
        t = self._t(t_us)
        xs, ys = self._grid()
        top = self.visible_layer(t_us)
        out = np.empty(self.sensor_size + (2,), dtype=np.float32)
        for k, layer in enumerate(self.layers):
            sel = top == k
            if not sel.any():
                continue
            u, v = apply_generator(layer.motion.generator(t), xs[sel], ys[sel])
            out[sel, 0] = u
            out[sel, 1] = v
        return out

    def displacement(self, t0_us, t1_us) -> np.ndarray:
        """Where each pixel's scene point at ``t0_us`` is at ``t1_us`` (µs): (H, W, 2)
        float32 px, exact along the trajectory (not flow x dt). The layer is the one
        visible at ``t0_us``; the point may be occluded at ``t1_us``."""
        self._t(t0_us, "t0_us")
        self._t(t1_us, "t1_us")
        t0, t1 = float(t0_us) * 1e-6, float(t1_us) * 1e-6
        xs, ys = self._grid()
        top = self.visible_layer(t0_us)
        out = np.empty(self.sensor_size + (2,), dtype=np.float32)
        for k, layer in enumerate(self.layers):
            sel = top == k
            if not sel.any():
                continue
            T = layer.motion.transport(t0, t1)
            x, y = xs[sel], ys[sel]
            den = T[2, 0] * x + T[2, 1] * y + T[2, 2]
            out[sel, 0] = (T[0, 0] * x + T[0, 1] * y + T[0, 2]) / den - x
            out[sel, 1] = (T[1, 0] * x + T[1, 1] * y + T[1, 2]) / den - y
        return out

    def flow_sequence(self, t0s, t1s):
        """The exact flow of windows ``[t0s[i], t1s[i])`` (µs) as a
        :class:`~evmotion.io.flowfiles.FlowSequence`: each window's :meth:`displacement`
        over its duration, px/s; what :func:`~evmotion.eval.windows.evaluate_windows` and
        :func:`~evmotion.io.flowfiles.write_flow_h5`-style tools take.

        Examples
        --------
        >>> from evmotion.sim import simulate
        >>> gt = simulate("translation", duration_s=0.02, sensor_size=(30, 40),
        ...               seed=0, show_progress=False).gt
        >>> seq = gt.flow_sequence([0, 10_000], [10_000, 20_000])
        >>> seq.flow.shape, seq.t1.tolist()
        ((2, 30, 40, 2), [10000, 20000])
        """
        from evmotion.io.flowfiles import FlowSequence

        # whole µs each (NaN failed in numpy's int conversion and 0.5 was cut to 0; 1e30
        # overflowed int64, probe OPT)
        t0s, t1s = (np.array([whole_time_us(name, v) for v in np.ravel(ts)], np.int64)
                    for name, ts in (("t0s", t0s), ("t1s", t1s)))
        if t0s.shape != t1s.shape or not np.all(t1s > t0s):
            raise ParameterError("flow_sequence: t0s and t1s must be as many window starts "
                                 "and ends (µs), each end after its start")
        flow = np.stack([self.displacement(a, b) / ((b - a) * 1e-6)
                         for a, b in zip(t0s, t1s, strict=True)]).astype(np.float32)
        return FlowSequence(flow, t0s, t1s, np.isfinite(flow).all(axis=-1),
                            attrs={"source": f"simulated {self.scene}", "units": "px/s"})

    def params(self, t_us) -> dict:
        """Motion parameters at time ``t_us``: those of each layer's warp referenced at
        ``t_us`` (rates per second; names and units of :mod:`evmotion.core.warps`).

        One layer: ``{"warp": name, <param>: value, ..., "units": {...}}`` plus
        ``"omega"`` (rad/s) for rotation and ``"hz"``, ``"ttc_s"``, ``"foe"`` for zoom.
        Several layers: ``{layer name: that dict}``."""
        t = self._t(t_us)
        out = {name: _layer_params(layer, t) for name, layer in
               ((la.name, la) for la in self.layers)}
        return out[self.layers[0].name] if len(self.layers) == 1 else out

    def angular_velocity(self, t_us=None) -> np.ndarray:
        """Camera angular velocity (rad/s, camera frame x right, y down, z forward);
        zeros for purely translating cameras, NaN where the scene is not a camera
        motion with a defined rotation (planar warps, independent objects)."""
        if self.angular_velocity_rad_s is None:
            return np.full(3, np.nan)
        return np.asarray(self.angular_velocity_rad_s, dtype=np.float64).copy()

    def event_mask(self, t0_us, t1_us) -> np.ndarray:
        """(H, W) bool: at least one event at the pixel in ``[t0_us, t1_us)``.

        Any window when the events are held (a fresh simulation); after
        :func:`~evmotion.sim.gtio.read_ground_truth`, windows on GT frame times."""
        h, w = self.sensor_size
        if self.events_xyt is not None:
            x, y, t = self.events_xyt
            i0, i1 = np.searchsorted(t, [t0_us, t1_us], side="left")
            m = np.zeros(h * w, dtype=bool)
            m[y[i0:i1].astype(np.int64) * w + x[i0:i1].astype(np.int64)] = True
            return m.reshape(h, w)
        if self.frame_masks is None:
            raise ParameterError("this ground truth holds neither events nor frame masks")
        ft = self.frame_times_us
        i0, i1 = np.searchsorted(ft, [t0_us, t1_us])
        if i0 >= len(ft) or i1 >= len(ft) or ft[i0] != t0_us or ft[i1] != t1_us:
            raise ParameterError(f"window [{t0_us}, {t1_us}) us does not start and end on GT "
                                 "frame times; event masks from a file exist per frame interval")
        return self.frame_masks[i0:i1].any(axis=0)


def _layer_params(layer: Layer, t_s: float) -> dict:
    w = layer.motion.warp
    th = layer.motion.params_at(t_s)
    d = {"warp": w.name}
    d.update({n: float(v) for n, v in zip(w.param_names, th, strict=True)})
    d["units"] = dict(zip(w.param_names, w.param_units, strict=True))
    if w.name == "rotation":
        d["omega"] = [float(v) for v in th]
    if w.name == "zoom":
        d["ttc_s"] = float(1.0 / th[0]) if th[0] != 0 else float("inf")
        d["foe"] = [float(c) for c in w.center]
    if w.name != "rotation":
        d["center"] = [float(c) for c in w.center]
    return d
