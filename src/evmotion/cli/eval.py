"""``evmotion eval FLOW --gt GT``: accuracy of estimated flow against ground truth;
``evmotion eval FLOW --events REC``: its sharpness alone (FWL), which needs no ground truth.

FLOW is any flow output of ``evmotion flow`` (:func:`evmotion.io.flowread.read_flow`:
``.h5``, ``.npz``, ``.flo`` / DSEC ``.png`` with their JSON sidecar, a pattern such as
``flow_{:05d}.flo``, or a folder of such files), read back with each window's times; a
``.flo``/``.png`` without sidecar or a bare ``.npy`` (px/s) needs ``--t0-us``/``--t1-us``.
Other tools' per-window files without times (a folder of ``.flo`` or ``.png``, or a
pattern: RAFT, E-RAFT on DSEC) take the ground truth's windows, paired by file name with a
DSEC ground truth's PNGs, else in name order when there are as many files as windows
(:func:`evmotion.io.flowread.read_flow_paired`). GT is MVSEC ``.npz``, a DSEC flow folder
or timestamps file, or an evmotion/simulator ``.h5``
(:func:`evmotion.io.flowfiles.read_gt_flow`). For every estimated window ``[t0, t1)`` the
ground-truth displacement is the GT flow integrated over the window along the trajectories
(each GT frame weighted by its overlap, chained as in the MVSEC protocol), compared with
the estimated flow times the window duration. ``--dt`` states the protocol (GT frames per
window, MVSEC dt = 1 or 4); windows spanning a different number of GT frames are reported.

A per-event flow file (``evmotion flow --method triplet``'s default output, ``.h5`` or
``.npz``: :mod:`evmotion.io.eventflow`) is scored event by event
(:func:`evmotion.eval.eventflow.event_flow_metrics`): each event with a flow against the
GT window holding its time, bilinear at its position; AEE in px/s and in px of
displacement over ``--dt`` GT frame intervals, %Out and AE on those displacements, and
how many events were scored, had no flow or no ground truth.

Ego-motion parameters (``evmotion egomotion``'s ``params.h5``, or its output folder) are
scored through the flow each window's warp gives at every pixel, as dense flow above
(windows that are no measurement, collapsed or a poor fit, are not scored); against the
simulator's ground truth of a scene moved by the same warp, the parameters are compared
too: the RMS of each one's error over the valid windows, in its unit (and of the angular
velocity's error for the rotation), at each window's reference time
(:mod:`evmotion.eval.egomotion`). The rotation's angular velocity is also scored against an
IMU (the thesis' reference): ``--gt`` an ECD folder or its ``imu.txt``, a recording with IMU
samples, or a table ``t gx gy gz`` (s, rad/s); each window against the mean of the samples
within it; ``--imu-axes`` maps the IMU's axes to the camera's
(:func:`evmotion.io.angvel.read_angular_velocity`).

Beside the AEE, ``AEE_zero`` is the zero flow's on the same pixels or events (the ground
truth's mean displacement): an AEE is read against it, and one no lower than it is flagged
(a failed estimate, or the ground truth of another scene).

Masks (thesis ch. 4): valid ground truth (the simulator's: events in any of the GT frames
the window spans), the estimate's own validity (its ``valid``
mask, or unknown values in a ``.flo``/``.png``: pixels without event support, or a window
without focus, are not measurements), and with ``--events`` at least one event in the
window at the pixel; ``--events`` also enables the FWL (IWE variance with the flow over
that of zero flow).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

from evmotion.cli.options import (
    HelpFormatter,
    add_sensor_size_argument,
    add_time_unit_argument,
    event_format,
    existing_input,
    int_range,
    positive_float,
    positive_int,
    read_kwargs,
    reject_unused,
)
from evmotion.errors import (
    EmptyWindowError,
    EventDataError,
    EvmotionWarning,
    FormatError,
    ParameterError,
)

EXAMPLES = """examples:
  evmotion eval flow.h5 --gt outdoor_day1_gt_flow_dist.npz --events rec.h5 --dt 4 --json
  evmotion eval flow.h5 --gt sim.h5 --events sim.h5
  evmotion eval 'flow_{:05d}.flo' --gt sim.h5
  evmotion eval flow.h5 --events sim.h5                    # no GT: sharpness (FWL)
  evmotion flow sim.h5 --method triplet --out triplet.h5   # per-event flow
  evmotion eval triplet.h5 --gt sim_gt.h5 --json            # scored event by event
  evmotion egomotion sim.h5 --warp rotation --out ego/
  evmotion eval ego/ --gt sim_gt.h5                        # omega RMS error and AEE
  evmotion eval ego/ --gt boxes_rotation/imu.txt --imu-axes x,y,z   # omega against the IMU
