"""The zoom test's share of the second look, checked on held-out training frames, never the test split.

    python benchmarks/zoom_weight.py [CHECKPOINT] [--out results/zoom_weight.json]

:mod:`armpose.zoom_test` averages the first pass and the second look with ``weight`` on the second
(``TRAINED_WEIGHT`` for a network trained with ``augment.zoom``). This script runs both looks once
on the held-out training frames of ``benchmarks/ray_bone_fit.py`` (rows outside both transfer sets,
200 per robot type) and scores the combination for several weights, 0 (the first pass alone) to 1
(the second look alone): joint and base medians (cm), type and mask accuracy per family.
Written to ``--out`` as JSON (atomically).
"""
from __future__ import annotations

import json

import numpy as np
import torch

from armpose.config import load_params
from armpose.data import LabelledFrames
from armpose.evaluate import family_of
from armpose.io import atomic_write_json
from armpose.model import predicted_mask
from armpose.robots import get_robot
from armpose.zoom_test import TRAINED_WEIGHT, second_look_views, settings_from_config, warp_images, zoom_combine

from checkpoint_cli import load_checkpoint_from_cli
from ray_bone_fit import held_out_rows

WEIGHTS = (0.0, 0.25, 0.5, 0.75, 1.0)


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir = root / "data" / "labels"
    rows = held_out_rows(data_dir, load_params(root / "params.yaml"))
    frames = LabelledFrames(data_dir, rows)
    types = frames.robot_types
    counts = [get_robot(t).num_joints for t in types]
    settings, threshold = settings_from_config(config), float(model.mask_threshold)
    scores = {w: {"joint": [], "base": [], "type": [], "mask": []} for w in WEIGHTS}
    fams = []
    with torch.no_grad():
        for start in range(0, len(frames), 32):
            items = [frames[i] for i in range(start, min(start + 32, len(frames)))]
            x = torch.stack([it["image"] for it in items]).contiguous(memory_format=torch.channels_last)
            cams = torch.stack([it["intrinsics"] for it in items])
            single = model(x)
            turns, scales, cam_rows = second_look_views(x, single, cams, settings, counts)
            second = model(warp_images(x, turns, scales, cam_rows).contiguous(memory_format=torch.channels_last))
            for w in WEIGHTS:
                _score(scores[w], zoom_combine(single, second, turns, scales, cam_rows, threshold, counts, w), items, model)
            fams += [family_of(types)[int(it["robot"])] for it in items]
    fams = np.array(fams)
    result = {"checkpoint": str(args.checkpoint), "frames": int(len(rows)), "trained_weight": TRAINED_WEIGHT,
              "settings": settings, "by_weight": {}}
    for w, s in scores.items():
        result["by_weight"][f"{w:g}"] = {f: {"joint_median_cm": round(100 * float(np.median(np.concatenate(
            [j for j, ff in zip(s["joint"], fams) if ff == f]))), 2),
            "base_median_cm": round(100 * float(np.median(np.array(s["base"])[fams == f])), 2),
            "type_accuracy": round(float(np.mean(np.array(s["type"])[fams == f])), 4),
            "mask_accuracy": round(float(np.mean(np.array(s["mask"])[fams == f])), 4)} for f in dict.fromkeys(fams.tolist())}
    print(json.dumps(result, indent=1))
    if args.out:
        atomic_write_json(args.out, result)


def _score(acc: dict, out: dict, items: list, model) -> None:
    for o_j, o_b, o_t, o_m, it in zip(out["joints"], out["base"], out["type_logits"].argmax(-1),
                                      predicted_mask(model, out["mask_logits"][:, 0]), items):
        valid = it["joint_valid"]
        acc["joint"].append(torch.linalg.norm(o_j[valid] - it["joints"][valid], dim=-1).numpy())
        acc["base"].append(float(torch.linalg.norm(o_b - it["base"])))
        acc["type"].append(float(int(o_t) == int(it["robot"])))
        acc["mask"].append(float((o_m == (it["mask"] > 0.5)).float().mean()))


if __name__ == "__main__":
    main()
