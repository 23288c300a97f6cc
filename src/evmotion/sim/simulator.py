"""The event simulator (ESIM-like): adaptive sampling of log intensity, events at
interpolated threshold crossings, per-pixel threshold mismatch, refractory period,
background-activity noise and hot pixels."""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from evmotion.catalog import MAX_SENSOR_SIDE, MAX_SIM_DURATION_S, MIN_SIM_SIDE
from evmotion.errors import EvmotionWarning, ParameterError
from evmotion.events import EventArray
from evmotion.sim.groundtruth import GroundTruth, Layer
from evmotion.sim.motions import make_motion
from evmotion.sim.options import EventOptions, SimOptions, check_number
from evmotion.sim.render import (
    MAX_SUBSAMPLES,
    EventBuffers,
    PixelState,
    StepLayers,
    emit_crossings,
    full_boxes,
    pad_periodic,
    render_log,
    sim_step,
    sim_step_numpy,
    step_grid,
    textured_cells_sat,
)
from evmotion.sim.scenes import SCENES, default_K, resolve_params
from evmotion.sim.textures import TEXTURES, Texture, make_texture, texture_from_image
from evmotion.utils import progress, resolve_options, whole_number

__all__ = ["EventOptions", "LogSimResult", "SimOptions", "SimResult", "parse_sensor_size",
           "simulate", "simulate_log_function"]

MAX_STEP_US = 5000  # sample at least every 5 ms (the 1 px bound usually binds first)
# a simulated recording of an hour is already days of rendering; beyond, a typo
MAX_DURATION_S = MAX_SIM_DURATION_S
# each ground-truth frame is a dense flow field when written (0.7 MB at 346x260)
MAX_GT_FRAMES = 100_000
STEP_SHIFT_PX = 1.0  # global steps move no texture point by more than ~1 px
STEP_GROW = 0.98  # aim steps at this fraction of the bound (a step beyond it is redone)
PREFETCH_STEPS = 8  # steps of equal length whose matrices are computed together


@dataclass(eq=False)
class SimResult:
    """Output of :func:`simulate`.

    Attributes
    ----------
    events : EventArray
        Sorted events at integer pixels, t in µs from 0.
    gt : GroundTruth
    scene : str
    params : dict
        The resolved scene parameters (defaults updated by the caller's).
    stats : dict
        Step and sub-sample counts, signal/noise event counts, thresholds.
    thresholds : (ndarray, ndarray)
        Per-pixel ON and OFF contrast thresholds (H, W) after mismatch.
    """

    events: EventArray
    gt: GroundTruth
    scene: str
    params: dict
    stats: dict = field(default_factory=dict)
    thresholds: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)