"""


def add_parser(sub) -> None:
    p = sub.add_parser("eval", help="flow and ego-motion accuracy (AEE, %%Out, AE, FWL, "
                                    "parameter RMS) against ground truth",
                       description=__doc__, epilog=EXAMPLES,
                       formatter_class=HelpFormatter)
    p.add_argument("flow", help="estimated flow (.h5, .npz, .flo, .png, a pattern "
                                "flow_{:05d}.flo; .npy with --t0-us/--t1-us), a folder of "
                                "another tool's .flo/.png (paired with the GT's windows), "
                                "a per-event flow file (.h5/.npz of --method triplet), "
                                "or egomotion's params.h5 (or its --out folder)")
    p.add_argument("--gt", default=None, type=existing_input,
                   help="ground-truth flow (MVSEC .npz, DSEC, .h5); without it, --events "
                        "gives the sharpness (FWL) alone")
    p.add_argument("--events", default=None, type=existing_input,
                   help="recording of the events: event mask and FWL (with no --gt: the "
                        "FWL of each window, which needs no ground truth)")
    p.add_argument("--format", type=event_format, default=None,
                   help="format of --events (default: detect)")
    add_sensor_size_argument(p)
    add_time_unit_argument(p)
    p.add_argument("--dt", "--gt-dt", dest="dt", type=positive_int(), default=1,
                   help="GT frames a window is meant to span (MVSEC's protocol: 1 or 4; "
                        "flow's --gt-dt): dense windows are scored over their own times "
                        "whatever it is, and those spanning another number are counted in a "
                        "note; per-event files: the GT frame intervals the displacements "
                        "span")
    p.add_argument("--t0-us", type=int_range(0, unit="µs"), default=None,
                   help="window start of a .npy, or a .flo/.png without sidecar")
    p.add_argument("--t1-us", type=int_range(0, unit="µs"), default=None,
                   help="window end of a .npy, or a .flo/.png without sidecar")
    p.add_argument("--out-px", type=positive_float(unit="px"), default=None,
                   help="%%Out threshold in px (default: the flow file's eval_out_px "
                        "attribute, e.g. 1 for BOS outputs (thesis §6.6.1), else 3)")
    p.add_argument("--imu-axes", default=None, metavar="AXES",
                   help="with egomotion's rotation parameters and an IMU or angular-velocity "
                        "table as --gt: the camera's x,y,z as the IMU's signed axes, e.g. "
                        "--imu-axes=-x,y,-z (with '=' where it starts with '-'; default "
                        "x,y,z: the same)")
    p.add_argument("--along-streamlines", action="store_true",
                   help="compare the displacement of the point at each pixel at the window "
                        "start: the window's flow (taken at its midpoint) transported to the "
                        "start along its streamlines (eq. 4.7, Burgers) times the duration; "
                        "default: flow times duration")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def _without_times(path: Path) -> bool:
    """Whether FLOW is other tools' per-window files without their times: a folder of
    them (not a DSEC ground-truth folder, which has its timestamps), or a pattern whose
    first file has no JSON sidecar."""
    from evmotion.io.flowout import is_pattern, sidecar_path, window_path
    from evmotion.io.flowread import is_dsec_flow_folder

    if is_pattern(path):
        first = window_path(path, 0)
        return first.exists() and not sidecar_path(first).exists()
    return path.is_dir() and not is_dsec_flow_folder(path) and not any(
        f.name.endswith((".flo.json", ".png.json")) for f in path.iterdir())


def _load_paired(args, path: Path):
    """FLOW files paired with the ground truth's windows (by name or order)."""
    from evmotion.io.flowfiles import dsec_gt_files, read_gt_flow
    from evmotion.io.flowread import read_flow_paired

    reject_unused(args, {"--t0-us": "t0_us", "--t1-us": "t1_us"},
                  f"to {path.name} (its files take the ground truth's windows)")
    gt = Path(args.gt)
    names = ([f.name for f in dsec_gt_files(gt)]
             if gt.is_dir() or gt.suffix.lower() == ".txt" else None)
    seq, how = read_flow_paired(path, read_gt_flow(gt), names)
    print(f"note: {path}: {how}", file=sys.stderr)
    flow = np.where(seq.valid[..., None], seq.flow, np.float32(np.nan))
    return flow, np.asarray(seq.t0), np.asarray(seq.t1), None, None, {}


def _load_flow(args, h5_format=None):
    from evmotion.io.flowout import CONTAINERS
    from evmotion.io.flowread import read_flow

    path = Path(args.flow)
    suffix = path.suffix.lower()
    missing = "{" not in path.name and not path.exists()
    if missing and suffix not in (".h5", ".hdf5", ".npz"):
        raise ParameterError(f"FLOW {path}: no such file or folder")
    if "{" not in path.name and args.gt is not None and \
            Path(args.gt).resolve() == path.resolve():
        raise ParameterError(f"FLOW {path} is the ground truth itself (--gt {args.gt})")
    if _without_times(path):
        if args.gt is None:
            raise ParameterError(f"FLOW {path}: its files carry no times; give --gt, whose "
                                 "windows they take")
        return _load_paired(args, path)
    if suffix == ".npy":
        return _load_npy(args, path)
    if suffix not in CONTAINERS and not path.is_dir():
        raise FormatError(path, f"not a flow file: FLOW must be an evmotion flow output (.h5, "
                          f".npz, .flo, .png or a pattern such as flow_{{:05d}}.flo from "
                          f"'evmotion flow'), or .npy, got {path.name!r})")
    if suffix in (".h5", ".hdf5", ".npz") or "{" in path.name or path.is_dir() or \
            path.with_name(path.name + ".json").exists():
        reject_unused(args, {"--t0-us": "t0_us", "--t1-us": "t1_us"},
                      f"to {path.name} (it carries its windows' times)")
        if missing:
            raise ParameterError(f"FLOW {path}: no such file or folder")
    elif args.t0_us is None or args.t1_us is None or args.t1_us <= args.t0_us:
        raise ParameterError(f"{path}: no {path.name}.json beside it, so no time interval; "
                             "give --t0-us and --t1-us (t1 > t0)")
    if suffix in (".h5", ".hdf5"):
        # a file that is not there (or has no format attribute) is read here, for its error
        _check_estimate(path, h5_format if h5_format is not None else _h5_format(path))
    seq = read_flow(path, t0_us=args.t0_us, t1_us=args.t1_us)
    # a method may name its evaluation's %Out threshold (BOS: 1 px)
    out_px = _file_out_px(path, seq.attrs) if args.out_px is None else None
    # the pixels the estimate does not claim (no event support, no focus) are not scored,
    # in every container: a .flo or .png stores them as unknown, an .h5 or .npz as a mask
    # beside the regularizer's fill
    flow = np.where(seq.valid[..., None], seq.flow, np.float32(np.nan))
    return flow, np.asarray(seq.t0), np.asarray(seq.t1), out_px, seq.extras.get("q"), seq.attrs


