"""More than one second look: zoom views at several fills, averaged, on held-out training frames.

    python benchmarks/zoom_looks.py [CHECKPOINT] [--out results/zoom_looks.json] [--threads 2]

The zoom test (:mod:`armpose.zoom_test`) takes one second look, dollied in until the robot's box
spans ``fill`` of the frame (the middle of the training range ``augment.zoom.fill``), and averages
it with the first pass. Looks at other fills see the robot at other apparent sizes, so their
errors may be partly independent. This script takes looks at the two ends and the middle of the
training range (0.55, 0.7, 0.85 by default) on the held-out training frames of
``benchmarks/ray_bone_fit.py`` (outside both transfer sets, 200 per robot type), maps each back
(:func:`armpose.zoom_test.zoom_combine` with the look's weight 1), and scores the equal-weight mean
of the first pass and each set of looks: joint and base medians (cm) and type accuracy per family,
then the kinematic fit (:func:`armpose.kinematic_fit.fit_predictions`, the checkpoint's stored
per-type weights, which were measured on one-look estimates) of the one-look and the all-looks
estimate. Written to ``--out`` as JSON (atomically).
"""
from __future__ import annotations

import itertools
import json

import numpy as np
import torch

from armpose.config import load_params
from armpose.data import LabelledFrames
from armpose.evaluate import family_of
from armpose.fit_sigmas import checkpoint_fit_sigmas
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings, fit_predictions
from armpose.robots import get_robot
from armpose.zoom_test import second_look_views, settings_from_config, warp_images, zoom_combine

from checkpoint_cli import load_checkpoint_from_cli
from kinematic_fit_sigmas import medians
from ray_bone_fit import held_out_rows

KEYS = ("joints", "base", "type_logits")


def looks_of_batch(model, images: torch.Tensor, cams: torch.Tensor, settings: dict, fills: list[float],
                   counts: list[int]) -> tuple[dict, dict]:
    """``(first pass, {fill: that look mapped back to the original camera})`` of one batch."""
    single = {k: v for k, v in model(images).items() if k in KEYS}
    looks = {}
    for fill in fills:
        turns, scales, cam_rows = second_look_views(images, single, cams, {**settings, "fill": fill}, counts)
        view = warp_images(images, turns, scales, cam_rows).contiguous(memory_format=torch.channels_last)
        zoomed = {k: v for k, v in model(view).items() if k in KEYS}
        looks[fill] = zoom_combine(single, zoomed, turns, scales, cam_rows, 0.0, counts, 1.0)
    return single, looks


def mean_estimate(outputs: list[dict]) -> dict:
    """Equal-weight mean of joints and base (metres) and of type probabilities; numpy arrays."""
    return {"joints": torch.stack([o["joints"].float() for o in outputs]).mean(0).numpy(),
            "base": torch.stack([o["base"].float() for o in outputs]).mean(0).numpy(),
            "type": torch.stack([o["type_logits"].float().softmax(-1) for o in outputs]).mean(0).argmax(-1).numpy()}


def scored(pred: dict, truth: dict, families: np.ndarray) -> dict:
    """:func:`kinematic_fit_sigmas.medians` (joint and base medians, cm, per family), plus type
    accuracy per family when ``pred`` has types."""
    out = medians(pred, truth, families)
    if "type" in pred:
        for fam in out:
            m = families == fam
            out[fam]["type_accuracy"] = round(float(np.mean(pred["type"][m] == truth["type"][m])), 4)
    return out


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(
        __doc__, lambda ap: ap.add_argument("--fills", type=float, nargs="+", default=[0.55, 0.7, 0.85]))
    data_dir = root / "data" / "labels"
    frames = LabelledFrames(data_dir, held_out_rows(data_dir, load_params(root / "params.yaml")))
    types, settings = frames.robot_types, settings_from_config(config)
    counts = [get_robot(t).num_joints for t in types]
    subsets = [s for n in range(len(args.fills) + 1) for s in itertools.combinations(args.fills, n)]
    estimates = {s: [] for s in subsets}
    truth = {"joints": [], "base": [], "joint_valid": [], "type": []}
    with torch.no_grad():
        for start in range(0, len(frames), 32):
            items = [frames[i] for i in range(start, min(start + 32, len(frames)))]
            images = torch.stack([it["image"] for it in items]).contiguous(memory_format=torch.channels_last)
            single, looks = looks_of_batch(model, images, torch.stack([it["intrinsics"] for it in items]),
                                           settings, args.fills, counts)
            for s in subsets:
                estimates[s].append(mean_estimate([single] + [looks[f] for f in s]))
            for key, item_key in (("joints", "joints"), ("base", "base"), ("joint_valid", "joint_valid"), ("type", "robot")):
                truth[key].append(np.stack([np.asarray(it[item_key]) for it in items]))
    truth = {k: np.concatenate(v) for k, v in truth.items()}
    families = np.array(family_of(types))[truth["type"]]
    merged = {s: {k: np.concatenate([e[k] for e in v]) for k in ("joints", "base", "type")} for s, v in estimates.items()}
    name = lambda s: "first pass" + "".join(f" + {f:g}" for f in s)   # noqa: E731
    sigmas, middle = checkpoint_fit_sigmas(root / args.checkpoint), (float(settings["fill"]),)
    fits = {}
    for s in dict.fromkeys([middle, tuple(args.fills)]):
        if s in merged:
            e = merged[s]
            fit = fit_predictions(e["joints"].astype(np.float64), e["base"].astype(np.float64), e["type"],
                                  list(types), FitSettings(), sigmas)
            fits[name(s)] = scored({"joints": fit["joints"], "base": fit["base"]}, truth, families)
    result = {"checkpoint": str(args.checkpoint), "frames": int(len(frames)), "fills": args.fills,
              "trained_fill": settings["fill"], "estimates": {name(s): scored(merged[s], truth, families) for s in subsets},
              "fit": fits}
    print(json.dumps(result, indent=1))
    if args.out:
        atomic_write_json(args.out, result)


if __name__ == "__main__":
    main()
