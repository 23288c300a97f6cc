"""Literal, slow implementation of thesis Algorithm 1 with explicit index maps.

The test oracle that :class:`evmotion.methods.triplet.TripletMatcher` must match (kept
under ``tests/``, not shipped in the package) and the Python baseline of the speed
benchmark (``benchmarks/bench_triplet.py``). Pure Python + numpy, O(N) work
per event over the kept history.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import numpy as np


def triplet_reference(x, y, t, p, *, dx: float = math.sqrt(2.0), dt_us: int = 100_000,
                      tau_us: int = 3_000, quadruple: bool = False,
                      max_maps: int | None = None, with_normal: bool = False,
                      ridge: float = 1e-3, normal_kappa: int = 256):
    """Per-event flow by Algorithm 1: build H_k (5.1), search J_{k,i} in H_i (5.2), average (5.3).

    ``max_maps`` keeps only the latest index maps per polarity (the thesis keeps 20,000);
    None keeps all. Returns ``(vx, vy, valid, n)`` arrays (float64 px/s, bool, int), and with
    ``with_normal`` also ``(nx, ny)``: the normal flow ``g / |g|^2`` of the weighted
    least-squares ``g`` of ``g . (x_k - x_j) = t_k - t_j`` over the matches, each weighted by
    its Gaussian's shape (the density without its normalization) to the power
    ``normal_kappa``, with the ridge ``ridge`` x the trace of the normal equations.
    """
    x = np.asarray(x, np.int64)
    y = np.asarray(y, np.int64)
    t = np.asarray(t, np.int64)
    p = np.asarray(p, np.int64)
    n_ev = t.shape[0]
    vx = np.zeros(n_ev)
    vy = np.zeros(n_ev)
    valid = np.zeros(n_ev, bool)
    count = np.zeros(n_ev, np.int64)
    nx = np.zeros(n_ev)
    ny = np.zeros(n_ev)
    maps: dict[int, OrderedDict[int, list[int]]] = {0: OrderedDict(), 1: OrderedDict()}
    for k in range(n_ev):
        c = int(p[k])
        past = np.arange(k)
        same = past[p[:k] == c]
        d2 = (x[same] - x[k]) ** 2 + (y[same] - y[k]) ** 2
        in_window = (t[same] >= t[k] - tau_us - dt_us) & (t[same] <= t[k] - tau_us)
        h_k = [int(i) for i in same[in_window & (d2 > 0) & (d2 <= dx * dx + 1e-9)]]
        votes = []
        for i in h_k:
            if i not in maps[c]:
                continue
            delta = t[k] - t[i]
            for j in maps[c][i]:
                if not (t[i] - tau_us - dt_us <= t[j] <= t[i] - tau_us):
                    continue
                if (x[i] - x[j], y[i] - y[j]) != (x[k] - x[i], y[k] - y[i]):
                    continue
                w = _gauss(t[j], t[i] - delta, delta)
                if not quadruple:
                    votes.append((w, x[j] - x[k], y[j] - y[k], t[j] - t[k],
                                  w * _norm(delta)))
                    continue
                for m in maps[c].get(j, []):
                    if not (t[j] - tau_us - dt_us <= t[m] <= t[j] - tau_us):
                        continue
                    if (x[j] - x[m], y[j] - y[m]) != (x[i] - x[j], y[i] - y[j]):
                        continue
                    wq = w * _gauss(t[m], t[j] - delta, delta)
                    votes.append((wq, x[m] - x[k], y[m] - y[k], t[m] - t[k],
                                  wq * _norm(delta) ** 2))
        maps[c][k] = h_k
        if max_maps is not None and len(maps[c]) > max_maps:
            maps[c].popitem(last=False)
        count[k] = len(votes)
        sw = sum(v[0] for v in votes)
        if votes and sw > 0:
            vx[k] = sum(w * ddx / (dt * 1e-6) for w, ddx, _, dt, _ in votes) / sw
            vy[k] = sum(w * ddy / (dt * 1e-6) for w, _, ddy, dt, _ in votes) / sw
            valid[k] = True
        if votes:
            nx[k], ny[k] = _normal_flow(votes, ridge, normal_kappa)
    if with_normal:
        return vx, vy, valid, count, nx, ny
    return vx, vy, valid, count


def _normal_flow(votes, ridge: float, kappa: int) -> tuple[float, float]:
    w = np.array([v[4] for v in votes]) ** kappa
    s = np.array([(-v[1], -v[2]) for v in votes], float)
    d = np.array([-v[3] * 1e-6 for v in votes])
    a = (s * w[:, None]).T @ s
    if not np.trace(a) > 0:
        return 0.0, 0.0
    g = np.linalg.solve(a + ridge * np.trace(a) * np.eye(2), (s * w[:, None]).T @ d)
    gg = float(g @ g)
    return (float(g[0] / gg), float(g[1] / gg)) if gg > 0 else (0.0, 0.0)


def _norm(sigma_us) -> float:
    """sqrt(2 pi) sigma: the Gaussian density times this is its shape exp(-z^2 / 2)."""
    return math.sqrt(2.0 * math.pi) * sigma_us * 1e-6


def _gauss(value, mean, sigma_us) -> float:
    sigma = sigma_us * 1e-6
    z = (value - mean) * 1e-6 / sigma
    return math.exp(-0.5 * z * z) / (math.sqrt(2.0 * math.pi) * sigma)
