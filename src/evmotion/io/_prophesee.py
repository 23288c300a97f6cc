"""What the Prophesee RAW formats (EVT 2.0, EVT 3.0) share: the ``%`` text header,
sniffing, the time offset evmotion stores when timestamps exceed the counter range."""

from __future__ import annotations

from pathlib import Path

from evmotion.errors import FormatError
from evmotion.io._binary import geometry_from_header, read_text_header

# Header key evmotion writes when the first timestamp does not fit the format's counter;
# readers add it to every timestamp. Other tools ignore unknown header keys.
OFFSET_KEY = "evmotion_time_offset_us"


def sniff_raw(head: bytes, version: str) -> bool:
    """True if ``head`` is a Prophesee RAW header announcing EVT ``version`` ("2.0"/"3.0")."""
    if not head.startswith(b"%"):
        return False
    text = head.split(b"\n% end", 1)[0]
    evt = f"% evt {version}".encode()
    fmt = f"% format EVT{version[0]}".encode()
    return any(line.strip() == evt or line.strip().startswith(fmt)
               for line in text.split(b"\n"))


def parse_raw_header(path: Path, sensor_size: tuple[int, int] | None,
                     version: str | None = None
                     ) -> tuple[list[str], int, tuple[int, int], int]:
    """(header lines, data offset, (height, width), time offset µs) of a RAW file.

    With ``version`` ("2.0"/"3.0"), a header declaring another encoding raises
    FormatError; EVT 3.0 must be declared, EVT 2.0 may be implicit (early Gen3 files).
    """
    lines, offset = read_text_header(path, b"%", end_line=b"% end")
    if not lines:
        raise FormatError(path, "no '%' header at byte 0", "not a Prophesee RAW file")
    if version is not None:
        _check_version(path, header_dict(lines), version)
    size = sensor_size if sensor_size is not None else geometry_from_header(
        lines, path, default=plugin_geometry(lines))
    t_offset = 0
    for line in lines:
        body = line.lstrip("%").strip()
        if body.startswith(OFFSET_KEY):
            try:
                t_offset = int(body.split()[1])
            except (IndexError, ValueError):
                raise FormatError(path, f"bad header line '{line}'") from None
    return lines, offset, size, t_offset


def _check_version(path: Path, head: dict[str, str], version: str) -> None:
    evt = head.get("evt")
    fmt = head.get("format", "").split(";")[0].strip().upper()
    want = f"EVT{version[0]}"
    if evt is not None and evt != version:
        raise FormatError(path, f"header field 'evt' is '{evt}', expected '{version}'",
                          "use the reader for that encoding or let evmotion detect it")
    if fmt and fmt != want:
        raise FormatError(path, f"header field 'format' is '{fmt}', expected '{want}'")
    if evt is None and not fmt and version != "2.0":
        raise FormatError(path, f"the '%' header does not declare 'evt {version}'",
                          "not an EVT 3.0 RAW file (a DAT file?)")


# Sensor of the camera plugins whose RAW headers predate the ``geometry`` key.
_PLUGIN_SIZES = (("gen31", (480, 640)), ("gen3", (480, 640)), ("gen41", (720, 1280)),
                 ("gen4", (720, 1280)), ("imx636", (720, 1280)))


def plugin_geometry(lines: list[str]) -> tuple[int, int] | None:
    """(height, width) implied by the ``plugin_name`` header key, if known."""
    plugin = header_dict(lines).get("plugin_name", "").lower()
    for key, size in _PLUGIN_SIZES:
        if key in plugin:
            return size
    return None


def header_dict(lines: list[str]) -> dict[str, str]:
    out = {}
    for line in lines:
        body = line.lstrip("%").strip()
        if body and body != "end":
            key, _, val = body.partition(" ")
            out[key] = val.strip()
    return out
