"""``evmotion egomotion FILE``: contrast-maximization ego-motion over every window (ch. 3).

Writes into ``--out DIR``: ``params.csv`` and ``params.h5`` (one row per window: time range,
reference time, event count, the warp parameters with their units, cost, focus, penalty,
seconds and the checks: ``collapsed``, ``explained_share``, ``poor_fit`` and ``valid``;
``params.h5`` (:mod:`evmotion.io.paramsfiles`) also says the warp, the pixel grid and each
value's units, and ``evmotion info`` describes it),
and PNG panels (IWE before / after, DIWE and IWA maps) for the first
``--max-png`` windows. ``--json`` prints the per-window parameters with names and units,
and each window's checks: ``collapsed`` and ``diagnostics`` (explained share of the image,
contrast gain over the identity warp; see :mod:`evmotion.methods.diagnostics`). A window
whose estimate is collapsed or explains the image poorly gets one warning line on stderr.
Each finished window is kept in ``OUT/params.part`` until the outputs are written: after an
interruption the same command with ``--resume`` estimates only the others. A recording
longer than a block (:data:`evmotion.streamed_windows.BLOCK_EVENTS` events) is not held in
memory: it is read as a stream, a block of windows at a time (:mod:`evmotion.cli.windowed`),
with the outputs of a whole read.
"""

from __future__ import annotations

import contextlib
import csv
import functools
import io
import os
import shutil
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from evmotion.catalog import MAX_WORKERS, OBJECTIVE_NAMES, WARP_NAMES, WEIGHT_DATASETS
from evmotion.cli.calib import add_camera_arguments, add_hot_pixel_argument
from evmotion.cli.options import (
    DEFAULT_WINDOW_EVENTS,
    POOR_FIT_LINES,
    SHORT_WINDOWS_HINT,
    HelpFormatter,
    add_scheduler_argument,
    add_sensor_size_argument,
    add_time_arguments,
    add_time_unit_argument,
    check_time_order,
    default_window_events,
    duration_us,
    event_format,
    int_range,
    nonnegative_float,
    reject_unused,
    remove_stale_pictures,
    seed_int,
    writable_folder,
)
from evmotion.errors import CalibrationError, ParameterError

EXAMPLES = """examples (sim.h5: made by 'evmotion simulate rotation --out sim.h5'):
  evmotion egomotion sim.h5 --warp rotation --window-events 30000 --max-windows 3 --out ego/
  evmotion egomotion sim.h5 --warp rotation --reg rcad --window-events 30000 --t0 0.02 --t1 0.06 --out ego_rcad/ --json
  evmotion egomotion sim.h5 --warp se2 --window-us 10000 --t0 20ms --max-windows 2 --workers 2 --max-png 0 --out ego_se2/
  evmotion egomotion boxes_rotation/ --warp rotation --window-us 10000 --max-windows 2 --out ego_ecd/
(an ECD folder's calib.txt gives the intrinsics and undistorts the events; --calib FILE
for others. --t0/--t1 are seconds on the recording's clock, or 20ms, 20000us.)
"""


REGULARIZERS = ("divergence", "deformation", "rcad", "whitening", "divergence+deformation")


def add_common(p, objectives=None, regularizers=REGULARIZERS) -> None:
    """Arguments shared by ``egomotion``, ``landscape`` and ``segment`` (their choices from
    :mod:`evmotion.catalog`: the parser does not load the numerical core); ``objectives``
    and ``regularizers``: those the command takes (default all)."""
    p.add_argument("file", help="recording (any format evmotion reads, or an ECD folder)")
    add_sensor_size_argument(p)
    add_time_unit_argument(p)
    p.add_argument("--warp", default="rotation", choices=sorted(WARP_NAMES),
                   help="motion model (default rotation)")
    p.add_argument("--objective", default="variance",
                   choices=sorted(objectives or OBJECTIVE_NAMES),
                   help="focus objective (default variance)")
    # the sum of both penalties is named only where the command offers it (segment's
    # --weight help spoke of it, a --reg choice segment does not take)
    both = "divergence+deformation" in regularizers
    p.add_argument("--reg", default=None, choices=list(regularizers),
                   help="event-collapse regularizer (default none)"
                        + ("; divergence+deformation is the sum of both penalties (thesis "
                           "'Div. + Def.')" if both else ""))
    p.add_argument("--weight", type=nonnegative_float(), default=None,
                   help="regularizer weight lambda >= 0, with --reg (default derived from each "
                        "window: scaled by its effective pixel count"
                        + ("; with divergence+deformation, one weight for both terms)" if both
                           else ")"))
    p.add_argument("--dataset", default=None, choices=sorted(WEIGHT_DATASETS),
                   help="with --reg: use this data set's thesis weights (Sec. 3.6.1) instead "
                        "of the window's (default: the window's)")
    add_camera_arguments(p)
    p.add_argument("--t-ref", default=None, choices=["start", "mid", "end"],
                   help="reference time of the warp within each window (default: "
                        "egomotion mid, or start with --reg, whose collapse penalties are "
                        "defined for it; segment and landscape start)")
    p.add_argument("--format", type=event_format, default=None,
                   help="input format (default: detected)")
    add_hot_pixel_argument(p)


