"""``evmotion kymogram``: a space-time plot along a line and the speed of its ridge.

The line is an image row (x–t), a column (y–t) or a segment ``--line x0 y0 x1 y1``,
``--width`` px wide. The kymogram comes from the events binned at ``--rate`` Hz (1200 and
above: "slow motion", thesis Fig. 6.11b), or from the q or flow of a BOS / flow HDF5 file
at its window rate. ``--compare-rate`` adds the events binned at a camera's frame rate and
``--frames`` the frames' differences at their own rate (Fig. 6.11a). A robust line fit to
each panel (by default the slope of its space-time autocorrelation, which many parallel
streaks share; ``--method ridge`` fits one streak) gives its speed in px/s along the line
(start -> end), and in m/s with ``--focal-mm``, ``--distance-m`` and ``--pixel-um``
(v = v_px * pitch * Z / f, §6.6.5).
"""

from __future__ import annotations

from dataclasses import replace

from evmotion.cli.options import (
    HelpFormatter,
    add_sensor_size_argument,
    add_time_unit_argument,
    check_time_order,
    empty_selection,
    event_format,
    existing_input,
    finite_float,
    int_range,
    read_kwargs,
    reject_unused,
    time_us,
    writable_output,
)

EXAMPLES = """examples:
  evmotion kymogram scene/ --col 80 --width 9 --rate 1200 --out kymo.png
  evmotion kymogram scene/ --col 80 --width 9 --compare-rate 120 --frames scene/ \\
      --out kymo_frames.png
  evmotion kymogram bos.h5 --from q --line 80 120 80 10 --width 5 --out q_kymo.png
  evmotion kymogram scene/ --col 80 --width 9 --focal-mm 25 --distance-m 1.7 \\
      --pixel-um 4.86 --t0 0.01 --out kymo_ms.png --json
(scene/: made by 'evmotion simulate schlieren --scene plume --size 128x160 --duration 0.25
--out scene/', whose plume rises at 427 px/s along the middle column, 80; off it the air
moves otherwise (column 64: 517 px/s); bos.h5 by 'evmotion bos scene/ --out bos.h5'.)
"""

SOURCES = ("events", "q", "flow")


