"""Format registry: detection by content, dispatch to readers and writers."""

from __future__ import annotations

import importlib
import os
import re
from pathlib import Path

from evmotion.errors import FormatError
from evmotion.io.base import FormatSpec
from evmotion.io.guard import file_head
from evmotion.io.h5filters import HDF5_MAGIC
from evmotion.utils import missing_path_hint

# Modules that define ``FORMAT``; imported lazily so optional dependencies stay optional.
FORMAT_MODULES: tuple[str, ...] = (
    "evmotion.io.h5",         # evmotion's own HDF5
    "evmotion.io.mvsec",
    "evmotion.io.dsec",
    "evmotion.io.ecd",        # folder layout and events.txt
    "evmotion.io.ccs",        # published event-based BOS recordings (raw_events HDF5)
    "evmotion.io.npy",        # .npy / .npz
    "evmotion.io.mat",        # MATLAB .mat excerpts
    "evmotion.io.aedat4",
    "evmotion.io.aedat2",
    "evmotion.io.aedat3",
    "evmotion.io.evt3",
    "evmotion.io.evt2",
    "evmotion.io.evt21",
    "evmotion.io.dat",
    "evmotion.io.rosbag",
    "evmotion.io.h5generic",  # other tools' HDF5 layouts: after every specific one
)


def all_formats() -> list[FormatSpec]:
    """Every format whose module is present, in detection order."""
    out = []
    for name in FORMAT_MODULES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:
                continue
            raise
        out.append(mod.FORMAT)
    return out


def get_format(name: str) -> FormatSpec:
    for f in all_formats():
        if f.name == name:
            return f
    names = [f.name for f in all_formats()]
    raise FormatError(None, f"unknown format '{name}'", f"known formats: {', '.join(names)}")


# the first bytes of compressed files and of text in a wide encoding, what they are, and
# what to do
_PACKED = ((b"\x1f\x8b", "gzip-compressed", "decompress it first, e.g. with gunzip"),
           (b"BZh", "bzip2-compressed", "decompress it first, e.g. with bunzip2"),
           (b"\xfd7zXZ\x00", "xz-compressed", "decompress it first, e.g. with unxz"),
           (b"\x28\xb5\x2f\xfd", "zstd-compressed", "decompress it first, e.g. with unzstd"),
           (b"PK\x03\x04", "a zip archive", "extract the recording from it"),
           (b"\xff\xfe", "text in UTF-16", "save it as UTF-8 or ASCII text"),
           (b"\xfe\xff", "text in UTF-16", "save it as UTF-8 or ASCII text"))


def _packed(head: bytes) -> tuple[str, str] | None:
    """``(what, hint)`` of a file that holds a recording only once unpacked or re-encoded
    (compressed, zipped, UTF-16 text), from its first bytes; None otherwise."""
    for magic, what, hint in _PACKED:
        if head.startswith(magic):
            return what, hint
    return None


def detect_format(path: str | os.PathLike) -> str:
    """Name of the format of ``path`` (file or folder), detected by content.

    Examples
    --------
    >>> from evmotion import EventArray
    >>> from evmotion.io import write_events
    >>> ev = EventArray(x=[1], y=[2], t=[10], p=[1], sensor_size=(180, 240))
    >>> write_events("boxes_rotation/events.txt", ev)
    >>> write_events("rec.raw", ev)
    >>> detect_format("boxes_rotation/"), detect_format("rec.raw")
    ('ecd', 'evt3')
    """
    return detect_spec(path).name


def resolve_format(path: str | os.PathLike, format: str | None = None) -> FormatSpec:
    """The :class:`FormatSpec` named ``format``, or, without a name, the one of ``path``
    detected by content (:func:`detect_spec`)."""
    if format is not None:
        _refuse_special(Path(path))
        return get_format(format)
    return detect_spec(path)


def _refuse_special(path: Path) -> None:
    """FormatError for a path that is neither a regular file nor a folder: a device or a
    pipe has no end (/dev/zero read with --format npy filled 24 GB of memory and ignored
    Ctrl-C; evt2 said '[Errno 20] Not a directory', probe CE)."""
    if path.exists() and not (path.is_file() or path.is_dir()):
        raise FormatError(path, "is not a regular file or folder (a device, pipe or socket): "
                          "evmotion reads recordings from files")


def _raise_unreadable_hdf5(path: Path) -> None:
    """Raise h5py's reason (in one line) when the HDF5 file ``path`` does not open, or
    name the event fields it lacks where it holds some of them."""
    import h5py

    from evmotion.io.guard import not_hdf5
    from evmotion.io.h5filters import register_filters
    from evmotion.io.h5generic import partial_fields

    register_filters()
    try:
        with h5py.File(path, "r") as f:
            names, missing = partial_fields(f)
    except OSError as exc:
        raise not_hdf5(path, exc) from None
    if names:
        # (probe: an events/ group without p was "format not recognised")
        raise FormatError(path, f"HDF5 datasets {', '.join(names[:8])} hold no event field "
                          f"{' or '.join(missing)}: events need t, x, y and p (names "
                          "evmotion.io.base.EVENT_FIELD_NAMES lists)")