def add_parser(sub) -> None:
    p = sub.add_parser("egomotion", help="camera ego-motion by contrast maximization (ch. 3)",
                       description=__doc__, epilog=EXAMPLES,
                       formatter_class=HelpFormatter)
    add_common(p)
    p.add_argument("--optimizer", default="bfgs", choices=["bfgs", "newton-cg", "adam", "tpe"],
                   help="optimizer (default bfgs)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--window-events", type=int_range(10), metavar="N",
                   help=f"events per window (>= 10; default {DEFAULT_WINDOW_EVENTS}, as flow, "
                        "as many per pixel on sensors larger than 346 x 260)")
    g.add_argument("--window-us", type=duration_us,
                   help="window duration: microseconds, or with a unit (10000, 10ms, 0.01s)")
    add_time_arguments(p)
    p.add_argument("--workers", type=int_range(1, MAX_WORKERS), default=1,
                   help="parallel worker processes (default 1)")
    add_scheduler_argument(p)
    p.add_argument("--seed", type=seed_int, default=None,
                   help="seed of the TPE sampler (--optimizer tpe; default 0)")
    p.add_argument("--warm-start", action="store_true",
                   help="start each window from the previous estimate (runs sequentially)")
    p.add_argument("--max-png", type=int_range(0), default=20,
                   help="PNG panels for the first N windows (default 20; 0 = none)")
    p.add_argument("--out", required=True,
                   type=writable_folder("params.csv, params.h5 and PNG panels"),
                   help="output folder")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run: the windows it finished (kept in "
                        "OUT/params.part) are not estimated again; the same options needed")
    p.add_argument("--json", action="store_true", help="print per-window parameters as JSON")
    p.set_defaults(func=run)


def check_common(args) -> None:
    """Cross-option checks of :func:`add_common` (--dataset None: the window's weight)."""
    if args.reg is None:
        reject_unused(args, {"--weight": "weight", "--dataset": "dataset"},
                      "without --reg (no regularizer to weigh)")
    if args.weight is not None:
        # (the weight given won, the data set's dropped unsaid; probe CI)
        reject_unused(args, {"--dataset": "dataset"}, "with --weight (the weight given)")


def check_scheduler(args) -> None:
    """``--scheduler`` runs the windows on the cluster's workers: ``--workers`` and
    ``--warm-start`` (windows in sequence) do not go with it."""
    if args.scheduler is None:
        return
    if args.workers != 1:
        raise ParameterError(f"--workers {args.workers} does not apply with --scheduler "
                             f"{args.scheduler}: the cluster's workers run the windows")
    if getattr(args, "warm_start", False):
        raise ParameterError(f"--warm-start runs the windows in sequence; it does not apply "
                             f"with --scheduler {args.scheduler}")


def centred_warp(warp: str) -> bool:
    """Whether a warp (without intrinsics) rotates or scales about the image centre, which
    a wrong sensor size moves."""
    return warp not in ("translation", "homography", "affine")


