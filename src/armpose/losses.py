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

Batch keys: ``"mask"`` (B, H, W) {0, 1} float or uint8, ``"joints"`` (B, J, 3),
``"joint_valid"`` (B, J) bool, ``"base"`` (B, 3), ``"robot"`` (B,) int64 class index.
Model output keys: ``"mask_logits"`` (B, 1, H, W), ``"joints"``, ``"base"``, ``"type_logits"``.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

PAPER_WEIGHTS = {"mask": 1.2, "joints": 1.2, "base": 1.2, "type": 0.6}


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


def type_loss(logits: torch.Tensor, robot: torch.Tensor) -> torch.Tensor:
    return F.cross_entropy(logits, robot.long())


def multi_objective_loss(out: dict, batch: dict, weights: dict) -> dict[str, torch.Tensor]:
    """``{"mask", "joints", "base", "type", "total"}``; ``weights`` keys are those of
    :data:`PAPER_WEIGHTS`, missing ones take the paper's values. Asserts the total is finite."""
    unknown = set(weights) - set(PAPER_WEIGHTS)
    if unknown:
        raise ValueError(f"unknown loss weights {sorted(unknown)}; known: {sorted(PAPER_WEIGHTS)}")
    w = {**PAPER_WEIGHTS, **weights}
    losses = {
        "mask": mask_loss(out["mask_logits"], batch["mask"]),
        "joints": joints_loss(out["joints"], batch["joints"], batch["joint_valid"]),
        "base": base_loss(out["base"], batch["base"]),
        "type": type_loss(out["type_logits"], batch["robot"]),
    }
    losses["total"] = sum(float(w[k]) * v for k, v in losses.items())
    assert torch.isfinite(losses["total"]), {k: float(v) for k, v in losses.items()}
    return losses
