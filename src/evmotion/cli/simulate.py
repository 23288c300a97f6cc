"""``evmotion simulate``: simulate an event camera with exact ground truth.

Writes the events (any writable format, chosen by the extension or --format) and the
ground truth beside them as ``<stem>_gt.h5`` (motion parameters per frame, dense flow in
px/s at virtual frame times, intrinsics, angular velocity, event masks).
"""

from __future__ import annotations

import argparse
import json

from evmotion.cli.options import (
    existing_input,
    int_range,
    nonnegative_float,
    positive_float,
    writable_output,
)

# sides of a simulated sensor: the simulator renders float64 frames of this size
MAX_SIDE = 4096

EXAMPLES = """examples:
  evmotion simulate rotation --out sim.h5
  evmotion simulate zoom --params hz=2.0 --params foe=150,120 --out zoom.h5 --json
  evmotion simulate object --texture shapes --duration 0.2 --noise-rate 0.1 --out obj.h5
  evmotion simulate translation --image photo.png --params vx=300 --params vy=0 --out t.h5
"""


def add_parser(sub) -> None:
    from evmotion.sim.scenes import SCENES

    lines = "\n".join(f"  {n:<12} {s.description}" for n, s in SCENES.items())
    p = sub.add_parser(
        "simulate", help="simulate events with ground truth (ESIM-like)",
        description=__doc__ + "\nscenes:\n" + lines, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scene", choices=sorted(SCENES), help="named scene (motion)")
    p.add_argument("--out", required=True, type=writable_output(),
                   help="events file; ground truth goes to <stem>_gt.h5")
    p.add_argument("--format", default=None, help="events format (default: from the extension)")
    p.add_argument("--duration", type=positive_float(unit="s"), default=0.1,
                   help="seconds (default 0.1)")
    p.add_argument("--size", default="260x346", type=parse_size,
                   help="HxW pixels (default 260x346, DAVIS346)")
    p.add_argument("--seed", type=int_range(0), default=0)
    p.add_argument("--texture", default="dots", choices=["dots", "shapes", "noise", "checker"])
    p.add_argument("--image", default=None, metavar="PATH", type=existing_input,
                   help="image to use as texture")
    p.add_argument("--threshold", type=positive_float(), default=0.2,
                   help="contrast threshold C (log)")
    p.add_argument("--mismatch", type=nonnegative_float(), default=0.03,
                   help="relative std of per-pixel thresholds")
    p.add_argument("--refractory-us", type=int_range(0, unit="µs"), default=0)
    p.add_argument("--noise-rate", type=nonnegative_float(unit="events/s"), default=0.0,
                   help="background activity, events/s per pixel")
    p.add_argument("--hot-pixels", type=int_range(0), default=0, help="number of hot pixels")
    p.add_argument("--hot-rate", type=nonnegative_float(unit="events/s"), default=1000.0,
                   help="events/s of a hot pixel")
    p.add_argument("--frame-rate", type=positive_float(unit="Hz"), default=100.0,
                   help="GT frame rate, Hz")
    p.add_argument("--params", action="append", default=[], metavar="KEY=VALUE",
                   help="motion parameter, repeatable (vector: comma-separated), or a JSON "
                        "object; see 'evmotion simulate --help' scenes and the docs of "
                        "evmotion.sim.scenes for names and units")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def parse_params(items: list[str]) -> dict:
    """``["vx=100", "omega=0.1,0.2,0.3"]`` or JSON objects -> dict of floats/lists."""
    import numpy as np

    from evmotion.errors import ParameterError

    out: dict = {}
    for item in items:
        item = item.strip()
        if item.startswith("{"):
            try:
                obj = json.loads(item)
            except json.JSONDecodeError as exc:
                raise ParameterError(f"--params {item!r} is not valid JSON: {exc}") from None
            if not isinstance(obj, dict):
                raise ParameterError(f"--params JSON must be an object, got {item!r}")
            out.update(obj)
            continue
        key, sep, val = item.partition("=")
        if not sep or not key.strip():
            raise ParameterError(f"--params expects KEY=VALUE, got {item!r}")
        try:
            vals = [float(v) for v in val.split(",")]
        except ValueError:
            raise ParameterError(f"--params {key}: value {val!r} is not a number "
                                 "(or comma-separated numbers)") from None
        if not all(np.isfinite(vals)):
            raise ParameterError(f"--params {key}: value {val!r} must be finite")
        out[key.strip()] = vals[0] if len(vals) == 1 else vals
    return out


def parse_size(text: str) -> tuple[int, int]:
    """``"260x346"`` -> ``(260, 346)``; an ``argparse`` type (sides 1 to :data:`MAX_SIDE`)."""
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be HxW (e.g. 260x346), got {text!r}") from None
    if not (1 <= h <= MAX_SIDE and 1 <= w <= MAX_SIDE):
        raise argparse.ArgumentTypeError(f"sides must be 1 to {MAX_SIDE} px, got {text!r}")
    return h, w


def run(args) -> int:
    import numpy as np

    from evmotion.cli import print_json
    from evmotion.errors import EvmotionError
    from evmotion.sim import gt_path_for, sim_calibration, simulate, write_ground_truth

    try:
        from evmotion.io import format_for_output, write_events
    except ImportError:
        raise EvmotionError("this build has no event writer (evmotion.io.write_events)") from None
    fmt = args.format or format_for_output(args.out)
    res = simulate(args.scene, duration_s=args.duration, sensor_size=args.size,
                   seed=args.seed, texture=args.texture, threshold=args.threshold,
                   params=parse_params(args.params), image=args.image, mismatch=args.mismatch,
                   refractory_us=args.refractory_us, noise_rate=args.noise_rate,
                   hot_pixels=args.hot_pixels, hot_rate=args.hot_rate,
                   frame_rate=args.frame_rate)
    # only HDF5 keeps free metadata; other formats would warn about it
    meta = {"simulator_scene": args.scene, "simulator_seed": args.seed,
            "calibration": sim_calibration(res.gt.K, res.events.sensor_size)} \
        if fmt == "h5" else {}
    write_events(args.out, res.events, format=fmt, **meta)
    gt_path = write_ground_truth(gt_path_for(args.out), res.gt)
    if args.json:
        print_json({
            "scene": args.scene, "events_file": str(args.out), "gt_file": str(gt_path),
            "n_events": len(res.events), "duration_s": args.duration,
            "sensor_size": list(res.events.sensor_size),
            "events_per_s": len(res.events) / max(args.duration, 1e-12),
            "params": res.gt.params(0), "frames": int(len(res.gt.frame_times_us)),
            "stats": res.stats, "K": np.asarray(res.gt.K),
        })
    else:
        print(f"{len(res.events)} events ({args.scene}, {args.duration} s) -> {args.out}; "
              f"ground truth -> {gt_path}")
    return 0
