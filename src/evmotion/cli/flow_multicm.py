"""``evmotion flow FILE --method multicm``: dense flow by multi-reference CMax (ch. 4).

Windows come from ``--window-events N`` (default 30000; on a sensor larger than 346 x 260
as many events per pixel), ``--window-us T`` or
``--window-gt GT`` (the ground truth's timestamps, ``--gt-dt`` frames per window). Each
window is warm-started from the previous one. With ``--workers > 1`` the windows are split
into one contiguous chunk per worker (:func:`evmotion.parallel.map_windows`) and the warm
start runs within each chunk only, so the first window of every chunk starts from zero flow.
``--scheduler ADDRESS`` runs the chunks on a Dask cluster instead (one chunk per worker
thread of the cluster, or ``--workers`` chunks: the same chunks give the same flow as
``--workers`` here); this process sends each chunk its events (see docs/cluster.rst).

Output through :func:`evmotion.io.flowout.open_flow_output`, by ``--out`` extension:
``.h5`` or ``.npz`` all windows (flow in px/s, each window's ``[t0, t1)``, and ``valid``:
the pixels whose flow events support), ``.flo`` or ``.png`` (DSEC) displacement over each
window with a JSON sidecar of its times (a pattern such as ``flow_{:05d}.flo`` for several
windows). Each window is written as soon as it is estimated, so memory does not grow with
the number of windows. A window that cannot be estimated (all its events at one time, say)
is written with no valid pixel, named in a warning and marked ``skipped`` in the ``--json``
rows; a run in which no window can be is an error.
"""

from __future__ import annotations

import contextlib
import itertools
import time
from pathlib import Path

import numpy as np

from evmotion.catalog import MAX_TIME_BINS, MAX_WORKERS
from evmotion.cli.options import (
    DEFAULT_WINDOW_EVENTS,
    POOR_FIT_LINES,
    SHORT_WINDOWS_HINT,
    add_scheduler_argument,
    check_flow_out,
    check_free_space,
    default_window_events,
    finite_float,
    int_range,
    nonnegative_float,
    reject_unused,
    remove_stale_pictures,
    seed_int,
)
from evmotion.errors import EmptyWindowError, ParameterError

# the options only this method reads: attribute and default (see evmotion.cli.flow)
OPTIONS: dict[str, tuple[str, object]] = {
    "--time-aware": ("time_aware", "none"),
    "--time-bins": ("time_bins", None),
    "--scales": ("scales", 5),
    "--finest-level": ("finest_level", None),
    "--lambda": ("lam", 0.0025),
    "--objective": ("objective", "gradient_magnitude"),
    "--max-iter": ("max_iter", 20),
    "--tol": ("tol", 3e-5),
    "--seed": ("seed", 0),
    "--workers": ("workers", 1),
    "--init": ("init", "previous"),
    "--scheduler": ("scheduler", None),
}


