"""Cost of one pretraining step at reduced input scales against the full 256x212 input.

    python benchmarks/bench_low_res.py [--scales 1.0 0.75 0.5] [--steps 20] [--threads 2]

One step as :func:`armpose.train.train` takes it with the default profile's pretraining
settings: a batch of real training frames of ``data/labels`` (loaded and augmented once,
outside the timing), shrunk by :func:`armpose.resolution.downscale_batch`, then the forward
pass (bfloat16 autocast as in params), every loss term, backward and the AdamW update. The
median over ``--steps`` timed steps after 3 warm-up steps, per scale, and each scale's
speed-up over scale 1. Data loading is left out: it does not change with the scale (the
frames are loaded at full size and shrunk after augmentation).
Writes ``results/bench_low_res.json`` (atomically).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import torch

from armpose.config import profile_params, project_root
from armpose.data import LabelledFrames, split_indices
from armpose.io import atomic_write_json
from armpose.losses import multi_objective_loss
from armpose.model import build_model
from armpose.resolution import downscale_batch
from armpose.train import to_channels_last, training_precision


def time_steps(model, optimizer, batch: dict, weights: dict, bf16: bool, steps: int) -> float:
    """Median seconds of one training step on ``batch``, over ``steps`` after 3 warm-up steps."""
    times = []
    for i in range(3 + steps):
        t0 = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            out = model(to_channels_last(batch["image"]))
        losses = multi_objective_loss({k: v.float() for k, v in out.items()}, batch, weights)
        optimizer.zero_grad(set_to_none=True)
        losses["total"].backward()
        optimizer.step()
        if i >= 3:
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scales", type=float, nargs="+", default=[1.0, 0.75, 0.5])
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=str(project_root() / "results" / "bench_low_res.json"))
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    params = profile_params("default")
    cfg, base = params["pretrain"], params["base"]
    data_dir = project_root() / "data" / "labels"
    rows = split_indices(data_dir, "train")[: int(cfg["batch_size"])]
    frames = LabelledFrames(data_dir, rows, augment=cfg.get("augment"), seed=int(base["seed"]))
    batch = torch.utils.data.default_collate([frames[i] for i in range(len(frames))])
    torch.manual_seed(int(base["seed"]))
    model = build_model(base.get("model", {})).to(memory_format=torch.channels_last).train()
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-4)
    bf16 = training_precision(cfg) == "bf16"
    per_scale = {}
    for scale in args.scales:
        small = downscale_batch(batch, scale)
        s = time_steps(model, optimizer, small, base["loss_weights"], bf16, args.steps)
        per_scale[str(scale)] = {"input": list(small["image"].shape[-2:][::-1]), "ms_per_step": round(1000 * s, 1)}
    full = per_scale.get("1.0", {}).get("ms_per_step")
    for entry in per_scale.values():
        entry["speedup_vs_full"] = round(full / entry["ms_per_step"], 2) if full else None
    out = {"batch_size": int(cfg["batch_size"]), "precision": training_precision(cfg), "threads": args.threads,
           "steps_timed": args.steps, "scales": per_scale,
           "machine": {"cpu_count": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                       "python": platform.python_version()},
           "command": "python benchmarks/bench_low_res.py --scales " + " ".join(str(s) for s in args.scales)
           + f" --steps {args.steps} --threads {args.threads}"}
    atomic_write_json(Path(args.out), out)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
