"""EV-FlowNet (Zhu et al., RSS 2018): a U-Net encoder-decoder with residual blocks and a
flow prediction at each of the four decoder scales, with a width multiplier.

Input: a voxel grid ``(B, n_bins, H, W)`` with ``H, W`` multiples of 16. Output: a list of
four flows ``(B, 2, H / 2^k, W / 2^k)``, ``k = 3, 2, 1, 0`` (coarse to fine), in px per
window at full resolution (u right, v down), i.e. the displacement over the window.

Width 1 has the paper's channels (64, 128, 256, 512; about 13 M parameters); the shipped
default is width 0.125.

:class:`InferenceNet` computes the finest flow of a trained :class:`EVFlowNet` with the same
weights, rearranged for speed (training always runs :class:`EVFlowNet`).
"""

from __future__ import annotations

import numbers

import torch
from torch import nn
from torch.nn import functional as F

from evmotion.errors import ParameterError
from evmotion.methods.dnn import MAX_WIDTH

__all__ = ["FLOW_SCALE", "NORMS", "EVFlowNet", "InferenceNet", "upsample_flows"]

#: The prediction heads output flow in units of FLOW_SCALE px per window, so that the
#: network works with O(1) values.
FLOW_SCALE = 10.0
#: Normalization after each encoder and decoder convolution: ``"batch"`` (batch norm, as
#: EV-FlowNet) or ``"none"`` (the checkpoints of before 2026-11-28 carry no norm).
NORMS = ("batch", "none")


