"""ROS 1 bags with ``dvs_msgs/EventArray`` messages (rpg_dvs_ros), via ``rosbags``.

The bag container is read and written with the ``rosbags`` package (optional extra
``ros``); the EventArray payload is decoded directly with numpy: ROS1 serialization of
``Header header, uint32 height, uint32 width, Event[] events`` where each Event is
``uint16 x, uint16 y, time ts (uint32 sec, uint32 nsec), bool polarity`` (13 bytes).
"""

from __future__ import annotations

import struct
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evmotion.errors import EvmotionWarning, FormatError, MissingDependencyError, ParameterError
from evmotion.events import EventArray
from evmotion.io import binary
from evmotion.io.base import FormatSpec
from evmotion.io.guard import SENSOR_SIZE_HINT, check_sensor_size
from evmotion.utils import atomic_path

__all__ = ["read", "iter_chunks", "write", "read_imu", "read_camera_info", "describe",
           "typestore", "ImuSamples", "FORMAT"]

MAGIC = b"#ROSBAG V2.0"
MSGTYPE = "dvs_msgs/msg/EventArray"
EVENT_MSG = "uint16 x\nuint16 y\ntime ts\nbool polarity\n"
EVENT_ARRAY_MSG = ("std_msgs/Header header\nuint32 height\nuint32 width\n"
                   "dvs_msgs/Event[] events\n")
_EVENT = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"),
                   ("p", "u1")])


IMU_MSGTYPE = "sensor_msgs/msg/Imu"
CAMERA_INFO_MSGTYPE = "sensor_msgs/msg/CameraInfo"


@dataclass(frozen=True)
class ImuSamples:
    """IMU samples from ``sensor_msgs/Imu``: ``t`` int64 µs (header stamp), ``accel``
    (N, 3) m/s², ``gyro`` (N, 3) rad/s, in the message's frame (ROS units)."""

    t: np.ndarray
    accel: np.ndarray
    gyro: np.ndarray


def _rosbags():
    try:
        from rosbags import rosbag1, typesys
    except ModuleNotFoundError:
        raise MissingDependencyError("rosbags", "reading and writing ROS bags", "ros") from None
    return rosbag1, typesys


def typestore():
    """A ROS1 Noetic typestore with ``dvs_msgs/Event`` and ``dvs_msgs/EventArray``
    registered from their message definitions."""
    _, typesys = _rosbags()
    store = typesys.get_typestore(typesys.Stores.ROS1_NOETIC)
    types = {}
    types.update(typesys.get_types_from_msg(EVENT_MSG, "dvs_msgs/msg/Event"))
    types.update(typesys.get_types_from_msg(EVENT_ARRAY_MSG, MSGTYPE))
    store.register(types)
    return store


def _decode(raw: bytes, path: Path) -> tuple[tuple[int, int], binary.Block]:
    """(sensor size, block) of one serialized EventArray message."""
    try:
        n_id = struct.unpack_from("<I", raw, 12)[0]
        pos = 16 + n_id
        h, w, n = struct.unpack_from("<III", raw, pos)
        ev = np.frombuffer(raw, _EVENT, count=n, offset=pos + 12)
    except (struct.error, ValueError):
        raise FormatError(path, "corrupt dvs_msgs/EventArray message "
                          f"({len(raw)} bytes)") from None
    t = ev["sec"].astype(np.int64) * 1_000_000 + ev["nsec"].astype(np.int64) // 1000
    return (h, w), (ev["x"].copy(), ev["y"].copy(), t, (ev["p"] != 0).astype(np.uint8))


def _open_bag(path: Path):
    """An opened rosbags ROS1 reader (the caller closes it)."""
    rosbag1, _ = _rosbags()
    try:
        reader = rosbag1.Reader(path)
        reader.open()
    except Exception as exc:
        raise FormatError(path, f"cannot open as a ROS1 bag: {exc}") from None
    return reader


def _topic_connections(reader, msgtype: str, topic: str | None, path=None,
                       quiet: bool = False) -> list:
    """The connections of ``topic`` (default: of the topics of type ``msgtype``, the first
    by name -- a stereo rig's "left" before its "right" -- with a warning naming the
    others), empty when there is none."""
    conns = [c for c in reader.connections if c.msgtype == msgtype
             and (topic is None or c.topic == topic)]
    names = sorted({c.topic for c in conns})
    if topic is None and len(names) > 1 and not quiet:
        warnings.warn(EvmotionWarning(
            f"{path}: {len(names)} topics carry {msgtype.rsplit('/', 1)[-1]} messages "
            f"({', '.join(names)}): read {names[0]} (topic= chooses another)"), stacklevel=4)
    return [c for c in conns if names and c.topic == names[0]]


def _messages(path: Path, topic: str | None, quiet: bool = False):
    reader = _open_bag(path)
    try:
        conns = _topic_connections(reader, MSGTYPE, topic, path, quiet)
        if not conns:
            found = sorted({(c.topic, c.msgtype) for c in reader.connections})
            raise FormatError(path, f"no {MSGTYPE} messages"
                              + (f" on topic '{topic}'" if topic else ""),
                              f"topics in the bag: {found}")
        for _, _, raw in reader.messages(connections=conns):
            yield conns[0].topic, raw
    finally:
        reader.close()


