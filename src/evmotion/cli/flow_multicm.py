"""``evmotion flow FILE --method multicm``: dense flow by multi-reference CMax (ch. 4).

Windows come from ``--window-events N`` (default 30000), ``--window-us T`` or
``--window-gt GT`` (the ground truth's timestamps, ``--gt-dt`` frames per window). Each
window is warm-started from the previous one. With ``--workers > 1`` the windows are split
into one contiguous chunk per worker (:func:`evmotion.parallel.map_windows`) and the warm
start runs within each chunk only, so the first window of every chunk starts from zero flow.

Output by ``--out`` extension: ``.h5`` all windows (flow in px/s with each window's
``[t0, t1)``), ``.npy`` an ``(N, H, W, 2)`` float32 array in px/s, ``.flo`` Middlebury
displacement over each window (``name_0000.flo``... when there are several windows).
"""

from __future__ import annotations

import functools
import time
from pathlib import Path

import numpy as np

from evmotion.errors import ParameterError

DEFAULT_WINDOW_EVENTS = 30_000


def add_arguments(group) -> None:
    group.add_argument("--time-aware", choices=("none", "upwind", "burgers"), default="none",
                       help="time-aware flow transport (4.8) (default none)")
    group.add_argument("--time-bins", type=int, default=None, metavar="B",
                       help="time bins of the time-aware flow (default 5; 40 from 640 px wide)")
    group.add_argument("--scales", type=int, default=5,
                       help="coarse-to-fine scales ending at 16x16 tiles (default 5)")
    group.add_argument("--lambda", dest="lam", type=float, default=0.0025,
                       help="TV weight of (4.9) (default 0.0025)")
    group.add_argument("--objective", default="gradient_magnitude",
                       choices=("gradient_magnitude", "variance", "avg_timestamp",
                                "avg_timestamp_norm"),
                       help="focus function (default gradient magnitude)")
    group.add_argument("--max-iter", type=int, default=20,
                       help="optimizer iterations per scale (default 20)")
    group.add_argument("--init", choices=("previous", "dnn"), default="previous",
                       help="start each window from the previous one's flow (default) or "
                            "from the network's (--checkpoint), skipping the coarse scales")


def _read(path, fmt):
    import evmotion.io as eio

    if hasattr(eio, "read_events"):
        return eio.read_events(path, **({"format": fmt} if fmt else {}))
    from evmotion.io.registry import detect_format, get_format

    spec = get_format(fmt) if fmt else detect_format(path)
    return spec.read(path)


def _windows(args, events):
    if args.window_gt:
        from evmotion.io.flowfiles import read_gt_flow

        gt = read_gt_flow(args.window_gt)
        # frame edges: every GT start plus the end of the last frame
        edges = np.append(np.asarray(gt.t0), np.asarray(gt.t1)[-1:])
        return events.windows_at(edges, dt=args.gt_dt)
    if args.window_us:
        if args.window_us <= 0:
            raise ParameterError(f"--window-us must be > 0, got {args.window_us}")
        return events.windows_by_duration(args.window_us)
    n = args.window_events or DEFAULT_WINDOW_EVENTS
    if n <= 0:
        raise ParameterError(f"--window-events must be > 0, got {n}")
    return events.windows_by_count(n)


def _chunk_fn(events, t0, t1, *, spans, kwargs):
    """Worker: the sub-windows of one chunk, warm-started in sequence."""
    from evmotion.methods.multicm import estimate_flow

    out, init = [], None
    for a, b in spans:
        if a < t0 or a >= t1:
            continue
        sub = events.slice_time(a, b)
        res = estimate_flow(sub, init=init, **kwargs)
        out.append(res)
        init = res
    return out


def _estimate(events, windows, kwargs, workers):
    from evmotion.methods.multicm import estimate_flow
    from evmotion.utils import progress

    if kwargs.get("init") == "dnn":
        return [estimate_flow(events.window(w), **kwargs)
                for w in progress(windows, total=len(windows), desc="multicm")]
    if workers <= 1:
        out, init = [], None
        for w in progress(windows, total=len(windows), desc="multicm"):
            res = estimate_flow(events.window(w), init=init, **kwargs)
            out.append(res)
            init = res
        return out
    from evmotion.parallel import map_windows

    spans = [(w.t0, w.t1) for w in windows]
    bounds = np.linspace(0, len(spans), min(workers, len(spans)) + 1).astype(int)
    chunks = [(spans[a][0], spans[b - 1][1]) for a, b in zip(bounds[:-1], bounds[1:],
                                                             strict=True) if b > a]
    fn = functools.partial(_chunk_fn, spans=spans, kwargs=kwargs)
    results = map_windows(fn, events, chunks, workers=workers, with_window=True,
                          desc="multicm")
    out = []
    for r in results:
        if not r.ok:
            raise ParameterError(f"window chunk [{r.t0}, {r.t1}) us failed: {r.error}")
        out.extend(r.value)
    return out


