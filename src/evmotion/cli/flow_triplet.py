"""``evmotion flow FILE --method triplet``: event-by-event triplet-matching flow (ch. 5).

Streams the recording in chunks through :class:`~evmotion.methods.triplet.TripletMatcher`,
so memory does not grow with the file. Output by extension: ``.h5`` dense per-window
fields (voxelized, 3x3 non-zero averaged, collapsed; px/s; the evmotion flow HDF5 of
:class:`~evmotion.io.flowfiles.FlowWriter`, ``valid`` = pixels with a value), ``.npy`` the
same fields as one ``(N, H, W, 2)`` float32 array in px/s, ``.flo`` Middlebury displacement
over each window (``name_0000.flo``... when there are several windows), ``.npz`` sparse
per-event flow (``t, x, y, p, vx, vy, nx, ny, valid, n_triplets``; ``nx, ny`` the normal
flow of :attr:`~evmotion.methods.triplet.TripletFlow.nx`). ``--dense lsq`` and ``--dense
robust`` replace the thesis' voxel mean by the normal-flow fits of
:func:`~evmotion.methods.triplet.estimate_flow_triplet`; with ``robust`` the dense windows
(and their IWE pictures) are those of the stream of burst means
(:class:`~evmotion.methods.bursts.BurstMeans`), which runs at least ``--gap-ms`` behind.
"""

from __future__ import annotations

import time
import zipfile
from pathlib import Path

import numpy as np

from evmotion.cli.options import (
    finite_float,
    int_range,
    nonnegative_float,
    positive_float,
    positive_int,
    reject_unused,
)
from evmotion.errors import ParameterError

DEFAULT_WINDOW_US = 50_000


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
DENSE_OPTIONS = ("--bins", "--dense", "--filter-size", "--ridge", "--gap-ms")


def add_arguments(group) -> None:
    group.add_argument("--dx", type=positive_float(unit="px"), default=None,
                       help="neighbourhood radius d_x in px (default sqrt(2), the thesis'; "
                            "2.3 with --dense lsq/robust)")
    group.add_argument("--dt-ms", type=positive_float(unit="ms"), default=None,
                       help="delay window d_t in ms (default 100)")
    group.add_argument("--tau-ms", type=nonnegative_float(unit="ms"), default=None,
                       help="refractory period tau in ms (default 3, the thesis'; 1 with "
                            "--dense lsq/robust)")
    group.add_argument("--quadruple", action="store_true", default=None,
                       help="match 4 aligned events instead of 3 (§5.3.5)")
    group.add_argument("--bins", type=int_range(1, 1000), default=None,
                       help="time bins per window of the dense .h5 output (default 1; windows "
                            f"default to {DEFAULT_WINDOW_US // 1000} ms); .npz is per event")
    group.add_argument("--dense", choices=("mean", "lsq", "robust"), default=None,
                       help="dense output: 'mean' of the per-event flow (thesis, default), "
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
                       help="events read and processed at a time (default 1e6)")
    group.add_argument("--depth", type=int_range(1, 255), default=None,
                       help="timestamps remembered per pixel and polarity, 1 to 255 "
                            "(default 8)")


