"""``evmotion segment FILE --warps N``: split the events of each window into N motions by
expectation-maximization of per-cluster contrast (Sec. 3.6.6). Writes per-window parameters
of every cluster (``clusters.csv``, and ``clusters.h5``: :mod:`evmotion.io.paramsfiles`,
with units, each row's [t0, t1) µs, warp, grid and a valid flag; ``evmotion info``
describes it), event labels (``labels.npz``: ``window_NNNNN`` the cluster of each event,
with its time ``window_NNNNN_t_us`` and pixel ``_x``, ``_y`` on the grid the command used,
undistorted where a calibration undistorts, and per cluster ``_valid`` and ``_same_as``,
the cluster it duplicates or -1) and PNGs of the per-cluster IWEs. An interrupted run keeps
the windows it finished in ``OUT/segment.part``; the same command with ``--resume``
segments only the others."""

from __future__ import annotations

import csv
import functools
import io
from pathlib import Path

import numpy as np

from evmotion.catalog import MAX_WORKERS
from evmotion.cli.options import (
    HelpFormatter,
    add_scheduler_argument,
    add_time_arguments,
    check_time_order,
    duration_us,
    int_range,
    reject_unused,
    remove_stale_pictures,
    remove_stale_results,
    seed_int,
    select_windows,
    writable_folder,
)

EXAMPLES = """examples (sim.h5: made by 'evmotion simulate rotation --out sim.h5'):
  evmotion segment sim.h5 --warp rotation --warps 2 --max-windows 1 --out seg/
  evmotion segment sim.h5 --warp translation --warps 3 --window-us 20000 --t0 0.02 --max-windows 2 --iterations 5 --out seg3/ --json
"""


# the objectives the clusters' weighted images take (the average-timestamp ones do not)
SEGMENT_OBJECTIVES = ("variance", "gradient_magnitude")
SEGMENT_REGULARIZERS = ("divergence", "deformation", "rcad")
# the journal of a run's finished windows, in its output folder until the run ends
JOURNAL_NAME = "segment.part"