def _write(out: Path, results, windows, sensor_size, attrs):
    from evmotion.io.flowfiles import FlowWriter, write_flo
    from evmotion.utils import atomic_path

    kind = out.suffix.lower()
    written = []
    if kind in (".h5", ".hdf5"):
        with FlowWriter(out, sensor_size, attrs=attrs) as fw:
            for r, w in zip(results, windows, strict=True):
                fw.append(r.flow, t0=w.t0, t1=w.t1)
        written.append(str(out))
    elif kind == ".npy":
        with atomic_path(out) as tmp, open(tmp, "wb") as fh:
            np.save(fh, np.stack([r.flow for r in results]))
        written.append(str(out))
    else:
        for i, (r, w) in enumerate(zip(results, windows, strict=True)):
            path = out if len(results) == 1 else out.with_name(f"{out.stem}_{i:04d}.flo")
            write_flo(path, r.flow, dt_s=(w.t1 - w.t0) * 1e-6)
            written.append(str(path))
    return written


def _pngs(png_dir: Path, results):
    from evmotion.viz import flow_to_rgb, iwe_to_rgb, save_png

    png_dir.mkdir(parents=True, exist_ok=True)
    for i, r in enumerate(results):
        save_png(png_dir / f"flow_{i:04d}.png", flow_to_rgb(r.flow))
        mask = r.iwes["identity"] > 0
        save_png(png_dir / f"flow_masked_{i:04d}.png", flow_to_rgb(r.flow, mask=mask))
        vmax = float(np.percentile(r.iwes["tmid"][mask], 99)) if mask.any() else None
        for key in ("tmid", "identity"):
            save_png(png_dir / f"iwe_{key}_{i:04d}.png", iwe_to_rgb(r.iwes[key], vmax=vmax))


def run(args) -> int:
    from evmotion.cli import print_json

    method = getattr(args, "method", "multicm")
    out = Path(args.out)
    if out.suffix.lower() not in (".h5", ".hdf5", ".npy", ".flo"):
        raise ParameterError(f"--out {out}: the {method} method writes .h5 (all windows), "
                             ".npy or .flo")
    if args.scales < 1 or args.scales > 5:
        raise ParameterError(f"--scales must be between 1 and 5, got {args.scales}")
    t_start = time.perf_counter()
    events = _read(args.file, getattr(args, "format", None))
    windows = [w for w in _windows(args, events) if w.count >= 10]
    if not windows:
        raise ParameterError(f"{args.file}: no window with at least 10 events")
    if method == "dnn":
        from evmotion.cli.flow_dnn import estimate as estimate_dnn

        results = estimate_dnn(events, windows, args)
        attrs = {"method": "dnn", "checkpoint": str(args.checkpoint or "shipped"),
                 "source": str(args.file)}
    else:
        kwargs = dict(time_aware=None if args.time_aware == "none" else args.time_aware,
                      n_scales=args.scales, objective=args.objective, lam=args.lam,
                      n_bins=args.time_bins, max_iter=args.max_iter)
        if getattr(args, "init", "previous") == "dnn":
            kwargs.update(init="dnn", checkpoint=getattr(args, "checkpoint", None))
        results = _estimate(events, windows, kwargs, args.workers)
        attrs = {"method": "multicm", "time_aware": args.time_aware,
                 "objective": args.objective, "lambda": args.lam, "scales": args.scales,
                 "init": getattr(args, "init", "previous"), "source": str(args.file)}
    written = _write(out, results, windows, events.sensor_size, attrs)
    if args.png_dir:
        _pngs(Path(args.png_dir), results)
    if args.json:
        print_json({
            "method": method, "time_aware": "none" if method == "dnn" else args.time_aware,
            "outputs": written,
            "n_windows": len(results), "sensor_size": list(events.sensor_size),
            "windows": [{"t0_us": w.t0, "t1_us": w.t1, "n_events": r.n_events,
                         "focus": r.focus, "seconds": r.timings["total_s"],
                         "mean_speed_px_s": float(np.linalg.norm(r.flow, axis=-1).mean())}
                        for r, w in zip(results, windows, strict=True)],
            "seconds": time.perf_counter() - t_start,
        })
    return 0
