"""Camera calibration: every calibration file, and the calibration a recording brings,
read into a :class:`~evmotion.camera.Camera` (intrinsics and radial-tangential distortion).

One entry point per job:

=============================  ================================================================
:func:`read_camera`            any calibration file below -> Camera (the format is detected)
:func:`recording_camera`       the Camera a recording brings with it (ECD ``calib.txt``,
                               evmotion HDF5 ``calibration`` attribute, jAER header), or None
:func:`read_calibration`       the calibration stored with a recording, as a plain dict
                               (``evmotion.io.read_calibration``)
:func:`camera_to_dict`         Camera -> dict (the JSON schema below); :func:`camera_from_dict`
                               the inverse
=============================  ================================================================

Formats (detected by :func:`read_camera`; each has its own reader, ``read_<format>``):

==========================  ==================================================================
ECD ``calib.txt``           one line ``fx fy cx cy k1 k2 p1 p2 k3`` (or a folder holding one)
Kalibr camchain YAML        ``cam0: {intrinsics: [fu, fv, pu, pv], distortion_model: radtan,
                            distortion_coeffs: [k1, k2, r1, r2], resolution: [W, H]}``
                            (pinhole-radtan; MVSEC's ``camchain-*.yaml`` are
                            equidistant, refused)
ROS ``camera_info`` YAML    ``image_width``, ``image_height``, ``camera_matrix.data`` (3x3
                            row-major), ``distortion_model: plumb_bob``,
                            ``distortion_coefficients.data`` (k1 k2 p1 p2 k3)
DV / AEDAT4 XML             OpenCV FileStorage written by DV's calibration module: a camera
                            node (or the root) with ``camera_matrix`` and
                            ``distortion_coefficients`` (``opencv-matrix``), ``image_width``,
                            ``image_height``; ``use_fisheye_model`` must be 0
DSEC ``cam_to_cam.yaml``    ``intrinsics.<camera>.camera_matrix: [fx, fy, cx, cy]``,
                            ``distortion_coeffs``, ``resolution: [W, H]`` (default camera
                            ``cam0``, the raw left event camera whose grid DSEC's events are
                            on, else ``camRect0``, rectified: no distortion)
JSON (evmotion)             see below; also the ``calibration`` attribute of evmotion HDF5
==========================  ==================================================================

The JSON schema (:func:`write_json` writes it, :func:`camera_from_dict` reads it)::

    {"fx": 199.09, "fy": 198.83, "cx": 132.19, "cy": 110.71,   # px (or "K": 3x3 rows)
     "dist": [-0.368, 0.151, -0.0003, -0.0008, 0.0],          # k1 k2 p1 p2 k3, optional
     "model": "radtan",                                        # optional, radtan only
     "sensor_size": [180, 240]}                                # [height, width], optional

Only the pinhole model with radial-tangential ("plumb bob") distortion is supported; a
file declaring another model (equidistant / fisheye, FOV) is refused with an error naming
it. Every error is one line naming the file, the field and the value.

A recording may bring its own intrinsics (:func:`recording_camera`): an ECD folder's
``calib.txt``, an evmotion HDF5 ``calibration`` attribute, or the lens focal length a jAER
AEDAT 2.0 header records (``lensFocalLengthMm`` of its filters: a nominal focal length, no
principal point or distortion, used only when every filter agrees).

Examples
--------
>>> import tempfile, pathlib
>>> p = pathlib.Path(tempfile.mkdtemp()) / "calib.txt"
>>> _ = p.write_text("199.09 198.83 132.19 110.71 -0.368 0.151 -0.0003 -0.0008 0")
>>> cam = read_camera(p)
>>> cam.fx, cam.dist[0], cam.sensor_size
(199.09, -0.368, (180, 240))
>>> read_calibration(p)["dist"][:2]
[-0.368, 0.151]
"""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np

from evmotion.camera import Camera, warn_strong_distortion
from evmotion.errors import CalibrationError, FormatError
from evmotion.io.guard import guard_call
from evmotion.io.h5attrs import read_attrs
from evmotion.io.h5filters import HDF5_MAGIC, is_hdf5

__all__ = [
    "read_camera",
    "read_calibration",
    "read_ecd",
    "read_kalibr_yaml",
    "read_ros_yaml",
    "read_dv_xml",
    "read_dsec_yaml",
    "read_json",
    "write_json",
    "camera_from_dict",
    "camera_to_dict",
    "jaer_header_camera",
    "recording_camera",
    "recording_intrinsics",
    "PIXEL_PITCH_UM",
]