def add_arguments(group) -> None:
    group.add_argument("--time-aware", choices=("none", "upwind", "burgers"), default=None,
                       help="time-aware flow transport (4.8) (default none)")
    group.add_argument("--time-bins", type=int_range(1, MAX_TIME_BINS), default=None, metavar="B",
                       help="with --time-aware: time bins of the time-aware flow (default 5; "
                            "40 from 640 px wide)")
    group.add_argument("--scales", type=int_range(1, 5), default=None,
                       help="coarse-to-fine scales ending at the finest tiles, 1 to 5 "
                            "(default 5, at most --finest-level)")
    group.add_argument("--finest-level", type=int_range(1, 8), default=None, metavar="L",
                       help="finest scale: 2^(L-1) x 2^(L-1) tiles, 1 to 8 (default: from "
                            "each window's event count, the finest up to 5 whose tiles "
                            "hold 100 events on average: 16x16 tiles from 25,600 events)")
    group.add_argument("--lambda", dest="lam", type=nonnegative_float(), default=None,
                       help="TV weight of (4.9), >= 0 (default 0.0025)")
    group.add_argument("--objective", default=None,
                       choices=("gradient_magnitude", "variance", "avg_timestamp",
                                "avg_timestamp_norm"),
                       help="focus function (default gradient magnitude)")
    group.add_argument("--max-iter", type=int_range(1, 10_000), default=None,
                       help="optimizer iterations per scale (default 20, at most 10000)")
    group.add_argument("--tol", type=finite_float(0.0, 1.0, hi_open=True), default=None,
                       help="from the 4x4-tile scale on, stop a scale once an iteration "
                            "lowers the objective by less than this, in [0, 1) (default "
                            "3e-5; 0: always --max-iter iterations)")
    group.add_argument("--seed", type=seed_int, default=None,
                       help="seed of the sub-pixel jitter of the event coordinates on the "
                            "coarse scales (default 0); the same seed gives the same flow")
    group.add_argument("--workers", type=int_range(1, MAX_WORKERS), default=None,
                       help="parallel worker processes (default 1); each takes a contiguous "
                            "chunk of windows, whose first window starts from zero flow "
                            "instead of the previous window's, so the windows of each later "
                            "chunk differ from one worker's, most in its first windows and "
                            "where a fit is marginal (on simulated rotations 0.1 %% of the "
                            "flow, and up to 1.5 %% on valid windows of a 79-window run with "
                            "--tol 0 --max-iter 40); a chunk's windows are written when it "
                            "ends, so an interrupted run keeps the finished chunks only "
                            "(none before the first ends; --resume continues with one "
                            "worker); with --scheduler, the number of chunks (default: the "
                            "cluster's worker threads)")
    add_scheduler_argument(group, "chunks of windows")
    group.add_argument("--init", choices=("previous", "dnn"), default=None,
                       help="start each window from the previous one's flow (default) or "
                            "from the network's (--checkpoint), skipping the coarse scales")


def _windows(args, events):
    """The windows to estimate (at least 10 events each), within --t0/--t1, at most
    --max-windows of them."""
    from evmotion.cli.options import select_windows

    kw = {"min_events": MIN_WINDOW_EVENTS, "file": args.file}
    if args.window_gt:
        from evmotion.io.flowfiles import read_gt_flow

        gt = read_gt_flow(args.window_gt)
        # frame edges: every GT start plus the end of the last frame
        edges = np.append(np.asarray(gt.t0), np.asarray(gt.t1)[-1:])
        if edges.size < args.gt_dt + 1:
            raise ParameterError(f"--window-gt {args.window_gt}: {max(edges.size - 1, 0)} "
                                 f"ground-truth frame(s), fewer than --gt-dt {args.gt_dt}")
        return select_windows(args, events, edges_us=edges, dt=args.gt_dt, **kw)
    windows = select_windows(args, events, **_cut(args), **kw)
    return _one_window_for_one_file(args, events, windows)


#: Below this many --window-events windows' worth of events, a single .flo / .png output
#: holds the first window (with a warning); from it on, the run is refused before the
#: work (a pattern or .h5 holds every window).
ONE_FILE_WINDOWS = 3


def _one_window_for_one_file(args, events, windows):
    """A single .flo/.png output and a recording of one count window plus a remainder
    (a window cut by time from another tool holds 30,457 events, not 30,000): one window
    of all its events, with a warning line, rather than no output (a second window) or the
    remainder's events left out (a remainder under 10 events)."""
    from evmotion.events import make_windows
    from evmotion.io.flowout import PER_WINDOW, flow_container, is_pattern

    out = Path(args.out)
    n = args.window_events or DEFAULT_WINDOW_EVENTS
    if (args.window_us is not None or args.window_gt or is_pattern(out)
            or flow_container(out) not in PER_WINDOW or args.max_windows is not None):
        return windows
    t0, t1 = getattr(args, "t0", None), getattr(args, "t1", None)
    total = events.slice_time(t0, t1) if t0 is not None or t1 is not None else events
    from evmotion.cli import warn_line

    if 2 * n <= len(total) < ONE_FILE_WINDOWS * n and len(windows) > 1:
        # two windows' worth for one file: the first, said (it was refused, probe AV: the
        # judged one-window command on a 60,000-event window file); a whole recording of
        # many windows into one file is still refused before the work
        warn_line(f"{args.file} holds {len(total):,} events, {len(windows)} windows of "
                  f"--window-events {n}: {out.name} holds the first; a pattern "
                  f"({out.stem}_{{:05d}}{out.suffix}) or .h5 output holds them all")
        return windows[:1]
    if not n < len(total) < 2 * n:
        return windows

    warn_line(f"{args.file} holds {len(total):,} events, one window of --window-events {n} "
              f"and {len(total) - n:,} more: {out.name} holds one window, so all "
              f"{len(total):,} are estimated as one")
    return make_windows(events, n_events=len(total), t0=t0, t1=t1)