def check_args(args) -> None:
    """Options that the chosen output and --dense do not read are errors."""
    kind = Path(args.out).suffix.lower()
    given = {flag: attr for flag, (attr, _) in OPTIONS.items()}
    reject_unused(args, {"--checkpoint": "checkpoint"}, "with --method triplet (a network's)")
    if kind == ".npz" and not args.png_dir:
        reject_unused(args, {f: given[f] for f in DENSE_OPTIONS},
                      "to a .npz output (per event; dense windows only with --png-dir)")
        reject_unused(args, {"--window-events": "window_events", "--window-us": "window_us",
                             "--window-gt": "window_gt"},
                      "to a .npz output (per event; windows only with --png-dir)")
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
    from evmotion.cli import print_json
    from evmotion.cli.calib import undistorted_chunks
    from evmotion.jitcache import compile_seconds
    from evmotion.methods.bursts import BurstMeans
    from evmotion.methods.triplet import (
        TripletMatcher,
        default_ridge,
        dense_defaults,
        max_normal_speed,
    )
    from evmotion.utils import progress

    if args.video:
        raise ParameterError(f"--video {args.video}: written by --method multicm only")
    out = Path(args.out)
    kind = out.suffix.lower()
    tau_us = None if args.tau_ms is None else int(round(args.tau_ms * 1000))
    args.dx, tau_us, args.filter_size = dense_defaults(args.dense, args.dx, tau_us,
                                                       args.filter_size)
    args.tau_ms = tau_us / 1000
    args.ridge = default_ridge(args.dense, args.ridge)
    gap_us = int(round(args.gap_ms * 1000))
    dense = kind != ".npz" or args.png_dir
    chunks, grid = undistorted_chunks(
        args, _iter_chunks(args.file, getattr(args, "format", None), args.chunk_events,
                           getattr(args, "t0", None), getattr(args, "t1", None)))
    first = next((c for c in chunks if len(c)), None)
    if first is None:
        raise ParameterError(f"{args.file}: no events")
    sensor = first.sensor_size
    matcher = TripletMatcher(sensor, args.dx, int(round(args.dt_ms * 1000)),
                             int(round(args.tau_ms * 1000)), quadruple=args.quadruple,
                             depth=args.depth)
    robust = args.dense == "robust" and dense
    if robust:
        bursts = BurstMeans(sensor, gap_us)
        burst_matcher = TripletMatcher(sensor, matcher.dx, matcher.dt_us, matcher.tau_us,
                                       quadruple=args.quadruple, depth=args.depth)
    params = {"dx": args.dx, "dt_ms": args.dt_ms, "tau_ms": args.tau_ms,
              "quadruple": args.quadruple, "bins": args.bins, "depth": args.depth,
              "dense": args.dense, "filter_size": args.filter_size, "ridge": args.ridge}
    if args.dense == "robust":
        params["gap_ms"] = gap_us / 1000
    if args.window_us is not None:
        params["window_us"] = args.window_us
    if args.window_events is not None:
        params["window_events"] = args.window_events
    windows = _Windows(sensor, args.bins, args.window_us, args.window_events,
                       int(first.t[0]), _gt_edges(args), filter_size=args.filter_size,
                       dense=args.dense, ridge=args.ridge,
                       vmax=max_normal_speed(matcher.dx, matcher.tau_us)) if dense else None
    # the sinks come last: nothing that can refuse the options runs after one exists
    if kind in (".h5", ".hdf5"):
        sink = _H5Sink(out, sensor, {"method": "triplet", "source": str(args.file), "grid": grid,
                                     **{f"triplet_{k}": v for k, v in params.items()}},
                       resume=args.resume)
        windows.skip = len(sink.done)
    elif kind == ".npz":
        sink = _NpzSink(out)
    elif kind == ".npy":
        sink = _NpySink(out, sensor)
    elif kind == ".flo":
        sink = _FloSink(out)
    png_dir = Path(args.png_dir) if args.png_dir else None
    bar = progress(iter(()), desc="triplet", unit="ev", unit_scale=True)
    n_events = n_valid = n_trip = 0
    t_first, t_last = int(first.t[0]), int(first.t[0])
    n_windows = 0
    wall0 = time.perf_counter()
    c0 = compile_seconds()

    def emit_all(wins) -> int:
        return sum(_emit(win, sink, png_dir, kind, args.max_speed) for win in wins)

    try:
        chunk = first
        while chunk is not None:
            flow = matcher.process(chunk)
            n_events += len(chunk)
            n_valid += int(flow.valid.sum())
            n_trip += int(flow.n_triplets.sum(dtype=np.int64))
            if len(chunk):
                t_last = int(chunk.t[-1])
            if kind == ".npz":
                sink.add(chunk, flow)
            if robust:
                b = bursts.process(chunk)
                n_windows += emit_all(windows.add(b, burst_matcher.process(b)))
            elif windows is not None:
                n_windows += emit_all(windows.add(chunk, flow))
            bar.update(len(chunk))
            chunk = next(chunks, None)
        if robust:
            b = bursts.flush()
            n_windows += emit_all(windows.add(b, burst_matcher.process(b)))
        if windows is not None:
            n_windows += emit_all(windows.finish())
        if kind in (".h5", ".hdf5"):
            sink.w.check_count(n_windows)
        sink.close()
    except BaseException:
        sink.abort()
        raise
    finally:
        bar.close()
    wall = time.perf_counter() - wall0
    args.flow_summary = {"windows": n_windows if dense else None, "events": n_events}
    # numba's first-use compilation is not the matcher's speed: reported apart
    compiled = compile_seconds() - c0
    run_s = wall - compiled
    if args.json:
        print_json({
            "method": "triplet", "file": str(args.file), "out": str(out),
            "sensor_size": {"height": sensor[0], "width": sensor[1]}, "grid": grid,
            "events": n_events, "duration_s": (t_last - t_first) * 1e-6,
            "valid_fraction": n_valid / max(n_events, 1),
            "mean_triplets": n_trip / max(n_events, 1),
            "windows": n_windows, "overflow": matcher.overflow,
            "state_bytes": matcher.state_nbytes,
            "wall_s": wall, "compile_s": compiled, "run_s": run_s,
            "events_per_s": n_events / run_s if run_s > 0 else None,
            "params": params,
        })
    return 0