_RADTAN = ("radtan", "plumb_bob", "plumb_tan", "radialtangential", "radial-tangential",
           "rational_polynomial", "pinhole-radtan")
# Pixel pitch of the DAVIS chips (iniVation data sheets), µm: turns a focal length in mm
# into pixels.
PIXEL_PITCH_UM = {(180, 240): 18.5, (260, 346): 18.5, (480, 640): 9.0}


def read_camera(path: str | os.PathLike, *, camera: str | None = None,
                sensor_size: tuple[int, int] | None = None) -> Camera:
    """Read intrinsics and distortion from a calibration file of any supported format.

    Parameters
    ----------
    path : path-like
        ECD ``calib.txt`` (or its folder), Kalibr camchain YAML (radtan), ROS
        ``camera_info`` YAML, DSEC ``cam_to_cam.yaml``, DV calibration XML, evmotion JSON.
    camera : str, optional
        Which camera of a multi-camera file (Kalibr ``cam0``, DSEC ``cam0`` or
        ``camRect0``, a DV camera node name); default the format's first / reference
        camera (DSEC: ``cam0`` when present, the grid of the raw events).
    sensor_size : (int, int), optional
        ``(height, width)`` of the sensor the calibration is for, when the file does not
        say (ECD text, JSON without ``sensor_size``); checked against the file when it does.

    Returns
    -------
    Camera
        With ``source`` the file.

    Examples
    --------
    >>> _ = Path("cam_to_cam.yaml").write_text(  # DSEC's layout, one camera
    ...     "intrinsics: {cam0: {camera_matrix: [553.5, 553.3, 325.2, 241.3],\\n"
    ...     "  distortion_coeffs: [-0.09, 0.19, 0.0, 0.0], resolution: [640, 480]}}\\n")
    >>> cam = read_camera("cam_to_cam.yaml", camera="cam0")
    >>> cam.K.tolist(), cam.sensor_size
    ([[553.5, 0.0, 325.2], [0.0, 553.3, 241.3], [0.0, 0.0, 1.0]], (480, 640))
    """
    path = Path(path)
    if path.is_dir() or path.suffix.lower() == ".txt":
        return read_ecd(path, sensor_size=sensor_size)
    if not path.is_file():
        raise CalibrationError(f"{path}: calibration file not found")
    suffix = path.suffix.lower()
    if suffix == ".json":
        return read_json(path, sensor_size=sensor_size)
    if suffix == ".xml":
        return read_dv_xml(path, camera=camera, sensor_size=sensor_size)
    if suffix in (".yaml", ".yml"):
        data = _load_yaml(path)
        intr = data.get("intrinsics")
        if isinstance(intr, dict):
            # the raw left event camera, the grid of DSEC's events.h5, when the file has it
            default = "cam0" if "cam0" in intr else "camRect0"
            return read_dsec_yaml(path, camera=camera or default, sensor_size=sensor_size)
        if "camera_matrix" in data:
            return read_ros_yaml(path, sensor_size=sensor_size)
        if "K" in data:
            return read_kd_yaml(path, sensor_size=sensor_size)
        return read_kalibr_yaml(path, camera=camera or "cam0", sensor_size=sensor_size)
    raise CalibrationError(f"{path}: unknown calibration format '{path.suffix}' (expected "
                           "calib.txt, .yaml, .xml or .json)")


def read_calibration(path: str | os.PathLike) -> dict:
    """Camera calibration stored with a recording, as a plain dict.

    Accepts an ECD ``calib.txt`` or a folder holding one (as the ECD reader puts it in
    ``meta["calibration"]``), an evmotion HDF5 file with a ``calibration`` attribute (the
    stored JSON object, verbatim), or any calibration file :func:`read_camera` reads
    (Kalibr / ROS / DSEC YAML, DV XML, JSON; through :func:`camera_to_dict`). For a
    :class:`~evmotion.camera.Camera`, use :func:`read_camera` or :func:`recording_camera`.

    Returns
    -------
    dict
        ``K`` (3x3 nested list, px), ``dist`` (``[k1, k2, p1, p2, k3]`` radial-tangential),
        ``fx, fy, cx, cy``, ``model``, ``source`` and ``sensor_size`` when known.

    Examples
    --------
    >>> Path("boxes_rotation").mkdir(exist_ok=True)
    >>> _ = Path("boxes_rotation/calib.txt").write_text(
    ...     "199.092366542 198.82882047 132.192071378 110.712660011 "
    ...     "-0.368436311798 0.150947243557 -0.000296130534385 -0.000759431726241 0.0\\n")
    >>> read_calibration("boxes_rotation/")["dist"][:2]
    [-0.368436311798, 0.150947243557]
    """
    from evmotion.io import ecd

    path = Path(path)
    if not path.exists():
        raise FormatError(path, "no such file or folder")
    if path.is_dir() or path.suffix.lower() == ".txt":
        return ecd.read_calibration(path)
    if is_hdf5(path):
        return guard_call(_h5_calibration, "HDF5", "read the calibration")(path)
    if path.suffix.lower() in (".yaml", ".yml", ".xml", ".json"):
        return camera_to_dict(read_camera(path))
    raise FormatError(path, "no calibration found",
                      "give an ECD calib.txt, an evmotion .h5 with calibration, or a "
                      "calibration .yaml/.xml/.json")


