"""Assertions shared by the tests (imported as ``from _helpers import ...``; pytest puts
this folder on sys.path)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

# the real recordings (tests reach them through conftest's ``shared_data`` fixture; a test
# that only uses them when present imports this name: not ``from conftest``, which is
# ambiguous next to src/conftest.py)
SHARED_DATA = Path(os.environ.get("EVMOTION_SHARED_DATA",
                                  Path(__file__).resolve().parents[2] / "shared" / "data"))


def assert_same_events(a, b, *, dtypes: bool = False) -> None:
    """``a`` and ``b`` hold the same events: equal length, sensor size and x, y, t, p
    columns (and column dtypes with ``dtypes=True``)."""
    assert len(a) == len(b) and a.sensor_size == b.sensor_size
    for f in "xytp":
        if dtypes:
            assert getattr(a, f).dtype == getattr(b, f).dtype, f
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def assert_grad_matches_central_differences(fn, theta, g, step, rel, abs_frac) -> None:
    """Each component of the gradient ``g`` of ``fn`` at ``theta`` against a central
    difference of step ``step * max(1, |theta_j|)`` (tolerance ``rel``, and ``abs_frac`` of
    the largest gradient component)."""
    for j in range(theta.size):
        h = step * max(1.0, abs(theta[j]))
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        fd = (fn(tp) - fn(tm)) / (2 * h)
        assert g[j] == pytest.approx(fd, rel=rel, abs=abs_frac * np.abs(g).max())


def bilinear_adjoint_numpy(xw, yw, g):
    """Plain-numpy derivatives of ``sum(g * IWE)`` (bilinear votes, votes off the image
    dropped) with respect to each event's position, and its bilinear sample of ``g``."""
    h, w = g.shape
    x0, y0 = np.floor(xw), np.floor(yw)
    fx, fy = xw - x0, yw - y0
    corners = {}
    for dy in (0, 1):
        for dx in (0, 1):
            # NaN: a cell far off the image
            cx = np.nan_to_num(x0, nan=-9.0).astype(int) + dx
            cy = np.nan_to_num(y0, nan=-9.0).astype(int) + dy
            ok = (cx >= 0) & (cx < w) & (cy >= 0) & (cy < h)
            corners[dy, dx] = np.where(ok, g[np.clip(cy, 0, h - 1), np.clip(cx, 0, w - 1)], 0.0)
    c00, c01, c10, c11 = corners[0, 0], corners[0, 1], corners[1, 0], corners[1, 1]
    gx = (c01 - c00) * (1 - fy) + (c11 - c10) * fy
    gy = (c10 - c00) * (1 - fx) + (c11 - c01) * fx
    s = c00 * (1 - fx) * (1 - fy) + c01 * fx * (1 - fy) + c10 * (1 - fx) * fy + c11 * fx * fy
    return gx, gy, s


def mean_window_aee(res, wins, **params) -> float:
    """Mean AEE (px) of ``estimate_flow_triplet(res.events, wins, **params)`` against the
    simulator's displacement over each window, at the pixels with events."""
    from evmotion.eval.metrics import flow_metrics
    from evmotion.methods.triplet import estimate_flow_triplet

    ev = res.events
    out = estimate_flow_triplet(ev, wins, **params)
    return float(np.mean([flow_metrics(out.displacement(k), res.gt.displacement(w.t0, w.t1),
                                       events=ev.window(w)).aee
                          for k, w in enumerate(wins)]))


def interrupt_at_call(monkeypatch, owner, name: str, n: int) -> list:
    """Make ``owner.name`` raise KeyboardInterrupt on its ``n``-th call (a Ctrl-C in the
    middle of a run); returns the list its calls are counted in."""
    real, calls = getattr(owner, name), []

    def interrupted(*a, **k):
        calls.append(1)
        if len(calls) == n:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(owner, name, interrupted)
    return calls


def with_hot_pixels(ev, xs, ys, per_pixel: int, seed: int = 0):
    """``ev`` plus ``per_pixel`` events at each pixel ``(xs[k], ys[k])`` at uniform random
    times within its span (polarity 1), sorted by time."""
    from evmotion.events import EventArray

    rng = np.random.default_rng(seed)
    n_hot = len(xs) * per_pixel
    t = np.concatenate([ev.t, rng.integers(int(ev.t[0]), int(ev.t[-1]), n_hot)])
    order = np.argsort(t, kind="stable")
    return EventArray(np.round(np.r_[ev.x, np.repeat(xs, per_pixel)]).astype(np.uint16)[order],
                      np.round(np.r_[ev.y, np.repeat(ys, per_pixel)]).astype(np.uint16)[order],
                      t[order], np.r_[ev.p, np.ones(n_hot)][order], ev.sensor_size)


def assert_decoders_agree(module, words: np.ndarray, n_cuts: int, rng) -> np.ndarray:
    """``module.decode_words`` by numpy and by its numba kernel on ``words`` split at
    ``n_cuts`` random places, the state carried across from a fresh decoder: the same
    arrays (and dtypes) and the same state after every block; returns the final state."""
    cuts = np.sort(rng.choice(np.arange(1, words.size), n_cuts, replace=False))
    ref_state, state = module.new_state(), module.new_state()
    for part in np.split(words, cuts):
        want = module.decode_words(part, ref_state, plain=False)
        got = module.decode_words(part, state, plain=True)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)
            assert a.dtype == b.dtype
        np.testing.assert_array_equal(state, ref_state)
    return state


def random_events(n: int, sensor_size: tuple[int, int], span_us: int, seed: int = 1,
                  t0: int = 0):
    """``n`` events at uniform random pixels, times (sorted, in ``[t0, t0 + span_us)``)
    and polarities."""
    from evmotion.events import EventArray

    rng = np.random.default_rng(seed)
    h, w = sensor_size
    return EventArray(x=rng.integers(0, w, n), y=rng.integers(0, h, n),
                      t=t0 + np.sort(rng.integers(0, span_us, n)), p=rng.integers(0, 2, n),
                      sensor_size=sensor_size)


def assert_chunks_track_the_file(module, path, n: int, block_bytes: int) -> None:
    """Chunks of ``module.iter_chunks`` carry how far into ``path`` (of ``n`` uniformly
    spread events) they are: ``bytes_read`` rising to the file's size, in step with the
    events read, and ``file_bytes``."""
    size = path.stat().st_size
    chunks = list(module.iter_chunks(path, 7_000, block_bytes=block_bytes))
    done = np.cumsum([len(c) for c in chunks])
    read = np.array([c.meta["bytes_read"] for c in chunks])
    assert all(c.meta["file_bytes"] == size for c in chunks)
    assert read[-1] == size and np.all(np.diff(read) > 0)
    np.testing.assert_allclose(read / size, done / n, atol=0.03)