def _file_out_px(path, attrs: dict) -> float | None:
    """The %Out threshold a flow file names (attribute ``eval_out_px``), or None; a value
    that is no number of px > 0 is the file's error (a string had ended in a traceback,
    probe EVAL)."""
    from evmotion.utils import is_finite_number

    value = attrs.get("eval_out_px")
    if value is None:
        return None
    if isinstance(value, np.ndarray) and value.size == 1:
        value = value.item()
    if not (is_finite_number(value) and value > 0):
        raise FormatError(path, f"attribute eval_out_px={value!r} is not a number of px > 0",
                          "give the threshold with --out-px")
    return float(value)


def _add_potential_scores(q, t0s, t1s, gt_path, per_window: list, total: dict
                          ) -> int | None:
    """BOS outputs against the schlieren simulator's ground truth: each window's q against
    the exact one (``q_corr``, ``q_std_ratio``), and their means; other GT has no q.
    Returns how many windows span one of the ground truth's frame intervals (their q is
    scored), None where the ground truth has no q."""
    from evmotion.errors import FormatError
    from evmotion.eval.windows import evaluate_potential
    from evmotion.sim.schlieren import is_schlieren_gt, read_schlieren_q

    if not is_schlieren_gt(gt_path):
        return None  # another ground truth: no q to score against
    gt_q, gt_t_us = read_schlieren_q(gt_path)
    if gt_q.shape[1:] != q.shape[1:]:
        raise FormatError(gt_path, f"'q' is {gt_q.shape[2]}x{gt_q.shape[1]} px (W x H), the "
                          f"flow's q {q.shape[2]}x{q.shape[1]} px")
    rows = evaluate_potential(q, t0s, t1s, gt_q, gt_t_us)
    for row in rows:
        per_window[row["window"]].update(q_corr=row["q_corr"], q_std_ratio=row["q_std_ratio"])
    # the means over the windows the flow is scored in: a window with no valid pixel (a
    # start-up interval, written so) measured no q either (probe AQ: 0.389 in the mean)
    scored = [r for r in rows if per_window[r["window"]].get("n_pixels", 0) > 0]
    if scored:
        total["q_corr"] = float(np.mean([r["q_corr"] for r in scored]))
        total["q_std_ratio"] = float(np.mean([r["q_std_ratio"] for r in scored]))
    return len(rows)


def _load_npy(args, path):
    """A bare (H, W, 2) / (1, H, W, 2) px/s array from elsewhere: no times, so
    ``--t0-us``/``--t1-us`` give its window (evmotion itself writes .npz)."""
    if args.t0_us is None or args.t1_us is None or args.t1_us <= args.t0_us:
        raise ParameterError(f"{path}: .npy files carry no time interval; give "
                             "--t0-us and --t1-us (t1 > t0)")
    try:
        flow = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise FormatError(path, f"not a .npy array: {exc}") from None
    flow = flow[None] if flow.ndim == 3 else flow
    if flow.ndim != 4 or flow.shape[-1] != 2 or flow.dtype.kind != "f":
        raise FormatError(path, f"not a flow array: shape {flow.shape} dtype {flow.dtype}, "
                          "expected (H, W, 2) or (N, H, W, 2) floats in px/s")
    n = flow.shape[0]
    if n != 1:
        raise ParameterError(f"{path}: {n} windows but one --t0-us/--t1-us interval")
    return (flow.astype(np.float32), np.array([args.t0_us]), np.array([args.t1_us]), None,
            None, {})


def _h5_format(path) -> object:
    """The ``format`` attribute of an HDF5 file (None if it has none)."""
    from evmotion.io.h5attrs import file_attrs

    return file_attrs(path, ("format",)).get("format")


def _warn_other_source(path: Path, events_path) -> None:
    """Warn when ``--events`` is not named as the recording the flow file says it was
    estimated on (its ``source`` attribute): another file of the same sensor and times
    passes the checks, and would mask the score with unrelated pixels. Names are compared
    without their suffix, so a converted copy (``rec.raw`` -> ``rec.h5``) passes."""
    from evmotion.io.h5attrs import file_attrs

    source = file_attrs(path, ("source",)).get("source")
    if not isinstance(source, str) or not source:
        return
    if Path(source).stem != Path(events_path).stem:
        warnings.warn(EvmotionWarning(
            f"{path} was estimated on '{source}' (its source attribute) but --events is "
            f"{events_path}: if that is another recording, the event mask and FWL are "
            "meaningless"), stacklevel=2)


