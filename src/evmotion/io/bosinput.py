"""Inputs of event-based BOS: events plus frames on the event sensor's grid, checked.

:func:`load_bos_input` reads a recording (an ECD-style folder ``events.txt`` +
``images.txt`` + ``images/``, or any event file with ``--frames``), the frames and their
timestamps, and cuts the frame intervals ``[t_i, t_{i+1})`` that the events cover (a
warning names those inside which their recording was cut). It
raises one clear error for each input the method cannot use: frames missing, frames and
events of different sizes or not overlapping in time, an ROI outside the sensor (the
solver, :func:`evmotion.methods.bos.estimate_bos`, rejects a frame without texture).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evmotion.errors import (
    EmptyWindowError,
    EvmotionError,
    EvmotionWarning,
    FormatError,
    ParameterError,
    TimeUnitGuessWarning,
)
from evmotion.events import EventArray
from evmotion.io.base import TIME_UNIT_US
from evmotion.io.bosfiles import roi_mask
from evmotion.io.guard import LARGEST_COORDINATE
from evmotion.utils import seconds_text

__all__ = ["BosInput", "frame_intervals", "load_bos_input"]

# frames more than a second and this many times the events' whole span apart: a unit slip
# (frame times in us or ms read as seconds), not a recording
UNIT_SLIP = 100
# frames further apart than this (median) see no schlieren: times in another unit
MAX_FRAME_SPACING_US = 60_000_000
# frames further apart than this (median) are slower than any BOS video: warned about
# (milliseconds in both lists read as seconds gave a flow 1000x too small, unsaid; probe)
SLOW_FRAME_SPACING_US = 1_000_000
# ... and closer than this, faster than a camera beside an event sensor runs (seconds in
# both lists read with --time-unit ms: 1000x too large a flow)
FAST_FRAME_SPACING_US = 100
# a frame interval the events stop inside of, covering less than this share of it as
# densely as the whole intervals (CUT_DENSITY of their rate, at least), is a cut recording:
# its flow is too small by the share (0.81x for 80 %, 0.68x for 60 % on another renderer's
# plume) and no measurement
MIN_COVERAGE = 0.95
CUT_DENSITY = 0.5
# the same for the interval the events begin in, where a sensor's start-up (bos_run) also
# thins them: the simulator's begin 72 % into their first interval, dense
MIN_START_COVERAGE = 0.6
# ... and where, at the intervals' event rate, at least this many events would have come in
# the part not covered (sparse events leave a gap at the end by chance: noise at 4 events
# a ms stopped 0.8 ms before a 10 ms interval's end)
CUT_EVENTS = 10
# a frame with more pixels than this share clipped at full scale is warned about
MAX_CLIPPED = 0.75
# where readers say the sensor size came from when the file does not state it
GUESSED_SIZES = ("ECD default", "default", "max coordinate", LARGEST_COORDINATE)
#: :func:`_refuse_finer_frames`: events it needs to judge, and how far (px) their extent
#: may fall short of 1/k of the frames (no event in the last rows or columns)
FINER_FRAMES_MIN_EVENTS = 1000
FINER_FRAMES_SLACK_PX = 4
#: ... and, short of that edge, how well the events must follow the frames binned k x k
#: (and how much better than the frames at full size) to say so: 0.99 against -0.03 on
#: probe AY's frames at 2x; on frames at the events' size -0.25 to 0.30 against 0.83-0.99
FINER_FRAMES_CORRELATION = 0.5
FINER_FRAMES_MARGIN = 0.3
#: :func:`_refuse_offset_view`: the margin (px) of the frames the events must leave
#: unreached, and the offset the best correlation must lie at, for it to look (a view a
#: few px off is :func:`~evmotion.methods.bos_run.check_registration`'s)
OFFSET_VIEW_MIN_PX = 4


@dataclass(frozen=True)
class BosInput:
    """Events and frames ready for the BOS solver.

    Attributes
    ----------
    events : EventArray
        All events of the recording (sensor size ``(H, W)``).
    frames : ndarray, (N, H, W)
        Frames on the event sensor's pixel grid.
    frame_times : ndarray, (N,) int64
        Frame timestamps in µs.
    intervals : ndarray, (M, 3) int64
        Selected frame intervals: ``(i, t_i, t_{i+1})``, each using frame ``i``.
    roi : (int, int, int, int) or None
        ``(x, y, w, h)`` px.
    source : str
        Where the data came from.
    frames_source : str
        Where the frames came from (``images.txt`` beside the events, ``--frames``, or
        the recording's own), as a real path.
    cut : tuple of int
        Indices (in ``intervals``) of the intervals the recording of the events was cut
        in: they cover less than :data:`MIN_COVERAGE` of it, as densely as elsewhere.
    """

    events: EventArray
    frames: np.ndarray
    frame_times: np.ndarray
    intervals: np.ndarray
    roi: tuple[int, int, int, int] | None
    source: str
    frames_source: str = ""
    cut: tuple[int, ...] = ()


def frame_intervals(frame_times: np.ndarray, t_first: int, t_last: int, *,
                    t0: int | None = None, t1: int | None = None,
                    max_intervals: int | None = None) -> np.ndarray:
    """The frame intervals ``(i, t_i, t_{i+1})`` that overlap the events' time span
    ``[t_first, t_last]`` µs, inside ``[t0, t1)`` when given, at most ``max_intervals``.

    Examples
    --------
    >>> frame_intervals(np.array([0, 10, 20, 30]), 5, 19).tolist()
    [[0, 0, 10], [1, 10, 20]]
    """
    ft = np.asarray(frame_times, dtype=np.int64)
    lo, hi = ft[:-1], ft[1:]
    keep = (hi > t_first) & (lo <= t_last)
    if t0 is not None:
        keep &= lo >= t0
    if t1 is not None:
        keep &= hi <= t1
    idx = np.flatnonzero(keep)
    if max_intervals is not None:
        idx = idx[:max_intervals]
    return np.stack([idx, lo[idx], hi[idx]], axis=1).astype(np.int64).reshape(-1, 3)


def _cut(intervals: np.ndarray, t: np.ndarray, rec) -> tuple[int, ...]:
    """Indices of the ``intervals`` the events ``t`` (sorted, µs) stop inside of, covering
    less than :data:`MIN_COVERAGE` of it (:data:`MIN_START_COVERAGE` where they begin
    inside it) while coming as densely as in the whole intervals, where at their rate
    :data:`CUT_EVENTS` would have come in the rest, said in a warning: a recording of the
    events cut there (the measured increment then holds only part of the change and the
    flow comes out too small: half, for half an interval). Events that begin late and
    sparse are the air starting to move, not a cut, and are not named; a dense onset
    cannot be told from a cut."""
    if not len(intervals):
        return ()
    lo, hi = intervals[:, 1], intervals[:, 2]
    t_first, t_last = int(t[0]), int(t[-1])
    covered = np.clip(np.minimum(hi, t_last + 1) - np.maximum(lo, t_first), 0, None)
    cover = covered / (hi - lo)
    count = np.searchsorted(t, hi) - np.searchsorted(t, lo)
    full = cover >= 0.99
    if full.all() or not full.any():
        return ()
    rate = float(np.median(count[full] / (hi - lo)[full]))
    least = np.where(hi > t_last + 1, MIN_COVERAGE, MIN_START_COVERAGE)
    cut = ((cover < least) & (count >= CUT_DENSITY * rate * covered)
           & (rate * ((hi - lo) - covered) >= CUT_EVENTS))
    if cut.any():
        listed = ", ".join(f"[{a}, {b}) us {100 * c:.0f} %" for a, b, c in
                           zip(lo[cut][:3], hi[cut][:3], cover[cut][:3], strict=True))
        more = f" and {int(cut.sum()) - 3} more" if cut.sum() > 3 else ""
        warnings.warn(EvmotionWarning(
            f"{rec}: the events stop or start inside frame intervals as densely as they "
            f"come elsewhere ({listed} covered{more}): their recording was cut there, and "
            "the flow of those intervals, too small by that share, is written with no valid "
            "pixel (--t0 / --t1 leave them out)"), stacklevel=3)
    return tuple(int(k) for k in np.flatnonzero(cut))


def _span_misfit(times: np.ndarray, t_first: int, t_last: int) -> float:
    # how far (log ratio) the frames' span is from the events'
    return abs(float(np.log(max(times[-1] - times[0], 1) / max(t_last - t_first, 1))))


def _whole_times(listing: Path) -> bool:
    """Whether the times of a timestamps file are whole numbers (no unit stated), as its
    reader tells them (its warning about them said already); an ``images.txt``'s are
    :func:`_image_list`'s ``whole_numbers``."""
    from evmotion.io.frames import whole_number_times

    try:
        return whole_number_times(listing)
    except (FormatError, OSError, UnicodeDecodeError, ValueError):
        return False


def _image_list(listing: Path) -> dict:
    """What :func:`~evmotion.io.ecd.read_image_list` tells of an ``images.txt`` (its
    warnings said already), or ``{}`` where it cannot be read (said by the frames'
    reader)."""
    from evmotion.io.ecd import read_image_list

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", EvmotionWarning)
            return read_image_list(listing)
    except (FormatError, OSError, UnicodeDecodeError, ValueError):
        return {}


def _replay(said: list) -> None:
    """Warn again the warnings ``said`` recorded (:class:`warnings.WarningMessage`)."""
    for w in said:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)