def _iter_chunks(path, fmt, chunk_events, t0=None, t1=None):
    import evmotion.io as eio

    if hasattr(eio, "iter_events"):
        kw = {"format": fmt} if fmt else {}
        yield from eio.iter_events(path, chunk_events=chunk_events, t0=t0, t1=t1, **kw)
        return
    from evmotion.io.registry import resolve_format

    spec = resolve_format(path, fmt or None)
    if spec.iter_chunks is not None:
        yield from spec.iter_chunks(path, chunk_events)
        return
    # Formats without a streaming reader (e.g. MATLAB files) are read whole.
    ev = spec.read(path)
    for s in range(0, len(ev), chunk_events):
        yield ev[s:s + chunk_events]


def _gt_edges(args):
    """Window starts and ends (µs) from --window-gt: ``[ts[k], ts[k + dt])`` every dt frames."""
    if not getattr(args, "window_gt", None):
        return None
    from evmotion.io.flowfiles import read_gt_flow

    gt = read_gt_flow(args.window_gt)
    dt = int(args.gt_dt)
    ts = np.append(np.asarray(gt.t0, np.int64), np.asarray(gt.t1, np.int64)[-1:])
    if dt < 1 or ts.size < dt + 1:
        raise ParameterError(f"--gt-dt {dt}: need >= 1 and at most {ts.size - 1} frames")
    starts = ts[:-dt:dt]
    return starts, ts[dt::dt][: starts.size]


class _Window:
    """A finished dense window: collapsed flow (px/s), mask, IWE and its time span."""

    def __init__(self, index, t0, t1, flow, mask, iwe, n_events):
        self.index, self.t0, self.t1 = index, t0, t1
        self.flow, self.mask, self.iwe, self.n_events = flow, mask, iwe, n_events


