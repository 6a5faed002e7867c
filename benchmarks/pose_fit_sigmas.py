"""The network's typical ray and depth errors, which weight the camera-pose refinement.

    python benchmarks/pose_fit_sigmas.py [CHECKPOINT] [--out results/pose_fit_sigmas.json]

:func:`armpose.camera_pose.refine_rays` holds each forward-kinematics point to the ray of its
predicted point (``RAY_SIGMA``, normalised image coordinates, about radians) and to its predicted
depth (``LOG_DEPTH_SIGMA``, relative). This script measures both on the same held-out training
frames as ``benchmarks/ray_bone_fit.py`` (rows outside both transfer sets, 200 per robot type),
never the test split: the median distance between predicted and true rays (``x/z, y/z``) and the
median ``|log(z_pred / z_true)|``, over the base and every valid joint, per family and over all,
and compares them with the constants in the code. Written to ``--out`` as JSON (atomically).
"""
from __future__ import annotations

import json

import numpy as np

from armpose.camera_pose import LOG_DEPTH_SIGMA, RAY_SIGMA
from armpose.config import load_params
from armpose.evaluate import family_of, predict_split
from armpose.io import atomic_write_json

from checkpoint_cli import load_checkpoint_from_cli
from ray_bone_fit import held_out_rows


def point_errors(pred: dict, truth: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(ray error, |log depth error|, frame index)`` of the base and every valid joint."""
    p = np.concatenate([pred["base"][:, None], pred["joints"]], axis=1)
    t = np.concatenate([truth["base"][:, None], truth["joints"]], axis=1)
    valid = np.concatenate([np.ones((len(p), 1), bool), truth["joint_valid"]], axis=1) & (p[..., 2] > 1e-3)
    with np.errstate(divide="ignore", invalid="ignore"):      # unused joint slots, dropped below
        ray = np.linalg.norm(p[..., :2] / p[..., 2:] - t[..., :2] / t[..., 2:], axis=-1)
        depth = np.abs(np.log(p[..., 2] / t[..., 2]))
    frame = np.broadcast_to(np.arange(len(p))[:, None], valid.shape)
    return ray[valid], depth[valid], frame[valid]


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir = root / "data" / "labels"
    pred, truth = predict_split(model, data_dir, "train", rows=held_out_rows(data_dir, load_params(root / "params.yaml")))
    ray, depth, frame = point_errors(pred, truth)
    fams = np.array(family_of(list(config["base"]["robot_types"])))[truth["type"]][frame]
    groups = {"all": np.ones(len(ray), bool), **{f: fams == f for f in dict.fromkeys(fams.tolist())}}
    out = {"checkpoint": str(args.checkpoint), "frames": len(pred["type"]),
           "in_code": {"RAY_SIGMA": RAY_SIGMA, "LOG_DEPTH_SIGMA": LOG_DEPTH_SIGMA},
           "median": {g: {"points": int(m.sum()), "ray_error": round(float(np.median(ray[m])), 4),
                          "abs_log_depth_error": round(float(np.median(depth[m])), 4)} for g, m in groups.items()}}
    print(json.dumps(out, indent=1))
    if args.out:
        atomic_write_json(args.out, out)


if __name__ == "__main__":
    main()
