"""Small shared helpers: atomic output files, progress bars, argument checks."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import sys
import tempfile
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TypeVar

import numpy as np

from evmotion.errors import ParameterError

T = TypeVar("T")


def is_file(path: str | os.PathLike) -> bool:
    """``Path.is_file`` that answers False, not an OSError, for a name the system refuses
    (ENAMETOOLONG: a 300-character name in images.txt was a traceback, probe AO).

    Examples
    --------
    >>> is_file("a" * 5000), is_file(".")
    (False, False)
    """
    try:
        return Path(path).is_file()
    except OSError:
        return False


def ensure_file_target(path: str | os.PathLike) -> None:
    """ParameterError when ``path`` exists and is not a regular file: an output written
    beside it and renamed onto it would replace a device or pipe (``/dev/null``) with a
    regular file, or fail on a folder at the end of the work.

    >>> ensure_file_target("new_result.h5")
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        from evmotion.errors import ParameterError

        kind = "a folder" if path.is_dir() else "not a regular file (a device or pipe)"
        raise ParameterError(f"cannot write {path}: it is {kind}; give a file path")


def temp_prefix(path: Path) -> str:
    """Name prefix of the hidden temporaries a writer of ``path`` makes beside it:
    ``.NAME.HOST-PID.``, so that a later run can tell a killed run's (SIGKILL leaves them:
    124 MB and 408 MB in probe AJ) from a running one's (:func:`remove_stale_temps`)."""
    return f"{_temp_stem(path)}{os.getpid()}."


def _temp_stem(path: Path) -> str:
    """``.NAME.HOST-``: how this host's temporaries for ``path`` begin."""
    import socket

    return f".{path.name}.{socket.gethostname()}-"


def remove_stale_temps(path: Path, suffix: str) -> list[Path]:
    """Remove the temporaries (files or folders ending in ``suffix``) that runs of this
    host writing ``path`` left when they were killed (their process is gone); returns
    them. Other hosts' (a shared folder) and running processes' stay."""
    import shutil

    start = _temp_stem(path)
    gone = []
    try:
        entries = list(os.scandir(path.parent))
    except OSError:
        return gone
    for entry in entries:
        pid = entry.name[len(start):].split(".", 1)[0]
        if not (entry.name.startswith(start) and entry.name.endswith(suffix)
                and pid.isdigit()) or _alive(int(pid)):
            continue
        try:
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
            gone.append(Path(entry.path))
        except OSError:
            pass
    return gone


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):  # another user's process, or no pid at all:
        return True  # left alone
    return True


def _user_mode(bits: int) -> int:
    """``bits`` less the process' umask: the mode of a file or folder the user makes."""
    umask = os.umask(0)
    os.umask(umask)
    return bits & ~umask


