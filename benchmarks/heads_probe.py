"""Are the heads or the trunk's features the limit? Retrain only the heads of a checkpoint.

    python benchmarks/heads_probe.py [--checkpoint models/pretrain/model.pt] [--steps 2000]

Runs :func:`armpose.train.train` with the default profile's ``transfer_stage1`` settings (heads
only, on cached trunk features, no distillation) but on every training frame of the UR types
instead of the transfer set, from ``--checkpoint``, for ``--steps`` steps with the learning
rate falling from 1e-3 as in stage 1. Then scores the checkpoint and the retrained one on the
UR test frames (:func:`armpose.evaluate.evaluate_checkpoint`). If more head training on the
same features barely moves the scores, the features are what limits them. The run goes to a
temporary folder; writes ``results/heads_probe.json`` (atomically) and prints it.
"""
from __future__ import annotations

import argparse
import copy
import json
import tempfile
from pathlib import Path

import torch

from armpose.config import profile_params, project_root
from armpose.evaluate import evaluate_checkpoint
from armpose.io import atomic_write_json
from armpose.train import train

KEYS = ("joint_median_cm", "base_median_cm", "type_accuracy")
UR_TYPES = ["ur3", "ur5", "ur10"]


def probe_config(params: dict, checkpoint: Path, steps: int) -> dict:
    """The stage config of the probe: transfer stage 1's, on all UR frames, from ``checkpoint``."""
    cfg = copy.deepcopy(params["transfer_stage1"])
    cfg.update(robots=UR_TYPES, per_type=None, init_from=str(checkpoint), max_steps=int(steps), plateau=None,
               eval_every=int(steps), distill=None, feature_cache=True, trainable=["heads"])
    return cfg


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", default="models/pretrain/model.pt")
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--out", default=str(project_root() / "results" / "heads_probe.json"))
    args = ap.parse_args()
    root = project_root()
    params = profile_params("default")
    data_dir = root / "data" / "labels"
    checkpoint = root / args.checkpoint
    cfg = probe_config(params, checkpoint, args.steps)
    torch.set_num_threads(int(cfg.get("threads", 2)))
    scores = {}
    with tempfile.TemporaryDirectory() as tmp:
        run = train("heads_probe", cfg, params["base"], data_dir, Path(tmp))
        for name, path in (("checkpoint", checkpoint), ("heads_retrained", Path(tmp) / "model.pt")):
            metrics, _, _ = evaluate_checkpoint(path, data_dir, params["base"])
            scores[name] = {k: round(float(metrics["by_family"]["UR"][k]), 4) for k in KEYS}
    out = {"checkpoint": args.checkpoint, "steps": args.steps, "train_frames": run["num_train_frames"],
           "wall_s": run["wall_s"], "ur_test": scores,
           "command": f"python benchmarks/heads_probe.py --checkpoint {args.checkpoint} --steps {args.steps}"}
    atomic_write_json(Path(args.out), out)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
