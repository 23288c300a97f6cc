"""One-line errors naming the file, whatever a reader trips over in a corrupt file.

Every format's ``sniff``, ``read``, ``iter_chunks`` and ``describe`` are wrapped by
:class:`~evmotion.io.base.FormatSpec` with :func:`guard_call` / :func:`guard_iter`, so an
exception from a low-level library (h5py's ``KeyError``/``OSError``, ``zlib.error``,
``zipfile.BadZipFile``, ``struct.error``, ``OverflowError``, a ``MemoryError``...) or an
:class:`~evmotion.errors.EvmotionError` raised without the path reaches the caller as a
:class:`~evmotion.errors.FormatError` that names the file, on one line, with the original
exception chained (``__cause__``) for debugging.

This is the net under the readers, not their validation: the readers check header fields
against the file's size and :data:`MAX_SENSOR_SIDE` before allocating anything, so memory
and time stay bounded on corrupt files (a net cannot give back memory already taken).
"""

from __future__ import annotations

import contextlib
import functools
import numbers
import os
import re
import struct
from collections.abc import Callable, Iterator
from pathlib import Path

from evmotion.catalog import MAX_SENSOR_SIDE
from evmotion.errors import (
    EvmotionError,
    FormatError,
    MissingDependencyError,
    ParameterError,
    UnsortedError,
    one_line,
)

__all__ = ["GIVEN_SIZE_HINT", "MAX_SENSOR_SIDE", "SENSOR_SIZE_HINT", "check_sensor_size",
           "guard_call", "guard_iter", "as_format_error", "extended_size", "file_head",
           "open_h5", "open_npz", "not_hdf5", "given_sensor_size",
           "sensor_size_hint", "warn_inferred_size", "LARGEST_COORDINATE"]


# Errors of the code itself or of the installation, not of the file: let them through
# unchanged so a bug is not reported as a corrupt file.
# (AssertionError and SyntaxError are not among them: rosbags asserts on file content,
# numpy parses .npy headers with ast.literal_eval.)
_NOT_THE_FILE = (NameError, ImportError, ParameterError, MissingDependencyError)


def check_sensor_size(path, size, field: str = "sensor size") -> tuple[int, int]:
    """``size`` as ``(height, width)`` ints, or FormatError unless both are in
    ``1..MAX_SENSOR_SIDE``.

    Examples
    --------
    >>> check_sensor_size("a.raw", ("720", 1280))
    (720, 1280)
    >>> check_sensor_size("a.npz", [60.9, 80.9], "array 'sensor_size'")
    Traceback (most recent call last):
    evmotion.errors.FormatError: a.npz: array 'sensor_size' [60.9, 80.9] is not two whole numbers (height, width)
    """
    try:
        if isinstance(size, (str, bytes)):
            raise TypeError  # "44" unpacked to (4, 4)
        h, w = (_whole(v) for v in size)
    except (TypeError, ValueError, OverflowError):
        # (fractions had been floored, 60.9 read as 60, and a size of one value or a word
        # left for a default: probe CG)
        raise FormatError(path, f"{field} {_shown(size)} is not two whole numbers (height, "
                          "width)") from None
    if not (0 < h <= MAX_SENSOR_SIDE and 0 < w <= MAX_SENSOR_SIDE):
        raise FormatError(path, f"{field} (height, width) = ({h}, {w}) is outside "
                          f"1..{MAX_SENSOR_SIDE} px per side", "corrupt header?")
    return h, w


def _shown(size) -> str:
    """``size`` as a message shows it: numpy values as plain numbers."""
    if hasattr(size, "tolist"):
        return repr(size.tolist())
    if isinstance(size, (tuple, list)):
        items = [v.item() if hasattr(v, "item") else v for v in size]
        return repr(items if isinstance(size, list) else tuple(items))
    return repr(size)


def _whole(v) -> int:
    """``v`` as an int: a decimal string of one, or a number without a fraction
    (ValueError otherwise, TypeError for what is neither)."""
    if isinstance(v, (str, bytes)):
        return int(v)
    f = float(v)
    if f != int(f):
        raise ValueError(v)
    return int(v) if isinstance(v, numbers.Integral) else int(f)


