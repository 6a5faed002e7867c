"""The four losses of the multi-objective CNN and their weighted sum (paper eq. 1-8).

- mask (eq. 1-4): binary cross-entropy with per-image class weights ``w_fg = 1/P(fg)``,
  ``w_bg = 1/P(bg)``, P from the ground-truth mask (clamped to [1/N, 1 - 1/N] so an
  all-background image stays finite), summed over pixels and divided by the pixel count N,
  then averaged over the batch. Computed from logits for numerical stability.
- joints (eq. 5): mean Euclidean distance over the valid joint slots of an image, then the
  mean over images that have any valid joint. Invalid slots never touch the loss or its
  gradient, even if their labels are NaN.
- base (eq. 6): Euclidean distance, mean over the batch.
- type (eq. 7): categorical cross-entropy.
- total (eq. 8): ``W_mask*mask + W_joints*joints + W_base*base + W_type*type``.
- reproj (ours, not in the paper; weight 0 unless params set it): the mean pixel distance,
  in the network input and in units of 100 px, between the projections of the predicted
  and true joints and base through the frame's intrinsics. It gives the image-plane
  position a gradient of its own, independent of the depth error, which speeds up learning
  where the joints are several-fold on a CPU budget.
- heatmap (ours; weight 0 unless params set it): cross-entropy between each keypoint
  head's spatial softmax and a Gaussian (sigma one cell) at the true projected point, for
  the joints and the base that project inside the image. It teaches the attention maps
  where to look directly instead of through the 3D loss alone.
- offsets (ours; weight 0 unless params set it; lifting models only): mean Euclidean distance
  between the predicted base-relative joint offsets (``"joint_offsets"``) and the true
  ``joints - base``, over valid joints: the metric robot shape that :mod:`armpose.lifting`
  turns into depth.
- direct (ours; weight 0 unless params set it; lifting models only): Euclidean distance of
  the directly regressed base (``"base_direct"``, the lifting solve's prior) from the truth.

Batch keys: ``"mask"`` (B, H, W) {0, 1} float or uint8, ``"joints"`` (B, J, 3),
``"joint_valid"`` (B, J) bool, ``"base"`` (B, 3), ``"robot"`` (B,) int64 class index.
``"intrinsics"`` (B, 4) fx, fy, cx, cy of the network input and ``"image_size"`` (B, 2) its
width and height in pixels (only for ``reproj`` and ``heatmap``). The heatmap term reads the
model outputs ``"joints_attention"`` (B, J, h, w) and ``"base_attention"`` (B, 1, h, w).
Model output keys: ``"mask_logits"`` (B, 1, H, W), ``"joints"``, ``"base"``, ``"type_logits"``.
Without ``"mask_logits"`` (a run whose mask branch is frozen skips it) the mask term is left out.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

PAPER_WEIGHTS = {"mask": 1.2, "joints": 1.2, "base": 1.2, "type": 0.6}
EXTRA_WEIGHTS = {"reproj": 0.0, "heatmap": 0.0, "offsets": 0.0, "direct": 0.0}
HEATMAP_SIGMA_CELLS = 1.0
REPROJ_UNIT_PX = 100.0
TERMS = ("mask", "joints", "base", "type", "reproj", "heatmap", "offsets", "direct")


def mask_loss(logits: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Class-balanced BCE; ``logits`` (B, 1, H, W) or (B, H, W), ``mask`` (B, H, W) in {0, 1}."""
    if logits.dim() == 4:
        logits = logits[:, 0]
    gt = mask.to(logits.dtype)
    n = gt[0].numel()
    p_fg = gt.flatten(1).mean(1).clamp(1.0 / n, 1.0 - 1.0 / n)[:, None, None]    # (B, 1, 1)
    weight = gt / p_fg + (1 - gt) / (1 - p_fg)
    per_pixel = F.binary_cross_entropy_with_logits(logits, gt, weight=weight, reduction="none")
    return per_pixel.flatten(1).mean(1).mean()


