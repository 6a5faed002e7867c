"""Progressive resizing: the first training steps at a reduced input resolution.

A training step's cost grows with the pixel count, and on a CPU most of it is the trunk's
convolutions: at half the width and height a step of the pipeline's network takes 1.8x
less time on the 2-core reference machine (``benchmarks/bench_low_res.py``,
``results/bench_low_res.json``). The idea (progressive resizing) is that coarse features are
learnt as well from small images, so a run can spend its first steps there, finish at the
full resolution and see more frames in the same wall time.

Off in every profile: in a UR pretraining A/B it did not pay (results/experiments/README.md, "Progressive resizing":
half the input for the first 4,000 of 8,000 steps, against 6,000 full-size steps in about the
same training time, gave a worse joint median and type accuracy).

A stage's ``low_res`` (``params.yaml``; absent or null: off) holds ``scale`` (0 < scale < 1,
the factor on the input's width and height) and ``steps`` (how many of the first training
steps use it). During those steps :func:`downscale_batch` shrinks each batch after loading
and augmentation:

- the image by area averaging (antialiased), the robot mask by area averaging thresholded at
  one half;
- ``intrinsics`` (fx, fy, cx, cy, pixels of the network input) to the smaller image, with
  pixel centres mapping as ``u' + 0.5 = (u + 0.5) * w / W`` (as :meth:`armpose.geometry.Camera.scale_crop`);
- ``image_size`` (width, height) to the smaller size.

The 3D labels (camera optical frame, metres) are unchanged: a resized image is the same view
through a coarser sensor, and the keypoint heads work in normalised image coordinates, so
the geometry carries over. What does not carry over is the convolutions' sense of size in
pixels, from which the network reads depth and robot type: trained on half-size frames, it
is far off at full size until it has trained there again (results/experiments/README.md). Validation and every
later stage run at the full resolution. Which steps are small is a function of the step
number alone, so a resumed run takes the same path as an uninterrupted one. Only for stages
trained from images without a plateau rule or a distillation teacher
(:func:`check_stage_low_res`): the loss jumps when the input grows, and a teacher would read
frames of a size it was never trained on.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F


def check_low_res(cfg) -> dict | None:
    """The stage's ``low_res`` setting as ``{"scale": float, "steps": int}``, or None when off.
    Raises ``ValueError`` naming the bad value otherwise."""
    if not cfg:
        return None
    if not isinstance(cfg, dict) or set(cfg) != {"scale", "steps"}:
        raise ValueError(f"low_res must be null or a mapping with keys 'scale' and 'steps', got {cfg!r}")
    scale, steps = cfg["scale"], cfg["steps"]
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0 < float(scale) < 1:
        raise ValueError(f"low_res.scale must be a number in (0, 1), got {scale!r}")
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
        raise ValueError(f"low_res.steps must be a whole number >= 0, got {steps!r}")
    return {"scale": float(scale), "steps": int(steps)}


def check_stage_low_res(stage: str, cfg: dict, cached: bool) -> dict | None:
    """:func:`check_low_res` of a training stage's ``cfg``, refusing what does not mix with it:
    cached trunk features (no images to shrink), a ``plateau`` rule (the loss jumps when the
    input grows, which could end the run) and a ``distill`` teacher (it would read the shrunk
    images it was not trained on). Errors name the stage and the values."""
    low_res = check_low_res(cfg.get("low_res"))
    if not low_res or not low_res["steps"]:
        return low_res
    clashes = [(what, value) for what, value, present in (
        ("cached trunk features", f"trainable {cfg.get('trainable')}", cached),
        ("a plateau rule", f"plateau {cfg.get('plateau')}", bool(cfg.get("plateau"))),
        ("a distillation teacher", f"distill {cfg.get('distill')}", bool(cfg.get("distill")))) if present]
    if clashes:
        what, value = clashes[0]
        raise ValueError(f"{stage}: low_res {cfg['low_res']} cannot be combined with {what} ({value}); "
                         "low_res is for training from images without a plateau rule or a teacher")
    return low_res


def input_scale(low_res: dict | None, step: int) -> float:
    """The input scale of training step ``step`` (0-based): ``low_res["scale"]`` for the first
    ``low_res["steps"]`` steps, else 1."""
    return low_res["scale"] if low_res and step < low_res["steps"] else 1.0


def scaled_size(height: int, width: int, scale: float) -> tuple[int, int]:
    """``(h, w)`` of an image scaled by ``scale``, rounded, at least one pixel each."""
    return max(1, round(height * scale)), max(1, round(width * scale))


def downscale_batch(batch: dict, scale: float) -> dict:
    """``batch`` (keys of :class:`armpose.data.LabelledFrames`, collated) with ``image``
    (B, 3, H, W), ``mask`` (B, H, W), ``intrinsics`` (B, 4) and ``image_size`` (B, 2) made
    ``scale`` times smaller; every other key as it was. ``scale == 1`` returns ``batch``."""
    if scale == 1.0:
        return batch
    image = batch["image"]
    H, W = image.shape[-2:]
    h, w = scaled_size(H, W, scale)
    sx, sy = w / W, h / H
    out = dict(batch)
    out["image"] = F.interpolate(image, size=(h, w), mode="area")
    out["mask"] = (F.interpolate(batch["mask"][:, None].float(), size=(h, w), mode="area")[:, 0] >= 0.5).to(
        batch["mask"].dtype)
    fx, fy, cx, cy = batch["intrinsics"].unbind(-1)
    out["intrinsics"] = torch.stack([fx * sx, fy * sy, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5], -1)
    if "image_size" in batch:
        out["image_size"] = torch.tensor([w, h], dtype=batch["image_size"].dtype,
                                         device=batch["image_size"].device).expand_as(batch["image_size"]).clone()
    return out