def _moved(cam, grid: str) -> bool:
    """Whether this run moved the events off the sensor's grid (a calibration with
    distortion; a pinhole one, or events undistorted as recorded, leave them)."""
    return (cam is not None and cam.is_distorted and grid.startswith("undistorted")
            and "as recorded" not in grid)


def _cut(args) -> dict:
    """How the windows are cut, by duration or by count (not by ground-truth frames)."""
    if args.window_us is not None:
        return {"duration_us": args.window_us}
    return {"n_events": args.window_events or DEFAULT_WINDOW_EVENTS}


# the fewest events a window must hold to be estimated
MIN_WINDOW_EVENTS = 10


def _estimate_parallel(events, windows, kwargs, workers, stack, keep_iwes=False,
                       scheduler=None, on_empty="raise"):
    """The windows' results in order, from ``workers`` chunks on local processes or, with
    ``scheduler`` (an address), on that Dask cluster (``workers`` None: one chunk per
    worker thread of the cluster), each chunk's as soon as it is done. The scheduler is
    reached here, before any output exists (a bad address writes nothing); the client
    stays connected until ``stack`` (a :class:`contextlib.ExitStack`) closes."""
    from evmotion.cli.options import cluster_threads, scheduler_client
    from evmotion.methods.multicm_windows import iter_chunks

    client = stack.enter_context(scheduler_client(scheduler))
    if workers is None:
        workers = cluster_threads(client)
    return iter_chunks(events, windows, workers=workers, scheduler=client,
                       keep_iwes=keep_iwes, on_empty=on_empty, **kwargs)


def _png(png_dir: Path, i: int, r, max_speed) -> None:
    from evmotion.utils import atomic_write_bytes
    from evmotion.viz import event_picture_png, save_flow_png

    png_dir.mkdir(parents=True, exist_ok=True)
    when = f"window {i}: {r.t0_us * 1e-6:.4f}-{r.t1_us * 1e-6:.4f} s"
    if r.valid is not None and not r.valid.any():
        # its flow is drawn (the unmasked picture, the warped events) as the estimate it
        # is, under a title that says so (it looked like any other window's, probe BX)
        when += ": NOT A MEASUREMENT (no valid pixel)"
    save_flow_png(png_dir / f"flow_{i:05d}.png", r.flow, max_speed=max_speed, title=when)
    save_flow_png(png_dir / f"flow_masked_{i:05d}.png", r.flow, max_speed=max_speed,
                  valid=_valid(r), title=when)
    has = r.iwes["identity"] > 0
    vmax = float(np.percentile(r.iwes["tmid"][has], 99)) if has.any() else None
    for key, what in (("tmid", "events warped by the flow to the window's middle"),
                      ("identity", "events not warped")):
        # one full scale for both: the warped image's sharpness shows against the other's
        atomic_write_bytes(png_dir / f"iwe_{key}_{i:05d}.png", event_picture_png(
            r.iwes[key], vmax=vmax, title=f"{when}, {what}"))


def _valid(r) -> np.ndarray:
    return r.valid if r.valid is not None else np.ones(r.flow.shape[:2], bool)