def given_sensor_size(size) -> tuple[int, int]:
    """A reader's ``sensor_size=`` argument as ``(height, width)`` ints, or
    ParameterError: two whole numbers in ``1..MAX_SENSOR_SIDE`` (a string, three numbers,
    a negative or fractional side had reached the text reader as a corrupt file, been cut
    or been floored: probe).

    Examples
    --------
    >>> given_sensor_size((180.0, 240))
    (180, 240)
    """
    try:
        h, w = size
        if isinstance(h, str) or isinstance(w, str) or float(h) != int(h) or float(w) != int(w):
            raise ValueError
        h, w = int(h), int(w)
    except (TypeError, ValueError, OverflowError):
        raise ParameterError(f"sensor_size must be two whole numbers (height, width), got "
                             f"{size!r}") from None
    if not (0 < h <= MAX_SENSOR_SIDE and 0 < w <= MAX_SENSOR_SIDE):
        raise ParameterError(f"sensor_size (height, width) = ({h}, {w}) is outside "
                             f"1..{MAX_SENSOR_SIDE} px per side")
    return h, w


#: What to do when a file does not give its sensor size: in Python and on the command line.
SENSOR_SIZE_HINT = "give the size: --sensor-size H W (sensor_size=(height, width) in Python)"
#: ... and when the size given is smaller than the events reach.
GIVEN_SIZE_HINT = ("the size given (--sensor-size, sensor_size= in Python) is smaller than "
                   "the events reach: give the true size, or leave it out to take the file's")


def sensor_size_hint(given: bool) -> str:
    """What to do about events outside the sensor: :data:`GIVEN_SIZE_HINT` when the user
    gave the size, else :data:`SENSOR_SIZE_HINT`."""
    return GIVEN_SIZE_HINT if given else SENSOR_SIZE_HINT

# 2^62 us is 146,000 years: any timestamp beyond it is a corrupt field, and int64 holds it
MAX_ABS_TIME_US = 1 << 62


def time_to_us(path, text: str, scale: float, where: str) -> int:
    """A time field of a text file (``text`` in units of ``scale`` us) as int us, or a
    FormatError naming ``where`` (e.g. ``"line 3"``) when it is not a finite number within
    +-2^62 us.

    Examples
    --------
    >>> time_to_us("images.txt", "0.008333", 1e6, "line 2")
    8333
    >>> time_to_us("images.txt", "inf", 1e6, "line 2")
    Traceback (most recent call last):
    evmotion.errors.FormatError: images.txt: line 2: time 'inf' is not a finite number within +-2^62 us
    """
    try:
        us = float(text) * scale
    except ValueError:
        raise FormatError(path, f"{where}: {text!r} is not a time") from None
    if not abs(us) < MAX_ABS_TIME_US:  # NaN fails too
        raise FormatError(path, f"{where}: time {text!r} is not a finite number within "
                          "+-2^62 us")
    return round(us)


def as_format_error(exc: BaseException, path, fmt: str, action: str,
                    size_given: bool = False) -> BaseException:
    """The exception to raise for ``exc`` met while ``action``-ing ``path`` as ``fmt``:
    ``exc`` itself when it already names the file or is not about the file, else a
    FormatError naming the file (``size_given``: the caller gave ``sensor_size``)."""
    if isinstance(exc, _NOT_THE_FILE) or not isinstance(exc, Exception):
        return exc
    if isinstance(exc, FormatError):
        if exc.path is not None:
            return exc
        return FormatError(path, exc.message, exc.hint)
    if isinstance(exc, EvmotionError):
        # events beyond the size the file states: a header that understates its sensor
        hint = sensor_size_hint(size_given) if "outside the sensor" in str(exc) else None
        return FormatError(path, str(exc), hint)
    if isinstance(exc, MemoryError):
        return FormatError(path, f"{action} as {fmt} needs more memory than is available "
                           "(MemoryError)", "corrupt header or file?")
    with contextlib.suppress(OSError, TypeError):
        if os.path.isfile(path) and os.path.getsize(path) == 0:
            # (numpy's "EOFError: No data left in file" of an empty .npz: probe)
            return FormatError(path, "the file is empty")
    detail = one_line(str(exc)) or "no detail"
    return FormatError(path, f"cannot {action} as {fmt}: {type(exc).__name__}: {detail}",
                       "the file is corrupt, truncated or not in this format")


