"""What a training's output folder holds, and whether a new run may write there (no torch:
``evmotion train`` refuses a taken folder before it imports torch, seconds earlier)."""

from __future__ import annotations

import os
from pathlib import Path

from evmotion.errors import ParameterError

__all__ = ["OUTPUT_NAMES", "check_training_folder"]

# what a training writes besides last.pt
OUTPUT_NAMES = ("model.pt", "model.npz", "best.pt", "best.npz", "steps.csv", "epochs.csv",
                "loss.png")


def check_training_folder(out_dir: str | os.PathLike, resume: bool = False) -> None:
    """Raise ParameterError when a run writing into ``out_dir`` would overwrite another
    training's files: its ``last.pt`` (unless ``resume``), or outputs without one.

    Examples
    --------
    >>> check_training_folder("no-such-training")
    >>> Path("old-run").mkdir(); Path("old-run/model.pt").touch()
    >>> check_training_folder("old-run")
    Traceback (most recent call last):
    ...
    evmotion.errors.ParameterError: --out old-run holds model.pt but no training (last.pt): a run would overwrite them; choose another --out or move them
    """
    out = Path(out_dir)
    last = out / "last.pt"
    if not resume and last.exists():
        # a fresh run would overwrite that training's checkpoints at its first epoch
        raise ParameterError(f"--out {out} already holds a training ({last}): add --resume "
                             "to continue it, or choose another --out")
    theirs = sorted(n for n in OUTPUT_NAMES if (out / n).exists()) if not last.exists() else []
    if theirs:
        raise ParameterError(f"--out {out} holds {', '.join(theirs)} but no training "
                             "(last.pt): a run would overwrite them; choose another --out "
                             "or move them")
