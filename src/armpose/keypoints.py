"""The keypoint heads of :mod:`armpose.model`: 3D points (metres, camera optical frame:
x right, y down, z forward) from trunk features by spatial softmax and a learned pinhole.

A :class:`KeypointHead` makes one spatial softmax ("attention") map per point. The map's
expected image position (u, v) in [-1, 1] and the attention-pooled features, with the
global mean feature, go through a small per-point MLP giving an offset (du, dv) and a
log-depth t. The point is back-projected through a learned pinhole::

    z = exp(log_z0 + t)          (log_z0 starts at log 2.5 m; t is soft-clamped to +-3)
    x = z * (u + du) * tan_x,    y = z * (v + dv) * tan_y

where ``tan_x, tan_y`` (learned, per head) start at the half field of view of the pipeline's
network input (scale-and-crop of a 480x360, fx=525 camera to 256x212). The last MLP
layer starts at zero, so an untrained head predicts points on the ray through its
attention centre at 2.5 m. Only 3D labels are needed; the maps learn where to look from
the 3D loss (integral / soft-argmax regression).

Options (``base.model``): ``keypoint_stride: 4`` puts the maps at stride 4 instead of 8
(:class:`KeypointNeck` adds the trunk's c1); ``skeleton_context: true`` gives every point's
MLP all joints' attention centres, the 2D skeleton, as a cue for the robot's distance. Both
are off by default: neither paid for itself in the pretraining ablation
(``benchmarks/ablate_pretrain.py``, README).
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from armpose.layers import PerSlotLinear, conv_bn_relu, resize as _resize

KEYPOINT_STRIDES = (4, 8)
# half field of view, tan(theta/2), of the pipeline's 256x212 input: 480x360, fx=fy=525 scaled
# by 212/360 and cropped to 256 wide gives fx=309.2, so 128/309.2 and 106/309.2
DEFAULT_HALF_FOV_TAN = (0.414, 0.343)
DEFAULT_DEPTH = 2.5


class KeypointHead(nn.Module):
    """K 3D points from a stride-8 (or stride-4) feature map: spatial softmax, soft-argmax, log-depth, pinhole.

    With ``depth=None`` the head regresses no depth: it gives rays only (the lifting head's
    joints, whose depth comes from :func:`armpose.lifting.solve_base`). ``extra`` more outputs
    per point (raw MLP outputs, zero at initialisation) are returned for the lifting head:
    the base-relative offset and the confidence of each point."""

    def __init__(self, cin: int, k: int, hidden: int, half_fov_tan=DEFAULT_HALF_FOV_TAN,
                 depth: float | None = DEFAULT_DEPTH, extra: int = 0, context: int = 0):
        super().__init__()
        self.k, self.has_depth, self.context = k, depth is not None, context
        self.features = conv_bn_relu(cin, hidden, 1)   # the trunk already gives wide context
        self.attention = nn.Conv2d(hidden, k, 1)
        self.mlp = nn.Sequential(PerSlotLinear(k, 2 * hidden + 2 + context, hidden), nn.ReLU(inplace=True),
                                 PerSlotLinear(k, hidden, 2 + int(self.has_depth) + extra))
        nn.init.zeros_(self.mlp[-1].weight)
        nn.init.zeros_(self.mlp[-1].bias)
        if self.has_depth:
            self.log_depth = nn.Parameter(torch.tensor(math.log(depth)))
        self.half_fov_tan = nn.Parameter(torch.tensor([float(t) for t in half_fov_tan]))

    def attend(self, x: torch.Tensor, coords: torch.Tensor) -> dict[str, torch.Tensor]:
        """The first half of :meth:`forward`: features ``f``, attention ``logits`` and
        ``attn``, and the attention centres ``uv`` (B, K, 2) in [-1, 1]."""
        f = self.features(x)                                               # (B, C, h, w)
        logits = self.attention(f)                                         # (B, K, h, w)
        attn = logits.flatten(2).softmax(-1)                               # (B, K, hw)
        uv = attn @ coords.flatten(2).transpose(1, 2)                      # (B, K, 2)
        return {"f": f, "logits": logits, "attn": attn, "uv": uv}

    def forward(self, x: torch.Tensor, coords: torch.Tensor, context: torch.Tensor | None = None,
                attended: dict | None = None) -> dict[str, torch.Tensor]:
        """``rays`` (B, K, 2) normalised image coordinates (x/z, y/z) of the points, ``points``
        (B, K, 3) in the camera frame (metres; only with a depth), ``extra`` (B, K, extra),
        ``attention`` (B, K, h, w) logits and ``pooled`` (B, C), the attention-pooled
        features averaged over the K points (robot-centred). ``context`` (B, context) goes
        to every point's MLP (the skeleton context: all joints' attention centres);
        ``attended`` reuses an earlier :meth:`attend` of the same input."""
        a = attended if attended is not None else self.attend(x, coords)
        f, logits, attn, uv = a["f"], a["logits"], a["attn"], a["uv"]
        pooled = attn @ f.flatten(2).transpose(1, 2)                       # (B, K, C)
        glob = f.mean((2, 3))[:, None].expand(-1, self.k, -1)             # (B, K, C)
        parts = [pooled, glob, uv]
        if self.context:
            parts.append(context[:, None].expand(-1, self.k, -1))
        out = self.mlp(torch.cat(parts, -1))                               # (B, K, 2 [+ 1] + extra)
        rays = (uv + out[..., :2]) * self.half_fov_tan
        result = {"rays": rays, "extra": out[..., 2 + int(self.has_depth):], "attention": logits,
                  "pooled": pooled.mean(1)}
        if self.has_depth:
            z = torch.exp(self.log_depth + 3 * torch.tanh(out[..., 2] / 3))[..., None]
            result["points"] = torch.cat([z * rays, z], -1)
        return result


class KeypointNeck(nn.Module):
    """Features for the keypoint heads: 1x1 laterals of c2, c3, c4 summed (FPN-style) at
    stride 8, or with ``stride=4`` also c1's lateral, summed at c1's stride 4."""

    def __init__(self, w: int, cout: int, stride: int = 8):
        super().__init__()
        if stride not in KEYPOINT_STRIDES:
            raise ValueError(f"keypoint_stride must be one of {KEYPOINT_STRIDES}, got {stride}")
        self.stride = stride
        self.lateral = nn.ModuleList(conv_bn_relu(c, cout, 1, relu=False) for c in (2 * w, 4 * w, 8 * w))
        if stride == 4:
            self.fine = conv_bn_relu(w, cout, 1, relu=False)

    @property
    def inputs(self) -> int:
        """How many of the trunk's deepest features it reads: 3 (c2..c4), or 4 (c1..c4) at stride 4."""
        return 4 if self.stride == 4 else 3

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        """``feats`` = ``[c1, c2, c3, c4]``; ``[c2, c3, c4]`` is enough at stride 8."""
        if len(feats) < self.inputs:
            names = ", ".join(f"c{i}" for i in range(5 - self.inputs, 5))
            raise ValueError(f"a stride-{self.stride} keypoint neck reads the trunk's [{names}], got {len(feats)} features")
        c2, c3, c4 = feats[-3:]
        if self.stride == 4:
            size = feats[-4].shape[-2:]
            x = self.fine(feats[-4]) + _resize(self.lateral[0](c2), size)
        else:
            size = c2.shape[-2:]
            x = self.lateral[0](c2)
        x = x + _resize(self.lateral[1](c3), size) + _resize(self.lateral[2](c4), size)
        return F.relu(x, inplace=True)