class _Windows:
    """Accumulates per-event flow into voxel sums window by window (time or count windows),
    and the IWE of each window's events warped by their own flow to the window start."""

    def __init__(self, sensor, bins, window_us, window_events, t_start, edges=None, *,
                 filter_size=3, dense="mean", ridge=1e-2, vmax=np.inf):
        if bins < 1:
            raise ParameterError(f"--bins must be >= 1, got {bins}")
        if filter_size < 1 or filter_size % 2 == 0:
            raise ParameterError(f"--filter-size must be an odd number >= 1, got {filter_size}")
        self.filter_size = filter_size
        self.dense, self.ridge, self.vmax = dense, ridge, vmax
        # the first `skip` windows are in the resumed file: delimited, not computed
        self.skip = 0
        if window_us is not None and window_us <= 0:
            raise ParameterError(f"--window-us must be > 0, got {window_us}")
        if window_events is not None and window_events <= 0:
            raise ParameterError(f"--window-events must be > 0, got {window_events}")
        self.sensor, self.bins = sensor, bins
        self.by_count = window_events
        self.window_us = window_us or (None if window_events else DEFAULT_WINDOW_US)
        self.edges = edges
        self.index = 0
        self.t0 = t_start
        self._new()

    def _bounds(self):
        """(t0, t1) of the current time window, or None past the last GT window."""
        if self.edges is None:
            return self.t0, self.t0 + self.window_us
        if self.index >= self.edges[0].size:
            return None
        return int(self.edges[0][self.index]), int(self.edges[1][self.index])

    def _new(self):
        h, w = self.sensor
        if self.dense == "robust":
            self.kept = []  # the window's (events, flow): the robust fit re-weights events
        else:
            self.acc = np.zeros((self.bins, h, w, 5 if self.dense == "lsq" else 2), np.float64)
            self.cnt = np.zeros((self.bins, h, w), np.int64)
        self.iwe = np.zeros((h, w), np.float64)
        self.n = 0
        self.pending = []  # count windows: (events, flow) until the end time is known

    def add(self, chunk, flow):
        if self.by_count:
            yield from self._add_count(chunk, flow)
            return
        t = chunk.t
        start = 0
        while start < len(chunk) and (b := self._bounds()) is not None:
            t0, t1 = b
            start = max(start, int(np.searchsorted(t, t0, side="left")))
            stop = int(np.searchsorted(t, t1, side="left"))
            self._accumulate(chunk[start:stop], flow[start:stop], t0, t1)
            start = stop
            if stop < len(chunk):
                yield self._close(t0, t1)
                self.t0 = t1

    def _add_count(self, chunk, flow):
        start = 0
        while start < len(chunk):
            take = min(self.by_count - self.n, len(chunk) - start)
            self.pending.append((chunk[start:start + take], flow[start:start + take]))
            self.n += take
            start += take
            if self.n == self.by_count:
                t1 = (int(chunk.t[start]) if start < len(chunk)
                      else int(self.pending[-1][0].t[-1]) + 1)
                yield self._close_count(t1)

    def _close_count(self, t1):
        n = self.n
        for ev, fl in self.pending:
            self._accumulate(ev, fl, self.t0, t1)
        win = self._close(self.t0, t1)
        win.n_events = n
        self.t0 = t1
        return win

    def _accumulate(self, ev, fl, t0, t1):
        from evmotion.methods.triplet import add_normal_voxels, add_voxels

        if not len(ev):
            return
        if self.index < self.skip:
            self.n += 0 if self.by_count else len(ev)
            return
        if self.dense == "robust":
            self.kept.append((ev, fl))
        elif self.dense == "lsq":
            add_normal_voxels(ev, fl, t0, t1, self.acc, self.cnt, self.vmax)
        else:
            add_voxels(ev, fl, t0, t1, self.acc, self.cnt)
        self.n += 0 if self.by_count else len(ev)
        from evmotion.core.iwe import accumulate

        dt = (ev.t - t0).astype(np.float64) * 1e-6
        self.iwe += accumulate(ev.x.astype(np.float64) - fl.vx * dt,
                               ev.y.astype(np.float64) - fl.vy * dt, self.sensor)

    def _close(self, t0, t1):
        from evmotion.events import concatenate
        from evmotion.methods.triplet import (
            TripletFlow,
            dense_from_sums,
            dense_lsq_from_sums,
            dense_robust_fit,
        )

        if self.index < self.skip:
            flow = mask = None  # already in the resumed file
        elif self.dense == "robust" and not self.kept:
            flow = np.zeros((*self.sensor, 2), np.float32)  # no event: no flow anywhere
            mask = np.zeros(self.sensor, bool)
        elif self.dense == "robust":
            ev = concatenate([e for e, _ in self.kept], validate=False)
            fl = TripletFlow.concatenate([f for _, f in self.kept])
            flow, mask = dense_robust_fit(ev, fl, t0, t1, n_bins=self.bins,
                                          filter_size=self.filter_size, ridge=self.ridge,
                                          vmax=self.vmax)
        elif self.dense == "lsq":
            flow, mask = dense_lsq_from_sums(self.acc, self.cnt, filter_size=self.filter_size,
                                             ridge=self.ridge)
        else:
            flow, mask = dense_from_sums(self.acc, self.cnt, filter_size=self.filter_size)
        win = _Window(self.index, t0, t1, flow, mask, self.iwe, self.n)
        self.index += 1
        self._new()
        return win

    def finish(self):
        if self.by_count:
            if self.n:
                last = self.pending[-1][0]
                yield self._close_count(int(last.t[-1]) + 1)
            return
        while (b := self._bounds()) is not None:
            if self.edges is None and not self.n:
                return
            yield self._close(*b)


def _emit(win, sink, png_dir, kind, max_speed) -> int:
    if win.flow is None:
        sink.check_done(win)
        return 1
    if kind != ".npz":
        sink.add_window(win)
    if png_dir is not None:
        from evmotion.viz import iwe_to_rgb, save_flow_png, save_png

        png_dir.mkdir(parents=True, exist_ok=True)
        save_flow_png(png_dir / f"flow_{win.index:05d}.png", win.flow, max_speed=max_speed,
                      valid=win.mask)
        save_png(png_dir / f"iwe_{win.index:05d}.png", iwe_to_rgb(win.iwe))
    return 1


class _H5Sink:
    """Dense windows appended through :class:`evmotion.io.flowfiles.FlowWriter`."""

    def __init__(self, out: Path, sensor, attrs: dict, resume: bool = False):
        from evmotion.cli.flow import H5Output

        self.w = H5Output(out, sensor, attrs, resume=resume, with_valid=True)
        self.done = self.w.done

    def check_done(self, win):
        """A window of the resumed file: it must be the one this run delimits."""
        self.w.check_done(win.index, win.t0, win.t1)

    def add_window(self, win):
        self.w.append(win.flow, win.t0, win.t1, valid=win.mask)

    def close(self):
        self.w.close()

    def abort(self):
        self.w.abort()


