"""``evmotion flow``: optical flow of a recording by one of several methods.

Each method lives in its own CLI module (``FLOW_METHODS``) that defines
``add_arguments(group)`` for its options and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib

FLOW_METHODS: dict[str, str] = {
    "multicm": "evmotion.cli.flow_multicm",
    "dnn": "evmotion.cli.flow_dnn",
    "triplet": "evmotion.cli.flow_triplet",
}

EXAMPLES = """examples:
  evmotion flow sim.h5 --method multicm --window-events 30000 --out flow.h5
  evmotion flow sim.h5 --method multicm --time-aware burgers --out flow.flo
  evmotion flow rec.raw --method triplet --out flow.h5 --json
  evmotion flow window.txt --method dnn --window-events 30000 --out x.flo
"""


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
                   help="output file: .h5 (all windows), .npy or .flo (per window)")
    p.add_argument("--format", default=None, help="input format (default: detect)")
    win = p.add_mutually_exclusive_group()
    win.add_argument("--window-events", type=int, default=None, metavar="N")
    win.add_argument("--window-us", type=int, default=None, metavar="T")
    win.add_argument("--window-gt", default=None, metavar="GT",
                     help="ground-truth file whose timestamps define the windows")
    p.add_argument("--gt-dt", type=int, default=1, help="frames per window with --window-gt")
    p.add_argument("--png-dir", default=None, help="folder for colour-wheel and IWE PNGs")
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    for name, mod in _method_modules():
        mod.add_arguments(p.add_argument_group(f"{name} options"))
    p.set_defaults(func=run)


def run(args) -> int:
    mod = importlib.import_module(FLOW_METHODS[args.method])
    return mod.run(args)
