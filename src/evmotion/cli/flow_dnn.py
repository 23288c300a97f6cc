"""``evmotion flow FILE --method dnn``: dense flow by the unsupervised EV-FlowNet (§4.3.7).

Same windows, outputs (``.h5`` / ``.npz`` / ``.flo`` / ``.png``), pictures, ``--resume`` and ``--json``
as ``--method multicm`` (whose runner it uses); each window goes through the network at
``--input-scales`` (the sharpest kept), each averaged with the time-reversed window's
negated flow unless ``--no-time-reversal`` (no warm start needed), at the gain whose warp
is sharpest unless ``--no-rescale``, the scales' predictions chosen tile by tile unless
``--no-fuse``, replaced by the polished flow of a plane's motion where the training loss
prefers it unless ``--no-planar``, and that flow (the plane's or the network's) refined on
multicm's finest tiles where that loss prefers it and the events are no blurrier unless
``--no-refine``.
``--checkpoint`` picks
weights from ``evmotion train`` (default: the shipped checkpoint); multicm's ``--init dnn``
reads it too.
"""

from __future__ import annotations

from evmotion.cli.options import existing_input, int_range

# the options only this method reads: attribute and default (see evmotion.cli.flow);
# --checkpoint is shared with multicm's --init dnn, so each method checks it itself
OPTIONS: dict[str, tuple[str, object]] = {
    "--device": ("device", "cpu"),
    "--threads": ("threads", 1),
    "--input-scales": ("input_scales", (1, 2, 4, 8)),
    "--no-time-reversal": ("no_time_reversal", False),
    "--no-rescale": ("no_rescale", False),
    "--no-fuse": ("no_fuse", False),
    "--no-planar": ("no_planar", False),
    "--no-refine": ("no_refine", False),
}


INPUT_SCALES = (1, 2, 4, 8, 16)


def _input_scale(text: str) -> int:
    """``--input-scales``' K: 1, 2, 4, 8 or 16 in one message (a range, then a list of
    choices, had each named half of it; probe CI)."""
    import argparse

    try:
        k = int(text)
    except ValueError:
        k = 0
    if k not in INPUT_SCALES:
        raise argparse.ArgumentTypeError(f"each K must be one of "
                                         f"{', '.join(map(str, INPUT_SCALES))}, got {text!r}")
    return k


def add_arguments(group) -> None:
    group.add_argument("--checkpoint", default=None, metavar="CKPT", type=existing_input,
                       help="network weights: a model.pt of evmotion train (needs torch) or "
                            "its .npz export (default: the shipped network); also used "
                            "by multicm's --init dnn")
    group.add_argument("--device", default=None,
                       help="cpu (default; the shipped network runs in numpy, no torch) "
                            "or a torch device such as cuda; also multicm's --init dnn")
    group.add_argument("--threads", type=int_range(1, 256), default=None,
                       help="torch threads where torch runs the network (default 1: "
                            "faster than 2 on a shared 2-core CPU); also multicm's "
                            "--init dnn")
    group.add_argument("--input-scales", type=_input_scale, nargs="+", default=None,
                       metavar="K",
                       help="dnn: also predict from the events binned K times coarser and "
                            "keep the sharpest warp; each K one of 1, 2, 4, 8, 16 (default "
                            "1 2 4 8: far-moving windows; 1 = the network on the sensor's "
                            "grid only)")
    group.add_argument("--no-time-reversal", action="store_true", default=None,
                       help="dnn: do not average with the negated flow of the time-reversed "
                            "window (one pass per scale instead of two)")
    group.add_argument("--no-rescale", action="store_true", default=None,
                       help="dnn: keep the network's magnitude (default: the gain among "
                            "0.7-3.2 whose warp is sharpest)")
    group.add_argument("--no-fuse", action="store_true", default=None,
                       help="dnn: keep one input scale's prediction for the whole window "
                            "(default: the sharpest, tile by tile of 32 px)")
    group.add_argument("--no-planar", action="store_true", default=None,
                       help="dnn: keep the network's flow (default: the polished flow of a "
                            "plane's motion instead where multicm's objective prefers it)")
    group.add_argument("--no-refine", action="store_true", default=None,
                       help="dnn: keep the plane's or the network's flow as it is "
                            "(default: its refinement on multicm's finest tiles where "
                            "multicm's objective prefers it and the events are no blurrier)")


def check_args(args) -> None:
    """The network writes dense windows: .h5, .npz, .flo or .png."""
    from evmotion.cli.options import check_flow_out
    from evmotion.errors import ParameterError

    check_flow_out(args.out)
    if args.resume and args.video:
        raise ParameterError(f"--video {args.video} needs every window's flow: it cannot "
                             "be made with --resume; run without --resume")


def check_network(args) -> None:
    """``--device`` and ``--checkpoint`` checked (the network loaded, and cached for the
    windows) before the recording is read: a wrong one was said after 5 s of reading a
    1280x720 file (probe AP). On the CPU the shipped network runs in numpy: torch is
    needed only for another device or a torch checkpoint (``model.pt``)."""
    from evmotion.methods.dnn.infer import load_network, resolve_backend

    if resolve_backend("auto", args.device, args.checkpoint) == "torch":
        from evmotion.methods.dnn import require_torch

        require_torch(f"the network on torch (--device {args.device!r})")
        from evmotion.methods.dnn.model import check_device

        check_device(args.device, option="--device")  # in the command's words
    load_network(args.checkpoint, args.device)


def estimator(args):
    """``(estimate(events, init) -> FlowResult, attrs)`` for the multicm runner."""
    from evmotion.methods.dnn import estimate_flow_dnn
    from evmotion.methods.dnn.infer import checkpoint_digest, resolve_backend

    # resolved once, and stored with the outputs: every window runs the same arithmetic
    backend = resolve_backend("auto", args.device, args.checkpoint)
    attrs = {"method": "dnn", "checkpoint": str(args.checkpoint or "shipped"),
             "checkpoint_sha1": checkpoint_digest(args.checkpoint, backend),
             "backend": backend,
             "source": str(args.file), "input_scales": list(args.input_scales),
             "time_reversal": not args.no_time_reversal, "rescale": not args.no_rescale,
             "fuse": not args.no_fuse, "planar": not args.no_planar,
             "refine": not args.no_refine}

    # the IWEs and the focus serve only the pictures (--png-dir) and the JSON rows; the
    # flow files do not hold them, and their numba kernels would cost a first run seconds
    # of compilation
    with_iwes = args.png_dir is not None or bool(args.json)

    def estimate(events, init):
        return estimate_flow_dnn(events, args.checkpoint, device=args.device,
                                 backend=backend, with_iwes=with_iwes,
                                 input_scales=tuple(args.input_scales),
                                 time_reversal=not args.no_time_reversal,
                                 rescale=not args.no_rescale, fuse=not args.no_fuse,
                                 planar=not args.no_planar, refine=not args.no_refine,
                                 threads=args.threads)

    return estimate, attrs


def run(args) -> int:
    from evmotion.cli import flow_multicm

    return flow_multicm.run(args)
