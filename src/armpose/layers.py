"""Small building blocks shared by the network's modules (:mod:`armpose.model`,
:mod:`armpose.keypoints`): conv-BN(-ReLU), a separable 3x3, bilinear resizing, CoordConv
channels and a per-slot linear layer. Tensors are ``(B, C, H, W)``."""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


def conv_bn_relu(cin: int, cout: int, k: int = 3, stride: int = 1, relu: bool = True,
                 groups: int = 1) -> nn.Sequential:
    """``k`` x ``k`` conv (no bias, same padding), BatchNorm, then ReLU unless ``relu=False``."""
    layers: list[nn.Module] = [nn.Conv2d(cin, cout, k, stride, k // 2, groups=groups, bias=False),
                               nn.BatchNorm2d(cout)]
    if relu:
        layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


def separable(cin: int, cout: int, relu: bool = True) -> nn.Sequential:
    """Depthwise 3x3 conv-BN-ReLU then pointwise 1x1 conv-BN(-ReLU): a cheap 3x3."""
    return nn.Sequential(conv_bn_relu(cin, cin, 3, groups=cin), conv_bn_relu(cin, cout, 1, relu=relu))


def resize(x: torch.Tensor, size) -> torch.Tensor:
    """Bilinear resize of ``x`` to ``size`` (h, w), align_corners=False."""
    return F.interpolate(x, size=size, mode="bilinear", align_corners=False)


def coord_channels(like: torch.Tensor) -> torch.Tensor:
    """``(1, 2, h, w)`` x and y of each cell centre in [-1, 1] (align_corners=False convention)."""
    h, w = like.shape[-2:]
    ys = (torch.arange(h, device=like.device, dtype=like.dtype) * 2 + 1) / h - 1
    xs = (torch.arange(w, device=like.device, dtype=like.dtype) * 2 + 1) / w - 1
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([gx, gy])[None]


class PerSlotLinear(nn.Module):
    """A separate linear layer for each of K slots: ``(B, K, cin) -> (B, K, cout)``."""

    def __init__(self, k: int, cin: int, cout: int):
        super().__init__()
        bound = 1 / math.sqrt(cin)
        self.weight = nn.Parameter(torch.empty(k, cin, cout).uniform_(-bound, bound))
        self.bias = nn.Parameter(torch.empty(k, cout).uniform_(-bound, bound))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.einsum("bkc,kco->bko", x, self.weight) + self.bias