def _row(r, w) -> dict:
    valid = _valid(r)
    speed = np.linalg.norm(r.flow, axis=-1)
    row = {"t0_us": w.t0, "t1_us": w.t1, "n_events": r.n_events, "focus": r.focus,
           "seconds": r.timings["total_s"], "compile_s": r.timings.get("compile_s", 0.0),
           "estimate_s": r.timings.get("estimate_s", r.timings["total_s"]),
           "mean_speed_px_s": float(speed[valid].mean()) if valid.any() else 0.0,
           "valid_fraction": float(valid.mean())}
    if "finest_level" in r.meta:  # multicm's: its finest tiles, 2^(L-1) per side
        row["finest_level"] = int(r.meta["finest_level"])
    if "input_scale" in r.meta:  # the network's: the input scale whose flow was kept
        row["input_scale"] = int(r.meta["input_scale"])
    if "gain" in r.meta:  # the network's: the magnitude its flow was kept at
        row["gain"] = float(r.meta["gain"])
    if "planar" in r.meta:  # the network's: the plane's polished flow kept instead
        row["planar"] = bool(r.meta["planar"])
    if "refined" in r.meta:  # the network's: its refinement on multicm's tiles kept
        row["refined"] = bool(r.meta["refined"])
    if np.isfinite(r.meta.get("chance_gain", np.nan)):
        # how much better the flow aligns the events than with their times shuffled
        row["chance_gain"] = float(r.meta["chance_gain"])
    if np.isfinite(r.meta.get("halves_correlation", np.nan)):
        # how well the flow carries the window's first half onto its second
        row["halves_correlation"] = float(r.meta["halves_correlation"])
    if np.isfinite(r.meta.get("refit_gain", np.nan)):
        # with few events: its focus over that of the same fit with the times shuffled
        row["refit_gain"] = float(r.meta["refit_gain"])
    if r.meta.get("no_focus"):  # warned: the flow sharpens nothing, no pixel is valid
        row["no_focus"] = True
    if r.meta.get("beyond_range"):  # warned: the network's magnitudes are not measured
        row["beyond_range"] = True
    return row


def borrowed_options(args) -> tuple[str, ...]:
    """The network's options this method reads: with ``--init dnn``, its torch device and
    threads (probe AP: they were refused as a dnn option)."""
    return ("--device", "--threads") if args.init == "dnn" else ()


def check_args(args) -> None:
    """Options that do not go together (before the defaults are filled in)."""
    if args.init != "dnn":
        reject_unused(args, {"--checkpoint": "checkpoint"}, "without --init dnn")
    if args.init == "dnn" and (args.workers or 1) > 1:
        raise ParameterError(f"--init dnn starts every window from the network: --workers "
                             f"{args.workers} would change nothing; leave it out")
    check_flow_out(args.out)
    if args.time_aware in (None, "none"):
        reject_unused(args, {"--time-bins": "time_bins"}, "without --time-aware")
    if args.finest_level is not None:
        if args.scales is None:
            args.scales = min(5, args.finest_level)
        elif args.scales > args.finest_level:
            raise ParameterError(f"--scales {args.scales} needs --finest-level >= {args.scales} "
                                 f"(got {args.finest_level}): the scales end at the finest")
    if args.resume and args.video:
        raise ParameterError(f"--video {args.video} needs every window's flow: it cannot "
                             "be made with --resume; run without --resume")
    if args.resume and (args.workers or 1) > 1:
        raise ParameterError(f"--resume needs --workers 1 (got {args.workers}): with several "
                             "workers each chunk of windows starts from zero flow")
    if args.scheduler is not None:
        for given, why in ((args.resume, "--resume continues a run in this process"),
                           (args.init == "dnn", "--init dnn runs the network in this process")):
            if given:
                raise ParameterError(f"--scheduler {args.scheduler} does not apply: {why}")
        # the chunks: --workers if given, else the cluster's worker threads (run())
        args.scheduler_chunks = args.workers


def _check_space(out: Path, windows, sensor_size) -> None:
    h, w = sensor_size
    kind = out.suffix.lower()
    if kind == ".npz":  # flow and masks spooled, then stored: twice at the end
        check_free_space(out, 2 * len(windows) * h * w * 9, "--out",
                         f"{len(windows)} windows of {w} x {h} px flow and masks")
    elif kind == ".flo":
        check_free_space(out, len(windows) * (12 + h * w * 8), "--out",
                         f"{len(windows)} .flo files of {w} x {h} px")