class _NpzSink:
    """Per-event arrays streamed to raw temporary files, then stored as ``.npy`` members of
    a zip (an ``.npz``) without holding the stream in memory."""

    FIELDS = (("t", np.int64), ("x", np.float32), ("y", np.float32), ("p", np.uint8),
              ("vx", np.float32), ("vy", np.float32), ("nx", np.float32), ("ny", np.float32),
              ("valid", np.bool_), ("n_triplets", np.int32))

    def __init__(self, out: Path):
        import tempfile

        from evmotion.utils import atomic_path

        self._ctx = atomic_path(out)
        self.tmp = self._ctx.__enter__()
        self.dir = tempfile.TemporaryDirectory(prefix=".triplet-", dir=out.parent)
        self.files = {k: open(Path(self.dir.name) / k, "wb") for k, _ in self.FIELDS}
        self.n = 0

    def add(self, chunk, flow):
        vals = {"t": chunk.t, "x": chunk.x, "y": chunk.y, "p": chunk.p, "vx": flow.vx,
                "vy": flow.vy, "nx": flow.nx, "ny": flow.ny, "valid": flow.valid,
                "n_triplets": flow.n_triplets}
        for k, dt in self.FIELDS:
            self.files[k].write(np.ascontiguousarray(vals[k], dtype=dt).tobytes())
        self.n += len(chunk)

    def close(self):
        for fh in self.files.values():
            fh.close()
        with zipfile.ZipFile(self.tmp, "w", allowZip64=True) as zf:
            for k, dt in self.FIELDS:
                with zf.open(f"{k}.npy", "w", force_zip64=True) as dst, \
                        open(Path(self.dir.name) / k, "rb") as src:
                    np.lib.format.write_array_header_1_0(
                        dst, {"descr": np.lib.format.dtype_to_descr(np.dtype(dt)),
                              "fortran_order": False, "shape": (self.n,)})
                    while block := src.read(1 << 22):
                        dst.write(block)
        self.dir.cleanup()
        self._ctx.__exit__(None, None, None)

    def abort(self):
        for fh in self.files.values():
            fh.close()
        self.dir.cleanup()
        self._ctx.__exit__(RuntimeError, RuntimeError("aborted"), None)


class _NpySink:
    """Dense windows streamed to a raw temporary file, then written as one ``(N, H, W, 2)``
    float32 ``.npy`` (px/s) once N is known, without holding the windows in memory."""

    def __init__(self, out: Path, sensor):
        import tempfile

        from evmotion.utils import atomic_path

        self.sensor = sensor
        self._ctx = atomic_path(out)
        self.tmp = self._ctx.__enter__()
        self.raw = tempfile.TemporaryFile(prefix=".triplet-", dir=out.parent)
        self.n = 0

    def add_window(self, win):
        self.raw.write(np.ascontiguousarray(win.flow, dtype="<f4").tobytes())
        self.n += 1

    def close(self):
        self.raw.seek(0)
        with open(self.tmp, "wb") as dst:
            np.lib.format.write_array_header_1_0(
                dst, {"descr": "<f4", "fortran_order": False,
                      "shape": (self.n, *self.sensor, 2)})
            while block := self.raw.read(1 << 22):
                dst.write(block)
        self.raw.close()
        self._ctx.__exit__(None, None, None)

    def abort(self):
        self.raw.close()
        self._ctx.__exit__(RuntimeError, RuntimeError("aborted"), None)


class _FloSink:
    """Middlebury ``.flo`` displacement per window: ``out`` itself for a single window,
    ``out_0000.flo``... otherwise (each file written atomically as its window ends; an
    interrupted or failed run removes the files it wrote, leaving no partial set)."""

    def __init__(self, out: Path):
        self.out = out
        self.first = None
        self.n = 0
        self.written: list[Path] = []

    def _write(self, path, win):
        from evmotion.io.flowfiles import write_flo

        write_flo(path, win.flow, dt_s=(win.t1 - win.t0) * 1e-6)
        self.written.append(Path(path))

    def _numbered(self, i):
        return self.out.with_name(f"{self.out.stem}_{i:04d}.flo")

    def add_window(self, win):
        if self.n == 0:
            self.first = win
        else:
            if self.n == 1:
                self._write(self._numbered(0), self.first)
                self.first = None
            self._write(self._numbered(self.n), win)
        self.n += 1

    def close(self):
        if self.first is not None:
            self._write(self.out, self.first)

    def abort(self):
        self.first = None
        for path in self.written:
            path.unlink(missing_ok=True)