def detect_spec(path: str | os.PathLike) -> FormatSpec:
    """The :class:`FormatSpec` of ``path`` (file or folder), detected by content;
    :func:`detect_format` gives its name."""
    path = Path(path)
    if not path.exists():
        raise FormatError(path, f"no such file or folder{missing_path_hint(path)}")
    _refuse_special(path)
    head = b""
    if path.is_file():
        head = file_head(path, 4096)
        if not head:
            raise FormatError(path, "the file is empty")
    candidates = []
    failed: FormatError | None = None
    for f in all_formats():
        try:
            if f.sniff(path, head):
                candidates.append(f)
        except FormatError as exc:
            # a sniffer that cannot open the file (corrupt HDF5...) does not stop another
            # format from recognising it; if none does, its error says the most
            failed = failed or exc
    if not candidates and path.name.endswith(".part"):
        # what an interrupted convert (or a killed run) leaves: not a recording to decode
        raise FormatError(path, "is the unfinished output of an interrupted evmotion run "
                          "(a .part file)", "run the command that wrote it again (with "
                          "--resume where it offers one), or delete it")
    if not candidates and failed is not None:
        raise failed
    if not candidates:
        found = own_output_folder(path)
        if found is not None:
            raise FormatError(path, f"is a folder of evmotion output ({found[0].name}: "
                              f"{found[1]}), not a recording of events",
                              "evmotion info describes it; evmotion eval scores it")
        own = _own_output(path, head)
        if own is not None:
            raise FormatError(path, f"is an evmotion output ({own}), not a recording of events",
                              "evmotion info describes it; eval and view read flow outputs")
        if head.startswith(HDF5_MAGIC):
            # an HDF5 file no reader could open (cut short, say) or one with some event
            # fields: what is wrong says more than "not recognised" (probe)
            _raise_unreadable_hdf5(path)
        if _frame_list(head):
            raise FormatError(path, "is a list of frames ('t path' lines), not events",
                              "give its folder, which holds the events too; bos also "
                              "takes it as --frames beside a recording")
        if re.search(rb"(?m)^[^#%\n]*\b(True|False)\b", head):
            # pandas writes a bool column so (probe BL: "format not recognised")
            raise FormatError(path, "holds words True / False where numbers are read (a "
                              "polarity column of booleans?)", "write them as 1 and 0")
        packed = _packed(head)
        if packed is not None:
            # (a bare "format not recognised", probe BL)
            raise FormatError(path, f"is {packed[0]}, not a recording evmotion reads as it is",
                              packed[1])
        if path.suffix.lower() == ".raw":
            # Prophesee's words without the '%' header that names their encoding
            raise FormatError(path, "a .raw file with no '%' header: its encoding and "
                              "sensor size are not stated", "give --format evt3 (or evt2, "
                              "evt21) and --sensor-size H W")
        names = ", ".join(sorted(f.name for f in all_formats()))
        raise FormatError(path, "format not recognised",
                          f"give --format explicitly, one of: {names}")
    if len(candidates) > 1:
        suffix = path.suffix.lower()
        by_ext = [f for f in candidates if suffix in f.extensions]
        if by_ext:
            return by_ext[0]
    return candidates[0]


def _frame_list(head: bytes) -> bool:
    """Whether ``head`` opens a list of frames, an ECD ``images.txt``: its first lines
    that are not comments are ``t path`` with an image file's name."""
    from evmotion.io.frames import IMAGE_SUFFIXES

    lines = [ln.split() for ln in head.decode("latin-1").splitlines()[:5]
             if ln.strip() and not ln.lstrip().startswith("#")]
    return bool(lines) and all(len(f) >= 2 and f[-1].lower().endswith(IMAGE_SUFFIXES)
                               for f in lines)


def own_output_folder(path: str | os.PathLike) -> tuple[Path, str] | None:
    """``(file, what it holds)`` where ``path`` is a folder evmotion wrote results into
    (``egomotion``'s params.h5, ``segment``'s clusters.h5; first by name), None otherwise.
    Its PNG panels had been read as frames without timestamps (``info``), and the folder as
    an unknown format (probe AZ).

    Examples
    --------
    >>> own_output_folder(".") is None
    True
    """
    from evmotion.io.h5filters import HDF5_MAGIC

    folder = Path(path)
    if not folder.is_dir() or (folder / "events.txt").is_file():
        # a recording, whose results may lie beside its events (info of a schlieren scene
        # described its schlieren_gt.h5, or a bos.h5 written there; probe BR)
        return None
    for f in sorted(folder.glob("*.h5"))[:16]:
        try:
            with open(f, "rb") as fh:
                head = fh.read(len(HDF5_MAGIC))
        except OSError:
            continue
        kind = _own_output(f, head)
        if kind is not None:
            return f, kind
    return None


def _own_output(path: Path, head: bytes) -> str | None:
    """What an HDF5 file evmotion wrote as a result (flow, parameters, ground truth...)
    holds, by its ``format`` / ``content`` attribute; None for anything else."""
    from evmotion.io.h5filters import HDF5_MAGIC

    if not head.startswith(HDF5_MAGIC):
        return None
    try:
        import h5py

        with h5py.File(path, "r") as f:
            attrs = {k: f.attrs.get(k) for k in ("content", "format", "method")}
    except (OSError, ValueError):
        return None
    text = {k: v.decode() if isinstance(v, bytes) else v for k, v in attrs.items()}
    kind = next((v for v in (text["content"], text["format"])
                 if isinstance(v, str) and v.startswith("evmotion-")), None)
    if kind is None:
        return None
    return kind + (f" of {text['method']}" if isinstance(text["method"], str) else "")