def run(args) -> int:
    from evmotion.cli import print_json
    from evmotion.cli.calib import read_for_windows
    from evmotion.cli.options import note_parallel_interrupt
    from evmotion.events import fingerprint
    from evmotion.utils import progress

    out = Path(args.out)
    t_start = time.perf_counter()
    if args.video:
        from evmotion.viz.video import require_video

        require_video()  # before the windows are computed and written, not after
    if args.method == "dnn" or getattr(args, "init", None) == "dnn":
        from evmotion.cli.flow_dnn import check_network

        check_network(args)
    # (a window count the user asked for: a file holding fewer events is said)
    args.window_events_given = args.window_events is not None
    if args.window_events is None and args.window_us is None and not args.window_gt:
        args.window_events = default_window_events(args.file, args.format,
                                                    args.sensor_size)
    events, cam, grid = read_for_windows(args, **({} if args.window_gt else _cut(args)),
                                         min_events=MIN_WINDOW_EVENTS)
    windows = _windows(args, events)
    check_flow_out(out, len(windows))
    _check_space(out, windows, events.sensor_size)
    if args.method == "dnn":
        from evmotion.cli.flow_dnn import estimator

        estimate, attrs = estimator(args)
        attrs["remove_hot_pixels"] = bool(args.remove_hot_pixels)
        workers = 1
    else:
        note_parallel_interrupt(args, "window")
        # imported here: --method dnn (which runs through this runner) needs none of it
        from evmotion.methods.multicm import estimate_flow

        kwargs = dict(time_aware=None if args.time_aware == "none" else args.time_aware,
                      n_scales=args.scales, finest_level=args.finest_level,
                      objective=args.objective, lam=args.lam,
                      n_bins=args.time_bins, max_iter=args.max_iter, tol=args.tol,
                      seed=args.seed)
        attrs = {"method": "multicm", "time_aware": args.time_aware,
                 "objective": args.objective, "lambda": args.lam, "scales": args.scales,
                 # auto: each window's own (its meta), from its event count
                 "finest_level": "auto" if args.finest_level is None else args.finest_level,
                 "max_iter": args.max_iter, "tol": args.tol, "seed": args.seed,
                 "init": args.init, "source": str(args.file),
                 "remove_hot_pixels": bool(args.remove_hot_pixels)}
        if args.time_bins is not None:
            attrs["time_bins"] = args.time_bins
        if args.init == "dnn":
            from evmotion.methods.dnn.infer import checkpoint_digest, resolve_backend

            kwargs.update(init="dnn", checkpoint=args.checkpoint, device=args.device,
                          threads=args.threads)
            attrs["checkpoint"] = str(args.checkpoint or "shipped")
            attrs["checkpoint_sha1"] = checkpoint_digest(
                args.checkpoint, resolve_backend("auto", args.device, args.checkpoint))

            def estimate(ev, init):
                return estimate_flow(ev, **kwargs)
        else:
            def estimate(ev, init):
                return estimate_flow(ev, init=init, **kwargs)
        workers = args.workers
    attrs["grid"] = grid
    # what --resume must find unchanged beside the options: the distortion removed (the
    # grid names K only) and the events themselves
    if cam is not None and grid.startswith("undistorted"):
        attrs["distortion"] = [float(v) for v in cam.dist]
    # of the first window's events: the same whether the run read the whole recording or
    # only what its --max-windows need, so that a resume may ask for more windows
    attrs["source_events"] = ("the first window's "
                              + fingerprint(events[windows[0].start:windows[0].stop]))
    png_dir = Path(args.png_dir) if args.png_dir else None
    if png_dir is not None and not args.resume:
        remove_stale_pictures(png_dir, ("flow_", "flow_masked_", "iwe_tmid_",
                                        "iwe_identity_"))
    video = [] if args.video else None

    def after(i, r) -> None:
        """Pictures of window ``i``, and its flow kept for the video (``r`` None: a
        skipped window, no picture and nothing valid in the video)."""
        if r is None:
            if video is not None:
                h, w = events.sensor_size
                video.append((np.zeros((h, w, 2), np.float32), np.zeros((h, w), bool)))
            return
        if png_dir is not None:
            _png(png_dir, i, r, args.max_speed)
        if video is not None:
            video.append((r.flow, _valid(r)))

    results = None
    scheduler = getattr(args, "scheduler", None)
    with contextlib.ExitStack() as stack:
        if scheduler is not None:
            results = _estimate_parallel(events, windows, kwargs, args.scheduler_chunks, stack,
                                         keep_iwes=png_dir is not None, scheduler=scheduler,
                                         on_empty="skip" if len(windows) > 1 else "raise")
        elif workers > 1:
            results = _estimate_parallel(events, windows, kwargs, workers, stack,
                                         keep_iwes=png_dir is not None,
                                         on_empty="skip" if len(windows) > 1 else "raise")
        rows, written = _run_windows(args, events, windows, attrs, after, progress,
                                     estimate=estimate, results=results)
    args.flow_summary = {"windows": len(rows), "outputs": written,
                         "skipped": sum("skipped" in r for r in rows),
                         "resumed": sum(bool(r.get("resumed")) for r in rows),
                         "events": sum(w.count for w in windows),
                         "undistorted": _moved(cam, grid)}
    if video is not None:
        from evmotion.viz import write_flow_video

        write_flow_video(args.video, events, windows, [f for f, _ in video],
                         valids=[v for _, v in video], max_speed=args.max_speed)
    if args.json:
        print_json({
            "method": args.method, "outputs": written,
            # a network has no time-aware transport to name
            **({} if args.method == "dnn" else {"time_aware": args.time_aware}),
            "n_windows": len(rows), "sensor_size": list(events.sensor_size), "grid": grid,
            "windows": rows, "seconds": time.perf_counter() - t_start,
        })
    return 0


