"""Calibration readers (evmotion.io.calibration) against small handwritten files of known content,
one per format, and their one-line errors naming the file, the field and the value."""

from __future__ import annotations

import json

import numpy as np
import pytest

from evmotion.camera import Camera
from evmotion.errors import CalibrationError, FormatError
from evmotion.io import calibration as calib
from evmotion.io import read_calibration as stored_calibration

# one camera, written in every format below
FX, FY, CX, CY = 226.38, 226.15, 173.64, 133.73
DIST = (-0.048, 0.0123, -0.00094, -0.00051, 0.0007)
SIZE = (260, 346)  # (height, width)


def _check(cam: Camera, path, *, dist=DIST, size=SIZE):
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (FX, FY, CX, CY)
    np.testing.assert_array_equal(cam.dist, dist)
    assert cam.sensor_size == size
    assert cam.source == str(path)


def _one_line(exc) -> str:
    text = str(exc.value)
    assert "\n" not in text
    return text


def test_ecd_calib_txt(tmp_path):
    p = tmp_path / "calib.txt"
    p.write_text(f"{FX} {FY} {CX} {CY} " + " ".join(map(str, DIST)) + "\n")
    _check(calib.read_camera(p, sensor_size=SIZE), p)
    _check(calib.read_camera(tmp_path, sensor_size=SIZE), p)  # the folder
    # no size in the file nor given: the ECD's DAVIS240C
    assert calib.read_camera(p).sensor_size == (180, 240)


def test_kalibr_camchain_yaml(tmp_path):
    p = tmp_path / "camchain.yaml"
    p.write_text(f"""cam0:
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [{DIST[0]}, {DIST[1]}, {DIST[2]}, {DIST[3]}]
  distortion_model: radtan
  intrinsics: [{FX}, {FY}, {CX}, {CY}]
  resolution: [346, 260]
  rostopic: /davis/left/image_raw
cam1:
  camera_model: pinhole
  distortion_coeffs: [0.1, 0.0, 0.0, 0.0]
  distortion_model: radtan
  intrinsics: [300.0, 300.0, 170.0, 130.0]
  resolution: [346, 260]
""")
    _check(calib.read_camera(p), p, dist=DIST[:4] + (0.0,))
    assert calib.read_camera(p, camera="cam1").fx == 300.0
    with pytest.raises(FormatError) as e:
        calib.read_camera(p, camera="cam2")
    assert "no camera 'cam2'" in _one_line(e) and str(p) in str(e.value)
    p.write_text(p.read_text().replace("distortion_model: radtan", "distortion_model: equidistant",
                                       1))
    with pytest.raises(CalibrationError) as e:
        calib.read_camera(p)
    assert "cam0.distortion_model = 'equidistant'" in _one_line(e)


def test_ros_camera_info_yaml(tmp_path):
    p = tmp_path / "davis.yaml"
    p.write_text(f"""image_width: 346
image_height: 260
camera_name: DAVIS-00000
camera_matrix:
  rows: 3
  cols: 3
  data: [{FX}, 0, {CX}, 0, {FY}, {CY}, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [{', '.join(map(str, DIST))}]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [{FX}, 0, {CX}, 0, 0, {FY}, {CY}, 0, 0, 0, 1, 0]
""")
    _check(calib.read_camera(p), p)
    p.write_text(p.read_text().replace(f"data: [{FX}, 0, {CX}", f"data: [{FX}, 0, x{CX}"))
    with pytest.raises(FormatError) as e:
        calib.read_camera(p)
    assert "field 'camera_matrix.data' must be a number, got 'x173.64'" in _one_line(e)