def _is_event_flow(path, h5_format=None) -> bool:
    """Whether FLOW is a per-event flow file (:mod:`evmotion.io.eventflow`), by its
    ``format`` attribute (``.h5``: ``h5_format``, read by the caller) or its ``meta``
    member (``.npz``); anything else goes to the dense readers, which report what is wrong
    with it."""
    import json
    import zipfile

    from evmotion.io.eventflow import EVENT_FLOW_FORMAT

    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5") and path.is_file():
        return h5_format == EVENT_FLOW_FORMAT
    if suffix != ".npz" or not path.is_file():
        return False
    from evmotion.io.guard import open_npz

    try:
        with open_npz(path) as z:
            if "meta" not in z.files:
                return False
            meta = json.loads(str(z["meta"]))
    except (OSError, ValueError, zipfile.BadZipFile):  # (FormatError among the ValueErrors)
        return False
    return isinstance(meta, dict) and meta.get("format") == EVENT_FLOW_FORMAT


def _check_estimate(path, fmt) -> None:
    """FLOW must be an estimate (an evmotion flow file: its format attribute ``fmt``), not
    events or ground truth: the reader also accepts an events file by the ground truth
    beside it, which would compare the ground truth with itself."""
    from evmotion.io.flowfiles import FLOW_FORMAT

    if fmt != FLOW_FORMAT:
        raise FormatError(path, f"not an evmotion flow file (format attribute {fmt!r}, "
                          f"expected {FLOW_FORMAT!r}): FLOW must be an estimate written by "
                          "'evmotion flow', not events or ground truth")


def _run_event_flow(args, path) -> int:
    """Score a per-event flow file (see the module docstring)."""
    from evmotion.cli import print_json
    from evmotion.eval.eventflow import event_flow_metrics
    from evmotion.io.eventflow import read_event_flow
    from evmotion.io.flowfiles import read_gt_flow

    reject_unused(args, {"--events": "events", "--format": "format",
                         "--sensor-size": "sensor_size", "--time-unit": "time_unit",
                         "--t0-us": "t0_us", "--t1-us": "t1_us",
                         "--along-streamlines": "along_streamlines"},
                  f"to the per-event flow file {path.name} (it holds its events and times)")
    ef = read_event_flow(path)
    if len(ef) == 0:
        raise FormatError(path, "no events (events=0): nothing to evaluate")
    gt = read_gt_flow(args.gt)
    if tuple(gt.flow.shape[1:3]) != ef.sensor_size:
        raise ParameterError(f"{path} is on a {ef.sensor_size} px grid but ground truth "
                             f"{args.gt} is {tuple(gt.flow.shape[1:3])} px (height, width)")
    file_out_px = _file_out_px(path, ef.attrs) if args.out_px is None else None
    out_px = args.out_px if args.out_px is not None else \
        file_out_px if file_out_px is not None else 3.0
    try:
        m = event_flow_metrics(ef, gt, frames=args.dt, out_px=out_px, per_window=True)
    except EmptyWindowError as exc:
        raise ParameterError(f"{path} against ground truth {args.gt}: {exc}") from None
    mean = m.as_dict()
    mean["AE_rad"] = float(np.radians(m.ae_deg))
    summary = {"flow": str(args.flow), "gt": str(args.gt), "kind": "per-event",
               "dt": args.dt, "displacement": f"over {args.dt} GT frame interval(s) "
                                               "(of the GT window holding each event)",
               "mask": "event with a flow & valid GT at its pixel", "out_px": out_px,
               "grid": str(ef.attrs.get("grid", "sensor")), "n_windows": len(m.windows),
               "units": EVENT_UNITS, "mean": mean, "windows": list(m.windows)}
    if args.json:
        print_json(summary)
    else:
        print(f"{m.n_scored} of {m.n_events} events scored ({m.n_no_flow} without a flow, "
              f"{m.n_no_gt} without GT; dt={args.dt}): AEE={m.aee:.4g} px  "
              f"AEE={m.aee_px_s:.4g} px/s  AEE_zero={m.aee_zero:.4g} px  "
              f"%Out={m.pct_out:.4g} %  AE_deg={m.ae_deg:.4g}")
    return 0


def _run_sharpness(args, path: Path, h5_format) -> int:
    """No ground truth: the FWL of each window on the recording's events."""
    from evmotion.eval.windows import sharpness_windows

    if args.events is None:
        raise ParameterError("give --gt GT (accuracy against ground truth), or --events REC "
                             "alone (the sharpness, FWL, which needs no ground truth)")
    if _is_event_flow(path, h5_format):
        raise ParameterError(f"{path} is a per-event flow file: its FWL without ground truth "
                             "is in the --json summary of 'evmotion flow --method triplet'; "
                             "eval scores it against --gt")
    reject_unused(args, {"--out-px": "out_px", "--along-streamlines": "along_streamlines"},
                  "without --gt (no accuracy is computed)")
    flow, t0s, t1s, _, _, attrs = _load_flow(args, h5_format)
    events = _events_on_grid(args, attrs)
    try:
        rows = sharpness_windows(flow, t0s, t1s, events)
    except EventDataError as exc:
        raise ParameterError(f"--events {args.events} against {path}: {exc}") from None
    if h5_format is not None:
        _warn_other_source(path, args.events)
    return _report_sharpness(args, rows)