def add_parser(sub) -> None:
    from evmotion.cli.egomotion import add_common

    p = sub.add_parser("segment", help="motion segmentation with several warps (Sec. 3.6.6)",
                       description=__doc__, epilog=EXAMPLES,
                       formatter_class=HelpFormatter)
    add_common(p, objectives=SEGMENT_OBJECTIVES, regularizers=SEGMENT_REGULARIZERS)
    p.add_argument("--warps", type=int_range(1, 64), default=2,
                   help="number of motion clusters (default 2)")
    p.add_argument("--iterations", type=int_range(1, 1000), default=10,
                   help="EM iterations (default 10, at most 1000)")
    p.add_argument("--split", choices=("best", "dominant", "spatial"), default="best",
                   help="how the events are first split among the clusters: 'dominant' "
                        "(the motion sharpening them all takes the events it lines up better "
                        "than they lie unwarped, the next the rest...), 'spatial' (k-means of positions), 'best' (both; "
                        "the clusters that together sharpen the events most; default)")
    p.add_argument("--seed", type=seed_int, default=None,
                   help="seed of the spatial split's k-means (--split spatial or best; "
                        "default 0)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--window-events", type=int_range(10), metavar="N", help="events per window (default: 30000)")
    g.add_argument("--window-us", type=duration_us,
                   help="window duration: microseconds, or with a unit (10000, 10ms, 0.01s)")
    add_time_arguments(p)
    p.add_argument("--workers", type=int_range(1, MAX_WORKERS), default=1,
                   help="parallel worker processes (default 1)")
    add_scheduler_argument(p)
    p.add_argument("--out", required=True,
                   type=writable_folder("clusters.csv, clusters.h5, labels.npz and PNGs"),
                   help="output folder")
    p.add_argument("--resume", action="store_true",
                   help="continue an interrupted run: the windows it finished (kept in "
                        f"OUT/{JOURNAL_NAME}) are not segmented again; the same options "
                        "needed")
    p.add_argument("--json", action="store_true", help="print per-window results as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    args.t_ref = args.t_ref or "start"  # (egomotion's default is mid)
    from evmotion.cli import print_json
    from evmotion.cli.egomotion import check_common, check_scheduler, load_events_and_camera
    from evmotion.cli.options import scheduler_client
    from evmotion.errors import EvmotionError
    from evmotion.events import events_digest
    from evmotion.io.journal import Journal
    from evmotion.parallel import imap_windows
    from evmotion.utils import interrupts_deferred

    check_common(args)
    check_scheduler(args)
    check_time_order(args)
    if args.split == "dominant" or args.warps == 1:
        # (it was stored in the outputs and changed nothing, probe DK)
        reject_unused(args, {"--seed": "seed"}, ("with --split dominant" if args.warps > 1
                                                  else "with --warps 1")
                      + " (it seeds the spatial split's k-means)")
    args.seed = 0 if args.seed is None else args.seed
    cut = {"n_events": None if args.window_us else args.window_events or 30000,
           "duration_us": args.window_us or None, "min_events": 10 * args.warps}
    events, cam = load_events_and_camera(args, **cut)
    windows = select_windows(args, events, file=args.file, **cut)
    out = Path(args.out)
    made_out = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    K = None if cam is None else cam.K
    job = functools.partial(_segment_job, n_warps=args.warps, warp=args.warp,
                            objective=args.objective, K=K, t_ref=args.t_ref,
                            n_iter=args.iterations, seed=args.seed, split=args.split,
                            regularizer=args.reg,
                            weight=args.weight, dataset=args.dataset)
    journal, done = Journal.open_run(out / JOURNAL_NAME, _journal_header(args, events, windows, K),
                                     events, windows, args.resume)
    todo = [k for k in range(len(windows)) if k not in done]
    resumed = len(done)
    try:
        with journal, scheduler_client(args.scheduler) as client:
            for k, r in zip(todo, imap_windows(job, events, [windows[k] for k in todo],
                                               workers=args.workers, scheduler=client,
                                               desc="segment"), strict=True):
                if not r.ok:
                    raise EvmotionError(f"{args.file}: window {windows[k].index} [{r.t0}, "
                                        f"{r.t1}) us failed: {r.error.splitlines()[0]}")
                journal.add(k, windows[k].t0, windows[k].t1,
                            events_digest(events.window(windows[k])), r.value)
    except BaseException:
        # nothing finished: nothing to resume, nor the output folder this run made
        if not journal.settle(bool(done)) and made_out and not any(out.iterdir()):
            out.rmdir()
        raise
    done = Journal.read(journal.path, _journal_header(args, events, windows, K))
    # published whole: an interrupt among the pictures and the three files left a set
    # without labels.npz and clusters.h5, its journal unnamed (probe BH)
    with interrupts_deferred():
        rows = _publish(args, out, windows, done, events)
        journal.path.unlink()
    if args.json:
        print_json({"file": str(args.file), "grid": args.grid, "warp": args.warp,
                    "clusters": rows})
    else:
        print(f"{len(windows)} window{'' if len(windows) == 1 else 's'} x {args.warps} "
              "clusters" + (f" ({resumed} windows kept from the interrupted run)"
                            if resumed else "")
              + f" -> {out}/clusters.csv, clusters.h5")
    return 0


def _publish(args, out, windows, done, events) -> list[dict]:
    """Write the pictures, clusters.csv, labels.npz and clusters.h5 of the finished
    windows ``done`` (an earlier run's removed first); return the CSV's rows."""
    from evmotion.io.paramsfiles import ParamsTable, write_params_h5
    from evmotion.methods.measured import MIN_CHANCE_Z, MIN_CONTRAST_GAIN
    from evmotion.methods.segmentation import MIN_CLUSTER_EVENTS, MIN_CLUSTER_GAIN
    from evmotion.utils import atomic_path, atomic_write_bytes, atomic_write_text

    remove_stale_pictures(out, ("window_",))
    remove_stale_results(out, ("clusters.csv", "clusters.h5", "labels.npz"))
    rows, labels, pngs = [], {}, []
    try:
        for k, w in enumerate(windows):
            seg, panel = done[k][2]
            key = f"window_{w.index:05d}"
            labels[key] = seg.labels.astype(np.int16)
            # which events they label: undistortion drops those leaving the sensor, so a
            # window's labels need not line up with the recording's events there
            sub = events.window(w)
            labels[key + "_t_us"] = sub.t
            labels[key + "_x"], labels[key + "_y"] = sub.x, sub.y
            # per cluster: whether it is a measurement, and the cluster it repeats (-1:
            # none), so that the labels alone do not read as two motions where one is
            labels[key + "_valid"] = np.asarray(seg.valid, bool)
            labels[key + "_same_as"] = np.asarray(seg.same_as, np.int16)
            for j in range(args.warps):
                rows.append({"window": w.index, "t0_us": w.t0, "t1_us": w.t1, "cluster": j,
                             "n_events": int(np.sum(seg.labels == j)),
                             "params": dict(zip(seg.param_names, map(float, seg.params[j]),
                                                strict=True)),
                             "units": dict(zip(seg.param_names, seg.param_units,
                                               strict=True)),
                             "contrast_gain": float(seg.gains[j]),
                             "valid": bool(seg.valid[j]), "same_as": int(seg.same_as[j]),
                             "collapsed": bool(seg.collapsed[j]),
                             "chance_gain": float(seg.chance_gains[j]),
                             "chance_z": float(seg.chance_z[j])})
            pngs.append(out / f"window_{w.index:05d}.png")
            atomic_write_bytes(pngs[-1], panel)
    except BaseException:
        # an interrupted or failed run leaves no partial set of pictures without its CSV
        for path in pngs:
            path.unlink(missing_ok=True)
        raise
    _warn_invalid(rows)
    buf = io.StringIO()
    wr = csv.writer(buf)
    names = list(rows[0]["params"])
    wr.writerow(["window", "t0_us", "t1_us", "cluster", "n_events",
                 *[f"{n} [{rows[0]['units'][n]}]" for n in names], "contrast_gain", "valid",
                 "collapsed", "chance_gain", "chance_z"])
    for r in rows:
        # (the flags after valid: a reader that took the last column for it stays right)
        wr.writerow([r["window"], r["t0_us"], r["t1_us"], r["cluster"], r["n_events"],
                     *[repr(r["params"][n]) for n in names], repr(r["contrast_gain"]),
                     int(r["valid"]), int(r["collapsed"]), repr(r["chance_gain"]),
                     repr(r["chance_z"])])
    atomic_write_text(out / "clusters.csv", buf.getvalue())
    with atomic_path(out / "labels.npz") as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **labels)
    n_ev = np.array([r["n_events"] for r in rows], np.int64)
    params = np.array([[r["params"][n] for n in names] for r in rows], np.float64)
    write_params_h5(out / "clusters.h5", ParamsTable(
        params, tuple(names), tuple(rows[0]["units"][n] for n in names),
        np.array([r["t0_us"] for r in rows]), np.array([r["t1_us"] for r in rows]),
        np.array([r["valid"] for r in rows]) & np.isfinite(params).all(axis=1),
        {"window": np.array([r["window"] for r in rows]),
         "cluster": np.array([r["cluster"] for r in rows]), "n_events": n_ev,
         "empty": n_ev == 0,
         "contrast_gain": np.array([r["contrast_gain"] for r in rows]),
         "chance_gain": np.array([r["chance_gain"] for r in rows]),
         "chance_z": np.array([r["chance_z"] for r in rows]),
         "collapsed": np.array([r["collapsed"] for r in rows])},
        {"n_events": "events"},
        {"window": "window index", "cluster": "cluster index (labels.npz)",
         "n_events": "events assigned to the cluster", "empty": "flag: no event assigned",
         "contrast_gain": "IWE variance at the cluster's parameters over unwarped (valid "
                          f"needs >= {MIN_CLUSTER_GAIN} with >= {MIN_CLUSTER_EVENTS} "
                          "events, no collapse, an alignment of the window's events "
                          "beyond chance: chance_z)",
         "chance_gain": "how much better the cluster's warp aligns the window's events "
                        "(all, or its territory's: whichever test lies further beyond "
                        "chance) than with their times shuffled (valid needs >= "
                        f"{MIN_CONTRAST_GAIN:g})",
         "chance_z": "standard deviations by which the cluster's warp aligns the window's "
                     "events (all, or its territory's: the blocks where it holds most of "
                     "the membership) beyond 16 shuffles of their times (valid needs >= "
                     f"{MIN_CHANCE_Z:g})",
         "collapsed": "flag: the cluster's warp collapses its events"},
        {"method": "segment", "warp": args.warp, "grid": args.grid,
         "objective": args.objective, "warps": args.warps, "iterations": args.iterations,
         "seed": args.seed, "split": args.split}))
    return rows


