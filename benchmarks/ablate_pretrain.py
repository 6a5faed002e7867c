"""Short UR pretraining runs that differ in one setting: what a change buys per minute of CPU.

    python benchmarks/ablate_pretrain.py [--steps 1200] [--variants fp32 bf16 lift]

Needs the labelled dataset of the current profile (``dvc repro labels``). Each variant is the
``pretrain`` section of ``params.yaml`` with ``max_steps`` set to ``--steps`` and one change:

- ``fp32``: as in params, but float32 training steps (the reference);
- ``bf16``: bfloat16 autocast of the trunk and mask decoder (``precision: bf16``);
- ``lift``: the lifting head (``base.model.lift``; offsets and direct-base loss terms 1.2 and 0.3),
  float32.

Validation is on 100 held-out frames per UR type. Writes ``results/ablations.json``: per variant
the wall time, seconds per step and the final validation metrics, plus the machine. Runs go to
a temporary directory; nothing in ``models/`` is touched.
"""
from __future__ import annotations

import argparse
import copy
import json
import logging
import os
import platform
import tempfile
from pathlib import Path

import yaml

from armpose.config import project_root
from armpose.io import atomic_write_json
from armpose.train import train

VARIANTS = {
    "fp32": {"cfg": {"precision": "fp32"}},
    "bf16": {"cfg": {"precision": "bf16"}},
    "lift": {"cfg": {"precision": "fp32"}, "model": {"lift": True}, "loss_weights": {"offsets": 1.2, "direct": 0.3}},
}


def variant_config(params: dict, name: str, steps: int) -> tuple[dict, dict]:
    """(stage cfg, base) of one variant: params' pretrain section with ``steps`` and the change."""
    change = VARIANTS[name]
    base, cfg = copy.deepcopy(params["base"]), copy.deepcopy(params["pretrain"])
    base["model"] = {**base.get("model", {}), **change.get("model", {})}
    base["loss_weights"] = {**base["loss_weights"], **change.get("loss_weights", {})}
    cfg.update(change.get("cfg", {}))
    cfg.update(max_steps=steps, eval_every=steps, val_per_type=100, checkpoint_every=10 ** 9)
    return cfg, base


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=1200)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    root = project_root()
    params = yaml.safe_load((root / "params.yaml").read_text())
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.variants:
            cfg, base = variant_config(params, name, args.steps)
            res = train("pretrain", cfg, base, root / "data" / "labels", Path(tmp) / name)
            results[name] = {k: res[k] for k in ("steps", "wall_s", "s_per_step", "val_joint_cm", "val_base_cm",
                                                 "val_type_acc", "val_mask_acc")}
            print(name, json.dumps(results[name]))
    out = {"steps": args.steps, "variants": results, "machine": platform.processor() or platform.machine(),
           "cpu_count": os.cpu_count(), "frames_per_robot": params["render"]["frames_per_robot"]}
    atomic_write_json(root / "results" / "ablations.json", out)
    print(f"wrote {root / 'results' / 'ablations.json'}")


if __name__ == "__main__":
    main()
