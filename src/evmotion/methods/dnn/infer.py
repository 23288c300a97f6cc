"""Inference: dense flow of a window from the network (``estimate_flow(..., method="dnn")``).

The window's voxel grid (whole sensor, zero-padded to a multiple of 16) goes through the
network; its finest flow, cropped back to the sensor, is the displacement over the window
in px, divided by the window's duration to give px/s at the window's midpoint (like
multicm). A network trained on windows that move a few px underestimates windows that move
far more (ECD shapes, 30k events: 25-36 px, predicted 14-17 px), so by default it also sees
the events binned 2x and 4x coarser, where they move 2x and 4x less, and the prediction
(upsampled, scaled back) whose warp makes the sharpest image of the events is kept, tile by
tile, at the magnitude (0.7-3.2 times its own) that warps the events sharpest. The
result is a :class:`~evmotion.methods.flowresult.FlowResult` with the same IWEs and focus
as multicm's, so every output, picture and evaluation of ``evmotion flow`` works unchanged.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from evmotion.catalog import HOT_NEIGHBOUR_RATIO
from evmotion.errors import EmptyWindowError, ParameterError, PoorFitWarning
from evmotion.events import EventArray, pixel_indices, require_events
from evmotion.filters import hot_pixel_mask
from evmotion.jitcache import compile_seconds
from evmotion.methods.flowresult import (
    FlowResult,
    aligned_support,
)
from evmotion.methods.measured import (
    flow_alignment_gain,
    halves_consistency,
    other_motion,
    warn_by_chance,
    warn_flicker,
    warn_gap,
    warn_inconsistent_halves,
    warn_no_gain,
    warn_too_few_for_flow,
)
from evmotion.utils import check_switches

__all__ = ["BACKENDS", "checkpoint_digest", "estimate_flow_dnn", "load_network",
           "predict_displacement", "resolve_backend", "sharpness"]

# the events binned this many times coarser (estimate_flow_dnn): 8 for windows whose
# events move tens of px (a 0.95 s DAVIS346 window: FWL 2.30 with 1-4, 3.24 with 8 too)
INPUT_SCALES = (1, 2, 4, 8)
# the magnitudes the network's flow is tried at (estimate_flow_dnn's rescale): its
# least-squares gains on held-out windows lie between 0.7 and 1.0, finely; coarser up to
# 3.2 for windows past what the network was trained on (the DAVIS346 window kept 1.6,
# the largest of 0.7-1.6, at a third of multicm's speed)
GAINS = tuple(round(0.7 + 0.05 * i, 2) for i in range(19)) + (1.8, 2.0, 2.25, 2.5, 2.8, 3.2)
# per-tile fusion of the scales' predictions (estimate_flow_dnn's fuse): in a rotating
# or zooming window the flow's magnitude varies over the sensor, and no one input scale
# suits every part (ECD shapes_rotation: the centre moves a few px, the corners 60)
FUSE_TILE = 32
FUSE_GAINS = (0.85, 1.0, 1.15)
FUSE_MIN_EVENTS = 50
FUSE_BLEND = 0.5  # tiles: the Gaussian that smooths the choices' seams
# _refined: the network's flow averaged over multicm's finest tiles, as a start, keeps at
# least this share of the flow's sharpness, else only the tiles' correction of the flow
# is tried (bench_dnn_planar's windows: the moving objects' 0.88-0.91 and DAVIS240's
# 0.89-0.90 refined; those at 0.18-0.68 -- DAVIS346, EVT2, a Prophesee 1280x720
# window -- were refused after 25 evaluations, 0.7 s of the 1280x720 window's 3.8 s)
TILE_START_SHARPNESS = 0.8
# _alternatives: the correction of a kept plane's flow on multicm's finest tiles makes at
# most this many evaluations, and is kept where it sharpens the events by this factor at
# least. On the simulator's planar scenes (bench_dnn's and bench_dnn_planar's 12 windows of
# translation, rotation, zoom) the plane is their exact motion and a correction fits
# noise: sharper by 1.0001-1.004, AEE 1.0-1.8x the plane's; on the ECD windows where it
# found depth, 1.02-1.07 with 12 evaluations (shapes_rotation FWL 3.97 -> 4.23, multicm
# 4.23) at half the time of 25 (0.3-0.5 s a 30k window)
#: Time reversal runs at the input scales whose grid has at most this many pixels (VGA):
#: its second pass of the network costs as much as the first, 0.47 s at 1280x720 on one
#: core, a tenth of the one-window command's 5 s. Without it at that scale, on nine 30k
#: windows of a Prophesee 1280x720 recording the FWL rose on six and fell on two (2.60 ->
#: 1.95 the most), 0.5 s faster (median).
TIME_REVERSAL_MAX_PIXELS = 640 * 480
# how much sharper than the network's flow the window's sharpest translation must warp the
# events to replace it (estimate_flow_dnn): the network's flow of a window it measures is
# as sharp as the translation or sharper (rotation, zoom, depth); one it fails on, far
# less (2.4 against 7.1 on a window moving 47 px)
TRANSLATION_MARGIN = 1.25
PLANE_CORRECTION_EVALUATIONS = 12
PLANE_CORRECTION_MARGIN = 1.01


def predict_displacement(events: EventArray, checkpoint: str | Path | None = None, *,
                         device: str = "cpu", backend: str = "auto") -> np.ndarray:
    """The network's displacement over the window, (H, W, 2) float32 px (u right, v down).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> ev = EventArray(x=rng.integers(0, 40, 900), y=rng.integers(0, 30, 900),
    ...                 t=np.arange(900) * 10, p=rng.integers(0, 2, 900), sensor_size=(30, 40))
    >>> predict_displacement(ev).shape
    (30, 40, 2)
    """
    return _predict(events, [1], checkpoint, device, None, time_reversal=False,
                    backend=backend)[1]


#: The network's arithmetic: ``"numpy"`` (:mod:`.numpynet`, the CPU only, no torch),
#: ``"torch"`` (:class:`~evmotion.methods.dnn.network.InferenceNet`), or ``"auto"``.
BACKENDS = ("auto", "numpy", "torch")


def resolve_backend(backend: str = "auto", device: str = "cpu", checkpoint=None) -> str:
    """``backend`` resolved to ``"numpy"`` or ``"torch"``. ``"auto"``: numpy for an
    ``.npz`` export, or for the shipped network on the CPU in a process that has not
    imported torch; torch otherwise (a ``model.pt`` needs torch to be read, so its
    faster convolutions run it; torch's are 1.5-2x numpy's, ``benchmarks/results/dnn.md``,
    but its import cost a one-window command 2.0-2.4 s of its 4-6 s).

    Examples
    --------
    >>> resolve_backend("numpy"), resolve_backend("auto", "cpu", "run/model.npz")
    ('numpy', 'numpy')
    >>> resolve_backend("auto", "cuda")
    'torch'
    """
    if backend not in BACKENDS:
        raise ParameterError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    on_cpu = isinstance(device, str) and device.strip().lower() in ("cpu", "cpu:0")
    path = str(checkpoint).lower() if isinstance(checkpoint, (str, os.PathLike)) else ""
    export = path.endswith(".npz")
    if (backend == "numpy" or export) and not on_cpu:
        raise ParameterError(f"the numpy network runs on the CPU only, got device {device!r}"
                             + (f" for the export {checkpoint}" if export else ""))
    if export and backend == "torch":
        raise ParameterError(f"checkpoint {checkpoint}: an .npz export runs on the numpy "
                             "backend only; give its model.pt for torch")
    if backend == "auto":
        shipped_here = checkpoint is None and on_cpu and sys.modules.get("torch") is None
        return "numpy" if export or shipped_here else "torch"
    return backend


def checkpoint_digest(checkpoint=None, backend: str = "numpy") -> str:
    """The first 16 hex digits of the SHA-1 of the checkpoint file a run reads (for None,
    the shipped network's: its ``.npz`` export with the numpy ``backend``, its
    ``model.pt`` with torch). Stored with a resumable output, so that a resume whose
    checkpoint holds other weights under the same name is refused, and one that names the
    same file another way is not (probe BG: a replaced ``model.pt`` gave a file whose
    windows came from two networks).

    Examples
    --------
    >>> checkpoint_digest() == checkpoint_digest(None, "numpy") != checkpoint_digest(
    ...     None, "torch")
    True
    """
    import hashlib

    from evmotion.methods.dnn.numpynet import SHIPPED_EXPORT, checkpoint_key

    shipped = SHIPPED_EXPORT if backend == "numpy" else SHIPPED_EXPORT.with_suffix(".pt")
    path, _ = checkpoint_key(checkpoint, shipped)
    try:
        with open(path, "rb") as fh:
            return hashlib.file_digest(fh, "sha1").hexdigest()[:16]
    except OSError as exc:
        raise ParameterError(f"checkpoint {path}: cannot be read ({exc.strerror or exc})"
                             ) from None


def load_network(checkpoint=None, device: str = "cpu", backend: str = "auto"):
    """The network that computes the finest flow of ``checkpoint`` (default the shipped
    one): with the numpy backend a :class:`~evmotion.methods.dnn.numpynet.NumpyNet` (torch
    is not imported for the shipped checkpoint), with torch's an
    :class:`~evmotion.methods.dnn.network.InferenceNet` on ``device``; ``"auto"`` as
    :func:`resolve_backend` says. The two networks' flows agree within float32 rounding
    (1e-6 px on the shipped network). Raises :class:`~evmotion.errors.ParameterError`
    naming a checkpoint or device that fails."""
    if resolve_backend(backend, device, checkpoint) == "numpy":
        from evmotion.methods.dnn.numpynet import load_numpy_net

        return load_numpy_net(checkpoint)
    from evmotion.methods.dnn import require_torch

    require_torch(f"the network on torch (device {device!r})")
    from evmotion.methods.dnn.model import load_inference_net

    return load_inference_net(checkpoint, device)


def _run(net, vox: np.ndarray, shape: tuple[int, int], device: str,
         time_reversal: bool = False) -> np.ndarray:
    """The network on one input ``(H', W', bins)``, its flow cropped to ``shape``; with
    ``time_reversal``, the mean of its flow and the negated flow of the time-reversed
    window (the bins in reverse order, polarities flipped), in one batch of two."""
    from evmotion.methods.dnn.numpynet import NumpyNet

    h, w = shape
    x = np.transpose(vox, (2, 0, 1))[None]           # (1, bins, H', W')
    if time_reversal:
        x = np.concatenate([x, -x[:, ::-1]])
    if isinstance(net, NumpyNet):
        out = net(x)[:, :, :h, :w]
    else:
        import torch

        with torch.inference_mode(), _full_fp32():
            out = net(torch.from_numpy(np.ascontiguousarray(x)).to(device))[:, :, :h, :w]
        out = out.cpu().numpy()
    flow = 0.5 * (out[0] - out[1]) if time_reversal else out[0]
    return np.ascontiguousarray(flow.transpose(1, 2, 0), dtype=np.float32)


@contextlib.contextmanager
def torch_threads(threads: int | None):
    """torch's intra-op thread count set to ``threads`` (None: left as it is) for the
    block, restored after."""
    if threads is None:
        yield
        return
    if not (isinstance(threads, (int, np.integer)) and not isinstance(threads, bool)
            and 1 <= threads <= 256):
        raise ParameterError(f"threads must be an integer in [1, 256] or None, got {threads!r}")
    if sys.modules.get("torch") is None:  # the network in numpy: no torch threads to set
        yield
        return
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(int(threads))
    try:
        yield
    finally:
        torch.set_num_threads(before)


@contextlib.contextmanager
def _full_fp32():
    """cuDNN's TF32 convolutions (its default on Ampere and newer GPUs) moved the flow by
    up to 1 % from the CPU's; in full float32 the two agree within 1.4e-5 px (H200,
    ``benchmarks/results/dnn_cuda.md``)."""
    import torch

    before = torch.backends.cudnn.allow_tf32
    torch.backends.cudnn.allow_tf32 = False
    try:
        yield
    finally:
        torch.backends.cudnn.allow_tf32 = before


def _resized(a: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Maps ``a`` (C, h, w) resized to ``size`` bilinearly, pixel centres aligned (torch's
    ``interpolate(..., mode="bilinear", align_corners=False)``; numpy: torch is not
    imported on the CPU)."""
    out = a
    for axis, n in ((1, size[0]), (2, size[1])):
        m = out.shape[axis]
        src = np.maximum((np.arange(n) + 0.5) * (m / n) - 0.5, 0.0)
        i0 = np.minimum(np.floor(src).astype(np.intp), m - 1)
        i1 = np.minimum(i0 + 1, m - 1)
        f = (src - i0).astype(out.dtype)
        shape = [1, 1, 1]
        shape[axis] = n
        f = f.reshape(shape)
        out = out.take(i0, axis) * (1 - f) + out.take(i1, axis) * f
    return out


