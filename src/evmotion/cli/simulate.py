"""``evmotion simulate``: simulate an event camera with exact ground truth.

Writes the events (any writable format, chosen by the extension or --format) and the
ground truth beside them as ``<stem>_gt.h5`` (motion parameters per frame, dense flow in
px/s at virtual frame times, intrinsics, angular velocity, event masks).

``evmotion simulate schlieren --scene plume|jet|breath|ice --out DIR`` simulates
background-oriented schlieren (thesis ch. 6): events and 8-bit (--bits) frames of a random-dot
background seen through moving air, written as an ECD-style folder (events.txt,
images.txt, images/) with the exact flow between frames, q and the displacement in
DIR/schlieren_gt.h5.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from evmotion.catalog import (
    MAX_MISMATCH,
    MAX_PIXEL_RATE,
    MAX_REFRACTORY_US,
    MAX_SIM_DURATION_S,
    MAX_SIM_SIDE,
    MIN_EVENT_PHOTONS,
    MIN_SIM_SIDE,
    MIN_THRESHOLD,
)
from evmotion.cli.options import (
    HelpFormatter,
    check_folder,
    check_output,
    check_output_format,
    existing_input,
    finite_float,
    int_range,
    nonnegative_float,
    positive_float,
    reject_unused,
    seed_int,
)

EXAMPLES = """examples:
  evmotion simulate rotation --out sim.h5
  evmotion simulate zoom --params hz=2.0 --params foe=80,60 --size 120x160 --out zoom.h5 --json
  evmotion simulate object --texture shapes --duration 0.05 --noise-rate 0.1 --out obj.h5
  evmotion simulate translation --image photo.png --params vx=300 --params vy=0 --size 120x160 --out t.h5
  evmotion simulate schlieren --scene plume --size 128x160 --duration 0.05 --magnitude 2 --out plume/
  evmotion simulate schlieren --scene breath --size 96x96 --duration 0.05 --photons 5 --out dark/ --json
