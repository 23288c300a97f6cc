"""ROS1 bags: write dvs_msgs/EventArray messages then read them back, cross-checked with
rosbags' generic deserializer; topic selection and the missing-dependency error."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from _helpers import assert_same_events
from evmotion.errors import FormatError, MissingDependencyError
from evmotion.events import EventArray
from evmotion.io import rosbag
from evmotion.io.registry import detect_spec

pytest.importorskip("rosbags")


@pytest.fixture
def events():
    rng = np.random.default_rng(3)
    n = 20_000
    t = np.sort(rng.integers(0, 500_000, n)) + 1_500_000_000_123_456
    return EventArray(x=rng.integers(0, 240, n), y=rng.integers(0, 180, n), t=t,
                      p=rng.integers(0, 2, n), sensor_size=(180, 240))


def test_round_trip(events, tmp_path):
    out = tmp_path / "ev.bag"
    rosbag.write(out, events, message_us=33_000)
    assert detect_spec(out).name == "rosbag"
    assert_same_events(rosbag.read(out), events)
    chunks = list(rosbag.iter_chunks(out, 7_000))
    assert [len(c) for c in chunks] == [7_000, 7_000, 6_000]
    d = rosbag.describe(out)
    assert d["n_events"] == len(events) and d["topics"]["/dvs/events"]["messages"] == 16
    t0, t1 = int(events.t[5]), int(events.t[15_000])
    assert_same_events(rosbag.read(out, t0=t0, t1=t1), events.slice_time(t0, t1))


def test_matches_generic_deserializer(events, tmp_path):
    from rosbags.rosbag1 import Reader

    out = tmp_path / "ev.bag"
    rosbag.write(out, events[:500], message_us=10**9)
    store = rosbag.typestore()
    with Reader(out) as reader:
        (conn, _, raw), = list(reader.messages())
        msg = store.deserialize_ros1(raw, conn.msgtype)
    assert (msg.height, msg.width) == (180, 240) and len(msg.events) == 500
    e = msg.events[123]
    assert (e.x, e.y, bool(e.polarity)) == (events.x[123], events.y[123], bool(events.p[123]))
    assert e.ts.sec * 10**6 + e.ts.nanosec // 1000 == events.t[123]


def test_missing_topic(events, tmp_path):
    out = tmp_path / "ev.bag"
    rosbag.write(out, events[:10], topic="/cam0/events")
    with pytest.raises(FormatError, match="/other"):
        rosbag.read(out, topic="/other")
    assert len(rosbag.read(out, topic="/cam0/events")) == 10


def test_missing_dependency(monkeypatch, events, tmp_path):
    monkeypatch.setitem(sys.modules, "rosbags", None)
    with pytest.raises(MissingDependencyError, match="evmotion\\[ros\\]"):
        rosbag.write(tmp_path / "x.bag", events)


def test_imu_messages(events, tmp_path):
    from rosbags.rosbag1 import Writer

    store = rosbag.typestore()
    T = store.types
    out = tmp_path / "imu.bag"
    with Writer(out) as writer:
        conn = writer.add_connection("/dvs/imu", rosbag.IMU_MSGTYPE, typestore=store)
        for k in range(5):
            stamp = T["builtin_interfaces/msg/Time"](sec=100 + k, nanosec=250_000)
            msg = T["sensor_msgs/msg/Imu"](
                header=T["std_msgs/msg/Header"](seq=k, stamp=stamp, frame_id="imu"),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0, y=0, z=0, w=1),
                orientation_covariance=np.zeros(9),
                angular_velocity=T["geometry_msgs/msg/Vector3"](x=0.1 * k, y=0, z=0),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=T["geometry_msgs/msg/Vector3"](x=0, y=-9.81, z=0),
                linear_acceleration_covariance=np.zeros(9))
            writer.write(conn, (100 + k) * 10**9, store.serialize_ros1(msg, rosbag.IMU_MSGTYPE))
    imu = rosbag.read_imu(out)
    assert imu.t.tolist() == [(100 + k) * 10**6 + 250 for k in range(5)]
    np.testing.assert_allclose(imu.gyro[:, 0], 0.1 * np.arange(5))
    np.testing.assert_allclose(imu.accel[:, 1], -9.81)
    assert rosbag.describe(out)["imu"] == 5


def test_no_imu_topic(events, tmp_path):
    out = tmp_path / "ev.bag"
    rosbag.write(out, events[:10])
    assert rosbag.read_imu(out).t.size == 0
    with pytest.raises(FormatError, match="/imu"):
        rosbag.read_imu(out, topic="/imu")


def test_a_stereo_bag_reads_the_first_topic_by_name_and_says_so(events, tmp_path):
    """Two EventArray topics: whichever was connected first (the right camera) was read
    without a word; now the first by name (left), with a warning naming both."""
    from rosbags.rosbag1 import Writer

    from evmotion.errors import EvmotionWarning

    right = EventArray(events.x, events.y, events.t, 1 - events.p, events.sensor_size)
    path = tmp_path / "stereo.bag"
    store = rosbag.typestore()
    with Writer(path) as w:
        for name, ev in (("/davis/right/events", right), ("/davis/left/events", events)):
            conn = w.add_connection(name, rosbag.MSGTYPE, typestore=store)
            w.write(conn, int(ev.t[-1]) * 1000, rosbag._serialize(ev, 0, b"dvs"))
    with pytest.warns(EvmotionWarning, match="/davis/left/events, /davis/right/events"):
        got = rosbag.read(path)
    assert_same_events(got, events)
    assert_same_events(rosbag.read(path, topic="/davis/right/events"), right)


def _bag_with_camera_info(path, events, k):
    """``events`` in one EventArray message and a CameraInfo of intrinsics ``k`` (9)."""
    from rosbags.rosbag1 import Writer

    store = rosbag.typestore()
    T = store.types
    stamp = T["builtin_interfaces/msg/Time"](sec=int(events.t[0] // 10**6), nanosec=0)
    info = T[rosbag.CAMERA_INFO_MSGTYPE](
        header=T["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id="cam"), height=180,
        width=240, distortion_model="plumb_bob", D=np.array([-0.37, 0.15, -3e-4, -7.6e-4, 0.0]),
        K=np.asarray(k, float), R=np.eye(3).ravel(), P=np.zeros(12), binning_x=0, binning_y=0,
        roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                  do_rectify=False))
    with Writer(path) as writer:
        cc = writer.add_connection("/dvs/camera_info", rosbag.CAMERA_INFO_MSGTYPE,
                                   typestore=store)
        writer.write(cc, int(events.t[0]) * 1000,
                     store.serialize_ros1(info, rosbag.CAMERA_INFO_MSGTYPE))
        ce = writer.add_connection("/dvs/events", rosbag.MSGTYPE, typestore=store)
        writer.write(ce, int(events.t[-1]) * 1000, rosbag._serialize(events, 0, b"dvs"))


def test_the_bags_camera_info_is_its_calibration(events, tmp_path):
    # rpg_dvs_ros publishes the sensor's calibration on /dvs/camera_info: info said
    # "intrinsics: none" and flow ran on the distorted grid (probe)
    from evmotion.io.calibration import recording_camera

    k = [199.09, 0, 132.19, 0, 198.83, 110.71, 0, 0, 1]
    out = tmp_path / "calib.bag"
    _bag_with_camera_info(out, events[:500], k)
    cal = rosbag.read_camera_info(out)
    assert cal["K"][0][0] == 199.09 and cal["dist"][:2] == [-0.37, 0.15]
    assert (cal["width"], cal["height"], cal["model"]) == (240, 180, "plumb_bob")
    cam = recording_camera(out, None, (180, 240))
    assert cam is not None and "/dvs/camera_info" in cam.source
    np.testing.assert_allclose(cam.K[0, 0], 199.09)
    # the driver's message before any calibration (K all zeros) is none
    _bag_with_camera_info(tmp_path / "zeros.bag", events[:500], np.zeros(9))
    assert rosbag.read_camera_info(tmp_path / "zeros.bag") is None
    assert recording_camera(tmp_path / "zeros.bag", None, (180, 240)) is None


def test_times_past_a_ros_time_are_one_line(tmp_path):
    """A ROS1 time's seconds are uint32: times from 2^32 s on had crashed the writer in a
    struct.error naming no file (probe DJ); the last representable second is written."""
    from evmotion.io import write_events

    end = 2**32 * 1_000_000
    late = EventArray(x=[1, 2], y=[1, 2], t=[end - 5, end], p=[1, 0], sensor_size=(180, 240))
    with pytest.raises(FormatError, match=r"late.bag.*past a ROS time's range"):
        write_events(tmp_path / "late.bag", late)
    assert not (tmp_path / "late.bag").exists()
    ok = late[:1]
    write_events(tmp_path / "ok.bag", ok)
    assert rosbag.read(tmp_path / "ok.bag").t.tolist() == [end - 5]