def _margin_shape(sensor_size):
    h, w = sensor_size
    mh, mw = max(16, h // 4), max(16, w // 4)
    return (h + 2 * mh, w + 2 * mw), (-float(mw), -float(mh))


def _texture(texture, image, shape, origin, seed) -> Texture:
    if isinstance(texture, Texture) and image is None:
        return texture
    if image is not None:
        return texture_from_image(image, shape, origin)
    if isinstance(texture, (str, Path)) and str(texture) in TEXTURES:
        return make_texture(str(texture), shape, origin, seed)
    if isinstance(texture, np.ndarray) or Path(str(texture)).suffix:
        return texture_from_image(texture, shape, origin)
    raise ParameterError(f"unknown texture {texture!r}; choose one of {sorted(TEXTURES)} "
                         "or give an image path/array")


def build_layers(scene: str, p: dict, sensor_size, K, texture, image, seed):
    """Layers (bottom first) and their textures for a scene with resolved parameters."""
    shape, origin = _margin_shape(sensor_size)
    ss = np.random.SeedSequence(seed).spawn(2)
    tex_seed = int(ss[0].generate_state(1)[0])
    bg_tex = _texture(texture, image, shape, origin, tex_seed)
    spec = SCENES[scene]
    if scene != "object":
        names = [k for k in spec.defaults]
        theta = [p[k] for k in names]
        center = tuple(p["foe"]) if scene == "zoom" else None
        motion = make_motion(spec.warp, theta, sensor_size, K=K, center=center)
        return [Layer("background", motion)], [bg_tex]
    bg = make_motion("translation", [p["bg_vx"], p["bg_vy"]], sensor_size)
    fg_center = (p["fg_x"], p["fg_y"])
    fg = make_motion("se2", [p["fg_vx"], p["fg_vy"], p["fg_wz"]], sensor_size, center=fg_center)
    fg_name = "noise" if bg_tex.name == "checker" else "checker"
    fg_tex = make_texture(fg_name, shape, origin, int(ss[1].generate_state(1)[0]))
    ys, xs = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    r = np.hypot(xs + origin[0] - fg_center[0], ys + origin[1] - fg_center[1])
    alpha = np.clip(p["radius"] + 0.5 - r, 0.0, 1.0).astype(np.float32)
    fg_tex = Texture(fg_tex.log_i, alpha, origin, fg_tex.name)
    return ([Layer("background", bg), Layer("object", fg, alpha, origin)], [bg_tex, fg_tex])


#: Noise events a simulation adds at most (16 bytes each as x, y, t, p: 8 GB).
MAX_NOISE_EVENTS = 5e8


def _noise_events(rng, sensor_size, duration_us, noise_rate, hot_pixels, hot_rate):
    h, w = sensor_size
    T = duration_us * 1e-6
    expected = noise_rate * h * w * T + hot_pixels * hot_rate * T
    if expected > MAX_NOISE_EVENTS:
        hot = f" and {hot_pixels} hot pixels at {hot_rate:g} events/s" if hot_pixels else ""
        raise ParameterError(f"noise_rate {noise_rate:g}{hot} over {w}x{h} px and {T:g} s "
                             f"would add ~{expected:.3g} noise events, over "
                             f"{MAX_NOISE_EVENTS:.0e}: a rate per pixel (events/s), not per "
                             "sensor?")
    n = rng.poisson(noise_rate * h * w * T) if noise_rate > 0 else 0
    xs = [rng.integers(0, w, n)]
    ys = [rng.integers(0, h, n)]
    ts = [rng.integers(0, duration_us, n)]
    if hot_pixels > 0:
        pix = rng.choice(h * w, size=hot_pixels, replace=False)
        counts = rng.poisson(hot_rate * T, size=hot_pixels)
        idx = np.repeat(pix, counts)
        xs.append(idx % w)
        ys.append(idx // w)
        ts.append(rng.integers(0, duration_us, idx.size))
    x = np.concatenate(xs)
    return (x.astype(np.uint16), np.concatenate(ys).astype(np.uint16),
            np.concatenate(ts).astype(np.int64), rng.integers(0, 2, x.size).astype(np.uint8))


def _step_numpy(layers: StepLayers, state: PixelState, events: EventBuffers, t_a, t_b, refr,
                target):
    """:func:`sim_step_numpy` behind the interface of :func:`sim_step` (``layers`` with
    unpadded rasters)."""
    lbn, x, y, t, p = sim_step_numpy(layers.Mseq, layers.texs, layers.alphas, layers.origins,
                                     state.la, state.ref, state.cp, state.cn, state.last, t_a,
                                     t_b, refr, target)
    state.lb[:] = lbn
    n = x.size
    if n <= events.x.size:
        events.x[:n], events.y[:n], events.t[:n], events.p[:n] = x, y, t, p
    return n, 0


def _check_motion(scene, p, layers, duration_s):
    """Refuse motions that degenerate within the recording (clear error, not NaN events)."""
    if scene == "zoom" and p["hz"] * duration_s >= 0.9:
        raise ParameterError(f"zoom: hz={p['hz']} 1/s over {duration_s:.6g} s reaches the scene "
                             f"(time to contact 1/hz = {1 / p['hz']:.3g} s); use "
                             "hz * duration < 0.9")
    ts = np.linspace(0.0, duration_s, 65)
    for layer in layers:
        det = np.linalg.det(layer.motion.matrices(ts))
        if not np.all(np.isfinite(det)) or np.any(det * det[0] <= 0) or \
                np.abs(np.log(np.abs(det))).max() > np.log(100.0):
            raise ParameterError(f"{scene}: the motion {layer.motion.theta.tolist()} "
                                 f"({layer.motion.warp.name}) degenerates within {duration_s:.6g} s "
                                 "(area scale beyond 100x); use smaller rates or a shorter "
                                 "duration")


def parse_sensor_size(sensor_size, min_side: int = 1) -> tuple[int, int]:
    """``(height, width)`` of ``sensor_size`` as ints, each a whole number between
    ``min_side`` and :data:`~evmotion.catalog.MAX_SENSOR_SIDE` (what the readers and the
    events accept).

    Raises
    ------
    ParameterError
        One line naming the value when it is not two whole numbers in that range.

    Examples
    --------
    >>> parse_sensor_size((260.0, 346))
    (260, 346)
    """
    try:
        h, w = sensor_size
    except (TypeError, ValueError):
        raise ParameterError(f"sensor_size must be (height, width), got {sensor_size!r}") from None
    # (a fractional side had been floored: 30.5 made 30, probe AU)
    return (whole_number("sensor_size height", h, lo=min_side, hi=MAX_SENSOR_SIDE),
            whole_number("sensor_size width", w, lo=min_side, hi=MAX_SENSOR_SIDE))


def _thresholds(rng, C, mismatch, shape):
    """Per-pixel ON and OFF thresholds: ``C`` with relative mismatch, at least 0.25 C
    (mismatch never makes a pixel absurdly sensitive)."""
    cmin = 0.25 * C
    cp = np.maximum(C * (1 + mismatch * rng.standard_normal(shape)), cmin)
    cn = np.maximum(C * (1 + mismatch * rng.standard_normal(shape)), cmin)
    return cp, cn


def _sorted_chunk(ex, ey, et, ep, n, w, h, packed):
    """The first ``n`` events of a step in time, then pixel index, then polarity order:
    an order that does not depend on the traversal. Packed into one sorted int64 key when
    ``packed`` (unpacked by :func:`_join_chunks`), else the four sorted arrays."""
    key = et[:n] * (h * w) + ey[:n].astype(np.int64) * w + ex[:n]
    if packed:
        key = key * 2 + ep[:n]
        key.sort()
        return key
    order = np.argsort(key, kind="stable")
    return ex[order], ey[order], et[order], ep[order]


def _join_chunks(chunks, w, h, packed):
    """``(x, y, t, p)`` of the chunks of :func:`_sorted_chunk`, concatenated."""
    if chunks and packed:
        key = np.concatenate(chunks)
        pp = (key & 1).astype(np.uint8)
        key >>= 1
        tt, pix = np.divmod(key, h * w)
        yy, xx = np.divmod(pix, w)
        return xx.astype(np.uint16), yy.astype(np.uint16), tt, pp
    if chunks:
        x, y, tt, pp = (np.concatenate(c) for c in zip(*chunks, strict=True))
        return x, y, tt, pp
    return (np.zeros(0, np.uint16), np.zeros(0, np.uint16), np.zeros(0, np.int64),
            np.zeros(0, np.uint8))


def _add_noise(x, y, tt, pp, rng, sensor_size, duration_us, noise_rate, hot_pixels,
               hot_rate):
    """Signal events merged with background-activity and hot-pixel noise, sorted by time
    (stable: signal first at equal times); also returns the number of noise events."""
    if noise_rate <= 0 and hot_pixels <= 0:
        return x, y, tt, pp, 0
    nx, ny, nt, npol = _noise_events(rng, sensor_size, duration_us, noise_rate, hot_pixels,
                                     hot_rate)
    x, y = np.concatenate([x, nx]), np.concatenate([y, ny])
    tt, pp = np.concatenate([tt, nt]), np.concatenate([pp, npol])
    order = np.argsort(tt, kind="stable")
    return x[order], y[order], tt[order], pp[order], nx.size


@dataclass(frozen=True)
class _Run:
    """The checked arguments of one :func:`simulate` call."""

    scene: str
    duration_us: int
    sensor_size: tuple[int, int]
    options: SimOptions
    K: np.ndarray
    show_progress: bool


def _checked_run(scene, duration_s, sensor_size, options: SimOptions, show_progress) -> _Run:
    if scene not in SCENES:
        raise ParameterError(f"unknown scene '{scene}'; choose one of {sorted(SCENES)}")
    duration_us = int(round(check_number("duration_s", duration_s, hi=MAX_DURATION_S,
                                         lo_open=True, units="s") * 1e6))
    if duration_us < 1:
        raise ParameterError(f"duration_s must be at least 1 µs, got {duration_s!r}")
    n_frames = duration_us * options.frame_rate * 1e-6 + 1
    if n_frames > MAX_GT_FRAMES:
        raise ParameterError(f"{n_frames:.3g} ground-truth frames ({options.frame_rate:g} Hz "
                             f"over {duration_s:g} s): at most {MAX_GT_FRAMES}; lower "
                             "frame_rate (--frame-rate) or duration_s (--duration)")
    if duration_us * options.frame_rate < 1e6:
        # one frame, no flow between two (probe OPT: 1e-30 Hz wrote a ground truth of no
        # window, unsaid)
        warnings.warn(EvmotionWarning(
            f"frame_rate {options.frame_rate:g} Hz gives one ground-truth frame over "
            f"{duration_s:g} s: the ground truth holds no flow; at least "
            f"{1e6 / duration_us:g} Hz (--frame-rate) gives one window"), stacklevel=3)
    h, w = parse_sensor_size(sensor_size, MIN_SIM_SIDE)
    options.check_hot_pixels(h * w)
    K = default_K((h, w)) if options.K is None else np.array(options.K, dtype=np.float64)
    return _Run(scene, duration_us, (h, w), options, K, bool(show_progress))


def simulate(scene: str = "rotation", duration_s: float = 0.1,
             sensor_size: tuple[int, int] = (260, 346), seed: int = 0,
             texture: str | np.ndarray | Texture = "dots", threshold: float | None = None,
             params: dict | None = None, *, image=None, show_progress: bool = True,
             options: SimOptions | None = None, **keywords) -> SimResult:
    """Simulate an event camera watching a textured scene under a known motion.

    The log intensity of the scene is rendered at adaptive time steps chosen so that no
    pixel's log intensity moves by more than ``max_step_fraction * threshold`` between
    samples; in between it is linear, and a pixel fires an event each time it moves by its
    threshold from its reference level, at the interpolated crossing time (rounded up to
    the next microsecond). The recording starts with every pixel at its reference level.

    Parameters
    ----------
    scene : str
        A name of :data:`SCENES` (see :mod:`evmotion.sim.scenes` for their parameters).
    duration_s : float
        Recording length in seconds.
    sensor_size : (int, int)
        ``(height, width)``; default DAVIS346 (260, 346).
    seed : int
        Seeds texture, threshold mismatch and noise: same seed, same events.
    texture : str, ndarray or Texture
        ``dots``, ``shapes``, ``noise``, ``checker``, an image path or array (mirrored to
        a periodic raster), or a ready :class:`~evmotion.sim.textures.Texture` (used as is).
    threshold : float, optional
        Nominal contrast threshold C (log intensity) for ON and OFF events; default 0.2
        (a field of :class:`SimOptions`, positional here as it always was).
    params : dict, optional
        Motion parameters overriding the scene defaults (warp units, rates per second).
    image : path or ndarray, optional
        User image as the texture (overrides ``texture``).
    show_progress : bool
        Progress bar on stderr (only when it is a terminal).
    options : SimOptions, optional
        The event sensor, ground-truth frame rate, intrinsics and backend as one object;
        then neither ``threshold`` nor the keywords below may be given.
    **keywords
        The fields of :class:`SimOptions`, with their defaults: ``mismatch`` (0.03,
        relative std of the per-pixel thresholds), ``refractory_us`` (0, µs),
        ``noise_rate`` (0, events/s per pixel), ``hot_pixels`` (0), ``hot_rate``
        (1000 events/s), ``max_step_fraction`` (0.5: bound on the per-sample
        log-intensity change, a fraction of the threshold), ``frame_rate`` (100 Hz, the
        ground-truth frames), ``K`` ((3, 3) intrinsics; default
        :func:`~evmotion.sim.scenes.default_K`), ``backend`` (``numba``, or ``numpy``:
        the plain-numpy reference of the kernel, slow, identical events).

    Returns
    -------
    SimResult

    Raises
    ------
    ParameterError
        One line naming the bad argument or option (an unknown keyword included).

    Examples
    --------
    >>> res = simulate("zoom", duration_s=0.01, sensor_size=(60, 80), seed=1)
    >>> res.events.sensor_size, res.gt.params(0)["hz"]
    ((60, 80), 1.5)
    >>> quiet = SimOptions(threshold=0.4)
    >>> res2 = simulate("zoom", duration_s=0.01, sensor_size=(60, 80), seed=1, options=quiet)
    >>> len(res2.events) < len(res.events)
    True
    """
    if threshold is not None:
        keywords["threshold"] = threshold
    opts = resolve_options(SimOptions, options, keywords, "simulate")
    run = _checked_run(scene, duration_s, sensor_size, opts, show_progress)
    seed = whole_number("seed", seed, lo=0)
    p = resolve_params(scene, params, run.sensor_size)
    layers, texs = build_layers(scene, p, run.sensor_size, run.K, texture, image, seed)
    _check_motion(scene, p, layers, run.duration_us * 1e-6)
    ss = np.random.SeedSequence(seed).spawn(4)
    cp, cn = _thresholds(np.random.default_rng(ss[2]), opts.threshold, opts.mismatch,
                         run.sensor_size)
    x, y, tt, pp, n_samples, n_sub = _signal_events(run, layers, texs, cp, cn)
    events, n_signal, n_noise = _with_noise(x, y, tt, pp, np.random.default_rng(ss[3]),
                                            run.sensor_size, run.duration_us, opts,
                                            {"simulator": "evmotion.sim", "scene": scene})
    gt = _ground_truth(run, layers, events)
    stats = {"n_events": len(events), "n_signal": int(n_signal), "n_noise": int(n_noise),
             "n_steps": n_samples, "n_subsamples": n_sub, "threshold": opts.threshold,
             "threshold_on_mean": float(cp.mean()), "threshold_off_mean": float(cn.mean()),
             "texture": texs[0].name}
    if not len(events):
        warnings.warn(EvmotionWarning(
            f"simulate('{scene}'): no event in {duration_s} s: the texture has no contrast "
            f"the motion moves across (a constant image?), the motion is too slow, or the "
            f"threshold {opts.threshold} is above the scene's log-intensity changes"),
            stacklevel=2)
    return SimResult(events, gt, scene, p, stats, (cp, cn))


class _Stepper:
    """The geometry of the adaptive steps of :func:`simulate`: layer matrices on a step's
    sub-sample grid, how far the texture moves over a step, and the pixel boxes of the
    upper layers."""

    def __init__(self, layers, texs, sensor_size, duration_us: int):
        self.layers, self.texs, self.duration_us = layers, texs, duration_us
        h, w = sensor_size
        self.mats_cache: dict = {}
        # points whose texture motion bounds the step: a grid over the sensor for opaque
        # layers, a sample of the opaque support (reference coordinates) for the others
        gy, gx = np.meshgrid(np.linspace(0, h - 1, 9), np.linspace(0, w - 1, 9), indexing="ij")
        self.grid = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
        self.supports, self.corners = [], []
        for tex in texs:
            support, corners = _support(tex)
            self.supports.append(support)
            self.corners.append(corners)
        self.boxes = full_boxes(len(texs), sensor_size)
        self.sensor_corners = np.array([[0.0, w - 1, w - 1, 0], [0, 0, h - 1, h - 1],
                                        [1, 1, 1, 1]])
        self.w, self.h = w, h

    def mats(self, t0_us: int, t1_us: int) -> np.ndarray:
        """Layer matrices at the step's sub-sample grid. Once the step length settles
        (constant speeds), the next steps repeat it: their grids are evaluated in the same
        call, as the warp's per-call cost exceeds its per-time cost."""
        hit = self.mats_cache.pop((t0_us, t1_us), None)
        if hit is not None:
            return hit
        self.mats_cache.clear()
        span = t1_us - t0_us
        starts = [s for s in range(t0_us, t0_us + PREFETCH_STEPS * span, span)
                  if s + span <= self.duration_us] if span > 0 else []
        if not starts:
            starts = [t0_us]
        ts = np.concatenate([step_grid(s, s + span) for s in starts]) * 1e-6
        m = np.stack([layer.motion.matrices(ts).reshape(-1, 9) for layer in self.layers],
                     axis=1)
        m = m.reshape(len(starts), MAX_SUBSAMPLES + 1, len(self.layers), 9)
        for i, s in enumerate(starts[1:], 1):
            self.mats_cache[(s, s + span)] = np.ascontiguousarray(m[i])
        return np.ascontiguousarray(m[0])

    def update_boxes(self, m0: np.ndarray, m1: np.ndarray) -> None:
        """Pixel boxes of the upper layers' opaque support over a step (the mapped corners
        of its reference box at both ends, plus a margin for the motion in between). The
        rasters are periodic: the box is that of the one copy of the support the sensor
        sees, or the whole sensor where it may see several."""
        w, h, boxes = self.w, self.h, self.boxes
        for k in range(1, len(self.texs)):
            boxes[k] = (0.0, 0.0, w - 1.0, h - 1.0)
            if self.corners[k] is None:
                continue
            foot = np.concatenate([m.reshape(3, 3) @ self.sensor_corners for m in (m0[k], m1[k])],
                                  axis=1)
            if np.any(foot[2] <= 0):
                continue
            fx, fy = foot[0] / foot[2], foot[1] / foot[2]
            th, tw = self.texs[k].shape
            c = self.corners[k]
            # copies n: the support shifted by n raster periods meets the footprint
            nx = np.arange(math.ceil((fx.min() - 4 - c[0, 1]) / tw),
                           math.floor((fx.max() + 4 - c[0, 0]) / tw) + 1)
            ny = np.arange(math.ceil((fy.min() - 4 - c[1, 2]) / th),
                           math.floor((fy.max() + 4 - c[1, 0]) / th) + 1)
            if nx.size > 1 or ny.size > 1:
                continue
            shifted = c + np.array([[tw * (nx[0] if nx.size else 0)],
                                    [th * (ny[0] if ny.size else 0)], [0.0]])
            pts = np.concatenate([np.linalg.solve(m.reshape(3, 3), shifted)
                                  for m in (m0[k], m1[k])], axis=1)
            px, py = pts[0] / pts[2], pts[1] / pts[2]
            boxes[k] = (px.min() - 2, py.min() - 2, px.max() + 2, py.max() + 2)

    def shift(self, m0: np.ndarray, m1: np.ndarray) -> float:
        """Largest motion (px) of the texture point seen at a probe pixel between two
        times; the step keeps it below STEP_SHIFT_PX."""
        return float(self.shifts(m0[None], m1[None])[0])

    def shifts(self, m0: np.ndarray, m1: np.ndarray) -> np.ndarray:
        """:meth:`shift` of each pair ``(m0[i], m1[i])`` of layer matrices ``(T, L, 9)``."""
        out = np.zeros(m0.shape[0])
        for k in range(m0.shape[1]):
            a, b = m0[:, k].reshape(-1, 3, 3), m1[:, k].reshape(-1, 3, 3)
            sup = self.supports[k]
            if sup is not None and sup.shape[1] == 0:
                continue
            if sup is None:
                q0, q1 = a @ self.grid, b @ self.grid
            else:  # the support's points where they are at m0, and at m1
                q0, q1 = sup[None], (b @ np.linalg.inv(a)) @ sup
            with np.errstate(all="ignore"):
                d = q1[:, :2] / q1[:, 2:] - q0[:, :2] / q0[:, 2:]
            out = np.fmax(out, np.sqrt((d ** 2).sum(axis=1)).max(axis=-1))
        return out

    def too_fast(self, n: int = 256) -> tuple[float, float] | None:
        """An interval (start, end in µs) where some texture point moves more than
        STEP_SHIFT_PX in 1 µs, the shortest step, or None: the first of ``n`` equal
        intervals of the duration where it does in the interval's last µs or on average
        over it (the shift over an interval is at most the sum of its 1-µs steps'),
        narrowed the same way within it. A scene refused here would fail in the loop,
        after minutes spent on its earlier part."""
        found, lo, hi = None, 0, self.duration_us
        while hi - lo > 1:
            ts = np.unique(np.linspace(lo, hi, n + 1).round())
            m, m1 = (np.stack([layer.motion.matrices(t * 1e-6).reshape(-1, 9)
                               for layer in self.layers], axis=1) for t in (ts, ts[1:] - 1))
            # each interval's last step, inside it (the step after the last sample lay
            # past the recording's end: a duration 1 us short of the one that fails had
            # been refused, probe CA)
            step = np.flatnonzero(self.shifts(m1, m[1:]) > STEP_SHIFT_PX)
            mean = np.flatnonzero(self.shifts(m[:-1], m[1:]) > STEP_SHIFT_PX * np.diff(ts))
            firsts = list(step[:1]) + list(mean[:1])
            if not firsts:
                break
            k = int(min(firsts))
            found = lo, hi = float(ts[k]), float(ts[k + 1])
        return found


def _support(tex: Texture):
    """A sample of a layer's opaque support (reference coordinates, homogeneous) and the
    corners of its bounding box with one cell of margin; ``(None, None)`` for an opaque
    layer, ``(empty, None)`` for one never visible."""
    if tex.alpha is None:
        return None, None
    iy, ix = np.nonzero(tex.alpha > 0)
    sub = slice(None, None, max(1, iy.size // 200))
    support = np.stack([ix[sub] + tex.origin[0], iy[sub] + tex.origin[1],
                        np.ones(iy[sub].size)])
    if iy.size == 0:  # never visible: no box needed, the kernel skips zero alpha
        return support, None
    # one cell of margin: a bilinear sample is nonzero next to a nonzero cell
    x0, x1 = ix.min() + tex.origin[0] - 1, ix.max() + tex.origin[0] + 1
    y0, y1 = iy.min() + tex.origin[1] - 1, iy.max() + tex.origin[1] + 1
    return support, np.array([[x0, x1, x1, x0], [y0, y0, y1, y1], [1.0, 1, 1, 1]])


def _step_layers(texs, boxes, backend: str) -> tuple[StepLayers, StepLayers]:
    """The layers of the steps (matrices left out) with padded rasters, as the numba
    kernels take them, and as ``backend``'s kernel takes them (unpadded for numpy);
    ``boxes`` is the array the stepper updates in place."""
    alphas = [t.alpha if t.alpha is not None else np.ones(t.shape, np.float32) for t in texs]
    origins = np.array([t.origin for t in texs], dtype=np.float64)
    padded = StepLayers(None, np.stack([pad_periodic(t.log_i) for t in texs]),
                        np.stack([pad_periodic(a) for a in alphas]), origins, boxes,
                        textured_cells_sat(texs[0].log_i))
    if backend == "numpy":
        return padded, StepLayers(None, np.stack([t.log_i for t in texs]), np.stack(alphas),
                                  origins)
    return padded, padded


def _signal_events(run: _Run, layers, texs, cp, cn):
    """The events of the moving scene, in time order: ``x, y, t, p`` and the step and
    sub-sample counts."""
    h, w = run.sensor_size
    duration_us = run.duration_us
    stepper = _Stepper(layers, texs, run.sensor_size, duration_us)
    fast = stepper.too_fast()
    if fast is not None:
        # said before the work (a 3 s default rotation, past 90 degrees at 1.2 s, failed
        # after 3 minutes)
        raise ParameterError(f"{run.scene}: the scene moves faster than the simulator's "
                             f"shortest step follows ({STEP_SHIFT_PX:g} px in 1 us) at t = "
                             f"{fast[0] * 1e-6:.6g} s: simulate less than that or give "
                             "slower motion (params)")
    padded, scene = _step_layers(texs, stepper.boxes, run.options.backend)
    kernel = _step_numpy if run.options.backend == "numpy" else sim_step
    refr = run.options.refractory_us
    la = np.zeros((h, w), np.float32)
    lb = np.empty((h, w), np.float32)
    m_start = stepper.mats(0, 0)[0]
    stepper.update_boxes(m_start, m_start)
    render_log(m_start, padded.texs, padded.alphas, padded.origins, la, stepper.boxes)
    ref = la.astype(np.float64)
    last = np.full((h, w), np.iinfo(np.int64).min // 2, dtype=np.int64)
    ref_bak, last_bak = ref.copy(), last.copy()
    bufs = EventBuffers.empty(h * w * 4)
    chunks = []
    packed = (duration_us + 1) * 2 * h * w < 2 ** 62  # the sort key fits in an int64
    t, dt, n_samples, n_sub = 0, 200, 0, 0
    bar = progress(None, total=duration_us, desc=f"simulate {run.scene}", unit="us",
                   disable=None if run.show_progress else True)
    while t < duration_us:
        tb = min(t + dt, duration_us)
        Mseq = stepper.mats(t, tb)
        d = stepper.shift(Mseq[0], Mseq[-1])
        if d > STEP_SHIFT_PX and tb - t > 1:
            dt = max(1, int((tb - t) * STEP_GROW * STEP_SHIFT_PX / d))
            continue
        if d > STEP_SHIFT_PX:
            # faster than the shortest step follows (vx=1e12 px/s wrote 18 M events that
            # follow no motion, with no word: probe)
            raise ParameterError(f"{run.scene}: the scene moves {d:.3g} px in 1 us, the "
                                 "simulator's shortest step, at t = "
                                 f"{t * 1e-6:.6g} s (its events follow at most "
                                 f"{STEP_SHIFT_PX:g} px a step): give slower motion "
                                 "(params)")
        stepper.update_boxes(Mseq[0], Mseq[-1])
        np.copyto(ref_bak, ref)
        np.copyto(last_bak, last)
        while True:
            n, ns = kernel(scene._replace(Mseq=Mseq), PixelState(la, lb, ref, cp, cn, last),
                           bufs, t, tb, refr, run.options.target)
            if n <= bufs.x.size:
                break
            # the buffers overflowed: redo the step with room for every event
            np.copyto(ref, ref_bak)
            np.copyto(last, last_bak)
            bufs = EventBuffers.empty(2 * n)
        if n:
            chunks.append(_sorted_chunk(*bufs, n, w, h, packed))
        n_samples += 1
        n_sub += ns
        bar.update(tb - t)
        dt = _next_step(dt, tb - t, d)
        t = tb
        la, lb = lb, la
    bar.close()
    return (*_join_chunks(chunks, w, h, packed), n_samples, n_sub)


def _next_step(dt: int, taken: int, d: float) -> int:
    """The next step length (µs) after a step of ``taken`` µs (``dt`` requested) over which
    the texture moved ``d`` px."""
    grow = STEP_GROW * STEP_SHIFT_PX / d if d > 0 else 2.0
    new_dt = int(min(max(1, taken * min(grow, 2.0)), MAX_STEP_US))
    # a length that just passed the bound is kept unless the new one differs notably:
    # equal-length steps reuse the prefetched matrices (each step is still checked)
    if taken != dt or abs(new_dt - dt) > 0.05 * dt:
        return new_dt
    return dt


def _with_noise(x, y, tt, pp, rng, sensor_size, duration_us, model: EventOptions,
                meta: dict):
    """The EventArray of the signal events plus the model's noise (the refractory period
    applied to the merged stream); also the signal and noise counts."""
    n_signal = x.size
    x, y, tt, pp, n_noise = _add_noise(x, y, tt, pp, rng, sensor_size, duration_us,
                                       model.noise_rate, model.hot_pixels, model.hot_rate)
    events = EventArray(x, y, tt, pp, sensor_size, meta=dict(meta))
    if model.refractory_us > 0 and n_noise:
        from evmotion.filters import refractory_filter

        events = refractory_filter(events, model.refractory_us)
        events.meta.update(meta)
    return events, n_signal, n_noise


def _ground_truth(run: _Run, layers, events: EventArray) -> GroundTruth:
    period = 1e6 / run.options.frame_rate
    frame_times = np.round(np.arange(0, run.duration_us + 0.5 * period, period)).astype(np.int64)
    frame_times = frame_times[frame_times <= run.duration_us]
    omega = None
    if run.scene == "rotation":
        omega = layers[0].motion.theta.copy()
    elif run.scene in ("translation", "zoom"):
        omega = np.zeros(3)
    return GroundTruth(scene=run.scene, sensor_size=run.sensor_size, K=run.K, layers=layers,
                       frame_times_us=frame_times, duration_us=run.duration_us,
                       angular_velocity_rad_s=omega, events_xyt=(events.x, events.y, events.t))


@dataclass(eq=False)
class LogSimResult:
    """Output of :func:`simulate_log_function`.

    Attributes
    ----------
    events : EventArray
        Sorted events, t in µs from 0.
    thresholds : (ndarray, ndarray)
        Per-pixel ON and OFF contrast thresholds (H, W) after mismatch.
    stats : dict
        Step and sub-sample counts, signal/noise event counts, thresholds.
    """

    events: EventArray
    thresholds: tuple[np.ndarray, np.ndarray]
    stats: dict = field(default_factory=dict)


def _base_steps(duration_us: int, breaks_us, max_step_us: int) -> list[tuple[int, int]]:
    """Steps ``(t_a, t_b)`` covering ``[0, duration_us]``, ending at every break, none
    longer than ``max_step_us``."""
    cuts = {0, duration_us}
    cuts.update(int(b) for b in np.asarray(breaks_us if breaks_us is not None else [],
                                           dtype=np.int64) if 0 < b < duration_us)
    cuts = sorted(cuts)
    steps = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        k = max(1, -(-(b - a) // max_step_us))
        edges = a + (np.arange(k + 1, dtype=np.int64) * (b - a)) // k
        steps.extend((int(u), int(v)) for u, v in zip(edges[:-1], edges[1:], strict=True)
                     if v > u)
    return steps


def simulate_log_function(log_at, sensor_size: tuple[int, int], duration_us: int, *,
                          breaks_us=None, max_step_us: int = 1000, seed: int = 0,
                          show_progress: bool = False, meta: dict | None = None,
                          options: EventOptions | None = None, **keywords) -> LogSimResult:
    """Events of a sensor watching a log intensity given as a function of time.

    The same event model as :func:`simulate` (per-pixel threshold mismatch, crossings at
    linearly interpolated times rounded up to the next microsecond, refractory period,
    background-activity noise and hot pixels) for scenes that are not textures moved by
    a warp, e.g. the schlieren simulator. Time advances in steps that end at every time
    of ``breaks_us`` and last at most ``max_step_us``; in each step every pixel whose log
    intensity changed by more than ``max_step_fraction * threshold`` is re-sampled at
    ``n`` (a power of two up to 64) evenly spaced times so that consecutive samples of a
    pixel differ by about that much or less (a step that would need more is halved).

    Parameters
    ----------
    log_at : callable
        ``log_at(t_us, pix)``: log intensity at integer time ``t_us`` (µs) of the whole
        sensor, (H, W), when ``pix`` is None, else of the pixels with row-major indices
        ``pix`` (P,), returning (P,).
    sensor_size : (int, int)
        ``(height, width)``.
    duration_us : int
        Events are simulated over ``[0, duration_us]``; every pixel starts at its
        reference level at 0.
    breaks_us : array_like of int, optional
        Times that must be sample times (e.g. frame times: the events between two of them
        then account exactly for the change of log intensity between them, up to the
        thresholds).
    max_step_us : int
        Longest step; bounds the motion between full-sensor samples (a pixel whose log
        intensity leaves and comes back within one step is not re-sampled).
    seed : int
        Seeds threshold mismatch and noise.
    show_progress : bool
        Progress bar on stderr (only when it is a terminal).
    meta : dict, optional
        Stored in the events' ``meta``.
    options : EventOptions, optional
        The event sensor as one object (a :class:`SimOptions` works too; its frame rate,
        intrinsics and backend do not apply); then no keyword below may be given.
    **keywords
        The fields of :class:`EventOptions`: ``threshold``, ``mismatch``,
        ``refractory_us``, ``noise_rate``, ``hot_pixels``, ``hot_rate`` (as
        :func:`simulate`) and ``max_step_fraction`` (bound on the per-sample
        log-intensity change, as a fraction of ``threshold``).

    Returns
    -------
    LogSimResult

    Examples
    --------
    >>> import numpy as np
    >>> ramp = lambda t, pix: np.full((2, 2) if pix is None else len(pix), t * 1e-3)
    >>> res = simulate_log_function(ramp, (2, 2), 1000, threshold=0.25, mismatch=0.0)
    >>> len(res.events), res.events.t[:4].tolist()
    (16, [250, 250, 250, 250])
    """
    h, w = parse_sensor_size(sensor_size, 1)
    # (NaN failed in int(), 1e30 ran on; probe API)
    duration_us = whole_number("duration_us", duration_us, lo=1,
                               hi=int(MAX_SIM_DURATION_S * 1_000_000))
    max_step_us = int(check_number("max_step_us", max_step_us, 1, MAX_SIM_DURATION_S * 1e6,
                                   units="µs"))
    model = resolve_options(EventOptions, options, keywords, "simulate_log_function")
    model.check_hot_pixels(h * w)
    target = model.target
    ss = np.random.SeedSequence(seed).spawn(2)
    cp, cn = _thresholds(np.random.default_rng(ss[0]), model.threshold, model.mismatch, h * w)

    full = _full_sampler(log_at, (h, w))
    la = full(0)
    ref = la.copy()
    last = np.full(h * w, np.iinfo(np.int64).min // 2, dtype=np.int64)
    bufs = EventBuffers.empty(max(1024, h * w))
    packed = (duration_us + 1) * 2 * h * w < 2 ** 62
    chunks = []
    todo = _base_steps(duration_us, breaks_us, max_step_us)[::-1]
    n_steps = n_sub = 0
    bar = progress(None, total=duration_us, desc="simulate", unit="us",
                   disable=None if show_progress else True)
    while todo:
        ta, tb = todo.pop()
        lb = full(tb)
        change = np.abs(lb - la)
        if change.max(initial=0.0) > MAX_SUBSAMPLES * target and tb - ta > 1:
            mid = (ta + tb) // 2
            todo.extend([(mid, tb), (ta, mid)])
            continue
        samples = _pixel_samples(log_at, ta, tb, la, lb, change, target)
        n_sub += sum((len(times) - 2) * pix.size for times, pix, _ in samples)
        while True:
            ref_bak, last_bak = ref.copy(), last.copy()
            n = 0
            for times, pix, vals in samples:
                n = emit_crossings(vals, times, pix, w, ref, cp, cn, last,
                                   model.refractory_us, bufs, n)
            if n <= bufs.x.size:
                break
            # the buffers overflowed: redo the step with room for every event
            ref, last = ref_bak, last_bak
            bufs = EventBuffers.empty(2 * n)
        if n:
            chunks.append(_sorted_chunk(*bufs, n, w, h, packed))
        n_steps += 1
        bar.update(tb - ta)
        la = lb
    bar.close()
    events, n_signal, n_noise = _with_noise(
        *_join_chunks(chunks, w, h, packed), np.random.default_rng(ss[1]), (h, w), duration_us,
        model, dict(meta or {}, simulator="evmotion.sim"))
    stats = {"n_events": len(events), "n_signal": int(n_signal), "n_noise": int(n_noise),
             "n_steps": n_steps, "n_subsamples": int(n_sub), "threshold": model.threshold,
             "threshold_on_mean": float(cp.mean()), "threshold_off_mean": float(cn.mean())}
    return LogSimResult(events, (cp.reshape(h, w), cn.reshape(h, w)), stats)


def _full_sampler(log_at, shape):
    """``log_at(t, None)`` checked (finite, ``shape``) and flattened (float64)."""
    def full(t):
        v = np.asarray(log_at(int(t), None), dtype=np.float64)
        if v.shape != shape or not np.all(np.isfinite(v)):
            raise ParameterError(f"log_at({t}, None) must return finite values of shape "
                                 f"{shape}, got shape {v.shape}")
        return v.ravel()
    return full


def _pixel_samples(log_at, ta, tb, la, lb, change, target):
    """The samples of the step ``(ta, tb)`` of :func:`simulate_log_function`: pixels are
    grouped by their number of sub-steps (the fewest power of two keeping the change
    between samples within ``target``); per group ``(times, pix, vals)`` with ``vals``
    (n_sub + 1, P) the log intensity of the pixels ``pix`` at ``times``."""
    levels = [2 ** k for k in range(int(math.log2(MAX_SUBSAMPLES)) + 1)]
    ns = np.ones(la.size, dtype=np.int64)
    for _ in range(len(levels) - 1):
        ns[change > target * ns] *= 2
    samples = []
    for lev in levels:
        pix = np.nonzero(ns == lev)[0]
        if not pix.size:
            continue
        g = np.arange(lev + 1, dtype=np.int64)
        times = ta + (g * (tb - ta)) // lev
        vals = np.empty((lev + 1, pix.size))
        vals[0], vals[-1] = la[pix], lb[pix]
        for j in range(1, lev):
            vals[j] = np.asarray(log_at(int(times[j]), pix), dtype=np.float64)
        samples.append((times, pix, vals))
    return samples
