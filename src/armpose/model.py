"""The multi-objective CNN: robot mask, 3D joints, 3D base and robot type from one RGB image.

Input: ``(B, 3, H, W)`` float RGB in [0, 1]; the pipeline uses H=212, W=256 but any size works.
Output, a dict:

- ``"mask_logits"`` ``(B, 1, H, W)``: per-pixel robot logits; :func:`predicted_mask`
  turns them into the mask (see "Mask decision" below);
- ``"joints"`` ``(B, max_joints, 3)``: joint positions in metres, camera optical frame
  (x right, y down, z forward); a robot with fewer joints uses the first slots;
- ``"base"`` ``(B, 3)``: robot base position, same frame;
- ``"type_logits"`` ``(B, num_types)``.

Architecture (``width`` = w, 32 by default; strides relative to the input)::

    image -> (x - 0.5) / 0.25
    trunk.early   stem 3x3/2 (w/2), 3x3/2 (w), residual separable 3x3   c1  stride 4,  w
                  BasicBlock/2                                          c2  stride 8,  2w
    trunk.late    BasicBlock/2 + BasicBlock                             c3  stride 16, 4w
                  BasicBlock/2                                          c4  stride 32, 8w
    mask_decoder  FPN: 1x1 laterals of c1..c4 to w channels, top-down bilinear upsample + add,
                  separable 3x3 at stride 4, 1x1 to one logit, bilinear upsample to (H, W)
    heads.neck    1x1 laterals of c2, c3, c4 to 2w channels, summed at stride 8, + x/y CoordConv
                  (``keypoint_stride: 4``: c1's lateral too, summed at stride 4)
      .joints     KeypointHead(K=max_joints)  \
      .base       KeypointHead(K=1)            } read trunk features only, never the decoder
      .robot_type [avg+max pool of c4, joint-attention-pooled features] -> MLP -> num_types logits

Every conv is conv-BN(-ReLU); BasicBlock is ResNet's (two 3x3, projection shortcut when the
shape changes); "/2" is stride 2. At w=32: about 0.3 GMAC per 212x256 frame, 1.9 M parameters.
Run it in ``channels_last`` memory format on CPU: faster at batch 1 (1.1-3x in our runs).

The keypoint heads (:mod:`armpose.keypoints`) give each point an image ray from a spatial
softmax and a depth from a small per-point MLP.

Lifting (``lift: true`` in the model config). Regressing each joint's depth directly leaves
a depth error common to the whole robot (8 % median on our renders, against 6 cm of joint
error along the right rays). With ``lift`` the joints head gives, instead of a depth, each
joint's offset from the base in metres (camera axes) and a confidence per point, and
:func:`armpose.lifting.solve_base` places the base where the offsets best meet the rays of
the joints and the base (weighted least squares, the base head's direct estimate as a weak
prior): the depth follows from the robot's apparent size. ``joints = base + offsets``.

Mask decision. The mask loss (paper eq. 1-3) weights each class by its inverse frequency, so
the trained logit estimates ``log(P(fg)/P(bg)) + log(w_fg/w_bg)``: thresholding it at 0 calls
a pixel robot whenever P(robot) is above the robot's share of the image (about 5 %), which
costs pixel accuracy. :func:`predicted_mask` thresholds at the buffer
``mask_decoder.threshold`` instead, ``log((1 - pi) / pi)`` with ``pi`` the mean foreground fraction of
the training frames (set by :func:`armpose.train.train` whenever the mask decoder trains):
the Bayes decision for pixel accuracy. The loss is untouched.

Trainable groups, for two-stage transfer learning (``params.yaml`` names them):
``GROUPS = ("trunk.early", "trunk.late", "mask_decoder", "heads")``; a dotted sub-path of a
group (``"heads.joints"``) is also accepted. :func:`set_trainable` freezes the rest, and a
frozen group's BatchNorm layers stay in eval mode (running statistics untouched) even
after ``model.train()``.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from armpose.keypoints import DEFAULT_DEPTH, DEFAULT_HALF_FOV_TAN, KeypointHead, KeypointNeck
from armpose.layers import conv_bn_relu, coord_channels, resize as _resize, separable
from armpose.lifting import solve_base

GROUPS: tuple[str, ...] = ("trunk.early", "trunk.late", "mask_decoder", "heads")


class SeparableBlock(nn.Module):
    """Residual block of one separable 3x3 conv: cheap at high resolution."""

    def __init__(self, c: int):
        super().__init__()
        self.conv = separable(c, c, relu=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.conv(x) + x, inplace=True)


class BasicBlock(nn.Module):
    """ResNet basic block: two 3x3 conv-BN, identity or 1x1 projection shortcut, ReLU."""

    def __init__(self, cin: int, cout: int, stride: int = 1):
        super().__init__()
        self.conv1 = conv_bn_relu(cin, cout, 3, stride)
        self.conv2 = conv_bn_relu(cout, cout, 3, 1, relu=False)
        self.shortcut = (nn.Identity() if stride == 1 and cin == cout
                         else conv_bn_relu(cin, cout, 1, stride, relu=False))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.conv2(self.conv1(x)) + self.shortcut(x), inplace=True)


class TrunkEarly(nn.Module):
    """Generic low-level features: c1 (stride 4) and c2 (stride 8)."""

    def __init__(self, w: int):
        super().__init__()
        self.stem = nn.Sequential(conv_bn_relu(3, w // 2, 3, 2), conv_bn_relu(w // 2, w, 3, 2))
        self.stage1 = SeparableBlock(w)
        self.stage2 = BasicBlock(w, 2 * w, 2)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        c1 = self.stage1(self.stem(x))
        return c1, self.stage2(c1)


class TrunkLate(nn.Module):
    """Object-level features: c3 (stride 16) and c4 (stride 32)."""

    def __init__(self, w: int):
        super().__init__()
        self.stage3 = nn.Sequential(BasicBlock(2 * w, 4 * w, 2), BasicBlock(4 * w, 4 * w))
        self.stage4 = BasicBlock(4 * w, 8 * w, 2)

    def forward(self, c2: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        c3 = self.stage3(c2)
        return c3, self.stage4(c3)


class Trunk(nn.Module):
    def __init__(self, w: int):
        super().__init__()
        self.early = TrunkEarly(w)
        self.late = TrunkLate(w)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        c1, c2 = self.early(x)
        c3, c4 = self.late(c2)
        return [c1, c2, c3, c4]


class MaskDecoder(nn.Module):
    """Light FPN: laterals to ``w`` channels, top-down sum, one 3x3 conv at stride 4, one logit.

    The buffer ``threshold`` is the logit above which a pixel is called robot (see the module
    docstring); it belongs to this group, so it changes only in a stage where the decoder trains.
    """

    def __init__(self, w: int):
        super().__init__()
        self.lateral = nn.ModuleList(conv_bn_relu(c, w, 1) for c in (w, 2 * w, 4 * w, 8 * w))
        self.smooth = separable(w, w)
        self.predict = nn.Conv2d(w, 1, 1)
        self.register_buffer("threshold", torch.zeros(()))

    def forward(self, feats: list[torch.Tensor], size) -> torch.Tensor:
        p = self.lateral[3](feats[3])
        for i in (2, 1, 0):
            lat = self.lateral[i](feats[i])
            p = lat + _resize(p, lat.shape[-2:])
        return _resize(self.predict(self.smooth(p)), size)


class TypeHead(nn.Module):
    """Robot type from global c4 statistics (avg + max) and robot-centred keypoint features."""

    def __init__(self, cin: int, hidden: int, num_types: int, cin_points: int = 0):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(2 * cin + cin_points, hidden), nn.ReLU(inplace=True),
                                 nn.Linear(hidden, num_types))

    def forward(self, c4: torch.Tensor, points: torch.Tensor | None = None) -> torch.Tensor:
        parts = [c4.mean((2, 3)), c4.amax((2, 3))] + ([points] if points is not None else [])
        return self.mlp(torch.cat(parts, 1))


class Heads(nn.Module):
    """The regression and classification branches; they read trunk features only.

    Outputs ``joints``, ``base``, ``type_logits`` and the keypoint heads' attention logits
    ``joints_attention`` (B, K, H/s, W/s) and ``base_attention`` (B, 1, H/s, W/s), with s the
    keypoint stride (8, or 4), which a heatmap loss can supervise (:func:`armpose.losses.heatmap_loss`).

    With ``lift`` the joints head also gives each joint's offset from the base (metres,
    camera axes) and every point a confidence; :func:`armpose.lifting.solve_base` puts the
    base where those offsets best meet the joints' image rays, and ``joints = base +
    offsets``. The directly regressed base is the solve's weak prior. Extra outputs:
    ``joint_offsets`` (B, K, 3), ``base_direct`` (B, 3) and ``point_weights`` (B, K + 1)."""

    def __init__(self, w: int, num_types: int, max_joints: int, half_fov_tan, depth: float,
                 lift: bool = False, lift_prior: float = 0.05, keypoint_stride: int = 8,
                 skeleton_context: bool = False):
        super().__init__()
        self.lift, self.lift_prior, self.skeleton_context = lift, lift_prior, skeleton_context
        context = 2 * max_joints if skeleton_context else 0
        self.neck = KeypointNeck(w, 2 * w, keypoint_stride)
        self.joints = KeypointHead(2 * w + 2, max_joints, 2 * w, half_fov_tan, None if lift else depth,
                                   extra=4 if lift else 0, context=context)
        self.base = KeypointHead(2 * w + 2, 1, w, half_fov_tan, depth, extra=1 if lift else 0, context=context)
        self.robot_type = TypeHead(8 * w, 4 * w, num_types, cin_points=2 * w)

    def forward(self, feats: list[torch.Tensor]) -> dict[str, torch.Tensor]:
        c4 = feats[-1]
        x = self.neck(feats)
        coords = coord_channels(x)
        x = torch.cat([x, coords.expand(x.shape[0], -1, -1, -1)], 1)
        attended = self.joints.attend(x, coords)
        context = attended["uv"].flatten(1) if self.skeleton_context else None   # (B, 2K) the 2D skeleton
        joints = self.joints(x, coords, context, attended)
        base = self.base(x, coords, context)
        out = {"base": base["points"][:, 0], "type_logits": self.robot_type(c4, joints["pooled"]),
               "joints_attention": joints["attention"], "base_attention": base["attention"]}
        if not self.lift:
            out["joints"] = joints["points"]
            return out
        offsets = joints["extra"][..., :3]
        rays = torch.cat([joints["rays"], base["rays"]], 1)
        weights = torch.sigmoid(torch.cat([joints["extra"][..., 3], base["extra"][..., 0]], 1))
        padded = torch.cat([offsets, torch.zeros_like(offsets[:, :1])], 1)
        solved = solve_base(rays, padded, weights, out["base"], self.lift_prior)
        out.update(joints=solved[:, None] + offsets, base=solved, joint_offsets=offsets,
                   base_direct=out["base"], point_weights=weights)
        return out


class ArmPoseNet(nn.Module):
    """See the module docstring. ``width`` scales every channel count."""

    def __init__(self, num_types: int = 5, max_joints: int = 7, width: int = 32,
                 half_fov_tan=DEFAULT_HALF_FOV_TAN, depth: float = DEFAULT_DEPTH, lift: bool = False,
                 lift_prior: float = 0.05, keypoint_stride: int = 8, skeleton_context: bool = False):
        super().__init__()
        if width < 2 or width % 2:
            raise ValueError(f"width must be an even number >= 2, got {width}")
        self.config = {"num_types": num_types, "max_joints": max_joints, "width": width,
                       "half_fov_tan": [float(t) for t in half_fov_tan], "depth": float(depth),
                       "lift": bool(lift), "lift_prior": float(lift_prior),
                       "keypoint_stride": int(keypoint_stride), "skeleton_context": bool(skeleton_context)}
        self.trunk = Trunk(width)
        self.mask_decoder = MaskDecoder(width)
        self.heads = Heads(width, num_types, max_joints, half_fov_tan, depth, lift, lift_prior, keypoint_stride,
                           skeleton_context)

    def forward(self, image: torch.Tensor | None = None, *,
                features: list[torch.Tensor] | None = None) -> dict[str, torch.Tensor]:
        """Every output from ``image``; or, given the trunk's ``features`` ``[c1, c2, c3, c4]``
        (or just ``[c2, c3, c4]``) instead, the heads' outputs only (no mask). The
        second form is how a run whose trunk is frozen trains on cached features."""
        if features is not None:
            return self._heads(features)
        feats = self.trunk(normalise(image))
        out = self._heads(feats)
        out["mask_logits"] = self.mask_decoder(feats, image.shape[-2:])
        return out

    def _heads(self, feats: list[torch.Tensor]) -> dict[str, torch.Tensor]:
        """The heads in float32 always, also under a bfloat16 autocast of the trunk."""
        with torch.autocast(feats[-1].device.type, enabled=False):
            return self.heads([f.float() for f in feats])

    @property
    def mask_threshold(self) -> torch.Tensor:
        """The mask decision logit, ``mask_decoder.threshold`` (0 until :meth:`set_mask_prior`)."""
        return self.mask_decoder.threshold

    def set_mask_prior(self, foreground_fraction: float) -> None:
        """Set ``mask_threshold`` to ``log((1 - pi) / pi)`` for training-set foreground share ``pi``."""
        pi = min(max(float(foreground_fraction), 1e-4), 1 - 1e-4)
        self.mask_decoder.threshold.fill_(math.log((1 - pi) / pi))

    @torch.no_grad()
    def trunk_features(self, image: torch.Tensor) -> list[torch.Tensor]:
        """The trunk's features that the heads read, for ``image``, without gradients:
        ``[c2, c3, c4]``, with c1 first for a stride-4 keypoint neck."""
        feats = self.trunk(normalise(image))
        return feats[-self.heads.neck.inputs:]

    def train(self, mode: bool = True) -> "ArmPoseNet":
        super().train(mode)
        apply_freeze_mode(self)
        return self


def predicted_mask(model: nn.Module, mask_logits: torch.Tensor) -> torch.Tensor:
    """Boolean robot mask from ``mask_logits`` by ``model``'s decision threshold (its
    ``mask_threshold`` buffer; 0 for a module without one, e.g. a test oracle)."""
    threshold = getattr(model, "mask_threshold", None)
    return mask_logits > (0.0 if threshold is None else threshold.to(mask_logits.dtype))


def normalise(image: torch.Tensor) -> torch.Tensor:
    """RGB in [0, 1] to the network's input scale, about zero mean and unit spread."""
    return (image - 0.5) / 0.25


