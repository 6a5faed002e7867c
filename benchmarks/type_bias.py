"""Whether the UR type errors are a class-prior problem: a per-class bias on the type logits.

    python benchmarks/type_bias.py [CHECKPOINT] [--out results/type_bias.json] [--threads 2]

The zoom test types most wrong UR frames as the UR of the other size (a UR10 taken for a UR5
far more often than the reverse; ``confusion`` in ``results/metrics.json``). If that asymmetry
were a prior the network had learnt, one bias per class on the zoom test's type logits would
take it out. This script runs the zoom test (:func:`armpose.zoom_test.forward_with_zoom`) on the
held-out training frames of ``benchmarks/ray_bone_fit.py`` (outside both transfer sets, 200 per
robot type) and on the test split, fits the five biases on the held-out frames only (the
cross-entropy minimum, by L-BFGS; mean-centred) and scores type accuracy per family and the
confusion matrix on both, without and with them, and on the test split the type accuracy and the
predicted types of each recorded test recording. The test split never chooses anything.
Written to ``--out`` as JSON (atomically).
"""
from __future__ import annotations

import json

import numpy as np
import torch

from armpose.config import load_params
from armpose.data import LabelledFrames, split_indices
from armpose.evaluate import family_of
from armpose.io import atomic_write_json
from armpose.robots import get_robot
from armpose.zoom_test import forward_with_zoom, settings_from_config

from checkpoint_cli import load_checkpoint_from_cli
from ray_bone_fit import held_out_rows


def zoom_type_logits(model, config: dict, frames: LabelledFrames, batch: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """``(logits (N, T), true class (N,))`` of the zoom test's type on every frame of ``frames``."""
    counts = [get_robot(t).num_joints for t in frames.robot_types]
    settings, logits, truth = settings_from_config(config), [], []
    with torch.no_grad():
        for start in range(0, len(frames), batch):
            items = [frames[i] for i in range(start, min(start + batch, len(frames)))]
            x = torch.stack([it["image"] for it in items]).contiguous(memory_format=torch.channels_last)
            _, zoomed = forward_with_zoom(model, x, torch.stack([it["intrinsics"] for it in items]), settings, counts)
            logits.append(zoomed["type_logits"].float().numpy())
            truth += [int(it["robot"]) for it in items]
    return np.concatenate(logits), np.asarray(truth)


def fit_class_bias(logits: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """The per-class bias (T,) that minimises the cross-entropy of ``logits + bias``, mean-centred."""
    x, y = torch.tensor(logits, dtype=torch.float64), torch.tensor(truth)
    bias = torch.zeros(logits.shape[1], dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([bias], max_iter=200)

    def closure():
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(x + bias, y)
        loss.backward()
        return loss
    opt.step(closure)
    b = bias.detach().numpy()
    return b - b.mean()


def type_scores(logits: np.ndarray, truth: np.ndarray, types: list[str]) -> dict:
    """Type accuracy per family (and overall) and the confusion matrix (rows: true class)."""
    pred, fams = logits.argmax(1), np.asarray(family_of(types))[truth]
    confusion = np.zeros((len(types), len(types)), int)
    np.add.at(confusion, (truth, pred), 1)
    acc = {f: round(float(np.mean(pred[fams == f] == truth[fams == f])), 4) for f in dict.fromkeys(fams.tolist())}
    return {"type_accuracy": {**acc, "all": round(float(np.mean(pred == truth)), 4)}, "confusion": confusion.tolist()}


def by_recording(pred: np.ndarray, truth: np.ndarray, recording: np.ndarray, index: dict, types: list[str]) -> dict:
    """Per recorded (non-synthetic) recording: frames, type accuracy and the count of each
    predicted type. ``pred``, ``truth``: type indices per frame; ``recording``: each frame's
    recording id in ``index["recordings"]`` (the dataset's ``index.json``)."""
    out = {}
    for r in np.unique(recording):
        meta = index["recordings"][int(r)]
        if meta.get("source") == "synthetic":
            continue
        sel = recording == r
        counts = np.bincount(pred[sel], minlength=len(types))
        out[meta["name"]] = {"frames": int(sel.sum()), "type_accuracy": round(float(np.mean(pred[sel] == truth[sel])), 4),
                             "predicted": {t: int(c) for t, c in zip(types, counts) if c}}
    return out


def main() -> None:
    args, root, model, config = load_checkpoint_from_cli(__doc__)
    data_dir = root / "data" / "labels"
    params = load_params(root / "params.yaml")
    types = list(params["base"]["robot_types"])
    held_out, test = (LabelledFrames(data_dir, rows) for rows in (held_out_rows(data_dir, params),
                                                                  split_indices(data_dir, "test")))
    (lh, yh), (lt, yt) = zoom_type_logits(model, config, held_out), zoom_type_logits(model, config, test)
    bias = fit_class_bias(lh, yh)
    result = {"checkpoint": str(args.checkpoint), "labels": types, "bias": [round(float(b), 4) for b in bias],
              "held_out": {"frames": int(len(yh)), "without": type_scores(lh, yh, types),
                           "with_bias": type_scores(lh + bias, yh, types)},
              "test": {"frames": int(len(yt)), "without": type_scores(lt, yt, types),
                       "with_bias": type_scores(lt + bias, yt, types),
                       "by_recording": by_recording(lt.argmax(1), yt, np.asarray(test.arrays["recording"])[test.indices],
                                                     test.meta, types)}}
    print(json.dumps(result, indent=1))
    if args.out:
        atomic_write_json(args.out, result)


if __name__ == "__main__":
    main()
