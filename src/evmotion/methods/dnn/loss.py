"""The training loss: multicm's composite objective (4.9) on the network's dense flow.

For one window, the flow predicted at a decoder scale (upsampled to the sensor grid, px per
window) is the tile flow of a :class:`~evmotion.methods.multicm.MultiCMProblem` whose tiles
are the pixels: the tile interpolation of multicm is then exactly the bilinear interpolation
of the dense flow at each event's sub-pixel position, and the problem's ``value_grad`` is
``1 / f + lam * TV``: the multi-reference focus (4.6) normalized by the identity warp, and
the Charbonnier smoothness of the flow in px/s. :class:`MultiCMLoss` wraps that numba
forward/backward in a ``torch.autograd.Function``, so the training loss and its gradient
ARE multicm's (``tests/test_dnn_loss.py`` checks both to 1e-6).

Objectives: ``gradient_magnitude`` (default, the thesis), ``variance``, and the two
average-timestamp losses ``avg_timestamp`` / ``avg_timestamp_norm`` (Table 4.5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from evmotion.methods.dnn.problem import window_problem
from evmotion.methods.multicm import MultiCMProblem

__all__ = ["MultiCMLoss", "WindowLoss", "multiscale_loss", "window_problem"]


class MultiCMLoss(torch.autograd.Function):
    """``loss = problem.value_grad(flow)`` with its analytic gradient as the backward.

    ``flow``: (H, W, 2) float64 tensor, px per window (u, v).
    """

    @staticmethod
    def forward(ctx, flow: torch.Tensor, problem: MultiCMProblem) -> torch.Tensor:
        theta = flow.detach().cpu().numpy().astype(np.float64).ravel()
        val, grad = problem.value_grad(theta)
        ctx.save_for_backward(torch.from_numpy(grad.reshape(flow.shape)).to(flow.device))
        return flow.new_tensor(val)

    @staticmethod
    def backward(ctx, gout):
        (grad,) = ctx.saved_tensors
        return gout * grad, None


@dataclass
class WindowLoss:
    """One training window: its multicm problem and its size on the (padded) input grid."""

    problem: MultiCMProblem
    shape: tuple[int, int]


def multiscale_loss(flows: list[torch.Tensor], windows: list[WindowLoss]) -> torch.Tensor:
    """Mean over the batch of the sum over decoder scales of :class:`MultiCMLoss`.

    Parameters
    ----------
    flows : list of tensors (B, 2, Hp, Wp)
        The decoder's flows upsampled to the padded input size (px per window).
    windows : list of WindowLoss, length B
    """
    total = flows[0].new_zeros((), dtype=torch.float64)
    for b, win in enumerate(windows):
        h, w = win.shape
        for f in flows:
            dense = f[b, :, :h, :w].permute(1, 2, 0).to(torch.float64)
            total = total + MultiCMLoss.apply(dense, win.problem)
    return total / len(windows)
