"""Short UR pretraining runs that differ in one setting: what a change buys per minute of CPU.

    python benchmarks/ablate_pretrain.py [--steps 1200] [--variants fp32 bf16 lift]

Needs the labelled dataset of the current profile (``dvc repro labels``). Each variant is the
``pretrain`` section of ``params.yaml`` with ``max_steps`` set to ``--steps`` and one change:

- ``fp32``: as in params, but float32 training steps (the reference);
- ``bf16``: bfloat16 autocast of the trunk and mask decoder (``precision: bf16``);
- ``lift``: the lifting head (``base.model.lift``; offsets and direct-base loss terms 1.2 and 0.3),
  float32;
- ``stride4``: keypoint heads at stride 4 instead of 8 (``base.model.keypoint_stride``), bf16;
- ``heatmap2``: heatmap loss weight 2.0 instead of params' 0.5, bf16;
- ``skeleton``: every keypoint's depth MLP also sees all joints' attention centres, the 2D
  skeleton (``base.model.skeleton_context``), bf16;
- ``photometric``: photometric augmentation only (no camera turn, mirror or dolly), bf16.

The results stored for ``fp32``, ``bf16``, ``lift``, ``stride4``, ``heatmap2`` and ``skeleton``
were measured when params' pretraining used photometric augmentation only (commit 8c0548a);
params now add the camera turn, mirror and dolly, so a new run of those variants includes them.

Validation is on 100 held-out frames per UR type. Writes ``results/ablations.json``: per variant
the wall time, seconds per step, the final validation metrics, the machine and the data size; a run with
other than the default 1200 steps is stored as ``<variant>@<steps>`` (an equal-time comparison
of a slower variant), and earlier runs of the other variants are kept. Runs go to
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

DEFAULT_STEPS = 1200
PHOTOMETRIC = {"brightness": 0.2, "contrast": 0.2, "saturation": 0.2, "noise": 0.02}
VARIANTS = {
    "fp32": {"cfg": {"precision": "fp32"}},
    "bf16": {"cfg": {"precision": "bf16"}},
    "lift": {"cfg": {"precision": "fp32"}, "model": {"lift": True}, "loss_weights": {"offsets": 1.2, "direct": 0.3}},
    "stride4": {"cfg": {"precision": "bf16"}, "model": {"keypoint_stride": 4}},
    "heatmap2": {"cfg": {"precision": "bf16"}, "loss_weights": {"heatmap": 2.0}},
    "skeleton": {"cfg": {"precision": "bf16"}, "model": {"skeleton_context": True}},
    "photometric": {"cfg": {"precision": "bf16", "augment": PHOTOMETRIC}},
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
    ap.add_argument("--steps", type=int, default=DEFAULT_STEPS)
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    root = project_root()
    params = yaml.safe_load((root / "params.yaml").read_text())
    out_path = root / "results" / "ablations.json"
    previous = json.loads(out_path.read_text()) if out_path.exists() else {}
    results = dict(previous.get("variants", {}))   # other variants' earlier runs are kept
    machine = {"processor": platform.processor() or platform.machine(), "cpu_count": os.cpu_count()}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.variants:
            cfg, base = variant_config(params, name, args.steps)
            res = train("pretrain", cfg, base, root / "data" / "labels", Path(tmp) / name)
            key = name if args.steps == DEFAULT_STEPS else f"{name}@{args.steps}"
            results[key] = {**{k: res[k] for k in ("steps", "wall_s", "s_per_step", "val_joint_cm", "val_base_cm",
                                                    "val_type_acc", "val_mask_acc")},
                            "machine": machine, "frames_per_robot": params["render"]["frames_per_robot"]}
            print(key, json.dumps(results[key]))
    out = {"steps": DEFAULT_STEPS, "variants": results}
    atomic_write_json(out_path, out)
    print(f"wrote {out_path}")


if __name__ == "__main__":
    main()
