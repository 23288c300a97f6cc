"""Frame-based optical flow by Farneback's polynomial expansion (OpenCV).

The thesis (ch. 6, §6.5) uses Farneback's method with four pyramid levels on the 120 fps
frames of its schlieren recordings as the "ground truth" flow. Here it is a baseline that the
schlieren simulator's exact flow can grade (how good that frame-based ground truth is).

OpenCV (``opencv-python-headless``, extra ``evmotion[bos]``) is imported when a flow is
computed, so the rest of evmotion works without it.
"""

from __future__ import annotations

import numpy as np

from evmotion.errors import MissingDependencyError, ParameterError
from evmotion.utils import check_finite

__all__ = ["farneback_flow", "frame_to_float"]


def _cv2():
    try:
        import cv2
    except ImportError:
        raise MissingDependencyError("opencv-python-headless", "Farneback optical flow",
                                     "bos") from None
    return cv2


def frame_to_float(frame: np.ndarray, name: str = "frame") -> np.ndarray:
    """A frame as a float32 grey image on the 8-bit scale [0, 255].

    Integer frames are scaled by 255 / (largest value of their dtype), so 16-bit frames keep
    their precision instead of being truncated to 8 bits; float frames are taken to be in
    [0, 1]. RGB(A) frames (H, W, 3|4) are converted to luma (ITU-R BT.601).

    Parameters
    ----------
    frame : ndarray, shape (H, W) or (H, W, 3|4)
        uint8, uint16 (any unsigned/signed integer dtype) or float in [0, 1].
    name : str
        Name used in error messages.

    Returns
    -------
    ndarray of float32, shape (H, W)

    Examples
    --------
    >>> frame_to_float(np.array([[0, 65535]], dtype=np.uint16)).tolist()
    [[0.0, 255.0]]
    >>> frame_to_float(np.array([[0.5]])).tolist()
    [[127.5]]
    """
    a = np.asarray(frame)
    if a.ndim == 3 and a.shape[2] in (3, 4):
        rgb = _scaled(a[..., :3], name)
        return np.ascontiguousarray(rgb @ np.array([0.299, 0.587, 0.114], np.float32))
    if a.ndim != 2:
        raise ParameterError(f"{name} must be a 2-D grey image or (H, W, 3) RGB, "
                             f"got shape {a.shape}")
    return _scaled(a, name)


def _scaled(a: np.ndarray, name: str) -> np.ndarray:
    # every channel of ``a`` as float32 on [0, 255] (see frame_to_float)
    if a.size == 0:
        raise ParameterError(f"{name} is empty (shape {a.shape})")
    if np.issubdtype(a.dtype, np.integer):
        return (a.astype(np.float32) * np.float32(255.0 / np.iinfo(a.dtype).max))
    if np.issubdtype(a.dtype, np.floating) or a.dtype == np.bool_:
        out = a.astype(np.float32) * np.float32(255.0)
        if not np.all(np.isfinite(out)):
            raise ParameterError(f"{name} has NaN or inf values")
        return out
    raise ParameterError(f"{name} has unsupported dtype {a.dtype} (need integer or float)")


def farneback_flow(frame0: np.ndarray, frame1: np.ndarray, dt_s: float, *, levels: int = 4,
                   pyr_scale: float = 0.5, winsize: int = 15, iterations: int = 3,
                   poly_n: int = 5, poly_sigma: float = 1.1, gaussian: bool = False,
                   ) -> np.ndarray:
    """Dense optical flow from ``frame0`` to ``frame1`` by Farneback's method, in px/s.

    Parameters
    ----------
    frame0, frame1 : ndarray, shape (H, W) or (H, W, 3)
        Consecutive frames (uint8, uint16 or float in [0, 1]; see :func:`frame_to_float`).
    dt_s : float
        Time between the frames in seconds (e.g. 1/120 at 120 fps).
    levels : int
        Pyramid levels (default 4, as the thesis' frame-based ground truth; 1 = no pyramid).
    pyr_scale : float
        Image scale between pyramid levels, in (0, 1) (default 0.5).
    winsize : int
        Averaging window in px (default 15): larger is more robust, smoother.
    iterations : int
        Iterations per pyramid level (default 3).
    poly_n : int
        Neighbourhood of the polynomial expansion in px (5 or 7 typical).
    poly_sigma : float
        Gaussian sigma of the polynomial expansion (1.1 for ``poly_n=5``, 1.5 for 7).
    gaussian : bool
        Gaussian instead of box averaging window (OpenCV's ``OPTFLOW_FARNEBACK_GAUSSIAN``).

    Returns
    -------
    ndarray of float32, shape (H, W, 2)
        Flow at ``frame0``'s pixels in px/s (u right, v down): the content at ``(x, y)`` in
        ``frame0`` is at ``(x, y) + flow * dt_s`` in ``frame1``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> img = rng.random((64, 64)).repeat(2, 0).repeat(2, 1)   # 2-px dots, 128 x 128
    >>> shifted = np.roll(img, 1, axis=1)                      # 1 px right
    >>> flow = farneback_flow(img, shifted, 0.01)
    >>> bool(abs(np.median(flow[16:-16, 16:-16, 0]) - 100.0) < 5.0)   # 1 px / 10 ms
    True
    """
    dt = float(check_finite("dt_s", dt_s))
    if dt <= 0:
        raise ParameterError(f"parameter 'dt_s' must be > 0 s, got {dt_s!r}")
    if int(levels) != levels or levels < 1:
        raise ParameterError(f"parameter 'levels' must be an integer >= 1, got {levels!r}")
    if not 0 < pyr_scale < 1:
        raise ParameterError(f"parameter 'pyr_scale' must be in (0, 1), got {pyr_scale!r}")
    if winsize < 3 or iterations < 1 or poly_n < 3 or not poly_sigma > 0:
        raise ParameterError(f"need winsize >= 3, iterations >= 1, poly_n >= 3, poly_sigma > 0; "
                             f"got winsize={winsize}, iterations={iterations}, "
                             f"poly_n={poly_n}, poly_sigma={poly_sigma}")
    a = frame_to_float(frame0, "frame0")
    b = frame_to_float(frame1, "frame1")
    if a.shape != b.shape:
        raise ParameterError(f"frames differ in size: frame0 {a.shape}, frame1 {b.shape}")
    cv2 = _cv2()
    flags = cv2.OPTFLOW_FARNEBACK_GAUSSIAN if gaussian else 0
    # OpenCV's "levels" counts the pyramid layers including the original image
    flow = cv2.calcOpticalFlowFarneback(a, b, None, float(pyr_scale), int(levels),
                                        int(winsize), int(iterations), int(poly_n),
                                        float(poly_sigma), flags)
    return (flow / np.float32(dt)).astype(np.float32)
