"""``evmotion view``: a picture of the events of a time slice of any readable recording,
or of one window of a flow output.

Counts per pixel in grayscale (dark = many events), or with ``--polarity`` the signed
polarity sum (red positive, blue negative). This is the image of events with the identity
warp: motion blur in it is what the motion-estimation commands remove.

Given a flow output (``evmotion flow`` or ``evmotion bos``: ``.h5``, ``.npz``, ``.flo``, a
pattern or a folder of per-window files), the window ``--window K`` (default: the one
holding ``--t0``, else the first with a valid pixel) is drawn colour-coded beside its
legend, grey where no event supports it; a BOS output's Poisson field q beside it.
A per-event flow file (``--method triplet``'s default output) is drawn as events are, with their
flow beside them: each pixel's mean over the selected events that have one.
"""

from __future__ import annotations

from pathlib import Path

from evmotion.cli.options import (
    HelpFormatter,
    add_sensor_size_argument,
    add_time_arguments,
    add_time_unit_argument,
    check_time_order,
    empty_selection,
    event_format,
    finite_float,
    format_bytes,
    int_range,
    positive_int,
    read_kwargs,
    reject_unused,
    warn_late_start,
    writable_output,
)

EXAMPLES = """examples:
  evmotion view rec.h5 --out events.png                       # first 30,000 events
  evmotion view rec.raw --t0 +0.01 --t1 +0.012 --out slice.png --polarity   # 10 to 12 ms in
  evmotion view events.txt --t0 +20ms --window-events 5000 --scale 2 --out w.png --json
  evmotion view bos.h5 --window 1 --out w1.png                # a flow output's window 1
"""

DEFAULT_EVENTS = 30_000
# the enlarged RGB image is held in memory twice (repeat along rows, then columns)
MAX_IMAGE_BYTES = 1 << 30


