"""EV-FlowNet (Zhu et al., RSS 2018): a U-Net encoder-decoder with residual blocks and a
flow prediction at each of the four decoder scales, with a width multiplier.

Input: a voxel grid ``(B, n_bins, H, W)`` with ``H, W`` multiples of 16. Output: a list of
four flows ``(B, 2, H / 2^k, W / 2^k)``, ``k = 3, 2, 1, 0`` (coarse to fine), in px per
window at full resolution (u right, v down), i.e. the displacement over the window.

Width 1 has the paper's channels (64, 128, 256, 512; about 13 M parameters); the shipped
default is width 0.125.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

__all__ = ["FLOW_SCALE", "EVFlowNet", "upsample_flows"]

#: The prediction heads output flow in units of FLOW_SCALE px per window, so that the
#: network works with O(1) values.
FLOW_SCALE = 10.0


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride=stride, padding=1), nn.ReLU())


class _Residual(nn.Module):
    def __init__(self, c: int):
        super().__init__()
        self.c1 = nn.Conv2d(c, c, 3, padding=1)
        self.c2 = nn.Conv2d(c, c, 3, padding=1)

    def forward(self, x):
        return F.relu(x + self.c2(F.relu(self.c1(x))))


class EVFlowNet(nn.Module):
    """EV-FlowNet with channels ``round(width * (64, 128, 256, 512))`` (at least 4).

    Parameters
    ----------
    n_bins : int
        Input channels (voxel time bins).
    width : float
        Channel multiplier (1 = the paper's network).

    Examples
    --------
    >>> net = EVFlowNet(width=0.0625)
    >>> [f.shape[-1] for f in net(torch.zeros(1, 5, 32, 48))]
    [6, 12, 24, 48]
    """

    def __init__(self, n_bins: int = 5, width: float = 0.125):
        super().__init__()
        self.n_bins, self.width = int(n_bins), float(width)
        c = [max(4, round(width * k)) for k in (32, 64, 128, 256, 512)]
        self.enc = nn.ModuleList([_conv(n_bins, c[1], 2), _conv(c[1], c[2], 2),
                                  _conv(c[2], c[3], 2), _conv(c[3], c[4], 2)])
        self.res = nn.Sequential(_Residual(c[4]), _Residual(c[4]))
        # decoder level i: concat(previous, skip, previous flow) -> x2 upsample -> conv
        self.dec = nn.ModuleList([_conv(2 * c[4], c[3]), _conv(2 * c[3] + 2, c[2]),
                                  _conv(2 * c[2] + 2, c[1]), _conv(2 * c[1] + 2, c[0])])
        self.heads = nn.ModuleList([nn.Conv2d(ch, 2, 1) for ch in (c[3], c[2], c[1], c[0])])
        for h in self.heads:
            # start near zero flow: the identity warp, where the loss is 1
            nn.init.normal_(h.weight, std=1e-3)
            nn.init.zeros_(h.bias)

    def forward(self, voxel: torch.Tensor) -> list[torch.Tensor]:
        skips = []
        x = voxel
        for layer in self.enc:
            x = layer(x)
            skips.append(x)
        x = self.res(x)
        flows = []
        flow = None
        for i, (dec, head) in enumerate(zip(self.dec, self.heads, strict=True)):
            parts = [x, skips[3 - i]] + ([flow] if flow is not None else [])
            x = dec(F.interpolate(torch.cat(parts, 1), scale_factor=2.0, mode="nearest"))
            flow = head(x)
            flows.append(flow)
        return [f * FLOW_SCALE for f in flows]


def upsample_flows(flows: list[torch.Tensor], shape: tuple[int, int]) -> list[torch.Tensor]:
    """Each flow bilinearly upsampled to ``shape`` (the padded input size); the values are
    already px per window at full resolution."""
    return [f if tuple(f.shape[-2:]) == tuple(shape)
            else F.interpolate(f, size=tuple(shape), mode="bilinear", align_corners=False)
            for f in flows]
