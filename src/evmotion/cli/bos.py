"""``evmotion bos REC --out bos.h5``: event-based background-oriented schlieren (ch. 6).

REC is an ECD-style folder (``events.txt``, ``images.txt`` with ``t path`` lines,
``images/``), a recording that holds its frames (AEDAT4 with DAVIS APS frames, a sequence
folder of the published event-based BOS data, an HDF5 file with frames) or any event
recording with ``--frames``. Every frame interval
``[t_i, t_{i+1})`` the events cover is one window: the events in it against frame ``i``
give the flow ``v`` (px/s), the Poisson field ``q`` (``v = Sobel(q)``) and the frame's
translation field ``p`` (px), warm-started from the previous interval. The contrast
threshold C that sets the flow's magnitude (``--data-term scale``) is one per sequence:
the median of its estimates from the frames bracketing up to 15 intervals, unless given.

The output is a regular evmotion flow output (:mod:`evmotion.io.flowout`, the one every
``evmotion flow`` method writes; ``read_flow``, ``evmotion info`` and ``evmotion eval``
read it): the flow in px/s, each interval's ``[t0, t1)`` µs, ``valid`` = the ROI's pixels
with event support (elsewhere the flow is the regularizer's interpolation), units and grid.
``.h5`` (the reference) and ``.npz`` also hold ``q``, ``p`` and per-window numbers
(contrast threshold, objective, events, seconds) as extra datasets; ``.flo`` (Middlebury
displacement in px, ``NAME.flo.json`` with dt/t0/t1) and ``.png`` (DSEC 16-bit
displacement) hold the flow only, one file per interval (a pattern such as
``bos_{:05d}.flo`` for several). ``--png-dir`` adds ``q_00000.png``, ``flow_00000.png``
and ``p_00000.png`` per interval (with .h5 / .npz). Each interval is written as soon as it
is solved: an interrupted ``.h5`` run keeps ``OUT.part`` (with each interval's solver
state, ``warm/scale<s>``), and the same command with ``--resume`` continues it to the file
an uninterrupted run writes.
"""

from __future__ import annotations

import time
from pathlib import Path

from evmotion.cli.options import (
    HelpFormatter,
    add_scheduler_argument,
    add_time_unit_argument,
    check_flow_out,
    check_time_order,
    event_format,
    existing_input,
    finite_float,
    int_range,
    positive_float,
    reject_unused,
    remove_stale_pictures,
    seed_int,
    time_us,
    writable_folder,
    writable_output,
)

EXAMPLES = """examples:
  evmotion bos scene/ --max-intervals 2 --out bos.h5
  evmotion bos scene/ --roi 32 0 96 128 --max-windows 1 --png-dir png/ --json --out bos_roi.h5
  evmotion bos scene/events.txt --frames scene/ --param flow --data-term scale --t1 0.01 --out bos_flow.h5
  evmotion bos scene/ --max-intervals 2 --out 'bos_{:05d}.flo'
  evmotion eval bos.h5 --gt scene/schlieren_gt.h5 --json
(scene/: made by 'evmotion simulate schlieren --scene plume --size 128x160 --duration 0.05
--out scene/'; --roi X Y W H in px; --t0/--t1 in seconds, or 10ms, 10000us.)
"""