def load_events_and_camera(args, **cut):
    """Read the recording and its camera (:func:`evmotion.cli.calib.camera_for`); undistort
    when the camera is distorted, unless ``--no-undistort``. Returns ``(events, camera)``
    and sets ``args.grid`` (which pixel grid the events are on). ``cut``: how the windows
    are cut (``n_events`` or ``duration_us``, and ``min_events``), so that with
    ``--max-windows`` only what those windows need is read
    (:func:`evmotion.cli.calib.read_for_windows`)."""
    from evmotion.cli.calib import read_for_windows

    events, cam, grid = read_for_windows(args, **cut)
    check_camera(args, cam, grid, events.meta, events.sensor_size)
    return events, cam


def check_camera(args, cam, grid: str, meta: dict, sensor_size: tuple[int, int]) -> None:
    """Sets ``args.grid`` and ``args.distortion`` (the lens distortion the events were
    moved by); refuses the rotation warp without intrinsics, and says where a centred warp
    turns about the centre of a ``sensor_size`` only guessed (the events'
    ``meta["sensor_size_from"]``)."""
    args.grid = grid
    # (params.h5 keeps it: eval says when a ground truth on the sensor's grid is compared
    # with them)
    args.distortion = ([float(v) for v in cam.dist] if cam is not None and cam.is_distorted
                       and args.grid.startswith("undistorted (K=") else None)
    if cam is None and args.warp == "rotation":
        raise CalibrationError(f"{args.file}: the rotation warp needs camera intrinsics; "
                               "none found with the recording, pass --calib FILE or --K "
                               "fx,fy,cx,cy")
    guessed = str(meta.get("sensor_size_from", ""))
    if guessed.startswith("ECD default") and cam is None and centred_warp(args.warp):
        # (a calibration says the sensor, as the ECD folders' calib.txt does)
        from evmotion.cli import warn_line

        h, w = sensor_size
        warn_line(f"{args.file} states no sensor size: taken as {w}x{h} px ({guessed}); "
                  f"the {args.warp} warp turns or scales about the image centre, so give "
                  "the true size with --sensor-size H W")


class WindowOutput(NamedTuple):
    """What a window job sends back: the estimate without its images, and its PNG panel
    (None for windows past the last one drawn)."""

    result: Any
    panel: bytes | None


def _window_job(events, t0_us: int, t1_us: int, *, warp, objective, reg, weight, optimizer, K,
                t_ref, seed, dataset, last_png_t0_us: int | None, init=None) -> WindowOutput:
    """Estimate one window ``[t0_us, t1_us)``. The windows that get a PNG panel (those
    starting at or before ``last_png_t0_us``, the start of the last one; None: no panel)
    compute the DIWE/IWA maps and draw the panel here, in the worker: a 2 x 2 panel of a
    240 x 180 window takes ~0.16 s, more than the estimate, and the caller only writes the
    bytes (``benchmarks/results/cli_panels.md``). No result keeps its IWEs or maps (0.7 MB
    a window to send back and hold)."""
    import dataclasses
    import warnings

    from evmotion.errors import EvmotionWarning
    from evmotion.methods.egomotion import estimate_egomotion

    png = last_png_t0_us is not None and t0_us <= last_png_t0_us
    # the result carries its warnings (diagnostics["warnings"]); run() prints them once
    # per window, also for results from worker processes
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", EvmotionWarning)
        r = estimate_egomotion(events, warp, objective, reg, weight, optimizer, K=K,
                               t_ref=t_ref, init=init, seed=seed, dataset=dataset, maps=png)
    return WindowOutput(dataclasses.replace(r, iwe_before=None, iwe_after=None, maps={}),
                        _panel(r, t0_us, t1_us) if png else None)