def _whole_milliseconds(times: np.ndarray, spacing: float, where: Path, t_first: int,
                        t_last: int) -> tuple[np.ndarray, float]:
    """Whole-number frame times read as µs that lie closer than any camera's (``spacing``)
    read as milliseconds, with a warning, where so they span the events' time (within 2x)
    and overlap them: 100 fps in whole ms had been 10 us apart, and the run refused for a
    contrast threshold it could not estimate (probe BOSIN); else as they were."""
    alt = times * 1000
    if not (_span_misfit(alt, t_first, t_last) < np.log(2) and alt[-1] > t_first
            and alt[0] < t_last):
        return times, spacing
    warnings.warn(EvmotionWarning(
        f"{where}: its whole-number times read as microseconds put the frames {spacing:g} "
        f"us apart, faster than any camera beside an event sensor, and span "
        f"{int(times[-1] - times[0])} us beside the events' {t_last - t_first} us: read as "
        "milliseconds, which span the events (--frames-time-unit us reads them as "
        "microseconds)"), stacklevel=3)
    return alt, spacing * 1000


def _frames_source(rec: Path, frames: str | os.PathLike | None) -> tuple[Path, bool]:
    """Where the frames are, and whether that is a guess that the recording holds its
    own: ``frames``; else the ``images.txt`` beside the events (or images and a timestamps
    file there, :func:`~evmotion.io.frames.read_frames`), or the recording itself
    where it may hold frames (AEDAT4 APS frames, the published BOS layout, an HDF5 file
    with a frames dataset)."""
    from evmotion.io.frames import TIMESTAMP_FILES, find_frames

    if frames is not None:
        path = Path(frames)
        if not path.exists():
            raise FormatError(path, "frames not found (no such file or folder)")
        return path, False
    folder = rec if rec.is_dir() else rec.parent
    beside = (folder / "images.txt").is_file()
    if beside and rec.is_file() and rec.name != "events.txt" and _holds_frames(rec):
        # a recording with frames of its own (AEDAT4 APS) next to another scene's
        # images.txt: its own frames are the ones registered with its events
        warnings.warn(EvmotionWarning(
            f"{rec}: the recording holds frames of its own, which are used; the images.txt "
            f"beside it ({folder / 'images.txt'}) is not (give it with --frames to use it)"),
            stacklevel=3)
        return rec, False
    if beside:
        return folder, False
    if any((folder / n).is_file() for n in TIMESTAMP_FILES) and \
            find_frames(folder) == "folder":
        return folder, False  # images and a timestamps file beside the events
    if rec.is_file() and rec.suffix.lower() in (".txt", ".csv"):
        # any name: ev.txt ended in a raw "[Errno 2] ... images.txt", exit 1 (probe BP)
        raise FormatError(rec, "no frames: BOS needs frames of the background, and there "
                          "is no images.txt beside these ECD-style events",
                          "give them with --frames")
    if find_frames(rec) in ("ccs", "recording"):
        return rec, True
    raise FormatError(rec, "no frames: BOS needs frames of the background, and there is no "
                      "images.txt beside the events", "give them with --frames")