# ------------------------------------------------------------------------------ formats
def read_ecd(path: str | os.PathLike, *, sensor_size: tuple[int, int] | None = None
             ) -> Camera:
    """ECD ``calib.txt``: ``fx fy cx cy k1 k2 p1 p2 k3`` (or 4 or 8 numbers).

    The sensor is the folder's APS frame size when ``images.txt`` lists one, else
    ``sensor_size``, else the ECD's DAVIS240C (180 x 240).
    """
    from evmotion.io import ecd

    file = ecd.calib_file(path)
    if not file.is_file():
        raise CalibrationError(f"{file}: calibration file not found (ECD folders hold "
                               "calib.txt)")
    cal = ecd.read_calibration(file)  # FormatError naming the file and value when malformed
    size = cal.get("sensor_size") or sensor_size or ecd.ECD_SENSOR_SIZE
    return _camera(file, cal["fx"], cal["fy"], cal["cx"], cal["cy"], cal["dist"], size)


def read_kalibr_yaml(path: str | os.PathLike, *, camera: str = "cam0",
                     sensor_size: tuple[int, int] | None = None) -> Camera:
    """Kalibr camchain YAML (pinhole-radtan; MVSEC's are equidistant): ``<camera>.intrinsics``
    ``[fu, fv, pu, pv]``, ``distortion_model`` (radtan), ``distortion_coeffs``
    ``[k1, k2, r1, r2]``, ``resolution`` ``[W, H]``; ``camera_model`` must be pinhole."""
    data = _load_yaml(path)
    if camera not in data:
        raise FormatError(path, f"no camera '{camera}'; has {sorted(map(str, data))}")
    c = _mapping(path, data[camera], camera)
    _refuse_other_models(path, c, camera)
    fx, fy, cx, cy = _numbers(path, f"{camera}.intrinsics", _field(path, c, "intrinsics",
                                                                  camera), 4)
    size = _resolution(path, f"{camera}.resolution", c.get("resolution"))
    dist = _numbers(path, f"{camera}.distortion_coeffs", c.get("distortion_coeffs", []), None)
    return _camera(path, fx, fy, cx, cy, dist, _check_size(path, size, sensor_size))


def read_ros_yaml(path: str | os.PathLike, *, sensor_size: tuple[int, int] | None = None
                  ) -> Camera:
    """ROS ``camera_info`` YAML (``camera_calibration_parsers``): ``image_width``,
    ``image_height``, ``camera_matrix.data`` (3x3 row-major), ``distortion_model``
    (plumb_bob), ``distortion_coefficients.data``."""
    data = _load_yaml(path)
    _refuse_other_models(path, data)
    k_node = _mapping(path, data.get("camera_matrix"), "camera_matrix")
    k = _numbers(path, "camera_matrix.data", _field(path, k_node, "data", "camera_matrix"), 9)
    _k_row3(path, "camera_matrix.data", k)
    dist_node = _mapping(path, data.get("distortion_coefficients") or {},
                         "distortion_coefficients")
    dist = _numbers(path, "distortion_coefficients.data", dist_node.get("data", []), None)
    if dist:
        _count(path, "distortion_coefficients", dist_node, dist)
    size = None
    if "image_width" in data or "image_height" in data:
        size = _resolution(path, "image_width/image_height",
                           [data.get("image_width"), data.get("image_height")])
    return _camera(path, k[0], k[4], k[2], k[5], dist, _check_size(path, size, sensor_size),
                   skew=k[1])


