"""Mirror test: the network's outputs for an image and for its horizontal mirror, mapped back and averaged.

The training stages mirror their images (``augment.flip``), so the network knows mirrored
robots, and its errors on an image and on the image's mirror are partly independent: their
mean is a better estimate, for one more forward pass (both images go through as one batch).
This is the "flip test" of human-pose estimation. ``armpose predict --mirror`` uses it, and the
``evaluate`` stage reports it next to the single pass (``evaluate.mirror_test``).

Mapping back, for a network camera with focal length ``fx`` and principal point column ``cx``
(pixels) and an image ``width`` pixels wide, whose mirror takes pixel column ``u`` to
``width - 1 - u``:

- a point ``(x', y, z)`` predicted on the mirror (metres, camera optical frame: x right,
  y down, z forward) sits on column ``u' = fx x' / z + cx``; the same point in the original
  image is on column ``width - 1 - u'`` at the same height and depth, so
  ``x = (width - 1 - 2 cx) z / fx - x'`` (``-x'`` when the principal point is centred);
- mask logits are mirrored back column by column;
- type probabilities are averaged; ``type_logits`` of the result are their logarithms.

Joints and base are the mean of the two estimates, mask logits the mean of the two maps.
"""
from __future__ import annotations

import torch
from torch import nn

OUTPUT_KEYS = ("joints", "base", "type_logits", "mask_logits")


def _per_frame(value, like: torch.Tensor) -> torch.Tensor:
    """``value`` (a number or one per frame, shape (B,)) shaped to broadcast over ``like`` (B, ...)."""
    v = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    return v.reshape(v.shape + (1,) * (like.dim() - v.dim())) if v.dim() else v


def unmirror_points(points: torch.Tensor, fx, cx, width: int) -> torch.Tensor:
    """Points ``(B, ..., 3)`` predicted on mirrored images, in the frames of the original images.

    ``fx`` and ``cx`` (pixels) are numbers or one per frame; ``width`` is the image width in pixels."""
    z = points[..., 2]
    x = (width - 1 - 2 * _per_frame(cx, z)) * z / _per_frame(fx, z) - points[..., 0]
    return torch.stack([x, points[..., 1], z], -1)


def mirror_average(single: dict, mirrored: dict, fx, cx, width: int) -> dict:
    """The mean of ``single`` (outputs on the images) and ``mirrored`` (outputs on their mirrors),
    both dicts with :data:`OUTPUT_KEYS` (``mask_logits`` optional)."""
    probs = (single["type_logits"].float().softmax(-1) + mirrored["type_logits"].float().softmax(-1)) / 2
    out = {"joints": (single["joints"] + unmirror_points(mirrored["joints"], fx, cx, width)) / 2,
           "base": (single["base"] + unmirror_points(mirrored["base"], fx, cx, width)) / 2,
           "type_logits": probs.clamp(min=1e-12).log()}
    if "mask_logits" in single:
        out["mask_logits"] = (single["mask_logits"] + mirrored["mask_logits"].flip(-1)) / 2
    return out


def forward_with_mirror(model, images: torch.Tensor, fx, cx) -> tuple[dict, dict]:
    """``(single, averaged)``: the model's outputs on ``images`` (B, 3, H, W) and the mirror-test
    average, from one forward pass over the batch of the images and their mirrors (2B frames).
    ``fx``, ``cx``: the network camera's focal length and principal point column, in pixels of ``images``."""
    b, width = images.shape[0], images.shape[-1]
    both = torch.cat([images, images.flip(-1)]).contiguous(memory_format=torch.channels_last)
    out = model(both)
    single = {k: out[k][:b] for k in OUTPUT_KEYS if k in out}
    mirrored = {k: out[k][b:] for k in OUTPUT_KEYS if k in out}
    return single, mirror_average(single, mirrored, fx, cx, width)


class MirrorAveraged(nn.Module):
    """``model`` whose every forward pass is the mirror-test average (:func:`forward_with_mirror`),
    for a network camera with focal length ``fx`` and principal point column ``cx`` (pixels of the
    network input; numbers, or one per frame of the batches it will see). Hand it to the zoom test
    in place of the model, and both of its looks are mirror-averaged, as ``armpose predict
    --mirror --zoom`` does. Its ``mask_threshold`` is the model's."""

    def __init__(self, model: nn.Module, fx, cx):
        super().__init__()
        self.model, self.fx, self.cx = model, fx, cx
        self.mask_threshold = getattr(model, "mask_threshold", None)

    def forward(self, images: torch.Tensor) -> dict:
        return forward_with_mirror(self.model, images, self.fx, self.cx)[1]