def _holds_frames(rec: Path) -> bool:
    """Whether an event recording holds frames of its own: AEDAT4 APS frames (the DAVIS
    files that come with frames)."""
    from evmotion.io.frames import describe_frames

    if rec.suffix.lower() != ".aedat4":
        return False
    try:
        return describe_frames(rec) is not None
    except FormatError:
        return False


def _events_on_frames(rec: Path, fmt: str | None, frame_size: tuple[int, int], **kw):
    """The recording's events; one outside the sensor is refused naming the frames' grid
    they must lie on (the reader's own hint names options bos does not have)."""
    from evmotion.io import read_events

    try:
        return read_events(rec, **({"format": fmt} if fmt else {}), **kw)
    except FormatError as exc:
        if "outside the sensor" not in exc.message:
            raise
        raise FormatError(exc.path, exc.message, f"BOS needs the events on the frames' "
                          f"pixel grid, {frame_size[1]}x{frame_size[0]} px (W x H)") from None


def _refuse_finer_frames(src: Path, events: EventArray, images: np.ndarray) -> None:
    """FormatError where the events, on a sensor whose size came from the frames, all lie
    within 1/k of them (k = 2, 3, 4) and either reach that edge to a few px or fire where
    the frames binned by k change, not where the frames at full size do: frames at k x the
    event sensor's resolution (they were solved on the frames' grid, the flow 3x too
    small, after warnings that named other causes, probe AT; a plume in the middle of the
    view left the edge unreached, and with C given the run went on, probe AY)."""
    if not str(events.meta.get("sensor_size_from", "")).startswith("image") \
            or len(events) < FINER_FRAMES_MIN_EVENTS:
        return
    fh, fw = images.shape[1:3]
    ex, ey = int(np.ceil(events.x.max())) + 1, int(np.ceil(events.y.max())) + 1
    change = None
    for k in (2, 3, 4):
        if ex > fw / k or ey > fh / k:
            continue
        at_edge = ex >= fw / k - FINER_FRAMES_SLACK_PX and ey >= fh / k - FINER_FRAMES_SLACK_PX
        if not at_edge:
            change = _frame_change(images) if change is None else change
            full, binned = _change_correlations(events, change, k)
        if at_edge or (binned >= FINER_FRAMES_CORRELATION
                       and binned > full + FINER_FRAMES_MARGIN):
            how = "" if at_edge else (
                f" and follow the frames' change binned {k}x{k} (correlation {binned:.2f}), "
                f"not at full size ({full:.2f})")
            raise FormatError(src, f"the frames are {fw}x{fh} px but every event lies within "
                              f"{ex}x{ey} px, 1/{k} of them (W x H){how}: frames at {k}x the "
                              "event sensor's resolution?",
                              "BOS needs the frames on the event sensor's pixel grid: bin or "
                              f"resize them to {fw // k}x{fh // k}")