def _conv(cin: int, cout: int, stride: int = 1, norm: str = "batch") -> nn.Sequential:
    layers = [nn.Conv2d(cin, cout, 3, stride=stride, padding=1)]
    if norm == "batch":
        layers.append(nn.BatchNorm2d(cout))
    return nn.Sequential(*layers, nn.ReLU())


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
    norm : {"batch", "none"}
        Batch normalization after each encoder and decoder convolution (EV-FlowNet's), or
        none. Why batch norm: without it a two-channel network learned one flow component
        only (the larger one in the data; the other's gain stayed near 0, even supervised
        with the ground truth); with it, it fits both on its training windows
        (``benchmarks/results/dnn_axes.md``); ``symmetric`` makes both hold on new ones.
    symmetric : bool
        One set of weights for both axes: u is the network's first output channel, and v
        the same channel of the input mirrored about the diagonal (x <-> y), mirrored back.
        Optical flow is equivariant to that mirroring (it swaps u and v), and this makes
        the network so by construction: each axis learns from every window's motion along
        both, and neither can be learned at the other's expense. Costs a second pass.

    Examples
    --------
    >>> net = EVFlowNet(width=0.0625)
    >>> [f.shape[-1] for f in net(torch.zeros(1, 5, 32, 48))]
    [6, 12, 24, 48]
    """

    def __init__(self, n_bins: int = 5, width: float = 0.125, norm: str = "batch",
                 symmetric: bool = True):
        super().__init__()
        if norm not in NORMS:
            raise ValueError(f"norm must be one of {', '.join(NORMS)}, got {norm!r}")
        if not 0 < width <= MAX_WIDTH:
            raise ParameterError(f"width must be in (0, {MAX_WIDTH:g}], got {width!r}")
        if not (isinstance(n_bins, numbers.Integral) and n_bins >= 1):
            # (n_bins=0 reached torch, which warned of zero-element tensors first)
            raise ParameterError(f"n_bins must be a whole number >= 1, got {n_bins!r}")
        self.n_bins, self.width, self.norm = int(n_bins), float(width), norm
        self.symmetric = bool(symmetric)
        c = [max(4, round(width * k)) for k in (32, 64, 128, 256, 512)]
        ins = (n_bins, c[1], c[2], c[3])
        self.enc = nn.ModuleList([_conv(i, o, 2, norm) for i, o in zip(ins, c[1:], strict=True)])
        self.res = nn.Sequential(_Residual(c[4]), _Residual(c[4]))
        # decoder level i: concat(previous, skip, previous flow) -> x2 upsample -> conv
        ins = (2 * c[4], 2 * c[3] + 2, 2 * c[2] + 2, 2 * c[1] + 2)
        self.dec = nn.ModuleList([_conv(i, o, 1, norm)
                                  for i, o in zip(ins, (c[3], c[2], c[1], c[0]), strict=True)])
        self.heads = nn.ModuleList([nn.Conv2d(ch, 2, 1) for ch in (c[3], c[2], c[1], c[0])])
        for h in self.heads:
            # start near zero flow: the identity warp, where the loss is 1
            nn.init.normal_(h.weight, std=1e-3)
            nn.init.zeros_(h.bias)

    def forward(self, voxel: torch.Tensor) -> list[torch.Tensor]:
        if not self.symmetric:
            return self._flows(voxel)
        return [_mirror_merge(a, b) for a, b in zip(self._flows(voxel),
                                                    self._flows(_mirrored(voxel)), strict=True)]

    def _flows(self, voxel: torch.Tensor) -> list[torch.Tensor]:
        """The four flows of one pass (both output channels as predicted)."""
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


def _mirrored(x: torch.Tensor) -> torch.Tensor:
    """``x`` mirrored about the image diagonal (its last two axes swapped), contiguous."""
    return x.transpose(-1, -2).contiguous()


def _mirror_merge(direct: torch.Tensor, mirrored: torch.Tensor) -> torch.Tensor:
    """The flow ``(u, v)`` of a symmetric network: u from the direct pass, v the mirrored
    pass's first channel mirrored back."""
    return torch.cat([direct[:, :1], mirrored[:, :1].transpose(-1, -2)], 1)


def upsample_flows(flows: list[torch.Tensor], shape: tuple[int, int]) -> list[torch.Tensor]:
    """Each flow bilinearly upsampled to ``shape`` (the padded input size); the values are
    already px per window at full resolution."""
    return [f if tuple(f.shape[-2:]) == tuple(shape)
            else F.interpolate(f, size=tuple(shape), mode="bilinear", align_corners=False)
            for f in flows]


# Row (or column) taps of a 3 x 3 kernel seen from the input of a x2 nearest upsampling:
# output row 2i + a reads upsampled rows 2i + a - 1 .. 2i + a + 1, i.e. input rows
# i - 1, i, i (a = 0) or i, i, i + 1 (a = 1). _PHASE_TAPS[a][r, k]: 1 where kernel tap k
# lands on input row i + r - 1.
_PHASE_TAPS = (((1.0, 0.0, 0.0), (0.0, 1.0, 1.0), (0.0, 0.0, 0.0)),
               ((0.0, 0.0, 0.0), (1.0, 1.0, 0.0), (0.0, 0.0, 1.0)))


def _folded(seq: nn.Sequential) -> tuple[torch.Tensor, torch.Tensor]:
    """Weight and bias of a block's convolution with its batch norm (if any) folded in, in
    eval mode (running statistics): ``bn(conv(x)) = conv'(x)``."""
    conv = seq[0]
    w, b = conv.weight.detach(), conv.bias.detach()
    if isinstance(seq[1], nn.BatchNorm2d):
        bn = seq[1]
        k = bn.weight.detach() / torch.sqrt(bn.running_var + bn.eps)
        w = w * k[:, None, None, None]
        b = (b - bn.running_mean) * k + bn.bias.detach()
    return w, b


def _subpixel_conv(w: torch.Tensor, bias: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weights of ``conv(upsample_nearest_x2(x))`` as one 3 x 3 convolution of ``x`` with
    4 outputs per channel (the four phases ``(a, b)`` of each output pixel ``(2i + a,
    2j + b)``, in :func:`torch.nn.functional.pixel_shuffle`'s order ``c * 4 + 2 a + b``):
    the same sums at a quarter of the pixels, with no upsampled copy of the input."""
    taps = [torch.tensor(t, dtype=w.dtype, device=w.device) for t in _PHASE_TAPS]
    phases = [torch.einsum("pk,oikl,ql->oipq", taps[a], w, taps[b])
              for a in (0, 1) for b in (0, 1)]
    cout, cin = w.shape[:2]
    weight = torch.stack(phases, 1).reshape(cout * 4, cin, 3, 3)
    return (weight.contiguous(memory_format=torch.channels_last),
            bias.repeat_interleave(4))


def _phase_head(head: nn.Conv2d, scale: float) -> tuple[torch.Tensor, torch.Tensor]:
    """A 1 x 1 prediction head applied to each phase of a sub-pixel feature map (channels
    ``c * 4 + phase``), as a matrix for :func:`torch.nn.functional.linear`, times ``scale``."""
    w = head.weight.detach()[:, :, 0, 0]
    k, c = w.shape
    eye = torch.eye(4, dtype=w.dtype, device=w.device)
    weight = torch.einsum("kc,pq->kpcq", w, eye).reshape(k * 4, c * 4)
    return weight * scale, head.bias.detach().repeat_interleave(4) * scale


class InferenceNet:
    """The finest flow of a trained :class:`EVFlowNet`, computed faster (inference only).

    The same function of the same weights, rearranged (the results agree to float32
    rounding, ``tests/test_dnn_infer.py``):

    * each decoder level's "x2 nearest upsampling, then 3 x 3 convolution" is one 3 x 3
      convolution at the lower resolution with four outputs per channel (the four
      sub-pixel phases; :func:`_subpixel_conv`), rearranged by ``pixel_shuffle``: the
      upsampled copy of the concatenated input is never made, and the convolution has 4x
      more outputs on 4x fewer pixels, which the CPU's GEMM runs far better (4 output
      channels at full resolution leave most of its vector lanes empty);
    * batch norms are folded into their convolutions (eval mode: running statistics);
    * the prediction heads run on the phase maps as a matrix product (1 x 1 convolutions
      took torch's slow path), and the finest level's features are never shuffled to full
      resolution: only its flow is;
    * tensors are channels-last (NHWC), the layout of the CPU's convolution kernels, and
      ReLUs work in place;
    * only the finest flow is scaled to px (the coarser ones feed the next level
      unscaled, as in training).

    Parameters
    ----------
    net : EVFlowNet
        Trained network (its current weights are copied; later changes to it are not seen).

    Examples
    --------
    >>> net = EVFlowNet(width=0.0625).eval()
    >>> x = torch.randn(1, 5, 32, 48)
    >>> with torch.inference_mode():
    ...     bool(torch.allclose(InferenceNet(net)(x), net(x)[-1], atol=1e-5))
    True
    """

    def __init__(self, net: EVFlowNet):
        self.n_bins, self.width, self.symmetric = net.n_bins, net.width, net.symmetric
        cl = torch.channels_last

        def conv(w: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            return w.contiguous(memory_format=cl), b

        def plain(c: nn.Conv2d) -> tuple[torch.Tensor, torch.Tensor]:
            return conv(c.weight.detach(), c.bias.detach())

        self.enc = [conv(*_folded(seq)) for seq in net.enc]
        self.res = [(*plain(r.c1), *plain(r.c2)) for r in net.res]
        self.dec = [_subpixel_conv(*_folded(seq)) for seq in net.dec]
        n = len(net.heads)
        self.heads = [_phase_head(h, FLOW_SCALE if i == n - 1 else 1.0)
                      for i, h in enumerate(net.heads)]

    def __call__(self, voxel: torch.Tensor) -> torch.Tensor:
        """The finest flow ``(B, 2, H, W)`` in px per window (``net(voxel)[-1]``), for a
        voxel grid ``(B, n_bins, H, W)`` (H, W multiples of 16; any memory layout)."""
        if not self.symmetric:
            return self._finest(voxel)
        return _mirror_merge(self._finest(voxel), self._finest(voxel.transpose(-1, -2)))

    def _finest(self, voxel: torch.Tensor) -> torch.Tensor:
        x = voxel.contiguous(memory_format=torch.channels_last)
        skips = []
        for w, b in self.enc:
            x = F.relu_(F.conv2d(x, w, b, stride=2, padding=1))
            skips.append(x)
        for w1, b1, w2, b2 in self.res:
            x = F.relu_(x + F.conv2d(F.relu_(F.conv2d(x, w1, b1, padding=1)), w2, b2,
                                     padding=1))
        flow = None
        last = len(self.dec) - 1
        for i, ((w, b), head) in enumerate(zip(self.dec, self.heads, strict=True)):
            parts = [x, skips[last - i]] + ([flow] if flow is not None else [])
            y = F.relu_(F.conv2d(torch.cat(parts, 1), w, b, padding=1))
            # the head on each phase (NHWC: channels last is a matrix product), then the
            # phases to their pixels
            flow = F.pixel_shuffle(F.linear(y.permute(0, 2, 3, 1), *head).permute(0, 3, 1, 2),
                                   2)
            if i < last:
                x = F.pixel_shuffle(y, 2)
        return flow