def _panel(r, t0_us: int, t1_us: int) -> bytes:
    """The window's PNG panel: its IWE without and with the warp (and the DIWE/IWA maps
    where the regularizer made them)."""
    from evmotion.viz import images
    from evmotion.viz.titles import parameters_text

    # one scale for both (the warped image's): the sharper one is also the darker
    vmax = images.full_scale(r.iwe_after)
    panels = [images.iwe_to_rgb(r.iwe_before, vmax=vmax),
              images.iwe_to_rgb(r.iwe_after, vmax=vmax)]
    values = parameters_text(r.param_names, r.params, r.param_units)
    titles = [f"IWE, zero motion\nwhite 0, black >= {vmax:.3g} events / px",
              f"IWE warped (same scale)\n{values}"]
    suptitle = _panel_title(r, t0_us, t1_us)
    if "diwe" in r.maps:
        # both unitless: the divergence of the window's displacement (px per px), an
        # area ratio ("full at +-0.19" had no unit, probe BX)
        maps = [("DIWE (divergence x window, px/px)", r.maps["diwe"]),
                ("IWA - 1 (deformation, area ratio - 1)", r.maps["iwa"] - 1.0)]
        peaks = [float(np.nanmax(np.abs(img))) if np.size(img) else 0.0 for _, img in maps]
        if max(peaks) < 1e-12:
            # two blank panels were half the picture (probe DA): said in a line instead
            suptitle += f"\nDIWE and IWA: 0 everywhere (none in a {r.warp})"
        else:
            for (name, img), peak in zip(maps, peaks, strict=True):
                panels.append(_signed_rgb(img))
                titles.append(f"{name}\n0 everywhere: none in a {r.warp}" if peak < 1e-12
                              else f"{name}\nred +, blue -, full at +-{peak:.3g}")
    return images.panel_png(panels, titles, ncols=2, suptitle=suptitle)


def _panel_title(r, t0_us: int, t1_us: int) -> str:
    """The panel's title: the window, and the verdict where the estimate is not a
    measurement (a picture looked at alone must not pass for one)."""
    # whole µs: epoch times in ms at 6 digits read [1.58916e+12, 1.58916e+12] (probe Y)
    # the window as params.csv gives it (its first and last events, a closed interval,
    # had disagreed with the table's [t0, t1), probe BX)
    from evmotion.viz.titles import duration_text

    t0, t1 = int(t0_us), int(t1_us)
    title = f"{r.warp}, {r.n_events:,} events, [{t0:,}, {t1:,}) µs ({duration_text(t1 - t0)})"
    if not r.valid:
        why = ("event collapse" if r.collapsed else "poor fit" if r.poor_fit
               else "non-finite parameters")
        title += f"\nNOT A MEASUREMENT: {why} (valid = False)"
    return title