def add_parser(sub) -> None:
    p = sub.add_parser(
        "kymogram", help="space-time plot along a line and velocimetry (ch. 6)",
        description=__doc__, epilog=EXAMPLES,
        formatter_class=HelpFormatter,
    )
    p.add_argument("file", help="recording (events), or a BOS/flow HDF5 file with --from q|flow")
    where = p.add_mutually_exclusive_group(required=True)
    where.add_argument("--line", nargs=4, type=finite_float(unit="px"), metavar=("X0", "Y0", "X1", "Y1"),
                       help="segment from (X0, Y0) to (X1, Y1) px (x = column, y = row)")
    where.add_argument("--row", type=int_range(0, unit="px"), metavar="R",
                       help="image row R, left to right (x-t kymogram)")
    where.add_argument("--col", type=int_range(0, unit="px"), metavar="C",
                       help="image column C, top to bottom (y-t; rising motion is < 0)")
    p.add_argument("--width", type=int_range(1, 4096, unit="px"), default=1, metavar="PX",
                   help="px across the line averaged (default 1)")
    p.add_argument("--from", dest="source", choices=SOURCES, default="events",
                   help="events (default), q of a BOS output (.h5, .npz), or |flow| of any "
                        "flow output (.h5, .npz, .flo/.png pattern)")
    p.add_argument("--rate", type=finite_float(0, 1e6, lo_open=True, unit="Hz"), default=None,
                   metavar="HZ", help="time bins per second of the events (default 1200)")
    p.add_argument("--compare-rate", type=finite_float(0, 1e6, lo_open=True, unit="Hz"),
                   default=None, metavar="HZ",
                   help="add a panel of the events binned at HZ (e.g. the frame rate, 120)")
    p.add_argument("--frames", default=None, metavar="PATH", type=existing_input,
                   help="add a panel of frame differences at the frame rate (folder with "
                        "images.txt, or a frames file)")
    p.add_argument("--format", type=event_format, default=None,
                   help="event format (default: detect)")
    add_sensor_size_argument(p)
    add_time_unit_argument(p)
    p.add_argument("--t0", type=time_us, default=None, metavar="TIME",
                   help="start: seconds on the recording's clock, or with a unit (1.5, "
                        "1500ms, 1500000us; +TIME: after the first event; default: first "
                        "event / window)")
    p.add_argument("--t1", type=time_us, default=None, metavar="TIME",
                   help="end (exclusive), same units as --t0")
    p.add_argument("--signed", action="store_true",
                   help="events: polarity sums instead of counts")
    fit = p.add_argument_group("velocimetry")
    fit.add_argument("--no-fit", action="store_true", help="draw the kymogram only")
    fit.add_argument("--method", choices=("correlation", "ridge"), default="correlation",
                     help="correlation (default): slope of the space-time autocorrelation, "
                          "for many parallel streaks (a plume's puffs); ridge: line through "
                          "each time bin's peak, for one dominant streak")
    fit.add_argument("--max-lag-s", type=finite_float(0, 1e6, lo_open=True, unit="s"),
                     default=None, metavar="S",
                     help="correlation: longest lag (default a quarter of the duration)")
    fit.add_argument("--sigma-px", type=finite_float(0, 1000, unit="px"), default=None,
                     help="smoothing along the line, px (ridge 2, correlation 1)")
    fit.add_argument("--sigma-bins", type=finite_float(0, 1000), default=None,
                     help="ridge: smoothing in time, bins (1)")
    fit.add_argument("--polarity", choices=("abs", "positive", "negative"), default=None,
                     help="ridge: of |signal| (abs, default), of its maxima or of its minima")
    fit.add_argument("--s-range", nargs=2, type=finite_float(unit="px"), default=None,
                     metavar=("S0", "S1"), help="search the ridge between S0 and S1 px "
                                                "along the line")
    # on the clock the picture's time axis shows (they were seconds after the kymogram's
    # start, so a time read off the axis fell outside it)
    fit.add_argument("--fit-t0", type=time_us, default=None, metavar="TIME",
                     help="fit from TIME, as --t0 takes it: seconds on the recording's clock "
                          "(the picture's time axis), with a unit, or +TIME after the "
                          "kymogram's start")
    fit.add_argument("--fit-t1", type=time_us, default=None, metavar="TIME",
                     help="fit up to TIME, as --fit-t0")
    fit.add_argument("--min-snr", type=finite_float(0, 1e6), default=None,
                     help="ridge peaks must stand this many robust sigmas above the median (3)")
    fit.add_argument("--stationary-px", type=finite_float(0, 1e4, unit="px"), default=None,
                     metavar="PX",
                     help="correlation: replace the autocorrelation within PX of shift 0 by "
                          "its running median (pixels that fire while structures pass; "
                          "default 3 * sigma-px + 1; 0 keeps it)")
    # bounds no lens, set-up or sensor reaches (probe OPT: --focal-mm 1e-30 printed a speed
    # of 1e27 m/s and exited 0)
    geo = p.add_argument_group("set-up geometry (all three for m/s)")
    geo.add_argument("--focal-mm", type=finite_float(0.1, 1e5, unit="mm"),
                     default=None, help="focal length f, mm")
    geo.add_argument("--distance-m", type=finite_float(1e-3, 1e6, unit="m"),
                     default=None, help="distance Z to the flow, m")
    geo.add_argument("--pixel-um", type=finite_float(0.1, 1e4, unit="µm"),
                     default=None, help="pixel pitch, µm")
    p.add_argument("--out", required=True, type=writable_output((".png",), "a PNG image"),
                   help="output PNG")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def _or(value, default):
    return default if value is None else value


