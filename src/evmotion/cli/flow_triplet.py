"""``evmotion flow FILE --method triplet``: event-by-event triplet-matching flow (ch. 5).

Streams the recording in chunks through
:class:`~evmotion.methods.triplet_stream.TripletStream`, so memory does not grow with the file.
By default the output is per event (:mod:`evmotion.io.eventflow`: ``t, x, y, p, vx, vy, nx,
ny, valid, n_triplets``, px/s and µs; ``.h5`` Blosc-LZ4 or ``.npz``). Dense per-window
fields (voxelized, non-zero averaged, collapsed; px/s) are computed only where asked:
``--dense``, a window option (``--window-us``/``--window-events``/``--window-gt``),
``--bins`` or ``--filter-size`` with an ``.h5`` output (the evmotion flow HDF5, Blosc-LZ4,
``valid`` = pixels with a value), and always for the per-window containers ``.flo`` and
``.png`` (displacement, a pattern such as ``flow_{:05d}.flo`` for several windows), all
written through :func:`evmotion.io.flowout.open_flow_output`; ``--png-dir`` draws the
windows of any output. ``--dense lsq`` and ``--dense robust`` replace
the thesis' voxel mean by the normal-flow fits of
:func:`~evmotion.methods.triplet.estimate_flow_triplet`; with ``robust`` the dense windows
(and their IWE pictures) are those of the stream of burst means
(:class:`~evmotion.methods.bursts.BurstMeans`), which runs at least ``--gap-ms`` behind.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from evmotion.cli.options import (
    empty_selection,
    finite_float,
    int_range,
    nonnegative_float,
    positive_float,
    positive_int,
    reject_unused,
    remove_stale_pictures,
)
from evmotion.errors import ParameterError

# the options only this method reads: attribute and default (see evmotion.cli.flow);
# None defaults are resolved by dense_defaults / default_ridge for the chosen --dense
OPTIONS: dict[str, tuple[str, object]] = {
    "--dx": ("dx", None),
    "--dt-ms": ("dt_ms", 100.0),
    "--tau-ms": ("tau_ms", None),
    "--quadruple": ("quadruple", False),
    "--bins": ("bins", 1),
    "--dense": ("dense", "mean"),
    "--filter-size": ("filter_size", None),
    "--ridge": ("ridge", None),
    "--gap-ms": ("gap_ms", 4.0),
    "--chunk-events": ("chunk_events", 1_000_000),
    "--depth": ("depth", 8),
}
# options of the dense output, which a .npz output without --png-dir does not make
# the recording's first events, whose fingerprint (source_events) a resume checks
FINGERPRINT_EVENTS = 4096
DENSE_OPTIONS = ("--bins", "--dense", "--filter-size", "--ridge", "--gap-ms")
# options that ask an .h5 output for dense windows instead of the per-event flow
DENSE_ASKS = ("dense", "window_us", "window_events", "window_gt", "bins", "filter_size")


def add_arguments(group) -> None:
    group.add_argument("--dx", type=positive_float(unit="px"), default=None,
                       help="neighbourhood radius d_x in px (default sqrt(2), the thesis'; "
                            "2.3 with --dense lsq/robust)")
    # (the kernels' clock holds dt + tau below 179 s; tau 0 admits triplets of one instant)
    group.add_argument("--dt-ms", type=finite_float(0.001, 100_000, unit="ms"), default=None,
                       help="delay window d_t in ms (default 100)")
    group.add_argument("--tau-ms", type=finite_float(0.001, 10_000, unit="ms"), default=None,
                       help="refractory period tau in ms (default 3, the thesis'; 1 with "
                            "--dense lsq/robust)")
    group.add_argument("--quadruple", action="store_true", default=None,
                       help="match 4 aligned events instead of 3 (§5.3.5)")
    group.add_argument("--bins", type=int_range(1, 1000), default=None,
                       help="time bins per window of the dense output (default 1; windows "
                            "default to 50 ms); "
                            ".npz is per event")
    group.add_argument("--dense", choices=("mean", "lsq", "robust"), default=None,
                       help="dense windows instead of the per-event output (the default): "
                            "'mean' of the per-event flow (thesis), "
                            "'lsq', the least-squares fit of the events' normal flows, or "
                            "'robust', a re-weighted fit of the normal flows of burst means "
                            "(extensions; 'robust' is the most accurate)")
    group.add_argument("--filter-size", type=int_range(1, 1001), default=None,
                       help="odd width of the non-zero average filter of the dense output "
                            "(default 3, the thesis'; larger odd sizes are an extension), or "
                            "of the --dense lsq/robust neighbourhood (default 15/41)")
    group.add_argument("--ridge", type=nonnegative_float(), default=None,
                       help="--dense lsq/robust: Tikhonov weight relative to the mean "
                            "eigenvalue (default 0.01/0.001)")
    group.add_argument("--gap-ms", type=finite_float(0.001, unit="ms"), default=None,
                       help="--dense robust: a pixel silent for longer than this ends its "
                            "burst (default 4)")
    group.add_argument("--chunk-events", type=positive_int(), default=None,
                       help="events read at a time (default 1e6); the matcher takes them "
                            "in multiples of 30,000, the stretches its flicker and noise "
                            "tests judge, so the flow is the same whatever this is")
    group.add_argument("--depth", type=int_range(1, 255), default=None,
                       help="timestamps remembered per pixel and polarity, 1 to 255 "
                            "(default 8)")


def check_args(args) -> None:
    """Options that the chosen output and --dense do not read are errors."""
    kind = Path(args.out).suffix.lower()
    if kind == ".npy":
        raise ParameterError(f"--out {args.out}: a bare .npy holds no times, units or validity; "
                             "write .npz (per event) or .h5 (per event, or dense windows)")
    given = {flag: attr for flag, (attr, _) in OPTIONS.items()}
    reject_unused(args, {"--checkpoint": "checkpoint"}, "with --method triplet (a network's)")
    if kind == ".npz" and not args.png_dir:
        # "dense windows only with --png-dir" read as if --png-dir put them in the .npz,
        # which stays per event: say where dense windows are written (probe)
        where = ("--out .h5, .flo or .png hold dense windows; --png-dir would only draw "
                 "them as pictures")
        reject_unused(args, {f: given[f] for f in DENSE_OPTIONS},
                      f"to a .npz output, which holds per-event flow ({where})")
        reject_unused(args, {"--window-events": "window_events", "--window-us": "window_us",
                             "--window-gt": "window_gt"},
                      f"to a .npz output, which holds per-event flow ({where})")
    args.dense_output = kind in (".flo", ".png") or (
        kind in (".h5", ".hdf5") and any(getattr(args, a, None) is not None for a in DENSE_ASKS))
    if args.dense_output:
        from evmotion.cli.options import check_flow_out

        check_flow_out(args.out)
    if args.resume and not args.dense_output:
        raise ParameterError(f"--resume continues a dense .h5 output (--dense or a window "
                             f"option); the per-event --out {args.out} is written whole")
    dense = args.dense or "mean"
    if dense != "robust":
        reject_unused(args, {"--gap-ms": "gap_ms"}, f"with --dense {dense} (robust only)")
    if dense == "mean":
        reject_unused(args, {"--ridge": "ridge"}, "with --dense mean (lsq/robust only)")
    if args.filter_size is not None and args.filter_size % 2 == 0:
        raise ParameterError(f"--filter-size must be odd, got {args.filter_size}")
    if args.resume and args.png_dir:
        raise ParameterError("--resume does not redraw the --png-dir pictures of the windows "
                             "already done; leave out --png-dir or --resume")


def run(args) -> int:
    import evmotion.io as eio
    from evmotion.cli import print_json, warn_line
    from evmotion.cli.calib import undistorted_chunks
    from evmotion.cli.flow_multicm import ONE_FILE_WINDOWS
    from evmotion.cli.options import header_event_count, read_kwargs
    from evmotion.events import fingerprint
    from evmotion.io.flowout import PER_WINDOW, check_flow_output, flow_container, is_pattern
    from evmotion.jitcache import compile_seconds
    from evmotion.methods.bursts import MAX_GAP_US
    from evmotion.methods.triplet import MAX_DX, default_ridge, dense_defaults
    from evmotion.methods.triplet_stream import TripletStream, stream_chunks
    from evmotion.utils import progress, refine_total

    if args.video:
        raise ParameterError(f"--video {args.video}: written by --method multicm and dnn "
                             "only (triplet's flow is per event)")
    # (bounds of the library's, said with the option's name before any reading)
    if args.dx is not None and args.dx > MAX_DX:
        raise ParameterError(f"--dx must be at most {MAX_DX:g} px (larger neighbourhoods "
                             f"match unrelated edges at hundreds of times the cost), got "
                             f"{args.dx:g}")
    if args.gap_ms is not None and args.gap_ms * 1000 > MAX_GAP_US:
        raise ParameterError(f"--gap-ms must be at most {MAX_GAP_US / 1000:g} ms (an hour), "
                             f"got {args.gap_ms:g}")
    out = Path(args.out)
    png_dir = Path(args.png_dir) if args.png_dir else None
    if png_dir is not None and not args.resume:
        remove_stale_pictures(png_dir, ("flow_", "iwe_"))
    tau_us = None if args.tau_ms is None else int(round(args.tau_ms * 1000))
    args.dx, tau_us, args.filter_size = dense_defaults(args.dense, args.dx, tau_us,
                                                       args.filter_size)
    args.tau_ms = tau_us / 1000
    args.ridge = default_ridge(args.dense, args.ridge)
    gap_us = int(round(args.gap_ms * 1000))
    windows_made = args.dense_output or png_dir is not None
    chunks, grid = undistorted_chunks(
        args, eio.iter_events(args.file, chunk_events=args.chunk_events,
                              t0=getattr(args, "t0", None), t1=getattr(args, "t1", None),
                              **read_kwargs(args)))
    # fed in chunks of a multiple of the stretches its flicker and noise tests judge: the
    # same stretches whatever --chunk-events (under 2,000 events none was tested, and the
    # fingerprint took the first chunk's events, probe DK)
    chunks = stream_chunks(chunks, args.chunk_events)
    first = next(chunks, None)
    if first is None:
        if getattr(args, "t0", None) is not None or getattr(args, "t1", None) is not None:
            # the error path only: the recording's own span, for the message
            info = eio.describe(args.file, **read_kwargs(args))
            if info.get("t_first_us") is not None:
                raise empty_selection(args, args.file, int(info["t_first_us"]),
                                      int(info["t_last_us"]), "no events")
        raise ParameterError(f"{args.file}: no events")
    sensor = first.sensor_size
    params = {"dx": args.dx, "dt_ms": args.dt_ms, "tau_ms": args.tau_ms,
              "quadruple": args.quadruple, "depth": args.depth}
    if windows_made:
        params.update(bins=args.bins, dense=args.dense, filter_size=args.filter_size,
                      ridge=args.ridge)
        if args.dense == "robust":
            params["gap_ms"] = gap_us / 1000
        if args.window_us is not None:
            params["window_us"] = args.window_us
        if args.window_events is not None:
            params["window_events"] = args.window_events

    def stream(skip: int = 0) -> TripletStream:
        return TripletStream(
            sensor, dense=args.dense if windows_made else None, window_us=args.window_us,
            window_events=args.window_events, windows=_gt_edges(args), n_bins=args.bins,
            filter_size=args.filter_size, ridge=args.ridge, gap_us=gap_us, dx=args.dx,
            dt_us=int(round(args.dt_ms * 1000)), tau_us=tau_us, quadruple=args.quadruple,
            depth=args.depth, with_iwe=png_dir is not None, skip=skip)

    total = header_event_count(args.file, getattr(args, "format", None),
                               getattr(args, "t0", None), getattr(args, "t1", None))
    one_file = (args.dense_output and not is_pattern(out)
                and flow_container(out) in PER_WINDOW)
    if one_file and args.window_events is not None and total is not None \
            and total >= ONE_FILE_WINDOWS * args.window_events:
        check_flow_output(out, -(-total // args.window_events))  # refused before the work
    if one_file and args.window_events is not None and total is not None \
            and args.window_events < total < 2 * args.window_events:
        # one count window and a remainder in a single .flo / .png: one window of all the
        # events, as multicm's (it was refused, probe AV)
        warn_line(f"{args.file} holds {total:,} events, one window of --window-events "
                  f"{args.window_events} and {total - args.window_events:,} more: "
                  f"{out.name} holds one window, so all {total:,} are estimated as one")
        args.window_events = total
    tri = stream()
    attrs = {"method": "triplet", "source": str(args.file), "grid": grid,
             # its first events (as many whatever --chunk-events), read before anything
             # named as what it is (read as the file's count, "4096 events", probe BX)
             "source_events": "the first " + fingerprint(first[:FINGERPRINT_EVENTS]),
             **{f"triplet_{k}": v for k, v in params.items()}}
    whole = getattr(args, "t0", None) is None and getattr(args, "t1", None) is None
    bar = progress(iter(()), desc="triplet", unit="ev", unit_scale=True, total=total)
    n_events = n_valid = n_trip = n_windows = 0
    t_first = t_last = int(first.t[0])
    wall0 = time.perf_counter()
    c0 = compile_seconds()

    no_focus: list[int] = []
    early: list[int] = []

    left_out = 0
    # the dense output's valid pixels of the windows written (those of a resumed run's
    # earlier windows are in the file: not counted)
    valid_px = all_px = 0

    def emit(wins) -> None:
        nonlocal n_windows, left_out, valid_px, all_px
        for win in wins:
            if one_file and n_windows == 1:
                left_out += 1  # a single file holds the first window (said at the end)
                continue
            _emit(win, dense_out, png_dir, args.max_speed)
            n_windows += 1
            if win.flow is not None:  # (its valid mask is set with it)
                valid_px += int(np.count_nonzero(win.valid))
                all_px += win.valid.size
            if win.no_focus:
                no_focus.append(win.index)
            if win.early and win.flow is not None:
                early.append(win.index)

    # the outputs come last: nothing that can refuse the options runs after one exists,
    # and the block that aborts them follows at once (a Ctrl-C between them left a
    # finished output reopened for --resume under OUT.part, probe BH)
    events_out = dense_out = None
    try:
        if not args.dense_output:
            from evmotion.io.eventflow import EventFlowWriter

            events_out = EventFlowWriter(out, sensor, attrs=attrs)
        else:
            from evmotion.io.flowout import open_flow_output

            dense_out = open_flow_output(out, sensor, attrs, resume=args.resume,
                                         compression="lz4")
    except BaseException:
        bar.close()
        raise
    try:
        if getattr(dense_out, "done", None):
            tri = stream(skip=len(dense_out.done))
        chunk = first
        while chunk is not None:
            flow = tri.process(chunk)
            n_events += len(chunk)
            n_valid += int(flow.valid.sum())
            n_trip += int(flow.n_triplets.sum(dtype=np.int64))
            if len(chunk):
                t_last = int(chunk.t[-1])
            if events_out is not None:
                events_out.append(t=chunk.t, x=chunk.x, y=chunk.y, p=chunk.p, vx=flow.vx,
                                  vy=flow.vy, nx=flow.nx, ny=flow.ny, valid=flow.valid,
                                  n_triplets=flow.n_triplets)
            emit(tri.windows())
            bar.update(len(chunk))
            if total is None and whole:
                # no count in the header (EVT RAW): the share of the file read says it
                refine_total(bar, n_events, chunk.meta)
            chunk = next(chunks, None)
        tri.finish()
        last = tri.windows()
        if args.window_events is None and not getattr(args, "window_gt", None):
            # the last time window ends with the data, as multicm's does: its nominal end
            # lay past the recording, beyond any ground truth of it, and eval dropped it
            # (probe Z)
            last = (dataclasses.replace(w, t1=min(w.t1, t_last + 1)) for w in last)
        emit(last)
        outputs = [str(out)]
        if dense_out is not None:
            dense_out.check_count(n_windows)
            outputs = [str(p) for p in dense_out.close() or [out]]
        if events_out is not None:
            events_out.close()
    except BaseException:
        for sink in (events_out, dense_out):
            if sink is not None:
                sink.abort()
        raise
    finally:
        bar.close()
    if left_out:
        warn_line(f"{args.file}: {n_windows + left_out} windows; {out.name} holds the first, "
                  f"{left_out} more {'was' if left_out == 1 else 'were'} not written: a "
                  f"pattern ({out.stem}_{{:05d}}"
                  f"{out.suffix}) or .h5 output holds them all")
    wall = time.perf_counter() - wall0
    # numba's first-use compilation is not the matcher's speed: reported apart
    compiled = compile_seconds() - c0
    run_s = wall - compiled
    if no_focus:
        from evmotion.methods.measured import MIN_CONTRAST_GAIN

        warn_line(f"{args.file}: {len(no_focus)} of {n_windows} windows (first: "
                  f"{no_focus[0]}) have no focus: their dense flow aligns their events less "
                  f"than {100 * (MIN_CONTRAST_GAIN - 1):.0f} % better than chance, or does "
                  "not carry each window's first half onto its second (noise or no "
                  "texture); no pixel of them is valid")
    if early:
        warn_line(f"{args.file}: {len(early)} of {n_windows} windows (first: {early[0]}) "
                  "hold events whose slow steps' triplets cannot be found (their partners lie "
                  "before the recording, or past its end too where --dense lsq/robust read "
                  "it backwards) and move that slowly: their flow is biased; a "
                  "longer recording, or a shorter --dt-ms for fast motion, avoids it")
    if tri.lit_events:
        warn_line(f"{args.file}: {tri.lit_events:,} of {n_events:,} events "
                  f"({100 * tri.lit_events / max(n_events, 1):.0f} %) come in stretches lit "
                  "rather than moved (bursts of one polarity: flickering light or a lighting "
                  "change): they get no flow (not valid)")
    if tri.unaligned_events:
        warn_line(f"{args.file}: {tri.unaligned_events:,} of {n_events:,} events "
                  f"({100 * tri.unaligned_events / max(n_events, 1):.0f} %) got a flow that "
                  "does not carry their stretch's first half onto its second (noise, or "
                  "no motion the triplets follow): they get no flow (not valid)")
    # (events whose flow the noise test took had triplets: not what this is about)
    if n_events >= NO_FLOW_MIN_EVENTS and \
            n_valid + tri.unaligned_events < NO_FLOW_SHARE * n_events:
        # (0 % valid on a 5.5 ms ECD window moving ~1000 px/s, without a word: a triplet's
        # steps are at least tau apart, so a motion of over dx / tau px/s finds none; probe CF)
        m = tri.matcher
        warn_line(f"{args.file}: {n_valid:,} of {n_events:,} events "
                  f"({100 * n_valid / n_events:.1f} %) got a flow: a triplet needs steps of "
                  f"{m.dx:.3g} px at least tau = {m.tau_us / 1e3:g} ms apart within d_t = "
                  f"{m.dt_us / 1e3:g} ms, so a motion faster than "
                  f"{m.dx / (m.tau_us * 1e-6):.0f} px/s finds none (a shorter --tau-ms), "
                  f"nor one slower than {m.dx / (m.dt_us * 1e-6):.3g} px/s (a longer "
                  "--dt-ms) or than two steps in the recording's time")
    if tri.overflow > OVERFLOW_NOTE * max(n_events, 1):
        warn_line(f"{args.file}: {tri.overflow:,} of {n_events:,} events "
                  f"({100 * tri.overflow / n_events:.0f} %) fired more than --depth "
                  f"{tri.matcher.depth} times within 2 (d_t + tau) at their pixel: the oldest "
                  "of those timestamps were forgotten, so their matches differ from "
                  "Algorithm 1's (a larger --depth keeps them, or a shorter --dt-ms)")
    # (a resumed run did not say how much it had reused, as multicm and bos do; probe BP)
    args.flow_summary = {"windows": n_windows if windows_made else None, "events": n_events,
                         "outputs": outputs,
                         "resumed": len(getattr(dense_out, "done", None) or ())}
    if args.json:
        print_json({
            "method": "triplet", "file": str(args.file), "out": str(out),
            "output": "dense windows" if args.dense_output else "per event",
            "sensor_size": list(sensor), "grid": grid,  # [H, W], as multicm and dnn
            "events": n_events, "duration_s": (t_last - t_first) * 1e-6,
            # what the output holds, as info and multicm give it: its pixels in a dense
            # output (the events' share had been given there, 0.207 beside a file whose
            # only window, without focus, has no valid pixel; probe DA)
            "valid_fraction": ((valid_px / all_px if all_px else None)
                               if args.dense_output else n_valid / max(n_events, 1)),
            "event_flow_fraction": n_valid / max(n_events, 1),
            "mean_triplets": n_trip / max(n_events, 1),
            "windows": n_windows, "no_focus_windows": no_focus,
            "early_windows": early, "overflow": tri.overflow,
            "lit_events": tri.lit_events, "unaligned_events": tri.unaligned_events,
            "state_bytes": tri.matcher.state_nbytes,
            "wall_s": wall, "compile_s": compiled, "run_s": run_s,
            "events_per_s": n_events / run_s if run_s > 0 else None,
            "params": params,
            # the keys multicm and dnn write, for scripts that read any method's summary
            "outputs": [str(o) for o in outputs], "n_windows": n_windows, "seconds": wall,
        })
    return 0


#: Below this share of events with a flow (of at least this many events), the run says
#: why triplets may be missing.
NO_FLOW_SHARE = 0.01
NO_FLOW_MIN_EVENTS = 1000


def _gt_edges(args):
    """Windows ``[ts[k], ts[k + dt])`` µs every dt frames of --window-gt, or None."""
    if not getattr(args, "window_gt", None):
        return None
    from evmotion.io.flowfiles import read_gt_flow

    gt = read_gt_flow(args.window_gt)
    dt = int(args.gt_dt)
    ts = np.append(np.asarray(gt.t0, np.int64), np.asarray(gt.t1, np.int64)[-1:])
    if dt < 1 or ts.size < dt + 1:
        raise ParameterError(f"--gt-dt {dt}: need >= 1 and at most {ts.size - 1} frames")
    starts = ts[:-dt:dt]
    return list(zip(starts.tolist(), ts[dt::dt][: starts.size].tolist(), strict=True))


# above this share of the events overflowing the per-pixel rings, the run says so
OVERFLOW_NOTE = 0.05


def _emit(win, dense_out, png_dir, max_speed) -> None:
    """A finished window: checked against a resumed file, written, drawn."""
    if win.flow is None:
        dense_out.check_done(win.index, win.t0, win.t1)
        return
    if dense_out is not None:
        dense_out.append(win.flow, win.t0, win.t1, valid=win.valid)
    if png_dir is not None:
        from evmotion.utils import atomic_write_bytes
        from evmotion.viz import event_picture_png, save_flow_png

        png_dir.mkdir(parents=True, exist_ok=True)
        when = f"window {win.index}: {win.t0 * 1e-6:.4f}-{win.t1 * 1e-6:.4f} s"
        # a picture looked at alone must not pass for a measurement (the warped events of
        # a window without focus were titled as any other's, probe DA)
        verdict = (", NO FOCUS: not a measurement (no pixel valid)" if win.no_focus
                   else "")
        save_flow_png(png_dir / f"flow_{win.index:05d}.png", win.flow, max_speed=max_speed,
                      valid=win.valid, title=when)
        atomic_write_bytes(png_dir / f"iwe_{win.index:05d}.png", event_picture_png(
            win.iwe, title=f"{when}, events warped by their flow to the window's start"
                           f"{verdict}"))
