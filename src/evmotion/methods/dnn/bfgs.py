"""A small BFGS for the few-dozen-evaluation polishes after the network (:mod:`.planar`,
:mod:`.tiles`): scipy.optimize's import cost a one-window command 0.3-0.6 s, and
torch.optim's L-BFGS imports torch._dynamo (1.5 s)."""

from __future__ import annotations

import numpy as np

__all__ = ["bfgs"]


def bfgs(fun_grad, x0: np.ndarray, max_evals: int, step_px: float = 0.5,
          xtol: float = 1e-3) -> np.ndarray:
    """BFGS with an Armijo backtracking line search, at most ``max_evals`` evaluations of
    ``fun_grad(x) -> (f, df/dx)``; the best point seen. Eight unknowns need no more, and
    scipy.optimize's import cost a one-window command 0.3-0.6 s; the cap matters, as near
    the optimum the float32 focus is noisy at the 1e-7 level (scipy's BFGS line search
    spent up to 78 evaluations there). The first step moves ``step_px`` at most; it stops
    once a step moves every parameter by less than ``xtol`` px."""
    x = np.asarray(x0, np.float64).copy()
    f, g = fun_grad(x)
    evals, n = 1, x.size
    eye = np.eye(n)
    h = eye * (step_px / max(float(np.abs(g).max()), 1e-12))
    while evals < max_evals:
        d = -h @ g
        slope = float(g @ d)
        if not slope < 0:  # the model went wrong: steepest descent again
            h = eye * (step_px / max(float(np.abs(g).max()), 1e-12))
            d, slope = -h @ g, float(-(g @ h @ g))
        t, accepted = 1.0, False
        while evals < max_evals:
            fn, gn = fun_grad(x + t * d)
            evals += 1
            if fn <= f + 1e-4 * t * slope:
                accepted = True
                break
            t *= 0.5
        if not accepted:
            break
        step, dg = t * d, gn - g
        x, f, g = x + step, fn, gn
        sy = float(step @ dg)
        if sy > 1e-12:
            if evals <= 3:  # the first curvature sets the scale (Nocedal & Wright 6.20)
                h = eye * (sy / float(dg @ dg))
            # (I - rho s y')H(I - rho y s') + rho s s', expanded: O(n^2), not the two
            # n^3 products (0.5 s of 25 evaluations at multicm's 512 tile unknowns)
            rho = 1.0 / sy
            hy = h @ dg
            h = (h - rho * (np.outer(step, hy) + np.outer(hy, step))
                 + (rho * rho * float(dg @ hy) + rho) * np.outer(step, step))
        if np.abs(step).max() < xtol:
            break
    return x
