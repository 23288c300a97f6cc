"""Checkpoint files: the network's weights with the configuration needed to rebuild it."""

from __future__ import annotations

from pathlib import Path

import torch

from evmotion.errors import ParameterError
from evmotion.methods.dnn.network import EVFlowNet, InferenceNet
from evmotion.methods.dnn.numpynet import checkpoint_key
from evmotion.utils import atomic_path

__all__ = ["DEFAULT_CHECKPOINT", "check_device", "damaged_archive", "load_inference_net",
           "load_model", "save_model"]

#: The shipped checkpoint (see MODEL_CARD.md beside this module).
DEFAULT_CHECKPOINT = Path(__file__).resolve().parent / "weights" / "evflownet_w0125.pt"

# the last checkpoint loaded (key: path, mtime, device) and its InferenceNet, if made
_CACHE: dict = {}
_FAST: dict = {}


def check_device(device: str, option: str = "device") -> str:
    """``device`` as torch spells it, once checked that this machine has it: ``"cpu"``,
    ``"cuda"`` or ``"cuda:N"`` (``"mps"`` on Apple silicon).

    Raises :class:`~evmotion.errors.ParameterError` naming the device when torch does not
    know it or this torch build or machine lacks it (a CPU-only wheel asked for ``cuda``),
    in the caller's words: ``option`` is the keyword (``device='gpu'``) or, starting with
    ``--``, the command-line option (``--device 'gpu'``).

    Examples
    --------
    >>> check_device("cpu"), check_device("cpu:0")
    ('cpu', 'cpu')
    >>> check_device("gpu")
    Traceback (most recent call last):
    evmotion.errors.ParameterError: device='gpu': not a torch device (cpu, cuda, cuda:N)
    """
    cli = option.startswith("--")
    said = f"{option} {device!r}" if cli else f"{option}={device!r}"
    on_cpu = f"use {option} cpu" if cli else f"use {option}='cpu'"
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError, ValueError):
        raise ParameterError(f"{said}: not a torch device (cpu, cuda, cuda:N)") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            why = ("a CPU-only build" if torch.version.cuda is None
                   else "no CUDA device is visible")
            raise ParameterError(f"{said}: torch {torch.__version__} is {why}; {on_cpu}")
        n = torch.cuda.device_count()
        if dev.index is not None and dev.index >= n:
            raise ParameterError(f"{said}: this machine has {n} CUDA "
                                 f"device(s), cuda:0 to cuda:{n - 1}")
    elif dev.type == "mps":
        if not torch.backends.mps.is_available():
            raise ParameterError(f"{said}: MPS is not available here; {on_cpu}")
    elif dev.type != "cpu":
        raise ParameterError(f"{said}: evmotion runs on cpu, cuda or mps")
    else:
        return "cpu"  # torch.load cannot map storages to "cpu:0"
    return str(dev)


def save_atomically(obj, path: str | Path) -> None:
    """``torch.save(obj)`` to ``path`` through a temporary file. torch's zip writer fails
    on a full device with a RuntimeError ('unexpected pos ...') that names no cause: with
    under 1 MiB left beside ``path`` it becomes an OSError ENOSPC (one line on the CLI)."""
    import errno
    import shutil

    with atomic_path(path) as tmp:
        try:
            # to an open file: torch names the archive's folder after a path it is given,
            # which was the temporary's (".model.pt.vm-25905.b7_xdk7f.part/data/30" in a
            # damaged file's message, probe AP)
            with open(tmp, "wb") as fh:
                torch.save(obj, fh)
        except RuntimeError as exc:
            if shutil.disk_usage(Path(path).resolve().parent).free >= 1 << 20:
                raise
            raise OSError(errno.ENOSPC, f"no space left on the device writing {path}") \
                from exc


def save_model(path: str | Path, net: EVFlowNet, **meta) -> None:
    """Write the weights (float32) and ``{"n_bins", "width", "norm", "symmetric"}`` plus
    ``meta`` atomically."""
    state = {k: v.detach().cpu().float() if v.is_floating_point() else v.detach().cpu()
             for k, v in net.state_dict().items()}
    save_atomically({"model": state, "n_bins": net.n_bins, "width": net.width,
                     "norm": net.norm, "symmetric": net.symmetric, "meta": meta}, path)


