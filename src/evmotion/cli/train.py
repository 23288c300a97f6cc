"""``evmotion train``: train EV-FlowNet unsupervised with multicm's objective (§4.3.7).

Data: recordings (any readable format; no ground truth needed) cut into windows of
``--window-events`` events, and/or ``--sim-windows`` simulated windows per epoch (random
scenes of every motion kind, an independently moving object, random textures and noise),
each randomly cropped to ``--crop``. Adam, learning rate ``--lr`` times ``--lr-decay``
after every epoch. Deterministic for a given ``--seed`` and ``--threads``.

Writes to ``--out DIR``: ``last.pt`` (after every epoch, atomically; ``--resume``
continues from it and ends with the same weights as an uninterrupted run), ``model.pt``
(the weights for ``evmotion flow --method dnn --checkpoint``) and ``model.npz`` (the
same network for the numpy backend: no torch import), ``best.pt`` and ``best.npz`` (the
same for the epoch of the lowest validation loss; with validation windows), ``steps.csv``,
``epochs.csv`` (training loss, validation loss / FWL / AEE) and ``loss.png``. A DIR that
already holds a training is refused without ``--resume`` (a new run would overwrite it).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from evmotion.catalog import (
    MAX_CROP_SIDE,
    MAX_EPOCHS,
    MAX_LR,
    MAX_TRAIN_SEED,
    MAX_WIDTH,
    MIN_CROP_SIDE,
)
from evmotion.cli.options import (
    HelpFormatter,
    add_sensor_size_argument,
    event_format,
    existing_input,
    finite_float,
    int_range,
    nonnegative_float,
    positive_int,
    writable_folder,
)

EXAMPLES = """examples:
  evmotion train --sim-windows 4 --epochs 1 --out runs/sim      # a smoke run (64 and 10 for real)
  evmotion train rec1.raw rec2.aedat4 --sim-windows 0 --epochs 1 --val val.h5 --out runs/mix
  evmotion train --sim-windows 4 --epochs 2 --out runs/sim --resume   # one more epoch
