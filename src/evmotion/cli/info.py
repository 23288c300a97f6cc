"""``evmotion info``: what a recording holds.

Sensor size, event count, time range, duration, event rate, polarity balance, what else the
file holds (APS frames, IMU, ground truth, calibration), and the camera intrinsics the
recording brings (``intrinsics``: K = fx, fy, cx, cy in px, distortion k1 k2 p1 p2 k3,
resolution and the file or header they come from). Events are streamed chunk by chunk, so
memory stays bounded for any file size (NumPy, MATLAB and other tools' HDF5 layouts are read
whole: their declared sizes are checked against what the file stores). A flow output of
``evmotion flow`` (any container, or a per-window pattern) is described by its container,
windows, time range, units, grid and valid fraction; a parameters file (``egomotion``'s
``params.h5``, ``segment``'s ``clusters.h5``) by its windows, parameters with their units,
warp, grid, valid fraction and flags."""

from __future__ import annotations

from evmotion.catalog import MAX_SENSOR_SIDE
from evmotion.cli.options import (
    HelpFormatter,
    add_time_unit_argument,
    event_format,
    int_range,
)

EXAMPLES = """examples:
  evmotion info boxes_rotation/                # an ECD folder
  evmotion info rec.h5 --json                  # machine-readable
  evmotion info rec.raw --header-only          # no pass over the events
  evmotion info flow.h5                        # a flow output: windows, times, units, valid
  evmotion info 'flow_{:05d}.flo'              # per-window flow files, by their pattern
  evmotion info ego/params.h5                  # egomotion's parameters: units, warp, grid
"""

_HIDDEN = {"path", "format"}


def add_parser(sub) -> None:
    p = sub.add_parser(
        "info", help="sensor size, event count, duration, rate and contents of a recording",
        description=__doc__, epilog=EXAMPLES,
        formatter_class=HelpFormatter,
    )
    p.add_argument("file", help="recording (file or ECD folder), any readable format, or a "
                                "flow output")
    p.add_argument("--format", type=event_format, default=None,
                   help="input format (default: detect by content)")
    p.add_argument("--sensor-size", type=int_range(1, MAX_SENSOR_SIDE, unit="px"), nargs=2,
                   default=None, metavar=("H", "W"),
                   help="override the sensor size (height width)")
    add_time_unit_argument(p)
    p.add_argument("--header-only", action="store_true",
                   help="report the header / layout only, without streaming the events")
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(func=run)


def _fmt_value(v) -> str:
    if isinstance(v, float):
        return f"{v:,.6g}"
    if isinstance(v, int) and not isinstance(v, bool):
        return f"{v:,}"
    if isinstance(v, dict):
        # a dict of dicts (a bag's topics: type and message count) as "key (its values)"
        return ", ".join(f"{k} ({_fmt_value(x)})" if isinstance(x, dict) else
                         f"{k}={_fmt_value(x)}" for k, x in v.items()
                         if not isinstance(x, list))
    return str(v)


def summarize(info: dict) -> list[str]:
    """Human-readable lines for an :func:`evmotion.io.describe` result."""
    lines = [f"file:        {info['path']}", f"format:      {info['format']}"]
    if info.get("sensor_size") is not None:
        h, w = info["sensor_size"]
        lines.append(f"sensor:      {w} x {h} px (W x H)")
    elif "sensor_size" in info:
        lines.append("sensor:      unknown (its header does not say; --sensor-size H W)")
    if "n_events" in info:
        lines.append(f"events:      {info['n_events']:,}")
    if info.get("t_first_us") is not None:
        # in s too: --t0 / --t1 take seconds
        lines.append(f"time range:  {info['t_first_us']:,} .. {info['t_last_us']:,} us "
                     f"({info['t_first_us'] * 1e-6:.6f} .. {info['t_last_us'] * 1e-6:.6f} s, "
                     "as --t0/--t1 take it)")
    if info.get("duration_s") is not None:
        lines.append(f"duration:    {info['duration_s']:.6f} s")
    if info.get("rate_ev_per_s"):
        lines.append(f"rate:        {_rate_text(info['rate_ev_per_s'])}")
    if info.get("positive_fraction") is not None:
        lines.append(f"polarity:    {100 * info['positive_fraction']:.1f}% positive")
    shown = {"path", "format", "sensor_size", "n_events", "t_first_us", "t_last_us",
             "duration_s", "rate_ev_per_s", "positive_fraction"}
    intr = info.get("intrinsics")
    if isinstance(intr, dict):
        shown.add("intrinsics")
        if intr.get("K"):
            size = intr.get("resolution")
            lines.append("intrinsics:  K=[" + ", ".join(f"{v:.6g}" for v in intr["K"])
                         + "] dist=[" + ", ".join(f"{v:.6g}" for v in intr["dist"]) + "]"
                         + (f" {size[1]} x {size[0]} px" if size else "")
                         + f" from {intr['source']}")
        else:
            lines.append(f"intrinsics:  none ({intr.get('reason', 'not in the recording')})")
            # the reason above is that error (it was said twice, probe BOSIN)
            shown.add("calibration_error")
    for k, v in info.items():
        if k not in shown:
            lines.append(f"{k + ':':<12} {_fmt_value(v)}")
    return lines


def _rate_text(rate: float) -> str:
    """An event rate in M events/s, or events/s below 0.01 M (a 184 events/s recording
    showed 0.000 M events/s; probe CS).

    Examples
    --------
    >>> _rate_text(2.5e6), _rate_text(184.3)
    ('2.500 M events/s', '184 events/s')
    """
    return f"{rate / 1e6:.3f} M events/s" if rate >= 1e4 else f"{rate:,.0f} events/s"


def run(args) -> int:
    import warnings

    import evmotion.io as eio
    from evmotion.cli import print_json
    from evmotion.cli.options import read_kwargs
    from evmotion.errors import UnusedCalibrationWarning
    from evmotion.io.flowread import describe_flow
    from evmotion.io.registry import own_output_folder

    kw = read_kwargs(args)
    kw.pop("format", None)
    # an output folder of egomotion or segment: what its parameters file holds
    found = own_output_folder(args.file) if args.format is None else None
    target = args.file if found is None else found[0]
    info = describe_flow(target) if args.format is None else None
    if info is None and args.format is None:
        from evmotion.io.paramsfiles import describe_params

        info = describe_params(target)
    if info is None:
        with warnings.catch_warnings():
            # info reports the calibration itself, on its intrinsics line
            warnings.simplefilter("ignore", UnusedCalibrationWarning)
            info = eio.describe(args.file, format=args.format, stream=not args.header_only,
                                progress=True, **kw)
        # (a raw file with no event, given --format and --sensor-size, has none: it ended
        # in a TypeError traceback, probe BY)
        if info.get("sensor_size") is not None:
            from evmotion.io.calibration import recording_intrinsics

            info["intrinsics"] = recording_intrinsics(args.file, tuple(info["sensor_size"]))
    if str(args.file).endswith(".part"):
        # what an interrupted run leaves (flow, bos, ...): readable, but not finished
        info["status"] = ("unfinished: an interrupted run's partial output; run the same "
                          "command with --resume to complete it")
    if args.json:
        print_json(info)
    else:
        print("\n".join(summarize(info)))
    return 0