def _path_of(args, kw):
    p = args[0] if args else kw.get("path")
    return Path(p) if isinstance(p, (str, os.PathLike)) else p


def _check_call(fn: Callable, fmt: str, args, kw) -> None:
    """ParameterError for arguments ``fn`` does not take (a misspelt option): called
    unchecked, its TypeError would be reported as a corrupt file."""
    import inspect

    try:
        inspect.signature(fn).bind(*args, **kw)
    except TypeError as exc:
        raise ParameterError(f"{fmt} {fn.__name__}: {exc}") from None
    except ValueError:  # no signature to check (a builtin): let the call say
        pass


def guard_call(fn: Callable, fmt: str, action: str) -> Callable:
    """``fn(path, ...)`` whose exceptions go through :func:`as_format_error`."""

    @functools.wraps(fn)
    def guarded(*args, **kw):
        _check_call(fn, fmt, args, kw)
        try:
            return fn(*args, **kw)
        except Exception as exc:
            new = as_format_error(exc, _path_of(args, kw), fmt, action,
                                  kw.get("sensor_size") is not None)
            if new is exc:
                raise
            raise new from exc

    guarded.__evmotion_guarded__ = True
    return guarded


def guarded(fmt: str, action: str = "read") -> Callable[[Callable], Callable]:
    """:func:`guard_call` as a decorator, for readers whose first argument is the path.

    Examples
    --------
    >>> @guarded("flow HDF5")
    ... def read_it(path):
    ...     return {}["flow"]
    >>> read_it("x.h5")
    Traceback (most recent call last):
    evmotion.errors.FormatError: x.h5: cannot read as flow HDF5: KeyError: 'flow' (the file is corrupt, truncated or not in this format)
    """
    return lambda fn: guard_call(fn, fmt, action)


def guard_iter(fn: Callable, fmt: str, action: str = "read") -> Callable:
    """As :func:`guard_call` for a function returning an iterator: errors raised while
    iterating are converted too, and closing the result closes ``fn``'s iterator."""

    @functools.wraps(fn)
    def guarded(*args, **kw) -> Iterator:
        _check_call(fn, fmt, args, kw)
        path = _path_of(args, kw)
        it = None
        done = 0  # events yielded: a chunk's error names its events by their place in the file
        try:
            try:
                it = iter(fn(*args, **kw))
                while True:
                    try:
                        item = next(it)
                    except StopIteration:
                        return
                    done += len(item) if hasattr(item, "__len__") else 0
                    yield item
            except Exception as exc:
                if isinstance(exc, UnsortedError) and done:
                    exc = exc.shifted(done)
                new = as_format_error(exc, path, fmt, action,
                                      kw.get("sensor_size") is not None)
                if new is exc:
                    raise
                raise new from exc
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()

    guarded.__evmotion_guarded__ = True
    return guarded


# --------------------------------------------------------------------- HDF5 datasets
# Largest HDF5 chunk accepted: a chunk is decompressed whole to read any of it, so a
# corrupt chunk shape must not cost gigabytes (writers use at most a few MiB).
MAX_H5_CHUNK_BYTES = 1 << 26


