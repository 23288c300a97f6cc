"""``evmotion convert``: copy events from one format to another, streaming.

The input format is detected by content, the output format follows the extension of OUT
(``.h5`` evmotion HDF5, ``.txt`` ECD text, ``.npz``, ``.raw``, ``.dat``, ``.aedat4``...)
unless given. Events go chunk by chunk for the streaming writers (``h5``, ``ecd``,
``dat``, ``evt2``, ``evt21``, ``evt3``, ``aedat2``, ``aedat3``, ``aedat4``), so a file of
any size converts to them in bounded memory (``npz``/``npy``, ``mvsec``, ``dsec`` and
``rosbag`` hold the events whole); the output appears only when complete.

IMU samples and APS frames (within --t0/--t1) go along where the output format can hold them
(``.h5``: its ``imu`` and ``frames`` groups); each stream the output cannot hold is named
in one warning line on stderr.
"""

from __future__ import annotations

from evmotion.catalog import MAX_SENSOR_SIDE
from evmotion.cli.options import (
    HelpFormatter,
    add_time_unit_argument,
    check_output_format,
    check_time_order,
    check_time_unit,
    empty_selection,
    event_format,
    int_range,
    positive_int,
    time_us,
    writable_output,
)
from evmotion.errors import EventDataError, UnsortedError

EXAMPLES = """examples:
  evmotion convert boxes_rotation/ boxes.h5       # ECD folder -> evmotion HDF5 (+ IMU, frames)
  evmotion convert rec.raw first_20ms.h5 --t1 +0.02      # + : from the first event; 20ms, 20000us
  evmotion convert rec.h5 out.txt --format-in h5 --json
  evmotion convert rec.h5 out.aedat4 --t1 +30ms
  evmotion convert rec.h5 sorted.h5 --sort         # timestamps out of order -> sorted
"""