def test_dv_calibration_xml(tmp_path):
    p = tmp_path / "calibration_camera_DAVIS346.xml"
    p.write_text(f"""<?xml version="1.0"?>
<opencv_storage>
<DAVIS346_00000499>
  <camera_matrix type_id="opencv-matrix">
    <rows>3</rows>
    <cols>3</cols>
    <dt>d</dt>
    <data>
      {FX} 0. {CX} 0. {FY} {CY} 0. 0. 1.</data></camera_matrix>
  <distortion_coefficients type_id="opencv-matrix">
    <rows>1</rows>
    <cols>5</cols>
    <dt>d</dt>
    <data>
      {' '.join(map(str, DIST))}</data></distortion_coefficients>
  <image_width>346</image_width>
  <image_height>260</image_height>
</DAVIS346_00000499>
<use_fisheye_model>0</use_fisheye_model>
<type>camera</type>
<pattern_width>9</pattern_width>
<pattern_height>6</pattern_height>
<distortion_model>RadialTangential</distortion_model>
</opencv_storage>
""")
    _check(calib.read_camera(p), p)
    p.write_text(p.read_text().replace("<use_fisheye_model>0", "<use_fisheye_model>1"))
    with pytest.raises(CalibrationError) as e:
        calib.read_camera(p)
    assert "use_fisheye_model = '1'" in _one_line(e)
    p.write_text("<opencv_storage><a>1</a>")
    with pytest.raises(FormatError) as e:
        calib.read_camera(p)
    assert "not valid XML" in _one_line(e)


def test_dv_older_root_level_xml(tmp_path):
    p = tmp_path / "old.xml"
    p.write_text(f"""<?xml version="1.0"?>
<opencv_storage>
<image_width>346</image_width><image_height>260</image_height>
<use_fisheye_model>0</use_fisheye_model>
<camera_matrix type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt>
<data>{FX} 0. {CX} 0. {FY} {CY} 0. 0. 1.</data></camera_matrix>
<distortion_coefficients type_id="opencv-matrix"><rows>5</rows><cols>1</cols><dt>d</dt>
<data>{' '.join(map(str, DIST))}</data></distortion_coefficients>
</opencv_storage>
""")
    _check(calib.read_camera(p), p)


def test_dsec_cam_to_cam_yaml(tmp_path):
    p = tmp_path / "cam_to_cam.yaml"
    p.write_text(f"""disparity_to_depth:
  cams_03: [[1, 0, 0, -335.0], [0, 1, 0, -221.9], [0, 0, 0, 569.7], [0, 0, 1.67, 0]]
extrinsics:
  R_rect0: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
intrinsics:
  cam0:
    camera_matrix: [{FX}, {FY}, {CX}, {CY}]
    distortion_coeffs: [{DIST[0]}, {DIST[1]}, {DIST[2]}, {DIST[3]}]
    distortion_model: plumb_tan
    resolution: [346, 260]
  camRect0:
    camera_matrix: [569.7, 569.7, 335.0, 221.9]
    resolution: [640, 480]
""")
    rect = calib.read_camera(p, camera="camRect0")  # the rectified left event camera
    assert rect.fx == 569.7 and rect.sensor_size == (480, 640) and not rect.is_distorted
    # default: cam0, the raw left event camera (the grid of DSEC's events)
    _check(calib.read_camera(p), p, dist=DIST[:4] + (0.0,))
    with pytest.raises(FormatError) as e:
        calib.read_camera(p, camera="cam9")
    assert "intrinsics.cam9" in _one_line(e)


def test_json_round_trip_and_schema(tmp_path):
    cam = Camera(FX, FY, CX, CY, DIST, SIZE, source="made here")
    p = tmp_path / "cam.json"
    calib.write_json(p, cam)
    back = calib.read_camera(p)
    _check(back, p)
    assert back == cam  # source is not compared
    # K instead of fx.. and width/height instead of sensor_size
    q = tmp_path / "k.json"
    q.write_text(json.dumps({"K": [[FX, 0, CX], [0, FY, CY], [0, 0, 1]], "dist": list(DIST),
                             "width": 346, "height": 260}))
    _check(calib.read_camera(q), q)
    # no size: unknown until fitted to the events
    q.write_text(json.dumps({"fx": FX, "fy": FY, "cx": CX, "cy": CY}))
    assert calib.read_camera(q).sensor_size is None
    assert calib.read_camera(q).for_sensor(SIZE).sensor_size == SIZE
    q.write_text(json.dumps({"fx": FX, "fy": -1, "cx": CX, "cy": CY}))
    with pytest.raises(CalibrationError) as e:
        calib.read_camera(q)
    assert str(q) in _one_line(e) and "fy=-1" in str(e.value)
    q.write_text(json.dumps({"fx": FX, "fy": FY, "cx": "nan", "cy": CY}))
    with pytest.raises(FormatError) as e:
        calib.read_camera(q)
    assert "field 'cx' must be finite, got 'nan'" in _one_line(e)