def _check_args(args) -> dict | None:
    from evmotion.errors import ParameterError

    check_time_order(args)
    if args.source != "events":
        reject_unused(args, {"--rate": "rate", "--compare-rate": "compare_rate",
                             "--signed": "signed", "--format": "format",
                             "--sensor-size": "sensor_size", "--time-unit": "time_unit"},
                      f"with --from {args.source} (the file's windows set the rate)")
    fit_options = {"--max-lag-s": "max_lag_s", "--sigma-px": "sigma_px",
                   "--sigma-bins": "sigma_bins", "--polarity": "polarity",
                   "--s-range": "s_range", "--fit-t0": "fit_t0", "--fit-t1": "fit_t1",
                   "--min-snr": "min_snr", "--stationary-px": "stationary_px",
                   # the fitted speed's conversion to m/s (accepted, unused; probe CI)
                   "--focal-mm": "focal_mm", "--distance-m": "distance_m",
                   "--pixel-um": "pixel_um"}
    if args.no_fit:
        reject_unused(args, fit_options, "with --no-fit")
    elif args.method == "ridge":
        reject_unused(args, {"--max-lag-s": "max_lag_s", "--stationary-px": "stationary_px"},
                      "with --method ridge")
    else:
        reject_unused(args, {"--sigma-bins": "sigma_bins", "--polarity": "polarity"},
                      "with --method correlation (ridge only)")
    if args.s_range is not None and args.s_range[1] <= args.s_range[0]:
        raise ParameterError(f"--s-range {args.s_range[0]:g} {args.s_range[1]:g}: the end "
                             "must be after the start")
    geo = {"focal_mm": args.focal_mm, "distance_m": args.distance_m, "pixel_um": args.pixel_um}
    given = [k for k, v in geo.items() if v is not None]
    if given and len(given) < 3:
        missing = [f"--{k.replace('_', '-')}" for k in geo if geo[k] is None]
        raise ParameterError(f"m/s needs --focal-mm, --distance-m and --pixel-um; missing "
                             f"{', '.join(missing)}")
    return geo if given else None


# events read at a time (the events near the line are kept, the others dropped)
CHUNK_EVENTS = 1 << 20


def _progress(chunks, args):
    """``chunks`` counted on a progress bar (rate, and ETA where the header states the
    event count or the reader the share of the file read)."""
    from evmotion.cli.options import header_event_count
    from evmotion.utils import progress, refine_total

    total = header_event_count(args.file, args.format, args.t0, args.t1)
    bar = progress(None, total=total, desc="kymogram", unit="ev", unit_scale=True)
    done = 0
    try:
        for chunk in chunks:
            done += len(chunk)
            if total is None and args.t0 is None and args.t1 is None:
                refine_total(bar, done, chunk.meta)
            bar.update(len(chunk))
            yield chunk
    finally:
        bar.close()


def _line(args, shape):
    from evmotion.methods.kymogram import KymoLine

    if args.row is not None:
        return KymoLine.row(args.row, shape, args.width)
    if args.col is not None:
        return KymoLine.column(args.col, shape, args.width)
    return KymoLine(*args.line, width=args.width)


def _field_kymogram(args):
    """Kymogram of q (BOS file) or |flow| (any flow file), one sample per window, and the
    file's grid (H, W)."""
    import numpy as np

    from evmotion.io.flowread import read_flow
    from evmotion.methods.kymogram import kymogram_from_images

    exact = False
    if args.source == "q":
        from evmotion.sim.schlieren import is_schlieren_gt, read_schlieren_q

        exact = is_schlieren_gt(args.file)
    if exact:
        # the simulator's exact q, beside its flow (it had been refused as holding no q,
        # probe BA)
        images, times = read_schlieren_q(args.file)
        t0, t1, label = times[:-1], times[1:], "q (exact)"
    else:
        if args.source == "q":
            from evmotion.io.bosfiles import read_bos

            bos = read_bos(args.file)
            seq, images, label = bos.flow, bos.q, "q"
        else:
            seq = read_flow(args.file)
            images, label = np.hypot(seq.flow[..., 0], seq.flow[..., 1]), "|flow| px/s"
            if seq.valid is not None:  # where no event supports the flow, no signal either
                if not seq.valid.any():
                    # (it said "nothing crosses the line there; choose another line",
                    # of a file whose every window is no measurement, probe CE)
                    from evmotion.errors import EmptyWindowError

                    raise EmptyWindowError(f"{args.file}: none of its {len(seq)} windows has "
                                           "a valid pixel (each is no measurement): no "
                                           "flow to draw a kymogram of")
                images = np.where(seq.valid, images, np.nan)
        t0 = np.asarray(seq.t0, dtype=np.int64)
        t1 = np.asarray(seq.t1, dtype=np.int64)
    sel = np.ones(t0.size, bool)
    if args.t0 is not None:
        sel &= t0 >= args.t0
    if args.t1 is not None:
        sel &= t1 <= args.t1
    if not sel.any():
        raise empty_selection(args, args.file, int(t0.min()), int(t1.max()), "no window")
    if sel.sum() < 2:
        # one image is no time axis: "q at nan Hz", its times lost (probe BU)
        raise empty_selection(args, args.file, int(t0.min()), int(t1.max()),
                              "one window only (a kymogram needs two or more)")
    # NaN (outside the ROI, flow no event supports) is kept: no measurement, not zero
    imgs = np.asarray(images)[sel]
    mid_s = 0.5 * (t0[sel] + t1[sel]) * 1e-6
    line = _line(args, imgs.shape[1:])
    kymo = kymogram_from_images(imgs, mid_s, line, source=label)
    # each window is drawn over the interval it covers, [t0, t1) (it had been its centre
    # +- half the mean step); between windows that leave a gap or overlap, half-way
    a, b = t0[sel], t1[sel]
    edges = np.concatenate([[a[0]], 0.5 * (b[:-1] + a[1:]), [b[-1]]]) * 1e-6
    return replace(kymo, meta={**kymo.meta, "t_edges_s": edges}), tuple(imgs.shape[1:])