def open_h5(path):
    """The HDF5 file ``path`` opened read-only (an ``h5py.File``, to be closed by the
    caller, e.g. in a ``with`` block).

    Raises
    ------
    FormatError
        One line naming the file when it is missing or not a readable HDF5 file.

    Examples
    --------
    >>> import h5py
    >>> with h5py.File("flow.h5", "w") as f:
    ...     f["t0"], f["t1"] = [0, 10_000], [10_000, 20_000]
    >>> with open_h5("flow.h5") as f:
    ...     names = list(f)
    >>> names
    ['t0', 't1']
    """
    import h5py

    from evmotion.io.h5filters import register_filters

    register_filters()  # evmotion writes Blosc-compressed datasets (events, flow)
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise not_hdf5(path, exc) from None


def file_head(path, n: int, action: str = "cannot open") -> bytes:
    """The first ``n`` bytes of the file ``path``, or :class:`FormatError` naming it and
    the system's reason after ``action``.

    Examples
    --------
    >>> _ = open("h.bin", "wb").write(b"abcdefg")
    >>> file_head("h.bin", 4)
    b'abcd'
    """
    try:
        with open(path, "rb") as fh:
            return fh.read(n)
    except OSError as exc:
        raise FormatError(path, f"{action}: {exc.strerror or exc}") from None


def open_npz(path):
    """The ``.npz`` archive ``path`` opened with ``np.load`` (no pickles; to be closed by
    the caller, e.g. in a ``with`` block).

    Raises
    ------
    FormatError
        One line naming the file when it is missing, empty, truncated or not a zip archive
        (numpy's own words for a file that is no archive speak of pickled data, and an
        empty file met an EOFError, probe EVAL).

    Examples
    --------
    >>> import numpy as np
    >>> np.savez("a.npz", t0=[0])
    >>> with open_npz("a.npz") as z:
    ...     z.files
    ['t0']
    >>> _ = open("b.npz", "w").write("not an archive")
    >>> open_npz("b.npz")
    Traceback (most recent call last):
    evmotion.errors.FormatError: b.npz: cannot read as .npz: not a zip archive (it begins with b'not ')
    """
    import zipfile

    import numpy as np

    head = file_head(path, 4, "cannot read as .npz")
    if not head:
        raise FormatError(path, "cannot read as .npz: the file is empty")
    if head not in (b"PK\x03\x04", b"PK\x05\x06"):  # a member, or an empty archive
        raise FormatError(path, f"cannot read as .npz: not a zip archive (it begins with "
                          f"{head!r})")
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise FormatError(path, f"cannot read as .npz: {exc}") from None


def not_hdf5(path, exc: OSError) -> FormatError:
    """The error for ``path`` that h5py could not open (``exc``), in one short line:
    HDF5's own reason, without its buffer addresses and time stamps.

    Examples
    --------
    >>> exc = OSError("Unable to synchronously open file (file read failed: time = Mon "
    ...               "Nov 30 2026, filename = 'b4', error message = 'Is a directory', "
    ...               "buf = 0x7ffd, total read size = 8)")
    >>> print(not_hdf5("b4", exc))
    b4: not a readable HDF5 file (Is a directory)
    """
    if Path(path).is_dir():
        return FormatError(path, "is a folder, not an HDF5 file")
    text = " ".join(str(exc).split())
    said = re.search(r"error message = '([^']*)'", text)
    inner = re.search(r"\(([^()]*)\)\s*$", text)
    reason = said.group(1) if said else inner.group(1) if inner else text
    return FormatError(path, f"not a readable HDF5 file ({reason[:120]})")


