"""PNG files with pypng: the one place the package decodes and encodes them (8- and
16-bit, grey, grey+alpha, RGB, RGBA).

Writes are atomic; a file pypng cannot decode gets a one-line
:class:`~evmotion.errors.FormatError` naming it.

Examples
--------
>>> import numpy as np
>>> from evmotion.io.pngfile import read_png, write_png
>>> write_png("grey.png", np.zeros((4, 5), np.uint8))
>>> img, info = read_png("grey.png")
>>> img.shape, info["bitdepth"]
((4, 5, 1), 8)
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evmotion.errors import FormatError, ParameterError
from evmotion.utils import atomic_path

__all__ = ["png_header", "read_png", "write_png"]


def read_png(path: str | os.PathLike, *, direct: bool = True,
             what: str = "cannot read PNG") -> tuple[np.ndarray, dict]:
    """Pixels and header of a PNG file.

    Parameters
    ----------
    path : path-like
    direct : bool
        Expand palettes and transparency chunks to plain channels and apply ``sBIT``
        (pypng's ``asDirect``); False gives the samples as stored (``read``).
    what : str
        Start of the error message when the file cannot be decoded.

    Returns
    -------
    pixels : ndarray, (H, W, C)
        uint8 for bit depths up to 8 (values below ``2**bitdepth``), uint16 for 16;
        ``C = info["planes"]``.
    info : dict
        pypng's header: ``bitdepth``, ``planes``, ``greyscale``, ``alpha``...

    Raises
    ------
    FormatError
        ``"<what>: <reason>"`` naming the file.
    """
    import png

    try:
        with open(path, "rb") as fh:  # Reader(filename=...) leaves its file open
            reader = png.Reader(file=fh)
            w, h, rows, info = reader.asDirect() if direct else reader.read()
            dtype = np.uint16 if info["bitdepth"] > 8 else np.uint8
            img = np.vstack([np.asarray(r, dtype=dtype) for r in rows])
            # (fewer rows than the header declares: probe AO's traceback at the reshape)
            img = img.reshape(h, w, info["planes"])
    except Exception as exc:  # pypng raises many types (zlib, struct, Value...) for corrupt files
        raise FormatError(Path(path), f"{what}: {exc}") from None
    return img, info


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def check_png(path: str | os.PathLike) -> tuple[int, int]:
    """``(height, width)`` of a PNG file whose chunks are whole and check out (each CRC,
    IHDR first, IEND last, a size of at most
    :data:`~evmotion.catalog.MAX_SENSOR_SIDE` px a side), without decoding it; else a
    :class:`FormatError` naming the file and what is wrong. Decoders met with a damaged
    file print their own lines on stderr (libpng, OpenCV) or allocate what a corrupt
    header declares (100000 x 100000 px); this reads the file once, at C speed (zlib's
    CRC).

    Examples
    --------
    >>> write_png("f.png", np.zeros((3, 4), np.uint8))
    >>> check_png("f.png")
    (3, 4)
    >>> data = bytearray(Path("f.png").read_bytes()); data[20] ^= 1
    >>> _ = Path("f.png").write_bytes(bytes(data))
    >>> check_png("f.png")
    Traceback (most recent call last):
    evmotion.errors.FormatError: f.png: corrupt PNG: chunk IHDR at byte 8 fails its CRC
    """
    import struct
    import zlib

    from evmotion.catalog import MAX_SENSOR_SIDE

    path = Path(path)
    data = path.read_bytes()
    if not data.startswith(PNG_SIGNATURE):
        raise FormatError(path, "not a PNG file (no PNG signature)")
    pos, header, inflate, stored = len(PNG_SIGNATURE), None, zlib.decompressobj(), 0
    while True:
        if pos + 12 > len(data):
            raise FormatError(path, f"corrupt PNG: truncated at byte {pos} (no IEND chunk)")
        n, kind = struct.unpack(">I4s", data[pos:pos + 8])
        name = kind.decode("latin-1") if kind.isalpha() else repr(kind)
        end = pos + 12 + n
        if end > len(data):
            raise FormatError(path, f"corrupt PNG: chunk {name} at byte {pos} runs past "
                              f"the end of the file ({n} bytes declared)")
        if zlib.crc32(data[pos + 4:pos + 8 + n]) != struct.unpack(">I", data[end - 4:end])[0]:
            raise FormatError(path, f"corrupt PNG: chunk {name} at byte {pos} fails its CRC")
        if header is None:
            if kind != b"IHDR" or n != 13:
                raise FormatError(path, "corrupt PNG: the first chunk is not its header (IHDR)")
            header = struct.unpack(">IIBBBBB", data[pos + 8:pos + 21])
            w, h = header[:2]
            if not (1 <= w <= MAX_SENSOR_SIDE and 1 <= h <= MAX_SENSOR_SIDE):
                raise FormatError(path, f"PNG declares {w}x{h} px (W x H): not a frame of "
                                  f"any sensor (1-{MAX_SENSOR_SIDE} px a side)")
            expected = _raw_size(*header)
        elif kind == b"IDAT":
            # inflated in pieces, only counted: a few ms a frame, no image held
            try:
                stored += len(inflate.decompress(data[pos + 8:pos + 8 + n], 1 << 20))
                while inflate.unconsumed_tail:
                    stored += len(inflate.decompress(inflate.unconsumed_tail, 1 << 20))
            except zlib.error as exc:
                raise FormatError(path, f"corrupt PNG: its image data does not inflate ({exc})"
                                  ) from None
            if stored > expected:
                break
        elif kind == b"IEND":
            if stored != expected:
                break
            return int(header[1]), int(header[0])
        pos = end
    raise FormatError(path, f"corrupt PNG: {stored} bytes of image data where its header "
                      f"({header[0]}x{header[1]} px) needs {expected}")


# (channels per colour type of a PNG header)
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}
# Adam7's passes: first column, first row, column step, row step
_ADAM7 = ((0, 0, 8, 8), (4, 0, 8, 8), (0, 4, 4, 8), (2, 0, 4, 4), (0, 2, 2, 4), (1, 0, 2, 2),
          (0, 1, 1, 2))


def _raw_size(w: int, h: int, depth: int, colour: int, _c: int, _f: int, interlace: int
              ) -> int:
    """Bytes of a PNG's inflated image data (a filter byte per row of each pass)."""
    bits = depth * _PNG_CHANNELS.get(colour, 1)
    passes = _ADAM7 if interlace else ((0, 0, 1, 1),)
    total = 0
    for x0, y0, dx, dy in passes:
        cols, rows = -(-(w - x0) // dx) if w > x0 else 0, -(-(h - y0) // dy) if h > y0 else 0
        if cols and rows:
            total += rows * (1 + -(-cols * bits // 8))
    return total


def png_header(path: str | os.PathLike) -> tuple[tuple[int, int], int]:
    """``(height, width)`` and bit depth of a PNG file from its header (no decoding)."""
    import png

    try:
        with open(path, "rb") as fh:  # Reader(filename=...) leaves its file open
            r = png.Reader(file=fh)
            r.preamble()
            w, h, depth = r.width, r.height, r.bitdepth
    except Exception as exc:  # as in read_png
        raise FormatError(Path(path), f"cannot read PNG: {exc}") from None
    return (int(h), int(w)), int(depth)


def write_png(path: str | os.PathLike, img: np.ndarray, *, compression: int | None = None
              ) -> None:
    """Write an image as PNG, atomically.

    Parameters
    ----------
    path : path-like
    img : ndarray, (H, W) or (H, W, C), uint8 or uint16
        ``C`` = 1 grey, 2 grey + alpha, 3 RGB, 4 RGBA; the dtype sets the bit depth
        (8 or 16).
    compression : int, optional
        zlib level 0-9 (default: zlib's).
    """
    img = np.asarray(img)
    if img.dtype not in (np.uint8, np.uint16):
        raise ParameterError(f"PNG images must be uint8 or uint16, got {img.dtype}")
    if img.ndim not in (2, 3) or (img.ndim == 3 and not 1 <= img.shape[2] <= 4):
        raise ParameterError(f"PNG images must be (H, W) or (H, W, 1..4), got {img.shape}")
    import png

    h, w = img.shape[:2]
    planes = 1 if img.ndim == 2 else img.shape[2]
    writer = png.Writer(width=w, height=h, greyscale=planes <= 2, alpha=planes in (2, 4),
                        bitdepth=16 if img.dtype == np.uint16 else 8, compression=compression)
    # rows handed over packed (big-endian bytes): ~3x faster than pypng packing them
    rows = np.ascontiguousarray(img, dtype=">u2" if img.dtype == np.uint16 else np.uint8)
    rows = rows.reshape(h, w * planes).view(np.uint8)
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        writer.write_packed(fh, (row.tobytes() for row in rows))
