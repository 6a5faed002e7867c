"""The kinematic fit's weights, measured and checked on held-out training frames, never the test split.

    python benchmarks/kinematic_fit_sigmas.py [CHECKPOINT] [--out results/kinematic_fit_sigmas.json]

:mod:`armpose.kinematic_fit` holds the model's points to the rays of the network's points
(``ray_sigma``) and to their depths (``log_depth_sigma``). This script runs the zoom test (the
estimate the fit starts from) on the held-out training frames of ``benchmarks/ray_bone_fit.py``
(rows outside both transfer sets, 200 per robot type) and reports:

- the median ray error (``x/z, y/z``) and median ``|log(z_pred / z_true)|`` over the base and
  valid joints, and the sigmas they imply (the ray median; the log-depth median times the
  square root of the points per frame: see the module docstring);
- the fit's joint and base medians per family on those frames for the defaults and for a few
  other ``log_depth_sigma`` values, so the choice in the code can be checked.

Written to ``--out`` as JSON (atomically).
"""
from __future__ import annotations

import json
from dataclasses import asdict, replace

import numpy as np

from armpose.config import load_params
from armpose.evaluate import family_of, fitted, predict_split
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings
from armpose.zoom_test import settings_from_config

from checkpoint_cli import load_checkpoint_from_cli
from pose_fit_sigmas import point_errors
from ray_bone_fit import held_out_rows

LOG_DEPTH_GRID = (0.09, 0.18, 0.36)


def medians(pred: dict, truth: dict, families: np.ndarray) -> dict:
    """Joint and base medians (cm) per family of ``pred`` against ``truth``."""
    joint = np.linalg.norm(pred["joints"] - truth["joints"], axis=-1)
    base = np.linalg.norm(pred["base"] - truth["base"], axis=-1)
    out = {}
    for fam in dict.fromkeys(families.tolist()):
        m = families == fam
        out[fam] = {"joint_median_cm": round(100 * float(np.median(joint[m][truth["joint_valid"][m]])), 2),
                    "base_median_cm": round(100 * float(np.median(base[m])), 2)}
    return out


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir = root / "data" / "labels"
    rows = held_out_rows(data_dir, load_params(root / "params.yaml"))
    pred, truth = predict_split(model, data_dir, "train", rows=rows, zoom=True, zoom_settings=settings_from_config(config))
    zoom = pred["zoom"]
    ray, depth, frame = point_errors(zoom, truth)
    points_per_frame = len(ray) / max(1, len(zoom["type"]))
    types = list(config["base"]["robot_types"])
    families = np.array(family_of(types))[truth["type"]]
    default = FitSettings()
    out = {"checkpoint": str(args.checkpoint), "frames": int(len(rows)), "in_code": asdict(default),
           "zoom_test": {"ray_error_median": round(float(np.median(ray)), 4),
                         "abs_log_depth_error_median": round(float(np.median(depth)), 4),
                         "points_per_frame": round(points_per_frame, 2),
                         "implied": {"ray_sigma": round(float(np.median(ray)), 4),
                                     "log_depth_sigma": round(float(np.median(depth) * np.sqrt(points_per_frame)), 4)},
                         "medians": medians(zoom, truth, families)},
           "fit": {}}
    for sigma in sorted({*LOG_DEPTH_GRID, default.log_depth_sigma}):
        out["fit"][f"log_depth_sigma={sigma:g}"] = medians(fitted(zoom, types, replace(default, log_depth_sigma=sigma)),
                                                           truth, families)
    print(json.dumps(out, indent=1))
    if args.out:
        atomic_write_json(args.out, out)


if __name__ == "__main__":
    main()