def _report_sharpness(args, rows: list[dict]) -> int:
    """The per-window FWLs of :func:`~evmotion.eval.windows.sharpness_windows` on stdout."""
    from evmotion.cli import print_json

    fwls = [r["FWL"] for r in rows if "FWL" in r]
    mean = {k: float(np.mean([r[k] for r in rows if k in r])) for k in ("FWL", "FWL_gauss")
            } if fwls else {}
    summary = {"flow": str(args.flow), "events": str(args.events), "kind": "sharpness",
               "n_windows": len(rows), "windows_scored": len(fwls),
               "mask": "events where the estimate is known", "units": SHARPNESS_UNITS,
               "mean": mean, "windows": rows}
    if args.json:
        print_json(summary)
        return 0
    n = len(rows)
    print(f"{n} window{'' if n == 1 else 's'}" if len(fwls) == n else
          f"{len(fwls)} of {n} windows scored", "(no ground truth: the FWL of the events "
          "where the estimate is known; > 1: the flow sharpens them; bilinear votes are "
          "biased low for events on integer pixels, Gaussian votes of 1 px are not)")
    print(f"FWL={mean['FWL']:.4g}  FWL_gauss={mean['FWL_gauss']:.4g}" if fwls else
          "FWL not defined: no window has two events where the estimate is known")
    return 0


def _warn_grids(path, attrs: dict, gt_path, gt_attrs: dict) -> None:
    """Say when the estimate lies on the undistorted grid of a calibration with distortion
    and the ground truth does not state that grid: pixels the lens moves are compared with
    others (a translation within 1 px scored AEE 2.36 px, 23 % out, unsaid; probe AW)."""
    from evmotion.cli import warn_line

    grid = str(attrs.get("grid", ""))
    moved = np.any(np.asarray(attrs.get("distortion", [0.0]), dtype=np.float64) != 0)
    if grid.startswith("undistorted (K=") and moved and str(gt_attrs.get("grid", "")) != grid:
        warn_line(f"{path} is on the grid '{grid}' (the events undistorted by their "
                  f"calibration), the ground truth {gt_path} on "
                  f"'{gt_attrs.get('grid', 'the sensor grid (it states none)')}': pixels the "
                  "lens distortion moves are compared with others and the scores count it; "
                  "estimate with --no-undistort for a ground truth on the sensor's grid")


def _events_on_grid(args, attrs: dict):
    """The events of ``--events`` on the pixel grid the flow was estimated on (its
    ``grid`` attribute): undistorted as the flow command undistorted them, by the
    recording's own calibration; refused when that does not give the flow's grid (another
    --calib or --K was used)."""

    from evmotion.cli.calib import undistort_for
    from evmotion.io import read_events

    path = args.events
    # (--sensor-size, which the reader's own warning names, was no option here, probe BK)
    events = read_events(path, **read_kwargs(args, path))
    grid = str(attrs.get("grid", ""))
    if not grid.startswith("undistorted (K=") or events.x.dtype.kind == "f":
        return events
    moved, _, mine = undistort_for(argparse.Namespace(file=path, K=None, calib=None,
                                                      no_undistort=False), events)
    if mine != grid:
        raise ParameterError(f"the flow is on the grid '{grid}', --events {path} with its "
                             f"own calibration on '{mine}': give the recording as it was "
                             "estimated (its calibration beside it), or estimate the flow "
                             "with --no-undistort")
    return moved


def _angular_velocities(gt: Path) -> bool:
    """Whether ``--gt`` is a table of angular velocities (or an IMU's) rather than a flow
    ground truth: a text file of other than 2 columns (DSEC's flow timestamps) is a table
    or nothing (its errors were DSEC's "from_us, to_us", probe BM)."""
    from evmotion.io.angvel import is_angular_velocity_table, text_columns

    return is_angular_velocity_table(gt) or (_is_text(gt) and text_columns(gt) != 2)


def _is_text(path: Path) -> bool:
    return path.is_file() and path.suffix.lower() in (".txt", ".csv")


def _ground_truth(args, angular: bool):
    """What --gt holds: ``(angular velocities, None)``
    (:func:`evmotion.io.angvel.read_angular_velocity`: a table of them, a folder's
    imu.txt, a recording's IMU; ``angular``: :func:`_angular_velocities` said so), or
    ``(None, flow)`` for a flow ground truth, read once. ("--gt imu.txt" was parsed as a
    DSEC timestamps file, and an ECD folder with its imu.txt "holds no ground truth",
    probe BJ.)"""
    from evmotion.io import detect_format
    from evmotion.io.angvel import TABLE_LAYOUTS, read_angular_velocity
    from evmotion.io.flowfiles import read_gt_flow

    axes = args.imu_axes or "x,y,z"
    gt = Path(args.gt)
    if angular:
        return read_angular_velocity(gt, axes=axes), None
    try:
        return None, read_gt_flow(gt)
    except FormatError as flow_error:
        if _is_text(gt) and flow_error.path == str(gt):
            # not DSEC's lines (their PNGs are another matter): an egomotion user's
            # 2-column table heard only of DSEC's timestamps (probe BM)
            raise FormatError(gt, "2 columns: not DSEC's flow timestamps 'from_us, to_us' "
                              f"({flow_error.message}), nor an angular-velocity table, which "
                              f"has {TABLE_LAYOUTS}") from None
        try:
            return read_angular_velocity(gt, axes=axes), None
        except FormatError:
            try:
                detect_format(gt)  # a recording: its own words ("holds no IMU samples")
            except FormatError:
                raise flow_error from None
            raise


#: The fastest rate a camera's gyroscope measures (2000 degrees/s, the usual top range):
#: beyond, a table is likely in degrees/s.
MAX_GYRO_RAD_S = 35.0


