"""Camera options shared by every command that needs or can use intrinsics.

:func:`add_camera_arguments` adds ``--calib FILE``, ``--K fx,fy,cx,cy``, ``--dist
k1,k2,p1,p2[,k3]`` and ``--no-undistort`` (values checked as they are parsed: one line, exit
code 2). :func:`camera_for` picks the camera (``--K``, else ``--calib``, else the
recording's own: an ECD folder's ``calib.txt``, an evmotion HDF5 ``calibration``, a jAER
header's lens focal length) and :func:`undistort_for` applies the one distortion rule of
every command: events are undistorted (:meth:`evmotion.camera.Camera.undistort_events`)
whenever the calibration has distortion, unless ``--no-undistort``; the returned ``grid``
label says which pixel grid the results live on.
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import math
from collections.abc import Iterator

from evmotion.cli.options import existing_input, float_list
from evmotion.errors import CalibrationError, ParameterError

#: Widest field of view across the sensor --K is taken without a word, degrees
MAX_FOV_DEG = 170.0

__all__ = ["add_camera_arguments", "add_hot_pixel_argument", "camera_for", "undistort_for",
           "undistorted_chunks", "check_camera_args", "read_for_windows"]


def _intrinsics(text: str) -> list[float]:
    from evmotion.io.calibration import MAX_FOCAL_PX, MIN_FOCAL_PX

    vals = float_list(4, unit="px")(text)
    if not all(MIN_FOCAL_PX <= v <= MAX_FOCAL_PX for v in vals[:2]):
        # the limits of a calibration file's focal lengths (1e-9 failed later, naming
        # no option; 1e30 was taken)
        raise argparse.ArgumentTypeError(f"focal lengths fx, fy must be in [{MIN_FOCAL_PX:g}, "
                                         f"{MAX_FOCAL_PX:g}] px, got {text!r}")
    return vals


def _distortion(text: str) -> list[float]:
    from evmotion.io.calibration import MAX_DISTORTION

    vals = float_list()(text)
    if len(vals) not in (4, 5):
        raise argparse.ArgumentTypeError(
            f"must be 4 or 5 comma-separated numbers (k1,k2,p1,p2[,k3]), got {len(vals)} in "
            f"{text!r}")
    if any(abs(v) > MAX_DISTORTION for v in vals):
        raise argparse.ArgumentTypeError(f"coefficients beyond +-{MAX_DISTORTION:g} are not "
                                         f"a lens, got {text!r}")
    return vals


def add_camera_arguments(p) -> None:
    """``--calib``, ``--K``, ``--dist`` and ``--no-undistort`` on parser (or group) ``p``."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--calib", default=None, type=existing_input, metavar="FILE",
                   help="calibration file: ECD calib.txt, Kalibr camchain YAML, ROS "
                        "camera_info YAML, DSEC cam_to_cam.yaml, DV calibration XML or "
                        "evmotion JSON; pinhole with radial-tangential distortion only, "
                        "fisheye / equidistant models are refused (default: the "
                        "recording's own, if any)")
    g.add_argument("--K", default=None, type=_intrinsics, metavar="FX,FY,CX,CY",
                   help="camera intrinsics in px (instead of --calib)")
    p.add_argument("--dist", default=None, type=_distortion, metavar="K1,K2,P1,P2[,K3]",
                   help="radial-tangential distortion, with --K (default none); write "
                        "--dist=-0.37,0.15,0,0 when k1 is negative")
    p.add_argument("--no-undistort", action="store_true",
                   help="keep the events on the distorted sensor grid even when the "
                        "calibration has distortion (default: undistort)")


def check_camera_args(args) -> None:
    """``--dist`` goes with ``--K`` only."""
    if getattr(args, "dist", None) is not None and getattr(args, "K", None) is None:
        raise ParameterError(f"--dist {','.join(f'{v:g}' for v in args.dist)} needs --K "
                             "(a --calib file or the recording brings its own distortion)")


