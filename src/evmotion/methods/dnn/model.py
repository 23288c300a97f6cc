"""Checkpoint files: the network's weights with the configuration needed to rebuild it."""

from __future__ import annotations

import pickle
from pathlib import Path

import torch

from evmotion.errors import ParameterError
from evmotion.methods.dnn.network import EVFlowNet, InferenceNet
from evmotion.utils import atomic_path

__all__ = ["DEFAULT_CHECKPOINT", "load_inference_net", "load_model", "save_model"]

#: The shipped checkpoint (see MODEL_CARD.md beside this module).
DEFAULT_CHECKPOINT = Path(__file__).resolve().parent / "weights" / "evflownet_w0125.pt"

# the last checkpoint loaded (key: path, mtime, device) and its InferenceNet, if made
_CACHE: dict = {}
_FAST: dict = {}


def save_model(path: str | Path, net: EVFlowNet, **meta) -> None:
    """Write the weights (float32) and ``{"n_bins", "width", "norm", "symmetric"}`` plus
    ``meta`` atomically."""
    state = {k: v.detach().cpu().float() if v.is_floating_point() else v.detach().cpu()
             for k, v in net.state_dict().items()}
    with atomic_path(path) as tmp:
        torch.save({"model": state, "n_bins": net.n_bins, "width": net.width,
                    "norm": net.norm, "symmetric": net.symmetric, "meta": meta}, tmp)


def load_model(checkpoint: str | Path | None = None, device: str = "cpu") -> EVFlowNet:
    """The network of a checkpoint (default: the shipped one), in eval mode; cached.

    Accepts the files of :func:`save_model` and the per-epoch training checkpoints of
    ``evmotion train``.
    """
    path, key = _cache_key(checkpoint, device)
    if key in _CACHE:
        return _CACHE[key]
    if not path.is_file():
        raise ParameterError(f"checkpoint {path}: file not found")
    try:
        blob = torch.load(path, map_location=device, weights_only=True)
        # checkpoints written before batch norm and the symmetric network carry neither key
        net = EVFlowNet(n_bins=int(blob["n_bins"]), width=float(blob["width"]),
                        norm=str(blob.get("norm", "none")),
                        symmetric=bool(blob.get("symmetric", False)))
        net.load_state_dict(blob["model"])
    except (RuntimeError, KeyError, ValueError, TypeError, OSError, EOFError,
            AttributeError, pickle.UnpicklingError) as exc:
        raise ParameterError(f"checkpoint {path}: not an evmotion EV-FlowNet checkpoint "
                             f"({type(exc).__name__}: {str(exc).splitlines()[0][:120]})"
                             ) from None
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
    key = _cache_key(checkpoint, device)[1]
    if key not in _FAST:
        _FAST[key] = InferenceNet(load_model(checkpoint, device))
    return _FAST[key]


def _cache_key(checkpoint, device: str) -> tuple[Path, tuple]:
    path = Path(checkpoint) if checkpoint is not None else DEFAULT_CHECKPOINT
    return path, (str(path.resolve()), path.stat().st_mtime_ns if path.exists() else 0,
                  device)
