"""The network's depth bias per robot type, and what correcting it before the kinematic fit does.

    python benchmarks/depth_bias.py [CHECKPOINT] [--out results/depth_bias.json]

The frame depth ratio (:func:`armpose.metrics.frame_depth_ratio`: per frame, the median over its
joints of predicted over true depth) has a median below 1 for the larger robots: the network
places them too close, as if it pulled every robot's size towards the mean. This script measures
that bias through the zoom test on the held-out training frames of ``benchmarks/ray_bone_fit.py``
(rows outside both transfer sets, 200 per robot type; never the test split), per *predicted* type,
as a correction must be applied. It then scores, on the test split, per family:

- ``zoom_test``: the zoom test's joints as they are, and ``zoom_test_corrected``: each frame's
  joints and base divided by its predicted type's held-out median ratio (a move along the rays);
- ``fit`` and ``fit_corrected``: the kinematic fit with the checkpoint's per-type sigmas, without
  any ``depth_ratio`` and with this script's (:mod:`armpose.kinematic_fit` divides the points by
  it: the depth prior centred on the corrected depths).

Figures are joint and base medians in cm. Written to ``--out`` as JSON (atomically). The pipeline
applies the ratio that transfer stage 2 stores in its checkpoint (``fit_sigmas: true``,
:mod:`armpose.fit_sigmas`, measured on its own held-out frames), so ``evaluate`` and
``armpose predict --fit`` give ``fit_corrected`` up to that choice of frames.
"""
from __future__ import annotations

import json

import numpy as np

from armpose.config import load_params
from armpose.evaluate import family_of, fitted, predict_split
from armpose.fit_sigmas import checkpoint_fit_sigmas, depth_ratios
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings
from armpose.metrics import frame_depth_ratio
from armpose.zoom_test import settings_from_config

from checkpoint_cli import load_checkpoint_from_cli
from kinematic_fit_sigmas import medians
from ray_bone_fit import held_out_rows


def corrected(pred: dict, ratio: np.ndarray) -> dict:
    """``pred`` with each frame's joints and base divided by ``ratio`` of its predicted type."""
    s = ratio[pred["type"]]
    return {**pred, "joints": pred["joints"] / s[:, None, None], "base": pred["base"] / s[:, None]}


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir, types = root / "data" / "labels", list(config["base"]["robot_types"])
    settings = settings_from_config(config)
    rows = held_out_rows(data_dir, load_params(root / "params.yaml"))
    held, held_truth = predict_split(model, data_dir, "train", rows=rows, zoom=True, zoom_settings=settings)
    found = depth_ratios(held["zoom"], held_truth, types)
    ratio = np.array([found.get(t, 1.0) for t in types])          # 1: no frame typed as it
    pred, truth = predict_split(model, data_dir, "test", zoom=True, zoom_settings=settings)
    zoom, fixed = pred["zoom"], corrected(pred["zoom"], ratio)
    families = np.array(family_of(types))[truth["type"]]
    test_ratio = frame_depth_ratio(zoom["joints"], truth["joints"], truth["joint_valid"])
    stored = checkpoint_fit_sigmas(root / args.checkpoint)
    plain = {t: {k: v for k, v in s.items() if k != "depth_ratio"} for t, s in stored.items()}
    with_ratio = {t: {**s, "depth_ratio": float(ratio[types.index(t)])} for t, s in plain.items()}
    out = {"checkpoint": str(args.checkpoint), "held_out_frames": int(len(rows)), "test_frames": int(len(truth["type"])),
           "held_out_ratio_per_predicted_type": {t: round(float(r), 4) for t, r in zip(types, ratio)},
           "stored_ratio": {t: s.get("depth_ratio") for t, s in stored.items()},
           "test_ratio_per_true_type": {t: round(float(np.nanmedian(test_ratio[truth["type"] == k])), 4)
                                        for k, t in enumerate(types) if (truth["type"] == k).any()},
           "test_medians": {"zoom_test": medians(zoom, truth, families),
                            "zoom_test_corrected": medians(fixed, truth, families),
                            "fit": medians(fitted(zoom, types, FitSettings(), plain), truth, families),
                            "fit_corrected": medians(fitted(zoom, types, FitSettings(), with_ratio), truth, families)}}
    print(json.dumps(out, indent=1))
    if args.out:
        atomic_write_json(args.out, out)


if __name__ == "__main__":
    main()
