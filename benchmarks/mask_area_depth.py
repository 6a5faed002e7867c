"""Does the predicted mask's size move the predicted distance? Per family and per recorded test recording.

    python benchmarks/mask_area_depth.py [CHECKPOINT] [--out FILE] [--threads 2]

Most of the joint error is a depth error that all joints of a frame share, read from the robot's
apparent size. If the network takes part of the scene for robot (a grey table under a dimly lit
KUKA, say), the robot it sees is larger, and it should place it closer. This script scores the
test split as the headline is scored (the ``evaluate`` section of ``params.yaml``: mirror test,
zoom test, on the mirror test's passes when ``zoom_on_mirror``, then the kinematic fit with the
checkpoint's per-type weights) and, per frame, compares:

- ``area_ratio``: the zoom test's predicted mask area over the true mask area (network-input
  pixels, 256x212);
- ``false_positive_ratio``: its pixels wrongly called robot, over the true mask area;
- ``depth_ratio``: :func:`armpose.metrics.frame_depth_ratio` of the fit (predicted over true depth,
  the median over the frame's valid joints).

Per family (synthetic test frames and recorded test recordings apart) and per recorded test
recording: frames, the medians of the three ratios, the fit's joint median (cm), and over the
family's frames the Pearson correlation of ``log area_ratio`` with ``log depth_ratio`` (negative:
a larger mask, a closer robot). Written to ``--out`` as JSON (atomically). Positions: metres,
camera optical frame.
"""
from __future__ import annotations

import json

import numpy as np

from armpose.config import load_params
from armpose.data import split_indices
from armpose.evaluate import family_of, predict_split
from armpose.fit_sigmas import checkpoint_fit_sigmas
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings
from armpose.labels.dataset import SOURCE_CODES, load_dataset
from armpose.metrics import frame_depth_ratio
from armpose.zoom_test import settings_from_config

from checkpoint_cli import load_checkpoint_from_cli


def frame_ratios(pred_masks: np.ndarray, true_masks: np.ndarray, pred_joints: np.ndarray,
                 true_joints: np.ndarray, joint_valid: np.ndarray) -> dict[str, np.ndarray]:
    """Per frame: ``area_ratio`` and ``false_positive_ratio`` of boolean masks (N, H, W) against
    the truth (a frame with an empty true mask gets NaN), and ``depth_ratio`` of the joints (N, J, 3)."""
    true_area = true_masks.sum((1, 2)).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        area = np.where(true_area > 0, pred_masks.sum((1, 2)) / true_area, np.nan)
        false_pos = np.where(true_area > 0, (pred_masks & ~true_masks).sum((1, 2)) / true_area, np.nan)
    return {"area_ratio": area, "false_positive_ratio": false_pos,
            "depth_ratio": frame_depth_ratio(pred_joints, true_joints, joint_valid)}


def group_summary(ratios: dict[str, np.ndarray], joint_err: np.ndarray, joint_valid: np.ndarray,
                  frames: np.ndarray) -> dict:
    """Frames, median of each ratio, joint median (cm) and the correlation of the logs of area
    and depth ratio over the boolean selection ``frames`` (None with fewer than 3 usable frames)."""
    out = {"frames": int(frames.sum())}
    for key, values in ratios.items():
        out[f"{key}_median"] = round(float(np.nanmedian(values[frames])), 3)
    out["joint_median_cm"] = round(100 * float(np.median(joint_err[frames][joint_valid[frames]])), 2)
    a, d = ratios["area_ratio"][frames], ratios["depth_ratio"][frames]
    ok = np.isfinite(a) & np.isfinite(d) & (a > 0) & (d > 0)
    out["corr_log_area_log_depth"] = (round(float(np.corrcoef(np.log(a[ok]), np.log(d[ok]))[0, 1]), 3)
                                      if ok.sum() >= 3 else None)
    return out


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir, params = root / "data" / "labels", load_params(root / "params.yaml")
    cfg, types = params["evaluate"], list(params["base"]["robot_types"])
    arrays, index = load_dataset(data_dir)
    rows = split_indices(arrays, "test")
    on_mirror = bool(cfg.get("zoom_on_mirror", False))
    pred, truth = predict_split(model, data_dir, rows=rows, mirror=on_mirror, zoom=True,
                                zoom_settings=settings_from_config(config), fit=FitSettings(),
                                fit_sigmas=checkpoint_fit_sigmas(root / args.checkpoint),
                                zoom_on_mirror=on_mirror, keep_masks=True)
    ratios = frame_ratios(pred["zoom"]["masks"], truth["masks"], pred["fit"]["joints"],
                          truth["joints"], truth["joint_valid"])
    err = np.linalg.norm(pred["fit"]["joints"] - truth["joints"], axis=-1)
    family = np.array(family_of(types))[truth["type"]]
    sources = {code: name for name, code in SOURCE_CODES.items()}
    recordings = list(index.get("recordings", []))
    result = {"checkpoint": str(args.checkpoint), "zoom_on_mirror": on_mirror, "by_family": {}, "by_recording": {}}
    for fam in dict.fromkeys(family_of(types)):
        of_family = family == fam
        result["by_family"][fam] = {"all": group_summary(ratios, err, truth["joint_valid"], of_family)}
        for code in np.unique(truth["source"][of_family]):
            result["by_family"][fam][sources.get(int(code), str(code))] = group_summary(
                ratios, err, truth["joint_valid"], of_family & (truth["source"] == code))
    recorded = truth["source"] == SOURCE_CODES.get("recorded", -1)
    for rec in np.unique(truth["recording"][recorded]):
        name = recordings[rec]["name"] if rec < len(recordings) else str(int(rec))
        result["by_recording"][name] = group_summary(ratios, err, truth["joint_valid"],
                                                          recorded & (truth["recording"] == rec))
    print(json.dumps(result, indent=1))
    if args.out:
        atomic_write_json(args.out, result)


if __name__ == "__main__":
    main()