# the library's parameter names in its messages, as this command spells them
# (min_shift_px has no option: "a lower min_shift_px / stationary_px" reads as the one
# option that sets both)
_OPTION_NAMES = {"min_shift_px / stationary_px": "--stationary-px", "max_lag_s": "--max-lag-s",
                 "min_snr": "--min-snr", "stationary_px": "--stationary-px",
                 "sigma_px": "--sigma-px", "sigma_bins": "--sigma-bins",
                 "s_range": "--s-range", "t_range": "--fit-t0/--fit-t1"}


def _fit_times(args, kymo, t_start: float) -> tuple[float, float] | None:
    """--fit-t0/--fit-t1 in seconds on the kymogram's clock (``+TIME`` after its start), or
    None; each must select part of the kymogram (a region outside it gave a run with exit
    code 0 and a message about 0 time bins)."""
    from evmotion.cli.options import FromStart
    from evmotion.errors import ParameterError

    if args.no_fit or (args.fit_t0 is None and args.fit_t1 is None):
        return None
    t_end = float(kymo.t_s[-1]) + 0.5 / kymo.rate_hz
    span = f"it spans {t_start:.6g}..{t_end:.6g} s on the recording's clock"

    def seconds(value, edge: float) -> float:
        if value is None:
            return edge
        return value * 1e-6 + (t_start if isinstance(value, FromStart) else 0.0)

    t0, t1 = seconds(args.fit_t0, t_start), seconds(args.fit_t1, t_end)
    if t0 >= t_end:
        raise ParameterError(f"--fit-t0 {t0:.6g} s is at or after the kymogram's end: {span}")
    if t1 <= t_start:
        raise ParameterError(f"--fit-t1 {t1:.6g} s is at or before the kymogram's start: "
                             f"{span}")
    if t1 <= t0:
        raise ParameterError(f"--fit-t1 ({t1:.6g} s) must be after --fit-t0 ({t0:.6g} s)")
    return t0, t1


def _check_s_range(args, kymo) -> None:
    """--s-range must select part of the line."""
    from evmotion.errors import ParameterError

    length = float(kymo.s_px[-1]) if len(kymo.s_px) else 0.0
    if (not args.no_fit and args.s_range is not None
            and (args.s_range[0] > length or args.s_range[1] < 0)):
        raise ParameterError(f"--s-range {args.s_range[0]:g} {args.s_range[1]:g} px lies off "
                             f"the line, which runs from 0 to {length:.4g} px")


def _cli_names(text: str) -> str:
    import re

    # longest names first, so that a phrase is replaced before the words in it
    names = sorted(_OPTION_NAMES, key=len, reverse=True)
    return re.sub(r"\b(" + "|".join(map(re.escape, names)) + r")\b",
                  lambda m: _OPTION_NAMES[m.group(1)], text)


def _events_kymogram(events, line, rate: float, option: str, **kw):
    """:func:`~evmotion.methods.kymogram.kymogram_from_events`, its refusals of a rate
    naming ``option`` (a bin longer than the span had been said as "at 1 Hz")."""
    from evmotion.errors import EmptyWindowError, ParameterError
    from evmotion.methods.kymogram import kymogram_from_events

    try:
        return kymogram_from_events(events, line, rate, **kw)
    except (ParameterError, EmptyWindowError) as exc:
        if "rate_hz=" in str(exc):
            raise type(exc)(str(exc).replace("rate_hz=", f"{option} ")) from None
        raise