def _run_angular_velocity(args, path: Path, table, ref) -> int:
    """The rotation's angular velocity of each window against reference samples."""
    from evmotion.cli import print_json, warn_line
    from evmotion.eval.egomotion import angular_velocity_errors

    reject_unused(args, {"--events": "events", "--out-px": "out_px"},
                  f"against the angular velocities of {args.gt} (no flow is scored)")
    rows, rms, reason = angular_velocity_errors(table, ref)
    if reason and not rms:
        raise ParameterError(f"{path} against {args.gt}: {reason}")
    unmeasured = int((~np.asarray(table.valid, bool)).sum())
    # (windows that are no measurement were counted beyond the samples too, probe BM)
    beyond = sum(r["n_samples"] < 0 and r["valid"] for r in rows)
    fastest = float(np.abs(ref.omega).max())
    if fastest > MAX_GYRO_RAD_S:
        warn_line(f"{args.gt}: angular velocities reach {fastest:.4g} rad/s, beyond a "
                  f"gyroscope's range ({MAX_GYRO_RAD_S:g} rad/s): in degrees/s? Give rad/s")
    if not rms["omega"] < rms["omega_zero"]:
        warn_line(f"{path}: the angular velocity's error ({rms['omega']:.4g} rad/s) is no "
                  f"lower than no rotation's ({rms['omega_zero']:.4g}): the estimate carries "
                  "no information on this reference (a failed estimate, or the reference of "
                  "another recording or time?)")
    axes = args.imu_axes or "x,y,z"
    what = ("one constant angular velocity" if ref.t is None else
            f"{len(ref):,} samples")
    if args.json:
        print_json({"flow": str(args.flow), "gt": str(args.gt), "kind": "egomotion",
                    "reference": "angular velocity", "reference_samples": len(ref),
                    "imu_axes": axes, "warp": "rotation",
                    "windows": len(table), "windows_compared": rms["n_windows"],
                    "windows_not_measurements": unmeasured, "windows_beyond_reference": beyond,
                    "parameters_rms": {k: v for k, v in rms.items() if k != "n_windows"},
                    "parameter_units": "rad/s", "parameters": rows})
        return 0
    print(f"{path}: the rotation's angular velocity against {args.gt} ({what}; camera axes "
          f"= the reference's {axes})")
    print(f"{rms['n_windows']} of {len(table)} windows compared: RMS error "
          + "  ".join(f"{k}={rms[k]:.4g}" for k in ("wx", "wy", "wz", "omega"))
          + f" rad/s (omega: the error vector's norm; no rotation: {rms['omega_zero']:.4g})")
    if unmeasured:
        print(f"note: {unmeasured} window{' is' if unmeasured == 1 else 's are'} no "
              "measurement (collapsed or a poor fit: params.h5's 'valid'): not compared")
    if beyond:
        print(f"note: {beyond} window{' lies' if beyond == 1 else 's lie'} beyond the "
              "reference's samples: not compared")
    return 0


def _params_file(path: Path, h5_format) -> Path | None:
    """FLOW as ego-motion parameters: a parameters file (``evmotion egomotion``'s
    ``params.h5``), or the output folder that holds one (``segment``'s, whose
    clusters.h5 is then refused by name: its PNG panels had been taken for flow files,
    probe AZ); None otherwise."""
    from evmotion.io.paramsfiles import PARAMS_FORMAT
    from evmotion.io.registry import own_output_folder

    if h5_format == PARAMS_FORMAT:
        return path
    found = own_output_folder(path)
    if found is not None and _h5_format(found[0]) == PARAMS_FORMAT:
        return found[0]
    return None


def _sim_truth(gt_path):
    """The simulator's ground truth in ``gt_path`` (its motion parameters), or None when
    the file is another kind of ground truth."""
    from evmotion.sim.gtio import GT_FORMAT, read_ground_truth

    gt_path = Path(gt_path)
    if gt_path.suffix.lower() not in (".h5", ".hdf5") or not gt_path.is_file():
        return None
    if _h5_format(gt_path) != GT_FORMAT:
        return None
    return read_ground_truth(gt_path)