def camera_for(args, sensor_size, events_meta: dict | None = None):
    """The camera of this run (``--K``, ``--calib`` or the recording's own), fitted to
    ``sensor_size`` (height, width); None when no intrinsics are known."""
    from evmotion.camera import Camera, warn_strong_distortion
    from evmotion.io.calibration import read_camera, recording_camera

    check_camera_args(args)
    if getattr(args, "K", None) is not None:
        _check_principal_point(args.K, sensor_size)
        dist = list(args.dist or [])
        cam = Camera(*args.K, dist=tuple(dist + [0.0] * (5 - len(dist))),
                     sensor_size=sensor_size, source="--K")
        warn_strong_distortion(cam, "--dist")
        return cam
    if getattr(args, "calib", None):
        return read_camera(args.calib, sensor_size=sensor_size).for_sensor(sensor_size)
    cam = recording_camera(args.file, events_meta, sensor_size)
    return None if cam is None else cam.for_sensor(sensor_size)


def _check_principal_point(k, sensor_size) -> None:
    """Say when --K puts the principal point off the sensor, and refuse it far off (as a
    calibration file's): most often the four values were given in another order than
    fx,fy,cx,cy, or are another camera's (a cropped sensor can have it just outside)."""
    from evmotion.io.calibration import principal_point_far_off

    h, w = sensor_size
    cx, cy = k[2], k[3]
    if principal_point_far_off(cx, cy, sensor_size):
        raise ParameterError(f"--K: the principal point (cx, cy) = ({cx:g}, {cy:g}) px lies "
                             f"far outside the {w} x {h} px sensor: the order is "
                             "FX,FY,CX,CY, on this sensor's grid")
    if not (0 <= cx <= w and 0 <= cy <= h):
        from evmotion.cli import warn_line

        warn_line(f"--K: the principal point (cx, cy) = ({cx:g}, {cy:g}) px lies outside the "
                  f"{w} x {h} px sensor; the order is FX,FY,CX,CY")
    # a focal length whose field of view across the sensor exceeds 170 degrees: a lens
    # no event camera carries (--K 2,2,125,86 on 240x180 ran, unsaid; probe)
    fov = max(2 * math.degrees(math.atan(0.5 * w / k[0])),
              2 * math.degrees(math.atan(0.5 * h / k[1])))
    if fov > MAX_FOV_DEG:
        from evmotion.cli import warn_line

        warn_line(f"--K: fx, fy = {k[0]:g}, {k[1]:g} px give a {fov:.0f} degree field of view "
                  f"across the {w} x {h} px sensor: focal lengths in mm, or another sensor's? "
                  "(the order is FX,FY,CX,CY in px)")


def _grid(cam, events, undistort: bool) -> str:
    if events.x.dtype.kind == "f" or events.meta.get("undistorted"):
        return "undistorted (as recorded)"
    if cam is None:
        return "sensor (no calibration known)"
    return cam.grid_label(undistorted=undistort or not cam.is_distorted)


def _distortion_rule(args, first):
    """``(camera, undistort, grid)`` for a recording whose events (or first chunk) are
    ``first``: the one rule of every command."""
    cam = camera_for(args, first.sensor_size, first.meta)
    undistort = (cam is not None and cam.is_distorted and first.x.dtype.kind != "f"
                 and not getattr(args, "no_undistort", False))
    return cam, undistort, _grid(cam, first, undistort)


def say_undistortion_loss(lost: int, n: int) -> None:
    """One line where undistortion left out ``lost`` of ``n`` events, a share over
    :data:`UNDISTORT_LOSS_NOTE`."""
    if lost > UNDISTORT_LOSS_NOTE * n:
        # a large share is worth knowing (a wide-angle lens, or the wrong calibration)
        from evmotion.cli import warn_line

        warn_line(f"undistortion moved {lost:,} of {n:,} events ({100 * lost / n:.0f} %) "
                  "outside the image: they are left out (--no-undistort keeps the "
                  "sensor's grid)")


