"""Test-split scores of any checkpoints, for A/B comparisons of a stage's settings.

    python benchmarks/score_checkpoint.py CHECKPOINT [CHECKPOINT ...] [--families UR] [--mirror] [--zoom] [--fit] [--zoom-on-mirror] [--out FILE]

Scores each checkpoint on the test split of ``data/labels`` with the ``evaluate`` stage's
metrics (:func:`armpose.evaluate.evaluate_checkpoint`) and prints, per robot family and per
robot type of those families: frames, median joint and base error (cm), type and mask accuracy.
A pretraining checkpoint has only seen UR robots, so compare those with ``--families UR``.
To score the checkpoint of another commit's settings, check that commit out and run its
stage (``dvc repro pretrain``) first; the dataset must be the same for the scores to compare.
``--mirror`` adds the scores of the mirror test (``mirror_test``, :mod:`armpose.mirror_test`),
``--zoom`` those of the zoom test (``zoom_test``, :mod:`armpose.zoom_test`), ``--fit`` those of the
kinematic fit (``kinematic_fit``, :mod:`armpose.kinematic_fit`; to the zoom test's estimate with ``--zoom``);
``--zoom-on-mirror`` runs the zoom test on the mirror test's passes, as the default ``evaluate`` stage does.
``--out`` also writes the scores as JSON (atomically).
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import torch
import yaml

from armpose.config import project_root
from armpose.evaluate import evaluate_checkpoint, family_of
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings

KEYS = ("frames", "joint_median_cm", "base_median_cm", "type_accuracy", "mask_accuracy")


def pick(group: dict, names: list[str]) -> dict:
    """The :data:`KEYS` of each of ``names`` present in ``group`` (metrics per family or type)."""
    return {n: {k: group[n][k] for k in KEYS if k in group[n]} for n in names if n in group}


def scores(metrics: dict, families: list[str], robot_types: list[str]) -> dict:
    """The :data:`KEYS` of ``metrics`` for ``families`` and their robot types."""
    types = [t for t, f in zip(robot_types, family_of(robot_types)) if f in families]
    return {"by_family": pick(metrics["by_family"], families), "by_type": pick(metrics["by_type"], types)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument("--families", nargs="+", default=["UR", "KUKA", "Panda"])
    ap.add_argument("--mirror", action="store_true", help="also score the mirror test")
    ap.add_argument("--zoom", action="store_true", help="also score the zoom test")
    ap.add_argument("--fit", action="store_true", help="also score the kinematic fit")
    ap.add_argument("--zoom-on-mirror", action="store_true",
                    help="run the zoom test (and the fit) on the mirror test's passes (needs --mirror --zoom)")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    root = project_root()
    base = yaml.safe_load((root / "params.yaml").read_text())["base"]
    torch.set_num_threads(int(base.get("threads", 2)))
    out = {}
    for ckpt in args.checkpoints:
        metrics, _, _ = evaluate_checkpoint(ckpt, root / "data" / "labels", base, mirror=args.mirror, zoom=args.zoom,
                                            fit=FitSettings() if args.fit else None, zoom_on_mirror=args.zoom_on_mirror)
        out[str(ckpt)] = scores(metrics, args.families, list(base["robot_types"]))
        for flag, name in ((args.mirror, "mirror_test"), (args.zoom, "zoom_test"), (args.fit, "kinematic_fit")):
            if flag:
                out[str(ckpt)][name] = scores(metrics[name], args.families, list(base["robot_types"]))
        print(ckpt, json.dumps(out[str(ckpt)], indent=1))
    if args.out:
        atomic_write_json(args.out, out)


if __name__ == "__main__":
    main()