def test_size_stated_by_the_file_is_checked(tmp_path):
    p = tmp_path / "cam.json"
    calib.write_json(p, Camera(FX, FY, CX, CY, DIST, SIZE))
    with pytest.raises(CalibrationError) as e:
        calib.read_camera(p, sensor_size=(180, 240))
    assert "346 x 260 px" in _one_line(e) and "240 x 180 px" in str(e.value)
    with pytest.raises(CalibrationError, match="346 x 260 px sensor"):
        calib.read_camera(p).for_sensor((180, 240))


def test_io_read_calibration_dict_reads_every_format(tmp_path):
    """evmotion.io.read_calibration (a dict, as evmotion HDF5 stores it) delegates here."""
    p = tmp_path / "cam.json"
    calib.write_json(p, Camera(FX, FY, CX, CY, DIST, SIZE))
    d = stored_calibration(p)
    assert d["fx"] == FX and d["dist"] == list(DIST) and d["sensor_size"] == list(SIZE)
    assert calib.camera_from_dict(d) == Camera(FX, FY, CX, CY, DIST, SIZE)


def test_unknown_and_missing(tmp_path):
    with pytest.raises(CalibrationError, match="not found"):
        calib.read_camera(tmp_path / "nope.yaml")
    p = tmp_path / "cam.ini"
    p.write_text("fx=1")
    with pytest.raises(CalibrationError) as e:
        calib.read_camera(p)
    assert "unknown calibration format '.ini'" in _one_line(e)
    y = tmp_path / "bad.yaml"
    y.write_text("cam0: [unclosed\n")
    with pytest.raises(FormatError) as e:
        calib.read_camera(y)
    assert "not valid YAML" in _one_line(e)


def _aedat2_header(path, entries):
    lines = ["#!AER-DAT2.0", "# AEChip: eu.seebetter.ini.chips.davis.DAVIS240C",
             *[f'#  <entry key="{k}" value="{v}"/>' for k, v in entries],
             "#End Of ASCII Header"]
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode() + bytes(8))


def test_jaer_header_focal_length(tmp_path):
    p = tmp_path / "rec.aedat"
    _aedat2_header(p, [("ImuFlow.lensFocalLengthMm", "4.5"),
                       ("LocalPlanesFlow.lensFocalLengthMm", "4.5")])
    cam, mm = calib.jaer_header_camera(p, (180, 240))
    assert mm == [4.5]
    assert cam.fx == pytest.approx(4.5e3 / 18.5) and cam.fy == cam.fx
    assert (cam.cx, cam.cy) == (119.5, 89.5) and not cam.is_distorted
    assert cam.source.endswith("(nominal)")
    info = calib.recording_intrinsics(p, (180, 240))
    assert info["nominal"] and info["K"][0] == pytest.approx(243.243, abs=1e-3)
    # filters disagree: no camera, and the reason names the values
    _aedat2_header(p, [("ImuFlow.lensFocalLengthMm", "4.5"),
                       ("Steadicam.lensFocalLengthMm", "12.0")])
    assert calib.jaer_header_camera(p, (180, 240)) == (None, [4.5, 12.0])
    assert "4.5, 12 mm" in calib.recording_intrinsics(p, (180, 240))["reason"]


@pytest.mark.realdata
def test_real_jaer_header_lists_disagreeing_focal_lengths(shared_data):
    p = shared_data / "formats" / "davis240_translboxes_aedat2.aedat"
    cam, mm = calib.jaer_header_camera(p, (180, 240))
    assert cam is None and mm == [4.5, 8.500001, 12.0]


@pytest.mark.realdata
def test_real_ecd_folder_camera(shared_data):
    folder = shared_data / "ecd_rotation_windows" / "boxes_rotation"
    cam = calib.recording_camera(folder)
    assert cam.fx == pytest.approx(199.092366542) and cam.dist[0] == pytest.approx(-0.368436311798)
    assert cam.source == str(folder / "calib.txt")