#: The extra dataset of a flow .h5 output holding each window's :func:`~evmotion.events.
#: events_digest`.
WINDOW_DIGEST = "window/events_digest"
WINDOW_DIGEST_MEANING = ("the first 8 bytes of the SHA-1 of the window's events (x, y, t, "
                         "p), as a signed integer: what a resumed run checks its kept "
                         "windows against")


class _PoorFitLines:
    """The poor-fit warnings of a run's windows (no focus, too few events): each line names
    its window, the first :data:`POOR_FIT_LINES` are printed and the others counted in one
    closing line (a recording of noise said 'no focus' once per window, hundreds of
    lines); other warnings pass unchanged."""

    def __init__(self, n_windows: int):
        self.n_windows = n_windows
        self.shown = self.held = self.held_valid = 0

    @contextlib.contextmanager
    def window(self, i: int, w):
        import warnings

        from evmotion.cli import warn_line
        from evmotion.errors import PoorFitWarning

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            yield
        for m in caught:
            if not issubclass(m.category, PoorFitWarning) or self.n_windows == 1:
                warnings.warn_explicit(m.message, m.category, m.filename, m.lineno)
            elif self.shown < POOR_FIT_LINES:
                self.shown += 1
                warn_line(f"window {i} [{w.t0}, {w.t1}) us: {m.message}")
            else:
                self.held += 1
                # a small motion's flow stays valid (biased), the others' is not valid
                self.held_valid += str(m.message).startswith("small motion")

    def close(self) -> None:
        if self.held:
            from evmotion.cli import warn_line

            marked = ("their flow stays valid, biased" if self.held_valid == self.held else
                      "their flow is marked not valid" if not self.held_valid else
                      f"{self.held_valid} of small motion keep their flow valid, biased, the "
                      "others' is marked not valid")
            warn_line(f"... and {self.held} more such warning{'s' if self.held > 1 else ''} "
                      f"of other windows ({marked}; --json lists each window's numbers)"
                      + (SHORT_WINDOWS_HINT if 2 * (self.shown + self.held) >= self.n_windows
                         else ""))