def joints_loss(pred: torch.Tensor, gt: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Mean Euclidean distance over valid joints per image, then over images with any valid joint."""
    valid = valid.bool()
    diff = torch.where(valid[..., None], pred - gt, torch.zeros_like(pred))
    dist = torch.linalg.vector_norm(diff, dim=-1) * valid                          # (B, J)
    count = valid.sum(1)
    per_image = dist.sum(1) / count.clamp(min=1)
    has = (count > 0).to(pred.dtype)
    return (per_image * has).sum() / has.sum().clamp(min=1)


def base_loss(pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Mean Euclidean distance between predicted and true base positions."""
    return torch.linalg.vector_norm(pred - gt, dim=-1).mean()


def project(points: torch.Tensor, intrinsics: torch.Tensor) -> torch.Tensor:
    """Pixel coordinates ``(..., 2)`` of camera-frame ``points`` (B, ..., 3), intrinsics (B, 4)."""
    k = intrinsics.reshape(intrinsics.shape[0], *([1] * (points.dim() - 2)), 4)
    z = points[..., 2].clamp(min=1e-3)
    return torch.stack([k[..., 0] * points[..., 0] / z + k[..., 2], k[..., 1] * points[..., 1] / z + k[..., 3]], -1)


def reprojection_loss(pred_joints: torch.Tensor, gt_joints: torch.Tensor, valid: torch.Tensor,
                      pred_base: torch.Tensor, gt_base: torch.Tensor, intrinsics: torch.Tensor) -> torch.Tensor:
    """Mean pixel distance (units of :data:`REPROJ_UNIT_PX`) between projected predicted and
    true points, the base and the valid joints alike, averaged per image then over the batch."""
    pred = torch.cat([pred_joints, pred_base[:, None]], 1)
    gt = torch.cat([gt_joints, gt_base[:, None]], 1)
    ok = torch.cat([valid.bool(), torch.ones_like(valid[:, :1], dtype=torch.bool)], 1)
    gt = torch.where(ok[..., None], gt, torch.ones_like(gt))          # NaN-free invalid slots
    dist = torch.linalg.vector_norm(project(pred, intrinsics) - project(gt, intrinsics), dim=-1) * ok
    return (dist.sum(1) / ok.sum(1)).mean() / REPROJ_UNIT_PX


def heatmap_loss(logits: torch.Tensor, points: torch.Tensor, valid: torch.Tensor, intrinsics: torch.Tensor,
                 image_size: torch.Tensor, sigma_cells: float = HEATMAP_SIGMA_CELLS) -> torch.Tensor:
    """Mean cross-entropy between ``logits`` (B, K, h, w) spatial softmaxes and Gaussians at
    the projections of ``points`` (B, K, 3) (camera frame, metres), over points that are
    ``valid`` and project inside the image. Grid cell centres use the align_corners=False
    convention of :func:`armpose.layers.coord_channels`; pixel centres are OpenCV's."""
    b, k, h, w = logits.shape
    pts = torch.where(valid[..., None], points, torch.ones_like(points))
    uv = project(pts, intrinsics)                                            # (B, K, 2) pixels
    size = image_size.to(uv.dtype)[:, None, :]                              # (B, 1, 2) W, H
    norm = (2 * uv + 1) / size - 1                                          # [-1, 1] at the borders
    inside = valid & (norm.abs() <= 1).all(-1) & (points[..., 2] > 0)
    ys = (torch.arange(h, device=logits.device, dtype=uv.dtype) * 2 + 1) / h - 1
    xs = (torch.arange(w, device=logits.device, dtype=uv.dtype) * 2 + 1) / w - 1
    gx = torch.exp(-0.5 * ((xs - norm[..., :1]) * w / (2 * sigma_cells)) ** 2)      # (B, K, w)
    gy = torch.exp(-0.5 * ((ys - norm[..., 1:]) * h / (2 * sigma_cells)) ** 2)      # (B, K, h)
    target = (gy[..., :, None] * gx[..., None, :]).flatten(2)
    target = target / target.sum(-1, keepdim=True).clamp(min=1e-12)
    ce = -(target * logits.flatten(2).float().log_softmax(-1)).sum(-1)        # (B, K)
    return (ce * inside).sum() / inside.sum().clamp(min=1)


def type_loss(logits: torch.Tensor, robot: torch.Tensor) -> torch.Tensor:
    return F.cross_entropy(logits, robot.long())


def multi_objective_loss(out: dict, batch: dict, weights: dict) -> dict[str, torch.Tensor]:
    """``{"mask", "joints", "base", "type", ["reproj", "heatmap",] "total"}``; ``weights`` keys are those
    of :data:`PAPER_WEIGHTS` (missing ones take the paper's values) and :data:`EXTRA_WEIGHTS`
    (missing: 0, term not computed). Asserts the total is finite."""
    known = {**PAPER_WEIGHTS, **EXTRA_WEIGHTS}
    unknown = set(weights) - set(known)
    if unknown:
        raise ValueError(f"unknown loss weights {sorted(unknown)}; known: {sorted(known)}")
    w = {**known, **weights}
    losses = {}
    if "mask_logits" in out:
        losses["mask"] = mask_loss(out["mask_logits"], batch["mask"])
    losses["joints"] = joints_loss(out["joints"], batch["joints"], batch["joint_valid"])
    losses["base"] = base_loss(out["base"], batch["base"])
    losses["type"] = type_loss(out["type_logits"], batch["robot"])
    if float(w["reproj"]) > 0:
        losses["reproj"] = reprojection_loss(out["joints"], batch["joints"], batch["joint_valid"],
                                             out["base"], batch["base"], batch["intrinsics"])
    if float(w["heatmap"]) > 0:
        logits = torch.cat([out["joints_attention"], out["base_attention"]], 1)
        points = torch.cat([batch["joints"], batch["base"][:, None]], 1)
        valid = torch.cat([batch["joint_valid"].bool(), torch.ones_like(batch["joint_valid"][:, :1], dtype=torch.bool)], 1)
        losses["heatmap"] = heatmap_loss(logits, points, valid, batch["intrinsics"], batch["image_size"])
    for term, key in (("offsets", "joint_offsets"), ("direct", "base_direct")):
        if float(w[term]) > 0 and key not in out:
            raise ValueError(f"loss weight {term}={w[term]} needs the model output {key!r}: "
                             f"set base.model.lift: true or the weight to 0")
    if float(w["offsets"]) > 0:
        losses["offsets"] = joints_loss(out["joint_offsets"], batch["joints"] - batch["base"][:, None],
                                        batch["joint_valid"])
    if float(w["direct"]) > 0:
        losses["direct"] = base_loss(out["base_direct"], batch["base"])
    losses["total"] = sum(float(w[k]) * v for k, v in losses.items())
    assert torch.isfinite(losses["total"]), {k: float(v) for k, v in losses.items()}
    return losses
