import numpy as np
import pytest

from evmotion import EventArray
from evmotion.camera import Camera
from evmotion.errors import CalibrationError, FormatError, ParameterError
from evmotion.io.calibration import read_camera, read_ecd

DAVIS = Camera(199.092366, 198.82882, 132.192071, 110.712276,
               (-0.368436311798, 0.150947243557, -0.000296130534, -0.000759431726, 0.0),
               sensor_size=(180, 240))


def test_distortion_formula_matches_opencv_plumb_bob_by_hand():
    cam = Camera(100, 100, 50, 50, (0.1, 0.01, 0.001, 0.002, 0.0005), (100, 100))
    x, y = 0.3, -0.2
    r2 = x * x + y * y
    rad = 1 + 0.1 * r2 + 0.01 * r2**2 + 0.0005 * r2**3
    xd = x * rad + 2 * 0.001 * x * y + 0.002 * (r2 + 2 * x * x)
    yd = y * rad + 0.001 * (r2 + 2 * y * y) + 2 * 0.002 * x * y
    got = cam.distort_normalized(np.array([x]), np.array([y]))
    np.testing.assert_allclose([got[0][0], got[1][0]], [xd, yd], rtol=1e-14)


def test_undistort_inverts_distort_over_the_sensor():
    vv, uu = np.mgrid[0:180:7, 0:240:7].astype(float)
    u, v = uu.ravel(), vv.ravel()
    ud, vd = DAVIS.undistort_pixels(u, v)
    u2, v2 = DAVIS.distort_pixels(ud, vd)
    assert np.max(np.hypot(u2 - u, v2 - v)) < 1e-8


def test_lut_undistortion_of_events_matches_direct():
    rng = np.random.default_rng(0)
    n = 500
    ev = EventArray(rng.integers(0, 240, n), rng.integers(0, 180, n), np.arange(n), rng.integers(0, 2, n),
                    (180, 240))
    und = DAVIS.undistort_events(ev, drop_outside=False)
    ux, uy = DAVIS.undistort_pixels(ev.xf, ev.yf)
    np.testing.assert_allclose(und.x, ux, atol=1e-4)
    np.testing.assert_allclose(und.y, uy, atol=1e-4)
    assert und.x.dtype == np.float32
    kept = DAVIS.undistort_events(ev)
    assert len(kept) <= n and kept.x.min() >= 0 and kept.x.max() <= 239
    # how many were left out is said (the README's 30k window held 24,602)
    assert kept.meta["undistort_dropped"] == n - len(kept) and und.meta["undistort_dropped"] == 0


def test_principal_point_is_fixed_and_normalize_roundtrip():
    u, v = DAVIS.undistort_pixels(np.array([DAVIS.cx]), np.array([DAVIS.cy]))
    np.testing.assert_allclose([u[0], v[0]], [DAVIS.cx, DAVIS.cy], atol=1e-12)
    x, y = DAVIS.normalize(np.array([10.0]), np.array([20.0]))
    np.testing.assert_allclose(DAVIS.denormalize(x, y), [[10.0], [20.0]])


def test_from_ecd_real_calib(shared_data):
    cam = read_ecd(shared_data / "ecd_rotation_windows" / "boxes_rotation")
    np.testing.assert_allclose(cam.K[0, 0], 199.092366)
    assert cam.is_distorted and cam.sensor_size == (180, 240)


def test_bad_calibration_errors(tmp_path):
    p = tmp_path / "calib.txt"
    p.write_text("1 2 3")
    with pytest.raises(FormatError, match="holds 3 numbers"):
        read_ecd(p)
    p.write_text("1 2 x 4")
    with pytest.raises(FormatError, match="calib.txt"):
        read_ecd(p)
    with pytest.raises(CalibrationError, match="not found"):
        read_ecd(tmp_path / "nope.txt")
    with pytest.raises(CalibrationError, match="finite"):
        Camera(np.nan, 1, 1, 1)


def test_yaml_calibrations(tmp_path):
    mv = tmp_path / "camchain-indoor_flying.yaml"
    mv.write_text("cam0:\n  intrinsics: [226.4, 226.2, 173.6, 133.7]\n"
                  "  distortion_coeffs: [-0.048, 0.0123, -0.00094, -0.00051]\n"
                  "  distortion_model: radtan\n  resolution: [346, 260]\n")
    cam = read_camera(mv)
    assert cam.sensor_size == (260, 346) and cam.dist[4] == 0.0 and cam.fx == 226.4
    ds = tmp_path / "cam_to_cam.yaml"
    ds.write_text("intrinsics:\n  camRect0:\n    camera_matrix: [569.7, 569.7, 335.0, 221.9]\n"
                  "    resolution: [640, 480]\n")
    cam = read_camera(ds)
    assert cam.sensor_size == (480, 640) and not cam.is_distorted


def test_a_camera_without_a_sensor_size_takes_the_events():
    # the default was the DAVIS240C's (180, 240): a 640x480 user's Camera(fx, fy, cx, cy)
    # failed with "calibration is for a 240 x 180 px sensor" (probe CB)
    cam = Camera(500.0, 500.0, 320.0, 240.0, (-0.3, 0.1, 0.0, 0.0, 0.0))
    assert cam.sensor_size is None and Camera.from_K(cam.K).sensor_size is None
    ev = EventArray(np.array([0, 639]), np.array([0, 479]), np.array([0, 1]),
                    np.array([1, 1]), (480, 640))
    und = cam.undistort_events(ev, drop_outside=False)
    assert und.sensor_size == (480, 640) and float(und.x[0]) < 0


@pytest.mark.parametrize("size", [(-1, 5), (180, 240, 3), (180.5, 240), (0, 10)])
def test_an_impossible_sensor_size_is_refused(size):
    with pytest.raises(CalibrationError, match=r"sensor_size must be \(height, width\)"):
        Camera(200.0, 200.0, 120.0, 90.0, sensor_size=size)


def test_integer_coordinates_cannot_be_kept_off_the_sensor():
    # they wrapped round in uint16: x = -35.9 became 65500 (probe CB)
    cam = Camera(200.0, 200.0, 120.0, 90.0, (-0.3, 0.1, 0.0, 0.0, 0.0), (180, 240))
    ev = EventArray(np.array([0, 120]), np.array([0, 90]), np.array([0, 1]),
                    np.array([1, 0]), (180, 240))
    with pytest.raises(ParameterError, match="integer=True needs drop_outside=True"):
        cam.undistort_events(ev, integer=True, drop_outside=False)
    assert cam.undistort_events(ev, integer=True).x.tolist() == [120]