def undistort_for(args, events, *, integer: bool = False):
    """``(events, camera, grid)``: the events undistorted when the camera has distortion and
    ``--no-undistort`` is not given; ``integer`` rounds to the pixel lattice (methods that
    need integer pixels)."""
    cam, undistort, grid = _distortion_rule(args, events)
    if undistort:
        n = len(events)
        events = cam.undistort_events(events, integer=integer)
        if n and not len(events):
            # (said here: "the recording holds no events" followed, of 30,000: probe)
            raise CalibrationError(f"{cam.source}: undistortion moved all {n:,} events "
                                   "outside the image: the wrong calibration for this "
                                   "sensor? (--no-undistort keeps the sensor's grid)")
        say_undistortion_loss(n - len(events), n)
    return events, cam, grid


def add_hot_pixel_argument(p) -> None:
    """``--remove-hot-pixels``, which :func:`read_for_windows` applies."""
    from evmotion.catalog import HOT_NEIGHBOUR_RATIO

    p.add_argument("--remove-hot-pixels", action="store_true",
                   help="drop the events of hot pixels (far busier than the median pixel "
                        f"and {HOT_NEIGHBOUR_RATIO:g}x each neighbour, or than the pixels "
                        "either side of a stuck row or column) before the windows are cut: a "
                        "few hot pixels hold a warp at rest")


def events_held(kept: int, events) -> int:
    """How many events the recording held where ``kept`` of ``events`` are left:
    undistortion leaves out those it moves off the image (``meta["undistort_dropped"]``)
    and says so itself, so a window short by them is not short of events."""
    return kept + int(events.meta.get("undistort_dropped", 0))


# share of the events on hot pixels from which a command offering --remove-hot-pixels says
# so when it was not given (40 pixels holding 10 % brought a flow to 0.62-0.77x, valid,
# unsaid; the shared real recordings hold 0-0.32 %)
HOT_EVENTS_NOTE = 0.02


def _hot_pixels_handled(args, events):
    """``events`` less its hot pixels' with ``--remove-hot-pixels`` (said in one line), or
    as they are, with one line naming the option where hot pixels hold
    :data:`HOT_EVENTS_NOTE` of them or more."""
    from evmotion.filters import pixel_counts, remove_hot_pixels

    if not args.remove_hot_pixels and getattr(args, "method", None) == "dnn":
        # the network sets a hot pixel's flow to zero and leaves its events out of its
        # checks itself: nothing to say, and its mask cost a 1280 x 720 window 0.1 s twice
        return events
    mask = hot_pixels_to_drop(args, pixel_counts(events))
    return events if mask is None else remove_hot_pixels(events, mask)


def hot_pixels_to_drop(args, counts):
    """The (H, W) mask of the hot pixels whose events ``--remove-hot-pixels`` drops (said
    in one line), from a recording's per-pixel event ``counts``
    (:func:`evmotion.filters.pixel_counts`); None when none are dropped, with one line
    naming the option where hot pixels hold :data:`HOT_EVENTS_NOTE` of the events or more."""
    from evmotion.catalog import HOT_NEIGHBOUR_RATIO
    from evmotion.cli import warn_line
    from evmotion.filters import hot_pixel_mask_of_counts

    mask = hot_pixel_mask_of_counts(counts, neighbour_ratio=HOT_NEIGHBOUR_RATIO)
    if not mask.any():
        return None
    n, hot = int(counts.sum()), int(counts[mask].sum())
    if args.remove_hot_pixels:
        warn_line(f"{args.file}: --remove-hot-pixels dropped {int(mask.sum())} hot pixels "
                  f"({hot:,} of {n:,} events)")
        return mask
    if hot >= HOT_EVENTS_NOTE * n:
        warn_line(f"{args.file}: {int(mask.sum())} hot pixels (each far busier than its "
                  f"neighbours, or on a stuck row or column) hold {hot / n:.0%} of the "
                  "events: their events do not move and pull the estimate toward rest; "
                  "--remove-hot-pixels drops them")
    return None


