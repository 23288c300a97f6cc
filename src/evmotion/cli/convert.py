"""``evmotion convert``: copy events from one format to another, streaming.

The input format is detected by content, the output format follows the extension of OUT
(``.h5`` evmotion HDF5, ``.txt`` ECD text, ``.npz``, ``.raw``, ``.dat``, ``.aedat4``...)
unless given. Events go chunk by chunk for the streaming writers (``h5``, ``ecd``), so a
file of any size converts in bounded memory; the output appears only when complete.
"""

from __future__ import annotations

import argparse

from evmotion.cli.options import int_range, positive_int, writable_output

EXAMPLES = """examples:
  evmotion convert boxes_rotation/ boxes.h5                  # ECD folder -> evmotion HDF5
  evmotion convert rec.raw rec.h5 --t0 0 --t1 2000000         # first 2 s of an EVT3 file
  evmotion convert events.h5 out.txt --format-in dsec --json
"""


def add_parser(sub) -> None:
    p = sub.add_parser(
        "convert", help="convert events between formats (streaming, atomic output)",
        description=__doc__, epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("input", help="recording (file or ECD folder)")
    p.add_argument("output", type=writable_output(),
                   help="output file; its extension picks the format")
    p.add_argument("--format-in", default=None, help="input format (default: detect)")
    p.add_argument("--format-out", default=None, help="output format (default: extension)")
    p.add_argument("--t0", type=int_range(0, unit="µs"), default=None, metavar="US",
                   help="start, absolute µs")
    p.add_argument("--t1", type=int_range(0, unit="µs"), default=None, metavar="US",
                   help="end (exclusive), absolute µs")
    p.add_argument("--sensor-size", type=positive_int(unit="px"), nargs=2, default=None,
                   metavar=("H", "W"),
                   help="override the input sensor size (height width)")
    p.add_argument("--chunk-events", type=positive_int(), default=1_000_000,
                   help="events read and written at a time (1,000,000)")
    p.add_argument("--json", action="store_true", help="print a JSON summary on stdout")
    p.set_defaults(func=run)


def run(args) -> int:
    import time
    from pathlib import Path

    import evmotion.io as eio
    from evmotion.cli import print_json
    from evmotion.errors import ParameterError
    from evmotion.utils import progress

    src, dst = Path(args.input), Path(args.output)
    if args.t0 is not None and args.t1 is not None and args.t1 <= args.t0:
        raise ParameterError(f"--t1 {args.t1} µs must be after --t0 {args.t0} µs")
    if src.resolve() == dst.resolve():
        raise ParameterError(f"input and output are the same file: {src}")
    fmt_in = args.format_in or eio.detect_format(src)
    fmt_out = args.format_out or eio.format_for_output(dst)
    kw = {}
    if args.sensor_size is not None:
        kw["sensor_size"] = tuple(args.sensor_size)
    counted = {"n": 0, "t_first": None, "t_last": None}

    def chunks():
        it = eio.iter_events(src, args.chunk_events, format=fmt_in, t0=args.t0, t1=args.t1,
                             **kw)
        for chunk in progress(it, desc="convert", unit="chunk"):
            if len(chunk):
                counted["n"] += len(chunk)
                if counted["t_first"] is None:
                    counted["t_first"] = int(chunk.t[0])
                counted["t_last"] = int(chunk.t[-1])
            yield chunk

    opts = {}
    if fmt_out == "h5":
        opts["provenance"] = {"tool": "evmotion convert", "source": str(src),
                              "source_format": fmt_in, "t0": args.t0, "t1": args.t1}
    start = time.perf_counter()
    it = chunks()
    first = next(it, None)
    if first is None:
        raise ParameterError(f"{src}: no events in the requested range "
                             f"[{args.t0}, {args.t1}) us; nothing written")

    def all_chunks():
        yield first
        yield from it

    eio.write_events(dst, all_chunks(), format=fmt_out, **opts)
    summary = {"input": str(src), "format_in": fmt_in, "output": str(dst),
               "format_out": fmt_out, "n_events": counted["n"],
               "t_first_us": counted["t_first"], "t_last_us": counted["t_last"],
               "seconds": round(time.perf_counter() - start, 3)}
    if args.json:
        print_json(summary)
    else:
        print(f"wrote {counted['n']:,} events ({fmt_in} -> {fmt_out}) to {dst}")
    return 0
