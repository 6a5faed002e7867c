"""The kinematic fit's per-type weights, checked on held-out training frames, never the test split.

    python benchmarks/kinematic_fit_sigmas.py [CHECKPOINT] [--out results/kinematic_fit_sigmas.json]

A training stage with ``fit_sigmas: true`` stores, per robot type, the network's median ray and
log-depth errors on training frames it did not train on (:mod:`armpose.fit_sigmas`), and
:mod:`armpose.kinematic_fit` weights the fit by them. This script runs the zoom test (the estimate
the fit starts from) on the held-out training frames of ``benchmarks/ray_bone_fit.py`` (rows outside
both transfer sets, 200 per robot type) and gives the joint and base medians per family of: the
estimate, the fit with the checkpoint's per-type sigmas, and the fit with one global pair (the
defaults of :class:`armpose.kinematic_fit.FitSettings`). Written to ``--out`` as JSON (atomically).
"""
from __future__ import annotations

import json
from dataclasses import asdict

import numpy as np

from armpose.config import load_params
from armpose.evaluate import family_of, fitted, predict_split
from armpose.fit_sigmas import checkpoint_fit_sigmas
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings
from armpose.zoom_test import settings_from_config

from checkpoint_cli import load_checkpoint_from_cli
from ray_bone_fit import held_out_rows

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
    types = list(config["base"]["robot_types"])
    families = np.array(family_of(types))[truth["type"]]
    stored = checkpoint_fit_sigmas(root / args.checkpoint)
    out = {"checkpoint": str(args.checkpoint), "frames": int(len(rows)), "stored_sigmas": stored,
           "defaults": asdict(FitSettings()), "medians": {
               "zoom_test": medians(zoom, truth, families),
               "fit_stored_sigmas": medians(fitted(zoom, types, FitSettings(), stored), truth, families),
               "fit_default_sigmas": medians(fitted(zoom, types, FitSettings()), truth, families)}}
    print(json.dumps(out, indent=1))
    if args.out:
        atomic_write_json(args.out, out)


if __name__ == "__main__":
    main()
