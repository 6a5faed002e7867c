"""How much the test scores move between runs of the two transfer stages that differ only in their seed.

    python benchmarks/transfer_seeds.py [--seeds 1 2] [--set transfer_stage2.KEY=VALUE ...] [--out FILE]

For each seed offset S, stage 1 and stage 2 are trained again from the project's pretrained
checkpoint (``models/pretrain/model.pt``, not retrained) with ``seed_offset: S`` in both
stages: another draw of the 500 frames per robot type (:func:`armpose.data.transfer_set`),
another shuffle and other augmentations. Each seed works in its own folder,
``models/transfer_seeds/<tag>/seed_<S>/`` (``data/`` and ``models/pretrain`` linked from the
project), so it never touches the pipeline's models, and an interrupted seed resumes there from
its ``last.pt``. Each network is scored on the test split as the ``evaluate`` stage scores the
headline model (zoom test and kinematic fit, on the mirror test's passes when
``evaluate.zoom_on_mirror`` says so; :func:`armpose.evaluate.evaluate_checkpoint`);
the project's own ``models/transfer_stage2/model.pt`` is scored too, as the pipeline's run
(its seed offset is the one in ``params.yaml``).

``--set SECTION.KEY=VALUE`` (VALUE read as YAML) changes a setting of both seeds' runs, so an
A/B of that setting can be read against the spread of the seeds; the tag is made from the
settings. Writes, atomically, per run and family: frames, joint and base median (cm), type and
mask accuracy (%), the stage-2 step count; and per family the minimum, maximum and spread
(max - min) of each figure over the runs (with ``--set``, over the seeds only: the pipeline's run
has the settings of ``params.yaml``). Default output: ``results/transfer_seeds.json``.
One seed takes about 14 minutes on the 2-core machine of the README (stage 2 most of it).
"""
from __future__ import annotations

import argparse
import json
import logging
import os
from pathlib import Path

import numpy as np
import torch
import yaml

from armpose.config import deep_merge, load_params, override_from_text, project_root
from armpose.evaluate import evaluate_checkpoint
from armpose.io import atomic_write_json
from armpose.kinematic_fit import FitSettings
from armpose.stages import transfer_stage1, transfer_stage2

STAGES = ("transfer_stage1", "transfer_stage2")
STAGE_RUNS = (transfer_stage1.run, transfer_stage2.run)   # the pipeline's own: stage 2 measures its fit sigmas
FIGURES = ("joint_median_cm", "base_median_cm", "type_accuracy", "mask_accuracy")


def seed_params(params: dict, seed: int, overrides: list[str]) -> dict:
    """``params`` with ``seed_offset: seed`` in both transfer stages, then ``overrides``
    (``SECTION.KEY=VALUE`` texts, :func:`armpose.config.override_from_text`) applied."""
    out = deep_merge(params, {stage: {"seed_offset": int(seed)} for stage in STAGES})
    for text in overrides:
        out = deep_merge(out, override_from_text(text, params))
    return out


def tag_of(overrides: list[str]) -> str:
    """A folder name for a set of overrides (``default`` for none)."""
    return "__".join(t.replace(" ", "") for t in overrides).replace("/", "_") or "default"


def link_project(root: Path, work: Path) -> None:
    """``work/data`` and ``work/models/pretrain`` as links to the project's."""
    (work / "models").mkdir(parents=True, exist_ok=True)
    for rel in ("data", "models/pretrain"):
        if not (work / rel).exists():
            os.symlink((root / rel).resolve(), work / rel)


def train_seed(params: dict, work: Path) -> None:
    """Both transfer stages in ``work`` with ``params``, through the stages' own ``run`` (as
    ``dvc repro`` runs them), so stage 2 also measures and stores the kinematic fit's weights
    (``transfer_stage2.fit_sigmas``, on the passes ``fit_sigmas_on_mirror`` names). A finished
    seed only has them measured, if its checkpoint lacks them."""
    for run in STAGE_RUNS:
        run(params, work)


def family_scores(metrics: dict, steps: int | None) -> dict:
    """The :data:`FIGURES` of the kinematic fit (the headline) per family, in cm and %."""
    percent = {"type_accuracy", "mask_accuracy"}
    out = {fam: {"frames": int(m["frames"]),
                 **{f: round((100 if f in percent else 1) * float(m[f]), 2) for f in FIGURES}}
           for fam, m in metrics["kinematic_fit"]["by_family"].items()}
    return {"stage2_steps": steps, "by_family": out}


def spread(runs: dict) -> dict:
    """Per family and figure: min, max and max - min over ``runs``."""
    fams = next(iter(runs.values()))["by_family"]
    out = {}
    for fam in fams:
        out[fam] = {}
        for f in FIGURES:
            vals = np.array([r["by_family"][fam][f] for r in runs.values()])
            out[fam][f] = {"min": round(float(vals.min()), 2), "max": round(float(vals.max()), 2),
                           "spread": round(float(vals.max() - vals.min()), 2)}
    return out


def score(stage2_dir: Path, root: Path, base: dict, on_mirror: bool = False) -> dict:
    """:func:`family_scores` of ``stage2_dir/model.pt`` (the zoom test on the mirror test's passes
    with ``on_mirror``); its step count from the stage's ``summary.json``."""
    metrics, _, _ = evaluate_checkpoint(stage2_dir / "model.pt", root / "data" / "labels", base, zoom=True,
                                        fit=FitSettings(), mirror=on_mirror, zoom_on_mirror=on_mirror)
    return family_scores(metrics, json.loads((stage2_dir / "summary.json").read_text()).get("steps"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", nargs="+", type=int, default=[1, 2])
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="SECTION.KEY=VALUE")
    ap.add_argument("--out", type=Path, help="default: results/transfer_seeds.json")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    root = project_root()
    params = load_params(root / "params.yaml")
    torch.set_num_threads(int(params["transfer_stage2"].get("threads", 2)))
    for text in args.overrides:  # a typo fails here, before any training
        override_from_text(text, params)
    tag = tag_of(args.overrides)
    on_mirror = bool(params["evaluate"].get("zoom_on_mirror", False))
    runs = {"pipeline": score(root / "models" / "transfer_stage2", root, params["base"], on_mirror)}
    runs["pipeline"]["seed_offset"] = int(params["transfer_stage2"].get("seed_offset", 0))
    for seed in args.seeds:
        work = root / "models" / "transfer_seeds" / tag / f"seed_{seed}"
        link_project(root, work)
        p = seed_params(params, seed, args.overrides)
        train_seed(p, work)
        runs[f"seed_{seed}"] = {**score(work / "models" / "transfer_stage2", root, p["base"], on_mirror),
                                "seed_offset": seed}
        print(f"seed {seed}:", json.dumps(runs[f"seed_{seed}"]["by_family"]))
    seeds = {k: v for k, v in runs.items() if k != "pipeline" or not args.overrides}
    result = {"tag": tag, "overrides": args.overrides, "zoom_on_mirror": on_mirror, "runs": runs, "spread_over": sorted(seeds), "spread": spread(seeds)}
    atomic_write_json(args.out or root / "results" / "transfer_seeds.json", result)
    print(json.dumps(result["spread"], indent=1))


if __name__ == "__main__":
    main()