def build_model(cfg: dict | None = None) -> ArmPoseNet:
    """An :class:`ArmPoseNet` from a plain config dict; missing keys take the defaults."""
    cfg = dict(cfg or {})
    known = {"num_types", "max_joints", "width", "half_fov_tan", "depth", "lift", "lift_prior", "keypoint_stride",
             "skeleton_context"}
    unknown = set(cfg) - known
    if unknown:
        raise ValueError(f"unknown model config keys {sorted(unknown)}; known: {sorted(known)}")
    return ArmPoseNet(**cfg)


def _check_group(group: str) -> None:
    if not any(group == g or group.startswith(g + ".") for g in GROUPS):
        raise KeyError(f"unknown layer group {group!r}; groups are {GROUPS} or a dotted sub-path of one")


def group_modules(model: nn.Module, group: str) -> nn.Module:
    """The submodule holding ``group`` (one of :data:`GROUPS`, or a dotted sub-path of one)."""
    _check_group(group)
    return model.get_submodule(group)


def group_parameters(model: nn.Module, group: str) -> list[nn.Parameter]:
    return list(group_modules(model, group).parameters())


def set_trainable(model: nn.Module, groups: list[str]) -> None:
    """``requires_grad`` True for the parameters of ``groups`` only; frozen BatchNorm to eval mode."""
    for p in model.parameters():
        p.requires_grad_(False)
    for g in groups:
        for p in group_parameters(model, g):
            p.requires_grad_(True)
    apply_freeze_mode(model)


def apply_freeze_mode(model: nn.Module) -> None:
    """Put every BatchNorm whose parameters are all frozen in eval mode, so its running
    statistics stay fixed. :meth:`ArmPoseNet.train` calls this; call it after ``train()``
    on any other wrapper."""
    for m in model.modules():
        if isinstance(m, nn.modules.batchnorm._BatchNorm) and m.training:
            params = list(m.parameters())
            if params and not any(p.requires_grad for p in params):
                m.eval()


def count_parameters(model: nn.Module, group: str | None = None) -> int:
    params = model.parameters() if group is None else group_parameters(model, group)
    return sum(p.numel() for p in params)
