"""The ``evmotion`` command: one entry point, one module per subcommand.

Each module listed in :data:`COMMANDS` defines ``add_parser(subparsers)`` (registering its
sub-parser with ``set_defaults(func=run)``) and ``run(args) -> int``. Modules import their
heavy dependencies inside ``run`` so that ``evmotion --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys

from evmotion.errors import EvmotionError

COMMANDS: tuple[str, ...] = (
    "info",
    "convert",
    "simulate",
    "view",
    "egomotion",
    "landscape",
    "segment",
    "flow",
    "eval",
    "bos",
    "kymogram",
)

EPILOG = """examples:
  evmotion simulate rotation --out sim.h5           # events + ground truth
  evmotion info sim.h5 --json                       # what a file holds
  evmotion egomotion sim.h5 --warp rotation --reg rcad --out ego/
  evmotion flow sim.h5 --method multicm --out flow.h5
  evmotion flow rec.raw --method triplet --out flow.h5
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="evmotion",
        description="Estimate motion from event cameras.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from evmotion import __version__

    parser.add_argument("--version", action="version", version=f"evmotion {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        try:
            mod = importlib.import_module(f"evmotion.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"evmotion.cli.{name}":
                continue
            raise
        mod.add_parser(sub)
    return parser


def print_json(obj) -> None:
    """Machine-readable summary on stdout (numpy scalars and arrays converted)."""
    import numpy as np

    def default(o):
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        return str(o)

    json.dump(obj, sys.stdout, indent=2, default=default)
    sys.stdout.write("\n")


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except EvmotionError as exc:
        print(f"evmotion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("evmotion: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