def run(args) -> int:
    from evmotion.cli import print_json, warn_line
    from evmotion.cli.options import scheduler_client
    from evmotion.cli.windowed import open_windowed
    from evmotion.events import events_digest
    from evmotion.io.journal import Journal
    from evmotion.methods.egomotion import reference_time
    from evmotion.parallel import imap_window_blocks
    from evmotion.utils import interrupts_deferred, progress

    check_common(args)
    # the library's rule: mid, or start with a regularizer (another time with one: warned)
    args.t_ref = reference_time(args.t_ref, args.reg)
    if args.warm_start and args.workers > 1:
        raise ParameterError(f"--warm-start runs the windows in sequence; it does not apply "
                             f"with --workers {args.workers}")
    check_scheduler(args)
    if args.optimizer != "tpe":
        reject_unused(args, {"--seed": "seed"}, f"with --optimizer {args.optimizer} "
                      "(it seeds the TPE sampler)")
    args.seed = 0 if args.seed is None else args.seed
    check_time_order(args)
    args.window_events_given = args.window_events is not None
    if args.window_events is None and args.window_us is None:
        args.window_events = default_window_events(args.file, args.format,
                                                    args.sensor_size)
    cut = {"n_events": args.window_events, "duration_us": args.window_us, "min_events": 10}
    # (a long recording is streamed, a block of windows at a time: probe DL)
    rec = open_windowed(args, **cut, check=functools.partial(check_camera, args))
    windows, cam = rec.windows, rec.camera
    K = None if cam is None else cam.K
    # windows are in time order: the first --max-png are those starting by the last one's t0
    last_png = windows[min(args.max_png, len(windows)) - 1].t0 if args.max_png > 0 else None
    job = functools.partial(_window_job, warp=args.warp, objective=args.objective,
                            reg=args.reg, weight=args.weight, optimizer=args.optimizer, K=K,
                            t_ref=args.t_ref, seed=args.seed, dataset=args.dataset,
                            last_png_t0_us=last_png)
    out_dir = Path(args.out)
    made_out = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    header = _journal_header(args, rec.window_events(0), K)
    journal, done = Journal.open_run(out_dir / JOURNAL_NAME, header, rec.events, windows,
                                     args.resume)
    resumed = len(done)
    # the panels of this run wait in a folder of their own until it ends: an earlier
    # run's complete results (params.csv / .h5 and panels) stay as they are until this
    # run's replace them, and an interrupted run leaves its panels beside its journal
    staged = out_dir / PANELS_PART
    if not done:
        # (also with --resume when nothing is resumed: an interrupted run's panels were
        # published as this run's, probe BH)
        shutil.rmtree(staged, ignore_errors=True)
    staged.mkdir(exist_ok=True)
    todo = [k for k in range(len(windows)) if k not in done]
    try:
        with journal:
            if args.warm_start:
                prev = [k for k in done if done[k][2][0] is not None]
                init = done[max(prev)][2][0].params if prev else None
                with contextlib.closing(_todo_blocks(rec, journal, done)) as blocks, \
                        progress(None, total=len(todo), desc="egomotion", unit="win") as bar:
                    for block, block_windows, positions in blocks:
                        for w, k in zip(block_windows, positions, strict=True):
                            sub = block.window(w)
                            out = job(sub, w.t0, w.t1, init=init)
                            init = out.result.params
                            journal.add(k, w.t0, w.t1, events_digest(sub),
                                        (_written(staged, w, out), None))
                            bar.update(1)
            else:
                with scheduler_client(args.scheduler) as client, contextlib.closing(
                        imap_window_blocks(job, _todo_blocks(rec, journal, done),
                                           total=len(todo), workers=args.workers,
                                           scheduler=client, desc="egomotion",
                                           with_window=True)) as results:
                    # each window's panel is written as its result comes in, while later
                    # windows run
                    for k, sub, r in results:
                        value = None if r.value is None else _written(staged, windows[k],
                                                                      r.value)
                        journal.add(k, windows[k].t0, windows[k].t1, events_digest(sub),
                                    (value, r.error))
    except BaseException:
        # nothing finished (a cluster out of reach, say): nothing to resume, nor a picture:
        # an empty staging folder, and the output folder this run made
        if not journal.settle(bool(done)):
            if not any(staged.iterdir()):
                staged.rmdir()
            if made_out and not any(out_dir.iterdir()):
                out_dir.rmdir()
        raise
    done = type(journal).read(journal.path, header)
    results = [(w, *done[k][2]) for k, w in enumerate(windows)]
    # published whole: an interrupt among the moves and the files left this run's
    # params.csv beside an earlier run's params.h5, or its panels lost to the resume
    # (probe BH)
    with interrupts_deferred():
        remove_stale_pictures(out_dir, ("window_",))
        for panel in sorted(staged.glob("window_*.png")):
            os.replace(panel, out_dir / panel.name)
        shutil.rmtree(staged, ignore_errors=True)
        rows = write_outputs(out_dir, results, grid=args.grid,
                             sensor_size=rec.sensor_size, K=K,
                             distortion=getattr(args, "distortion", None))
        journal.path.unlink()
    failed = [f"window {w.index}: {err.splitlines()[0]}" for w, _, err in results if err]
    if not rows:
        from evmotion.errors import EvmotionError

        raise EvmotionError(f"{args.file}: all {len(results)} windows failed; the first: "
                            f"{failed[0] if failed else 'no result'}")
    for line in failed[:POOR_FIT_LINES]:
        warn_line(f"{line} (no row in params.csv / .h5)")
    said = [f"window {w.index}: {msg}" for w, r, err in results
            for msg in ([] if err or r is None else r.diagnostics.get("warnings", []))]
    for line in said[:POOR_FIT_LINES]:
        warn_line(line)
    if len(said) > POOR_FIT_LINES:
        # hundreds of windows of one recording said the same thing, line by line
        no_focus = sum("no focus" in ln for ln in said)
        warn_line(f"... and {len(said) - POOR_FIT_LINES} more warnings of other windows "
                  "(--json lists each window's diagnostics)"
                  + (SHORT_WINDOWS_HINT if 2 * no_focus >= len(results) else ""))
    if args.json:
        print_json({"file": str(args.file), "grid": args.grid, "warp": args.warp,
                    "regularizer": args.reg,
                    "objective": args.objective, "optimizer": args.optimizer,
                    "windows": rows, "failed": failed})
    else:
        print(f"{len(rows)} window{'' if len(rows) == 1 else 's'}"
              + (f" ({resumed} kept from the interrupted run)" if resumed else "")
              + f" -> {out_dir}/params.csv, params.h5"
              + (f"; {len(failed)} failed" if failed else ""))
    return 0