def _blocks(path: Path, topic: str | None, info: dict) -> Iterator[binary.Block]:
    for name, raw in _messages(path, topic):
        size, blk = _decode(raw, path)
        info.setdefault("size", size)
        info.setdefault("topic", name)
        yield blk


def _first_size(path: Path, topic: str | None, sensor_size):
    if sensor_size is not None:
        return tuple(sensor_size)
    seen = False
    for _, raw in _messages(path, topic, quiet=True):  # _blocks says which topic is read
        seen = True
        size, _ = _decode(raw, path)
        if size[0] > 0 and size[1] > 0:
            return check_sensor_size(path, size, "EventArray message height, width")
    raise FormatError(path, "EventArray messages give height/width 0" if seen else
                      f"no {MSGTYPE} message in the bag" + (f" on topic '{topic}'" if topic
                                                            else ""),
                      SENSOR_SIZE_HINT)


def read(path: str | Path, t0: int | None = None, t1: int | None = None, *,
         topic: str | None = None, sensor_size: tuple[int, int] | None = None,
         validate: bool = True) -> EventArray:
    """Read the events of a ROS1 bag (``dvs_msgs/EventArray`` messages).

    Parameters
    ----------
    path : path-like
    t0, t1 : int, optional
        Keep ``t0 <= t < t1`` (µs since the Unix epoch, from the events' ``ts``).
    topic : str, optional
        Event topic (default: the first one carrying EventArray messages).
    sensor_size : (int, int), optional
        Overrides the messages' ``height``/``width``.
    validate : bool
        Check sortedness and bounds.

    Examples
    --------
    >>> ev = read("boxes.bag", topic="/dvs/events")  # doctest: +SKIP
    """
    path = Path(path)
    size = _first_size(path, topic, sensor_size)
    meta = {"source": str(path), "format": "rosbag"}
    return binary.collect(_blocks(path, topic, {}), size, meta, t0, t1, validate=validate)


def iter_chunks(path: str | Path, chunk_events: int, *, topic: str | None = None,
                sensor_size: tuple[int, int] | None = None,
                validate: bool = True) -> Iterator[EventArray]:
    """Stream a bag's events in chunks of ``chunk_events``, one message at a time."""
    chunk_events = binary.check_chunk_events(chunk_events)
    path = Path(path)
    size = _first_size(path, topic, sensor_size)
    meta = {"source": str(path), "format": "rosbag"}
    yield from binary.rechunk(_blocks(path, topic, {}), chunk_events, size, meta,
                               validate=validate)


#: A ROS1 time's seconds are uint32: times from here on cannot be written (µs)
_ROS_TIME_END_US = 2**32 * 1_000_000


def _serialize(events: EventArray, seq: int, frame_id: bytes) -> bytes:
    h, w = events.sensor_size
    ev = np.empty(len(events), _EVENT)
    ev["x"], ev["y"] = events.x, events.y
    ev["sec"] = events.t // 1_000_000
    ev["nsec"] = (events.t % 1_000_000) * 1000
    ev["p"] = events.p
    t_last = int(events.t[-1]) if len(events) else 0
    head = struct.pack("<IIII", seq, t_last // 1_000_000, (t_last % 1_000_000) * 1000,
                       len(frame_id)) + frame_id
    return head + struct.pack("<III", h, w, len(events)) + ev.tobytes()


def write(path: str | Path, events: EventArray, *, topic: str = "/dvs/events",
          message_us: int = 33_000, frame_id: str = "dvs") -> None:
    """Write ``events`` to a ROS1 bag as ``dvs_msgs/EventArray`` messages (atomically).

    Parameters
    ----------
    path : path-like
    events : EventArray
        Integer coordinates, times in µs since the Unix epoch (≥ 0).
    topic : str
        Topic name.
    message_us : int
        Time span of the events in one message (rpg_dvs_ros publishes ~30 Hz).
    frame_id : str
        Header frame id.

    Examples
    --------
    >>> write("out.bag", events)  # doctest: +SKIP
    """
    rosbag1, _ = _rosbags()
    if events.x.dtype.kind == "f":
        raise FormatError(None, "events have float (undistorted) coordinates; dvs_msgs "
                          "stores integer pixels")
    if int(message_us) <= 0:
        raise ParameterError(f"message_us must be positive, got {message_us}")
    if len(events) and events.t[0] < 0:
        raise FormatError(None, f"negative timestamp {events.t[0]} us cannot be a ROS time")
    if len(events) and events.t[-1] >= _ROS_TIME_END_US:
        raise FormatError(None, f"timestamp {events.t[-1]} us is past a ROS time's range "
                          "(uint32 seconds: before 2^32 s, the year 2106)")
    store = typestore()
    if len(events):
        edges = np.arange(int(events.t[0]), int(events.t[-1]) + int(message_us),
                          int(message_us))
        cuts = np.searchsorted(events.t, edges[1:], side="left")
        bounds = np.unique(np.concatenate([[0], cuts, [len(events)]]))
    else:
        # one message without events keeps the sensor size of an empty recording
        bounds = np.array([0, 0])
    with atomic_path(path) as tmp:
        tmp.unlink()
        with rosbag1.Writer(tmp) as writer:
            conn = writer.add_connection(topic, MSGTYPE, typestore=store)
            for seq, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
                part = events[int(a):int(b)]
                stamp_ns = int(part.t[-1]) * 1000 if len(part) else 0
                writer.write(conn, stamp_ns, _serialize(part, seq, frame_id.encode()))


