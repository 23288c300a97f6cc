"""What every HDF5 reader and writer shares: the file signature (:func:`is_hdf5`) and the
compression filters (Blosc/zstd, Blosc/LZ4 through :mod:`hdf5plugin`): registering them, and
the one-line error a dataset that needs a filter this process cannot load gets.

Examples
--------
>>> from evmotion.io.h5filters import register_filters
>>> register_filters()  # True when hdf5plugin is importable
True
"""

from __future__ import annotations

import os
from pathlib import Path

from evmotion.errors import FormatError, ParameterError

__all__ = ["FILTER_HINT", "H5_COMPRESSIONS", "HDF5_MAGIC", "filter_error", "h5_compression",
           "is_hdf5", "missing_filters", "register_filters"]

HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"  # the first 8 bytes of every HDF5 file

FILTER_HINT = "pip install hdf5plugin (DSEC compresses events with Blosc/zstd)"
# Prophesee's ECF codec (Metavision HDF5 event files), which only its own plugin decodes
ECF_FILTER = 36559
ECF_HINT = ("the ECF codec comes with Prophesee's Metavision SDK (or the hdf5_ecf plugin): "
            "point HDF5_PLUGIN_PATH at it, or export the recording to RAW with Metavision")


def is_hdf5(path: str | os.PathLike) -> bool:
    """True if the file ``path`` starts with the HDF5 signature (read without h5py)."""
    with open(path, "rb") as fh:
        return fh.read(8).startswith(HDF5_MAGIC)


def register_filters() -> bool:
    """Make the Blosc/zstd/LZ4 filters of :mod:`hdf5plugin` available to h5py.

    hdf5plugin is a dependency, but an installation without it (or with a broken one)
    must still read uncompressed files, and name the missing filter for the others.

    Returns
    -------
    bool
        False when hdf5plugin cannot be imported.
    """
    from evmotion.utils import interrupts_deferred

    # Ctrl-C during the registration is caught by hdf5plugin, which logs a traceback and
    # goes on ("Cannot register filter fcidecomp"): the signals wait until it is done
    with interrupts_deferred():
        try:
            import hdf5plugin  # noqa: F401  (importing registers the Blosc/zstd filters)
        except ImportError:
            return False
    return True


def missing_filters(ds) -> list[str]:
    """Names of the HDF5 filters a dataset needs that this process cannot load.

    Parameters
    ----------
    ds : h5py.Dataset
    """
    import h5py

    plist = ds.id.get_create_plist()
    missing = []
    for i in range(plist.get_nfilters()):
        code, _, _, name = plist.get_filter(i)
        if not h5py.h5z.filter_avail(code):
            label = name.decode(errors="replace") if isinstance(name, bytes) else str(name)
            if not label and code == ECF_FILTER:
                label = "ECF"
            missing.append(f"'{label}' (id {code})" if label else f"(id {code})")
    return missing


def filter_error(path: Path, exc: Exception, ds, field: str) -> FormatError:
    """The error for a dataset ``field`` of ``path`` that could not be read (``exc``):
    names the missing compression filter when that is the cause, else calls the file
    corrupt or truncated."""
    missing = missing_filters(ds)
    if missing:
        ecf = any(f"(id {ECF_FILTER})" in m for m in missing)
        return FormatError(path, f"cannot decompress '{field}': HDF5 compression filter "
                           f"{', '.join(missing)} is not available",
                           ECF_HINT if ecf else FILTER_HINT)
    return FormatError(path, f"cannot read '{field}' (corrupt or truncated file?): {exc}")


H5_COMPRESSIONS = ("gzip", "lzf", "lz4", "zstd", None)


def h5_compression(name: str | None, *, bitshuffle: bool = False) -> dict:
    """h5py dataset keywords of an HDF5 filter: ``"gzip"`` (level 1, shuffled), ``"lzf"``,
    ``"lz4"`` / ``"zstd"`` (Blosc, byte shuffle, through :mod:`hdf5plugin`: several times
    faster than gzip on flow fields; gzip where hdf5plugin cannot be imported, so that the
    file is still written and read everywhere), or None (uncompressed). ``bitshuffle``:
    Blosc shuffles bits instead of bytes (for columns of small integers).

    Examples
    --------
    >>> h5_compression("gzip")
    {'compression': 'gzip', 'compression_opts': 1, 'shuffle': True}
    """
    if name not in H5_COMPRESSIONS:
        raise ParameterError(f"compression must be one of {H5_COMPRESSIONS}, got {name!r}")
    if name is None:
        return {}
    if name == "gzip" or (name in ("lz4", "zstd") and not register_filters()):
        return {"compression": "gzip", "compression_opts": 1, "shuffle": True}
    if name == "lzf":
        return {"compression": "lzf"}
    import hdf5plugin

    level = 5 if name == "lz4" else 1
    shuffle = hdf5plugin.Blosc.BITSHUFFLE if bitshuffle else hdf5plugin.Blosc.SHUFFLE
    return dict(hdf5plugin.Blosc(cname=name, clevel=level, shuffle=shuffle))
