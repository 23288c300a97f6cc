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
  order, or ``t path`` lines), or a video file with a timestamps file.
"""

from __future__ import annotations

import contextlib
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evmotion.catalog import NS_EPOCH_US
from evmotion.errors import (
    EvmotionError,
    EvmotionWarning,
    FormatError,
    MissingDependencyError,
    ParameterError,
)
from evmotion.io.base import TIME_UNIT_US
from evmotion.io.guard import time_to_us
from evmotion.io.pngfile import check_png, png_header, read_png
from evmotion.utils import is_file

__all__ = ["Frames", "describe_frames", "find_frames", "folder_members", "frame_paths",
           "image_size", "read_frames", "read_image", "whole_number_times"]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm", ".webp")
TIMESTAMP_FILES = ("timestamps.txt", "times.txt", "frame_timestamps.txt",
                   "image_timestamps.txt", "timestamps.csv")
TIME_UNITS = TIME_UNIT_US
VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov")
CCS_SENSOR_SIZE = (720, 1280)  # Prophesee Gen4 of the published BOS recordings


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
        bits = 8 if images.dtype == np.uint8 else 16
        if not (isinstance(self.bit_depth, (int, np.integer)) and 1 <= self.bit_depth <= bits):
            raise FormatError(src, f"bit_depth must be an integer in 1..{bits} for "
                              f"{images.dtype} frames, got {self.bit_depth!r}")
        t = np.asarray(self.t).reshape(-1)
        if t.dtype.kind not in "iu":
            # whole microseconds: a float list (or NaN) is checked, not wrapped by a cast
            try:
                t = t.astype(np.float64)
            except (TypeError, ValueError):
                raise FormatError(src, "frame timestamps must be numbers (us)") from None
            if not np.isfinite(t).all():
                raise FormatError(src, "frame timestamps must be finite numbers (us)")
        t = t.astype(np.int64)
        if t.shape[0] != images.shape[0]:
            raise FormatError(src, f"{images.shape[0]} images but {t.shape[0]} timestamps")
        _check_times(t, src)
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


# ---------------------------------------------------------------------------------------
# single images


def _read_png(path: Path) -> tuple[np.ndarray, int]:
    img, info = read_png(path)
    depth = int(info.get("bitdepth", 8))
    planes = img.shape[2]
    if info.get("alpha"):
        planes -= 1
    grey = img[..., 0] if planes == 1 else np.rint(img[..., :3].mean(axis=2))
    return grey.astype(np.uint16 if depth > 8 else np.uint8), 16 if depth > 8 else 8


@contextlib.contextmanager
def _opencv_quiet(cv2):
    """OpenCV's own log lines ("[ERROR:0@0.015] global grfmt_png.cpp ...") silenced while
    it decodes: a damaged file is said in our one line."""
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is None:
        yield
        return
    before = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        log.setLogLevel(before)


def read_image(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """A grey image (colour is averaged over its channels) and its bit depth (8 or 16), read
    with OpenCV (the ``bos`` extra); PNG with pypng when OpenCV is not installed.

    Examples
    --------
    >>> from evmotion.io.pngfile import write_png
    >>> write_png("images/frame_00000000.png", np.full((6, 8), 1000, np.uint16))
    >>> img, bits = read_image("images/frame_00000000.png")
    >>> img.shape, int(img[0, 0]), bits
    ((6, 8), 1000, 16)
    """
    return _read_frame(Path(path), None)


def _read_frame(path: Path, like: tuple[Path, tuple] | None) -> tuple[np.ndarray, int]:
    """:func:`read_image`; with ``like`` (a frame's path and shape), a PNG of another size
    is refused from its header, before it is decoded."""
    path = Path(path)
    if not path.is_file():
        raise FormatError(path, "frame file not found")
    if path.suffix.lower() == ".png":
        # a damaged PNG is named here: libpng and OpenCV inside cv2.imread print their own
        # lines on stderr before ours, pypng and OpenCV allocate what a corrupt header
        # declares (probes AM, AO)
        size = check_png(path)
        if like is not None and size != like[1][:2]:
            # said before it is decoded (probe AO: a 20000 x 20000 frame among 128 x 96
            # ones took 0.9 GB and 7 s to be refused)
            raise FormatError(path, f"image is {size[1]}x{size[0]} px (WxH) but "
                              f"{like[0].name} is {like[1][1]}x{like[1][0]}")
    try:
        import cv2
    except ImportError:
        if path.suffix.lower() == ".png":
            return _read_png(path)
        raise MissingDependencyError("opencv-python-headless", f"reading {path.suffix} frames",
                                     "bos") from None
    # OpenCV decodes a PNG 5-30 times faster than pypng (a 1280x720 frame: 16 ms against
    # 0.37 s), which reads them when it is not installed
    try:
        with _opencv_quiet(cv2):
            img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise FormatError(path, "cannot read image: " + " ".join(str(exc).split())[-200:]
                          ) from None
    if img is None:
        if path.suffix.lower() == ".png":
            return _read_png(path)  # its message says what is wrong with the file
        raise FormatError(path, "cannot read image (corrupt or unsupported)")
    if img.ndim == 3:
        img = img[..., 0] if img.shape[2] < 3 else \
            np.rint(img[..., :3].mean(axis=2)).astype(img.dtype)
    if img.dtype not in (np.uint8, np.uint16):
        raise FormatError(path, f"frames must be 8- or 16-bit, got {img.dtype}")
    return img, 16 if img.dtype == np.uint16 else 8


# the JPEG standard's luminance quantization table (Annex K), which IJG libjpeg scales by
# quality: 50 as is, 100 all ones
_JPEG_LUMA = (16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16,
              24, 40, 57, 69, 56, 14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109,
              103, 77, 24, 35, 55, 64, 81, 104, 113, 92, 49, 64, 78, 87, 103, 121, 120, 101,
              72, 92, 95, 98, 112, 100, 103, 99)
# below this JPEG quality the frames' block artefacts are said (an independent renderer's
# BOS magnitudes: 1.09-1.14x at 40, 1.00-1.02x at 60, 75 and 90; probe BC)
JPEG_QUALITY_WARN = 50


def jpeg_quality(path: str | os.PathLike) -> int | None:
    """The IJG quality (1-100) a JPEG file's luminance quantization table was scaled to,
    or None for a file that is not a baseline JPEG with one.

    Examples
    --------
    >>> import cv2
    >>> _ = cv2.imwrite("q40.jpg", np.zeros((8, 8), np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 40])
    >>> jpeg_quality("q40.jpg")
    40
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read(1 << 16)
    except OSError:
        return None
    if data[:2] != b"\xff\xd8":
        return None
    i = 2
    while i + 4 <= len(data) and data[i] == 0xFF:
        marker, size = data[i + 1], int.from_bytes(data[i + 2:i + 4], "big")
        if marker == 0xDA:  # the image data: no table before it
            return None
        if marker == 0xDB:
            seg, j = data[i + 4:i + 2 + size], 0
            while j < len(seg):
                wide, table = seg[j] >> 4, seg[j] & 0x0F
                n = 128 if wide else 64
                if table == 0 and j + 1 + n <= len(seg):
                    vals = np.frombuffer(seg[j + 1:j + 1 + n], ">u2" if wide else "u1")
                    scale = 100.0 * vals.sum() / sum(_JPEG_LUMA)
                    q = (200.0 - scale) / 2.0 if scale <= 100 else 5000.0 / scale
                    return int(np.clip(round(q), 1, 100))
                j += 1 + n
        i += 2 + size
    return None


def _warn_lossy(files: list[Path]) -> None:
    """Say when the frames are JPEGs of a quality under :data:`JPEG_QUALITY_WARN`."""
    if not files or files[0].suffix.lower() not in (".jpg", ".jpeg"):
        return
    q = jpeg_quality(files[0])
    if q is not None and q < JPEG_QUALITY_WARN:
        warnings.warn(EvmotionWarning(
            f"{files[0]}: the frames are JPEGs of quality {q}: their 8x8 block artefacts "
            "change from frame to frame as the image does (BOS magnitudes came out "
            "1.09-1.14x at quality 40, 1.00-1.02x at 60-90); lossless frames (PNG) avoid "
            "it"), stacklevel=4)


def _stack(files: list[Path]) -> tuple[np.ndarray, int]:
    _warn_lossy(files)
    images, depth, first = [], None, None
    for f in files:
        img, bits = _read_frame(f, first)
        if first is None:
            first, depth = (f, img.shape), bits
        elif img.shape != first[1]:
            raise FormatError(f, f"image is {img.shape[1]}x{img.shape[0]} px (WxH) but "
                              f"{first[0].name} is {first[1][1]}x{first[1][0]}")
        elif bits != depth:
            raise FormatError(f, f"image is {bits}-bit but {first[0].name} is {depth}-bit")
        images.append(img)
    if not images:
        return np.zeros((0, 0, 0), np.uint8), 8
    return np.stack(images), int(depth)


def _check_times(t: np.ndarray, path: Path | str | None, files: list[Path] | None = None
                 ) -> None:
    """Refuse frame times that do not increase, naming the two frames: their files where
    ``files`` lists them, else their places in the list, from 1 (entries from 0, which an
    ``images.txt`` with comment lines put two lines off; probe BS)."""
    d = np.diff(t)
    if d.size and d.min() <= 0:
        i = int(np.argmax(d <= 0))
        what = "duplicate" if d[i] == 0 else "unsorted"
        which = (f"{files[i].name} and {files[i + 1].name}" if files is not None
                 else f"frames {i + 1} and {i + 2} of the list")
        raise FormatError(path, f"{what} frame timestamps: {which} at {t[i]} us, "
                          f"{t[i + 1]} us")


# ---------------------------------------------------------------------------------------
# layouts


def _in_time_order(t: np.ndarray, files: list[Path], src: Path
                   ) -> tuple[np.ndarray, list[Path]]:
    """``t path`` lines out of time order, sorted by their times: each line carries its
    own (probe BC: refused, with no fix named). Equal times stay for
    :func:`_check_times` to refuse."""
    d = np.diff(t)
    if not d.size or d.min() > 0 or np.unique(t).size < t.size:
        return t, files
    i = int(np.argmax(d < 0))
    warnings.warn(EvmotionWarning(
        f"{src}: its lines list the frames out of time order (lines {i + 1} and {i + 2} of "
        f"the frames: {t[i]} us, {t[i + 1]} us): read in time order"), stacklevel=4)
    order = np.argsort(t, kind="stable")
    return t[order], [files[k] for k in order]


def _ecd_list(folder: Path, time_unit: str | None = None
              ) -> tuple[np.ndarray, list[Path], Path]:
    from evmotion.io.ecd import read_image_list

    lst_path = folder / "images.txt"
    try:
        lst = read_image_list(lst_path, time_unit)
    except FormatError:
        raise
    except ValueError as exc:
        raise FormatError(lst_path, f"cannot parse 't path' lines: {exc}") from None
    return (*_in_time_order(lst["t"], _listed_files(lst_path, folder, lst["files"]),
                            lst_path), lst_path)


def _parse_timestamps(path: Path, unit: str | None) -> tuple[np.ndarray, list[str] | None]:
    """Times (µs) of a timestamps file, and the image names when its lines are ``t path``.
    ``unit`` None: seconds where a time has a decimal point or exponent, else whole
    numbers, read as µs (ns past 1e17) with a warning, as events text."""
    if unit is not None and unit not in TIME_UNITS:
        raise ParameterError(f"time_unit must be one of {sorted(TIME_UNITS)}, got {unit!r}")
    rows = _timestamp_rows(path)
    if unit is None:
        unit = _sniffed_unit(path, [parts[0] for _, parts in rows])
    times, names = [], []
    for i, parts in rows:
        times.append(time_to_us(path, parts[0], TIME_UNITS[unit], f"line {i}"))
        names.append(parts[1] if len(parts) == 2 else None)
    if any(n is None for n in names) and not all(n is None for n in names):
        raise FormatError(path, "mixes 't' and 't path' lines")
    return np.asarray(times, dtype=np.int64), (names if names and names[0] is not None else None)


def whole_number_times(path: str | os.PathLike) -> bool:
    """Whether every time of a timestamps file is a whole number (which states no unit).

    Examples
    --------
    >>> _ = Path("stamps.txt").write_text("0\\n8333\\n16667\\n")
    >>> whole_number_times("stamps.txt")
    True
    """
    firsts = [parts[0] for _, parts in _timestamp_rows(Path(path))]
    return bool(firsts) and all(f.lstrip("+-").isdigit() for f in firsts)


def _timestamp_rows(path: Path) -> list[tuple[int, list[str]]]:
    """The ``(line number, fields)`` of a timestamps file's ``t`` or ``t path`` lines."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise FormatError(path, f"cannot read timestamps: {exc}") from None
    lines = [(i, line.replace(",", " ").split()) for i, line in enumerate(text.splitlines(), 1)]
    lines = [(i, parts) for i, parts in lines if parts and not parts[0].startswith("#")]
    if len(lines) > 1 and _HEADER.fullmatch(lines[0][1][0]) and \
            _NUMBER.fullmatch(lines[1][1][0]):
        lines = lines[1:]  # a header line ("timestamp, filename")
    rows = []
    for i, parts in lines:
        if len(parts) > 2:
            raise FormatError(path, f"line {i}: expected 't' or 't path', got "
                              f"{' '.join(parts)!r}")
        rows.append((i, parts))
    return rows


def natural_key(path: Path) -> list:
    """Sort key of a file name with its digit runs as numbers: ``frame_2`` before
    ``frame_10`` (plain text order puts ``frame_10`` first, unpadded names scrambled).

    Examples
    --------
    >>> [p.name for p in sorted(map(Path, ["f_10.png", "f_2.png", "f_1.png"]), key=natural_key)]
    ['f_1.png', 'f_2.png', 'f_10.png']
    """
    return [(0, int(tok), "") if tok.isdigit() else (1, 0, tok)
            for tok in re.split(r"(\d+)", path.name) if tok]


_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")
# a column name: letters, not a number's spelling (nan, inf: a bad time, said as such)
_HEADER = re.compile(r"(?!(?i:[-+]?(nan|inf|infinity))$)[A-Za-z_][\w\[\]()./ -]*")


def _sniffed_unit(path: Path, firsts: list[str]) -> str:
    """The unit of a timestamps file's times, as :func:`evmotion.io.ecd.sniff_time_unit`
    tells an events file's: decimals are seconds; whole numbers are µs (ns past 1e17),
    said in a warning."""
    if not firsts or not all(f.lstrip("+-").isdigit() for f in firsts):
        return "s"  # decimals (or a bad field, which time_to_us names)
    unit = "ns" if int(firsts[0]) > NS_EPOCH_US else "us"
    warnings.warn(EvmotionWarning(
        f"{path}: every frame time is a whole number: read as "
        f"{'nanoseconds since the epoch' if unit == 'ns' else 'microseconds'} (decimal "
        "times are seconds; other units: evmotion bos --frames-time-unit, time_unit= in "
        "Python)"), stacklevel=4)
    return unit


#: The files of an ECD-style folder besides its frames (and the schlieren simulator's
#: ground truth): what a command reading the folder must not write over.
FOLDER_MEMBERS = ("events.txt", "images.txt", "calib.txt", "imu.txt", "groundtruth.txt",
                  "schlieren_gt.h5", *TIMESTAMP_FILES)


def folder_members(folder: str | os.PathLike) -> set[Path]:
    """The files a recording or frames folder is made of: its events, frame list,
    calibration, IMU, ground truth and timestamps files, and the frames they list (or the
    images beside a timestamps file). An output written over one of them destroyed the
    recording (``kymogram scene/ --out scene/images/frame_00000000.png``, probe BP).

    Examples
    --------
    >>> import os
    >>> os.makedirs("rec/images", exist_ok=True)
    >>> _ = open("rec/events.txt", "w").write("0.1 1 2 1\\n")
    >>> _ = open("rec/images.txt", "w").write("0.0 images/f0.png\\n")
    >>> open("rec/images/f0.png", "wb").close()
    >>> sorted(p.relative_to("rec").as_posix() for p in folder_members("rec"))
    ['events.txt', 'images.txt', 'images/f0.png']
    """
    from evmotion.io.ecd import read_image_list

    folder = Path(folder)
    if not folder.is_dir():
        return set()
    out = {folder / name for name in FOLDER_MEMBERS if (folder / name).is_file()}
    if (folder / "images.txt").is_file():
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                out.update(frame_paths(folder, read_image_list(folder)["files"]))
        except (EvmotionError, OSError, UnicodeDecodeError):
            pass  # a list that cannot be read lists nothing to spare
    elif any(folder / name in out for name in TIMESTAMP_FILES):
        out.update(_images_in(folder))
    return out


def _images_in(folder: Path) -> list[Path]:
    files = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
                    and p.is_file()), key=natural_key)
    if not files and (folder / "images").is_dir():
        files = _images_in(folder / "images")
    return files


def _folder_list(folder: Path, timestamps: Path, unit: str
                 ) -> tuple[np.ndarray, list[Path], Path]:
    t, names = _parse_timestamps(timestamps, unit)
    if names is not None:
        return (*_in_time_order(t, _listed_files(timestamps, timestamps.parent, names),
                                timestamps), timestamps)
    files = _images_in(folder)
    if len(files) != t.size:
        raise FormatError(timestamps, f"{t.size} timestamps but {len(files)} images in "
                          f"{files[0].parent if files else folder}")
    return t, files, timestamps


def _ccs_triggers(path: Path) -> np.ndarray:
    """Frame times (µs) from a Metavision trigger log: rising edges of ``t id p`` rows
    (whitespace) or ``p,id,t`` rows (comma-separated, newer Metavision)."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise FormatError(path, f"cannot read trigger events: {exc}") from None
    comma = "," in text
    rows = []
    for i, line in enumerate(text.splitlines(), 1):
        parts = line.split(",") if comma else line.split()
        if not parts or not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            vals = [int(float(v)) for v in parts]
        except ValueError:
            raise FormatError(path, f"line {i}: not integers: {line.strip()!r}") from None
        if len(vals) != 3:
            raise FormatError(path, f"line {i}: expected 3 columns, got {len(vals)}")
        rows.append(vals)
    arr = np.asarray(rows, dtype=np.int64).reshape(-1, 3)
    if comma:
        return arr[arr[:, 0] == 1, 2]
    return arr[arr[:, 2] == 1, 0]


def _video_timestamps(video: Path, timestamps) -> Path:
    """The timestamps file of a video: given, or ``<stem>.txt``, ``<stem>_timestamps.txt``
    or ``timestamps.txt`` beside it."""
    if timestamps is not None:
        ts = Path(timestamps)
        if not ts.is_file():
            raise FormatError(ts, "timestamps file not found")
        return ts
    for name in (f"{video.stem}.txt", f"{video.stem}_timestamps.txt", "timestamps.txt"):
        if (video.parent / name).is_file():
            return video.parent / name
    raise FormatError(video, f"video frames need timestamps: give a timestamps file or put "
                      f"{video.stem}.txt (one time per frame) beside it")


def _is_ccs(folder: Path) -> bool:
    return (folder / "basler_0").is_dir() and \
        (folder / "prophesee_0" / "trigger_events.txt").is_file()


def _read_video(path: Path) -> np.ndarray:
    try:
        import cv2
    except ImportError:
        raise MissingDependencyError("opencv-python-headless", "reading frames.mp4",
                                     "bos") from None
    cap = cv2.VideoCapture(str(path))
    images = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        images.append(img if img.ndim == 2 else np.rint(img.mean(axis=2)).astype(np.uint8))
    cap.release()
    if not images:
        raise FormatError(path, "no frames could be decoded from the video")
    return np.stack(images)


def _read_ccs(folder: Path, sensor_size, warp: bool) -> Frames:
    trig = folder / "prophesee_0" / "trigger_events.txt"
    t = _ccs_triggers(trig)
    frame_dir = folder / "basler_0" / "frames"
    video = folder / "basler_0" / "frames.mp4"
    if frame_dir.is_dir() and _images_in(frame_dir):
        files = _images_in(frame_dir)
        if len(files) != t.size:
            raise FormatError(trig, f"{t.size} rising trigger edges but {len(files)} images "
                              f"in {frame_dir}")
        images, depth = _stack(files)
    elif video.is_file():
        images, depth = _read_video(video), 8
        if images.shape[0] != t.size:
            raise FormatError(trig, f"{t.size} rising trigger edges but {images.shape[0]} "
                              f"frames in {video}")
    else:
        raise FormatError(folder / "basler_0", "no frames: neither frames/ with images nor "
                          "frames.mp4")
    _check_times(t, trig)
    hom = folder / "homography.txt"
    if warp and hom.is_file():
        try:
            import cv2
        except ImportError:
            raise MissingDependencyError("opencv-python-headless",
                                         "mapping frames onto the event sensor", "bos") from None
        try:
            H = np.loadtxt(hom, dtype=np.float64).reshape(3, 3)
        except ValueError as exc:
            raise FormatError(hom, f"expected a 3x3 matrix: {exc}") from None
        h, w = sensor_size if sensor_size is not None else CCS_SENSOR_SIZE
        images = np.stack([cv2.warpPerspective(im, H, (int(w), int(h))) for im in images])
    return Frames(images, t, source=str(folder), bit_depth=depth)


def _from_module(path: Path) -> Frames:
    """Frames of an event recording that holds them (AEDAT4, evmotion/MVSEC HDF5...)."""
    if path.suffix.lower() == ".aedat4":
        from evmotion.io import aedat4

        fr = aedat4.read_frames(path)
        if fr.images.ndim == 4:  # BGR(A) frames: grey by the mean of the colour channels
            grey = np.rint(fr.images[..., :3].mean(axis=3)).astype(np.uint8)
            return Frames(grey, fr.t, source=fr.source, exposure_start=fr.exposure_start,
                          exposure_end=fr.exposure_end, position=fr.position)
        return fr
    from evmotion.io.aux import read_frames as read_aux

    fr = read_aux(path)
    if isinstance(fr.images, np.ndarray):
        images = fr.images
    elif len(fr.images):
        shapes = {im.shape for im in fr.images}
        if len(shapes) > 1:
            raise FormatError(path, f"frames of different sizes {sorted(shapes)}")
        images = np.stack(fr.images)
    else:
        images = np.zeros((0, 0, 0), np.uint8)
    if images.ndim == 4:
        images = np.rint(images[..., :3].mean(axis=3)).astype(images.dtype)
    depth = 16 if images.dtype == np.uint16 else 8
    return Frames(images, fr.t, source=str(path), bit_depth=depth)


def frame_paths(folder: str | os.PathLike, names: list[str]) -> list[Path]:
    """The paths of the frame files a list in ``folder`` names (``images.txt``, a ``t
    path`` timestamps file): relative to ``folder``, or bare names of files kept in its
    ``images/`` (the ECD layout's folder, left out of the list by other tools; they were
    refused as missing, probe BN).

    Examples
    --------
    >>> import os
    >>> os.makedirs("scene/images", exist_ok=True)
    >>> open("scene/images/f0.png", "wb").close()
    >>> [p.as_posix() for p in frame_paths("scene", ["f0.png"])]
    ['scene/images/f0.png']
    """
    folder = Path(folder)
    # each name on its own (decided by the first, a stray copy of one frame beside the list
    # made the others missing; probe BR)
    return [folder / name if is_file(folder / name) or not is_file(folder / "images" / name)
            else folder / "images" / name for name in names]


def _listed_files(listing: Path, folder: Path, names: list[str]) -> list[Path]:
    """The frame files a list (``images.txt``, a ``t path`` timestamps file) names, each
    checked to be there (:func:`frame_paths`)."""
    files = frame_paths(folder, names)
    for f in files:
        if not is_file(f):
            raise FormatError(listing, f"lists a missing frame file {_shown(f.name)} "
                              f"({_shown(str(f))})")
    return files


def _shown(name: str, most: int = 120) -> str:
    """``name`` quoted, its middle left out past ``most`` characters."""
    return repr(name) if len(name) <= most else repr(f"{name[:60]}...{name[-40:]}")


def _is_timestamps_file(path: Path) -> bool:
    return path.is_file() and path.name.lower() in TIMESTAMP_FILES


def find_frames(path: str | os.PathLike, timestamps: str | os.PathLike | None = None) -> str:
    """Which frame layout :func:`read_frames` sees at ``path``: ``ecd``, ``ccs`` (the
    published BOS data), ``folder`` (images + timestamps file), ``video`` (a video
    file + timestamps file) or ``recording`` (an event
    file that holds frames, e.g. AEDAT4). Raises :class:`FormatError` if none."""
    path = Path(path)
    if not path.exists():
        raise FormatError(path, "no such file or folder")
    if timestamps is None and _is_timestamps_file(path):
        return "folder"  # of the images beside it
    if path.is_file():
        if path.name == "images.txt":
            return "ecd"
        if path.suffix.lower() in VIDEO_SUFFIXES:
            return "video"
        return "recording"
    if (path / "images.txt").is_file():
        return "ecd"
    # events.txt beside images and a timestamps file is that layout, not an ECD folder
    # without frames (probe BC: "no images.txt", and --frames said the same)
    stamped = timestamps is not None or any((path / n).is_file() for n in TIMESTAMP_FILES)
    if (path / "events.txt").is_file() and not stamped:
        return "none"  # an ECD folder without images.txt
    if _is_ccs(path):
        return "ccs"
    if stamped:
        return "folder"
    if _images_in(path):
        raise FormatError(path, "images without timestamps: add images.txt ('t path' lines) "
                          f"or one of {', '.join(TIMESTAMP_FILES)}")
    return "recording"


def read_frames(path: str | os.PathLike, *, timestamps: str | os.PathLike | None = None,
                time_unit: str | None = None, sensor_size: tuple[int, int] | None = None,
                warp: bool = True) -> Frames:
    """Frames co-captured with events, from any supported layout.

    Parameters
    ----------
    path : path-like
        * an ECD-style folder (or its ``images.txt``): ``t path`` lines, t in seconds,
          8- or 16-bit PNGs (16-bit stay uint16);
        * the published event-based BOS layout (``tub-rip/event_based_bos``): a sequence
          folder with ``basler_0/frames/*`` images (or ``basler_0/frames.mp4``),
          ``prophesee_0/trigger_events.txt`` (Metavision external-trigger log: a frame
          per rising edge, times in µs of the event camera's clock) and optionally
          ``homography.txt`` (3x3, frame pixels -> event pixels);
        * a folder of images (sorted by name; or in its ``images/`` sub-folder) with a
          timestamps file (``timestamps``, or one of ``timestamps.txt``, ``times.txt``,
          ``frame_timestamps.txt``, ``image_timestamps.txt``, ``timestamps.csv``
          inside): one time per line in name order, or ``t path`` lines;
        * a video file (.mp4, .avi, .mkv, .mov; decoded with OpenCV, grey) with a
          timestamps file (``timestamps``, or ``<stem>.txt``, ``<stem>_timestamps.txt``,
          ``timestamps.txt`` beside it), one time per frame;
        * an event recording holding frames (AEDAT4 DAVIS APS frames, evmotion or MVSEC
          HDF5...).
    timestamps : path-like, optional
        Timestamps file of an image folder or a video.
    time_unit : str, optional
        Unit of the times in a timestamps file: ``s``, ``ms``, ``us``, ``ns``; default
        seconds where a time has a decimal point, else whole numbers read as µs (ns past
        1e17) with a warning. In an ECD ``images.txt`` it is the unit of whole-number
        times only (its decimal times are seconds).
    sensor_size : (int, int), optional
        ``(height, width)`` of the event sensor the BOS frames are mapped onto
        (default 720x1280).
    warp : bool
        Map BOS-layout frames onto the event sensor with ``homography.txt`` if present.

    Returns
    -------
    Frames

    Examples
    --------
    >>> from evmotion.io.pngfile import write_png
    >>> for i in range(3):  # an ECD-style folder: PNGs and images.txt (t [s] and path)
    ...     write_png(f"plume_sim/images/frame_{i:08d}.png", np.full((6, 8), i, np.uint8))
    >>> _ = Path("plume_sim/images.txt").write_text(
    ...     "".join(f"{i / 100:.6f} images/frame_{i:08d}.png\\n" for i in range(3)))
    >>> fr = read_frames("plume_sim/")
    >>> fr.images.shape, fr.bit_depth, round(fr.fps), fr.t.tolist()
    ((3, 6, 8), 8, 100, [0, 10000, 20000])
    """
    path = Path(path)
    if timestamps is None and _is_timestamps_file(path):
        # the timestamps file named for its folder (probe AM: "format not recognised")
        path, timestamps = path.parent, path
    kind = find_frames(path, timestamps)
    if kind == "ecd":
        folder = path if path.is_dir() else path.parent
        t, files, src = _ecd_list(folder, time_unit)
    elif kind == "ccs":
        return _read_ccs(path, sensor_size, warp)
    elif kind == "none":
        raise FormatError(path, "holds no frames (no images.txt)")
    elif kind == "video":
        ts = _video_timestamps(path, timestamps)
        t, _ = _parse_timestamps(ts, time_unit)
        images = _read_video(path)
        if images.shape[0] != t.size:
            raise FormatError(ts, f"{t.size} timestamps but {images.shape[0]} frames in "
                              f"{path.name}")
        _check_times(t, ts)
        return Frames(images, t, source=str(path), bit_depth=8)
    elif kind == "folder":
        ts = Path(timestamps) if timestamps is not None else next(
            path / n for n in TIMESTAMP_FILES if (path / n).is_file())
        if not ts.is_file():
            raise FormatError(ts, "timestamps file not found")
        t, files, src = _folder_list(path, ts, time_unit)
    else:
        return _from_module(path)
    _check_times(t, src, files)
    images, depth = _stack(files)
    if not files:
        raise FormatError(src, "lists no frames")
    return Frames(images, t, source=str(path), bit_depth=depth)


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(height, width)`` of an image file: from a PNG's header, other formats decoded
    (OpenCV).

    Examples
    --------
    >>> from evmotion.io.pngfile import write_png
    >>> write_png("images/frame_00000000.png", np.zeros((72, 64), np.uint8))
    >>> image_size("images/frame_00000000.png")
    (72, 64)
    """
    return _header(Path(path))[0]


def _header(path: Path) -> tuple[tuple[int, int], int]:
    """``(height, width)`` and bit depth of an image from its header (PNG) or pixels."""
    if path.suffix.lower() == ".png":
        size, depth = png_header(path)
        return size, 16 if depth > 8 else 8
    img, bits = read_image(path)
    return img.shape[:2], bits


# what a whole PNG (its IEND chunk) and a whole JPEG (EOI) end with
_FILE_ENDS = {"PNG": b"\x00\x00\x00\x00IEND\xaeB`\x82", "JPEG": b"\xff\xd9"}
_SUFFIX_KINDS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}


def _check_ends(files: list[Path]) -> None:
    """Refuse a PNG or JPEG frame cut short: the last bytes of each, not the image (a
    summary decodes none; it had called a folder with a truncated frame fine, which the
    BOS run then refused, probe BS)."""
    for f in files:
        with open(f, "rb") as fh:
            # by the content, as the frames are decoded: PNGs named .jpg are read (probe)
            head = fh.read(4)
            kind = ("PNG" if head == b"\x89PNG" else "JPEG" if head[:3] == b"\xff\xd8\xff"
                    else _SUFFIX_KINDS.get(f.suffix.lower()))
            end = _FILE_ENDS.get(kind)
            if end is None:
                continue
            fh.seek(0, os.SEEK_END)
            n = fh.tell()
            fh.seek(max(n - len(end), 0))
            if fh.read() != end:
                raise FormatError(f, f"truncated {kind} ({n} bytes): it does not end as a "
                                  "whole one does")


def describe_frames(path: str | os.PathLike, *, timestamps: str | os.PathLike | None = None,
                    time_unit: str | None = None, sensor_size: tuple[int, int] | None = None
                    ) -> dict | None:
    """Summary of the frames at ``path`` without decoding them all: ``count``, ``size``
    (``WxH``), ``bit_depth``, ``t_first_us``, ``t_last_us``, ``span_s``, ``fps``; None when
    ``path`` holds no frames (AEDAT4 frames are decoded; other event files are not looked
    into: None).

    Examples
    --------
    >>> from evmotion.io.pngfile import write_png
    >>> for i in range(3):  # a folder of images and a timestamps file (s, one per line)
    ...     write_png(f"shots/{i:04d}.png", np.full((6, 8), i, np.uint8))
    >>> _ = Path("shots/timestamps.txt").write_text("0.0\\n0.01\\n0.02\\n")
    >>> d = describe_frames("shots/")
    >>> d["count"], d["size"], d["fps"]
    (3, '8x6', 100.0)
    """
    path = Path(path)
    kind = find_frames(path, timestamps)
    if kind == "none":
        return None
    if kind in ("recording", "video"):
        if kind == "recording" and path.suffix.lower() != ".aedat4":
            return None
        fr = read_frames(path, timestamps=timestamps, time_unit=time_unit)
        if not len(fr):
            return None
        t, size, depth = fr.t, fr.sensor_size, fr.bit_depth
    elif kind == "ccs":
        t = _ccs_triggers(path / "prophesee_0" / "trigger_events.txt")
        files = _images_in(path / "basler_0" / "frames") \
            if (path / "basler_0" / "frames").is_dir() else []
        if not files:
            fr = _read_ccs(path, sensor_size, True)
            t, size, depth = fr.t, fr.sensor_size, fr.bit_depth
        else:
            if len(files) != t.size:
                raise FormatError(path / "prophesee_0" / "trigger_events.txt",
                                  f"{t.size} rising trigger edges but {len(files)} images")
            size, depth = _header(files[0])
            if (path / "homography.txt").is_file():
                size = sensor_size if sensor_size is not None else CCS_SENSOR_SIZE
    else:
        if kind == "ecd":
            t, files, src = _ecd_list(path if path.is_dir() else path.parent)
        else:
            ts = Path(timestamps) if timestamps is not None else next(
                path / n for n in TIMESTAMP_FILES if (path / n).is_file())
            t, files, src = _folder_list(path, ts, time_unit)
        _check_times(t, src, files)
        if not files:
            return None
        size, depth = _header(files[0])
        _check_ends(files)
    out = {"count": int(len(t)), "size": f"{size[1]}x{size[0]}", "bit_depth": int(depth),
           "t_first_us": int(t[0]), "t_last_us": int(t[-1]),
           "span_s": (int(t[-1]) - int(t[0])) * 1e-6}
    if len(t) > 1:
        out["fps"] = round((len(t) - 1) * 1e6 / float(t[-1] - t[0]), 3)
    return out