ROS = """image_width: 160
image_height: 120
camera_matrix: {{rows: 3, cols: 3, data: [{k}]}}
distortion_model: plumb_bob
distortion_coefficients: {{rows: 1, cols: {cols}, data: [{dist}]}}
"""


@pytest.mark.parametrize("k, dist, cols, match", [
    ("120, 0, 79.5, 0, 120, 59.5, 0, 0, 0", "0, 0, 0, 0, 0", 5, "last row .* expected"),
    ("120, 0, 79.5, 0, 120, 59.5, 0, 0, 1", "0.1, 0.2", 5, "states 1 x 5 values but holds 2"),
    ("120, 0, 79.5, 0, 120, 59.5, 0, 0, 1", "0.1, 0.2, 0.3", 3, "3 distortion coefficients"),
    ("120, 0, 79.5, 0, 120, 59.5, 0, 0, 1", "1e300, 0, 0, 0, 0", 5, "not a lens"),
    ("1e308, 0, 79.5, 0, 1e308, 59.5, 0, 0, 1", "0, 0, 0, 0, 0", 5, "focal lengths"),
    ("120, 0, 1e9, 0, 120, 59.5, 0, 0, 1", "0, 0, 0, 0, 0", 5, "far outside the 160 x 120"),
])
def test_calibrations_that_are_not_a_camera_are_refused(tmp_path, k, dist, cols, match):
    """Accepted before: a K whose last row was zeros, a distortion list shorter than its
    stated size or of 3 values (zero-padded), coefficients of 1e300 (numpy warnings, then
    'the recording holds no events'), fx = 1e308, a principal point 1e9 px away."""
    path = tmp_path / "cam.yaml"
    path.write_text(ROS.format(k=k, dist=dist, cols=cols))
    with pytest.raises(CalibrationError, match=match):
        calib.read_camera(path)
    path.write_text(ROS.format(k="120, 0, 79.5, 0, 120, 59.5, 0, 0, 1", dist="0.1, -0.2",
                               cols=2))
    assert calib.read_camera(path).dist == (0.1, -0.2, 0.0, 0.0, 0.0)


def test_other_labs_fisheye_flags_and_model_keys_are_refused(tmp_path):
    """Probe AR: OpenCV's fisheye_model: 1 (YAML and XML), use_fisheye_model in a YAML, a
    JSON distortion_model and a DSEC camera_model were read as radtan: the estimate 26 %
    off, valid."""
    k = f"{FX}, 0, {CX}, 0, {FY}, {CY}, 0, 0, 1"
    yaml = ("%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n"
            f"   dt: d\n   data: [{k}]\ndistortion_coefficients: !!opencv-matrix\n"
            "   rows: 4\n   cols: 1\n   dt: d\n   data: [0.3, 0.1, -0.05, 0.01]\n")
    for flag in ("fisheye_model: 1\n", "use_fisheye_model: 1\n",
                 "distortion_model: equidistant\n"):
        path = tmp_path / "cv.yaml"
        path.write_text(yaml + flag)
        with pytest.raises(CalibrationError, match="not supported") as exc:
            calib.read_camera(path)
        assert flag.split(":")[0] in _one_line(exc)
    xml = (f'<?xml version="1.0"?>\n<opencv_storage>\n<fisheye_model>1</fisheye_model>\n'
           f'<camera_matrix type_id="opencv-matrix"><rows>3</rows><cols>3</cols><dt>d</dt>'
           f'<data>{k.replace(",", " ")}</data></camera_matrix>\n</opencv_storage>\n')
    (tmp_path / "cv.xml").write_text(xml)
    with pytest.raises(CalibrationError, match="fisheye_model = '1'"):
        calib.read_camera(tmp_path / "cv.xml")
    (tmp_path / "cam.json").write_text(json.dumps(
        {"fx": FX, "fy": FY, "cx": CX, "cy": CY, "distortion_model": "equidistant"}))
    with pytest.raises(CalibrationError, match="distortion_model = 'equidistant'"):
        calib.read_camera(tmp_path / "cam.json")
    (tmp_path / "dsec.yaml").write_text(
        "intrinsics: {cam0: {camera_model: omni, camera_matrix: [553.5, 553.3, 325.2, 241.3],"
        " distortion_coeffs: [0, 0, 0, 0], resolution: [640, 480]}}\n")
    with pytest.raises(CalibrationError, match="camera_model = 'omni'"):
        calib.read_camera(tmp_path / "dsec.yaml")


