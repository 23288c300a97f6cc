"""``evmotion landscape FILE``: the cost along one warp parameter (Fig. 3.12), with and
without a regularizer, plotted to a PNG (and optionally saved as CSV). The window is the
``--window-events`` events from ``--t0`` (before ``--t1``); ``--json`` prints the curves."""

from __future__ import annotations

import numpy as np

from evmotion.cli.options import (
    HelpFormatter,
    check_time_order,
    check_time_range,
    finite_float,
    float_list,
    int_range,
    time_us,
    writable_output,
)
from evmotion.errors import ParameterError

EXAMPLES = """examples:
  evmotion simulate rotation --out sim.h5
  evmotion landscape sim.h5 --warp rotation --param wz --range 0 2.5 --theta 0.5,-0.7,0 --out land.png
  evmotion landscape sim.h5 --warp rotation --param wz --range 0 2.5 --theta 0.5,-0.7,0 --reg rcad --steps 21 --t0 0.05 --out land_rcad.png --csv land.csv --json
"""


def add_parser(sub) -> None:
    from evmotion.cli.egomotion import add_common

    p = sub.add_parser("landscape", help="cost landscape along one warp parameter (Fig. 3.12)",
                       description=__doc__, epilog=EXAMPLES,
                       formatter_class=HelpFormatter)
    add_common(p)
    p.add_argument("--param", default="0",
                   help="parameter to scan: index or name (e.g. 0, hz, wz; default 0, the "
                        "warp's first)")
    p.add_argument("--range", nargs=2, type=finite_float(), required=True, metavar=("LO", "HI"),
                   help="scan range in the parameter's units")
    p.add_argument("--steps", type=int_range(2, 100_000), default=101,
                   help="number of samples (default 101)")
    p.add_argument("--theta", default=None, type=float_list(),
                   help="comma-separated values of the other parameters (default identity)")
    p.add_argument("--t0", type=time_us, default=None, metavar="TIME",
                   help="window start: seconds on the recording's clock, or with a unit "
                        "(1.5, 1500ms, 1500000us; +TIME: after the first event; default: "
                        "the first event)")
    p.add_argument("--t1", type=time_us, default=None, metavar="TIME",
                   help="the window ends before this time, same units as --t0 (default: "
                        "after --window-events events)")
    p.add_argument("--window-events", type=int_range(10), default=30000, metavar="N",
                   help="events of the window from --t0 (default 30000)")
    p.add_argument("--out", required=True, type=writable_output((".png",), "a PNG image"),
                   help="output PNG")
    p.add_argument("--csv", default=None, type=writable_output((".csv",), "a CSV table"),
                   help="also write the curves as CSV (a .csv file)")
    p.add_argument("--json", action="store_true",
                   help="print the curves, the window and the minimum as JSON on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    args.t_ref = args.t_ref or "start"  # (egomotion's default is mid)
    from evmotion.cli.egomotion import check_common, load_events_and_camera
    from evmotion.core.warps import make_warp
    from evmotion.methods.diagnostics import MIN_CONTRAST_GAIN
    from evmotion.methods.egomotion import cost_landscape, landscape_verdict
    from evmotion.utils import atomic_write_text
    from evmotion.viz.landscape import landscape_png

    check_common(args)
    check_time_order(args)
    lo, hi = args.range
    if not hi > lo:
        raise ParameterError(f"--range {lo:g} {hi:g}: HI must be greater than LO")
    # only the window's events are read, as egomotion's first --max-windows 1 (the whole
    # recording was: 2.9 GB for one window of a 97.5 M-event file; probe DL)
    args.max_windows = 1
    events, cam = load_events_and_camera(args, n_events=args.window_events)
    args.max_windows = None
    if not len(events):
        raise ParameterError(f"{args.file}: the recording holds no events")
    check_time_range(args, events.t_start, events.t_end, args.file)
    events = events.slice_time(args.t0, args.t1)[:args.window_events]
    if len(events) < 10:
        from evmotion.cli.options import empty_selection

        full = load_events_and_camera(args)[0]
        raise empty_selection(args, args.file, full.t_start, full.t_end,
                              f"the window holds {len(events)} events (10 needed)")
    K = None if cam is None else cam.K
    w = make_warp(args.warp, events.sensor_size, K=K)
    if args.param.isdigit():
        j = int(args.param)
    elif args.param in w.param_names:
        j = w.param_names.index(args.param)
    else:
        raise ParameterError(f"--param {args.param!r}: warp '{args.warp}' has parameters "
                             f"{list(w.param_names)} (or their indices)")
    if not 0 <= j < w.n_params:
        raise ParameterError(f"--param {j} out of range for {w.n_params} parameters")
    theta = w.identity()
    if args.theta:
        if len(args.theta) != w.n_params:
            raise ParameterError(f"--theta {','.join(f'{v:g}' for v in args.theta)}: warp "
                                 f"'{args.warp}' needs {w.n_params} values "
                                 f"{list(w.param_names)}, got {len(args.theta)}")
        theta = np.array(args.theta)
    # the grid's points to 12 significant digits: linspace's -1.2999999999999998 for -1.3
    # went into the CSV and JSON (probe CE)
    values = np.array([float(f"{v:.12g}") for v in
                       np.linspace(args.range[0], args.range[1], args.steps)])
    plain = cost_landscape(events, w, j, values, theta, args.objective, None, K=K,
                           t_ref=args.t_ref)
    curves = {"no regularizer": plain["cost"]}
    if args.reg:
        reg = cost_landscape(events, w, j, values, theta, args.objective, args.reg, args.weight,
                             K=K, t_ref=args.t_ref, dataset=args.dataset)
        curves[f"with {args.reg}"] = reg["cost"]
        curves[f"{args.reg} penalty"] = reg["penalty"]
    name, unit = w.param_names[j], w.param_units[j]
    verdict = landscape_verdict(values, plain["cost"], plain["focus"], args.objective)
    best, at_edge, gain, flat = (verdict[k] for k in ("minimum", "at_edge", "best_gain", "flat"))
    why, said = [], []  # the warnings, and their short form on the picture
    if flat:
        said.append(f"flat: the best {name} sharpens the events by {100 * (gain - 1):.1f} % "
                    f"(< {100 * (MIN_CONTRAST_GAIN - 1):.0f} %)")
        why.append(f"flat: no {name} in the range sharpens the events by "
                   f"{100 * (MIN_CONTRAST_GAIN - 1):.0f} % (best {100 * (gain - 1):.1f} %): "
                   "its minimum is no measurement -- no motion along this parameter, too few "
                   "events, or the other parameters (--theta) far off")
    if at_edge:
        said.append("the minimum is at the edge of the range")
        why.append(f"the minimum ({name} = {best:.4g} {unit}) is at the edge of --range "
                   f"[{values[0]:.4g}, {values[-1]:.4g}]: the true one may lie beyond; "
                   "widen --range")
    fixed = ", ".join(f"{n} = {v:.4g}" for i, (n, v) in enumerate(zip(w.param_names, theta,
                                                                     strict=True)) if i != j)
    landscape_png(args.out, values, curves, name=name, unit=unit, minimum=best,
                  title=f"{args.warp} warp, {args.objective}, {len(events):,} events, "
                        f"{events.t[0] * 1e-6:.4f}-{events.t[-1] * 1e-6:.4f} s\n"
                        f"{fixed or 'one parameter'}; {args.grid}",
                  verdict="\n".join(said) or None)
    if args.csv:
        # the parameter's unit in the header (probe BJ: "wz,no regularizer")
        lines = [",".join([f"{name} [{unit}]"] + list(curves))]
        lines += [",".join(repr(float(v)) for v in row)
                  for row in zip(values, *curves.values(), strict=True)]
        atomic_write_text(args.csv, "\n".join(lines) + "\n")
    from evmotion.cli import warn_line

    if args.window_events and len(events) < args.window_events:
        from evmotion.cli.calib import events_held

        why_short = ("undistortion left out the rest (said above)"
                     if events_held(len(events), events) >= args.window_events
                     else "the recording (or --t1) ends first")
        warn_line(f"the window holds {len(events):,} events, not the {args.window_events:,} "
                  f"asked: {why_short}")
    for line in reversed(why):  # the edge first, as before
        warn_line(line)
    best_reg = None
    reg_at_edge = False
    if args.reg:
        k_reg = int(np.argmin(curves[f"with {args.reg}"]))
        best_reg = float(values[k_reg])
        # a regularized minimum at the range's edge is no cure either: past a zoom's
        # 1/T the penalty falls again and the image flips (rcad's minimum at hz = 60 for a
        # true 1.5, said as the cure, probe AW)
        reg_at_edge = k_reg in (0, len(values) - 1)
        if reg_at_edge:
            warn_line(f"with {args.reg} the minimum ({name} = {best_reg:.4g} {unit}) is at "
                      f"the edge of --range [{values[0]:.4g}, {values[-1]:.4g}]: no measurement "
                      "either (a collapse the penalty does not hold, or one beyond the range)")
        elif abs(best_reg - best) > (values[1] - values[0]) * 1.5:
            warn_line(f"{args.reg} moves the minimum from {name} = {best:.4g} to "
                      f"{best_reg:.4g} {unit}: the one without a regularizer may be an event "
                      "collapse (thesis Fig. 3.12)")
    if args.json:
        from evmotion.cli import print_json

        print_json({"file": str(args.file), "out": str(args.out), "warp": args.warp,
                    "objective": args.objective, "regularizer": args.reg,
                    "param": name, "unit": unit, "theta": theta,
                    "window": {"t0_us": int(events.t[0]), "t1_us": int(events.t[-1]) + 1,
                               "n_events": len(events)},
                    "grid": args.grid, "values": values, "curves": curves,
                    "minimum": float(best), "minimum_at_edge": at_edge,
                    "minimum_with_regularizer": best_reg,
                    "minimum_with_regularizer_at_edge": reg_at_edge,
                    "best_contrast_gain": gain, "flat": flat})
    else:
        with_reg = (f"; with {args.reg} at {name} = {best_reg:.4g} {unit}"
                    if best_reg is not None else "")
        print(f"{args.out}: minimum without regularizer at {name} = {best:.4g} {unit}"
              f"{' (no measurement: ' + said[0].split(':')[0] + ')' if said else ''}"
              f"{with_reg} (events on the {args.grid} grid)")
    return 0