def _upsampled(disp: np.ndarray, k: int, shape: tuple[int, int]) -> np.ndarray:
    """A displacement predicted on the grid ``k`` times coarser, on the sensor's grid in
    px: bilinear (pixel centres aligned), times ``k``, cropped to ``shape``."""
    h, w = disp.shape[:2]
    up = _resized(np.ascontiguousarray(disp.transpose(2, 0, 1)), (h * k, w * k))
    return np.ascontiguousarray(up.transpose(1, 2, 0)[:shape[0], :shape[1]] * k,
                                dtype=np.float32)


def _predict(events: EventArray, scales: list[int], checkpoint, device: str, xys,
             time_reversal: bool, backend: str = "auto"):
    """``(k, displacement, candidates)``: the network's prediction at input scale ``k``,
    of the ``scales`` the one whose prediction warps the events (``xys``, from
    :func:`_pixels_and_times`) sharpest (the one scale's when there is one), and the
    predictions at every scale."""
    from evmotion.methods.dnn.voxel import network_inputs

    net = load_network(checkpoint, device, backend)
    h, w = events.sensor_size
    best, disp, score, cands = 1, None, -np.inf, []
    for k, vox in zip(scales, network_inputs(events, tuple(scales), net.n_bins), strict=True):
        grid = (-(-h // k), -(-w // k))
        cand = _run(net, vox, grid, device,
                    time_reversal and grid[0] * grid[1] <= TIME_REVERSAL_MAX_PIXELS)
        if not np.isfinite(cand).all():
            raise ParameterError(f"checkpoint {checkpoint or 'shipped'}: the network "
                                 "gives a non-finite flow (its training diverged)")
        if k > 1:
            cand = _upsampled(cand, k, (h, w))
        if len(scales) == 1:
            return k, cand, [cand]
        cands.append(cand)
        s = _warped_variance(*xys, cand)
        if s > score:
            best, disp, score = k, cand, s
    return best, disp, cands


def _tile_groups(xys, shape, tile: int):
    """The tile each event starts in, the tile grid and each tile's event count."""
    x, y = xys[0], xys[1]
    h, w = shape
    grid = (-(-h // tile), -(-w // tile))
    # (int64: times h * w in _tile_sharpness, past int32 from ~1.5 Mpx, 1920 x 1080)
    tiles = ((y // tile) * grid[1] + x // tile).astype(np.int64)
    return tiles, grid, np.bincount(tiles, minlength=grid[0] * grid[1]).reshape(grid)


def _tile_sharpness(xys, disp: np.ndarray, groups) -> np.ndarray:
    """Per tile of the sensor (``groups``: :func:`_tile_groups`), the sum of squares of the
    image of its events (those that start in it) moved by ``disp`` to the window's
    midpoint: for a tile's fixed events, the higher the sharper. numpy only: the dnn path
    does not import numba (0.5-1 s of a one-window command)."""
    h, w = disp.shape[:2]
    landed, inside = _landed(*xys, disp)
    tiles, grid, _ = groups
    key = np.sort(tiles[inside] * (h * w) + landed)
    if not key.size:
        return np.zeros(grid)
    first = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    runs = np.diff(np.r_[first, key.size]).astype(np.float64)
    out = np.bincount(key[first] // (h * w), runs * runs, minlength=grid[0] * grid[1])
    return out.reshape(grid)


def _blurred(maps: np.ndarray, sigma: float) -> np.ndarray:
    """``maps`` (K, h, w) smoothed along their last two axes by a 3-tap Gaussian of
    ``sigma`` cells, edges repeated (numpy: scipy.ndimage costs a one-window command a
    quarter of a second to import)."""
    side = float(np.exp(-0.5 / (sigma * sigma)))
    out = maps
    for axis in (1, 2):
        pad = np.concatenate([out.take([0], axis), out, out.take([-1], axis)], axis)
        n = out.shape[axis]
        out = (side * pad.take(range(0, n), axis) + pad.take(range(1, n + 1), axis)
               + side * pad.take(range(2, n + 2), axis)) / (1.0 + 2.0 * side)
    return out


def _fused(xys, cands: list[np.ndarray], fallback: np.ndarray, shape) -> np.ndarray:
    """One displacement made, tile by tile (:data:`FUSE_TILE` px), of the candidate (a
    scale's prediction times one of :data:`FUSE_GAINS`) that warps the tile's events
    sharpest, the choices blended smoothly across tiles; tiles with fewer than
    :data:`FUSE_MIN_EVENTS` events keep ``fallback`` (the whole window's choice)."""
    h, w = shape
    tile = FUSE_TILE
    options = [c * np.float32(g) for c in cands for g in FUSE_GAINS] + [fallback]
    groups = _tile_groups(xys, shape, tile)
    scores = np.stack([_tile_sharpness(xys, c, groups) for c in options])
    pick = np.where(groups[2] >= FUSE_MIN_EVENTS, scores.argmax(0), len(options) - 1)
    weights = _blurred(np.stack([(pick == k).astype(np.float64)
                                 for k in range(len(options))]), FUSE_BLEND)
    weights /= weights.sum(0)
    # per scale, its gains' weights fold into one weighted gain: one map per scale and
    # one for the fallback, upsampled at once (bilinear between tile centres)
    g = np.asarray(FUSE_GAINS)[:, None, None]
    maps = [(weights[i * len(FUSE_GAINS):(i + 1) * len(FUSE_GAINS)] * g).sum(0)
            for i in range(len(cands))] + [weights[-1]]
    up = _resized(np.stack(maps).astype(np.float32),
                  (weights.shape[1] * tile, weights.shape[2] * tile))[:, :h, :w]
    fused = up[-1][..., None] * fallback
    for m, c in zip(up[:-1], cands, strict=True):
        fused += m[..., None] * c
    return fused


def _translated(xys, disp: np.ndarray, shape: tuple[int, int]) -> np.ndarray | None:
    """The window's sharpest translation
    (:func:`~evmotion.core.translation.sharpest_translation`) as a displacement field where
    it warps the events :data:`TRANSLATION_MARGIN` times sharper than the network's
    ``disp``, else None."""
    from evmotion.core.translation import sharpest_translation

    x, y, _, s = xys
    if not x.size:
        return None
    moved = np.empty(disp.shape, np.float32)
    moved[...] = sharpest_translation(x, y, s, shape)
    if _warped_variance(*xys, moved) >= TRANSLATION_MARGIN * _warped_variance(*xys, disp):
        return moved
    return None


def _rescaled(xys, disp: np.ndarray) -> tuple[float, np.ndarray]:
    """``(gain, disp * gain)``: of :data:`GAINS`, the one whose warp is sharpest; the
    network's own magnitude (1) unless another is strictly sharper, so a window whose
    image no gain changes keeps it."""
    scores = {g: _warped_variance(*xys, disp * np.float32(g)) for g in GAINS}
    best = max(GAINS, key=lambda g: (scores[g], g == 1.0))  # a tie keeps 1
    return best, disp if best == 1.0 else disp * np.float32(best)


def sharpness(events: EventArray, disp: np.ndarray) -> float:
    """Variance of the image of the events moved by ``disp`` (H, W, 2, px over the window)
    to the window's midpoint, one vote per event at its nearest pixel: the contrast that
    ranks candidate flows of one window (higher is sharper).

    Examples
    --------
    >>> ev = EventArray(x=[1, 2, 3], y=[0, 0, 0], t=[0, 50, 100], p=[1, 1, 1],
    ...                 sensor_size=(1, 5))
    >>> right = np.zeros((1, 5, 2), np.float32); right[..., 0] = 2.0   # 2 px per window
    >>> sharpness(ev, right) > sharpness(ev, np.zeros_like(right))
    True
    """
    return _warped_variance(*_pixels_and_times(events), disp)


def _pixels_and_times(events: EventArray):
    h, w = events.sensor_size
    t = events.t
    s = ((t - t[0]) / max(int(t[-1] - t[0]), 1) - 0.5).astype(np.float32)
    x, y = pixel_indices(events.x, w), pixel_indices(events.y, h)
    return x, y, y * w + x, s


def _landed(x, y, pix, s, disp) -> tuple[np.ndarray, np.ndarray]:
    """``(pixel, inside)``: the events (:func:`_pixels_and_times`) moved by ``disp`` to the
    window's midpoint, each one's pixel index (``y * w + x``, int64) where it lands inside
    the sensor, and which do."""
    h, w = disp.shape[:2]
    d = disp.reshape(-1, 2)[pix]
    xw = np.rint(x - d[:, 0] * s).astype(np.int64)
    yw = np.rint(y - d[:, 1] * s).astype(np.int64)
    inside = (xw >= 0) & (xw < w) & (yw >= 0) & (yw < h)
    return yw[inside] * w + xw[inside], inside


def _warped_variance(x, y, pix, s, disp) -> float:
    """The variance over the sensor's pixels of the count image of the events moved by
    ``disp`` to the window's midpoint: from the counts of the pixels they land on (the
    others are 0), not a whole image of counts, which a 1280 x 720 window's 33 calls had
    spent 0.3 s making and summing."""
    h, w = disp.shape[:2]
    counts = np.unique(_landed(x, y, pix, s, disp)[0], return_counts=True)[1]
    counts = counts.astype(np.float64)
    mean = counts.sum() / (h * w)
    return float(np.dot(counts, counts) / (h * w) - mean * mean)


def _alternatives(events: EventArray, disp: np.ndarray, hot: np.ndarray, xys,
                  planar: bool, refine: bool):
    """``(plane, refined)``: the plane's ``(params, flow)`` (:func:`_planar`) and the
    refined flow (:func:`_refined`: of the plane's flow where the plane is kept, else of
    the network's), each None where not kept. All are polished and judged on at most
    ``MAX_EVENTS`` evenly spaced events, their focus on images binned as
    :func:`.planar.binning` says, against the loss of the flow they would replace."""
    from evmotion.methods.dnn.planar import MAX_EVENTS, binning, window_loss

    k = binning(events.sensor_size)
    if len(events) > MAX_EVENTS:
        events = events[np.linspace(0, len(events) - 1, MAX_EVENTS).astype(np.intp)]
    reference = window_loss(events, disp, binning=k)
    plane = _planar(events, disp, hot, k, reference) if planar else None
    refined = None
    if refine and plane is not None:
        # a plane is a scene's motion up to its depth: real scenes have depth, and a
        # correction on multicm's finest tiles finds it (PLANE_CORRECTION_MARGIN)
        refined = _refined(events, plane[1], hot, xys, k, plane[2], means_first=False,
                           evaluations=PLANE_CORRECTION_EVALUATIONS,
                           margin=PLANE_CORRECTION_MARGIN)
    elif refine:
        refined = _refined(events, disp, hot, xys, k, reference)
    return None if plane is None else plane[:2], refined


def _planar(events: EventArray, disp: np.ndarray, hot: np.ndarray, k: int,
            reference: float):
    """``(params, flow, loss)`` of the plane's motion polished from the network's flow
    ``disp`` when its training loss is lower than the network's flow's (``reference``),
    else None."""
    from evmotion.methods.dnn.planar import (
        POLISH_EVALUATIONS,
        PROBE_EVALUATIONS,
        PROBE_RATIO,
        fit_planar,
        planar_flow,
        polish_planar,
        translation_start,
        window_loss,
    )

    def field(params):
        flow = planar_flow(params, events.sensor_size)
        flow[hot] = 0.0
        return flow

    # the plane closest to a noisy or 20 % short network flow can bend into quadratic
    # terms the polish does not leave; the translation of its median may not (probe BD:
    # one object moving 33 px over a still background, loss 0.065 against 0.037)
    for start in (fit_planar, translation_start):
        params = polish_planar(events, start(events, disp), PROBE_EVALUATIONS, k)
        if window_loss(events, field(params), binning=k) <= PROBE_RATIO * reference:
            break
    else:
        return None
    params = polish_planar(events, params, POLISH_EVALUATIONS - PROBE_EVALUATIONS, k)
    flow = field(params)
    loss = window_loss(events, flow, binning=k)
    return (params, flow, loss) if loss < reference else None


def _refined(events: EventArray, disp: np.ndarray, hot: np.ndarray, xys, k: int,
             reference: float, means_first: bool = True,
             evaluations: int | None = None, margin: float = 1.0):
    """The network's flow ``disp`` refined on multicm's finest tiles (:mod:`.tiles`), the
    first of two refinements whose training loss is lower than ``reference`` (``disp``'s)
    and whose :func:`sharpness` (on ``xys``, the events' pixels and times) is no lower
    than ``disp``'s; None where neither is.

    First the tiles started from ``disp``'s means over their events, a flow without
    ``disp``'s detail finer than a tile; then, where that is not kept, a tile correction
    of ``disp`` itself, detail kept. On bench_dnn_planar's windows the first was kept on
    the simulated moving objects, where it gave the lower loss of the two and the lower
    AEE (2.87 against 3.48 px on bench_dnn's), and on one of the seven real windows
    without a plane; where it was not, the tiles' start (loss 1.13-2.66x ``disp``'s,
    sharpness 0.18-0.90x) had lost what the network saw and the loss went down while the
    events blurred, and the correction was kept on all six (FWL e.g. 2.21 -> 2.79,
    multicm 3.40). A start under ``TILE_START_SHARPNESS`` of ``disp``'s sharpness, or
    ``means_first=False``, goes straight to the correction. Each run makes at most
    ``evaluations`` (default :data:`.tiles.REFINE_EVALUATIONS`); ``margin`` > 1 asks that
    much more sharpness than ``disp``'s.
    """
    from evmotion.core.tilegrid import (
        auto_finest_level,
        dense_flow,
        event_tile_means,
        scale_grid,
    )
    from evmotion.methods.dnn.planar import window_loss
    from evmotion.methods.dnn.tiles import REFINE_EVALUATIONS, refine_tiles

    evaluations = REFINE_EVALUATIONS if evaluations is None else evaluations
    shape = events.sensor_size
    grid = scale_grid(auto_finest_level(len(events), shape), shape)
    sharp = _warped_variance(*xys, disp)
    means = event_tile_means(disp, events.x, events.y, grid)
    runs = [(np.zeros_like(means), disp)]
    if means_first and (_warped_variance(*xys, dense_flow(means, shape))
                        >= TILE_START_SHARPNESS * sharp):
        runs.insert(0, (means, None))
    for start, base in runs:
        flow = dense_flow(refine_tiles(events, start, grid, evaluations, binning=k, base=base),
                          shape)
        if base is not None:
            flow = flow + base
        flow = flow.astype(np.float32)
        flow[hot] = 0.0
        if (window_loss(events, flow, binning=k) < reference
                and _warped_variance(*xys, flow) >= margin * sharp):
            return flow
    return None


def _verdict(checked: EventArray, flow: np.ndarray, t_ref: int, gains: list[float]
             ) -> tuple[bool, float, float]:
    """``(no_focus, chance gain, halves correlation)`` of the network's flow: the tests
    that say a flow is no measurement, each said in a warning when it fails."""
    # under flicker the network answers the bursts with flows 20-800x the truth, which
    # gather them (probe AK: FWL 4-23, chance 1.07-2.1): said before the gains
    if (warn_too_few_for_flow(checked, "network's flow") is not None
            or warn_gap(checked.t, "network's flow") is not None
            or warn_flicker(checked, "network's flow") is not None
            or (bool(gains) and warn_no_gain(min(gains), "network's flow") is not None)):
        return True, float("nan"), float("nan")
    # a flow that sharpens the window without following its motion (half a pixel of it;
    # a sparse window it cannot hold) sharpens it as well with shuffled times
    chance = flow_alignment_gain(checked, flow, t_ref)
    if warn_by_chance(chance, "network's flow") is not None:
        return True, chance, float("nan")
    # (as multicm's: a flow that does not carry the window's first half onto its second
    # measures no motion; an 8 s pan gave 0.1 px/s for 67, valid)
    halves = halves_consistency(checked, flow, t_ref)
    return warn_inconsistent_halves(halves, "network's flow") is not None, chance, halves


def estimate_flow_dnn(events: EventArray, checkpoint: str | Path | None = None, *,
                      device: str = "cpu", backend: str = "auto", with_iwes: bool = True,
                      input_scales: tuple[int, ...] = INPUT_SCALES,
                      time_reversal: bool = True, rescale: bool = True,
                      fuse: bool = True, translation: bool = True, planar: bool = True,
                      refine: bool = True, threads: int | None = 1, check: bool = True
                      ) -> FlowResult:
    """Dense optical flow of one window by the unsupervised EV-FlowNet.

    Parameters
    ----------
    events : EventArray
        One window (the network was trained on 40k-event windows; 30k works as well).
    checkpoint : path, optional
        Weights from ``evmotion train`` (its ``model.pt``); default the
        shipped checkpoint (``evmotion/methods/dnn/weights``, see its model card).
    device : str
        ``"cpu"`` (default) or a torch device (``"cuda"``, ``"cuda:N"``, ``"mps"``).
    backend : {"auto", "numpy", "torch"}
        The network's arithmetic (:func:`load_network`): numpy (the CPU) needs no torch,
        whose import is 2.0-2.4 s; torch's convolutions are 1.5-2x faster. ``"auto"``
        (default, :func:`resolve_backend`): numpy for the shipped network in a process
        that has not imported torch (as the CLI) and for an ``.npz`` export, else torch.
        The two networks agree within float32 rounding (1e-6 px), but the plane's polish
        and the refinement that follow are searches that can carry such a difference
        further: up to 0.6 % of the flow on a probe's 640x480 window, with the same FWL.
        For bit-for-bit results across processes, name the backend;
        ``meta["backend"]`` says which ran.
    with_iwes : bool
        Also compute the IWEs and the multi-reference focus of the flow, as multicm
        reports them (a few ms; default True).
    input_scales : tuple of int
        The network also predicts from the events binned this many times coarser (default
        1, 2, 4, 8; each of 1, 2, 4, 8, 16), where far-moving windows move within what it
        was trained on; the prediction whose warp gives the highest :func:`sharpness` is
        kept (``(1,)``: the network on the sensor's grid only).
    time_reversal : bool
        Also predict from the time-reversed window (events in reverse order, polarities
        flipped: its flow is the negative) and average the two (default True): errors the
        network makes alike forwards and backwards cancel. The two passes run as one batch,
        at the input scales of at most :data:`TIME_REVERSAL_MAX_PIXELS` pixels.
        Both options together take about 4x one pass (``benchmarks/results/dnn.md``);
        ``input_scales=(1,), time_reversal=False`` is the network's single pass.
    fuse : bool
        Choose among the input scales' predictions (each also at 0.85 and 1.15 times its
        magnitude) tile by tile (32 px; tiles of fewer than 50 events keep the whole
        window's choice), by the sharpness of each tile's events, blended across tiles
        (default True): in a rotation or zoom the flow's magnitude varies over the sensor
        and no one scale suits every part. On bench_dnn's held-out simulated windows the
        AEE fell by 4-22 % (zoom 2.01 -> 1.57 px), on ECD shapes_rotation the FWL rose
        from 2.83 to 3.24 (``benchmarks/results/dnn.md``).
    translation : bool
        Also find the window's sharpest global translation by a grid search
        (:mod:`evmotion.core.translation`, within half the sensor's longer side;
        0.01-0.2 s) and take
        it instead of the network's prediction (fused across input scales when ``fuse``)
        where it warps the events :data:`TRANSLATION_MARGIN` times sharper (default
        True): a window moving far past
        what the network was trained on can come out of every input scale at a fraction
        of its motion (a 346x260 window moving 47 px: 19 px, AEE 29 px; with the
        translation and the plane's polish 0.07 px). ``meta["translation"]`` says whether
        it was taken.
    rescale : bool
        Multiply the flow kept by the gain among 0.7, 0.75, ..., 1.6, 1.8, ..., 3.2 whose warp gives the
        highest :func:`sharpness` (default True; 1 unless another is strictly sharper):
        the network tends to underestimate magnitudes (least-squares gains 0.7-1.0 on
        held-out simulated windows), and a whole-window gain costs 25 event images (one per gain).
    planar : bool
        Also fit the 8-parameter flow of a plane's motion (:mod:`.planar`) to the network's
        flow, polish it on the events' multi-reference focus, and keep it instead when its
        loss (multicm's objective (4.9): gradient magnitude with the smoothness weight
        :data:`.planar.LAM`, whatever objective the checkpoint was trained with;
        :func:`.planar.window_loss`) is the lower (default True; 0.58-0.95 s a 346x260 window
        with ``refine=False``, against 0.30-0.34 s without). The network's dense flow is noisy, which gathers
        events and raises its focus; the loss' smoothness term sees through that. On
        bench_dnn's held-out simulated windows it was kept on translation, rotation and zoom (AEE 0.681 -> 0.075, 0.874 -> 0.076, 1.567 -> 0.430
        px) and not on the window with an independently moving object
        (``benchmarks/results/dnn.md``; other windows: ``dnn_planar.md``).
        ``meta["planar"]`` says whether it was kept, ``meta["planar_params"]`` its
        parameters (px over the window, :mod:`.planar`).
    refine : bool
        Also refine the flow kept so far on multicm's finest tiles, polished by
        evaluations of multicm's objective (:mod:`.tiles`), and keep the refinement where
        it lowers that loss without lowering the :func:`sharpness` (default True; 0.3-1 s
        a window). Where the plane is kept, the tiles correct the plane's flow (12
        evaluations), kept where the events come out at least 1 % sharper: real scenes
        have depth (ECD shapes_rotation's FWL 3.97 -> 4.23, multicm 4.23), the
        simulator's planar scenes do not and keep the plane. Where no plane is kept, they
        start from the network's flow's mean over each tile's events (15 evaluations),
        and where that is not kept they correct the network's flow itself. On bench_dnn's
        held-out window with an independently moving object the AEE fell from 3.75 to
        2.87 px (multicm 2.52) (``benchmarks/results/dnn.md``, ``dnn_planar.md``).
        ``meta["refined"]`` says whether it was kept.
    check : bool
        Run the tests that say the flow is no measurement (flicker, contrast gain,
        chance, halves; default True). False for a flow that only starts another
        estimate (multicm's ``init="dnn"``, whose own tests judge its result): none runs,
        nothing is said, ``meta["no_focus"]`` is None.
    threads : int or None
        torch threads for this call, the process's count restored after (default 1, as
        the CLI's ``--threads``: on the shared 2-core machine, under load, one thread ran
        the network 2-12x faster than torch's default of two (probe AP); quiet, the two
        were alike, 0.094 against 0.100 s a window; None: torch's own setting).

    Returns
    -------
    FlowResult
        ``flow`` in px/s at the window's midpoint; ``valid`` the pixels with event support,
        as multicm's; ``params`` empty; ``meta["method"]`` is ``"dnn"`` and
        ``meta["input_scale"]`` the scale kept, ``meta["gain"]`` the gain applied,
        ``meta["fwl"]`` the variance of the image of the events warped to the midpoint over
        the unwarped one's, ``meta["hot_pixels"]`` how many hot pixels
        (:func:`evmotion.filters.hot_pixel_mask`) were given zero flow (and are left out of
        the checks), ``meta["beyond_range"]`` whether the gain kept by a measured flow is
        the largest tried (PoorFitWarning: the magnitudes are a lower bound). A flow that
        sharpens the events by less than 5 % (that ratio, or with ``with_iwes`` the
        multi-reference focus, under :data:`~evmotion.methods.measured.MIN_CONTRAST_GAIN`) is no
        measurement: PoorFitWarning, ``valid`` all False, ``meta["no_focus"]`` True.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> ev = EventArray(x=rng.integers(0, 40, 900), y=rng.integers(0, 30, 900),
    ...                 t=np.arange(900) * 10, p=rng.integers(0, 2, 900), sensor_size=(30, 40))
    >>> estimate_flow_dnn(ev).flow.shape
    (30, 40, 2)
    """
    events = require_events(events, "estimate_flow_dnn", on_sensor=True)
    # (refine="False" and the like were taken as True, probe CB)
    check_switches(with_iwes=with_iwes, time_reversal=time_reversal, rescale=rescale,
                   fuse=fuse, translation=translation, planar=planar, refine=refine,
                   check=check)
    if len(events) < 10 or events.t[-1] <= events.t[0]:
        raise EmptyWindowError(f"window has {len(events)} events spanning "
                               f"{int(events.t[-1] - events.t[0]) if len(events) else 0} us; "
                               "need at least 10 events and a positive duration")
    if np.isscalar(input_scales):
        input_scales = (input_scales,)
    if not len(input_scales) or any(k not in (1, 2, 4, 8, 16) for k in input_scales):
        raise ParameterError("input_scales must be one or more of 1, 2, 4, 8, 16 (divisors "
                             f"of the network's 16-px padding), got {input_scales!r}")
    scales = sorted({int(k) for k in input_scales})
    backend = resolve_backend(backend, device, checkpoint)
    c_start = compile_seconds()
    t_start = time.perf_counter()
    xys = _pixels_and_times(events)
    with torch_threads(threads):
        best, disp, cands = _predict(events, scales, checkpoint, device, xys,
                                     bool(time_reversal), backend)
    # a window moving far past what the network was trained on can come out of every
    # input scale at a fraction of its motion, looking like a measurement (47 px as 19;
    # probe BT): its sharpest translation, much sharper, takes the network's place. It is
    # weighed against the fused flow, not the best single scale's: a rotating window's
    # fused flow is the sharper where no one scale is (ECD shapes_rotation: FWL 3.24
    # fused, 3.00 translated)
    if fuse and len(cands) > 1:
        disp = _fused(xys, cands, disp, events.sensor_size)
    moved = _translated(xys, disp, events.sensor_size) if translation else None
    if moved is not None:
        disp = moved
    # a hot pixel's events do not move: any flow there smears them, and they outnumber
    # a moving pixel's many times over (2 % of a window's events on 5 hot pixels brought
    # the window's contrast below the unwarped one's); their flow is zero
    hot = hot_pixel_mask(events, neighbour_ratio=HOT_NEIGHBOUR_RATIO)
    disp[hot] = 0.0
    gain, disp = _rescaled(xys, disp) if rescale else (1.0, disp)
    # the checks below leave out the hot pixels' events: no flow moves them, so they are
    # alike in the warped and the unwarped image and pull the ratio to 1 (8 hot pixels
    # holding 11 % of a 640x480 window: 1.003 for a flow of 1.8 px AEE, 1.35 without)
    checked, xyc = events, xys
    if hot.any():
        keep = ~hot.ravel()[xys[2]]
        checked, xyc = events[np.flatnonzero(keep)], tuple(a[keep] for a in xys)
    # under the network's thread count: the polish's float32 sums, and so its path,
    # depend on it
    with torch_threads(threads):
        plane, refined = (_alternatives(checked, disp, hot, xyc, planar, refine)
                          if (planar or refine) and len(checked) >= 10 else (None, None))
    if refined is not None:
        disp = refined
    elif plane is not None:
        disp = plane[1]
    # the magnitude at the top of the search: the window moves further than the network
    # sees even on its coarsest input (a 240x180 window moving 80 px came out at 11 px,
    # gain 3.2): what it gives is a lower bound (unless the plane's polish went further)
    beyond = bool(rescale and gain == GAINS[-1] and plane is None)
    # the contrast gain of the flow kept, checked on every call (the focus below only
    # with the IWEs): the variance of the warped events' image over the unwarped one's
    still = _warped_variance(*xyc, np.zeros_like(disp)) if len(checked) else 0.0
    fwl = _warped_variance(*xyc, disp) / still if still > 0 else float("nan")
    t_net = time.perf_counter() - t_start
    t0, t1 = int(events.t[0]), int(events.t[-1])
    duration_s = (t1 - t0) * 1e-6
    iwes, focus = {}, float("nan")
    if with_iwes:
        from evmotion.core.tileflow import iwe_forward
        from evmotion.methods.dnn.problem import window_problem

        prob = window_problem(checked if len(checked) >= 2 else events)
        focus, _, imgs = prob.focus_grad(disp.astype(np.float64))
        iwes = {k: v.astype(np.float32) for k, v in zip(("t1", "tmid", "tN"), imgs,
                                                         strict=True)}
        iwes["identity"] = iwe_forward(prob.x, prob.y, np.zeros((prob.x.size, 2)),
                                       np.zeros(prob.x.size), events.sensor_size
                                       ).astype(np.float32)
    flow = (disp / duration_s).astype(np.float32)
    # the network answers everywhere; only where events are is it a measurement
    # (and only where its flow lines the events up: noise alone supports no flow)
    valid = aligned_support(events, flow, (t0 + t1) // 2)
    # the lower of the two gains decides: hot pixels can leave the multi-reference focus
    # above the threshold while the flow blurs the window
    gains = [g for g in (fwl, focus if with_iwes else float("nan")) if np.isfinite(g)]
    no_focus, chance, halves = (_verdict(checked, flow, (t0 + t1) // 2, gains) if check
                                else (False, float("nan"), float("nan")))
    other = 0
    if no_focus:
        valid = np.zeros_like(valid)
        beyond = False  # said already: not a measurement at all
    elif check and len(checked):
        # a region whose motion the network's flow (or the window's one translation)
        # does not follow (probe BZ: a patch's flow over its background, AEE above the
        # zero flow's, valid): numpy's scores, the path imports no numba
        xc, yc, _, sc = _pixels_and_times(checked)
        valid, other = other_motion(xc, yc, sc, disp, valid, "network's flow")
    if beyond:
        # (it said "a lower bound" of flows 2-2.6x too large, on smooth textures whose
        # focus kept rising with the gain, probe CD)
        warnings.warn(f"the network's flow needed the largest gain tried ({gain}x its own): "
                      "its magnitude is not measured: the window's motion may exceed what "
                      "the network measures (the flow then a lower bound), or the focus "
                      "keeps rising with the flow on a texture too smooth to pin it (then "
                      "too large); use shorter windows (--window-events) or multicm",
                      PoorFitWarning, stacklevel=2)
    total = time.perf_counter() - t_start
    compiled = compile_seconds() - c_start
    return FlowResult(flow=flow, t0_us=t0, t1_us=t1, t_ref_us=(t0 + t1) // 2, params=(),
                      iwes=iwes, focus=float(focus), history=[],
                      # numba's first-use compilation (voxel grid, IWEs) apart, as multicm's
                      timings={"network_s": t_net, "total_s": total, "compile_s": compiled,
                               "estimate_s": total - compiled},
                      time_aware=None,
                      n_bins=0, n_events=len(events), valid=valid,
                      meta={"method": "dnn", "checkpoint": str(checkpoint or "shipped"),
                            "backend": backend,
                            "input_scale": best, "time_reversal": bool(time_reversal),
                            "gain": gain, "no_focus": bool(no_focus) if check else None,
                            "translation": moved is not None,
                            "planar": plane is not None,
                            "planar_params": None if plane is None else plane[0].tolist(),
                            "refined": refined is not None,
                            "fwl": float(fwl),
                            "hot_pixels": int(hot.sum()), "beyond_range": beyond,
                            "chance_gain": chance, "halves_correlation": halves,
                            "other_motion_tiles": other})
