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
from pathlib import Path

import numpy as np

from evmotion.errors import CalibrationError, FormatError
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
    sensor_size : (int, int)
        ``(height, width)`` in pixels.

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
    sensor_size: tuple[int, int] = (180, 240)
    _lut: dict = field(default_factory=dict, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        vals = np.array([self.fx, self.fy, self.cx, self.cy, *self.dist], dtype=np.float64)
        if vals.size != 9 or not np.all(np.isfinite(vals)):
            raise CalibrationError(f"camera parameters must be 4 intrinsics + 5 distortion "
                                   f"coefficients, all finite; got {vals.tolist()}")
        if self.fx <= 0 or self.fy <= 0:
            raise CalibrationError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        object.__setattr__(self, "dist", tuple(float(d) for d in self.dist))
        object.__setattr__(self, "sensor_size", tuple(int(s) for s in self.sensor_size))

    # ----------------------------------------------------------- constructors
    @classmethod
    def from_K(cls, K: np.ndarray, dist=None, sensor_size=(180, 240)) -> Camera:
        """From a 3x3 intrinsic matrix and optional distortion coefficients."""
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3):
            raise CalibrationError(f"K must be 3x3, got shape {K.shape}")
        d = _dist5(dist)
        return cls(K[0, 0], K[1, 1], K[0, 2], K[1, 2], d, sensor_size)

    @classmethod
    def from_ecd(cls, path: str | Path, sensor_size=(180, 240)) -> Camera:
        """From an ECD ``calib.txt``: one line ``fx fy cx cy k1 k2 p1 p2 k3``."""
        from evmotion.io.ecd import calib_file, parse_calib

        path = calib_file(path)
        if not path.is_file():
            raise CalibrationError(f"{path}: calibration file not found (ECD folders hold calib.txt)")
        vals = parse_calib(path)  # FormatError naming the file and value when malformed
        return cls(*vals[:4], dist=tuple(vals[4:]), sensor_size=sensor_size)

    @classmethod
    def from_mvsec_yaml(cls, path: str | Path, camera: str = "cam0") -> Camera:
        """From an MVSEC ``camchain-*.yaml`` (Kalibr: ``intrinsics``, ``distortion_coeffs``,
        ``resolution`` of ``cam0``/``cam1``, radtan model)."""
        data = _load_yaml(path)
        if camera not in data:
            raise FormatError(path, f"no camera '{camera}'; has {sorted(data)}")
        c = data[camera]
        for key in ("intrinsics", "resolution"):
            if key not in c:
                raise FormatError(path, f"field '{camera}.{key}' is missing")
        model = c.get("distortion_model", "radtan")
        if model not in ("radtan", "plumb_bob"):
            raise CalibrationError(f"{path}: distortion model '{model}' is not supported "
                                   "(radtan only)")
        fx, fy, cx, cy = (float(v) for v in c["intrinsics"])
        w, h = (int(v) for v in c["resolution"])
        return cls(fx, fy, cx, cy, _dist5(c.get("distortion_coeffs")), (h, w))

    @classmethod
    def from_dsec_yaml(cls, path: str | Path, camera: str = "camRect0") -> Camera:
        """From a DSEC ``cam_to_cam.yaml`` (``intrinsics.<camera>.camera_matrix`` = fx fy cx cy,
        ``distortion_coeffs``, ``resolution``). Rectified cameras have no distortion."""
        data = _load_yaml(path)
        try:
            c = data["intrinsics"][camera]
            fx, fy, cx, cy = (float(v) for v in c["camera_matrix"])
            w, h = (int(v) for v in c["resolution"])
        except (KeyError, TypeError, ValueError) as exc:
            raise FormatError(path, f"field 'intrinsics.{camera}' is missing or malformed ({exc})",
                              ) from None
        return cls(fx, fy, cx, cy, _dist5(c.get("distortion_coeffs")), (h, w))

    @classmethod
    def from_file(cls, path: str | Path, **kw) -> Camera:
        """Detect the calibration format: ECD ``calib.txt`` (or a folder holding one), MVSEC or
        DSEC YAML."""
        path = Path(path)
        if path.is_dir() or path.suffix == ".txt":
            return cls.from_ecd(path, **kw)
        if path.suffix in (".yaml", ".yml"):
            data = _load_yaml(path)
            if "intrinsics" in data and isinstance(data["intrinsics"], dict):
                return cls.from_dsec_yaml(path, **kw)
            return cls.from_mvsec_yaml(path, **kw)
        raise CalibrationError(f"{path}: unknown calibration format (expected calib.txt or YAML)")

    def with_sensor_size(self, sensor_size: tuple[int, int]) -> Camera:
        return replace(self, sensor_size=sensor_size, _lut={})

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
        if "undist" not in self._lut:
            h, w = self.sensor_size
            vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
            ux, uy = self.undistort_pixels(uu.ravel(), vv.ravel())
            self._lut["undist"] = (ux.reshape(h, w).astype(np.float32),
                                   uy.reshape(h, w).astype(np.float32))
        return self._lut["undist"]

    def undistort_events(self, events: EventArray, *, drop_outside: bool = True) -> EventArray:
        """Events with undistorted float32 coordinates, through the per-pixel lookup table.

        Events whose undistorted position falls outside the sensor are dropped unless
        ``drop_outside=False`` (then they are kept and the result is not bounds-checked).
        """
        if events.sensor_size != self.sensor_size:
            raise CalibrationError(
                f"calibration is for sensor_size {self.sensor_size} (height, width) but the "
                f"events are {events.sensor_size}")
        if events.x.dtype.kind == "f":
            raise CalibrationError("events already have float (undistorted?) coordinates")
        ux, uy = self.undistortion_lut()
        xi = events.x.astype(np.intp)
        yi = events.y.astype(np.intp)
        x = ux[yi, xi]
        y = uy[yi, xi]
        meta = dict(events.meta, undistorted=True)
        if drop_outside:
            h, w = self.sensor_size
            keep = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
            return EventArray(x[keep], y[keep], events.t[keep], events.p[keep], self.sensor_size,
                              validate=False, meta=meta)
        return EventArray(x, y, events.t, events.p, self.sensor_size, validate=False, meta=meta)


def _dist5(dist) -> tuple[float, float, float, float, float]:
    if dist is None:
        return (0.0, 0.0, 0.0, 0.0, 0.0)
    d = np.zeros(5)
    vals = np.asarray(dist, dtype=np.float64).ravel()
    if vals.size > 5:
        raise CalibrationError(f"at most 5 distortion coefficients (k1 k2 p1 p2 k3), got {vals.size}")
    d[: vals.size] = vals
    return (d[0], d[1], d[2], d[3], d[4])


def _load_yaml(path) -> dict:
    import yaml

    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: calibration file not found")
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise FormatError(path, f"not valid YAML: {exc}") from None
    if not isinstance(data, dict):
        raise FormatError(path, "expected a YAML mapping at the top level")
    return data