def _frames_kymogram(path, line, t0, t1, sensor_size, on: str):
    import numpy as np

    from evmotion.errors import FormatError, ParameterError
    from evmotion.io.frames import read_frames
    from evmotion.methods.kymogram import kymogram_from_frame_differences

    try:
        fr = read_frames(path)
    except FormatError as exc:
        # the reader's hint names --format, the events' option: these are frames
        raise ParameterError(f"--frames {path}: no frames read ({exc.message}); give an "
                             "ECD-style folder (images.txt + images/), an AEDAT4 file with "
                             "APS frames, or images with a timestamps file") from None
    if tuple(fr.sensor_size) != tuple(sensor_size):
        # another grid: the line's pixels would sample another part of the scene
        raise ParameterError(f"--frames {path} are {fr.sensor_size[1]}x{fr.sensor_size[0]} "
                             f"px but {on} is {sensor_size[1]}x{sensor_size[0]} px "
                             "(W x H): a kymogram line needs both on one pixel grid")
    t = np.asarray(fr.t, dtype=np.int64)
    sel = np.ones(t.size, bool)
    if t0 is not None:
        sel &= t >= t0
    if t1 is not None:
        sel &= t < t1
    if sel.sum() < 2:
        raise ParameterError(f"{path}: {int(sel.sum())} frame(s) in [{t0}, {t1}) us; a frame "
                             "kymogram needs two")
    kymo = kymogram_from_frame_differences(np.asarray(fr.images)[sel], t[sel], line)
    # a difference spans the two frames' times: drawn from the one to the other
    return replace(kymo, meta={**kymo.meta, "t_edges_s": t[sel] * 1e-6})