def load_model(checkpoint: str | Path | None = None, device: str = "cpu") -> EVFlowNet:
    """The network of a checkpoint (default: the shipped one), in eval mode; cached.

    Accepts the files of :func:`save_model`: the ``model.pt`` that ``evmotion train``
    writes after every epoch (its ``last.pt``, the training's state for ``--resume``, is
    refused, naming the ``model.pt`` beside it).
    """
    device = check_device(device)
    path, key = _cache_key(checkpoint, device)
    if key in _CACHE:
        return _CACHE[key]
    if path.is_dir():
        inside = " (give the model.pt in it)" if (path / "model.pt").is_file() else ""
        raise ParameterError(f"checkpoint {path}: is a folder, not a checkpoint file{inside}")
    if not path.is_file():
        raise ParameterError(f"checkpoint {path}: " + ("not a regular file" if path.exists()
                                                       else "no such file"))
    if path.suffix.lower() == ".npz":
        # (torch's error was "[enforce fail at inline_container.cc:180] ...", probe BG)
        raise ParameterError(f"checkpoint {path}: the numpy export of a network, which "
                             "torch does not load: give the model.pt beside it")
    damaged = damaged_archive(path)
    if damaged:
        raise ParameterError(f"checkpoint {path}: damaged ({damaged}); copy it again or "
                             "retrain")
    try:
        blob = torch.load(path, map_location=device, weights_only=True)
    except Exception as exc:  # torch.load raises many types for files it cannot read
        hint = ("; the training state (last.pt) needs the trusted loader: give the model.pt "
                "beside it") if path.name == "last.pt" else ""
        raise ParameterError(f"checkpoint {path}: not an evmotion EV-FlowNet checkpoint "
                             f"({_load_failure(path, exc)}){hint}") from None
    if isinstance(blob, dict) and {"config", "optimizer", "model"} <= set(blob):
        raise ParameterError(f"checkpoint {path}: a training's state (for train --resume), "
                             f"not its network: give the model.pt beside it")
    if not isinstance(blob, dict) or not {"n_bins", "width", "model"} <= set(blob):
        raise ParameterError(f"checkpoint {path}: not an evmotion EV-FlowNet checkpoint (no "
                             "'n_bins', 'width' and 'model' entries: write it with "
                             "evmotion train)")
    try:
        # checkpoints written before batch norm and the symmetric network carry neither key
        net = EVFlowNet(n_bins=int(blob["n_bins"]), width=float(blob["width"]),
                        norm=str(blob.get("norm", "none")),
                        symmetric=bool(blob.get("symmetric", False)))
    except Exception as exc:  # settings no network has (width -1 was named without the file)
        raise ParameterError(f"checkpoint {path}: its settings make no network "
                             f"({_reason(exc)})") from None
    try:
        mismatch = _first_mismatch(net.state_dict(), blob["model"])
        if mismatch:
            raise ParameterError(f"checkpoint {path}: its weights do not make the network it "
                                 f"names (width {float(blob['width']):g}, {int(blob['n_bins'])} "
                                 f"time bins): {mismatch}")
        net.load_state_dict(blob["model"])
    except ParameterError:
        raise
    except Exception as exc:  # shapes, names or values that do not make the network
        raise ParameterError(f"checkpoint {path}: not an evmotion EV-FlowNet checkpoint "
                             f"({_reason(exc)})") from None
    net.to(device).eval()
    _CACHE.clear()
    _FAST.clear()
    _CACHE[key] = net
    return net


def load_inference_net(checkpoint: str | Path | None = None,
                       device: str = "cpu") -> InferenceNet:
    """The :class:`~evmotion.methods.dnn.network.InferenceNet` of a checkpoint (default:
    the shipped one), which computes its finest flow faster; cached like :func:`load_model`.
    """
    key = _cache_key(checkpoint, check_device(device))[1]
    if key not in _FAST:
        _FAST[key] = InferenceNet(load_model(checkpoint, device))
    return _FAST[key]


def damaged_archive(path: Path) -> str | None:
    """What is damaged in the zip archive ``torch.save`` wrote (a member whose CRC fails:
    torch does not check them, and loaded a checkpoint with 400 flipped bytes as other
    weights), or None (intact, or not a zip archive: torch.load says what it is)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()
    except (zipfile.BadZipFile, OSError, EOFError, ValueError):
        return None
    except Exception as exc:  # a corrupt header (zlib, struct) raises where it is read
        return _reason(exc)
    return None if bad is None else f"member {bad} fails its CRC check"


def _first_mismatch(expected: dict, stored) -> str | None:
    """The first tensor of ``stored`` (a state dict) whose name or shape differs from the
    network's, said with both shapes, or None."""
    if not isinstance(stored, dict):
        return f"'model' is a {type(stored).__name__}, not a state dict"
    for name, tensor in expected.items():
        if name not in stored:
            return f"no tensor {name}"
        got = tuple(getattr(stored[name], "shape", ()))
        if got != tuple(tensor.shape):
            return f"{name} is {list(got)} in the file, {list(tensor.shape)} in the network"
    extra = sorted(set(stored) - set(expected))
    return f"unexpected tensor {extra[0]}" if extra else None


def _load_failure(path: Path, exc: BaseException) -> str:
    """Why torch could not load ``path``: a file that is no PyTorch archive at all (torch's
    own message is then a paragraph about ``weights_only``) or what torch said."""
    import zipfile

    with open(path, "rb") as fh:
        head = fh.read(4)
    if not zipfile.is_zipfile(path) and head[:1] != b"\x80":  # torch archives, old pickles
        if head == b"PK\x03\x04":
            # the start of a zip archive without its end (its central directory)
            return "truncated or damaged: the start of a PyTorch archive without its end"
        return "not a PyTorch file: torch.save writes a zip archive"
    return _reason(exc)


def _reason(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text[:160]}" if text else type(exc).__name__


def _cache_key(checkpoint, device: str) -> tuple[Path, tuple]:
    path, key = checkpoint_key(checkpoint, DEFAULT_CHECKPOINT)
    return path, (*key, device)