def add_parser(sub) -> None:
    p = sub.add_parser(
        "view", help="picture of the events of a time slice (histogram / IWE)",
        description=__doc__, epilog=EXAMPLES,
        formatter_class=HelpFormatter,
    )
    p.add_argument("file", help="recording (any readable format), or a flow output")
    p.add_argument("--out", required=True, type=writable_output((".png",), "a PNG image"),
                   help="output PNG")
    p.add_argument("--format", type=event_format, default=None,
                   help="input format (default: detect)")
    add_sensor_size_argument(p)
    add_time_unit_argument(p)
    add_time_arguments(p, max_windows=False)
    p.add_argument("--window-events", type=positive_int(), default=None, metavar="N",
                   help=f"take N events from --t0 (default {DEFAULT_EVENTS:,} "
                        "when --t1 is not given)")
    p.add_argument("--polarity", action="store_true",
                   help="signed polarity sum, red (+) / blue (-), instead of counts")
    p.add_argument("--percentile", type=finite_float(0, 100, lo_open=True), default=None,
                   help="events: percentile of the nonzero pixels shown at full intensity "
                        "(default 99)")
    p.add_argument("--scale", type=positive_int(), default=1,
                   help="enlarge each pixel to SCALE x SCALE (nearest neighbour; the image "
                        f"may hold at most {format_bytes(MAX_IMAGE_BYTES)} as RGB)")
    p.add_argument("--raw", action="store_true",
                   help="write the bare image, one pixel per sensor pixel (times --scale), "
                        "without title, axes and colour bar")
    p.add_argument("--window", type=int_range(0), default=None, metavar="K",
                   help="flow outputs: the window to draw, from 0 (default: the one holding "
                        "--t0, else the first with a valid pixel)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def _read_slice(path: str, kw: dict, t0: int | None, t1: int | None, n: int | None):
    """Events of ``[t0, t1)``, cut to the first ``n``; a count window is streamed so that
    it does not load the whole file. ``kw``: the reader options (:func:`read_kwargs`)."""
    import evmotion.io as eio
    from evmotion.events import concatenate

    if n is None:
        return eio.read_events(path, t0=t0, t1=t1, warn_empty=False, **kw).slice_time(t0, t1)
    parts, have = [], 0
    for chunk in eio.iter_events(path, chunk_events=max(min(n, 1_000_000), 1), t0=t0, t1=t1,
                                 **kw):
        chunk = chunk.slice_time(t0, t1)
        if len(chunk):
            parts.append(chunk[: n - have])
            have += len(parts[-1])
        if have >= n:
            break
    return concatenate(parts, validate=False) if parts else None


def check_scale(scale: int, sensor_size: tuple[int, int]) -> None:
    """Refuse a ``--scale`` whose RGB image would exceed :data:`MAX_IMAGE_BYTES`."""
    from evmotion.errors import ParameterError

    h, w = sensor_size
    need = 3 * h * w * scale * scale
    if need > MAX_IMAGE_BYTES:
        largest = max(int((MAX_IMAGE_BYTES / (3 * h * w)) ** 0.5), 1)
        raise ParameterError(f"--scale {scale}: the {w} x {h} px image would become "
                             f"{w * scale:,} x {h * scale:,} px, {format_bytes(need)} as RGB, "
                             f"over the {format_bytes(MAX_IMAGE_BYTES)} limit; use --scale "
                             f"{largest} or less")


def _percentile(args) -> float:
    return 99.0 if args.percentile is None else args.percentile


def run(args) -> int:
    import numpy as np

    from evmotion.cli import print_json
    from evmotion.errors import EmptyWindowError, EvmotionError
    from evmotion.utils import atomic_write_bytes, seconds_text
    from evmotion.viz import event_histogram, event_picture_png, iwe_to_rgb, read_png, save_png
    from evmotion.viz.flowpic import upscale

    check_time_order(args)
    out = Path(args.out)
    if args.format is None:
        # a flow's picture: its colour wheel and scale, which neither option changes (both
        # were ignored, the picture byte-identical; probe CI)
        events_only = {"--raw": "raw", "--percentile": "percentile",
                       "--sensor-size": "sensor_size"}
        from evmotion.io.flowread import describe_flow, undated_flow_files

        undated = undated_flow_files(args.file)
        if undated:  # .flo / .png files of another tool: their displacement, in px
            # (before describe_flow, which reads every file of a folder of them)
            reject_unused(args, events_only, f"to {args.file}, a flow")
            return _view_undated(args, out, undated)
        info = describe_flow(args.file)
        if (info is not None and "windows" in info) or _is_simulator_gt(Path(args.file)):
            reject_unused(args, events_only, f"to {args.file}, a flow")
            return _view_flow(args, out)
        per_event = info is not None and info.get("format") == "evmotion-event-flow"
    else:
        per_event = False
    reject_unused(args, {"--window": "window"},
                  ("to a per-event flow file (one flow per event, no windows" if per_event
                   else "to a recording (it draws events") + "; --t0 / --t1 choose them)")
    n = args.window_events
    if n is None and args.t1 is None:
        n = DEFAULT_EVENTS
    if args.scale > 1:
        import evmotion.io as eio

        # the header's sensor size, when it has one, refuses a huge --scale before reading
        try:
            size = eio.describe(args.file, format=args.format, stream=False).get("sensor_size")
        except EvmotionError:
            size = None  # reading the events below reports what is wrong with the file
        if size is not None:
            check_scale(args.scale, tuple(size))
    ev = _read_slice(args.file, read_kwargs(args), args.t0, args.t1, n)
    if ev is None or not len(ev):
        import evmotion.io as eio

        # the error path only: reads the file through once more for its time range
        try:
            info = eio.describe(args.file, **read_kwargs(args))
        except EvmotionError:
            info = {}
        if info.get("t_first_us") is None:
            raise EmptyWindowError(f"{args.file}: no events" if args.t0 is None and
                                   args.t1 is None else f"{args.file}: no events in the "
                                   f"requested slice (--t0 {args.t0}, --t1 {args.t1} µs)")
        raise empty_selection(args, args.file, int(info["t_first_us"]),
                              int(info["t_last_us"]), "no events")
    warn_late_start(args.t0, int(ev.t[0]), int(ev.t[-1]))
    check_scale(args.scale, ev.sensor_size)
    hist = event_histogram(ev, signed=args.polarity)
    if args.raw:
        rgb = iwe_to_rgb(hist, polarity=args.polarity, percentile=_percentile(args))
        if args.scale > 1:
            rgb = upscale(rgb, args.scale)
        save_png(out, rgb)
    else:
        # (to the µs: epoch times at 6 digits read [1.58916e+09, 1.58916e+09): probe)
        t0_us, t1_us = int(ev.t[0]), int(ev.t[-1]) + 1
        title = (f"{Path(args.file).name}: {len(ev):,} events, [{t0_us / 1e6:.6f}, "
                 f"{t1_us / 1e6:.6f}) s ({(t1_us - t0_us) / 1e3:.4g} ms)")
        if per_event:
            # a per-event flow file drew its events alone, its flow nowhere (probe BK)
            rgb = _event_flow_picture(args, ev, hist, title)
            save_png(out, rgb)
        else:
            atomic_write_bytes(out, event_picture_png(hist, polarity=args.polarity,
                                                      percentile=_percentile(args),
                                                      title=title, scale=args.scale))
            rgb = read_png(out)
    if args.json:
        print_json({
            "file": str(args.file),
            "out": str(out),
            "events": len(ev),
            "t0_us": int(ev.t[0]),
            "t1_us": int(ev.t[-1]) + 1,
            "duration_s": (int(ev.t[-1]) - int(ev.t[0])) * 1e-6,
            "sensor_size": {"height": ev.height, "width": ev.width},
            "image": {"height": int(rgb.shape[0]), "width": int(rgb.shape[1])},
            "polarity": bool(args.polarity),
            "pixels_with_events": int((hist != 0).sum()),
            "max_per_pixel": float(np.abs(hist).max()),
        })
    else:
        print(f"{out}: {len(ev):,} events, [{seconds_text(ev.t[0])}, "
              f"{seconds_text(int(ev.t[-1]) + 1)}) s")
    return 0


def _event_flow_picture(args, ev, hist, title: str):
    """The events beside their flow (a per-event flow file's, each pixel's mean over the
    selected events with a flow)."""
    import numpy as np

    from evmotion.io.eventflow import read_event_flow
    from evmotion.viz import full_scale, iwe_to_rgb
    from evmotion.viz.flowpic import flow_picture, mean_event_flow, picture_row, upscale

    ef = read_event_flow(args.file)
    t = ef["t"]
    lo, hi = np.searchsorted(t, int(ev.t[0])), np.searchsorted(t, int(ev.t[-1]), "right")
    sl = slice(lo, hi)
    flow, has = mean_event_flow(ef["x"][sl], ef["y"][sl], ef["vx"][sl], ef["vy"][sl],
                                ef["valid"][sl], ef.sensor_size)
    pic = flow_picture(flow, valid=has)
    vmax = full_scale(hist, _percentile(args))
    events = iwe_to_rgb(hist, polarity=args.polarity, vmax=vmax)
    if pic.scale > 1:
        events = upscale(events, pic.scale)
    # the events' scale in words, as the flow's legend gives its own (probe BX)
    scale = (f"red +, blue -, full at +-{vmax:.3g}" if args.polarity
             else f"white 0, black >= {vmax:.3g}")
    rgb = picture_row([events, pic.rgb], [f"events ({scale} / px)",
                                          "their flow: each pixel's mean"], title=title)
    if args.scale > 1:
        rgb = upscale(rgb, args.scale)
    return rgb


def _view_flow(args, out: Path) -> int:
    """``view`` of a flow output: one window's flow (and a BOS output's q)."""
    import numpy as np

    from evmotion.cli import print_json, warn_line
    from evmotion.errors import ParameterError
    from evmotion.io.flowread import read_flow
    from evmotion.utils import seconds_text
    from evmotion.viz import save_png
    from evmotion.viz.bos import bos_q_limit, flow_window_picture
    from evmotion.viz.flowpic import upscale

    reject_unused(args, {"--t1": "t1", "--window-events": "window_events",
                         "--polarity": "polarity"},
                  f"to a flow output ({args.file}: --window or --t0 choose its window)")
    seq = read_flow(args.file)
    n = len(seq.t0)
    if args.window is not None:
        if args.window >= n:
            raise ParameterError(f"--window {args.window}: {args.file} holds {n} window"
                                 f"{'' if n == 1 else 's'} (0 to {n - 1})")
        k = args.window
    elif args.t0 is not None:
        inside = np.flatnonzero((seq.t0 <= args.t0) & (args.t0 < seq.t1))
        if not inside.size:
            # (in seconds, as the option is typed: it echoed "--t0 5000000 us" for 5)
            raise ParameterError(f"--t0 {seconds_text(args.t0)} s: no window of {args.file} "
                                 f"holds it (they span [{seconds_text(seq.t0[0])}, "
                                 f"{seconds_text(seq.t1[-1])}) s)")
        k = int(inside[0])
    else:
        # the first window that measured something (a BOS run's first interval is often
        # the sensor's start-up, written with no valid pixel; probe AM drew it, q and all)
        measured = [i for i in range(n) if seq.valid is None or seq.valid[i].any()]
        k = measured[0] if measured else 0
        if k:
            which = "window 0 holds" if k == 1 else f"windows 0 to {k - 1} hold"
            warn_line(f"{args.file}: {which} no valid pixel (no measurement): drawing "
                      f"window {k} (--window 0 draws the first)")
    unmeasured = seq.valid is not None and not seq.valid[k].any()
    t0, t1 = int(seq.t0[k]), int(seq.t1[k])
    check_scale(args.scale, seq.flow.shape[1:3])
    q = seq.extras.get("q")
    units = seq.attrs.get("extras_units") or {}
    rgb = flow_window_picture(seq.flow[k], valid=None if seq.valid is None else seq.valid[k],
                              q=None if q is None else q[k],
                              # the file's q range, as bos --png-dir draws this window
                              q_limit=None if q is None else bos_q_limit(q, seq.valid,
                                                                         seq.flow),
                              q_unit=units.get("q", "px^2/s") if isinstance(units, dict)
                              else "px^2/s",
                              title=f"{Path(args.file).name}: window {k} of {n}, "
                                    f"[{seconds_text(t0)}, {seconds_text(t1)}) s"
                                    + (": no valid pixel, no measurement" if unmeasured
                                       else ""))
    if args.scale > 1:
        rgb = upscale(rgb, args.scale)
    save_png(out, rgb)
    if args.json:
        valid = seq.valid[k] if seq.valid is not None else np.isfinite(seq.flow[k]).all(-1)
        print_json({"file": str(args.file), "out": str(out), "kind": "flow", "window": k,
                    "n_windows": n, "t0_us": t0, "t1_us": t1,
                    "sensor_size": {"height": int(seq.flow.shape[1]),
                                    "width": int(seq.flow.shape[2])},
                    "image": {"height": int(rgb.shape[0]), "width": int(rgb.shape[1])},
                    "valid_fraction": float(np.mean(valid)),
                    "has_q": q is not None})
    else:
        print(f"{out}: window {k} of {n} of {args.file}, [{seconds_text(t0)}, "
              f"{seconds_text(t1)}) s" + (": no valid pixel, no measurement" if unmeasured
                                          else ""))
    return 0


def _view_undated(args, out, files: list[Path]) -> int:
    """``view`` of ``.flo`` / ``.png`` files without sidecars: one file's displacement
    (``--window`` picks the file of a folder)."""
    import numpy as np

    from evmotion.cli import print_json
    from evmotion.errors import ParameterError
    from evmotion.io.flowread import read_displacement
    from evmotion.viz import save_png
    from evmotion.viz.bos import flow_window_picture
    from evmotion.viz.flowpic import upscale

    n = len(files)
    reject_unused(args, {"--t1": "t1", "--window-events": "window_events",
                         "--polarity": "polarity", "--t0": "t0",
                         **({} if n > 1 else {"--window": "window"})},
                  f"to {args.file}: " + ("one window, with no times" if n == 1 else
                                         f"{n} files with no times (--window picks one)"))
    k = args.window or 0
    if k >= n:
        raise ParameterError(f"--window {k}: {args.file} holds {n} flow files (0 to {n - 1})")
    disp, valid = read_displacement(files[k])
    check_scale(args.scale, disp.shape[:2])
    name = files[k].name if n == 1 else f"{Path(args.file).name}/{files[k].name}"
    rgb = flow_window_picture(disp, valid=valid, unit="px",
                              title=f"{name}: displacement (no times: no sidecar)"
                                    + (f", file {k} of {n}" if n > 1 else ""))
    if args.scale > 1:
        rgb = upscale(rgb, args.scale)
    save_png(out, rgb)
    if args.json:
        print_json({"file": str(args.file), "out": str(out), "kind": "flow", "window": k,
                    "n_windows": n, "t0_us": None, "t1_us": None, "units": "px",
                    "flow_file": str(files[k]),
                    "sensor_size": {"height": int(disp.shape[0]), "width": int(disp.shape[1])},
                    "image": {"height": int(rgb.shape[0]), "width": int(rgb.shape[1])},
                    "valid_fraction": float(np.mean(valid))})
    else:
        print(f"{out}: the displacement of {files[k]} (px; no times without its sidecar"
              + (f"; file {k} of {n} of {args.file})" if n > 1 else ")"))
    return 0


def _is_simulator_gt(path: Path) -> bool:
    """Whether ``path`` is the simulator's ground truth (``*_gt.h5``), a flow file too."""
    from evmotion.io.flowfiles import SIM_GT_FORMAT
    from evmotion.io.h5filters import is_hdf5

    if not path.is_file() or not is_hdf5(path):
        return False
    import h5py

    try:
        with h5py.File(path, "r") as f:
            fmt = f.attrs.get("format")
    except OSError:
        return False
    return (fmt.decode() if isinstance(fmt, bytes) else fmt) == SIM_GT_FORMAT