# the journal of a run's finished windows, in its output folder until the run ends
JOURNAL_NAME = "params.part"
# the folder of a run's panels, in its output folder until the run ends
PANELS_PART = "panels.part"


def _journal_header(args, first, K) -> dict:
    """What a resumed run must share with the interrupted one: the estimate's options, the
    windows' cut and the events of the first window, ``first`` (another recording has
    others)."""
    from evmotion.events import fingerprint

    return {"warp": args.warp, "objective": args.objective, "reg": args.reg,
            "weight": args.weight, "optimizer": args.optimizer, "t_ref": args.t_ref,
            "seed": args.seed, "dataset": args.dataset, "warm_start": args.warm_start,
            "window_events": args.window_events, "window_us": args.window_us,
            "t0": args.t0, "grid": args.grid, "remove_hot_pixels": args.remove_hot_pixels,
            "K": None if K is None else np.asarray(K, np.float64).round(9).tolist(),
            "first_window": fingerprint(first)}


def _todo_blocks(rec, journal, done: dict):
    """The blocks of ``rec`` (:meth:`~evmotion.cli.windowed.WindowedRecording.blocks`)
    less the windows ``done`` in the interrupted run; those are checked against the
    journal as they pass where the recording is streamed (their events were not held when
    it was opened)."""
    if not rec.streamed:
        keep = [k for k in range(len(rec.windows)) if k not in done]
        if keep:
            yield from rec.blocks(keep)
        return
    with contextlib.closing(rec.blocks()) as blocks:
        for block, block_windows, positions in blocks:
            todo = []
            for w, k in zip(block_windows, positions, strict=True):
                if k in done:
                    journal.check_events(k, w.t0, w.t1, block.window(w))
                else:
                    todo.append((w, k))
            if todo:
                yield block, [w for w, _ in todo], [k for _, k in todo]


def _written(out_dir: Path, w, out: WindowOutput):
    """Write the window's panel (if it has one) and return its result."""
    from evmotion.utils import atomic_write_bytes

    if out.panel is not None:
        atomic_write_bytes(out_dir / f"window_{w.index:05d}.png", out.panel)
    return out.result


