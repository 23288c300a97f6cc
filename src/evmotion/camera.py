"""Camera intrinsics, radial-tangential distortion and event undistortion.

The model is the pinhole camera with the radial-tangential ("plumb bob") distortion of
OpenCV, ECD and MVSEC: a normalized point ``(x, y)`` is distorted to

    r² = x² + y²
    x_d = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)
    y_d = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y

and projected to pixels ``u = fx x_d + cx``, ``v = fy y_d + cy``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from evmotion.errors import CalibrationError, ParameterError
from evmotion.events import EventArray

__all__ = ["Camera"]


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics with radial-tangential distortion.

    Parameters
    ----------
    fx, fy : float
        Focal lengths in pixels.
    cx, cy : float
        Principal point in pixels (x = column, y = row).
    dist : tuple of float
        ``(k1, k2, p1, p2, k3)``; zeros for an undistorted camera.
    sensor_size : (int, int) or None
        ``(height, width)`` in pixels; None when the calibration does not say (then
        :meth:`undistort_events` takes the events' size).
    source : str
        Where the intrinsics came from (a file, ``--K``, a header), for messages and outputs.

    Examples
    --------
    >>> cam = Camera(200.0, 200.0, 120.0, 90.0, sensor_size=(180, 240))
    >>> cam.normalize(np.array([120.0]), np.array([90.0]))
    (array([0.]), array([0.]))
    """

    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    sensor_size: tuple[int, int] | None = None
    _lut: dict = field(default_factory=dict, repr=False, compare=False, hash=False)
    source: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        vals = np.array([self.fx, self.fy, self.cx, self.cy, *self.dist], dtype=np.float64)
        if vals.size != 9 or not np.all(np.isfinite(vals)):
            raise CalibrationError(f"{self._where()}camera parameters must be 4 intrinsics + 5 "
                                   f"distortion coefficients, all finite; got {vals.tolist()}")
        if self.fx <= 0 or self.fy <= 0:
            raise CalibrationError(f"{self._where()}focal lengths must be positive, got "
                                   f"fx={self.fx}, fy={self.fy}")
        object.__setattr__(self, "dist", tuple(float(d) for d in self.dist))
        if self.sensor_size is not None:
            size = tuple(self.sensor_size)
            # (a (-1, 5) or a 3-tuple was taken, and failed later in the lookup table)
            if (len(size) != 2 or not all(isinstance(v, (int, np.integer)) for v in size)
                    or min(size) < 1):
                raise CalibrationError(f"{self._where()}sensor_size must be (height, width), "
                                       f"two positive whole numbers of pixels, got {size}")
            object.__setattr__(self, "sensor_size", tuple(int(v) for v in size))

    def _where(self) -> str:
        return f"{self.source}: " if self.source else ""

    # ----------------------------------------------------------- constructors
    @classmethod
    def from_K(cls, K: np.ndarray, dist=None, sensor_size=None, source: str = ""
               ) -> Camera:
        """From a 3x3 intrinsic matrix and optional distortion coefficients."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise CalibrationError(f"K must be 3x3, got shape {K.shape}")
        d = _dist5(dist)
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], d, sensor_size, source=source)

    def with_sensor_size(self, sensor_size: tuple[int, int]) -> Camera:
        return replace(self, sensor_size=sensor_size, _lut={})

    def for_sensor(self, sensor_size: tuple[int, int]) -> Camera:
        """This camera on a sensor of ``sensor_size`` (height, width): itself when the sizes
        agree or its own is unknown (None); CalibrationError when they differ."""
        size = tuple(int(s) for s in sensor_size)
        if self.sensor_size is None:
            return self.with_sensor_size(size)
        if self.sensor_size != size:
            where = f"{self.source}: " if self.source else ""
            raise CalibrationError(
                f"{where}calibration is for a {self.sensor_size[1]} x {self.sensor_size[0]} px "
                f"sensor (W x H) but the events are {size[1]} x {size[0]} px")
        return self

    def describe(self) -> str:
        """One line: ``K=[fx, fy, cx, cy] dist=[k1, k2, p1, p2, k3]`` (px)."""
        k = ", ".join(f"{v:.6g}" for v in (self.fx, self.fy, self.cx, self.cy))
        d = ", ".join(f"{v:.6g}" for v in self.dist)
        return f"K=[{k}] dist=[{d}]"

    # ------------------------------------------------------------- geometry
    @property
    def K(self) -> np.ndarray:
        """3x3 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def is_distorted(self) -> bool:
        return any(d != 0.0 for d in self.dist)

    def normalize(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted pixels -> calibrated (normalized) coordinates, no distortion removal."""
        return (np.asarray(u, np.float64) - self.cx) / self.fx, \
               (np.asarray(v, np.float64) - self.cy) / self.fy

    def denormalize(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated coordinates -> pixels (no distortion)."""
        return np.asarray(x) * self.fx + self.cx, np.asarray(y) * self.fy + self.cy

    def distort_normalized(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply radial-tangential distortion to normalized coordinates."""
        k1, k2, p1, p2, k3 = self.dist
        x = np.asarray(x, np.float64)
        y = np.asarray(y, np.float64)
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        return xd, yd

    def corner_shift(self) -> float:
        """How far the distortion model moves the sensor's corners, at most, as a share of
        their distance from the principal point (0 without distortion; NaN without a
        sensor size). Real lenses' radtan models stay at a few tenths (the ECD DAVIS240C's:
        0.19).

        Examples
        --------
        >>> Camera(200, 200, 119.5, 89.5, (5.0, 0, 0, 0, 0), (180, 240)).corner_shift() > 1
        True
        """
        if self.sensor_size is None:
            return float("nan")
        h, w = self.sensor_size
        u = np.array([0.0, w - 1.0, 0.0, w - 1.0])
        v = np.array([0.0, 0.0, h - 1.0, h - 1.0])
        ud, vd = self.distort_pixels(u, v)
        r = np.hypot(u - self.cx, v - self.cy)
        return float(np.max(np.hypot(ud - u, vd - v) / np.maximum(r, 1e-9)))

    def distort_pixels(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Undistorted pixels -> distorted (sensor) pixels."""
        xd, yd = self.distort_normalized(*self.normalize(u, v))
        return self.denormalize(xd, yd)

    def undistort_normalized(self, u: np.ndarray, v: np.ndarray, *, iterations: int = 20,
                             ) -> tuple[np.ndarray, np.ndarray]:
        """Distorted sensor pixels -> undistorted normalized coordinates.

        Gauss-Newton on the distortion map (converges to < 1e-10 px for the distortions of
        DAVIS lenses, where OpenCV's fixed-point iteration can stop short).
        """
        xd, yd = self.normalize(u, v)
        if not self.is_distorted:
            return xd, yd
        k1, k2, p1, p2, k3 = self.dist
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r2
            fx_ = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
            fy_ = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
            a = radial + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
            b = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            c = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            d = radial + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
            det = a * d - b * c
            x = x - (d * fx_ - b * fy_) / det
            y = y - (-c * fx_ + a * fy_) / det
        return x, y

    def undistort_pixels(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Distorted sensor pixels -> undistorted pixels (same K)."""
        return self.denormalize(*self.undistort_normalized(u, v))

    def undistortion_lut(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-pixel lookup table ``(ux, uy)``, each (H, W) float32: undistorted pixel position
        of every integer sensor pixel. Computed once per camera."""
        if self.sensor_size is None:
            raise CalibrationError(f"{self._where()}the sensor size is unknown; give it with "
                                   "for_sensor((height, width))")
        if "undist" not in self._lut:
            h, w = self.sensor_size
            vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
            ux, uy = self.undistort_pixels(uu.ravel(), vv.ravel())
            self._lut["undist"] = (ux.reshape(h, w).astype(np.float32),
                                   uy.reshape(h, w).astype(np.float32))
        return self._lut["undist"]

    def undistort_events(self, events: EventArray, *, drop_outside: bool = True,
                         integer: bool = False) -> EventArray:
        """Events at their undistorted positions on the same pixel grid (same K), through the
        per-pixel lookup table.

        Parameters
        ----------
        events : EventArray
            Events with integer sensor coordinates (``x`` column, ``y`` row).
        drop_outside : bool
            Drop events whose undistorted position falls outside the sensor (default); with
            False they are kept and the result is not bounds-checked.
        integer : bool
            Round the undistorted positions to the nearest pixel and keep the input's integer
            dtype, for methods that work on the pixel lattice (triplet matching); default
            float32 coordinates. Whole-pixel coordinates lie on the sensor: it needs
            ``drop_outside``.

        Returns
        -------
        EventArray
            ``meta["undistorted"]`` is True, ``meta["grid"]`` says which grid
            (:meth:`grid_label`) and ``meta["undistort_dropped"]`` how many events fell
            outside the sensor and were left out (18 % of an ECD DAVIS240C window).

        Examples
        --------
        >>> cam = Camera(200.0, 200.0, 120.0, 90.0, (-0.3, 0.1, 0.0, 0.0, 0.0), (180, 240))
        >>> ev = EventArray(np.array([0, 120]), np.array([0, 90]), np.array([0, 1]),
        ...                 np.array([1, 0]), (180, 240))
        >>> und = cam.undistort_events(ev, drop_outside=False)
        >>> [round(float(v), 2) for v in und.x]  # the corner moves outwards, the centre stays
        [-26.58, 120.0]
        """
        if integer and not drop_outside:
            # (the positions past the border wrapped round in uint16: x = -35.9 became
            # 65500, which write_events took; probe CB)
            raise ParameterError("undistort_events: integer=True needs drop_outside=True: "
                                 "whole-pixel (uint16) coordinates cannot lie off the sensor; "
                                 "the float coordinates of integer=False can")
        cam = self.for_sensor(events.sensor_size)
        if events.x.dtype.kind == "f":
            raise CalibrationError("events already have float (undistorted?) coordinates")
        ux, uy = cam.undistortion_lut()
        xi = events.x.astype(np.intp)
        yi = events.y.astype(np.intp)
        x = ux[yi, xi]
        y = uy[yi, xi]
        if integer:
            x = np.rint(x)
            y = np.rint(y)
        meta = dict(events.meta, undistorted=True, grid=cam.grid_label(undistorted=True),
                    undistort_dropped=0)
        h, w = cam.sensor_size
        if drop_outside:
            keep = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
            x, y, t, p = x[keep], y[keep], events.t[keep], events.p[keep]
            meta["undistort_dropped"] = int(keep.size - np.count_nonzero(keep))
        else:
            t, p = events.t, events.p
        if integer:
            x, y = x.astype(events.x.dtype), y.astype(events.y.dtype)
        return EventArray(x, y, t, p, cam.sensor_size, validate=False, meta=meta)

    def grid_label(self, *, undistorted: bool) -> str:
        """Which pixel grid coordinates live on: ``"distorted sensor"`` or
        ``"undistorted (K=[fx, fy, cx, cy])"`` (the pinhole grid of this K)."""
        if not undistorted:
            return "distorted sensor"
        k = ", ".join(f"{v:.6g}" for v in (self.fx, self.fy, self.cx, self.cy))
        return f"undistorted (K=[{k}])"


def _dist5(dist) -> tuple[float, float, float, float, float]:
    if dist is None:
        return (0.0, 0.0, 0.0, 0.0, 0.0)
    d = np.zeros(5)
    vals = np.asarray(dist, dtype=np.float64).ravel()
    if vals.size > 5:
        raise CalibrationError(f"at most 5 distortion coefficients (k1 k2 p1 p2 k3), got {vals.size}")
    d[: vals.size] = vals
    return (d[0], d[1], d[2], d[3], d[4])


#: A distortion model that moves a sensor corner by more than this share of its distance
#: from the principal point is said (:func:`warn_strong_distortion`).
MAX_CORNER_SHIFT = 1.0


def warn_strong_distortion(cam: Camera, where: str) -> str | None:
    """Warn (EvmotionWarning) when ``cam``'s distortion moves a sensor corner by more than
    :data:`MAX_CORNER_SHIFT` of its distance from the principal point: a model of no lens
    (coefficients in another order, or of another model); returns the message (else
    None)."""
    shift = cam.corner_shift()
    if not shift > MAX_CORNER_SHIFT:  # NaN: no sensor size to test
        return None
    import warnings

    from evmotion.errors import EvmotionWarning

    d = ", ".join(f"{v:g}" for v in cam.dist)
    msg = (f"{where}: the distortion coefficients [{d}] move the sensor's corners by "
           f"{shift:.0%} of their distance from the principal point (real lenses: a few "
           "tens of %): coefficients in another order (k1 k2 p1 p2 k3), or of another "
           "lens model? The events are undistorted with them as given")
    warnings.warn(EvmotionWarning(msg), stacklevel=3)
    return msg
