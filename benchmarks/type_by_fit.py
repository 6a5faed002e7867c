"""Can the kinematic fit tell apart the robot types of one family? A post-hoc check.

    python benchmarks/type_by_fit.py [CHECKPOINT] [--out results/type_by_fit.json] [--threads 2]

Most UR type errors are a UR5 taken for a UR10 or the reverse (``confusion`` in
``results/metrics.json``): nearly one shape at two scales, so the image alone says little. The
kinematic fit (:mod:`armpose.kinematic_fit`) poses a type's own model onto the network's rays and
depths; its final cost (a sum of squared, sigma-scaled residuals) is how well that type explains
the network's points. This check fits every type of the zoom test's predicted family (UR3, UR5
and UR10 for a frame typed UR; one type for KUKA and Panda, so nothing changes there) and picks,
per frame, the type with the highest ``log p(type) - alpha * cost / 2`` (``p``: the zoom test's
type probabilities). ``alpha = 0`` is today's choice (the network's type); ``alpha = 1`` treats
the cost as a Gaussian log-likelihood.

``alpha`` is chosen without the test split: on the held-out training frames of
``benchmarks/ray_bone_fit.py`` (200 per robot type, outside both transfer sets; UR frames seen in
pretraining), the grid value with the highest type accuracy of the multi-type families (ties: the
smallest). On both sets, per family and per alpha: type accuracy and the joint and base medians
(cm) of the chosen type's fit; on the test split also the chosen alpha's confusion matrix and its
recorded test recordings' type accuracy. Written to ``--out`` as JSON (atomically). Positions:
metres, camera optical frame.
"""
from __future__ import annotations

import json

import numpy as np

from armpose.config import load_params
from armpose.data import load_dataset, split_indices
from armpose.evaluate import family_of, predict_split
from armpose.fit_sigmas import checkpoint_fit_sigmas
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings, fit_predictions
from armpose.metrics import confusion_matrix
from armpose.zoom_test import settings_from_config

from bone_rescale import medians
from checkpoint_cli import load_checkpoint_from_cli
from ray_bone_fit import held_out_rows
from type_bias import by_recording

ALPHAS = (0.0, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0)


def candidate_fits(pred: dict, types: list[str], sigmas: dict | None) -> dict:
    """The kinematic fit of every type of each frame's predicted family: ``cost`` (N, T), +inf
    for types outside it, ``joints`` (N, T, max_joints, 3) and ``base`` (N, T, 3), metres."""
    families = np.asarray(family_of(types))
    n, t = len(pred["type"]), len(types)
    cost = np.full((n, t), np.inf)
    joints = np.repeat(pred["joints"][:, None], t, 1).astype(np.float64)
    base = np.repeat(pred["base"][:, None], t, 1).astype(np.float64)
    for k in range(t):
        rows = np.flatnonzero(families[pred["type"]] == families[k])
        if rows.size:
            fit = fit_predictions(pred["joints"][rows], pred["base"][rows], np.full(rows.size, k), types,
                                  FitSettings(), sigmas)
            cost[rows, k], joints[rows, k], base[rows, k] = fit["cost"], fit["joints"], fit["base"]
    return {"cost": cost, "joints": joints, "base": base}


def rerank(type_probs: np.ndarray, cost: np.ndarray, alpha: float) -> np.ndarray:
    """Per frame, the type (class index) maximising ``log p - alpha * cost / 2`` over the finite costs."""
    score = np.log(np.clip(type_probs, 1e-12, 1.0)) - alpha * np.where(np.isfinite(cost), cost, 0.0) / 2
    return np.where(np.isfinite(cost), score, -np.inf).argmax(1)


def scored(chosen: np.ndarray, fits: dict, truth: dict, types: list[str]) -> dict:
    """Per family: type accuracy and the joint and base medians (cm) of the chosen type's fit."""
    families = family_of(types)
    names = list(dict.fromkeys(families))
    rows = np.arange(len(chosen))
    out = medians(fits["joints"][rows, chosen], fits["base"][rows, chosen], truth, families, names)
    fam = np.asarray(families)[truth["type"]]
    for f in names:
        out[f]["type_accuracy"] = round(float(np.mean(chosen[fam == f] == truth["type"][fam == f])), 4)
    return out


def sweep(pred: dict, truth: dict, types: list[str], sigmas: dict | None) -> tuple[dict, dict]:
    """``(fits, {alpha: scores})`` of one set of frames."""
    fits = candidate_fits(pred, types, sigmas)
    return fits, {a: scored(rerank(pred["type_probs"], fits["cost"], a), fits, truth, types) for a in ALPHAS}


def choose_alpha(scores: dict, types: list[str]) -> float:
    """The alpha with the highest mean type accuracy over the families holding several types."""
    families = family_of(types)
    multi = [f for f in dict.fromkeys(families) if families.count(f) > 1]
    return max(ALPHAS, key=lambda a: (np.mean([scores[a][f]["type_accuracy"] for f in multi]), -a))


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir = root / "data" / "labels"
    params = load_params(root / "params.yaml")
    types = list(params["base"]["robot_types"])
    sigmas = checkpoint_fit_sigmas(root / args.checkpoint)
    zoom = settings_from_config(config)
    result = {"checkpoint": str(args.checkpoint), "alphas": list(ALPHAS)}
    sets = {"held_out": held_out_rows(data_dir, params), "test": split_indices(data_dir, "test")}
    for name, rows in sets.items():
        pred, truth = predict_split(model, data_dir, rows=rows, zoom=True, zoom_settings=zoom)
        fits, scores = sweep(pred["zoom"], truth, types, sigmas)
        result[name] = {"frames": int(len(rows)), "by_alpha": {str(a): s for a, s in scores.items()}}
        if name == "held_out":
            alpha = choose_alpha(scores, types)
            result["chosen_alpha"] = alpha
        else:
            chosen = rerank(pred["zoom"]["type_probs"], fits["cost"], alpha)
            result[name]["confusion"] = confusion_matrix(chosen, truth["type"], len(types)).tolist()
            _, index = load_dataset(data_dir)
            result[name]["by_recording"] = {
                source: by_recording(types_, truth["type"], truth["recording"], index, types)
                for source, types_ in (("network", pred["zoom"]["type"]), ("chosen_alpha", chosen))}
    print(json.dumps({k: result[k] for k in ("chosen_alpha",)} | {
        s: {a: result[s]["by_alpha"][a] for a in ("0.0", str(result["chosen_alpha"]))} for s in sets}, indent=1))
    if args.out:
        atomic_write_json(args.out, result)


if __name__ == "__main__":
    main()