def _run_windows(args, events, windows, attrs, after, progress, *, estimate, results=None):
    """Every window into the output, in order: its result taken from ``results`` (worker
    processes, in window order) or made by ``estimate(events, init)`` warm-started from the
    previous window's. With ``--resume`` (one process) the windows already in the ``.part``
    file are taken from it (the last one as warm start, as stored: float32, exactly the flow
    that was written)."""
    from evmotion.events import events_digest
    from evmotion.io.flowfiles import ExtraSpec
    from evmotion.io.flowout import flow_container, open_flow_output
    from evmotion.methods.flowresult import estimate_or_skip

    # each window's events' digest, in a resumable output: a resume checks every window it
    # keeps, not only the recording's first (probe BH: a file changed after its first
    # window resumed, and its flow matched neither recording)
    keyed = flow_container(args.out) == "h5"
    extras = {WINDOW_DIGEST: ExtraSpec((), "<i8", "", WINDOW_DIGEST_MEANING)} if keyed \
        else None

    def digest(w) -> dict | None:
        return {WINDOW_DIGEST: events_digest(events.window(w))} if keyed else None

    todo = None
    said = _PoorFitLines(len(windows))
    if results is not None:
        # the worker processes fork at the first result: before the output is open, so
        # that none holds the file (and its HDF5 lock) after this run has closed it
        it = iter(results)
        try:
            with said.window(0, windows[0]):
                head = [next(it)]
        except StopIteration:
            head = []
        except BaseException:
            if hasattr(it, "close"):
                it.close()
            raise
        todo = itertools.chain(head, it)
    rows, init, held = [], None, []

    def flush(pending: list) -> None:
        for r, rw in pending:
            sink.append(r.flow, rw.t0, rw.t1, valid=_valid(r), extras=digest(rw))
        pending.clear()
    bar = None
    # opened just before the block that aborts it: a Ctrl-C while the progress bar was
    # made left a finished output reopened for --resume under OUT.part (probe BH)
    sink = open_flow_output(args.out, events.sensor_size, attrs, resume=args.resume,
                            n_windows=len(windows), extras=extras)
    try:
        sink.check_count(len(windows))
        if todo is None:
            # the windows to compute: a resume's kept ones, taken at once, had counted in
            # the rate, and so made the ETA too short (probe BH)
            bar = progress(None, total=len(windows) - len(sink.done), desc=attrs["method"],
                           unit="win")
        for i, w in enumerate(windows):
            if i < len(sink.done):
                sink.check_done(i, w.t0, w.t1)
                if keyed and int(sink.stored(WINDOW_DIGEST, i)) != digest(w)[WINDOW_DIGEST]:
                    raise ParameterError(f"cannot resume (--resume): window {i} of "
                                         f"{sink.stored_at()} was made from other events "
                                         f"than this run's window {i} (the recording "
                                         "changed?); start again without --resume")
                if i == len(sink.done) - 1:
                    init = sink.stored_flow(i)  # only an .h5 output resumes
                rows.append({"t0_us": w.t0, "t1_us": w.t1, "resumed": True})
                continue
            try:
                with said.window(i, w):
                    res = (next(todo) if todo is not None else estimate_or_skip(
                        lambda ev, i0=init: estimate(ev, i0), events, w,
                        "skip" if len(windows) > 1 else "raise"))
            except EmptyWindowError as exc:
                # which window of the recording (all its events at one time, say)
                raise EmptyWindowError(f"{args.file}: window {i} [{w.t0}, {w.t1}) us: "
                                       f"{exc}") from None
            if bar is not None:
                bar.update(1)
            # skipped windows are written once a window is estimated: a run of nothing
            # else writes nothing
            held.append((res, w))
            if "skipped" in res.meta:
                rows.append({"t0_us": w.t0, "t1_us": w.t1, "n_events": res.n_events,
                             "skipped": res.meta["skipped"], "valid_fraction": 0.0})
                after(i, None)
                continue
            # drawn before it is written: a window kept for --resume has its pictures (an
            # interrupt between the two had left kept windows without theirs, probe BH)
            after(i, res)
            flush(held)
            init = res
            rows.append(_row(res, w))
        if rows and all("skipped" in r for r in rows):
            raise EmptyWindowError(f"{args.file}: no window could be estimated (the first: "
                                   f"{rows[0]['skipped']})")
        flush(held)
        written = [str(p) for p in sink.close()]
        said.close()
    except BaseException:
        sink.abort()
        if results is not None and hasattr(it, "close"):
            it.close()  # ends the worker pool (or the cluster's tasks' feed) now
        raise
    finally:
        if bar is not None:
            bar.close()
    return rows, written
