"""Event-based background-oriented schlieren (thesis ch. 6, §6.4).

The flow of a schlieren scene is estimated from the events between two frames and the
first frame of a textured background. The measured brightness increment is the per-pixel
sum of the events' polarities (6.8), times the contrast threshold C where it is known,
Gaussian-smoothed with sigma = 2 px. The linearized event generation model (6.9) predicts
it from the log frame ``L`` as ``-grad L(x + p) . v dt``, with a per-pixel translation
``p`` of the frame (to first order: ``grad L + H p``). The objective (6.10) is::

    E = data + lambda_1 * mean(w * |grad v|) + lambda_2 * mean(|p|)

with the weighted TV weight ``w = 1 - alpha b`` (``b`` the sigma = 5 px event histogram
normalized to [0, 1]). Two data terms:

* ``"normalized"`` (6.11): ``mean |pred / rms(pred) - meas / rms(meas)|``, the thesis' term. It
  cannot see the flow's scale; with a contrast threshold (given, or estimated from the next
  frame) the solution is rescaled by the least-squares factor between the prediction and
  C times the event sum (``BosResult.scale``).
* ``"scale"``: ``mean |pred - C sum(p)| / rms(C sum(p))``, compared unnormalized, so the flow
  comes out in px directly; needs C.

The flow is parameterized on a patch grid either directly (``param="flow"``) or as the Sobel
gradient of a scalar field q (``param="poisson"``, §6.4.3), bilinearly interpolated to the
pixels, and solved coarse to fine (patches 64 -> 32 -> 16 -> 8 px) with Adam (lr 0.05
decaying exponentially to 0.1 x lr over each scale's iterations, §6.4.5). Gradients are
analytic (numba kernels in :mod:`evmotion.methods.bos_kernels`; every absolute value is a
Charbonnier ``sqrt(r^2 + eps^2) - eps`` with a small eps so that it is differentiable).

Differences from the thesis, and why:

* all terms are pixel means (the thesis writes sums; its data term of unit-norm images is
  the mean times sqrt(N)): lambda then means the same at any ROI size;
* at the coarse scales the objective may be evaluated on block-pooled images
  (``BosOptions.pool``): pooling commutes with the gradient, so for a flow that is smooth
  over a block the pooled increment is the pooled frame's prediction; the finest scale
  always runs on full-resolution pixels. With ``pool=None`` and ``tol=0`` this is the
  thesis' schedule exactly;
* crossing to a finer scale, q is doubled so that the flow (Sobel over the patch grid,
  whose spacing halves) is continuous;
* the model frame is smoothed with the measurement's Gaussian (sigma = 2 px) before its
  gradient: the smoothed increment of a smooth flow is ``-(G * grad L) . v``, and without
  it the scale-aware term returned about 0.2x the flow's magnitude on LEGM data;
* p enters to first order and is bounded to +-``p_max`` (0.5 px) per component;
* the returned q is the potential of the returned flow (:func:`potential_from_flow`), not
  the solver's patch-grid q: the Sobel over patches is blind to constants and odd-even
  patterns, which the random initialization leaves in that q, so its pictures showed a
  lattice that the flow does not have.

Measured (``benchmarks/results/bos_magnitude.md``, ``bos_accuracy.md``, ``bos.md``): on
simulated plume, jet, breath and ice scenes (360x320, 2 px) Poisson beats Flow in AEE and
AE in every window. The events under-count the log change (C times the event sums against
the LEGM prediction with the true flow: slope 0.36 on the 640x720 jet, 0.53 plume,
0.84-0.86 breath and ice, while the frames' difference has slope 1.00-1.07); C is
therefore estimated by regressing the event sums on the frames' difference
(:func:`estimate_contrast_threshold`, method "auto"), which folds the under-count into C:
the scale-aware term's median ``|v|/|v_gt|`` on the 640x720 scenes is 0.93, 0.98, 0.99, 0.98
(plume, jet, breath, ice; 0.89, 0.85, 0.97, 0.97 with the reduced-major-axis C), AEE
+1 %, +6 %, +1 %, +0.5 %. One 640x720 interval on one core
(CPU time, ``benchmarks/results/bos.md``): 15.8 s with the thesis' schedule, 2.81 s
with the defaults 150/150/150/300 on pooled coarse scales (+0.16 % of the thesis' final
objective, same AEE), 6.0 s with ``iterations=600`` (-0.01 %).
Against Farneback on two noise-free frames (AE 0.04-0.06 rad there, 0.08-0.16 here) the
events' quantization is what loses, not the solver: fed the frames' log difference
(``increment=``) the same solver reaches 0.02-0.03 rad, and the frame time of the
gradient, the thesis' schedule and w = 1 change nothing (``bos_diagnosis.md``).

Units: flow in px/s (u right, v down), q in px^2/s (``v ~ grad q``), p in px.
"""

from __future__ import annotations

import functools
import time
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.ndimage import (
    distance_transform_edt,
    gaussian_filter,
    map_coordinates,
    maximum_filter,
    uniform_filter,
)

from evmotion.catalog import MIN_THRESHOLD
from evmotion.errors import (
    EmptyWindowError,
    EventDataError,
    EvmotionError,
    EvmotionWarning,
    InvertedPolarityError,
    ParameterError,
    UnderfitWarning,
)
from evmotion.events import EventArray, require_events
from evmotion.methods.bos_kernels import (
    LevelBuffers,
    LevelGrid,
    LevelImages,
    ObjectiveTerms,
    interp_index,
    objective_grad,
    upsample,
)
from evmotion.methods.flowresult import SUPPORT_MIN_EVENTS, SUPPORT_RADIUS, event_box_counts
from evmotion.utils import is_finite_number, is_whole_number

__all__ = [
    "BosOptions",
    "BosResult",
    "BosLevel",
    "NoEventsInWindowError",
    "TexturelessFrameError",
    "estimate_bos",
    "estimate_bos_sequence",
    "iter_bos_sequence",
    "estimate_contrast_threshold",
    "contrast_threshold_slope",
    "event_sums",
    "exposure_change",
    "frame_texture",
    "log_difference_noise",
    "log_frame",
    "texture_correlation",
    "noise_floor_count",
    "potential_from_flow",
    "quantized_frame",
    "still_air",
]

# below it, the events do not measure the frames' change (estimate_contrast_threshold)
MIN_CORRELATION = 0.3
# below this correlation over the pixels within NEAR_EVENTS_PX of an event (fired or not),
# the events follow the frames' change too weakly for a sure magnitude (warned)
WEAK_CORRELATION = 0.45
NEAR_EVENTS_PX = 10.0
#: Below this :func:`texture_correlation` a background varies from one pixel to the next
#: and its gradient does not predict the change (warned).
MIN_TEXTURE_CORRELATION = 0.25
#: Displacement over a frame interval (px, 95th percentile where events support the flow)
#: from which :func:`estimate_bos` warns that the linearized model underestimates it, or
#: with ``BosOptions.relinearize`` solves again with the frame warped by its flow.
RELINEARIZE_PX = 1.0
LARGE_DISPLACEMENT_NOTE = (
    f"the linearized model (6.9) holds within ~{RELINEARIZE_PX:g} px, beyond it the "
    "magnitude comes out too small (0.58-0.98x above 1.5 px on scenes moving up to 3-5 "
    "px): a higher frame rate keeps it small; relinearize=2 (--relinearize 2) solves "
    "again at the flow found, which can correct smooth air but raised the error of finer "
    "structures (benchmarks/results/bos_relinearize.md)")
#: Largest contrast threshold accepted, log units (sensors: 0.1-0.5): beyond it the
#: predicted increments overflow float32.
MAX_CONTRAST_THRESHOLD = 10.0
#: Most Adam iterations of one scale (the thesis' schedule: 600).
MAX_ITERATIONS = 100_000
#: Widest smoothing of the measurements and of the data weights, px.
MAX_SIGMA_PX = 1000.0


class TexturelessFrameError(ParameterError):
    """The interval's frame shows no texture in the ROI (uniform, black, out of focus):
    nothing to measure the background's displacement against."""


class NoEventsInWindowError(EventDataError):
    """No event of the recording lies in the interval: frames and events on other clocks,
    or, in a sequence, an interval before its first event or after its last, which
    ``on_empty="skip"`` skips as it does one without events in the ROI."""


_ADAM_B1, _ADAM_B2, _ADAM_EPS = 0.9, 0.999, 1e-8


