"""Does the predicted skeleton clean up the predicted mask? A post-hoc check.

    python benchmarks/mask_band.py [CHECKPOINT] [--out results/mask_band.json] [--threads 2]

KUKA's mask accuracy is held down by one dim handheld recording (``iiwa_s01``) whose table the
network takes for robot. A robot's pixels lie near its bones; a table's mostly do not. This check
takes the zoom test's mask (:mod:`armpose.zoom_test`) and keeps only

* ``band``: the pixels within ``radius`` metres (at the skeleton's mean depth, through the
  network-input focal length) of the zoom test's 2D skeleton: the base and the joints of the
  predicted type, joined in chain order;
* ``components``: the whole connected components of the mask that touch that band.

``radius`` is chosen without the test split: on the held-out training frames of
``benchmarks/ray_bone_fit.py`` (200 per robot type, outside both transfer sets), the value with
the highest mean mask accuracy over the families, per variant (the variant itself is reported,
not chosen). Per family, and on the test split per source (synthetic / recorded): mask accuracy
and IoU, without and with each variant at each radius. Written to ``--out`` as JSON (atomically).
"""
from __future__ import annotations

import json

import cv2
import numpy as np
import torch

from armpose.config import load_params
from armpose.data import LabelledFrames, split_indices
from armpose.evaluate import family_of
from armpose.io import atomic_write_json
from armpose.labels.dataset import SOURCE_CODES
from armpose.metrics import mask_counts
from armpose.model import predicted_mask
from armpose.robots import get_robot
from armpose.zoom_test import forward_with_zoom, settings_from_config

from checkpoint_cli import load_checkpoint_from_cli
from ray_bone_fit import held_out_rows

RADII_M = (0.1, 0.15, 0.2, 0.3, 0.45)


def skeleton_band(joints: np.ndarray, base: np.ndarray, count: int, camera: np.ndarray, shape: tuple[int, int],
                  radius_m: float) -> np.ndarray:
    """Bool (H, W): pixels within ``radius_m`` metres (at the points' mean depth) of the polyline
    base -> joint 1 -> ... -> joint ``count``; points metres, camera frame; ``camera`` (fx, fy, cx, cy)."""
    pts = np.concatenate([base[None], joints[:count]]).astype(np.float64)
    z = np.clip(pts[:, 2], 0.05, None)
    uv = np.stack([camera[0] * pts[:, 0] / z + camera[2], camera[1] * pts[:, 1] / z + camera[3]], -1)
    r = max(1, int(round(camera[0] * radius_m / float(z.mean()))))
    canvas = np.zeros(shape, np.uint8)
    uv = np.clip(np.round(uv), -4 * max(shape), 4 * max(shape)).astype(np.int32)
    for a, b in zip(uv[:-1], uv[1:]):
        cv2.line(canvas, tuple(map(int, a)), tuple(map(int, b)), 1, thickness=2 * r + 1)
    return canvas.astype(bool)


def touching_components(mask: np.ndarray, band: np.ndarray) -> np.ndarray:
    """The connected components (8-connected) of ``mask`` that share a pixel with ``band``."""
    n, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[np.unique(labels[band & mask])] = True
    keep[0] = False
    return keep[labels]


def collect(model, config: dict, frames: LabelledFrames, batch: int = 32) -> dict:
    """Per frame (N, 4) mask counts of the zoom test's mask, raw and under each variant and radius."""
    counts_of = [get_robot(t).num_joints for t in frames.robot_types]
    settings = settings_from_config(config)
    out = {"none": []} | {f"{v}@{r}": [] for v in ("band", "components") for r in RADII_M}
    with torch.no_grad():
        for start in range(0, len(frames), batch):
            items = [frames[i] for i in range(start, min(start + batch, len(frames)))]
            x = torch.stack([it["image"] for it in items]).contiguous(memory_format=torch.channels_last)
            cams = torch.stack([it["intrinsics"] for it in items])
            truth = torch.stack([it["mask"] for it in items]).numpy() > 0.5
            _, zoomed = forward_with_zoom(model, x, cams, settings, counts_of)
            masks = predicted_mask(model, zoomed["mask_logits"][:, 0]).numpy()
            out["none"].append(mask_counts(masks, truth))
            types = zoomed["type_logits"].argmax(-1).numpy()
            joints, base = zoomed["joints"].float().numpy(), zoomed["base"].float().numpy()
            for r in RADII_M:
                bands = np.stack([skeleton_band(joints[i], base[i], counts_of[types[i]], cams[i].numpy(),
                                                masks.shape[1:], r) for i in range(len(items))])
                out[f"band@{r}"].append(mask_counts(masks & bands, truth))
                comps = np.stack([touching_components(masks[i], bands[i]) for i in range(len(items))])
                out[f"components@{r}"].append(mask_counts(comps, truth))
    return {k: np.concatenate(v) for k, v in out.items()}


def scores(counts: np.ndarray, groups: np.ndarray) -> dict:
    """Mask accuracy and IoU (pooled over pixels, like ``evaluate``'s) per group label."""
    out = {}
    for g in dict.fromkeys(groups.tolist()):
        c = counts[groups == g].sum(0)
        out[g] = {"mask_accuracy": round(float(c[0] / c[3]), 4), "mask_iou": round(float(c[1] / max(c[2], 1)), 4)}
    return out


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir = root / "data" / "labels"
    params = load_params(root / "params.yaml")
    families = np.asarray(family_of(list(params["base"]["robot_types"])))
    result = {"checkpoint": str(args.checkpoint), "radii_m": list(RADII_M)}
    for name, rows in (("held_out", held_out_rows(data_dir, params)), ("test", split_indices(data_dir, "test"))):
        frames = LabelledFrames(data_dir, rows)
        counts = collect(model, config, frames)
        fam = families[np.asarray(frames.arrays["robot"])[frames.indices]]
        result[name] = {k: scores(c, fam) for k, c in counts.items()}
        if name == "test":
            names = {code: name for name, code in SOURCE_CODES.items()}
            source = np.array([names[int(c)] for c in np.asarray(frames.arrays["source"])[frames.indices]])
            result[name + "_by_source"] = {k: {s: scores(c[source == s], fam[source == s])
                                               for s in np.unique(source)} for k, c in counts.items()}
    mean_acc = {k: float(np.mean([v["mask_accuracy"] for v in s.values()])) for k, s in result["held_out"].items()}
    result["chosen"] = {v: max((k for k in mean_acc if k.startswith(v)), key=mean_acc.get) for v in ("band", "components")}
    print(json.dumps({"chosen": result["chosen"], "test": {k: result["test"][k] for k in ["none", *result["chosen"].values()]}},
                     indent=1))
    if args.out:
        atomic_write_json(args.out, result)


if __name__ == "__main__":
    main()