def _run_egomotion(args, path: Path) -> int:
    """Score ``evmotion egomotion``'s parameters (see the module docstring): their flow
    against --gt, and the parameters themselves against the simulator's; with --events
    alone, their flow's FWL."""
    from evmotion.cli import print_json
    from evmotion.eval.egomotion import evaluate_egomotion, sharpness_egomotion
    from evmotion.io.paramsfiles import read_params

    reject_unused(args, {"--t0-us": "t0_us", "--t1-us": "t1_us",
                         "--along-streamlines": "along_streamlines"},
                  f"to {path} (its rows carry their windows' times and a motion model)")
    if args.dt != 1:
        # (it was printed as the protocol, 'dt=4', with windows of 7.6 GT frames unsaid,
        # probe BJ)
        raise ParameterError(f"--dt {args.dt} does not apply to {path}: ego-motion windows "
                             "are cut by events or time, not by ground-truth frames")
    table = read_params(path)
    method = str(table.attrs.get("method", ""))
    if method != "egomotion":
        raise ParameterError(f"{path} holds the parameters of '{method or 'unknown'}' (one "
                             "row per cluster): eval scores 'evmotion egomotion''s "
                             "params.h5, one motion per window")
    if not len(table):
        raise ParameterError(f"{path} holds no window")
    warp = str(table.attrs.get("warp", ""))
    angular = args.gt is not None and _angular_velocities(Path(args.gt))
    if angular and warp != "rotation":
        # (a translation's (vx, vy) table was read as 'gx gy gz' lines; probe BR)
        raise ParameterError(f"--gt {args.gt}: an angular velocity (a table's, an IMU's) "
                             "scores the rotation warp's parameters; "
                             f"{path} holds those of a {warp} warp: score them "
                             "against a flow ground truth (--gt) or the events' sharpness "
                             "(--events)")
    reference, gt = _ground_truth(args, angular) if args.gt is not None else (None, None)
    if reference is not None:
        return _run_angular_velocity(args, path, table, reference)
    reject_unused(args, {"--imu-axes": "imu_axes"}, "to a flow ground truth (it maps an "
                  "IMU's axes to the camera's)")
    events = _events_on_grid(args, table.attrs) if args.events else None
    if args.gt is None:
        if events is None:
            raise ParameterError("give --gt GT (accuracy against ground truth), or --events "
                                 "REC alone (the sharpness, FWL, which needs no ground truth)")
        reject_unused(args, {"--out-px": "out_px"}, "without --gt (no accuracy is computed)")
        try:
            rows = sharpness_egomotion(table, events)
        except EventDataError as exc:
            raise ParameterError(f"--events {args.events} against {path}: {exc}") from None
        return _report_sharpness(args, rows)
    _warn_grids(path, table.attrs, args.gt, gt.attrs)
    truth = _sim_truth(args.gt)
    # a file written before the sensor size and K were recorded: the ground truth's
    size = None if "sensor_size" in table.attrs else gt.flow.shape[1:3]
    K = None if "K" in table.attrs or truth is None else truth.K
    out_px = args.out_px if args.out_px is not None else 3.0
    if not np.asarray(table.valid, bool).any():
        raise ParameterError(f"{path}: none of its {len(table)} windows is a measurement "
                             "(collapsed or a poor fit: params.h5's 'valid'): nothing to score")
    try:
        res = evaluate_egomotion(table, gt, truth=truth, sensor_size=size, K=K,
                                 events=events, dt=args.dt, out_px=out_px)
    except (EmptyWindowError, ParameterError) as exc:
        # (a grid mismatch named neither file, probe BJ)
        raise ParameterError(f"{path} against ground truth {args.gt}: {exc}") from None
    except EventDataError as exc:
        raise ParameterError(f"--events {args.events} against {path}: {exc}") from None
    summary = _windows_summary(args, res.flow, out_px)
    # a window that is no measurement has no flow to score: said as such, not as a
    # window without pixels
    unmeasured = int((~np.asarray(table.valid, bool)).sum())
    summary["windows_without_pixels"] -= unmeasured
    summary.update(kind="egomotion", warp=str(table.attrs.get("warp")),
                   windows_not_measurements=unmeasured,
                   parameters_rms=res.parameters_rms, parameter_units=res.units,
                   parameters=res.parameters, parameters_note=res.reason)
    if args.json:
        print_json(summary)
        return 0
    print(f"{path}: the {table.attrs.get('warp')} warp's parameters, scored through their "
          "flow at each pixel")
    # ego-motion windows are cut by events or time, not by GT frames: --dt is no protocol
    _print_windows(args, res.flow, summary, dt_note=False)
    if unmeasured:
        print(f"note: {unmeasured} window{' is' if unmeasured == 1 else 's are'} no "
              "measurement (collapsed or a poor fit: params.h5's 'valid'): not scored")
    rms = res.parameters_rms
    if rms:
        print("parameters, RMS error over the valid windows: " + "  ".join(
            f"{k}={v:.4g} {res.units.get(k, 'rad/s')}" for k, v in rms.items()))
    elif res.reason:
        print(f"note: parameters not compared: {res.reason}")
    return 0


def run(args) -> int:

    from evmotion.cli import print_json
    from evmotion.eval.windows import evaluate_windows
    from evmotion.io.flowfiles import read_gt_flow

    path = Path(args.flow)
    if args.events is None:
        reject_unused(args, {"--format": "format", "--sensor-size": "sensor_size",
                             "--time-unit": "time_unit"},
                      "without --events (they say how to read its recording)")
    # the format attribute of an .h5 FLOW, read once for both checks below
    h5_format = _h5_format(path) if path.suffix.lower() in (".h5", ".hdf5") and \
        path.is_file() else None
    params = _params_file(path, h5_format)
    if args.gt is not None:
        from evmotion.io.flowfiles import gt_in_folder

        # a scene's folder (events, frames and the simulator's schlieren_gt.h5) as --gt
        args.gt = gt_in_folder(args.gt)
    if params is not None:
        return _run_egomotion(args, params)
    # (--imu-axes x,y,q on a flow passed, exit 0; probe CI)
    reject_unused(args, {"--imu-axes": "imu_axes"}, f"to {path.name}, a flow (it maps an "
                  "IMU's axes to the camera's for egomotion's parameters)")
    if args.gt is None:
        return _run_sharpness(args, path, h5_format)
    if _is_event_flow(path, h5_format):
        if Path(args.gt).resolve() == path.resolve():
            raise ParameterError(f"FLOW {path} is the ground truth itself (--gt {args.gt})")
        return _run_event_flow(args, path)
    flow, t0s, t1s, file_out_px, q, attrs = _load_flow(args, h5_format)
    out_px = args.out_px if args.out_px is not None else file_out_px or 3.0
    gt = read_gt_flow(args.gt)
    if gt.flow.shape[1:3] != flow.shape[1:3]:
        raise ParameterError(f"flow is {flow.shape[1:3]} px but ground truth {args.gt} is "
                             f"{gt.flow.shape[1:3]} px (height, width)")
    _warn_grids(path, attrs, args.gt, gt.attrs)
    events = _events_on_grid(args, attrs) if args.events else None
    try:
        res = evaluate_windows(flow, t0s, t1s, gt, events=events, dt=args.dt, out_px=out_px,
                               along_streamlines=args.along_streamlines)
    except EmptyWindowError as exc:
        raise ParameterError(f"{path} against ground truth {args.gt}: {exc}") from None
    except EventDataError as exc:
        raise ParameterError(f"--events {args.events} against {path}: {exc}") from None
    if events is not None and h5_format is not None:
        _warn_other_source(path, args.events)
    q_scored = None if q is None else _add_potential_scores(q, t0s, t1s, args.gt,
                                                             res.windows, res.total)
    summary = _windows_summary(args, res, out_px)
    if q_scored is not None:
        summary["windows_q_scored"] = q_scored
    if args.json:
        print_json(summary)
    else:
        _print_windows(args, res, summary)
    return 0