def read_kd_yaml(path: str | os.PathLike, *, sensor_size: tuple[int, int] | None = None
                 ) -> Camera:
    """A YAML with ``K`` (3x3, a list of 9 or an OpenCV ``opencv-matrix``) and ``D`` (the
    coefficients), as a ROS ``CameraInfo`` message dump (with ``width``, ``height``,
    ``distortion_model``) or OpenCV FileStorage with those names write them."""
    data = _load_yaml(path)
    _refuse_other_models(path, data)

    def values(key: str, n: int | None) -> list[float]:
        node = data.get(key)
        if isinstance(node, dict):
            node = _field(path, node, "data", key)
        return _numbers(path, key, node if node is not None else [], n)

    k = values("K", 9)
    _k_row3(path, "K", k)
    dist = values("D", None)
    size = None
    for w_key, h_key in (("width", "height"), ("image_width", "image_height")):
        if w_key in data or h_key in data:
            size = _resolution(path, f"{w_key}/{h_key}", [data.get(w_key), data.get(h_key)])
            break
    return _camera(path, k[0], k[4], k[2], k[5], dist, _check_size(path, size, sensor_size),
                   skew=k[1])


def read_dv_xml(path: str | os.PathLike, *, camera: str | None = None,
                sensor_size: tuple[int, int] | None = None) -> Camera:
    """DV (iniVation) calibration XML, an OpenCV FileStorage: the camera node (``camera``,
    default the first node holding ``camera_matrix``, or the root in older files) with
    ``camera_matrix`` 3x3 and ``distortion_coefficients`` as ``opencv-matrix``,
    ``image_width``, ``image_height``; ``use_fisheye_model`` must be 0."""
    import xml.etree.ElementTree as ET

    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise FormatError(path, f"not valid XML: {exc}") from None
    if camera is not None:
        node = root.find(camera)
        if node is None:
            raise FormatError(path, f"no camera node '{camera}'; has "
                              f"{[c.tag for c in root if c.find('camera_matrix') is not None]}")
    elif root.find("camera_matrix") is not None:
        node = root
    else:
        node = next((c for c in root if c.find("camera_matrix") is not None), None)
        if node is None:
            raise FormatError(path, "no element 'camera_matrix' in the XML")
    for el in (root, node):
        _refuse_other_models(path, {c.tag: (c.text or "").strip() for c in el
                                    if not len(c)})
    where = node.tag if node is not root else ""
    k = _cv_matrix(path, node, "camera_matrix", where, 9)
    _k_row3(path, "camera_matrix", k)
    dist = _cv_matrix(path, node, "distortion_coefficients", where, None) \
        if node.find("distortion_coefficients") is not None else []
    if dist:
        _count(path, "distortion_coefficients", node.find("distortion_coefficients"), dist)
    size = None
    if node.find("image_width") is not None or node.find("image_height") is not None:
        size = _resolution(path, f"{where + '.' if where else ''}image_width/image_height",
                           [node.findtext("image_width"), node.findtext("image_height")])
    return _camera(path, k[0], k[4], k[2], k[5], dist, _check_size(path, size, sensor_size),
                   skew=k[1])


def read_dsec_yaml(path: str | os.PathLike, *, camera: str = "camRect0",
                   sensor_size: tuple[int, int] | None = None) -> Camera:
    """DSEC ``cam_to_cam.yaml``: ``intrinsics.<camera>.camera_matrix`` ``[fx, fy, cx, cy]``,
    ``distortion_coeffs`` and ``resolution`` ``[W, H]``. ``camRect0`` (default) is the
    rectified left event camera (no distortion); ``cam0`` the raw one."""
    data = _load_yaml(path)
    intr = _mapping(path, data.get("intrinsics"), "intrinsics")
    if camera not in intr:
        raise FormatError(path, f"no camera 'intrinsics.{camera}'; has "
                          f"{sorted(map(str, intr))}")
    where = f"intrinsics.{camera}"
    c = _mapping(path, intr[camera], where)
    _refuse_other_models(path, c, where)
    fx, fy, cx, cy = _numbers(path, f"{where}.camera_matrix",
                              _field(path, c, "camera_matrix", where), 4)
    size = _resolution(path, f"{where}.resolution", _field(path, c, "resolution", where))
    dist = _numbers(path, f"{where}.distortion_coeffs", c.get("distortion_coeffs", []), None)
    return _camera(path, fx, fy, cx, cy, dist, _check_size(path, size, sensor_size))