def _refuse_offset_view(src: Path, events: EventArray, images: np.ndarray) -> None:
    """FormatError where the events, on a sensor whose size came from the frames, leave a
    margin of the frames unreached and follow the frames' change far better with their
    view moved by some offset into the frames than at the corner: an event sensor's view
    that the frames hold at that offset (larger frames, a padded or uncropped image). The
    registration check searches a few px only: at (13, 10) px the run was refused as
    "frames not of these events", and with C given went on to a flow no better than
    zero (probe CC)."""
    if not str(events.meta.get("sensor_size_from", "")).startswith("image") \
            or len(events) < FINER_FRAMES_MIN_EVENTS:
        return
    fh, fw = images.shape[1:3]
    ex, ey = int(np.ceil(events.x.max())) + 1, int(np.ceil(events.y.max())) + 1
    if fw - ex <= OFFSET_VIEW_MIN_PX and fh - ey <= OFFSET_VIEW_MIN_PX:
        return
    corr = _offset_correlations(events, _frame_change(images), ex, ey)
    oy, ox = np.unravel_index(int(np.argmax(corr)), corr.shape)
    best, corner = float(corr[oy, ox]), float(corr[0, 0])
    if max(ox, oy) > OFFSET_VIEW_MIN_PX and best >= FINER_FRAMES_CORRELATION \
            and best > corner + FINER_FRAMES_MARGIN:
        raise FormatError(src, f"the frames are {fw}x{fh} px and the events lie within "
                          f"{ex}x{ey} px of them (W x H), but follow the frames' change "
                          f"best with their view at ({ox}, {oy}) px into the frames (x, y; "
                          f"correlation {best:.2f}, against {corner:.2f} at the corner): "
                          "the frames hold the event sensor's view at an offset",
                          "BOS needs the frames on the event sensor's pixel grid: crop them "
                          f"to the event sensor's size from x {ox}, y {oy} (its events reach "
                          f"x {ox + ex - 1}, y {oy + ey - 1} of the frames)")