def write_outputs(out_dir: Path, results, grid: str | None = None,
                  sensor_size: tuple[int, int] | None = None, K=None,
                  distortion: list[float] | None = None) -> list[dict]:
    """params.csv and params.h5 of the windows' results ``(window, result or None, error)``
    (the panels are written as the results come in, :func:`_written`); returns the JSON
    rows. ``grid`` (which pixel grid the events were on), ``sensor_size`` and the
    intrinsics ``K`` go into params.h5's attributes: with them the parameters give each
    window's flow (``evmotion eval``); so does the lens ``distortion`` the events were
    undistorted by."""
    from evmotion.io.paramsfiles import ParamsTable, write_params_h5
    from evmotion.methods.diagnostics import MIN_CONTRAST_GAIN, MIN_FIT_EVENTS, POOR_FIT_SHARE
    from evmotion.methods.measured import MAX_GAP_SHARE, min_motion_px
    from evmotion.utils import atomic_write_text

    ok = [(w, r) for w, r, err in results if err is None and r is not None]
    rows = []
    for w, r in ok:
        d = r.as_dict()
        rows.append({"window": w.index, "t0_us": w.t0, "t1_us": w.t1, "t_ref_us": r.t_ref_us,
                     "n_events": r.n_events, "params": d["params"], "units": d["units"],
                     "cost": r.cost, "focus": r.focus, "penalty": r.penalty,
                     "weight": d["weight"], "seconds": r.timings["total"],
                     "compile_s": r.timings["compile"], "estimate_s": r.timings["estimate"],
                     "collapsed": r.collapsed, "diagnostics": d["diagnostics"]})
        if r.warp == "rotation":
            # the camera's angular velocity, camera frame x right, y down, z forward
            rows[-1]["omega"] = [float(v) for v in r.params]
            rows[-1]["omega_units"] = "rad/s"
    if not ok:
        return rows
    names = ok[0][1].param_names
    units = ok[0][1].param_units
    params = np.array([r.params for _, r in ok], dtype=np.float64)
    # each result's verdict (collapsed estimates and poor fits are not measurements)
    for row, (_, r) in zip(rows, ok, strict=True):
        row["poor_fit"], row["valid"] = r.poor_fit, r.valid
    collapsed = np.array([row["collapsed"] for row in rows], dtype=bool)
    poor_fit = np.array([row["poor_fit"] for row in rows], dtype=bool)
    valid = np.array([row["valid"] for row in rows], dtype=bool)
    share = np.array([_share(row) for row in rows])
    gain = np.array([row["diagnostics"].get("contrast_gain", np.nan) for row in rows])
    chance = np.array([row["diagnostics"].get("chance_gain", np.nan) for row in rows])
    buf = io.StringIO()
    wr = csv.writer(buf)
    wr.writerow(["window", "t0_us", "t1_us", "t_ref_us", "n_events",
                 *[f"{n} [{u}]" for n, u in zip(names, units, strict=True)],
                 "cost", "focus", "penalty", "seconds", "collapsed", "explained_share",
                 "contrast_gain", "chance_gain", "poor_fit", "valid"])
    for k, row in enumerate(rows):
        wr.writerow([row["window"], row["t0_us"], row["t1_us"], row["t_ref_us"], row["n_events"],
                     *[repr(row["params"][n]) for n in names], repr(row["cost"]),
                     repr(row["focus"]), repr(row["penalty"]), f"{row['seconds']:.4f}",
                     int(row["collapsed"]), repr(_share(row)),
                     repr(row["diagnostics"].get("contrast_gain", float("nan"))),
                     repr(float(chance[k])), int(poor_fit[k]), int(valid[k])])
    atomic_write_text(out_dir / "params.csv", buf.getvalue())
    cols = {"window": ("", "window index"), "t_ref_us": ("us", "reference time of the warp"),
            "n_events": ("events", "events in the window"), "cost": ("", "objective value"),
            "focus": ("", "focus term"), "penalty": ("", "regularizer term"),
            "collapsed": ("", "flag: the IWE collapsed"),
            "poor_fit": ("", f"flag: explained_share < {POOR_FIT_SHARE} or NaN (no tile to "
                             f"test), contrast_gain or chance_gain < {MIN_CONTRAST_GAIN}, a "
                             f"motion under {min_motion_px(ok[0][1].warp):g} px, fewer "
                             "than "
                             f"{MIN_FIT_EVENTS} events or a time gap over "
                             f"{MAX_GAP_SHARE:.0%} of the window"),
            "explained_share": ("", "share of the image the warp explains"),
            "contrast_gain": ("", "contrast over the identity warp's"),
            "chance_gain": ("", "the warp's alignment of the events over that with their "
                                "times shuffled")}
    values = {k: np.array([row[k] for row in rows]) for k in list(cols)[:6]}
    values.update(collapsed=collapsed, poor_fit=poor_fit, explained_share=share,
                  contrast_gain=gain, chance_gain=chance)
    first = ok[0][1]
    write_params_h5(out_dir / "params.h5", ParamsTable(
        params, tuple(names), tuple(units),
        np.array([row["t0_us"] for row in rows]), np.array([row["t1_us"] for row in rows]),
        valid, values,
        {k: u for k, (u, _) in cols.items()}, {k: m for k, (_, m) in cols.items()},
        {"method": "egomotion", "warp": first.warp, "regularizer": str(first.regularizer),
         "objective": first.objective, "grid": "not recorded" if grid is None else grid,
         **({} if sensor_size is None else {"sensor_size": np.asarray(sensor_size, np.int64)}),
         **({} if K is None else {"K": np.asarray(K, np.float64)}),
         **({} if distortion is None else {"distortion": np.asarray(distortion)})}))
    return rows


def _share(row: dict) -> float:
    """Explained share of a window's image (NaN when not checked or collapsed)."""
    return float(row["diagnostics"].get("fit", {}).get("explained_share", np.nan))


def _signed_rgb(img: np.ndarray) -> np.ndarray:
    from evmotion.viz import images

    return images.iwe_to_rgb(img, polarity=True)
