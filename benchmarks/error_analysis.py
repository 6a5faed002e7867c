"""Where the transfer model's errors come from, on the test split: two diagnostics.

    python benchmarks/error_analysis.py [--checkpoint models/transfer_stage2/model.pt]

1. **Type and depth.** Per robot type, the frames typed right and those typed wrong, with their
   median joint error (cm) and the signed and absolute median of the frame depth ratio (the
   median over a frame's valid joints of predicted over true depth, minus one, in %). A UR5
   taken for a UR10 should also be placed further away: the robot's apparent size ties type and
   distance together.
2. **Mask errors.** Per robot family, the share of test pixels that are false positives and
   false negatives, the share of the wrong pixels that lie within 1 and within 3 px of the true
   mask's outline on either side (boundary errors, against whole missed or invented regions;
   :func:`near_outline`), the share of all pixels in those bands (the base rate: thick links
   have a longer outline), and the pixel
   accuracy if each image were thresholded at ``log((1 - p) / p)`` with ``p`` the robot share of
   its own first-pass mask instead of the training set's share (``armpose.model.predicted_mask``).

Pixels are those of the 256x212 network input. Writes ``results/error_analysis.json`` (atomically)
and prints it.
"""
from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import torch

from armpose.config import project_root
from armpose.data import LabelledFrames, split_indices
from armpose.evaluate import family_of, predict_split
from armpose.inference import load_inference_model
from armpose.io import atomic_write_json
from armpose.labels.dataset import load_dataset
from armpose.metrics import frame_depth_ratio
from armpose.model import predicted_mask


def type_and_depth(pred: dict, truth: dict, robot_types: list[str]) -> dict:
    """Per true robot type and outcome ("right", "wrong"): frames, joint median (cm), signed
    and absolute median frame depth error (%)."""
    ratio = frame_depth_ratio(pred["joints"], truth["joints"], truth["joint_valid"])
    err = np.linalg.norm(pred["joints"] - truth["joints"], axis=-1)
    out = {}
    for t, name in enumerate(robot_types):
        of_type = truth["type"] == t
        for outcome, rows in (("right", of_type & (pred["type"] == t)), ("wrong", of_type & (pred["type"] != t))):
            if not rows.any():
                continue
            d = ratio[rows] - 1
            out.setdefault(name, {})[outcome] = {
                "frames": int(rows.sum()),
                "joint_median_cm": round(100 * float(np.median(err[rows][truth["joint_valid"][rows]])), 2),
                "frame_depth_error_signed_median_pct": round(100 * float(np.nanmedian(d)), 2),
                "frame_depth_error_abs_median_pct": round(100 * float(np.nanmedian(np.abs(d))), 2)}
    return out


def near_outline(mask: np.ndarray, radius: int) -> np.ndarray:
    """Pixels of boolean ``mask`` (H, W) at most ``radius`` px (Euclidean) from the nearest
    pixel of the other class, on either side of the outline: ``radius=1`` is the ring of
    pixels that touch the other class (4-neighbours), one pixel deep on each side."""
    m = mask.astype(np.uint8)
    inside = cv2.distanceTransform(m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)       # fg: distance to background
    outside = cv2.distanceTransform(1 - m, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)  # bg: distance to foreground
    return np.where(mask, inside, outside) <= radius


@torch.no_grad()
def mask_errors(model, data_dir: Path, rows: np.ndarray, batch_size: int = 32) -> dict:
    """Counts over ``rows``: pixels, false positives and negatives, wrong pixels near the
    outline (1 and 3 px) and all pixels there, wrong pixels under the per-image threshold
    (the first-pass robot share is clipped to [0.001, 0.5] so the threshold stays finite and
    never calls most of an image robot)."""
    frames = LabelledFrames(data_dir, rows)
    c = dict.fromkeys(("pixels", "fp", "fn", "near1", "near3", "band1", "band3", "adaptive_wrong"), 0)
    for start in range(0, len(frames), batch_size):
        items = [frames[i] for i in range(start, min(start + batch_size, len(frames)))]
        logits = model(torch.stack([it["image"] for it in items]).contiguous(memory_format=torch.channels_last))[
            "mask_logits"][:, 0]
        pred = predicted_mask(model, logits).numpy()
        p = np.clip(pred.mean((1, 2)), 1e-3, 0.5)
        adaptive = logits.numpy() > np.log((1 - p) / p)[:, None, None]
        for it, pm, am in zip(items, pred, adaptive):
            gt = it["mask"].numpy() > 0.5
            wrong = pm != gt
            c["pixels"] += gt.size
            c["fp"] += int((pm & ~gt).sum())
            c["fn"] += int((~pm & gt).sum())
            for r in (1, 3):
                band = near_outline(gt, r)
                c[f"near{r}"] += int((wrong & band).sum())
                c[f"band{r}"] += int(band.sum())
            c["adaptive_wrong"] += int((am != gt).sum())
    return c


def mask_summary(c: dict) -> dict:
    wrong = c["fp"] + c["fn"]
    return {"pixel_accuracy_pct": round(100 * (1 - wrong / c["pixels"]), 2),
            "false_positive_pct": round(100 * c["fp"] / c["pixels"], 2),
            "false_negative_pct": round(100 * c["fn"] / c["pixels"], 2),
            "wrong_within_1px_of_outline_pct": round(100 * c["near1"] / max(wrong, 1), 1),
            "wrong_within_3px_of_outline_pct": round(100 * c["near3"] / max(wrong, 1), 1),
            "pixels_within_1px_of_outline_pct": round(100 * c["band1"] / c["pixels"], 2),
            "pixels_within_3px_of_outline_pct": round(100 * c["band3"] / c["pixels"], 2),
            "per_image_threshold_accuracy_pct": round(100 * (1 - c["adaptive_wrong"] / c["pixels"]), 2)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", default="models/transfer_stage2/model.pt")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(project_root() / "results" / "error_analysis.json"))
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    root = project_root()
    data_dir = root / "data" / "labels"
    model, _ = load_inference_model(root / args.checkpoint)
    arrays, index = load_dataset(data_dir)
    robot_types = list(index["robot_types"])
    pred, truth = predict_split(model, data_dir, "test")
    rows = split_indices(arrays, "test")
    robot = np.asarray(arrays["robot"][rows])
    families = family_of(robot_types)
    masks = {}
    for family in dict.fromkeys(families):
        classes = [i for i, f in enumerate(families) if f == family]
        masks[family] = mask_summary(mask_errors(model, data_dir, rows[np.isin(robot, classes)]))
    digest = hashlib.sha256((root / args.checkpoint).read_bytes()).hexdigest()[:16]
    out = {"checkpoint": args.checkpoint, "checkpoint_sha256_16": digest, "split": "test", "type_and_depth": type_and_depth(pred, truth, robot_types),
           "mask_errors": masks, "command": f"python benchmarks/error_analysis.py --checkpoint {args.checkpoint}"}
    atomic_write_json(Path(args.out), out)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
