"""Time-aware flow: transport a flow field along its own streamlines (eq. 4.7, App. B).

The flow is assumed constant along its streamlines, ``v_t + (v . grad) v = 0``. Given the
flow at one time, explicit finite-difference schemes on the pixel grid (dx = dy = 1 px)
propagate it to other times:

* ``"upwind"`` (B.4): first-order upwind differences for every advection term;
* ``"burgers"`` (B.5-B.6): the self-advection terms ``v_x d_x v_x`` and ``v_y d_y v_y``
  use the conservative Engquist-Osher flux of the inviscid Burgers equation, the cross
  terms stay upwind.

Upwind direction: information travels with the flow, so for a positive velocity the
backward difference is used (this is what makes the scheme stable; B.4 in the thesis prints
the forward difference, which corresponds to integrating backwards in time). Backward time
is handled exactly by symmetry: ``w(x, s) = -v(x, t0 - s)`` obeys the same equation.

Stability: every transport is split into sub-steps with ``dt * max(|v_x| + |v_y|) <= cfl``
(``cfl = 0.9`` px per sub-step); an anchor implementation took one step per bin and
silently went unstable above 1 px per bin.

:func:`transport_adjoint` is the exact adjoint (transposed Jacobian) of the discrete
scheme, with the upwind selections frozen at the forward values -- the scheme is piecewise
smooth and the selections change only on a measure-zero set.

Units: flow in px per unit time and time in the same unit (multicm uses px per window and
window fractions).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from evmotion.errors import ParameterError

__all__ = ["TransportPlan", "transport", "transport_adjoint", "transport_to_times"]

SCHEMES = ("upwind", "burgers")


@njit(cache=True, inline="always")
def _upwind(vx, vy, i, j, h, w):
    """Upwind neighbours: column jn and row im, with signs a, b so that the one-sided
    difference of a field q is a * (q_c - q[i, jn]) along x and b * (q_c - q[im, j]) along y."""
    if vx > 0:
        jn = max(j - 1, 0)
        a = 1.0
    else:
        jn = min(j + 1, w - 1)
        a = -1.0
    if vy > 0:
        im = max(i - 1, 0)
        b = 1.0
    else:
        im = min(i + 1, h - 1)
        b = -1.0
    return jn, a, im, b


@njit(cache=True, inline="always")
def _neighbours(i, j, h, w):
    """Right, left, lower and upper neighbour indices, clamped at the border."""
    return min(j + 1, w - 1), max(j - 1, 0), min(i + 1, h - 1), max(i - 1, 0)


@njit(cache=True)
def _step(v, dt, burgers, out):
    _, h, w = v.shape
    for i in range(h):
        for j in range(w):
            vx = v[0, i, j]
            vy = v[1, i, j]
            jn, a, im, b = _upwind(vx, vy, i, j, h, w)
            dxvy = a * (vy - v[1, i, jn])
            dyvx = b * (vx - v[0, im, j])
            if burgers:
                jr, jl, ir, il = _neighbours(i, j, h, w)
                vr = v[0, i, jr]
                vl = v[0, i, jl]
                ux = 0.5 * ((vx * abs(vx)) + (vr * vr if vr < 0 else 0.0)
                            - (vl * vl if vl > 0 else 0.0))
                vd = v[1, ir, j]
                vu = v[1, il, j]
                uy = 0.5 * ((vy * abs(vy)) + (vd * vd if vd < 0 else 0.0)
                            - (vu * vu if vu > 0 else 0.0))
            else:
                ux = vx * a * (vx - v[0, i, jn])
                uy = vy * b * (vy - v[1, im, j])
            out[0, i, j] = vx - dt * (ux + vy * dyvx)
            out[1, i, j] = vy - dt * (vx * dxvy + uy)


@njit(cache=True)
def _step_adj(v, dt, burgers, lam, out):
    # out = J^T lam, J the Jacobian of _step at v (upwind selections frozen).
    _, h, w = v.shape
    out[:] = 0.0
    for i in range(h):
        for j in range(w):
            lx = lam[0, i, j]
            ly = lam[1, i, j]
            vx = v[0, i, j]
            vy = v[1, i, j]
            jn, a, im, b = _upwind(vx, vy, i, j, h, w)
            dxvy = a * (vy - v[1, i, jn])
            dyvx = b * (vx - v[0, im, j])
            # cross terms: new_x -= dt*vy*dyvx ; new_y -= dt*vx*dxvy
            out[0, i, j] += lx
            out[1, i, j] += ly
            out[1, i, j] -= dt * lx * dyvx
            out[0, i, j] -= dt * lx * vy * b
            out[0, im, j] += dt * lx * vy * b
            out[0, i, j] -= dt * ly * dxvy
            out[1, i, j] -= dt * ly * vx * a
            out[1, i, jn] += dt * ly * vx * a
            if burgers:
                jr, jl, ir, il = _neighbours(i, j, h, w)
                vr = v[0, i, jr]
                vl = v[0, i, jl]
                out[0, i, j] -= dt * lx * abs(vx)
                if vr < 0:
                    out[0, i, jr] -= dt * lx * vr
                if vl > 0:
                    out[0, i, jl] += dt * lx * vl
                vd = v[1, ir, j]
                vu = v[1, il, j]
                out[1, i, j] -= dt * ly * abs(vy)
                if vd < 0:
                    out[1, ir, j] -= dt * ly * vd
                if vu > 0:
                    out[1, il, j] += dt * ly * vu
            else:
                # ux = vx * a * (vx - vx_n)
                dxvx = a * (vx - v[0, i, jn])
                out[0, i, j] -= dt * lx * (dxvx + vx * a)
                out[0, i, jn] += dt * lx * vx * a
                dyvy = b * (vy - v[1, im, j])
                out[1, i, j] -= dt * ly * (dyvy + vy * b)
                out[1, im, j] += dt * ly * vy * b


def _check_scheme(scheme: str) -> bool:
    if scheme not in SCHEMES:
        raise ParameterError(f"time-aware scheme must be one of {SCHEMES}, got {scheme!r}")
    return scheme == "burgers"


#: Sub-steps beyond which a transport is refused: a field that moves its pixels this many
#: times over the span is no flow of its image (1e20 px had run for ever, probe EVAL).
MAX_SUBSTEPS = 100_000


def _n_substeps(v: np.ndarray, duration: float, cfl: float) -> int:
    speed = float(np.max(np.abs(v[0]) + np.abs(v[1]))) if v.size else 0.0
    n = speed * abs(duration) / cfl
    if not n <= MAX_SUBSTEPS:
        raise ParameterError(f"transport: the flow moves pixels up to {speed * abs(duration):.3g}"
                             f" px over the span to transport, more than {MAX_SUBSTEPS:,} CFL "
                             "sub-steps: not a flow of this image")
    return max(1, math.ceil(n))


def transport(v0: np.ndarray, duration: float, scheme: str = "burgers",
              cfl: float = 0.9) -> np.ndarray:
    """Propagate a flow field over ``duration`` (may be negative) along its streamlines.

    Parameters
    ----------
    v0 : ndarray, shape (2, H, W)
        Flow (u, v) in px per time unit at the start time.
    duration : float
        Time to propagate, in the flow's time unit (negative: backwards in time).
    scheme : {"upwind", "burgers"}
    cfl : float
        Largest displacement per sub-step in px (< 1 for stability).

    Returns
    -------
    ndarray (2, H, W): the flow at ``start + duration``.

    Examples
    --------
    >>> v = np.ones((2, 4, 4))
    >>> bool(np.allclose(transport(v, 3.0), 1.0))   # constant flow is invariant
    True
    """
    burgers = _check_scheme(scheme)
    sign = 1.0 if duration >= 0 else -1.0
    cur = np.ascontiguousarray(v0, dtype=np.float64) * sign
    n = _n_substeps(cur, duration, cfl)
    dt = abs(duration) / n
    nxt = np.empty_like(cur)
    for _ in range(n):
        _step(cur, dt, burgers, nxt)
        cur, nxt = nxt, cur
    return cur * sign


@dataclass
class TransportPlan:
    """Forward states of a multi-time transport, kept for the adjoint.

    ``flows[b]`` is the flow (2, H, W) at ``times[b]``. For the adjoint only the state at
    the start of each segment between consecutive target times is kept (a checkpoint);
    :func:`transport_adjoint` recomputes the sub-steps of one segment at a time. Memory is
    then that of the target times plus one segment, not of every CFL sub-step (a 1280x720
    window with 40 bins and fast flow held thousands of sub-step states, over 1 GB).
    """

    times: np.ndarray
    flows: list
    scheme: str
    _chains: list  # per direction: (sign, [(start state, n sub-steps, dt, bin)])


def transport_to_times(v0: np.ndarray, times: np.ndarray, scheme: str = "burgers",
                       cfl: float = 0.9) -> TransportPlan:
    """Transport ``v0`` (defined at time 0) to every time in ``times`` (any sign).

    Sub-steps respect the CFL condition between consecutive target times; the forward
    states are kept for :func:`transport_adjoint`.

    Examples
    --------
    >>> plan = transport_to_times(np.ones((2, 3, 3)), np.array([-0.5, 0.0, 0.5]))
    >>> len(plan.flows)
    3
    """
    burgers = _check_scheme(scheme)
    times = np.asarray(times, dtype=np.float64)
    v0 = np.ascontiguousarray(v0, dtype=np.float64)
    flows: list = [None] * len(times)
    chains = []
    for sign in (1.0, -1.0):
        sel = np.flatnonzero(times * sign > 0)
        sel = sel[np.argsort(times[sel] * sign)]
        if sign > 0:
            for b in np.flatnonzero(times == 0):
                flows[b] = v0.copy()
        if sel.size == 0:
            continue
        cur = v0 * sign
        segments = []
        t_prev = 0.0
        for b in sel:
            span = times[b] * sign - t_prev
            n = _n_substeps(cur, span, cfl)
            dt = span / n
            segments.append((cur, n, dt, int(b)))
            cur = _advance(cur, n, dt, burgers)
            flows[b] = cur * sign
            t_prev = times[b] * sign
        chains.append((sign, segments))
    return TransportPlan(times, flows, scheme, chains)


def _advance(cur: np.ndarray, n: int, dt: float, burgers: bool, keep: list | None = None
             ) -> np.ndarray:
    """The state after ``n`` sub-steps of ``dt`` from ``cur`` (a new array; ``cur`` is not
    modified). With ``keep``, the state before each sub-step is appended to it."""
    if keep is None:
        a, b = cur.copy(), np.empty_like(cur)
        for _ in range(n):
            _step(a, dt, burgers, b)
            a, b = b, a
        return a
    a = cur
    for _ in range(n):
        keep.append(a)
        b = np.empty_like(cur)
        _step(a, dt, burgers, b)
        a = b
    return a


def transport_adjoint(plan: TransportPlan, grads: list) -> np.ndarray:
    """Gradient with respect to ``v0`` given gradients on every transported flow.

    Parameters
    ----------
    plan : TransportPlan
        From :func:`transport_to_times`.
    grads : list of ndarray (2, H, W) or None
        ``d loss / d plan.flows[b]``.

    Returns
    -------
    ndarray (2, H, W): ``d loss / d v0`` (exact adjoint of the discrete scheme).
    """
    burgers = plan.scheme == "burgers"
    shape = next(g.shape for g in grads if g is not None)
    total = np.zeros(shape)
    for b, t in enumerate(plan.times):
        if t == 0 and grads[b] is not None:
            total += grads[b]
    for sign, segments in plan._chains:
        lam = np.zeros(shape)
        tmp = np.empty(shape)
        for start, n, dt, b in reversed(segments):
            if grads[b] is not None:
                lam += sign * grads[b]
            states: list = []
            _advance(start, n, dt, burgers, states)  # the segment's sub-steps, recomputed
            for i in range(n - 1, -1, -1):
                _step_adj(states[i], dt, burgers, lam, tmp)
                lam, tmp = tmp, lam
        total += sign * lam
    return total
