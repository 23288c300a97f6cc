"""The trained network's finest flow in numpy, for inference on the CPU without torch.

A one-window command spent 2.0-2.4 s of its 4-6 s importing torch (probe AV, the
twenty-fifth session's profile); the network itself is 0.07 s of it. This module holds
:class:`~evmotion.methods.dnn.network.InferenceNet`'s arithmetic -- batch norms folded,
each decoder level one 3 x 3 convolution with four sub-pixel phases per channel, heads on
the phases -- over plain arrays, channels first: a 3 x 3 convolution is one matrix product
of the weights and the input's nine shifted copies (im2col, rows of whole image lines, which
numpy copies fast). It matches the torch network to float32 rounding and runs at
0.9-1.2x its speed on one core (``benchmarks/results/dnn.md``).

The shipped checkpoint's weights are exported beside it as ``.npz``
(:func:`export_checkpoint`, tested equal to the ``.pt``); a ``.pt`` from
``evmotion train`` is converted through torch on first use.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from evmotion.errors import ParameterError

__all__ = ["SHIPPED_EXPORT", "NumpyNet", "checkpoint_key", "export_checkpoint", "load_numpy_net",
           "save_export"]

#: The shipped checkpoint's export (see :func:`export_checkpoint`).
SHIPPED_EXPORT = Path(__file__).resolve().parent / "weights" / "evflownet_w0125.npz"
#: Floats of the nine shifted copies one band of a convolution holds (1 MiB).
_BAND_FLOATS = 1 << 18

_CACHE: dict = {}


def _conv3(x: np.ndarray, w: np.ndarray, b: np.ndarray, stride: int = 1) -> np.ndarray:
    """3 x 3 convolution, zero padding 1: ``x`` (C, B, H, W), ``w`` (O, 9 C) with its taps
    ordered (row, column, channel), ``b`` (O,); (O, B, H', W'). In bands of output rows
    whose nine shifted copies fit the CPU's cache (:data:`_BAND_FLOATS`), one buffer
    reused: made whole, those copies were 50 MB at 640x480 and the layer memory-bound
    (42 ms, against 7 ms at 346x260 for a third of the pixels)."""
    c, n, h, wd = x.shape
    pad = np.zeros((c, n, h + 2, wd + 2), np.float32)
    pad[:, :, 1:-1, 1:-1] = x
    ho, wo = (h - 1) // stride + 1, (wd - 1) // stride + 1
    out = np.empty((w.shape[0], n, ho, wo), np.float32)
    band = max(1, min(ho, _BAND_FLOATS // (9 * c * n * wo)))
    buf = np.empty(9 * c * n * band * wo, np.float32)
    for r0 in range(0, ho, band):
        rows = min(band, ho - r0)
        cols = buf[:9 * c * n * rows * wo].reshape(3, 3, c, n, rows, wo)
        for i in range(3):
            for j in range(3):
                top = i + stride * r0
                cols[i, j] = pad[:, :, top:top + stride * (rows - 1) + 1:stride,
                                 j:j + stride * (wo - 1) + 1:stride]
        out[:, :, r0:r0 + rows] = (w @ cols.reshape(9 * c, -1)).reshape(-1, n, rows, wo)
    out += b[:, None, None, None]
    return out


def _shuffle(y: np.ndarray) -> np.ndarray:
    """Pixel shuffle, channels first: (4 C, B, h, w), channel ``c * 4 + 2 a + b`` the phase
    ``(a, b)``, to (C, B, 2 h, 2 w)."""
    c4, n, h, w = y.shape
    c = c4 // 4
    return y.reshape(c, 2, 2, n, h, w).transpose(0, 3, 4, 1, 5, 2).reshape(c, n, 2 * h, 2 * w)


def _relu(x: np.ndarray) -> np.ndarray:
    return np.maximum(x, 0.0, out=x)


class NumpyNet:
    """The finest flow of a trained EV-FlowNet from its exported arrays (inference only).

    Parameters
    ----------
    arrays : dict of str to ndarray
        What :func:`export_checkpoint` writes: ``n_bins``, ``symmetric`` and, per layer,
        ``enc{i}_w`` / ``enc{i}_b`` (4), ``res{i}_w1`` ... ``res{i}_b2`` (2),
        ``dec{i}_w`` / ``dec{i}_b`` and ``head{i}_w`` / ``head{i}_b`` (4), convolution
        weights as (out, 9 in) with taps ordered (row, column, channel).

    Examples
    --------
    >>> net = load_numpy_net()
    >>> net(np.zeros((1, net.n_bins, 32, 48), np.float32)).shape
    (1, 2, 32, 48)
    """

    def __init__(self, arrays: dict):
        def f(key: str) -> np.ndarray:
            return np.ascontiguousarray(arrays[key], np.float32)

        self.n_bins = int(arrays["n_bins"])
        self.symmetric = bool(arrays["symmetric"])
        self.width = float(arrays["width"])
        self.enc = [(f(f"enc{i}_w"), f(f"enc{i}_b")) for i in range(4)]
        self.res = [tuple(f(f"res{i}_{k}") for k in ("w1", "b1", "w2", "b2")) for i in range(2)]
        self.dec = [(f(f"dec{i}_w"), f(f"dec{i}_b")) for i in range(4)]
        self.heads = [(f(f"head{i}_w"), f(f"head{i}_b")) for i in range(4)]

    def __call__(self, voxel: np.ndarray) -> np.ndarray:
        """The finest flow ``(B, 2, H, W)`` in px per window of a voxel grid
        ``(B, n_bins, H, W)`` (H, W multiples of 16)."""
        x = np.ascontiguousarray(np.swapaxes(voxel, 0, 1), np.float32)   # (C, B, H, W)
        if not self.symmetric:
            return np.swapaxes(self._finest(x), 0, 1)
        # u from the direct pass, v the mirrored pass's u mirrored back
        direct = self._finest(x)
        mirrored = self._finest(np.ascontiguousarray(np.swapaxes(x, 2, 3)))
        flow = np.concatenate([direct[:1], np.swapaxes(mirrored[:1], 2, 3)], 0)
        return np.ascontiguousarray(np.swapaxes(flow, 0, 1))

    def _finest(self, x: np.ndarray) -> np.ndarray:
        skips = []
        for w, b in self.enc:
            x = _relu(_conv3(x, w, b, 2))
            skips.append(x)
        for w1, b1, w2, b2 in self.res:
            x = _relu(x + _conv3(_relu(_conv3(x, w1, b1)), w2, b2))
        flow = None
        last = len(self.dec) - 1
        for i, ((w, b), (hw, hb)) in enumerate(zip(self.dec, self.heads, strict=True)):
            parts = [x, skips[last - i]] + ([flow] if flow is not None else [])
            y = _relu(_conv3(np.concatenate(parts, 0), w, b))
            c4, n, h, wd = y.shape
            flow = _shuffle((hw @ y.reshape(c4, -1) + hb[:, None]).reshape(-1, n, h, wd))
            if i < last:
                x = _shuffle(y)
        return flow


def _arrays_of(inet) -> dict:
    """The arrays of a torch ``InferenceNet`` (:class:`NumpyNet`'s layout)."""
    def a(t) -> np.ndarray:
        return t.detach().cpu().float().numpy()

    def conv(w) -> np.ndarray:  # (O, C, 3, 3) channels-last in memory -> (O, 9 C)
        w = a(w)
        return np.ascontiguousarray(w.transpose(0, 2, 3, 1).reshape(w.shape[0], -1))

    out = {"n_bins": np.int64(inet.n_bins), "symmetric": np.bool_(inet.symmetric),
           "width": np.float64(inet.width)}
    for i, (w, b) in enumerate(inet.enc):
        out[f"enc{i}_w"], out[f"enc{i}_b"] = conv(w), a(b)
    for i, (w1, b1, w2, b2) in enumerate(inet.res):
        out.update({f"res{i}_w1": conv(w1), f"res{i}_b1": a(b1),
                    f"res{i}_w2": conv(w2), f"res{i}_b2": a(b2)})
    for i, ((w, b), (hw, hb)) in enumerate(zip(inet.dec, inet.heads, strict=True)):
        out[f"dec{i}_w"], out[f"dec{i}_b"] = conv(w), a(b)
        out[f"head{i}_w"], out[f"head{i}_b"] = a(hw), a(hb)
    return out


def save_export(out: str | Path, inet) -> None:
    """Write the arrays :class:`NumpyNet` runs of a torch ``InferenceNet`` to ``out``
    (``.npz``), atomically (``evmotion train`` writes its ``model.npz`` so)."""
    from evmotion.utils import atomic_path

    arrays = _arrays_of(inet)
    with atomic_path(out) as tmp, open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def export_checkpoint(checkpoint: str | Path, out: str | Path) -> None:
    """Write the arrays :class:`NumpyNet` runs of a torch checkpoint (``model.pt`` of
    ``evmotion train``) to ``out`` (``.npz``), atomically; needs torch. The shipped
    ``.npz`` is made so from the shipped ``.pt``::

        python -c "from evmotion.methods.dnn import numpynet as n; n.export_checkpoint(
            n.SHIPPED_EXPORT.with_suffix('.pt'), n.SHIPPED_EXPORT)"
    """
    from evmotion.methods.dnn.model import load_inference_net

    save_export(out, load_inference_net(checkpoint, "cpu"))


def checkpoint_key(checkpoint, default: Path) -> tuple[Path, tuple[str, int]]:
    """``(path, key)`` of a checkpoint (``default`` for None): the key, its resolved path
    and modification time, tells a loaded network's file apart from an edited one (the
    caches of :func:`load_numpy_net` and :func:`~evmotion.methods.dnn.model.load_model`).
    Raises :class:`~evmotion.errors.ParameterError` for what is not a path."""
    if checkpoint is not None and not isinstance(checkpoint, (str, os.PathLike)):
        raise ParameterError(f"checkpoint must be a path, got {type(checkpoint).__name__}")
    path = default if checkpoint is None else Path(checkpoint)
    return path, (str(path.resolve()), path.stat().st_mtime_ns if path.exists() else 0)


def load_numpy_net(checkpoint: str | Path | None = None) -> NumpyNet:
    """The :class:`NumpyNet` of a checkpoint: default the shipped one (its ``.npz``
    export, no torch); a ``.npz`` of :func:`export_checkpoint`; or a torch checkpoint
    (``model.pt``), converted through torch. Cached (the last one loaded).

    Raises :class:`~evmotion.errors.ParameterError` naming the file when it cannot be read
    or its arrays do not make the network.
    """
    path, key = checkpoint_key(checkpoint, SHIPPED_EXPORT)
    if key in _CACHE:
        return _CACHE[key]
    if path.suffix.lower() == ".npz":
        net = _from_npz(path)
    else:
        from evmotion.methods.dnn import require_torch

        require_torch(f"the torch checkpoint {path}")
        from evmotion.methods.dnn.model import load_inference_net

        net = NumpyNet(_arrays_of(load_inference_net(path, "cpu")))
    _CACHE.clear()
    _CACHE[key] = net
    return net


#: The most time bins an export may name (the shipped network has 5).
MAX_BINS = 64


def _shape_error(arrays: dict) -> str | None:
    """The first array whose shape does not make the network (numpy's broadcasting would
    run a bias of one value, or a head of one output, without a word: probe AX), said
    with the shape expected, or None. Shapes follow :class:`NumpyNet`: channels ``c1..c4``
    from the encoder, the decoder's outputs ``4 o_i`` (phases), its inputs the previous
    level, the skip and the previous flow."""
    n = arrays.get("n_bins")
    if n is None or np.ndim(n) or not float(n).is_integer() or not 1 <= int(n) <= MAX_BINS:
        return f"n_bins is {n!r}, not a whole number of time bins in [1, {MAX_BINS}]"

    def check(key: str, want: tuple) -> str | None:
        got = tuple(np.shape(arrays[key]))
        return None if got == want else f"{key} is {list(got)}, the network needs {list(want)}"

    expected, prev, c = [], int(n), []
    for i in range(4):
        out = np.shape(arrays[f"enc{i}_w"])[0] if np.ndim(arrays[f"enc{i}_w"]) == 2 else -1
        expected += [(f"enc{i}_w", (out, 9 * prev)), (f"enc{i}_b", (out,))]
        c.append(out)
        prev = out
    for i in range(2):
        expected += [(f"res{i}_w1", (c[3], 9 * c[3])), (f"res{i}_b1", (c[3],)),
                     (f"res{i}_w2", (c[3], 9 * c[3])), (f"res{i}_b2", (c[3],))]
    x = c[3]
    for i in range(4):
        w = arrays[f"dec{i}_w"]
        phases = np.shape(w)[0] if np.ndim(w) == 2 and np.shape(w)[0] % 4 == 0 else -4
        ins = x + c[3 - i] + (2 if i else 0)
        expected += [(f"dec{i}_w", (phases, 9 * ins)), (f"dec{i}_b", (phases,)),
                     (f"head{i}_w", (8, phases)), (f"head{i}_b", (8,))]
        x = phases // 4
    return next((msg for key, want in expected if (msg := check(key, want))), None)


def _from_npz(path: Path) -> NumpyNet:
    import zipfile

    if not path.is_file():
        raise ParameterError(f"checkpoint {path}: " + ("not a regular file" if path.exists()
                                                       else "no such file"))
    if not zipfile.is_zipfile(path):
        raise ParameterError(f"checkpoint {path}: not an evmotion network export (not an "
                             ".npz archive)")
    try:
        with np.load(path, allow_pickle=False) as data:
            names = data.files
            if "n_bins" not in names:
                raise KeyError("n_bins")
            arrays = {k: data[k] for k in names}
        wrong = _shape_error(arrays)
        net = None if wrong else NumpyNet(arrays)
    except KeyError as exc:
        raise ParameterError(f"checkpoint {path}: not an evmotion network export (no array "
                             f"{exc}; evmotion train writes model.npz, and export_checkpoint "
                             "makes one of a model.pt)") from None
    except (OSError, ValueError, TypeError, EOFError, zipfile.BadZipFile) as exc:
        text = " ".join(str(exc).split())[:160]
        raise ParameterError(f"checkpoint {path}: not an evmotion network export "
                             f"({type(exc).__name__}: {text})") from None
    if wrong:
        raise ParameterError(f"checkpoint {path}: its arrays do not make the network: {wrong}")
    return net