def read_json(path: str | os.PathLike, *, sensor_size: tuple[int, int] | None = None
              ) -> Camera:
    """evmotion JSON calibration (schema in the module docstring)."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FormatError(path, f"not valid JSON: {exc}") from None
    return camera_from_dict(data, source=str(path), sensor_size=sensor_size)


def write_json(path: str | os.PathLike, cam: Camera) -> None:
    """Write ``cam`` as evmotion JSON (read back by :func:`read_json`), atomically."""
    from evmotion.utils import atomic_write_text

    atomic_write_text(Path(path), json.dumps(camera_to_dict(cam), indent=2) + "\n")


def camera_to_dict(cam: Camera) -> dict:
    """The JSON schema's dict (plus ``K`` and ``source``): what evmotion HDF5 stores in its
    ``calibration`` attribute and :func:`read_calibration` returns for a calibration
    file."""
    out = {"fx": cam.fx, "fy": cam.fy, "cx": cam.cx, "cy": cam.cy,
           "K": cam.K.tolist(), "dist": list(cam.dist), "model": "radtan"}
    if cam.sensor_size is not None:
        out["sensor_size"] = list(cam.sensor_size)
    if cam.source:
        out["source"] = cam.source
    return out


def camera_from_dict(data, *, source: str = "", sensor_size: tuple[int, int] | None = None
                     ) -> Camera:
    """A Camera from the JSON schema's dict (``fx, fy, cx, cy`` or ``K``; ``dist``,
    ``model``, ``sensor_size`` or ``width``/``height`` optional)."""
    where = source or "calibration"
    if not isinstance(data, dict):
        raise FormatError(where, f"expected a JSON object, got {type(data).__name__}")
    _check_model(where, "model", data.get("model", "radtan"), _RADTAN)
    _refuse_other_models(where, data)
    if all(k in data for k in ("fx", "fy", "cx", "cy")):
        fx, fy, cx, cy = (_number(where, k, data[k]) for k in ("fx", "fy", "cx", "cy"))
    elif "K" in data or "camera_matrix" in data:
        name = "K" if "K" in data else "camera_matrix"
        k = _numbers(where, name, np.asarray(data[name], dtype=object).ravel().tolist(), 9)
        _k_row3(where, name, k)
        fx, fy, cx, cy = k[0], k[4], k[2], k[5]
    else:
        raise FormatError(where, "fields 'fx', 'fy', 'cx', 'cy' (or 'K') are missing; has "
                          f"{sorted(data)}")
    size = None
    if data.get("sensor_size") is not None:
        s = _numbers(where, "sensor_size", data["sensor_size"], 2)
        size = _resolution(where, "sensor_size", [s[1], s[0]])
    elif "width" in data or "height" in data:
        size = _resolution(where, "width/height", [data.get("width"), data.get("height")])
    # (other tools' names for the coefficients: probe AR's JSON had 'dist_coeffs')
    name = next((n for n in ("dist", "D", "dist_coeffs", "distortion_coeffs",
                             "distortion_coefficients") if n in data), "dist")
    dist = _numbers(where, name, np.asarray(data.get(name) or [], dtype=object).ravel()
                    .tolist(), None)
    return _camera(where, fx, fy, cx, cy, dist, _check_size(where, size, sensor_size))


# ------------------------------------------------------------------- recordings' own
def jaer_header_camera(path: str | os.PathLike, sensor_size: tuple[int, int]
                       ) -> tuple[Camera | None, list[float]]:
    """The nominal camera a jAER AEDAT 2.0 header implies, from its filters'
    ``lensFocalLengthMm`` preferences.

    Returns ``(camera, focal_lengths_mm)``: the camera (focal length / pixel pitch, principal
    point at the sensor centre, no distortion, ``source`` ending in ``(nominal)``) when the
    header holds lens focal lengths that all agree and the chip's pixel pitch is known
    (:data:`PIXEL_PITCH_UM`); None otherwise. The distinct focal lengths found (mm) come
    with it either way, so that callers can say why none was used.
    """
    from evmotion.io import binary

    path = Path(path)
    lines, _ = binary.read_text_header(path, b"#", max_bytes=1 << 24)
    found = re.findall(r'key="[^"]*lensFocalLengthMm" value="([^"]+)"', "\n".join(lines))
    mm = sorted({float(v) for v in found if _finite_positive(v)})
    pitch = PIXEL_PITCH_UM.get(tuple(sensor_size))
    if len(mm) != 1 or pitch is None:
        return None, mm
    f = mm[0] * 1000.0 / pitch
    h, w = sensor_size
    cam = Camera(f, f, (w - 1) / 2, (h - 1) / 2, sensor_size=(h, w),
                 source=f"{path} header lensFocalLengthMm={mm[0]:g} mm, pixel pitch "
                        f"{pitch:g} um (nominal)")
    return cam, mm


def recording_camera(path: str | os.PathLike, events_meta: dict | None = None,
                     sensor_size: tuple[int, int] | None = None) -> Camera | None:
    """The intrinsics a recording brings with it, or None.

    An ECD folder's (or events file's sibling) ``calib.txt``, the ``calibration`` the
    reader put in ``events_meta`` (ECD, evmotion HDF5), a ROS bag's ``CameraInfo``
    (:func:`evmotion.io.rosbag.read_camera_info`), or a jAER AEDAT 2.0 header's lens
    focal length (nominal; see :func:`jaer_header_camera`).
    """
    path = Path(path)
    cal = (events_meta or {}).get("calibration")
    if isinstance(cal, dict):
        # the file first: the dict's own source (a simulator, a tool) says what made it
        made = f" (calibration from {cal['source']})" if cal.get("source") else ""
        return camera_from_dict(cal, source=f"{path}{made}", sensor_size=sensor_size)
    folder = path if path.is_dir() else path.parent
    if (folder / "calib.txt").is_file() and (path.is_dir() or path.suffix == ".txt"):
        return read_ecd(folder, sensor_size=sensor_size)
    if path.is_file():
        with open(path, "rb") as fh:
            head = fh.read(12)  # one read for both signatures
        if head.startswith(HDF5_MAGIC):
            try:
                cal = read_calibration(path)
            except FormatError:
                return None  # no calibration in it; a broken one is said below
            what = "its camera K" if cal.get("simulated") else "calibration attribute"
            return camera_from_dict(cal, source=f"{path} ({what})", sensor_size=sensor_size)
        if head == b"#!AER-DAT2.0" and sensor_size is not None:
            return jaer_header_camera(path, sensor_size)[0]
        if head.startswith(b"#ROSBAG V2"):
            from evmotion.io import rosbag

            cal = rosbag.read_camera_info(path)
            if cal is not None:
                return camera_from_dict(cal, source=cal["source"], sensor_size=sensor_size)
    return None


def recording_intrinsics(path: str | os.PathLike, sensor_size: tuple[int, int]) -> dict:
    """What :func:`recording_camera` finds, as a JSON-ready dict: ``source``, ``K``
    ``[fx, fy, cx, cy]`` (px), ``dist`` ``[k1, k2, p1, p2, k3]``, ``resolution``
    ``[H, W]`` (None when the calibration does not say), ``nominal`` (a header's lens focal
    length, not a calibration); or ``{"source": None, "reason": ...}`` when there is none.
    """
    path = Path(path)
    try:
        # on the recording's sensor: an ECD calib.txt states none, and the ECD's 240 x 180
        # was reported for a 346 x 260 recording (probe AW)
        cam = recording_camera(path, None, sensor_size)
    except (FormatError, CalibrationError) as exc:
        return {"source": None, "reason": str(exc)}
    if cam is None and path.is_file():
        with open(path, "rb") as fh:
            if fh.read(12) == b"#!AER-DAT2.0":
                cam, mm = jaer_header_camera(path, sensor_size)
                if cam is None:
                    return {"source": None, "reason": (
                        "the jAER header's filters give different lens focal lengths "
                        f"{', '.join(f'{v:g}' for v in mm)} mm" if len(mm) > 1 else
                        "the jAER header gives no lens focal length" if not mm else
                        f"no pixel pitch known for a {sensor_size[1]} x {sensor_size[0]} "
                        "px chip")}
    if cam is None:
        return {"source": None, "reason": "the recording brings no calibration"}
    return {"source": cam.source, "K": [cam.fx, cam.fy, cam.cx, cam.cy],
            "dist": list(cam.dist),
            "resolution": None if cam.sensor_size is None else list(cam.sensor_size),
            "nominal": cam.source.endswith("(nominal)")}


# ------------------------------------------------------------------------------ helpers
# beyond these a value is a typo, not a lens: radtan coefficients of real lenses stay
# within a few units (k3 up to some tens), focal lengths within 10^5 px
MAX_DISTORTION = 1e4
MAX_FOCAL_PX = 1e6
MIN_FOCAL_PX = 1.0


def _k_row3(path, field: str, k: list[float]) -> None:
    """A 3x3 camera matrix's last row must be 0 0 1 (a projective K is not intrinsics)."""
    if abs(k[6]) > 1e-9 or abs(k[7]) > 1e-9 or abs(k[8] - 1.0) > 1e-9:
        raise CalibrationError(f"{path}: {field} has last row {k[6:9]}, expected [0, 0, 1]")


