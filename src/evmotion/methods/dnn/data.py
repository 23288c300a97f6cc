"""Training and validation windows: the simulator's scenes generated on the fly, and
windows cut from recordings (no ground truth needed: the loss is unsupervised).

Every random choice (scene, texture, motion, noise, crop) is drawn from a
``numpy.random.Generator`` seeded by the caller, so an epoch's data is a function of
``(seed, epoch)`` alone: that is what makes ``--resume`` reproduce an uninterrupted run.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evmotion.errors import EvmotionError, EvmotionWarning, ParameterError
from evmotion.events import EventArray

__all__ = ["SIM_SCENES", "TrainWindow", "crop_window", "recording_windows", "sim_window",
           "transpose_window"]

SIM_SCENES = ("translation", "rotation", "zoom", "se2", "inplane", "similarity", "affine",
              "homography", "object")
_TEXTURES = ("dots", "shapes", "noise", "checker")
_OBJECT_SPEED_KEYS = ("bg_vx", "bg_vy", "fg_vx", "fg_vy", "fg_wz")


@dataclass
class TrainWindow:
    """One window of events; ``gt`` the ground-truth displacement over it (H, W, 2) px,
    or None (recordings)."""

    events: EventArray
    gt: np.ndarray | None
    name: str


def _sim_params(scene: str, rng: np.random.Generator) -> dict:
    from evmotion.sim.scenes import SCENES

    out = {}
    for key, val in SCENES[scene].defaults.items():
        if val is None or (scene == "object" and key not in _OBJECT_SPEED_KEYS) \
                or key == "foe":
            continue
        # magnitude 0.3-1.5x the default (a few tens to ~500 px/s), random sign
        out[key] = float(val) * rng.uniform(0.3, 1.5) * rng.choice((-1.0, 1.0))
    return out


def sim_window(seed: int, *, scene: str | None = None, sensor_size=(260, 346),
               window_events: int = 40_000, texture: str | None = None,
               duration_s: float = 0.05) -> TrainWindow:
    """A simulated window: random scene (all motion kinds, independently moving object),
    texture, motion parameters, contrast threshold and noise, all drawn from ``seed``.

    Returns the middle ``window_events`` events of a ``duration_s`` recording (fewer if it has
    fewer) with the exact ground-truth displacement over the window.

    Examples
    --------
    >>> w = sim_window(3, sensor_size=(60, 80), window_events=2000)
    >>> len(w.events) <= 2000
    True
    """
    from evmotion.sim import simulate

    rng = np.random.default_rng(seed)
    scene = scene or str(rng.choice(SIM_SCENES))
    texture = texture or str(rng.choice(_TEXTURES))
    params = _sim_params(scene, rng)
    sim = simulate(scene, duration_s=duration_s, sensor_size=tuple(sensor_size), seed=int(seed),
                   texture=texture, params=params, threshold=float(rng.uniform(0.15, 0.35)),
                   noise_rate=float(rng.uniform(0.0, 0.3)), show_progress=False)
    ev = sim.events
    mid = len(ev) // 2
    half = min(window_events, len(ev)) // 2
    win = ev[mid - half: mid + half]
    if len(win) < 2:
        # a scene that fires nothing on a small sensor (probe AP: 1 seed in 300 at 64x64):
        # no motion to learn; training drops it with its too-small crops
        gt = np.zeros((*win.sensor_size, 2))
    else:
        gt = sim.gt.displacement(int(win.t[0]), int(win.t[-1]))
    return TrainWindow(win, gt, f"sim:{scene}:{texture}:seed{seed}")


def recording_windows(paths: Sequence[str | Path], window_events: int = 40_000, *,
                      what: str = "training recording", format: str | None = None,
                      sensor_size: tuple[int, int] | None = None) -> list[TrainWindow]:
    """Consecutive ``window_events`` windows of each recording (any readable format, or
    ``format``; ``sensor_size`` for files that do not state it); a last partial window is
    kept if it has at least half as many events, a first one if it has 1000. A recording
    that gives no window is named in an :class:`~evmotion.errors.EvmotionWarning`
    (``what`` says which kind it is)."""
    from evmotion.io import read_events

    kw = {k: v for k, v in (("format", format), ("sensor_size", sensor_size)) if v}
    out = []
    for path in paths:
        try:
            ev = read_events(path, **kw)
        except EvmotionError as exc:
            said = str(exc)  # a reader's error mostly names the file already
            raise ParameterError(f"{what} {said}" if said.startswith(str(path))
                                 else f"{what} {path}: {said}") from None
        n, instant = len(out), 0
        for w in ev.windows_by_count(window_events):
            if w.count >= max(window_events // 2, 1000) or (w.index == 0 and w.count >= 1000):
                win = ev.window(w)
                if win.t[-1] <= win.t[0]:
                    instant += 1  # no time for motion: its loss is no flow's (116 vs ~4)
                    continue
                if w.count < window_events // 2:
                    # (used without a word, where flow says a short window; probe CK)
                    warnings.warn(EvmotionWarning(
                        f"{what} {path}: {len(ev)} events, fewer than half a window of "
                        f"--window-events {window_events}: used as one window of "
                        f"{w.count} events"), stacklevel=2)
                out.append(TrainWindow(win, None, f"{path}#{w.index}"))
        zero = (f"{instant} window{'s' if instant > 1 else ''} with all events at one time "
                "(0 us)" if instant else "")
        if len(out) == n:
            warnings.warn(EvmotionWarning(
                f"{what} {path}: {len(ev)} events give no window (a window needs half of "
                f"--window-events {window_events} and 1000, or 1000 for the recording's "
                "first, over a positive duration"
                f"{': ' + zero if zero else ''}): not used"), stacklevel=2)
        elif zero:
            warnings.warn(EvmotionWarning(f"{what} {path}: {zero} left out"), stacklevel=2)
    return out


def crop_window(win: TrainWindow, crop: tuple[int, int], rng: np.random.Generator,
                min_events: int = 1000, tries: int = 10) -> TrainWindow | None:
    """A random ``crop = (h, w)`` region of the window (each axis no larger than the
    sensor), its events shifted to the crop's origin; None if no try keeps
    ``min_events`` events. The first ``tries`` are anywhere on the sensor, the next
    ``tries`` around a random event (events gathered in a corner of a large sensor were
    missed by every blind try, and the run failed or not by the seed)."""
    h, w = win.events.sensor_size
    ch, cw = min(crop[0], h), min(crop[1], w)
    ev = win.events
    x = np.asarray(ev.x, dtype=np.float64)
    y = np.asarray(ev.y, dtype=np.float64)
    for k in range(2 * tries):
        if k < tries:
            oy = int(rng.integers(0, h - ch + 1))
            ox = int(rng.integers(0, w - cw + 1))
        else:
            e = int(rng.integers(0, len(ev))) if len(ev) else 0
            oy = int(np.clip(y[e] - ch // 2, 0, h - ch)) if len(ev) else 0
            ox = int(np.clip(x[e] - cw // 2, 0, w - cw)) if len(ev) else 0
        keep = (x >= ox) & (x < ox + cw) & (y >= oy) & (y < oy + ch)
        if keep.sum() < min_events:
            continue
        xs = x[keep] - ox
        ys = y[keep] - oy
        if np.issubdtype(ev.x.dtype, np.integer):
            xs, ys = xs.astype(np.int64), ys.astype(np.int64)
        sub = EventArray(x=xs, y=ys, t=ev.t[keep], p=ev.p[keep], sensor_size=(ch, cw),
                         validate=False)
        gt = None if win.gt is None else win.gt[oy:oy + ch, ox:ox + cw]
        return TrainWindow(sub, gt, f"{win.name}@{oy},{ox}")
    return None


def transpose_window(win: TrainWindow) -> TrainWindow:
    """The window mirrored about the image diagonal: x and y swapped, the sensor ``(h, w)``
    becomes ``(w, h)`` and the ground truth's (u, v) becomes (v, u).

    Training augmentation: the simulated scenes and the recordings move more horizontally
    than vertically (e.g. the translation default 220 / -130 px/s, wider than tall
    sensors), and a network trained on them learned u only (gain of v on the held-out
    windows 0.05); transposing half the windows gives both axes the same statistics. The
    symmetric network (the default since) computes each axis with the other's weights on
    the mirrored input, so it sees every window both ways already.

    Examples
    --------
    >>> ev = EventArray(x=np.array([3]), y=np.array([1]), t=np.array([0]), p=np.array([1]),
    ...                 sensor_size=(2, 5))
    >>> w = transpose_window(TrainWindow(ev, np.zeros((2, 5, 2)), "a"))
    >>> (int(w.events.x[0]), int(w.events.y[0]), w.events.sensor_size, w.gt.shape)
    (1, 3, (5, 2), (5, 2, 2))
    """
    ev = win.events
    h, w = ev.sensor_size
    sub = EventArray(x=ev.y, y=ev.x, t=ev.t, p=ev.p, sensor_size=(w, h), validate=False)
    gt = None if win.gt is None else np.ascontiguousarray(win.gt.transpose(1, 0, 2)[..., ::-1])
    return TrainWindow(sub, gt, f"{win.name}:T")