def test_other_labs_layouts_of_a_pinhole_camera_are_read(tmp_path):
    """Probe AR: a ROS CameraInfo message dump (K, D), OpenCV K/D YAML, a JSON with
    camera_matrix / dist_coeffs, a 3x3 K in text, calib.txt of 6 numbers and Kalibr's
    distortion_model none were refused, each with a misleading message."""
    k = [FX, 0.0, CX, 0.0, FY, CY, 0.0, 0.0, 1.0]
    (tmp_path / "msg.yaml").write_text(
        f"header: {{frame_id: davis}}\nheight: {SIZE[0]}\nwidth: {SIZE[1]}\n"
        f"distortion_model: plumb_bob\nD: {list(DIST)}\nK: {k}\n")
    _check(calib.read_camera(tmp_path / "msg.yaml"), tmp_path / "msg.yaml")
    (tmp_path / "kd.yaml").write_text(
        "%YAML:1.0\n---\nK: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        f"   data: {k}\nD: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
        f"   data: {list(DIST)}\n")
    _check(calib.read_camera(tmp_path / "kd.yaml", sensor_size=SIZE), tmp_path / "kd.yaml")
    (tmp_path / "cm.json").write_text(json.dumps(
        {"camera_matrix": [k[:3], k[3:6], k[6:]], "dist_coeffs": list(DIST),
         "sensor_size": list(SIZE)}))
    _check(calib.read_camera(tmp_path / "cm.json"), tmp_path / "cm.json")
    (tmp_path / "K.txt").write_text("\n".join(" ".join(map(str, k[i:i + 3]))
                                              for i in (0, 3, 6)))
    _check(calib.read_camera(tmp_path / "K.txt", sensor_size=SIZE), tmp_path / "K.txt",
           dist=(0.0,) * 5)
    (tmp_path / "six.txt").write_text(f"{FX} {FY} {CX} {CY} {DIST[0]} {DIST[1]}")
    _check(calib.read_camera(tmp_path / "six.txt", sensor_size=SIZE), tmp_path / "six.txt",
           dist=(DIST[0], DIST[1], 0.0, 0.0, 0.0))
    (tmp_path / "fourteen.txt").write_text(" ".join(["0.1"] * 14))
    with pytest.raises(FormatError, match="holds 14 numbers, expected fx fy cx cy and up to 5"):
        calib.read_camera(tmp_path / "fourteen.txt")
    (tmp_path / "kalibr.yaml").write_text(
        f"cam0: {{camera_model: pinhole, intrinsics: [{FX}, {FY}, {CX}, {CY}], "
        f"distortion_model: none, distortion_coeffs: [], resolution: [{SIZE[1]}, {SIZE[0]}]}}\n")
    _check(calib.read_camera(tmp_path / "kalibr.yaml"), tmp_path / "kalibr.yaml",
           dist=(0.0,) * 5)


def test_a_calibration_of_another_resolution_is_refused(tmp_path):
    """Probe AR: a 640x480 K in an ECD calib.txt (cx 346.7 on a 240-px-wide sensor) gave a
    valid estimate 60 % off; a principal point just outside (a crop) is still read."""
    (tmp_path / "k640.txt").write_text("553.5 553.3 346.7 260.0 0 0 0 0 0")
    with pytest.raises(CalibrationError, match=r"\(346.7, 260\) lies far outside the 240 x "
                                               r"180 px sensor: a calibration of another"):
        calib.read_camera(tmp_path / "k640.txt")
    (tmp_path / "crop.txt").write_text("199.1 198.8 250.0 110.7 0 0 0 0 0")
    assert calib.read_camera(tmp_path / "crop.txt").cx == 250.0
