"""Can the robots' known bone lengths fix the predicted depth? A post-hoc check, not a method.

    python benchmarks/bone_rescale.py [CHECKPOINT] [--out results/bone_rescale.json]

The distance between consecutive joint origins (and from the base to the first joint) of a robot
does not depend on its joint angles. A skeleton predicted at the wrong distance but with the right
shape would therefore have bone lengths off by a common factor, and scaling it about the camera
centre (which keeps every ray, so every 2D position) by ``s = sum(l L) / sum(l^2)`` (``l`` its
bone lengths, ``L`` the predicted type's, bones of at least 5 cm) would fix its depth. This script
predicts the test split with CHECKPOINT (default: the two-stage transfer model), applies that
rescaling per frame, and prints per robot family the joint and base medians (cm) before and after,
and the 5th / 50th / 95th percentiles of ``s``. The numbers go to ``--out`` as JSON (atomically).
Positions are metres in the camera optical frame.
"""
from __future__ import annotations

import json

import numpy as np

from armpose.bone_fit import bone_lengths
from armpose.evaluate import family_of, predict_split
from armpose.io import atomic_write_json

from checkpoint_cli import load_checkpoint_from_cli

MIN_BONE_M = 0.05


def rescale_factors(joints: np.ndarray, base: np.ndarray, types: np.ndarray, bones: list[np.ndarray]) -> np.ndarray:
    """Per frame, the least-squares factor taking the predicted bone lengths to the true ones
    of its predicted type (``joints`` (N, J, 3), ``base`` (N, 3), ``types`` (N,))."""
    s = np.ones(len(types))
    for n, t in enumerate(types):
        true = bones[t]
        pts = np.vstack([base[n], joints[n, :len(true)]])
        pred = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        keep = true >= MIN_BONE_M
        if (pred[keep] ** 2).sum() > 0:
            s[n] = (pred[keep] * true[keep]).sum() / (pred[keep] ** 2).sum()
    return s


def medians(joints, base, truth, families, names) -> dict:
    err = np.linalg.norm(joints - truth["joints"], axis=-1)
    err = np.where(truth["joint_valid"], err, np.nan)
    base_err = np.linalg.norm(base - truth["base"], axis=-1)
    fam = np.array([families[t] for t in truth["type"]])
    return {f: {"joint_median_cm": round(float(100 * np.nanmedian(err[fam == f])), 2),
                "base_median_cm": round(float(100 * np.median(base_err[fam == f])), 2)} for f in names}


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    types = list(config["base"]["robot_types"])
    families = family_of(types)
    names = list(dict.fromkeys(families))
    pred, truth = predict_split(model, root / "data" / "labels", "test")
    s = rescale_factors(pred["joints"], pred["base"], pred["type"], [bone_lengths(t) for t in types])
    out = {"checkpoint": str(args.checkpoint),
           "scale_percentiles_5_50_95": [round(float(v), 3) for v in np.percentile(s, [5, 50, 95])],
           "before": medians(pred["joints"], pred["base"], truth, families, names),
           "after": medians(pred["joints"] * s[:, None, None], pred["base"] * s[:, None], truth, families, names)}
    print(json.dumps(out, indent=1))
    if args.out:
        atomic_write_json(args.out, out)


if __name__ == "__main__":
    main()