def check_h5_dataset(path, f, name: str, *, ndim: int, kinds: str,
                     length: int | None = None, row: int | None = None):
    """The dataset ``f[name]``, checked before anything is read from it: a dataset (not a
    group) of ``ndim`` dimensions (``length`` rows and ``row`` columns when given), a
    plain number dtype of kind in ``kinds`` (numpy ``dtype.kind`` letters), and storage
    that covers its extent inside the file (a corrupt shape or chunk size would otherwise
    make h5py return gigabytes of fill values or decompress a huge chunk).

    Raises FormatError naming the file and the dataset otherwise.
    """
    import h5py

    obj = f.get(name)
    if not isinstance(obj, h5py.Dataset):
        raise FormatError(path, f"'{name}' is {'missing' if obj is None else 'not a dataset'}")
    shape, dt = obj.shape, obj.dtype
    if shape is None or len(shape) != ndim:
        raise FormatError(path, f"dataset '{name}' has shape {shape}, expected {ndim}-D")
    if length is not None and shape[0] != length:
        raise FormatError(path, f"dataset '{name}' has {shape[0]} rows, expected {length} "
                          "like the other event fields")
    if row is not None and shape[1] != row:
        raise FormatError(path, f"dataset '{name}' has shape {shape}, expected (N, {row})")
    if dt.names is not None or dt.kind not in kinds or dt.itemsize > 8:
        raise FormatError(path, f"dataset '{name}' has dtype {dt}, expected a plain "
                          f"number of kind {'/'.join(kinds)}")
    return check_h5_storage(path, obj, name)