(a progress bar with the loss and ETA shows on a terminal, EVMOTION_PROGRESS=1 forces it
and 0 hides it; each epoch's line is printed either way, in a log too.)
"""


def _size(text: str) -> tuple[int, int]:
    from evmotion.methods.dnn.voxel import PAD_MULTIPLE

    try:
        h, w = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HxW, got {text!r}") from None
    if not (MIN_CROP_SIDE <= h <= MAX_CROP_SIDE and MIN_CROP_SIDE <= w <= MAX_CROP_SIDE) \
            or h % PAD_MULTIPLE or w % PAD_MULTIPLE:
        raise argparse.ArgumentTypeError(f"each side must be a multiple of {PAD_MULTIPLE} "
                                         f"(the network halves it 4 times) from "
                                         f"{MIN_CROP_SIDE} to {MAX_CROP_SIDE} px, got {text!r}")
    return h, w


def add_parser(sub) -> None:
    p = sub.add_parser("train", help="train the unsupervised flow network (EV-FlowNet)",
                       description=__doc__, epilog=EXAMPLES,
                       formatter_class=HelpFormatter)
    p.add_argument("recordings", nargs="*", type=existing_input, help="training recordings (any readable format)")
    p.add_argument("--out", required=True,
                   type=writable_folder("model.pt, model.npz, last.pt, steps.csv, "
                                        "epochs.csv and loss.png"),
                   help="output folder")
    p.add_argument("--format", type=event_format, default=None,
                   help="format of the recordings (default: detected per file)")
    add_sensor_size_argument(p)
    p.add_argument("--sim-windows", type=int_range(0, 9999), default=64,
                   help="simulated windows per epoch (default 64; 0: recordings only)")
    p.add_argument("--epochs", type=int_range(1, MAX_EPOCHS), default=10,
                   help=f"passes over the data (default 10, at most {MAX_EPOCHS}; with "
                        "--resume, the total)")
    p.add_argument("--batch-size", type=int_range(1, 4096), default=8,
                   help="windows per step (default 8)")
    p.add_argument("--lr", type=finite_float(0, MAX_LR, lo_open=True), default=1e-3,
                   help="Adam learning rate (default 0.001, at most 1)")
    p.add_argument("--lr-decay", type=finite_float(0, 1, lo_open=True), default=0.8,
                   help="per epoch (default 0.8)")
    p.add_argument("--width", type=finite_float(0, MAX_WIDTH, lo_open=True), default=0.125,
                   help=f"channel multiplier in (0, {MAX_WIDTH:g}] (1 = the paper's EV-FlowNet, "
                        "14 M parameters; default 0.125)")
    p.add_argument("--window-events", type=int_range(100), default=40_000, metavar="N",
                   help="events per training window (default 40000, the thesis')")
    p.add_argument("--crop", type=_size, default=(176, 240), metavar="HxW",
                   help="training crop, multiples of 16 (default 176x240)")
    p.add_argument("--sim-duration", type=finite_float(1e-6, 10, unit="s"),
                   default=0.05, metavar="S",
                   help="length of each simulated recording in s; the window is its middle "
                        "--window-events events (scaled to the crop), fewer if it has fewer "
                        "(default 0.05)")
    p.add_argument("--transpose", action="store_true",
                   help="mirror half the training windows about the diagonal (x <-> y) so that "
                        "both flow components get the same statistics (for --no-symmetric: "
                        "the symmetric network already sees every window both ways)")
    p.add_argument("--init", default="default", choices=("default", "kaiming"),
                   help="convolution weight initialization (default: torch's; kaiming: "
                        "He-normal, zero biases: keeps the ReLUs alive)")
    p.add_argument("--norm", default="batch", choices=("batch", "none"),
                   help="normalization after each convolution (default batch: EV-FlowNet's)")
    p.add_argument("--symmetric", action=argparse.BooleanOptionalAction, default=True,
                   help="one set of weights for both axes: v is u of the input mirrored about "
                        "the diagonal (default; --no-symmetric: two output channels)")
    p.add_argument("--objective", default="gradient_magnitude",
                   choices=("gradient_magnitude", "variance", "avg_timestamp",
                            "avg_timestamp_norm"),
                   help="focus of the training loss (default gradient_magnitude, the "
                        "thesis' (4.9); variance and the two average-timestamp losses are "
                        "Table 4.5's ablations, the latter collapse)")
    p.add_argument("--lambda", dest="lam", type=nonnegative_float(), default=0.0025,
                   help="Charbonnier smoothness weight (default 0.0025, multicm's)")
    p.add_argument("--val", action="append", default=[], metavar="REC", type=existing_input,
                   help="validation recording (repeatable): its FWL per epoch (val_rec_FWL; "
                        "val_FWL is over these and the simulated ones)")
    p.add_argument("--val-sim", type=int_range(0, 9999), default=4,
                   help="held-out simulated validation windows (AEE and FWL; default 4)")
    p.add_argument("--max-steps", type=positive_int(), default=None,
                   help="at most this many steps per epoch")
    p.add_argument("--seed", type=int_range(0, MAX_TRAIN_SEED - 1), default=0,
                   help="seed of the initial weights, the simulated windows and the crops "
                        f"(default 0, below {MAX_TRAIN_SEED}; the same seed gives the same "
                        "weights)")
    p.add_argument("--threads", type=int_range(1, 256), default=1,
                   help="torch threads (default 1: faster than 2 on a loaded 2-core machine)")
    p.add_argument("--device", default="cpu", help="torch device (cpu, cuda)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--init-weights", default=None, metavar="CKPT", type=existing_input,
                   help="start from these weights (fine-tuning; same --width)")
    p.add_argument("--json", action="store_true", help="print the last epoch as JSON")
    p.set_defaults(func=run)


def _say_unfinished_model(out: Path, epochs: int) -> None:
    """After an interruption: which epoch's network ``model.pt`` / ``model.npz`` hold (they
    looked like a finished training's, and flow took them without a word; probe BP)."""
    from evmotion.utils import set_interrupt_note

    log = out / "epochs.csv"
    done = max(0, len(log.read_text().splitlines()) - 1) if log.is_file() else 0
    if not (out / "model.pt").is_file() or done >= epochs:
        return
    # (it said "after epoch 1 of 3" where epochs.csv numbers that epoch 0, probe CE)
    set_interrupt_note(f"model.pt and model.npz there are the network after {done} of "
                       f"{epochs} epochs (epochs.csv's epoch {done - 1}), not a finished "
                       "training's; run the same command with --resume to continue", "")


def _above_the_bar(line: str) -> None:
    """An epoch's line on stderr, above the progress bar (printed plainly it was glued to
    the end of the bar's line)."""
    from tqdm.auto import tqdm

    tqdm.write(line, file=sys.stderr)


def run(args) -> int:
    from evmotion.cli import print_json
    from evmotion.cli.options import reject_unused, warn_replaced_sensor_size
    from evmotion.io.registry import get_format
    from evmotion.methods.dnn import require_torch
    from evmotion.methods.dnn.folder import check_training_folder
    from evmotion.utils import keep_for_resume

    t_start = time.perf_counter()
    if not args.recordings and not args.val:
        # (--format bogus with no recording to read had passed, exit 0; probe)
        reject_unused(args, {"--format": "format", "--sensor-size": "sensor_size"},
                      "without recordings to read (they apply to the recordings and --val)")
    if args.format is not None:
        get_format(args.format)  # an unknown name, said before any work
    for path in [*args.recordings, *args.val]:
        warn_replaced_sensor_size(args, path)
    check_training_folder(args.out, args.resume)  # before torch's import: seconds
    require_torch("evmotion train")
    from evmotion.methods.dnn.model import check_device
    from evmotion.methods.dnn.train import TrainConfig, train

    check_device(args.device, option="--device")  # in the command's words

    cfg = TrainConfig(width=args.width, epochs=args.epochs, batch_size=args.batch_size,
                      lr=args.lr, lr_decay=args.lr_decay, sim_windows=args.sim_windows,
                      recordings=list(args.recordings), val_sim=args.val_sim,
                      val_recordings=list(args.val), window_events=args.window_events,
                      crop=tuple(args.crop), sim_duration_s=args.sim_duration,
                      transpose=args.transpose, init=args.init, norm=args.norm,
                      symmetric=args.symmetric,
                      objective=args.objective, lam=args.lam,
                      seed=args.seed, threads=args.threads, device=args.device,
                      max_steps_per_epoch=args.max_steps, init_weights=args.init_weights,
                      read_format=args.format,
                      sensor_size=tuple(args.sensor_size) if args.sensor_size else None)
    # the bar as evmotion.utils.progress draws it: on a terminal, or EVMOTION_PROGRESS=1;
    # in a log the epochs' lines stand for its lines
    env = os.environ.get("EVMOTION_PROGRESS")
    bar = env == "1" or (env != "0" and sys.stderr.isatty())
    existed = Path(args.out).exists()
    try:
        summary = train(cfg, args.out, resume=args.resume, show_progress=bar,
                        log=_above_the_bar)
    except KeyboardInterrupt:
        out = Path(args.out)
        last = out / "last.pt"
        if last.exists():
            keep_for_resume(last)
            _say_unfinished_model(out, args.epochs)
        elif out.is_dir() and not any(out.iterdir()) and not existed:
            out.rmdir()  # interrupted before its first epoch: nothing to keep
        raise
    model = Path(args.out) / "model.pt"
    best = summary.pop("best_epoch", None)
    if args.json:
        # "seconds" stays the last epoch's (as epochs.csv has it); the whole run apart
        print_json({**summary, "model": str(model), "out": str(args.out),
                    "best_epoch": best,
                    "best": None if best is None else str(Path(args.out) / "best.pt"),
                    "total_seconds": time.perf_counter() - t_start})
    else:
        done = int(summary.get("epoch", -1)) + 1
        loss = summary.get("train_loss", float("nan"))
        steps = int(summary.get("step", 0))
        print(f"{done} epoch{'' if done == 1 else 's'}, {steps:,} step{'' if steps == 1 else 's'}, "
              f"last training loss {loss:.4g}, {time.perf_counter() - t_start:.1f} s -> "
              f"{model} (evmotion flow --method dnn --checkpoint {model})"
              + ("" if best is None else f"; lowest validation loss at epoch {best}: "
                                         f"{Path(args.out) / 'best.pt'}"))
    return 0