def read_imu(path: str | Path, *, topic: str | None = None) -> ImuSamples:
    """The ``sensor_msgs/Imu`` messages of a bag (first IMU topic unless ``topic``).

    Examples
    --------
    >>> imu = read_imu("boxes.bag", topic="/dvs/imu")  # doctest: +SKIP
    """
    path = Path(path)
    store = typestore()
    t, acc, gyr = [], [], []
    reader = _open_bag(path)
    try:
        conns = _topic_connections(reader, IMU_MSGTYPE, topic)
        if not conns and topic is not None:
            raise FormatError(path, f"no {IMU_MSGTYPE} messages on topic '{topic}'")
        # an empty connection list would mean "every connection" to rosbags
        for conn, _, raw in reader.messages(connections=conns) if conns else ():
            m = store.deserialize_ros1(raw, conn.msgtype)
            t.append(m.header.stamp.sec * 1_000_000 + m.header.stamp.nanosec // 1000)
            a, g = m.linear_acceleration, m.angular_velocity
            acc.append((a.x, a.y, a.z))
            gyr.append((g.x, g.y, g.z))
    finally:
        reader.close()
    return ImuSamples(t=np.array(t, np.int64), accel=np.array(acc, float).reshape(-1, 3),
                      gyro=np.array(gyr, float).reshape(-1, 3))


def read_camera_info(path: str | Path, *, topic: str | None = None) -> dict | None:
    """The calibration of a bag's first ``sensor_msgs/CameraInfo`` message (rpg_dvs_ros
    publishes the sensor's on ``/dvs/camera_info``), as
    :func:`~evmotion.io.calibration.read_calibration`'s dict: ``K``, ``dist``
    (``D``), ``model`` (``distortion_model``), ``width``, ``height``, ``source``; None
    where the bag has none, or only an uncalibrated one (K all zeros, as the driver
    publishes before a calibration).

    Examples
    --------
    >>> cal = read_camera_info("boxes.bag")  # doctest: +SKIP
    >>> cal["model"], cal["K"][0][0]  # doctest: +SKIP
    ('plumb_bob', 199.09)
    """
    path = Path(path)
    store = typestore()
    reader = _open_bag(path)
    try:
        conns = _topic_connections(reader, CAMERA_INFO_MSGTYPE, topic, path)
        for conn, _, raw in reader.messages(connections=conns) if conns else ():
            try:
                m = store.deserialize_ros1(raw, conn.msgtype)
            except Exception:
                raise FormatError(path, f"corrupt {CAMERA_INFO_MSGTYPE} message on "
                                  f"'{conn.topic}' ({len(raw)} bytes)") from None
            k = np.asarray(m.K, dtype=float).reshape(3, 3)
            if not k.any():
                return None
            return {"K": k.tolist(), "dist": np.asarray(m.D, dtype=float).tolist(),
                    "model": m.distortion_model or "plumb_bob", "width": int(m.width),
                    "height": int(m.height), "source": f"{path} ({conn.topic})"}
    finally:
        reader.close()
    return None


def describe(path: str | Path) -> dict:
    """Topics with message types and counts, and the event count per EventArray topic."""
    rosbag1, _ = _rosbags()
    path = Path(path)
    try:
        with rosbag1.Reader(path) as reader:
            topics = {}
            for c in reader.connections:
                d = topics.setdefault(c.topic, {"type": c.msgtype, "messages": 0})
                d["messages"] += c.msgcount
            size = None
            n_events = 0
            conns = [c for c in reader.connections if c.msgtype == MSGTYPE]
            for _, _, raw in reader.messages(connections=conns):
                s, blk = _decode(raw, path)
                size = size or s
                n_events += len(blk[2])
    except FormatError:
        raise
    except Exception as exc:
        raise FormatError(path, f"cannot open as a ROS1 bag: {exc}") from None
    n_imu = sum(v["messages"] for v in topics.values() if v["type"] == "sensor_msgs/msg/Imu")
    return {"format": "rosbag", "topics": topics, "sensor_size": size,
            "n_events": n_events, "imu": n_imu, "frames": sum(
                v["messages"] for v in topics.values() if v["type"] == "sensor_msgs/msg/Image")}


def _sniff(path: Path, head: bytes) -> bool:
    return head.startswith(MAGIC)


FORMAT = FormatSpec(name="rosbag", extensions=(".bag",), sniff=_sniff, read=read,
                    iter_chunks=iter_chunks, write=write, describe=describe)