def check_h5_storage(path, obj, name: str):
    """The dataset ``obj`` (named ``name``), its storage checked to cover its extent
    inside the file: a corrupt shape or chunk size would otherwise make h5py return
    gigabytes of fill values or decompress a huge chunk (a 2 KiB file declaring 3e9
    values took 23 GB through another tool's layout, probe BL). FormatError otherwise."""
    shape, dt = obj.shape, obj.dtype
    count = 1
    for s in shape:
        count *= int(s)
    if count == 0:
        return obj
    size = Path(path).stat().st_size
    if obj.chunks is None:
        offset = obj.id.get_offset()
        stored = obj.id.get_storage_size()
        if offset is None and stored < count * dt.itemsize:
            raise FormatError(path, f"dataset '{name}' declares {count} values but only "
                              f"{stored} bytes are stored")
        if offset is not None and offset + count * dt.itemsize > size:
            raise FormatError(path, f"dataset '{name}' ({count} values at byte offset "
                              f"{offset}) runs past the end of the file ({size} bytes)")
        return obj
    chunk_bytes = dt.itemsize
    need = 1
    for s, c in zip(shape, obj.chunks, strict=True):
        chunk_bytes *= int(c)
        need *= -(-int(s) // int(c))
    if chunk_bytes > MAX_H5_CHUNK_BYTES:
        raise FormatError(path, f"dataset '{name}' has chunks {obj.chunks} of {chunk_bytes} "
                          f"bytes, over the {MAX_H5_CHUNK_BYTES} accepted")
    have = obj.id.get_num_chunks()
    if have < need:
        raise FormatError(path, f"dataset '{name}' of shape {shape} needs {need} chunks but "
                          f"the file stores {have} (corrupt shape or truncated file)")
    blosc = _blosc_stage(path, obj, name, chunk_bytes)
    chunks = []
    if hasattr(obj.id, "chunk_iter"):
        obj.id.chunk_iter(chunks.append)
    else:
        chunks = [obj.id.get_chunk_info(i) for i in range(have)]
    with open(path, "rb") as fh:
        for info in chunks:
            if info.byte_offset + info.size > size:
                raise FormatError(path, f"dataset '{name}': chunk at byte offset "
                                  f"{info.byte_offset} ({info.size} bytes) runs past the end "
                                  f"of the file ({size} bytes)")
            if blosc is not None and not info.filter_mask & (1 << blosc):
                fh.seek(info.byte_offset)
                _check_blosc_header(path, name, info, fh.read(16), chunk_bytes)
    return obj


BLOSC_FILTER_ID = 32001


def _blosc_stage(path, obj, name: str, chunk_bytes: int) -> int | None:
    """Index of the Blosc filter in the dataset's pipeline when it is the last one (so a
    stored chunk starts with a Blosc header), after checking its parameters; else None.

    The Blosc HDF5 filter trusts its parameters and the chunk header: a corrupt one makes
    it allocate up to 4 GiB or dereference a null pointer (a segfault, seen by fuzzing).
    """
    plist = obj.id.get_create_plist()
    n = plist.get_nfilters()
    for i in range(n):
        code, _, values, _ = plist.get_filter(i)
        if code != BLOSC_FILTER_ID:
            continue
        if len(values) < 4 or values[3] != chunk_bytes:
            raise FormatError(path, f"dataset '{name}': Blosc filter parameters {values} do "
                              f"not match its {chunk_bytes}-byte chunks")
        return i if i == n - 1 else None
    return None


def _check_blosc_header(path, name: str, info, head: bytes, chunk_bytes: int) -> None:
    """The 16-byte Blosc header of a stored chunk agrees with the chunk it must hold."""
    if len(head) < 16:
        raise FormatError(path, f"dataset '{name}': chunk at byte offset {info.byte_offset} "
                          "is cut short")
    _, _, _, typesize, nbytes, blocksize, cbytes = struct.unpack("<BBBBIII", head)
    if (nbytes != chunk_bytes or cbytes != info.size or typesize == 0
            or not 0 < blocksize <= max(nbytes, 1)):
        raise FormatError(path, f"dataset '{name}': Blosc chunk at byte offset "
                          f"{info.byte_offset} declares {nbytes} bytes in {cbytes} (blocks of "
                          f"{blocksize}), expected {chunk_bytes} in {info.size}",
                          "corrupt compressed chunk")


# where a reader says a sensor size came from when it took the largest coordinates
LARGEST_COORDINATE = "largest coordinate (the file states no sensor size)"


def extended_size(path, size: tuple[int, int], x_max: int, y_max: int,
                  why: str = "") -> tuple[int, int] | None:
    """A file stating no sensor size, read on a default ``size`` ``(H, W)``, whose events
    reach ``x_max, y_max`` (pixels, >= 0) beyond it: the smallest sensor holding every
    event (at least ``size``), said by :func:`warn_inferred_size`; None when the events
    fit ``size``, or when no sensor is that large (they are refused as outside).

    Examples
    --------
    >>> extended_size("a.txt", (180, 240), 100, 100) is None
    True
    """
    if (x_max < size[1] and y_max < size[0]) or max(x_max, y_max) >= MAX_SENSOR_SIDE:
        return None
    size = (max(size[0], int(y_max) + 1), max(size[1], int(x_max) + 1))
    warn_inferred_size(path, size, why, stacklevel=4)
    return size


def warn_inferred_size(path, size: tuple[int, int], why: str = "",
                       stacklevel: int = 3) -> None:
    """Say that a file stating no sensor size was given the smallest one holding its
    events (``size`` ``(H, W)``); ``why`` says more (", events beyond 240x180")."""
    import warnings

    from evmotion.errors import EvmotionWarning

    warnings.warn(EvmotionWarning(
        f"{path}: no sensor size in the file{why}: taken as {size[1]}x{size[0]} px (W x H) "
        "from the largest coordinates; give the true size (--sensor-size H W, or "
        "sensor_size=(H, W) in Python)"), stacklevel=stacklevel)


def verified_position(path, read_t: Callable, n: int, tq: int, i: int, index: str) -> int:
    """Where ``tq`` goes among a file's ``n`` sorted times (``read_t(a, b)`` reads times
    ``a..b``): ``i``, the position its time ``index`` gave, when the times around it agree;
    otherwise (a stale or corrupt index, which silently gave another time range) the
    position found by bisecting the times, with a warning naming the index."""
    import warnings

    import numpy as np

    from evmotion.errors import EvmotionWarning

    if (i == 0 or read_t(i - 1, i)[0] < tq) and (i == n or read_t(i, i + 1)[0] >= tq):
        return i
    warnings.warn(EvmotionWarning(
        f"{path}: its time index ({index}) does not match its timestamps (a stale or "
        "corrupt index): the times were searched instead"), stacklevel=4)
    lo, hi = 0, n
    while hi - lo > 1 << 16:  # a few reads of one time each, then one block
        mid = (lo + hi) // 2
        if read_t(mid, mid + 1)[0] < tq:
            lo = mid + 1
        else:
            hi = mid
    return lo + int(np.searchsorted(read_t(lo, hi), tq, side="left"))