def _journal_header(args, events, windows, K) -> dict:
    """What a resumed run must share with the interrupted one: the segmentation's options,
    the windows' cut and the events of the first window (another recording has others)."""
    from evmotion.events import fingerprint

    w = windows[0]
    return {"warp": args.warp, "warps": args.warps, "objective": args.objective,
            "reg": args.reg, "weight": args.weight, "t_ref": args.t_ref, "seed": args.seed,
            "iterations": args.iterations, "dataset": args.dataset, "split": args.split,
            "window_events": args.window_events, "window_us": args.window_us,
            "t0": args.t0, "grid": args.grid, "remove_hot_pixels": args.remove_hot_pixels,
            "K": None if K is None else np.asarray(K, np.float64).round(9).tolist(),
            "first_window": fingerprint(events[w.start:w.stop])}


#: Windows (and clusters of each) _warn_invalid names one by one; the rest are counted
#: (a 34-window run printed a line for each, and 50 clusters made one line of 4 KB, probe CE)
WARN_WINDOWS = 3
WARN_CLUSTERS = 4


def _warn_invalid(rows: list[dict]) -> None:
    """One warning line for the first :data:`WARN_WINDOWS` windows whose clusters are not
    all measurements, and one counting the others."""
    import warnings

    from evmotion.errors import PoorFitWarning
    from evmotion.methods.measured import MIN_CHANCE_Z, MIN_CONTRAST_GAIN

    bad: dict[int, list[dict]] = {}
    for r in rows:
        if not r["valid"]:
            bad.setdefault(r["window"], []).append(r)
    for window, rs in list(bad.items())[:WARN_WINDOWS]:
        what = ", ".join(f"{r['cluster']} ({r['n_events']} events, contrast gain "
                         f"{r['contrast_gain']:.3f}"
                         + (f", the motion of cluster {r['same_as']}" if r["same_as"] >= 0
                            else ", event collapse" if r["collapsed"]
                            else f", no better than its events with shuffled times: chance z "
                                 f"{r['chance_z']:.1f}, gain {r['chance_gain']:.3f}"
                            if (r["chance_z"] < MIN_CHANCE_Z
                                or r["chance_gain"] < MIN_CONTRAST_GAIN)
                            else "")
                         + ")" for r in rs[:WARN_CLUSTERS])
        more = f" and {len(rs) - WARN_CLUSTERS} more" if len(rs) > WARN_CLUSTERS else ""
        warnings.warn(PoorFitWarning(
            f"window {window}: cluster{'s' if len(rs) > 1 else ''} {what}{more}: "
            "not a measurement -- it sharpens nothing, holds too few events, collapses its "
            "events, aligns them no better than chance or repeats another cluster's motion "
            "(fewer --warps) (valid 0 in clusters.csv / clusters.h5)"), stacklevel=2)
    if len(bad) > WARN_WINDOWS:
        rest = list(bad)[WARN_WINDOWS:]
        warnings.warn(PoorFitWarning(
            f"{len(rest)} more windows (windows {rest[0]}..{rest[-1]}) hold clusters that "
            f"are not measurements ({sum(len(bad[w]) for w in rest)} clusters; valid 0 in "
            "clusters.csv / clusters.h5)"), stacklevel=2)