def _count(path, field: str, node, values: list) -> None:
    """An OpenCV / ROS matrix whose ``rows`` x ``cols`` disagree with its data."""
    get = node.get if isinstance(node, dict) else (lambda k: node.findtext(k))
    try:
        rows, cols = int(get("rows")), int(get("cols"))
    except (TypeError, ValueError):
        return  # not stated
    if rows * cols != len(values):
        raise CalibrationError(f"{path}: {field} states {rows} x {cols} values but holds "
                               f"{len(values)}")


def _camera(path, fx, fy, cx, cy, dist, size, *, skew: float = 0.0) -> Camera:
    if skew != 0.0:
        raise CalibrationError(f"{path}: camera_matrix skew = {skew!r}: a skewed K is not "
                               "supported")
    if len(dist) > 5:
        if any(d != 0.0 for d in dist[5:]):
            raise CalibrationError(f"{path}: distortion coefficients {list(dist)}: only "
                                   "k1 k2 p1 p2 k3 are supported")
        dist = dist[:5]
    if len(dist) in (1, 3):
        raise CalibrationError(f"{path}: {len(dist)} distortion coefficients {list(dist)}: "
                               "radtan takes k1 k2 (2), k1 k2 p1 p2 (4) or k1 k2 p1 p2 k3 (5)")
    if any(abs(d) > MAX_DISTORTION for d in dist):
        raise CalibrationError(f"{path}: distortion coefficients {list(dist)}: beyond "
                               f"+-{MAX_DISTORTION:g}, not a lens")
    if not (MIN_FOCAL_PX <= fx <= MAX_FOCAL_PX and MIN_FOCAL_PX <= fy <= MAX_FOCAL_PX):
        raise CalibrationError(f"{path}: focal lengths must be in [{MIN_FOCAL_PX:g}, "
                               f"{MAX_FOCAL_PX:g}] px, got fx={fx!r}, fy={fy!r}")
    if size is not None:
        h, w = size
        if principal_point_far_off(cx, cy, size):
            raise CalibrationError(f"{path}: principal point (cx, cy) = ({cx:g}, {cy:g}) lies "
                                   f"far outside the {w} x {h} px sensor: a calibration of "
                                   "another camera or resolution?")
    d = tuple(dist) + (0.0,) * (5 - len(dist))
    cam = Camera(float(fx), float(fy), float(cx), float(cy), d,
                 None if size is None else tuple(size), source=str(path))
    warn_strong_distortion(cam, str(path))
    return cam


