"""``evmotion flow``: optical flow of a recording by one of several methods.

Each method lives in its own CLI module (``FLOW_METHODS``) that defines
``add_arguments(group)`` for its options, ``OPTIONS`` (``{"--flag": (attribute,
default)}``: the options only it reads), ``check_args(args)`` (options that do not go
together, seen before the defaults are filled in) and ``run(args) -> int``. An option of another
method is an error, not silently ignored; the defaults are filled in here. A method's
``run`` sets ``args.flow_summary`` (``windows``, ``events``, ``outputs``), from which
:func:`summary_line` prints the one line of a successful run. (These notes are for
developers: ``--help`` shows :data:`DESCRIPTION`.)

Every output (:mod:`evmotion.io.flowout`) says its units, each window's ``[t0, t1)`` in µs
and its validity mask (the pixels whose flow events support), by ``--out`` extension:
``.h5`` (the reference: flow in px/s, t0/t1, valid, attributes units/grid/method),
``.npz`` (the same arrays and units; not a bare ``.npy``, which is refused), ``.flo``
(Middlebury *displacement* in px over the window, by the format's convention, unknown where
not valid; ``NAME.flo.json`` beside it keeps ``dt_s``, ``t0_us``, ``t1_us`` and units) and
``.png`` (DSEC 16-bit *displacement*, the benchmark's format, with the same JSON sidecar).
``.flo``/``.png`` hold one window per file: several windows need an explicit pattern,
``--out flow_{:05d}.flo``. (``--method triplet`` writes its per-event flow to ``.h5`` or
``.npz``, :mod:`evmotion.io.eventflow`, and dense windows only when asked.) Pictures in
``--png-dir`` are numbered with 5 digits (``flow_00000.png``).

An ``.h5`` output is written window by window to ``OUT.part`` and renamed when complete;
an interrupted or failed run keeps the ``.part`` file, and ``--resume`` continues it (the
same command with ``--resume`` gives the file an uninterrupted run would have written).
The other outputs appear only when complete.
"""

from __future__ import annotations

import importlib
import time

from evmotion.cli.calib import add_camera_arguments, add_hot_pixel_argument, check_camera_args
from evmotion.cli.options import (
    HelpFormatter,
    add_sensor_size_argument,
    add_time_arguments,
    add_time_unit_argument,
    check_time_order,
    duration_us,
    event_format,
    existing_input,
    int_range,
    positive_float,
    positive_int,
    reject_unused,
    writable_folder,
    writable_output,
)
from evmotion.errors import ParameterError

DESCRIPTION = """Optical flow of a recording, window by window (multicm, dnn) or event by event
(triplet), written to one file.

Methods: multicm (multi-reference contrast maximization, ch. 4: dense, accurate, the
default), dnn (the unsupervised EV-FlowNet, one network pass per window), triplet (ch. 5:
per-event flow at millions of events per second; dense windows on request).
Windows: --window-events N (default 30000, as many per pixel on sensors over 346 x 260),
--window-us T or --window-gt GT; --t0/--t1
crop the recording (seconds, or with a unit: 1.5, 1500ms, 1500000us) and --max-windows N
keeps the first N windows. Flow is in px/s (u right, v down) on the sensor grid; .flo
stores Middlebury displacement over each window. On success one line says how many
windows and events went in, the time taken and the output (--json: a JSON summary).
"""

FLOW_METHODS: dict[str, str] = {
    "multicm": "evmotion.cli.flow_multicm",
    "dnn": "evmotion.cli.flow_dnn",
    "triplet": "evmotion.cli.flow_triplet",
}