def _windows_summary(args, res, out_px: float) -> dict:
    """The JSON summary of a :class:`~evmotion.eval.windows.WindowsEvaluation`."""
    per_window = res.windows
    # a window with no pixel where both the estimate and the ground truth are known
    # adds nothing to the means: it is not counted as scored
    empty = sum(1 for w in per_window if w.get("scored", True) and not w.get("n_pixels"))
    return {"flow": str(args.flow), "gt": str(args.gt), "dt": args.dt,
            "n_windows": len(per_window),
            "windows_scored": len(per_window) - res.uncovered - empty,
            "windows_without_pixels": empty,
            "windows_beyond_gt": res.uncovered, "windows_with_other_dt": res.mismatched,
            "mask": res.mask, "out_px": out_px, "units": WINDOW_UNITS, "mean": res.total,
            "windows": per_window}


#: Units of the dense scores, as printed (a space before a unit) and in --json's "units".
METRIC_UNITS = {"AEE": " px", "AEE_zero": " px", "%Out": " %", "AE_deg": " deg"}
WINDOW_UNITS = {"AEE": "px over the window", "AEE_zero": "px over the window",
                "%Out": "% of the pixels with EE > out_px", "AE_deg": "degrees",
                "AE_rad": "radians", "nPE": "% of the pixels with EE > n px",
                "FWL": "ratio", "FWL_gt": "ratio"}


#: Units of the per-event scores in --json's "units" (the dense ones' less the window's
#: pixels: each event's flow against the ground truth at its pixel)
EVENT_UNITS = {"AEE": "px over dt GT frame intervals", "AEE_px_s": "px/s",
               "AEE_zero": "px over dt GT frame intervals",
               "%Out": "% of the scored events with EE > out_px",
               "nPE": "% of the scored events with EE > n px", "AE_deg": "degrees",
               "AE_rad": "radians", "valid_fraction": "share of the events",
               "scored_fraction": "share of the events"}
#: Units of the sharpness scores in --json's "units"
SHARPNESS_UNITS = {"FWL": "ratio (the IWE's variance over the identity warp's)",
                   "FWL_gauss": "ratio (the same of Gaussian-splatted IWEs)"}


def _print_windows(args, res, summary: dict, dt_note: bool = True) -> None:
    """The lines of a :class:`~evmotion.eval.windows.WindowsEvaluation` on stdout
    (``dt_note``: say how many windows span another number of GT frames than --dt)."""
    per_window, total, mismatched = res.windows, res.total, res.mismatched
    empty = summary["windows_without_pixels"]
    keys = [k for k in ("AEE", "AEE_zero", "%Out", "AE_deg", "FWL", "FWL_gt", "q_corr",
                        "q_std_ratio", "n_pixels") if k in total]
    scored = summary["windows_scored"]
    n = len(per_window)
    print(f"{n} window{'' if n == 1 else 's'}" if scored == n else
          f"{scored} of {n} windows scored",
          f"({summary['mask']}" + (f", dt={args.dt})" if dt_note else ")"))
    # (the units were not said, where the per-event score says px and px/s: probe CE)
    print("  ".join(f"{k}={int(total[k]):,}" if k == "n_pixels" else
                    f"{k}={total[k]:.4g}{METRIC_UNITS.get(k, '')}" for k in keys))
    if res.uncovered:
        print(f"note: {res.uncovered} window{' reaches' if res.uncovered == 1 else 's reach'} "
              "more than 1 % beyond the ground truth's time span: not scored (their "
              "ground truth would be only part of the motion)")
    if empty:
        print(f"note: {empty} window{' has' if empty == 1 else 's have'} no pixel where both "
              "the estimate and the ground truth are known: not scored")
    q_scored = summary.get("windows_q_scored")
    if q_scored is not None and q_scored < n:
        # (against a ground truth of another frame rate q_corr was left out unsaid, probe BA)
        print(f"note: {n - q_scored} of {n} windows span no single frame interval of the "
              "ground truth: their q is not scored (q_corr and q_std_ratio"
              + (" over the others)" if q_scored else " absent)"))
    if mismatched and dt_note:
        # (how many: a ground truth in ms read as s gave 0.025 frames a window, unsaid,
        # probe BK)
        frames = [w["gt_frames"] for w in per_window if "gt_frames" in w]
        print(f"note: {mismatched} window{' spans' if mismatched == 1 else 's span'} a number "
              f"of GT frames other than --dt {args.dt}"
              + (f" ({np.median(frames):.3g} a window, median)" if frames else ""))