"""


def add_parser(sub) -> None:
    from evmotion.sim.scenes import BOS_SCENES, SCENES

    # each scene's --params with their defaults (only the error message named them,
    # probe CE)
    lines = "\n".join(f"  {n:<12} {s.description}\n  {'':<12} --params "
                      + " ".join(f"{k}={'auto' if v is None else f'{v:g}'}"
                                 for k, v in s.defaults.items())
                      for n, s in SCENES.items())
    lines += ("\n  (rates per second: px/s for translations, rad/s for rotations, 1/s for "
              "zoom and the matrix entries)")
    lines += "\n  schlieren    background-oriented schlieren, --scene one of:\n" + "\n".join(
        f"    {n:<10} {d}" for n, d in BOS_SCENES.items())
    p = sub.add_parser(
        "simulate", help="simulate events with ground truth (ESIM-like)",
        description=__doc__ + "\nscenes:\n" + lines, epilog=EXAMPLES,
        formatter_class=HelpFormatter,
    )
    p.add_argument("scene", choices=[*sorted(SCENES), "schlieren"],
                   help="named scene (motion), or schlieren")
    p.add_argument("--out", required=True, help="events file; ground truth goes to "
                   "<stem>_gt.h5 (schlieren: an output folder)")
    p.add_argument("--format", default=None, help="events format (default: from the extension)")
    p.add_argument("--duration", type=finite_float(1e-6, MAX_SIM_DURATION_S, unit="s"),
                   default=0.1,
                   help="seconds (default 0.1)")
    p.add_argument("--size", "--sensor-size", default=None, nargs="+", action=_SizeAction,
                   metavar="HxW",
                   help="HxW pixels, or H W as convert's --sensor-size (default 260x346, "
                   "DAVIS346; schlieren 720x640)")
    p.add_argument("--height", type=int_range(1, MAX_SIM_SIDE, unit="px"), default=None,
                   help="pixels (overrides --size)")
    p.add_argument("--width", type=int_range(1, MAX_SIM_SIDE, unit="px"), default=None,
                   help="pixels (overrides --size)")
    p.add_argument("--seed", type=seed_int, default=0,
                   help="seed of every random choice: texture, noise, thresholds (default 0)")
    p.add_argument("--texture", default=None, choices=["dots", "shapes", "noise", "checker"],
                   help="texture of a motion scene (default dots)")
    p.add_argument("--image", default=None, metavar="PATH", type=existing_input,
                   help="image to use as texture")
    p.add_argument("--threshold", type=finite_float(MIN_THRESHOLD), default=0.2,
                   help="contrast threshold C, log-intensity units (default 0.2)")
    p.add_argument("--mismatch", type=finite_float(0.0, MAX_MISMATCH), default=0.03,
                   help="relative std of the per-pixel thresholds (default 0.03)")
    p.add_argument("--refractory-us", type=int_range(0, MAX_REFRACTORY_US, unit="µs"), default=0,
                   help="refractory period of a pixel after each event, µs (default 0)")
    p.add_argument("--noise-rate", type=finite_float(0.0, MAX_PIXEL_RATE, unit="events/s"),
                   default=0.0,
                   help="background activity, events/s per pixel (default 0)")
    p.add_argument("--hot-pixels", type=int_range(0), default=None,
                   help="number of hot pixels (default 0)")
    p.add_argument("--hot-rate", type=finite_float(0.0, MAX_PIXEL_RATE, unit="events/s"),
                   default=None,
                   help="events/s of a hot pixel (default 1000)")
    p.add_argument("--frame-rate", type=positive_float(unit="Hz"), default=None,
                   help="GT frame rate, Hz (default 100)")
    # (several after one --params, as the scene list above shows them: '--params vx=220
    # vy=-130' had stopped at 'unrecognized arguments: vy=-130', probe FLOWFOREIGN)
    p.add_argument("--params", action="extend", nargs="+", default=None, metavar="KEY=VALUE",
                   help="motion parameters (vector: comma-separated), or a JSON object; "
                        "several after one --params or --params repeated; each scene's names "
                        "and defaults are listed above (the docs of evmotion.sim.scenes give "
                        "their units)")
    g = p.add_argument_group("schlieren")
    g.add_argument("--scene", dest="bos_scene", default=None, choices=sorted(BOS_SCENES),
                   help="schlieren scene (default plume)")
    g.add_argument("--fps", type=finite_float(0, 1e5, lo_open=True, unit="Hz"), default=None,
                   help="frame rate, Hz (default 120)")
    g.add_argument("--magnitude", type=finite_float(0, 50, lo_open=True, unit="px"), default=None,
                   help="largest inter-frame displacement, px (default 1)")
    g.add_argument("--speed", type=positive_float(unit="px/s"), default=None,
                   help="air speed, px/s (plume rise speed; default scaled to the size)")
    g.add_argument("--photons", type=finite_float(0, 1e9, lo_open=True), default=None,
                   help="photons (photoelectrons) of a white pixel per frame: shot noise "
                        "(low light: a few)")
    g.add_argument("--gain", type=positive_float(), default=None,
                   help="frame camera's gain, grey levels per photon (default "
                        "(2^bits - 1)/photons: full scale at any light; a real camera at a "
                        "fixed exposure keeps its bright-scene gain)")
    g.add_argument("--read-noise", type=finite_float(0, 1e6, unit="e- rms"), default=None,
                   help="frame camera's temporal dark (read) noise, electrons rms, Gaussian "
                        "(default 0; needs --photons)")
    g.add_argument("--bits", type=int_range(1, 16, unit="bits"), default=None,
                   help="frame ADC bit depth, 1-16 (default 8): rounded and clipped to "
                        "0..2^bits-1; PNGs are 16-bit above 8")
    g.add_argument("--normalize", action="store_true",
                   help="stretch each quantized frame to the full grey range (min to 0, "
                        "max to 2^bits-1), as the thesis did with its dark frames")
    g.add_argument("--event-photons", type=finite_float(MIN_EVENT_PHOTONS, 1e12), default=None,
                   help="photons of a white event pixel per --event-tau-us: shot noise in "
                        "the events (low light); default none")
    g.add_argument("--event-tau-us", type=int_range(1, 1_000_000, unit="µs"), default=None,
                   help="time constant of the events' shot noise, µs (1000)")
    g.add_argument("--event-bandwidth", choices=("fixed", "intensity"), default=None,
                   help="event photoreceptor under --event-photons: 'fixed' noise bandwidth "
                        "(worst case, default) or 'intensity' (the DVS's time constant "
                        "grows as the light falls; from --event-tau-us in bright light)")
    g.add_argument("--exposure", type=nonnegative_float(unit="s"), default=None,
                   help="exposure, s (default half the frame period)")
    g.add_argument("--dot-density", type=finite_float(0, 2, lo_open=True, unit="dots/px²"),
                   default=None, help="dots per px² (0.06)")
    g.add_argument("--dot-radius", type=finite_float(0.2, 10, unit="px"), default=None,
                   help="dot radius, px (1.0)")
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
    """``"260x346"`` -> ``(260, 346)``; an ``argparse`` type (sides :data:`MIN_SIM_SIDE`
    to :data:`MAX_SIM_SIDE`)."""
    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be HxW (e.g. 260x346), got {text!r}") from None
    # (1x1 passed here and was refused by the simulator as "between 2 and 65535": probe)
    if not (MIN_SIM_SIDE <= h <= MAX_SIM_SIDE and MIN_SIM_SIDE <= w <= MAX_SIM_SIDE):
        raise argparse.ArgumentTypeError(f"sides must be {MIN_SIM_SIDE} to {MAX_SIM_SIDE} px, "
                                         f"got {text!r}")
    return h, w


class _SizeAction(argparse.Action):
    """``--size 260x346`` or ``--sensor-size 260 346`` (the spelling of convert and info)."""

    def __call__(self, parser, namespace, values, option_string=None):
        text = " ".join(values)
        if len(values) > 2 or (len(values) == 2 and not all(v.isdigit() for v in values)):
            raise argparse.ArgumentError(self, f"must be HxW or H W, got {text!r}")
        try:
            size = parse_size("x".join(values))
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentError(self, str(exc).replace("x".join(values), text)
                                         ) from None
        setattr(namespace, self.dest, size)


def _size(args, default: tuple[int, int]) -> tuple[int, int]:
    h, w = args.size or default
    return (args.height if args.height is not None else h,
            args.width if args.width is not None else w)


# options of one kind of scene only: given with the other kind, they are errors
MOTION_ONLY = {"--format": "format", "--texture": "texture", "--image": "image",
               "--hot-pixels": "hot_pixels", "--hot-rate": "hot_rate",
               "--frame-rate": "frame_rate", "--params": "params"}
SCHLIEREN_ONLY = {"--scene": "bos_scene", "--fps": "fps", "--magnitude": "magnitude",
                  "--speed": "speed", "--photons": "photons", "--gain": "gain",
                  "--read-noise": "read_noise", "--bits": "bits", "--normalize": "normalize",
                  "--event-photons": "event_photons", "--event-tau-us": "event_tau_us",
                  "--event-bandwidth": "event_bandwidth",
                  "--exposure": "exposure", "--dot-density": "dot_density",
                  "--dot-radius": "dot_radius"}


def _check_gt_not_shared(out: Path, gt: Path) -> None:
    """Refuse to write ``gt`` when it is the ground truth of another recording beside
    ``out``, as its ``events_file`` attribute says: ``a.txt`` after ``a.h5`` replaced
    ``a_gt.h5``, which ``a.h5`` still named as its own (probe)."""
    from evmotion.errors import FormatError, ParameterError
    from evmotion.io.h5attrs import file_attrs

    if not gt.is_file():
        return
    try:
        owner = file_attrs(gt, ("events_file",)).get("events_file")
    except FormatError:
        return  # not readable as HDF5: replacing it takes nothing
    if isinstance(owner, str) and owner != out.name and (out.parent / owner).is_file():
        raise ParameterError(f"--out {out}: its ground truth {gt.name} is that of {owner} "
                             f"beside it (the same stem); give another name, or remove "
                             f"{owner} and {gt.name}")


def _write_pair(out: Path, write_events, write_truth) -> Path:
    """Write a recording's events (``write_events()``, atomic) and its ground truth
    (``write_truth(path)``) as a pair. The new truth is written first under a hidden name;
    an earlier truth steps aside (hidden) as the events are written, and the new one takes
    its name once they stand. Interrupted before that, the earlier pair is put back; killed
    (SIGKILL), events may stand without a truth, never beside another scene's.

    Interrupted between the two files, new events had stood beside another scene's truth,
    which info then named as theirs (probe BH); deleting that truth first, a Ctrl-C while
    the events were written left the earlier events, or a finished new file, with no truth
    at all (probe BP); killed as the events appeared, new events stood beside the earlier
    truth, and the hidden truths of killed runs piled up (probe BR)."""
    from evmotion.sim import gt_path_for
    from evmotion.utils import remove_stale_temps, temp_prefix

    gt = Path(gt_path_for(out))
    for suffix in (".part.h5", ".old.h5"):
        remove_stale_temps(gt, suffix)  # a killed run's
    hidden = gt.with_name(f"{temp_prefix(gt)}part.h5")
    earlier = gt.with_name(f"{temp_prefix(gt)}old.h5")
    before = _signature(out)
    try:
        write_truth(hidden)
        if gt.exists():
            os.replace(gt, earlier)
        write_events()
    finally:
        # also when an interrupt came between the events' publication and this line
        if hidden.exists() and out.exists() and _signature(out) != before:
            os.replace(hidden, gt)
            earlier.unlink(missing_ok=True)
        else:
            hidden.unlink(missing_ok=True)
            if earlier.exists():
                os.replace(earlier, gt)
    return gt


def _signature(path: Path) -> tuple | None:
    """What tells a file written anew from the one that was there."""
    if not path.exists():
        return None
    st = path.stat()
    return st.st_ino, st.st_mtime_ns, st.st_size


def _or(value, default):
    return default if value is None else value


def run_schlieren(args) -> int:
    from evmotion.cli import print_json
    from evmotion.errors import ParameterError
    from evmotion.sim.options import SchlierenOptions
    from evmotion.sim.schlieren import simulate_schlieren, write_schlieren

    reject_unused(args, MOTION_ONLY, "to 'evmotion simulate schlieren'", SCHLIEREN_ONLY)
    scene = _or(args.bos_scene, "plume")
    size = _size(args, (720, 640))
    if min(size) < 8:
        raise ParameterError(f"--size/--height/--width: a schlieren sensor needs at least "
                             f"8 px per side, got {size[0]}x{size[1]} (HxW)")
    fps = _or(args.fps, 120.0)
    if args.duration * fps < 1.0:
        raise ParameterError(f"--duration {args.duration:g} s holds fewer than two frames "
                             f"at --fps {fps:g}; give at least {1.0 / fps:.6g} s")
    if args.exposure is not None and args.exposure > 1.0 / fps:
        raise ParameterError(f"--exposure {args.exposure:g} s is longer than the frame "
                             f"period at --fps {fps:g} ({1.0 / fps:.6g} s)")
    if args.gain is not None and args.photons is None:
        raise ParameterError(f"--gain {args.gain:g} needs --photons (shot-noise mode)")
    if args.read_noise and args.photons is None:
        raise ParameterError(f"--read-noise {args.read_noise:g} needs --photons (the noise "
                             "is in electrons)")
    if args.event_bandwidth == "intensity" and args.event_photons is None:
        raise ParameterError("--event-bandwidth intensity needs --event-photons (the "
                             "photoreceptor's time constant depends on the light)")
    check_folder(args.out, "--out", "events.txt, images.txt, images/ and schlieren_gt.h5")
    opts = SchlierenOptions(magnitude_px=_or(args.magnitude, 1.0),
                            dot_density=_or(args.dot_density, 0.06),
                            dot_radius_px=_or(args.dot_radius, 1.0), speed_px_s=args.speed,
                            photons=args.photons, gain=args.gain,
                            read_noise_e=_or(args.read_noise, 0.0),
                            bit_depth=_or(args.bits, 8), normalize=args.normalize,
                            exposure_s=args.exposure,
                            contrast_threshold=args.threshold, mismatch=args.mismatch,
                            refractory_us=args.refractory_us, noise_rate=args.noise_rate,
                            event_photons=args.event_photons,
                            event_tau_us=_or(args.event_tau_us, 1000),
                            event_bandwidth=_or(args.event_bandwidth, "fixed"))
    sim = simulate_schlieren(scene, sensor_size=size, duration_s=args.duration, fps=fps,
                             seed=args.seed, show_progress=not args.json, options=opts)
    gt_path = write_schlieren(sim, args.out)
    if args.json:
        print_json({"scene": scene, "out": str(args.out), "gt_file": str(gt_path),
                    "n_events": len(sim.events), "n_frames": len(sim.frames),
                    "sensor_size": list(sim.events.sensor_size), "meta": sim.gt.meta,
                    "stats": sim.stats})
    else:
        span = sim.gt.meta["span_s"]
        cut = f" of --duration {args.duration:g}: whole frame intervals" \
            if span < args.duration - 1e-6 else ""
        print(f"schlieren {scene}: {len(sim.events)} events, {len(sim.frames)} frames "
              f"({sim.events.sensor_size[1]} x {sim.events.sensor_size[0]} px (W x H), "
              f"{span:.6g} s{cut}) -> {args.out}; ground truth -> {gt_path}")
    return 0


def run(args) -> int:
    import numpy as np

    if args.scene == "schlieren":
        return run_schlieren(args)
    reject_unused(args, SCHLIEREN_ONLY, f"to the motion scene {args.scene!r} (it is for "
                  "'evmotion simulate schlieren')", MOTION_ONLY)
    if args.image is not None and args.texture is not None:
        from evmotion.errors import ParameterError

        # (the image won without a word over --texture checker, probe CE)
        raise ParameterError(f"--image {args.image} and --texture {args.texture}: the image "
                             "is the texture; give one of them")

    from evmotion.cli import print_json
    from evmotion.errors import EvmotionError
    from evmotion.sim import (
        SimOptions,
        gt_path_for,
        sim_calibration,
        simulate,
        write_ground_truth,
    )

    try:
        from evmotion.io import format_for_output, write_events
    except ImportError:
        raise EvmotionError("this build has no event writer (evmotion.io.write_events)") from None
    check_output(args.out, "--out")
    check_output(gt_path_for(args.out), "--out (its ground truth)")
    fmt = args.format or format_for_output(args.out, "--format")
    check_output_format(args.out, fmt, "--format")
    opts = SimOptions(threshold=args.threshold, mismatch=args.mismatch,
                      refractory_us=args.refractory_us, noise_rate=args.noise_rate,
                      hot_pixels=_or(args.hot_pixels, 0), hot_rate=_or(args.hot_rate, 1000.0),
                      frame_rate=_or(args.frame_rate, 100.0))
    res = simulate(args.scene, duration_s=args.duration, sensor_size=_size(args, (260, 346)),
                   seed=args.seed, texture=_or(args.texture, "dots"),
                   params=parse_params(args.params or []), image=args.image, options=opts)
    # (checked here rather than first: the ground truth's file is opened, h5py's import
    # and handles at the start had met a Ctrl-C there in the test of interruptions)
    _check_gt_not_shared(Path(args.out), gt_path_for(args.out))
    # only HDF5 keeps free metadata; other formats would warn about it
    meta = {"simulator_scene": args.scene, "simulator_seed": args.seed,
            "calibration": sim_calibration(res.gt.K, res.events.sensor_size)} \
        if fmt == "h5" else {}
    gt_path = _write_pair(Path(args.out), lambda: write_events(args.out, res.events,
                                                               format=fmt, **meta),
                          lambda path: write_ground_truth(path, res.gt,
                                                          events_file=Path(args.out).name))
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