def add_parser(sub) -> None:
    p = sub.add_parser(
        "convert", help="convert events between formats (streaming, atomic output)",
        description=__doc__, epilog=EXAMPLES,
        formatter_class=HelpFormatter,
    )
    p.add_argument("input", help="recording (file or ECD folder)")
    p.add_argument("output", type=writable_output(), nargs="?", default=None,
                   help="output file; its extension picks the format")
    p.add_argument("--out", type=writable_output(), default=None, dest="out_option",
                   metavar="OUTPUT", help="the output file, as the other commands take it "
                                          "(instead of the positional OUTPUT)")
    p.add_argument("--format-in", type=event_format, default=None,
                   help="input format (default: detect)")
    p.add_argument("--format-out", default=None, help="output format (default: extension)")
    p.add_argument("--t0", type=time_us, default=None, metavar="TIME",
                   help="start: seconds on the recording's clock, or with a unit (1.5, "
                        "1500ms, 1500000us); +TIME: after the first event")
    p.add_argument("--t1", type=time_us, default=None, metavar="TIME",
                   help="end (exclusive), same units as --t0")
    p.add_argument("--sensor-size", type=int_range(1, MAX_SENSOR_SIDE, unit="px"), nargs=2,
                   default=None, metavar=("H", "W"),
                   help="override the input sensor size (height width)")
    p.add_argument("--chunk-events", type=positive_int(), default=1_000_000,
                   help="events read and written at a time (1,000,000)")
    add_time_unit_argument(p)
    p.add_argument("--sort", action="store_true",
                   help="sort the events by time (stable) for a recording whose timestamps "
                        "are not in order; reads the whole recording into memory")
    p.add_argument("--invert-polarity", action="store_true",
                   help="write ON as OFF and OFF as ON (a sensor or tool that stores them the "
                        "other way round)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    import time
    from pathlib import Path

    import evmotion.io as eio
    from evmotion.cli import print_json, warn_line
    from evmotion.cli.options import header_event_count
    from evmotion.errors import ParameterError
    from evmotion.utils import progress, refine_total

    if (args.output is None) == (args.out_option is None):
        raise ParameterError("give the output file once: as the second argument or as --out"
                             if args.output is None else
                             f"two outputs: {args.output} and --out {args.out_option}")
    src, dst = Path(args.input), Path(args.output or args.out_option)
    check_time_order(args)
    if src.resolve() == dst.resolve():
        raise ParameterError(f"input and output are the same file: {src}")
    fmt_in = args.format_in or eio.detect_format(src)
    fmt_out = args.format_out or eio.format_for_output(dst, "--format-out")
    _check_writable(fmt_out)
    check_output_format(dst, fmt_out, "--format-out")
    kw = {}
    if args.sensor_size is not None:
        kw["sensor_size"] = tuple(args.sensor_size)
    if args.time_unit is not None:
        check_time_unit(args.time_unit, src, fmt_in)
        kw["time_unit"] = args.time_unit
    # the longest pause between events: one corrupt time field moved half an EVT3 file
    # 16.8 s on, which info and read_events said and convert wrote unsaid (probe BL)
    counted = {"n": 0, "t_first": None, "t_last": None, "gap": (0, 0)}

    def chunks():
        if args.sort:
            whole = eio.read_events(src, format=fmt_in, validate=False, **kw).sorted()
            whole = whole.slice_time(args.t0, args.t1)
            it = (whole[s:s + args.chunk_events] for s in range(0, len(whole),
                                                                args.chunk_events))
        else:
            it = eio.iter_events(src, args.chunk_events, format=fmt_in, t0=args.t0,
                                 t1=args.t1, **kw)
        # events, not chunks, with the total when the header states it (rate and ETA)
        total = header_event_count(src, fmt_in, args.t0, args.t1)
        bar = progress(None, total=total, desc="convert", unit="ev", unit_scale=True)
        try:
            for chunk in it:
                if args.invert_polarity:
                    chunk = chunk.with_polarity_inverted()
                if len(chunk):
                    _longest_pause(counted, chunk.t)
                    counted["n"] += len(chunk)
                    if counted["t_first"] is None:
                        counted["t_first"] = int(chunk.t[0])
                    counted["t_last"] = int(chunk.t[-1])
                    if total is None and args.t0 is None and args.t1 is None:
                        # else the share of the file read (EVT RAW, text), which says
                        # how many events a whole file's conversion makes: rate and ETA
                        refine_total(bar, counted["n"], chunk.meta)
                    bar.update(len(chunk))
                yield chunk
        finally:
            bar.close()

    opts = {}
    if fmt_out == "h5":
        opts["provenance"] = {"tool": "evmotion convert", "source": str(src),
                              "source_format": fmt_in, "t0": args.t0, "t1": args.t1}
    start = time.perf_counter()
    it = chunks()
    first = next(it, None)
    if first is None:
        info = eio.describe(src, format=fmt_in, **kw) if args.t0 or args.t1 else {}
        if info.get("t_first_us") is None:
            raise ParameterError(f"{src}: no events; nothing written")
        raise empty_selection(args, src, int(info["t_first_us"]), int(info["t_last_us"]),
                              "nothing written: no events")

    def all_chunks():
        yield first
        yield from it

    kept, dropped = _aux_streams(src, fmt_in, fmt_out, args.t0, args.t1)
    for name, stream in kept.items():
        opts[name] = stream
    try:
        eio.write_events(dst, all_chunks(), format=fmt_out, **opts)
    except UnsortedError as exc:
        # the input's order, found as its chunks are written: name the input
        raise EventDataError(f"{src}: {exc}") from None
    if fmt_out != "h5" and _has_calibration(src, first):
        dropped["calibration"] = (1, f"evmotion's '{fmt_out}' writer does not store it "
                                     "(convert to .h5 to keep it, or give the calibration "
                                     "to the commands that read the output, with --calib)")
    for name, (n, why) in dropped.items():
        what = "calibration" if name == "calibration" else f"{n:,} {_AUX_NAMES[name]}"
        warn_line(f"{dst}: dropped the {what} of {src}: {why}")
    if counted["n"] > 1:
        from evmotion.io.read import warn_time_jump

        warn_time_jump(src, *counted["gap"], counted["t_last"] - counted["t_first"],
                       counted["n"])
    summary = {"input": str(src), "format_in": fmt_in, "output": str(dst),
               "format_out": fmt_out, "n_events": counted["n"],
               "t_first_us": counted["t_first"], "t_last_us": counted["t_last"],
               "kept": {name: int(len(v["t"])) for name, v in kept.items()},
               "dropped": {name: n for name, (n, _) in dropped.items()},
               "seconds": round(time.perf_counter() - start, 3)}
    if args.json:
        print_json(summary)
    else:
        extra = "".join(f" + {len(v['t']):,} {_AUX_NAMES[name]}" for name, v in kept.items())
        n = counted["n"]
        print(f"wrote {n:,} event{'' if n == 1 else 's'}{extra} ({fmt_in} -> {fmt_out}) to "
              f"{dst}")
    return 0


_AUX_NAMES = {"imu": "IMU samples", "frames": "APS frames"}


def _longest_pause(counted: dict, t) -> None:
    """Update ``counted["gap"]`` = (longest pause in µs, index of the event before it)
    with a chunk's times ``t``, ``counted["n"]`` and ``["t_last"]`` being the events
    before it."""
    import numpy as np

    t = np.asarray(t, np.int64)
    if counted["t_last"] is not None:
        t = np.concatenate([[counted["t_last"]], t])
    if t.size < 2:
        return
    d = np.diff(t)
    k = int(np.argmax(d))
    if int(d[k]) > counted["gap"][0]:
        before = counted["n"] - (1 if counted["t_last"] is not None else 0)
        counted["gap"] = (int(d[k]), before + k)


def _has_calibration(src, first) -> bool:
    """Whether the recording brings a camera calibration (not a header's nominal lens)."""
    if first.meta.get("calibration"):
        return True
    from evmotion.io.calibration import recording_intrinsics

    intr = recording_intrinsics(src, tuple(first.sensor_size))
    return bool(intr.get("K")) and not intr.get("nominal")


def _check_writable(fmt_out: str) -> None:
    """``--format-out`` names a format evmotion writes (a read-only one crashed the aux
    streams' check with a traceback)."""
    from evmotion.errors import ParameterError
    from evmotion.io.registry import all_formats, get_format

    if get_format(fmt_out).write is None:
        writable = sorted(f.name for f in all_formats() if f.write is not None)
        raise ParameterError(f"--format-out {fmt_out}: a format evmotion reads only; it "
                             f"writes {', '.join(writable)}")


def _aux_streams(src, fmt_in: str, fmt_out: str, t0: int | None, t1: int | None):
    """The IMU samples and APS frames of ``src`` within ``[t0, t1)``: ``(kept, dropped)``,
    ``kept`` the writer options (``imu``/``frames`` dicts) for an output format whose writer
    takes them, ``dropped`` ``{name: (count, reason)}`` for the others."""
    import inspect

    import numpy as np

    import evmotion.io as eio
    from evmotion.errors import FormatError
    from evmotion.io.registry import get_format

    takes = inspect.signature(get_format(fmt_out).write).parameters
    kept, dropped = {}, {}
    listed = None
    for name, read in (("imu", eio.read_imu), ("frames", eio.read_frames)):
        try:
            seq = read(src, format=fmt_in)
        except (FormatError, FileNotFoundError) as exc:
            # the format or this recording has none, unless its description lists some
            # (a stream this reader cannot decode is dropped, and said so)
            if listed is None:
                try:
                    listed = eio.describe(src, format=fmt_in, stream=False)
                except FormatError:
                    listed = {}
            n = listed.get(name, 0)
            if isinstance(n, (int, np.integer)) and n > 0:
                why = exc.message if isinstance(exc, FormatError) else str(exc)
                dropped[name] = (int(n), f"they cannot be read ({why})")
            continue
        t = np.asarray(seq.t, np.int64)
        sel = np.ones(t.shape, bool)
        if t0 is not None:
            sel &= t >= t0
        if t1 is not None:
            sel &= t < t1
        if not sel.any():
            continue
        idx = np.flatnonzero(sel)
        if name == "imu":
            stream = {"t": t[idx], "gyro": seq.gyro[idx], "accel": seq.accel[idx]}
        else:
            images = [np.asarray(seq.images[i]) for i in idx]
            if len({im.shape for im in images}) > 1:
                dropped[name] = (len(idx), "the frames differ in size, the output stores a "
                                           "stack of equal frames")
                continue
            stream = {"t": t[idx], "images": np.stack(images)}
        if name in takes:
            kept[name] = stream
        else:
            dropped[name] = (len(idx), f"evmotion's '{fmt_out}' writer does not store them "
                                       "(convert to .h5 to keep them)")
    return kept, dropped