def _offset_correlations(events: EventArray, change: np.ndarray, ex: int, ey: int
                         ) -> np.ndarray:
    """Correlation of the events' count image over ``ex`` x ``ey`` px with the frames'
    ``change`` over the same size at each offset ``(oy, ox)`` into it, both band-passed
    (Gaussians of 1 px less 4 px: the dots' edges, not the plume's outline, which
    correlated 0.85 at 13 px off, probe CC's frames): the numerator by FFT, each offset's
    variance of ``change`` from integral images."""
    from scipy.ndimage import gaussian_filter

    def band(v: np.ndarray) -> np.ndarray:
        return gaussian_filter(v, 1.0) - gaussian_filter(v, 4.0)

    xs, ys = events.x.astype(np.int64), events.y.astype(np.int64)
    a = band(np.bincount(ys * ex + xs, minlength=ey * ex)[:ey * ex]
             .reshape(ey, ex).astype(np.float64))
    a -= a.mean()
    b = band(change)
    # the valid cross-correlation by numpy's FFT over the frames' size: offsets up to the
    # size difference never wrap round (scipy.signal's import cost 0.43 s of the check's
    # 0.6 s on a 200x180 scene)
    num = np.fft.irfft2(np.fft.rfft2(b) * np.conj(np.fft.rfft2(a, s=b.shape)), s=b.shape)
    num = num[:b.shape[0] - ey + 1, :b.shape[1] - ex + 1]
    n = ex * ey

    def box(v: np.ndarray) -> np.ndarray:
        c = np.pad(v.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
        return c[ey:, ex:] - c[:-ey, ex:] - c[ey:, :-ex] + c[:-ey, :-ex]

    var = box(b * b) - box(b) ** 2 / n
    den = np.sqrt(np.maximum(var, 0.0) * float(np.sum(a * a)))
    return np.where(den > 0, num / np.where(den > 0, den, 1.0), 0.0)


def _frame_change(images: np.ndarray, pairs: int = 30) -> np.ndarray:
    """The sum of the absolute log differences of up to ``pairs`` consecutive frames
    spread over the sequence (where the air changed the frames, and noise)."""
    n = len(images)
    picks = np.unique(np.linspace(0, n - 2, min(pairs, n - 1)).round().astype(int))
    out = np.zeros(images.shape[1:3])
    for i in picks:
        a, b = (np.log(images[j].astype(np.float64) + 1.0) for j in (i, i + 1))
        out += np.abs(b - a).reshape(out.shape[0], out.shape[1], -1).mean(axis=2)
    return out


def _change_correlations(events: EventArray, change: np.ndarray, k: int
                         ) -> tuple[float, float]:
    """Correlations of the events' count image over the top-left 1/k of the frames (2 px
    Gaussian) with the frames' ``change`` there at full size, and with ``change`` binned
    k x k."""
    from scipy.ndimage import gaussian_filter

    fh, fw = change.shape
    sh, sw = fh // k, fw // k
    xs, ys = events.x.astype(np.int64), events.y.astype(np.int64)
    counts = np.bincount(ys * sw + xs, minlength=sh * sw)[:sh * sw].reshape(sh, sw)
    binned = change[:sh * k, :sw * k].reshape(sh, k, sw, k).mean(axis=(1, 3))
    ev = gaussian_filter(counts.astype(np.float64), 2.0)
    return (_correlation(ev, gaussian_filter(change[:sh, :sw], 2.0)),
            _correlation(ev, gaussian_filter(binned, 2.0)))


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
    return float(np.sum(a * b)) / den if den > 0 else 0.0


def frames_digest(frames: np.ndarray, frame_times: np.ndarray) -> str:
    """A short digest of frames (their shape, times and pixels): what identifies a BOS
    run's frames for ``--resume`` wherever their folder lies.

    Examples
    --------
    >>> f, t = np.zeros((2, 3, 4), np.uint8), np.array([0, 8333])
    >>> same = frames_digest(f, t) == frames_digest(f.copy(), t)
    >>> same, frames_digest(f, t + 1) == frames_digest(f, t)
    (True, False)
    """
    import hashlib

    h = hashlib.sha1(str((frames.shape, str(frames.dtype))).encode())
    h.update(np.ascontiguousarray(frame_times, np.int64).tobytes())
    h.update(np.ascontiguousarray(frames).tobytes())
    return f"{len(frames)} frames, sha1 {h.hexdigest()[:16]}"


def load_bos_input(rec: str | os.PathLike, frames: str | os.PathLike | None = None, *,
                   fmt: str | None = None, roi: tuple[int, int, int, int] | None = None,
                   t0: int | None = None, t1: int | None = None,
                   max_intervals: int | None = None, time_unit: str | None = None,
                   frames_time_unit: str | None = None) -> BosInput:
    """Read events and frames for BOS and select the frame intervals to estimate.

    Parameters
    ----------
    rec : path-like
        Events: an ECD-style folder (``events.txt``, ``images.txt``, ``images/``) or any
        recording :func:`evmotion.io.read_events` reads.
    frames : path-like, optional
        Frames (:func:`evmotion.io.frames.read_frames`); default the ``images.txt`` of
        ``rec``'s folder, else the frames ``rec`` holds (AEDAT4 APS frames, the published
        BOS layout's).
    fmt : str, optional
        Event format (default: detected).
    roi : (x, y, w, h), optional
        Region of interest in px; must lie inside the sensor.
    t0, t1 : int, optional
        Only frame intervals inside ``[t0, t1)`` µs.
    max_intervals : int, optional
        At most this many intervals (the first ones).
    time_unit : {"s", "ms", "us", "ns"}, optional
        Unit of the events' times where their file does not state it
        (:func:`evmotion.io.read_events`), and of an ``images.txt``'s whole-number times;
        its decimal times are seconds, or in ``time_unit`` where their span is then nearer
        the events'. Other frames' times are read on their own.
    frames_time_unit : {"s", "ms", "us", "ns"}, optional
        Unit of the frames' list's times (``images.txt`` or a timestamps file) where it is
        not the events' (then ``time_unit`` is the events' only).

    Raises
    ------
    FormatError
        No frames, unreadable or missing frame files.
    ParameterError
        Frames and events of different sizes or not overlapping in time, ROI outside the
        sensor.
    EmptyWindowError
        No event at all.

    Examples
    --------
    >>> from evmotion.io import write_events
    >>> from evmotion.io.pngfile import write_png
    >>> for i in range(3):  # an ECD-style folder: frames at 120 fps and their events
    ...     write_png(f"scene/images/frame_{i:08d}.png", np.full((6, 8), 100 + i, np.uint8))
    >>> _ = Path("scene/images.txt").write_text(
    ...     "".join(f"{i / 120:.6f} images/frame_{i:08d}.png\\n" for i in range(3)))
    >>> write_events("scene/events.txt", EventArray(
    ...     x=[1, 2, 3], y=[1, 2, 3], t=[1_000, 9_000, 12_000], p=[1, 0, 1], sensor_size=(6, 8)))
    >>> data = load_bos_input("scene/")
    >>> data.intervals[:2].tolist(), data.frames.shape
    ([[0, 0, 8333], [1, 8333, 16667]], (3, 6, 8))
    """
    from evmotion.io.frames import TIMESTAMP_FILES, read_frames

    if max_intervals is not None and not (isinstance(max_intervals, (int, np.integer))
                                          and max_intervals >= 1):
        raise ParameterError(f"max_intervals must be an integer >= 1, got {max_intervals!r}")
    rec = Path(rec)
    if not rec.exists():
        raise FormatError(rec, "no such file or folder")
    src, guessed = _frames_source(rec, frames)
    # --time-unit is the events'; in an images.txt beside them it also reads the times
    # that state no unit (whole numbers): the folder's two lists are one clock's
    listed = (src / "images.txt") if src.is_dir() else src
    ecd_list = listed.name == "images.txt" and listed.is_file()
    # what its times state, read once for the checks below
    listing = _image_list(listed) if ecd_list else {}
    listed_whole = bool(listing.get("whole_numbers"))
    if frames_time_unit is not None:
        read_unit = {"time_unit": frames_time_unit}
    else:
        # (decimals are seconds, a header's unit is the list's own)
        read_unit = {"time_unit": time_unit} if ecd_list and time_unit and listed_whole \
            else {}
    # the list's guess of its time unit waits for the unit its times are finally read in
    # (a guess of µs that whole milliseconds below replace was said beside that, probe
    # BOSIN); its other warnings are said now
    with warnings.catch_warnings(record=True) as listed_notes:
        warnings.simplefilter("always")
        try:
            fr = read_frames(src, **read_unit)
        except FormatError as exc:
            failed = exc
        else:
            failed = None
    guesses = [w for w in listed_notes if issubclass(w.category, TimeUnitGuessWarning)]
    _replay([w for w in listed_notes if w not in guesses])
    if failed is not None:
        _replay(guesses)
        if not guessed:
            raise failed
        raise FormatError(rec, "no frames: BOS needs frames of the background; there is no "
                          "images.txt beside the events and the recording gives none "
                          f"({failed.message})", "give them with --frames") from None
    roi = None if roi is None else tuple(int(v) for v in roi)
    try:
        images, times, events = _frames_and_events(rec, fmt, src, fr, time_unit, roi)
    except EvmotionError:
        _replay(guesses)
        raise
    t_first, t_last = int(events.t[0]), int(events.t[-1])
    if (ecd_list and frames_time_unit is None and time_unit not in (None, "s")
            and not listed_whole and listing.get("unit") is None):
        # decimal times beside events read in time_unit: ECD's seconds, or that unit too
        # (decimal milliseconds in both lists, probe)
        alt = np.rint(times * (TIME_UNIT_US[time_unit] * 1e-6)).astype(np.int64)
        if np.all(np.diff(alt) > 0) and _span_misfit(alt, t_first, t_last) < \
                _span_misfit(times, t_first, t_last):
            times = alt
    where = src / "images.txt" if (src / "images.txt").is_file() else next(
        (src / n for n in TIMESTAMP_FILES if src.is_dir() and (src / n).is_file()), src)
    spacing = float(np.median(np.diff(times)))
    # whole numbers were read as µs: nanoseconds (relative ns; ms was the wrong advice,
    # then refused, probe AT); decimals as seconds: milliseconds
    whole = (frames_time_unit is None and not (ecd_list and time_unit is not None)
             and where.is_file() and (listed_whole if ecd_list and where == listed
                                      else _whole_times(where)))
    if whole and spacing < FAST_FRAME_SPACING_US:
        read_ms, spacing = _whole_milliseconds(times, spacing, where, t_first, t_last)
        if read_ms is not times:
            guesses = []  # its own warning says the times are read as milliseconds
        times = read_ms
    _replay(guesses)
    unit, read = (("ns", "nanoseconds read as microseconds") if whole
                  else ("ms", "milliseconds read as seconds"))
    if not whole and FAST_FRAME_SPACING_US <= spacing * 1e-6 <= SLOW_FRAME_SPACING_US:
        # decimals read as seconds that are a camera's spacing as microseconds (10000.0
        # us apart: the hint named ms, which read them 10 s apart, probe BOSIN)
        unit, read = "us", "microseconds read as seconds"
    if spacing > MAX_FRAME_SPACING_US:
        raise FormatError(where, f"frames are {spacing * 1e-6:g} s apart (median): times in "
                          "another unit? (images.txt, timestamps files and events.txt hold "
                          f"seconds; {_unit_hint(unit, ecd_list)})")
    if spacing > max(UNIT_SLIP * (t_last - t_first), 1e6):
        raise FormatError(where, f"frames are {spacing * 1e-6:g} s apart but the events span "
                          f"{(t_last - t_first) * 1e-6:g} s: frame times in another unit? "
                          f"(images.txt and timestamps files hold seconds; "
                          f"{_unit_hint(unit, ecd_list)})")
    ev_span, fr_span = t_last - t_first, int(times[-1] - times[0])
    slip = ev_span > max(UNIT_SLIP * fr_span, 1e6)
    hint = " (event times in another unit? events.txt holds seconds)" if slip else ""
    frames_whole = bool(slip and ecd_list and time_unit is None and listed_whole)
    if frames_whole:
        # whole numbers in images.txt were read as µs (said in a warning): 1 fps in
        # whole seconds spans 6 us beside 6 s of events (probe)
        hint = (f" (frame times in another unit? {listed.name}'s whole numbers were read "
                "as microseconds; --time-unit s (or ms) reads them, and events.txt's whole "
                "numbers, in that unit)")
    if not slip and (ev_span > UNIT_SLIP * fr_span or fr_span > UNIT_SLIP * ev_span):
        # (only said beside a refusal: milliseconds read as µs, say, probe AM; frames in
        # ns beside events in µs, probe AT)
        hint = (f" (the frames span {fr_span} us, the events {ev_span} us, "
                f"{max(fr_span, ev_span) / max(min(fr_span, ev_span), 1):.4g}x: frame times "
                "in another unit? images.txt and timestamps files hold seconds)")
    ratio = ev_span / max(fr_span, 1)
    factor = next((f for f in (1e3, 1e6) if f / 2 <= ratio <= 2 * f), None)
    read_in = events.meta.get("time_unit", "s")
    # (whole-number frame times read as us have their own hint above)
    slipped = None if frames_whole else next(
        (u for u, f in TIME_UNIT_US.items() if factor and read_in in TIME_UNIT_US
         and np.isclose(f * factor, TIME_UNIT_US[read_in])), None)
    if slip and slipped and time_unit is None:
        # the events' times in ms (or µs) read as seconds: only the first thousandth of them
        # met the frames, and the run was refused as inverted polarity, or, flipped as
        # that said, solved to nothing with rc 0 (probe CC)
        hint = (f" (event times in {UNIT_WORDS[slipped]} read as {UNIT_WORDS[read_in]}? "
                f"the events span {ratio:.4g}x the frames' time; --time-unit {slipped} reads "
                f"them in {slipped})")
    if times[-1] <= t_first or times[0] >= t_last:
        raise ParameterError(f"frames ({where}) span [{times[0]}, {times[-1]}] us but the "
                             f"events ({rec}) [{t_first}, {t_last}] us: they do not overlap "
                             f"in time{hint}")
    if slip and slipped and time_unit is None and t0 is None and t1 is None:
        raise FormatError(rec, f"the events span {ev_span * 1e-6:g} s, the frames "
                          f"{fr_span * 1e-6:g} s, {ratio:.4g}x: event times in "
                          f"{UNIT_WORDS[slipped]} read as {UNIT_WORDS[read_in]}?",
                          f"--time-unit {slipped} reads the events' times in "
                          f"{slipped}; --t0/--t1 keep to the frames' span if the events do "
                          "run that much longer")
    if slip:
        warnings.warn(EvmotionWarning(
            f"{rec}: the events span {ev_span * 1e-6:g} s, the frames {fr_span * 1e-6:g} s"
            f"{hint}"), stacklevel=2)
    elif spacing > SLOW_FRAME_SPACING_US:
        if fr_span > UNIT_SLIP * ev_span and len(frame_intervals(times, t_first, t_last)) < 2:
            # the events within one frame interval of a unit slip: no BOS run at all, and
            # the registration check then blamed the cameras' alignment (probe BS)
            raise FormatError(where, f"frames are {spacing * 1e-6:g} s apart (median) and "
                              f"the events' {ev_span * 1e-6:g} s lie within one frame "
                              f"interval: frame times in {read}? {_unit_hint(unit, ecd_list)}")
        warnings.warn(EvmotionWarning(
            f"{where}: frames are {spacing * 1e-6:g} s apart (median), slower than a BOS "
            f"video runs: times in {read}? The flow would be 1000x too small; "
            f"{_unit_hint(unit, ecd_list)}"), stacklevel=2)
    elif spacing < FAST_FRAME_SPACING_US:
        warnings.warn(EvmotionWarning(
            f"{where}: frames are {spacing:g} us apart (median), faster than a camera beside "
            "an event sensor runs: times in seconds read in another unit (--time-unit)? "
            "The flow would be as many times too large"), stacklevel=2)
    intervals = frame_intervals(times, t_first, t_last, t0=t0, t1=t1,
                                max_intervals=max_intervals)
    cut = _cut(intervals, events.t, rec)
    if max_intervals is None:
        # the frames' intervals before the first event or after the last: still air, or
        # events recorded for part of the frames only; said, as the output leaves them out
        every = frame_intervals(times, int(times[0]), int(times[-1]), t0=t0, t1=t1)
        skipped = len(every) - len(intervals)
        if skipped > 0 and len(intervals):
            # events over a sliver of the frames (1e-6 to 2.5e-5 s of 0.025 s): their
            # seconds read as milliseconds, say (probe)
            unit = (" (the events' times in another unit? events.txt holds seconds; "
                    "--time-unit)" if ev_span * UNIT_SLIP < fr_span else "")
            warnings.warn(EvmotionWarning(
                f"{rec}: {skipped} of {len(every)} frame intervals hold no event (the events "
                f"span [{seconds_text(t_first)}, {seconds_text(t_last)}] s, the frames "
                f"[{seconds_text(times[0])}, {seconds_text(times[-1])}] s){unit}: not estimated, "
                "not in the output"), stacklevel=2)
    if not len(intervals):
        span = " within " + " / ".join(f"{name} {v} us" for name, v in (("--t0", t0),
                                                                        ("--t1", t1))
                                        if v is not None)
        selected = t0 is not None or t1 is not None
        raise ParameterError(f"no frame interval [t_i, t_i+1) overlaps the events' time span "
                             f"[{t_first}, {t_last}] us{span} (an interval must lie wholly "
                             "within --t0 / --t1 and overlap the events)" if selected else
                             f"no frame interval overlaps the events' time span "
                             f"[{t_first}, {t_last}] us")
    _warn_clipped(images, intervals, src, roi)
    return BosInput(events=events, frames=images, frame_times=times, intervals=intervals,
                    roi=roi, source=str(rec), frames_source=os.path.realpath(src), cut=cut)


UNIT_WORDS = {"s": "seconds", "ms": "milliseconds", "us": "microseconds",
              "ns": "nanoseconds"}


def _frames_and_events(rec: Path, fmt: str | None, src: Path, fr, time_unit: str | None,
                       roi) -> tuple[np.ndarray, np.ndarray, EventArray]:
    """The frames' images and times (µs) and the events on their grid, checked against
    each other (count, order, grid, registration, ``roi``)."""
    images = np.asarray(fr.images)
    times = np.asarray(fr.t, dtype=np.int64)
    if images.shape[0] < 2:
        raise FormatError(src, f"{images.shape[0]} frame(s): BOS needs at least two "
                          "(one frame interval)")
    if np.any(np.diff(times) <= 0):
        bad = int(np.argmax(np.diff(times) <= 0))
        raise FormatError(src, f"frame times are not increasing: frame {bad + 1} at "
                          f"{times[bad + 1]} us after {times[bad]} us")
    if fmt is None and rec.is_dir() and (rec / "images.txt").is_file() \
            and not (rec / "events.txt").is_file():
        raise FormatError(rec, "an ECD-style folder with frames (images.txt) but no "
                          "events.txt: BOS needs the events too")
    fh, fw = images.shape[1:3]
    unit = {"time_unit": time_unit} if time_unit is not None else {}
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        events = _events_on_frames(rec, fmt, (fh, fw), **unit)
    if not len(events):
        named = rec / "events.txt" if rec.is_dir() and (rec / "events.txt").is_file() else rec
        raise EmptyWindowError(f"{named}: no events")
    guessed_size = (fh, fw) != tuple(events.sensor_size) and str(
        events.meta.get("sensor_size_from", "")).startswith(GUESSED_SIZES)
    # the reader's guess of a size the frames then give is not worth a word
    _replay([w for w in said if not (guessed_size and "no sensor size" in str(w.message))])
    if guessed_size:
        # events that do not state their sensor (ECD text without frames beside it, say)
        # lie on the frames' grid
        events = _events_on_frames(rec, fmt, (fh, fw), sensor_size=(fh, fw), **unit)
    _refuse_finer_frames(src, events, images)
    _refuse_offset_view(src, events, images)
    if (fh, fw) != tuple(events.sensor_size):
        eh, ew = events.sensor_size
        raise ParameterError(f"frames {src} are {fw}x{fh} px but the events' sensor is "
                             f"{ew}x{eh} px (W x H): the frames must be on the event sensor's "
                             "pixel grid")
    if roi is not None:
        roi_mask(events.sensor_size, roi)
    return images, times, events


def _unit_hint(unit: str, ecd_list: bool) -> str:
    """How to read the frames' times in ``unit``: with the events' (an ``images.txt``
    beside them) or on their own."""
    own = f"--frames-time-unit {unit} (frames_time_unit= in Python) reads the frames' times"
    if ecd_list:
        return (f"--time-unit {unit} reads events.txt's and images.txt's times in {unit}, "
                f"{own} only")
    return f"{own} in {unit}"


def full_scale(images: np.ndarray) -> int:
    """The full scale of integer frames: 255 for 8 bits, else ``2^b - 1`` for the fewest
    bits ``b`` >= 8 that hold their largest sample (12-bit frames in 16-bit PNGs, as
    cameras write them, clip at 4095: taken as 65535, clipping went unsaid, probe BOSIN).

    Examples
    --------
    >>> full_scale(np.array([0, 4095], np.uint16)), full_scale(np.array([0, 200], np.uint8))
    (4095, 255)
    >>> full_scale(np.array([0, 65520], np.uint16))  # 12 bits shifted to the top
    65535
    """
    if images.dtype.kind not in "ui":
        return 255
    largest = int(images.max()) if images.size else 0
    return (1 << max(8, largest.bit_length())) - 1


def _warn_clipped(images: np.ndarray, intervals: np.ndarray, src, roi) -> None:
    """A warning where a frame the solver uses is mostly clipped at full scale: there it
    has no gradient, so the predicted increment is flat and the flow's magnitude is not a
    measurement (on a rendered scene: 1.06x the true magnitude at 64 % clipped, 1.53x at
    85 %)."""
    y0, x0, y1, x1 = (0, 0, *images.shape[1:3]) if roi is None else \
        (roi[1], roi[0], roi[1] + roi[3], roi[0] + roi[2])
    used = [images[i, y0:y1, x0:x1] for i in intervals[:, 0]]  # (views)
    top = full_scale(np.array([frame.max() for frame in used], images.dtype))
    full = top - (top >> 8)  # 255 of 8 bits, 4080 of 12, 65280 of 16
    share = np.array([np.mean(frame >= full) for frame in used])
    bad = share > MAX_CLIPPED
    if bad.any():
        i = int(np.argmax(share))
        warnings.warn(EvmotionWarning(
            f"{src}: {int(bad.sum())} of the {len(share)} frames used are more than "
            f"{100 * MAX_CLIPPED:.0f} % clipped at full scale (frame {int(intervals[i, 0])}: "
            f"{100 * share[i]:.0f} %): no texture there, and the flow's magnitude is not a "
            "measurement; lower the exposure or gain"), stacklevel=3)
