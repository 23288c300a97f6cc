"""Frames co-captured with events: one container and one reader for every layout.

:class:`Frames` holds a stack of grey images on the event sensor's pixel grid with their
timestamps (int64 µs). :func:`read_frames` reads it from

* an ECD-style folder: ``images.txt`` with ``t path`` lines (t in seconds), 8- or 16-bit
  PNGs (the layout :func:`evmotion.sim.schlieren.write_schlieren` writes);
* an AEDAT4 file (DAVIS APS frames, :func:`evmotion.io.aedat4.read_frames`);
* the layout of the published event-based BOS data (``tub-rip/event_based_bos``): a
  sequence folder with the frames as images in a sub-folder and their trigger times in
  a text file;
* a folder of images plus a timestamps file (one time per line in the images' name
  order, or ``t path`` lines).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from evmotion.errors import FormatError

__all__ = ["Frames"]


@dataclass(frozen=True, eq=False)
class Frames:
    """Grey frames with timestamps.

    Attributes
    ----------
    images : ndarray (N, H, W)
        uint8 or uint16 (``bit_depth`` says how many bits are used), or (N, H, W, C) for
        colour sources that keep their channels.
    t : ndarray (N,) int64
        Frame timestamps in µs, strictly increasing.
    source : str or None
        The file or folder read.
    bit_depth : int
        Significant bits per pixel (8 for uint8; 16, 12 or 10 for uint16 sources).
    exposure_start, exposure_end : ndarray (N,) int64 or None
        Exposure window per frame, µs, where the source records it.
    position : ndarray (N, 2) int64 or None
        ``x, y`` of each image's top-left corner on the sensor (DAVIS ROI frames).

    Examples
    --------
    >>> import numpy as np
    >>> fr = Frames(np.zeros((2, 4, 5), np.uint8), np.array([0, 8333]))
    >>> len(fr), fr.sensor_size, round(fr.fps, 1)
    (2, (4, 5), 120.0)
    """

    images: np.ndarray
    t: np.ndarray
    source: str | None = None
    bit_depth: int = 8
    exposure_start: np.ndarray | None = field(default=None, repr=False)
    exposure_end: np.ndarray | None = field(default=None, repr=False)
    position: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        src = self.source
        images = np.asarray(self.images)
        if images.ndim == 2:
            images = images[None]
        if images.ndim not in (3, 4) or (images.size == 0 and images.ndim != 3):
            raise FormatError(src, f"frames must be a stack (N, H, W), got shape {images.shape}")
        if images.dtype not in (np.uint8, np.uint16):
            raise FormatError(src, f"frames must be uint8 or uint16, got {images.dtype}")
        t = np.asarray(self.t, dtype=np.int64).reshape(-1)
        if t.shape[0] != images.shape[0]:
            raise FormatError(src, f"{images.shape[0]} images but {t.shape[0]} timestamps")
        d = np.diff(t)
        if d.size and d.min() <= 0:
            i = int(np.argmax(d <= 0))
            what = "duplicate" if d[i] == 0 else "unsorted"
            raise FormatError(src, f"{what} frame timestamps: t[{i}]={t[i]} us, "
                              f"t[{i + 1}]={t[i + 1]} us")
        object.__setattr__(self, "images", images)
        object.__setattr__(self, "t", t)
        for name in ("exposure_start", "exposure_end"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, np.asarray(v, dtype=np.int64).reshape(-1))
        if self.position is not None:
            object.__setattr__(self, "position",
                               np.asarray(self.position, dtype=np.int64).reshape(-1, 2))

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def sensor_size(self) -> tuple[int, int]:
        """``(height, width)`` of the images."""
        return int(self.images.shape[1]), int(self.images.shape[2])

    @property
    def fps(self) -> float:
        """Mean frame rate (Hz) from the timestamps; NaN for fewer than two frames."""
        if len(self) < 2:
            return float("nan")
        return (len(self) - 1) * 1e6 / float(self.t[-1] - self.t[0])

    def as_float(self) -> np.ndarray:
        """Images scaled to [0, 1] by the bit depth (float32)."""
        return self.images.astype(np.float32) / float(2 ** self.bit_depth - 1)