@dataclass(frozen=True)
class BosOptions:
    """Settings of :func:`estimate_bos` (defaults: the thesis' §6.4 with pooled coarse
    scales and a convergence stop, and for the scale-aware term a shorter schedule,
    150/150/150/300 Adam iterations with the learning rate decaying over each scale; on a
    640x720 plume interval its final objective is within 0.3 % of the thesis' 600 per
    scale at a fifth of the time: ``benchmarks/results/bos.md``. The normalized term
    keeps 600 per scale: its scale is free, and the flow of the random initial q shrinks
    to a usable solution only over them (150/150/150/300: median ``|v|/|v_gt|`` 0.38 after
    the rescale by C on that plume, 600: 0.89). ``iterations=600, pool=None, tol=0`` runs
    the thesis' schedule exactly).

    Attributes
    ----------
    param : {"poisson", "flow"}
        Flow as the Sobel gradient of q on the patch grid (§6.4.3), or directly.
    data_term : {"normalized", "scale"}
        Thesis (6.11) of normalized increments, or the scale-aware term (needs C).
    contrast_threshold : float or None
        C in log-intensity units per net event; None: estimated from ``frame_next`` if
        given (:func:`estimate_contrast_threshold`, which folds the events' under-count
        into C: a sensor's nominal threshold gives too small a flow where the air changes
        the image by less than C, 0.76x the true one on a rendered plume at 0.20, whose
        estimate 0.26 gave 0.97x).
    rescale : bool
        With ``data_term="normalized"`` and a known C, rescale the flow by the
        least-squares factor between the prediction and the measured increment.
    scales : tuple of int
        Patch sizes in px, coarse to fine.
    iterations : int, tuple of int or None
        Adam iterations per scale (one for all, or one per scale); None: 150 at each
        coarse scale and 300 at the finest with ``data_term="scale"``, 600 each with
        ``"normalized"``.
    lr, lr_decay : float
        Adam learning rate, decaying exponentially to ``lr * lr_decay`` over a scale.
    lambda_tv, lambda_p : float
        Weights of the weighted TV of the flow and of ``|p|`` (6.12).
    alpha : float
        TV weight ``w = 1 - alpha b``.
    sigma_meas, sigma_weight : float
        Gaussian sigmas (px) of the measured increment (2) and of the event histogram b (5).
    use_p : bool
        Estimate the translation field p (False: p = 0, the Table 6.5 ablation).
    p_max : float
        Bound on each component of p in px, smooth (``p_max tanh(theta / p_max)`` on the
        patch grid): within it the first-order expansion of the smoothed frame's gradient
        holds (the authors' configuration bounds p to +-0.4 px). Unbounded, the expansion
        lets p fit residuals as a free linear term (up to 3 px on a simulated plume).
    pool : tuple of int, "auto" or None
        Block pooling factor of the images at each scale; "auto": each patch size over the
        finest (64/32/16/8 -> 8, 4, 2, 1); None: 1 everywhere (the thesis). The last scale
        is always solved at full resolution.
    tol : float
        Convergence stop: a scale ends when the objective fell by less than ``tol`` (relative)
        over the last ``patience`` iterations. 0 runs every iteration (the thesis).
    patience : int
        Iterations of the convergence window.
    eps_data, eps_reg : float
        Charbonnier eps of the data term (normalized units) and of the regularizers (px).
    log_eps : float or None
        Offset of the log frame, relative to full scale (None: half a quantization step for
        integer frames and float frames on grey levels (:func:`quantized_frame`), 1e-3 for
        other float frames).
    min_texture : float
        Least 90th percentile of ``|grad log frame|`` (log units per px) in the ROI.
    seed : int
        Seed of the uniform [-1, 1] initialization of q.
    relinearize : int
        With the scale-aware term, at most this many further solves, each with the frame
        and its gradient warped by the flow found so far and the prediction linearized
        there (as Lucas-Kanade iterates), while the flow moves the background by
        :data:`RELINEARIZE_PX` or more over the interval (95th percentile over the pixels
        whose flow events support). The linearized model (6.9) holds within the frame's
        smoothing (2 px): above 1.5 px the single solve came out at 0.58-0.98x the true
        magnitude on scenes moving up to 3-5 px. Solving again did not fix it
        reliably (``benchmarks/results/bos_relinearize.md``): the AEE changed by -6 % to
        +11 % on the simulator's scenes and rose 38 % on a rendered plume of 18-27 px
        blobs (magnitudes overshooting to 1.10x), while on a smooth wave rendered by a
        probe moving up to 6 px it fell from 1.06 to 0.43 px. 0 (default): the thesis'
        single solve, with an UnderfitWarning past :data:`RELINEARIZE_PX`.
    """

    param: str = "poisson"
    data_term: str = "normalized"
    contrast_threshold: float | None = None
    rescale: bool = True
    scales: tuple[int, ...] = (64, 32, 16, 8)
    iterations: int | tuple[int, ...] | None = None
    lr: float = 0.05
    lr_decay: float = 0.1
    lambda_tv: float = 0.5
    lambda_p: float = 0.1
    alpha: float = 0.95
    sigma_meas: float = 2.0
    sigma_weight: float = 5.0
    use_p: bool = True
    p_max: float = 0.5
    pool: tuple[int, ...] | str | None = "auto"
    tol: float = 1e-3
    patience: int = 50
    eps_data: float = 1e-3
    eps_reg: float = 1e-4
    log_eps: float | None = None
    min_texture: float = 0.02
    seed: int = 0
    relinearize: int = 0

    def __post_init__(self):
        if self.param not in ("poisson", "flow"):
            raise ParameterError(f"param must be 'poisson' or 'flow', got {self.param!r}")
        if self.data_term not in ("normalized", "scale"):
            raise ParameterError(f"data_term must be 'normalized' or 'scale', "
                                 f"got {self.data_term!r}")
        if not (isinstance(self.scales, (tuple, list)) and self.scales
                and all(is_whole_number(v) and v >= 1 for v in self.scales)):
            raise ParameterError(f"scales must be positive patch sizes in px, e.g. "
                                 f"(64, 32, 16, 8), got {self.scales!r}")
        scales = tuple(int(s) for s in self.scales)
        if any(a <= b for a, b in zip(scales[:-1], scales[1:], strict=True)):
            raise ParameterError(f"scales must run coarse to fine (decreasing patch sizes, "
                                 f"e.g. (64, 32, 16, 8)), got {self.scales!r}")
        object.__setattr__(self, "scales", scales)
        self.iterations_per_scale()
        self.pool_per_scale()
        for name in ("lr", "lambda_tv", "lambda_p", "alpha", "sigma_meas", "sigma_weight", "p_max",
                     "tol", "eps_data", "eps_reg", "min_texture", "lr_decay"):
            v = float(getattr(self, name))
            if not np.isfinite(v) or v < 0:
                raise ParameterError(f"{name} must be finite and >= 0, got {v}")
            if name.startswith("sigma_") and v > MAX_SIGMA_PX:
                # (a smoothing of 1e30 px reached scipy's "Maximum allowed size exceeded",
                # 10**30 numpy's TypeError; probe API)
                raise ParameterError(f"{name} must be at most {MAX_SIGMA_PX:g} px, got {v:g}")
        if min(self.lr, self.lr_decay, self.eps_data, self.eps_reg, self.p_max) <= 0:
            raise ParameterError("lr, lr_decay, eps_data, eps_reg and p_max must be > 0")
        if self.alpha > 1:
            raise ParameterError(f"alpha must be in [0, 1], got {self.alpha}")
        c = self.contrast_threshold
        if c is not None and not (is_finite_number(c) and c > 0):
            raise ParameterError(f"contrast_threshold must be a number > 0, got {c!r}")
        if not (is_whole_number(self.patience) and self.patience >= 1):
            raise ParameterError(f"patience must be an integer >= 1, got {self.patience!r}")
        if not (is_whole_number(self.seed) and self.seed >= 0):
            raise ParameterError(f"seed must be an integer >= 0, got {self.seed!r}")
        object.__setattr__(self, "seed", int(self.seed))  # (1e30 failed in SeedSequence)
        if not (is_whole_number(self.relinearize) and 0 <= self.relinearize <= 10):
            raise ParameterError(f"relinearize must be an integer in [0, 10], "
                                 f"got {self.relinearize!r}")
        if c is not None and not MIN_THRESHOLD <= c <= MAX_CONTRAST_THRESHOLD:
            # (1e-30 made a flow of 1e-30 px, unsaid; probe API)
            raise ParameterError(f"contrast_threshold must be in [{MIN_THRESHOLD:g}, "
                                 f"{MAX_CONTRAST_THRESHOLD:g}] (log units), got {c}")
        e = self.log_eps
        if e is not None and not (is_finite_number(e) and e > 0):
            raise ParameterError(f"log_eps must be None or a finite number > 0, got {e!r}")
        if e is not None:
            object.__setattr__(self, "log_eps", float(e))

    @classmethod
    def fast(cls, **kwargs) -> BosOptions:
        """The fast schedule (the scale-aware term's default): 150 iterations at
        each coarse scale and 300 at the finest (the learning rate decays over each),
        pooled coarse scales. On a 640x720 plume interval its final objective is within
        0.3 % of the thesis' 600 per scale at a fifth of the time
        (``benchmarks/results/bos.md``). Keyword arguments override fields."""
        n = len(kwargs.get("scales", cls.scales))
        return cls(**{"iterations": (150,) * (n - 1) + (300,), **kwargs})

    def iterations_per_scale(self) -> tuple[int, ...]:
        """Adam iterations of each scale."""
        its = self.iterations
        if its is None:
            n = len(self.scales)
            its = (150,) * (n - 1) + (300,) if self.data_term == "scale" else 600
        its = (its,) * len(self.scales) if np.isscalar(its) else tuple(its)
        # (1e30 reached numpy's "Maximum allowed dimension exceeded", probe API)
        if len(its) != len(self.scales) or not all(is_whole_number(i) and 1 <= i <= MAX_ITERATIONS
                                                   for i in its):
            raise ParameterError(f"iterations must be whole numbers in 1..{MAX_ITERATIONS}, one "
                                 f"or one per scale ({len(self.scales)}), got "
                                 f"{self.iterations!r}")
        return tuple(int(i) for i in its)

    def param_shapes(self, height: int, width: int) -> list[tuple[int, int, int]]:
        """Shape of each scale's patch-grid parameters (:attr:`BosResult.params`, the warm
        start of the next interval) for a ROI of ``height`` x ``width`` px.

        Examples
        --------
        >>> BosOptions().param_shapes(720, 640)
        [(3, 12, 10), (3, 23, 20), (3, 45, 40), (3, 90, 80)]
        """
        n = (1 if self.param == "poisson" else 2) + (2 if self.use_p else 0)
        return [(n, -(-int(height) // s), -(-int(width) // s)) for s in self.scales]

    def pool_per_scale(self) -> tuple[int, ...]:
        """Pooling factor of each scale (the last is always 1)."""
        n = len(self.scales)
        if self.pool is None:
            pool = (1,) * n
        elif isinstance(self.pool, str):
            if self.pool != "auto":
                raise ParameterError(f"pool must be 'auto', None or factors, got {self.pool!r}")
            pool = tuple(max(1, s // self.scales[-1]) for s in self.scales)
        else:
            pool = tuple(int(k) for k in self.pool)
        if len(pool) != n or min(pool) < 1:
            raise ParameterError(f"pool must hold one factor >= 1 per scale ({n}), "
                                 f"got {self.pool!r}")
        return pool[:-1] + (1,)


@dataclass
class BosResult:
    """Outcome of :func:`estimate_bos` for one frame interval.

    Attributes
    ----------
    flow : ndarray (H, W, 2) float32
        Flow in px/s on the sensor grid (zero outside the ROI).
    q : ndarray (H, W) float32
        Poisson field in px^2/s, ``flow ~ grad q``: :func:`potential_from_flow` of the
        flow over the ROI (zero mean; zero outside the ROI).
    p : ndarray (H, W, 2) float32
        Translation of the frame in px.
    valid : ndarray (H, W) bool
        Pixels of the ROI the window's events support (at least 2 events within 2 px, as
        every flow method marks them); elsewhere the flow is the regularizers'
        interpolation. Fewer than 1 % of the ROI is warned about.
    roi : (x, y, w, h)
        The ROI in px.
    t0_us, t1_us : int
        The window.
    contrast_threshold : float or None
        C used (given or estimated); None when unknown.
    calibrated : bool
        True when the flow magnitude is physical (scale term, or normalized term rescaled
        with a known C or a given ``increment`` in log units); False: only the direction
        is a measurement.
    scale : float
        Factor the normalized solution was multiplied by (1 when not rescaled).
    objective : float
        Final objective (6.10) at full resolution, before any rescaling.
    losses : list of ndarray
        Objective per iteration, per scale.
    timings_s : list of float
        Wall time per scale in seconds.
    iterations : list of int
        Iterations run per scale.
    params : list of ndarray
        Patch-grid parameters per scale (for warm starts).
    options : BosOptions
    fit_gain : float
        The measured increment regressed on the flow's predicted one over the ``valid``
        pixels (calibrated results; NaN otherwise): about 1 where the flow explains the
        events (1.01-1.08 on the simulator's and other renderers' scenes), above
        :data:`FIT_GAIN_WARN` where the flow fields cannot follow the air and its magnitude
        shrinks (1.3-1.6 with structures of 4-5 px: 0.4-0.7x the true magnitude).
    relinearized : int
        Further solves with the frame warped by the flow (``BosOptions.relinearize``).
    displacement_q95 : float
        95th percentile of the flow's displacement over the interval on the ``valid``
        pixels, px (calibrated results; NaN otherwise).
    """

    flow: np.ndarray
    q: np.ndarray
    p: np.ndarray
    valid: np.ndarray
    roi: tuple[int, int, int, int]
    t0_us: int
    t1_us: int
    contrast_threshold: float | None
    calibrated: bool
    scale: float
    objective: float
    losses: list = field(default_factory=list)
    timings_s: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    params: list = field(default_factory=list)
    options: BosOptions = field(default_factory=BosOptions)
    fit_gain: float = float("nan")
    relinearized: int = 0
    displacement_q95: float = float("nan")


# above this median fit gain over a run, the flow is said to be too small (bos_run)
FIT_GAIN_WARN = 1.25

# --------------------------------------------------------------------------- inputs

def quantized_frame(frame: np.ndarray) -> np.ndarray:
    """``frame`` on the grey levels its values lie on, so that one picture gives one flow
    whatever array it comes in: a float frame whose values are all whole 8-bit levels
    (``k / 255`` in [0, 1], as ``skimage.img_as_float`` makes them, or whole numbers up to
    255) becomes uint8, one of whole numbers up to 65535 uint16, and a uint16 frame of
    8-bit data (every value a multiple of 257, as an 8-bit image converted) uint8; any
    other frame is returned as it is. (A float frame was taken as continuous intensity:
    no quantization noise, another log offset; the flow of the same frames moved by 7 %,
    probe AN.)

    Examples
    --------
    >>> quantized_frame(np.array([[0.0, 1.0, 128 / 255]])).tolist()
    [[0, 255, 128]]
    >>> quantized_frame(np.array([[0, 257 * 200]], np.uint16)).dtype
    dtype('uint8')
    >>> quantized_frame(np.array([[0, 257 * 200]], ">u2")).tolist()  # big-endian
    [[0, 200]]
    >>> quantized_frame(np.array([[0.0, 0.3]])).dtype   # not on a grid: as it is
    dtype('float64')
    """
    f = np.asarray(frame)
    if not f.dtype.isnative:  # as read from a big-endian file: the same picture
        f = f.astype(f.dtype.newbyteorder("="))
    if f.size == 0:
        return f
    if f.dtype == np.uint16 and not np.any(f % 257):
        return (f // 257).astype(np.uint8)
    if f.dtype.kind != "f" or not np.isfinite(f).all() or f.min() < 0:
        return f
    top = float(f.max())
    for scale, limit, dtype in ((255.0, 1.0, np.uint8), (1.0, 255.0, np.uint8),
                                (1.0, 65535.0, np.uint16)):
        if top <= limit:
            levels = f.astype(np.float64) * scale
            whole = np.rint(levels)
            if np.all(np.abs(levels - whole) <= 1e-4):
                return whole.astype(dtype)
    return f


def log_frame(frame: np.ndarray, eps: float | None = None, name: str = "frame") -> np.ndarray:
    """Log intensity ``log(I / full_scale + eps)`` of a grayscale frame (float64).

    Integer frames are scaled by their dtype's maximum (uint8: 255); float frames are taken
    as relative intensity, unless their values lie on grey levels (:func:`quantized_frame`:
    then as those integers). ``eps`` defaults to half a quantization step for integer
    frames and 1e-3 for float frames. ``name`` is the argument the messages name.

    >>> log_frame(np.array([[255, 0]], np.uint8)).round(3).tolist()
    [[0.002, -6.234]]
    >>> log_frame(np.array([[1.0, 0.0]])).round(3).tolist()   # 8-bit levels as floats
    [[0.002, -6.234]]
    """
    f = quantized_frame(frame)
    if f.ndim != 2:
        raise ParameterError(f"{name} must be a 2-D grayscale image, got shape {f.shape}")
    if np.issubdtype(f.dtype, np.integer):
        full = float(np.iinfo(f.dtype).max)
        e = 0.5 / full if eps is None else float(eps)
    else:
        full = 1.0
        e = 1e-3 if eps is None else float(eps)
    if not (np.isfinite(e) and e > 0):
        raise ParameterError(f"log_eps must be a finite number > 0, got {eps!r}")
    g = f.astype(np.float64) / full
    if not np.isfinite(g).all():
        raise ParameterError(f"{name} has NaN or inf values")
    if (g < 0).any():
        raise ParameterError(f"{name} has negative intensities (min {g.min():g})")
    return np.log(g + e)


def _texture(logf: np.ndarray) -> float:
    """90th percentile of ``|grad log I|`` (log units per px) of a log frame."""
    gy, gx = np.gradient(logf)
    return float(np.quantile(np.hypot(gx, gy), 0.9))


def frame_texture(frame: np.ndarray, roi=None, log_eps: float | None = None) -> float:
    """The texture :func:`estimate_bos` requires of a frame (at least
    ``BosOptions.min_texture``): the 90th percentile of ``|grad log I|`` in the ROI, log
    units per px.

    Examples
    --------
    >>> frame_texture(np.full((32, 32), 100, np.uint8))
    0.0
    """
    x, y, w, h = _check_roi(roi, np.shape(frame)[:2])
    return _texture(log_frame(frame, log_eps)[y:y + h, x:x + w])


def texture_correlation(frame: np.ndarray, roi=None, log_eps: float | None = None) -> float:
    """How smooth a background is at the pixel scale: the correlation of neighbouring
    pixels (right and below, averaged) of its log frame in the ROI, less a 4-px Gaussian
    blur (lighting). The model (6.9) predicts the change from the frame's gradient, which
    pixel-to-pixel noise or 1-px dots do not resolve: on a white-noise background (0.01)
    the flow came out worse than the zero flow; dots of 1-3 px, speckle and natural
    textures score 0.5-0.9 (:data:`MIN_TEXTURE_CORRELATION`).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> noise = rng.integers(20, 235, (64, 64)).astype(np.uint8)
    >>> abs(texture_correlation(noise)) < 0.05
    True
    """
    x, y, w, h = _check_roi(roi, np.shape(frame)[:2])
    logf = log_frame(frame, log_eps)[y:y + h, x:x + w]
    hp = (logf - gaussian_filter(logf, 4.0, mode="nearest"))[4:-4, 4:-4]
    power = float(np.mean(hp * hp))
    if not power > 0:
        return float("nan")
    return 0.5 * float(np.mean(hp[:, 1:] * hp[:, :-1]) + np.mean(hp[1:] * hp[:-1])) / power


def _check_roi(roi, sensor):
    h, w = sensor
    if roi is None:
        roi = (0, 0, w, h)
    try:
        vals = list(roi)
    except TypeError:
        vals = []
    if len(vals) != 4 or not all(is_whole_number(v) for v in vals):
        raise ParameterError(f"roi must be (x, y, w, h), whole px, got {roi!r}")
    x, y, rw, rh = (int(v) for v in vals)
    if rw < 16 or rh < 16:
        what = "the sensor" if (x, y, rw, rh) == (0, 0, w, h) else "roi"
        raise ParameterError(f"{what} ({rw}x{rh} px) is smaller than the 16x16 px that BOS "
                             "needs")
    if x < 0 or y < 0 or x + rw > w or y + rh > h:
        raise ParameterError(f"roi (x={x}, y={y}, w={rw}, h={rh}) must lie inside the "
                             f"{w}x{h} sensor")
    return x, y, rw, rh


def _check_overlap(events: EventArray, t0_us: int, t1_us: int, what: str) -> None:
    """Raise :class:`NoEventsInWindowError` unless an event lies in ``[t0_us, t1_us)``."""
    if len(events) == 0 or events.t[-1] < t0_us or events.t[0] >= t1_us:
        span = "no events" if len(events) == 0 else \
            f"events span [{int(events.t[0])}, {int(events.t[-1])}] us"
        raise NoEventsInWindowError(f"frames and events do not overlap in time: {what} "
                                f"[{t0_us}, {t1_us}) us, {span}")


def _window_events(events: EventArray, t0_us: int, t1_us: int, roi) -> EventArray:
    if t1_us <= t0_us:
        raise ParameterError(f"the window must have t1_us > t0_us, got [{t0_us}, {t1_us}) us")
    _check_overlap(events, t0_us, t1_us, "window")
    ev = events.slice_time(t0_us, t1_us)
    x, y, rw, rh = roi
    xs = ev.x.astype(np.int64)
    ys = ev.y.astype(np.int64)
    inside = (xs >= x) & (xs < x + rw) & (ys >= y) & (ys < y + rh)
    if not inside.any():
        raise EmptyWindowError(f"no events in the window [{t0_us}, {t1_us}) us inside the "
                               f"ROI (x={x}, y={y}, w={rw}, h={rh})")
    return ev


def event_sums(events: EventArray, roi=None, *, t0_us: int | None = None,
               t1_us: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel polarity sums (+1/-1) and event counts of the events in ``[t0, t1)``
    inside ``roi = (x, y, w, h)``; two (h, w) float64 images.

    >>> ev = EventArray(x=[0, 0, 1], y=[0, 0, 0], t=[0, 1, 2], p=[1, 1, 0],
    ...                 sensor_size=(1, 2))
    >>> [a.tolist() for a in event_sums(ev)]
    [[[2.0, -1.0]], [[2.0, 1.0]]]
    """
    x0, y0, rw, rh = _check_roi(roi, events.sensor_size) if roi is not None else \
        (0, 0, events.sensor_size[1], events.sensor_size[0])
    ev = events
    if t0_us is not None and t1_us is not None and int(t1_us) <= int(t0_us):
        raise ParameterError(f"t1_us={t1_us} must be after t0_us={t0_us}")
    if t0_us is not None or t1_us is not None:
        ev = events.slice_time(events.t[0] if t0_us is None else t0_us,
                               events.t[-1] + 1 if t1_us is None else t1_us)
    xs = ev.x.astype(np.int64) - x0
    ys = ev.y.astype(np.int64) - y0
    keep = (xs >= 0) & (xs < rw) & (ys >= 0) & (ys < rh)
    idx = ys[keep] * rw + xs[keep]
    pol = np.where(ev.p[keep] > 0, 1.0, -1.0)
    sums = np.bincount(idx, weights=pol, minlength=rw * rh).reshape(rh, rw)
    counts = np.bincount(idx, minlength=rw * rh).reshape(rh, rw).astype(np.float64)
    return sums, counts


def estimate_contrast_threshold(events: EventArray, frame: np.ndarray, frame_next: np.ndarray,
                                *, t0_us: int, t1_us: int, roi=None,
                                sigma: float | None = None, method: str = "auto",
                                log_eps: float | None = None,
                                min_correlation: float = MIN_CORRELATION,
                                frame_after: np.ndarray | None = None) -> float:
    """Contrast threshold C from two frames and the events between them.

    Per pixel, the log-frame difference ``D = L(t1) - L(t0)`` and the events' polarity sum
    ``S`` (both smoothed with ``sigma``: None is 2 px for "auto", 1 px for the others)
    obey ``C S ~ D`` over the pixels with events near them ("auto": with events). Both are
    noisy measurements of the same change: D carries the frames' noise (shot noise,
    quantization), and S the leftover below threshold at both ends of the window, which the
    sensor's hysteresis (a pixel must travel a full C back after an event) makes large where
    the schlieren flickers by less than C. So the one-sided regressions
    disagree, and:

    * ``method="events"``: ``cov(D, S) / var(S)``, D regressed on S: the change per net
      event. Unbiased by frame noise; close to the sensor's nominal C where the changes are
      large against C, below it where they are not.
    * ``method="frames"``: ``(var(D) - var(noise)) / cov(D, S)``, S regressed on D with the
      frame noise's attenuation removed (its variance measured where no event fired within
      ~10 px, still air, at the same log levels). Above the nominal C where the changes are small.
    * ``method="rma"``: their geometric mean, the reduced-major-axis slope that treats both
      sides as noisy; where the frame noise exceeds half of var(D) the "events" slope alone.
    * ``method="auto"`` (default): the "frames" slope, with ``sigma`` the data term's
      (2 px) and over the pixels that fired; where the frame noise exceeds half of var(D),
      the "events" slope. This is the C that calibrates the scale-aware data
      term: the solver fits the (noise-free) prediction ``P`` to ``C S``, so the flow's
      scale it returns is about ``C cov(P, S) / var(P)``, and ``P`` of the true flow
      follows ``D`` (slope 1.00-1.07 on the simulated scenes): the flow comes out at its
      true scale when ``C = var(D) / cov(D, S)``, S regressed on D. The events'
      under-count (no event below threshold; sign reversals within the window cost up to
      2C without an event) is then part of the calibration, not noise shared between the
      sides as "rma" has it. On the 640x720 simulated scenes the median ``|v|/|v_gt|`` of the
      scale-aware term is 0.93-0.99 with it, 0.85-0.97 with "rma"
      (``benchmarks/results/bos_accuracy.md``); over the pixels within ~sigma of an event
      (a ring of pixels below threshold with them) 1.02-1.12. Above that noise level the
      noise-corrected "frames" slope is unreliable (on a 360x320 plume: 0.2 %, 2 % and
      9 % above the noise-free one at 1000, 300 and 100 photons per white pixel, noise
      0.10, 0.27 and 0.49 var(D); 35 % at 30 photons, 0.78), and the events' own slope
      is the fallback.

    The frame noise is measured on still air (:func:`still_air`): pixels with no event
    within ~10 px or, amid the sensor's noise events, as few events as the view's
    quietest pixels, which do not follow the frames' change. Where
    the air moves everywhere in view there is none, and with ``frame_after`` (the frame
    after ``frame_next``) it is measured in time instead: the second difference of the
    three log frames holds the noise of the log difference three times over, plus how
    much the change itself changed from one interval to the next (an upper bound; steady
    air adds little). Without either the noise is taken as nil: on a uniform 0.06 px
    shift in noisy 8-bit frames (no still air) C came out 0.14 and 0.30 for a sensor at
    0.1, and 0.094 and 0.082 (events' slope) measured in time.

    Where ``D`` and ``S`` correlate less than ``min_correlation`` over the fitted pixels
    the events do not measure the frames' change -- still air (the events are noise: -0.12
    to 0.20 on rendered scenes with no air, against 0.66-0.98 with it), light so low that
    noise events swamp them (0.07-0.28 on a simulated plume at 100-300 photons per white
    pixel; at 100 photons the slope came out 2.85 and 10.2 for a sensor at C = 0.27,
    ``benchmarks/results/bos_lowlight.json``), or frames not registered with the events --
    and no C is returned.

    Returns
    -------
    float
        C in log-intensity units.

    Raises
    ------
    EventDataError
        When the frames do not change where events fire (no slope to fit), or the events'
        sums correlate with the frames' change less than ``min_correlation``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> f0 = rng.uniform(0.2, 1.0, (32, 32))
    >>> d = rng.normal(0, 0.3, (32, 32))
    >>> s = np.round(d / 0.15).astype(int)  # events of a sensor with C = 0.15
    >>> ys, xs = np.nonzero(s)
    >>> n = np.abs(s[ys, xs])
    >>> ev = EventArray(x=np.repeat(xs, n), y=np.repeat(ys, n), t=np.zeros(n.sum(), int),
    ...                 p=np.repeat(s[ys, xs] > 0, n), sensor_size=(32, 32))
    >>> c = estimate_contrast_threshold(ev, f0, f0 * np.exp(d), t0_us=0, t1_us=1, sigma=0)
    >>> round(c, 2)
    0.15
    """
    return contrast_threshold_slope(events, frame, frame_next, t0_us=t0_us, t1_us=t1_us,
                                    roi=roi, sigma=sigma, method=method, log_eps=log_eps,
                                    min_correlation=min_correlation,
                                    frame_after=frame_after)[0]


def contrast_threshold_slope(events: EventArray, frame: np.ndarray, frame_next: np.ndarray,
                             *, t0_us: int, t1_us: int, roi=None, sigma: float | None = None,
                             method: str = "auto", log_eps: float | None = None,
                             min_correlation: float = MIN_CORRELATION,
                             frame_after: np.ndarray | None = None
                             ) -> tuple[float, str, float]:
    """:func:`estimate_contrast_threshold` (the same arguments), the slope it returned
    (``"frames"``, or :data:`TIMED_NOISE` where the frames' noise was measured in time;
    ``"events"``: also the fallback where the frames' noise exceeds half
    their change, low where the air changes the image by less than C; or ``"rma"``) and
    the correlation of the events' sums with the frames' change over every pixel within
    :data:`NEAR_EVENTS_PX` of an event. Below :data:`WEAK_CORRELATION` the flow's
    magnitude is uncertain: on 21 scenes (15 from an independent renderer, 6 from the
    simulator at 240x320) it marked 9 of the 16 whose median ``|v|/|v_gt|`` left
    [0.9, 1.1] (those 9: 0.18-1.24) and none of the 5 within."""
    if method not in ("auto", "rma", "events", "frames"):
        raise ParameterError(f"method must be 'auto', 'rma', 'events' or 'frames', got "
                             f"{method!r}")
    if not -1.0 <= min_correlation <= 1.0:
        raise ParameterError(f"min_correlation must be in [-1, 1], got {min_correlation!r}")
    sensor = events.sensor_size
    for name, f in (("frame", frame), ("frame_next", frame_next), ("frame_after", frame_after)):
        if f is not None and np.shape(f) != tuple(sensor):
            raise EventDataError(f"{name} has shape {np.shape(f)} but the events' sensor is "
                                 f"{tuple(sensor)} (H, W): frames and events do not overlap "
                                 "in size")
    x, y, rw, rh = _check_roi(roi, sensor)
    ev = _window_events(events, t0_us, t1_us, (x, y, rw, rh))
    if sigma is None:
        sigma = 2.0 if method == "auto" else 1.0
    if not (is_finite_number(sigma) and 0 <= sigma <= 1000):
        raise ParameterError(f"sigma must be a number of px in [0, 1000], got {sigma!r}")
    # the frames' noise is the camera's, not the ROI's: it is measured on the still air of
    # the whole view (an ROI drawn around the plume holds little of it, and the noise
    # measured in time instead, an upper bound that counts the air's own change, had
    # lowered C from 0.257 to 0.206 and the flow from 0.97x to 0.79x the true one, probe)
    s_all, counts_all = event_sums(ev)
    l0_all, l1_all = log_frame(frame, log_eps), log_frame(frame_next, log_eps, "frame_next")
    d_all, level_all = l1_all - l0_all, 0.5 * (l0_all + l1_all)
    if sigma > 0:
        s_all = gaussian_filter(s_all, sigma, mode="nearest")
        d_all = gaussian_filter(d_all, sigma, mode="nearest")
        level_all = gaussian_filter(level_all, sigma, mode="nearest")
    crop = (slice(y, y + rh), slice(x, x + rw))
    s, counts, d = s_all[crop], counts_all[crop], d_all[crop]
    l0, l1 = l0_all[crop], l1_all[crop]
    # "auto" fits over the pixels that fired, as the solver's data term measures there;
    # the others over the pixels with events within about sigma
    near = counts > 0
    if sigma > 0 and method != "auto":
        near = gaussian_filter(counts, sigma, mode="nearest") > 0.05
    quiet = still_air(counts_all, d_all, s_all)
    d_all -= exposure_change(d_all, quiet)  # in place: d is its view
    near_all = np.zeros(sensor, bool)
    near_all[crop] = near
    noise = _frame_noise(d_all, level_all, quiet, near_all)
    timed = noise is None and frame_after is not None and near.any()
    if timed:
        after = log_frame(frame_after, log_eps, "frame_after")[crop]
        noise = log_difference_noise(l0, l1, after, sigma, near)
    noise = max(noise or 0.0,
                _quantization_noise(frame, frame_next, crop, sigma, near, log_eps))
    dd, ss = d[near], s[near]
    var_d, cov, var_s = (float(np.mean(v)) for v in (dd * dd, dd * ss, ss * ss))
    corr = cov / np.sqrt(var_d * var_s) if var_d > 0 and var_s > 0 else 0.0
    if dd.size >= 16 and corr <= -min_correlation:
        # ON events where the frames darken: the flow would come out reversed (probe AT)
        raise InvertedPolarityError(
            f"the events' polarity sums in [{t0_us}, {t1_us}) us anti-correlate with the "
            f"frames' log difference (correlation {corr:.2f} over {dd.size} pixels): their "
            "polarity is inverted (ON where the frames darken)? Flip it (evmotion convert "
            "IN OUT --invert-polarity) and run again")
    if dd.size < 16 or cov <= 0 or var_s <= 0:
        raise EventDataError(f"cannot estimate the contrast threshold in [{t0_us}, {t1_us}) "
                             f"us: the events' polarity sums do not follow the frames' log "
                             f"difference in the ROI "
                             f"(covariance {cov:.3g}): no texture, still air or events "
                             "that are noise; give contrast_threshold "
                             "(--contrast-threshold) if you know C")
    if corr < min_correlation:
        raise EventDataError(f"cannot estimate the contrast threshold in [{t0_us}, {t1_us}) "
                             f"us: the events' polarity sums correlate {corr:.2f} with the "
                             f"frames' log difference over "
                             f"{dd.size} pixels (< {min_correlation:g}): no schlieren in this "
                             "interval, events swamped by noise, or frames not registered "
                             "with the events; give contrast_threshold (--contrast-threshold)")
    c_events = cov / var_s
    c_frames = (var_d - noise) / cov
    # how well the events follow the change around them, the pixels below threshold too:
    # the fired pixels alone are selected by the events and correlate well even where
    # most of the air's change goes unseen
    ring = distance_transform_edt(counts == 0) <= NEAR_EVENTS_PX
    dr, sr = d[ring], s[ring]
    ring_var = float(np.mean(dr * dr)) * float(np.mean(sr * sr))
    ring_corr = float(np.mean(dr * sr)) / np.sqrt(ring_var) if ring_var > 0 else 0.0
    if method == "events":
        return float(c_events), "events", ring_corr
    if method == "frames":
        if c_frames <= 0:
            raise EventDataError("cannot estimate the contrast threshold from the frames: "
                                 "their noise exceeds their change (use method='events')")
        return float(c_frames), "frames", ring_corr
    if noise > 0.5 * var_d or c_frames <= 0:
        return float(c_events), "events", ring_corr
    if method == "auto":
        return float(c_frames), TIMED_NOISE if timed else "frames", ring_corr
    return float(np.sqrt(c_frames * c_events)), "rma", ring_corr


#: Still air among noise events: the pixels whose events (5 px around) are at most this many
#: times the view's 10th percentile (:func:`still_air`)
QUIET_FLOOR_FACTOR = 2.0
#: ... accepted as still air where their events follow the frames' change less than this
QUIET_MAX_CORRELATION = 0.1
#: Fewest still-air pixels on which the frames' noise is measured (:func:`_frame_noise`)
MIN_QUIET_PIXELS = 100


def still_air(counts: np.ndarray, d: np.ndarray, s: np.ndarray) -> np.ndarray:
    """The pixels of still air, on which the frames' noise is measured: those with no
    event within about 5 px (smoothed count at most 1e-3 of its maximum); where fewer
    than :data:`MIN_QUIET_PIXELS` are, the sensor's noise events may be everywhere, so
    the pixels whose smoothed count is at most :data:`QUIET_FLOOR_FACTOR` times the
    view's 10th percentile, if their events' sums ``s`` follow the frames' log
    difference ``d`` by less than :data:`QUIET_MAX_CORRELATION` (noise, not air).

    Probe DI: amid noise events of 2-10 Hz a pixel, a plume with still air around it had
    none by the first test; the frames' noise was then measured in time, C came out
    0.15 for 0.2 and the flow 0.85x.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> counts = rng.poisson(0.05, (64, 64)).astype(float)   # noise events everywhere
    >>> d, s = rng.normal(0, 0.01, (64, 64)), rng.normal(0, 1, (64, 64))
    >>> counts[:, :16] += 5                                   # and air on the left
    >>> quiet = still_air(counts, d, s)
    >>> bool(quiet[:, 24:].mean() > 0.5), bool(quiet[:, :8].any())
    (True, False)
    """
    wide = gaussian_filter(counts, 5.0, mode="nearest")
    quiet = wide <= 1e-3 * wide.max()
    if quiet.sum() >= MIN_QUIET_PIXELS:
        return quiet
    floor = wide <= QUIET_FLOOR_FACTOR * np.percentile(wide, 10.0)
    if floor.sum() < MIN_QUIET_PIXELS:
        return quiet
    dd, ss = d[floor] - d[floor].mean(), s[floor] - s[floor].mean()
    den = np.sqrt(np.mean(dd * dd) * np.mean(ss * ss))
    return floor if den > 0 and np.mean(dd * ss) / den < QUIET_MAX_CORRELATION else quiet


#: The slope :func:`contrast_threshold_slope` names "frames" where the frames' noise was
#: measured in time (no still air in view): an upper bound that counts the air's own
#: change, so C comes out low where the flow is steady over the whole view
TIMED_NOISE = "frames, noise in time"


def _quantization_noise(frame, frame_next, crop, sigma: float, fit: np.ndarray,
                        log_eps: float | None) -> float:
    """Mean variance that the frames' quantization adds to the smoothed log difference over
    the ``fit`` pixels: a uniform error of half a grey level in each frame, ``step^2 / 12``
    in intensity, ``/ I^2`` in log units, independent where the image changes. Still air
    shows none of it (an unchanged pixel rounds alike in both frames), so
    :func:`_frame_noise` misses it; in dark frames it dominates (a background imaged at 20
    grey levels raised the estimated C by half). 0 for float frames."""
    frame, frame_next = quantized_frame(frame), quantized_frame(frame_next)
    if not (np.issubdtype(frame.dtype, np.integer)
            and np.issubdtype(frame_next.dtype, np.integer)):
        return 0.0
    var = np.zeros(np.asarray(frame)[crop].shape)
    for f in (frame, frame_next):
        full = float(np.iinfo(np.asarray(f).dtype).max)
        e = 0.5 / full if log_eps is None else float(log_eps)
        g = np.asarray(f)[crop].astype(np.float64) / full
        var += (1.0 / full) ** 2 / 12.0 / (g + e) ** 2
    if sigma > 0:
        # the smoothed difference sums the pixels' errors with the kernel's squared
        # weights: a Gaussian of sigma / sqrt(2) scaled by 1 / (4 pi sigma^2)
        var = gaussian_filter(var, sigma / np.sqrt(2.0), mode="nearest") \
            / (4.0 * np.pi * sigma * sigma)
    return float(np.mean(var[fit])) if fit.any() else 0.0


def log_difference_noise(l0: np.ndarray, l1: np.ndarray, l2: np.ndarray, sigma: float,
                         mask: np.ndarray) -> float:
    """The frames' noise variance in the log difference ``l1 - l0`` (smoothed with
    ``sigma`` px) over the ``mask`` pixels, measured in time from three consecutive log
    frames: their second difference holds each frame's independent noise (1 + 4 + 1 times,
    the difference 1 + 1), so its mean square over 3, plus how much the change itself
    changed from one interval to the next: an upper bound, close where the air is steady.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> logs = [rng.normal(0.0, 0.1, (64, 64)) for _ in range(3)]  # noise alone
    >>> round(log_difference_noise(*logs, 0, np.ones((64, 64), bool)) / 0.02, 1)
    1.0
    """
    second = l2 - 2.0 * l1 + l0
    if sigma > 0:
        second = gaussian_filter(second, sigma, mode="nearest")
    return float(np.mean(second[mask] ** 2)) / 3.0


def exposure_change(d: np.ndarray, still: np.ndarray) -> float:
    """The change of the whole frame's log intensity in a log difference ``d`` of two
    frames (a camera's auto-exposure or gain, which no event sees): its median over the
    ``still`` pixels (still air) where they are 100 or more, else over every pixel (a
    moving texture changes pixels both ways about as often).

    A gain ramp of 2.5 % a frame had been taken for frames that change where no event
    fires, and had weakened the events' correlation with the frames' change (probe AY).

    Examples
    --------
    >>> d = np.full((20, 20), 0.025)
    >>> d[5:10, 5:10] += 0.3
    >>> round(exposure_change(d, np.ones_like(d, bool)), 3)
    0.025
    """
    pool = d[still] if int(np.count_nonzero(still)) >= 100 else d
    return float(np.median(pool)) if pool.size else 0.0


def _frame_noise(d: np.ndarray, level: np.ndarray, quiet: np.ndarray, fit: np.ndarray
                 ) -> float | None:
    """Mean frame-noise variance of the log difference ``d`` over the ``fit`` pixels,
    measured on the ``quiet`` ones (still air) in up to 16 bins of the log level: shot noise
    in log units grows as the intensity falls, and the pixels that fire (dot edges) are
    darker than the average (on a 360x320 plume at 300 photons the plain mean
    under-corrected C_frames by 7 %, the binned one by 2 %). None with < 100 quiet pixels
    (not measured)."""
    n_bins = min(16, int(quiet.sum()) // MIN_QUIET_PIXELS)
    if n_bins < 1:
        return None
    edges = np.quantile(level[quiet], np.linspace(0.0, 1.0, n_bins + 1)[1:-1])
    bq = np.searchsorted(edges, level[quiet])
    var = np.bincount(bq, d[quiet] ** 2, n_bins) / np.maximum(np.bincount(bq, None, n_bins), 1)
    return float(np.mean(var[np.searchsorted(edges, level[fit])]))


# --------------------------------------------------------------------------- model

def _sobel_mats(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Smoothing [1 2 1] and central difference [-1 0 1] along one axis of the patch grid,
    border replicated."""
    sm = np.zeros((n, n))
    df = np.zeros((n, n))
    for j in range(n):
        lo, hi = max(j - 1, 0), min(j + 1, n - 1)
        sm[j, lo] += 1.0
        sm[j, j] += 2.0
        sm[j, hi] += 1.0
        df[j, hi] += 1.0
        df[j, lo] -= 1.0
    return sm, df


def _pool(img: np.ndarray, k: int) -> np.ndarray:
    if k == 1:
        return img
    h, w = img.shape[0] // k, img.shape[1] // k
    return img[:h * k, :w * k].reshape(h, k, w, k).mean(axis=(1, 3))


class BosLevel:
    """The objective (6.10) at one scale: patch size ``patch``, images pooled by ``k``.

    ``value_grad(theta, normalized)`` returns ``((total, data, tv, p), gradient)`` for the
    patch-grid parameters ``theta`` (q or (du, dv), then (pu, pv) with ``use_p``), shape
    ``(n_params(), nh, nw)``; :func:`estimate_bos` builds one per scale. Public for tests,
    benchmarks and custom solvers.
    """

    def __init__(self, patch: int, k: int, logf, meas, weight, opts: BosOptions, dtype,
                 gradient=None):
        self.patch, self.k = patch, k
        H, W = logf.shape
        self.nh, self.nw = -(-H // patch), -(-W // patch)
        lf = _pool(logf, k)
        if min(lf.shape) < 2:
            raise ParameterError(f"the ROI is too small for pooling by {k} (use pool=None)")
        gy, gx = np.gradient(lf)
        hxy, hxx = np.gradient(gx)
        hyy, hyx = np.gradient(gy)
        # per original pixel: gradient / k, Hessian / k^2 (symmetrized)
        gx, gy = gx / k, gy / k
        if gradient is not None:  # (gx, gy) per original pixel, given at full resolution
            gx, gy = _pool(gradient[0], k), _pool(gradient[1], k)
        self.gimg = np.ascontiguousarray(
            np.stack([gx, gy, hxx / k**2, 0.5 * (hxy + hyx) / k**2, hyy / k**2]),
            dtype=dtype)
        self.meas = np.ascontiguousarray(_pool(meas, k), dtype=dtype)
        self.weight = np.ascontiguousarray(_pool(weight, k), dtype=dtype)
        self.s_meas = float(np.sqrt(np.mean(self.meas.astype(np.float64) ** 2))) or 1.0
        h, w = lf.shape
        self.iy, self.fy = interp_index(h, k, self.nh, patch)
        self.ix, self.fx = interp_index(w, k, self.nw, patch)
        self.fy_d = self.fy.astype(dtype)  # the kernels' loops stay in the images' precision
        self.fx_d = self.fx.astype(dtype)
        self.sm_y, self.d_y = _sobel_mats(self.nh)
        self.sm_x, self.d_x = _sobel_mats(self.nw)
        self.buf = LevelBuffers(h, w, self.nh, dtype)
        self.gpatch = np.zeros((4, self.nh, self.nw))
        self.opts = opts

    def n_flow(self) -> int:
        """Parameters of the flow per patch: 1 (q) or 2 (du, dv)."""
        return 1 if self.opts.param == "poisson" else 2

    def patch_fields(self, theta: np.ndarray) -> np.ndarray:
        """(4, nh, nw): du, dv, pu, pv on the patch grid from the parameters."""
        out = np.zeros((4, self.nh, self.nw))
        if self.opts.param == "poisson":
            q = theta[0]
            out[0] = self.sm_y @ q @ self.d_x.T
            out[1] = self.d_y @ q @ self.sm_x.T
        else:
            out[0:2] = theta[0:2]
        if self.opts.use_p:
            pm = self.opts.p_max
            out[2:4] = pm * np.tanh(theta[self.n_flow():self.n_flow() + 2] / pm)
        return out

    def value_grad(self, theta: np.ndarray, normalized: bool) -> tuple[tuple, np.ndarray]:
        """``((total, data, tv, p), d total / d theta)``: the fields upsampled to the pixels,
        the kernel, and the adjoints of the upsampling and of the Sobel back to theta."""
        o = self.opts
        terms = self.objective(self.patch_fields(theta), normalized)
        g = np.zeros_like(theta)
        if o.param == "poisson":
            g[0] = self.sm_y.T @ self.gpatch[0] @ self.d_x + self.d_y.T @ self.gpatch[1] @ self.sm_x
        else:
            g[0:2] = self.gpatch[0:2]
        if o.use_p:
            th = np.tanh(theta[self.n_flow():self.n_flow() + 2] / o.p_max)
            g[self.n_flow():self.n_flow() + 2] = self.gpatch[2:4] * (1.0 - th * th)
        return terms, g

    def objective(self, patch_fields: np.ndarray, normalized: bool, regularize: bool = True):
        """(total, data, tv, p) of patch-grid fields (4, nh, nw); the gradient with respect
        to them in ``self.gpatch`` and the predicted increment in ``self.buf.pred``."""
        o = self.opts
        lam_tv, lam_p = (o.lambda_tv, o.lambda_p) if regularize else (0.0, 0.0)
        return objective_grad(np.ascontiguousarray(patch_fields),
                              LevelGrid(self.iy, self.fy_d, self.ix, self.fx_d, 1.0 / self.k),
                              LevelImages(self.gimg, self.meas, self.weight, self.s_meas),
                              ObjectiveTerms(lam_tv, lam_p, o.eps_data, o.eps_reg, normalized,
                                             o.use_p),
                              self.buf, self.gpatch)

    def n_params(self) -> int:
        """Parameters per patch (flow, then p when estimated)."""
        return self.n_flow() + (2 if self.opts.use_p else 0)


def _resample_params(theta: np.ndarray, src: BosLevel, dst: BosLevel) -> np.ndarray:
    """Parameters of ``src``'s patch grid interpolated to ``dst``'s; q scaled by the ratio of
    patch sizes so that the flow (a Sobel over patches) keeps its magnitude."""
    iy, fy = interp_index(dst.nh, dst.patch, src.nh, src.patch)
    ix, fx = interp_index(dst.nw, dst.patch, src.nw, src.patch)
    out = np.zeros((theta.shape[0], dst.nh, dst.nw))
    upsample(np.ascontiguousarray(theta), iy, fy, ix, fx, out)
    if src.opts.param == "poisson":
        out[0] *= src.patch / dst.patch
    return out


def _adam(level: BosLevel, theta: np.ndarray, iters: int, normalized: bool):
    o = level.opts
    m = np.zeros_like(theta)
    v = np.zeros_like(theta)
    losses = np.empty(iters)
    n = 0
    for t in range(1, iters + 1):
        (total, *_), g = level.value_grad(theta, normalized)
        losses[t - 1] = total
        n = t
        if o.tol > 0 and t > o.patience:
            prev = losses[t - 1 - o.patience]
            if prev - total < o.tol * abs(prev):
                break
        lr = o.lr * o.lr_decay ** ((t - 1) / iters)
        m = _ADAM_B1 * m + (1 - _ADAM_B1) * g
        v = _ADAM_B2 * v + (1 - _ADAM_B2) * g * g
        mh = m / (1 - _ADAM_B1 ** t)
        vh = v / (1 - _ADAM_B2 ** t)
        theta = theta - lr * mh / (np.sqrt(vh) + _ADAM_EPS)
    return theta, losses[:n]


def _prepare(events, frame, t0_us, t1_us, frame_next, roi, o: BosOptions, increment=None):
    """Crop, check and build the measured increment, TV weight and log frame. Returns the
    ROI, smoothed log frame, measured increment, TV weight, C (or None) and whether the
    increment is in log units."""
    sensor = events.sensor_size
    if increment is not None and np.shape(increment) != tuple(sensor):
        raise EventDataError(f"increment has shape {np.shape(increment)} but the events' "
                             f"sensor is {tuple(sensor)} (H, W)")
    for name, img in (("frame", frame), ("frame_next", frame_next)):
        if img is not None and np.asarray(img).dtype.kind not in "uif":
            raise ParameterError(f"{name} has dtype {np.asarray(img).dtype}: give grey levels "
                                 "(uint8 / uint16) or a float relative intensity")
    if frame_next is not None and np.asarray(frame).dtype != np.asarray(frame_next).dtype:
        # grey levels are scaled by their dtype (frame_to_float): an int64 frame beside a
        # uint8 one differed 256x in log intensity, the flow 7x too large, unsaid (probe)
        raise ParameterError(f"frame is {np.asarray(frame).dtype} but frame_next "
                             f"{np.asarray(frame_next).dtype}: their grey levels are read on "
                             "the scale of their dtype, so the two must share one")
    if np.shape(frame) != tuple(sensor):
        raise EventDataError(f"frame has shape {np.shape(frame)} but the events' sensor is "
                             f"{tuple(sensor)} (H, W): frames and events do not overlap in size")
    if frame_next is not None and np.shape(frame_next) != tuple(sensor):
        raise EventDataError(f"frame_next has shape {np.shape(frame_next)} but the events' "
                             f"sensor is {tuple(sensor)} (H, W)")
    r = _check_roi(roi, sensor)
    ev = _window_events(events, int(t0_us), int(t1_us), r)
    x, y, rw, rh = r
    logf = log_frame(frame, o.log_eps)[y:y + rh, x:x + rw]
    texture = _texture(logf)
    if texture < o.min_texture:
        raise TexturelessFrameError(
            f"the frame at {int(t0_us)} us (interval [{int(t0_us)}, {int(t1_us)}) us) is "
            f"textureless in the ROI (90th percentile of |grad log I| = {texture:.3g} < "
            f"{o.min_texture}): BOS needs a textured background")
    sums, counts = event_sums(ev, r)
    c = o.contrast_threshold
    if increment is not None:
        inc = np.asarray(increment, dtype=np.float64)[y:y + rh, x:x + rw]
        if not np.isfinite(inc).all():
            raise ParameterError("increment has NaN or inf values in the ROI")
        meas = gaussian_filter(inc, o.sigma_meas, mode="nearest")
    elif c is None and frame_next is not None:
        try:
            c = estimate_contrast_threshold(ev, frame, frame_next, t0_us=int(t0_us),
                                            t1_us=int(t1_us), roi=r, sigma=o.sigma_meas,
                                            log_eps=o.log_eps)
        except InvertedPolarityError:
            raise  # the flow would come out reversed under either data term (probe AT)
        except EventDataError as exc:
            # the normalized term needs no C: its result is then flagged uncalibrated
            if o.data_term == "scale":
                raise
            warnings.warn(EvmotionWarning(
                f"{exc}; the flow's magnitude is not calibrated (calibrated False): its "
                "direction is the normalized term's, its size is not px/s"), stacklevel=3)
    if increment is None and o.data_term == "scale" and c is None:
        raise ParameterError("data_term='scale' needs contrast_threshold or frame_next "
                             "(to estimate it)")
    if increment is None:
        meas = gaussian_filter(sums * (1.0 if c is None else c), o.sigma_meas, mode="nearest")
    # the prediction must see the measurement's blur: G * (grad L . v) = (G * grad L) . v
    # for a flow smooth over the kernel, so the model frame is smoothed alike
    logf = gaussian_filter(logf, o.sigma_meas, mode="nearest")
    b = gaussian_filter(counts, o.sigma_weight, mode="nearest")
    b /= max(b.max(), 1e-12)
    weight = 1.0 - o.alpha * b
    return r, logf, meas, weight, c, increment is not None or c is not None


def _coarse_to_fine(logf, meas, weight, o: BosOptions, dtype, warm, normalized: bool,
                    gradient=None):
    """Solve (6.10) scale by scale. Returns the finest parameters and level, and per scale
    the losses, iterations, parameters and seconds."""
    rng = np.random.default_rng(o.seed)
    losses, timings, iters, params = [], [], [], []
    prev_level = theta = level = None
    for s, (patch, k, n_it) in enumerate(zip(o.scales, o.pool_per_scale(),
                                             o.iterations_per_scale(), strict=True)):
        start = time.perf_counter()
        level = BosLevel(patch, k, logf, meas, weight, o, dtype, gradient)
        if prev_level is None:
            theta = np.zeros((level.n_params(), level.nh, level.nw))
            if o.param == "poisson":
                theta[0] = rng.uniform(-1.0, 1.0, (level.nh, level.nw))
            if warm is not None:
                theta = _same_shape(warm[s], theta)
        else:
            theta = _resample_params(theta, prev_level, level)
            if warm is not None:
                theta = 0.5 * (theta + _same_shape(warm[s], theta))
        theta, lh = _adam(level, theta, n_it, normalized)
        losses.append(lh)
        iters.append(len(lh))
        params.append(theta.copy())
        timings.append(time.perf_counter() - start)
        prev_level = level
    return theta, level, losses, iters, params, timings


def _pixel_fields(level: BosLevel, theta: np.ndarray, shape) -> tuple[np.ndarray, np.ndarray]:
    """``(patch fields, dense fields)`` of a full-resolution level's parameters: du, dv,
    pu, pv on its patch grid (4, nh, nw) and interpolated to its ``shape`` (H, W) pixels."""
    pf = level.patch_fields(theta)
    dense = np.zeros((4, *shape))
    upsample(pf, level.iy, level.fy, level.ix, level.fx, dense)
    return pf, dense


def _relinearized(logf: np.ndarray, meas: np.ndarray, du: np.ndarray, dv: np.ndarray):
    """``(Lw, (gx, gy), meas - (Lw - L + g . d))``: the log frame ``L`` warped by the
    displacement ``d = (du, dv)`` (px over the interval; ``Lw(x) = L(x - d)``), its
    gradient warped alike (``g(x) = grad L(x - d)``, the derivative of ``L(x - d')`` in
    ``d'`` at ``d``: not ``grad Lw``, which the warp's own gradient distorts where the air
    varies within a few px), and the measured increment less the part of the prediction
    the linearization at ``d`` makes known, so that ``-g . d'`` predicts the rest."""
    h, w = logf.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    at = [yy - dv, xx - du]
    gy, gx = np.gradient(logf)
    lw = map_coordinates(logf, at, order=3, mode="nearest")
    gxw = map_coordinates(gx, at, order=3, mode="nearest")
    gyw = map_coordinates(gy, at, order=3, mode="nearest")
    return lw, (gxw, gyw), meas - (lw - logf + gxw * du + gyw * dv)


def estimate_bos(
    events: EventArray,
    frame: np.ndarray,
    *,
    t0_us: int,
    t1_us: int,
    frame_next: np.ndarray | None = None,
    roi: Sequence[int] | None = None,
    options: BosOptions | None = None,
    init: BosResult | Sequence[np.ndarray] | None = None,
    dtype=np.float32,
    increment: np.ndarray | None = None,
    on_empty: str = "raise",
    **kwargs,
) -> BosResult:
    """Flow of a schlieren scene from the events of one frame interval and its first frame.

    Parameters
    ----------
    events : EventArray
        Events on the frame's pixel grid (at least those of ``[t0_us, t1_us)``).
    frame : ndarray (H, W)
        Grayscale frame at ``t0_us`` (uint8/uint16 or float relative intensity; one whose
        values lie on grey levels, e.g. 8-bit data as float / 255, is taken as those
        levels: :func:`quantized_frame`).
    t0_us, t1_us : int
        The window (the frame interval) in µs.
    frame_next : ndarray (H, W), optional
        The frame at ``t1_us``: used to estimate the contrast threshold when none is given.
    roi : (x, y, w, h), optional
        Region solved (default: the whole sensor).
    options : BosOptions, optional
        Settings; keyword arguments (e.g. ``param="flow"``, ``iterations=300``) override
        its fields.
    init : BosResult or sequence of ndarray, optional
        Warm start: a previous interval's result with the same scales, or its
        :attr:`BosResult.params` (its parameters start each scale, averaged with the
        coarser scale's solution as in the authors' code).
    dtype : numpy dtype
        Precision of the dense images (float32: half the memory traffic of float64, which
        bounds the kernels' speed).
    increment : ndarray (H, W), optional
        A measured log-brightness increment over the window (log units) used instead of
        the events' polarity sums times C, e.g. the frames' log difference: a diagnostic
        of how much the events' quantized measurement costs against the same solver fed
        a finer one (``benchmarks/bench_bos_accuracy.py``, part ``diagnosis``). The events
        still give the TV weight; C is then neither needed nor estimated.
    on_empty : {"raise", "skip"}
        A window without events in the ROI (still air, or a sensor that saw nothing) or
        whose frame is textureless there (a dropped, black or uniform frame): raise
        EmptyWindowError / TexturelessFrameError (EventDataError when no event of
        ``events`` lies in the window), or ``"skip"``: return a result that
        estimates nothing
        (``valid`` all False, zero flow, ``objective`` NaN) and carries ``init``'s
        parameters on as the next interval's warm start, with an EvmotionWarning (the
        sequence functions skip).

    Returns
    -------
    BosResult

    Raises
    ------
    EventDataError
        Frames and events differ in size, or do not overlap in time
        (``on_empty="raise"``).
    EmptyWindowError
        No event in the window inside the ROI (``on_empty="raise"``).
    ParameterError
        Bad option, ROI outside the sensor, scale term without C; TexturelessFrameError
        (a ParameterError) for a textureless frame (``on_empty="raise"``).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> frame = (rng.random((32, 32)) * 200 + 20).astype(np.uint8)
    >>> ev = EventArray(x=rng.integers(0, 32, 500), y=rng.integers(0, 32, 500),
    ...                 t=np.arange(500) * 10, p=rng.integers(0, 2, 500), sensor_size=(32, 32))
    >>> res = estimate_bos(ev, frame, t0_us=0, t1_us=5000, scales=(16, 8), iterations=20)
    >>> res.flow.shape, res.flow.dtype, res.calibrated
    ((32, 32, 2), dtype('float32'), False)
    """
    require_events(events, "estimate_bos")
    o = _options(options, kwargs)
    if np.dtype(dtype) not in (np.float32, np.float64):
        raise ParameterError(f"dtype must be float32 or float64, got {np.dtype(dtype)}")
    for name, t in (("t0_us", t0_us), ("t1_us", t1_us)):
        if not is_whole_number(t):
            raise ParameterError(f"{name} must be a whole number of us, got {t!r}")
    if on_empty not in ("raise", "skip"):
        raise ParameterError(f"on_empty must be 'raise' or 'skip', got {on_empty!r}")
    try:
        r, logf, meas, weight, c, log_units = _prepare(events, frame, t0_us, t1_us,
                                                       frame_next, roi, o, increment)
    except (EmptyWindowError, NoEventsInWindowError, TexturelessFrameError) as exc:
        if on_empty == "raise":
            raise
        warnings.warn(EvmotionWarning(f"{exc}: the interval is written with no valid pixel"),
                      stacklevel=2)
        return _nothing_measured(events.sensor_size, _check_roi(roi, events.sensor_size),
                                 int(t0_us), int(t1_us), o, init)
    if o.param == "poisson" and min(-(-r[3] // o.scales[-1]), -(-r[2] // o.scales[-1])) < 2:
        raise ParameterError(f"the finest patches ({o.scales[-1]} px) cover the {r[2]}x{r[3]} "
                             "px ROI in one row or column: q on it has no gradient (flow 0); "
                             "use smaller scales or a larger ROI")
    normalized = o.data_term == "normalized"
    warm = None if init is None else list(init.params if isinstance(init, BosResult) else init)
    if warm is not None:
        nan = [np.isnan(np.asarray(a, dtype=np.float64)) for a in warm]
        if all(m.all() for m in nan):
            warm = None  # an interval before without events and no warm start
        elif any(m.any() for m in nan):
            raise ParameterError("init has NaN parameters (a diverged or corrupt warm start): "
                                 "every value NaN means none, or none at all")
    if warm is not None and len(warm) != len(o.scales):
        raise ParameterError(f"init has {len(warm)} scales, expected {len(o.scales)}")
    x, y, rw, rh = r
    # the pixels whose flow events support (valid): where the displacement is measured
    support = _supported(events, int(t0_us), int(t1_us), frame, frame_next,
                         o.log_eps)[y:y + rh, x:x + rw]

    def q95(d) -> float:
        # still air elsewhere in the ROI would dilute it: over the supported pixels
        mag = np.hypot(d[0], d[1])
        return float(np.quantile(mag[support] if support.any() else mag, 0.95))

    theta, level, losses, iters, params, timings = _coarse_to_fine(
        logf, meas, weight, o, dtype, warm, normalized)
    final = level if level.k == 1 else BosLevel(level.patch, 1, logf, meas, weight, o, dtype)
    pf, dense = _pixel_fields(final, theta, logf.shape)
    passes = 0
    while (log_units and not normalized and passes < o.relinearize
           and q95(dense) >= RELINEARIZE_PX):
        # the prediction linearized at the flow found v0: L(x - v dt) ~ Lw - g . (v - v0) dt
        # with Lw and g the frame and its gradient warped by v0 (_relinearized): the same
        # model on them, with the known part moved to the measurement
        logf_w, grad_w, meas_w = _relinearized(logf, meas, dense[0], dense[1])
        theta, level, more_losses, more_iters, params, more_t = _coarse_to_fine(
            logf_w, meas_w, weight, o, dtype, params, normalized, grad_w)
        # per scale, over the passes
        losses = [np.concatenate([a, b]) for a, b in zip(losses, more_losses, strict=True)]
        iters = [a + b for a, b in zip(iters, more_iters, strict=True)]
        timings = [a + b for a, b in zip(timings, more_t, strict=True)]
        final = level
        pf, dense = _pixel_fields(final, theta, logf.shape)
        passes += 1
    (objective, *_), _ = final.value_grad(theta, normalized)
    scale = 1.0
    if normalized and o.rescale and log_units:
        final.objective(pf, True, regularize=False)
        pr = final.buf.pred.astype(np.float64)
        den = float(np.sum(pr * pr))
        if den > 0:
            scale = float(np.sum(pr * final.meas) / den)
    dt = (int(t1_us) - int(t0_us)) * 1e-6
    H, W = events.sensor_size
    flow = np.zeros((H, W, 2), np.float32)
    flow[y:y + rh, x:x + rw, 0] = dense[0] * scale / dt
    flow[y:y + rh, x:x + rw, 1] = dense[1] * scale / dt
    p = np.zeros((H, W, 2), np.float32)
    p[y:y + rh, x:x + rw, 0] = dense[2]
    p[y:y + rh, x:x + rw, 1] = dense[3]
    q = np.zeros((H, W), np.float32)
    q[y:y + rh, x:x + rw] = potential_from_flow(flow[y:y + rh, x:x + rw])
    valid = np.zeros((H, W), bool)
    valid[y:y + rh, x:x + rw] = support
    calibrated = log_units and (not normalized or o.rescale)
    fit_gain = float("nan")
    if calibrated and increment is None:
        # the flow's predicted increment against the measured one where events support it:
        # ~1 when the flow explains the events; well above where the flow fields cannot
        # follow the air (structures finer than the finest patches: the magnitude shrinks)
        final.objective(pf, normalized, regularize=False)
        pr = final.buf.pred.astype(np.float64) * scale
        sup = valid[y:y + rh, x:x + rw]
        den = float(np.sum(pr[sup] ** 2))
        if den > 0:
            fit_gain = float(np.sum(pr[sup] * final.meas[sup]) / den)
        elif sup.any():
            # (probe API: lr=1e-30 left the flow at zero, fit_gain NaN, unsaid)
            warnings.warn(UnderfitWarning(
                f"interval [{int(t0_us)}, {int(t1_us)}) us: the flow predicts no increment "
                "where the events fired: it explains none of them (the solver did not move "
                "from its start: lr too small, or too few iterations?); no measurement"),
                stacklevel=2)
    moved = q95(dense) * scale if calibrated else float("nan")
    if o.relinearize == 0 and moved >= RELINEARIZE_PX:
        warnings.warn(UnderfitWarning(
            f"interval [{int(t0_us)}, {int(t1_us)}) us: the flow moves the background "
            f"{moved:.2g} px over the interval (95th percentile where events support it): "
            f"{LARGE_DISPLACEMENT_NOTE}"), stacklevel=2)
    if fit_gain > FIT_GAIN_WARN:
        warnings.warn(UnderfitWarning(
            f"interval [{int(t0_us)}, {int(t1_us)}) us: the flow explains the events' "
            f"increment at 1/{fit_gain:.2f} of its size where they fired (fit_gain > "
            f"{FIT_GAIN_WARN}): air structures finer than the finest patches "
            f"({min(o.scales)} px), or events that are noise, not schlieren? Its magnitude "
            "is then too small, or no measurement"), stacklevel=2)
    share = valid.sum() / max(rw * rh, 1)
    if share < MIN_SUPPORTED_SHARE:
        warnings.warn(EvmotionWarning(
            f"interval [{int(t0_us)}, {int(t1_us)}) us: events support the flow on "
            f"{100 * share:.2g} % of the ROI only (valid); elsewhere it is the regularizer's "
            "interpolation, not a measurement"), stacklevel=2)
    return BosResult(flow=flow, q=q, p=p, valid=valid, roi=r, t0_us=int(t0_us),
                     t1_us=int(t1_us), contrast_threshold=None if c is None else float(c),
                     calibrated=bool(calibrated), scale=scale, objective=float(objective),
                     losses=losses, timings_s=timings, iterations=iters, params=params,
                     options=o, fit_gain=fit_gain, relinearized=passes,
                     displacement_q95=moved)


# below this share of the ROI with event support, the interval is warned about: the flow
# elsewhere is the regularizer's interpolation of a handful of measurements
MIN_SUPPORTED_SHARE = 0.01


def _supported(events: EventArray, t0_us: int, t1_us: int, frame: np.ndarray,
               frame_next: np.ndarray | None, log_eps: float | None) -> np.ndarray:
    """Pixels with event support in ``[t0_us, t1_us)``: as every flow method marks them
    (:func:`~evmotion.methods.flowresult.event_support`), with the count needed raised
    above what background noise events give where the two frames show still air
    (:func:`noise_floor_count`): at 20 noise events per pixel and second two-thirds of a
    still background passed the plain rule. Without ``frame_next``, the plain rule."""
    win = events.slice_time(t0_us, t1_us)
    box = event_box_counts(win.x, win.y, events.sensor_size, SUPPORT_RADIUS)
    if frame_next is None:
        return box >= SUPPORT_MIN_EVENTS
    # still air: no pixel of the square changed between the frames at all; in noisy
    # frames, which have none, the squares that changed least
    d = log_frame(frame_next, log_eps, "frame_next") - log_frame(frame, log_eps)
    still = ~maximum_filter(d != 0, size=2 * SUPPORT_RADIUS + 1, mode="nearest")
    if np.count_nonzero(still) < MIN_STILL_PIXELS:
        still = least_changed(d)
    return box >= noise_floor_count(box[still])


# the chance a square of background noise alone passes the support rule
NOISE_TAIL = 1e-3
# still-air pixels needed to measure the background noise's events
MIN_STILL_PIXELS = 100


# least_changed: the share of the view taken as the level of still air in noisy frames
# (the air may cover the rest), and the margin over that level of a still square
STILL_QUANTILE = 0.1
STILL_MARGIN = 1.5


def least_changed(d: np.ndarray) -> np.ndarray:
    """Still air in noisy frames: the support squares whose mean square log change ``d``
    (H, W) is at most ``STILL_MARGIN`` times its ``STILL_QUANTILE`` quantile over the
    view. Frame noise alone gives every still square about the same mean square (within
    ~30 % over 25 pixels), air more; with background noise events at 5 Hz per pixel and
    frames of read noise 1 DN 28 % of the still background had passed the plain rule, and
    at 20 Hz 92 % (probe BC's renderer).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> d = rng.normal(0, 0.01, (40, 40)); d[:, 20:] += rng.normal(0, 0.2, (40, 20))
    >>> s = least_changed(d)
    >>> bool(s[:, :16].mean() > 0.4), bool(s[:, 24:].any())
    (True, False)
    """
    m = uniform_filter(d * d, size=2 * SUPPORT_RADIUS + 1, mode="nearest")
    return m <= STILL_MARGIN * np.quantile(m, STILL_QUANTILE)


def noise_floor_count(still_box: np.ndarray, tail: float = NOISE_TAIL) -> int:
    """Events a support square must hold to stand out of uniform background noise: the
    smallest ``k >= SUPPORT_MIN_EVENTS`` that a Poisson count, of mean the squares' mean
    count in still air (``still_box``), reaches with probability at most ``tail``;
    ``SUPPORT_MIN_EVENTS`` with no noise or fewer than ``MIN_STILL_PIXELS`` still pixels.

    Examples
    --------
    >>> noise_floor_count(np.zeros(400))
    2
    >>> noise_floor_count(np.full(400, 4.0))  # 4 noise events per square
    12
    """
    vals = np.asarray(still_box, dtype=np.float64).ravel()
    lam = float(vals.mean()) if vals.size >= MIN_STILL_PIXELS else 0.0
    if lam <= 0:
        return int(SUPPORT_MIN_EVENTS)
    from scipy.special import pdtrc  # P(X > k) for X ~ Poisson(lam)

    ks = np.arange(int(lam + 10 * np.sqrt(lam) + 10))
    k = int(ks[np.argmax(pdtrc(ks, lam) <= tail)]) + 1  # P(X >= k) <= tail
    return max(k, int(SUPPORT_MIN_EVENTS))


def potential_from_flow(flow: np.ndarray) -> np.ndarray:
    """The potential ``q`` (zero mean) whose gradient best fits ``flow``: ``flow`` (H, W, 2)
    in px/s gives ``q`` (H, W) float32 in px^2/s, the least-squares solution of
    ``q(x + 1) - q(x) = (v(x) + v(x + 1)) / 2`` along both axes (the Neumann Poisson
    equation, solved exactly by a cosine transform).

    The solver's own q lives on its patch grid, where the Sobel stencil is blind to odd-even
    patterns that the random start puts in and no iteration removes; upsampled, its
    gradient correlated 0.45 and 0.37 (u, v) with the flow on an interval of a rendered
    plume. The potential of the flow is the q that the flow measures: over six intervals
    of that plume it correlates 0.96-0.99 with the true q, the patch-grid q 0.78-0.88.

    Examples
    --------
    >>> yy, xx = np.mgrid[0:32, 0:48].astype(float)
    >>> q = 0.5 * xx ** 2 - 3.0 * yy                     # px^2/s
    >>> flow = np.stack([xx, np.full_like(xx, -3.0)], -1)  # its gradient, px/s
    >>> bool(np.allclose(potential_from_flow(flow), q - q.mean(), atol=1e-3))
    True
    """
    from scipy.fft import dctn, idctn

    try:
        v = np.asarray(flow, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"flow must be an (H, W, 2) array in px/s, got "
                             f"{type(flow).__name__}") from None
    if v.ndim != 3 or v.shape[2] != 2 or min(v.shape[:2]) < 1:
        raise ParameterError(f"flow must be (H, W, 2) px/s, got shape {v.shape}")
    bad = int(np.count_nonzero(~np.isfinite(v).all(axis=2)))
    if bad:
        raise ParameterError(f"flow has {bad} pixels with NaN or inf, which a cosine "
                             "transform spreads everywhere: crop it to where it is finite "
                             "(a BOS output is NaN outside its ROI)")
    h, w = v.shape[:2]
    # the divergence of the mid-point flow, as the adjoint of the forward difference
    div = np.zeros((h, w))
    gx = 0.5 * (v[:, :-1, 0] + v[:, 1:, 0])
    gy = 0.5 * (v[:-1, :, 1] + v[1:, :, 1])
    div[:, :-1] += gx
    div[:, 1:] -= gx
    div[:-1, :] += gy
    div[1:, :] -= gy
    lam = ((2.0 * np.cos(np.pi * np.arange(h) / h) - 2.0)[:, None]
           + (2.0 * np.cos(np.pi * np.arange(w) / w) - 2.0)[None, :])
    lam[0, 0] = 1.0
    coef = dctn(div, type=2, norm="ortho") / lam
    coef[0, 0] = 0.0
    return idctn(coef, type=2, norm="ortho").astype(np.float32)


def _nothing_measured(sensor, r, t0_us: int, t1_us: int, o: BosOptions, init) -> BosResult:
    """The result of a window without events: nothing valid, and the warm start it was
    given passed on (NaN parameters where there was none: the next starts cold)."""
    h, w = sensor
    if init is None:
        params = [np.full(shape, np.nan) for shape in o.param_shapes(r[3], r[2])]
    else:
        params = [np.array(a, dtype=np.float64)
                  for a in (init.params if isinstance(init, BosResult) else init)]
    n = len(o.scales)
    return BosResult(flow=np.zeros((h, w, 2), np.float32), q=np.zeros((h, w), np.float32),
                     p=np.zeros((h, w, 2), np.float32), valid=np.zeros((h, w), bool), roi=r,
                     t0_us=t0_us, t1_us=t1_us, contrast_threshold=o.contrast_threshold,
                     calibrated=False, scale=1.0, objective=float("nan"),
                     losses=[np.zeros(0)] * n, timings_s=[0.0] * n, iterations=[0] * n,
                     params=params, options=o)


def _options(options, kwargs: dict) -> BosOptions:
    """``options`` (default :class:`BosOptions`) with the fields in ``kwargs`` replaced."""
    if options is not None and not isinstance(options, BosOptions):
        raise ParameterError(f"options must be a BosOptions, got {type(options).__name__}")
    o = options or BosOptions()
    unknown = set(kwargs) - set(BosOptions.__dataclass_fields__)
    if unknown:
        raise ParameterError(f"unknown option(s) {sorted(unknown)}")
    return replace(o, **kwargs) if kwargs else o


def _same_shape(prev: np.ndarray, like: np.ndarray) -> np.ndarray:
    prev = np.asarray(prev, dtype=np.float64)
    if prev.shape != like.shape:
        raise ParameterError(f"init parameters have shape {prev.shape}, expected {like.shape} "
                             "(same ROI, scales and options)")
    return prev.copy()


# --------------------------------------------------------------------------- sequences

def _solve_chunk(events: EventArray, t0_us: int, t1_us: int, *, frames, times, roi, options,
                 warm_start, init=None) -> list[BosResult]:
    """Solve the frame intervals inside ``[t0_us, t1_us]`` in order (a worker's chunk);
    ``init`` warm-starts the sequence's first interval."""
    from evmotion.parallel import report_progress

    out = []
    idx = [i for i in range(len(times) - 1) if t0_us <= times[i] and times[i + 1] <= t1_us]
    prev = init if idx and idx[0] == 0 else None
    for i in idx:
        with warnings.catch_warnings():  # said once for the sequence, by its median
            warnings.simplefilter("ignore", UnderfitWarning)
            res = estimate_bos(events, frames[i], t0_us=int(times[i]),
                               t1_us=int(times[i + 1]), frame_next=frames[i + 1], roi=roi,
                               options=options, init=prev if warm_start else None,
                               on_empty="skip")
        out.append(res)
        report_progress()
        prev = res
    return out


def estimate_bos_sequence(events: EventArray, frames, times_us: Sequence[int],
                          **kwargs) -> list[BosResult]:
    """:func:`iter_bos_sequence`'s results as a list, once every interval is solved (the
    same arguments).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> frames = (rng.random((3, 32, 32)) * 200 + 20).astype(np.uint8)
    >>> ev = EventArray(x=rng.integers(0, 32, 900), y=rng.integers(0, 32, 900),
    ...                 t=np.arange(900) * 10, p=rng.integers(0, 2, 900), sensor_size=(32, 32))
    >>> res = estimate_bos_sequence(ev, frames, [0, 4500, 9000], scales=(16, 8), iterations=10)
    >>> [(r.t0_us, r.t1_us) for r in res]
    [(0, 4500), (4500, 9000)]
    """
    results = list(iter_bos_sequence(events, frames, times_us, **kwargs))
    warn_underfit((r.fit_gain for r in results), single_solve_displacements(results),
                  finest_px=min(results[0].options.scales) if results else None)
    return results


def warn_underfit(gains, displacements=(), finest_px: int | None = None) -> None:
    """Say when the median :attr:`BosResult.fit_gain` of a sequence's intervals exceeds
    :data:`FIT_GAIN_WARN`, or the median of their :attr:`BosResult.displacement_q95`
    (solved once: NaN for the others) reaches :data:`RELINEARIZE_PX`: the flow is too
    small (the intervals' own warnings are left out in a sequence: one per run).
    ``finest_px``, the finest patch size of the solves, is named when given."""
    d = np.asarray([v for v in displacements if v is not None and np.isfinite(v)],
                   np.float64)
    if d.size and np.median(d) >= RELINEARIZE_PX:
        warnings.warn(UnderfitWarning(
            f"the flow moves the background {np.median(d):.2g} px over an interval (95th "
            f"percentile, median over {d.size} intervals): {LARGE_DISPLACEMENT_NOTE}"),
            stacklevel=2)
    g = np.asarray([v for v in gains if v is not None and np.isfinite(v)], np.float64)
    if g.size and np.median(g) > FIT_GAIN_WARN:
        size = f" ({finest_px} px)" if finest_px else ""
        warnings.warn(UnderfitWarning(
            f"the flow explains the events' increment at 1/{np.median(g):.2f} of its size "
            f"where they fired (median over {g.size} intervals): air structures finer than "
            f"the solver's finest patches{size}, or events that are noise, not schlieren "
            "(still air)? Its magnitude is then too small (0.4-0.7x on scenes of fine "
            "structures), or no measurement"), stacklevel=2)


def single_solve_displacements(results) -> list[float]:
    """:attr:`BosResult.displacement_q95` of the results solved once (no
    :attr:`~BosResult.relinearized` pass), NaN for the others: the second argument of
    :func:`warn_underfit`."""
    return [r.displacement_q95 if r.relinearized == 0 else float("nan") for r in results]


def iter_bos_sequence(
    events: EventArray,
    frames: Sequence[np.ndarray] | np.ndarray,
    times_us: Sequence[int],
    *,
    roi: Sequence[int] | None = None,
    options: BosOptions | None = None,
    warm_start: bool = True,
    workers: int = 1,
    chunks: int | None = None,
    progress: bool = False,
    scheduler=None,
    init: BosResult | Sequence[np.ndarray] | None = None,
    **kwargs,
) -> Iterator[BosResult]:
    """:func:`estimate_bos` over every frame interval ``[times[i], times[i+1])``.

    Each interval uses ``frames[i]`` and ``frames[i+1]`` (the latter for C). With
    ``warm_start`` an interval starts from the previous interval's solution (the first
    from ``init``, if given), so the intervals of one chunk run in order; ``chunks``
    contiguous chunks (default ``workers``) run in parallel with
    :func:`evmotion.parallel.imap_windows` (each later chunk's first interval starts cold).
    With ``scheduler`` (a Dask scheduler address or ``distributed.Client``) the chunks run
    on that cluster instead of local processes. The results come in time order as soon as
    their chunk is done (one interval at a time with one chunk), so that a caller writes
    them while the later ones are computed; the arguments are checked at the call, the
    work starts at the first ``next()``.

    Returns
    -------
    iterator of BosResult
        One per interval, in time order.

    Raises
    ------
    EventDataError
        No event lies between the first and the last frame (an interval without events
        is skipped: ``on_empty="skip"`` of :func:`estimate_bos`).
    EvmotionError
        The first interval's error, re-raised with its window (see :func:`estimate_bos`).

    Examples
    --------
    >>> rng = np.random.default_rng(1)
    >>> ev = EventArray(x=rng.integers(0, 32, 600), y=rng.integers(0, 32, 600),
    ...                 t=np.sort(rng.integers(0, 9000, 600)), p=rng.integers(0, 2, 600),
    ...                 sensor_size=(32, 32))
    >>> images = rng.integers(20, 220, (3, 32, 32)).astype(np.uint8)
    >>> [r.t1_us for r in iter_bos_sequence(ev, images, [0, 4500, 9000], scales=(16, 8))]
    [4500, 9000]
    """
    from evmotion.parallel import imap_windows

    o = _options(options, kwargs)
    for name, v in (("workers", workers), ("chunks", 1 if chunks is None else chunks)):
        if not (is_whole_number(v) and v >= 1):
            raise ParameterError(f"{name} must be an integer >= 1, got {v!r}")
    times = np.asarray(times_us, dtype=np.float64)
    if times.ndim != 1 or not np.isfinite(times).all():
        raise ParameterError(f"times_us must be finite frame times in us, got {times_us!r}")
    if np.any(times != np.round(times)):
        # seconds given for µs: truncated, then "must increase" (probe AU)
        raise ParameterError(f"times_us must be whole microseconds, got {times[:3].tolist()}"
                             f"{'...' if times.size > 3 else ''} (seconds? times_us = "
                             "np.round(t_s * 1e6))")
    times = times.astype(np.int64)
    if len(frames) != len(times):
        raise ParameterError(f"{len(frames)} frames but {len(times)} timestamps")
    if len(times) < 2:
        raise ParameterError("a sequence needs at least two frames")
    if np.any(np.diff(times) <= 0):
        raise ParameterError("frame timestamps must increase")
    # intervals without events are skipped, but not all of them: other clocks, not still air
    _check_overlap(require_events(events, "iter_bos_sequence"), int(times[0]),
                   int(times[-1]), "frames")
    n = len(times) - 1
    n_chunks = max(1, min(n, workers if chunks is None else int(chunks)))
    bounds = np.linspace(0, n, n_chunks + 1).round().astype(int)
    windows = [(int(times[a]), int(times[b])) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    if init is not None and not isinstance(init, BosResult):
        init = [np.asarray(a, dtype=np.float64) for a in init]
    fn = functools.partial(_solve_chunk, frames=frames, times=times, roi=roi, options=o,
                           warm_start=warm_start, init=init if warm_start else None)
    results = imap_windows(fn, events, windows, workers=workers, scheduler=scheduler,
                           progress=progress, desc="bos", with_window=True,
                           units=np.diff(bounds).tolist(), unit="interval")
    return _chunk_results(results)


def _chunk_results(results) -> Iterator[BosResult]:
    try:
        for res in results:
            if not res.ok:
                raise EvmotionError(f"window [{res.t0}, {res.t1}) us failed: "
                                     f"{res.error.splitlines()[0]}")
            yield from res.value
    finally:
        results.close()  # ends the worker pool (or the cluster's feed) when stopped early