def run(args) -> int:
    from evmotion.cli import print_json
    from evmotion.errors import EmptyWindowError, FormatError, ParameterError
    from evmotion.methods.kymogram import (
        fit_correlation,
        fit_ridge,
        px_per_s_to_m_per_s,
    )
    from evmotion.viz.kymogram import save_kymogram_png, time_edges_s

    geometry = _check_args(args)
    if args.source == "events":
        import itertools

        import evmotion.io as eio
        from evmotion.methods.kymogram import events_near_line

        # a stream, keeping the events near the line only: the whole recording had been
        # held (2.9 GB for 97.5 M events, 13 GB and on for 475 M, probe DL)
        chunks = eio.iter_events(args.file, CHUNK_EVENTS, t0=args.t0, t1=args.t1,
                                 **read_kwargs(args))
        try:
            # (--sensor-size: the readers' own hint names it for text beside frames of
            # another size, probe BA)
            first = next((c for c in chunks if len(c)), None)
        except FormatError:
            from evmotion.io.flowread import describe_flow

            if args.format is None and describe_flow(args.file) is not None:
                raise ParameterError(f"{args.file} is a flow output (BOS or evmotion flow): "
                                     "its kymograms need --from q or --from flow") from None
            raise
        if first is None:
            # the error path only: one more pass over the file for its time range
            info = eio.describe(args.file, **read_kwargs(args))
            if info.get("t_first_us") is None:
                raise EmptyWindowError(f"{args.file}: the recording holds no events")
            raise empty_selection(args, args.file, int(info["t_first_us"]),
                                  int(info["t_last_us"]), "no events")
        line = _line(args, first.sensor_size)
        grid = first.sensor_size
        rate = 1200.0 if args.rate is None else args.rate
        try:
            # a rate past the cells a kymogram holds is refused as the span gets there
            near = events_near_line(_progress(itertools.chain([first], chunks), args),
                                    line, rate_hz=rate, t1_us=args.t1)
        except ParameterError as exc:
            raise ParameterError(str(exc).replace("rate_hz=", "--rate ")) from None
        events = near.events
        # the time axis spans the events: a --t0 / --t1 beyond them (0.5 s on a recording
        # whose clock starts at 1.6e9 s) only adds empty bins, petabytes of them
        t0 = near.t_first_us
        t1 = near.t_last_us + 1 if args.t1 is None else min(args.t1, near.t_last_us + 1)
        kymos = [_events_kymogram(events, line, rate, "--rate", t0_us=t0, t1_us=t1,
                                  signed=args.signed)]
        if args.compare_rate is not None:
            kymos.append(_events_kymogram(events, line, args.compare_rate, "--compare-rate",
                                          t0_us=t0, t1_us=t1, signed=args.signed))
    else:
        field, grid = _field_kymogram(args)
        kymos = [field]
        line = field.line
        t0, t1 = args.t0, args.t1
    if args.frames is not None:
        # frames of another size sampled the field's line elsewhere in the scene (probe BA)
        on = "the events' sensor" if args.source == "events" else f"{args.file}'s grid"
        kymos.append(_frames_kymogram(args.frames, line, t0, t1, grid, on))

    fits, summaries = [], []
    t_start = float(kymos[0].t_s[0]) - 0.5 / kymos[0].rate_hz
    t_range = _fit_times(args, kymos[0], t_start)
    _check_s_range(args, kymos[0])
    for k in kymos:
        fit, error = None, None
        if not args.no_fit:
            try:
                if args.method == "ridge":
                    fit = fit_ridge(k, sigma_px=_or(args.sigma_px, 2.0),
                                    sigma_bins=_or(args.sigma_bins, 1.0),
                                    polarity=_or(args.polarity, "abs"),
                                    s_range=args.s_range, t_range=t_range,
                                    min_snr=_or(args.min_snr, 3.0))
                else:
                    fit = fit_correlation(k, sigma_px=_or(args.sigma_px, 1.0),
                                          max_lag_s=args.max_lag_s,
                                          s_range=args.s_range, t_range=t_range,
                                          min_snr=_or(args.min_snr, 3.0),
                                          stationary_px=args.stationary_px)
            except (EmptyWindowError, ParameterError) as exc:
                # a coarse comparison panel may have too few bins for a fit: say so, draw it
                error = _cli_names(str(exc))
        fits.append(fit)
        edges = time_edges_s(k)
        row = {"source": k.source, "rate_hz": k.rate_hz, "shape": list(k.data.shape),
               # the span's edges, not its first and last bins' centres (half a bin in),
               # as the picture draws them
               "t0_s": float(edges[0]), "t1_s": float(edges[-1])}
        if t_range is not None:
            row.update(fit_t0_s=t_range[0], fit_t1_s=t_range[1])
        if fit is not None:
            row.update(method=fit.method, velocity_px_s=fit.velocity_px_s,
                       velocity_std_px_s=fit.velocity_std_px_s,
                       ridge_points=int(fit.t_s.size), inliers=int(fit.inliers.sum()),
                       residual_px=fit.residual_px,
                       reliable=fit.reliable)
            if not fit.reliable:
                row["unreliable_because"] = _cli_names(fit.unreliable_because)
            if geometry:
                row["speed_m_s"] = px_per_s_to_m_per_s(fit.speed_px_s, **geometry)
                row["speed_std_m_s"] = px_per_s_to_m_per_s(fit.velocity_std_px_s, **geometry)
        elif error:
            row["fit_error"] = error
        summaries.append(row)
    # the picture in the command's words too ("a lower stationary_px" was drawn, probe DE)
    save_kymogram_png(args.out, kymos, fits, geometry=geometry,
                      fit_errors=[row.get("fit_error") for row in summaries],
                      unreliable=[row.get("unreliable_because") for row in summaries])

    ln = kymos[0].line
    summary = {"file": str(args.file), "out": str(args.out),
               "line": {"x0": ln.x0, "y0": ln.y0, "x1": ln.x1, "y1": ln.y1, "width": ln.width},
               "geometry": geometry, "panels": summaries}
    if args.json:
        print_json(summary)
    else:
        for row in summaries:
            text = f"{row['source']} at {row['rate_hz']:.4g} Hz {tuple(row['shape'])}: "
            if "velocity_px_s" in row:
                text += f"{row['velocity_px_s']:.4g} ± {row['velocity_std_px_s']:.2g} px/s"
                if "speed_m_s" in row:
                    text += f" (|v| = {row['speed_m_s']:.4g} m/s)"
                if not row["reliable"]:
                    text += f" -- unreliable: {row['unreliable_because']}"
            else:
                text += row.get("fit_error", "no fit")
            print(text)
        print(f"wrote {args.out}")
    if "fit_error" in summaries[0]:
        # the velocity asked for is not there: said on stderr as the other commands say a
        # result that is no measurement (it was in the panel's row only, on stdout);
        # comparison panels, coarser, may fail alone: said in their rows
        from evmotion.cli import warn_line

        warn_line(f"no velocity fit on the {summaries[0]['source']} panel: "
                  f"{summaries[0]['fit_error']} (the kymogram is drawn in {args.out}; "
                  "--no-fit draws it alone)")
    return 0