EXAMPLES = """examples (sim.h5: made by 'evmotion simulate rotation --out sim.h5'):
  evmotion flow sim.h5 --method multicm --window-events 30000 --max-windows 2 --out flow.h5
  evmotion flow sim.h5 --method multicm --time-aware burgers --t0 0.02 --max-windows 1 --out flow.flo
  evmotion flow sim.h5 --method multicm --max-windows 3 --out flow_{:05d}.flo
  evmotion flow sim.h5 --method multicm --max-windows 2 --out flow.npz
  evmotion flow rec.raw --method triplet --out triplet.h5 --json
  evmotion flow rec.raw --method triplet --dense robust --t1 +0.03 --out robust.h5 --resume
  evmotion flow window.txt --method dnn --window-events 30000 --max-windows 1 --out x.flo
  evmotion flow boxes_rotation/ --max-windows 1 --out ecd_flow.h5
  evmotion flow sim.h5 --K 200,200,120,90 --dist=-0.1,0.02,0,0 --max-windows 1 --out k.h5
(an ECD folder is undistorted with its calib.txt; --calib FILE reads Kalibr/ROS/DSEC YAML,
DV XML or JSON intrinsics)
"""

OUTPUT_SUFFIXES = (".h5", ".hdf5", ".flo", ".npz", ".png")
_CHECK_OUT = writable_output(OUTPUT_SUFFIXES, "a flow file (.h5, .npz: all windows; .flo, "
                             ".png: per window)")


def _flow_output(text: str) -> str:
    """``--out``'s check; a bare ``.npy`` passes it to get its own advice (write .npz)
    once the options are parsed, and is not listed as an output it can write."""
    return text if text.lower().endswith(".npy") else _CHECK_OUT(text)


def _method_modules():
    for name, modname in FLOW_METHODS.items():
        try:
            yield name, importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise


def add_parser(sub) -> None:
    p = sub.add_parser(
        "flow", help="optical flow (multi-reference CMax, triplet matching, network)",
        description=DESCRIPTION, epilog=EXAMPLES,
        formatter_class=HelpFormatter,
    )
    p.add_argument("file", help="recording (any readable format)")
    p.add_argument("--method", default="multicm", choices=sorted(FLOW_METHODS),
                   help="flow method (default multicm)")
    p.add_argument("--out", required=True, type=_flow_output,
                   help="output: .h5 (all windows, px/s, t0/t1, valid; resumable; triplet: "
                        "per event unless --dense or a window option), .npz (the same "
                        "arrays; triplet: per event), .flo (Middlebury displacement in "
                        "px, dt/t0/t1 in NAME.flo.json) or .png (DSEC 16-bit displacement, "
                        "same sidecar); several .flo/.png windows need a pattern: "
                        "--out flow_{:05d}.flo")
    p.add_argument("--format", type=event_format, default=None,
                   help="input format (default: detect)")
    add_sensor_size_argument(p)
    add_time_unit_argument(p)
    win = p.add_mutually_exclusive_group()
    win.add_argument("--window-events", type=int_range(10), default=None, metavar="N",
                     help="events per window (>= 10; default 30000, as many per pixel on "
                          "sensors larger than 346 x 260; a dense flow of fewer than 1000, "
                          "or 0.05 a pixel on a small sensor, is no measurement)")
    win.add_argument("--window-us", type=duration_us, default=None, metavar="T",
                     help="windows of this duration instead: microseconds, or with a unit "
                          "(10000, 10ms, 0.01s)")
    win.add_argument("--window-gt", type=existing_input, default=None, metavar="GT",
                     help="ground-truth file whose timestamps define the windows")
    p.add_argument("--gt-dt", type=positive_int(), default=None,
                   help="frames per window with --window-gt (default 1)")
    p.add_argument("--png-dir", type=writable_folder("colour-wheel and IWE PNGs"), default=None,
                   help="folder for colour-wheel and IWE PNGs")
    p.add_argument("--resume", action="store_true",
                   help=".h5 output: continue the OUT.part file an interrupted run kept "
                        "(same options), computing only the windows it lacks (triplet "
                        "matches every event again, its matcher's state being the events "
                        "before; only the kept windows' dense fits are saved)")
    p.add_argument("--max-speed", type=positive_float(unit="px/s"), default=None,
                   metavar="PX_S",
                   help="speed at the colour wheel's rim in px/s, one scale for every picture "
                        "(default: each picture's own maximum, said so in its legend)")
    p.add_argument("--video", default=None, metavar="MP4", type=writable_output((".mp4",)),
                   help="video of the windows: events | warped IWE | flow (needs the 'video' "
                        "extra; multicm and dnn)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    add_hot_pixel_argument(p)
    add_camera_arguments(p.add_argument_group(
        "camera (the flow is estimated on the undistorted grid when the calibration has "
        "distortion; the output's 'grid' attribute says which)"))
    add_time_arguments(p, what="windows (multicm, dnn)")
    for name, mod in _method_modules():
        mod.add_arguments(p.add_argument_group(f"{name} options"))
    p.set_defaults(func=run)


def run(args) -> int:
    check_camera_args(args)
    check_time_order(args)
    if args.method == "triplet":
        reject_unused(args, {"--max-windows": "max_windows"},
                      "with --method triplet (it streams the recording: crop it with --t1)")
        reject_unused(args, {"--remove-hot-pixels": "remove_hot_pixels"},
                      "with --method triplet (a hot pixel's events find no triplet partner)")
    if args.window_gt is None:
        reject_unused(args, {"--gt-dt": "gt_dt"}, "without --window-gt")
    if args.png_dir is None and args.video is None:
        # (accepted, and no picture drawn to scale; probe CI)
        reject_unused(args, {"--max-speed": "max_speed"},
                      "without --png-dir or --video (no picture)")
    args.gt_dt = 1 if args.gt_dt is None else args.gt_dt
    if args.resume and args.out.lower().endswith((".npy", ".flo", ".npz", ".png")):
        raise ParameterError(f"--resume continues an .h5 output; --out {args.out} is written "
                             "whole at the end (an interrupted run leaves nothing)")
    mod = importlib.import_module(FLOW_METHODS[args.method])
    # another method's options this one also reads (multicm's --init dnn: the network's)
    borrowed = getattr(mod, "borrowed_options", lambda a: ())(args)
    defaults = dict(mod.OPTIONS.values())
    for name, modname in FLOW_METHODS.items():
        if name != args.method:
            options = importlib.import_module(modname).OPTIONS
            reject_unused(args, {flag: attr for flag, (attr, _) in options.items()
                                 if flag not in borrowed},
                          f"with --method {args.method} (a {name} option)", mod.OPTIONS)
            # a borrowed option has its owner's default
            defaults.update(options[flag] for flag in borrowed if flag in options)
    mod.check_args(args)  # sees which options were given, before the defaults fill in
    for attr, default in defaults.items():
        if getattr(args, attr, None) is None:
            setattr(args, attr, default)
    start = time.perf_counter()
    rc = mod.run(args)
    if rc == 0 and not args.json:
        print(summary_line(args, time.perf_counter() - start))
    return rc


def summary_line(args, seconds: float) -> str:
    """The one line ``flow`` prints on success: windows, events, time and output, from
    ``args.flow_summary`` (``windows``, ``events``, ``outputs``, ``skipped``, ``resumed``,
    ``undistorted``) that a method's ``run`` sets; what a method does not report is left
    out."""
    info = getattr(args, "flow_summary", None) or {}
    parts = [f"{args.method}:"]
    if info.get("windows") is not None:
        # (as bos says it: a resumed run did not say how much it had reused, probe BH;
        # "earlier", not "interrupted": a finished output extended is resumed too, BK)
        notes = [f"{info['skipped']:,} skipped: no flow"] if info.get("skipped") else []
        notes += [f"{info['resumed']:,} kept from the earlier run"] \
            if info.get("resumed") else []
        parts.append(f"{info['windows']:,} window{'' if info['windows'] == 1 else 's'}"
                     + (f" ({'; '.join(notes)})," if notes else ","))
    if info.get("events") is not None:
        parts.append(f"{info['events']:,} events,")
    outputs = info.get("outputs") or [args.out]
    shown = outputs[0] if len(outputs) == 1 else f"{outputs[0]} ... {outputs[-1]} " \
                                                  f"({len(outputs)} files)"
    parts.append(f"{seconds:.1f} s -> {shown}")
    if info.get("undistorted"):
        # a calibration beside the recording moved the flow off the sensor's pixel grid:
        # said here, as a .flo cannot say it
        parts.append("(on the undistorted pixel grid; --no-undistort keeps the sensor's)")
    return " ".join(parts)