def add_parser(sub) -> None:
    p = sub.add_parser("bos", help="background-oriented schlieren from events + frames (ch. 6)",
                       description=__doc__, epilog=EXAMPLES,
                       formatter_class=HelpFormatter)
    p.add_argument("rec", help="ECD-style folder (events.txt + images.txt + images/), a "
                               "recording holding frames (AEDAT4, event_based_bos sequence), or "
                               "an event recording (then --frames)")
    p.add_argument("--frames", default=None, type=existing_input,
                   help="frames: ECD folder, AEDAT4, event_based_bos sequence, or a folder of "
                        "images with a timestamps file (default: images.txt beside REC, else "
                        "REC's own frames)")
    p.add_argument("--format", type=event_format, default=None,
                   help="event format (default: detected)")
    add_time_unit_argument(p)
    p.add_argument("--frames-time-unit", choices=("s", "ms", "us", "ns"), default=None,
                   help="unit of the frames' times (images.txt, a timestamps file) where it "
                        "is not the events' (default: an images.txt beside the events in "
                        "--time-unit; else decimal seconds, whole microseconds)")
    p.add_argument("--roi", nargs=4, type=int_range(0, unit="px"), default=None,
                   metavar=("X", "Y", "W", "H"),
                   help="region of interest in px, top-left corner and size "
                        "(default: whole sensor)")
    p.add_argument("--param", choices=("poisson", "flow"), default="poisson",
                   help="parameterization: v = Sobel(q) (poisson, default) or v directly")
    p.add_argument("--data-term", choices=("normalized", "scale"), default="scale",
                   help="normalized (6.11, scale-free) or scale-aware with the contrast "
                        "threshold (default scale: physical magnitudes)")
    # (below 0.001 log units no sensor fires: 1e-6 passed and scaled every flow down)
    p.add_argument("--contrast-threshold", type=finite_float(0.001, 10),
                   default=None, metavar="C",
                   help="log-intensity change per net event that scales the flow "
                        "(default: the median of the estimates from the frames bracketing "
                        "up to 15 intervals). It folds in the events' under-count (no event "
                        "below threshold), so it is not the sensor's nominal threshold: on a "
                        "rendered plume with a sensor at 0.20 the estimate was 0.26 and the "
                        "flow 0.97x the true one, 0.76x with 0.20 given; where nearly every "
                        "pixel's change stays below C (slow air, high frame rates) it falls "
                        "below the nominal one and the flow comes out small, which a warning "
                        "says. Give it where the frames are too dark or noisy to estimate it")
    p.add_argument("--iterations", type=int_range(1, 100_000),
                   default=None, metavar="N",
                   help="Adam iterations per scale (default 150/150/150/300 for the scale "
                        "term, within 0.3 %% of the thesis' objective, 600 for the normalized "
                        "one; 600: the thesis' schedule; below ~100 the objective is far "
                        "from its optimum: on a simulated plume 20 raised the AEE from 0.18 "
                        "to 0.21 px, 5 to 1.66)")
    p.add_argument("--seed", type=seed_int, default=None,
                   help="seed of the random initial q (--param poisson; default 0)")
    p.add_argument("--relinearize", type=int_range(0, 10), default=0, metavar="N",
                   help="scale term: at most N further solves with the frame warped by the "
                        "flow found, while the flow moves the background 1 px or more over "
                        "an interval (95th percentile), where the linearized model "
                        "underestimates; it helped smooth air and hurt finer structures "
                        "(AEE -6 %% to +38 %%, benchmarks/results/bos_relinearize.md): "
                        "default 0, the thesis' single solve, with a warning past 1 px")
    p.add_argument("--t0", type=time_us, default=None, metavar="TIME",
                   help="only frame intervals from this time: seconds on the recording's "
                        "clock, or with a unit (1.5, 1500ms, 1500000us); +TIME: after the first "
                        "event")
    p.add_argument("--t1", type=time_us, default=None, metavar="TIME",
                   help="only frame intervals up to this time, same units as --t0")
    p.add_argument("--max-intervals", "--max-windows", dest="max_intervals",
                   type=int_range(1), default=None,
                   metavar="N", help="at most N frame intervals (default all)")
    p.add_argument("--workers", type=int_range(1, 256), default=None,
                   help="parallel worker processes over frame intervals (default 1): each "
                        "takes a contiguous chunk, whose first interval starts cold instead "
                        "of from the previous one; the solution depends on its start, so "
                        "each later interval of the chunk differs from one worker's too "
                        "(by up to a quarter of the flow per window on a simulated plume, at "
                        "the same accuracy overall); a chunk's intervals are written when it "
                        "ends, so an interrupted run keeps the finished chunks only (none "
                        "before the first ends; --resume continues with one worker); with "
                        "--scheduler, the number of chunks of intervals (default: one per "
                        "worker thread of the cluster)")
    add_scheduler_argument(p, "chunks of frame intervals")
    p.add_argument("--out", required=True,
                   type=writable_output((".h5", ".hdf5", ".npz", ".flo", ".png"),
                                        "a flow output (.h5, .npz; .flo, .png per interval)"),
                   help="output: .h5 (reference: flow px/s, t0/t1, valid, q, p, per-window "
                        "numbers; resumable layout), .npz (the same arrays), .flo "
                        "(Middlebury displacement px + NAME.flo.json) or .png (DSEC 16-bit "
                        "displacement + NAME.png.json): flow only, no q/p; a pattern "
                        "(bos_{:05d}.flo) for several intervals")
    p.add_argument("--resume", action="store_true",
                   help="continue the .h5 output of an interrupted run (its OUT.part): the "
                        "intervals it holds are kept, the next starts from the last one's "
                        "solver state, so the file is the one an uninterrupted run writes "
                        "(needs --workers 1 and the first run's options)")
    p.add_argument("--max-speed", type=positive_float(unit="px/s"), default=None,
                   metavar="PX_S",
                   help="--png-dir: speed at the flow colour wheel's rim in px/s (default: "
                        "the largest valid speed of the run; one scale for every interval, "
                        "as q's)")
    p.add_argument("--png-dir", default=None, type=writable_folder("q, flow and p PNGs"),
                   help="write q/flow/p PNGs per interval here (needs --out .h5 or .npz)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from evmotion.cli import print_json
    from evmotion.cli.options import (
        check_time_range,
        check_time_unit,
        cluster_threads,
        note_parallel_interrupt,
        scheduler_client,
    )
    from evmotion.errors import EventDataError, ParameterError
    from evmotion.events import fingerprint
    from evmotion.io.bosinput import frames_digest, load_bos_input
    from evmotion.io.flowout import EXTRA_CONTAINERS
    from evmotion.methods.bos import BosOptions
    from evmotion.methods.bos_run import (
        check_input,
        open_bos_output,
        sequence_threshold,
        solve_bos_into,
    )

    out = Path(args.out)
    check_time_order(args)
    # (each was accepted and had no effect; probe CI)
    if args.png_dir is None:
        reject_unused(args, {"--max-speed": "max_speed"}, "without --png-dir (no picture)")
    if args.param == "flow":
        # (it was stored in the output and changed nothing, probe DK)
        reject_unused(args, {"--seed": "seed"}, "with --param flow (it seeds the random "
                      "initial q of --param poisson; the flow starts at zero)")
    args.seed = 0 if args.seed is None else args.seed
    if args.data_term == "normalized" and args.relinearize:
        raise ParameterError(f"--relinearize {args.relinearize} does not apply with "
                             "--data-term normalized (it solves the scale term again)")
    kind = check_flow_out(out)
    if args.png_dir and kind not in EXTRA_CONTAINERS:
        raise ParameterError(f"--png-dir draws q and p, which a .{kind} output does not hold; "
                             "write --out .h5 or .npz")
    if args.resume:
        if kind != "h5":
            raise ParameterError(f"--resume continues an .h5 output; --out {out} is written "
                                 "whole at the end")
        if (args.workers or 1) > 1 or args.scheduler is not None:
            raise ParameterError("--resume needs --workers 1 and no --scheduler: with several "
                                 "chunks each chunk's first interval starts cold")
    note_parallel_interrupt(args, "interval")
    t_start = time.perf_counter()
    opts = {"param": args.param, "data_term": args.data_term, "seed": args.seed,
            "relinearize": args.relinearize}
    if args.iterations is not None:
        opts["iterations"] = args.iterations
    try:
        check_time_unit(args.time_unit, args.rec, args.format)
        data = load_bos_input(args.rec, args.frames, fmt=args.format, roi=args.roi,
                              time_unit=args.time_unit,
                              frames_time_unit=args.frames_time_unit, t0=args.t0, t1=args.t1, max_intervals=args.max_intervals)
        check_time_range(args, int(data.events.t[0]), int(data.events.t[-1]), args.rec)
        check_flow_out(out, len(data.intervals))
        options = BosOptions(**opts)
        unmeasured = check_input(data, options)
        c, c_source, _ = sequence_threshold(data, args.contrast_threshold, exclude=unmeasured)
        attrs = {"method": "bos", "param": args.param, "data_term": args.data_term,
                 "seed": args.seed, "relinearize": args.relinearize,
                 "source": data.source, "frames": data.frames_source,
                 "source_events": fingerprint(data.events),
                 # the frames by content: a copied or moved folder resumes (its path was
                 # compared, probe BH), other frames under the same name do not
                 "frames_digest": frames_digest(data.frames, data.frame_times),
                 "iterations": np.asarray(options.iterations_per_scale(), np.int64),
                 # the selection before C, which is estimated on it: a --resume with other
                 # --t0 / --t1 / --max-intervals is named as such
                 "frame_intervals": np.asarray([data.intervals[0, 0], len(data.intervals)],
                                               np.int64),
                 "contrast_threshold": c,
                 "contrast_threshold_source": c_source}
        with scheduler_client(args.scheduler) as client:
            # (a --workers 1 given with --scheduler is one chunk, as without: it had been
            # taken for the default, one chunk per cluster thread, probe BB)
            chunks = (args.workers or 1) if client is None or args.workers is not None \
                else cluster_threads(client)
            rows = solve_bos_into(open_bos_output(out, data, attrs, options,
                                                  resume=args.resume),
                                  data, c, workers=chunks, scheduler=client, progress=True,
                                  unmeasured=unmeasured, **opts)
    except ParameterError as exc:
        if args.roi is not None and str(exc).startswith("roi "):
            # the library names its argument; the user typed the option
            raise ParameterError(f"--{exc} (--roi X Y W H)") from None
        raise
    except EventDataError as exc:
        if str(exc).startswith("cannot estimate the contrast threshold"):
            # the library names the interval; the user ran it on a recording
            raise EventDataError(f"{args.rec}: {exc}") from None
        raise
    png_files: list[str] = []
    if args.png_dir:
        from evmotion.io.bosfiles import read_bos
        from evmotion.viz.bos import save_bos_sequence_pngs

        remove_stale_pictures(args.png_dir, ("q_", "flow_", "p_"))
        png_files = save_bos_sequence_pngs(args.png_dir, read_bos(out),
                                           max_speed=args.max_speed)
    seconds = time.perf_counter() - t_start
    if args.json:
        print_json({"rec": str(args.rec), "frames": data.frames_source, "out": str(out),
                    "param": args.param,
                    "data_term": args.data_term, "roi": list(data.roi) if data.roi else None,
                    "contrast_threshold": c, "contrast_threshold_source": c_source,
                    "sensor_size": list(data.events.sensor_size),
                    "n_intervals": len(rows), "windows": rows, "pngs": png_files,
                    "seconds": seconds})
    else:
        resumed = sum(1 for r in rows if r.get("resumed"))
        note = f", {resumed} kept from the earlier run" if resumed else ""
        print(f"{len(rows)} frame interval{'' if len(rows) == 1 else 's'} -> {out} "
              f"({seconds:.1f} s{note})")
    return 0