#: How far off the sensor (a share of its side) a principal point may lie before its
#: calibration is refused as another camera's: a crop can put it just outside, but a
#: DSEC 640x480 K on a 240x180 sensor (cx 346.7) gave a valid estimate 60 % off (probe AR).
PRINCIPAL_POINT_MARGIN = 0.25


def principal_point_far_off(cx: float, cy: float, size: tuple[int, int]) -> bool:
    """Whether ``(cx, cy)`` lies beyond :data:`PRINCIPAL_POINT_MARGIN` of the sensor's
    sides outside it (``size`` = (height, width)).

    Examples
    --------
    >>> principal_point_far_off(132.2, 110.7, (180, 240)), principal_point_far_off(
    ...     346.7, 260.0, (180, 240))
    (False, True)
    """
    h, w = size
    m = PRINCIPAL_POINT_MARGIN
    return not (-m * w <= cx <= (1 + m) * w and -m * h <= cy <= (1 + m) * h)


def _h5_calibration(path: Path) -> dict:
    import h5py

    with h5py.File(path, "r") as f:
        attrs = read_attrs(path, f, ("calibration", "height", "width"))
        if "calibration" in attrs:
            try:
                cal = json.loads(attrs["calibration"])
            except (TypeError, ValueError):
                raise FormatError(path, "attribute 'calibration' is not valid JSON") from None
            if not isinstance(cal, dict):
                raise FormatError(path, "attribute 'calibration' is not a JSON object")
            cal.setdefault("sensor_size", [int(attrs["height"]), int(attrs["width"])]
                           if "height" in attrs and "width" in attrs else None)
            return cal
        if f.attrs.get("format") == "evmotion-sim-gt" and "K" in f:
            # the simulator's ground truth: the pinhole camera its events were made with
            return {"K": np.asarray(f["K"]).tolist(),
                    "sensor_size": np.asarray(f.attrs["sensor_size"]).tolist(),
                    "simulated": True}
    raise FormatError(path, "no 'calibration' attribute in this HDF5 file")


