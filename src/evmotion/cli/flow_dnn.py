"""``evmotion flow FILE --method dnn``: dense flow by the unsupervised EV-FlowNet (§4.3.7).

Same windows, outputs (``.h5`` / ``.npy`` / ``.flo``), pictures and ``--json`` as
``--method multicm``; each window goes through the network once (no warm start needed).
``--checkpoint`` picks weights from ``evmotion train`` (default: the shipped checkpoint).
"""

from __future__ import annotations


def add_arguments(group) -> None:
    group.add_argument("--checkpoint", default=None, metavar="CKPT",
                       help="network weights (default: the shipped checkpoint); also used "
                            "by multicm's --init dnn")
    group.add_argument("--device", default="cpu", help="torch device (default cpu)")
    group.add_argument("--threads", type=int, default=1,
                       help="torch threads (default 1)")


def estimate(events, windows, args) -> list:
    """The network's :class:`~evmotion.methods.multicm.FlowResult` of every window."""
    import torch

    from evmotion.errors import ParameterError
    from evmotion.methods.dnn import estimate_flow_dnn
    from evmotion.utils import progress

    if args.threads < 1:
        raise ParameterError(f"--threads must be >= 1, got {args.threads}")
    torch.set_num_threads(args.threads)
    return [estimate_flow_dnn(events.window(w), args.checkpoint, device=args.device)
            for w in progress(windows, total=len(windows), desc="dnn")]


def run(args) -> int:
    from evmotion.cli import flow_multicm

    return flow_multicm.run(args)