def staging_folder(path: str | os.PathLike) -> Path:
    """A new hidden folder beside ``path``, to build an output in before it is moved into
    place (named so that a later run removes it if this one is killed:
    :func:`remove_stale_temps`), with the mode of a folder the user makes (``mkdtemp``
    makes 0700). The caller removes it.

    Examples
    --------
    >>> d = staging_folder("scene")
    >>> d.is_dir(), d.name.startswith(".scene."), d.name.endswith(".part")
    (True, True, True)
    >>> d.rmdir()
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(path, ".part")
    tmp = Path(tempfile.mkdtemp(prefix=temp_prefix(path), suffix=".part", dir=path.parent))
    os.chmod(tmp, _user_mode(0o777))
    return tmp


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    An interrupted or failing writer leaves no file at ``path`` (nor a half-written one):
    the temporary file is removed on error.

    Examples
    --------
    >>> import numpy as np
    >>> with atomic_path("out.npy") as tmp:
    ...     np.save(tmp, np.arange(3))
    >>> np.load("out.npy").tolist()
    [0, 1, 2]
    """
    path = Path(path)
    ensure_file_target(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(path, ".part" + path.suffix)
    tmp_path = None
    try:
        with interrupts_deferred():  # the name is known before a Ctrl-C can unwind
            fd, tmp = tempfile.mkstemp(prefix=temp_prefix(path),
                                       suffix=".part" + path.suffix, dir=path.parent)
            tmp_path = Path(tmp)
            os.close(fd)
        # mkstemp creates 0600; results are meant to be as readable as any file the user
        # writes
        os.chmod(tmp_path, _user_mode(0o666))
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path is not None and tmp_path.exists():
            tmp_path.unlink()


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[list[int] | None]:
    """Hold Ctrl-C (SIGINT) and SIGTERM until the block ends, then deliver the first that
    came, to whatever handler is installed then.

    For the steps that make or remove a partial output, which an interrupt must not cut
    in two: a writer whose constructor was interrupted after it had created its ``.part``
    left that file behind, as nothing held the writer to abort it (one Ctrl-C in 40 at the
    end of ``evmotion simulate``). Holding the signals with ``pthread_sigmask`` does not
    do it: the kernel hands a process's signal to any thread that does not block it (the
    numba and BLAS threads), and Python runs the handler in the main thread.

    Yields the list of the signals held so far (empty while none came), or None where
    nothing is held: outside the main thread (Python runs handlers there only), inside
    another such block (the outermost delivers), or where a handler was installed from
    C (it could not be put back).

    Examples
    --------
    >>> import signal
    >>> seen = []
    >>> try:
    ...     with interrupts_deferred() as held:
    ...         signal.raise_signal(signal.SIGINT)
    ...         seen.append([signal.Signals(s).name for s in held])  # not interrupted
    ... except KeyboardInterrupt:
    ...     seen.append("KeyboardInterrupt as the block ends")
    >>> seen
    [['SIGINT'], 'KeyboardInterrupt as the block ends']
    """
    import signal
    import threading

    names = (signal.SIGINT, signal.SIGTERM)
    old = {s: signal.getsignal(s) for s in names}
    if _DEFERRING or any(h is None for h in old.values()) \
            or threading.current_thread() is not threading.main_thread():
        yield None
        return
    held: list[int] = []

    def hold(signum, frame) -> None:
        held.append(signum)

    for s in names:
        signal.signal(s, hold)
    _DEFERRING.append(held)
    try:
        yield held
    finally:
        _DEFERRING.pop()
        for s, h in old.items():
            signal.signal(s, h)
        if held:
            signal.raise_signal(held[0])


# the signals held by the active interrupts_deferred block (at most one)
_DEFERRING: list[list[int]] = []


# partial outputs an interrupted run kept for --resume, in the order they were kept
_KEPT_FOR_RESUME: list[Path] = []


def keep_for_resume(path: str | os.PathLike) -> None:
    """Record that an interrupted run left ``path`` (an ``OUT.part``, a checkpoint) for
    ``--resume`` to continue: the command line names it when it reports the interruption.
    """
    _KEPT_FOR_RESUME.append(Path(path))


def warn_nothing_to_resume(path: str | os.PathLike, why: str = "does not exist") -> None:
    """Say that ``--resume`` found no interrupted run to continue at ``path`` (``why``:
    it ``"does not exist"``, or held no finished window) and starts from the first window:
    a mistyped --out resumed nothing without a word (probes AM, BB, BH)."""
    import warnings

    from evmotion.errors import EvmotionWarning

    warnings.warn(EvmotionWarning(
        f"--resume: there is no interrupted run to continue ({path} {why}): starting from "
        "the first window"), stacklevel=3)


#: Why a ``.part`` or journal that is there holds nothing to resume.
HELD_NO_WINDOW = "held no finished window: its run stopped before one"


def kept_for_resume() -> list[Path]:
    """The partial outputs recorded by :func:`keep_for_resume`."""
    return list(_KEPT_FOR_RESUME)


def forget_kept_for_resume() -> None:
    """Start a new command: forget what :func:`keep_for_resume` recorded, and its
    :func:`set_interrupt_note`."""
    _KEPT_FOR_RESUME.clear()
    _INTERRUPT_NOTE.clear()


def set_interrupt_note(kept: str, lost: str) -> None:
    """What the command line says after an interruption in place of its usual "run the
    same command with --resume" (``kept``: with partial outputs kept) or its bare
    "interrupted" (``lost``: none kept), for a run whose resume needs other options (a
    parallel run: one worker)."""
    _INTERRUPT_NOTE[:] = [kept, lost]


def interrupt_note() -> tuple[str, str] | None:
    """The ``(kept, lost)`` of :func:`set_interrupt_note`, or None."""
    return tuple(_INTERRUPT_NOTE) if _INTERRUPT_NOTE else None


_INTERRUPT_NOTE: list[str] = []


def nearest_existing(path: str | os.PathLike) -> Path:
    """The path itself or its closest ancestor that exists (what ``mkdir -p`` starts from)."""
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def missing_path_hint(path: str | os.PathLike) -> str:
    """For a path that does not exist: ``" (did you mean 'NAME'?)"`` naming the entry of
    its folder whose name is closest to it (a typo), or ``""`` when none is close.

    Examples
    --------
    >>> Path("recording.h5").touch()
    >>> missing_path_hint("recordng.h5"), missing_path_hint("other.txt")
    (" (did you mean 'recording.h5'?)", '')
    """
    import difflib

    p = Path(path)
    try:
        names = [e.name for e in os.scandir(p.parent if str(p.parent) else ".")]
    except OSError:
        return ""
    close = difflib.get_close_matches(p.name, names, n=1, cutoff=0.75)
    return f" (did you mean '{p.parent / close[0] if p.parent != Path() else close[0]}'?)" \
        if close else ""


class NoRoomError(OSError):
    """No room for the next write: the device is full, or the file would pass a size limit
    (checked before the write, so what was written so far is intact, unlike a write that
    fails half-way)."""


# what a write may add beyond its arrays (HDF5 metadata, chunk indexes)
_WRITE_MARGIN = 1 << 20


def ensure_room(path: str | os.PathLike, nbytes: int, *, size_now: int | None = None) -> None:
    """Raise :class:`NoRoomError` when the next streamed write of ``nbytes`` to ``path``
    would not fit: errno ENOSPC when its file system has less than ``nbytes`` (plus 1 MiB)
    free, EFBIG when the file (``size_now`` bytes, default its size) would grow past the
    largest one the process' file-size limit (``ulimit -f``) or the file system (FAT32's
    4 GiB) allows. Checked before the write, so that it stops between two writes instead
    of in the middle of one (where libhdf5 leaves a damaged file, prints tracebacks and
    crashes the process at exit)."""
    import errno
    import shutil

    path = Path(path)
    need = nbytes + _WRITE_MARGIN
    free = shutil.disk_usage(nearest_existing(path.parent)).free
    if need > free:
        # as many decimals as tell the two apart ("needs up to 1.0 MiB, 1.0 MiB are free",
        # probe BB)
        digits = next((d for d in range(1, 7)
                       if round(need / 2**20, d) != round(free / 2**20, d)), 6)
        raise NoRoomError(errno.ENOSPC, f"no space left on the device for {path}: the next "
                          f"write needs up to {need / 2**20:.{digits}f} MiB, "
                          f"{free / 2**20:.{digits}f} MiB are free")
    limit, whose = _largest_file(path)
    if limit is not None:
        now = size_now if size_now is not None else (path.stat().st_size if path.exists()
                                                      else 0)
        if now + need > limit:
            raise NoRoomError(errno.EFBIG, f"{path} would grow past {limit / 2**20:.1f} MiB, "
                              f"the largest file {whose} allows (it holds "
                              f"{now / 2**20:.1f} MiB, the next write needs up to "
                              f"{need / 2**20:.1f} MiB)")


def _largest_file(path: Path) -> tuple[int | None, str]:
    """The largest file size in bytes a write to ``path`` may reach (the smaller of the
    process' RLIMIT_FSIZE and the file system's ``PC_FILESIZEBITS``), and whose limit it
    is; ``(None, "")`` without either."""
    limits = []
    try:
        import resource
    except ImportError:  # (not on Windows)
        resource = None
    if resource is not None:
        soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if soft != resource.RLIM_INFINITY:
            limits.append((soft, "the process' file-size limit (ulimit -f)"))
    try:
        bits = os.pathconf(nearest_existing(path.parent), "PC_FILESIZEBITS")
    except (OSError, ValueError, AttributeError):
        bits = None
    if bits and 0 < bits < 64:
        limits.append(((1 << bits) - 1, f"its file system ({bits}-bit file sizes)"))
    return min(limits) if limits else (None, "")


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def progress(iterable: Iterable[T], *, total: int | None = None, desc: str = "",
             unit: str = "it", disable: bool | None = None, unit_scale: bool = False,
             ) -> Iterable[T]:
    """A tqdm progress bar on stderr (rate and ETA). When stderr is not a TTY (a log
    file), a plain line every :data:`LOG_PROGRESS_S` seconds instead, from the first
    such interval on (short runs print none); ``EVMOTION_PROGRESS=1`` forces the bar,
    ``EVMOTION_PROGRESS=0`` silences both."""
    from tqdm.auto import tqdm

    env = os.environ.get("EVMOTION_PROGRESS")
    if disable is None and env != "1" and not sys.stderr.isatty():
        if env == "0":
            disable = True
        else:
            # miniters=1: a line only as an item completes, with its count, rate and ETA
            # (tqdm's monitor thread otherwise repeated the last line with only the
            # elapsed time moved, between slow items)
            bar = tqdm(iterable, total=total, desc=desc, unit=unit, unit_scale=unit_scale,
                       file=_LogLines(sys.stderr), mininterval=LOG_PROGRESS_S, miniters=1,
                       bar_format="{desc}: {n_fmt}/{total_fmt} {unit} [{elapsed} elapsed, "
                                  "{remaining} left, {rate_fmt}]")
            bar.log_lines = True  # (refine_total: no refresh, which writes a line)
            return bar
    return tqdm(iterable, total=total, desc=desc, unit=unit, disable=bool(disable),
                unit_scale=unit_scale, file=sys.stderr, **_bar_width())


def _bar_width() -> dict:
    """tqdm's width keywords: the terminal's, followed as it is resized; 80 columns where it
    reports none (a terminal of 0 columns, as ``script`` opens one: the bar was drawn 0
    wide, no rate, no ETA; probe BP)."""
    try:
        columns = os.get_terminal_size(sys.stderr.fileno()).columns
    except (OSError, ValueError, AttributeError):
        columns = 0
    return {"dynamic_ncols": True} if columns > 0 else {"ncols": 80}


#: Seconds between the progress lines written to a log (stderr not a TTY)
LOG_PROGRESS_S = 30.0


class _LogLines:
    """A file for tqdm that turns its carriage-return updates into whole lines, none
    before :data:`LOG_PROGRESS_S` seconds have passed."""

    def __init__(self, fh):
        self.fh = fh
        self.start = time.monotonic()
        self.last = None

    def write(self, text: str) -> None:
        line = text.replace("\r", "").strip()
        # a line whose count did not move (the closing refresh) says nothing new
        count = line.split(" [")[0]
        if line and count != self.last and time.monotonic() - self.start >= LOG_PROGRESS_S:
            self.fh.write(line + "\n")
            self.last = count

    def flush(self) -> None:
        self.fh.flush()


def refine_total(bar, done: int, meta: dict) -> None:
    """Set a progress bar's total (and so its ETA) to ``done`` items scaled by the share
    of the file read so far, when ``meta`` (of the last chunk read) tells it
    (``bytes_read`` and ``file_bytes``, from a reader whose header states no event count:
    EVT RAW files); otherwise leave the bar as it is.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> bar = SimpleNamespace(total=None, refresh=lambda: None)
    >>> refine_total(bar, 1000, {"bytes_read": 250, "file_bytes": 1000})
    >>> bar.total
    4000
    """
    read, size = meta.get("bytes_read"), meta.get("file_bytes")
    if not read or not size or done <= 0:
        return
    bar.total = max(int(done), int(round(done * size / read)))
    # a log's bar (lines every LOG_PROGRESS_S) shows it at its next line: a refresh there
    # wrote a line per chunk, whatever the interval
    if not getattr(bar, "log_lines", False):
        bar.refresh()


def seconds_text(t_us: int) -> str:
    """A time in µs written in seconds to the µs, for a user to type back as an option:
    ``%g`` rounds an epoch time (1.7e9 s) to whole seconds.

    Examples
    --------
    >>> seconds_text(1_700_000_000_008_334), seconds_text(1_500_000), seconds_text(-250)
    ('1700000000.008334', '1.5', '-0.00025')
    """
    t_us = int(t_us)
    sign, t_us = ("-", -t_us) if t_us < 0 else ("", t_us)
    whole, frac = divmod(t_us, 1_000_000)
    return f"{sign}{whole}{f'.{frac:06d}'.rstrip('0') if frac else ''}"


def check_finite(name: str, value) -> np.ndarray:
    """Raise :class:`ParameterError` naming ``name`` if ``value`` has NaN or inf or is no
    number (a string had met a bare ValueError from the float conversion, probe EVAL)."""
    try:
        if isinstance(value, (str, bytes)):  # ("1.5" would convert: no number either)
            raise ValueError
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ParameterError(f"parameter '{name}' must be a finite number, got "
                             f"{value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise ParameterError(f"parameter '{name}' must be finite, got {value!r}")
    return arr


#: The largest time, µs, a window bound or reference may be (int64 with room for sums).
MAX_TIME_US = 2**62


def is_finite_number(value) -> bool:
    """Whether ``value`` is one finite real number: an int, a float or a numpy scalar, not a
    bool (``np.isfinite`` raised a TypeError on a Python int past int64, probe API).

    Examples
    --------
    >>> is_finite_number(10**30), is_finite_number(float("nan")), is_finite_number(True)
    (True, False, False)
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an int past a float's range
        return False


def check_number(name: str, value, lo: float = 0.0, hi: float = math.inf, *,
                 lo_open: bool = False, units: str = "") -> float:
    """``value`` as a float, checked to be finite and in ``[lo, hi]`` (``(lo, hi]`` when
    ``lo_open``).

    Raises
    ------
    ParameterError
        One line naming ``name``, the allowed range (with ``units``) and the value.

    Examples
    --------
    >>> check_number("fps", 120, 0.0, lo_open=True, units="Hz")
    120.0
    >>> check_number("dt_s", "0.01")
    Traceback (most recent call last):
    evmotion.errors.ParameterError: dt_s must be finite and >= 0.0, got '0.01'
    """
    try:
        # (a string is no number: duration_s="0.01" had run: probe)
        v = math.nan if isinstance(value, (str, bytes)) else float(value)
    except (TypeError, ValueError, OverflowError):
        v = math.nan
    if not math.isfinite(v) or v < lo or (lo_open and v <= lo) or v > hi:
        op = ">" if lo_open else ">="
        rng = f"{op} {lo}" if hi == math.inf else \
            f"in {'(' if lo_open else '['}{lo}, {hi}]"
        unit = f" ({units})" if units else ""
        raise ParameterError(f"{name} must be finite and {rng}{unit}, got {value!r}")
    return v


def check_switches(**switches) -> None:
    """:class:`ParameterError` naming the first of ``switches`` that is not True or False
    (a string "no" is true to Python, and turned a switch on without a word).

    Examples
    --------
    >>> check_switches(refine=True, planar=np.bool_(False))
    >>> check_switches(refine="False")
    Traceback (most recent call last):
    evmotion.errors.ParameterError: refine must be True or False, got 'False'
    """
    for name, value in switches.items():
        if not isinstance(value, (bool, np.bool_)):
            raise ParameterError(f"{name} must be True or False, got {value!r}")


def check_not_seconds(name: str, value) -> None:
    """:class:`ParameterError` for a time in µs strictly between -1 and 1 but not 0: no
    clock ticks in fractions of a microsecond, and such a value is a time in seconds
    (``slice_time(0.001, 0.01)`` gave no event and ``gt.params(0.025)`` the motion at
    0 µs, without a word, probe DB).

    Examples
    --------
    >>> check_not_seconds("t0", 2500)
    >>> check_not_seconds("t0", 0.0025)
    Traceback (most recent call last):
    evmotion.errors.ParameterError: t0 = 0.0025 µs: times are in microseconds (seconds? 0.0025 s is 2500 µs)
    """
    v = float(value)
    if 0.0 < abs(v) < 1.0:
        raise ParameterError(f"{name} = {value:g} µs: times are in microseconds (seconds? "
                             f"{value:g} s is {v * 1e6:.6g} µs)")


def is_whole_number(value) -> bool:
    """Whether ``value`` is a whole number: an int or numpy integer (not a bool), or a
    finite float without a fraction.

    Examples
    --------
    >>> is_whole_number(3), is_whole_number(1e5), is_whole_number(2.5), is_whole_number(True)
    (True, True, False, False)
    """
    if isinstance(value, (bool, np.bool_)):
        return False
    if isinstance(value, (int, np.integer)):
        return True
    return isinstance(value, (float, np.floating)) and bool(np.isfinite(value)) \
        and float(value).is_integer()


def whole_number(name: str, value, lo: int | None = None, hi: int | None = None) -> int:
    """``value`` as an int, or :class:`ParameterError` naming ``name`` unless it is a whole
    number (an int, or a float such as ``1e5`` without a fraction) within ``[lo, hi]``.

    Examples
    --------
    >>> whole_number("dt_us", 1e5, lo=1)
    100000
    >>> whole_number("n_bins", 2.5, lo=1)
    Traceback (most recent call last):
    evmotion.errors.ParameterError: n_bins must be a whole number >= 1, got 2.5
    """
    want = ("a whole number" + (f" >= {lo}" if lo is not None and hi is None else "")
            + (f" in {lo}..{hi}" if lo is not None and hi is not None else "")
            + (f" <= {hi}" if lo is None and hi is not None else ""))
    ok = is_whole_number(value)
    if ok:
        v = int(value)
        ok = (lo is None or v >= lo) and (hi is None or v <= hi)
    if not ok:
        raise ParameterError(f"{name} must be {want}, got {value!r}")
    return v


def whole_time_us(name: str, value) -> int:
    """``value`` as an int of µs, or :class:`ParameterError` naming ``name`` unless it is a
    whole number within ``±MAX_TIME_US`` (past it, int64 sums overflow).

    Examples
    --------
    >>> whole_time_us("t0", 2.5e3)
    2500
    """
    return whole_number(name, value, -MAX_TIME_US, MAX_TIME_US)


def resolve_options(cls: type, options, keywords: dict, func: str):
    """The options of one call of ``func(..., options=None, **keywords)``:
    ``cls(**keywords)``, or ``options``; a function with many tuning parameters takes
    them either way (an options dataclass, or its fields as keywords).

    Parameters
    ----------
    cls : dataclass type
        The options class; its fields are the keywords ``func`` accepts.
    options : cls or None
        Options passed as an object.
    keywords : dict
        The keywords the caller passed (only those).
    func : str
        Name of the function, for the messages.

    Raises
    ------
    ParameterError
        A keyword that is not a field of ``cls``, ``options`` not a ``cls``, or both
        ``options`` and keywords given (the call would be ambiguous).

    Examples
    --------
    >>> Opts = dataclasses.make_dataclass("Opts", [("n_iter", int, 100)], frozen=True)
    >>> resolve_options(Opts, None, {"n_iter": 5}, "f")
    Opts(n_iter=5)
    >>> resolve_options(Opts, None, {"n_it": 5}, "f")
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: f() got unknown keyword(s) n_it; its options are n_iter
    """
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(keywords) - set(names))
    if unknown:
        raise ParameterError(f"{func}() got unknown keyword(s) {', '.join(unknown)}; its "
                             f"options are {', '.join(names)}")
    if options is None:
        return cls(**keywords)
    if not isinstance(options, cls):
        raise ParameterError(f"options must be a {cls.__name__}, got {type(options).__name__}")
    if keywords:
        raise ParameterError(f"pass either options= or the keyword(s) "
                             f"{', '.join(sorted(keywords))}, not both")
    return options
