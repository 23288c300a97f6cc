"""Videos of a sequence: RGB frames to an H.264 ``.mp4`` through imageio-ffmpeg (the
``video`` extra: ``pip install 'evmotion[video]'``), and the flow | IWE | events frames of a
sequence of windows on one colour scale.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Iterator, Sequence

import numpy as np

from evmotion.errors import MissingDependencyError, ParameterError
from evmotion.events import EventArray, Window
from evmotion.utils import atomic_path
from evmotion.viz.flowpic import flow_panel, sequence_max_speed

__all__ = ["flow_video_frames", "require_video", "write_flow_video", "write_video"]


def require_video():
    """The ``imageio_ffmpeg`` module, or MissingDependencyError naming the extra: for
    commands to check before their work, not after it."""
    try:
        import imageio_ffmpeg
    except ImportError:
        raise MissingDependencyError("imageio-ffmpeg", "writing videos", "video") from None
    return imageio_ffmpeg


def write_video(frames_rgb: Iterable[np.ndarray], path: str | os.PathLike,
                fps: float = 10.0, *, quality: int = 8) -> int:
    """Write uint8 RGB frames as an H.264 video (yuv420p, plays everywhere), atomically.

    Parameters
    ----------
    frames_rgb : iterable of ndarray of uint8, shape (H, W, 3)
        All frames the same shape; odd sizes are padded white by one row/column (H.264 in
        yuv420p needs even sizes). Consumed lazily, so a generator keeps memory flat.
    path : path-like
        Output file; its suffix picks the container (``.mp4``, ``.mkv``...).
    fps : float
        Frames per second (> 0).
    quality : int
        imageio-ffmpeg's quality, 0 (worst) to 10 (best, largest file).

    Returns
    -------
    int
        The number of frames written.

    Raises
    ------
    MissingDependencyError
        imageio-ffmpeg is not installed.

    Examples
    --------
    >>> frames = [np.full((64, 64, 3), 25 * k, np.uint8) for k in range(10)]
    >>> write_video(frames, "fade.mp4", fps=5)
    10
    """
    if not (math.isfinite(fps) and fps > 0):
        raise ParameterError(f"fps must be finite and > 0, got {fps}")
    if not 0 <= quality <= 10:
        raise ParameterError(f"quality must be in 0..10, got {quality}")
    iio = require_video()
    frames = iter(frames_rgb)
    first = next(frames, None)
    if first is None:
        raise ParameterError(f"{os.fspath(path)}: no frames to write")
    shape = np.asarray(first).shape
    if len(shape) != 3 or shape[2] != 3 or 0 in shape:
        raise ParameterError(f"{os.fspath(path)}: frames must be (H, W, 3) RGB, got {shape}")
    h2, w2 = shape[0] + shape[0] % 2, shape[1] + shape[1] % 2
    n = 0
    with atomic_path(path) as tmp:
        writer = iio.write_frames(os.fspath(tmp), (w2, h2), fps=float(fps), codec="libx264",
                                  pix_fmt_in="rgb24", pix_fmt_out="yuv420p", quality=quality,
                                  macro_block_size=1, ffmpeg_log_level="error")
        writer.send(None)
        try:
            for k, frame in enumerate(_chain(first, frames)):
                frame = np.asarray(frame)
                if frame.shape != shape or frame.dtype != np.uint8:
                    raise ParameterError(
                        f"{os.fspath(path)}: frame {k} is {frame.dtype} {frame.shape}, "
                        f"expected uint8 {shape} like frame 0")
                if (h2, w2) != shape[:2]:
                    frame = np.pad(frame, ((0, h2 - shape[0]), (0, w2 - shape[1]), (0, 0)),
                                   constant_values=255)
                writer.send(np.ascontiguousarray(frame))
                n += 1
        finally:
            writer.close()
    return n


def _chain(first, rest: Iterator) -> Iterator:
    yield first
    yield from rest


def flow_video_frames(events: EventArray, windows: Sequence[Window],
                      flows: Sequence[np.ndarray], *, valids: Sequence[np.ndarray] | None = None,
                      max_speed: float | None = None, t_refs_us: Sequence[int] | None = None,
                      ) -> Iterator[np.ndarray]:
    """The :func:`~evmotion.viz.flowpic.flow_panel` of every window, on one colour scale.

    Parameters
    ----------
    events : EventArray
        The recording the windows index.
    windows : sequence of Window
        One per flow.
    flows : sequence of ndarray, shape (H, W, 2)
        Flow of each window, px/s.
    valids : sequence of ndarray of bool, optional
        Event support of each flow (grey elsewhere).
    max_speed : float, optional
        Speed at the legend wheel's rim (px/s); default: the largest valid speed of the whole
        sequence, so colours compare across frames.
    t_refs_us : sequence of int, optional
        Warp reference time of each window (default: its first event).

    Yields
    ------
    ndarray of uint8, shape (rows, cols, 3)
        One frame per window, all the same shape.
    """
    if len(flows) != len(windows):
        raise ParameterError(f"{len(flows)} flows for {len(windows)} windows")
    if valids is not None and len(valids) != len(windows):
        raise ParameterError(f"{len(valids)} valid masks for {len(windows)} windows")
    if max_speed is None:
        max_speed = sequence_max_speed(flows, valids)
    for k, w in enumerate(windows):
        rgb, _ = flow_panel(events.window(w), flows[k], max_speed=max_speed,
                            valid=None if valids is None else valids[k],
                            t_ref_us=None if t_refs_us is None else t_refs_us[k],
                            title=f"window {w.index}: [{w.t0}, {w.t1}) µs")
        yield rgb


def write_flow_video(path: str | os.PathLike, events: EventArray, windows: Sequence[Window],
                     flows: Sequence[np.ndarray], *, valids: Sequence[np.ndarray] | None = None,
                     max_speed: float | None = None, fps: float = 5.0) -> int:
    """Write the events | warped IWE | flow frames of a sequence as a video (see
    :func:`flow_video_frames` and :func:`write_video`); returns the number of frames.

    Examples
    --------
    >>> from evmotion.events import make_windows
    >>> from evmotion.sim import simulate
    >>> sim = simulate("translation", duration_s=0.02, sensor_size=(40, 60), seed=0,
    ...                show_progress=False)
    >>> windows = make_windows(sim.events, n_events=2000)
    >>> flows = [sim.gt.flow((w.t0 + w.t1) // 2) for w in windows]   # px/s
    >>> write_flow_video("flow.mp4", sim.events, windows, flows) == len(windows)
    True
    """
    require_video()  # fail before rendering anything
    frames = flow_video_frames(events, windows, flows, valids=valids, max_speed=max_speed)
    return write_video(frames, path, fps)