def _segment_job(events, **kwargs):
    """``(segmentation, PNG panel)`` of one window (each cluster's IWE), in a worker
    (module level, so that it pickles): the workers share the drawing and the client only
    writes the bytes (``benchmarks/results/cli_panels.md``). The result keeps no IWEs (a
    window's worth each to send back)."""
    import dataclasses
    import warnings

    import numpy as np

    from evmotion.errors import PoorFitWarning
    from evmotion.methods.segmentation import segment_motion
    from evmotion.viz import images
    from evmotion.viz.titles import parameters_text

    with warnings.catch_warnings():
        # the client says which clusters are not measurements, once, whichever process
        warnings.simplefilter("ignore", PoorFitWarning)
        seg = segment_motion(events, **kwargs)
    titles = []
    for j in range(len(seg.iwes)):
        # each value with its unit (the units joined by "/" after them all read
        # "1/(px s)/1/s/px/s", probe DA)
        values = parameters_text(seg.param_names, seg.params[j], seg.param_units)
        flag = ("" if seg.valid[j] else
                ", NOT VALID: event collapse" if seg.collapsed[j] else ", NOT VALID")
        titles.append(f"cluster {j}\n{values}\n"
                      f"{int(np.sum(seg.labels == j)):,} ev, gain {seg.gains[j]:.2f}{flag}")
    # one stated scale for all clusters' warped images (membership-weighted counts), of
    # the clusters that did not collapse: one collapsed onto a dot blanked the others
    # (probe DA)
    kept = [img for img, c in zip(seg.iwes, seg.collapsed, strict=True) if not c] or seg.iwes
    vmax = max(images.full_scale(img) for img in kept)
    # the span of the events drawn (the window's [t0, t1) in clusters.csv can reach past
    # its last event: a title [0.419, 22.991) ms beside t1_us 22994 read as a mismatch,
    # probe CE)
    t0_ms, t1_ms = int(events.t[0]) / 1e3, int(events.t[-1]) / 1e3
    panel = images.panel_png([images.iwe_to_rgb(img, vmax=vmax) for img in seg.iwes], titles,
                             suptitle=f"{seg.warp}, events at {t0_ms:.6g}-{t1_ms:.6g} ms\n"
                                      f"events warped by their cluster's motion; white 0, "
                                      f"black >= {vmax:.3g} events / px")
    return dataclasses.replace(seg, iwes=None), panel