def _load_yaml(path) -> dict:
    import yaml

    path = Path(path)
    if not path.is_file():
        raise CalibrationError(f"{path}: calibration file not found")
    text = path.read_text(errors="replace")
    if text.startswith("%YAML:1.0"):  # OpenCV FileStorage YAML: drop its directive line
        text = "\n".join(line for line in text.splitlines()[1:]
                         if not line.startswith("---"))
        text = text.replace("!!opencv-matrix", "")
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise FormatError(path, f"not valid YAML: {' '.join(str(exc).split())}") from None
    if not isinstance(data, dict):
        raise FormatError(path, "expected a YAML mapping at the top level")
    return data


def _mapping(path, node, where: str) -> dict:
    if not isinstance(node, dict):
        raise FormatError(path, f"field '{where}' is missing or not a mapping: {node!r}")
    return node


def _field(path, node: dict, key: str, where: str):
    if key not in node:
        raise FormatError(path, f"field '{where}.{key}' is missing")
    return node[key]


def _number(path, field: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise FormatError(path, f"field '{field}' must be a number, got {value!r}") from None
    if not math.isfinite(v):
        raise FormatError(path, f"field '{field}' must be finite, got {value!r}")
    return v


def _numbers(path, field: str, values, n: int | None) -> list[float]:
    if not isinstance(values, (list, tuple)):
        raise FormatError(path, f"field '{field}' must be a list of numbers, got {values!r}")
    if n is not None and len(values) != n:
        raise FormatError(path, f"field '{field}' must hold {n} numbers, got {len(values)}: "
                          f"{list(values)!r}")
    return [_number(path, field, v) for v in values]


def _resolution(path, field: str, wh) -> tuple[int, int]:
    """``[W, H]`` -> ``(H, W)``, positive integers."""
    if not isinstance(wh, (list, tuple)) or len(wh) != 2:
        raise FormatError(path, f"field '{field}' must be [width, height], got {wh!r}")
    out = []
    for v in wh:
        try:
            f = float(v)
        except (TypeError, ValueError):
            f = math.nan
        if not (math.isfinite(f) and f == int(f) and f > 0):
            raise FormatError(path, f"field '{field}' must be positive integers, got {wh!r}")
        out.append(int(f))
    return out[1], out[0]


def _check_size(path, size, sensor_size):
    if size is None or sensor_size is None:
        return size if size is not None else sensor_size
    if tuple(size) != tuple(sensor_size):
        raise CalibrationError(f"{path}: calibration is for a {size[1]} x {size[0]} px sensor "
                               f"(W x H), not {sensor_size[1]} x {sensor_size[0]} px")
    return size


# keys other tools use to say a camera is no pinhole-radtan one: a flag, or a model name
_FISHEYE_FLAGS = ("fisheye_model", "use_fisheye_model", "fisheye", "is_fisheye")
_MODEL_KEYS = {"camera_model": ("pinhole",), "projection_model": ("pinhole",),
               "distortion_model": _RADTAN + ("none",), "lens_model": _RADTAN + ("pinhole",),
               "distortion_type": _RADTAN}


def _refuse_other_models(path, node: dict, where: str = "") -> None:
    """Refuse a mapping whose keys declare a fisheye / equidistant (or any non-radtan)
    camera, whatever tool wrote it: OpenCV's ``fisheye_model: 1`` was read as radtan, the
    estimate 26 % off and valid (probe AR)."""
    prefix = f"{where}." if where else ""
    for key, value in node.items():
        low = str(key).strip().lower()
        if low in _FISHEYE_FLAGS and str(value).strip().lower() not in ("0", "false", "",
                                                                       "none", "no"):
            raise CalibrationError(f"{path}: {prefix}{key} = {value!r}: the fisheye model "
                                   "is not supported (pinhole with radial-tangential "
                                   "distortion only)")
        if low in _MODEL_KEYS and value is not None:
            _check_model(path, f"{prefix}{key}", value, _MODEL_KEYS[low])


def _check_model(path, field: str, model, allowed) -> None:
    if str(model).strip().lower().replace(" ", "") not in allowed:
        raise CalibrationError(f"{path}: {field} = {model!r} is not supported (pinhole with "
                               "radial-tangential distortion only)")


def _cv_matrix(path, node, name: str, where: str, n: int | None) -> list[float]:
    field = f"{where + '.' if where else ''}{name}"
    el = node.find(name)
    if el is None:
        raise FormatError(path, f"field '{field}' is missing")
    text = el.findtext("data")
    if text is None:
        raise FormatError(path, f"field '{field}.data' is missing")
    return _numbers(path, f"{field}.data", text.split(), n)


def _finite_positive(text: str) -> bool:
    try:
        v = float(text)
    except ValueError:
        return False
    return math.isfinite(v) and v > 0