def read_for_windows(args, *, n_events: int | None = None, duration_us: int | None = None,
                     min_events: int = 1):
    """``(events, camera, grid)`` of ``args.file`` as :func:`undistort_for` gives them,
    hot pixels handled as ``--remove-hot-pixels`` says where the command offers it. With
    ``--max-windows`` and windows cut by count (``n_events``) or duration (``duration_us``),
    only the part the first N windows within ``--t0``/``--t1`` need is read, as a stream
    (:func:`evmotion.events.events_for_windows`): the first windows of a long recording
    neither wait for all of it nor hold it in memory. Otherwise the span ``--t0``/``--t1``
    select, or the whole recording without them or when that part holds no such window
    (the refusal then names the recording's span)."""
    from evmotion.cli.options import read_kwargs
    from evmotion.events import events_for_windows, make_windows
    from evmotion.io import iter_events, read_events

    kw = read_kwargs(args)
    n_max = getattr(args, "max_windows", None)
    if n_max is not None and (n_events is not None or duration_us is not None):
        t0, t1 = getattr(args, "t0", None), getattr(args, "t1", None)
        # closed when done: the rest of the file is not read, and its handle not kept
        with contextlib.closing(iter_events(args.file, CHUNK_EVENTS, t0=t0, t1=t1,
                                            **kw)) as chunks:
            read = [0]

            def counted():
                for chunk in chunks:
                    read[0] += len(chunk)
                    yield chunk

            undistorted = undistorting(args, counted(), integer=False)
            if undistorted is not None:
                stream, cam, grid = undistorted
                events = events_for_windows(stream, max_windows=n_max, n_events=n_events,
                                            duration_us=duration_us, t0=t0,
                                            min_events=min_events)
                if events is not None and make_windows(
                        events, n_events=n_events, duration_us=duration_us, t0=t0, t1=t1,
                        max_windows=n_max, min_events=min_events):
                    say_undistortion_loss(read[0] - len(events), read[0])
                    return _hot_pixels_checked(args, (events, cam, grid))
    t0, t1 = getattr(args, "t0", None), getattr(args, "t1", None)
    if t0 is not None or t1 is not None:
        # only the span asked for (a 0.3 s window of a 29M-event file held 987 MB; probe AJ);
        # the whole recording only when it holds nothing there, for the refusal to name its
        # span (hence no warning here)
        part = read_events(args.file, t0=t0, t1=t1, warn_empty=False, **kw)
        if len(part):
            return _hot_pixels_checked(args, undistort_for(args, part))
    return _hot_pixels_checked(args, undistort_for(args, read_events(args.file, **kw)))


def _hot_pixels_checked(args, read: tuple):
    events, cam, grid = read
    if getattr(args, "remove_hot_pixels", None) is None or not len(events):
        return read
    return _hot_pixels_handled(args, events), cam, grid


# events read at a time by read_for_windows
CHUNK_EVENTS = 1 << 20
# the share of events undistortion may move out of the image before it is said
UNDISTORT_LOSS_NOTE = 0.05


def undistorted_chunks(args, chunks: Iterator, *, integer: bool = True
                       ) -> tuple[Iterator, str]:
    """A chunk stream undistorted like :func:`undistort_for` (the camera resolved from the
    first non-empty chunk), and its grid label."""
    undistorted = undistorting(args, chunks, integer=integer)
    if undistorted is None:
        return iter(()), "sensor (no calibration known)"
    return undistorted[0], undistorted[2]


def undistorting(args, chunks: Iterator, *, integer: bool):
    """``(stream, camera, grid)``: ``chunks`` undistorted by the rule of
    :func:`undistort_for`, the camera resolved from the first non-empty chunk; None when
    there is none."""
    first = next((c for c in chunks if len(c)), None)
    if first is None:
        return None
    cam, undistort, grid = _distortion_rule(args, first)

    def stream():
        for chunk in itertools.chain((first,), chunks):
            yield cam.undistort_events(chunk, integer=integer) if undistort else chunk

    return stream(), cam, grid
