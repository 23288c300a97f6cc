"""``evmotion flow``: optical flow of a recording by one of several methods.

Each method lives in its own CLI module (``FLOW_METHODS``) that defines
``add_arguments(group)`` for its options, ``OPTIONS`` (``{"--flag": (attribute,
default)}``: the options only it reads), ``check_args(args)`` (options that do not go
together, seen before the defaults are filled in) and ``run(args) -> int``. An option of another
method is an error, not silently ignored; the defaults are filled in here.

An ``.h5`` output is written window by window to ``OUT.part`` and renamed when complete;
an interrupted or failed run keeps the ``.part`` file, and ``--resume`` continues it (the
same command with ``--resume`` gives the file an uninterrupted run would have written).
"""

from __future__ import annotations

import argparse
import importlib

from evmotion.cli.options import (
    existing_input,
    positive_float,
    positive_int,
    reject_unused,
    writable_folder,
    writable_output,
)
from evmotion.errors import ParameterError

FLOW_METHODS: dict[str, str] = {
    "multicm": "evmotion.cli.flow_multicm",
    "dnn": "evmotion.cli.flow_dnn",
    "triplet": "evmotion.cli.flow_triplet",
}

EXAMPLES = """examples:
  evmotion flow sim.h5 --method multicm --window-events 30000 --out flow.h5
  evmotion flow sim.h5 --method multicm --time-aware burgers --out flow.flo
  evmotion flow rec.raw --method triplet --out flow.h5 --json
  evmotion flow rec.raw --method triplet --dense robust --out flow.h5 --resume
  evmotion flow window.txt --method dnn --window-events 30000 --out x.flo
"""

OUTPUT_SUFFIXES = (".h5", ".hdf5", ".npy", ".flo", ".npz")


def _method_modules():
    for name, modname in FLOW_METHODS.items():
        try:
            yield name, importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise


def add_parser(sub) -> None:
    p = sub.add_parser(
        "flow", help="optical flow (multi-reference CMax, triplet matching, network)",
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("file", help="recording (any readable format)")
    p.add_argument("--method", default="multicm", choices=sorted(FLOW_METHODS))
    p.add_argument("--out", required=True,
                   type=writable_output(OUTPUT_SUFFIXES, "a flow file (.h5, .npy, .flo: dense "
                                        "per window; .npz triplet: per event)"),
                   help="output file: .h5 (all windows), .npy or .flo (per window), .npz "
                        "(triplet: per event)")
    p.add_argument("--format", default=None, help="input format (default: detect)")
    win = p.add_mutually_exclusive_group()
    win.add_argument("--window-events", type=positive_int(), default=None, metavar="N")
    win.add_argument("--window-us", type=positive_int(unit="µs"), default=None, metavar="T")
    win.add_argument("--window-gt", type=existing_input, default=None, metavar="GT",
                     help="ground-truth file whose timestamps define the windows")
    p.add_argument("--gt-dt", type=positive_int(), default=None,
                   help="frames per window with --window-gt (default 1)")
    p.add_argument("--png-dir", type=writable_folder, default=None,
                   help="folder for colour-wheel and IWE PNGs")
    p.add_argument("--resume", action="store_true",
                   help=".h5 output: continue the OUT.part file an interrupted run kept "
                        "(same options), computing only the windows it lacks")
    p.add_argument("--max-speed", type=positive_float(unit="px/s"), default=None,
                   metavar="PX_S",
                   help="speed at the colour wheel's rim in px/s, one scale for every picture "
                        "(default: each picture's own maximum, said so in its legend)")
    p.add_argument("--video", default=None, metavar="MP4", type=writable_output((".mp4",)),
                   help="video of the windows: events | warped IWE | flow (needs the 'video' "
                        "extra; multicm only)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    for name, mod in _method_modules():
        mod.add_arguments(p.add_argument_group(f"{name} options"))
    p.set_defaults(func=run)


def run(args) -> int:
    if args.window_gt is None:
        reject_unused(args, {"--gt-dt": "gt_dt"}, "without --window-gt")
    args.gt_dt = 1 if args.gt_dt is None else args.gt_dt
    if args.resume and args.out.lower().endswith((".npy", ".flo", ".npz")):
        raise ParameterError(f"--resume continues an .h5 output; --out {args.out} is written "
                             "whole at the end (an interrupted run leaves nothing)")
    for name, modname in FLOW_METHODS.items():
        if name != args.method:
            options = importlib.import_module(modname).OPTIONS
            reject_unused(args, {flag: attr for flag, (attr, _) in options.items()},
                          f"with --method {args.method} (a {name} option)")
    mod = importlib.import_module(FLOW_METHODS[args.method])
    mod.check_args(args)  # sees which options were given, before the defaults fill in
    for attr, default in mod.OPTIONS.values():
        if getattr(args, attr, None) is None:
            setattr(args, attr, default)
    return mod.run(args)


class H5Output:
    """An ``.h5`` flow output written window by window to ``OUT.part``
    (:class:`~evmotion.io.flowfiles.FlowWriter`), resumable.

    With ``resume`` it continues ``OUT.part`` (or a finished OUT) after checking that it
    was made with the same ``attrs`` (method, options, source); :attr:`done` lists the
    ``(t0, t1)`` µs of the windows it already holds, which the run must delimit again
    (:meth:`check_done`) but not recompute. :meth:`abort` keeps the ``.part`` file for
    a later ``--resume`` (and puts back a finished OUT it had reopened).
    """

    def __init__(self, out, sensor_size, attrs: dict, *, resume: bool,
                 with_valid: bool = False, compression: str | None = "gzip"):
        from pathlib import Path

        import numpy as np

        from evmotion.io.flowfiles import FlowWriter

        self.out = Path(out)
        self.part = self.out.with_name(self.out.name + ".part")  # FlowWriter's own name
        self.reopened_final = resume and self.out.exists() and not self.part.exists()
        self.done: list[tuple[int, int]] = []
        if not resume:
            self.w = FlowWriter(out, sensor_size, with_valid=with_valid, attrs=attrs,
                                compression=compression)
            return
        self.w = FlowWriter(out, sensor_size, with_valid=with_valid, resume=True)
        old = dict(self.w.f.attrs)
        for key, value in attrs.items():
            if self.w.n_done and key in old and not _same(old[key], value):
                self.abort()
                raise ParameterError(f"--resume: {self.part} was made with {key}="
                                     f"{_shown(old[key])!r}, this run has {value!r}; repeat the "
                                     "options of the first run, or leave out --resume to "
                                     "start again")
            self.w.f.attrs[key] = value
        if self.w.with_valid != with_valid:
            self.abort()
            raise ParameterError(f"--resume: {self.part} has another layout (valid masks: "
                                 f"{self.w.with_valid}); leave out --resume to start again")
        t1 = np.asarray(self.w.f["t1"][: self.w.n_done])
        self.done = list(zip(np.asarray(self.w.done_t0).tolist(), t1.tolist(), strict=True))

    def stored_flow(self, index: int):
        """Flow (H, W, 2) float32 px/s of a window already in the file, as written."""
        import numpy as np

        return np.asarray(self.w.f["flow"][index])

    def check_done(self, index: int, t0: int, t1: int) -> None:
        """Raise ParameterError if window ``index`` of this run is not the ``index``-th
        window of the resumed file (other windowing options, or another recording)."""
        if index >= len(self.done):
            self.abort()
            raise ParameterError(f"--resume: this run skipped window {index}, which "
                                 f"{self.part} does not hold")
        if (int(t0), int(t1)) != tuple(self.done[index]):
            self.abort()
            a, b = self.done[index]
            raise ParameterError(f"--resume: window {index} of {self.part} is [{a}, {b}) µs but "
                                 f"this run makes [{t0}, {t1}) µs; repeat the windowing options "
                                 "of the first run, or leave out --resume to start again")

    def check_count(self, n_windows: int) -> None:
        """The run made ``n_windows``: the resumed file must not hold more."""
        if len(self.done) > n_windows:
            self.abort()
            raise ParameterError(f"--resume: {self.part} holds {len(self.done)} windows, this "
                                 f"run makes {n_windows}; repeat the options of the first run, "
                                 "or leave out --resume to start again")

    def append(self, flow, t0: int, t1: int, valid=None) -> None:
        self.w.append(flow, t0, t1, valid=valid)

    def close(self) -> None:
        self.w.close()

    def abort(self) -> None:
        import os

        self.w.abort()
        if self.reopened_final and self.part.exists():
            os.replace(self.part, self.out)
            self.reopened_final = False


def _shown(value):
    return value.item() if hasattr(value, "item") else value


def _same(a, b) -> bool:
    import numpy as np

    if isinstance(a, bytes):
        a = a.decode(errors="replace")
    try:
        return bool(np.array_equal(np.asarray(a), np.asarray(b)))
    except (TypeError, ValueError):
        return str(a) == str(b)
